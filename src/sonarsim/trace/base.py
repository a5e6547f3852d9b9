"""The ray-casting interface: the only thing an engine (Embree, NumPy, a GPU) must provide.

A caster is built once from the scene's triangle meshes (in world coordinates) and answers
closest-hit queries for batches of rays. It returns plain arrays; the physics lives elsewhere.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

from ..scene.meshes import TriangleMesh


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


class RayCaster(Protocol):
    """What a ray-casting engine implements."""

    name: str

    def __init__(self, meshes: Sequence[TriangleMesh], threads: int | None = None) -> None: ...

    def intersect(self, origins: np.ndarray, directions: np.ndarray, max_distance: float,
                  threads: int | None = None, with_uv: bool = False) -> Hits:
        """Closest hits.

        Parameters
        ----------
        origins : (n, 3) float array, metres
        directions : (n, 3) float array, unit vectors
        max_distance : float, metres
            Hits further than this are reported as misses.
        threads : int, optional
            Use at most this many threads (default: the caster's own count), e.g. 1 when the
            other core has work of its own.
        with_uv : bool
            Also report the triangle hit and the barycentric coordinates of the hit
            (``Hits.primitive_id``, ``Hits.barycentric``: what a texture lookup needs).
        """
        ...


def nonempty_meshes(meshes: Sequence[TriangleMesh]) -> tuple[np.ndarray, list[TriangleMesh]]:
    """The meshes with triangles, and the index of each in ``meshes``.

    Embree numbers the geometries it is given and takes no empty one: a hit's geometry id ``g``
    is mesh ``ids[g]`` of the caller's sequence.

    Returns
    -------
    ids : (k,) int32 ndarray
    kept : list of TriangleMesh
    """
    ids = np.array([i for i, m in enumerate(meshes) if len(m.faces)], dtype=np.int32)
    return ids, [meshes[i] for i in ids]


def available_cores() -> int:
    """CPU cores this process may run on (respects affinity masks, e.g. in containers)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
