"""A scenario's frames refused before the first is rendered when they cannot fit (issue 21: a
group of `count: 10000` ran 300 s into 7.1 GB before its label maps were refused)."""

from __future__ import annotations

import time

import pytest

from sonarsim.core import memory
from sonarsim.dataset.scenario import load_scenario
from sonarsim.dataset.writer import generate
from sonarsim.errors import ConfigError


def _scenario(count, entry):
    return {
        "seed": 0,
        "scene": {"sonar": {"preset": "aris3000-128", "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}},
                  "ground": {}},
        "trajectory": {"generate": {"kind": "orbit", "centre_m": [3, 0, 0.2], "radius_m": 2.5, "z_m": 1.0,
                                    "frames": 3}},
        "variation": {"objects": [{"name": "rock", "count": count, "pool": [entry],
                                   "pose": {"position_m": [{"uniform": [1, 4]}, {"uniform": [-1, 1]}, 0.1]}}]},
    }


BOX = {"primitive": "box", "size_m": [0.05, 0.05, 0.05]}


@pytest.fixture(autouse=True)
def eight_gib():
    memory.set_memory_budget(8 * 2**30)
    yield
    memory.set_memory_budget(None)


def test_label_maps_of_the_largest_frame_are_refused_before_the_folder_is_made(tmp_path):
    doc = _scenario({"randint": [9000, 10000]}, BOX)
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=r"^variation\.objects: label maps of 10001 surfaces x 3 orders would need "
                       r"24\.6 GiB, more than the memory budget of 8 GiB .*; or ask for no labels \(--labels none\)"):
        generate(doc, tmp_path / "out", labels="all", progress=False)
    assert time.monotonic() - t0 < 30  # a hang guard (before: 300 s): nothing was rendered
    assert not (tmp_path / "out").exists()
    # Storing the total's map alone still renders every order's (the boxes are the direct
    # echoes', the object component's map): the same size.
    with pytest.raises(ConfigError, match=r"label maps of 10001 surfaces x 3 orders would need 24\.6 GiB"):
        generate(doc, tmp_path / "out", labels="total", progress=False)
    assert not (tmp_path / "out").exists()


def test_objects_whose_triangles_would_not_fit_are_refused_when_the_scenario_is_loaded():
    # 10,000 spheres of 10 cm at the count's high end: 51 million triangles.
    doc = _scenario({"randint": [10, 10000]}, {"primitive": "sphere", "radius_m": 0.1})
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=r"^variation\.objects: building 10,000 objects of 51,200,000 triangles would "
                       r"need 9\.\d+ GiB, more than the memory budget of 8 GiB .*\(every distribution at its high end\)"):
        load_scenario(doc)
    assert time.monotonic() - t0 < 30  # a hang guard (before: minutes)


def test_a_group_of_many_alike_objects_is_checked_in_a_moment():
    # 10,000 boxes at the high end: one of each distinct spec is built for the check.
    doc = _scenario(10000, BOX)
    t0 = time.monotonic()
    scenario = load_scenario(doc)
    assert time.monotonic() - t0 < 30  # a hang guard (about 1.7 s here)
    assert len(scenario.probe("high")[0]["objects"]) == 10000


def test_a_frame_whose_images_rays_and_sensor_fields_do_not_fit_together_is_refused_first(tmp_path):
    # Each part fits 128 MiB alone; together (with the sensor's speckle and noise fields) not.
    doc = _scenario(1, BOX)
    doc["scene"]["sonar"] = {"preset": "oculus-m1200d-hf", "n_range_bins": 700,
                             "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}}
    doc["scene"]["sensor"] = {"preset": "oculus-m1200d-hf"}
    memory.set_memory_budget(128 * 2**20)
    with pytest.raises(ConfigError, match=r"^scene\.sonar\.n_beams: a frame of 700 x 512 would hold 0\.18\d GiB at once "
                       r"\(images .*, rays .*, speckle and noise fields .*\), more than the memory budget"):
        generate(doc, tmp_path / "out", labels="none", progress=False)
    assert not (tmp_path / "out").exists()
