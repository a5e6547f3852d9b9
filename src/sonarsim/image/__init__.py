"""Sonar images and their geometry, below the renderer and the readers that make them.

:mod:`~sonarsim.image.grid` (:class:`PolarGrid`: range bins and beams),
:mod:`~sonarsim.image.result` (:class:`SonarImage`, :class:`RayMaps`) and
:mod:`~sonarsim.image.fan` (scan conversion to the Cartesian fan, :class:`FanImage`).
"""

from .fan import FanImage
from .grid import PolarGrid
from .result import RayMaps, SonarImage

__all__ = ["FanImage", "PolarGrid", "RayMaps", "SonarImage"]
