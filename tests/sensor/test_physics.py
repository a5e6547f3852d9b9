"""The sensor's physics against closed forms: absorption, sonar equation and TVG, beam
patterns, pulse, output chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.config.sensor import OutputSpec, PatternSpec, PulseSpec, TvgSpec, parse_sensor
from sonarsim.config.sonar import SonarConfig
from sonarsim.sensor import acoustics, output, patterns, pulse
from sonarsim.sensor.model import SensorModel


def small_sonar(**kw) -> SonarConfig:
    args = dict(n_beams=64, azimuth_fov_deg=32.0, elevation_fov_deg=14.0, range_min_m=0.5, range_max_m=5.0,
                n_range_bins=450, frequency_khz=1000.0)
    args.update(kw)
    n, fov, el, r0, r1, nr = (args.pop(k) for k in ("n_beams", "azimuth_fov_deg", "elevation_fov_deg",
                                                    "range_min_m", "range_max_m", "n_range_bins"))
    return SonarConfig.uniform(n, fov, el, r0, r1, nr, **args)


# Absorption -------------------------------------------------------------------------------

def francois_garrison_by_hand(f, t, s, z, ph):
    """The three terms of Francois & Garrison (1982) written out once more, term by term."""
    c = 1412 + 3.21 * t + 1.19 * s + 0.0167 * z
    theta = 273 + t
    boric = (8.86 / c) * 10 ** (0.78 * ph - 5) * (2.8 * (s / 35) ** 0.5 * 10 ** (4 - 1245 / theta)) * f ** 2 / (
        (2.8 * (s / 35) ** 0.5 * 10 ** (4 - 1245 / theta)) ** 2 + f ** 2)
    f2 = 8.17 * 10 ** (8 - 1990 / theta) / (1 + 0.0018 * (s - 35))
    mg = 21.44 * (s / c) * (1 + 0.025 * t) * (1 - 1.37e-4 * z + 6.2e-9 * z ** 2) * f2 * f ** 2 / (f2 ** 2 + f ** 2)
    a3 = 4.937e-4 - 2.59e-5 * t + 9.11e-7 * t ** 2 - 1.5e-8 * t ** 3 if t <= 20 else \
        3.964e-4 - 1.146e-5 * t + 1.45e-7 * t ** 2 - 6.5e-10 * t ** 3
    return boric + mg + a3 * (1 - 3.83e-5 * z + 4.9e-10 * z ** 2) * f ** 2


@pytest.mark.parametrize("f,t,s,z", [(1.0, 4, 35, 1000), (10.0, 10, 35, 0), (100.0, 10, 35, 0),
                                     (1000.0, 15, 0, 2), (2100.0, 25, 35, 10)])
def test_francois_garrison_matches_the_formula_term_by_term(f, t, s, z):
    assert acoustics.francois_garrison_db_per_km(f, t, s, z, 8.0) == pytest.approx(
        francois_garrison_by_hand(f, t, s, z, 8.0), rel=1e-12)


def test_francois_garrison_published_figures():
    # Orders of magnitude every sonar engineer knows for sea water at 10 degC, 35 PSU:
    # ~1 dB/km at 10 kHz, ~30-40 dB/km at 100 kHz, ~0.3-0.4 dB/m at 1 MHz (F&G 1982, Fig. 8).
    assert 0.6 < acoustics.francois_garrison_db_per_km(10.0, 10, 35, 0) < 1.3
    assert 28 < acoustics.francois_garrison_db_per_km(100.0, 10, 35, 0) < 42
    assert 300 < acoustics.francois_garrison_db_per_km(1000.0, 10, 35, 0) < 400
    # Fresh water has no relaxation terms: only viscosity, ~f^2.
    fresh = acoustics.francois_garrison_db_per_km(np.array([500.0, 1000.0]), 10, 0, 0)
    assert fresh[1] / fresh[0] == pytest.approx(4.0, rel=1e-9)


@pytest.mark.parametrize("f", [1.0, 10.0, 50.0, 100.0, 300.0, 1000.0])
def test_two_published_formulas_agree_within_their_stated_spread(f):
    fg = acoustics.francois_garrison_db_per_km(f, 10, 35, 100, 8)
    am = acoustics.ainslie_mccolm_db_per_km(f, 10, 35, 100, 8)
    assert am == pytest.approx(fg, rel=0.15)


# Sonar equation and TVG ------------------------------------------------------------------

def test_tvg_of_40_log_r_plus_2_alpha_r_cancels_the_loss_of_a_point_target_exactly():
    sonar = small_sonar()
    spec = parse_sensor({"source_level_db": 200, "absorption": {"model": "constant", "db_per_m": 0.3},
                         "tvg": {"spreading": 40, "absorption": True}})
    m = SensorModel(spec, sonar)
    r = sonar.range_m
    sigma = 1e-3  # m^2: a point target fills the solid angle sigma / r^2 of the image
    x = np.zeros((len(r), sonar.n_beams), np.float32)
    x[:, 10] = sigma / r ** 2 / m.column_factor[10]
    p = m.apply(x, speckle=True)[:, 10].astype(float)
    expected = 10 ** (200 / 10) * sigma
    np.testing.assert_allclose(p, expected, rtol=1e-5)


def test_20_log_r_tvg_and_no_absorption_leave_the_rendered_image_times_a_constant():
    sonar = small_sonar()
    spec = parse_sensor({"source_level_db": 0, "tvg": {"spreading": 20, "absorption": False}})
    m = SensorModel(spec, sonar)
    x = np.random.default_rng(0).random((sonar.n_range_bins, sonar.n_beams)).astype(np.float32)
    np.testing.assert_allclose(m.apply(x), x * m.column_factor[None, :], rtol=1e-6)


def test_absorption_appears_as_2_alpha_r_without_tvg_absorption():
    sonar = small_sonar()
    spec = parse_sensor({"source_level_db": 0, "absorption": {"model": "constant", "db_per_m": 1.0},
                         "tvg": {"spreading": 20, "absorption": False}})
    m = SensorModel(spec, sonar)
    x = np.ones((sonar.n_range_bins, sonar.n_beams), np.float32)
    level = 10 * np.log10(m.apply(x)[:, 0] / m.column_factor[0])
    np.testing.assert_allclose(level, -2.0 * sonar.range_m, atol=1e-4)


# Beam patterns -----------------------------------------------------------------------------

def test_uniform_line_array_power_pattern_integrates_like_sinc_squared():
    # int_{-U}^{U} sinc^2(u) du = (2 / pi) Si(2 pi U) for integer U.
    from scipy.special import sici
    for big_u in (1, 5, 20):
        u = np.linspace(-big_u, big_u, 200001)
        a = patterns.array_amplitude(u, "rect")
        assert np.trapezoid(a ** 2, u) == pytest.approx(2 / np.pi * sici(2 * np.pi * big_u)[0], rel=2e-4)


def test_hann_power_pattern_integral_is_parseval():
    # int |A(u)|^2 du = int w^2 / (int w)^2 = 0.375 / 0.25 = 1.5 over the unit aperture.
    u = np.linspace(-60, 60, 120001)
    assert np.trapezoid(patterns.array_amplitude(u, "hann") ** 2, u) == pytest.approx(1.5, rel=2e-3)


def test_uniform_line_array_has_its_half_power_point_and_first_sidelobe():
    assert patterns.half_power_u("rect", None, 1) == pytest.approx(0.4429, abs=2e-4)
    u = np.linspace(1.0, 2.0, 20001)
    side = (patterns.array_amplitude(u, "rect") ** 2).max()
    assert 10 * np.log10(side) == pytest.approx(-13.26, abs=0.02)


@pytest.mark.parametrize("shape,window", [("line", "rect"), ("line", "hann"), ("gaussian", "rect"),
                                          ("line", "taylor")])
@pytest.mark.parametrize("ways", [1, 2])
def test_pattern_falls_3_db_at_half_its_width(shape, window, ways):
    spec = PatternSpec(shape=shape, window=window, width_deg=12.0, sidelobe_db=30.0 if window == "taylor" else None)
    g = patterns.pattern_gain(np.radians([0.0, 6.0, -6.0]), spec, 99.0, ways)
    np.testing.assert_allclose(10 * np.log10(g), [0.0, -3.0103, -3.0103], atol=2e-3)


def test_taylor_window_holds_its_sidelobe_level():
    spec = PatternSpec(shape="line", window="taylor", sidelobe_db=35.0, width_deg=10.0)
    a = np.radians(np.linspace(0, 60, 60000))
    g = patterns.pattern_gain(a, spec, 10.0, ways=1)
    first_null = np.flatnonzero((g[1:-1] < g[:-2]) & (g[1:-1] < g[2:]))[0]
    peak_db = 10 * np.log10(g[first_null:].max())
    assert -36.0 < peak_db < -33.0


def test_azimuth_kernels_conserve_power_and_peak_on_the_beam():
    spec = PatternSpec(shape="line", window="rect", width_deg=0.6, leakage_beams=20)
    leak, amp, _ = patterns.azimuth_kernels(spec, 0.25, 0.25)
    assert leak.sum() == pytest.approx(1.0) and np.sum(amp ** 2) == pytest.approx(1.0)
    assert leak.argmax() == 20 and amp.argmax() == 20
    np.testing.assert_allclose(leak, leak[::-1])
    # A beam 4 widths away hears the sidelobes: about 1 / (pi u)^2 of the main lobe.
    assert 1e-4 < leak[20 + 10] / leak[20] < 1e-2


def test_measured_table_pattern_is_interpolated(tmp_path):
    f = tmp_path / "pattern.csv"
    f.write_text("# angle_deg, gain_db\n-30,-40\n-5,-3\n0,0\n5,-3\n30,-40\n")
    spec = PatternSpec(shape="table", table=str(f))
    g = patterns.pattern_gain(np.radians([0.0, 2.5, 5.0, 45.0]), spec, 10.0, 2)
    np.testing.assert_allclose(10 * np.log10(g), [0.0, -1.5, -3.0, -40.0], atol=1e-9)


# Pulse -------------------------------------------------------------------------------------

def test_cw_pulse_spreads_a_point_over_c_tau_over_2():
    dr = 0.01
    # c tau / 2 = 1500 * 40e-6 / 2 = 3 cm = 3 bins: a gate covering three bins.
    intensity, amplitude = pulse.range_kernels(PulseSpec(kind="cw", length_us=40.0), dr, 1500.0)
    assert len(intensity) in (3, 5)
    centre = len(intensity) // 2
    assert intensity.sum() == pytest.approx(1.0) and np.sum(amplitude ** 2) == pytest.approx(1.0)
    assert intensity[centre - 1:centre + 2].sum() > 0.95


def test_chirp_main_lobe_is_c_over_2b_and_window_lowers_the_sidelobes():
    c, b = 1500.0, 100.0  # c / 2B = 7.5 mm
    d = np.linspace(-0.05, 0.05, 20001)
    rect = pulse.envelope(d, PulseSpec(kind="chirp", bandwidth_khz=b, window="rect"), c)
    hann = pulse.envelope(d, PulseSpec(kind="chirp", bandwidth_khz=b, window="hann"), c)
    first_null = d[d > 0][np.argmax(rect[d > 0] <= 0)]
    assert first_null == pytest.approx(c / (2 * b * 1e3), rel=2e-3)
    out = np.abs(d) > c / (2 * b * 1e3)  # beyond the first null
    assert 20 * np.log10(np.abs(rect[out]).max()) == pytest.approx(-13.26, abs=0.05)
    out_hann = np.abs(d) > 2 * c / (2 * b * 1e3)  # Hann: main lobe twice as wide, sidelobes -31.5 dB
    assert 20 * np.log10(np.abs(hann[out_hann]).max()) == pytest.approx(-31.5, abs=0.3)


# Output chain ------------------------------------------------------------------------------

def test_log_compression_maps_floor_and_ceiling_and_quantises():
    spec = OutputSpec(compression="log", floor_db=60, ceiling_db=160, dtype="uint8")
    levels = np.array([40.0, 60.0, 110.0, 160.0, 180.0])
    v = output.compress(10 ** (levels / 10), spec)
    np.testing.assert_array_equal(v, [0, 0, 128, 255, 255])  # 127.5 rounds half up
    assert np.all(v == np.round(v))


def test_gamma_compression_and_16_bit_full_scale():
    spec = OutputSpec(compression="gamma", gamma=0.5, ceiling_db=100, dtype="uint16")
    p = 10 ** (np.array([100.0, 80.0, 60.0]) / 10)
    np.testing.assert_array_equal(output.compress(p, spec), np.floor(65535 * np.array([1, 0.1, 0.01]) + 0.5))
    f = OutputSpec(compression="linear", ceiling_db=0, dtype="float32")
    np.testing.assert_allclose(output.compress(np.array([0.25, 3.0]), f), [0.25, 1.0])


def test_expected_output_is_the_mean_over_exponential_speckle():
    spec = OutputSpec(compression="log", floor_db=0, ceiling_db=40, dtype="uint8")
    e = output.ExpectedOutput(spec, output.exponential_quantiles())
    rng = np.random.default_rng(0)
    for level in (5.0, 20.0, 35.0):
        mu = 10 ** (level / 10)
        mc = output.compress(mu * rng.exponential(size=400000), spec).mean()
        assert e(np.array([mu]))[0] == pytest.approx(mc, abs=0.15)
    # Log of exponential speckle: mean level 2.51 dB below the mean power (Euler's constant).
    mu = 10 ** 2.0
    assert e(np.array([mu]))[0] == pytest.approx((20.0 - 2.507) / 40 * 255, abs=0.3)


def test_config_errors_name_the_key(tmp_path):
    from sonarsim.errors import ConfigError
    bad = [({"nois": {}}, "sensor.nois"), ({"noise": {"level": 3}}, "sensor.noise.level"),
           ({"tvg": {"spreading": 25}}, "sensor.tvg.spreading"), ({"preset": "nope"}, "sensor.preset"),
           ({"output": {"dtype": "int8"}}, "sensor.output.dtype"), ({"source_level_db": float("nan")}, "sensor.source_level_db"),
           ({"absorption": {"model": "constant"}}, "sensor.absorption.db_per_m"),
           ({"elevation_pattern": {"window": "taylor"}}, "sensor.elevation_pattern.sidelobe_db"),
           ({"azimuth_pattern": {"leakage_beams": 10000}}, "sensor.azimuth_pattern.leakage_beams"),
           ({"azimuth_pattern": {"span_deg": 30}}, "sensor.azimuth_pattern.span_deg"),
           ({"elevation_pattern": {"shape": "table"}}, "sensor.elevation_pattern.table"),
           ({"pulse": {"kind": "chirp"}}, "sensor.pulse.bandwidth_khz"),
           ({"elevation_pattern": {"shape": "table", "table": "missing.csv"}}, "sensor.elevation_pattern.table")]
    for doc, key in bad:
        with pytest.raises(ConfigError) as e:
            parse_sensor(doc)
        assert e.value.key == key, (doc, e.value)


def test_sensor_section_round_trips_and_presets_merge():
    spec = parse_sensor({"preset": "aris3000-64", "noise": {"level_db": 50}, "bang": False})
    assert spec.noise.level_db == 50 and spec.bang is None and spec.speckle is not None
    from dataclasses import replace
    assert parse_sensor(spec.to_dict()) == replace(spec, preset=None)


def test_hostile_sizes_are_refused_before_allocating():
    from sonarsim.errors import ConfigError
    from sonarsim.sensor.speckle import SpecklePool

    with pytest.raises(ConfigError, match="sensor.speckle"):
        SpecklePool((100000, 4096), np.ones(1), np.ones(1), None, True, 0)
    with pytest.raises(ConfigError, match="gamma"):
        OutputSpec(compression="gamma", gamma=1e-6)
    with pytest.raises(ConfigError, match="ceiling_db"):
        OutputSpec(ceiling_db=1e9)
    with pytest.raises(ConfigError, match="sensor.pulse"):
        SensorModel(parse_sensor({"pulse": {"kind": "cw", "length_us": 1e6}}), small_sonar())
    # The widest allowed output window still makes a bounded table.
    e = output.ExpectedOutput(OutputSpec(compression="log", floor_db=-100, ceiling_db=400), output.exponential_quantiles(64))
    assert len(e.table) <= output.MAX_TABLE_LEVELS + 1
