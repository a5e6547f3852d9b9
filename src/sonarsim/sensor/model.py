"""The sensor stage: from the renderer's noise-free image to what the device outputs.

Per frame, for a range-compensated image X (``render.tvg: true``: the backscatter each bin
receives, ``sigma / r^2`` summed over the bin):

1. the receive beams' azimuth sidelobes leak each beam's echo into its neighbours, and the
   pulse spreads it over neighbouring range bins: ``M = K_range * (K_beams * X)`` (powers);
2. the sonar equation makes it an echo power at the receiver: ``mu = g(r) M + bang(r) B_j``
   (the bang's range profile times its pattern across beams, :mod:`~sonarsim.sensor.channels`),
   ``10 log10 g = SL - 20 log10 r - 2 alpha r + 10 log10(dtheta) + TS_offset``
   (:func:`~sonarsim.sensor.acoustics.echo_level_offset_db`);
3. speckle and noise are complex amplitudes: ``a = sqrt(mu) F + sqrt(N) W + sqrt(C(r)) z``, F
   the speckle field (unit power, filtered by the pulse and the beam: its grain is the
   resolution cell), W receiver noise (unit power, through the same beamformer and receiver
   band; N also carries the noise added after the TVG, ``N_a / t(r)``), z one unit complex
   Gaussian per row and frame: noise common to all beams of the row, of power C(r);
4. the channel's gain, TVG and gain: ``P = t(r) G_j |a|^2``, G_j the across-fan gain and stripes
   (:mod:`~sonarsim.sensor.channels`), ``10 log10 t = spreading log10 r + 2 alpha r + gain``;
5. the output chain: compression, saturation, quantisation (:mod:`~sonarsim.sensor.output`).

``speckle=False`` gives instead the expected device value ``E[out(t G (mu + N + C) S)]`` (S the
unit speckle intensity), tabulated over the level. The elevation pattern acts earlier, on the rays:
the renderer casts them over ``span_deg`` weighted by the two-way pattern
(:meth:`SensorModel.elevation_gain`).
"""

from __future__ import annotations

import importlib
import os
from concurrent.futures import Executor
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ..config.sensor import SensorSpec, check_azimuth_width, check_bandwidth, check_beam_count
from ..config.sonar import SonarConfig
from ..core import streams
# The stream ids, defined with their generators in core.streams: re-exported here, where they were before.
from ..core.streams import BEAM_DRAWS, BEAM_STREAM, FRAME_STREAM, POOL_STREAM, WORLD_STREAM  # noqa: F401
from ..core.streams import beam_rng
from ..errors import ConfigError
from . import acoustics, channels, output, patterns, pulse, speckle as speckle_mod

# The compiled loops are imported by name, not ``from . import _stage``: they import nothing of
# sonarsim, but a static import of an extension reads, to an import graph of the .py files, as
# an import of this package, whose __init__ imports this module (a false cycle).
try:  # the compiled loops; the NumPy twins below are the reference
    _stage_baseline = importlib.import_module(f"{__package__}._stage")
except ImportError:  # pragma: no cover - a source checkout without the extension built
    _stage_baseline = None


def _choose_stage():
    """The compiled stage for this processor: the AVX2/FMA build where it runs, else the baseline.

    ``SONARSIM_SIMD=baseline`` forces the baseline build (to compare the two, or to rule one out).
    """
    if _stage_baseline is None or os.environ.get("SONARSIM_SIMD", "").lower() == "baseline":
        return _stage_baseline
    if _stage_baseline.has_avx2_fma():
        try:
            return importlib.import_module(f"{__package__}._stage_avx2")
        except ImportError:  # pragma: no cover - built without it (not x86-64)
            pass
    return _stage_baseline


_stage = _choose_stage()

COMPRESSION_CODES = {None: 0, "log": 1, "gamma": 2, "linear": 3}


class FrameDraws(NamedTuple):
    """What a frame draws: the speckle's and the noise's pool windows, and the noise common to
    each row's beams ((n_range_bins,) complex amplitudes, sqrt(uPa^2); ``None`` without it)."""

    speckle: speckle_mod.FieldDraw
    noise: speckle_mod.FieldDraw
    common: np.ndarray | None


# A sensor's elevation span defaults to this many -3 dB widths.
DEFAULT_SPAN_WIDTHS = 3.0


def _edge_norm(kernel: np.ndarray, n: int) -> np.ndarray:
    """1 / (kernel weight falling inside 0..n-1) at each index: a uniform image stays uniform."""
    h = len(kernel) // 2
    inside = np.convolve(np.ones(n), kernel[::-1], mode="full")[h:h + n]
    return (1.0 / inside).astype(np.float32)


# The stage forms powers in float32 (at most about 385 dB): the levels it multiplies must stay
# below this, with 15 dB (x30) of room for the image's own values and the speckle's tail.
MAX_LEVEL_DB = 370.0


def _check_levels(echo_gain_db: np.ndarray, tvg_db: np.ndarray, spec: SensorSpec, sonar: SonarConfig,
                  alpha_db_per_m: float, beam_gain_db: np.ndarray, bang_beam_db: np.ndarray) -> None:
    """Refuse a sensor whose levels over the range window leave what float32 holds.

    Each key is bounded on its own (config.sensor); together they can still overflow: the
    absorption (up to hundreds of dB/m at a high frequency) over a long range window, a TVG
    that lifts it back, a gain on top. The image would be inf or nan without a word.

    Raises
    ------
    ConfigError
        ``sensor``: the level reached, where, and what sets it.
    """
    from ..errors import ConfigError

    levels = [echo_gain_db]
    if spec.noise is not None:
        levels.append(np.full_like(tvg_db, spec.noise.level_db))
        if spec.noise.common_db is not None:
            levels.append(np.full_like(tvg_db, spec.noise.common_db))
    if spec.bang is not None:
        levels.append(np.full_like(tvg_db, spec.bang.level_db + float(np.max(bang_beam_db))))
        if spec.bang.ringing_db is not None:
            levels.append(np.full_like(tvg_db, spec.bang.ringing_db + float(np.max(bang_beam_db))))
    # Each channel's gain multiplies every level of its beam: the largest one bounds them.
    peak = np.max(levels, axis=0) + tvg_db + float(np.max(beam_gain_db))
    worst = int(np.argmax(np.abs(peak)))
    low = spec.noise is not None and spec.noise.after_tvg_db is not None and float(np.min(tvg_db)) < -MAX_LEVEL_DB
    if not np.all(np.isfinite(peak)) or float(np.abs(peak[worst])) > MAX_LEVEL_DB or low:
        where = float(sonar.range_m[worst])
        raise ConfigError(
            "sensor",
            f"the sonar equation reaches {float(peak[worst]):.4g} dB at {where:.4g} m (absorption "
            f"{alpha_db_per_m:.3g} dB/m each way, TVG {float(tvg_db[worst]):.4g} dB with gain_db, beam gains up to "
            f"{float(np.max(beam_gain_db)):.4g} dB): beyond the "
            f"+-{MAX_LEVEL_DB:g} dB the sensor stage can hold; shorten sonar.range_max_m, or lower the "
            "absorption, the frequency or the gain",
        )


def elevation_span_deg(spec: SensorSpec, sonar: SonarConfig) -> float:
    """The full elevation span (degrees) a sensor's rays are cast over: its elevation pattern's
    ``span_deg`` (default 3 -3 dB widths, at most 170), or the sonar's aperture without one."""
    p = spec.elevation_pattern
    if p is None:
        return sonar.elevation_fov_deg
    width = p.width_deg if p.width_deg is not None else sonar.elevation_fov_deg
    return p.span_deg if p.span_deg is not None else min(DEFAULT_SPAN_WIDTHS * width, 170.0)


class SensorModel:
    """A sensor spec made concrete for one sonar: its tables, kernels and speckle pool.

    Parameters
    ----------
    spec : SensorSpec
    sonar : SonarConfig
        The image's intrinsics (range bins, beams, frequency).
    seed : int
        Seed of the speckle and noise pool (the scene's ``render.seed``).
    fields : bool
        Build the speckle and noise fields; ``False``: only the expected output is available
        (``apply(..., speckle=False)``), which is what a calibration evaluates many times.

    Attributes
    ----------
    range_m : (n_range_bins,) float64 ndarray, metres
    echo_gain, tvg : (n_range_bins,) float32 ndarrays
        g(r) and t(r) (TVG and gain) as powers.
    bang : (n_range_bins,) float32 ndarray, uPa^2
        The bang's range profile (:func:`~sonarsim.sensor.channels.bang_row`).
    beam_gain_db, bang_beam_db : (n_beams,) float64 ndarrays, dB
        The channels' gain G_j and the bang's pattern B_j, seeded stripes included
        (:func:`~sonarsim.sensor.channels.beam_gain_db`, :func:`~sonarsim.sensor.channels.bang_beam_db`,
        drawn from :func:`~sonarsim.core.streams.beam_rng`); ``beam_gain`` and ``bang_beam``: the
        same as float32 powers.
    noise_row : (n_range_bins,) float32 ndarray, uPa^2
        N(r): the receiver's noise plus the after-TVG noise referred to the receiver.
    common_power : (n_range_bins,) float64 ndarray, uPa^2
        C(r), the noise common to a row's beams (:func:`~sonarsim.sensor.channels.common_noise_power`).
    """

    def __init__(self, spec: SensorSpec, sonar: SonarConfig, seed: int = 0, fields: bool = True) -> None:
        self.spec = spec
        self.sonar = sonar
        self.seed = int(seed)
        freq = spec.frequency_khz if spec.frequency_khz is not None else sonar.frequency_khz
        self.alpha_db_per_m = acoustics.absorption_db_per_m(spec.absorption, freq, spec.sound_speed_m_s)
        r = sonar.range_m
        self.range_m = r
        self.echo_gain_db = acoustics.echo_level_offset_db(r, spec.source_level_db, self.alpha_db_per_m,
                                                           spec.target_strength_db)
        self.tvg_db = acoustics.tvg_db(r, spec.tvg, self.alpha_db_per_m) + spec.gain_db
        try:  # as Scene checks its own sonar: this one may be another (Simulator.render(sonar=...))
            check_beam_count(spec, sonar.n_beams)
        except ConfigError as exc:
            raise ConfigError(f"sensor.{exc.key}", exc.detail) from None
        # The channels' per-beam factors (dB, then powers): fixed for the scene's seed.
        self.beam_gain_db = channels.beam_gain_db(spec.beam_gain, sonar.azimuth_deg, beam_rng(self.seed, "beam_gain"))
        self.bang_beam_db = channels.bang_beam_db(spec.bang, sonar.n_beams, beam_rng(self.seed, "bang"))
        _check_levels(self.echo_gain_db, self.tvg_db, spec, sonar, self.alpha_db_per_m, self.beam_gain_db,
                      self.bang_beam_db)
        self.echo_gain = (10.0 ** (self.echo_gain_db / 10.0)).astype(np.float32)
        self.tvg = (10.0 ** (self.tvg_db / 10.0)).astype(np.float32)
        self.beam_gain = (10.0 ** (self.beam_gain_db / 10.0)).astype(np.float32)
        self.bang_beam = (10.0 ** (self.bang_beam_db / 10.0)).astype(np.float32)
        self.noise_power = 0.0 if spec.noise is None else 10.0 ** (spec.noise.level_db / 10.0)
        self.bang = channels.bang_row(spec.bang, r).astype(np.float32)
        # Noise power per range bin, referred to the receiver: the receiver's, plus the noise
        # added after the TVG over t(r) (a floor the TVG does not lift). Both are complex
        # Gaussian and independent of the echo: one noise term of their summed power.
        noise_row = np.full(len(r), self.noise_power)
        if spec.noise is not None and spec.noise.after_tvg_db is not None:
            noise_row = noise_row + 10.0 ** (spec.noise.after_tvg_db / 10.0) / self.tvg.astype(np.float64)
        self.noise_row = noise_row.astype(np.float32)
        # The noise common to a row's beams: its power per row, and in the expected output
        # (where every independent complex Gaussian term adds its power) the total.
        self.common_power = channels.common_noise_power(spec.noise, r)
        self._has_common = bool(np.any(self.common_power > 0))
        self.noise_expected = ((noise_row + self.common_power).astype(np.float32) if self._has_common
                               else self.noise_row)
        self._no_common = np.zeros(len(r), np.float32)
        # The image holds backscatter per radian of beam width (sigma / cos(alpha) cos(phi) dphi
        # per ray, see config.materials and core.rays); times each beam's width in radians it is
        # sigma / r^2.
        self.column_factor = np.radians(sonar.effective_beam_width_deg()).astype(np.float32)
        spacing = float(np.median(np.abs(np.diff(sonar.azimuth_deg)))) if sonar.n_beams > 1 else 1.0
        # The cell a pose is quantised to for world-anchored speckle (see anchored_rng).
        self._anchor_cell = np.array([sonar.range_resolution_m / 2.0] * 3 + [spacing / 2.0] * 3)
        default_width = float(np.median(sonar.effective_beam_width_deg()))
        try:  # as Scene checks its own sonar: this one may be another (Simulator.render(sonar=...))
            check_bandwidth(spec, sonar.frequency_khz)
            if sonar.n_beams > 1:
                check_azimuth_width(spec, spacing, default_width)
        except ConfigError as exc:
            raise ConfigError(exc.key if exc.key.startswith("sonar.") else f"sensor.{exc.key}", exc.detail) from None
        self._spacing_deg, self._default_width_deg = spacing, default_width
        self._sub_kernels: dict = {}
        if spec.azimuth_pattern is None:
            self.beam_leakage, self.beam_amplitude, self.azimuth_gain = np.ones(1), np.ones(1), 1.0
        else:
            self.beam_leakage, self.beam_amplitude, self.azimuth_gain = patterns.azimuth_kernels(
                spec.azimuth_pattern, spacing, default_width)
            # With a receive pattern the beam's width is the pattern's: each beam's rays stand
            # for its cell (one beam spacing of azimuth, where the rays tile the fan), and the
            # pattern's equivalent width (azimuth_gain spacings) is what a beam hears of an even
            # floor, while a point target on its axis is heard at the pattern's peak. (The
            # sonar's beam_width_deg would count the overlap of neighbouring beams twice.)
            self.column_factor = (np.radians(-np.diff(sonar.beam_edges_deg)) * self.azimuth_gain).astype(np.float32)
            if spec.azimuth_pattern.steering_loss:
                # a steered beam's aperture is foreshortened: its directivity falls as cos(theta)
                self.column_factor = (self.column_factor * np.cos(np.radians(sonar.azimuth_deg))).astype(np.float32)
        self.range_spread, self.range_amplitude = pulse.range_kernels(spec.pulse, sonar.range_resolution_m,
                                                                      spec.sound_speed_m_s)
        self._kb = self.beam_leakage.astype(np.float32)
        self._one = np.ones(1, np.float32)
        self._ones_b = np.ones(sonar.n_beams, np.float32)
        self._kr = self.range_spread.astype(np.float32)
        self._norm_b = _edge_norm(self.beam_leakage, sonar.n_beams)
        self._norm_r = _edge_norm(self.range_spread, sonar.n_range_bins)
        shape = (sonar.n_range_bins, sonar.n_beams)
        self.pool = speckle_mod.SpecklePool(shape, self.range_amplitude, self.beam_amplitude,
                                            spec.speckle if fields else None, fields and spec.noise is not None,
                                            self.seed)
        if spec.speckle is None or spec.speckle.exponential:
            self.expected_output = output.expected_output(spec.output, spec.speckle is not None)
        else:
            self.expected_output = output.ExpectedOutput(spec.output, self.speckle_quantiles())
        out = spec.output
        self._comp = COMPRESSION_CODES[None if out is None else out.compression]
        self._fs = 1.0 if out is None else out.full_scale
        self._quantise = out is not None and out.dtype != "float32"
        lo = 0.0 if out is None else out.floor_db
        hi = 1.0 if out is None else out.ceiling_db
        self._lo_db = lo
        self._inv_span = 1.0 / (hi - lo) if out is not None and out.compression == "log" else 0.0
        self._inv_ceiling = 0.0 if out is None else 10.0 ** (-out.ceiling_db / 10.0)
        self._gamma = 1.0 if out is None else out.gamma
        self._dummy = np.zeros((1, 1, 2, 2), np.int8)  # stands for an absent pool field
        self._work: tuple[np.ndarray, np.ndarray] | None = None
        self._traced: SonarConfig | None = None
        self._saturation_warned = False

    def speckle_quantiles(self) -> np.ndarray | None:
        """Midpoint quantiles (:data:`~sonarsim.sensor.output.QUANTILES`) of the unit-mean speckle
        intensity S the expected output averages over (:func:`~sonarsim.sensor.output.intensity_quantiles`:
        the law of the spec's looks and texture, which the pool's fields follow); ``None``
        without speckle."""
        spec = self.spec.speckle
        if spec is None:
            return None
        return output.intensity_quantiles(spec.model, float(spec.k_shape), float(spec.looks))

    # The elevation pattern (used by the renderer when it makes the rays) ---------------------

    def elevation_span_deg(self) -> float:
        """The full elevation span rays are cast over (the sonar's aperture without a pattern)."""
        return elevation_span_deg(self.spec, self.sonar)

    def trace_sonar(self, sonar: SonarConfig | None = None) -> SonarConfig:
        """The sonar the renderer traces: the image's, with the elevation aperture widened to the span.

        Formed once per model: the renderer asks every frame, and building a ``SonarConfig``
        (validation, beam edges) costs a third of a millisecond.
        """
        if sonar is None or sonar is self.sonar or sonar == self.sonar:
            if self._traced is None:
                self._traced = self._widen(self.sonar)
            return self._traced
        return self._widen(sonar)

    def _widen(self, sonar: SonarConfig) -> SonarConfig:
        span = self.elevation_span_deg()
        return sonar if span == sonar.elevation_fov_deg else replace(sonar, elevation_fov_deg=span)

    def elevation_gain(self, elevation_rad: np.ndarray) -> np.ndarray:
        """Two-way power gain (transmit x receive) at elevations off the acoustic axis; 1 without a pattern."""
        p = self.spec.elevation_pattern
        if p is None:
            return np.ones_like(np.asarray(elevation_rad, dtype=float))
        return patterns.pattern_gain(elevation_rad, p, self.sonar.elevation_fov_deg, ways=2)

    # Per frame ---------------------------------------------------------------------------------

    def draws(self, rng: np.random.Generator, noise_rng: np.random.Generator | None = None) -> FrameDraws:
        """The speckle and noise fields a frame reads: the speckle's from ``rng`` (the frame's, or
        the pose's when anchored to the world), the noise's from ``noise_rng`` (default ``rng``):
        receiver noise is new in every frame even when the speckle is still. The noise common
        to a row's beams is drawn after the noise's window, from the same generator."""
        n_rng = noise_rng if noise_rng is not None else rng
        ds, dn = self.pool.draw(rng), self.pool.draw(n_rng)
        common = None
        if self._has_common and self.pool.noise is not None:
            common = channels.common_noise_amplitude(self.common_power, self.range_amplitude, n_rng)
        return FrameDraws(ds, dn, common)

    def anchored_rng(self, position_m, rpy_deg) -> np.random.Generator:
        """A generator that is a function of the pose quantised to half a resolution cell.

        A still sonar reads the same fields frame after frame (still speckle); moving by more
        than half a range bin, or turning by more than half a beam, reads other fields
        (:func:`~sonarsim.core.streams.world_rng`).
        """
        pose = np.concatenate([np.asarray(position_m, float), np.asarray(rpy_deg, float)])
        return streams.world_rng(self.seed, np.floor(pose / self._anchor_cell))

    def mean_image(self, image: np.ndarray, pool: Executor | None = None,
                   column_offsets_deg: np.ndarray | None = None) -> np.ndarray:
        """``M``: the image through the azimuth leakage and the range spread (float32).

        ``image``: (n_range_bins, n_beams), or (n_range_bins, n_beams, S) of a beam's S columns
        of rays with ``column_offsets_deg`` (see :meth:`fold_columns`)."""
        x, kb, col, norm_b = self._beams_input(image, column_offsets_deg)
        if _stage is None:
            return self._mean_reference(x, kb, col, norm_b)
        if len(kb) == 1 and len(self._kr) == 1:  # no leakage, no pulse: the beam's width only
            return x * (col * kb[0])[None, :]
        tmp, out = self._buffers(x.shape)
        self._rows(pool, x.shape[0], lambda a, b: _stage.blur_beams(x, col, kb, norm_b, tmp, a, b))
        self._rows(pool, x.shape[0], lambda a, b: _stage.blur_range(tmp, self._kr, self._norm_r, out, a, b))
        return out

    def _beams_input(self, image: np.ndarray, column_offsets_deg: np.ndarray | None):
        """``(x, kb, column, norm_b)`` for the beam blur: the image and the model's own kernel, or
        a beam's columns of rays already weighed by the pattern (:meth:`fold_columns`), which
        then pass through the blur unchanged."""
        x = np.asarray(image)
        if x.ndim == 2:
            return np.ascontiguousarray(x, dtype=np.float32), self._kb, self.column_factor, self._norm_b
        if column_offsets_deg is None:
            raise ValueError("an image of a beam's columns of rays needs their column_offsets_deg")
        folded = self.fold_columns(x, column_offsets_deg)
        return folded, self._one, self._ones_b, self._ones_b

    def column_kernel(self, column_offsets_deg: np.ndarray) -> np.ndarray:
        """(2K + 1, S) kernel of :func:`~sonarsim.sensor.patterns.sub_ray_kernel` for a beam's S
        columns of rays at these offsets from its centre (degrees; cached); without an azimuth
        pattern, every column counts alike in its own beam only."""
        offsets = np.round(np.asarray(column_offsets_deg, dtype=float).reshape(-1), 12)
        key = tuple(offsets)
        k = self._sub_kernels.get(key)
        if k is None:
            if self.spec.azimuth_pattern is None:
                k = np.full((1, len(offsets)), 1.0 / len(offsets))
            else:
                k, _ = patterns.sub_ray_kernel(self.spec.azimuth_pattern, self._spacing_deg, self._default_width_deg,
                                               offsets, (len(self.beam_leakage) - 1) // 2)
            self._sub_kernels[key] = k
        return k

    def fold_columns(self, image: np.ndarray, column_offsets_deg: np.ndarray) -> np.ndarray:
        """A beam's S columns of rays through the azimuth pattern, each at its own angle.

        ``out[:, j] = n_j sum_{d, s} k[K + d, s] c_{j+d} x[:, j + d, s]`` with k the
        :meth:`column_kernel`, c the column factor and n_j the edge normalisation (an even
        image stays even). An even image gives what the one-column image does (the kernel
        averaged over the columns is the beam's leakage); a point target in one column is
        heard at the pattern's value at that column's angle, within the column's width.

        Parameters
        ----------
        image : (n_range_bins, n_beams, S) float array
            Each column's own image (the beam's image is their mean), ``l(r) = 1``.
        column_offsets_deg : (S,) float array
            Each column's angle from its beam's centre, degrees.

        Returns
        -------
        (n_range_bins, n_beams) float32 ndarray: the image after the pattern and the column factor.
        """
        x = np.asarray(image, dtype=np.float32)
        if x.ndim != 3 or x.shape[:2] != self.pool.shape or x.shape[2] != len(np.ravel(column_offsets_deg)):
            raise ValueError(f"columns of shape {x.shape}; this sensor's sonar forms {self.pool.shape} with "
                             f"{len(np.ravel(column_offsets_deg))} columns a beam")
        k = self.column_kernel(column_offsets_deg).astype(np.float32)
        h = (k.shape[0] - 1) // 2
        n_b = x.shape[1]
        pad = np.zeros((x.shape[0], n_b + 2 * h, x.shape[2]), np.float32)
        pad[:, h:h + n_b] = x * self.column_factor[None, :, None]
        out = np.zeros(x.shape[:2], np.float32)
        for d in range(k.shape[0]):  # a NumPy product over the frame per offset (2K + 1 of them)
            out += pad[:, d:d + n_b, :] @ k[d]
        return np.ascontiguousarray(out * _edge_norm(k.sum(axis=1), n_b).astype(np.float32)[None, :])

    def apply(self, image: np.ndarray, rng: np.random.Generator | None = None, speckle: bool = True,
              pool: Executor | None = None, noise_rng: np.random.Generator | None = None,
              warn_saturation: bool = False, column_offsets_deg: np.ndarray | None = None) -> np.ndarray:
        """The device's output for a range-compensated image.

        Parameters
        ----------
        image : (n_range_bins, n_beams) or (n_range_bins, n_beams, S) float array
            The renderer's total image with ``l(r) = 1``; or its S columns of rays per beam
            apart (each an image of its own column, their mean the beam's image), for the
            azimuth pattern to weigh each at its own angle (:meth:`fold_columns`).
        rng : numpy Generator, optional
            Chooses the speckle and noise fields of this frame (ignored with ``speckle=False``);
            default: frame 0 of the sensor's seed.
        speckle : bool
            ``False``: the expected output (no speckle or noise draws).
        pool : Executor, optional
            A worker thread: the rows are split between it and the caller.
        noise_rng : numpy Generator, optional
            Chooses the noise field instead of ``rng`` (the frame's, when the speckle is the pose's).
        column_offsets_deg : (S,) float array, optional
            With a 3-D ``image``: each column's angle from its beam's centre, degrees.
        warn_saturation : bool
            Warn (:class:`~sonarsim.sensor.output.SaturationWarning`, one line naming the
            fraction) when more than :data:`~sonarsim.sensor.output.SATURATION_WARN_FRACTION` of
            the output is at full scale; once per model (a sequence's first such frame), so that
            a dataset says it once. The renderer asks for it; a calibration's trial sensors
            (which saturate on the way to their fit) do not.

        Returns
        -------
        (n_range_bins, n_beams) float32 ndarray in device units (integers for integer data types).
        """
        out = self._apply(image, rng, speckle, pool, noise_rng, column_offsets_deg)
        if warn_saturation and not self._saturation_warned:
            self._saturation_warned = output.saturation_warning(out, self.spec.output) > \
                output.SATURATION_WARN_FRACTION
        return out

    def _apply(self, image: np.ndarray, rng: np.random.Generator | None, speckle: bool, pool: Executor | None,
               noise_rng: np.random.Generator | None, column_offsets_deg: np.ndarray | None = None) -> np.ndarray:
        x, kb, col, norm_b = self._beams_input(image, column_offsets_deg)
        if _stage is None:
            m = self._mean_reference(x, kb, col, norm_b)
            draws = None if not speckle else self.draws(rng or self._default_rng(), noise_rng)
            return self.combine_reference(m, draws, speckle)
        out = np.empty_like(x)
        if x.shape != self.pool.shape:
            raise ValueError(f"image of shape {x.shape}; this sensor's sonar forms {self.pool.shape}")
        ds, dn, common = (self.draws(rng if rng is not None else self._default_rng(), noise_rng) if speckle
                          else (None, None, None))
        if common is None:
            common_re = common_im = self._no_common
        else:
            common_re, common_im = common.real.astype(np.float32), common.imag.astype(np.float32)
        p = self.pool
        sf = p.speckle if p.speckle is not None else self._dummy
        nf = p.noise if p.noise is not None else self._dummy
        n_r = x.shape[0]
        t = self.expected_output
        args = (
            x, col, kb, norm_b, self._kr, self._norm_r,
            self.echo_gain, self.bang, self.bang_beam, self.tvg, self.beam_gain,
            self.noise_row if speckle else self.noise_expected, common_re, common_im,
            sf, ds.field if ds else 0, ds.row if ds else 0, ds.beam if ds else 0, p.speckle_scale,
            p.speckle is not None and speckle,
            nf, dn.field if dn else 0, dn.row if dn else 0, dn.beam if dn else 0, p.noise_scale,
            p.noise is not None and speckle,
            self._comp, self._lo_db, self._inv_span, self._inv_ceiling, self._gamma, self._fs, self._quantise,
            t.table, t.lo_db, t.step_db, not speckle, out,
        )
        self._rows(pool, n_r, lambda a, b: _stage.frame(*args, a, b))
        return out

    def _default_rng(self) -> np.random.Generator:
        """Without a generator: the first frame of the sensor's seed (reproducible)."""
        return streams.frame_rng(self.seed, 0)

    # NumPy twins (the reference the compiled loops are tested against) -------------------------

    def mean_image_reference(self, image: np.ndarray, column_offsets_deg: np.ndarray | None = None) -> np.ndarray:
        return self._mean_reference(*self._beams_input(image, column_offsets_deg))

    def _mean_reference(self, image: np.ndarray, kb: np.ndarray, column: np.ndarray, norm_b: np.ndarray) -> np.ndarray:
        x = np.asarray(image, dtype=np.float64) * column[None, :]
        kb, kr = np.asarray(kb, dtype=np.float64), self.range_spread
        hb, hr = len(kb) // 2, len(kr) // 2
        xb = np.pad(x, ((0, 0), (hb, hb)))
        t = sum(kb[m] * xb[:, m:m + x.shape[1]] for m in range(len(kb))) * norm_b[None, :]
        tr = np.pad(t, ((hr, hr), (0, 0)))
        out = sum(kr[m] * tr[m:m + x.shape[0], :] for m in range(len(kr))) * self._norm_r[:, None]
        return out.astype(np.float32)

    def fields(self, draws) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The (n_range_bins, n_beams) complex speckle and noise fields of a frame's draws."""
        ds, dn = draws[:2]
        f = None if self.pool.speckle is None else self.pool.window("speckle", ds)
        w = None if self.pool.noise is None else self.pool.window("noise", dn)
        return f, w

    def received_power(self, mean: np.ndarray, draws, speckle: bool = True) -> np.ndarray:
        """``P = t(r) G_j |sqrt(mu) F + sqrt(N) W + sqrt(C) z|^2`` (or ``t G (mu + N + C)``
        without draws), uPa^2; ``mu = g(r) M + bang(r) B_j``."""
        mu = (self.echo_gain[:, None].astype(np.float64) * mean
              + self.bang[:, None].astype(np.float64) * self.bang_beam[None, :])
        t = self.tvg[:, None].astype(np.float64) * self.beam_gain[None, :]
        if not speckle:
            return t * (mu + self.noise_expected[:, None])
        f, w = self.fields(draws)
        a = np.sqrt(np.maximum(mu, 0.0)) * (1.0 if f is None else f)
        if w is not None:
            a = a + np.sqrt(self.noise_row[:, None].astype(np.float64)) * w
            common = getattr(draws, "common", None)
            if common is not None:
                a = a + common[:, None]
        return t * np.abs(a) ** 2

    def combine_reference(self, mean: np.ndarray, draws, speckle: bool = True) -> np.ndarray:
        p = self.received_power(mean, draws, speckle)
        if not speckle:
            return self.expected_output(p)
        return output.compress(p, self.spec.output)

    def reference(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A frame formed without the pool: fresh scatterers filtered through the point-spreads.

        ``a_l = sqrt(T) PSF * (sqrt(g X') w_l) + sqrt(N) W_l`` with X' the image after the beam's
        column factor, w_l and W_l drawn afresh for each look l, T the K texture (1 otherwise),
        and ``P = t G sum_l v_l |a_l|^2`` with the looks' weights v_l
        (:func:`~sonarsim.sensor.speckle.look_weights`; slow; for tests and for scenes with sharp
        edges).
        """
        x = np.asarray(image, dtype=np.float64) * self.column_factor[None, :]
        mu = self.echo_gain[:, None] * x + self.bang[:, None] * self.bang_beam[None, :]
        spec = self.spec.speckle
        # Every look in full (scatterers, noise, the row's common noise), averaged in intensity
        # with the pool's weights; the K texture once per cell, common to the looks.
        texture = speckle_mod.texture(rng, x.shape, spec)
        weights = speckle_mod.look_weights(1.0 if spec is None else spec.looks)
        power = np.zeros(x.shape)
        for weight in weights:
            w = speckle_mod.scatterer_amplitudes(rng, x.shape) if spec else 1.0
            a = speckle_mod.filter_field(np.sqrt(mu) * w, self.range_amplitude, self.beam_amplitude, circular=False)
            if texture is not None:
                a = a * np.sqrt(texture)
            if self.spec.noise is not None:
                n = speckle_mod.filter_field(speckle_mod.complex_gaussian(rng, x.shape), self.range_amplitude,
                                             self.beam_amplitude, circular=False)
                a = a + np.sqrt(self.noise_row[:, None].astype(np.float64)) * n
                if self._has_common:
                    a = a + channels.common_noise_amplitude(self.common_power, self.range_amplitude, rng)[:, None]
            power += weight * np.abs(a) ** 2
        p = (self.tvg[:, None] * self.beam_gain[None, :]).astype(np.float64) * power
        return output.compress(p, self.spec.output)

    # Helpers ------------------------------------------------------------------------------------

    def _buffers(self, shape) -> tuple[np.ndarray, np.ndarray]:
        if self._work is None or self._work[0].shape != shape:
            self._work = (np.empty(shape, np.float32), np.empty(shape, np.float32))
        return self._work[0], np.empty(shape, np.float32)

    @staticmethod
    def _rows(pool: Executor | None, n: int, fn) -> None:
        """Run ``fn(r0, r1)`` over all rows: half on the pool's worker, half here."""
        if pool is None or n < 64:
            fn(0, n)
            return
        half = n // 2
        future = pool.submit(fn, half, n)
        fn(0, half)
        future.result()
