"""The differentiable renderer's memory and time, estimated before it is built (issue 37):
2,000 small spheres are refused in a second, naming the objects, the estimate, the budget and
how to raise it, where they used to pass 6 GB in 163 s; the estimate is the sum of its parts
and grows with what makes the renderer large."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.config.loader import load_scene
from sonarsim.core import memory
from sonarsim.diff import cost
from sonarsim.diff.cost import check_diff_cost, diff_cost, expected_paths
from sonarsim.errors import ConfigError
from tests.diff.small_scenes import SCENE


def spheres(n: int, seed: int = 0) -> dict:
    """The issue's scene: ``n`` spheres of 3 cm on a ground, 64 beams of 256 range bins."""
    rng = np.random.default_rng(seed)
    objs = [{"name": f"s{i}", "primitive": "sphere", "radius_m": 0.03,
             "pose": {"position_m": [float(rng.uniform(1, 4)), float(rng.uniform(-1, 1)), float(rng.uniform(0.03, 0.3))]}}
            for i in range(n)]
    return {"sonar": {"n_beams": 64, "azimuth_fov_deg": 60, "elevation_fov_deg": 20, "range_min_m": 0.5,
                      "range_max_m": 5, "n_range_bins": 256, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}},
            "render": {"elevation_samples": 50}, "ground": {}, "objects": objs}


@pytest.fixture
def budgets():
    """The default budgets (8 GiB or 80 % of the memory, 120 s), whatever the environment says."""
    memory.set_memory_budget(8 * 2**30)
    memory.set_time_budget(120.0)
    yield
    memory.set_memory_budget(None)
    memory.set_time_budget(None)


def test_two_thousand_small_spheres_are_refused_before_anything_is_built(budgets, monkeypatch):
    pytest.importorskip("jax")
    import sonarsim.diff as sd
    from sonarsim.diff import renderer as renderer_mod

    scene = load_scene(spheres(2000))

    def no_build(*args, **kwargs):
        raise AssertionError("the compiled engine's scene was built before the estimate refused it")

    monkeypatch.setattr(renderer_mod, "Simulator", no_build)
    with pytest.raises(ConfigError) as info:
        sd.Renderer(scene)
    message = str(info.value)
    assert message.startswith("objects: the differentiable renderer of 2,000 objects")
    assert "GiB" in message and "memory budget of 8 GiB" in message and "--max-memory" in message
    assert "\n" not in message
    # Raised budgets let it through the estimate (nothing is built here).
    memory.set_memory_budget(64 * 2**30)
    with pytest.raises(ConfigError, match=r"objects: .* would take about .* s, more than the build-time budget of "
                                          r"120 s \(raise it with --max-build-time"):
        check_diff_cost(scene)
    memory.set_time_budget(3600.0)
    assert check_diff_cost(scene).objects == 2000


def test_the_estimate_is_the_sum_of_its_parts_and_grows_with_objects_and_grid():
    small, large = diff_cost(load_scene(spheres(10))), diff_cost(load_scene(spheres(300)))
    assert large.paths == small.paths  # the same rays
    for c in (small, large):
        assert c.bytes == pytest.approx(sum(p[0] for p in c.parts))
    assert large.bytes - small.bytes > 290 * cost.BYTES_PER_OBJECT
    assert large.seconds > small.seconds
    fine = spheres(10)
    fine["sonar"]["n_range_bins"] *= 8  # (the same rays: their count is set, not "auto")
    assert diff_cost(load_scene(fine)).bytes - small.bytes == pytest.approx(
        7 * 256 * 64 * small.images * cost.BYTES_PER_CELL)
    # The search's counts, where given, replace the estimate's.
    counted = diff_cost(load_scene(spheres(10)), n_paths=100, n_faces=10, n_images=3, legs=0)
    assert (counted.paths, counted.faces, counted.images, counted.legs) == (100, 10, 3, 0)


def test_paths_are_estimated_from_the_rays_and_the_orders():
    scene = load_scene(SCENE)  # 16 beams x 24 elevation samples, max_order 2 over a ground
    assert expected_paths(scene) == 16 * 24 * 2
    dry = load_scene({k: v for k, v in SCENE.items() if k != "ground"})
    assert expected_paths(dry) == 16 * 24  # nothing mirrors: one path per ray
    separate = load_scene({**SCENE, "render": {**SCENE["render"], "double_beam": "separate"}})
    assert expected_paths(separate) == 2 * 16 * 24 * 2


def test_the_estimate_needs_no_jax_and_no_build():
    """``reconstruct`` sums the views' estimates before building any: it takes milliseconds."""
    c = diff_cost(load_scene(SCENE))
    assert c.seconds > 0 and c.bytes > cost.BYTES_BASE
    assert "import jax" not in open(cost.__file__, encoding="utf-8").read()
