"""The ``sonarsim demo`` command and its built-in scene: a water tank with a concrete floor and
objects, seen by an ARIS 3000.

Needs no files: :func:`demo_scene_dict` is a scene-file dict that ``sonarsim demo`` renders and
also writes out as ``scene.yaml`` for users to edit.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..core.console import log as _log
from .render import (RENDER_FIGURES, RENDER_IMAGES, add_image_options, add_render_options, check_pixel_size,
                     options_named, render_and_write)

__all__ = ["add_demo_parser", "cmd_demo", "demo_scene_dict", "tank_scene_dict"]


def demo_scene_dict() -> dict:
    """The demo tank scene in scene-file form.

    An ARIS Explorer 3000 (preset: 128 beams, 0.7-5 m, 1288 bins) 1 m above a concrete floor, pitched
    20 degrees down; the floor is lit from about 2.2 m to 4.4 m on the centre beam. On the
    floor: a concrete block, a plastic drum standing upright and a pipe lying down; above it, a
    tethered buoy. Each casts an acoustic shadow on the floor behind it.
    """
    return {
        "sonar": {
            "preset": "aris3000-128",
            "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]},
        },
        "render": {"elevation_samples": "auto", "tvg": True, "bounces": [1, 2, 3], "method": "fast"},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "objects": [
            {
                "name": "concrete_block",
                "primitive": "box",
                "size_m": [0.5, 0.4, 0.35],
                "pose": {"position_m": [2.7, -0.45, 0.175], "rpy_deg": [0.0, 0.0, 30.0]},
                "albedo": 0.8,
            },
            {
                "name": "plastic_drum",
                "primitive": "cylinder",
                "radius_m": 0.18,
                "height_m": 0.5,
                "pose": {"position_m": [3.3, 0.45, 0.25]},
                "albedo": 0.4,
            },
            {
                "name": "pipe",
                "primitive": "cylinder",
                "radius_m": 0.06,
                "height_m": 1.2,
                "pose": {"position_m": [3.9, -0.1, 0.06], "rpy_deg": [90.0, 0.0, 70.0]},
                "albedo": 0.7,
            },
            {
                "name": "buoy",
                "primitive": "sphere",
                "radius_m": 0.15,
                "pose": {"position_m": [2.4, 0.2, 0.4]},
                "albedo": 0.6,
            },
        ],
    }


def tank_scene_dict(mirror: bool = False) -> dict:
    """A water tank with a floor, a water surface and walls, in scene-file form (the multipath demo).

    An Oculus M1200d (1.2 MHz, here 256 beams over 60 degrees, 20 degrees of elevation) 1.4 m
    above the floor of a tank 2 m deep, tilted 2 degrees down: it sees the water surface from
    about 4.3 m and the floor from about 6.6 m; the far wall is 7.2 m away, the side walls 2 m
    to either side. A buoy floats near the surface, a post stands from floor to surface, a
    block hangs in mid-water. Paths up to order 3 over all five planes.

    With ``mirror`` (the demo's tank), a steel plate (1.2 x 1.0 m, R 0.9) stands on the floor
    4.2 m ahead and 1.3 m to the left, turned to mirror the post and the block towards the
    sonar: a mesh mirror whose ghosts the multipath figure shows.
    """
    doc = _tank_planes()
    if mirror:
        doc["objects"].append({"name": "steel_plate", "primitive": "box", "size_m": [0.03, 1.2, 1.0],
                               "pose": {"position_m": [4.2, 1.3, 0.5], "rpy_deg": [0.0, 0.0, 66.6]},
                               "albedo": 0.1, "specular": 0.9})
    return doc


def _tank_planes() -> dict:
    wall = {"albedo": 0.6, "specular": 0.5}
    return {
        "sonar": {
            "preset": "oculus-m1200d-lf", "azimuth_fov_deg": 60.0, "n_beams": 256,
            "range_min_m": 0.5, "range_max_m": 8.0, "n_range_bins": 750,
            "pose": {"position_m": [0.0, 0.0, 1.4], "rpy_deg": [0.0, 2.0, 0.0]},
        },
        "render": {"max_order": 3},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": [
            {"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0, "specular": 0.9},
            {"name": "far_wall", "point_m": [7.2, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], **wall},
            {"name": "left_wall", "point_m": [0.0, 2.0, 0.0], "normal": [0.0, -1.0, 0.0], **wall},
            {"name": "right_wall", "point_m": [0.0, -2.0, 0.0], "normal": [0.0, 1.0, 0.0], **wall},
        ],
        "objects": [
            {"name": "buoy", "primitive": "sphere", "radius_m": 0.15, "pose": {"position_m": [3.0, 0.4, 1.6]},
             "albedo": 0.7},
            {"name": "post", "primitive": "cylinder", "radius_m": 0.08, "height_m": 2.0,
             "pose": {"position_m": [5.0, -0.8, 1.0]}, "albedo": 0.6},
            {"name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.5],
             "pose": {"position_m": [6.0, 0.6, 1.2], "rpy_deg": [0.0, 0.0, 30.0]}, "albedo": 0.8},
        ],
    }


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
