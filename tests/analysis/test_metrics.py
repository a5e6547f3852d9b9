"""Tests of sonarsim.analysis.metrics: MSE, PSNR, SSIM and normalisation.

SSIM is checked against scikit-image's ``structural_similarity`` (the reference the module
documents matching), MSE and PSNR against hand-computed values.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy import ndimage

from sonarsim.analysis.metrics import mse, normalize_255, psnr, ssim, ssim_support

def _skimage_ssim(a, b, full=False):
    metrics = pytest.importorskip("skimage.metrics")
    return metrics.structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=255,
        full=full,
    )


# --------------------------------------------------------------------------------------------
# MSE and PSNR
# --------------------------------------------------------------------------------------------


def test_mse_and_psnr_of_a_hand_computed_pair():
    a = np.zeros((2, 2))
    b = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert mse(a, b) == pytest.approx((1 + 4 + 9 + 16) / 4)
    assert psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 7.5))
    # Only the masked-in pixels count: 3 and 4.
    mask = np.array([[False, False], [True, True]])
    assert mse(a, b, mask) == pytest.approx((9 + 16) / 2)
    assert psnr(a, b, mask, data_range=1.0) == pytest.approx(10 * math.log10(1 / 12.5))


@pytest.mark.parametrize("d", [0.5, 1.0, 7.0, 100.0])
def test_a_constant_offset_d_gives_mse_d_squared(d):
    a = np.random.default_rng(1).uniform(0, 150, (13, 17))
    assert mse(a, a + d) == pytest.approx(d * d, rel=1e-12)
    assert mse(a + d, a) == pytest.approx(d * d, rel=1e-12)
    assert psnr(a, a + d) == pytest.approx(10 * math.log10(255**2 / d**2), rel=1e-12)


def test_identical_images_give_mse_0_psnr_inf_ssim_1():
    a = np.random.default_rng(2).uniform(0, 255, (30, 40)).astype(np.float32)
    assert mse(a, a) == 0.0
    assert psnr(a, a) == math.inf
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    const = np.full((20, 20), 37.0)
    assert ssim(const, const) == pytest.approx(1.0, abs=1e-12)


def test_metrics_reject_bad_input():
    a = np.zeros((12, 12))
    with pytest.raises(ValueError, match="same shape"):
        mse(a, np.zeros((12, 13)))
    with pytest.raises(ValueError, match="NaN"):
        mse(a, np.full((12, 12), np.nan))
    with pytest.raises(ValueError, match="mask"):
        mse(a, a, np.ones((12, 12), dtype=np.uint8))
    with pytest.raises(ValueError, match="data_range"):
        psnr(a, a + 1, data_range=0.0)
    with pytest.raises(ValueError, match="11 x 11"):
        ssim(np.zeros((10, 40)), np.zeros((10, 40)))
    # An empty selection has no mean.
    assert math.isnan(mse(a, a + 1, np.zeros((12, 12), dtype=bool)))
    assert math.isnan(psnr(a, a + 1, np.zeros((12, 12), dtype=bool)))


# --------------------------------------------------------------------------------------------
# SSIM against scikit-image
# --------------------------------------------------------------------------------------------


def _structured(shape, seed):
    """A disk, a ramp and a bright bar plus noise: edges, gradients and flat areas."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    img = 40.0 + 100.0 * (np.hypot(yy - shape[0] / 2, xx - shape[1] / 3) < min(shape) / 4)
    img += 0.5 * xx
    img[:, shape[1] * 2 // 3 : shape[1] * 2 // 3 + 4] = 250.0
    return np.clip(img + rng.normal(0, 5, shape), 0, 255)


@pytest.mark.parametrize("shape", [(11, 11), (48, 64), (81, 37)])
@pytest.mark.parametrize("seed", [0, 1])
def test_ssim_equals_scikit_image_on_random_images(shape, seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 255, shape)
    b = np.clip(0.7 * a + rng.normal(20, 25, shape), 0, 255)
    assert ssim(a, b) == pytest.approx(_skimage_ssim(a, b), abs=1e-6)


@pytest.mark.parametrize("seed", [0, 3])
def test_ssim_equals_scikit_image_on_structured_images(seed):
    a = _structured((70, 90), seed)
    b = ndimage.shift(_structured((70, 90), seed + 10), (1.5, -2.0), order=1, mode="nearest")
    b = np.clip(0.8 * b + 10, 0, 255).astype(np.uint8)  # integer input is accepted too
    ours = ssim(a, b)
    assert ours == pytest.approx(_skimage_ssim(a, b.astype(np.float64)), abs=1e-6)
    assert 0.0 < ours < 1.0
    assert ssim(b, a) == pytest.approx(ours, abs=1e-12)  # symmetric


def test_masked_ssim_averages_the_reference_map_over_the_eroded_mask():
    a = _structured((60, 80), 4)
    b = np.clip(a + np.random.default_rng(5).normal(0, 20, a.shape), 0, 255)
    yy, xx = np.mgrid[:60, :80]
    mask = np.hypot(yy - 35, xx - 40) < 24
    _, smap = _skimage_ssim(a, b, full=True)
    # Erosion by the 11 x 11 window, written independently of ssim_support.
    valid = ndimage.binary_erosion(mask, structure=np.ones((11, 11)), border_value=0)
    assert valid.sum() > 100
    assert np.array_equal(ssim_support(a.shape, mask), valid)
    assert ssim(a, b, mask) == pytest.approx(float(smap[valid].mean()), abs=1e-6)


def test_masked_ssim_ignores_the_pixels_outside_the_mask():
    rng = np.random.default_rng(6)
    a = _structured((50, 50), 6)
    b = np.clip(a + rng.normal(0, 10, a.shape), 0, 255)
    mask = np.zeros(a.shape, dtype=bool)
    mask[5:45, 10:40] = True
    other = a.copy()
    other[~mask] = rng.uniform(0, 255, int((~mask).sum()))
    assert ssim(other, b, mask) == pytest.approx(ssim(a, b, mask), abs=1e-12)
    assert mse(other, b, mask) == pytest.approx(mse(a, b, mask), abs=1e-12)


def test_ssim_support_without_mask_is_the_image_less_its_5_pixel_border():
    support = ssim_support((30, 25))
    expected = np.zeros((30, 25), dtype=bool)
    expected[5:-5, 5:-5] = True
    assert np.array_equal(support, expected)


# --------------------------------------------------------------------------------------------
# Normalisation
# --------------------------------------------------------------------------------------------


def test_normalize_max_divides_by_the_maximum():
    img = np.array([[0.0, 1.0], [2.0, 4.0]])
    assert np.allclose(normalize_255(img), [[0, 63.75], [127.5, 255]])
    # Scale-free: a simulation in any intensity units gives the same 0-255 image.
    assert np.allclose(normalize_255(img * 3e-5), normalize_255(img))
    # Negative values are not intensities: clipped to 0.
    assert np.allclose(normalize_255(np.array([[-2.0, 2.0]])), [[0, 255]])


def test_normalize_minmax_stretches_min_to_0_and_max_to_255():
    img = np.array([[2.0, 3.0], [4.0, 3.5]])
    assert np.allclose(normalize_255(img, mode="minmax"), [[0, 127.5], [255, 191.25]])


def test_normalize_takes_the_extremes_inside_the_mask_and_zeros_the_rest():
    img = np.array([[100.0, 1.0], [2.0, 4.0]])
    mask = np.array([[False, True], [True, True]])
    assert np.allclose(normalize_255(img, mask), [[0, 63.75], [127.5, 255]])
    assert np.allclose(normalize_255(img, mask, "minmax"), [[0, 0], [85, 255]])


def test_normalize_of_flat_images_is_zero_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not normalize_255(np.zeros((3, 3))).any()
        assert not normalize_255(np.full((3, 3), 5.0), mode="minmax").any()
        assert not normalize_255(np.ones((2, 2)), np.zeros((2, 2), dtype=bool)).any()
    with pytest.raises(ValueError, match="mode"):
        normalize_255(np.ones((2, 2)), mode="log")
