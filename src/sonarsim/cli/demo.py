"""The ``sonarsim demo`` command and its built-in scene: a water tank with a concrete floor and
objects, seen by an ARIS 3000.

Needs no files: :func:`~sonarsim.config.examples.demo_scene_dict` is a scene-file dict that
``sonarsim demo`` renders and also writes out as ``scene.yaml`` for users to edit.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..config.examples import demo_scene_dict, tank_scene_dict
from ..core.console import log as _log
from .render import (RENDER_FIGURES, RENDER_IMAGES, add_image_options, add_render_options, check_pixel_size,
                     options_named, render_and_write)

__all__ = ["add_demo_parser", "cmd_demo", "demo_scene_dict", "tank_scene_dict"]


def add_demo_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``demo`` sub-command to an ``add_subparsers()`` object; sets ``func=cmd_demo``."""
    p = subparsers.add_parser("demo", help="render the built-in water-tank scene (needs no files)",
                              description="Render the built-in water-tank scene: an ARIS 3000 1 m above a concrete floor, "
                              "tilted 20 degrees down, with a block, a drum, a pipe and a buoy. Writes scene.yaml, "
                              "polar.png, fan.png, render.npz and ground_echo.png (fan views of single, single + triple "
                              "and all bounces side by side, as in the paper's Fig. 9) into --out; then a tank with a water "
                              "surface and walls: tank.yaml and multipath.png (all paths, direct echoes, the surface's and "
                              "the walls' ghosts); then the first scene as an ARIS 3000 records it (sensor model: beam "
                              "patterns, speckle, noise, TVG, 8-bit output): scene_aris3000.yaml and aris3000.png. "
                              "Beside the exact-pixel images, annotated figures (axes in metres and degrees, colour "
                              "bar, labelled panels): fan_figure.png, polar_figure.png, ground_echo_figure.png, "
                              "multipath_figure.png and aris3000_figure.png (--figure-format, --no-figures); "
                              "last, sonarsim-run.json, the run's record.")
    p.add_argument("--out", default="sonarsim-demo", help="output folder (default: ./sonarsim-demo)")
    add_render_options(p)
    add_image_options(p)
    p.set_defaults(func=cmd_demo)
    return p


#: The exact-pixel files ``demo`` writes into --out (--components adds per-component images).
DEMO_IMAGES = ("scene.yaml", *RENDER_IMAGES, "ground_echo.png", "tank.yaml", "multipath.png", "scene_aris3000.yaml",
               "aris3000.png")
#: The annotated figures ``demo`` writes beside them (stems; one file per --figure-format).
DEMO_FIGURES = (*RENDER_FIGURES, "ground_echo_figure", "multipath_figure", "aris3000_figure")
#: Every file ``demo`` writes into --out with the default options (figures as PNG).
DEMO_FILES = (*DEMO_IMAGES, *(f"{stem}.png" for stem in DEMO_FIGURES))


def cmd_demo(args) -> None:
    from ..config.loader import scene_from_dict
    from ..io.run_record import OutputRun

    out = Path(args.out)
    # The output folder first, then the three scenes, all before the first render.
    from .figures import figure_names

    run = OutputRun.for_folder(out, [*DEMO_IMAGES, *figure_names(args, DEMO_FIGURES)],
                               command=getattr(args, "command_line", None))
    doc = demo_scene_dict()
    # The scene.yaml written must reproduce this render, command-line overrides included.
    if args.bounces is not None:
        doc["render"]["bounces"] = list(args.bounces)
    if args.max_order is not None:
        doc["render"]["max_order"] = args.max_order
        if args.bounces is None:
            doc["render"].pop("bounces", None)  # every order up to the new maximum
    if args.elevation_samples is not None:
        doc["render"]["elevation_samples"] = args.elevation_samples
    if args.seed is not None:
        doc["render"]["seed"] = args.seed
    with options_named(args):
        scene = scene_from_dict(doc)

    tank = tank_scene_dict(mirror=True)
    # The command line's render options apply to the tank too (its scene file says so).
    if args.max_order is not None:
        tank["render"]["max_order"] = args.max_order
    if args.bounces is not None:
        tank["render"]["bounces"] = list(args.bounces)
    if args.elevation_samples is not None:
        tank["render"]["elevation_samples"] = args.elevation_samples
    if args.seed is not None:
        tank["render"]["seed"] = args.seed
    with options_named(args):
        tank_scene = scene_from_dict(tank)

    # The demo scene once more, through the sensor model of an ARIS 3000 at 1.8 MHz.
    aris = {**doc, "sensor": {"preset": "aris3000-128"}}
    with options_named(args):
        aris_scene = scene_from_dict(aris)

    check_pixel_size([scene], args)  # the tank's figure keeps its own pixel size
    with run:
        _demo_files(args, out, run, (doc, scene), (tank, tank_scene), (aris, aris_scene))


def _demo_files(args, out: Path, run, demo, tank, aris) -> None:
    """Render the demo's three scenes and write their files; each scene is (document, Scene)."""
    import yaml

    from ..io.figures import bounce_comparison, multipath_comparison, sensor_comparison
    from ..io.output import atomic_write, write_png
    from ..plot.figures import ground_echo_figure, multipath_figure, sensor_figure
    from ..renderer.simulator import Simulator
    from .figures import write_figure

    # The figures take the PNGs' mapping, gain and window, and the command's colour map (the
    # demo's renders are intensities: dB unless --mapping says otherwise).
    mapping = args.mapping or "db"
    shown = {"mapping": mapping, "gain_db": args.gain_db, "dynamic_range_db": args.dynamic_range_db,
             "colormap": args.colormap}

    with atomic_write(out / "scene.yaml", "w") as f:
        yaml.safe_dump(demo[0], f, sort_keys=False)
    image = render_and_write(demo[1], out, args, run)
    write_png(out / "ground_echo.png", bounce_comparison(image, args.pixel_size, mapping, args.gain_db, args.dynamic_range_db))
    _log(f"wrote {out / 'ground_echo.png'} (fan views: single | single + triple | all bounces)")
    write_figure(args, out / "ground_echo_figure", lambda: ground_echo_figure(image, pixel_size_m=args.pixel_size, **shown),
                 run)

    with atomic_write(out / "tank.yaml", "w") as f:
        yaml.safe_dump(tank[0], f, sort_keys=False)
    with Simulator(tank[1], backend=args.backend) as sim:
        tank_image = sim.render()
    figure = multipath_comparison(tank_image, mapping=mapping, gain_db=args.gain_db,
                                  dynamic_range_db=args.dynamic_range_db)
    write_png(out / "multipath.png", figure)
    _log(f"wrote {out / 'tank.yaml'} and {out / 'multipath.png'} "
         "(fan views: all paths | direct echoes | via the water surface | via a wall | via the steel plate, a mirror)")
    write_figure(args, out / "multipath_figure", lambda: multipath_figure(tank_image, **shown), run)

    with atomic_write(out / "scene_aris3000.yaml", "w") as f:
        yaml.safe_dump(aris[0], f, sort_keys=False)
    with Simulator(aris[1], backend=args.backend) as sim:
        recorded, expected = sim.render(), sim.render(speckle=False)
    write_png(out / "aris3000.png", sensor_comparison(recorded, expected, "an ARIS 3000", 255.0, args.pixel_size,
                                                        ideal=image))
    _log(f"wrote {out / 'scene_aris3000.yaml'} and {out / 'aris3000.png'} "
         "(fan views: ideal | as an ARIS 3000 records it, 8-bit | its expected output)")
    write_figure(args, out / "aris3000_figure",
                 lambda: sensor_figure(recorded, expected, "an ARIS 3000", ideal=image, dynamic_range_db=args.dynamic_range_db,
                                       colormap=args.colormap, pixel_size_m=args.pixel_size), run)
