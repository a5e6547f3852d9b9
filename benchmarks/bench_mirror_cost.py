"""Mesh mirrors' cost (issue 37): a smooth mirror sphere's frame against a flat one's, and a
crowd of small mirror boxes at a high order: its frame, and the images of its path signatures.

Usage::

    python benchmarks/bench_mirror_cost.py                 # sphere of 81,920 facets, 300 boxes
    python benchmarks/bench_mirror_cost.py --subdivisions 7 --boxes 900 --aris

Prints one line per case (build, first frame, second frame, signatures and their images' time
and size). Times are wall-clock on this machine, whatever else it runs.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import sonarsim  # noqa: E402


def sphere_case(mesh: str, normals: str) -> dict:
    return {"sonar": {"n_beams": 64, "azimuth_fov_deg": 60, "elevation_fov_deg": 20, "range_min_m": 0.5,
                      "range_max_m": 8, "n_range_bins": 400, "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 5, 0]}},
            "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5}, "render": {"max_order": 3},
            "objects": [{"name": "ball", "mesh": mesh, "pose": {"position_m": [5, 0, 1.5]}, "albedo": 0.5,
                         "specular": 0.9, "normals": normals}]}


def boxes_case(n: int, aris: bool) -> dict:
    rng = np.random.default_rng(0)
    side = int(np.ceil(np.sqrt(n)))
    objects = [{"name": f"b{k}", "primitive": "box", "size_m": [0.05, 0.05, 0.05],
                "pose": {"position_m": [2.0 + 1.5 * (k // side) / side, -0.75 + 1.5 * (k % side) / side,
                                        0.3 + 0.4 * rng.random()], "rpy_deg": (rng.random(3) * 90).tolist()},
                "albedo": 0.5, "specular": 0.8} for k in range(n)]
    sonar = ({"preset": "aris3000-128", "range_min_m": 0.5, "range_max_m": 5} if aris else
             {"n_beams": 64, "azimuth_fov_deg": 60, "elevation_fov_deg": 20, "range_min_m": 0.5, "range_max_m": 5,
              "n_range_bins": 400})
    wall = {"albedo": 0.6, "specular": 0.5}
    return {"sonar": {**sonar, "pose": {"position_m": [0, 0, 0.5], "rpy_deg": [0, 5, 0]}},
            "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
            "planes": [{"name": "surface", "point_m": [0, 0, 2.0], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9},
                       {"name": "far_wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], **wall},
                       {"name": "left_wall", "point_m": [0, 1.5, 0], "normal": [0, -1, 0], **wall},
                       {"name": "right_wall", "point_m": [0, -1.5, 0], "normal": [0, 1, 0], **wall}],
            "render": {"max_order": 5, "glints": True}, "objects": objects}


def run(name: str, doc: dict, signatures: bool) -> None:
    t0 = time.perf_counter()
    sim = sonarsim.Simulator(doc)
    t1 = time.perf_counter()
    image = sim.render(speckle=False)
    t2 = time.perf_counter()
    sim.render(speckle=False)
    t3 = time.perf_counter()
    line = f"{name}: build {t1 - t0:.2f} s, first frame {t2 - t1:.2f} s, second {t3 - t2:.2f} s"
    if signatures:
        n = len(image.components.signatures)
        t4 = time.perf_counter()
        line += f", {n} signature images in {t4 - t3:.2f} s"
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{line}, peak RSS {rss:.0f} MB", flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--subdivisions", type=int, default=6, help="icosphere subdivisions (6: 81,920 facets)")
    p.add_argument("--boxes", type=int, default=300, help="small mirror boxes (default 300)")
    p.add_argument("--aris", action="store_true", help="the boxes seen by an ARIS 3000 (1288 x 128 images)")
    args = p.parse_args(argv)
    import trimesh

    with tempfile.TemporaryDirectory() as tmp:
        mesh = str(Path(tmp) / "sphere.stl")
        trimesh.creation.icosphere(subdivisions=args.subdivisions, radius=1.0).export(mesh)
        for normals in ("flat", "smooth"):
            run(f"sphere of {20 * 4 ** args.subdivisions} facets, {normals}", sphere_case(mesh, normals), False)
    run(f"{args.boxes} mirror boxes, max_order 5, glints", boxes_case(args.boxes, args.aris), True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
