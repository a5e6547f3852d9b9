# cython: boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False, language_level=3
"""Compiled per-pixel loops of the sensor stage (NumPy twins in :mod:`sonarsim.sensor.model`).

``blur_beams`` and ``blur_range``: the mean image through the azimuth leakage and the pulse's
range spread. ``combine``: echo + bang + noise amplitudes -> power -> TVG and gain -> device
values (or, with no fields, the tabulated expected value). Each works on rows ``[r0, r1)``
without the GIL, so that the caller can run row blocks on several threads.
"""

from libc.math cimport logf, expf, sqrtf, floorf
from libc.stdlib cimport malloc, free
from libc.string cimport memset

cdef float DB_PER_LN = 4.342944819032518  # 10 / ln 10
# Powers below this are zero: the vectorised square root is not exact for subnormal floats.
cdef float TINY = 1e-30


def blur_beams(const float[:, ::1] x, const float[::1] column_factor, const float[::1] kb,
               const float[::1] norm_b, float[:, ::1] out, Py_ssize_t r0, Py_ssize_t r1):
    """Rows r0..r1 of ``out = norm_b * sum_m kb[m] (x * column_factor)[:, j + m - K]`` (zero outside)."""
    cdef Py_ssize_t n_b = x.shape[1], kb_len = kb.shape[0], hb = kb_len // 2
    cdef Py_ssize_t i, j, m
    cdef float k
    cdef float *pad = <float *> malloc((n_b + 2 * hb) * sizeof(float))
    if pad == NULL:
        raise MemoryError()
    with nogil:
        memset(pad, 0, (n_b + 2 * hb) * sizeof(float))
        for i in range(r0, r1):
            for j in range(n_b):
                pad[hb + j] = x[i, j] * column_factor[j]
                out[i, j] = 0.0
            for m in range(kb_len):
                k = kb[m]
                for j in range(n_b):
                    out[i, j] += k * pad[j + m]
            for j in range(n_b):
                out[i, j] *= norm_b[j]
    free(pad)


def blur_range(const float[:, ::1] x, const float[::1] kr, const float[::1] norm_r, float[:, ::1] out,
               Py_ssize_t r0, Py_ssize_t r1):
    """Rows r0..r1 of ``out = norm_r * sum_m kr[m] x[i + m - R, :]`` (zero outside)."""
    cdef Py_ssize_t n_r = x.shape[0], n_b = x.shape[1], kr_len = kr.shape[0], hr = kr_len // 2
    cdef Py_ssize_t i, j, m, ii
    cdef float k
    with nogil:
        for i in range(r0, r1):
            for j in range(n_b):
                out[i, j] = 0.0
            for m in range(kr_len):
                ii = i + m - hr
                if ii < 0 or ii >= n_r:
                    continue
                k = kr[m]
                for j in range(n_b):
                    out[i, j] += k * x[ii, j]
            for j in range(n_b):
                out[i, j] *= norm_r[i]


cdef void _compress_row(float *p, float *out, Py_ssize_t n, int comp, float lo_db, float inv_span,
                       float inv_ceiling, float gamma, float fs, bint quantise) noexcept nogil:
    """``out[j] = compress(p[j])``; one loop per compression so that each vectorises."""
    cdef Py_ssize_t j
    cdef float v, scale
    if comp == 0:
        for j in range(n):
            out[j] = p[j]
        return
    if comp == 1:
        scale = inv_span * fs
        for j in range(n):
            v = p[j]
            v = v if v > 1e-30 else 1e-30
            out[j] = (DB_PER_LN * logf(v) - lo_db) * scale
    elif comp == 2:
        for j in range(n):
            v = p[j] * inv_ceiling
            v = v if v > 1e-30 else 1e-30
            out[j] = fs * expf(gamma * logf(v))
    else:
        scale = fs * inv_ceiling
        for j in range(n):
            out[j] = p[j] * scale
    for j in range(n):
        v = out[j]
        v = v if v > 0.0 else 0.0
        out[j] = v if v < fs else fs
    if quantise:
        for j in range(n):  # values are >= 0: truncating v + 0.5 rounds half up
            out[j] = <float> (<int> (out[j] + 0.5))


def combine(const float[:, ::1] mean, const float[::1] echo_gain, const float[::1] bang, const float[::1] tvg,
            float noise_power, const float[:, ::1] speckle, Py_ssize_t s_row, Py_ssize_t s_beam, bint has_speckle,
            const float[:, ::1] noise, Py_ssize_t n_row, Py_ssize_t n_beam, bint has_noise,
            int comp, float lo_db, float inv_span, float inv_ceiling, float gamma, float fs, bint quantise,
            const float[::1] table, float table_lo_db, float table_step_db, bint expected,
            float[:, ::1] out, Py_ssize_t r0, Py_ssize_t r1):
    """Rows r0..r1 of the device values of one frame.

    Per pixel: ``mu = echo_gain[i] mean + bang[i]``; with ``expected``:
    ``table(10 log10(tvg[i] (mu + N)))``; else
    ``P = tvg[i] |sqrt(mu) F + sqrt(N) W|^2`` (F = 1 without speckle, W = 0 without noise) and
    the compression of P. ``speckle`` and ``noise`` are complex fields stored as float pairs;
    the frame reads them from the given row and beam offsets.
    """
    cdef Py_ssize_t n_b = mean.shape[1], n_t = table.shape[0]
    cdef Py_ssize_t i, j, k
    cdef float g, b, t, mu, re, im, s, sn = sqrtf(noise_power), x, frac, inv_step = 1.0 / table_step_db
    cdef const float *f
    cdef const float *w
    cdef float *p = <float *> malloc(n_b * sizeof(float))
    if p == NULL:
        raise MemoryError()
    with nogil:
        for i in range(r0, r1):
            g, b, t = echo_gain[i], bang[i], tvg[i]
            if expected:
                for j in range(n_b):
                    x = t * (g * mean[i, j] + b + noise_power)
                    x = x if x > 1e-30 else 1e-30
                    p[j] = (DB_PER_LN * logf(x) - table_lo_db) * inv_step
                for j in range(n_b):
                    x = p[j]
                    if x <= 0.0:
                        out[i, j] = table[0]
                    elif x >= n_t - 1:
                        out[i, j] = table[n_t - 1]
                    else:
                        k = <Py_ssize_t> x
                        frac = x - k
                        out[i, j] = table[k] + frac * (table[k + 1] - table[k])
                continue
            if has_speckle and has_noise:
                f = &speckle[s_row + i, 2 * s_beam]
                w = &noise[n_row + i, 2 * n_beam]
                for j in range(n_b):
                    mu = g * mean[i, j] + b
                    s = sqrtf(mu if mu > TINY else 0.0)
                    re = s * f[2 * j] + sn * w[2 * j]
                    im = s * f[2 * j + 1] + sn * w[2 * j + 1]
                    p[j] = re * re + im * im
            elif has_speckle:
                f = &speckle[s_row + i, 2 * s_beam]
                for j in range(n_b):
                    mu = g * mean[i, j] + b
                    s = sqrtf(mu if mu > TINY else 0.0)
                    re = s * f[2 * j]
                    im = s * f[2 * j + 1]
                    p[j] = re * re + im * im
            elif has_noise:
                w = &noise[n_row + i, 2 * n_beam]
                for j in range(n_b):
                    mu = g * mean[i, j] + b
                    s = sqrtf(mu if mu > TINY else 0.0)
                    re = s + sn * w[2 * j]
                    im = sn * w[2 * j + 1]
                    p[j] = re * re + im * im
            else:
                for j in range(n_b):
                    mu = g * mean[i, j] + b
                    p[j] = mu if mu > TINY else 0.0
            for j in range(n_b):
                p[j] = t * p[j]
            _compress_row(p, &out[i, 0], n_b, comp, lo_db, inv_span, inv_ceiling, gamma, fs, quantise)
    free(p)
