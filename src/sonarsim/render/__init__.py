"""The renderer: the :class:`~sonarsim.render.simulator.Simulator` and its pipeline.

:mod:`~sonarsim.render.simulator` (rays -> casting -> intensities -> images per frame),
:mod:`~sonarsim.render.components` (which bounces make which image),
:mod:`~sonarsim.render.formation` (Algorithm 1: rays into polar images, NumPy) and
:mod:`~sonarsim.render.compiled` (the compiled per-ray kernels of ``_kernels.pyx``).
"""
