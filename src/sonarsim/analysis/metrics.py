"""Image similarity: the metrics of the paper's Table I (MSE, PSNR), SSIM, and image comparison.

The paper (Section V, Table I) compares synthetic and real sonar images, "normalized to
0~255", with the mean squared error (MSE) and the peak signal-to-noise ratio (PSNR), in the
polar domain and in the fan-shaped (Cartesian) domain. This module computes those two, plus the
structural similarity index (SSIM, Wang et al. 2004), which rewards matching structure (edges,
shadows) rather than matching brightness, and :mod:`sonarsim.analysis.comparison` compares two sonar
images whatever their geometry with them.

Definitions used here (the standard ones):

* ``MSE = mean((a - b)**2)`` over the compared pixels, in squared image units (0-255 images:
  squared grey levels).
* ``PSNR = 10 log10(data_range**2 / MSE)`` dB, ``data_range = 255`` for 0-255 images; ``inf``
  for identical images.
* SSIM with a Gaussian window (sigma 1.5, truncated at 3.5 sigma: 11 x 11 taps), population
  (co)variances, ``K1 = 0.01``, ``K2 = 0.03``: the same numbers as scikit-image's
  ``structural_similarity(..., gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False, data_range=255)``.

How :func:`compare_images` applies them: each image is normalised to 0-255 by default by
dividing by its maximum (:func:`normalize_255` says why not min-max) over the compared pixels;
the polar comparison runs on image A's grid (B resampled if needed) and the fan comparison on
the pixels inside both fans; SSIM is averaged only where its whole 11 x 11 window lies inside
the compared region (:func:`ssim`).

A note on the paper's figures: its PSNR and MSE columns are not related by the formula above.
MSE 104.67 on 0-255 images gives ``10 log10(255**2 / 104.67) = 27.93`` dB, but the paper
reports 17.90 dB (and 19.15 dB for MSE 79.35, which would give 29.14 dB). The changes do not
match either: adding the triple bounce raises the reported PSNR by 0.54 dB while the reported
MSE falls by 0.28 %, which by the formula is a gain of 0.012 dB, so no fixed data range makes
the two columns agree. We use the standard definition with data range 255, so that PSNR is a
function of MSE and our figures can be compared with other work. What the paper did is not
stated; *possibly* (a guess, not verified) its PSNR was computed on images with another
normalisation or another peak value than the MSE (the text says the 0-255 normalisation was
"for MSE"), and/or per-image PSNRs were averaged over its 1,648 images while the MSE was
averaged separately (a mean of logarithms is not the logarithm of a mean). Absolute figures
from sonarsim should therefore not be expected to match Table I.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import ndimage


__all__ = [
    "scores",
    "NORMALIZATIONS",
    "SSIM_K1",
    "SSIM_K2",
    "SSIM_SIGMA",
    "SSIM_TRUNCATE",
    "SSIM_WINDOW",
    "mse",
    "normalize_255",
    "psnr",
    "ssim",
    "ssim_map",
    "ssim_support",
]

#: Normalisation modes of :func:`normalize_255`.
NORMALIZATIONS = ("max", "minmax")

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
#: Half-size (radius) and full edge of the SSIM window: scipy's Gaussian filter with sigma 1.5
#: truncated at 3.5 sigma has radius int(3.5 * 1.5 + 0.5) = 5, i.e. 11 x 11 taps, the window
#: of Wang et al. (2004).
SSIM_RADIUS = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)
SSIM_WINDOW = 2 * SSIM_RADIUS + 1

# --------------------------------------------------------------------------------------------
# Array metrics
# --------------------------------------------------------------------------------------------


def _as_image(image: Any, name: str) -> np.ndarray:
    arr = np.asarray(image)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be a real-valued array, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got shape {arr.shape}")
    # float64: squared differences of 0-255 images summed over millions of pixels lose digits
    # in float32, and scikit-image (the SSIM reference) works in float64 too.
    out = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return out


def _as_mask(mask: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    if mask is None:
        return None
    m = np.asarray(mask)
    if m.dtype != bool:
        raise ValueError(f"mask must be a boolean array, got dtype {m.dtype}")
    if m.shape != shape:
        raise ValueError(f"mask must have the images' shape {shape}, got {m.shape}")
    return m


def _pair(a: Any, b: Any, mask: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    x = _as_image(a, "a")
    y = _as_image(b, "b")
    if x.shape != y.shape:
        raise ValueError(f"a and b must have the same shape, got {x.shape} and {y.shape}")
    return x, y, _as_mask(mask, x.shape)


def normalize_255(image: Any, mask: Any = None, mode: str = "max") -> np.ndarray:
    """Scale an intensity image to the range 0-255 (the paper's "normalized to 0~255").

    * ``"max"`` (default): ``v = 255 * max(I, 0) / max(I)``, the maximum taken inside the
      mask. Zero stays zero.
    * ``"minmax"``: ``v = 255 * (I - min(I)) / (max(I) - min(I))``, both taken inside the mask.

    ``"max"`` is the default because it keeps the meaning of the intensity scale: zero means
    "no echo" in both a simulated and a recorded image, and ratios between pixels are kept.
    Min-max instead moves the zero to the darkest pixel, which in a recording is the noise
    floor and in a simulation is exactly 0, so the same scene would be shifted differently in
    the two images and the MSE would measure the noise floor rather than the geometry. Use
    ``"minmax"`` for images with an offset (e.g. log-scaled or display-mapped data).

    Parameters
    ----------
    image : array_like, shape (H, W), real
        Intensity (any linear scale, e.g. simulated echo energy or recorded 8-bit samples).
    mask : array_like of bool, shape (H, W), optional
        Pixels that count (e.g. inside both fans). The extremes are taken over them only, and
        pixels outside are set to 0. Default: every pixel.
    mode : {"max", "minmax"}
        See above.

    Returns
    -------
    np.ndarray, shape (H, W), float64
        Values in [0, 255]. An image with no positive value (``"max"``) or a constant image
        (``"minmax"``) inside the mask gives all zeros, without warnings. In ``"max"`` mode
        negative values (not physical intensities) are clipped to 0.

    Raises
    ------
    ValueError
        For an unknown mode, a non-real, non-2-D or non-finite image, or a mask of another
        shape or dtype.
    """
    if mode not in NORMALIZATIONS:
        raise ValueError(
            f"mode must be one of {', '.join(map(repr, NORMALIZATIONS))}, got {mode!r}"
        )
    x = _as_image(image, "image")
    m = _as_mask(mask, x.shape)
    inside = x if m is None else x[m]
    out = np.zeros(x.shape, dtype=np.float64)
    if inside.size == 0:
        return out
    if mode == "max":
        peak = float(inside.max())
        if peak > 0.0:
            out = np.clip(x, 0.0, None) * (255.0 / peak)
    else:
        low, high = float(inside.min()), float(inside.max())
        if high > low:
            out = (x - low) * (255.0 / (high - low))
    if m is not None:
        out[~m] = 0.0
    return out


def mse(a: Any, b: Any, mask: Any = None) -> float:
    """Mean squared error ``mean((a - b)**2)``.

    Parameters
    ----------
    a, b : array_like, shape (H, W), real
        Images on the same grid (normalise them first, e.g. with :func:`normalize_255`).
    mask : array_like of bool, shape (H, W), optional
        Only these pixels count. Default: every pixel.

    Returns
    -------
    float
        In squared image units. NaN if the mask selects no pixel.

    Raises
    ------
    ValueError
        For images of different shapes, non-real, non-2-D or non-finite images, or a bad mask.
    """
    x, y, m = _pair(a, b, mask)
    d = x - y
    if m is not None:
        d = d[m]
    if d.size == 0:
        return math.nan
    return float(np.mean(d * d))


def psnr(a: Any, b: Any, mask: Any = None, data_range: float = 255.0) -> float:
    """Peak signal-to-noise ratio ``10 log10(data_range**2 / MSE)``, dB.

    Parameters
    ----------
    a, b : array_like, shape (H, W), real
        Images on the same grid.
    mask : array_like of bool, shape (H, W), optional
        Only these pixels count. Default: every pixel.
    data_range : float
        Peak-to-peak range of the images' scale, > 0: 255 for 0-255 images.

    Returns
    -------
    float
        dB; ``inf`` for identical images (MSE 0), NaN if the mask selects no pixel.

    Raises
    ------
    ValueError
        As :func:`mse`, and for a non-positive data range.
    """
    data_range = float(data_range)
    if not (math.isfinite(data_range) and data_range > 0.0):
        raise ValueError(f"data_range must be finite and > 0, got {data_range!r}")
    err = mse(a, b, mask)
    if math.isnan(err):
        return math.nan
    if err == 0.0:
        return math.inf
    return 10.0 * math.log10(data_range * data_range / err)


def ssim_support(shape: tuple[int, int], mask: Any = None) -> np.ndarray:
    """Pixels at which SSIM is averaged: those whose whole 11 x 11 window lies in the mask.

    Parameters
    ----------
    shape : (int, int)
        Image shape ``(H, W)``.
    mask : array_like of bool, shape (H, W), optional
        Pixels that count. Default: every pixel.

    Returns
    -------
    np.ndarray, shape (H, W), bool
        The mask eroded by an 11 x 11 square, with everything within 5 pixels of the image
        border removed (the image outside is treated as outside the mask).
    """
    m = np.ones(shape, dtype=bool) if mask is None else _as_mask(mask, tuple(shape))
    # One separable minimum filter does both the erosion and the border crop: cval=0 makes
    # the outside of the image count as "not in the mask".
    return ndimage.minimum_filter(
        m.astype(np.uint8), size=SSIM_WINDOW, mode="constant", cval=0
    ).astype(bool)


def ssim_map(x: np.ndarray, y: np.ndarray, data_range: float) -> np.ndarray:
    """Per-pixel SSIM of two float64 images (Wang et al. 2004, Eq. 13, Gaussian window)."""
    # All five local moments in one call: sigma 0 on the stacking axis leaves it unfiltered.
    # mode="reflect" (half-sample symmetric) is what scikit-image uses; it only affects
    # windows that reach past the border, which are not averaged anyway.
    stack = np.stack([x, y, x * x, y * y, x * y])
    mu_x, mu_y, m_xx, m_yy, m_xy = ndimage.gaussian_filter(
        stack, sigma=(0.0, SSIM_SIGMA, SSIM_SIGMA), truncate=SSIM_TRUNCATE, mode="reflect"
    )
    # Population (co)variances (weights sum to 1), as in the paper of Wang et al.
    var_x = m_xx - mu_x * mu_x
    var_y = m_yy - mu_y * mu_y
    cov = m_xy - mu_x * mu_y
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    num = (2.0 * mu_x * mu_y + c1) * (2.0 * cov + c2)
    den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2)
    return num / den


def ssim(a: Any, b: Any, mask: Any = None, data_range: float = 255.0) -> float:
    """Mean structural similarity (Wang et al. 2004) with an 11 x 11 Gaussian window.

    Local means, variances and the covariance are Gaussian-weighted (sigma 1.5 pixels,
    truncated at 3.5 sigma, population statistics); ``C1 = (0.01 R)**2`` and
    ``C2 = (0.03 R)**2`` with ``R = data_range``. Without a mask the result equals
    scikit-image's ``structural_similarity(a, b, gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=R)``.

    Borders and masks: the local statistics are computed over the whole image, but SSIM is
    averaged only over the pixels whose whole 11 x 11 window lies inside the image and inside
    the mask (:func:`ssim_support`). So no averaged value depends on how the filter extends the
    image past its border, nor on the pixels outside the mask (e.g. the zeros outside a sonar
    fan, which would otherwise add a spurious perfectly matching edge). A region narrower than
    11 pixels therefore does not count.

    Parameters
    ----------
    a, b : array_like, shape (H, W), real
        Images on the same grid (normalised to ``[0, data_range]``).
    mask : array_like of bool, shape (H, W), optional
        Pixels that count. Default: every pixel.
    data_range : float
        Peak-to-peak range of the images' scale, > 0: 255 for 0-255 images.

    Returns
    -------
    float
        Mean SSIM, at most 1 (1 for identical images).

    Raises
    ------
    ValueError
        As :func:`mse`, for a non-positive data range, or when no pixel has its whole window
        inside the image and mask (an image or region smaller than 11 x 11).
    """
    data_range = float(data_range)
    if not (math.isfinite(data_range) and data_range > 0.0):
        raise ValueError(f"data_range must be finite and > 0, got {data_range!r}")
    x, y, m = _pair(a, b, mask)
    valid = ssim_support(x.shape, m)
    if not valid.any():
        raise ValueError(
            f"SSIM needs at least one pixel whose {SSIM_WINDOW} x {SSIM_WINDOW} window lies "
            f"inside the image and the mask; images of shape {x.shape}"
            + (f" with {int(m.sum())} masked-in pixels" if m is not None else "")
            + " have none"
        )
    return float(np.mean(ssim_map(x, y, data_range)[valid]))


def scores(x: np.ndarray, y: np.ndarray, mask: np.ndarray, normalize: str | None,
           data_range: float) -> dict[str, Any]:
    """MSE, PSNR and SSIM of two images on one grid over ``mask`` (after ``normalize_255``
    of each where ``normalize`` is given), with the pixel counts they were taken over: what
    :func:`sonarsim.analysis.comparison.compare_images` and the held-out scores of
    :mod:`sonarsim.analysis.baselines` report."""
    if normalize is not None:
        x = normalize_255(x, mask, normalize)
        y = normalize_255(y, mask, normalize)
    support = ssim_support(x.shape, mask)
    out: dict[str, Any] = {
        "mse": mse(x, y, mask),
        "psnr": psnr(x, y, mask, data_range),
        # NaN rather than an error: MSE and PSNR are still meaningful for a region too small
        # for an SSIM window (e.g. a tiny PNG), and the caller reports "n/a".
        "ssim": float(np.mean(ssim_map(x, y, data_range)[support])) if support.any() else math.nan,
        "n_pixels": int(mask.sum()),
        "n_ssim_pixels": int(support.sum()),
    }
    return out
