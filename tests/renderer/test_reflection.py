"""Mirrors that reflect by the physics (``reflection:``): each reflection of a path scaled by
the Rayleigh coefficient of the mirror's medium at that reflection's grazing angle and the
roughness loss of its rms height, in both kernels and the brute-force reference, on planes, the
ground, the water surface and mesh mirrors."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.config.materials import Reflection
from sonarsim.reference.brute_force import render_reference
from tests.conftest import sonar_dict
from tests.reference.test_brute_force import L1_TOLERANCE, compare, tank_dict


def ball_over_ground(ground: dict) -> dict:
    """A 5 cm ball 0.8 m above the ground, 3 m ahead of a sonar 1.5 m up pitched down 20 degrees:
    its ground paths reflect at grazing ``asin(2.3 / hypot(3, 2.3))`` (37.5 degrees)."""
    return {"sonar": sonar_dict(pose={"position_m": [0.0, 0.0, 1.5], "rpy_deg": [0.0, 20.0, 0.0]},
                                elevation_fov_deg=40.0, frequency_khz=600.0),
            "render": {"elevation_samples": 200, "max_order": 3, "double_beam": "coherent"},
            "ground": {"height_m": 0.0, **({} if "material" in ground else {"albedo": 0.0}), **ground},
            "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.05,
                         "pose": {"position_m": [3.0, 0.0, 0.8]}}]}


def test_each_ground_reflection_scales_a_path_by_the_roughness_loss_at_its_grazing_angle():
    h = 0.4e-3
    flat = sonarsim.render(ball_over_ground({"specular": 1.0})).components
    rough = sonarsim.render(ball_over_ground({"reflection": {"medium": "pressure-release", "rms_height_m": h}}))
    rough = rough.components
    k = 2 * math.pi * 600e3 / 1500.0
    sin_grazing = 2.3 / math.hypot(3.0, 2.3)
    loss = math.exp(-4 * k * k * h * h * sin_grazing**2)  # 0.224
    ratio = {n: rough[n].astype(float).sum() / flat[n].astype(float).sum()
             for n in ("O-[objects]-O", "O-ground-[objects]-O", "O-[objects]-ground-O", "O-ground-[objects]-ground-O")}
    assert ratio["O-[objects]-O"] == pytest.approx(1.0, rel=1e-9)  # no reflection, no loss
    # One reflection: the loss once, traced (receive leg) or by the image source (transmit leg);
    # the ball's lit side spreads the grazing angle by about a degree (3 %).
    assert ratio["O-ground-[objects]-O"] == pytest.approx(loss, rel=0.05)
    assert ratio["O-[objects]-ground-O"] == pytest.approx(loss, rel=0.05)
    assert ratio["O-ground-[objects]-ground-O"] == pytest.approx(loss**2, rel=0.08)


def reflecting_tank(max_order: int = 3, double_beam: str = "coherent") -> dict:
    """The reference tank with a sandy floor, a wind-roughened surface, a rough concrete far wall
    leaning back (a mirror at no right angle to the others: a transmit leg's second incidence
    depends on the first reflection's turn), side walls that mirror by a constant, and a
    steel block that mirrors by its medium."""
    doc = tank_dict(max_order=max_order, double_beam=double_beam)
    doc["sonar"]["frequency_khz"] = 300.0
    doc["ground"] = {"height_m": 0.0, "material": {"law": "sediment", "sediment": "coarse-sand"},
                     "reflection": {"rms_height_m": 0.2e-3}}
    planes = doc["planes"]
    del planes[0]["specular"]
    planes[0]["reflection"] = {"medium": "pressure-release", "wind_speed_m_s": 0.4}
    del planes[1]["specular"]
    planes[1]["reflection"] = {"medium": "concrete", "rms_height_m": 1e-3}
    planes[1]["normal"] = [-1.0, 0.0, 0.3]
    doc["objects"][1].update(material={"preset": "steel"}, reflection={})
    del doc["objects"][1]["albedo"]
    return doc


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_the_fast_paths_reflect_as_the_reference_does(kernels):
    worst = compare(reflecting_tank(), kernels)
    assert worst  # the tank has paths of every order
    # Each pair formed from both sides: transmit legs of two reflections (the direction turned
    # between them) at order 3.
    assert compare(reflecting_tank(double_beam="separate"), kernels)
    # The physics acts: the same tank with every mirror at R = 1 is brighter in each multipath
    # signature through the floor.
    doc = reflecting_tank()
    sim = sonarsim.Simulator(doc, kernels=kernels)
    ref = render_reference(sim)
    for p in doc["planes"]:
        if p.pop("reflection", None) is not None:
            p["specular"] = 1.0
    doc["ground"]["specular"] = 1.0
    doc["ground"].pop("reflection")
    one = render_reference(sonarsim.Simulator(doc, kernels=kernels))
    through_floor = [n for n in ref.signatures if n.startswith("O-ground-[") and ref.signatures[n].sum() > 0]
    assert through_floor
    for n in through_floor:  # (near grazing, below the sand's critical angle, nearly everything)
        assert ref.signatures[n].sum() < 0.99 * one.signatures[n].sum(), n
    total = sum(ref.signatures[n].sum() for n in through_floor)
    assert total < 0.9 * sum(one.signatures[n].sum() for n in through_floor)


def test_a_sediment_plane_reflects_by_its_physics_unless_given_a_constant():
    doc = ball_over_ground({"material": {"law": "sediment", "sediment": "fine-sand"}})
    default = sonarsim.render(doc).components
    explicit = copy.deepcopy(doc)
    explicit["ground"]["reflection"] = {}
    np.testing.assert_array_equal(default["total"], sonarsim.render(explicit).components["total"])
    constant = copy.deepcopy(doc)
    constant["ground"]["specular"] = 1.0
    one = sonarsim.render(constant).components
    a, b = default["O-ground-[objects]-O"].astype(float).sum(), one["O-ground-[objects]-O"].astype(float).sum()
    assert 0 < a < 0.5 * b  # fine sand, 1.5 mm rms, at 600 kHz: most of the coherent reflection lost
    assert load_scene(doc).ground.reflection is not None
    assert load_scene(constant).ground.reflection is None


def test_the_papers_method_keeps_its_constant():
    doc = ball_over_ground({"material": {"law": "sediment", "sediment": "fine-sand"}})
    doc["render"] = {"elevation_samples": 64, "method": "paper"}
    const = copy.deepcopy(doc)
    const["ground"]["specular"] = 1.0
    np.testing.assert_array_equal(sonarsim.render(doc).polar, sonarsim.render(const).polar)


def test_a_mesh_mirror_reflects_by_its_medium_at_each_incidence():
    # A plate (a thin box, mirroring) 1 m behind the ball: the ball's echo via the plate meets
    # it at sin(grazing) = 5 / hypot(5, 0.7) (the ball's image across the plate seen from the
    # sonar), above steel's critical angle (75.5 degrees): |V|^2 of the solid there.
    def plate(material: dict, **mirror) -> dict:
        doc = ball_over_ground({"specular": 0.0})
        doc["objects"].append({"name": "plate", "primitive": "box", "size_m": [0.02, 1.5, 1.0],
                               "pose": {"position_m": [4.0, 0.0, 0.5]}, "material": material, **mirror})
        return doc
    name = "O-[objects]-plate-O"
    rigid = sonarsim.render(plate({"preset": "steel"}, specular=1.0)).components[name].astype(float).sum()
    assert rigid > 0
    c = 5.0 / math.hypot(5.0, 0.7)
    for medium in ("steel", "concrete", "rubber"):
        got = sonarsim.render(plate({"preset": medium}, reflection={"rms_height_m": 0.0})).components[name]
        expected = float(Reflection(medium, rms_height_m=0.0).evaluate(c, None, 600e3, 1500.0))
        assert got.astype(float).sum() / rigid == pytest.approx(expected, rel=0.02), medium
    # rubber is nearly matched to water: a weak mirror
    assert float(Reflection("rubber").evaluate(c, None, 600e3, 1500.0)) < 0.1


def test_reflections_are_refused_with_their_keys():
    base = ball_over_ground({"specular": 1.0})
    both = copy.deepcopy(base)
    both["ground"]["reflection"] = {"medium": "steel"}
    with pytest.raises(ConfigError, match=r"ground\.specular.*not both"):
        load_scene(both)
    lamb = ball_over_ground({"reflection": {}})
    with pytest.raises(ConfigError, match=r"ground\.reflection\.medium"):
        load_scene(lamb)
    bad = ball_over_ground({"reflection": {"medium": "steel", "depth": 3}})
    with pytest.raises(ConfigError, match=r"ground\.reflection\.depth"):
        load_scene(bad)
    obj = copy.deepcopy(base)
    obj["objects"][0]["reflection"] = {"medium": "granite"}
    with pytest.raises(ConfigError, match=r"objects\[0\]\.reflection\.medium"):
        load_scene(obj)
    rough = ball_over_ground({"reflection": {"medium": "steel"}})
    del rough["sonar"]["frequency_khz"]
    with pytest.raises(ConfigError, match="frequency_khz"):
        sonarsim.render(rough)


def test_a_scene_with_reflections_reads_back_as_written():
    scene = load_scene(reflecting_tank())
    again = load_scene(scene.to_dict())
    assert again.ground.reflection == scene.ground.reflection
    assert [p.reflection for p in again.planes] == [p.reflection for p in scene.planes]
    assert [o.reflection for o in again.objects] == [o.reflection for o in scene.objects]
    assert [o.specular for o in again.objects] == [o.specular for o in scene.objects]


def test_the_differentiable_engine_refuses_a_reflection_by_name():
    pytest.importorskip("jax")
    from sonarsim.diff.params import check_diff_laws

    scene = load_scene(ball_over_ground({"reflection": {"medium": "pressure-release", "rms_height_m": 1e-3}}))
    with pytest.raises(ConfigError, match=r"ground\.reflection"):
        check_diff_laws(scene)


def test_l1_tolerance_is_tight():
    assert L1_TOLERANCE <= 1e-3  # the comparisons above are to the reference's own precision
