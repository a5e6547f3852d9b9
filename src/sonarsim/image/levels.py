"""Display levels: a sonar intensity image mapped to 8-bit values (dB or linear).

The one place where intensities become display levels: the exact-pixel PNGs
(:mod:`sonarsim.io.output`, which re-exports :func:`to_uint8`), the figures'
colours (:mod:`sonarsim.plot`) and :meth:`FanImage.to_pil <sonarsim.image.fan.FanImage.to_pil>`.
Pure array functions, here in the image layer so that the image types can use them without
importing :mod:`sonarsim.io`.

What an image is drawn on unless told otherwise (:func:`default_levels`) is decided here too:
a device's output -- a sensor model's render, a real recording -- is already compressed by the
device (an Oculus's gamma, an ARIS's 0-80 dB onto 0-255), so it is drawn in its counts, linearly
against the output type's full scale, as the device's own software and a real recording's PNG
show it; a dB mapping on top would compress it twice (median pixel 240 of 255: a pale image in
which objects hide). A render without a sensor model is in echo intensity and drawn in dB below
its maximum.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MAPPINGS", "default_fan_levels", "default_levels", "device_full_scale", "to_uint8"]

#: Intensity mappings accepted by :func:`to_uint8`.
MAPPINGS = ("db", "linear")


def to_uint8(
    image: np.ndarray,
    mapping: str = "db",
    gain_db: float = 0.0,
    dynamic_range_db: float = 60.0,
    reference: float | None = None,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Map a sonar intensity image to 8-bit display values.

    The intensity ``I`` is treated as a power-like quantity (echo intensity), so decibels
    are ``10*log10`` and a gain of ``gain_db`` multiplies intensity by ``10**(gain_db/10)``
    in both mappings. With this choice a pixel saturates (255) in the linear mapping exactly
    when it reaches 0 dB in the dB mapping.

    * ``"linear"``: ``v = clip(10**(gain_db/10) * I / ref, 0, 1)``
    * ``"db"``: ``d = 10*log10(I / ref) + gain_db`` (``-inf`` for ``I <= 0``), then
      ``v = clip((d + dynamic_range_db) / dynamic_range_db, 0, 1)``, i.e. the window
      ``[-dynamic_range_db, 0]`` dB maps linearly onto ``[0, 1]``.

    The output is ``floor(255 * v + 0.5)`` (round half up). Zero, negative and NaN
    intensities give 0; ``+inf`` gives 255. ``ref`` is ``reference`` if given, else the
    largest finite intensity (inside ``mask`` if given). If that is not positive (e.g. an
    all-zero image) the result is all zeros, without warnings.

    Parameters
    ----------
    image : array_like, any shape, real
        Intensity, linear units (any scale; only ratios to ``ref`` matter).
    mapping : {"db", "linear"}
        Intensity mapping, see above.
    gain_db : float
        Display gain, dB (intensity dB: +10 dB = x10 intensity).
    dynamic_range_db : float
        Width of the displayed dB window, > 0. Only used by ``"db"``.
    reference : float, optional
        Intensity mapped to full scale at zero gain, > 0. Default: the image maximum. Pass a
        fixed value to keep the brightness comparable across frames.
    mask : array_like of bool, same shape as ``image``, optional
        Pixels where ``mask`` is False are set to 0 (e.g. outside a sonar fan) and do not
        take part in the default reference.

    Returns
    -------
    np.ndarray, same shape as ``image``, uint8

    Raises
    ------
    ValueError
        For an unknown mapping, a non-finite gain, a non-positive dynamic range or reference,
        a non-real image, or a mask of another shape.
    """
    if mapping not in MAPPINGS:
        raise ValueError(
            f"mapping must be one of {', '.join(map(repr, MAPPINGS))}, got {mapping!r}"
        )
    gain_db = float(gain_db)
    if not math.isfinite(gain_db):
        raise ValueError(f"gain_db must be finite, got {gain_db!r}")
    dynamic_range_db = float(dynamic_range_db)
    if not (math.isfinite(dynamic_range_db) and dynamic_range_db > 0.0):
        raise ValueError(f"dynamic_range_db must be finite and > 0, got {dynamic_range_db!r}")

    arr = np.asarray(image)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"image must be a real-valued array, got dtype {arr.dtype}")
    # float64 so that huge dynamic ranges and log10 keep their precision whatever came in.
    intensity = arr.astype(np.float64, copy=False)

    inside: np.ndarray | None = None
    if mask is not None:
        inside = np.asarray(mask, dtype=bool)
        if inside.shape != intensity.shape:
            raise ValueError(
                f"mask must have the image's shape {intensity.shape}, got {inside.shape}"
            )

    if reference is None:
        usable = np.isfinite(intensity)
        if inside is not None:
            usable &= inside
        candidates = intensity[usable]
        ref = float(candidates.max()) if candidates.size else 0.0
    else:
        ref = float(reference)
        if not (math.isfinite(ref) and ref > 0.0):
            raise ValueError(f"reference must be finite and > 0, got {reference!r}")

    out = np.zeros(intensity.shape, dtype=np.uint8)
    if not ref > 0.0:
        # Nothing to show (all zero/negative/NaN); avoid dividing by zero.
        return out

    # Only positive intensities can be non-zero on output; selecting them first keeps log10
    # away from zeros/negatives/NaN, so no RuntimeWarning is ever emitted.
    lit = intensity > 0.0
    if inside is not None:
        lit &= inside
    ratio = intensity[lit] / ref
    if mapping == "linear":
        v = ratio * 10.0 ** (gain_db / 10.0)
    else:
        d = 10.0 * np.log10(ratio) + gain_db
        v = (d + dynamic_range_db) / dynamic_range_db
    v = np.clip(v, 0.0, 1.0)
    out[lit] = np.floor(v * 255.0 + 0.5).astype(np.uint8)
    return out


def device_full_scale(image: Any) -> float | None:
    """Full-scale value of a device's output, or ``None`` for a render in intensity units.

    A render through a sensor model (its configuration has a ``sensor`` section) gives the output
    type's full scale (255, 65535, 1.0); a real recording 255 for 8-bit data and its frame's
    maximum for wider data (as ``sonarsim show`` does).
    """
    config = getattr(image, "config", None) or {}
    sensor = config.get("sensor")
    if isinstance(sensor, dict):
        dtype = (sensor.get("output") or {}).get("dtype", "uint8")
        return {"uint8": 255.0, "uint16": 65535.0}.get(dtype, 1.0)
    if "format" in config:  # a recording (sonarsim.io.readers)
        bits = (config.get("header") or {}).get("bits_per_value", 8)
        if bits == 8:
            return 255.0
        peak = float(np.max(image.polar)) if np.size(image.polar) else 0.0
        return peak if peak > 0.0 else 1.0
    return None


def default_levels(image: Any, values: np.ndarray, mask: np.ndarray | None = None, mapping: str | None = None,
                   gain_db: float = 0.0, dynamic_range_db: float = 40.0) -> np.ndarray:
    """8-bit display levels of ``values`` (the polar image, a fan, a component of ``image``) as
    sonarsim draws ``image`` unless told otherwise (see the module notes).

    Parameters
    ----------
    image : SonarImage
        Whose configuration says whether ``values`` are a device's counts
        (:func:`device_full_scale`).
    values : array_like, any shape
    mask : array_like of bool, optional
        As :func:`to_uint8`.
    mapping : {'db', 'linear'}, optional
        Default: ``linear`` for device output (against its full scale: an 8-bit device's counts
        are the PNG's values), ``db`` for a render (below the image's maximum).
    gain_db, dynamic_range_db : float
        As :func:`to_uint8`.

    Returns
    -------
    np.ndarray, uint8, the shape of ``values``
    """
    full = device_full_scale(image)
    if full is not None:
        return to_uint8(values, mapping or "linear", gain_db, dynamic_range_db, full, mask)
    return to_uint8(values, mapping or "db", gain_db, dynamic_range_db, None, mask)


def default_fan_levels(image: Any, mapping: str | None = None, gain_db: float = 0.0,
                       dynamic_range_db: float = 40.0) -> np.ndarray:
    """The fan as sonarsim draws it (``fan.png``, a dataset's fan PNG, a live or bag ``mono8``
    fan): :func:`default_levels` of the polar image, on the polar grid, resampled to the fan
    (:meth:`SonarImage.fan_levels <sonarsim.image.result.SonarImage.fan_levels>`).

    Returns
    -------
    (height, width) uint8 ndarray
    """
    return image.fan_levels(default_levels(image, image.polar, None, mapping, gain_db, dynamic_range_db))

