"""The ground specialisation in blocks of beams: the fused block (GroundBlocks, casting through
the Embree 4 binding's packet loop) against the same stages called one by one from Python, and
one thread against two. Same kernels in the same order on the same arrays: the same bits."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.cli.demo import demo_scene_dict
from sonarsim.errors import SonarsimError
from sonarsim.renderer import compiled

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
pytest.importorskip("sonarsim.trace._embree4")

POSES = [None, {"position_m": [0.3, 0.2, 1.3], "rpy_deg": [-10.0, 28.0, 8.0]},
         {"position_m": [-0.2, -0.4, 0.7], "rpy_deg": [6.0, 12.0, -15.0]}]


def _variants():
    base = demo_scene_dict()
    out = {"demo": base}
    for key, value in (("double_beam", "split"), ("double_line_of_sight", True), ("tvg", False),
                       ("range_splat", False), ("azimuth_samples", 3)):
        d = copy.deepcopy(base)
        d["render"][key] = value
        out[f"{key}={value}"] = d
    rough = copy.deepcopy(base)
    for obj in rough["objects"]:
        obj.pop("albedo", None)
        obj["material"] = {"law": "rough", "albedo": 0.3, "specular_strength": 2.0, "roughness": 0.15}
    out["rough_objects"] = rough
    single = copy.deepcopy(base)
    single["render"]["bounces"] = [1]
    out["single_bounce"] = single
    return out


def _stacks(doc, threads, fused, monkeypatch):
    doc = copy.deepcopy(doc)
    doc["render"]["threads"] = threads
    with monkeypatch.context() as m:
        if not fused:
            m.setattr(compiled, "ground_blocks", lambda *a: None)
        with sonarsim.Simulator(doc) as sim:
            assert sim.caster.name == "embree4"
            out = []
            for pose in POSES:
                img = sim.render(pose=pose)
                out.append(np.stack([img.components[k] for k in ("object", "ground", "double", "triple", "total")]))
                out.append(img.rays.distance_m)
                out.append(img.rays.intensity)
            if fused:
                assert sim._work.ground_blocks is not None  # the fused route was taken
            return out


@pytest.mark.parametrize("name", list(_variants()))
def test_fused_blocks_equal_the_stages_called_one_by_one(name, monkeypatch):
    doc = _variants()[name]
    reference = _stacks(doc, 1, False, monkeypatch)
    assert any(a.any() for a in reference[0::3][:1])
    for threads, fused in ((1, True), (2, True), (2, False)):
        got = _stacks(doc, threads, fused, monkeypatch)
        for a, b in zip(got, reference):
            np.testing.assert_array_equal(a, b, err_msg=f"threads={threads} fused={fused}")


def test_blocks_cover_the_beams_once():
    for n, k in ((128, 4), (7, 4), (3, 8), (1, 1), (512, 6)):
        blocks = compiled.beam_blocks(n, k)
        assert blocks[0][0] == 0 and blocks[-1][1] == n
        assert all(b0 < b1 for b0, b1 in blocks) and all(blocks[i][1] == blocks[i + 1][0] for i in range(len(blocks) - 1))
        assert len(blocks) == min(n, k)
        sizes = [b1 - b0 for b0, b1 in blocks]
        assert max(sizes) - min(sizes) <= 1


def test_on_both_cores_runs_every_task_once_and_waits_for_the_other_thread():
    from concurrent.futures import ThreadPoolExecutor
    import threading
    import time

    seen, threads = [], set()

    def task(k):
        time.sleep(0.002)
        seen.append(k)
        threads.add(threading.get_ident())

    with ThreadPoolExecutor(1) as pool:
        compiled.on_both_cores(task, 9, pool)
        assert sorted(seen) == list(range(9)) and len(threads) == 2
        # A task that raises: the error reaches the caller after the other thread stopped.
        done = []

        def failing(k):
            time.sleep(0.002)
            if k == 1:
                raise ValueError("block 1")
            done.append(k)

        with pytest.raises(ValueError, match="block 1"):
            compiled.on_both_cores(failing, 6, pool)
        n = len(done)
        time.sleep(0.02)
        assert len(done) == n  # nothing ran after the call returned


def test_ground_blocks_refuse_misuse():
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        sim.render()
        blocks = sim._work.ground_blocks[3]
        with pytest.raises(ValueError, match="outside"):
            blocks.block(0, 10_000)
        with pytest.raises(ValueError, match="outside"):
            blocks.block(5, 2)
        assert blocks.block(3, 3) == 0


def test_a_released_caster_is_not_cast_through():
    sim = sonarsim.Simulator(demo_scene_dict())
    sim.render()
    blocks = sim._work.ground_blocks[3]
    sim.caster.release()
    with pytest.raises(SonarsimError, match="released"):
        sim.render()
    # Nor by the fused blocks already built on it (the Embree scene is freed).
    with pytest.raises(SonarsimError, match="closed"):
        blocks.block(0, 4)


def test_a_sonar_with_as_many_rays_but_other_beams_gets_its_own_workspace():
    """64 beams x 366 elevation rays are as many rays as the demo's 128 x 183: a workspace kept
    for the ray count alone gave the second sonar the first one's beam of each ray."""
    from dataclasses import replace

    for doc in (demo_scene_dict(), _with_surface(demo_scene_dict())):
        sim = sonarsim.Simulator(doc)
        a = sim.scene.sonar
        angles = np.linspace(max(a.beam_angles_deg), min(a.beam_angles_deg), 64)
        b = replace(a, beam_angles_deg=tuple(angles), elevation_fov_deg=27.95)
        assert sim.ray_fan(b).n_rays == sim.ray_fan(a).n_rays and sim.ray_fan(b).shape[0] != sim.ray_fan(a).shape[0]
        sim.render(keep_rays=False)
        got = sim.render(sonar=b, keep_rays=False).polar
        with sonarsim.Simulator(doc) as fresh:
            np.testing.assert_array_equal(got, fresh.render(sonar=b, keep_rays=False).polar)
        sim.close()


def _with_surface(doc):
    doc = copy.deepcopy(doc)
    doc["planes"] = [{"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0,
                      "specular": 0.9}]
    return doc
