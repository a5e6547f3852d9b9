"""The long ``sonarsim dataset`` fuzzing run (issue 37): N seeded cases, a JSON summary.

Every case is a command line over a scenario file and an output folder (see
``tests/fuzz/dataset_options.py``), run in this process and checked as the test suite checks
its few dozen: exit 0 with a complete, consistent dataset folder (every manifest line sealed,
every file's size and SHA-256 its line's, the NPZs finite, coco.json, the PNGs and the bag as
asked), or exit 2/3 with one error line naming an option, key or file, nothing half-written;
never a traceback, a case past its time limit or a traced allocation beyond the budget.
Resumed and interrupted folders, the cases that started worker processes and (``--repeat``)
every accepted case are run again in a fresh folder in one process and must give the same
bytes.

Usage::

    python benchmarks/fuzz_dataset.py                       # 1000 cases, seed 0
    python benchmarks/fuzz_dataset.py --cases 300 --seed 3 --out benchmarks/fuzz_dataset.json

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

from tests.fuzz.dataset_options import FUZZ_BUDGET_BYTES, Summary, check_case, generate_cases  # noqa: E402


def run(cases: int, seed: int, processes: bool = True, trace_every: int = 3, repeat: bool = False,
        progress: bool = True) -> dict:
    """Run ``cases`` cases from ``seed``; returns the summary as a JSON-ready dict.

    Parameters
    ----------
    cases, seed : int
    processes : bool
        Let cases start worker processes (``--workers 2`` under a budget that holds them).
    trace_every : int
        Every that many cases (0: none) traces allocations against the budget.
    repeat : bool
        Compare every accepted case with a fresh run of the same command in one process.
    """
    summary = Summary()
    messages: dict[str, str] = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonarsim-dfuzz-") as tmp:
        for case in generate_cases(cases, seed, processes=processes):
            trace = trace_every > 0 and case.index % trace_every == 0
            out = check_case(case, Path(tmp), trace_memory=trace, repeat=repeat, processes=processes)
            summary.add(out)
            if out.error_key and out.message and out.error_key not in messages:
                messages[out.error_key] = out.message.replace(tmp, "TMP")[:300]
            if progress and (case.index + 1) % 50 == 0:
                print(f"{case.index + 1} cases, {len(summary.failures)} failures, {time.perf_counter() - t0:.0f} s",
                      file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    refused = dict(sorted(summary.refused.items(), key=lambda kv: (-kv[1], kv[0])))
    return {
        "cases": summary.cases,
        "seed": seed,
        "processes": processes,
        "by_scenario": summary.by_base,
        "by_out_state": dict(sorted(summary.by_out_state.items(), key=lambda kv: -kv[1])),
        "by_status": {str(k): v for k, v in sorted(summary.by_status.items())},
        "no_status": summary.cases - sum(summary.by_status.values()),
        "datasets_written": summary.written,
        "frames_written": summary.frames,
        "compared_with_a_fresh_run": summary.compared,
        "written_by_worker_processes": summary.processes,
        "refused": sum(v for k, v in summary.refused.items()),
        "distinct_error_keys": len(refused),
        "outcomes_by_error_key": refused,
        "a_message_per_key": messages,
        "failures": len(summary.failures),
        "failure_cases": [f.replace(str(Path(tempfile.gettempdir())), "TMP") for f in summary.failures[:50]],
        "slowest_case_s": round(summary.slowest_s, 2),
        "slowest_case": summary.slowest_case[:500],
        "peak_traced_mib": round(summary.peak_bytes / 2**20, 2),
        "budget_mib": FUZZ_BUDGET_BYTES // 2**20,
        "wall_s": round(wall, 1),
        "cases_per_s": round(summary.cases / wall, 2),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=1000, help="number of cases (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the cases (default 0)")
    p.add_argument("--no-processes", action="store_true", help="never start worker processes (faster)")
    p.add_argument("--trace-every", type=int, default=3, metavar="N",
                   help="trace allocations in every N-th case (default 3; 0: none)")
    p.add_argument("--repeat", action="store_true", help="compare every accepted case with a fresh run")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = p.parse_args(argv)
    result = run(args.cases, args.seed, not args.no_processes, args.trace_every, args.repeat)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
