"""Tests of the side-scan, multibeam, scanning and single-beam device presets.

The recording presets are checked twice: against the figures of the design notes (section 6),
and, when ``../shared/data`` is present, against the recordings' own headers (read here with a
few lines of ``struct``, so that the check needs no reader of the package).
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from sonarsim.config.instrument_presets import (
    BEAM_SPACINGS,
    INSTRUMENT_KEYS,
    INSTRUMENT_PRESETS,
    INSTRUMENT_TYPES,
    OPTIONAL_KEYS,
    InstrumentPreset,
    check_instrument_preset,
    instrument_preset,
    instrument_presets,
    ping360_settings,
    ping_rate_hz,
    scan_step_period_s,
)
from sonarsim.errors import ConfigError

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
needs_data = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data is absent")

REQUIRED_NAMES = {
    "sidescan": {"seascan_hds_600", "edgetech_4125_400", "edgetech_4125_900", "klein_3000_100", "klein_3000_500"},
    "multibeam": {"r2sonic_2026_400", "kongsberg_em2040"},
    "scanning": {"ping360", "tritech_micron"},
    "singlebeam": {"imagenex_852", "ping2"},
}


# ------------------------------------------------------------------ the table's invariants


def test_every_required_preset_exists_with_its_type():
    for kind, names in REQUIRED_NAMES.items():
        assert names <= set(instrument_presets(kind)), kind
        for name in names:
            assert INSTRUMENT_PRESETS[name].type == kind


@pytest.mark.parametrize("name", sorted(INSTRUMENT_PRESETS))
def test_every_preset_has_every_key_of_its_type_and_sane_values(name):
    preset = INSTRUMENT_PRESETS[name]
    assert preset.name == name
    assert preset.type in INSTRUMENT_TYPES
    keys = set(preset.values)
    assert set(INSTRUMENT_KEYS[preset.type]) <= keys
    assert keys <= set(INSTRUMENT_KEYS[preset.type]) | set(OPTIONAL_KEYS[preset.type])
    for key, value in preset.values.items():
        if key == "beam_spacing":
            assert value in BEAM_SPACINGS
        elif value is None:
            assert key == "ping_rate_hz"
        else:
            assert not isinstance(value, bool)
            assert isinstance(value, (int, float)) and math.isfinite(value), key
            assert value > 0 or (key == "motor_time_per_step_s" and value == 0), key
            if key.startswith("n_") or key.endswith("_ticks_min") or key.endswith("_ticks_max") or key == "steps_per_turn":
                assert isinstance(value, int), key
    assert preset.source.strip() and preset.description.strip()
    assert isinstance(preset.notes, str)


@pytest.mark.parametrize("name", sorted(INSTRUMENT_PRESETS))
def test_every_preset_marks_what_is_not_from_a_document(name):
    """A preset whose figures are not all read from a document or recording says which in notes."""
    preset = INSTRUMENT_PRESETS[name]
    text = preset.notes.lower()
    assert any(word in text for word in ("inferred", "our choice", "not confirmed", "typical", "assumption")), name


def test_physical_relations_hold_in_every_preset():
    for preset in INSTRUMENT_PRESETS.values():
        v = preset.values
        if preset.type == "sidescan":
            # Narrow along track, wide across; the beam axis points below the horizontal.
            assert v["horizontal_beam_width_deg"] < v["vertical_beam_width_deg"] < 90
            assert 0 < v["depression_deg"] < 90
        if preset.type == "multibeam":
            assert v["swath_deg"] < 180
            # Beams may overlap but a swath of n beams is wider than one receive beam.
            assert v["swath_deg"] > v["rx_beam_width_across_deg"]
        if preset.type == "scanning":
            assert v["n_samples"] <= v["n_samples_max"]
            assert v["horizontal_beam_width_deg"] < v["vertical_beam_width_deg"]
            # A step is finer than the beam, so that a turn covers every direction.
            assert 360.0 / v["steps_per_turn"] <= v["horizontal_beam_width_deg"]
        for key in ("range_limit_m",):
            if key in v:
                assert v[key] >= v["range_max_m"]
        if "range_min_m" in v:
            assert v["range_min_m"] < v["range_max_m"]


def test_presets_are_read_only():
    preset = INSTRUMENT_PRESETS["ping360"]
    with pytest.raises(TypeError):
        preset.values["frequency_khz"] = 1.0  # type: ignore[index]
    with pytest.raises(AttributeError):
        preset.source = "x"  # type: ignore[misc]
    copy = preset.as_dict()
    copy["frequency_khz"] = 1.0
    assert preset["frequency_khz"] == 750.0
    assert copy["type"] == "scanning" and copy["source"] == preset.source


# ------------------------------------------------------------------ the recordings' figures


def test_recording_presets_agree_with_the_design_notes():
    seascan = instrument_preset("seascan_hds_600", "sidescan")
    assert seascan["n_samples"] == 1024
    assert seascan["range_max_m"] == pytest.approx(29.98, abs=0.005)
    assert seascan["frequency_khz"] == 600.0
    # The recording's ping interval, 0.123 s (the header's 0.04 s is the listening time, 2 R / c).
    assert 1.0 / ping_rate_hz(seascan) == pytest.approx(0.123, abs=0.001)

    r2 = instrument_preset("r2sonic_2026_400", "multibeam")
    assert (r2["n_beams"], r2["frequency_khz"], r2["pulse_length_us"]) == (256, 400.0, 35.0)
    assert (r2["tx_beam_width_along_deg"], r2["rx_beam_width_across_deg"]) == (1.0, 0.5)
    assert 120 < r2["swath_deg"] < 130

    imagenex = instrument_preset("imagenex_852", "singlebeam")
    assert (imagenex["n_samples"], imagenex["range_max_m"]) == (500, 10.0)
    # The data sheet's 20 mm range resolution is the recording's sample spacing.
    assert imagenex["range_max_m"] / imagenex["n_samples"] == pytest.approx(0.020)


def _xtf_sonar_channel_headers(path: Path):
    """(SlantRange m, SecondsPerPing s, Frequency kHz, NumSamples) of each channel of each ping
    of an XTF file, and each ping's time of day in seconds."""
    data = path.read_bytes()
    channels, times = [], []
    offset = 1024  # the file header
    while offset + 14 <= len(data):
        magic, header_type = struct.unpack_from("<HB", data, offset)
        n_channels, = struct.unpack_from("<H", data, offset + 4)
        n_bytes, = struct.unpack_from("<I", data, offset + 10)
        assert magic == 0xFACE and n_bytes > 0
        if header_type == 0:  # sonar ping: 256-byte ping header, then 64 bytes per channel
            hour, minute, second, hundredths = struct.unpack_from("<4B", data, offset + 18)
            times.append(hour * 3600 + minute * 60 + second + hundredths / 100)
            position = offset + 256
            for _ in range(n_channels):
                slant, = struct.unpack_from("<f", data, position + 4)
                per_ping, = struct.unpack_from("<f", data, position + 20)
                frequency, = struct.unpack_from("<H", data, position + 26)
                n_samples, = struct.unpack_from("<I", data, position + 42)
                channels.append((slant, per_ping, frequency, n_samples))
                position += 64 + n_samples * 2  # 2-byte samples in this recording
        offset += n_bytes
    return channels, np.array(times)


@needs_data
def test_seascan_preset_agrees_with_the_recording():
    preset = INSTRUMENT_PRESETS["seascan_hds_600"]
    channels, times = _xtf_sonar_channel_headers(REAL / "sidescan" / "iver2_seascan_pings_0-179.xtf")
    assert len(channels) == 360 and len(times) == 180
    for slant, per_ping, frequency, n_samples in channels:
        assert n_samples == preset["n_samples"]
        assert slant == pytest.approx(preset["range_max_m"], abs=0.01)
        assert frequency == preset["frequency_khz"]
        assert per_ping == pytest.approx(2 * preset["range_max_m"] / 1500.0, rel=1e-3)  # listening time
    # The notes' other figure: the pings themselves are about 0.123 s apart (ping 0 excluded:
    # it has no navigation), not 0.04 s.
    interval = (times[-1] - times[1]) / (len(times) - 2)
    assert interval == pytest.approx(0.123, abs=0.002)
    assert 1.0 / ping_rate_hz(preset) == pytest.approx(interval, rel=0.01)
    assert "0.123 s" in preset.notes


@needs_data
def test_r2sonic_preset_agrees_with_the_recording():
    preset = INSTRUMENT_PRESETS["r2sonic_2026_400"]
    data = (REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf").read_bytes()
    seen, position = 0, data.find(b"BTH0")
    while position >= 0:
        size, = struct.unpack_from(">I", data, position + 4)
        record = data[position : position + 8 + size]
        h0 = record.find(b"H0", 8)
        model = record[h0 + 4 : h0 + 16].rstrip(b"\0")
        (frequency, _power, pulse_s, width_vert, width_horiz) = struct.unpack_from(">5f", record, h0 + 48)
        rx_range, = struct.unpack_from(">f", record, h0 + 88)
        n_points, = struct.unpack_from(">H", record, h0 + 114)
        assert model == b"2026"
        assert frequency / 1e3 == preset["frequency_khz"]
        assert pulse_s * 1e6 == pytest.approx(preset["pulse_length_us"], rel=1e-6)
        assert math.degrees(width_vert) == pytest.approx(preset["tx_beam_width_along_deg"], rel=1e-6)
        assert math.degrees(width_horiz) == pytest.approx(preset["rx_beam_width_across_deg"], rel=1e-6)
        assert n_points == preset["n_beams"]
        assert rx_range <= preset["range_max_m"]
        # Equidistant mode: an A2 section (cumulative angle steps) follows.
        a2 = record.find(b"A2", h0 + 116)
        first, scale = struct.unpack_from(">ff", record, a2 + 4)
        steps = np.frombuffer(record, ">u2", n_points, a2 + 36).astype(np.int64)
        angles = np.degrees(first + np.cumsum(steps) * scale)
        assert angles[-1] - angles[0] == pytest.approx(preset["swath_deg"], abs=0.3)
        spacing = np.diff(angles)
        # Equidistant on a flat floor: the widest spacing at nadir, the narrowest at the edges.
        assert spacing[len(spacing) // 2] > 3 * spacing[0]
        seen += 1
        position = data.find(b"BTH0", position + 8 + size)
    assert seen == 460
    assert preset["beam_spacing"] == "equidistant"


@needs_data
def test_imagenex_preset_agrees_with_the_recording():
    preset = INSTRUMENT_PRESETS["imagenex_852"]
    raw = np.frombuffer((REAL / "singlebeam" / "imagenex852_2016-11-18.852").read_bytes(), np.uint8)
    records = raw.reshape(-1, 640)
    assert len(records) == 917
    assert bytes(records[0, 100:103]) == b"IGX"
    # Return header (bytes 100-111): range in metres at byte 107; the echo-byte count as two
    # 7-bit bytes, low first, at 110-111.
    assert np.all(records[:, 107] == preset["range_max_m"])
    n_bytes = (records[:, 110] & 0x7F).astype(int) | ((records[:, 111] & 0x7F).astype(int) << 7)
    assert np.all(n_bytes == preset["n_samples"])
    assert np.all(records[:, 112 + preset["n_samples"]] == 0xFC)
    # Time stamps "HH:MM:SS" at byte 20 and ".hh" at byte 29: one ping a second.
    seconds = np.array(
        [
            sum(int(part) * scale for part, scale in zip(bytes(r[20:28]).decode().split(":"), (3600, 60, 1)))
            + float(bytes(r[29:32]).decode())
            for r in records
        ]
    )
    assert (seconds[-1] - seconds[0]) / (len(seconds) - 1) == pytest.approx(1.0 / preset["ping_rate_hz"], rel=0.01)


# ------------------------------------------------------------------ look-up and its errors


def test_lookup_by_name_and_type():
    assert instrument_preset("ping360") is INSTRUMENT_PRESETS["ping360"]
    assert instrument_preset("ping360", type="scanning").type == "scanning"
    assert instrument_presets() == tuple(INSTRUMENT_PRESETS)
    listed = [name for kind in INSTRUMENT_TYPES for name in instrument_presets(kind)]
    assert sorted(listed) == sorted(INSTRUMENT_PRESETS)


def test_unknown_name_of_a_type_names_it_and_lists_that_types_presets():
    with pytest.raises(ConfigError) as info:
        instrument_preset("seascan_hds_900", type="sidescan")
    error = info.value
    assert error.key == "preset"
    assert "'seascan_hds_900'" in str(error)
    for name in instrument_presets("sidescan"):
        assert name in str(error)
    assert "ping360" not in str(error)


def test_unknown_name_without_a_type_lists_every_preset_by_type():
    with pytest.raises(ConfigError) as info:
        instrument_preset("no_such_sonar")
    message = str(info.value)
    assert info.value.key == "preset" and "'no_such_sonar'" in message
    for kind in INSTRUMENT_TYPES:
        assert f"{kind}:" in message
    assert all(name in message for name in INSTRUMENT_PRESETS)


def test_a_preset_of_another_type_is_refused_with_its_type():
    with pytest.raises(ConfigError) as info:
        instrument_preset("ping2", type="sidescan")
    assert info.value.key == "preset"
    assert "singlebeam" in str(info.value) and "seascan_hds_600" in str(info.value)


@pytest.mark.parametrize("bad", ["sss", "FLS", 3])
def test_unknown_type_lists_the_types(bad):
    with pytest.raises(ConfigError) as info:
        instrument_presets(bad)
    assert info.value.key == "type"
    assert all(kind in str(info.value) for kind in INSTRUMENT_TYPES)


@pytest.mark.parametrize("name", [None, 7, ["ping360"], "x" * 10_000])
def test_odd_names_give_one_line_errors(name):
    with pytest.raises(ConfigError) as info:
        instrument_preset(name)  # type: ignore[arg-type]
    assert "\n" not in str(info.value) and len(str(info.value)) < 2000


# ------------------------------------------------------------------ the validator


def _values(**changes):
    values = dict(INSTRUMENT_PRESETS["klein_3000_500"].values)
    values.update(changes)
    return values


@pytest.mark.parametrize(
    "values, key",
    [
        ({k: v for k, v in _values().items() if k != "depression_deg"}, "depression_deg"),
        (_values(n_beams=3), "n_beams"),
        (_values(n_samples=2048.0), "n_samples"),
        (_values(n_samples=True), "n_samples"),
        (_values(frequency_khz=float("nan")), "frequency_khz"),
        (_values(frequency_khz=-100.0), "frequency_khz"),
        (_values(range_max_m=0.0), "range_max_m"),
        (_values(pulse_length_us="25"), "pulse_length_us"),
    ],
)
def test_the_validator_refuses_bad_presets_naming_the_key(values, key):
    with pytest.raises(ConfigError) as info:
        InstrumentPreset("bad", "sidescan", "d", values, source="s", notes="n")
    assert info.value.key == f"preset.bad.{key}"


def test_the_validator_refuses_an_empty_source_and_bad_spacing_and_type():
    with pytest.raises(ConfigError) as info:
        InstrumentPreset("bad", "sidescan", "d", _values(), source="  ")
    assert info.value.key == "preset.bad.source"
    mb = dict(INSTRUMENT_PRESETS["kongsberg_em2040"].values, beam_spacing="equi-angle")
    with pytest.raises(ConfigError) as info:
        InstrumentPreset("bad", "multibeam", "d", mb, source="s")
    assert info.value.key == "preset.bad.beam_spacing" and "equiangular" in str(info.value)
    with pytest.raises(ConfigError) as info:
        InstrumentPreset("bad", "forward", "d", _values(), source="s")
    assert info.value.key == "preset.bad" and "sidescan" in str(info.value)


def test_every_built_in_preset_passes_the_validator_again():
    for preset in INSTRUMENT_PRESETS.values():
        check_instrument_preset(preset)


# ------------------------------------------------------------------ derived timing


def test_side_scan_ping_rate_is_derived_from_the_range():
    klein = INSTRUMENT_PRESETS["klein_3000_100"]
    assert ping_rate_hz(klein) == pytest.approx(1500.0 / (2 * 600.0))
    assert ping_rate_hz(klein, range_m=75.0, sound_speed_m_s=1480.0) == pytest.approx(1480.0 / 150.0)
    # A preset that gives a rate keeps it.
    assert ping_rate_hz(INSTRUMENT_PRESETS["imagenex_852"], range_m=50.0) == 1.0
    with pytest.raises(ConfigError) as info:
        ping_rate_hz(klein, range_m=0.0)
    assert info.value.key == "range_m"
    with pytest.raises(ConfigError) as info:
        ping_rate_hz(INSTRUMENT_PRESETS["ping360"])
    assert info.value.key == "preset"


@pytest.mark.parametrize(
    "range_m, ticks, transmit_us",
    # Ping Viewer's settings at 1200 samples and 1500 m/s, as logged in the Blue Robotics forum
    # thread 'Ping 360 time info/split image'.
    [(2.0, 88, 11), (20.0, 888, 107), (50.0, 2222, 267)],
)
def test_ping360_settings_reproduce_the_logged_ones(range_m, ticks, transmit_us):
    settings = ping360_settings(range_m)
    assert settings.n_samples == 1200
    assert settings.sample_period_ticks == ticks
    assert settings.transmit_duration_us == transmit_us
    assert settings.sample_period_s == pytest.approx(ticks * 25e-9)
    assert settings.range_m == pytest.approx(1200 * ticks * 25e-9 * 1500 / 2)
    assert range_m - 0.03 < settings.range_m <= range_m


def test_ping360_short_ranges_take_fewer_samples_and_transmit_limits_hold():
    # 1 m at the 80-tick minimum: 2 m / (80 x 25 ns x 1500 m/s) = 666.7 -> 666 samples.
    settings = ping360_settings(1.0)
    assert settings.n_samples == 666
    assert settings.sample_period_ticks == 80
    # 8000 x 0.999 / 1500 = 5.3 us, above 2.5 periods (5 us) and the 5 us floor.
    assert settings.transmit_duration_us == 5
    for r in np.linspace(0.3, 50.0, 60):
        s = ping360_settings(float(r))
        period_us = s.sample_period_s * 1e6
        assert 200 <= s.n_samples <= 1200 and 80 <= s.sample_period_ticks <= 40000
        assert 5 <= s.transmit_duration_us <= min(500, 64 * period_us)
    for bad in (0.2, 50.5, -1.0, float("inf")):
        with pytest.raises(ConfigError) as info:
            ping360_settings(bad)
        assert info.value.key == "range_m"
    with pytest.raises(ConfigError) as info:
        ping360_settings(10.0, n_samples=100)
    assert info.value.key == "n_samples"


@pytest.mark.parametrize(
    "step, range_m, seconds",
    # Full-turn times measured with Ping Viewer over Ethernet (forum thread above), 1200 samples.
    [(1, 2, 10.74), (1, 20, 20.57), (1, 50, 37.6), (10, 2, 3.29), (10, 20, 4.19), (10, 50, 5.89)],
)
def test_ping360_step_timing_reproduces_the_measured_turn_times(step, range_m, seconds):
    preset = INSTRUMENT_PRESETS["ping360"]
    turn = preset["steps_per_turn"] / step * scan_step_period_s(preset, range_m, steps=step)
    assert turn == pytest.approx(seconds, rel=0.05)


def test_micron_turn_time_falls_in_the_quoted_range():
    micron = INSTRUMENT_PRESETS["tritech_micron"]
    # 5-20 s a turn is quoted; the preset gives 5 s at a short range and stays under 20 s at 20 m.
    short = micron["steps_per_turn"] * scan_step_period_s(micron, 1.0)
    at_20_m = micron["steps_per_turn"] * scan_step_period_s(micron, 20.0)
    assert 5.0 <= short < 5.6 and at_20_m < 20.0
    with pytest.raises(ConfigError) as info:
        scan_step_period_s(micron, 10.0, steps=0)
    assert info.value.key == "steps"
    with pytest.raises(ConfigError):
        scan_step_period_s(INSTRUMENT_PRESETS["ping2"])
