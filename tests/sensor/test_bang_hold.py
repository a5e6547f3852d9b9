"""The bang holds its level over ``hold_m`` (the transmission), then decays."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.config.sensor import parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor.channels import bang_row


def test_the_bang_holds_its_level_then_decays_by_1_over_e_per_length():
    spec = parse_sensor({"bang": {"level_db": 100.0, "length_m": 0.01, "hold_m": 0.02}}).bang
    r = np.array([0.0, 0.01, 0.02, 0.03, 0.04])
    p = bang_row(spec, r)
    np.testing.assert_allclose(p[:3], 1e10, rtol=1e-12)
    np.testing.assert_allclose(p[3:], 1e10 * np.exp([-1.0, -2.0]), rtol=1e-12)
    # Without hold_m: the decay from range 0, as before.
    plain = parse_sensor({"bang": {"level_db": 100.0, "length_m": 0.01}}).bang
    np.testing.assert_allclose(bang_row(plain, r), 1e10 * np.exp(-r / 0.01), rtol=1e-12)


def test_hold_m_is_validated_and_round_trips():
    with pytest.raises(ConfigError, match="hold_m"):
        parse_sensor({"bang": {"level_db": 100.0, "length_m": 0.01, "hold_m": -1.0}})
    spec = parse_sensor({"bang": {"level_db": 100.0, "length_m": 0.01, "hold_m": 0.005}})
    assert parse_sensor(spec.to_dict()) == spec
