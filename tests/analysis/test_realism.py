"""Realism statistics against closed forms and seeded statistics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from sonarsim.analysis.realism import (
    beam_profile_db, correlation_lengths, distribution_distances, range_profile_db, speckle_contrast,
)

SHAPE = (400, 256)


def test_fully_developed_speckle_has_contrast_one_in_intensity_and_0_52_in_amplitude():
    rng = np.random.default_rng(1)
    intensity = rng.exponential(1.0, SHAPE)
    # The local mean is estimated from 45 pixels, which adds a little variance: ~1/45.
    assert speckle_contrast(intensity) == pytest.approx(1.0, abs=0.06)
    amplitude = np.sqrt(intensity)  # Rayleigh: std/mean = sqrt(4/pi - 1)
    assert speckle_contrast(amplitude) == pytest.approx(np.sqrt(4 / np.pi - 1), abs=0.04)
    assert speckle_contrast(np.full(SHAPE, 3.0)) == pytest.approx(0.0, abs=1e-12)


def test_contrast_ignores_a_smooth_trend_and_follows_the_mask():
    rng = np.random.default_rng(2)
    trend = np.linspace(1.0, 50.0, SHAPE[0])[:, None] * np.ones(SHAPE)
    speckled = trend * rng.exponential(1.0, SHAPE)
    assert speckle_contrast(speckled) == pytest.approx(1.0, abs=0.06)
    mixed = np.where(np.arange(SHAPE[1]) < 128, speckled, trend)  # left half speckle, right smooth
    left = np.zeros(SHAPE, dtype=bool)
    left[:, 10:118] = True
    right = np.zeros(SHAPE, dtype=bool)
    right[:, 138:246] = True
    assert speckle_contrast(mixed, left) == pytest.approx(1.0, abs=0.08)
    assert speckle_contrast(mixed, right) < 0.02  # a ramp reflected at its ends bends the local mean a little


@pytest.mark.parametrize("sigma_range, sigma_beam", [(3.0, 1.5), (5.0, 2.0)])
def test_correlation_lengths_of_smoothed_noise_match_the_closed_form(sigma_range, sigma_beam):
    # White noise through a Gaussian of width sigma has autocorrelation exp(-lag^2 / (4 sigma^2)):
    # 1/e at lag 2 sigma. A wide local-mean window keeps the high-pass of the residual negligible.
    rng = np.random.default_rng(3)
    noise = gaussian_filter(rng.normal(size=(1200, 600)), (sigma_range, sigma_beam), mode="wrap")
    image = 1.0 + 0.1 * noise / noise.std()
    lengths = correlation_lengths(image, window=(101, 61))
    assert lengths.range_bins == pytest.approx(2 * sigma_range, rel=0.1)
    assert lengths.beams == pytest.approx(2 * sigma_beam, rel=0.1)


def test_white_speckle_has_a_grain_below_one_pixel():
    rng = np.random.default_rng(4)
    lengths = correlation_lengths(rng.exponential(1.0, SHAPE))
    assert lengths.range_bins < 1.0 and lengths.beams < 1.0


def test_distribution_distances():
    rng = np.random.default_rng(5)
    a = rng.exponential(2.0, SHAPE)
    b = rng.exponential(2.0, SHAPE)
    same = distribution_distances(a, b)
    assert same.ks < 0.01 and same.wasserstein < 0.03
    shifted = distribution_distances(a, b + 3.0)  # the earth mover moves every pixel by 3
    assert shifted.wasserstein == pytest.approx(3.0, abs=0.03)
    assert shifted.ks > 0.7
    # Regions of images of different shapes.
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:100] = True
    part = distribution_distances(a, b[:50, :60], mask_a=mask)
    assert part.ks < 0.05


def test_profiles_in_db():
    rows = np.logspace(-2, 1, SHAPE[0])
    image = rows[:, None] * np.ones(SHAPE)
    np.testing.assert_allclose(range_profile_db(image), 10 * np.log10(rows), rtol=1e-12)
    np.testing.assert_allclose(beam_profile_db(image), 10 * np.log10(rows.mean()), rtol=1e-12)
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:10, :] = True
    profile = range_profile_db(image, mask)
    np.testing.assert_allclose(profile[:10], 10 * np.log10(rows[:10]))
    assert np.all(np.isnan(profile[10:]))


def test_bad_regions_are_refused():
    image = np.ones(SHAPE)
    with pytest.raises(ValueError, match="shape"):
        speckle_contrast(image, np.ones((3, 3), dtype=bool))
    with pytest.raises(ValueError, match="fewer than two"):
        speckle_contrast(image, np.zeros(SHAPE, dtype=bool))
    with pytest.raises(ValueError, match="at least one pixel"):
        distribution_distances(image, image, mask_a=np.zeros(SHAPE, dtype=bool))


def test_the_real_oculus_floor_band_has_the_measured_speckle_contrast(shared_data):
    # DESIGN.md section 8 measured 0.29 in the floor band of the real M1200d ping (std/mean
    # after removing a 9 x 5 local mean): far below exponential speckle's 1.
    import sonarsim
    from sonarsim.analysis.realism import local_mean

    polar = sonarsim.read(shared_data / "real" / "oculus" / "one_ping_8bit.raw").polar.astype(float)
    band = local_mean(polar) > np.percentile(polar, 80)
    assert speckle_contrast(polar, band) == pytest.approx(0.29, abs=0.02)
    lengths = correlation_lengths(polar, band)
    assert 0.0 < lengths.range_bins < 3.0 and 0.5 < lengths.beams < 4.0


def _floor_band(rng, onset=None):
    """A synthetic polar image: weak water column, then a bright speckled band from ``onset``."""
    rows, beams = SHAPE
    onset = np.full(beams, 150) if onset is None else onset
    level = np.where(np.arange(rows)[:, None] >= onset[None, :], 100.0, 2.0)
    return level * rng.exponential(1.0, SHAPE), onset


def test_auto_regions_find_the_band_and_the_water_column_before_it():
    from sonarsim.analysis.realism import auto_regions

    rng = np.random.default_rng(6)
    onset = (150 + 40 * np.sin(np.linspace(0, np.pi, SHAPE[1]))).astype(int)  # a curved floor onset
    image, onset = _floor_band(rng, onset)
    regions = auto_regions(image)
    lit, water = regions["lit"], regions["water"]
    first_lit = lit.argmax(axis=0)
    # The local mean blurs the onset by half its window (9 bins) at most.
    assert np.all(np.abs(first_lit - onset) <= 5)
    rows = np.arange(SHAPE[0])[:, None]
    assert not (water & (rows >= onset[None, :] + 5)).any()  # (the same blur)
    assert water[: onset.min() - 5].all()
    assert lit[onset.max() + 10:].mean() > 0.95


def test_region_statistics_of_an_image_against_itself_and_against_another_draw():
    from sonarsim.analysis.realism import auto_regions, region_statistics

    rng = np.random.default_rng(7)
    a, _ = _floor_band(rng)
    same = region_statistics(a, a, auto_regions(a)["lit"])
    assert same["ks"] == 0.0 and same["wasserstein"] == 0.0 and same["range_profile_rms_db"] == 0.0
    assert same["contrast_a"] == same["contrast_b"]
    b, _ = _floor_band(rng)  # another speckle draw of the same scene
    other = region_statistics(a, b, auto_regions(a)["lit"])
    assert other["ks"] < 0.02 and abs(other["contrast_a"] - other["contrast_b"]) < 0.03
    brighter = region_statistics(a, 2 * b, auto_regions(a)["lit"])  # 3 dB too bright
    assert brighter["range_profile_rms_db"] == pytest.approx(10 * np.log10(2), abs=0.3)
    assert brighter["ks"] > 0.2


def test_compare_reports_region_statistics(tmp_path, capsys):
    import json

    from sonarsim.cli.main import main

    rng = np.random.default_rng(8)
    a, _ = _floor_band(rng)
    b, _ = _floor_band(rng)
    for name, img in (("a.npy", a), ("b.npy", b)):
        from PIL import Image

        Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)[::-1]).save(tmp_path / name.replace(".npy", ".png"))
    assert main(["compare", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--normalize", "none", "--stats",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["stats"]) == {"all", "lit", "water"}
    assert doc["stats"]["lit"]["ks"] < 0.05 and doc["stats"]["lit"]["pixels"] > 1000
