"""Differentiable rendering: the expected image as a JAX function of poses, geometry, materials
and the sensor (``pip install 'sonarsim[diff]'``).

>>> import sonarsim.diff, jax                                      # doctest: +SKIP
>>> r = sonarsim.diff.Renderer("tank.yaml")
>>> params = r.params()        # flat dict of JAX arrays: "sonar.position_m", "objects.buoy.albedo", ...
>>> image = r.render(params)   # (n_range_bins, n_beams)
>>> g = jax.grad(lambda p: ((r.render(p) - target) ** 2).sum())(params)

The compiled engine finds which surfaces each path meets (the discrete search, held fixed);
everything continuous after it is formed again in JAX (:mod:`sonarsim.diff.forward`). The
parameters are listed in :mod:`sonarsim.diff.params`.
"""

from __future__ import annotations

import importlib
from typing import Any

from ..core.extras import install_command

DIFF_EXTRA_MESSAGE = f"the differentiable engine needs JAX: {install_command('diff')}"

_EXPORTS = {"Renderer": ".renderer", "Search": ".search", "record_search": ".search",
            "StaleSearchWarning": ".renderer"}
__all__ = sorted(_EXPORTS)


class MissingExtraError(ImportError):
    """An optional part of sonarsim is used without its extra installed."""


def require_jax() -> None:
    """Raise :class:`MissingExtraError` naming the extra when JAX cannot be imported."""
    try:
        importlib.import_module("jax")
    except ImportError:
        raise MissingExtraError(DIFF_EXTRA_MESSAGE) from None


def enable_compilation_cache(path: str | None = None) -> str:
    """Keep JAX's compiled functions on disk (``SONARSIM_JAX_CACHE``, default
    ``~/.cache/sonarsim/jax``): a fit or calibration in a new process then loads them instead
    of compiling them again (seconds each). Returns the folder."""
    import os
    from pathlib import Path

    require_jax()
    import jax

    folder = path or os.environ.get("SONARSIM_JAX_CACHE") or str(Path.home() / ".cache" / "sonarsim" / "jax")
    Path(folder).mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return folder


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sonarsim.diff' has no attribute {name!r}")
    require_jax()
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value
