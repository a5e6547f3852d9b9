"""The flat-floor bound (sonarsim.analysis.flatfloor): hand-computed geometry, exact recovery
of an image of the model's own form, a monotone fit, and the pose and knot width it tells apart."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.analysis.flatfloor import flat_floor_bound, flat_floor_image, floor_elevation_deg

RANGE = np.linspace(0.05, 2.0, 160)
AZ = np.linspace(30.0, -30.0, 48)


def _rot_pitch_down(p_deg):
    p = np.radians(p_deg)
    # World vector of a sonar-frame vector for a sonar pitched down by p (about y).
    return np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])


@pytest.mark.parametrize("z, pitch", [(0.4, 0.0), (0.4, 30.0), (1.5, 12.0), (0.2, 70.0)])
def test_the_elevation_puts_each_range_on_the_floor(z, pitch):
    e = np.radians(floor_elevation_deg(RANGE, AZ, z, pitch))
    t = np.radians(AZ)[None, :]
    d = np.stack([np.cos(e) * np.cos(t), np.cos(e) * np.sin(t), np.sin(e)], axis=-1)
    world = d @ _rot_pitch_down(pitch).T
    seen = np.isfinite(e)
    assert seen.any()
    # The point at range r along that direction is on the floor z below the sonar.
    np.testing.assert_allclose((RANGE[:, None] * world[..., 2])[seen], -z, atol=1e-9)
    # the root on the side of the sonar's axis, not the one behind its back
    assert np.all(np.abs(e[seen]) <= np.pi / 2)
    # Ranges shorter than the height cannot reach it.
    assert not seen[RANGE < z].any()


def test_level_sonar_on_axis_is_arcsin():
    e = floor_elevation_deg([1.0, 2.0], [0.0], 0.5, 0.0)
    np.testing.assert_allclose(e[:, 0], -np.degrees(np.arcsin([0.5, 0.25])), atol=1e-12)


def _synthetic(z, pitch, knot, pattern_fn, seed=0):
    rng = np.random.default_rng(seed)
    e = floor_elevation_deg(RANGE, AZ, z, pitch)
    seen = np.isfinite(e)
    lo = e[seen].min()
    centre = lo + knot * (np.floor((np.where(seen, e, lo) - lo) / knot) + 0.5)
    p = np.where(seen, pattern_fn(centre), 0.0)
    a = 1.0 + 0.3 * rng.random(AZ.size)
    g = 80.0 * np.exp(-RANGE)
    c = 5.0 + 2.0 * np.sin(RANGE * 7.0)
    return a[None, :] * g[:, None] * p + c[:, None]


def test_an_image_of_the_models_form_is_recovered_exactly():
    y = _synthetic(0.4, 25.0, 2.0, lambda e: np.exp(-0.5 * ((e + 20.0) / 8.0) ** 2) + 0.05)
    fit = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 2.0, iterations=200)
    # Alternating least squares converges slowly along the factors' trade-offs, but far below
    # what the same fit leaves at a pose 5 degrees off.
    off = flat_floor_image(y, RANGE, AZ, 0.4, 30.0, 2.0, iterations=200)
    assert fit.mse < 1e-3 * np.mean(y ** 2)
    assert fit.mse < 0.05 * off.mse
    assert fit.pattern.max() == pytest.approx(1.0)


def test_each_sweep_never_raises_the_error():
    rng = np.random.default_rng(3)
    y = _synthetic(0.4, 25.0, 2.0, lambda e: 1.0 + 0.0 * e) * rng.gamma(2.0, 0.5, (RANGE.size, AZ.size))
    for rk in (None, 0.1):
        h = np.asarray(flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 3.0, iterations=30, range_knot_m=rk).history)
        assert np.all(np.diff(h) <= 1e-9 * h[0])


def test_the_bound_finds_the_pose_that_made_the_image_and_scores_held_out():
    rng = np.random.default_rng(5)
    mean = _synthetic(0.4, 25.0, 2.0, lambda e: np.exp(-0.5 * ((e + 20.0) / 6.0) ** 2) + 0.02)
    frames = [mean * rng.gamma(8.0, 1.0 / 8.0, mean.shape) for _ in range(3)]
    out = flat_floor_bound(frames[0], frames[1:], RANGE, AZ, [0.2, 0.4, 0.8], [10.0, 25.0, 45.0],
                           knots_deg=(2.0,), data_range=float(np.max(frames)), iterations=40)
    row = out["knots"][0]
    assert (row["height_m"], row["pitch_deg"]) == (0.4, 25.0)
    # Fitted on frame 0 only: the held-out score sits below the score on frame 0 itself.
    assert row["psnr"] < row["psnr_reference"]
    assert row["above_range_profile_db"] > 0.1  # the band's curvature that a range profile lacks
    assert set(out["baselines"]) == {"range profile", "separable", "ceiling"}


def test_coarse_knots_cannot_draw_fine_structure():
    fine = _synthetic(0.4, 25.0, 1.0, lambda e: 1.0 + 0.8 * (np.floor(e) % 2))  # a 1 deg comb
    errs = [flat_floor_image(fine, RANGE, AZ, 0.4, 25.0, k, iterations=60).mse for k in (1.0, 4.0)]
    assert errs[0] < 1e-3 * np.mean(fine ** 2)
    assert errs[1] > 20 * errs[0]


def test_a_smooth_range_law_cannot_follow_a_ridge():
    y = _synthetic(0.4, 25.0, 2.0, lambda e: 1.0 + 0.0 * e)
    y[80:83] *= 1.5  # a ridge across the fan at one range
    free = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 2.0, iterations=60)
    smooth = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 2.0, iterations=60, range_knot_m=0.2)
    assert free.mse < 1e-3 * np.mean(y ** 2)
    assert smooth.mse > 20 * free.mse


def test_mirrored_beams_give_the_mirrored_fit():
    rng = np.random.default_rng(1)
    y = _synthetic(0.4, 25.0, 2.0, lambda e: 1.0 + 0.0 * e) * rng.gamma(4.0, 0.25, (RANGE.size, AZ.size))
    a = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 3.0, iterations=20)
    b = flat_floor_image(y[:, ::-1], RANGE, -AZ, 0.4, 25.0, 3.0, iterations=20)
    np.testing.assert_allclose(b.image[:, ::-1], a.image, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kw, match", [(dict(knot_deg=0.0), "knot_deg"), (dict(height_m=-1.0), "height_m"),
                                       (dict(range_knot_m=float("nan")), "range_knot_m")])
def test_bad_arguments_are_named(kw, match):
    args = dict(height_m=0.4, pitch_deg=25.0, knot_deg=2.0)
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        flat_floor_image(np.ones((RANGE.size, AZ.size)), RANGE, AZ, **args)


def test_held_to_one_lobe_the_pattern_rises_to_the_axis_and_falls_after_it():
    rng = np.random.default_rng(2)
    # A two-lobed pattern: the free fit draws both lobes, the one-lobe fit cannot.
    y = _synthetic(0.4, 25.0, 2.0, lambda e: 0.1 + np.exp(-0.5 * ((e + 30.0) / 4.0) ** 2)
                   + np.exp(-0.5 * (e / 4.0) ** 2)) * rng.gamma(50.0, 1 / 50.0, (RANGE.size, AZ.size))
    free = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 2.0, iterations=40)
    lobe = flat_floor_image(y, RANGE, AZ, 0.4, 25.0, 2.0, iterations=40, lobe=True)
    assert np.all(np.diff(lobe.history) <= 1e-9 * lobe.history[0])
    p = lobe.pattern
    axis = int(np.floor(-lobe.knot_edges_deg[0] / 2.0))
    assert np.all(p >= 0)
    assert np.all(np.diff(p[: axis + 1]) >= -1e-12) and np.all(np.diff(p[axis:]) <= 1e-12)
    mean = _synthetic(0.4, 25.0, 2.0, lambda e: 0.1 + np.exp(-0.5 * ((e + 30.0) / 4.0) ** 2)
                      + np.exp(-0.5 * (e / 4.0) ** 2))
    free0 = flat_floor_image(mean, RANGE, AZ, 0.4, 25.0, 2.0, iterations=100)
    lobe0 = flat_floor_image(mean, RANGE, AZ, 0.4, 25.0, 2.0, iterations=100, lobe=True)
    assert lobe0.mse > 10 * free0.mse  # measured: 25 times
    # A pattern that is one lobe about the axis is fitted as well held as free.
    one = _synthetic(0.4, 25.0, 2.0, lambda e: 0.05 + np.exp(-0.5 * (e / 6.0) ** 2))
    a = flat_floor_image(one, RANGE, AZ, 0.4, 25.0, 2.0, iterations=100)
    b = flat_floor_image(one, RANGE, AZ, 0.4, 25.0, 2.0, iterations=100, lobe=True)
    assert b.mse <= 1.5 * a.mse + 1e-9 * np.mean(one ** 2)
