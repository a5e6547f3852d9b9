"""A slow, independent pure-NumPy ray caster (Moller-Trumbore), the reference for tests.

About 10,000 times slower than Embree: for small scenes and cross-checks only.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..scene.meshes import TriangleMesh
from .base import Hits

# Rays x triangles evaluated at once; bounds the temporary arrays to a few tens of MB.
_BLOCK_ELEMENTS = 1_000_000


class NumpyCaster:
    """Closest hits by testing every ray against every triangle, in float64."""

    name = "numpy"

    def __init__(self, meshes: Sequence[TriangleMesh], threads: int | None = None) -> None:
        tris = [m.triangles for m in meshes]
        ids = [np.full(len(m.faces), i, dtype=np.int32) for i, m in enumerate(meshes)]
        self._tri = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        self._tri_mesh = np.concatenate(ids) if ids else np.zeros(0, np.int32)
        # Index of each triangle within its mesh (Embree's primID).
        self._tri_index = np.concatenate([np.arange(len(m.faces), dtype=np.int32) for m in meshes]) if tris \
            else np.zeros(0, np.int32)
        self._e1 = self._tri[:, 1] - self._tri[:, 0]
        self._e2 = self._tri[:, 2] - self._tri[:, 0]
        n = np.cross(self._e1, self._e2)
        self._normal = n / np.linalg.norm(n, axis=1, keepdims=True)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, max_distance: float,
                  threads: int | None = None, with_uv: bool = False) -> Hits:
        d = np.asarray(directions, dtype=float)
        o = np.broadcast_to(np.asarray(origins, dtype=float), d.shape)
        n_rays, n_tri = len(d), len(self._tri)
        out = Hits.misses(n_rays, with_uv)
        if n_tri == 0 or n_rays == 0:
            return out
        best_t = np.full(n_rays, np.inf)
        best_k = np.full(n_rays, -1)
        best_uv = np.zeros((n_rays, 2))
        step = max(1, _BLOCK_ELEMENTS // n_tri)
        v0, e1, e2 = self._tri[:, 0], self._e1, self._e2
        for s in range(0, n_rays, step):
            dd = d[s:s + step, None, :]
            oo = o[s:s + step, None, :]
            p = np.cross(dd, e2[None])
            det = np.einsum("rtk,tk->rt", p, e1)
            ok = np.abs(det) > 1e-14
            inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)
            tv = oo - v0[None]
            u = np.einsum("rtk,rtk->rt", tv, p) * inv
            q = np.cross(tv, e1[None])
            v = np.einsum("rk,rtk->rt", d[s:s + step], q) * inv
            t = np.einsum("tk,rtk->rt", e2, q) * inv
            valid = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t <= max_distance)
            t = np.where(valid, t, np.inf)
            k = np.argmin(t, axis=1)
            rows = np.arange(len(k))
            tk = t[rows, k]
            best_t[s:s + step] = tk
            best_k[s:s + step] = np.where(np.isfinite(tk), k, -1)
            best_uv[s:s + step, 0] = u[rows, k]
            best_uv[s:s + step, 1] = v[rows, k]
        hit = best_k >= 0
        out.distance[hit] = best_t[hit]
        out.mesh_id[hit] = self._tri_mesh[best_k[hit]]
        out.normal[hit] = self._normal[best_k[hit]]
        if with_uv:
            out.primitive_id[hit] = self._tri_index[best_k[hit]]
            out.barycentric[hit] = best_uv[hit]
        return out
