"""Backscatter laws in rendered images: closed forms, per-ray values, and every implementation alike."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

import sonarsim
from sonarsim.config.examples import demo_scene_dict
from sonarsim.config.materials import Material
from sonarsim.renderer import compiled
from tests.conftest import sonar_dict
from tests.reference.test_brute_force import compare, tank_dict

LAMBERT = {"law": "lambert", "mu": 0.01}
ROUGH = {"law": "rough", "albedo": 0.3, "specular_strength": 2.0, "roughness": 0.15}
LAWS = {"lambertian": {"law": "lambertian", "albedo": 0.6}, "lambert": LAMBERT, "rough": ROUGH}


def wall_scene(material: dict, d: float = 3.0, elev: float = 12.0, **render) -> dict:
    """A wall x = d facing the sonar at the origin: cos(alpha) = cos(phi) cos(theta), r = d / cos(alpha)."""
    return {
        "sonar": sonar_dict(elevation_fov_deg=elev),
        "objects": [{"name": "wall", "primitive": "box", "size_m": [0.2, 10.0, 10.0],
                     "pose": {"position_m": [d + 0.1, 0.0, 0.0]}, "material": material}],
        "render": dict(render),
    }


@pytest.mark.parametrize("law", list(LAWS))
def test_wall_matches_the_integral_of_the_law(law):
    # Eq. 3 with f(alpha) in place of rho cos(alpha): each beam's energy is the integral over
    # the elevation aperture of f(cos(phi) cos(theta)) cos(phi) dphi (the solid angle per
    # radian of beam width; TVG on, uniform beam pattern).
    elev = 12.0
    img = sonarsim.render(wall_scene(LAWS[law], elev=elev))
    theta = np.radians(img.azimuth_deg)
    a = math.radians(elev) / 2
    if law == "lambert":  # closed form: mu cos(alpha) cos(phi) = mu cos(theta) cos(phi)**2
        expected = 0.01 * np.cos(theta) * (2 * a + math.sin(2 * a)) / 2
    else:
        phi = np.linspace(-a, a, 20001)
        f = Material(**LAWS[law]).evaluate(np.cos(phi)[None, :] * np.cos(theta)[:, None]) * np.cos(phi)[None, :]
        expected = (0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(phi)).sum(axis=1)  # trapezoids
    if law == "lambertian":
        np.testing.assert_allclose(expected, 0.6 * np.cos(theta) * (2 * a + math.sin(2 * a)) / 2, rtol=1e-8)
    np.testing.assert_allclose(img.polar.sum(axis=0), expected, rtol=2e-3)


def test_per_ray_intensity_is_the_law_at_each_rays_incidence():
    # A ray at distance r from the wall x = d meets it at cos(alpha) = d / r; with TVG its
    # intensity is its weight times f(alpha), exactly.
    d = 2.0
    for law, material in LAWS.items():
        sim = sonarsim.Simulator(wall_scene(material, d=d))
        img = sim.render()
        w = sim.ray_fan(sim.scene.sonar).weight
        r = img.rays.distance_m.astype(float)
        hit = np.isfinite(r)
        f = img.rays.intensity[hit] / w[hit]
        np.testing.assert_allclose(f, Material(**material).evaluate(d / r[hit]), rtol=2e-5, err_msg=law)


def test_the_rough_lobe_peaks_at_normal_incidence():
    material = {"law": "rough", "albedo": 0.2, "specular_strength": 5.0, "roughness": 0.05}
    d = 2.0
    sim = sonarsim.Simulator(wall_scene(material, d=d, elevation_samples=64))
    img = sim.render()
    w = sim.ray_fan(sim.scene.sonar).weight
    f = np.where(np.isfinite(img.rays.distance_m), img.rays.intensity / w, 0.0)
    nearest = np.unravel_index(np.argmin(img.rays.distance_m), f.shape)
    assert np.unravel_index(np.argmax(f), f.shape) == nearest
    # Beams near the axis are far brighter than the diffuse part alone would make them...
    columns = img.polar.sum(axis=0)
    centre, edge = columns[len(columns) // 2], columns[0]
    assert centre > 5 * edge
    # ... and the lobe's share of each beam is the integral of its formula over the aperture
    # (the image of the diffuse part alone subtracted).
    diffuse = sonarsim.render(wall_scene({"law": "lambertian", "albedo": 0.2}, d=d, elevation_samples=64))
    lobe_energy = columns.astype(float) - diffuse.polar.sum(axis=0)
    a = math.radians(sim.scene.sonar.elevation_fov_deg) / 2
    phi = np.linspace(-a, a, 20001)
    theta = np.radians(img.azimuth_deg)
    c = np.cos(phi)[None, :] * np.cos(theta)[:, None]
    f = Material(**material).evaluate(c) - Material.lambertian(0.2).evaluate(c)
    expected = (0.5 * (f[:, 1:] + f[:, :-1]) * np.diff(phi)).sum(axis=1)
    assert expected[0] < 1e-3 * expected[len(expected) // 2]
    np.testing.assert_allclose(lobe_energy, expected, rtol=2e-2, atol=1e-4 * expected.max())


def test_lambert_floor_against_lambertian_floor_ray_by_ray():
    # Lambert's law per unit area (mu cos^2) is the paper's rho cos per ray with rho = mu: on
    # every ray of a floor the ratio is mu / rho, whatever the incidence.
    h, mu, rho = 1.0, 0.01, 0.5
    base = {
        "sonar": sonar_dict(pose={"position_m": [0.0, 0.0, h], "rpy_deg": [0.0, 25.0, 0.0]}),
        "ground": {"albedo": rho, "specular": 0.0},
    }
    lam = sonarsim.render(base)
    doc = copy.deepcopy(base)
    doc["ground"] = {"material": {"law": "lambert", "mu": mu}, "specular": 0.0}
    lmb = sonarsim.render(doc)
    r = lam.rays.distance_m.astype(float)
    hit = np.isfinite(r)
    assert hit.sum() > 1000
    np.testing.assert_array_equal(r, lmb.rays.distance_m)
    ratio = lmb.rays.intensity[hit] / lam.rays.intensity[hit]
    np.testing.assert_allclose(ratio, mu / rho, rtol=2e-5)


def test_material_lambertian_is_the_albedo_shorthand_bit_for_bit():
    doc = demo_scene_dict()
    a = sonarsim.render(doc)
    for o in doc["objects"]:
        o["material"] = {"law": "lambertian", "albedo": o.pop("albedo")}
    doc["ground"]["material"] = {"albedo": doc["ground"].pop("albedo")}
    b = sonarsim.render(doc)
    for key in a.components:
        np.testing.assert_array_equal(a.components[key], b.components[key], err_msg=key)


def material_variants() -> dict:
    """The demo scenes with a law on every kind of surface."""
    ground = demo_scene_dict()
    ground["ground"] = {"height_m": 0.0, "material": {"law": "lambert", "mu_db": -15.0}, "specular": 0.6}
    ground["objects"][0]["material"] = ROUGH
    del ground["objects"][0]["albedo"]
    ground["objects"][1]["material"] = LAMBERT
    del ground["objects"][1]["albedo"]
    out = {"ground": ground}
    tvg = copy.deepcopy(ground)
    tvg["render"]["tvg"] = False
    out["ground_no_tvg"] = tvg
    out["planes"] = with_laws(tank_dict())
    return out


def with_laws(tank: dict) -> dict:
    """The test tank (tests/reference/test_brute_force.py) with Lambert's floor, a rough wall and a rough ball."""
    tank["ground"] = {"height_m": 0.0, "material": {"law": "lambert", "mu": 0.05}, "specular": 0.6}
    wall = tank["planes"][1]
    del wall["albedo"]
    wall["material"] = {"law": "rough", "albedo": 0.3, "specular_strength": 0.5, "roughness": 0.3}
    del tank["objects"][0]["albedo"]
    tank["objects"][0]["material"] = ROUGH
    return tank


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
@pytest.mark.parametrize("name", list(material_variants()))
def test_compiled_kernels_equal_the_numpy_reference_under_every_law(name):
    doc = material_variants()[name]
    a = sonarsim.Simulator(doc, kernels="compiled").render()
    b = sonarsim.Simulator(doc, kernels="numpy").render()
    for key in b.components:
        x, y = a.components[key].astype(float), b.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-6 * np.abs(y).sum() + 1e-12, key
    np.testing.assert_allclose(a.rays.intensity, b.rays.intensity, rtol=1e-5, atol=1e-12)
    # The laws changed the picture (against the same scene with the paper's law everywhere).
    plain = sonarsim.render(demo_scene_dict() if name.startswith("ground") else tank_dict())
    assert np.abs(plain.polar - a.polar).sum() > 0.05 * np.abs(plain.polar).sum()


def test_algorithm2_equals_the_fast_method_under_every_law():
    doc = material_variants()["ground"]
    doc["render"] = {**doc.get("render", {}), "elevation_samples": 96, "double_beam": "paper"}
    fast = sonarsim.render(doc)
    doc["render"]["method"] = "paper"
    paper = sonarsim.render(doc)
    for key in ("object", "ground", "double", "triple"):
        x, y = paper.components[key].astype(float), fast.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-3 * np.abs(y).sum() + 1e-9, key


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_the_reference_path_model_agrees_under_every_law(kernels):
    # The reference evaluates each law from its formula (Material.evaluate), surface by surface.
    compare(with_laws(tank_dict()), kernels)
