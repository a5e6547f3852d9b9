"""Estimating a floor texture from speckled images (:func:`sonarsim.scene.floor_texture.estimate_texture`).

Tolerances come from the floor seen: N independent patches (floor area over the correlation
area) estimate the texture's variance to about sqrt(2 / N) relative; here N is about 200, so
``std_db`` is known to about 5 % (three standard errors: 15 %) and each correlation length, a
ratio of lags fitted to that variance, to about 10 % (three: 30 %, 35 % across the beams, where
each row holds fewer blocks).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.config.scene import TextureSpec
from sonarsim.core.transforms import Pose
from sonarsim.scene.floor_texture import TEXTURE_STREAM, ReflectivityField, estimate_texture

STD_DB = 3.0
LENGTHS_M = (1.0, 0.4)
HEIGHT_M = 2.0


def floor_doc(std_db: float) -> dict:
    """A floor seen from 2 m, pitched 12 degrees down, lit from 3 to 19 m; speckle on.

    Cells: 2.5 cm in range, 0.25 degrees across (3 to 8 cm at the band's ranges): small against
    the texture's correlation lengths, 1 m along x (the sonar's range direction) and 0.4 m along y.
    """
    return {
        "sonar": {"n_beams": 96, "azimuth_fov_deg": 24.0, "elevation_fov_deg": 30.0, "range_min_m": 3.0,
                  "range_max_m": 19.0, "n_range_bins": 640,
                  "pose": {"position_m": [0.0, 0.0, HEIGHT_M], "rpy_deg": [0.0, 12.0, 0.0]}},
        "render": {"speckle": True, "seed": 0, "max_order": 1},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.0,
                   "texture": {"std_db": std_db, "correlation_m": list(LENGTHS_M), "seed": 11}},
    }


@pytest.fixture(scope="module")
def floor_frames():
    """Frames of the textured floor from four poses 20 m apart, and the expected untextured images."""
    textured, plain = sonarsim.Simulator(floor_doc(STD_DB)), sonarsim.Simulator(floor_doc(0.0))
    frames, expected, untextured = [], [], []
    for x in (0.0, 20.0, 40.0, 60.0):
        pose = Pose([x, 0.0, HEIGHT_M], [0.0, 12.0, 0.0])
        frames.append(textured.render(pose=pose).polar)
        expected.append(plain.render(pose=pose, speckle=False).polar)
        untextured.append(plain.render(pose=pose).polar)  # the floor without texture, speckled: the control
    sonar = textured.scene.sonar
    expected = np.array(expected)
    mask = expected[0] > 1e-2 * expected[0].max()  # the lit band
    return np.array(frames), expected, mask, sonar, np.array(untextured)


def test_estimate_recovers_the_texture_of_synthetic_renders(floor_frames):
    frames, expected, mask, sonar, _ = floor_frames
    est = estimate_texture(frames, sonar.range_m, sonar.azimuth_deg, mask=mask, expected=expected, height_m=HEIGHT_M)
    assert est.n_blocks > 40_000
    assert est.std_db == pytest.approx(STD_DB, rel=0.15)
    assert est.correlation_range_m == pytest.approx(LENGTHS_M[0], rel=0.30)
    assert est.correlation_across_m == pytest.approx(LENGTHS_M[1], rel=0.35)
    # The fitted model follows the empirical covariances.
    assert np.nanmax(np.abs(est.model_range - est.covariance_range)) < 0.05
    # Without the expected image (each row's mean removed only), larger blocks: the same answer.
    rough = estimate_texture(frames, sonar.range_m, sonar.azimuth_deg, mask=mask, height_m=HEIGHT_M, window=(4, 2))
    assert rough.std_db == pytest.approx(STD_DB, rel=0.15)
    assert rough.correlation_range_m == pytest.approx(LENGTHS_M[0], rel=0.30)
    assert rough.correlation_across_m == pytest.approx(LENGTHS_M[1], rel=0.35)


def test_estimate_finds_no_texture_in_speckle_alone(floor_frames):
    _, expected, mask, sonar, speckled = floor_frames
    est = estimate_texture(speckled, sonar.range_m, sonar.azimuth_deg, mask=mask, expected=expected, height_m=HEIGHT_M)
    # Against 3 dB (the speckle alone is 5.6 dB per cell). The estimate's noise floor: a variance
    # of about sqrt(2 / blocks) of the speckle's, fitted with free lengths (measured 0.24 dB
    # from four frames, 0.6 dB from one).
    assert est.std_db < 0.5


def test_estimate_recovers_an_exponential_covariance_sampled_directly():
    # The field sampled at the cells' floor points (no renderer), a range trend, unit speckle.
    r = np.linspace(5.0, 25.0, 800)
    az = np.linspace(8.0, -8.0, 64)
    ground = np.sqrt(r**2 - HEIGHT_M**2)
    rho, theta = np.meshgrid(ground, np.radians(az), indexing="ij")
    points = np.stack([rho * np.cos(theta), rho * np.sin(theta), np.zeros_like(rho)], axis=-1).reshape(-1, 3)
    trend = np.cos(np.radians(az))[None, :] ** 2 / r[:, None]
    rng = np.random.default_rng(5)
    got = []
    for seed in range(3):
        field = ReflectivityField(TextureSpec(STD_DB, LENGTHS_M, 0.0, None, "exponential"), (0, 0, 1),
                                  (seed, TEXTURE_STREAM))
        image = trend * field.factor(points).reshape(rho.shape) * rng.exponential(1.0, rho.shape)
        est = estimate_texture(image, r, az, expected=trend, covariance="exponential", height_m=HEIGHT_M)
        got.append((est.std_db, est.correlation_range_m, est.correlation_across_m))
    mean = np.mean(got, axis=0)
    # Three realisations of about 100 patches each.
    assert mean[0] == pytest.approx(STD_DB, rel=0.15)
    assert mean[1] == pytest.approx(LENGTHS_M[0], rel=0.30)
    assert mean[2] == pytest.approx(LENGTHS_M[1], rel=0.35)


def test_estimate_refuses_what_it_cannot_use():
    image = np.ones((40, 12))
    with pytest.raises(ValueError, match="one value per range bin"):
        estimate_texture(image, np.arange(39.0), np.arange(12.0))
    with pytest.raises(ValueError, match="blocks"):
        estimate_texture(image, np.arange(40.0), np.arange(12.0), mask=np.zeros((40, 12), bool))
    with pytest.raises(ValueError, match="window"):
        estimate_texture(image, np.arange(40.0), np.arange(12.0), window=(20, 5))
    assert math.isfinite(estimate_texture(image * np.random.default_rng(0).exponential(1.0, image.shape),
                                          np.arange(40.0) + 5, np.linspace(10, -10, 12)).std_db)
