"""Coherent (specular) reflection off a plane boundary: the plane-wave reflectance of a fluid
half-space against grazing angle, reduced by the boundary's roughness.

The reflectance a mirror applies to a path's intensity (one reflection, grazing angle
``theta`` from the mean boundary):

``R(theta) = |V(theta)|^2 exp(-4 k^2 h^2 sin^2(theta))``

The Rayleigh coefficient ``V``
    ``V = (rho sin(theta) - P) / (rho sin(theta) + P)``, ``P = sqrt(kappa^2 - cos^2(theta))``
    (``Im P >= 0``), ``kappa = (1 + i delta) / nu``, for a fluid half-space of density ratio
    ``rho``, sound-speed ratio ``nu`` and loss parameter ``delta`` [Brekhovskikh & Lysanov,
    *Fundamentals of Ocean Acoustics*, Ch. 4]. At normal incidence
    ``V = (Z - Z_w) / (Z + Z_w)`` (``Z = rho nu`` relative impedance); below the critical
    grazing angle ``arccos(1 / nu)`` of a lossless fast half-space ``|V| = 1``. Solids are
    treated as fast fluids (no shear waves: the Rayleigh-wave and shear losses of a metal near
    its critical angles are not modelled). The water surface, seen from below, is a
    pressure-release boundary: ``V = -1``.
The roughness (coherent-reflection) loss ``exp(-4 k^2 h^2 sin^2(theta))``
    The mean field reflected by a boundary of Gaussian height statistics with rms height ``h``
    (the Kirchhoff approximation's coherent term; Eckart 1953, J. Acoust. Soc. Am. 25, 566;
    the exponent is ``-g / 2`` with ``g = (2 k h sin(theta))^2`` the Rayleigh parameter):
    ``k = 2 pi f / c`` the water's wavenumber. Millimetres of rms height remove most of the
    coherent reflection at MHz except near grazing incidence.
The water surface by wind speed
    A fully developed wind sea's significant wave height ``H_s = 0.21 U^2 / g`` (U the wind
    speed at 19.5 m, m/s; Pierson & Moskowitz 1964, J. Geophys. Res. 69, 5181) and its rms
    height ``h = H_s / 4``. Only the loss of the coherent reflection is modelled: the sound the
    rough surface scatters incoherently is not.

The kernels read ``|V|^2`` tabulated against ``c = sin(theta)`` (the cosine of the incidence
from the normal: what they compute at a reflection) on :data:`TABLE_SIZE` points evenly from
0 to 1, linearly interpolated, and the roughness exponent ``q = 4 k^2 h^2`` exactly
(:func:`reflectance`: the reference they are tested against).
"""

from __future__ import annotations

import math

import numpy as np

#: Points of the tabulated ``|V|^2`` against ``c = sin(grazing)``, evenly from 0 to 1.
TABLE_SIZE = 1025

#: Standard gravity, m/s^2.
GRAVITY_M_S2 = 9.80665

#: The Pierson-Moskowitz significant wave height over ``U^2 / g``.
PIERSON_MOSKOWITZ_HS = 0.21


def rayleigh_fluid(grazing_rad, density_ratio: float, sound_speed_ratio: float,
                   loss_parameter: float = 0.0) -> np.ndarray:
    """The plane-wave reflection coefficient ``V`` of a fluid half-space (complex).

    Parameters
    ----------
    grazing_rad : (...) float array
        Grazing angle, radians, in [0, pi/2].
    density_ratio, sound_speed_ratio : float
        The half-space's density and sound speed over the water's (``rho``, ``nu``), > 0.
    loss_parameter : float
        ``delta``: the imaginary over the real part of the half-space's wavenumber, >= 0.

    Returns
    -------
    (...) complex128 ndarray
    """
    g = np.asarray(grazing_rad, dtype=np.float64)
    kappa = (1.0 + 1j * loss_parameter) / sound_speed_ratio
    p = np.sqrt(kappa**2 - np.cos(g) ** 2 + 0j)  # principal root: Re, Im >= 0 here
    rs = density_ratio * np.sin(g)
    den = rs + p
    # At grazing incidence on a lossless bed of the water's speed both vanish: V's limit is -1.
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den == 0, -1.0 + 0j, (rs - p) / np.where(den == 0, 1.0, den))


def roughness_loss(grazing_rad, wavenumber_rad_m: float, rms_height_m: float) -> np.ndarray:
    """The coherent reflection's roughness loss ``exp(-4 k^2 h^2 sin^2(theta))`` (intensity).

    Parameters
    ----------
    grazing_rad : (...) float array, radians
    wavenumber_rad_m : float
        The water's wavenumber ``2 pi f / c``, rad/m.
    rms_height_m : float
        The boundary's rms height, metres.

    Returns
    -------
    (...) float64 ndarray, in (0, 1].
    """
    s = np.sin(np.asarray(grazing_rad, dtype=np.float64))
    return np.exp(-4.0 * (wavenumber_rad_m * rms_height_m) ** 2 * s * s)


def wind_sea_rms_height_m(wind_speed_m_s: float) -> float:
    """The rms height of a fully developed wind sea, ``0.21 U^2 / (4 g)``, metres."""
    return PIERSON_MOSKOWITZ_HS * float(wind_speed_m_s) ** 2 / GRAVITY_M_S2 / 4.0


def reflectance_table(density_ratio: float | None, sound_speed_ratio: float = 1.0,
                      loss_parameter: float = 0.0) -> np.ndarray:
    """``|V|^2`` on :data:`TABLE_SIZE` values of ``c = sin(grazing)`` evenly from 0 to 1.

    ``density_ratio`` None: a pressure-release boundary (``|V|^2 = 1``); ``inf``: a rigid one
    (``|V|^2 = 1``). Read-only.
    """
    c = np.linspace(0.0, 1.0, TABLE_SIZE)
    if density_ratio is None or math.isinf(density_ratio):
        out = np.ones_like(c)
    else:
        out = np.abs(rayleigh_fluid(np.arcsin(c), density_ratio, sound_speed_ratio, loss_parameter)) ** 2
    out.setflags(write=False)
    return out


def reflectance(c, table: np.ndarray, q: float) -> np.ndarray:
    """The reflectance the kernels apply at ``c = |cos(incidence)|`` = ``sin(grazing)``:
    ``table`` (:func:`reflectance_table`, or any row of the same length) linearly interpolated,
    times ``exp(-q c^2)`` (``q = 4 k^2 h^2``).

    Parameters
    ----------
    c : (...) float array, in [0, 1]
    table : (T,) float array
    q : float

    Returns
    -------
    (...) float64 ndarray
    """
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    grid = np.linspace(0.0, 1.0, len(table))
    return np.interp(c, grid, np.asarray(table, dtype=np.float64)) * np.exp(-q * c * c)


# The coherent lobe of a flat face ------------------------------------------------------------

#: Table points per first-null half-width of a face's lobe (:func:`face_lobe_table`).
LOBE_POINTS_PER_NULL = 24

#: The largest face table (points from 0 to 90 degrees of incidence).
MAX_FACE_TABLE = 2**17 + 1

#: The first zero of ``J1``: the Airy pattern's first null at ``2 k a sin(alpha) = 3.8317``.
AIRY_FIRST_ZERO = 3.831705970207512


def airy(x) -> np.ndarray:
    """``(2 J1(x) / x)^2`` (1 at ``x = 0``): a disc's far-field intensity pattern."""
    from scipy import special

    x = np.asarray(x, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = (2.0 * special.j1(x) / x) ** 2
    return np.where(np.abs(x) < 1e-8, 1.0, out)


def face_cross_section(incidence_rad, area_m2: float, wavenumber_rad_m: float, reflectance: float = 1.0) -> np.ndarray:
    """A flat face's monostatic backscattering cross-section per steradian in the far field
    (``sigma_bs = sigma / (4 pi)``, m^2, whose ``10 log10`` is the target strength; physical
    optics, the face taken as the disc of its area, radius ``a = sqrt(A / pi)``):

    ``sigma_bs(alpha) = |R|^2 A^2 / lambda^2 (2 J1(x) / x)^2 cos^2(alpha)``, ``x = 2 k a sin(alpha)``

    at normal incidence ``TS = 10 log10(|R|^2 A^2 / lambda^2)`` whatever the face's shape
    [Urick, *Principles of Underwater Sound*, 3rd ed., Table 9.1; Knott et al., *Radar Cross
    Section*, 2nd ed., Sect. 5]; a square face's lobe is ``sinc^2(k L sin(alpha))`` across its
    sides, which the disc's replaces (the same peak and about the same width).

    Parameters
    ----------
    incidence_rad : (...) float array
        Angle from the face's normal, radians.
    area_m2, wavenumber_rad_m, reflectance : float
        The face's area, the water's wavenumber ``2 pi f / c`` and ``|R|^2``.

    Returns
    -------
    (...) float64 ndarray, m^2.
    """
    alpha = np.asarray(incidence_rad, dtype=np.float64)
    a = math.sqrt(area_m2 / math.pi)
    k = float(wavenumber_rad_m)
    peak = reflectance * area_m2**2 * (k / (2.0 * math.pi)) ** 2
    return peak * airy(2.0 * k * a * np.sin(alpha)) * np.cos(alpha) ** 2


def face_table_size(area_m2: float, wavenumber_rad_m: float) -> int:
    """Points of a face's table from 0 to 90 degrees: :data:`LOBE_POINTS_PER_NULL` per first-null
    half-width ``3.83 / (2 k a)`` (at least 361, at most :data:`MAX_FACE_TABLE`)."""
    null = AIRY_FIRST_ZERO / (2.0 * wavenumber_rad_m * math.sqrt(area_m2 / math.pi))
    n = int(math.ceil((math.pi / 2) / (null / LOBE_POINTS_PER_NULL))) + 1
    return int(min(max(n, 361), MAX_FACE_TABLE))


def face_lobe_table(area_m2: float, wavenumber_rad_m: float, reflectance: float = 1.0,
                    albedo: float = 0.0) -> np.ndarray:
    """The per-ray law of a face, ``f(alpha) = albedo cos(alpha) + sigma(alpha) / (A cos(alpha))``
    (:func:`face_cross_section` per unit area of the face, over the cosine a ray's footprint
    grows by), on :func:`face_table_size` incidences evenly from 0 to 90 degrees (read-only).

    Summed over the rays that meet the face, the lobe gives ``sigma(alpha) / r^2`` in the far
    field (where the face subtends less than its lobe), and in the near field, where the rays
    sweep the lobe across the face, ``(r^2 / 4) / r^2``: the infinite mirror's level
    ``TS = 10 log10(r^2 / 4)`` (the lobe integrates to ``r^2 / 4`` over the face's plane). The rays must resolve the lobe for either (angular spacing well below
    ``3.83 / (2 k a)``).
    """
    n = face_table_size(area_m2, wavenumber_rad_m)
    alpha = np.linspace(0.0, math.pi / 2, n)
    c = np.cos(alpha)
    with np.errstate(invalid="ignore", divide="ignore"):
        lobe = np.where(c > 1e-12, face_cross_section(alpha, area_m2, wavenumber_rad_m, reflectance)
                        / (area_m2 * np.where(c > 1e-12, c, 1.0)), 0.0)
    out = albedo * c + lobe
    out[-1] = 0.0
    out.setflags(write=False)
    return out
