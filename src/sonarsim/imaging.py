"""Image formation (paper Eq. 3-6 and Algorithm 1): per-ray intensities into a polar image.

Two ways to put a ray's energy into range bins:

* ``splat=False`` -- the paper's Algorithm 1: ray k adds its intensity ``I_f[k]`` to the bin of
  its range ``D_f[k]``. Surfaces seen at grazing angles (the floor) then show empty bins
  (stripes) wherever neighbouring rays land more than a bin apart.
* ``splat=True`` (default) -- ray k stands for the elevation interval ``[phi_k - dphi/2,
  phi_k + dphi/2]``. Each half of it is spread uniformly over the range interval it covers on
  the surface: up to the midpoint towards the neighbouring ray when both rays lie on one
  continuous surface, else extrapolated from the other neighbour, else (an isolated ray) put at
  the ray's own range. This integrates Eq. 3 with a piecewise-linear range map r(phi): it
  conserves every ray's energy exactly and leaves no stripes at any ray density.

Spreading is done with a first-difference trick so that it stays one ``np.bincount`` plus one
``cumsum`` per image, whatever the number of bins a segment covers: a uniform density ``c`` from
fractional bin position ``a`` upwards adds ``c * clip(i + 1 - a, 0, 1)`` to bin ``i``, whose first
difference is ``c * (1 - frac(a))`` at ``floor(a)`` and ``c * frac(a)`` at ``floor(a) + 1``.
"""

from __future__ import annotations

import numpy as np

# Neighbouring hits are on one continuous surface when the chord between them is within this
# angle (sine) of both hits' tangent planes: 30 degrees passes the facets of a tessellated
# sphere or cylinder and rejects a box edge (90 degrees), a step, or a jump to another surface.
CONTINUITY_SINE = 0.5

# Half-segments shorter than this (in bins) are deposited as points: no precision lost, and the
# spread densities stay bounded.
MIN_SPREAD_BINS = 1e-3


def lambertian_intensity(
    weight: np.ndarray,
    cos_incidence: np.ndarray,
    albedo: np.ndarray,
    distance_m: np.ndarray,
    tvg: bool,
) -> np.ndarray:
    """Per-ray backscatter ``beta * l(r) * rho * cos(alpha) * dphi`` (paper Eq. 3-6).

    Parameters
    ----------
    weight : (...) float array
        Ray weight ``beta(theta, phi) * dphi`` (radians), see :class:`sonarsim.rays.RayFan`.
    cos_incidence : (...) float array
        cos of the angle between the ray and the surface normal, in [0, 1].
    albedo : (...) float array
        Diffuse albedo rho of the surface hit (0 where nothing is hit).
    distance_m : (...) float array
        Range of the hit, metres (``inf`` where nothing is hit).
    tvg : bool
        ``True``: ``l(r) = 1``; ``False``: ``l(r) = 1 / r**2``.

    Returns
    -------
    (...) float64 ndarray: the intensity map I_f (0 where nothing is hit).
    """
    hit = np.isfinite(distance_m)
    out = np.where(hit, weight * albedo * cos_incidence, 0.0)
    if not tvg:
        r = np.where(hit, distance_m, 1.0)
        out = out / np.maximum(r, 1e-6) ** 2
    return out


def continuity(points: np.ndarray, normals: np.ndarray, surface_id: np.ndarray) -> np.ndarray:
    """Whether neighbouring rays along the last ray axis hit one continuous surface.

    Parameters
    ----------
    points : (..., n, 3) float array
        Hit points, metres.
    normals : (..., n, 3) float array
        Unit surface normals at the hits (either orientation).
    surface_id : (..., n) int array
        Which surface each ray hit, -1 for none.

    Returns
    -------
    (..., n - 1) bool ndarray: entry k is True when rays k and k+1 are on one surface.
    """
    chord = points[..., 1:, :] - points[..., :-1, :]
    length = np.linalg.norm(chord, axis=-1)
    off0 = np.abs(np.einsum("...k,...k->...", chord, normals[..., :-1, :]))
    off1 = np.abs(np.einsum("...k,...k->...", chord, normals[..., 1:, :]))
    limit = CONTINUITY_SINE * length
    same = (surface_id[..., 1:] == surface_id[..., :-1]) & (surface_id[..., 1:] >= 0)
    with np.errstate(invalid="ignore"):
        return same & (off0 <= limit) & (off1 <= limit)


def _half_segment_ends(x: np.ndarray, cont: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Far ends (in bins) of each ray's lower and upper half-interval; NaN means 'a point'."""
    nan = np.full(x.shape[:-1] + (1,), np.nan)
    nxt = np.concatenate([x[..., 1:], nan], axis=-1)
    prv = np.concatenate([nan, x[..., :-1]], axis=-1)
    false = np.zeros(x.shape[:-1] + (1,), dtype=bool)
    c_up = np.concatenate([cont, false], axis=-1)  # ray k continues to k+1
    c_dn = np.concatenate([false, cont], axis=-1)  # ray k continues to k-1
    with np.errstate(invalid="ignore"):  # inf - inf where rays miss: masked out below
        up_interp = 0.5 * (x + nxt)
        dn_interp = 0.5 * (x + prv)
        up_extra = x + 0.5 * (x - prv)  # mirror of the lower neighbour
        dn_extra = x + 0.5 * (x - nxt)
        upper = np.where(c_up, up_interp, np.where(c_dn, up_extra, np.nan))
        lower = np.where(c_dn, dn_interp, np.where(c_up, dn_extra, np.nan))
    return lower, upper


def form_image(
    distance_m: np.ndarray,
    intensity: np.ndarray,
    beam_index: np.ndarray,
    range_min_m: float,
    range_resolution_m: float,
    n_range_bins: int,
    n_beams: int,
    label: np.ndarray | None = None,
    n_labels: int = 1,
    continuous: np.ndarray | None = None,
) -> np.ndarray:
    """Accumulate per-ray intensities into polar images (paper Algorithm 1, vectorised).

    Parameters
    ----------
    distance_m : (..., n) float array
        Range at which each ray's energy arrives, metres (D_f); non-finite: no energy.
    intensity : (..., n) float array
        Energy of each ray (I_f).
    beam_index : int array broadcastable to ``distance_m``
        Column of each ray, e.g. shape ``(n_beams, 1, 1)`` for rays shaped
        ``(n_beams, n_azimuth_samples, n_elevation_samples)``.
    range_min_m, range_resolution_m : float
        Start of the range window and bin width, metres.
    n_range_bins, n_beams : int
        Image shape.
    label : (..., n) int array, optional
        Image (component) index of each ray in ``[0, n_labels)``; default all 0. Rays with a
        negative label are dropped.
    n_labels : int
        Number of images to form.
    continuous : (..., n - 1) bool array, optional
        Neighbour continuity along the last axis (see :func:`continuity`). Given: spread each
        ray over its range interval (no stripes); ``None``: Algorithm 1, one bin per ray.

    Returns
    -------
    (n_labels, n_range_bins, n_beams) float64 ndarray
    """
    x = (np.asarray(distance_m, dtype=float) - range_min_m) / range_resolution_m
    energy = np.asarray(intensity, dtype=float)
    beams = np.broadcast_to(np.asarray(beam_index, dtype=np.int64), x.shape)
    lab = np.zeros(x.shape, dtype=np.int64) if label is None else np.asarray(label, dtype=np.int64)
    live = np.isfinite(x) & (energy != 0) & (lab >= 0)
    n_rows = n_range_bins + 1  # one spare row so that floor(a) + 1 never needs clipping away
    size = n_labels * n_rows * n_beams
    base = (lab * n_rows) * n_beams + beams  # flat index of row 0 of the ray's column

    def flat(rows: np.ndarray, sel: np.ndarray) -> np.ndarray:
        return base[sel] + rows * n_beams

    if continuous is None:
        sel = live & (x >= 0) & (x < n_range_bins)
        rows = np.floor(x[sel]).astype(np.int64)
        img = np.bincount(flat(rows, sel), weights=energy[sel], minlength=size)
        return img.reshape(n_labels, n_rows, n_beams)[:, :n_range_bins]

    # A ray without energy (dropped, out of the field of view) is no neighbour to spread towards.
    continuous = continuous & live[..., 1:] & live[..., :-1]
    lower, upper = _half_segment_ends(x, continuous)
    half = 0.5 * energy
    direct = np.zeros(size)
    ramp = np.zeros(size)
    for end in (lower, upper):
        width = np.abs(end - x)
        spread = live & np.isfinite(end) & (width >= MIN_SPREAD_BINS)
        point = live & ~spread
        # Points (isolated rays, or negligible spans): the bin of the ray's own range.
        px = np.where(np.isfinite(end), 0.5 * (x + end), x)[point]
        ok = (px >= 0) & (px < n_range_bins)
        psel = np.flatnonzero(point)[ok]
        rows = np.floor(px[ok]).astype(np.int64)
        direct += np.bincount(base.ravel()[psel] + rows * n_beams, weights=half.ravel()[psel], minlength=size)
        # Spread: density c = E / width on [lo, hi): +c hinge at lo, -c hinge at hi.
        lo = np.minimum(x, end)[spread]
        hi = np.maximum(x, end)[spread]
        c = half[spread] / (hi - lo)
        b = base[spread]
        idx, wts = [], []
        for pos, coef in ((lo, c), (hi, -c)):
            fl = np.floor(pos)
            fr = pos - fl
            row = np.clip(fl, -1, n_range_bins).astype(np.int64)
            # Positions before the window fold into row 0 (a cumulative sum starts there);
            # positions past it land in the spare row and are discarded.
            r0 = np.clip(row, 0, n_range_bins)
            r1 = np.clip(row + 1, 0, n_range_bins)
            idx += [b + r0 * n_beams, b + r1 * n_beams]
            wts += [coef * (1.0 - fr), coef * fr]
        ramp += np.bincount(np.concatenate(idx), weights=np.concatenate(wts), minlength=size)
    img = np.cumsum(ramp.reshape(n_labels, n_rows, n_beams), axis=1)
    img += direct.reshape(n_labels, n_rows, n_beams)
    img = img[:, :n_range_bins]
    # The cumulative sum leaves round-off (~1e-16 of the densities) where segments ended.
    total = np.abs(energy[live]).sum()
    img[np.abs(img) <= 1e-12 * total] = 0.0
    return img
