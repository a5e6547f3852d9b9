"""Mesh files that are not what they claim (issue 21 item 3): far vertices, unknown formats,
textures without their files, pipes named inside a mesh; one error naming the file and key."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh
from PIL import Image

import sonarsim
from sonarsim.errors import ConfigError, MeshFileError
from sonarsim.scene.meshes import load_mesh_file
from tests.fifo import no_hang

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30, "elevation_fov_deg": 14, "range_min_m": 0.5, "range_max_m": 5.0,
         "n_range_bins": 100}
TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"


def scene_with(mesh, **extra):
    return {"sonar": SONAR, "objects": [{"name": "m", "mesh": str(mesh), **extra}]}


def write_textured_obj(folder, mtl="tex.mtl", image="tex.png", mtl_text=None):
    """tex.obj: a triangle with UVs whose material library is ``mtl`` naming ``image`` (neither written)."""
    obj = folder / "tex.obj"
    obj.write_text(f"mtllib {mtl}\n{TRIANGLE}vt 0 0\nvt 1 0\nvt 0 1\nusemtl skin\nf 1/1 2/2 3/3\n")
    return obj, folder / mtl, folder / image, mtl_text if mtl_text is not None else f"newmtl skin\nmap_Kd {image}\n"


def test_vertices_beyond_the_scene_are_refused_naming_the_file(tmp_path):
    far = tmp_path / "far.obj"
    far.write_text("v 0 0 0\nv 1e30 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshFileError, match=r"reach 1e\+30 m; allowed: within 1e\+06 m") as e:
        load_mesh_file(far)
    assert str(far) in str(e.value)
    with pytest.raises(ConfigError) as e:
        sonarsim.load_scene(scene_with(far))
    assert e.value.key == "objects[0].mesh" and str(far) in str(e.value)


@pytest.mark.parametrize("extra", [{"scale": 2000.0},
                                   {"pose": {"position_m": [999_999.5, 0, 0]}},
                                   {"scale": 1000.0, "pose": {"position_m": [0, 0, 0], "rpy_deg": [0, 0, 45]}}])
def test_a_mesh_scaled_or_posed_beyond_the_scene_is_refused(tmp_path, extra):
    big = tmp_path / "big.obj"
    big.write_text("v 0 0 0\nv 1000 0 0\nv 0 1000 0\nv 1000 1000 0\nf 1 2 3\nf 2 4 3\n")
    with pytest.raises(ConfigError, match="its vertices reach .* m from the origin; allowed: within 1e\\+06 m") as e:
        sonarsim.load_scene(scene_with(big, **extra))
    assert e.value.key == "objects[0].mesh" and str(big) in str(e.value)
    # A Trimesh from Python goes past the loader: the simulator refuses it, naming the object.
    mesh = trimesh.load(big, process=False)
    scale, pose = extra.get("scale", 1.0), sonarsim.Pose(**extra["pose"]) if "pose" in extra else sonarsim.Pose()
    scene = sonarsim.Scene(sonarsim.load_scene({"sonar": SONAR}).sonar,
                           objects=(sonarsim.ObjectSpec("slab", mesh=mesh, scale=scale, pose=pose),))
    with pytest.raises(MeshFileError, match="object 'slab': scaled and posed"):
        sonarsim.Simulator(scene, backend="numpy")


def test_a_mesh_within_the_scene_loads(tmp_path):
    # 1000 m across, rotated 45 degrees: its box's corners reach 1414 m but no vertex beyond 1000.
    ok = tmp_path / "ok.obj"
    ok.write_text("v 0 0 0\nv 1000 0 0\nv 0 1000 0\nf 1 2 3\n")
    scene = sonarsim.load_scene(scene_with(ok, scale=999.0, pose={"position_m": [0, 0, 0], "rpy_deg": [0, 0, 45]}))
    assert scene.objects[0].scale == 999.0


@pytest.mark.parametrize("name", ["cloud.xyz", "model.fbx", "noext"])
def test_formats_other_than_meshes_are_refused_by_suffix(tmp_path, name):
    # An OBJ named .xyz failed with "could not convert string to float: 'v'".
    p = tmp_path / name
    p.write_text(TRIANGLE + "f 1 2 3\n")
    with pytest.raises(ConfigError, match="is not a mesh format sonarsim reads; allowed: .obj, .stl, .ply, .off, .glb, .gltf, .dae") as e:
        sonarsim.load_scene(scene_with(p))
    assert e.value.key == "objects[0].mesh" and str(p) in str(e.value)


def test_texture_true_without_the_mtl_or_its_image_names_the_missing_file(tmp_path):
    obj, mtl, image, mtl_text = write_textured_obj(tmp_path)
    # Without its MTL trimesh gave the UVs a 2 x 2 grey image of its own, silently.
    with pytest.raises(ConfigError, match="'tex.mtl' not found beside the mesh") as e:
        sonarsim.load_scene(scene_with(obj, material={"texture": True}))
    assert e.value.key == "objects[0].material.texture" and str(obj) in str(e.value)
    mtl.write_text(mtl_text)
    os.utime(obj, ns=(1, 1))  # meshes are cached by their file's time
    with pytest.raises(ConfigError, match="'tex.png' not found beside the mesh") as e:
        sonarsim.load_scene(scene_with(obj, material={"texture": True}))
    assert e.value.key == "objects[0].material.texture"
    mtl.write_text("newmtl skin\nKd 0.5 0.5 0.5\n")
    os.utime(obj, ns=(2, 2))
    with pytest.raises(ConfigError, match="no texture"):
        sonarsim.load_scene(scene_with(obj, material={"texture": True}))
    # Without texture: true the geometry alone is read, as before.
    assert sonarsim.load_scene(scene_with(obj)).objects[0].mesh == str(obj)
    mtl.write_text(mtl_text)
    Image.fromarray(np.full((2, 2), 128, np.uint8)).save(image)
    os.utime(obj, ns=(3, 3))
    assert load_mesh_file(obj, texture=True).texture.shape == (2, 2)


@pytest.mark.parametrize("which, texture", [("mtl", False), ("mtl", True), ("image", False), ("image", True)])
def test_pipes_named_inside_an_obj_are_refused_not_opened(tmp_path, which, texture):
    obj, mtl, image, mtl_text = write_textured_obj(tmp_path)
    if which == "mtl":
        os.mkfifo(mtl)
        fifo = mtl
    else:
        mtl.write_text(mtl_text)
        os.mkfifo(image)
        fifo = image
    doc = scene_with(obj, material={"texture": True}) if texture else scene_with(obj)
    with pytest.raises(ConfigError, match="not a regular file") as e:
        no_hang(lambda: sonarsim.load_scene(doc), [fifo])
    assert e.value.key in ("objects[0].mesh", "objects[0].material.texture")
    assert str(obj) in str(e.value) and str(fifo) in str(e.value)


def test_a_pipe_as_a_gltf_buffer_is_refused(tmp_path):
    path = tmp_path / "box.gltf"
    trimesh.creation.box().export(path)
    buffers = sorted(tmp_path.glob("*.bin"))
    assert buffers
    buffers[0].unlink()
    os.mkfifo(buffers[0])
    with pytest.raises(MeshFileError, match="not a regular file") as e:
        no_hang(lambda: load_mesh_file(path), buffers[:1])
    assert str(buffers[0]) in str(e.value)
