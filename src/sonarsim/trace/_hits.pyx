# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Embree's raw answer to the casters' hits, compiled (twin: :func:`sonarsim.trace.embree.embree_hits`).

Its own small extension so that the ray-casting layer needs nothing of the renderer's kernels
(the Embree 4 binding converts its packets itself, in ``_embree4.pyx``).
"""

from libc.math cimport sqrtf, INFINITY


def embree_hits(const float[::1] tfar, const int[::1] geom_id, const float[:, ::1] ng,
                const int[::1] ids, float[::1] distance, int[::1] mesh_id, float[:, ::1] normal):
    """Embree's raw answer -> distance (inf for none), mesh index (-1), unit normal (0)."""
    cdef Py_ssize_t i, n = tfar.shape[0]
    cdef int g
    cdef float inv
    with nogil:
        for i in range(n):
            g = geom_id[i]
            if g >= 0:
                distance[i] = tfar[i]
                mesh_id[i] = ids[g]
                inv = 1.0 / sqrtf(ng[i, 0] * ng[i, 0] + ng[i, 1] * ng[i, 1] + ng[i, 2] * ng[i, 2])
                normal[i, 0] = ng[i, 0] * inv
                normal[i, 1] = ng[i, 1] * inv
                normal[i, 2] = ng[i, 2] * inv
            else:
                distance[i] = INFINITY
                mesh_id[i] = -1
                normal[i, 0] = 0.0
                normal[i, 1] = 0.0
                normal[i, 2] = 0.0
