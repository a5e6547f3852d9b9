"""Tests of the built-in sonar presets and the ARIS beam-angle fits."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from sonarsim.errors import ConfigError
from sonarsim.config.presets import (
    ARIS_BEAM_ANGLE_FITS,
    ARIS_MODES,
    PRESETS,
    SONAR_KEYS,
    Preset,
    aris_beam_angles_deg,
    aris_preset_name,
    beam_angles_from_table,
    fit_beam_angles,
    get_preset,
    normalised_beam_index,
    sine_spaced_beam_angles_deg,
)

SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
ARIS_TABLES = SHARED_DATA / "aris_beam_widths"
OCULUS_PING = SHARED_DATA / "real" / "oculus" / "one_ping_8bit.raw"

EXPECTED_NAMES = {
    "aris3000-128",
    "aris3000-64",
    "aris1800-96",
    "aris1800-48",
    "aris1200-48",
    "aris1800-96-telephoto",
    "aris1800-48-telephoto",
    "aris1200-48-telephoto",
    "didson300",
    "oculus-m750d-lf",
    "oculus-m750d-hf",
    "oculus-m1200d-lf",
    "oculus-m1200d-hf",
    "blueview-p900-130",
    "gemini-720i",
}


def _measured_centres_left_first(table: str) -> np.ndarray:
    """Centre column of a Sound Metrics table, flipped to left-most first."""
    path = ARIS_TABLES / table
    if not path.is_file():
        pytest.skip(f"measured ARIS tables not available ({path})")
    data = np.genfromtxt(path, delimiter=",", names=True)
    # Beam 0 is the right-most beam in these tables; check the file agrees before flipping.
    assert np.all(np.diff(data["beam"]) == 1)
    return data["center_deg"][::-1]


# ---------------------------------------------------------------------------------------------
# Presets
# ---------------------------------------------------------------------------------------------


def test_preset_names_are_exactly_the_documented_ones():
    assert set(PRESETS) == EXPECTED_NAMES
    for name, preset in PRESETS.items():
        assert preset.name == name


@pytest.mark.parametrize("name", sorted(EXPECTED_NAMES))
def test_preset_keys_and_values_are_sane(name):
    preset = get_preset(name)
    sonar = preset.sonar
    assert set(sonar) <= SONAR_KEYS
    assert preset.description and preset.source

    # Exactly one way of giving the beams and one of giving the range bins.
    assert ("azimuth_fov_deg" in sonar) != ("beam_angles_deg" in sonar)
    assert ("n_range_bins" in sonar) != ("range_resolution_m" in sonar)

    n_beams = sonar["n_beams"]
    assert isinstance(n_beams, int) and n_beams >= 1
    if "beam_angles_deg" in sonar:
        angles = sonar["beam_angles_deg"]
        assert isinstance(angles, tuple)
        assert len(angles) == n_beams
        assert all(isinstance(a, float) for a in angles)
        assert np.all(np.diff(angles) < 0), "beam angles must be strictly descending"
        # Left-most beam is the most positive azimuth (to the sonar's left).
        assert angles[0] > 0 > angles[-1]
        spacing = (angles[0] - angles[-1]) / (n_beams - 1)
        fov = angles[0] - angles[-1] + spacing  # edge to edge, approximately
        assert all(abs(a) < 90.0 for a in angles)
    else:
        fov = sonar["azimuth_fov_deg"]
        spacing = fov / n_beams
    assert 0.0 < fov < 180.0

    # A beam is narrower than the fan and at least as wide as the spacing it tiles.
    width = sonar["beam_width_deg"]
    assert 0.0 < width < fov
    assert width >= 0.9 * spacing

    assert 0.0 < sonar["elevation_fov_deg"] < 180.0
    assert 0.0 <= sonar["range_min_m"] < sonar["range_max_m"]
    if "n_range_bins" in sonar:
        assert isinstance(sonar["n_range_bins"], int) and sonar["n_range_bins"] >= 1
    else:
        assert 0.0 < sonar["range_resolution_m"] < sonar["range_max_m"] - sonar["range_min_m"]
    assert sonar["frequency_khz"] > 0.0


def test_preset_sonar_mapping_is_read_only():
    sonar = get_preset("aris3000-128").sonar
    with pytest.raises(TypeError):
        sonar["n_beams"] = 3  # type: ignore[index]
    with pytest.raises(AttributeError):
        get_preset("aris3000-128").name = "other"  # type: ignore[misc]


def test_preset_freezes_lists_into_tuples():
    angles = [1.0, 0.0, -1.0]
    preset = Preset(
        name="custom",
        description="three beams",
        source="test",
        sonar={
            "n_beams": 3,
            "beam_angles_deg": angles,
            "beam_width_deg": 1.0,
            "elevation_fov_deg": 10.0,
            "range_min_m": 0.5,
            "range_max_m": 5.0,
            "n_range_bins": 100,
            "frequency_khz": 1000.0,
        },
    )
    angles.append(-2.0)  # the caller's list must not leak into the preset
    assert preset.sonar["beam_angles_deg"] == (1.0, 0.0, -1.0)


@pytest.mark.parametrize(
    "change",
    [
        {"MinRange": 0.5},  # unknown key (the HoloOcean failure the design notes warn of)
        {"azimuth_fov_deg": 30.0},  # both fov and explicit angles
        {"range_resolution_m": 0.01},  # both bins and resolution
    ],
)
def test_preset_rejects_bad_keys(change):
    sonar = dict(get_preset("aris3000-128").sonar)
    sonar.update(change)
    with pytest.raises(ConfigError):
        Preset(name="bad", description="", source="", sonar=sonar)


def test_unknown_preset_names_the_preset_and_lists_known_ones():
    with pytest.raises(ConfigError) as info:
        get_preset("aris9000")
    error = info.value
    assert error.key == "sonar.preset"
    assert "'aris9000'" in str(error)
    assert "aris3000-128" in str(error) and "gemini-720i" in str(error)
    assert isinstance(error, ValueError)


def test_aris_presets_use_the_fitted_beam_angles():
    for name, n_beams in (("aris3000-128", 128), ("aris3000-64", 64)):
        preset_angles = np.array(get_preset(name).sonar["beam_angles_deg"])
        np.testing.assert_allclose(
            preset_angles, aris_beam_angles_deg("ARIS3000", n_beams), atol=1e-6
        )


# Every model x beam count x lens of Sound Metrics' lookup (aris-file-sdk Metrics.cs), with the
# measured table it uses, the table's fan edge to edge (degrees, from the CSVs' centres) and the
# lens's elevation aperture.
ARIS_LOOKUP = [
    ("ARIS1200", 48, False, "aris1200-48", "ARIS1800_1200_48.csv", 14.0),
    ("ARIS1200", 48, True, "aris1200-48-telephoto", "ARIS_Telephoto_48.csv", 3.0),
    ("ARIS1800", 48, False, "aris1800-48", "ARIS1800_1200_48.csv", 14.0),
    ("ARIS1800", 48, True, "aris1800-48-telephoto", "ARIS_Telephoto_48.csv", 3.0),
    ("ARIS1800", 96, False, "aris1800-96", "ARIS1800_96.csv", 14.0),
    ("ARIS1800", 96, True, "aris1800-96-telephoto", "ARIS_Telephoto_96.csv", 3.0),
    ("ARIS3000", 64, False, "aris3000-64", "ARIS3000_64.csv", 14.0),
    ("ARIS3000", 128, False, "aris3000-128", "ARIS3000_128.csv", 14.0),
]


@pytest.mark.parametrize("model, n_beams, telephoto, name, table, elevation", ARIS_LOOKUP)
def test_every_aris_lens_has_a_preset_with_its_table_and_aperture(model, n_beams, telephoto, name, table, elevation):
    assert aris_preset_name(model, n_beams, telephoto) == name
    sonar = get_preset(name).sonar
    assert sonar["n_beams"] == n_beams and sonar["elevation_fov_deg"] == elevation
    np.testing.assert_allclose(sonar["beam_angles_deg"], _measured_centres_left_first(table), atol=0.01)
    assert f"{table[:-4]}" in get_preset(name).source


def test_aris_combinations_without_a_table_have_no_preset():
    assert aris_preset_name("ARIS 3000", 128, telephoto=True) is None  # no telephoto table for the 3000
    assert aris_preset_name("ARIS1200", 96, telephoto=False) is None  # the 1200 has 48 beams only
    assert len(ARIS_MODES) == len(ARIS_LOOKUP)


@pytest.mark.parametrize("name, start, end", [
    # SDK limits: window start >= 0.7 m; window end <= 20 m (3000), 50 m (1800), 100 m (1200).
    ("aris3000-128", 0.7, 20.0), ("aris3000-64", 0.7, 20.0), ("aris1800-96", 0.7, 50.0),
    ("aris1800-48", 0.7, 50.0), ("aris1200-48", 0.7, 100.0), ("aris1200-48-telephoto", 0.7, 100.0),
])
def test_aris_preset_windows_are_inside_the_models_limits(name, start, end):
    sonar = get_preset(name).sonar
    assert start <= sonar["range_min_m"] < sonar["range_max_m"] <= end


def test_the_telephoto_lens_fan_is_half_the_standard_lens_fan():
    # Measured tables: 15.0 deg against 27.7 deg edge to edge (ARIS 1800 / 1200, 48 beams).
    tele = np.array(get_preset("aris1200-48-telephoto").sonar["beam_angles_deg"])
    std = np.array(get_preset("aris1200-48").sonar["beam_angles_deg"])
    spacing = lambda a: (a[0] - a[-1]) / (len(a) - 1)  # noqa: E731
    assert tele[0] - tele[-1] + spacing(tele) == pytest.approx(15.0, abs=0.1)
    assert std[0] - std[-1] + spacing(std) == pytest.approx(27.7, abs=0.15)


def test_aris3000_fan_spans_the_published_30_degrees():
    # Sound Metrics quotes 30 deg; the fitted outermost centres plus half a spacing each side.
    for n_beams in (64, 128):
        angles = aris_beam_angles_deg("ARIS 3000", n_beams)
        half_spacing = 0.5 * (angles[0] - angles[1])
        span = angles[0] - angles[-1] + 2 * half_spacing
        assert span == pytest.approx(30.0, abs=0.5)


def test_oculus_presets_put_outermost_beam_centres_at_half_the_aperture():
    for name, aperture in (
        ("oculus-m750d-lf", 130.0),
        ("oculus-m750d-hf", 70.0),
        ("oculus-m1200d-lf", 130.0),
        ("oculus-m1200d-hf", 60.0),
    ):
        angles = get_preset(name).sonar["beam_angles_deg"]
        assert angles[0] == pytest.approx(aperture / 2, abs=1e-6)
        assert angles[-1] == pytest.approx(-aperture / 2, abs=1e-6)
        # Even in sine, so the spacing in angle grows towards the edges.
        steps = -np.diff(angles)
        assert steps[0] > steps[len(steps) // 2]


# ---------------------------------------------------------------------------------------------
# Beam-angle fits
# ---------------------------------------------------------------------------------------------


def test_normalised_beam_index_is_symmetric_and_left_first():
    u = normalised_beam_index(4)
    np.testing.assert_allclose(u, [0.75, 0.25, -0.25, -0.75])
    # A uniform fan is theta = (F/2) u: the conventions' F/2 - (j + 0.5) F/N.
    fov, n = 30.0, 128
    j = np.arange(n)
    np.testing.assert_allclose(fov / 2 * normalised_beam_index(n), fov / 2 - (j + 0.5) * fov / n)


@pytest.mark.parametrize(("model", "n_beams"), sorted(ARIS_BEAM_ANGLE_FITS))
def test_aris_fit_matches_the_measured_table(model, n_beams):
    fit = ARIS_BEAM_ANGLE_FITS[(model, n_beams)]
    measured = _measured_centres_left_first(fit.table)
    assert measured.size == n_beams == fit.n_beams
    fitted = aris_beam_angles_deg(model, n_beams)
    error = fitted - measured
    assert np.max(np.abs(error)) <= fit.max_error_deg
    assert math.sqrt(np.mean(error**2)) <= fit.rms_error_deg
    # The stated bound is "well below a tenth of the beam spacing".
    assert fit.max_error_deg <= np.min(-np.diff(measured)) / 20


@pytest.mark.parametrize(("model", "n_beams"), sorted(ARIS_BEAM_ANGLE_FITS))
def test_aris_fit_coefficients_are_reproducible(model, n_beams):
    fit = ARIS_BEAM_ANGLE_FITS[(model, n_beams)]
    measured = _measured_centres_left_first(fit.table)
    degree = len(fit.coefficients) - 1
    odd_form = all(c == 0.0 for c in fit.coefficients[2::2])
    refit = fit_beam_angles(measured, degree, odd=odd_form)
    np.testing.assert_allclose(refit, fit.coefficients, atol=1e-6)


def test_aris_fit_angles_are_descending_and_named_loosely():
    for spelling in ("ARIS3000", "aris-3000", "Aris 3000", "ARIS_3000"):
        angles = aris_beam_angles_deg(spelling, 128)
        assert angles.shape == (128,)
        assert np.all(np.diff(angles) < 0)
    np.testing.assert_array_equal(
        aris_beam_angles_deg("telephoto", 48), aris_beam_angles_deg("ARIS-Telephoto", 48)
    )
    np.testing.assert_array_equal(
        aris_beam_angles_deg("ARIS1200", 48), aris_beam_angles_deg("ARIS1800", 48)
    )


def test_aris_fit_unknown_model_or_beam_count_raises():
    with pytest.raises(ConfigError, match="ARIS 3000|ARIS3000"):
        aris_beam_angles_deg("ARIS3000", 96)
    with pytest.raises(ConfigError):
        aris_beam_angles_deg("DIDSON", 96)


def test_sine_spaced_angles_match_a_recorded_oculus_ping():
    if not OCULUS_PING.is_file():
        pytest.skip(f"Oculus recording not available ({OCULUS_PING})")
    message = OCULUS_PING.read_bytes()
    (n_beams,) = struct.unpack_from("<H", message, 108)
    bearings = np.frombuffer(message, dtype="<i2", count=n_beams, offset=122) / 100.0
    # The sonar lists bearings from -30 to +30 deg; compare magnitudes in our left-first order.
    ours = sine_spaced_beam_angles_deg(60.0, n_beams)
    np.testing.assert_allclose(np.sort(ours), np.sort(bearings), atol=0.0101)
    # Evenly spaced angles would be off by more than half a degree.
    uniform = np.linspace(-30.0, 30.0, n_beams)
    assert np.max(np.abs(uniform - np.sort(bearings))) > 0.5


# ---------------------------------------------------------------------------------------------
# Reading beam tables
# ---------------------------------------------------------------------------------------------


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_beam_table_round_trips_and_flips_to_left_first(tmp_path):
    centres = np.array([-1.5, -0.5, 0.5, 1.5])  # ARIS order: beam 0 right-most
    lines = ["beam,center_deg,left_deg,right_deg"]
    for beam, c in enumerate(centres):
        lines.append(f"{beam},{c:.4f},{c - 0.5:.4f},{c + 0.5:.4f}")
    path = _write(tmp_path / "table.csv", "\n".join(lines) + "\n")
    angles = beam_angles_from_table(path)
    np.testing.assert_allclose(angles, centres[::-1])
    # Written back left-most first, it reads the same.
    again = _write(tmp_path / "again.txt", "\n".join(f"{a}" for a in angles))
    np.testing.assert_allclose(beam_angles_from_table(again), angles)


def test_beam_table_single_column_either_order_with_comments(tmp_path):
    text = "# measured 2024\nangle_deg\n\n-2.0\n-1.0\n 0.5 \n2.0\n"
    ascending = _write(tmp_path / "asc.txt", text)
    np.testing.assert_allclose(beam_angles_from_table(ascending), [2.0, 0.5, -1.0, -2.0])
    descending = _write(tmp_path / "desc.txt", "2.0\n0.5\n-1.0\n-2.0\n")
    np.testing.assert_allclose(beam_angles_from_table(descending), [2.0, 0.5, -1.0, -2.0])


def test_beam_table_reads_the_measured_aris_file():
    measured = _measured_centres_left_first("ARIS3000_128.csv")
    np.testing.assert_allclose(
        beam_angles_from_table(ARIS_TABLES / "ARIS3000_128.csv"), measured
    )


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("", "empty"),
        ("# only a comment\n", "empty"),
        ("angle_deg\n", "no angles"),
        ("1.0\nabc\n-1.0\n", "'abc' is not a number"),
        ("1.0\n1.0\n-1.0\n", "strictly"),
        ("1.0\n-1.0\n0.5\n", "strictly"),
        ("95.0\n0.0\n", "(-90, 90)"),
        ("beam,centre,left,right\n0,1,0,2\n", "center_deg"),
        ("0,1.0\n1,2.0\n", "header"),
        ("beam,center_deg\n0,1.0\n1\n", "line 3"),
        ("nan\n0\n", "finite"),
    ],
)
def test_bad_beam_table_raises_config_error_naming_the_file(tmp_path, text, fragment):
    path = _write(tmp_path / "bad_table.csv", text)
    with pytest.raises(ConfigError) as info:
        beam_angles_from_table(path, key="sonar.beam_table")
    message = str(info.value)
    assert "bad_table.csv" in message
    assert fragment in message
    assert info.value.key == "sonar.beam_table"


def test_missing_beam_table_raises_config_error_naming_the_file(tmp_path):
    path = tmp_path / "no_such_table.csv"
    with pytest.raises(ConfigError) as info:
        beam_angles_from_table(path)
    assert "no_such_table.csv" in str(info.value)
    assert info.value.source == str(path)
