"""Calibrate the sensor model (and optionally the pose) against a real recording.

The real frame is a speckled draw in the device's units; the simulator's expected output
(``render(..., speckle=False)``: the mean device value of each pixel) is what a fit can match.
The cost is the mean squared difference between the two over the whole frame, i.e. the PSNR
in the recording's own units that :func:`sonarsim.analysis.metrics.psnr` reports. Parameters:

* sensor: ``gain_db`` (receiver gain), ``noise_db`` (receiver noise), ``bang_db`` (the
  transmit bang), ``elevation_width_deg`` (the two-way -3 dB width of the elevation pattern,
  whose sidelobes light the floor beyond it);
* pose: any of x, y, z, roll, pitch, yaw named free.

The output is gamma-compressed: for fully developed speckle the contrast of ``P ** gamma`` is
``sqrt(Gamma(1 + 2 gamma) / Gamma(1 + gamma)^2 - 1)`` whatever the level, so gamma is set from
the recording's speckle contrast in its lit band before the search (a log compression would
give the dark water column the same spread in counts as the lit floor, which real 8-bit
Oculus frames do not show).

The search is derivative-free (Nelder-Mead over a bounded transform), re-rendering only when a
parameter that changes the rays (pose, elevation width) moves; the sensor-only parameters
re-run the sensor stage on the cached noise-free image. Afterwards, the azimuth width of the
receive beams is set so that the speckle grain across beams matches the recording's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import optimize

from ..config.scene import Scene
from ..config.sensor import SensorSpec, parse_sensor
from ..core.transforms import Pose
from ..errors import ConfigError
from ..image.result import SonarImage
from ..renderer.simulator import Simulator
from . import realism
from .fitting import PARAMETERS, pose_values

SENSOR_PARAMETERS = ("gain_db", "noise_db", "bang_db", "elevation_width_deg")
# (lower, upper, initial step) of each parameter, in its units.
BOUNDS = {
    "gain_db": (-120.0, 120.0, 6.0), "noise_db": (-60.0, 200.0, 6.0),
    "bang_db": (-60.0, 250.0, 6.0), "elevation_width_deg": (2.0, 60.0, 2.0),
    "x": (-1e3, 1e3, 0.02), "y": (-1e3, 1e3, 0.02), "z": (-1e3, 1e3, 0.02),
    "roll": (-90.0, 90.0, 1.0), "pitch": (-90.0, 90.0, 1.0), "yaw": (-180.0, 180.0, 1.0),
}

#: The starting sensor when the scene has none: an 8-bit device with log compression, 20 log r
#: TVG and absorption in fresh water, a uniform line array in elevation, Gaussian receive beams.
STARTING_SENSOR = {
    "source_level_db": 180.0,
    "absorption": {"model": "francois-garrison", "temperature_c": 15.0, "salinity_psu": 0.0, "depth_m": 1.0},
    "tvg": {"spreading": 20.0, "absorption": True},
    "elevation_pattern": {"shape": "line", "window": "rect"},
    "azimuth_pattern": {"shape": "gaussian"},
    "speckle": {"model": "rayleigh", "anchor": "world"},
    "noise": {"level_db": 60.0},
    "bang": {"level_db": 150.0, "length_m": 0.01},
    "output": {"compression": "gamma", "gamma": 0.3, "ceiling_db": 160.0, "dtype": "uint8"},
}


def gamma_for_contrast(contrast: float) -> float:
    """The gamma whose compression gives exponential speckle this contrast (std / mean)."""
    from scipy.special import gammaln

    def c(g):
        return math.sqrt(math.exp(gammaln(1 + 2 * g) - 2 * gammaln(1 + g)) - 1.0) - contrast

    return float(optimize.brentq(c, 0.01, 2.0))


def parse_free_parameters(text: str | Sequence[str]) -> tuple[str, ...]:
    """``"z,pitch"`` -> pose parameters to fit; unknown names are errors naming what is allowed."""
    names = [t.strip() for t in (text.split(",") if isinstance(text, str) else text) if t.strip()]
    for n in names:
        if n not in PARAMETERS:
            raise ConfigError("free", f"unknown pose parameter {n!r}; allowed: {', '.join(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise ConfigError("free", f"a parameter is named twice in {names}")
    return tuple(names)


def sensor_values(spec: SensorSpec, sonar_elevation_deg: float) -> dict[str, float]:
    """The calibrated parameters' values in a sensor spec."""
    el = spec.elevation_pattern
    return {
        "gain_db": spec.gain_db,
        "noise_db": spec.noise.level_db if spec.noise else -60.0,
        "bang_db": spec.bang.level_db if spec.bang else -60.0,
        "elevation_width_deg": el.width_deg if el and el.width_deg else sonar_elevation_deg,
    }


def with_values(spec: SensorSpec, v: dict[str, float]) -> SensorSpec:
    """``spec`` with the calibrated parameters replaced (others kept)."""
    el = spec.elevation_pattern
    if el is not None:
        width = v["elevation_width_deg"]
        span = min(max(el.span_deg or 0.0, 3.0 * width), 170.0)
        el = replace(el, width_deg=width, span_deg=span)
    return replace(spec, gain_db=v["gain_db"], elevation_pattern=el,
                   noise=replace(spec.noise, level_db=v["noise_db"]) if spec.noise else None,
                   bang=replace(spec.bang, level_db=v["bang_db"]) if spec.bang else None)


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
    renders : int
        Noise-free renders made.
    expected : SonarImage
        The calibrated expected render.
    """

    scene: Scene
    values: dict
    psnr_db: float
    psnr_start_db: float
    renders: int
    expected: SonarImage


def _psnr(mse: float, peak: float) -> float:
    return float(10 * np.log10(peak ** 2 / mse)) if mse > 0 else float("inf")


def calibrate(real: SonarImage, scene: Scene, free: Sequence[str] = (), max_iterations: int = 600,
              fit_grain: bool = True) -> CalibrationResult:
    """Fit the sensor (and the free pose parameters) so that the expected render matches ``real``.

    Parameters
    ----------
    real : SonarImage
        One frame of a recording, in the device's units (e.g. 0-255).
    scene : Scene
        The scene behind it; its ``sensor`` (or :data:`STARTING_SENSOR`) and pose are the start.
        The image grid is the recording's (its beams and range bins).
    free : sequence of str
        Pose parameters to fit as well.
    max_iterations : int
        Budget of the simplex search.
    fit_grain : bool
        Also set the receive beams' azimuth width from the speckle grain across beams.
    """
    free = tuple(free)
    sonar = replace(real.sonar, elevation_fov_deg=scene.sonar.elevation_fov_deg)
    if sonar.frequency_khz is None:
        sonar = replace(sonar, frequency_khz=scene.sonar.frequency_khz)
    spec = scene.sensor if scene.sensor is not None else parse_sensor(STARTING_SENSOR)
    if spec.output is None or spec.output.compression != "gamma":
        raise ConfigError("sensor.output", "calibration fits a gamma-compressed output (compression: gamma)")
    target = np.asarray(real.polar, dtype=np.float64)
    lit = realism.auto_regions(target)["lit"]
    contrast = realism.speckle_contrast(target, lit)
    spec = replace(spec, output=replace(spec.output, gamma=gamma_for_contrast(contrast)))
    peak = spec.output.full_scale
    pose0 = scene.sonar_pose
    start = {**sensor_values(spec, sonar.elevation_fov_deg), **{k: pose_values(pose0)[k] for k in free}}
    names = list(start)
    lo = np.array([BOUNDS[n][0] for n in names])
    hi = np.array([BOUNDS[n][1] for n in names])
    step = np.array([BOUNDS[n][2] for n in names])
    x0 = np.array([start[n] for n in names])

    cache: dict = {}
    renders = [0]

    def values_of(u):
        x = np.clip(x0 + u * step, lo, hi)
        return dict(zip(names, x))

    def frame_for(v):
        """Noise-free total image for the pose and elevation width in v (cached)."""
        pv = {**pose_values(pose0), **{k: v[k] for k in free}}
        key = tuple(round(pv[k], 6) for k in PARAMETERS) + (round(v["elevation_width_deg"], 4),)
        if key not in cache:
            # Only the elevation pattern acts on the rays: render with it alone.
            s2 = SensorSpec(elevation_pattern=with_values(spec, v).elevation_pattern)
            sc = replace(scene, sensor=s2, sonar=sonar)
            with Simulator(sc) as sim:
                pose = Pose((pv["x"], pv["y"], pv["z"]), (pv["roll"], pv["pitch"], pv["yaw"]))
                img = sim.render(pose, keep_rays=False, speckle=False)
            renders[0] += 1
            if len(cache) > 64:
                cache.clear()
            cache[key] = (img.components["total"], pose)
        return cache[key]

    models: dict = {}

    def expected(v):
        total, pose = frame_for(v)
        s2 = with_values(spec, v)
        from ..sensor.model import SensorModel

        m = models.get(s2)
        if m is None:
            m = SensorModel(s2, sonar, scene.render.seed, fields=False)
            models.clear()
            models[s2] = m
        return m.apply(total, speckle=False), pose, s2

    def cost(u):
        e, _, _ = expected(values_of(u))
        return float(np.mean((e - target) ** 2))

    c0 = cost(np.zeros(len(names)))
    res = optimize.minimize(cost, np.zeros(len(names)), method="Nelder-Mead",
                            options={"maxiter": max_iterations, "xatol": 1e-3, "fatol": 1e-4,
                                     "initial_simplex": np.vstack([np.zeros(len(names)), np.eye(len(names))])})
    v = values_of(res.x)
    e, pose, s2 = expected(v)
    if fit_grain and s2.speckle is not None:
        s2 = _fit_grain(real, s2, sonar, frame_for(v)[0], scene.render.seed, pose)
        v["azimuth_width_deg"] = s2.azimuth_pattern.width_deg
    fitted = replace(scene, sensor=s2, sonar_pose=pose)
    from ..sensor.model import SensorModel

    m = SensorModel(s2, sonar, scene.render.seed)
    e = m.apply(frame_for(v)[0], speckle=False)
    mse = float(np.mean((e - target) ** 2))
    image = SonarImage(polar=e, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg, components={"expected": e},
                       sonar=sonar, pose=pose, config=fitted.to_dict())
    return CalibrationResult(fitted, v, _psnr(mse, peak), _psnr(c0, peak), renders[0], image)


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
    return replace(spec, azimuth_pattern=replace(base, width_deg=float(width)))
