"""The Sea Scan side-scan recording against the simulator, fitted on some pings and scored on
others, with the trivial predictions beside it (issue 38 item 6; :mod:`sonarsim.analysis.sidescan`).

Two splits of the 179 pings with navigation (ping 0 has none): fit on the first half (the
vehicle 11.4 -> 8.7 m above the floor) and score on the second (8.7 -> 6.2 m), and the other way
round. Printed and written as JSON (``--json``).

Usage::

    python benchmarks/realism_sidescan.py [--json benchmarks/realism_sidescan.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

RECORDING = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "sidescan" / \
    "iver2_seascan_pings_0-179.xtf"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recording", type=Path, default=RECORDING)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from sonarsim.analysis import sidescan as A
    from sonarsim.io.readers.xtf import read_waterfall

    rec = read_waterfall(args.recording)
    halves = (np.arange(1, 90), np.arange(90, rec.n_pings))
    out = {"recording": str(args.recording.name), "splits": []}
    for cal, test in (halves, halves[::-1]):
        t = time.perf_counter()
        fit = A.calibrate(rec, cal)
        s = A.score(rec, fit, cal, test)
        s["fit_s"] = time.perf_counter() - t
        out["splits"].append(s)
        f, i = s["first_return"], s["intensity_db"]
        print(f"fit on pings {s['calibration_pings']}, scored on {s['test_pings']} ({s['fit_s']:.1f} s):")
        print(f"  first return, median |error|: model {f['model_m']:.2f} m; logged altitude {f['altitude_m']:.2f} m; "
              f"altitude/(cos pitch cos roll) {f['geometry_m']:.2f} m")
        print(f"  intensity, rms dB over {i['cells']} cells: model {i['model_db']:.2f}; calibration mean profile "
              f"{i['mean_profile_db']:.2f}; shifted to each ping's first return {i['shifted_profile_db']:.2f}; "
              f"ceiling (neighbouring pings) {i['ceiling_neighbours_db']:.2f}")
        for part in ("water_column", "floor"):
            w = i[part]
            print(f"    {part.replace('_', ' ')} ({w['cells']} cells): model {w['model_db']:.2f}; shifted profile "
                  f"{w['shifted_profile_db']:.2f}")
        print("  fit: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in s["fit"].items()))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
