"""A classifier two-sample test (C2ST): can a simple classifier tell real patches from simulated ones?

A pixel-wise score (PSNR, SSIM) rewards a smooth image; a per-region statistic (speckle
contrast, KS) looks at one property at a time. The C2ST asks the question a reviewer asks of
synthetic data as a whole: given small patches of a real and of a simulated image, described
by a few texture statistics, how often does a classifier trained on other patches tell which is
which (Lopez-Paz and Oquab, "Revisiting classifier two-sample tests", ICLR 2017)?

* Both images (or lists of images) are cut into patches, by default 16 range bins x 8 beams on
  a grid from the nearest bin and the left-most beam; a patch is used when all its cells lie
  inside the mask and it holds echo (see :func:`patch_features`).
* Each patch is described by :data:`FEATURES`: its log mean, its speckle contrast (std / mean),
  its skewness, its lag-1 correlation along range and across beams, the 10th, 50th and 90th
  percentiles of its values over its mean, and its range position (row of its centre over the
  number of rows) with the square and cube of its centred value ``2 p - 1``: a linear
  classifier then compares the log mean with a level that follows a smooth range profile (with
  the position alone, a gain of 1.5 on a floor band over a dark background goes undetected, 0.57,
  since no single threshold on the log mean fits every range; with the cubic, 0.82).
* An L2-regularised logistic regression (:func:`fit_logistic`, L-BFGS on the log-loss and its
  gradient) is cross-validated over ``k`` stratified folds, the classes balanced by drawing
  from the larger one as many patches as the smaller holds, the features standardised on each
  training fold alone. This is repeated for several seeds (the draw and the folds change).

What the accuracy means: 0.5 is chance, i.e. the classifier found nothing in these statistics
that tells the two sets apart; 1 is a perfect separation. Under the null hypothesis (the same
distribution) each of the ``n`` held-out predictions is a fair coin, so the accuracy has a
standard error of ``sqrt(0.25 / n)`` (:attr:`C2STResult.null_standard_error`); an accuracy more
than about 3 of these above 0.5 is evidence of a difference. Cross-validation on the null can
fall slightly *below* 0.5 (a held-out patch leaves its own class under-represented in
training), so values a little under 0.5 mean "indistinguishable" too; copies of the same patches
in both sets (an image against itself, or real pings whose speckle is frozen) go further below
(0.46 for an Oculus ping against itself), since a patch's twin in training has the other label.
An accuracy near 0.5 says only that *these* statistics do not differ: a classifier on other
features might still separate the sets.

Images are polar ``(n_range_bins, n_beams)`` arrays; any unit (counts or intensity), since every
feature but the log mean is scale-free and the log mean's offset is learned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .metrics import _as_image, _as_mask

__all__ = ["FEATURES", "PATCH_SHAPE", "C2STResult", "classifier_two_sample_test", "fit_logistic",
           "patch_features"]

#: Names of the patch features, in the order of :func:`patch_features`' columns.
FEATURES = ("log_mean", "contrast", "skewness", "lag1_range", "lag1_beams", "q10_over_mean",
            "q50_over_mean", "q90_over_mean", "range_position", "range_position_2", "range_position_3")

#: Default patch size (range bins, beams): DESIGN.md section 10.
PATCH_SHAPE = (16, 8)

#: A patch holds echo when at least this fraction of its cells is non-zero (an 8-bit device
#: quantises a dark water column to zeros, where the log mean and the quantiles say nothing).
MIN_NONZERO_FRACTION = 0.5

_QUANTILES = (10.0, 50.0, 90.0)


def _images(images: Any, name: str) -> list[np.ndarray]:
    """One 2-D image, a 3-D stack or a sequence of 2-D images, as float64 arrays."""
    if isinstance(images, (list, tuple)) and images and np.ndim(images[0]) == 2:
        return [_as_image(im, f"{name}[{k}]") for k, im in enumerate(images)]
    arr = np.asarray(images)
    if arr.ndim == 3:
        return [_as_image(im, f"{name}[{k}]") for k, im in enumerate(arr)]
    return [_as_image(arr, name)]


def patch_features(image: Any, mask: Any = None, patch: tuple[int, int] = PATCH_SHAPE,
                   features: Sequence[str] = FEATURES) -> np.ndarray:
    """The feature vectors of an image's patches.

    The image is tiled by ``patch`` from row 0 and column 0 (a remainder at the far range or
    the right edge is left out). A tile is used when every cell lies in ``mask`` and at least
    :data:`MIN_NONZERO_FRACTION` of its cells are non-zero.

    Parameters
    ----------
    image : (n_range_bins, n_beams) array-like
        Non-negative values (counts or intensity).
    mask : (n_range_bins, n_beams) bool array-like, optional
        Where patches may lie (default everywhere).
    patch : (int, int)
        Patch size in range bins and beams, each >= 2 (a lag-1 correlation needs two cells).
    features : sequence of str
        Names from :data:`FEATURES`, in the order wanted.

    Returns
    -------
    (n_patches, len(features)) float64 ndarray
        Dimensionless but for ``log_mean`` (natural log of the image's unit). Undefined values
        of a flat patch (skewness, correlations) are 0.
    """
    x = _as_image(image, "image")
    m = _as_mask(mask, x.shape)
    unknown = [f for f in features if f not in FEATURES]
    if unknown or not len(features):
        raise ValueError(f"features must be a non-empty selection of {', '.join(FEATURES)}, got {list(features)}")
    if len(patch) != 2 or min(int(v) for v in patch) < 2:
        raise ValueError(f"patch must be two sizes >= 2 (range bins, beams), got {patch}")
    h, w = (int(v) for v in patch)
    if (x < 0).any():
        raise ValueError("image must be non-negative (intensities or counts)")
    nr, nb = x.shape[0] // h, x.shape[1] // w
    if nr == 0 or nb == 0:
        return np.zeros((0, len(features)))
    # (nr, nb, h, w) view of the tiles, then one row per tile.
    tiles = x[: nr * h, : nb * w].reshape(nr, h, nb, w).swapaxes(1, 2).reshape(nr * nb, h, w)
    keep = (tiles > 0).mean(axis=(1, 2)) >= MIN_NONZERO_FRACTION
    if m is not None:
        keep &= m[: nr * h, : nb * w].reshape(nr, h, nb, w).swapaxes(1, 2).reshape(nr * nb, h * w).all(axis=1)
    rows = np.repeat(np.arange(nr), nb)[keep]
    p = tiles[keep]
    if not len(p):
        return np.zeros((0, len(features)))
    mean = p.mean(axis=(1, 2))
    c = p - mean[:, None, None]
    var = (c**2).mean(axis=(1, 2))
    flat = var <= 0.0
    safe_var = np.where(flat, 1.0, var)
    cols = {}
    cols["log_mean"] = np.log(mean)
    cols["contrast"] = np.sqrt(var) / mean
    cols["skewness"] = np.where(flat, 0.0, (c**3).mean(axis=(1, 2)) / safe_var**1.5)
    cols["lag1_range"] = np.where(flat, 0.0, (c[:, 1:, :] * c[:, :-1, :]).mean(axis=(1, 2)) / safe_var)
    cols["lag1_beams"] = np.where(flat, 0.0, (c[:, :, 1:] * c[:, :, :-1]).mean(axis=(1, 2)) / safe_var)
    q = np.percentile(p.reshape(len(p), -1), _QUANTILES, axis=1) / mean[None, :]
    cols["q10_over_mean"], cols["q50_over_mean"], cols["q90_over_mean"] = q
    cols["range_position"] = (rows * h + h / 2.0) / x.shape[0]
    centred = 2.0 * cols["range_position"] - 1.0
    cols["range_position_2"], cols["range_position_3"] = centred**2, centred**3
    return np.column_stack([cols[f] for f in features])


def _loss_and_gradient(params: np.ndarray, X: np.ndarray, s: np.ndarray, l2: float) -> tuple[float, np.ndarray]:
    """Mean log-loss plus ``l2 / 2 |w|^2`` (the intercept unpenalised), and its gradient.

    ``s`` holds the labels as -1 / +1, so that the loss of a sample is ``log(1 + exp(-s z))``.
    """
    w, b = params[:-1], params[-1]
    z = X @ w + b
    loss = float(np.mean(np.logaddexp(0.0, -s * z))) + 0.5 * l2 * float(w @ w)
    # d/dz log(1 + exp(-s z)) = -s / (1 + exp(s z)); expit keeps it finite for large |z|.
    from scipy.special import expit

    g = -s * expit(-s * z) / len(s)
    return loss, np.concatenate([X.T @ g + l2 * w, [g.sum()]])


def fit_logistic(X: Any, y: Any, l2: float = 1e-2) -> tuple[np.ndarray, float]:
    """L2-regularised logistic regression, fitted by L-BFGS on the log-loss and its gradient.

    Minimises ``mean(log(1 + exp(-s_i (x_i . w + b)))) + l2 / 2 |w|^2`` with ``s_i = 2 y_i - 1``
    (the intercept ``b`` is not penalised).

    Parameters
    ----------
    X : (n_samples, n_features) array-like
        Features (standardise them first: the penalty treats every weight alike).
    y : (n_samples,) array-like of 0 / 1
    l2 : float
        Penalty weight, >= 0.

    Returns
    -------
    w : (n_features,) float64 ndarray
    b : float
        ``P(y = 1 | x) = 1 / (1 + exp(-(x . w + b)))``.
    """
    from scipy.optimize import minimize

    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y)
    if X.ndim != 2 or y.shape != (X.shape[0],):
        raise ValueError(f"X must be (n_samples, n_features) and y (n_samples,), got {X.shape} and {y.shape}")
    if not np.isin(y, (0, 1)).all():
        raise ValueError("y must hold 0 / 1 labels")
    if not (l2 >= 0.0 and math.isfinite(l2)):
        raise ValueError(f"l2 must be a finite number >= 0, got {l2}")
    s = 2.0 * y.astype(np.float64) - 1.0
    res = minimize(_loss_and_gradient, np.zeros(X.shape[1] + 1), args=(X, s, float(l2)), jac=True,
                   method="L-BFGS-B", options={"maxiter": 1000})
    return res.x[:-1], float(res.x[-1])


def _folds(y: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Fold index of each sample: each class shuffled and dealt round the ``k`` folds."""
    fold = np.empty(len(y), dtype=int)
    for label in (0, 1):
        idx = rng.permutation(np.flatnonzero(y == label))
        fold[idx] = np.arange(len(idx)) % k
    return fold


def _cross_validated_accuracy(A: np.ndarray, B: np.ndarray, k: int, l2: float,
                              rng: np.random.Generator) -> tuple[float, int]:
    """One repetition: balance, fold, standardise on the training fold, fit, score."""
    n = min(len(A), len(B))
    a = A[rng.choice(len(A), n, replace=False)]
    b = B[rng.choice(len(B), n, replace=False)]
    X = np.concatenate([a, b])
    y = np.concatenate([np.zeros(n, dtype=int), np.ones(n, dtype=int)])
    fold = _folds(y, k, rng)
    correct = 0
    for f in range(k):
        train, test = fold != f, fold == f
        mu = X[train].mean(axis=0)
        sd = X[train].std(axis=0)
        sd[sd == 0] = 1.0  # a constant feature carries nothing; leave it at 0
        w, b0 = fit_logistic((X[train] - mu) / sd, y[train], l2)
        z = ((X[test] - mu) / sd) @ w + b0
        correct += int(((z > 0).astype(int) == y[test]).sum())
    return correct / len(y), len(y)


@dataclass(frozen=True)
class C2STResult:
    """What :func:`classifier_two_sample_test` found.

    Attributes
    ----------
    accuracy : float
        Cross-validated accuracy, mean over the seeds (0.5 = indistinguishable, 1 = separated).
    standard_error : float
        Binomial standard error of one repetition's accuracy, ``sqrt(a (1 - a) / n)``.
    null_standard_error : float
        Its value under the null (``a = 0.5``): ``sqrt(0.25 / n)``.
    seed_std : float
        Standard deviation of the accuracy over the seeds (the draw of the balanced subset and
        of the folds); 0 with one seed.
    accuracies : list of float
        Per seed.
    n_real, n_simulated : int
        Patches found in each set.
    n_tested : int
        Predictions per repetition: twice the smaller set.
    folds : int
    seeds : int
    features : list of str
    patch : list of int
        (range bins, beams).
    """

    accuracy: float
    standard_error: float
    null_standard_error: float
    seed_std: float
    accuracies: list
    n_real: int
    n_simulated: int
    n_tested: int
    folds: int
    seeds: int
    features: list
    patch: list

    @property
    def z(self) -> float:
        """How many null standard errors the accuracy lies above 0.5."""
        return (self.accuracy - 0.5) / self.null_standard_error

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the attributes and ``z``."""
        return {**asdict(self), "z": self.z}


def classifier_two_sample_test(real: Any, simulated: Any, mask: Any = None, *, patch: tuple[int, int] = PATCH_SHAPE,
                               features: Sequence[str] = FEATURES, folds: int = 5, seeds: int = 5,
                               seed: int = 0, l2: float = 1e-2, min_patches: int = 20) -> C2STResult:
    """Cross-validated accuracy of a logistic regression telling real patches from simulated ones.

    See the module notes for the patches, the features, and what the accuracy means.

    Parameters
    ----------
    real, simulated : (n_range_bins, n_beams) array-like, or a sequence of them
        The two sets of images (e.g. held-out frames of a recording, and speckled renders), in
        the same units.
    mask : (n_range_bins, n_beams) bool array-like, optional
        Where patches may lie, for every image (which must then all share its shape).
    patch : (int, int)
        Patch size, range bins x beams.
    features : sequence of str
        Names from :data:`FEATURES` (default all).
    folds : int
        ``k`` of the stratified k-fold cross-validation, >= 2.
    seeds : int
        Repetitions with different draws of the balanced subset and of the folds, >= 1.
    seed : int
        Seed of those draws: the same seed gives the same result.
    l2 : float
        Penalty weight of :func:`fit_logistic` (on standardised features).
    min_patches : int
        Least number of patches in each set; fewer raise (an accuracy on a handful of
        patches has a standard error of 0.1 or more and says nothing).

    Returns
    -------
    C2STResult

    Raises
    ------
    ValueError
        Fewer than ``min_patches`` (or ``folds``) patches in a set, with how many were found;
        bad images, mask or options.
    """
    if int(folds) != folds or folds < 2:
        raise ValueError(f"folds must be an integer >= 2, got {folds}")
    if int(seeds) != seeds or seeds < 1:
        raise ValueError(f"seeds must be an integer >= 1, got {seeds}")
    sets = []
    for name, images in (("real", real), ("simulated", simulated)):
        feats = [patch_features(im, mask, patch, features) for im in _images(images, name)]
        sets.append(np.concatenate(feats))
    A, B = sets
    need = max(int(min_patches), int(folds))
    for name, s in (("real", A), ("simulated", B)):
        if len(s) < need:
            raise ValueError(
                f"too few patches in the {name} images for a two-sample test: {len(s)} of "
                f"{patch[0]} x {patch[1]} cells with echo (at least {MIN_NONZERO_FRACTION:.0%} non-zero) inside "
                f"the mask, at least {need} needed; give more images, a larger mask or a smaller patch")
    children = np.random.SeedSequence(int(seed)).spawn(int(seeds))
    runs = [_cross_validated_accuracy(A, B, int(folds), l2, np.random.default_rng(c)) for c in children]
    acc = np.array([r[0] for r in runs])
    n = runs[0][1]
    mean = float(acc.mean())
    return C2STResult(
        accuracy=mean, standard_error=math.sqrt(max(mean * (1.0 - mean), 0.0) / n),
        null_standard_error=math.sqrt(0.25 / n), seed_std=float(acc.std()),
        accuracies=[float(a) for a in acc], n_real=int(len(A)), n_simulated=int(len(B)), n_tested=int(n),
        folds=int(folds), seeds=int(seeds), features=list(features), patch=[int(patch[0]), int(patch[1])],
    )
