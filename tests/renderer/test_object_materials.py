"""Objects' materials (issue 39 item 2): named solids whose specular lobe has Kirchhoff's scale, so
that a sphere's echo is the geometric-optics target strength ``10 log10(|R|^2 a^2 / 4)``."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.config.materials import OBJECT_MATERIALS, WATER_IMPEDANCE_MRAYL, object_material
from tests.conftest import sonar_dict


def sphere_ts_db(preset: str, radius_m: float) -> float:
    doc = {"sonar": sonar_dict(n_beams=64, azimuth_fov_deg=20.0, elevation_fov_deg=20.0, range_max_m=6.0,
                               n_range_bins=600),
           "objects": [{"name": "ball", "primitive": "sphere", "radius_m": radius_m,
                        "pose": {"position_m": [4.0, 0.0, 0.0]}, "material": {"preset": preset}}],
           "render": {"elevation_samples": 400, "azimuth_samples": 8}}
    img = sonarsim.render(doc)
    width = np.radians(img.sonar.effective_beam_width_deg())  # the image's unit: per radian of beam
    return 10 * math.log10(float((img.polar.astype(float) * width[None, :] * img.range_m[:, None] ** 2).sum()))


@pytest.mark.parametrize("radius_m", [0.1, 0.3])
def test_a_rigid_spheres_echo_is_its_geometric_target_strength(radius_m):
    assert sphere_ts_db("rigid", radius_m) == pytest.approx(10 * math.log10(radius_m**2 / 4), abs=1.0)


def test_a_steel_sphere_returns_its_reflection_coefficient_squared():
    r = OBJECT_MATERIALS["steel"].reflection
    z = 7850 * 5900 * 1e-6  # steel's rho c, MRayl
    assert r == pytest.approx((z - WATER_IMPEDANCE_MRAYL) / (z + WATER_IMPEDANCE_MRAYL))
    assert sphere_ts_db("steel", 0.1) == pytest.approx(10 * math.log10(r * r * 0.1**2 / 4), abs=1.0)


def test_the_lobe_has_kirchhoffs_scale():
    for name, m in OBJECT_MATERIALS.items():
        law = object_material(name)
        assert law.law == "rough" and law.roughness == m.roughness
        assert law.specular_strength == pytest.approx(m.reflection**2 / (8 * math.pi * m.roughness**2))


def test_material_presets_in_scene_files():
    doc = {"sonar": sonar_dict(), "objects": [{"name": "hull", "primitive": "box", "size_m": [1, 1, 1],
                                               "pose": {"position_m": [3, 0, 0]}, "material": {"preset": "concrete"}}]}
    scene = load_scene(doc)
    assert scene.objects[0].backscatter == object_material("concrete")
    assert load_scene(scene.to_dict()).objects[0].backscatter == object_material("concrete")
    doc["objects"][0]["material"] = {"preset": "titanium"}
    with pytest.raises(ConfigError, match="allowed: rigid, steel") as info:
        load_scene(doc)
    assert info.value.key == "objects[0].material.preset"
    doc["objects"][0]["material"] = {"preset": "steel", "albedo": 0.5}
    with pytest.raises(ConfigError) as info:
        load_scene(doc)
    assert info.value.key == "objects[0].material.albedo"
