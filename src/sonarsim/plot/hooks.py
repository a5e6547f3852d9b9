"""Registers the pictures (and the NPZ writer) of the image types into :mod:`sonarsim.image.display`.

:class:`~sonarsim.image.result.SonarImage` and :class:`~sonarsim.image.fan.FanImage` do not import
this package (it sits above them); their ``_repr_png_``, ``plot``, ``save``, ``to_pil`` and
``save_npz`` call the hooks installed here. This module is imported by :mod:`sonarsim.plot`
(and so by ``import sonarsim``) and must stay light: each hook imports what does the work
(:mod:`sonarsim.plot.notebook`, matplotlib, :mod:`sonarsim.io.output`) on its first call, so that
``import sonarsim`` and the command's start load none of them.

The NPZ writer belongs to :mod:`sonarsim.io`, which registers it too when
:mod:`sonarsim.io.output` is imported; it is registered here as well (plot sits above io) so that
``import sonarsim`` gives ``save_npz`` without loading the writers.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from ..image.display import register

__all__: list[str] = []


def _deferred(module: str, name: str) -> Callable[..., Any]:
    """A hook that imports ``module`` (relative to this package: ``.notebook`` loads
    matplotlib) on its first call and calls its ``name``."""

    def hook(*args: Any, **options: Any) -> Any:
        return getattr(importlib.import_module(module, __package__), name)(*args, **options)

    hook.__name__ = hook.__qualname__ = name
    return hook


#: Hook name (``sonarsim.image.display``) -> (module, function) that does the work.
HOOKS = {
    "image_repr_png": (".notebook", "image_repr_png"),
    "image_plot": (".notebook", "image_plot"),
    "image_save": (".notebook", "image_save"),
    "image_to_pil": (".notebook", "image_to_pil"),
    "fan_repr_png": (".notebook", "fan_image_repr_png"),
    "fan_plot": (".notebook", "fan_image_plot"),
    "fan_save": (".notebook", "fan_image_save"),
    # Belongs to io (which registers it too when io.output is imported); here as well so that
    # ``import sonarsim`` gives ``save_npz`` without loading the writers.
    "write_npz": ("..io.output", "write_npz"),
}


def register_all() -> None:
    """Install every hook (done on import; again after a test replaced one)."""
    for hook, (module, name) in HOOKS.items():
        register(hook, _deferred(module, name))


register_all()
