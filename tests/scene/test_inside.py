"""A sonar inside a closed object is warned about (issue 21 item 3): once per object, when the
simulator is built and when a pose is rendered; open meshes and rooms never are."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import sonarsim
from sonarsim.scene.inside import InsideTest
from sonarsim.scene.meshes import TriangleMesh
from sonarsim.trace import make_caster

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30, "elevation_fov_deg": 14, "range_min_m": 0.5, "range_max_m": 5.0,
         "n_range_bins": 100}


def scene(position, **extra):
    return {"sonar": {**SONAR, "pose": {"position_m": list(position)}}, "render": {"elevation_samples": 8},
            "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 1.0, "pose": {"position_m": [3, 0, 0]}},
                        {"name": "block", "primitive": "box", "size_m": [1, 1, 1], "pose": {"position_m": [0, 4, 0]}}],
            **extra}


def inside_warnings(record) -> list[str]:
    return [str(w.message) for w in record if "lies inside the object" in str(w.message)]


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_a_sonar_inside_a_sphere_is_warned_about_once(backend):
    # Inside a sphere the image was empty, without a word.
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sim = sonarsim.Simulator(scene([3.2, 0.1, 0.0]), backend=backend)
        sim.render(pose={"position_m": [3.1, 0, 0]})  # still inside: said already
    (message,) = inside_warnings(record)
    assert "'ball'" in message and "[3.2, 0.1, 0.0]" in message and "\n" not in message
    assert record[0].filename == __file__  # points at the caller's line


def test_a_pose_rendered_inside_an_object_is_warned_about():
    sim = sonarsim.Simulator(scene([0, 0, 0]))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        sim.render()
        sim.render(pose={"position_m": [1.0, 0, 0]})
        assert not inside_warnings(record)
        sim.render(pose={"position_m": [0.2, 4.1, -0.3]})   # in the block
        sim.render(pose={"position_m": [3.0, 0.5, 0.5]})    # in the ball
        sim.render(pose={"position_m": [3.0, 0.4, 0.5]})    # still: said once
    said = inside_warnings(record)
    assert len(said) == 2 and "'block'" in said[0] and "'ball'" in said[1]


def test_outside_open_meshes_and_rooms_are_not_inside():
    def tm(m):
        return TriangleMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int32))

    sphere = tm(trimesh.creation.icosphere(3, radius=1.0))
    bowl = trimesh.creation.icosphere(3, radius=1.5)
    bowl = tm(trimesh.Trimesh(bowl.vertices, bowl.faces[bowl.triangles_center[:, 2] < 0], process=False))
    room = tm(trimesh.creation.box(extents=(10, 10, 10)))
    room = TriangleMesh(room.vertices, np.ascontiguousarray(room.faces[:, ::-1]))  # faces towards the inside
    box = tm(trimesh.creation.box(extents=(1, 1, 1)))
    meshes = [sphere, bowl, room, box]
    test = InsideTest(make_caster("embree", meshes), meshes, ["sphere", "bowl", "room", "box"])
    assert test.holding([0.0, 0.0, -0.3]) == ["sphere", "box"]   # the bowl around them is open above
    assert test.holding([0.0, 0.0, 0.9]) == ["sphere"]
    assert test.holding([3.0, 3.0, 3.0]) == []                    # in the room: meant to be
    assert test.holding([0.0, 0.0, 0.0], ignore=frozenset({"sphere"})) == ["box"]
    # Points inside and outside a box, as trimesh's own test says.
    points = np.random.default_rng(0).uniform(-0.7, 0.7, (200, 3))
    ours = [bool(InsideTest(make_caster("embree", [box]), [box], ["box"]).holding(p)) for p in points]
    assert ours == list(trimesh.creation.box(extents=(1, 1, 1)).contains(points))
