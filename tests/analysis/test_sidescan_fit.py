"""Side-scan calibration and scoring (issue 38 item 6): the unknowns of a side-scan recovered from
a waterfall rendered with them (speckle drawn, seeded), and the real Sea Scan recording scored on
pings it was not fitted on, beside the trivial predictions."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sonarsim.analysis import sidescan as A
from sonarsim.image.films import PingGeometry, Waterfall

RECORDING = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real" / "sidescan" / \
    "iver2_seascan_pings_0-179.xtf"


def synthetic(truth: A.SidescanFit, n: int = 40, seed: int = 7) -> Waterfall:
    """A recording made by the model itself: a vehicle descending from 11 m to 7 m over a flat
    floor, pitching 20-23 degrees and rolling +-3, its expected intensity times single-look
    speckle (exponential, seeded)."""
    t = np.arange(n) * 0.123
    geometry = PingGeometry.of(n, time_s=t, altitude_m=np.linspace(11.0, 7.0, n),
                               pitch_deg=20.0 + 3.0 * np.sin(t), roll_deg=3.0 * np.sin(2.1 * t),
                               heading_deg=350.0, x_m=0.0, y_m=t, sound_speed_m_s=1500.0)
    blank = Waterfall(np.zeros((n, 2, 1024), np.float32), 0.0, 29.98, geometry, source="synthetic")
    expected = A.predict(blank, truth, np.arange(n))
    rng = np.random.default_rng(seed)
    return replace(blank, samples=(expected * rng.exponential(1.0, expected.shape)).astype(np.float32))


def test_calibration_recovers_the_unknowns_and_beats_the_baselines():
    # near what the Sea Scan recording fits (its pattern's main lobe ends well short of nadir)
    truth = A.SidescanFit(depression_deg=16.0, vertical_beam_width_deg=36.0, gain_db=95.0, range_exponent=0.2,
                          noise_db=-70.0)
    rec = synthetic(truth)
    cal, test = np.arange(0, 20), np.arange(20, 40)
    fit = A.calibrate(rec, cal, every=1)
    assert abs(fit.depression_deg - truth.depression_deg) < 3.0  # (partly traded against the width and gain)
    assert abs(fit.vertical_beam_width_deg - truth.vertical_beam_width_deg) < 5.0
    assert abs(fit.range_exponent - truth.range_exponent) < 0.3
    s = A.score(rec, fit, cal, test)
    first, level = s["first_return"], s["intensity_db"]
    assert first["model_m"] < 0.2 and first["model_m"] < 0.5 * first["geometry_m"] < first["altitude_m"]
    assert level["model_db"] < level["shifted_profile_db"] and level["model_db"] < level["mean_profile_db"]
    # speckle of one look averaged over 16 samples: about 1.1 dB rms; the model is near it
    assert level["model_db"] < 1.6


def test_the_detector_finds_a_step():
    r = (np.arange(1024) + 0.5) * 30 / 1024
    line = np.where(r < 12.0, 1.0, 100.0)
    samples = np.broadcast_to(line, (3, 2, 1024)).copy()
    samples[:, :, :8] = 32767  # a saturated bang is ignored
    got = A.first_return_m(samples, r)
    # the running mean of 9 samples crosses a quarter of the floor's level two samples before the step
    assert np.all(np.abs(got - 12.0) < 3 * 30 / 1024)


@pytest.mark.skipif(not RECORDING.is_file(), reason="needs ../shared/data/real/sidescan")
def test_the_sea_scan_recording_on_pings_it_was_not_fitted_on():
    pytest.importorskip("pyxtf")
    from sonarsim.io.readers.xtf import read_waterfall

    rec = read_waterfall(RECORDING)
    cal, test = np.arange(1, 90), np.arange(90, 180)  # fit high (11.4-8.7 m), score low (8.7-6.2 m)
    fit = A.calibrate(rec, cal)
    s = A.score(rec, fit, cal, test)
    first, level = s["first_return"], s["intensity_db"]
    assert first["model_m"] < 0.5 * first["geometry_m"] and first["geometry_m"] < first["altitude_m"]
    assert level["model_db"] < level["shifted_profile_db"] < level["mean_profile_db"]
    assert level["ceiling_neighbours_db"] < level["model_db"]
    # where the model loses (issue 39 item 8's 1 dB target): the water column, whose recorded
    # level falls 5.7 dB over the dive, the model's noise level held (measured 3.2 dB against
    # the shifted profile's 4.2), and the floor, where the calibration pings' shifted profile
    # is closer (1.3 against the model's 1.6)
    water, floor = level["water_column"], level["floor"]
    assert water["cells"] + floor["cells"] < level["cells"] and min(water["cells"], floor["cells"]) > 2000
    assert water["model_db"] > 1.5 * floor["model_db"] and water["model_db"] < water["shifted_profile_db"]
    assert floor["shifted_profile_db"] < floor["model_db"]
