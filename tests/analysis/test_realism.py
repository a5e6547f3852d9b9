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
