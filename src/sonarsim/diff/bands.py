"""A floor band's edges, differentiable: the pose of a floor-only scene by gradient on where its
band begins and ends in each beam, not on its intensity.

An uncalibrated render (intensity, no sensor) and a device's counts differ in their range law
(the device's TVG, its output's compression): a loss on their levels, however normalised,
pulls the pose to wherever the render's fall-off mimics the device's (on the real Oculus ping,
0.13 m and 4 degrees where the floor is near 0.42 m and 29 degrees). The band's edges do not
depend on that law. :func:`band_edges` finds them as :func:`sonarsim.analysis.fitting.band_edges`
does (the strongest rise and, beyond it, the strongest fall of the smoothed log level along
each beam) and places each between range bins by the vertex of the parabola through the
derivative's three values about its extremum: the bin is chosen, the position within it is a smooth function of
the image and so of the parameters. Its derivative is exact for the held image, whose onset
bin fills as the edge crosses it: through the logarithm that makes the edge's motion cycle
with its position in its bin (on a floor's near edge the height's derivative goes from 0.6 to
1.6 times its mean over a bin, which is the closed form's). A blur before the logarithm
removes the cycle but moves the edge off the recording's detector (2 bins: 7 mm nearer), so
the fit takes the cycling Jacobian: Levenberg-Marquardt converges with it all the same, to
where the edges agree. :func:`fit_band` fits the free pose parameters to a
recording's edges (:func:`sonarsim.analysis.fitting.band_view`) by Levenberg-Marquardt, the
search refreshed at every point.
"""

from __future__ import annotations

import math
import time
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..analysis.fitting import BAND_GAP_SIGMAS, BAND_MEDIAN_BEAMS, BAND_SMOOTHING
from .least_squares import POSE_KEYS, UNITS, levenberg_marquardt

#: A beam's edge counts where the smoothed level's step there is at least this fraction of the
#: image's spread of level (:data:`sonarsim.analysis.fitting.BAND_MIN_CONTRAST`'s role).
MIN_STEP = 0.2


def _smooth(level: jax.Array, sigma: tuple[float, float]) -> jax.Array:
    """A Gaussian blur with the edge values extended (scipy's ``mode='nearest'``), by FFT."""
    pad = tuple(int(math.ceil(4.0 * s)) + 1 for s in sigma)
    x = jnp.pad(level, ((pad[0], pad[0]), (pad[1], pad[1])), mode="edge")
    for axis in (0, 1):
        n = x.shape[axis]
        freq = jnp.fft.rfftfreq(n) * (2.0 * jnp.pi)
        shape = [1, 1]
        shape[axis] = len(freq)
        x = jnp.fft.irfft(jnp.fft.rfft(x, axis=axis) * jnp.exp(-0.5 * (sigma[axis] * freq) ** 2).reshape(shape),
                          n=n, axis=axis)
    return x[pad[0]:pad[0] + level.shape[0], pad[1]:pad[1] + level.shape[1]]


def _vertex(step: jax.Array, index: jax.Array) -> jax.Array:
    """The extremum's position between bins: the vertex of the parabola through the step at
    ``index - 1``, ``index``, ``index + 1`` (within half a bin)."""
    cols = jnp.arange(step.shape[1])
    a, b, c = (step[index + k, cols] for k in (-1, 0, 1))
    curvature = a - 2.0 * b + c
    safe = jnp.where(jnp.abs(curvature) > 1e-12, curvature, -1.0)
    offset = jnp.where(jnp.abs(curvature) > 1e-12, 0.5 * (a - c) / safe, 0.0)
    return index + jnp.clip(offset, -0.5, 0.5)


def band_edges(image: jax.Array, range_m: np.ndarray, smoothing: tuple[float, float] = BAND_SMOOTHING,
               median_beams: int = BAND_MEDIAN_BEAMS):
    """Per beam, the near and far edges of the band (metres) and whether each is clear.

    Parameters
    ----------
    image : (n_range_bins, n_beams) array
        Intensities >= 0, any scale (row 0 nearest).
    range_m : (n_range_bins,) array, metres
        Evenly spaced.
    smoothing : (float, float)
        Gaussian sigmas (range bins, beams), as the recording's edges were found with.
    median_beams : int
        Width (beams) of the median across beams (1: none), as the recording's.

    Returns
    -------
    near, far : (n_beams,) arrays, metres
    near_ok, far_ok : (n_beams,) bool arrays
        The step at the edge is at least :data:`MIN_STEP` of the level's spread.
    """
    img = jnp.maximum(image, 0.0)
    # The level as sonarsim.analysis.fitting scales it: log1p over 5 % of the 99th percentile
    # of the lit pixels. Not held: log1p is not a logarithm, and a scale that moves with the
    # parameters moves the edge (held, the height's derivative of the near edge came out 12 %
    # high against the compiled engine's differences).
    scale = jnp.nanpercentile(jnp.where(img > 0, img, jnp.nan), 99.0)
    level = jnp.log1p(img / (0.05 * jnp.where(jnp.isfinite(scale) & (scale > 0), scale, 1.0)))
    smooth = _smooth(level, smoothing)
    step = jnp.gradient(smooth, axis=0)
    n = smooth.shape[0]
    gap = max(1, int(math.ceil(BAND_GAP_SIGMAS * smoothing[0])))
    rows = jnp.arange(n)[:, None]
    inside = (rows >= gap) & (rows < n - gap)
    first = jnp.argmax(jnp.where(inside, step, -jnp.inf), axis=0)
    beyond = inside & (rows >= first[None, :] + gap)
    last = jnp.argmin(jnp.where(beyond, step, jnp.inf), axis=0)
    spread = jax.lax.stop_gradient(jnp.percentile(smooth, 99.0) - jnp.percentile(smooth, 1.0))
    to_step = smoothing[0] * math.sqrt(2.0 * math.pi)
    cols = jnp.arange(smooth.shape[1])
    near_ok = step[first, cols] * to_step >= MIN_STEP * spread
    far_ok = (-step[last, cols] * to_step >= MIN_STEP * spread) & jnp.any(beyond, axis=0)
    r0 = float(range_m[0])
    dr = float(range_m[1] - range_m[0])
    near = _median_across(r0 + _vertex(step, first) * dr, near_ok, median_beams)
    far = _median_across(r0 + _vertex(step, last) * dr, far_ok, median_beams)
    return near, far, near_ok, far_ok


def _median_across(edges: jax.Array, ok: jax.Array, width: int) -> jax.Array:
    """Each beam's edge replaced by the median over ``width`` neighbouring beams of those with a
    clear edge, as the recording's are (:func:`sonarsim.analysis.fitting.band_edges`: on a
    noise-free render it pulls the fan's outer beams towards their neighbours, by up to 12 mm
    on a 60-degree fan; compared unfiltered with a recording's filtered edges, that is a bias
    of half a degree of pitch)."""
    half = int(width) // 2
    if half < 1:
        return edges
    x = jnp.pad(jnp.where(ok, edges, jnp.nan), half, constant_values=jnp.nan)
    windows = jnp.stack([x[k:k + edges.shape[0]] for k in range(2 * half + 1)])
    return jnp.where(jnp.any(jnp.isfinite(windows), axis=0), jnp.nanmedian(windows, axis=0), edges)


def fit_band(renderer, real, free: Sequence[str] = ("z", "pitch"), starts: Sequence[Mapping] | None = None,
             iterations: int = 30, progress=None):
    """The free pose parameters that put the renderer's floor band where the recording shows it.

    Parameters
    ----------
    renderer : sonarsim.diff.Renderer
        On the recording's grid; its scene's pose is the default start and where unfree
        parameters stay.
    real : SonarImage
        The recording (its edges: :func:`sonarsim.analysis.fitting.band_view`).
    free : sequence of str
        Pose names (``x``, ``y``, ``z``, ``roll``, ``pitch``, ``yaw``).
    starts : sequence of dict, optional
        Start values by name; the lowest final cost wins.

    Returns
    -------
    values : dict of str to float
        The free parameters' values.
    cost : float
        The RMS of the edge differences over the beams counted, metres.
    per_start : list of dict
        Each start, where it ended, its cost and seconds.
    """
    from ..analysis.fitting import band_view
    from ..errors import ConfigError

    unknown = [k for k in free if k not in POSE_KEYS]
    if unknown:
        raise ConfigError("free", f"{', '.join(unknown)}: the band fit takes pose names only ({', '.join(POSE_KEYS)})")
    view = band_view(real)
    want = np.concatenate([view.near, view.far])
    counted = np.isfinite(want)
    if not counted.any():
        raise ConfigError("recording", "shows no floor band edge: the band fit has nothing to line up with")
    target = jnp.asarray(np.where(counted, want, 0.0))
    mask = jnp.asarray(counted)
    range_m = np.asarray(real.range_m, float)
    base = renderer.params()
    names = [(k, *POSE_KEYS[k]) for k in free]
    units = np.array([UNITS[key] for _, key, _ in names])
    image = renderer.image_function()

    def to_params(u):
        p = dict(base)
        for j, (_, key, index) in enumerate(names):
            p[key] = p[key].at[index].set(u[j] * units[j])
        return p

    def residuals(u, data):
        near, far, near_ok, far_ok = band_edges(image(to_params(u), data), range_m)
        sim = jnp.concatenate([near, far])
        ok = mask & jax.lax.stop_gradient(jnp.concatenate([near_ok, far_ok]))
        # A beam whose render shows no clear edge where the recording does: counted as the
        # window's length off (the render's band must move there), without a derivative.
        miss = mask & ~ok
        span = float(range_m[-1] - range_m[0])
        return jnp.where(ok, sim - target, jnp.where(miss, span, 0.0)) / math.sqrt(float(counted.sum()))

    res_at, jac_at = jax.jit(residuals), jax.jit(jax.jacfwd(residuals))
    out = []
    for k, start in enumerate(starts or [{}]):
        t0 = time.perf_counter()
        u = np.array([float(start.get(name, float(np.asarray(base[key])[index]))) for name, key, index in names]) / units
        renderer.refresh(to_params(jnp.asarray(u)))
        u, value, used = levenberg_marquardt(renderer, to_params, lambda x: res_at(x, renderer.data),
                                              lambda x: jac_at(x, renderer.data), u, iterations, ftol=1e-4,
                                              held=np.zeros(len(u), bool))
        out.append({"start": dict(start), "values": {n: float(u[j] * units[j]) for j, (n, _, _) in enumerate(names)},
                    "cost": math.sqrt(max(value, 0.0)), "iterations": used, "seconds": time.perf_counter() - t0})
        if progress is not None:
            progress(k, out[-1]["cost"])
    best = min(out, key=lambda o: o["cost"])
    renderer.refresh(to_params(jnp.asarray([best["values"][n] / units[j] for j, (n, _, _) in enumerate(names)])))
    return best["values"], best["cost"], out
