"""The ``material:`` key of objects, planes and the ground: parsing, validation, round trip.

Every bad document is a valid base with one edit; each error names the key
(``objects[0].material.roughness``), as the rest of the loader does.
"""

from __future__ import annotations

import copy
import json
import math

import pytest
import yaml

from sonarsim import ConfigError, load_scene
from sonarsim.config.materials import Material, mu_from_db
from sonarsim.config.scene import GroundSpec, ObjectSpec, PlaneSpec

BASE = {
    "sonar": {"n_beams": 8, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
              "range_max_m": 4.0, "n_range_bins": 40,
              "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}},
    "ground": {"height_m": 0.0, "material": {"law": "lambert", "mu_db": -27.0}, "specular": 0.5},
    "planes": [{"name": "wall", "point_m": [5.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0],
                "material": {"law": "lambertian", "albedo": 0.3}}],
    "objects": [
        {"name": "hull", "primitive": "box", "size_m": [0.4, 0.4, 0.4], "pose": {"position_m": [2.5, 0.0, 0.2]},
         "material": {"law": "rough", "albedo": 0.3, "specular_strength": 2.0, "roughness": 0.2}},
        {"name": "rock", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [3.0, 0.5, 0.2]},
         "albedo": 0.6},
    ],
}


def edited(path, value):
    doc = copy.deepcopy(BASE)
    node = doc
    for key in path[:-1]:
        node = node[key]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


DELETE = object()


def test_the_base_document_loads_with_its_laws():
    scene = load_scene(BASE)
    assert scene.ground.backscatter.law == "lambert"
    assert scene.ground.backscatter.mu == pytest.approx(10 ** -2.7)
    assert scene.planes[0].backscatter == Material("lambertian", albedo=0.3)
    hull, rock = scene.objects
    assert hull.backscatter.lobe == (2.0, 0.2) and hull.backscatter.coefficient == 0.3
    assert rock.material is None and rock.backscatter == Material.lambertian(0.6)
    # The ground's law reaches the plane it stands for.
    assert scene.reflecting_planes[0].backscatter.law == "lambert"


def test_the_dict_form_round_trips():
    scene = load_scene(BASE)
    d = scene.to_dict()
    assert d["ground"]["material"] == {"law": "lambert", "mu": mu_from_db(-27.0)}
    assert "albedo" not in d["ground"] and "albedo" not in d["objects"][0]
    assert d["objects"][1]["albedo"] == 0.6 and "material" not in d["objects"][1]  # the shorthand stays
    assert d["planes"][0]["material"] == {"law": "lambertian", "albedo": 0.3}
    again = load_scene(json.loads(json.dumps(d)))
    assert again.to_dict() == d
    assert again.objects == scene.objects and again.ground == scene.ground and again.planes == scene.planes
    assert load_scene(yaml.safe_load(yaml.safe_dump(d))).to_dict() == d


def test_a_document_without_materials_keeps_its_dict_form():
    doc = edited(("ground",), {"height_m": 0.0, "albedo": 0.5, "specular": 0.5})
    doc["objects"][0] = {k: v for k, v in doc["objects"][0].items() if k != "material"}
    doc["planes"][0] = {k: v for k, v in doc["planes"][0].items() if k != "material"}
    d = load_scene(doc).to_dict()
    assert d["ground"] == {"height_m": 0.0, "albedo": 0.5, "specular": 0.5}
    assert d["objects"][0]["albedo"] == 0.8 and d["planes"][0]["albedo"] == 0.0
    assert not any("material" in o for o in d["objects"] + d["planes"])


def test_mu_and_mu_db_are_the_same_law():
    a = load_scene(edited(("ground", "material"), {"law": "lambert", "mu_db": -20.0})).ground
    b = load_scene(edited(("ground", "material"), {"law": "lambert", "mu": 0.01})).ground
    assert a.backscatter.mu == pytest.approx(b.backscatter.mu, rel=1e-15)


def test_the_default_law_is_lambertian_with_the_default_albedo():
    obj = load_scene(edited(("objects", 0, "material"), {})).objects[0]
    assert obj.backscatter.law == "lambertian" and obj.backscatter.coefficient == 0.8


BAD = [
    ("albedo and material", ("objects", 0, "albedo"), 0.5, "objects[0].albedo", ["either albedo", "material"]),
    ("ground albedo and material", ("ground", "albedo"), 0.5, "ground.albedo", ["not both"]),
    ("plane albedo and material", ("planes", 0, "albedo"), 0.5, "planes[0].albedo", ["not both"]),
    ("unknown law", ("objects", 0, "material", "law"), "phong", "objects[0].material.law",
     ["lambertian, lambert, rough"]),
    ("law not text", ("objects", 0, "material", "law"), 3, "objects[0].material.law", ["string"]),
    ("unknown key", ("objects", 0, "material", "shininess"), 1.0, "objects[0].material.shininess",
     ["unknown key", "roughness"]),
    ("material not a mapping", ("objects", 0, "material"), "steel", "objects[0].material", ["mapping"]),
    ("negative albedo", ("objects", 0, "material", "albedo"), -0.1, "objects[0].material.albedo", ["[0, 1]"]),
    ("nan albedo", ("objects", 0, "material", "albedo"), math.nan, "objects[0].material.albedo", ["finite"]),
    ("negative strength", ("objects", 0, "material", "specular_strength"), -1.0,
     "objects[0].material.specular_strength", ["[0, 1e+06]"]),
    ("nan strength", ("objects", 0, "material", "specular_strength"), math.nan,
     "objects[0].material.specular_strength", ["finite"]),
    ("inf strength", ("objects", 0, "material", "specular_strength"), math.inf,
     "objects[0].material.specular_strength", ["finite"]),
    ("zero roughness", ("objects", 0, "material", "roughness"), 0.0, "objects[0].material.roughness",
     ["[0.001, 0.5]"]),
    ("negative roughness", ("objects", 0, "material", "roughness"), -0.2, "objects[0].material.roughness",
     ["[0.001, 0.5]"]),
    ("too rough", ("objects", 0, "material", "roughness"), 0.8, "objects[0].material.roughness",
     ["normal incidence"]),
    ("nan roughness", ("objects", 0, "material", "roughness"), math.nan, "objects[0].material.roughness",
     ["finite"]),
    ("rough without roughness", ("objects", 0, "material", "roughness"), DELETE, "objects[0].material.roughness",
     ["required", "rough"]),
    ("rough without strength", ("objects", 0, "material", "specular_strength"), DELETE,
     "objects[0].material.specular_strength", ["required"]),
    ("lambert without mu", ("ground", "material"), {"law": "lambert"}, "ground.material.mu", ["required"]),
    ("mu and mu_db", ("ground", "material", "mu"), 0.01, "ground.material.mu_db", ["not both"]),
    ("positive mu_db", ("ground", "material", "mu_db"), 3.0, "ground.material.mu_db", ["<= -4.97"]),
    ("nan mu_db", ("ground", "material", "mu_db"), math.nan, "ground.material.mu_db", ["finite"]),
    ("negative mu", ("ground", "material"), {"law": "lambert", "mu": -0.01}, "ground.material.mu", ["[0, 1/pi"]),
    ("mu above 1", ("ground", "material"), {"law": "lambert", "mu": 2.0}, "ground.material.mu", ["[0, 1/pi"]),
    ("mu on a lambertian law", ("planes", 0, "material", "mu"), 0.1, "planes[0].material.mu",
     ["not used", "lambertian"]),
    ("mu_db on a rough law", ("objects", 0, "material", "mu_db"), -20.0, "objects[0].material.mu_db", ["not used"]),
    ("albedo on the lambert law", ("ground", "material", "albedo"), 0.3, "ground.material.albedo",
     ["not used", "lambert"]),
    ("roughness on a lambertian law", ("planes", 0, "material", "roughness"), 0.1, "planes[0].material.roughness",
     ["not used"]),
    ("texture on a plane", ("planes", 0, "material", "texture"), True, "planes[0].material.texture",
     ["unknown key"]),
    ("texture on the ground", ("ground", "material", "texture"), True, "ground.material.texture", ["unknown key"]),
    ("texture on a primitive", ("objects", 0, "material", "texture"), True, "objects[0].material.texture",
     ["primitive"]),
    ("texture not a bool", ("objects", 0, "material", "texture"), "yes", "objects[0].material.texture",
     ["true or false"]),
]


@pytest.mark.parametrize("name,path,value,key,words", BAD, ids=[b[0] for b in BAD])
def test_bad_materials_name_the_key(name, path, value, key, words):
    with pytest.raises(ConfigError) as info:
        load_scene(edited(path, value))
    assert info.value.key == key, str(info.value)
    for word in words:
        assert word in str(info.value), (word, str(info.value))


def test_python_callers_get_the_same_checks():
    with pytest.raises(ConfigError, match="albedo.*not both"):
        ObjectSpec("a", primitive="sphere", radius_m=1.0, albedo=0.3, material=Material.lambertian(0.3))
    with pytest.raises(ConfigError, match="roughness"):
        Material("rough", specular_strength=1.0, roughness=0.0)
    with pytest.raises(ConfigError) as info:
        GroundSpec(material=Material("lambert", mu=0.1, texture=True))
    assert info.value.key == "ground.material.texture"
    with pytest.raises(ConfigError, match="must be a Material"):
        PlaneSpec("wall", material={"law": "lambert"})
    # The ground as a plane carries its law (and the plane's default albedo beside it).
    plane = GroundSpec(material=Material("lambert", mu=0.01))
    assert plane.backscatter == Material("lambert", mu=0.01)


def test_the_example_scene_loads_renders_and_round_trips():
    from pathlib import Path

    import sonarsim

    path = Path(__file__).resolve().parents[2] / "examples" / "materials.yaml"
    scene = load_scene(path)
    assert [o.backscatter.law for o in scene.objects] == ["rough", "lambertian"]
    assert scene.ground.backscatter.law == "lambert" and scene.planes[0].backscatter.law == "rough"
    img = sonarsim.render(scene)
    assert img.components["ground"].any() and img.components["object"].any()
    assert load_scene(img.config).to_dict() == img.config
