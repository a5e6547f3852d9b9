"""Seeded fuzzing of mirror scenes (issue 37): mesh mirrors, planes, orders and specular returns.

A case is a random scene that the scene format accepts: a small sonar, up to a few planes, up
to a few dozen objects (boxes, spheres, cylinders), each a mirror or not (``specular``, flat or
smooth normals), ``max_order`` 1 to 6, the specular returns on or off, each ``double_beam``
and line-of-sight setting; one case in :data:`HOSTILE_EVERY` is a crowd of hundreds of small
mirror boxes at a high order (the issue's 900 boxes at ``max_order: 5`` passed 6 GB). Each is
loaded, rendered and its components listed (every path signature's image) under a small
memory budget and a time limit. It must end in:

* a refusal: a :class:`~sonarsim.errors.ConfigError` whose one-line message names a key (a
  size beyond the budget: ``render.max_order``, ``objects``, ...); or
* a frame whose images are finite, non-negative and of the configured shape, whose signature
  images add up to its order images (every path in exactly one signature), within the budget
  (traced allocations) and the time limit.

Anything else is a failure. Used by ``tests/fuzz/test_mirrors_fuzz.py`` (a seeded subset) and
``benchmarks/fuzz_mirrors.py`` (the long run).
"""

from __future__ import annotations

import time
import tracemalloc
import warnings
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np

from tests.fuzz.scenes import FUZZ_BUDGET_BYTES, PEAK_BUDGETS, CaseTimeout, check_error, time_limit

#: Every that many cases is a crowd of small mirror boxes at a high order.
HOSTILE_EVERY = 20
#: A case that runs longer than this (seconds) counts as a hang (a small frame renders in well
#: under a second; a crowd of 900 mirror boxes at order 6 in a few).
CASE_TIME_LIMIT_S = 60.0


@dataclass
class MirrorCase:
    """One mirror scene and how it was drawn."""

    index: int
    doc: dict
    notes: list[str]

    def describe(self) -> str:
        return f"mirror case {self.index} ({'; '.join(self.notes)})"


def _pose(rng: np.random.Generator, centre: tuple, spread: float) -> dict:
    return {"position_m": [float(c + spread * (rng.random() - 0.5)) for c in centre],
            "rpy_deg": [float(v) for v in rng.uniform(-180, 180, 3)]}


def _object(rng: np.random.Generator, k: int, small: bool = False) -> dict:
    kind = "box" if small else str(rng.choice(["box", "box", "sphere", "cylinder"]))
    size = 0.05 if small else float(rng.uniform(0.05, 0.6))
    obj: dict[str, Any] = {"name": f"m{k}", "primitive": kind, "albedo": float(rng.uniform(0, 1))}
    if kind == "box":
        obj["size_m"] = [float(size * rng.uniform(0.2, 1.5)) for _ in range(3)]
    elif kind == "sphere":
        obj["radius_m"] = size / 2
    else:
        obj.update(radius_m=size / 2, height_m=float(rng.uniform(0.05, 1.0)))
    obj["pose"] = _pose(rng, (2.5, 0.0, 0.6), 2.0 if small else 3.0)
    if small or rng.random() < 0.7:
        obj["specular"] = float(rng.choice([1.0, rng.uniform(0, 1)]))
        if rng.random() < 0.4:
            obj["normals"] = "smooth"
    return obj


def _planes(rng: np.random.Generator) -> list[dict]:
    out = []
    choices = [("surface", [0, 0, 2.0], [0, 0, -1]), ("far_wall", [5.0, 0, 0], [-1, 0, 0]),
               ("left_wall", [0, 1.6, 0], [0, -1, 0]), ("right_wall", [0, -1.6, 0], [0, 1, 0]),
               ("slope", [4.0, 0, 0], [-0.6, 0.2, 0.77])]
    for name, point, normal in choices:
        if rng.random() < 0.35:
            out.append({"name": name, "point_m": point, "normal": normal, "albedo": float(rng.uniform(0, 0.8)),
                        "specular": float(rng.uniform(0, 1))})
    return out


def mirror_case(index: int, rng: np.random.Generator) -> MirrorCase:
    """Case ``index`` drawn from ``rng`` (a crowd of small mirror boxes every :data:`HOSTILE_EVERY`)."""
    crowd = index % HOSTILE_EVERY == HOSTILE_EVERY - 1
    n_objects = int(rng.integers(200, 901)) if crowd else int(rng.integers(0, 25))
    sonar = {"n_beams": int(rng.integers(4, 49)), "azimuth_fov_deg": float(rng.uniform(10, 90)),
             "elevation_fov_deg": float(rng.uniform(4, 40)), "range_min_m": float(rng.uniform(0.1, 1.0)),
             "range_max_m": float(rng.uniform(3.0, 9.0)), "n_range_bins": int(rng.integers(32, 400)),
             "pose": {"position_m": [0.0, float(rng.uniform(-0.5, 0.5)), float(rng.uniform(0.3, 1.8))],
                      "rpy_deg": [float(rng.uniform(-10, 10)), float(rng.uniform(-5, 30)), float(rng.uniform(-20, 20))]}}
    max_order = int(rng.integers(4, 7)) if crowd else int(rng.integers(1, 7))
    render: dict[str, Any] = {"max_order": max_order, "elevation_samples": int(rng.integers(8, 97)),
                              "glints": bool(crowd or rng.random() < 0.4),
                              "double_beam": str(rng.choice(["paper", "separate", "split"])),
                              "double_line_of_sight": bool(rng.random() < 0.2)}
    if render["glints"]:
        render["glint_radius_m"] = float(rng.uniform(0.02, 0.5))
    if render["double_beam"] == "split" and render["double_line_of_sight"]:
        render["double_line_of_sight"] = False  # (the scene format refuses the two together)
    doc: dict[str, Any] = {"sonar": sonar, "render": render,
                           "objects": [_object(rng, k, small=crowd) for k in range(n_objects)]}
    if rng.random() < 0.8:
        doc["ground"] = {"height_m": 0.0, "albedo": float(rng.uniform(0, 1)), "specular": float(rng.uniform(0, 1))}
    planes = _planes(rng)
    if planes:
        doc["planes"] = planes
    mirrors = sum(1 for o in doc["objects"] if o.get("specular", 0) > 0)
    notes = [("crowd of " if crowd else "") + f"{n_objects} objects ({mirrors} mirrors)", f"{len(planes)} planes",
             f"max_order {max_order}", f"glints {render['glints']}", f"double_beam {render['double_beam']}"]
    return MirrorCase(index, doc, notes)


def generate_mirror_cases(n: int, seed: int) -> Iterator[MirrorCase]:
    """``n`` cases from one seed (the same cases for the same seed)."""
    rng = np.random.default_rng([37, seed])
    for index in range(n):
        yield mirror_case(index, rng)


@dataclass
class MirrorOutcome:
    """What a case came to: rendered, refused (``error_key``) or ``failure``."""

    case: MirrorCase
    rendered: bool = False
    signatures: int = 0
    error_key: str | None = None
    failure: str | None = None
    seconds: float = 0.0
    peak_bytes: int = 0


def _check_frame(image, scene) -> str | None:
    """Why a rendered frame is wrong (None: it is right)."""
    shape = (scene.sonar.n_range_bins, scene.sonar.n_beams)
    comps = image.components
    for name in (*comps.table, *comps.signatures):
        a = np.asarray(comps[name], dtype=np.float64)
        if a.shape != shape:
            return f"component {name} has shape {a.shape}, configured {shape}"
        if not np.all(np.isfinite(a)):
            return f"component {name} has {int(np.sum(~np.isfinite(a)))} non-finite pixels"
        if np.any(a < 0):
            return f"component {name} has negative intensities (min {a.min()})"
    if not np.all(np.isfinite(image.polar)) or np.any(image.polar < 0):
        return "the image is not finite and non-negative"
    orders = ["object", "ground"] + [n for n in comps.table if n not in ("object", "ground", "single", "total")]
    rows = sum(np.asarray(comps[n], np.float64).sum() for n in orders)
    signed = sum(np.asarray(comps[n], np.float64).sum() for n in comps.signatures)
    if abs(rows - signed) > 1e-4 * max(rows, signed) + 1e-9:
        return f"the signature images add up to {signed:.6g}, the order images to {rows:.6g}"
    return None


def check_mirror_case(case: MirrorCase, budget: int = FUZZ_BUDGET_BYTES, trace_memory: bool = True) -> MirrorOutcome:
    """Load, render and list the components of one case under ``budget`` and the time limit."""
    from sonarsim import Simulator
    from sonarsim.config.loader import scene_from_dict
    from sonarsim.core.memory import set_memory_budget
    from sonarsim.errors import ConfigError

    out = MirrorOutcome(case)
    set_memory_budget(budget)
    if trace_memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as seen, time_limit(CASE_TIME_LIMIT_S):
            warnings.simplefilter("always")
            try:
                scene = scene_from_dict(case.doc)
                with Simulator(scene) as sim:
                    image = sim.render(speckle=False, keep_rays=False)
                    out.signatures = len(image.components.signatures)
                out.rendered = True
                out.failure = _check_frame(image, scene)
            except ConfigError as exc:
                out.error_key = exc.key
                out.failure = check_error(exc, case, None)  # type: ignore[arg-type]
            except CaseTimeout as exc:
                out.failure = f"{exc}"
            except Exception as exc:  # noqa: BLE001 - classifying every exception is the point
                out.failure = f"{type(exc).__name__}: {str(exc)[:300]}"
        numeric = [w for w in seen if issubclass(w.category, RuntimeWarning)]
        if out.failure is None and numeric:
            out.failure = f"{numeric[0].category.__name__}: {numeric[0].message}"
    finally:
        out.seconds = time.perf_counter() - t0
        if trace_memory:
            out.peak_bytes = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        set_memory_budget(None)
    if out.failure is None and out.peak_bytes > PEAK_BUDGETS * budget:
        out.failure = (f"traced allocations peaked at {out.peak_bytes / 2**20:.1f} MiB, beyond {PEAK_BUDGETS} x the "
                       f"{budget / 2**20:.0f} MiB budget")
    return out


@dataclass
class MirrorSummary:
    """Counts over many outcomes."""

    cases: int = 0
    rendered: int = 0
    crowds: int = 0
    signatures: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    slowest_s: float = 0.0

    def add(self, out: MirrorOutcome) -> None:
        self.cases += 1
        self.rendered += out.rendered and out.failure is None
        self.crowds += out.case.notes[0].startswith("crowd")
        self.signatures += out.signatures
        self.slowest_s = max(self.slowest_s, out.seconds)
        if out.error_key is not None:
            self.refused[out.error_key] = self.refused.get(out.error_key, 0) + 1
        if out.failure is not None:
            self.failures.append(f"{out.case.describe()}: {out.failure}")
