"""Inputs that are not regular files (issue 11 review): a FIFO given as a recording, image or
region hung ``show``, ``compare``, ``fit`` and ``calibrate`` for ever (the open blocks until
someone writes), and a symbolic link loop was reported as "not found"."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import yaml

from sonarsim.errors import SonarsimError, check_input_file

SCENE = {"sonar": {"preset": "aris3000-128"}, "render": {"elevation_samples": 8}}


@pytest.fixture()
def odd(tmp_path):
    fifo = tmp_path / "pipe.raw"
    os.mkfifo(fifo)
    loop = tmp_path / "loop.raw"
    os.symlink(tmp_path / "loop2.raw", loop)
    os.symlink(loop, tmp_path / "loop2.raw")
    scene = tmp_path / "s.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    return fifo, loop, scene


def test_check_input_file_tells_the_kinds_apart(tmp_path, odd):
    fifo, loop, scene = odd
    with pytest.raises(SonarsimError, match=r"pipe.raw: not a regular file \(a device or pipe\?\); give a recording"):
        check_input_file(fifo, "recording")
    with pytest.raises(SonarsimError, match="loop.raw: cannot read the recording: Too many levels of symbolic links"):
        check_input_file(loop, "recording")
    with pytest.raises(SonarsimError, match="is a directory, not a recording"):
        check_input_file(tmp_path, "recording")
    with pytest.raises(SonarsimError, match="nothere.raw: recording not found"):
        check_input_file(tmp_path / "nothere.raw", "recording")
    assert check_input_file(scene, "scene file").st_size == scene.stat().st_size


@pytest.mark.parametrize("command", [
    ["show", "{bad}", "--out", "{tmp}/o"],
    ["compare", "{bad}", "{bad}"],
    ["compare", "{tmp}/a.npz", "{tmp}/a.npz", "--region", "x={bad}"],
    ["fit", "{bad}", "--scene", "{scene}", "--out", "{tmp}/f.yaml"],
    ["calibrate", "{bad}", "--scene", "{scene}", "--out", "{tmp}/c.yaml"],
    ["render", "{bad}", "--out", "{tmp}/o"],
])
def test_fifos_and_link_loops_end_in_one_line_without_hanging(tmp_path, odd, command):
    import sonarsim

    fifo, loop, scene = odd
    sonarsim.render({"sonar": {"n_beams": 4, "azimuth_fov_deg": 10, "elevation_fov_deg": 10, "range_min_m": 0.5,
                               "range_max_m": 2.0, "n_range_bins": 20}}).save_npz(tmp_path / "a.npz")
    for bad, message in ((fifo, "not a regular file"), (loop, "Too many levels of symbolic links")):
        argv = [a.format(bad=bad, tmp=tmp_path, scene=scene) for a in command]
        r = subprocess.run([sys.executable, "-m", "sonarsim.cli.main", *argv], capture_output=True, text=True,
                           timeout=60)
        assert r.returncode == 2, (argv, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, (argv, r.stderr)
        assert "not found" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_a_mesh_that_is_a_link_loop_is_not_called_missing(tmp_path, odd):
    import sonarsim
    from sonarsim.errors import MeshFileError
    from sonarsim.scene.meshes import load_mesh_file

    fifo, loop, scene = odd
    with pytest.raises(MeshFileError, match="cannot read the mesh file: Too many levels of symbolic links"):
        load_mesh_file(loop)
    with pytest.raises(SonarsimError, match="not a regular file"):
        sonarsim.load_scene({**SCENE, "objects": [{"name": "m", "mesh": str(fifo)}]})


def test_a_mesh_file_beyond_the_budget_is_refused_before_reading(tmp_path):
    # A sparse 10 GB file: read whole, it ended in "cannot read mesh (MemoryError: )" after
    # filling memory.
    from sonarsim.errors import MeshFileError
    from sonarsim.scene.meshes import load_mesh_file

    huge = tmp_path / "huge.stl"
    with open(huge, "wb") as f:
        f.truncate(10 * 2**30)
    with pytest.raises(MeshFileError, match=r"huge.stl: reading a mesh file of 1.024e\+04 MiB would need 40 GiB, "
                                            "more than the memory budget"):
        load_mesh_file(huge)
