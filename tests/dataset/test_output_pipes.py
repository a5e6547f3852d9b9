"""Files sonarsim keeps in its output folders (a dataset's manifest and description, a run's
record) are read only when they are regular files: a pipe put in their place must not block a
resumed run (issue 21)."""

from __future__ import annotations

import os

import pytest

from sonarsim.dataset.manifest import read_manifest
from sonarsim.dataset.writer import INFO_NAME, MANIFEST_NAME, generate
from sonarsim.errors import SonarsimError
from sonarsim.io.run_record import read_record
from tests.fifo import no_hang

SCENARIO = {
    "seed": 0,
    "scene": {"sonar": {"preset": "aris3000-128", "n_range_bins": 64,
                        "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}}, "ground": {}},
    "trajectory": {"generate": {"kind": "orbit", "centre_m": [3, 0, 0.2], "radius_m": 2.5, "z_m": 1.0, "frames": 2}},
}


def test_a_pipe_as_the_manifest_is_refused_not_read(tmp_path):
    fifo = tmp_path / MANIFEST_NAME
    os.mkfifo(fifo)
    with pytest.raises(SonarsimError, match=r"manifest\.jsonl: not a regular file \(a device or pipe\?\); give a "
                       "dataset manifest"):
        no_hang(lambda: read_manifest(fifo), [fifo])
    assert read_manifest(tmp_path / "none.jsonl") == []


@pytest.mark.parametrize("name", [INFO_NAME, MANIFEST_NAME])
def test_a_dataset_folder_holding_a_pipe_is_refused_naming_it(tmp_path, name):
    out = tmp_path / "out"
    out.mkdir()
    fifo = out / name
    os.mkfifo(fifo)
    with pytest.raises(SonarsimError, match=rf"{name.replace('.', '[.]')}: not a regular file"):
        no_hang(lambda: generate(SCENARIO, out, labels="none", progress=False), [fifo], seconds=60)


def test_a_pipe_as_a_run_record_is_no_record(tmp_path):
    fifo = tmp_path / "sonarsim-run.json"
    os.mkfifo(fifo)
    assert no_hang(lambda: read_record(fifo), [fifo]) is None
