"""The path engine's frame-time ratios (issue 23 item 6), in one run on this machine.

* the ground-only demo (case a of ``bench_render.py``): frame time over the bare casting of
  the very rays the frame cast (target: no higher than the former fused ground route's 2.8-3.0);
* the demo tank with a water surface and four walls at order 3 (case e): its frame time over
  the demo's (target: within 2.0x);
* the demo with its default labels (``labels=True``: instance maps per component, elevation,
  points, boxes) and with ``labels='total'``, over the plain frame (target: within 1.3x).

Frames of the three kinds are interleaved in blocks (``bench_render.interleaved``), so that the
machine's load drifts hit all of them alike. The dataset frame with its default content
written: ``benchmarks/bench_dataset.py``.

Usage::

    python benchmarks/bench_engine.py [--runs 3] [--repeats 30] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import sonarsim  # noqa: E402
from bench_render import interleaved, measure, tank_scene  # noqa: E402
from sonarsim.config.examples import demo_scene_dict  # noqa: E402


def one_run(repeats: int) -> dict:
    """The ratios of one run."""
    demo = measure("a", demo_scene_dict(), repeats)
    tank = measure("e", tank_scene(6), repeats)
    sim = sonarsim.Simulator(demo_scene_dict())
    times = interleaved({
        "plain": lambda: sim.render(keep_rays=False),
        "labels": lambda: sim.render(keep_rays=False, labels=True),
        "labels_total": lambda: sim.render(keep_rays=False, labels="total"),
    }, repeats)
    sim.close()
    return {
        "demo_frame_ms": demo["frame_ms"], "demo_bare_cast_ms": demo["bare_cast_ms"],
        "demo_frame_over_cast": demo["frame_over_cast"],
        "tank_frame_ms": tank["frame_ms"], "tank_frame_over_cast": tank["frame_over_cast"],
        "tank_over_demo": tank["frame_ms"] / demo["frame_ms"],
        "plain_ms": times["plain"] * 1e3, "labels_ms": times["labels"] * 1e3,
        "labels_total_ms": times["labels_total"] * 1e3,
        "labels_over_plain": times["labels"] / times["plain"],
        "labels_total_over_plain": times["labels_total"] / times["plain"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    runs = []
    for k in range(args.runs):
        r = one_run(args.repeats)
        runs.append(r)
        print(f"run {k + 1}: demo {r['demo_frame_ms']:.2f} ms, frame/cast {r['demo_frame_over_cast']:.2f}; "
              f"six planes {r['tank_frame_ms']:.2f} ms, {r['tank_over_demo']:.2f}x the demo; "
              f"labels {r['labels_over_plain']:.2f}x, labels 'total' {r['labels_total_over_plain']:.2f}x the plain frame",
              flush=True)
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump({"sonarsim": sonarsim.__version__, "runs": runs}, f, indent=2)
        os.replace(tmp, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
