"""Image formation (paper Eq. 3-6 and Algorithm 1): per-ray intensities into a polar image.

Two ways to put a ray's energy into range bins:

* ``splat=False`` -- the paper's Algorithm 1: ray k adds its intensity ``I_f[k]`` to the bin of
  its range ``D_f[k]``. Surfaces seen at grazing angles (the floor) then show empty bins
  (stripes) wherever neighbouring rays land more than a bin apart.
* ``splat=True`` (default) -- ray k stands for the elevation cell ``[phi_k - dphi/2,
  phi_k + dphi/2]``, and its energy is spread uniformly over the range interval that cell covers
  on the surface: from the midpoint towards one neighbouring ray to the midpoint towards the
  other, where the neighbour lies on the same continuous surface; mirrored from the other side
  where it does not; the ray's own bin for an isolated ray. The interval always includes the
  ray's own range (so a range minimum, e.g. the nearest point of a sphere, is kept). This
  integrates Eq. 3 with a piecewise-linear range map r(phi): it conserves every ray's energy
  exactly and leaves no stripes at any ray density.

Spreading expands each (half-)segment into the bins it overlaps (``np.repeat``) and adds
``density x overlap`` with one ``np.bincount`` for all images of a frame: exact, with work
proportional to the bins actually touched, and no Python loop per ray or per bin.

Both the path search (:mod:`sonarsim.paths`, which splats the echoes it finds) and the renderer
use this; it imports nothing but NumPy, so it lives here, at the bottom, and
:mod:`sonarsim.renderer.formation` re-exports every name, where it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Neighbouring hits are on one continuous surface when the chord between them is within this
# angle (sine) of both hits' tangent planes: 30 degrees passes the facets of a tessellated
# sphere or cylinder and rejects a box edge (90 degrees), a step, or a jump to another surface.
CONTINUITY_SINE = 0.5

# Half-segments shorter than this (in bins) are deposited as points, in the bin of their start.
MIN_SPREAD_BINS = 1e-6


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
    # Rays without a hit have NaN or far-away (float32 max) points: their chords are NaN or
    # overflow to inf, and compare False below, as they should.
    with np.errstate(invalid="ignore", over="ignore"):
        chord = points[..., 1:, :] - points[..., :-1, :]
        length = np.sqrt(np.einsum("...k,...k->...", chord, chord))
        off0 = np.abs(np.einsum("...k,...k->...", chord, normals[..., :-1, :]))
        off1 = np.abs(np.einsum("...k,...k->...", chord, normals[..., 1:, :]))
        limit = CONTINUITY_SINE * length
        same = (surface_id[..., 1:] == surface_id[..., :-1]) & (surface_id[..., 1:] >= 0)
        return same & (off0 <= limit) & (off1 <= limit)


@dataclass(frozen=True)
class RayEnergy:
    """Energy arriving along a set of rays, for :func:`accumulate`.

    Attributes
    ----------
    distance_m : (..., n) float array
        Range at which each ray's energy arrives, metres; non-finite: no energy.
    intensity : (..., n) float array
        Energy of each ray.
    beam_index : int array broadcastable to ``distance_m``
        Column of each ray, e.g. shape ``(n_beams, 1, 1)`` for rays shaped
        ``(n_beams, n_azimuth_samples, n_elevation_samples)``.
    label : int or int array broadcastable to ``distance_m``
        Which image (component) receives the energy; negative: dropped.
    continuous : (..., n - 1) bool array or None
        Neighbour continuity along the last axis (see :func:`continuity`). Given: spread each
        ray over its range interval (no stripes); ``None``: Algorithm 1, one bin per ray.
    """

    distance_m: np.ndarray
    intensity: np.ndarray
    beam_index: np.ndarray | int
    label: np.ndarray | int = 0
    continuous: np.ndarray | None = None


def _segments(rays: RayEnergy, range_min_m: float, dr: float, n_range_bins: int, n_beams: int):
    """(lo, hi, density, column) of every ray's range cell, flat, lo/hi in fractional bins.

    Rays without energy get an empty cell (lo == hi); isolated rays the cell of their own bin.
    ``column`` is ``label * n_range_bins * n_beams + beam``.
    """
    x = (np.asarray(rays.distance_m, dtype=float) - range_min_m) / dr
    energy = np.asarray(rays.intensity, dtype=float)
    label = np.broadcast_to(np.asarray(rays.label, dtype=np.int64), x.shape)
    live = np.isfinite(x) & (energy != 0) & (label >= 0)
    x = np.where(live, x, 0.0)  # finite everywhere: dead rays get empty cells below
    column = np.maximum(label, 0) * (n_range_bins * n_beams) + np.asarray(rays.beam_index, dtype=np.int64)
    column = np.broadcast_to(column, x.shape)
    if rays.continuous is None:
        lo = hi = x
    else:
        # A ray without energy (dropped, out of the field of view) is no neighbour to spread to.
        cont = rays.continuous & live[..., 1:] & live[..., :-1]
        edge = np.zeros(x.shape[:-1] + (1,))
        no = np.zeros(x.shape[:-1] + (1,), dtype=bool)
        mid = 0.5 * (x[..., 1:] + x[..., :-1])
        m_dn, c_dn = np.concatenate([edge, mid], axis=-1), np.concatenate([no, cont], axis=-1)
        m_up, c_up = np.concatenate([mid, edge], axis=-1), np.concatenate([cont, no], axis=-1)
        lower = np.where(c_dn, m_dn, np.where(c_up, 2.0 * x - m_up, x))
        upper = np.where(c_up, m_up, np.where(c_dn, 2.0 * x - m_dn, x))
        lo = np.minimum(np.minimum(lower, upper), x)
        hi = np.maximum(np.maximum(lower, upper), x)
    width = hi - lo
    point = width < MIN_SPREAD_BINS
    # A point is the unit cell of its bin with density = its energy.
    lo = np.where(point, np.floor(lo), lo)
    hi = np.where(point, lo + 1.0, hi)
    density = np.where(live, energy / np.where(point, 1.0, width), 0.0)
    hi = np.where(live, hi, lo)
    return lo.ravel(), hi.ravel(), density.ravel(), column.ravel()


def accumulate(
    rays: "list[RayEnergy] | tuple[RayEnergy, ...]",
    range_min_m: float,
    range_resolution_m: float,
    n_range_bins: int,
    n_beams: int,
    n_labels: int = 1,
) -> np.ndarray:
    """Accumulate ray energies into polar images (paper Algorithm 1, vectorised, with splatting).

    Parameters
    ----------
    rays : sequence of RayEnergy
        Every set of rays of the frame; all go through one ``np.bincount``.
    range_min_m, range_resolution_m : float
        Start of the range window and bin width, metres.
    n_range_bins, n_beams : int
        Image shape.
    n_labels : int
        Number of images (labels ``0 .. n_labels - 1``).

    Returns
    -------
    (n_labels, n_range_bins, n_beams) float64 ndarray
    """
    parts = [_segments(r, range_min_m, range_resolution_m, n_range_bins, n_beams) for r in rays]
    lo, hi, density, column = (np.concatenate(p) for p in zip(*parts))
    owner, bins, overlap = expand_cells(lo, hi, n_range_bins)
    index = column[owner] + bins * n_beams
    shape = (n_labels, n_range_bins, n_beams)
    return np.bincount(index, weights=density[owner] * overlap, minlength=np.prod(shape)).reshape(shape)


def expand_cells(lo: np.ndarray, hi: np.ndarray, n_range_bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Expand range cells into the bins they overlap, clipped to the window.

    Parameters
    ----------
    lo, hi : (m,) float arrays
        Cells in fractional bins (``lo <= hi``); an empty cell, or one outside
        ``[0, n_range_bins)``, expands to nothing (the energy outside the window is lost, as
        it should be).
    n_range_bins : int

    Returns
    -------
    owner : (t,) intp ndarray
        The cell of each expanded slot, ascending.
    bins : (t,) intp ndarray
        Its range bin.
    overlap : (t,) float64 ndarray
        Length of the cell inside the bin, in bins.
    """
    lo = np.clip(lo, 0.0, n_range_bins)
    hi = np.clip(hi, 0.0, n_range_bins)
    live = np.flatnonzero(hi > lo)
    lo, hi = lo[live], hi[live]
    first = np.floor(lo)
    count = (np.ceil(hi) - first).astype(np.intp)
    start = np.cumsum(count) - count
    total = int(start[-1] + count[-1]) if len(count) else 0
    # owner[t]: the cell that expanded bin slot t (a cumulative sum of cell starts; np.repeat
    # is several times slower for this).
    marks = np.zeros(total, dtype=np.intp)
    marks[start[1:]] = 1
    owner = np.cumsum(marks)
    bins = first[owner] + (np.arange(total) - start[owner])
    overlap = np.minimum(hi[owner], bins + 1.0) - np.maximum(lo[owner], bins)
    return live[owner], bins.astype(np.intp), overlap


def range_cells(rays: RayEnergy, range_min_m: float, range_resolution_m: float, n_range_bins: int,
                n_beams: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The range cell each ray's energy covers, as :func:`accumulate` spreads it.

    Returns
    -------
    lo, hi : (n,) float64 ndarray
        The cell in fractional bins, flat over the rays (``lo == hi``: no energy).
    density : (n,) float64 ndarray
        Energy per bin.
    column : (n,) int64 ndarray
        ``label * n_range_bins * n_beams + beam``.
    """
    return _segments(rays, range_min_m, range_resolution_m, n_range_bins, n_beams)


def form_image(
    distance_m: np.ndarray,
    intensity: np.ndarray,
    beam_index: np.ndarray,
    range_min_m: float,
    range_resolution_m: float,
    n_range_bins: int,
    n_beams: int,
    label: np.ndarray | int = 0,
    n_labels: int = 1,
    continuous: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`accumulate` for one set of rays (see :class:`RayEnergy` for the arguments).

    Returns
    -------
    (n_labels, n_range_bins, n_beams) float64 ndarray
    """
    rays = RayEnergy(distance_m, intensity, beam_index, label, continuous)
    return accumulate([rays], range_min_m, range_resolution_m, n_range_bins, n_beams, n_labels)
