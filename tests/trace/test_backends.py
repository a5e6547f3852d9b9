"""Embree (through embreex) against the slow pure-NumPy reference, on the same rays."""

from __future__ import annotations

import numpy as np

import sonarsim
from sonarsim.trace import make_caster
from sonarsim.scene.meshes import object_mesh_world
from tests.conftest import sonar_dict

SCENE = {
    "sonar": sonar_dict(n_beams=24, n_range_bins=300, pose={"position_m": [0, 0, 1.0], "rpy_deg": [5, 15, -3]}),
    "ground": {"albedo": 0.7},
    "render": {"elevation_samples": 40},
    "objects": [
        {"name": "box", "primitive": "box", "size_m": [0.5, 0.4, 0.3], "pose": {"position_m": [2.5, -0.3, 0.15], "rpy_deg": [0, 0, 25]}},
        {"name": "drum", "primitive": "cylinder", "radius_m": 0.2, "height_m": 0.5, "pose": {"position_m": [3.2, 0.4, 0.25]}},
    ],
}


def test_embree_and_numpy_hits_agree():
    scene = sonarsim.load_scene(SCENE)
    meshes = [object_mesh_world(o) for o in scene.objects]
    rng = np.random.default_rng(0)
    n = 3000
    origins = np.tile([0.0, 0.0, 1.0], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    target = np.column_stack([rng.uniform(2, 4, n), rng.uniform(-1, 1, n), rng.uniform(0, 0.6, n)])
    d = target - origins
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = make_caster("embree", meshes).intersect(origins, d, 10.0)
    b = make_caster("numpy", meshes).intersect(origins, d, 10.0)
    hit = np.isfinite(b.distance)
    assert 0.2 < hit.mean() < 0.9  # the test exercises both hits and misses
    # float32 ray casting: rays grazing an edge within ~1e-6 m may go either way.
    same = (a.mesh_id == b.mesh_id)
    assert same.mean() > 0.998
    both = same & hit
    np.testing.assert_allclose(a.distance[both], b.distance[both], rtol=0, atol=2e-5)
    cos = np.abs(np.sum(a.normal[both] * b.normal[both], axis=1))
    assert np.all(cos > 1 - 1e-5)


def test_embree_and_numpy_images_agree():
    a = sonarsim.Simulator(SCENE, backend="embree").render()
    b = sonarsim.Simulator(SCENE, backend="numpy").render()
    assert a.polar.any()
    same = a.rays.surface_id == b.rays.surface_id
    assert same.mean() > 0.999
    np.testing.assert_allclose(a.rays.distance_m[same], b.rays.distance_m[same], atol=2e-5)
    diff = np.abs(a.polar - b.polar).sum() / np.abs(b.polar).sum()
    assert diff < 2e-3


def test_multithreaded_embree_equals_single_thread():
    doc = dict(SCENE, render={"elevation_samples": 800, "threads": 1})
    a = sonarsim.render(doc)
    doc["render"] = {"elevation_samples": 800, "threads": 2}
    b = sonarsim.render(doc)
    np.testing.assert_array_equal(a.rays.distance_m, b.rays.distance_m)
    np.testing.assert_array_equal(a.polar, b.polar)


def _hit_rays(rng, n=3000):
    origins = np.tile([0.0, 0.0, 1.0], (n, 1)) + rng.normal(0, 0.05, (n, 3))
    target = np.column_stack([rng.uniform(2, 4, n), rng.uniform(-1, 1, n), rng.uniform(0, 0.6, n)])
    d = target - origins
    return origins, d / np.linalg.norm(d, axis=1, keepdims=True)


def test_both_backends_report_the_same_triangle_and_barycentric_coordinates():
    # What a texture lookup needs: the triangle hit within its mesh and (u, v) on it, with
    # p = (1 - u - v) a + u b + v c, the hit point itself.
    scene = sonarsim.load_scene(SCENE)
    meshes = [object_mesh_world(o) for o in scene.objects]
    origins, d = _hit_rays(np.random.default_rng(1))
    hits = {name: make_caster(name, meshes).intersect(origins, d, 10.0, with_uv=True) for name in ("embree", "numpy")}
    a, b = hits["embree"], hits["numpy"]
    hit = (a.mesh_id == b.mesh_id) & (b.mesh_id >= 0)
    assert hit.mean() > 0.2
    same = hit & (a.primitive_id == b.primitive_id)
    assert same.sum() > 0.998 * hit.sum()  # rays across a shared edge may go either way
    np.testing.assert_allclose(a.barycentric[same], b.barycentric[same], atol=1e-4)  # float32 on slim triangles
    for h in (a, b):
        assert h.primitive_id.dtype == np.int32 and h.barycentric.dtype == np.float32
        assert np.all(h.primitive_id[h.mesh_id < 0] == -1) and np.all(h.barycentric[h.mesh_id < 0] == 0)
        k = np.flatnonzero(h.mesh_id >= 0)
        corners = np.stack([meshes[m].triangles[f] for m, f in zip(h.mesh_id[k], h.primitive_id[k])])
        u, v = h.barycentric[k, 0:1].astype(float), h.barycentric[k, 1:2].astype(float)
        p = (1 - u - v) * corners[:, 0] + u * corners[:, 1] + v * corners[:, 2]
        np.testing.assert_allclose(p, origins[k] + d[k] * h.distance[k, None], atol=5e-5)
    # Without with_uv, neither backend spends anything on them.
    plain = make_caster("embree", meshes).intersect(origins, d, 10.0)
    assert plain.primitive_id is None and plain.barycentric is None
    np.testing.assert_array_equal(plain.distance, a.distance)


def test_with_uv_on_an_empty_scene_and_no_rays():
    for name in ("embree", "numpy"):
        caster = make_caster(name, [])
        h = caster.intersect(np.zeros((3, 3)), np.tile([1.0, 0, 0], (3, 1)), 5.0, with_uv=True)
        assert np.all(h.primitive_id == -1) and h.barycentric.shape == (3, 2)
