"""The sensor stage per frame: seeded speckle statistics, grain against the point-spread,
the compiled loops against their NumPy twins, and the stage inside the renderer."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import sonarsim
from sonarsim.config.sensor import PatternSpec, SpeckleSpec, parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor import speckle as speckle_mod
from sonarsim.sensor.model import SensorModel
from tests.conftest import sonar_dict
from tests.sensor.test_physics import small_sonar

POWER_ONLY = {"source_level_db": 0.0, "tvg": {"spreading": 20, "absorption": False}}


def uniform_model(**sensor) -> tuple[SensorModel, np.ndarray]:
    sonar = small_sonar()
    m = SensorModel(parse_sensor({**POWER_ONLY, **sensor}), sonar, seed=1)
    x = np.ones((sonar.n_range_bins, sonar.n_beams), np.float32) / m.column_factor[None, :]
    return m, x


# Speckle statistics -------------------------------------------------------------------------

def test_fully_developed_speckle_is_exponential_with_rayleigh_amplitude():
    m, x = uniform_model(speckle={"model": "rayleigh"})
    p = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(4)])
    assert p.mean() == pytest.approx(1.0, abs=0.01)
    assert p.var() == pytest.approx(1.0, abs=0.03)  # exponential: variance = mean^2
    amp = np.sqrt(p[::7])
    assert stats.kstest(amp, stats.rayleigh(scale=np.sqrt(0.5)).cdf).statistic < 0.01


def test_k_distributed_speckle_has_the_variance_of_its_shape():
    nu = 2.0
    m, x = uniform_model(speckle={"model": "k", "k_shape": nu})
    p = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(4)])
    # Unit-mean K intensity (no point-spread): variance 1 + 2 / nu.
    assert p.mean() == pytest.approx(1.0, abs=0.02)
    assert p.var() == pytest.approx(1.0 + 2.0 / nu, rel=0.06)


def intensity_acf_one_over_e(p: np.ndarray, axis: int) -> float:
    r = p - p.mean()
    n = r.shape[axis]
    acf = [1.0] + [float(np.mean(np.take(r, range(0, n - k), axis) * np.take(r, range(k, n), axis)) / r.var())
                   for k in range(1, 12)]
    acf = np.array(acf)
    k = int(np.argmax(acf < np.exp(-1)))
    return k - 1 + (acf[k - 1] - np.exp(-1)) / (acf[k - 1] - acf[k])


@pytest.mark.parametrize("width_deg", [1.0, 2.0])
def test_speckle_grain_across_beams_follows_the_beam_width(width_deg):
    # Intensity correlation of filtered complex Gaussian noise: |sum_n h[n] h[n+k]|^2 (Siegert).
    m, x = uniform_model(speckle={"model": "rayleigh"},
                         azimuth_pattern={"shape": "gaussian", "width_deg": width_deg, "leakage_beams": 12})
    h = m.beam_amplitude
    predicted = np.array([np.sum(h[:len(h) - k] * h[k:]) ** 2 for k in range(12)])
    k = int(np.argmax(predicted < np.exp(-1)))
    expect = k - 1 + (predicted[k - 1] - np.exp(-1)) / (predicted[k - 1] - predicted[k])
    p = m.apply(x, np.random.default_rng(0)).astype(float)
    measured = intensity_acf_one_over_e(p, axis=1)
    assert measured == pytest.approx(expect, rel=0.1)
    # Closed form: a Gaussian power pattern of -3 dB width W has an amplitude of standard
    # deviation W / (2 sqrt(ln 2)); the intensity correlation exp(-k^2 / (2 s^2)) falls to 1/e
    # at k = s sqrt(2) = 0.849 W (beams of 0.5 degrees).
    assert measured == pytest.approx(np.sqrt(2) * width_deg / (2 * np.sqrt(np.log(2))) / 0.5, rel=0.08)


def test_speckle_grain_along_range_follows_the_pulse():
    dr = small_sonar().range_resolution_m  # 1 cm
    short, _ = uniform_model(speckle={"model": "rayleigh"}, pulse={"kind": "cw", "length_us": 5.0})
    long_, x = uniform_model(speckle={"model": "rayleigh"}, pulse={"kind": "cw", "length_us": 80.0})
    g_short = intensity_acf_one_over_e(short.apply(x, np.random.default_rng(0)).astype(float), axis=0)
    g_long = intensity_acf_one_over_e(long_.apply(x, np.random.default_rng(0)).astype(float), axis=0)
    # c tau / 2 = 6 cm = 6 bins for the long pulse: a gate's intensity correlation falls to 1/e
    # at about 0.4 of its length; the short pulse stays within a bin.
    assert g_short < 0.8
    assert g_long == pytest.approx(0.4 * 1500 * 80e-6 / 2 / dr, rel=0.2)


def test_pool_speckle_matches_fresh_scatterers_on_a_uniform_scene():
    m, x = uniform_model(speckle={"model": "rayleigh"}, azimuth_pattern={"shape": "line", "width_deg": 1.5},
                         pulse={"kind": "cw", "length_us": 30.0})
    fast = np.concatenate([m.apply(x, np.random.default_rng(k)).ravel() for k in range(2)])
    slow = np.concatenate([m.reference(x, np.random.default_rng(10 + k)).ravel() for k in range(2)])
    # The reference's zero padding darkens its edges: compare the interior.
    inner = lambda a: a.reshape(-1, *x.shape)[:, 10:-10, 10:-10].ravel()
    assert stats.ks_2samp(inner(fast), inner(slow)).statistic < 0.02


# Compiled loops against their NumPy twins --------------------------------------------------

FULL = {"preset": "aris3000-64"}


@pytest.fixture(scope="module")
def full_model():
    sonar = small_sonar(frequency_khz=1800.0)
    return SensorModel(parse_sensor(FULL), sonar, seed=3)


def scene_like(shape, seed=0):
    rng = np.random.default_rng(seed)
    x = (rng.random(shape) ** 4 * 3e-3).astype(np.float32)
    x[shape[0] // 2:, shape[1] // 3: shape[1] // 2] = 0.0  # a shadow: exact zeros
    x[40:45, 20] = 0.5  # a bright point
    return x


def test_blur_equals_its_numpy_twin(full_model):
    x = scene_like(full_model.pool.shape)
    np.testing.assert_allclose(full_model.mean_image(x), full_model.mean_image_reference(x), rtol=1e-5, atol=1e-12)


def test_combine_equals_its_numpy_twin_bit_for_bit_but_for_rounding_ties(full_model):
    x = scene_like(full_model.pool.shape)
    mean = full_model.mean_image_reference(x)
    for seed in range(3):
        fast = full_model.apply(x, np.random.default_rng(seed))
        ref = full_model.combine_reference(mean, full_model.draws(np.random.default_rng(seed)))
        diff = np.abs(fast - ref)
        assert diff.max() <= 1.0 and (diff > 0).mean() < 1e-3


def test_expected_output_equals_its_numpy_twin(full_model):
    x = scene_like(full_model.pool.shape)
    fast = full_model.apply(x, speckle=False)
    ref = full_model.combine_reference(full_model.mean_image_reference(x), None, speckle=False)
    np.testing.assert_allclose(fast, ref, atol=2e-3)


def test_expected_output_is_the_mean_of_speckled_frames(full_model):
    x = scene_like(full_model.pool.shape, 1)
    mean = np.mean([full_model.apply(x, np.random.default_rng(k)) for k in range(48)], axis=0)
    e = full_model.apply(x, speckle=False)
    # Per pixel, 48 frames of log speckle (5.6 dB std, 16 counts) average to within 2.3 counts;
    # over the whole image the bias must vanish.
    assert np.abs(mean - e).mean() < 2.5
    assert abs(mean.mean() - e.mean()) < 0.3


def test_rows_split_over_a_worker_give_the_same_frame(full_model):
    from concurrent.futures import ThreadPoolExecutor
    x = scene_like(full_model.pool.shape)
    with ThreadPoolExecutor(1) as pool:
        a = full_model.apply(x, np.random.default_rng(5), pool=pool)
    np.testing.assert_array_equal(a, full_model.apply(x, np.random.default_rng(5)))


def test_receiver_noise_is_lifted_by_tvg_with_range():
    m, x = uniform_model(noise={"level_db": 10.0}, tvg={"spreading": 40, "absorption": False},
                         speckle={"model": "rayleigh"})
    p = np.mean([m.apply(np.zeros_like(x), np.random.default_rng(k)) for k in range(8)], axis=(0, 2))
    expected = 10.0 * m.range_m ** 4  # N t(r), t = r^40/10
    ratio = p / expected
    assert ratio.mean() == pytest.approx(1.0, abs=0.02)
    np.testing.assert_allclose(ratio.reshape(9, 50).mean(axis=1), 1.0, atol=0.06)


def test_bang_brightens_the_first_ranges_and_decays():
    m, x = uniform_model(bang={"level_db": 30.0, "length_m": 0.1})
    p = m.apply(np.zeros_like(x), speckle=False)[:, 0]
    expected = 1e3 * np.exp(-m.range_m / 0.1) * m.range_m ** 2
    keep = expected > 1e-8  # the expected-output table ends 100 dB below 1 uPa^2
    np.testing.assert_allclose(p[keep], expected[keep], rtol=1e-4)
    assert np.argmax(p) < 30


# In the renderer ------------------------------------------------------------------------------

def tank(sensor=None, **render):
    d = {
        "sonar": sonar_dict(n_beams=48, n_range_bins=300, frequency_khz=1800.0,
                            pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 25, 0]}),
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
        "objects": [{"name": "box", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                     "pose": {"position_m": [3.0, 0.0, 0.2]}}],
        "render": {"seed": 4, **render},
    }
    if sensor is not None:
        d["sensor"] = sensor
    return d


def test_sensor_leaves_the_components_as_noise_free_ground_truth():
    plain = sonarsim.render(tank())
    sensed = sonarsim.render(tank({"preset": "aris3000-64", "elevation_pattern": False}))
    for k in ("object", "ground", "double", "triple", "total"):
        np.testing.assert_array_equal(plain.components[k], sensed.components[k])
    assert not np.array_equal(sensed.polar, plain.polar)
    assert np.all(sensed.polar == np.round(sensed.polar)) and sensed.polar.max() <= 255


def test_frames_are_reproducible_by_index_and_differ_between_indices():
    sim = sonarsim.Simulator(tank({"preset": "aris3000-64", "speckle": {"anchor": "frame"}}))
    a, b = sim.render(frame=7).polar, sim.render(frame=8).polar
    assert np.array_equal(sim.render(frame=7).polar, a)
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] < 0.99
    other = sonarsim.Simulator(tank({"preset": "aris3000-64", "speckle": {"anchor": "frame"}}))
    other.render(frame=1)
    assert np.array_equal(other.render(frame=7).polar, a)  # whoever renders it, in any order


def test_world_anchored_speckle_is_still_for_a_still_sonar_and_decorrelates_when_it_moves():
    sim = sonarsim.Simulator(tank({"preset": "aris3000-64", "noise": {"level_db": 75.0}}))
    pose = {"position_m": [0, 0, 1.0], "rpy_deg": [0, 25, 0]}
    moved = {"position_m": [0.05, 0, 1.0], "rpy_deg": [0, 25, 0]}
    a, b, c = sim.render(pose, frame=0).polar, sim.render(pose, frame=1).polar, sim.render(moved, frame=0).polar
    mean_a, mean_c = sim.render(pose, speckle=False).polar, sim.render(moved, speckle=False).polar
    lit = mean_a > 150  # echo far above the noise
    ra, rb, rc = a - mean_a, b - mean_a, c - mean_c
    # Still sonar: the same speckle, the receiver noise drawn anew (frames differ where it shows).
    assert np.corrcoef(ra[lit], rb[lit])[0, 1] > 0.9
    dark = (mean_a > 5) & (mean_a < 60)
    assert dark.sum() > 100 and np.corrcoef(ra[dark], rb[dark])[0, 1] < 0.5
    # Moved by 5 cm: new speckle.
    assert abs(np.corrcoef(ra[lit], rc[lit])[0, 1]) < 0.2


def test_no_speckle_gives_the_expected_output_deterministically():
    sim = sonarsim.Simulator(tank({"preset": "aris3000-64"}))
    e1, e2 = sim.render(speckle=False).polar, sim.render(speckle=False, frame=3).polar
    np.testing.assert_array_equal(e1, e2)
    assert not np.all(e1 == np.round(e1))  # an expectation, not a quantised draw


def test_elevation_sidelobes_return_floor_echo_beyond_the_nominal_aperture():
    base = {"source_level_db": 0.0, "tvg": {"spreading": 20, "absorption": False}}
    main = sonarsim.render(tank(base), speckle=False)
    lobes = sonarsim.render(tank({**base, "elevation_pattern": {"shape": "line", "window": "rect", "span_deg": 60}}),
                            speckle=False)
    col = main.polar.shape[1] - 6  # well clear of the box and its shadow
    # Past the floor's far edge in the 14-degree aperture, the sidelobes keep returning echo.
    far = np.flatnonzero(main.components["ground"][:, col] > 0).max() + 20
    assert far < main.polar.shape[0] - 20
    assert not main.components["ground"][far:, col].any()
    beyond = lobes.components["ground"][far:, col]
    assert beyond.min() > 0
    assert beyond.max() < 0.1 * lobes.components["ground"][:, col].max()  # sidelobes, weak


def test_sensor_scene_errors_name_the_key():
    with pytest.raises(ConfigError, match="render.tvg"):
        sonarsim.load_scene(tank({"preset": "aris3000-64"}, tvg=False))
    with pytest.raises(ConfigError, match="render.speckle"):
        sonarsim.load_scene(tank({"preset": "aris3000-64"}, speckle=True))
    with pytest.raises(ConfigError, match="sensor.absorption"):
        d = tank({"absorption": {"model": "francois-garrison"}})
        d["sonar"].pop("frequency_khz")
        sonarsim.render(d)


@pytest.mark.parametrize("sensor", [
    {"output": {"compression": "gamma", "gamma": 0.05, "ceiling_db": 150.0, "dtype": "uint8"}},
    {"output": {"compression": "gamma", "gamma": 0.3, "ceiling_db": 150.0, "dtype": "float32"},
     "speckle": {"model": "k", "k_shape": 1.5}, "noise": {"level_db": 60.0, "after_tvg_db": 110.0}},
])
def test_gamma_k_and_after_tvg_noise_twins_agree_with_exact_zeros(sensor):
    sonar = small_sonar(frequency_khz=1800.0)
    m = SensorModel(parse_sensor({"preset": "aris3000-64", **sensor}), sonar, seed=5)
    x = scene_like(m.pool.shape)
    fast = m.apply(x, np.random.default_rng(2))
    ref = m.combine_reference(m.mean_image_reference(x), m.draws(np.random.default_rng(2)))
    tol = 1.0 if sensor["output"]["dtype"] == "uint8" else 1e-4
    assert np.abs(fast - ref).max() <= tol and (np.abs(fast - ref) > 1e-4).mean() < 1e-3
    np.testing.assert_allclose(m.apply(x, speckle=False),
                               m.combine_reference(m.mean_image_reference(x), None, speckle=False), atol=2e-3)


def test_no_power_gives_no_output_under_gamma():
    m, x = uniform_model(output={"compression": "gamma", "gamma": 0.05, "ceiling_db": 0.0, "dtype": "uint8"})
    assert not m.apply(np.zeros_like(x)).any()


def test_apply_refuses_an_image_of_another_grid():
    m, x = uniform_model()
    with pytest.raises(ValueError, match="shape"):
        m.apply(np.zeros((x.shape[0] * 2, x.shape[1]), np.float32))


def test_bad_sensor_presets_and_k_shape_are_config_errors():
    with pytest.raises(ConfigError, match="sensor.preset"):
        parse_sensor({"preset": ["a"]})
    with pytest.raises(ConfigError, match="sensor.speckle.k_shape"):
        parse_sensor({"speckle": {"model": "k", "k_shape": 1e-300}})


def test_the_stages_inlined_logarithm_is_within_float_rounding_of_numpys():
    _stage = pytest.importorskip("sonarsim.sensor._stage")
    # Every binade from the stage's floor (1e-30) to 1e30, densely, and the range-reduction's
    # seams (2/3 and 4/3 of each power of two).
    x = np.concatenate([np.logspace(-30, 30, 1_000_001), 2.0 ** np.arange(-99, 99)[:, None] * [2 / 3, 4 / 3]],
                       axis=None).astype(np.float32)
    out = np.empty_like(x)
    _stage.ln(x, out)
    exact = np.log(x.astype(np.float64))
    # Absolute error in ln is relative error in power: 2e-7 is 1e-6 dB; beyond it, only the two
    # float32 roundings at the size of ln x (e ln 2 and the sum: an ulp of ln x, 7.6e-6 near
    # ln x = +-69, with half an ulp to spare).
    ulp = np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(out - exact) <= 2e-7 + 1.5 * ulp)
    assert np.median(np.abs(out - exact)) < 2e-6


def _builds():
    base = pytest.importorskip("sonarsim.sensor._stage")
    builds = [base]
    if base.has_avx2_fma():
        from sonarsim.sensor import _stage_avx2
        builds.append(_stage_avx2)
    return builds


def test_both_builds_of_the_stage_equal_the_numpy_twin(full_model, monkeypatch):
    # The AVX2/FMA build rounds differently (fused multiply-adds): each build against the
    # reference, and both builds against each other, to the rounding of a quantisation tie.
    from sonarsim.sensor import model as model_mod
    x = scene_like(full_model.pool.shape)
    ref = full_model.combine_reference(full_model.mean_image_reference(x), full_model.draws(np.random.default_rng(4)))
    outs = []
    for build in _builds():
        monkeypatch.setattr(model_mod, "_stage", build)
        fast = full_model.apply(x, np.random.default_rng(4))
        diff = np.abs(fast - ref)
        assert diff.max() <= 1.0 and (diff > 0).mean() < 1e-3, build.__name__
        np.testing.assert_allclose(full_model.apply(x, speckle=False),
                                   full_model.combine_reference(full_model.mean_image_reference(x), None, speckle=False),
                                   atol=2e-3)
        outs.append(fast)
    assert all((np.abs(o - outs[0]) > 0).mean() < 1e-3 for o in outs)


def test_the_baseline_build_can_be_forced(monkeypatch):
    from sonarsim.sensor import model as model_mod
    monkeypatch.setenv("SONARSIM_SIMD", "baseline")
    assert model_mod._choose_stage().__name__ == "sonarsim.sensor._stage"
    monkeypatch.delenv("SONARSIM_SIMD")
    expected = "sonarsim.sensor._stage_avx2" if _builds()[0].has_avx2_fma() else "sonarsim.sensor._stage"
    assert model_mod._choose_stage().__name__ == expected
