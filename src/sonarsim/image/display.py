"""How the image types show and save themselves, without importing what draws or writes them.

:class:`~sonarsim.image.result.SonarImage` and :class:`~sonarsim.image.fan.FanImage` sit below
:mod:`sonarsim.plot` (figures, matplotlib) and :mod:`sonarsim.io` (files) and import neither.
Their picture and file methods (``_repr_png_``, ``plot``, ``save``, ``to_pil``, ``save_npz``)
call the functions registered here under the names of :data:`HOOKS`. The layers above register
them when they are imported: :mod:`sonarsim.plot` (through its light :mod:`sonarsim.plot.hooks`,
which loads matplotlib only when a picture is made) registers the pictures and the NPZ writer,
:mod:`sonarsim.io.output` its NPZ writer too; ``import sonarsim`` imports :mod:`sonarsim.plot`,
so that every image has them. A method whose hook is missing raises :class:`MissingHookError`,
naming the module that provides it.

The short text ``repr`` of the image types needs nothing above this layer: it is here
(:func:`image_repr`, :func:`fan_image_repr`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

__all__ = ["HOOKS", "MissingHookError", "fan_image_repr", "hook", "image_repr", "register", "registered"]

#: The hooks the image types call, and the module that registers each (what they do:
#: ``image_*`` take a :class:`~sonarsim.image.result.SonarImage` first, ``fan_*`` a
#: :class:`~sonarsim.image.fan.FanImage`).
HOOKS: dict[str, str] = {
    # (image) -> PNG bytes of the small annotated fan a notebook shows
    "image_repr_png": "sonarsim.plot.notebook",
    # (image, ax, kind, component, **options) -> matplotlib Axes
    "image_plot": "sonarsim.plot.notebook",
    # (image, path, kind, component, **options) -> None: the annotated figure, PNG/SVG/PDF
    "image_save": "sonarsim.plot.notebook",
    # (image, kind, component, **options) -> PIL image: the exact-pixel 8-bit grey image
    "image_to_pil": "sonarsim.plot.notebook",
    # (fan) -> PNG bytes
    "fan_repr_png": "sonarsim.plot.notebook",
    # (fan, ax, **options) -> matplotlib Axes
    "fan_plot": "sonarsim.plot.notebook",
    # (fan, path, **options) -> None
    "fan_save": "sonarsim.plot.notebook",
    # (path, arrays, config) -> None: an NPZ file of named arrays and the configuration, atomically
    "write_npz": "sonarsim.io.output",
}

_registered: dict[str, Callable[..., Any]] = {}


class MissingHookError(RuntimeError):
    """A picture or file method was called before the module that provides it registered it."""


def register(name: str, function: Callable[..., Any]) -> None:
    """Install ``function`` as the hook ``name`` (one of :data:`HOOKS`), replacing any before.

    Raises
    ------
    KeyError
        An unknown name.
    """
    if name not in HOOKS:
        raise KeyError(f"no image hook {name!r}; the hooks are {', '.join(sorted(HOOKS))}")
    if not callable(function):
        raise TypeError(f"hook {name!r} must be callable, got {type(function).__name__}")
    _registered[name] = function


def registered() -> dict[str, Callable[..., Any]]:
    """The hooks installed now, by name (a copy)."""
    return dict(_registered)


def hook(name: str, method: str) -> Callable[..., Any]:
    """The function registered as ``name``, for the method ``method`` (named in the error).

    Raises
    ------
    MissingHookError
        None is registered: the message names the module that provides it.
    """
    try:
        return _registered[name]
    except KeyError:
        provider = HOOKS[name]
        raise MissingHookError(
            f"{method} needs {provider}, which registers it (sonarsim.image.display hook {name!r}) "
            f"when imported: import {provider} (import sonarsim does it)"
        ) from None


# ---------------------------------------------------------------------------------- text reprs

def image_repr(image: Any) -> str:
    """One or two lines about a :class:`~sonarsim.image.result.SonarImage`: device, shape,
    range window and beams, components, pose; never the arrays."""
    import numpy as np  # not at the top: this module is imported by ``import sonarsim``

    s = image.sonar
    config = getattr(image, "config", None) or {}
    if "format" in config:
        device = f"{config['format']} recording {os.path.basename(str(config.get('source', '')))} frame {config.get('frame')}"
    else:
        device = s.preset or "sonar"
    rows, cols = np.shape(image.polar)
    edges = s.beam_edges_deg
    first = (f"SonarImage({device}: {rows} ranges x {cols} beams, {s.range_min_m:.4g}-{s.range_max_m:.4g} m, "
             f"{float(edges[0]):+.4g} to {float(edges[-1]):+.4g} deg")
    comp = image.components
    # The table's names cost nothing; listing path signatures would form them all.
    table = getattr(comp, "table", None)
    names = list(table) if table is not None else list(comp)
    parts = []
    if names:
        parts.append("components " + ", ".join(names) + (" (+ path signatures)" if table is not None else ""))
    if isinstance(config.get("sensor"), dict):
        parts.append("sensor model on")
    if image.pose is not None:
        parts.append(f"pose {tuple(image.pose.position_m)} m rpy {tuple(image.pose.rpy_deg)} deg")
    if image.labels is not None:
        parts.append("labels")
    return first + (";\n  " + "; ".join(parts) + ")" if parts else ")")


def fan_image_repr(fan: Any) -> str:
    """One line about a FanImage: shape, pixel size, extent, pixels inside the fan."""
    import numpy as np

    h, w = fan.shape
    return (f"FanImage({w} x {h} pixels of {fan.pixel_size_m * 1000:.4g} mm, forward to "
            f"{float(fan.x_m[0]) + fan.pixel_size_m / 2:.4g} m, {int(np.count_nonzero(fan.mask))} pixels inside the fan)")
