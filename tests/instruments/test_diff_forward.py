"""The differentiable engine's forward equals the compiled engine's on each instrument (issue 38
item 7): a scene whose sonar is a side-scan, a scanning sonar or a single-beam renders its first
channel (its own fan and pattern) through :class:`sonarsim.diff.Renderer` as
:meth:`Simulator.render` does."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")

import sonarsim  # noqa: E402
import sonarsim.diff as sd  # noqa: E402

BOX = {"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [0.0, 6.0, 0.5]}}

SECTIONS = {
    "sidescan": {"type": "sidescan", "frequency_khz": 600, "horizontal_beam_width_deg": 1.0,
                 "vertical_beam_width_deg": 50, "depression_deg": 15, "range_max_m": 12, "n_samples": 256},
    "scanning": {"type": "scanning", "frequency_khz": 750, "horizontal_beam_width_deg": 2.0,
                 "vertical_beam_width_deg": 25, "tilt_deg": 20, "steps_per_turn": 400, "range_max_m": 12,
                 "n_samples": 256, "sound_speed_m_s": 1500},
    "singlebeam": {"type": "singlebeam", "frequency_khz": 330, "beam_width_deg": 10, "range_max_m": 6,
                   "n_samples": 200},
}


def rel_l1(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.abs(a - b).sum() / max(np.abs(b).sum(), 1e-300))


@pytest.mark.parametrize("kind", sorted(SECTIONS))
def test_the_forward_equals_the_compiled_engine(kind):
    section = {**SECTIONS[kind], "pose": {"position_m": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 0.0, 90.0 if kind == "scanning" else 0.0]}}
    doc = {"sonar": section, "ground": {"height_m": 0.0, "albedo": 0.5}, "objects": [BOX],
           "render": {"max_order": 1}}
    with sonarsim.Simulator(doc) as sim:
        ref = sim.render(speckle=False).polar
        spec = sim.scene.instruments[0]
        assert sim.ray_fan(sim.scene.sonar) is not None and spec.make_fan(sim.scene.render) is not None
        np.testing.assert_array_equal(sim.ray_fan(sim.scene.sonar).weight, spec.make_fan(sim.scene.render).weight)
    assert ref.any()
    r = sd.Renderer(doc)
    assert rel_l1(r.render(), ref) < 1e-3
