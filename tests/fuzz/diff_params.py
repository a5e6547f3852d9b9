"""Seeded fuzzing of the differentiable engine's parameters (issue 37): mutators and the check.

A case changes one to three parameters of a small scene with a sensor
(:mod:`tests.diff.small_scenes`) and renders it one of five ways:

* ``direct``: :meth:`~sonarsim.diff.Renderer.render` with the values;
* ``grad``: ``jax.grad`` of a functional of ``render``, called outside ``jit``;
* ``vmap``: ``jax.vmap`` of ``render`` over a batch of two (the case's values and the scene's);
* ``refresh``: :meth:`~sonarsim.diff.Renderer.refresh` at the values, then ``render`` (and
  back to the scene's search);
* ``jit``: the pure image function and its gradient inside ``jit``, where nothing can be
  checked: the values are degenerate (zeros, negatives, collapsed triangles, a zero normal,
  a width of 0) but finite and within the scene's extent.

The values (:func:`mutate`) are non-finite numbers, values beyond the scene format's bounds
(just beyond and far beyond), values at the bounds, degenerate geometry, and ordinary values.

:func:`check_case` says what happened. A case passes when:

* the values are refused with a :class:`~sonarsim.errors.ConfigError` whose one-line message
  names one of the changed keys (and, for a value beyond a bound, the range), and they were
  indeed not finite or out of bounds; or
* the image (and the gradient, for ``grad`` and ``jit``) is finite everywhere and of the
  image's shape, and the values were finite and (except inside ``jit``) within the bounds.

Anything else is a failure: another exception, a refusal of valid values or of a key not
changed, an image or gradient with NaN or inf from finite values, values accepted that the
scene format refuses. Used by ``tests/fuzz/test_diff_fuzz.py`` (a few hundred cases) and
``benchmarks/fuzz_diff.py`` (the long run).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MODES = ("direct", "grad", "vmap", "refresh", "jit")
#: Mode weights: the checks outside jit are cheap; jit cases form a gradient each.
MODE_WEIGHTS = (0.3, 0.15, 0.15, 0.1, 0.3)
#: A case slower than this (seconds, after the harness's compilations; a refreshed search of
#: more paths compiles the image again) counts as a hang.
CASE_TIME_LIMIT_S = 300.0


@dataclass(frozen=True)
class Case:
    """One case: its index, mode and the values it gives (key -> array)."""

    index: int
    mode: str
    values: dict
    kinds: tuple[str, ...]

    def describe(self) -> str:
        shown = ", ".join(f"{k}={_short(v)} ({kind})" for (k, v), kind in zip(self.values.items(), self.kinds))
        return f"case {self.index} [{self.mode}] {shown}"


def _short(v: np.ndarray) -> str:
    a = np.asarray(v)
    if a.size <= 3:
        return np.array2string(a, precision=3)
    return f"array{a.shape}"


@dataclass
class Outcome:
    case: Case
    refused_key: str = ""
    rendered: bool = False
    failure: str | None = None
    seconds: float = 0.0


@dataclass
class Summary:
    """Counts over many outcomes."""

    cases: int = 0
    rendered: int = 0
    by_mode: dict[str, int] = field(default_factory=dict)
    by_kind: dict[str, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    slowest_s: float = 0.0
    slowest_case: str = ""

    def add(self, out: Outcome) -> None:
        self.cases += 1
        self.rendered += out.rendered
        self.by_mode[out.case.mode] = self.by_mode.get(out.case.mode, 0) + 1
        for kind in out.case.kinds:
            self.by_kind[kind] = self.by_kind.get(kind, 0) + 1
        if out.refused_key:
            self.refused[out.refused_key] = self.refused.get(out.refused_key, 0) + 1
        if out.failure:
            self.failures.append(f"{out.case.describe()}: {out.failure}")
        if out.seconds > self.slowest_s:
            self.slowest_s, self.slowest_case = out.seconds, out.case.describe()


# Values ------------------------------------------------------------------------------------

def mutate(rng: np.random.Generator, key: str, default: np.ndarray, bound, jit: bool,
           faces: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """A new value for ``key`` and its kind.

    Outside ``jit``: any of ``nan``, ``inf``, ``beyond`` (just past a bound), ``far`` (1e3 to
    1e300 past it), ``at-bound``, ``zero``, ``negative``, ``ordinary`` (near the scene's value).
    Inside: only finite values within the scene's extent: ``zero``, ``negative``, ``ordinary``,
    ``scaled`` (0 to 10 times the scene's), ``collapsed`` (a mesh's triangles collapsed, all or
    one) or ``at-bound``.
    """
    d = np.asarray(default, float)
    kinds = ["zero", "negative", "ordinary", "scaled", "at-bound"] if jit else \
        ["nan", "inf", "beyond", "far", "at-bound", "zero", "negative", "ordinary"]
    if key.endswith("vertices_m") and faces is not None and len(faces):
        kinds.append("collapsed")
    kind = str(rng.choice(kinds))
    lo, hi = (-np.inf, np.inf) if bound is None else (bound.lo, bound.hi)
    v = d.copy()
    pick = (rng.random(d.shape) < 0.5) | (d.size == 1) if d.ndim else True
    if kind == "nan":
        v = np.where(pick, np.nan, d)
    elif kind == "inf":
        v = np.where(pick, rng.choice([-np.inf, np.inf]), d)
    elif kind in ("beyond", "far"):
        past = 10.0 ** rng.uniform(-6, -1) if kind == "beyond" else 10.0 ** rng.uniform(3, 300)
        ends = [e for e in (lo, hi) if np.isfinite(e)]
        if not ends:  # no bound but finiteness: a value past any extent
            kind, v = "far", np.where(pick, rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(200, 300), d)
        else:
            end = float(rng.choice(ends))
            step = past * max(abs(end), 1.0)
            v = np.where(pick, end + step if end == hi else end - step, d)
    elif kind == "at-bound":
        ends = [e for e in (lo, hi) if np.isfinite(e) and not (e == hi and bound.open_hi)]
        if ends:
            v = np.where(pick, float(rng.choice(ends)), d)
        else:
            kind = "ordinary"
    elif kind == "zero":
        v = np.where(pick, 0.0, d)
    elif kind == "negative":
        v = np.where(pick, -np.abs(d) - rng.uniform(0.0, 1.0), d)
    elif kind == "scaled":
        v = d * rng.uniform(0.0, 10.0)
    elif kind == "collapsed":
        v = d.copy()
        if rng.random() < 0.5:
            v[:] = d[int(rng.integers(len(d)))]
        else:
            f = faces[int(rng.integers(len(faces)))]
            v[f[1]] = v[f[2]] = v[f[0]]
    if kind == "ordinary":
        v = d + rng.normal(0.0, 0.01, d.shape) * np.maximum(np.abs(d), 1e-3)
    if jit:  # within the scene's extent
        v = np.clip(v, -1e4, 1e4)
    return np.asarray(v, float), kind


def generate_cases(renderer, n: int, seed: int) -> list[Case]:
    """``n`` seeded cases over ``renderer``'s parameters."""
    from sonarsim.diff.params import bound_of, parameter_bounds

    rng = np.random.default_rng(seed)
    names = list(renderer.names)
    p = {k: np.asarray(v) for k, v in renderer.params().items()}
    table = parameter_bounds()
    faces = {}
    all_faces = np.asarray(renderer.data["faces"])
    face_object = np.asarray(renderer.data["face_object"])
    starts = np.concatenate([[0], np.cumsum([len(p[f"objects.{o}.vertices_m"]) for o in renderer.static.objects])])
    for k, o in enumerate(renderer.static.objects):
        faces[f"objects.{o}.vertices_m"] = all_faces[face_object == k] - starts[k]
    out = []
    for i in range(n):
        mode = str(rng.choice(MODES, p=MODE_WEIGHTS))
        keys = rng.choice(names, size=int(rng.integers(1, 4)), replace=False)
        values, kinds = {}, []
        for key in keys:
            v, kind = mutate(rng, str(key), p[str(key)], bound_of(str(key), table), mode == "jit", faces.get(str(key)))
            values[str(key)] = v
            kinds.append(kind)
        out.append(Case(i, mode, values, tuple(kinds)))
    return out


# The check ---------------------------------------------------------------------------------

class Harness:
    """A renderer of the small scene and its functions, compiled once for many cases."""

    def __init__(self) -> None:
        import jax
        import jax.numpy as jnp

        import sonarsim.diff as sd
        from sonarsim.diff.check import smooth_weights
        from tests.diff.small_scenes import SENSED

        self.jax, self.jnp = jax, jnp
        self.renderer = sd.Renderer(SENSED)
        r = self.renderer
        self.base = r.params()
        self.numpy_base = {k: np.asarray(v) for k, v in self.base.items()}
        self.shape = tuple(r.render().shape)
        w = jnp.asarray(smooth_weights(self.shape))
        f = r.image_function()
        self.image = f
        self.loss_grad = jax.grad(lambda q, d: jnp.sum(w * f(q, d)))
        # The image function is jitted itself (its values are abstract there: nothing is
        # checked), and what render compiles: no compilation of its own.
        self.jit_image = f
        self.jit_grad = self.loss_grad
        self.w = w
        # Refresh cases on a renderer of their own: a refreshed search may hold more paths,
        # and the functions compiled for the larger size would be compiled again for every
        # mode (the two share the compilations while their sizes agree).
        self.refreshed = sd.Renderer(SENSED)
        # Compiled before the cases, so that a case's time is its own: the image, its
        # gradient, a batch of two.
        jax.block_until_ready(self.loss_grad(self.base, r.data))
        self.batched = jax.vmap(r.render)
        jax.block_until_ready(self.batched({k: jnp.stack([v, v]) for k, v in self.base.items()}))


def _valid(case: Case, bounds: bool, base: dict | None = None) -> bool:
    """Whether the scene format takes the case's values (finite, and within the bounds; an
    object's vertices, scaled and posed, within the scene's extent as the scene format's own
    :func:`~sonarsim.config.meshfiles.world_reach_m` measures it)."""
    from types import SimpleNamespace

    from sonarsim.config.meshfiles import world_reach_m
    from sonarsim.config.scene import MAX_COORDINATE_M
    from sonarsim.core.transforms import Pose
    from sonarsim.diff.params import check_value
    from sonarsim.errors import ConfigError

    try:
        for k, v in case.values.items():
            check_value(k, v, None if bounds else {})
    except ConfigError:
        return False
    if bounds and base is not None:
        objects = {k.split(".")[1] for k in case.values if k.startswith("objects.")}
        for o in objects:
            get = lambda part: np.asarray(case.values.get(f"objects.{o}.{part}", base[f"objects.{o}.{part}"]), float)
            reach = world_reach_m(SimpleNamespace(vertices=get("vertices_m")), get("scale"),
                                  Pose(tuple(get("position_m")), tuple(get("rpy_deg"))))
            if reach > MAX_COORDINATE_M:
                return False
    return True


def check_case(h: Harness, case: Case) -> Outcome:
    """Run one case on the harness and judge it (see the module docstring)."""
    from sonarsim.errors import ConfigError
    from sonarsim.diff import StaleSearchWarning

    jax, jnp = h.jax, h.jnp
    r = h.renderer
    out = Outcome(case)
    t0 = time.perf_counter()
    given = {k: jnp.asarray(v) for k, v in case.values.items()}
    finite_in = all(np.isfinite(v).all() for v in case.values.values())
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", StaleSearchWarning)  # far values: the warning is said, and tested elsewhere
            warnings.simplefilter("error", RuntimeWarning)  # NumPy overflow in a check is a defect
            if case.mode == "direct":
                results = [r.render(given)]
            elif case.mode == "grad":  # with respect to every parameter: one compilation for all cases
                results = [jax.grad(lambda q: jnp.sum(h.w * r.render(q)))({**h.base, **given})]
            elif case.mode == "vmap":  # every parameter batched: one compilation for all cases
                full = {**h.base, **given}
                results = [h.batched({k: jnp.stack([v, h.base[k].astype(v.dtype)]) for k, v in full.items()})]
            elif case.mode == "refresh":
                rr = h.refreshed
                try:
                    rr.refresh(given)
                    results = [rr.render(given)]
                finally:
                    rr.refresh()
            else:  # jit
                q = {**h.base, **given}
                results = [h.jit_image(q, r.data), h.jit_grad(q, r.data)]
            leaves = [np.asarray(x) for res in results for x in jax.tree_util.tree_leaves(res)]
    except ConfigError as exc:
        out.seconds = time.perf_counter() - t0
        message = str(exc)
        key = exc.key
        out.refused_key = key
        if "\n" in message:
            out.failure = f"a refusal of more than one line: {message!r}"
        elif case.mode == "refresh" and "lies on the plane" in message:
            pass  # a plane or the sonar moved onto the other: the compiled engine cannot search it
        elif key not in case.values:
            out.failure = f"refused a key not changed: {message}"
        elif case.mode != "jit" and _valid(case, bounds=True, base=h.numpy_base):
            out.failure = f"refused values the scene format takes: {message}"
        elif "within" in message and "[" not in message:
            out.failure = f"the refusal names no range: {message}"
        return out
    except Exception as exc:  # noqa: BLE001 - the defect the fuzz looks for
        out.seconds = time.perf_counter() - t0
        out.failure = f"{type(exc).__name__}: {str(exc)[:300]}"
        return out
    out.seconds = time.perf_counter() - t0
    if case.mode != "jit" and not _valid(case, bounds=True, base=h.numpy_base):
        out.failure = "values the scene format refuses were rendered"
    elif not finite_in:
        out.failure = "values that are not finite were rendered"
    elif not all(np.isfinite(x).all() for x in leaves):
        out.failure = "NaN or inf in the image or gradient from finite values"
    elif np.shape(leaves[0])[-2:] != h.shape and case.mode != "grad":
        out.failure = f"image of shape {np.shape(leaves[0])}, expected {h.shape}"
    else:
        out.rendered = True
    if out.seconds > CASE_TIME_LIMIT_S and out.failure is None:
        out.failure = f"took {out.seconds:.1f} s"
    return out
