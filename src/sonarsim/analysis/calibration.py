"""Calibrate the sensor model (and optionally the pose) against a real recording.

The real frame is a speckled draw in the device's units; the simulator's expected output
(``render(..., speckle=False)``: the mean device value of each pixel) is what a fit can match.
The cost is the mean squared difference between the two over the whole frame, i.e. the PSNR
in the recording's own units that :func:`sonarsim.analysis.metrics.psnr` reports, plus the
squared error of the water column's mean range profile (weight :data:`WATER_WEIGHT`): the dark
water column counts little in the pixels' MSE, yet its distribution is set by that profile.
Parameters:

* sensor: ``gain_db`` (receiver gain), ``noise_db`` (receiver noise, before the TVG, which
  lifts it with range), ``noise_after_tvg_db`` (the digitiser's noise, after the TVG: a floor
  at every range), ``bang_db`` and ``bang_length_m`` (the transmit bang),
  ``elevation_width_deg`` (the two-way -3 dB width of the elevation pattern, whose sidelobes
  light the floor before and beyond the band: the rays cover at least :data:`MIN_SPAN_DEG`);
* the TVG's spreading law, a discrete choice (20, 30 or 40 log r): the search runs for each
  and keeps the best. The real Oculus ping is fitted with 40 log r: its water column rises by
  about 20 dB per decade where the floor of noise after the TVG still shows (below 0.3 m) and
  by 40 beyond the floor band, where the noise before the TVG dominates;
* pose: any of x, y, z, roll, pitch, yaw named free, fitted with the sensor after the
  sensor alone has been fitted at the scene's pose (fitting them together from the start lets
  the simplex trade the pose against the elevation pattern: a 0.7 m height and 51 degree
  pitch on the real ping). Start from a pose fitted on the floor band
  (:func:`sonarsim.analysis.fitting.fit_pose` with ``domain="band"``): on the real ping it
  then moves by about 1 cm and 0.5 degree.

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

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
from scipy import optimize

from ..config.scene import Scene
from ..config.sensor import SensorSpec, parse_sensor
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError
from ..image.result import SonarImage
from ..renderer.simulator import Simulator
from . import realism
from .fitting import PARAMETERS, check_overlap, parse_free, pose_values, recording_geometry

SENSOR_PARAMETERS = ("gain_db", "noise_db", "noise_after_tvg_db", "bang_db", "bang_length_m",
                     "elevation_width_deg")
# (lower, upper, initial step) of each parameter, in its units.
BOUNDS = {
    "gain_db": (-120.0, 120.0, 6.0), "noise_db": (-60.0, 200.0, 6.0), "noise_after_tvg_db": (-60.0, 250.0, 6.0),
    "bang_db": (-60.0, 250.0, 6.0), "bang_length_m": (0.0005, 0.2, 0.01), "elevation_width_deg": (2.0, 60.0, 2.0),
    "x": (-1e3, 1e3, 0.02), "y": (-1e3, 1e3, 0.02), "z": (-1e3, 1e3, 0.02),
    "roll": (-90.0, 90.0, 1.0), "pitch": (-90.0, 90.0, 1.0), "yaw": (-180.0, 180.0, 1.0),
}

#: The least elevation span (degrees) the rays cover while calibrating: the pattern's sidelobes
#: light the floor well outside the main lobe (on the real Oculus ping, the echo beyond the floor
#: band and before it, 17-20 degrees off the axis), and a span of three -3 dB widths misses it.
MIN_SPAN_DEG = 60.0

#: Weight of the water column's mean profile in the cost (see :func:`calibrate`).
WATER_WEIGHT = 5.0

#: The starting sensor when the scene has none: an 8-bit device with log compression, 20 log r
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


# Speckle contrasts gamma can explain: gamma from 0.05 to 2 (exponential speckle compressed).
MIN_CONTRAST, MAX_CONTRAST = 0.062, 2.2
# Passes correcting gamma by the speckled model's contrast, and when to stop.
GAMMA_PASSES = 2
GAMMA_TOLERANCE = 0.02


def gamma_for_contrast(contrast: float) -> float:
    """The gamma whose compression gives exponential speckle this contrast (std / mean)."""
    from scipy.special import gammaln

    def c(g):
        return math.sqrt(math.exp(gammaln(1 + 2 * g) - 2 * gammaln(1 + g)) - 1.0) - contrast

    return float(optimize.brentq(c, 0.01, 2.0))


def parse_free_parameters(text: str | Sequence[str]) -> tuple[str, ...]:
    """``"z,pitch"`` -> pose parameters to fit (possibly none); unknown names are errors."""
    return parse_free(text, allow_none=True)


def sensor_values(spec: SensorSpec, sonar_elevation_deg: float) -> dict[str, float]:
    """The calibrated parameters' values in a sensor spec."""
    el = spec.elevation_pattern
    return {
        "gain_db": spec.gain_db,
        "noise_db": spec.noise.level_db if spec.noise else -60.0,
        "noise_after_tvg_db": spec.noise.after_tvg_db if spec.noise and spec.noise.after_tvg_db is not None else -60.0,
        "bang_db": spec.bang.level_db if spec.bang else -60.0,
        "bang_length_m": spec.bang.length_m if spec.bang else 0.01,
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
                   bang=replace(spec.bang, level_db=v["bang_db"], length_m=v["bang_length_m"]) if spec.bang else None)


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
              fit_grain: bool = True, water_weight: float = WATER_WEIGHT, spreading: Sequence[float] | None = (20.0, 30.0, 40.0)) -> CalibrationResult:
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
    water_weight : float
        Weight of the water column's mean range profile (squared error of its rows' means, in
        device units squared) added to the pixels' mean squared error.
    spreading : sequence of float, optional
        TVG spreading laws (dB per decade) to try; the one that fits best is kept. ``None``:
        the starting sensor's.
    """
    free = tuple(free)
    check_overlap(real, scene)
    sonar = recording_geometry(real, scene)  # the recording's grid, as fit_pose renders
    spec = scene.sensor if scene.sensor is not None else parse_sensor(STARTING_SENSOR)
    if spec.output is None or spec.output.compression != "gamma":
        raise ConfigError("sensor.output", "calibration fits a gamma-compressed output (compression: gamma)")
    target = np.asarray(real.polar, dtype=np.float64)
    lit = realism.auto_regions(target)["lit"]
    try:
        contrast = realism.speckle_contrast(target, lit)
    except ValueError as exc:
        raise SonarsimError(f"the recording has no speckle to calibrate on in its bright band: {exc}") from None
    if not MIN_CONTRAST <= contrast <= MAX_CONTRAST:
        raise SonarsimError(f"the recording's speckle contrast in its bright band is {contrast:.3g}; calibration "
                            f"needs {MIN_CONTRAST}-{MAX_CONTRAST} (a speckled frame in the device's units, not a "
                            "noise-free render)")
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

    # The water column is dark: its squared errors are small next to the lit band's, yet its
    # distribution is set by its mean profile. Its rows' mean errors are weighted in.
    water = realism.auto_regions(target)["water"]
    n_water = np.maximum(water.sum(axis=1), 1)
    water_rows = water.sum(axis=1) >= 0.25 * water.shape[1]
    real_water = (target * water).sum(axis=1) / n_water

    def cost(u):
        e, _, _ = expected(values_of(u))
        c = float(np.mean((e - target) ** 2))
        if water_weight > 0 and water_rows.any():
            d = ((e * water).sum(axis=1) / n_water - real_water)[water_rows]
            c += water_weight * float(np.mean(d ** 2))
        return c

    laws = [None] if spreading is None or spec.tvg is None else list(spreading)
    c0 = cost(np.zeros(len(names)))

    def search(active: np.ndarray, u0: np.ndarray):
        """Nelder-Mead over the parameters ``active`` (indices), the others held at ``u0``."""
        def f(w):
            u = u0.copy()
            u[active] = w
            return cost(u)

        n = len(active)
        r = optimize.minimize(f, u0[active], method="Nelder-Mead",
                              options={"maxiter": max_iterations, "xatol": 1e-3, "fatol": 1e-4,
                                       "initial_simplex": u0[active] + np.vstack([np.zeros(n), np.eye(n)])})
        u = u0.copy()
        u[active] = r.x
        return u, float(r.fun)

    # First the sensor alone at the scene's pose, for each TVG law; then, with the best law,
    # the free pose parameters and the sensor together from there.
    sensor_idx = np.array([i for i, n in enumerate(names) if n not in free])
    best = None
    for law in laws:
        spec = spec if law is None else replace(spec, tvg=replace(spec.tvg, spreading=float(law)))
        u, c = search(sensor_idx, np.zeros(len(names)))
        if best is None or c < best[1]:
            best = (u, c, spec)
    u, c, spec = best
    if free:
        u, c = search(np.arange(len(names)), u)
    res = optimize.OptimizeResult(x=u, fun=c)
    v = {k: float(x) for k, x in values_of(res.x).items()}
    e, pose, s2 = expected(v)
    if fit_grain and s2.speckle is not None:
        s2 = _fit_grain(real, s2, sonar, frame_for(v)[0], scene.render.seed, pose)
        v["azimuth_width_deg"] = s2.azimuth_pattern.width_deg
        # The closed-form gamma assumes independent pixels; speckle grain correlates them and
        # lowers the contrast measured over a local mean. Correct gamma by the ratio of the
        # recording's contrast to the model's (contrast is nearly proportional to gamma), then
        # refit the sensor at the new gamma.
        for _ in range(GAMMA_PASSES):
            model_contrast = _speckled_contrast(s2, sonar, frame_for(v)[0], scene.render.seed, pose, lit)
            ratio = contrast / model_contrast
            if abs(ratio - 1.0) < GAMMA_TOLERANCE:
                break
            gamma = float(np.clip(s2.output.gamma * ratio, 0.05, 4.0))
            spec = replace(spec, output=replace(spec.output, gamma=gamma),
                           azimuth_pattern=s2.azimuth_pattern)
            u, c = search(sensor_idx, u)
            v = {k: float(x) for k, x in values_of(u).items()}
            e, pose, s2 = expected(v)
            s2 = _fit_grain(real, s2, sonar, frame_for(v)[0], scene.render.seed, pose)
            v["azimuth_width_deg"] = s2.azimuth_pattern.width_deg
    v["tvg_spreading"] = s2.tvg.spreading if s2.tvg is not None else 0.0
    v["gamma"] = s2.output.gamma
    # The recording's grid, so that the calibrated scene renders frames like the recording's.
    fitted = replace(scene, sensor=s2, sonar=sonar, sonar_pose=pose)
    from ..sensor.model import SensorModel

    m = SensorModel(s2, sonar, scene.render.seed)
    e = m.apply(frame_for(v)[0], speckle=False)
    mse = float(np.mean((e - target) ** 2))
    image = SonarImage(polar=e, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg, components={"expected": e},
                       sonar=sonar, pose=pose, config=fitted.to_dict())
    return CalibrationResult(fitted, v, _psnr(mse, peak), _psnr(c0, peak), renders[0], image)


def _speckled_contrast(spec: SensorSpec, sonar, total: np.ndarray, seed: int, pose, lit: np.ndarray) -> float:
    """Speckle contrast in the region ``lit`` of a speckled frame of the model."""
    from ..sensor.model import SensorModel

    m = SensorModel(spec, sonar, seed)
    return realism.speckle_contrast(m.apply(total, m.anchored_rng(pose.position_m, pose.rpy_deg)), lit)


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
