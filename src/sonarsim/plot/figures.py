"""Annotated figures of sonar images: fan and polar views with axes, rings, colour bars, titles.

Every builder returns a :class:`matplotlib.figure.Figure` made without pyplot (no global state,
no display needed); :func:`save_figure` writes one atomically as PNG, SVG or PDF. Values become
colours in two steps that exist once in sonarsim: :func:`sonarsim.io.output.to_uint8` (the dB or
linear mapping of the exact-pixel PNGs) and :func:`sonarsim.plot.style.colorize` (the colour
map); :class:`DisplayScale` holds the first step's settings and says what the colour bar reads.

Fans are drawn in metres (:mod:`sonarsim.plot.axes`): lateral on the horizontal axis with the
sonar's left on the left, forward up; polar views show azimuth across (left-most beam on the
left) and range up (far range at the top), as the exact-pixel PNGs do.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.interrupts import signals_deferred
from ..image.levels import device_full_scale  # noqa: F401 (here before; figures use it)
from ..io.output import to_uint8
from .formats import FIGURE_FORMATS
from .axes import azimuth_ticks_deg, draw_fan_frame, format_azimuth, range_rings_m
from .style import DEFAULT_COLORMAP, OUTSIDE_FAN_RGB, colorize, colormap_lut

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "FIGURE_FORMATS",
    "FIGURE_PIXELS",
    "DisplayScale",
    "Panel",
    "calibration_figure",
    "comparison_figure",
    "default_scale",
    "describe",
    "draw_fan",
    "draw_fan_image",
    "draw_polar",
    "fan_figure",
    "figure_pixel_size",
    "fit_figure",
    "ground_echo_figure",
    "multipath_figure",
    "panels_figure",
    "polar_figure",
    "save_figure",
    "reconstruction_figure",
    "sensor_figure",
    "signed_limit",
]

#: A fan drawn in a figure is resampled to about this many pixels along its range, whatever the
#: range resolution: finer than any figure shows it, and a figure stays well under a second.
FIGURE_PIXELS = 600
#: Resolution of PNG figures, dots per inch.
FIGURE_DPI = 120

_INTENSITY, _COUNTS = "intensity", "counts"
#: What the colour bar refers to when the image has no echo at all (nothing above zero).
NO_ECHO_REFERENCE = "1; no echo: nothing above 0"


@dataclass(frozen=True)
class DisplayScale:
    """How values become display levels (:func:`~sonarsim.io.output.to_uint8`) and what the
    colour bar says about them.

    Attributes
    ----------
    mapping : {'db', 'linear'}
        As :func:`~sonarsim.io.output.to_uint8`.
    gain_db : float
        Display gain, dB.
    dynamic_range_db : float
        Width of the dB window shown, > 0.
    reference : float or None
        The value shown at full scale with zero gain; ``None``: each image's maximum.
    units : {'intensity', 'counts'}
        ``intensity``: a render's echo intensity (any scale); ``counts``: a device's output
        values (sensor model, real recordings).
    reference_name : str
        What ``reference`` is, for the colour bar's label (e.g. ``"the image's maximum"``).
    quantity : str
        What the image's values are, with their unit (:attr:`Unit.label
        <sonarsim.image.units.Unit.label>`), said in the colour bar's label; empty: not said.
    """

    mapping: str = "db"
    gain_db: float = 0.0
    dynamic_range_db: float = 40.0
    reference: float | None = None
    units: str = _INTENSITY
    reference_name: str = "the image's maximum"
    quantity: str = ""

    def encode(self, values: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        """Display levels of ``values`` (any shape), uint8, 0 outside ``mask``."""
        return to_uint8(values, self.mapping, self.gain_db, self.dynamic_range_db, self.reference, mask)

    def resolved(self, *arrays: np.ndarray) -> "DisplayScale":
        """This scale with ``reference`` fixed to the largest finite value of ``arrays`` when it
        is ``None`` (so that several panels, and the colour bar, share it); 1 when nothing is
        above zero, with :data:`NO_ECHO_REFERENCE` as its name."""
        if self.reference is not None:
            return self
        peaks = [float(np.max(a[np.isfinite(a)])) for a in map(np.asarray, arrays) if np.isfinite(a).any()]
        peak = max(peaks, default=0.0)
        if peak > 0.0:
            return replace(self, reference=peak)
        # A dark frame (all zero, or NaN): there is no maximum to refer to; any reference shows
        # it black, and the colour bar says why rather than "dB re the image's maximum".
        return replace(self, reference=1.0, reference_name=NO_ECHO_REFERENCE)

    @property
    def limits(self) -> tuple[float, float]:
        """The colour bar's (low, high) ends, in the units of :attr:`label`."""
        if self.mapping == "db":
            return (-self.gain_db - self.dynamic_range_db, -self.gain_db)
        top = 10.0 ** (-self.gain_db / 10.0)
        if self.units == _COUNTS and self.reference is not None:
            return (0.0, float(self.reference) * top)
        return (0.0, top)

    @property
    def label(self) -> str:
        """The colour bar's label, with its unit."""
        of = f"; {self.quantity}" if self.quantity and self.units != _COUNTS else ""
        if self.mapping == "db":
            return f"echo level (dB re {self.reference_name}{of})"
        if self.units == _COUNTS and self.reference is not None:
            return "device output (counts)"
        return f"intensity / {self.reference_name}{of}"


@dataclass(frozen=True, eq=False)
class Panel:
    """One picture of a figure made of several.

    Attributes
    ----------
    title : str
    image : SonarImage
        Gives the geometry (and, without ``values``, the picture: its ``polar``).
    values : (n_range_bins, n_beams) ndarray or None
        What to draw on the image's grid instead of ``image.polar`` (a component, a sum).
    signed_limit : float or None
        Set for a signed panel (a difference): ``values`` are drawn as they are, on a diverging
        colour map centred on zero from ``-signed_limit`` to ``+signed_limit``, with a colour
        bar of their own labelled ``signed_label``.
    signed_label : str
        The signed panel's colour-bar label, with its unit.
    """

    title: str
    image: Any
    values: np.ndarray | None = None
    signed_limit: float | None = None
    signed_label: str = "difference"

    @property
    def polar(self) -> np.ndarray:
        """The values drawn, (n_range_bins, n_beams)."""
        return np.asarray(self.image.polar if self.values is None else self.values)


# ---------------------------------------------------------------------------------- descriptions

def default_scale(image: Any, mapping: str | None = None, gain_db: float = 0.0,
                  dynamic_range_db: float = 40.0) -> DisplayScale:
    """The scale an image is shown on unless told otherwise.

    Device output (a sensor model's render, a recording) is shown in its counts, linearly
    against full scale, as the device's own software shows it; a render's intensity in dB below
    the image's maximum.

    Parameters
    ----------
    image : SonarImage
    mapping : {'db', 'linear'}, optional
        Overrides the default mapping (linear for device output, dB otherwise).
    gain_db, dynamic_range_db : float
        As :func:`~sonarsim.io.output.to_uint8`.
    """
    full = device_full_scale(image)
    if full is not None:
        return DisplayScale(mapping or "linear", gain_db, dynamic_range_db, full, _COUNTS,
                            f"full scale ({full:g})")
    unit = getattr(image, "unit", None)
    return DisplayScale(mapping or "db", gain_db, dynamic_range_db, quantity=unit.label if unit is not None else "")


def _fmt(v: float) -> str:
    """Three significant digits, without an exponent from 1 mm to a million (1000 m reads
    "1000", not "1e+03"); below 1e-3 in scientific notation."""
    if abs(v) < 1e-3 and v != 0:
        return f"{v:.1e}"
    return f"{float(f'{v:.3g}'):g}"


def describe(image: Any, component: str | None = None, frame: int | None = None) -> str:
    """A figure's title: what the image shows, on two or three lines.

    Line 1: the device (preset, or the recording's format and file, and the frame), the beams
    and the range window. Line 2 (renders): the component(s) shown and the sensor model (on or
    off); line 3: the sonar's pose, where known.

    Parameters
    ----------
    image : SonarImage
    component : str, optional
        The component shown (default: the total image).
    frame : int, optional
        The frame number, if the caller knows it (a recording's is read from its configuration).
    """
    s = image.sonar
    config = getattr(image, "config", None) or {}
    window = f"{s.n_beams} beams, {_fmt(s.range_min_m)}\u2013{_fmt(s.range_max_m)} m"
    if "format" in config:  # a recording
        frame = config.get("frame", frame)
        source = os.path.basename(str(config.get("source", "")))
        return f"{config['format']} recording {source}, frame {frame}\n{window}"
    device = s.preset or "sonar"
    first = f"{device}, {window}" + (f", frame {frame}" if frame is not None else "")
    render = config.get("render") or {}
    if component is None:
        bounces = render.get("bounces")
        orders = f"orders {', '.join(map(str, bounces))}" if bounces else f"orders up to {render.get('max_order', 3)}"
        what = f"total ({orders})"
    else:
        what = f"component {component}"
    sensor = config.get("sensor")
    what += ", sensor model on" if isinstance(sensor, dict) else ", no sensor model"
    pose = getattr(image, "pose", None)
    if pose is not None:
        p, r = pose.position_m, pose.rpy_deg
        what += (f"\nsonar at ({', '.join(_fmt(v) for v in p)}) m, "
                 f"roll/pitch/yaw ({', '.join(_fmt(v) for v in r)})\u00b0")
    return f"{first}\n{what}"


# ---------------------------------------------------------------------------------- drawing

def figure_pixel_size(sonar: Any, pixel_size_m: float | None = None) -> float:
    """The fan pixel of a figure: ``pixel_size_m`` if given, else the range resolution or
    ``range_max_m / FIGURE_PIXELS``, whichever is coarser (metres)."""
    if pixel_size_m is not None:
        return float(pixel_size_m)
    return max(sonar.range_resolution_m, sonar.range_max_m / FIGURE_PIXELS)


def _listed(colormap: str):
    from matplotlib.colors import ListedColormap

    return ListedColormap(colormap_lut(colormap) / 255.0, name=colormap)


def _colorbar(fig: Figure, axes: Any, scale: DisplayScale, colormap: str):
    """A colour bar of ``scale`` beside ``axes``: its ends are :attr:`DisplayScale.limits`."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    lo, hi = scale.limits
    mappable = ScalarMappable(norm=Normalize(lo, hi), cmap=_listed(colormap))
    return fig.colorbar(mappable, ax=axes, label=scale.label, shrink=0.85, pad=0.03)


def draw_fan(ax: Axes, image: Any, values: np.ndarray | None = None, scale: DisplayScale | None = None, *,
             colormap: str = DEFAULT_COLORMAP, pixel_size_m: float | None = None, mapper: Any = None,
             annotate: bool = True) -> dict[str, list]:
    """Draw an image's fan in metres on ``ax``: the picture, its outline, rings and spokes.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    image : SonarImage
        Gives the geometry (and the picture, without ``values``).
    values : (n_range_bins, n_beams) ndarray, optional
        The polar values to draw (default ``image.polar``).
    scale : DisplayScale, optional
        Default :func:`default_scale` of ``image``.
    colormap : str
        A colour map of :mod:`sonarsim.plot.style`.
    pixel_size_m : float, optional
        See :func:`figure_pixel_size`.
    mapper : FanMapper, optional
        A scan converter of the image's grid (shared by the panels of one figure).
    annotate : bool
        Draw rings, spokes and axis labels (the outline is always drawn).

    Returns
    -------
    dict
        What :func:`sonarsim.plot.axes.draw_fan_frame` returns, plus ``"image"``: the AxesImage.
    """
    from ..image.fan import FanMapper

    s = image.sonar
    if mapper is None:
        mapper = FanMapper.from_grid(s.grid, figure_pixel_size(s, pixel_size_m))
    scale = scale or default_scale(image)
    fan = mapper(image.polar if values is None else values)
    drawn = draw_fan_image(ax, fan, scale, (mapper.range_min_m, mapper.range_max_m, mapper.left_edge_deg,
                                            mapper.right_edge_deg), colormap=colormap, annotate=annotate)
    return drawn


def draw_fan_image(ax: Axes, fan: Any, scale: DisplayScale, bounds: tuple[float, float, float, float], *,
                   colormap: str = DEFAULT_COLORMAP, annotate: bool = True) -> dict[str, list]:
    """Draw a :class:`~sonarsim.image.fan.FanImage` in metres on ``ax`` with its frame.

    Parameters
    ----------
    fan : FanImage
    scale : DisplayScale
    bounds : (range_min_m, range_max_m, left_edge_deg, right_edge_deg)
        The fan's window, for its outline, rings and spokes.

    Returns
    -------
    dict
        What :func:`sonarsim.plot.axes.draw_fan_frame` returns, plus ``"image"``: the AxesImage.
    """
    rgb = colorize(scale.encode(fan.image, fan.mask), colormap, fan.mask, outside=OUTSIDE_FAN_RGB)
    half = fan.pixel_size_m / 2.0
    # Extent from +y (left) to -y (right): the sonar's left is on the figure's left.
    extent = (fan.y_m[0] + half, fan.y_m[-1] - half, fan.x_m[-1] - half, fan.x_m[0] + half)
    shown = ax.imshow(rgb, extent=extent, origin="upper", interpolation="antialiased", zorder=1)
    ax.set_facecolor(np.asarray(OUTSIDE_FAN_RGB) / 255.0)
    rmin, rmax, left, right = bounds
    drawn = draw_fan_frame(ax, rmin, rmax, left, right, rings=annotate, spokes=annotate, axis_labels=annotate)
    # Room beyond the far arc for the spokes' labels, and beside the fan for the rings'.
    ax.set_xlim(extent[0] + 0.03 * rmax, extent[1] - 0.12 * rmax)
    ax.set_ylim(0.0, max(extent[3], rmax) + 0.09 * rmax)
    drawn["image"] = [shown]
    return drawn


def draw_polar(ax: Axes, image: Any, values: np.ndarray | None = None, scale: DisplayScale | None = None, *,
               colormap: str = DEFAULT_COLORMAP) -> Any:
    """Draw an image in polar form on ``ax``: azimuth across (left-most beam on the left, in
    degrees), range up (far range at the top, in metres), each beam and bin its own cell (lens
    tables with unequal beams are drawn as they are).

    Returns
    -------
    matplotlib.image.AxesImage or matplotlib.image.PcolorImage
        One image (``PcolorImage`` where the beams are unequal).
    """
    from matplotlib.colors import Normalize

    s = image.sonar
    scale = scale or default_scale(image)
    levels = scale.encode(image.polar if values is None else values)
    edges_az = np.asarray(s.beam_edges_deg, dtype=np.float64)
    edges_r = np.asarray(image.range_edges_m, dtype=np.float64)
    # One image with cell edges, not one quadrilateral per cell (pcolormesh): an 8000-bin,
    # 512-beam image took 1.6 s (PNG) to 2.6 s (SVG, PDF) to draw, this takes 0.1-0.2 s.
    mesh = ax.pcolorfast(edges_az, edges_r, levels, cmap=_listed(colormap), norm=Normalize(0, 255))
    ax.set_xlim(edges_az[0], edges_az[-1])  # descending: the left-most beam on the left
    ax.set_ylim(edges_r[0], edges_r[-1])
    ticks = azimuth_ticks_deg(edges_az[0], edges_az[-1])
    ax.set_xticks(ticks, [format_azimuth(a) for a in ticks])
    radii, _ = range_rings_m(float(edges_r[0]), float(edges_r[-1]))
    ax.set_yticks(radii, [f"{r:g}" for r in radii])
    ax.set_xlabel("azimuth (deg), + = sonar's left")
    ax.set_ylabel("range (m)")
    return mesh


def _new_figure(figsize: tuple[float, float], layout: str = "compressed") -> Figure:
    from matplotlib.figure import Figure

    # "compressed" packs fixed-aspect axes (fans) tightly; panels under a figure title take
    # "constrained", which leaves the title room above theirs.
    return Figure(figsize=figsize, layout=layout)


def _fan_size(sonar: Any, ncols: int = 1, nrows: int = 1, colorbar: bool = True) -> tuple[float, float]:
    """Figure size (inches) for fans of this sonar: room for each fan at its width/height ratio
    (capped), its axis labels and title, the colour bar and a figure title."""
    edges = np.asarray(sonar.beam_edges_deg, dtype=np.float64)
    chord = abs(math.sin(math.radians(edges[0])) - math.sin(math.radians(edges[-1])))
    ratio = min(2.2, max(0.5, (chord + 0.15) / 1.09))  # the axes' limits of draw_fan
    h = 4.4 if nrows == 1 else 3.4
    return (min(18.0, ncols * (h * ratio + 0.7) + (1.4 if colorbar else 0.2)), nrows * (h + 0.9) + 0.5)


def _one_panel(image: Any, component: str | None, ax: Axes | None, scale: DisplayScale | None,
               mapping: str | None, gain_db: float, dynamic_range_db: float,
               figsize: tuple[float, float]) -> tuple[Figure, Axes, np.ndarray | None, DisplayScale]:
    """What a one-image figure starts from: its figure and axes (new ones unless ``ax`` is
    given), the component's values (``None``: the image's own), and the scale resolved on them."""
    values = None if component is None else np.asarray(image.components[component])
    scale = (scale or default_scale(image, mapping, gain_db, dynamic_range_db)).resolved(
        image.polar if values is None else values)
    if ax is None:
        fig = _new_figure(figsize)
        ax = fig.add_subplot()
    else:
        fig = ax.figure
    return fig, ax, values, scale


def fan_figure(image: Any, component: str | None = None, *, ax: Axes | None = None,
               scale: DisplayScale | None = None, mapping: str | None = None, gain_db: float = 0.0,
               dynamic_range_db: float = 40.0, colormap: str = DEFAULT_COLORMAP,
               pixel_size_m: float | None = None, title: str | None = None, frame: int | None = None,
               figsize: tuple[float, float] | None = None) -> Figure:
    """The annotated fan of one image: metres, rings, spokes, outline, colour bar and title.

    Parameters
    ----------
    image : SonarImage
        A render or a recording's frame.
    component : str, optional
        A key of ``image.components`` (default: the image itself, ``polar``).
    ax : matplotlib.axes.Axes, optional
        Draw there (its figure gets the colour bar); default a new figure.
    scale : DisplayScale, optional
        Default :func:`default_scale` with ``mapping``, ``gain_db``, ``dynamic_range_db``.
    colormap : str
        ``inferno`` (default) or ``grey``, or any of :data:`sonarsim.plot.style.COLORMAPS`.
    pixel_size_m : float, optional
        See :func:`figure_pixel_size`.
    title : str, optional
        Default :func:`describe`.
    frame : int, optional
        Named in the default title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax, values, scale = _one_panel(image, component, ax, scale, mapping, gain_db, dynamic_range_db,
                                        figsize or _fan_size(image.sonar))
    draw_fan(ax, image, values, scale, colormap=colormap, pixel_size_m=pixel_size_m)
    _colorbar(fig, ax, scale, colormap)
    ax.set_title(describe(image, component, frame) if title is None else title, fontsize=9)
    return fig


def polar_figure(image: Any, component: str | None = None, *, ax: Axes | None = None,
                 scale: DisplayScale | None = None, mapping: str | None = None, gain_db: float = 0.0,
                 dynamic_range_db: float = 40.0, colormap: str = DEFAULT_COLORMAP, title: str | None = None,
                 frame: int | None = None, figsize: tuple[float, float] = (6.0, 5.0)) -> Figure:
    """The annotated polar image: azimuth (deg) across, range (m) up, colour bar and title.

    Parameters are those of :func:`fan_figure` (without the pixel size).

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax, values, scale = _one_panel(image, component, ax, scale, mapping, gain_db, dynamic_range_db, figsize)
    draw_polar(ax, image, values, scale, colormap=colormap)
    _colorbar(fig, ax, scale, colormap)
    ax.set_title(describe(image, component, frame) if title is None else title, fontsize=9)
    return fig


def panels_figure(panels: Sequence[Panel], scales: DisplayScale | Sequence[DisplayScale], *, title: str = "",
                  ncols: int | None = None, colormap: str = DEFAULT_COLORMAP,
                  pixel_size_m: float | None = None) -> Figure:
    """Fans side by side (or in a grid), each under its title, with one colour bar per scale.

    Parameters
    ----------
    panels : sequence of Panel
    scales : DisplayScale or sequence of DisplayScale
        One scale for all panels (one colour bar: their brightness compares directly), or one
        per panel; panels given the same scale object share its colour bar. A scale whose
        ``reference`` is ``None`` is fixed to the largest value of the panels that use it.
    title : str
        The figure's title.
    ncols : int, optional
        Panels per row (default: all in one row).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..image.fan import FanMapper

    per_panel = [scales] * len(panels) if isinstance(scales, DisplayScale) else list(scales)
    if len(per_panel) != len(panels):
        raise ValueError(f"{len(panels)} panels but {len(per_panel)} scales")
    # Panels that share a scale object share its reference (and colour bar).
    groups: dict[int, list[int]] = {}
    for k, sc in enumerate(per_panel):
        groups.setdefault(id(sc), []).append(k)
    fixed: dict[int, DisplayScale] = {}
    for key, members in groups.items():
        fixed[key] = per_panel[members[0]].resolved(*(panels[k].polar for k in members))
    ncols = ncols or len(panels)
    nrows = math.ceil(len(panels) / ncols)
    width, height = _fan_size(panels[0].image.sonar, ncols, nrows, colorbar=True)
    # Fans keep their aspect: the constrained layout cannot shrink them below the height their
    # width asks for, and without this room the x labels fell off the bottom and the figure's
    # title sat on the panels' titles.
    lines = title.count("\n") + 1 if title else 0
    fig = _new_figure((width, height + 0.45 + 0.18 * lines), "constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    mappers: dict[Any, Any] = {}
    for k, panel in enumerate(panels):
        grid = panel.image.sonar.grid
        px = figure_pixel_size(panel.image.sonar, pixel_size_m)
        if (grid, px) not in mappers:  # one scan converter per geometry
            mappers[(grid, px)] = FanMapper.from_grid(grid, px)
        if panel.signed_limit is not None:
            _draw_signed_fan(fig, axes[k], panel, mappers[(grid, px)])
        else:
            draw_fan(axes[k], panel.image, panel.values, fixed[id(per_panel[k])], colormap=colormap,
                     mapper=mappers[(grid, px)])
        axes[k].set_title(panel.title, fontsize=10)
        if k % ncols:  # the forward axis label once per row is enough
            axes[k].set_ylabel("")
        if k // ncols < nrows - 1:  # and the lateral one under the last row (room for the titles)
            axes[k].set_xlabel("")
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    # One colour bar per distinct reading (label and ends): panels scaled each to its own
    # maximum read alike on one bar, a dB panel beside panels in counts gets a bar of its own.
    bars: dict[tuple, list[int]] = {}
    for k in range(len(panels)):
        if panels[k].signed_limit is not None:  # its own bar, drawn with it
            continue
        sc = fixed[id(per_panel[k])]
        bars.setdefault((sc.label, sc.limits), []).append(k)
    for members in bars.values():
        _colorbar(fig, [axes[k] for k in members], fixed[id(per_panel[members[0]])], colormap)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


#: The diverging colour map of signed panels (differences, height errors): white at zero.
SIGNED_COLORMAP = "RdBu_r"


def _draw_signed_fan(fig: Figure, ax: Axes, panel: Panel, mapper: Any) -> None:
    """A signed panel (:attr:`Panel.signed_limit`): the values' fan on a diverging map centred
    on zero, the fan's frame and a colour bar of its own."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    limit = float(panel.signed_limit) if panel.signed_limit and np.isfinite(panel.signed_limit) else 1.0
    fan = mapper(np.nan_to_num(np.asarray(panel.polar, np.float64), nan=0.0, posinf=0.0, neginf=0.0))
    norm = Normalize(-limit, limit)
    rgba = _signed_rgba(fan.image, norm)
    rgba[~fan.mask] = (*(np.asarray(OUTSIDE_FAN_RGB) / 255.0), 1.0)
    half = fan.pixel_size_m / 2.0
    extent = (fan.y_m[0] + half, fan.y_m[-1] - half, fan.x_m[-1] - half, fan.x_m[0] + half)
    ax.imshow(rgba, extent=extent, origin="upper", interpolation="antialiased", zorder=1)
    ax.set_facecolor(np.asarray(OUTSIDE_FAN_RGB) / 255.0)
    draw_fan_frame(ax, mapper.range_min_m, mapper.range_max_m, mapper.left_edge_deg, mapper.right_edge_deg)
    rmax = mapper.range_max_m
    ax.set_xlim(extent[0] + 0.03 * rmax, extent[1] - 0.12 * rmax)
    ax.set_ylim(0.0, max(extent[3], rmax) + 0.09 * rmax)
    fig.colorbar(ScalarMappable(norm=norm, cmap=SIGNED_COLORMAP), ax=ax, label=panel.signed_label, shrink=0.85,
                 pad=0.03)


def _signed_rgba(values: np.ndarray, norm: Any) -> np.ndarray:
    """RGBA (float, 0-1) of signed values on :data:`SIGNED_COLORMAP` under ``norm``."""
    from matplotlib import colormaps

    return colormaps[SIGNED_COLORMAP](norm(values))


def signed_limit(values: np.ndarray) -> float:
    """The symmetric colour limit of a signed panel: the largest finite magnitude (1 when there
    is none, so that an all-zero difference still has a scale)."""
    v = np.asarray(values, np.float64)
    v = np.abs(v[np.isfinite(v)])
    peak = float(v.max()) if v.size else 0.0
    return peak if peak > 0.0 else 1.0


# ---------------------------------------------------------------------------------- the comparisons

def ground_echo_figure(image: Any, *, mapping: str = "db", gain_db: float = 0.0, dynamic_range_db: float = 40.0,
                       colormap: str = DEFAULT_COLORMAP, pixel_size_m: float | None = None) -> Figure:
    """The paper's Fig. 9: single | single + triple | all bounces, on one scale (dB re the
    all-bounce image's maximum), labelled panels (:data:`sonarsim.io.figures.BOUNCE_VARIANTS`).

    Parameters
    ----------
    image : SonarImage
        A render with its ``components``.
    """
    from ..io.figures import BOUNCE_VARIANTS

    comp = image.components
    zero = np.zeros(image.polar.shape)
    # Orders beyond the render's max_order are absent: they add nothing to a panel.
    sums = [sum((np.asarray(comp[k], np.float64) for k in keys if k in comp), zero) for _, keys in BOUNCE_VARIANTS]
    scale = DisplayScale(mapping, gain_db, dynamic_range_db, reference_name="the all-bounce image's maximum").resolved(sums[-1])
    panels = [Panel(name, image, values) for (name, _), values in zip(BOUNCE_VARIANTS, sums)]
    return panels_figure(panels, scale, title="Ground echo: " + describe(image).split("\n")[0], colormap=colormap,
                         pixel_size_m=pixel_size_m)


def multipath_figure(image: Any, *, mapping: str = "db", gain_db: float = 0.0, dynamic_range_db: float = 40.0,
                     colormap: str = DEFAULT_COLORMAP, pixel_size_m: float | None = None) -> Figure:
    """A tank's path families (:func:`sonarsim.io.figures.path_families`) in a labelled grid,
    two across (three where a mirroring object adds its ghosts), on one scale (dB re the
    maximum of all paths).

    Parameters
    ----------
    image : SonarImage
        A render with path-signature components.
    """
    from ..io.figures import path_families

    families = path_families(image)
    scale = DisplayScale(mapping, gain_db, dynamic_range_db, reference_name="the maximum of all paths").resolved(
        np.asarray(families[0][1]))
    panels = [Panel(name, image, np.asarray(values, np.float64)) for name, values in families]
    return panels_figure(panels, scale, ncols=2 if len(panels) <= 4 else 3,
                         title="Multipath: " + describe(image).split("\n")[0],
                         colormap=colormap, pixel_size_m=pixel_size_m)


def sensor_figure(recorded: Any, expected: Any, device: str, *, ideal: Any = None, dynamic_range_db: float = 40.0,
                  colormap: str = DEFAULT_COLORMAP, pixel_size_m: float | None = None) -> Figure:
    """The renderer's ideal image (dB) | as the device records it | its expected output (both
    in the device's counts, one colour bar).

    Parameters
    ----------
    recorded : SonarImage
        A render through a sensor model (``polar`` in counts).
    expected : SonarImage
        The same frame with ``speckle=False``.
    device : str
        Its name, for the titles.
    ideal : SonarImage, optional
        The same scene rendered without the sensor model: the paper's ideal image. Without it
        the first panel is ``recorded.components["total"]``, which a sensor whose elevation
        pattern widens the rays' span (an ARIS preset: 42 degrees) forms over that span, not
        over the sonar's aperture; its title says so.
    """
    scale = DisplayScale("db", 0.0, dynamic_range_db, reference_name="the ideal image's maximum")
    counts = default_scale(recorded)
    if ideal is not None:
        first = Panel("ideal (the paper's model, no sensor)", ideal, np.asarray(ideal.polar))
    else:
        first = Panel("renderer's image over the sensor's ray span", recorded,
                      np.asarray(recorded.components["total"]))
    panels = [first, Panel(f"as {device} records it", recorded), Panel(f"{device}: expected (no speckle)", expected)]
    return panels_figure(panels, [scale, counts, counts], title=describe(recorded).split("\n")[0],
                         colormap=colormap, pixel_size_m=pixel_size_m)


def _same_counts(images: Sequence[Any]) -> float | None:
    """The common full scale of images that are all device output on one scale, else None."""
    scales = {device_full_scale(im) for im in images}
    return scales.pop() if len(scales) == 1 and None not in scales else None


def comparison_figure(images: Sequence[Any], titles: Sequence[str], *, normalize: str | None = "max",
                      colormap: str = DEFAULT_COLORMAP, pixel_size_m: float | None = None,
                      title: str = "", metrics: Mapping[str, Mapping[str, float]] | None = None,
                      difference: bool = False) -> Figure:
    """Real and simulated images side by side, on the same scale; optionally their difference
    and the metrics.

    Images in one device's counts (recordings, renders through a sensor model) are shown in
    those counts against full scale. Others (a render's intensity beside a recording's counts
    have no unit in common) are shown as ``compare`` measures them: linearly, each divided by
    its own maximum (``normalize="max"``, the default), or as stored on one shared reference
    (``normalize=None``).

    Parameters
    ----------
    images : sequence of SonarImage
        With geometry (``sonar``) they are drawn as fans in metres; if any has none (a PNG read
        by :func:`~sonarsim.analysis.comparison.load_image`), all are drawn as polar images
        over beam and range-bin indices (far range at the top).
    titles : sequence of str
    metrics : mapping, optional
        Per domain (``"polar"``, ``"fan"``), the scores ``mse``, ``psnr`` (dB) and ``ssim``:
        written under the figure's title.
    difference : bool
        Add a panel of the first image minus the second on the scale the panels show (counts,
        or each image over its maximum), on a diverging map centred on zero. Drawn where the
        two share one polar grid; otherwise the title says why there is none.

    Returns
    -------
    matplotlib.figure.Figure
    """
    title = _with_metrics(title, metrics)
    if any(getattr(im, "sonar", None) is None for im in images):
        return _index_comparison(images, titles, normalize=normalize, colormap=colormap, title=title,
                                 difference=difference)
    full = _same_counts(images)
    if full is not None:
        scale: DisplayScale | list[DisplayScale] = DisplayScale("linear", reference=full, units=_COUNTS,
                                                                reference_name=f"full scale ({full:g})")
        shown = [np.asarray(im.polar, np.float64) for im in images]
        unit = "counts"
    elif normalize is None:
        scale = DisplayScale("linear", reference_name="the larger maximum")
        peak = scale.resolved(*(im.polar for im in images)).reference
        shown = [np.asarray(im.polar, np.float64) / peak for im in images]
        unit = "/ the larger maximum"
    else:
        # One scale per image (each its own reference), all reading alike: one colour bar.
        # (resolved: an image without echo, or with NaN, or below zero, has no maximum to divide by)
        scale = [DisplayScale("linear", reference_name="each image's maximum").resolved(im.polar) for im in images]
        shown = [np.asarray(im.polar, np.float64) / sc.reference for im, sc in zip(images, scale)]
        unit = "/ each image's maximum"
    panels = [Panel(t, im) for t, im in zip(titles, images)]
    if difference and len(images) == 2:
        a, b = images
        if _same_polar_grid(a, b):
            diff = shown[0] - shown[1]
            panels.append(Panel("A \u2212 B", a, diff, signed_limit=signed_limit(diff),
                                signed_label=f"A \u2212 B ({unit})"))
            if isinstance(scale, list):
                scale = [*scale, scale[0]]
            else:
                scale = [scale] * 3
        else:
            title = (title + "\n" if title else "") + "no difference panel: A and B lie on different polar grids"
    return panels_figure(panels, scale, title=title, colormap=colormap, pixel_size_m=pixel_size_m)


def _same_polar_grid(a: Any, b: Any) -> bool:
    """Whether two images' pixels are the same cells (same shape, range and azimuth axes)."""
    pa, pb = np.shape(a.polar), np.shape(b.polar)
    if pa != pb:
        return False
    return bool(np.allclose(a.range_m, b.range_m, rtol=0, atol=1e-9)
                and np.allclose(a.azimuth_deg, b.azimuth_deg, rtol=0, atol=1e-9))


def _with_metrics(title: str, metrics: Mapping[str, Mapping[str, float]] | None) -> str:
    """``title`` with one line of scores per domain (``polar: MSE 12.3, PSNR 37.2 dB, SSIM 0.91``)."""
    if not metrics:
        return title
    lines = []
    for domain, scores in metrics.items():
        parts = []
        for key, name, unit in (("mse", "MSE", ""), ("psnr", "PSNR", " dB"), ("ssim", "SSIM", "")):
            if key in scores:
                v = float(scores[key])
                parts.append(f"{name} {v:.4g}{unit}" if np.isfinite(v) else f"{name} {v}")
        if parts:
            lines.append(f"{domain}: " + ", ".join(parts))
    return "\n".join(([title] if title else []) + lines)


def _index_comparison(images: Sequence[Any], titles: Sequence[str], *, normalize: str | None, colormap: str,
                      title: str, difference: bool = False) -> Figure:
    """Polar images without geometry side by side: beam index across, range bin up (and, with
    ``difference``, the first minus the second where their shapes agree)."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    if normalize is None:
        shared = DisplayScale("linear", reference_name="the larger maximum").resolved(*(im.polar for im in images))
        scales = [shared] * len(images)
    else:
        scales = [DisplayScale("linear", reference_name="each image's maximum").resolved(im.polar) for im in images]
    with_diff = difference and len(images) == 2 and np.shape(images[0].polar) == np.shape(images[1].polar)
    if difference and not with_diff:
        title = (title + "\n" if title else "") + "no difference panel: A and B differ in shape"
    n = len(images) + (1 if with_diff else 0)
    fig = _new_figure((4.0 * n + 1.4 + (1.0 if with_diff else 0.0), 5.2 + 0.18 * title.count("\n")), "constrained")
    axes = fig.subplots(1, n, squeeze=False).ravel()
    for ax, im, sc, name in zip(axes, images, scales, titles):
        polar = np.asarray(im.polar)
        rows, cols = polar.shape
        ax.imshow(sc.encode(polar), origin="lower", aspect="auto", extent=(-0.5, cols - 0.5, -0.5, rows - 0.5),
                  cmap=_listed(colormap), norm=Normalize(0, 255), interpolation="antialiased")
        ax.set_xlabel("beam (index, left-most first)")
        ax.set_ylabel("range bin (index, nearest at the bottom)")
        ax.set_title(name, fontsize=10)
    _colorbar(fig, list(axes[:len(images)]), scales[-1], colormap)
    if with_diff:
        a, b = (np.asarray(im.polar, np.float64) / sc.reference for im, sc in zip(images, scales))
        diff = a - b
        limit = signed_limit(diff)
        rows, cols = diff.shape
        norm = Normalize(-limit, limit)
        axes[-1].imshow(diff, origin="lower", aspect="auto", extent=(-0.5, cols - 0.5, -0.5, rows - 0.5),
                        cmap=SIGNED_COLORMAP, norm=norm, interpolation="antialiased")
        axes[-1].set_xlabel("beam (index, left-most first)")
        axes[-1].set_title("A \u2212 B", fontsize=10)
        fig.colorbar(ScalarMappable(norm=norm, cmap=SIGNED_COLORMAP), ax=axes[-1], shrink=0.85, pad=0.03,
                     label=f"A \u2212 B (/ {scales[0].reference_name})")
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def reconstruction_figure(heights_m: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, seen: np.ndarray, *,
                          truth_m: np.ndarray | None = None, reflectivity: np.ndarray | None = None) -> Figure:
    """``sonarsim reconstruct``: the floor's heights over the grid, the seen vertices only.

    With ``truth_m``: truth | reconstructed | error (reconstructed minus truth); truth and
    result on one colour scale (one bar), the error on a diverging map centred on zero. Without:
    start (flat) | reconstructed, on one scale. ``reflectivity`` adds its own panel.

    Parameters
    ----------
    heights_m : (ny, nx) ndarray
        The reconstructed heights, metres.
    x_m : (nx,) ndarray
    y_m : (ny,) ndarray
        The grid's axes, metres.
    seen : (ny, nx) bool ndarray
        The vertices some path met; the others are not drawn.
    truth_m : (ny, nx) ndarray, optional
        The true heights on the same grid.
    reflectivity : (ny, nx) ndarray, optional
        Per vertex, relative to the ground's albedo.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    heights = np.asarray(heights_m, np.float64)
    seen = np.asarray(seen, bool)
    ref = np.zeros_like(heights) if truth_m is None else np.asarray(truth_m, np.float64)
    pair = [("truth" if truth_m is not None else "start (flat)", ref), ("reconstructed", heights)]
    shown = [np.where(seen, z, np.nan) for _, z in pair]
    finite = np.concatenate([v[np.isfinite(v)] for v in shown])
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if hi <= lo:  # a flat result: a scale a millimetre wide about it
        lo, hi = lo - 5e-4, hi + 5e-4
    n = 2 + (truth_m is not None) + (reflectivity is not None)
    fig = _new_figure((4.6 * n + 1.0, 3.8), "compressed")  # compressed: maps keep their aspect, bars stay beside them
    axes = list(fig.subplots(1, n, squeeze=False).ravel())
    extent = (float(x_m[0]), float(x_m[-1]), float(y_m[0]), float(y_m[-1]))

    def frame(ax: Axes, title: str) -> None:
        ax.set_title(f"{title} (seen vertices)", fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")

    heights_norm = Normalize(lo, hi)
    for ax, (title, _), z in zip(axes, pair, shown):
        ax.imshow(z, origin="lower", extent=extent, cmap="viridis", norm=heights_norm)
        frame(ax, title)
    fig.colorbar(ScalarMappable(norm=heights_norm, cmap="viridis"), ax=axes[:2], label="height (m)", shrink=0.9)
    k = 2
    if truth_m is not None:
        error = np.where(seen, heights - ref, np.nan)
        norm = Normalize(-signed_limit(error), signed_limit(error))
        axes[k].imshow(error, origin="lower", extent=extent, cmap=SIGNED_COLORMAP, norm=norm)
        frame(axes[k], "error: reconstructed \u2212 truth")
        fig.colorbar(ScalarMappable(norm=norm, cmap=SIGNED_COLORMAP), ax=axes[k], label="height error (m)",
                     shrink=0.9)
        k += 1
    if reflectivity is not None:
        shown_r = np.where(seen, np.asarray(reflectivity, np.float64), np.nan)
        im = axes[k].imshow(shown_r, origin="lower", extent=extent, cmap="cividis")
        frame(axes[k], "reflectivity")
        fig.colorbar(im, ax=axes[k], label="relative to the ground's albedo", shrink=0.9)
    return fig


def fit_figure(real: Any, fitted: Any, *, colormap: str = DEFAULT_COLORMAP, frame: int | None = None,
               band: tuple[Any, Any] | None = None) -> Figure:
    """``sonarsim fit``: the real image with the fitted floor band's edges (near: red, far:
    yellow) | the render at the fitted pose, on the same scale (:func:`comparison_figure`).

    Parameters
    ----------
    real, fitted : SonarImage
    band : (near, far) of (n_beams,) float arrays, metres, optional
        The fitted render's floor-band edges per beam, NaN where none:
        ``sonarsim.analysis.fitting.floor_band_m(fitted)``. Passed in: the figures sit below
        the analysis and do not import it. Without it, the real image is drawn unmarked.
    """
    real_title = "real" + (f" (frame {frame})" if frame is not None else "")
    if band is not None:
        real_title += ", fitted floor band"
    fig = comparison_figure([real, fitted], [real_title, "render at the fitted pose"], colormap=colormap,
                            title=describe(real).split("\n")[0])
    if band is None:
        return fig
    ax = fig.axes[0]
    onset, end = band
    az = np.radians(np.asarray(fitted.azimuth_deg, dtype=np.float64))
    for ranges, colour, name in ((onset, "red", "near edge"), (end, "gold", "far edge")):
        ranges = np.asarray(ranges, dtype=np.float64)
        ok = np.isfinite(ranges)
        ax.plot(ranges[ok] * np.sin(az[ok]), ranges[ok] * np.cos(az[ok]), ".", ms=2.0, color=colour, label=name,
                zorder=6)
    ax.legend(loc="lower left", fontsize=7, markerscale=3)
    return fig


def calibration_figure(real: Any, expected: Any, speckled: Any, peak: float, frame: int = 0, *,
                       colormap: str = DEFAULT_COLORMAP) -> Figure:
    """``sonarsim calibrate``: real | calibrated expected render | speckled render, in the
    recording's counts on one scale (0 to ``peak``)."""
    scale = DisplayScale("linear", reference=float(peak), units=_COUNTS, reference_name=f"full scale ({peak:g})")
    panels = [Panel(f"real (frame {frame})", real), Panel("calibrated model: expected (no speckle)", expected),
              Panel("calibrated model: speckled frame", speckled)]
    return panels_figure(panels, scale, title=describe(real).split("\n")[0], colormap=colormap)


# ---------------------------------------------------------------------------------- files

def save_figure(fig: Figure, path: str | os.PathLike, fmt: str | None = None, *, dpi: int = FIGURE_DPI,
                close: bool = True) -> Path:
    """Write a figure atomically; the format from ``fmt`` or the path's suffix.

    SVG and PDF carry no date (the same figure gives the same file); images in them are
    embedded as rasters, lines and text as vectors.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or os.PathLike
    fmt : {'png', 'svg', 'pdf'}, optional
        Default: the suffix of ``path``.
    dpi : int
        Resolution of the PNG (and of the rasters inside SVG/PDF).
    close : bool
        Release the figure's memory afterwards (a pyplot figure is closed too).

    Raises
    ------
    ValueError
        An unknown format, naming the allowed ones.
    """
    import matplotlib

    from ..io.output import atomic_write

    target = Path(path)
    fmt = (fmt or target.suffix.lstrip(".")).lower()
    if fmt not in FIGURE_FORMATS:
        raise ValueError(f"figure format {fmt!r} of {os.fspath(target)!r}: allowed: {', '.join(FIGURE_FORMATS)}")
    metadata = {"png": {"Software": None}, "svg": {"Date": None}, "pdf": {"CreationDate": None}}[fmt]
    # A fixed salt: SVG element ids come out the same on every run.
    with matplotlib.rc_context({"svg.hashsalt": "sonarsim"}), atomic_write(target, "wb") as handle:
        # matplotlib's C code turns an exception raised inside it into its own error: a Ctrl-C
        # landing mid-draw became 'ValueError: Invalid affine transformation matrix'. Held back,
        # it is raised here, after drawing: the unfinished file is discarded.
        with signals_deferred():  # raised here, after drawing: the unfinished file is discarded
            fig.savefig(handle, format=fmt, dpi=dpi, metadata=metadata)
    if close:
        _close(fig)
    return target


def _close(fig: Figure) -> None:
    import sys

    if "matplotlib.pyplot" in sys.modules:  # a figure pyplot manages would stay in its list
        import matplotlib.pyplot as plt

        plt.close(fig)
    fig.clear()
