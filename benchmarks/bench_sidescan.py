"""A side-scan ping against a bare cast of its rays, and how its cost grows (issue 38 item 9).

The Sea Scan HDS preset 10 m over a flat sandy floor with three objects (a box, a sphere, a
cylinder) and, in case ``surface``, a water surface 15 m above the floor (its multipath); in
case ``mesh_floor_32k_rays`` the floor is a mesh (as a bathymetry is: Embree meets every ray)
and each side casts 4 x 4,096 rays.

A ping is measured two ways: within a waterfall of ``PINGS`` pings (a survey: where the scene
lets one engine frame hold several poses -- direct paths, ``Simulator.trace_poses`` -- many
pings' sides go through the kernels in one frame) and alone (one ping: its two sides in one
frame). Its bare cast is Embree casting the very rays the pings cast
(``bench_render.record_casts``; one call, no conversion of the hits), nothing else, per ping.
With the surface (multipath: transmit legs by each pose's own image sources) every side is a
frame of its own. Pings and bare casts alternate in blocks so that the machine's load hits both
alike: compare their ratio, not the times, across runs or machines.

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

#: Pings of the waterfall measured (a survey's steady state: a ping within many).
PINGS = 64

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


def measure(doc: dict, repeats: int, pings: int = PINGS) -> dict:
    """One ping alone, and a ping within a waterfall of ``pings`` (a survey's steady state:
    many pings in one engine frame where the scene lets one hold them), each against the bare
    casting of the very rays it cast."""
    sim = sonarsim.Simulator(doc)
    one = lambda: render_pings(sim, n_pings=1, speckle=False)  # noqa: E731
    many = lambda: render_pings(sim, n_pings=pings, speckle=False)  # noqa: E731
    for _ in range(2):
        one()
        many()
    rec_one, rec_many = record_casts(sim, one), record_casts(sim, many)
    n_rays = sum(len(d) for _, _, d, _, _ in rec_one)
    t_one, t_many, c_one, c_many = [], [], [], []
    for _ in range(max(1, repeats // 5)):
        for _ in range(5):
            t = time.perf_counter()
            one()
            t_one.append(time.perf_counter() - t)
        t = time.perf_counter()
        many()
        t_many.append((time.perf_counter() - t) / pings)
        for _ in range(5):
            c_one.append(min(bare_cast_s(rec_one, 1), bare_cast_s(rec_one, 2)))
        c_many.append(min(bare_cast_s(rec_many, 1), bare_cast_s(rec_many, 2)) / pings)
    sim.close()
    p1, c1 = statistics.median(t_one), statistics.median(c_one)
    pn, cn = statistics.median(t_many), statistics.median(c_many)
    return {"rays_per_ping": n_rays, "pings": pings,
            "ping_ms": 1e3 * pn, "bare_cast_ms": 1e3 * cn, "ping_over_cast": pn / cn,
            "alone_ping_ms": 1e3 * p1, "alone_bare_cast_ms": 1e3 * c1, "alone_over_cast": p1 / c1}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    results = {}
    cases = [("flat_1024", scene(), PINGS), ("surface_1024", scene(surface=True), PINGS),
             ("flat_256", scene(256), PINGS), ("flat_4096", scene(4096), PINGS),
             ("mesh_floor_32k_rays", mesh_floor(scene()), PINGS)]
    cases += [(f"flat_1024_pings_{n}", scene(), n) for n in (8, 32, 256)]
    cases += [(f"mesh_floor_pings_{n}", mesh_floor(scene()), n) for n in (8, 256)]
    print(f"{'case':22s} {'rays':>7s}  {'ping':>9s}  {'bare cast':>9s}  ratio   (one ping alone: ping, cast, ratio)")
    for name, doc, n in cases:
        r = measure(doc, args.repeats, n)
        results[name] = r
        print(f"{name:22s} {r['rays_per_ping']:7d}  {r['ping_ms']:6.3f} ms  {r['bare_cast_ms']:6.3f} ms  "
              f"{r['ping_over_cast']:5.2f}   ({r['alone_ping_ms']:.2f} ms, {r['alone_bare_cast_ms']:.3f} ms, "
              f"{r['alone_over_cast']:.1f})", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
