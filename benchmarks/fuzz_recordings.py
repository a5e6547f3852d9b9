"""Fuzz the recording readers for many cases: the CI fuzz test's generator and check, at length.

Each case is a seeded mutation of a real recording in ``../shared/data/real`` (see
``tests/fuzz/recordings.py``), read every way (``read(path, k)`` for every frame and
``read_frames``) and checked: a RecordingError or images of plausible geometry, every reader
agreeing on the good frames (``read``, ``read_frames``, ``open_recording(path).n_frames`` and
``damage``, ``n_frames``; and ``sonarsim show --frame 0`` on every ``--show-every``-th case),
nothing slower than the per-case limit, nothing allocated beyond the memory budget
(``tracemalloc`` peaks of every ``--trace-every``-th case).

Usage (from the repository root)::

    python benchmarks/fuzz_recordings.py                    # 100,000 cases, seed 0
    python benchmarks/fuzz_recordings.py --cases 20000 --seed 3 --json /tmp/x/fuzz.json

Prints a summary and writes it as JSON (cases by outcome, refusals by field, failures - 0
expected - with the case numbers that regenerate them, the slowest case, the largest memory
peak, wall time). Exits 1 if any case failed.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # for tests.fuzz.recordings

from sonarsim.core.memory import set_memory_budget  # noqa: E402
from tests.fuzz import recordings as fuzz  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    """Run the fuzzing; returns the exit status (0: no failures)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=100_000, help="number of cases (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the case generator (default 0)")
    p.add_argument("--budget-mib", type=float, default=64.0,
                   help="memory budget set for the readers, MiB (default 64)")
    p.add_argument("--time-limit", type=float, default=5.0,
                   help="seconds a case may take before it counts as a hang (default 5)")
    p.add_argument("--trace-every", type=int, default=10,
                   help="measure the allocation peak of every N-th case (default 10)")
    p.add_argument("--show-every", type=int, default=100,
                   help="run `sonarsim show --frame 0` on every N-th case, 0: never (default 100)")
    p.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "fuzz_recordings.json",
                   help="where to write the summary (default benchmarks/fuzz_recordings.json)")
    args = p.parse_args(argv)

    budget = int(args.budget_mib * 2**20)
    set_memory_budget(budget)
    by_outcome: collections.Counter = collections.Counter()
    refused_by_field: collections.Counter = collections.Counter()
    by_source: collections.Counter = collections.Counter()
    failures = []
    slowest = {"seconds": 0.0}
    peak = {"bytes": 0}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonarsim-fuzz-") as tmp:
        path = Path(tmp) / "case.bin"
        for case in fuzz.cases(args.seed, args.cases):
            path.unlink(missing_ok=True)  # a new file: truncating in place is much slower
            path.write_bytes(case.data)
            kind = "aris" if case.source == "aris" else "oculus"
            traced = args.trace_every > 0 and case.index % args.trace_every == 0
            shown = args.show_every > 0 and case.index % args.show_every == 0
            o = fuzz.check_file(path, kind, budget, args.time_limit, trace_memory=traced,
                                show_dir=Path(tmp) / "show" if shown else None)
            by_outcome[o.kind] += 1
            by_source[f"{case.source} {o.kind}"] += 1
            if o.kind in ("refused", "partial"):
                refused_by_field[o.field] += 1
            if o.seconds > slowest["seconds"]:
                slowest = {"seconds": round(o.seconds, 4), "case": case.index, "source": case.source,
                           "mutations": list(case.mutations), "outcome": o.kind}
            if o.peak_bytes > peak["bytes"]:
                peak = {"bytes": o.peak_bytes, "case": case.index, "source": case.source}
            if o.failure:
                failures.append({"case": case.index, "source": case.source,
                                 "mutations": list(case.mutations), "failure": o.failure})
            if (case.index + 1) % 10_000 == 0:
                print(f"{case.index + 1} cases, {len(failures)} failures, "
                      f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0

    summary = {
        "cases": args.cases,
        "seed": args.seed,
        "budget_bytes": budget,
        "time_limit_s": args.time_limit,
        "outcomes": dict(by_outcome.most_common()),
        "refused_by_field": dict(refused_by_field.most_common()),
        "by_source": dict(sorted(by_source.items())),
        "shown_cases": sum(1 for i in range(args.cases) if args.show_every > 0 and i % args.show_every == 0),
        "failures": len(failures),
        "failed_cases": failures[:100],
        "slowest_case": slowest,
        "peak_memory": {**peak, "traced_cases": sum(1 for i in range(args.cases)
                                                   if args.trace_every > 0 and i % args.trace_every == 0)},
        "wall_s": round(wall, 1),
        "ms_per_case": round(1e3 * wall / max(args.cases, 1), 2),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "failed_cases"}, indent=2))
    for f in failures[:20]:
        print(f"FAILED case {f['case']} ({f['source']}; {', '.join(f['mutations'])}): {f['failure']}")
    print(f"wrote {args.json}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
