"""One home for how sonar images are coloured: the colour maps, and their lookup tables.

The default map is perceptually uniform (lightness rises steadily with the echo level, so equal
steps in dB look like equal steps, in print and for colour-blind readers) and dark at zero
(no echo), as a sonar display is. ``grey`` is offered for those who want the device's look.
Figures (:mod:`sonarsim.plot`) and the live viewer colour images through the same tables.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["COLORMAPS", "DEFAULT_COLORMAP", "OUTSIDE_FAN_RGB", "colorize", "colormap_lut"]

#: The default colour map of sonar images (matplotlib's ``inferno``: perceptually uniform,
#: black at zero, readable in grey print).
DEFAULT_COLORMAP = "inferno"
#: Colour maps offered on the command line (any matplotlib name works from Python).
COLORMAPS = ("inferno", "magma", "viridis", "cividis", "grey")
#: Colour of the pixels outside the fan in figures: a light blue-grey, which none of
#: :data:`COLORMAPS` contains (the grey map's greys have r = g = b), so that "outside the fan"
#: never reads as "no echo" (dark) nor as a strong echo.
OUTSIDE_FAN_RGB = (206, 214, 226)


def _mpl_name(name: str) -> str:
    return "gray" if name in ("grey", "gray") else name


@functools.lru_cache(maxsize=16)
def colormap_lut(name: str = DEFAULT_COLORMAP) -> np.ndarray:
    """A colour map as a (256, 3) uint8 table (index: the 8-bit display value).

    Raises
    ------
    ValueError
        An unknown colour map, naming the allowed ones.
    """
    from matplotlib import colormaps

    try:
        cmap = colormaps[_mpl_name(name)]
    except KeyError:
        raise ValueError(f"unknown colour map {name!r}; allowed: {', '.join(COLORMAPS)} or any matplotlib "
                         "colour map name") from None
    table = cmap(np.linspace(0.0, 1.0, 256))[:, :3]
    lut = np.round(table * 255.0).astype(np.uint8)
    lut.setflags(write=False)
    return lut


def colorize(image_uint8: np.ndarray, name: str = DEFAULT_COLORMAP, mask: np.ndarray | None = None,
             outside: tuple[int, int, int] = (255, 255, 255)) -> np.ndarray:
    """Colour an 8-bit display image (:func:`sonarsim.io.output.to_uint8`) through a colour map.

    Parameters
    ----------
    image_uint8 : (H, W) uint8 ndarray
    name : str
        Colour map (:data:`COLORMAPS`, or any matplotlib name).
    mask : (H, W) bool ndarray, optional
        Pixels inside the fan; the others get ``outside`` (so that "outside the fan" and "no
        echo" differ).
    outside : (r, g, b)

    Returns
    -------
    (H, W, 3) uint8 ndarray
    """
    rgb = colormap_lut(name)[np.asarray(image_uint8, dtype=np.uint8)]
    if mask is not None:
        rgb[~np.asarray(mask, dtype=bool)] = np.asarray(outside, dtype=np.uint8)
    return rgb
