"""The side-scan in layered water (issue 39 item 4): its straight-ray lines mapped onto the
device's time axis through the true sound-speed profile, against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.instruments import render_pings
from sonarsim.instruments.multibeam import SoundSpeedProfile
from tests.instruments.test_sidescan import ALTITUDE_M, DR, first_return_m, scene

DEVICE_C = 1500.0


def waterfall(**sidescan):
    with sonarsim.Simulator(scene(**sidescan)) as sim:
        return render_pings(sim, speckle=False)


def test_a_profile_at_the_devices_own_speed_changes_nothing():
    straight = waterfall()
    uniform = waterfall(sound_speed_profile=[[0.0, DEVICE_C]])
    np.testing.assert_allclose(uniform.samples, straight.samples, rtol=1e-5, atol=1e-12)


@pytest.mark.parametrize("speed", [1450.0, 1540.0])
def test_uniform_water_of_another_speed_scales_every_range(speed):
    """A device set to 1500 m/s in water of ``speed``: every range reads ``1500 / speed`` times
    the true one (the first return, and the floor's echo sample by sample)."""
    straight = waterfall().samples[0, 0]
    w = waterfall(sound_speed_profile=[[0.0, speed]]).samples[0, 0]
    scale = DEVICE_C / speed
    assert first_return_m(w) == pytest.approx(ALTITUDE_M * scale, abs=2 * DR)
    r = (np.arange(len(w)) + 0.5) * DR
    far = (r > 14.0) & (r < 26.0)
    np.testing.assert_allclose(w[far], np.interp(r[far] / scale, r, straight), rtol=0.02)


def test_a_gradient_puts_the_first_return_at_the_integral_of_the_slowness():
    """c(z) = c0 + g z below the head: straight down to the floor, T = ln(c(a) / c0) / g."""
    c0, g = 1440.0, 6.0
    w = waterfall(sound_speed_profile=[[0.0, c0], [20.0, c0 + 20.0 * g]]).samples[0, 1]
    expected = DEVICE_C * math.log((c0 + g * ALTITUDE_M) / c0) / g
    assert first_return_m(w) == pytest.approx(expected, abs=2 * DR)
    assert abs(expected - ALTITUDE_M) > 4 * DR  # the straight-ray range is visibly off


def test_far_samples_arrive_at_the_two_point_rays_time():
    """The floor at across-track distance x arrives at c T with T the solved ray's: an echo's
    edge (a box's near face on the floor) moves to where the ray tracing puts it."""
    c0, g = 1440.0, 6.0
    box = {"name": "box", "primitive": "box", "size_m": [2.0, 1.0, 1.0], "pose": {"position_m": [0.0, 18.0, 0.5]}}
    profile = [[0.0, c0], [20.0, c0 + 20.0 * g]]
    straight = waterfall(objects=[box], sound_speed_profile=[[0.0, DEVICE_C]]).samples[0, 0]
    bent = waterfall(objects=[box], sound_speed_profile=profile).samples[0, 0]
    # the box's echo: where the line rises most steeply (its near face)
    edge = lambda line: (int(np.argmax(np.diff(line[400:]))) + 400 + 0.5) * DR  # noqa: E731
    rho = edge(straight)
    across = math.sqrt(rho**2 - ALTITUDE_M**2)
    _, t = SoundSpeedProfile(depth_m=(0.0, 20.0), speed_m_s=(c0, c0 + 20.0 * g)).solve(0.0, ALTITUDE_M, across)
    assert edge(bent) == pytest.approx(DEVICE_C * float(t), abs=2 * DR)


def test_faster_water_is_rendered_far_enough_to_fill_the_window():
    w = waterfall(sound_speed_profile=[[0.0, 1560.0]]).samples[0, 0]
    assert w[-5:].min() > 0  # the floor's echo reaches the device's last samples


def test_the_profile_round_trips_through_the_section_and_the_water_gives_it():
    s = sonarsim.load_scene(scene(sound_speed_profile=[[0.0, 1480.0], [30.0, 1520.0]], surface_height_m=20.0))
    spec = s.instruments[0]
    assert spec.sound_speed_profile.speed_m_s == (1480.0, 1520.0) and spec.surface_height_m == 20.0
    assert sonarsim.load_scene(s.to_dict()).instruments[0] == spec
    doc = scene()
    doc["water"] = {"preset": "sea", "profile": [[0.0, 1490.0], [40.0, 1510.0]]}
    assert sonarsim.load_scene(doc).instruments[0].sound_speed_profile.speed_m_s == (1490.0, 1510.0)
    with pytest.raises(sonarsim.ConfigError, match="sound_speed_profile"):
        sonarsim.load_scene(scene(sound_speed_profile=[[0.0, 99.0]]))


def test_slower_water_and_a_window_that_starts_late_keep_the_devices_first_and_last_samples():
    w = waterfall(range_min_m=12.0, sound_speed_profile=[[0.0, 1450.0]]).samples[0, 0]
    assert w[:3].min() > 0 and w[-3:].min() > 0  # the floor's echo at both ends of the device's window
    w = waterfall(range_min_m=12.0, sound_speed_profile=[[0.0, 1560.0]]).samples[0, 0]
    assert w[:3].min() > 0 and w[-3:].min() > 0
