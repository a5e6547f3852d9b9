"""The general path engine in blocks of beams (``_kernels.PathBlocks``): the fused block
(casting through the Embree 4 binding's packet loop) against the same stages with Python
casting between them, one thread against two, and any cut of the beams into blocks. The
same kernels on the same rays: the same bits."""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import numpy as np
import pytest

import sonarsim
from sonarsim.cli.demo import demo_scene_dict
from sonarsim.paths.engine import SonarView, probe_chains
from sonarsim.paths.planes import ChainTable, PlaneSet
from sonarsim.renderer import compiled

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
pytest.importorskip("sonarsim.trace._embree4")

POSES = [None, {"position_m": [0.3, 0.2, 1.3], "rpy_deg": [-10.0, 28.0, 8.0]},
         {"position_m": [-0.2, -0.4, 0.7], "rpy_deg": [6.0, 12.0, -15.0]}]

WALLS = [
    {"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0, "specular": 0.9},
    {"name": "far_wall", "point_m": [4.5, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.3, "specular": 0.5},
    {"name": "left_wall", "point_m": [0.0, 2.0, 0.0], "normal": [0.0, -1.0, 0.0], "albedo": 0.3, "specular": 0.5},
    {"name": "right_wall", "point_m": [0.0, -2.0, 0.0], "normal": [0.0, 1.0, 0.0], "albedo": 0.3, "specular": 0.5},
    {"name": "back_wall", "point_m": [-1.5, 0.0, 0.0], "normal": [1.0, 0.0, 0.0], "albedo": 0.3, "specular": 0.5},
]


def _tank(n_walls: int, max_order: int) -> dict:
    doc = demo_scene_dict()
    doc["planes"] = copy.deepcopy(WALLS[:n_walls])
    doc["render"]["max_order"] = max_order
    doc["render"].pop("bounces", None)
    return doc


def _variants():
    base = demo_scene_dict()
    out = {"demo": base, "tank6_order3": _tank(5, 3), "tank2_order5": _tank(1, 5)}
    for key, value in (("double_beam", "split"), ("double_beam", "separate"), ("double_line_of_sight", True),
                       ("tvg", False), ("range_splat", False), ("azimuth_samples", 3)):
        d = copy.deepcopy(out["tank6_order3"] if key == "double_beam" else base)
        d["render"][key] = value
        out[f"{key}={value}"] = d
    rough = copy.deepcopy(base)
    for obj in rough["objects"]:
        obj.pop("albedo", None)
        obj["material"] = {"law": "rough", "albedo": 0.3, "specular_strength": 2.0, "roughness": 0.15}
    out["rough_objects"] = rough
    return out


def _frames(doc, threads, fused, monkeypatch, n_blocks=compiled.N_BLOCKS, capacity=compiled.CHAIN_CAPACITY):
    doc = copy.deepcopy(doc)
    doc["render"]["threads"] = threads
    with monkeypatch.context() as m:
        m.setattr(compiled, "N_BLOCKS", n_blocks)
        m.setattr(compiled, "CHAIN_CAPACITY", capacity)
        if not fused:
            m.setattr(compiled, "packet_loop", lambda caster: None)
        with sonarsim.Simulator(doc) as sim:
            sim.specialise_ground = False
            assert sim.caster.name == "embree4"
            out = []
            for pose in POSES:
                img = sim.render(pose=pose, speckle=False)
                out.append(np.stack([img.components[k] for k in ("object", "ground", "single", "double", "triple", "total")]))
                out.append(img.rays.distance_m)
                out.append(img.rays.intensity)
                out.append(np.stack([img.components[k] for k in sorted(img.components.signatures)]))
            assert sim._work.engine[4].fused == fused
            return out


@pytest.mark.parametrize("name", list(_variants()))
def test_fused_blocks_equal_the_stages_with_python_casting(name, monkeypatch):
    doc = _variants()[name]
    reference = _frames(doc, 1, False, monkeypatch)
    assert reference[0].any()
    for threads, fused in ((1, True), (2, True), (2, False)):
        got = _frames(doc, threads, fused, monkeypatch)
        for a, b in zip(got, reference):
            np.testing.assert_array_equal(a, b, err_msg=f"threads={threads} fused={fused}")


@pytest.mark.parametrize("name", ["demo", "tank6_order3", "tank2_order5"])
def test_the_image_does_not_depend_on_how_the_beams_are_cut_into_blocks(name, monkeypatch):
    doc = _variants()[name]
    reference = _frames(doc, 2, True, monkeypatch)
    for n_blocks in (1, 3, 13):
        for a, b in zip(_frames(doc, 2, True, monkeypatch, n_blocks=n_blocks), reference):
            np.testing.assert_array_equal(a, b, err_msg=f"{n_blocks} blocks")


def test_a_block_whose_chain_table_overflows_is_traced_again_with_a_larger_one(monkeypatch):
    doc = _tank(5, 4)
    reference = _frames(doc, 2, True, monkeypatch)
    for fused in (True, False):
        for a, b in zip(_frames(doc, 2, fused, monkeypatch, capacity=2), reference):
            np.testing.assert_array_equal(a, b)


def test_chains_are_numbered_canonically_whatever_order_they_were_met_in():
    planes = PlaneSet.from_specs(sonarsim.load_scene(_tank(5, 4)).reflecting_planes)
    a = ChainTable(planes, np.zeros(3), 3)
    b = ChainTable(planes, np.zeros(3), 3)
    chains = [(1, 0, 2), (0,), (3, 1), (2,), (0, 4, 1)]
    for c in chains:
        a.add(c)
    for c in reversed(chains):
        b.add(c)
    ca, remap_a = a.canonical()
    cb, remap_b = b.canonical()
    assert ca.chains == cb.chains
    assert ca.chains == sorted(ca.chains, key=lambda c: (len(c), c))  # by ChainTable.key
    for table, remap in ((a, remap_a), (b, remap_b)):
        for old, new in enumerate(remap):
            assert ca.chains[new] == table.chains[old]
    for c in range(len(ca)):  # the children table agrees with the chains
        for p in range(len(planes)):
            k = ca.children[c, p]
            assert (k < 0) == (ca.chains[c] + (p,) not in ca.chains)


@pytest.mark.parametrize("seed", range(6))
def test_the_probe_kernel_follows_the_chains_its_twin_follows(seed):
    rng = np.random.default_rng(seed)
    doc = _tank(5, 5)
    scene = sonarsim.load_scene(doc)
    planes = PlaneSet.from_specs(scene.reflecting_planes)
    pose = sonarsim.Pose(rng.uniform([-1.0, -1.5, 0.3], [3.5, 1.5, 1.8]), rng.uniform([-20, -10, -90], [20, 60, 90]))
    view = SonarView.of(scene.sonar, pose)
    active = planes.facing(pose.translation)
    got = {}
    for kernel in (None, compiled.probe_kernel()):
        table = ChainTable(planes, pose.translation, 4)
        probe_chains(table, view, active, 4, kernel=kernel)
        got[kernel is None] = sorted(table.chains)
    assert got[True] == got[False]
    assert len(got[True]) > 1
