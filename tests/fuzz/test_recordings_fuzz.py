"""Fuzzing the recording readers with seeded mutations of the real recordings.

The generator and the per-case check live in :mod:`tests.fuzz.recordings` (shared with
``benchmarks/fuzz_recordings.py``, which runs the same check for 100,000 cases). A failure
prints the seed, the case number and its mutations: ``cases(seed, index + 1)`` regenerates it.
"""

from __future__ import annotations

import collections
import os
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sonarsim.core.memory import set_memory_budget
from sonarsim.io import readers

from . import recordings as fuzz

pytestmark = pytest.mark.skipif(
    not all(p.is_file() for p in fuzz.SOURCES.values()), reason="../shared/data is absent"
)

SEED = 20261123
N_CASES = 2500
# Small (the default is up to 8 GiB), yet above what the real recordings plan for: 29 MB for
# an Oculus ping of 703 x 256 values (SonarConfig plans 40 float32 images per frame), 15 MB
# for an ARIS frame; what they allocate while read is far less (the tracemalloc peaks).
BUDGET_BYTES = 64 * 2**20
TRACE_EVERY = 10  # tracemalloc slows a case four-fold: measure every tenth
SHOW_EVERY = 100  # `sonarsim show` (fan image, PNGs) costs ten cases: run it on every 100th


@pytest.fixture
def small_budget():
    set_memory_budget(BUDGET_BYTES)
    yield BUDGET_BYTES
    set_memory_budget(None)


def run_cases(tmp_path: Path, seed: int, n: int, budget: int):
    """Check ``n`` cases.

    Returns
    -------
    (Counter of (kind, field), Counter of (source, kind), failures, slowest seconds)
    """
    counts: collections.Counter = collections.Counter()
    by_source: collections.Counter = collections.Counter()
    failures = []
    slowest = 0.0
    path = tmp_path / "case.bin"
    for case in fuzz.cases(seed, n):
        path.unlink(missing_ok=True)  # a new file: truncating one in place is ten times slower
        path.write_bytes(case.data)
        kind = "aris" if case.source == "aris" else "oculus"
        outcome = fuzz.check_file(path, kind, budget, time_limit_s=5.0,
                                  trace_memory=case.index % TRACE_EVERY == 0,
                                  show_dir=tmp_path / "show" if case.index % SHOW_EVERY == 0 else None)
        counts[outcome.kind, outcome.field] += 1
        by_source[case.source, outcome.kind] += 1
        slowest = max(slowest, outcome.seconds)
        if outcome.failure:
            failures.append(f"case {case.index} ({case.source}; {', '.join(case.mutations)}): "
                            f"{outcome.failure}")
    return counts, by_source, failures, slowest


def test_mutated_recordings_end_in_recording_error_or_plausible_images(tmp_path, small_budget):
    counts, by_source, failures, slowest = run_cases(tmp_path, SEED, N_CASES, small_budget)
    assert not failures, f"{len(failures)} of {N_CASES} cases failed (seed {SEED}):\n" + "\n".join(failures[:20])
    # The mutations must exercise both ends: files still read, and refusals of many kinds
    # (a generator that only ever truncated would pass the check above trivially).
    kinds = collections.Counter(kind for kind, _ in counts.elements())
    assert kinds["ok"] > N_CASES // 10 and kinds["refused"] + kinds["partial"] > N_CASES // 3
    for source in fuzz.SOURCES:  # every recording is still read when its mutation is harmless
        assert by_source[source, "ok"] > N_CASES // 30, by_source
    fields = {field for (kind, field) in counts if kind != "ok"}
    for geometry in ("SamplePeriod", "SamplesPerBeam", "SoundSpeed", "rangeResolution", "nBeams",
                     "bearings", "truncated", "payloadSize"):
        assert geometry in fields, f"no case was refused for {geometry}: {sorted(fields)}"
    assert slowest < 5.0


def test_the_check_catches_a_silent_stop(tmp_path, monkeypatch):
    # The regression the issue found (read raises, read_frames yields nothing), reintroduced
    # on purpose: the check must report it, or the fuzz test above proves nothing.
    path = tmp_path / "logs.raw"
    data = bytearray(fuzz.SOURCES["oculus1"].read_bytes())
    data[6] = 0x80  # msgId: no longer a simple ping result
    path.write_bytes(bytes(data))
    assert fuzz.check_file(path, "oculus", BUDGET_BYTES).failure is None
    monkeypatch.setattr(readers, "read_frames", lambda p: iter(()))
    failure = fuzz.check_file(path, "oculus", BUDGET_BYTES).failure
    assert failure and "stopped silently at frame 0" in failure


def test_the_check_catches_an_implausible_window(tmp_path, monkeypatch):
    # The other regression the issue found: a SamplePeriod of 0x7FFFFFFF us read "successfully"
    # as a window of 3e9 m. With the reader's limits switched off on purpose, the check must
    # catch the window itself.
    from sonarsim.io.readers import aris as aris_reader

    path = tmp_path / "far.aris"
    data = bytearray(fuzz.SOURCES["aris"].read_bytes())
    data[1024 + 452:1024 + 456] = (0x7FFFFFFF).to_bytes(4, "little")  # frame 0 SamplePeriod
    path.write_bytes(bytes(data))
    outcome = fuzz.check_file(path, "aris", BUDGET_BYTES)
    assert outcome.failure is None and (outcome.kind, outcome.field) == ("refused", "SamplePeriod")
    monkeypatch.setattr(aris_reader, "check_within", lambda *a, **k: None)
    monkeypatch.setattr(aris_reader, "check_range_window", lambda *a, **k: None)
    # SonarConfig itself now refuses windows beyond 10 km (which the check reports as a reader
    # check missed): 2000 us give a window to about 3 km, which only the check's own
    # plausibility (400 m for an ARIS) catches.
    data[1024 + 452:1024 + 456] = (2000).to_bytes(4, "little")
    path.write_bytes(bytes(data))
    failure = fuzz.check_file(path, "aris", BUDGET_BYTES).failure
    assert failure and "implausible geometry: range window" in failure


# ------------------------------------------------------------------------------------------
# Issue 21: every reader agrees on the good frames of a damaged file
# ------------------------------------------------------------------------------------------


def _aris_frame_size(data: bytes) -> int:
    return fuzz._aris_frame_size(data)


def _damaged(name: str) -> tuple[str, bytes, int, str]:
    """(source, mutated bytes, the first damaged frame, the field or word its error names)."""
    aris = fuzz.SOURCES["aris"].read_bytes()
    three = fuzz.SOURCES["oculus3"].read_bytes()
    size = _aris_frame_size(aris)
    messages = fuzz.oculus_messages(three)

    def put(data: bytes, offset: int, fmt: str, value) -> bytes:
        out = bytearray(data)
        struct.pack_into(fmt, out, offset, value)
        return bytes(out)

    if name == "aris-sound-speed-frame3":  # an impossible header in the middle of the file
        return "aris", put(aris, 1024 + 3 * size + 464, "<f", 1e-3), 3, "SoundSpeed"
    if name == "aris-cut-in-frame4":  # a file cut short (a copy interrupted)
        return "aris", aris[:1024 + 4 * size + 3000], 4, "truncated"
    if name == "aris-frame2-changes-size":  # PingMode 9 (128 beams) after frames of 48
        return "aris", put(aris, 1024 + 2 * size + 436, "<I", 9), 2, "PingMode"
    if name == "oculus-garbage-header-1":  # the second message's header overwritten
        return "oculus3", put(three, messages[1][0], "<H", 0x5C36), 1, "oculusId"
    if name == "oculus-bearings-ping1":  # ping 1's bearing table out of order
        bearing = messages[1][0] + 122 + 2 * 40
        return "oculus3", put(three, bearing, "<h", 8900), 1, "bearings"
    if name == "oculus-cut-in-ping2":
        return "oculus3", three[:messages[2][0] + 5000], 2, "payloadSize"
    if name == "aris-frame0-sample-period":  # nothing is readable: refused everywhere
        return "aris", put(aris, 1024 + 452, "<I", 0xFFFFFFFF), 0, "SamplePeriod"
    raise AssertionError(name)


DAMAGED = ["aris-sound-speed-frame3", "aris-cut-in-frame4", "aris-frame2-changes-size",
           "oculus-garbage-header-1", "oculus-bearings-ping1", "oculus-cut-in-ping2",
           "aris-frame0-sample-period"]


@pytest.mark.parametrize("name", DAMAGED)
def test_every_reader_agrees_on_the_good_frames_of_a_damaged_recording(tmp_path, name, capsys):
    from sonarsim.cli.main import main

    source, data, bad, word = _damaged(name)
    path = tmp_path / f"{name}.bin"
    path.write_bytes(data)
    original = list(readers.read_frames(fuzz.SOURCES[source]))
    assert bad < len(original)  # the damage is inside the real recording's frames

    def names_the_damage(exc):
        return isinstance(exc, readers.RecordingError) and (exc.field == word or word in exc.detail)

    if bad == 0:  # nothing readable: every reader refuses the file with the same error
        with pytest.raises(readers.RecordingError) as opened:
            readers.open_recording(path)
        assert names_the_damage(opened.value)
        for call in (lambda: readers.n_frames(path), lambda: readers.read(path, 0),
                     lambda: list(readers.read_frames(path))):
            with pytest.raises(readers.RecordingError) as err:
                call()
            assert str(err.value) == str(opened.value)
    else:
        with readers.open_recording(path) as recording:
            assert recording.n_frames == len(recording) == bad
            damage = recording.damage
        assert names_the_damage(damage), damage
        assert readers.n_frames(path) == bad
        # The good frames are the real recording's frames, unchanged.
        got = []
        with pytest.raises(readers.RecordingError) as ended:
            for image in readers.read_frames(path):
                got.append(image)
        assert str(ended.value) == str(damage)
        assert len(got) == bad
        for k in range(bad):
            np.testing.assert_array_equal(readers.read(path, k).polar, original[k].polar)
            np.testing.assert_array_equal(got[k].polar, original[k].polar)
        with pytest.raises(readers.RecordingError) as err:
            readers.read(path, bad)
        assert str(err.value) == str(damage)
        # Frames after the damage are not good frames, even where their bytes are intact.
        for k in range(bad + 1, len(original) + 1):
            with pytest.raises(readers.RecordingError, match=f"out of range.*valid: 0 to {bad - 1}.*damaged"):
                readers.read(path, k)
    # sonarsim show: frame 0 when it is good, with a note naming the damage; else exit 2.
    capsys.readouterr()
    code = main(["show", str(path), "--frame", "0", "--out", str(tmp_path / "out"), "--no-figures"])
    err = capsys.readouterr().err
    if bad:
        assert code == 0 and f"frame 0 of {bad} from" in err
        assert "note:" in err and word in err.split("note:", 1)[1]
        assert (tmp_path / "out" / "polar.png").is_file()
        assert fuzz.check_show(path, tmp_path / "again") is None
        code = main(["show", str(path), "--frame", str(bad), "--out", str(tmp_path / "after"), "--no-figures"])
        assert code == 2 and not (tmp_path / "after").exists()
    else:
        assert code == 2 and len(err.strip().splitlines()) == 1 and word in err


def test_the_check_catches_readers_that_disagree_on_the_good_frames(tmp_path, monkeypatch):
    # The disagreement of issue 21 reintroduced on purpose: n_frames counting frames after the
    # damage. The check must report it, or the fuzz test above proves nothing.
    _, data, bad, _ = _damaged("aris-sound-speed-frame3")
    path = tmp_path / "mid.aris"
    path.write_bytes(data)
    assert fuzz.check_file(path, "aris", BUDGET_BYTES).failure is None
    monkeypatch.setattr(readers.ArisRecording, "n_frames", property(lambda self: self._n_complete))
    failure = fuzz.check_file(path, "aris", BUDGET_BYTES).failure
    assert failure and f"n_frames is 6, but read_frames gave {bad} frames" in failure


def test_cases_are_reproducible():
    a = [(c.source, c.mutations, c.data) for c in fuzz.cases(7, 20)]
    b = [(c.source, c.mutations, c.data) for c in fuzz.cases(7, 20)]
    assert a == b and len({m for _, m, _ in a}) > 10


# ------------------------------------------------------------------------------------------
# The command line: a handful of mutated files through ``sonarsim show``
# ------------------------------------------------------------------------------------------


def _cli_cases() -> list[tuple[str, str, bytes]]:
    """(name, kind, bytes): chosen mutations, then seeded ones."""
    aris = fuzz.SOURCES["aris"].read_bytes()
    oculus = fuzz.SOURCES["oculus3"].read_bytes()
    one = fuzz.SOURCES["oculus1"].read_bytes()

    def put(data: bytes, offset: int, fmt: str, value) -> bytes:
        out = bytearray(data)
        struct.pack_into(fmt, out, offset, value)
        return bytes(out)

    chosen = [
        ("aris-sample-period", "aris", put(aris, 1024 + 452, "<I", 0xFFFFFFFF)),
        ("aris-start-delay", "aris", put(aris, 1024 + 476, "<I", 0xFFFFFFFF)),
        ("oculus-resolution", "oculus", put(oculus, 98, "<d", 1e-300)),
        ("oculus-msg-id", "oculus", put(one, 6, "<H", 0x80)),  # the file's only ping
        ("oculus-cut", "oculus", oculus[:300_000]),  # in ping 1: ping 0 is shown
        ("aris-frame-copied", "aris", aris[:1024] + aris[1024:1024 + 97_024] + aris[1024:]),
    ]
    seeded = [(f"seeded-{c.index}", "aris" if c.source == "aris" else "oculus", c.data)
              for c in fuzz.cases(SEED + 1, 1)]
    return chosen + seeded


def test_show_on_mutated_files_exits_0_or_2_with_one_line(tmp_path):
    exe = Path(sys.executable).with_name("sonarsim")
    command = [str(exe)] if exe.is_file() else [sys.executable, "-m", "sonarsim.cli.main"]
    env = dict(os.environ, SONARSIM_MAX_MEMORY="256M")
    runs = []
    for name, _kind, data in _cli_cases():
        path = tmp_path / f"{name}.bin"
        path.write_bytes(data)
        out = tmp_path / f"{name}-out"
        proc = subprocess.Popen([*command, "show", str(path), "--out", str(out)], env=env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        runs.append((name, out, proc))
    codes = {}
    for name, out, proc in runs:
        stdout, stderr = proc.communicate(timeout=120)
        codes[name] = proc.returncode
        assert proc.returncode in (0, 2), f"{name}: exit {proc.returncode}\n{stderr}"
        assert "Traceback" not in stderr + stdout, f"{name}:\n{stderr}"
        if proc.returncode == 2:
            lines = stderr.strip().splitlines()
            assert len(lines) == 1 and str(out.parent) in lines[0], f"{name}: {stderr!r}"
            left = sorted(p.name for p in out.rglob("*")) if out.exists() else []
            assert left == [], f"{name}: failed but left {left} in {out}"
        else:
            assert (out / "polar.png").is_file() and (out / "fan.png").is_file()
    # The chosen ones end as designed: refused (2) for impossible fields, shown (0) otherwise.
    assert [codes[n] for n in ("aris-sample-period", "aris-start-delay", "oculus-resolution",
                               "oculus-msg-id", "oculus-cut", "aris-frame-copied")] == [2, 2, 2, 2, 0, 0]
