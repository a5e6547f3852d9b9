"""Tests of sonarsim.io.run_record: outputs checked before the work, the run record, stale files."""

from __future__ import annotations

import hashlib
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from sonarsim.io import run_record
from sonarsim.io.output import atomic_write
from sonarsim.io.run_record import RECORD_NAME, OutputError, OutputRun, read_record, record_beside


def write(path: Path, data: bytes = b"x") -> None:
    with atomic_write(path) as handle:
        handle.write(data)


def run_writing(folder: Path, contents: dict[str, bytes], command=("sonarsim", "test")) -> dict:
    """One complete run that writes ``contents`` (name -> bytes) into ``folder``; its record."""
    with OutputRun.for_folder(folder, contents, command=command, log=lambda msg: None) as run:
        for name, data in contents.items():
            write(folder / name, data)
    assert run.files == [Path(os.path.abspath(folder / n)) for n in contents]
    return json.loads((folder / RECORD_NAME).read_text())


def test_complete_record_lists_each_file_with_size_and_sha256(tmp_path: Path) -> None:
    out = tmp_path / "new" / "folder"  # created by the run, not by the check
    run = OutputRun.for_folder(out, ["a.png", "b.npz"], command=["sonarsim", "x", "--out", str(out)])
    assert not out.exists()
    with run:
        assert read_record(out / RECORD_NAME)["status"] == "running"
        write(out / "a.png", b"hello")
        write(out / "b.npz", b"")
    doc = json.loads((out / RECORD_NAME).read_text())
    assert doc["status"] == "complete" and doc["sonarsim_run"] == 1
    assert doc["command"] == ["sonarsim", "x", "--out", str(out)]
    assert doc["pid"] == os.getpid() and doc["host"] == socket.gethostname()
    assert doc["started_utc"].endswith("Z") and doc["finished_utc"] >= doc["started_utc"]
    # sha256 of b"hello" and of nothing, computed independently.
    assert doc["files"] == [
        {"name": "a.png", "bytes": 5, "sha256": hashlib.sha256(b"hello").hexdigest()},
        {"name": "b.npz", "bytes": 0,
         "sha256": "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"},
    ]
    assert sorted(os.listdir(out)) == ["a.png", "b.npz", RECORD_NAME]


def test_running_record_lists_the_plan_before_any_file_exists(tmp_path: Path) -> None:
    with OutputRun.for_folder(tmp_path, ["a.png"]) as run:
        doc = read_record(tmp_path / RECORD_NAME)
        assert doc["status"] == "running" and doc["files"] == [{"name": "a.png"}]
        run.add(tmp_path / "late.png")  # known only later: recorded before it is written
        assert read_record(tmp_path / RECORD_NAME)["files"] == [{"name": "a.png"}, {"name": "late.png"}]
        write(tmp_path / "a.png")
        write(tmp_path / "late.png")
    assert [e["name"] for e in read_record(tmp_path / RECORD_NAME)["files"]] == ["a.png", "late.png"]


def test_stale_files_of_the_previous_run_are_removed_and_others_kept(tmp_path: Path) -> None:
    run_writing(tmp_path, {"a.png": b"1", "b.png": b"2", "c.png": b"3"})
    (tmp_path / "notes.txt").write_text("mine")  # never sonarsim's
    (tmp_path / "c.png").write_bytes(b"edited")  # sonarsim's, but changed since: the user's now
    notes: list[str] = []
    with OutputRun.for_folder(tmp_path, ["a.png"], log=notes.append):
        write(tmp_path / "a.png", b"new")
    assert sorted(os.listdir(tmp_path)) == ["a.png", "c.png", "notes.txt", RECORD_NAME]
    assert (tmp_path / "c.png").read_bytes() == b"edited"
    assert notes == [f"removed 1 file(s) of an earlier run in {tmp_path} that this run does not write: b.png",
                     f"kept c.png in {tmp_path}: listed by an earlier run but changed since"]
    assert [e["name"] for e in read_record(tmp_path / RECORD_NAME)["files"]] == ["a.png"]


def test_files_of_an_interrupted_run_are_removed_without_checksums(tmp_path: Path) -> None:
    with pytest.raises(KeyboardInterrupt):
        with OutputRun.for_folder(tmp_path, ["a.png", "b.png"]):
            write(tmp_path / "a.png")
            write(tmp_path / "b.png")
            raise KeyboardInterrupt
    doc = read_record(tmp_path / RECORD_NAME)
    assert doc["status"] == "interrupted" and doc["files"] == [{"name": "a.png"}, {"name": "b.png"}]
    run_writing(tmp_path, {"b.png": b"2"})
    assert sorted(os.listdir(tmp_path)) == ["b.png", RECORD_NAME]


def test_a_failed_run_records_the_error_and_a_note(tmp_path: Path) -> None:
    with pytest.raises(ValueError) as info:
        with OutputRun.for_folder(tmp_path, ["a.png"]):
            raise ValueError("disk on fire")
    doc = read_record(tmp_path / RECORD_NAME)
    assert doc["status"] == "failed" and doc["error"] == "disk on fire" and "finished_utc" in doc
    assert info.value.__notes__ == [f"{tmp_path / RECORD_NAME} records the run as failed"]


def test_a_planned_file_not_written_is_a_bug(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="b.png"):
        with OutputRun.for_folder(tmp_path, ["a.png", "b.png"]):
            write(tmp_path / "a.png")
    assert read_record(tmp_path / RECORD_NAME)["status"] == "failed"


def test_a_record_cannot_make_a_run_remove_anything_outside_its_folder(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    for name in ("outside.txt", "elsewhere.txt"):
        (tmp_path / name).write_text("keep")
    (out / ".hidden").write_text("keep")
    (out / "sub").mkdir()
    (out / "sub" / "x").write_text("keep")
    forged = {"sonarsim_run": 1, "status": "running", "files": [
        {"name": "../outside.txt"}, {"path": str(tmp_path / "elsewhere.txt")}, {"name": "sub"},
        {"name": "sub/x"}, {"name": ".."}, {"name": RECORD_NAME}, {"name": 3}, "junk"]}
    (out / RECORD_NAME).write_text(json.dumps(forged))
    run_writing(out, {"a.png": b"1"})
    assert (tmp_path / "outside.txt").exists() and (tmp_path / "elsewhere.txt").exists()
    assert (out / "sub" / "x").exists() and (out / ".hidden").exists()


def test_a_file_that_is_not_a_record_is_ignored_and_replaced(tmp_path: Path) -> None:
    (tmp_path / RECORD_NAME).write_text("{not json")
    assert read_record(tmp_path / RECORD_NAME) is None
    (tmp_path / "a.png").write_text("x")
    run_writing(tmp_path, {"b.png": b"1"})
    assert sorted(os.listdir(tmp_path)) == ["a.png", "b.png", RECORD_NAME]


# --------------------------------------------------------------------------- checks


def test_out_under_a_file_is_refused_naming_both(tmp_path: Path) -> None:
    a_file = tmp_path / "a_file.txt"
    a_file.write_text("x")
    with pytest.raises(OutputError) as info:
        OutputRun.for_folder(a_file / "child" / "deeper", ["a.png"])
    assert str(info.value) == (f"--out {a_file / 'child' / 'deeper'}: cannot create this folder: {a_file} is a "
                               "file, not a folder")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        OutputRun.for_folder(a_file, ["a.png"])
    assert os.listdir(tmp_path) == ["a_file.txt"]


def test_an_output_that_is_a_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "fan.png").mkdir()
    with pytest.raises(OutputError, match=r"fan\.png: is a folder; this command writes a file"):
        OutputRun.for_folder(tmp_path, ["polar.png", "fan.png"])


def test_an_unwritable_folder_is_refused_naming_it_not_the_probe(tmp_path: Path, monkeypatch) -> None:
    # Tests run as root, where permission bits do not stop writing: simulate what a
    # read-only or foreign folder answers.
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / ".write-probe.sonarsim-1-x.tmp"))

    monkeypatch.setattr(run_record.tempfile, "mkstemp", refuse)
    with pytest.raises(OutputError) as info:
        OutputRun.for_folder(tmp_path, ["a.png"])
    assert str(info.value) == f"--out {tmp_path}: cannot write into this folder: Permission denied"
    with pytest.raises(OutputError, match=f"cannot create this folder in {tmp_path}: Permission denied"):
        OutputRun.for_folder(tmp_path / "new", ["a.png"])


def test_two_outputs_on_one_path_are_refused(tmp_path: Path) -> None:
    out = tmp_path / "fit.yaml"
    with pytest.raises(OutputError, match=r"--image .*fit\.yaml: is also the file of --out"):
        OutputRun(record_beside(out), [(out, "--out"), (out, "--image")])
    (tmp_path / "sub").mkdir()
    with pytest.raises(OutputError, match=r"--json .*fit\.yaml: is also the file of --out"):
        OutputRun(record_beside(out), [(out, "--out"), (tmp_path / "sub" / ".." / "fit.yaml", "--json")])
    with pytest.raises(OutputError, match="sonarsim's run record"):
        OutputRun(tmp_path / RECORD_NAME, [(tmp_path / RECORD_NAME, "--json")])


def test_a_live_run_in_the_same_folder_is_refused(tmp_path: Path) -> None:
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        record = {"sonarsim_run": 1, "status": "running", "pid": sleeper.pid, "host": socket.gethostname(),
                  "files": []}
        (tmp_path / RECORD_NAME).write_text(json.dumps(record))
        with pytest.raises(OutputError, match=f"sonarsim process {sleeper.pid} is writing these outputs now"):
            OutputRun.for_folder(tmp_path, ["a.png"])
    finally:
        sleeper.kill()
        sleeper.wait()
    # Once it is gone, its record is just the trace of a killed run.
    run_writing(tmp_path, {"a.png": b"1"})


def test_record_beside_a_single_output() -> None:
    assert record_beside(Path("d/fitted.yaml")) == Path("d/fitted.yaml.sonarsim-run.json")


def test_files_outside_the_record_folder_are_listed_by_path(tmp_path: Path) -> None:
    out, image = tmp_path / "a" / "fit.yaml", tmp_path / "b" / "fit.png"
    with OutputRun(record_beside(out), [(out, "--out"), (image, "--image")]):
        write(out, b"y")
        write(image, b"p")
    files = read_record(record_beside(out))["files"]
    assert [e.get("name") or e.get("path") for e in files] == ["fit.yaml", str(image)]


@pytest.mark.parametrize("stop", [KeyboardInterrupt, "killed"])
def test_a_users_file_that_an_unfinished_run_planned_but_never_replaced_is_kept(tmp_path: Path, stop) -> None:
    # `sonarsim demo --out mywork` over the user's own tank.yaml, stopped before it wrote
    # tank.yaml: its record lists tank.yaml (without a checksum), and the next run in the folder
    # removed the user's file as a stale file of that run.
    (tmp_path / "tank.yaml").write_text("my own tank\n")
    run = OutputRun.for_folder(tmp_path, ["polar.png", "tank.yaml"], log=lambda msg: None)
    if stop == "killed":  # SIGKILL: the record stays "running"
        run.__enter__()
        write(tmp_path / "polar.png")
    else:
        with pytest.raises(KeyboardInterrupt), run:
            write(tmp_path / "polar.png")
            raise KeyboardInterrupt
    assert read_record(tmp_path / RECORD_NAME)["status"] in ("running", "interrupted")
    notes: list[str] = []
    with OutputRun.for_folder(tmp_path, ["fan.png"], log=notes.append):
        write(tmp_path / "fan.png")
    assert (tmp_path / "tank.yaml").read_text() == "my own tank\n"
    assert not (tmp_path / "polar.png").exists()  # that one the unfinished run did write
    assert any("kept tank.yaml" in n for n in notes) and any("removed 1 file(s)" in n for n in notes)


def test_a_file_an_unfinished_run_did_replace_is_removed_as_its_own(tmp_path: Path) -> None:
    (tmp_path / "tank.yaml").write_text("my own tank\n")
    with pytest.raises(KeyboardInterrupt), OutputRun.for_folder(tmp_path, ["tank.yaml", "x.png"], log=lambda m: None):
        write(tmp_path / "tank.yaml", b"sonar: {}\n")
        raise KeyboardInterrupt
    with OutputRun.for_folder(tmp_path, ["fan.png"], log=lambda m: None):
        write(tmp_path / "fan.png")
    assert not (tmp_path / "tank.yaml").exists()
