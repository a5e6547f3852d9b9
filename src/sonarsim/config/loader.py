"""Read scenes from YAML/JSON files or dicts, rejecting unknown keys, wrong types and bad values.

This is the edge of the library: everything after it trusts the frozen dataclasses of
:mod:`sonarsim.config.scene`. Every error names the key (``objects[1].albedo``) or the file.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, MeshFileError, SonarsimError, check_input_file, key_text, shown
from .document import MAX_DOCUMENT_BYTES as MAX_SCENE_BYTES, read_document  # noqa: F401 - re-exported
from .materials import LAWS, MAX_LAMBERT_MU, Material, Reflection, mu_from_db, object_material
from .meshfiles import load_mesh_file, world_reach_m  # below scene: config imports nothing of it
from .parameters import MAX_ANGLE_DEG
from .presets import beam_angles_from_table, get_preset
from .sensor import parse_sensor, preset_device_mismatch
from .instruments import FlsSpec, instrument_class, mounted
from .scene import MAX_COORDINATE_M, ObjectSpec, PlaneSpec, RenderSettings, Scene, TextureSpec, ground_plane
from .sdf import OVERRIDE_KEYS, WorldSpec, read_sdf_world
from .tracks import TRACK_KEYS, Track, Trajectory, read_trajectory
from .sonar import MIN_RELATIVE_BIN_WIDTH, RangeBinError, SonarConfig, beam_edges_deg, check_range_window
from .water import WaterSpec, parse_water
from ..core.transforms import Pose

# Lambert's energy bound in dB (-4.97): mu_db above it returns more than the surface receives.
MAX_LAMBERT_MU_DB = 10.0 * math.log10(MAX_LAMBERT_MU)
TOP_KEYS = ("sonar", "render", "ground", "planes", "objects", "sensor", "vehicle", "instruments", "water", "world")
#: Keys of the ``world:`` section (a Gazebo SDF world's models as objects: :mod:`sonarsim.config.sdf`).
WORLD_KEYS = ("sdf", "model_path", "materials", "skip", "environment")
SONAR_KEYS = (
    "preset", "n_beams", "azimuth_fov_deg", "beam_angles_deg", "beam_angles_file", "beam_width_deg",
    "elevation_fov_deg", "range_min_m", "range_max_m", "n_range_bins", "range_resolution_m",
    "frequency_khz", "pose", "type", "sound_speed_m_s", "beam_shape",
)
VEHICLE_KEYS = ("pose", "speed_m_s")
POSE_KEYS = ("position_m", "rpy_deg", "quat_xyzw")
RENDER_KEYS = tuple(RenderSettings.__dataclass_fields__)
GROUND_KEYS = ("height_m", "albedo", "specular", "material", "texture", "reflection")
PLANE_KEYS = ("name", "point_m", "normal", "albedo", "specular", "material", "texture", "reflection")
REFLECTION_KEYS = ("medium", "rms_height_m", "wind_speed_m_s")
TEXTURE_KEYS = tuple(TextureSpec.__dataclass_fields__)
OBJECT_KEYS = ("name", "primitive", "size_m", "radius_m", "height_m", "mesh", "pose", "scale", "albedo", "material",
               "specular", "normals", "reflection", "track")
#: The fastest an object's velocity track moves, m/s (a torpedo; beyond, a typo).
MAX_TRACK_SPEED_M_S = 100.0
MATERIAL_KEYS = ("law", "albedo", "mu", "mu_db", "specular_strength", "roughness", "texture", "sediment",
                 "grain_size_phi", "level_db", "preset", "area_m2", "reflectance")


# Plausibility bounds: a sonar scene spans kilometres at most (MAX_COORDINATE_M); an angle
# beyond two turns is a typo (MAX_ANGLE_DEG). Both from the one table of fittable parameters.


# Typed getters ---------------------------------------------------------------------------

def _check_keys(d: Any, allowed: tuple[str, ...], where: str) -> Mapping:
    if not isinstance(d, Mapping):
        raise ConfigError(where, f"must be a mapping with keys from: {', '.join(allowed)}; got {type(d).__name__}")
    for key in d:
        if key not in allowed:
            raise ConfigError(
                f"{where}.{key_text(key)}" if where else key_text(key),
                f"unknown key; allowed keys{' of ' + where if where else ''}: {', '.join(allowed)}",
            )
    return d


def _number(value: Any, key: str) -> float:
    # An integer beyond a float's range (YAML reads 1000 digits as one) is not finite either:
    # math.isfinite would raise OverflowError on it.
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or (isinstance(value, int) and abs(value) > sys.float_info.max) or not math.isfinite(value)):
        raise ConfigError(key, f"must be a finite number, got {shown(value)}")
    return float(value)


def _integer(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(key, f"must be an integer, got {shown(value)}")
    return int(value)


def _vector(value: Any, key: str, n: int | None) -> tuple[float, ...]:
    if not isinstance(value, (list, tuple)) or (n is not None and len(value) != n):
        what = f"a list of {n} numbers" if n is not None else "a list of numbers"
        raise ConfigError(key, f"must be {what}, got {shown(value)}")
    return tuple(_number(v, f"{key}[{i}]") for i, v in enumerate(value))


def _string(value: Any, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(key, f"must be a non-empty string, got {shown(value)}")
    return value


def _boolean(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(key, f"must be true or false, got {shown(value)}")
    return value


def _prefixed(prefix: str, fn, *args, **kwargs):
    """Call a dataclass constructor, putting ``prefix`` before the key named in its errors."""
    try:
        return fn(*args, **kwargs)
    except ConfigError as exc:
        key = exc.key if exc.key.startswith(prefix) else f"{prefix}.{exc.key}" if exc.key else prefix
        raise ConfigError(key, exc.detail) from None


# Sections ---------------------------------------------------------------------------------

def parse_pose(d: Any, where: str) -> Pose:
    """A pose mapping ``{position_m, rpy_deg | quat_xyzw}``; missing parts are zero."""
    _check_keys(d, POSE_KEYS, where)
    position = _vector(d.get("position_m", [0.0, 0.0, 0.0]), f"{where}.position_m", 3)
    if max(abs(v) for v in position) > MAX_COORDINATE_M:
        raise ConfigError(f"{where}.position_m", f"must lie within {MAX_COORDINATE_M:g} m of the origin, got {list(position)}")
    if "rpy_deg" in d and "quat_xyzw" in d:
        raise ConfigError(f"{where}.quat_xyzw", "give either rpy_deg or quat_xyzw, not both")
    if "quat_xyzw" in d:
        q = _vector(d["quat_xyzw"], f"{where}.quat_xyzw", 4)
        if math.hypot(*q) < 1e-9:  # hypot: the squares of 1e300 overflow
            raise ConfigError(f"{where}.quat_xyzw", "must not be the zero quaternion")
        return Pose.from_quaternion(position, q)
    rpy = _vector(d.get("rpy_deg", [0.0, 0.0, 0.0]), f"{where}.rpy_deg", 3)
    if max(abs(v) for v in rpy) > MAX_ANGLE_DEG:
        raise ConfigError(f"{where}.rpy_deg", f"angles must lie within +-{MAX_ANGLE_DEG:g} degrees, got {list(rpy)}")
    return Pose(position, rpy)


def parse_sonar(d: Any, base_dir: Path | None) -> SonarConfig:
    """The intrinsics of the ``sonar`` section: a preset (optional) overridden by the keys given.

    Its ``pose`` is checked too; :func:`parse_sonar_section` returns it as well.
    """
    return parse_sonar_section(d, base_dir)[0]


def parse_sonar_section(d: Any, base_dir: Path | None) -> tuple[SonarConfig, Pose]:
    """The ``sonar`` section: the intrinsics (a preset, optional, overridden by the keys given)
    and the pose (``sonar.pose``; the origin looking along +x if absent).

    Returns
    -------
    sonar : SonarConfig
    pose : Pose
    """
    _check_keys(d, SONAR_KEYS, "sonar")
    if "type" in d:
        if d["type"] != "fls":
            raise ConfigError("sonar.type", f"the intrinsics of an FLS; got type {shown(d['type'])}")
        d = {k: v for k, v in d.items() if k != "type"}
    merged: dict[str, Any] = {}
    preset_name = None
    if "preset" in d:
        preset_name = _string(d["preset"], "sonar.preset")
        merged.update(get_preset(preset_name).sonar)
    user = dict(d)
    user.pop("preset", None)
    if "beam_angles_file" in user:
        path = Path(_string(user.pop("beam_angles_file"), "sonar.beam_angles_file"))
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        user["beam_angles_deg"] = list(beam_angles_from_table(path, key="sonar.beam_angles_file"))
    # Keys given by the user replace the preset's alternatives for the same quantity.
    if "beam_angles_deg" in user and "azimuth_fov_deg" in user:
        raise ConfigError("sonar.azimuth_fov_deg", "give either azimuth_fov_deg or beam_angles_deg, not both")
    if "beam_angles_deg" in user or "azimuth_fov_deg" in user or "n_beams" in user:
        if "beam_angles_deg" not in user:
            # A user's beam count or field of view turns a preset's lens table into equal beams.
            if "beam_angles_deg" in merged and "azimuth_fov_deg" not in merged:
                table = np.asarray(merged["beam_angles_deg"], dtype=float)
                edges = beam_edges_deg(table)
                merged["azimuth_fov_deg"] = float(edges[0] - edges[-1])
                merged.setdefault("n_beams", len(table))
            merged.pop("beam_angles_deg", None)
        else:
            merged.pop("azimuth_fov_deg", None)
            if "n_beams" not in user:
                merged.pop("n_beams", None)
    if "n_range_bins" in user or "range_resolution_m" in user:
        merged.pop("n_range_bins", None)
        merged.pop("range_resolution_m", None)
    merged.update(user)

    def get(key, conv):
        if key not in merged:
            raise ConfigError(f"sonar.{key}", "required (give it, or a `preset` that sets it)")
        return conv(merged[key], f"sonar.{key}")

    if "n_range_bins" in merged and "range_resolution_m" in merged:
        raise ConfigError("sonar.range_resolution_m", "give either n_range_bins or range_resolution_m, not both")
    r_min = get("range_min_m", _number)
    r_max = get("range_max_m", _number)
    # The window first: the bins are counted from it (range_max_m 1e308 counted 1e308 bins).
    check_range_window(r_min, r_max)
    if "range_resolution_m" in merged:
        res = get("range_resolution_m", _number)
        if res <= 0:
            raise ConfigError("sonar.range_resolution_m", f"must be > 0 metres, got {res}")
        n_bins_float = (r_max - r_min) / res
        if not math.isfinite(n_bins_float):  # 1e300 metres over 1e-300 metres a bin
            raise ConfigError("sonar.range_resolution_m",
                              f"{res:g} m gives {n_bins_float} range bins over {r_min:g} to {r_max:g} m; "
                              "give a coarser resolution")
        # A resolution as wide as the window made a one-bin image: a resolution is asked for to
        # resolve something, so it must give at least two bins (n_range_bins: 1 stays possible).
        if n_bins_float < 2:
            raise ConfigError("sonar.range_resolution_m",
                              f"must be at most half the range window ((range_max_m - range_min_m) / 2 = "
                              f"{(r_max - r_min) / 2:g} m: at least two range bins), got {res:g}")
        n_bins = int(round(n_bins_float))
    else:
        n_bins = get("n_range_bins", _integer)
        if n_bins < 1:
            raise ConfigError("sonar.n_range_bins", f"must be at least 1, got {n_bins}")
    pose = parse_pose(merged.get("pose", {}), "sonar.pose")
    extra = {}
    for key in ("beam_width_deg", "frequency_khz", "sound_speed_m_s"):
        if merged.get(key) is not None:
            extra[key] = get(key, _number)
    if merged.get("beam_shape") is not None:
        extra["beam_shape"] = _string(merged["beam_shape"], "sonar.beam_shape")
    common = dict(
        elevation_fov_deg=get("elevation_fov_deg", _number),
        range_min_m=r_min,
        range_max_m=r_max,
        n_range_bins=n_bins,
        preset=preset_name,
        **extra,
    )
    try:
        if "beam_angles_deg" in merged:
            angles = _vector(merged["beam_angles_deg"], "sonar.beam_angles_deg", None)
            if "n_beams" in merged and get("n_beams", _integer) != len(angles):
                raise ConfigError("sonar.n_beams", f"is {merged['n_beams']} but beam_angles_deg has {len(angles)} angles")
            return SonarConfig(beam_angles_deg=angles, **common), pose
        sonar = SonarConfig.uniform(
            n_beams=get("n_beams", _integer), azimuth_fov_deg=get("azimuth_fov_deg", _number), **common
        )
    except RangeBinError as exc:
        if "range_resolution_m" not in merged:
            raise
        finest = MIN_RELATIVE_BIN_WIDTH * r_max
        raise ConfigError("sonar.range_resolution_m",
                          f"{merged['range_resolution_m']:g} m is finer than float32 ranges resolve at {r_max:g} m; "
                          f"allowed: {finest:.3g} m ({MIN_RELATIVE_BIN_WIDTH:g} of range_max_m) to "
                          f"{(r_max - r_min) / 2:g} m (two bins)") from exc
    return sonar, pose


def parse_material(d: Any, where: str, texture_allowed: bool) -> Material:
    """A ``material`` mapping: ``{law, albedo | mu | mu_db, specular_strength, roughness, texture}``,
    or for the sediment law ``{law: sediment, sediment | grain_size_phi, level_db, texture}``.

    ``where`` is the key of the mapping (``objects[0].material``); ``texture`` only where
    ``texture_allowed`` (objects).
    """
    keys = MATERIAL_KEYS if texture_allowed else tuple(k for k in MATERIAL_KEYS if k != "texture")
    _check_keys(d, keys, where)
    if "preset" in d:  # a named solid: the rough law with its impedance's reflection (object_material)
        other = [k for k in d if k not in ("preset", "texture")]
        if other:
            raise ConfigError(f"{where}.{other[0]}", "not with a material preset (its law is the preset's)")
        texture = _boolean(d["texture"], f"{where}.texture") if "texture" in d else False
        return _prefixed(where, object_material, _string(d["preset"], f"{where}.preset"), texture)
    kw: dict[str, Any] = {}
    if "law" in d:
        kw["law"] = _string(d["law"], f"{where}.law")
        if kw["law"] not in LAWS:
            raise ConfigError(f"{where}.law", f"unknown law {shown(kw['law'])}; allowed: {', '.join(LAWS)}")
    if "mu" in d and "mu_db" in d:
        raise ConfigError(f"{where}.mu_db", "give either mu (linear) or mu_db, not both")
    for key in ("albedo", "mu", "specular_strength", "roughness", "grain_size_phi", "level_db", "area_m2",
                "reflectance"):
        if key in d:
            kw[key] = _number(d[key], f"{where}.{key}")
    if "sediment" in d:
        kw["sediment"] = _string(d["sediment"], f"{where}.sediment")
    if "mu_db" in d:
        mu_db = _number(d["mu_db"], f"{where}.mu_db")
        if mu_db > MAX_LAMBERT_MU_DB:
            raise ConfigError(f"{where}.mu_db", f"must be <= {MAX_LAMBERT_MU_DB:.2f} dB (mu <= 1/pi: Lambert's energy "
                                                f"bound), got {mu_db}")
        if kw.get("law", "lambertian") != "lambert":
            raise ConfigError(f"{where}.mu_db", f"not used by the law {shown(kw.get('law', 'lambertian'))}")
        kw["mu"] = mu_from_db(mu_db)
    if "texture" in d:
        kw["texture"] = _boolean(d["texture"], f"{where}.texture")
    return _prefixed(where, Material, **kw)


def _material_of(d: Mapping, where: str, texture_allowed: bool) -> dict[str, Any]:
    """``{'material': Material}`` from ``d['material']`` (empty without one); refuses ``albedo`` beside it."""
    if "material" not in d:
        return {}
    if "albedo" in d:
        raise ConfigError(f"{where}.albedo", "give either albedo (the Lambertian shorthand) or material, not both")
    return {"material": parse_material(d["material"], f"{where}.material", texture_allowed)}


def parse_render(d: Any) -> RenderSettings:
    _check_keys(d, RENDER_KEYS, "render")
    kw: dict[str, Any] = {}
    for key, value in d.items():
        k = f"render.{key}"
        if key == "elevation_samples":
            if isinstance(value, str) and value != "auto" or isinstance(value, bool) or not isinstance(value, (str, int)):
                raise ConfigError(k, f"must be 'auto' or a positive integer, got {shown(value)}")
            kw[key] = value
        elif key in ("azimuth_samples", "seed", "max_order"):
            kw[key] = _integer(value, k)
        elif key == "threads":
            kw[key] = None if value is None else _integer(value, k)
        elif key in ("tvg", "range_splat", "double_line_of_sight", "speckle", "glints"):
            kw[key] = _boolean(value, k)
        elif key == "glint_radius_m":
            kw[key] = _number(value, k)
        elif key == "bounces":
            if isinstance(value, int) and not isinstance(value, bool):
                value = [value]
            if value is None:
                kw[key] = None
                continue
            if not isinstance(value, (list, tuple)):
                raise ConfigError(k, f"must be a list of path orders (1 single, 2 double, 3 triple, ...), got {shown(value)}")
            kw[key] = tuple(_integer(v, f"{k}[{i}]") for i, v in enumerate(value))
        else:
            kw[key] = _string(value, k)
    return _prefixed("render", RenderSettings, **kw)


def parse_texture(d: Any, where: str) -> TextureSpec:
    """A plane's ``texture`` mapping: ``{std_db, correlation_m, angle_deg, seed, covariance}``."""
    _check_keys(d, TEXTURE_KEYS, where)
    kw: dict[str, Any] = {}
    for key in ("std_db", "angle_deg"):
        if key in d:
            kw[key] = _number(d[key], f"{where}.{key}")
    if "correlation_m" in d:
        c = d["correlation_m"]
        if isinstance(c, (list, tuple)):
            kw["correlation_m"] = _vector(c, f"{where}.correlation_m", 2)
        else:
            kw["correlation_m"] = _number(c, f"{where}.correlation_m")
    if "seed" in d:
        kw["seed"] = None if d["seed"] is None else _integer(d["seed"], f"{where}.seed")
    if "covariance" in d:
        kw["covariance"] = _string(d["covariance"], f"{where}.covariance")
    # TextureSpec names its keys ``texture.<key>``: put what comes before ``texture`` in front.
    return _prefixed(where[: -len("texture")].rstrip("."), TextureSpec, **kw)


def parse_ground(d: Any) -> PlaneSpec | None:
    """The ``ground:`` section: the plane named ``ground`` (:func:`~sonarsim.config.scene.ground_plane`)."""
    if d is None:
        return None
    _check_keys(d, GROUND_KEYS, "ground")
    kw = {key: _number(value, f"ground.{key}") for key, value in d.items()
          if key not in ("material", "texture", "reflection")}
    kw.update(_material_of(d, "ground", texture_allowed=False))
    kw.update(_reflection_of(d, "ground"))
    if "texture" in d:
        kw["texture"] = parse_texture(d["texture"], "ground.texture")
    return _prefixed("ground", ground_plane, **kw)


def parse_plane(d: Any, index: int) -> PlaneSpec:
    """One entry of the ``planes`` list."""
    where = f"planes[{index}]"
    _check_keys(d, PLANE_KEYS, where)
    for key in ("name", "point_m", "normal"):
        if key not in d:
            raise ConfigError(f"{where}.{key}", "required for a plane (name, point_m, normal; albedo, specular optional)")
    kw: dict[str, Any] = {
        "name": _string(d["name"], f"{where}.name"),
        "point_m": _vector(d["point_m"], f"{where}.point_m", 3),
        "normal": _vector(d["normal"], f"{where}.normal", 3),
    }
    for key in ("albedo", "specular"):
        if key in d:
            kw[key] = _number(d[key], f"{where}.{key}")
    kw.update(_material_of(d, where, texture_allowed=False))
    kw.update(_reflection_of(d, where))
    if "texture" in d:
        kw["texture"] = parse_texture(d["texture"], f"{where}.texture")
    return _prefixed(where, PlaneSpec, **kw)


def parse_reflection(d: Any, where: str) -> Reflection:
    """A ``reflection`` mapping: ``{medium, rms_height_m | wind_speed_m_s}`` (every key optional;
    ``{}``: the surface's own material, its own roughness)."""
    if d is None:
        d = {}
    _check_keys(d, REFLECTION_KEYS, where)
    kw: dict[str, Any] = {}
    if "medium" in d:
        kw["medium"] = _string(d["medium"], f"{where}.medium")
    for key in ("rms_height_m", "wind_speed_m_s"):
        if key in d:
            kw[key] = _number(d[key], f"{where}.{key}")
    return _prefixed(where, Reflection, **kw)


def _reflection_of(d: Mapping, where: str) -> dict[str, Any]:
    """``{'reflection': Reflection}`` from ``d['reflection']`` (empty without one); refuses
    ``specular`` beside it."""
    if "reflection" not in d:
        return {}
    if "specular" in d:
        raise ConfigError(f"{where}.specular", "give either specular (one constant R) or reflection (R by the "
                                               "Rayleigh coefficient and roughness), not both")
    return {"reflection": parse_reflection(d["reflection"], f"{where}.reflection")}


def parse_track(d: Any, where: str, base_dir: Path | None, pose: Pose | None = None) -> Track:
    """An object's ``track``: ``{file, format}`` (a CSV or TUM trajectory file), ``{keys: [{t,
    position_m, rpy_deg | quat_xyzw}, ...]}``, either with ``repeat``, or ``{velocity_m_s,
    yaw_rate_deg_s}`` from ``pose`` at time 0."""
    if not isinstance(d, Mapping):
        raise ConfigError(where, f"must be a mapping (file, keys or velocity_m_s); got {type(d).__name__}")
    _check_keys(d, TRACK_KEYS, where)
    given = [k for k in ("file", "keys", "velocity_m_s") if k in d]
    if len(given) != 1:
        raise ConfigError(where, f"give exactly one of file, keys, velocity_m_s; got {', '.join(given) or 'none'}")
    repeat = d.get("repeat", False)
    if not isinstance(repeat, bool):
        raise ConfigError(f"{where}.repeat", f"must be true or false, got {shown(repeat)}")
    if given[0] == "velocity_m_s":
        for key in ("format", "repeat"):
            if key in d:
                raise ConfigError(f"{where}.{key}", "belongs to timed poses (file or keys), not to a velocity")
        velocity = _vector(d["velocity_m_s"], f"{where}.velocity_m_s", 3)
        if max(abs(v) for v in velocity) > MAX_TRACK_SPEED_M_S:
            raise ConfigError(f"{where}.velocity_m_s", f"must be within +-{MAX_TRACK_SPEED_M_S:g} m/s, got {list(velocity)}")
        rate = _number(d.get("yaw_rate_deg_s", 0.0), f"{where}.yaw_rate_deg_s")
        if abs(rate) > MAX_ANGLE_DEG:
            raise ConfigError(f"{where}.yaw_rate_deg_s", f"must be within +-{MAX_ANGLE_DEG:g} deg/s, got {shown(rate)}")
        return Track(velocity_m_s=velocity, yaw_rate_deg_s=rate, start=pose or Pose())
    if "yaw_rate_deg_s" in d:
        raise ConfigError(f"{where}.yaw_rate_deg_s", "belongs to a velocity_m_s track")
    if given[0] == "file":
        path = Path(_string(d["file"], f"{where}.file"))
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        fmt = d.get("format")
        if fmt is not None and fmt not in ("csv", "tum"):
            raise ConfigError(f"{where}.format", f"unknown format {shown(fmt)}; allowed: csv, tum")
        return Track(trajectory=read_trajectory(path, fmt, f"{where}.file"), repeat=repeat, source=str(path))
    if "format" in d:
        raise ConfigError(f"{where}.format", "belongs to a track file")
    keys = d["keys"]
    if not isinstance(keys, (list, tuple)) or not keys:
        raise ConfigError(f"{where}.keys", "must be a non-empty list of {t, position_m, rpy_deg | quat_xyzw}")
    times, poses = [], []
    for i, key in enumerate(keys):
        at = f"{where}.keys[{i}]"
        if not isinstance(key, Mapping) or "t" not in key:
            raise ConfigError(at, "must be a mapping with t (seconds) and a pose (position_m, rpy_deg | quat_xyzw)")
        t = _number(key["t"], f"{at}.t")
        if times and not t > times[-1]:
            raise ConfigError(f"{at}.t", f"{t:g} s does not follow {times[-1]:g} s (times must increase strictly)")
        times.append(t)
        poses.append(parse_pose({k: v for k, v in key.items() if k != "t"}, at))
    trajectory = Trajectory(np.array(times), np.array([p.position_m for p in poses]),
                            np.array([p.quat_xyzw for p in poses]))
    return Track(trajectory=trajectory, repeat=repeat)


def parse_object(d: Any, index: int, base_dir: Path | None) -> ObjectSpec:
    where = f"objects[{index}]"
    _check_keys(d, OBJECT_KEYS, where)
    kw: dict[str, Any] = {"name": _string(d["name"], f"{where}.name") if "name" in d else f"object{index}"}
    if "primitive" in d:
        kw["primitive"] = _string(d["primitive"], f"{where}.primitive")
    if "mesh" in d:
        path = Path(_string(d["mesh"], f"{where}.mesh"))
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        try:
            load_mesh_file(path)  # fail now, naming the key, rather than at render time
        except MeshFileError as exc:
            raise ConfigError(f"{where}.mesh", str(exc)) from None
        kw["mesh"] = str(path)
    if "size_m" in d:
        kw["size_m"] = _vector(d["size_m"], f"{where}.size_m", 3)
    for key in ("radius_m", "height_m", "albedo", "specular"):
        if key in d:
            kw[key] = _number(d[key], f"{where}.{key}")
    if "normals" in d:
        kw["normals"] = _string(d["normals"], f"{where}.normals")
    if "scale" in d:
        s = d["scale"]
        kw["scale"] = _vector(s, f"{where}.scale", 3) if isinstance(s, (list, tuple)) else _number(s, f"{where}.scale")
    if "pose" in d:
        kw["pose"] = parse_pose(d["pose"], f"{where}.pose")
    if "track" in d:
        kw["track"] = parse_track(d["track"], f"{where}.track", base_dir, kw.get("pose"))
        if kw["track"].trajectory is not None:
            if "pose" in d:
                raise ConfigError(f"{where}.pose", "an object with timed poses (track.file or track.keys) takes its "
                                  "pose from them; give no pose (a velocity_m_s track starts from the pose)")
            kw["pose"] = kw["track"].pose_at(float(kw["track"].trajectory.times_s[0]))
    kw.update(_material_of(d, where, texture_allowed=True))
    kw.update(_reflection_of(d, where))
    if "mesh" in kw and kw.get("material") is not None and kw["material"].texture:
        try:
            load_mesh_file(kw["mesh"], texture=True)
        except MeshFileError as exc:
            raise ConfigError(f"{where}.material.texture", str(exc)) from None
    spec = _prefixed(where, ObjectSpec, **kw)
    if spec.mesh is not None:
        # Once scaled and posed (both checked now), the mesh must stay within the scene's extent.
        reach = world_reach_m(load_mesh_file(spec.mesh), spec.scale, spec.pose)  # cached: read above
        if reach > MAX_COORDINATE_M:
            raise ConfigError(f"{where}.mesh", f"{spec.mesh}: scaled by {shown(spec.scale)} and posed at "
                              f"{list(spec.pose.position_m)}, its vertices reach {reach:.3g} m from the origin; "
                              f"allowed: within {MAX_COORDINATE_M:g} m (mind scale and pose)")
    return spec


def parse_world(d: Any, base_dir: Path | None) -> WorldSpec:
    """The ``world:`` section: ``{sdf, model_path, materials, skip, environment}``.

    ``sdf`` and the ``model_path`` folders (a string or a list) are relative to the scene file;
    ``materials`` maps a model, ``model::link`` or ``model::link::visual`` to surface keys;
    ``skip`` lists models left out; ``environment`` (default true) searches
    :data:`~sonarsim.config.sdf.MODEL_PATH_VARIABLES` after ``model_path``.
    """
    _check_keys(d, WORLD_KEYS, "world")
    if "sdf" not in d:
        raise ConfigError("world.sdf", "required: the SDF world file (relative to the scene file)")

    def place(text: str) -> Path:
        p = Path(text)
        return base_dir / p if base_dir is not None and not p.is_absolute() else p

    sdf = place(_string(d["sdf"], "world.sdf"))
    folders = d.get("model_path", []) or []
    if isinstance(folders, str):
        folders = [folders]
    if not isinstance(folders, list):
        raise ConfigError("world.model_path", f"must be a folder or a list of folders, got {shown(folders)}")
    model_path = tuple(place(_string(f, f"world.model_path[{i}]")) for i, f in enumerate(folders))
    for i, folder in enumerate(model_path):
        if not folder.is_dir():
            raise ConfigError(f"world.model_path[{i}]", f"{folder}: not a folder")
    materials = d.get("materials", {}) or {}
    if not isinstance(materials, Mapping):
        raise ConfigError("world.materials", f"must map model names to surface keys, got {shown(materials)}")
    for name, value in materials.items():
        _string(name, "world.materials")
        if not isinstance(value, Mapping):
            raise ConfigError(f"world.materials.{key_text(name)}", "must be a mapping of surface keys (material, "
                              f"albedo, specular, reflection, normals), got {shown(value)}")
    skip = d.get("skip", []) or []
    if not isinstance(skip, list):
        raise ConfigError("world.skip", f"must be a list of model names, got {shown(skip)}")
    skip = tuple(_string(s, f"world.skip[{i}]") for i, s in enumerate(skip))
    environment = _boolean(d.get("environment", True), "world.environment")
    return WorldSpec(sdf, model_path, {str(k): dict(v) for k, v in materials.items()}, skip, environment)


def _world_objects(d: Mapping, base: Path | None, own: list) -> tuple[list[ObjectSpec], dict | None]:
    """The objects and the ground section of the scene's ``world:`` (none without one)."""
    if d.get("world") is None:
        return [], None
    world = read_sdf_world(parse_world(d["world"], base))
    names = {o.get("name") for o in own if isinstance(o, Mapping)}
    specs = []
    for raw in world.objects:
        name = raw["name"]
        if name in names:
            raise ConfigError("world", f"{world_sdf(d, base)}: the model {shown(name)} has the name of one of the "
                              "scene's objects; rename that object or leave the model out with world.skip")
        try:
            # The dicts pass the scene's own checks; errors name the world's model, not an index.
            specs.append(parse_object(raw, 0, None))
        except ConfigError as exc:
            # A surface key came from an override (world.materials) or the table; the rest from the SDF.
            inner = exc.key.split(".", 1)[1] if "." in exc.key else ""
            surface = inner.split(".")[0] in OVERRIDE_KEYS
            raise ConfigError("world.materials" if surface else "world",
                              f"{world_sdf(d, base)}: model {shown(name)}: {inner + ': ' if inner else ''}"
                              f"{exc.detail}") from None
    return specs, world.ground


def world_sdf(d: Mapping, base: Path | None) -> str:
    """The SDF file of a scene's ``world:``, as its messages name it."""
    sdf = Path(str(d["world"].get("sdf", "")))
    return str(base / sdf if base is not None and not sdf.is_absolute() else sdf)


def parse_instrument(d: Any, key: str, base_dir: Path | None, default_name: str, mount_key: str = "mount"):
    """One instrument's section (``instruments[i]``, or ``sonar:`` with a ``type``).

    The type's keys are the type's (:mod:`sonarsim.config.instruments`); ``name`` defaults to
    ``default_name`` and ``mount`` (``mount_key``) to the vehicle's origin.

    Returns
    -------
    InstrumentSpec
    """
    if not isinstance(d, Mapping):
        raise ConfigError(key, f"must be a mapping with a type; got {type(d).__name__}")
    kind = d.get("type", "fls")
    cls = instrument_class(kind, f"{key}.type")
    name = _string(d.get("name", default_name), f"{key}.name")
    mount = parse_pose(d.get(mount_key, {}) or {}, f"{key}.{mount_key}")
    if cls is FlsSpec:
        body = {k: v for k, v in d.items() if k not in ("type", "name", mount_key, "ping_rate_hz")}
        try:
            sonar, _ = parse_sonar_section(body, base_dir)
        except ConfigError as exc:
            raise ConfigError(exc.key.replace("sonar", key, 1), exc.detail) from None
        rate = d.get("ping_rate_hz")
        if rate is not None:
            rate = _number(rate, f"{key}.ping_rate_hz")
            if not 0 < rate <= 1e4:
                raise ConfigError(f"{key}.ping_rate_hz", f"must be a rate in (0, 10000] Hz, got {shown(rate)}")
        return FlsSpec(name=name, mount=mount, sonar=sonar, ping_rate_hz=rate)
    allowed = ("type", "name", mount_key) + tuple(cls.keys)
    _check_keys(d, allowed, key)
    body = {k: v for k, v in d.items() if k not in ("type", "name", mount_key)}
    return cls.parse(body, key, base_dir, name, mount)


def _instruments(d: Mapping, base: Path | None) -> tuple[tuple, Pose]:
    """The scene's instruments and the vehicle's pose: from ``vehicle`` + ``instruments``, or
    from a ``sonar:`` section with a ``type`` other than ``fls`` (one instrument, the vehicle at
    its pose); ``((), pose)`` for today's ``sonar:``."""
    if "instruments" in d:
        if "sonar" in d:
            raise ConfigError("instruments", "give either sonar (one instrument) or instruments, not both")
        raw = d["instruments"]
        if not isinstance(raw, list) or not raw:
            raise ConfigError("instruments", "must be a non-empty list of instruments, each with a type")
        vehicle = d.get("vehicle") or {}
        _check_keys(vehicle, VEHICLE_KEYS, "vehicle")
        pose = parse_pose(vehicle.get("pose", {}) or {}, "vehicle.pose")
        specs = tuple(parse_instrument(x, f"instruments[{i}]", base, f"{x.get('type', 'fls') if isinstance(x, Mapping) else 'x'}{i}")
                      for i, x in enumerate(raw))
        names = [s.name for s in specs]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ConfigError(f"instruments[{i}].name", f"duplicate instrument name {shown(n)}; names must be unique")
        return specs, pose
    sonar = d.get("sonar")
    if isinstance(sonar, Mapping) and sonar.get("type", "fls") != "fls":
        vehicle = d.get("vehicle") or {}
        _check_keys(vehicle, VEHICLE_KEYS, "vehicle")
        if "pose" in vehicle:
            raise ConfigError("vehicle.pose", "with one instrument in sonar:, its pose is the vehicle's: give sonar.pose")
        pose = parse_pose(sonar.get("pose", {}) or {}, "sonar.pose")
        spec = parse_instrument(sonar, "sonar", base, str(sonar.get("type")), mount_key="pose")
        return (replace(spec, mount=Pose()),), pose
    if "vehicle" in d:
        raise ConfigError("vehicle", "a vehicle carries instruments: give instruments: (or sonar: alone)")
    return (), Pose()


def _vehicle_speed(d: Mapping) -> float:
    """``vehicle.speed_m_s``: the vehicle runs straight ahead (its x axis) at this speed; 0 stands still."""
    vehicle = d.get("vehicle") or {}
    if "speed_m_s" not in vehicle:
        return 0.0
    v = _number(vehicle["speed_m_s"], "vehicle.speed_m_s")
    if not 0.0 <= v <= 100.0:
        raise ConfigError("vehicle.speed_m_s", f"must lie in [0, 100] m/s, got {shown(v)}")
    return v


def _water(d: Mapping) -> WaterSpec | None:
    """The ``water:`` section, refusing a sensor that sets the water's properties otherwise."""
    water = parse_water(d.get("water"))
    sensor = d.get("sensor")
    if water is None or not isinstance(sensor, Mapping):
        return water
    # (a value equal to the water's passes: a scene written by to_dict holds the folded values)
    if "sound_speed_m_s" in sensor and sensor["sound_speed_m_s"] != water.speed_m_s:
        raise ConfigError("sensor.sound_speed_m_s", "with a water: section the water gives the speed of sound "
                          f"({water.speed_m_s:.2f} m/s); the speed the device assumes is sonar.sound_speed_m_s")
    absorption = sensor.get("absorption")
    if isinstance(absorption, Mapping):
        for key in ("temperature_c", "salinity_psu", "depth_m", "ph"):
            if key in absorption and absorption[key] != getattr(water, key):
                raise ConfigError(f"sensor.absorption.{key}", f"with a water: section the absorption takes the "
                                  f"water's {key} ({getattr(water, key):g}); set it in water:")
    return water


def scene_from_dict(d: Any, base_dir: str | os.PathLike | None = None, source: str | None = None) -> Scene:
    """Build a :class:`Scene` from the scene-file dict.

    Parameters
    ----------
    d : mapping
        The document (see DESIGN.md section 2).
    base_dir : path-like, optional
        Folder that relative mesh and table paths are resolved against.
    source : str, optional
        Name of the file, for error messages.
    """
    base = Path(base_dir) if base_dir is not None else None
    try:
        _check_keys(d, TOP_KEYS, "")
        instruments, vehicle_pose = _instruments(d, base)
        if "sonar" not in d and not instruments:
            raise ConfigError("sonar", "required: the sonar section (or vehicle and instruments)")
        objects_raw = d.get("objects", []) or []
        if not isinstance(objects_raw, list):
            raise ConfigError("objects", f"must be a list of objects, got {type(objects_raw).__name__}")
        planes_raw = d.get("planes", []) or []
        if not isinstance(planes_raw, list):
            raise ConfigError("planes", f"must be a list of planes, got {type(planes_raw).__name__}")
        world_objects, world_ground = _world_objects(d, base, objects_raw)
        # The scene's own ground: section wins over the world's plane (ground: null: no ground).
        if "ground" in d or world_ground is None:
            ground = parse_ground(d.get("ground"))
        else:
            try:
                ground = parse_ground(world_ground)
            except ConfigError as exc:  # only an override's keys can be wrong here
                raise ConfigError("world.materials", f"{world_sdf(d, base)}: the ground plane: {exc}") from None
        sensor = parse_sensor(d.get("sensor"), base)
        if instruments and sensor is not None:
            # The top-level sensor is the FLS's; another type carries its own (``sensor:`` in its
            # section; ``sonar:`` of that type: the top-level one is moved into it).
            if "sonar" in d and "sensor" in type(instruments[0]).keys:
                instruments, sensor = (replace(instruments[0], sensor=sensor),), None
            elif not isinstance(instruments[0], FlsSpec):
                raise ConfigError("sensor", "the top-level sensor is the first instrument's, an FLS's; give "
                                  f"the {instruments[0].type_name} {shown(instruments[0].name)} its own "
                                  "sensor: in its section")
        if instruments:
            primary = instruments[0].primary
            sonar, sonar_pose = primary.sonar, mounted(vehicle_pose, primary.mount)
        else:
            sonar, sonar_pose = parse_sonar_section(d["sonar"], base)
        scene = _prefixed(
            "",
            Scene,
            sonar=sonar,
            sonar_pose=sonar_pose,
            objects=tuple(parse_object(o, i, base) for i, o in enumerate(objects_raw)) + tuple(world_objects),
            ground=ground,
            planes=tuple(parse_plane(p, i) for i, p in enumerate(planes_raw)),
            render=parse_render(d.get("render", {}) or {}),
            source=source,
            sensor=sensor if instruments else parse_sensor(d.get("sensor"), base),
            instruments=instruments,
            vehicle_pose=vehicle_pose,
            vehicle_speed_m_s=_vehicle_speed(d) if instruments else 0.0,
            water=_water(d),
        )
        if scene.sensor is not None and scene.sensor.preset is not None:
            # The command line's --force takes another device's preset on purpose; in a file the
            # pairing is a slip (an ARIS's sensor on an Oculus's sonar gives another device's levels).
            mismatch = preset_device_mismatch(scene.sensor.preset, sonar)
            if mismatch is not None:
                raise ConfigError("sensor.preset", mismatch.replace("use --sensor ", "use sensor.preset: ")
                                  + " (or give the sensor's keys without a preset)")
        return scene
    except ConfigError as exc:
        if source and exc.source is None:
            raise ConfigError(exc.key, exc.detail, source) from None
        raise


def load_scene(scene: str | os.PathLike | Mapping | Scene) -> Scene:
    """Load a scene from a YAML/JSON file, a dict of the same shape, or pass a Scene through.

    Raises
    ------
    ConfigError
        Unknown keys, wrong types or impossible values; the message names the key (and file).
    SonarsimError
        The file is missing or not valid YAML/JSON.
    """
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, Mapping):
        return scene_from_dict(scene)
    p = Path(scene)
    doc = read_document(p)
    if doc is None:
        raise ConfigError("", "the scene file is empty", str(p))
    return scene_from_dict(doc, base_dir=p.parent, source=str(p))
