"""Scene variation: distribution specs (parsing, seeded statistics, draw order, extremes) and
how a variation is drawn into a scene document."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from sonarsim.dataset.variation import (
    Choice, Normal, RandInt, Uniform, Variation, draw, parse_value, parse_variation, probe,
)
from sonarsim.errors import ConfigError

SCENE = {
    "sonar": {"n_beams": 8, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
              "range_max_m": 5.0, "n_range_bins": 50},
    "ground": {"height_m": 0.0, "material": {"law": "lambertian", "albedo": 0.5}, "specular": 0.5},
    "planes": [{"name": "surface", "point_m": [0, 0, 3], "normal": [0, 0, -1], "specular": 0.9},
               {"name": "wall", "point_m": [6, 0, 0], "normal": [-1, 0, 0], "albedo": 0.6}],
    "objects": [{"name": "post", "primitive": "cylinder", "radius_m": 0.1, "height_m": 1.0}],
    "sensor": {"gain_db": 0.0, "noise": {"level_db": 40.0, "after_tvg_db": 20.0}},
}


# Distributions ----------------------------------------------------------------------------

def test_parse_value_builds_templates_at_any_depth():
    t = parse_value({"a": [1, {"uniform": [0, 2]}], "b": {"normal": [1, 0.5], "min": 0}, "c": "x",
                     "d": {"choice": [1, {"randint": [2, 3]}], "weights": [1, 3]}}, "k")
    assert t == {"a": [1, Uniform(0.0, 2.0)], "b": Normal(1.0, 0.5, 0.0, None), "c": "x",
                 "d": Choice((1, RandInt(2, 3)), (1.0, 3.0))}


@pytest.mark.parametrize("value, key, match", [
    ({"uniform": [2, 1]}, "k.uniform", "lower bound"),
    ({"uniform": [0]}, "k.uniform", r"must be \[lo, hi\]"),
    ({"uniform": "0..1"}, "k.uniform", r"must be \[lo, hi\]"),
    ({"uniform": [0, float("inf")]}, "k.uniform[1]", "finite"),
    ({"normal": [0, -1]}, "k.normal", "standard deviation"),
    ({"normal": [0, 1], "min": 2, "max": 1}, "k.max", "below min"),
    ({"randint": [0.5, 2]}, "k.randint", "two integers"),
    ({"randint": [3, 2]}, "k.randint", "lower bound"),
    ({"choice": []}, "k.choice", "non-empty"),
    ({"choice": [1, 2], "weights": [1]}, "k.weights", "list of 2"),
    ({"choice": [1, 2], "weights": [0, 0]}, "k.weights", "not all zero"),
    ({"choice": [1, {"uniform": [1, 0]}]}, "k.choice[1].uniform", "lower bound"),
    ({"uniform": [0, 1], "normal": [0, 1]}, "k", "one distribution"),
    ({"uniform": [0, 1], "seed": 3}, "k.seed", "unknown key"),
    ([{"uniform": [1, 0]}], "k[0].uniform", "lower bound"),
])
def test_bad_distributions_name_the_key(value, key, match):
    with pytest.raises(ConfigError, match=match) as info:
        parse_value(value, "k")
    assert info.value.key == key


def test_seeded_statistics():
    rng = np.random.default_rng(0)
    n = 20000
    u = np.array([draw(Uniform(2.0, 5.0), rng) for _ in range(n)])
    assert u.min() >= 2.0 and u.max() < 5.0
    assert u.mean() == pytest.approx(3.5, abs=4 * 3 / np.sqrt(12 * n))
    g = np.array([draw(Normal(1.0, 2.0, -1.0, None), rng) for _ in range(n)])
    assert g.min() == -1.0  # clipped: about 16 % of the draws sit at the bound
    assert np.mean(g == -1.0) == pytest.approx(0.1587, abs=0.01)
    r = np.array([draw(RandInt(1, 3), rng) for _ in range(n)])
    assert set(np.unique(r)) == {1, 2, 3}
    assert all(isinstance(draw(RandInt(1, 3), rng), int) for _ in range(5))
    c = np.array([draw(Choice(("a", "b"), (3.0, 1.0)), rng) for _ in range(n)])
    assert np.mean(c == "a") == pytest.approx(0.75, abs=4 * np.sqrt(0.75 * 0.25 / n))


def test_draw_order_is_document_order():
    t = parse_value({"z": {"uniform": [0, 1]}, "a": [{"normal": [0, 1]}, {"randint": [0, 9]}],
                     "m": {"choice": [{"uniform": [5, 6]}, 7]}}, "k")
    got = draw(t, np.random.default_rng(42))
    rng = np.random.default_rng(42)
    z = rng.uniform(0, 1)
    a = [rng.normal(0, 1), int(rng.integers(0, 9, endpoint=True))]
    pick = int(rng.choice(2))
    m = rng.uniform(5, 6) if pick == 0 else 7
    assert got == {"z": z, "a": a, "m": m}
    assert all(type(v) is float for v in (got["z"], got["a"][0]))  # plain Python numbers for YAML/JSON


def test_probe_takes_the_ends():
    t = parse_value([{"uniform": [1, 2]}, {"normal": [5, 1]}, {"normal": [5, 1], "min": 3, "max": 8},
                     {"randint": [0, 4]}, {"choice": ["a", {"uniform": [7, 9]}]}], "k")
    assert probe(t, "low") == [1.0, 5.0, 3.0, 0, "a"]
    assert probe(t, "high") == [2.0, 5.0, 8.0, 4, 9.0]


# The variation section ------------------------------------------------------------------

def test_objects_from_pools_with_overrides():
    v = parse_variation({"objects": [{
        "name": "rock", "count": 3,
        "pool": [{"primitive": "sphere", "radius_m": {"uniform": [0.1, 0.2]}, "albedo": 0.3},
                 {"primitive": "box", "size_m": [0.1, 0.1, 0.1], "material": {"law": "lambertian", "albedo": 0.2}}],
        "weights": [1, 1],
        "pose": {"position_m": [{"uniform": [1, 2]}, 0, 0.1]},
        "material": {"law": "lambert", "mu_db": {"uniform": [-20, -10]}},
    }]}, SCENE, None)
    before = copy.deepcopy(SCENE)
    doc, origins = v.apply(SCENE, np.random.default_rng(3))
    assert SCENE == before  # not modified
    objs = doc["objects"]
    assert [o["name"] for o in objs] == ["post", "rock_0", "rock_1", "rock_2"]
    assert origins[0] == "scene.objects[0]" and origins[1].startswith("variation.objects[0].pool[")
    for o in objs[1:]:
        assert "albedo" not in o  # the group's material replaces the entry's albedo
        assert o["material"]["law"] == "lambert" and -20 <= o["material"]["mu_db"] < -10
        assert 1 <= o["pose"]["position_m"][0] < 2 and o["pose"]["position_m"][1:] == [0, 0.1]
        if o["primitive"] == "sphere":
            assert 0.1 <= o["radius_m"] < 0.2


def test_ground_planes_and_sensor_are_merged():
    v = parse_variation({"ground": {"albedo": {"uniform": [0.2, 0.3]}},
                         "planes": {"wall": {"specular": {"uniform": [0.1, 0.2]}}},
                         "sensor": {"gain_db": {"normal": [0, 1]}, "noise": {"level_db": {"uniform": [30, 35]}}}},
                        SCENE, None)
    doc, _ = v.apply(SCENE, np.random.default_rng(0))
    assert "material" not in doc["ground"] and 0.2 <= doc["ground"]["albedo"] < 0.3  # albedo replaces material
    assert doc["ground"]["specular"] == 0.5
    assert doc["planes"][0] == SCENE["planes"][0]
    assert 0.1 <= doc["planes"][1]["specular"] < 0.2 and doc["planes"][1]["albedo"] == 0.6
    assert 30 <= doc["sensor"]["noise"]["level_db"] < 35
    assert doc["sensor"]["noise"]["after_tvg_db"] == 20.0  # the sub-section is merged, not replaced
    assert doc["objects"] == SCENE["objects"]


def test_counts_from_distributions_and_zero():
    v = parse_variation({"objects": [{"count": {"randint": [0, 2]}, "pool": [{"primitive": "sphere", "radius_m": 0.1}]}]},
                        SCENE, None)
    counts = {len(v.apply(SCENE, np.random.default_rng(s))[0]["objects"]) - 1 for s in range(40)}
    assert counts == {0, 1, 2}
    assert Variation().apply(SCENE, np.random.default_rng(0))[0] == SCENE


@pytest.mark.parametrize("section, key", [
    ({"colour": 1}, "variation.colour"),
    ({"objects": {"pool": []}}, "variation.objects"),
    ({"objects": [{"count": 2}]}, "variation.objects[0].pool"),
    ({"objects": [{"pool": []}]}, "variation.objects[0].pool"),
    ({"objects": [{"pool": [{"primitive": "sphere", "colour": 1}]}]}, "variation.objects[0].pool[0].colour"),
    ({"objects": [{"pool": [{"primitive": "sphere", "name": "x"}]}]}, "variation.objects[0].pool[0].name"),
    ({"objects": [{"pool": [{"primitive": "sphere"}], "count": {"uniform": [1, 2]}}]}, "variation.objects[0].count"),
    ({"objects": [{"pool": [{"primitive": "sphere"}], "count": {"randint": [-1, 2]}}]},
     "variation.objects[0].count.randint"),
    ({"objects": [{"pool": [{"primitive": "sphere"}], "weights": [1, 2]}]}, "variation.objects[0].weights"),
    ({"objects": [{"pool": [{"primitive": "sphere"}], "albedo": 0.5, "material": {}}]}, "variation.objects[0].albedo"),
    ({"objects": [{"name": "a", "pool": [{"primitive": "sphere"}]}, {"name": "a", "pool": [{"primitive": "box"}]}]},
     "variation.objects[1].name"),
    ({"planes": {"floor": {"albedo": 0.1}}}, "variation.planes.floor"),
    ({"planes": {"wall": 0.1}}, "variation.planes.wall"),
    ({"ground": 0.5}, "variation.ground"),
])
def test_bad_variation_sections_name_the_key(section, key):
    with pytest.raises(ConfigError) as info:
        parse_variation(section, SCENE, None)
    assert info.value.key == key, str(info.value)


def test_varying_what_the_scene_lacks_is_refused():
    bare = {k: v for k, v in SCENE.items() if k not in ("ground", "sensor")}
    with pytest.raises(ConfigError, match="no ground") as info:
        parse_variation({"ground": {"albedo": 0.5}}, bare, None)
    assert info.value.key == "variation.ground"
    with pytest.raises(ConfigError, match="no sensor section"):
        parse_variation({"sensor": {"gain_db": 1.0}}, bare, None)


def test_a_count_drawn_out_of_range_is_refused():
    v = parse_variation({"objects": [{"count": {"choice": [1, -3]}, "pool": [{"primitive": "sphere"}]}]}, SCENE, None)
    with pytest.raises(ConfigError, match=r"integer in \[0") as info:
        v.apply(SCENE, None, side="high")
    assert info.value.key == "variation.objects[0].count"


# Issue 21 item 3: weights whose sum overflows -----------------------------------------------

@pytest.mark.parametrize("weights, expected", [([1e308, 1e308], [0.5, 0.5]), ([1e308, 0.0], [1.0, 0.0]),
                                               ([5e-324, 1.5e-323], [0.25, 0.75])])
def test_huge_or_tiny_choice_weights_are_normalised_safely(weights, expected):
    # [1e308, 1e308] summed to inf: "ValueError: Probabilities do not sum to 1" at the first frame.
    from sonarsim.dataset import load_scenario

    t = parse_value({"choice": ["a", "b"], "weights": weights}, "x")
    drawn = {draw(t, np.random.default_rng(k)) for k in range(40)}
    assert drawn == {"a", "b"} if expected[1] else drawn == {"a"}
    from sonarsim.dataset.variation import probabilities

    np.testing.assert_allclose(probabilities(tuple(weights)), expected)
    doc = {"scene": SCENE, "seed": 1,
           "trajectory": {"generate": {"kind": "orbit", "centre_m": [3, 0, 0], "radius_m": 2.0, "z_m": 1.0,
                                       "frames": 3}},
           "variation": {"ground": {"albedo": {"choice": [0.2, 0.7], "weights": weights}},
                         "objects": [{"name": "rock", "count": 2, "weights": weights,
                                      "pool": [{"primitive": "sphere", "radius_m": 0.1,
                                                "pose": {"position_m": [3, 0, 0.5]}},
                                               {"primitive": "sphere", "radius_m": 0.2,
                                                "pose": {"position_m": [3, 1, 0.5]}}]}]}}
    scenario = load_scenario(doc)
    assert all(f.scene["ground"]["albedo"] in (0.2, 0.7) for f in scenario.frame_specs())


def test_weights_that_are_not_finite_or_all_zero_are_refused():
    for weights in ([float("inf"), 1.0], [0.0, 0.0], [-1.0, 2.0]):
        with pytest.raises(ConfigError) as e:
            parse_value({"choice": ["a", "b"], "weights": weights}, "variation.ground.albedo")
        assert e.value.key.startswith("variation.ground.albedo.weights")
