"""The differentiable renderer's cost, measured against its estimate (issue 37).

Each configuration runs in a fresh process: build a ``sonarsim.diff.Renderer``, render once,
take one gradient; its wall times, peak memory and the search's counts are printed beside
``sonarsim.diff.cost.diff_cost``'s estimate (before the search and with its counts), so that
the rates in ``src/sonarsim/diff/cost.py`` can be checked and measured again.

Usage::

    python benchmarks/bench_diff_cost.py                      # the default grid of scenes
    python benchmarks/bench_diff_cost.py spheres:300 grid:128 tank
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time

DEFAULT = ("spheres:10", "spheres:100", "spheres:300", "grid:32", "grid:128", "demo", "tank")


def scene(kind: str, n: int) -> dict:
    import numpy as np

    rng = np.random.default_rng(0)
    sonar = {"n_beams": 64, "azimuth_fov_deg": 60, "elevation_fov_deg": 20, "range_min_m": 0.5, "range_max_m": 5,
             "n_range_bins": 256, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}}
    if kind == "spheres":  # the issue's: n spheres of 3 cm on a ground
        objs = [{"name": f"s{i}", "primitive": "sphere", "radius_m": 0.03,
                 "pose": {"position_m": [float(rng.uniform(1, 4)), float(rng.uniform(-1, 1)),
                                         float(rng.uniform(0.03, 0.3))]}} for i in range(n)]
        return {"sonar": sonar, "ground": {}, "objects": objs}
    if kind == "grid":  # n beams of 4n range bins, a box on a ground
        return {"sonar": {**sonar, "n_beams": n, "n_range_bins": 4 * n}, "ground": {},
                "objects": [{"name": "b", "primitive": "box", "size_m": [0.5, 0.5, 0.5],
                             "pose": {"position_m": [3, 0, 0.25]}}]}
    from sonarsim.cli import demo

    return demo.tank_scene_dict() if kind == "tank" else demo.demo_scene_dict()


def measure(spec: str) -> dict:
    """Run one configuration here (in this process) and return its figures."""
    import jax

    import sonarsim.diff as sd
    from sonarsim.config.loader import load_scene
    from sonarsim.diff.cost import diff_cost

    kind, _, n = spec.partition(":")
    doc = scene(kind, int(n or 0))
    before = diff_cost(load_scene(doc))
    base_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    r = sd.Renderer(doc)
    t1 = time.perf_counter()
    jax.block_until_ready(r.render())
    t2 = time.perf_counter()
    jax.block_until_ready(jax.grad(lambda p: r.render(p).sum())(r.params()))
    t3 = time.perf_counter()
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"scene": spec, "objects": len(r.scene.objects), "paths": r.search.n_paths,
            "estimated_paths": before.paths, "build_s": round(t1 - t0, 2), "render_s": round(t2 - t1, 2),
            "gradient_s": round(t3 - t2, 2), "total_s": round(t3 - t0, 2), "estimated_s": round(r.cost.seconds, 1),
            "estimated_before_search_s": round(before.seconds, 1),
            "peak_mib_beyond_imports": round(peak_mb - base_mb), "estimated_mib": round(r.cost.bytes / 2**20),
            "estimated_before_search_mib": round(before.bytes / 2**20), "load": round(os.getloadavg()[0], 1)}


def main(argv: list[str]) -> int:
    if argv[:1] == ["--one"]:
        print(json.dumps(measure(argv[1])))
        return 0
    for spec in argv or DEFAULT:
        out = subprocess.run([sys.executable, __file__, "--one", spec], capture_output=True, text=True)
        lines = out.stdout.strip().splitlines()
        print(lines[-1] if out.returncode == 0 and lines else json.dumps({"scene": spec, "error": out.stderr[-500:]}),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
