"""Time mesh mirrors (issue 25, item 6): the demo with its block and pipe made mirrors against
the demo, and a specular hull over a floor by its triangle count and the path order.

Ratios are taken in one run on one machine (timings swing with the load):

* ``demo_mirrors / demo``: the demo scene at order 3, its concrete block and pipe with
  ``specular: 0.5`` (the target: 1.6), the medians of frames of the two taken in turn;
* ``hull, order k / order 1``: an ellipsoidal hull (6 x 2 x 1.5 m, a UV sphere of about
  ``--triangles`` faces, ``specular: 0.8``) 1 m over a plane floor, seen from below and
  ahead (the target at 50,000 triangles and order 3: 3), the orders' frames taken in turn;
* the same at orders 1 and 3 for a range of triangle counts: how the cost grows with them.

    python benchmarks/bench_mirrors.py [--rounds 10] [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
import time
from pathlib import Path

import numpy as np

import sonarsim
from sonarsim.config.examples import demo_scene_dict


def paired_times(docs: list[dict], rounds: int, batch: int = 10) -> tuple[np.ndarray, list[str]]:
    """Frame times of several scenes taken in turn, round after round: (rounds * batch,
    len(docs)) seconds, and the kernels each used. Taken in turn, a swing in the machine's
    load falls on every scene alike; the medians' ratio is the figure. Each turn is a batch of
    frames after one more to warm up: a simulator's worker thread watches for its next task
    for a millisecond after a frame (``SecondCore.SPIN_S``), so frames of two simulators taken
    one by one would each find the other's worker on a core."""
    sims = [sonarsim.Simulator(doc) for doc in docs]
    try:
        for sim in sims:
            sim.render(keep_rays=False)
        out = np.empty((rounds, batch, len(sims)))
        for r in range(rounds):
            for k, sim in enumerate(sims):
                sim.render(keep_rays=False)
                for j in range(batch):
                    t = time.perf_counter()
                    sim.render(keep_rays=False)
                    out[r, j, k] = time.perf_counter() - t
        return out.reshape(-1, len(sims)), [sim.path_kernels for sim in sims]
    finally:
        for sim in sims:
            sim.close()


def hull_mesh(folder: Path, triangles: int) -> str:
    """A PLY file of an ellipsoidal hull with about ``triangles`` faces."""
    import trimesh

    n = max(int(round(np.sqrt(triangles / 4.0))), 4)  # a UV sphere of count n has about 4 n^2 faces
    m = trimesh.creation.uv_sphere(radius=1.0, count=[n, n])
    m.apply_scale([3.0, 1.0, 0.75])
    path = folder / f"hull_{len(m.faces)}.ply"
    m.export(path)
    return str(path), len(m.faces)


def hull_scene(mesh: str, order: int) -> dict:
    return {
        "sonar": {"preset": "aris3000-128", "range_min_m": 0.5, "range_max_m": 8.0, "n_range_bins": 1000,
                  "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, -4.0, 0.0]}},
        "render": {"max_order": order},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "objects": [{"name": "hull", "mesh": mesh, "pose": {"position_m": [5.0, 0.0, 2.75]}, "albedo": 0.3,
                     "specular": 0.8}],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=10, help="turns of 10 frames per hull scene")
    parser.add_argument("--triangles", type=int, default=50_000)
    parser.add_argument("--quick", action="store_true", help="fewer frames and triangle counts")
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args()
    out: dict = {}

    demo = demo_scene_dict()
    mirrors = copy.deepcopy(demo)
    for obj in mirrors["objects"]:
        if obj["name"] in ("concrete_block", "pipe"):
            obj["specular"] = 0.5
    times, (k_demo, k_mirror) = paired_times([demo, mirrors], 3 if args.quick else 30)
    t_demo, t_mirror = np.median(times, axis=0)
    best = times.min(axis=0)
    out["demo_s"], out["demo_mirrors_s"] = t_demo, t_mirror
    out["demo_ratio"] = t_mirror / t_demo
    out["demo_ratio_best"] = best[1] / best[0]
    print(f"demo, order 3 ({k_demo}): {t_demo * 1e3:.2f} ms; block and pipe mirrors ({k_mirror}): "
          f"{t_mirror * 1e3:.2f} ms (medians of {len(times)} frames taken in turn); ratio {t_mirror / t_demo:.2f}, "
          f"of the best frames {best[1] / best[0]:.2f} (target 1.6)")

    rounds = 2 if args.quick else args.rounds
    with tempfile.TemporaryDirectory() as tmp:
        mesh, n_faces = hull_mesh(Path(tmp), args.triangles)
        orders = (1, 3) if args.quick else (1, 2, 3, 4)
        hull_times, kernels = paired_times([hull_scene(mesh, order) for order in orders], rounds)
        times = dict(zip(orders, np.median(hull_times, axis=0)))
        for order, k in zip(orders, kernels):
            print(f"hull, {n_faces} triangles, order {order} ({k}): {times[order] * 1e3:.2f} ms; "
                  f"{times[order] / times[1]:.2f} x order 1")
        out["hull_triangles"] = n_faces
        out["hull_order_s"] = {str(k): v for k, v in times.items()}
        out["hull_ratio_order3"] = times[3] / times[1]
        print(f"hull order 3 / order 1: {times[3] / times[1]:.2f} (target 3)")
        counts = (2_000, args.triangles) if args.quick else (500, 2_000, 8_000, 20_000, args.triangles)
        growth = {}
        for count in counts:
            mesh, n_faces = hull_mesh(Path(tmp), count)
            t1, t3 = np.median(paired_times([hull_scene(mesh, 1), hull_scene(mesh, 3)], rounds)[0], axis=0)
            growth[n_faces] = (t1, t3)
            print(f"  {n_faces:>6} triangles: order 1 {t1 * 1e3:7.2f} ms, order 3 {t3 * 1e3:7.2f} ms ({t3 / t1:.2f} x)")
        out["growth"] = {str(k): {"order1_s": a, "order3_s": b} for k, (a, b) in growth.items()}
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
