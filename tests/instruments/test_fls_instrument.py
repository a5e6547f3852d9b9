"""The FLS as an instrument is today's sonar (issue 38 item 1): ``sonar:`` with ``type: fls``,
``instruments:`` with an FLS on the vehicle, and :func:`render_pings` give the very bits of
:meth:`Simulator.render` (``benchmarks/bench_seam.py`` compares whole frames with a commit
before the seam)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.config.examples import demo_scene_dict
from sonarsim.config.instruments import FlsSpec, mounted
from sonarsim.core.transforms import Pose
from sonarsim.errors import ConfigError
from sonarsim.instruments import render_pings


def as_instruments(doc: dict, mount: dict | None = None, vehicle: dict | None = None) -> dict:
    out = copy.deepcopy(doc)
    sonar = out.pop("sonar")
    pose = sonar.pop("pose")
    out["vehicle"] = {"pose": vehicle if vehicle is not None else pose}
    out["instruments"] = [{"type": "fls", "name": "front", **sonar, **({"mount": mount} if mount else {})}]
    return out


def test_type_fls_means_what_sonar_always_meant():
    doc = demo_scene_dict()
    typed = copy.deepcopy(doc)
    typed["sonar"]["type"] = "fls"
    assert sonarsim.load_scene(typed) == sonarsim.load_scene(doc)


def test_an_fls_on_a_vehicle_renders_the_same_bits():
    doc = demo_scene_dict()
    with sonarsim.Simulator(doc) as sim:
        before = sim.render(frame=2, labels=True)
    with sonarsim.Simulator(as_instruments(doc)) as sim:
        spec = sim.scene.instruments[0]
        assert isinstance(spec, FlsSpec) and spec.name == "front"
        (after,) = render_pings(sim, "front", poses=[sim.scene.vehicle_pose], first_ping=2, labels=True)
    for k in before.components:
        assert before.components[k].tobytes() == after.components[k].tobytes(), k
    assert before.polar.tobytes() == after.polar.tobytes()
    for k, v in before.labels.arrays().items():
        assert np.asarray(v).tobytes() == np.asarray(after.labels.arrays()[k]).tobytes(), k


def test_a_mount_moves_the_sonar_on_the_vehicle():
    doc = demo_scene_dict()
    pose = doc["sonar"]["pose"]
    # the vehicle 0.5 m behind and 0.2 m above the sonar, level; the sonar mounted forward,
    # down and pitched as the scene's sonar is
    vehicle = {"position_m": [pose["position_m"][0] - 0.5, pose["position_m"][1], pose["position_m"][2] + 0.2],
               "rpy_deg": [0, 0, 0]}
    mount = {"position_m": [0.5, 0.0, -0.2], "rpy_deg": pose["rpy_deg"]}
    scene = sonarsim.load_scene(as_instruments(doc, mount=mount, vehicle=vehicle))
    expected = Pose(pose["position_m"], pose["rpy_deg"])
    np.testing.assert_allclose(scene.sonar_pose.matrix(), expected.matrix(), atol=1e-12)
    assert mounted(scene.vehicle_pose, scene.instruments[0].mount) == scene.sonar_pose


def test_instrument_sections_are_checked():
    doc = demo_scene_dict()
    bad = as_instruments(doc)
    bad["instruments"][0]["type"] = "lidar"
    with pytest.raises(ConfigError, match=r"instruments\[0\]\.type.*allowed: .*sidescan"):
        sonarsim.load_scene(bad)
    both = as_instruments(doc)
    both["sonar"] = doc["sonar"]
    with pytest.raises(ConfigError, match="either sonar"):
        sonarsim.load_scene(both)
    twice = as_instruments(doc)
    twice["instruments"].append(dict(twice["instruments"][0]))
    with pytest.raises(ConfigError, match=r"instruments\[1\]\.name.*duplicate"):
        sonarsim.load_scene(twice)
    with pytest.raises(ConfigError, match="sonar.type"):
        sonarsim.config.loader.parse_sonar_section({**doc["sonar"], "type": "sidescan"}, None)


def test_several_instruments_on_one_vehicle():
    doc = as_instruments(demo_scene_dict())
    doc["instruments"].append({"type": "sidescan", "name": "sss", "range_max_m": 5.0, "n_samples": 256,
                               "mount": {"position_m": [0.0, 0.0, 0.0]}})
    with sonarsim.Simulator(doc) as sim:
        (front,) = render_pings(sim, "front")
        sss = render_pings(sim, "sss", n_pings=2, speckle=False)
        with pytest.raises(ConfigError, match="no instrument 'nope'.*front, sss"):
            render_pings(sim, "nope")
    assert front.polar.shape == (sim.scene.sonar.n_range_bins, sim.scene.sonar.n_beams)
    assert sss.samples.shape == (2, 2, 256) and sss.samples.any()
    again = sonarsim.load_scene(sim.scene.to_dict())
    assert [i.name for i in again.instruments] == ["front", "sss"]
