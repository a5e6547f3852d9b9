"""The compiled per-ray kernels against their NumPy twins (the reference implementation)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.renderer import compiled
from sonarsim.cli.demo import demo_scene_dict

pytestmark = pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")


def _variants():
    base = demo_scene_dict()
    out = {"demo": base}
    rolled = copy.deepcopy(base)
    rolled["sonar"]["pose"] = {"position_m": [0.3, 0.2, 1.3], "rpy_deg": [-10.0, 28.0, 8.0]}
    out["rolled"] = rolled
    for key, value in (("range_splat", False), ("tvg", False), ("double_beam", "split"),
                       ("double_line_of_sight", True), ("azimuth_samples", 3), ("beam_pattern", "gaussian")):
        d = copy.deepcopy(rolled)
        d["render"][key] = value
        out[f"{key}={value}"] = d
    no_ground = copy.deepcopy(base)
    del no_ground["ground"]
    out["no_ground"] = no_ground
    oculus = copy.deepcopy(base)
    oculus["sonar"] = {"preset": "oculus-m1200d-lf", "range_max_m": 6.0,
                       "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}}
    out["oculus_sine_spaced"] = oculus
    return out


@pytest.mark.parametrize("name", list(_variants()))
def test_compiled_kernels_equal_the_numpy_reference(name):
    # Same arithmetic in the same precisions, summed in another order: 1e-9 of the energy; a
    # continuity decision exactly at its threshold could differ by float32 rounding, hence the
    # per-component L1 bound rather than exact equality.
    doc = _variants()[name]
    a = sonarsim.Simulator(doc, kernels="compiled").render()
    b = sonarsim.Simulator(doc, kernels="numpy").render()
    for key in b.components:
        x, y = a.components[key].astype(float), b.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-6 * np.abs(y).sum() + 1e-12, key
    np.testing.assert_array_equal(a.rays.surface_id, b.rays.surface_id)
    np.testing.assert_allclose(a.rays.distance_m, b.rays.distance_m, rtol=1e-6)
    np.testing.assert_allclose(a.rays.intensity, b.rays.intensity, rtol=1e-5, atol=1e-12)


def test_compiled_path_renders_many_poses_from_one_workspace():
    sim = sonarsim.Simulator(demo_scene_dict())
    ref = sonarsim.Simulator(demo_scene_dict(), kernels="numpy")
    for z in (0.8, 1.0, 1.3):
        pose = {"position_m": [0.0, 0.1, z], "rpy_deg": [3.0, 22.0, -2.0]}
        a, b = sim.render(pose=pose), ref.render(pose=pose)
        assert np.abs(a.polar - b.polar).sum() <= 1e-6 * np.abs(b.polar).sum()
    # Results do not alias the reused buffers.
    first = sim.render(pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]})
    kept = first.polar.copy()
    sim.render(pose={"position_m": [0, 0, 1.2], "rpy_deg": [0, 25, 0]})
    np.testing.assert_array_equal(first.polar, kept)


def test_unknown_kernels_name_is_rejected():
    with pytest.raises(sonarsim.ConfigError, match="kernels"):
        sonarsim.Simulator(demo_scene_dict(), kernels="gpu")


def test_a_closed_simulator_still_renders_on_one_thread():
    with sonarsim.Simulator(demo_scene_dict()) as sim:
        before = sim.render().polar
    after = sim.render().polar  # the compiled path without its second core, Embree inline
    np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-9)
