"""Side-scan on the engine (issue 38 items 2 and 7): geometry checked by hand.

- the first bottom return at ``altitude / (cos pitch cos roll)`` where the pattern reaches nadir;
- a box's shadow, start and end, against the closed form of the rays over its far top edge;
- the mirrored scene gives the mirrored waterfall (port and starboard swapped);
- the water column before the first return is dark; a ping's draws are its own (seeded).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.errors import ConfigError
from sonarsim.instruments import render_pings
from sonarsim.instruments.sidescan import NADIR_MARGIN_DEG, SidescanSpec

ALTITUDE_M, RANGE_M, N_SAMPLES = 10.0, 30.0, 1024
DR = RANGE_M / N_SAMPLES


def scene(rpy_deg=(0.0, 0.0, 0.0), objects=(), planes=(), **sidescan) -> dict:
    section = {"type": "sidescan", "frequency_khz": 600, "horizontal_beam_width_deg": 0.5,
               "vertical_beam_width_deg": 50, "depression_deg": 15, "range_max_m": RANGE_M,
               "n_samples": N_SAMPLES, "pose": {"position_m": [0.0, 0.0, ALTITUDE_M], "rpy_deg": list(rpy_deg)}}
    section.update(sidescan)
    return {"sonar": section, "ground": {"height_m": 0.0}, "objects": list(objects), "planes": list(planes),
            "render": {"max_order": 1}}


def first_return_m(line: np.ndarray) -> float:
    """Near edge of the first sample with energy."""
    k = int(np.argmax(line > 0))
    assert line[k] > 0
    return k * DR


@pytest.mark.parametrize("roll_deg, pitch_deg", [(0.0, 0.0), (0.0, 10.0), (5.0, 0.0), (-8.0, 6.0), (12.0, -15.0)])
def test_first_return_where_the_pattern_reaches_nadir(roll_deg, pitch_deg):
    with sonarsim.Simulator(scene((roll_deg, pitch_deg, 0.0))) as sim:
        w = render_pings(sim, speckle=False)
    c_pitch = math.cos(math.radians(pitch_deg))
    # Each side's rays reach NADIR_MARGIN_DEG past the vehicle's down axis: the side whose down
    # edge rolls away from the vertical (port for roll > 0: lifts port) first meets the floor
    # at that edge, altitude / (cos pitch cos(|roll| - margin)); the other side reaches the
    # plane's own nearest point, altitude / cos pitch.
    edge = ALTITUDE_M / (c_pitch * math.cos(math.radians(max(abs(roll_deg) - NADIR_MARGIN_DEG, 0.0))))
    nearest = ALTITUDE_M / c_pitch
    port, starboard = (edge, nearest) if roll_deg > 0 else (nearest, edge)
    for side, expected in ((0, port), (1, starboard)):
        got = first_return_m(w.samples[0, side])
        assert abs(got - expected) <= 2 * DR, (side, got, expected)
    # the trivial prediction (first return = the altitude) is off where the vehicle tilts
    if abs(roll_deg) > 5 or abs(pitch_deg) > 5:
        assert abs(max(port, starboard) - ALTITUDE_M) > 4 * DR


def test_water_column_is_dark_and_the_floor_lit_to_the_window_end():
    with sonarsim.Simulator(scene()) as sim:
        w = render_pings(sim, speckle=False)
    r = w.slant_range_m
    for side in range(2):
        line = w.samples[0, side]
        assert not line[r < ALTITUDE_M - DR].any()
        assert (line[(r > ALTITUDE_M + 0.1) & (r < RANGE_M - 0.1)] > 0).all()
    # The port and starboard of a level vehicle over a level floor: the same line.
    np.testing.assert_allclose(w.samples[0, 0], w.samples[0, 1], rtol=1e-5, atol=1e-12)


BOX = {"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [0.0, 15.0, 0.5]}}


def test_shadow_behind_a_box_against_the_closed_form():
    """A 1 m cube on the floor 15 m to port (near face 14.5 m, far face 15.5 m across track),
    the side-scan 10 m up: the box's echo ends at its far top edge, slant sqrt(15.5^2 + 9^2);
    the floor behind is hidden to where the ray over that edge lands, ground range
    15.5 * 10 / 9, slant sqrt(that^2 + 10^2). Its length on the floor gives the box's height
    back (altitude x shadow length / ground range of its end)."""
    with sonarsim.Simulator(scene(objects=[BOX])) as sim:
        w = render_pings(sim, speckle=False, labels=True)
    shadow = w.labels["shadow"][0, 0]
    r = w.slant_range_m
    start_m, end_m = r[shadow].min(), r[shadow].max()
    far_top = math.hypot(15.5, ALTITUDE_M - 1.0)
    ground_end = 15.5 * ALTITUDE_M / (ALTITUDE_M - 1.0)
    assert abs(start_m - far_top) <= 3 * DR, (start_m, far_top)
    assert abs(end_m - math.hypot(ground_end, ALTITUDE_M)) <= 3 * DR, (end_m, math.hypot(ground_end, ALTITUDE_M))
    # contiguous, no echo in it, and none on starboard
    k = np.nonzero(shadow)[0]
    assert (np.diff(k) == 1).all()
    assert not w.samples[0, 0][shadow].any()
    assert not w.labels["shadow"][0, 1].any()
    # the box's height from the shadow, as a surveyor measures it (ground ranges)
    g_start, g_end = math.sqrt(start_m ** 2 - ALTITUDE_M ** 2), math.sqrt(end_m ** 2 - ALTITUDE_M ** 2)
    assert abs(ALTITUDE_M * (g_end - 15.5) / g_end - 1.0) < 0.05
    # the box's samples carry its id; its box spans them
    ids = w.ids
    box_id = ids.index("box")
    box_samples = np.nonzero(w.labels["instance"][0, 0] == box_id)[0]
    assert box_samples.size and abs(r[box_samples].max() - far_top) <= 3 * DR
    assert w.labels["boxes"][box_id, 0, 1] == box_samples.min() and w.labels["boxes"][box_id, 1, 0] == -1
    assert g_start < 15.5 + 0.3  # (the shadow starts at the box's far edge)


def test_mirrored_scene_gives_the_mirrored_waterfall():
    box = {**BOX, "pose": {"position_m": [2.0, 12.0, 0.5], "rpy_deg": [0, 0, 20]}}
    mirrored = {**BOX, "pose": {"position_m": [2.0, -12.0, 0.5], "rpy_deg": [0, 0, -20]}}
    with sonarsim.Simulator(scene(objects=[box])) as sim:
        a = render_pings(sim, speckle=False)
    with sonarsim.Simulator(scene(objects=[mirrored])) as sim:
        b = render_pings(sim, speckle=False)
    assert a.samples[0, 0].max() > 10 * a.samples[0, 1][a.slant_range_m > 12].max() or a.samples[0, 0].any()
    np.testing.assert_allclose(a.samples[:, 0], b.samples[:, 1], rtol=2e-4, atol=1e-7 * a.samples.max())
    np.testing.assert_allclose(a.samples[:, 1], b.samples[:, 0], rtol=2e-4, atol=1e-7 * a.samples.max())


def test_a_pings_draws_are_its_own():
    doc = scene(sensor={"speckle": True})
    with sonarsim.Simulator(doc) as sim:
        all_four = render_pings(sim, n_pings=4)
        third = render_pings(sim, n_pings=1, first_ping=2)
        again = render_pings(sim, n_pings=4)
    np.testing.assert_array_equal(all_four.samples[2], third.samples[0])
    np.testing.assert_array_equal(all_four.samples, again.samples)
    assert not np.array_equal(all_four.samples[0], all_four.samples[1])  # speckle differs ping to ping


def test_a_moving_vehicle_pings_along_its_track():
    from sonarsim.dataset.trajectory import Trajectory

    track = Trajectory(times_s=[0.0, 10.0], positions_m=[[0, 0, ALTITUDE_M], [20, 0, ALTITUDE_M]],
                       quats_xyzw=[[0, 0, 0, 1], [0, 0, 0, 1]])
    box = {**BOX, "pose": {"position_m": [10.0, 15.0, 0.5]}}
    with sonarsim.Simulator(scene(objects=[box], ping_rate_hz=5.0)) as sim:
        w = render_pings(sim, trajectory=track, speckle=False, labels=True)
    assert w.n_pings == 51
    np.testing.assert_allclose(w.geometry.time_s, np.arange(51) * 0.2)
    np.testing.assert_allclose(w.geometry.x_m, np.arange(51) * 0.4, atol=1e-9)
    np.testing.assert_allclose(w.geometry.speed_m_s, 2.0)
    np.testing.assert_allclose(w.geometry.altitude_m, ALTITUDE_M)
    np.testing.assert_allclose(w.geometry.heading_deg, 90.0)  # yaw 0: east
    # the box is seen on the pings passing it (x within its half-metre, the beam's footprint)
    seen = np.nonzero((w.labels["instance"][:, 0] == w.ids.index("box")).any(axis=1))[0]
    x_seen = w.geometry.x_m[seen]
    assert x_seen.min() >= 10.0 - 0.5 - 0.2 and x_seen.max() <= 10.0 + 0.5 + 0.2 and len(seen) >= 2


def test_ground_range_puts_the_first_return_at_nadir():
    with sonarsim.Simulator(scene()) as sim:
        w = render_pings(sim, speckle=False)
    ground, g = w.ground_range()
    lit = np.nonzero(np.nan_to_num(ground[0, 0]) > 0)[0]
    assert g[lit[0]] < 0.5
    far = math.sqrt(RANGE_M ** 2 - ALTITUDE_M ** 2)
    assert np.isnan(ground[0, 0][g > far + 0.05]).all()
    assert w.display().shape == (1, 2 * N_SAMPLES)


@pytest.mark.parametrize("key, value", [("depression_deg", 0.0), ("vertical_beam_width_deg", 500),
                                        ("n_samples", 0), ("range_max_m", -1.0), ("frequency_khz", "x")])
def test_bad_values_are_named(key, value):
    with pytest.raises(ConfigError, match=f"sonar.{key}"):
        sonarsim.load_scene(scene(**{key: value}))


def test_a_sensor_key_is_named_in_the_instruments_section():
    with pytest.raises(ConfigError, match=r"sonar\.sensor\.speckle\.looks"):
        sonarsim.load_scene(scene(sensor={"speckle": {"looks": 0}}))


def test_spec_round_trips_through_its_section():
    s = sonarsim.load_scene(scene())
    spec = s.instruments[0]
    assert isinstance(spec, SidescanSpec) and spec.name == "sidescan"
    again = sonarsim.load_scene(s.to_dict())
    assert again.instruments[0] == spec


def test_the_sensor_chain_acts_on_the_waterfall():
    """A sensor section in the side-scan's section: TVG, noise and speckle, the output in 16-bit
    counts (integers within full scale); its expected output rises with the floor's echo."""
    doc = scene(sensor={"speckle": True, "noise": {"level_db": 40.0}, "output": {"dtype": "uint16"}})
    with sonarsim.Simulator(doc) as sim:
        drawn = render_pings(sim, n_pings=2)
        mean = render_pings(sim, n_pings=1, speckle=False)
    assert np.array_equal(drawn.samples, np.round(drawn.samples))  # drawn: counts (the expected output is their mean)
    for w in (drawn, mean):
        assert w.samples.min() >= 0 and w.samples.max() <= 65535
    r = mean.slant_range_m
    line = mean.samples[0, 0]
    assert line[(r > ALTITUDE_M + 1) & (r < 20)].mean() > line[r < ALTITUDE_M - 1].mean()  # floor above the water column
    assert not np.array_equal(drawn.samples[0], drawn.samples[1])


def test_the_surfaces_multipath_ghost_arrives_where_the_mirror_path_says():
    """A mirror-like surface 5 m above the side-scan (10 m over the floor): no echo of its own
    (albedo 0), but the paths that meet it. The first to arrive leaves down to the floor and
    comes back off the surface along the fan's upper edge (elevation e = 90 - 2 depression +
    margin above the horizontal: straight up is outside the fan): its range is
    (sqrt((20 / tan e)^2 + 10^2) + 20 / sin e) / 2 (19.04 m at e = 60.5 deg); nothing new
    arrives before it."""
    surface = {"name": "surface", "point_m": [0.0, 0.0, ALTITUDE_M + 5.0], "normal": [0.0, 0.0, -1.0],
               "albedo": 0.0, "specular": 0.9}
    plain, with_surface = scene(), scene(planes=[surface])
    for doc in (plain, with_surface):
        doc["render"] = {"max_order": 3}
    with sonarsim.Simulator(plain) as sim:
        a = render_pings(sim, speckle=False).samples[0, 0].astype(np.float64)
    with sonarsim.Simulator(with_surface) as sim:
        b = render_pings(sim, speckle=False).samples[0, 0].astype(np.float64)
    e = math.radians(90.0 - 2 * 15.0 + NADIR_MARGIN_DEG)
    span = 5.0 + (5.0 + ALTITUDE_M)  # the reflected receive leg's vertical run
    first = (math.hypot(span / math.tan(e), ALTITUDE_M) + span / math.sin(e)) / 2.0
    extra = b - a
    lit = np.nonzero(extra > 1e-9 * a.max())[0]
    assert abs(lit[0] * DR - first) <= 4 * DR, (lit[0] * DR, first)
    assert np.all(extra >= -1e-7 * a.max())


def test_rays_across_the_beam_span_its_along_track_width():
    doc = scene(horizontal_beam_width_deg=0.4)
    doc["render"]["azimuth_samples"] = 4
    with sonarsim.Simulator(doc) as sim:
        fan = sim.ray_fan(sim.scene.sonar)
    spread = np.degrees(fan.azimuth_rad.max() - fan.azimuth_rad.min())
    assert spread == pytest.approx(0.4 * 3 / 4)  # four sub-samples at the centres of quarters of 0.4 deg
