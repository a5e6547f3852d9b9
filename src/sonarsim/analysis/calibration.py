"""Calibrate the sensor model (and optionally the pose) against a real recording.

The real frame is a speckled draw in the device's units; the simulator's expected output
(``render(..., speckle=False)``: the mean device value of each pixel) is what a fit can match.
The cost is the mean squared difference between the two over the whole frame, i.e. the PSNR
in the recording's own units that :func:`sonarsim.analysis.metrics.psnr` reports, plus the
squared error of the water column's mean range profile (weight :data:`WATER_WEIGHT`): the dark
water column counts little in the pixels' MSE, yet its distribution is set by that profile.

Parameters fitted:

* sensor: ``gain_db`` (receiver gain), ``noise_db`` (receiver noise, before the TVG, which
  lifts it with range), ``noise_after_tvg_db`` (the digitiser's noise, after the TVG: a floor
  at every range), ``bang_db`` and ``bang_length_m`` (the transmit bang),
  ``elevation_width_deg`` (the two-way -3 dB width of the elevation pattern, whose sidelobes
  light the floor before and beyond the band: the rays cover at least :data:`MIN_SPAN_DEG`);
* the laws, discrete choices made jointly with the pose (each is fitted and the best kept):
  the TVG's spreading (20, 30 or 40 log r) and the output's compression (``gamma`` or
  ``log``, :data:`COMPRESSIONS`). The compression's shape (gamma, or the log's span in dB)
  is set from the recording's speckle in its lit band and corrected against the model's own
  speckled frames (:func:`output_shape`);
* pose: any of x, y, z, roll, pitch, yaw named free.

How the search avoids the wrong basin (issue 22: from a grid of starts, half ended more than
1 dB below the best, silently):

1. a closed-form start from the floor band's edges (:mod:`sonarsim.analysis.bandpose`): the
   edges give ``1 / r = a cos(beam) + c sin(beam) +- b``, hence the pose for each elevation
   half-angle along the family a flat floor allows; several half-angles are started from
   (:data:`HALF_ANGLES_DEG`) instead of the user's pose;
2. each start and each law: the sensor alone is fitted at the start's pose (cheap: the
   noise-free image is rendered once); the best :data:`REFINED` of them, and each law's best
   start, are then refined with the free pose parameters and the sensor together, and the
   best result kept;
3. physical bounds on every parameter (:func:`parameter_bounds`: the bang below the source
   level and at least a range cell long, noise and gain where the device's output can show
   them);
4. degenerate outcomes are refused (:class:`CalibrationFailed`, exit status 3), by this search
   and by the gradient calibration (:func:`sonarsim.diff.inverse.calibrate_recording`) alike:
   a frame without echo (:func:`frame_problems`: one level, saturated, no lit region, pixel
   noise, no speckle), the echo switched off (the lit band explained as noise lifted by the
   TVG), the pose unmoved from its start or a free parameter that does not change the fit, a
   parameter pinned at a bound where moving it off the bound costs fit, height, pitch or roll
   free where the recording shows no floor band edge, a model that explains less than
   :data:`MIN_EXPLAINED` of the frame's variance (:func:`model_problems`); a score below a
   trivial baseline (the frame's own range profile in every beam) is a warning, and so is a
   value at a bound where moving it off changes nothing (``CalibrationResult.at_bounds``);
5. the family of equally good poses (within :data:`FAMILY_DB` of the best PSNR): the
   elevation width is held at each of :data:`FAMILY_WIDTHS_DEG` and the pose and sensor
   refitted there; the range of height, pitch and width is reported, and the member written
   is the family's middle (:func:`family_middle`), not its best, which is chance within the
   tolerance and was the scan's narrowest width on the real Oculus ping.

The search is derivative-free (Nelder-Mead over a bounded transform), re-rendering only when a
parameter that changes the rays (pose, elevation width) moves; the sensor-only parameters
re-run the sensor stage on the cached noise-free image. Afterwards, the azimuth width of the
receive beams is set so that the speckle grain across beams matches the recording's, and, at
the chosen member of the family, the range law's departure from its formula
(``tvg.correction_db``: :data:`RANGE_CORRECTION_KNOTS` knots over the window,
:func:`_fit_range_correction`): over a flat floor the sea bed's angular response and the
device's TVG curve are one function of range, which no formula of the laws above follows
(on the real Oculus ping it is 1 dB RMS and gains 0.26 dB on the calibration frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Callable, Sequence

import numpy as np
from scipy import optimize

from ..config.scene import MIN_CORRELATION_M, Scene
from ..config import parameters
from ..config.sensor import SensorSpec, parse_sensor
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError
from ..image.result import SonarImage
from ..renderer.simulator import Simulator
from . import realism
from .fitting import PARAMETERS, check_overlap, parse_free, pose_values, recording_geometry

SENSOR_PARAMETERS = ("gain_db", "noise_db", "noise_after_tvg_db", "bang_db", "bang_length_m", "bang_hold_m",
                     "ringing_db", "ringing_length_m", "elevation_width_deg")
#: The entry of the one table of fittable parameters (:mod:`sonarsim.config.parameters`) each
#: calibrated parameter is.
TABLE_NAMES = {
    "gain_db": "sensor.gain_db", "noise_db": "sensor.noise.level_db", "noise_after_tvg_db": "sensor.noise.after_tvg_db",
    "bang_db": "sensor.bang.level_db", "bang_length_m": "sensor.bang.length_m", "bang_hold_m": "sensor.bang.hold_m",
    "ringing_db": "sensor.bang.ringing_db", "ringing_length_m": "sensor.bang.ringing_length_m",
    "elevation_width_deg": "sensor.elevation_pattern.width_deg",
    **{k: f"pose.{k}" for k in PARAMETERS},
}
#: Initial simplex step of each parameter, in its units: the table's.
STEPS = {k: parameters.step(name) for k, name in TABLE_NAMES.items()}

#: The least elevation span (degrees) the rays cover while calibrating: the pattern's sidelobes
#: light the floor well outside the main lobe (on the real Oculus ping, the echo beyond the floor
#: band and before it, 17-20 degrees off the axis), and a span of three -3 dB widths misses it.
MIN_SPAN_DEG = 60.0

#: Weight of the water column's mean profile in the cost (see :func:`calibrate`).
WATER_WEIGHT = 5.0

#: Output laws tried (with each TVG spreading law).
COMPRESSIONS = ("gamma", "log")

#: Half-angles (degrees) of the band's edges that the closed-form starts are made for.
HALF_ANGLES_DEG = (2.0, 3.5, 5.0, 7.0, 10.0, 14.0)

#: The band detector's edges lie at about this fraction of the two-way -3 dB width off the
#: axis, each side (measured on renders of a uniform line array, widths 6-16 degrees: 0.84-1.03).
EDGE_RATIO = 0.9

#: Starts (a half-angle and a law) refined with the pose after the sensor-only stage, besides
#: each law's best start.
REFINED = 2

#: Iterations of each sensor-only start (the refinement gets the full budget).
START_ITERATIONS = 120

#: A pose is one of the family when its PSNR is within this many dB of the best.
FAMILY_DB = 0.2

#: Elevation widths (degrees, two-way -3 dB) of the family scan, besides the best fit's.
FAMILY_WIDTHS_DEG = (2.0, 3.0, 4.5, 6.0, 8.0, 10.5, 14.0, 18.0, 24.0)

#: A free pose parameter is unconstrained when a step either way changes the cost by less than
#: this fraction.
UNCONSTRAINED_COST = 1e-6

#: The echo is "switched off" when, over the recording's lit band, less than this share of the
#: model's expected power is echo (the rest: noise and bang lifted by the TVG).
MIN_ECHO_SHARE = 0.5

#: A parameter at a bound counts as pinned there when moving it a quarter step inward raises the
#: cost by more than this fraction (0.023 dB of PSNR: a change the fit can see).
PINNED_COST_RISE = 0.005

#: The longest the bang holds its level: a transmission of 100 us (c tau / 2 = 7.5 cm).
BANG_HOLD_MAX_M = 0.075
#: The longest 1/e decay of the bang and its ringing (0.5 m of range, 670 us).
BANG_REACH_M = 0.5

#: A texture estimated below this spread (dB, after the model's own speckle is subtracted) is
#: taken as none.
TEXTURE_FLOOR_DB = 0.75

#: Bounds that are a natural limit rather than a plausibility bound: a result there is not
#: pinned ((name, True) for the lower bound). The bang's decay over a twentieth of a range cell
#: is an abrupt end (the receiver's blanking ends), which a sampled image cannot tell from 0;
#: so is its ringing's.
NATURAL_LIMITS = {("bang_length_m", True), ("ringing_length_m", True)}

#: The starting sensor when the scene has none: an 8-bit device with gamma compression, 20 log r
#: TVG and absorption in fresh water, a uniform line array in elevation, Gaussian receive beams.
STARTING_SENSOR = {
    "source_level_db": 180.0,
    "absorption": {"model": "francois-garrison", "temperature_c": 15.0, "salinity_psu": 0.0, "depth_m": 1.0},
    "tvg": {"spreading": 20.0, "absorption": True},
    "elevation_pattern": {"shape": "line", "window": "rect", "span_deg": MIN_SPAN_DEG},
    "azimuth_pattern": {"shape": "gaussian"},
    "speckle": {"model": "rayleigh", "anchor": "world"},
    "noise": {"level_db": 60.0, "after_tvg_db": 100.0},
    "bang": {"level_db": 150.0, "length_m": 0.01},
    "output": {"compression": "gamma", "gamma": 0.3, "ceiling_db": 160.0, "dtype": "uint8"},
}


#: The least share of the frame's variance (about its mean) that the calibrated expected image
#: must explain: a model no better than the frame's mean level explains no echo. Measured: 71 %
#: (Oculus ping) and 78 % (ARIS sample) for the frames' own range profiles, under 3 % on
#: random bytes.
MIN_EXPLAINED = 0.1
#: The steering loss's exponent the channels' fit allows (``cos^n``); at it, the fan's profile
#: is not a steering loss (reported).
MAX_STEERING_EXPONENT = 200.0


# Speckle contrasts gamma can explain: gamma from 0.05 to 2 (exponential speckle compressed).
MIN_CONTRAST, MAX_CONTRAST = 0.062, 2.2
# Passes correcting the output's shape by the speckled model's statistic, and when to stop.
GAMMA_PASSES = 2
GAMMA_TOLERANCE = 0.02
#: Standard deviation (dB) of ``10 log10`` of exponential speckle: ``10 / ln 10 * pi / sqrt 6``.
LOG_SPECKLE_STD_DB = 10.0 / math.log(10.0) * math.pi / math.sqrt(6.0)
#: Spans (dB) a log output is fitted within.
MIN_SPAN_DB, MAX_SPAN_DB = 10.0, 200.0


class CalibrationFailed(SonarsimError):
    """The search ended somewhere that does not describe the recording (exit status 3).

    Attributes
    ----------
    reasons : tuple of str
        What was found (the echo switched off, the pose unmoved, parameters pinned at bounds).
    result : CalibrationResult or None
        What the search ended with, for inspection (None when refused before searching).
    source : str or None
        The recording, named first in the message (the command line gives it).
    """

    exit_status = 3

    def __init__(self, reasons: Sequence[str], result: "CalibrationResult | None", source: str | None = None) -> None:
        self.reasons = tuple(reasons)
        self.result = result
        self.source = source
        super().__init__((f"{source}: " if source else "") + "calibration refused: " + "; ".join(self.reasons))


def gamma_for_contrast(contrast: float) -> float:
    """The gamma whose compression gives exponential speckle this contrast (std / mean).

    Raises
    ------
    ValueError
        A contrast outside :data:`MIN_CONTRAST` - :data:`MAX_CONTRAST` (no gamma from 0.01 to 2
        gives it: a saturated or noise-free region), or not finite.
    """
    from scipy.special import gammaln

    def c(g):
        return math.sqrt(math.exp(gammaln(1 + 2 * g) - 2 * gammaln(1 + g)) - 1.0) - contrast

    if not (np.isfinite(contrast) and c(0.01) < 0.0 < c(2.0)):
        raise ValueError(f"the speckle contrast of the region is {contrast:.3g}; a gamma output's speckle shows "
                         f"{MIN_CONTRAST}-{MAX_CONTRAST}")
    return float(optimize.brentq(c, 0.01, 2.0))


def span_for_spread(spread_counts: float, full_scale: float) -> float:
    """The log output's span (dB) whose compression gives exponential speckle this standard
    deviation in counts: ``LOG_SPECKLE_STD_DB * full_scale / spread``, within the fitted limits."""
    return float(np.clip(LOG_SPECKLE_STD_DB * full_scale / max(spread_counts, 1e-9), MIN_SPAN_DB, MAX_SPAN_DB))


def speckle_spread(image: np.ndarray, mask: np.ndarray) -> float:
    """Standard deviation (counts) of ``image`` less its local mean over ``mask``: what a log
    output's speckle shows whatever the level (:func:`span_for_spread`)."""
    x = np.asarray(image, dtype=np.float64)
    r = x - realism.local_mean(x)
    keep = mask & (realism.local_mean(x) > 0)
    if keep.sum() < 2:
        raise ValueError("the region holds fewer than two pixels with echo")
    # The local mean takes 1/(window cells) of the variance with it.
    cells = realism.LOCAL_MEAN_WINDOW[0] * realism.LOCAL_MEAN_WINDOW[1]
    return float(r[keep].std() / math.sqrt(1.0 - 1.0 / cells))


def frame_problems(image: np.ndarray) -> list[str]:
    """Why a frame holds no echo to calibrate on (both methods refuse it before fitting):
    :func:`~sonarsim.analysis.fitting.echo_problems`, and no speckle in its lit band (a
    contrast no gamma output shows)."""
    from .fitting import echo_problems

    out = list(echo_problems(image))
    if out:
        return out
    x = np.asarray(image, dtype=np.float64)
    try:
        contrast = realism.speckle_contrast(x, realism.auto_regions(x)["lit"])
    except ValueError as exc:
        return [f"the frame has no speckle in its bright band: {exc}"]
    if not MIN_CONTRAST <= contrast <= MAX_CONTRAST:
        return [f"the frame's speckle contrast in its bright band is {contrast:.3g}; calibration needs "
                f"{MIN_CONTRAST}-{MAX_CONTRAST} (a speckled frame in the device's units, not a noise-free render)"]
    return []


def model_problems(target: np.ndarray, expected: np.ndarray) -> list[str]:
    """Why a calibrated expected image explains no echo of ``target``: it explains less than
    :data:`MIN_EXPLAINED` of the frame's variance about its mean (the trivial image of one
    level does as well), or its error is not finite."""
    t = np.asarray(target, dtype=np.float64)
    mse = float(np.mean((np.asarray(expected, dtype=np.float64) - t) ** 2))
    var = float(t.var())
    if not np.isfinite(mse):
        return [f"the calibrated image's error is {mse}"]
    explained = 1.0 - mse / var if var > 0 else 0.0
    if explained < MIN_EXPLAINED:
        return [f"the calibrated model explains {100 * explained:.1f} % of the frame's variance about its mean level "
                f"(at least {100 * MIN_EXPLAINED:g} % is an echo the model explains; the frame's mean level alone "
                "explains 0 %)"]
    return []


def bound_report(values: dict, bounds: dict[str, tuple[float, float]], exclude=NATURAL_LIMITS) -> tuple[list, list]:
    """The values at or beyond their bounds: ``(beyond, at)``, each a list of clauses naming the
    value and the bounds. At a bound means within 1e-3 of the span; ``exclude`` holds
    ``(name, is_lower)`` bounds that are natural limits, not plausibility bounds."""
    beyond, at = [], []
    for k, (lo, hi) in bounds.items():
        if k not in values or np.ndim(values[k]) != 0:
            continue
        x = float(values[k])
        tol = 1e-3 * (hi - lo)
        text = f"{k} {x:.4g} (bounds {lo:.4g} to {hi:.4g})"
        if not np.isfinite(x) or x < lo - tol or x > hi + tol:
            beyond.append(text)
        elif (abs(x - lo) <= tol and (k, True) not in exclude) or (abs(x - hi) <= tol and (k, False) not in exclude):
            at.append(text)
    return beyond, at


def output_shape(compression: str, image: np.ndarray, mask: np.ndarray, full_scale: float) -> float:
    """The compression's shape from a frame's speckle in ``mask``: gamma (``gamma``) from the
    speckle contrast, or the span in dB (``log``) from its spread in counts.

    Raises
    ------
    ValueError
        No speckle to measure in ``mask`` (fewer than two pixels with echo, a contrast no
        gamma gives).
    """
    if compression == "gamma":
        return gamma_for_contrast(realism.speckle_contrast(image, mask))
    return span_for_spread(speckle_spread(image, mask), full_scale)


def parse_free_parameters(text: str | Sequence[str]) -> tuple[str, ...]:
    """``"z,pitch"`` -> pose parameters to fit (possibly none); unknown names are errors."""
    return parse_free(text, allow_none=True)


def parameter_bounds(spec: SensorSpec, sonar) -> dict[str, tuple[float, float]]:
    """Physical bounds of each calibrated parameter, in its units.

    * ``bang_db`` below the source level (the bang is the transmitter's own signal leaking in);
      it holds its level for ``bang_hold_m``, at least one range cell (a bang shorter than a
      bin is not resolved: its level would trade against its length without end) and at most
      :data:`BANG_HOLD_MAX_M` (a transmission of 100 us), then decays over ``bang_length_m`` (a
      twentieth of a cell, an abrupt end, to :data:`BANG_REACH_M`); the ringing's decay length
      is at most :data:`BANG_REACH_M` as well (a transducer rings for well under a
      millisecond: without the limit, a bang and its ringing can draw the whole range profile
      of a grazing sea bed and leave the echo nothing, as on the ARIS sample);
    * ``noise_db`` (before the TVG) from 0 dB re 1 uPa^2 (below any receiver's self-noise) to
      20 dB under the source level; ``noise_after_tvg_db`` within 120 dB under the output's
      ceiling (an 8- or 16-bit output shows nothing lower) and not above it (everything would
      saturate);
    * ``gain_db`` from -40 dB (an attenuating front end) to 120 dB (more than any receiver chain
      offers; without a TVG law the gain alone lifts the echo of the far range);
    * ``elevation_width_deg`` 1-60 degrees; the pose within a kilometre and its angles;

    each within its entry of the one table of fittable parameters (:data:`TABLE_NAMES`).
    """
    ceiling = spec.output.ceiling_db if spec.output is not None else 160.0
    cell = float(sonar.range_resolution_m)
    physical = {
        "gain_db": (-40.0, 120.0), "noise_db": (0.0, spec.source_level_db - 20.0),
        "noise_after_tvg_db": (ceiling - 120.0, ceiling), "bang_db": (0.0, spec.source_level_db),
        "bang_length_m": (0.05 * cell, BANG_REACH_M),
        "bang_hold_m": (cell, max(BANG_HOLD_MAX_M, 2.0 * cell)),
        "ringing_db": (0.0, spec.source_level_db),
        "ringing_length_m": (max(0.05 * cell, 1e-4), BANG_REACH_M),
        "elevation_width_deg": (1.0, 60.0),
        "x": (-1e3, 1e3), "y": (-1e3, 1e3), "z": (-1e3, 1e3),
        "roll": (-90.0, 90.0), "pitch": (-90.0, 90.0), "yaw": (-180.0, 180.0),
    }
    # Within the table's (the scene format's) bounds, always.
    return {k: parameters.parameter(TABLE_NAMES[k]).narrowed(*b) for k, b in physical.items()}


def sensor_values(spec: SensorSpec, sonar_elevation_deg: float) -> dict[str, float]:
    """The calibrated parameters' values in a sensor spec."""
    el = spec.elevation_pattern
    return {
        "gain_db": spec.gain_db,
        "noise_db": spec.noise.level_db if spec.noise else 0.0,
        "noise_after_tvg_db": spec.noise.after_tvg_db if spec.noise and spec.noise.after_tvg_db is not None else 40.0,
        "bang_db": spec.bang.level_db if spec.bang else 0.0,
        "bang_length_m": spec.bang.length_m if spec.bang else 0.01,
        "bang_hold_m": spec.bang.hold_m if spec.bang else 0.0,
        # Without ringing in the start, a weak, longer tail for the search to raise.
        "ringing_db": (spec.bang.ringing_db if spec.bang and spec.bang.ringing_db is not None
                       else (spec.bang.level_db - 30.0 if spec.bang else 0.0)),
        "ringing_length_m": (spec.bang.ringing_length_m if spec.bang and spec.bang.ringing_length_m is not None
                             else (3.0 * spec.bang.length_m if spec.bang else 0.03)),
        "elevation_width_deg": el.width_deg if el and el.width_deg else sonar_elevation_deg,
    }


def with_values(spec: SensorSpec, v: dict[str, float]) -> SensorSpec:
    """``spec`` with the calibrated parameters replaced (others kept)."""
    el = spec.elevation_pattern
    if el is not None:
        width = v["elevation_width_deg"]
        span = min(max(el.span_deg or 0.0, 3.0 * width, MIN_SPAN_DEG), 170.0)
        el = replace(el, width_deg=float(width), span_deg=float(span))
    v = {k: float(x) for k, x in v.items()}
    return replace(spec, gain_db=v["gain_db"], elevation_pattern=el,
                   noise=replace(spec.noise, level_db=v["noise_db"], after_tvg_db=v["noise_after_tvg_db"])
                   if spec.noise else None,
                   bang=_bang_with(spec.bang, v) if spec.bang else None)


def _bang_with(bang, v: dict):
    """The bang of ``v``; its ringing is held weaker and longer than the bang itself (a tail
    after it: as strong and as short, it would be a second bang that the fit trades against
    the first)."""
    level, length = v["bang_db"], v["bang_length_m"]
    ringing_db = v.get("ringing_db", bang.ringing_db)
    ringing_length = v.get("ringing_length_m", bang.ringing_length_m)
    if ringing_db is not None:
        ringing_db = min(float(ringing_db), level)
        ringing_length = max(float(ringing_length), length)
    return replace(bang, level_db=level, length_m=length, hold_m=v.get("bang_hold_m", bang.hold_m),
                   ringing_db=ringing_db, ringing_length_m=ringing_length)


def with_law(spec: SensorSpec, compression: str, spreading: float | None, shape: float) -> SensorSpec:
    """``spec`` with a TVG spreading law (``None``: kept) and an output law of the given shape
    (gamma, or the log's span in dB below its ceiling)."""
    out = spec.output
    if compression == "gamma":
        out = replace(out, compression="gamma", gamma=float(np.clip(shape, 0.05, 4.0)))
    elif compression == "log":
        out = replace(out, compression="log", floor_db=float(out.ceiling_db - shape))
    else:
        raise ConfigError("sensor.output.compression", f"calibration fits gamma or log, got {compression!r}")
    tvg = spec.tvg if spreading is None or spec.tvg is None else replace(spec.tvg, spreading=float(spreading))
    return replace(spec, output=out, tvg=tvg)


def law_of(spec: SensorSpec) -> dict:
    """The laws of a spec: ``{"compression", "spreading", "shape"}``."""
    out = spec.output
    shape = out.gamma if out.compression == "gamma" else out.ceiling_db - out.floor_db
    return {"compression": out.compression, "spreading": spec.tvg.spreading if spec.tvg is not None else None,
            "shape": float(shape)}


@dataclass
class CalibrationResult:
    """What :func:`calibrate` found.

    Attributes
    ----------
    scene : Scene
        The input scene with the calibrated sensor and pose.
    values : dict
        Calibrated parameters (sensor and free pose), in their units.
    psnr_db : float
        PSNR of the expected render against the recording, in its units (peak 255 for 8-bit).
    psnr_start_db : float
        The same at the user's start.
    renders : int
        Noise-free renders made.
    expected : SonarImage
        The calibrated expected render.
    starts : list of dict
        Each start tried: its half-angle, law, pose and PSNR after the sensor-only fit (and
        ``refined_psnr_db`` where it was refined).
    family : dict
        The equally good poses (:func:`calibrate`, step 5): ``members`` (width, pose, PSNR
        each), and the ``z``, ``pitch``, ``elevation_width_deg`` ranges within ``within_db``;
        empty when no pose parameter is free or the band has no far edge.
    baselines : dict
        PSNR of the trivial images of the frame itself (its range profile in every beam, its
        separable range x beam image) and its local mean (the ceiling), dB.
    warnings : list of str
        What the user should know about the result (a score below a baseline).
    law : dict
        The laws chosen: ``compression`` (gamma or log), ``spreading`` (TVG, dB per decade, or
        None) and ``shape`` (gamma, or the log's span in dB).
    at_bounds : list of str
        Parameters that ended at a bound where the frame does not determine them (said in
        ``warnings``).
    """

    scene: Scene
    values: dict
    psnr_db: float
    psnr_start_db: float
    renders: int
    expected: SonarImage
    starts: list = field(default_factory=list)
    family: dict = field(default_factory=dict)
    baselines: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    law: dict = field(default_factory=dict)
    at_bounds: list = field(default_factory=list)


def _psnr(mse: float, peak: float) -> float:
    return float(10 * np.log10(peak ** 2 / mse)) if mse > 0 else float("inf")


class _Problem:
    """The cost of the calibration and what it caches (renders, sensor models)."""

    def __init__(self, real: SonarImage, scene: Scene, sonar, free: tuple[str, ...], water_weight: float,
                 bounds: dict) -> None:
        self.scene, self.sonar, self.free = scene, sonar, free
        self.target = np.asarray(real.polar, dtype=np.float64)
        regions = realism.auto_regions(self.target)
        self.lit, water = regions["lit"], regions["water"]
        self.water = water
        self.n_water = np.maximum(water.sum(axis=1), 1)
        self.water_rows = water.sum(axis=1) >= 0.25 * water.shape[1]
        self.real_water = (self.target * water).sum(axis=1) / self.n_water
        self.water_weight = water_weight
        self.bounds = bounds
        self.pose0 = pose_values(scene.sonar_pose)
        self.frames: dict = {}
        self.models: dict = {}
        self._residual: np.ndarray | None = None
        self._sim = None  # (simulator(): built on first use, one for the whole calibration)
        self.renders = 0

    def pose(self, v: dict) -> Pose:
        pv = {**self.pose0, **{k: v[k] for k in self.free if k in v}}
        return Pose((pv["x"], pv["y"], pv["z"]), (pv["roll"], pv["pitch"], pv["yaw"]))

    def frame_for(self, spec: SensorSpec, v: dict) -> tuple[np.ndarray, Pose]:
        """Noise-free total image for the pose and elevation width in v (cached)."""
        pose = self.pose(v)
        el = spec.elevation_pattern
        key = (tuple(round(x, 6) for x in (*pose.position_m, *pose.rpy_deg)) + (round(v["elevation_width_deg"], 4),)
               + ((el.correction_db,) if el is not None and el.correction_db is not None else ()))
        if key not in self.frames:
            # Only the elevation pattern acts on the rays: render with it alone.
            s2 = SensorSpec(elevation_pattern=with_values(spec, v).elevation_pattern)
            total = self.pattern_frame(s2, pose)
            self.renders += 1
            if len(self.frames) > 64:
                self.frames.clear()
            self.frames[key] = total
        return self.frames[key], pose

    def simulator(self):
        """One simulator of the scene (without its sensor) for every render of the calibration:
        each trial's elevation pattern is in the rays it traces (:meth:`pattern_frame`), not in
        the scene, so that nothing is built again per trial."""
        if self._sim is None:
            self._sim = Simulator(replace(self.scene, sensor=None, sonar=self.sonar))
        return self._sim

    def pattern_frame(self, pattern: SensorSpec, pose: Pose) -> np.ndarray:
        """The noise-free total image at ``pose`` with ``pattern``'s elevation pattern on the rays
        (what a simulator of the scene with that sensor renders: its fan and its span), float32."""
        from ..core.rays import make_ray_fan
        from ..sensor.model import SensorModel

        sim = self.simulator()
        model = SensorModel(pattern, self.sonar, self.scene.render.seed, fields=False)
        traced = model.trace_sonar(self.sonar)
        sim.require_frame_memory(traced)
        fan = make_ray_fan(traced, self.scene.render, model.elevation_gain)
        paths = sim.trace(pose, self.sonar, fan=fan, traced=traced)
        return sim.form(paths, keep_rays=False, speckle=False, sensor=False).components["total"]

    def model(self, spec: SensorSpec):
        from ..sensor.model import SensorModel

        m = self.models.get(spec)
        if m is None:
            m = SensorModel(spec, self.sonar, self.scene.render.seed, fields=False)
            if len(self.models) > 8:
                self.models.clear()
            self.models[spec] = m
        return m

    def expected(self, spec: SensorSpec, v: dict) -> tuple[np.ndarray, Pose, SensorSpec]:
        total, pose = self.frame_for(spec, v)
        s2 = with_values(spec, v)
        return self.model(s2).apply(total, speckle=False), pose, s2

    def cost_of(self, e: np.ndarray) -> float:
        c = float(np.mean((e - self.target) ** 2))
        if self.water_weight > 0 and self.water_rows.any():
            d = ((e * self.water).sum(axis=1) / self.n_water - self.real_water)[self.water_rows]
            c += self.water_weight * float(np.mean(d ** 2))
        return c

    def cost(self, spec: SensorSpec, v: dict) -> float:
        return self.cost_of(self.expected(spec, v)[0])

    def psnr(self, spec: SensorSpec, v: dict, peak: float) -> float:
        """PSNR (dB) of the expected image alone (the cost adds the water column's profile)."""
        return _psnr(float(np.mean((self.expected(spec, v)[0] - self.target) ** 2)), peak)

    def spread_mismatch(self, spec: SensorSpec, v: dict, n_bins: int = 12) -> float:
        """Mean absolute difference (counts^2) between the recording's speckle variance and the
        model's at each level of the expected image, the model's scaled to fit at best.

        The recording's spread is its standard deviation about its local mean, pixels binned by
        the model's expected count; the model's, in closed form for exponential speckle:
        ``c(gamma) E`` for a gamma output (contrast fixed, :func:`gamma_for_contrast`'s law),
        ``LOG_SPECKLE_STD_DB * full_scale / span`` for a log output (fixed in counts).
        """
        from scipy.special import gammaln

        e = self.expected(spec, v)[0]
        out = spec.output
        fs = out.full_scale
        if self._residual is None:
            cells = realism.LOCAL_MEAN_WINDOW[0] * realism.LOCAL_MEAN_WINDOW[1]
            self._residual = (self.target - realism.local_mean(self.target)) / math.sqrt(1.0 - 1.0 / cells)
        keep = (e > 2.0 * fs / 255.0) & (e < 0.9 * fs)
        if keep.sum() < 10 * n_bins:
            return 0.0
        ev, rv = e[keep], self._residual[keep]
        edges = np.quantile(ev, np.linspace(0, 1, n_bins + 1))
        idx = np.clip(np.searchsorted(edges, ev, side="right") - 1, 0, n_bins - 1)
        real_std, model_std, count = [], [], []
        for b in range(n_bins):
            sel = idx == b
            if sel.sum() < 10:
                continue
            real_std.append(float(rv[sel].std()))
            if out.compression == "gamma":
                g = out.gamma
                c = math.sqrt(math.exp(gammaln(1 + 2 * g) - 2 * gammaln(1 + g)) - 1.0)
                model_std.append(c * float(ev[sel].mean()))
            else:
                model_std.append(LOG_SPECKLE_STD_DB * fs / (out.ceiling_db - out.floor_db))
            count.append(int(sel.sum()))
        if not count:
            return 0.0
        a, m, w = np.array(real_std), np.array(model_std), np.array(count, dtype=float)
        # The shape of spread against level tells the laws apart (a gamma's grows with the
        # level, a log's is flat); its scale is the compression's shape, set afterwards from the
        # speckle (_fit_speckle), and a grain longer than the local mean's window lowers the
        # measured spread: the model's curve is scaled to the recording's before they are compared.
        # Compared as variances (counts^2, the units of the cost it is added to: a frame's
        # squared error is the mean's error squared plus the speckle's variance).
        a2, m2 = a ** 2, m ** 2
        k = float((w * a2 * m2).sum() / max((w * m2 * m2).sum(), 1e-300))
        return float((w * np.abs(a2 - k * m2)).sum() / w.sum())

    def search(self, spec: SensorSpec, start: dict, active: Sequence[str], budget: int) -> tuple[dict, float]:
        """Nelder-Mead over the parameters ``active`` from ``start`` (the others held), bounded
        by clipping a scaled transform (``x = start + u * step``)."""
        active = list(active)
        lo = np.array([self.bounds[n][0] for n in active])
        hi = np.array([self.bounds[n][1] for n in active])
        step = np.array([STEPS[n] for n in active])
        x0 = np.clip(np.array([start[n] for n in active]), lo, hi)

        def values_of(u):
            return {**start, **dict(zip(active, np.clip(x0 + u * step, lo, hi)))}

        def f(u):
            return self.cost(spec, values_of(u))

        n = len(active)
        r = optimize.minimize(f, np.zeros(n), method="Nelder-Mead",
                              options={"maxiter": budget, "xatol": 1e-3, "fatol": 1e-4,
                                       "initial_simplex": np.vstack([np.zeros(n), np.eye(n)])})
        v = {k: float(x) for k, x in values_of(r.x).items()}
        return v, float(r.fun)


def _band_starts(real: SonarImage, problem: _Problem, free: tuple[str, ...], width0: float,
                 half_angles: Sequence[float] | None) -> tuple[list[dict], object]:
    """Closed-form start poses (one per half-angle) from the recording's floor band, or the
    user's pose alone where no pose parameter that the band tells is free or no band is found."""
    from .bandpose import pose_for_half_angle, pose_from_near_edge

    user = {"half_angle_deg": None, "elevation_width_deg": width0, "pose": {}}
    if not {"z", "pitch", "roll"} & set(free):
        return [user], None
    lines = band_lines(real)
    if lines is None:
        return [user], None
    starts = []
    for h in (HALF_ANGLES_DEG if half_angles is None else half_angles):
        try:
            z, pitch, roll = (pose_for_half_angle(lines, h) if lines.both_edges
                              else pose_from_near_edge(lines, problem.pose0["z"] - _ground_height(problem.scene), h))
        except ValueError:
            continue
        pose = {}
        if "z" in free:
            pose["z"] = z + _ground_height(problem.scene)
        if "pitch" in free:
            pose["pitch"] = pitch
        if "roll" in free:
            pose["roll"] = roll
        starts.append({"half_angle_deg": float(h), "elevation_width_deg": float(h) / EDGE_RATIO, "pose": pose})
    return (starts or [user]), lines


def band_lines(real: SonarImage):
    """The recording's floor band edges as lines (:func:`~sonarsim.analysis.bandpose.fit_band_lines`),
    or None where it shows no band edge to fit them to."""
    from .bandpose import fit_band_lines
    from .fitting import floor_band_m

    try:
        near, far = floor_band_m(real)
        return fit_band_lines(real.azimuth_deg, near, far)
    except ValueError:
        return None


def no_band_edge_problem(told: Sequence[str]) -> str:
    """Why height, pitch or roll (``told``) free are refused on a recording without a floor band
    edge (both methods)."""
    return (f"the recording shows no floor band edge, so {', '.join(told)} {'is' if len(told) == 1 else 'are'} not "
            "identified by it: bound the pose with `sonarsim fit`, hold it (leave it out of --free) and calibrate "
            "the sensor")


def _ground_height(scene: Scene) -> float:
    return float(scene.ground.offset_m) if scene.ground is not None else 0.0


def calibrate(real: SonarImage, scene: Scene, free: Sequence[str] = (), max_iterations: int = 600,
              fit_grain: bool = True, water_weight: float = WATER_WEIGHT,
              spreading: Sequence[float] | None = (20.0, 30.0, 40.0),
              compressions: Sequence[str] | None = COMPRESSIONS, half_angles_deg: Sequence[float] | None = None,
              family: bool = True, progress: Callable[[str], None] | None = None,
              refuse_degenerate: bool = True, channels: bool = True, common_noise: bool = True,
              texture: bool = True, pattern_correction: bool = False,
              range_correction: bool = True) -> CalibrationResult:
    """Fit the sensor (and the free pose parameters) so that the expected render matches ``real``.

    Parameters
    ----------
    real : SonarImage
        One frame of a recording, in the device's units (e.g. 0-255).
    scene : Scene
        The scene behind it; its ``sensor`` (or :data:`STARTING_SENSOR`) and pose are the start.
        The image grid is the recording's (its beams and range bins).
    free : sequence of str
        Pose parameters to fit as well. Where z, pitch or roll are free and the recording shows
        a floor band, the starts are the band's closed-form poses (the user's pose matters only
        for the others, and for the height where the band has no far edge).
    max_iterations : int
        Budget of each refining simplex search (the sensor-only starts get at most
        :data:`START_ITERATIONS`).
    fit_grain : bool
        Also set the receive beams' azimuth width from the speckle grain across beams.
    water_weight : float
        Weight of the water column's mean range profile (squared error of its rows' means, in
        device units squared) added to the pixels' mean squared error.
    spreading : sequence of float, optional
        TVG spreading laws (dB per decade) to try. ``None``: the starting sensor's.
    compressions : sequence of str, optional
        Output laws to try (:data:`COMPRESSIONS`). ``None``: the starting sensor's.
    half_angles_deg : sequence of float, optional
        Half-angles of the closed-form starts (default :data:`HALF_ANGLES_DEG`).
    family : bool
        Scan the family of equally good poses (step 5 above).
    progress : callable, optional
        Called with a line of text as each stage ends (the CLI prints it on stderr).
    refuse_degenerate : bool
        Raise :class:`CalibrationFailed` on a degenerate outcome (else list it in ``warnings``).
    channels : bool
        Fit the receive channels' structure (:func:`_fit_channels`): the across-fan gain
        (``sensor.beam_gain``: steering exponent and per-beam stripes) and the bang's pattern
        across beams (``sensor.bang.beam_db``).
    common_noise : bool
        Fit the noise common to a row's beams (``sensor.noise.common_db``, ``common_length_m``)
        from the water column's correlation across beams (:func:`_fit_common_noise`); kept
        where the expected image fits better with it.
    pattern_correction : bool
        Fit the elevation pattern's departure from its shape
        (``elevation_pattern.correction_db``, :func:`_fit_elevation_correction`) at the fitted
        pose; kept where the fit is better for it. Off by default: on a synthetic recording
        made with the very pattern it gains 0.17 dB (1.97 dB RMS of correction) by fitting the
        one frame's speckle, more than the 0.10 dB it gains on the real Oculus ping, so one
        frame is no evidence for it.
    range_correction : bool
        Fit the range law's departure from its formula (``tvg.correction_db``, a smooth curve
        of :data:`RANGE_CORRECTION_KNOTS` knots over the window, :func:`_fit_range_correction`)
        at the final pose; kept where the fit is better for it. Over a flat floor it draws the
        sea bed's angular response as much as the device's TVG curve: the two are one function
        of range there.
    texture : bool
        Estimate the floor's texture (``ground.texture``) from the lit band
        (:func:`_fit_texture`). The calibrated scene carries it (its renders are patchy like
        the recording); ``expected`` and the PSNR are the texture's expectation (the field's
        realisation under the recording cannot be known from its parameters): the expectation
        over the texture's distribution of the expected output, the gain refitted to it
        (:func:`_texture_mean`: through a gamma or log output a patchy floor's mean count is
        lower than a uniform one's).

    Raises
    ------
    CalibrationFailed
        The result is degenerate (see step 4 above); ``exc.result`` holds it.
    """
    say = progress or (lambda line: None)
    free = tuple(free)
    check_overlap(real, scene)
    sonar = recording_geometry(real, scene)  # the recording's grid, as fit_pose renders
    spec0 = scene.sensor if scene.sensor is not None else parse_sensor(STARTING_SENSOR)
    if spec0.output is None or spec0.output.compression not in COMPRESSIONS:
        raise ConfigError("sensor.output", f"calibration fits an output with compression {' or '.join(COMPRESSIONS)}")
    refused = frame_problems(real.polar)
    if refused:  # the same verdict as the gradient calibration's, before any search
        raise CalibrationFailed(["the recording holds no echo to calibrate on: " + "; ".join(refused)], None)
    problem = _Problem(real, scene, sonar, free, water_weight, parameter_bounds(spec0, sonar))
    target, lit = problem.target, problem.lit
    peak = spec0.output.full_scale
    start_values = {**sensor_values(spec0, sonar.elevation_fov_deg), **{k: problem.pose0[k] for k in free}}
    start_values = {k: float(np.clip(x, *problem.bounds[k])) for k, x in start_values.items()}
    c0 = problem.cost(spec0, start_values)

    laws = []
    for comp in ([spec0.output.compression] if compressions is None else compressions):
        shape = output_shape(comp, target, lit, peak)
        for law in ([None] if spreading is None or spec0.tvg is None else spreading):
            laws.append(with_law(spec0, comp, law, shape))
    starts, lines = _band_starts(real, problem, free, start_values["elevation_width_deg"], half_angles_deg)
    told = [k for k in ("z", "pitch", "roll") if k in free]
    if told and lines is None and refuse_degenerate:
        # Without a band edge, the range profile alone sets height, tilt and the elevation
        # pattern together: on the ARIS sample (a sea bed lit across the whole window) the search
        # ended 4.9 m up, pitched 86 degrees down and rolled 43, with a 50-degree pattern.
        raise CalibrationFailed([no_band_edge_problem(told)], None)
    names = sensor_names(spec0)
    # The starts fit the sensor at their own pose and width: one render each.
    level_names = [n for n in names if n != "elevation_width_deg"] if len(starts) > 1 else names
    tried = []
    for k, st in enumerate(starts):
        v0 = {**start_values, **st["pose"], "elevation_width_deg": float(np.clip(st["elevation_width_deg"],
                                                                                 *problem.bounds["elevation_width_deg"]))}
        for spec in laws:
            v, c = problem.search(spec, v0, level_names, min(max_iterations, START_ITERATIONS))
            tried.append({"start": k, "spec": spec, "values": v, "cost": c})
        here = min((t for t in tried if t["start"] == k), key=lambda t: t["cost"])
        h = st["half_angle_deg"]
        say(f"start {k + 1}/{len(starts)}" + (f" (band edges at +-{h:g} deg)" if h is not None else " (the scene's pose)")
            + f": best law PSNR {problem.psnr(here['spec'], here['values'], peak):.2f} dB")
    tried.sort(key=lambda t: t["cost"])
    # Refined with the pose: the best starts overall, and each law's best start (a law is
    # chosen with the pose, not before it: ranked at a start's pose, the right law can trail).
    chosen = tried[:REFINED]
    for key in dict.fromkeys(law_key(t["spec"]) for t in tried):
        first = next(t for t in tried if law_key(t["spec"]) == key)
        if first not in chosen:
            chosen.append(first)
    refined = []
    for t in chosen:
        v, c = problem.search(t["spec"], t["values"], names + list(free), max_iterations)
        refined.append({**t, "values": v, "cost": c, "from": t["values"]})
        law = law_of(t["spec"])
        tvg = f", {law['spreading']:g} log r" if law["spreading"] is not None else ""
        say(f"refined start {t['start'] + 1} ({law['compression']}{tvg}): "
            f"PSNR {problem.psnr(t['spec'], v, peak):.2f} dB")
    # The laws are told apart by the speckle's spread as much as by the mean: a gamma output's
    # spread in counts grows with the level, a log output's does not; both fit the mean image.
    for t in refined:
        t["rank"] = t["cost"] + problem.spread_mismatch(t["spec"], t["values"])
    best = min(refined, key=lambda t: t["rank"])
    spec, v = best["spec"], best["values"]
    start_report = []
    for t in tried:
        st = starts[t["start"]]
        rec = {"half_angle_deg": st["half_angle_deg"], **law_of(t["spec"]),
               "pose": {k: t["values"][k] for k in free}, "psnr_db": problem.psnr(t["spec"], t["values"], peak)}
        for r in refined:
            if r["start"] == t["start"] and r["spec"] is t["spec"]:
                rec["refined_psnr_db"] = problem.psnr(r["spec"], r["values"], peak)
        start_report.append(rec)

    if pattern_correction:
        spec, v = _fit_elevation_correction(problem, spec, v, say)
    if channels:
        spec_c, v_c = _fit_channels(problem, spec, v, max_iterations, say)
        # The closed forms move the levels; kept only where the fit is better for them.
        if problem.cost(spec_c, v_c) < problem.cost(spec, v):
            spec, v = spec_c, v_c
        else:
            say("channels: not kept (no better than without them)")
    if common_noise:
        spec_n, v_n = _fit_common_noise(problem, spec, v, max_iterations, say)
        if spec_n is not spec and problem.cost(spec_n, v_n) < problem.cost(spec, v):
            spec, v = spec_n, v_n
        elif spec_n is not spec:
            say("common noise: not kept (no better than without it)")
    e, pose, s2 = problem.expected(spec, v)
    if fit_grain and s2.speckle is not None:
        spec, v, s2 = _fit_speckle(problem, real, spec, v, s2, free, max_iterations, peak, say)
        pulse = (f", CW pulse {s2.pulse.length_us:.3g} us ({s2.pulse.length_us * 1e-6 * s2.sound_speed_m_s / 2 * 1e3:.3g} "
                 "mm of range)" if s2.pulse is not None and s2.pulse.kind == "cw" else "")
        say(f"speckle: {s2.speckle.looks:.3g} looks, azimuth width {s2.azimuth_pattern.width_deg:.3g} deg{pulse}, "
            f"{law_of(s2)['compression']} shape {law_of(s2)['shape']:.4g}")

    family_report: dict = {}
    if family and lines is not None and getattr(lines, "both_edges", False) and {"z", "pitch"} <= set(free):
        # The range law's correction is fitted after, at the member chosen: fitted at every
        # member's pose as well, it chose another member, 0.02 dB worse on the Oculus ping with
        # it, for 85 s more.
        spec, v, family_report = _family(problem, spec, v, free, max_iterations, peak, say)

    if range_correction:
        spec, v = _fit_range_correction(problem, spec, v, say)
    e, pose, s2 = problem.expected(spec, v)
    if fit_grain and s2.speckle is not None and spec.azimuth_pattern is not None:
        s2 = replace(s2, azimuth_pattern=spec.azimuth_pattern, pulse=spec.pulse)
    law = law_of(s2)
    values = dict(v)
    values["tvg_spreading"] = law["spreading"] if law["spreading"] is not None else 0.0
    if law["compression"] == "gamma":
        values["gamma"] = s2.output.gamma
    else:
        values["log_span_db"] = law["shape"]
    if s2.azimuth_pattern is not None and s2.azimuth_pattern.width_deg is not None:
        values["azimuth_width_deg"] = s2.azimuth_pattern.width_deg
    if s2.pulse is not None and s2.pulse.kind == "cw":
        values["pulse_length_us"] = float(s2.pulse.length_us)
    if s2.speckle is not None:
        values["looks"] = float(s2.speckle.looks)
    if s2.tvg is not None and s2.tvg.correction_db is not None:
        values["range_correction_rms_db"] = float(np.std(s2.tvg.correction_db))
    if s2.beam_gain is not None:
        values["steering_exponent"] = s2.beam_gain.steering_exponent
        if s2.beam_gain.gain_db is not None:
            values["stripes_rms_db"] = float(np.sqrt(np.mean(np.square(s2.beam_gain.gain_db))))
    # The recording's grid, so that the calibrated scene renders frames like the recording's.
    fitted = replace(scene, sensor=s2, sonar=sonar, sonar_pose=pose)
    tex = _fit_texture(problem, spec, v, pose, say) if texture else None
    if tex is not None:
        values["texture_std_db"] = tex.std_db
        values["texture_correlation_range_m"], values["texture_correlation_across_m"] = tex.correlation_m
        e, v["gain_db"] = _texture_mean(problem, spec, v, tex, say)
        values["gain_db"] = v["gain_db"]
        s2 = replace(s2, gain_db=v["gain_db"])
        fitted = replace(fitted, sensor=s2, ground=replace(fitted.ground, texture=tex))
    mse = float(np.mean((e - target) ** 2))
    image = SonarImage(polar=e, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg, components={"expected": e},
                       sonar=sonar, pose=pose, config=fitted.to_dict())
    result = CalibrationResult(fitted, values, _psnr(mse, peak), _psnr(c0, peak), problem.renders, image,
                               starts=start_report, family=family_report, law=law)
    result.baselines = _baselines(target, peak)
    best_trivial = max(result.baselines["range profile"], result.baselines["separable"])
    if result.psnr_db < best_trivial:
        result.warnings.append(
            f"the calibrated model scores {result.psnr_db:.2f} dB on the frame it was fitted to, below a trivial "
            f"image (the frame's own {'range profile' if best_trivial == result.baselines['range profile'] else 'separable range x beam profile'}"
            f": {best_trivial:.2f} dB): the model explains less of this frame than a profile does")
    problems = _degenerate(problem, s2, spec, v, best, free, pose) + model_problems(target, e)
    # Values at a bound where moving off it changes nothing (not refused by _degenerate): the
    # recording does not determine them there; said, not hidden (the ARIS sample's noise_db 0).
    _, at = bound_report(v, {k: problem.bounds[k] for k in sensor_names(spec)})
    if s2.beam_gain is not None and s2.beam_gain.steering_exponent >= MAX_STEERING_EXPONENT:
        at.append(f"steering_exponent {s2.beam_gain.steering_exponent:.4g} (bounds 0 to {MAX_STEERING_EXPONENT:g}: "
                  "the fan's profile falls off faster than a steering loss; the stripes hold the rest)")
    pinned_text = " ".join(problems)
    at = [a for a in at if a.split(" ")[0] + " " not in pinned_text]
    if at:
        result.warnings.append("parameters at their bounds, which the frame does not determine there (the fit is "
                               "as good on the bound as off it): " + ", ".join(at))
    result.at_bounds = [a.split(" ")[0] for a in at]
    if problems:
        if refuse_degenerate:
            raise CalibrationFailed(problems, result)
        result.warnings.extend(problems)
    return result


def sensor_names(spec: SensorSpec) -> list[str]:
    """The searched sensor parameters (:data:`SENSOR_PARAMETERS`, in its order) that act in
    ``spec``: no bang, no bang parameters."""
    absent = set()
    if spec.noise is None:
        absent |= {"noise_db", "noise_after_tvg_db"}
    if spec.bang is None:
        absent |= {"bang_db", "bang_length_m", "bang_hold_m", "ringing_db", "ringing_length_m"}
    if spec.elevation_pattern is None:
        absent.add("elevation_width_deg")
    return [n for n in SENSOR_PARAMETERS if n not in absent]


def law_key(spec: SensorSpec) -> tuple:
    law = law_of(spec)
    return (law["compression"], law["spreading"])


def _baselines(target: np.ndarray, peak: float) -> dict:
    """PSNR (dB) of the frame's trivial images and its local mean against the frame itself."""
    from . import metrics
    from .baselines import baseline_images

    return {name: metrics.psnr(target, img, data_range=peak) for name, img in baseline_images(target).items()}


def _fit_speckle(problem: _Problem, real: SonarImage, spec: SensorSpec, v: dict, s2: SensorSpec,
                 free: tuple[str, ...], max_iterations: int, peak: float, say=None):
    """The azimuth width from the grain across beams, the looks from the speckle's shape
    (:func:`_fit_looks`), then the output's shape corrected by the ratio of the recording's
    speckle statistic to the model's (the closed forms assume independent pixels; the grain
    correlates them), the sensor refitted at each correction.

    Several looks narrow the output's shape (less speckle spread to explain), and the levels are
    refitted to it; where that fits the calibration frame worse than one look does (the ARIS
    sample: 21.3 dB against 25.5 dB, the level search falling into a far wider elevation lobe
    from the narrower log span), one look is kept, and said.
    """
    seed = problem.scene.render.seed
    total, pose = problem.frame_for(spec, v)
    s2 = _fit_grain(real, s2, problem.sonar, total, seed, pose)
    looked = _fit_looks(problem.target, s2, problem.sonar, total, seed, pose, problem.lit)
    one = replace(s2, speckle=replace(s2.speckle, looks=1.0))
    tried = [_shape_passes(problem, real, spec, v, one, max_iterations, peak, pose)]
    if looked.speckle.looks != 1.0:
        tried.append(_shape_passes(problem, real, spec, v, looked, max_iterations, peak, pose))
        costs = [problem.cost(t[0], t[1]) for t in tried]
        if costs[1] > costs[0] and say is not None:
            say(f"looks: {looked.speckle.looks:g} from the speckle's shape, not kept (the frame fits worse: PSNR "
                f"{problem.psnr(tried[1][0], tried[1][1], peak):.2f} dB against {problem.psnr(tried[0][0], tried[0][1], peak):.2f} "
                "dB with one look)")
        return tried[int(costs[1] <= costs[0])]
    return tried[0]


def _shape_passes(problem: _Problem, real: SonarImage, spec: SensorSpec, v: dict, s2: SensorSpec,
                  max_iterations: int, peak: float, pose):
    """The output's shape corrected over :data:`GAMMA_PASSES`, with ``s2``'s speckle (grain and
    looks); returns ``(spec, v, s2)``."""
    lit = problem.lit
    seed = problem.scene.render.seed
    compression = spec.output.compression
    spec = replace(spec, speckle=s2.speckle)
    stat = _statistic(compression, peak)
    want = stat(problem.target, lit)
    for _ in range(GAMMA_PASSES):
        got = stat(_speckled(s2, problem.sonar, problem.frame_for(spec, v)[0], seed, pose), lit)
        ratio = want / got
        if abs(ratio - 1.0) < GAMMA_TOLERANCE:
            break
        # Contrast is nearly proportional to gamma; the log's spread in counts inversely to its span.
        shape = law_of(spec)["shape"] * (ratio if compression == "gamma" else 1.0 / ratio)
        spec = with_law(replace(spec, azimuth_pattern=s2.azimuth_pattern, pulse=s2.pulse), compression, None,
                        float(np.clip(shape, 0.05, 4.0) if compression == "gamma" else np.clip(shape, MIN_SPAN_DB, MAX_SPAN_DB)))
        v, _ = problem.search(spec, v, sensor_names(spec), max_iterations)
        e, pose, s2 = problem.expected(spec, v)
        s2 = _fit_grain(real, s2, problem.sonar, problem.frame_for(spec, v)[0], seed, pose)
    spec = replace(spec, azimuth_pattern=s2.azimuth_pattern, pulse=s2.pulse, speckle=s2.speckle)
    return spec, v, s2


#: The looks tried, in order (a device averages a whole number of looks: pings, sub-apertures,
#: bands); ``speckle.looks``'s bounds. A real number of looks is a law of another shape (its
#: contrast exact, its asymmetry not monotonic between the integers).
LOOKS_TRIED = (1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 16, 20, 24, 32, 40, 48, 64)
#: The log-domain asymmetry by which the recording's must exceed one look's for looks to be
#: fitted: pools of three seeds differ by up to 0.01 over a 450 x 64 frame.
ASYMMETRY_TOLERANCE = 0.01


def _fit_looks(target: np.ndarray, spec: SensorSpec, sonar, total: np.ndarray, seed: int, pose,
               lit: np.ndarray) -> SensorSpec:
    """The looks whose speckle, in the lit band, has the recording's log-domain asymmetry.

    The quantile asymmetry of the log-domain values about their local mean
    (:func:`~sonarsim.analysis.realism.log_asymmetry`) measures the speckle's shape apart from
    the output's scale: the gamma exponent or the log's span (fitted after, from the contrast)
    scale the log-domain spread and leave its shape. The log-variance (the trigamma function of
    L) would tell the looks too, but only with the output's scale known, which is fitted from
    that same spread. One look gives -0.27; more looks less, towards 0. Matched on the model's
    own speckled frame (the same grain, quantiser and noise as the recording's), over the whole
    numbers of :data:`LOOKS_TRIED` (the nearest); kept at one look where the recording is within
    :data:`ASYMMETRY_TOLERANCE` of it (or more asymmetric: a texture, not looks).
    """
    from ..sensor.model import SensorModel

    if spec.speckle is None:
        return spec
    log_domain = spec.output is not None and spec.output.compression == "log"
    want = realism.log_asymmetry(target, lit, log_domain)

    def with_looks(looks: float) -> SensorSpec:
        return replace(spec, speckle=replace(spec.speckle, looks=float(looks)))

    def asymmetry(looks: float) -> float:
        m = SensorModel(with_looks(looks), sonar, seed)
        return realism.log_asymmetry(m.apply(total, m.anchored_rng(pose.position_m, pose.rpy_deg)), lit,
                                     log_domain) - want

    gaps = []
    for looks in LOOKS_TRIED:  # the asymmetry falls towards 0 as the looks grow: stop past the recording's
        gaps.append(asymmetry(looks))
        if len(gaps) == 1 and gaps[0] >= -ASYMMETRY_TOLERANCE:
            break
        if gaps[-1] >= 0.0:
            break
    best = int(np.argmin(np.abs(gaps)))
    return with_looks(float(LOOKS_TRIED[best]))


#: Passes of the channels' closed forms (per-beam gains, the bang's pattern), each followed by a
#: short refit of the sensor's levels.
CHANNEL_PASSES = 2

#: A range row belongs to the bang when, in the model, the bang is at least this share of its
#: expected power (echo and noise the rest).
BANG_SHARE = 0.5


def beam_ratio_db(real: np.ndarray, model: np.ndarray, output, rows: np.ndarray) -> np.ndarray:
    """Per beam, the power gain (dB) that brings the model's mean counts over ``rows`` to the
    recording's.

    With a gamma output a power gain G scales every expected count by ``G ** gamma``; with a
    log output it adds ``10 log10(G) * full_scale / span`` counts: both invert in closed form.
    Pixels near the quantiser's floor (under 5 counts of 255) or saturated are left out.

    Parameters
    ----------
    real, model : (n_range_bins, n_beams) arrays, counts
        The recording and the model's expected image.
    output : OutputSpec
    rows : (n_range_bins,) bool array
        The range rows used.

    Returns
    -------
    (n_beams,) float64 ndarray, dB (0 for a beam without usable pixels).
    """
    x, e = np.asarray(real, dtype=np.float64), np.asarray(model, dtype=np.float64)
    fs = output.full_scale
    # Counts near the quantiser's floor are rounded too coarsely to invert (a gain of 2 dB on
    # a pixel of 2 counts is lost in the rounding): at least 5 counts of 255.
    keep = rows[:, None] & (e > 5.0 * fs / 255.0) & (e < 0.98 * fs)
    n = keep.sum(axis=0)
    sr, se = np.where(keep, x, 0.0).sum(axis=0), np.where(keep, e, 0.0).sum(axis=0)
    ok = (n >= 2) & (sr > 0) & (se > 0)
    out = np.zeros(x.shape[1])
    if output.compression == "gamma":
        out[ok] = 10.0 / output.gamma * np.log10(sr[ok] / se[ok])
    else:
        out[ok] = (sr[ok] - se[ok]) / n[ok] * (output.ceiling_db - output.floor_db) / fs
    return out


def _fit_channels(problem: _Problem, spec: SensorSpec, v: dict, max_iterations: int, say):
    """The receive channels' structure in closed form: the across-fan gain (steering loss
    ``cos^n`` and stripes, from the beams' mean levels beyond the bang) and the bang's
    pattern across beams (from the rows the bang dominates), the levels refitted after each."""
    from ..config.sensor import BeamGainSpec
    from ..sensor import channels

    sonar = problem.sonar
    steer = 10.0 * np.log10(np.cos(np.radians(np.asarray(sonar.azimuth_deg, dtype=float))))
    target = problem.target
    for _ in range(CHANNEL_PASSES):
        e, pose, s2 = problem.expected(spec, v)
        m = problem.model(s2)
        total, _ = problem.frame_for(spec, v)
        echo_row = np.median(m.echo_gain[:, None] * np.asarray(m.mean_image(total), dtype=np.float64), axis=1)
        bang = np.asarray(m.bang, dtype=np.float64)
        share = bang / np.maximum(bang + np.asarray(m.noise_row, dtype=np.float64) + echo_row, 1e-300)
        bang_rows = share >= BANG_SHARE
        # Across the fan: the channels' gain, fitted as k + n * 10 log10 cos(theta) + stripes.
        current = np.asarray(m.beam_gain_db, dtype=float)
        rows = np.flatnonzero(~bang_rows)
        ratio = beam_ratio_db(target, e, s2.output, ~bang_rows)
        # The ratio's noise (speckle, not the channels): half the difference of the ratios
        # measured on the window's near and far halves.
        half = np.zeros(len(bang_rows), bool)
        half[rows[: len(rows) // 2]] = True
        noise_var = float(np.var(beam_ratio_db(target, e, s2.output, half)
                                 - beam_ratio_db(target, e, s2.output, ~bang_rows & ~half))) / 4.0
        want = current + ratio
        design = np.column_stack([np.ones_like(steer), steer])
        coef = np.linalg.lstsq(design, want, rcond=None)[0]
        # The exponent's standard error from the ratio's noise: one that speckle could draw
        # (within two standard errors of none) is none.
        se = math.sqrt(noise_var * float(np.linalg.pinv(design.T @ design)[1, 1]))
        n = float(np.clip(coef[1], 0.0, MAX_STEERING_EXPONENT)) if coef[1] > 2.0 * se else 0.0
        stripes = want - n * steer
        k = float(stripes.mean())
        stripes = stripes - k
        # Shrunk towards none by how much of their spread the noise explains (James-Stein):
        # stripes drawn from speckle alone are fitted as (nearly) none.
        spread = float(np.mean(stripes ** 2))
        stripes = np.clip(stripes * max(0.0, 1.0 - noise_var / spread) if spread > 0 else stripes, -60.0, 60.0)
        v = {**v, "gain_db": float(np.clip(v["gain_db"] + k, *problem.bounds["gain_db"]))}
        spec = replace(spec, beam_gain=BeamGainSpec(steering_exponent=n, gain_db=tuple(float(x) for x in stripes)))
        if spec.bang is not None and bang_rows.sum() >= 1:
            e, _, s2 = problem.expected(spec, v)
            pattern = channels.bang_beam_db(s2.bang, sonar.n_beams) + beam_ratio_db(target, e, s2.output, bang_rows)
            b = float(pattern.mean())
            spec = replace(spec, bang=replace(spec.bang, beam_db=tuple(float(x) for x in np.clip(pattern - b, -60, 60))))
            v["bang_db"] = float(np.clip(v["bang_db"] + b, *problem.bounds["bang_db"]))
        v, _ = problem.search(spec, v, [n_ for n_ in sensor_names(spec) if n_ != "elevation_width_deg"],
                              max(max_iterations // 2, 1))
    stripes_rms = float(np.sqrt(np.mean(np.square(spec.beam_gain.gain_db))))
    say(f"channels: steering loss cos^{spec.beam_gain.steering_exponent:.3g}, stripes {stripes_rms:.2f} dB RMS"
        + (f", bang pattern {float(np.std(spec.bang.beam_db)):.2f} dB RMS over {int(bang_rows.sum())} rows"
           if spec.bang is not None and spec.bang.beam_db is not None else "")
        + f": PSNR {problem.psnr(spec, v, spec.output.full_scale):.2f} dB")
    return spec, v


#: Beam lags over which the water column's across-beam correlation is measured: beyond the
#: beamformer's grain (1-2 beams), where independent noise is uncorrelated.
COMMON_LAGS = (3, 4, 5, 6)
#: Range bands of the water column the common noise is measured in.
COMMON_BANDS = 8
#: Below this amplitude correlation a band holds no common noise (an intensity correlation of
#: 0.09: well above the estimate's noise, about 1 / sqrt(pixels), and the leakage of structure
#: that repeats across beams).
COMMON_FLOOR = 0.3


def counts_to_power(counts: np.ndarray, output) -> np.ndarray:
    """Invert an output law (without its clipping): counts -> power over the ceiling (gamma,
    linear) or 10^(level / 10) (log), up to a constant factor. For the texture's estimator."""
    x = np.clip(np.asarray(counts, dtype=np.float64), 0.0, None) / output.full_scale
    if output.compression == "gamma":
        return x ** (1.0 / output.gamma)
    if output.compression == "log":
        return 10.0 ** (x * (output.ceiling_db - output.floor_db) / 10.0)
    return x


def across_beam_correlation(image: np.ndarray, rows: np.ndarray, mask: np.ndarray,
                            lags: Sequence[int] = COMMON_LAGS) -> float:
    """Correlation of a frame's residual (less its local mean along range) between beams
    ``lags`` apart, over the pixels of ``rows`` inside ``mask``: what noise common to a row's
    beams adds (independent noise and speckle have none beyond the beam's grain)."""
    x = np.asarray(image, dtype=np.float64)
    res = x - realism.local_mean(x, (9, 1))
    vals = []
    for lag in lags:
        m = (mask[:, :-lag] & mask[:, lag:])[rows]
        if m.sum() < 50:
            continue
        a, b = res[rows][:, :-lag][m], res[rows][:, lag:][m]
        if a.std() > 0 and b.std() > 0:
            vals.append(float(np.corrcoef(a, b)[0, 1]))
    return float(np.mean(vals)) if vals else float("nan")


def _fit_common_noise(problem: _Problem, spec: SensorSpec, v: dict, max_iterations: int, say):
    """Noise common to a row's beams, from the water column's correlation across beams.

    In a band of rows where the noise dominates, beams ``lags`` apart correlate (in intensity)
    by ``f**2`` with ``f = C / (C + N)`` (Siegert), C the common noise's power and N the
    independent noise's: so ``C = N f / (1 - f)`` with N the model's noise there. The bands'
    C are fitted by ``C0 exp(-r / L)`` (log-linear least squares), the levels then refitted
    (the independent noise gives up what the common takes).
    """
    if spec.noise is None:
        return spec, v
    target, water, r = problem.target, problem.water, np.asarray(problem.sonar.range_m, dtype=float)
    rows_all = np.flatnonzero(problem.water_rows)
    if len(rows_all) < COMMON_BANDS * 4:
        return spec, v
    e, pose, s2 = problem.expected(spec, v)
    m = problem.model(s2)
    noise = np.asarray(m.noise_row, dtype=np.float64) + np.asarray(m.common_power, dtype=np.float64)
    rs, cs = [], []
    for chunk in np.array_split(rows_all, COMMON_BANDS):
        rows = np.zeros(len(r), dtype=bool)
        rows[chunk] = True
        rho = across_beam_correlation(target, rows, water)
        if not np.isfinite(rho):
            continue
        f = math.sqrt(max(rho, 0.0))
        if f < COMMON_FLOOR:
            continue
        f = min(f, 0.95)
        rs.append(float(r[chunk].mean()))
        cs.append(float(np.mean(noise[chunk])) * f / (1.0 - f))
    if len(rs) < 2:
        say("common noise: none found across the water column's beams")
        return spec, v
    slope, intercept = np.polyfit(np.array(rs), np.log(np.array(cs)), 1)
    length = -1.0 / slope if slope < 0 else None
    common_db = float(10.0 * intercept / math.log(10.0))
    if length is not None:
        length = float(np.clip(length, 1e-3, 1e4))
    trial = replace(spec, noise=replace(spec.noise, common_db=float(np.clip(common_db, -300, 300)),
                                        common_length_m=length))
    v2, _ = problem.search(trial, v, [n for n in sensor_names(trial) if n != "elevation_width_deg"],
                           max(max_iterations // 2, 1))
    say(f"common noise: {common_db:.1f} dB" + (f", decaying over {length:.3g} m" if length else "")
        + f" (from {len(rs)} bands of the water column): PSNR {problem.psnr(trial, v2, spec.output.full_scale):.2f} dB")
    return trial, v2


#: Texture spreads (dB) the model's frames are rendered with to match the recording's statistic.
TEXTURE_GRID_DB = (0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0)
#: Blocks (range bins, beams) of :func:`log_block_variance`.
TEXTURE_BLOCK = (4, 4)


def log_block_variance(image: np.ndarray, expected: np.ndarray, mask: np.ndarray, output,
                       block: tuple[int, int] = TEXTURE_BLOCK) -> float:
    """Variance of the log of block means of ``image`` over ``expected`` (both in counts, turned
    into power by ``output``), each row of blocks less its mean: the floor's patchiness plus
    the speckle's share, with the range trend and the gain removed.

    Parameters
    ----------
    image, expected : (n_range_bins, n_beams) arrays, counts
    mask : (n_range_bins, n_beams) bool array
        The lit floor; blocks wholly inside it are used.
    output : OutputSpec
    block : (int, int)

    Returns
    -------
    float (natural-log units squared); nan with fewer than 10 blocks.
    """
    p = counts_to_power(image, output) / np.maximum(counts_to_power(expected, output), 1e-300)
    nb, na = block
    n_r, n_b = (p.shape[0] // nb) * nb, (p.shape[1] // na) * na
    blocks = p[:n_r, :n_b].reshape(n_r // nb, nb, n_b // na, na).mean(axis=(1, 3))
    inside = mask[:n_r, :n_b].reshape(n_r // nb, nb, n_b // na, na).all(axis=(1, 3)) & (blocks > 0)
    if inside.sum() < 10:
        return float("nan")
    lg = np.where(inside, np.log(np.where(inside, blocks, 1.0)), 0.0)
    count = inside.sum(axis=1)
    row_mean = np.divide(lg.sum(axis=1), count, out=np.zeros(len(count)), where=count > 0)
    res = (lg - row_mean[:, None])[inside & (count[:, None] >= 2)]
    return float(res.var()) if len(res) >= 10 else float("nan")


def _fit_texture(problem: _Problem, spec: SensorSpec, v: dict, pose: Pose, say):
    """The floor's texture (a world-anchored log-normal reflectivity) from the lit band's
    excess variance of local means (:func:`sonarsim.scene.floor_texture.estimate_texture`),
    on the recording's counts turned back into power by the fitted output law, less what the
    estimator reads in the calibrated model's own (untextured) speckled frame."""
    from ..config.scene import TextureSpec
    from ..scene.floor_texture import estimate_texture

    scene = problem.scene
    if scene.ground is None:
        return None
    e, _, s2 = problem.expected(spec, v)
    mask = problem.lit & (e > 0)
    kwargs = dict(mask=mask, expected=counts_to_power(e, s2.output),
                  height_m=float(pose.position_m[2]) - _ground_height(scene))
    try:  # the correlation lengths: the estimator's, on the recording
        est = estimate_texture(counts_to_power(problem.target, s2.output), problem.sonar.range_m,
                               problem.sonar.azimuth_deg, **kwargs)
    except ValueError as exc:
        say(f"texture: not estimated ({exc})")
        return None
    cell = float(problem.sonar.range_resolution_m)
    # At least two range cells, and what a texture may be (MIN_CORRELATION_M: the Oculus's
    # 2.8 mm cells would allow 5.7 mm, which TextureSpec refuses).
    lengths = tuple(float(np.clip(x, max(2.0 * cell, MIN_CORRELATION_M), 1e4))
                    for x in (est.correlation_range_m, est.correlation_across_m))
    # The spread: the statistic's value in the recording matched by the calibrated model's own
    # speckled frames rendered with textures of known spreads (the estimator's closed form
    # assumes independent speckle cells; the model's frames carry the recording's grain).
    want = log_block_variance(problem.target, e, mask, s2.output)
    spreads, stats = [], []
    for sd in TEXTURE_GRID_DB:
        tex = TextureSpec(std_db=sd, correlation_m=lengths, angle_deg=float(pose.rpy_deg[2])) if sd > 0 else None
        sc = replace(scene, sensor=s2, sonar=problem.sonar, ground=replace(scene.ground, texture=tex))
        with Simulator(sc) as sim:
            frame = sim.render(pose, keep_rays=False).polar
        spreads.append(sd)
        stats.append(log_block_variance(frame, e, mask, s2.output))
        if stats[-1] >= want:
            break
    if want <= stats[0]:
        say(f"texture: none (the recording's block variance {want:.4g} is within the model's speckle, {stats[0]:.4g})")
        return None
    std_db = float(np.interp(want, stats, spreads)) if want < stats[-1] else float(spreads[-1])
    if std_db < TEXTURE_FLOOR_DB:
        say(f"texture: {std_db:.2f} dB, below {TEXTURE_FLOOR_DB} dB: none")
        return None
    spec_t = TextureSpec(std_db=std_db, correlation_m=lengths, angle_deg=float(pose.rpy_deg[2]))
    say(f"texture: {spec_t.std_db:.2f} dB, correlation {spec_t.correlation_m[0]:.3g} m along the range, "
        f"{spec_t.correlation_m[1]:.3g} m across ({est.n_blocks} blocks)")
    return spec_t


#: Gauss-Hermite nodes of the expectation over the texture's log-normal factor (:func:`_texture_mean`).
TEXTURE_NODES = 12


def _texture_mean(problem: _Problem, spec: SensorSpec, v: dict, tex, say) -> tuple[np.ndarray, float]:
    """The expected image of the textured floor, and the gain that fits it.

    The texture's mean reflectivity is 1, but the output law is not linear: through a gamma
    or a log, a patchy floor's mean count is lower than a uniform floor's of the same mean
    reflectivity (on the Oculus ping the textured speckled frames came out 5 % darker over the
    lit band than the expected image the gain had been fitted to). So the expected image is the
    expectation over the texture's factor ``F = exp(s g - s^2 / 2)`` (``g`` standard normal,
    ``s`` the spread in nepers) of the expected output of ``F`` times the noise-free floor
    image, by Gauss-Hermite quadrature (:data:`TEXTURE_NODES` nodes; exact in the texture's
    distribution, no draws: a mean over 16 rendered draws kept their patchiness, 1/4 of it,
    and lost 0.13 dB of PSNR), and the gain is refitted to it (the other parameters kept).
    ``F`` is taken as constant over the pulse's and the beam's kernels: the texture's
    correlation lengths are many cells (4.6 cm along the range against 2.8 mm cells on the
    Oculus ping). The echo is taken as the textured floor's alone, as in a floor scene.

    Returns
    -------
    expected : (n_range_bins, n_beams) ndarray
        The expectation over the texture of the expected output, at the refitted gain.
    gain_db : float
    """
    from scipy.optimize import minimize_scalar

    total, _ = problem.frame_for(spec, v)
    sigma = float(tex.std_db) * math.log(10.0) / 10.0
    x, w = np.polynomial.hermite.hermgauss(TEXTURE_NODES)
    factors = np.exp(sigma * math.sqrt(2.0) * x - 0.5 * sigma * sigma)
    weights = w / math.sqrt(math.pi)

    def mean_of(gain_db: float) -> np.ndarray:
        m = problem.model(with_values(spec, {**v, "gain_db": float(gain_db)}))
        return sum(wq * np.asarray(m.apply((fq * total).astype(np.float32), speckle=False), dtype=np.float64)
                   for fq, wq in zip(factors, weights))

    g0 = float(v["gain_db"])
    lo, hi = problem.bounds["gain_db"]
    fit = minimize_scalar(lambda g: problem.cost_of(mean_of(g)), bounds=(max(lo, g0 - 6.0), min(hi, g0 + 6.0)),
                          method="bounded", options={"xatol": 0.005})
    g = float(fit.x) if problem.cost_of(mean_of(fit.x)) <= problem.cost_of(mean_of(g0)) else g0
    e = mean_of(g)
    say(f"texture's mean ({TEXTURE_NODES}-node quadrature): gain {g0:.2f} -> {g:.2f} dB, PSNR "
        f"{_psnr(float(np.mean((e - problem.target) ** 2)), spec.output.full_scale):.2f} dB")
    return e, g


#: Knots of the elevation pattern's correction: one every this many degrees over the span.
CORRECTION_STEP_DEG = 2.0
#: Weight of the correction's roughness (its second differences, dB) in the least squares, per
#: knot, against the pixels' residuals (counts): a pattern varies smoothly with the angle.
CORRECTION_SMOOTHING = 20.0


def _fit_smooth_knots(expected_of, target: np.ndarray, n: int, smoothing: float, bound_db: float) -> np.ndarray:
    """Knot values (dB, within +-``bound_db``) whose expected image ``expected_of(x)`` fits
    ``target`` best in the least-squares sense on every other row (a tenth of a second per
    Jacobian on the real pings), with ``smoothing`` times their second differences as a
    roughness penalty (a pattern or a range law varies smoothly): what the corrections of the
    elevation pattern and of the range law both fit."""
    from scipy.optimize import least_squares

    rows = slice(None, None, 2)

    def residuals(x):
        r = (expected_of(x)[rows] - target[rows]).ravel()
        rough = smoothing * np.diff(x, 2) if len(x) > 2 else np.zeros(0)
        return np.concatenate([r / math.sqrt(r.size), rough / math.sqrt(max(len(rough), 1))])

    return least_squares(residuals, np.zeros(n), bounds=(-bound_db, bound_db), diff_step=0.05, max_nfev=40,
                         x_scale=3.0).x


def _fit_elevation_correction(problem: _Problem, spec: SensorSpec, v: dict, say):
    """The elevation pattern's departure from its shape (``elevation_pattern.correction_db``).

    The noise-free image is linear in the pattern's power at each knot of the correction
    (:func:`sonarsim.sensor.patterns.correction_gain` interpolates the knots' powers linearly):
    the image of each knot alone is rendered once at the fitted pose, and the knots' powers
    are fitted by bounded least squares on the expected image's counts, with a penalty on
    their roughness. On a flat floor each elevation angle lights one range along each beam,
    so the correction draws the range profile of the lit band the ideal array misses.
    """
    from ..sensor.patterns import correction_knots_deg

    el = spec.elevation_pattern
    if el is None:
        return spec, v
    s2 = with_values(spec, v)
    span = s2.elevation_pattern.span_deg
    n = int(np.clip(round(span / CORRECTION_STEP_DEG) + 1, 3, 256))
    base_el = replace(s2.elevation_pattern, correction_db=None)
    images = []
    pose = problem.pose(v)
    for k in range(n):
        db = np.full(n, -300.0)
        db[k] = 0.0
        el_k = replace(base_el, correction_db=tuple(db))
        images.append(np.asarray(problem.pattern_frame(SensorSpec(elevation_pattern=el_k), pose), dtype=np.float64))
        problem.renders += 1
    stack = np.stack(images)  # (n, n_range_bins, n_beams)
    model = problem.model(replace(s2, elevation_pattern=base_el))
    target = problem.target
    used = np.flatnonzero(stack.reshape(n, -1).max(axis=1) > 0)  # knots that light some pixel

    def expected_of(x):
        c = np.ones(n)
        c[used] = 10.0 ** (x / 10.0)
        return model.apply(np.tensordot(c, stack, axes=1).astype(np.float32), speckle=False)

    before = problem.cost(spec, v)
    db = np.zeros(n)
    db[used] = _fit_smooth_knots(expected_of, target, len(used), CORRECTION_SMOOTHING, 30.0)
    trial = replace(spec, elevation_pattern=replace(el, correction_db=tuple(float(x) for x in db), span_deg=span))
    after = problem.cost(trial, v)
    if not after < before:
        say("elevation pattern correction: not kept (no better than without it)")
        return spec, v
    knots = correction_knots_deg(trial.elevation_pattern, v["elevation_width_deg"])
    say(f"elevation pattern correction: {n} knots over +-{knots[-1]:g} deg, {float(np.std(db[used])):.2f} dB RMS: "
        f"PSNR {problem.psnr(spec, v, spec.output.full_scale):.2f} -> {problem.psnr(trial, v, spec.output.full_scale):.2f} dB")
    return trial, v


#: Knots of the range law's correction, evenly over the range window.
RANGE_CORRECTION_KNOTS = 16
#: Its bounds (dB) at each knot.
RANGE_CORRECTION_BOUND_DB = 20.0
#: Weight of its roughness (second differences, dB) against the pixels' residuals (counts).
CORRECTION_SMOOTHING_RANGE = 2.0
#: The least PSNR (dB, on the calibration frame) it must gain to be kept: on a synthetic
#: recording made without one it gains 0.02 dB by fitting the speckle and the noise's trade-offs.
RANGE_CORRECTION_MIN_DB = 0.05


def _fit_range_correction(problem: _Problem, spec: SensorSpec, v: dict, say):
    """The range law's departure from its formula (``tvg.correction_db``).

    The TVG multiplies each row's echo and receiver noise before the output law, so with the
    pose held the noise-free image is rendered once and each trial correction only re-runs the
    sensor stage: bounded least squares on the knots' values (dB) against the expected image's
    counts, with the same roughness penalty as the elevation pattern's correction. A curve of
    :data:`RANGE_CORRECTION_KNOTS` knots over the window averages thousands of pixels per knot,
    so it follows the range profile's slow course, not one frame's speckle.
    """
    if spec.tvg is None:
        return spec, v
    r = np.asarray(problem.sonar.range_m, dtype=float)
    n = RANGE_CORRECTION_KNOTS
    span = (float(r[0]), float(r[-1]))
    total, _ = problem.frame_for(spec, v)

    def trial(x):
        return replace(spec, tvg=replace(spec.tvg, correction_db=tuple(float(a) for a in x), correction_range_m=span))

    x = _fit_smooth_knots(lambda x: problem.model(with_values(trial(x), v)).apply(total, speckle=False),
                          problem.target, n, CORRECTION_SMOOTHING_RANGE, RANGE_CORRECTION_BOUND_DB)
    out = trial(x)
    peak = spec.output.full_scale
    gain = problem.psnr(out, v, peak) - problem.psnr(spec, v, peak)
    if not (problem.cost(out, v) < problem.cost(spec, v) and gain >= RANGE_CORRECTION_MIN_DB):
        say(f"range law correction: not kept ({gain:+.3f} dB: below {RANGE_CORRECTION_MIN_DB} dB, what fitting "
            "a frame's speckle gains)")
        return spec, v
    say(f"range law correction: {n} knots over {span[0]:.3g}-{span[1]:.3g} m, {float(np.std(x)):.2f} dB RMS, "
        f"{float(np.min(x)):+.1f} to {float(np.max(x)):+.1f} dB: PSNR {problem.psnr(spec, v, peak):.2f} -> "
        f"{problem.psnr(out, v, peak):.2f} dB")
    return out, v


def _statistic(compression: str, peak: float):
    if compression == "gamma":
        return realism.speckle_contrast
    return speckle_spread


def _speckled(spec: SensorSpec, sonar, total: np.ndarray, seed: int, pose) -> np.ndarray:
    from ..sensor.model import SensorModel

    m = SensorModel(spec, sonar, seed)
    return m.apply(total, m.anchored_rng(pose.position_m, pose.rpy_deg))


def family_middle(members: Sequence[dict], within_db: float = FAMILY_DB) -> int:
    """The index in ``members`` of the middle of the equally good family: of the members within
    ``within_db`` of the best PSNR, the one of median elevation width (the lower of the two
    middle ones for an even count). The family's members fit equally well, so its best is
    chance; its edges are where it stops, the worst guess of the pose.

    Parameters
    ----------
    members : sequence of dict
        Each with ``elevation_width_deg`` and ``psnr_db``.
    within_db : float

    Returns
    -------
    int
    """
    top = max(float(m["psnr_db"]) for m in members)
    good = sorted((i for i, m in enumerate(members) if float(m["psnr_db"]) >= top - within_db),
                  key=lambda i: float(members[i]["elevation_width_deg"]))
    return good[(len(good) - 1) // 2]


def _family(problem: _Problem, spec: SensorSpec, v: dict, free: tuple[str, ...], max_iterations: int, peak: float,
            say) -> tuple[SensorSpec, dict, dict]:
    """Hold the elevation width at each of :data:`FAMILY_WIDTHS_DEG` and refit pose and sensor:
    the poses within :data:`FAMILY_DB` of the best are the family; the member returned is its
    middle (:func:`family_middle`), never an edge."""
    w0 = v["elevation_width_deg"]
    members = [{"elevation_width_deg": w0, **{k: v[k] for k in free}, "psnr_db": problem.psnr(spec, v, peak)}]
    fits = [v]
    others = [n for n in sensor_names(spec) if n != "elevation_width_deg"] + list(free)
    lo, hi = problem.bounds["elevation_width_deg"]
    for w in FAMILY_WIDTHS_DEG:
        w = float(np.clip(w, lo, hi))
        # Along the family the band's half-angle scales with the width: start from the pose the
        # band's lines give for it (the best pose moved along the curve).
        start = {**v, "elevation_width_deg": w, **_along_family(v, w0, w, free)}
        u, c = problem.search(spec, start, others, max(max_iterations // 2, 1))
        members.append({"elevation_width_deg": w, **{k: u[k] for k in free}, "psnr_db": problem.psnr(spec, u, peak)})
        fits.append(u)
    middle = family_middle(members)
    say(f"family: {len(members)} elevation widths refitted; the middle of the equally good ones kept "
        f"(width {members[middle]['elevation_width_deg']:.3g} deg)")
    top = max(m["psnr_db"] for m in members)
    good = [m for m in members if m["psnr_db"] >= top - FAMILY_DB]
    report = {"within_db": FAMILY_DB, "members": sorted(members, key=lambda m: m["elevation_width_deg"])}
    for k in ("elevation_width_deg", *[n for n in ("z", "pitch", "roll") if n in free]):
        report[k] = [min(m[k] for m in good), max(m[k] for m in good)]
    # Bracketed: the scan's extreme widths are themselves within the tolerance.
    widths = [m["elevation_width_deg"] for m in members]
    report["open_ended"] = any(m["elevation_width_deg"] in (min(widths), max(widths)) for m in good)
    report["chosen"] = {k: members[middle][k] for k in ("elevation_width_deg", *[n for n in ("z", "pitch", "roll")
                                                                                  if n in free])}
    return spec, fits[middle], report


def _along_family(v: dict, w0: float, w: float, free: tuple[str, ...]) -> dict:
    """The pose that draws the same band edges with the width ``w`` as ``v``'s with ``w0``
    (bandpose's closed form: the same lines at the half-angle scaled by the width)."""
    from .bandpose import BandLines, pose_for_half_angle

    if not {"z", "pitch"} <= set(free):
        return {}
    h0, h = EDGE_RATIO * w0, EDGE_RATIO * w
    z, p, r = v["z"], math.radians(v["pitch"]), math.radians(v.get("roll", 0.0))
    hr = math.radians(h0)
    a = math.cos(hr) * math.sin(p) / z
    c = -math.cos(hr) * math.cos(p) * math.sin(r) / z
    b = math.sin(hr) * math.cos(p) * math.cos(r) / z
    lines = BandLines(a, c, b, a + b, 0.0, 99, 99)
    z2, p2, r2 = pose_for_half_angle(lines, min(h, 80.0))
    out = {"z": z2, "pitch": p2}
    if "roll" in free:
        out["roll"] = r2
    return out


def _degenerate(problem: _Problem, s2: SensorSpec, spec: SensorSpec, v: dict, best: dict,
                free: tuple[str, ...], pose: Pose) -> list[str]:
    """What makes the result meaningless (see :func:`calibrate`, step 4)."""
    out = []
    total, _ = problem.frame_for(spec, v)
    m = problem.model(s2)
    mean = np.asarray(m.mean_image(total), dtype=np.float64)
    echo = m.echo_gain[:, None] * mean
    rest = m.bang[:, None] + m.noise_row[:, None]
    lit = problem.lit
    if lit.any():
        share = float(np.median((echo / np.maximum(echo + rest, 1e-300))[lit]))
        if share < MIN_ECHO_SHARE:
            out.append(f"the echo is switched off: over the recording's bright band the model's echo is "
                       f"{100 * share:.0f} % of its expected power (the rest noise and bang lifted by the TVG, "
                       f"at least {100 * MIN_ECHO_SHARE:.0f} % echo is needed)")
    moved = [k for k in free if abs(v[k] - best["from"][k]) > 1e-6 * STEPS[k]]
    if free and not moved:
        out.append(f"the pose did not move from its start ({', '.join(f'{k} {v[k]:.4g}' for k in free)}): "
                   "the recording does not constrain it (is the scene's echo in the recording's window?)")
    base = problem.cost(spec, v)
    # A free parameter that a step either way does not change the fit of is not measured: it
    # ends wherever the simplex left it (yaw over a flat floor, say).
    loose = [k for k in free if k in moved and all(
        abs(problem.cost(spec, {**v, k: v[k] + d * STEPS[k]}) - base) <= UNCONSTRAINED_COST * base for d in (-1.0, 1.0))]
    if loose:
        out.append(f"{', '.join(loose)} did not move the fit: the recording does not constrain "
                   f"{'it' if len(loose) == 1 else 'them'}; hold {'it' if len(loose) == 1 else 'them'} (leave out of --free)")
    pinned = []
    for k in (*sensor_names(spec), *free):
        lo, hi = problem.bounds[k]
        span = hi - lo
        for edge, inward in ((lo, +1.0), (hi, -1.0)):
            if (k, edge == lo) in NATURAL_LIMITS:
                continue
            if abs(v[k] - edge) <= 1e-3 * span:
                moved_v = {**v, k: edge + inward * min(0.25 * STEPS[k], 0.1 * span)}
                if problem.cost(spec, moved_v) > base * (1.0 + PINNED_COST_RISE):
                    pinned.append(f"{k} {v[k]:.4g} (bounds {lo:.4g} to {hi:.4g})")
    if pinned:
        out.append("parameters pinned at their physical bounds, where the fit wants them beyond: " + ", ".join(pinned))
    return out


def _fit_grain(real: SonarImage, spec: SensorSpec, sonar, total: np.ndarray, seed: int, pose) -> SensorSpec:
    """The azimuth width whose speckle grain across beams, in the lit band, is the recording's."""
    from ..sensor.model import SensorModel

    lit = realism.auto_regions(real.polar)["lit"]
    want = realism.correlation_lengths(real.polar, lit).beams
    spacing = float(np.median(np.abs(np.diff(sonar.azimuth_deg))))
    base = spec.azimuth_pattern or parse_sensor({"azimuth_pattern": {"shape": "gaussian"}}).azimuth_pattern

    def grain(width):
        s = replace(spec, azimuth_pattern=replace(base, width_deg=float(width)))
        m = SensorModel(s, sonar, seed)
        rng = m.anchored_rng(pose.position_m, pose.rpy_deg)
        return realism.correlation_lengths(m.apply(total, rng), lit).beams - want

    lo, hi = 0.5 * spacing, 8.0 * spacing
    try:
        width = optimize.brentq(grain, lo, hi, xtol=0.01 * spacing)
    except ValueError:  # the recording's grain is outside what widths in [lo, hi] give
        width = lo if abs(grain(lo)) < abs(grain(hi)) else hi
    spec = replace(spec, azimuth_pattern=replace(base, width_deg=float(width)))
    return _fit_range_grain(real, spec, sonar, total, seed, pose, lit)


#: The CW pulses the range grain is matched with: range extents (c tau / 2) in range cells. A
#: gate centred on a cell reaches into its neighbours by 0 (1 cell: no spread) to 50 % (2 cells)
#: of its amplitude, and the grain grows steadily with it; longer gates are not matched: the
#: grain (1/e length of the residual about the local mean) is no monotonic function of them
#: (measured: 0.86 cells of grain for a 2-cell gate, 0.83 for 3, 1.27 for 4).
PULSE_CELLS = (1.0, 2.0)
#: The grain (range cells) by which the recording's must exceed the model's without a pulse for
#: one to be fitted: three draws of one recording spread by 0.02.
GRAIN_TOLERANCE = 0.03


def _fit_range_grain(real: SonarImage, spec: SensorSpec, sonar, total: np.ndarray, seed: int, pose,
                     lit: np.ndarray) -> SensorSpec:
    """The CW pulse length whose speckle grain along range, in the lit band, is the recording's.

    The pulse spreads each echo over ``c tau / 2`` of range, so neighbouring range cells share
    scatterers: the grain along range grows with it (and the mean image is blurred as much).
    Without a pulse the model's speckle is independent from cell to cell, where the real
    Oculus ping's correlates 0.15 between neighbours (0.06 in the model without a pulse):
    the classifier two-sample test tells real from simulated patches by that more than by
    anything else. Matched over :data:`PULSE_CELLS`; left as it is where the spec has a chirp
    (its lobe is the device's), or where the recording's grain is within
    :data:`GRAIN_TOLERANCE` of what no pulse gives.
    """
    from ..config.sensor import PulseSpec
    from ..sensor.model import SensorModel

    if spec.pulse is not None and spec.pulse.kind != "cw":
        return spec
    want = realism.correlation_lengths(real.polar, lit).range_bins
    cell = float(sonar.range_resolution_m)
    c = float(spec.sound_speed_m_s)

    def with_cells(k: float) -> SensorSpec:
        return replace(spec, pulse=PulseSpec(kind="cw", length_us=float(2.0 * k * cell / c * 1e6)))

    def grain(k: float) -> float:
        m = SensorModel(with_cells(k), sonar, seed)
        return realism.correlation_lengths(m.apply(total, m.anchored_rng(pose.position_m, pose.rpy_deg)),
                                           lit).range_bins - want

    lo, hi = PULSE_CELLS
    if grain(lo) >= -GRAIN_TOLERANCE:  # a gate of one cell spreads nothing: as no pulse
        return spec
    try:
        k = optimize.brentq(grain, lo, hi, xtol=0.02)
    except ValueError:  # even the longest pulse matched gives less grain than the recording's
        k = hi
    return with_cells(k)


def evaluate(real: np.ndarray, expected: np.ndarray, speckled: np.ndarray, peak: float = 255.0,
             regions: dict | None = None) -> dict:
    """The realism figures of a calibrated model against a real frame (all in device units).

    Parameters
    ----------
    real, expected, speckled : (n_range_bins, n_beams) arrays
        The recording's frame, the model's expected render (``speckle=False``) and a speckled
        render, on the same grid.
    peak : float
        Full scale (255 for 8-bit), the PSNR's and SSIM's data range.
    regions : dict of name to bool mask, optional
        Default :func:`sonarsim.analysis.realism.auto_regions` of ``real``.

    Returns
    -------
    dict: ``psnr_db``, ``mse``, ``ssim`` of the expected render, ``psnr_speckled_db`` and
    ``ssim_speckled`` of the speckled one; ``regions``: per region (``lit``, ``water``,
    ``shadow``) :func:`~sonarsim.analysis.realism.region_statistics` of the speckled render
    (KS, 1-Wasserstein, contrast, grain along range and across beams, real ``_a`` and model
    ``_b``), plus ``range_profile_db_real``/``_model`` and ``beam_profile_db_real``/``_model``
    (mean levels in dB of the counts, lists; NaN-free where the region has pixels).
    """
    from . import metrics

    x = np.asarray(real, dtype=np.float64)
    e = np.asarray(expected, dtype=np.float64)
    sp = np.asarray(speckled, dtype=np.float64)
    regions = realism.auto_regions(x) if regions is None else regions
    out: dict = {
        "psnr_db": metrics.psnr(x, e, data_range=peak), "mse": metrics.mse(x, e),
        "ssim": metrics.ssim(x, e, data_range=peak),
        "psnr_speckled_db": metrics.psnr(x, sp, data_range=peak), "ssim_speckled": metrics.ssim(x, sp, data_range=peak),
        "regions": {},
    }
    for name, mask in regions.items():
        st = realism.region_statistics(x, sp, mask)
        if mask.any():
            def clean(a):
                return [None if not np.isfinite(t) or t <= -300 else round(float(t), 3) for t in a]
            st["range_profile_db_real"] = clean(realism.range_profile_db(x, mask))
            st["range_profile_db_model"] = clean(realism.range_profile_db(sp, mask))
            st["beam_profile_db_real"] = clean(realism.beam_profile_db(x, mask))
            st["beam_profile_db_model"] = clean(realism.beam_profile_db(sp, mask))
        out["regions"][name] = st
    return out


def format_evaluation(ev: dict, title: str = "") -> str:
    """A few lines of text: the scores and, per region, real vs model."""
    lines = [f"{title}PSNR {ev['psnr_db']:.2f} dB  MSE {ev['mse']:.1f}  SSIM {ev['ssim']:.3f} (expected); "
             f"PSNR {ev['psnr_speckled_db']:.2f} dB  SSIM {ev['ssim_speckled']:.3f} (speckled)"]
    for name, st in ev["regions"].items():
        if not st["pixels"]:
            lines.append(f"  {name:6s} (empty)")
            continue
        lines.append(
            f"  {name:6s} {int(st['pixels']):6d} px  KS {st['ks']:.3f}  W1 {st['wasserstein']:.2f}  "
            f"mean {st['mean_a']:.1f} / {st['mean_b']:.1f}  contrast {st['contrast_a']:.3f} / {st['contrast_b']:.3f}  "
            f"grain {st['grain_range_a']:.2f} / {st['grain_range_b']:.2f} bins, "
            f"{st['grain_beams_a']:.2f} / {st['grain_beams_b']:.2f} beams  "
            f"range profile RMS {st['range_profile_rms_db']:.2f} dB  (real / model)")
    return "\n".join(lines)
