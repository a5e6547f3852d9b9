"""Ray-casting engines behind one small interface (:class:`RayCaster`).

``embree`` (default) is Intel Embree over all cores: through our own binding to its C API
(``embree4``, :mod:`.embree4`) where that loads, else through embreex's caster (``embreex``,
:mod:`.embree`), which the environment variable ``SONARSIM_EMBREE=embreex`` also forces. Both
use the Embree library bundled with embreex. ``numpy`` is a slow pure-NumPy reference for
tests. Another engine (open3d, a GPU) registers a factory here.
"""

from __future__ import annotations

import logging
import os
from typing import Callable, Sequence

from ..errors import ConfigError, SonarsimError
from ..scene.meshes import TriangleMesh
from .base import Hits, RayCaster, available_cores

logger = logging.getLogger(__name__)
_reported: set = set()


def _make_embreex(meshes, threads):
    from .embree import EmbreeCaster

    return EmbreeCaster(meshes, threads)


def _make_embree4(meshes, threads, dynamic=False):
    from .embree4 import Embree4Caster

    return Embree4Caster(meshes, threads, dynamic=dynamic)


def _make_embree(meshes, threads, dynamic=False):
    """Our Embree 4 binding where it loads, else embreex's caster (``SONARSIM_EMBREE=embreex`` forces it)."""
    choice = os.environ.get("SONARSIM_EMBREE", "").strip().lower()
    if choice not in ("", "embree4", "embreex"):
        raise ConfigError("SONARSIM_EMBREE", f"must be 'embree4' or 'embreex', got {choice!r}")
    if choice != "embreex":
        from .embree4 import load_binding

        try:
            load_binding()
        except SonarsimError as exc:
            if choice == "embree4":
                raise
            if str(exc) not in _reported:  # once per reason, not per caster
                _reported.add(str(exc))
                logger.warning("Embree 4 binding unavailable (%s); using embreex's caster", exc)
        else:
            return _make_embree4(meshes, threads, dynamic)
    return _make_embreex(meshes, threads)


def _make_numpy(meshes, threads):
    from .numpy_ref import NumpyCaster

    return NumpyCaster(meshes, threads)


BACKENDS: dict[str, Callable[[Sequence[TriangleMesh], int | None], RayCaster]] = {
    "embree": _make_embree,
    "embree4": _make_embree4,
    "embreex": _make_embreex,
    "numpy": _make_numpy,
}


def make_caster(name: str, meshes: Sequence[TriangleMesh], threads: int | None = None,
                dynamic: bool = False) -> RayCaster:
    """Build the named engine over ``meshes`` (world frame).

    ``dynamic``: meshes will move (``replace_meshes``); the engines that can move meshes in
    place (Embree 4) build for it, the others ignore it (a simulator rebuilds them instead).
    """
    if name not in BACKENDS:
        raise ConfigError("backend", f"unknown ray-casting backend {name!r}; allowed: {', '.join(BACKENDS)}")
    if dynamic and name in DYNAMIC_BACKENDS:
        return BACKENDS[name](meshes, threads, dynamic=True)
    return BACKENDS[name](meshes, threads)


#: The engines whose factories take ``dynamic`` (meshes moved in place, each refitted).
DYNAMIC_BACKENDS = ("embree", "embree4")

__all__ = ["BACKENDS", "DYNAMIC_BACKENDS", "Hits", "RayCaster", "available_cores", "make_caster"]
