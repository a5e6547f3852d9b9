"""Fuzzing the differentiable engine's parameters (issue 37): seeded values (not finite,
beyond the scene format's bounds, at them, degenerate geometry, ordinary) given directly,
through ``jax.grad`` and ``jax.vmap``, after ``refresh`` and inside ``jit`` end in a one-line
refusal naming the parameter and its range, or in a finite image and gradient. The mutators
and the check are in :mod:`tests.fuzz.diff_params`; the long run is ``benchmarks/fuzz_diff.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jax")

from tests.fuzz.diff_params import Case, Harness, Summary, check_case, generate_cases  # noqa: E402

SEED = 37
# 80 cases after the scene's compilations (the image, its gradient, a batch of two).
CASES = 80


@pytest.fixture(scope="module")
def harness():
    return Harness()


def test_mutated_parameters_end_in_a_refusal_or_a_finite_image(harness):
    summary = Summary()
    for case in generate_cases(harness.renderer, CASES, SEED):
        summary.add(check_case(harness, case))
    assert not summary.failures, f"{len(summary.failures)} of {summary.cases} cases failed:\n" + "\n".join(
        summary.failures[:10])
    # Both sides are reached, in every mode, from many parameters.
    assert set(summary.by_mode) == {"direct", "grad", "vmap", "refresh", "jit"}
    assert summary.rendered > 0.25 * CASES and sum(summary.refused.values()) > 0.2 * CASES
    assert len(summary.refused) >= 6, summary.refused
    assert {"nan", "beyond", "collapsed", "zero"} <= set(summary.by_kind)


def test_cases_are_reproducible_from_the_seed(harness):
    def cases(seed):  # (bytes: NaN values compare equal)
        return [(c.mode, {k: v.tobytes() for k, v in c.values.items()}) for c in generate_cases(harness.renderer, 30, seed)]

    assert cases(1) == cases(1) and cases(1) != cases(2)


def test_the_check_catches_what_it_is_there_to_catch(harness, monkeypatch):
    """A NaN image from finite values, values rendered that the scene format refuses, and a
    refusal of valid values are failures."""
    p = harness.base
    ok = Case(0, "direct", {"objects.box.albedo": np.asarray(0.5)}, ("ordinary",))
    assert check_case(harness, ok).rendered
    bad_albedo = Case(1, "direct", {"objects.box.albedo": np.asarray(-0.5)}, ("negative",))
    assert check_case(harness, bad_albedo).refused_key == "objects.box.albedo"
    r = harness.renderer
    monkeypatch.setattr(type(r), "_checked", lambda self, q: self._complete(q, bounds=False))
    assert "scene format refuses" in check_case(harness, bad_albedo).failure
    monkeypatch.setattr(harness, "jit_image", lambda q, d: harness.jnp.full(harness.shape, np.nan))
    jit = Case(2, "jit", {"objects.box.scale": np.zeros(3)}, ("zero",))
    assert "NaN" in check_case(harness, jit).failure
    from sonarsim.errors import ConfigError

    def refuse(self, q):
        raise ConfigError("objects.box.albedo", "must be something else")

    monkeypatch.setattr(type(r), "_checked", refuse)
    assert "refused values the scene format takes" in check_case(harness, ok).failure
    assert p is harness.base
