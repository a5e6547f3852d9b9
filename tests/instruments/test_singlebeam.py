"""Single-beam echosounder on the engine: a conical beam down, checked against hand geometry.

- a level vehicle over a flat floor at altitude h: bottom at h within a sample;
- tilted (roll, pitch) by T from the vertical, the axis meets the floor at h / (cos roll cos
  pitch), but the first return is the nearest point in the cone: h while T is within the cone's
  half-angle A, else h / cos(T - A); the detector (-10 dB below the peak) stays at h while T is
  within the -3 dB half-width;
- an object in the beam gives an earlier return; a ping's draws are its own; bad keys named.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.errors import ConfigError
from sonarsim.instruments import render_pings
from sonarsim.instruments.singlebeam import CONE_BEAMS, SinglebeamSpec, cone_gain, detect_bottom

H, RANGE_M, N_SAMPLES, WIDTH = 10.0, 30.0, 1000, 10.0
DR = RANGE_M / N_SAMPLES


def scene(rpy_deg=(0.0, 0.0, 0.0), objects=(), **over) -> dict:
    s = {"type": "singlebeam", "frequency_khz": 200, "beam_width_deg": WIDTH, "pattern": "piston",
         "range_min_m": 0.0, "range_max_m": RANGE_M, "n_samples": N_SAMPLES, "ping_rate_hz": 10,
         "sound_speed_m_s": 1500, "threshold_db": -10,
         "pose": {"position_m": [0.0, 0.0, H], "rpy_deg": list(rpy_deg)}}
    s.update(over)
    return {"sonar": s, "ground": {"height_m": 0.0}, "objects": list(objects), "render": {"max_order": 1}}


def first_return_m(line: np.ndarray) -> float:
    k = int(np.argmax(line > 0))
    assert line[k] > 0
    return k * DR


def in_sample(got: float, expected: float, samples: int = 1) -> bool:
    """``got`` (a sample's near edge) is the sample holding ``expected``, within ``samples``."""
    return -samples * DR - 1e-9 <= got - math.floor(expected / DR) * DR <= samples * DR + 1e-9


def test_level_over_a_flat_floor_the_bottom_is_the_altitude():
    with sonarsim.Simulator(scene()) as sim:
        env = render_pings(sim, speckle=False)
    assert env.samples.shape == (1, N_SAMPLES) and env.samples.dtype == np.float32
    assert in_sample(env.bottom_range_m[0], H, 0), env.bottom_range_m
    assert in_sample(first_return_m(env.samples[0]), H, 0)
    assert not env.samples[0][env.range_m < H - DR].any()  # the water column is dark
    np.testing.assert_allclose(env.geometry.altitude_m, H)


def test_the_pattern_is_half_power_at_half_the_width_and_zero_at_the_null():
    half = math.radians(WIDTH / 2)
    for pattern in ("piston", "gaussian"):
        assert abs(cone_gain(np.array([half]), WIDTH, pattern)[0] - 0.5) < 1e-9
        assert cone_gain(np.array([0.0]), WIDTH, pattern)[0] == 1.0
    spec = SinglebeamSpec(name="sb", beam_width_deg=WIDTH)
    null = math.radians(spec.cone_half_angle_deg)
    assert cone_gain(np.array([null]), WIDTH)[0] < 1e-12
    # the piston's main lobe: null / half-width = asin(3.832 / 1.616 sin 5 deg) / 5 deg = 3.35
    assert abs(spec.cone_half_angle_deg / (WIDTH / 2) - 3.35) < 0.02


@pytest.mark.parametrize("roll_deg, pitch_deg", [(0.0, 4.0), (4.0, 0.0), (3.0, -3.0), (0.0, 12.0), (-12.0, 0.0),
                                                 (0.0, 25.0), (25.0, 0.0), (0.0, -40.0), (14.0, 14.0)])
def test_tilted_the_first_return_is_the_nearest_point_in_the_cone(roll_deg, pitch_deg):
    with sonarsim.Simulator(scene((roll_deg, pitch_deg, 0.0))) as sim:
        env = render_pings(sim, speckle=False)
        spec = sim.scene.instruments[0]
    tilt = math.degrees(math.acos(math.cos(math.radians(roll_deg)) * math.cos(math.radians(pitch_deg))))
    axis = H / math.cos(math.radians(tilt))  # where the axis meets the floor
    a = spec.cone_half_angle_deg
    # The cone's rays reach a from the axis in pitch (the fan's elevation, finely sampled) and,
    # in roll (across its CONE_BEAMS beams), to the outermost beam's centre a (1 - 1 / CONE_BEAMS);
    # the floor's nearest point in the cone is h while tilt <= reach, else h / cos(tilt - reach).
    got = first_return_m(env.samples[0])
    if roll_deg == 0.0 or pitch_deg == 0.0:
        reach = a if roll_deg == 0.0 else a * (1.0 - 1.0 / CONE_BEAMS)
        nearest = H / math.cos(math.radians(max(tilt - reach, 0.0)))
        assert in_sample(got, nearest), (got, nearest)
    else:
        # Both (14, 14: tilt 19.7 deg, beyond a): the cone's edge towards the vertical lies
        # between the fan's rays; the nearest ray is within a beam spacing of it.
        spacing = 2.0 * a / CONE_BEAMS
        lo = H / math.cos(math.radians(max(tilt - a, 0.0)))
        hi = H / math.cos(math.radians(max(tilt - a + spacing, 0.0)))
        assert lo - DR <= got <= hi + DR, (lo, got, hi)
    detected = env.bottom_range_m[0]
    assert H - DR <= detected <= axis + 2 * DR
    if tilt <= WIDTH / 2:
        # the floor below is within the -3 dB cone: at most 3 dB down, above the -10 dB threshold
        assert in_sample(detected, H), (detected, H)
    if tilt >= 12.0:
        # the trivial prediction (the axis's range) is off: the first return is nearer
        assert axis - got > 4 * DR


def test_an_object_in_the_beam_gives_an_earlier_return():
    box = {"name": "box", "primitive": "box", "size_m": [1.5, 1.5, 1.5], "pose": {"position_m": [0.4, -0.3, 0.75]}}
    with sonarsim.Simulator(scene(objects=[box])) as sim:
        env = render_pings(sim, speckle=False)
    top = H - 1.5
    assert in_sample(first_return_m(env.samples[0]), top, 0)
    assert in_sample(env.bottom_range_m[0], top)
    # The box off to the side, outside the cone (a = 16.7 deg: 2.7 m at 9 m), is not seen.
    far = {**box, "pose": {"position_m": [5.0, 0.0, 0.75]}}
    with sonarsim.Simulator(scene(objects=[far])) as sim:
        env = render_pings(sim, speckle=False)
    assert in_sample(env.bottom_range_m[0], H, 0)


def test_a_pings_draws_are_its_own():
    from sonarsim.dataset.trajectory import Trajectory

    track = Trajectory(times_s=[0.0, 1.0], positions_m=[[0, 0, H], [1.0, 0, H - 0.5]],
                       quats_xyzw=[[0, 0, 0, 1], [0, 0, 0, 1]])
    with sonarsim.Simulator(scene(sensor={"speckle": True})) as sim:
        all_five = render_pings(sim, trajectory=track, n_pings=5)
        third = render_pings(sim, times_s=[0.2], trajectory=track, first_ping=2)
        again = render_pings(sim, trajectory=track, n_pings=5)
        expected = render_pings(sim, trajectory=track, n_pings=5, speckle=False)
    np.testing.assert_array_equal(all_five.samples[2], third.samples[0])
    np.testing.assert_array_equal(all_five.samples, again.samples)
    assert not np.array_equal(all_five.samples, expected.samples)
    np.testing.assert_allclose(all_five.geometry.time_s, np.arange(5) * 0.1)
    # the expected bottom follows the vehicle down: h - 0.5 t
    for k, t in enumerate(np.arange(5) * 0.1):
        assert in_sample(expected.bottom_range_m[k], H - 0.5 * t, 0)


def test_the_detector_by_hand():
    e = np.zeros((3, 10))
    e[0, 4:] = [0.05, 0.2, 1.0, 0.5, 0.1, 0.0]
    e[1, 2] = 3.0
    got = detect_bottom(e, 1.0, 11.0, -10.0)
    np.testing.assert_allclose(got[:2], [1.0 + 5.0, 1.0 + 2.0])
    assert np.isnan(got[2])


@pytest.mark.parametrize("key, value", [("beam_width_deg", 0.5), ("beam_width_deg", 90), ("pattern", "cone"),
                                        ("pattern", 3), ("threshold_db", 0), ("threshold_db", -100),
                                        ("n_samples", 0), ("range_max_m", -1.0), ("ping_rate_hz", -2),
                                        ("frequency_khz", "x"), ("sound_speed_m_s", 100)])
def test_bad_values_are_named(key, value):
    with pytest.raises(ConfigError, match=f"sonar.{key}"):
        sonarsim.load_scene(scene(**{key: value}))


def test_an_unknown_key_is_named():
    with pytest.raises(ConfigError, match="beamwidth_deg"):
        sonarsim.load_scene(scene(beamwidth_deg=10))


def test_spec_round_trips_through_its_section():
    s = sonarsim.load_scene(scene(pattern="gaussian", ping_rate_hz=None))
    spec = s.instruments[0]
    assert isinstance(spec, SinglebeamSpec) and spec.pattern == "gaussian"
    assert abs(spec.ping_period_s() - 2 * RANGE_M / 1500) < 1e-12
    again = sonarsim.load_scene(s.to_dict())
    assert again.instruments[0] == spec


def test_a_gaussian_beam_finds_the_same_level_bottom():
    with sonarsim.Simulator(scene(pattern="gaussian")) as sim:
        env = render_pings(sim, speckle=False)
    assert in_sample(env.bottom_range_m[0], H, 0)


def test_a_preset_gives_defaults_and_the_section_overrides_them():
    """The Imagenex 852's preset (config.instrument_presets) gives its figures; the section's keys win."""
    spec = sonarsim.load_scene({"sonar": {"type": "singlebeam", "preset": "imagenex_852", "n_samples": 800}}).instruments[0]
    assert (spec.beam_width_deg, spec.frequency_khz, spec.range_max_m, spec.n_samples) == (30.0, 330.0, 10.0, 800)
