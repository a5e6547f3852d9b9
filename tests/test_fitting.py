"""Pose fitting: recover a known pose from a noisy synthetic image; band-edge detection."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import sonarsim
from sonarsim.demo import demo_scene_dict
from sonarsim.errors import ConfigError
from sonarsim.fitting import fit_pose, floor_band_m, parse_free
from sonarsim.transforms import Pose


def noisy(image, seed=0):
    """Speckle (exponential, the intensity statistics of fully developed speckle) + a floor."""
    rng = np.random.default_rng(seed)
    level = np.median(image.polar[image.polar > 0])
    polar = image.polar * rng.exponential(1.0, image.polar.shape) + 0.1 * level * rng.random(image.polar.shape)
    return replace(image, polar=polar.astype(np.float32), components={"total": polar.astype(np.float32)})


def test_edge_domain_fit_recovers_height_and_tilt_from_a_perturbed_start():
    scene = sonarsim.load_scene(demo_scene_dict())  # sonar at z = 1 m, pitch 20 deg
    real = noisy(sonarsim.render(scene))
    start = scene.with_pose(Pose((0.0, 0.0, 1.08), (0.0, 23.0, 0.0)))
    res = fit_pose(real, start, free=("z", "pitch"))
    assert abs(res.values["z"] - 1.0) < 0.005
    assert abs(res.values["pitch"] - 20.0) < 0.1
    assert res.cost < res.cost_start
    assert res.values["roll"] == 0.0 and res.values["x"] == 0.0  # not free: untouched


def floor_scene(z, pitch, roll):
    return sonarsim.load_scene({
        "sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, z], "rpy_deg": [roll, pitch, 0]}},
        "ground": {"albedo": 0.8},
        "render": {"bounces": [1]},
    })


def test_band_domain_fit_recovers_a_floor_pose_with_roll():
    real = noisy(sonarsim.render(floor_scene(0.40, 28.0, 3.0)), seed=1)
    res = fit_pose(real, floor_scene(0.35, 24.0, 0.0), free=("z", "pitch", "roll"), domain="band")
    assert abs(res.values["z"] - 0.40) < 0.01
    assert abs(res.values["pitch"] - 28.0) < 0.8
    assert abs(res.values["roll"] - 3.0) < 0.8
    assert res.onset_rms_m < 0.005


def test_band_edges_follow_the_flat_floor_formula():
    h, tau, elev = 0.4, 28.0, 12.0
    img = sonarsim.render(floor_scene(h, tau, 0.0))
    onset, end = floor_band_m(img)
    theta = np.radians(img.azimuth_deg)
    a, t = math.radians(elev / 2), math.radians(tau)
    expect_onset = h / (math.cos(a) * np.cos(theta) * math.sin(t) + math.sin(a) * math.cos(t))
    expect_end = h / (math.cos(a) * np.cos(theta) * math.sin(t) - math.sin(a) * math.cos(t))
    inner = slice(10, -10)  # the median across beams reaches past the fan's edges
    np.testing.assert_allclose(onset[inner], expect_onset[inner], atol=0.01)
    np.testing.assert_allclose(end[inner], expect_end[inner], atol=0.015)


@pytest.mark.parametrize("text, message", [("", "at least one"), ("z,depth", "unknown pose parameter 'depth'"),
                                           ("z,z", "named twice")])
def test_free_parameter_errors_name_what_is_allowed(text, message):
    with pytest.raises(ConfigError, match=message):
        parse_free(text)


def test_unknown_domain_is_rejected():
    scene = floor_scene(0.4, 28.0, 0.0)
    with pytest.raises(ConfigError, match="domain"):
        fit_pose(sonarsim.render(scene), scene, domain="pixels")
