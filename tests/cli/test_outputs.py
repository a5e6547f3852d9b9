"""What the commands leave in their output folders (issue 11, item 4).

Every command that writes files checks its outputs before any work, removes its temporary files
on every exit path (exceptions, Ctrl-C, SIGTERM), writes a run record last
(``sonarsim-run.json``: status complete, each file's size and sha256) and leaves no stale files
of an earlier run beside its own. Killed runs (SIGKILL) are cleaned up by the next run.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.cli import main as cli
from sonarsim.cli.demo import DEMO_FILES
from sonarsim.cli.render import RENDER_FILES
from sonarsim.io.run_record import RECORD_NAME, read_record, record_beside

from tests.cli.test_cli import TINY_SCENE  # 8 beams x 50 bins: renders and writes in well under a second

# 512 beams x 3000 bins up to order 3: the render takes a fraction of a second, but with
# --components writing its 22 images (3000 x 3000 px fans) takes 5-15 s, long enough to be
# stopped half-way through writing, with temporary files on disk.
BIG_SCENE = {
    **TINY_SCENE,
    "sonar": {**TINY_SCENE["sonar"], "n_beams": 512, "azimuth_fov_deg": 60.0, "range_max_m": 10.0,
              "n_range_bins": 3000},
    "render": {"elevation_samples": 64, "max_order": 3},
}


@pytest.fixture()
def tiny_scene(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY_SCENE))
    return path


# What `fit --domain band` is for: a floor alone (TINY_SCENE's box carries 79 % of its echo), its
# band inside the window (near edge 1.74 m, far edge 2.37 m at pitch 30 deg), in 200 bins. The
# band detector smooths over 12 bins and keeps 24 clear on each side of an edge: in TINY_SCENE's
# 50 bins it can tell no edge from its own blur (the old detector put one at 2.03 m, between
# the box's face at 1.93 m and the floor's edge at 2.37 m).
BAND_SCENE = {
    **{k: v for k, v in TINY_SCENE.items() if k != "objects"},
    "sonar": {**TINY_SCENE["sonar"], "n_range_bins": 200,
              "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 30.0, 0.0]}},
}


@pytest.fixture()
def band_scene(tmp_path: Path) -> Path:
    path = tmp_path / "band.yaml"
    path.write_text(yaml.safe_dump(BAND_SCENE))
    return path


@pytest.fixture()
def big_scene(tmp_path: Path) -> Path:
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(BIG_SCENE))
    return path


def run_main(capsys, *args) -> tuple[int, str]:
    """``sonarsim ARGS`` in-process: exit status and stderr."""
    code = cli.main([str(a) for a in args])
    return code, capsys.readouterr().err


def temp_files(folder: Path) -> list[str]:
    return sorted(n for n in os.listdir(folder) if n.endswith(".tmp"))


def check_record(folder: Path, record: Path, names: list[str], others: tuple[str, ...] = ()) -> dict:
    """``folder`` holds exactly ``names``, the record, which is complete and right about them,
    and the files ``others`` that no sonarsim run wrote."""
    assert sorted(os.listdir(folder)) == sorted([*names, record.name, *others])
    doc = read_record(record)
    assert doc["status"] == "complete"
    assert sorted(e["name"] for e in doc["files"]) == sorted(names)
    for entry in doc["files"]:
        data = (folder / entry["name"]).read_bytes()
        assert entry["bytes"] == len(data)
        assert entry["sha256"] == hashlib.sha256(data).hexdigest()
    return doc


# --------------------------------------------------------------------------- records and stale files


def test_render_writes_its_files_then_a_complete_record(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    code, err = run_main(capsys, "render", tiny_scene, "--out", out, "--seed", "3")
    assert code == 0, err
    doc = check_record(out, out / RECORD_NAME, list(RENDER_FILES))
    assert doc["command"] == ["sonarsim", "render", str(tiny_scene), "--out", str(out), "--seed", "3"]
    assert doc["version"] == sonarsim.__version__
    # Written last: no output is newer than the record.
    assert max((out / n).stat().st_mtime_ns for n in RENDER_FILES) <= (out / RECORD_NAME).stat().st_mtime_ns


def test_a_reused_folder_keeps_no_stale_files(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    assert run_main(capsys, "render", tiny_scene, "--out", out, "--components")[0] == 0
    components = sorted(set(os.listdir(out)) - {*RENDER_FILES, RECORD_NAME})
    assert "polar_object.png" in components and "fan_single.png" in components
    (out / "notes.txt").write_text("the user's, never sonarsim's")
    (out / ".hidden").write_text("also the user's")
    code, err = run_main(capsys, "render", tiny_scene, "--out", out, "--bounces", "1")
    assert code == 0, err
    assert f"removed {len(components)} file(s) of an earlier run in {out}" in err
    check_record(out, out / RECORD_NAME, list(RENDER_FILES), others=("notes.txt", ".hidden"))


def test_files_that_are_not_sonarsims_are_left_alone(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    assert run_main(capsys, "render", tiny_scene, "--out", out, "--components")[0] == 0
    (out / "notes.txt").write_text("mine")
    (out / "polar_object.png").write_bytes(b"my edit")  # sonarsim wrote it, the user changed it
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == 0, err
    assert sorted(os.listdir(out)) == sorted([*RENDER_FILES, RECORD_NAME, "notes.txt", "polar_object.png"])
    assert (out / "notes.txt").read_text() == "mine" and (out / "polar_object.png").read_bytes() == b"my edit"
    assert f"kept polar_object.png in {out}: listed by an earlier run but changed since" in err


def test_show_after_render_in_one_folder(capsys, tmp_path: Path, tiny_scene: Path, shared_data: Path) -> None:
    out = tmp_path / "out"
    assert run_main(capsys, "render", tiny_scene, "--out", out, "--components")[0] == 0
    recording = shared_data / "real" / "oculus" / "one_ping_8bit.raw"
    code, err = run_main(capsys, "show", recording, "--out", out)
    assert code == 0, err
    doc = check_record(out, out / RECORD_NAME, ["polar.png", "fan.png", "fan_figure.png", "polar_figure.png"])
    assert doc["command"][:3] == ["sonarsim", "show", str(recording)]


def test_demo_record_lists_all_its_files_and_replaces_a_render(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    out = tmp_path / "out"
    assert run_main(capsys, "render", tiny_scene, "--out", out, "--components")[0] == 0
    code, err = run_main(capsys, "demo", "--out", out, "--elevation-samples", "4")
    assert code == 0, err
    check_record(out, out / RECORD_NAME, list(DEMO_FILES))


def test_fit_keeps_its_record_beside_its_scene(capsys, tmp_path: Path, band_scene: Path) -> None:
    sonarsim.render(sonarsim.load_scene(band_scene)).save_npz(tmp_path / "real.npz")
    out = tmp_path / "fits" / "fitted.yaml"
    (tmp_path / "fits").mkdir()
    (tmp_path / "fits" / "other_fit.png").write_bytes(b"another fit's, no record lists it")
    args = ["fit", tmp_path / "real.npz", "--scene", band_scene, "--free", "z", "--domain", "band",
            "--max-renders", "12", "--out", out]
    code, err = run_main(capsys, *args)
    assert code == 0, err
    record = record_beside(out)
    assert record.name == "fitted.yaml.sonarsim-run.json"
    check_record(out.parent, record, ["fitted.yaml", "fitted_fit.png", "fitted_fit_figure.png"],
                 others=("other_fit.png",))
    # Again with the picture elsewhere: the first picture (and figure) are stale, the stranger's file stays.
    picture = tmp_path / "pictures" / "fit.png"
    code, err = run_main(capsys, *args, "--image", picture)
    assert code == 0, err
    assert sorted(os.listdir(out.parent)) == ["fitted.yaml", record.name, "other_fit.png"]
    files = read_record(record)["files"]
    assert [e.get("name") or e.get("path") for e in files] == ["fitted.yaml", str(picture),
                                                                str(picture.with_name("fit_figure.png"))]
    assert files[1]["sha256"] == hashlib.sha256(picture.read_bytes()).hexdigest()


def test_fit_band_on_a_window_too_short_for_the_detector_writes_nothing(capsys, tmp_path: Path,
                                                                        tiny_scene: Path) -> None:
    # TINY_SCENE's 50 bins: no band edge the detector can tell (see BAND_SCENE), and its band
    # starts 2.4 m out, not at the window start: no grazing sea bed to bound either.
    sonarsim.render(sonarsim.load_scene(tiny_scene)).save_npz(tmp_path / "real.npz")
    out = tmp_path / "fits" / "fitted.yaml"
    with pytest.raises(SystemExit) as stopped:
        cli.main([str(a) for a in ["fit", tmp_path / "real.npz", "--scene", tiny_scene, "--free", "z",
                                   "--domain", "band", "--max-renders", "4", "--quiet", "--out", out]])
    captured = capsys.readouterr()
    assert stopped.value.code == 3, captured.err
    assert "no beam shows a band in both the recording and the render" in captured.err
    assert "no clear band edge in any of its 8 beams and is not lit from its first range bin" in captured.out
    assert "fading with range" not in captured.out
    assert not out.parent.exists() or os.listdir(out.parent) == []


# --------------------------------------------------------------------------- checked before the work


def _unwritable_cases(tmp_path: Path, tiny_scene: Path) -> dict:
    """Command lines whose outputs cannot be written, with inputs that are missing: the output
    error must come first, so nothing is read (let alone rendered)."""
    a_file = tmp_path / "a_file.txt"
    a_file.write_text("I am a file\n")
    (tmp_path / "a_folder.png").mkdir()
    missing = tmp_path / "missing.yaml"
    return {
        "render": ["render", missing, "--out", a_file / "out"],
        "render-out-is-file": ["render", missing, "--out", a_file],
        "demo": ["demo", "--out", a_file / "out"],
        "show": ["show", tmp_path / "missing.raw", "--out", a_file / "out"],
        "fit": ["fit", tmp_path / "missing.npz", "--scene", missing, "--out", a_file / "fit.yaml"],
        "fit-image": ["fit", tmp_path / "missing.npz", "--scene", missing, "--out", tmp_path / "fit.yaml",
                      "--image", tmp_path / "a_folder.png"],
        "calibrate": ["calibrate", tmp_path / "missing.npz", "--scene", missing, "--out", a_file / "c.yaml"],
        "calibrate-json": ["calibrate", tmp_path / "missing.npz", "--scene", missing, "--out", tmp_path / "c.yaml",
                           "--json", a_file / "figures.json"],
    }


@pytest.mark.parametrize("case", ["render", "render-out-is-file", "demo", "show", "fit", "fit-image", "calibrate",
                                  "calibrate-json"])
def test_unwritable_outputs_stop_the_command_before_any_work(capsys, tmp_path: Path, tiny_scene: Path,
                                                             case: str) -> None:
    args = _unwritable_cases(tmp_path, tiny_scene)[case]
    before = sorted(os.listdir(tmp_path))
    code, err = run_main(capsys, *args)
    assert code == cli.EXIT_BAD_INPUT
    assert err.count("\n") == 1 and err.startswith("sonarsim: error: "), err
    assert not any(f"missing.{ext}" in err for ext in ("yaml", "npz", "raw")), err  # no input was opened
    assert ".tmp" not in err, err
    a_file = tmp_path / "a_file.txt"
    expected = {
        "render": f"--out {a_file / 'out'}: cannot create this folder: {a_file} is a file, not a folder",
        "render-out-is-file": f"--out {a_file}: is a file, not a folder (allowed: a folder, or a path where one "
                              "can be created)",
        "demo": f"--out {a_file / 'out'}: cannot create this folder: {a_file} is a file, not a folder",
        "show": f"--out {a_file / 'out'}: cannot create this folder: {a_file} is a file, not a folder",
        "fit": f"--out {a_file / 'fit.yaml'}: cannot create its folder: {a_file} is a file, not a folder",
        "fit-image": f"--image {tmp_path / 'a_folder.png'}: is a folder; this command writes a file of that "
                     "name there",
        "calibrate": f"--out {a_file / 'c.yaml'}: cannot create its folder: {a_file} is a file, not a folder",
        "calibrate-json": f"--json {a_file / 'figures.json'}: cannot create its folder: {a_file} is a file, "
                          "not a folder",
    }[case]
    assert err.startswith(f"sonarsim: error: {expected}"), err
    assert sorted(os.listdir(tmp_path)) == before  # nothing created, nothing left


def test_unwritable_out_is_found_before_a_large_render(tmp_path: Path, big_scene: Path) -> None:
    a_file = tmp_path / "a_file.txt"
    a_file.write_text("x")
    proc = subprocess.run([sys.executable, "-m", "sonarsim", "render", big_scene, "--out", a_file / "out"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr == (f"sonarsim: error: --out {a_file / 'out'}: cannot create this folder: {a_file} is a "
                           "file, not a folder\n")


def test_show_of_a_bad_recording_leaves_no_folder(capsys, tmp_path: Path) -> None:
    # Regression: show used to create the folder and write polar.png before failing.
    garbage = tmp_path / "garbage.raw"
    garbage.write_bytes(b"\x00\x01garbage" * 10)
    out = tmp_path / "out"
    code, err = run_main(capsys, "show", garbage, "--out", out)
    assert code == cli.EXIT_BAD_INPUT and "garbage.raw" in err and "Traceback" not in err
    assert not out.exists()


# --------------------------------------------------------------------------- interrupted runs


def test_ctrl_c_while_writing_in_process(capsys, monkeypatch, tmp_path: Path, tiny_scene: Path) -> None:
    from sonarsim.io import output

    real_write_png = output.write_png
    calls = []

    def second_write_interrupted(path, image):
        calls.append(path)
        if len(calls) == 2:
            with output.atomic_write(path) as handle:
                handle.write(b"half a PNG")
                raise KeyboardInterrupt
        real_write_png(path, image)

    monkeypatch.setattr(output, "write_png", second_write_interrupted)
    out = tmp_path / "out"
    handler = signal.getsignal(signal.SIGTERM)
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert signal.getsignal(signal.SIGTERM) == handler  # main's own handler only while it runs
    assert code == 130
    assert err.splitlines()[-1] == (f"sonarsim: interrupted by Ctrl-C (SIGINT); {out / RECORD_NAME} records the run "
                                    "as interrupted")
    assert sorted(os.listdir(out)) == ["polar.png", RECORD_NAME]
    doc = read_record(out / RECORD_NAME)
    assert doc["status"] == "interrupted" and [e["name"] for e in doc["files"]] == list(RENDER_FILES)


@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_stop_signals_in_process(capsys, monkeypatch, tmp_path: Path, tiny_scene: Path, signum, code: int) -> None:
    from sonarsim.io import output

    real_write_png = output.write_png

    slept = []

    def signalled(path, image):
        real_write_png(path, image)
        os.kill(os.getpid(), signum)  # main turns it into an exception at the next step
        time.sleep(5)  # never reached in full
        slept.append(path)

    monkeypatch.setattr(output, "write_png", signalled)
    out = tmp_path / "out"
    code_, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code_ == code and slept == []  # the signal cut the first sleep short: no write went on
    name = signal.Signals(signum).name
    assert err.splitlines()[-1] == f"sonarsim: interrupted by {name}; {out / RECORD_NAME} records the run as interrupted"
    assert sorted(os.listdir(out)) == ["polar.png", RECORD_NAME]
    assert read_record(out / RECORD_NAME)["error"] == name


def test_a_folder_named_like_the_record_is_refused(capsys, tmp_path: Path, tiny_scene: Path) -> None:
    (tmp_path / "out" / RECORD_NAME).mkdir(parents=True)
    code, err = run_main(capsys, "render", tiny_scene, "--out", tmp_path / "out")
    assert code == cli.EXIT_BAD_INPUT
    assert err.startswith(f"sonarsim: error: --out {tmp_path / 'out' / RECORD_NAME}: is a folder")


def test_failed_write_is_recorded_as_failed(capsys, monkeypatch, tmp_path: Path, tiny_scene: Path) -> None:
    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    from sonarsim.io import npz

    monkeypatch.setattr(npz, "encode_npz", disk_full)
    out = tmp_path / "out"
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == cli.EXIT_BAD_INPUT
    assert err.splitlines()[-1] == f"sonarsim: error: {out / 'render.npz'}: No space left on device"
    doc = read_record(out / RECORD_NAME)
    assert doc["status"] == "failed" and "No space left on device" in doc["error"]
    assert temp_files(out) == []


def _start_big_render(big_scene: Path, out: Path) -> subprocess.Popen:
    """A large render with --components, returned once it has begun writing its images."""
    proc = subprocess.Popen([sys.executable, "-m", "sonarsim", "render", big_scene, "--out", out, "--components"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "polar.png").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the render did not start writing in 120 s"
        time.sleep(0.02)
    time.sleep(0.1)  # into the component images
    assert proc.poll() is None, "the render finished before it could be interrupted; make BIG_SCENE larger"
    return proc


@pytest.mark.parametrize("signum, code, name, error", [(signal.SIGINT, 130, "Ctrl-C (SIGINT)", "KeyboardInterrupt"),
                                                       (signal.SIGTERM, 143, "SIGTERM", "SIGTERM")])
def test_a_signal_while_writing_stops_cleanly(tmp_path: Path, big_scene: Path, signum, code: int, name: str,
                                              error: str) -> None:
    out = tmp_path / "out"
    proc = _start_big_render(big_scene, out)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert err.splitlines()[-1] == f"sonarsim: interrupted by {name}; {out / RECORD_NAME} records the run as interrupted"
    assert temp_files(out) == []
    doc = read_record(out / RECORD_NAME)
    assert doc["status"] == "interrupted" and doc["error"] == error
    # Every file there is one the record lists (so the next run can clear it), and it is
    # incomplete: the npz, written last, is not there.
    assert set(os.listdir(out)) - {RECORD_NAME} <= {e["name"] for e in doc["files"]}
    assert not (out / "render.npz").exists()


def test_sigkill_leftovers_are_cleaned_by_the_next_run(capsys, tmp_path: Path, big_scene: Path,
                                                       tiny_scene: Path) -> None:
    out = tmp_path / "out"
    proc = _start_big_render(big_scene, out)
    proc.kill()
    proc.communicate(timeout=60)
    assert read_record(out / RECORD_NAME)["status"] == "running"  # recognisably incomplete
    # Whether or not the kill caught a write half-way, a dead process's temporary file is there:
    dead = proc.pid
    (out / f".fan_triple.png.sonarsim-{dead}-k1lled00.tmp").write_bytes(b"half")
    alive = out / f".fan.png.sonarsim-{os.getpid()}-l1ve0000.tmp"  # a live writer's: kept
    alive.write_bytes(b"in progress")
    (out / "notes.txt").write_text("mine")
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == 0, err
    assert sorted(os.listdir(out)) == sorted([*RENDER_FILES, RECORD_NAME, "notes.txt", alive.name])
    alive.unlink()
    check_record(out, out / RECORD_NAME, list(RENDER_FILES), others=("notes.txt",))


def _start_command_at_its_first_line(*args) -> tuple[subprocess.Popen, list[str]]:
    """``python -m sonarsim ARGS``, returned once ``import sonarsim`` has put the Ctrl-C hold in
    place (its first statement; told by ``-X importtime``), with the list its stderr lines fill.

    The interpreter's own start (site, runpy) comes before any line of sonarsim and is beyond
    its reach: on a loaded machine it alone took more than 0.15 s, so a delay counted from the
    process's start landed there and tested Python, not sonarsim.
    """
    import threading

    proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "sonarsim", *map(str, args)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    held = threading.Event()

    def drain() -> None:  # importtime writes a line per module: a full pipe would stop the child
        imported = False
        for line in proc.stderr:
            lines.append(line.rstrip("\n"))
            if line.startswith("import time:"):
                # A line after core.interrupts' is printed once the hold is in place (the next
                # statement after that import): a loaded machine may pause the child in between.
                if imported:
                    held.set()
                imported = imported or line.split("|")[-1].strip() == "sonarsim.core.interrupts"
        held.set()  # (the process ended)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    proc.reader = reader  # joined by the caller once the process has ended
    assert held.wait(120), "sonarsim was not imported within 120 s"
    assert proc.poll() is None, "the command ended before it could be interrupted"
    return proc, lines


@pytest.mark.parametrize("delay_s", [0.15, 0.4, 0.55, 0.8])
def test_ctrl_c_while_the_command_starts_says_one_line(tmp_path: Path, big_scene: Path, delay_s: float) -> None:
    # The first second of a command is imports (the package, argparse, the renderer, Embree,
    # SciPy), parsing and loading the scene: Ctrl-C there must end like Ctrl-C later. Counted
    # from the first statement of ``import sonarsim`` (core.interrupts holds Ctrl-C from there
    # until the command runs); a loaded machine stretches these phases, not the test's clock.
    out = tmp_path / "out"
    proc, lines = _start_command_at_its_first_line("render", big_scene, "--out", out)
    time.sleep(delay_s)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=60)
    proc.reader.join(timeout=60)
    err = "\n".join(line for line in lines if not line.startswith("import time:"))
    assert "Traceback" not in err, err
    assert proc.returncode == 130, err
    assert err.splitlines()[-1].startswith("sonarsim: interrupted by Ctrl-C (SIGINT)")
    assert temp_files(out) == [] if out.exists() else True


def test_ctrl_c_during_an_import_stops_the_command_as_ctrl_c(capsys, monkeypatch, tmp_path: Path,
                                                             tiny_scene: Path) -> None:
    # A Ctrl-C that lands while Python initialises a compiled module surfaces as
    # "ImportError: initialization failed" caused by the KeyboardInterrupt (seen in CI, SciPy
    # imported at the first scene build): it must end as Ctrl-C does, not with a traceback.
    import sonarsim.renderer.simulator as simulator

    def interrupted_import(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    monkeypatch.setattr(simulator.Simulator, "__init__", interrupted_import)
    out = tmp_path / "out"
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == 130 and "Traceback" not in err
    assert err.splitlines()[-1].startswith("sonarsim: interrupted by Ctrl-C (SIGINT)")
    assert read_record(out / RECORD_NAME)["status"] == "interrupted"


def test_interrupt_of_walks_causes_and_contexts() -> None:
    from sonarsim.errors import interrupt_of

    ctrl_c = KeyboardInterrupt()
    try:
        try:
            raise ctrl_c
        except KeyboardInterrupt:
            raise ValueError("while handling it")  # context, not cause
    except ValueError as exc:
        assert interrupt_of(exc) is ctrl_c
    assert interrupt_of(ValueError("plain")) is None and interrupt_of(None) is None
