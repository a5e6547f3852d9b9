"""Fit the sonar pose to a real image by rendering and comparing (the paper's calibration).

Raw intensities of a real image depend on gain, speckle and the transducer; the places where
the echo starts and stops (the onset of the floor, the front of an object, the edge of a
shadow) depend on the pose. Two comparison domains:

* ``edges`` (the paper's authors calibrated this way): both images become edge maps --
  smoothed log-intensity, differentiated along range -- and the cost is one minus their
  normalised correlation, coarse to fine over decreasing smoothing. General scenes.
* ``band``: per beam, the near and far edges of the floor band (the steepest rise of the
  echo and the steepest fall after it); the cost is the RMS difference of those curves, in
  metres. For calibrating height and tilt against a floor: both edges are needed (the near
  edge alone lets height and tilt trade off), and they are far less sensitive to speckle and
  to the unmodelled brightness of the floor beyond the aperture than whole images are.

``auto`` (the default) chooses between them from the scene and the recording
(:func:`choose_domain`): ``band`` where the scene's echo is one floor band, ``edges`` otherwise.

The real-time renderer makes each evaluation cheap; a derivative-free simplex search (scipy's
Nelder-Mead) does the rest. A simplex ends somewhere whether or not that means anything:
:func:`fit_problems` lists the signs that it does not (an echo that does not line up with the
recording's, band edges a window's tenth apart, a search that found no way downhill, a
parameter that ran away), and ``sonarsim fit`` exits with status 3 on any of them.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
from scipy import ndimage, optimize

from ..errors import ConfigError, SonarsimError
from ..config import parameters
from ..config.scene import Scene
from ..config.sonar import SonarConfig
from ..image.result import SonarImage
from ..renderer.simulator import Simulator
from ..core.transforms import Pose

PARAMETERS = ("x", "y", "z", "roll", "pitch", "yaw")
# Initial simplex steps: a few range bins of a typical tank window, a few degrees (the coarse
# steps of the one table of fittable parameters: fit starts further off than calibrate).
STEPS = {k: parameters.parameter(f"pose.{k}").coarse_step for k in PARAMETERS}
UNITS = {k: "deg" if parameters.parameter(f"pose.{k}").unit == "degrees" else "m" for k in PARAMETERS}
# Smoothing (range bins, beams) of the coarse-to-fine passes: wide first, to see far edges.
DEFAULT_SMOOTHING = ((8.0, 4.0), (4.0, 2.0), (2.0, 1.0))


def parse_free(text: str | Sequence[str], allow_none: bool = False) -> tuple[str, ...]:
    """``"z,pitch"`` or ``["z", "pitch"]`` -> ``("z", "pitch")``; unknown names are errors.

    ``allow_none``: an empty list is allowed (a calibration may fit no pose parameter).
    """
    names = [t.strip() for t in (text.split(",") if isinstance(text, str) else text) if t.strip()]
    if not names and not allow_none:
        raise ConfigError("free", f"name at least one pose parameter: {', '.join(PARAMETERS)}")
    for n in names:
        if n not in PARAMETERS:
            raise ConfigError("free", f"unknown pose parameter {n!r}; allowed: {', '.join(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise ConfigError("free", f"a parameter is named twice in {names}")
    return tuple(names)


def pose_values(pose: Pose) -> dict[str, float]:
    """The six pose parameters (metres, degrees) of a pose."""
    (x, y, z), (roll, pitch, yaw) = pose.position_m, pose.rpy_deg
    return {"x": x, "y": y, "z": z, "roll": roll, "pitch": pitch, "yaw": yaw}


def pose_from_values(values: dict[str, float]) -> Pose:
    return Pose((values["x"], values["y"], values["z"]), (values["roll"], values["pitch"], values["yaw"]))


def edge_map(polar: np.ndarray, smoothing: tuple[float, float]) -> np.ndarray:
    """Normalised range-edge map of a polar image.

    Parameters
    ----------
    polar : (n_range_bins, n_beams) float array
        Intensities (any scale; >= 0).
    smoothing : (float, float)
        Gaussian sigma along range (bins) and azimuth (beams).

    Returns
    -------
    (n_range_bins, n_beams) float64 ndarray with zero mean and unit norm (all zeros for a
    featureless image): the magnitude of the range derivative of the smoothed log-intensity.
    """
    img = np.asarray(polar, dtype=float)
    scale = np.percentile(img[img > 0], 99) if np.any(img > 0) else 1.0
    # log1p of the image scaled to its own level: contrast, not absolute gain, matters.
    logged = np.log1p(np.clip(img, 0, None) / (0.05 * scale))
    smooth = ndimage.gaussian_filter(logged, smoothing, mode="nearest")
    edges = np.abs(np.gradient(smooth, axis=0))
    edges -= edges.mean()
    norm = np.linalg.norm(edges)
    return edges / norm if norm > 0 else edges


def edge_cost(simulated: np.ndarray, real_edges: np.ndarray, smoothing: tuple[float, float]) -> float:
    """1 - correlation of the edge maps, in [0, 2]; 0 is a perfect match."""
    return 1.0 - float(np.sum(edge_map(simulated, smoothing) * real_edges))


# Smoothing (range bins, beams) of the band-edge detector and the width (beams) of the median
# filter across beams: speckle makes single-beam edges of a real image jump by centimetres.
BAND_SMOOTHING = (12.0, 8.0)
BAND_MEDIAN_BEAMS = 15
# Least step of a band edge in the smoothed log-intensity, as a fraction of the image's spread of
# that level (its 99th minus 1st percentile). Measured with the default smoothing: the real
# Oculus floor ping's edges step by 0.27-0.50 (rise, 5th-95th percentile over beams) and
# 0.37-0.41 (fall) of its spread; the ARIS sample's sea bed, lit from before its window start
# to beyond its end and fading with range, has no step above 0.19 (rise) and 0.31 (fall, a
# patch of brighter sea bed 22 m out) in 95 % of its beams. The step alone cannot tell them
# apart: the level on each side of an edge must also persist (BAND_PERSISTENCE).
BAND_MIN_CONTRAST = 0.2
# Least step of an edge in units of its own noise (the speckle that is left after smoothing):
# an image of speckle alone (whose spread is itself speckle) shows no edge.
BAND_MIN_SIGNIFICANCE = 6.0
# A band edge separates a band from a region that is darker throughout (hysteresis): below a
# near edge, the region from the window start to the edge (its 75th percentile, so that the
# transmit bang does not count) must lie at least this share of BAND_MIN_CONTRAST's step below
# the band just beyond the edge; beyond a far edge, the region to the window end below the
# band just before it. A sea bed seen at a grazing angle, brighter near the sonar and fading
# with range, has steps of its texture that the smoothing leaves, but no region that stays dark.
BAND_PERSISTENCE = 0.5
# The range (in range smoothing sigmas) kept clear between an edge and the regions whose
# levels it separates, and the length of the band measured on its far side of an edge.
BAND_GAP_SIGMAS = 2.0
BAND_LEVEL_SIGMAS = 4.0
# Edges farther than this many robust standard deviations (and BAND_GAP_SIGMAS range
# smoothing sigmas) from the flat-floor curve fitted through all beams' edges are dropped.
BAND_OUTLIER_SIGMAS = 4.0


def _log_level(polar: np.ndarray) -> np.ndarray:
    """log1p of an image scaled to its own 99th percentile: gain does not matter, contrast does."""
    img = np.clip(np.asarray(polar, dtype=float), 0, None)
    scale = np.percentile(img[img > 0], 99) if np.any(img > 0) else 1.0
    return np.log1p(img / (0.05 * scale))


def _curve_outliers(azimuth_rad: np.ndarray, ranges: np.ndarray, floor_m: float) -> np.ndarray:
    """Beams whose edge lies off the flat-floor curve through the others.

    On a flat floor the ray at a fixed elevation meets the floor at ``1/r = a + b cos(theta) +
    c sin(theta)`` (height, pitch and roll in ``a, b, c``; DESIGN section 10), so the edges of all
    beams lie on one such curve; speckle taken for an edge does not. Fitted with two rounds of
    rejection; returns a boolean mask of the outliers (False where ``ranges`` is NaN).
    """
    ok = np.isfinite(ranges) & (ranges > 0)
    out = np.zeros(ranges.shape, dtype=bool)
    if ok.sum() < 6:
        return out
    design = np.stack([np.ones_like(azimuth_rad), np.cos(azimuth_rad), np.sin(azimuth_rad)], axis=1)
    keep = ok.copy()
    for _ in range(3):
        coef, *_ = np.linalg.lstsq(design[keep], 1.0 / ranges[keep], rcond=None)
        inverse = design @ coef
        model = np.where(inverse > 0, 1.0 / np.where(inverse > 0, inverse, 1.0), np.inf)
        resid = np.abs(ranges - model)
        spread = 1.4826 * np.median(resid[keep])
        limit = max(BAND_OUTLIER_SIGMAS * spread, floor_m)
        new_keep = ok & (resid <= limit)
        if new_keep.sum() < 6 or np.array_equal(new_keep, keep):
            keep = new_keep if new_keep.sum() >= 6 else keep
            break
        keep = new_keep
    out[ok & ~keep] = True
    return out


def _column_upper_quartile(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """75th percentile (nearest rank) of ``values[mask[:, j], j]`` for every column (NaN where empty)."""
    ranked = np.sort(np.where(mask, values, np.inf), axis=0)
    count = mask.sum(axis=0)
    index = np.clip(np.floor(0.75 * (count - 1)).astype(int), 0, values.shape[0] - 1)
    return np.where(count > 0, ranked[index, np.arange(values.shape[1])], np.nan)


def _column_means(values: np.ndarray, start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Mean of ``values[start[j]:stop[j], j]`` for every column ``j`` (NaN where empty)."""
    n = values.shape[0]
    start, stop = np.clip(start, 0, n), np.clip(stop, 0, n)
    cumulative = np.vstack([np.zeros((1, values.shape[1])), np.cumsum(values, axis=0)])
    cols = np.arange(values.shape[1])
    count = stop - start
    total = cumulative[stop, cols] - cumulative[start, cols]
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def band_edges(
    image: SonarImage | np.ndarray,
    smoothing: tuple[float, float] = BAND_SMOOTHING,
    median_beams: int = BAND_MEDIAN_BEAMS,
    *,
    range_m: np.ndarray | None = None,
    azimuth_deg: np.ndarray | None = None,
    min_contrast: float = BAND_MIN_CONTRAST,
) -> tuple[np.ndarray, np.ndarray]:
    """Per beam, the near and far edges of a floor band, or NaN where the image shows none.

    The image is taken as log-intensity scaled to its own 99th percentile (gain does not
    matter) and smoothed with a Gaussian of ``smoothing`` sigmas (range bins, beams) against
    speckle. In each beam the near edge is the strongest rise of that level and the far edge
    the strongest fall beyond it, each kept only when it is a clear edge:

    * its step is at least ``min_contrast`` of the image's spread of level (99th minus 1st
      percentile) and :data:`BAND_MIN_SIGNIFICANCE` times the noise left by the smoothing;
    * the side away from the band stays dark (hysteresis, :data:`BAND_PERSISTENCE`): all of
      the window before a near edge, all of it after a far edge, lies below the band next to
      the edge. A sea bed lit from before the window start to beyond its end, fading with range
      (grazing incidence), has neither edge: both are NaN, not two speckle maxima;
    * it lies on the flat-floor curve through the other beams' edges (``1/r = a + b cos(theta)
      + c sin(theta)``) within :data:`BAND_OUTLIER_SIGMAS` robust deviations.

    The edges kept are then replaced by the median over ``median_beams`` neighbouring beams (of
    those that have one), which removes the speckle's jitter; a beam whose neighbourhood has an
    edge in fewer than half of its beams gets NaN.

    On a flat floor the near edge is where the lowest ray of the elevation aperture meets it,
    the far edge the highest ray (where inside the window): DESIGN section 10 gives the closed
    form ``1/r = A cos(theta) +- B`` (no roll), ``A = cos(h) sin(p) / z``, ``B = sin(h) cos(p) / z``.

    Parameters
    ----------
    image : SonarImage or (n_range_bins, n_beams) float array
        A recording or render (its ``polar``, ``range_m`` and ``azimuth_deg``), or a polar image
        (intensities >= 0, any scale; row 0 nearest, column 0 the left-most beam) with
        ``range_m`` given.
    smoothing : (float, float), optional
        Gaussian sigmas along range (bins) and across beams (beams).
    median_beams : int, optional
        Width (beams) of the median across beams; 1 for none.
    range_m : (n_range_bins,) float array, metres, optional
        Range of each bin; required with a bare array, else the image's.
    azimuth_deg : (n_beams,) float array, degrees, optional
        Beam centres, left-most first; with a bare array, evenly spaced over +-15 degrees if not
        given (used only by the flat-floor outlier test).
    min_contrast : float, optional
        Least step of an edge as a fraction of the image's spread of level (see above).

    Returns
    -------
    near, far : (n_beams,) float64 ndarrays, metres
        Range of the near and far edge in each beam; NaN where the beam shows no clear edge (no
        echo, an echo that begins before the window start or ends beyond its end, or only
        speckle). NaN in every beam of a window too short for the smoothing: at most
        ``2 ceil(BAND_GAP_SIGMAS sigma) + 2`` range bins (50 at the default 12-bin sigma), where
        an edge cannot be told from the smoothing's own blur.

    Raises
    ------
    ValueError
        A bare array without ``range_m``, or axes that do not match its shape.
    """
    if isinstance(image, SonarImage):
        polar = image.polar
        r = np.asarray(image.range_m if range_m is None else range_m, dtype=float)
        az = np.asarray(image.azimuth_deg if azimuth_deg is None else azimuth_deg, dtype=float)
    else:
        polar = np.asarray(image)
        if range_m is None:
            raise ValueError("band_edges: give range_m (metres, one per row) with a bare polar image")
        r = np.asarray(range_m, dtype=float)
        az = (np.asarray(azimuth_deg, dtype=float) if azimuth_deg is not None
              else np.linspace(15.0, -15.0, polar.shape[1] if polar.ndim == 2 else 1))
    if polar.ndim != 2 or r.shape != (polar.shape[0],) or az.shape != (polar.shape[1],):
        raise ValueError(f"band_edges: a polar image of shape {polar.shape} needs range_m of shape "
                         f"({polar.shape[0] if polar.ndim else 0},) and azimuth_deg of one value per beam; "
                         f"got {r.shape} and {az.shape}")
    return _band_core(polar, r, az, smoothing, median_beams, min_contrast)[:2]


def _band_core(polar, r, az, smoothing, median_beams, min_contrast):
    """:func:`band_edges` on checked arrays; also returns the smoothed level and its 1st and
    99th percentiles (for :func:`band_view`)."""
    n_bins, n_beams = polar.shape
    near = np.full(n_beams, np.nan)
    far = np.full(n_beams, np.nan)
    level = _log_level(polar)
    smooth = ndimage.gaussian_filter(level, smoothing, mode="nearest")
    low, high = np.percentile(smooth, [1, 99])
    sigma_r = float(smoothing[0])
    # The step of level across an edge: the range derivative of the smoothed level times
    # sigma sqrt(2 pi), which is exactly the step's height for a sharp step.
    to_step = max(sigma_r, 1e-9) * np.sqrt(2.0 * np.pi)
    step = np.gradient(smooth, axis=0) * to_step if n_bins > 1 else np.zeros_like(smooth)
    spread = float(high - low)
    if not spread > 0:
        return near, far, smooth, low, high
    # The noise of the step: speckle left by the smoothing, through the same filter.
    residual = level - smooth
    noise = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    delta = np.zeros((int(8 * sigma_r) + 3, int(8 * smoothing[1]) + 3))
    delta[delta.shape[0] // 2, delta.shape[1] // 2] = 1.0
    kernel = np.gradient(ndimage.gaussian_filter(delta, smoothing, mode="constant"), axis=0) * to_step
    threshold = max(min_contrast * spread, BAND_MIN_SIGNIFICANCE * noise * float(np.linalg.norm(kernel)))
    gap = max(1, int(np.ceil(BAND_GAP_SIGMAS * sigma_r)))
    width = max(1, int(np.ceil(BAND_LEVEL_SIGMAS * sigma_r)))
    if n_bins <= 2 * gap + 2:
        return near, far, smooth, low, high
    persist = BAND_PERSISTENCE * threshold
    rows = np.arange(n_bins)[:, None]
    cols = np.arange(n_beams)
    inner = step[gap:n_bins - gap]
    # Near edge: the strongest rise, kept when the band beyond it is brighter than (the 75th
    # percentile of) everything before it by the persistence margin.
    first = gap + np.argmax(inner, axis=0)
    band_after = _column_means(smooth, first + gap, first + gap + width)
    below_level = _column_upper_quartile(smooth, rows < (first - gap)[None, :])
    ok = (step[first, cols] >= threshold) & np.isfinite(band_after)
    ok &= ~np.isfinite(below_level) | (band_after - below_level >= persist)
    near[ok] = r[first[ok]]
    # Far edge: the strongest fall beyond the near edge (beyond the window start without one),
    # kept when everything after it is darker than the band before it.
    begin = np.where(ok, first + gap, gap)
    searched = np.where((rows >= begin[None, :]) & (rows < n_bins - gap), step, np.inf)
    last = np.argmin(searched, axis=0)
    band_before = _column_means(smooth, np.maximum(0, last - gap - width), np.maximum(0, last - gap))
    beyond_level = _column_upper_quartile(smooth, rows >= (last + gap)[None, :])
    ok = np.isfinite(searched[last, cols]) & (-step[last, cols] >= threshold) & np.isfinite(band_before)
    ok &= ~np.isfinite(beyond_level) | (band_before - beyond_level >= persist)
    far[ok] = r[last[ok]]
    dr = abs(float(r[1] - r[0])) if n_bins > 1 else 0.0
    azimuth = np.radians(az)
    for edges in (near, far):
        edges[_curve_outliers(azimuth, edges, BAND_GAP_SIGMAS * sigma_r * dr)] = np.nan
        if median_beams > 1 and np.isfinite(edges).any():
            half = int(median_beams) // 2
            padded = np.pad(edges, half, constant_values=np.nan)  # beyond the fan: no edge
            windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
            support = np.isfinite(windows).sum(axis=1)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                median = np.nanmedian(windows, axis=1)
            keep = np.isfinite(edges) & (2 * support >= min(2 * half + 1, n_beams))
            edges[:] = np.where(keep, median, np.nan)
    return near, far, smooth, low, high


def floor_band_m(
    image: SonarImage, smoothing: tuple[float, float] = BAND_SMOOTHING, median_beams: int = BAND_MEDIAN_BEAMS
) -> tuple[np.ndarray, np.ndarray]:
    """The near and far edges of a floor band per beam, metres, NaN where none: :func:`band_edges`.

    Returns
    -------
    onset, end : (n_beams,) float64 ndarrays, metres; NaN for a beam without a clear edge.
    """
    return band_edges(image, smoothing, median_beams)


def floor_onset_m(image: SonarImage, **kwargs) -> np.ndarray:
    """The near edge of the floor band in each beam, metres (see :func:`band_edges`)."""
    return band_edges(image, **kwargs)[0]


# What makes a fit meaningless (see :func:`fit_problems`). Smoothing of the domain-neutral check:
# the widest pass of the edges domain, where a floor band or an object front is one broad edge
# and speckle has averaged out.
CHECK_SMOOTHING = DEFAULT_SMOOTHING[0]
# Least correlation of the edge maps (at CHECK_SMOOTHING) between the recording and the render
# at the fitted pose. Measured: 0.45 on the real Oculus floor ping at its fitted pose, 0.99 on
# the noisy demo scene at its true pose, 0.73 at a start 8 cm and 3 deg off; -0.17 and 0.11 at
# poses where the render's echo lies elsewhere than the recording's (1.5 m and 60 deg; 2.5 m
# and 60 deg).
MIN_EDGE_CORRELATION = 0.2
# Largest RMS band-edge difference (``band`` domain), as a fraction of the recording's range
# span: 0.064 m (3 %) on the real floor ping; beyond a tenth of the window the two bands are
# different echoes, not one echo slightly displaced.
MAX_BAND_RMS_FRACTION = 0.1
# A cost this low (either domain) is a perfect match: a search that stays put there is done.
PERFECT_COST = 1e-6
# A parameter that moves farther than the recording's far range (metres) or than this (degrees)
# from the start has run away along a flat or misleading cost, not converged.
MAX_ANGLE_MOVE_DEG = 90.0
# ``auto`` chooses ``band`` when the objects carry at most this share of the single-bounce
# echo at the start and the band is found in at least MIN_BAND_BEAMS of the beams.
MAX_OBJECT_SHARE = 0.05
MIN_BAND_BEAMS = 0.5
# A recording that shows an edge in fewer than this share of its beams shows none: its band
# passes that end of the window (:func:`band_residuals`), and its fit is checked on the range
# profile (:func:`profile_correlation`, at least MIN_PROFILE_CORRELATION) instead of edge maps.
CENSORED_EDGE_FRACTION = 0.1
# Intensity, as a fraction of a beam's largest, above which a bin counts as lit (BandView's
# first_lit_m / last_lit_m): 60 dB down, so that a noise-free render's faded grazing echo
# counts and only its true silence (outside the elevation aperture) does not.
LIT_FLOOR = 1e-6
# Measured: 0.99 on the ARIS sample's sea bed at its fitted pose; a recording of speckle alone
# has no range profile to follow.
MIN_PROFILE_CORRELATION = 0.5

# What a recording must show for a fit or a calibration to mean anything (:func:`echo_problems`).
# Least lit region (realism.auto_regions' ``lit``), pixels: one bright pixel on a silent ping
# is no echo to fit (it sent a pose fit to a pitch of 87 degrees).
MIN_ECHO_PIXELS = 20
# Largest share of the pixels at the frame's largest value: beyond it the frame is saturated
# and what is left below saturation is too little to fit (a synthetic floor 91 % saturated by
# a gain without TVG still calibrates).
MAX_SATURATED_SHARE = 0.98
# Least share of a frame's variance that its 15 x 9 local mean explains: pixel noise explains
# 1/135 (measured: 0.7 % on random bytes in the Oculus and ARIS layouts), an echo far more
# (82 % on the real Oculus ping, 83 % on the ARIS sample). Judged on frames of at least two
# windows along each axis (30 bins, 18 beams): over a narrower frame the window is no local mean.
MIN_STRUCTURE = 0.05
# A free parameter whose step (:data:`STEPS`) either way changes the render by less than this
# share of the render's standard deviation (RMS) is not determined by any recording: x, y and
# yaw over a flat floor change nothing at all.
MIN_PARAMETER_EFFECT = 1e-3


def echo_problems(image) -> tuple[str, ...]:
    """Why a frame holds no echo that a model can explain; empty when nothing shows that.

    * every pixel has one value (an all-zero or all-saturated ping);
    * more than :data:`MAX_SATURATED_SHARE` of the pixels at the frame's largest value;
    * fewer than :data:`MIN_ECHO_PIXELS` pixels in its lit region
      (:func:`~sonarsim.analysis.realism.auto_regions`);
    * its 15 x 9 local mean explains less than :data:`MIN_STRUCTURE` of its variance (pixel
      noise, such as random bytes).

    Parameters
    ----------
    image : (n_range_bins, n_beams) array-like
        The frame, in its own units.

    Returns
    -------
    tuple of str
        One clause per problem, with the figure found and the limit.
    """
    from .baselines import CEILING_WINDOW, local_mean_image
    from .realism import auto_regions

    x = np.asarray(image, dtype=np.float64)
    finite = x[np.isfinite(x)]
    if finite.size == 0:
        return ("the frame holds no finite pixel",)
    top = float(finite.max())
    if float(finite.min()) == top:
        return (f"every pixel of the frame is {top:g} (a silent or saturated ping): no echo",)
    out = []
    saturated = float(np.mean(finite == top))
    if saturated > MAX_SATURATED_SHARE:
        out.append(f"{100 * saturated:.0f} % of the frame's pixels are at its largest value {top:g} (saturated; at "
                   f"most {100 * MAX_SATURATED_SHARE:.0f} % may be)")
    x = np.where(np.isfinite(x), x, 0.0)
    lit = int(auto_regions(x)["lit"].sum())
    if lit < MIN_ECHO_PIXELS:
        out.append(f"the frame's lit region holds {lit} pixel{'s' if lit != 1 else ''} (at least {MIN_ECHO_PIXELS} "
                   "are an echo)")
    var = float(x.var())
    window = np.asarray(CEILING_WINDOW)
    if np.any(np.asarray(x.shape) < 2 * window):
        return tuple(out)
    explained = 1.0 - float(np.mean((local_mean_image(x) - x) ** 2)) / var if var > 0 else 0.0
    if explained < MIN_STRUCTURE:
        out.append(f"the frame shows no echo structure: its 15 x 9 local mean explains {100 * explained:.1f} % of its "
                   f"variance (pixel noise: under 1 %; at least {100 * MIN_STRUCTURE:g} % is an echo)")
    return tuple(out)


def unidentified_parameters(scene: Scene, free: Sequence[str], simulator: Simulator | None = None) -> tuple[str, ...]:
    """The free pose parameters that do not change ``scene``'s render at its pose: a step of
    :data:`STEPS` either way moves it by less than :data:`MIN_PARAMETER_EFFECT` of its standard
    deviation (RMS). No recording determines them (x, y and yaw over a flat floor).

    Parameters
    ----------
    scene : Scene
        At the fitted pose, on the recording's grid.
    free : sequence of str
        Pose parameter names (:data:`PARAMETERS`).
    simulator : Simulator, optional
        Reused if given (it must hold ``scene``).

    Returns
    -------
    tuple of str
        The names, in ``free``'s order.
    """
    sim = simulator if simulator is not None else Simulator(scene)
    try:
        values = pose_values(scene.sonar_pose)
        base = np.asarray(sim.render(keep_rays=False, speckle=False).polar, dtype=np.float64)
        scale = float(base.std())
        if not scale > 0:
            return ()
        out = []
        for name in free:
            if name not in STEPS:
                continue
            changes = []
            for sign in (-1.0, 1.0):
                moved = sim.render(pose=pose_from_values({**values, name: values[name] + sign * STEPS[name]}),
                                   keep_rays=False, speckle=False).polar
                changes.append(float(np.sqrt(np.mean((np.asarray(moved, np.float64) - base) ** 2))) / scale)
            if max(changes) < MIN_PARAMETER_EFFECT:
                out.append(name)
        return tuple(out)
    finally:
        if simulator is None:
            sim.close()


def unidentified_problem(names: Sequence[str]) -> str:
    """The clause that refuses free parameters no recording determines."""
    steps = ", ".join(f"{n} {STEPS[n]:g} {UNITS[n]}" for n in names)
    return (f"{', '.join(names)} {'does' if len(names) == 1 else 'do'} not change the render (a step of {steps} "
            f"either way leaves it unchanged): the recording cannot determine {'it' if len(names) == 1 else 'them'}; "
            "leave " + ("it" if len(names) == 1 else "them") + " out of --free")


# Sentinel cost of a band comparison without a beam where both images show a band: finite, so
# that the simplex can step away from it; reported as a problem, never as a residual.
NO_BAND_COST = 1e3


class FitError(SonarsimError):
    """The fit ran but found no meaningful pose (the CLI's exit status 3)."""


@dataclass(frozen=True)
class FitProgress:
    """What :func:`fit_pose` reports to its ``progress`` callback after each render.

    Attributes
    ----------
    renders : int
        Images rendered so far.
    budget : int
        The render budget (``max_renders``).
    stage : str
        The pass running: ``band``, or ``edges 2/3`` (pass and number of passes).
    best_cost : float
        The lowest cost of the current pass so far (its units: see :attr:`FitResult.cost`).
    elapsed_s : float
        Seconds since the fit started.
    """

    renders: int
    budget: int
    stage: str
    best_cost: float
    elapsed_s: float


@dataclass(frozen=True)
class FitResult:
    """Outcome of :func:`fit_pose`.

    Attributes
    ----------
    pose : Pose
        The fitted sonar pose (world frame).
    scene : Scene
        The scene fitted, with ``pose`` as its ``sonar_pose`` and the recording's intrinsics
        (:func:`recording_geometry`): it renders :attr:`image`, on the recording's grid.
    free : tuple of str
        The parameters that were fitted.
    domain : str
        The comparison domain used (``edges`` or ``band``; ``auto`` resolved).
    start, values : dict of str to float
        All six parameters before and after, metres and degrees.
    cost_start, cost : float
        The domain's cost at the start and at the fitted pose: 1 - edge correlation at the
        finest smoothing, or the RMS of the band-edge differences in metres.
    onset_rms_m : float
        RMS over beams of the difference between the real and the fitted floor onset ranges,
        metres (NaN where no beam shows a floor in both).
    renders : int
        Number of images rendered.
    image : SonarImage
        The render at the fitted pose (its ``pose``), in the real image's geometry (its ``sonar``:
        the real image's beams and range window, the scene's elevation aperture;
        :func:`recording_geometry`).
    domain_reason : str
        Why the domain was used (the rule of :func:`choose_domain`, or "asked for").
    edge_correlation : float
        Correlation of the edge maps of the recording and of the fitted render at
        :data:`CHECK_SMOOTHING`: the domain-neutral check of :func:`fit_problems`.
    profile_correlation : float
        Correlation of the range profiles of the recording and of the fitted render
        (:func:`profile_correlation`): the check instead of ``edge_correlation`` for a recording
        that shows no band edge (a sea bed lit across the whole window).
    problems : tuple of str
        Why the fit is meaningless (:func:`fit_problems`); empty for a fit to be trusted.
    converged : bool
        The last search stopped on its tolerances, not on the render budget.
    """

    pose: Pose
    free: tuple[str, ...]
    domain: str
    start: dict
    values: dict
    cost_start: float
    cost: float
    onset_rms_m: float
    renders: int
    image: SonarImage
    scene: Scene
    domain_reason: str = ""
    edge_correlation: float = float("nan")
    problems: tuple[str, ...] = ()
    profile_correlation: float = float("nan")
    converged: bool = True

    @property
    def meaningful(self) -> bool:
        """No problem found (:attr:`problems` is empty)."""
        return not self.problems


DOMAINS = ("edges", "band")


def check_overlap(real: SonarImage, scene: Scene) -> None:
    """Refuse a recording whose window the scene's sonar hardly covers (as ``compare`` does).

    Fitting and calibration render on the recording's grid; a recording of another range window
    or fan is another sonar setting (or another scene), and nothing there can be fitted.

    Raises
    ------
    SonarsimError
        Less than :data:`~sonarsim.analysis.comparison.MIN_OVERLAP` of the recording's area is shared.
    """
    from .comparison import MIN_OVERLAP, _overlap_fraction

    overlap = _overlap_fraction(real.sonar.grid, scene.sonar.grid)
    if overlap < MIN_OVERLAP:
        g, h = real.sonar.grid, scene.sonar.grid
        source = real.config.get("source") if isinstance(real.config, dict) else None
        raise SonarsimError(
            (f"{source}: " if source else "") + f"the recording covers {g.range_min_m:.3g}-{g.range_max_m:.3g} m over {g.right_edge_deg:.3g} to "
            f"{g.left_edge_deg:.3g} deg, the scene's sonar {h.range_min_m:.3g}-{h.range_max_m:.3g} m over "
            f"{h.right_edge_deg:.3g} to {h.left_edge_deg:.3g} deg: they share {100 * overlap:.0f} % of the "
            f"recording's area (at least {100 * MIN_OVERLAP:.0f} % is needed); give the scene the recording's "
            "sonar settings")


def recording_geometry(real: SonarImage, scene: Scene) -> SonarConfig:
    """The sonar intrinsics that fitting and calibration render with: the recording's.

    The recording's beams (its bearing table), range window and range bins, so that renders
    land on its grid pixel for pixel (nothing is resampled when they are compared), with what a
    recording does not say taken from the scene's sonar: the elevation aperture, and the
    frequency where the recording has none. ``sonarsim fit`` and ``sonarsim calibrate`` write
    these intrinsics into the scene files they make.

    Parameters
    ----------
    real : SonarImage
        The recording's frame (its ``sonar``).
    scene : Scene
        The scene behind it.

    Returns
    -------
    SonarConfig
    """
    sonar = replace(real.sonar, elevation_fov_deg=scene.sonar.elevation_fov_deg)
    if sonar.frequency_khz is None:
        sonar = replace(sonar, frequency_khz=scene.sonar.frequency_khz)
    return sonar


@dataclass(frozen=True)
class BandView:
    """What one image shows of a floor band, per beam (see :func:`band_view`).

    Attributes
    ----------
    near, far : (n_beams,) float64 ndarrays, metres
        :func:`band_edges`; NaN where the beam shows no clear edge.
    lit_start, lit_end : (n_beams,) bool ndarrays
        The beam is lit at the window's start (end): its smoothed level over the first (last)
        :data:`BAND_LEVEL_SIGMAS` range sigmas is above the middle of the image's spread.
    fading : (n_beams,) bool ndarray
        The beam shows no far edge and its level falls from the window start to its end by more
        than :data:`BAND_MIN_CONTRAST` of the spread: a sea bed seen at a grazing angle, whose
        echo fades with range instead of ending at an edge.
    window_m : (float, float)
        The first and last range bin, metres.
    first_lit_m, last_lit_m : (n_beams,) float64 ndarrays, metres
        The first and last range bin whose intensity exceeds :data:`LIT_FLOOR` of the beam's
        largest (NaN in a beam without echo): where a noise-free render's echo begins and ends,
        however gradually. (A recording's noise keeps it lit everywhere.)
    """

    near: np.ndarray
    far: np.ndarray
    lit_start: np.ndarray
    lit_end: np.ndarray
    fading: np.ndarray
    window_m: tuple[float, float]
    first_lit_m: np.ndarray
    last_lit_m: np.ndarray

    @property
    def determined(self) -> np.ndarray:
        """(n_beams,) bool: the band's extent in the window is known: each end an edge, or the
        band lit at that end of the window (it begins before the start, or lasts beyond the end
        or fades out)."""
        # A near edge begins a band, whatever follows (a far edge, or a band lasting beyond the
        # window); without one, the band must be lit at the start and end at an edge, fade out,
        # or last to the window's end.
        return np.isfinite(self.near) | (self.lit_start & (np.isfinite(self.far) | self.fading | self.lit_end))

    @property
    def edge_fraction(self) -> float:
        """Fraction of the beams with a near or a far edge."""
        return float(np.mean(np.isfinite(self.near) | np.isfinite(self.far)))


def band_view(image: SonarImage, smoothing: tuple[float, float] = BAND_SMOOTHING) -> BandView:
    """The band's edges (:func:`band_edges`) and what each beam shows at the window's ends.

    Parameters
    ----------
    image : SonarImage
    smoothing : (float, float), optional
        Gaussian sigmas (range bins, beams), as for :func:`band_edges`.

    Returns
    -------
    BandView
    """
    r = np.asarray(image.range_m, dtype=float)
    near, far, smooth, lo, hi = _band_core(np.asarray(image.polar), r, np.asarray(image.azimuth_deg, dtype=float),
                                           smoothing, BAND_MEDIAN_BEAMS, BAND_MIN_CONTRAST)
    width = max(1, min(smooth.shape[0], int(np.ceil(BAND_LEVEL_SIGMAS * smoothing[0]))))
    start, end = smooth[:width].mean(axis=0), smooth[-width:].mean(axis=0)
    middle = lo + 0.5 * (hi - lo)
    lit = hi > lo
    polar = np.asarray(image.polar, dtype=float)
    peak = polar.max(axis=0)
    echo = (polar > LIT_FLOOR * peak) & (peak > 0)
    any_echo = echo.any(axis=0)
    first = np.where(any_echo, r[np.argmax(echo, axis=0)], np.nan)
    last = np.where(any_echo, r[len(r) - 1 - np.argmax(echo[::-1], axis=0)], np.nan)
    return BandView(
        near=near, far=far, lit_start=lit & (start > middle), lit_end=lit & (end > middle),
        fading=lit & ~np.isfinite(far) & (start - end > BAND_MIN_CONTRAST * (hi - lo)),
        window_m=(float(r[0]), float(r[-1])), first_lit_m=first, last_lit_m=last,
    )


def band_residuals(real: BandView, simulated: BandView) -> np.ndarray:
    """Per beam, how far the simulated band's ends are from the recording's, metres.

    Where both images show an edge: the difference of the edges. Where only one does, the other
    image's band passes that end of the window, and the residual is the distance from the edge
    to the window's limit it must be beyond: a render whose near edge lies inside the window of
    a recording lit from its first range bin (a sea bed at a grazing angle) is that far from
    agreeing with it, however its speckle looks. Such a bound is used for the recording only
    where it shows that edge in none of its beams (its band is lit at the start, or shows no
    far edge anywhere), so that a beam where speckle hid an edge is not read as a band beyond
    the window; for the render (noise-free where it is a plain render), wherever it is lit at
    that end. Beams where neither shows the edge agree (0) when both bands pass that end of
    the window, and are not counted (NaN) otherwise.

    Parameters
    ----------
    real, simulated : BandView
        :func:`band_view` of the recording and of the render, on one grid.

    Returns
    -------
    (2 n_beams,) float64 ndarray, metres
        Near-edge residuals of every beam, then far-edge residuals; NaN where not counted.
    """
    lo, hi = real.window_m
    # The recording's band begins before its window (nearly) everywhere, or never ends in it
    # sharply: a few beams where speckle passed for an edge do not change that.
    real_before = (np.mean(np.isfinite(real.near)) < CENSORED_EDGE_FRACTION
                   and np.mean(real.lit_start) >= MIN_BAND_BEAMS)
    real_beyond = (np.mean(np.isfinite(real.far)) < CENSORED_EDGE_FRACTION
                   and np.mean(real.lit_end | real.fading) >= MIN_BAND_BEAMS)
    rn, sn, rf, sf = real.near, simulated.near, real.far, simulated.far
    # The render shows a band in the beam: one that begins at an edge, or before the window.
    sim_band = np.isfinite(sn) | simulated.lit_start
    near = np.full(rn.shape, np.nan)
    far = np.full(rf.shape, np.nan)
    both = np.isfinite(rn) & np.isfinite(sn)
    near[both] = sn[both] - rn[both]
    only_real = np.isfinite(rn) & ~np.isfinite(sn) & simulated.lit_start
    near[only_real] = rn[only_real] - lo
    if real_before:
        only_sim = ~np.isfinite(rn) & np.isfinite(sn)
        near[only_sim] = sn[only_sim] - lo
        # Neither shows an edge: the render's echo must begin at the window start too (a render
        # without echo in the beam is as far from it as can be).
        neither = ~np.isfinite(rn) & ~np.isfinite(sn)
        near[neither] = np.where(np.isfinite(simulated.first_lit_m), simulated.first_lit_m - lo, hi - lo)[neither]
    both = np.isfinite(rf) & np.isfinite(sf)
    far[both] = sf[both] - rf[both]
    only_real = np.isfinite(rf) & ~np.isfinite(sf) & sim_band
    far[only_real] = hi - rf[only_real]
    if real_beyond:
        only_sim = ~np.isfinite(rf) & np.isfinite(sf)
        far[only_sim] = hi - sf[only_sim]
        # Neither shows an edge: the render's echo, however faded, must last to the window end.
        neither = ~np.isfinite(rf) & ~np.isfinite(sf)
        far[neither] = np.where(np.isfinite(simulated.last_lit_m), hi - simulated.last_lit_m, hi - lo)[neither]
    return np.concatenate([near, far])


def _band_beams(image: SonarImage) -> float:
    """Fraction of the beams in which the band's extent is known (:attr:`BandView.determined`)."""
    return float(np.mean(band_view(image).determined))


def profile_correlation(a: SonarImage, b: SonarImage, smoothing: tuple[float, float] = BAND_SMOOTHING) -> float:
    """Correlation, in [-1, 1], of the range profiles (mean over beams of the smoothed log level)
    of two images on one grid: the domain-neutral check of a recording without band edges."""
    pa, pb = (ndimage.gaussian_filter1d(_log_level(i.polar).mean(axis=1), smoothing[0], mode="nearest") for i in (a, b))
    pa, pb = pa - pa.mean(), pb - pb.mean()
    norm = float(np.linalg.norm(pa) * np.linalg.norm(pb))
    return float(np.dot(pa, pb) / norm) if norm > 0 else 0.0


def choose_domain(real: SonarImage, scene: Scene, start: SonarImage) -> tuple[str, str]:
    """The comparison domain for a scene and a recording (``fit --domain auto``), and why.

    ``band`` compares one band per beam, the direct echo of one floor, and nothing else: where
    that is what the scene shows, its near and far edges fix height and tilt, and it is blind to
    the speckle that the whole-image edges of ``edges`` follow off to a wrong pose (the real
    Oculus floor ping: a near-edge residual of 0.118 m with ``edges``, 0.068 m with ``band``).
    Where objects echo, or several planes do, their edges carry the pose and ``band`` would
    miss them or mistake one plane's band for another's. So ``band`` is chosen when all of these
    hold, ``edges`` otherwise:

    * the scene has exactly one reflecting plane (``ground`` or one entry of ``planes``);
    * at the start pose its objects carry at most :data:`MAX_OBJECT_SHARE` of the single-bounce
      echo inside the recording's window, and some of it if it has objects (objects out of
      view at the start may still be in the recording);
    * the recording, and the render at the start pose (where anything echoes), show both edges
      of a band in at least :data:`MIN_BAND_BEAMS` of their beams.

    Parameters
    ----------
    real : SonarImage
        The recording.
    scene : Scene
        The scene, at its starting pose.
    start : SonarImage
        The render of ``scene`` at its starting pose, on the recording's grid (with its
        ``object`` and ``ground`` components).

    Returns
    -------
    domain : {'edges', 'band'}
    reason : str
        One sentence naming the rule that decided.
    """
    n_planes = len(scene.planes) + (scene.ground is not None)
    if n_planes == 0:
        return "edges", "the scene has no floor or other plane, and the band domain fits a floor's band"
    if n_planes > 1:
        return "edges", (f"the scene has {n_planes} reflecting planes, and the band domain would take the "
                         "nearest plane's band for the floor's")
    obj = float(np.sum(start.components["object"], dtype=float))
    plane = float(np.sum(start.components["ground"], dtype=float))
    share = obj / (obj + plane) if obj + plane > 0 else 0.0
    if scene.objects and obj == 0:
        # Out of view at the start is no evidence that the recording does not show them.
        return "edges", (f"the scene has {len(scene.objects)} object(s), none echoing at the start pose: edges "
                         "sees them once they come into view (--domain band fits the floor alone)")
    if share > MAX_OBJECT_SHARE:
        return "edges", (f"objects carry {100 * share:.0f} % of the echo at the start pose (band needs at most "
                         f"{100 * MAX_OBJECT_SHARE:.0f} %): their edges fix the pose")
    seen = _band_beams(real)
    if seen < MIN_BAND_BEAMS:
        return "edges", (f"the recording shows a band in {100 * seen:.0f} % of its beams (band needs "
                         f"{100 * MIN_BAND_BEAMS:.0f} %)")
    rendered = _band_beams(start) if obj + plane > 0 else 1.0
    if rendered < MIN_BAND_BEAMS:
        return "edges", (f"the scene at its start pose shows a band in {100 * rendered:.0f} % of the beams "
                         f"(band needs {100 * MIN_BAND_BEAMS:.0f} %)")
    if band_view(real).edge_fraction < CENSORED_EDGE_FRACTION:
        return "band", (f"the scene's echo is one floor band (objects {100 * share:.0f} % of it) and the recording "
                        f"is lit in {100 * seen:.0f} % of its beams from its first range bin, fading with range, "
                        "without a band edge (a sea bed at a grazing angle): the band's near edge lies before the "
                        "window and its far edge beyond it, which bounds height and tilt but does not fix them")
    return "band", (f"the scene's echo is one floor band (objects {100 * share:.0f} % of it) and the recording "
                    f"shows a band in {100 * seen:.0f} % of its beams: its edges fix height and tilt, where "
                    "whole-image edges follow speckle")


def edge_correlation(a: SonarImage, b: SonarImage, smoothing: tuple[float, float] = CHECK_SMOOTHING) -> float:
    """Correlation, in [-1, 1], of the edge maps (:func:`edge_map`) of two images on one grid."""
    return float(np.sum(edge_map(a.polar, smoothing) * edge_map(b.polar, smoothing)))


def fit_problems(real: SonarImage, result: FitResult) -> tuple[str, ...]:
    """Why a fit is meaningless; empty when nothing shows it to be.

    The conditions, each a known way for a simplex search to end somewhere that means nothing:

    * the cost at the fitted pose is not finite, or (``band``) no beam shows a band in both
      the recording and the render;
    * the render's echo does not line up with the recording's: the correlation of their edge
      maps at :data:`CHECK_SMOOTHING` (the same in both domains) is below
      :data:`MIN_EDGE_CORRELATION`;
    * (``band``) the RMS band-edge difference exceeds :data:`MAX_BAND_RMS_FRACTION` of the
      recording's range span;
    * the search ended at a higher cost than it started; or at the start's cost, above
      :data:`PERFECT_COST`, stopped by the render budget: it never found a way downhill. (A
      search that converged onto its start is not a problem: the start was already a minimum,
      as when a fitted scene is fitted again; the band cost is flat between range bins.);
    * a free parameter moved farther from the start than the recording's far range (x, y, z)
      or :data:`MAX_ANGLE_MOVE_DEG` (angles): it ran away;
    * a free parameter does not change the render at the fitted pose
      (:func:`unidentified_parameters`: x, y and yaw over a flat floor): no recording
      determines it.

    (A render that is black at the fitted pose is not returned at all: :func:`fit_pose` raises
    :class:`FitError`.)

    Parameters
    ----------
    real : SonarImage
        The recording fitted.
    result : FitResult
        The fit.

    Returns
    -------
    tuple of str
        One short clause per problem, naming the value found and the limit.
    """
    out = []
    span = real.sonar.range_max_m - real.sonar.range_min_m
    if not np.isfinite(result.cost):
        out.append(f"the cost at the fitted pose is {result.cost}")
    elif result.domain == "band" and result.cost >= NO_BAND_COST:
        out.append("no beam shows a band in both the recording and the render")
    elif result.domain == "band" and result.cost > MAX_BAND_RMS_FRACTION * span:
        out.append(f"the band edges differ by {result.cost:.3g} m RMS (at most {MAX_BAND_RMS_FRACTION:g} of the "
                   f"{span:.3g} m window, {MAX_BAND_RMS_FRACTION * span:.3g} m, is a fit)")
    if result.domain == "band" and band_view(real).edge_fraction < CENSORED_EDGE_FRACTION:
        # No edge to line up with (a sea bed lit across the window): its fall-off with range.
        if not result.profile_correlation >= MIN_PROFILE_CORRELATION:  # also NaN
            out.append(f"the render's echo does not fall off with range as the recording's does (profile "
                       f"correlation {result.profile_correlation:.2f}, at least {MIN_PROFILE_CORRELATION:g} "
                       "is needed; the recording shows no band edge)")
    elif not result.edge_correlation >= MIN_EDGE_CORRELATION:  # also NaN
        out.append(f"the render's echo does not line up with the recording's (edge correlation "
                   f"{result.edge_correlation:.2f}, at least {MIN_EDGE_CORRELATION:g} is needed)")
    if np.isfinite(result.cost) and result.cost > result.cost_start:
        out.append(f"the search ended worse than it started (cost {result.cost_start:.4g} -> {result.cost:.4g})")
    elif (np.isfinite(result.cost) and result.cost == result.cost_start and result.cost > PERFECT_COST
          and not result.converged):
        out.append(f"the search found nothing better than the start before the render budget ran out "
                   f"(cost {result.cost:.4g})")
    for name in result.free:
        moved = abs(result.values[name] - result.start[name])
        limit = MAX_ANGLE_MOVE_DEG if UNITS[name] == "deg" else real.sonar.range_max_m
        if moved > limit:
            out.append(f"{name} ran away by {moved:.3g} {UNITS[name]} (more than {limit:.3g})")
    loose = unidentified_parameters(result.scene, result.free)
    if loose:
        out.append(unidentified_problem(loose))
    return tuple(out)


def require_echo(real: SonarImage) -> None:
    """Raise :class:`FitError` where the recording holds no echo to fit (:func:`echo_problems`)."""
    problems = echo_problems(real.polar)
    if problems:
        raise FitError("the recording holds no echo to fit: " + "; ".join(problems) + "; nothing written")


def fit_pose(
    real: SonarImage,
    scene: Scene,
    free: Sequence[str] = ("z", "pitch"),
    domain: str = "auto",
    smoothing: Sequence[tuple[float, float]] = DEFAULT_SMOOTHING,
    max_renders: int = 600,
    simulator: Simulator | None = None,
    progress: Callable[[FitProgress], None] | None = None,
) -> FitResult:
    """Find the sonar pose parameters that make the rendered image match a real one.

    Parameters
    ----------
    real : SonarImage
        The real (or reference) image; its beam angles, range window and bins are used for the
        renders.
    scene : Scene
        The scene; its sonar pose (``scene.sonar_pose``) is the starting point, its elevation
        aperture is used.
    free : sequence of {'x', 'y', 'z', 'roll', 'pitch', 'yaw'}
        Parameters to fit; the others keep the scene's values.
    domain : {'auto', 'edges', 'band'}
        What is compared (see the module docstring); ``auto``: chosen by
        :func:`choose_domain` from the scene and the recording.
    smoothing : sequence of (float, float)
        Gaussian sigmas (range bins, beams) of the coarse-to-fine passes (``edges``).
    max_renders : int
        Budget of renders over all passes.
    simulator : Simulator, optional
        Reused if given (it must hold ``scene``).
    progress : callable, optional
        Called with a :class:`FitProgress` after every render of the search.

    Returns
    -------
    FitResult
        Check :attr:`FitResult.problems` (:func:`fit_problems`) before trusting it.

    Raises
    ------
    ConfigError
        An unknown parameter or domain, or ``max_renders`` below 1.
    SonarsimError
        The recording's window is not the scene's sonar's (:func:`check_overlap`).
    FitError
        Nothing echoes inside the recording's window at the fitted pose.
    """
    free = parse_free(free)
    if domain != "auto" and domain not in DOMAINS:
        raise ConfigError("domain", f"unknown domain {domain!r}; allowed: auto, {', '.join(DOMAINS)}")
    if int(max_renders) < 1:
        raise ConfigError("max_renders", f"the render budget is {max_renders}; it must be at least 1")
    check_overlap(real, scene)
    require_echo(real)
    sim = simulator if simulator is not None else Simulator(scene)
    # The intrinsics of every render (fixed): the recording's grid; only the pose varies.
    geometry = recording_geometry(real, scene)
    start = pose_values(scene.sonar_pose)
    renders = 0
    began = time.monotonic()
    stage = {"name": "", "best": float("inf")}

    def render_at(vec: np.ndarray) -> SonarImage:
        nonlocal renders
        renders += 1
        values = dict(start, **dict(zip(free, map(float, vec))))
        return sim.render(pose=pose_from_values(values), sonar=geometry, keep_rays=False)

    x0 = np.array([start[n] for n in free])
    start_image = render_at(x0)
    chosen, why = choose_domain(real, scene, start_image)
    if domain == "auto":
        domain, reason = chosen, why
    else:  # the rule's opinion costs nothing: say when it differs
        reason = "asked for" if chosen == domain else f"asked for (auto would choose {chosen}: {why})"
    real_view = band_view(real)

    def onset_rms(image: SonarImage) -> float:
        d = floor_onset_m(image) - real_view.near
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else float("nan")

    def band_rms(image: SonarImage) -> float:
        d = band_residuals(real_view, band_view(image))
        return float(np.sqrt(np.nanmean(d**2))) if np.isfinite(d).any() else NO_BAND_COST

    def reported(cost_of_image):
        """The cost of the image rendered at a vector, with the progress report."""
        def cost(vec):
            value = cost_of_image(render_at(vec))
            stage["best"] = min(stage["best"], value)
            if progress is not None:
                progress(FitProgress(renders, int(max_renders), stage["name"], stage["best"],
                                     time.monotonic() - began))
            return value
        return cost

    def search(cost, x, budget):
        simplex = np.vstack([x] + [x + STEPS[n] * np.eye(len(free))[i] for i, n in enumerate(free)])
        return optimize.minimize(
            cost, x, method="Nelder-Mead",
            options={"initial_simplex": simplex, "maxfev": budget, "xatol": 1e-4, "fatol": 1e-7},
        )

    if domain == "edges":
        x = x0
        for i, sigma in enumerate(smoothing):
            stage.update(name=f"edges {i + 1}/{len(smoothing)}", best=float("inf"))
            target = edge_map(real.polar, sigma)
            found = search(reported(lambda img, s=sigma, t=target: edge_cost(img.polar, t, s)), x,
                           max(1, max_renders // len(smoothing)))
            x = found.x
        finest = tuple(smoothing[-1])
        target = edge_map(real.polar, finest)

        def final_cost(image):
            return edge_cost(image.polar, target, finest)
    else:
        stage.update(name="band", best=float("inf"))
        found = search(reported(band_rms), x0, max_renders)
        x = found.x
        final_cost = band_rms
    cost_start = final_cost(start_image)
    fitted = render_at(x)
    values = dict(start, **dict(zip(free, map(float, x))))
    pose = pose_from_values(values)
    if not np.any(fitted.polar > 0):
        raise FitError("the fit found no pose at which the scene echoes inside the recording's window "
                       f"(started at {', '.join(f'{k} {start[k]:.4g}' for k in free)}): nothing to compare; "
                       "check the scene, its sonar settings and the starting pose")
    result = FitResult(
        pose=pose, scene=replace(scene, sonar=geometry, sonar_pose=pose), free=free, domain=domain, start=start, values=values,
        cost_start=cost_start, cost=final_cost(fitted), onset_rms_m=onset_rms(fitted), renders=renders,
        image=fitted, domain_reason=reason, edge_correlation=edge_correlation(real, fitted),
        profile_correlation=profile_correlation(real, fitted),
        converged=bool(found.success),
    )
    return replace(result, problems=fit_problems(real, result))
