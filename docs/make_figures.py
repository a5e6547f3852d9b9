"""Regenerate the documentation's figures and performance tables, each dated.

Run from the repository root after a change to the figures, the demo scenes or the engine::

    python docs/make_figures.py                 # the figures (about 15 s)
    python docs/make_figures.py --tables        # and the performance tables (short runs, 2-4 min)
    python docs/make_figures.py --tables --notebook   # and the differentiable notebook's time

What it writes:

* ``docs/images/*.png``: the demo's figures exactly as ``sonarsim demo`` writes them (it runs the
  command), the exact-pixel comparisons beside them, and, where the real recordings are present
  (``../shared/data``), the pose fit of the real Oculus ping (``sonarsim fit``);
* ``docs/figures.md``: each figure, the command that made it and the date;
* with ``--tables``: the block between ``<!-- make_figures:NAME -->`` and
  ``<!-- /make_figures:NAME -->`` in ``README.md`` and ``docs/performance.md``, from short runs
  of the benchmarks (``benchmarks/bench_render.py``'s frame measurement, ``bench_dataset.py``'s
  rates, the figures' build times), each table with its date, the machine and its load.

The machine this project runs on is shared: the runs are short and ``nice``'d, the load
average at the start is printed in the tables, and figures from one run compare only within it.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
IMAGES = DOCS / "images"
# ../shared/data beside the clone (as the tests find it), or SONARSIM_SHARED_DATA.
SHARED_DATA = Path(os.environ.get("SONARSIM_SHARED_DATA", ROOT.parent / "shared" / "data"))

#: The demo's files copied into docs/images (as demo_<name>), with what each shows.
DEMO_FILES = {
    "fan_figure.png": "the demo's annotated fan (ARIS 3000 over the tank floor, all bounces)",
    "ground_echo_figure.png": "the paper's Fig. 9: single, single + triple, all bounces, one dB scale",
    "ground_echo.png": "single, single + triple, all bounces as exact-pixel fans",
    "multipath_figure.png": "the walled tank's path families: all paths, direct, water surface, walls, steel plate",
    "multipath.png": "the walled tank's path families as exact-pixel fans",
    "aris3000_figure.png": "the ideal render (no sensor, dB), as an ARIS 3000 records it, its expected output (counts)",
    "aris3000.png": "ideal, recorded and expected ARIS 3000 images as exact-pixel fans",
}


def today() -> str:
    """The date stamped on what this run writes (UTC)."""
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d")


def sonarsim_cmd(*args: str) -> list[str]:
    """``python -m sonarsim ARGS`` with this interpreter."""
    return [sys.executable, "-m", "sonarsim", *args]


def run(cmd: list[str], cwd: Path | None = None, required: bool = True) -> float | None:
    """Run a command (its output shown on failure); the seconds it took, or ``None`` where a
    command that is not ``required`` failed (the figures it would have made are kept as they
    were)."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.stderr.write(done.stdout[-2000:] + done.stderr[-2000:])
        message = f"make_figures: {' '.join(cmd)} failed with exit status {done.returncode}"
        if required:
            raise SystemExit(message)
        print(message + ": its figure is left as it was", file=sys.stderr)
        return None
    return time.perf_counter() - t0


# ---------------------------------------------------------------------------------- figures

def make_figures(date: str) -> list[tuple[str, str, str]]:
    """Write the figures; (file, what it shows, command) per figure."""
    made = []
    with tempfile.TemporaryDirectory(prefix="sonarsim-figures-") as tmp:
        out = Path(tmp) / "demo"
        seconds = run(sonarsim_cmd("demo", "--out", str(out)))
        print(f"make_figures: sonarsim demo in {seconds:.1f} s")
        for name, what in DEMO_FILES.items():
            shutil.copyfile(out / name, IMAGES / f"demo_{name}")
            made.append((f"demo_{name}", what, "sonarsim demo --out DIR"))
        ping = SHARED_DATA / "real" / "oculus" / "one_ping_8bit.raw"
        if ping.exists():
            fitted = Path(tmp) / "fitted.yaml"
            run(sonarsim_cmd("fit", str(ping), "--scene", str(ROOT / "examples" / "oculus_floor.yaml"), "--free",
                             "z,pitch,roll", "--domain", "band", "--quiet", "--out", str(fitted)))
            figure = next(Path(tmp).glob("fitted*_fit_figure.png"))
            shutil.copyfile(figure, IMAGES / "oculus_fit_figure.png")
            made.append(("oculus_fit_figure.png", "the real Oculus ping with the fitted floor band, beside the render at the "
                         "fitted pose", "sonarsim fit ../shared/data/real/oculus/one_ping_8bit.raw --scene "
                         "examples/oculus_floor.yaml --free z,pitch,roll --domain band --out fitted.yaml"))
            pings = SHARED_DATA / "real" / "oculus" / "three_pings_8bit.raw"
            calibrated = Path(tmp) / "calibrated.yaml"
            if run(sonarsim_cmd("calibrate", str(pings), "--scene", str(fitted), "--free", "z,pitch,roll",
                                "--evaluate-frames", "1,2", "--method", "gradient", "--out", str(calibrated)),
                   required=False) is not None:
                shutil.copyfile(Path(tmp) / "calibrated_figure.png", IMAGES / "oculus_calibrated_figure.png")
                made.append(("oculus_calibrated_figure.png", "the real Oculus ping, the calibrated model's expected "
                             "image and a speckled frame, in the recording's counts", "sonarsim calibrate "
                             "../shared/data/real/oculus/three_pings_8bit.raw --scene fitted.yaml --free z,pitch,roll "
                             "--evaluate-frames 1,2 --method gradient --out calibrated.yaml"))
        else:
            print(f"make_figures: {ping} absent: the real-data figures are left as they are")
    run([sys.executable, str(DOCS / "make_seabed_figure.py")])
    made.append(("seabed_backscatter.png", "the sediment law: backscattering strength against grazing angle for six sea "
                 "beds at 40 kHz to 1.8 MHz, and their coherent reflectance", "python docs/make_seabed_figure.py"))
    for name, _, _ in made:
        print(f"make_figures: wrote {IMAGES / name}")
    return made


def write_figure_index(made: list[tuple[str, str, str]], date: str) -> None:
    """docs/figures.md: each figure, what it shows, the command and the date; figures this run
    did not make keep their earlier row."""
    page = DOCS / "figures.md"
    rows = {}
    if page.exists():
        for line in page.read_text(encoding="utf-8").splitlines():
            m = re.match(r"^\| `([^`]+)` \|", line)
            if m:
                rows[m.group(1)] = line
    for name, what, cmd in made:
        rows[name] = f"| `{name}` | {what} | `{cmd}` | {date} |"
    # Figures this run did not make (the real data absent, a command that failed) keep their
    # row; one without a row gets the date of its last commit.
    for png in sorted(IMAGES.glob("*.png")):
        if png.name not in rows and png.name != "viewer.png":
            when = subprocess.run(["git", "log", "-1", "--format=%cs", "--", str(png)], cwd=ROOT, capture_output=True,
                                  text=True).stdout.strip() or "unknown"
            rows[png.name] = (f"| `{png.name}` | an earlier figure (see the page that shows it) | not regenerated by "
                              f"this script's last run | {when} |")
    # Not made by this script: a screenshot of a browser (the viewer's test drives Chromium).
    rows.setdefault("viewer.png", "| `viewer.png` | the viewer: the demo scene in 3D with its fan and polar images | "
                    "a screenshot of `sonarsim view sonarsim-demo/scene.yaml` in a browser (not regenerated by this "
                    "script: it needs a browser and a display) | 2026-11 |")
    body = [
        "# Figures: how each was made, and when",
        "",
        "Every figure in this documentation is written by `python docs/make_figures.py` from the",
        "repository root (the demo's by running `sonarsim demo`; the real-data ones where",
        "`../shared/data` is present). The date is the day it was last regenerated.",
        "",
        "| file (`docs/images/`) | what it shows | made by | date |",
        "|---|---|---|---|",
        *[rows[k] for k in sorted(rows)],
        "",
    ]
    page.write_text("\n".join(body), encoding="utf-8")
    print(f"make_figures: wrote {page}")


# ---------------------------------------------------------------------------------- tables

def machine_line() -> str:
    """The machine, for the tables: CPU model, cores, Python, NumPy, and its load at the start."""
    import numpy

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_render import cpu_model

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, NumPy {numpy.__version__}; "
            f"load average {load:.1f} at the start (the machine is shared: other work ran beside these runs)")


def render_table(repeats: int) -> list[str]:
    """Frames/s of the demo and of the Oculus tank (``bench_render.measure``: medians, frames
    and bare casts in alternating blocks)."""
    from bench_render import measure, oculus_scene

    from sonarsim.config.examples import demo_scene_dict

    import sonarsim

    rows = ["| case | image | rays per frame | frame | frames/s | CPU per frame (both threads) | "
            "frame / bare casting |", "|---|---|---|---|---|---|---|"]
    for name, doc in (("demo tank, ARIS 3000, all bounces", demo_scene_dict()),
                      ("the same tank, Oculus M1200d (lf), 512 beams", oculus_scene())):
        runs = [measure(name, doc, repeats) for _ in range(3)]
        fps = sorted(r["fps"] for r in runs)
        ms = statistics.median(r["frame_ms"] for r in runs)
        ratio = statistics.median(r["frame_over_cast"] for r in runs)
        # CPU time moves less than wall time with the neighbours' load: it is what a frame
        # costs, where the wall time is also what the others took.
        with sonarsim.Simulator(sonarsim.load_scene(doc)) as sim:
            for _ in range(3):
                sim.render(keep_rays=False)
            c0 = time.process_time()
            for _ in range(repeats):
                sim.render(keep_rays=False)
            cpu_ms = 1e3 * (time.process_time() - c0) / repeats
        rows.append(f"| {name} | {runs[0]['image']} | {runs[0]['rays_per_frame']:,} | {ms:.2f} ms | "
                    f"{fps[0]:.0f}-{fps[-1]:.0f} | {cpu_ms:.2f} ms | {ratio:.2f} |")
    return rows


def dataset_table(n_frames: int) -> list[str]:
    """Dataset frames/s (``bench_dataset``: the demo orbit, default labels), 1 and 2 workers."""
    from bench_dataset import _rate, scenario_doc

    from sonarsim.dataset import generate, load_scenario

    scenario = load_scenario(scenario_doc(n_frames))
    plain = _rate(scenario, False)
    labelled = _rate(scenario, "total")
    cells = {}
    with tempfile.TemporaryDirectory(prefix="sonarsim-bench-dataset-") as tmp:
        for workers in (1, 2):
            stamps: list[float] = []
            summary = generate(scenario, Path(tmp) / f"w{workers}", threads=1, progress=False, log=lambda m: None,
                               labels="total", workers=workers, on_frame=lambda k: stamps.append(time.perf_counter()))
            warm = 2 * workers
            steady = (len(stamps) - warm) / (stamps[-1] - stamps[warm - 1])
            cells[workers] = (steady, summary.frames_per_s)
    return ["| plain render (1 thread) | labelled render | 1 worker, written: steady (whole run) | "
            "2 workers, written: steady (whole run) |", "|---|---|---|---|",
            f"| {plain:.0f} fps | {labelled:.0f} fps | {cells[1][0]:.1f} ({cells[1][1]:.1f}) fps | "
            f"{cells[2][0]:.1f} ({cells[2][1]:.1f}) fps |"]


def figures_table() -> list[str]:
    """Build-and-write time of each of the demo's figures (best of 3)."""
    import sonarsim
    from sonarsim.config.examples import demo_scene_dict, tank_scene_dict
    from sonarsim.plot import figures as F

    demo = sonarsim.render(demo_scene_dict())
    tank = sonarsim.render(tank_scene_dict(mirror=True))
    cases = {"fan_figure": lambda: F.fan_figure(demo), "polar_figure": lambda: F.polar_figure(demo),
             "ground_echo_figure": lambda: F.ground_echo_figure(demo),
             "multipath_figure": lambda: F.multipath_figure(tank)}
    rows = ["| figure | build and write (PNG) |", "|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        F.save_figure(F.fan_figure(demo), Path(tmp) / "warm.png")  # imports, fonts
        for name, build in cases.items():
            best = float("inf")
            for _ in range(3):
                t0 = time.perf_counter()
                F.save_figure(build(), Path(tmp) / f"{name}.png")
                best = min(best, time.perf_counter() - t0)
            rows.append(f"| `{name}` | {best:.2f} s |")
    return rows


def notebook_seconds(path: Path) -> float:
    """Wall time of running a notebook top to bottom (nbclient), as the test suite runs it."""
    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    t0 = time.perf_counter()
    NotebookClient(nb, timeout=1200, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    return time.perf_counter() - t0


def _steady(cell: str) -> str:
    """A dataset cell ("8.2 (7.4) fps") in words."""
    steady, whole = re.findall(r"[\d.]+", cell)[:2]
    return f"{steady} frames/s steady ({whole} over the whole run, the workers' start included)"


def kept_lines(path: Path, name: str, prefix: str, blank: bool = False) -> list[str]:
    """The lines of the file's ``NAME`` block that start with ``prefix`` (a figure not measured
    this time keeps its last measurement and date), after a blank line if ``blank``."""
    text = path.read_text(encoding="utf-8")
    match = re.search(rf"<!-- make_figures:{name} -->(.*?)<!-- /make_figures:{name} -->", text, re.S)
    lines = [line for line in (match.group(1).splitlines() if match else []) if line.startswith(prefix)]
    return ([""] if blank and lines else []) + lines


def replace_block(path: Path, name: str, lines: list[str]) -> None:
    """Put ``lines`` between the file's ``<!-- make_figures:NAME -->`` markers."""
    text = path.read_text(encoding="utf-8")
    start, end = f"<!-- make_figures:{name} -->", f"<!-- /make_figures:{name} -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise SystemExit(f"make_figures: {path} has no {start} ... {end} block")
    text = pattern.sub(lambda _: "\n".join([start, *lines, end]), text, count=1)
    path.write_text(text, encoding="utf-8")
    print(f"make_figures: updated the {name} block of {path}")


def make_tables(date: str, repeats: int, n_frames: int, notebook: bool) -> None:
    """Measure and write the tables (README's summary, docs/performance.md's current figures)."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    machine = machine_line()
    render = render_table(repeats)
    print("\n".join(render))
    dataset = dataset_table(n_frames)
    print("\n".join(dataset))
    figures = figures_table()
    print("\n".join(figures))
    nb = None
    if notebook:
        nb = notebook_seconds(ROOT / "examples" / "differentiable.ipynb")
        print(f"examples/differentiable.ipynb: {nb:.0f} s")
    stamp = f"Measured {date} by `python docs/make_figures.py --tables` on {machine}."
    page = [stamp, "", "**Frames** (three short runs of `benchmarks/bench_render.py`'s measurement, medians "
            f"of {repeats} frames each; the range of frames/s over the runs):", "", *render, "",
            f"**Datasets** (`benchmarks/bench_dataset.py`'s orbit of the demo tank, {n_frames} frames, the default "
            "labels, NPZ + fan PNG + manifest written, one thread per worker; steady leaves out the workers' start):",
            "", *dataset, "", "**Figures** (best of 3):", "", *figures]
    if nb is not None:
        page += ["", f"**The differentiable notebook** (`examples/differentiable.ipynb`, run top to bottom by "
                     f"nbclient as the tests run it; {date}, load average {load:.1f}): {nb:.0f} s."]
    else:  # not measured this time: the last measurement stays, with its own date
        page += kept_lines(DOCS / "performance.md", "current", "**The differentiable notebook**", blank=True)
    replace_block(DOCS / "performance.md", "current", page)
    demo_row = render[2].split("|")
    dataset_row = dataset[2].split("|")
    summary = [f"Measured {date} (`python docs/make_figures.py --tables`, short runs on a shared "
               f"{os.cpu_count()}-core machine whose load average was {load:.1f}: other work ran beside them, and "
               "a quiet machine gives more; details in [docs/performance.md](docs/performance.md)):", "",
               f"- the demo (1288 x 128, all bounces): {demo_row[5].strip()} frames/s, {demo_row[4].strip()} a frame "
               f"({demo_row[6].strip()} of CPU);",
               "- a dataset of it with the default labels, written (NPZ, fan PNG, manifest): "
               f"{_steady(dataset_row[3])} with 1 worker, {_steady(dataset_row[4])} with 2;"]
    if nb is not None:
        summary.append(f"- `examples/differentiable.ipynb` runs in {nb / 60:.1f} min ({date}, load average {load:.1f}).")
    else:
        summary += kept_lines(ROOT / "README.md", "summary", "- `examples/differentiable.ipynb`")
    replace_block(ROOT / "README.md", "summary", summary)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tables", action="store_true", help="also measure and write the performance tables")
    p.add_argument("--notebook", action="store_true", help="with --tables: time examples/differentiable.ipynb")
    p.add_argument("--no-figures", action="store_true", help="the tables only")
    p.add_argument("--repeats", type=int, default=30, help="frames per measurement (default 30)")
    p.add_argument("--frames", type=int, default=60, help="dataset frames per run (default 60)")
    args = p.parse_args(argv)
    try:
        os.nice(10)  # a shared machine: the others' work first
    except OSError:
        pass
    date = today()
    if not args.no_figures:
        write_figure_index(make_figures(date), date)
    if args.tables:
        make_tables(date, args.repeats, args.frames, args.notebook)
    return 0


if __name__ == "__main__":
    sys.exit(main())
