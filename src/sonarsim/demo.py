"""The built-in demo: a water tank with a concrete floor and objects, seen by an ARIS 3000.

Needs no files: :func:`demo_scene_dict` is a scene-file dict that ``sonarsim demo`` renders and
also writes out as ``scene.yaml`` for users to edit.
"""

from __future__ import annotations


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
