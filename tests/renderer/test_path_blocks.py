"""The general path engine in blocks of beams (``_kernels.PathBlocks``): the fused block
(casting through the Embree 4 binding's packet loop) against the same stages with Python
casting between them, one thread against two, and any cut of the beams into blocks. The
same kernels on the same rays: the same bits."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.config.examples import demo_scene_dict
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
    mirrors = _tank(1, 4)  # the block and the pipe mirror (mesh mirrors, issue 25) in a tank
    for obj in mirrors["objects"]:
        if obj["name"] in ("concrete_block", "pipe"):
            obj["specular"] = 0.5
    out["mirrors_order4"] = mirrors
    smooth = copy.deepcopy(mirrors)  # the pipe mirrors about its smooth normals: partners formed
    for obj in smooth["objects"]:
        if obj["name"] == "pipe":
            obj["normals"] = "smooth"
    smooth["render"]["double_beam"] = "separate"
    out["mirrors_smooth_separate"] = smooth
    # And the specular returns (one generation more, traced): the far wall met square on, the
    # sonar level.
    glints = _tank(2, 4)
    for obj in glints["objects"]:
        if obj["name"] in ("concrete_block", "pipe"):
            obj["specular"] = 0.5
    glints["sonar"]["pose"]["rpy_deg"] = [0.0, 3.0, 0.0]
    glints["render"].update(glints=True, glint_radius_m=0.2)
    out["mirrors_glints"] = glints
    return out


def _frames(doc, threads, fused, monkeypatch, n_blocks=compiled.N_BLOCKS, capacity=compiled.CHAIN_CAPACITY,
            path_buffer_bytes=compiled.PATH_BUFFER_BYTES):
    doc = copy.deepcopy(doc)
    doc["render"]["threads"] = threads
    with monkeypatch.context() as m:
        m.setattr(compiled, "N_BLOCKS", n_blocks)
        m.setattr(compiled, "CHAIN_CAPACITY", capacity)
        m.setattr(compiled, "PATH_BUFFER_BYTES", path_buffer_bytes)
        if not fused:
            m.setattr(compiled, "packet_loop", lambda caster: None)
        with sonarsim.Simulator(doc) as sim:
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


@pytest.mark.parametrize("name", ["demo", "tank6_order3", "tank2_order5", "mirrors_order4", "mirrors_smooth_separate",
                                  "mirrors_glints"])
def test_the_image_does_not_depend_on_how_the_beams_are_cut_into_blocks(name, monkeypatch):
    doc = _variants()[name]
    reference = _frames(doc, 2, True, monkeypatch)
    for n_blocks in (1, 3, 13):
        for a, b in zip(_frames(doc, 2, True, monkeypatch, n_blocks=n_blocks), reference):
            np.testing.assert_array_equal(a, b, err_msg=f"{n_blocks} blocks")


@pytest.mark.parametrize("name", ["tank6_order4", "mirrors_order4"])
def test_a_block_whose_chain_table_overflows_is_traced_again_with_a_larger_one(name, monkeypatch):
    doc = _tank(5, 4) if name == "tank6_order4" else _variants()[name]
    reference = _frames(doc, 2, True, monkeypatch)
    for fused in (True, False):
        for a, b in zip(_frames(doc, 2, fused, monkeypatch, capacity=2), reference):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", ["demo", "mirrors_order4", "double_beam=separate", "mirrors_smooth_separate"])
def test_a_path_buffer_laid_out_for_the_counted_paths_gives_the_same_frames(name, monkeypatch):
    """Past ``PATH_BUFFER_BYTES`` (here: always) a frame counts its paths in a first pass and
    lays its path buffer out for them alone: the same frames, labels and signatures, and a
    buffer of exactly its paths."""
    doc = _variants()[name]
    reference = _frames(doc, 2, True, monkeypatch)
    sizes = []
    real = compiled.PathBuffer.__init__

    def spy(self, options, offset, size, n_blocks, pool=None, swap=None):
        real(self, options, offset, size, n_blocks, pool, swap)
        sizes.append((size, self))

    monkeypatch.setattr(compiled.PathBuffer, "__init__", spy)
    for fused in (True, False):
        for a, b in zip(_frames(doc, 2, fused, monkeypatch, path_buffer_bytes=0), reference):
            np.testing.assert_array_equal(a, b)
    size, buffer = sizes[-1]
    assert size == buffer.count.sum() > 0  # every entry a path
    np.testing.assert_array_equal(buffer.offset[1:], np.cumsum(buffer.count)[:-1])
    with sonarsim.Simulator(doc) as sim:  # labels formed in the pass, too
        monkeypatch.setattr(compiled, "PATH_BUFFER_BYTES", 0)
        counted = sim.render(speckle=False, labels=True)
        monkeypatch.setattr(compiled, "PATH_BUFFER_BYTES", 2**40)
        plain = sim.render(speckle=False, labels=True)
    a, b = counted.labels.arrays(), plain.labels.arrays()
    assert a.keys() == b.keys() and len(a) > 3
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


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


def test_blocks_cover_the_beams_once():
    for n, k in ((128, 4), (7, 4), (3, 8), (1, 1), (512, 6)):
        blocks = compiled.beam_blocks(n, k)
        assert blocks[0][0] == 0 and blocks[-1][1] == n
        assert all(b0 < b1 for b0, b1 in blocks) and all(blocks[i][1] == blocks[i + 1][0] for i in range(len(blocks) - 1))
        assert len(blocks) == min(n, k)
        sizes = [b1 - b0 for b0, b1 in blocks]
        assert max(sizes) - min(sizes) <= 1


@pytest.mark.parametrize("kind", ["thread_pool", "second_core"])
def test_on_both_cores_runs_every_task_once_and_waits_for_the_other_thread(kind):
    from concurrent.futures import ThreadPoolExecutor
    import threading
    import time

    seen, threads = [], set()
    both = threading.Event()

    def task(k):
        threads.add(threading.get_ident())
        if len(threads) == 2:
            both.set()
        # Each thread holds its first task until the other has one: on a loaded machine the
        # worker may start after this thread has drained every 2 ms task (one thread seen).
        both.wait(30)
        seen.append(k)

    with (ThreadPoolExecutor(1) if kind == "thread_pool" else compiled.SecondCore()) as pool:
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


def test_path_blocks_refuse_misuse(monkeypatch):
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        sim.render()
        engine = sim._work.engine[4]
        with pytest.raises(ValueError, match="frame"):  # it let go of the frame's arrays
            engine.trace(0, 0, 4)
        checked = []
        run = compiled.on_both_cores

        def checking(task, n, pool=None, signals=False):
            if not checked:  # inside the frame, before its blocks are traced
                for args in ((0, 0, 10_000), (0, 5, 2), (99, 0, 4)):
                    with pytest.raises(ValueError, match="block"):
                        engine.trace(*args)
                assert engine.trace(0, 3, 3)  # no beams: nothing to do
                checked.append(True)
            run(task, n, pool, signals)

        monkeypatch.setattr(compiled, "on_both_cores", checking)
        sim.render()
        assert checked


def test_a_released_caster_is_not_cast_through():
    sim = sonarsim.Simulator(demo_scene_dict())
    sim.render()
    engine = sim._work.engine[4]
    sim.caster.release()
    with pytest.raises(sonarsim.SonarsimError, match="released"):
        sim.render()
    # Nor by the blocks already built on it (the Embree scene is freed).
    with pytest.raises(sonarsim.SonarsimError, match="closed"):
        engine.trace(0, 0, 4)


def test_a_sonar_with_as_many_rays_but_other_beams_gets_its_own_workspace():
    """64 beams x 366 elevation rays are as many rays as the demo's 128 x 183: a workspace kept
    for the ray count alone gave the second sonar the first one's beam of each ray."""
    from dataclasses import replace

    for doc in (demo_scene_dict(), _tank(1, 3)):
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


def test_the_array_pool_hands_a_set_out_again_only_once_nothing_holds_it():
    pool = compiled.ArrayPool()
    shapes = {"a": ((4, 10), np.float64), "b": ((10,), np.int32)}
    first = pool.take(shapes)
    view = first["a"][1]  # something still holds the first set (as an image holds its legs)
    second = pool.take(shapes)
    assert second["a"] is not first["a"]
    del view
    assert pool.take(shapes)["a"] is first["a"]  # free again: reused
    smaller = pool.take({"a": ((2, 5), np.float64), "b": ((3,), np.int32)})
    assert smaller["a"].shape == (4, 10)  # a larger free set serves a smaller request
    # Many frames held at once, then let go: the pool keeps no more than KEEP sets.
    held = [pool.take(shapes)["a"][:] for _ in range(20)]  # a view of each set, as a frame's legs are
    assert len({id(v.base) for v in held}) == 20 and len(pool._sets) == compiled.ArrayPool.KEEP
    kept = held[-1].base
    del held
    for _ in range(5):
        pool.take(shapes)
    assert len(pool._sets) == compiled.ArrayPool.KEEP
    assert any(s[2]["a"] is kept for s in pool._sets)


def test_a_loop_of_frames_reuses_its_legs_and_paths_and_an_image_keeps_its_own():
    sim = sonarsim.Simulator(_tank(5, 3))
    kept = sim.render()  # its signature images are formed from its legs and paths when asked
    for pose in POSES[1:]:
        sim.render(pose=pose)  # later frames cannot take the arrays the kept image still uses
    with sonarsim.Simulator(_tank(5, 3)) as fresh:
        ref = fresh.render()
    assert len(ref.components.signatures) > 4
    for k in ref.components.signatures:
        np.testing.assert_array_equal(kept.components[k], ref.components[k])
    pools = sim._work.legs_pool, sim._work.paths_pool
    n = [len(p._sets) for p in pools]
    for _ in range(4):
        sim.render()
    assert [len(p._sets) for p in pools] == n


def test_a_textured_frame_does_not_depend_on_how_the_beams_are_cut(monkeypatch):
    # Textures take Python casting between the stages, and are applied over the whole frame
    # after the blocks traced (per block, the factor's matrix products round differently).
    from tests.paths.test_floor_texture_paths import textured
    from tests.reference.test_brute_force import tank_dict

    doc = textured(tank_dict(3))
    reference = _frames(doc, 2, False, monkeypatch)
    for n_blocks in (1, 3):
        for a, b in zip(_frames(doc, 2, False, monkeypatch, n_blocks=n_blocks), reference):
            np.testing.assert_array_equal(a, b, err_msg=f"{n_blocks} blocks")
    with sonarsim.Simulator(doc, kernels="numpy") as twin, sonarsim.Simulator(doc) as sim:
        a, b = sim.render(speckle=False).polar, twin.render(speckle=False).polar
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * b.max())


def test_path_blocks_check_a_frame_and_its_options_before_keeping_them(monkeypatch):
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        sim.render()
        engine = sim._work.engine[4]
        seen = []
        run = compiled.on_both_cores

        def checking(task, n, pool=None, signals=False):
            run(task, n, pool, signals)
            if len(seen) == 0:  # after phase 1: options with a path buffer one path short
                seen.append(True)
                legs = compiled.FrameLegs(3, sim._work.n, engine.chain_tables()[1].shape[0])
                with pytest.raises(ValueError, match="legs"):
                    engine.frame(legs, np.ones(1, np.uint8), np.eye(3), np.zeros(3), 1.0, True, 4, 183, 0.7,
                                 0.01, 10, 128, 5.0, 7.0, np.linspace(15, -15, 129), True, False, 3)
                with pytest.raises(ValueError, match="call options"):  # the failed frame() left nothing set
                    engine.paths(0, 0, 4)

        monkeypatch.setattr(compiled, "on_both_cores", checking)
        with pytest.raises(ValueError, match="frame"):
            sim.render()
        monkeypatch.setattr(compiled, "on_both_cores", run)
        sim.render()  # the engine recovers on the next frame
        assert seen


def test_a_path_buffer_too_small_for_the_options_is_refused_and_the_next_frame_renders(monkeypatch):
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        good = sim.render(speckle=False).polar
        options = compiled._options
        monkeypatch.setattr(compiled, "_options", lambda *a: (*options(*a)[:2], 1, options(*a)[3]))  # room for one
        with pytest.raises(ValueError, match="does not fit in the path buffer"):
            sim.render()
        monkeypatch.setattr(compiled, "_options", options)
        np.testing.assert_array_equal(sim.render(speckle=False).polar, good)


LABELLED = ["demo", "tank6_order3", "tank2_order5", "range_splat=False", "double_beam=separate"]


def _label_arrays(labels) -> list:
    return [*(labels.instance[k] for k in labels.instance), labels.elevation_deg, labels.elevation_min_deg,
            labels.elevation_max_deg, labels.points_world, labels.points_object, labels.points_component,
            labels.points_cell, labels.boxes_polar]


def _labelled(doc, threads, fused, monkeypatch, n_blocks=compiled.N_BLOCKS, mode=True, in_pass=True):
    """Each pose's labels and image, formed in the frame's pass (or, ``in_pass=False``, from
    the frame's path sets after it, as ``double_beam: split`` does)."""
    doc = copy.deepcopy(doc)
    doc["render"]["threads"] = threads
    with monkeypatch.context() as m:
        m.setattr(compiled, "N_BLOCKS", n_blocks)
        if not fused:
            m.setattr(compiled, "packet_loop", lambda caster: None)
        render_paths, formed = compiled.render_paths, []

        def spy(*a, **k):
            result = render_paths(*a, **(k if in_pass else {**k, "labels": None}))
            formed.append(result[-1] is not None)
            return result

        m.setattr(compiled, "render_paths", spy)
        with sonarsim.Simulator(doc) as sim:
            out = []
            for pose in POSES:
                img = sim.render(pose=pose, speckle=False, labels=mode)
                out += _label_arrays(img.labels) + [img.polar, np.stack([img.components[k] for k in img.components])]
        assert formed == [in_pass] * len(POSES)  # the route asked for was the one taken
        return out


@pytest.mark.parametrize("name", LABELLED)
def test_labels_formed_in_the_pass_do_not_depend_on_threads_blocks_or_casting(name, monkeypatch):
    doc = _variants()[name]
    reference = _labelled(doc, 1, False, monkeypatch)
    assert (reference[0] >= 0).any() and len(reference[-6])  # some cell labelled, some point
    for threads, fused, n_blocks in ((2, True, compiled.N_BLOCKS), (2, False, compiled.N_BLOCKS), (2, True, 1),
                                     (2, True, 3), (1, True, 13)):
        got = _labelled(doc, threads, fused, monkeypatch, n_blocks)
        assert len(got) == len(reference)
        for a, b in zip(got, reference):
            np.testing.assert_array_equal(a, b, err_msg=f"threads={threads} fused={fused} blocks={n_blocks}")


@pytest.mark.parametrize("mode", [True, "total"])
@pytest.mark.parametrize("name", LABELLED)
def test_labels_formed_in_the_pass_equal_those_formed_from_the_path_sets_after_it(name, mode, monkeypatch):
    """The same deposits in the same order per cell (option after option, rays ascending), so
    the same bits: ids, ties, elevation moments, points in the path buffer's order."""
    doc = _variants()[name]
    after = _labelled(doc, 2, True, monkeypatch, mode=mode, in_pass=False)
    for a, b in zip(_labelled(doc, 2, True, monkeypatch, mode=mode), after):
        np.testing.assert_array_equal(a, b)
    # And the labelled frame's image is the plain frame's.
    per_pose = len(after) // len(POSES)
    with sonarsim.Simulator(doc) as sim:
        for k, pose in enumerate(POSES):
            np.testing.assert_array_equal(sim.render(pose=pose, speckle=False).polar, after[(k + 1) * per_pose - 2])


def test_the_label_scratch_is_left_clean_and_a_failed_frame_does_not_poison_the_next(monkeypatch):
    with sonarsim.Simulator(_tank(5, 3)) as sim:
        ref = _label_arrays(sim.render(speckle=False, labels=True).labels)
        scratch = sim._work.labels_scratch
        cells = scratch._arrays["cells"]
        assert (cells[:, 0::2] == -1).all()  # every cell's state back to "nothing"
        assert not scratch._arrays["touched"].any()  # and every tile's flag
        sim.render(speckle=False, labels="total")
        assert scratch._arrays["cells"] is cells  # kept: no frame fills it
        option_maps = compiled.FrameTruth.option_maps
        monkeypatch.setattr(compiled.FrameTruth, "option_maps",
                            lambda self, label: (option_maps(self, label)[0] + 99, option_maps(self, label)[1]))
        with pytest.raises(ValueError, match="order map"):
            sim.render(labels=True)
        monkeypatch.setattr(compiled.FrameTruth, "option_maps", option_maps)
        got = _label_arrays(sim.render(speckle=False, labels=True).labels)
        assert scratch._arrays["cells"] is not cells  # the failed frame's was let go
        for a, b in zip(got, ref):
            np.testing.assert_array_equal(a, b)


def test_the_frame_view_carries_the_rays_rotated_once_as_the_blocks_rotate_them():
    from sonarsim.renderer.simulator import as_pose

    with sonarsim.Simulator(_tank(5, 3)) as sim:
        for pose in POSES[1:]:
            sim.render(pose=pose)
            p = as_pose(pose)
            fan = sim.ray_fan(sim.traced_sonar(sim.scene.sonar))
            view = SonarView.of(sim.scene.sonar, p, fan)
            assert view.directions is view.directions  # formed once
            assert view.directions.shape == fan.shape + (3,) and view.pose is p
            np.testing.assert_array_equal(view.directions.reshape(-1, 3), sim._work.d64)  # the kernel's bits
            np.testing.assert_allclose(view.directions, fan.directions @ p.rotation.T, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match="no rays"):
        SonarView.of(sim.scene.sonar, p).directions


def _search(doc, monkeypatch, fused=True, kernels="compiled"):
    """The receive legs of the scene's frame (the discrete search: surfaces, triangles,
    barycentrics, scatterers), and the simulator's meshes."""
    with monkeypatch.context() as m:
        if not fused:
            m.setattr(compiled, "packet_loop", lambda caster: None)
        with sonarsim.Simulator(copy.deepcopy(doc), kernels=kernels) as sim:
            render, sonar, pose = sim.scene.render, sim.scene.sonar, sim.scene.sonar_pose
            fan = sim.ray_fan(sonar)
            active, multipath, reach = sim.frame_reach(sonar, pose)
            _, legs, *_ = sim._render_paths(sonar, SonarView.of(sonar, pose, fan), reach, active,
                                            render.max_order if multipath else 1, primitives=True)
            legs = [(leg.sid.copy(), leg.prim.copy(), leg.uv.copy(), leg.point.copy()) for leg in legs]
            return legs, sim.meshes, len(sim.planes)


@pytest.mark.parametrize("name", ["demo", "tank6_order3"])
def test_the_search_records_each_scatterer_s_triangle_and_barycentrics(name, monkeypatch):
    """Where an object scatters, the legs hold its triangle and (u, v), from which the
    scatterer is found again on the mesh (what the differentiable engine re-evaluates); -1
    and 0 on planes. The fused blocks, Python casting and the NumPy twin record the same."""
    doc = _variants()[name]
    legs, meshes, n_planes = _search(doc, monkeypatch)
    on_objects = 0
    for sid, prim, uv, point in legs:
        obj = sid >= n_planes
        assert (prim[~obj] == -1).all() and (uv[~obj] == 0).all()
        for k, mesh in enumerate(meshes):
            i = np.flatnonzero(sid == n_planes + k)
            if not len(i):
                continue
            a, b, c = (mesh.vertices[mesh.faces[prim[i], j]] for j in range(3))
            u, v = uv[i, :1].astype(float), uv[i, 1:].astype(float)
            np.testing.assert_allclose((1 - u - v) * a + u * b + v * c, point[i], rtol=0, atol=2e-5)
            assert ((u >= -1e-6) & (v >= -1e-6) & (u + v <= 1 + 1e-6)).all()
            on_objects += len(i)
    assert on_objects > 100 and (len(legs) == 1 or (legs[1][0] >= n_planes).any())  # reflected rays meet objects too
    for other in (_search(doc, monkeypatch, fused=False)[0], _search(doc, monkeypatch, kernels="numpy")[0]):
        for (sid, prim, uv, _), (sid2, prim2, uv2, _) in zip(legs, other):
            same = sid == sid2
            assert same.mean() > 0.999
            np.testing.assert_array_equal(prim[same], prim2[same])
            np.testing.assert_array_equal(uv[same], uv2[same])


def test_the_search_s_triangles_are_recorded_only_on_request():
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        sonar, pose = sim.scene.sonar, sim.scene.sonar_pose
        view = SonarView.of(sonar, pose, sim.ray_fan(sonar))
        active = sim.planes.facing(pose.translation)
        plain = sim._render_paths(sonar, view, 10.0, active, 3)
        asked = sim._render_paths(sonar, view, 10.0, active, 3, primitives=True)
        assert all(leg.prim is None and leg.uv is None for leg in plain[1])
        assert all(leg.prim is not None and leg.prim.shape == leg.sid.shape for leg in asked[1])
        np.testing.assert_array_equal(plain[0], asked[0])  # the same image either way


def _weighing_scenes():
    from tests.renderer.test_textures import multipath_scene

    v = _variants()
    return {"demo": (v["demo"], True), "tank6_order3": (v["tank6_order3"], True), "tvg=False": (v["tvg=False"], True),
            "rough_objects": (v["rough_objects"], False), "textured": (multipath_scene(), True),
            "textured_no_tvg": (multipath_scene(tvg=False), False)}


@pytest.mark.parametrize("name", list(_weighing_scenes()))
def test_the_weighing_reads_only_what_the_search_recorded(name, monkeypatch):
    """The diffuse weights are formed from the legs the search wrote (surface, incidence,
    length, the texture's factor) and nothing else: the NumPy twin's weighing, run on the
    compiled engine's recorded legs with their weights erased, gives the engine's weights and
    live rays bit for bit (fused blocks, and Python casting between the stages)."""
    from sonarsim.paths.engine import weigh_leg

    doc, fused = _weighing_scenes()[name]
    with monkeypatch.context() as m:
        if not fused:
            m.setattr(compiled, "packet_loop", lambda caster: None)
        with sonarsim.Simulator(copy.deepcopy(doc) if isinstance(doc, dict) else doc) as sim:
            render, sonar, pose = sim.scene.render, sim.scene.sonar, sim.scene.sonar_pose
            assert not sim._textured  # no plane texture: the legs' weights are the weighing's alone
            fan = sim.ray_fan(sonar)
            active, multipath, reach = sim.frame_reach(sonar, pose)
            _, legs, *_ = sim._render_paths(sonar, SonarView.of(sonar, pose, fan), reach, active,
                                            render.max_order if multipath else 1)
            assert (legs[0].texel is not None) == name.startswith("textured")
            n_planes, weighed = len(sim.planes), 0
            exact = not (np.asarray(sim._laws.lobe)[:, 0] > 0).any()  # no lobe: the same arithmetic
            for leg in legs:
                reached = np.flatnonzero(leg.sid >= 0)
                want, live = leg.intensity[reached].copy(), leg.live_rays().copy()
                leg.intensity[:] = np.nan  # what the weighing must form again
                got = weigh_leg(leg, reached, sim._laws, fan.weight.reshape(-1), render.tvg, n_planes)
                if exact:
                    np.testing.assert_array_equal(leg.intensity[reached], want)
                else:  # a lobe's exp(): NumPy's and the C library's may differ in the last bit
                    np.testing.assert_allclose(leg.intensity[reached], want, rtol=1e-14, atol=0)
                np.testing.assert_array_equal(got, live)
                weighed += len(reached)
            assert weighed > 1000 and len(legs) >= (2 if name != "demo" and "tvg" not in name else 1)


def test_label_maps_serve_one_frame_each_block_resolved_once(monkeypatch):
    """Deposits after a block's cells were resolved (and set back to "nothing") would append
    past its reached cells and table rows: refused, on both routes."""
    from sonarsim.renderer.ground_truth import LabelSpec, surface_ids

    spec = LabelSpec(surface_ids(np.arange(3), 1, 2), np.array([-1.0, 1.0]), 2, 2, (1, 2))
    truth = compiled.FrameTruth(4, spec, (1.0, 0.5, 4, 2), False)
    points, normals = np.zeros((4, 3)), np.tile(np.float32([0.0, 0.0, 1.0]), (4, 1))
    sid = np.array([1, 2, 0, 1], np.int32)
    path_set = (np.array([0, 2], np.intp), np.array([1.2, 1.7]), np.ones(2), np.array([0, 1], np.int32),
                np.zeros(2, np.int8))
    truth.maps.add(points, normals, sid, sid, *path_set, 0, True)
    truth.maps.finish(0)
    with pytest.raises(ValueError, match="already resolved"):
        truth.maps.add(points, normals, sid, sid, *path_set, 0, True)
    with pytest.raises(ValueError, match="resolved once"):
        truth.maps.finish(0)

    with sonarsim.Simulator(_tank(5, 3)) as sim:
        ref = _label_arrays(sim.render(speckle=False, labels=True).labels)
        run, calls = compiled.on_both_cores, []

        def again(task, n, pool=None, signals=False):  # the frame's second hand-off forms the paths: once more
            run(task, n, pool, signals)
            calls.append(n)
            if len(calls) == 2:
                with pytest.raises(ValueError, match="already resolved"):
                    task(0)

        monkeypatch.setattr(compiled, "on_both_cores", again)
        sim.render(speckle=False, labels=True)
        monkeypatch.setattr(compiled, "on_both_cores", run)
        assert len(calls) == 2
        # Label maps of another range grid would splat the image on their own: refused.
        init = compiled.FrameTruth.__init__
        monkeypatch.setattr(compiled.FrameTruth, "__init__",
                            lambda self, n, spec, geometry, *a: init(self, n, spec, (geometry[0] + 0.01, *geometry[1:]),
                                                                     *a))
        with pytest.raises(ValueError, match="another range grid"):
            sim.render(labels=True)
        monkeypatch.setattr(compiled.FrameTruth, "__init__", init)
        for a, b in zip(_label_arrays(sim.render(speckle=False, labels=True).labels), ref):
            np.testing.assert_array_equal(a, b)


def test_the_label_scratch_is_kept_only_when_the_frame_that_took_it_gives_it_back():
    scratch = compiled.LabelScratch()
    first = scratch.take(1, 5, 2, 3)
    second = scratch.take(1, 5, 2, 3)  # the first is still in use: a new set
    assert second is not first
    scratch.give_back(first)  # an older frame's word does not clean the newer set
    third = scratch.take(1, 5, 2, 3)
    assert third is not second
    scratch.give_back(third)
    assert scratch.take(1, 5, 2, 3) is third and (third["cells"] == -1).all() and (third["touched"] == 0).all()


def test_the_layout_kernel_forms_the_image_sources_and_offsets_as_numpy_does(monkeypatch):
    """PathBlocks.layout against its twins: ChainTable.sources bit for bit, and the path
    buffer's option-major offsets from the blocks' live rays."""
    seen = []
    layout = compiled._options

    def checking(table, n_gen, max_order, double_beam, engine, work):
        options, offset, size, only = layout(table, n_gen, max_order, double_beam, engine, work)
        gen, tx, same, _, length, _, sources, _, _ = options
        assert (only == -1).all()  # (planes only: every transmit chain flat)
        for o in range(len(gen)):
            if same[o]:
                assert not sources[o].any()
            else:
                np.testing.assert_array_equal(sources[o, : length[o] + 1], table.sources(int(tx[o])))
        n_live = engine_live[0]
        capacity = n_live[:, gen].T.reshape(-1)
        np.testing.assert_array_equal(offset, np.concatenate([[0], np.cumsum(capacity)[:-1]]))
        assert size == capacity.sum()
        seen.append(int((same == 0).sum()))
        return options, offset, size, only

    frame_legs = compiled.FrameLegs
    engine_live = []

    def legs(*a, **k):
        out = frame_legs(*a, **k)
        engine_live[:] = [out.n_live]
        return out

    monkeypatch.setattr(compiled, "_options", checking)
    monkeypatch.setattr(compiled, "FrameLegs", legs)
    with sonarsim.Simulator(_tank(5, 4)) as sim:
        for pose in POSES:
            sim.render(pose=pose)
    assert len(seen) == len(POSES) and min(seen) > 3  # options along chains of planes, every frame


def test_the_second_core_runs_tasks_in_order_passes_errors_and_stops_when_collected():
    import gc
    import threading
    import weakref

    pool = compiled.SecondCore()
    order = []
    futures = [pool.submit(order.append, k) for k in range(50)]
    assert [f.result() for f in futures] == [None] * 50 and order == list(range(50))
    assert list(pool.map(lambda x: x * x, range(5))) == [0, 1, 4, 9, 16]
    with pytest.raises(ZeroDivisionError):
        pool.submit(lambda: 1 / 0).result()
    thread = pool._thread
    assert thread.is_alive()
    ref = weakref.ref(pool)
    del pool, futures
    gc.collect()
    assert ref() is None
    thread.join(timeout=5)
    assert not thread.is_alive()  # collected: its thread stopped
    other = compiled.SecondCore()
    other.shutdown()
    assert not other._thread.is_alive() and not any(t is other._thread for t in threading.enumerate())
    with pytest.raises(RuntimeError, match="shutdown"):
        other.submit(print)


def test_on_both_cores_hands_off_through_the_flag_and_never_hangs():
    """Each task runs once whichever thread takes it; a first task that raises the flag from
    without the GIL (a kernel), one that never raises it, and one that fails before it could:
    every call returns (or raises the task's error) with the worker idle again."""
    import time

    from sonarsim.renderer import _kernels

    pool = compiled.SecondCore()
    zero = np.zeros(1, np.uint8)
    # join() returns once the worker is idle again, its task done.
    future, go = pool.hand_off(lambda: time.sleep(0.02) or "slept")
    go[0] = 1
    assert pool.join(future) == "slept" and future.done()
    for mode in ("kernel", "never", "fails"):
        for n in (1, 2, 5):
            done = []

            def task(k, signal=None):
                if signal is not None and mode == "fails":
                    raise KeyError(k)
                if signal is not None and mode == "kernel":
                    _kernels.watch_flag(zero, 0.0005, signal)  # raised once the GIL is let go
                time.sleep(0.003)  # the worker's tasks end after this thread's: the call waits for them
                done.append(k)

            if mode == "fails" and n > 1:
                with pytest.raises(KeyError):
                    compiled.on_both_cores(task, n, pool, signals=True)
            else:
                compiled.on_both_cores(task, n, pool, signals=True)
                assert sorted(done) == list(range(n)), (mode, n)
            deadline = time.monotonic() + 5
            while not pool._state[2][0] and time.monotonic() < deadline:  # raised as it goes back to watching
                time.sleep(0.001)
            assert pool._state[2][0] == 1  # idle
    pool.shutdown()


def test_the_second_core_lets_go_of_its_tasks_and_refuses_what_it_cannot_run():
    import gc
    import weakref

    class Held:
        pass

    pool = compiled.SecondCore()
    held = Held()
    ref = weakref.ref(held)
    assert pool.submit(lambda h: None, held).result() is None
    del held
    gc.collect()
    assert ref() is None  # the worker does not keep its last task's arguments alive
    pool.shutdown()
    with pytest.raises(RuntimeError, match="shutdown"):
        pool.submit(print)
    stopped = compiled.SecondCore()
    stopped._stop()  # the thread stops (as in a process forked from one that had started it)
    stopped._thread.join(timeout=5)
    with pytest.raises(RuntimeError, match="worker thread is gone"):
        stopped.submit(print)


@pytest.mark.parametrize("kind", ["thread_pool", "second_core"])
def test_an_interrupted_frame_waits_for_the_other_thread_before_it_lets_go(kind):
    """Ctrl-C while the frame's thread waits for the other: the wait goes on until the other
    thread's tasks end (they write into the frame's arrays), then the interrupt is raised."""
    from concurrent.futures import ThreadPoolExecutor
    import threading
    import time

    pool = ThreadPoolExecutor(1) if kind == "thread_pool" else compiled.SecondCore()
    ended = []

    def task(k, signal=None):
        if signal is not None:
            signal[0] = 1
        # The other thread's task ends well after this thread's.
        time.sleep(0.02 if threading.current_thread() is threading.main_thread() else 0.2)
        ended.append(k)

    waits = []
    if kind == "second_core":
        real = pool.join

        def interrupted_once(future):
            if not waits:
                waits.append(1)
                raise KeyboardInterrupt
            return real(future)

        pool.join = interrupted_once
        run = lambda: compiled.on_both_cores(task, 2, pool, signals=True)  # noqa: E731
    else:
        submit = pool.submit

        def submit_interrupted_once(fn):
            future = submit(fn)
            result = future.result

            def once(*a, **k):
                if not waits:
                    waits.append(1)
                    raise KeyboardInterrupt
                return result(*a, **k)

            future.result = once
            return future

        pool.submit = submit_interrupted_once
        run = lambda: compiled.on_both_cores(lambda k: task(k), 2, pool)  # noqa: E731
    with pytest.raises(KeyboardInterrupt):
        run()
    assert waits and sorted(ended) == [0, 1]  # both tasks had ended when the interrupt came out
    pool.shutdown()


def test_the_cut_into_blocks_moves_towards_equal_work_and_holds_against_one_slow_frame():
    work = compiled.Workspace(128 * 4, 128, 4)
    blocks = work.blocks(128, 2)
    assert blocks == ((0, 64), (64, 128))
    # Block 1 three times as slow: after BALANCE_FRAMES frames the cut gives it a third of its
    # beams less (equal shares of the work, taken as even over each block's beams: 64 + 64 / 3).
    for _ in range(compiled.BALANCE_FRAMES - 1):
        work.balance(blocks, [1.0, 3.0])
        assert work.blocks(128, 2) is blocks
    work.balance(blocks, [1.0, 3.0])
    assert work.blocks(128, 2) == ((0, 85), (85, 128))
    # Nearly even, or one frame slow among even ones: the cut holds.
    blocks = work.blocks(128, 2)
    for seconds in ([1.0, 1.05], [1.0, 1.0], [1.0, 9.0], [1.0, 1.0]):
        work.balance(blocks, seconds)
    assert work.blocks(128, 2) is blocks
    # Another number of blocks, or a frame cut otherwise (an older cut): even again, or ignored.
    assert work.blocks(128, 3) == compiled.beam_blocks(128, 3)
    work.balance(((0, 10), (10, 128)), [1.0, 50.0])
    assert work.blocks(128, 3) == compiled.beam_blocks(128, 3)


def test_a_frame_renders_the_same_image_whatever_the_cut_the_balance_chose(monkeypatch):
    """Cuts the balance may choose (uneven, one block of a few beams): the same frame, bit for
    bit, labels and signatures included."""
    monkeypatch.setattr(compiled, "BALANCE_FRAMES", 10**9)  # the cut set here holds
    doc = copy.deepcopy(_variants()["mirrors_order4"])
    with sonarsim.Simulator(doc) as sim:
        frames = []
        for cut in (((0, 64), (64, 128)), ((0, 20), (20, 128)), ((0, 121), (121, 128))):
            sim.render(speckle=False)  # (the workspace exists)
            sim._work.cut = cut
            img = sim.render(speckle=False, labels=True)
            assert sim._work.cut == cut
            frames.append(img)
    first = frames[0]
    for img in frames[1:]:
        np.testing.assert_array_equal(img.polar, first.polar)
        assert img.components.signatures == first.components.signatures
        for key in first.components:
            np.testing.assert_array_equal(img.components[key], first.components[key])
        a, b = img.labels.arrays(), first.labels.arrays()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_path_blocks_refuse_a_room_other_than_the_counted_a_bad_growth_and_generations_out_of_order(monkeypatch):
    """The counting pass's room is held to: a block that would form more paths stops at its
    room and the frame fails (nothing is written past it), and the next frame renders; a chain
    table smaller than the chains held, and a generation stepped out of order, are refused."""
    doc = _variants()["mirrors_order4"]
    monkeypatch.setattr(compiled, "PATH_BUFFER_BYTES", 0)
    with sonarsim.Simulator(doc) as sim:
        good = sim.render(speckle=False).polar
        layout = compiled._counted_layout

        def short(*args):
            offset, size, capacity = layout(*args)
            k = int(np.argmax(capacity))
            capacity = capacity.copy()
            capacity[k] -= 1  # one path less room than counted, in the largest option of a block
            return offset, size, capacity

        monkeypatch.setattr(compiled, "_counted_layout", short)
        with pytest.raises(RuntimeError, match="counting pass counted"):
            sim.render()
        monkeypatch.setattr(compiled, "_counted_layout", layout)
        np.testing.assert_array_equal(sim.render(speckle=False).polar, good)
        engine = sim._work.engine[4]
        with pytest.raises(ValueError, match="chain table of 0 rows"):
            engine.grow(0)
        seen = []
        run = compiled.on_both_cores

        def checking(task, n, pool=None, signals=False):
            if not seen:  # inside the frame, before its blocks are traced
                with pytest.raises(ValueError, match="generation 1 next"):
                    engine.step(0, 0, 4, 1)  # not begun
                seen.append(True)
            run(task, n, pool, signals)

        monkeypatch.setattr(compiled, "on_both_cores", checking)
        sim.render()
        assert seen
