"""A side-scan recording against the simulator, with its logged geometry (issue 38 item 6).

The recording logs, per ping, the vehicle's altitude, attitude and heading; the simulator puts a
side-scan there over a flat floor (:mod:`sonarsim.instruments.replay`) and predicts what the
device records. What the logs do not say (the transducers' depression and vertical beam width,
the device's gain and its time-varied gain) is fitted on calibration pings and scored on other
pings, never on those it was fitted on.

Two predictions are scored, each beside trivial ones:

* **The first bottom return** per ping and side, found by one detector on the recording and on
  the prediction alike (:func:`first_return_m`): against "first return = the logged altitude"
  and against the pure geometry of a flat floor, ``altitude / (cos pitch cos roll)``.
* **The expected intensity** across track, in dB per coarse range bin
  (:func:`profile_db`): against the calibration pings' mean profile copied to every ping, and
  that profile shifted to each ping's own first return (measured on the recording: a baseline
  that is given the answer to the first question). The ceiling is a ping's profile predicted
  by the mean of its neighbours (what speckle leaves predictable).

The model of the recorded intensity: ``I = g r^k (E(r) + n)``, with ``E`` the simulator's
expected echo (spreading compensated, ``render.tvg``), ``g`` the gain (``gain_db``), ``r^k`` the
device's time-varied gain beyond spreading (``range_exponent``), ``n`` the noise at its input
(``noise_db``, relative to ``E``: the device's gains act on both).
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.ndimage import uniform_filter1d

from ..config import parameters
from ..image.films import Waterfall

__all__ = ["SidescanFit", "first_return_m", "profile_db", "predict", "calibrate", "score", "FIT_KEYS"]

#: Samples at or above this are clipped (the recording's transmit bang saturates at 32767).
SATURATED = 32767.0
#: What the detector ignores at the start of a line (the transmit bang), metres.
BANG_M = 0.5
#: The detector: the first sample whose running mean over SMOOTH samples exceeds FRACTION of
#: the median of those running means beyond the bang (the floor's level), and where PERSIST of
#: the HOLD samples from it on do too.
SMOOTH, FRACTION = 9, 0.25
HOLD, PERSIST = 33, 0.8
#: Coarse range bins of the intensity profiles.
N_BINS = 64
#: The parameters fitted, and their bounds (``sidescan.*`` in the one table of fittable parameters).
FIT_KEYS = ("depression_deg", "vertical_beam_width_deg", "gain_db", "range_exponent", "noise_db")
BOUNDS = {k: parameters.bounds(f"sidescan.{k}") for k in FIT_KEYS}


@dataclass(frozen=True)
class SidescanFit:
    """What a side-scan's logs do not say, as fitted (see the module notes for the model)."""

    depression_deg: float = 10.0
    vertical_beam_width_deg: float = 50.0
    gain_db: float = 80.0
    range_exponent: float = 0.0
    noise_db: float = 20.0
    altitude_offset_m: float = 0.0

    def vector(self) -> np.ndarray:
        return np.array([getattr(self, k) for k in FIT_KEYS])

    @classmethod
    def of(cls, x: np.ndarray, base: "SidescanFit") -> "SidescanFit":
        return replace(base, **{k: float(v) for k, v in zip(FIT_KEYS, x)})


def _clean(samples: np.ndarray) -> np.ndarray:
    s = np.asarray(samples, np.float64)
    return np.where(s >= SATURATED, np.nan, s)


def first_return_m(samples: np.ndarray, slant_range_m: np.ndarray) -> np.ndarray:
    """The first bottom return of each line, metres (one detector for recordings and renders).

    Parameters
    ----------
    samples : (n_pings, 2, n_samples) array
        Intensities (saturated samples, ``>= 32767``, are ignored).
    slant_range_m : (n_samples,) array

    Returns
    -------
    (n_pings, 2) float64 ndarray
        NaN where no sample qualifies.
    """
    s = _clean(samples)
    after = slant_range_m > BANG_M
    level = uniform_filter1d(np.nan_to_num(s), SMOOTH, axis=2)
    # the floor's level from the running means (a recording's speckle moves a median of single
    # samples to 0.69 of the mean; a render has none)
    floor = np.nanmedian(np.where(after & np.isfinite(s), level, np.nan), axis=2)
    above = (level > FRACTION * floor[..., None]) & after
    # ... and stays there: at least PERSIST of the next HOLD samples above too (a speckle
    # spike in the water column is a few samples long; the floor goes on)
    ahead = uniform_filter1d(above.astype(np.float64), HOLD, axis=2, origin=-(HOLD // 2), mode="nearest")
    above &= ahead >= PERSIST
    k = np.argmax(above, axis=2)
    out = slant_range_m[k].astype(np.float64)
    return np.where(above.any(axis=2), out, np.nan)


def profile_db(samples: np.ndarray, n_bins: int = N_BINS) -> np.ndarray:
    """Mean intensity in ``n_bins`` equal range bins, dB (``10 log10``), ``(n_pings, 2, n_bins)``;
    NaN where a bin holds no unsaturated sample or only zeros."""
    s = _clean(samples)
    n = s.shape[2] // n_bins * n_bins
    b = s[..., :n].reshape(s.shape[:2] + (n_bins, -1))
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a bin of saturated samples only: NaN, said so above
        mean = np.nanmean(b, axis=3)
        return np.where(mean > 0, 10.0 * np.log10(mean), np.nan)


class Predictor:
    """Renders a recording's pings over a flat floor with a side-scan of given unknowns."""

    def __init__(self, recording: Waterfall, preset: str | None = "seascan_hds_600") -> None:
        import sonarsim

        self.recording = recording
        # in the recording's layout: its range window and samples
        section = {"type": "sidescan", **({"preset": preset} if preset else {}), "range_min_m": recording.range_min_m,
                   "range_max_m": recording.range_max_m, "n_samples": recording.n_samples,
                   "pose": {"position_m": [0.0, 0.0, 10.0]}}
        self.doc = {"sonar": section, "ground": {"height_m": 0.0, "material": {"law": "lambert", "mu": 0.01}},
                    "render": {"max_order": 1}}
        self.sim = sonarsim.Simulator(self.doc)
        self.spec = self.sim.scene.instruments[0]

    def expected(self, fit: SidescanFit, pings) -> np.ndarray:
        """The model's expected intensity at ``pings`` (indices into the recording),
        ``(len(pings), 2, n_samples)`` float64."""
        from ..instruments.replay import poses_from_geometry
        from ..instruments.sidescan import render_sidescan

        geometry = self.recording.geometry[np.asarray(pings)]
        if fit.altitude_offset_m:
            geometry = replace(geometry, altitude_m=geometry.altitude_m + fit.altitude_offset_m)
        poses = poses_from_geometry(self.sim.scene, geometry)
        spec = replace(self.spec, depression_deg=fit.depression_deg, vertical_beam_width_deg=fit.vertical_beam_width_deg)
        w = render_sidescan(self.sim, spec, poses, geometry.time_s, 0, False, False)
        r = self.recording.slant_range_m
        # the device's gain and time-varied gain act on all it receives: echo and noise alike
        g = 10.0 ** (fit.gain_db / 10.0) * np.power(r, fit.range_exponent)
        return (w.samples.astype(np.float64) + 10.0 ** (fit.noise_db / 10.0)) * g

    def close(self) -> None:
        self.sim.close()


def predict(recording: Waterfall, fit: SidescanFit, pings) -> np.ndarray:
    """:meth:`Predictor.expected` once."""
    p = Predictor(recording)
    try:
        return p.expected(fit, pings)
    finally:
        p.close()


def calibrate(recording: Waterfall, pings, start: SidescanFit | None = None, every: int = 3) -> SidescanFit:
    """Fit :data:`FIT_KEYS` on the recording's ``pings`` (every ``every``-th of them) by least
    squares on the dB profiles (:func:`profile_db`) of each ping and side.

    Returns
    -------
    SidescanFit
    """
    from scipy.optimize import least_squares

    pings = np.asarray(pings)[::every]
    measured = profile_db(recording.samples[pings])
    predictor = Predictor(recording)
    start = start or SidescanFit(gain_db=float(np.nanmedian(measured)) + 20.0, noise_db=-30.0)
    lo = np.array([BOUNDS[k][0] for k in FIT_KEYS])
    hi = np.array([BOUNDS[k][1] for k in FIT_KEYS])

    def residual(x):
        got = profile_db(predictor.expected(SidescanFit.of(x, start), pings))
        d = got - measured
        return np.where(np.isfinite(d), d, 0.0).ravel()

    try:
        res = least_squares(residual, np.clip(start.vector(), lo, hi), bounds=(lo, hi), x_scale=[5, 10, 10, 0.5, 10],
                            diff_step=1e-3, max_nfev=200)
    finally:
        predictor.close()
    return SidescanFit.of(res.x, start)


def _rmse(d: np.ndarray) -> float:
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")


def _shift_profile(mean_profile: np.ndarray, first_cal: np.ndarray, first: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The calibration pings' mean dB profile (per side) against range after the first return,
    placed at each ping's own first return: ``(n_pings, 2, n_bins)``."""
    out = np.full(first.shape + (len(centres),), np.nan)
    ref = np.nanmedian(first_cal, axis=0)  # (2,)
    for side in range(2):
        ok = np.isfinite(mean_profile[side])
        for p in range(first.shape[0]):
            if np.isfinite(first[p, side]):
                out[p, side] = np.interp(centres - first[p, side] + ref[side], centres[ok], mean_profile[side][ok],
                                         left=np.nan, right=np.nan)
    return out


def score(recording: Waterfall, fit: SidescanFit, calibration, test) -> dict:
    """The fitted model on ``test`` pings beside the trivial predictions (module notes).

    Returns
    -------
    dict
        ``first_return``: median absolute error, metres, of the model and of the baselines;
        ``intensity_db``: RMS error of the dB profiles, model, baselines and ceiling; the pings.
    """
    calibration, test = np.asarray(calibration), np.asarray(test)
    r = recording.slant_range_m
    measured_first = first_return_m(recording.samples[test], r)
    expected = predict(recording, fit, test)
    model_first = first_return_m(expected, r)
    g = recording.geometry[test]
    h = g.altitude_m[:, None]
    geometric = h / (np.cos(np.radians(g.pitch_deg)) * np.cos(np.radians(g.roll_deg)))[:, None]
    med = lambda a: float(np.nanmedian(np.abs(a)))  # noqa: E731
    first = {"model_m": med(model_first - measured_first), "altitude_m": med(h - measured_first),
             "geometry_m": med(geometric - measured_first)}

    measured = profile_db(recording.samples[test])
    cal_profiles = profile_db(recording.samples[calibration])
    mean_profile = 10.0 * np.log10(np.nanmean(10.0 ** (cal_profiles / 10.0), axis=0))  # (2, n_bins)
    n_bins = measured.shape[2]
    centres = (np.arange(n_bins) + 0.5) * (r[-1] + (r[1] - r[0]) / 2) / n_bins
    shifted = _shift_profile(mean_profile, first_return_m(recording.samples[calibration], r), measured_first, centres)
    neighbours = np.full_like(measured, np.nan)
    neighbours[1:-1] = 10.0 * np.log10((10.0 ** (measured[:-2] / 10.0) + 10.0 ** (measured[2:] / 10.0)) / 2.0)
    model = profile_db(expected)
    # one set of cells for all: where the recording, the model and every baseline have a value
    cells = np.isfinite(measured) & np.isfinite(model) & np.isfinite(shifted) & np.isfinite(neighbours)
    cells &= np.isfinite(mean_profile)[None]
    d = lambda a: np.where(cells, a - measured, np.nan)  # noqa: E731
    intensity = {"model_db": _rmse(d(model)), "mean_profile_db": _rmse(d(np.broadcast_to(mean_profile, measured.shape))),
                 "shifted_profile_db": _rmse(d(shifted)), "ceiling_neighbours_db": _rmse(d(neighbours)),
                 "cells": int(cells.sum())}
    # The same split where the recording's echo comes from: the water column (bins ending half a
    # metre before the ping's measured first return: noise, the model's one level) and the floor
    # (bins from a metre after it), each with the model and the shifted profile.
    half_bin = centres[1] - centres[0]
    water = centres[None, None, :] + half_bin / 2 < measured_first[..., None] - 0.5
    floor = centres[None, None, :] - half_bin / 2 > measured_first[..., None] + 1.0
    for name, where in (("water_column", water), ("floor", floor)):
        e = lambda a: np.where(cells & where, a - measured, np.nan)  # noqa: E731
        intensity[name] = {"model_db": _rmse(e(model)), "shifted_profile_db": _rmse(e(shifted)),
                           "cells": int((cells & where).sum())}
    return {"first_return": first, "intensity_db": intensity, "fit": asdict(fit),
            "calibration_pings": [int(calibration.min()), int(calibration.max())],
            "test_pings": [int(test.min()), int(test.max())]}
