"""Every fittable parameter in one table: its name, unit, bounds, step and the scene field it sets.

One home for what a parameter may be: the scene format validates its fields against these
bounds (:mod:`sonarsim.config.sensor`, :mod:`~sonarsim.config.materials`,
:mod:`~sonarsim.config.scene` take their constants from here), ``calibrate``
(:mod:`sonarsim.analysis.calibration`) and ``fit`` (:mod:`~sonarsim.analysis.fitting`) take their
search steps and the outer limits of their physical bounds, the side-scan and multibeam fits
(:mod:`~sonarsim.analysis.sidescan`, :mod:`~sonarsim.analysis.multibeam`) their bounds, and the
differentiable engine (:func:`sonarsim.diff.params.parameter_bounds`) the bounds it checks values
against. ``docs/parameters.md`` shows the table (a test holds the two equal).

The bounds are the widest a value may take anywhere (the scene format's). A search may narrow
them further from the scene at hand (calibrate's bang below the source level, the noise 20 dB
under it; :func:`sonarsim.analysis.calibration.parameter_bounds`), never widen them. The step
is a search's first move in the parameter's unit (a Nelder-Mead simplex's edge): about what a
start is off by; ``coarse_step`` the first move of a search from further away (``fit``'s
coarse-to-fine pose search).

This module imports nothing of sonarsim but the sea-bed model's range of validity
(:mod:`sonarsim.core.seabed`): every other module may read it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..core.seabed import GRAIN_SIZE_RANGE_PHI


@dataclass(frozen=True)
class Parameter:
    """One fittable parameter.

    Attributes
    ----------
    name : str
        Its name in the table (the scene field's path where it has one: ``sensor.gain_db``).
    unit : str
        Its unit (``""``: dimensionless).
    lo, hi : float
        Inclusive bounds (``hi`` exclusive where ``open_hi``); infinite where unbounded.
    step : float
        A search's first move, in ``unit``.
    field : str
        The scene format's field it sets (or the fit's own, said so).
    meaning : str
        One line.
    open_hi : bool
        ``hi`` itself is refused.
    coarse_step : float or None
        The first move of a search from further away (``fit``); ``None``: ``step``.
    """

    name: str
    unit: str
    lo: float
    hi: float
    step: float
    field: str
    meaning: str
    open_hi: bool = False
    coarse_step: float | None = None

    @property
    def bounds(self) -> tuple[float, float]:
        """``(lo, hi)``."""
        return (self.lo, self.hi)

    def text(self) -> str:
        """The bounds as a message says them: ``[0, 1] dB``."""
        unit = f" {self.unit}" if self.unit else ""
        return f"[{self.lo:g}, {self.hi:g}{')' if self.open_hi else ']'}{unit}"

    def narrowed(self, lo: float, hi: float) -> tuple[float, float]:
        """``(lo, hi)`` clipped into this parameter's bounds (a search narrows, never widens).

        Raises
        ------
        ValueError
            When nothing is left (``lo`` above ``hi`` once clipped).
        """
        a, b = max(float(lo), self.lo), min(float(hi), self.hi)
        if a > b:
            raise ValueError(f"{self.name}: the bounds [{lo:g}, {hi:g}] lie outside {self.text()}")
        return a, b


# The scene format's outer limits ------------------------------------------------------------

#: Coordinates, metres: a scene larger than a thousand kilometres is a typo.
MAX_COORDINATE_M = 1e6
#: Angles, degrees: two turns either way (a trajectory may wind).
MAX_ANGLE_DEG = 720.0
#: Lengths (sizes, scales), metres.
MIN_LENGTH_M, MAX_LENGTH_M = 1e-6, 1e4
#: The narrowest beam, degrees (an ARIS 3000's is 0.24).
MIN_BEAM_WIDTH_DEG = 0.01
#: Levels and gains, dB: the sensor stage forms powers (10 ** (L / 10)) in float32, which holds
#: about 385 dB. Sonars transmit 180-230 dB re 1 uPa at 1 m; anything beyond these is a typo.
LEVEL_RANGE_DB = (-300.0, 300.0)
GAIN_RANGE_DB = (-200.0, 200.0)
#: Beam pattern widths (-3 dB, full), degrees: the narrowest beams of imaging sonars are about
#: 0.1 degree wide; a beam far narrower would need an aperture of tens of metres.
PATTERN_WIDTH_RANGE_DEG = (MIN_BEAM_WIDTH_DEG, 180.0)
#: Pulse lengths, microseconds: imaging sonars transmit pulses of a few to a few hundred us.
PULSE_LENGTH_RANGE_US = (0.1, 1e5)
#: Per-beam factors, dB: a channel more than 60 dB off its neighbours is a dead channel.
PER_BEAM_RANGE_DB = (-60.0, 60.0)
#: The across-fan gain cos(theta)^n: the ARIS's 9 dB over 15 degrees needs n near 60; beyond a
#: few hundred the fan's edge beams are below float32's smallest power.
STEERING_EXPONENT_RANGE = (0.0, 200.0)
#: Decay lengths of the near-range effects (bang, ringing, row noise), metres: from a tenth of a
#: millimetre (below any range cell) to the longest range window.
NEAR_RANGE_LENGTH_M = (1e-4, 1e4)
#: The output chain's gamma exponent.
GAMMA_RANGE = (0.05, 4.0)
#: TVG spreading laws, dB per decade of range (the scene format takes these four; the
#: differentiable engine anything between).
TVG_SPREADING = (0.0, 20.0, 30.0, 40.0)
#: Looks a device averages: beyond 64 the speckle is within 0.54 dB of its mean (contrast
#: 0.125) and the pool, which filters ``ceil(L)`` fields per stored one, grows.
LOOKS_RANGE = (1.0, 64.0)
#: Lambert's mu: its energy bound (a floor returns at most what it receives: mu <= 1/pi).
MAX_LAMBERT_MU = 1.0 / math.pi
#: The rough law's rms facet slope: above 0.5 the lobe is no lobe; below 1e-3 a mirror.
MIN_ROUGHNESS, MAX_ROUGHNESS = 1e-3, 0.5
#: The rough law's lobe at normal incidence.
MAX_SPECULAR_STRENGTH = 1e6
#: A sediment law's level offset, dB (a patch of sea bed brighter or darker than its class).
SEDIMENT_LEVEL_RANGE_DB = (-30.0, 30.0)


def _p(name, unit, bounds, step, field, meaning, **kw) -> Parameter:
    return Parameter(name, unit, float(bounds[0]), float(bounds[1]), float(step), field, meaning, **kw)


_COORD = (-MAX_COORDINATE_M, MAX_COORDINATE_M)
_ANGLE = (-MAX_ANGLE_DEG, MAX_ANGLE_DEG)

#: The table, by name.
PARAMETERS: dict[str, Parameter] = {p.name: p for p in (
    # The sonar's pose (and an object's, by the same bounds).
    _p("pose.x", "m", _COORD, 0.02, "sonar_pose.position_m[0]", "the sonar's position, world frame", coarse_step=0.05),
    _p("pose.y", "m", _COORD, 0.02, "sonar_pose.position_m[1]", "", coarse_step=0.05),
    _p("pose.z", "m", _COORD, 0.02, "sonar_pose.position_m[2]", "its height", coarse_step=0.05),
    _p("pose.roll", "degrees", _ANGLE, 1.0, "sonar_pose.rpy_deg[0]", "ROS fixed axes", coarse_step=2.0),
    _p("pose.pitch", "degrees", _ANGLE, 1.0, "sonar_pose.rpy_deg[1]", "positive looks down", coarse_step=2.0),
    _p("pose.yaw", "degrees", _ANGLE, 1.0, "sonar_pose.rpy_deg[2]", "", coarse_step=2.0),
    _p("objects.scale", "", (MIN_LENGTH_M, MAX_LENGTH_M), 0.05, "objects[].scale", "per-axis scale"),
    _p("planes.offset_m", "m", _COORD, 0.02, "planes[].point_m", "n . x on the plane (the ground: its height)"),
    # Surfaces' laws (objects, planes, the ground).
    _p("material.albedo", "", (0.0, 1.0), 0.1, "material.albedo", "lambertian and rough laws' diffuse albedo"),
    _p("material.mu", "", (0.0, MAX_LAMBERT_MU), 0.02, "material.mu", "Lambert's mu (<= 1/pi)"),
    _p("material.specular", "", (0.0, 1.0), 0.1, "specular", "specular reflectance R"),
    _p("material.specular_strength", "", (0.0, MAX_SPECULAR_STRENGTH), 1.0, "material.specular_strength",
       "rough law: the lobe at normal incidence"),
    _p("material.roughness", "", (MIN_ROUGHNESS, MAX_ROUGHNESS), 0.02, "material.roughness",
       "rough law: rms facet slope"),
    _p("material.grain_size_phi", "phi", GRAIN_SIZE_RANGE_PHI, 0.5, "material.grain_size_phi",
       "sediment law: mean grain size (the APL-UW regressions' range)"),
    _p("material.level_db", "dB", SEDIMENT_LEVEL_RANGE_DB, 1.0, "material.level_db", "sediment law: level offset"),
    # The sensor.
    _p("sensor.gain_db", "dB", GAIN_RANGE_DB, 6.0, "sensor.gain_db", "receiver gain"),
    _p("sensor.source_level_db", "dB re 1 uPa at 1 m", LEVEL_RANGE_DB, 6.0, "sensor.source_level_db", "source level"),
    _p("sensor.noise.level_db", "dB re 1 uPa^2", LEVEL_RANGE_DB, 6.0, "sensor.noise.level_db",
       "receiver noise before the TVG"),
    _p("sensor.noise.after_tvg_db", "dB re 1 uPa^2", LEVEL_RANGE_DB, 6.0, "sensor.noise.after_tvg_db",
       "noise after the TVG, on the output's scale"),
    _p("sensor.noise.common_db", "dB re 1 uPa^2", LEVEL_RANGE_DB, 6.0, "sensor.noise.common_db",
       "noise common to a row's beams, at range 0"),
    _p("sensor.noise.common_length_m", "m", NEAR_RANGE_LENGTH_M, 0.02, "sensor.noise.common_length_m",
       "its 1/e decay length"),
    _p("sensor.bang.level_db", "dB re 1 uPa^2", LEVEL_RANGE_DB, 6.0, "sensor.bang.level_db", "transmit bang at range 0"),
    _p("sensor.bang.length_m", "m", NEAR_RANGE_LENGTH_M, 0.01, "sensor.bang.length_m", "its 1/e decay length"),
    _p("sensor.bang.hold_m", "m", (0.0, 1e4), 0.005, "sensor.bang.hold_m", "range it holds its level over"),
    _p("sensor.bang.ringing_db", "dB re 1 uPa^2", LEVEL_RANGE_DB, 6.0, "sensor.bang.ringing_db",
       "near-range ringing at range 0"),
    _p("sensor.bang.ringing_length_m", "m", NEAR_RANGE_LENGTH_M, 0.02, "sensor.bang.ringing_length_m",
       "its 1/e decay length"),
    _p("sensor.tvg.spreading", "dB per decade", (min(TVG_SPREADING), max(TVG_SPREADING)), 10.0,
       "sensor.tvg.spreading", "TVG spreading law (the scene format: 0, 20, 30 or 40)"),
    _p("sensor.elevation_pattern.width_deg", "degrees", PATTERN_WIDTH_RANGE_DEG, 2.0,
       "sensor.elevation_pattern.width_deg", "elevation -3 dB width", open_hi=True),
    _p("sensor.azimuth_pattern.width_deg", "degrees", PATTERN_WIDTH_RANGE_DEG, 0.1,
       "sensor.azimuth_pattern.width_deg", "azimuth -3 dB width (the speckle's grain across beams)", open_hi=True),
    _p("sensor.pulse.length_us", "us", PULSE_LENGTH_RANGE_US, 1.0, "sensor.pulse.length_us",
       "CW pulse length (the grain along range)"),
    _p("sensor.output.gamma", "", GAMMA_RANGE, 0.05, "sensor.output.gamma", "gamma output's exponent"),
    _p("sensor.beam_gain.gain_db", "dB", PER_BEAM_RANGE_DB, 1.0, "sensor.beam_gain.gain_db", "per-beam gains"),
    _p("sensor.beam_gain.steering_exponent", "", STEERING_EXPONENT_RANGE, 1.0, "sensor.beam_gain.steering_exponent",
       "across-fan gain cos(theta)^n"),
    _p("sensor.speckle.looks", "looks", LOOKS_RANGE, 1.0, "sensor.speckle.looks", "looks averaged in intensity"),
    _p("sensor.speckle.k_shape", "", (0.1, math.inf), 0.5, "sensor.speckle.k_shape", "K law's shape"),
    # The side-scan fit's own (analysis.sidescan): what a side-scan's logs do not say.
    _p("sidescan.depression_deg", "degrees", (1.0, 45.0), 2.0, "instruments[].depression_deg",
       "the transducer's depression"),
    _p("sidescan.vertical_beam_width_deg", "degrees", (10.0, 110.0), 5.0, "instruments[].vertical_beam_width_deg",
       "its vertical -3 dB width"),
    _p("sidescan.gain_db", "dB", (-100.0, 200.0), 6.0, "(the side-scan fit's level)", "counts per unit intensity"),
    _p("sidescan.range_exponent", "", (-4.0, 4.0), 0.5, "(the side-scan fit's TVG residual)",
       "the recording's level against range r^n beyond the model's"),
    _p("sidescan.noise_db", "dB", (-100.0, 200.0), 6.0, "(the side-scan fit's noise floor)", "counts' noise floor"),
)}


def parameter(name: str) -> Parameter:
    """The table's entry ``name``.

    Raises
    ------
    KeyError
        Naming the parameters there are.
    """
    try:
        return PARAMETERS[name]
    except KeyError:
        raise KeyError(f"no fittable parameter {name!r}; the table has: {', '.join(PARAMETERS)}") from None


def bounds(name: str) -> tuple[float, float]:
    """``(lo, hi)`` of parameter ``name``."""
    return parameter(name).bounds


def step(name: str) -> float:
    """A search's first move for parameter ``name``, in its unit."""
    return parameter(name).step
