# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The fan's 8-bit levels from the polar grid's, one pass over the pixels inside the fan.

The twin of :meth:`sonarsim.image.fan.FanMapper.levels`' NumPy path, in the same integer
arithmetic (8-bit fixed-point weights), so that both give the same bytes.
"""

from libc.stdint cimport int32_t, uint8_t, uint16_t, uint32_t


def bilinear_levels(const uint8_t[::1] polar, const int32_t[::1] k00, const int32_t[::1] k01,
                    const int32_t[::1] k10, const int32_t[::1] k11, const uint16_t[::1] wb,
                    const uint16_t[::1] wr, const int32_t[::1] dest, uint8_t[::1] out):
    """``out[dest[i]]`` = the bilinear blend of the four polar levels around pixel ``i``:
    across beams with weight ``wb[i] / 256``, then across range with ``wr[i] / 256``, rounded
    half up (``(near * (256 - wr) + far * wr + 32768) >> 16``)."""
    cdef Py_ssize_t i, n = dest.shape[0]
    cdef uint32_t b, r, near, far
    with nogil:
        for i in range(n):
            b = wb[i]
            r = wr[i]
            near = polar[k00[i]] * (256 - b) + polar[k01[i]] * b
            far = polar[k10[i]] * (256 - b) + polar[k11[i]] * b
            out[dest[i]] = <uint8_t>((near * (256 - r) + far * r + 32768) >> 16)
