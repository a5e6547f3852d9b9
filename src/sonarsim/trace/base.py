"""The ray-casting interface: the only thing an engine (Embree, NumPy, a GPU) must provide.

A caster is built once from the scene's triangle meshes (in world coordinates) and answers
closest-hit queries for batches of rays. It returns plain arrays; the physics lives elsewhere.
"""

from __future__ import annotations

import os
from typing import Protocol, Sequence

import numpy as np

from ..core.hits import Hits  # the engines' answer, a plain data type (re-exported here)
from ..scene.meshes import TriangleMesh


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
