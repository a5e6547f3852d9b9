"""The ground is a plane with a name: one spec (``PlaneSpec``), ``ground:`` its shorthand in
scene files, ``ground_plane`` (and the earlier name ``GroundSpec``) in Python."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError
from sonarsim.config.examples import demo_scene_dict
from sonarsim.config.loader import load_scene
from sonarsim.config.materials import Material
from sonarsim.config.scene import PlaneSpec, Scene, TextureSpec, ground_plane, ground_section


def test_the_ground_is_the_plane_named_ground():
    g = ground_plane(-1.25, albedo=0.4, specular=0.7)
    assert isinstance(g, PlaneSpec) and g.name == "ground"
    assert g.point_m == (0.0, 0.0, -1.25) and g.normal == (0.0, 0.0, 1.0) and g.offset_m == -1.25
    assert g.height_m == -1.25 and (g.albedo, g.specular) == (0.4, 0.7)
    assert sonarsim.GroundSpec(-1.25, albedo=0.4, specular=0.7) == g  # the earlier name, the same spec
    assert ground_plane().albedo == 0.8  # the ground's default albedo, not the water surface's 0
    lambert = Material("lambert", mu=0.01)
    assert ground_plane(material=lambert).backscatter == lambert


def test_a_scene_file_ground_section_is_that_plane_and_is_written_back_as_a_section():
    doc = demo_scene_dict()
    doc["ground"] = {"height_m": -0.5, "albedo": 0.3, "specular": 0.9,
                     "texture": {"std_db": 2.0, "correlation_m": 1.5}}
    scene = load_scene(doc)
    assert scene.ground == ground_plane(-0.5, 0.3, 0.9, texture=TextureSpec(2.0, (1.5, 1.5)))
    assert scene.reflecting_planes[0] is scene.ground  # plane 0, surface id 0
    out = scene.to_dict()
    assert out["ground"] == {"height_m": -0.5, "albedo": 0.3, "specular": 0.9,
                             "texture": TextureSpec(2.0, (1.5, 1.5)).to_dict()}
    assert load_scene(out).ground == scene.ground
    assert ground_section(ground_plane(material=Material("lambert", mu=0.01))) == {
        "height_m": 0.0, "material": Material("lambert", mu=0.01).to_dict(), "specular": 1.0}


@pytest.mark.parametrize("kwargs, key", [
    ({"height_m": np.nan}, "ground.height_m"), ({"height_m": 2e6}, "ground.height_m"),
    ({"height_m": "low"}, "ground.height_m"), ({"albedo": 1.5}, "ground.albedo"),
    ({"specular": -0.1}, "ground.specular"),
    ({"albedo": 0.5, "material": Material("lambert", mu=0.01)}, "ground.albedo"),
])
def test_a_bad_ground_names_its_ground_key(kwargs, key):
    with pytest.raises(ConfigError) as e:
        ground_plane(**kwargs)
    assert e.value.key == key


def test_only_the_horizontal_plane_named_ground_is_a_scene_ground():
    scene = load_scene(demo_scene_dict())
    for bad in (PlaneSpec("floor", (0, 0, 0), (0, 0, 1)), PlaneSpec("ground", (0, 0, 0), (0.1, 0, 1)),
                PlaneSpec("ground", (0, 0, 2), (0, 0, -1))):
        with pytest.raises(ConfigError) as e:
            Scene(scene.sonar, scene.objects, ground=bad)
        assert e.value.key == "ground"
    with pytest.raises(AttributeError, match="not horizontal"):
        PlaneSpec("wall", (4, 0, 0), (-1, 0, 0)).height_m


def test_a_ground_given_as_a_plane_renders_as_the_ground_section():
    doc = demo_scene_dict()
    h = doc.get("ground", {}).get("height_m", 0.0)
    moved = copy.deepcopy(doc)
    g = load_scene(doc).ground
    moved.pop("ground")
    moved["planes"] = [g.to_dict()] + list(moved.get("planes", []))  # the same plane, in the planes list
    a = sonarsim.Simulator(doc).render(speckle=False, keep_rays=False)
    b = sonarsim.Simulator(moved).render(speckle=False, keep_rays=False)
    assert h == g.height_m
    np.testing.assert_array_equal(a.polar, b.polar)
    assert a.polar.any()
