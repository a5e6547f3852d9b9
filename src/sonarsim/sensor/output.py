"""The device's output chain: compression, saturation, quantisation; and its expected value.

A received power P (uPa^2, after TVG and gain) becomes a device value: ``log`` maps the level
``10 log10 P`` linearly between ``floor_db`` and ``ceiling_db``; ``gamma`` maps
``(P / P_ceiling) ** gamma``; ``linear`` maps ``P / P_ceiling``; then values are clipped to
``[0, full scale]`` (saturation) and rounded (integer data types). An output with more than
:data:`SATURATION_WARN_FRACTION` of its pixels at full scale is warned about
(:func:`saturation_warning`): those pixels say only "at least this loud".

The expected output of a pixel whose mean power is mu is ``E[out(mu S)]`` with S the speckle's
unit-mean intensity law: it is a function of mu alone, tabulated once per sensor
(:class:`ExpectedOutput`) so that ``render(..., speckle=False)`` costs a table look-up per pixel.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from ..config.sensor import OutputSpec

# Levels of the expected-output table: every 0.05 dB over the compressed window, widened.
TABLE_STEP_DB = 0.05
TABLE_MARGIN_DB = 60.0
MAX_TABLE_LEVELS = 8192
# Quantiles of the speckle intensity averaged over (midpoints of equal-probability slices).
QUANTILES = 4096
# More than this fraction of an output's pixels at the device's maximum is warned about. A device
# set up well clips at most a strong target's peak or the transmit bang's first bins (the
# project's ARIS and Oculus recordings hold no pixel at 255: their maxima are 181-202 and 254);
# beyond 1 % a gain or ceiling is off and a whole structure (a floor band, an object) is clipped flat.
SATURATION_WARN_FRACTION = 0.01


class SaturationWarning(UserWarning):
    """A sensor's output holds more than :data:`SATURATION_WARN_FRACTION` of its pixels at full scale."""


def saturated_fraction(values: np.ndarray, spec: OutputSpec | None) -> float:
    """The fraction of device values at the output's full scale (0 without an output chain).

    Parameters
    ----------
    values : (...) float array
        Device values (:func:`compress`, or their expectation).
    spec : OutputSpec or None

    Returns
    -------
    float
        In [0, 1]; 0 for an empty array or without ``spec`` (a power saturates nowhere).
    """
    v = np.asarray(values)
    if spec is None or v.size == 0:
        return 0.0
    return float(np.count_nonzero(v >= spec.full_scale)) / v.size


def saturation_warning(values: np.ndarray, spec: OutputSpec | None) -> float:
    """Warn (:class:`SaturationWarning`, one line) when more than :data:`SATURATION_WARN_FRACTION`
    of the values are at full scale; returns the fraction.

    Parameters
    ----------
    values : (...) float array
        Device values.
    spec : OutputSpec or None

    Returns
    -------
    float
        The saturated fraction (:func:`saturated_fraction`).
    """
    fraction = saturated_fraction(values, spec)
    if fraction > SATURATION_WARN_FRACTION:
        top = f"{spec.full_scale:g}" if spec.dtype != "float32" else "1.0 (float32 full scale)"
        warnings.warn(
            f"the sensor output saturates: {100 * fraction:.1f} % of its pixels are at the device's maximum "
            f"({top}; more than {100 * SATURATION_WARN_FRACTION:g} % is warned about): lower sensor.gain_db or "
            f"sensor.source_level_db, or raise sensor.output.ceiling_db",
            SaturationWarning, stacklevel=3)
    return fraction


def compress(power: np.ndarray, spec: OutputSpec | None) -> np.ndarray:
    """Device values of received powers (NumPy reference of the compiled kernel).

    Parameters
    ----------
    power : (...) array, uPa^2
    spec : OutputSpec or None
        ``None``: the power itself (float32).

    Returns
    -------
    (...) float32 ndarray
    """
    p = np.asarray(power, dtype=np.float64)
    if spec is None:
        return p.astype(np.float32)
    fs = spec.full_scale
    if spec.compression == "log":
        level = 10.0 * np.log10(np.maximum(p, 1e-30))
        v = (level - spec.floor_db) / (spec.ceiling_db - spec.floor_db) * fs
    elif spec.compression == "gamma":
        v = fs * (np.maximum(p, 0.0) / 10.0 ** (spec.ceiling_db / 10.0)) ** spec.gamma
    else:
        v = fs * p / 10.0 ** (spec.ceiling_db / 10.0)
    v = np.clip(v, 0.0, fs)
    if spec.dtype != "float32":
        v = np.floor(v + 0.5)
    return v.astype(np.float32)


def level_window_db(spec: OutputSpec | None) -> tuple[float, float]:
    """Levels (dB re 1 uPa^2) between which the output changes, widened by the table margin."""
    if spec is None:
        return -100.0, 300.0
    if spec.compression == "log":
        lo, hi = spec.floor_db, spec.ceiling_db
    else:
        # Below the level that maps to half a quantisation step (or 1e-6 of full scale) the output is 0.
        fs = spec.full_scale
        step = 0.5 / fs if spec.dtype != "float32" else 1e-6
        lo = spec.ceiling_db + 10.0 * np.log10(step) / (spec.gamma if spec.compression == "gamma" else 1.0)
        hi = spec.ceiling_db
    return float(lo) - TABLE_MARGIN_DB, float(hi) + TABLE_MARGIN_DB


class ExpectedOutput:
    """``E[out(mu S)]`` tabulated over the level ``10 log10 mu`` (dB re 1 uPa^2).

    Parameters
    ----------
    spec : OutputSpec or None
    speckle_quantiles : (QUANTILES,) array or None
        Sorted samples of the unit-mean speckle intensity S at equal-probability midpoints;
        ``None``: S = 1 (no speckle: the output of the mean power).
    """

    def __init__(self, spec: OutputSpec | None, speckle_quantiles: np.ndarray | None) -> None:
        self.lo_db, hi = level_window_db(spec)
        # Bounded size: coarser steps for very wide windows (the table is smooth in the level).
        self.step_db = max(TABLE_STEP_DB, (hi - self.lo_db) / MAX_TABLE_LEVELS)
        n = int(np.ceil((hi - self.lo_db) / self.step_db)) + 1
        levels = self.lo_db + np.arange(n) * self.step_db
        mu = 10.0 ** (levels / 10.0)
        s = np.ones(1) if speckle_quantiles is None else np.asarray(speckle_quantiles, dtype=float)
        table = np.empty(n)
        for start in range(0, n, 256):  # bounded temporaries
            chunk = mu[start:start + 256, None] * s[None, :]
            table[start:start + 256] = compress(chunk, spec).astype(np.float64).mean(axis=1)
        self.table = table.astype(np.float32)

    def __call__(self, mean_power: np.ndarray) -> np.ndarray:
        """Expected device values of pixels with these mean powers (uPa^2)."""
        level = 10.0 * np.log10(np.maximum(np.asarray(mean_power, dtype=np.float64), 1e-30))
        x = (level - self.lo_db) / self.step_db
        return np.interp(x, np.arange(len(self.table)), self.table).astype(np.float32)


@functools.lru_cache(maxsize=16)
def expected_output(spec: OutputSpec | None, speckled: bool) -> ExpectedOutput:
    """The (cached) table of an output chain for fully developed speckle (or none)."""
    return ExpectedOutput(spec, exponential_quantiles() if speckled else None)


def exponential_quantiles(n: int = QUANTILES) -> np.ndarray:
    """Midpoint quantiles of the unit-mean exponential law (fully developed speckle intensity)."""
    u = (np.arange(n) + 0.5) / n
    q = -np.log1p(-u)
    return q / q.mean()


#: Samples (and their generator's seed) of the intensity laws that have no closed-form quantiles.
LAW_SAMPLES = 2 ** 18
LAW_SEED = 20261202


@functools.lru_cache(maxsize=64)
def intensity_quantiles(model: str, k_shape: float, looks: float, n: int = QUANTILES) -> np.ndarray:
    """Midpoint quantiles of the unit-mean speckle intensity a device records (cached).

    The marginal law of one cell does not depend on the point-spread (a filtered circular complex
    Gaussian field is complex Gaussian in every cell), so it is a function of the speckle spec
    alone: ``S = T sum_l w_l E_l`` with E_l unit exponentials over the looks' weights
    (:func:`~sonarsim.sensor.speckle.look_weights`) and T the K model's gamma texture (1 for
    Rayleigh). One Rayleigh look: the exponential law; a whole number L of looks: the gamma law
    of shape L (both exact); otherwise :data:`LAW_SAMPLES` seeded samples.

    Parameters
    ----------
    model : {'rayleigh', 'k'}
    k_shape : float
        The K texture's shape (ignored for Rayleigh).
    looks : float
        >= 1.
    n : int

    Returns
    -------
    (n,) float64 ndarray, sorted, mean 1.
    """
    from scipy import stats

    from .speckle import look_weights

    u = (np.arange(n) + 0.5) / n
    weights = look_weights(looks)
    if model == "rayleigh" and len(weights) == 1:
        return exponential_quantiles(n)
    if model == "rayleigh" and np.allclose(weights, weights[0]):
        q = stats.gamma(len(weights), scale=1.0 / len(weights)).ppf(u)
        return q / q.mean()
    rng = np.random.default_rng(LAW_SEED)
    s = np.zeros(LAW_SAMPLES)
    for w in weights:
        s += w * rng.exponential(size=LAW_SAMPLES)
    if model == "k":
        s *= rng.gamma(k_shape, 1.0 / k_shape, size=LAW_SAMPLES)
    return empirical_quantiles(s, n)


def empirical_quantiles(samples: np.ndarray, n: int = QUANTILES) -> np.ndarray:
    """Midpoint quantiles of samples, rescaled to unit mean."""
    s = np.sort(np.asarray(samples, dtype=float).ravel())
    q = s[((np.arange(n) + 0.5) / n * len(s)).astype(int)]
    return q / q.mean()
