"""The one table of fittable parameters: the scene format, calibrate, fit, the side-scan and
multibeam fits and the differentiable engine read it, and docs/parameters.md shows it."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from sonarsim.config import parameters
from sonarsim.config.parameters import PARAMETERS
from sonarsim.config.sensor import parse_sensor
from sonarsim.errors import ConfigError

DOC = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"


def _number(text: str) -> float:
    return {"inf": math.inf, "-inf": -math.inf}[text] if text in ("inf", "-inf") else float(text)


def test_the_docs_table_is_the_code_table():
    rows = {}
    for line in DOC.read_text().splitlines():
        m = re.match(r"\| `([^`]+)` \| ([^|]+) \| ([\[(])([^,]+), ([^\])]+)([\])]) \| ([^|]+) \| ([^|]+) \| `([^`]+)` \|", line)
        if m:
            rows[m.group(1)] = m
    assert set(rows) == set(PARAMETERS)
    for name, m in rows.items():
        p = PARAMETERS[name]
        assert m.group(2).strip() == (p.unit or "-"), name
        assert _number(m.group(4)) == pytest.approx(p.lo) and _number(m.group(5)) == pytest.approx(p.hi), name
        assert (m.group(6) == ")") == p.open_hi, name
        assert float(m.group(7)) == pytest.approx(p.step), name
        assert (m.group(8).strip() == "-") == (p.coarse_step is None), name
        assert m.group(9) == p.field, name


def test_every_entry_is_well_formed():
    for name, p in PARAMETERS.items():
        assert p.name == name
        assert p.lo < p.hi and p.step > 0, name
        assert p.step < (p.hi - p.lo), name
        if p.coarse_step is not None:
            assert p.coarse_step >= p.step, name


def test_the_scene_format_refuses_what_the_table_refuses():
    # Just inside each bound is accepted, just outside refused, naming the key.
    for name, doc_of in (("sensor.gain_db", lambda v: {"gain_db": v}),
                         ("sensor.speckle.looks", lambda v: {"speckle": {"looks": v}}),
                         ("sensor.output.gamma", lambda v: {"output": {"compression": "gamma", "gamma": v}}),
                         ("sensor.noise.level_db", lambda v: {"noise": {"level_db": v}})):
        p = PARAMETERS[name]
        parse_sensor(doc_of(p.lo))
        parse_sensor(doc_of(p.hi))
        for bad in (p.lo - 1e-3 * (p.hi - p.lo), p.hi + 1e-3 * (p.hi - p.lo)):
            with pytest.raises(ConfigError) as e:
                parse_sensor(doc_of(bad))
            assert e.value.key == "sensor." + name.split(".", 1)[1]


def test_calibrate_and_fit_take_their_steps_and_bounds_from_the_table():
    from sonarsim.analysis import calibration, fitting, multibeam, sidescan
    from tests.sensor.test_physics import small_sonar

    for k, name in calibration.TABLE_NAMES.items():
        assert calibration.STEPS[k] == parameters.step(name)
    spec = parse_sensor(calibration.STARTING_SENSOR)
    b = calibration.parameter_bounds(spec, small_sonar())
    for k, (lo, hi) in b.items():
        p = parameters.parameter(calibration.TABLE_NAMES[k])
        assert p.lo <= lo <= hi <= p.hi, k
    for k in fitting.PARAMETERS:
        assert fitting.STEPS[k] == parameters.parameter(f"pose.{k}").coarse_step
    for k in sidescan.FIT_KEYS:
        assert sidescan.BOUNDS[k] == parameters.bounds(f"sidescan.{k}")
    # The multibeam fit tries grain sizes over the table's bounds, no further.
    inc = np.linspace(5.0, 70.0, 30)
    from sonarsim.core import seabed
    law = 10 * np.log10(seabed.backscatter(np.radians(90 - inc), seabed.sediment_from_grain_size(9.0), 400e3))
    fit = multibeam.fit_sediment(inc, law, 400e3)
    assert fit["grain_size_phi"] == pytest.approx(parameters.bounds("material.grain_size_phi")[1])


def test_the_differentiable_engine_checks_the_table_bounds():
    from sonarsim.diff.params import bound_of

    for key, name in (("sensor.gain_db", "sensor.gain_db"), ("objects.buoy.albedo", "material.albedo"),
                      ("planes.floor.mu", "material.mu"), ("sensor.gamma", "sensor.output.gamma"),
                      ("sonar.position_m", "pose.x")):
        b, p = bound_of(key), PARAMETERS[name]
        assert (b.lo, b.hi, b.unit, b.open_hi) == (p.lo, p.hi, p.unit, p.open_hi), key


def test_narrowing_never_widens():
    p = PARAMETERS["sensor.output.gamma"]
    assert p.narrowed(-5.0, 0.5) == (p.lo, 0.5)
    with pytest.raises(ValueError, match="sensor.output.gamma"):
        p.narrowed(10.0, 20.0)
    with pytest.raises(KeyError, match="the table has"):
        parameters.parameter("sensor.nope")
