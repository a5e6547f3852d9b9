"""The water (issue 39 item 4): the speed of sound against the equations' published check values,
the ``water:`` section, a device that ranges with another speed, and the sensor's absorption."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim import ConfigError, load_scene
from sonarsim.core import water
from tests.conftest import sonar_dict


def test_mackenzie_check_value():
    # Mackenzie (1981), JASA 70(3): 1550.744 m/s at 25 degC, salinity 35, 1000 m.
    assert water.mackenzie_1981(25.0, 35.0, 1000.0) == pytest.approx(1550.744, abs=5e-4)


def test_fresh_water_against_an_independent_measurement():
    # Del Grosso & Mader (1972, JASA 52) measured pure water at 20 degC: 1482.343 m/s; at 0 degC 1402.388.
    c20, out20 = water.sound_speed_m_s(20.0, 0.0, 0.0)
    assert c20 == pytest.approx(1482.343, abs=0.1) and not out20
    assert water.sound_speed_m_s(0.0, 0.0, 0.0)[0] == pytest.approx(1402.388, abs=0.1)
    # Pressure: Mackenzie's depth term, 1.63 cm/s a metre.
    assert water.sound_speed_m_s(20.0, 0.0, 10.0)[0] - c20 == pytest.approx(0.1630, abs=1e-3)


def test_brackish_water_is_said_to_be_extrapolated():
    assert water.sound_speed_m_s(10.0, 15.0, 5.0)[1]
    assert not water.sound_speed_m_s(10.0, 35.0, 5.0)[1]
    assert load_scene({"sonar": sonar_dict(), "water": {"preset": "sea", "salinity_psu": 12}}).water.extrapolated


def test_presets_and_keys():
    sea = load_scene({"sonar": sonar_dict(), "water": {"preset": "sea"}}).water
    assert (sea.temperature_c, sea.salinity_psu, sea.depth_m, sea.ph) == (10.0, 35.0, 10.0, 8.0)
    assert sea.speed_m_s == pytest.approx(water.mackenzie_1981(10.0, 35.0, 10.0))
    warm = load_scene({"sonar": sonar_dict(), "water": {"preset": "fresh", "temperature_c": 25.0}}).water
    assert warm.salinity_psu == 0.0 and warm.speed_m_s == pytest.approx(water.marczak_1997(25.0) + 1.63e-2 * 2.0,
                                                                        abs=1e-3)
    given = load_scene({"sonar": sonar_dict(), "water": {"sound_speed_m_s": 1510.0}}).water
    assert given.speed_m_s == 1510.0
    scene = load_scene({"sonar": sonar_dict(), "water": {"preset": "sea", "profile": [[0, 1500], [20, 1490]]}})
    assert load_scene(scene.to_dict()).water == scene.water.__class__(**{**scene.water.to_dict(),
                                                                         "profile": ((0.0, 1500.0), (20.0, 1490.0))})


@pytest.mark.parametrize("section, key, words", [
    ({"preset": "ocean"}, "water.preset", ["sea, fresh"]),
    ({"temperature_c": 60}, "water.temperature_c", ["[-2, 40]"]),
    ({"salinity_psu": -1}, "water.salinity_psu", ["[0, 45]"]),
    ({"colour": "blue"}, "water.colour", ["unknown key"]),
    ({"sound_speed_m_s": 340}, "water.sound_speed_m_s", ["[1300, 1700]"]),
    ({"profile": [[0, 1500], [0, 1490]]}, "water.profile[1]", ["rise"]),
    ({"profile": [[0, 1500, 3]]}, "water.profile[0]", ["two numbers"]),
    ("sea", "water", ["mapping"]),
])
def test_bad_water_names_its_key(section, key, words):
    with pytest.raises(ConfigError) as info:
        load_scene({"sonar": sonar_dict(), "water": section})
    assert info.value.key == key
    for w in words:
        assert w in str(info.value)


def ball_scene(**water_and_device) -> dict:
    device = water_and_device.pop("device", None)
    sonar = sonar_dict(n_range_bins=1000, range_max_m=6.0)
    if device is not None:
        sonar["sound_speed_m_s"] = device
    doc = {"sonar": sonar, "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.1,
                                        "pose": {"position_m": [5.0, 0.0, 0.0]}}]}
    if water_and_device:
        doc["water"] = water_and_device
    return doc


def first_echo_m(doc) -> float:
    img = sonarsim.render(doc)
    rows = np.flatnonzero(img.polar.sum(axis=1) > 0)
    return float(img.range_edges_m[rows[0]])


def test_a_device_set_to_another_speed_scales_every_range():
    true = first_echo_m(ball_scene())  # the ball's front at 4.9 m
    assert true == pytest.approx(4.9, abs=0.012)
    dr = 5.5 / 1000
    # set right: the same image
    assert first_echo_m(ball_scene(preset="fresh")) == true
    # fresh water at 15 degC (1466 m/s) with the device at 1500: 2.3 % long, 0.11 m at 4.9 m
    c = load_scene(ball_scene(preset="fresh")).water.speed_m_s
    reported = first_echo_m(ball_scene(preset="fresh", device=1500.0))
    assert reported == pytest.approx(true * 1500.0 / c, abs=dr)
    assert reported - true > 20 * dr
    # and short in warm sea water
    c = load_scene(ball_scene(preset="sea", temperature_c=25.0)).water.speed_m_s
    assert first_echo_m(ball_scene(preset="sea", temperature_c=25.0, device=1500.0)) == pytest.approx(
        true * 1500.0 / c, abs=dr)


def test_the_sensor_takes_the_waters_absorption_and_speed():
    doc = {"sonar": {"preset": "aris1800-96"}, "sensor": {"preset": "aris1800-96"}}
    fresh = sonarsim.Simulator(doc).sensor_model()
    sea_doc = copy.deepcopy(doc)
    sea_doc["water"] = {"preset": "sea", "temperature_c": 15.0}
    sim = sonarsim.Simulator(sea_doc)
    a = sim.scene.sensor.absorption
    assert (a.temperature_c, a.salinity_psu, a.depth_m, a.ph) == (15.0, 35.0, 10.0, 8.0)
    assert sim.scene.sensor.sound_speed_m_s == pytest.approx(sim.scene.water.speed_m_s)
    assert sim.water_speed_m_s() == sim.scene.water.speed_m_s
    # sea water absorbs more than the presets' fresh water at 1.8 MHz (the MgSO4 relaxation)
    assert sim.sensor_model().alpha_db_per_m > 1.05 * fresh.alpha_db_per_m
    # the folded scene reloads
    load_scene(sim.scene.to_dict())


@pytest.mark.parametrize("sensor, key", [
    ({"preset": "aris1800-96", "sound_speed_m_s": 1450.0}, "sensor.sound_speed_m_s"),
    ({"preset": "aris1800-96", "absorption": {"model": "francois-garrison", "salinity_psu": 0.0}},
     "sensor.absorption.salinity_psu"),
])
def test_a_sensor_that_sets_the_water_otherwise_is_refused(sensor, key):
    with pytest.raises(ConfigError) as info:
        load_scene({"sonar": {"preset": "aris1800-96"}, "sensor": sensor, "water": {"preset": "sea"}})
    assert info.value.key == key and "water" in str(info.value)


def test_the_waters_profile_is_the_multibeams_true_water():
    doc = {"vehicle": {"pose": {"position_m": [0.0, 0.0, 0.0]}},
           "instruments": [{"type": "multibeam", "name": "mb", "preset": "r2sonic_2026_400",
                            "mount": {"position_m": [0.0, 0.0, -0.5]}}],
           "ground": {"height_m": -10.0}, "water": {"preset": "sea", "profile": [[0, 1500], [30, 1480]]}}
    mb = load_scene(doc).instruments[0]
    assert mb.sound_speed_profile.speed_m_s == (1500.0, 1480.0)
    own = copy.deepcopy(doc)
    own["instruments"][0]["sound_speed_profile"] = [[0, 1520]]
    assert load_scene(own).instruments[0].sound_speed_profile.speed_m_s == (1520.0,)
