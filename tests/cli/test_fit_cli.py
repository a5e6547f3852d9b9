"""``sonarsim fit`` on the command line: the domain it chooses and says, progress on stderr,
exit status 3 (and nothing written) on a fit that means nothing, the exit codes in --help."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.cli import fit as fit_cli
from sonarsim.cli.main import main
from sonarsim.core.extras import install_command

FLOOR = {"preset": "oculus-m1200d-hf"}


def floor_doc(z: float, pitch: float) -> dict:
    return {"sonar": dict(FLOOR, pose={"position_m": [0, 0, z], "rpy_deg": [0, pitch, 0]}),
            "ground": {"albedo": 0.8}, "render": {"bounces": [1]}}


@pytest.fixture
def floor_case(tmp_path):
    """A floor recorded at z 0.40 m, pitch 28 deg (noise-free), and a scene file to start from."""
    sonarsim.render(sonarsim.load_scene(floor_doc(0.40, 28.0))).save_npz(tmp_path / "real.npz")

    def scene(z: float, pitch: float) -> Path:
        path = tmp_path / f"scene_{z}_{pitch}.yaml"
        path.write_text(yaml.safe_dump(floor_doc(z, pitch)))
        return path

    return tmp_path / "real.npz", scene


def run(argv) -> int:
    """main's status, or the status of the SystemExit it lets through (argparse: 2; fit: 3)."""
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


def test_help_lists_the_exit_statuses(capsys):
    assert run(["fit", "--help"]) == 0
    out = capsys.readouterr().out
    assert "exit status:" in out and "  2  bad input" in out
    assert "  3  the fit found no meaningful pose (nothing written)" in out
    assert "{auto,edges,band}" in out and "--quiet" in out


def test_auto_says_which_domain_and_progress_goes_to_stderr(floor_case, tmp_path, capsys, monkeypatch):
    real, scene = floor_case
    monkeypatch.setattr(fit_cli, "PROGRESS_INTERVAL_S", 0.0)  # every render reported
    out = tmp_path / "fitted.yaml"
    assert run(["fit", "--method", "search", real, "--scene", scene(0.37, 26.0), "--max-renders", 40, "--out", out]) == 0
    err = capsys.readouterr().err.splitlines()
    progress = [line for line in err if line.startswith("sonarsim: fit (band): ")]
    assert len(progress) >= 20 and progress[0].startswith("sonarsim: fit (band): 2/40 renders, best band-edge RMS")
    assert progress[-1].endswith(" s") and "Traceback" not in "\n".join(err)
    assert any(line.startswith("sonarsim: fit: ") and "domain band: the scene's echo is one floor band" in line
               for line in err)
    fitted = sonarsim.load_scene(out).sonar_pose
    assert abs(fitted.position_m[2] - 0.40) < 0.01 and abs(fitted.rpy_deg[1] - 28.0) < 1.0


def test_quiet_silences_progress_and_notes(floor_case, tmp_path, capsys, monkeypatch):
    real, scene = floor_case
    monkeypatch.setattr(fit_cli, "PROGRESS_INTERVAL_S", 0.0)
    out = tmp_path / "fitted.yaml"
    assert run(["fit", "--method", "search", real, "--scene", scene(0.37, 26.0), "--max-renders", 40, "--quiet", "--out", out]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and "near edge RMS" in captured.out and out.exists()


def test_a_terminal_gets_one_status_line_rewritten_in_place():
    import io

    from sonarsim.analysis.fitting import FitProgress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()
    show = fit_cli._Progress(stream)
    show(FitProgress(5, 600, "edges 2/3", 0.75, 1.25))
    show(FitProgress(6, 600, "edges 2/3", 0.74, 1.30))  # within the interval: not shown
    show.close()
    assert stream.getvalue() == ("\rsonarsim: fit (edges 2/3): 5/600 renders, best 1 - edge correlation 0.75, "
                                 "1.2 s\033[K\n")


def assert_one_line_exit_3(status, err, *, says):
    assert status == 3
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sonarsim: error: ") and "Traceback" not in err
    for text in says:
        assert text in lines[0]


def test_a_far_start_exits_3_and_writes_nothing(floor_case, tmp_path, capsys):
    real, scene = floor_case
    out = tmp_path / "out" / "fitted.yaml"
    status = run(["fit", "--method", "search", real, "--scene", scene(1.5, 60.0), "--max-renders", 30, "--quiet", "--out", out])
    captured = capsys.readouterr()
    assert_one_line_exit_3(status, captured.err, says=(
        "real.npz: the fit found no meaningful pose: the render's echo does not line up with the recording's",
        "nothing written; try a starting pose nearer the recording's", "--domain edges"))
    assert "z " in captured.out  # what it found is still shown
    assert not out.exists() and not (tmp_path / "out" / "fitted_fit.png").exists()


def test_a_pose_where_nothing_echoes_exits_3(floor_case, tmp_path, capsys):
    real, scene = floor_case  # pitched 40 deg up: the floor is never seen
    status = run(["fit", real, "--scene", scene(0.4, -40.0), "--domain", "edges", "--max-renders", 6,
                  "--out", tmp_path / "f.yaml"])
    err = capsys.readouterr().err
    assert status == 3 and "no pose at which the scene echoes" in err and "Traceback" not in err
    assert not (tmp_path / "f.yaml").exists()


def test_a_recording_of_noise_exits_3(floor_case, tmp_path, capsys):
    real, scene = floor_case
    image = sonarsim.render(sonarsim.load_scene(floor_doc(0.40, 28.0)))  # its grid, exponential noise in it
    rng = np.random.default_rng(1)
    replace(image, polar=rng.exponential(1.0, image.polar.shape).astype(np.float32),
            components={}).save_npz(tmp_path / "noise.npz")
    status = run(["fit", "--method", "search", tmp_path / "noise.npz", "--scene", scene(0.4, 28.0), "--max-renders", 20, "--quiet",
                  "--out", tmp_path / "f.yaml"])
    # Refused before any search: exponential noise has no echo structure (issue 37).
    assert_one_line_exit_3(status, capsys.readouterr().err, says=(
        "noise.npz: the recording holds no echo to fit: the frame shows no echo structure",))
    assert not (tmp_path / "f.yaml").exists()


@pytest.mark.parametrize("budget", ["0", "-3", "many"])
def test_a_bad_render_budget_is_bad_input(floor_case, tmp_path, capsys, budget):
    real, scene = floor_case
    status = run(["fit", "--method", "search", real, "--scene", scene(0.4, 28.0), "--max-renders", budget, "--out", tmp_path / "f.yaml"])
    err = capsys.readouterr().err
    assert status == 2 and f"--max-renders: expected a number of renders >= 1, got '{budget}'" in err


def test_fit_on_the_real_oculus_ping_writes_the_recording_geometry(shared_data, tmp_path, capsys):
    """The preset of examples/oculus_floor.yaml has 512 beams over 0.1-2 m; the recording has 256
    over 0-2 m. The written scene has the recording's beams and window (as calibrate writes
    them), so its render and the recording compare pixel for pixel, without resampling."""
    from sonarsim.analysis.comparison import compare_images

    ping = shared_data / "real" / "oculus" / "one_ping_8bit.raw"
    if not ping.is_file():
        pytest.skip(f"{ping} is not present")
    example = Path(__file__).resolve().parents[2] / "examples" / "oculus_floor.yaml"
    out = tmp_path / "fitted.yaml"
    assert run(["fit", ping, "--scene", example, "--free", "z,pitch,roll", "--domain", "band", "--quiet",
                "--no-figures", "--out", out]) == 0
    capsys.readouterr()
    real = sonarsim.read(ping)
    start = sonarsim.load_scene(example)
    assert start.sonar.n_beams != real.sonar.n_beams  # what made compare resample before
    doc = yaml.safe_load(out.read_text())
    assert "preset" not in doc["sonar"]  # the preset's beams and window are not the recording's
    fitted = sonarsim.load_scene(out)
    assert fitted.sonar.n_beams == real.sonar.n_beams == 256
    np.testing.assert_array_equal(fitted.sonar.azimuth_deg, real.sonar.azimuth_deg)
    assert (fitted.sonar.range_min_m, fitted.sonar.range_max_m, fitted.sonar.n_range_bins) == (
        real.sonar.range_min_m, real.sonar.range_max_m, real.sonar.n_range_bins)
    np.testing.assert_array_equal(fitted.sonar.range_m, real.sonar.range_m)
    assert fitted.sonar.elevation_fov_deg == start.sonar.elevation_fov_deg  # not in the recording
    # The fitted pose, as before (README: z 0.416 m, pitch 28.8 deg).
    assert fitted.sonar_pose.position_m[2] == pytest.approx(0.416, abs=0.01)
    assert fitted.sonar_pose.rpy_deg[1] == pytest.approx(28.8, abs=0.5)
    render = sonarsim.render(fitted)
    info = compare_images(real, render)["info"]
    assert info["resampled"] is False and info["overlap"] == 1.0


def test_fit_by_gradient_recovers_height_and_tilt_of_a_synthetic_floor(floor_case, tmp_path, capsys):
    """The gradient is the default method where JAX is installed (--method auto)."""
    pytest.importorskip("jax")
    real, scene = floor_case
    out = tmp_path / "fitted.yaml"
    assert run(["fit", real, "--scene", scene(0.45, 31.0), "--out", out, "--no-figures"]) == 0
    captured = capsys.readouterr()
    assert "fit: method gradient;" in captured.err
    assert "domain band: by gradient on the floor band's edges" in captured.err and "Traceback" not in captured.err
    pose = yaml.safe_load(out.read_text())["sonar"]["pose"]
    assert pose["position_m"][2] == pytest.approx(0.40, abs=0.005)
    assert pose["rpy_deg"][1] == pytest.approx(28.0, abs=0.3)


def test_fit_by_gradient_without_jax_names_the_extra(floor_case, tmp_path, capsys, monkeypatch):
    import importlib.util

    real, scene = floor_case
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "jax" else find_spec(name, *a))
    status = run(["fit", real, "--scene", scene(0.45, 31.0), "--method", "gradient", "--out", tmp_path / "f.yaml"])
    err = capsys.readouterr().err
    assert status == 2 and install_command("diff") in err and "Traceback" not in err
    assert not (tmp_path / "f.yaml").exists()


METHODS = ["search", pytest.param("gradient", marks=pytest.mark.skipif(
    __import__("importlib.util").util.find_spec("jax") is None, reason="needs JAX (sonarsim[diff])"))]


@pytest.mark.parametrize("method", METHODS)
def test_one_bright_pixel_on_a_silent_ping_is_refused(shared_data, tmp_path, capsys, method):
    """Issue 37: an all-zero Oculus ping with one bright pixel was fitted to a pitch of 87 deg,
    exit 0. It holds no echo: refused before any search, one line, nothing written."""
    from .crafted import crafted_oculus, one_bright_pixel

    ping = crafted_oculus(shared_data / "real" / "oculus" / "one_ping_8bit.raw", tmp_path / "one_pixel.raw",
                          one_bright_pixel)
    out = tmp_path / "out"
    out.mkdir()
    example = Path(__file__).resolve().parents[2] / "examples" / "oculus_floor.yaml"
    status = run(["fit", ping, "--scene", example, "--method", method, "--out", out / "f.yaml"])
    assert_one_line_exit_3(status, capsys.readouterr().err, says=(
        f"{ping}: the recording holds no echo to fit: the frame's lit region holds 0 pixels", "nothing written"))
    assert list(out.iterdir()) == []


def test_free_parameters_no_floor_determines_are_refused_by_name(floor_case, tmp_path, capsys):
    """Issue 37: ``--free x,y,z,roll,pitch,yaw`` on a flat floor wrote an x and a y that no floor
    determines. x, y and yaw do not change a flat floor's render at all: refused, named."""
    real, scene = floor_case
    out = tmp_path / "out"
    out.mkdir()
    status = run(["fit", "--method", "search", real, "--scene", scene(0.39, 27.0), "--free", "x,y,z,roll,pitch,yaw",
                  "--max-renders", 60, "--quiet", "--out", out / "f.yaml"])
    captured = capsys.readouterr()
    assert_one_line_exit_3(status, captured.err, says=(
        "x, y, yaw do not change the render (a step of x 0.05 m, y 0.05 m, yaw 2 deg either way leaves it unchanged)",
        "leave them out of --free"))
    assert list(out.iterdir()) == []


def test_both_methods_give_the_aris_sample_the_same_bounded_pose(shared_data, tmp_path, capsys):
    """A sea bed lit across the window shows no band edge: the band's cost is flat within its
    bounds. The gradient fitted the images instead and refused by their edges (exit 3) what the
    search bounds (exit 0); now the search's band fit decides for both."""
    pytest.importorskip("jax")
    aris = shared_data / "real" / "aris" / "sample.aris"
    example = Path(__file__).resolve().parents[2] / "examples" / "aris_seabed.yaml"
    poses = {}
    for method in ("search", "gradient"):
        out = tmp_path / f"{method}.yaml"
        assert run(["fit", aris, "--scene", example, "--method", method, "--no-figures", "--out", out]) == 0
        err = capsys.readouterr().err
        assert f"fit: method {method};" in err and "domain band" in err
        poses[method] = yaml.safe_load(out.read_text())["sonar"]["pose"]
    assert poses["search"] == poses["gradient"]


def test_auto_is_the_gradient_with_jax_and_the_search_without(monkeypatch):
    import importlib.util

    notes = []
    expected = "gradient" if importlib.util.find_spec("jax") is not None else "search"
    assert fit_cli.resolve_method("auto", notes.append) == expected
    assert notes == [f"method {expected} (--method auto: " + ("JAX is installed)" if expected == "gradient" else
                     f"JAX is not installed; {install_command('diff')} for the gradient method)")]
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "jax" else find_spec(name, *a))
    assert fit_cli.resolve_method("auto") == "search" and fit_cli.resolve_method("search") == "search"
    with pytest.raises(sonarsim.SonarsimError, match="--method gradient: the differentiable engine needs JAX"):
        fit_cli.resolve_method("gradient")
    # Both commands default to auto.
    from sonarsim.cli.main import build_parser

    parser = build_parser()
    for command in ("fit", "calibrate"):
        args = parser.parse_args([command, "r.npz", "--scene", "s.yaml", "--out", "o.yaml"])
        assert args.method == "auto"
