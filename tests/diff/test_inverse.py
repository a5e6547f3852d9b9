"""Inverse problems by gradient (issue 24, item 5): the pose of a synthetic recording."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

from sonarsim.cli.demo import demo_scene_dict  # noqa: E402
from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.renderer.simulator import Simulator  # noqa: E402

import sonarsim.diff as sd  # noqa: E402
from sonarsim.diff.inverse import blur, fit  # noqa: E402


@pytest.fixture(scope="module")
def demo_target():
    doc = demo_scene_dict()
    with Simulator(doc) as sim:
        return doc, sim.render(speckle=False).polar


def test_fit_recovers_a_synthetic_pose_from_10_cm_and_5_degrees_off(demo_target):
    doc, target = demo_target
    truth = {"x": 0.0, "y": 0.0, "z": 1.0, "pitch": 20.0, "yaw": 0.0}
    start = {"x": 0.1, "y": -0.1, "z": 1.1, "pitch": 25.0, "yaw": -5.0}
    r = sd.Renderer(doc, attach="surfaces")
    result = fit(r, target, free=("x", "y", "z", "pitch", "yaw"), starts=[start])
    for k in ("x", "y", "z"):
        assert abs(result.values[k] - truth[k]) < 0.01, result.values
    for k in ("pitch", "yaw"):
        assert abs(result.values[k] - truth[k]) < 0.3, result.values
    assert result.loss < 1e-4
    (only,) = result.starts
    assert only.start == start and only.values == result.values
    # The renderer's search is left at the fit.
    assert np.allclose(np.asarray(r.paths(result.params)["distance"]), r.search.distance[: r.search.n_paths], atol=2e-6)


def test_fit_refuses_unknown_parameters_and_a_target_of_another_shape(demo_target):
    doc, target = demo_target
    r = sd.Renderer(doc)
    with pytest.raises(ConfigError, match="free: unknown free parameter 'heave'"):
        fit(r, target, free=("heave",))
    with pytest.raises(ConfigError, match="target: has shape"):
        fit(r, target[:10], free=("z",))


def test_the_blur_is_a_gaussian_of_unit_mass_inside_and_zero_outside():
    x = np.zeros((101, 61))
    x[50, 30] = 1.0
    y = np.asarray(blur(jnp.asarray(x), (4.0, 2.0)))
    assert y.sum() == pytest.approx(1.0, rel=1e-9)
    r = np.arange(101) - 50
    np.testing.assert_allclose(y[:, 30] / y[50, 30], np.exp(-0.5 * (r / 4.0) ** 2), atol=1e-9)
    # Zero outside: an impulse at the edge loses the half that falls outside.
    x[:] = 0.0
    x[0, 30] = 1.0
    assert np.asarray(blur(jnp.asarray(x), (4.0, 2.0))).sum() == pytest.approx(0.5 + 0.5 * 0.0997, rel=0.05)
