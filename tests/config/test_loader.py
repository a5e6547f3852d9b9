"""Validation of scene documents by :func:`sonarsim.load_scene`.

Every bad scene is a small modification of one valid base document; each must raise a
:class:`ConfigError` whose message names the offending key path and says what is allowed.
Files (scene YAML/JSON and meshes) must give errors that name the file.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim import ConfigError, SonarsimError, load_scene
from sonarsim.scene.meshes import object_mesh_world
from sonarsim.config.presets import PRESETS
from sonarsim.config.sonar import uniform_beam_angles_deg
from sonarsim.core.transforms import Pose

# --------------------------------------------------------------------------- the base scene

BASE: dict[str, Any] = {
    "sonar": {
        "n_beams": 16,
        "azimuth_fov_deg": 30.0,
        "elevation_fov_deg": 14.0,
        "range_min_m": 0.5,
        "range_max_m": 5.0,
        "n_range_bins": 100,
        "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]},
    },
    "render": {
        "elevation_samples": "auto", "azimuth_samples": 1, "tvg": True,
        "bounces": [1, 2, 3], "method": "fast", "seed": 0,
    },
    "ground": {"height_m": 0.0, "albedo": 0.8, "specular": 1.0},
    "objects": [
        {
            "name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.3],
            "pose": {"position_m": [2.5, 0.0, 0.15], "rpy_deg": [0, 0, 30]},
            "scale": 1.0, "albedo": 0.8,
        },
        {
            "name": "ball", "primitive": "sphere", "radius_m": 0.2,
            "pose": {"position_m": [3.0, 0.5, 0.2]}, "albedo": 0.5,
        },
        {
            "name": "drum", "primitive": "cylinder", "radius_m": 0.2, "height_m": 0.5,
            "pose": {"position_m": [3.5, -0.5, 0.25]},
        },
    ],
}

DELETE = object()  # sentinel: remove the key


def modified(*edits: tuple[tuple, Any]) -> dict:
    """A deep copy of BASE with each ``(path, value)`` edit applied (value DELETE removes)."""
    doc = copy.deepcopy(BASE)
    for path, value in edits:
        node: Any = doc
        for part in path[:-1]:
            node = node[part]
        if value is DELETE:
            del node[path[-1]]
        else:
            node[path[-1]] = value
    return doc


# Beam tables given explicitly instead of azimuth_fov_deg.
def _table(angles, n_beams=DELETE):
    return [(("sonar", "azimuth_fov_deg"), DELETE), (("sonar", "beam_angles_deg"), angles),
            (("sonar", "n_beams"), n_beams)]


def _resolution(res):
    return [(("sonar", "n_range_bins"), DELETE), (("sonar", "range_resolution_m"), res)]


# (id, edits, expected key, fragments of the message that say what is allowed)
BAD_SCENES: list = [
    # ---- unknown keys at every level
    ("unknown-top", [(("bogus",), 1)], "bogus", ["unknown key", "sonar, render, ground, planes, objects"]),
    ("unknown-sonar", [(("sonar", "bogus"), 1)], "sonar.bogus", ["unknown key", "range_max_m", "n_beams"]),
    ("unknown-sonar-pose", [(("sonar", "pose", "bogus"), 1)], "sonar.pose.bogus",
     ["unknown key", "position_m", "rpy_deg", "quat_xyzw"]),
    ("unknown-object-pose", [(("objects", 0, "pose", "rpy"), [0, 0, 0])], "objects[0].pose.rpy",
     ["unknown key", "rpy_deg"]),
    ("unknown-render", [(("render", "bogus"), 1)], "render.bogus", ["unknown key", "bounces", "method"]),
    ("unknown-ground", [(("ground", "bogus"), 1)], "ground.bogus", ["unknown key", "albedo", "specular"]),
    ("unknown-object", [(("objects", 1, "bogus"), 1)], "objects[1].bogus",
     ["unknown key", "primitive", "albedo"]),
    ("missing-sonar", [(("sonar",), DELETE)], "sonar", ["required"]),
    ("missing-range-min", [(("sonar", "range_min_m"), DELETE)], "sonar.range_min_m", ["required"]),
    # ---- wrong types: string for a number
    ("str-range-max", [(("sonar", "range_max_m"), "5")], "sonar.range_max_m", ["number"]),
    ("str-object-albedo", [(("objects", 1, "albedo"), "0.5")], "objects[1].albedo", ["number"]),
    ("str-ground-height", [(("ground", "height_m"), "0")], "ground.height_m", ["number"]),
    ("str-scale", [(("objects", 0, "scale"), "2")], "objects[0].scale", ["number"]),
    ("str-n-beams", [(("sonar", "n_beams"), "16")], "sonar.n_beams", ["integer"]),
    ("str-method", [(("render", "method"), 3)], "render.method", ["string"]),
    # ---- bool for an int / number, float for an int
    ("bool-n-beams", [(("sonar", "n_beams"), True)], "sonar.n_beams", ["integer"]),
    ("bool-n-range-bins", [(("sonar", "n_range_bins"), True)], "sonar.n_range_bins", ["integer"]),
    ("bool-azimuth-samples", [(("render", "azimuth_samples"), True)], "render.azimuth_samples", ["integer"]),
    ("bool-range-max", [(("sonar", "range_max_m"), True)], "sonar.range_max_m", ["number"]),
    ("bool-bounce", [(("render", "bounces"), [True])], "render.bounces[0]", ["integer"]),
    ("float-n-range-bins", [(("sonar", "n_range_bins"), 100.0)], "sonar.n_range_bins", ["integer"]),
    ("float-seed", [(("render", "seed"), 1.5)], "render.seed", ["integer"]),
    ("int-tvg", [(("render", "tvg"), 1)], "render.tvg", ["true or false"]),
    ("nan-range-max", [(("sonar", "range_max_m"), float("nan"))], "sonar.range_max_m", ["finite number"]),
    ("inf-range-max", [(("sonar", "range_max_m"), float("inf"))], "sonar.range_max_m", ["finite number"]),
    # ---- lists of the wrong length
    ("short-position", [(("sonar", "pose", "position_m"), [0.0, 0.0])], "sonar.pose.position_m",
     ["list of 3 numbers"]),
    ("short-rpy", [(("sonar", "pose", "rpy_deg"), [0.0, 20.0])], "sonar.pose.rpy_deg", ["list of 3 numbers"]),
    ("long-rpy", [(("sonar", "pose", "rpy_deg"), [0, 0, 0, 0])], "sonar.pose.rpy_deg", ["list of 3 numbers"]),
    ("short-size", [(("objects", 0, "size_m"), [0.5, 0.5])], "objects[0].size_m", ["list of 3 numbers"]),
    ("short-quat", [(("sonar", "pose", "rpy_deg"), DELETE), (("sonar", "pose", "quat_xyzw"), [0, 0, 1])],
     "sonar.pose.quat_xyzw", ["list of 4 numbers"]),
    ("scale-two", [(("objects", 0, "scale"), [1.0, 1.0])], "objects[0].scale", ["list of 3 numbers"]),
    ("str-in-position", [(("sonar", "pose", "position_m"), [0, "0", 1])], "sonar.pose.position_m[1]", ["number"]),
    # ---- mapping where a list is expected (and the reverse)
    ("map-rpy", [(("sonar", "pose", "rpy_deg"), {"pitch": 20})], "sonar.pose.rpy_deg", ["list of 3 numbers"]),
    ("map-size", [(("objects", 0, "size_m"), {"x": 1})], "objects[0].size_m", ["list of 3 numbers"]),
    ("map-bounces", [(("render", "bounces"), {"a": 1})], "render.bounces", ["list", "path orders"]),
    ("str-bounces", [(("render", "bounces"), "1,2")], "render.bounces", ["list", "path orders"]),
    ("map-objects", [(("objects",), {"name": "x"})], "objects", ["list"]),
    ("map-beam-angles", _table({"a": 1}), "sonar.beam_angles_deg", ["list of numbers"]),
    ("list-pose", [(("sonar", "pose"), [0.0, 0.0, 1.0])], "sonar.pose", ["mapping", "position_m", "rpy_deg"]),
    ("list-sonar", [(("sonar",), [1, 2])], "sonar", ["mapping", "range_max_m"]),
    ("list-render", [(("render",), [1])], "render", ["mapping", "bounces"]),
    ("list-ground", [(("ground",), [0.0])], "ground", ["mapping", "specular"]),
    ("str-object", [(("objects", 2), "cylinder")], "objects[2]", ["mapping", "primitive"]),
    # ---- range window
    ("negative-range-min", [(("sonar", "range_min_m"), -0.1)], "sonar.range_min_m", [">= 0"]),
    ("range-max-equals-min", [(("sonar", "range_max_m"), 0.5)], "sonar.range_max_m",
     ["greater than range_min_m"]),
    ("range-max-below-min", [(("sonar", "range_max_m"), 0.2)], "sonar.range_max_m",
     ["greater than range_min_m"]),
    # ---- fields of view
    ("azimuth-180", [(("sonar", "azimuth_fov_deg"), 180.0)], "sonar.azimuth_fov_deg", ["[0.01, 180)"]),
    ("azimuth-200", [(("sonar", "azimuth_fov_deg"), 200.0)], "sonar.azimuth_fov_deg", ["[0.01, 180)"]),
    ("azimuth-0", [(("sonar", "azimuth_fov_deg"), 0.0)], "sonar.azimuth_fov_deg", ["[0.01, 180)"]),
    ("azimuth-table-too-wide", _table([89.5, 0.0, -89.5]), "sonar.azimuth_fov_deg", ["below 180"]),
    ("elevation-0", [(("sonar", "elevation_fov_deg"), 0.0)], "sonar.elevation_fov_deg", ["[0.01, 180)"]),
    ("elevation-negative", [(("sonar", "elevation_fov_deg"), -5.0)], "sonar.elevation_fov_deg", ["[0.01, 180)"]),
    ("elevation-180", [(("sonar", "elevation_fov_deg"), 180.0)], "sonar.elevation_fov_deg", ["[0.01, 180)"]),
    ("beam-width-0", [(("sonar", "beam_width_deg"), 0.0)], "sonar.beam_width_deg", ["[0.01, 90)"]),
    # ---- albedo / specular in [0, 1]
    ("object-albedo-high", [(("objects", 1, "albedo"), 1.5)], "objects[1].albedo", ["[0, 1]"]),
    ("object-albedo-negative", [(("objects", 0, "albedo"), -0.1)], "objects[0].albedo", ["[0, 1]"]),
    ("ground-albedo-high", [(("ground", "albedo"), 1.2)], "ground.albedo", ["[0, 1]"]),
    ("ground-albedo-negative", [(("ground", "albedo"), -0.01)], "ground.albedo", ["[0, 1]"]),
    ("specular-high", [(("ground", "specular"), 1.01)], "ground.specular", ["[0, 1]"]),
    ("specular-negative", [(("ground", "specular"), -0.5)], "ground.specular", ["[0, 1]"]),
    # ---- range bins and resolution
    ("n-range-bins-0", [(("sonar", "n_range_bins"), 0)], "sonar.n_range_bins", ["at least 1"]),
    ("n-range-bins-negative", [(("sonar", "n_range_bins"), -5)], "sonar.n_range_bins", ["at least 1"]),
    ("range-resolution-0", _resolution(0.0), "sonar.range_resolution_m", ["> 0"]),
    ("range-resolution-negative", _resolution(-0.01), "sonar.range_resolution_m", ["> 0"]),
    ("bins-and-resolution", [(("sonar", "range_resolution_m"), 0.01)], "sonar.range_resolution_m",
     ["n_range_bins", "not both"]),
    # ---- beams
    ("n-beams-0", [(("sonar", "n_beams"), 0)], "sonar.n_beams", ["positive integer"]),
    ("n-beams-negative", [(("sonar", "n_beams"), -3)], "sonar.n_beams", ["positive integer"]),
    ("beam-angles-ascending", _table([-1.0, 0.0, 1.0]), "sonar.beam_angles_deg", ["descending"]),
    ("beam-angles-repeated", _table([1.0, 1.0, -1.0]), "sonar.beam_angles_deg", ["descending"]),
    ("beam-angles-empty", _table([]), "sonar.n_beams", ["at least 1"]),
    ("n-beams-mismatch", _table([1.0, 0.0, -1.0], n_beams=4), "sonar.n_beams", ["3 angles"]),
    # ---- pose
    ("rpy-and-quat", [(("sonar", "pose", "quat_xyzw"), [0.0, 0.0, 0.0, 1.0])], "sonar.pose.quat_xyzw",
     ["rpy_deg", "not both"]),
    ("object-rpy-and-quat", [(("objects", 0, "pose", "quat_xyzw"), [0.0, 0.0, 0.0, 1.0])],
     "objects[0].pose.quat_xyzw", ["rpy_deg", "not both"]),
    ("zero-quat", [(("sonar", "pose", "rpy_deg"), DELETE), (("sonar", "pose", "quat_xyzw"), [0, 0, 0, 0])],
     "sonar.pose.quat_xyzw", ["zero quaternion"]),
    # ---- objects
    ("unknown-primitive", [(("objects", 1, "primitive"), "cone")], "objects[1].primitive",
     ["box, sphere, cylinder"]),
    ("box-without-size", [(("objects", 0, "size_m"), DELETE)], "objects[0].size_m", ["required", "box"]),
    ("sphere-with-size", [(("objects", 1, "size_m"), [1.0, 1.0, 1.0])], "objects[1].size_m",
     ["not used", "sphere", "radius_m"]),
    ("cylinder-without-height", [(("objects", 2, "height_m"), DELETE)], "objects[2].height_m",
     ["required", "cylinder"]),
    ("neither-primitive-nor-mesh", [(("objects", 0, "primitive"), DELETE)], "objects[0].primitive",
     ["`primitive` or `mesh`"]),
    ("zero-radius", [(("objects", 1, "radius_m"), 0.0)], "objects[1].radius_m", ["within [1e-06, 10000] metres"]),
    ("zero-size", [(("objects", 0, "size_m"), [0.5, 0.0, 0.3])], "objects[0].size_m", ["within [1e-06, 10000]"]),
    ("negative-scale", [(("objects", 0, "scale"), -1.0)], "objects[0].scale", ["within [1e-06, 10000]"]),
    ("duplicate-names", [(("objects", 2, "name"), "block")], "objects[2].name", ["duplicate", "unique"]),
    ("empty-name", [(("objects", 1, "name"), "")], "objects[1].name", ["non-empty string"]),
    # ---- presets
    ("unknown-preset", [(("sonar", "preset"), "aris9000")], "sonar.preset",
     ["unknown preset", "aris3000-128", "gemini-720i"]),
    ("non-string-preset", [(("sonar", "preset"), 5)], "sonar.preset", ["string"]),
    # ---- render
    ("unknown-method", [(("render", "method"), "slow")], "render.method", ["fast, paper"]),
    ("unknown-beam-pattern", [(("render", "beam_pattern"), "square")], "render.beam_pattern",
     ["uniform, gaussian"]),
    ("bounces-4", [(("render", "bounces"), [4])], "render.bounces", ["[1, 2, 3]"]),
    ("bounces-0", [(("render", "bounces"), [0, 1])], "render.bounces", ["[1, 2, 3]"]),
    ("bounces-empty", [(("render", "bounces"), [])], "render.bounces", ["non-empty", "[1, 2, 3]"]),
    ("bounces-str-item", [(("render", "bounces"), [1, "2"])], "render.bounces[1]", ["integer"]),
    ("elevation-samples-0", [(("render", "elevation_samples"), 0)], "render.elevation_samples",
     ["'auto' or a positive integer"]),
    ("azimuth-samples-0", [(("render", "azimuth_samples"), 0)], "render.azimuth_samples", ["positive integer"]),
    ("threads-0", [(("render", "threads"), 0)], "render.threads", ["from 1 to 256"]),
    ("unknown-double-beam", [(("render", "double_beam"), "both")], "render.double_beam", ["paper, split"]),
    ("int-double-line-of-sight", [(("render", "double_line_of_sight"), 1)], "render.double_line_of_sight",
     ["true or false"]),
    pytest.param(
        "elevation-samples-str", [(("render", "elevation_samples"), "many")], "render.elevation_samples",
        ["auto"],
    ),
]


def _id(case) -> str:
    return case.values[0] if hasattr(case, "values") else case[0]


def test_base_scene_is_valid() -> None:
    scene = load_scene(copy.deepcopy(BASE))
    assert scene.sonar.n_beams == 16
    assert scene.sonar.n_range_bins == 100
    assert scene.sonar.azimuth_fov_deg == pytest.approx(30.0)
    assert [o.name for o in scene.objects] == ["block", "ball", "drum"]
    assert scene.ground is not None and scene.ground.specular == 1.0
    assert scene.render.bounces == (1, 2, 3)


def test_bad_scene_ids_are_unique() -> None:
    ids = [_id(c) for c in BAD_SCENES]
    assert len(ids) == len(set(ids))


@pytest.mark.parametrize("name, edits, key, allowed", BAD_SCENES, ids=[_id(c) for c in BAD_SCENES])
def test_bad_scene_names_key_and_what_is_allowed(name, edits, key, allowed) -> None:
    doc = modified(*edits)
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    exc = info.value
    assert isinstance(exc, SonarsimError) and isinstance(exc, ValueError)
    message = str(exc)
    assert exc.key == key, message
    assert message.startswith(f"{key}: "), message
    for fragment in allowed:
        assert fragment in message, f"{fragment!r} not in {message!r}"


@pytest.mark.parametrize("name, edits, key, allowed", BAD_SCENES[:12], ids=[_id(c) for c in BAD_SCENES[:12]])
def test_bad_scene_in_a_file_names_file_and_key(tmp_path: Path, name, edits, key, allowed) -> None:
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(modified(*edits)))
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert info.value.key == key
    assert str(path) in str(info.value)
    assert f"{key}: " in str(info.value)


def test_bad_scene_does_not_modify_the_input() -> None:
    doc = modified((("objects", 1, "albedo"), 2.0))
    before = copy.deepcopy(doc)
    with pytest.raises(ConfigError):
        load_scene(doc)
    assert doc == before


# --------------------------------------------------------------------------- valid inputs: presets


def test_preset_with_n_range_bins_override() -> None:
    sonar = load_scene({"sonar": {"preset": "aris3000-128", "n_range_bins": 500}}).sonar
    assert sonar.n_range_bins == 500
    assert sonar.n_beams == 128
    assert sonar.preset == "aris3000-128"
    # The other preset keys are kept.
    preset = PRESETS["aris3000-128"].sonar
    assert sonar.range_min_m == preset["range_min_m"]
    assert sonar.range_max_m == preset["range_max_m"]
    assert sonar.elevation_fov_deg == preset["elevation_fov_deg"]
    np.testing.assert_allclose(sonar.beam_angles_deg, preset["beam_angles_deg"])


def test_preset_with_azimuth_fov_override_gives_uniform_beams() -> None:
    sonar = load_scene({"sonar": {"preset": "aris3000-128", "azimuth_fov_deg": 20}}).sonar
    assert sonar.n_beams == 128
    assert sonar.azimuth_fov_deg == pytest.approx(20.0)
    np.testing.assert_allclose(np.diff(sonar.azimuth_deg), -20.0 / 128)
    j = np.arange(128)
    np.testing.assert_allclose(sonar.azimuth_deg, 10.0 - (j + 0.5) * 20.0 / 128)
    assert sonar.n_range_bins == 1288


def test_preset_with_n_beams_override_keeps_the_fan() -> None:
    preset = load_scene({"sonar": {"preset": "aris3000-128"}}).sonar
    sonar = load_scene({"sonar": {"preset": "aris3000-128", "n_beams": 64}}).sonar
    assert sonar.n_beams == 64
    assert sonar.azimuth_fov_deg == pytest.approx(preset.azimuth_fov_deg)
    np.testing.assert_allclose(sonar.azimuth_deg, uniform_beam_angles_deg(64, preset.azimuth_fov_deg))


def test_preset_with_uniform_fan_and_n_beams_override() -> None:
    sonar = load_scene({"sonar": {"preset": "didson300", "n_beams": 10}}).sonar
    assert sonar.n_beams == 10
    assert sonar.azimuth_fov_deg == pytest.approx(PRESETS["didson300"].sonar["azimuth_fov_deg"])


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_loads_alone(name: str) -> None:
    sonar = load_scene({"sonar": {"preset": name}}).sonar
    assert sonar.preset == name
    assert sonar.n_beams == PRESETS[name].sonar["n_beams"]


@pytest.mark.parametrize("preset", ["aris3000-128", "didson300"])
def test_preset_with_own_beam_table(preset: str) -> None:
    sonar = load_scene({"sonar": {"preset": preset, "beam_angles_deg": [1.0, 0.0, -1.0]}}).sonar
    assert sonar.beam_angles_deg == (1.0, 0.0, -1.0)
    assert sonar.n_beams == 3


def test_azimuth_fov_and_beam_angles_together_are_rejected() -> None:
    doc = modified((("sonar", "n_beams"), DELETE), (("sonar", "beam_angles_deg"), [1.0, 0.0, -1.0]))
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    assert info.value.key in ("sonar.azimuth_fov_deg", "sonar.beam_angles_deg")
    assert "not both" in str(info.value)


def test_explicit_beam_table() -> None:
    sonar = load_scene(modified(*_table([10.0, 0.0, -10.0], n_beams=3))).sonar
    assert sonar.beam_angles_deg == (10.0, 0.0, -10.0)
    assert sonar.azimuth_fov_deg == pytest.approx(30.0)


# --------------------------------------------------------------------------- range resolution


@pytest.mark.parametrize(
    "r_min, r_max, res",
    [(0.5, 5.0, 0.01), (0.5, 5.0, 0.007), (1.0, 2.0, 0.3), (0.0, 10.0, 0.0125), (0.5, 5.0, 2.25)],
)
def test_range_resolution_gives_rounded_bin_count(r_min: float, r_max: float, res: float) -> None:
    # A resolution coarser than half the window is refused (issue 21; tests/config/test_hostile_documents.py).
    doc = modified(*_resolution(res), (("sonar", "range_min_m"), r_min), (("sonar", "range_max_m"), r_max))
    sonar = load_scene(doc).sonar
    assert sonar.n_range_bins == max(2, round((r_max - r_min) / res))
    assert sonar.range_edges_m[0] == pytest.approx(r_min)
    assert sonar.range_edges_m[-1] == pytest.approx(r_max)


def test_range_resolution_with_preset() -> None:
    sonar = load_scene({"sonar": {"preset": "aris3000-128", "range_resolution_m": 0.01}}).sonar
    assert sonar.n_range_bins == round((5.0 - 0.7) / 0.01) == 430


# --------------------------------------------------------------------------- poses


def _quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _quat_from_rpy_deg(roll, pitch, yaw):
    """q = qz(yaw) * qy(pitch) * qx(roll), (x, y, z, w) order -- independent of sonarsim."""
    r, p, y = (math.radians(v) / 2 for v in (roll, pitch, yaw))
    qx = (math.sin(r), 0.0, 0.0, math.cos(r))
    qy = (0.0, math.sin(p), 0.0, math.cos(p))
    qz = (0.0, 0.0, math.sin(y), math.cos(y))
    return _quat_mul(qz, _quat_mul(qy, qx))


def _sonar_rotation(pose: dict) -> np.ndarray:
    return load_scene(modified((("sonar", "pose"), pose))).sonar_pose.rotation


def test_quaternion_pitch_matches_rpy() -> None:
    h = math.radians(10.0)
    q = [0.0, math.sin(h), 0.0, math.cos(h)]
    r_quat = _sonar_rotation({"position_m": [0, 0, 1], "quat_xyzw": q})
    r_rpy = _sonar_rotation({"position_m": [0, 0, 1], "rpy_deg": [0.0, 20.0, 0.0]})
    np.testing.assert_allclose(r_quat, r_rpy, atol=1e-12)
    s = load_scene(modified((("sonar", "pose"), {"quat_xyzw": q}))).sonar_pose
    assert s.rpy_deg == pytest.approx((0.0, 20.0, 0.0), abs=1e-9)


@pytest.mark.parametrize("rpy", [(10.0, -25.0, 40.0), (-30.0, 5.0, 170.0), (0.0, 0.0, -90.0), (45.0, 0.0, 0.0)])
def test_quaternion_matches_rpy_general(rpy) -> None:
    q = _quat_from_rpy_deg(*rpy)
    r_quat = _sonar_rotation({"quat_xyzw": list(q)})
    r_rpy = _sonar_rotation({"rpy_deg": list(rpy)})
    np.testing.assert_allclose(r_quat, r_rpy, atol=1e-12)
    # A non-unit quaternion is normalised; -q is the same rotation.
    np.testing.assert_allclose(_sonar_rotation({"quat_xyzw": [3 * v for v in q]}), r_rpy, atol=1e-12)
    np.testing.assert_allclose(_sonar_rotation({"quat_xyzw": [-v for v in q]}), r_rpy, atol=1e-12)
    assert np.allclose(r_rpy @ r_rpy.T, np.eye(3)) and np.linalg.det(r_rpy) == pytest.approx(1.0)


def test_object_pose_quaternion() -> None:
    q = _quat_from_rpy_deg(0.0, 0.0, 30.0)
    scene = load_scene(modified((("objects", 0, "pose"), {"position_m": [2.5, 0, 0.15], "quat_xyzw": list(q)})))
    np.testing.assert_allclose(scene.objects[0].pose.rotation, load_scene(BASE).objects[0].pose.rotation, atol=1e-12)


@pytest.mark.parametrize("pitch", [5.0, 20.0, 45.0, 80.0])
def test_positive_pitch_turns_x_axis_down(pitch: float) -> None:
    r = _sonar_rotation({"rpy_deg": [0.0, pitch, 0.0]})
    axis = r @ np.array([1.0, 0.0, 0.0])
    assert axis[2] < 0
    np.testing.assert_allclose(axis, [math.cos(math.radians(pitch)), 0.0, -math.sin(math.radians(pitch))], atol=1e-12)
    # The same through the quaternion form.
    h = math.radians(pitch) / 2
    rq = _sonar_rotation({"quat_xyzw": [0.0, math.sin(h), 0.0, math.cos(h)]})
    assert (rq @ np.array([1.0, 0.0, 0.0]))[2] < 0


def test_positive_yaw_turns_x_axis_left() -> None:
    axis = _sonar_rotation({"rpy_deg": [0.0, 0.0, 30.0]}) @ np.array([1.0, 0.0, 0.0])
    assert axis[1] > 0 and axis[2] == pytest.approx(0.0)


def test_missing_pose_parts_default_to_zero() -> None:
    pose = load_scene(modified((("sonar", "pose"), {}))).sonar_pose
    assert pose.position_m == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(pose.rotation, np.eye(3))
    doc = modified()
    del doc["sonar"]["pose"]
    assert load_scene(doc).sonar_pose == Pose()


def test_the_sonar_config_is_the_intrinsics_alone_and_hashable() -> None:
    from dataclasses import fields

    from sonarsim.config.sonar import SonarConfig

    assert "pose" not in {f.name for f in fields(SonarConfig)} and not hasattr(SonarConfig, "with_pose")
    with pytest.raises(TypeError):
        SonarConfig.uniform(8, 20.0, 14.0, 0.5, 5.0, 100, pose=Pose())
    here = load_scene(BASE)
    there = load_scene(modified((("sonar", "pose"), {"position_m": [1.0, 2.0, 0.5], "rpy_deg": [5.0, 10.0, 15.0]})))
    # The same intrinsics at two poses: one key, one hash (the renderer's ray fans share it).
    assert here.sonar == there.sonar and hash(here.sonar) == hash(there.sonar)
    assert here.sonar_pose != there.sonar_pose
    assert "pose" not in here.sonar.to_dict()
    assert {here.sonar: 1}[there.sonar] == 1
    other = load_scene(modified((("sonar", "elevation_fov_deg"), 20.0))).sonar
    assert other != here.sonar and len({here.sonar, there.sonar, other}) == 2


@pytest.mark.parametrize("pose", [
    {"position_m": [0.5, -1.0, 1.25], "rpy_deg": [3.0, 27.5, -40.0]},
    {"position_m": [0.0, 0.0, 2.0], "quat_xyzw": [0.1, 0.2, -0.3, 0.9]},
])
def test_scene_to_dict_round_trips_the_sonar_pose(pose) -> None:
    from sonarsim.config.loader import scene_from_dict

    scene = load_scene(modified((("sonar", "pose"), pose)))
    d = scene.to_dict()
    # Written inside the sonar section, where scene files have it.
    assert list(d["sonar"])[:6] == ["beam_angles_deg", "elevation_fov_deg", "range_min_m", "range_max_m",
                                   "n_range_bins", "pose"]
    assert d["sonar"]["pose"] == scene.sonar_pose.to_dict()
    again = scene_from_dict(json.loads(json.dumps(d)))
    assert again.sonar == scene.sonar
    np.testing.assert_allclose(again.sonar_pose.matrix(), scene.sonar_pose.matrix(), atol=1e-12)
    if "rpy_deg" in pose:  # given as roll-pitch-yaw: written back exactly
        assert again.sonar_pose == scene.sonar_pose
    assert again.to_dict() == json.loads(json.dumps(d))


def test_scene_with_pose_moves_the_sonar_only() -> None:
    scene = load_scene(BASE)
    pose = Pose((1.0, 0.0, 0.5), (0.0, 10.0, 0.0))
    moved = scene.with_pose(pose)
    assert moved.sonar_pose == pose and moved.sonar is scene.sonar
    assert moved.objects == scene.objects and moved.render == scene.render and moved.ground == scene.ground
    assert scene.sonar_pose == Pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))  # unchanged
    assert moved.to_dict()["sonar"]["pose"] == {"position_m": [1.0, 0.0, 0.5], "rpy_deg": [0.0, 10.0, 0.0]}


def test_optional_sections() -> None:
    scene = load_scene({"sonar": copy.deepcopy(BASE["sonar"])})
    assert scene.ground is None and scene.objects == ()
    assert scene.render == sonarsim.RenderSettings()
    assert load_scene({"sonar": copy.deepcopy(BASE["sonar"]), "objects": None}).objects == ()
    assert load_scene(modified((("render", "bounces"), 2))).render.bounces == (2,)
    assert load_scene(modified((("render", "bounces"), [3, 1, 1]))).render.bounces == (1, 3)


# --------------------------------------------------------------------------- scene files


def test_yaml_and_json_files_give_the_same_scene(tmp_path: Path) -> None:
    y = tmp_path / "scene.yaml"
    j = tmp_path / "scene.json"
    y.write_text(yaml.safe_dump(BASE))
    j.write_text(json.dumps(BASE, indent=2))
    sy, sj, sd = load_scene(y), load_scene(j), load_scene(copy.deepcopy(BASE))
    assert sy.to_dict() == sj.to_dict() == sd.to_dict()
    assert sy.source == str(y) and sj.source == str(j)
    # str and Path both work.
    assert load_scene(str(y)).to_dict() == sd.to_dict()


def test_invalid_yaml_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("sonar:\n  preset: aris3000-128\n   range_max_m: 3.0\n")
    with pytest.raises(SonarsimError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message
    assert "line 3" in message
    assert "YAML" in message


def test_invalid_yaml_tab_names_line(tmp_path: Path) -> None:
    path = tmp_path / "tab.yml"
    path.write_text("sonar:\n  preset: aris3000-128\nrender:\n\tmethod: fast\n")
    with pytest.raises(SonarsimError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and "line 4" in str(info.value)


def test_invalid_json_names_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{\n  "sonar": {\n    "preset": "aris3000-128",\n  }\n}\n')
    with pytest.raises(SonarsimError) as info:
        load_scene(path)
    message = str(info.value)
    assert str(path) in message
    assert "line 4" in message
    assert "JSON" in message


@pytest.mark.parametrize("name, text", [("empty.yaml", ""), ("comments.yaml", "# nothing here\n\n"),
                                        ("empty.json", ""), ("blank.json", "  \n")])
def test_empty_scene_file(tmp_path: Path, name: str, text: str) -> None:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(SonarsimError) as info:
        load_scene(path)
    assert str(path) in str(info.value)


def test_empty_yaml_file_says_empty(tmp_path: Path) -> None:
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(ConfigError, match="empty") as info:
        load_scene(path)
    assert info.value.source == str(path)


def test_missing_scene_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "scene.yaml"
    with pytest.raises(SonarsimError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and "not found" in str(info.value)


def test_scene_file_that_is_a_folder(tmp_path: Path) -> None:
    with pytest.raises(SonarsimError) as info:
        load_scene(tmp_path)
    assert str(tmp_path) in str(info.value)


@pytest.mark.parametrize("text", ["- 1\n- 2\n", "just a string\n", "42\n"])
def test_scene_file_that_is_not_a_mapping(tmp_path: Path, text: str) -> None:
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert str(path) in str(info.value)
    assert "mapping" in str(info.value) and "sonar" in str(info.value)


def test_json_file_error_names_file_and_key(tmp_path: Path) -> None:
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(modified((("ground", "specular"), 3.0))))
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert info.value.key == "ground.specular"
    assert info.value.source == str(path)
    assert str(info.value) == f"{path}: ground.specular: {info.value.detail}"


# --------------------------------------------------------------------------- meshes

TETRAHEDRON_OBJ = """\
# a unit right tetrahedron, outward-facing triangles
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
"""


def _mesh_scene(mesh: str) -> dict:
    return modified((("objects",), [{"name": "thing", "mesh": mesh, "pose": {"position_m": [2.0, 0.0, 0.0]}}]))


def _bad_mesh(tmp_path: Path, kind: str) -> Path:
    if kind == "missing":
        return tmp_path / "missing.obj"
    if kind == "empty":
        p = tmp_path / "empty.stl"
        p.write_bytes(b"")
    elif kind == "text":
        p = tmp_path / "notes.stl"
        rng = np.random.default_rng(1)
        words = ["".join(rng.choice(list("abcdefghij klmnop\n"), size=40)) for _ in range(30)]
        p.write_text("\n".join(words))
    elif kind == "no-faces":
        p = tmp_path / "points.obj"
        p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n")
    elif kind == "folder":
        p = tmp_path / "folder.obj"
        p.mkdir()
    else:  # pragma: no cover
        raise AssertionError(kind)
    return p


@pytest.mark.parametrize("kind", ["missing", "empty", "text", "no-faces", "folder"])
def test_bad_mesh_file_names_file_and_key(tmp_path: Path, kind: str) -> None:
    path = _bad_mesh(tmp_path, kind)
    with pytest.raises(ConfigError) as info:
        load_scene(_mesh_scene(str(path)))
    assert info.value.key == "objects[0].mesh"
    assert str(info.value).startswith("objects[0].mesh: ")
    assert path.name in str(info.value)


@pytest.mark.parametrize("kind", ["missing", "empty", "text", "no-faces"])
def test_bad_mesh_in_scene_file_names_both_files(tmp_path: Path, kind: str) -> None:
    path = _bad_mesh(tmp_path, kind)
    scene_path = tmp_path / "scene.yaml"
    scene_path.write_text(yaml.safe_dump(_mesh_scene(path.name)))
    with pytest.raises(ConfigError) as info:
        load_scene(scene_path)
    message = str(info.value)
    assert info.value.key == "objects[0].mesh"
    assert str(scene_path) in message and str(path) in message


def test_valid_obj_mesh_loads(tmp_path: Path) -> None:
    path = tmp_path / "tet.obj"
    path.write_text(TETRAHEDRON_OBJ)
    scene = load_scene(_mesh_scene(str(path)))
    obj = scene.objects[0]
    assert obj.primitive is None and Path(obj.mesh) == path
    mesh = object_mesh_world(obj)
    assert mesh.faces.shape == (4, 3) and mesh.vertices.shape == (4, 3)
    np.testing.assert_allclose(mesh.vertices.min(axis=0), [2.0, 0.0, 0.0])
    np.testing.assert_allclose(mesh.vertices.max(axis=0), [3.0, 1.0, 1.0])


def test_relative_mesh_path_resolves_against_scene_folder(tmp_path: Path, monkeypatch) -> None:
    scenes = tmp_path / "scenes"
    (scenes / "meshes").mkdir(parents=True)
    (scenes / "meshes" / "tet.obj").write_text(TETRAHEDRON_OBJ)
    scene_path = scenes / "scene.yaml"
    scene_path.write_text(yaml.safe_dump(_mesh_scene("meshes/tet.obj")))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    scene = load_scene(scene_path)
    assert Path(scene.objects[0].mesh) == scenes / "meshes" / "tet.obj"
    assert object_mesh_world(scene.objects[0]).faces.shape == (4, 3)
    # A relative scene-file path works too.
    monkeypatch.chdir(tmp_path)
    assert Path(load_scene(Path("scenes/scene.yaml")).objects[0].mesh).resolve() == (scenes / "meshes" / "tet.obj")
    # The same relative path in a dict is relative to the working folder: not found here.
    with pytest.raises(ConfigError) as info:
        load_scene(_mesh_scene("meshes/tet.obj"))
    assert info.value.key == "objects[0].mesh"


def test_primitive_and_mesh_together(tmp_path: Path) -> None:
    path = tmp_path / "tet.obj"
    path.write_text(TETRAHEDRON_OBJ)
    with pytest.raises(ConfigError) as info:
        load_scene(modified((("objects", 0, "mesh"), str(path))))
    assert info.value.key == "objects[0].primitive"
    assert "exactly one of `primitive` or `mesh`" in str(info.value)
