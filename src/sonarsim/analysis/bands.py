"""Realism statistics per range band, the across-fan beam profile, and the realism report.

A statistic over a whole region hides what changes with range: a sonar image's speckle
contrast, grain and level distribution change from the near field to the far edge of the floor
band (log compression makes the ARIS's contrast grow from 0.09 at 3-4 m to 0.21 at 20-22 m,
issue 22), and one region-wide KS can pass while every band fails. So:

* :func:`range_bands` splits the rows where a region has pixels into ``n_bands`` equal range
  intervals (default 8);
* :func:`band_statistics` reports per band the KS statistic and the 1-Wasserstein distance
  between the real and the model's pixel values, both speckle contrasts and their relative
  difference, and both grains (correlation lengths along range and across beams), with the
  functions of :mod:`sonarsim.analysis.realism`;
* :func:`beam_profile_comparison` compares the mean level per beam in dB over the lit region
  (the across-fan gain a real array loses towards the fan's edges);
* :func:`realism_report` gathers everything a realism figure needs beside it, for frames held
  out from the calibration: the trivial baselines and the ceiling
  (:mod:`sonarsim.analysis.baselines`), the margin over the best baseline, the band tables, the
  beam profile and the classifier two-sample test (:mod:`sonarsim.analysis.twosample`).

Everything returned is plain dicts and lists of floats, ints, strings and None (JSON-ready;
NaN marks a statistic that is undefined and a ``reason`` says why; strict JSON writers turn NaN
into null). Images are polar ``(n_range_bins, n_beams)`` arrays, in the device's counts for
real frames and a model in device units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from . import realism
from .metrics import _as_image, _as_mask

__all__ = ["BAND_REGIONS", "MIN_BAND_PIXELS", "N_BANDS", "band_statistics", "beam_profile_comparison",
           "range_bands", "realism_report"]

#: Default number of range bands (issue 22: at least 8).
N_BANDS = 8

#: Regions of :func:`sonarsim.analysis.realism.auto_regions` that are split into bands.
BAND_REGIONS = ("lit", "water")

#: A band with fewer pixels is marked ``ok: False`` and its statistics are NaN: a speckle
#: contrast over fewer than about 100 exponential pixels has a relative error above 10 %, as
#: large as the differences looked for (the issue's target is 15 %).
MIN_BAND_PIXELS = 100

_NAN = float("nan")


def range_bands(mask: Any, n_bands: int = N_BANDS) -> list[tuple[int, int]]:
    """Equal range intervals over the rows where ``mask`` has pixels.

    Parameters
    ----------
    mask : (n_range_bins, n_beams) bool array-like
        The region.
    n_bands : int
        Number of bands, >= 1.

    Returns
    -------
    list of (start, stop) row intervals, ``n_bands`` of them, covering the rows from the
    region's first to its last row without gaps; a band of a region with fewer rows than bands
    may be empty (``start == stop``). An empty region gives ``n_bands`` empty bands at row 0.
    """
    m = np.asarray(mask)
    if m.dtype != bool or m.ndim != 2:
        raise ValueError(f"mask must be a 2-D boolean array, got {m.dtype} of shape {m.shape}")
    if int(n_bands) != n_bands or n_bands < 1:
        raise ValueError(f"n_bands must be an integer >= 1, got {n_bands}")
    rows = np.flatnonzero(m.any(axis=1))
    if not len(rows):
        return [(0, 0)] * int(n_bands)
    edges = np.round(np.linspace(rows[0], rows[-1] + 1, int(n_bands) + 1)).astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _frames(images: Any, name: str) -> list[np.ndarray]:
    """A 2-D image or a sequence of them (same shape) as float64 arrays."""
    if isinstance(images, (list, tuple)) and images and np.ndim(images[0]) == 2:
        out = [_as_image(im, f"{name}[{k}]") for k, im in enumerate(images)]
    else:
        arr = np.asarray(images)
        out = [_as_image(im, f"{name}[{k}]") for k, im in enumerate(arr)] if arr.ndim == 3 else [_as_image(arr, name)]
    if not out:
        raise ValueError(f"{name}: no image given")
    if any(f.shape != out[0].shape for f in out):
        raise ValueError(f"{name}: the images must share a shape, got {sorted({f.shape for f in out})}")
    return out


def _rows(x: np.ndarray, m: np.ndarray, start: int, stop: int, pad: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``start:stop`` of an image with ``pad`` rows either side, and the mask limited to
    ``start:stop``. A local mean of at most ``2 pad + 1`` rows inside the band is then the same
    as in the whole image (the crop only moves the reflected edge outside the band), and the
    statistics cost a band's rows rather than the image's."""
    lo, hi = max(0, start - pad), min(x.shape[0], stop + pad)
    band = np.zeros((hi - lo, x.shape[1]), dtype=bool)
    band[start - lo:stop - lo] = m[start:stop]
    return x[lo:hi], band


def _texture(frames: list[np.ndarray], masks: list[np.ndarray], window: tuple[int, int]) -> tuple[dict, str | None]:
    """Speckle contrast and grain, averaged over frames; NaN and the reason when undefined."""
    try:
        contrast = [realism.speckle_contrast(f, m, window) for f, m in zip(frames, masks)]
        grain = [realism.correlation_lengths(f, m, window) for f, m in zip(frames, masks)]
    except ValueError as exc:  # no echo in the band: a statistic of speckle is undefined
        return {"contrast": _NAN, "grain_range": _NAN, "grain_beams": _NAN}, str(exc)
    return {"contrast": float(np.mean(contrast)), "grain_range": float(np.mean([g.range_bins for g in grain])),
            "grain_beams": float(np.mean([g.beams for g in grain]))}, None


def band_statistics(real: Any, model: Any, region: Any, n_bands: int = N_BANDS, *, range_m: Any = None,
                    min_pixels: int = MIN_BAND_PIXELS,
                    window: tuple[int, int] = realism.LOCAL_MEAN_WINDOW) -> list[dict[str, Any]]:
    """Distribution and texture statistics of a model against real frames, per range band.

    Parameters
    ----------
    real : (n_range_bins, n_beams) array-like, or a sequence of them
        Real frames in the device's counts. With several, KS and Wasserstein are taken between
        their pooled pixels and the model's, contrast and grain are averaged over the frames.
    model : (n_range_bins, n_beams) array-like
        The model on the same grid and in the same units: a speckled render (an expected
        image has no speckle, so its contrast is that of its local structure alone).
    region : (n_range_bins, n_beams) bool array-like
        The region (e.g. ``auto_regions(real)["lit"]``), split by :func:`range_bands`.
    n_bands : int
        Number of bands.
    range_m : (n_range_bins,) array-like, optional
        Range bin centres, metres (uniform), to report each band's range interval.
    min_pixels : int
        Bands with fewer pixels are marked ``ok: False`` with NaN statistics.
    window : (int, int)
        Local-mean window (range bins, beams) of the speckle contrast and the grain.

    Returns
    -------
    list of dict, one per band, nearest first, with ``band`` (index), ``rows`` ([start, stop)),
    ``range_m`` ([near, far] edges in metres, or None), ``pixels``, ``ok`` (enough pixels),
    ``reason`` (None, or why some statistics are NaN), ``ks`` (0-1), ``wasserstein`` (units of
    the images), ``mean_real``/``mean_model``, ``contrast_real``/``contrast_model``,
    ``contrast_rel_diff`` ((model - real) / real), ``grain_range_real``/``_model`` (range bins)
    and ``grain_beams_real``/``_model`` (beams).
    """
    frames = _frames(real, "real")
    y = _as_image(model, "model")
    if y.shape != frames[0].shape:
        raise ValueError(f"model must share the real frames' grid {frames[0].shape}, got {y.shape}")
    m = _as_mask(region, y.shape)
    if m is None:
        raise ValueError("region must be a boolean mask")
    if range_m is not None:
        r = np.asarray(range_m, dtype=np.float64).ravel()
        if r.shape != (y.shape[0],):
            raise ValueError(f"range_m must hold one centre per range bin ({y.shape[0]}), got {r.shape}")
        dr = float(r[1] - r[0]) if len(r) > 1 else 0.0
    pad = int(max(window))
    out = []
    for k, (start, stop) in enumerate(range_bands(m, n_bands)):
        pixels = int(m[start:stop].sum())
        row: dict[str, Any] = {
            "band": k, "rows": [start, stop],
            # Rounded to the nanometre: a window from 0 m must not print as -2e-19 m.
            "range_m": ([round(float(r[start] - dr / 2), 9) + 0.0, round(float(r[stop - 1] + dr / 2), 9) + 0.0]
                        if range_m is not None and stop > start else None),
            "pixels": pixels, "ok": pixels >= min_pixels, "reason": None,
        }
        keys = ("ks", "wasserstein", "mean_real", "mean_model", "contrast_real", "contrast_model", "contrast_rel_diff",
                "grain_range_real", "grain_range_model", "grain_beams_real", "grain_beams_model")
        row.update(dict.fromkeys(keys, _NAN))
        if not row["ok"]:
            row["reason"] = f"{pixels} pixels in the band, fewer than {min_pixels}"
            out.append(row)
            continue
        cut = [_rows(f, m, start, stop, pad) for f in frames]
        ym, ymask = _rows(y, m, start, stop, pad)
        pooled = np.concatenate([f[b] for f, b in cut])
        d = realism.distribution_distances(pooled[None, :], ym[ymask][None, :])
        row.update(ks=d.ks, wasserstein=d.wasserstein, mean_real=float(pooled.mean()), mean_model=float(ym[ymask].mean()))
        whys = {}
        for tag, (tex, why) in (("real", _texture([f for f, _ in cut], [b for _, b in cut], window)),
                                ("model", _texture([ym], [ymask], window))):
            row.update({f"{key}_{tag}": value for key, value in tex.items()})
            if why:
                whys[tag] = why
        reasons = ([f"real and model: {whys['real']}"] if len(whys) == 2 and len(set(whys.values())) == 1
                   else [f"{tag}: {why}" for tag, why in whys.items()])
        if math.isfinite(row["contrast_real"]) and row["contrast_real"] > 0:
            row["contrast_rel_diff"] = (row["contrast_model"] - row["contrast_real"]) / row["contrast_real"]
        elif not reasons:
            reasons.append("real: speckle contrast 0, no relative difference")
        row["reason"] = "; ".join(reasons) or None
        out.append(row)
    return out


def _band_summary(bands: list[dict[str, Any]]) -> dict[str, Any]:
    """Worst values over the bands that have enough pixels (what a target is checked on)."""
    ok = [b for b in bands if b["ok"]]

    def worst(key: str) -> float:
        values = [abs(b[key]) for b in ok if math.isfinite(b[key])]
        return float(max(values)) if values else _NAN

    nulls = [b for b in ok if math.isfinite(b.get("ks_null", _NAN)) and math.isfinite(b["ks"])]
    return {"bands": len(bands), "bands_ok": len(ok), "max_ks": worst("ks"),
            "max_abs_contrast_rel_diff": worst("contrast_rel_diff"),
            "max_ks_null": float(max(b["ks_null"] for b in nulls)) if nulls else _NAN,
            "bands_ks_above_null": sum(b["ks"] > b["ks_null"] for b in nulls) if nulls else None}


def beam_profile_comparison(real: Any, model: Any, region: Any) -> dict[str, Any]:
    """The mean level per beam over a region, in dB, of real frames and of a model.

    Parameters
    ----------
    real : (n_range_bins, n_beams) array-like, or a sequence of them
        Real frames in counts; with several, their pixel-wise mean.
    model : (n_range_bins, n_beams) array-like
        The model (its expected image: the profile is a mean, and speckle only adds noise).
    region : (n_range_bins, n_beams) bool array-like
        Where the means are taken (the lit region: the across-fan gain shows where there is echo).

    Returns
    -------
    dict with ``real_db`` and ``model_db`` (lists of ``n_beams``, ``10 log10`` of the mean,
    None where the beam has no pixel in the region or a mean of 0), ``rms_db`` (RMS of
    model - real over the beams where both are defined; NaN with ``reason`` when none is),
    ``beams`` (that number) and ``reason``.
    """
    frames = _frames(real, "real")
    x = np.mean(frames, axis=0)
    y = _as_image(model, "model")
    if y.shape != x.shape:
        raise ValueError(f"model must share the real frames' grid {x.shape}, got {y.shape}")
    m = _as_mask(region, x.shape)
    pa, pb = realism.beam_profile_db(x, m), realism.beam_profile_db(y, m)
    # beam_profile_db gives its floor (-300 dB) for a mean of 0: no level to compare in dB.
    both = np.isfinite(pa) & np.isfinite(pb) & (pa > -300) & (pb > -300)

    def listed(p: np.ndarray) -> list:
        return [float(v) if np.isfinite(v) and v > -300 else None for v in p]

    rms = float(np.sqrt(np.mean((pb[both] - pa[both]) ** 2))) if both.any() else _NAN
    return {"real_db": listed(pa), "model_db": listed(pb), "rms_db": rms, "beams": int(both.sum()),
            "reason": None if both.any() else "no beam with echo in both images inside the region"}


def realism_report(real_frames: Sequence[Any], model_expected: Any, model_speckled: Any = None,
                   calibration_frame_index: int = 0, *, held_out: Sequence[int] | None = None, mask: Any = None,
                   regions: Mapping[str, Any] | None = None, n_bands: int = N_BANDS, range_m: Any = None,
                   data_range: float = 255.0, min_band_pixels: int = MIN_BAND_PIXELS,
                   c2st: Mapping[str, Any] | None = None,
                   frame_numbers: Sequence[int] | None = None) -> dict[str, Any]:
    """Everything a realism figure needs beside it, scored on frames held out from the calibration.

    The trivial images (:func:`sonarsim.analysis.baselines.baseline_images`: the calibration
    frame's range profile in every beam, its separable range x beam image, and its 15 x 9
    local mean, the ceiling) are made from the calibration frame, then they and the model's
    expected image are scored (PSNR, SSIM, in the images' own units) on the held-out frames,
    which none of them was made from. Then, on the held-out frames: statistics per range band
    of the lit region and of the water column (:func:`band_statistics`, regions found on the
    calibration frame by :func:`sonarsim.analysis.realism.auto_regions`), the across-fan beam
    profile (:func:`beam_profile_comparison`) and the classifier two-sample test
    (:func:`sonarsim.analysis.twosample.classifier_two_sample_test`, real held-out frames
    against the speckled model).

    With a single real frame there is nothing to hold out: everything is scored against the
    calibration frame itself. That favours the trivial images (made from the very pixels they
    are scored on; the ceiling most, a local mean of its own frame) and a model calibrated on
    that frame; the report says so (``optimistic: True`` and ``note``).

    Parameters
    ----------
    real_frames : sequence of (n_range_bins, n_beams) array-like
        Frames of a recording, in the device's counts, on one grid.
    model_expected : (n_range_bins, n_beams) array-like
        The model's expected image (``render(..., speckle=False)``) in device units, on that grid.
    model_speckled : (n_range_bins, n_beams) array-like, or a sequence of them, optional
        Speckled renders, for the distributions (bands, C2ST). Default ``model_expected``
        (then the model's contrast is its local structure's alone, and ``note`` says so).
    calibration_frame_index : int
        The frame the model was calibrated on (and the trivial images are made from).
    held_out : sequence of int, optional
        Frames scored on (default every other frame). Must not hold the calibration frame
        unless it is the only frame.
    mask : (n_range_bins, n_beams) bool array-like, optional
        Cells scored (default all), e.g. where a resampled model covers the recording.
    regions : mapping of name -> (n_range_bins, n_beams) bool array-like, optional
        Regions split into bands (default ``lit`` and ``water`` of ``auto_regions`` of the
        calibration frame within ``mask``).
    n_bands : int
        Range bands per region (:func:`range_bands`).
    range_m : (n_range_bins,) array-like, optional
        Range bin centres, metres, to label the bands.
    data_range : float
        Full scale of PSNR and SSIM (255 for 8-bit devices).
    min_band_pixels : int
        Bands with fewer pixels are marked, with NaN statistics.
    c2st : mapping, optional
        Keyword options of ``classifier_two_sample_test`` (``patch``, ``folds``, ``seeds``,
        ``seed``, ...). Its patches lie inside ``mask``.
    frame_numbers : sequence of int, optional
        The recording's numbers of ``real_frames`` (default 0, 1, ...), used in the report's
        ``calibration_frame``, ``held_out_frames`` and ``note``; ``calibration_frame_index``
        and ``held_out`` index ``real_frames``.

    Returns
    -------
    dict (JSON-ready; NaN where undefined) with:

    * ``calibration_frame`` (int), ``held_out_frames`` (list of int), ``optimistic`` (bool),
      ``note`` (str: what was scored on what);
    * ``scores``: ``{"model", "range profile", "separable", "ceiling"}`` each ``{"psnr" (dB),
      "ssim", "margin_db"}``, means over the held-out frames; ``margin_db`` is the PSNR above
      the best of the two trivial images;
    * ``best_baseline`` (its name), ``margin_db`` (the model's), ``ceiling_margin_db`` (how
      far above the best baseline a deterministic image can get), ``below_baseline`` (bool)
      and ``warning`` (a one-line message when the model scores below the best baseline, else
      None);
    * ``bands``: ``{region: list of band dicts}`` (:func:`band_statistics`, of the first
      speckled render), each with ``ks_null`` where several speckled renders are given: the
      largest KS between the first and another of them in that band, what a perfect model
      scores against a recording that is another draw of it (NaN with one render); and
      ``band_summary``: ``{region: {"bands", "bands_ok", "max_ks", "max_abs_contrast_rel_diff",
      "max_ks_null", "bands_ks_above_null"}}``;
    * ``beam_profile``: :func:`beam_profile_comparison` over the lit region;
    * ``c2st``: ``C2STResult.to_dict()``, or ``{"accuracy": NaN, "reason": ...}`` when there
      are too few patches.

    Raises
    ------
    ValueError
        No real frame, frames or model on different grids, a calibration or held-out index out
        of range, the calibration frame among several frames' held-out ones.
    """
    from .baselines import baseline_images, held_out_scores
    from .twosample import classifier_two_sample_test

    frames = _frames(list(real_frames), "real_frames")
    n = len(frames)
    shape = frames[0].shape
    expected = _as_image(model_expected, "model_expected")
    if expected.shape != shape:
        raise ValueError(f"model_expected must share the real frames' grid {shape}, got {expected.shape}")
    speckled = [expected] if model_speckled is None else _frames(model_speckled, "model_speckled")
    if speckled[0].shape != shape:
        raise ValueError(f"model_speckled must share the real frames' grid {shape}, got {speckled[0].shape}")
    cal = int(calibration_frame_index)
    if not 0 <= cal < n:
        raise ValueError(f"calibration_frame_index {calibration_frame_index} is not a frame (0-{n - 1})")
    if held_out is None:
        held = [k for k in range(n) if k != cal] or [cal]
    else:
        held = [int(k) for k in held_out]
        bad = [k for k in held if not 0 <= k < n]
        if bad or not held:
            raise ValueError(f"held_out must name frames 0-{n - 1}, got {list(held_out)}")
        if cal in held and n > 1:
            raise ValueError(f"held_out holds the calibration frame {cal}: score on the other frames")
    m = _as_mask(mask, shape)
    m = np.ones(shape, dtype=bool) if m is None else m
    labels = list(range(n)) if frame_numbers is None else [int(k) for k in frame_numbers]
    if len(labels) != n:
        raise ValueError(f"frame_numbers must number the {n} real frames, got {len(labels)}")
    optimistic = held == [cal]
    scored = [frames[k] for k in held]
    if optimistic:
        note = (f"one real frame: the baselines and the ceiling are made from frame {labels[cal]} and scored "
                "against it, which favours them (the ceiling most: the frame's own local mean), and a model "
                "calibrated on it; optimistic figures")
    else:
        note = (f"baselines and ceiling made from frame {labels[cal]}; they and the model scored on held-out "
                f"frame{'s' if len(held) > 1 else ''} {', '.join(str(labels[k]) for k in held)}")
    if model_speckled is None:
        note += "; distributions of model_expected (no speckled render given)"

    scores = held_out_scores({"model": expected, **baseline_images(frames[cal], m)}, scored, m, data_range)
    best = max(("range profile", "separable"), key=lambda k: scores[k]["psnr"])
    margin = scores["model"]["margin_db"]
    below = bool(margin < 0)
    warning = (f"the model scores {scores['model']['psnr']:.2f} dB, {-margin:.2f} dB below the trivial "
               f"'{best}' image ({scores[best]['psnr']:.2f} dB), which has no geometry") if below else None

    if regions is None:
        found = realism.auto_regions(frames[cal], m)
        regions = {k: found[k] for k in BAND_REGIONS}
    bands = {}
    for name, region in regions.items():
        region = _as_mask(region, shape)
        # Statistics of the model's (first) speckled render; pooled over the scored frames.
        bands[name] = band_statistics(scored, speckled[0], region & m, n_bands, range_m=range_m,
                                      min_pixels=min_band_pixels)
        # The KS a perfect model would score: its first draw against its other draws, band by
        # band. A patchy floor's band holds few independent patches, so two draws of one model
        # differ by more than speckle alone makes them (issue 22: 0.12-0.28 in the worst lit
        # band for the calibrated Oculus scene with its texture, 0.04-0.06 without).
        nulls = [band_statistics([s], speckled[0], region & m, n_bands, range_m=range_m, min_pixels=min_band_pixels)
                 for s in speckled[1:]]
        for k, b in enumerate(bands[name]):
            values = [nb[k]["ks"] for nb in nulls if math.isfinite(nb[k]["ks"])]
            b["ks_null"] = float(max(values)) if values else _NAN
    lit = regions.get("lit")
    beam = beam_profile_comparison(scored, expected, (np.asarray(lit, dtype=bool) if lit is not None else m) & m)
    try:
        two = classifier_two_sample_test(scored, speckled, m, **dict(c2st or {})).to_dict()
    except ValueError as exc:
        two = {"accuracy": _NAN, "reason": str(exc)}
    return {
        "calibration_frame": labels[cal], "held_out_frames": [labels[k] for k in held], "optimistic": optimistic,
        "note": note,
        "data_range": float(data_range), "scores": scores, "best_baseline": best, "margin_db": margin,
        "ceiling_margin_db": scores["ceiling"]["margin_db"], "below_baseline": below, "warning": warning,
        "bands": bands, "band_summary": {k: _band_summary(v) for k, v in bands.items()},
        "beam_profile": beam, "c2st": two,
    }
