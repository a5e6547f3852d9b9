"""Fan and polar axes: range rings, azimuth spokes, the fan's outline, and their round steps.

The fan is drawn in the sonar frame seen from above, in metres: the vertical axis is the
forward distance ``x``, the horizontal axis the lateral distance ``y`` with the sonar's LEFT on
the figure's left (DESIGN.md section 1), so the horizontal axis runs from +y on the left to -y on
the right. Azimuths follow the same convention: positive to the sonar's left.

Steps are "round": 1, 2, 2.5 or 5 times a power of ten metres for the rings, and one of
:data:`AZIMUTH_STEPS_DEG` for the spokes, the smallest that keeps the count readable.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = [
    "AZIMUTH_STEPS_DEG",
    "MAX_RINGS",
    "MAX_SPOKES",
    "azimuth_ticks_deg",
    "draw_fan_frame",
    "fan_outline",
    "format_azimuth",
    "format_range",
    "range_rings_m",
    "round_step",
]

#: At most this many range rings (and range ticks of polar axes) for a window.
MAX_RINGS = 6
#: At most this many azimuth spokes (and azimuth ticks of polar axes) for a fan.
MAX_SPOKES = 7
#: Azimuth steps offered, degrees.
AZIMUTH_STEPS_DEG = (0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 45.0)

# Colours of the annotations: rings and spokes light and half transparent (they cross "no echo",
# the dark end of the maps), the outline dark against the neutral colour outside the fan.
RING_COLOUR = "#e8e8e8"
OUTLINE_COLOUR = "#202020"
# A true minus sign, typeset as wide as the plus.
MINUS = "\u2212"


def _multiples(step: float, lo: float, hi: float) -> np.ndarray:
    """Multiples of ``step`` in ``[lo, hi]`` (with a relative tolerance for round-off)."""
    eps = 1e-9 * max(1.0, abs(hi), abs(lo))
    first = math.ceil((lo - eps) / step)
    last = math.floor((hi + eps) / step)
    return np.arange(first, last + 1, dtype=np.float64) * step


def round_step(span: float, max_count: int, lo: float = 0.0) -> float:
    """The smallest round step (1, 2, 2.5, 5 x 10^k) with at most ``max_count`` multiples in
    ``[lo, lo + span]`` (and at least one where a step that large exists).

    Parameters
    ----------
    span : float
        Length of the interval, > 0 (metres for rings).
    max_count : int
        Most multiples wanted, >= 1.
    lo : float
        Start of the interval.

    Returns
    -------
    float
    """
    if not (math.isfinite(span) and span > 0.0):
        raise ValueError(f"span must be finite and > 0, got {span!r}")
    k = math.floor(math.log10(span / max(max_count, 1))) - 1
    while True:
        for mantissa in (1.0, 2.0, 2.5, 5.0):
            step = mantissa * 10.0**k
            if _multiples(step, lo, lo + span).size <= max_count:
                return step
        k += 1


def range_rings_m(range_min_m: float, range_max_m: float, max_rings: int = MAX_RINGS) -> tuple[np.ndarray, float]:
    """Radii of the range rings of a window: the multiples of a round step inside it.

    Parameters
    ----------
    range_min_m, range_max_m : float
        The range window, metres, ``0 <= range_min_m < range_max_m``.
    max_rings : int
        Most rings drawn.

    Returns
    -------
    radii_m : (n,) float64 ndarray
        Ascending, within ``[range_min_m, range_max_m]``; none at 0.
    step_m : float
        Their spacing.

    Examples
    --------
    >>> range_rings_m(0.7, 5.0)  # the ARIS 3000 preset's window
    (array([1., 2., 3., 4., 5.]), 1.0)
    """
    step = round_step(range_max_m - range_min_m, max_rings, range_min_m)
    radii = _multiples(step, range_min_m, range_max_m)
    return radii[radii > 0.0], step


def azimuth_ticks_deg(left_edge_deg: float, right_edge_deg: float, max_ticks: int = MAX_SPOKES) -> np.ndarray:
    """Azimuths of the spokes of a fan: multiples of a step of :data:`AZIMUTH_STEPS_DEG`.

    Parameters
    ----------
    left_edge_deg, right_edge_deg : float
        The fan's outer edges, degrees, positive to the sonar's left (``left > right``).
    max_ticks : int
        Most spokes drawn.

    Returns
    -------
    (n,) float64 ndarray
        Descending (left-most first, as the beams), within the edges.
    """
    lo, hi = float(right_edge_deg), float(left_edge_deg)
    for step in AZIMUTH_STEPS_DEG:
        ticks = _multiples(step, lo, hi)
        if ticks.size <= max_ticks:
            return ticks[::-1]
    return np.array([0.0]) if lo <= 0.0 <= hi else np.array([])


def format_range(r_m: float) -> str:
    """A ring's label: ``"2 m"``, ``"2.5 m"``, ``"0.25 m"``."""
    return f"{r_m:g} m"


def format_azimuth(a_deg: float) -> str:
    """A spoke's label, with its side: ``"+10°"`` (left), ``"0°"``, ``"−10°"`` (right)."""
    if abs(a_deg) < 1e-9:
        return "0°"
    sign = "+" if a_deg > 0 else MINUS
    return f"{sign}{abs(a_deg):g}°"


def _arc(r: float, a0_deg: float, a1_deg: float, n: int = 181) -> tuple[np.ndarray, np.ndarray]:
    """(lateral y, forward x) of an arc of radius ``r`` from azimuth a0 to a1."""
    a = np.radians(np.linspace(a0_deg, a1_deg, n))
    return r * np.sin(a), r * np.cos(a)


def fan_outline(range_min_m: float, range_max_m: float, left_edge_deg: float,
                right_edge_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """The fan's closed outline as (lateral y, forward x) metres: near arc, right edge, far arc,
    left edge.

    Returns
    -------
    y_m, x_m : (n,) float64 ndarray
    """
    yf, xf = _arc(range_max_m, right_edge_deg, left_edge_deg)
    yn, xn = _arc(range_min_m, left_edge_deg, right_edge_deg)
    return np.concatenate([yn, yf, yn[:1]]), np.concatenate([xn, xf, xn[:1]])


def draw_fan_frame(ax: Axes, range_min_m: float, range_max_m: float, left_edge_deg: float,
                   right_edge_deg: float, *, rings: bool = True, spokes: bool = True,
                   axis_labels: bool = True) -> dict[str, list]:
    """Draw the fan's outline, range rings (labelled in metres) and azimuth spokes (labelled in
    degrees) on Cartesian axes whose data are (lateral y, forward x) metres.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes where ``y`` (positive left) runs along the horizontal axis, the figure's left being
        the sonar's left (an extent or limits from +y to -y), and ``x`` along the vertical one.
    range_min_m, range_max_m : float
        The range window, metres.
    left_edge_deg, right_edge_deg : float
        The fan's outer edges, degrees, positive left.
    rings, spokes : bool
        Draw (and label) the range rings and azimuth spokes.
    axis_labels : bool
        Label the axes (``lateral``/``forward``, in metres).

    Returns
    -------
    dict
        ``"rings"``: (radius_m, label Text) pairs; ``"spokes"``: (azimuth_deg, label Text) pairs;
        ``"outline"``: the outline's Line2D, as a one-item list.
    """
    drawn: dict[str, list] = {"rings": [], "spokes": [], "outline": []}
    span = range_max_m
    if rings:
        radii, _ = range_rings_m(range_min_m, range_max_m)
        for r in radii:
            y, x = _arc(r, right_edge_deg, left_edge_deg)
            ax.plot(y, x, color=RING_COLOUR, lw=0.6, alpha=0.7, zorder=3)
            # Labels just beyond the right edge (the sonar's starboard side), along the edge.
            a = math.radians(right_edge_deg)
            # On the neutral background outside the fan: dark text reads there.
            text = ax.text(r * math.sin(a), r * math.cos(a), " " + format_range(r), color="black", fontsize=8,
                           ha="left", va="center", zorder=5, clip_on=False)
            drawn["rings"].append((float(r), text))
    if spokes:
        # Fewer spokes on a narrow fan: their labels sit side by side on the far arc, whose
        # chord is 2 sin(half width) of the range that sets the figure's height.
        chord = abs(math.sin(math.radians(left_edge_deg)) - math.sin(math.radians(right_edge_deg)))
        n_spokes = int(min(MAX_SPOKES, max(3, round(14 * chord))))
        for a_deg in azimuth_ticks_deg(left_edge_deg, right_edge_deg, n_spokes):
            a = math.radians(a_deg)
            ax.plot([range_min_m * math.sin(a), range_max_m * math.sin(a)],
                    [range_min_m * math.cos(a), range_max_m * math.cos(a)],
                    color=RING_COLOUR, lw=0.5, alpha=0.5, ls=(0, (4, 4)), zorder=3)
            out = range_max_m + 0.035 * span  # just beyond the far arc
            text = ax.text(out * math.sin(a), out * math.cos(a), format_azimuth(a_deg), color="black", fontsize=8,
                           ha="center", va="bottom", rotation=-a_deg, rotation_mode="anchor", zorder=5,
                           clip_on=False)
            drawn["spokes"].append((float(a_deg), text))
    y, x = fan_outline(range_min_m, range_max_m, left_edge_deg, right_edge_deg)
    (line,) = ax.plot(y, x, color=OUTLINE_COLOUR, lw=1.0, zorder=4)
    drawn["outline"].append(line)
    if axis_labels:
        ax.set_xlabel("lateral (m), + = sonar's left")
        ax.set_ylabel("forward (m)")
    ax.set_aspect("equal")
    return drawn
