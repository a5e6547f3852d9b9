"""The multibeam and single-beam recordings against the simulator, fitted on some pings and
scored on others, with the trivial predictions beside them (issue 38 item 6;
:mod:`sonarsim.analysis.multibeam`, :mod:`sonarsim.analysis.singlebeam`). The side-scan's:
``benchmarks/realism_sidescan.py``.

Two splits of each recording: fit on the first half of the pings, score on the second, and the
other way round (the multibeam: every fifth ping of each half). Printed and written as JSON.

Usage::

    python benchmarks/realism_survey.py [--json benchmarks/realism_survey.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from sonarsim.analysis.multibeam import score
    from sonarsim.analysis.singlebeam import bottom_check
    from sonarsim.io.readers.imagenex import read_envelope
    from sonarsim.io.readers.r2sonic import read_soundings

    out = {"multibeam": [], "singlebeam": []}
    s = read_soundings(REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf")
    half = s.n_pings // 2
    halves = (np.arange(0, half, 5), np.arange(half, s.n_pings, 5))
    for cal, test in (halves, halves[::-1]):
        r = score(s, cal, test)
        out["multibeam"].append(r)
        g, b, f = r["range_m"], r["backscatter_db"], r["floor"]
        print(f"R2Sonic 2026: floor fitted on pings {r['calibration_pings']} ({f['depth_m']:.2f} m, tilt "
              f"{f['tilt_east_deg']:.2f} E / {f['tilt_north_deg']:.2f} N deg), scored on {r['test_pings']}:")
        print(f"  per-beam range, median |error|: model {g['model']:.3f} m; calibration mean per beam "
              f"{g['calibration_mean_per_beam']:.3f} m; level floor {g['level_floor']:.3f} m ({g['cells']} beams)")
        print(f"  per-beam backscatter, rms: model {b['model']:.2f} dB; calibration mean per beam "
              f"{b['calibration_mean_per_beam']:.2f} dB; ceiling (neighbouring pings) {b['ceiling_neighbours']:.2f} dB")
        a = r["angular_response_db"]
        print(f"  angular response, rms dB over {a['bins']} bins of incidence {a['incidence_deg'][0]:g}-"
              f"{a['incidence_deg'][1]:g} deg: sediment {a['sediment']:.2f}, with beam gains "
              f"{a['sediment_with_beam_gains']:.2f}; calibration mean per beam {a['calibration_mean_per_beam']:.2f}; "
              f"Lambert over the footprint {a['footprint_lambert']:.2f}; flat {a['flat']:.2f}; ceiling (calibration "
              f"response) {a['ceiling_calibration_response']:.2f}; a beam's incidence moves "
              f"{a['incidence_spread_per_beam_deg']:.2f} deg (median std over the pings)")
    e = read_envelope(REAL / "singlebeam" / "imagenex852_2016-11-18.852")
    half = e.n_pings // 2
    for cal, test in ((np.arange(half), np.arange(half, e.n_pings)), (np.arange(half, e.n_pings), np.arange(half))):
        r = bottom_check(e, cal, test)
        out["singlebeam"].append(r)
        print(f"Imagenex 852: threshold {r['threshold_db']} dB fitted on pings {r['calibration_pings']}, scored on "
              f"{r['test_pings']}: bottom median |error| {r['detector']['median_m']:.3f} m "
              f"({100 * r['detector']['within_0.1_m']:.0f} % within 0.1 m); constant {r['constant']['median_m']:.2f} m; "
              f"previous ping {r['persistence']['median_m']:.2f} m; strongest sample {r['peak_sample']['median_m']:.3f} m")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
