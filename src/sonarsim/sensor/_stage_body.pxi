# The sensor stage's loops, compiled twice: ``_stage`` (the platform's baseline instruction set)
# and, on x86-64, ``_stage_avx2`` (AVX2 and FMA; twice as fast). sonarsim.sensor.model picks the
# second where the processor has them. Included by both .pyx files; edit here.

from libc.math cimport expf, sqrtf
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy, memset
from libc.stdint cimport int32_t

cdef float DB_PER_LN = 4.342944819032518  # 10 / ln 10
# Powers below this are zero: the vectorised square root is not exact for subnormal floats.
cdef float TINY = 1e-30
cdef float HALF = 0.5
# ln(1 + f) = f (L0 + L1 f + ... + L7 f^7) for 1 + f in [2/3, 4/3) (see _ln).
cdef float LN2 = 0.6931471805599453
cdef float L0 = 0.99999982, L1 = -0.49999931, L2 = 0.33337992, L3 = -0.25008029
cdef float L4 = 0.19794965, L5 = -0.16412768, L6 = 0.17111619, L7 = -0.15403341


def blur_beams(const float[:, ::1] x, const float[::1] column_factor, const float[::1] kb,
               const float[::1] norm_b, float[:, ::1] out, Py_ssize_t r0, Py_ssize_t r1):
    """Rows r0..r1 of ``out = norm_b * sum_m kb[m] (x * column_factor)[:, j + m - K]`` (zero outside)."""
    cdef Py_ssize_t n_b = x.shape[1], hb = kb.shape[0] // 2, i
    cdef float *pad = <float *> malloc((n_b + 2 * hb) * sizeof(float))
    if pad == NULL:
        raise MemoryError()
    with nogil:
        memset(pad, 0, (n_b + 2 * hb) * sizeof(float))
        for i in range(r0, r1):
            _blur_beams_row(x, i, column_factor, kb, norm_b, pad, &out[i, 0])
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


cdef inline float _ln(float x) noexcept nogil:
    """Natural logarithm of a positive normal float, to 1e-7 (about float32's own rounding).

    Inlined so that the row loops vectorise without calling a vector maths library (glibc's is
    not everywhere). ``x = 2^e (1 + f)`` with ``1 + f`` in [2/3, 4/3);
    ``ln(1 + f) = f P(f)``, P of degree 7 fitted to ``log1p(f) / f`` on Chebyshev nodes of that
    interval (largest error 9.8e-8, checked against NumPy in the tests).
    """
    cdef int32_t bits, e
    cdef float f
    memcpy(&bits, &x, 4)
    e = (bits - 0x3f2aaaab) >> 23  # 0x3f2aaaab: the bits of 2/3
    bits = bits - (e << 23)
    memcpy(&f, &bits, 4)
    f = f - 1.0
    # Float constants (a bare literal is a C double and would turn the loop into doubles).
    return LN2 * <float> e + f * (L0 + f * (L1 + f * (L2 + f * (L3 + f * (L4 + f * (L5 + f * (L6 + f * L7)))))))


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
            v = v if v > TINY else TINY
            out[j] = (DB_PER_LN * _ln(v) - lo_db) * scale
    elif comp == 2:
        for j in range(n):  # no power, no output (the twin's 0 ** gamma)
            v = p[j] * inv_ceiling
            out[j] = fs * expf(gamma * _ln(v if v > TINY else TINY)) if v > TINY else 0.0
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
            out[j] = <float> (<int> (out[j] + HALF))


ctypedef signed char part_t  # a pool field's stored real or imaginary part (sensor.speckle)


cdef struct Field:
    # A frame's window into a quantised pool field (``SpecklePool``): rows of ``2 n_b`` real
    # parts then ``2 n_b`` imaginary parts; row ``i`` of the window is stored row
    # ``first + (row + i) mod n_rows``, its beams start at ``beam``.
    const part_t *data
    Py_ssize_t first, row, n_rows, stride, beam, n_b
    float scale


cdef inline const part_t *_field_row(const Field *f, Py_ssize_t i) noexcept nogil:
    return f.data + (f.first + (f.row + i) % f.n_rows) * f.stride + f.beam


cdef struct Chain:
    # What turns a row of the mean image into device values (see ``frame``).
    const float *echo_gain
    const float *bang
    const float *bang_beam    # per beam: the bang's pattern across beams
    const float *tvg
    const float *beam_gain    # per beam: the channel's gain (steering loss, stripes)
    const float *noise_power  # per row: the receiver's, plus the after-TVG noise referred to it
    const float *common_re    # per row: this frame's noise common to the row's beams
    const float *common_im
    Field speckle  # data NULL: no speckle
    Field noise    # data NULL: no noise
    int comp
    float lo_db, inv_span, inv_ceiling, gamma, fs
    bint quantise
    const float *table
    Py_ssize_t n_table
    float table_lo_db, table_step_db
    bint expected


cdef inline void _combine_row(const float *m, Py_ssize_t i, Py_ssize_t n_b, const Chain *c, float *p,
                              float *tg, float *bb, float *out, bint per_beam, bint common) noexcept nogil:
    """Device values of row ``i`` whose mean image is ``m`` (``p``, ``tg``, ``bb``: scratch of
    ``n_b`` floats each).

    Per pixel: ``mu = echo_gain[i] m + bang[i] bang_beam[j]``; with ``expected``:
    ``table(10 log10(tvg[i] beam_gain[j] (mu + N)))`` (N the row's noise power, common noise
    included); else ``P = tvg[i] beam_gain[j] |sqrt(mu) F + sqrt(N) W + C|^2`` (F = 1 without
    speckle, W = 0 without noise, C = common_re[i] + i common_im[i]) and the compression of P.

    ``per_beam`` (the per-beam factors are not all 1) and ``common`` (C is not 0) are constants
    at each call (:func:`_combine`): the compiler makes a copy of the loops for each, and
    without them the loops are those of a stage without these effects (same speed, same
    rounding).
    """
    cdef Py_ssize_t j, k, n_t = c.n_table
    cdef float g = c.echo_gain[i], b = c.bang[i], t = c.tvg[i], mu, re, im, s, x, frac
    cdef float cr = c.common_re[i], ci = c.common_im[i]
    cdef const float *bang_beam = c.bang_beam
    cdef const float *beam_gain = c.beam_gain
    # Locals, not the struct's fields, in the loops: the compiler then knows nothing aliases them.
    cdef float noise_power = c.noise_power[i], inv_step = 1.0 / c.table_step_db
    cdef float sn = sqrtf(c.noise_power[i]) * c.noise.scale
    cdef float lo = c.table_lo_db, top = <float> (n_t - 1)
    cdef const float *table = c.table
    cdef const part_t *fr = NULL  # set below where the fields exist (the compiler cannot tell)
    cdef const part_t *fi = NULL
    cdef const part_t *wr = NULL
    cdef const part_t *wi = NULL
    if per_beam:  # the row's gain and bang in each beam
        for j in range(n_b):
            tg[j] = t * beam_gain[j]
    if c.expected:
        if per_beam:
            for j in range(n_b):
                bb[j] = b * bang_beam[j]
            for j in range(n_b):
                x = tg[j] * (g * m[j] + bb[j] + noise_power)
                x = x if x > TINY else TINY
                x = (DB_PER_LN * _ln(x) - lo) * inv_step
                x = x if x > 0.0 else 0.0
                p[j] = x if x < top else top
        else:
            for j in range(n_b):
                x = t * (g * m[j] + b + noise_power)
                x = x if x > TINY else TINY
                x = (DB_PER_LN * _ln(x) - lo) * inv_step
                x = x if x > 0.0 else 0.0
                p[j] = x if x < top else top
        for j in range(n_b):
            x = p[j]
            k = <Py_ssize_t> x
            if k >= n_t - 1:
                out[j] = table[n_t - 1]
            else:
                frac = x - k
                out[j] = table[k] + frac * (table[k + 1] - table[k])
        return
    if c.speckle.data != NULL:
        # sqrt(mu) * scale * stored = sqrt(mu scale^2) * stored: the step folds into the gains.
        g = g * c.speckle.scale * c.speckle.scale
        b = b * c.speckle.scale * c.speckle.scale
        fr = _field_row(&c.speckle, i)
        fi = fr + 2 * c.speckle.n_b
    if c.noise.data != NULL:
        wr = _field_row(&c.noise, i)
        wi = wr + 2 * c.noise.n_b
    else:  # the common noise comes with the receiver's (``frame`` passes zeros without it)
        cr = ci = 0.0
    if per_beam:
        for j in range(n_b):
            bb[j] = b * bang_beam[j]
    # ``bb[j] if per_beam else b``: a constant condition, resolved when the loops are compiled;
    # likewise ``+ cr`` (zero without common noise, where fast maths drops it).
    if c.speckle.data != NULL and c.noise.data != NULL:
        for j in range(n_b):
            mu = g * m[j] + (bb[j] if per_beam else b)
            s = sqrtf(mu if mu > TINY else 0.0)
            re = s * <float> fr[j] + sn * <float> wr[j]
            im = s * <float> fi[j] + sn * <float> wi[j]
            if common:
                re = re + cr
                im = im + ci
            p[j] = re * re + im * im
    elif c.speckle.data != NULL:
        for j in range(n_b):
            mu = g * m[j] + (bb[j] if per_beam else b)
            s = sqrtf(mu if mu > TINY else 0.0)
            re = s * <float> fr[j]
            im = s * <float> fi[j]
            p[j] = re * re + im * im
    elif c.noise.data != NULL:
        for j in range(n_b):
            mu = g * m[j] + (bb[j] if per_beam else b)
            s = sqrtf(mu if mu > TINY else 0.0)
            re = s + sn * <float> wr[j]
            im = sn * <float> wi[j]
            if common:
                re = re + cr
                im = im + ci
            p[j] = re * re + im * im
    else:
        for j in range(n_b):
            mu = g * m[j] + (bb[j] if per_beam else b)
            p[j] = mu if mu > TINY else 0.0
    if per_beam:
        for j in range(n_b):
            p[j] = tg[j] * p[j]
    else:
        for j in range(n_b):
            p[j] = t * p[j]
    _compress_row(p, out, n_b, c.comp, c.lo_db, c.inv_span, c.inv_ceiling, c.gamma, c.fs, c.quantise)


cdef void _combine(const float *m, Py_ssize_t i, Py_ssize_t n_b, const Chain *c, float *p, float *tg, float *bb,
                   float *out, bint per_beam) noexcept nogil:
    """:func:`_combine_row` with its flags as constants (one specialised copy each)."""
    cdef bint common = c.common_re[i] != 0.0 or c.common_im[i] != 0.0
    if per_beam:
        if common:
            _combine_row(m, i, n_b, c, p, tg, bb, out, True, True)
        else:
            _combine_row(m, i, n_b, c, p, tg, bb, out, True, False)
    elif common:
        _combine_row(m, i, n_b, c, p, tg, bb, out, False, True)
    else:
        _combine_row(m, i, n_b, c, p, tg, bb, out, False, False)


cdef inline void _blur_beams_row(const float[:, ::1] x, Py_ssize_t i, const float[::1] column_factor,
                                 const float[::1] kb, const float[::1] norm_b, float *pad, float *t) noexcept nogil:
    """``t = norm_b * sum_m kb[m] (x[i] * column_factor)[j + m - K]``; ``pad``: zero-edged scratch."""
    cdef Py_ssize_t n_b = x.shape[1], kb_len = kb.shape[0], hb = kb_len // 2, j, m
    cdef float k
    for j in range(n_b):
        pad[hb + j] = x[i, j] * column_factor[j]
        t[j] = 0.0
    for m in range(kb_len):
        k = kb[m]
        for j in range(n_b):
            t[j] += k * pad[j + m]
    for j in range(n_b):
        t[j] *= norm_b[j]


cdef Field _field(const part_t[:, :, :, ::1] pool, Py_ssize_t field, Py_ssize_t row, Py_ssize_t beam,
                  float scale, bint used):
    cdef Field f
    f.data = &pool[0, 0, 0, 0] if used else NULL
    f.n_rows = pool.shape[1]
    f.first = field * pool.shape[1]
    f.row = row
    f.stride = 2 * pool.shape[3]
    f.beam = beam
    f.n_b = pool.shape[3] // 2
    f.scale = scale if used else 0.0
    return f


cdef Chain _chain(const float[::1] echo_gain, const float[::1] bang, const float[::1] bang_beam, const float[::1] tvg,
                  const float[::1] beam_gain, const float[::1] noise_power, const float[::1] common_re,
                  const float[::1] common_im, Field speckle, Field noise,
                  int comp, float lo_db, float inv_span, float inv_ceiling, float gamma, float fs, bint quantise,
                  const float[::1] table, float table_lo_db, float table_step_db, bint expected):
    cdef Chain c
    c.echo_gain, c.bang, c.tvg, c.noise_power = &echo_gain[0], &bang[0], &tvg[0], &noise_power[0]
    c.bang_beam, c.beam_gain, c.common_re, c.common_im = &bang_beam[0], &beam_gain[0], &common_re[0], &common_im[0]
    c.speckle, c.noise = speckle, noise
    c.comp, c.lo_db, c.inv_span, c.inv_ceiling, c.gamma, c.fs, c.quantise = (
        comp, lo_db, inv_span, inv_ceiling, gamma, fs, quantise)
    c.table, c.n_table, c.table_lo_db, c.table_step_db, c.expected = (
        &table[0], table.shape[0], table_lo_db, table_step_db, expected)
    return c


def frame(const float[:, ::1] x, const float[::1] column_factor, const float[::1] kb, const float[::1] norm_b,
          const float[::1] kr, const float[::1] norm_r, const float[::1] echo_gain, const float[::1] bang,
          const float[::1] bang_beam, const float[::1] tvg, const float[::1] beam_gain, const float[::1] noise_power,
          const float[::1] common_re, const float[::1] common_im,
          const part_t[:, :, :, ::1] speckle, Py_ssize_t s_field, Py_ssize_t s_row, Py_ssize_t s_beam, float s_scale,
          bint has_speckle,
          const part_t[:, :, :, ::1] noise, Py_ssize_t n_field, Py_ssize_t n_row, Py_ssize_t n_beam, float n_scale,
          bint has_noise,
          int comp, float lo_db, float inv_span, float inv_ceiling, float gamma, float fs, bint quantise,
          const float[::1] table, float table_lo_db, float table_step_db, bint expected,
          float[:, ::1] out, Py_ssize_t r0, Py_ssize_t r1):
    """Rows r0..r1 of a frame's device values from its image, in one pass: row by row,
    ``blur_beams`` of the row the range kernel reaches next, ``blur_range`` and the chain of
    :func:`_combine_row`, without a full-frame intermediate (one call per worker and
    frame). ``speckle`` and ``noise`` are a pool's quantised fields (``SpecklePool.speckle``:
    (n_fields, n_r, 2, 2 n_b) int8, one step worth ``*_scale``); the frame reads field
    ``*_field`` cyclically from the given row and beam offsets. ``bang_beam`` and ``beam_gain``
    are per beam (n_b,), ``common_re`` and ``common_im`` per row (n_r,): zeros without noise
    common to the beams."""
    if (bang_beam.shape[0] != x.shape[1] or beam_gain.shape[0] != x.shape[1]
            or common_re.shape[0] != x.shape[0] or common_im.shape[0] != x.shape[0]):
        raise ValueError("per-beam factors need one value per beam, common noise one per row")
    cdef Py_ssize_t n_r = x.shape[0], n_b = x.shape[1]
    cdef Py_ssize_t kb_len = kb.shape[0], hb = kb_len // 2, kr_len = kr.shape[0], hr = kr_len // 2
    cdef Py_ssize_t i, j, m, ii
    cdef float k
    cdef Chain c = _chain(echo_gain, bang, bang_beam, tvg, beam_gain, noise_power, common_re, common_im,
                          _field(speckle, s_field, s_row, s_beam, s_scale, has_speckle),
                          _field(noise, n_field, n_row, n_beam, n_scale, has_noise),
                          comp, lo_db, inv_span, inv_ceiling, gamma, fs, quantise, table,
                          table_lo_db, table_step_db, expected)
    # The rows blurred across beams that the range kernel needs, in a ring of kr_len rows:
    # a few kilobytes that stay in the first-level cache (a block of the frame would not).
    cdef float *ring = <float *> malloc((kr_len * n_b + n_b + 2 * hb + 4 * n_b) * sizeof(float))
    if ring == NULL:
        raise MemoryError()
    cdef float *pad = ring + kr_len * n_b
    cdef float *row = pad + n_b + 2 * hb
    cdef float *p = row + n_b
    cdef float *tg = p + n_b
    cdef float *bb = tg + n_b
    # The per-beam factors are all 1 unless an effect sets them: then the loops skip them.
    cdef bint per_beam = False
    for j in range(n_b):
        per_beam = per_beam or bang_beam[j] != 1.0 or beam_gain[j] != 1.0
    cdef float *t
    with nogil:
        memset(pad, 0, (n_b + 2 * hb) * sizeof(float))
        for ii in range(r0 - hr if r0 > hr else 0, r0 + hr if r0 + hr < n_r else n_r):
            _blur_beams_row(x, ii, column_factor, kb, norm_b, pad, ring + (ii % kr_len) * n_b)
        for i in range(r0, r1):  # along range, then the chain
            ii = i + hr
            if ii < n_r:
                _blur_beams_row(x, ii, column_factor, kb, norm_b, pad, ring + (ii % kr_len) * n_b)
            for j in range(n_b):
                row[j] = 0.0
            for m in range(kr_len):
                ii = i + m - hr
                if ii < 0 or ii >= n_r:
                    continue
                k = kr[m]
                t = ring + (ii % kr_len) * n_b
                for j in range(n_b):
                    row[j] += k * t[j]
            for j in range(n_b):
                row[j] *= norm_r[i]
            _combine(row, i, n_b, &c, p, tg, bb, &out[i, 0], per_beam)
    free(ring)


def ln(const float[::1] x, float[::1] out):
    """``out = ln(x)`` by the stage's inlined logarithm (for its test against NumPy); x > 0, normal."""
    cdef Py_ssize_t j
    with nogil:
        for j in range(x.shape[0]):
            out[j] = _ln(x[j])
