"""The long scene-file fuzzing run (issue 11 item 6): N seeded cases, a JSON summary.

Every case is a mutation of an example scene (document or text level, see
``tests/fuzz/scenes.py``) checked as the test suite checks its few thousand: it must end in the
documented error (a SonarsimError whose one-line message names the key or file) or in a
plausible scene; a sample of the accepted scenes is rendered under a 64 MiB memory budget and
must give a finite image of the configured shape (or a ConfigError). Any other exception, a case
past its time limit, a traced allocation beyond the budget or a NumPy overflow warning is a
failure.

Usage::

    python benchmarks/fuzz_scenes.py                  # 100,000 cases, seed 0
    python benchmarks/fuzz_scenes.py --cases 5000 --seed 3 --render-every 10 --out fuzz.json

Exit status 1 when any case failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # for tests.fuzz

from tests.fuzz.scenes import FUZZ_BUDGET_BYTES, Summary, check_case, generate_cases  # noqa: E402


def run(cases: int, seed: int, render_every: int, trace_every: int, progress: bool = True) -> dict:
    """Run ``cases`` cases from ``seed``; returns the summary as a JSON-ready dict.

    Parameters
    ----------
    cases, seed : int
    render_every : int
        Every that many cases (0: none) also renders the scene if it loads.
    trace_every : int
        Every that many cases (0: none), and every render, traces allocations against the
        budget (about three times slower).
    """
    summary = Summary()
    by_level = {"doc": 0, "text": 0, "files": 0}
    # Issue 21's hostile cases, by kind (tests/fuzz/scenes.py, hostile_case).
    hostile = {"many objects": 0, "aliases": 0, "referenced files": 0}
    refused_at_load = 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonarsim-fuzz-") as tmp:
        for case in generate_cases(cases, seed, render_every=render_every):
            trace = case.render or (trace_every > 0 and case.index % trace_every == 0)
            out = check_case(case, Path(tmp), trace_memory=trace)
            summary.add(out)
            by_level[case.level] += 1
            if case.seed_name in hostile:
                hostile[case.seed_name] += 1
            elif case.level == "text" and any("alias" in m or "merge key" in m for m in case.mutations):
                hostile["aliases"] += 1
            refused_at_load += not out.accepted and out.failure is None
            if progress and (case.index + 1) % 10000 == 0:
                print(f"{case.index + 1} cases, {len(summary.failures)} failures, "
                      f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    refused = dict(sorted(summary.refused.items(), key=lambda kv: -kv[1]))
    render_refused = {k: v for k, v in refused.items() if k.startswith("render:")}
    return {
        "cases": summary.cases,
        "seed": seed,
        "by_level": by_level,
        "hostile": hostile,
        "accepted": summary.accepted,
        "rendered": summary.rendered,
        "refused_at_load": refused_at_load,
        "refused_at_render": sum(render_refused.values()),
        "distinct_error_keys": len(refused),
        "outcomes_by_error_key": refused,
        "failures": len(summary.failures),
        "failure_cases": summary.failures[:50],
        "slowest_case_s": round(summary.slowest_s, 4),
        "slowest_case": summary.slowest_case[:500],
        "peak_traced_mib": round(summary.peak_bytes / 2**20, 2),
        "budget_mib": FUZZ_BUDGET_BYTES // 2**20,
        "wall_s": round(wall, 1),
        "cases_per_s": round(summary.cases / wall, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=100_000, help="number of cases (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the mutations (default 0)")
    p.add_argument("--render-every", type=int, default=25, metavar="N",
                   help="render every N-th case if it loads (default 25; 0: none)")
    p.add_argument("--trace-every", type=int, default=10, metavar="N",
                   help="trace allocations in every N-th case (default 10; 0: renders only)")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = p.parse_args(argv)
    result = run(args.cases, args.seed, args.render_every, args.trace_every)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
