"""What an image's values are: its unit, from the configuration that made it.

===================== ========== =============================================================
unit                  symbol     the value of a pixel (range bin x beam)
===================== ========== =============================================================
``backscatter``       rad^-1     without a sensor, TVG on (``render.tvg``): the sum over the bin
                                 of ``sigma dA / r^2`` (each scattering element's
                                 backscattering cross-section per steradian over the square of
                                 its range: the solid angle it fills) per radian of the beam's
                                 azimuth width; ``10 log10(value * width_rad * r^2)`` is the
                                 bin's target strength, dB re 1 m^2 (tested on a sphere)
``backscatter_per_r2`` m^-2 rad^-1 without a sensor, TVG off: that over ``r^2`` again (the
                                 two-way spherical spreading left in)
``uPa^2``             uPa^2      a sensor without ``output``: the received mean-square pressure
                                 after TVG and gain; ``10 log10`` is dB re 1 uPa^2
``counts``            counts     a sensor with ``output``, or a recording: the device's values
                                 (its compression of the received level, its data type)
``uPa``               uPa        a recording's backscatter amplitude re 1 uPa (an R2Sonic's
                                 soundings)
``cross_section_per_r2`` 1       a single-beam's envelope without a sensor: the backscatter
                                 summed over the whole beam (times r^2: the bin's m^2)
===================== ========== =============================================================

:func:`unit_of` reads it from an image's configuration (scene-file form, or a reader's
``{"format": ...}``); :attr:`SonarImage.unit <sonarsim.image.result.SonarImage.unit>` is that.
NPZ files hold it as ``unit`` (a string), ROS 2 bags on the image topic's ``/unit`` topic
(``std_msgs/String``), figures in the colour bar's label. The instruments' films (waterfall,
soundings, envelope, scan) carry theirs as ``unit_name`` (:attr:`unit` the :class:`Unit`):
:func:`instrument_unit` for a render, the device's for a recording; their NPZ files hold it as
``unit``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping


@dataclass(frozen=True)
class Unit:
    """An image's unit.

    Attributes
    ----------
    name : str
        A key of :data:`UNITS`: ``backscatter``, ``backscatter_per_r2``, ``uPa^2``, ``counts``,
        ``uPa`` or ``cross_section_per_r2``.
    symbol : str
        As written after a number (``1`` for dimensionless).
    description : str
        One line: what a pixel's value is.
    """

    name: str
    symbol: str
    description: str

    @property
    def label(self) -> str:
        """Short text for a figure's axis or colour bar."""
        return {"backscatter": "sigma / r^2 per bin and radian of beam", "backscatter_per_r2": "sigma / r^4 per bin and radian",
                "uPa^2": "received power, uPa^2", "counts": "device counts", "uPa": "backscatter, uPa",
                "cross_section_per_r2": "sigma / r^2 per bin over the beam"}[self.name]


UNITS: dict[str, Unit] = {
    "backscatter": Unit("backscatter", "rad^-1", "sum over the bin of sigma dA / r^2 per radian of beam width "
                        "(backscattering cross-section per steradian in the solid angle each element fills); times the "
                        "beam's width in radians and r^2: the bin's backscattering cross-section, m^2 (10 log10: its "
                        "target strength)"),
    "backscatter_per_r2": Unit("backscatter_per_r2", "m^-2 rad^-1", "sum over the bin of sigma dA / r^4 per radian of "
                               "beam width (render.tvg false: the two-way spreading left in)"),
    "uPa^2": Unit("uPa^2", "uPa^2", "received mean-square pressure after TVG and gain, re 1 uPa^2 (the sensor model "
                  "without output)"),
    "counts": Unit("counts", "counts", "the device's output values (the sensor model's output, or a recording)"),
    "cross_section_per_r2": Unit("cross_section_per_r2", "1", "sum over the bin of sigma dA / r^2 over the whole beam "
                                 "(a single-beam's envelope without a sensor); times r^2: the bin's backscattering "
                                 "cross-section, m^2 (render.tvg false: over r^2 again)"),
    "uPa": Unit("uPa", "uPa", "a recording's backscatter amplitude at the receiver, re 1 uPa (an R2Sonic's "
                "soundings)"),
}


def instrument_unit(sensor: Any, tvg: bool = True) -> Unit:
    """The unit of an instrument's rendered film: its sensor chain's (``sensor``: a
    :class:`~sonarsim.config.sensor.SensorSpec` or None), or without one the engine's image
    (``tvg``: ``render.tvg``)."""
    if sensor is not None:
        return UNITS["counts"] if sensor.output is not None else UNITS["uPa^2"]
    return UNITS["backscatter"] if tvg else UNITS["backscatter_per_r2"]


def check_unit(name: Any, where: str) -> str:
    """``name`` if it names a unit of :data:`UNITS`, else ValueError naming ``where``."""
    if name not in UNITS:
        raise ValueError(f"{where}: unit must be one of {', '.join(UNITS)}, got {name!r}")
    return name


def unit_of(config: Mapping[str, Any] | None) -> Unit:
    """The unit of an image made with ``config`` (a scene's :meth:`~sonarsim.Scene.to_dict`
    form, or a recording reader's ``{"format": ...}``; see the module's table)."""
    config = config if isinstance(config, Mapping) else {}
    if "format" in config and "sonar" not in config and "instruments" not in config:
        return UNITS["counts"]  # a recording: the device's own values
    sensor = config.get("sensor")
    if isinstance(sensor, Mapping):
        return UNITS["counts"] if sensor.get("output") else UNITS["uPa^2"]
    render = config.get("render")
    tvg = render.get("tvg", True) if isinstance(render, Mapping) else True
    return UNITS["backscatter"] if tvg else UNITS["backscatter_per_r2"]
