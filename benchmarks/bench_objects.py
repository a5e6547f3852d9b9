"""Scenes of many small objects: load, build and first-frame time against the object count.

Usage::

    python benchmarks/bench_objects.py [--counts 1250 2500 5000 10000 20000] [--out benchmarks/objects.json]

Each count is a scene file of that many spheres of 1 cm (radius_m 0.01, 320 triangles each)
scattered in front of the demo's ARIS 3000 over a floor, written as a user would (one object a
line). For each: reading the file (``load_scene``), building the simulator (objects placed,
clipped at the floor, Embree's tree), one frame, and the peak memory of the process, each in a
fresh process so that counts do not share caches. The per-object figures show whether the cost
grows linearly (issue 21: 20,000 such spheres ran past 400 s and 10 GB before). The machine is
shared: compare the ratios within one run.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
import sonarsim
t1 = time.perf_counter()
scene = sonarsim.load_scene(sys.argv[1])
t2 = time.perf_counter()
sim = sonarsim.Simulator(scene)
t3 = time.perf_counter()
sim.render(keep_rays=False)
t4 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "load_s": t2 - t1, "build_s": t3 - t2, "frame_s": t4 - t3,
                  "triangles": int(sum(len(m.faces) for m in sim.meshes)),
                  "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def scene_text(n: int, seed: int = 0) -> str:
    """A scene file of ``n`` spheres of 1 cm in front of the demo sonar, one object a line."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(1.0, 4.5, n), rng.uniform(-1.0, 1.0, n), rng.uniform(0.02, 0.5, n)])
    lines = [f"  - {{name: s{i}, primitive: sphere, radius_m: 0.01, pose: {{position_m: [{x:.4f}, {y:.4f}, {z:.4f}]}}}}"
             for i, (x, y, z) in enumerate(xyz)]
    return ("sonar: {preset: aris3000-128, pose: {position_m: [0, 0, 1], rpy_deg: [0, 20, 0]}}\n"
            "ground: {height_m: 0.0}\nobjects:\n" + "\n".join(lines) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1250, 2500, 5000, 10000, 20000])
    parser.add_argument("--out", default=None, help="write the figures as JSON here")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.counts:
            path = Path(tmp) / f"spheres{n}.yaml"
            path.write_text(scene_text(n))
            done = subprocess.run([sys.executable, "-c", CHILD, str(path)], capture_output=True, text=True, check=True)
            row = {"objects": n, "file_mib": path.stat().st_size / 2**20, **json.loads(done.stdout.strip().splitlines()[-1])}
            total = row["load_s"] + row["build_s"]
            row["ms_per_object"] = 1000 * total / n
            rows.append(row)
            print(f"{n:6d} objects {row['triangles']:>10,} triangles  file {row['file_mib']:5.2f} MiB  "
                  f"load {row['load_s']:6.2f} s  build {row['build_s']:6.2f} s  frame {row['frame_s']:5.2f} s  "
                  f"peak {row['peak_mib']:7.0f} MiB  ({row['ms_per_object']:.2f} ms an object)", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({"machine": platform.platform(), "python": sys.version.split()[0],
                                              "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
