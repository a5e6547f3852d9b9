"""Backscatter laws: the table the kernels evaluate against each law's own formula."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.config.materials import MAX_ROUGHNESS, Material
from sonarsim.core.radiometry import SurfaceLaws, backscatter, lambertian_intensity, specular_lobe

MATERIALS = [
    Material.lambertian(0.6),
    Material("lambert", mu=0.002),
    Material("rough", albedo=0.3, specular_strength=2.0, roughness=0.15),
    Material("rough", specular_strength=0.5, roughness=MAX_ROUGHNESS),  # default albedo 0.8
]


def test_each_law_is_its_formula_at_known_angles():
    alpha = np.radians([0.0, 30.0, 45.0, 60.0, 89.0])
    c = np.cos(alpha)
    lam, lmb, rough, _ = MATERIALS
    np.testing.assert_allclose(lam.evaluate(c), 0.6 * c, rtol=1e-15)
    # Per unit area sigma = mu cos^2; a ray's footprint grows as 1 / cos: per ray mu cos.
    np.testing.assert_allclose(lmb.evaluate(c) * c, 0.002 * c**2, rtol=1e-15)
    # cos(60 deg) = 1/2: per unit area Lambert's law is a quarter of mu, per ray a half.
    assert lmb.evaluate(0.5) == pytest.approx(0.001) and lam.evaluate(0.5) == pytest.approx(0.3)
    lobe = 2.0 * np.exp(-np.tan(alpha) ** 2 / (2 * 0.15**2)) / np.cos(alpha) ** 4 / np.cos(alpha)
    np.testing.assert_allclose(rough.evaluate(c), 0.3 * c + lobe, rtol=1e-12)
    assert rough.evaluate(1.0) == pytest.approx(0.3 + 2.0)
    assert rough.evaluate(0.0) == 0.0 and lmb.evaluate(0.0) == 0.0


def test_lambert_over_lambertian_is_mu_over_rho_at_every_angle():
    # The paper's rho cos per ray is Lambert's law per unit area: the same angular law.
    c = np.cos(np.radians(np.linspace(0.0, 89.0, 50)))
    ratio = Material("lambert", mu=0.01).evaluate(c) / Material.lambertian(0.5).evaluate(c)
    np.testing.assert_allclose(ratio, 0.02, rtol=1e-14)


@pytest.mark.parametrize("s", [0.02, 0.1, 0.3, MAX_ROUGHNESS])
def test_the_lobe_peaks_at_normal_incidence(s):
    alpha = np.radians(np.linspace(0.0, 89.9, 2000))
    # Per unit area: the per-ray lobe times the footprint's cos(alpha).
    lobe = specular_lobe(np.cos(alpha), np.full(alpha.shape, s)) * np.cos(alpha)
    assert lobe[0] == 1.0
    assert np.all(np.diff(lobe) <= 1e-12)  # falls monotonically away from normal incidence
    assert lobe[-1] < 1e-6
    # Half its peak where tan^2(alpha) / (2 s^2) - 4 ln(sec alpha) = ln 2: narrower when smoother.
    half = alpha[np.argmin(np.abs(lobe - 0.5))]
    t2 = math.tan(half) ** 2
    assert t2 / (2 * s * s) - 2 * math.log(1 + t2) == pytest.approx(math.log(2), abs=0.02)


def test_rougher_than_allowed_would_peak_off_normal():
    # Why roughness stops at 1/2: the slope density no longer beats the 1/cos^4 Jacobian.
    c = np.cos(np.radians([0.0, 20.0]))
    lobe = specular_lobe(c, np.full(2, 0.8)) * c  # per unit area
    assert lobe[1] > lobe[0]


def test_grazing_and_degenerate_cosines_give_zero_not_nan():
    c = np.array([0.0, 1e-170, 1e-30, 1e-3])
    out = specular_lobe(c, np.full(4, 0.3))
    assert np.all(np.isfinite(out)) and np.all(out == 0.0)


def test_backscatter_of_a_table_equals_each_laws_formula():
    rng = np.random.default_rng(0)
    laws = SurfaceLaws.of(MATERIALS)
    n = 5000
    index = rng.integers(0, len(laws), n)  # 0: nothing hit
    cos = rng.uniform(0.0, 1.0, n).astype(np.float32)
    cos[::97] = 0.0
    cos[::89] = 1.0
    weight = rng.uniform(0.0, 1e-3, n)
    dist = np.where(index > 0, rng.uniform(0.5, 5.0, n), np.inf)
    texel = rng.uniform(0.0, 1.0, n).astype(np.float32)
    for tvg in (True, False):
        for tex in (None, texel):
            out = backscatter(weight, cos, laws, index, dist, tvg, tex)
            expected = np.zeros(n)
            for k, m in enumerate(MATERIALS, start=1):
                on = index == k
                expected[on] = weight[on] * m.evaluate(cos[on], None if tex is None else tex[on])
            if not tvg:
                expected = expected / np.where(np.isfinite(dist), dist, 1.0) ** 2
            np.testing.assert_allclose(out, expected, rtol=1e-12, atol=0)
            assert np.all(out[index == 0] == 0)


def test_a_lambertian_table_is_the_papers_arithmetic_bit_for_bit():
    rng = np.random.default_rng(1)
    albedo = np.array([0.0, 0.8, 0.4, 0.55])
    index = rng.integers(0, 4, 1000)
    cos = rng.uniform(0, 1, 1000).astype(np.float32)
    weight = rng.uniform(0, 1e-3, 1000)
    dist = np.where(index > 0, rng.uniform(0.5, 5.0, 1000), np.inf)
    for tvg in (True, False):
        ref = lambertian_intensity(weight, cos, albedo[index], dist, tvg)
        for laws in (SurfaceLaws.of(albedo), SurfaceLaws.of([Material.lambertian(a) for a in albedo[1:]])):
            np.testing.assert_array_equal(backscatter(weight, cos, laws, index, dist, tvg), ref)
        # A texture of ones changes nothing either.
        np.testing.assert_array_equal(
            backscatter(weight, cos, SurfaceLaws.of(albedo), index, dist, tvg, np.ones(1000, np.float32)), ref)
