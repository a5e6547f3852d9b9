"""An echo sounder's recording against the simulator's bottom detector (issue 38 item 6).

The Imagenex 852 recording logs its own bottom range per ping (none where it found none) but no
attitude or altitude: what can be checked is that the simulator's detector
(:func:`sonarsim.instruments.singlebeam.detect_bottom`: the leading edge, the first sample
within ``threshold_db`` of the ping's peak), run on the recorded envelopes, finds the bottom the
sounder reported. The threshold is fitted on calibration pings and scored on others, beside
trivial predictions of the sounder's bottom: the calibration pings' median bottom (a constant),
and the previous ping's reported bottom (persistence); and beside another detector, the range of
each ping's strongest sample.
"""

from __future__ import annotations

import numpy as np

from ..image.films import Envelope
from ..instruments.singlebeam import detect_bottom

__all__ = ["THRESHOLDS_DB", "bottom_check"]

#: The thresholds tried on the calibration pings, dB below each ping's peak.
THRESHOLDS_DB = tuple(float(t) for t in np.arange(-0.5, -20.5, -0.5))


def _errors(got: np.ndarray, truth: np.ndarray) -> dict:
    ok = np.isfinite(truth)
    d = np.abs(got[ok] - truth[ok])
    d = np.where(np.isfinite(d), d, np.inf)  # a ping the detector finds nothing in is a miss
    return {"median_m": float(np.median(d)), "within_0.1_m": float(np.mean(d <= 0.1)), "pings": int(ok.sum())}


def bottom_check(envelope: Envelope, calibration, test) -> dict:
    """The detector's threshold fitted on ``calibration`` pings, scored on ``test`` pings.

    Returns
    -------
    dict
        ``threshold_db``; ``detector``, ``constant``, ``persistence`` and ``peak_sample``: each
        the median absolute difference from the sounder's bottom (metres) and the fraction
        within 0.1 m, over the test pings where the sounder reported one.
    """
    cal, test = np.asarray(calibration), np.asarray(test)
    s = np.asarray(envelope.samples, np.float64)
    truth = envelope.bottom_range_m
    lo, hi = envelope.range_min_m, envelope.range_max_m
    scores = [(_errors(detect_bottom(s[cal], lo, hi, t), truth[cal])["median_m"], t) for t in THRESHOLDS_DB]
    best = min(scores)[1]
    previous = np.concatenate([[np.nan], truth[:-1]])[test]
    constant = np.full(len(test), np.nanmedian(truth[cal]))
    peak = envelope.range_m[np.argmax(s[test], axis=1)]
    return {
        "threshold_db": best,
        "detector": _errors(detect_bottom(s[test], lo, hi, best), truth[test]),
        "constant": _errors(constant, truth[test]),
        "persistence": _errors(previous, truth[test]),
        "peak_sample": _errors(peak, truth[test]),
        "calibration_pings": [int(cal.min()), int(cal.max())], "test_pings": [int(test.min()), int(test.max())],
    }
