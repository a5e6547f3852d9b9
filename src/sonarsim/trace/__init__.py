"""Ray-casting engines behind one small interface (:class:`RayCaster`).

``embree`` (default) is Intel Embree through embreex over all cores; ``numpy`` is a slow
pure-NumPy reference for tests. Another engine (open3d, a GPU) registers a factory here.
"""

from __future__ import annotations

from typing import Callable, Sequence

from ..errors import ConfigError
from ..scene.meshes import TriangleMesh
from .base import Hits, RayCaster, available_cores


def _embree(meshes, threads):
    from .embree import EmbreeCaster

    return EmbreeCaster(meshes, threads)


def _numpy(meshes, threads):
    from .numpy_ref import NumpyCaster

    return NumpyCaster(meshes, threads)


BACKENDS: dict[str, Callable[[Sequence[TriangleMesh], int | None], RayCaster]] = {
    "embree": _embree,
    "numpy": _numpy,
}


def make_caster(name: str, meshes: Sequence[TriangleMesh], threads: int | None = None) -> RayCaster:
    """Build the named engine over ``meshes`` (world frame)."""
    if name not in BACKENDS:
        raise ConfigError("backend", f"unknown ray-casting backend {name!r}; allowed: {', '.join(BACKENDS)}")
    return BACKENDS[name](meshes, threads)


__all__ = ["BACKENDS", "Hits", "RayCaster", "available_cores", "make_caster"]
