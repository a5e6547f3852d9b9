"""Coherent reflection against its closed forms: the Rayleigh coefficient at normal incidence
and at the critical angle, the roughness loss against a seeded Gaussian surface, the wind sea's
height, and the tables the kernels read against the formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim import ConfigError
from sonarsim.config.materials import OBJECT_MATERIALS, Material, Reflection
from sonarsim.core import reflection, seabed


def test_the_rayleigh_coefficient_at_normal_incidence_is_the_impedance_contrast():
    for rho, nu in ((1.9, 1.18), (2.5, 2.5), (1.15, 0.98), (7.85, 3.99)):
        v = reflection.rayleigh_fluid(math.pi / 2, rho, nu)
        z = rho * nu
        assert v.real == pytest.approx((z - 1) / (z + 1), abs=1e-12)
        assert abs(v.imag) < 1e-12


def test_below_the_critical_angle_a_lossless_fast_bed_reflects_everything():
    rho, nu = 1.845, 1.178
    critical = math.acos(1 / nu)  # grazing, 31.9 degrees
    below = np.linspace(0.0, critical, 50)
    np.testing.assert_allclose(np.abs(reflection.rayleigh_fluid(below, rho, nu)), 1.0, atol=1e-9)
    # Just above, energy enters the bed: |V| falls steeply from 1.
    above = reflection.rayleigh_fluid(critical + np.radians([0.5, 2.0, 10.0]), rho, nu)
    assert np.all(np.diff(np.abs(above)) < 0) and np.abs(above[0]) < 0.97
    # The sediment's own coefficient is this one.
    sand = seabed.sediment("medium-sand")
    g = np.radians([5.0, 30.0, 60.0, 90.0])
    np.testing.assert_allclose(seabed.rayleigh_coefficient(g, sand),
                               reflection.rayleigh_fluid(g, sand.density_ratio, sand.sound_speed_ratio,
                                                         sand.loss_parameter), rtol=1e-14)


def test_the_roughness_loss_is_the_mean_field_of_a_seeded_gaussian_surface():
    # The coherent field reflected by heights z is the mean of exp(2 i k sin(theta) z): its
    # intensity for Gaussian heights of rms h is exp(-4 k^2 h^2 sin^2 theta).
    rng = np.random.default_rng(1234)
    h, k = 0.8e-3, 2 * math.pi * 600e3 / 1500.0
    z = rng.normal(0.0, h, 400_000)
    for deg in (3.0, 10.0, 25.0, 60.0):
        s = math.sin(math.radians(deg))
        mean = np.mean(np.exp(2j * k * s * z))
        expected = float(reflection.roughness_loss(math.radians(deg), k, h))
        assert abs(mean) ** 2 == pytest.approx(expected, abs=4e-3)
    assert float(reflection.roughness_loss(math.radians(60.0), k, h)) < 0.05  # most of it removed at 600 kHz


def test_a_wind_seas_rms_height():
    # Pierson-Moskowitz: H_s = 0.21 U^2 / g; rms height a quarter of it.
    assert reflection.wind_sea_rms_height_m(10.0) == pytest.approx(0.21 * 100 / 9.80665 / 4)
    assert reflection.wind_sea_rms_height_m(0.0) == 0.0


def test_the_kernels_table_against_the_formulas():
    sand = Material("sediment", sediment="fine-sand")
    r = Reflection(rms_height_m=0.3e-3)
    table = r.table(sand, 1500.0)
    q = r.exponent(sand, 400e3, 1500.0)
    assert q == pytest.approx(4 * (2 * math.pi * 400e3 / 1500 * 0.3e-3) ** 2)
    c = np.linspace(0.0, 1.0, 3001)
    np.testing.assert_allclose(reflection.reflectance(c, table, q), r.evaluate(c, sand, 400e3, 1500.0),
                               atol=2e-4)


def test_every_medium_returns_at_most_what_it_receives():
    c = np.linspace(0.0, 1.0, 201)
    media = [*seabed.SEDIMENT_NAMES, *OBJECT_MATERIALS, "pressure-release"]
    for medium in media:
        r = Reflection(medium).evaluate(c, None, 1e6, 1480.0)
        assert np.all((r >= 0.0) & (r <= 1.0 + 1e-12)), medium


def test_a_sediments_rms_height_is_its_spectrum_integrated_to_the_patch():
    sand = seabed.sediment("medium-sand")
    h = seabed.rms_height_m(sand, 0.1)
    # Numerically: h^2 = int W(K) 2 pi K dK from 2 pi / 0.1 m up.
    from scipy import integrate
    k0 = 2 * math.pi / 0.1
    h2, _ = integrate.quad(lambda k: seabed.roughness_spectrum(k, sand) * 2 * math.pi * k, k0, np.inf, limit=200)
    assert h == pytest.approx(math.sqrt(h2), rel=1e-6)
    assert 1e-3 < h < 2.5e-3  # millimetres of roughness
    assert Reflection().rms_height(Material("sediment", sediment="medium-sand")) == pytest.approx(h)


def test_the_surface_by_wind_speed():
    c = np.array([0.0, 0.01, 0.05, 0.2])
    r = Reflection("pressure-release", wind_speed_m_s=3.0).evaluate(c, None, 900e3, 1500.0)
    k, h = 2 * math.pi * 900e3 / 1500.0, reflection.wind_sea_rms_height_m(3.0)
    np.testing.assert_allclose(r, np.exp(-4 * k * k * h * h * c * c), rtol=1e-12)
    assert np.all(Reflection("pressure-release").evaluate(c, None, 900e3, 1500.0) == 1.0)  # a calm sea


def test_bad_reflections_are_refused_by_name():
    with pytest.raises(ConfigError, match="medium"):
        Reflection("mud pie")
    with pytest.raises(ConfigError, match="wind_speed_m_s"):
        Reflection("steel", wind_speed_m_s=3.0)
    with pytest.raises(ConfigError, match="wind_speed_m_s"):
        Reflection("pressure-release", wind_speed_m_s=3.0, rms_height_m=0.1)
    with pytest.raises(ConfigError, match="rms_height_m"):
        Reflection("steel", rms_height_m=-1.0)
    with pytest.raises(ConfigError, match="medium"):  # a Lambertian surface names no medium
        Reflection().evaluate(0.5, Material.lambertian(0.5), 1e6, 1500.0)
    with pytest.raises(ConfigError, match="frequency_khz"):
        Reflection("steel").exponent(None, None, 1500.0)
