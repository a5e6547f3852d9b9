"""sonarsim: real-time 2D forward-looking sonar simulation with multipath off floors, surfaces and walls.

The package is laid out in pipeline order: :mod:`~sonarsim.config` (sonar and scene specs, YAML
I/O, presets) -> :mod:`~sonarsim.core` (poses, ray fans, radiometry) -> :mod:`~sonarsim.scene`
(meshes in the world) -> :mod:`~sonarsim.trace` (ray casting, closest surfaces) ->
:mod:`~sonarsim.paths` (reflecting planes, image sources, the paper's Algorithm 2) ->
:mod:`~sonarsim.renderer` (the :class:`Simulator`:
components, image formation, compiled kernels) -> :mod:`~sonarsim.image` (result types, polar
grid, fan) -> :mod:`~sonarsim.io` (files, real recordings) -> :mod:`~sonarsim.analysis`
(metrics, comparison, pose fitting); beside them :mod:`~sonarsim.dataset` (scenarios, labelled
datasets, ROS 2 bags) and :mod:`~sonarsim.plot` (annotated figures, notebook displays, the
live viewer); :mod:`~sonarsim.cli` is a thin layer on top.
"""

# First: in the ``sonarsim`` command, a Ctrl-C from here on says one line (and no traceback) even
# while the modules below, and then the command's, load: before its own handler is in place.
from .core.interrupts import hold_ctrl_c_while_the_command_starts as _hold_ctrl_c

_hold_ctrl_c()

import importlib  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

__version__ = "0.1.0"

# Public names and the modules that define them. They are imported on first use (PEP 562), so
# that ``import sonarsim`` (and the ``sonarsim`` command's start) does not load the renderer,
# Embree and SciPy before it needs them: the command catches Ctrl-C from its first line, which
# a second of imports before ``main`` runs would not allow.
_EXPORTS = {
    "load_scene": ".config.loader",
    "Material": ".config.materials",
    "GroundSpec": ".config.scene", "ObjectSpec": ".config.scene", "PlaneSpec": ".config.scene",
    "RenderSettings": ".config.scene", "Scene": ".config.scene", "ground_plane": ".config.scene",
    "SonarConfig": ".config.sonar",
    "Pose": ".core.transforms",
    "ConfigError": ".errors", "MeshFileError": ".errors", "SonarsimError": ".errors",
    "RayMaps": ".image", "SonarImage": ".image",
    "open_recording": ".io.readers", "read": ".io.readers", "read_frames": ".io.readers",
    "Simulator": ".renderer.simulator", "render": ".renderer.simulator",
}

__all__ = sorted(_EXPORTS)
_SUBPACKAGES = ("analysis", "cli", "config", "core", "dataset", "diff", "errors", "image", "io", "paths", "plot",
                "renderer", "scene", "sensor", "trace")


# The image types show and save themselves (``_repr_png_``, ``plot``, ``save``, ``to_pil``,
# ``save_npz``) through hooks that sonarsim.plot registers when imported (sonarsim.image.display):
# imported here, so that every image has them. Light: matplotlib, NumPy and the writers load
# when a picture or file is first made.
from . import plot  # noqa: E402,F401


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        if name in _SUBPACKAGES:  # ``sonarsim.io.output`` after a bare ``import sonarsim``
            return importlib.import_module(f".{name}", __name__)
        raise AttributeError(f"module 'sonarsim' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # what type checkers and IDEs see
    from .config.loader import load_scene
    from .config.materials import Material
    from .config.scene import GroundSpec, ObjectSpec, PlaneSpec, RenderSettings, Scene, ground_plane
    from .config.sonar import SonarConfig
    from .core.transforms import Pose
    from .errors import ConfigError, MeshFileError, SonarsimError
    from .image import RayMaps, SonarImage
    from .io.readers import open_recording, read, read_frames
    from .renderer.simulator import Simulator, render
