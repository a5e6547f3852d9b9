"""The compiled per-ray kernels against their NumPy twins (the reference implementation)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.trace import _hits
from sonarsim.trace.embree import embree_hits
from sonarsim.renderer import compiled
from sonarsim.config.examples import demo_scene_dict

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")


def _variants():
    base = demo_scene_dict()
    out = {"demo": base}
    rolled = copy.deepcopy(base)
    rolled["sonar"]["pose"] = {"position_m": [0.3, 0.2, 1.3], "rpy_deg": [-10.0, 28.0, 8.0]}
    out["rolled"] = rolled
    for key, value in (("range_splat", False), ("tvg", False), ("double_beam", "split"),
                       ("double_line_of_sight", True), ("azimuth_samples", 3), ("beam_pattern", "gaussian")):
        d = copy.deepcopy(rolled)
        d["render"][key] = value
        out[f"{key}={value}"] = d
    no_ground = copy.deepcopy(base)
    del no_ground["ground"]
    out["no_ground"] = no_ground
    oculus = copy.deepcopy(base)
    oculus["sonar"] = {"preset": "oculus-m1200d-lf", "range_max_m": 6.0,
                       "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}}
    out["oculus_sine_spaced"] = oculus
    # Mesh mirrors (issue 25): the demo's block and pipe mirror, at order 3 and 4, each
    # reciprocal pair once and both members, and with the transmit legs cast against objects.
    # With the pipe smooth, a path whose transmit leg would cross it is formed from its partner.
    for name, order, mode, los in (("mirrors", 3, "paper", False), ("mirrors_order4_separate", 4, "separate", False),
                                   ("mirrors_split_los", 3, "split", True), ("mirrors_smooth", 3, "paper", False),
                                   ("mirrors_smooth_separate", 3, "separate", False)):
        d = copy.deepcopy(rolled)
        for obj in d["objects"]:
            if obj["name"] in ("concrete_block", "pipe"):
                obj["specular"] = 0.5
            if obj["name"] == "pipe" and "smooth" in name:
                obj["normals"] = "smooth"
        d["render"].update(max_order=order, double_beam=mode, double_line_of_sight=los)
        d["render"].pop("bounces", None)
        out[name] = d
    return out


@pytest.mark.parametrize("name", list(_variants()))
def test_compiled_kernels_equal_the_numpy_reference(name):
    # Same arithmetic in the same precisions, summed in another order: 1e-9 of the energy; a
    # continuity decision exactly at its threshold could differ by float32 rounding, hence the
    # per-component L1 bound rather than exact equality.
    doc = _variants()[name]
    sa, sb = sonarsim.Simulator(doc, kernels="compiled"), sonarsim.Simulator(doc, kernels="numpy")
    assert (sa.path_kernels, sb.path_kernels) == ("compiled", "numpy")
    a, b = sa.render(), sb.render()
    if name.startswith("mirrors"):  # paths via the mirrors were formed, on both legs
        names = [n.split("[") for n in b.components.signatures]
        assert any("pipe" in tx for tx, _ in names) and any("concrete_block" in rx for _, rx in names)
        assert set(a.components.signatures) == set(b.components.signatures)
    for key in b.components:
        x, y = a.components[key].astype(float), b.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-6 * np.abs(y).sum() + 1e-12, key
    np.testing.assert_array_equal(a.rays.surface_id, b.rays.surface_id)
    np.testing.assert_allclose(a.rays.distance_m, b.rays.distance_m, rtol=1e-6)
    np.testing.assert_allclose(a.rays.intensity, b.rays.intensity, rtol=1e-5, atol=1e-12)


def test_compiled_path_renders_many_poses_from_one_workspace():
    sim = sonarsim.Simulator(demo_scene_dict())
    ref = sonarsim.Simulator(demo_scene_dict(), kernels="numpy")
    for z in (0.8, 1.0, 1.3):
        pose = {"position_m": [0.0, 0.1, z], "rpy_deg": [3.0, 22.0, -2.0]}
        a, b = sim.render(pose=pose), ref.render(pose=pose)
        assert np.abs(a.polar - b.polar).sum() <= 1e-6 * np.abs(b.polar).sum()
    # Results do not alias the reused buffers.
    first = sim.render(pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]})
    kept = first.polar.copy()
    sim.render(pose={"position_m": [0, 0, 1.2], "rpy_deg": [0, 25, 0]})
    np.testing.assert_array_equal(first.polar, kept)


def test_unknown_kernels_name_is_rejected():
    with pytest.raises(sonarsim.ConfigError, match="kernels"):
        sonarsim.Simulator(demo_scene_dict(), kernels="gpu")


def test_a_closed_simulator_still_renders_on_one_thread():
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        before = sim.render().polar
    after = sim.render().polar  # the compiled path without its second core, Embree inline
    np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-9)


# Kernel by kernel, on random inputs ---------------------------------------------------------
#
# Each compiled kernel of the general path against its NumPy twin in sonarsim.paths.engine,
# with the same inputs. The twins do the same arithmetic in the same order and precision, so
# outputs are compared exactly, except the splat (float32 sums in the kernel, float64 in
# formation.accumulate).

from sonarsim.paths import engine  # noqa: E402
from sonarsim.paths.planes import ChainTable, PlaneSet, apply  # noqa: E402
from sonarsim.renderer import _kernels as K  # noqa: E402  (skipped above when not built)
from sonarsim.trace.base import Hits  # noqa: E402
from sonarsim.core.radiometry import SurfaceLaws  # noqa: E402


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return np.ascontiguousarray(q if np.linalg.det(q) > 0 else -q)


def _planes(rng, origin, n_planes=4):
    """Random planes with ``origin`` 0.3-2 m inside the water of each; one axis-aligned (the
    floor z = origin_z - 1, for rays parallel to it), one with zero specular, one with zero albedo."""
    normal = _unit(rng, n_planes)
    normal[0] = (0.0, 0.0, 1.0)
    depth = rng.uniform(0.3, 2.0, n_planes)
    depth[0] = 1.0
    offset = normal @ origin - depth
    albedo = rng.uniform(0.1, 1.0, n_planes)
    specular = rng.uniform(0.2, 1.0, n_planes)
    specular[1] = 0.0
    albedo[2] = 0.0
    names = tuple(f"p{k}" for k in range(n_planes))
    return PlaneSet(names, normal, offset, albedo, specular)


def _table(planes, origin, rng, n_chains=6, capacity=64):
    table = ChainTable(planes, origin, 8, capacity=capacity)
    mirrors = np.flatnonzero(planes.specular > 0)
    while len(table) < n_chains:
        table.child(int(rng.integers(len(table))), int(rng.choice(mirrors)))
    return table


def _trace_both(rng, *, first, reflect, tvg, n=600, m=None, capacity=64, at_reach=True, laws=False):
    """Run ``trace_leg`` and ``engine.trace_generation`` on the same random generation.

    ``laws``: random backscatter laws per surface and a random texture brightness per hit."""
    origin = rng.normal(size=3)
    planes = _planes(rng, origin)
    n_planes, n_objects = len(planes), 3
    active = np.ones(n_planes, bool)
    active[3] = False
    table = _table(planes, origin, rng, capacity=capacity)
    reach = 6.0
    if first:
        ray = np.arange(n, dtype=np.intp)
        org, before = origin.reshape(1, 3), np.zeros(1)
        atten, chain = np.ones(1), np.zeros(1, np.int32)
    else:
        m = m if m is not None else n // 2
        ray = np.sort(rng.choice(n, m, replace=False)).astype(np.intp)
        org = origin + rng.uniform(-0.3, 0.3, (m, 3))
        before = rng.uniform(0.0, 2.0, m)
        atten = rng.uniform(0.1, 1.0, m)
        chain = rng.integers(0, len(table), m).astype(np.int32)
    k = len(ray)
    dirs = _unit(rng, k)
    dirs[::17, 2] = 0.0  # parallel to the floor (plane 0, normal +z): dn is exactly 0
    dirs[::17] /= np.linalg.norm(dirs[::17], axis=1, keepdims=True)
    hit_mesh = rng.integers(-1, n_objects, k).astype(np.int32)
    hit_dist = rng.uniform(0.05, 1.3 * reach, k).astype(np.float32)
    hit_normal = _unit(rng, k).astype(np.float32)
    hit_normal[hit_mesh < 0] = 0.0
    hit_dist[hit_mesh < 0] = np.inf
    # The caster's triangle and barycentrics: the search records them where an object scatters.
    hit_prim = np.where(hit_mesh >= 0, rng.integers(0, 500, k), -1).astype(np.int32)
    hit_uv = np.where(hit_mesh[:, None] >= 0, rng.uniform(0.0, 0.5, (k, 2)), 0.0).astype(np.float32)
    if at_reach and k > 10:
        # Hits exactly at the reach: kept (total <= reach) but not reflected (total < reach).
        rows = slice(5, None, 20)
        hit_mesh[rows] = 1
        hit_dist[rows] = np.float32(reach) if first else np.float32(1.5)
        if not first:
            before[rows] = reach - 1.5  # 1.5 is exact in float32: before + t == reach exactly
    albedo_by_id = np.concatenate([[0.0], planes.albedo, rng.uniform(0.0, 1.0, n_objects)])
    albedo_by_id[-1] = 0.0  # an object with zero albedo: reached, reflects nothing, scatters nothing
    weight = rng.uniform(0.0, 1e-3, n)
    n_surfaces = n_planes + n_objects
    law_args, table_laws, texel = (), albedo_by_id, None
    if laws:
        codes = np.concatenate([[0], rng.integers(0, 3, n_surfaces)]).astype(np.int32)
        codes[[1, n_planes + 1]] = (1, 2)  # the floor follows Lambert's law, the first object is rough
        lobe = np.column_stack([rng.uniform(0.0, 3.0, n_surfaces + 1), rng.uniform(0.01, 0.5, n_surfaces + 1)])
        lobe[codes != 2] = 0.0
        texel = rng.uniform(0.0, 1.0, k).astype(np.float32)
        law_args = (codes, lobe, texel)
        table_laws = SurfaceLaws(albedo_by_id, codes, lobe)

    # The kernel, as compiled.py calls it (grow the chain table and redo on overflow).
    kt = copy.deepcopy(table)
    dense = lambda: (np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan),
                     np.full((n, 3), np.nan, np.float32), np.full(n, np.nan), np.full(n, np.nan),
                     np.full(n, -7, np.int32))
    kd = dense()
    kprim, kuv = np.full(n, -1, np.int32), np.zeros((n, 2), np.float32)
    key = np.full(n, -1, np.int32)
    live = np.full(k, -9, np.intp)
    nx = (np.empty(k, np.intp), np.empty((k, 3)), np.empty((k, 3), np.float32), np.empty((k, 3)),
          np.empty((k, 3), np.float32), np.empty(k), np.empty(k), np.empty(k, np.int32))
    overflows = 0
    while True:
        n_next, n_chains, min_next, overflow, n_live = K.trace_leg(
            ray, hit_dist, hit_mesh, hit_normal, org, dirs, before, atten, chain, planes.normal, planes.offset,
            active.astype(np.uint8), planes.specular, reach, albedo_by_id, weight, tvg, first, reflect,
            kt.children, len(kt), kd[0], kd[1], kd[2], kd[3], kd[4], kd[5], kd[6], key,
            live, n_surfaces, *nx, *law_args, hit_prim=hit_prim, hit_uv=hit_uv, prim=kprim, uv=kuv)
        kt.sync(n_chains)
        if not overflow:
            break
        overflows += 1
        kt._grow()

    tt = copy.deepcopy(table)
    td = dense()
    leg = engine.Leg(1, *td, prim=np.full(n, -1, np.int32), uv=np.zeros((n, 2), np.float32))
    rays = engine.Rays(ray, org, dirs, before, atten, chain)
    nxt, tlive = engine.trace_generation(rays, Hits(hit_dist, hit_mesh, hit_normal, texel, hit_prim, hit_uv), planes,
                                         active, reach, table_laws, weight, tvg, first, reflect, tt, leg)
    kernel = dict(zip(("distance", "sid", "point", "normal", "intensity", "atten", "chain"), kd))
    kernel.update(prim=kprim, uv=kuv, key=key, live=live[:n_live], ray=nx[0][:n_next], origin=nx[1][:n_next],
                  origin32=nx[2][:n_next], direction=nx[3][:n_next], direction32=nx[4][:n_next],
                  before=nx[5][:n_next], next_atten=nx[6][:n_next], next_chain=nx[7][:n_next],
                  min_next=min_next, n_chains=len(kt), chains=kt.chains)
    twin = dict(zip(("distance", "sid", "point", "normal", "intensity", "atten", "chain"), td))
    twin.update(prim=leg.prim, uv=leg.uv, key=leg.key(n_surfaces) if not first else key, live=tlive, ray=nxt.ray,
                origin=nxt.origin,
                origin32=nxt.origin32, direction=nxt.direction, direction32=nxt.direction32, before=nxt.before,
                next_atten=nxt.atten, next_chain=nxt.chain, min_next=nxt.before.min() if len(nxt) else np.inf,
                n_chains=len(tt), chains=tt.chains)
    return kernel, twin, overflows


def _assert_same(kernel, twin):
    assert kernel.keys() == twin.keys()
    for name in kernel:
        a, b = kernel[name], twin[name]
        if isinstance(a, list):
            assert a == b, name
            continue
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape, (name, a.shape, b.shape)
        np.testing.assert_array_equal(a, b, err_msg=name)  # bit for bit (NaN equals NaN)


@pytest.mark.parametrize("first", [True, False])
@pytest.mark.parametrize("tvg", [True, False])
@pytest.mark.parametrize("reflect", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_trace_leg_equals_trace_generation(first, tvg, reflect, seed):
    kernel, twin, _ = _trace_both(np.random.default_rng(seed), first=first, reflect=reflect, tvg=tvg)
    _assert_same(kernel, twin)
    # The random generation reaches planes, objects and nothing, and reflects.
    sid = kernel["sid"]
    assert (sid == -1).any() and ((sid >= 0) & (sid < 4)).any() and (sid >= 4).any()
    assert (len(kernel["ray"]) > 0) == reflect
    assert len(kernel["live"]) < np.count_nonzero(sid >= 0)  # zero albedo: reached, not live


@pytest.mark.parametrize("first", [True, False])
@pytest.mark.parametrize("tvg", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_trace_leg_equals_trace_generation_under_every_law(first, tvg, seed):
    kernel, twin, _ = _trace_both(np.random.default_rng(10 + seed), first=first, reflect=True, tvg=tvg, laws=True)
    ki, ti = kernel.pop("intensity"), twin.pop("intensity")
    _assert_same(kernel, twin)
    # The same operations in the same order; libm's exp and NumPy's may differ in the last bit.
    np.testing.assert_allclose(ki, ti, rtol=1e-14, atol=0)
    plain, _, _ = _trace_both(np.random.default_rng(10 + seed), first=first, reflect=True, tvg=tvg)
    reached = np.isfinite(ki) & (kernel["sid"] >= 0)
    assert np.any(ki[reached] != plain["intensity"][reached])  # the laws did something


def test_trace_leg_edge_rows():
    # Hits exactly at the reach (rows 5, 25, ... unless a plane comes first) are kept and not
    # reflected.
    for first in (True, False):
        kernel, twin, _ = _trace_both(np.random.default_rng(3), first=first, reflect=True, tvg=False)
        _assert_same(kernel, twin)
        at = np.flatnonzero(kernel["distance"] == 6.0)
        assert len(at) and not np.isin(at, kernel["ray"]).any()


@pytest.mark.parametrize("first", [True, False])
def test_trace_leg_on_no_rays(first):
    kernel, twin, _ = _trace_both(np.random.default_rng(5), first=first, reflect=True, tvg=True, n=40, m=0,
                                  at_reach=False)
    if not first:
        _assert_same(kernel, twin)
        assert not len(kernel["live"]) and not len(kernel["ray"])


def test_trace_leg_chain_overflow_numbers_chains_like_the_twin():
    # A chain table too small: the kernel reports overflow, is rerun on a grown table (as
    # compiled.py does), and must end with the twin's numbering.
    kernel, twin, overflows = _trace_both(np.random.default_rng(6), first=False, reflect=True, tvg=True,
                                          capacity=6)
    assert overflows >= 1
    _assert_same(kernel, twin)


def test_trace_leg_without_planes():
    rng = np.random.default_rng(7)
    n = 50
    planes = PlaneSet((), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
    table = ChainTable(planes, np.zeros(3), 2)
    dirs = _unit(rng, n)
    hit_mesh = rng.integers(-1, 2, n).astype(np.int32)
    hit_dist = np.where(hit_mesh >= 0, rng.uniform(0, 5, n), np.inf).astype(np.float32)
    hit_normal = _unit(rng, n).astype(np.float32)
    albedo, weight = np.array([0.0, 0.5, 0.7]), rng.uniform(0, 1, n)
    out = [np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan),
           np.full((n, 3), np.nan, np.float32), np.full(n, np.nan)]
    ref = copy.deepcopy(out)
    live = np.empty(n, np.intp)
    nx = (np.empty(n, np.intp), np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3)),
          np.empty((n, 3), np.float32), np.empty(n), np.empty(n), np.empty(n, np.int32))
    r = K.trace_leg(np.arange(n, dtype=np.intp), hit_dist, hit_mesh, hit_normal, np.zeros((1, 3)), dirs, np.zeros(1),
                    np.ones(1), np.zeros(1, np.int32), planes.normal, planes.offset, np.zeros(0, np.uint8),
                    planes.specular, 4.0, albedo, weight, True, True, True, table.children, 1, out[0], out[1], out[2],
                    out[3], out[4], np.empty(n), np.empty(n, np.int32),
                    np.empty(n, np.int32), live, 2, *nx)
    leg = engine.Leg(0, *ref, np.ones(n), np.zeros(n, np.int32))
    nxt, tlive = engine.trace_generation(engine.Rays.from_sonar(np.zeros(3), dirs),
                                         Hits(hit_dist, hit_mesh, hit_normal), planes, np.zeros(0, bool), 4.0,
                                         albedo, weight, True, True, True, table, leg)
    assert r[0] == len(nxt) == 0
    for a, b in zip(out, ref):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(live[:r[4]], tlive)


@pytest.mark.parametrize("n", [0, 1, 257])
def test_rotate_equals_its_twin(n):
    rng = np.random.default_rng(n)
    dirs, rot, origin = _unit(rng, n), _rotation(rng), rng.normal(size=3) * 10
    out = np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    K.rotate(dirs, rot, *origin, *out)
    for a, b in zip(out, engine.rotate(dirs, rot, origin)):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n", [0, 1, 300])
def test_embree_hits_equals_its_twin(n):
    rng = np.random.default_rng(10 + n)
    ids = rng.permutation(7).astype(np.int32)[:5]  # empty meshes skipped: geometry g is mesh ids[g]
    geom = rng.integers(-1, 5, n).astype(np.int32)
    tfar = rng.uniform(0, 50, n).astype(np.float32)
    ng = (rng.normal(size=(n, 3)) * rng.uniform(1e-3, 1e3, (n, 1))).astype(np.float32)
    out = np.empty(n, np.float32), np.empty(n, np.int32), np.empty((n, 3), np.float32)
    _hits.embree_hits(tfar, geom, ng, ids, *out)
    twin = embree_hits(tfar, geom, ng, ids)
    for a, b in zip(out, (twin.distance, twin.mesh_id, twin.normal)):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    if n:
        assert np.isinf(out[0][geom < 0]).all() and (out[1][geom < 0] == -1).all()


def _paths_setup(rng, n=2000, per_beam=20):
    """A random leg in front of a sonar with random planes, its chain table and view."""
    origin = rng.normal(size=3)
    planes = _planes(rng, origin, 5)
    active = np.ones(len(planes), bool)
    active[4] = False
    table = _table(planes, origin, rng, n_chains=8)
    rot = _rotation(rng)
    n_beams = n // per_beam
    edges = np.linspace(60.0, -60.0, n_beams + 1) + rng.uniform(-0.2, 0.2, n_beams + 1)
    view = engine.SonarView(origin, rot, edges, 25.0, 0.5, 6.0)
    # Scatterers inside the fan and range window, as seen from the sonar.
    az, el, r = np.radians(rng.uniform(-60, 60, n)), np.radians(rng.uniform(-25, 25, n)), rng.uniform(0.5, 6, n)
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1) * r[:, None]
    n_objects = 2
    leg = engine.Leg(1, rng.uniform(0.5, 8.0, n), rng.integers(0, len(planes) + n_objects, n).astype(np.int32),
                     origin + local @ rot.T, _unit(rng, n), rng.uniform(0, 1e-3, n), rng.uniform(0.1, 1, n),
                     rng.integers(0, len(table), n).astype(np.int32))
    leg.distance[::13] = np.inf
    leg.intensity[::11] = 0.0
    live = np.flatnonzero(np.isfinite(leg.distance) & (leg.intensity != 0))
    return planes, active, table, view, leg, live, per_beam


def _path_events(live, leg, same, tx, table, rank, separate, label, n_planes, per_beam, view, planes, active):
    m = len(live)
    buf = (np.full(m, -5, np.intp), np.full(m, np.nan), np.full(m, np.nan), np.full(m, -5, np.int32),
           np.full(m, -5, np.int32), np.full(m, -5, np.int8))
    chain = np.asarray(table.chains[tx], np.int32) if not same else np.empty(0, np.int32)
    k = K.path_events(live, leg.distance, leg.sid, leg.point, leg.intensity, leg.atten, leg.chain, same, tx,
                      table.unfold(tx), table.sources(tx), chain, 1.0 if same else table.specular(tx), rank, separate,
                      label, n_planes, per_beam, *view.origin, view.rotation, view.beam_edges_deg,
                      view.half_elevation_deg, view.range_min_m, view.range_max_m, planes.normal, planes.offset,
                      active.astype(np.uint8), *buf)
    twin = engine.option_paths(live, leg, same, tx, table.unfold(tx), table.sources(tx), chain,
                               1.0 if same else table.specular(tx), rank, separate, label, n_planes, per_beam, view,
                               planes, active)
    return tuple(b[:k] for b in buf), twin


@pytest.mark.parametrize("seed", [0, 1, 3])
@pytest.mark.parametrize("separate", [False, True])
def test_path_events_equal_option_paths(seed, separate):
    rng = np.random.default_rng(20 + seed)
    planes, active, table, view, leg, live, per_beam = _paths_setup(rng)
    rank = engine.chain_ranks(table)
    found = 0
    for tx in [engine.SAME, *range(1, len(table))]:
        same = tx == engine.SAME
        for label in ((1, 3) if same else (table.length(tx) + 2,)):
            kernel, twin = _path_events(live, leg, same, 0 if same else tx, table, rank, separate, label, len(planes),
                                        per_beam, view, planes, active)
            for name, a, b in zip(("ray", "distance", "energy", "beam", "beam_tx", "label"), kernel, twin):
                assert a.dtype == b.dtype, name
                np.testing.assert_array_equal(a, b, err_msg=f"{name} (tx {tx}, label {label})")
            found += 0 if same else len(kernel[0])
    assert found > 20  # transmit legs via the planes were formed, not only refused


def test_path_events_edges_of_the_range_window():
    # Paths exactly at range_min are kept, exactly at range_max refused: set the window to the
    # lengths of two transmit legs, as the twin computes them (same arithmetic as the kernel).
    rng = np.random.default_rng(30)
    planes, active, table, view, leg, live, per_beam = _paths_setup(rng)
    rank = engine.chain_ranks(table)
    options = [engine.option_paths(live, leg, False, tx, table.unfold(tx), table.sources(tx),
                                   np.asarray(table.chains[tx], np.int32), 1.0, rank, True, 2, len(planes), per_beam,
                                   view, planes, active) for tx in range(1, len(table))]
    tx = 1 + int(np.argmax([len(o[0]) for o in options]))
    out = options[tx - 1]
    # |A* - O| as the kernel sums it (the twin's distance is 0.5 * (receive + transmit)).
    a = leg.point[out[0]]
    u = apply(table.unfold(tx), a) - view.origin
    length = np.sqrt(((u @ view.rotation) ** 2).sum(axis=1))  # only to pick two legs: need not be exact
    lo, hi = np.sort(length)[[2, -3]]
    tight = engine.SonarView(view.origin, view.rotation, view.beam_edges_deg, view.half_elevation_deg, lo, hi)
    kernel, twin = _path_events(live, leg, False, tx, table, rank, True, 2, len(planes), per_beam, tight,
                                planes, active)
    for x, y in zip(kernel, twin):
        np.testing.assert_array_equal(x, y)
    assert 0 < len(kernel[0]) < len(out[0])


def test_path_events_on_no_live_rays():
    rng = np.random.default_rng(31)
    planes, active, table, view, leg, _, per_beam = _paths_setup(rng)
    rank = engine.chain_ranks(table)
    for same, tx in ((True, 0), (False, 2)):
        kernel, twin = _path_events(np.empty(0, np.intp), leg, same, tx, table, rank, False, 1, len(planes), per_beam,
                                    view, planes, active)
        assert all(len(a) == 0 for a in kernel) and all(len(b) == 0 for b in twin)


def _splat_both(rng, *, spread, n_cols=40, n_el=16, nb=60, n_beams=8, n_labels=3, scale=0.7, fraction=0.7,
                energy=None):
    n = n_cols * n_el
    # Scatterers on smooth surfaces along each column (continuous) with jumps; one key per
    # run of rays, and the same key on both sides of every column boundary.
    step = rng.uniform(0.01, 0.05, n)
    points = np.cumsum(step)[:, None] * np.array([1.0, 0.2, 0.1]) + rng.normal(0, 1e-4, (n, 3))
    normals = np.tile([0.0, 0.0, 1.0], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    normals = (normals / np.linalg.norm(normals, axis=1, keepdims=True)).astype(np.float32)  # as the legs hold them
    key = (np.arange(n) // 6 % 3).astype(np.int32)
    key[rng.random(n) < 0.05] = -1
    ray = np.flatnonzero(rng.random(n) < fraction).astype(np.intp)
    m = len(ray)
    distance = rng.uniform(-0.2, 3.3, m)  # range window 0.1 + 60 * 0.05 = 3.1 m: some outside
    e = rng.uniform(0.1, 1.0, m) if energy is None else energy(m)
    beam = rng.integers(0, n_beams, m).astype(np.int32)
    label = rng.integers(0, n_labels, m).astype(np.int8)
    geometry = (0.1, 0.05, nb, n_beams)
    out = np.zeros(n_labels * nb * n_beams, np.float32)
    K.splat_events(points, normals, key, ray, distance, e, beam, label, scale, spread, n_el, *geometry, out)
    twin = engine.splat_set(points, normals, key, ray, distance, e, beam, label, scale, spread, n_el, *geometry,
                            n_labels)
    return out.reshape(twin.shape), twin


def _close(kernel, twin):
    # The kernel adds float32 deposits into float32 pixels, accumulate sums in float64: a few
    # float32 roundings per pixel (a changed continuity decision would move whole deposits).
    np.testing.assert_allclose(kernel, twin, rtol=2e-6, atol=2e-7 * twin.max())


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("spread", [True, False])
def test_splat_events_equal_splat_set(seed, spread):
    kernel, twin = _splat_both(np.random.default_rng(40 + seed), spread=spread)
    assert twin.any()
    _close(kernel, twin)


def test_splat_events_at_column_boundaries():
    # Every ray in the set: runs of one key cross every column boundary, where rays are no
    # neighbours (the next ray starts another column of the fan).
    kernel, twin = _splat_both(np.random.default_rng(50), spread=True, fraction=1.1)
    _close(kernel, twin)


def test_splat_events_on_an_empty_set():
    kernel, twin = _splat_both(np.random.default_rng(51), spread=True, fraction=0.0)
    assert not kernel.any() and not twin.any()


def test_splat_events_with_zero_energy_paths():
    # Regression: splat_events used to count a path of zero energy as a continuity neighbour,
    # which formation.accumulate does not.
    def energy(m):
        e = np.random.default_rng(52).uniform(0.1, 1.0, m)
        e[::3] = 0.0
        return e

    kernel, twin = _splat_both(np.random.default_rng(52), spread=True, fraction=1.1, energy=energy)
    _close(kernel, twin)


@pytest.mark.parametrize("first", [True, False])
def test_trace_leg_ties_and_planes_at_the_reach(first):
    # Plane 1 is plane 0 again (a tie: the earlier plane wins), and the reach is set to the
    # length of one ray's leg to the floor: that ray scatters there and is not reflected.
    rng = np.random.default_rng(60)
    n = 200
    origin = np.array([0.1, -0.2, 1.0])
    normal = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    planes = PlaneSet(("a", "b", "c"), normal, normal @ origin - [1.0, 1.0, 3.0], np.array([0.5, 0.4, 0.3]),
                      np.array([0.9, 0.8, 0.7]))
    active = np.ones(3, bool)
    dirs = _unit(rng, n)
    dirs[:, 2] = -np.abs(dirs[:, 2])  # all towards the floor
    ray = np.arange(n, dtype=np.intp)
    org = origin.reshape(1, 3) if first else np.broadcast_to(origin, (n, 3)).copy()
    before = np.zeros(1) if first else rng.uniform(0, 1, n)
    b = np.broadcast_to(before, (n,))
    tp = (planes.offset[0] - _dot_like_kernel(org if not first else origin.reshape(1, 3), normal[0])) / (
        dirs[:, 0] * normal[0, 0] + dirs[:, 1] * normal[0, 1] + dirs[:, 2] * normal[0, 2])
    reach = float(b[7] + tp[7])
    hits = Hits(np.full(n, np.inf, np.float32), np.full(n, -1, np.int32), np.zeros((n, 3), np.float32))
    table = ChainTable(planes, origin, 3)
    kt, tt = copy.deepcopy(table), copy.deepcopy(table)
    out = [np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan),
           np.full((n, 3), np.nan, np.float32), np.full(n, np.nan), np.full(n, np.nan), np.full(n, -7, np.int32)]
    ref = copy.deepcopy(out)
    live = np.empty(n, np.intp)
    nx = (np.empty(n, np.intp), np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3)),
          np.empty((n, 3), np.float32), np.empty(n), np.empty(n), np.empty(n, np.int32))
    atten, chain = (np.ones(1), np.zeros(1, np.int32)) if first else (np.ones(n), np.zeros(n, np.int32))
    n_next, n_chains, _, _, n_live = K.trace_leg(
        ray, hits.distance, hits.mesh_id, hits.normal, org, dirs, before, atten, chain, planes.normal, planes.offset,
        active.astype(np.uint8), planes.specular, reach, np.array([0.0, 0.5, 0.4, 0.3]), np.ones(n), True, first,
        True, kt.children, 1, out[0], out[1], out[2], out[3], out[4], out[5], out[6],
        np.full(n, -1, np.int32), live, 3, *nx)
    kt.sync(n_chains)
    leg = engine.Leg(0, *ref)
    nxt, tlive = engine.trace_generation(engine.Rays(ray, org, dirs, before, atten, chain), hits, planes, active,
                                         reach, np.array([0.0, 0.5, 0.4, 0.3]), np.ones(n), True, first, True, tt, leg)
    for a, c in zip(out, ref):
        np.testing.assert_array_equal(a, c)
    np.testing.assert_array_equal(nx[0][:n_next], nxt.ray)
    np.testing.assert_array_equal(nx[7][:n_next], nxt.chain)
    assert kt.chains == tt.chains
    assert out[1][7] == 0 and out[0][7] == reach and 7 not in nxt.ray  # at the reach: kept, not reflected
    assert 1 not in out[1]  # the tie goes to the earlier plane


def _dot_like_kernel(org, n):
    return org[:, 0] * n[0] + org[:, 1] * n[1] + org[:, 2] * n[2]


def test_law_tables_of_the_wrong_size_are_refused():
    # The kernels read the tables without bounds checks: their sizes are checked on entry.
    rng = np.random.default_rng(8)
    n = 20
    planes = PlaneSet((), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
    table = ChainTable(planes, np.zeros(3), 2)
    hit_mesh = np.zeros(n, np.int32)
    args = lambda law, lobe, texel: (
        np.arange(n, dtype=np.intp), np.ones(n, np.float32), hit_mesh, _unit(rng, n).astype(np.float32),
        np.zeros((1, 3)), _unit(rng, n), np.zeros(1), np.ones(1), np.zeros(1, np.int32), planes.normal,
        planes.offset, np.zeros(0, np.uint8), planes.specular, 4.0, np.array([0.0, 0.5]), np.ones(n), True, True,
        False, table.children, 1, np.empty(n), np.empty(n, np.int32), np.empty((n, 3)),
        np.empty((n, 3), np.float32), np.empty(n), np.empty(n), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.intp), 1,
        np.empty(n, np.intp), np.empty((n, 3)), np.empty((n, 3), np.float32), np.empty((n, 3)),
        np.empty((n, 3), np.float32), np.empty(n), np.empty(n), np.empty(n, np.int32), law, lobe, texel)
    ok = (np.array([0, 1], np.int32), np.zeros((2, 2)), np.ones(n, np.float32))
    K.trace_leg(*args(*ok))
    for bad in ((np.array([0], np.int32), np.zeros((2, 2)), None), (ok[0], np.zeros((3, 2)), None),
                (ok[0], None, None), (None, None, np.ones(n - 1, np.float32))):
        with pytest.raises(ValueError):
            K.trace_leg(*args(*bad))
