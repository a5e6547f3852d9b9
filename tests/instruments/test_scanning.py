"""Mechanical scanning sonar on the engine (issue 38 item 4): geometry checked by hand.

- a straight wall at distance D from a still vehicle: each step's first return at
  ``D / cos(angle between the step and the wall's normal)``;
- the same wall ahead of a moving vehicle: step i's return at ``(D - v t_i) / cos(angle_i)``,
  the vehicle's position at that step's own time (the smear of a real scan);
- the mirrored scene (y -> -y) gives step i <-> step (steps - i) mod steps;
- a full Ping360 turn renders; a step's draws are its own; bad keys are named.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

import sonarsim
from sonarsim.errors import ConfigError
from sonarsim.instruments import render_pings
from sonarsim.instruments.scanning import ScanImage, ScanningSpec

RANGE_M, N_SAMPLES = 20.0, 800
DR = RANGE_M / N_SAMPLES
WALL_D = 8.0


def section(**over) -> dict:
    """Every value given (no preset): Ping360's beam and head, a 20 m window."""
    s = {"type": "scanning", "frequency_khz": 750, "horizontal_beam_width_deg": 2, "vertical_beam_width_deg": 25,
         "tilt_deg": 0, "steps_per_turn": 400, "step": 1, "sector_deg": 360, "range_min_m": 0.0,
         "range_max_m": RANGE_M, "n_samples": N_SAMPLES, "sound_speed_m_s": 1500, "step_overhead_s": 0.0,
         "pose": {"position_m": [0.0, 0.0, 0.0]}}
    s.update(over)
    return s


def wall_to_port(d=WALL_D, x_end=None) -> dict:
    """A wall 0.2 m thick whose face is the plane y = d, 100 m tall, 400 m long (or ending at x_end)."""
    if x_end is None:
        return {"name": "wall", "primitive": "box", "size_m": [400.0, 0.2, 100.0],
                "pose": {"position_m": [0.0, d + 0.1, 0.0]}}
    return {"name": "wall", "primitive": "box", "size_m": [200.0, 0.2, 100.0],
            "pose": {"position_m": [x_end - 100.0, d + 0.1, 0.0]}}


def scene(objects=(), ground=None, **over) -> dict:
    doc = {"sonar": section(**over), "objects": list(objects), "render": {"max_order": 1}}
    if ground is not None:
        doc["ground"] = {"height_m": ground}
    return doc


def first_return_m(img: ScanImage) -> np.ndarray:
    """Near edge of each step's first sample with energy; NaN for a step that sees nothing."""
    lit = img.samples > 0
    k = np.argmax(lit, axis=0)
    return np.where(lit.any(axis=0), img.range_min_m + k * DR, np.nan)


def test_a_wall_seen_by_every_step_at_d_over_cos():
    with sonarsim.Simulator(scene([wall_to_port()])) as sim:
        img = render_pings(sim, n_pings=400, speckle=False)
    assert img.samples.shape == (N_SAMPLES, 400) and img.samples.dtype == np.float32
    np.testing.assert_allclose(img.angle_deg, np.arange(400) * 0.9)
    # The wall's normal (towards the wall) is +y: head angle 90 deg.
    c = np.cos(np.radians(img.angle_deg - 90.0))
    with np.errstate(divide="ignore"):
        expected = np.where(c > 0, WALL_D / c, np.inf)
    got = first_return_m(img)
    seen = expected < RANGE_M - 2 * DR
    assert seen.sum() > 100  # about +-66 deg about the normal: 147 steps
    np.testing.assert_array_less(np.abs(got[seen] - expected[seen]), 2 * DR)
    # The steps facing away (starboard half) and those whose wall lies beyond the window: dark.
    assert np.isnan(got[expected > RANGE_M + 2 * DR]).all()
    # The water between the head and the wall is dark in every step.
    assert not img.samples[img.range_m < WALL_D - DR].any()


def test_the_wall_ahead_of_a_moving_vehicle_is_smeared_by_its_motion():
    """A sector scan (120 deg, forward) of a wall ahead, face x = D, the vehicle running at it at
    v: step i leaves at t_i = i T (T the step period) with the vehicle at v t_i, so its return is
    at (D - v t_i) / cos(angle_i), angle_i = -66 x 0.9 + 0.9 i deg."""
    from sonarsim.dataset.trajectory import Trajectory

    d, v, period = 15.0, 1.0, 0.05
    overhead = period - 2.0 * RANGE_M / 1500.0
    wall = {"name": "wall", "primitive": "box", "size_m": [0.2, 400.0, 100.0], "pose": {"position_m": [d + 0.1, 0.0, 0.0]}}
    track = Trajectory(times_s=[0.0, 20.0], positions_m=[[0.0, 0.0, 0.0], [20.0 * v, 0.0, 0.0]],
                       quats_xyzw=[[0, 0, 0, 1], [0, 0, 0, 1]])
    doc = scene([wall], sector_deg=120, step_overhead_s=overhead)
    with sonarsim.Simulator(doc) as sim:
        spec = sim.scene.instruments[0]
        assert spec.steps_per_scan() == 133 and abs(spec.ping_period_s() - period) < 1e-12
        img = render_pings(sim, n_pings=133, trajectory=track, speckle=False)
    t = np.arange(133) * period
    np.testing.assert_allclose(img.times_s, t)
    np.testing.assert_allclose(img.geometry.x_m, v * t, atol=1e-9)
    np.testing.assert_allclose(img.angle_deg, (np.arange(133) - 66) * 0.9)
    cos_a = np.cos(np.radians(img.angle_deg))
    expected = (d - v * t) / cos_a
    got = first_return_m(img)
    seen = expected < RANGE_M - 2 * DR
    assert seen.sum() > 80
    np.testing.assert_array_less(np.abs(got[seen] - expected[seen]), 2 * DR)
    # The smear is there: a still vehicle's prediction is off by metres at the sweep's end.
    assert np.abs(got[seen] - d / cos_a[seen]).max() > 3.0
    # The sweep's two ends see the wall at different ranges though symmetric in angle.
    i, j = 20, 112  # angles -41.4 and +41.4 deg
    assert abs(img.angle_deg[i] + img.angle_deg[j]) < 1e-9
    assert got[i] - got[j] > 4.0 * v * (j - i) * period / 5.0


def test_the_end_of_a_wall_passed_along_moves_with_the_vehicle():
    """A wall to port (face y = D) ending at x = X, the vehicle running along it at v: step i's
    ray (angle a_i = 0.9 i deg, time t_i = i T) meets the plane y = D at x = v t_i + D cot(a_i),
    and sees the wall where that is short of X. A still vehicle would see the wall's end at
    atan(D / X) = 33.7 deg; the moving one carries it to about 54 deg."""
    from sonarsim.dataset.trajectory import Trajectory

    x_end, v, period = 12.0, 2.0, 0.05
    overhead = period - 2.0 * RANGE_M / 1500.0
    track = Trajectory(times_s=[0.0, 20.0], positions_m=[[0.0, 0.0, 0.0], [20.0 * v, 0.0, 0.0]],
                       quats_xyzw=[[0, 0, 0, 1], [0, 0, 0, 1]])
    n = 200  # half a turn, 0 to 179.1 deg: 10 s, the vehicle moves 20 m
    with sonarsim.Simulator(scene([wall_to_port(x_end=x_end)], step_overhead_s=overhead)) as sim:
        img = render_pings(sim, n_pings=n, trajectory=track, speckle=False)
    t = np.arange(n) * period
    a = np.radians(img.angle_deg)
    with np.errstate(divide="ignore"):
        meets_x = v * t + WALL_D / np.tan(a)
        slant = WALL_D / np.sin(a)
    in_window = (slant < RANGE_M - 1.0) & (a > 0)
    got = first_return_m(img)
    # The beam's centre ray decides (one azimuth sample): a margin of 0.3 m about the end.
    on_wall = in_window & (meets_x < x_end - 0.3)
    off_wall = in_window & (meets_x > x_end + 0.3)
    assert on_wall.sum() > 50 and off_wall.sum() > 10
    np.testing.assert_array_less(np.abs(got[on_wall] - slant[on_wall]), 2 * DR)
    assert np.isnan(got[off_wall]).all()  # nothing else in the scene
    # The first step to see the wall, against the hand computation and the still vehicle's.
    first_seen = int(np.nonzero(np.isfinite(got))[0][0])
    crossing = int(np.nonzero(in_window & (meets_x < x_end))[0][0])  # step 59, 53.1 deg
    assert abs(first_seen - crossing) <= 1, (first_seen, crossing)
    still = math.degrees(math.atan2(WALL_D, x_end))
    assert img.angle_deg[first_seen] > still + 15.0


def test_mirrored_scene_gives_the_mirrored_scan():
    box = {"name": "box", "primitive": "box", "size_m": [1.0, 2.0, 1.5],
           "pose": {"position_m": [6.0, 5.0, -1.0], "rpy_deg": [0, 0, 25]}}
    ball = {"name": "ball", "primitive": "sphere", "radius_m": 0.6, "pose": {"position_m": [-4.0, 9.0, -2.0]}}

    def mirror(o):
        p = o["pose"]
        rpy = p.get("rpy_deg", [0, 0, 0])
        return {**o, "pose": {"position_m": [p["position_m"][0], -p["position_m"][1], p["position_m"][2]],
                              "rpy_deg": [-rpy[0], rpy[1], -rpy[2]]}}

    with sonarsim.Simulator(scene([box, ball], ground=-3.0)) as sim:
        a = render_pings(sim, n_pings=400, speckle=False)
    with sonarsim.Simulator(scene([mirror(box), mirror(ball)], ground=-3.0)) as sim:
        b = render_pings(sim, n_pings=400, speckle=False)
    j = (400 - np.arange(400)) % 400
    scale = a.samples.max()
    assert scale > 0
    np.testing.assert_allclose(a.samples, b.samples[:, j], rtol=2e-4, atol=1e-6 * scale)
    # and the scan is not symmetric itself (the test would pass trivially otherwise)
    assert np.abs(a.samples - a.samples[:, j]).max() > 0.1 * scale


def test_a_full_ping360_turn_renders_and_its_time_is_reported(capsys):
    """Ping360 at 50 m and 1200 samples: 400 steps of 2 x 50 / 1500 s = 26.7 s per turn; the
    render's time is reported beside it (not asserted: the machine's load varies)."""
    doc = scene([wall_to_port()], ground=-5.0, range_max_m=50.0, n_samples=1200)
    with sonarsim.Simulator(doc) as sim:
        spec = sim.scene.instruments[0]
        t0 = time.perf_counter()
        img = render_pings(sim, n_pings=spec.steps_per_scan(), speckle=False)
        took = time.perf_counter() - t0
    assert img.samples.shape == (1200, 400)
    np.testing.assert_allclose(img.times_s, np.arange(400) * 2 * 50 / 1500)
    assert abs(spec.turn_time_s() - 400 * 2 * 50 / 1500) < 1e-9
    with capsys.disabled():
        print(f"\n[scanning] Ping360 turn (400 steps, 1200 samples, 50 m): render {took:.2f} s, device "
              f"{spec.turn_time_s():.2f} s, ratio {took / spec.turn_time_s():.3f}")
    top = img.cartesian(256)
    assert top.shape == (256, 256) and top.dtype == np.float32 and top.any()


def test_a_steps_draws_are_its_own():
    doc = scene([wall_to_port()], sensor={"speckle": True})
    with sonarsim.Simulator(doc) as sim:
        six = render_pings(sim, n_pings=6)
        fourth = render_pings(sim, n_pings=1, first_ping=3)
        again = render_pings(sim, n_pings=6)
        expected = render_pings(sim, n_pings=6, speckle=False)
    np.testing.assert_array_equal(six.samples[:, 3], fourth.samples[:, 0])
    assert fourth.angle_deg[0] == six.angle_deg[3]
    np.testing.assert_array_equal(six.samples, again.samples)
    assert not np.array_equal(six.samples, expected.samples)


def test_sector_steps_sweep_back_and_forth():
    spec = ScanningSpec(name="s", sector_deg=9.0)  # 10 motor steps: -5 .. +5
    assert spec.sector_steps == 10 and spec.steps_per_scan() == 11
    k = np.arange(23)
    expected = [-5, -4, -3, -2, -1, 0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0, -1, -2, -3, -4, -5, -4, -3]
    np.testing.assert_array_equal(spec.head_steps(k), expected)
    two = ScanningSpec(name="s", sector_deg=9.0, step=2)
    np.testing.assert_array_equal(two.head_steps(np.arange(12)), [-5, -3, -1, 1, 3, 5, 3, 1, -1, -3, -5, -3])
    turn = ScanningSpec(name="s", step=3)
    np.testing.assert_array_equal(turn.head_steps([0, 1, 133, 134]), [0, 3, 399, 2])
    assert turn.steps_per_scan() == 134


def test_cartesian_puts_forward_up_and_port_left():
    with sonarsim.Simulator(scene([wall_to_port()])) as sim:
        img = render_pings(sim, n_pings=400, speckle=False)
    n = 400
    top = img.cartesian(n)
    p = 2 * RANGE_M / n
    c = n / 2 - np.arange(n) - 0.5
    y = c * p
    row = n // 2  # x = -p/2: beside the head
    lit = np.nonzero(top[row] > 0)[0]
    assert lit.size and (y[lit] > WALL_D - 2 * p).all()  # the wall, to port (left columns)
    assert abs(y[lit].min() - WALL_D) < 2 * p
    assert not top[:, n // 2:].any()  # starboard: nothing
    # A sector scan's top view is dark outside its sector.
    with sonarsim.Simulator(scene([wall_to_port()], sector_deg=90)) as sim:
        sector = render_pings(sim, n_pings=101, speckle=False).cartesian(n)
    x = c[:, None] * p
    angle = np.degrees(np.arctan2(c[None, :] * p, x))
    assert not sector[np.abs(angle) > 45.0 + 1.0].any() and sector.any()


@pytest.mark.parametrize("key, value", [("steps_per_turn", 3), ("step", 0), ("step", 300), ("sector_deg", 0.0),
                                        ("sector_deg", 400), ("vertical_beam_width_deg", 500), ("n_samples", 0),
                                        ("range_max_m", -1.0), ("frequency_khz", "x"), ("tilt_deg", 100),
                                        ("step_overhead_s", -1.0), ("steps_per_turn", 400.5)])
def test_bad_values_are_named(key, value):
    with pytest.raises(ConfigError, match=f"sonar.{key}"):
        sonarsim.load_scene(scene(**{key: value}))


def test_an_unknown_key_is_named():
    with pytest.raises(ConfigError, match="steps_per_trun"):
        sonarsim.load_scene(scene(steps_per_trun=400))


def test_spec_round_trips_through_its_section():
    s = sonarsim.load_scene(scene(tilt_deg=10, sector_deg=180, step=2))
    spec = s.instruments[0]
    assert isinstance(spec, ScanningSpec) and spec.name == "scanning"
    again = sonarsim.load_scene(s.to_dict())
    assert again.instruments[0] == spec


def test_a_tilted_head_sees_the_floor_at_altitude_over_sin_tilt():
    """Tilted 30 deg down at 4 m over a floor, the beam's axis meets it at 8 m; the rays' span
    reaches the vertical (85 deg below the axis and above it), so the first return is the floor
    right below, at 4 / sin(min(30 + 85, 90)) = 4 m -- in every step alike."""
    doc = scene(ground=0.0, tilt_deg=30, pose={"position_m": [0.0, 0.0, 4.0]})
    with sonarsim.Simulator(doc) as sim:
        img = render_pings(sim, n_pings=8, speckle=False)
    got = first_return_m(img)
    np.testing.assert_array_less(np.abs(got - 4.0), 2 * DR)
    # the strongest return is near the axis's footprint (the pattern's main lobe), not at nadir
    peak = img.range_m[np.argmax(img.samples, axis=0)]
    assert (np.abs(peak - 8.0) < 3.0).all()


def test_on_a_vehicle_with_a_single_beam_beside_it():
    """A vehicle carrying a scanning head 1 m to port and a single-beam 0.2 m below its origin:
    the head's wall is 1 m nearer (step 100 looks to port), the single-beam's floor 2.8 m off."""
    doc = {"vehicle": {"pose": {"position_m": [0.0, 0.0, 3.0]}},
           "instruments": [{**{k: v for k, v in section().items() if k != "pose"}, "name": "head",
                            "mount": {"position_m": [0.0, 1.0, 0.0]}},
                           {"type": "singlebeam", "name": "alt", "beam_width_deg": 10, "range_max_m": 10.0,
                            "n_samples": 500, "mount": {"position_m": [0.5, 0.0, -0.2]}}],
           "ground": {"height_m": 0.0}, "objects": [wall_to_port()], "render": {"max_order": 1}}
    with sonarsim.Simulator(doc) as sim:
        img = render_pings(sim, "head", n_pings=400, speckle=False)
        env = render_pings(sim, "alt", speckle=False)
    # The floor (3 m below) echoes in every step alike; the wall is where step 100 (port)
    # departs from step 300 (starboard, the floor alone).
    port, starboard = img.samples[:, 100].astype(np.float64), img.samples[:, 300].astype(np.float64)
    k = int(np.argmax(np.abs(port - starboard) > 1e-3 * port.max()))
    assert abs(k * DR - (WALL_D - 1.0)) <= 2 * DR, k * DR
    assert abs(env.bottom_range_m[0] - 2.8) <= 10.0 / 500


def test_a_preset_gives_defaults_and_the_section_overrides_them():
    """The Ping360's preset (config.instrument_presets) gives its figures; the section's keys win."""
    from sonarsim.errors import ConfigError

    doc = {"sonar": {"type": "scanning", "preset": "ping360", "range_max_m": 10.0}}
    spec = sonarsim.load_scene(doc).instruments[0]
    with pytest.raises(ConfigError, match=r"sonar\.preset.*not a scanning one"):
        sonarsim.load_scene({"sonar": {"type": "scanning", "preset": "imagenex_852"}})
    assert (spec.n_samples, spec.range_max_m, spec.vertical_beam_width_deg, spec.preset) == (1200, 10.0, 25.0, "ping360")


def test_labels_name_what_each_step_sees():
    """A box 6 m ahead on the floor, the head 2 m up tilted down 20 degrees: the steps looking
    ahead carry the box's id where its echo lands, the others only the floor's."""
    doc = {"sonar": {"type": "scanning", "frequency_khz": 750, "horizontal_beam_width_deg": 2.0,
                     "vertical_beam_width_deg": 25.0, "tilt_deg": 20.0, "steps_per_turn": 400, "range_max_m": 10.0,
                     "n_samples": 400, "sound_speed_m_s": 1500.0, "pose": {"position_m": [0.0, 0.0, 2.0]}},
           "ground": {"height_m": 0.0},
           "objects": [{"name": "box", "primitive": "box", "size_m": [0.6, 0.6, 0.6], "pose": {"position_m": [6.0, 0.0, 0.3]}}]}
    with sonarsim.Simulator(doc) as sim:
        scan = render_pings(sim, n_pings=400, speckle=False, labels=True)
    box = scan.ids.index("box")
    inst = scan.labels["instance"]
    steps = np.nonzero((inst == box).any(axis=0))[0]
    angles = np.where(scan.angle_deg[steps] > 180, scan.angle_deg[steps] - 360, scan.angle_deg[steps])
    assert len(steps) >= 2 and np.all(np.abs(angles) < 5.0)  # the box subtends +-2.9 deg, the beam 2 deg
    r = (np.arange(400) + 0.5) * 10.0 / 400
    assert np.all(np.abs(r[np.nonzero(inst[:, steps[0]] == box)[0]] - 6.0) < 0.8)
    ground = scan.ids.index("ground")
    assert (inst == ground).any(axis=0).sum() > 300  # the floor in most steps
