"""The FLS through the instrument seam against a commit before it, in one run (issue 38 item 1):
the same images, components and labels, bit for bit, and the frame times side by side.

Each tree must be a checkout with its compiled extensions built in place. Each tree renders, in
a fresh process that imports sonarsim from that tree's ``src``, the same frames: the demo tank
(with labels), the demo with the ARIS sensor preset (seeded speckle and noise), the tank with a
water surface and four walls at order 3 (with labels), the mirrors example and ``method:
paper``; it saves every array and the median frame times. The trees alternate ``--runs`` times
(the machine's load drifts hit both alike); then every array of one is compared with the other's.

Usage::

    git worktree add /tmp/before 0586e53 && (cd /tmp/before && python setup.py build_ext --inplace)
    python benchmarks/bench_seam.py /tmp/before . [--runs 3] [--repeats 20] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = r"""
import copy, json, sys, time
import numpy as np
tree, out, repeats = sys.argv[1], sys.argv[2], int(sys.argv[3])
sys.path[:0] = [tree + "/src", tree + "/benchmarks"]
import sonarsim
assert sonarsim.__file__.startswith(tree), sonarsim.__file__
from bench_render import tank_scene
from sonarsim.config.examples import demo_scene_dict

def scenes():
    demo = demo_scene_dict()
    sensor = copy.deepcopy(demo); sensor["sensor"] = {"preset": "aris3000-128"}
    sensor["sonar"] = {**sensor["sonar"], "preset": "aris3000-128"}
    for k in ("n_beams", "azimuth_fov_deg", "elevation_fov_deg", "n_range_bins", "range_resolution_m",
              "beam_angles_deg", "frequency_khz"):
        sensor["sonar"].pop(k, None)
    paper = copy.deepcopy(demo); paper["render"]["method"] = "paper"
    return {"demo": (demo, "all"), "sensor": (sensor, False), "tank": (tank_scene(6), "total"),
            "mirrors": (tree + "/examples/materials.yaml", False), "paper": (paper, False)}

arrays, times = {}, {}
for name, (scene, labels) in scenes().items():
    sim = sonarsim.Simulator(scene)
    img = sim.render(frame=3, labels=labels)
    for k, v in img.components.items():
        arrays[f"{name}/components/{k}"] = np.asarray(v)
    arrays[f"{name}/polar"] = img.polar
    if img.rays is not None:
        arrays[f"{name}/rays/distance"] = img.rays.distance_m
        arrays[f"{name}/rays/intensity"] = img.rays.intensity
    if img.labels is not None:
        for k, v in img.labels.arrays().items() if hasattr(img.labels, "arrays") else []:
            arrays[f"{name}/labels/{k}"] = np.asarray(v)
    t = []
    for i in range(repeats):
        t0 = time.perf_counter(); sim.render(frame=i, keep_rays=False); t.append(time.perf_counter() - t0)
    times[name] = 1e3 * float(np.median(t))
    sim.close()
np.savez(out, **arrays)
print(json.dumps(times))
"""


def one(tree: Path, out: Path, repeats: int) -> dict:
    r = subprocess.run([sys.executable, "-c", CHILD, str(tree), str(out), str(repeats)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{tree}: the run failed:\n{r.stderr.strip()[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trees", nargs=2, type=Path, help="before, after: checkouts with their extensions built")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    trees = [t.resolve() for t in args.trees]
    times: dict[str, list] = {str(t): [] for t in trees}
    with tempfile.TemporaryDirectory() as tmp:
        files = [Path(tmp) / f"{i}.npz" for i in range(2)]
        for run in range(args.runs):
            for t, f in zip(trees, files):
                times[str(t)].append(one(t, f, args.repeats))
        a, b = np.load(files[0]), np.load(files[1])
        differ = [k for k in sorted(set(a.files) | set(b.files))
                  if k not in a.files or k not in b.files or a[k].shape != b[k].shape
                  or a[k].tobytes() != b[k].tobytes()]
        n = len(set(a.files) | set(b.files))
    print(f"arrays compared: {n}; differing bits: {len(differ)}" + (f" ({', '.join(differ[:10])})" if differ else ""))
    summary = {}
    for name in times[str(trees[0])][0]:
        before = float(np.median([r[name] for r in times[str(trees[0])]]))
        after = float(np.median([r[name] for r in times[str(trees[1])]]))
        summary[name] = {"before_ms": before, "after_ms": after, "after_over_before": after / before}
        print(f"{name:8s} before {before:8.2f} ms  after {after:8.2f} ms  ratio {after / before:.3f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"arrays": n, "differing": differ, "frames": summary}, indent=1) + "\n")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
