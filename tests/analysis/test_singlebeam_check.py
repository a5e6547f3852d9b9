"""The simulator's bottom detector on the Imagenex 852 recording against the sounder's own bottom
(issue 38 item 6): the threshold fitted on one half of the pings, scored on the other."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sonarsim.analysis.singlebeam import bottom_check
from sonarsim.image.films import Envelope, PingGeometry

RECORDING = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real" / "singlebeam" / \
    "imagenex852_2016-11-18.852"


def test_a_synthetic_leading_edge_is_found_and_the_threshold_fitted():
    rng = np.random.default_rng(3)
    n, k = 60, 500
    bottom = 3.0 + 2.0 * np.sin(np.arange(n) / 9.0)
    r = (np.arange(k) + 0.5) * 10.0 / k
    # a water column rising to a tenth of the echo, a step at the bottom, then a decay
    env = 0.1 * (r / 10.0)[None, :] + np.where(r[None, :] >= bottom[:, None], np.exp(-(r[None, :] - bottom[:, None])), 0.0)
    env *= rng.uniform(0.9, 1.1, env.shape)
    e = Envelope(env.astype(np.float32), 0.0, 10.0, bottom, PingGeometry.of(n, time_s=np.arange(n)))
    s = bottom_check(e, np.arange(30), np.arange(30, 60))
    assert s["detector"]["median_m"] <= 10.0 / k
    assert s["constant"]["median_m"] > 0.5 and s["detector"]["within_0.1_m"] == 1.0


@pytest.mark.skipif(not RECORDING.is_file(), reason="needs ../shared/data/real/singlebeam")
def test_the_imagenex_recording():
    from sonarsim.io.readers.imagenex import read_envelope

    e = read_envelope(RECORDING)
    half = e.n_pings // 2
    for cal, test in ((np.arange(half), np.arange(half, e.n_pings)), (np.arange(half, e.n_pings), np.arange(half))):
        s = bottom_check(e, cal, test)
        assert s["detector"]["median_m"] <= 0.03 and s["detector"]["within_0.1_m"] > 0.8
        assert s["detector"]["median_m"] < s["persistence"]["median_m"] < s["constant"]["median_m"]
