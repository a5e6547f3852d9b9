"""Textured meshes: the texture's pattern in the image, with every law, kernel and backend."""

from __future__ import annotations

import copy
import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from PIL import Image

import sonarsim
from sonarsim import ConfigError
from sonarsim.config.materials import Material
from sonarsim.config.scene import GroundSpec, ObjectSpec
from sonarsim.core.transforms import Pose
from sonarsim.renderer import compiled
from tests.conftest import sonar_dict

# Four vertical stripes, left to right in the image (u from 0 to 1).
STRIPES = np.array([1.0, 0.25, 0.5, 0.0])
SEEN = np.round(STRIPES * 255) / 255  # as an 8-bit image stores them


def textured_quad(levels=STRIPES, rows: int = 4, width_m: float = 4.0, height_m: float = 4.0) -> trimesh.Trimesh:
    """A wall in the plane x = 0 facing -x: u runs along -y (the sonar's left to right), v along z."""
    w, h = width_m / 2, height_m / 2
    vertices = [[0, w, -h], [0, -w, -h], [0, -w, h], [0, w, h]]
    mesh = trimesh.Trimesh(vertices=vertices, faces=[[0, 1, 2], [0, 2, 3]], process=False)
    pixels = np.repeat(np.repeat(np.asarray(levels, float)[None, :], rows, axis=0), 16, axis=1)
    image = Image.fromarray(np.round(pixels * 255).astype(np.uint8))
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]], image=image)
    return mesh


def wall_scene(material: Material, d: float = 2.0, mesh=None, ground: GroundSpec | None = None, **sonar):
    doc = {"sonar": sonar_dict(azimuth_fov_deg=60.0, n_beams=64, **sonar), "render": {"elevation_samples": 64}}
    scene = sonarsim.load_scene(doc)
    obj = ObjectSpec("wall", mesh=mesh if mesh is not None else textured_quad(), pose=Pose((d, 0.0, 0.0)),
                     material=material)
    return replace(scene, objects=(obj,), ground=ground)


def stripe_of_beam(img, d: float = 2.0, width_m: float = 4.0):
    """Stripe index each beam's centre ray meets on the wall (u = (w - y) / width), -1 near an edge."""
    y = d * np.tan(np.radians(img.azimuth_deg))
    u = (width_m / 2 - y) / width_m
    k = np.floor(u * 4).astype(int)
    near_edge = np.abs(u * 4 - np.round(u * 4)) < 0.06
    return np.where(near_edge | (u <= 0) | (u >= 1), -1, k)


@pytest.mark.parametrize("law", ["lambertian", "lambert", "rough"])
def test_the_stripes_show_in_the_beams(law):
    # Each beam's energy is the law's integral (tests/renderer/test_materials.py) times the
    # brightness of the stripe it looks at (the lobe, where there is one, is not scaled).
    material = {"lambertian": Material(albedo=0.6, texture=True), "lambert": Material("lambert", mu=0.01, texture=True),
                "rough": Material("rough", albedo=0.3, specular_strength=2.0, roughness=0.2, texture=True)}[law]
    img = sonarsim.render(wall_scene(material))
    plain = sonarsim.render(wall_scene(replace(material, texture=False)))
    energy, full = img.polar.sum(axis=0).astype(float), plain.polar.sum(axis=0).astype(float)
    k = stripe_of_beam(img)
    assert {0, 1, 2, 3} <= set(k[k >= 0])
    lobe = np.zeros_like(full)
    if law == "rough":
        lobe = full - sonarsim.render(wall_scene(Material(albedo=0.3))).polar.sum(axis=0)
    inside = k >= 0
    np.testing.assert_allclose(energy[inside], SEEN[k[inside]] * (full - lobe)[inside] + lobe[inside],
                               rtol=1e-5, atol=1e-7 * full.max())
    assert energy[k == 3].max() <= lobe[k == 3].max() + 1e-7  # the black stripe: nothing diffuse


def test_a_white_texture_changes_nothing_bit_for_bit():
    white = textured_quad(levels=np.ones(4))
    ground = GroundSpec(albedo=0.5, specular=0.6)
    pose = {"position_m": [0, 0, 1.0], "rpy_deg": [0, 15, 0]}
    a = sonarsim.render(wall_scene(Material(albedo=0.6, texture=True), mesh=white, ground=ground), pose=pose)
    b = sonarsim.render(wall_scene(Material(albedo=0.6), mesh=white, ground=ground), pose=pose)
    for key in b.components:
        np.testing.assert_array_equal(a.components[key], b.components[key], err_msg=key)


def test_horizontal_stripes_show_in_range():
    # A floor z = 0 textured with stripes across the view (v along x): the echo of each range
    # interval follows the stripe that lies at that range.
    n = 8
    levels = (np.arange(n) % 2).astype(float)  # 0, 1, 0, 1, ... along v
    mesh = trimesh.Trimesh(vertices=[[0, -2, 0], [0, 2, 0], [4, 2, 0], [4, -2, 0]], faces=[[0, 1, 2], [0, 2, 3]],
                           process=False)
    pixels = np.repeat(levels[::-1, None], 4, axis=1)  # image row 0 is the top: v = 1
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                                image=Image.fromarray((pixels * 255).astype(np.uint8)))
    doc = {"sonar": sonar_dict(range_max_m=4.5, n_range_bins=450, pose={"position_m": [0, 0, 1.0],
                                                                         "rpy_deg": [0, 30, 0]}),
           "render": {"elevation_samples": 96}}
    scene = replace(sonarsim.load_scene(doc), objects=(ObjectSpec("floor", mesh=mesh, material=Material(texture=True)),))
    img = sonarsim.render(scene)
    # The centre beam's rays meet the floor at x = sqrt(r^2 - 1): stripe floor(x / 0.5).
    column = img.polar[:, img.sonar.n_beams // 2]
    r = img.range_m
    x = np.sqrt(np.maximum(r**2 - 1.0, 0.0))
    stripe = np.floor(x / 0.5).astype(int)
    lit = column > 0
    assert lit.sum() > 30
    away = np.abs(x / 0.5 - np.round(x / 0.5)) > 0.1  # not at a stripe's edge
    dark = lit[away & (stripe % 2 == 0)]
    bright = lit[away & (stripe % 2 == 1) & (r > img.range_m[np.flatnonzero(lit)[0]] + 0.05)
                 & (r < img.range_m[np.flatnonzero(lit)[-1]] - 0.05)]
    assert len(dark) > 20 and len(bright) > 20
    assert not dark.any() and bright.all()


def multipath_scene(**render) -> sonarsim.Scene:
    """A textured wall standing on a reflecting floor, seen from above: every path meets the texture."""
    scene = wall_scene(Material("rough", albedo=0.7, specular_strength=0.5, roughness=0.3, texture=True),
                       d=3.0, mesh=textured_quad(height_m=1.0), ground=GroundSpec(0.0, material=Material(
                           "lambert", mu=0.05), specular=0.7),
                       range_max_m=6.0, pose={"position_m": [0.0, 0.0, 1.2], "rpy_deg": [0.0, 25.0, 0.0]})
    wall = scene.objects[0]
    return replace(scene, objects=(replace(wall, pose=Pose((3.0, 0.0, 0.5))),),
                   render=replace(scene.render, **render))


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
def test_compiled_and_numpy_kernels_agree_on_textures():
    scene = multipath_scene()
    a = sonarsim.Simulator(scene).render()
    b = sonarsim.Simulator(scene, kernels="numpy").render()
    assert a.components["double"].any() and a.components["triple"].any()
    for key in b.components:
        x, y = a.components[key].astype(float), b.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-5 * np.abs(y).sum() + 1e-12, key
    # The texture is seen in the echoes too (the untextured wall gives other images).
    plain = sonarsim.render(replace(scene, objects=(replace(scene.objects[0], material=replace(
        scene.objects[0].material, texture=False)),)))
    for key in ("object", "double", "triple"):
        assert np.abs(plain.components[key] - a.components[key]).sum() > 0.1 * a.components[key].sum(), key


def test_algorithm2_and_the_numpy_caster_see_the_same_texture():
    scene = multipath_scene(elevation_samples=48, double_beam="paper")  # Algorithm 2's convention for the pairs
    fast = sonarsim.render(scene)
    paper = sonarsim.render(replace(scene, render=replace(scene.render, method="paper")))
    slow = sonarsim.Simulator(scene, backend="numpy").render()
    for key in ("object", "ground", "double", "triple"):
        y = fast.components[key].astype(float)
        assert np.abs(paper.components[key] - y).sum() <= 1e-3 * y.sum() + 1e-9, key
        assert np.abs(slow.components[key] - y).sum() <= 2e-3 * y.sum() + 1e-9, key


def test_scene_files_with_a_textured_mesh(tmp_path):
    mesh = textured_quad()
    mesh.export(tmp_path / "wall.glb")
    trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces).export(tmp_path / "bare.stl")
    doc = {"sonar": sonar_dict(azimuth_fov_deg=60.0, n_beams=64), "render": {"elevation_samples": 64},
           "objects": [{"name": "wall", "mesh": "wall.glb", "pose": {"position_m": [2.0, 0.0, 0.0]},
                        "material": {"albedo": 0.6, "texture": True}}]}
    (tmp_path / "scene.yaml").write_text(__import__("yaml").safe_dump(doc))
    img = sonarsim.render(str(tmp_path / "scene.yaml"))
    ref = sonarsim.render(wall_scene(Material(albedo=0.6, texture=True)))
    np.testing.assert_allclose(img.polar, ref.polar, rtol=1e-5, atol=1e-9)
    assert img.config["objects"][0]["material"] == {"law": "lambertian", "albedo": 0.6, "texture": True}
    # A mesh without a texture, asked for one: the error names the key.
    bad = copy.deepcopy(doc)
    bad["objects"][0]["mesh"] = "bare.stl"
    (tmp_path / "bad.yaml").write_text(__import__("yaml").safe_dump(bad))
    with pytest.raises(ConfigError) as info:
        sonarsim.load_scene(str(tmp_path / "bad.yaml"))
    assert info.value.key == "objects[0].material.texture" and "no texture" in str(info.value)


def test_an_in_memory_mesh_without_a_texture_asked_for_one_names_the_object():
    bare = trimesh.Trimesh(vertices=textured_quad().vertices, faces=textured_quad().faces)
    with pytest.raises(sonarsim.MeshFileError, match="'wall'.*no texture"):
        sonarsim.Simulator(wall_scene(Material(texture=True), mesh=bare))
