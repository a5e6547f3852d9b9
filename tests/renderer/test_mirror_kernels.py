"""The compiled kernels with mesh mirrors (``_kernels.Mirrors``) against their NumPy twins, bit for bit.

``trace_leg`` against ``engine.trace_generation`` with facets: rays reflecting off facets into
mirror chains, a closed object's inside refused, the chain table's overflow; ``path_events``
against ``engine.option_paths`` over transmit chains through mesh mirrors: the triangles'
containment, the closed object's side, the scatterer on the chain's own last mirror; misuse.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import trimesh

from sonarsim.core.triangles import TriangleMesh
from sonarsim.paths import engine
from sonarsim.paths.facets import FacetSet
from sonarsim.paths.planes import ChainTable, PlaneSet
from sonarsim.renderer import compiled
from sonarsim.scene.meshes import outer_side
from sonarsim.trace.base import Hits
from tests.renderer.test_kernels import K, _assert_same, _planes, _rotation, _table, _unit

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")

SLOTS = 1024  # the mirror chains' open-addressing table: at least twice the chain table's rows throughout
REACH = 6.0
SHEET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def _mesh(vertices, faces, rot, shift):
    return TriangleMesh(np.asarray(vertices, float) @ rot.T + shift, np.asarray(faces, np.int32))


def _facets(meshes, specular, normals=None):
    """The FacetSet of ``meshes`` (flat normals unless ``normals`` says), each mirroring on its
    outside, and its kernel tables."""
    sides = [outer_side(m) if r > 0 else 0 for m, r in zip(meshes, specular)]
    facets = FacetSet.of(meshes, [f"o{k}" for k in range(len(meshes))], specular,
                         normals or ["flat"] * len(meshes), sides)
    return facets, K.Mirrors.of(facets)


def _scene(rng, capacity=64, smooth=False):
    """Three random planes round a sonar and three objects: a closed box and an open sheet that
    mirror, a box that does not; a chain table of random plane chains. ``smooth``: the first
    object is a ball mirroring about its smooth normals instead, and the sheet is smooth too."""
    origin = rng.normal(size=3)
    planes = _planes(rng, origin, 3)
    box = trimesh.creation.box(extents=rng.uniform(0.5, 1.5, 3))
    first = trimesh.creation.icosphere(subdivisions=1, radius=0.7) if smooth else box
    meshes = [_mesh(first.vertices, first.faces, _rotation(rng), origin + rng.uniform(-1, 1, 3)),
              _mesh(SHEET, [[0, 1, 2], [0, 2, 3]], _rotation(rng), origin + rng.uniform(-1, 1, 3)),
              _mesh(box.vertices, box.faces, _rotation(rng), origin + rng.uniform(-1, 1, 3))]
    normals = ["smooth", "smooth", "flat"] if smooth else None
    facets, mirrors = _facets(meshes, [rng.uniform(0.3, 0.9), rng.uniform(0.3, 0.9), 0.0], normals)
    # The box's 6 faces and the sheet; smooth: each of the ball's 80 and the sheet's 2 facets alone.
    assert facets.side.tolist() == [1, 0, 0] and facets.n_mirrors == (82 if smooth else 7)
    table = _table(planes, origin, rng, capacity=capacity)
    table.facets = facets
    albedo = np.concatenate([[0.0], planes.albedo, rng.uniform(0.1, 1.0, 3)])
    return dict(origin=origin, planes=planes, meshes=meshes, facets=facets, mirrors=mirrors, table=table,
                albedo=albedo, active=np.ones(len(planes), bool))


def _rays(rng, s, n, first, n_chains):
    """A random generation of fan rays and its object hits (triangles of the objects' meshes)."""
    if first:
        ray, org, before = np.arange(n, dtype=np.intp), s["origin"].reshape(1, 3), np.zeros(1)
        atten, chain = np.ones(1), np.zeros(1, np.int32)
    else:
        ray = np.sort(rng.choice(n, n // 2, replace=False)).astype(np.intp)
        org = s["origin"] + rng.uniform(-0.3, 0.3, (len(ray), 3))
        before, atten = rng.uniform(0.0, 2.0, len(ray)), rng.uniform(0.1, 1.0, len(ray))
        chain = rng.integers(0, n_chains, len(ray)).astype(np.int32)
    k = len(ray)
    obj = rng.integers(-1, 3, k).astype(np.int32)
    faces = np.array([len(m.faces) for m in s["meshes"]])
    prim = np.where(obj >= 0, (rng.random(k) * faces[obj]).astype(np.int32), -1).astype(np.int32)
    dist = np.where(obj >= 0, rng.uniform(0.05, 1.3 * REACH, k), np.inf).astype(np.float32)
    normal = np.where(obj[:, None] >= 0, _unit(rng, k), 0.0).astype(np.float32)
    uv = np.where(obj[:, None] >= 0, rng.uniform(0.0, 0.5, (k, 2)), 0.0).astype(np.float32)
    return engine.Rays(ray, org, _unit(rng, k), before, atten, chain), Hits(dist, obj, normal, None, prim, uv)


def _kernel_tables(table):
    """The kernel's chain tables from ``table``: the dense plane table, the mirror chains' open
    addressing table, each chain's parent and last mirror, and the chains as rebuilt from those."""
    cap = table.children.shape[0]
    return dict(children=table.children.copy(), keys=np.full(SLOTS, -1, np.int64), vals=np.zeros(SLOTS, np.int32),
                parent=np.zeros(cap, np.int32), last=np.zeros(cap, np.int32), chains=list(table.chains))


def _grow(kt):
    """Double the kernel's chain table (as ChainTable._grow does); the mirror slots suffice."""
    cap, n_p = kt["children"].shape
    kt["children"] = np.vstack([kt["children"], np.full((cap, n_p), -1, np.int32)])
    for name in ("parent", "last"):
        kt[name] = np.concatenate([kt[name], np.zeros(cap, np.int32)])


def _dense(n):
    return (np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan), np.full((n, 3), np.nan, np.float32),
            np.full(n, np.nan), np.full(n, np.nan), np.full(n, -7, np.int32))


def _trace_kernel(s, kt, rays, hits, first, n, weight, **change):
    """``trace_leg`` with mirrors on the kernel tables ``kt``, grown and rerun on overflow (as
    ``_trace_both`` does); ``change``: keyword arguments replaced. Returns (outputs, overflows)."""
    planes, k = s["planes"], len(rays.ray)
    out = _dense(n) + (np.full(n, -1, np.int32), np.zeros((n, 2), np.float32), np.full(n, -1, np.int32),
                       np.full(k, -9, np.intp))
    nx = (np.empty(k, np.intp), np.empty((k, 3)), np.empty((k, 3), np.float32), np.empty((k, 3)),
          np.empty((k, 3), np.float32), np.empty(k), np.empty(k), np.empty(k, np.int32))
    overflows = 0
    while True:
        kw = dict(hit_prim=hits.primitive_id, hit_uv=hits.barycentric, prim=out[7], uv=out[8], mirrors=s["mirrors"],
                  mirror_keys=kt["keys"], mirror_children=kt["vals"], parent=kt["parent"], last_mirror=kt["last"])
        kw.update(change)
        n_known = kw.pop("n_chains", len(kt["chains"]))
        n_next, n_chains, min_next, overflow, n_live = K.trace_leg(
            rays.ray, hits.distance, hits.mesh_id, hits.normal, rays.origin, rays.direction, rays.before, rays.atten,
            rays.chain, planes.normal, planes.offset, s["active"].astype(np.uint8), planes.specular, REACH,
            s["albedo"], weight, True, first, True, kt["children"], n_known, *out[:7], out[9], out[10],
            len(planes) + 3, *nx, **kw)
        for c in range(len(kt["chains"]), n_chains):  # chain c: its parent's then its last mirror
            kt["chains"].append(kt["chains"][kt["parent"][c]] + (int(kt["last"][c]),))
        if not overflow:
            break
        overflows += 1
        _grow(kt)
    kernel = dict(zip(("distance", "sid", "point", "normal", "intensity", "atten", "chain", "prim", "uv", "key"), out))
    kernel.update(live=out[10][:n_live], ray=nx[0][:n_next], origin=nx[1][:n_next], origin32=nx[2][:n_next],
                  direction=nx[3][:n_next], direction32=nx[4][:n_next], before=nx[5][:n_next],
                  next_atten=nx[6][:n_next], next_chain=nx[7][:n_next], min_next=min_next, n_chains=n_chains,
                  chains=list(kt["chains"]))
    return kernel, overflows


def _trace_twin(s, tt, rays, hits, first, n, weight, key):
    """``engine.trace_generation`` with the facets on ChainTable ``tt``, as ``_trace_kernel``'s dict."""
    leg = engine.Leg(1, *_dense(n), prim=np.full(n, -1, np.int32), uv=np.zeros((n, 2), np.float32))
    nxt, live = engine.trace_generation(rays, hits, s["planes"], s["active"], REACH, s["albedo"], weight, True, first,
                                        True, tt, leg, facets=s["facets"])
    twin = dict(zip(("distance", "sid", "point", "normal", "intensity", "atten", "chain"),
                    (leg.distance, leg.sid, leg.point, leg.normal, leg.intensity, leg.atten, leg.chain)))
    twin.update(prim=leg.prim, uv=leg.uv, key=key if first else leg.key(len(s["planes"]) + 3), live=live,
                ray=nxt.ray, origin=nxt.origin, origin32=nxt.origin32, direction=nxt.direction,
                direction32=nxt.direction32, before=nxt.before, next_atten=nxt.atten, next_chain=nxt.chain,
                min_next=nxt.before.min() if len(nxt) else np.inf, n_chains=len(tt), chains=list(tt.chains))
    return twin


def _generations(seed, n=800, capacity=64, planes_active=True, smooth=False):
    """Generation 0 (first) and then 1 of random rays in a random scene, each traced by the kernel
    and the twin on their own chain tables: [(kernel, twin, overflows, rays, scene)] per generation."""
    rng = np.random.default_rng(seed)
    s = _scene(rng, capacity, smooth)
    s["active"][:] = planes_active
    kt, tt = _kernel_tables(s["table"]), copy.deepcopy(s["table"])
    out = []
    for first in (True, False):
        rays, hits = _rays(rng, s, n, first, len(tt))
        weight = rng.uniform(0.0, 1e-3, n)
        kernel, overflows = _trace_kernel(s, kt, rays, hits, first, n, weight)
        out.append((kernel, _trace_twin(s, tt, rays, hits, first, n, weight, kernel["key"]), overflows, rays, s))
    return out


@pytest.mark.parametrize("first", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_trace_leg_with_mirrors_equals_trace_generation(first, seed):
    kernel, twin, _, rays, s = _generations(seed)[0 if first else 1]
    _assert_same(kernel, twin)
    # The random generation reflects off facets, meets the box from inside, meets the dull box.
    P, facets, chains = len(s["planes"]), s["facets"], kernel["chains"]
    assert any(chains[c][-1] >= P for c in kernel["next_chain"])
    assert any(chains[c][-1] < P for c in kernel["next_chain"])
    r = np.flatnonzero(kernel["sid"] >= P)
    row = np.searchsorted(rays.ray, r)
    f = facets.facet(kernel["sid"][r] - P, kernel["prim"][r])
    inside = (f >= 0) & ~facets.facing(np.maximum(f, 0), rays.direction[row]) & (kernel["distance"][r] < REACH)
    assert inside.sum() >= 5 and not np.isin(r[inside], kernel["ray"]).any()
    dull = r[kernel["sid"][r] == P + 2]
    assert len(dull) >= 5 and not np.isin(dull, kernel["ray"]).any()


@pytest.mark.parametrize("first", [True, False])
def test_trace_leg_with_smooth_mirrors_equals_trace_generation(first):
    """A smooth facet reflects about the normal interpolated at the hit (the caster's
    barycentrics), or its own where that would send a grazing ray on through."""
    kernel, twin, _, rays, s = _generations(7, capacity=256, smooth=True)[0 if first else 1]
    _assert_same(kernel, twin)
    P, facets = len(s["planes"]), s["facets"]
    # Rays reflected off the ball left along its interpolated normals, not its facets' own.
    reflected = [kernel["chains"][c][-1] for c in kernel["next_chain"]]
    assert sum(1 for m in reflected if m >= P and facets.mirror_obj[m - P] == 0) >= 5
    hit = np.isin(kernel["ray"], np.flatnonzero(kernel["sid"] == P))
    flat = facets.normal[facets.facet(np.zeros(hit.sum(), int), kernel["prim"][kernel["ray"][hit]])]
    d_in = rays.direction[np.searchsorted(rays.ray, kernel["ray"][hit])]
    d_flat = d_in - 2.0 * np.einsum("ij,ij->i", d_in, flat)[:, None] * flat
    assert np.abs(kernel["direction"][hit] - d_flat).max() > 1e-3


def test_trace_leg_mirror_chain_overflow_numbers_chains_like_the_twin():
    # A full chain table and no planes met: every new chain is a mirror chain, the first overflows.
    for kernel, twin, overflows, _, s in _generations(4, capacity=6, planes_active=False):
        assert overflows >= 1
        _assert_same(kernel, twin)
        assert all(c[-1] >= len(s["planes"]) for c in kernel["chains"][6:])


def _plate_scene(rng, n=3000, per_beam=20):
    """A sonar between a floor and a surface facing a mirror plate (an open sheet, 3 m ahead),
    a mirroring closed box and a dull box; a random receive leg whose scatterers fill the fan."""
    origin, rot = rng.normal(size=3), _rotation(rng)
    normal = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]) @ rot.T
    planes = PlaneSet(("floor", "surface"), normal, normal @ origin - [1.0, 1.2], np.array([0.5, 0.3]),
                      np.array([0.8, 0.6]))
    box = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
    plate = [[3.0, -0.6, -0.95], [3.0, 0.6, -0.95], [3.0, 0.6, 0.95], [3.0, -0.6, 0.95]]
    meshes = [_mesh(plate, [[0, 1, 2], [0, 2, 3]], rot, origin),
              _mesh(box.vertices + [2.5, -1.2, 0.0], box.faces, rot, origin),
              _mesh(box.vertices + [2.0, 1.5, 0.0], box.faces, rot, origin)]
    facets, mirrors = _facets(meshes, [0.9, 0.7, 0.0])
    P, M = len(planes), facets.n_mirrors
    table = ChainTable(planes, origin, 8, facets=facets)
    for chain in [(0,), (1,), (0, 1), *[(P + m,) for m in range(M)], (P, 0), (0, P), (P, 1), (1, P), (P + 1, 0)]:
        table.add(chain)
    az, el, r = np.radians(rng.uniform(-60, 60, n)), np.radians(rng.uniform(-25, 25, n)), rng.uniform(0.5, 6, n)
    local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1) * r[:, None]
    sid = rng.integers(0, P + 3, n).astype(np.int32)
    faces = np.array([2, 12, 12])
    prim = np.where(sid >= P, (rng.random(n) * faces[np.maximum(sid - P, 0)]).astype(np.int32), -1).astype(np.int32)
    chain = rng.integers(0, len(table), n).astype(np.int32)
    # Rows 0, 2, 4, ... of the first 200: scatterers 1 mm in front of the plate, on it (sid, prim);
    # rows 1, 3, ...: the same points on the dull box. Their chain: the last (longest) one.
    local[:200] = np.repeat(np.column_stack([np.full(100, 2.999), rng.uniform(-0.5, 0.5, (100, 2))]), 2, axis=0)
    sid[:200:2], sid[1:200:2], prim[:200] = P, P + 2, np.tile([0, 1], 100)
    chain[:200] = len(table) - 1
    edges = np.linspace(60.0, -60.0, n // per_beam + 1) + rng.uniform(-0.2, 0.2, n // per_beam + 1)
    view = engine.SonarView(origin, rot, edges, 25.0, 0.5, 9.0)
    leg = engine.Leg(1, rng.uniform(0.5, 8.0, n), sid, origin + local @ rot.T, _unit(rng, n).astype(np.float32),
                     rng.uniform(0, 1e-3, n), rng.uniform(0.1, 1, n), chain, prim=prim)
    leg.distance[201::13] = np.inf
    leg.intensity[201::11] = 0.0
    live = np.flatnonzero(np.isfinite(leg.distance) & (leg.intensity != 0))
    return dict(planes=planes, active=np.ones(P, bool), facets=facets, mirrors=mirrors, table=table, view=view,
                leg=leg, live=live, per_beam=per_beam)


def _paths_both(s, tx, separate, facets=None, **change):
    """``path_events`` with mirrors and ``option_paths`` with ``facets`` (default: the scene's) on
    transmit chain ``tx`` (SAME: the leg reversed); ``change``: the kernel's arguments replaced."""
    planes, table, view, leg = s["planes"], s["table"], s["view"], s["leg"]
    facets = s["facets"] if facets is None else facets
    live, same, P, rank = s["live"], tx == engine.SAME, len(planes), engine.chain_ranks(table)
    tx, label = (0, 1) if same else (tx, table.length(tx) + 2)
    chain = np.empty(0, np.int32) if same else np.asarray(table.chains[tx], np.int32)
    m = len(live)
    buf = (np.full(m, -5, np.intp), np.full(m, np.nan), np.full(m, np.nan), np.full(m, -5, np.int32),
           np.full(m, -5, np.int32), np.full(m, -5, np.int8))
    kw = dict(plane_normal=np.vstack([planes.normal, s["facets"].mirror_normal]), tx_planes=chain,
              plane_offset=np.concatenate([planes.offset, s["facets"].mirror_offset]), mirrors=s["mirrors"],
              prim=leg.prim)
    kw.update(change)
    k = K.path_events(live, leg.distance, leg.sid, leg.point, leg.intensity, leg.atten, leg.chain, same, tx,
                      table.unfold(tx), table.sources(tx), kw.pop("tx_planes"), 1.0 if same else table.specular(tx),
                      rank, separate, label, P, s["per_beam"], *view.origin, view.rotation, view.beam_edges_deg,
                      view.half_elevation_deg, view.range_min_m, view.range_max_m, kw.pop("plane_normal"),
                      kw.pop("plane_offset"), s["active"].astype(np.uint8), *buf, **kw)
    twin = engine.option_paths(live, leg, same, tx, table.unfold(tx), table.sources(tx), chain,
                               1.0 if same else table.specular(tx), rank, separate, label, P, s["per_beam"], view,
                               planes, s["active"], facets)
    return tuple(b[:k] for b in buf), twin


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("separate", [False, True])
def test_path_events_with_mirrors_equal_option_paths(seed, separate):
    s = _plate_scene(np.random.default_rng(70 + seed))
    table, P = s["table"], len(s["planes"])
    found = {}
    for tx in [engine.SAME, *range(1, len(table))]:
        kernel, twin = _paths_both(s, tx, separate)
        for name, a, b in zip(("ray", "distance", "energy", "beam", "beam_tx", "label"), kernel, twin):
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=f"{name} (tx {tx}: {table.chains[max(tx, 0)]})")
        if tx != engine.SAME:
            found[table.chains[tx]] = kernel[0]
    # Paths via the plate alone, plate then floor, floor then plate, a box's face alone.
    for chain in [(P,), (P, 0), (0, P)]:
        assert len(found[chain]) > 0, chain
    assert sum(len(found[(P + m,)]) for m in range(1, 7)) > 0
    # The scatterers on the plate make no path via the plate; the same points on the dull box do.
    np.testing.assert_array_equal(found[(P,)][found[(P,)] < 200], np.arange(1, 200, 2))
    if separate:
        # Each transmit chain's reflection points: some off the plate's triangles, some off the
        # box's outside (the twin on a plate 100 times as large / on a box mirroring both sides).
        big = copy.deepcopy(s["facets"])
        centre = big.corners[:2].reshape(-1, 3).mean(axis=0)
        big.corners[:2] = centre + 100.0 * (big.corners[:2] - centre)
        assert len(_paths_both(s, table.add((P,)), True, big)[1][0]) > len(found[(P,)])
        open_box = dataclasses.replace(s["facets"], side=np.zeros(3, np.int8))
        assert sum(len(_paths_both(s, table.add((P + m,)), True, open_box)[1][0]) > len(found[(P + m,)])
                   for m in range(1, 7))


def test_mirror_misuse_is_refused():
    rng = np.random.default_rng(9)
    s = _scene(rng)
    kt = _kernel_tables(s["table"])
    rays, hits = _rays(rng, s, 50, True, 1)
    weight = np.ones(50)
    rows, slots = kt["children"].shape[0], "a power of 2 of slots"
    for change, match in ((dict(hit_prim=None, hit_uv=None, prim=None, uv=None), "the search's triangles"),
                          (dict(mirror_keys=np.full(3 * rows, -1, np.int64),
                                mirror_children=np.zeros(3 * rows, np.int32)), slots),  # not a power of 2
                          (dict(mirror_keys=np.full(rows, -1, np.int64), mirror_children=np.zeros(rows, np.int32)),
                           slots),  # too short
                          (dict(mirror_keys=None), slots)):
        with pytest.raises(ValueError, match=match):
            _trace_kernel(s, copy.deepcopy(kt), rays, hits, True, 50, weight, **change)
    _trace_kernel(s, kt, rays, hits, True, 50, weight)  # the same call, as it should be: accepted
    p = _plate_scene(np.random.default_rng(10), n=400)
    P, M = len(p["planes"]), p["facets"].n_mirrors
    tx = p["table"].add((P,))
    _paths_both(p, tx, True)
    bad = [(dict(plane_normal=p["planes"].normal, plane_offset=p["planes"].offset), "the planes then"),
           (dict(prim=None), "the legs' triangles"),
           (dict(tx_planes=np.array([P + M], np.int32)), f"mirror {P + M} of"),
           (dict(tx_planes=np.array([0, -1], np.int32)), "mirror -1 of")]
    for change, match in bad:
        with pytest.raises(ValueError, match=match):
            _paths_both(p, tx, True, **change)


def test_the_returns_kernel_equals_returns_to_sonar():
    """``returns_impl`` (run by the blocks after each generation) against its twin, bit for bit,
    on rays aimed near the sonar: within and without the disc, behind it, beyond what they meet
    next, beyond the reach."""
    rng = np.random.default_rng(11)
    n, m, origin, radius = 400, 300, np.array([0.2, -0.1, 1.0]), 0.1
    ray = np.sort(rng.choice(n, m, replace=False)).astype(np.intp)
    org = origin + rng.normal(size=(m, 3)) * 2.0
    aim = origin + rng.normal(size=(m, 3)) * 0.08  # about half pass within the disc
    dirs = _unit(rng, m)
    dirs[::2] = (aim - org)[::2] / np.linalg.norm((aim - org)[::2], axis=1)[:, None]
    dirs[::9] *= -1.0  # the sonar behind them
    before, atten = rng.uniform(0.0, 3.0, m), rng.uniform(0.1, 1.0, m)
    chain = rng.integers(1, 20, m).astype(np.int32)
    reached = np.full(n, np.inf)
    reached[ray[::5]] = before[::5] + rng.uniform(0.5, 4.0, len(ray[::5]))  # something met first, or not
    outs = []
    for which in ("kernel", "twin"):
        back = (np.full(n, np.inf), np.zeros(n), np.zeros((n, 3)), np.full(n, -1, np.int32))
        if which == "kernel":
            K.returns_to_sonar(ray, org, dirs, before, atten, chain, reached, origin, radius, 6.0, *back)
        else:
            leg = engine.Leg(0, *_dense(n))
            leg.back_length, leg.back_atten, leg.back_dir, leg.back_chain = back
            nxt = engine.Leg(1, *_dense(n))
            nxt.distance[:] = reached
            engine.returns_to_sonar(leg, engine.Rays(ray, org, dirs, before, atten, chain), nxt, origin, radius, 6.0)
        outs.append(back)
    for a, b in zip(*outs):
        np.testing.assert_array_equal(a, b)
    found = np.isfinite(outs[0][0])
    assert 20 <= found.sum() < m // 2  # returns found, and rays refused
    with pytest.raises(ValueError, match="different lengths"):
        K.returns_to_sonar(ray[:-1], org, dirs, before, atten, chain, reached, origin, radius, 6.0, *outs[0])


def test_the_view_decides_by_the_angles_within_round_off_of_every_edge():
    """``beam_in_view`` decides by sine and tangent, and by the angles themselves (C's asin and
    atan2) within ``ANGLE_MARGIN`` of an edge: points a few ulps either side of the beams' and
    the aperture's edges land where the angles put them. (NumPy's vectorised arctan2 may differ
    from C's in the last ulp, so the reference here is ``math``'s, which is C's.)"""
    import math

    from tests.renderer.test_kernels import _path_events, _paths_setup

    wrong = total = rejected = 0
    deg = 180.0 / math.pi  # (multiplied by, as the kernel does: not times 180, over pi)
    for seed in range(4):
        rng = np.random.default_rng(200 + seed)
        planes, active, table, view, leg, live, per_beam = _paths_setup(rng)
        n, rank, edges = len(leg.distance), engine.chain_ranks(table), np.asarray(view.beam_edges_deg)
        half = np.radians(view.half_elevation_deg)
        for tx in range(1, len(table)):
            unfold = np.asarray(table.unfold(tx))
            az = np.radians(edges[rng.integers(0, len(edges), n)]) * (1 + rng.integers(-3, 4, n) * np.finfo(float).eps)
            el = np.where(rng.random(n) < 0.5, rng.uniform(-half, half, n),
                          np.sign(rng.normal(size=n)) * half * (1 + rng.integers(-3, 4, n) * np.finfo(float).eps))
            r = rng.uniform(1.0, 5.0, n)
            local = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1) * r[:, None]
            # Scatterers whose unfolded image lies there: A = unfold^-1 (O + R local).
            leg.point[:] = np.linalg.solve(unfold[:, :3], (view.origin + local @ view.rotation.T - unfold[:, 3]).T).T
            kernel, _ = _path_events(live, leg, False, tx, table, rank, True, 2, len(planes), per_beam, view, planes,
                                     active)
            formed = dict(zip(kernel[0].tolist(), kernel[4].tolist()))
            U, R, o = unfold.tolist(), view.rotation.tolist(), view.origin.tolist()
            for i in live:
                a = leg.point[i].tolist()  # summed term by term as the kernel sums, in Python floats
                u = [U[j][0] * a[0] + U[j][1] * a[1] + U[j][2] * a[2] + U[j][3] - o[j] for j in range(3)]
                v = [R[0][j] * u[0] + R[1][j] * u[1] + R[2][j] * u[2] for j in range(3)]
                length = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
                if not view.range_min_m <= length < view.range_max_m:
                    continue
                inside = abs(math.asin(max(-1.0, min(1.0, v[2] / length))) * deg) <= view.half_elevation_deg
                beam = int(engine.beam_index(edges, np.array([math.atan2(v[1], v[0]) * deg]))[0])
                if not inside or beam < 0:
                    rejected += 1
                    wrong += i in formed
                    continue
                total += 1
                wrong += formed.get(i, beam) != beam  # (the walk may refuse it; where formed, this beam)
    assert wrong == 0 and total > 1000 and rejected > 1000


def test_a_smooth_object_that_does_not_mirror_beside_one_that_does_renders_compiled():
    """``normals: smooth`` on an object without ``specular`` (it has no facets, no corner
    normals): the compiled frame renders, as the NumPy one does."""
    import sonarsim
    from sonarsim.config.examples import demo_scene_dict

    doc = demo_scene_dict()
    for obj in doc["objects"]:
        if obj["name"] == "concrete_block":
            obj["specular"] = 0.5
        if obj["name"] == "pipe":
            obj["normals"] = "smooth"
    a = sonarsim.Simulator(doc, kernels="compiled").render(speckle=False)
    b = sonarsim.Simulator(doc, kernels="numpy").render(speckle=False)
    assert np.abs(a.polar.astype(float) - b.polar).sum() <= 1e-6 * np.abs(b.polar).sum()


def test_the_kernels_refuse_tables_and_arrays_they_would_read_or_write_past():
    rng = np.random.default_rng(3)
    s = _scene(rng)
    kt = _kernel_tables(s["table"])
    rays, hits = _rays(rng, s, 50, True, len(kt["chains"]))
    weight = rng.uniform(0.0, 1e-3, 50)
    with pytest.raises(ValueError, match="chains in a chain table"):
        _trace_kernel(s, kt, rays, hits, True, 50, weight, n_chains=-3)
    full = np.arange(SLOTS, dtype=np.int64)  # every slot taken by some other chain's key
    with pytest.raises(ValueError, match="more than half full"):
        _trace_kernel(s, kt, rays, hits, True, 50, weight, mirror_keys=full)
    n = 10
    args = (np.arange(n, dtype=np.intp), np.zeros((n, 3)), np.ones((n, 3)), np.zeros(n), np.ones(n),
            np.zeros(n, np.int32), np.full(n, np.inf), np.zeros(3), 0.1, 5.0)
    with pytest.raises(ValueError, match=r"\(rows, 3\)"):
        K.returns_to_sonar(*args, np.full(n, np.inf), np.zeros(n), np.zeros((n, 1)), np.full(n, -1, np.int32))
