"""``sonarsim show``: write the polar and fan images of one frame of a real recording, or of an
image sonarsim stored (a dataset frame's NPZ, ``render.npz``).

Wiring (in :mod:`sonarsim.cli.main`)::

    from ..io.readers.readers.show import add_show_parser, cmd_show
    add_show_parser(sub)          # in build_parser(), after the other sub-commands
    COMMANDS["show"] = cmd_show

Display mapping. Recorded 8-bit values are already display values: ARIS maps 0-80 dB of echo
level onto 0-255 (aris-file-sdk, "Understanding ARIS data"), and the Oculus sends
gamma-compressed 8-bit data. A dB mapping would compress them a second time and wash out the
image, so the default is ``linear`` with 0 dB gain against the data type's full scale (255):
the PNG then shows exactly the recorded values, as the sonar's own software would, and frames
of one recording keep comparable brightness. Wider data (16/24/32-bit Oculus pings) use the
frame's maximum as full scale. ``--mapping db`` remains available (dB window below that
reference, ``--dynamic-range-db`` wide). A stored sonarsim image is shown as ``sonarsim render``
shows it: a render's intensity in dB below its maximum, a sensor model's output in its counts
(:func:`sonarsim.plot.figures.default_scale` decides, for the PNGs and the figures alike).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from ..core.console import log as _log
from .argtypes import display_gain_db, display_range_db, ping_count_or_range, positive_float

__all__ = ["add_show_parser", "cmd_show", "figure_title"]


def add_show_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``show`` sub-command to an ``argparse`` sub-parsers object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers()`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The new sub-parser; its defaults carry ``func=cmd_show``.
    """
    p = subparsers.add_parser(
        "show",
        help="write polar.png and fan.png of one frame of a real recording (ARIS, Oculus) or a stored image (NPZ)",
        description="Read one frame of a real sonar recording - an ARIS .aris file or Oculus "
        "simple-ping-result messages (.raw), recognised by content - or an image sonarsim stored (a dataset "
        "frame's frames/NNNNNN.npz, render.npz), and write polar.png "
        "(range up, left-most beam on the left) and fan.png into --out, the annotated figures fan_figure.png and "
        "polar_figure.png (axes in metres and degrees, colour bar in the device's counts or a render's dB, title; --figure-format, "
        "--no-figures), then sonarsim-run.json, the run's record.",
    )
    p.add_argument("recording", metavar="FILE",
                   help="the recording (.aris, or Oculus .raw messages), or a sonarsim image (.npz)")
    p.add_argument("--frame", type=int, default=0, metavar="N",
                   help="0-based frame (ARIS) or ping (Oculus) to show (default: 0; an NPZ holds frame 0 only)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--pings", type=ping_count_or_range, default=None, metavar="A:B",
                   help="a side-scan, multibeam or echo-sounder recording: the pings A to B - 1 (default: all)")
    g = p.add_argument_group("images")
    g.add_argument("--pixel-size", type=positive_float, default=None, metavar="M",
                   help="fan image pixel size in metres (default: the range resolution)")
    g.add_argument("--mapping", choices=("db", "linear"), default=None,
                   help="PNG intensity mapping (default: linear for a recording and a sensor model's output, which "
                   "shows the recorded 8-bit values as they are - db compresses them a second time; db for a "
                   "render's intensity)")
    g.add_argument("--gain-db", type=display_gain_db, default=0.0, metavar="DB", help="display gain in dB (default: 0)")
    g.add_argument("--dynamic-range-db", type=display_range_db, default=40.0, metavar="DB",
                   help="width of the dB window shown with --mapping db (default: 40)")
    from .figures import add_figure_options

    add_figure_options(p)
    p.set_defaults(func=cmd_show)
    return p


def cmd_show(args: argparse.Namespace) -> None:
    """Run ``sonarsim show``: read ``args.recording`` frame ``args.frame``, write the PNGs.

    Parameters
    ----------
    args : argparse.Namespace
        ``recording``, ``frame``, ``out``, ``pixel_size``, ``mapping``, ``gain_db`` and
        ``dynamic_range_db``, as :func:`add_show_parser` defines them.

    Raises
    ------
    RecordingError
        For an unreadable recording or a frame that is not among its good frames (a
        SonarsimError: the CLI prints it on one line and exits with status 2). A recording
        damaged after the frame shown is shown, with a note on stderr naming the damage.
    OutputError
        If --out cannot be written; checked before the recording is read.
    OSError
        If the recording cannot be opened, or a write fails (e.g. a full disk).
    """
    from ..io.output import write_png
    from ..io.readers import open_recording
    from ..io.run_record import OutputRun
    from ..plot.figures import default_scale, fan_figure, polar_figure
    from .figures import figure_names, write_figure

    out = Path(args.out)
    film = _film_of(args.recording)
    if film != "polar":
        return _show_film(args, film, out)
    # Checked before the recording is read; nothing is written until both images exist.
    run = OutputRun.for_folder(out, ["polar.png", "fan.png", *figure_names(args, ("fan_figure", "polar_figure"))],
                               command=getattr(args, "command_line", None))
    run.protect([(args.recording, "the recording")])
    t0 = time.perf_counter()
    with open_recording(args.recording) as recording:
        image = recording.read(args.frame)
        # The good frames (those before any damage: the readers' common rule), and what ends them.
        total, damage, unit = recording.n_frames, recording.damage, recording.unit
    t1 = time.perf_counter()
    s = image.sonar
    # (A stored image's config is its scene's, not a recording's source/format/frame.)
    source = os.fspath(args.recording)
    _log(
        f"read {recording.format} frame {image.config.get('frame', args.frame)} of {total} from {source}: "
        f"{s.n_range_bins} ranges x {s.n_beams} beams, {s.range_min_m:.3f}-{s.range_max_m:.3f} m, "
        f"{s.azimuth_fov_deg:.1f} deg wide, in {t1 - t0:.3f} s"
    )
    if damage is not None:
        what = ": ".join(part for part in (damage.where, damage.field, damage.detail) if part)
        _log(f"note: {source} is damaged after {unit} {total - 1}: its good {unit}s are 0 to "
             f"{total - 1} ({what})")

    # One scale for the PNGs and the figures: a device's counts against its full scale (255
    # for 8-bit data whatever the frame holds, see the module notes), a render's intensity in
    # dB below its maximum.
    scale = default_scale(image, args.mapping, args.gain_db, args.dynamic_range_db)
    # Far range at the top of the polar PNG, like the fan, so both read the same way.
    polar_png = scale.encode(image.polar[::-1])
    # The fan's levels made on the polar grid and resampled, as render draws fan.png.
    fan_png = image.fan_levels(scale.encode(image.polar), pixel_size_m=args.pixel_size)
    with run:
        write_png(out / "polar.png", polar_png)
        write_png(out / "fan.png", fan_png)
        _log(f"wrote {out / 'polar.png'} and {out / 'fan.png'} ({fan_png.shape[1]} x {fan_png.shape[0]} px) "
             f"in {time.perf_counter() - t1:.3f} s")
        title = figure_title(image, source)
        write_figure(args, out / "fan_figure", lambda: fan_figure(image, scale=scale, colormap=args.colormap,
                                                                   pixel_size_m=args.pixel_size, title=title), run)
        write_figure(args, out / "polar_figure", lambda: polar_figure(image, scale=scale, colormap=args.colormap,
                                                                       title=title), run)


def _film_of(path) -> str:
    """The film a recording holds (``polar`` for FLS frames and stored images), from its content."""
    import os.path

    from ..io.readers import FILMS, detect_format

    if not os.path.lexists(path):
        return "polar"  # (open() names the missing file, as for any recording)
    return FILMS.get(detect_format(path), "polar")


def _show_film(args, film: str, out: Path) -> None:
    """``show`` for a side-scan (its waterfall and altitude track), a multibeam (its swath and
    soundings) or an echo sounder (its echogram and bottom track): ``FILM.png`` in exact pixels
    and ``FILM_figure.png`` annotated."""
    import numpy as np

    from ..io.output import to_uint8, write_png
    from ..io.readers import open_recording
    from ..io.run_record import OutputRun
    from ..instruments.replay import ping_slice
    from ..plot.films import envelope_figure, soundings_figure, waterfall_figure
    from .figures import figure_names, write_figure

    run = OutputRun.for_folder(out, [f"{film}.png", *figure_names(args, (f"{film}_figure",))],
                               command=getattr(args, "command_line", None))
    run.protect([(args.recording, "the recording")])
    source = os.fspath(args.recording)
    with open_recording(args.recording, film) as recording:
        total, damage = recording.n_frames, recording.damage
        pings = ping_slice(total, args.pings, source)
        data = getattr(recording, film)(slice(pings.start, pings.stop))
    _log(f"read {film} pings {pings.start}:{pings.stop} of {total} from {source}")
    if damage is not None:
        _log(f"note: {source} is damaged after ping {total - 1}: its good pings are 0 to {total - 1} ({damage.detail})")
    if film == "waterfall":
        png = to_uint8(data.display(data.samples.astype(np.float64)), args.mapping or "db", args.gain_db,
                       args.dynamic_range_db)
        build = lambda: waterfall_figure(data, args.dynamic_range_db, args.gain_db)  # noqa: E731
    elif film == "soundings":
        depth = -data.level_points()[..., 2]
        png = to_uint8(np.nan_to_num(depth), "linear")
        build = lambda: soundings_figure(data)  # noqa: E731
    else:
        png = to_uint8(np.asarray(data.samples, np.float64).T, args.mapping or "db", args.gain_db, args.dynamic_range_db)
        build = lambda: envelope_figure(data, args.dynamic_range_db)  # noqa: E731
    with run:
        write_png(out / f"{film}.png", png)
        write_figure(args, out / f"{film}_figure", build, run)
        _log(f"wrote {out / f'{film}.png'} ({png.shape[1]} x {png.shape[0]} px)")


def figure_title(image, source: str) -> str:
    """The figures' title: a recording's as :func:`~sonarsim.plot.figures.describe` gives it
    (format, file, frame); a stored image named by its file, and for a dataset's frame its
    number and time, in place of the plain "sonar" of a render without a preset.

    Parameters
    ----------
    image : SonarImage
        What was read (a recording's frame or a stored image).
    source : str
        The file given on the command line.

    Returns
    -------
    str
        Two or three lines.
    """
    from ..plot.figures import describe

    lines = describe(image).split("\n")
    config = getattr(image, "config", None) or {}
    if "format" in config:  # a recording: describe names it
        return "\n".join(lines)
    name = os.path.basename(source)
    dataset = config.get("dataset")
    if isinstance(dataset, dict) and isinstance(dataset.get("frame"), int) and not isinstance(dataset["frame"], bool):
        name += f", dataset frame {dataset['frame']}"
        t = dataset.get("time_s")
        if isinstance(t, (int, float)) and not isinstance(t, bool):
            name += f" at t = {t:g} s"
    s = image.sonar
    device = f"{s.preset}, " if s.preset else ""
    lines[0] = f"{name}: {device}{lines[0].split(', ', 1)[1] if ', ' in lines[0] else lines[0]}"
    return "\n".join(lines)
