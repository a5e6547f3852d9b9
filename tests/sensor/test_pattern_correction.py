"""The elevation pattern's correction: knots over the span, linear in power between them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.config.sensor import parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor.patterns import correction_gain, correction_knots_deg, pattern_gain


def test_the_correction_multiplies_the_pattern_linearly_in_power_between_its_knots():
    spec = parse_sensor({"elevation_pattern": {"shape": "gaussian", "width_deg": 10.0, "span_deg": 40.0,
                                               "correction_db": [0.0, -10.0, 10.0, 0.0, 3.0]}}).elevation_pattern
    np.testing.assert_allclose(correction_knots_deg(spec, 10.0), [-20.0, -10.0, 0.0, 10.0, 20.0])
    angles = np.radians([-20.0, -15.0, 0.0, 5.0, 20.0, 30.0])
    got = correction_gain(angles, spec, 10.0)
    np.testing.assert_allclose(got, [1.0, (1.0 + 0.1) / 2, 10.0, (10.0 + 1.0) / 2, 10 ** 0.3, 10 ** 0.3])
    plain = parse_sensor({"elevation_pattern": {"shape": "gaussian", "width_deg": 10.0, "span_deg": 40.0}}).elevation_pattern
    np.testing.assert_allclose(pattern_gain(angles, spec, 10.0, ways=2), pattern_gain(angles, plain, 10.0, ways=2) * got)


def test_images_of_single_knots_add_up_to_the_image_of_any_correction():
    """Linear in each knot's power: sum_k c_k g_k(angle) = g(angle) for hats g_k."""
    knots = 7
    values = np.array([0.5, 1.0, 2.0, 0.1, 1.0, 3.0, 1.0])
    angles = np.radians(np.linspace(-14, 14, 101))
    base = {"shape": "line", "width_deg": 8.0, "span_deg": 24.0}
    whole = parse_sensor({"elevation_pattern": {**base, "correction_db": (10 * np.log10(values)).tolist()}}).elevation_pattern
    parts = 0.0
    for k in range(knots):
        db = np.full(knots, -300.0)
        db[k] = 10 * math.log10(values[k])
        spec = parse_sensor({"elevation_pattern": {**base, "correction_db": db.tolist()}}).elevation_pattern
        parts = parts + pattern_gain(angles, spec, 8.0, ways=2)
    np.testing.assert_allclose(parts, pattern_gain(angles, whole, 8.0, ways=2), rtol=1e-12, atol=1e-30)


def test_the_correction_is_validated_and_round_trips():
    with pytest.raises(ConfigError, match="correction_db"):
        parse_sensor({"elevation_pattern": {"correction_db": [0.0]}})
    with pytest.raises(ConfigError, match=r"correction_db\[1\]"):
        parse_sensor({"elevation_pattern": {"correction_db": [0.0, 99.0]}})
    with pytest.raises(ConfigError, match="azimuth_pattern.correction_db"):
        parse_sensor({"azimuth_pattern": {"correction_db": [0.0, 1.0]}})
    spec = parse_sensor({"elevation_pattern": {"span_deg": 30.0, "correction_db": [0.0, -1.5, 2.0]}})
    assert parse_sensor(spec.to_dict()) == spec
