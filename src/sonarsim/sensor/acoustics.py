"""The sonar equation's range terms: absorption of sound in water, spreading, TVG.

Levels are in dB; ``r`` in metres. One way, the transmission loss is
``TL(r) = 20 log10(r) + alpha r`` (spherical spreading and absorption, alpha in dB/m).
"""

from __future__ import annotations

import numpy as np

from ..config.sensor import AbsorptionSpec, TvgSpec

# Ranges below this are clamped in log10(r): spreading is undefined at the transducer face.
MIN_RANGE_M = 1e-3


def francois_garrison_db_per_km(frequency_khz, temperature_c: float = 10.0, salinity_psu: float = 35.0,
                                depth_m: float = 0.0, ph: float = 8.0, sound_speed_m_s: float | None = None):
    """Absorption of sound in sea water after Francois & Garrison (1982), dB/km.

    Sum of the boric-acid and magnesium-sulphate relaxations and the viscosity of pure water
    (JASA 72(3) 896-907 and 72(6) 1879-1890), valid from 200 Hz to 1 MHz (and used above it,
    where pure water dominates), -2 to 22 degC (the pure-water term has a second form above 20).

    Parameters
    ----------
    frequency_khz : float or array, kHz
    temperature_c, salinity_psu, depth_m, ph : float
    sound_speed_m_s : float, optional
        Default: the paper's ``1412 + 3.21 T + 1.19 S + 0.0167 z``.

    Returns
    -------
    float or ndarray: alpha, dB/km.
    """
    f = np.asarray(frequency_khz, dtype=float)
    t, s, z = float(temperature_c), float(salinity_psu), float(depth_m)
    c = 1412.0 + 3.21 * t + 1.19 * s + 0.0167 * z if sound_speed_m_s is None else float(sound_speed_m_s)
    tk = t + 273.0
    f2 = f * f
    # Boric acid.
    a1 = 8.86 / c * 10.0 ** (0.78 * ph - 5.0)
    f1 = 2.8 * np.sqrt(s / 35.0) * 10.0 ** (4.0 - 1245.0 / tk)
    boric = a1 * f1 * f2 / (f1 * f1 + f2) if f1 > 0 else np.zeros_like(f)
    # Magnesium sulphate.
    a2 = 21.44 * s / c * (1.0 + 0.025 * t)
    p2 = 1.0 - 1.37e-4 * z + 6.2e-9 * z * z
    fm = 8.17 * 10.0 ** (8.0 - 1990.0 / tk) / (1.0 + 0.0018 * (s - 35.0))
    mgso4 = a2 * p2 * fm * f2 / (fm * fm + f2)
    # Pure water.
    p3 = 1.0 - 3.83e-5 * z + 4.9e-10 * z * z
    if t <= 20.0:
        a3 = 4.937e-4 - 2.59e-5 * t + 9.11e-7 * t ** 2 - 1.50e-8 * t ** 3
    else:
        a3 = 3.964e-4 - 1.146e-5 * t + 1.45e-7 * t ** 2 - 6.5e-10 * t ** 3
    water = a3 * p3 * f2
    out = boric + mgso4 + water
    return float(out) if out.ndim == 0 else out


def ainslie_mccolm_db_per_km(frequency_khz, temperature_c: float = 10.0, salinity_psu: float = 35.0,
                             depth_m: float = 0.0, ph: float = 8.0):
    """Absorption of sound in sea water after Ainslie & McColm (1998, JASA 103(3) 1671-1672), dB/km.

    A simplified formula fitted to Francois & Garrison; within about 10 % of it over
    100 Hz to 1 MHz.
    """
    f = np.asarray(frequency_khz, dtype=float)
    t, s, zk = float(temperature_c), float(salinity_psu), float(depth_m) / 1000.0
    f1 = 0.78 * np.sqrt(s / 35.0) * np.exp(t / 26.0)
    f2 = 42.0 * np.exp(t / 17.0)
    f_sq = f * f
    boric = 0.106 * f1 * f_sq / (f1 * f1 + f_sq) * np.exp((ph - 8.0) / 0.56)
    mgso4 = 0.52 * (1.0 + t / 43.0) * (s / 35.0) * f2 * f_sq / (f2 * f2 + f_sq) * np.exp(-zk / 6.0)
    water = 0.00049 * f_sq * np.exp(-(t / 27.0 + zk / 17.0))
    out = boric + mgso4 + water
    return float(out) if out.ndim == 0 else out


def absorption_db_per_m(spec: AbsorptionSpec | None, frequency_khz: float | None,
                        sound_speed_m_s: float | None = None) -> float:
    """alpha (dB/m, one way) of an absorption spec at the sonar's frequency; 0 when off."""
    if spec is None:
        return 0.0
    if spec.model == "constant":
        return float(spec.db_per_m)
    if frequency_khz is None:
        from ..errors import ConfigError

        raise ConfigError("sensor.absorption", f"model {spec.model!r} needs the frequency: set sonar.frequency_khz "
                          "or sensor.frequency_khz")
    args = (frequency_khz, spec.temperature_c, spec.salinity_psu, spec.depth_m, spec.ph)
    if spec.model == "francois-garrison":
        return francois_garrison_db_per_km(*args, sound_speed_m_s=sound_speed_m_s) / 1000.0
    return ainslie_mccolm_db_per_km(*args) / 1000.0


def _log_range(range_m: np.ndarray) -> np.ndarray:
    return np.log10(np.maximum(np.asarray(range_m, dtype=float), MIN_RANGE_M))


def echo_level_offset_db(range_m: np.ndarray, source_level_db: float, alpha_db_per_m: float,
                         target_strength_db: float = 0.0) -> np.ndarray:
    """What the sonar equation adds, per range, to ``10 log10`` of the rendered backscatter.

    The renderer's range-compensated image X is ``sigma / r^2`` summed over a bin (a surface
    element's backscattering cross-section over the square of its range: the solid angle it
    fills), so its target strength is ``TS = 10 log10 X + 20 log10 r``, and the echo level
    ``EL = SL - 2 TL + TS = SL - 20 log10 r - 2 alpha r + 10 log10 X``.

    Returns
    -------
    (n,) float64 ndarray, dB: ``SL + TS_offset - 20 log10 r - 2 alpha r``.
    """
    r = np.asarray(range_m, dtype=float)
    return source_level_db + target_strength_db - 20.0 * _log_range(r) - 2.0 * alpha_db_per_m * r


def tvg_db(range_m: np.ndarray, spec: TvgSpec | None, alpha_db_per_m: float) -> np.ndarray:
    """The TVG added at each range, dB: ``spreading log10 r + 2 alpha r`` (0 when off), plus
    ``correction_db`` (:class:`~sonarsim.config.sensor.TvgSpec`) where it is given."""
    r = np.asarray(range_m, dtype=float)
    if spec is None:
        return np.zeros_like(r)
    out = spec.spreading * _log_range(r)
    if spec.absorption:
        out = out + 2.0 * alpha_db_per_m * r
    if spec.correction_db is not None:
        out = out + 10.0 * np.log10(tvg_correction_gain(r, spec))
    return out


def tvg_correction_gain(range_m: np.ndarray, spec: TvgSpec) -> np.ndarray:
    """The power factor of ``spec.correction_db`` at each range: the knots' values as powers,
    interpolated linearly between the knots (evenly over ``correction_range_m``), the end values
    beyond them. Linear in each knot's power, as the elevation pattern's correction is."""
    knots = np.linspace(spec.correction_range_m[0], spec.correction_range_m[1], len(spec.correction_db))
    return np.interp(np.asarray(range_m, dtype=float), knots, 10.0 ** (np.asarray(spec.correction_db) / 10.0))
