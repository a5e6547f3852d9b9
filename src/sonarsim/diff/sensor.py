"""The sensor stage, differentiable: the expected device output of the rendered image (JAX).

What :meth:`sonarsim.sensor.model.SensorModel.apply` computes with ``speckle=False``, as a
function of the sensor's parameters (:mod:`sonarsim.sensor.model` has the physics):

==================================  ==============================================================
key                                 meaning, unit
==================================  ==============================================================
``sensor.gain_db``                  the receiver's gain, dB (added to the TVG)
``sensor.source_level_db``          the source level, dB re 1 uPa at 1 m
``sensor.tvg_spreading``            the TVG law's coefficient (``spreading log10 r``), dB per decade
``sensor.noise_db``                 receiver noise power, dB re 1 uPa^2
``sensor.noise_after_tvg_db``       noise added after the TVG, dB (where the sensor has it)
``sensor.elevation_width_deg``      the elevation pattern's -3 dB width (two-way), degrees: the
                                    rays' weights (and, without ``span_deg``, their span)
``sensor.azimuth_width_deg``        the azimuth pattern's -3 dB width (one-way), degrees: the
                                    leakage across beams
``sensor.gamma``                    the output chain's exponent (``compression: gamma``)
``sensor.beam_gain_db``             (n_beams,) each receive channel's own gain ``beam_gain.gain_db``,
                                    dB, in the image's beam order (the steering loss and seeded
                                    stripes stay as the scene has them)
==================================  ==============================================================

Each exists where the scene's sensor has the part it belongs to (a Gaussian or line-array
pattern for the widths; a table pattern's width is not a parameter).

The expected output ``E[out(P S)]`` (S the speckle's unit-mean intensity) is tabulated over the
level ``10 log10 P`` on the compiled model's grid and interpolated, as the compiled stage
does; the table is formed in JAX from the parameters. With fully developed speckle and an
integer output it is the exact sum ``sum_k P(out >= k - 1/2) = sum_k exp(-p_k / P)`` over the
output's steps (``p_k`` the power at which the output reaches ``k - 1/2``): smooth in the
power and in the output chain's parameters, where an average of rounded values (the compiled
table's, over 4096 quantiles of S) is a staircase in the exponent. Otherwise the table
averages over the same quantiles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..sensor import acoustics, patterns
from ..sensor.model import SensorModel
from ..sensor.output import exponential_quantiles

LN2 = math.log(2.0)
# Integer outputs up to this full scale take the exact sum over their steps; above it the
# quantile average (a step is then a small part of the scale).
MAX_EXACT_STEPS = 4096
_FORCE_QUANTILES = False


@dataclass(frozen=True)
class SensorStatic:
    """What the sensor's forward is compiled for (hashable)."""

    elevation: str | None  # 'gaussian' | 'line' | None: the width is a parameter
    elevation_window: tuple | None
    span_follows_width: bool
    azimuth: str | None
    azimuth_window: tuple | None
    leakage_m: tuple[int, ...]  # beam offsets of the leakage kernel
    beam_spacing_deg: float
    output: str  # 'none' | 'exact' | 'quantiles'
    compression: str | None
    full_scale: float
    floor_db: float
    ceiling_db: float
    quantise: bool
    table: tuple[float, float, int]  # lo_db, step_db, n
    has_noise: bool
    has_after_tvg: bool
    tvg: bool
    span0_deg: float
    span_given: float | None = None  # the elevation pattern's span_deg
    correction: tuple | None = None  # the elevation pattern's correction_db


def _line_amplitude(u: jax.Array, window: tuple) -> jax.Array:
    """One-way amplitude of a line array (:func:`sonarsim.sensor.patterns.array_amplitude`)."""
    w = jnp.asarray(patterns.aperture_weights(*window))
    x = jnp.asarray(patterns.aperture_positions())
    return jnp.cos(2.0 * jnp.pi * u[..., None] * x) @ w / jnp.sum(w)


def pattern_gain(angle_rad: jax.Array, shape: str, window: tuple, width_deg: jax.Array, ways: int) -> jax.Array:
    """Power gain of a Gaussian or line-array pattern (:func:`sonarsim.sensor.patterns.pattern_gain`).

    A width of 0 or less (possible only inside ``jit``: the scene format's bounds are checked
    where values are concrete) is a beam that receives nothing: gain 0, gradients 0 (the width
    divided by is a stand-in there, so that no NaN comes back through the ``where``).
    """
    ok = width_deg > 0
    width = jnp.where(ok, width_deg, 1.0) * (jnp.pi / 180.0)
    if shape == "gaussian":
        gain = jnp.exp(-LN2 * (2.0 * angle_rad / width) ** 2)
    else:
        u3 = patterns.half_power_u(window[0], window[1], ways)
        gain = _line_amplitude(u3 / jnp.sin(width / 2.0) * jnp.sin(angle_rad), window) ** (2 * ways)
    return jnp.where(ok, gain, 0.0)


class SensorPart:
    """The scene's sensor, made differentiable: parameters, held arrays and the static part."""

    def __init__(self, sim, fan) -> None:
        scene = sim.scene
        spec = scene.sensor
        self.spec = spec
        self.model: SensorModel = sim.sensor_model(scene.sonar)
        model = self.model
        sonar = scene.sonar
        self.fan = fan
        ep, ap = spec.elevation_pattern, spec.azimuth_pattern
        elevation = ep.shape if ep is not None and ep.shape in ("gaussian", "line") else None
        azimuth = ap.shape if ap is not None and ap.shape in ("gaussian", "line") else None
        spacing = float(np.median(np.abs(np.diff(sonar.azimuth_deg)))) if sonar.n_beams > 1 else 1.0
        k = (len(model.beam_leakage) - 1) // 2
        out = spec.output
        speckled = spec.speckle is not None
        if out is None:
            kind = "none"
        elif out.dtype != "float32" and out.full_scale <= MAX_EXACT_STEPS and speckled and spec.speckle.exponential:
            kind = "exact" if not _FORCE_QUANTILES else "quantiles"
        else:
            kind = "quantiles"
        t = model.expected_output
        self._quantiles = None
        if kind == "quantiles":
            q = exponential_quantiles() if not speckled or spec.speckle.exponential else None
            if q is None:  # several looks, K speckle: the law the compiled table was formed with
                q = model.speckle_quantiles()
            self._quantiles = q if speckled else np.ones(1)
        self.static = SensorStatic(
            elevation=elevation, elevation_window=None if ep is None else (ep.window, ep.sidelobe_db),
            span_follows_width=elevation is not None and ep.span_deg is None,
            azimuth=azimuth, azimuth_window=None if ap is None else (ap.window, ap.sidelobe_db),
            leakage_m=tuple(range(-k, k + 1)), beam_spacing_deg=spacing, output=kind,
            compression=None if out is None else out.compression, full_scale=1.0 if out is None else float(out.full_scale),
            floor_db=0.0 if out is None else float(out.floor_db), ceiling_db=0.0 if out is None else float(out.ceiling_db),
            quantise=out is not None and out.dtype != "float32", table=(float(t.lo_db), float(t.step_db), len(t.table)),
            has_noise=spec.noise is not None, has_after_tvg=spec.noise is not None and spec.noise.after_tvg_db is not None,
            tvg=spec.tvg is not None,
            span0_deg=float(model.elevation_span_deg()),
            span_given=None if ep is None or ep.span_deg is None else float(ep.span_deg),
            correction=None if ep is None or ep.correction_db is None else tuple(float(c) for c in ep.correction_db),
        )
        self._speckled = speckled
        # The rays without the elevation pattern's gain (it is formed again from the width).
        if elevation is not None:
            from ..core.rays import make_ray_fan

            self._base_weight = make_ray_fan(model.trace_sonar(sonar), scene.render).weight.reshape(-1)
            n_el = fan.shape[2]
            self._frac = (np.arange(n_el) + 0.5) / n_el - 0.5

    def params(self) -> dict[str, np.ndarray]:
        """The sensor's parameters and their values."""
        s, st = self.spec, self.static
        out = {"sensor.gain_db": s.gain_db, "sensor.source_level_db": s.source_level_db}
        if st.tvg:
            out["sensor.tvg_spreading"] = s.tvg.spreading
        if st.has_noise:
            out["sensor.noise_db"] = s.noise.level_db
        if st.has_after_tvg:
            out["sensor.noise_after_tvg_db"] = s.noise.after_tvg_db
        if st.elevation is not None:
            w = s.elevation_pattern.width_deg
            out["sensor.elevation_width_deg"] = w if w is not None else self.model.sonar.elevation_fov_deg
        if st.azimuth is not None:
            w = s.azimuth_pattern.width_deg
            out["sensor.azimuth_width_deg"] = w if w is not None else float(np.median(self.model.sonar.effective_beam_width_deg()))
        if st.compression == "gamma":
            out["sensor.gamma"] = s.output.gamma
        out["sensor.beam_gain_db"] = self._given_beam_db()
        return {k: np.asarray(v, float) for k, v in out.items()}

    def _given_beam_db(self) -> np.ndarray:
        bg = self.spec.beam_gain
        n = self.model.sonar.n_beams
        return np.zeros(n) if bg is None or bg.gain_db is None else np.asarray(bg.gain_db, float)

    def arrays(self, search) -> dict:
        """The held arrays the sensor's forward reads (per path where the rays' weights depend
        on the elevation width)."""
        m = self.model
        r = m.range_m
        out = {
            "s_range": jnp.asarray(r), "s_log_range": jnp.asarray(np.log10(np.maximum(r, acoustics.MIN_RANGE_M))),
            "s_echo_gain": jnp.asarray(10.0 ** (m.echo_gain_db / 10.0)), "s_bang": jnp.asarray(m.bang, jnp.float64),
            "s_bang_beam": jnp.asarray(m.bang_beam, jnp.float64), # The channels' gain without the given per-beam part (a parameter).
            "s_beam_gain": jnp.asarray(10.0 ** ((m.beam_gain_db - self._given_beam_db()) / 10.0), jnp.float64),
            "s_column": jnp.asarray(m.column_factor, jnp.float64), "s_azimuth_gain": jnp.asarray(m.azimuth_gain),
            "s_kr": jnp.asarray(m.range_spread),
            "s_norm_r": jnp.asarray(m._norm_r, jnp.float64), "s_common": jnp.asarray(m.common_power),
            "s_tvg_fixed_db": jnp.asarray(self._tvg_fixed_db()), "s_kb": jnp.asarray(m.beam_leakage),
            "s_sl0": jnp.asarray(float(self.spec.source_level_db)),
        }
        if self._quantiles is not None:
            out["s_quantiles"] = jnp.asarray(self._quantiles)
        if self.static.elevation is not None:
            n_el = self.fan.shape[2]
            out["s_elevation_index"] = jnp.asarray(search.ray % n_el)
            out["s_frac"] = jnp.asarray(self._frac)
            out["s_base_weight"] = jnp.asarray(self._base_weight[search.ray])
            out["s_theta"] = jnp.asarray(self.fan.azimuth_rad.reshape(-1)[search.ray // n_el])
        return out

    def _tvg_fixed_db(self) -> np.ndarray:
        """The TVG's parts that are not parameters: absorption and the correction, dB."""
        spec = self.spec.tvg
        r = self.model.range_m
        if spec is None:
            return np.zeros(len(r))
        out = np.zeros(len(r))
        if spec.absorption:
            out = out + 2.0 * self.model.alpha_db_per_m * r
        if spec.correction_db is not None:
            out = out + 10.0 * np.log10(acoustics.tvg_correction_gain(r, spec))
        return out


def fan_rays(params: dict, data: dict, st: SensorStatic) -> tuple[jax.Array, jax.Array]:
    """The paths' fan directions (sonar frame) and weights where the elevation width is a
    parameter: the two-way pattern's gain at each ray's elevation (and, without ``span_deg``,
    the elevations and their interval scaled with the width)."""
    width = params["sensor.elevation_width_deg"]
    k = data["s_elevation_index"]
    span = jnp.minimum(3.0 * width, 170.0) if st.span_follows_width else st.span0_deg
    phi = data["s_frac"] * span * (jnp.pi / 180.0)  # (n_elevation,): one gain per elevation sample
    gain = pattern_gain(phi, st.elevation, st.elevation_window, width, ways=2)
    if st.correction is not None:  # its departure from the shape, over its span (which may follow the width)
        half = (st.span_given if st.span_given is not None else jnp.minimum(3.0 * width, 170.0)) / 2.0
        half = jnp.where(half > 0, half, 1.0)  # (a width of 0: no gain to correct, and knots apart)
        knots = jnp.linspace(-half, half, len(st.correction))
        gain = gain * jnp.interp(phi * (180.0 / jnp.pi), knots, 10.0 ** (jnp.asarray(st.correction) / 10.0))
    gain = gain[k]
    if st.span_follows_width:
        phi, theta = phi[k], data["s_theta"]
        direction = jnp.stack([jnp.cos(phi) * jnp.cos(theta), jnp.cos(phi) * jnp.sin(theta), jnp.sin(phi)], axis=1)
        # (the base weight holds cos(phi) at the fan's own elevation: a ray's solid angle)
        cos0 = jnp.cos(data["s_frac"] * st.span0_deg * (jnp.pi / 180.0))[k]
        return direction, data["s_base_weight"] * (span / st.span0_deg) * gain * (jnp.cos(phi) / cos0)
    return data["direction"], data["s_base_weight"] * gain


def leakage_kernel(params: dict, data: dict, st: SensorStatic) -> jax.Array:
    """The azimuth leakage across beams (:func:`sonarsim.sensor.patterns.azimuth_kernels`),
    on the compiled model's beam offsets, from ``sensor.azimuth_width_deg``."""
    return _leakage(params, data, st)[0]


def column_factor(params: dict, data: dict, st: SensorStatic) -> jax.Array:
    """(n_beams,) the compiled model's column factor: with an azimuth pattern each beam's cell
    (radians, the steering's cosine in it) times the pattern's equivalent width in beam
    spacings (:func:`sonarsim.sensor.patterns.azimuth_kernels`'s gain), which the width moves."""
    if st.azimuth is None:
        return data["s_column"]
    return data["s_column"] * _leakage(params, data, st)[1] / data["s_azimuth_gain"]


def _leakage(params: dict, data: dict, st: SensorStatic) -> tuple[jax.Array, jax.Array]:
    """``(kernel, gain)``: the normalised leakage and its sum before normalising."""
    if st.azimuth is None:
        return data["s_kb"], jnp.ones(())
    m = jnp.asarray(st.leakage_m, jnp.float64)
    sub = (jnp.arange(16) + 0.5) / 16 - 0.5
    offsets = (m[:, None] + sub[None, :]) * st.beam_spacing_deg * (jnp.pi / 180.0)
    k = jnp.mean(pattern_gain(offsets, st.azimuth, st.azimuth_window, params["sensor.azimuth_width_deg"], ways=1), axis=1)
    # A beam far narrower than the beams' spacing (its gain underflows at every offset, as at a
    # width of 0, possible only inside jit) leaks into no other beam: the kernel is its centre.
    total = jnp.sum(k)
    ok = total > jnp.finfo(k.dtype).tiny
    centre = jnp.asarray([1.0 if m == 0 else 0.0 for m in st.leakage_m], k.dtype)
    return jnp.where(ok, k / jnp.where(ok, total, 1.0), centre), total


def _blur(x: jax.Array, kernel: jax.Array, axis: int) -> jax.Array:
    """``sum_m k[m] x[j + m - h]`` along ``axis`` (zero outside), divided by the kernel's
    weight inside (a uniform image stays uniform)."""
    n_k = kernel.shape[0]
    if n_k == 1:
        return x
    h = n_k // 2
    n = x.shape[axis]
    pad = [(0, 0), (0, 0)]
    pad[axis] = (h, h)
    xp = jnp.pad(x, pad)
    ones = jnp.pad(jnp.ones(n), (h, h))
    out = 0.0
    inside = 0.0
    for m in range(n_k):
        sl = [slice(None), slice(None)]
        sl[axis] = slice(m, m + n)
        out = out + kernel[m] * xp[tuple(sl)]
        inside = inside + kernel[m] * ones[m:m + n]
    norm = 1.0 / inside
    return out * (norm[None, :] if axis == 1 else norm[:, None])


def expected_output(image: jax.Array, params: dict, data: dict, st: SensorStatic) -> jax.Array:
    """The sensor's expected output (n_range_bins, n_beams) of the renderer's total image."""
    x = image * column_factor(params, data, st)[None, :]
    m = _blur(_blur(x, leakage_kernel(params, data, st), axis=1), data["s_kr"], axis=0)
    sl = 10.0 ** ((params["sensor.source_level_db"] - data["s_sl0"]) / 10.0)
    mu = (data["s_echo_gain"] * sl)[:, None] * m + data["s_bang"][:, None] * data["s_bang_beam"][None, :]
    tvg_db = data["s_tvg_fixed_db"] + params["sensor.gain_db"]
    if st.tvg:
        tvg_db = tvg_db + params["sensor.tvg_spreading"] * data["s_log_range"]
    tvg = 10.0 ** (tvg_db / 10.0)
    noise = data["s_common"]
    if st.has_noise:
        noise = noise + 10.0 ** (params["sensor.noise_db"] / 10.0)
    if st.has_after_tvg:
        noise = noise + 10.0 ** (params["sensor.noise_after_tvg_db"] / 10.0) / tvg
    beam = data["s_beam_gain"] * 10.0 ** (params["sensor.beam_gain_db"] / 10.0)
    p = tvg[:, None] * beam[None, :] * (mu + noise[:, None])
    if st.output == "none":
        return p
    lo_db, step_db, n = st.table
    levels = lo_db + jnp.arange(n) * step_db
    table = output_table(10.0 ** (levels / 10.0), params, data, st)
    level = 10.0 * jnp.log10(jnp.maximum(p, 1e-30))
    return jnp.interp((level - lo_db) / step_db, jnp.arange(n, dtype=level.dtype), table)


def _compress(p: jax.Array, params: dict, st: SensorStatic) -> jax.Array:
    """Device values of powers before rounding (:func:`sonarsim.sensor.output.compress`)."""
    fs = st.full_scale
    if st.compression == "log":
        v = (10.0 * jnp.log10(jnp.maximum(p, 1e-30)) - st.floor_db) / (st.ceiling_db - st.floor_db) * fs
    elif st.compression == "gamma":
        v = fs * (jnp.maximum(p, 1e-300) / 10.0 ** (st.ceiling_db / 10.0)) ** params["sensor.gamma"]
    else:
        v = fs * p / 10.0 ** (st.ceiling_db / 10.0)
    return jnp.clip(v, 0.0, fs)


def _threshold_powers(params: dict, st: SensorStatic) -> jax.Array:
    """(full_scale,) the powers at which the output reaches ``k - 1/2``, k = 1 .. full scale."""
    fs = st.full_scale
    level = (jnp.arange(1, int(fs) + 1) - 0.5) / fs
    ceiling = 10.0 ** (st.ceiling_db / 10.0)
    if st.compression == "log":
        return 10.0 ** ((st.floor_db + level * (st.ceiling_db - st.floor_db)) / 10.0)
    if st.compression == "gamma":
        return ceiling * level ** (1.0 / params["sensor.gamma"])
    return ceiling * level


def output_table(mu: jax.Array, params: dict, data: dict, st: SensorStatic) -> jax.Array:
    """``E[out(mu S)]`` at the table's mean powers ``mu`` (n,)."""
    if st.output == "exact":
        pk = _threshold_powers(params, st)
        return jnp.sum(jnp.exp(-pk[None, :] / mu[:, None]), axis=1)
    q = data["s_quantiles"]
    out = jnp.mean(jax.vmap(lambda m: _compress(m * q, params, st))(mu), axis=1)
    if st.quantise:  # the value rounded, the derivative the unrounded mean's
        out = out + jax.lax.stop_gradient(
            jnp.mean(jax.vmap(lambda m: jnp.floor(_compress(m * q, params, st) + 0.5))(mu), axis=1) - out)
    return out
