"""Multibeam echosounder on the engine (issue 38 items 3 and 7): geometry checked by hand.

- a flat floor's soundings lie on the plane for any roll, pitch and heading (straight rays, and
  through a sound-speed profile when the processing uses the true one);
- each beam's range is ``altitude / (cos pitch cos(roll + angle))`` (the nadir beam's
  ``altitude / (cos pitch cos roll)``), the detection within a range sample of the truth;
- the ray tracer against a direct integration of the ray equations (scipy's solve_ivp) and the
  textbook arc of one constant-gradient layer;
- a wrong processing profile curls the outer beams: the depth error against angle as an
  independent integration predicts it, with the sign Snell's law gives;
- the mirrored scene gives the mirrored swath; a ping's draws are its own (seeded); bad keys
  are named.

Every test gives all the instrument's values (no device preset).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.core.transforms import rpy_to_matrix
from sonarsim.errors import ConfigError
from sonarsim.instruments import render_pings
from sonarsim.instruments.multibeam import (MultibeamSpec, SoundSpeedProfile, beam_table_deg, detect_bottom,
                                            georeference)

ALTITUDE_M, RANGE_M, N_SAMPLES = 10.0, 40.0, 2048
DR = RANGE_M / N_SAMPLES


def section(rpy_deg=(0.0, 0.0, 0.0), altitude_m=ALTITUDE_M, **keys) -> dict:
    s = {"type": "multibeam", "frequency_khz": 400.0, "n_beams": 65, "swath_deg": 120.0,
         "beam_spacing": "equiangular", "tx_beam_width_along_deg": 1.0, "rx_beam_width_across_deg": 1.0,
         "pulse_length_us": 30.0, "range_min_m": 0.0, "range_max_m": RANGE_M, "n_samples": N_SAMPLES,
         "ping_rate_hz": 10.0, "sound_speed_m_s": 1500.0, "detection": "amplitude", "detection_window_db": 10.0,
         "rays_across": "auto", "rays_along": "auto",
         "pose": {"position_m": [0.0, 0.0, altitude_m], "rpy_deg": list(rpy_deg)}}
    s.update(keys)
    return s


def scene(rpy_deg=(0.0, 0.0, 0.0), objects=(), altitude_m=ALTITUDE_M, **keys) -> dict:
    return {"sonar": section(rpy_deg, altitude_m, **keys), "ground": {"height_m": 0.0}, "objects": list(objects),
            "render": {"max_order": 1}}


def render(doc, **kwargs):
    with sonarsim.Simulator(doc) as sim:
        film = render_pings(sim, **kwargs)
        spec = sim.scene.instruments[0]
        world, vehicle = spec.soundings_points(film, [sim.scene.vehicle_pose] * film.n_pings)
        return film, spec, world, vehicle, sim.scene.vehicle_pose


ATTITUDES = [(0.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 8.0, 0.0), (-8.0, 6.0, 0.0), (5.0, -10.0, 30.0)]


@pytest.mark.parametrize("rpy", ATTITUDES)
def test_flat_floor_soundings_lie_on_the_plane(rpy):
    film, spec, world, vehicle, pose = render(scene(rpy), speckle=False)
    assert film.water_column.shape == (1, N_SAMPLES, 65) and film.angle_deg.shape == (1, 65)
    assert np.isfinite(film.two_way_time_s).all()
    # depth within a couple of range samples at every beam (the detection's error is along range)
    assert np.abs(world[0, :, 2]).max() <= 2 * DR, np.abs(world[0, :, 2]).max()
    # the truth points are on the floor too, and the soundings are at them
    assert np.abs(film.points_m[0, :, 2]).max() < 1e-4
    assert np.linalg.norm(world[0] - film.points_m[0], axis=1).max() <= 2 * DR
    # the vehicle frame: the same points seen from the (level-free) vehicle
    r = pose.rotation
    np.testing.assert_allclose(vehicle[0] @ r.T + pose.translation, world[0], atol=1e-9)
    # port beams land to port: across track (the vehicle's y) falls from beam 0 to the last
    assert (np.diff(vehicle[0, :, 1]) < 0).all()


@pytest.mark.parametrize("rpy", ATTITUDES)
def test_each_beams_range_against_hand_geometry(rpy):
    """A beam at angle a in the head's across-track plane meets the floor at range
    h / (cos pitch cos(roll + a)): the third row of R = Rz Ry Rx dotted with (0, sin a, -cos a)."""
    film, spec, *_ = render(scene(rpy), speckle=False)
    roll, pitch = math.radians(rpy[0]), math.radians(rpy[1])
    a = np.radians(spec.beam_table_deg())
    expected = ALTITUDE_M / (math.cos(pitch) * np.cos(roll + a))
    got = film.range_m[0]
    assert np.abs(got - expected).max() <= 1.0 * DR, np.abs(got - expected).max() / DR
    nadir = 32
    assert spec.beam_table_deg()[nadir] == 0.0
    assert abs(got[nadir] - ALTITUDE_M / (math.cos(pitch) * math.cos(roll))) <= 0.6 * DR
    # the trivial prediction (range = altitude / cos(angle)) is off where the vehicle tilts
    if abs(rpy[0]) >= 5:
        assert np.abs(got - ALTITUDE_M / np.cos(a)).max() > 20 * DR


def test_detection_range_accuracy_on_a_flat_floor():
    film, spec, *_ = render(scene(), speckle=False)
    truth = np.linalg.norm(film.points_m[0] - np.array([0.0, 0.0, ALTITUDE_M]), axis=1)
    err = film.range_m[0] - truth
    # within half a sample where the floor is met squarely, and far less on the slant beams
    # (their echo spans many samples: the centroid interpolates)
    assert np.abs(err).max() <= 0.55 * DR, np.abs(err).max() / DR
    outer = np.abs(spec.beam_table_deg()) > 30
    assert np.abs(err[outer]).max() <= 0.15 * DR, np.abs(err[outer]).max() / DR
    # and the backscatter falls away from nadir (the floor's angular response)
    level = film.intensity[0]
    assert level[32] > level[16] > level[0] > 0


def test_detect_bottom_on_a_hand_made_column():
    col = np.zeros((100, 3))
    col[40:44, 0] = [1.0, 4.0, 4.0, 1.0]      # centroid 41.5 + 0.5 (centres): 42.0 samples
    col[[10, 60], 1] = [0.01, 1.0]           # a faint echo 20 dB down stays out of the window
    r, level, window = detect_bottom(col, 0.0, 100.0, window_db=10.0)
    assert r[0] == pytest.approx(42.0) and level[0] == pytest.approx(2.5)
    assert r[1] == pytest.approx(60.5) and tuple(window[:, 1]) == (60, 61)
    assert np.isnan(r[2]) and np.isnan(level[2])


def test_equidistant_beams_are_evenly_spaced_across_track():
    film, spec, world, *_ = render(scene(beam_spacing="equidistant"), speckle=False)
    y = world[0, :, 1]
    step = np.diff(y)
    assert np.abs(step - step.mean()).max() < 0.02
    table = spec.beam_table_deg()
    np.testing.assert_allclose(np.diff(np.tan(np.radians(table))), np.diff(np.tan(np.radians(table))).mean())
    assert table[0] == pytest.approx(60.0) and table[-1] == pytest.approx(-60.0)


def test_an_asymmetric_swath_from_its_first_and_last_beam():
    doc = scene(swath_deg=None, beam_angles_deg=[63.0, -60.0], n_beams=256)
    spec = sonarsim.load_scene(doc).instruments[0]
    table = spec.beam_table_deg()
    assert table[0] == 63.0 and table[-1] == -60.0 and len(table) == 256 and (np.diff(table) < 0).all()
    np.testing.assert_allclose(beam_table_deg(3, 10.0, -10.0), [10.0, 0.0, -10.0])


BOX = {"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [0.5, 4.0, 0.5],
                                                                           "rpy_deg": [0, 0, 20]}}


def test_mirrored_scene_gives_the_mirrored_swath():
    mirrored = {**BOX, "pose": {"position_m": [0.5, -4.0, 0.5], "rpy_deg": [0, 0, -20]}}
    a, *_ = render(scene(objects=[BOX]), speckle=False)
    b, *_ = render(scene(objects=[mirrored]), speckle=False)
    # the box shows: the beams over it range shorter than the floor
    floor, *_ = render(scene(), speckle=False)
    hit = a.range_m[0] < floor.range_m[0] - 0.3
    assert hit[:32].any() and not hit[33:].any()
    peak = a.water_column.max()
    # (rtol 1e-3: a ray at a bin's edge, the nadir at exactly 10 m, falls either side by float32 round-off)
    np.testing.assert_allclose(a.water_column[..., ::-1], b.water_column, rtol=1e-3, atol=1e-6 * peak)
    np.testing.assert_allclose(a.two_way_time_s[:, ::-1], b.two_way_time_s, rtol=1e-6)
    np.testing.assert_allclose(a.angle_deg[:, ::-1], -b.angle_deg, atol=1e-6)
    np.testing.assert_allclose(a.points_m[:, ::-1] * [1, -1, 1], b.points_m, atol=1e-5)


def test_a_beam_half_on_an_object_has_its_truth_on_what_it_detected():
    """A 2 x 2 x 1 m box floating 4.5 m under the head, 1 to 3 m to port: the beams over its
    edges see it and the floor behind. The truth of each sounding is on a surface (the box's or
    the floor), not between them, and the sounding is at it."""
    box = {"name": "box", "primitive": "box", "size_m": [2.0, 2.0, 1.0], "pose": {"position_m": [0.0, 2.0, 5.0]}}
    film, spec, world, *_ = render(scene(objects=[box]), speckle=False)
    p = film.points_m[0]
    q = np.abs(p - [0.0, 2.0, 5.0]) - [1.0, 1.0, 0.5]
    to_box = np.abs(np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0))
    assert np.minimum(np.abs(p[:, 2]), to_box).max() < 1e-3
    on_box = to_box < 1e-3
    # its top, or the side facing the head (y = 1 m, seen obliquely)
    assert 5 <= on_box.sum() <= 20 and ((p[on_box, 2] > 5.5 - 1e-3) | (np.abs(p[on_box, 1] - 1.0) < 1e-3)).all()
    assert np.linalg.norm(world[0] - p, axis=1).max() <= 2 * DR


def test_a_pings_draws_are_its_own():
    doc = scene(sensor={"speckle": True})
    with sonarsim.Simulator(doc) as sim:
        all_four = render_pings(sim, n_pings=4)
        third = render_pings(sim, n_pings=1, first_ping=2)
        again = render_pings(sim, n_pings=4)
    np.testing.assert_array_equal(all_four.water_column[2], third.water_column[0])
    np.testing.assert_array_equal(all_four.two_way_time_s[2], third.two_way_time_s[0])
    np.testing.assert_array_equal(all_four.water_column, again.water_column)
    assert not np.array_equal(all_four.water_column[0], all_four.water_column[1])  # speckle differs
    np.testing.assert_allclose(all_four.geometry.time_s, [0.0, 0.1, 0.2, 0.3])


# -- sound speed ---------------------------------------------------------------------------

def integrate_ray(profile: SoundSpeedProfile, beta0: float, z0: float, t_end: float | None = None,
                  z_end: float | None = None):
    """The ray equations integrated with small steps: dx/dt = p c^2, dz/dt = c sqrt(1 - p^2 c^2)
    (p = sin(beta0) / c(z0), Snell), to a time or to a depth (an event). Returns (x, z, t)."""
    from scipy.integrate import solve_ivp

    p = math.sin(beta0) / float(profile.speed(z0))

    def f(_, y):
        c = float(profile.speed(y[1]))
        return [p * c * c, c * math.sqrt(max(0.0, 1.0 - (p * c) ** 2))]

    events = None
    if z_end is not None:
        def events(_, y):
            return y[1] - z_end
        events.terminal = True
    sol = solve_ivp(f, (0.0, t_end if t_end is not None else 10.0), [0.0, z0], events=events, rtol=1e-10,
                    atol=1e-10, max_step=2e-4)
    if z_end is not None:
        return sol.y_events[0][0][0], z_end, sol.t_events[0][0]
    return sol.y[0, -1], sol.y[1, -1], t_end


PROFILE = SoundSpeedProfile((0.0, 12.0, 25.0, 60.0), (1500.0, 1495.0, 1530.0, 1520.0))


@pytest.mark.parametrize("beta_deg", [0.0, 15.0, 40.0, 60.0, 70.0])
@pytest.mark.parametrize("z0", [0.0, 5.0, 14.0])
def test_ray_tracing_against_the_ray_equations(beta_deg, z0):
    beta = math.radians(beta_deg)
    p = math.sin(beta) / float(PROFILE.speed(z0))
    t = 0.035
    x, z = PROFILE.trace(np.array([p]), np.array([z0]), np.array([t]))
    xi, zi, _ = integrate_ray(PROFILE, beta, z0, t_end=t)
    assert abs(x[0] - xi) < 1e-5 and abs(z[0] - zi) < 1e-5, (x[0] - xi, z[0] - zi)
    # travel is the inverse of trace, and two-point ray tracing finds p and t again
    x2, t2, _ = PROFILE.travel(np.array([p]), np.array([z0]), z)
    assert abs(x2[0] - x[0]) < 1e-8 and abs(t2[0] - t) < 1e-12
    p3, t3 = PROFILE.solve(np.array([z0]), z, x)
    assert abs(p3[0] - p) < 1e-12 and abs(t3[0] - t) < 1e-11


def test_one_constant_gradient_layer_is_the_textbook_arc():
    """c = c0 + g z: the ray is a circle of radius 1 / (p g); x = (cos b0 - cos b) / (p g) and
    t = ln(tan(b / 2) / tan(b0 / 2)) / g between the angles b0 and b (from the vertical)."""
    c0, g = 1480.0, 0.8
    prof = SoundSpeedProfile((0.0, 100.0), (c0, c0 + 100.0 * g))
    b0 = np.radians([10.0, 35.0, 55.0])
    p = np.sin(b0) / c0
    z = 40.0
    b = np.arcsin(p * (c0 + g * z))
    x, t, _ = prof.travel(p, np.zeros(3), np.full(3, z))
    np.testing.assert_allclose(x, (np.cos(b0) - np.cos(b)) / (p * g), rtol=1e-10)
    np.testing.assert_allclose(t, np.log(np.tan(b / 2) / np.tan(b0 / 2)) / g, rtol=1e-10)
    # the sound bends away from the vertical as it speeds up (Snell): farther than a straight ray
    assert (x > z * np.tan(b0)).all()


def test_a_ray_that_turns_has_no_sounding():
    prof = SoundSpeedProfile((0.0, 50.0), (1500.0, 1650.0))
    p = math.sin(math.radians(70.0)) / 1500.0  # horizontal where c = 1596 m/s, at 32 m
    x, z = prof.trace(np.array([p]), np.zeros(1), np.array([0.3]))
    assert np.isnan(x[0]) and np.isnan(z[0])
    # beyond the 216 m that a ray grazing at 45 m reaches
    p2, _ = prof.solve(np.zeros(1), np.array([45.0]), np.array([300.0]))
    assert np.isnan(p2[0])


def test_a_bent_ray_meets_a_tilted_plane_where_the_ray_equations_put_it():
    from sonarsim.instruments.multibeam import bent_to_plane

    beta = np.radians([5.0, 30.0, 55.0])
    alpha = np.radians([0.0, 120.0, -60.0])
    u = np.stack([np.sin(beta) * np.cos(alpha), np.sin(beta) * np.sin(alpha), -np.cos(beta)], axis=1)
    n = np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0])  # a 13 deg slope
    point = np.array([[0.0, 0.0, -25.0]] * 3)  # the plane through (0, 0, -25) below the head
    origin = np.zeros(3)
    hit, t = bent_to_plane(origin, u, point, np.tile(n, (3, 1)), PROFILE, 3.0)
    np.testing.assert_allclose((hit - point) @ n, 0.0, atol=1e-6)
    for k in range(3):
        x, z, _ = integrate_ray(PROFILE, beta[k], 3.0, t_end=t[k])
        np.testing.assert_allclose(hit[k], [x * np.cos(alpha[k]), x * np.sin(alpha[k]), -(z - 3.0)], atol=1e-5)


H = 30.0  # the head at the surface, the floor 30 m down
TRUE = [[0.0, 1500.0], [40.0, 1540.0]]  # 1 m/s per metre: a strong thermocline


def profile_scene(rpy=(0.0, 0.0, 0.0), **keys):
    return scene(rpy, altitude_m=H, range_max_m=80.0, surface_height_m=H, sound_speed_profile=TRUE, **keys)


@pytest.mark.parametrize("refraction", ["arrival", "beam"])
@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (8.0, 0.0, 0.0), (-8.0, 6.0, 0.0), (5.0, -10.0, 30.0)])
def test_true_profile_processed_with_itself_lies_on_the_plane(rpy, refraction):
    film, spec, world, *_ = render(profile_scene(rpy, refraction=refraction), speckle=False)
    dr = 80.0 / N_SAMPLES
    ok = np.isfinite(film.two_way_time_s[0])
    assert ok.sum() >= 64
    assert np.abs(world[0, ok, 2]).max() <= 2 * dr, np.abs(world[0, ok, 2]).max()
    assert np.linalg.norm(world[0, ok] - film.points_m[0, ok], axis=1).max() <= 2 * dr
    assert np.abs(film.points_m[0, ok, 2]).max() < 1e-6  # the truth on the floor, either way
    bent = np.abs(film.angle_deg[0, ok] - spec.beam_table_deg()[ok])
    if refraction == "beam":  # the beam table's angles (the footprint's centroid: a hundredth of a degree)
        assert bent.max() < 0.01
    else:  # the arrival's: bent towards the vertical by up to about a degree at 60 deg
        assert 0.5 < bent.max() < 2.0
    # refraction is there: processed with straight rays the swath is not flat
    straight, _ = spec.soundings_points(film, [sonarsim.Pose((0, 0, H), rpy)], profile=None)
    assert np.nanmax(np.abs(straight[0, :, 2])) > 0.2


@pytest.mark.parametrize("refraction", ["arrival", "beam"])
@pytest.mark.parametrize("true, c0", [(TRUE, 1500.0), ([[0.0, 1540.0], [40.0, 1500.0]], 1540.0)])
def test_a_wrong_processing_profile_curls_the_outer_beams(true, c0, refraction):
    """True water 1500 m/s at the surface, faster below (1 m/s per m); the processing assumes
    1500 m/s throughout (and the mirror case: slower below, 1540 m/s assumed: the frown). At nadir the echo comes early: too shallow by about g H^2 / (2 c).
    Away from nadir Snell's law bends the true ray away from the vertical, so the straight
    ray of the same time and arrival angle goes deeper than the floor: to second order in the
    gradient the depth error is -(g H^2 / (2 c)) (1 - tan^2 b), zero near 45 deg, positive
    (too deep) beyond. Checked against an independent integration of the ray equations: the
    ray of each beam's arrival angle, integrated through the true water to the floor, gives the
    time, and a straight ray of that time at 1500 m/s its processed depth."""
    doc = profile_scene(processing_profile=[[0.0, c0]])
    doc["sonar"].update(sound_speed_profile=true, sound_speed_m_s=c0, refraction=refraction)
    film, spec, world, *_ = render(doc, speckle=False)
    dr = 80.0 / N_SAMPLES
    angle = film.angle_deg[0]
    depth_error = -world[0, :, 2]  # > 0: deeper than the floor
    water = SoundSpeedProfile.parse(true, "t")
    g = (true[1][1] - true[0][1]) / (true[1][0] - true[0][0])  # 1/s
    for j in range(0, 65, 4):
        b = math.radians(abs(angle[j]))
        x_i, _, t_i = integrate_ray(water, b, 0.0, z_end=H)
        assert abs(film.two_way_time_s[0, j] / 2.0 - t_i) * c0 <= 1.5 * dr  # the film's time
        predicted = c0 * t_i * math.cos(b) - H
        assert abs(depth_error[j] - predicted) <= 1.5 * dr, (j, depth_error[j], predicted)
    # the sign Snell's law gives, and the growth with angle
    g_term = g * H ** 2 / (2 * c0)  # > 0: faster below
    assert depth_error[32] == pytest.approx(-g_term, rel=0.1)
    outer = np.abs(angle) > 55
    assert (np.sign(g) * depth_error[outer] > 0.2).all()
    snell = -g_term * (1.0 - np.tan(np.radians(angle)) ** 2)
    assert np.abs(depth_error - snell).max() < 0.3 * np.abs(snell).max()
    half = np.sign(g) * depth_error[32:]  # nadir to starboard edge: the error grows with the angle
    assert (np.diff(half) > -0.5 * dr).all() and half[-1] - half[0] > 0.8
    np.testing.assert_allclose(depth_error, depth_error[::-1], atol=2 * dr)  # symmetric: a smile (or frown)


def test_georeference_applies_heave_and_the_lever_arm():
    t = np.array([[2 * 10.0 / 1500.0]])
    mount = sonarsim.Pose((1.0, 0.5, -0.2), (0.0, 0.0, 0.0))
    w, v = georeference(t, [[0.0]], [[0.0, 0.0, 90.0]], mount, position_m=[[5.0, 6.0, 20.0]], heave_m=[0.3])
    # yaw 90: the vehicle's x is the world's y; the head 1 m forward, 0.5 m to port, 0.2 m down
    np.testing.assert_allclose(w[0, 0], [5.0 - 0.5, 6.0 + 1.0, 20.0 + 0.3 - 0.2 - 10.0], atol=1e-12)
    np.testing.assert_allclose(v[0, 0], [1.0, 0.5, -10.2], atol=1e-12)
    r = rpy_to_matrix(0.0, math.radians(10.0), 0.0)
    w2, _ = georeference(t, [[0.0]], [[0.0, 10.0, 0.0]])
    np.testing.assert_allclose(w2[0, 0], r @ [0.0, 0.0, -10.0], atol=1e-12)


# -- the configuration -------------------------------------------------------------------

@pytest.mark.parametrize("key, value", [
    ("n_beams", 0), ("swath_deg", 200.0), ("beam_spacing", "random"), ("detection", "phase"),
    ("tx_beam_width_along_deg", 0.0), ("rx_beam_width_across_deg", "x"), ("pulse_length_us", -1.0),
    ("n_samples", 0), ("range_max_m", -1.0), ("frequency_khz", "x"), ("sound_speed_m_s", 900.0),
    ("sound_speed_profile", [[0, 1500], [0, 1510]]), ("processing_profile", "warm"),
    ("sound_speed_profile", [[0, 1500], [10, 2500]]), ("detection_window_db", 0.0), ("rays_across", 0),
    ("beam_angles_deg", [10.0, 20.0]), ("surface_height_m", "sea"), ("refraction", "curved"),
])
def test_bad_values_are_named(key, value):
    with pytest.raises(ConfigError, match=f"sonar.{key}"):
        sonarsim.load_scene(scene(**{key: value}))


def test_swath_and_beam_angles_together_are_refused():
    with pytest.raises(ConfigError, match="sonar.beam_angles_deg"):
        sonarsim.load_scene(scene(beam_angles_deg=[60.0, -60.0]))


def test_an_unknown_key_is_named():
    with pytest.raises(ConfigError, match="sonar.beams"):
        sonarsim.load_scene(scene(beams=12))


def test_spec_round_trips_through_its_section():
    s = sonarsim.load_scene(scene(sound_speed_profile=TRUE, processing_profile=[[0.0, 1500.0]], surface_height_m=H,
                                  sensor={"speckle": True}))
    spec = s.instruments[0]
    assert isinstance(spec, MultibeamSpec) and spec.name == "multibeam"
    assert spec.processing.speed_m_s == (1500.0,)
    again = sonarsim.load_scene(s.to_dict())
    assert again.instruments[0] == spec
    # the channel looks straight down: its axis is the vehicle's -z, its azimuth to port
    chan = spec.channels()[0]
    np.testing.assert_allclose(chan.mount.rotation @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(chan.mount.rotation @ [0, 1, 0], [0, 1, 0], atol=1e-12)


def test_the_banded_detection_equals_the_whole_column_one():
    rng = np.random.default_rng(1)
    wc = (rng.random((1024, 64)) ** 8).astype(np.float32)
    wc[:, 5] = 0.0                    # no echo
    wc[300:700, 7] = 1.0              # a window longer than the band
    wc[:, 9] = 0.0
    wc[1000:, 9] = 1.0                # at the far end of the column
    wc[:3, 11] = 2.0                  # at the near end
    full = detect_bottom(wc, 0.0, 50.0, 10.0, 3, band=None)
    banded = detect_bottom(wc, 0.0, 50.0, 10.0, 3)
    np.testing.assert_allclose(banded[0], full[0], rtol=1e-12)
    np.testing.assert_allclose(banded[1], full[1], rtol=1e-6)
    np.testing.assert_array_equal(banded[2], full[2])
    # the 3-sample envelope reaches one sample past a sharp edge (a third of the level: within 10 dB)
    assert np.isnan(full[0][5]) and tuple(full[2][:, 7]) == (299, 701) and tuple(full[2][:, 9]) == (999, 1024)


def test_a_head_on_a_mount_of_a_moving_vehicle():
    """The multibeam in a vehicle's instruments, with a lever arm and a mount rotation (a
    patch-test offset): its soundings still lie on the floor, and in the vehicle's frame they
    hang below the head's position on the vehicle."""
    from sonarsim.dataset.trajectory import Trajectory

    mbes = section()
    mbes.pop("pose")
    mbes.update(name="mbes", mount={"position_m": [0.5, 0.2, -0.3], "rpy_deg": [2.0, 0.0, 0.0]})
    doc = {"vehicle": {"pose": {"position_m": [0.0, 0.0, ALTITUDE_M]}}, "instruments": [mbes],
           "ground": {"height_m": 0.0}, "render": {"max_order": 1}}
    track = Trajectory(times_s=[0.0, 1.0], positions_m=[[0, 0, ALTITUDE_M], [2, 0, ALTITUDE_M]],
                       quats_xyzw=[sonarsim.Pose((0, 0, 0), (3.0, -4.0, 20.0)).quat_xyzw] * 2)
    with sonarsim.Simulator(doc) as sim:
        film = render_pings(sim, "mbes", trajectory=track, speckle=False)
        spec = sim.scene.instruments[0]
        from sonarsim.instruments import vehicle_poses

        poses, _ = vehicle_poses(sim, spec, trajectory=track)
        world, vehicle = spec.soundings_points(film, poses)
    assert film.n_pings == 11
    np.testing.assert_allclose(film.geometry.x_m[-1] - film.geometry.x_m[0], 2.0, atol=1e-9)
    assert np.abs(world[..., 2]).max() <= 2 * DR
    # in the vehicle frame: the head's lever arm, then the swath beneath it
    np.testing.assert_allclose(np.nanmean(vehicle[:, 32, :2], axis=0), [0.5, 0.2], atol=0.6)
    head_z = spec.mount.translation[2]
    assert (vehicle[..., 2] < head_z - 0.9 * ALTITUDE_M).all()
    # ignoring the mount's roll puts the far beams off the floor (the patch test's signature)
    wrong, _ = sonarsim.instruments.multibeam.georeference(
        film.two_way_time_s, film.angle_deg, [p.rpy_deg for p in poses], sonarsim.Pose(spec.mount.position_m),
        position_m=[p.position_m for p in poses], tilt_deg=film.tilt_deg)
    assert np.abs(wrong[..., 2]).max() > 0.3


def test_an_unknown_preset_is_named():
    # (without the presets module in the build, and with it: an unknown name either way)
    with pytest.raises(ConfigError, match="sonar.preset"):
        sonarsim.load_scene(scene(preset="no-such-multibeam"))


def test_the_benchmark_runs_at_tiny_sizes(tmp_path):
    """Smoke test of benchmarks/bench_multibeam.py (no timing is asserted)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "bench.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root / "src"), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / "bench_multibeam.py"), "--quick", "--json",
                           str(out)], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr
    res = json.loads(out.read_text())
    assert [r["n_beams"] for r in res["beams"]] == [16, 32] and len(res["samples"]) == 2
    for r in res["cases"] + res["beams"] + res["samples"]:
        assert r["ping_ms"] > 0 and r["bare_cast_ms"] > 0 and r["rays_per_ping"] > 0
        assert r["ping_over_cast"] == pytest.approx(r["ping_ms"] / r["bare_cast_ms"])


def test_soundings_under_speckle_scatter_about_the_floor():
    """With the sensor's speckle every ping's columns differ; the detection's depths scatter by
    a couple of samples (more on the slant outer beams, whose echo is long) about the floor,
    not off it."""
    with sonarsim.Simulator(scene(sensor={"speckle": True})) as sim:
        film = render_pings(sim, n_pings=20)
        spec = sim.scene.instruments[0]
        world, _ = spec.soundings_points(film, [sim.scene.vehicle_pose] * 20)
    z = world[..., 2]
    assert np.isfinite(z).all()
    assert np.sqrt((z ** 2).mean(axis=0)).max() <= 4 * DR
    assert abs(z.mean()) <= 0.3 * DR
    assert np.std(film.intensity[:, 32]) > 0.1 * film.intensity[:, 32].mean()  # the backscatter speckles too


def test_soundings_head_points_with_a_tilt():
    from sonarsim.image.films import PingGeometry, Soundings

    g = PingGeometry.of(1, sound_speed_m_s=1500.0)
    t = np.array([[2 * 10.0 / 1500.0, 2 * 20.0 / 1500.0]])
    s = Soundings(np.array([[30.0, -45.0]]), t, np.ones((1, 2)), g, tilt_deg=np.array([[0.0, 10.0]]))
    p = s.head_points()
    np.testing.assert_allclose(p[0, 0], [0.0, 5.0, -10.0 * math.cos(math.radians(30))], atol=1e-12)
    b, a = math.radians(10.0), math.radians(-45.0)
    np.testing.assert_allclose(p[0, 1], 20.0 * np.array([math.sin(b), math.cos(b) * math.sin(a), -math.cos(b) * math.cos(a)]))
    np.testing.assert_allclose(Soundings(s.angle_deg, t, s.intensity, g).head_points()[0, 0], p[0, 0])
    with pytest.raises(ValueError, match="tilt_deg"):
        Soundings(s.angle_deg, t, s.intensity, g, tilt_deg=np.zeros(2))
