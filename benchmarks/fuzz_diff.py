"""The long fuzzing run of the differentiable engine's parameters (issue 37): N seeded cases,
a JSON summary.

Every case changes one to three parameters of a small scene with a sensor and renders it
directly, through ``jax.grad``, ``jax.vmap``, after ``refresh``, or inside ``jit`` (see
``tests/fuzz/diff_params.py``): it must end in a one-line ``ConfigError`` naming a changed
parameter and its range (for values not finite or beyond the scene format's bounds), or in a
finite image and gradient (for the others, and for every degenerate but finite value inside
``jit``). Anything else is a failure.

Usage::

    python benchmarks/fuzz_diff.py                  # 5,000 cases, seed 0
    python benchmarks/fuzz_diff.py --cases 500 --seed 3 --out fuzz.json

Exit status 1 when any case failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # for tests.fuzz

from tests.fuzz.diff_params import Harness, Summary, check_case, generate_cases  # noqa: E402


def run(cases: int, seed: int, progress: bool = True) -> dict:
    """Run ``cases`` cases from ``seed``; returns the summary as a JSON-ready dict."""
    t0 = time.perf_counter()
    harness = Harness()
    setup = time.perf_counter() - t0
    summary = Summary()
    t1 = time.perf_counter()
    for case in generate_cases(harness.renderer, cases, seed):
        summary.add(check_case(harness, case))
        if progress and (case.index + 1) % 500 == 0:
            print(f"{case.index + 1} cases, {len(summary.failures)} failures, {time.perf_counter() - t1:.0f} s",
                  file=sys.stderr, flush=True)
    wall = time.perf_counter() - t1
    return {
        "cases": summary.cases,
        "seed": seed,
        "by_mode": dict(sorted(summary.by_mode.items())),
        "values_by_kind": dict(sorted(summary.by_kind.items(), key=lambda kv: -kv[1])),
        "rendered": summary.rendered,
        "refused": sum(summary.refused.values()),
        "refused_by_key": dict(sorted(summary.refused.items(), key=lambda kv: -kv[1])),
        "failures": len(summary.failures),
        "failure_cases": summary.failures[:50],
        "slowest_case_s": round(summary.slowest_s, 3),
        "slowest_case": summary.slowest_case[:500],
        "setup_s": round(setup, 1),
        "wall_s": round(wall, 1),
        "cases_per_s": round(summary.cases / wall, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=5000, help="number of cases (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the values (default 0)")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = p.parse_args(argv)
    result = run(args.cases, args.seed)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
