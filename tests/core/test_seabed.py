"""The sediment backscatter model (core/seabed.py) against its published regressions, its own
limits (perturbation theory, Kirchhoff), closed forms and an energy bound."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import integrate, special

from sonarsim.core import seabed as sb
from sonarsim.errors import ConfigError

K100 = 2 * math.pi * 100e3 / 1500.0  # the wavenumber at 100 kHz, rad/m


@pytest.mark.parametrize("name, rho, nu", [
    # The handbook's table (APL-UW TR 9407, Table IV-2): its regressions must give these.
    ("sandy-gravel", 2.492, 1.337),
    ("medium-sand", 1.845, 1.1782),
    ("fine-sand", 1.451, 1.1073),
    ("clay", 1.145, 0.9800),
])
def test_regressions_give_the_handbook_table(name, rho, nu):
    s = sb.sediment(name)
    assert s.density_ratio == pytest.approx(rho, abs=6e-4)
    assert s.sound_speed_ratio == pytest.approx(nu, abs=6e-4)


def test_loss_parameter_is_the_attenuation_per_wavelength():
    # delta = Im k / Re k; an attenuation of k_p dB/m/kHz is k_p f / 8.686 Np/m, Re k = 2 pi f / (nu c).
    s = sb.sediment("medium-sand", water_sound_speed_m_s=1500.0)
    k_p = 0.4556 + 0.0245 * 1.5
    f = 100e3
    assert s.loss_parameter == pytest.approx((k_p * f / 1000 / (20 / math.log(10))) / (2 * math.pi * f / (s.sound_speed_ratio * 1500)),
                                             rel=1e-12)


def test_rayleigh_coefficient_at_normal_incidence_and_the_critical_angle():
    s = dataclasses.replace(sb.sediment("medium-sand"), loss_parameter=0.0)  # lossless: closed forms
    z = s.density_ratio * s.sound_speed_ratio
    assert sb.rayleigh_coefficient(np.pi / 2, s) == pytest.approx((z - 1) / (z + 1), abs=1e-14)
    theta_c = math.radians(s.critical_angle_deg)
    assert math.cos(theta_c) == pytest.approx(1 / s.sound_speed_ratio)
    # Total reflection at and below the critical angle, none of it above.
    below = np.linspace(0.0, theta_c, 20)
    np.testing.assert_allclose(np.abs(sb.rayleigh_coefficient(below, s)), 1.0, atol=1e-12)
    assert abs(sb.rayleigh_coefficient(theta_c + 0.05, s)) < 0.9
    # Loss lets energy in below the critical angle too.
    assert abs(sb.rayleigh_coefficient(theta_c / 2, sb.sediment("medium-sand"))) < 0.99
    assert sb.sediment("clay").critical_angle_deg is None  # a slow bed has none


@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")  # J0's slow oscillation; checked below
def test_structure_constant_is_that_of_the_spectrum():
    # D(r) = 2 int (1 - J0(K r)) W(K) d^2K, by quadrature, against C_h^2 r^(2 alpha).
    s = sb.sediment("fine-sand")
    ch2, alpha = sb.structure_constant(s)
    gamma, x_max = s.spectral_exponent, 400.0
    for r in (0.01, 0.1, 1.0):
        f = lambda x: (1 - special.j0(x)) * sb.roughness_spectrum(x / r, s) * x / r**2  # noqa: E731
        near = integrate.quad(f, 0, x_max, limit=2000)[0]
        # Beyond x_max, 1 - J0 averages 1 (its J0 part is below x_max^-2.75): W's own integral.
        far = sb.roughness_spectrum(x_max / r, s) * x_max**2 / r**2 / (gamma - 2)
        d = 4 * math.pi * (near + far)
        assert d == pytest.approx(ch2 * r ** (2 * alpha), rel=2e-4)


def test_kirchhoff_integral_against_its_two_series():
    alpha = 0.625
    # Large q: I = sum_n (-1)^n / (n!^2 4^n) Gamma((n + 1) / alpha) / (2 alpha q^((n + 1) / alpha)).
    for q in (10.0, 100.0, 1e4):
        series = sum((-1) ** n / (math.factorial(n) ** 2 * 4**n) * special.gamma((n + 1) / alpha)
                     / (2 * alpha * q ** ((n + 1) / alpha)) for n in range(20))
        assert sb.kirchhoff_integral(q, alpha)[0] == pytest.approx(series, rel=1e-6)
    # Small q: the quadrature just above the switch against the small-q series.
    q = np.array([2.5e-3])
    assert sb.kirchhoff_integral(q, alpha)[0] == pytest.approx(sb._series(q, alpha)[0], rel=1e-4)


def test_roughness_term_tends_to_perturbation_theory_for_small_roughness():
    s = dataclasses.replace(sb.sediment("medium-sand"), spectral_strength_cm4=1e-6)
    g = np.radians([5.0, 20.0, 40.0, 60.0, 75.0])
    ratio_db = 10 * np.log10(sb.roughness_backscatter(g, s, K100) / sb.perturbation_backscatter(g, s, K100))
    np.testing.assert_allclose(ratio_db, 0.0, atol=0.01)


def test_roughness_term_tends_to_kirchhoff_near_normal_incidence():
    s = sb.sediment("medium-sand")
    g = np.radians([86.0, 88.0, 89.5])
    ratio_db = 10 * np.log10(sb.roughness_backscatter(g, s, K100) / sb.kirchhoff_backscatter(g, s, K100))
    np.testing.assert_allclose(ratio_db, 0.0, atol=0.05)
    # At normal incidence the limit q -> inf: |V|^2 Gamma(1/alpha) / (2 alpha) (C)^(-1/alpha) / (8 pi).
    scale, alpha = sb._q_scale(s, K100)
    peak = abs(sb.rayleigh_coefficient(np.pi / 2, s)) ** 2 * special.gamma(1 / alpha) / (2 * alpha) * scale ** (-1 / alpha)
    assert sb.roughness_backscatter(np.pi / 2, s, K100) == pytest.approx(peak / (8 * math.pi), rel=1e-12)
    assert sb.roughness_backscatter(np.radians(89.9), s, K100) == pytest.approx(peak / (8 * math.pi), rel=1e-3)


def test_perturbation_regime_grows_as_k_to_the_4_minus_gamma():
    # 4 k^4 W(2 k cos) with W ~ K^-3.25: k^0.75, 7.5 dB a decade, where the roughness is small.
    s = sb.sediment("clay")
    g = np.radians([10.0, 20.0])
    lo = sb.roughness_backscatter(g, s, K100 / 10)
    hi = sb.roughness_backscatter(g, s, K100)
    np.testing.assert_allclose(10 * np.log10(hi / lo), 7.5, atol=0.1)


def test_volume_term_at_normal_incidence_is_its_closed_form():
    s = sb.sediment("silty-clay")
    kappa = (1 + 1j * s.loss_parameter) / s.sound_speed_ratio
    v = (s.density_ratio - kappa) / (s.density_ratio + kappa)
    expected = (5 * s.loss_parameter * s.volume_parameter * abs(1 - v**2) ** 2
                / (s.sound_speed_ratio * math.log(10) * abs(kappa) ** 2 * kappa.imag))
    assert sb.volume_backscatter(np.pi / 2, s) == pytest.approx(expected, rel=1e-12)
    # The loss cancels (deeper penetration, as much more volume): a tenth of it, nearly the same level.
    less = dataclasses.replace(s, loss_parameter=s.loss_parameter / 10)
    assert sb.volume_backscatter(np.pi / 4, less) == pytest.approx(sb.volume_backscatter(np.pi / 4, s), rel=0.02)


@pytest.mark.parametrize("name", ["rock", "cobble", "sandy-gravel", "medium-sand", "coarse-silt", "clay"])
def test_no_sediment_returns_more_than_it_receives(name):
    # Reciprocity with a separable bistatic law, sigma(i, s) = sqrt(sigma(i) sigma(s)) (exact for
    # Lambert's), gives the fraction scattered into the water's half-space; below 80 degrees
    # grazing (where the backscatter is diffuse, not the specular lobe's edge) it stays under 1.
    # On the renderer's own tables (sigma = f cos(alpha)), the hardest beds to the softest.
    s = sb.sediment(name)
    incidence = np.linspace(0, np.pi / 2, sb.TABLE_SIZE)[1:-1][::-1]
    th = np.pi / 2 - incidence  # grazing, rising
    for f in (10e3, 100e3, 1e6, 3e6):
        sigma = sb.law_table(s, f, 1500.0)[1:-1][::-1] * np.cos(incidence)
        into_water = 2 * math.pi * integrate.trapezoid(np.sqrt(sigma) * np.cos(th), th)
        fraction = np.sqrt(sigma) / np.sin(th) * into_water
        assert fraction[th < np.radians(80)].max() < 1.0, (name, f)


def test_harder_beds_scatter_more():
    g = np.radians(30.0)
    levels = [float(sb.backscatter(g, sb.sediment(n), 100e3)) for n in ("sandy-gravel", "fine-sand", "clay")]
    assert levels[0] > levels[1] > levels[2]


def test_table_is_the_law_per_ray():
    s = sb.sediment("fine-sand")
    table = sb.law_table(s, 400e3, 1500.0)
    assert table.shape == (sb.TABLE_SIZE,) and not table.flags.writeable
    incidence = np.linspace(0, np.pi / 2, sb.TABLE_SIZE)[1:-1]
    np.testing.assert_allclose(table[1:-1], sb.backscatter(np.pi / 2 - incidence, s, 400e3) / np.cos(incidence),
                               rtol=1e-12)
    assert table[-1] == 0.0


def test_unknown_sediments_and_grain_sizes_are_refused():
    with pytest.raises(ConfigError, match="allowed: rock, cobble"):
        sb.sediment("marmalade")
    with pytest.raises(ConfigError, match=r"grain_size_phi.*\[-1, 9\]"):
        sb.sediment_from_grain_size(12.0)
    assert sb.model_range() == (10e3, 100e3)


def test_perturbation_kernel_has_the_pressure_release_and_rigid_limits():
    # First-order perturbation theory's closed forms: a pressure-release surface (rho -> 0)
    # scatters 4 k^4 sin^4 W (|Y| = 1); a rigid one (rho -> inf) (1 + cos^2)^2 / sin^4 times that.
    g = np.radians([10.0, 30.0, 60.0])
    soft = dataclasses.replace(sb.sediment("fine-sand"), density_ratio=1e-9)
    hard = dataclasses.replace(sb.sediment("fine-sand"), density_ratio=1e9)
    np.testing.assert_allclose(np.abs(sb._kernel_y(g, soft)), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.abs(sb._kernel_y(g, hard)), (1 + np.cos(g) ** 2) / np.sin(g) ** 2, rtol=1e-6)
