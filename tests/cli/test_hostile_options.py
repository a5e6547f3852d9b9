"""Hostile values through the command-line options (issue 11 review): each ends in exit status
2 and one line naming the option, before any output folder is touched; never a traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml

import sonarsim
from sonarsim.cli.main import main
from sonarsim.core import memory
from sonarsim.errors import ConfigError

SCENE = {
    "sonar": {"n_beams": 8, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 10.0, "range_min_m": 0.5,
              "range_max_m": 3.0, "n_range_bins": 50,
              "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}},
    "render": {"elevation_samples": 8},
    "ground": {"height_m": 0.0},
}


@pytest.fixture()
def scene(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(SCENE))
    return path


def _sonarsim(*args, env=None):
    return subprocess.run([sys.executable, "-m", "sonarsim.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=120, env=env)


@pytest.mark.parametrize("text", ["1e400", "1e19", "2000000P0"])
def test_memory_budgets_beyond_any_integer_are_refused(text):
    with pytest.raises(ValueError, match="above 1 EiB|memory size"):
        memory.parse_size(text)


def test_an_infinite_budget_in_the_environment_is_one_line(tmp_path):
    import os

    r = _sonarsim("demo", "--out", tmp_path / "d", env={**os.environ, memory.ENV_VAR: "1e400"})
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert memory.ENV_VAR in r.stderr and "1e400" in r.stderr
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("pixel, message", [
    ("5e-324", "more than 1e300 GiB"),   # the ratio overflows to infinity
    ("1e-300", "3e+300 x 1.04e+300 pixels"),  # 3 m / 1e-300 m rows; 2 x 3 m sin 10 deg / 1e-300 m columns
    ("1e300", "longer than the range window (0.5-3 m)"),
    ("2.6", "allowed: up to 2.5 m"),
])
def test_pixel_sizes_are_refused_before_the_render_naming_the_option(scene, tmp_path, capsys, pixel, message):
    out = tmp_path / "o"
    assert main(["render", str(scene), "--out", str(out), "--pixel-size", pixel]) == 2
    err = capsys.readouterr().err
    line = err.strip().splitlines()
    assert len(line) == 1 and line[0].startswith("sonarsim: error: --pixel-size: "), err
    assert message in err and len(err) < 300
    assert not out.exists()  # refused before the run: nothing created, no record


def test_fan_pixel_sizes_too_small_or_too_long_are_config_errors(tmp_path):
    real = sonarsim.render(SCENE)
    real.save_npz(tmp_path / "r.npz")
    from sonarsim.analysis.comparison import load_image

    image = load_image(tmp_path / "r.npz")
    for pixel in (5e-324, 1e300):
        with pytest.raises(ConfigError) as e:
            image.fan(pixel_size_m=pixel)
        assert e.value.key == "pixel_size_m"
    # The largest pixel allowed still draws a fan.
    assert image.fan(pixel_size_m=2.5).image.size >= 2


def test_ray_counts_name_the_factor_that_made_them_large_and_are_refused_before_the_run(scene, tmp_path, capsys):
    doc = {**SCENE, "render": {"elevation_samples": 1, "azimuth_samples": 10**9}}
    with pytest.raises(ConfigError) as e:
        sonarsim.load_scene(doc)  # when the scene is built, not at the first render
    assert e.value.key == "render.azimuth_samples"
    out = tmp_path / "o"
    assert main(["render", str(scene), "--out", str(out), "--elevation-samples", str(10**12)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sonarsim: error: --elevation-samples: ") and "memory budget" in err
    assert not out.exists()


def test_a_budget_beyond_the_machine_ends_in_one_line_not_a_memory_error(scene, tmp_path, monkeypatch, capsys):
    from sonarsim.renderer import simulator

    def no_memory(*args, **kwargs):
        raise MemoryError("Unable to allocate 191. GiB for an array")

    monkeypatch.setattr(simulator.Simulator, "render", no_memory)
    try:
        assert main(["--max-memory", "10T", "render", str(scene), "--out", str(tmp_path / "o")]) == 2
    finally:
        memory.set_memory_budget(None)
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "out of memory" in err and "1.02e+04 GiB" in err and "--max-memory" in err


@pytest.mark.parametrize("pixel", ["5e-324", "1e-300", "1e300"])
def test_compare_refuses_extreme_pixel_sizes_in_one_line(tmp_path, capsys, pixel):
    sonarsim.render(SCENE).save_npz(tmp_path / "a.npz")
    a = str(tmp_path / "a.npz")
    assert main(["compare", a, a, "--pixel-size", pixel]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "pixel" in err


@pytest.mark.parametrize("command", ["fit", "calibrate"])
@pytest.mark.parametrize("free, message", [("z,z", "a parameter is named twice"), ("z2", "unknown pose parameter 'z2'")])
def test_free_parameter_errors_name_the_option(tmp_path, capsys, command, free, message):
    real = tmp_path / "missing.aris"  # --free is checked before the recording is read
    assert main([command, str(real), "--scene", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "f.yaml"),
                 "--free", free]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sonarsim: error: --free: ") and message in err


@pytest.mark.parametrize("argv", [
    ["fit", "{rec}", "--scene", "{scene}", "--out", "{tmp}/f.yaml", "--image", "{rec}"],
    ["calibrate", "{rec}", "--scene", "{scene}", "--out", "{rec}"],
    ["show", "{tmp}/polar.png", "--out", "{tmp}"],
])
def test_outputs_that_are_the_recording_are_refused(tmp_path, scene, capsys, argv):
    # fit --image REC wrote its PNG over the real recording (exit 0).
    rec = tmp_path / "rec.npz"
    sonarsim.render(SCENE).save_npz(rec)
    (tmp_path / "polar.png").write_bytes(rec.read_bytes())
    before = {p: p.read_bytes() for p in (rec, tmp_path / "polar.png")}
    assert main([a.format(rec=rec, scene=scene, tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "is the recording" in err and "never writes over its inputs" in err
    assert {p: p.read_bytes() for p in before} == before


def test_an_output_name_too_long_for_the_file_system_names_the_option(scene, tmp_path, capsys):
    out = tmp_path / ("a" * 300)
    assert main(["render", str(scene), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sonarsim: error: --out ") and "File name too long" in err and len(err) < 300


@pytest.mark.parametrize("option, value", [("--gain-db", "1e308"), ("--gain-db", "-500"), ("--gain-db", "nan"),
                                           ("--dynamic-range-db", "1e-320"), ("--dynamic-range-db", "0"),
                                           ("--dynamic-range-db", "1e9")])
@pytest.mark.parametrize("command", ["render", "show"])
def test_display_levels_beyond_any_picture_are_refused(scene, tmp_path, capsys, command, option, value):
    # 1e308 dB of gain made an all-white picture (exit 0); 1e-320 dB of range a NumPy warning.
    source = scene if command == "render" else "../shared/data/real/oculus/one_ping_8bit.raw"
    with pytest.raises(SystemExit) as e:
        main([command, str(source), "--out", str(tmp_path / "o"), option, value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert option in err and "expected a number of dB from" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()
