"""The polar grid of a sonar image: uniform range bins across, a beam table along.

A polar sonar image has shape ``(n_range_bins, n_beams)``. Row ``i`` is the range bin
``[range_min_m + i*dr, range_min_m + (i+1)*dr)`` with ``dr = (range_max_m - range_min_m) /
n_range_bins``; column ``j`` is the beam centred at azimuth ``beam_angles_deg[j]``, LEFT-most
(port) beam first, so the table strictly descends (positive azimuth = the sonar's left). Beams
may be unevenly spaced (the lens tables of ARIS/DIDSON-type sonars); the edge between two beams
lies midway between their centres, and each outermost beam reaches half the spacing to its
only neighbour beyond its centre.

:class:`PolarGrid` is the one place this geometry is computed: the sonar
(:attr:`sonarsim.config.sonar.SonarConfig.grid`), the scan conversion
(:mod:`sonarsim.image.fan`) and the comparison of images (:mod:`sonarsim.analysis.comparison`)
all use it.

The grid is a data type of this layer: :mod:`sonarsim.config.sonar` builds its sonar's grid from
it, and this package imports nothing of :mod:`sonarsim.config`. What an image needs of the
sonar that made it is :class:`PolarSonar` (which ``SonarConfig`` satisfies).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

__all__ = ["PolarGrid", "PolarSonar", "beam_edges_deg", "sector_area_m2"]


def _check_count(value: object, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _check_ranges(range_min_m: float, range_max_m: float) -> tuple[float, float]:
    try:
        rmin = float(range_min_m)
        rmax = float(range_max_m)
    except (TypeError, ValueError):
        raise ValueError(
            f"range_min_m and range_max_m must be numbers, got {range_min_m!r}, {range_max_m!r}"
        ) from None
    if not (math.isfinite(rmin) and rmin >= 0.0):
        raise ValueError(f"range_min_m must be finite and >= 0, got {range_min_m!r}")
    if not (math.isfinite(rmax) and rmax > rmin):
        raise ValueError(
            f"range_max_m must be finite and > range_min_m ({rmin}), got {range_max_m!r}"
        )
    return rmin, rmax


def _check_azimuth(azimuth_deg: object) -> np.ndarray:
    try:
        az = np.asarray(azimuth_deg, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"azimuth_deg must be a 1-D sequence of numbers, got {type(azimuth_deg).__name__}"
        ) from None
    if az.ndim != 1 or az.size == 0:
        raise ValueError(f"azimuth_deg must be a non-empty 1-D array, got shape {az.shape}")
    if not np.all(np.isfinite(az)):
        raise ValueError("azimuth_deg must contain only finite values")
    if az.size > 1 and not np.all(np.diff(az) < 0):
        raise ValueError(
            "azimuth_deg must be strictly descending (column 0 is the left/port beam and "
            "positive azimuth is to the sonar's left); reverse both the table and the polar "
            "image columns if yours ascends"
        )
    return az


def _check_single_beam_width(az: np.ndarray, single_beam_width_deg: float | None) -> float | None:
    if az.size != 1:
        return None if single_beam_width_deg is None else float(single_beam_width_deg)
    if single_beam_width_deg is None:
        raise ValueError("single_beam_width_deg is required when azimuth_deg has a single beam")
    width = float(single_beam_width_deg)
    if not (math.isfinite(width) and width > 0.0):
        raise ValueError(
            f"single_beam_width_deg must be finite and > 0, got {single_beam_width_deg!r}"
        )
    return width


def beam_edges_deg(beam_angles_deg: np.ndarray, single_beam_width_deg: float = 1.0) -> np.ndarray:
    """Edges between beams, midway between centres; each outer edge half a spacing outside.

    Parameters
    ----------
    beam_angles_deg : array_like, shape (n_beams,)
        Beam centres, degrees, strictly descending (not checked here).
    single_beam_width_deg : float
        Full width of a lone beam, degrees (used only when ``n_beams == 1``).

    Returns
    -------
    np.ndarray, shape (n_beams + 1,), float64
        Degrees, descending: ``edges[j]`` and ``edges[j + 1]`` bound beam ``j``.
    """
    c = np.asarray(beam_angles_deg, dtype=np.float64).ravel()
    if c.size == 1:
        return np.array([c[0] + single_beam_width_deg / 2.0, c[0] - single_beam_width_deg / 2.0])
    mid = 0.5 * (c[:-1] + c[1:])
    left = c[0] + (c[0] - c[1]) / 2.0
    right = c[-1] - (c[-2] - c[-1]) / 2.0
    return np.concatenate([[left], mid, [right]])


def beam_index(beam_edges_deg: np.ndarray, azimuth_deg) -> np.ndarray:
    """Index of the beam whose edges contain each azimuth; -1 outside the fan.

    Parameters
    ----------
    beam_edges_deg : (n_beams + 1,) float array, degrees, descending (left-most beam first)
    azimuth_deg : float array, degrees (positive to the sonar's left)

    Returns
    -------
    int ndarray shaped like ``azimuth_deg``: ``j`` with ``edges[j] >= az > edges[j + 1]``.
    """
    e = np.asarray(beam_edges_deg, dtype=float)
    j = np.searchsorted(-e, -np.asarray(azimuth_deg, dtype=float), side="right") - 1
    return np.where((j >= 0) & (j < len(e) - 1), j, -1)


def beam_azimuth_deg(v: np.ndarray, cone: bool = False) -> np.ndarray:
    """The azimuth that picks a direction's beam, degrees: ``atan2(y, x)`` for plane beams; for
    a phased array's cone beams the angle of its direction cosine along the array,
    ``atan2(y, sqrt(x^2 + z^2))``, NaN behind the (baffled) array (the kernels' ``beam_in_view``).

    Parameters
    ----------
    v : (..., 3) float array
        Directions (or points) in the sonar frame.
    cone : bool

    Returns
    -------
    (...) float64 ndarray, degrees (NaN: in no beam).
    """
    v = np.asarray(v, dtype=np.float64)
    if not cone:
        return np.degrees(np.arctan2(v[..., 1], v[..., 0]))
    x = np.sqrt(v[..., 0] * v[..., 0] + v[..., 2] * v[..., 2])
    return np.where(v[..., 0] > 0.0, np.degrees(np.arctan2(v[..., 1], x)), np.nan)


def sector_area_m2(r0: float, r1: float, left_deg: float, right_deg: float) -> float:
    """Area of the annular sector ``[r0, r1] x [right_deg, left_deg]``, m^2 (0 if empty)."""
    if r1 <= r0 or left_deg <= right_deg:
        return 0.0
    return 0.5 * math.radians(left_deg - right_deg) * (r1 * r1 - r0 * r0)


@dataclass(frozen=True)
class PolarGrid:
    """Geometry of a polar sonar image: range bins and beams (validated, immutable, hashable).

    Parameters
    ----------
    range_min_m, range_max_m : float
        The range window, metres; ``0 <= range_min_m < range_max_m``.
    n_range_bins : int
        Number of range bins (rows), >= 1.
    beam_angles_deg : sequence of float, shape (n_beams,)
        Beam centre azimuths, degrees, left-most first (strictly descending; positive = left).
        Stored as a tuple.
    single_beam_width_deg : float, optional
        Full width of the beam, degrees, > 0; required when there is a single beam (there is
        no neighbour to take a spacing from), ignored otherwise.

    Raises
    ------
    ValueError
        A non-integer or non-positive bin count, a bad range window, a beam table that is
        empty, not finite or not strictly descending, or a single beam without a width.
    """

    range_min_m: float
    range_max_m: float
    n_range_bins: int
    beam_angles_deg: tuple[float, ...]
    single_beam_width_deg: float | None = None

    def __post_init__(self) -> None:
        n = _check_count(self.n_range_bins, "n_range_bins")
        rmin, rmax = _check_ranges(self.range_min_m, self.range_max_m)
        az = _check_azimuth(self.beam_angles_deg)
        width = _check_single_beam_width(az, self.single_beam_width_deg)
        object.__setattr__(self, "n_range_bins", n)
        object.__setattr__(self, "range_min_m", rmin)
        object.__setattr__(self, "range_max_m", rmax)
        object.__setattr__(self, "beam_angles_deg", tuple(float(a) for a in az))
        object.__setattr__(self, "single_beam_width_deg", width)

    # Range ------------------------------------------------------------------------------

    @property
    def range_resolution_m(self) -> float:
        """Width ``dr`` of one range bin, metres."""
        return (self.range_max_m - self.range_min_m) / self.n_range_bins

    @property
    def range_edges_m(self) -> np.ndarray:
        """(n_range_bins + 1,) float64 bin edges, metres, ascending."""
        return np.linspace(self.range_min_m, self.range_max_m, self.n_range_bins + 1)

    @property
    def range_m(self) -> np.ndarray:
        """(n_range_bins,) float64 bin centres, metres, ascending."""
        e = self.range_edges_m
        return 0.5 * (e[:-1] + e[1:])

    # Azimuth ----------------------------------------------------------------------------

    @property
    def n_beams(self) -> int:
        return len(self.beam_angles_deg)

    @property
    def azimuth_deg(self) -> np.ndarray:
        """(n_beams,) float64 beam centres, degrees, left-most first (descending)."""
        return np.asarray(self.beam_angles_deg, dtype=np.float64)

    @property
    def beam_edges_deg(self) -> np.ndarray:
        """(n_beams + 1,) float64 beam edges, degrees, descending (see :func:`beam_edges_deg`);
        read-only, formed once (every frame asks)."""
        edges = self.__dict__.get("_beam_edges")
        if edges is None:
            width = 1.0 if self.single_beam_width_deg is None else self.single_beam_width_deg
            edges = beam_edges_deg(self.azimuth_deg, width)
            edges.setflags(write=False)
            self.__dict__["_beam_edges"] = edges  # (a frozen dataclass: its fields stay as they are)
        return edges

    @property
    def left_edge_deg(self) -> float:
        """Azimuth of the fan's left (port, positive) outer edge, degrees."""
        return float(self.beam_edges_deg[0])

    @property
    def right_edge_deg(self) -> float:
        """Azimuth of the fan's right (starboard) outer edge, degrees."""
        return float(self.beam_edges_deg[-1])

    @property
    def azimuth_fov_deg(self) -> float:
        """Edge-to-edge azimuth extent of the fan, degrees."""
        e = self.beam_edges_deg
        return float(e[0] - e[-1])

    # Both -------------------------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """``(n_range_bins, n_beams)``: the shape of a polar image on this grid."""
        return (self.n_range_bins, self.n_beams)

    @property
    def area_m2(self) -> float:
        """Area covered: the annular sector between the range window and the outer edges, m^2."""
        return sector_area_m2(self.range_min_m, self.range_max_m, self.left_edge_deg, self.right_edge_deg)

    def describe(self) -> str:
        """One line for messages, e.g. ``0.5-5 m in 400 bins, 32 beams over 30 deg (+15 to -15)``."""
        return (
            f"{self.range_min_m:g}-{self.range_max_m:g} m in {self.n_range_bins} bins, "
            f"{self.n_beams} beams over {self.azimuth_fov_deg:.4g} deg "
            f"({self.left_edge_deg:+.4g} to {self.right_edge_deg:+.4g})"
        )


class PolarSonar(Protocol):
    """What the image types need of the sonar that made an image: its polar grid.

    :class:`sonarsim.config.sonar.SonarConfig` is one (the sonar of every rendered or recorded
    :class:`~sonarsim.image.result.SonarImage`); this protocol lets :mod:`sonarsim.image` name
    it without importing :mod:`sonarsim.config`, which sits above it (the sonar builds its grid
    from this module).
    """

    @property
    def grid(self) -> PolarGrid:
        """The polar grid (range bins x beams) of the sonar's images."""
        ...

    @property
    def range_edges_m(self) -> np.ndarray:
        """(n_range_bins + 1,) range bin edges, metres."""
        ...
