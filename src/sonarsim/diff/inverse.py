"""Inverse problems by gradient: the pose (and any other parameters) that make the renderer's
image match a target image.

The loss compares the two images after a Gaussian blur and a compressive map, coarse to fine:
``mean((T(B_s(sim)) - T(B_s(target)))^2)`` with ``B_s`` a blur of ``s`` bins and beams and
``T(x) = log(1 + x / scale)`` (so that the floor's weak echo counts beside an object's strong
one; blurred first, so that a narrow range cell crossing a bin edge does not make the
derivative spike). A wide blur makes the loss informative far from the optimum (an echo a metre off still
overlaps its target's blurred echo); the finer levels then place it. Each level is a
Levenberg-Marquardt least-squares fit of the blurred residuals, with their Jacobian by JAX's
forward mode (one JVP per free parameter); the search is refreshed at every point the fit
evaluates (:meth:`~sonarsim.diff.Renderer.refresh`), so that the held search follows the
parameters. Several starts may be given; the lowest final loss wins.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from .least_squares import POSE_KEYS, UNITS, levenberg_marquardt

#: Parameters that act in the sensor stage alone (:func:`sonarsim.diff.sensor.expected_output`
#: on the echo): their Jacobian columns are taken there.
SENSOR_STAGE = frozenset({"sensor.gain_db", "sensor.source_level_db", "sensor.tvg_spreading", "sensor.noise_db",
                          "sensor.noise_after_tvg_db", "sensor.azimuth_width_deg", "sensor.gamma",
                          "sensor.beam_gain_db"})
#: Coarse-to-fine blur widths, in range bins and beams.
DEFAULT_BLURS = ((40.0, 20.0), (12.0, 6.0), (4.0, 2.0), (1.5, 1.0))


@dataclass(frozen=True)
class StartResult:
    """One start of a fit: where it began and ended, and its final loss."""

    start: dict
    values: dict
    loss: float
    iterations: int
    seconds: float


@dataclass(frozen=True)
class GradientFit:
    """The result of :func:`fit`.

    Attributes
    ----------
    values : dict of str to float
        The free parameters' fitted values (short pose names: metres, degrees; other keys as
        in :mod:`sonarsim.diff.params`).
    params : dict
        Every parameter at the fit (JAX arrays).
    loss : float
        The finest level's loss at the fit.
    loss_start : float
        The finest level's loss at the first start.
    starts : tuple of StartResult
        Every start, in the order tried.
    seconds : float
    """

    values: dict
    params: dict
    loss: float
    starts: tuple = field(default_factory=tuple)
    seconds: float = 0.0
    loss_start: float = float("nan")


def blur(image: jax.Array, sigma, pad: tuple[int, int] | None = None) -> jax.Array:
    """A separable Gaussian blur of ``sigma`` (range bins, beams; may be traced), zero outside
    the image: by FFT over the image padded with ``pad`` zeros on each side of each axis
    (default three sigmas), so that one compiled function serves every width up to the pad."""
    if pad is None:  # (a width given as numbers; a traced width needs its pad)
        pad = tuple(int(math.ceil(3.0 * float(v))) + 1 for v in sigma)
    sigma = jnp.asarray(sigma, image.dtype)
    x = jnp.pad(image, ((pad[0], pad[0]), (pad[1], pad[1])))
    for axis in (0, 1):
        n = x.shape[axis]
        freq = jnp.fft.rfftfreq(n) * (2.0 * jnp.pi)
        transfer = jnp.exp(-0.5 * (sigma[axis] * freq) ** 2)
        shape = [1, 1]
        shape[axis] = len(freq)
        x = jnp.fft.irfft(jnp.fft.rfft(x, axis=axis) * transfer.reshape(shape), n=n, axis=axis)
    return x[pad[0]:pad[0] + image.shape[0], pad[1]:pad[1] + image.shape[1]]


def compress_scale(target: np.ndarray) -> float:
    """The scale of ``T``: the target's median echo."""
    t = np.asarray(target, float)
    positive = t[t > 0]
    return float(np.median(positive)) if len(positive) else 1.0


def _names(free: Sequence[str], params: Mapping[str, Any]) -> list[tuple[str, str, int | None]]:
    """``(name, key, index)`` of each free parameter (a pose name, or a scalar key)."""
    out = []
    if not len(free):
        raise ConfigError("free", "no free parameter: name at least one (pose names or scalar keys)")
    if len(set(free)) != len(free):
        raise ConfigError("free", f"names a parameter twice: {', '.join(free)}")
    for name in free:
        if name in POSE_KEYS:
            key, index = POSE_KEYS[name]
            out.append((name, key, index))
        elif name in params and np.ndim(params[name]) == 0:
            out.append((name, name, None))
        else:
            allowed = ", ".join(list(POSE_KEYS) + [k for k in params if np.ndim(params[k]) == 0])
            raise ConfigError("free", f"unknown free parameter {name!r}; allowed: {allowed}")
    return out


def fit(renderer, target: np.ndarray, free: Sequence[str] = ("z", "pitch"), starts: Sequence[Mapping] | None = None,
        blurs: Sequence[tuple[float, float]] = DEFAULT_BLURS, iterations: int = 20,
        weights: np.ndarray | None = None, scale: float | None = None, progress=None,
        normalise: bool = False, linear: bool = False, base: Mapping[str, Any] | None = None,
        ftol: float = 0.0, snap: Mapping[str, Any] | None = None) -> GradientFit:
    """The free parameters that make ``renderer``'s image match ``target`` (see the module docstring).

    Parameters
    ----------
    renderer : sonarsim.diff.Renderer
        Its scene's values are where unfree parameters stay and the default start.
    target : (n_range_bins, n_beams) array
        On the renderer's grid, in the renderer's units (intensity, or counts with a sensor).
    free : sequence of str
        Pose names (``x``, ``y``, ``z``, ``roll``, ``pitch``, ``yaw``) or scalar parameter keys.
    starts : sequence of dict, optional
        Start values of free parameters by name (missing ones: the scene's); default one start,
        the scene's.
    blurs : sequence of (float, float)
        Coarse-to-fine blur widths (range bins, beams).
    iterations : int
        Per level: at most this many Levenberg-Marquardt steps.
    weights : (n_range_bins, n_beams) array, optional
        Per-pixel weights of the loss (1: all).
    scale : float, optional
        Of ``T``; default :func:`compress_scale` of the target.
    progress : callable, optional
        Called with ``(start index, level, loss)`` after each level.
    normalise : bool
        Divide each blurred image by its mean before the compressive map (images in other
        units: only their shapes are compared).
    linear : bool
        Compare the blurred images themselves (over ``scale``: the loss is their mean squared
        difference), not their logarithms: a calibration's counts.
    base : dict, optional
        The values of the parameters that are not free (default: the scene's).
    ftol : float
        A level ends when two steps in a row (after the third) lower its loss by less than
        this fraction.
    snap : dict of str to callable, optional
        Free parameters whose value, after the first level, is replaced by ``snap[name](value)``
        and then held (a value the scene format restricts, as the TVG law's coefficient).
    Returns
    -------
    GradientFit
    """
    t0 = time.perf_counter()
    if not len(blurs):
        raise ConfigError("blurs", "no level: give at least one blur width (0, 0: none)")
    base = {**renderer.params(), **({} if base is None else {k: jnp.asarray(v) for k, v in base.items()})}
    names = _names(free, base)
    target = np.asarray(target, float)
    renderer.check_params(base)  # refused as render would (the start is far from the held search: no render)
    expected = tuple(renderer.render().shape)
    if target.shape != expected:
        raise ConfigError("target", f"has shape {target.shape}; the renderer forms {expected}")
    if not np.all(np.isfinite(target)):
        raise ConfigError("target", "must be finite (it holds NaN or infinite values)")
    s = compress_scale(target) if scale is None else float(scale)
    if normalise and scale is None:
        s = 0.1  # of the mean
    w = jnp.asarray(np.ones_like(target) if weights is None else np.asarray(weights, float))
    t_img = jnp.asarray(target)
    units = np.array([UNITS[key] if key in UNITS else max(abs(float(base[key])), 1e-3) for _, key, index in names])

    def to_params(u: jax.Array) -> dict:
        p = dict(base)
        for j, (_, key, index) in enumerate(names):
            v = u[j] * units[j]
            p[key] = p[key].at[index].set(v) if index is not None else v
        return p

    def values_of(u: np.ndarray) -> dict:
        return {name: float(u[j] * units[j]) for j, (name, _, _) in enumerate(names)}

    # One compiled residual and Jacobian for every level: the blur's width is an argument.
    pad = tuple(int(math.ceil(3.0 * max(float(b[axis]) for b in blurs))) + 1 for axis in (0, 1))
    sw = jnp.sqrt(w / jnp.sum(w))

    image = renderer.image_function()

    def unit(x):
        return x / jnp.mean(x) if normalise else x

    def compressed(x):
        return x / s if linear else jnp.log1p(jnp.maximum(x, 0.0) / s)

    def finish(img, sigma, tb):
        return (sw * (compressed(unit(blur(img, sigma, pad))) - tb)).ravel()

    def residuals(u, sigma, tb, data):  # the search's arrays an argument: refreshed, not traced in
        return finish(image(to_params(u), data), sigma, tb)

    # The parameters that act in the sensor stage alone (its levels, laws and the leakage across
    # beams) take their derivatives there, on the echo formed once: forward-mode tangents
    # through the geometry cost as much for a gain as for a height.
    st = renderer.static.sensor
    stage = np.array([st is not None and key in SENSOR_STAGE for _, key, _ in names])
    if stage.any() and not stage.all():
        from . import sensor as sensor_mod

        echo = renderer.echo_function()
        i_geo, i_stage = np.flatnonzero(~stage), np.flatnonzero(stage)

        def jacobian(u, sigma, tb, data):
            j_geo = jax.jacfwd(lambda v: residuals(u.at[i_geo].set(v), sigma, tb, data))(u[i_geo])
            e = echo(to_params(u), data)
            j_stage = jax.jacfwd(lambda v: finish(sensor_mod.expected_output(
                e, to_params(u.at[i_stage].set(v)), data, st), sigma, tb))(u[i_stage])
            out = jnp.zeros((j_geo.shape[0], len(u)), j_geo.dtype)
            return out.at[:, i_geo].set(j_geo).at[:, i_stage].set(j_stage)
    else:
        jacobian = jax.jacfwd(residuals)
    residuals_at, jacobian_at = jax.jit(residuals), jax.jit(jacobian)
    levels = []
    for sigma in blurs:
        tb = compressed(unit(blur(t_img, sigma, pad)))
        sg = jnp.asarray(sigma, t_img.dtype)
        levels.append((lambda u, sg=sg, tb=tb: residuals_at(u, sg, tb, renderer.data),
                       lambda u, sg=sg, tb=tb: jacobian_at(u, sg, tb, renderer.data)))

    start_list = list(starts) if starts else [{}]
    results = []
    best = None
    for k, start in enumerate(start_list):
        ts = time.perf_counter()
        u = np.array([float(start.get(name, _value(base, key, index))) for name, key, index in names]) / units
        if k == 0:
            renderer.refresh(to_params(jnp.asarray(u)))
            r0 = np.asarray(levels[-1][0](jnp.asarray(u)), float)
            loss_start = float(r0 @ r0)
        n_iter = 0
        value = float("nan")
        held = np.zeros(len(u), bool)

        def snapped(u):
            for j, (name, _, _) in enumerate(names):
                if snap and name in snap:
                    u[j] = float(snap[name](u[j] * units[j])) / units[j]
                    held[j] = True
            return u

        for level, (res_fn, jac_fn) in enumerate(levels):
            if level == 1:
                u = snapped(u)
            u, value, used = levenberg_marquardt(renderer, to_params, res_fn, jac_fn, u, iterations, ftol=ftol,
                                                  held=held)
            n_iter += used
            if progress is not None:
                progress(k, level, value)
        if snap and not held.any() and any(name in snap for name, _, _ in names):  # one level: snapped at the end
            u = snapped(u)
            renderer.refresh(to_params(jnp.asarray(u)))
            r_end = np.asarray(levels[-1][0](jnp.asarray(u)), float)
            value = float(r_end @ r_end)
        results.append(StartResult(dict(start), values_of(u), value, n_iter, time.perf_counter() - ts))
        if best is None or value < best[1]:
            best = (u, value)
    renderer.refresh(to_params(jnp.asarray(best[0])))
    return GradientFit(values_of(best[0]), to_params(jnp.asarray(best[0])), best[1], tuple(results),
                       time.perf_counter() - t0, loss_start)


def _value(params: Mapping[str, Any], key: str, index: int | None) -> float:
    v = np.asarray(params[key], float)
    return float(v[index]) if index is not None else float(v)


def fit_recording(real, scene, free: Sequence[str] = ("z", "pitch"), starts: Sequence[Mapping] | None = None,
                  blurs: Sequence[tuple[float, float]] = DEFAULT_BLURS, progress=None):
    """:func:`sonarsim.analysis.fitting.fit_pose` by gradient: the pose parameters ``free`` that
    make ``scene`` look like the recording ``real``, on the recording's grid.

    Where the scene's echo is one floor band and the recording shows its edges
    (:func:`~sonarsim.analysis.fitting.choose_domain` says ``band``), the band's edges are
    fitted (:func:`sonarsim.diff.bands.fit_band`: they do not depend on the range law that an
    uncalibrated render and a device's counts differ in), from the band's closed-form pose for
    the sonar's elevation aperture and from the scene's pose. Where the domain is ``band`` but
    the recording shows no band edge (a sea bed lit across the window), the band's cost is flat
    within its bounds and has no gradient: the search's band fit
    (:func:`~sonarsim.analysis.fitting.fit_pose`) decides, so both methods give one verdict.
    A recording without echo (:func:`~sonarsim.analysis.fitting.echo_problems`) raises
    :class:`~sonarsim.analysis.fitting.FitError`. Otherwise the images themselves:
    without a sensor in the scene, after dividing each by its blurred mean (only their shapes
    can agree); with one, in counts. The scatterers are held on their triangles
    (``attach='surfaces'``) and the search refreshed at every point evaluated.

    Returns
    -------
    FitResult
        Its ``domain`` is ``band`` (``cost_start`` and ``cost`` the RMS band-edge differences,
        metres, as :func:`~sonarsim.analysis.fitting.fit_pose` reports them) or ``image``
        (the finest level's loss); ``renders`` counts the searches run;
        :func:`~sonarsim.analysis.fitting.fit_problems` has judged it.
    """
    from dataclasses import replace

    from ..analysis.fitting import (CENSORED_EDGE_FRACTION, NO_BAND_COST, FitResult, band_residuals, band_view,
                                    check_overlap, choose_domain, edge_correlation, fit_problems, floor_onset_m,
                                    parse_free, pose_from_values, pose_values, profile_correlation,
                                    recording_geometry, require_echo)
    from ..renderer.simulator import Simulator
    from .renderer import Renderer

    free = parse_free(free)
    check_overlap(real, scene)
    require_echo(real)
    geometry = recording_geometry(real, scene)
    fitted_scene = replace(scene, sonar=geometry)
    r = Renderer(fitted_scene, attach="surfaces")
    start = pose_values(scene.sonar_pose)
    real_view = band_view(real)

    def band_rms(image) -> float:
        d = band_residuals(real_view, band_view(image))
        return float(np.sqrt(np.nanmean(d ** 2))) if np.isfinite(d).any() else NO_BAND_COST

    t0 = time.perf_counter()
    with Simulator(fitted_scene) as sim:
        start_image = sim.render(keep_rays=False, speckle=False)
    domain, _ = choose_domain(real, fitted_scene, start_image)
    if domain == "band" and real_view.edge_fraction < CENSORED_EDGE_FRACTION:
        # A sea bed lit across the window shows no band edge: the band's cost is flat (zero)
        # wherever the render's band also passes both ends of the window, so there is no gradient
        # to follow, and the images' gradient fit judged by edges refused what the search
        # bounds. The search's band fit decides (the same verdict by either method).
        from ..analysis.fitting import fit_pose

        out = fit_pose(real, scene, free=free, domain="band")
        return replace(out, domain_reason=out.domain_reason + "; by the search: the recording shows no band edge, "
                       "so the band's cost is flat within its bounds and has no gradient to follow")
    if domain == "band" and real_view.edge_fraction >= CENSORED_EDGE_FRACTION:
        from .bands import fit_band

        if starts is None:
            starts = [{k: v for k, v in st.items() if k in free}
                      for st in band_starts(real, fitted_scene, free, half_angles=(_edge_half_angle(fitted_scene),))]
            starts = [st for st in starts if st] + [{}]
        fitted, _, per = fit_band(r, real, free, starts=starts)
        n_starts = len(per)
    else:
        domain = "image"
        result = fit(r, np.asarray(real.polar, float), free=free, starts=starts, blurs=blurs, progress=progress,
                     normalise=scene.sensor is None)
        fitted, n_starts = result.values, len(result.starts)
    values = dict(start, **{k: fitted[k] for k in free})
    pose = pose_from_values(values)
    with Simulator(fitted_scene) as sim:
        image = sim.render(pose=pose, keep_rays=False, speckle=False)
    if domain == "band":
        cost_start, cost = band_rms(start_image), band_rms(image)
    else:
        cost_start, cost = result.loss_start, result.loss
    d = floor_onset_m(image) - real_view.near
    onset = float(np.sqrt(np.nanmean(d ** 2))) if np.isfinite(d).any() else float("nan")
    how = "on the floor band's edges" if domain == "band" else "on the images"
    out = FitResult(pose=pose, free=free, domain=domain, start=start, values=values, cost_start=cost_start,
                    cost=cost, onset_rms_m=onset, renders=r.searches, image=image,
                    scene=replace(fitted_scene, sonar_pose=pose),
                    domain_reason=f"by gradient {how} ({time.perf_counter() - t0:.1f} s, {n_starts} start(s))",
                    edge_correlation=edge_correlation(real, image), profile_correlation=profile_correlation(real, image))
    return replace(out, problems=fit_problems(real, out))


def _edge_half_angle(scene) -> float:
    """Where the noise-free render's band edges lie off the sonar's axis in elevation (degrees):
    the elevation pattern's edge (:data:`~sonarsim.analysis.calibration.EDGE_RATIO` of its
    half-width) with a sensor that has one, the fan's half-aperture otherwise."""
    from ..analysis.calibration import EDGE_RATIO

    sensor = scene.sensor
    ep = None if sensor is None else sensor.elevation_pattern
    if ep is not None and ep.width_deg is not None:
        return EDGE_RATIO * float(ep.width_deg) / 2.0
    return float(scene.sonar.elevation_fov_deg) / 2.0


#: The sensor's parameters a calibration by gradient fits (where the sensor has them).
CALIBRATED = ("sensor.gain_db", "sensor.noise_db", "sensor.noise_after_tvg_db", "sensor.elevation_width_deg",
              "sensor.gamma", "sensor.tvg_spreading")
#: The levels' candidate starts (dB) tried before a calibration's first level (the generic
#: sensor's gain can be 60 dB off a device's, where the compressed output hardly moves with it).
LEVEL_GRID = {"sensor.gain_db": tuple(np.arange(-60.0, 121.0, 6.0)),
              "sensor.noise_db": tuple(np.arange(-20.0, 121.0, 10.0)),
              "sensor.noise_after_tvg_db": tuple(np.arange(-20.0, 121.0, 10.0))}
#: Blurs of a calibration's levels: the images' means first, the pixels last.
CALIBRATION_BLURS = ((4.0, 2.0), (0.0, 0.0))
#: Half-angles of the floor band's edges the closed-form starts take (degrees): one, in the
#: middle of the family, by default (from 3.5, 5 and 7 degrees the real Oculus ping's
#: calibrations end within 0.01 % of each other's loss: one floor does not tell them apart).
CALIBRATION_HALF_ANGLES = (5.0,)


def band_starts(real, scene, free: Sequence[str], half_angles: Sequence[float] = CALIBRATION_HALF_ANGLES) -> list[dict]:
    """Closed-form starts from the recording's floor band: for each half-angle of its edges,
    the height, pitch and roll that put the band where it is (:mod:`sonarsim.analysis.bandpose`)
    and an elevation width of the pattern whose edges those are; ``[{}]`` where the band does
    not give them (no band, or no pose parameter it tells is free)."""
    from ..analysis.bandpose import fit_band_lines, pose_for_half_angle, pose_from_near_edge
    from ..analysis.calibration import EDGE_RATIO
    from ..analysis.fitting import floor_band_m

    if not {"z", "pitch", "roll"} & set(free):
        return [{}]
    ground = scene.ground.offset_m if scene.ground is not None else 0.0
    try:
        near, far = floor_band_m(real)
        lines = fit_band_lines(real.azimuth_deg, near, far)
    except ValueError:
        return [{}]
    out = []
    for h in half_angles:
        try:
            z, pitch, roll = (pose_for_half_angle(lines, h) if lines.both_edges
                              else pose_from_near_edge(lines, scene.sonar_pose.position_m[2] - ground, h))
        except ValueError:
            continue
        start = {k: v for k, v in (("z", z + ground), ("pitch", pitch), ("roll", roll)) if k in free}
        start["sensor.elevation_width_deg"] = float(h) / EDGE_RATIO
        out.append(start)
    return out or [{}]


#: How far beyond the window's depression angles the window start's elevation pattern reaches
#: (its edges a fifth of the window's span outside it: the band shows no edge inside).
WINDOW_MARGIN = 1.2


def window_start(real, scene, height_m: float | None = None) -> dict | None:
    """A start for a recording lit across its whole window (a sea bed at a grazing angle: no
    band edge, so no height or tilt is told by it): at a height above the ground (default the
    scene's), the pitch that centres the window's depression angles in the elevation pattern
    and the elevation width whose edges lie just outside them (:data:`WINDOW_MARGIN`); ``z``
    the sonar's. ``None`` where the recording is not lit that way (most beams lit at the
    window's start and fading or lit to its end)."""
    from ..analysis.calibration import EDGE_RATIO
    from ..analysis.fitting import band_view

    view = band_view(real)
    across = view.lit_start & (view.fading | view.lit_end) & ~np.isfinite(view.near)
    if across.mean() < 0.5:
        return None
    ground = scene.ground.offset_m if scene.ground is not None else 0.0
    h = float(scene.sonar_pose.position_m[2]) - ground if height_m is None else float(height_m)
    r0, r1 = (max(float(x), 1e-3) for x in view.window_m)
    if h <= 0.0 or h >= r0:
        return None
    near, far = math.degrees(math.asin(h / r0)), math.degrees(math.asin(h / r1))
    half = WINDOW_MARGIN * (near - far) / 2.0
    return {"z": h + ground, "pitch": (near + far) / 2.0, "sensor.elevation_width_deg": half / EDGE_RATIO}


#: The window start's other heights: those whose window end is seen this far below the
#: horizontal (degrees). The frame chooses among them and the scene's height (a sea bed seen at
#: 0.7 degrees at the window's end fitted the ARIS sample 0.5 dB worse than at 1-4 degrees).
WINDOW_DEPRESSIONS_DEG = (1.0, 2.0, 4.0)


def fit_beam_gains(renderer, params: Mapping[str, Any], target: np.ndarray, passes: int = 4,
                   max_step_db: float = 6.0) -> dict:
    """Each receive channel's gain (``sensor.beam_gain_db``) by Gauss-Newton on the pixels'
    squared error, every beam at once: a beam's gain moves only its own column (it applies
    after the leakage across beams), so one forward-mode derivative along all of them gives
    every column's. The mean over beams is moved into ``sensor.gain_db``.

    Returns
    -------
    dict
        ``params`` with the two keys replaced.
    """
    image = renderer.image_function()
    base = dict(params)

    def with_gains(g):
        return {**base, "sensor.beam_gain_db": g}

    column = jax.jit(lambda g, data: jax.jvp(lambda x: image(with_gains(x), data), (g,), (jnp.ones_like(g),)))
    t = jnp.asarray(target)
    g = jnp.asarray(base["sensor.beam_gain_db"])
    for _ in range(passes):
        e, d = column(g, renderer.data)
        step = jnp.sum(d * (t - e), axis=0) / jnp.maximum(jnp.sum(d * d, axis=0), 1e-30)
        g = g + jnp.clip(step, -max_step_db, max_step_db)
    mean = jnp.mean(g)
    return {**base, "sensor.beam_gain_db": g - mean, "sensor.gain_db": base["sensor.gain_db"] + mean}


def level_start(renderer, start: Mapping[str, float], target: np.ndarray,
                grid: Mapping[str, Sequence[float]] | None = None, passes: int = 2,
                sigma: tuple[float, float] = (4.0, 2.0)) -> dict:
    """``start`` with the sensor's levels set by a coordinate search over :data:`LEVEL_GRID`:
    the generic sensor's gain can be 60 dB off a device's, where the compressed output hardly
    moves with it and a gradient step finds nothing. The echo is rendered once at the start
    (the levels do not move it); each candidate costs the sensor stage alone, all of one
    parameter's candidates evaluated together (``vmap``). The loss is the blurred images'
    squared difference, as at a calibration's first level."""
    from . import sensor as sensor_mod

    grid = LEVEL_GRID if grid is None else grid
    params = _with_start(renderer.params(), start)
    keys = [k for k in grid if k in params and k not in start]
    st = renderer.static.sensor
    if not keys or st is None:
        return dict(start)
    renderer.refresh(params)
    echo, data = renderer.echo(params), renderer.data
    pad = tuple(int(math.ceil(3.0 * s)) + 1 for s in sigma)
    sg = jnp.asarray(sigma, echo.dtype)
    tb = blur(jnp.asarray(target, echo.dtype), sg, pad)

    def loss(levels):
        p = dict(params)
        for j, k in enumerate(keys):
            p[k] = levels[j]
        return jnp.sum((blur(sensor_mod.expected_output(echo, p, data, st), sg, pad) - tb) ** 2)

    losses_of = jax.jit(jax.vmap(loss))
    current = np.array([float(params[k]) for k in keys])
    for _ in range(passes):
        for j, k in enumerate(keys):
            trials = np.repeat(current[None, :], len(grid[k]), axis=0)
            trials[:, j] = np.asarray(grid[k], float)
            current = _best(losses_of, trials, current, echo.dtype)
    return {**start, **{k: float(v) for k, v in zip(keys, current)}}


def _with_start(params: Mapping[str, Any], start: Mapping[str, float]) -> dict:
    """``params`` with a start's values (pose names and parameter keys) set."""
    out = dict(params)
    for name, value in start.items():
        if name in POSE_KEYS:
            key, index = POSE_KEYS[name]
            out[key] = out[key].at[index].set(float(value))
        elif name in out:
            out[name] = jnp.asarray(float(value), out[name].dtype)
    return out


def _at_pose(scene, start: Mapping[str, float]):
    """``scene`` with the pose names in ``start`` set."""
    from .params import scene_with

    position = np.array(scene.sonar_pose.position_m, float)
    rpy = np.array(scene.sonar_pose.rpy_deg, float)
    for name, value in start.items():
        if name in POSE_KEYS:
            key, index = POSE_KEYS[name]
            (position if key == "sonar.position_m" else rpy)[index] = float(value)
    return scene_with(scene, {"sonar.position_m": position, "sonar.rpy_deg": rpy})


def _best(losses_of, trials: np.ndarray, current: np.ndarray, dtype) -> np.ndarray:
    losses = np.array(losses_of(jnp.asarray(trials, dtype)), float)
    losses[~np.isfinite(losses)] = np.inf
    return trials[int(np.argmin(losses))].copy() if np.isfinite(losses).any() else current


def calibrate_recording(real, scene, free: Sequence[str] = ("z", "pitch", "roll"), starts: Sequence[Mapping] | None = None,
                        iterations: int = 10, ftol: float = 1e-3, progress=None, refuse_degenerate: bool = True):
    """Fit the sensor (:data:`CALIBRATED`) and the pose parameters ``free`` to one frame of a
    recording by gradient: the expected output against the frame's counts, pixel by pixel,
    after blurs from coarse to none (:data:`CALIBRATION_BLURS`), from the floor band's
    closed-form starts (:func:`band_starts`), the best start kept.

    Parameters
    ----------
    real : SonarImage
        The frame, in the device's counts (8-bit: 0-255).
    scene : Scene
        The scene behind it: its sensor, or the calibration's generic start
        (:data:`sonarsim.analysis.calibration.STARTING_SENSOR`), and its pose.
    free : sequence of str
        Pose names fitted as well.
    starts : sequence of dict, optional
        Default :func:`band_starts`.
    iterations : int
        Levenberg-Marquardt steps per level.
    refuse_degenerate : bool
        Raise :class:`~sonarsim.analysis.calibration.CalibrationFailed` (as the search
        calibration does, the same verdicts): height, pitch or roll free where the recording
        shows no floor band edge, a free pose parameter that does not change the render
        (:func:`~sonarsim.analysis.fitting.unidentified_parameters`), a sensor value beyond
        its physical bounds (:func:`~sonarsim.analysis.calibration.parameter_bounds`), a model
        that explains no echo (:func:`~sonarsim.analysis.calibration.model_problems`). False:
        the pose is held at a window start where the recording is lit across its window, and
        the rest are listed in ``warnings``. A frame without an echo
        (:func:`~sonarsim.analysis.calibration.frame_problems`) is refused either way.

    Returns
    -------
    CalibrationResult
        As :func:`sonarsim.analysis.calibration.calibrate` returns it: the calibrated scene on
        the recording's grid (the TVG law's coefficient the nearest the scene format allows
        to the coarse level's, held at the finer), the values (sensor keys without their
        ``sensor.`` prefix), the PSNR on the frame at the start (the closed-form start, its
        levels set by :func:`level_start`) and at the end, the expected
        render (the compiled engine's), the starts, the laws and the frame's trivial
        baselines; ``renders`` counts the searches run.
    """
    from dataclasses import replace

    from ..analysis import metrics
    from ..analysis.baselines import baseline_images
    from ..analysis import realism
    from ..analysis.calibration import (PINNED_COST_RISE, STARTING_SENSOR, CalibrationFailed, CalibrationResult,
                                        band_lines, frame_problems, model_problems, no_band_edge_problem,
                                        output_shape, parameter_bounds, with_law)
    from ..analysis.fitting import check_overlap, recording_geometry, unidentified_parameters, unidentified_problem
    from ..config.sensor import TVG_SPREADING, parse_sensor
    from ..renderer.simulator import Simulator
    from .params import scene_with
    from .renderer import Renderer

    check_overlap(real, scene)
    target = np.asarray(real.polar, float)
    refused = frame_problems(target)
    if refused:  # the search calibration's verdict, before any work
        raise CalibrationFailed(["the recording holds no echo to calibrate on: " + "; ".join(refused)], None)
    told = [k for k in ("z", "pitch", "roll") if k in free]
    if told and refuse_degenerate and band_lines(real) is None:
        raise CalibrationFailed([no_band_edge_problem(told)], None)
    spec = scene.sensor
    if spec is None:  # the generic sensor, its output's shape from the frame's speckle
        spec = parse_sensor(STARTING_SENSOR)
        if spec.output is not None and spec.output.compression in ("gamma", "log"):
            try:
                shape = output_shape(spec.output.compression, target, realism.auto_regions(target)["lit"],
                                     spec.output.full_scale)
            except ValueError as exc:
                raise CalibrationFailed([f"the recording has no speckle to calibrate on in its bright band: {exc}"],
                                        None) from None
            spec = with_law(spec, spec.output.compression, None, shape)
    fitted = replace(scene, sonar=recording_geometry(real, scene), sensor=spec)
    notes = []
    across = None
    if starts is None:
        starts = band_starts(real, fitted, free)
        across = window_start(real, fitted) if starts == [{}] and {"z", "pitch", "roll"} & set(free) else None
    base = None
    if across is not None:
        # Lit across the window: the band tells neither height nor tilt, so the pose is held
        # where a window start puts it: the one that fits the frame best, with its levels, of
        # the scene's height and those of WINDOW_DEPRESSIONS_DEG.
        r1 = float(real.range_m[-1])
        heights = [None] + [r1 * math.sin(math.radians(d)) for d in WINDOW_DEPRESSIONS_DEG]
        candidates = [c for c in (window_start(real, fitted, h) for h in heights) if c is not None]
        # (built at a fixed candidate: one compiled shape whatever the scene's pose)
        r = Renderer(_at_pose(fitted, candidates[-1]), attach="surfaces")
        tried = []
        for c in candidates:
            st = level_start(r, c, target)
            image = np.asarray(r.render(_with_start(r.params(), st)))
            tried.append((float(np.mean((image - target) ** 2)), st))
        chosen = min(tried, key=lambda t: t[0])[1]
        held = [k for k in free if k in POSE_KEYS]
        notes.append(f"the recording is lit across its window (no floor band edge): {', '.join(held)} not "
                     f"identified by it; held at a window start: z {chosen['z']:.3f} m, pitch {chosen['pitch']:.2f} deg "
                     f"(of {len(candidates)} heights, the one that fits this frame best)")
        free = tuple(k for k in free if k not in POSE_KEYS)
        at = _with_start(r.params(), chosen)
        base = {"sonar.position_m": at["sonar.position_m"], "sonar.rpy_deg": at["sonar.rpy_deg"]}
        fitted = _at_pose(fitted, chosen)
        starts = [{k: v for k, v in chosen.items() if k not in POSE_KEYS}]
    else:
        # Built at the first start's pose: its search's capacity (and so the compiled
        # functions' shapes) is then the same whatever pose the scene gave.
        r = Renderer(_at_pose(fitted, starts[0] if starts else {}), attach="surfaces")
        starts = [level_start(r, start, target) for start in starts]
    names = [n for n in free] + [k for k in CALIBRATED if k in r.names]
    full = float(spec.output.full_scale) if spec.output is not None else float(np.max(target))
    # The TVG law's coefficient is fitted at the coarse level, then set to the nearest the
    # scene format allows and held while the rest is fitted again.
    nearest = {"sensor.tvg_spreading": lambda v: min(TVG_SPREADING, key=lambda w: abs(w - v))}
    result = fit(r, target, free=names, starts=starts, blurs=CALIBRATION_BLURS, iterations=iterations,
                 scale=full, linear=True, progress=progress, ftol=ftol, snap=nearest, base=base)
    values = dict(result.values)
    best = dict(result.params)
    image = r.image_function()
    # Levenberg-Marquardt knows no bounds: a value beyond the search's physical bounds
    # (parameter_bounds) is set to its bound. Where that costs fit, the fit wants it beyond:
    # pinned, refused; where it does not, the frame does not determine it there (the ARIS
    # sample's noise before the TVG went to -110 dB re 1 uPa^2): said, as the search says it.
    bounds = parameter_bounds(spec, fitted.sonar)
    clipped = {k: float(np.clip(values[k], *bounds[k[7:]])) for k in values
               if k.startswith("sensor.") and k[7:] in bounds and not bounds[k[7:]][0] <= values[k] <= bounds[k[7:]][1]}
    pinned, at_bounds = [], []
    if clipped:
        mse_free = float(np.mean((np.asarray(image(best, r.data)) - target) ** 2))
        on_bounds = {**best, **{k: jnp.asarray(v, best[k].dtype) for k, v in clipped.items()}}
        mse_bound = float(np.mean((np.asarray(image(on_bounds, r.data)) - target) ** 2))
        texts = [f"{k[7:]} {values[k]:.4g} (bounds {bounds[k[7:]][0]:.4g} to {bounds[k[7:]][1]:.4g})" for k in clipped]
        if not mse_bound <= mse_free * (1.0 + PINNED_COST_RISE):
            pinned = texts
        else:
            best = on_bounds
            values.update(clipped)
            at_bounds = [k[7:] for k in clipped]
            notes.append("parameters at their bounds, which the frame does not determine there (the fit is as good on "
                         "the bound as beyond it): " + ", ".join(f"{k[7:]} {v:.4g}" for k, v in clipped.items()))
    if "sensor.beam_gain_db" in best:
        # The channels' gains last, in closed form (kept where they lower the frame's error).
        before = float(np.mean((np.asarray(image(best, r.data)) - target) ** 2))
        channels = fit_beam_gains(r, best, target)
        if float(np.mean((np.asarray(image(channels, r.data)) - target) ** 2)) < before:
            best = channels
            values["sensor.gain_db"] = float(best["sensor.gain_db"])
    params = {k: v for k, v in values.items() if k.startswith("sensor.")}
    params["sensor.beam_gain_db"] = np.asarray(best["sensor.beam_gain_db"], float)
    pose = {"sonar.position_m": np.asarray(result.params["sonar.position_m"], float),
            "sonar.rpy_deg": np.asarray(result.params["sonar.rpy_deg"], float)}
    calibrated = scene_with(fitted, {**pose, **params})
    with Simulator(calibrated) as sim:
        expected = sim.render(speckle=False, keep_rays=False)
    out_spec = calibrated.sensor
    peak = float(out_spec.output.full_scale) if out_spec.output is not None else float(np.max(target))
    start_mse = result.loss_start * full ** 2  # the finest level's loss is the MSE over full scale squared
    law = {"compression": None if out_spec.output is None else out_spec.output.compression,
           "spreading": None if out_spec.tvg is None else out_spec.tvg.spreading,
           "shape": None if out_spec.output is None else out_spec.output.gamma}
    values["sensor.beam_gain_db"] = [round(float(x), 4) for x in params["sensor.beam_gain_db"]]
    # The search calibration's verdicts (analysis.calibration): the same recording, the same answer.
    problems = model_problems(target, expected.polar)
    loose = unidentified_parameters(calibrated, [k for k in free if k in POSE_KEYS])
    if loose:
        problems.append(unidentified_problem(loose))
    if pinned:
        problems.append("parameters pinned at their physical bounds, where the fit wants them beyond: "
                        + ", ".join(pinned))
    out = CalibrationResult(
        scene=calibrated, values={k.replace("sensor.", "", 1): v for k, v in values.items()},
        psnr_db=metrics.psnr(target, expected.polar, data_range=peak),
        psnr_start_db=float(10 * np.log10(peak ** 2 / start_mse)) if start_mse > 0 else float("inf"),
        renders=r.searches, expected=expected,
        starts=[{"start": dict(st.start), "values": dict(st.values), "loss": st.loss, "seconds": st.seconds}
                for st in result.starts],
        baselines={k: metrics.psnr(target, img, data_range=peak) for k, img in baseline_images(target).items()},
        law=law, warnings=notes, at_bounds=at_bounds)
    if problems:
        if refuse_degenerate:
            raise CalibrationFailed(problems, out)
        out.warnings.extend(problems)
    return out
