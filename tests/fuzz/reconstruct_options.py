"""Seeded fuzzing of ``sonarsim reconstruct``'s options (issue 37): generators and the check
every case must pass.

A case is one command line: one to three images (render.npz files, one with NaN rows, one
without echo, a file of random bytes, a missing file), the starting scene (or a broken one),
``--extent`` and ``--resolution`` drawn from plain, extreme and malformed values (in the
``--opt VALUE`` and the ``--opt=VALUE`` forms, values with a leading minus included),
``--smoothness``, ``--poses`` (right, out of reach, looking away, the wrong count, not a list),
``--truth`` (a floor under the extent, one elsewhere, a face past the vertices, missing),
``--reflectivity``, the budgets (``--max-memory``, ``--max-build-time``), and now and then a
required option left out or an unknown one added.

:func:`check_case` runs the command in this process (:func:`sonarsim.cli.main.main`) and says
whether it kept the promise: exit status 0 with the NPZ written and its grid the one asked
for, or 2 (bad input) or 3 (an outcome that means nothing) with one ``error:`` line naming an
option or a file, nothing written; never a traceback, another status, a case past its time
limit or a traced allocation beyond the memory budget given. By default the reconstruction
itself is replaced by a stand-in that checks what it is handed (the options' checks passed:
a finite smoothness in range, finite images with echo, a grid within the budgets) and returns
a flat floor of the planned grid, so that a case takes milliseconds; ``real=True`` runs the
reconstruction (seconds to minutes: the long run does one case in so many).

Used by ``tests/fuzz/test_reconstruct_fuzz.py`` (a few hundred cases) and
``benchmarks/fuzz_reconstruct.py`` (the long run).
"""

from __future__ import annotations

import contextlib
import io
import re
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from tests.fuzz.scenes import CaseTimeout, time_limit

SONAR = {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 120}
RENDER = {"bounces": [1], "max_order": 1}
VALID_EXTENT = "1,3,-0.8,0.8"

#: The memory budget a case runs under when it gives none, and the largest it may give: small,
#: so that a size nobody checked shows up as a traced allocation beyond it.
FUZZ_BUDGET = "256M"
FUZZ_BUDGET_BYTES = 256 * 2**20
#: Seconds a case may take: the stand-in's cases are refused or written in well under a
#: second here; a real reconstruction of the small grids the budgets allow, in minutes.
CASE_TIME_LIMIT_S = 30.0
REAL_TIME_LIMIT_S = 600.0
MAX_MESSAGE_CHARS = 2000

IMAGES = ("view0.npz", "view1.npz", "nan.npz", "zero.npz", "noise.npz", "missing.npz")
POSES = ("poses1.yaml", "poses2.yaml", "far.yaml", "away.yaml", "three.yaml", "mapping.yaml", "missing.yaml")
TRUTHS = ("truth.obj", "elsewhere.obj", "badindex.obj", "empty.obj", "missing.obj")
SCENES = ("start.yaml", "start.yaml", "start.yaml", "broken.yaml", "missing.yaml")
NUMBERS = ("0", "-0", "1", "-1", "0.1", "0.2", "0.5", "2", "3", "-0.8", "0.8", "1e-4", "1e-300", "5e-324", "1e6",
           "-1e6", "1e7", "1e300", "-1e300", "1e400", "nan", "inf", "-inf", "-nan", "abc", "", "1,2", "0x10", " 1")
RESOLUTIONS = ("0.1", "0.2", "0.25", "0.4", "0.05", "0.02", "0.01", "1e-3", "1e-4", "1e-300", "5e-324", "0", "-0.1",
               "1.6", "1.7", "5", "1000", "nan", "inf", "-inf", "x", "0.1,0.1", "")
SMOOTHNESS = ("0", "1e-3", "1e-2", "1", "1e3", "1e4", "-10", "-1e-9", "-0", "nan", "inf", "-inf", "5e-324", "x", "")
MEMORY = ("64M", "128M", "256M", "1M", "512K", "0", "-1", "1e400", "x")
BUILD_TIME = ("1", "2", "5", "30", "120", "0.5", "0", "-5", "1 week", "x")


@dataclass
class Case:
    """One command line (``argv``, without the program's name) of seed ``index``."""

    index: int
    argv: list[str]
    notes: list[str]
    real: bool = False

    def describe(self) -> str:
        return f"case {self.index} ({', '.join(self.notes) or 'valid'}): sonarsim {' '.join(self.argv)}"


def make_files(folder: Path) -> Path:
    """Write the images, scenes, poses and meshes the cases name into ``folder``; returns it."""
    import sonarsim
    from sonarsim.core.transforms import Pose

    folder.mkdir(parents=True, exist_ok=True)
    doc = {"sonar": SONAR, "render": RENDER, "ground": {"albedo": 0.6}}
    poses = [Pose((0.0, 0.0, 1.0), (0.0, 25.0, 0.0)), Pose((0.0, -0.5, 1.0), (0.0, 25.0, 12.0))]
    with sonarsim.Simulator(doc) as sim:
        for k, pose in enumerate(poses):
            sim.render(pose=pose, speckle=False).save_npz(folder / f"view{k}.npz")
    (folder / "start.yaml").write_text(yaml.safe_dump(doc))
    (folder / "broken.yaml").write_text("sonar: {preset: nope\n")
    members = dict(np.load(folder / "view0.npz"))
    nan = members["polar"].copy()
    nan[40:42] = np.nan
    np.savez(folder / "nan.npz", **{**members, "polar": nan})
    np.savez(folder / "zero.npz", **{**members, "polar": np.zeros_like(members["polar"])})
    (folder / "noise.npz").write_bytes(np.random.default_rng(0).bytes(4096))
    one = {"position_m": [0, 0, 1], "rpy_deg": [0, 25, 0]}
    two = [one, {"position_m": [0, -0.5, 1], "rpy_deg": [0, 25, 12]}]
    for name, value in (("poses1.yaml", [one]), ("poses2.yaml", two),
                        ("far.yaml", [{"position_m": [1e6, 0, 1], "rpy_deg": [0, 25, 0]}] * 3),
                        ("away.yaml", [{"position_m": [0, 0, 1], "rpy_deg": [0, 25, 180]}] * 3),
                        ("three.yaml", [one] * 3), ("mapping.yaml", one)):
        (folder / name).write_text(yaml.safe_dump(value))
    (folder / "truth.obj").write_text("v 0 -2 0\nv 4 -2 0\nv 4 2 0\nv 0 2 0\nf 1 2 3\nf 1 3 4\n")
    (folder / "elsewhere.obj").write_text("v 50 50 0\nv 51 50 0\nv 50 51 0\nf 1 2 3\n")
    (folder / "badindex.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    (folder / "empty.obj").write_text("")
    return folder


def _option(rng: np.random.Generator, name: str, value: str) -> list[str]:
    # Both forms a user types; the separate token also when the value begins with a minus.
    return [f"{name}={value}"] if rng.random() < 0.3 else [name, value]


def _valid_extent(rng: np.random.Generator) -> str:
    """A rectangle the views see part of (they look along +x from x = 0, 1 m up, 0.7-3.5 m)."""
    x0, y0 = rng.uniform(0.5, 2.0), rng.uniform(-1.5, 0.0)
    return f"{x0:.2f},{x0 + rng.uniform(0.6, 2.5):.2f},{y0:.2f},{y0 + rng.uniform(0.6, 2.0):.2f}"


def _hostile_extent(rng: np.random.Generator) -> str:
    if rng.random() < 0.3:  # a rectangle elsewhere, negative corners included
        x0, y0 = rng.uniform(-50, 50, 2).round(2)
        return f"{x0:g},{x0 + rng.uniform(0.2, 40):.2f},{y0:g},{y0 + rng.uniform(0.2, 40):.2f}"
    n = int(rng.choice([4, 4, 4, 3, 5, 1]))
    return ",".join(str(rng.choice(NUMBERS)) for _ in range(n))


#: What a case may make hostile; the rest of its command line is valid.
ASPECTS = ("images", "scene", "extent", "resolution", "smoothness", "poses", "truth", "max-memory", "max-build-time",
           "left out", "unknown")


def generate_cases(n: int, seed: int, real_every: int = 0) -> Iterator[Case]:
    """``n`` cases from ``seed`` (the same cases for the same seed): a valid command line with
    0 to 3 of its :data:`ASPECTS` made hostile; every ``real_every``-th case (0: none) runs the
    real reconstruction."""
    rng = np.random.default_rng(seed)
    for index in range(n):
        m = int(rng.choice([0, 1, 1, 2, 2, 3]))
        hostile = set(rng.choice(ASPECTS, m, replace=False)) if m else set()
        notes = sorted(hostile)
        budgets: list[str] = []
        memory = str(rng.choice(MEMORY)) if "max-memory" in hostile else FUZZ_BUDGET
        budgets += _option(rng, "--max-memory", memory)
        if "max-build-time" in hostile:
            budgets += _option(rng, "--max-build-time", str(rng.choice(BUILD_TIME)))
        k = int(rng.choice([1, 1, 2]))
        images = list(rng.choice(IMAGES, k)) if "images" in hostile else ["view0.npz", "view1.npz"][:k]
        options = {
            "--scene": str(rng.choice(SCENES[3:])) if "scene" in hostile else "start.yaml",
            "--extent": _hostile_extent(rng) if "extent" in hostile else _valid_extent(rng),
            "--resolution": str(rng.choice(RESOLUTIONS)) if "resolution" in hostile
            else str(rng.choice(["0.1", "0.2", "0.25", "0.4"])),
            "--out": "OUT",
        }
        if "smoothness" in hostile:
            options["--smoothness"] = str(rng.choice(SMOOTHNESS))
        elif rng.random() < 0.3:
            options["--smoothness"] = str(rng.choice(["0", "1e-3", "0.1", "1000"]))
        if "poses" in hostile:
            options["--poses"] = str(rng.choice(POSES))
        elif rng.random() < 0.2:
            options["--poses"] = f"poses{k}.yaml"
        if "truth" in hostile or rng.random() < 0.2:
            options["--truth"] = str(rng.choice(TRUTHS)) if "truth" in hostile else "truth.obj"
        if "left out" in hostile:
            del options[str(rng.choice(["--scene", "--extent", "--resolution", "--out"]))]
        args = ["reconstruct", *images]
        for name in rng.permutation(list(options)):
            args += _option(rng, str(name), options[name])
        if rng.random() < 0.15:
            args.append("--reflectivity")
        if "unknown" in hostile:
            args += [str(rng.choice(["--nope", "-x", "--extent-x"])), str(rng.choice(["-1", "1", "-1e3,2"]))]
        yield Case(index, budgets + args, notes, real=bool(real_every) and index % real_every == 0)


# The check -----------------------------------------------------------------------------------

@dataclass
class Outcome:
    """What a case came to: ``status`` 0 (written), 2 or 3 (refused, naming ``error_key``), or a
    ``failure`` (why it broke the promise)."""

    case: Case
    status: int | None = None
    error_key: str | None = None
    failure: str | None = None
    seconds: float = 0.0
    peak_bytes: int = 0
    real: bool = False


_OPTION = re.compile(r"(--[a-z][a-z-]*)")


def _resolve(argv: list[str], folder: Path, out: Path) -> list[str]:
    """The case's file names made paths in ``folder`` (``OUT``: the case's output)."""
    resolved = []
    for a in argv:
        name, eq, value = a.partition("=")
        target = value if eq else a
        if target == "OUT":
            target = str(out)
        elif re.fullmatch(r"[a-z0-9]+\.(npz|yaml|obj)", target):
            target = str(folder / target)
        resolved.append(f"{name}={target}" if eq else target)
    return resolved


def _stand_in(budget_bytes: int):
    """A reconstruction that checks what it is handed, and returns a flat floor of the grid."""
    from sonarsim.diff import reconstruct as rec

    def reconstruct_heights(scene, images, poses, extent, resolution, smoothness=1e-3, reflectivity=False,
                            progress=None, **kwargs):
        lo, hi = rec.SMOOTHNESS_RANGE
        assert lo <= smoothness <= hi, f"the reconstruction was handed smoothness {smoothness!r}"
        assert len(images) == len(poses) and images, "the reconstruction was handed no images or no poses"
        for img in images:
            assert np.all(np.isfinite(img)) and np.any(np.asarray(img) > 0), "handed an image that is not finite"
        # The CLI checked the plan: here it must pass (raising would be a refusal too late).
        try:
            plan = rec.plan_grid(extent, resolution, len(images), scene)
        except Exception as exc:  # noqa: BLE001 - any refusal here comes after the CLI's checks
            raise AssertionError(f"the plan was refused only at the reconstruction: {exc}") from None
        assert plan.bytes <= budget_bytes, "a plan beyond the budget reached the reconstruction"
        x, y = rec.grid_axes(extent, resolution)
        shape = (len(y), len(x))
        return rec.HeightField(np.zeros(shape), x, y, np.ones(shape, bool), np.array([1.0, 0.5]), 0.0,
                               reflectivity=np.ones(shape) if reflectivity else None)

    return reconstruct_heights


class _Figure:
    """A stand-in for the figure: drawing one takes a second, the fuzz wants thousands."""

    def savefig(self, f, **kwargs) -> None:
        f.write(b"\x89PNG stand-in")


def _budget_of(argv: list[str]) -> int:
    """The memory budget the case runs under (bytes; the fuzz's when it gives none that parses)."""
    from sonarsim.core.memory import parse_size

    for i, a in enumerate(argv):
        text = a.split("=", 1)[1] if a.startswith("--max-memory=") else argv[i + 1] if a == "--max-memory" else None
        if text is not None:
            try:
                return parse_size(text)
            except ValueError:
                return FUZZ_BUDGET_BYTES
    return FUZZ_BUDGET_BYTES


def check_case(case: Case, folder: Path, workdir: Path, real: bool | None = None) -> Outcome:
    """Run ``case`` in this process on the files of ``folder`` (:func:`make_files`), its output
    in ``workdir``; returns what it came to (see the module's promise)."""
    from sonarsim.cli import reconstruct as cli_rec
    from sonarsim.cli.main import main
    from sonarsim.diff import reconstruct as rec

    real = case.real if real is None else real
    out_path = workdir / f"h{case.index}.npz"
    figure = out_path.with_name(out_path.stem + "_figure.png")
    argv = _resolve(case.argv, folder, out_path)
    budget = _budget_of(argv)
    outcome = Outcome(case, real=real)
    stdout, stderr = io.StringIO(), io.StringIO()
    saved = rec.reconstruct_heights, cli_rec._figure
    if not real:
        rec.reconstruct_heights = _stand_in(budget)
        cli_rec._figure = lambda result, truth: _Figure()
    tracing = not real  # (JAX's buffers are not traced; the real run is sized by the plan)
    if tracing:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with time_limit(REAL_TIME_LIMIT_S if real else CASE_TIME_LIMIT_S), \
                contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                outcome.status = main(argv)
            except SystemExit as exc:  # argparse's refusals
                outcome.status = exc.code
    except CaseTimeout as exc:
        outcome.failure = f"the case {exc}"
    except BaseException as exc:  # noqa: BLE001 - what the promise forbids: a traceback
        outcome.failure = f"{type(exc).__name__} escaped: {str(exc)[:300]}"
    finally:
        outcome.seconds = time.perf_counter() - t0
        if tracing:
            outcome.peak_bytes = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        rec.reconstruct_heights, cli_rec._figure = saved
    if outcome.failure is None:
        outcome.failure = _judge(outcome, stdout.getvalue(), stderr.getvalue(), out_path, figure, budget, tracing)
    for path in (out_path, figure, out_path.with_name(out_path.name + ".run.json")):
        path.unlink(missing_ok=True)
    for path in workdir.glob(f"{out_path.stem}*"):
        path.unlink(missing_ok=True)
    return outcome


def _judge(outcome: Outcome, out: str, err: str, out_path: Path, figure: Path, budget: int,
           traced: bool) -> str | None:
    status = outcome.status
    if "Traceback" in err:
        return "a traceback on stderr"
    if traced and outcome.peak_bytes > budget:
        return f"traced {outcome.peak_bytes / 2**20:.1f} MiB, beyond the {budget / 2**20:.0f} MiB budget"
    if status == 0:
        if not out_path.is_file() or not figure.is_file():
            return "exit 0 without the NPZ and the figure"
        with np.load(out_path) as d:
            h, x, y = d["heights_m"], d["x_m"], d["y_m"]
            if h.shape != (len(y), len(x)) or not np.all(np.isfinite(h)):
                return f"heights of shape {h.shape} for {len(y)} x {len(x)} vertices, or not finite"
        if "grid vertices seen by" not in out or "nan" in out.lower():
            return f"no summary line, or a NaN in it: {out.strip()[:200]!r}"
        return None
    if status not in (2, 3):
        return f"exit status {status!r}"
    errors = [line for line in err.splitlines() if "error:" in line]
    if len(errors) != 1:
        return f"{len(errors)} error lines: {err.strip()[:300]!r}"
    line = errors[0]
    if len(line) > MAX_MESSAGE_CHARS:
        return f"a message of {len(line)} characters"
    left = [p.name for p in (out_path, figure) if p.exists()]
    if left:
        return f"refused, yet wrote {', '.join(left)}"
    message = line.split("error:", 1)[1]
    option = _OPTION.search(message)
    named_file = re.search(r"/([a-z0-9]+\.(?:npz|yaml|obj))", message)
    if status == 3:  # by its first words, the files' folders left out
        outcome.error_key = "3: " + " ".join(re.sub(r"\S*/", "", message).split()[:4])
    elif option:
        outcome.error_key = option.group(1)
    elif named_file:
        outcome.error_key = "file: " + named_file.group(1)
    elif "required" in message or "unrecognized" in message:
        outcome.error_key = message.split(":")[0].strip()
    else:
        return f"a refusal naming no option and no file: {line[:200]!r}"
    return None


@dataclass
class Summary:
    """Counts over many outcomes."""

    cases: int = 0
    written: int = 0
    real: int = 0
    by_status: dict[int, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    slowest_s: float = 0.0
    slowest_case: str = ""
    peak_bytes: int = 0

    def add(self, out: Outcome) -> None:
        self.cases += 1
        self.written += out.status == 0 and out.failure is None
        self.real += out.real
        if out.status is not None:
            self.by_status[out.status] = self.by_status.get(out.status, 0) + 1
        if out.error_key:
            self.refused[out.error_key] = self.refused.get(out.error_key, 0) + 1
        if out.failure:
            self.failures.append(f"{out.case.describe()}: {out.failure}")
        if out.seconds > self.slowest_s and not out.real:
            self.slowest_s, self.slowest_case = out.seconds, out.case.describe()
        self.peak_bytes = max(self.peak_bytes, out.peak_bytes)
