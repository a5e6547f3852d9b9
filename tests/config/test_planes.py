"""Validation of the ``planes:`` list, ``render.max_order`` and ``render.bounces``.

Every bad document is the valid base with one edit; each error names the key
(``planes[1].normal``) as the rest of the loader does.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.cli.main import main

BASE = {
    "sonar": {"n_beams": 8, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
              "range_max_m": 4.0, "n_range_bins": 40,
              "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}},
    "render": {"elevation_samples": 8},
    "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
    "planes": [
        {"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0]},
        {"name": "wall", "point_m": [5.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.3, "specular": 0.8},
    ],
    "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                 "pose": {"position_m": [2.5, 0.0, 0.2]}}],
}


def with_plane(index, **edit):
    doc = copy.deepcopy(BASE)
    for key, value in edit.items():
        if value is DELETE:
            del doc["planes"][index][key]
        else:
            doc["planes"][index][key] = value
    return doc


DELETE = object()

BAD_PLANES = [
    ("zero normal", dict(normal=[0.0, 0.0, 0.0]), "planes[1].normal", "zero vector"),
    ("nan normal", dict(normal=[0.0, math.nan, 1.0]), "planes[1].normal[1]", "finite"),
    ("inf normal", dict(normal=[math.inf, 0.0, 1.0]), "planes[1].normal[0]", "finite"),
    ("short normal", dict(normal=[0.0, 1.0]), "planes[1].normal", "3 numbers"),
    ("text normal", dict(normal="up"), "planes[1].normal", "3 numbers"),
    ("nan point", dict(point_m=[math.nan, 0.0, 0.0]), "planes[1].point_m[0]", "finite"),
    ("inf point", dict(point_m=[0.0, 0.0, -math.inf]), "planes[1].point_m[2]", "finite"),
    ("far point", dict(point_m=[2e6, 0.0, 0.0]), "planes[1].point_m", "1e6 m"),
    ("bad name", dict(name="2walls"), "planes[1].name", "start with a letter"),
    ("dash in name", dict(name="far-wall"), "planes[1].name", "letters, digits and _"),
    ("reserved objects", dict(name="objects"), "planes[1].name", "not objects or O"),
    ("reserved O", dict(name="O"), "planes[1].name", "not objects or O"),
    ("name not text", dict(name=3), "planes[1].name", "non-empty string"),
    ("empty name", dict(name=""), "planes[1].name", "non-empty string"),
    ("duplicate name", dict(name="surface"), "planes[1].name", "duplicate plane name 'surface'"),
    ("ground beside ground:", dict(name="ground"), "planes[1].name", "the ground: section"),
    ("albedo above 1", dict(albedo=1.5), "planes[1].albedo", "[0, 1]"),
    ("albedo below 0", dict(albedo=-0.1), "planes[1].albedo", "[0, 1]"),
    ("specular above 1", dict(specular=1.01), "planes[1].specular", "[0, 1]"),
    ("specular nan", dict(specular=math.nan), "planes[1].specular", "finite"),
    ("specular text", dict(specular="high"), "planes[1].specular", "finite number"),
    ("albedo bool", dict(albedo=True), "planes[1].albedo", "finite number"),
    ("missing name", dict(name=DELETE), "planes[1].name", "required"),
    ("missing point", dict(point_m=DELETE), "planes[1].point_m", "required"),
    ("missing normal", dict(normal=DELETE), "planes[1].normal", "required"),
    ("unknown key", dict(height_m=1.0), "planes[1].height_m", "unknown key"),
]


@pytest.mark.parametrize("name, edit, key, text", BAD_PLANES, ids=[b[0] for b in BAD_PLANES])
def test_bad_plane_names_the_key(name, edit, key, text):
    with pytest.raises(ConfigError) as info:
        load_scene(with_plane(1, **edit))
    assert info.value.key == key
    assert str(info.value).startswith(f"{key}: ") and text in str(info.value)


@pytest.mark.parametrize("planes, key, text", [
    ({"name": "surface"}, "planes", "must be a list of planes"),
    ("surface", "planes", "must be a list of planes"),
    ([["surface", [0, 0, 2], [0, 0, -1]]], "planes[0]", "must be a mapping"),
    ([None], "planes[0]", "must be a mapping"),
])
def test_planes_must_be_a_list_of_mappings(planes, key, text):
    doc = copy.deepcopy(BASE)
    doc["planes"] = planes
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    assert info.value.key == key and text in str(info.value)


def test_plane_named_ground_without_a_ground_section_is_allowed():
    doc = copy.deepcopy(BASE)
    del doc["ground"]
    doc["planes"][1]["name"] = "ground"
    scene = load_scene(doc)
    assert [p.name for p in scene.reflecting_planes] == ["surface", "ground"]


def test_the_normal_is_normalised():
    scene = load_scene(with_plane(1, normal=[-3.0, 0.0, 4.0]))
    np.testing.assert_allclose(scene.planes[1].normal, [-0.6, 0.0, 0.8], rtol=0, atol=1e-15)
    assert scene.planes[1].offset_m == pytest.approx(-0.6 * 5.0)
    scene = load_scene(with_plane(1, normal=[0.0, 1e3, 0.0]))
    assert scene.planes[1].normal == (0.0, 1.0, 0.0)


def test_a_plane_round_trips_through_its_dict():
    scene = load_scene(BASE)
    again = load_scene(scene.to_dict())
    assert again.planes == scene.planes


@pytest.mark.parametrize("value, text", [
    (0, "from 1 to 9"), (10, "from 1 to 9"), (-1, "from 1 to 9"), (2.0, "must be an integer"),
    ("3", "must be an integer"), (True, "must be an integer"), (None, "must be an integer"),
])
def test_max_order_out_of_range_or_not_an_integer(value, text):
    doc = copy.deepcopy(BASE)
    doc["render"]["max_order"] = value
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    assert info.value.key == "render.max_order" and text in str(info.value)


@pytest.mark.parametrize("max_order, bounces, key", [
    (2, [1, 3], "render.bounces"), (3, [4], "render.bounces"), (1, [2], "render.bounces"),
    (3, [], "render.bounces"), (3, [0], "render.bounces"), (3, [1, "2"], "render.bounces[1]"),
    (3, "1,2", "render.bounces"),
])
def test_bounces_beyond_max_order(max_order, bounces, key):
    doc = copy.deepcopy(BASE)
    doc["render"].update(max_order=max_order, bounces=bounces)
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    assert info.value.key == key


def test_bounces_within_max_order():
    doc = copy.deepcopy(BASE)
    doc["render"].update(max_order=5, bounces=[5, 1, 1])
    assert load_scene(doc).render.bounces == (1, 5)
    doc["render"].update(max_order=4, bounces=None)
    assert load_scene(doc).render.bounces == (1, 2, 3, 4)


def test_the_cli_exits_2_without_a_traceback_on_a_bad_plane(tmp_path, capsys):
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(with_plane(1, normal=[0, 0, 0])))
    assert main(["render", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "planes[1].normal" in err and str(path) in err and "Traceback" not in err


@pytest.mark.parametrize("position", [[0.0, 0.0, 2.0], [5.0, 1.0, 1.0], [1.0, 1.0, 0.0]])
def test_a_sonar_on_a_plane_is_refused_at_render_time(position):
    doc = copy.deepcopy(BASE)
    doc["sonar"]["pose"]["position_m"] = position
    sim = sonarsim.Simulator(doc)
    with pytest.raises(ConfigError) as info:
        sim.render()
    assert info.value.key == "sonar.pose.position_m" and "lies on the plane" in str(info.value)
    with pytest.raises(ConfigError) as info:
        sonarsim.Simulator(BASE).render(pose={"position_m": position, "rpy_deg": [0, 20, 0]})
    assert info.value.key == "pose"


def test_a_sonar_just_off_a_plane_renders():
    sim = sonarsim.Simulator(BASE)
    image = sim.render(pose={"position_m": [0.0, 0.0, 2.0 - 1e-3], "rpy_deg": [0, 20, 0]})
    assert np.isfinite(image.polar).all()
