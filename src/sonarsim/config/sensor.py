"""The sensor's configuration: the ``sensor:`` section of a scene file, and its device presets.

The renderer forms the paper's noise-free image: the expected backscatter of each range bin
and beam, with range compensated (``l(r) = 1``). The sensor stage
(:mod:`sonarsim.sensor`) turns it into what a device outputs: the sonar equation in dB, beam
patterns, the pulse's range spread, coherent speckle, receiver noise, the transmit bang, TVG,
gain, compression and quantisation. Every effect is a sub-section; a missing or ``false``
sub-section is off. With no ``sensor:`` section at all the image is the renderer's, unchanged.

Units: levels in dB re 1 uPa (at 1 m for the source level), powers in uPa^2; frequencies in
kHz; lengths in metres; angles in degrees; pulse lengths in microseconds.

Example::

    sensor:
      preset: oculus-m1200d-2100      # optional; keys given here override the preset's
      source_level_db: 190
      absorption: {model: francois-garrison, temperature_c: 15, salinity_psu: 0, depth_m: 2}
      tvg: {spreading: 20, absorption: true}
      elevation_pattern: {shape: line, width_deg: 12, window: rect, span_deg: 60}
      azimuth_pattern: {shape: line, width_deg: 0.6, window: hann}
      pulse: {kind: cw, length_us: 10}
      speckle: {model: rayleigh, anchor: world}
      noise: {level_db: 50}
      bang: {level_db: 120, length_m: 0.02}
      beam_gain: {steering_exponent: 2, std_db: 0.5}
      output: {compression: gamma, gamma: 0.3, ceiling_db: 150, dtype: uint8}
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from ..errors import ConfigError, SonarsimError, check_input_file, key_text, shown
from .parameters import (GAIN_RANGE_DB, GAMMA_RANGE, LEVEL_RANGE_DB, LOOKS_RANGE, NEAR_RANGE_LENGTH_M,  # noqa: F401
                         PATTERN_WIDTH_RANGE_DEG, PER_BEAM_RANGE_DB, PULSE_LENGTH_RANGE_US,
                         STEERING_EXPONENT_RANGE, TVG_SPREADING)
from .presets import ARIS_MODES, PRESETS, ArisMode
from .sonar import FREQUENCY_RANGE_KHZ, MIN_BEAM_WIDTH_DEG

ABSORPTION_MODELS = ("francois-garrison", "ainslie-mccolm", "constant")
PATTERN_SHAPES = ("line", "gaussian", "table")
WINDOWS = ("rect", "hann", "hamming", "blackman", "taylor")
PULSE_KINDS = ("cw", "chirp")
SPECKLE_MODELS = ("rayleigh", "k")
SPECKLE_ANCHORS = ("frame", "world")
COMPRESSIONS = ("log", "gamma", "linear")
DTYPES = {"uint8": 255.0, "uint16": 65535.0, "float32": None}

# Sizes checked before allocating: a kernel wider than this many beams or range bins is a typo.
MAX_KERNEL_HALF_WIDTH = 256
# A Taylor window's sidelobe level: beyond 13.3 dB (the uniform array's), and no deeper than this
# (no array gets near it; near 6000 dB the window's own arithmetic overflows).
MIN_SIDELOBE_DB, MAX_SIDELOBE_DB = 13.3, 200.0
# The bounds of the fittable levels, gains, widths, lengths and looks live in the one table
# of fittable parameters (config.parameters), imported above.
MAX_ABSORPTION_DB_PER_M = 1000.0
# The azimuth pattern is averaged over 16 points across each beam (sensor.patterns.azimuth_kernels):
# a -3 dB width below two of those steps aliases its sidelobes (a 0.01-degree line pattern over
# beams 10 degrees apart leaked half of each echo into either neighbour and kept 5 %).
MIN_AZIMUTH_WIDTH_PER_SPACING = 1.0 / 8.0
# Seeded stripes of more than 20 dB standard deviation are a typo for a level.
PER_BEAM_STD_RANGE_DB = (0.0, 20.0)


def _within(key: str, value: Any, bounds: tuple[float, float], unit: str = "dB") -> float:
    v = _finite(key, value)
    if not bounds[0] <= v <= bounds[1]:
        raise ConfigError(key, f"must be within [{bounds[0]:g}, {bounds[1]:g}] {unit}, got {v:g}")
    return v


def _check_sidelobe(window: str, sidelobe_db: Any) -> None:
    """``sidelobe_db`` is given exactly for a Taylor window, within (13.3, 200] dB."""
    if window == "taylor":
        if sidelobe_db is None or not MIN_SIDELOBE_DB < _finite("sidelobe_db", sidelobe_db) <= MAX_SIDELOBE_DB:
            raise ConfigError("sidelobe_db", f"window taylor needs sidelobe_db in ({MIN_SIDELOBE_DB:g}, "
                              f"{MAX_SIDELOBE_DB:g}] (dB below the main lobe), got {shown(sidelobe_db)}")
    elif sidelobe_db is not None:
        raise ConfigError("sidelobe_db", "only with window: taylor (the other windows fix their sidelobes)")


def _finite(key: str, value: Any) -> float:
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer))
            or (isinstance(value, int) and abs(value) > sys.float_info.max) or not math.isfinite(value)):
        raise ConfigError(key, f"must be a finite number, got {shown(value)}")
    return float(value)


def _positive(key: str, value: Any) -> float:
    v = _finite(key, value)
    if v <= 0:
        raise ConfigError(key, f"must be positive, got {shown(value)}")
    return v


def _choice(key: str, value: Any, allowed) -> Any:
    if value not in allowed:
        raise ConfigError(key, f"unknown value {shown(value)}; allowed: {', '.join(map(str, allowed))}")
    return value


def _per_beam_db(key: str, value: Any) -> tuple[float, ...] | None:
    """A list of per-beam values in dB (left-most beam first) as a tuple, each within
    :data:`PER_BEAM_RANGE_DB`; ``None`` stays ``None``. Its length is checked against a sonar by
    :func:`check_beam_count` (the spec does not know the sonar)."""
    if value is None:
        return None
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (list, tuple, np.ndarray)):
        raise ConfigError(key, f"must be a list of numbers in dB, one per beam (left-most first), got {shown(value)}")
    if len(value) == 0:
        raise ConfigError(key, "must hold one value per beam, got an empty list")
    return tuple(_within(f"{key}[{i}]", v, PER_BEAM_RANGE_DB) for i, v in enumerate(value))


def _length_m(key: str, value: Any) -> float:
    return _within(key, value, NEAR_RANGE_LENGTH_M, "m")


@dataclass(frozen=True)
class AbsorptionSpec:
    """Frequency-dependent absorption of sound in water, alpha (dB/m, one way).

    Attributes
    ----------
    model : {'francois-garrison', 'ainslie-mccolm', 'constant'}
        Francois & Garrison (1982, JASA 72: boric acid, MgSO4, pure water) or Ainslie &
        McColm (1998, JASA 103) at the sonar's ``frequency_khz``; ``constant``: ``db_per_m``.
    db_per_m : float or None
        alpha for ``constant``, within [0, 1000] dB/m.
    temperature_c, salinity_psu, depth_m, ph : float
        Water properties (fresh water: salinity 0).
    """

    model: str = "francois-garrison"
    db_per_m: float | None = None
    temperature_c: float = 10.0
    salinity_psu: float = 35.0
    depth_m: float = 5.0
    ph: float = 8.0

    def __post_init__(self) -> None:
        _choice("model", self.model, ABSORPTION_MODELS)
        if self.model == "constant":
            if self.db_per_m is None:
                raise ConfigError("db_per_m", "required with model: constant (alpha in dB/m)")
            _within("db_per_m", self.db_per_m, (0.0, MAX_ABSORPTION_DB_PER_M), "dB/m")
        elif self.db_per_m is not None:
            raise ConfigError("db_per_m", f"only with model: constant (model {shown(self.model)} computes alpha)")
        t = _finite("temperature_c", self.temperature_c)
        if not -2.0 <= t <= 40.0:
            raise ConfigError("temperature_c", f"must be within [-2, 40] degC (the formulas' range), got {t}")
        s = _finite("salinity_psu", self.salinity_psu)
        if not 0.0 <= s <= 45.0:
            raise ConfigError("salinity_psu", f"must be within [0, 45], got {s}")
        z = _finite("depth_m", self.depth_m)
        if not 0.0 <= z <= 11000.0:
            raise ConfigError("depth_m", f"must be within [0, 11000] m, got {z}")
        p = _finite("ph", self.ph)
        if not 6.0 <= p <= 9.0:
            raise ConfigError("ph", f"must be within [6, 9], got {p}")


@dataclass(frozen=True)
class TvgSpec:
    """Time-variant gain: ``spreading * log10(r) + 2 alpha r`` dB added to the received level.

    Attributes
    ----------
    spreading : {0, 20, 30, 40}
        dB per decade of range (40: point targets, 30: area, 20: volume scattering).
    absorption : bool
        Also add back the two-way absorption ``2 alpha r``.
    correction_db : list of float or None
        The range law's departure from ``spreading log10 r + 2 alpha r``, dB, at ranges evenly
        spaced over ``correction_range_m`` (2 to 256 values, each within [-60, 60] dB),
        interpolated linearly in power between them and held at the end values beyond: a real
        device's TVG curve is no ideal law, and over a flat floor the sea bed's angular response
        (its backscatter against the grazing angle, a function of range alone there) departs
        from Lambert's (``sonarsim calibrate`` fits it).
    correction_range_m : (float, float) or None
        First and last knot (m), first < last; required with ``correction_db``.
    """

    spreading: float = 40.0
    absorption: bool = True
    correction_db: tuple[float, ...] | None = None
    correction_range_m: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        _choice("spreading", _finite("spreading", self.spreading), TVG_SPREADING)
        if not isinstance(self.absorption, bool):
            raise ConfigError("absorption", f"must be true or false, got {shown(self.absorption)}")
        c, span = self.correction_db, self.correction_range_m
        if c is not None:
            if isinstance(c, (str, bytes)) or not hasattr(c, "__len__") or not 2 <= len(c) <= 256:
                raise ConfigError("correction_db", f"must be a list of 2 to 256 numbers (dB), got {shown(c)}")
            object.__setattr__(self, "correction_db", tuple(_within(f"correction_db[{i}]", x, (-60.0, 60.0))
                                                            for i, x in enumerate(c)))
            if span is None:
                raise ConfigError("correction_range_m", "required with correction_db: [first, last] knot in metres")
        if span is not None:
            if c is None:
                raise ConfigError("correction_range_m", "only with correction_db")
            if isinstance(span, (str, bytes)) or not hasattr(span, "__len__") or len(span) != 2:
                raise ConfigError("correction_range_m", f"must be [first, last] in metres, got {shown(span)}")
            a = _within("correction_range_m[0]", span[0], (0.0, 1e4), "m")
            b = _within("correction_range_m[1]", span[1], (0.0, 1e4), "m")
            if not a < b:
                raise ConfigError("correction_range_m", f"the first knot must be nearer than the last, got [{a:g}, {b:g}]")
            object.__setattr__(self, "correction_range_m", (a, b))


@dataclass(frozen=True)
class PatternSpec:
    """A beam pattern: elevation (transmit x receive) or azimuth (each receive beam).

    Attributes
    ----------
    shape : {'line', 'gaussian', 'table'}
        ``line``: a line array with an aperture ``window`` (``rect``: sinc, first sidelobe
        -13.3 dB one way; ``taylor`` with ``sidelobe_db``), scaled to ``width_deg``;
        ``gaussian``: no sidelobes; ``table``: measured ``(angle_deg, gain_db)`` rows in a CSV file.
    width_deg : float or None
        Full width at -3 dB of the pattern as it acts (two-way in elevation, one-way receive in
        azimuth), within [0.01, 180) degrees. Default: the sonar's ``elevation_fov_deg`` / beam
        width.
    window : {'rect', 'hann', 'hamming', 'blackman', 'taylor'}
    sidelobe_db : float or None
        ``taylor`` only: the sidelobe level below the main lobe, dB, in (13.3, 200].
    span_deg : float or None
        Elevation only: rays are cast over this full span (wider than the -3 dB width so that
        sidelobes see what the main lobe misses), within [0.01, 170] degrees. Default: three
        times ``width_deg``.
    table : str or None
        ``table`` only: the CSV file (relative to the scene file), angle_deg and gain_db
        columns, gain 0 dB on axis.
    correction_db : list of float or None
        Elevation only: the pattern's departure from its shape, dB, at angles evenly spaced over
        the span (first at ``-span_deg / 2``, last at ``+span_deg / 2``; 2 to 256 values, each
        within [-300, 60] dB), interpolated linearly in power between them: a real
        transducer's pattern is no ideal array's (``sonarsim calibrate`` fits it).
    leakage_beams : int or None
        Azimuth only: how many beams either side a beam's sidelobes reach. Default: as far as
        the leakage stays above -40 dB of the main beam, at most eight -3 dB widths (a uniform
        array's sidelobes are then below -28 dB) and 256 beams.
    steering_loss : bool
        Azimuth only: the receive beams are steered electronically (a phased array), so beam k
        at azimuth ``theta_k`` sees the array's aperture foreshortened to ``L cos(theta_k)``:
        its directivity falls by ``10 log10(cos(theta_k))`` (-3 dB at 60 degrees, -3.7 at 65;
        Urick, *Principles of Underwater Sound*, 3rd ed., sect. 3.7). (The steered beam's
        widening by ``1 / cos(theta_k)`` is that of beams evenly spaced in sine, as the Oculus
        presets' are, whose leakage kernel is the same in beams at every steer: each beam's
        cell, and with it what it hears of an even floor, widens so, and makes up for the loss
        there, as a foreshortened aperture's does; a point target keeps the loss. Beams evenly
        spaced in angle, as the Gemini and BlueView presets' are, do not widen here: their
        floor falls by the loss too.)
    """

    shape: str = "line"
    width_deg: float | None = None
    window: str = "rect"
    sidelobe_db: float | None = None
    span_deg: float | None = None
    table: str | None = None
    leakage_beams: int | None = None
    correction_db: tuple[float, ...] | None = None
    steering_loss: bool = False

    def __post_init__(self) -> None:
        _choice("shape", self.shape, PATTERN_SHAPES)
        if not isinstance(self.steering_loss, (bool, np.bool_)):
            raise ConfigError("steering_loss", f"must be true or false, got {shown(self.steering_loss)}")
        if self.correction_db is not None:
            c = self.correction_db
            if isinstance(c, (str, bytes)) or not hasattr(c, "__len__") or not 2 <= len(c) <= 256:
                raise ConfigError("correction_db", f"must be a list of 2 to 256 numbers (dB), got {shown(c)}")
            object.__setattr__(self, "correction_db", tuple(_within(f"correction_db[{i}]", x, (-300.0, 60.0))
                                                            for i, x in enumerate(c)))
        _choice("window", self.window, WINDOWS)
        lo, hi = PATTERN_WIDTH_RANGE_DEG
        if self.width_deg is not None:
            w = _finite("width_deg", self.width_deg)
            if not lo <= w < hi:
                raise ConfigError("width_deg", f"must be within [{lo:g}, {hi:g}) degrees (the -3 dB full width), "
                                  f"got {shown(self.width_deg)}")
        _check_sidelobe(self.window, self.sidelobe_db)
        if self.span_deg is not None:
            s = _finite("span_deg", self.span_deg)
            if not lo <= s <= 170:
                raise ConfigError("span_deg", f"must be within [{lo:g}, 170] degrees, got {shown(self.span_deg)}")
        if (self.shape == "table") != (self.table is not None):
            raise ConfigError("table", "give a table file exactly when shape is 'table'")
        lb = self.leakage_beams
        if lb is not None and (isinstance(lb, bool) or not isinstance(lb, (int, np.integer))
                               or not 0 <= lb <= MAX_KERNEL_HALF_WIDTH):
            raise ConfigError("leakage_beams", f"must be an integer in [0, {MAX_KERNEL_HALF_WIDTH}], got {shown(lb)}")


@dataclass(frozen=True)
class PulseSpec:
    """The transmitted pulse, which sets the range point-spread.

    Attributes
    ----------
    kind : {'cw', 'chirp'}
        ``cw``: a gated sine of ``length_us``; its echo envelope spans ``c tau / 2`` in range.
        ``chirp``: a linear FM sweep of ``bandwidth_khz`` after matched filtering: main lobe
        ``c / (2 B)`` wide, range sidelobes set by the spectral ``window``.
    length_us : float
        Within [0.1, 100000] microseconds.
    bandwidth_khz : float or None
        ``chirp`` only: within (0, 100000] kHz, and at most the carrier frequency
        (``sensor.frequency_khz`` or ``sonar.frequency_khz``, checked by the scene): a sweep of
        an octave about the carrier at the widest.
    window : {'rect', 'hann', 'hamming', 'blackman', 'taylor'}
    sidelobe_db : float or None
    """

    kind: str = "cw"
    length_us: float = 10.0
    bandwidth_khz: float | None = None
    window: str = "hann"
    sidelobe_db: float | None = None

    def __post_init__(self) -> None:
        _choice("kind", self.kind, PULSE_KINDS)
        _within("length_us", self.length_us, PULSE_LENGTH_RANGE_US, "us")
        _choice("window", self.window, WINDOWS)
        if self.kind == "chirp":
            if self.bandwidth_khz is None:
                raise ConfigError("bandwidth_khz", "required with kind: chirp")
            b = _positive("bandwidth_khz", self.bandwidth_khz)
            if b > FREQUENCY_RANGE_KHZ[1]:
                raise ConfigError("bandwidth_khz", f"must be within (0, {FREQUENCY_RANGE_KHZ[1]:g}] kHz, got {b:g}")
        elif self.bandwidth_khz is not None:
            raise ConfigError("bandwidth_khz", "only with kind: chirp")
        _check_sidelobe(self.window, self.sidelobe_db)


@dataclass(frozen=True)
class SpeckleSpec:
    """Coherent speckle.

    Attributes
    ----------
    model : {'rayleigh', 'k'}
        ``rayleigh``: many scatterers per resolution cell (complex Gaussian amplitudes,
        exponential intensity). ``k``: few scatterers: the intensity of each cell is also
        modulated by a gamma-distributed texture of shape ``k_shape`` (K-distribution).
    k_shape : float
        The K-distribution's shape (number of effective scatterers); large -> Rayleigh.
    anchor : {'frame', 'world'}
        ``frame``: drawn afresh every frame from the frame's seed. ``world``: a function of the
        sonar's pose (quantised to half a resolution cell): a still sonar over a still scene
        sees still speckle, and moving it decorrelates the speckle.
    looks : float
        The number of independent looks the device averages in intensity (pings, sub-apertures,
        frequency bands), within [1, 64]: the speckle intensity's contrast (std / mean) is
        ``1 / sqrt(looks)`` (gamma law of shape ``looks`` for an integer; a real number is the
        equivalent number of looks, its contrast exact). 1: single-look speckle (exponential
        intensity). The K model's texture is common to the looks (the same scatterers).
    """

    model: str = "rayleigh"
    k_shape: float = 4.0
    anchor: str = "frame"
    looks: float = 1.0

    def __post_init__(self) -> None:
        _choice("model", self.model, SPECKLE_MODELS)
        if _positive("k_shape", self.k_shape) < 0.1:
            raise ConfigError("k_shape", f"must be at least 0.1 (effective scatterers per cell), got {self.k_shape}")
        _choice("anchor", self.anchor, SPECKLE_ANCHORS)
        _within("looks", self.looks, LOOKS_RANGE, unit="looks")

    @property
    def exponential(self) -> bool:
        """Fully developed single-look speckle: the unit intensity is exponential (closed forms hold)."""
        return self.model == "rayleigh" and float(self.looks) == 1.0


@dataclass(frozen=True)
class NoiseSpec:
    """Receiver noise: complex Gaussian, added before detection and TVG.

    Attributes
    ----------
    level_db : float
        Noise power at the receiver input, dB re 1 uPa^2 (the level an echo must exceed),
        within [-300, 300].
    after_tvg_db : float or None
        Noise added after the TVG and gain (the digitiser's), dB re 1 uPa^2 on the output's
        scale (that of ``output.ceiling_db``): a floor the TVG does not lift, which sets the
        darkest ranges of a device with a steep TVG, within [-300, 300]. ``None``: none.
    common_db : float or None
        A component common to every beam of a range bin (interference and cross-talk reaching
        all channels alike, which the real water column shows near the sonar): its power at
        range 0, dB re 1 uPa^2 at the receiver (before the TVG, like ``level_db``), within
        [-300, 300]. ``None``: none.
    common_length_m : float or None
        The range over which the common component's power decays by 1/e, within [1e-4, 1e4] m;
        ``None``: it does not decay. Only with ``common_db``.
    """

    level_db: float = 40.0
    after_tvg_db: float | None = None
    common_db: float | None = None
    common_length_m: float | None = None

    def __post_init__(self) -> None:
        _within("level_db", self.level_db, LEVEL_RANGE_DB)
        if self.after_tvg_db is not None:
            _within("after_tvg_db", self.after_tvg_db, LEVEL_RANGE_DB)
        if self.common_db is not None:
            _within("common_db", self.common_db, LEVEL_RANGE_DB)
        if self.common_length_m is not None:
            if self.common_db is None:
                raise ConfigError("common_length_m", "only with common_db (the level of the noise common to all beams)")
            _length_m("common_length_m", self.common_length_m)


@dataclass(frozen=True)
class BangSpec:
    """The transmit bang: the transducer ringing after the pulse, bright at the first ranges.

    Its power is a range profile times a pattern across beams that repeats from ping to ping
    (each channel picks up the transmission differently):
    ``bang(r, j) = [L exp(-max(r - hold_m, 0) / length_m) + R exp(-r / ringing_length_m) ring(r)] 10^(b_j / 10)``
    with ``ring(r) = cos^2(pi r / ringing_period_m)`` (1 without a period) and ``b_j`` the
    pattern in dB (:mod:`sonarsim.sensor.channels`).

    Attributes
    ----------
    level_db : float
        L: its level at range 0, dB re 1 uPa^2 at the receiver (before TVG), within [-300, 300].
    length_m : float
        Range over which it decays by 1/e (in power).
    hold_m : float
        Range over which it holds its level before decaying (the transmission itself: the
        receiver hears the transmitter for the pulse's length, ``c tau / 2``), within [0, 1e4] m;
        0: it decays from range 0 (on the real Oculus ping the first two bins, 5.7 mm, are
        equally bright, then the level falls).
    ringing_db : float or None
        R: the near-range ringing's level at range 0, dB re 1 uPa^2 at the receiver, within
        [-300, 300]: a second, usually weaker and longer tail. ``None``: no ringing.
    ringing_length_m : float or None
        The ringing's 1/e decay length (power), within [1e-4, 1e4] m; required with ``ringing_db``.
    ringing_period_m : float or None
        The ringing's period in range, within [1e-4, 1e4] m; ``None``: a smooth tail.
    beam_db : list of float or None
        The pattern b_j, one value per beam (left-most first), each within [-60, 60] dB.
    beam_std_db : float
        A seeded pattern instead (or on top): b_j drawn normal with this standard deviation
        (dB, within [0, 20]) from the scene's seed, less its mean over beams; 0: none.
    """

    level_db: float = 120.0
    length_m: float = 0.02
    hold_m: float = 0.0
    ringing_db: float | None = None
    ringing_length_m: float | None = None
    ringing_period_m: float | None = None
    beam_db: tuple[float, ...] | None = None
    beam_std_db: float = 0.0

    def __post_init__(self) -> None:
        _within("level_db", self.level_db, LEVEL_RANGE_DB)
        _positive("length_m", self.length_m)
        _within("hold_m", self.hold_m, (0.0, 1e4), "m")
        if self.ringing_db is not None:
            _within("ringing_db", self.ringing_db, LEVEL_RANGE_DB)
            if self.ringing_length_m is None:
                raise ConfigError("ringing_length_m", "required with ringing_db (the ringing's 1/e decay length, m)")
        for key in ("ringing_length_m", "ringing_period_m"):
            if getattr(self, key) is not None:
                if self.ringing_db is None:
                    raise ConfigError(key, "only with ringing_db (the ringing's level)")
                _length_m(key, getattr(self, key))
        object.__setattr__(self, "beam_db", _per_beam_db("beam_db", self.beam_db))
        _within("beam_std_db", self.beam_std_db, PER_BEAM_STD_RANGE_DB)


@dataclass(frozen=True)
class BeamGainSpec:
    """The receive channels' gain across the fan: steering loss and fixed per-beam stripes.

    Each beam's channel multiplies everything it carries (echo, bang, noise) by a power gain
    ``G_j = cos(theta_j)^n 10^((s_j + e_j) / 10)``: theta_j the beam's steering angle (its
    centre, ``sonar.beam_angles_deg``), n ``steering_exponent`` (the element's directivity,
    roughly cos^n, lowers the gain of beams steered off the axis), s_j the given ``gain_db`` and
    e_j seeded stripes (:mod:`sonarsim.sensor.channels`).

    Attributes
    ----------
    steering_exponent : float
        n, within [0, 200] (0: no steering loss; the ARIS's 9 dB from centre to the edge of a
        30-degree fan is n near 60).
    gain_db : list of float or None
        s_j, one value per beam (left-most first; a calibration's), each within [-60, 60] dB.
    std_db : float
        e_j drawn normal with this standard deviation (dB, within [0, 20]) from the scene's
        seed, less its mean over beams (the fan's mean level stays ``gain_db``'s); 0: none.
    """

    steering_exponent: float = 0.0
    gain_db: tuple[float, ...] | None = None
    std_db: float = 0.0

    def __post_init__(self) -> None:
        _within("steering_exponent", self.steering_exponent, STEERING_EXPONENT_RANGE, "(dimensionless)")
        object.__setattr__(self, "gain_db", _per_beam_db("gain_db", self.gain_db))
        _within("std_db", self.std_db, PER_BEAM_STD_RANGE_DB)


@dataclass(frozen=True)
class OutputSpec:
    """The device's output chain, after TVG and gain.

    Attributes
    ----------
    compression : {'log', 'gamma', 'linear'}
        ``log``: ``(L - floor_db) / (ceiling_db - floor_db)`` of full scale, L the level in dB;
        ``gamma``: ``(P / P_ceiling) ** gamma`` of full scale; ``linear``: ``P / P_ceiling``.
    gamma : float
    floor_db, ceiling_db : float
        Levels (dB re 1 uPa^2) mapped to 0 and to full scale; above the ceiling saturates.
    dtype : {'uint8', 'uint16', 'float32'}
        Quantisation: full scale 255 / 65535, rounded to integers; ``float32`` keeps the value
        (full scale 1, no quantisation).
    """

    compression: str = "log"
    gamma: float = 0.5
    floor_db: float = 60.0
    ceiling_db: float = 160.0
    dtype: str = "uint8"

    def __post_init__(self) -> None:
        _choice("compression", self.compression, COMPRESSIONS)
        g = _positive("gamma", self.gamma)
        if not GAMMA_RANGE[0] <= g <= GAMMA_RANGE[1]:
            raise ConfigError("gamma", f"must be in [{GAMMA_RANGE[0]:g}, {GAMMA_RANGE[1]:g}], got {g}")
        lo, hi = _finite("floor_db", self.floor_db), _finite("ceiling_db", self.ceiling_db)
        for key, v in (("floor_db", lo), ("ceiling_db", hi)):
            if not -100.0 <= v <= 400.0:
                raise ConfigError(key, f"must be within [-100, 400] dB re 1 uPa^2, got {v}")
        if self.compression == "log" and hi <= lo:
            raise ConfigError("ceiling_db", f"must exceed floor_db ({lo}), got {hi}")
        _choice("dtype", self.dtype, tuple(DTYPES))

    @property
    def full_scale(self) -> float:
        """The largest output value (1.0 for float32)."""
        return DTYPES[self.dtype] or 1.0


_SUBSPECS: dict[str, type] = {
    "absorption": AbsorptionSpec, "tvg": TvgSpec, "elevation_pattern": PatternSpec, "azimuth_pattern": PatternSpec,
    "pulse": PulseSpec, "speckle": SpeckleSpec, "noise": NoiseSpec, "bang": BangSpec, "output": OutputSpec,
    "beam_gain": BeamGainSpec,
}


@dataclass(frozen=True)
class SensorSpec:
    """Everything between the noise-free image and the device's output (see the module docs).

    Attributes
    ----------
    source_level_db : float
        SL, dB re 1 uPa at 1 m, within [-300, 300].
    target_strength_db : float
        Offset added to the target strength the scene's materials give (calibration), within
        [-200, 200] dB.
    sound_speed_m_s : float
        For the pulse's range extent and the absorption formulas.
    frequency_khz : float or None
        Carrier, within [1, 100000] kHz (as ``sonar.frequency_khz``); default the sonar's
        ``frequency_khz``. Needed by the absorption formulas.
    gain_db : float
        Receiver gain, added after TVG, within [-200, 200] dB.
    absorption, tvg, elevation_pattern, azimuth_pattern, pulse, speckle, noise, bang, output, beam_gain
        The effects; ``None``: off. Without ``output`` the output is the received power after
        TVG and gain, float32, uPa^2.
    preset : str or None
        The preset the section started from.
    """

    source_level_db: float = 200.0
    target_strength_db: float = 0.0
    sound_speed_m_s: float = 1500.0
    frequency_khz: float | None = None
    gain_db: float = 0.0
    absorption: AbsorptionSpec | None = None
    tvg: TvgSpec | None = None
    elevation_pattern: PatternSpec | None = None
    azimuth_pattern: PatternSpec | None = None
    pulse: PulseSpec | None = None
    speckle: SpeckleSpec | None = None
    noise: NoiseSpec | None = None
    bang: BangSpec | None = None
    output: OutputSpec | None = None
    beam_gain: BeamGainSpec | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        _within("source_level_db", self.source_level_db, LEVEL_RANGE_DB)
        _within("target_strength_db", self.target_strength_db, GAIN_RANGE_DB)
        c = _positive("sound_speed_m_s", self.sound_speed_m_s)
        if not 1300 <= c <= 1700:
            raise ConfigError("sound_speed_m_s", f"must be within [1300, 1700] m/s, got {c}")
        if self.frequency_khz is not None:
            _within("frequency_khz", self.frequency_khz, FREQUENCY_RANGE_KHZ, "kHz")
        _within("gain_db", self.gain_db, GAIN_RANGE_DB)
        if self.elevation_pattern is not None and self.elevation_pattern.leakage_beams is not None:
            raise ConfigError("elevation_pattern.leakage_beams", "only for the azimuth pattern")
        if self.azimuth_pattern is not None and self.azimuth_pattern.span_deg is not None:
            raise ConfigError("azimuth_pattern.span_deg", "only for the elevation pattern")
        if self.azimuth_pattern is not None and self.azimuth_pattern.correction_db is not None:
            raise ConfigError("azimuth_pattern.correction_db", "only for the elevation pattern")
        if self.elevation_pattern is not None and self.elevation_pattern.steering_loss:
            raise ConfigError("elevation_pattern.steering_loss", "only for the azimuth pattern (the receive beams)")
        check_bandwidth(self, None)

    def carrier_khz(self, sonar_frequency_khz: float | None) -> float | None:
        """The carrier frequency: ``frequency_khz``, else the sonar's (``None`` if neither)."""
        return self.frequency_khz if self.frequency_khz is not None else sonar_frequency_khz

    def to_dict(self) -> dict:
        """The scene-file form (every key explicit; ``false`` for an effect that is off)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "preset":
                continue
            if f.name in _SUBSPECS:
                out[f.name] = False if v is None else {k: list(x) if isinstance(x, tuple) else x
                                                       for k, x in dataclasses.asdict(v).items() if x is not None}
            elif v is not None:
                out[f.name] = v
        return out


SENSOR_KEYS = tuple(f.name for f in dataclasses.fields(SensorSpec))


def check_azimuth_width(spec: SensorSpec, beam_spacing_deg: float, beam_width_deg: float) -> None:
    """The azimuth pattern's -3 dB width is at least :data:`MIN_AZIMUTH_WIDTH_PER_SPACING` of the
    spacing between beams (a measured table is taken as given).

    Parameters
    ----------
    spec : SensorSpec
    beam_spacing_deg : float
        The (median) spacing between the sonar's beam centres, degrees.
    beam_width_deg : float
        The sonar's (median) beam width: the pattern's width when it gives none.

    Raises
    ------
    ConfigError
        ``azimuth_pattern.width_deg`` (the caller prefixes ``sensor.``), or ``sonar.beam_width_deg``
        when the width is the sonar's.
    """
    p = spec.azimuth_pattern
    if p is None or p.shape == "table":
        return
    width = p.width_deg if p.width_deg is not None else beam_width_deg
    least = MIN_AZIMUTH_WIDTH_PER_SPACING * beam_spacing_deg
    if width < least:
        key = "azimuth_pattern.width_deg" if p.width_deg is not None else "sonar.beam_width_deg"
        raise ConfigError(key, f"the azimuth pattern's -3 dB width must be at least {least:.3g} degrees "
                          f"({MIN_AZIMUTH_WIDTH_PER_SPACING:g} of the beams' spacing, {beam_spacing_deg:.3g} degrees), "
                          f"got {width:g}")


def check_beam_count(spec: SensorSpec, n_beams: int) -> None:
    """Every per-beam list of the sensor has one value per beam of the sonar.

    Parameters
    ----------
    spec : SensorSpec
    n_beams : int
        The sonar's beam count.

    Raises
    ------
    ConfigError
        ``beam_gain.gain_db`` or ``bang.beam_db`` (the caller prefixes ``sensor.``), naming the
        count given and the count expected.
    """
    for key, values in (("beam_gain.gain_db", spec.beam_gain and spec.beam_gain.gain_db),
                        ("bang.beam_db", spec.bang and spec.bang.beam_db)):
        if values is not None and len(values) != n_beams:
            raise ConfigError(key, f"has {len(values)} values; the sonar has {n_beams} beams: give one per beam, "
                              "left-most first")


def check_bandwidth(spec: SensorSpec, sonar_frequency_khz: float | None) -> None:
    """A chirp's bandwidth is at most its carrier frequency, where the carrier is known.

    A linear FM sweep of B about the carrier f runs from f - B/2 to f + B/2: B = f is a sweep of
    an octave, wider than any sonar transducer passes (and beyond 2 f it would need negative
    frequencies); ``bandwidth_khz: 1e9`` was accepted.

    Parameters
    ----------
    spec : SensorSpec
    sonar_frequency_khz : float or None
        The sonar's ``frequency_khz`` (the carrier when ``spec.frequency_khz`` is not given).

    Raises
    ------
    ConfigError
        ``pulse.bandwidth_khz`` (the caller prefixes ``sensor.``), naming the carrier.
    """
    pulse, carrier = spec.pulse, spec.carrier_khz(sonar_frequency_khz)
    if pulse is None or pulse.kind != "chirp" or carrier is None or pulse.bandwidth_khz <= carrier:
        return
    which = "sensor.frequency_khz" if spec.frequency_khz is not None else "sonar.frequency_khz"
    raise ConfigError("pulse.bandwidth_khz", f"must be within (0, {carrier:g}] kHz: at most the carrier frequency "
                      f"({which}, a sweep of an octave), got {pulse.bandwidth_khz:g}")


def _parse_sub(name: str, value: Any, key: str, base_dir: Path | None):
    cls = _SUBSPECS[name]
    if value is False or value is None:
        return None
    if value is True:
        return cls()
    allowed = tuple(f.name for f in dataclasses.fields(cls))
    if not isinstance(value, Mapping):
        raise ConfigError(key, f"must be false or a mapping with keys from: {', '.join(allowed)}; got {shown(value)}")
    for k in value:
        if k not in allowed:
            raise ConfigError(f"{key}.{key_text(k)}", f"unknown key; allowed keys of {key}: {', '.join(allowed)}")
    kw = dict(value)
    if name.endswith("_pattern") and kw.get("table") is not None:
        t = kw["table"]
        if not isinstance(t, str) or not t:
            raise ConfigError(f"{key}.table", f"must be a file name, got {shown(t)}")
        p = Path(t)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        try:  # missing, too long a name, a directory, a pipe (it blocked the render forever): refused
            check_input_file(p, "pattern table (a CSV of angle_deg, gain_db rows, relative to the scene file)")
        except SonarsimError as exc:
            raise ConfigError(f"{key}.table", str(exc)) from None
        kw["table"] = str(p)
    try:
        return cls(**kw)
    except ConfigError as exc:
        raise ConfigError(f"{key}.{exc.key}" if exc.key else key, exc.detail) from None
    except TypeError as exc:  # a value of the wrong type where a comparison was made
        raise ConfigError(key, str(exc)) from None


def parse_sensor(d: Any, base_dir: Path | None = None) -> SensorSpec | None:
    """The ``sensor`` section (mapping, or ``None``/``false`` for none) as a :class:`SensorSpec`.

    Raises
    ------
    ConfigError
        Unknown keys, presets, values out of range; the key is named (``sensor.noise.level_db``).
    """
    if d is None or d is False:
        return None
    if not isinstance(d, Mapping):
        raise ConfigError("sensor", f"must be a mapping with keys from: {', '.join(SENSOR_KEYS)}; got {shown(d)}")
    for k in d:
        if k not in SENSOR_KEYS:
            raise ConfigError(f"sensor.{key_text(k)}", f"unknown key; allowed keys of sensor: {', '.join(SENSOR_KEYS)}")
    merged: dict[str, Any] = {}
    preset = d.get("preset")
    if preset is not None:
        if not isinstance(preset, str) or preset not in SENSOR_PRESETS:
            raise ConfigError("sensor.preset", f"unknown sensor preset {shown(preset)}; allowed: {', '.join(SENSOR_PRESETS)}")
        merged.update(SENSOR_PRESETS[preset])
    for k, v in d.items():
        if k in _SUBSPECS and isinstance(v, Mapping) and isinstance(merged.get(k), Mapping):
            merged[k] = {**merged[k], **v}  # a preset's effect, partly overridden
        else:
            merged[k] = v
    kw: dict[str, Any] = {}
    for k, v in merged.items():
        key = f"sensor.{k}"
        if k in _SUBSPECS:
            kw[k] = _parse_sub(k, v, key, base_dir)
        elif k == "preset":
            kw[k] = v
        elif k == "frequency_khz" and v is None:
            kw[k] = None
        else:
            kw[k] = _finite(key, v)
    try:
        return SensorSpec(**kw)
    except ConfigError as exc:
        raise ConfigError(f"sensor.{exc.key}", exc.detail) from None


def _device(frequency_khz: float, elevation_deg: float, beam_deg: float, pulse_us: float, dtype: str = "uint8",
            source_level_db: float = 182.0, window: str = "hann", steered: bool = False) -> Mapping[str, Any]:
    """A device's ``sensor`` section from its published figures (the rest: our choices, below)."""
    full = {"uint8": 90.0, "uint16": 120.0}[dtype]  # dB of dynamic range the output spans
    return MappingProxyType({
        "source_level_db": source_level_db, "frequency_khz": frequency_khz,
        "absorption": {"model": "francois-garrison", "temperature_c": 15.0, "salinity_psu": 0.0, "depth_m": 2.0},
        "tvg": {"spreading": 20.0, "absorption": True},
        "elevation_pattern": {"shape": "line", "window": "rect", "width_deg": elevation_deg,
                              "span_deg": min(3.0 * elevation_deg, 60.0)},
        "azimuth_pattern": {"shape": "line", "window": window, "width_deg": beam_deg, "steering_loss": steered},
        "pulse": {"kind": "cw", "length_us": pulse_us},
        "speckle": {"model": "rayleigh", "anchor": "world"},
        "noise": {"level_db": 42.0},
        "bang": {"level_db": 110.0, "length_m": 0.03},
        "output": {"compression": "log", "floor_db": 60.0, "ceiling_db": 60.0 + full, "dtype": dtype},
    })


# The ARIS presets' pulse lengths by carrier (kHz): our choice, as for the other devices' (a few
# microseconds at 3 MHz, longer at the lower carriers: 13 to 18 cycles of the carrier).
_ARIS_PULSE_US: Mapping[float, float] = MappingProxyType({3000.0: 6.0, 1800.0: 8.0, 1200.0: 12.0, 1100.0: 12.0})


def _aris_device(mode: ArisMode) -> Mapping[str, Any]:
    """An ARIS mode's ``sensor`` section: its carrier, elevation aperture and beam width are those
    of the sonar preset of the same name (taken from Sound Metrics' measured beam table and
    figures, :mod:`sonarsim.config.presets`), so that both presets read one source."""
    sonar = PRESETS[mode.name].sonar
    return _device(float(sonar["frequency_khz"]), float(sonar["elevation_fov_deg"]), float(sonar["beam_width_deg"]),
                   _ARIS_PULSE_US[mode.frequency_khz])


#: Sensor presets, named after the sonar presets they go with (``sonar: {preset: X}`` and
#: ``sensor: {preset: X}``): carrier frequency, -3 dB elevation and azimuth widths from the
#: manufacturers' published figures (the sonar presets' ``frequency_khz``, ``elevation_fov_deg``
#: and ``beam_width_deg``; for every ARIS model x beam count x lens, those of Sound Metrics'
#: measured beam tables), output data type as the devices record it; the pulse lengths, levels
#: (source level, noise, bang, compression window: a concrete floor at mid-scale, a noise
#: floor just visible) and windows are our choices, to be calibrated against a recording with
#: ``sonarsim calibrate`` (see the README).
SENSOR_PRESETS: Mapping[str, Mapping[str, Any]] = MappingProxyType({
    **{mode.name: _aris_device(mode) for mode in ARIS_MODES},
    "didson300": _device(1800.0, 14.0, 0.3, 8.0),
    # (the beamformed arrays: steering_loss, as their sonar presets' beams are cones)
    "oculus-m750d-lf": _device(750.0, 20.0, 1.0, 20.0, steered=True),
    "oculus-m750d-hf": _device(1200.0, 12.0, 0.6, 12.0, steered=True),
    "oculus-m1200d-lf": _device(1200.0, 20.0, 0.6, 12.0, steered=True),
    # Calibrated (``sonarsim calibrate``, benchmarks/bench_realism.py) on the first real ping
    # of an M1200d at 2.1 MHz over a tank floor (pose z 0.433 m, pitch 29.06, roll 1.42 deg);
    # scores 19.2 dB PSNR on the two held-out pings. (Gain 27.19 dB: 30.11 as calibrated, less
    # the 2.92 dB by which a beam of this pattern hears more of the floor, 1.96 spacings of the
    # recording's 256 beams, since the pattern's equivalent width counts: the same counts.)
    "oculus-m1200d-hf": MappingProxyType({
        "source_level_db": 180.0, "frequency_khz": 2100.0, "gain_db": 27.19,
        "absorption": {"model": "francois-garrison", "temperature_c": 15.0, "salinity_psu": 0.0, "depth_m": 1.0},
        "tvg": {"spreading": 40.0, "absorption": True},
        "elevation_pattern": {"shape": "line", "window": "rect", "width_deg": 7.48, "span_deg": 60.0},
        "azimuth_pattern": {"shape": "gaussian", "width_deg": 0.423, "steering_loss": True},
        "speckle": {"model": "rayleigh", "anchor": "world"},
        "noise": {"level_db": 92.46, "after_tvg_db": 107.83},
        "bang": {"level_db": 90.33, "length_m": 0.0087},
        "output": {"compression": "gamma", "gamma": 0.2616, "floor_db": 60.0, "ceiling_db": 160.0, "dtype": "uint8"},
    }),
    "blueview-p900-130": _device(900.0, 20.0, 1.0, 15.0, dtype="uint16", steered=True),
    "gemini-720i": _device(720.0, 20.0, 1.0, 20.0, steered=True),
})


# A sonar without a preset is taken for a preset's device unless its carrier differs from the
# preset's by more than this fraction (the ARIS 1800's 1.1 MHz against the 1200's 1.2 MHz: 8 %).
DEVICE_FREQUENCY_TOLERANCE = 0.05


def preset_device_mismatch(preset: str, sonar: Any) -> str | None:
    """Why a sensor preset models another device than a sonar, or ``None`` where it may be the same.

    A sensor preset is the device of the sonar preset of the same name. A sonar made from a
    preset (``sonar.preset``, whatever keys override it) is that preset's device: only the
    sensor preset of that name fits it (``aris3000-64`` on an ``aris3000-128`` sonar is another
    mode, with another carrier and beam width). A sonar without a preset is another device when
    its ``frequency_khz`` differs from the sensor preset's by more than
    :data:`DEVICE_FREQUENCY_TOLERANCE`; without a frequency it cannot be told, and fits.

    Parameters
    ----------
    preset : str
        A key of :data:`SENSOR_PRESETS`.
    sonar : SonarConfig
        The scene's sonar (its ``preset`` and ``frequency_khz`` are read).

    Returns
    -------
    str or None
        One sentence naming both devices and the preset that fits, or ``None``.
    """
    own = getattr(sonar, "preset", None)
    if own is not None:
        if own == preset:
            return None
        fits = f"--sensor {own}" if own in SENSOR_PRESETS else "a sensor section of its own"
        return (f"sensor preset {shown(preset)} models another device than the scene's sonar (sonar preset "
                f"{shown(own)}): use {fits}")
    freq, theirs = getattr(sonar, "frequency_khz", None), SENSOR_PRESETS[preset].get("frequency_khz")
    if freq is not None and theirs is not None and abs(theirs - freq) > DEVICE_FREQUENCY_TOLERANCE * freq:
        return (f"sensor preset {shown(preset)} models a {theirs:g} kHz device; the scene's sonar is at "
                f"{freq:g} kHz (sonar.frequency_khz)")
    return None
