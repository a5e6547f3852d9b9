"""A phased array's beams are cones (issue 39 item 5): ``sin theta_s = cos phi sin theta``: the rays'
directions, their solid angles, where a point target lands, and the engine against its reference."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

import sonarsim
from sonarsim.image.grid import beam_azimuth_deg
from tests.conftest import sonar_dict


def cone_sonar(**overrides) -> dict:
    d = sonar_dict(n_beams=60, azimuth_fov_deg=130.0, elevation_fov_deg=20.0, beam_shape="cone")
    d.update(overrides)
    return d


def test_every_ray_of_a_beam_has_the_beams_direction_cosine():
    sim = sonarsim.Simulator({"sonar": cone_sonar(), "render": {"azimuth_samples": 3}})
    fan = sim.ray_fan(sim.scene.sonar)
    d = fan.directions  # (beams, azimuth samples, elevation samples, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d[..., 1], np.sin(fan.azimuth_rad)[..., None] * np.ones(d.shape[2]), atol=1e-12)
    np.testing.assert_allclose(d[..., 2], np.sin(fan.elevation_rad)[None, None, :] * np.ones(d.shape[:2] + (1,)),
                               atol=1e-12)
    # The outermost centre at +-65 degrees lies at asin(sin 65 / cos 10) = 66.97 at the aperture's edge.
    theta = math.radians(sim.scene.sonar.azimuth_deg[0])
    phi = fan.elevation_rad[-1]
    edge = d[0, 1, -1]
    assert math.degrees(math.atan2(edge[1], edge[0])) == pytest.approx(
        math.degrees(math.asin(math.sin(theta) / math.cos(phi))), abs=1e-9)
    assert math.degrees(math.atan2(edge[1], edge[0])) - math.degrees(theta) > 1.5


def test_the_rays_solid_angles_sum_to_the_fans_against_a_monte_carlo():
    sonar = cone_sonar(n_beams=20)
    sim = sonarsim.Simulator({"sonar": sonar, "render": {"elevation_samples": 400, "azimuth_samples": 4}})
    fan = sim.ray_fan(sim.scene.sonar)
    width = np.radians(sim.scene.sonar.effective_beam_width_deg())
    omega = float((fan.weight.sum(axis=(1, 2)) * width).sum())  # the weights are per radian of beam
    # Directions uniform on the sphere (seeded): the share inside the fan is its solid angle / 4 pi.
    rng = np.random.default_rng(39)
    v = rng.normal(size=(4_000_000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    edges = sim.scene.sonar.beam_edges_deg
    u_lo, u_hi = math.sin(math.radians(edges[-1])), math.sin(math.radians(edges[0]))
    inside = (v[:, 0] > 0) & (np.abs(v[:, 2]) <= math.sin(math.radians(10.0))) & (v[:, 1] >= u_lo) & (v[:, 1] <= u_hi)
    assert omega == pytest.approx(4 * math.pi * inside.mean(), rel=5e-3)


def test_a_point_target_lands_in_the_beam_of_its_direction_cosine():
    # A ball 8 degrees up and 55 degrees to the left: plane beams put it at 55, cones at
    # asin(cos 8 sin 55) = 54.2 degrees.
    r, az, el = 4.0, math.radians(55.0), math.radians(8.0)
    p = [r * math.cos(el) * math.cos(az), r * math.cos(el) * math.sin(az), r * math.sin(el)]
    found = {}
    for shape in ("plane", "cone"):
        doc = {"sonar": cone_sonar(n_beams=512, beam_shape=shape, range_max_m=6.0),
               "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.02, "pose": {"position_m": p}}],
               "render": {"elevation_samples": 600}}
        img = sonarsim.render(doc)
        columns = img.polar.sum(axis=0)
        found[shape] = float(np.average(img.azimuth_deg, weights=columns))
    assert found["plane"] == pytest.approx(55.0, abs=0.15)
    assert found["cone"] == pytest.approx(math.degrees(math.asin(math.cos(el) * math.sin(az))), abs=0.15)


def test_beam_azimuth_of_a_direction():
    v = np.array([[math.cos(0.2) * math.cos(0.5), math.cos(0.2) * math.sin(0.5), math.sin(0.2)], [-1.0, 0.1, 0.0]])
    np.testing.assert_allclose(beam_azimuth_deg(v)[0], math.degrees(0.5))
    assert beam_azimuth_deg(v, cone=True)[0] == pytest.approx(math.degrees(math.asin(math.cos(0.2) * math.sin(0.5))))
    assert np.isnan(beam_azimuth_deg(v, cone=True)[1])  # behind the baffled array


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_the_engine_equals_the_reference_with_cone_beams(kernels):
    from tests.reference.test_brute_force import compare, tank_dict

    doc = copy.deepcopy(tank_dict(3, "coherent"))
    doc["sonar"]["beam_shape"] = "cone"
    compare(doc, kernels)


def test_presets_say_their_beam_shape():
    assert sonarsim.load_scene({"sonar": {"preset": "oculus-m1200d-hf"}}).sonar.beam_shape == "cone"
    assert sonarsim.load_scene({"sonar": {"preset": "gemini-720i"}}).sonar.beam_shape == "cone"
    assert sonarsim.load_scene({"sonar": {"preset": "aris3000-128"}}).sonar.beam_shape == "plane"
    with pytest.raises(sonarsim.ConfigError, match="plane, cone"):
        sonarsim.load_scene({"sonar": cone_sonar(beam_shape="dome")})
