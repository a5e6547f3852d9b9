"""Sensor presets: one per ARIS model x beam count x lens, from Sound Metrics' measured tables;
a preset of another device refused on the command line (``--force`` takes it); a saturated
output warned about with its fraction."""

from __future__ import annotations

import copy
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from sonarsim.cli.main import main
from sonarsim.errors import ConfigError
from sonarsim.config.loader import parse_sonar
from sonarsim.config.presets import ARIS_ELEVATION_FOV_DEG, ARIS_MODES, PRESETS
from sonarsim.config.sensor import SENSOR_PRESETS, OutputSpec, parse_sensor, preset_device_mismatch
from sonarsim.renderer.simulator import Simulator
from sonarsim.sensor.output import (SATURATION_WARN_FRACTION, SaturationWarning, saturated_fraction,
                                    saturation_warning)

TABLES = Path(__file__).resolve().parents[3] / "shared" / "data" / "aris_beam_widths"

# Each ARIS preset's measured table (aris-file-sdk beam-width-metrics; the ARIS 1200 has the 48-beam
# ARIS 1800 lens's), carrier (kHz: the model's high frequency for its high-frequency beam count) and
# lens.
ARIS = {
    "aris3000-128": ("ARIS3000_128.csv", 3000.0, "standard"),
    "aris3000-64": ("ARIS3000_64.csv", 1800.0, "standard"),
    "aris1800-96": ("ARIS1800_96.csv", 1800.0, "standard"),
    "aris1800-48": ("ARIS1800_1200_48.csv", 1100.0, "standard"),
    "aris1200-48": ("ARIS1800_1200_48.csv", 1200.0, "standard"),
    "aris1800-96-telephoto": ("ARIS_Telephoto_96.csv", 1800.0, "telephoto"),
    "aris1800-48-telephoto": ("ARIS_Telephoto_48.csv", 1100.0, "telephoto"),
    "aris1200-48-telephoto": ("ARIS_Telephoto_48.csv", 1200.0, "telephoto"),
}


def _table_beam_width_deg(table: str) -> float:
    """A measured table's mean beam width: left-to-right edges (the beams tile the fan), or, for
    ARIS_Telephoto_48, whose edge columns span half its centres' spacing, the spacing."""
    path = TABLES / table
    if not path.is_file():
        pytest.skip(f"the measured ARIS tables are not present ({path})")
    data = np.genfromtxt(path, delimiter=",", names=True)
    if table == "ARIS_Telephoto_48.csv":
        return float(np.mean(np.abs(np.diff(data["center_deg"]))))
    return float(np.mean(np.abs(data["left_deg"] - data["right_deg"])))


def test_every_aris_model_and_lens_has_a_sensor_preset_and_every_sonar_preset_one():
    assert {mode.name for mode in ARIS_MODES} == set(ARIS)
    assert set(SENSOR_PRESETS) == set(PRESETS)  # each device: its geometry and its sensor, one name


@pytest.mark.parametrize("name", sorted(ARIS))
def test_aris_sensor_preset_against_the_measured_table(name):
    table, khz, lens = ARIS[name]
    spec = parse_sensor({"preset": name})
    assert spec.frequency_khz == khz
    assert spec.azimuth_pattern.width_deg == pytest.approx(_table_beam_width_deg(table), abs=5e-4)
    assert spec.elevation_pattern.width_deg == ARIS_ELEVATION_FOV_DEG[lens] == (14.0 if lens == "standard" else 3.0)
    assert spec.elevation_pattern.span_deg == 3 * spec.elevation_pattern.width_deg  # three widths, under 60
    assert spec.output.dtype == "uint8"  # ARIS files store 8-bit samples
    # The sonar preset of the same name is the same device: the same carrier and widths.
    sonar = PRESETS[name].sonar
    assert (sonar["frequency_khz"], sonar["beam_width_deg"], sonar["elevation_fov_deg"]) == (
        spec.frequency_khz, spec.azimuth_pattern.width_deg, spec.elevation_pattern.width_deg)


def test_the_recordings_device_renders_with_its_own_sensor_preset():
    # ../shared/data/real/aris/sample.aris is an ARIS 1200 with the telephoto lens (48 beams).
    doc = {"sonar": {"preset": "aris1200-48-telephoto", "n_range_bins": 200,
                     "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 10, 0]}},
           "render": {"elevation_samples": 8}, "ground": {"height_m": 0.0, "albedo": 0.5},
           "sensor": {"preset": "aris1200-48-telephoto"}}
    with Simulator(doc) as sim:
        image = sim.render(speckle=False).polar
    assert image.shape == (200, 48) and 0 < image.max() <= 255


# --- a preset of another device -----------------------------------------------------------------


def _sonar(**d):
    return parse_sonar({"n_beams": 16, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 10.0, "range_min_m": 0.5,
                        "range_max_m": 3.0, "n_range_bins": 40, **d}, None)


def test_device_of_a_preset_sonar_is_its_preset():
    oculus = parse_sonar({"preset": "oculus-m1200d-hf"}, None)
    assert preset_device_mismatch("oculus-m1200d-hf", oculus) is None
    message = preset_device_mismatch("aris3000-128", oculus)
    assert "'aris3000-128'" in message and "'oculus-m1200d-hf'" in message and "--sensor oculus-m1200d-hf" in message
    # Another mode of the same model is another carrier and beam width: refused too.
    assert preset_device_mismatch("aris3000-64", parse_sonar({"preset": "aris3000-128"}, None)) is not None
    # Keys overriding the preset keep its device.
    assert preset_device_mismatch("aris1200-48", parse_sonar({"preset": "aris1200-48", "n_range_bins": 99}, None)) is None


def test_device_of_a_sonar_without_preset_is_told_by_its_frequency():
    assert preset_device_mismatch("aris3000-128", _sonar()) is None  # no frequency: cannot tell
    assert preset_device_mismatch("aris3000-128", _sonar(frequency_khz=2950.0)) is None  # within 5 %
    message = preset_device_mismatch("aris3000-128", _sonar(frequency_khz=2100.0))
    assert "3000 kHz" in message and "2100 kHz" in message and "sonar.frequency_khz" in message


SMALL_ARIS = {"sonar": {"preset": "aris1200-48", "n_range_bins": 60, "range_max_m": 4.0,
                        "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}},
              "render": {"elevation_samples": 4}, "ground": {"height_m": 0.0, "albedo": 0.5}}


def test_sensor_option_of_another_device_is_refused_unless_forced(tmp_path, capsys):
    scene = tmp_path / "aris.yaml"
    scene.write_text(yaml.safe_dump(SMALL_ARIS))
    out = tmp_path / "refused"
    assert main(["render", str(scene), "--out", str(out), "--sensor", "aris3000-128", "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["sonarsim: error: --sensor: sensor preset 'aris3000-128' models another device than the scene's "
                   "sonar (sonar preset 'aris1200-48'): use --sensor aris1200-48, or --force to take it anyway"]
    assert not out.exists()  # refused before anything was written
    assert main(["render", str(scene), "--out", str(out), "--force", "--no-figures"]) == 2  # --force alone
    assert capsys.readouterr().err.strip() == ("sonarsim: error: --force: takes a --sensor preset of another device "
                                               "than the scene's sonar: give it with --sensor PRESET")
    assert not out.exists()
    for options in (["--sensor", "aris1200-48"], ["--sensor", "aris3000-128", "--force"], ["--sensor", "none"]):
        folder = tmp_path / "_".join(options).strip("-")
        assert main(["render", str(scene), "--out", str(folder), "--no-figures", *options]) == 0, options
        assert (folder / "render.npz").is_file()


def test_a_scene_file_pairing_another_devices_sensor_preset_is_refused(tmp_path, capsys):
    from sonarsim.config.loader import load_scene

    doc = copy.deepcopy(SMALL_ARIS)
    doc["sensor"] = {"preset": "aris3000-128"}
    scene = tmp_path / "paired.yaml"
    scene.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=r"sensor\.preset: sensor preset 'aris3000-128' models another device "
                                          r".*sonar preset 'aris1200-48'\): use sensor\.preset: aris1200-48"):
        load_scene(scene)
    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensor.preset" in err[0] and not out.exists()
    doc["sensor"] = {"preset": "aris1200-48"}  # its own device's preset loads
    scene.write_text(yaml.safe_dump(doc))
    assert load_scene(scene).sensor.preset == "aris1200-48"


# --- saturation -----------------------------------------------------------------------------------

UINT8 = OutputSpec(dtype="uint8")


def _frame(n_saturated: int, size: int = 1000, top: float = 255.0) -> np.ndarray:
    values = np.full(size, 100.0, np.float32)
    values[:n_saturated] = top
    return values.reshape(40, 25)


def test_saturated_fraction_counts_pixels_at_full_scale():
    assert saturated_fraction(_frame(96), UINT8) == pytest.approx(0.096)
    assert saturated_fraction(_frame(96, top=254.0), UINT8) == 0.0  # one count below: not saturated
    assert saturated_fraction(_frame(96), None) == 0.0  # powers: no full scale
    assert saturated_fraction(_frame(10, top=1.0) / 255.0, OutputSpec(dtype="float32")) == 0.0
    assert saturated_fraction(np.ones((4, 4), np.float32), OutputSpec(dtype="float32")) == 1.0
    assert saturated_fraction(np.zeros((0, 3), np.float32), UINT8) == 0.0


def test_saturation_warns_above_the_threshold_only():
    assert SATURATION_WARN_FRACTION == 0.01
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails
        assert saturation_warning(_frame(10), UINT8) == 0.01  # exactly 1 %: quiet
        assert saturation_warning(_frame(0), UINT8) == 0.0
    with pytest.warns(SaturationWarning) as record:
        saturation_warning(_frame(96), UINT8)
    (w,) = record
    message = str(w.message)
    assert "9.6 % of its pixels are at the device's maximum (255" in message and "\n" not in message
    assert "sensor.gain_db" in message and "sensor.output.ceiling_db" in message


def _floor_scene(gain_db: float) -> dict:
    return {"sonar": {"n_beams": 16, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
                      "range_max_m": 4.0, "n_range_bins": 80, "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 25, 0]}},
            "render": {"elevation_samples": 8}, "ground": {"height_m": 0.0, "albedo": 0.5},
            "sensor": {"preset": "aris3000-64", "gain_db": gain_db}}


def test_a_saturating_render_warns_once_with_its_fraction():
    with Simulator(_floor_scene(60.0)) as sim:
        with pytest.warns(SaturationWarning) as record:
            first = sim.render(frame=0).polar
        fraction = np.mean(first >= 255)
        assert fraction > 0.05
        (w,) = [r for r in record if r.category is SaturationWarning]
        assert f"{100 * fraction:.1f} % of its pixels" in str(w.message)
        with warnings.catch_warnings():
            warnings.simplefilter("error", SaturationWarning)
            sim.render(frame=1)  # said once per sensor: a dataset's frames do not repeat it


def test_a_render_within_the_range_of_the_output_does_not_warn():
    with Simulator(_floor_scene(0.0)) as sim, warnings.catch_warnings():
        warnings.simplefilter("error", SaturationWarning)
        image = sim.render(frame=0).polar
        sim.render(speckle=False)
    assert 0 < image.max() and np.mean(image >= 255) <= SATURATION_WARN_FRACTION


def test_the_command_says_the_saturation_in_one_line(tmp_path):
    scene = tmp_path / "hot.yaml"
    scene.write_text(yaml.safe_dump(copy.deepcopy(_floor_scene(60.0))))
    proc = subprocess.run([sys.executable, "-m", "sonarsim", "render", str(scene), "--out", str(tmp_path / "o"),
                           "--no-figures"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "warning" in line]
    assert len(lines) == 1 and lines[0].startswith("sonarsim: warning: the sensor output saturates: "), proc.stderr
    with np.load(tmp_path / "o" / "render.npz") as z:
        assert f"{100 * np.mean(z['polar'] >= 255):.1f} %" in lines[0]
