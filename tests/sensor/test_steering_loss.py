"""A steered receive beam loses directivity as its aperture foreshortens (issue 39 item 5):
``10 log10(cos theta)``, -3 dB at 60 degrees, in every preset that steers."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError
from sonarsim.config.sensor import SENSOR_PRESETS


def model(preset: str, steering: bool | None = None):
    sensor = {"preset": preset}
    if steering is not None:
        sensor["azimuth_pattern"] = {**SENSOR_PRESETS[preset]["azimuth_pattern"], "steering_loss": steering}
    sim = sonarsim.Simulator({"sonar": {"preset": preset}, "sensor": sensor})
    return sim.sensor_model()


def test_the_loss_is_the_cosine_of_the_steer():
    on, off = model("oculus-m750d-lf"), model("oculus-m750d-lf", steering=False)
    az = np.radians(on.sonar.azimuth_deg)
    np.testing.assert_allclose(on.column_factor / off.column_factor, np.cos(az), rtol=1e-6)
    edge = 10 * math.log10(on.column_factor[0] / off.column_factor[0])
    assert edge == pytest.approx(10 * math.log10(math.cos(math.radians(65.0))), abs=0.01)  # -3.7 dB


def test_every_steering_preset_says_so_and_the_lenses_do_not():
    for name, preset in SENSOR_PRESETS.items():
        steered = preset["azimuth_pattern"].get("steering_loss", False)
        shape = sonarsim.load_scene({"sonar": {"preset": name}}).sonar.beam_shape
        assert steered == (shape == "cone"), name


def test_the_elevation_pattern_has_no_steering():
    with pytest.raises(ConfigError, match="only for the azimuth pattern") as info:
        sonarsim.load_scene({"sonar": {"preset": "oculus-m750d-lf"},
                             "sensor": {"preset": "oculus-m750d-lf", "elevation_pattern": {"steering_loss": True}}})
    assert info.value.key == "sensor.elevation_pattern.steering_loss"
