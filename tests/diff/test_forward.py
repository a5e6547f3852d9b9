"""The differentiable engine's forward: equal to the compiled engine, per component; its
parameters, errors, batches and refreshed search (issue 24, items 1 and 4)."""

from __future__ import annotations

import re

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

from sonarsim.config.examples import demo_scene_dict, tank_scene_dict  # noqa: E402
from sonarsim.core.extras import install_command  # noqa: E402
from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.renderer.simulator import Simulator  # noqa: E402

import sonarsim.diff as sd  # noqa: E402

OCULUS = {"sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 0.433], "rpy_deg": [1.42, 29.06, 0]}},
          "ground": {}, "sensor": {"preset": "oculus-m1200d-hf"}}
SCENES = {"demo": demo_scene_dict, "tank": tank_scene_dict, "oculus": lambda: OCULUS}


def rel_l1(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.abs(a - b).sum() / np.abs(b).sum())


@pytest.fixture(scope="module", params=sorted(SCENES))
def pair(request):
    doc = SCENES[request.param]()
    r = sd.Renderer(doc)
    with Simulator(doc) as sim:
        ref = sim.render(speckle=False)
        components = {k: np.array(ref.components[k]) for k in ref.components}
    return request.param, r, ref, components


def test_the_forward_equals_the_compiled_engine_per_component(pair):
    name, r, ref, components = pair
    assert rel_l1(r.render(), ref.polar) < 1e-3, name
    mine = r.components()
    assert set(components) <= set(mine)
    for k, image in components.items():
        if image.any():
            assert rel_l1(mine[k], image) < 1e-3, (name, k)
    # The signatures the held search names and the compiled engine left out hold nothing.
    for k in set(mine) - set(components):
        assert float(np.abs(np.asarray(mine[k])).sum()) == 0.0, (name, k)


def test_the_demo_has_every_order_and_the_tank_its_signatures(pair):
    name, r, _, components = pair
    if name == "demo":
        assert all(float(np.asarray(r.components()[k]).sum()) > 0 for k in ("object", "ground", "double", "triple"))
    if name == "tank":
        assert len([k for k in components if k.startswith("O-")]) > 20


def test_a_changed_parameter_changes_the_image_as_the_compiled_engine_does():
    doc = tank_scene_dict()
    r = sd.Renderer(doc)
    p = r.params()
    # A material and a plane's reflectance move no path: the held search is exact for them.
    q = {**p, "objects.block.albedo": jnp.asarray(0.3), "planes.far_wall.specular": jnp.asarray(0.2)}
    from sonarsim.diff.params import scene_with

    with Simulator(scene_with(r.scene, q)) as sim:
        ref = sim.render(speckle=False).polar
    assert rel_l1(r.render(q), ref) < 1e-3
    assert rel_l1(r.render(p), ref) > 1e-2


def test_refresh_searches_again_where_the_parameters_moved_the_sonar():
    r = sd.Renderer(demo_scene_dict())
    p = r.params()
    q = {**p, "sonar.position_m": p["sonar.position_m"] + jnp.asarray([0.3, -0.2, 0.1]),
         "sonar.rpy_deg": p["sonar.rpy_deg"] + jnp.asarray([1.0, 3.0, -4.0])}
    with Simulator(demo_scene_dict()) as sim:
        from sonarsim.core.transforms import Pose

        ref = sim.render(pose=Pose(tuple(np.asarray(q["sonar.position_m"])), tuple(np.asarray(q["sonar.rpy_deg"]))),
                         speckle=False).polar
    stale = rel_l1(r.render(q), ref)
    r.refresh(q)
    assert rel_l1(r.render(q), ref) < 1e-3 < stale


def test_refresh_searches_moved_objects_and_planes():
    r = sd.Renderer(tank_scene_dict())
    p = r.params()
    q = {**p, "objects.block.position_m": p["objects.block.position_m"] + jnp.asarray([-0.5, 0.3, 0.0]),
         "planes.far_wall.offset_m": p["planes.far_wall.offset_m"] + 0.4}
    from sonarsim.diff.params import scene_with

    with Simulator(scene_with(r.scene, q)) as sim:
        ref = sim.render(speckle=False).polar
    r.refresh(q)
    assert rel_l1(r.render(q), ref) < 1e-3


def test_params_are_named_and_shaped_as_documented():
    r = sd.Renderer(tank_scene_dict())
    p = r.params()
    assert p["sonar.position_m"].shape == (3,) and p["sonar.rpy_deg"].shape == (3,)
    assert np.allclose(p["sonar.rpy_deg"], [0.0, 2.0, 0.0])
    assert p["objects.buoy.position_m"].shape == (3,) and p["objects.buoy.scale"].shape == (3,)
    assert p["objects.buoy.vertices_m"].shape[1] == 3
    assert float(p["objects.buoy.albedo"]) == pytest.approx(0.7)
    assert float(p["planes.ground.offset_m"]) == 0.0 and float(p["planes.surface.offset_m"]) == pytest.approx(-2.0)
    assert np.allclose(p["planes.far_wall.normal"], [-1.0, 0.0, 0.0])
    assert float(p["planes.far_wall.specular"]) == pytest.approx(0.5)
    s = sd.Renderer(OCULUS).params()
    assert {"sensor.gain_db", "sensor.tvg_spreading", "sensor.noise_db", "sensor.elevation_width_deg",
            "sensor.azimuth_width_deg", "sensor.gamma"} <= set(s)
    assert float(s["sensor.elevation_width_deg"]) == pytest.approx(7.48)


def test_an_unknown_or_misshapen_parameter_is_refused_by_name():
    r = sd.Renderer(demo_scene_dict())
    with pytest.raises(ConfigError, match="objects.nothing.albedo: no such parameter"):
        r.render({"objects.nothing.albedo": 0.5})
    with pytest.raises(ConfigError, match=r"sonar.position_m: has shape \(2,\); expected \(3,\)"):
        r.render({"sonar.position_m": jnp.zeros(2)})
    with pytest.raises(ConfigError, match="dtype"):
        sd.Renderer(demo_scene_dict(), dtype="float16")


def test_a_missing_jax_names_the_extra(monkeypatch):
    import sys

    import sonarsim.diff as diff

    monkeypatch.setitem(sys.modules, "jax", None)
    with pytest.raises(ImportError, match=re.escape(install_command("diff"))):
        diff.require_jax()


def test_a_batch_of_poses_by_vmap_equals_one_by_one():
    r = sd.Renderer(demo_scene_dict())
    p = r.params()
    offsets = jnp.asarray([[0.0, 0.0, 0.0], [0.01, -0.02, 0.005], [-0.03, 0.01, 0.0], [0.0, 0.0, -0.01]])

    def image(offset):
        return r.render({**p, "sonar.position_m": p["sonar.position_m"] + offset})

    batch = jax.vmap(image)(offsets)
    assert batch.shape == (4, r.scene.sonar.n_range_bins, r.scene.sonar.n_beams)
    for k in range(4):
        one = np.asarray(image(offsets[k]))
        np.testing.assert_allclose(np.asarray(batch[k]), one, rtol=1e-9, atol=1e-12 * np.abs(one).max())
    assert rel_l1(batch[1], batch[0]) > 1e-3


def test_float32_agrees_with_float64():
    a = sd.Renderer(demo_scene_dict(), dtype="float32")
    img = a.render()
    assert img.dtype == jnp.float32
    b = sd.Renderer(demo_scene_dict())
    assert rel_l1(img, b.render()) < 3e-4  # (coherent pairs: both paths of each pair, each rounded: 1.9e-4)


def test_paths_are_the_held_searchs_with_the_compiled_ranges():
    r = sd.Renderer(tank_scene_dict())
    paths = r.paths()
    n = r.search.n_paths
    assert paths["distance"].shape == (n,) and paths["point"].shape == (n, 3)
    # The compiled engine's ranges, formed again from the geometry (float32 hits there).
    np.testing.assert_allclose(np.asarray(paths["distance"]), r.search.distance[:n], rtol=0, atol=2e-6)


def _tank(**render):
    d = tank_scene_dict()
    d["render"].update(render)
    return d


def _textured_ground():
    d = tank_scene_dict()
    d["ground"]["texture"] = {"std_db": 3.0, "correlation_m": [0.3, 0.3], "seed": 1}
    return d


def _demo(**render):
    d = demo_scene_dict()
    d["render"] = {**d.get("render", {}), **render}
    return d


def _oculus_corrected():
    d = {**OCULUS, "sensor": {"preset": "oculus-m1200d-hf",
                              "elevation_pattern": {"shape": "gaussian", "width_deg": 10.0, "correction_db": [-3, 2, -3]}}}
    return d


@pytest.mark.parametrize("make", [
    lambda: _tank(double_beam="split"), lambda: _tank(double_beam="separate"), lambda: _tank(double_line_of_sight=True),
    _textured_ground, lambda: _demo(range_splat=False), lambda: _demo(tvg=False),
    lambda: _demo(beam_pattern="gaussian", azimuth_samples=3), _oculus_corrected,
], ids=["split", "separate", "line-of-sight", "textured-ground", "no-splat", "no-tvg", "gaussian-3-azimuth",
        "elevation-correction"])
@pytest.mark.parametrize("attach", ["rays", "surfaces"])
def test_render_settings_and_sensors_equal_the_compiled_engine(make, attach):
    doc = make()
    with Simulator(doc) as sim:
        ref = sim.render(speckle=False).polar
    assert rel_l1(sd.Renderer(doc, attach=attach).render(), ref) < 1e-3


def test_a_texture_scales_a_rough_objects_diffuse_part_not_its_lobe():
    from dataclasses import replace

    from sonarsim.config.materials import Material
    from sonarsim.config.scene import ground_plane
    from sonarsim.core.transforms import Pose
    from tests.renderer.test_textures import textured_quad, wall_scene

    for texture in (True, False):
        material = Material("rough", albedo=0.7, specular_strength=0.5, roughness=0.3, texture=texture)
        scene = wall_scene(material, d=3.0, mesh=textured_quad(height_m=1.0),
                           ground=ground_plane(0.0, material=Material("lambert", mu=0.01), specular=0.5))
        scene = replace(scene, sonar_pose=Pose((0.0, 0.0, 0.5), (0.0, 10.0, 0.0)))
        with Simulator(scene) as sim:
            ref = sim.render(speckle=False)
        mine = sd.Renderer(scene).components()
        for k in ("total", "object", "double"):
            assert rel_l1(mine[k], ref.components[k]) < 1e-3, (texture, k)


def test_an_empty_search_renders_nothing_and_a_sonar_on_a_plane_is_refused():
    doc = demo_scene_dict()
    doc.pop("ground")
    doc["objects"] = []
    r = sd.Renderer(doc)
    assert r.search.n_paths == 0 and float(np.abs(np.asarray(r.render())).sum()) == 0.0
    doc = demo_scene_dict()
    doc["sonar"]["pose"]["position_m"] = [0.0, 0.0, 0.0]
    with pytest.raises(ConfigError, match="lies on the plane 'ground'"):
        sd.Renderer(doc)


def test_refresh_moves_only_geometry_and_takes_float32_values_as_they_are():
    r = sd.Renderer(demo_scene_dict(), dtype="float32")
    r.refresh(r.params())  # float32-rounded values are the scene's: no object rebuilt as a mesh
    assert r.searches == 2
    r = sd.Renderer(demo_scene_dict())
    p = r.params()
    # A law's value beyond the scene format's bounds (a fit's trial step may go there) does not
    # move the search, and refresh takes it; render refuses it (issue 37).
    r.refresh({**p, "objects.concrete_block.albedo": jnp.asarray(1.4)})
    with pytest.raises(ConfigError, match=r"objects.concrete_block.albedo: must be finite, within \[0, 1\]"):
        r.render({**p, "objects.concrete_block.albedo": jnp.asarray(1.4)})
    with pytest.raises(ConfigError, match="sonar.position_m: must be finite"):
        r.render({**p, "sonar.position_m": jnp.asarray([np.nan, 0.0, 1.0])})
    # A list is taken as an array.
    assert r.render({"sonar.position_m": [0.0, 0.0, 1.0]}).shape == (1288, 128)


def test_a_reflectivity_per_vertex_is_interpolated_at_each_scatterer():
    """``Renderer(reflectivity=...)``: at 1 the image is the plain renderer's; a field linear in
    position, ``a + b x`` at the vertices, scales each path of the object by exactly
    ``a + b x`` at its scatterer (barycentric interpolation of a linear field is exact), and
    leaves the planes' paths alone."""
    doc = demo_scene_dict()
    name = doc["objects"][0]["name"]
    plain = sd.Renderer(doc)
    r = sd.Renderer(doc, reflectivity=(name,))
    p = r.params()
    assert p[f"objects.{name}.reflectivity"].shape == p[f"objects.{name}.vertices_m"].shape[:1]
    np.testing.assert_allclose(np.asarray(r.render(p)), np.asarray(plain.render()), rtol=1e-12, atol=1e-15)
    v = np.asarray(p[f"objects.{name}.vertices_m"])
    field = {**p, f"objects.{name}.reflectivity": jnp.asarray(0.7 + 2.0 * v[:, 0])}
    base, scaled = r.paths(p), r.paths(field)
    mine = np.asarray(base["signature"]) >= 0
    surface = np.asarray(r.data["surface"])[: r.search.n_paths]
    first = len(r.static.planes)  # the triangle table's rows follow the planes'
    face_object = np.asarray(r.data["face_object"])
    on_object = (surface >= first) & (face_object[np.clip(surface - first, 0, len(face_object) - 1)] == 0)
    # The object's own frame: its vertices are local, the scatterer is posed.
    local = _to_local(np.asarray(base["point"]), doc["objects"][0])
    want = np.where(on_object, 0.7 + 2.0 * local[:, 0], 1.0)
    e0, e1 = np.asarray(base["energy"]), np.asarray(scaled["energy"])
    live = mine & (e0 > 0)
    # (to the float32 round-off of the search's hits, where the barycentric coordinates come from)
    np.testing.assert_allclose(e1[live], e0[live] * want[live], rtol=1e-5)
    assert on_object[live].any() and (~on_object[live]).any()
    with pytest.raises(ConfigError, match="reflectivity"):
        sd.Renderer(doc, reflectivity=("no_such_object",))


def _to_local(points: np.ndarray, obj: dict) -> np.ndarray:
    from sonarsim.core.transforms import Pose

    pose = obj.get("pose", {})
    rot = Pose(pose.get("position_m", (0, 0, 0)), pose.get("rpy_deg", (0, 0, 0)))
    return (points - np.asarray(rot.position_m)) @ rot.rotation / np.asarray(obj.get("scale", 1.0))
