"""Calibration renders every trial through one simulator (issue 38 item 1: no simulator rebuilt
per pose): a trial's elevation pattern is in the rays it traces, and the frame is the very one a
simulator of the scene with that sensor renders, bit for bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import sonarsim
from sonarsim.analysis.calibration import _Problem
from sonarsim.config.examples import demo_scene_dict
from sonarsim.config.sensor import PatternSpec, SensorSpec
from sonarsim.core.transforms import Pose


def test_a_trials_frame_is_a_sensor_scenes_frame():
    scene = sonarsim.load_scene(demo_scene_dict())
    with sonarsim.Simulator(scene) as sim:
        real = sim.render(speckle=False)
    problem = _Problem(real, scene, scene.sonar, (), 1.0, {})
    for width, pose in ((8.0, scene.sonar_pose), (14.0, Pose((0.1, -0.05, 1.1), (1.0, 25.0, 3.0)))):
        pattern = SensorSpec(elevation_pattern=PatternSpec(width_deg=width))
        with sonarsim.Simulator(replace(scene, sensor=pattern)) as sim:
            expected = sim.render(pose, keep_rays=False, speckle=False).components["total"]
        got = problem.pattern_frame(pattern, pose)
        assert got.tobytes() == np.asarray(expected).tobytes()
    assert problem.simulator() is problem.simulator()
