"""Sea beds by sediment: the backscattering cross-section of a fluid sediment half-space with a
rough, power-law interface and scatterers in its volume, after the APL-UW high-frequency model.

The model (all angles grazing, ``theta`` from the mean interface; cross-sections per unit area
and unit solid angle, dimensionless; ``10 log10`` of them is the backscattering strength):

Geoacoustic parameters by mean grain size ``Mz`` (phi units, ``-log2`` of the diameter in mm)
    The regressions of the APL-UW handbook [APL94, Sect. IV, Table IV-2 and its regression
    formulas]: the density ratio ``rho`` and sound-speed ratio ``nu`` (sediment over water), the
    attenuation ``k_p`` (dB / m / kHz, linear in frequency) giving the loss parameter
    ``delta = k_p nu c_w ln(10) / (40 pi 1000)`` (imaginary over real wavenumber), the
    spectral strength ``w2`` (cm^4) of the roughness spectrum ``W(K) = w2 / (h0 K)^gamma``
    (``h0`` = 1 cm, ``gamma`` = 3.25, two-dimensional, isotropic) and the volume parameter
    ``sigma2`` (the volume scattering coefficient over the sediment's attenuation in dB/m).
    The regressions hold for ``-1 <= Mz <= 9`` (sandy gravel to clay); rock and cobble take the
    handbook's density and speed ratios (2.5 and 2.5, 2.5 and 1.8) with the regressions' values
    at ``Mz = -1`` for the rest (our choice, said in :data:`ROCKS`).
The Rayleigh reflection coefficient
    ``V(theta) = (rho sin(theta) - P) / (rho sin(theta) + P)``, ``P = sqrt(kappa^2 - cos^2(theta))``
    (``Im P >= 0``), ``kappa = (1 + i delta) / nu``: the plane-wave coefficient of a lossy
    fluid half-space [Brekhovskikh & Lysanov, *Fundamentals of Ocean Acoustics*, Ch. 4]. Above
    the critical angle ``theta_c = arccos(1 / nu)`` (``nu > 1``) energy enters the sediment;
    below it, without loss, ``|V| = 1``.
Interface roughness: the small-slope approximation, lowest order
    ``sigma_r = |Y(theta)|^2 sin^2(theta) I(q) / (8 pi cos^2(theta))`` with
    ``I(q) = int_0^inf exp(-q u^(2 alpha)) J0(u) u du``,
    ``q = C_h^2 2^(1 - 2 alpha) k^(2 - 2 alpha) sin^2(theta) / cos^(2 alpha)(theta)``,
    ``alpha = gamma / 2 - 1`` and the structure constant of the spectrum
    ``C_h^2 = 2 pi w2 h0^-gamma Gamma(1 - alpha) 2^(-2 alpha) / (alpha Gamma(1 + alpha))``
    (the structure function ``D(r) = C_h^2 r^(2 alpha)``), ``Y`` the first-order perturbation
    kernel ``Y = ((rho - 1)^2 cos^2 + rho^2 - kappa^2) / (rho sin + P)^2``
    [JR07, Sect. 13.2; Jackson, Winebrenner & Ishimaru 1986]. It is the first-order perturbation
    result ``4 k^4 sin^4 |Y|^2 W(2 k cos)`` where the roughness is small against the wavelength
    and the Kirchhoff result ``|V(90)|^2 I(q) / (8 pi sin^2 cos^2)`` near normal incidence
    (``Y(90) = V(90)``), so that no interpolation between the two is needed: the handbook
    blends a Kirchhoff and a composite-roughness term instead (its ``f(x)`` switch), which we do
    not reproduce; the curves agree with its two limits (tests/core/test_seabed.py).
Volume scattering
    ``sigma_v = 5 delta sigma2 |1 - V^2|^2 sin^2(theta) / (nu ln(10) |P|^2 Im P)``: scatterers of
    cross-section ``sigma2`` times the attenuation (dB/m) per unit volume, the field entering
    and leaving through the interface (``1 - V^2`` for the two crossings) and decaying with
    depth as ``exp(-4 k Im(P) z)`` [APL94, Sect. IV; JR07, Sect. 14.1].
The total: ``sigma_b = sigma_r + sigma_v``.

Frequency enters through ``k = 2 pi f / c_w`` in the roughness term (the attenuation is linear in
frequency, so ``delta`` and the volume term are not). The handbook's model was built on and
checked against data from 10 to 100 kHz (:data:`MODEL_RANGE_HZ`); above 100 kHz (every
forward-looking sonar, most side-scans) it is extrapolated: the sediment's loss is held linear
in frequency, the roughness spectrum's power law held down to millimetre scales, and the
volume term (dominant on soft beds at moderate angles) held constant -- measured sea beds at
300 kHz - 1 MHz fall within a few dB of such extrapolations [JR07, Ch. 14] but no sea bed here
was fitted there. Nothing warns at run time; :func:`model_range` says it.

Not modelled: shadowing of the interface by its own large-scale slopes (low grazing angles),
layering, shear (rock is treated as a fast fluid), gas, and anisotropic roughness.

[APL94] Applied Physics Laboratory, University of Washington, *APL-UW High-Frequency Ocean
Environmental Acoustic Models Handbook*, APL-UW TR 9407 (1994).
[JR07] D. R. Jackson and M. D. Richardson, *High-Frequency Seafloor Acoustics* (Springer, 2007).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy import integrate, special

from ..errors import ConfigError
from .reflection import rayleigh_fluid

#: The spectral exponent of the roughness spectrum (the handbook's value for every sediment).
SPECTRAL_EXPONENT = 3.25
#: Reference length of the roughness spectrum, metres (1 cm).
H0_M = 0.01
#: Where the model was fitted to data, Hz [APL94]: outside it the law is extrapolated.
MODEL_RANGE_HZ = (10e3, 100e3)
#: The grain sizes the regressions cover, phi.
GRAIN_SIZE_RANGE_PHI = (-1.0, 9.0)
#: Samples of a law table in incidence (0 to 90 degrees: a quarter degree apart).
TABLE_SIZE = 361
#: Below this ``q`` the integral ``I(q)`` is taken from its two-term series (rough against
#: nothing: the perturbation limit), above it by quadrature.
_Q_SERIES = 2e-3

# Named classes by mean grain size, phi: the handbook's sediment names (Table IV-2).
SEDIMENT_CLASSES: dict[str, float] = {
    "sandy-gravel": -1.0,
    "very-coarse-sand": -0.5,
    "muddy-sandy-gravel": 0.0,
    "coarse-sand": 0.5,
    "gravelly-muddy-sand": 1.0,
    "medium-sand": 1.5,
    "muddy-gravel": 2.0,
    "fine-sand": 2.5,
    "muddy-sand": 3.0,
    "very-fine-sand": 3.5,
    "clayey-sand": 4.0,
    "coarse-silt": 4.5,
    "sandy-silt": 5.0,
    "medium-silt": 5.5,
    "sandy-mud": 6.0,
    "fine-silt": 6.5,
    "sandy-clay": 7.0,
    "very-fine-silt": 7.5,
    "silty-clay": 8.0,
    "clay": 9.0,
}


@dataclass(frozen=True)
class Sediment:
    """The geoacoustic and roughness parameters of a sediment (see the module's docstring).

    Attributes
    ----------
    name : str
    grain_size_phi : float
        Mean grain size ``Mz``, phi.
    density_ratio : float
        ``rho``: sediment over water density.
    sound_speed_ratio : float
        ``nu``: sediment over water sound speed.
    loss_parameter : float
        ``delta``: imaginary over real part of the sediment's wavenumber.
    spectral_strength_cm4 : float
        ``w2``, cm^4: the roughness spectrum ``w2 / (h0 K)^gamma`` at ``K = 1 / h0``.
    volume_parameter : float
        ``sigma2``: the volume scattering coefficient over the attenuation in dB/m.
    spectral_exponent : float
        ``gamma``, within (2, 4).
    """

    name: str
    grain_size_phi: float
    density_ratio: float
    sound_speed_ratio: float
    loss_parameter: float
    spectral_strength_cm4: float
    volume_parameter: float
    spectral_exponent: float = SPECTRAL_EXPONENT

    @property
    def critical_angle_deg(self) -> float | None:
        """The critical grazing angle ``arccos(1 / nu)``, degrees; ``None`` for a slow sediment."""
        if self.sound_speed_ratio <= 1.0:
            return None
        return math.degrees(math.acos(1.0 / self.sound_speed_ratio))


def _density_ratio(mz: float) -> float:
    if mz < 1.0:
        return 0.007797 * mz**2 - 0.17057 * mz + 2.3139
    if mz < 5.3:
        return -0.0165406 * mz**3 + 0.2290201 * mz**2 - 1.1069031 * mz + 3.0455
    return -0.0012973 * mz + 1.1565


def _sound_speed_ratio(mz: float) -> float:
    if mz < 1.0:
        return 0.002709 * mz**2 - 0.056452 * mz + 1.2778
    if mz < 5.3:
        return -0.0014881 * mz**3 + 0.0213937 * mz**2 - 0.1382798 * mz + 1.3425
    return -0.0024324 * mz + 1.0019


def _attenuation_db_per_m_khz(mz: float) -> float:
    if mz < 0.0:
        return 0.4556
    if mz < 2.6:
        return 0.4556 + 0.0245 * mz
    if mz < 4.5:
        return 0.1978 + 0.1245 * mz
    if mz < 6.0:
        return 8.0399 - 2.5228 * mz + 0.20098 * mz**2
    if mz < 9.5:
        return 0.9431 - 0.2041 * mz + 0.0117 * mz**2
    return 0.0601


def _spectral_strength_cm4(mz: float) -> float:
    # The handbook's regression, and its constant from Mz = 5 on (a step of a factor 2 there,
    # as the volume parameter's).
    if mz < 5.0:
        return 0.00207 * (2.03846 - 0.26923 * mz) / (1.0 + 0.076923 * mz)
    return 0.0005175


def _volume_parameter(mz: float) -> float:
    return 0.002 if mz < 5.0 else 0.001


def sediment_from_grain_size(grain_size_phi: float, name: str | None = None,
                             water_sound_speed_m_s: float = 1500.0) -> Sediment:
    """A sediment's parameters from its mean grain size by the handbook's regressions.

    Parameters
    ----------
    grain_size_phi : float
        ``Mz`` in phi, within :data:`GRAIN_SIZE_RANGE_PHI` (-1, sandy gravel, to 9, clay).
    name : str, optional
        Default ``"Mz=<value>"``.
    water_sound_speed_m_s : float
        The water's sound speed, which converts the attenuation per metre into ``delta``.

    Returns
    -------
    Sediment
    """
    lo, hi = GRAIN_SIZE_RANGE_PHI
    mz = float(grain_size_phi)
    if not (math.isfinite(mz) and lo <= mz <= hi):
        raise ConfigError("grain_size_phi", f"must be within [{lo:g}, {hi:g}] phi (sandy gravel to clay: the "
                                            f"regressions' range), got {grain_size_phi!r}")
    nu = _sound_speed_ratio(mz)
    delta = _attenuation_db_per_m_khz(mz) * nu * water_sound_speed_m_s * math.log(10.0) / (40.0 * math.pi * 1000.0)
    return Sediment(name or f"Mz={mz:g}", mz, _density_ratio(mz), nu, delta, _spectral_strength_cm4(mz),
                    _volume_parameter(mz))


def _rock(name: str, mz: float, nu: float) -> Sediment:
    coarsest = sediment_from_grain_size(-1.0)
    return Sediment(name, mz, 2.5, nu, coarsest.loss_parameter, coarsest.spectral_strength_cm4,
                    coarsest.volume_parameter)


#: Beds coarser than the regressions: the handbook's density and speed ratios (rock 2.5 / 2.5,
#: cobble 2.5 / 1.8); loss, roughness and volume taken from sandy gravel (our choice: a rock
#: outcrop's roughness is a property of the site; fit ``level_db`` to a recording).
ROCKS: dict[str, Sediment] = {"cobble": _rock("cobble", -3.0, 1.8), "rock": _rock("rock", -7.0, 2.5)}

#: Every named sediment, coarsest first.
SEDIMENT_NAMES: tuple[str, ...] = ("rock", "cobble") + tuple(SEDIMENT_CLASSES)


def sediment(name: str, water_sound_speed_m_s: float = 1500.0) -> Sediment:
    """The named sediment (:data:`SEDIMENT_NAMES`)."""
    if name in ROCKS:
        return ROCKS[name]
    if name not in SEDIMENT_CLASSES:
        raise ConfigError("sediment", f"unknown sediment {name!r}; allowed: {', '.join(SEDIMENT_NAMES)}")
    return sediment_from_grain_size(SEDIMENT_CLASSES[name], name, water_sound_speed_m_s)


def model_range() -> tuple[float, float]:
    """``(low, high)``, Hz: the frequencies the model was fitted on; outside, it is extrapolated."""
    return MODEL_RANGE_HZ


def _p(grazing: np.ndarray, sed: Sediment) -> np.ndarray:
    kappa = (1.0 + 1j * sed.loss_parameter) / sed.sound_speed_ratio
    return np.sqrt(kappa**2 - np.cos(grazing) ** 2 + 0j)  # principal root: Re, Im >= 0 here


def rayleigh_coefficient(grazing_rad, sed: Sediment) -> np.ndarray:
    """The plane-wave reflection coefficient ``V(theta)`` of the sediment half-space (complex).

    Parameters
    ----------
    grazing_rad : (...) float array
        Grazing angle, radians, in [0, pi/2].
    sed : Sediment

    Returns
    -------
    (...) complex128 ndarray; ``|V|^2`` is the coherent reflectance of a smooth bed.
    """
    return rayleigh_fluid(grazing_rad, sed.density_ratio, sed.sound_speed_ratio, sed.loss_parameter)


def structure_constant(sed: Sediment) -> tuple[float, float]:
    """``(C_h^2, alpha)`` of the structure function ``D(r) = C_h^2 r^(2 alpha)`` (``C_h^2`` in
    m^(2 - 2 alpha)) of the roughness spectrum ``w2 / (h0 K)^gamma``."""
    gamma = sed.spectral_exponent
    alpha = gamma / 2.0 - 1.0
    w2_m4 = sed.spectral_strength_cm4 * 1e-8
    ch2 = (2.0 * math.pi * w2_m4 * H0_M ** (-gamma) * special.gamma(1.0 - alpha) * 2.0 ** (-2.0 * alpha)
           / (alpha * special.gamma(1.0 + alpha)))
    return float(ch2), alpha


def rms_height_m(sed: Sediment, longest_wavelength_m: float) -> float:
    """The rms height of the roughness at wavelengths up to ``longest_wavelength_m``, metres:
    ``h^2 = int_{K_0}^inf W(K) 2 pi K dK = 2 pi w2 h0^-gamma K_0^(2 - gamma) / (gamma - 2)``,
    ``K_0 = 2 pi / longest_wavelength_m`` (the power law diverges at long wavelengths: a patch's
    height needs the cut)."""
    gamma = sed.spectral_exponent
    k0 = 2.0 * math.pi / float(longest_wavelength_m)
    h2 = 2.0 * math.pi * sed.spectral_strength_cm4 * 1e-8 * H0_M ** (-gamma) * k0 ** (2.0 - gamma) / (gamma - 2.0)
    return math.sqrt(h2)


def roughness_spectrum(wavenumber_rad_m, sed: Sediment) -> np.ndarray:
    """``W(K) = w2 / (h0 K)^gamma``, m^4 (two-dimensional, isotropic)."""
    k = np.asarray(wavenumber_rad_m, dtype=np.float64)
    return sed.spectral_strength_cm4 * 1e-8 / (H0_M * k) ** sed.spectral_exponent


def _series(q: np.ndarray, alpha: float) -> np.ndarray:
    """``I(q)`` for small ``q``: the first two terms of ``sum_n (-q)^n / n! 2^(2 n alpha + 1)
    Gamma(1 + n alpha) / Gamma(-n alpha)`` (the Hankel transforms of ``u^(2 n alpha)``)."""
    out = np.zeros_like(q)
    for n in (1, 2):
        out += ((-q) ** n / math.factorial(n) * 2.0 ** (2 * n * alpha + 1) * special.gamma(1 + n * alpha)
                / special.gamma(-n * alpha))
    return out


def kirchhoff_integral(q, alpha: float) -> np.ndarray:
    """``I(q) = int_0^inf exp(-q u^(2 alpha)) J0(u) u du`` for ``q > 0``, ``0 < alpha < 1``.

    By parts, ``I = 2 alpha q int_0^inf u^(2 alpha) exp(-q u^(2 alpha)) J1(u) du``, whose
    integrand is small where the first form's oscillates widely; taken by the trapezoid rule
    on a grid of a tenth of a radian (twenty points a period of ``J1`` or more) up to where the
    exponential is below ``e^-46``; below ``q = 2e-3`` the two-term series.

    Parameters
    ----------
    q : (...) float array, > 0
    alpha : float

    Returns
    -------
    (...) float64 ndarray
    """
    q = np.atleast_1d(np.asarray(q, dtype=np.float64))
    out = np.empty_like(q)
    small = q < _Q_SERIES
    out[small] = _series(q[small], alpha)
    for i in np.flatnonzero(~small):
        u_max = (46.0 / q[i]) ** (1.0 / (2.0 * alpha))
        n = int(min(max(2000, 10.0 * u_max), 400_000))
        u = np.linspace(0.0, u_max, n)
        a = u ** (2.0 * alpha)
        out[i] = 2.0 * alpha * q[i] * integrate.trapezoid(a * np.exp(-q[i] * a) * special.j1(u), u)
    return out


def _q_scale(sed: Sediment, k: float) -> tuple[float, float]:
    """``(C, alpha)`` with ``q = C sin^2 / cos^(2 alpha)``."""
    ch2, alpha = structure_constant(sed)
    return ch2 * 2.0 ** (1.0 - 2.0 * alpha) * k ** (2.0 - 2.0 * alpha), alpha


def _i_over_cos2(grazing: np.ndarray, sed: Sediment, k: float) -> np.ndarray:
    """``I(q(theta)) / cos^2(theta)``, finite at normal incidence (``q -> inf``: the limit
    ``Gamma(1 / alpha) / (2 alpha) (C sin^2)^(-1 / alpha)``)."""
    scale, alpha = _q_scale(sed, k)
    s2 = np.sin(grazing) ** 2
    c = np.cos(grazing)
    out = np.empty_like(grazing)
    normal = c < 1e-7
    out[normal] = special.gamma(1.0 / alpha) / (2.0 * alpha) * (scale * s2[normal]) ** (-1.0 / alpha)
    g = ~normal & (s2 > 0)
    q = scale * s2[g] / c[g] ** (2.0 * alpha)
    out[g] = kirchhoff_integral(q, alpha) / c[g] ** 2
    out[~normal & ~(s2 > 0)] = 0.0
    return out


def _kernel_y(grazing: np.ndarray, sed: Sediment) -> np.ndarray:
    kappa = (1.0 + 1j * sed.loss_parameter) / sed.sound_speed_ratio
    rho = sed.density_ratio
    c2 = np.cos(grazing) ** 2
    return ((rho - 1.0) ** 2 * c2 + rho**2 - kappa**2) / (rho * np.sin(grazing) + _p(grazing, sed)) ** 2


def roughness_backscatter(grazing_rad, sed: Sediment, wavenumber_rad_m: float) -> np.ndarray:
    """``sigma_r(theta)``: the interface's roughness backscatter (small-slope approximation).

    Parameters
    ----------
    grazing_rad : (...) float array, radians in [0, pi/2]
    sed : Sediment
    wavenumber_rad_m : float
        The water's wavenumber ``k = 2 pi f / c``, rad/m.

    Returns
    -------
    (...) float64 ndarray, per unit area and solid angle.
    """
    g = np.atleast_1d(np.asarray(grazing_rad, dtype=np.float64))
    y2 = np.abs(_kernel_y(g, sed)) ** 2
    return (y2 * np.sin(g) ** 2 * _i_over_cos2(g, sed, wavenumber_rad_m) / (8.0 * math.pi)).reshape(np.shape(grazing_rad))


def perturbation_backscatter(grazing_rad, sed: Sediment, wavenumber_rad_m: float) -> np.ndarray:
    """First-order perturbation theory, ``4 k^4 sin^4 |Y|^2 W(2 k cos)``: the small-roughness
    limit of :func:`roughness_backscatter` (its check)."""
    g = np.asarray(grazing_rad, dtype=np.float64)
    k = wavenumber_rad_m
    return 4.0 * k**4 * np.sin(g) ** 4 * np.abs(_kernel_y(g, sed)) ** 2 * roughness_spectrum(2.0 * k * np.cos(g), sed)


def kirchhoff_backscatter(grazing_rad, sed: Sediment, wavenumber_rad_m: float) -> np.ndarray:
    """The Kirchhoff approximation, ``|V(90)|^2 I(q) / (8 pi sin^2 cos^2)``: the near-normal
    limit of :func:`roughness_backscatter` (its check)."""
    g = np.atleast_1d(np.asarray(grazing_rad, dtype=np.float64))
    v0 = np.abs(rayleigh_coefficient(np.pi / 2, sed)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        out = v0 * _i_over_cos2(g, sed, wavenumber_rad_m) / (8.0 * math.pi * np.sin(g) ** 2)
    return out.reshape(np.shape(grazing_rad))


def volume_backscatter(grazing_rad, sed: Sediment) -> np.ndarray:
    """``sigma_v(theta)``: the sediment volume's backscatter (frequency-independent: the
    attenuation is linear in frequency)."""
    g = np.asarray(grazing_rad, dtype=np.float64)
    v = rayleigh_coefficient(g, sed)
    p = _p(g, sed)
    return (5.0 * sed.loss_parameter * sed.volume_parameter * np.abs(1.0 - v**2) ** 2 * np.sin(g) ** 2
            / (sed.sound_speed_ratio * math.log(10.0) * np.abs(p) ** 2 * p.imag))


def backscatter(grazing_rad, sed: Sediment, frequency_hz: float, sound_speed_m_s: float = 1500.0) -> np.ndarray:
    """``sigma_b(theta) = sigma_r + sigma_v``: the sediment's backscattering cross-section.

    Parameters
    ----------
    grazing_rad : (...) float array
        Grazing angles, radians in [0, pi/2].
    sed : Sediment
    frequency_hz : float
        The sonar's frequency, Hz (extrapolated outside :data:`MODEL_RANGE_HZ`).
    sound_speed_m_s : float
        The water's sound speed, m/s.

    Returns
    -------
    (...) float64 ndarray, per unit area and unit solid angle (``10 log10``: dB).
    """
    k = 2.0 * math.pi * float(frequency_hz) / float(sound_speed_m_s)
    return roughness_backscatter(grazing_rad, sed, k) + volume_backscatter(grazing_rad, sed)


@functools.lru_cache(maxsize=64)
def law_table(sed: Sediment, frequency_hz: float, sound_speed_m_s: float) -> np.ndarray:
    """The per-ray law ``f(alpha) = sigma_b / cos(alpha)`` on :data:`TABLE_SIZE` incidences
    ``alpha`` from 0 to 90 degrees (read-only; 0 at grazing incidence).

    A ray meeting the bed at incidence ``alpha`` (grazing ``90 - alpha``) carries ``w f(alpha)``
    (:mod:`sonarsim.config.materials`); the kernels interpolate this table linearly in ``alpha``.
    """
    incidence = np.linspace(0.0, np.pi / 2, TABLE_SIZE)
    grazing = np.pi / 2 - incidence
    grazing[-1] = 0.0
    sigma = backscatter(grazing, sed, frequency_hz, sound_speed_m_s)
    c = np.cos(incidence)
    out = np.where(c > 1e-12, sigma / np.where(c > 1e-12, c, 1.0), 0.0)
    out[-1] = 0.0
    out.setflags(write=False)
    return out
