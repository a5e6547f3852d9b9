"""Trajectories: look-at, orbit, lawnmower and random poses against hand-computed poses;
resampling (linear positions, slerp orientations); CSV and TUM readers and their errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.core.memory import set_memory_budget
from sonarsim.core.transforms import Pose
from sonarsim.dataset.trajectory import (
    RandomPoses, Trajectory, lawnmower, look_at, look_at_rpy_deg, orbit, parse_trajectory, read_csv_trajectory,
    read_trajectory, read_tum_trajectory,
)
from sonarsim.errors import ConfigError

HEADER = "t,x,y,z,roll_deg,pitch_deg,yaw_deg\n"


def forward(pose: Pose) -> np.ndarray:
    """The sonar's acoustic axis (body x) in the world frame."""
    return pose.rotation[:, 0]


def angle_between_deg(r0: np.ndarray, r1: np.ndarray) -> float:
    """Angle of the rotation taking r0 to r1, degrees."""
    c = (np.trace(r0.T @ r1) - 1.0) / 2.0
    return math.degrees(math.acos(np.clip(c, -1.0, 1.0)))


# Look-at ---------------------------------------------------------------------------------

@pytest.mark.parametrize("position, target, rpy", [
    ((0, 0, 1), (1, 0, 0), (0, 45, 0)),          # 1 m ahead and 1 m below: 45 degrees down
    ((0, 0, 1), (0, 2, 1), (0, 0, 90)),          # to the left, level
    ((1, 1, 0), (0, 0, 0), (0, 0, -135)),        # behind-right, level
    ((0, 0, 2), (-math.sqrt(3), 0, 1), (0, 30, 180)),  # behind, 30 degrees down
    ((0, 0, 0), (1, 0, math.sqrt(3)), (0, -60, 0)),    # up: negative pitch
    ((0, 0, 3), (0, 0, 0), (0, 90, 0)),          # straight down
])
def test_look_at_hand_computed_angles(position, target, rpy):
    got = look_at_rpy_deg(position, target)
    np.testing.assert_allclose(got, rpy, atol=1e-9)
    d = np.subtract(target, position, dtype=float)
    np.testing.assert_allclose(forward(look_at(position, target)), d / np.linalg.norm(d), atol=1e-12)


def test_look_at_keeps_the_fan_level_and_applies_roll():
    rng = np.random.default_rng(1)
    for _ in range(50):
        p, t = rng.uniform(-5, 5, 3), rng.uniform(-5, 5, 3)
        pose = look_at(p, t)
        np.testing.assert_allclose(forward(pose), (t - p) / np.linalg.norm(t - p), atol=1e-12)
        assert abs(pose.rotation[2, 1]) < 1e-12  # body y (left) stays horizontal without roll
    rolled = look_at((0, 0, 0), (1, 0, 0), roll_deg=90.0)
    np.testing.assert_allclose(rolled.rotation[:, 1], [0, 0, 1], atol=1e-12)  # left axis turned up


def test_look_at_refuses_coincident_points():
    with pytest.raises(ValueError, match="coincides"):
        look_at_rpy_deg((1, 2, 3), (1, 2, 3))


# Orbit -----------------------------------------------------------------------------------

def test_orbit_positions_and_yaw_point_at_the_centre():
    centre = (1.0, 2.0, 0.5)
    tr = orbit(centre, radius_m=2.0, z_m=1.5, frames=4, rate_hz=2.0)
    np.testing.assert_allclose(tr.positions_m, [[3, 2, 1.5], [1, 4, 1.5], [-1, 2, 1.5], [1, 0, 1.5]], atol=1e-12)
    pitch = math.degrees(math.atan2(1.0, 2.0))  # 1 m above the centre, 2 m away
    expected_yaw = [180.0, -90.0, 0.0, 90.0]
    for k in range(4):
        pose = tr.pose(k)
        np.testing.assert_allclose(pose.rpy_deg, (0.0, pitch, expected_yaw[k]), atol=1e-9)
        d = np.asarray(centre) - pose.translation
        np.testing.assert_allclose(forward(pose), d / np.linalg.norm(d), atol=1e-12)
    np.testing.assert_allclose(tr.times_s, [0.0, 0.5, 1.0, 1.5])


def test_orbit_partial_sweep_includes_both_ends_and_goes_clockwise_when_negative():
    tr = orbit((0, 0, 0), 1.0, 0.0, frames=3, sweep_deg=90.0)
    np.testing.assert_allclose(tr.positions_m[:, :2], [[1, 0], [math.sqrt(0.5), math.sqrt(0.5)], [0, 1]], atol=1e-12)
    cw = orbit((0, 0, 0), 1.0, 0.0, frames=2, start_deg=90.0, sweep_deg=-90.0)
    np.testing.assert_allclose(cw.positions_m[:, :2], [[0, 1], [1, 0]], atol=1e-12)


# Lawnmower -------------------------------------------------------------------------------

def test_lawnmower_legs_turns_and_headings():
    tr = lawnmower([[0, 0], [4, 2]], spacing_m=1.0, z_m=1.2, speed_m_s=1.0, rate_hz=1.0, pitch_deg=20.0)
    # (0,0) -> (4,0) -> (4,1) -> (0,1) -> (0,2) -> (4,2): 14 m, a pose every metre.
    assert tr.n_frames == 15
    expected = {0: (0, 0, 0), 2: (2, 0, 0), 4: (4, 0, 90), 5: (4, 1, 180), 7: (2, 1, 180), 9: (0, 1, 90),
                10: (0, 2, 0), 14: (4, 2, 0)}
    for k, (x, y, yaw) in expected.items():
        pose = tr.pose(k)
        np.testing.assert_allclose(pose.position_m, (x, y, 1.2), atol=1e-12)
        np.testing.assert_allclose(pose.rpy_deg, (0.0, 20.0, yaw), atol=1e-12)
    np.testing.assert_allclose(tr.times_s, np.arange(15.0))


def test_lawnmower_along_y_from_the_far_corner():
    tr = lawnmower([[2, 4], [0, 0]], spacing_m=2.0, z_m=0.0, speed_m_s=2.0, rate_hz=1.0, legs_along="y")
    # Legs along y at x = 2 then 0, starting at (2, 4) heading -y: (2,4)->(2,0)->(0,0)->(0,4).
    np.testing.assert_allclose(tr.positions_m[:, :2], [[2, 4], [2, 2], [2, 0], [0, 0], [0, 2], [0, 4]], atol=1e-12)
    np.testing.assert_allclose([tr.pose(k).rpy_deg[2] for k in range(6)], [-90, -90, 180, 90, 90, 90], atol=1e-12)


def test_lawnmower_sampling_between_pings():
    tr = lawnmower([[0, 0], [3, 0]], spacing_m=1.0, z_m=0.0, speed_m_s=0.5, rate_hz=2.0)
    np.testing.assert_allclose(tr.positions_m[:, 0], np.arange(0, 3.01, 0.25))


# Resampling ------------------------------------------------------------------------------

def test_resampling_midpoints_linear_and_slerp():
    r0, r1 = (10.0, 20.0, 0.0), (-30.0, 40.0, 120.0)
    q = [Pose((0, 0, 0), r).quat_xyzw for r in (r0, r1)]
    tr = Trajectory([1.0, 3.0], [[0, 0, 0], [2, 4, -6]], q).resampled(1.0)
    np.testing.assert_allclose(tr.times_s, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(tr.positions_m[1], [1, 2, -3], atol=1e-12)
    a, m, b = (tr.pose(k).rotation for k in range(3))
    full = angle_between_deg(a, b)
    # slerp's midpoint lies halfway along the shortest rotation from the first to the last.
    assert angle_between_deg(a, m) == pytest.approx(full / 2, abs=1e-9)
    assert angle_between_deg(m, b) == pytest.approx(full / 2, abs=1e-9)
    np.testing.assert_allclose(a, Pose((0, 0, 0), r0).rotation, atol=1e-12)
    np.testing.assert_allclose(b, Pose((0, 0, 0), r1).rotation, atol=1e-12)


def test_resampling_about_one_axis_is_the_half_angle():
    q = [Pose((0, 0, 0), (0, 0, yaw)).quat_xyzw for yaw in (0.0, 90.0)]
    tr = Trajectory([0.0, 2.0], [[0, 0, 0], [0, 0, 0]], q).resampled(2.0)
    np.testing.assert_allclose([tr.pose(k).rpy_deg[2] for k in range(tr.n_frames)], [0, 22.5, 45, 67.5, 90], atol=1e-9)


@pytest.mark.parametrize("duration, rate, n", [(2.5, 2.0, 6), (2.4, 2.0, 5), (0.3, 10.0, 4), (1.0, 0.5, 1)])
def test_resampling_counts_stop_at_the_last_timestamp(duration, rate, n):
    q = [(0, 0, 0, 1)] * 2
    tr = Trajectory([0.0, duration], [[0, 0, 0], [1, 0, 0]], q).resampled(rate)
    assert tr.n_frames == n
    assert tr.times_s[-1] <= duration


def test_resampling_too_many_poses_names_the_rate():
    # A year-long track at the highest rate allowed (rates beyond 1e4 Hz are refused as such).
    tr = Trajectory([0.0, 3.2e7], [[0, 0, 0], [1, 0, 0]], [(0, 0, 0, 1)] * 2)
    with pytest.raises(ConfigError, match="trajectory.rate_hz.*memory budget"):
        tr.resampled(1e4)
    for rate in (0.0, 1e-300, 1e15):
        with pytest.raises(ConfigError, match=r"trajectory.rate_hz: must be within \[0.001, 10000\] pings per second"):
            tr.resampled(rate)


# Random poses ----------------------------------------------------------------------------

def test_random_poses_look_at_the_target_within_the_jitter():
    lo, hi = (-3.0, -3.0, 1.0), (-1.0, 3.0, 2.0)
    exact = RandomPoses(50, (lo, hi), ((0.0, 0.0, 0.2), (0.0, 0.0, 0.2)))
    jittered = RandomPoses(50, (lo, hi), ((0.0, 0.0, 0.2), (0.0, 0.0, 0.2)), jitter_deg=(2.0, 5.0))
    for k in range(50):
        pose = exact.pose(k, np.random.default_rng(k))
        p = np.array(pose.position_m)
        assert np.all(p >= lo) and np.all(p <= hi)
        d = np.array([0.0, 0.0, 0.2]) - p
        np.testing.assert_allclose(forward(pose), d / np.linalg.norm(d), atol=1e-12)
        j = jittered.pose(k, np.random.default_rng(k))  # same position and target, then the jitter
        assert j.position_m == pose.position_m
        dp, dy = np.subtract(j.rpy_deg, pose.rpy_deg)[1:]
        assert abs(dp) <= 2.0 and abs(dy) <= 5.0
    assert jittered.time_s(4) == 4.0


def test_random_poses_target_region_and_determinism():
    rp = RandomPoses(10, ((0, 0, 1), (1, 1, 1)), ((5, -1, 0), (6, 1, 0)))
    for k in range(10):
        pose = rp.pose(k, np.random.default_rng([7, k]))
        assert pose == rp.pose(k, np.random.default_rng([7, k]))
        # The axis meets the plane z = 0 inside the target box.
        p, f = pose.translation, forward(pose)
        hit = p + f * (-p[2] / f[2])
        assert 5 <= hit[0] <= 6 and -1 <= hit[1] <= 1
    with pytest.raises(ValueError):
        rp.pose(0)


# Files -----------------------------------------------------------------------------------

def test_csv_reader_round_trip_with_comments_and_blank_lines(tmp_path):
    f = tmp_path / "track.csv"
    f.write_text("# recorded 2026-11-23\n" + HEADER + "0, 1, 2, 3, 0, 10, 20\n\n1.5,4,5,6,5,-10,-170\n")
    tr = read_csv_trajectory(f)
    np.testing.assert_allclose(tr.times_s, [0.0, 1.5])
    assert tr.pose(1) == Pose((4.0, 5.0, 6.0), (5.0, -10.0, -170.0))
    assert tr.pose(0).rpy_deg == (0.0, 10.0, 20.0)
    np.testing.assert_allclose(Pose.from_quaternion((0, 0, 0), tr.quats_xyzw[1]).rotation, tr.pose(1).rotation,
                               atol=1e-12)


@pytest.mark.parametrize("text, match", [
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n", r"line 1: the header must be exactly t,x,y,z,roll_deg"),
    (HEADER, "header but no poses"),
    ("", "no poses"),
    (HEADER + "0,0,0,0,0,0,0\n1,0,0,0,0,0\n", r"line 3: expected 7 values"),
    (HEADER + "0,0,0,0,0,0,0\n1,0,zero,0,0,0,0\n", r"line 3: y is not a number"),
    (HEADER + "0,0,0,0,0,0,0\n1,0,nan,0,0,0,0\n", r"line 3: y must be finite"),
    (HEADER + "0,0,0,0,0,0,0\n# comment\n2,0,0,0,0,0,0\n1,0,0,0,0,0,0\n", r"line 5: time 1 s does not follow"),
    (HEADER + "0,0,0,0,0,0,0\n0,1,0,0,0,0,0\n", r"line 3: time 0 s does not follow"),
    (HEADER + "0,2e6,0,0,0,0,0\n", r"line 2: position .* beyond"),
    (HEADER + "0,0,0,0,0,0,1000\n", r"line 2: angles must lie within"),
])
def test_csv_reader_errors_name_file_and_line(tmp_path, text, match):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        read_csv_trajectory(f)
    assert info.value.key == "trajectory.file"
    assert "bad.csv" in str(info.value)


def test_tum_reader_quaternion_is_xyzw(tmp_path):
    s = math.sqrt(0.5)
    f = tmp_path / "track.txt"
    # A yaw of 90 degrees is (x, y, z, w) = (0, 0, s, s); a second pose pitched 90 degrees
    # (nose down) given unnormalised.
    f.write_text(f"# timestamp tx ty tz qx qy qz qw\n0.0 1 2 3 0 0 {s} {s}\n0.1 0 0 0 0 2 0 2\n")
    tr = read_tum_trajectory(f)
    np.testing.assert_allclose(tr.positions_m[0], [1, 2, 3])
    np.testing.assert_allclose(forward(tr.pose(0)), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(tr.pose(0).rpy_deg, [0, 0, 90], atol=1e-9)
    np.testing.assert_allclose(forward(tr.pose(1)), [0, 0, -1], atol=1e-12)  # positive pitch looks down
    assert read_trajectory(f).n_frames == 2  # guessed TUM


@pytest.mark.parametrize("text, match", [
    ("0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 1\n", r"line 2: expected 8 values"),
    ("0 0 0 0 0 0 0 0\n", r"line 1: the quaternion must not be zero"),
    ("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", r"line 2: time 0 s does not follow"),
    ("# only a comment\n", "no poses"),
])
def test_tum_reader_errors(tmp_path, text, match):
    f = tmp_path / "bad.txt"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match):
        read_tum_trajectory(f)


def test_format_guess_and_file_errors(tmp_path):
    f = tmp_path / "track.txt"
    f.write_text(HEADER + "0,0,0,0,0,0,0\n")
    assert read_trajectory(f).rpy_deg is not None  # a CSV header in a .txt file
    with pytest.raises(ConfigError, match="is a directory"):
        read_trajectory(tmp_path)
    with pytest.raises(ConfigError, match="not found"):
        read_trajectory(tmp_path / "missing.csv")
    b = tmp_path / "binary.csv"
    b.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="not UTF-8"):
        read_trajectory(b)


def test_a_file_too_large_for_the_budget_is_refused_before_reading(tmp_path):
    f = tmp_path / "big.csv"
    f.write_text(HEADER + "0,0,0,0,0,0,0\n" * 200_000)  # 3 MB
    set_memory_budget(2**20)
    try:
        with pytest.raises(ConfigError, match="trajectory.file.*memory budget"):
            read_trajectory(f)
    finally:
        set_memory_budget(None)


# The trajectory section -----------------------------------------------------------------

def test_parse_trajectory_file_relative_and_resampled(tmp_path):
    (tmp_path / "t.csv").write_text(HEADER + "0,0,0,0,0,0,0\n1,1,0,0,0,0,0\n")
    tr = parse_trajectory({"file": "t.csv", "rate_hz": 4.0}, tmp_path)
    assert tr.n_frames == 5
    np.testing.assert_allclose(tr.positions_m[:, 0], [0, 0.25, 0.5, 0.75, 1.0])
    with pytest.raises(ConfigError, match="rpy.csv: line 1"):
        (tmp_path / "rpy.csv").write_text("0 0 0 0 0 0 0 1\n")
        parse_trajectory({"file": "rpy.csv", "format": "csv"}, tmp_path)


@pytest.mark.parametrize("section, key", [
    ({}, "trajectory"),
    ({"file": "a.csv", "generate": {"kind": "orbit"}}, "trajectory"),
    ({"generate": {"kind": "orbit"}, "speed": 1}, "trajectory.speed"),
    ({"file": "a.csv", "rate_hz": 0}, "trajectory.rate_hz"),
    ({"file": "a.csv", "rate_hz": -2.0}, "trajectory.rate_hz"),
    ({"file": "a.csv", "rate_hz": "fast"}, "trajectory.rate_hz"),
    ({"file": "a.csv", "format": "kitti"}, "trajectory.format"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0}, "format": "csv"}, "trajectory.format"),
    ({"generate": {"kind": "spiral"}}, "trajectory.generate.kind"),
    ({"generate": {"centre_m": [0, 0, 0]}}, "trajectory.generate.kind"),
    ({"generate": "orbit"}, "trajectory.generate"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0}}, "trajectory.generate.frames"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 0, "z_m": 0, "frames": 3}},
     "trajectory.generate.radius_m"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0], "radius_m": 1, "z_m": 0, "frames": 3}},
     "trajectory.generate.centre_m"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0, "frames": 0}},
     "trajectory.generate.frames"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0, "frames": 2, "sweep_deg": 0}},
     "trajectory.generate.sweep_deg"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0, "frames": 10**12}},
     "trajectory.generate.frames"),
    ({"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "radius_m": 1, "z_m": 0, "frames": 2, "area_m": 1}},
     "trajectory.generate.area_m"),
    ({"generate": {"kind": "lawnmower", "area_m": [[0, 0], [1, 1]], "spacing_m": 1, "z_m": 0, "speed_m_s": 1}},
     "trajectory.rate_hz"),
    ({"rate_hz": 1, "generate": {"kind": "lawnmower", "area_m": [[0, 0], [1, 1]], "spacing_m": 1, "z_m": 0,
                                 "speed_m_s": 1e-12}}, "trajectory.generate.speed_m_s"),
    ({"rate_hz": 1, "generate": {"kind": "lawnmower", "area_m": [[0, 0], [1, 1e5]], "spacing_m": 1e-9, "z_m": 0,
                                 "speed_m_s": 1}}, "trajectory.generate.spacing_m"),
    ({"rate_hz": 1, "generate": {"kind": "lawnmower", "area_m": [[0, 0], [1, 1]], "spacing_m": 1, "z_m": 0,
                                 "speed_m_s": 1, "legs_along": "z"}}, "trajectory.generate.legs_along"),
    ({"rate_hz": 1, "generate": {"kind": "lawnmower", "area_m": [[0, 0]], "spacing_m": 1, "z_m": 0,
                                 "speed_m_s": 1}}, "trajectory.generate.area_m"),
    ({"rate_hz": 1, "generate": {"kind": "lawnmower", "area_m": [[1, 1], [1, 1]], "spacing_m": 1, "z_m": 0,
                                 "speed_m_s": 1}}, "trajectory.generate.area_m"),
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[0, 0, 0], [1, 1, 1]]}}, "trajectory.generate.look_at_m"),
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[0, 0, 0], [1, 1, 1]], "look_at_m": [0, 0, 0],
                   "look_at_bounds_m": [[0, 0, 0], [1, 1, 1]]}}, "trajectory.generate.look_at_m"),
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[1, 0, 0], [0, 1, 1]], "look_at_m": [0, 0, 0]}},
     "trajectory.generate.bounds_m"),
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[0, 0, 0], [1, 1, 1]], "look_at_m": [0, 0, 0],
                   "jitter_deg": [-1, 0]}}, "trajectory.generate.jitter_deg"),
    ({"generate": {"kind": "random", "frames": True, "bounds_m": [[0, 0, 0], [1, 1, 1]], "look_at_m": [0, 0, 0]}},
     "trajectory.generate.frames"),
])
def test_bad_trajectory_sections_name_the_key(tmp_path, section, key):
    with pytest.raises(ConfigError) as info:
        parse_trajectory(section, tmp_path)
    assert info.value.key == key, str(info.value)


# Issue 21 item 3: no hang, no traceback, no silent nonsense ---------------------------------

SCENE = {"sonar": {"n_beams": 16, "azimuth_fov_deg": 30, "elevation_fov_deg": 14, "range_min_m": 0.5,
                   "range_max_m": 5.0, "n_range_bins": 100}}


def orbit_scenario(**generate):
    return {"scene": SCENE, "seed": 0,
            "trajectory": {"generate": {"kind": "orbit", "centre_m": [0, 0, 0], "z_m": 0.0, "frames": 4, **generate}}}


@pytest.mark.parametrize("generate, message", [
    ({"radius_m": 1e7}, r"within \[0.5, 1000000\] m: the orbit must stay within 1e\+06 m"),   # empty frames
    ({"radius_m": 999_000.0, "centre_m": [5000, 0, 0]}, r"within \[0.5, 995000\] m"),
    ({"radius_m": 1e-12}, r"within \[0.5, .*range_min_m \(0.5 m\), in its blind zone"),       # on its own target
    ({"radius_m": 0.2, "z_m": 0.4}, r"within \[0.3, "),                       # 0.45 m from the centre
    ({"radius_m": 0.0}, r"within \[0.5, "),
])
def test_an_orbit_beyond_the_scene_or_on_its_target_is_refused(generate, message):
    from sonarsim.dataset import load_scenario

    with pytest.raises(ConfigError, match=message) as e:
        load_scenario(orbit_scenario(**generate))
    assert e.value.key == "trajectory.generate.radius_m"


def test_an_orbits_floor_is_a_millimetre_without_a_blind_zone_and_its_centre_is_bounded():
    generate = {"kind": "orbit", "centre_m": [0, 0, 0], "z_m": 0.0, "frames": 2}
    with pytest.raises(ConfigError, match=r"within \[0.001, .*sits on its own target") as e:
        parse_trajectory({"generate": {**generate, "radius_m": 1e-12}}, None)
    assert e.value.key == "trajectory.generate.radius_m"
    assert parse_trajectory({"generate": {**generate, "radius_m": 0.001}}, None).n_frames == 2
    with pytest.raises(ConfigError, match="within 1e\\+06 m of the origin") as e:
        parse_trajectory({"generate": {**generate, "radius_m": 1.0, "centre_m": [1e300, 0, 0]}}, None)
    assert e.value.key == "trajectory.generate.centre_m"


def test_a_csv_track_with_a_byte_order_mark_reads(tmp_path):
    # Spreadsheets save one; the header was refused as '\ufefft,x,...'.
    p = tmp_path / "track.csv"
    p.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0,0,0,1,0,10,0\n1,1,0,1,0,10,0\n", encoding="utf-8-sig")
    assert p.read_bytes().startswith(b"\xef\xbb\xbf")
    traj = read_trajectory(p)
    assert traj.n_frames == 2 and traj.positions_m[1].tolist() == [1.0, 0.0, 1.0]


def test_a_tum_quaternion_of_huge_numbers_is_a_direction_not_zero(tmp_path):
    # The squares of 1e308 overflowed and the quaternion was called zero.
    p = tmp_path / "track.tum"
    p.write_text("0 0 0 1 1e308 1e308 1e308 1e308\n1 1 0 1 0 0 0 2\n")
    traj = read_trajectory(p, "tum")
    np.testing.assert_allclose(traj.quats_xyzw, [[0.5, 0.5, 0.5, 0.5], [0, 0, 0, 1]])
    p.write_text("0 0 0 1 0 0 0 0\n")
    with pytest.raises(ConfigError, match="line 1: the quaternion must not be zero"):
        read_trajectory(p, "tum")
    big = Trajectory(np.array([0.0]), np.zeros((1, 3)), np.full((1, 4), 1e308))
    np.testing.assert_allclose(big.quats_xyzw, [[0.5, 0.5, 0.5, 0.5]])


@pytest.mark.parametrize("suffix", [".csv", ".tum", ".txt"])
def test_a_pipe_as_a_track_is_refused_not_read(tmp_path, suffix):
    import os

    from sonarsim.dataset import load_scenario
    from tests.fifo import no_hang

    fifo = tmp_path / f"track{suffix}"
    os.mkfifo(fifo)
    doc = {"scene": SCENE, "seed": 0, "trajectory": {"file": fifo.name}}
    with pytest.raises(ConfigError, match="not a regular file") as e:
        no_hang(lambda: load_scenario(doc, base_dir=tmp_path), [fifo])
    assert e.value.key == "trajectory.file" and str(fifo) in str(e.value)


@pytest.mark.parametrize("section, key, message", [
    ({"generate": {"kind": "orbit", "centre_m": [3, 0, 0], "radius_m": 3.0, "z_m": 1.0, "frames": 3}, "rate_hz": 1e300},
     "trajectory.rate_hz", r"\[0.001, 10000\] pings per second"),       # every frame at the same time
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[0, 0, 0], [1, 1, 1]], "look_at_m": [3, 0, 0]},
      "rate_hz": 1e-300}, "trajectory.rate_hz", r"\[0.001, 10000\]"),    # frames 1e300 s apart
    ({"generate": {"kind": "lawnmower", "area_m": [[0, 0], [4, 2]], "spacing_m": 1.0, "z_m": 1.0, "speed_m_s": 1e300},
      "rate_hz": 2.0}, "trajectory.generate.speed_m_s", r"\(0, 100\] m/s"),
    ({"generate": {"kind": "random", "frames": 3, "bounds_m": [[0, 0, 0], [1, 1, 1]], "look_at_m": [1e300, 0, 0]}},
     "trajectory.generate.look_at_m", "within 1e\\+06 m of the origin"),
])
def test_rates_speeds_and_targets_beyond_reason_are_refused(section, key, message):
    with pytest.raises(ConfigError, match=message) as e:
        parse_trajectory(section, None)
    assert e.value.key == key
