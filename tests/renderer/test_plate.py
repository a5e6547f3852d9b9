"""A flat face's coherent lobe (``law: plate``): its far-field target strength
``10 log10(|R|^2 A^2 / lambda^2)``, its lobe against the closed form, and its near-field level,
the infinite mirror's ``10 log10(r^2 / 4)``, from one per-ray law."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.config.materials import Material
from sonarsim.core import reflection
from tests.conftest import sonar_dict


def plate_ts_db(side_m: float, range_m: float, khz: float, yaw_deg: float = 0.0, reflectance: float | None = None,
                elevation_samples: int = 800, azimuth_samples: int = 32) -> float:
    """The target strength of a square plate (a 2 mm box of the plate law) at ``range_m`` on the
    sonar's axis, turned ``yaw_deg`` about the vertical: the image summed times each beam's
    width and r^2 (the sensor's reading of the image as sigma / r^2 per radian of beam)."""
    material = {"law": "plate", "area_m2": side_m**2}
    if reflectance is not None:
        material["reflectance"] = reflectance
    doc = {"sonar": sonar_dict(frequency_khz=khz, range_min_m=0.5, range_max_m=range_m + 1.0),
           "objects": [{"name": "plate", "primitive": "box", "size_m": [0.002, side_m, side_m],
                        "pose": {"position_m": [range_m, 0.0, 0.0], "rpy_deg": [0.0, 0.0, yaw_deg]},
                        "material": material}],
           "render": {"elevation_samples": elevation_samples, "azimuth_samples": azimuth_samples}}
    img = sonarsim.render(doc)
    width = np.radians(img.sonar.effective_beam_width_deg())
    return 10 * math.log10(float((img.polar.astype(float) * width[None, :] * img.range_m[:, None] ** 2).sum()))


def test_a_plate_in_its_far_field_has_the_target_strength_a2_over_lambda2():
    # 5 cm at 400 kHz: far field beyond L^2 / lambda = 0.67 m; at 5 m.
    lam = 1500.0 / 400e3
    expected = 10 * math.log10(0.05**4 / lam**2)  # -3.5 dB
    assert plate_ts_db(0.05, 5.0, 400.0) == pytest.approx(expected, abs=0.5)
    # |R|^2 scales it
    assert plate_ts_db(0.05, 5.0, 400.0, reflectance=0.5) == pytest.approx(expected - 3.01, abs=0.5)


@pytest.mark.parametrize("yaw_deg", [0.5, 1.5, 3.1])  # main lobe, its flank, the first side lobe
def test_the_far_field_lobe_follows_the_closed_form(yaw_deg):
    k = 2 * math.pi * 400e3 / 1500.0
    expected = 10 * math.log10(float(reflection.face_cross_section(math.radians(yaw_deg), 0.05**2, k)))
    assert plate_ts_db(0.05, 5.0, 400.0, yaw_deg, elevation_samples=400, azimuth_samples=16) == pytest.approx(
        expected, abs=1.0)


@pytest.mark.parametrize("range_m", [2.0, 3.0])
def test_a_plate_in_its_near_field_reads_the_mirrors_level(range_m):
    # 10 cm at 2 MHz: its far field begins at L^2 / lambda = 13 m, where it would read +22.5 dB;
    # nearer, the coherent echo is the infinite mirror's, r^2 / 4.
    far = 10 * math.log10(0.1**4 / (1500.0 / 2e6) ** 2)
    got = plate_ts_db(0.1, range_m, 2000.0, elevation_samples=480, azimuth_samples=32)
    assert got == pytest.approx(10 * math.log10(range_m**2 / 4), abs=0.5)
    assert got < far - 15


def test_the_lobe_integrates_to_the_mirrors_level():
    # The identity behind the near field: int sigma_bs(rho / r) d^2 rho / A = r^2 / 4 at any r.
    from scipy import integrate

    area, k, r = 0.01, 2 * math.pi * 2e6 / 1500.0, 2.0
    null = reflection.AIRY_FIRST_ZERO / (2 * k * math.sqrt(area / math.pi))
    value, _ = integrate.quad(lambda rho: float(reflection.face_cross_section(math.atan(rho / r), area, k))
                              * 2 * math.pi * rho, 0.0, 400 * null * r, limit=4000)
    assert value / area == pytest.approx(r * r / 4, rel=0.02)


def test_the_kernels_table_is_the_formula_and_both_kernels_agree():
    m = Material("plate", area_m2=0.01, reflectance=0.8, albedo=0.01)
    table = m.table(1e6, 1500.0)
    assert len(table) == reflection.face_table_size(0.01, 2 * math.pi * 1e6 / 1500.0) > 361
    alpha = np.linspace(0.0, math.pi / 2, len(table))
    np.testing.assert_allclose(table[:-1], m.evaluate(np.cos(alpha[:-1]), frequency_hz=1e6), rtol=1e-9, atol=1e-15)
    doc = {"sonar": sonar_dict(frequency_khz=600.0), "render": {"elevation_samples": 64, "azimuth_samples": 4},
           "ground": {"height_m": -1.0, "material": {"law": "sediment", "sediment": "fine-sand"}, "specular": 0.0},
           "objects": [{"name": "plate", "primitive": "box", "size_m": [0.002, 0.2, 0.2],
                        "pose": {"position_m": [3.0, 0.0, 0.0], "rpy_deg": [0, 0, 3.0]},
                        "material": {"law": "plate", "area_m2": 0.04}}]}
    a = sonarsim.Simulator(doc, kernels="compiled").render().polar.astype(float)
    b = sonarsim.Simulator(doc, kernels="numpy").render().polar.astype(float)
    assert a.max() > 0
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6 * b.max())


def test_plates_are_refused_where_they_do_not_belong():
    with pytest.raises(ConfigError, match="area_m2"):
        Material("plate")
    with pytest.raises(ConfigError, match="area_m2"):
        Material("plate", area_m2=1e3)
    with pytest.raises(ConfigError, match="reflectance"):
        Material("plate", area_m2=0.1, reflectance=1.5)
    with pytest.raises(ConfigError, match=r"ground\.material\.law"):
        load_scene({"sonar": sonar_dict(frequency_khz=600.0), "ground": {"material": {"law": "plate", "area_m2": 1.0}}})
    doc = {"sonar": sonar_dict(), "objects": [{"name": "p", "primitive": "box", "size_m": [0.01, 0.1, 0.1],
                                               "pose": {"position_m": [2.0, 0, 0]},
                                               "material": {"law": "plate", "area_m2": 0.01}}]}
    with pytest.raises(ConfigError, match="frequency_khz"):
        sonarsim.render(doc)
