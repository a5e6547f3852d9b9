"""Every image says its unit (issue 39 item 6): from its configuration, in NPZ files, figures and
bags; and the unit means what it says (a sphere's target strength from a render)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.image.units import UNITS, unit_of
from tests.conftest import sonar_dict


@pytest.mark.parametrize("config, name", [
    ({"sonar": {}, "render": {"tvg": True}}, "backscatter"),
    ({"sonar": {}}, "backscatter"),
    ({"sonar": {}, "render": {"tvg": False}}, "backscatter_per_r2"),
    ({"sonar": {}, "sensor": {"source_level_db": 200.0, "output": False}}, "uPa^2"),
    ({"sonar": {}, "sensor": {"output": {"dtype": "uint8"}}}, "counts"),
    ({"source": "x.aris", "format": "aris", "frame": 0}, "counts"),
    ({}, "backscatter"),
])
def test_the_unit_follows_the_configuration(config, name):
    assert unit_of(config) is UNITS[name]


def test_a_spheres_target_strength_from_the_backscatter_unit():
    # Lambert's law on a sphere of radius a: sigma_bs = int mu cos^2 dA = 2 pi a^2 mu / 3 (m^2).
    # The unit: value * beam width (rad) * r^2, summed over the sphere's cells, is that.
    a, r0, mu = 0.1, 4.0, 0.1
    doc = {"sonar": sonar_dict(n_beams=64, azimuth_fov_deg=10.0, elevation_fov_deg=10.0, range_max_m=6.0,
                               n_range_bins=600),
           "objects": [{"name": "ball", "primitive": "sphere", "radius_m": a, "pose": {"position_m": [r0, 0.0, 0.0]},
                        "material": {"law": "lambert", "mu": mu}}],
           "render": {"elevation_samples": 400, "azimuth_samples": 8}}
    img = sonarsim.render(doc)
    assert img.unit.name == "backscatter"
    width = np.radians(img.sonar.effective_beam_width_deg())
    sigma = float((img.polar.astype(float) * width[None, :] * img.range_m[:, None] ** 2).sum())
    # (the sphere's mesh is facetted: 0.3 dB)
    assert 10 * math.log10(sigma) == pytest.approx(10 * math.log10(2 * math.pi * a * a * mu / 3), abs=0.3)


def test_npz_files_say_the_unit(tmp_path):
    img = sonarsim.render({"sonar": sonar_dict(), "render": {"tvg": False},
                           "objects": [{"name": "b", "primitive": "sphere", "radius_m": 0.2,
                                        "pose": {"position_m": [3.0, 0.0, 0.0]}}]})
    path = tmp_path / "frame.npz"
    img.save_npz(path)
    with np.load(path) as z:
        assert str(z["unit"]) == "backscatter_per_r2"
    back = sonarsim.read(path)
    assert back.unit.name == "backscatter_per_r2" and "unit" not in back.components


def test_a_sensors_images_are_in_its_units():
    doc = {"sonar": {"preset": "aris1800-96"}, "sensor": {"preset": "aris1800-96"}, "ground": {"height_m": -2.0}}
    assert sonarsim.render(doc).unit.name == "counts"
    doc["sensor"]["output"] = False
    assert sonarsim.render(doc).unit.name == "uPa^2"
