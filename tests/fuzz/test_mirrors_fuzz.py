"""Fuzzing mirror scenes (issue 37): seeded random scenes of mesh mirrors, planes, orders up to 6
and specular returns, and crowds of hundreds of small mirror boxes, end in a refusal naming a
key or in a right frame within the budget and the time limit. The cases and the check are in
:mod:`tests.fuzz.mirrors`; the long run is ``benchmarks/fuzz_mirrors.py``."""

from __future__ import annotations

import numpy as np
import pytest

from tests.fuzz.mirrors import HOSTILE_EVERY, MirrorCase, MirrorSummary, check_mirror_case, generate_mirror_cases

# One crowd of mirror boxes among 20 cases: about 20 s here (2 shared cores).
SEED, CASES, TRACE_EVERY = 1, 20, 4


def test_mirror_scenes_end_in_a_refusal_or_a_right_frame():
    summary = MirrorSummary()
    for case in generate_mirror_cases(CASES, SEED):
        summary.add(check_mirror_case(case, trace_memory=case.index % TRACE_EVERY == 0))
    assert not summary.failures, "\n".join(summary.failures[:10])
    assert summary.cases == CASES and summary.crowds == CASES // HOSTILE_EVERY
    assert summary.rendered > CASES // 2 and summary.signatures > 100


def test_mirror_cases_are_reproducible_from_the_seed():
    a = [c.doc for c in generate_mirror_cases(30, 5)]
    assert a == [c.doc for c in generate_mirror_cases(30, 5)] and a != [c.doc for c in generate_mirror_cases(30, 6)]
    assert {o.get("normals") for d in a for o in d["objects"]} == {None, "smooth"}
    assert {d["render"]["glints"] for d in a} == {True, False}


def _small_case():
    """A mirror plate and a ball over a mirroring floor, order 3, the specular returns on."""
    doc = {"sonar": {"n_beams": 16, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 20.0, "range_min_m": 0.5,
                     "range_max_m": 5.0, "n_range_bins": 100, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 10, 0]}},
           "render": {"max_order": 3, "glints": True, "elevation_samples": 32},
           "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
           "objects": [{"name": "plate", "primitive": "box", "size_m": [0.05, 1.0, 0.8],
                        "pose": {"position_m": [3.0, 0.3, 0.5], "rpy_deg": [0, 0, -20]}, "specular": 0.9},
                       {"name": "ball", "primitive": "sphere", "radius_m": 0.15, "pose": {"position_m": [2.0, -0.3, 0.5]}}]}
    return MirrorCase(0, doc, ["plate and ball"])


def test_the_check_fails_a_nan_frame(monkeypatch):
    from sonarsim import Simulator

    render = Simulator.render

    def nan_render(self, *args, **kwargs):
        image = render(self, *args, **kwargs)
        image.polar[0, 0] = np.nan
        return image

    assert check_mirror_case(_small_case(), trace_memory=False).failure is None  # (without the NaN)
    monkeypatch.setattr(Simulator, "render", nan_render)
    out = check_mirror_case(_small_case(), trace_memory=False)
    assert out.failure == "component total has 1 non-finite pixels"


def test_the_check_fails_signatures_that_lose_paths(monkeypatch):
    from sonarsim.renderer import simulator

    form = simulator.Simulator._signature_images

    def lossy(self, *args, **kwargs):
        images = form(self, *args, **kwargs)
        return dict(list(images.items())[1:])  # one signature dropped

    monkeypatch.setattr(simulator.Simulator, "_signature_images", lossy)
    out = check_mirror_case(_small_case(), trace_memory=False)
    assert out.failure is not None and "signature images add up to" in out.failure


def test_the_check_fails_a_traceback(monkeypatch):
    monkeypatch.setattr("sonarsim.renderer.simulator.Simulator.render", lambda *a, **k: 1 / 0)
    out = check_mirror_case(_small_case(), trace_memory=False)
    assert out.failure.startswith("ZeroDivisionError")
