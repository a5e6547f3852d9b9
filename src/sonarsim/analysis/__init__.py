"""Evaluation: :mod:`~sonarsim.analysis.metrics` (MSE, PSNR, SSIM as in the paper's Table I),
:mod:`~sonarsim.analysis.comparison` (two images whatever their geometry) and
:mod:`~sonarsim.analysis.fitting` (the sonar pose fitted to a real image)."""
