"""The classifier two-sample test (issue 22 item 1): known answers on seeded synthetic images."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import check_grad

from sonarsim.analysis.twosample import (FEATURES, _loss_and_gradient, classifier_two_sample_test, fit_logistic,
                                         patch_features)

# A mean profile along range (a floor band over a rising background), the same in every beam.
_ROWS = np.arange(256)[:, None]
_PROFILE = (5.0 + 40.0 * np.exp(-0.5 * ((_ROWS - 150) / 40.0) ** 2)) * np.ones((1, 128))


def _speckled(seed: int, shape_k: float = 1.0, scale: float = 1.0) -> np.ndarray:
    """The profile under unit-mean gamma speckle of shape k (contrast 1 / sqrt(k); k = 1 is
    exponential, fully developed speckle in intensity)."""
    rng = np.random.default_rng(seed)
    return _PROFILE * scale * rng.gamma(shape_k, 1.0 / shape_k, size=_PROFILE.shape)


def test_the_loss_gradient_is_the_loss_derivative():
    rng = np.random.default_rng(1)
    X, s = rng.normal(size=(300, 4)), np.where(rng.random(300) < 0.4, -1.0, 1.0)
    for l2 in (0.0, 0.3):
        err = check_grad(lambda p: _loss_and_gradient(p, X, s, l2)[0], lambda p: _loss_and_gradient(p, X, s, l2)[1],
                         rng.normal(size=5))
        assert err < 1e-5


def test_logistic_regression_recovers_the_weights_of_a_logistic_model():
    # Labels drawn from P(y=1|x) = expit(x . w + b): the maximum-likelihood fit of 20,000 samples
    # (a negligible penalty) finds w and b within a few of their standard errors (about 0.03).
    rng = np.random.default_rng(2)
    w, b = np.array([1.5, -0.7, 0.0]), 0.4
    X = rng.normal(size=(20_000, 3))
    y = (rng.random(20_000) < 1.0 / (1.0 + np.exp(-(X @ w + b)))).astype(int)
    w_fit, b_fit = fit_logistic(X, y, l2=1e-6)
    assert np.allclose(w_fit, w, atol=0.1) and b_fit == pytest.approx(b, abs=0.1)
    # A strong penalty shrinks the weights towards 0 (and leaves the intercept free).
    w_shrunk, _ = fit_logistic(X, y, l2=10.0)
    assert np.linalg.norm(w_shrunk) < 0.2 * np.linalg.norm(w_fit)


def test_patch_features_of_known_patches():
    # One flat patch (echo 4) and one checkerboard of 1 and 3: known mean, contrast, correlations.
    image = np.full((16, 16), 4.0)
    image[:, 8:] = np.where((np.add.outer(np.arange(16), np.arange(8)) % 2) == 0, 1.0, 3.0)
    f = dict(zip(FEATURES, patch_features(image).T))
    assert np.allclose(f["log_mean"], [math.log(4.0), math.log(2.0)])
    assert np.allclose(f["contrast"], [0.0, 0.5])
    assert np.allclose(f["skewness"], [0.0, 0.0])
    # Every neighbouring pair of a checkerboard alternates: correlation -1 both ways.
    assert np.allclose(f["lag1_range"], [0.0, -1.0]) and np.allclose(f["lag1_beams"], [0.0, -1.0])
    assert np.allclose(f["q50_over_mean"], [1.0, 1.0]) and np.allclose(f["q90_over_mean"], [1.0, 1.5])
    assert np.allclose(f["range_position"], [0.5, 0.5])
    # A patch that is mostly zeros (a quantised dark water column) or leaves the mask is not used.
    image[:12, :8] = 0.0
    assert len(patch_features(image)) == 1
    mask = np.ones(image.shape, bool)
    mask[0, 15] = False
    assert len(patch_features(image, mask)) == 0


def test_two_draws_of_the_same_distribution_are_indistinguishable():
    # Same mean profile, same exponential speckle, independent seeds: the accuracy lies within
    # 3 null standard errors (sqrt(0.25 / n)) of 0.5 for every seed of the test.
    for k in range(3):
        res = classifier_two_sample_test([_speckled(10 + k), _speckled(20 + k)], [_speckled(30 + k), _speckled(40 + k)],
                                         seed=k)
        assert res.n_tested == 1024 and res.null_standard_error == pytest.approx(math.sqrt(0.25 / 1024))
        assert abs(res.accuracy - 0.5) < 3 * res.null_standard_error, res


def test_a_contrast_shifted_by_30_percent_is_detected():
    # Gamma speckle of contrast 0.5 against 0.65, same mean: per 128-cell patch the contrast is
    # known to about 0.04, so the classifier separates the sets nearly always.
    res = classifier_two_sample_test([_speckled(1, 4.0), _speckled(2, 4.0)],
                                     [_speckled(3, 4.0 / 1.3**2), _speckled(4, 4.0 / 1.3**2)])
    assert res.accuracy > 0.8 and res.z > 10, res


def test_a_mean_shift_is_detected_and_only_through_the_level():
    # A gain of 1.5 on a floor band over a dark background: the log mean differs by 0.41 while
    # the profile spans 2.2 along range; the cubic in range position lets a linear classifier
    # follow the profile.
    real, shifted = [_speckled(1, 4.0), _speckled(2, 4.0)], [_speckled(3, 4.0, 1.5), _speckled(4, 4.0, 1.5)]
    assert classifier_two_sample_test(real, shifted).accuracy > 0.8
    # The scale-free features do not see a gain: contrast, skewness and quantiles over the mean.
    blind = classifier_two_sample_test(real, shifted, features=("contrast", "skewness", "q10_over_mean",
                                                                 "q90_over_mean"))
    assert abs(blind.accuracy - 0.5) < 3 * blind.null_standard_error, blind


def test_the_range_position_alone_cannot_separate_identical_images():
    # The patches of both sets lie at the same positions: whatever the images hold, the range
    # position carries no label (cross-validation on the null falls a little below 0.5).
    res = classifier_two_sample_test(_speckled(5), _speckled(6, 4.0, 3.0),
                                     features=("range_position", "range_position_2", "range_position_3"))
    assert abs(res.accuracy - 0.5) < 3 * res.null_standard_error, res


def test_the_same_seed_gives_the_same_result_and_another_seed_another_draw():
    a, b = [_speckled(1), _speckled(2)], [_speckled(3), _speckled(4)]
    first = classifier_two_sample_test(a, b, seed=7)
    assert classifier_two_sample_test(a, b, seed=7) == first
    other = classifier_two_sample_test(a, b, seed=8)
    assert other.accuracies != first.accuracies
    assert first.seeds == 5 and len(first.accuracies) == 5 and first.seed_std >= 0.0


def test_too_few_patches_is_a_clear_error():
    small = _speckled(1)[:32, :32]  # 2 x 4 patches of 16 x 8
    with pytest.raises(ValueError, match=r"too few patches in the real images for a two-sample test: 8 of 16 x 8.*at least 20"):
        classifier_two_sample_test(small, _speckled(2))
    with pytest.raises(ValueError, match="too few patches in the simulated images for a two-sample test: 0 of"):
        classifier_two_sample_test(_speckled(1), np.zeros_like(_PROFILE))
    with pytest.raises(ValueError, match="folds"):
        classifier_two_sample_test(_speckled(1), _speckled(2), folds=1)
    with pytest.raises(ValueError, match="features"):
        classifier_two_sample_test(_speckled(1), _speckled(2), features=("colour",))
