"""Gazebo worlds (sonarsim.config.sdf): SDF models, links and visuals as scene objects.

Geometry is checked against world-space bounds computed by hand; the rendered image of a world
against the same scene written as scene-file objects; every refusal names what it refuses.
Every file is written into tmp_path by the test.
"""

from __future__ import annotations

import math
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from sonarsim.config.loader import load_scene, scene_from_dict
from sonarsim.config.sdf import MAX_NESTING, UnmappedMaterialWarning, WorldSpec, load_sdf_world, read_sdf_world
from sonarsim.errors import ConfigError
from sonarsim.scene.meshes import object_mesh_world


@pytest.fixture(autouse=True)
def _no_environment_model_path(monkeypatch):
    # The machine's own Gazebo model path must not change what a test reads.
    for var in ("GZ_SIM_RESOURCE_PATH", "IGN_GAZEBO_RESOURCE_PATH", "GAZEBO_MODEL_PATH"):
        monkeypatch.delenv(var, raising=False)


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text).strip() + "\n")
    return path


def _world(tmp_path: Path, body: str, name: str = "tank.world", version: str = "1.9") -> Path:
    return _write(tmp_path / name, f'<?xml version="1.0"?>\n<sdf version="{version}"><world name="w">'
                  f"{textwrap.dedent(body)}</world></sdf>")


def _box_model(name: str, pose: str, size: str = "1 1 1", link_pose: str = "0 0 0 0 0 0",
               material: str = "") -> str:
    return (f'<model name="{name}"><static>true</static><pose>{pose}</pose><link name="link">'
            f'<pose>{link_pose}</pose><visual name="visual"><geometry><box><size>{size}</size></box></geometry>'
            f"{material}</visual></link></model>")


SONAR = {"azimuth_fov_deg": 30.0, "n_beams": 32, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
         "range_max_m": 5.0, "n_range_bins": 200, "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}}


def _bounds(obj) -> tuple[np.ndarray, np.ndarray]:
    v = object_mesh_world(obj).vertices
    return v.min(axis=0), v.max(axis=0)


def _quiet(fn, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnmappedMaterialWarning)
        return fn(*args, **kwargs)


# Geometry ----------------------------------------------------------------------------------

def test_a_box_at_a_pose_with_a_rotated_link_lands_where_computed_by_hand(tmp_path):
    # Model at (1, 2, 0.5) turned 90 degrees about z; its link 0.5 m along the model's x and
    # rolled 90 degrees about x. The box is 1 x 0.2 x 0.4 in the link's axes.
    # World rotation Rz(90) Rx(90): link x -> world y, link y -> world z, link z -> world x.
    # Link origin: (1, 2, 0.5) + Rz(90) (0.5, 0, 0) = (1, 2.5, 0.5).
    # Extents in the world: x 0.4, y 1, z 0.2.
    path = _world(tmp_path, _box_model("block", f"1 2 0.5 0 0 {math.pi / 2}", "1 0.2 0.4",
                                       f"0.5 0 0 {math.pi / 2} 0 0"))
    objects = _quiet(load_sdf_world, path)
    assert [o["name"] for o in objects] == ["block"]
    scene = scene_from_dict({"sonar": SONAR, "objects": objects})
    lo, hi = _bounds(scene.objects[0])
    np.testing.assert_allclose(lo, [0.8, 2.0, 0.4], atol=1e-9)
    np.testing.assert_allclose(hi, [1.2, 3.0, 0.6], atol=1e-9)


def test_one_pose_turns_roll_then_pitch_then_yaw_about_fixed_axes(tmp_path):
    # SDF's rpy is sonarsim's: R = Rz(yaw) Ry(pitch) Rx(roll). Roll 90 then yaw 90 turns the
    # box's x (1 m) onto y, its y (0.2 m) onto z and its z (0.4 m) onto x; the other order
    # (Rx Rz) would stand the 1 m edge upright.
    path = _world(tmp_path, _box_model("b", f"0 0 0 {math.pi / 2} 0 {math.pi / 2}", "1 0.2 0.4"))
    lo, hi = _bounds(scene_from_dict({"sonar": SONAR, "objects": _quiet(load_sdf_world, path)}).objects[0])
    np.testing.assert_allclose(hi - lo, [0.4, 1.0, 0.2], atol=1e-9)


def test_sphere_cylinder_and_visual_pose_compose(tmp_path):
    body = ('<model name="m"><pose>0 0 1 0 0 0</pose><link name="l"><pose>1 0 0 0 0 0</pose>'
            '<visual name="ball"><pose>0 1 0 0 0 0</pose><geometry><sphere><radius>0.25</radius></sphere></geometry></visual>'
            '<visual name="post"><pose>0 0 0 0 1.5707963267948966 0</pose><geometry><cylinder><radius>0.1</radius>'
            '<length>2</length></cylinder></geometry></visual></link></model>')
    objects = _quiet(load_sdf_world, _world(tmp_path, body))
    by_name = {o["name"]: o for o in objects}
    assert set(by_name) == {"m::l::ball", "m::l::post"}  # a model of two visuals: scoped names
    scene = scene_from_dict({"sonar": SONAR, "objects": objects})
    ball, post = scene.objects
    np.testing.assert_allclose(ball.pose.position_m, [1, 1, 1], atol=1e-12)
    assert ball.radius_m == 0.25
    # The cylinder (axis z, length 2) pitched 90 degrees lies along x: x in [0, 2], y and z +-0.1 about (1, 0, 1).
    lo, hi = _bounds(post)
    np.testing.assert_allclose([lo[0], hi[0]], [0.0, 2.0], atol=1e-9)
    assert abs(lo[2] - 0.9) < 1e-3 and abs(hi[2] - 1.1) < 1e-3


def test_pose_in_degrees_and_quaternions(tmp_path):
    body = ('<model name="a"><pose degrees="true">0 0 0 0 0 90</pose><link name="l"><visual name="v"><geometry>'
            '<box><size>2 0.2 0.2</size></box></geometry></visual></link></model>'
            '<model name="b"><pose rotation_format="quat_xyzw">0 5 0 0 0 0.7071067811865476 0.7071067811865476</pose>'
            '<link name="l"><visual name="v"><geometry><box><size>2 0.2 0.2</size></box></geometry></visual>'
            '</link></model>')
    scene = scene_from_dict({"sonar": SONAR, "objects": _quiet(load_sdf_world, _world(tmp_path, body))})
    for obj, y in zip(scene.objects, (0.0, 5.0)):
        lo, hi = _bounds(obj)  # the long axis turned onto y
        np.testing.assert_allclose(lo, [-0.1, y - 1, -0.1], atol=1e-9)
        np.testing.assert_allclose(hi, [0.1, y + 1, 0.1], atol=1e-9)


def test_an_included_model_comes_from_the_model_path_with_its_pose_composed(tmp_path, monkeypatch):
    models = tmp_path / "models"
    _write(models / "crate" / "model.config", '<?xml version="1.0"?><model><name>crate</name>'
           '<sdf version="1.6">crate.sdf</sdf></model>')
    # The model's own pose is replaced by the include's (SDF's rule); its link's pose is kept.
    _write(models / "crate" / "crate.sdf", '<sdf version="1.6"><model name="crate"><pose>9 9 9 0 0 0</pose>'
           '<link name="body"><pose>0 0 0.25 0 0 0</pose><visual name="v"><geometry><box><size>1 0.5 0.5</size>'
           "</box></geometry></visual></link></model></sdf>")
    # The include sits in a model at (2, 0, 0) turned 90 degrees, at (1, 0, 0) in that model's frame:
    # the crate's frame at (2, 1, 0) turned 90 degrees; its body 0.25 up.
    body = (f'<model name="dock"><pose>2 0 0 0 0 {math.pi / 2}</pose>'
            '<include><uri>model://crate</uri><name>crate_1</name><pose>1 0 0 0 0 0</pose></include></model>')
    world = _world(tmp_path, body)
    objects = _quiet(load_sdf_world, world, model_path=[models])
    assert [o["name"] for o in objects] == ["dock::crate_1"]
    lo, hi = _bounds(scene_from_dict({"sonar": SONAR, "objects": objects}).objects[0])
    np.testing.assert_allclose(lo, [1.75, 0.5, 0.0], atol=1e-9)
    np.testing.assert_allclose(hi, [2.25, 1.5, 0.5], atol=1e-9)
    # The same from the environment's model path, and a folder without model.config (model.sdf).
    (models / "crate" / "model.config").unlink()
    (models / "crate" / "crate.sdf").rename(models / "crate" / "model.sdf")
    monkeypatch.setenv("GZ_SIM_RESOURCE_PATH", f"/nonexistent:{models}")
    assert _quiet(load_sdf_world, world) == objects
    with pytest.raises(ConfigError, match="not found on the model path"):
        load_sdf_world(world, use_environment=False)


def test_mesh_uris_resolve_against_the_model_path_and_the_sdf_folder(tmp_path):
    import trimesh

    models = tmp_path / "models"
    (models / "rock" / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(1, 1, 1)).export(models / "rock" / "meshes" / "rock.stl")
    (tmp_path / "meshes").mkdir()
    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "meshes" / "pier.stl")
    body = ('<model name="rock_1"><link name="l"><visual name="v"><geometry><mesh><uri>model://rock/meshes/rock.stl'
            '</uri><scale>2 1 0.5</scale></mesh></geometry></visual></link></model>'
            '<model name="pier"><pose>0 3 0 0 0 0</pose><link name="l"><visual name="v"><geometry><mesh>'
            '<uri>meshes/pier.stl</uri></mesh></geometry></visual></link></model>'
            '<model name="pier2"><pose>0 -3 0 0 0 0</pose><link name="l"><visual name="v"><geometry><mesh>'
            f'<uri>file://{tmp_path / "meshes" / "pier.stl"}</uri></mesh></geometry></visual></link></model>')
    objects = _quiet(load_sdf_world, _world(tmp_path, body), model_path=[models])
    scene = scene_from_dict({"sonar": SONAR, "objects": objects})
    lo, hi = _bounds(scene.objects[0])
    np.testing.assert_allclose(hi - lo, [2.0, 1.0, 0.5], atol=1e-9)
    np.testing.assert_allclose(_bounds(scene.objects[1])[0], [-0.5, 2.5, -0.5], atol=1e-9)
    np.testing.assert_allclose(_bounds(scene.objects[2])[0], [-0.5, -3.5, -0.5], atol=1e-9)


# Collada -----------------------------------------------------------------------------------

def _collada(path: Path, up_axis: str, meter: float) -> Path:
    """A hand-written Collada file: one triangle with its corners at (100, 0, 0), (0, 200, 0)
    and (0, 0, 300) in the file's units, placed by a node without a transform."""
    return _write(path, f"""
        <?xml version="1.0" encoding="utf-8"?>
        <COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
          <asset><unit name="u" meter="{meter}"/><up_axis>{up_axis}</up_axis></asset>
          <library_geometries>
            <geometry id="tri" name="tri"><mesh>
              <source id="tri-pos">
                <float_array id="tri-pos-array" count="9">100 0 0 0 200 0 0 0 300</float_array>
                <technique_common><accessor source="#tri-pos-array" count="3" stride="3">
                  <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
                </accessor></technique_common>
              </source>
              <vertices id="tri-vtx"><input semantic="POSITION" source="#tri-pos"/></vertices>
              <triangles count="1"><input semantic="VERTEX" source="#tri-vtx" offset="0"/><p>0 1 2</p></triangles>
            </mesh></geometry>
          </library_geometries>
          <library_visual_scenes>
            <visual_scene id="scene"><node id="n" name="n">
              <instance_geometry url="#tri"/>
            </node></visual_scene>
          </library_visual_scenes>
          <scene><instance_visual_scene url="#scene"/></scene>
        </COLLADA>""")


def test_collada_y_up_in_centimetres_comes_out_in_metres_z_up(tmp_path):
    pytest.importorskip("collada")
    from sonarsim.config.meshfiles import load_mesh_file

    # Y_UP: the file's y is up and its z toward the viewer; in sonarsim's z-up world the file's
    # (x, y, z) is (x, -z, y). Centimetres: 0.01 m a unit.
    mesh = load_mesh_file(_collada(tmp_path / "tri_y.dae", "Y_UP", 0.01))
    got = {tuple(np.round(v, 9)) for v in mesh.vertices}
    assert got == {(1.0, 0.0, 0.0), (0.0, 0.0, 2.0), (0.0, -3.0, 0.0)}
    mesh_z = load_mesh_file(_collada(tmp_path / "tri_z.dae", "Z_UP", 1.0))
    assert {tuple(np.round(v, 9)) for v in mesh_z.vertices} == {(100.0, 0, 0), (0, 200.0, 0), (0, 0, 300.0)}
    # Through a world: the mesh of a model, its size in metres.
    body = ('<model name="t"><link name="l"><visual name="v"><geometry><mesh><uri>tri_y.dae</uri></mesh>'
            '</geometry></visual></link></model>')
    scene = scene_from_dict({"sonar": SONAR, "objects": _quiet(load_sdf_world, _world(tmp_path, body))})
    lo, hi = _bounds(scene.objects[0])
    np.testing.assert_allclose(lo, [0, -3, 0], atol=1e-9)
    np.testing.assert_allclose(hi, [1, 0, 2], atol=1e-9)


def test_collada_exported_by_trimesh_reads_back(tmp_path):
    pytest.importorskip("collada")
    import trimesh

    from sonarsim.config.meshfiles import load_mesh_file

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    path = tmp_path / "box.dae"
    path.write_bytes(trimesh.exchange.dae.export_collada(box))
    # trimesh writes no up_axis (the spec's default, Y_UP): its y (2 m) becomes sonarsim's z.
    lo, hi = load_mesh_file(path).vertices.min(axis=0), load_mesh_file(path).vertices.max(axis=0)
    np.testing.assert_allclose(hi - lo, [1.0, 3.0, 2.0], atol=1e-9)


def test_collada_with_a_doctype_is_refused_before_pycollada_reads_it(tmp_path):
    pytest.importorskip("collada")
    from sonarsim.config.meshfiles import load_mesh_file
    from sonarsim.errors import MeshFileError

    text = _collada(tmp_path / "a.dae", "Z_UP", 1.0).read_text()
    bomb = tmp_path / "bomb.dae"
    bomb.write_text(text.replace('<?xml version="1.0" encoding="utf-8"?>',
                                 '<?xml version="1.0"?><!DOCTYPE c [<!ENTITY a "aaaaaaaa">]>'))
    with pytest.raises(MeshFileError, match="document type declaration"):
        load_mesh_file(bomb)


def test_a_dae_that_is_not_collada_is_refused_by_name(tmp_path):
    pytest.importorskip("collada")
    from sonarsim.config.meshfiles import load_mesh_file
    from sonarsim.errors import MeshFileError

    obj = tmp_path / "obj.dae"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshFileError, match=r"obj.dae: not well-formed XML"):
        load_mesh_file(obj)
    other = _write(tmp_path / "other.dae", "<sdf version='1.6'/>")
    with pytest.raises(MeshFileError, match=r"other.dae: not a Collada file: the root element is <sdf>"):
        load_mesh_file(other)
    text = _collada(tmp_path / "u.dae", "Z_UP", 1.0).read_text()
    bad = tmp_path / "bad_unit.dae"
    bad.write_text(text.replace('meter="1.0"', 'meter="-2"'))
    with pytest.raises(MeshFileError, match=r"<unit meter='-2'> must be a positive number"):
        load_mesh_file(bad)


def test_a_doctype_hidden_in_utf16_is_refused():
    from sonarsim.config.xmlfiles import XmlFileError, parse_xml

    doc = '<?xml version="1.0" encoding="utf-16"?><!DOCTYPE a [<!ENTITY e "x">]><a>&e;</a>'.encode("utf-16")
    with pytest.raises(XmlFileError, match="document type declaration"):
        parse_xml(doc, "x.world")


def test_a_missing_pycollada_names_the_extra(tmp_path, monkeypatch):
    import importlib

    from sonarsim.config import meshfiles

    real = importlib.import_module

    def no_collada(name, *args, **kwargs):
        if name == "collada":
            raise ImportError("No module named 'collada'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", no_collada)
    with pytest.raises(meshfiles.MeshFileError, match=r"pycollada.*gazebo"):
        meshfiles._load_mesh_file_cached(str(_collada(tmp_path / "x.dae", "Z_UP", 1.0)), 0, 1)


# Rendering: a world and the same scene written by hand ------------------------------------

def test_a_rendered_world_equals_the_same_scene_written_as_objects(tmp_path):
    import trimesh

    from sonarsim.renderer.simulator import render

    trimesh.creation.icosphere(subdivisions=2, radius=0.3).export(tmp_path / "ball.stl")
    body = ('<include><uri>model://ground_plane</uri></include><include><uri>model://sun</uri></include>'
            + _box_model("block", f"2.5 0.3 0.15 0 0 {math.radians(30)}", "0.5 0.5 0.3",
                         material="<material><script><name>Gazebo/Bricks</name></script></material>")
            + '<model name="ball"><pose>3.5 -0.4 0.3 0 0 0</pose><link name="l"><visual name="v"><geometry>'
              '<mesh><uri>ball.stl</uri></mesh></geometry></visual></link></model>')
    _world(tmp_path, body)
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(yaml.safe_dump({"sonar": SONAR, "world": {"sdf": "tank.world",
                                          "materials": {"ball": {"albedo": 0.5}}}}))
    from_world = _quiet(load_scene, scene_file)
    assert from_world.ground is not None and from_world.ground.point_m[2] == 0.0
    by_hand = scene_from_dict({
        "sonar": SONAR, "ground": {"height_m": 0.0},
        "objects": [
            {"name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.3], "material": {"preset": "concrete"},
             "pose": {"position_m": [2.5, 0.3, 0.15], "rpy_deg": [0, 0, 30]}},
            {"name": "ball", "mesh": str(tmp_path / "ball.stl"), "albedo": 0.5,
             "pose": {"position_m": [3.5, -0.4, 0.3]}},
        ]})
    a = render(from_world, speckle=False).polar
    b = render(by_hand, speckle=False).polar
    assert a.max() > 0 and (a > 0).sum() > 50  # the objects and the ground are in view
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7 * float(b.max()))
    # The objects are in view: without them the image differs.
    ground_only = render(scene_from_dict({"sonar": SONAR, "ground": {"height_m": 0.0}}), speckle=False).polar
    assert np.abs(a - ground_only).max() > 0.1 * float(a.max())


def test_a_scene_ground_wins_over_the_world_plane_and_null_removes_it(tmp_path):
    _world(tmp_path, '<model name="ground_plane"><static>true</static><pose>0 0 -2 0 0 0</pose><link name="link">'
           '<visual name="visual"><geometry><plane><normal>0 0 1</normal><size>100 100</size></plane></geometry>'
           '</visual></link></model>' + _box_model("b", "3 0 0 0 0 0"))
    base = {"sonar": SONAR, "world": {"sdf": "tank.world", "materials": {"b": {"material": "steel"}}}}
    s = scene_from_dict(base, tmp_path)
    assert s.ground.point_m[2] == -2.0 and [o.name for o in s.objects] == ["b"]
    assert s.objects[0].material.preset == "steel"
    assert scene_from_dict({**base, "ground": {"height_m": -1.0}}, tmp_path).ground.point_m[2] == -1.0
    assert scene_from_dict({**base, "ground": None}, tmp_path).ground is None


# Materials ---------------------------------------------------------------------------------

def test_the_material_table_and_the_overrides(tmp_path):
    body = (_box_model("a", "1 0 0 0 0 0", material="<material><script><name>Gazebo/WoodPallet</name></script>"
                       "</material>")
            + _box_model("rock_7", "2 0 0 0 0 0")  # the model's name says rock
            + _box_model("c", "3 0 0 0 0 0", material="<material><script><name>Gazebo/Grey</name></script></material>")
            + _box_model("d", "4 0 0 0 0 0")
            + _box_model("e", "5 0 0 0 0 0", material="<material><script><name>Gazebo/Bricks</name></script>"
                         "</material>"))
    path = _world(tmp_path, body)
    with pytest.warns(UnmappedMaterialWarning, match=r"2 visual\(s\).*c::link::visual, d::link::visual") as record:
        world = read_sdf_world(WorldSpec(path, materials={"e::link::visual": {"albedo": 0.3}}))
    assert len(record) == 1  # once, listing them all
    mats = {o["name"]: o.get("material", o.get("albedo")) for o in world.objects}
    assert mats == {"a": {"preset": "wood"}, "rock_7": {"preset": "rock"}, "c": None, "d": None, "e": 0.3}
    assert world.unmapped == ("c::link::visual", "d::link::visual")
    # A model's override covers its visuals; the visual's own comes first.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        w2 = read_sdf_world(WorldSpec(path, materials={"c": {"material": "rubber"}, "d": {"material": {"law": "lambert",
                                                                                                    "mu": 0.01}}}))
    mats = {o["name"]: o.get("material") for o in w2.objects}
    assert mats["c"] == {"preset": "rubber"} and mats["d"] == {"law": "lambert", "mu": 0.01}


def test_overrides_and_skips_that_name_nothing_are_refused(tmp_path):
    path = _world(tmp_path, _box_model("a", "1 0 0 0 0 0"))
    with pytest.raises(ConfigError, match=r"world.materials.nope: .*no model, link or visual of that name.*a::link"):
        _quiet(read_sdf_world, WorldSpec(path, materials={"nope": {"albedo": 0.2}}))
    with pytest.raises(ConfigError, match=r"world.skip: .*no model named 'gone'"):
        _quiet(read_sdf_world, WorldSpec(path, skip=("gone",)))
    with pytest.raises(ConfigError, match=r"world.materials.a.colour: unknown key; allowed: material, albedo"):
        read_sdf_world(WorldSpec(path, materials={"a": {"colour": 1}}))
    with pytest.raises(ConfigError, match=r"unknown material 'unobtainium'"):
        read_sdf_world(WorldSpec(path, materials={"a": {"material": "unobtainium"}}))
    assert _quiet(load_sdf_world, path, skip=["a"]) == []


# The scene-file section --------------------------------------------------------------------

def test_world_section_keys_are_checked(tmp_path):
    _world(tmp_path, _box_model("a", "1 0 0 0 0 0"))
    with pytest.raises(ConfigError, match=r"world.sdfs: unknown key; allowed keys of world: sdf, model_path"):
        scene_from_dict({"sonar": SONAR, "world": {"sdfs": "tank.world"}}, tmp_path)
    with pytest.raises(ConfigError, match=r"world.sdf: required"):
        scene_from_dict({"sonar": SONAR, "world": {}}, tmp_path)
    with pytest.raises(ConfigError, match=r"world.model_path\[0\]: .*not a folder"):
        scene_from_dict({"sonar": SONAR, "world": {"sdf": "tank.world", "model_path": "nowhere"}}, tmp_path)
    with pytest.raises(ConfigError, match=r"world: .*'a' has the name of one of the scene's objects"):
        _quiet(scene_from_dict, {"sonar": SONAR, "world": {"sdf": "tank.world"},
                                 "objects": [{"name": "a", "primitive": "sphere", "radius_m": 0.1}]}, tmp_path)
    # A bad value from an override names the override.
    with pytest.raises(ConfigError, match=r"world.materials: .*tank.world: model 'a': albedo: "):
        scene_from_dict({"sonar": SONAR, "world": {"sdf": "tank.world", "materials": {"a": {"albedo": 7}}}}, tmp_path)
    # And one for the ground plane names it.
    _world(tmp_path, '<include><uri>model://ground_plane</uri></include>')
    with pytest.raises(ConfigError, match=r"world.materials: .*the ground plane: ground.albedo"):
        scene_from_dict({"sonar": SONAR, "world": {"sdf": "tank.world", "materials": {"ground_plane": {"albedo": 7}}}},
                        tmp_path)


def test_world_objects_join_the_scene_objects(tmp_path):
    _world(tmp_path, _box_model("a", "1 0 0 0 0 0") + _box_model("sun", "0 0 0 0 0 0"))
    scene = _quiet(scene_from_dict, {"sonar": SONAR, "world": {"sdf": "tank.world", "skip": ["sun"]},
                                     "objects": [{"name": "own", "primitive": "sphere", "radius_m": 0.1}]}, tmp_path)
    assert [o.name for o in scene.objects] == ["own", "a"]


# Refusals ----------------------------------------------------------------------------------

@pytest.mark.parametrize("kind, xml", [
    ("heightmap", "<heightmap><uri>h.png</uri></heightmap>"),
    ("polyline", "<polyline><point>0 0</point><height>1</height></polyline>"),
    ("capsule", "<capsule><radius>1</radius><length>1</length></capsule>"),
    ("ellipsoid", "<ellipsoid><radii>1 2 3</radii></ellipsoid>"),
])
def test_unread_geometries_are_refused_by_name(tmp_path, kind, xml):
    path = _world(tmp_path, f'<model name="m"><link name="l"><visual name="v"><geometry>{xml}</geometry></visual>'
                  "</link></model>")
    with pytest.raises(ConfigError, match=rf"tank.world: m::l::v: geometry <{kind}> is not read; read: mesh, box, "
                                          "sphere, cylinder, plane"):
        load_sdf_world(path)


@pytest.mark.parametrize("pose, message", [
    ("1 2 3", r"<pose> must be 6 finite numbers, x y z roll pitch yaw"),
    ("1 2 3 a b c", r"<pose> must be 6 finite numbers"),
    ("1 2 3 0 0 nan", r"<pose> must be 6 finite numbers"),
    ("1e9 0 0 0 0 0", r"<pose> position .* lies beyond"),
])
def test_malformed_poses_are_refused(tmp_path, pose, message):
    with pytest.raises(ConfigError, match=r"tank.world: m: " + message):
        load_sdf_world(_world(tmp_path, _box_model("m", pose)))


def test_poses_relative_to_other_frames_are_refused(tmp_path):
    body = ('<model name="m"><frame name="f"/><link name="l"><pose relative_to="f">0 0 0 0 0 0</pose>'
            '<visual name="v"><geometry><box><size>1 1 1</size></box></geometry></visual></link></model>')
    with pytest.raises(ConfigError, match=r"m::l: <pose relative_to='f'> is not read"):
        load_sdf_world(_world(tmp_path, body))
    ok = body.replace('relative_to="f"', 'relative_to="__model__"')
    assert len(_quiet(load_sdf_world, _world(tmp_path, ok))) == 1


def test_includes_not_on_the_model_path_name_the_folders_searched(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    path = _world(tmp_path, "<include><uri>model://wreck</uri></include>")
    with pytest.raises(ConfigError, match=rf"wreck: model 'model://wreck' not found on the model path; folders "
                                          rf"searched: {models}"):
        load_sdf_world(path, model_path=[models])
    with pytest.raises(ConfigError, match=r"folders searched: none \(give world.model_path or set GZ_SIM_RESOURCE_PATH"):
        load_sdf_world(path)
    path = _world(tmp_path, "<include><uri>https://fuel.gazebosim.org/1.0/x/models/wreck</uri></include>")
    with pytest.raises(ConfigError, match=r"only model://, package://, file:// and paths are read"):
        load_sdf_world(path)


def test_a_missing_or_unreadable_mesh_is_refused(tmp_path):
    body = ('<model name="m"><link name="l"><visual name="v"><geometry><mesh><uri>{}</uri></mesh></geometry>'
            "</visual></link></model>")
    with pytest.raises(ConfigError, match=r"m::l::v: mesh 'missing.stl' not found"):
        load_sdf_world(_world(tmp_path, body.format("missing.stl")))
    (tmp_path / "junk.stl").write_bytes(b"not a mesh at all")
    _world(tmp_path, body.format("junk.stl"))
    with pytest.raises(ConfigError, match=r"world: .*model 'm': mesh: .*junk.stl"):
        _quiet(scene_from_dict, {"sonar": SONAR, "world": {"sdf": "tank.world"}}, tmp_path)
    with pytest.raises(ConfigError, match=r"<mesh><submesh> is not read"):
        load_sdf_world(_world(tmp_path, body.format("junk.stl").replace("</uri>", "</uri><submesh><name>a</name>"
                                                                               "</submesh>")))


def test_files_that_are_not_sdf_are_refused(tmp_path):
    robot = _write(tmp_path / "r.urdf", '<robot name="r"><link name="l"/></robot>')
    with pytest.raises(ConfigError, match=r"r.urdf: not an SDF file: the root element is <robot>.*URDF"):
        load_sdf_world(robot)
    with pytest.raises(ConfigError, match=r"SDF version '1.0' is not read; allowed: 1.4 to 1.12"):
        load_sdf_world(_world(tmp_path, "", version="1.0"))
    with pytest.raises(ConfigError, match=r"not well-formed XML"):
        load_sdf_world(_write(tmp_path / "bad.world", "<sdf version='1.6'><world>"))
    bomb = _write(tmp_path / "bomb.world", '<?xml version="1.0"?><!DOCTYPE sdf [<!ENTITY a "aaaa">]>'
                  '<sdf version="1.6"><world name="w">&a;</world></sdf>')
    with pytest.raises(ConfigError, match=r"document type declaration"):
        load_sdf_world(bomb)
    with pytest.raises(ConfigError, match=r"SDF file not found"):
        load_sdf_world(tmp_path / "nothing.world")


def test_too_large_a_file_is_refused_before_reading(tmp_path, monkeypatch):
    from sonarsim.config import sdf

    path = _world(tmp_path, _box_model("a", "0 0 0 0 0 0"))
    monkeypatch.setattr(sdf, "MAX_SDF_BYTES", 100)
    with pytest.raises(ConfigError, match=r"the SDF file is .* MiB; allowed: at most"):
        load_sdf_world(path)


def test_include_loops_and_deep_nesting_are_refused(tmp_path):
    models = tmp_path / "models"
    _write(models / "a" / "model.sdf", '<sdf version="1.7"><model name="a"><include><uri>model://b</uri></include>'
           "</model></sdf>")
    _write(models / "b" / "model.sdf", '<sdf version="1.7"><model name="b"><include><uri>model://a</uri></include>'
           "</model></sdf>")
    with pytest.raises(ConfigError, match=r"the include loops: .*a/model.sdf -> .*b/model.sdf -> .*a/model.sdf"):
        load_sdf_world(_world(tmp_path, "<include><uri>model://a</uri></include>"), model_path=[models])
    deep = "".join(f'<model name="m{i}">' for i in range(MAX_NESTING + 1)) + "</model>" * (MAX_NESTING + 1)
    with pytest.raises(ConfigError, match=rf"nest {MAX_NESTING + 1} deep; allowed: at most {MAX_NESTING}"):
        load_sdf_world(_world(tmp_path, deep))


def test_unread_world_elements_and_planes_that_are_not_the_ground(tmp_path):
    with pytest.raises(ConfigError, match=r"people: <actor> is not read .*world.skip: \[people\]"):
        load_sdf_world(_world(tmp_path, '<actor name="people"/>'))
    assert load_sdf_world(_world(tmp_path, '<actor name="people"/>'), skip=["people"]) == []
    wall = ('<model name="wall"><pose>0 0 0 1.5707963267948966 0 0</pose><link name="l"><visual name="v"><geometry>'
            "<plane><normal>0 0 1</normal></plane></geometry></visual></link></model>")
    with pytest.raises(ConfigError, match=r"wall::l::v: a <plane> facing .* is not read"):
        load_sdf_world(_world(tmp_path, wall))
    two = ('<include><uri>model://ground_plane</uri></include>'
           '<include><name>low</name><uri>model://ground_plane</uri><pose>0 0 -1 0 0 0</pose></include>')
    with pytest.raises(ConfigError, match=r"low: a second ground plane at z = -1 m"):
        load_sdf_world(_world(tmp_path, two))


def test_the_cli_prints_one_line_for_a_bad_world(tmp_path, capsys):
    from sonarsim.cli.main import main

    _world(tmp_path, '<model name="m"><link name="l"><visual name="v"><geometry><heightmap/></geometry>'
           "</visual></link></model>")
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump({"sonar": SONAR, "world": {"sdf": "tank.world"}}))
    code = main(["render", str(scene), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and "geometry <heightmap> is not read" in err and "scene.yaml" in err
