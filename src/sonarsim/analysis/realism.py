"""Statistics that a pixel-wise score misses: how an image's texture and distributions look.

PSNR and SSIM compare two images pixel by pixel; a simulated frame with the right speckle can
score worse than a smooth one. These functions describe an image region by what a sonar
person looks at instead, so that a simulation and a recording can be compared statistic by
statistic (issue: a sensor model calibrated against real recordings):

* :func:`distribution_distances` -- Kolmogorov-Smirnov statistic and 1-Wasserstein distance
  between the pixel values of two regions;
* :func:`speckle_contrast` -- std / mean of the image divided by its local mean (1 for fully
  developed speckle in intensity, about 0.52 in amplitude; the real Oculus floor band: 0.29);
* :func:`correlation_lengths` -- how far the speckle residual stays correlated along range
  and across beams (the grain size), in bins and beams;
* :func:`range_profile_db` and :func:`beam_profile_db` -- the mean level per range bin and
  per beam, in dB.

Images are polar ``(n_range_bins, n_beams)`` arrays (rows range, columns beams); a region is a
boolean mask of the same shape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .metrics import _as_image, _as_mask

# Local mean window (range bins, beams) that speckle is measured against (DESIGN: 9 x 5).
LOCAL_MEAN_WINDOW = (9, 5)

# Lags (bins, beams) beyond which correlation is not looked for.
MAX_LAG = 64


def _region(image, mask) -> tuple[np.ndarray, np.ndarray]:
    x = _as_image(image, "image")
    m = _as_mask(mask, x.shape)
    return x, (np.ones(x.shape, dtype=bool) if m is None else m)


def local_mean(image, window: tuple[int, int] = LOCAL_MEAN_WINDOW) -> np.ndarray:
    """Mean over a ``window`` (range bins, beams) around each pixel, edges reflected.

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray
    """
    from scipy.ndimage import uniform_filter

    x = _as_image(image, "image")
    if len(window) != 2 or min(window) < 1:
        raise ValueError(f"window must be two positive sizes (bins, beams), got {window}")
    return uniform_filter(x, size=tuple(int(w) for w in window), mode="reflect")


def speckle_residual(image, window: tuple[int, int] = LOCAL_MEAN_WINDOW) -> np.ndarray:
    """The image over its local mean, minus 1 (0 where the local mean is 0).

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray, mean about 0 where the image is speckle.
    """
    x = _as_image(image, "image")
    mean = local_mean(x, window)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(mean > 0, x / mean - 1.0, 0.0)


def speckle_contrast(image, mask=None, window: tuple[int, int] = LOCAL_MEAN_WINDOW) -> float:
    """std / mean of the image divided by its local mean, over a region.

    Parameters
    ----------
    image : (n_range_bins, n_beams) array
        Intensities (or the device's counts).
    mask : (n_range_bins, n_beams) bool array, optional
        The region (default the whole image); pixels whose local mean is 0 are left out.
    window : (int, int)
        Local-mean window in range bins and beams.

    Returns
    -------
    float : 1 for fully developed speckle in intensity (exponential), 0 for a smooth image.
    """
    x, m = _region(image, mask)
    ratio = speckle_residual(x, window) + 1.0
    keep = m & (local_mean(x, window) > 0)
    if keep.sum() < 2:
        raise ValueError("the region holds fewer than two pixels with echo")
    r = ratio[keep]
    if not r.any():  # zeros beside echo (e.g. a noise-free shadow): no speckle to measure
        raise ValueError("the region holds no echo")
    return float(r.std() / r.mean())


@dataclass(frozen=True)
class CorrelationLengths:
    """Where the normalised autocorrelation of the speckle residual falls to 1/e.

    Attributes
    ----------
    range_bins : float
        Along range (down the columns), in range bins (interpolated; 0 for white noise).
    beams : float
        Across beams (along the rows), in beams.
    """

    range_bins: float
    beams: float


def _one_over_e_lag(acf: np.ndarray) -> float:
    """First lag where a normalised autocorrelation (acf[0] = 1) falls to 1/e, interpolated."""
    level = np.exp(-1.0)
    below = np.flatnonzero(acf < level)
    if not len(below):
        return float(len(acf) - 1)  # correlated beyond the lags looked at
    k = int(below[0])
    a0, a1 = acf[k - 1], acf[k]
    return float(k - 1 + (a0 - level) / (a0 - a1))


def _acf(residual: np.ndarray, keep: np.ndarray, axis: int, max_lag: int) -> np.ndarray:
    """Normalised autocorrelation along ``axis`` over pairs of pixels both in the region."""
    r = np.where(keep, residual, 0.0)
    r = r - r[keep].mean() * keep
    var = float((r[keep] ** 2).mean())
    n = residual.shape[axis]
    out = [1.0]
    for lag in range(1, min(max_lag, n - 1) + 1):
        a = np.take(r, np.arange(0, n - lag), axis=axis)
        b = np.take(r, np.arange(lag, n), axis=axis)
        pairs = np.take(keep, np.arange(0, n - lag), axis=axis) & np.take(keep, np.arange(lag, n), axis=axis)
        if pairs.sum() < 2 or var == 0:
            break
        out.append(float((a * b)[pairs].mean() / var))
    return np.asarray(out)


#: The tails' quantile that :func:`log_asymmetry` compares (the 5th and 95th percentiles).
ASYMMETRY_QUANTILE = 0.05


def log_asymmetry(image, mask=None, log_domain: bool = False, window: tuple[int, int] = LOCAL_MEAN_WINDOW,
                  tail: float = ASYMMETRY_QUANTILE) -> float:
    """Quantile asymmetry of the image's log-domain values about their local mean, over a region.

    ``(q_hi + q_lo - 2 q_50) / (q_hi - q_lo)`` of the residual (Kelly's measure, ``q_lo`` and
    ``q_hi`` the ``tail`` and ``1 - tail`` quantiles): the speckle's shape, whatever the output's
    scale. A log output's counts are logarithmic already (their spread scales with the span, this
    ratio does not), and the log of a gamma output's counts is ``gamma ln P`` plus a constant. The
    log of one look's exponential intensity has a long dark tail: -0.27 at the 5th percentile
    (9 x 5 local mean); L looks -0.15 (3), -0.09 (8), -0.05 (32), towards 0. A ratio of
    quantiles, it varies far less from one draw to the next than the third moment (a third of
    the spread over 115,000 cells).

    Parameters
    ----------
    image : (n_range_bins, n_beams) array
        Device values (counts) or intensities.
    mask : (n_range_bins, n_beams) bool array, optional
        The region (default the whole image).
    log_domain : bool
        The values are logarithmic already (a log output); otherwise their natural log is
        taken, pixels at 0 or below left out (a quantiser's zeros have no log).
    window : (int, int)
        Local-mean window in range bins and beams (over the pixels kept).
    tail : float
        In (0, 0.5).

    Returns
    -------
    float in [-1, 1], dimensionless: negative where the dark tail is the longer.
    """
    x, m = _region(image, mask)
    if not 0.0 < tail < 0.5:
        raise ValueError(f"tail must lie in (0, 0.5), got {tail}")
    if not log_domain:
        keep = m & (x > 0)
        y = np.log(np.where(x > 0, x, 1.0))
    else:
        keep, y = m, x
    if keep.sum() < 3:
        raise ValueError("the region holds fewer than three pixels with echo")
    weight = np.maximum(local_mean(keep.astype(float), window), 1e-12)
    r = (y - local_mean(np.where(keep, y, 0.0), window) / weight)[keep]
    lo, mid, hi = np.quantile(r, [tail, 0.5, 1.0 - tail])
    if hi <= lo:
        raise ValueError("the region is flat: no speckle to measure")
    return float((hi + lo - 2.0 * mid) / (hi - lo))


def correlation_lengths(image, mask=None, window: tuple[int, int] = LOCAL_MEAN_WINDOW,
                        max_lag: int = MAX_LAG) -> CorrelationLengths:
    """Grain size of the speckle: 1/e lengths of the residual's autocorrelation.

    Parameters
    ----------
    image : (n_range_bins, n_beams) array
    mask : (n_range_bins, n_beams) bool array, optional
        The region; pairs of pixels count when both lie in it.
    window : (int, int)
        Local-mean window the residual is taken against.
    max_lag : int
        Longest lag looked at.
    """
    x, m = _region(image, mask)
    keep = m & (local_mean(x, window) > 0)
    if keep.sum() < 2:
        raise ValueError("the region holds fewer than two pixels with echo")
    res = speckle_residual(x, window)
    return CorrelationLengths(
        range_bins=_one_over_e_lag(_acf(res, keep, 0, max_lag)),
        beams=_one_over_e_lag(_acf(res, keep, 1, max_lag)),
    )


@dataclass(frozen=True)
class DistributionDistances:
    """How far apart two regions' pixel values are distributed.

    Attributes
    ----------
    ks : float
        Kolmogorov-Smirnov statistic, the largest gap between the two empirical CDFs (0 to 1).
    wasserstein : float
        1-Wasserstein (earth mover's) distance, in the images' units.
    """

    ks: float
    wasserstein: float


def distribution_distances(a, b, mask_a=None, mask_b=None) -> DistributionDistances:
    """Distances between the pixel values of region ``mask_a`` of ``a`` and ``mask_b`` of ``b``.

    The images may differ in shape (each region is taken from its own image); compare them in
    the same units (a simulated frame in the device's counts against a recording).
    """
    from scipy.stats import ks_2samp, wasserstein_distance

    x, ma = _region(a, mask_a)
    y, mb = _region(b, mask_b)
    va, vb = x[ma], y[mb]
    if not len(va) or not len(vb):
        raise ValueError("each region must hold at least one pixel")
    return DistributionDistances(ks=float(ks_2samp(va, vb, method="asymp").statistic),
                                 wasserstein=float(wasserstein_distance(va, vb)))


def _profile_db(x: np.ndarray, m: np.ndarray, axis: int, floor_db: float) -> np.ndarray:
    count = m.sum(axis=axis)
    total = np.where(m, x, 0.0).sum(axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
        return np.where(mean > 0, 10.0 * np.log10(np.maximum(mean, 10 ** (floor_db / 10))), np.where(
            np.isnan(mean), np.nan, floor_db))


def range_profile_db(image, mask=None, floor_db: float = -300.0) -> np.ndarray:
    """Mean level per range bin over the region, in dB (``10 log10``; NaN where the row is empty).

    Returns
    -------
    (n_range_bins,) float64 ndarray; a mean of 0 gives ``floor_db``.
    """
    x, m = _region(image, mask)
    return _profile_db(x, m, 1, floor_db)


def beam_profile_db(image, mask=None, floor_db: float = -300.0) -> np.ndarray:
    """Mean level per beam over the region, in dB (NaN where the column is empty).

    Returns
    -------
    (n_beams,) float64 ndarray; a mean of 0 gives ``floor_db``.
    """
    x, m = _region(image, mask)
    return _profile_db(x, m, 0, floor_db)


# A pixel is "lit" when its local mean is within this factor of the image's bright level (the
# 99th percentile of the local mean): 0.25 is 6 dB.
LIT_FRACTION = 0.25
BRIGHT_PERCENTILE = 99.0

#: A pixel behind the first echo of its beam is in shadow when its local mean is at most this
#: many dB above the water column's level (2x in intensity): within the spread of a local mean
#: of speckled noise (a 9 x 5 mean of exponential noise has a std of 15 % of its mean), far
#: below a lit pixel (at least 6 dB under the bright level).
SHADOW_DB = 3.0

#: Level taken as "no echo" when the water column is darker still (a noise-free simulation
#: has a water column of exactly 0): this many dB below the image's bright level.
SHADOW_FLOOR_DB = 40.0

#: Names of the regions :func:`auto_regions` finds.
REGIONS = ("lit", "water", "shadow")


def auto_regions(image, mask=None, window: tuple[int, int] = LOCAL_MEAN_WINDOW) -> dict[str, np.ndarray]:
    """Regions of a sonar image found from its own levels.

    * ``lit``: pixels whose local mean is within 6 dB (:data:`LIT_FRACTION`) of the image's
      bright level (the 99th percentile of the local mean): the lit floor band and objects;
    * ``water``: in each beam, the range bins nearer than its first lit bin (the water column
      before the first echo);
    * ``shadow``: in each beam, the bins farther than its first lit bin that are not lit and
      whose local mean is within :data:`SHADOW_DB` (3 dB) of the level of no echo: where the
      echo falls back to the noise behind an echo. The level of no echo is the median of the
      local mean over the ``water`` of the beams that have a lit bin (a beam without one may
      hold unlit echo), or :data:`SHADOW_FLOOR_DB` (40 dB) below the bright level when that is
      higher (a noise-free simulation's water column is exactly 0). This is an object's
      acoustic shadow on the floor, and also the dark beyond the far edge of a floor band
      (outside the vertical beam, or where the echo fades into the noise): levels alone do not
      tell them apart. It is empty when the image has no such drop (the real Oculus ping
      nearly so: what is not lit behind its first echoes stays 4.4 dB (1st percentile) to
      5.6 dB (median) above its water column, echo of the elevation pattern), and when no beam
      has a water column before a lit bin to measure the level in.

    The local mean blurs every edge by up to half the window, so a region stops short of a
    brighter neighbour by up to half the window (4 bins and 2 beams for 9 x 5): a shadow
    smaller than the window is not found.

    Parameters
    ----------
    image : (n_range_bins, n_beams) array
    mask : (n_range_bins, n_beams) bool array, optional
        Pixels that may belong to a region (e.g. where a compared image has data).
    window : (int, int)
        Local-mean window in range bins and beams.

    Returns
    -------
    dict of :data:`REGIONS` name to (n_range_bins, n_beams) bool ndarray (possibly empty)
    """
    x, m = _region(image, mask)
    mean = local_mean(x, window)
    level = float(np.percentile(mean[m], BRIGHT_PERCENTILE)) if m.any() else 0.0
    lit = m & (mean >= LIT_FRACTION * level) & (level > 0)
    first = np.where(lit.any(axis=0), lit.argmax(axis=0), x.shape[0])
    rows = np.arange(x.shape[0])[:, None]
    water = m & (rows < first[None, :])
    # The water column of a beam with no lit bin is the whole beam, unlit echo included.
    before_echo = water & lit.any(axis=0)[None, :]
    if before_echo.any():
        noise = max(float(np.median(mean[before_echo])), level * 10 ** (-SHADOW_FLOOR_DB / 10))
        shadow = m & ~lit & (rows > first[None, :]) & (mean <= noise * 10 ** (SHADOW_DB / 10))
    else:
        shadow = np.zeros(x.shape, dtype=bool)
    return {"lit": lit, "water": water, "shadow": shadow}


def region_statistics(a, b, mask, window: tuple[int, int] = LOCAL_MEAN_WINDOW) -> dict[str, float]:
    """How region ``mask`` of ``b`` looks next to the same region of ``a`` (same grid and units).

    Returns
    -------
    dict with ``pixels``; ``mean_a``, ``mean_b``; ``contrast_a``, ``contrast_b`` (speckle
    contrast); ``grain_range_a``/``_b`` and ``grain_beams_a``/``_b`` (correlation lengths, bins
    and beams); ``ks`` and ``wasserstein`` (between the two regions' values); and
    ``range_profile_rms_db`` (RMS difference of the two mean range profiles, dB, over the
    rows where both are positive). NaN where a statistic is undefined (too few pixels, no echo).
    """
    x, m = _region(a, mask)
    y = _as_image(b, "b")
    if y.shape != x.shape:
        raise ValueError(f"a and b must share a grid, got {x.shape} and {y.shape}")
    out: dict[str, float] = {"pixels": float(m.sum())}
    for tag, img in (("a", x), ("b", y)):
        out[f"mean_{tag}"] = float(img[m].mean()) if m.any() else float("nan")
        try:
            out[f"contrast_{tag}"] = speckle_contrast(img, m, window)
            lengths = correlation_lengths(img, m, window)
            out[f"grain_range_{tag}"], out[f"grain_beams_{tag}"] = lengths.range_bins, lengths.beams
        except ValueError:
            out[f"contrast_{tag}"] = out[f"grain_range_{tag}"] = out[f"grain_beams_{tag}"] = float("nan")
    if m.any():
        d = distribution_distances(x, y, m, m)
        out["ks"], out["wasserstein"] = d.ks, d.wasserstein
        pa, pb = range_profile_db(x, m), range_profile_db(y, m)
        both = np.isfinite(pa) & np.isfinite(pb) & (pa > -300) & (pb > -300)
        out["range_profile_rms_db"] = float(np.sqrt(np.mean((pa[both] - pb[both]) ** 2))) if both.any() else float("nan")
    else:
        out["ks"] = out["wasserstein"] = out["range_profile_rms_db"] = float("nan")
    return out
