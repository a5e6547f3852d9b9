"""The long mirror-scene fuzzing run (issue 37): N seeded random mirror scenes, a JSON summary.

Every case is a random scene of mesh mirrors (flat or smooth normals), planes, orders up to 6
and specular returns, one in 20 a crowd of 200 to 900 small mirror boxes at order 4 to 6
(``tests/fuzz/mirrors.py``), loaded, rendered and its components listed under a 64 MiB memory
budget: it must end in a refusal naming a key or in a frame that is finite, non-negative, of the
configured shape, whose signature images add up to its order images, within the budget (traced
allocations, every ``--trace-every``-th case) and the time limit.

Usage::

    python benchmarks/fuzz_mirrors.py                     # 2,000 cases, seed 0
    python benchmarks/fuzz_mirrors.py --cases 500 --seed 3 --out benchmarks/fuzz_mirrors.json

Exit status 1 when any case failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # for tests.fuzz

from tests.fuzz.mirrors import MirrorSummary, check_mirror_case, generate_mirror_cases  # noqa: E402
from tests.fuzz.scenes import FUZZ_BUDGET_BYTES  # noqa: E402


def run(cases: int, seed: int, trace_every: int, progress: bool = True) -> dict:
    """Run ``cases`` cases from ``seed``; the summary as a JSON-ready dict."""
    summary = MirrorSummary()
    peak, slowest = 0, ""
    t0 = time.perf_counter()
    for case in generate_mirror_cases(cases, seed):
        out = check_mirror_case(case, trace_memory=trace_every > 0 and case.index % trace_every == 0)
        if out.seconds >= summary.slowest_s:
            slowest = case.describe()
        summary.add(out)
        peak = max(peak, out.peak_bytes)
        if progress and (case.index + 1) % 100 == 0:
            print(f"{case.index + 1} cases, {len(summary.failures)} failures, {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    return {
        "cases": summary.cases,
        "seed": seed,
        "crowds_of_mirror_boxes": summary.crowds,
        "rendered": summary.rendered,
        "signature_images": summary.signatures,
        "refused": sum(summary.refused.values()),
        "refused_by_key": dict(sorted(summary.refused.items(), key=lambda kv: -kv[1])),
        "failures": len(summary.failures),
        "failure_cases": summary.failures[:50],
        "slowest_case_s": round(summary.slowest_s, 2),
        "slowest_case": slowest,
        "peak_traced_mib": round(peak / 2**20, 2),
        "budget_mib": FUZZ_BUDGET_BYTES // 2**20,
        "wall_s": round(wall, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=2000, help="number of cases (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the scenes (default 0)")
    p.add_argument("--trace-every", type=int, default=5, metavar="N",
                   help="trace allocations in every N-th case (default 5; 0: none)")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = p.parse_args(argv)
    result = run(args.cases, args.seed, args.trace_every)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
