"""What :class:`~sonarsim.image.result.SonarImage`, :class:`~sonarsim.image.fan.FanImage` and the
recordings show in a notebook and a console: a small annotated figure (``_repr_png_``), a short
text ``repr`` (never the arrays), and ``plot`` / ``save`` / ``to_pil``.

The classes keep one-line methods that call these functions through the hooks of
:mod:`sonarsim.image.display` (registered by :mod:`sonarsim.plot.hooks`), so that the image types
neither import this package nor matplotlib until a picture is asked for.
"""

from __future__ import annotations

import io
import math
import os
from typing import TYPE_CHECKING, Any

import numpy as np

# The text reprs need no figure: they live with the image types and the recordings
# (re-exported here).
from ..image.display import fan_image_repr, image_repr
from ..io.readers._common import recording_repr
from .style import DEFAULT_COLORMAP

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from PIL import Image as PILImage

__all__ = [
    "KINDS",
    "fan_image_figure",
    "fan_image_plot",
    "fan_image_repr",
    "fan_image_repr_png",
    "fan_image_save",
    "image_plot",
    "image_repr",
    "image_repr_png",
    "image_save",
    "image_to_pil",
    "png_bytes",
    "recording_repr",
]

#: The views of a sonar image: the Cartesian fan, or the polar image (beams x ranges).
KINDS = ("fan", "polar")
# Size of the pictures notebooks show (inches, dpi): small beside the code.
_REPR_DPI = 72


def _check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(map(repr, KINDS))}, got {kind!r}")
    return kind


def png_bytes(fig: Any, dpi: int = _REPR_DPI) -> bytes:
    """A figure as PNG bytes (what a notebook shows); the figure is released afterwards."""
    from .figures import _close

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
    _close(fig)
    return buffer.getvalue()


def _figure(image: Any, kind: str, component: str | None, ax: Any, **options: Any) -> Any:
    from .figures import fan_figure, polar_figure

    builder = fan_figure if _check_kind(kind) == "fan" else polar_figure
    if kind == "polar":
        options.pop("pixel_size_m", None)
    return builder(image, component, ax=ax, **options)


def image_plot(image: Any, ax: Axes | None = None, kind: str = "fan", component: str | None = None,
               **options: Any) -> Axes:
    """Draw a sonar image's annotated figure on ``ax`` (default: a new pyplot figure, which a
    notebook shows) and return the axes. ``options`` go to
    :func:`~sonarsim.plot.figures.fan_figure` or :func:`~sonarsim.plot.figures.polar_figure`
    (``colormap="grey"``, ``mapping``, ``dynamic_range_db``, ``title``, ...)."""
    if ax is None:
        import matplotlib.pyplot as plt

        from .figures import _fan_size

        size = _fan_size(image.sonar) if kind == "fan" else (6.0, 5.0)
        ax = plt.figure(figsize=size, layout="compressed").add_subplot()
    _figure(image, kind, component, ax, **options)
    return ax


def image_save(image: Any, path: str | os.PathLike, kind: str = "fan", component: str | None = None,
               **options: Any) -> None:
    """Write a sonar image's annotated figure; PNG, SVG or PDF from the suffix, atomically."""
    from .figures import save_figure

    save_figure(_figure(image, kind, component, None, **options), path)


def image_to_pil(image: Any, kind: str = "fan", component: str | None = None, mapping: str | None = None,
                 gain_db: float = 0.0, dynamic_range_db: float = 40.0,
                 pixel_size_m: float | None = None) -> PILImage.Image:
    """The exact-pixel image (8-bit grey, as the commands' ``fan.png`` / ``polar.png``): the fan
    at ``pixel_size_m`` (default the range resolution), 0 outside it; or the polar image with
    far range at the top. The mapping is :func:`~sonarsim.plot.figures.default_scale`'s."""
    from PIL import Image

    from .figures import default_scale

    values = image.polar if component is None else np.asarray(image.components[component])
    scale = default_scale(image, mapping, gain_db, dynamic_range_db)
    if _check_kind(kind) == "polar":
        return Image.fromarray(scale.encode(np.asarray(values)[::-1]))
    fan = image.fan(pixel_size_m=pixel_size_m, component=component)
    return Image.fromarray(scale.encode(fan.image, fan.mask))


def image_repr_png(image: Any) -> bytes:
    """The small annotated fan a notebook shows for a sonar image."""
    from .figures import _fan_size, fan_figure

    w, h = _fan_size(image.sonar)
    return png_bytes(fan_figure(image, figsize=(w * 0.8, h * 0.8)))


# ---------------------------------------------------------------------------------- FanImage

def _fan_bounds(fan: Any) -> tuple[float, float, float, float]:
    """(range_min, range_max, left edge, right edge) of a fan image, from the centres of its
    pixels inside the mask (within a pixel of the true window: a FanImage does not keep it)."""
    yy, xx = np.meshgrid(fan.y_m, fan.x_m)
    inside = np.asarray(fan.mask, dtype=bool)
    if not inside.any():
        return 0.0, float(fan.x_m[0]), 0.0, 0.0
    r = np.hypot(xx[inside], yy[inside])
    a = np.degrees(np.arctan2(yy[inside], xx[inside]))
    # Pixel centres lie up to half a diagonal inside the true bounds: widen by that much, so
    # that rings and spokes on the bounds (a 5 m window's 5 m ring) are drawn.
    d = fan.pixel_size_m / math.sqrt(2.0)
    rmax = float(r.max()) + d
    da = math.degrees(d / rmax)
    return max(0.0, float(r.min()) - d), rmax, float(a.max()) + da, float(a.min()) - da


def fan_image_figure(fan: Any, ax: Axes | None = None, *, mapping: str = "db", gain_db: float = 0.0,
                     dynamic_range_db: float = 40.0, colormap: str = DEFAULT_COLORMAP, title: str | None = None,
                     figsize: tuple[float, float] = (4.5, 5.0)) -> Any:
    """The annotated figure of a bare :class:`~sonarsim.image.fan.FanImage` (metres, rings,
    spokes, outline, colour bar in dB re its maximum).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .figures import DisplayScale, _colorbar, _new_figure, draw_fan_image

    if ax is None:
        fig = _new_figure(figsize)
        ax = fig.add_subplot()
    else:
        fig = ax.figure
    scale = DisplayScale(mapping, gain_db, dynamic_range_db).resolved(np.where(fan.mask, fan.image, 0.0))
    draw_fan_image(ax, fan, scale, _fan_bounds(fan), colormap=colormap)
    _colorbar(fig, ax, scale, colormap)
    h, w = fan.shape
    ax.set_title(title if title is not None else f"fan image, {w} x {h} pixels of {fan.pixel_size_m * 1000:.3g} mm",
                 fontsize=9)
    return fig


def fan_image_plot(fan: Any, ax: Axes | None = None, **options: Any) -> Axes:
    """Draw a FanImage's annotated figure (:func:`fan_image_figure`) on ``ax`` (default: a new
    pyplot figure, which a notebook shows) and return the axes."""
    if ax is None:
        import matplotlib.pyplot as plt

        ax = plt.figure(figsize=(4.5, 5.0), layout="compressed").add_subplot()
    fan_image_figure(fan, ax, **options)
    return ax


def fan_image_save(fan: Any, path: str | os.PathLike, **options: Any) -> None:
    """Write a FanImage's annotated figure; PNG, SVG or PDF from the suffix, atomically."""
    from .figures import save_figure

    save_figure(fan_image_figure(fan, **options), path)


def fan_image_repr_png(fan: Any) -> bytes:
    """What a notebook shows for a FanImage: its annotated fan (dB re its maximum)."""
    return png_bytes(fan_image_figure(fan))
