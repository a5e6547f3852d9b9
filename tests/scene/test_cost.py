"""Sizes refused before they are spent (issue 21 item 2): a scene's objects and triangles, a
scenario's variation groups and labels, and mesh files, estimated from the document and checked
against the memory and time budgets before anything is built."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

import sonarsim
from sonarsim.config.loader import scene_from_dict
from sonarsim.core import memory
from sonarsim.errors import ConfigError, MeshFileError
from sonarsim.scene.cost import BYTES_PER_TRIANGLE, check_scene_cost, object_triangles, scene_cost
from sonarsim.scene.meshes import distinct_faces, load_mesh_file, object_mesh_local

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30, "elevation_fov_deg": 12, "range_min_m": 0.5, "range_max_m": 5.0,
         "n_range_bins": 100, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}}


def _spheres(n, radius):
    rng = np.random.default_rng(0)
    return [{"name": f"s{i}", "primitive": "sphere", "radius_m": radius,
             "pose": {"position_m": [float(rng.uniform(1, 4)), float(rng.uniform(-1, 1)), 0.5]}} for i in range(n)]


@pytest.fixture
def budgets():
    yield
    memory.set_memory_budget(None)
    memory.set_time_budget(None)


def test_the_estimate_counts_the_triangles_the_simulator_builds():
    objects = [{"name": "b", "primitive": "box", "size_m": [0.3, 0.3, 0.3]},
               {"name": "s", "primitive": "sphere", "radius_m": 0.01},
               {"name": "S", "primitive": "sphere", "radius_m": 0.3, "scale": [1, 2, 1]},
               {"name": "c", "primitive": "cylinder", "radius_m": 0.02, "height_m": 0.4}]
    scene = scene_from_dict({"sonar": SONAR, "objects": [
        {**o, "pose": {"position_m": [2.0 + i, 0, 0.5]}} for i, o in enumerate(objects)]})
    sim = sonarsim.Simulator(scene)
    built = [len(m.faces) for m in sim.meshes]
    assert built == [object_triangles(o) for o in scene.objects]
    cost = scene_cost(scene)
    assert cost.triangles == sum(built) and cost.objects == 4
    assert cost.bytes >= cost.triangles * BYTES_PER_TRIANGLE
    sim.close()


def test_twenty_thousand_large_spheres_are_refused_before_anything_is_built(budgets):
    # 20,000 spheres of 20 cm: 102 million triangles, about 19 GiB; refused from the specs alone.
    scene = scene_from_dict({"sonar": SONAR, "objects": _spheres(20_000, 0.2)})
    memory.set_memory_budget(8 * 2**30)
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=r"^objects: building 20,000 objects of 102,400,000 triangles would need "
                       r"19\.\d GiB, more than the memory budget of 8 GiB"):
        sonarsim.Simulator(scene)
    assert time.monotonic() - t0 < 30  # a hang guard (about 2 s here): the specs are counted, nothing is built


def test_the_time_budget_refuses_what_the_memory_budget_lets_through(budgets):
    scene = scene_from_dict({"sonar": SONAR, "objects": _spheres(2_000, 0.2)})  # 10 million triangles
    memory.set_memory_budget(8 * 2**30)  # 1.9 GiB fits
    memory.set_time_budget(10)
    with pytest.raises(ConfigError, match=r"^objects: building 2,000 objects of 10,240,000 triangles would take about "
                       r"3\d\.\d s, more than the build-time budget of 10 s \(raise it with --max-build-time"):
        check_scene_cost(scene)
    memory.set_time_budget(None)
    assert check_scene_cost(scene).triangles == 10_240_000


def test_many_small_spheres_build_in_time_linear_in_their_number():
    # 1 cm pebbles: 320 triangles each (not 5120); 4x the pebbles, about 4x the work.
    assert object_triangles(scene_from_dict({"sonar": SONAR, "objects": _spheres(1, 0.01)}).objects[0]) == 320
    small, large = (scene_cost(scene_from_dict({"sonar": SONAR, "objects": _spheres(n, 0.01)})) for n in (500, 2000))
    assert large.triangles == 4 * small.triangles and large.seconds == pytest.approx(4 * small.seconds)


def test_distinct_faces_drops_repeats_and_degenerate_faces_and_keeps_both_windings():
    faces = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1], [0, 2, 1], [1, 3, 2], [0, 1, 2]], np.int32)
    proper = np.array([True, True, True, True, False, True])
    kept = distinct_faces(faces, proper)
    # The three rotations of one face are one; the reversed winding is another surface side.
    assert kept.tolist() == [[0, 1, 2], [0, 2, 1]]
    unique = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    assert distinct_faces(unique) is unique


def test_a_mesh_of_a_million_copies_of_one_face_is_one_face(tmp_path):
    # Each ray tested every copy (30 s a frame); one face is the same surface.
    p = tmp_path / "copies.obj"
    p.write_text("v 2 0 0.2\nv 2 1 0.2\nv 2 0 1.2\nv 2 1 1.2\n" + "f 1 2 3\n" * 200_000 + "f 2 4 3\n" + "f 1 1 2\n" * 10)
    mesh = load_mesh_file(p)
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 3, 2]]


def test_a_mesh_file_beyond_the_time_budget_is_refused_before_it_is_read(tmp_path, budgets, monkeypatch):
    p = tmp_path / "big.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "f 1 2 3\n" * 1_500_000)  # 12 MB: about 5 s to parse
    memory.set_time_budget(1)
    # Not read: the mesh reader is never asked (a clock said the same on a quiet machine only).
    from sonarsim.config import meshfiles

    monkeypatch.setattr(meshfiles, "_trimesh", lambda: pytest.fail("the mesh file was read"))
    with pytest.raises(MeshFileError, match=r"big\.obj: reading a mesh file of 11\.44 MiB would take about \d\.\d s, "
                       r"more than the build-time budget of 1 s"):
        load_mesh_file(p)


@pytest.mark.parametrize("text, seconds", [("300", 300.0), ("90s", 90.0), ("5min", 300.0), ("1.5 h", 5400.0)])
def test_time_budgets_read(text, seconds):
    assert memory.parse_seconds(text) == seconds


@pytest.mark.parametrize("text", ["", "abc", "0", "0.5", "-3", "1e9", "5 days", "inf", "nan"])
def test_bad_time_budgets_are_refused(text):
    with pytest.raises(ValueError, match="a time is|between 1 s and a week"):
        memory.parse_seconds(text)


def test_the_time_budget_from_the_environment_and_the_command_line(tmp_path, monkeypatch, budgets):
    from sonarsim.cli.main import main

    # The command's budgets hold for its run only (they reach its workers through the
    # environment): an in-process call leaves neither the environment nor the budgets set.
    monkeypatch.delenv(memory.ENV_VAR, raising=False)
    assert main(["--max-memory", "1G", "--max-build-time", "7", "presets"]) == 0
    assert memory.ENV_VAR not in os.environ and memory.TIME_ENV_VAR not in os.environ
    assert memory.time_budget() == memory.DEFAULT_TIME_BUDGET_S
    monkeypatch.setenv(memory.TIME_ENV_VAR, "42")
    assert memory.time_budget() == 42.0
    monkeypatch.setenv(memory.TIME_ENV_VAR, "soon")
    with pytest.raises(sonarsim.SonarsimError, match=r"SONARSIM_MAX_BUILD_TIME: a time is"):
        memory.time_budget()
    monkeypatch.delenv(memory.TIME_ENV_VAR)
    assert memory.time_budget() == memory.DEFAULT_TIME_BUDGET_S
    scene = tmp_path / "scene.yaml"
    import yaml

    scene.write_text(yaml.safe_dump({"sonar": SONAR, "objects": _spheres(2_000, 0.2)}))
    out = subprocess.run([sys.executable, "-m", "sonarsim.cli.main", "--max-memory", "8G", "--max-build-time", "10",
                          "render", str(scene),
                          "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines() == [
        f"sonarsim: error: {scene}: objects: building 2,000 objects of 10,240,000 triangles would take about "
        f"{3 * 10_240_000e-6 + 0.2:.3g} s, more than the build-time budget of 10 s (raise it with --max-build-time or "
        "$SONARSIM_MAX_BUILD_TIME)"]
    assert not (tmp_path / "out").exists()
    bad = subprocess.run([sys.executable, "-m", "sonarsim.cli.main", "--max-build-time", "never", "presets"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--max-build-time: a time is" in bad.stderr and "Traceback" not in bad.stderr
