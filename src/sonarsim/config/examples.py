"""The built-in scenes, in scene-file form: the demo tank (``sonarsim demo``, ``sonarsim
live-demo``) and the tank with a water surface and walls (the multipath demo).

Plain dicts, so that the commands, the live demo and the tests share one home for them and a
user can write them out and edit them.
"""

from __future__ import annotations

__all__ = ["demo_scene_dict", "tank_scene_dict"]


def demo_scene_dict() -> dict:
    """The demo tank scene in scene-file form.

    An ARIS Explorer 3000 (preset: 128 beams, 0.7-5 m, 1288 bins) 1 m above a concrete floor, pitched
    20 degrees down; the floor is lit from about 2.2 m to 4.4 m on the centre beam. On the
    floor: a concrete block, a plastic drum standing upright and a pipe lying down; above it, a
    tethered buoy. Each casts an acoustic shadow on the floor behind it.
    """
    return {
        "sonar": {
            "preset": "aris3000-128",
            "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]},
        },
        "render": {"elevation_samples": "auto", "tvg": True, "bounces": [1, 2, 3], "method": "fast"},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "objects": [
            {
                "name": "concrete_block",
                "primitive": "box",
                "size_m": [0.5, 0.4, 0.35],
                "pose": {"position_m": [2.7, -0.45, 0.175], "rpy_deg": [0.0, 0.0, 30.0]},
                "albedo": 0.8,
            },
            {
                "name": "plastic_drum",
                "primitive": "cylinder",
                "radius_m": 0.18,
                "height_m": 0.5,
                "pose": {"position_m": [3.3, 0.45, 0.25]},
                "albedo": 0.4,
            },
            {
                "name": "pipe",
                "primitive": "cylinder",
                "radius_m": 0.06,
                "height_m": 1.2,
                "pose": {"position_m": [3.9, -0.1, 0.06], "rpy_deg": [90.0, 0.0, 70.0]},
                "albedo": 0.7,
            },
            {
                "name": "buoy",
                "primitive": "sphere",
                "radius_m": 0.15,
                "pose": {"position_m": [2.4, 0.2, 0.4]},
                "albedo": 0.6,
            },
        ],
    }


def tank_scene_dict(mirror: bool = False) -> dict:
    """A water tank with a floor, a water surface and walls, in scene-file form (the multipath demo).

    An Oculus M1200d (1.2 MHz, here 256 beams over 60 degrees, 20 degrees of elevation) 1.4 m
    above the floor of a tank 2 m deep, tilted 2 degrees down: it sees the water surface from
    about 4.3 m and the floor from about 6.6 m; the far wall is 7.2 m away, the side walls 2 m
    to either side. A buoy floats near the surface, a post stands from floor to surface, a
    block hangs in mid-water. Paths up to order 3 over all five planes.

    With ``mirror`` (the demo's tank), a steel plate (1.2 x 1.0 m, R 0.9) stands on the floor
    4.2 m ahead and 1.3 m to the left, turned to mirror the post and the block towards the
    sonar: a mesh mirror whose ghosts the multipath figure shows.
    """
    doc = _tank_planes()
    if mirror:
        doc["objects"].append({"name": "steel_plate", "primitive": "box", "size_m": [0.03, 1.2, 1.0],
                               "pose": {"position_m": [4.2, 1.3, 0.5], "rpy_deg": [0.0, 0.0, 66.6]},
                               "albedo": 0.1, "specular": 0.9})
    return doc


def _tank_planes() -> dict:
    wall = {"albedo": 0.6, "specular": 0.5}
    return {
        "sonar": {
            "preset": "oculus-m1200d-lf", "azimuth_fov_deg": 60.0, "n_beams": 256,
            "range_min_m": 0.5, "range_max_m": 8.0, "n_range_bins": 750,
            "pose": {"position_m": [0.0, 0.0, 1.4], "rpy_deg": [0.0, 2.0, 0.0]},
        },
        "render": {"max_order": 3},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": [
            {"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0, "specular": 0.9},
            {"name": "far_wall", "point_m": [7.2, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], **wall},
            {"name": "left_wall", "point_m": [0.0, 2.0, 0.0], "normal": [0.0, -1.0, 0.0], **wall},
            {"name": "right_wall", "point_m": [0.0, -2.0, 0.0], "normal": [0.0, 1.0, 0.0], **wall},
        ],
        "objects": [
            {"name": "buoy", "primitive": "sphere", "radius_m": 0.15, "pose": {"position_m": [3.0, 0.4, 1.6]},
             "albedo": 0.7},
            {"name": "post", "primitive": "cylinder", "radius_m": 0.08, "height_m": 2.0,
             "pose": {"position_m": [5.0, -0.8, 1.0]}, "albedo": 0.6},
            {"name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.5],
             "pose": {"position_m": [6.0, 0.6, 1.2], "rpy_deg": [0.0, 0.0, 30.0]}, "albedo": 0.8},
        ],
    }
