"""The band detector on a sea bed seen at a grazing angle: no speckle taken for edges.

Regression tests for ``sonarsim fit`` on the ARIS sample drifting to z 17.9 m (20.2 m and
pitch 66 deg from a start at z 2 m, pitch 10 deg): its sea bed is lit from the first range bin
to the last and fades with range, and the old detector took the strongest speckle rise and fall
(19-22 m out) for the band's edges.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.fitting import band_edges, band_view, fit_pose

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def grazing_scene(z, pitch):
    """48 beams over 28 deg, 14 deg of elevation, 1-14 m: at pitch 8 deg the highest ray of the
    aperture meets the floor 57 m out, far beyond the window."""
    return sonarsim.load_scene({
        "sonar": {"n_beams": 48, "azimuth_fov_deg": 28.0, "elevation_fov_deg": 14.0, "range_min_m": 1.0,
                  "range_max_m": 14.0, "n_range_bins": 700, "frequency_khz": 1200.0,
                  "pose": {"position_m": [0, 0, z], "rpy_deg": [0, pitch, 0]}},
        "ground": {"albedo": 0.5}, "render": {"bounces": [1]},
    })


def rayleigh(image, seed):
    """Fully developed speckle (Rayleigh amplitude: exponential intensity) and a weak noise floor."""
    rng = np.random.default_rng(seed)
    p = image.polar.astype(float)
    level = np.percentile(p[p > 0], 50)
    polar = (p * rng.exponential(1.0, p.shape) + 0.01 * level * rng.exponential(1.0, p.shape)).astype(np.float32)
    return replace(image, polar=polar, components={"total": polar})


def near_edge_m(z, pitch_deg, half_deg, azimuth_deg):
    """Flat-floor near edge without roll (DESIGN section 10): 1/r = A cos(theta) + B."""
    h, p = math.radians(half_deg), math.radians(pitch_deg)
    return z / (math.cos(h) * math.sin(p) * np.cos(np.radians(azimuth_deg)) + math.sin(h) * math.cos(p))


@pytest.fixture(scope="module")
def grazing():
    return rayleigh(sonarsim.render(grazing_scene(1.0, 8.0)), seed=3)


def test_a_speckled_grazing_floor_shows_its_near_edge_and_no_far_edge(grazing):
    near, far = band_edges(grazing)
    expect = near_edge_m(1.0, 8.0, 7.0, grazing.azimuth_deg)  # 3.86 m at the centre
    inner = slice(8, -8)  # the median across beams needs neighbours on both sides
    np.testing.assert_allclose(near[inner], expect[inner], atol=0.05)
    # The far edge is 57 m out: the band fades to the window's end; the old detector put one at
    # 4.5-6.7 m (the steepest fall of speckle on the fading echo).
    assert np.isnan(far).all()


def test_band_edges_of_a_bare_array_need_its_ranges(grazing):
    near, far = band_edges(grazing.polar, range_m=grazing.range_m, azimuth_deg=grazing.azimuth_deg)
    np.testing.assert_array_equal(near, band_edges(grazing)[0])
    with pytest.raises(ValueError, match="range_m"):
        band_edges(grazing.polar)


def test_a_speckled_grazing_floor_gives_its_height_back(grazing):
    # The near edge alone: with the pitch known, the height is fixed.
    res = fit_pose(grazing, grazing_scene(1.3, 8.0), free=("z",), domain="band")
    assert res.meaningful and abs(res.values["z"] - 1.0) < 0.01
    # Height and pitch together: one edge fixes one curve (DESIGN section 10), along which the
    # fit stays: its near edge is the true one, whatever the point on the curve.
    res = fit_pose(grazing, grazing_scene(1.3, 11.0), free=("z", "pitch"), domain="band")
    z, p = res.values["z"], res.values["pitch"]
    assert res.meaningful and near_edge_m(z, p, 7.0, 0.0) == pytest.approx(near_edge_m(1.0, 8.0, 7.0, 0.0), abs=0.03)


def test_the_aris_sea_bed_shows_no_band_edge(shared_data):
    real = sonarsim.read(shared_data / "real" / "aris" / "sample.aris", 0)
    near, far = band_edges(real)
    assert np.isnan(near).all() and np.isnan(far).all()
    view = band_view(real)
    assert view.lit_start.all() and view.fading.all()  # lit from 3.3 m, fading with range


def test_fit_on_the_aris_sample_gives_a_physically_plausible_pose(shared_data):
    """The sample's sea bed is lit from the window start (3.30 m) to its end (23.40 m) in every
    beam, fading with range, with no edge: the band's near edge lies before 3.30 m and its far edge
    beyond 23.40 m (or the highest ray never meets the floor). With the aperture [-h, +h] of the
    telephoto lens (h = 1.5 deg) and pitch p, height z (no roll), the centre beam's edges are at
    z / sin(p + h) <= 3.30 and z / sin(p - h) >= 23.40: p <= 2 deg and z <= 3.30 sin(3.5 deg) =
    0.20 m. A fit inside that region is all the image supports; z 17.9 m was far outside it."""
    real = sonarsim.read(shared_data / "real" / "aris" / "sample.aris", 0)
    scene = sonarsim.load_scene(EXAMPLES / "aris_seabed.yaml")  # z 1 m, pitch 5 deg: band inside the window
    res = fit_pose(real, scene, free=("z", "pitch"))
    assert res.domain == "band" and "without a band edge" in res.domain_reason
    assert res.meaningful and res.profile_correlation >= 0.5
    z, p = res.values["z"], math.radians(res.values["pitch"])
    h = math.radians(scene.sonar.elevation_fov_deg / 2)
    lo, hi = real.sonar.range_min_m, real.sonar.range_max_m
    assert 0 < z <= 0.21
    assert z / math.sin(p + h) <= lo + 0.05
    assert p <= h or z / math.sin(p - h) >= hi - 0.05
