"""Sonar images and their geometry, below the renderer and the readers that make them.

:mod:`~sonarsim.image.grid` (:class:`PolarGrid`: range bins and beams),
:mod:`~sonarsim.image.result` (:class:`SonarImage`, :class:`RayMaps`),
:mod:`~sonarsim.image.fan` (scan conversion to the Cartesian fan, :class:`FanImage`),
:mod:`~sonarsim.image.levels` (intensities to 8-bit display levels) and
:mod:`~sonarsim.image.display` (the hooks through which the image types show and save
themselves: :mod:`sonarsim.plot` and :mod:`sonarsim.io` sit above this package and register them).

This package imports nothing of :mod:`sonarsim.plot`, :mod:`sonarsim.io`,
:mod:`sonarsim.renderer` or :mod:`sonarsim.analysis`. Its names are imported on first use
(PEP 562): ``import sonarsim`` loads :mod:`~sonarsim.image.display` (through
:mod:`sonarsim.plot`) and must not load NumPy with it.
"""

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {"FanImage": ".fan", "PolarGrid": ".grid", "RayMaps": ".result", "SonarImage": ".result"}

__all__ = ["FanImage", "PolarGrid", "RayMaps", "SonarImage"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sonarsim.image' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # what type checkers and IDEs see
    from .fan import FanImage
    from .grid import PolarGrid
    from .result import RayMaps, SonarImage
