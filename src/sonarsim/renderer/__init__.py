"""The renderer: the :class:`~sonarsim.renderer.simulator.Simulator` and its pipeline.

:mod:`~sonarsim.renderer.simulator` (rays -> casting -> intensities -> images per frame),
:mod:`~sonarsim.renderer.components` (which bounces make which image),
:mod:`~sonarsim.renderer.formation` (Algorithm 1: rays into polar images, NumPy) and
:mod:`~sonarsim.renderer.compiled` (the compiled per-ray kernels of ``_kernels.pyx``).
"""
