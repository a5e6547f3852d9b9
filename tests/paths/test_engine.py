"""The path engine on the ground-only case: the paper's four paths, their names, and the orders
each method forms. (Its images against the literal Algorithm 2 and the brute-force reference:
``tests/reference/``.)"""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.config.examples import demo_scene_dict
from sonarsim.paths.engine import parse_path_name, path_name
from tests.reference.test_algorithm2 import _scenes as ground_scenes


def _scenes():
    # The ground-only scenes the literal Algorithm 2 is checked on, and the render options.
    base = ground_scenes()
    out = {k: base[k] for k in ("demo", "rolled", "crossing")}
    for key, value in (("range_splat", False), ("tvg", False), ("double_beam", "split"),
                       ("double_line_of_sight", True), ("beam_pattern", "gaussian")):
        d = copy.deepcopy(base["rolled"])
        d["render"][key] = value
        out[f"{key}={value}"] = d
    return out


def test_ground_only_signatures_are_the_paper_paths():
    doc = demo_scene_dict()
    doc["render"]["double_beam"] = "paper"
    img = sonarsim.render(doc)
    c = img.components
    assert set(c.signatures) == {"O-[objects]-O", "O-[ground]-O", "O-[objects]-ground-O",
                                 "O-ground-[objects]-ground-O"}
    for sig, name in (("O-[objects]-O", "object"), ("O-[ground]-O", "ground"),
                      ("O-[objects]-ground-O", "double"), ("O-ground-[objects]-ground-O", "triple")):
        np.testing.assert_allclose(c[sig], c[name], rtol=1e-5, atol=1e-6 * c[name].max())


@pytest.mark.parametrize("tx, at, rx", [([], "objects", []), (["ground"], "objects", ["ground"]),
                                        (["surface", "ground"], "far_wall", ["left_wall"]), ([], "ground", ["surface"])])
def test_path_names_read_back(tx, at, rx):
    name = path_name(tx, at, rx)
    assert parse_path_name(name) == (tx, at, rx)
    assert name.startswith("O-") and name.endswith("-O") and f"[{at}]" in name


def test_a_path_name_is_written_as_the_sound_travels():
    # Transmit via the surface, scatter on the floor, receive via a wall: the receive chain is
    # listed from the sonar outwards, so it is reversed in the name.
    assert path_name(["surface"], "ground", ["left_wall", "surface"]) == "O-surface-[ground]-surface-left_wall-O"
    with pytest.raises(ValueError):
        parse_path_name("ground")


@pytest.mark.parametrize("max_order", [1, 2, 3, 4])
def test_max_order_bounds_the_ground_paths_in_both_methods(max_order):
    # A ground alone makes paths up to order 3: order 4 adds nothing, order 2 drops the triple.
    images = {}
    for method in ("fast", "paper"):
        doc = demo_scene_dict()
        doc["render"].update(max_order=max_order, method=method, double_beam="paper")
        doc["render"].pop("bounces")
        images[method] = sonarsim.render(doc).components
    fast, paper = images["fast"], images["paper"]
    names = {"single", "double", "triple", "order4"}
    assert {k for k in fast if k in names} == {"single", "double", "triple", "order4"}.intersection(
        ["single", "double", "triple", "order4"][:max_order])
    assert sorted(fast) == sorted(paper)
    for key in fast:
        assert np.abs(fast[key] - paper[key]).sum() <= 1e-3 * max(paper[key].sum(), 1e-12), key
    if max_order >= 2:
        assert fast["double"].any()
    if max_order == 4:
        assert not fast["order4"].any()


def test_method_paper_refuses_planes_beyond_the_ground():
    doc = demo_scene_dict()
    doc["render"]["method"] = "paper"
    doc["planes"] = [{"name": "surface", "point_m": [0, 0, 2], "normal": [0, 0, -1]}]
    with pytest.raises(sonarsim.ConfigError, match="render.method.*surface"):
        sonarsim.load_scene(doc)


def test_method_paper_refuses_the_separate_convention():
    doc = demo_scene_dict()
    doc["render"].update(method="paper", double_beam="separate")
    with pytest.raises(sonarsim.ConfigError, match="render.double_beam"):
        sonarsim.load_scene(doc)


def test_a_normal_given_the_wrong_way_round_is_warned_about():
    # The water surface written with its normal up: the sonar is on its "dry" side, and every
    # object (below it) is clipped away. Both are almost always a mistake: say so, by name.
    doc = demo_scene_dict()
    doc["planes"] = [{"name": "surface", "point_m": [0, 0, 2], "normal": [0, 0, 1]}]
    with pytest.warns(UserWarning) as record:
        sonarsim.Simulator(doc)
    text = " ".join(str(w.message) for w in record)
    assert "dry side of the planes 'surface'" in text and "'concrete_block'" in text


def test_signature_images_are_never_empty():
    from sonarsim.config.examples import tank_scene_dict

    doc = tank_scene_dict()
    doc["sonar"].update(n_beams=48, n_range_bins=300)
    img = sonarsim.render(doc)
    assert img.components.signatures
    assert all(img.components[k].any() for k in img.components.signatures)


def test_one_thread_and_two_give_the_same_tank_images():
    # The compiled frame casts the reflected rays on both cores (a share each) while one forms
    # the direct image: the images must not depend on it.
    from sonarsim.config.examples import tank_scene_dict

    doc = tank_scene_dict()
    doc["sonar"].update(n_beams=48, n_range_bins=300)
    two = sonarsim.Simulator(doc).render()
    doc["render"]["threads"] = 1
    one = sonarsim.Simulator(doc).render()
    assert sorted(one.components) == sorted(two.components)
    for key in two.components:
        np.testing.assert_array_equal(one.components[key], two.components[key])
