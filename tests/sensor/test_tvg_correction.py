"""The TVG's correction: knots over a range span, linear in power between them, acting on the
echo and on the noise before the TVG, not on the noise after it."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.config.sensor import parse_sensor
from sonarsim.errors import ConfigError
from sonarsim.sensor.acoustics import tvg_correction_gain, tvg_db
from tests.conftest import sonar_dict


def test_the_correction_adds_its_knots_interpolated_in_power_and_holds_its_ends():
    tvg = parse_sensor({"tvg": {"spreading": 20, "absorption": False, "correction_db": [0.0, 10.0, -10.0],
                                "correction_range_m": [1.0, 3.0]}}).tvg
    r = np.array([0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0])
    want = np.array([1.0, 1.0, (1.0 + 10.0) / 2, 10.0, (10.0 + 0.1) / 2, 0.1, 0.1])
    np.testing.assert_allclose(tvg_correction_gain(r, tvg), want, rtol=1e-12)
    np.testing.assert_allclose(tvg_db(r, tvg, 0.0), 20 * np.log10(r) + 10 * np.log10(want), rtol=1e-12)


def test_the_sensor_model_scales_each_rows_echo_and_receiver_noise_by_it_but_not_the_noise_after_tvg():
    from sonarsim.config.loader import load_scene
    from sonarsim.sensor.model import SensorModel

    base = {"output": {"compression": "linear", "ceiling_db": 200.0}, "tvg": {"spreading": 20, "absorption": False},
            "bang": False, "speckle": False}
    scene = load_scene({"sonar": sonar_dict(n_beams=8, n_range_bins=50, range_min_m=0.5, range_max_m=3.0),
                        "ground": {"height_m": -1.0}})
    corr = {"correction_db": [3.0, -6.0], "correction_range_m": [1.0, 2.5]}
    echo = np.full((50, 8), 1e-6, dtype=np.float32)
    out = {}
    for name, noise in (("receiver", {"level_db": 60.0}), ("after", {"level_db": 0.0, "after_tvg_db": 150.0})):
        for with_corr in (False, True):
            spec = parse_sensor({**base, "noise": noise, "tvg": {**base["tvg"], **(corr if with_corr else {})}})
            m = SensorModel(spec, scene.sonar, 0, fields=False)
            out[name, with_corr] = np.asarray(m.apply(echo, speckle=False), dtype=np.float64)
            out[name, with_corr, "noise"] = np.asarray(m.apply(0 * echo, speckle=False), dtype=np.float64)
    c = tvg_correction_gain(scene.sonar.range_m, parse_sensor({"tvg": {**base["tvg"], **corr}}).tvg)
    # Echo and receiver noise both pass the TVG: the whole output scales by c(r).
    np.testing.assert_allclose(out["receiver", True], out["receiver", False] * c[:, None], rtol=1e-4)
    # Noise added after the TVG does not: with no echo, the output is unchanged.
    np.testing.assert_allclose(out["after", True, "noise"], out["after", False, "noise"], rtol=1e-4)
    # and the echo on top of it scales by c(r)
    np.testing.assert_allclose(out["after", True] - out["after", True, "noise"],
                               (out["after", False] - out["after", False, "noise"]) * c[:, None], rtol=1e-3)


@pytest.mark.parametrize("tvg, key", [
    ({"correction_db": [0.0]}, "correction_db"),
    ({"correction_db": [0.0, 1.0]}, "correction_range_m"),
    ({"correction_db": [0.0, 61.0], "correction_range_m": [1, 2]}, r"correction_db\[1\]"),
    ({"correction_range_m": [1, 2]}, "correction_range_m"),
    ({"correction_db": [0.0, 1.0], "correction_range_m": [2, 1]}, "correction_range_m"),
    ({"correction_db": [0.0, 1.0], "correction_range_m": [1]}, "correction_range_m"),
])
def test_the_correction_is_validated_naming_its_key(tvg, key):
    with pytest.raises(ConfigError, match=key):
        parse_sensor({"tvg": tvg})


def test_the_correction_round_trips():
    spec = parse_sensor({"tvg": {"correction_db": [0.0, -1.5, 2.0], "correction_range_m": [0.5, 2.0]}})
    assert parse_sensor(spec.to_dict()) == spec
