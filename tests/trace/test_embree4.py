"""Our Embree 4 binding (``embree4``) against embreex's caster (the reference), ray by ray and
frame by frame; the ray-hit layout checked against the library itself; the fallbacks."""

from __future__ import annotations

import gc
import struct
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import sonarsim
from sonarsim.config.examples import demo_scene_dict, tank_scene_dict
from sonarsim.errors import SonarsimError
from sonarsim.scene.meshes import TriangleMesh
from sonarsim.trace import make_caster
from sonarsim.trace.embree import EmbreeCaster

pytest.importorskip("sonarsim.trace._embree4")  # not built on Windows
from sonarsim.trace import embree4  # noqa: E402

_binding = embree4.load_binding()  # found, bound and its layout verified: else every test fails
Embree4Caster = embree4.Embree4Caster

INVALID = 0xFFFFFFFF


def assert_same_hits(a, b, with_uv=False):
    """``a`` (embree4) against ``b`` (embreex): same meshes, distances, normals (and triangles)."""
    np.testing.assert_array_equal(a.mesh_id, b.mesh_id)
    hit = b.mesh_id >= 0
    assert np.all(np.isinf(a.distance[~hit])) and np.all(a.normal[~hit] == 0)
    np.testing.assert_allclose(a.distance[hit], b.distance[hit], rtol=1e-5, atol=0)
    np.testing.assert_allclose(a.normal, b.normal, rtol=0, atol=1e-5)
    for h in (a, b):
        assert h.distance.dtype == np.float32 and h.mesh_id.dtype == np.int32 and h.normal.dtype == np.float32
    if with_uv:
        np.testing.assert_array_equal(a.primitive_id, b.primitive_id)
        np.testing.assert_allclose(a.barycentric, b.barycentric, rtol=0, atol=1e-5)
        assert np.all(a.primitive_id[~hit] == -1) and np.all(a.barycentric[~hit] == 0)
    else:
        assert a.primitive_id is None and a.barycentric is None


class Recorder:
    """Wraps a caster and keeps every batch of rays a frame casts."""

    def __init__(self, caster):
        self.caster, self.calls = caster, []

    def intersect(self, origins, directions, max_distance, threads=None, with_uv=False):
        self.calls.append((np.array(origins, np.float32), np.array(directions, np.float32), float(max_distance)))
        return self.caster.intersect(origins, directions, max_distance, threads=threads, with_uv=with_uv)

    def __getattr__(self, name):
        return getattr(self.caster, name)


@pytest.fixture(scope="module")
def demo_frame():
    """The demo scene's meshes and every ray batch of one of its frames (cast through embreex)."""
    with sonarsim.Simulator(demo_scene_dict(), backend="embreex") as sim:
        sim.caster = Recorder(sim.caster)
        sim.render(keep_rays=False)
        calls, meshes = sim.caster.calls, sim.meshes
    assert sum(len(d) for _, d, _ in calls) > 30_000
    return meshes, calls


@pytest.mark.parametrize("threads, coherent", [(1, True), (2, True), (1, False)])
def test_demo_frame_rays_hit_as_with_embreex(demo_frame, threads, coherent):
    meshes, calls = demo_frame
    new, ref = Embree4Caster(meshes, threads, coherent=coherent), EmbreeCaster(meshes, threads)
    n_hits = 0
    for o, d, reach in calls:
        for with_uv in (False, True):
            a = new.intersect(o, d, reach, with_uv=with_uv)
            b = ref.intersect(o, d, reach, with_uv=with_uv)
            assert_same_hits(a, b, with_uv)
        n_hits += int((b.mesh_id >= 0).sum())
    assert n_hits > 1000


def random_scene(rng) -> list[TriangleMesh]:
    """Closed spheres and boxes at random poses, a triangle soup, and empty meshes between them."""
    meshes = [TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32))]
    for k in range(4):
        m = trimesh.creation.icosphere(subdivisions=2, radius=rng.uniform(0.2, 0.6)) if k % 2 == 0 \
            else trimesh.creation.box(extents=rng.uniform(0.2, 0.8, 3))
        m.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        m.apply_translation(rng.uniform(-2, 2, 3))
        meshes.append(TriangleMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int32)))
        if k == 1:
            meshes.append(TriangleMesh(np.zeros((3, 3)), np.zeros((0, 3), np.int32)))  # vertices, no faces
    corners = rng.uniform(-2.5, 2.5, (60, 1, 3)) + rng.normal(0, 0.3, (60, 3, 3))
    meshes.append(TriangleMesh(corners.reshape(-1, 3), np.arange(180, dtype=np.int32).reshape(-1, 3)))
    return meshes


def random_rays(rng, meshes, n):
    """Rays from outside towards the meshes (many hit, many miss) and from inside a sphere."""
    o = rng.uniform(-4, 4, (n, 3))
    inside = rng.random(n) < 0.2  # these start at a sphere's centre: they hit its inside
    centre = meshes[1].vertices.mean(axis=0)
    o[inside] = centre
    d = rng.normal(0, 1, (n, 3))
    aim = rng.random(n) < 0.6
    d[aim] = rng.uniform(-2, 2, (aim.sum(), 3)) - o[aim]
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("coherent", [True, False])
@pytest.mark.parametrize("n", [0, 1, 7, 8, 9, 1003, 2 * 8192 + 13])
def test_random_rays_against_random_meshes(n, coherent):
    # Rays in random order: the coherent traversal is slower on them but must give the same hits.
    rng = np.random.default_rng(n)
    meshes = random_scene(rng)
    o, d = random_rays(rng, meshes, n)
    new, ref = Embree4Caster(meshes, threads=2, coherent=coherent), EmbreeCaster(meshes, threads=2)
    for reach in (20.0, 1.5):  # 1.5 m: the limit cuts many rays that would hit further away
        for with_uv in (False, True):
            a = new.intersect(o, d, reach, with_uv=with_uv)
            b = ref.intersect(o, d, reach, with_uv=with_uv)
            assert len(a.distance) == n
            assert_same_hits(a, b, with_uv)
            assert np.all(a.distance[a.mesh_id >= 0] <= reach)
    if n > 1000:
        far = new.intersect(o, d, 20.0)
        near = new.intersect(o, d, 1.5)
        cut = (far.mesh_id >= 0) & (far.distance > 1.5)
        assert cut.sum() > 50 and np.all(near.mesh_id[cut] == -1)  # the limit did cut
        assert 0.2 < (far.mesh_id >= 0).mean() < 0.9
        assert set(np.unique(far.mesh_id)) == {-1, 1, 2, 4, 5, 6}  # empty meshes 0 and 3 never hit
        # Rays from a sphere's centre hit that sphere (its inside) within its radius (or a
        # triangle of the soup that happens to lie inside it, first).
        centre = meshes[1].vertices.mean(axis=0)
        inside = np.all(o == centre, axis=1)
        radius = np.linalg.norm(meshes[1].vertices - centre, axis=1).max()
        assert inside.sum() > 100 and (far.mesh_id[inside] == 1).mean() > 0.8
        assert np.all(far.distance[inside] <= radius * (1 + 1e-5))


def test_single_rays_one_by_one_equal_the_batch():
    # Each lane of a packet answers for its own ray: a ray alone (1-ray tail packet) or in any
    # position of a batch gets the same hit.
    rng = np.random.default_rng(5)
    meshes = random_scene(rng)
    o, d = random_rays(rng, meshes, 21)
    caster = Embree4Caster(meshes, threads=1)
    batch = caster.intersect(o, d, 20.0, with_uv=True)
    for i in range(21):
        one = caster.intersect(o[i:i + 1], d[i:i + 1], 20.0, with_uv=True)
        assert one.mesh_id[0] == batch.mesh_id[i] and one.distance[0] == batch.distance[i]
        assert one.primitive_id[0] == batch.primitive_id[i]


def test_no_meshes_or_only_empty_ones_give_misses():
    empty = TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
    for meshes in ([], [empty, empty]):
        caster = Embree4Caster(meshes)
        h = caster.intersect(np.zeros((3, 3)), np.tile([1.0, 0, 0], (3, 1)), 5.0, with_uv=True)
        assert np.all(h.mesh_id == -1) and np.all(np.isinf(h.distance)) and np.all(h.primitive_id == -1)
        caster.release()


# ----- the ray-hit structure as the library writes it ---------------------------------------

def _packet_rays():
    """8 rays that all hit the unit square z = 0 from above."""
    xy = np.linspace(-0.4, 0.4, 8)
    o = np.column_stack([xy, xy[::-1], np.ones(8)]).astype(np.float32)
    d = np.tile(np.array([0, 0, -1], np.float32), (8, 1))
    return o, d, np.full(8, 10.0, np.float32)


@pytest.fixture(scope="module")
def square():
    mesh = TriangleMesh(np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float),
                        np.array([[0, 1, 2], [0, 2, 3]], np.int32))
    caster = Embree4Caster([mesh], threads=1)
    yield caster
    caster.release()


def _u32(raw: bytes, offset: int, count: int = 8) -> np.ndarray:
    return np.frombuffer(raw, dtype=np.uint32, count=count, offset=offset)


def _f32(raw: bytes, offset: int, count: int = 8) -> np.ndarray:
    return np.frombuffer(raw, dtype=np.float32, count=count, offset=offset)


CANARY = 0xA5A5A5A5
# Embree 4's RTCRayHit8 with instance arrays and one instance level (rtcore_ray.h): 12 ray
# fields then Ng_x Ng_y Ng_z u v primID geomID instID[1] instPrimID[1], each 8 x 4 bytes.
RAY8 = 12 * 32
TFAR8, NG8, U8, V8, PRIM8, GEOM8, INST8, INSTPRIM8 = 8 * 32, RAY8, RAY8 + 3 * 32, RAY8 + 4 * 32, RAY8 + 5 * 32, \
    RAY8 + 6 * 32, RAY8 + 7 * 32, RAY8 + 8 * 32
SIZE8 = RAY8 + 9 * 32


def test_packet_structure_matches_the_library(square):
    # Everything past the ray is canary before the cast; Embree must write the hit fields where
    # we declare them, instID and instPrimID included (the instance-array build), and nothing
    # past the structure. A hit declared without instPrimID (or with two instance levels) fails.
    assert _binding.RAYHIT8_SIZE == SIZE8 == 672
    o, d, tfar = _packet_rays()
    raw = square._scene.probe_packet(o, d, tfar, 8)
    assert len(raw) == SIZE8 + 64
    assert raw[SIZE8:] == b"\xa5" * 64, "Embree wrote past the declared RTCRayHit8"
    np.testing.assert_array_equal(_u32(raw, GEOM8), 0)
    assert np.all(_u32(raw, PRIM8) <= 1)
    np.testing.assert_array_equal(_u32(raw, INST8), INVALID)  # written by Embree: no instance
    np.testing.assert_array_equal(_u32(raw, INSTPRIM8), INVALID)
    np.testing.assert_allclose(_f32(raw, TFAR8), 1.0)
    ng = np.stack([_f32(raw, NG8 + 32 * k) for k in range(3)], axis=1)
    np.testing.assert_allclose(ng / np.linalg.norm(ng, axis=1, keepdims=True), np.tile([0, 0, 1], (8, 1)), atol=1e-6)
    u, v = _f32(raw, U8), _f32(raw, V8)
    assert np.all((u >= 0) & (v >= 0) & (u + v <= 1))


@pytest.mark.parametrize("m", [1, 3, 7])
def test_tail_packet_casts_only_its_active_lanes(square, m):
    # All 8 lanes hold rays that hit, but a tail packet of m rays marks only lanes 0..m valid:
    # Embree must leave the other lanes' hits (canary) alone.
    o, d, tfar = _packet_rays()
    raw = square._scene.probe_packet(o, d, tfar, m)
    geom = _u32(raw, GEOM8)
    np.testing.assert_array_equal(geom[:m], 0)
    np.testing.assert_array_equal(geom[m:], CANARY)
    np.testing.assert_array_equal(_u32(raw, INSTPRIM8)[m:], CANARY)
    np.testing.assert_allclose(_f32(raw, TFAR8)[:m], 1.0)
    np.testing.assert_array_equal(_f32(raw, TFAR8)[m:], 10.0)  # the inactive rays were not cut
    assert raw[SIZE8:] == b"\xa5" * 64


def test_declared_layout_is_embree4s_and_the_guard_rejects_another(monkeypatch):
    assert _binding.RAYHIT8_OFFSETS == {"tfar": TFAR8, "Ng_x": NG8, "u": U8, "v": V8, "primID": PRIM8,
                                        "geomID": GEOM8, "instID": INST8, "instPrimID": INSTPRIM8}
    embree4.verify_layout(_binding)
    shifted = dict(_binding.RAYHIT8_OFFSETS, instID=INSTPRIM8, instPrimID=INST8)
    monkeypatch.setattr(_binding, "RAYHIT8_OFFSETS", shifted)
    with pytest.raises(SonarsimError, match="not Embree 4's"):
        embree4.verify_layout(_binding)


def test_single_ray_structure_matches_the_library(square):
    # RTCRayHit for rtcIntersect1: ray 48 bytes, hit Ng u v primID geomID instID instPrimID
    # (36 bytes, padded to 48).
    assert _binding.RAYHIT1_SIZE == 96
    raw = square._scene.probe_single(0.2, -0.3, 2.0, 0.0, 0.0, -1.0, 10.0)
    tfar, = struct.unpack_from("<f", raw, 32)
    assert tfar == pytest.approx(2.0)
    prim, geom, inst, inst_prim = struct.unpack_from("<4I", raw, 48 + 20)
    assert geom == 0 and prim in (0, 1) and inst == INVALID and inst_prim == INVALID
    assert raw[96:] == b"\xa5" * 64


# ----- whole frames ---------------------------------------------------------------------------

@pytest.mark.parametrize("scene", [demo_scene_dict, tank_scene_dict], ids=["demo", "tank"])
def test_frames_equal_those_rendered_through_embreex(scene):
    with sonarsim.Simulator(scene(), backend="embree4") as sim:
        assert isinstance(sim.caster, Embree4Caster) or isinstance(sim.caster.caster, Embree4Caster)
        a = sim.render()
    with sonarsim.Simulator(scene(), backend="embreex") as sim:
        b = sim.render()
    assert b.polar.any()
    np.testing.assert_array_equal(a.rays.surface_id, b.rays.surface_id)
    np.testing.assert_allclose(a.rays.distance_m, b.rays.distance_m, rtol=1e-6)
    np.testing.assert_allclose(a.polar, b.polar, rtol=1e-5, atol=1e-6 * np.abs(b.polar).max())


# ----- choosing and loading -------------------------------------------------------------------

def _caster_class(caster):
    return type(getattr(caster, "caster", caster))


def test_backend_embree_uses_the_binding_unless_told_otherwise(monkeypatch, square):
    meshes = [TriangleMesh(np.eye(3), np.array([[0, 1, 2]], np.int32))]
    monkeypatch.delenv("SONARSIM_EMBREE", raising=False)
    assert _caster_class(make_caster("embree", meshes)) is Embree4Caster
    monkeypatch.setenv("SONARSIM_EMBREE", "embreex")
    assert _caster_class(make_caster("embree", meshes)) is EmbreeCaster
    monkeypatch.setenv("SONARSIM_EMBREE", "embree5")
    with pytest.raises(SonarsimError, match="SONARSIM_EMBREE"):
        make_caster("embree", meshes)


def test_a_missing_library_is_reported_and_embree_falls_back(monkeypatch):
    monkeypatch.delenv("SONARSIM_EMBREE", raising=False)
    monkeypatch.setattr(_binding, "loaded_path", lambda: None)  # as in a fresh process
    monkeypatch.setattr(embree4, "find_library", lambda: None)
    with pytest.raises(SonarsimError, match=r"no Embree 4 library.*embreex\.libs/libembree4-\*\.so\*"):
        embree4.load_binding()
    meshes = [TriangleMesh(np.eye(3), np.array([[0, 1, 2]], np.int32))]
    assert _caster_class(make_caster("embree", meshes)) is EmbreeCaster  # the fallback
    with pytest.raises(SonarsimError, match="no Embree 4 library"):
        make_caster("embree4", meshes)
    monkeypatch.setenv("SONARSIM_EMBREE", "embree4")
    with pytest.raises(SonarsimError, match="no Embree 4 library"):
        make_caster("embree", meshes)


def test_the_library_is_found_beside_embreex():
    path = embree4.find_library()
    assert path is not None and "embreex.libs" in path and "libembree4" in path
    assert _binding.loaded_path() == path


@pytest.mark.parametrize("target, message", [
    ("/nonexistent/libembree4.so.4", "cannot open the Embree 4 library /nonexistent/libembree4.so.4"),
    ("libm.so.6", "lacks rtcNewDevice, rtcReleaseDevice"),
])
def test_bad_libraries_give_clear_errors(target, message):
    # A fresh interpreter: in this one the library is bound already.
    code = ("from sonarsim.errors import SonarsimError\nfrom sonarsim.trace import _embree4\n"
            f"try:\n    _embree4.load({target!r})\nexcept SonarsimError as e:\n    print(e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert message in out.stdout, out.stdout + out.stderr


def test_close_stops_the_threads_and_release_frees_embree():
    rng = np.random.default_rng(3)
    meshes = random_scene(rng)
    caster = Embree4Caster(meshes, threads=2)
    o, d = random_rays(rng, meshes, 20_000)
    before = caster.intersect(o, d, 20.0)
    assert (before.mesh_id >= 0).any()
    caster.close()  # as a closed simulator's: it still casts, on the calling thread
    np.testing.assert_array_equal(caster.intersect(o, d, 20.0).distance, before.distance)
    caster.release()
    caster.release()  # idempotent
    with pytest.raises(SonarsimError, match="released"):
        caster.intersect(o, d, 20.0)
    # Many casters built and dropped: Embree's devices and scenes are released by the GC.
    for _ in range(20):
        Embree4Caster(meshes, threads=1).intersect(o[:100], d[:100], 20.0)
    gc.collect()



IDLE_CPU = """
import sys, time
import sonarsim
from sonarsim.config.examples import demo_scene_dict
doc = demo_scene_dict()
doc["render"]["threads"] = int(sys.argv[1])
sim = sonarsim.Simulator(doc)
for _ in range(3):
    sim.render(keep_rays=False)
time.sleep(0.2)  # TBB's workers may spin briefly after the build; then they must sleep
c = time.process_time()
time.sleep(1.0)
print(time.process_time() - c)
"""


@pytest.mark.parametrize("threads", [1, 2])
def test_an_idle_simulator_burns_no_cpu(threads):
    """An Embree device configured with ``threads=1`` kept a TBB worker spinning for as long as
    it lived: a whole core burnt while the simulator sat idle, and the second core taken from a
    second single-threaded worker. Idle, the process must use (almost) no CPU."""
    out = subprocess.run([sys.executable, "-c", IDLE_CPU, str(threads)], capture_output=True, text=True,
                         timeout=120, check=True)
    assert float(out.stdout.strip().splitlines()[-1]) < 0.2
    assert embree4.device_config(1) == "" and embree4.device_config(2) == "threads=2"
