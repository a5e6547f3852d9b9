"""sonarsim: real-time 2D forward-looking sonar simulation with multipath off floors, surfaces and walls.

The package is laid out in pipeline order: :mod:`~sonarsim.config` (sonar and scene specs, YAML
I/O, presets) -> :mod:`~sonarsim.core` (poses, ray fans, radiometry) -> :mod:`~sonarsim.scene`
(meshes in the world) -> :mod:`~sonarsim.trace` (ray casting, closest surfaces) ->
:mod:`~sonarsim.paths` (reflecting planes, image sources, the paper's Algorithm 2) ->
:mod:`~sonarsim.renderer` (the :class:`Simulator`:
components, image formation, compiled kernels) -> :mod:`~sonarsim.image` (result types, polar
grid, fan) -> :mod:`~sonarsim.io` (files, real recordings) -> :mod:`~sonarsim.analysis`
(metrics, comparison, pose fitting); :mod:`~sonarsim.cli` is a thin layer on top.
"""

from .config.loader import load_scene
from .config.materials import Material
from .config.scene import GroundSpec, ObjectSpec, PlaneSpec, RenderSettings, Scene
from .config.sonar import SonarConfig
from .core.transforms import Pose
from .errors import ConfigError, MeshFileError, SonarsimError
from .image import RayMaps, SonarImage
from .io.readers import read, read_frames
from .renderer.simulator import Simulator, render

__version__ = "0.1.0"

__all__ = [
    "ConfigError", "GroundSpec", "Material", "MeshFileError", "ObjectSpec", "PlaneSpec", "Pose", "RayMaps", "RenderSettings",
    "Scene", "Simulator", "SonarConfig", "SonarImage", "SonarsimError", "load_scene", "read", "read_frames",
    "render",
]
