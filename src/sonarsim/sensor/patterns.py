"""Beam patterns of line arrays (and Gaussian or measured ones), as power gains.

A line array of length L with aperture weighting ``w(x)``, ``x`` in [-1/2, 1/2], has the
one-way amplitude response ``A(u) = sum w(x) exp(2 pi i u x) / sum w(x)`` at
``u = (L / lambda) sin(theta)``; uniform weighting (``rect``) gives ``sinc(u)``: -3 dB at
``u = 0.443``, first sidelobe -13.3 dB. Windows lower the sidelobes and widen the main lobe.
Instead of L / lambda, the pattern is specified by its -3 dB full width as it acts: two-way
(transmit x receive, the same aperture) in elevation, one-way (receive) in azimuth.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..config.sensor import MAX_KERNEL_HALF_WIDTH, PatternSpec
from ..errors import ConfigError, SonarsimError, check_input_file

APERTURE_SAMPLES = 512  # midpoint samples of the aperture weighting: far more than any sidelobe needs
LEAKAGE_WIDTHS = 8.0  # default reach of the azimuth leakage, in -3 dB beam widths, at most
LEAKAGE_FLOOR = 1e-4  # ... and no farther than its power stays above this fraction of the peak (-40 dB)

# Weightings as functions of the position x in [-1/2, 1/2] along the aperture.
_COSINE_WINDOWS = {"rect": (1.0,), "hann": (0.5, 0.5), "hamming": (0.54, 0.46), "blackman": (0.42, 0.5, 0.08)}


def aperture_positions() -> np.ndarray:
    """(APERTURE_SAMPLES,) midpoints of equal cells of the unit aperture: its length is exactly 1."""
    n = APERTURE_SAMPLES
    return (np.arange(n) + 0.5) / n - 0.5


@functools.lru_cache(maxsize=32)
def aperture_weights(window: str, sidelobe_db: float | None = None) -> np.ndarray:
    """(APERTURE_SAMPLES,) weighting of the aperture at :func:`aperture_positions`, peak about 1."""
    x = aperture_positions()
    if window == "taylor":
        from scipy import signal  # here, not at import: SciPy's signal module takes half a second

        return np.asarray(signal.windows.taylor(len(x), nbar=5, sll=float(sidelobe_db), norm=True, sym=True), float)
    coeffs = _COSINE_WINDOWS[window]
    return sum(c * np.cos(2.0 * np.pi * k * x) for k, c in enumerate(coeffs))


def array_amplitude(u: np.ndarray, window: str = "rect", sidelobe_db: float | None = None) -> np.ndarray:
    """One-way amplitude response ``A(u)`` (real: the weighting is symmetric), ``A(0) = 1``.

    Parameters
    ----------
    u : (...) array
        ``(L / lambda) sin(theta)``.
    """
    w = aperture_weights(window, sidelobe_db)
    x = aperture_positions()
    u = np.asarray(u, dtype=float)
    out = np.cos(2.0 * np.pi * u.reshape(-1, 1) * x[None, :]) @ w / w.sum()
    return out.reshape(u.shape)


@functools.lru_cache(maxsize=32)
def half_power_u(window: str, sidelobe_db: float | None, ways: int) -> float:
    """u at which the ``ways``-way power ``A(u)^(2 ways)`` falls to one half."""
    f = lambda u: float(array_amplitude(np.array([u]), window, sidelobe_db)[0]) ** (2 * ways) - 0.5
    from scipy import optimize

    return float(optimize.brentq(f, 1e-6, 2.0))


def _read_table(path: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        # Checked when the scene is read; again here for a PatternSpec built in Python (a pipe
        # given as the table would block this read forever).
        check_input_file(path, "pattern table")
    except SonarsimError as exc:
        raise ConfigError("sensor pattern table", str(exc)) from None
    try:
        # utf-8-sig: a table saved with a byte-order mark failed on '\ufeff0.5' in its first cell.
        rows = np.loadtxt(path, delimiter=",", comments="#", ndmin=2, encoding="utf-8-sig")
    except OSError as exc:
        raise ConfigError("sensor pattern table", f"cannot read the pattern table {path!r}: {exc.strerror or exc}") from None
    except ValueError as exc:
        raise ConfigError("sensor pattern table", f"{path!r} must hold rows 'angle_deg, gain_db' of numbers: {exc}") from None
    if rows.shape[1] != 2 or len(rows) < 2 or not np.isfinite(rows).all():
        raise ConfigError("sensor pattern table", f"{path!r} must hold at least two rows 'angle_deg, gain_db' of finite numbers")
    order = np.argsort(rows[:, 0])
    angle, gain = rows[order, 0], rows[order, 1]
    if np.any(np.diff(angle) <= 0):
        raise ConfigError("sensor pattern table", f"{path!r}: angles must be distinct")
    return angle, gain


def pattern_gain(angle_rad: np.ndarray, spec: PatternSpec, default_width_deg: float, ways: int) -> np.ndarray:
    """Power gain (1 on axis) of a pattern at angles off its axis, as the pattern acts.

    Parameters
    ----------
    angle_rad : (...) array
        Angles from the beam axis, radians.
    spec : PatternSpec
    default_width_deg : float
        -3 dB full width when ``spec.width_deg`` is not given.
    ways : {1, 2}
        2: transmit x receive through the same aperture (elevation); 1: receive only.

    Returns
    -------
    (...) float64 ndarray in [0, 1]: ``|A(u)|^(2 ways)``; -3 dB at half the width.
    """
    a = np.asarray(angle_rad, dtype=float)
    width = math.radians(spec.width_deg if spec.width_deg is not None else default_width_deg)
    if spec.shape == "gaussian":
        gain = np.exp(-math.log(2.0) * (2.0 * a / width) ** 2)
    elif spec.shape == "table":
        angle, gain_db = _read_table(spec.table)
        # Outside the table: its last value (a measured pattern's far sidelobe level).
        gain = 10.0 ** (np.interp(np.degrees(a), angle, gain_db) / 10.0)
    else:
        u3 = half_power_u(spec.window, spec.sidelobe_db, ways)
        scale = u3 / math.sin(width / 2.0)  # L / lambda
        amp = array_amplitude(scale * np.sin(a), spec.window, spec.sidelobe_db)
        gain = amp ** (2 * ways)
    if spec.correction_db is not None:
        gain = gain * correction_gain(a, spec, math.degrees(width))
    return gain


def correction_knots_deg(spec: PatternSpec, width_deg: float) -> np.ndarray:
    """Angles (degrees) of a pattern's ``correction_db`` values: evenly over its span (default
    three -3 dB widths), from ``-span / 2`` to ``+span / 2``."""
    span = spec.span_deg if spec.span_deg is not None else min(3.0 * width_deg, 170.0)
    return np.linspace(-span / 2.0, span / 2.0, len(spec.correction_db))


def correction_gain(angle_rad: np.ndarray, spec: PatternSpec, width_deg: float) -> np.ndarray:
    """The power factor of ``spec.correction_db`` at angles off the axis: its values as powers,
    interpolated linearly between the knots (:func:`correction_knots_deg`), the end values
    beyond them. Linear in each value's power, so that a calibration can form the image of any
    correction from the images of one knot each."""
    knots = correction_knots_deg(spec, width_deg)
    return np.interp(np.degrees(np.asarray(angle_rad, dtype=float)), knots,
                     10.0 ** (np.asarray(spec.correction_db, dtype=float) / 10.0))


def azimuth_kernels(spec: PatternSpec, beam_spacing_deg: float, default_width_deg: float,
                    oversample: int = 16) -> tuple[np.ndarray, np.ndarray, float]:
    """Across-beam kernels of the receive azimuth pattern, on beams ``-K..K`` (K = leakage_beams).

    Returns
    -------
    leakage : (2K + 1,) float64 ndarray, sums to 1
        Power leaking from an echo in beam j into beam j + m: the pattern averaged over the
        beam's cell, one beam spacing wide about its centre (where inside it the echo lies is
        not known when each beam has one column of rays).
    amplitude : (2K + 1,) float64 ndarray, squares sum to 1
        The pattern's amplitude at beam offsets m: the filter that gives white scatterer
        amplitudes the correlation across beams of the beamformer's output.
    gain : float
        The leakage before it was normalised, summed: the pattern's equivalent width in beam
        spacings (``int g dtheta / spacing``). A beam hears ``gain`` spacings of an even floor
        (the sonar equation's equivalent beam width), and a point target on its axis at the
        pattern's peak (:class:`~sonarsim.sensor.model.SensorModel`'s column factor).

    The pattern must be at least an eighth of the beam spacing wide
    (:func:`sonarsim.config.sensor.check_azimuth_width`, checked when the scene is built and
    by :class:`~sonarsim.sensor.model.SensorModel`): narrower, its sidelobes alias.
    """
    width = spec.width_deg if spec.width_deg is not None else default_width_deg
    k = spec.leakage_beams
    if k is None:
        k = min(max(int(math.ceil(LEAKAGE_WIDTHS * width / beam_spacing_deg)), 1), MAX_KERNEL_HALF_WIDTH)
    m = np.arange(-k, k + 1, dtype=float)
    leakage = _cell_gain(m * beam_spacing_deg, spec, default_width_deg, beam_spacing_deg, oversample)
    if spec.leakage_beams is None:
        # Beyond where every beam's leakage is below LEAKAGE_FLOOR of the main beam, stop:
        # a window's fast-falling sidelobes need fewer beams than a uniform array's.
        strong = np.flatnonzero(leakage > LEAKAGE_FLOOR * leakage.max())
        reach = int(np.abs(m[strong]).max())
        keep = slice(k - reach, k + reach + 1)
        leakage, m = leakage[keep], m[keep]
    gain = float(leakage.sum())
    leakage = leakage / gain
    amp = np.sqrt(pattern_gain(np.radians(m * beam_spacing_deg), spec, default_width_deg, ways=1))
    if spec.shape == "line":  # keep the sign of the sidelobes (the amplitude is real and symmetric)
        amp = _signed_line_amplitude(np.radians(m * beam_spacing_deg), spec, default_width_deg)
    amp = amp / np.sqrt(np.sum(amp * amp))
    return leakage, amp, gain


def sub_ray_kernel(spec: PatternSpec, beam_spacing_deg: float, default_width_deg: float,
                   ray_offsets_deg: np.ndarray, half_width: int, oversample: int = 16) -> tuple[np.ndarray, float]:
    """The azimuth pattern at each of a beam's columns of rays (``render.azimuth_samples``).

    With S columns of rays per beam the image knows where inside a beam an echo came from;
    the pattern then weighs each column at its own angle, so that a point target on a beam's
    axis is heard at the pattern's peak and its response across azimuth has the pattern's
    width (both to within the columns' spacing, ``spacing / S``).

    Parameters
    ----------
    spec : PatternSpec
    beam_spacing_deg, default_width_deg : float
    ray_offsets_deg : (S,) float array
        Each column's angle from its beam's centre (:func:`sonarsim.core.rays.make_ray_fan`:
        ``(s + 1/2) / S - 1/2`` of the beam's width), degrees.
    half_width : int
        K: the kernel covers beams ``-K..K`` (that of :func:`azimuth_kernels`).

    Returns
    -------
    kernel : (2K + 1, S) float64 ndarray, sums to 1
        ``kernel[K + d, s]``: the power beam j hears of column s of beam ``j + d``, the pattern
        at ``theta_{j+d} + offset_s - theta_j = offset_s - d spacing`` averaged over the
        column's cell (``spacing / S`` wide), divided by ``S`` times ``gain``.
    gain : float
        The unnormalised kernel's sum over offsets, averaged over the columns: the equivalent
        width in beam spacings, as :func:`azimuth_kernels`'s.

    Where the columns tile the beam (``beam_width_deg`` the spacing, or unset) the kernel
    summed over the columns is the beam's leakage; where the beams are wider than their spacing
    the columns lie farther apart than their cells, and a point target's response is a little
    less smoothed than the one-column kernel (an even image reads the same either way).
    """
    offsets = np.asarray(ray_offsets_deg, dtype=float).reshape(-1)
    n_sub = len(offsets)
    d = np.arange(-half_width, half_width + 1, dtype=float)
    angle = offsets[None, :] - d[:, None] * beam_spacing_deg  # (2K + 1, S)
    k = _cell_gain(angle.reshape(-1), spec, default_width_deg, beam_spacing_deg / n_sub, oversample)
    k = k.reshape(angle.shape)
    gain = float(k.sum() / n_sub)
    return k / (gain * n_sub), gain


def _cell_gain(angle_deg: np.ndarray, spec: PatternSpec, default_width_deg: float, cell_deg: float,
               oversample: int) -> np.ndarray:
    """The one-way pattern averaged over a cell ``cell_deg`` wide about each angle (midpoints)."""
    sub = (np.arange(oversample) + 0.5) / oversample - 0.5
    offsets = np.radians(np.asarray(angle_deg, dtype=float)[:, None] + sub[None, :] * cell_deg)
    return pattern_gain(offsets, spec, default_width_deg, ways=1).mean(axis=1)


def _signed_line_amplitude(a: np.ndarray, spec: PatternSpec, default_width_deg: float) -> np.ndarray:
    width = math.radians(spec.width_deg if spec.width_deg is not None else default_width_deg)
    scale = half_power_u(spec.window, spec.sidelobe_db, 1) / math.sin(width / 2.0)
    return array_amplitude(scale * np.sin(a), spec.window, spec.sidelobe_db)
