"""The example scenarios in examples/scenarios load, and their first frames render (with few
elevation rays to stay fast) and see what they are meant to see."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sonarsim
from sonarsim.config.loader import scene_from_dict
from sonarsim.dataset import load_scenario

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "scenarios"
NAMES = sorted(p.name for p in EXAMPLES.glob("*.yaml"))


def render_fast(frame):
    """Render a frame with 8 rays per beam across the elevation aperture."""
    doc = {**frame.scene, "render": {**frame.scene.get("render", {}), "elevation_samples": 8}}
    with sonarsim.Simulator(scene_from_dict(doc, base_dir=frame.base_dir)) as sim:
        return frame.render(sim)


def test_there_are_examples():
    assert {"orbit_tank.yaml", "lawnmower_rocks.yaml", "track_file.yaml", "random_views.yaml"} <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_example_loads_and_its_first_frames_render(name):
    s = load_scenario(EXAMPLES / name)
    assert s.n_frames >= 2
    images = [render_fast(s.frame(k)) for k in (0, 1)]
    for image in images:
        assert np.isfinite(image.polar).all()
        assert image.polar.max() > 0
    assert not np.array_equal(images[0].polar, images[1].polar)


def test_orbit_example_sees_its_objects_from_every_side():
    s = load_scenario(EXAMPLES / "orbit_tank.yaml")
    assert s.n_frames == 36
    centre = np.array([3.15, 0.0, 0.2])
    for k in (0, 9, 18, 27):
        f = s.frame(k)
        axis = f.pose.rotation[:, 0]
        d = centre - f.pose.translation
        np.testing.assert_allclose(axis, d / np.linalg.norm(d), atol=1e-12)
        ids = np.unique(render_fast(f).rays.surface_id)
        assert (ids >= 1).sum() >= 2  # at least two of the four objects (surface ids 1-4) in view


def test_lawnmower_example_rocks_and_sensor_vary():
    s = load_scenario(EXAMPLES / "lawnmower_rocks.yaml")
    assert s.n_frames == 341  # 5 legs of 12 m and 4 crossings of 2 m at 1 m/s, 5 Hz
    f0, f1 = s.frame(0), s.frame(1)
    assert f0.pose.position_m == (0.0, -4.0, 1.5) and f0.pose.rpy_deg == (0.0, 25.0, 0.0)
    rocks = [o for o in f0.scene["objects"] if o["name"].startswith("rock_")]
    assert 4 <= len(rocks) <= 10
    assert f0.scene["sensor"]["gain_db"] != f1.scene["sensor"]["gain_db"]
    image = render_fast(f0)
    assert image.polar.max() <= 255 and np.array_equal(image.polar, np.round(image.polar))  # uint8 device output


def test_track_example_is_resampled_to_its_rate():
    s = load_scenario(EXAMPLES / "track_file.yaml")
    assert s.n_frames == 17  # 4 s at 4 Hz, both ends
    np.testing.assert_allclose([s.frame(k).time_s for k in range(3)], [0.0, 0.25, 0.5])
    np.testing.assert_allclose(s.frame(2).pose.position_m, [0.25, 0.0, 0.355])
    assert s.start_time_ns == 1_714_564_800 * 10**9  # start_time: 2024-05-01T12:00:00Z (the bag's frame 0)
