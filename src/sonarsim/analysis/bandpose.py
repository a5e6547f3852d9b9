"""The pose of a sonar over a flat floor in closed form, from the edges of the floor band.

A ray leaving the sonar at azimuth ``theta`` and elevation ``e`` (sonar frame, DESIGN.md
section 1) has the unit direction ``d = (cos e cos theta, cos e sin theta, sin e)``. With the
sonar at height ``z`` above the floor and rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)``, its
downward component is ``u . d`` where ``u = -R[2, :] = (sin p, -cos p sin rho, -cos p cos rho)``
(``p`` the pitch, ``rho`` the roll; yaw does not matter over a flat floor), and it meets the
floor at the range ``r = z / (u . d)``. The lowest ray of an elevation aperture of half-angle
``h`` (``e = -h``) draws the band's near edge, the highest (``e = +h``) its far edge:

    1 / r_near = a cos(theta) + c sin(theta) + b,     1 / r_far = a cos(theta) + c sin(theta) - b,

    a = cos h sin p / z,   c = -cos h cos p sin rho / z,   b = sin h cos p cos rho / z.

Both edges across the fan give ``(a, c, b)`` by linear least squares (:func:`fit_band_lines`);
the pose then follows for any half-angle ``h`` (:func:`pose_for_half_angle`): three numbers
from four unknowns. Height, pitch and elevation width trade off along a curve that one flat
floor cannot resolve (DESIGN.md section 10); :func:`band_family` walks it. With the near edge
alone, ``b`` and ``a`` are hardly separable over a narrow fan, so the height is taken as given
(:func:`pose_from_near_edge`).

The edges a band detector finds are where the two-way pattern has fallen by a few dB, not at a
nominal aperture: ``h`` is the half-angle of those edges, about half the pattern's -3 dB width.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BandLines", "band_family", "fit_band_lines", "pose_for_half_angle", "pose_from_near_edge"]

#: Fewest beams with an edge for a fit: three unknowns, and outliers to reject.
MIN_EDGES = 6

#: Most fits made while rejecting outlying edges.
REJECT_PASSES = 5


@dataclass(frozen=True)
class BandLines:
    """The floor band's edges as ``1 / r = a cos(theta) + c sin(theta) +- b``.

    Attributes
    ----------
    a, c, b : float
        Coefficients, 1/m (``b`` is nan when no far edge was used).
    near_axis : float
        ``1 / r_near`` on the axis (``a + b``), 1/m: well determined even from the near edge
        alone, where ``a`` and ``b`` are not.
    rms_m : float
        RMS of the fitted edges' residuals, in metres of range.
    n_near, n_far : int
        Beams whose near (far) edge entered the fit after outliers were rejected.
    """

    a: float
    c: float
    b: float
    near_axis: float
    rms_m: float
    n_near: int
    n_far: int

    @property
    def both_edges(self) -> bool:
        """Whether the far edge was used (the pose family is then determined)."""
        return self.n_far >= MIN_EDGES // 2 and math.isfinite(self.b) and self.b > 0


def _lstsq(rows: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    return np.linalg.lstsq(rows, rhs, rcond=None)[0]


def fit_band_lines(azimuth_deg, near_m, far_m=None, reject: float = 3.0) -> BandLines:
    """Fit the band-edge model to per-beam edge ranges.

    Parameters
    ----------
    azimuth_deg : (n_beams,) array-like
        Beam centres, degrees (positive to the sonar's left).
    near_m, far_m : (n_beams,) array-like
        The band's near and far edge in each beam, metres; NaN where a beam has none.
        ``far_m`` may be omitted (the near edge alone: ``b`` is then fitted from it).
    reject : float
        Edges whose residual exceeds this many robust standard deviations (1.4826 x the median
        absolute residual of the near, or the far, edges, at least a millimetre) are left out and the fit repeated (at most
        :data:`REJECT_PASSES` fits).

    Returns
    -------
    BandLines

    Raises
    ------
    ValueError
        Fewer than :data:`MIN_EDGES` usable near edges.
    """
    th = np.radians(np.asarray(azimuth_deg, dtype=float))
    near = np.asarray(near_m, dtype=float)
    far = np.full_like(near, np.nan) if far_m is None else np.asarray(far_m, dtype=float)
    if th.shape != near.shape or far.shape != near.shape:
        raise ValueError(f"azimuth_deg, near_m and far_m must have one value per beam, got {th.shape}, "
                         f"{near.shape} and {far.shape}")
    ok_n = np.isfinite(near) & (near > 0)
    ok_f = np.isfinite(far) & (far > 0)
    if ok_n.sum() < MIN_EDGES:
        raise ValueError(f"{int(ok_n.sum())} beams have a near edge; the fit needs {MIN_EDGES}")
    use_far = ok_f.sum() >= MIN_EDGES // 2
    for _ in range(REJECT_PASSES):
        rows, rhs, ranges = [], [], []
        for ok, sign, r in ((ok_n, 1.0, near), (ok_f if use_far else ok_f & False, -1.0, far)):
            k = np.flatnonzero(ok)
            rows.append(np.column_stack([np.cos(th[k]), np.sin(th[k]), np.full(len(k), sign)]))
            rhs.append(1.0 / r[k])
            ranges.append(r[k])
        a_rows, b_rhs, rr = np.vstack(rows), np.concatenate(rhs), np.concatenate(ranges)
        coef = _lstsq(a_rows, b_rhs)
        # Residuals in metres: d(1/r) = -dr / r^2.
        pred = a_rows @ coef
        with np.errstate(divide="ignore", invalid="ignore"):
            resid_m = np.where(pred > 0, 1.0 / pred - rr, np.inf)
        # Each edge against its own spread: a far edge is blurrier than a near one (it is
        # drawn by the pattern's weak upper side), and one scale would reject all of it.
        n_n = int(ok_n.sum())
        bad = np.zeros(len(resid_m), dtype=bool)
        for part in (slice(0, n_n), slice(n_n, len(resid_m))):
            rp = resid_m[part]
            if not len(rp):
                continue
            fin = np.isfinite(rp)
            scale = max(1.4826 * float(np.median(np.abs(rp[fin]))), 1e-3) if fin.any() else 1e-3
            bad[part] = ~(np.abs(rp) <= reject * scale)
        if not bad.any():
            break
        ok_n = ok_n.copy()
        ok_f = ok_f.copy()
        ok_n[np.flatnonzero(ok_n)[bad[:n_n]]] = False
        if use_far:
            ok_f[np.flatnonzero(ok_f)[bad[n_n:]]] = False
        if ok_n.sum() < MIN_EDGES:
            raise ValueError("too few near edges agree on one floor")
        use_far = ok_f.sum() >= MIN_EDGES // 2
    fin = np.isfinite(resid_m)
    rms = float(np.sqrt(np.mean(resid_m[fin] ** 2))) if fin.any() else float("nan")
    return BandLines(float(coef[0]), float(coef[1]), float(coef[2]) if use_far else float("nan"),
                     float(coef[0] + coef[2]), rms,
                     int(ok_n.sum()), int(ok_f.sum()) if use_far else 0)


def pose_for_half_angle(lines: BandLines, half_angle_deg: float) -> tuple[float, float, float]:
    """The height, pitch and roll for which edges at elevations ``-h`` and ``+h`` are ``lines``.

    Parameters
    ----------
    lines : BandLines
        With both edges (:attr:`BandLines.both_edges`).
    half_angle_deg : float
        ``h``, degrees, in (0, 90).

    Returns
    -------
    (z_m, pitch_deg, roll_deg) : tuple of float
        Height above the floor, and the pose's pitch (positive down) and roll.
    """
    if not lines.both_edges:
        raise ValueError("the band's far edge was not found: the pose family needs both edges")
    h = math.radians(half_angle_deg)
    if not 0.0 < h < math.pi / 2:
        raise ValueError(f"half_angle_deg must be in (0, 90), got {half_angle_deg}")
    vx, vy, vz = lines.a / math.cos(h), lines.c / math.cos(h), lines.b / math.sin(h)
    z = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, vx * z))))
    roll = math.degrees(math.atan2(-vy, vz))
    return z, pitch, roll


def pose_from_near_edge(lines: BandLines, z_m: float, half_angle_deg: float) -> tuple[float, float, float]:
    """Pitch and roll from the near edge alone, the height given.

    ``1 / r_near = (sin p cos h + cos p cos rho sin h) / z`` on the axis; the roll from the
    ``sin(theta)`` term. Used where the far edge lies beyond the range window (a floor seen at
    a grazing angle).

    Returns
    -------
    (z_m, pitch_deg, roll_deg) : tuple of float
    """
    h = math.radians(half_angle_deg)
    # On the axis, 1/r_near = (sin p cos h + cos p cos rho sin h) / z = sin(p + h) / z for a
    # small roll; across the fan, c = -cos h cos p sin rho / z.
    pitch = math.degrees(math.asin(max(-1.0, min(1.0, z_m * lines.near_axis)))) - half_angle_deg
    cp = math.cos(math.radians(pitch))
    roll = math.degrees(math.asin(max(-1.0, min(1.0, -lines.c * z_m / (math.cos(h) * cp))))) if cp > 0 else 0.0
    return z_m, pitch, roll


def band_family(lines: BandLines, half_angles_deg) -> list[dict[str, float]]:
    """The poses along the family that one floor band allows, one per half-angle.

    Parameters
    ----------
    lines : BandLines
    half_angles_deg : sequence of float
        Half-angles ``h`` of the band's edges, degrees.

    Returns
    -------
    list of dict with ``half_angle_deg``, ``z``, ``pitch``, ``roll`` (metres, degrees)
    """
    out = []
    for h in half_angles_deg:
        z, p, r = pose_for_half_angle(lines, float(h))
        out.append({"half_angle_deg": float(h), "z": z, "pitch": p, "roll": r})
    return out
