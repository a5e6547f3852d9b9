"""What a realism score means: trivial images a simulator must beat, and the ceiling.

A simulated image scored against a real frame (PSNR, SSIM) says little alone: on the real
Oculus pings an image with no geometry at all, the calibration frame's mean over beams at each
range copied into every beam, scores 19.1 dB on the held-out pings, as well as the calibrated
simulator (issue 22). So every score is reported beside:

* :func:`range_profile_image` -- the calibration frame's range profile (its mean over beams at
  each range) in every beam: no geometry, no across-fan structure;
* :func:`separable_image` -- its range profile times its beam profile (the rank-one image of
  the means): the across-fan gain without any 2D structure;
* :func:`local_mean_image` -- the calibration frame's own local mean (15 x 9): the best a
  deterministic image can do against a frame whose speckle is another draw (the ceiling).

All are made from the frame the simulator was calibrated on and scored, like the simulator, on
the other frames (:func:`held_out_scores`): nothing is fitted to the frames scored.

Images are polar ``(n_range_bins, n_beams)`` arrays in a device's counts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .metrics import _as_image
from .metrics import scores as image_scores
from .realism import _region

__all__ = ["CEILING_WINDOW", "baseline_images", "held_out_scores", "local_mean_image", "range_profile_image",
           "separable_image"]

#: The local mean window (range bins, beams) of the ceiling.
CEILING_WINDOW = (15, 9)


def _masked_means(x: np.ndarray, m: np.ndarray, axis: int) -> np.ndarray:
    count = m.sum(axis=axis)
    total = np.where(m, x, 0.0).sum(axis=axis)
    return np.divide(total, count, out=np.zeros(total.shape), where=count > 0)


def range_profile_image(reference: Any, mask: Any = None) -> np.ndarray:
    """The reference's mean over beams at each range, in every beam.

    Parameters
    ----------
    reference : (n_range_bins, n_beams) array-like, counts
    mask : (n_range_bins, n_beams) bool array-like, optional
        The cells averaged (default all); rows without one are 0.

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray
    """
    x, m = _region(reference, mask)
    return np.repeat(_masked_means(x, m, axis=1)[:, None], x.shape[1], axis=1)


def separable_image(reference: Any, mask: Any = None) -> np.ndarray:
    """The reference's range profile times its beam profile over its mean: the image whose
    every row and column has the reference's mean (for a separable reference, the reference).

    Parameters
    ----------
    reference : (n_range_bins, n_beams) array-like, counts
    mask : (n_range_bins, n_beams) bool array-like, optional

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray
    """
    x, m = _region(reference, mask)
    mean = float(x[m].mean()) if m.any() else 0.0
    if mean == 0.0:
        return np.zeros(x.shape)
    return np.outer(_masked_means(x, m, axis=1), _masked_means(x, m, axis=0)) / mean


def local_mean_image(reference: Any, window: tuple[int, int] = CEILING_WINDOW) -> np.ndarray:
    """The reference's local mean over ``window`` (range bins, beams):
    :func:`sonarsim.analysis.realism.local_mean` with the ceiling's window.

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray
    """
    from .realism import local_mean

    return local_mean(reference, window)


def baseline_images(reference: Any, mask: Any = None) -> dict[str, np.ndarray]:
    """``{"range profile", "separable", "ceiling"}``: the images of this module from one frame."""
    return {"range profile": range_profile_image(reference, mask), "separable": separable_image(reference, mask),
            "ceiling": local_mean_image(reference)}


def held_out_scores(images: Mapping[str, Any], held_out: Sequence[Any], mask: Any = None,
                    data_range: float = 255.0) -> dict[str, dict[str, float]]:
    """PSNR and SSIM of each image against each held-out frame, in counts, averaged.

    Parameters
    ----------
    images : mapping of name -> (n_range_bins, n_beams) array-like
        What is scored: the simulated image and the :func:`baseline_images` of the calibration
        frame, say.
    held_out : sequence of (n_range_bins, n_beams) array-like
        Real frames the images were not made from.
    mask : (n_range_bins, n_beams) bool array-like, optional
        The cells scored (default all).
    data_range : float
        Full scale of the counts (255 for 8-bit data).

    Returns
    -------
    dict of name -> {"psnr", "ssim", "margin_db"}
        Means over the held-out frames; ``margin_db`` is the PSNR above the best of the
        ``range profile`` and ``separable`` baselines (present when they are scored).
    """
    if not held_out:
        raise ValueError("no held-out frames to score on")
    frames = [_as_image(f, f"held_out[{k}]") for k, f in enumerate(held_out)]
    m = _region(frames[0], mask)[1]
    out: dict[str, dict[str, float]] = {}
    for name, image in images.items():
        x = _as_image(image, name)
        scores = [image_scores(x, f, m, None, data_range) for f in frames]
        out[name] = {"psnr": float(np.mean([s["psnr"] for s in scores])),
                     "ssim": float(np.mean([s["ssim"] for s in scores]))}
    trivial = [out[k]["psnr"] for k in ("range profile", "separable") if k in out]
    if trivial:
        best = max(trivial)
        for scores_of in out.values():
            scores_of["margin_db"] = scores_of["psnr"] - best if math.isfinite(best) else math.nan
    return out
