"""Single-bounce images against analytic geometry and radiometry (paper Eq. 1-6, Algorithm 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.core.transforms import Pose
from sonarsim.renderer.formation import form_image
from tests.conftest import sonar_dict


def floor_range(h: float, tau_deg: float, theta_deg: np.ndarray, phi_deg: float) -> np.ndarray:
    """Range at which the ray (theta, phi) of a sonar at height h pitched down by tau meets z=0."""
    t, p, tau = np.radians(theta_deg), math.radians(phi_deg), math.radians(tau_deg)
    return h / (math.cos(p) * np.cos(t) * math.sin(tau) - math.sin(p) * math.cos(tau))


def first_last_nonzero(column: np.ndarray) -> tuple[int, int]:
    nz = np.flatnonzero(column > 0)
    return int(nz[0]), int(nz[-1])


@pytest.mark.parametrize("h,tau,elev", [(1.0, 20.0, 14.0), (0.7, 30.0, 10.0), (1.5, 15.0, 20.0)])
def test_flat_floor_onset_and_end_per_beam(h, tau, elev):
    # Everything lit between the analytic onset (lowest ray) and end (highest ray), no stripes.
    scene = {
        "sonar": sonar_dict(
            n_beams=64, elevation_fov_deg=elev, range_max_m=8.0, n_range_bins=1000,
            pose={"position_m": [0.0, 0.0, h], "rpy_deg": [0.0, tau, 0.0]},
        ),
        "ground": {"albedo": 0.8},
        "render": {"bounces": [1]},
    }
    img = sonarsim.render(scene)
    s = img.sonar
    onset = floor_range(h, tau, s.azimuth_deg, -elev / 2)
    end = floor_range(h, tau, s.azimuth_deg, +elev / 2)
    edges = s.range_edges_m
    for j in range(s.n_beams):
        first, last = first_last_nonzero(img.components["ground"][:, j])
        a = int(np.searchsorted(edges, onset[j], side="right")) - 1
        b = int(np.searchsorted(edges, min(end[j], s.range_max_m - 1e-9), side="right")) - 1
        assert abs(first - a) <= 1, (j, first, a)
        assert abs(last - b) <= 1, (j, last, b)
        assert np.all(img.components["ground"][first:last + 1, j] > 0), f"empty range bins in beam {j}"
    assert np.array_equal(img.polar, img.components["ground"])
    assert not img.components["object"].any()


def test_floor_without_splatting_shows_stripes_that_splatting_removes():
    # The regression the splatting exists for: too few rays on a grazing floor.
    scene = {
        "sonar": sonar_dict(n_range_bins=1288, pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}),
        "ground": {},
        "render": {"elevation_samples": 64, "range_splat": False},
    }
    img = sonarsim.render(scene)
    col = img.polar[:, 16]
    first, last = first_last_nonzero(col)
    assert (col[first:last] == 0).sum() > 100  # Algorithm 1 with 64 rays: mostly stripes
    scene["render"]["range_splat"] = True
    col = sonarsim.render(scene).polar[:, 16]
    first, last = first_last_nonzero(col)
    assert (col[first:last] == 0).sum() == 0


def nearest_sphere_range(centre, radius, theta_deg, elev_deg, n=200001):
    """Slow reference: minimum over the beam's elevation fan of the ray-sphere distance."""
    phi = np.radians(np.linspace(-elev_deg / 2, elev_deg / 2, n))
    t = math.radians(theta_deg)
    d = np.stack([np.cos(phi) * math.cos(t), np.cos(phi) * math.sin(t), np.sin(phi)], axis=1)
    c = np.asarray(centre, float)
    b = d @ c
    disc = b * b - c @ c + radius**2
    r = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0)), np.inf)
    return r.min()


def test_sphere_nearest_range_in_each_beam():
    centre, radius = (3.0, 0.25, 0.1), 0.4
    scene = {
        "sonar": sonar_dict(n_beams=48, n_range_bins=900),
        "objects": [{"name": "ball", "primitive": "sphere", "radius_m": radius, "pose": {"position_m": list(centre)}}],
    }
    img = sonarsim.render(scene)
    s = img.sonar
    seen = 0
    for j, theta in enumerate(s.azimuth_deg):
        ref = nearest_sphere_range(centre, radius, theta, s.elevation_fov_deg)
        col = img.polar[:, j]
        if not np.isfinite(ref):
            assert not col.any(), f"beam {j} misses the sphere but has echoes"
            continue
        seen += 1
        first, _ = first_last_nonzero(col)
        expected = int((ref - s.range_min_m) // s.range_resolution_m)
        # Tessellation (5120 faces) moves the surface by < 1 mm; one bin is 5 mm.
        assert abs(first - expected) <= 1, (j, first, expected)
    assert seen >= 10


@pytest.mark.parametrize("tvg", [True, False])
def test_wall_radiometry_matches_the_integral_of_eq3(tvg):
    # A wall x = d facing the sonar: cos(alpha) = cos(phi) cos(theta), r = d / (cos phi cos theta).
    d, rho, elev = 3.0, 0.6, 12.0
    scene = {
        "sonar": sonar_dict(elevation_fov_deg=elev),
        "objects": [{"name": "wall", "primitive": "box", "size_m": [0.2, 10.0, 10.0],
                     "pose": {"position_m": [d + 0.1, 0.0, 0.0]}, "albedo": rho}],
        "render": {"tvg": tvg},
    }
    img = sonarsim.render(scene)
    theta = np.radians(img.azimuth_deg)
    a = math.radians(elev) / 2
    if tvg:
        expected = rho * np.cos(theta) * 2 * math.sin(a)
    else:
        expected = rho * np.cos(theta) ** 3 / d**2 * 2 * (math.sin(a) - math.sin(a) ** 3 / 3)
    np.testing.assert_allclose(img.polar.sum(axis=0), expected, rtol=2e-3)
    # The echo spans exactly the ranges d/cos(theta) .. d/(cos(theta) cos(a)).
    j = 10
    first, last = first_last_nonzero(img.polar[:, j])
    s = img.sonar
    lo = d / math.cos(theta[j])
    hi = lo / math.cos(a)
    assert abs(s.range_m[first] - lo) <= s.range_resolution_m
    assert abs(s.range_m[last] - hi) <= s.range_resolution_m


def test_image_does_not_depend_on_the_number_of_rays():
    from sonarsim.config.examples import demo_scene_dict

    doc = demo_scene_dict()
    doc["render"] = {"elevation_samples": 150, "bounces": [1]}
    a = sonarsim.render(doc).polar.astype(float)
    doc["render"]["elevation_samples"] = 300
    b = sonarsim.render(doc).polar.astype(float)
    # Energy per beam agrees closely; the images agree up to sampling noise at silhouettes.
    np.testing.assert_allclose(a.sum(axis=0), b.sum(axis=0), rtol=0.02)
    k = np.ones(9) / 9
    sa = np.apply_along_axis(np.convolve, 0, a, k, "same")
    sb = np.apply_along_axis(np.convolve, 0, b, k, "same")
    assert np.abs(sa - sb).sum() / np.abs(sb).sum() < 0.03
    # ... whereas the unnormalised sum of rays would double.
    assert 0.95 < a.sum() / b.sum() < 1.05


def test_azimuth_samples_do_not_change_the_level():
    scene = {
        "sonar": sonar_dict(),
        "objects": [{"name": "wall", "primitive": "box", "size_m": [0.2, 10, 10], "pose": {"position_m": [3.1, 0, 0]}}],
        "render": {"azimuth_samples": 1},
    }
    a = sonarsim.render(scene).polar.sum(axis=0)
    scene["render"]["azimuth_samples"] = 4
    b = sonarsim.render(scene).polar.sum(axis=0)
    np.testing.assert_allclose(a, b, rtol=5e-3)


@pytest.mark.filterwarnings("ignore:the sonar is on the dry side")
@pytest.mark.filterwarnings("ignore:objects .* lie entirely beyond")  # on purpose
def test_empty_scene_and_objects_outside_the_field_of_view_give_zeros():
    empty = sonarsim.render({"sonar": sonar_dict()})
    assert empty.polar.shape == (400, 32) and empty.polar.dtype == np.float32
    assert not empty.polar.any()
    outside = {
        "sonar": sonar_dict(),
        "objects": [
            {"name": "behind", "primitive": "sphere", "radius_m": 0.5, "pose": {"position_m": [-3, 0, 0]}},
            {"name": "too_far", "primitive": "sphere", "radius_m": 0.5, "pose": {"position_m": [7, 0, 0]}},
            {"name": "above", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [3, 0, 1.5]}},
            {"name": "aside", "primitive": "box", "size_m": [1, 1, 1], "pose": {"position_m": [2, 2.5, 0]}},
            {"name": "too_near", "primitive": "sphere", "radius_m": 0.1, "pose": {"position_m": [0.3, 0, 0]}},
        ],
        "ground": {"height_m": 1.0},  # above the sonar: a floor it cannot see
    }
    img = sonarsim.render(outside)
    assert not img.polar.any()
    assert all(not c.any() for c in img.components.values())


def test_left_of_the_sonar_is_the_left_columns_and_pose_moves_the_view():
    ball = {"name": "ball", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [3.0, 0.5, 0.0]}}
    img = sonarsim.render({"sonar": sonar_dict(), "objects": [ball]})
    cols = np.flatnonzero(img.polar.any(axis=0))
    assert cols.max() < 16 and np.all(img.azimuth_deg[cols] > 0)
    # Yawing the sonar 90 degrees left puts an object on the world's +y axis straight ahead.
    ball2 = dict(ball, pose={"position_m": [0.0, 3.0, 0.0]})
    sim = sonarsim.Simulator({"sonar": sonar_dict(), "objects": [ball2]})
    assert not sim.render().polar.any()
    img = sim.render(pose={"position_m": [0, 0, 0], "rpy_deg": [0, 0, 90]})
    cols = np.flatnonzero(img.polar.any(axis=0))
    assert cols.min() + cols.max() == 31 and cols.size < 12  # centred on the middle beams


def test_the_image_carries_the_pose_it_was_rendered_at():
    start = Pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))
    sim = sonarsim.Simulator({"sonar": sonar_dict(pose=start.to_dict()), "ground": {}})
    assert sim.render().pose == start  # the scene's
    other = Pose((0.5, -0.2, 1.2), (2.0, 25.0, -5.0))
    for given in (other, other.matrix(), other.to_dict()):
        img = sim.render(pose=given)
        assert img.pose == other
        assert img.config["sonar"]["pose"] == other.to_dict()
        assert img.sonar is sim.scene.sonar  # the intrinsics, unchanged


def test_other_intrinsics_render_at_the_scene_pose_and_every_pose_shares_the_ray_fan():
    from dataclasses import replace

    pose = Pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))
    sim = sonarsim.Simulator({"sonar": sonar_dict(pose=pose.to_dict()), "ground": {}})
    fan = sim.ray_fan(sim.scene.sonar)
    sim.render(pose=Pose((0.0, 0.0, 1.5), (0.0, 30.0, 0.0)))
    # Keyed by the intrinsics: an equal configuration (another object) finds the same fan.
    assert sim.ray_fan(replace(sim.scene.sonar)) is fan
    near = replace(sim.scene.sonar, range_max_m=3.0)
    img = sim.render(sonar=near)
    assert img.pose == pose and img.sonar is near
    np.testing.assert_array_equal(img.range_m, near.range_m)
    assert img.config["sonar"]["range_max_m"] == 3.0 and img.config["sonar"]["pose"] == pose.to_dict()


def algorithm1_reference(distance, intensity, beam, range_min, dr, n_bins, n_beams):
    """The paper's Algorithm 1, literally (loops), for checking the vectorised version."""
    out = np.zeros((n_bins, n_beams))
    for r, i, p in zip(distance.ravel(), intensity.ravel(), beam.ravel()):
        if not np.isfinite(r):
            continue
        d = math.floor((r - range_min) / dr)
        if 0 <= d < n_bins:
            out[d, p] += i
    return out


def test_vectorised_algorithm1_equals_the_literal_loop():
    rng = np.random.default_rng(3)
    n_beams, n_el = 8, 50
    dist = rng.uniform(0.0, 6.0, (n_beams, 1, n_el))
    dist[rng.random(dist.shape) < 0.2] = np.inf
    inten = rng.random(dist.shape)
    beam = np.broadcast_to(np.arange(n_beams)[:, None, None], dist.shape)
    got = form_image(dist, inten, beam, 0.5, 0.01, 450, n_beams)[0]
    ref = algorithm1_reference(dist, inten, beam, 0.5, 0.01, 450, n_beams)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)


def test_range_splatting_conserves_energy_and_spreads_uniformly():
    # Two rays on one surface 10.4 bins apart: the energy between them spreads evenly.
    dist = np.array([[[1.0, 1.104]]])
    inten = np.array([[[2.0, 2.0]]])
    cont = np.array([[[True]]])
    img = form_image(dist, inten, np.zeros((1, 1, 1), int), 0.0, 0.01, 200, 1, continuous=cont)[0][:, 0]
    assert img.sum() == pytest.approx(4.0, rel=1e-12)
    # Extent: from 1.0 - 0.052 to 1.104 + 0.052 (extrapolated outer halves): 20.8 bins.
    nz = np.flatnonzero(img)
    assert nz[0] == 94 and nz[-1] == 115
    np.testing.assert_allclose(img[96:114], 4.0 / 20.8, rtol=1e-9)
    # An isolated ray lands in its own bin.
    img = form_image(dist, inten, np.zeros((1, 1, 1), int), 0.0, 0.01, 200, 1, continuous=~cont)[0][:, 0]
    assert img[100] == pytest.approx(2.0) and img[110] == pytest.approx(2.0) and img.sum() == pytest.approx(4.0)


def test_gaussian_beam_pattern_weights_the_aperture_as_documented():
    # beta(phi) = exp(-ln2 (phi / a)^2): half power at the aperture edges phi = +-a.
    from scipy.integrate import quad

    d, rho, elev = 3.0, 0.6, 12.0
    scene = {
        "sonar": sonar_dict(elevation_fov_deg=elev),
        "objects": [{"name": "wall", "primitive": "box", "size_m": [0.2, 10.0, 10.0],
                     "pose": {"position_m": [d + 0.1, 0.0, 0.0]}, "albedo": rho}],
        "render": {"beam_pattern": "gaussian"},
    }
    img = sonarsim.render(scene)
    a = math.radians(elev) / 2
    integral, _ = quad(lambda p: math.exp(-math.log(2) * (p / a) ** 2) * math.cos(p), -a, a)
    expected = rho * np.cos(np.radians(img.azimuth_deg)) * integral
    np.testing.assert_allclose(img.polar.sum(axis=0), expected, rtol=2e-3)


def test_speckle_is_seeded_unit_mean_exponential_and_leaves_the_components_clean():
    from sonarsim.config.examples import demo_scene_dict

    doc = demo_scene_dict()
    doc["render"] = {"speckle": True, "seed": 7, "elevation_samples": 60}
    sim = sonarsim.Simulator(doc)
    a, b = sim.render(), sim.render()
    clean = a.components["total"]
    lit = clean > 0
    ratio = a.polar[lit] / clean[lit]
    # Exponential with mean 1: mean 1, variance 1, median ln 2 (seeded, 40k+ samples).
    assert lit.sum() > 20000
    assert abs(ratio.mean() - 1) < 0.02 and abs(ratio.var() - 1) < 0.05
    assert abs(np.median(ratio) - math.log(2)) < 0.02
    assert not a.polar[~lit].any()
    assert not np.array_equal(a.polar, b.polar)  # a new draw every frame ...
    np.testing.assert_array_equal(a.components["total"], b.components["total"])
    again = sonarsim.Simulator(doc).render()  # ... and the same sequence for the same seed
    np.testing.assert_array_equal(again.polar, a.polar)
