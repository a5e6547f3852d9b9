# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False, language_level=3
"""Compiled per-pixel loops of the sensor stage (NumPy twins in :mod:`sonarsim.sensor.model`).

``blur_beams`` and ``blur_range``: the mean image through the azimuth leakage and the pulse's
range spread (``SensorModel.mean_image``). ``frame``: the same, then per row echo + bang +
noise amplitudes -> power -> TVG and gain -> device values (or the tabulated expected value),
without a full-frame intermediate. Each works on rows ``[r0, r1)`` without the GIL, so that
the caller can run row blocks on several threads.

This build uses the platform's baseline instructions; ``_stage_avx2`` is the same code for
processors with AVX2 and FMA (see :func:`has_avx2_fma`).
"""

cdef extern from *:
    """
    static int sonarsim_has_avx2_fma(void) {
    #if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    #else
        return 0;
    #endif
    }
    """
    int sonarsim_has_avx2_fma() nogil


def has_avx2_fma() -> bool:
    """Whether this processor runs ``_stage_avx2`` (AVX2 and FMA)."""
    return bool(sonarsim_has_avx2_fma())


include "_stage_body.pxi"
