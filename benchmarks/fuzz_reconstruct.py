"""The long run of ``sonarsim reconstruct``'s option fuzzing (issue 37): N seeded command
lines, a JSON summary.

Every case is a valid command line with up to three of its parts made hostile (images, scene,
extent, resolution, smoothness, poses, truth, budgets, a required option left out, an unknown
one; see ``tests/fuzz/reconstruct_options.py``), run in this process as the test suite runs
its few hundred: it must end in a written height field, or in one line naming the option or
file with exit status 2 (bad input) or 3 (an outcome that means nothing), nothing written. The
reconstruction itself is a stand-in that checks what it is handed, except in every
``--real-every``-th case, which runs it. A traceback, another status, files left by a refusal,
a case past its time limit or a traced allocation beyond the memory budget is a failure.

Usage::

    python benchmarks/fuzz_reconstruct.py                    # 20,000 cases, seed 0, 1 in 2000 real
    python benchmarks/fuzz_reconstruct.py --cases 2000 --seed 3 --real-every 0 --out fuzz.json

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

from tests.fuzz.reconstruct_options import (FUZZ_BUDGET_BYTES, Summary, check_case, generate_cases,  # noqa: E402
                                            make_files)


def run(cases: int, seed: int, real_every: int, progress: bool = True) -> dict:
    """Run ``cases`` cases from ``seed``; returns the summary as a JSON-ready dict."""
    summary = Summary()
    by_aspect: dict[str, int] = {}
    real_written = 0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonarsim-fuzz-reconstruct-") as tmp:
        folder = make_files(Path(tmp) / "files")
        work = Path(tmp) / "work"
        work.mkdir()
        for case in generate_cases(cases, seed, real_every=real_every):
            out = check_case(case, folder, work)
            summary.add(out)
            real_written += out.real and out.status == 0 and out.failure is None
            for aspect in case.notes or ["valid"]:
                by_aspect[aspect] = by_aspect.get(aspect, 0) + 1
            if progress and (case.index + 1) % 1000 == 0:
                print(f"{case.index + 1} cases, {len(summary.failures)} failures, "
                      f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    return {
        "cases": summary.cases,
        "seed": seed,
        "real_every": real_every,
        "by_hostile_aspect": dict(sorted(by_aspect.items())),
        "by_exit_status": {str(k): v for k, v in sorted(summary.by_status.items())},
        "written": summary.written,
        "real_reconstructions": summary.real,
        "real_written": real_written,
        "distinct_refusals": len(summary.refused),
        "refusals": dict(sorted(summary.refused.items(), key=lambda kv: -kv[1])),
        "failures": len(summary.failures),
        "failure_cases": summary.failures[:50],
        "slowest_stand_in_case_s": round(summary.slowest_s, 3),
        "slowest_case": summary.slowest_case[:500],
        "peak_traced_mib": round(summary.peak_bytes / 2**20, 2),
        "budget_mib": FUZZ_BUDGET_BYTES // 2**20,
        "wall_s": round(wall, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=20_000, help="number of cases (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the command lines (default 0)")
    p.add_argument("--real-every", type=int, default=2000, metavar="N",
                   help="run the real reconstruction in every N-th case (default 2000; 0: none)")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON summary here")
    args = p.parse_args(argv)
    result = run(args.cases, args.seed, args.real_every)
    text = json.dumps(result, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
