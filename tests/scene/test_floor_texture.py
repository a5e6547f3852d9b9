"""The sea-floor texture field: its configuration, its statistics against the closed forms, its seeding.

The field's statistics are checked on one tile period of several seeded realisations. The
sampling error of a spatial average over an area ``A`` of a field with correlation ``C`` has
variance ``(1 / A) * integral(C)`` (of a mean) or at most ``(2 / A) * integral(C**2)`` (of a
covariance); tolerances are four of those standard errors, plus the documented bias of
bilinear interpolation between tile nodes where it applies.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError
from sonarsim.config.scene import GroundSpec, PlaneSpec, TextureSpec
from sonarsim.scene.floor_texture import (
    CELLS_PER_LENGTH, TEXTURE_STREAM, TILE_CELLS, ReflectivityField, field_correlation, plane_axes, texture_fields,
)
from tests.conftest import sonar_dict

SEEDS = (0, 1, 2, 3)
LENGTHS_M = (2.0, 0.5)
ANGLE_DEG = 30.0
# Integral of the correlation over the plane, in correlation areas (l_1 l_2): pi (Gaussian),
# 2 pi (exponential); of its square: pi / 2 and pi / 2.
INTEGRAL = {"gaussian": math.pi, "exponential": 2 * math.pi}
INTEGRAL_SQ = {"gaussian": math.pi / 2, "exponential": math.pi / 2}
# Bilinear interpolation between nodes l / 8 (Gaussian) or l / 16 (exponential) apart smooths
# the field slightly: its covariance at a lag moves by at most this much (measured below 0.006).
INTERPOLATION_BIAS = 0.01


def doc(texture=None, planes=None) -> dict:
    d = {"sonar": sonar_dict(pose={"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}),
         "ground": {"height_m": 0.0, "albedo": 0.5}}
    if texture is not None:
        d["ground"]["texture"] = texture
    if planes is not None:
        d["planes"] = planes
    return d


def period_points(field: ReflectivityField, n: int, rng) -> np.ndarray:
    """(n, 3) points uniform over one period of the field's tile (in its turned axes), on the ground."""
    a = math.radians(field.spec.angle_deg)
    p1, p2 = field.period_m
    s, t = rng.uniform(0, p1, n), rng.uniform(0, p2, n)
    return np.stack([s * math.cos(a) - t * math.sin(a), s * math.sin(a) + t * math.cos(a), np.zeros(n)], axis=1)


def fields(covariance: str, std_db: float = 3.0) -> list[ReflectivityField]:
    spec = TextureSpec(std_db, LENGTHS_M, ANGLE_DEG, None, covariance)
    return [ReflectivityField(spec, (0.0, 0.0, 1.0), (seed, TEXTURE_STREAM)) for seed in SEEDS]


def standard_error(covariance: str, field: ReflectivityField, integral: float) -> float:
    """Standard error over one period averaged over the seeds, for a correlation integral in correlation areas."""
    area = field.period_m[0] * field.period_m[1] / (LENGTHS_M[0] * LENGTHS_M[1])
    return math.sqrt(integral / area / len(SEEDS))


# Configuration -----------------------------------------------------------------------------


@pytest.mark.parametrize("texture, key", [
    ({"std_db": -1.0}, "ground.texture.std_db"),
    ({"std_db": 25.0}, "ground.texture.std_db"),
    ({"std_db": "3"}, "ground.texture.std_db"),
    ({"correlation_m": [1.0, 0.0]}, "ground.texture.correlation_m"),
    ({"correlation_m": [1.0, 2.0, 3.0]}, "ground.texture.correlation_m"),
    ({"correlation_m": 1e5}, "ground.texture.correlation_m"),
    ({"angle_deg": 400.0}, "ground.texture.angle_deg"),
    ({"seed": -1}, "ground.texture.seed"),
    ({"seed": 1.5}, "ground.texture.seed"),
    ({"covariance": "matern"}, "ground.texture.covariance"),
    ({"variance": 1.0}, "ground.texture.variance"),
])
def test_bad_texture_keys_are_refused_by_name(texture, key):
    with pytest.raises(ConfigError) as err:
        sonarsim.load_scene(doc(texture))
    assert err.value.key == key


def test_a_plane_texture_is_named_by_its_plane():
    plane = {"name": "wall", "point_m": [5, 0, 0], "normal": [-1, 0, 0], "albedo": 0.3,
             "texture": {"std_db": 3.0, "correlation_m": -1}}
    with pytest.raises(ConfigError) as err:
        sonarsim.load_scene(doc(planes=[plane]))
    assert err.value.key == "planes[0].texture.correlation_m"


def test_texture_round_trips_through_the_scene_file_and_reaches_the_plane():
    texture = {"std_db": 4.0, "correlation_m": [3.0, 1.0], "angle_deg": 45.0, "seed": 9, "covariance": "exponential"}
    scene = sonarsim.load_scene(doc(texture))
    assert scene.ground.texture == TextureSpec(4.0, (3.0, 1.0), 45.0, 9, "exponential")
    assert scene.ground.to_dict()["texture"] == texture
    assert sonarsim.load_scene(scene.to_dict()).ground == scene.ground
    assert scene.reflecting_planes[0].texture == scene.ground.texture
    # One length: isotropic; defaults elsewhere.
    assert sonarsim.load_scene(doc({"std_db": 2.0, "correlation_m": 1.5})).ground.texture == TextureSpec(2.0, (1.5, 1.5))
    with pytest.raises(ConfigError):
        GroundSpec(texture={"std_db": 1.0})  # a spec, not a mapping, from Python


def test_plane_axes_are_orthonormal_and_world_x_y_on_the_ground():
    np.testing.assert_allclose(plane_axes((0.0, 0.0, 1.0)), [[1, 0, 0], [0, 1, 0]])
    rng = np.random.default_rng(0)
    for n in list(rng.normal(size=(20, 3))) + [np.array([1.0, 0, 0]), np.array([0, 0, -1.0])]:
        n = n / np.linalg.norm(n)
        ax = plane_axes(n)
        np.testing.assert_allclose(ax @ ax.T, np.eye(2), atol=1e-12)
        np.testing.assert_allclose(ax @ n, 0.0, atol=1e-12)


# The field against its closed form -------------------------------------------------------------


@pytest.mark.parametrize("covariance", ["gaussian", "exponential"])
def test_field_has_zero_mean_unit_variance_and_the_configured_spread_in_db(covariance):
    rng = np.random.default_rng(42)
    std_db = 3.0
    g, f = [], []
    for field in fields(covariance, std_db):
        pts = period_points(field, 200_000, rng)
        g.append(field.log_field(pts))
        f.append(field.factor(pts))
    g, f = np.concatenate(g), np.concatenate(f)
    field = fields(covariance)[0]
    se_mean = standard_error(covariance, field, INTEGRAL[covariance])
    se_var = standard_error(covariance, field, 2 * INTEGRAL_SQ[covariance])
    assert abs(g.mean()) < 4 * se_mean
    assert abs(g.var() - 1.0) < 4 * se_var
    s2 = (std_db * math.log(10) / 10) ** 2
    # exp(s^2 C) - 1 <= (exp(s^2) - 1) C: a bound on the factor's correlation integral.
    se_factor = math.sqrt(math.expm1(s2)) * se_mean
    assert abs(f.mean() - 1.0) < 4 * se_factor
    db = 10 * np.log10(f)
    assert abs(db.std() - std_db) < 4 * std_db * se_var
    assert (f > 0).all()


@pytest.mark.parametrize("covariance", ["gaussian", "exponential"])
def test_field_covariance_along_its_turned_axes_is_the_closed_form(covariance):
    rng = np.random.default_rng(7)
    field = fields(covariance)[0]
    a = math.radians(ANGLE_DEG)
    axes = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])  # the field's axes, world x-y
    lags = [(q, 0.0) for q in (0.25, 0.5, 1.0, 2.0)] + [(0.0, q) for q in (0.25, 0.5, 1.0, 2.0)] + [(0.7, 0.7)]
    se = standard_error(covariance, field, 2 * INTEGRAL_SQ[covariance])
    for q in lags:
        lag = (q[0] * LENGTHS_M[0]) * axes[0] + (q[1] * LENGTHS_M[1]) * axes[1]  # metres, world x-y
        products = []
        for f in fields(covariance):
            pts = period_points(f, 100_000, rng)
            products.append(f.log_field(pts) * f.log_field(pts + [lag[0], lag[1], 0.0]))
        got = float(np.mean(products))
        want = float(field_correlation(field.spec, lag))
        assert want == pytest.approx(math.exp(-(math.hypot(*q) ** (2 if covariance == "gaussian" else 1))))
        assert abs(got - want) < 4 * se + INTERPOLATION_BIAS, (q, got, want)


def test_the_variogram_is_anisotropic_as_configured():
    # Along the long axis the field stays correlated four times further than along the short one.
    rng = np.random.default_rng(3)
    field = fields("gaussian")[0]
    a = math.radians(ANGLE_DEG)
    long_axis, short_axis = np.array([math.cos(a), math.sin(a), 0]), np.array([-math.sin(a), math.cos(a), 0])
    pts = period_points(field, 200_000, rng)
    g = field.log_field(pts)

    def variogram(lag):
        return 0.5 * np.mean((field.log_field(pts + lag) - g) ** 2)

    assert variogram(0.5 * long_axis) < 0.15 < 0.5 < variogram(0.5 * short_axis)
    assert variogram(2.0 * long_axis) == pytest.approx(variogram(0.5 * short_axis), abs=0.08)


def test_the_tile_wraps_with_its_period_and_off_grid_points_are_smooth():
    field = fields("gaussian")[0]
    p1, p2 = field.period_m
    assert (p1, p2) == (TILE_CELLS / CELLS_PER_LENGTH["gaussian"] * LENGTHS_M[0],
                        TILE_CELLS / CELLS_PER_LENGTH["gaussian"] * LENGTHS_M[1])
    a = math.radians(ANGLE_DEG)
    shift = p1 * np.array([math.cos(a), math.sin(a), 0.0]) + 2 * p2 * np.array([-math.sin(a), math.cos(a), 0.0])
    pts = period_points(field, 1000, np.random.default_rng(1))
    np.testing.assert_allclose(field.log_field(pts + shift), field.log_field(pts), atol=1e-9)
    # Continuous: a micrometre moves g by far less than its spread.
    assert np.abs(field.log_field(pts + 1e-6) - field.log_field(pts)).max() < 1e-3


def test_fields_are_seeded_and_default_to_the_render_seed_and_the_plane():
    spec = TextureSpec(3.0, (1.0, 1.0))
    wall = PlaneSpec("wall", (5.0, 0, 0), (-1.0, 0, 0), 0.3, 1.0, None, spec)
    ground = GroundSpec(texture=spec)
    pts = np.random.default_rng(0).uniform(-20, 20, (500, 3)) * [1, 1, 0]
    a = texture_fields((ground, wall), render_seed=5)
    b = texture_fields((ground, wall), render_seed=5)
    c = texture_fields((ground, wall), render_seed=6)
    np.testing.assert_array_equal(a[0].factor(pts), b[0].factor(pts))
    assert not np.allclose(a[0].factor(pts), c[0].factor(pts))
    assert a[0].entropy != a[1].entropy  # two planes, two patterns
    # A seed of its own: the render seed no longer matters.
    seeded = GroundSpec(texture=TextureSpec(3.0, (1.0, 1.0), seed=8))
    np.testing.assert_array_equal(texture_fields((seeded,), 5)[0].factor(pts), texture_fields((seeded,), 6)[0].factor(pts))
    # No texture, or none to speak of: no field.
    assert texture_fields((GroundSpec(), GroundSpec(texture=TextureSpec(0.0))), 0) == (None, None)
