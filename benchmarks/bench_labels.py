"""Cost of ground truth (``Simulator.render(..., labels=True)``) on the demo tank (issue 12).

Renders the demo tank (ARIS 3000 preset, 128 beams x 1288 bins, all bounces, default rays)
without labels, with labels and with ``labels="total"``, frame after frame (interleaved, so
that the shared machine's noise falls on all alike), and reports medians: the plain frame
(which takes the ground specialisation), the labelled frame (the general path engine, then the
labels), the labels stage alone (``last_timing["labels"]``), the same with the total's
instance map only, and the ratios.

Usage::

    python benchmarks/bench_labels.py [--repeats 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from sonarsim import Simulator
from sonarsim.cli.demo import demo_scene_dict


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=40)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    with Simulator(demo_scene_dict()) as sim:
        for _ in range(5):  # warm: fans, workspaces, caches
            sim.render(speckle=False)
            sim.render(speckle=False, labels=True)
        plain, labelled, stage, general, total_only, total_stage = [], [], [], [], [], []
        for i in range(args.repeats):
            t = time.perf_counter()
            sim.render(frame=i)
            plain.append(time.perf_counter() - t)
            t = time.perf_counter()
            img = sim.render(frame=i, labels=True)
            labelled.append(time.perf_counter() - t)
            stage.append(sim.last_timing["labels"])
            general.append(sim.last_timing["total"] - sim.last_timing["labels"])
            t = time.perf_counter()
            sim.render(frame=i, labels="total")
            total_only.append(time.perf_counter() - t)
            total_stage.append(sim.last_timing["labels"])
    med = {k: statistics.median(v) * 1e3 for k, v in
           (("plain_ms", plain), ("labelled_ms", labelled), ("labels_stage_ms", stage), ("general_path_ms", general),
            ("labelled_total_only_ms", total_only), ("labels_total_only_stage_ms", total_stage))}
    med["labelled_over_plain"] = med["labelled_ms"] / med["plain_ms"]
    med["labels_stage_over_plain"] = med["labels_stage_ms"] / med["plain_ms"]
    med["labels_total_only_stage_over_plain"] = med["labels_total_only_stage_ms"] / med["plain_ms"]
    med["points"] = int(len(img.labels.points_world))
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in med.items()}, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(med, f, indent=1)


if __name__ == "__main__":
    main()
