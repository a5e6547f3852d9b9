"""Realism benchmark (issue 10, items 4-5): calibrate on one real ping, evaluate on held-out pings.

Calibrates the sensor model (:func:`sonarsim.analysis.calibration.calibrate`) on the first ping
of ``../shared/data/real/oculus/three_pings_8bit.raw`` (floor scene, starting from the pose of
the floor-band fit: z 0.416 m, pitch 28.8 deg, roll 1.4 deg, then fitting z, pitch and roll) and evaluates it on the second and third: PSNR,
MSE and SSIM of the expected render in device units; per region (lit floor band, water column,
shadow) KS and 1-Wasserstein distances, speckle contrast, correlation lengths along range and
across beams, and the mean range and beam profiles in dB, of a speckled render. For comparison,
the uncalibrated paper model (no sensor section: the noise-free image scaled so that its
maximum is full scale) is scored the same way.

Usage::

    python benchmarks/bench_realism.py [--json benchmarks/realism.json] [--data RECORDING.raw]

Skips with a message (exit status 0) when ../shared/data is absent.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "real" / "oculus" / "three_pings_8bit.raw"
SCENE = {
    "sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 0.416], "rpy_deg": [1.4, 28.8, 0]}},
    "render": {"bounces": [1]}, "ground": {"height_m": 0, "albedo": 0.8},
}
FREE = ("z", "pitch", "roll")
TARGETS = "item 5: PSNR >= 19 dB; lit and water KS < 0.1, contrast within 15 %, grain within 25 %"


def _strip_profiles(ev: dict) -> dict:
    return {**ev, "regions": {k: {n: x for n, x in v.items() if "profile_db_" not in n} for k, v in ev["regions"].items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=str(ROOT / "benchmarks" / "realism.json"))
    ap.add_argument("--max-iterations", type=int, default=250)
    ap.add_argument("--data", default=str(DATA), help="the three-ping Oculus recording (default: %(default)s)")
    args = ap.parse_args(argv)
    data = Path(args.data)
    if not data.is_file():
        print(f"bench_realism: skipped: {data} is not present", file=sys.stderr)
        return 0

    from dataclasses import replace

    import sonarsim
    from sonarsim.analysis.calibration import calibrate, evaluate, format_evaluation
    from sonarsim.analysis.metrics import normalize_255
    from sonarsim.io.readers import read_frames

    pings = list(read_frames(data))
    scene = sonarsim.load_scene(SCENE)
    t0 = time.perf_counter()
    res = calibrate(pings[0], scene, free=FREE, max_iterations=args.max_iterations)
    seconds = time.perf_counter() - t0
    peak = res.scene.sensor.output.full_scale
    with sonarsim.Simulator(res.scene) as sim:
        speckled = sim.render(res.scene.sonar_pose, keep_rays=False).polar
    # The paper's model: no sensor, the noise-free image on the recording's grid, max -> 255.
    paper_scene = replace(scene, sonar=res.expected.sonar)
    with sonarsim.Simulator(paper_scene) as sim:
        paper = normalize_255(sim.render(scene.sonar_pose, keep_rays=False).polar, mode="max")

    out = {"data": data.name, "calibrated_on": 0, "seconds": seconds,
           "values": res.values, "sensor": res.scene.sensor.to_dict(),
           "pose": res.scene.sonar_pose.to_dict(), "targets": TARGETS, "frames": {}}
    print(f"calibrated on ping 0 in {seconds:.1f} s ({res.renders} renders): "
          f"PSNR {res.psnr_start_db:.2f} -> {res.psnr_db:.2f} dB")
    for k, v in res.values.items():
        print(f"  {k:20s} {v:10.4f}")
    for i, p in enumerate(pings):
        cal = evaluate(p.polar, res.expected.polar, speckled, peak)
        unc = evaluate(p.polar, paper, paper, peak)
        tag = "calibrated on" if i == 0 else "held out"
        print(format_evaluation(cal, f"ping {i} ({tag}), calibrated model: "))
        print(format_evaluation(unc, f"ping {i} ({tag}), paper model:      "))
        out["frames"][str(i)] = {"calibrated": cal, "paper": unc}
    print("\nheld-out summary (pings 1, 2):  " + TARGETS)
    print(f"{'ping':>4} {'PSNR':>6} {'region':>6} {'KS':>6} {'W1':>6} {'contrast real/model':>20} "
          f"{'grain bins':>12} {'grain beams':>12}")
    for i in (1, 2):
        ev = out["frames"][str(i)]["calibrated"]
        for name in ("lit", "water", "shadow"):
            st = ev["regions"][name]
            if not st["pixels"]:
                continue
            print(f"{i:4d} {ev['psnr_db']:6.2f} {name:>6} {st['ks']:6.3f} {st['wasserstein']:6.2f} "
                  f"{st['contrast_a']:9.3f}/{st['contrast_b']:.3f} {st['grain_range_a']:6.2f}/{st['grain_range_b']:.2f} "
                  f"{st['grain_beams_a']:6.2f}/{st['grain_beams_b']:.2f}")
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    from sonarsim.io.output import atomic_write

    text = json.dumps(out, indent=1, default=lambda x: float(x) if np.isscalar(x) else str(x))
    # Lists of numbers (the profiles) on one line each.
    text = re.sub(r"\[\s+([^\[\]{}]*?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", text)
    with atomic_write(Path(args.json), "w") as f:
        f.write(text + "\n")
    print(f"bench_realism: wrote {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
