"""A side-scan ping against a bare cast of its rays, and how its cost grows (issue 38 item 9).

The Sea Scan HDS preset 10 m over a flat sandy floor with three objects (a box, a sphere, a
cylinder) and, in case ``surface``, a water surface 15 m above the floor (its multipath); in
case ``mesh_floor_32k_rays`` the floor is a mesh (as a bathymetry is: Embree meets every ray)
and each side casts 4 x 4,096 rays. Each
ping is two engine frames (port, starboard: ``Simulator.trace`` + ``Simulator.form``); its bare
cast is Embree casting the very rays the ping cast (``bench_render.record_casts``), nothing
else. Frames and bare casts alternate in blocks so that the machine's load hits both alike:
compare their ratio, not the times, across runs or machines.

Usage::

    python benchmarks/bench_sidescan.py [--repeats 20] [--json benchmarks/sidescan.json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import sonarsim  # noqa: E402
from bench_render import bare_cast_s, record_casts  # noqa: E402
from sonarsim.instruments import render_pings  # noqa: E402

OBJECTS = [
    {"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [0.0, 15.0, 0.5]}},
    {"name": "ball", "primitive": "sphere", "radius_m": 0.6, "pose": {"position_m": [0.0, -12.0, 0.6]}},
    {"name": "pipe", "primitive": "cylinder", "radius_m": 0.3, "height_m": 4.0,
     "pose": {"position_m": [0.0, 6.0, 0.3], "rpy_deg": [90, 0, 0]}},
]


def scene(n_samples: int = 1024, surface: bool = False) -> dict:
    doc = {"sonar": {"type": "sidescan", "preset": "seascan_hds_600", "n_samples": n_samples,
                     "pose": {"position_m": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, 0.0]}},
           "ground": {"height_m": 0.0}, "objects": OBJECTS, "render": {"max_order": 3 if surface else 1}}
    if surface:
        doc["planes"] = [{"name": "surface", "point_m": [0, 0, 15.0], "normal": [0, 0, -1], "albedo": 0.0,
                          "specular": 0.9}]
    return doc


def mesh_floor(doc: dict, azimuth_samples: int = 4, elevation_samples: int = 4096) -> dict:
    """The same survey over a floor that is a mesh (a bathymetry's case: Embree meets every ray),
    sampled densely (4 rays across the beam, 4,096 down it)."""
    out = {**doc, "objects": doc["objects"] + [{"name": "seabed", "primitive": "box", "size_m": [200.0, 200.0, 1.0],
                                                  "pose": {"position_m": [0.0, 0.0, -0.5]}}]}
    out.pop("ground")
    out["render"] = {**doc["render"], "azimuth_samples": azimuth_samples, "elevation_samples": elevation_samples}
    return out


def measure(doc: dict, repeats: int) -> dict:
    sim = sonarsim.Simulator(doc)
    ping = lambda: render_pings(sim, n_pings=1, speckle=False)  # noqa: E731
    for _ in range(3):
        ping()
    recorded = record_casts(sim, ping)
    n_rays = sum(len(d) for _, _, d, _, _ in recorded)
    pings, casts = [], []
    for _ in range(max(1, repeats // 5)):
        for _ in range(5):
            t = time.perf_counter()
            ping()
            pings.append(time.perf_counter() - t)
        for _ in range(5):
            casts.append(min(bare_cast_s(recorded, 1), bare_cast_s(recorded, 2)))
    t = time.perf_counter()
    render_pings(sim, n_pings=50, speckle=False)
    fifty = time.perf_counter() - t
    sim.close()
    p, c = statistics.median(pings), statistics.median(casts)
    return {"rays_per_ping": n_rays, "ping_ms": 1e3 * p, "bare_cast_ms": 1e3 * c, "ping_over_cast": p / c,
            "ms_per_ping_of_50": 1e3 * fifty / 50}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    results = {}
    for name, doc in (("flat_1024", scene()), ("surface_1024", scene(surface=True)),
                      ("flat_256", scene(256)), ("flat_4096", scene(4096)), ("mesh_floor_32k_rays", mesh_floor(scene()))):
        r = measure(doc, args.repeats)
        results[name] = r
        print(f"{name:13s} {r['rays_per_ping']:7d} rays  ping {r['ping_ms']:7.2f} ms  bare cast {r['bare_cast_ms']:6.2f} ms"
              f"  ratio {r['ping_over_cast']:.2f}  ({r['ms_per_ping_of_50']:.2f} ms a ping over 50)", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
