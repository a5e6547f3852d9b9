"""The sediment law in rendered images: each ray carries the model's law at its incidence and the
sonar's frequency, in both kernels, on objects, planes and the ground."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.config.materials import Material
from sonarsim.core import seabed
from tests.conftest import sonar_dict
from tests.renderer.test_materials import wall_scene

SAND = {"law": "sediment", "sediment": "fine-sand"}


def floor_scene(material: dict, khz: float | None = 400.0, **render) -> dict:
    """A sonar 1.5 m above a sea bed, pitched down 30 degrees, with a wall behind the floor."""
    sonar = sonar_dict(pose={"position_m": [0.0, 0.0, 1.5], "rpy_deg": [0.0, 30.0, 0.0]}, elevation_fov_deg=30.0)
    if khz is not None:
        sonar["frequency_khz"] = khz
    return {"sonar": sonar, "ground": {"height_m": 0.0, "material": material, "specular": 0.0},
            "render": dict(render)}


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_per_ray_intensity_is_the_model_at_each_rays_incidence(kernels):
    d = 2.0
    doc = wall_scene(SAND, d=d)
    doc["sonar"]["frequency_khz"] = 900.0
    sim = sonarsim.Simulator(doc, kernels=kernels)
    img = sim.render()
    w = sim.ray_fan(sim.scene.sonar).weight
    r = img.rays.distance_m.astype(float)
    hit = np.isfinite(r)
    f = img.rays.intensity[hit] / w[hit]
    model = Material(**SAND).evaluate(d / r[hit], frequency_hz=900e3)
    # The kernels read a table a quarter degree apart, linearly: within 0.2 % of the formula.
    np.testing.assert_allclose(f, model, rtol=2e-3)


@pytest.mark.parametrize("method", ["fast", "paper"])
def test_both_kernels_render_the_same_sea_bed(method):
    # Paths of third order over a mirroring sea bed, a clay wall and a rock block that mirrors too.
    doc = floor_scene(SAND, method=method, max_order=3)
    doc["ground"]["specular"] = 0.5
    doc["objects"] = [{"name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.5], "specular": 0.5,
                       "pose": {"position_m": [3.0, 0.3, 0.25]}, "material": {"law": "sediment", "sediment": "rock"}}]
    if method == "fast":
        doc["planes"] = [{"name": "wall", "point_m": [4.5, 0, 0], "normal": [-1, 0, 0], "specular": 0.3,
                          "material": {"law": "sediment", "sediment": "clay"}}]
    a = sonarsim.Simulator(doc, kernels="compiled").render().polar.astype(float)
    b = sonarsim.Simulator(doc, kernels="numpy").render().polar.astype(float)
    assert a.max() > 0
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * b.max())


def test_the_law_follows_the_sonars_frequency_and_level():
    lo = sonarsim.render(floor_scene(SAND, khz=100.0)).polar.astype(float)
    hi = sonarsim.render(floor_scene(SAND, khz=1000.0)).polar.astype(float)
    # The sea bed scatters more at the higher frequency at these grazing angles (roughness's k^0.75).
    assert hi.sum() > 1.5 * lo.sum()
    up = sonarsim.render(floor_scene({**SAND, "level_db": 6.0}, khz=100.0)).polar.astype(float)
    np.testing.assert_allclose(up, lo * 10 ** 0.6, rtol=1e-5, atol=1e-7 * up.max())


def test_a_sediment_by_grain_size_is_that_class():
    by_name = sonarsim.render(floor_scene({"law": "sediment", "sediment": "medium-sand"})).polar
    by_phi = sonarsim.render(floor_scene({"law": "sediment", "grain_size_phi": 1.5})).polar
    np.testing.assert_array_equal(by_name, by_phi)


def test_a_floor_against_the_model_beam_by_beam():
    # Each range bin of a flat floor seen with TVG holds sum(w f(alpha)) over its rays; the image of
    # a Lambertian floor of albedo 1 holds sum(w cos(alpha)): their ratio, bin by bin, is the
    # model's sigma / cos^2 at that bin's incidence where one incidence fills the bin.
    doc = floor_scene(SAND, khz=300.0, tvg=True)
    sed = sonarsim.Simulator(doc).render()
    lam = sonarsim.render(floor_scene({"law": "lambertian", "albedo": 1.0}, tvg=True))
    r = sed.range_m
    beam = sed.polar.shape[1] // 2
    ok = lam.polar[:, beam] > 1e-3 * lam.polar[:, beam].max()
    cos_alpha = 1.5 / r[ok]  # the centre beam: the floor's incidence at range r from 1.5 m up
    ratio = sed.polar[ok, beam] / lam.polar[ok, beam]
    expected = Material(**SAND).evaluate(cos_alpha, frequency_hz=300e3) / cos_alpha
    # The bins span a little incidence each (and the beam's width): a few per cent.
    np.testing.assert_allclose(ratio, expected, rtol=0.05)


def test_a_sediment_needs_the_sonars_frequency():
    with pytest.raises(ConfigError, match="frequency_khz"):
        sonarsim.render(floor_scene(SAND, khz=None))


def test_scene_files_parse_and_round_trip_the_sediment_law():
    scene = load_scene(floor_scene({"law": "sediment", "sediment": "clay", "level_db": -3.0}))
    m = scene.ground.backscatter
    assert (m.law, m.sediment, m.level_db) == ("sediment", "clay", -3.0)
    assert m.coefficient == pytest.approx(10 ** -0.3)
    again = load_scene(scene.to_dict()).ground.backscatter
    assert again == m
    assert Material("sediment").sediment_model().name == "medium-sand"  # the default class


@pytest.mark.parametrize("material, key, words", [
    ({"law": "sediment", "sediment": "lava"}, "ground.material.sediment", ["unknown sediment", "medium-sand"]),
    ({"law": "sediment", "sediment": "clay", "grain_size_phi": 3.0}, "ground.material.grain_size_phi", ["not both"]),
    ({"law": "sediment", "grain_size_phi": 11.0}, "ground.material.grain_size_phi", ["[-1, 9]"]),
    ({"law": "sediment", "level_db": 40.0}, "ground.material.level_db", ["[-30, 30]"]),
    ({"law": "sediment", "albedo": 0.3}, "ground.material.albedo", ["not used"]),
    ({"law": "lambert", "sediment": "clay", "mu": 0.01}, "ground.material.sediment", ["not used"]),
    ({"law": "lambert", "mu": 0.5}, "ground.material.mu", ["1/pi"]),
    ({"law": "lambert", "mu_db": -3.0}, "ground.material.mu_db", ["-4.97"]),
])
def test_bad_sediment_laws_name_their_key(material, key, words):
    with pytest.raises(ConfigError) as info:
        load_scene(floor_scene(material))
    assert info.value.key == key
    for w in words:
        assert w in str(info.value)


def test_the_energy_bound_of_lamberts_law():
    # pi mu of what a Lambert surface receives goes back into the water: mu = 1/pi is all of it.
    assert Material("lambert", mu=1 / math.pi).coefficient == pytest.approx(0.3183, abs=1e-4)
    with pytest.raises(ConfigError, match="1/pi"):
        Material("lambert", mu=0.33)
    assert seabed.MODEL_RANGE_HZ == (10e3, 100e3)


def test_diff_engine_refuses_the_sediment_law_by_name():
    pytest.importorskip("jax")
    from sonarsim.diff import Renderer

    doc = copy.deepcopy(floor_scene(SAND))
    with pytest.raises(ConfigError, match="sediment"):
        Renderer(doc)
