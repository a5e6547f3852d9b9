"""Speckle as devices record it: several looks averaged in intensity, the K texture per cell
after the point-spread; seeded statistics against their closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import special, stats

from sonarsim.config.sensor import SpeckleSpec, parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor import speckle as speckle_mod
from sonarsim.sensor.model import SensorModel
from tests.sensor.test_physics import small_sonar
from tests.sensor.test_stage import intensity_acf_one_over_e, uniform_model

GRAIN = {"azimuth_pattern": {"shape": "gaussian", "width_deg": 1.5, "leakage_beams": 8},
         "pulse": {"kind": "cw", "length_us": 20.0}}


@pytest.mark.parametrize("looks", [1.0, 1.3, 2.0, 3.7, 8.0, 17.5, 64.0])
def test_look_weights_sum_to_one_with_the_contrast_of_their_count(looks):
    w = speckle_mod.look_weights(looks)
    assert len(w) == int(np.ceil(looks))
    assert np.all(w >= 0)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    # Independent unit exponentials: Var(sum w_l E_l) = sum w_l^2 = 1 / L.
    assert np.sum(w ** 2) == pytest.approx(1.0 / looks, rel=1e-9)


@pytest.mark.parametrize("looks", [1.0, 4.0, 9.5])
def test_multi_look_speckle_has_contrast_one_over_root_looks(looks):
    m, x = uniform_model(speckle={"model": "rayleigh", "looks": looks}, **GRAIN)
    p = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(6)]).astype(float)
    assert p.mean() == pytest.approx(1.0, abs=0.02)
    assert p.std() / p.mean() == pytest.approx(1.0 / np.sqrt(looks), rel=0.04)


@pytest.mark.parametrize("looks", [2.0, 6.0])
def test_integer_looks_give_the_gamma_law_and_its_log_variance_is_trigamma(looks):
    m, x = uniform_model(speckle={"model": "rayleigh", "looks": looks})
    p = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(4)]).astype(float)
    sample = p[::5]
    assert stats.kstest(sample, stats.gamma(looks, scale=1.0 / looks).cdf).statistic < 0.015
    # Var[ln S] of a gamma(L) intensity is the trigamma function psi_1(L); its skewness
    # psi_2(L) / psi_1(L)^1.5 (-1.14 for one look, towards 0 as L grows).
    log_p = np.log(sample[sample > 0])
    assert np.var(log_p) == pytest.approx(special.polygamma(1, looks), rel=0.05)
    assert stats.skew(log_p) == pytest.approx(special.polygamma(2, looks) / special.polygamma(1, looks) ** 1.5,
                                              abs=0.05)


def test_looks_keep_the_grain_of_one_look():
    one, x = uniform_model(speckle={"model": "rayleigh"}, **GRAIN)
    many, _ = uniform_model(speckle={"model": "rayleigh", "looks": 5.0}, **GRAIN)
    for axis in (0, 1):
        g1 = np.mean([intensity_acf_one_over_e(one.apply(x, np.random.default_rng(k)).astype(float), axis)
                      for k in range(3)])
        g5 = np.mean([intensity_acf_one_over_e(many.apply(x, np.random.default_rng(k)).astype(float), axis)
                      for k in range(3)])
        assert g5 == pytest.approx(g1, rel=0.1)


def test_the_pool_and_the_full_reference_agree_in_mean_and_contrast():
    # The reference averages every look in full (echo and noise); the pool stores one field whose
    # intensity is the looks' average. Where the echo dominates the two laws are the same.
    looks = 4.0
    m, x = uniform_model(speckle={"model": "rayleigh", "looks": looks}, **GRAIN)
    pool = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(3)]).astype(float)
    ref = np.concatenate([m.reference(x, np.random.default_rng(10 + k))[40:-40, 8:-8].ravel()
                          for k in range(3)]).astype(float)
    assert ref.mean() == pytest.approx(pool.mean(), rel=0.02)
    assert ref.std() / ref.mean() == pytest.approx(pool.std() / pool.mean(), rel=0.05)
    assert ref.std() / ref.mean() == pytest.approx(0.5, rel=0.05)


def test_multi_look_noise_is_averaged_over_the_looks_too():
    m, x = uniform_model(speckle={"model": "rayleigh", "looks": 4.0}, noise={"level_db": 0.0})
    mean = m.apply(0.0 * x, speckle=False).astype(float)  # the noise through the TVG, row by row
    p = np.concatenate([(m.apply(0.0 * x, np.random.default_rng(k)) / mean).ravel() for k in range(4)])
    assert p.mean() == pytest.approx(1.0, abs=0.02)
    assert p.std() / p.mean() == pytest.approx(0.5, rel=0.05)


@pytest.mark.parametrize("nu", [0.5, 2.0])
def test_the_k_texture_multiplies_each_cell_after_the_point_spread(nu):
    # Compound law: I = tau E, tau ~ gamma(nu, 1/nu), E exponential: E[I^2] = 2 (1 + 1/nu) for a
    # unit mean, whatever the point-spread. A texture drawn per scatterer before the point-spread
    # is averaged over the cells it spans and gives less (4.1 instead of 6 at nu = 0.5 here).
    m, x = uniform_model(speckle={"model": "k", "k_shape": nu}, **GRAIN)
    p = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(6)]).astype(float)
    assert p.mean() == pytest.approx(1.0, abs=0.03)
    assert np.mean(p ** 2) / p.mean() ** 2 == pytest.approx(2.0 * (1.0 + 1.0 / nu), rel=0.06)
    with_looks, _ = uniform_model(speckle={"model": "k", "k_shape": nu, "looks": 3.0}, **GRAIN)
    q = np.concatenate([with_looks.apply(x, np.random.default_rng(k)).ravel() for k in range(6)]).astype(float)
    # tau S_L, both unit mean and independent: E[I^2] = (1 + 1/nu)(1 + 1/L).
    assert np.mean(q ** 2) / q.mean() ** 2 == pytest.approx((1.0 + 1.0 / nu) * (1.0 + 1.0 / 3.0), rel=0.06)


@pytest.mark.parametrize("looks", [1.0, 3.0, 12.0])
def test_the_expected_output_is_the_mean_of_speckled_frames(looks):
    out = {"compression": "log", "floor_db": -25.0, "ceiling_db": 15.0, "dtype": "uint8"}
    m, x = uniform_model(speckle={"model": "rayleigh", "looks": looks}, output=out)
    frames = np.stack([m.apply(x, np.random.default_rng(k)) for k in range(6)]).astype(float)
    expected = m.apply(x, speckle=False).astype(float)
    assert frames.mean() == pytest.approx(expected.mean(), abs=0.15)
    # The log's mean falls below the mean power's level by psi(L) - ln L (Euler's 2.51 dB at one
    # look, 0.04 dB at 12): more looks, brighter log images.
    shortfall_db = 10.0 / np.log(10.0) * (np.log(looks) - special.digamma(looks))
    assert expected.mean() == pytest.approx((-shortfall_db + 25.0) / 40.0 * 255.0, abs=0.3)


def test_looks_are_bounded_and_named_in_errors():
    for bad in (0.5, 65.0, float("nan"), "four"):
        with pytest.raises(ConfigError) as e:
            parse_sensor({"speckle": {"looks": bad}})
        assert e.value.key == "sensor.speckle.looks"
    assert SpeckleSpec(looks=1.0).exponential and not SpeckleSpec(looks=2.0).exponential
    assert not SpeckleSpec(model="k").exponential


def test_one_look_keeps_the_pool_it_had():
    # Seeds keep their images: one Rayleigh look draws exactly what the pool drew before looks.
    sonar = small_sonar()
    m = SensorModel(parse_sensor({"speckle": {"model": "rayleigh"}}), sonar, seed=3)
    rng = speckle_mod.pool_rng(3)
    w = speckle_mod.complex_gaussian(rng, (sonar.n_range_bins, sonar.n_beams))
    f = speckle_mod.filter_field(w, m.range_amplitude, m.beam_amplitude)
    np.testing.assert_allclose(m.pool.field("speckle", 0), f, atol=1.5 * m.pool.speckle_scale)


# Calibration recovers the looks ----------------------------------------------------------------

@pytest.mark.parametrize("looks, output", [  # the asymmetry flattens with many looks: 25 % at 16
    (1.0, {"compression": "log", "floor_db": -30.0, "ceiling_db": 15.0, "dtype": "uint8"}),
    (3.0, {"compression": "log", "floor_db": -30.0, "ceiling_db": 15.0, "dtype": "uint8"}),
    (7.0, {"compression": "gamma", "gamma": 0.6, "ceiling_db": 12.0, "dtype": "uint8"}),
    (16.0, {"compression": "log", "floor_db": -30.0, "ceiling_db": 15.0, "dtype": "uint8"}),
])
def test_calibration_recovers_the_looks_of_a_synthetic_recording(looks, output):
    from sonarsim.analysis.calibration import _fit_looks
    from sonarsim.core.transforms import Pose

    truth, x = uniform_model(speckle={"model": "rayleigh", "looks": looks}, output=output, **GRAIN)
    recording = np.concatenate([truth.apply(x, np.random.default_rng(100 + k)) for k in range(3)])
    total = np.concatenate([x] * 3)
    sonar = small_sonar(n_range_bins=3 * 450, range_max_m=0.5 + 3 * 4.5)
    # The model starts from one look and another output shape (0.35 instead of 0.6; a span of
    # 60 dB instead of 45): the skewness in the log domain does not see the scale.
    wrong = dict(output)
    if wrong["compression"] == "gamma":
        wrong["gamma"] = 0.35
    else:
        wrong["floor_db"] = -45.0
    start = parse_sensor({"source_level_db": 0.0, "tvg": {"spreading": 20, "absorption": False},
                          "speckle": {"model": "rayleigh"}, "output": wrong, **GRAIN})
    lit = np.ones(recording.shape, bool)
    fitted = _fit_looks(recording, start, sonar, total, 5, Pose(), lit)
    assert fitted.speckle.looks == pytest.approx(looks, rel=0.2 if looks < 10 else 0.3)


@pytest.mark.parametrize("speckle", [{"model": "rayleigh", "looks": 3.0}, {"model": "rayleigh", "looks": 2.4},
                                     {"model": "k", "k_shape": 1.5, "looks": 2.0}])
def test_the_expected_outputs_law_is_the_pools(speckle):
    # The expected output averages over the spec's intensity law, formed without the pool (a
    # calibration builds thousands of models); the pool's fields follow the same law.
    from sonarsim.sensor import output

    m, _ = uniform_model(speckle=speckle, **GRAIN)
    pool = np.abs(np.stack([m.pool.field("speckle", k) for k in range(m.pool.n_fields)])).ravel() ** 2
    q = m.speckle_quantiles()
    assert q is output.intensity_quantiles(speckle["model"], float(speckle.get("k_shape", 4.0)), speckle["looks"])
    assert stats.ks_2samp(pool[::13], q).statistic < 0.03
