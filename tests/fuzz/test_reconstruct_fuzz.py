"""Fuzzing ``sonarsim reconstruct``'s options (issue 37): seeded command lines end in a written
height field or in one line naming the option or file (exit 2, or 3 for an outcome that
means nothing), never a traceback, files left by a refusal, or an allocation beyond the
budget. The generators and the check are in :mod:`tests.fuzz.reconstruct_options`; the long
run is ``benchmarks/fuzz_reconstruct.py``.
"""

from __future__ import annotations

import pytest

pytest.importorskip("jax")

from tests.fuzz import reconstruct_options as fuzz  # noqa: E402
from tests.fuzz.reconstruct_options import Case, Summary, check_case, generate_cases, make_files  # noqa: E402

# 2 x 100 cases with the reconstruction's stand-in: about 20 s here (2 shared cores, loaded).
SEEDS = (1, 2)
CASES_PER_SEED = 100


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return make_files(tmp_path_factory.mktemp("files"))


@pytest.mark.parametrize("seed", SEEDS)
def test_reconstruct_options_end_in_a_result_or_one_line(folder, tmp_path, seed):
    summary = Summary()
    for case in generate_cases(CASES_PER_SEED, seed):
        summary.add(check_case(case, folder, tmp_path))
    assert not summary.failures, f"{len(summary.failures)} of {summary.cases} failed:\n" + "\n".join(
        summary.failures[:10])
    # Both sides are reached: results written, refusals of many options and files, and
    # outcomes that mean nothing (exit 3).
    assert summary.written > 0.1 * CASES_PER_SEED, summary.by_status
    assert summary.by_status.get(2, 0) > 0.3 * CASES_PER_SEED, summary.by_status
    assert len(summary.refused) >= 10, sorted(summary.refused)
    assert summary.peak_bytes <= fuzz.FUZZ_BUDGET_BYTES
    assert list(tmp_path.iterdir()) == []  # every case's output removed


def test_cases_are_reproducible_from_the_seed():
    a = [c.argv for c in generate_cases(100, 5)]
    assert a == [c.argv for c in generate_cases(100, 5)] and a != [c.argv for c in generate_cases(100, 6)]
    # Values with a leading minus in the separate-token form are among them.
    assert any(v.startswith("-") and v[1:2].isdigit() for argv in a for v in argv)


# The check itself must catch what it is there to catch -------------------------------------

VALID = ["--max-memory", "256M", "reconstruct", "view0.npz", "--scene", "start.yaml", "--extent", "1,3,-0.8,0.8",
         "--resolution", "0.2", "--out", "OUT"]


def test_the_check_accepts_a_valid_command(folder, tmp_path):
    out = check_case(Case(0, VALID, []), folder, tmp_path)
    assert out.failure is None and out.status == 0


def test_the_check_fails_a_traceback(folder, tmp_path, monkeypatch):
    from sonarsim.diff import reconstruct as rec

    def broken(*args, **kwargs):
        raise KeyError("extent")

    monkeypatch.setattr(rec, "plan_grid", broken)
    out = check_case(Case(0, VALID, []), folder, tmp_path)
    assert out.failure.startswith("KeyError escaped")


def test_the_check_fails_a_plan_refused_only_by_the_reconstruction(folder, tmp_path, monkeypatch):
    from sonarsim.diff import reconstruct as rec

    # A CLI that skipped its size check: the stand-in is handed a grid beyond the budget.

    real_plan = rec.plan_grid
    calls = []

    def lenient(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:  # the CLI's check lets it through
            return None
        return real_plan(*args, **kwargs)

    monkeypatch.setattr(rec, "plan_grid", lenient)
    argv = [a if a != "0.2" else "1e-4" for a in VALID]
    out = check_case(Case(0, argv, []), folder, tmp_path)
    assert out.failure and "refused only at the reconstruction" in out.failure


def test_the_check_fails_a_refusal_that_wrote_files_or_names_nothing(folder, tmp_path, monkeypatch):
    from sonarsim.errors import SonarsimError

    def writes_then_refuses(args):
        open(args.out, "wb").close()
        raise SonarsimError("--extent: no")

    from sonarsim.cli import main as cli_main

    parser = cli_main.build_parser
    monkeypatch.setattr(cli_main, "build_parser", lambda: _with_func(parser(), writes_then_refuses))
    assert "wrote h0.npz" in check_case(Case(0, VALID, []), folder, tmp_path).failure

    def names_nothing(args):
        raise SonarsimError("something is wrong")

    monkeypatch.setattr(cli_main, "build_parser", lambda: _with_func(parser(), names_nothing))
    assert "naming no option and no file" in check_case(Case(0, VALID, []), folder, tmp_path).failure


def _with_func(parser, func):
    import argparse

    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub.choices["reconstruct"].set_defaults(func=func)
    return parser
