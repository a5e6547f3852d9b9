"""sonarsim: real-time 2D forward-looking sonar simulation with flat-ground multipath.

The pipeline, one module each: :mod:`~sonarsim.config.sonar` (beams, range window, pose) ->
:mod:`~sonarsim.config.scene` / :mod:`~sonarsim.config.loader` (objects, ground, settings) ->
:mod:`~sonarsim.core.rays` (ray fan) -> :mod:`~sonarsim.trace` + :mod:`~sonarsim.trace.surfaces`
(closest surfaces) -> :mod:`~sonarsim.render.formation` (Algorithm 1) -> :mod:`~sonarsim.image.fan` and
:mod:`~sonarsim.io.output` (images, files) -> :mod:`~sonarsim.io.readers`, :mod:`~sonarsim.analysis.metrics` and
:mod:`~sonarsim.analysis.fitting` (real recordings, comparison, pose fitting). :class:`Simulator` ties
the simulation together.
"""

from .errors import ConfigError, MeshFileError, SonarsimError
from .config.loader import load_scene
from .io.readers import read, read_frames
from .config.scene import GroundSpec, ObjectSpec, RenderSettings, Scene
from .image import RayMaps, SonarImage
from .render.simulator import Simulator, render
from .config.sonar import SonarConfig
from .core.transforms import Pose

__version__ = "0.1.0"

__all__ = [
    "ConfigError", "GroundSpec", "MeshFileError", "ObjectSpec", "Pose", "RayMaps", "RenderSettings",
    "Scene", "Simulator", "SonarConfig", "SonarImage", "SonarsimError", "load_scene", "read", "read_frames",
    "render",
]
