"""The answer of a ray caster: the closest hits of a batch of rays, as plain arrays.

:class:`Hits` is the data every ray-casting engine (:mod:`sonarsim.trace`) returns and every
consumer reads: the path engine, the surface tracer, and the texture wrapper of
:mod:`sonarsim.scene.textures`, which sits below :mod:`sonarsim.trace` (the engines are built
from the scene's meshes). A plain data type, it lives here, at the bottom;
:mod:`sonarsim.trace.base` re-exports it, where it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Hits"]


@dataclass(frozen=True)
class Hits:
    """Closest hits of a batch of ``n`` rays.

    Attributes
    ----------
    distance : (n,) float32 ndarray, metres
        Distance along the (unit) ray to the hit; ``inf`` where the ray hits nothing within
        its limit.
    mesh_id : (n,) int32 ndarray
        Index of the mesh hit, in the order the meshes were given; -1 for no hit.
    normal : (n, 3) float32 ndarray
        Geometric normal of the triangle hit, unit length, either orientation; 0 for no hit.
    texel : (n,) float32 ndarray or None
        Brightness in [0, 1] of the texture at the hit (1 on untextured meshes and for no hit);
        None: the scene has no textures (see :mod:`sonarsim.scene.textures`).
    primitive_id : (n,) int32 ndarray or None
        Triangle hit, an index into its mesh's faces (-1 for no hit); asked for with ``with_uv``.
    barycentric : (n, 2) float32 ndarray or None
        ``(u, v)`` of the hit on that triangle, ``p = (1 - u - v) a + u b + v c`` for its corners
        ``a, b, c`` (Embree's convention; 0 for no hit); asked for with ``with_uv``.
    """

    distance: np.ndarray
    mesh_id: np.ndarray
    normal: np.ndarray
    texel: np.ndarray | None = None
    primitive_id: np.ndarray | None = None
    barycentric: np.ndarray | None = None

    @classmethod
    def misses(cls, n: int, with_uv: bool = False) -> "Hits":
        uv = dict(primitive_id=np.full(n, -1, dtype=np.int32), barycentric=np.zeros((n, 2), dtype=np.float32))
        return cls(
            distance=np.full(n, np.inf, dtype=np.float32),
            mesh_id=np.full(n, -1, dtype=np.int32),
            normal=np.zeros((n, 3), dtype=np.float32),
            **(uv if with_uv else {}),
        )
