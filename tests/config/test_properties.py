"""Property-based tests (Hypothesis) of the scene loader's validation (issue 11 item 6).

For each numeric key with a documented range: every finite value inside it is accepted and
lands in the configuration unchanged; every value outside it (or of another type) is refused
with a ConfigError naming that key. Refusals do not depend on the order of the keys, and a
loaded scene written back (``Scene.to_dict``, through YAML) loads as the same scene.

Derandomized (the examples are a function of the test), no example database: CI runs the same
examples every time.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sonarsim.config.loader import scene_from_dict
from sonarsim.errors import ConfigError

PROPERTY_SETTINGS = settings(derandomize=True, database=None, deadline=None, max_examples=25,
                             suppress_health_check=[HealthCheck.too_slow])

BASE = {
    "sonar": {"n_beams": 32, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
              "range_max_m": 10.0, "n_range_bins": 200, "pose": {"position_m": [0.0, 0.0, 1.0]}},
    "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.8},
    "planes": [{"name": "surface", "point_m": [0.0, 0.0, 4.0], "normal": [0.0, 0.0, -1.0]}],
    "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [3.0, 0.0, 0.5]},
                 "material": {"law": "rough", "albedo": 0.4, "specular_strength": 1.0, "roughness": 0.2}}],
    "sensor": {"sound_speed_m_s": 1500.0, "gain_db": 0.0, "frequency_khz": 900.0,
               "absorption": {"temperature_c": 10.0, "salinity_psu": 35.0, "depth_m": 5.0, "ph": 8.0},
               "output": {"compression": "gamma", "gamma": 0.5, "floor_db": 60.0, "ceiling_db": 160.0}},
}


def closed(lo: float, hi: float):
    return st.floats(lo, hi, allow_nan=False)


def open_(lo: float, hi: float):
    return st.floats(lo, hi, exclude_min=True, exclude_max=True, allow_nan=False)


def beyond(lo: float | None, hi: float | None, lo_open: bool = False, hi_open: bool = False):
    """Finite floats outside [lo, hi] (the bounds themselves too where the range is open), and
    non-finite ones."""
    parts = [st.sampled_from([math.nan, math.inf, -math.inf])]
    if lo is not None:
        parts.append(st.floats(max_value=lo, exclude_max=not lo_open, allow_nan=False, allow_infinity=False))
    if hi is not None:
        parts.append(st.floats(min_value=hi, exclude_min=not hi_open, allow_nan=False, allow_infinity=False))
    return st.one_of(parts)


def at(doc: dict, path: str):
    """The mapping holding the last part of a dotted ``path`` (``objects.0.radius_m``), and that part."""
    parts = path.split(".")
    for p in parts[:-1]:
        doc = doc[int(p)] if p.isdigit() else doc[p]
    return doc, parts[-1]


def key_of(path: str) -> str:
    """The key a ConfigError names for ``path``: ``objects.0.radius_m`` -> ``objects[0].radius_m``."""
    out = ""
    for p in path.split("."):
        out += f"[{p}]" if p.isdigit() else (f".{p}" if out else p)
    return out


def with_value(path: str, value) -> dict:
    doc = copy.deepcopy(BASE)
    parent, last = at(doc, path)
    parent[last] = value
    return doc


def loaded(scene, path: str):
    """The value ``path`` names, read back from the loaded Scene."""
    obj = scene
    for p in path.split("."):
        if p.isdigit():
            obj = obj[int(p)]
        elif p == "pose" and obj is scene.sonar:
            obj = scene.sonar_pose
        elif p == "material":
            obj = obj.material
        else:
            obj = getattr(obj, p)
    return obj


# (dotted path, in-range strategy, out-of-range strategy); ranges as documented in config/.
RANGES = [
    ("sonar.elevation_fov_deg", st.floats(0.01, 180, exclude_max=True), beyond(0.01, 180, hi_open=True)),
    ("sonar.azimuth_fov_deg", closed(1.0, 179.0), beyond(0, 180, True, True)),
    # A range_min_m beyond range_max_m is refused naming range_max_m ("must be greater than ...").
    ("sonar.range_min_m", closed(0, 9.99), beyond(0, None)),
    ("sonar.range_max_m", closed(0.51, 1e4), beyond(0.5, 1e4, lo_open=True)),
    ("sonar.frequency_khz", closed(1, 1e5), beyond(1, 1e5)),
    ("sonar.beam_width_deg", st.floats(0.01, 90, exclude_max=True), beyond(0.01, 90, hi_open=True)),
    ("ground.albedo", closed(0, 1), beyond(0, 1)),
    ("ground.specular", closed(0, 1), beyond(0, 1)),
    ("ground.height_m", closed(-1e6, 0.99), beyond(-1e6, 1e6)),
    ("planes.0.specular", closed(0, 1), beyond(0, 1)),
    ("planes.0.albedo", closed(0, 1), beyond(0, 1)),
    ("objects.0.radius_m", st.floats(1e-6, 1e4), beyond(0, 1e4, lo_open=True)),
    ("objects.0.material.albedo", closed(0, 1), beyond(0, 1)),
    ("objects.0.material.roughness", closed(0.001, 0.5), beyond(0.001, 0.5)),
    ("objects.0.material.specular_strength", st.floats(0, 1e6), beyond(0, 1e6)),
    ("objects.0.scale", closed(1e-6, 1e4), beyond(1e-6, 1e4)),
    ("sensor.sound_speed_m_s", closed(1300, 1700), beyond(1300, 1700)),
    ("sensor.gain_db", closed(-200, 200), beyond(-200, 200)),
    ("sensor.frequency_khz", closed(1, 1e5), beyond(1, 1e5)),
    ("sensor.source_level_db", closed(-300, 300), beyond(-300, 300)),
    ("sensor.absorption.temperature_c", closed(-2, 40), beyond(-2, 40)),
    ("sensor.absorption.salinity_psu", closed(0, 45), beyond(0, 45)),
    ("sensor.absorption.depth_m", closed(0, 11000), beyond(0, 11000)),
    ("sensor.absorption.ph", closed(6, 9), beyond(6, 9)),
    ("sensor.output.gamma", closed(0.05, 4), beyond(0.05, 4)),
    ("sensor.output.floor_db", closed(-100, 159), beyond(-100, 400)),
]
IDS = [r[0] for r in RANGES]
WRONG_TYPES = st.one_of(st.text(max_size=5), st.booleans(), st.none(), st.lists(st.floats(), max_size=3),
                        st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@pytest.mark.parametrize("path, inside, outside", RANGES, ids=IDS)
@PROPERTY_SETTINGS
@given(data=st.data())
def test_any_value_in_range_is_accepted_and_kept(path, inside, outside, data):
    value = data.draw(inside, label=path)
    scene = scene_from_dict(with_value(path, value))
    if path == "sonar.azimuth_fov_deg":  # kept as beam centres; the width is computed back from them
        assert loaded(scene, path) == pytest.approx(value, rel=1e-12)
    else:
        assert loaded(scene, path) == value


@pytest.mark.parametrize("path, inside, outside", RANGES, ids=IDS)
@PROPERTY_SETTINGS
@given(data=st.data())
def test_any_value_out_of_range_is_refused_naming_the_key(path, inside, outside, data):
    value = data.draw(st.one_of(outside, WRONG_TYPES), label=path)
    if path in ("sonar.frequency_khz", "sonar.beam_width_deg", "sensor.frequency_khz") and value is None:  # "not given"
        return
    with pytest.raises(ConfigError) as e:
        scene_from_dict(with_value(path, value))
    assert e.value.key == key_of(path), str(e.value)


@PROPERTY_SETTINGS
@given(n=st.integers(2, 512), fov=closed(0.5, 179.5), bins=st.integers(1, 4096))
def test_beam_counts_and_range_bins_are_kept_and_the_fan_is_as_wide_as_asked(n, fov, bins):
    # From two beams: a lone beam is 1 degree wide whatever azimuth_fov_deg says (SonarConfig).
    doc = with_value("sonar.n_beams", n)
    doc["sonar"].update(azimuth_fov_deg=fov, n_range_bins=bins)
    sonar = scene_from_dict(doc).sonar
    assert sonar.n_beams == n and sonar.n_range_bins == bins
    assert sonar.azimuth_fov_deg == pytest.approx(fov, rel=1e-9)
    assert sonar.beam_angles_deg[0] == pytest.approx(fov / 2 - fov / (2 * n), rel=1e-9, abs=1e-12)


@PROPERTY_SETTINGS
@given(n=st.one_of(st.integers(max_value=0), st.floats(allow_nan=True), st.text(max_size=3), st.booleans()))
def test_a_beam_count_that_is_not_a_positive_integer_is_refused(n):
    with pytest.raises(ConfigError) as e:
        scene_from_dict(with_value("sonar.n_beams", n))
    assert e.value.key == "sonar.n_beams"


@PROPERTY_SETTINGS
@given(position=st.lists(closed(-1e6, 1e6), min_size=3, max_size=3),
       rpy=st.lists(closed(-720, 720), min_size=3, max_size=3))
def test_any_pose_within_the_scene_is_accepted_as_given(position, rpy):
    from sonarsim import Pose

    doc = with_value("objects.0.pose", {"position_m": position, "rpy_deg": rpy})
    pose = scene_from_dict(doc).objects[0].pose
    assert pose == Pose(position, rpy) and pose.position_m == tuple(position)


@PROPERTY_SETTINGS
@given(which=st.sampled_from(["position_m", "rpy_deg"]), index=st.integers(0, 2), data=st.data())
def test_a_pose_beyond_the_scene_is_refused_naming_the_key(which, index, data):
    bound = 1e6 if which == "position_m" else 720.0
    value = data.draw(st.one_of(st.floats(min_value=bound, exclude_min=True),
                                st.floats(max_value=-bound, exclude_max=True)))
    vector = [0.0, 0.0, 0.0]
    vector[index] = value
    with pytest.raises(ConfigError) as e:
        scene_from_dict(with_value(f"sonar.pose.{which}", vector))
    # A non-finite entry is named by its index; a finite one too far out by the vector.
    assert e.value.key in (f"sonar.pose.{which}", f"sonar.pose.{which}[{index}]")
    assert (e.value.key.endswith("]")) == (not math.isfinite(value))


def _reordered(doc, data):
    """``doc`` with the keys of every mapping in an order drawn from ``data``."""
    if isinstance(doc, dict):
        keys = data.draw(st.permutations(list(doc)))
        return {k: _reordered(doc[k], data) for k in keys}
    if isinstance(doc, list):
        return [_reordered(v, data) for v in doc]
    return doc


@pytest.mark.parametrize("path, inside, outside", RANGES[::3], ids=IDS[::3])
@PROPERTY_SETTINGS
@given(data=st.data())
def test_refusal_does_not_depend_on_the_order_of_the_keys(path, inside, outside, data):
    doc = with_value(path, data.draw(outside))
    reordered = _reordered(doc, data)
    with pytest.raises(ConfigError) as first:
        scene_from_dict(doc)
    with pytest.raises(ConfigError) as second:
        scene_from_dict(reordered)
    assert first.value.key == second.value.key == key_of(path)


@PROPERTY_SETTINGS
@given(data=st.data())
def test_acceptance_does_not_depend_on_the_order_of_the_keys(data):
    path, inside, _ = data.draw(st.sampled_from(RANGES))
    doc = with_value(path, data.draw(inside))
    assert scene_from_dict(_reordered(doc, data)) == scene_from_dict(doc)


def _without_presets(scene):
    """``scene`` as written back: ``to_dict`` writes the preset's values, not its name."""
    sensor = scene.sensor and dataclasses.replace(scene.sensor, preset=None)
    return dataclasses.replace(scene, source=None, sonar=dataclasses.replace(scene.sonar, preset=None), sensor=sensor)


@PROPERTY_SETTINGS
@given(data=st.data(), preset=st.sampled_from([None, "aris3000-128", "oculus-m1200d-hf", "gemini-720i"]))
def test_a_scene_written_back_loads_as_the_same_scene(data, preset):
    path, inside, _ = data.draw(st.sampled_from(RANGES))
    doc = with_value(path, data.draw(inside))
    if preset is not None:
        doc["sonar"] = {"preset": preset, "pose": doc["sonar"]["pose"]}
        doc["sensor"]["preset"] = preset
        doc["sensor"].pop("frequency_khz")
    try:
        scene = scene_from_dict(doc)
    except ConfigError:  # the preset's sonar replaced the sonar key drawn, or a sensor key clashed
        return
    text = yaml.safe_dump(scene.to_dict())
    assert scene_from_dict(yaml.safe_load(text)) == _without_presets(scene)
