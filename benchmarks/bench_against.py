"""Frame times of two source trees, run in turn on this machine (issue 23 item 6: the engine
against the former fused ground route).

Each tree must be a checkout with its compiled extensions built in place (``python setup.py
build_ext --inplace``); each run imports sonarsim from that tree's ``src`` in a fresh process
and measures, with that tree's own ``benchmarks/bench_render.py``, the ground-only demo (case
a: frame time, bare casting of the very rays the frame cast, their ratio) and the demo tank with
a water surface and four walls at order 3 (case e). The trees alternate, ``--runs`` times, so
that the machine's load drifts hit both alike: compare their figures, not either with a figure
taken at another hour or on another machine.

Usage (the commit before the fused ground route was retired, built beside this one)::

    git worktree add /tmp/fused 94a4ddd~1
    (cd /tmp/fused && python setup.py build_ext --inplace)
    python benchmarks/bench_against.py /tmp/fused . [--runs 3] [--repeats 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

# Run in the child: the tree's own package and benchmark code, nothing of this process.
CHILD = """
import json, sys
tree = sys.argv[1]
sys.path[:0] = [tree + "/src", tree + "/benchmarks"]
import sonarsim
assert sonarsim.__file__.startswith(tree), sonarsim.__file__
from bench_render import measure, tank_scene
from sonarsim.config.examples import demo_scene_dict
demo = measure("a", demo_scene_dict(), int(sys.argv[2]))
tank = measure("e", tank_scene(6), int(sys.argv[2]))
print(json.dumps({"demo_frame_ms": demo["frame_ms"], "demo_bare_cast_ms": demo["bare_cast_ms"],
                  "demo_frame_over_cast": demo["frame_over_cast"], "tank_frame_ms": tank["frame_ms"],
                  "tank_over_demo": tank["frame_ms"] / demo["frame_ms"]}))
"""


def one(tree: Path, repeats: int) -> dict:
    """One tree's figures, measured in a fresh process."""
    out = subprocess.run([sys.executable, "-c", CHILD, str(tree), str(repeats)], capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{tree}: the measurement failed:\n{out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trees", nargs=2, type=Path, help="two checkouts with their extensions built in place")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=40)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    trees = [t.resolve() for t in args.trees]
    for t in trees:
        if not (t / "src" / "sonarsim").is_dir() or not (t / "benchmarks" / "bench_render.py").is_file():
            raise SystemExit(f"{t}: not a sonarsim checkout (no src/sonarsim or benchmarks/bench_render.py)")
    results: dict[str, list] = {str(t): [] for t in trees}
    for run in range(args.runs):
        for t in trees:
            r = one(t, args.repeats)
            results[str(t)].append(r)
            print(f"run {run + 1} {t}: demo {r['demo_frame_ms']:.3f} ms, frame/cast {r['demo_frame_over_cast']:.2f}; "
                  f"six planes {r['tank_frame_ms']:.3f} ms, {r['tank_over_demo']:.2f}x the demo", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
