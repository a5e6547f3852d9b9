"""The ``sonarsim render`` command: a scene file to polar.png, fan.png and render.npz.

Also holds what ``render`` and ``demo`` share: their options and the render-and-write step.
"""

from __future__ import annotations

import argparse
import contextlib
import time
from pathlib import Path
from typing import Any

from ..core.console import log as _log
from .argtypes import display_gain_db, display_range_db, frame_index, positive_float, ping_count_or_range

__all__ = ["RENDER_FIGURES", "RENDER_FILES", "add_image_options", "add_render_options", "add_render_parser", "cmd_render",
           "options_named", "render_and_write"]


def _bounces(text: str) -> list[int]:
    what = "a comma-separated list of path orders (1 single, 2 double, 3 triple, ... up to --max-order)"
    try:
        values = [int(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--bounces must be {what}, got {text!r}") from None
    if not values or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"--bounces must be {what}, got {text!r}")
    return values


def add_image_options(p: argparse.ArgumentParser) -> None:
    """The PNG and figure options of ``render`` and ``demo``."""
    from .figures import add_figure_options

    g = p.add_argument_group("images")
    g.add_argument("--pixel-size", type=positive_float, default=None, metavar="M",
                   help="fan image pixel size in metres (default: the range resolution)")
    g.add_argument("--mapping", choices=("db", "linear"), default=None,
                   help="PNG mapping: dB window below the maximum, or linear (default: a sensor model's output "
                   "linear in the device's counts, as a real recording shows, 0-255 for an 8-bit device; a render "
                   "without one, and every component image, in dB)")
    g.add_argument("--gain-db", type=display_gain_db, default=0.0, help="display gain in dB (default: 0)")
    g.add_argument("--dynamic-range-db", type=display_range_db, default=40.0,
                   help="width of the dB window shown (default: 40)")
    g.add_argument("--components", action="store_true",
                   help="also write one polar and one fan PNG per component (object, ground, single, double, ..., "
                   "and one per path signature such as O-ground-[objects]-ground-O)")
    add_figure_options(p)


def add_render_options(p: argparse.ArgumentParser) -> None:
    """The rendering options of ``render`` and ``demo``."""
    g = p.add_argument_group("rendering")
    g.add_argument("--bounces", type=_bounces, default=None, metavar="LIST",
                   help="path orders that make the total image, e.g. 1 or 1,3 or 1,2,3 (overrides render.bounces)")
    g.add_argument("--max-order", type=int, default=None, metavar="N",
                   help="longest path formed, in surface interactions (overrides render.max_order)")
    g.add_argument("--elevation-samples", type=int, default=None, metavar="N",
                   help="rays per beam across the elevation aperture (overrides render.elevation_samples)")
    g.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of every random draw (speckle, noise; overrides render.seed)")
    g.add_argument("--backend", choices=("embree", "embree4", "embreex", "numpy"), default="embree",
                   help="ray-casting engine: embree (Embree 4 through sonarsim's binding where it loads, else "
                   "embreex), embree4 or embreex (that one only), numpy (slow reference)")


def add_render_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``render`` sub-command to an ``add_subparsers()`` object; sets ``func=cmd_render``."""
    p = subparsers.add_parser("render", help="render a scene file to polar.png, fan.png and render.npz",
                              description="Render a YAML/JSON scene file. Writes polar.png, fan.png and render.npz into --out, "
                              "the annotated figures fan_figure.png and polar_figure.png (axes in metres and degrees, "
                              "colour bar, title; --figure-format, --no-figures), then sonarsim-run.json, the run's record (status complete, each file's sha256). "
                              "Files an earlier run listed there and this one does not write are removed.")
    p.add_argument("scene", help="scene file (YAML or JSON)")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    g = p.add_argument_group("instruments")
    g.add_argument("--instrument", default=None, metavar="NAME",
                   help="with instruments: render this one only (default: every one)")
    g.add_argument("--pings", type=ping_count_or_range, default=None, metavar="N|A:B",
                   help="with a side-scan: N pings along the vehicle's track (default: 100); with --along, the "
                   "recording's pings A to B - 1 (default: all)")
    g.add_argument("--trajectory", default=None, metavar="FILE",
                   help="with instruments: the vehicle's timestamped poses (CSV t,x,y,z,roll_deg,pitch_deg,yaw_deg or "
                   "TUM, as datasets take them); each instrument pings at its own times along it (default: "
                   "the scene's vehicle pose, running ahead at vehicle.speed_m_s)")
    g.add_argument("--along", default=None, metavar="RECORDING",
                   help="a side-scan recording (XTF): render its pings where its navigation and attitude put the "
                   "vehicle (altitude above the scene's ground), in its layout (range window, samples): a survey "
                   "replayed in simulation")
    add_render_options(p)
    g = p.add_argument_group("sensor")
    g.add_argument("--sensor", default=None, metavar="PRESET",
                   help="device model: a sensor preset (named like the sonar presets, e.g. aris3000-128; "
                   "replaces the scene's sensor section) or 'none' (the noise-free image); a preset of another "
                   "device than the scene's sonar is refused")
    g.add_argument("--force", action="store_true",
                   help="take a --sensor preset of another device than the scene's sonar (e.g. aris3000-128 on an "
                   "Oculus scene)")
    g.add_argument("--no-speckle", action="store_true",
                   help="no random draws: with a sensor section, its expected (mean) output; without, the "
                   "noise-free total even when render.speckle is on")
    g.add_argument("--frame", type=frame_index, default=None, metavar="N",
                   help="frame index: speckle and noise are drawn from (render.seed, N), as frame N of a "
                   "sequence would be (default: the first frame of the simulator's own generator; "
                   "sensor.speckle.anchor: world draws from the pose instead)")
    add_image_options(p)
    p.set_defaults(func=cmd_render)
    return p


def override_render(scene, args):
    """The scene with the command line's ``--bounces`` / ``--max-order`` / ``--elevation-samples`` applied."""
    from dataclasses import replace

    changes = {}
    if args.bounces is not None:
        changes["bounces"] = tuple(args.bounces)
    if getattr(args, "max_order", None) is not None:
        changes["max_order"] = args.max_order
        if args.bounces is None:
            changes["bounces"] = None  # every order up to the new maximum
    if args.elevation_samples is not None:
        changes["elevation_samples"] = args.elevation_samples
    if getattr(args, "seed", None) is not None:
        changes["seed"] = args.seed
    sensor = getattr(args, "sensor", None)
    if getattr(args, "force", False) and sensor in (None, "none"):
        from ..errors import ConfigError

        raise ConfigError("--force", "takes a --sensor preset of another device than the scene's sonar: give it "
                          "with --sensor PRESET")
    if not changes and sensor is None:
        return scene
    from ..config.loader import _prefixed
    from ..config.scene import RenderSettings
    from ..config.sensor import parse_sensor, preset_device_mismatch
    from ..errors import ConfigError

    with options_named(args):
        render = _prefixed("render", RenderSettings, **{**scene.render.__dict__, **changes})
        if sensor is None:
            return replace(scene, render=render)
        if sensor == "none":
            return replace(scene, render=render, sensor=None)
        spec = parse_sensor({"preset": sensor})
    # A device's preset on another device's scene renders without complaint and means nothing.
    mismatch = preset_device_mismatch(sensor, scene.sonar)
    if mismatch is not None and not getattr(args, "force", False):
        raise ConfigError("--sensor", f"{mismatch}, or --force to take it anyway")
    return replace(scene, render=render, sensor=spec)


# Scene keys that a command-line option can set: an error in their value names the option.
OPTION_OF_KEY = {"render.bounces": "--bounces", "render.max_order": "--max-order", "render.seed": "--seed",
                 "render.elevation_samples": "--elevation-samples", "sensor.preset": "--sensor",
                 "pixel_size_m": "--pixel-size"}


@contextlib.contextmanager
def options_named(args):
    """Re-raise a ConfigError about a key that a given command-line option set, naming the option."""
    from ..errors import ConfigError

    try:
        yield
    except ConfigError as exc:
        option = OPTION_OF_KEY.get(exc.key)
        if option is None or getattr(args, option[2:].replace("-", "_"), None) is None:
            raise
        raise ConfigError(option, exc.detail) from None


def check_pixel_size(scenes, args) -> None:
    """Refuse ``--pixel-size`` for the scenes' fans (too long, or beyond the memory budget)
    before anything is rendered or written, naming the option."""
    from ..image.fan import check_fan_size

    if getattr(args, "pixel_size", None) is None:
        return
    with options_named(args):
        for scene in scenes:
            check_fan_size(scene.sonar.grid, args.pixel_size)


#: The exact-pixel files ``render`` writes into --out (and ``demo`` among others); --components adds more.
RENDER_IMAGES = ("polar.png", "fan.png", "render.npz")
#: The annotated figures ``render`` writes beside them (stems; one file per --figure-format).
RENDER_FIGURES = ("fan_figure", "polar_figure")
#: Every file ``render`` writes into --out with the default options (figures as PNG).
RENDER_FILES = (*RENDER_IMAGES, *(f"{stem}.png" for stem in RENDER_FIGURES))


def render_files(args) -> list[str]:
    """The files ``render`` writes into --out with these options (--components adds more)."""
    from .figures import figure_names

    return [*RENDER_IMAGES, *figure_names(args, RENDER_FIGURES)]


def render_and_write(scene, out: Path, args, run=None):
    """Render ``scene`` once and write polar.png, fan.png and render.npz into ``out``.

    ``run`` (an entered :class:`~sonarsim.io.run_record.OutputRun`) learns the names of the
    per-component images before they are written.
    """
    from ..image.levels import default_levels
    from ..io.output import to_uint8, write_png
    from ..renderer.simulator import Simulator

    t0 = time.perf_counter()
    sim = Simulator(scene, backend=args.backend)
    t1 = time.perf_counter()
    # ``demo`` has neither option: its render draws as configured.
    image = sim.render(speckle=False if getattr(args, "no_speckle", False) else None,
                       frame=getattr(args, "frame", None))
    t2 = time.perf_counter()
    s = image.sonar
    _log(f"scene built in {t1 - t0:.3f} s; rendered {s.n_range_bins} x {s.n_beams} image "
         f"({sim.ray_fan(s).n_rays} rays) in {t2 - t1:.3f} s")
    # The path-signature images (render.npz holds them) are formed, and checked against the
    # budget, before anything is written: a refusal must leave no PNG behind.
    image.components.signatures
    out.mkdir(parents=True, exist_ok=True)

    def write(name: str, polar, label: str) -> None:
        # The device's output (the total, with a sensor model) in its counts, as a recording
        # is drawn; every component is echo intensity, in dB (image.levels explains why).
        def levels(values, mask=None):
            if label is None:
                return default_levels(image, values, mask, args.mapping, args.gain_db, args.dynamic_range_db)
            return to_uint8(values, args.mapping or "db", args.gain_db, args.dynamic_range_db, mask=mask)

        # The polar PNG shows far range at the top, like the fan, so both read the same way.
        polar_png = levels(polar[::-1])
        # The fan's levels are made on the polar grid and resampled (image.fan_levels), as every
        # fan sonarsim draws: a dataset's, a bag's, a live topic's.
        fan_png = image.fan_levels(levels(polar), pixel_size_m=args.pixel_size)
        # Both images are made before either is written: a failure leaves neither.
        for kind, png in (("polar", polar_png), ("fan", fan_png)):
            path = out / f"{kind}{name}.png"
            if run is not None:
                run.add(path)
            write_png(path, png)

    write("", image.polar, None)
    if args.components:
        for key, comp in image.components.items():
            if key != "total":  # that is polar.png / fan.png (less any speckle)
                write(f"_{key}", comp, key)
    image.save_npz(out / "render.npz")
    _log(f"wrote {out / 'polar.png'}, {out / 'fan.png'}, {out / 'render.npz'} in {time.perf_counter() - t2:.3f} s")
    write_render_figures(image, out, args, run)
    return image


def write_render_figures(image, out: Path, args, run=None) -> None:
    """The annotated fan and polar figures of a render (device output in its counts, a render's
    intensity in dB with the command's gain and window)."""
    from ..plot.figures import default_scale, fan_figure, polar_figure
    from .figures import write_figure

    # As the PNGs: a device's output in its counts, a render's intensity in dB (or --mapping).
    scale = default_scale(image, args.mapping, args.gain_db, args.dynamic_range_db)
    colormap = getattr(args, "colormap", "inferno")
    frame = getattr(args, "frame", None)
    write_figure(args, out / "fan_figure", lambda: fan_figure(image, scale=scale, colormap=colormap, frame=frame,
                                                               pixel_size_m=args.pixel_size), run)
    write_figure(args, out / "polar_figure", lambda: polar_figure(image, scale=scale, colormap=colormap,
                                                                   frame=frame), run)


def cmd_render(args) -> None:
    from ..config.loader import load_scene
    from ..io.run_record import OutputRun
    from ..scene.cost import check_scene_cost

    out = Path(args.out)
    # Checked before the scene is even read: a render must not be lost to an unwritable --out.
    run = OutputRun.for_folder(out, render_files(args), command=getattr(args, "command_line", None))
    scene = override_render(load_scene(args.scene), args)
    check_pixel_size([scene], args)
    check_scene_cost(scene)  # (the simulator checks it too; here before the folder is made)
    if scene.instruments:
        from .instruments import instrument_files, render_instruments

        run = OutputRun.for_folder(out, instrument_files(scene, args, render_files(args)),
                                   command=getattr(args, "command_line", None))
        with run:
            render_instruments(scene, out, args, run, render_fls=render_and_write)
        return
    with run:
        render_and_write(scene, out, args, run)
