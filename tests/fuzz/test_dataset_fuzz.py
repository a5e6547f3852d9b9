"""Fuzzing ``sonarsim dataset`` (issue 37): seeded command lines, scenario files and output
folders end in a complete, consistent dataset (every manifest SHA-256 the file's) or in one
line naming the option, key or file (exit 2 or 3), never a traceback, a temporary file left,
a folder made for a refusal, or an allocation beyond the budget; resumed folders end in the
bytes of an uninterrupted run. The generators and the check are in
:mod:`tests.fuzz.dataset_options`; the long run is ``benchmarks/fuzz_dataset.py``.
"""

from __future__ import annotations

import hashlib
import io
import json
from contextlib import redirect_stderr
from pathlib import Path

import pytest
import yaml

from tests.fuzz import dataset_options as fuzz
from tests.fuzz.dataset_options import Case, Summary, base_scenarios, check_case, generate_cases

# 2 x 40 cases in this process (no worker processes): about 10 s each here (2 shared cores).
SEEDS = (1, 2)
CASES_PER_SEED = 40


@pytest.mark.parametrize("seed", SEEDS)
def test_dataset_commands_end_in_a_consistent_dataset_or_one_line(tmp_path, seed):
    summary = Summary()
    for case in generate_cases(CASES_PER_SEED, seed, processes=False):
        summary.add(check_case(case, tmp_path, trace_memory=case.index % 3 == 0, processes=False))
    assert not summary.failures, f"{len(summary.failures)} of {summary.cases} failed:\n" + "\n".join(
        summary.failures[:10])
    # Both sides are reached: datasets written (resumed ones among them), refusals of many
    # options, keys and files.
    assert summary.written >= 0.15 * CASES_PER_SEED, summary.by_status
    assert summary.by_status.get(2, 0) >= 0.3 * CASES_PER_SEED, summary.by_status
    assert len(summary.refused) >= 8, sorted(summary.refused)
    assert summary.compared >= 1, "no resumed folder compared with an uninterrupted run"
    assert list(tmp_path.iterdir()) == []  # every case's folder removed


def test_cases_are_reproducible_from_the_seed():
    a = [(c.argv, c.scenario, c.out_state) for c in generate_cases(60, 5)]
    assert a == [(c.argv, c.scenario, c.out_state) for c in generate_cases(60, 5)]
    assert a != [(c.argv, c.scenario, c.out_state) for c in generate_cases(60, 6)]
    states = {state for _, _, state in a}
    assert {"half-written", "interrupted", None} <= states, states


# The check itself must catch what it is there to catch -------------------------------------

def _valid(out_state: str | None = None) -> Case:
    text = yaml.safe_dump(base_scenarios()["orbit"]).encode()
    argv = ["--max-memory", "256M", "dataset", "SCENARIO", "--out", "OUT", "--frames", "2", "--no-progress"]
    return Case(0, "orbit", argv, text, ".yaml", out_state=out_state)


def test_the_check_accepts_a_valid_command_and_a_resumed_one(tmp_path):
    out = check_case(_valid(), tmp_path)
    assert out.failure is None and out.status == 0 and out.frames == 2
    out = check_case(_valid("interrupted"), tmp_path)
    assert out.failure is None and out.status == 0 and out.compared


def test_the_check_fails_a_traceback(tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise KeyError("frames")

    monkeypatch.setattr("sonarsim.dataset.generate", broken)
    assert check_case(_valid(), tmp_path).failure.startswith("KeyError escaped")


def test_the_check_fails_a_file_that_is_not_its_manifest_line(tmp_path, monkeypatch):
    from sonarsim.dataset import writer

    real = writer._write_files

    def flips(out, encoded):
        real(out, encoded)
        path = out / encoded.record["files"][0]
        data = bytearray(path.read_bytes())
        data[-1] ^= 1
        path.write_bytes(bytes(data))

    monkeypatch.setattr(writer, "_write_files", flips)
    assert "size or SHA-256 is not its manifest line's" in check_case(_valid(), tmp_path).failure


def test_the_check_fails_a_temporary_file_left(tmp_path, monkeypatch):
    from sonarsim.dataset import writer
    from sonarsim.io.output import temp_prefix

    real = writer._write_files

    def leaves(out, encoded):
        real(out, encoded)
        (out / "frames" / (temp_prefix("x.npz") + "abc.tmp")).write_bytes(b"")

    monkeypatch.setattr(writer, "_write_files", leaves)
    assert check_case(_valid(), tmp_path).failure.startswith("temporary files left")


def test_the_check_fails_a_refusal_that_names_nothing_or_leaves_a_folder(tmp_path, monkeypatch):
    from sonarsim.errors import SonarsimError

    def vague(*args, **kwargs):
        raise SonarsimError("something went wrong")

    monkeypatch.setattr("sonarsim.dataset.generate", vague)
    assert check_case(_valid(), tmp_path).failure.startswith("a refusal naming no option, key or file")

    def leaves_folder(scenario, out, **kwargs):
        Path(out).mkdir()
        (Path(out) / "dataset.json").write_text("{}")
        raise SonarsimError(f"{out}: refused")

    monkeypatch.setattr("sonarsim.dataset.generate", leaves_folder)
    assert check_case(_valid(), tmp_path).failure.startswith("refused, yet made out")


def test_the_check_fails_a_resume_that_changes_the_bytes(tmp_path, monkeypatch):
    # A resumed run whose frames differ from a fresh run's (the encoder's state once did).
    from sonarsim.dataset import writer

    real = writer._write_files

    def differs(out, encoded):
        real(out, encoded)
        if "fresh" not in str(out):
            path = out / encoded.record["files"][0]
            data = path.read_bytes() + b"\0"
            path.write_bytes(data)
            encoded.record["bytes"][encoded.record["files"][0]] = len(data)
            encoded.record["sha256"][encoded.record["files"][0]] = hashlib.sha256(data).hexdigest()

    monkeypatch.setattr(writer, "_write_files", differs)
    out = check_case(_valid("complete"), tmp_path)
    assert out.failure.startswith("not the bytes of an uninterrupted run"), out.failure


# Findings of the fuzz, each as it now ends ---------------------------------------------------

def _scenario(tmp_path, frames: int, kind: str = "random"):
    doc = base_scenarios()[kind]
    doc["trajectory"]["generate"]["frames"] = frames
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("frames", [10**6, 10**9, 10**30, 10**400])
@pytest.mark.parametrize("bag", [[], ["--rosbag", "mcap", "--start-time", "2024-01-01T00:00:00Z"]])
def test_a_random_trajectory_of_absurd_length_is_refused_before_any_frame_is_listed(tmp_path, frames, bag):
    # Finding: a random trajectory of 10**9 frames listed every frame's spec (4-6 ms and 1.3 kB
    # each) before the folder was made: no end, and memory without a check.
    from sonarsim.cli.main import main

    path = _scenario(tmp_path, frames)
    err = io.StringIO()
    with redirect_stderr(err):
        status = main(["--max-memory", "256M", "dataset", str(path), "--out", str(tmp_path / "o"), "--no-progress",
                       *bag])
    lines = err.getvalue().strip().splitlines()
    assert status == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"sonarsim: error: {path}: trajectory.generate.frames: the manifest of ")
    assert "more than the memory budget of 0.25 GiB" in lines[0] and "--frames N" in lines[0]
    assert not (tmp_path / "o").exists()


def test_the_manifest_check_counts_4_kib_a_frame(tmp_path):
    from sonarsim.core.memory import set_memory_budget
    from sonarsim.dataset import load_scenario
    from sonarsim.dataset.frames import MANIFEST_BYTES_PER_FRAME, require_manifest_memory
    from sonarsim.errors import ConfigError

    scenario = load_scenario(_scenario(tmp_path, 1000))
    try:
        set_memory_budget(1000 * MANIFEST_BYTES_PER_FRAME)
        require_manifest_memory(scenario)  # exactly what it holds
        set_memory_budget(1000 * MANIFEST_BYTES_PER_FRAME - 1)
        with pytest.raises(ConfigError) as info:
            require_manifest_memory(scenario)
        assert info.value.key == "trajectory.generate.frames" and "the manifest of 1000 frames" in str(info.value)
        require_manifest_memory(scenario.capped(999))  # the first 999 (--frames 999) fit
    finally:
        set_memory_budget(None)


def test_an_empty_ray_address_names_the_option(tmp_path, capsys):
    # Finding: --ray '' was refused as "ray: must be a cluster address", naming no option.
    from sonarsim.cli.main import main

    with pytest.raises(SystemExit) as info:
        main(["dataset", str(_scenario(tmp_path, 2)), "--out", str(tmp_path / "o"), "--ray", ""])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "error: argument --ray: expected a Ray cluster address, 'auto' or 'local', got ''" in err
    assert not (tmp_path / "o").exists()


def test_the_long_run_summary_is_json(tmp_path):
    # benchmarks/fuzz_dataset.py's summary, on 4 cases: counts that add up.
    import sys

    sys.path.insert(0, str(Path(fuzz.__file__).resolve().parents[2] / "benchmarks"))
    try:
        import fuzz_dataset
    finally:
        sys.path.pop(0)
    result = fuzz_dataset.run(4, 3, processes=False, trace_every=2, progress=False)
    json.dumps(result)
    assert result["cases"] == 4 and sum(result["by_status"].values()) + result["no_status"] == 4
    assert result["failures"] == 0, result["failure_cases"]
