"""The annotated figures the commands write next to their exact-pixel PNGs, and their options.

``render``, ``demo``, ``show``, ``fit`` and ``calibrate`` write figures made by
:mod:`sonarsim.plot.figures` beside exact-pixel PNGs; ``compare --out`` writes its figure alone
(``compare_figure.png``). All of them write figures made by
:mod:`sonarsim.plot.figures` (``fan_figure.png``, ``polar_figure.png``, ...). Their names are
planned with the command's :class:`~sonarsim.io.run_record.OutputRun` before any work, from
:func:`figure_names`, so the run's record lists them and stale ones are removed; each is
written atomically.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

__all__ = ["add_figure_options", "figure_formats", "figure_names", "figure_paths", "write_figure"]


def _formats(text: str) -> tuple[str, ...]:
    from ..plot import FIGURE_FORMATS  # no numpy: this runs while the command line is parsed

    values = tuple(dict.fromkeys(v.strip().lower() for v in text.split(",") if v.strip()))
    bad = [v for v in values if v not in FIGURE_FORMATS]
    if not values or bad:
        raise argparse.ArgumentTypeError(
            f"--figure-format must be a comma-separated list of {', '.join(FIGURE_FORMATS)} (e.g. png or png,pdf), "
            f"got {text!r}")
    return values


def _colormap(text: str) -> str:
    # matplotlib spells it "gray": accepted as the same map (and any case).
    name = text.strip().lower()
    return "grey" if name == "gray" else name


def add_figure_options(p: argparse.ArgumentParser, exact_pixels: bool = True) -> None:
    """``--figure-format``, ``--colormap`` and ``--no-figures``.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The command's parser.
    exact_pixels : bool
        Whether the command also writes exact-pixel images, which ``--no-figures`` leaves; a
        command that writes only figures (``compare``) says so in the help instead.
    """
    from ..plot.style import COLORMAPS, DEFAULT_COLORMAP

    g = p.add_argument_group("figures (annotated, for people: axes in metres and degrees, colour bar, title)")
    g.add_argument("--figure-format", type=_formats, default=("png",), metavar="LIST",
                   help="formats of the figures: png, svg, pdf, or several (e.g. png,pdf) (default: png)")
    g.add_argument("--colormap", type=_colormap, choices=COLORMAPS, default=DEFAULT_COLORMAP,
                   help=f"colour map of the figures (default: {DEFAULT_COLORMAP}, perceptually uniform; grey: "
                   "the device's look)")
    g.add_argument("--no-figures", action="store_true",
                   help="write no figures, only the exact-pixel images" if exact_pixels else
                   "write no figure (this command writes no other image: with --no-figures, --out writes nothing)")


def figure_formats(args: argparse.Namespace) -> tuple[str, ...]:
    """The formats asked for; none with ``--no-figures`` (or for callers without the options)."""
    if getattr(args, "no_figures", False):
        return ()
    return tuple(getattr(args, "figure_format", ("png",)))


def figure_names(args: argparse.Namespace, stems: Iterable[str]) -> list[str]:
    """File names of the figures ``stems`` (e.g. ``fan_figure``) in every format asked for."""
    formats = figure_formats(args)
    return [f"{stem}.{fmt}" for stem in stems for fmt in formats]


def figure_paths(args: argparse.Namespace, stem_path: Path) -> list[Path]:
    """Paths of one figure (``stem_path`` without suffix) in every format asked for."""
    return [stem_path.with_name(f"{stem_path.name}.{fmt}") for fmt in figure_formats(args)]


def write_figure(args: argparse.Namespace, stem_path: Path, build: Callable[[], Any], run: Any = None) -> list[Path]:
    """Build a figure (only if figures are asked for) and write it in each format, atomically.

    Parameters
    ----------
    args : argparse.Namespace
        With the options of :func:`add_figure_options` (absent: PNG).
    stem_path : Path
        Where, without the suffix (e.g. ``out / "fan_figure"``).
    build : callable
        ``build() -> matplotlib.figure.Figure``.
    run : OutputRun, optional
        Learns each path before it is written (already planned paths are simply kept).

    Returns
    -------
    list of Path
        The files written.
    """
    from ..plot.figures import _close, save_figure

    paths = figure_paths(args, stem_path)
    if not paths:
        return []
    t0 = time.perf_counter()
    fig = build()
    try:
        for path in paths:
            if run is not None:
                run.add(path)
            save_figure(fig, path, close=False)
    finally:
        _close(fig)
    if getattr(args, "quiet", False):  # fit --quiet: errors only
        return paths
    names = ", ".join(str(p) for p in paths)
    print(f"sonarsim: wrote {names} in {time.perf_counter() - t0:.2f} s", file=sys.stderr, flush=True)
    return paths
