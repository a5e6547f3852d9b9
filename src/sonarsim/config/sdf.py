"""Gazebo worlds: an SDF file's models as scene-file objects.

One responsibility: read an SDF world (or model) file into the object dicts of a scene file
(``objects:`` entries), the ground its ground plane gives, and the visuals whose material fell
back to the default. The scene loader (:mod:`sonarsim.config.loader`, the ``world:`` section)
validates those dicts as it validates a scene's own objects.

What is read: ``<world>`` (or the file's top-level ``<model>``) -> ``<model>`` (nested models
too) and ``<include>`` -> ``<link>`` -> ``<visual>`` -> ``<geometry>``: ``<mesh>`` (``<uri>``,
``<scale>``), ``<box>``, ``<sphere>``, ``<cylinder>`` and ``<plane>`` (the ground). Poses
compose model -> link -> visual, each relative to its parent (SDF's default); an SDF pose is
``x y z roll pitch yaw`` in metres and radians with ``R = Rz(yaw) Ry(pitch) Rx(roll)``, the
convention of :class:`~sonarsim.core.transforms.Pose`, and Gazebo's world is z up as sonarsim's,
so coordinates are taken as they are. What cannot be read is refused by name
(:class:`~sonarsim.errors.ConfigError` naming the file and the model, link and visual).

Materials: the table :data:`GAZEBO_MATERIAL_KEYWORDS` maps words in a visual's Gazebo material
name (``Gazebo/Wood``), or else in its model's name, to sonarsim's named solids
(:data:`~sonarsim.config.materials.OBJECT_MATERIALS`); per-model overrides come first.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element

import numpy as np

from ..core.transforms import Pose
from ..errors import ConfigError, shown
from .materials import OBJECT_MATERIALS
from .parameters import MAX_COORDINATE_M
from .xmlfiles import XmlFileError, read_xml

__all__ = [
    "GAZEBO_MATERIAL_KEYWORDS", "MAX_NESTING", "MAX_SDF_BYTES", "MAX_VISUALS", "MODEL_PATH_VARIABLES",
    "READ_GEOMETRIES", "SDF_VERSIONS", "SdfWorld", "UnmappedMaterialWarning", "WorldSpec",
    "environment_model_path", "load_sdf_world", "read_sdf_world",
]

#: The largest SDF (or model.config) file read, bytes: a world of thousands of models is a few MB.
MAX_SDF_BYTES = 16 * 2**20
#: Deepest nesting of models and includes (a model in a model in an included model ...).
MAX_NESTING = 16
#: Most visuals one world gives (each becomes one object of the scene).
MAX_VISUALS = 20_000
#: SDF versions read: ``1.4`` (Gazebo classic's oldest current worlds) to ``1.12``. Older
#: versions wrote poses differently (``<origin pose=...>``, before 1.2).
SDF_VERSIONS = ((1, 4), (1, 12))
#: Geometry elements read; the others (``heightmap``, ``polyline``, ``capsule``, ``ellipsoid``,
#: ``image``) are refused by name. ``<empty/>`` gives nothing.
READ_GEOMETRIES = ("mesh", "box", "sphere", "cylinder", "plane")
#: Environment variables whose colon-separated folders are searched for ``model://NAME`` after
#: the model path given (Gazebo Harmonic's, Fortress's and Gazebo classic's, in that order).
MODEL_PATH_VARIABLES = ("GZ_SIM_RESOURCE_PATH", "IGN_GAZEBO_RESOURCE_PATH", "GAZEBO_MODEL_PATH")
#: Keywords (case-insensitive, whole or part of a word) in a Gazebo material name, else in the
#: model's name, and the named solid each gives (``material: {preset: NAME}``); first match wins.
#: Colour-only names (``Gazebo/Grey``, ``Gazebo/Red``) say nothing of the substance: they fall
#: back to the default (Lambertian, albedo 0.8) and are listed in one warning.
GAZEBO_MATERIAL_KEYWORDS: tuple[tuple[str, str], ...] = (
    ("wood", "wood"), ("pallet", "wood"), ("trunk", "wood"),
    ("brick", "concrete"), ("concrete", "concrete"), ("cement", "concrete"), ("road", "concrete"),
    ("asphalt", "concrete"), ("ceiling", "concrete"), ("cinder", "concrete"),
    ("rock", "rock"), ("stone", "rock"), ("boulder", "rock"), ("granite", "rock"),
    ("steel", "steel"), ("metal", "steel"), ("iron", "steel"), ("chrome", "steel"), ("gold", "steel"),
    ("alumin", "steel"), ("hull", "steel"), ("wreck", "steel"), ("anchor", "steel"), ("chain", "steel"),
    ("rubber", "rubber"), ("tire", "rubber"), ("tyre", "rubber"),
    ("plastic", "plastic"), ("pvc", "plastic"),
)
#: Keys of a per-model override (``world.materials.NAME``): the surface keys of an object.
OVERRIDE_KEYS = ("material", "albedo", "specular", "reflection", "normals")
#: Gazebo's own models that a world names without shipping: ``sun`` is a light (nothing for a
#: sonar), ``ground_plane`` the plane z = 0. Used only where the model path has no such folder.
BUILTIN_MODELS = ("sun", "ground_plane")

_URI_SCHEMES = ("model://", "package://")


class UnmappedMaterialWarning(UserWarning):
    """Visuals of a world whose material sonarsim does not map: they take the default."""


@dataclass(frozen=True)
class WorldSpec:
    """The ``world:`` section of a scene file, validated.

    Attributes
    ----------
    sdf : pathlib.Path
        The SDF world file.
    model_path : tuple of pathlib.Path
        Folders searched for ``model://NAME`` first (then :data:`MODEL_PATH_VARIABLES`).
    materials : mapping of str to mapping
        Per-model overrides: a model's (scoped) name, a link's ``model::link`` or a visual's
        ``model::link::visual`` -> object keys of :data:`OVERRIDE_KEYS`.
    skip : tuple of str
        Models (or includes, by name) left out.
    use_environment : bool
        Whether :data:`MODEL_PATH_VARIABLES` are searched after ``model_path``.
    """

    sdf: Path
    model_path: tuple[Path, ...] = ()
    materials: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    skip: tuple[str, ...] = ()
    use_environment: bool = True


@dataclass(frozen=True)
class SdfWorld:
    """What an SDF world gives a scene.

    Attributes
    ----------
    objects : tuple of dict
        Scene-file object dicts (``name``, ``primitive`` or ``mesh``, ``pose`` as ``position_m``
        and ``quat_xyzw``, ``scale``, surface keys), one per visual, in the file's order.
    ground : dict or None
        The ``ground:`` section its horizontal ground plane gives (``{height_m: z}``, with an
        override's surface keys), or None.
    unmapped : tuple of str
        Visuals (``model::link::visual``) whose material took the default.
    search_path : tuple of str
        The folders ``model://`` URIs were looked for in, in order.
    """

    objects: tuple[dict, ...]
    ground: dict | None
    unmapped: tuple[str, ...]
    search_path: tuple[str, ...]


def environment_model_path() -> tuple[Path, ...]:
    """The folders of :data:`MODEL_PATH_VARIABLES` (colon-separated), in order, without repeats."""
    folders: list[Path] = []
    for var in MODEL_PATH_VARIABLES:
        for part in os.environ.get(var, "").split(os.pathsep):
            if part and Path(part) not in folders:
                folders.append(Path(part))
    return tuple(folders)


# Reading ----------------------------------------------------------------------------------

class _Reader:
    """One world's reading: the search path, the include stack, what was produced."""

    def __init__(self, spec: WorldSpec) -> None:
        self.spec = spec
        paths = list(spec.model_path) + (list(environment_model_path()) if spec.use_environment else [])
        self.search = tuple(dict.fromkeys(paths))
        self.objects: list[dict] = []
        self.scopes: list[str] = []  # every model, link and visual scope seen (for the overrides' check)
        self.ground: dict | None = None
        self.ground_from = ""
        self.unmapped: list[str] = []
        self.skipped: set[str] = set()
        self.stack: list[Path] = []  # files being included, for loops

    # Errors name the file and the scope ---------------------------------------------------

    def fail(self, source: Path, scope: str, message: str) -> ConfigError:
        where = f"{scope}: " if scope else ""
        return ConfigError("", f"{source}: {where}{message}")

    # Files ----------------------------------------------------------------------------------

    def root(self, path: Path, what: str) -> Element:
        try:
            root = read_xml(path, what, MAX_SDF_BYTES)
        except XmlFileError as exc:
            raise ConfigError("", str(exc)) from None
        if root.tag != "sdf":
            raise self.fail(path, "", f"not an SDF file: the root element is <{root.tag}>, not <sdf>"
                            + (" (a URDF robot: convert it to SDF first)" if root.tag == "robot" else ""))
        version = root.get("version", "")
        m = re.fullmatch(r"\s*(\d+)\.(\d+)\s*", version)
        lo, hi = SDF_VERSIONS
        if m is None or not lo <= (int(m.group(1)), int(m.group(2))) <= hi:
            raise self.fail(path, "", f"SDF version {shown(version) if version else '(none given)'} is not read; "
                            f"allowed: {lo[0]}.{lo[1]} to {hi[0]}.{hi[1]}")
        return root

    def world(self, path: Path) -> None:
        root = self.root(path, "SDF file")
        worlds = root.findall("world")
        if len(worlds) > 1:
            raise self.fail(path, "", f"holds {len(worlds)} worlds; sonarsim reads one")
        self.stack.append(path.resolve())
        if worlds:
            world = worlds[0]
            for child in world:
                self.world_child(path, child, Pose(), "", 1)
        else:
            models = [c for c in root if c.tag in ("model", "include")]
            if not models:
                raise self.fail(path, "", "holds no <world> and no <model>")
            for child in models:
                self.world_child(path, child, Pose(), "", 1)
        self.stack.pop()

    def world_child(self, path: Path, child: Element, frame: Pose, prefix: str, depth: int) -> None:
        """A child of ``<world>`` (or of a model: ``prefix`` its scoped name, ``frame`` its pose)."""
        tag = child.tag
        if tag == "model":
            self.model(path, child, frame, prefix, depth, None, None)
        elif tag == "include":
            self.include(path, child, frame, prefix, depth)
        elif tag in ("population", "actor", "road"):
            name = child.get("name", "")
            if name and self.is_skipped(_join(prefix, name), name):
                return
            raise self.fail(path, _join(prefix, name), f"<{tag}> is not read (sonarsim reads models and includes); "
                            f"leave it out with world.skip: [{name or 'NAME'}]")

    def check_depth(self, path: Path, scope: str, depth: int) -> None:
        if depth > MAX_NESTING:
            raise self.fail(path, scope, f"models and includes nest {depth} deep; allowed: at most {MAX_NESTING}")

    def is_skipped(self, scoped: str, local: str) -> bool:
        for name in (scoped, local):
            if name in self.spec.skip:
                self.skipped.add(name)
                return True
        return False

    def model(self, path: Path, el: Element, frame: Pose, prefix: str, depth: int,
              name_override: str | None, pose_override: Pose | None) -> None:
        local = name_override or el.get("name", "")
        if not local:
            raise self.fail(path, prefix, "a <model> without a name")
        scoped = _join(prefix, local)
        self.check_depth(path, scoped, depth)
        if self.is_skipped(scoped, local):
            return
        if el.get("placement_frame"):
            raise self.fail(path, scoped, "placement_frame is not read; give the model's pose itself")
        own = pose_override if pose_override is not None else _pose_of(self, path, el, scoped, _parent_frames(prefix))
        model_pose = frame.compose(own)
        self.scopes.append(scoped)
        for child in el:
            if child.tag == "link":
                self.link(path, child, model_pose, scoped, local)
            elif child.tag in ("model", "include", "population", "actor", "road"):
                self.world_child(path, child, model_pose, scoped, depth + 1)

    def link(self, path: Path, el: Element, model_pose: Pose, model_scope: str, model_local: str) -> None:
        name = el.get("name", "")
        scope = _join(model_scope, name)
        link_pose = model_pose.compose(_pose_of(self, path, el, scope, ("", "__model__", model_local)))
        self.scopes.append(scope)
        for visual in el.findall("visual"):
            vname = visual.get("name", "")
            vscope = _join(scope, vname)
            self.scopes.append(vscope)
            pose = link_pose.compose(_pose_of(self, path, visual, vscope, ("", name)))
            self.visual(path, visual, pose, vscope, model_scope)

    def visual(self, path: Path, el: Element, pose: Pose, scope: str, model_scope: str) -> None:
        geometry = el.find("geometry")
        if geometry is None:
            raise self.fail(path, scope, "a <visual> without <geometry>")
        shapes = [g for g in geometry if isinstance(g.tag, str)]
        if len(shapes) != 1:
            raise self.fail(path, scope, f"<geometry> must hold one shape, got {len(shapes)}")
        shape = shapes[0]
        kind = shape.tag
        obj: dict[str, Any] = {"_scope": scope, "_model": model_scope}
        if kind == "empty":
            return
        if kind == "plane":
            self.plane(path, shape, pose, scope)
            return
        if kind not in READ_GEOMETRIES:
            raise self.fail(path, scope, f"geometry <{kind}> is not read; read: {', '.join(READ_GEOMETRIES)} "
                            "(convert it to a mesh, or leave the model out with world.skip)")
        if kind == "box":
            obj["primitive"] = "box"
            obj["size_m"] = list(_numbers(self, path, shape, "size", scope, 3))
        elif kind == "sphere":
            obj["primitive"] = "sphere"
            obj["radius_m"] = _numbers(self, path, shape, "radius", scope, 1)[0]
        elif kind == "cylinder":  # SDF's cylinder stands on its z axis, centred: as sonarsim's
            obj["primitive"] = "cylinder"
            obj["radius_m"] = _numbers(self, path, shape, "radius", scope, 1)[0]
            obj["height_m"] = _numbers(self, path, shape, "length", scope, 1)[0]
        else:
            if shape.find("submesh") is not None:
                raise self.fail(path, scope, "<mesh><submesh> is not read (sonarsim reads the whole mesh file); "
                                "export the submesh to its own file")
            uri = shape.findtext("uri", "").strip()
            if not uri:
                raise self.fail(path, scope, "<mesh> without a <uri>")
            obj["mesh"] = str(self.resolve(path, uri, scope, "mesh"))
            if shape.find("scale") is not None:
                scale = _numbers(self, path, shape, "scale", scope, 3)
                if not all(s > 0 for s in scale):
                    raise self.fail(path, scope, f"<mesh><scale> must be positive, got {list(scale)} (a mirrored "
                                    "mesh is not read)")
                obj["scale"] = list(scale)
        obj["pose"] = _pose_dict(pose)
        material = el.find("material")
        obj["_gazebo_material"] = (material.findtext("script/name", "") or "").strip() if material is not None else ""
        if len(self.objects) >= MAX_VISUALS:
            raise self.fail(path, scope, f"the world has more than {MAX_VISUALS} visuals; allowed: at most {MAX_VISUALS}")
        self.objects.append(obj)

    def plane(self, path: Path, shape: Element, pose: Pose, scope: str) -> None:
        normal = _numbers(self, path, shape, "normal", scope, 3) if shape.find("normal") is not None else (0.0, 0.0, 1.0)
        n = np.asarray(normal, float)
        if not np.linalg.norm(n) > 0:
            raise self.fail(path, scope, "<plane><normal> must not be zero")
        n = pose.rotation @ (n / np.linalg.norm(n))
        if not np.allclose(n, [0.0, 0.0, 1.0], atol=1e-6):
            raise self.fail(path, scope, f"a <plane> facing {[round(float(v), 6) for v in n]} is not read: sonarsim "
                            "reads a world's plane as the ground (horizontal, facing +z); give walls as planes: in "
                            "the scene and leave this model out with world.skip")
        self.set_ground(path, scope, float(pose.translation[2]))

    def set_ground(self, path: Path, scope: str, height: float) -> None:
        if self.ground is not None and not math.isclose(self.ground["height_m"], height, abs_tol=1e-9):
            raise self.fail(path, scope, f"a second ground plane at z = {height:g} m (the first, {self.ground_from}, "
                            f"at {self.ground['height_m']:g} m); a scene has one ground: leave one out with world.skip")
        if self.ground is None:
            self.ground, self.ground_from = {"height_m": height, "_scope": scope}, scope

    def include(self, path: Path, el: Element, frame: Pose, prefix: str, depth: int) -> None:
        uri = el.findtext("uri", "").strip()
        if not uri:
            raise self.fail(path, prefix, "an <include> without a <uri>")
        default_name = uri.rstrip("/").rsplit("/", 1)[-1]
        local = (el.findtext("name") or "").strip() or None
        scoped = _join(prefix, local or default_name)
        self.check_depth(path, scoped, depth)
        if self.is_skipped(scoped, local or default_name):
            return
        if (el.findtext("placement_frame") or "").strip():
            raise self.fail(path, scoped, "<include><placement_frame> is not read; give the pose of the model itself")
        # The include's pose replaces the included model's own (SDF's rule), in the parent's frame.
        pose = None
        if el.find("pose") is not None:
            pose = _pose_of(self, path, el, scoped, _parent_frames(prefix))
        try:
            folder_or_file = self.resolve(path, uri, scoped, "model")
        except ConfigError:
            name = uri[len("model://"):].strip("/") if uri.startswith("model://") else None
            if name in BUILTIN_MODELS:
                self.builtin(path, name, frame.compose(pose or Pose()), scoped)
                return
            raise
        model_file = self.model_file(folder_or_file, scoped, path)
        if model_file.resolve() in self.stack:
            chain = " -> ".join(str(p) for p in [*self.stack, model_file.resolve()])
            raise self.fail(path, scoped, f"the include loops: {chain}")
        root = self.root(model_file, "SDF model file")
        models = root.findall("model")
        if len(models) != 1:
            raise self.fail(model_file, "", f"an included file must hold one <model>, got {len(models)}")
        self.stack.append(model_file.resolve())
        self.model(model_file, models[0], frame, prefix, depth, local or models[0].get("name") or default_name, pose)
        self.stack.pop()

    def builtin(self, path: Path, name: str, pose: Pose, scope: str) -> None:
        """Gazebo's own ``sun`` (a light: nothing) or ``ground_plane`` (the plane z = 0 of its frame)."""
        if name == "ground_plane":
            n = pose.rotation @ np.array([0.0, 0.0, 1.0])
            if not np.allclose(n, [0.0, 0.0, 1.0], atol=1e-6):
                raise self.fail(path, scope, f"Gazebo's ground_plane turned to face {list(np.round(n, 6))} is not read")
            self.set_ground(path, scope, float(pose.translation[2]))
            self.scopes.append(scope)

    def model_file(self, target: Path, scope: str, source: Path) -> Path:
        """The SDF file of a model folder: the one its model.config names (the highest version
        read), else model.sdf; a file is itself."""
        if target.is_file():
            return target
        config = target / "model.config"
        if config.exists():
            try:
                root = read_xml(config, "model.config", MAX_SDF_BYTES)
            except XmlFileError as exc:
                raise ConfigError("", str(exc)) from None
            best: tuple[tuple[int, int], str] | None = None
            for entry in root.findall("sdf"):
                m = re.fullmatch(r"\s*(\d+)\.(\d+)\s*", entry.get("version", "") or "0.0")
                version = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
                text = (entry.text or "").strip()
                if text and SDF_VERSIONS[0] <= version <= SDF_VERSIONS[1] or (text and not entry.get("version")):
                    if best is None or version > best[0]:
                        best = (version, text)
            if best is not None:
                candidate = (target / best[1]).resolve()
                if target.resolve() not in candidate.parents:
                    raise self.fail(source, scope, f"{config}: names {shown(best[1])}, outside the model's folder")
                return candidate
        if (target / "model.sdf").exists():
            return target / "model.sdf"
        raise self.fail(source, scope, f"{target}: a model folder without model.sdf (nor a model.config naming an "
                        f"SDF file of version {SDF_VERSIONS[0][0]}.{SDF_VERSIONS[0][1]} to "
                        f"{SDF_VERSIONS[1][0]}.{SDF_VERSIONS[1][1]})")

    def resolve(self, source: Path, uri: str, scope: str, what: str) -> Path:
        """The file or folder a URI names: ``model://NAME/...`` (or ``package://``) on the model
        path; ``file://`` and plain paths against the SDF file's folder."""
        for scheme in _URI_SCHEMES:
            if uri.startswith(scheme):
                rest = uri[len(scheme):].strip("/")
                if not rest or ".." in Path(rest).parts:
                    raise self.fail(source, scope, f"{what} URI {shown(uri)} names no model folder")
                for folder in self.search:
                    candidate = folder / rest
                    if candidate.exists():
                        return Path(os.path.abspath(candidate))
                searched = ", ".join(str(f) for f in self.search) or "none (give world.model_path or set " \
                    f"{MODEL_PATH_VARIABLES[0]})"
                raise self.fail(source, scope, f"{what} {shown(uri)} not found on the model path; folders "
                                f"searched: {searched}")
        if "://" in uri and not uri.startswith("file://"):
            raise self.fail(source, scope, f"{what} URI {shown(uri)}: only model://, package://, file:// and paths "
                            "are read (sonarsim fetches nothing: download the model and put its folder on the "
                            "model path)")
        rest = uri[len("file://"):] if uri.startswith("file://") else uri
        p = Path(rest)
        if not p.is_absolute():
            p = Path(os.path.abspath(source.parent / p))
        if not p.exists():
            raise self.fail(source, scope, f"{what} {shown(uri)} not found ({p})")
        return p


def _parent_frames(prefix: str) -> tuple[str, ...]:
    """The ``relative_to`` values that name a model's parent frame: the world's, or the enclosing model's."""
    return ("", "world") if not prefix else ("", "__model__", prefix.rsplit("::", 1)[-1])


def _join(prefix: str, name: str) -> str:
    return f"{prefix}::{name}" if prefix else name


def _numbers(reader: _Reader, path: Path, parent: Element, tag: str, scope: str, n: int) -> tuple[float, ...]:
    text = parent.findtext(tag)
    if text is None:
        raise reader.fail(path, scope, f"<{parent.tag}> needs <{tag}> ({n} number{'s' if n > 1 else ''})")
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        values = ()
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise reader.fail(path, scope, f"<{parent.tag}><{tag}> must be {n} finite number{'s' if n > 1 else ''}, "
                          f"got {shown(text.strip())}")
    return values


def _pose_of(reader: _Reader, path: Path, el: Element, scope: str, parents: tuple[str, ...]) -> Pose:
    """An element's ``<pose>``, relative to its parent (``relative_to`` empty or one of ``parents``)."""
    p = el.find("pose")
    if p is None:
        return Pose()
    relative = (p.get("relative_to") or "").strip()
    if relative not in parents:
        allowed = ", ".join(repr(x) for x in parents if x) or "none"
        raise reader.fail(path, scope, f"<pose relative_to={shown(relative)}> is not read: sonarsim composes poses "
                          f"relative to the parent element (relative_to empty or {allowed})")
    fmt = (p.get("rotation_format") or "euler_rpy").strip()
    degrees = (p.get("degrees") or "false").strip().lower()
    if fmt not in ("euler_rpy", "quat_xyzw") or degrees not in ("true", "false", "1", "0"):
        raise reader.fail(path, scope, f"<pose rotation_format={shown(fmt)} degrees={shown(degrees)}> is not read; "
                          "allowed: rotation_format euler_rpy or quat_xyzw, degrees true or false")
    text = (p.text or "").split()
    n = 7 if fmt == "quat_xyzw" else 6
    try:
        values = [float(v) for v in text] if text else [0.0] * n
    except ValueError:
        values = []
    if len(values) != n or not all(math.isfinite(v) for v in values):
        what = "x y z qx qy qz qw" if n == 7 else "x y z roll pitch yaw (metres, radians)"
        raise reader.fail(path, scope, f"<pose> must be {n} finite numbers, {what}; got {shown(p.text or '')}")
    if max(abs(v) for v in values[:3]) > MAX_COORDINATE_M:
        raise reader.fail(path, scope, f"<pose> position {values[:3]} lies beyond {MAX_COORDINATE_M:g} m")
    if n == 7:
        if math.hypot(*values[3:]) < 1e-9:
            raise reader.fail(path, scope, "<pose> quaternion must not be zero")
        return Pose.from_quaternion(values[:3], values[3:])
    angles = values[3:] if degrees in ("true", "1") else [math.degrees(v) for v in values[3:]]
    if max(abs(a) for a in angles) > 720.0:
        raise reader.fail(path, scope, f"<pose> angles {values[3:]} are beyond two turns")
    return Pose(values[:3], angles)


def _pose_dict(pose: Pose) -> dict:
    # The quaternion, not roll-pitch-yaw: a composed rotation has it exactly (no gimbal lock).
    return {"position_m": [float(v) for v in pose.position_m], "quat_xyzw": [float(v) for v in pose.quat_xyzw]}


def _keyword_material(text: str) -> str | None:
    low = text.lower()
    for word, name in GAZEBO_MATERIAL_KEYWORDS:
        if word in low:
            return name
    return None


def _override_for(scope: str, materials: Mapping[str, Any]) -> str | None:
    """The key of the most specific override of a visual: itself, its link, then each enclosing
    model, innermost first; None without one."""
    parts = scope.split("::")
    for k in range(len(parts), 0, -1):
        name = "::".join(parts[:k])
        if name in materials:
            return name
    return None


def _surface_keys(override: Mapping[str, Any], where: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in override.items():
        if key not in OVERRIDE_KEYS:
            raise ConfigError(f"{where}.{key}", f"unknown key; allowed: {', '.join(OVERRIDE_KEYS)}")
        if key == "material" and isinstance(value, str):  # shorthand: a named solid
            if value not in OBJECT_MATERIALS:
                raise ConfigError(f"{where}.material", f"unknown material {shown(value)}; allowed: "
                                  f"{', '.join(OBJECT_MATERIALS)} (or a material mapping)")
            value = {"preset": value}
        out[key] = value
    return out


def read_sdf_world(spec: WorldSpec) -> SdfWorld:
    """Read an SDF world into scene-file objects, the ground, and the visuals left unmapped.

    Parameters
    ----------
    spec : WorldSpec
        The file, model path, per-model overrides and models to skip.

    Returns
    -------
    SdfWorld

    Raises
    ------
    ConfigError
        The file is missing, too large (:data:`MAX_SDF_BYTES`), not SDF, of a version outside
        :data:`SDF_VERSIONS`, or holds what sonarsim does not read (a geometry outside
        :data:`READ_GEOMETRIES`, a pose relative to another frame, a malformed pose, an include
        not found on the model path, an include loop, nesting deeper than :data:`MAX_NESTING`);
        an override or skip names nothing in the world. The message names the file and the
        ``model::link::visual``.

    Warns
    -----
    UnmappedMaterialWarning
        Once, listing the visuals whose material took the default.
    """
    reader = _Reader(spec)
    reader.world(Path(spec.sdf))
    unknown = [s for s in spec.skip if s not in reader.skipped]
    if unknown:
        raise ConfigError("world.skip", f"{spec.sdf}: no model named {', '.join(map(repr, unknown))} in the world")
    known = set(reader.scopes)
    for name in spec.materials:
        if name not in known:
            raise ConfigError(f"world.materials.{name}", f"{spec.sdf}: no model, link or visual of that name; names "
                              f"are model, model::link, model::link::visual (e.g. "
                              f"{', '.join(list(dict.fromkeys(reader.scopes))[:4]) or 'none'})")
    # Names: the model's when it has one visual, else the visual's scoped name.
    per_model: dict[str, int] = {}
    for obj in reader.objects:
        per_model[obj["_model"]] = per_model.get(obj["_model"], 0) + 1
    objects: list[dict] = []
    seen: dict[str, str] = {}
    for obj in reader.objects:
        scope, model = obj.pop("_scope"), obj.pop("_model")
        gazebo = obj.pop("_gazebo_material")
        name = model if per_model[model] == 1 else scope
        if name in seen:
            raise ConfigError("", f"{spec.sdf}: two visuals are named {shown(name)}; SDF names must be unique "
                              "among siblings")
        seen[name] = scope
        override = _override_for(scope, spec.materials)
        surface: dict[str, Any] = {}
        if override is not None:
            surface = _surface_keys(spec.materials[override], f"world.materials.{override}")
        if "material" not in surface and "albedo" not in surface:
            preset = _keyword_material(gazebo) or _keyword_material(model)
            if preset is not None:
                surface["material"] = {"preset": preset}
            else:
                reader.unmapped.append(scope)
        objects.append({"name": name, **obj, **surface})
    ground = None
    if reader.ground is not None:
        ground = {"height_m": reader.ground["height_m"]}
        scope = reader.ground["_scope"]
        override = _override_for(scope, spec.materials)
        if override is not None:
            surface = _surface_keys(spec.materials[override], f"world.materials.{override}")
            surface.pop("normals", None)
            ground.update(surface)
    if reader.unmapped:
        shown_names = ", ".join(reader.unmapped[:6]) + (f" and {len(reader.unmapped) - 6} more"
                                                         if len(reader.unmapped) > 6 else "")
        warnings.warn(f"{spec.sdf}: {len(reader.unmapped)} visual(s) with no material sonarsim maps ({shown_names}) "
                      "take the default (lambertian, albedo 0.8); map them with world.materials",
                      UnmappedMaterialWarning, stacklevel=2)
    return SdfWorld(tuple(objects), ground, tuple(reader.unmapped), tuple(str(p) for p in reader.search))


def load_sdf_world(path: str | os.PathLike, model_path: Sequence[str | os.PathLike] = (),
                   materials: Mapping[str, Mapping[str, Any]] | None = None, skip: Sequence[str] = (),
                   use_environment: bool = True) -> list[dict]:
    """The scene-file objects of an SDF world's visuals (see :func:`read_sdf_world`).

    Parameters
    ----------
    path : path-like
        The SDF world (or model) file.
    model_path : sequence of path-like
        Folders searched for ``model://NAME`` before :data:`MODEL_PATH_VARIABLES`.
    materials : mapping, optional
        Per-model overrides (:attr:`WorldSpec.materials`).
    skip : sequence of str
        Models left out.
    use_environment : bool
        Search :data:`MODEL_PATH_VARIABLES` too.

    Returns
    -------
    list of dict
        One ``objects:`` entry per visual (poses in metres, ``quat_xyzw``), ready for
        :func:`~sonarsim.config.loader.scene_from_dict`. The world's ground plane is
        :attr:`SdfWorld.ground` of :func:`read_sdf_world`.

    Examples
    --------
    >>> objects = load_sdf_world("tank.world", model_path=["models"])  # doctest: +SKIP
    >>> scene = scene_from_dict({"sonar": {...}, "objects": objects})  # doctest: +SKIP
    """
    spec = WorldSpec(Path(path), tuple(Path(p) for p in model_path), dict(materials or {}), tuple(skip),
                     use_environment)
    return list(read_sdf_world(spec).objects)
