"""The closed-form pose from a floor band's edges, against ray-plane geometry and a render."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.bandpose import band_family, fit_band_lines, pose_for_half_angle, pose_from_near_edge
from sonarsim.analysis.fitting import floor_band_m
from sonarsim.core.transforms import Pose
from tests.conftest import sonar_dict


def edge_ranges(z, pitch, roll, yaw, elevation_deg, azimuth_deg):
    """Range at which each beam's ray at ``elevation_deg`` meets the floor z=0 (ray-plane, by the pose's matrix)."""
    R = Pose((0.3, -0.2, z), (roll, pitch, yaw)).rotation
    th, e = np.radians(azimuth_deg), math.radians(elevation_deg)
    d = np.stack([np.cos(e) * np.cos(th), np.cos(e) * np.sin(th), np.full_like(th, np.sin(e))])
    down = -(R @ d)[2]
    return np.where(down > 0, z / np.where(down > 0, down, 1), np.nan)


@pytest.mark.parametrize("z,pitch,roll,h", [(0.5, 25.0, 0.0, 6.0), (1.2, 15.0, 3.0, 7.0), (0.4, 35.0, -2.0, 3.5)])
def test_the_pose_is_recovered_from_exact_edges_for_its_half_angle(z, pitch, roll, h):
    az = np.linspace(30, -30, 64)
    near = edge_ranges(z, pitch, roll, 40.0, -h, az)
    far = edge_ranges(z, pitch, roll, 40.0, +h, az)
    lines = fit_band_lines(az, near, far)
    assert lines.rms_m < 1e-9 and lines.n_near == 64 and lines.n_far == 64
    got = pose_for_half_angle(lines, h)
    assert got == pytest.approx((z, pitch, roll), abs=1e-6)
    # The near edge alone, the height given, gives back the pitch (the roll only to first order).
    zn, pn, rn = pose_from_near_edge(fit_band_lines(az, near), z, h)
    assert pn == pytest.approx(pitch, abs=0.3) and rn == pytest.approx(roll, abs=0.5)


def test_the_family_is_one_curve_every_member_of_which_draws_the_same_edges():
    az = np.linspace(30, -30, 64)
    near, far = edge_ranges(0.5, 25.0, 1.0, 0.0, -6.0, az), edge_ranges(0.5, 25.0, 1.0, 0.0, 6.0, az)
    lines = fit_band_lines(az, near, far)
    family = band_family(lines, [3.0, 6.0, 10.0])
    zs = [m["z"] for m in family]
    # A wider aperture draws the same band from higher up and pitched further down.
    assert zs[0] < zs[1] < zs[2]
    assert family[0]["pitch"] < family[1]["pitch"] < family[2]["pitch"]
    assert family[1]["z"] == pytest.approx(0.5) and family[1]["pitch"] == pytest.approx(25.0)
    for m in family:
        n2 = edge_ranges(m["z"], m["pitch"], m["roll"], 0.0, -m["half_angle_deg"], az)
        f2 = edge_ranges(m["z"], m["pitch"], m["roll"], 0.0, m["half_angle_deg"], az)
        np.testing.assert_allclose(n2, near, rtol=1e-9)
        np.testing.assert_allclose(f2, far, rtol=1e-9)


def test_outlying_edges_are_rejected():
    az = np.linspace(30, -30, 64)
    near, far = edge_ranges(0.5, 25.0, 0.0, 0.0, -6.0, az), edge_ranges(0.5, 25.0, 0.0, 0.0, 6.0, az)
    near[[3, 10, 40]] = [0.2, 2.5, 0.9]  # speckle taken for edges
    far[5] = 0.8
    lines = fit_band_lines(az, near, far)
    assert lines.n_near == 61 and lines.n_far == 63
    assert pose_for_half_angle(lines, 6.0) == pytest.approx((0.5, 25.0, 0.0), abs=1e-6)


def test_too_few_edges_and_a_missing_far_edge_are_refused():
    az = np.linspace(30, -30, 16)
    with pytest.raises(ValueError, match="near edge"):
        fit_band_lines(az, np.full(16, np.nan))
    lines = fit_band_lines(az, edge_ranges(0.5, 25.0, 0.0, 0.0, -6.0, az))
    assert not lines.both_edges
    with pytest.raises(ValueError, match="far edge"):
        pose_for_half_angle(lines, 6.0)


def test_a_rendered_floor_band_gives_its_pose_back():
    """A noise-free render with a sharp 12-degree aperture: the edges are at +-6 degrees."""
    z, pitch, roll = 0.5, 25.0, 2.0
    scene = {"sonar": sonar_dict(n_beams=96, n_range_bins=600, range_min_m=0.2, range_max_m=3.0,
                                 elevation_fov_deg=12.0, pose={"position_m": [0, 0, z], "rpy_deg": [roll, pitch, 0]}),
             "ground": {"height_m": 0.0, "albedo": 0.8}, "render": {"bounces": [1]}}
    img = sonarsim.render(scene)
    near, far = floor_band_m(img)
    lines = fit_band_lines(img.azimuth_deg, near, far)
    got = pose_for_half_angle(lines, 6.0)
    assert got[0] == pytest.approx(z, abs=0.02)
    assert got[1] == pytest.approx(pitch, abs=1.0)
    assert got[2] == pytest.approx(roll, abs=1.0)
