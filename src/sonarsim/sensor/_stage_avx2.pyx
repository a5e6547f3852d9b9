# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False, language_level=3
"""Compiled per-pixel loops of the sensor stage (NumPy twins in :mod:`sonarsim.sensor.model`).

``blur_beams`` and ``blur_range``: the mean image through the azimuth leakage and the pulse's
range spread (``SensorModel.mean_image``). ``frame``: the same, then per row echo + bang +
noise amplitudes -> power -> TVG and gain -> device values (or the tabulated expected value),
without a full-frame intermediate. Each works on rows ``[r0, r1)`` without the GIL, so that
the caller can run row blocks on several threads.

This build uses AVX2 and FMA: import it only where ``_stage.has_avx2_fma()`` is true.
"""

include "_stage_body.pxi"
