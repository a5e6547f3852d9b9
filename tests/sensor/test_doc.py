"""docs/sensor.md against the code: its keys and presets exist, its example scene renders as it says."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import yaml

import sonarsim
from sonarsim.config.sensor import _SUBSPECS, SENSOR_KEYS, SENSOR_PRESETS

DOC = (Path(__file__).resolve().parents[2] / "docs" / "sensor.md").read_text()


def _section(title: str) -> str:
    return DOC.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_the_keys_table_names_every_key_of_the_section_and_no_other():
    named = set()
    for row in _section("The `sensor:` section").splitlines():
        if not row.startswith("| `"):
            continue
        keys = re.findall(r"`([a-z_.]+)`", row.split("|")[1])
        parent = keys[0].split(".")[0]
        named |= {parent + k if k.startswith(".") else k for k in keys}  # `.salinity_psu` after its parent's key
    valid = {k for k in SENSOR_KEYS if k not in _SUBSPECS}
    valid |= {f"{name}.{f.name}" for name, cls in _SUBSPECS.items() for f in dataclasses.fields(cls)}
    valid -= {"elevation_pattern.leakage_beams", "azimuth_pattern.span_deg",
              "azimuth_pattern.correction_db", "elevation_pattern.steering_loss"}  # refused: azimuth / elevation only
    assert named == valid


def test_the_presets_listed_are_the_presets():
    rows = [line for line in _section("Presets").splitlines() if line.startswith("| `")]
    assert {re.findall(r"`([a-z0-9-]+)`", row)[0] for row in rows} == set(SENSOR_PRESETS)


def test_the_example_renders_device_values_and_their_expectation():
    doc = yaml.safe_load(re.findall(r"```yaml\n(.*?)```", DOC, re.S)[-1])
    with sonarsim.Simulator(doc) as sim:
        img = sim.render(frame=0)
        np.testing.assert_array_equal(img.polar, np.round(img.polar))
        assert img.polar.min() >= 0 and img.polar.max() <= 255 and (img.polar > 0).mean() > 0.5
        mean = sim.render(speckle=False).polar
        lit = mean[mean > 0]
        assert np.mean(lit != np.round(lit)) > 0.5
        np.testing.assert_array_equal(sim.render(frame=0).polar, img.polar)
