"""A multibeam recording against the simulator, with its logged attitude (issue 38 item 6).

The R2Sonic recording logs per ping the head's roll, pitch, heave, heading and position, and per
beam the two-way travel time, the angle and the backscatter. What it does not log is the floor:
a plane (depth and tilt) is fitted to the soundings of calibration pings, and the simulator
renders the other pings over it (:mod:`sonarsim.instruments.multibeam`: each beam's bottom
detected in the engine's water column) with each ping's attitude.

Scored on those other pings, beside trivial predictions on the same pings:

* **per-beam range** (``c t / 2``) against the recorded two-way times: the calibration pings'
  mean range per beam, and a level flat floor at their mean depth seen straight
  (``depth / cos(angle)``, attitude ignored);
* **per-beam backscatter** (dB): the calibration pings' mean per beam, against the floor's
  angular response (dB against incidence, a table fitted on the calibration pings) read at each
  beam's incidence as the render finds it (the ping's attitude and the floor's tilt move every
  beam's incidence), plus each beam's own gain (fitted with it: the head's per-beam
  calibration);
* **the angular response** (mean dB in 2-degree bins of incidence, the sea bed's signature):
  the sediment law (:mod:`sonarsim.core.seabed`) with its grain size and level fitted on the
  calibration pings' response (:func:`fit_sediment`), against the test pings' response, beside
  the calibration pings' per-beam mean binned the same way and the calibration pings' own
  response (the ceiling: what a perfect law fitted there could score).
"""

from __future__ import annotations

import numpy as np

from ..config import parameters
from ..image.films import Soundings

__all__ = ["world_points", "fit_floor", "render_pings_over", "score", "fit_sediment", "angular_response",
           "INCIDENCE_KNOTS_DEG", "RESPONSE_BIN_DEG"]

#: Knots of the fitted angular response, degrees of incidence.
INCIDENCE_KNOTS_DEG = np.arange(0.0, 75.0, 5.0)
#: Bins of the angular response (mean dB against incidence), degrees.
RESPONSE_BIN_DEG = 2.0
#: The R2Sonic 2026's frequency in the recording (its preset's, r2sonic_2026_400), Hz.
FREQUENCY_HZ = 400e3
# The rendered floor's law: Lambert's, whose known mu cos^2 the footprint is read against.
FLOOR_MU = 0.01
#: The grain sizes fit_sediment tries are this far apart (phi), over the table's bounds.
PHI_STEP = 0.1
# A bin of the angular response counts where it holds at least this many cells.
_MIN_CELLS = 20


def angular_response(incidence_deg: np.ndarray, db: np.ndarray, edges: np.ndarray | None = None):
    """Mean dB per bin of incidence: ``(centres_deg, mean_db, counts)`` over the finite cells,
    bins of :data:`RESPONSE_BIN_DEG` from 0 to 80 degrees (bins with fewer than 20 cells: NaN)."""
    edges = np.arange(0.0, 80.0 + RESPONSE_BIN_DEG, RESPONSE_BIN_DEG) if edges is None else edges
    inc, v = np.asarray(incidence_deg).ravel(), np.asarray(db).ravel()
    ok = np.isfinite(inc) & np.isfinite(v)
    k = np.digitize(inc[ok], edges) - 1
    inside = (k >= 0) & (k < len(edges) - 1)
    counts = np.bincount(k[inside], minlength=len(edges) - 1)
    sums = np.bincount(k[inside], weights=v[ok][inside], minlength=len(edges) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(counts >= _MIN_CELLS, sums / np.maximum(counts, 1), np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), mean, counts


def fit_sediment(incidence_deg: np.ndarray, response_db: np.ndarray, frequency_hz: float,
                 sound_speed_m_s: float = 1500.0, weights: np.ndarray | None = None) -> dict:
    """The sediment (grain size, or rock / cobble) and level whose law best fits an angular
    response (least squares in dB; the level is each candidate's weighted mean residual).

    Parameters
    ----------
    incidence_deg, response_db : (n,) float arrays
        The response: mean dB at each incidence (NaN: no data). The dB are ``10 log10`` of an
        intensity (or ``20 log10`` of an amplitude) up to a constant, which the level absorbs.
    frequency_hz, sound_speed_m_s : float
    weights : (n,) float array, optional
        Per point (a bin's cell count); default equal.

    Returns
    -------
    dict
        ``sediment`` (a class name or ``None``), ``grain_size_phi``, ``level_db`` (the constant
        added to ``10 log10 sigma``), ``rms_db`` (weighted, on the points fitted).
    """
    from ..core import seabed

    inc = np.asarray(incidence_deg, float)
    y = np.asarray(response_db, float)
    w = np.ones_like(y) if weights is None else np.asarray(weights, float)
    ok = np.isfinite(inc) & np.isfinite(y) & (w > 0) & (inc < 89.0)
    grazing = np.radians(90.0 - inc[ok])
    phi_lo, phi_hi = parameters.bounds("material.grain_size_phi")  # the scene format's, from the one table
    candidates = [(None, phi, seabed.sediment_from_grain_size(phi, water_sound_speed_m_s=sound_speed_m_s))
                  for phi in np.round(np.arange(phi_lo, phi_hi + 1e-4, PHI_STEP), 6)]
    candidates += [(name, None, seabed.ROCKS[name]) for name in ("cobble", "rock")]
    best = None
    for name, phi, sed in candidates:
        law = 10.0 * np.log10(seabed.backscatter(grazing, sed, frequency_hz, sound_speed_m_s))
        level = float(np.average(y[ok] - law, weights=w[ok]))
        rms = float(np.sqrt(np.average((y[ok] - law - level) ** 2, weights=w[ok])))
        if best is None or rms < best["rms_db"]:
            best = {"sediment": name, "grain_size_phi": None if phi is None else float(phi), "level_db": level,
                    "rms_db": rms}
    return best


def sediment_response_db(incidence_deg: np.ndarray, fit: dict, frequency_hz: float,
                         sound_speed_m_s: float = 1500.0) -> np.ndarray:
    """The fitted sediment law in dB at ``incidence_deg`` (:func:`fit_sediment`'s result)."""
    from ..core import seabed

    sed = (seabed.ROCKS[fit["sediment"]] if fit["sediment"] is not None
           else seabed.sediment_from_grain_size(fit["grain_size_phi"], water_sound_speed_m_s=sound_speed_m_s))
    inc = np.asarray(incidence_deg, float)
    out = np.full(inc.shape, np.nan)
    ok = np.isfinite(inc) & (inc < 89.9)
    out[ok] = 10.0 * np.log10(seabed.backscatter(np.radians(90.0 - inc[ok]), sed, frequency_hz, sound_speed_m_s))
    return out + fit["level_db"]


def world_points(s: Soundings, pings) -> np.ndarray:
    """The soundings of ``pings`` in a local world frame (x east, y north, z up; the head's
    positions and heave), metres, ``(n, n_beams, 3)``: roll and pitch applied
    (:meth:`Soundings.level_points`), then the heading (yaw ``90 - heading``)."""
    pings = np.asarray(pings)
    level = s.level_points()[pings]
    yaw = np.radians(90.0 - s.geometry.heading_deg[pings])[:, None]
    x, y = level[..., 0], level[..., 1]
    g = s.geometry
    east = x * np.cos(yaw) - y * np.sin(yaw) + np.nan_to_num(g.x_m[pings])[:, None]
    north = x * np.sin(yaw) + y * np.cos(yaw) + np.nan_to_num(g.y_m[pings])[:, None]
    up = level[..., 2] + np.nan_to_num(g.heave_m[pings])[:, None]
    return np.stack([east, north, up], axis=-1)


def fit_floor(s: Soundings, pings) -> np.ndarray:
    """The plane ``z = a + b x + c y`` through the soundings of ``pings`` (least squares, twice:
    the second time without soundings more than 3 robust sigmas off the first). Returns ``(a, b, c)``."""
    p = world_points(s, pings).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    keep = np.ones(len(p), bool)
    for _ in range(2):
        A = np.column_stack([np.ones(keep.sum()), p[keep, 0], p[keep, 1]])
        coef = np.linalg.lstsq(A, p[keep, 2], rcond=None)[0]
        r = p[:, 2] - (coef[0] + coef[1] * p[:, 0] + coef[2] * p[:, 1])
        keep = np.abs(r) < 3.0 * 1.4826 * np.median(np.abs(r - np.median(r)))
    return coef


def _scene(s: Soundings, floor: np.ndarray, n_samples: int, range_max_m: float) -> dict:
    a, b, c = floor
    normal = np.array([-b, -c, 1.0])
    normal /= np.linalg.norm(normal)
    first, last = float(np.nanmedian(s.angle_deg[:, 0])), float(np.nanmedian(s.angle_deg[:, -1]))
    return {
        "sonar": {"type": "multibeam", "preset": "r2sonic_2026_400", "beam_angles_deg": [first, last],
                  "n_beams": s.n_beams, "range_max_m": range_max_m, "n_samples": n_samples,
                  "sound_speed_m_s": float(np.nanmedian(s.geometry.sound_speed_m_s)),
                  "pose": {"position_m": [0.0, 0.0, 0.0]}},
        "planes": [{"name": "floor", "point_m": [0.0, 0.0, float(a)], "normal": normal.tolist(),
                    "material": {"law": "lambert", "mu": FLOOR_MU}, "specular": 0.0}],
        "render": {"max_order": 1},
    }


def render_pings_over(s: Soundings, floor: np.ndarray, pings, n_samples: int = 2048, range_max_m: float = 32.0):
    """The recording's ``pings`` rendered over the plane ``floor`` with each ping's attitude,
    heading, position and heave: the simulator's :class:`Soundings` (its ``points_m`` the truth)."""
    import sonarsim
    from ..core.transforms import Pose
    from ..instruments import render_pings

    pings = np.asarray(pings)
    g = s.geometry
    poses = [Pose((float(np.nan_to_num(g.x_m[k])), float(np.nan_to_num(g.y_m[k])), float(np.nan_to_num(g.heave_m[k]))),
                  (float(g.roll_deg[k]), float(g.pitch_deg[k]), float(90.0 - g.heading_deg[k]))) for k in pings]
    with sonarsim.Simulator(_scene(s, floor, n_samples, range_max_m)) as sim:
        return render_pings(sim, poses=poses, times_s=g.time_s[pings], speckle=False)


def _interp_beams(angle_from: np.ndarray, values: np.ndarray, angle_to: np.ndarray) -> np.ndarray:
    """Per ping, ``values`` at ``angle_from`` read at ``angle_to`` (angles descend across beams)."""
    out = np.full(angle_to.shape, np.nan)
    for p in range(angle_to.shape[0]):  # per ping: one np.interp over its beams
        ok = np.isfinite(values[p]) & np.isfinite(angle_from[p])
        if ok.sum() > 1:
            out[p] = np.interp(-angle_to[p], -angle_from[p][ok], values[p][ok], left=np.nan, right=np.nan)
    return out


def _spread_per_beam(values: np.ndarray) -> float:
    """The median over beams of each beam's standard deviation over pings (NaN ignored)."""
    ok = np.isfinite(values).sum(axis=0) > 1
    if not ok.any():
        return float("nan")
    return float(np.median(np.nanstd(values[:, ok], axis=0)))


def _incidence_deg(render: Soundings, floor: np.ndarray, heads: np.ndarray) -> np.ndarray:
    a, b, c = floor
    n = np.array([-b, -c, 1.0]) / np.linalg.norm([-b, -c, 1.0])
    d = render.points_m - heads[:, None, :]
    cos = np.abs(d @ n) / np.linalg.norm(d, axis=-1)
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


def score(s: Soundings, calibration, test, n_samples: int = 2048) -> dict:
    """Fit the floor on ``calibration`` pings, render ``test`` pings over it, score (module notes).

    Returns
    -------
    dict
        ``floor`` (depth below the heads' mean height, tilt east and north, degrees);
        ``range_m``: median absolute error of the model and the baselines; ``backscatter_db``:
        rms error of the model and the baseline; the pings.
    """
    cal, test = np.asarray(calibration), np.asarray(test)
    floor = fit_floor(s, cal)
    c_head = s.geometry.sound_speed_m_s[test][:, None]
    measured = s.two_way_time_s[test] * c_head / 2.0
    render = render_pings_over(s, floor, test, n_samples)
    model = _interp_beams(render.angle_deg, render.range_m, s.angle_deg[test])
    cal_range = s.two_way_time_s[cal] * s.geometry.sound_speed_m_s[cal][:, None] / 2.0
    per_beam = np.nanmean(cal_range, axis=0)[None, :]
    depth = float(np.nanmedian(-world_points(s, cal)[..., 2]))
    level = depth / np.cos(np.radians(s.angle_deg[test]))
    cells = np.isfinite(measured) & np.isfinite(model)
    med = lambda a: float(np.median(np.abs(a[cells] - measured[cells])))  # noqa: E731

    # backscatter: the angular response fitted on the calibration pings, read at the render's incidence
    heads = np.column_stack([np.nan_to_num(s.geometry.x_m), np.nan_to_num(s.geometry.y_m),
                             np.nan_to_num(s.geometry.heave_m)])
    with np.errstate(divide="ignore"):
        db = 20.0 * np.log10(np.where(s.intensity > 0, s.intensity, np.nan))  # micropascal: an amplitude
    # (the angular response from at most about 50 of the calibration pings: 256 beams each)
    cal_bs = cal[:: max(1, len(cal) // 50)]
    cal_render = render_pings_over(s, floor, cal_bs, n_samples)
    cal_inc = _interp_beams(cal_render.angle_deg, _incidence_deg(cal_render, floor, heads[cal_bs]), s.angle_deg[cal_bs])
    test_inc = _interp_beams(render.angle_deg, _incidence_deg(render, floor, heads[test]), s.angle_deg[test])
    ok = np.isfinite(cal_inc) & np.isfinite(db[cal_bs])
    knots = INCIDENCE_KNOTS_DEG
    # piecewise-linear in incidence: hat functions on the knots, least squares
    def basis(x):
        return np.clip(1.0 - np.abs(x[:, None] - knots[None, :]) / (knots[1] - knots[0]), 0.0, None)
    # ... plus each beam's own gain (the head's per-beam calibration): one least squares over
    # the knots' values and the beams' offsets (their mean held at 0: the knots carry the level)
    beam = np.broadcast_to(np.arange(s.n_beams), cal_inc.shape)[ok]
    one_hot = np.zeros((ok.sum(), s.n_beams))
    one_hot[np.arange(ok.sum()), beam] = 1.0
    A = np.vstack([np.hstack([basis(cal_inc[ok]), one_hot]),
                   np.hstack([np.zeros((1, len(knots))), np.ones((1, s.n_beams))])])
    y = np.concatenate([db[cal_bs][ok], [0.0]])
    sol = np.linalg.lstsq(A, y, rcond=None)[0]
    coef, offsets = sol[: len(knots)], sol[len(knots):]
    bs_cells = np.isfinite(test_inc) & np.isfinite(db[test])
    bs_model = np.full(test_inc.shape, np.nan)
    beams_test = np.broadcast_to(np.arange(s.n_beams), test_inc.shape)
    bs_model[bs_cells] = basis(test_inc[bs_cells]) @ coef + offsets[beams_test[bs_cells]]
    bs_per_beam = np.nanmean(db[cal], axis=0)[None, :]
    # what speckle leaves predictable: each test ping's beam by its neighbouring pings' (dB mean)
    neighbours = np.full(db.shape, np.nan)
    neighbours[1:-1] = (db[:-2] + db[2:]) / 2.0
    neighbours = neighbours[test]
    bs_cells &= np.isfinite(neighbours)
    rms = lambda a: float(np.sqrt(np.nanmean((a - db[test])[bs_cells] ** 2)))  # noqa: E731
    tilt = np.degrees(np.arctan(floor[1:]))

    # The angular response. The recorded per-beam values hold the footprint each beam
    # insonifies (beam- then pulse-limited: it shrinks away from nadir) as well as the bed's
    # backscatter; the render over a Lambert floor holds the same footprint times the known
    # mu cos^2, so that footprint (dB) = render - 10 log10(mu cos^2(incidence)), beam by beam,
    # and the bed's own response is the recording less it. The sediment law (class and level)
    # is fitted to the calibration pings' bed response and predicts the test pings' values as
    # their footprint plus the law, with and without each beam's gain (fitted on the
    # calibration pings' residuals, as the knots' model has it).
    c_water = float(np.nanmedian(s.geometry.sound_speed_m_s))

    def footprint_db(rendered, incidence, pings):
        with np.errstate(divide="ignore", invalid="ignore"):
            rdb = 10.0 * np.log10(np.where(rendered.intensity > 0, rendered.intensity, np.nan))
            law = 10.0 * np.log10(FLOOR_MU * np.cos(np.radians(incidence)) ** 2)
        return _interp_beams(rendered.angle_deg, rdb, s.angle_deg[pings]) - law

    cal_foot = footprint_db(cal_render, cal_inc, cal_bs)
    test_foot = footprint_db(render, test_inc, test)
    centres, cal_bed, cal_n = angular_response(cal_inc, db[cal_bs] - cal_foot)
    fit = fit_sediment(centres, cal_bed, FREQUENCY_HZ, c_water, weights=cal_n)
    cal_pred = cal_foot + sediment_response_db(cal_inc, fit, FREQUENCY_HZ, c_water)
    residual = db[cal_bs] - cal_pred
    gains = np.nan_to_num(np.nanmean(np.where(np.isfinite(residual), residual, np.nan), axis=0)) \
        if np.isfinite(residual).any() else np.zeros(s.n_beams)
    test_pred = test_foot + sediment_response_db(test_inc, fit, FREQUENCY_HZ, c_water)
    _, test_resp, test_n = angular_response(test_inc, db[test])
    _, cal_resp, _ = angular_response(cal_inc, db[cal_bs])
    _, sediment_resp, _ = angular_response(test_inc, test_pred)
    _, gained_resp, _ = angular_response(test_inc, test_pred + gains[None, :])
    _, per_beam_resp, _ = angular_response(test_inc, np.broadcast_to(bs_per_beam, test_inc.shape))
    _, knots_resp, _ = angular_response(test_inc, bs_model)
    # trivial beds over the same footprint, each level fitted on the calibration pings: a flat
    # bed (no angular law at all) and Lambert's mu cos^2
    with np.errstate(divide="ignore", invalid="ignore"):
        lambert_cal = 10.0 * np.log10(np.cos(np.radians(cal_inc)) ** 2)
        lambert_test = 10.0 * np.log10(np.cos(np.radians(test_inc)) ** 2)
    flat_level = float(np.nanmean(db[cal_bs] - cal_foot))
    lambert_level = float(np.nanmean(db[cal_bs] - cal_foot - lambert_cal))
    _, flat_bed_resp, _ = angular_response(test_inc, test_foot + flat_level)
    _, lambert_resp, _ = angular_response(test_inc, test_foot + lambert_test + lambert_level)
    both = np.isfinite(test_resp) & np.isfinite(cal_resp) & np.isfinite(sediment_resp)

    def resp_rms(pred):
        return float(np.sqrt(np.average((pred[both] - test_resp[both]) ** 2, weights=test_n[both])))
    return {
        "floor": {"depth_m": depth, "tilt_east_deg": float(tilt[0]), "tilt_north_deg": float(tilt[1])},
        "range_m": {"model": med(model), "calibration_mean_per_beam": med(np.broadcast_to(per_beam, measured.shape)),
                    "level_floor": med(level), "cells": int(cells.sum())},
        "backscatter_db": {"model": rms(bs_model), "calibration_mean_per_beam": rms(np.broadcast_to(bs_per_beam, db[test].shape)),
                           "ceiling_neighbours": rms(neighbours), "cells": int(bs_cells.sum())},
        "angular_response_db": {
            "sediment": resp_rms(sediment_resp), "sediment_with_beam_gains": resp_rms(gained_resp),
            "calibration_mean_per_beam": resp_rms(per_beam_resp), "footprint_flat_bed": resp_rms(flat_bed_resp),
            "footprint_lambert": resp_rms(lambert_resp),
            "knots_with_beam_gains": resp_rms(knots_resp), "ceiling_calibration_response": resp_rms(cal_resp),
            "flat": resp_rms(np.full(centres.shape, np.average(cal_resp[both], weights=cal_n[both]))),
            "bins": int(both.sum()), "incidence_deg": [float(centres[both].min()), float(centres[both].max())],
            # how far a beam's incidence moves over the test pings (median over beams of its
            # standard deviation): where the head holds its beams' angles against the roll, as
            # the R2Sonic does, a beam keeps its incidence and the per-beam mean is the bed's
            # response at it; only other attitudes or heights would tell a law from it
            "incidence_spread_per_beam_deg": _spread_per_beam(test_inc),
            "fit": fit,
        },
        "calibration_pings": [int(cal.min()), int(cal.max())], "test_pings": [int(test.min()), int(test.max())],
    }
