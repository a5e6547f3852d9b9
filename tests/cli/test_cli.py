"""The ``sonarsim`` command line, run in a subprocess and in-process via ``sonarsim.cli.main.main``.

Bad input must end with a non-zero exit status and a message on stderr naming the key or file,
never a traceback, and must leave no partial files behind.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from sonarsim.cli import main as cli

PRESET_NAMES = [
    "aris3000-128", "aris3000-64", "aris1800-96", "aris1800-48", "aris1200-48", "aris1800-96-telephoto",
    "aris1800-48-telephoto", "aris1200-48-telephoto", "didson300", "oculus-m750d-lf", "oculus-m750d-hf",
    "oculus-m1200d-lf", "oculus-m1200d-hf", "blueview-p900-130", "gemini-720i",
]
NPZ_KEYS = {"polar", "range_m", "azimuth_deg", "object", "ground", "single", "config_json"}

# A small, fast scene: 8 beams x 50 bins, 8 elevation samples.
TINY_SCENE = {
    "sonar": {
        "n_beams": 8, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 10.0,
        "range_min_m": 0.5, "range_max_m": 3.0, "n_range_bins": 50,
        "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]},
    },
    "render": {"elevation_samples": 8},
    "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
    "objects": [{"name": "block", "primitive": "box", "size_m": [0.3, 0.3, 0.3],
                 "pose": {"position_m": [2.0, 0.0, 0.15]}}],
}


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sonarsim", *map(str, args)],
        cwd=cwd, capture_output=True, text=True, timeout=120,
    )


def run_main(capsys, *args: str) -> tuple[int, str, str]:
    """``cli.main`` in-process; argparse errors (SystemExit) count as the exit status."""
    try:
        code = cli.main([str(a) for a in args])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _leftovers(folder: Path) -> list[str]:
    """Temporary or partial files in ``folder`` (hidden names included)."""
    if not folder.exists():
        return []
    return sorted(n for n in os.listdir(folder) if n.endswith(".tmp") or n.startswith("."))


def _assert_complete_outputs(folder: Path) -> None:
    """Whatever files remain in ``folder`` are complete: PNGs decode, npz files load."""
    assert _leftovers(folder) == []
    for name in os.listdir(folder):
        p = folder / name
        if not p.is_file():
            continue
        if name.endswith(".png"):
            with Image.open(p) as im:
                im.load()
        elif name.endswith(".npz"):
            with np.load(p, allow_pickle=False) as z:
                for key in z.files:
                    z[key]


@pytest.fixture()
def tiny_scene(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY_SCENE))
    return path


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("demo") / "out"
    proc = run_cli("demo", "--out", out, "--elevation-samples", "40")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return out


# --------------------------------------------------------------------------- help and presets


@pytest.mark.parametrize("sub", [[], ["render"], ["demo"], ["presets"]], ids=["top", "render", "demo", "presets"])
def test_help_subprocess(sub) -> None:
    proc = run_cli(*sub, "--help")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: sonarsim" + (" " + sub[0] if sub else ""))
    assert "Traceback" not in proc.stderr
    if not sub:
        for command in ("render", "demo", "presets"):
            assert command in proc.stdout
    elif sub[0] in ("render", "demo"):
        assert "--out" in proc.stdout and "--bounces" in proc.stdout


@pytest.mark.parametrize("sub", [[], ["render"], ["demo"], ["presets"]], ids=["top", "render", "demo", "presets"])
def test_help_in_process(capsys, sub) -> None:
    code, out, err = run_main(capsys, *sub, "--help")
    assert code == 0
    assert "usage: sonarsim" in out


def test_no_command_is_an_error(capsys) -> None:
    code, out, err = run_main(capsys)
    assert code != 0
    assert "usage" in err and "Traceback" not in err


def test_presets_table_subprocess() -> None:
    proc = run_cli("presets")
    assert proc.returncode == 0, proc.stderr
    listed = [line.split()[0] for line in proc.stdout.splitlines()[1:] if line.strip()]
    assert listed == PRESET_NAMES


def test_presets_json_subprocess() -> None:
    proc = run_cli("presets", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(proc.stdout)
    assert [r["name"] for r in rows] == PRESET_NAMES
    by_name = {r["name"]: r for r in rows}
    assert by_name["aris3000-128"]["n_beams"] == 128
    assert by_name["aris3000-128"]["n_range_bins"] == 1288
    for r in rows:
        assert r["range_max_m"] > r["range_min_m"] >= 0
        assert 0 < r["azimuth_fov_deg"] < 180 and 0 < r["elevation_fov_deg"] < 180


def test_presets_in_process(capsys) -> None:
    code, out, err = run_main(capsys, "presets")
    assert code == 0
    for name in PRESET_NAMES:
        assert name in out
    code, out, err = run_main(capsys, "presets", "--json")
    assert code == 0
    assert {r["name"] for r in json.loads(out)} == set(PRESET_NAMES)


# --------------------------------------------------------------------------- demo and render


def test_demo_writes_all_files(demo_dir: Path) -> None:
    for name in ("scene.yaml", "polar.png", "fan.png", "render.npz"):
        assert (demo_dir / name).is_file(), name
    assert _leftovers(demo_dir) == []
    with Image.open(demo_dir / "polar.png") as im:
        im.load()
        assert im.size == (128, 1288)  # width = beams, height = range bins
    with Image.open(demo_dir / "fan.png") as im:
        im.load()
        assert im.width > 0 and im.height > 0
    doc = yaml.safe_load((demo_dir / "scene.yaml").read_text())
    assert set(doc) >= {"sonar", "objects"}


def test_demo_npz_contents(demo_dir: Path) -> None:
    with np.load(demo_dir / "render.npz", allow_pickle=False) as z:
        assert NPZ_KEYS <= set(z.files)
        polar = z["polar"]
        assert polar.shape == (1288, 128)
        assert polar.dtype == np.float32
        assert np.all(np.isfinite(polar)) and np.any(polar > 0)
        assert z["range_m"].shape == (1288,)
        assert z["azimuth_deg"].shape == (128,)
        for key in ("object", "ground", "single"):
            assert z[key].shape == (1288, 128)
        config = json.loads(str(z["config_json"][()]))
    assert isinstance(config, dict)


def test_render_reproduces_demo_with_same_override(demo_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "again"
    proc = run_cli("render", demo_dir / "scene.yaml", "--out", out, "--elevation-samples", "40")
    assert proc.returncode == 0, proc.stderr
    with np.load(demo_dir / "render.npz") as a, np.load(out / "render.npz") as b:
        assert a["polar"].shape == b["polar"].shape
        assert np.allclose(a["polar"], b["polar"])


def test_demo_scene_yaml_reproduces_the_demo_render(demo_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "again"
    proc = run_cli("render", demo_dir / "scene.yaml", "--out", out)
    assert proc.returncode == 0, proc.stderr
    with np.load(demo_dir / "render.npz") as a, np.load(out / "render.npz") as b:
        assert np.allclose(a["polar"], b["polar"])


def test_render_in_process(capsys, tiny_scene: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out, "--bounces", "1,2", "--components")
    assert code == 0, err
    with np.load(out / "render.npz") as z:
        assert z["polar"].shape == (50, 8)
        assert json.loads(str(z["config_json"][()]))["render"]["bounces"] == [1, 2]
    with Image.open(out / "polar.png") as im:
        assert im.size == (8, 50)
    assert (out / "polar_object.png").is_file()
    _assert_complete_outputs(out)


# --------------------------------------------------------------------------- bad input


def _bad_cases(tmp_path: Path, tiny_scene: Path) -> dict:
    bad_key = tmp_path / "badkey.yaml"
    doc = yaml.safe_load(tiny_scene.read_text())
    doc["sonar"]["range_maximum"] = 4.0
    bad_key.write_text(yaml.safe_dump(doc))
    bad_value = tmp_path / "badvalue.json"
    doc = yaml.safe_load(tiny_scene.read_text())
    doc["objects"][0]["albedo"] = 1.5
    bad_value.write_text(json.dumps(doc))
    bad_mesh = tmp_path / "badmesh.yaml"
    doc = yaml.safe_load(tiny_scene.read_text())
    doc["objects"] = [{"name": "m", "mesh": "nothing_here.stl"}]
    bad_mesh.write_text(yaml.safe_dump(doc))
    broken = tmp_path / "broken.yaml"
    broken.write_text("sonar:\n  n_beams: [1, 2\n")
    a_file = tmp_path / "a_file.txt"
    a_file.write_text("I am a file\n")
    out = tmp_path / "out"
    return {
        "unknown-key": (["render", bad_key, "--out", out], ["sonar.range_maximum", "badkey.yaml"]),
        "bad-value": (["render", bad_value, "--out", out], ["objects[0].albedo", "badvalue.json"]),
        "bad-mesh": (["render", bad_mesh, "--out", out], ["objects[0].mesh", "nothing_here.stl"]),
        "invalid-yaml": (["render", broken, "--out", out], ["broken.yaml", "line"]),
        "missing-scene": (["render", tmp_path / "missing.yaml", "--out", out], ["missing.yaml"]),
        "bounces-4": (["render", tiny_scene, "--out", out, "--bounces", "4"], ["--bounces"]),
        "bounces-text": (["render", tiny_scene, "--out", out, "--bounces", "one"], ["--bounces"]),
        "elevation-samples-0": (["render", tiny_scene, "--out", out, "--elevation-samples", "0"],
                                ["--elevation-samples"]),
        "demo-bounces": (["demo", "--out", out, "--bounces", "1,4"], ["--bounces"]),
        "out-under-file": (["render", tiny_scene, "--out", a_file / "child"], ["a_file.txt"]),
        "out-is-file": (["render", tiny_scene, "--out", a_file], ["a_file.txt"]),
        "demo-out-under-file": (["demo", "--out", a_file / "child", "--elevation-samples", "4"], ["a_file.txt"]),
    }


BAD_IDS = [
    "unknown-key", "bad-value", "bad-mesh", "invalid-yaml", "missing-scene", "bounces-4", "bounces-text",
    "elevation-samples-0", "demo-bounces", "out-under-file", "out-is-file", "demo-out-under-file",
]
# Each error path once in a subprocess (a real process exit); all of them in-process.
SUBPROCESS_IDS = ["unknown-key", "missing-scene", "bounces-4", "out-under-file", "demo-out-under-file"]


def _check_failure(code: int, err: str, expected: list[str], out_dir: Path) -> None:
    assert code != 0
    assert "Traceback" not in err, err
    for text in expected:
        assert text in err, f"{text!r} not in stderr {err!r}"
    # Nothing half-written: the out folder is absent or holds no temporary/partial files.
    if out_dir.is_dir():
        _assert_complete_outputs(out_dir)
        assert not (out_dir / "render.npz").exists()


@pytest.mark.parametrize("case", SUBPROCESS_IDS)
def test_bad_input_subprocess(tmp_path: Path, tiny_scene: Path, case: str) -> None:
    args, expected = _bad_cases(tmp_path, tiny_scene)[case]
    proc = run_cli(*args, cwd=tmp_path)
    _check_failure(proc.returncode, proc.stderr, expected, tmp_path / "out")
    assert proc.stdout == ""


@pytest.mark.parametrize("case", BAD_IDS)
def test_bad_input_in_process(capsys, tmp_path: Path, tiny_scene: Path, case: str) -> None:
    args, expected = _bad_cases(tmp_path, tiny_scene)[case]
    code, out, err = run_main(capsys, *args)
    _check_failure(code, err, expected, tmp_path / "out")
    if not case.startswith(("bounces", "demo-bounces")):
        assert code == cli.EXIT_BAD_INPUT
        assert err.startswith("sonarsim: error: ") or "\nsonarsim: error: " in err


def test_bad_scene_creates_no_out_folder(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    args, _ = _bad_cases(tmp_path, tiny_scene)["unknown-key"]
    run_main(capsys, *args)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("blocked", ["polar.png", "fan.png", "render.npz"])
def test_failed_write_leaves_no_partial_files(capsys, tmp_path: Path, tiny_scene: Path, blocked: str) -> None:
    out = tmp_path / "out"
    (out / blocked).mkdir(parents=True)  # a folder where an output file must go
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == cli.EXIT_BAD_INPUT
    assert "Traceback" not in err
    assert blocked in err
    _assert_complete_outputs(out)
    assert (out / blocked).is_dir() and os.listdir(out / blocked) == []


def test_failed_write_names_the_destination_not_a_temp_file(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    (out / "polar.png").mkdir(parents=True)
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == cli.EXIT_BAD_INPUT
    assert ".tmp" not in err
    assert str(out / "polar.png") in err


def test_failed_npz_write_leaves_nothing(capsys, monkeypatch, tmp_path: Path, tiny_scene: Path) -> None:
    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    from sonarsim.io import npz

    monkeypatch.setattr(npz, "encode_npz", disk_full)
    out = tmp_path / "out"
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == cli.EXIT_BAD_INPUT
    assert "No space left on device" in err and "Traceback" not in err
    assert not (out / "render.npz").exists()
    _assert_complete_outputs(out)


def test_failed_rerender_leaves_only_complete_files(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == 0, err
    before = {n: (out / n).read_bytes() for n in os.listdir(out)}
    # A second render whose npz cannot be written must not damage the first render's files.
    (out / "render.npz").unlink()
    (out / "render.npz").mkdir()
    code, _, err = run_main(capsys, "render", tiny_scene, "--out", out, "--bounces", "1")
    assert code == cli.EXIT_BAD_INPUT
    _assert_complete_outputs(out)
    assert set(os.listdir(out)) == set(before)


def test_render_backend_choices_give_the_same_image(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    from sonarsim.io.output import read_npz

    polar = {}
    for backend in ("embree", "embreex"):
        out = tmp_path / backend
        code, _, err = run_main(capsys, "render", str(tiny_scene), "--out", str(out), "--backend", backend,
                                "--no-figures")
        assert code == 0, err
        polar[backend] = read_npz(out / "render.npz")[0]["polar"]
    np.testing.assert_allclose(polar["embree"], polar["embreex"], rtol=1e-5, atol=1e-12)
    assert polar["embree"].max() > 0
    code, _, err = run_main(capsys, "render", str(tiny_scene), "--out", str(tmp_path / "x"), "--backend", "optix")
    assert code != 0 and "backend" in err and "embreex" in err


# --------------------------------------------------------------------------- warnings

# The sonar at z 1 m above a surface at 0.5 m whose normal points down (away from it): the
# simulator warns that the sonar is on the plane's dry side.
DRY_SIDE_WARNING = ("sonarsim: warning: the sonar is on the dry side of the planes 'surface' (their normals point "
                    "away from it): for this sonar they neither echo nor reflect, and it sees through them")


@pytest.fixture()
def dry_side_scene(tmp_path: Path) -> Path:
    doc = dict(TINY_SCENE, planes=[{"name": "surface", "point_m": [0, 0, 0.5], "normal": [0, 0, -1],
                                    "albedo": 0.0, "specular": 0.9}])
    path = tmp_path / "dry.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _warning_lines(stderr: str) -> list[str]:
    """Lines of stderr that are, or look like, warnings: ours, or Python's raw ``UserWarning:``."""
    return [line for line in stderr.splitlines() if "warning:" in line.lower()]


def test_a_warning_is_one_sonarsim_line(tmp_path: Path, dry_side_scene: Path) -> None:
    proc = run_cli("render", dry_side_scene, "--out", tmp_path / "out", "--no-figures")
    assert proc.returncode == 0, proc.stderr
    # Python's own form would add "render.py:182: UserWarning: ..." and the line of code.
    assert _warning_lines(proc.stderr) == [DRY_SIDE_WARNING]
    assert ".py:" not in proc.stderr and "Simulator(" not in proc.stderr


def test_dataset_workers_warn_in_the_same_form(tmp_path: Path, dry_side_scene: Path) -> None:
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(yaml.safe_dump({
        "seed": 1, "scene": dry_side_scene.name,
        "trajectory": {"rate_hz": 2.0, "generate": {"kind": "orbit", "centre_m": [2, 0, 0], "radius_m": 1.0,
                                                     "z_m": 1.0, "frames": 4}}}))
    proc = run_cli("dataset", scenario, "--out", tmp_path / "ds", "--workers", "2", "--labels", "none",
                   "--no-progress")
    assert proc.returncode == 0, proc.stderr
    # One line from each worker process that built the scene's simulator.
    lines = _warning_lines(proc.stderr)
    assert 1 <= len(lines) <= 2 and set(lines) == {DRY_SIDE_WARNING}, proc.stderr


def test_a_logged_warning_is_one_sonarsim_line(tmp_path: Path, tiny_scene: Path) -> None:
    # The Embree 4 binding made to fail: the ray casters' module logs its fallback.
    script = (
        "import sys\n"
        "import sonarsim.trace.embree4 as embree4\n"
        "from sonarsim.errors import SonarsimError\n"
        "def fail():\n"
        "    raise SonarsimError('no Embree 4 library in this test')\n"
        "embree4.load_binding = fail\n"
        "from sonarsim.cli.main import console_main\n"
        f"sys.argv = ['sonarsim', 'render', {str(tiny_scene)!r}, '--out', {str(tmp_path / 'out')!r}, '--no-figures']\n"
        "console_main()\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert _warning_lines(proc.stderr) == [
        "sonarsim: warning: Embree 4 binding unavailable (no Embree 4 library in this test); using embreex's caster"]
