"""The receive channels' structure (sonarsim.sensor.channels) against closed forms and seeded
statistics: the across-fan gain of a steered array, stripes, the bang's pattern across beams and
its ringing, noise common to a row's beams; the compiled stage against its NumPy twin with each;
the section's validation."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.config.sensor import BangSpec, BeamGainSpec, NoiseSpec, parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor import channels
from sonarsim.sensor.model import SensorModel
from tests.sensor.test_physics import small_sonar
from tests.sensor.test_stage import POWER_ONLY, scene_like, tank

# Received power out (no output chain), no absorption: P = t(r) G_j |a|^2 with t = r^2.
WIDE = dict(n_beams=64, azimuth_fov_deg=120.0)


def model(sonar=None, seed=1, fields=True, **sensor) -> SensorModel:
    return SensorModel(parse_sensor({**POWER_ONLY, **sensor}), sonar or small_sonar(), seed=seed, fields=fields)


def uniform(m: SensorModel) -> np.ndarray:
    """An image whose mean power at the receiver is 1 uPa^2 / r^2 in every bin (t(r) g(r) M = 1)."""
    return np.ones(m.pool.shape, np.float32) / m.column_factor[None, :]


# The across-fan gain of a steered array --------------------------------------------------------

@pytest.mark.parametrize("n", [1.0, 4.0, 30.0])
def test_the_expected_beam_profile_of_a_uniform_scene_follows_cos_n_of_the_steering_angle(n):
    sonar = small_sonar(**WIDE)
    theta = np.radians(sonar.azimuth_deg)
    # Through the expected-output law of a log output: E[out] = FS (10 log10 P + E[10 log10 S]
    # - floor) / span for exponential speckle S, so differences across beams are the gain in dB.
    # (gain_db keeps the edge beams, 87 dB down for n = 30, within the expected-output table.)
    m = model(sonar, speckle={"model": "rayleigh"}, beam_gain={"steering_exponent": n}, gain_db=60.0,
              output={"compression": "log", "floor_db": -100.0, "ceiling_db": 100.0, "dtype": "float32"})
    profile_db = m.apply(uniform(m), speckle=False).mean(axis=0) * 200.0
    expect_db = 10.0 * n * np.log10(np.cos(theta))
    np.testing.assert_allclose(profile_db - profile_db.max(), expect_db - expect_db.max(), atol=2e-3)
    # The received power itself: cos^n times the speckled frames' mean, within seeded error.
    p = model(sonar, speckle={"model": "rayleigh"}, beam_gain={"steering_exponent": n})
    frames = np.mean([p.apply(uniform(p), np.random.default_rng(k)) for k in range(4)], axis=(0, 1))
    assert np.max(np.abs(10 * np.log10(frames) - expect_db)) < 0.35  # 1800 exponential samples a beam


def test_an_aris_like_fan_loses_9_db_from_centre_to_edge():
    # The ARIS figure: 9 dB over 15 degrees is n = 9 / -10 log10 cos(15 deg) = 60.
    sonar = small_sonar(n_beams=128, azimuth_fov_deg=30.0)
    n = 9.0 / -(10.0 * np.log10(np.cos(np.radians(15.0))))
    assert 55 < n < 65
    assert channels.steering_gain_db([15.0, -15.0], n) == pytest.approx([-9.0, -9.0], abs=1e-12)
    g = channels.beam_gain_db(BeamGainSpec(steering_exponent=n), sonar.azimuth_deg)
    assert g.max() - g.min() == pytest.approx(9.0, abs=0.2)  # the edge beams' centres: 14.9 degrees


def test_steering_gain_at_known_angles():
    np.testing.assert_allclose(channels.steering_gain_db([0.0, 60.0, -60.0], 2.0),
                               [0.0, 20 * np.log10(0.5), 20 * np.log10(0.5)], atol=1e-12)


# Stripes ---------------------------------------------------------------------------------------

def test_given_stripes_set_each_beams_mean_power():
    sonar = small_sonar()
    gains = np.random.default_rng(0).uniform(-6, 6, sonar.n_beams)
    m = model(sonar, speckle={"model": "rayleigh"}, beam_gain={"gain_db": gains.tolist()})
    x = uniform(m)
    np.testing.assert_allclose(m.apply(x, speckle=False), np.broadcast_to(10 ** (gains / 10), x.shape), rtol=1e-4)
    frames = np.mean([m.apply(x, np.random.default_rng(k)) for k in range(4)], axis=(0, 1))
    ratio_db = 10 * np.log10(frames) - gains
    assert np.max(np.abs(ratio_db)) < 0.35 and abs(ratio_db.mean()) < 0.05


def test_seeded_stripes_have_their_spread_and_the_scenes_seed():
    sonar = small_sonar(n_beams=512, azimuth_fov_deg=60.0)
    spec = {"beam_gain": {"std_db": 1.5}}
    a, b, other = model(sonar, 7, **spec), model(sonar, 7, **spec), model(sonar, 8, **spec)
    np.testing.assert_array_equal(a.beam_gain, b.beam_gain)  # a function of the seed
    assert not np.allclose(a.beam_gain_db, other.beam_gain_db)
    assert a.beam_gain_db.mean() == pytest.approx(0.0, abs=1e-12)  # the fan's level is gain_db's
    assert a.beam_gain_db.std() == pytest.approx(1.5, rel=0.1)  # 512 draws: 3 % standard error
    # Stripes do not move when the bang's pattern is drawn too (separate streams).
    c = model(sonar, 7, **spec, bang={"level_db": 30.0, "beam_std_db": 2.0})
    np.testing.assert_array_equal(a.beam_gain, c.beam_gain)
    assert not np.allclose(c.bang_beam_db, c.beam_gain_db)


# The bang across beams, and its ringing --------------------------------------------------------

def test_the_bang_repeats_its_pattern_across_beams_while_the_speckle_is_new():
    sonar = small_sonar()
    pattern = np.random.default_rng(3).normal(0.0, 3.0, sonar.n_beams)
    m = model(sonar, speckle={"model": "rayleigh", "anchor": "frame"},
              bang={"level_db": 60.0, "length_m": 0.3, "beam_db": pattern.tolist()})
    zero = np.zeros(m.pool.shape, np.float32)
    near = slice(0, 60)  # 0.5-1.1 m: the bang is the only power there is
    expected = m.apply(zero, speckle=False)[near]
    bang_row = 1e6 * np.exp(-m.range_m[near] / 0.3) * m.range_m[near] ** 2
    np.testing.assert_allclose(expected, bang_row[:, None] * 10 ** (pattern / 10)[None, :], rtol=1e-4)
    a, b = m.apply(zero, np.random.default_rng(1))[near], m.apply(zero, np.random.default_rng(2))[near]
    per_beam = [10 * np.log10((f / bang_row[:, None]).mean(axis=0)) for f in (a, b)]
    # 60 exponential samples a beam: 0.56 dB of error against a 3 dB pattern.
    assert np.corrcoef(per_beam[0], pattern)[0, 1] > 0.9 and np.corrcoef(per_beam[1], pattern)[0, 1] > 0.9
    assert np.corrcoef(per_beam[0], per_beam[1])[0, 1] > 0.85
    assert abs(np.corrcoef((a / expected).ravel(), (b / expected).ravel())[0, 1]) < 0.05  # new speckle


def test_ringing_adds_a_periodic_tail_to_the_bang():
    spec = BangSpec(level_db=30.0, length_m=0.05, ringing_db=20.0, ringing_length_m=1.0, ringing_period_m=0.4)
    r = np.linspace(0.0, 3.0, 301)
    by_hand = 1e3 * np.exp(-r / 0.05) + 1e2 * np.exp(-r / 1.0) * np.cos(np.pi * r / 0.4) ** 2
    np.testing.assert_allclose(channels.bang_row(spec, r), by_hand, rtol=1e-12)
    smooth = BangSpec(level_db=30.0, length_m=0.05, ringing_db=20.0, ringing_length_m=1.0)
    np.testing.assert_allclose(channels.bang_row(smooth, r), 1e3 * np.exp(-r / 0.05) + 1e2 * np.exp(-r), rtol=1e-12)
    m = model(bang={"level_db": 30.0, "length_m": 0.05, "ringing_db": 20.0, "ringing_length_m": 1.0,
                    "ringing_period_m": 0.4})
    p = m.apply(np.zeros(m.pool.shape, np.float32), speckle=False)[:, 5]
    expect = channels.bang_row(spec, m.range_m) * m.range_m ** 2
    keep = expect > 1e-6
    np.testing.assert_allclose(p[keep], expect[keep], rtol=1e-4)
    # Its minima fall at odd multiples of half the period.
    troughs = m.range_m[np.flatnonzero((p[1:-1] < p[:-2]) & (p[1:-1] < p[2:])) + 1]
    np.testing.assert_allclose(troughs[:4], [0.6, 1.0, 1.4, 1.8], atol=0.011)


# Noise common to a row's beams -----------------------------------------------------------------

def across_beam_intensity_correlation(frames: np.ndarray, mean_row: np.ndarray) -> np.ndarray:
    """Per row, the correlation of two different beams' intensities over frames and beam pairs."""
    u = frames / mean_row[None, :, None] - 1.0  # unit-mean exponential intensities, less 1
    n = u.shape[2]
    s = u.sum(axis=2)
    pairs = (s ** 2 - (u ** 2).sum(axis=2)) / (n * (n - 1))
    return pairs.mean(axis=0) / (u ** 2).mean(axis=(0, 2))


def test_common_noise_correlates_beams_by_its_share_of_the_noise_and_decays_with_range():
    n_db, length = 50.0, 1.0
    c0_db = n_db + 10 * np.log10(4.0 * np.exp(0.5 / length))  # 4 N at the first bin (0.5 m)
    m = model(noise={"level_db": n_db, "common_db": float(c0_db), "common_length_m": length})
    zero = np.zeros(m.pool.shape, np.float32)
    frames = np.stack([m.apply(zero, np.random.default_rng(k)) for k in range(48)])
    n = 10 ** (n_db / 10)
    c = 10 ** (c0_db / 10) * np.exp(-m.range_m / length)
    t = m.range_m ** 2
    # The expected output adds the common noise's power.
    np.testing.assert_allclose(m.apply(zero, speckle=False)[:, 0], t * (n + c), rtol=1e-4)
    # Two beams' amplitudes correlate by rho = C / (C + N); complex Gaussian intensities by rho^2
    # (Siegert). Bands of 50 rows x 48 frames.
    rho = c / (c + n)
    measured = across_beam_intensity_correlation(frames, t * (n + c)).reshape(9, 50).mean(axis=1)
    np.testing.assert_allclose(measured, (rho ** 2).reshape(9, 50).mean(axis=1), atol=0.04)
    assert measured[0] > 0.45 and measured[-1] < 0.03
    # The decay: log(C / N) = log(rho / (1 - rho)) falls by 1 / L per metre.
    r_band = m.range_m.reshape(9, 50).mean(axis=1)
    rho_band = np.sqrt(measured[:5])
    slope = np.polyfit(r_band[:5], np.log(rho_band / (1 - rho_band)), 1)[0]
    assert slope == pytest.approx(-1.0 / length, rel=0.15)


def test_common_noise_is_the_frames_and_independent_of_the_speckle_seed():
    m = model(speckle={"model": "rayleigh"}, noise={"level_db": 30.0, "common_db": 60.0})
    x = uniform(m)
    a = m.apply(x, np.random.default_rng(0), noise_rng=np.random.default_rng(1))
    assert np.array_equal(a, m.apply(x, np.random.default_rng(0), noise_rng=np.random.default_rng(1)))
    b = m.apply(x, np.random.default_rng(0), noise_rng=np.random.default_rng(2))
    # The row noise dominates: the same speckle under new common noise gives another frame.
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] < 0.5


def test_common_noise_amplitude_has_its_power_and_the_receivers_band():
    rng = np.random.default_rng(5)
    kernel = np.array([0.5, np.sqrt(0.5), 0.5])  # squares sum to 1
    z = np.stack([channels.common_noise_amplitude(np.full(400, 9.0), kernel, rng) for _ in range(200)])
    assert np.mean(np.abs(z) ** 2) == pytest.approx(9.0, rel=0.02)
    lag1 = np.mean(z[:, 1:] * np.conj(z[:, :-1])).real / 9.0
    assert lag1 == pytest.approx(2 * 0.5 * np.sqrt(0.5), abs=0.02)  # sum_m k[m] k[m+1]
    np.testing.assert_allclose(channels.common_noise_power(NoiseSpec(common_db=10.0, common_length_m=2.0),
                                                           np.array([0.0, 2.0])), [10.0, 10.0 / np.e])
    assert not channels.common_noise_power(NoiseSpec(), np.ones(3)).any()


# The compiled stage against its NumPy twin, with each effect -----------------------------------

EFFECTS = {
    "steering": {"beam_gain": {"steering_exponent": 40.0}},
    "stripes": {"beam_gain": {"gain_db": np.linspace(-5, 5, 64).tolist(), "std_db": 1.0}},
    "bang": {"bang": {"level_db": 130.0, "length_m": 0.2, "ringing_db": 100.0, "ringing_length_m": 1.0,
                      "ringing_period_m": 0.1, "beam_std_db": 3.0}},
    "common": {"noise": {"level_db": 60.0, "common_db": 75.0, "common_length_m": 1.5}},
    "common, no speckle": {"speckle": False, "noise": {"level_db": 60.0, "common_db": 75.0}},
    "all, float32 gamma": {"beam_gain": {"steering_exponent": 10.0, "std_db": 2.0},
                           "bang": {"level_db": 130.0, "length_m": 0.2, "beam_db": np.linspace(3, -3, 64).tolist()},
                           "noise": {"level_db": 60.0, "common_db": 80.0, "common_length_m": 0.5},
                           "output": {"compression": "gamma", "gamma": 0.3, "ceiling_db": 150.0, "dtype": "float32"}},
}


def _builds():
    base = pytest.importorskip("sonarsim.sensor._stage")
    builds = [base]
    if base.has_avx2_fma():
        from sonarsim.sensor import _stage_avx2
        builds.append(_stage_avx2)
    return builds


@pytest.mark.parametrize("name", list(EFFECTS))
def test_each_effect_in_both_builds_equals_the_numpy_twin(name, monkeypatch):
    from sonarsim.sensor import model as model_mod
    sensor = EFFECTS[name]
    m = SensorModel(parse_sensor({"preset": "aris3000-64", **sensor}), small_sonar(frequency_khz=1800.0), seed=5)
    x = scene_like(m.pool.shape)
    tol = 1e-4 if "float32" in name else 1.0
    for build in _builds():
        monkeypatch.setattr(model_mod, "_stage", build)
        for seed in range(2):
            fast = m.apply(x, np.random.default_rng(seed))
            ref = m.combine_reference(m.mean_image_reference(x), m.draws(np.random.default_rng(seed)))
            diff = np.abs(fast - ref)
            assert diff.max() <= tol and (diff > 1e-4).mean() < 1e-3, build.__name__
        np.testing.assert_allclose(m.apply(x, speckle=False),
                                   m.combine_reference(m.mean_image_reference(x), None, speckle=False), atol=2e-3)


def test_factors_of_one_leave_the_frame_bit_for_bit():
    sonar = small_sonar(frequency_khz=1800.0)
    base = {"preset": "aris3000-64", "noise": {"level_db": 60.0}}
    plain = SensorModel(parse_sensor(base), sonar, seed=5)
    ones = SensorModel(parse_sensor({**base, "beam_gain": {"steering_exponent": 0.0, "gain_db": [0.0] * 64},
                                     "bang": {"beam_db": [0.0] * 64}}), sonar, seed=5)
    x = scene_like(plain.pool.shape)
    np.testing.assert_array_equal(plain.apply(x, np.random.default_rng(3)), ones.apply(x, np.random.default_rng(3)))
    np.testing.assert_array_equal(plain.apply(x, speckle=False), ones.apply(x, speckle=False))


def test_the_reference_frame_carries_every_effect():
    m = model(speckle={"model": "rayleigh"}, beam_gain={"steering_exponent": 2.0, "gain_db": [3.0] * 64},
              noise={"level_db": -100.0, "common_db": -100.0})
    x = uniform(m)
    p = np.mean([m.reference(x, np.random.default_rng(k))[20:-20] for k in range(3)], axis=(0, 1))
    expect = 10 ** 0.3 * np.cos(np.radians(m.sonar.azimuth_deg)) ** 2
    np.testing.assert_allclose(p, expect, rtol=0.15)


def test_the_expected_output_without_fields_carries_every_effect():
    # What a calibration evaluates: SensorModel(spec, sonar, seed, fields=False).apply(x, speckle=False).
    sensor = {"beam_gain": {"steering_exponent": 5.0, "std_db": 1.0},
              "bang": {"level_db": 40.0, "length_m": 0.5, "beam_std_db": 2.0},
              "noise": {"level_db": 0.0, "common_db": 10.0, "common_length_m": 2.0}}
    m = model(fields=False, **sensor)
    x = uniform(m)
    t = m.range_m ** 2
    g = 10 ** (channels.beam_gain_db(m.spec.beam_gain, m.sonar.azimuth_deg,
                                     np.random.default_rng([1, 4, 0])) / 10)
    b = 10 ** (channels.bang_beam_db(m.spec.bang, 64, np.random.default_rng([1, 4, 1])) / 10)
    mu = 1 / t[:, None] + 1e4 * np.exp(-m.range_m / 0.5)[:, None] * b[None, :]
    expect = t[:, None] * g[None, :] * (mu + 1.0 + 10.0 * np.exp(-m.range_m / 2.0)[:, None])
    np.testing.assert_allclose(m.apply(x, speckle=False), expect, rtol=1e-4)


def test_a_frame_split_over_a_worker_is_the_same_with_every_effect():
    from concurrent.futures import ThreadPoolExecutor
    m = SensorModel(parse_sensor({"preset": "aris3000-64", **EFFECTS["all, float32 gamma"]}),
                    small_sonar(frequency_khz=1800.0), seed=5)
    x = scene_like(m.pool.shape)
    with ThreadPoolExecutor(1) as pool:
        a = m.apply(x, np.random.default_rng(5), pool=pool)
    np.testing.assert_array_equal(a, m.apply(x, np.random.default_rng(5)))


def test_rendered_frames_with_every_effect_are_reproducible_by_index():
    sensor = {"preset": "aris3000-64", "elevation_pattern": False, "speckle": {"anchor": "world"},
              "beam_gain": {"steering_exponent": 20.0, "std_db": 1.0},
              "bang": {"level_db": 120.0, "length_m": 0.3, "beam_std_db": 2.0},
              "noise": {"level_db": 50.0, "common_db": 70.0, "common_length_m": 1.0}}
    sim = sonarsim.Simulator(tank(sensor))
    a = sim.render(frame=3).polar
    other = sonarsim.Simulator(tank(sensor))
    other.render(frame=1)
    np.testing.assert_array_equal(other.render(frame=3).polar, a)
    # A still sonar: the speckle is the pose's, the receiver and common noise the frame's.
    assert not np.array_equal(sim.render(frame=4).polar[:40], a[:40])


# The section -----------------------------------------------------------------------------------

def test_the_new_keys_round_trip_through_the_scene_file_form():
    spec = parse_sensor({"beam_gain": {"steering_exponent": 2.5, "gain_db": [0.5, -1.0, 2.0], "std_db": 0.3},
                         "bang": {"ringing_db": 80.0, "ringing_length_m": 0.1, "ringing_period_m": 0.02,
                                  "beam_db": [1.0, 2.0, 3.0], "beam_std_db": 1.0},
                         "noise": {"common_db": 50.0, "common_length_m": 0.5}})
    d = spec.to_dict()
    assert d["beam_gain"]["gain_db"] == [0.5, -1.0, 2.0]  # a list in the file, a tuple in the spec
    assert parse_sensor(d) == spec and parse_sensor(yaml.safe_load(yaml.safe_dump(d))) == spec
    assert hash(spec) == hash(parse_sensor(d))  # specs key the simulator's and calibration's caches
    assert parse_sensor({}).beam_gain is None and parse_sensor({}).to_dict()["beam_gain"] is False


@pytest.mark.parametrize("sensor, key, message", [
    ({"beam_gain": {"steering_exponent": -1}}, "sensor.beam_gain.steering_exponent", r"within \[0, 200\]"),
    ({"beam_gain": {"steering_exponent": 1e3}}, "sensor.beam_gain.steering_exponent", r"within \[0, 200\]"),
    ({"beam_gain": {"gain_db": "3 dB"}}, "sensor.beam_gain.gain_db", "a list of numbers in dB, one per beam"),
    ({"beam_gain": {"gain_db": []}}, "sensor.beam_gain.gain_db", "one value per beam"),
    ({"beam_gain": {"gain_db": [0.0, 61.0]}}, r"sensor.beam_gain.gain_db\[1\]", r"within \[-60, 60\] dB"),
    ({"beam_gain": {"gain_db": [0.0, None]}}, r"sensor.beam_gain.gain_db\[1\]", "finite number"),
    ({"beam_gain": {"std_db": 21}}, "sensor.beam_gain.std_db", r"within \[0, 20\] dB"),
    ({"beam_gain": {"stripes": 1}}, "sensor.beam_gain.stripes", "unknown key"),
    ({"bang": {"ringing_db": 80.0}}, "sensor.bang.ringing_length_m", "required with ringing_db"),
    ({"bang": {"ringing_period_m": 0.1}}, "sensor.bang.ringing_period_m", "only with ringing_db"),
    ({"bang": {"ringing_db": 80.0, "ringing_length_m": 0.0}}, "sensor.bang.ringing_length_m",
     r"within \[0.0001, 10000\] m"),
    ({"bang": {"ringing_db": 400.0, "ringing_length_m": 1.0}}, "sensor.bang.ringing_db", r"within \[-300, 300\]"),
    ({"bang": {"beam_db": [float("nan")]}}, r"sensor.bang.beam_db\[0\]", "finite number"),
    ({"bang": {"beam_std_db": -1.0}}, "sensor.bang.beam_std_db", r"within \[0, 20\] dB"),
    ({"noise": {"common_length_m": 1.0}}, "sensor.noise.common_length_m", "only with common_db"),
    ({"noise": {"common_db": 1e9}}, "sensor.noise.common_db", r"within \[-300, 300\]"),
    ({"noise": {"common_db": 10.0, "common_length_m": -1.0}}, "sensor.noise.common_length_m", "within"),
])
def test_the_new_keys_are_refused_out_of_bounds_by_name(sensor, key, message):
    with pytest.raises(ConfigError, match=message) as err:
        parse_sensor(sensor)
    assert err.value.key == key.replace("\\", "")


def test_a_per_beam_list_must_match_the_sonars_beams():
    for sensor, key in (({"beam_gain": {"gain_db": [0.0, 1.0, 2.0]}}, "sensor.beam_gain.gain_db"),
                        ({"bang": {"beam_db": [0.0] * 65}}, "sensor.bang.beam_db")):
        with pytest.raises(ConfigError, match=r"the sonar has 64 beams") as err:
            model(**sensor)
        assert err.value.key == key
        with pytest.raises(ConfigError, match=r"the sonar has 48 beams") as err:
            sonarsim.render(tank({"preset": "aris3000-64", "elevation_pattern": False, **sensor}))
        assert err.value.key == key


def test_a_beam_gain_beyond_float32_is_refused():
    loud = {"source_level_db": 0.0, "gain_db": 200.0, "noise": {"level_db": 150.0}}
    model(**loud)  # 350 dB: held
    with pytest.raises(ConfigError, match="beam gains up to 30 dB"):
        model(**loud, beam_gain={"gain_db": [30.0] * 64})
