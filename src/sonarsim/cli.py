"""Command-line interface: a thin layer over the library.

Results go to files; progress and timing go to stderr. Bad input ends with a one-line message
naming the key or file, exit status 2, and no traceback.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from .argtypes import finite_float, positive_float
from .errors import SonarsimError

EXIT_BAD_INPUT = 2


def _log(msg: str) -> None:
    print(f"sonarsim: {msg}", file=sys.stderr, flush=True)


def _bounces(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--bounces must be a comma-separated list drawn from 1,2,3, got {text!r}") from None
    if not values or any(v not in (1, 2, 3) for v in values):
        raise argparse.ArgumentTypeError(f"--bounces must be a comma-separated list drawn from 1,2,3, got {text!r}")
    return values


def _add_image_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("images")
    g.add_argument("--pixel-size", type=positive_float, default=None, metavar="M",
                   help="fan image pixel size in metres (default: the range resolution)")
    g.add_argument("--mapping", choices=("db", "linear"), default="db",
                   help="PNG intensity mapping: dB window below the maximum, or linear (default: db)")
    g.add_argument("--gain-db", type=finite_float, default=0.0, help="display gain in dB (default: 0)")
    g.add_argument("--dynamic-range-db", type=positive_float, default=40.0,
                   help="width of the dB window shown (default: 40)")
    g.add_argument("--components", action="store_true",
                   help="also write one polar and one fan PNG per component (object, ground, single, ...)")


def _add_render_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("rendering")
    g.add_argument("--bounces", type=_bounces, default=None, metavar="LIST",
                   help="echoes to form, e.g. 1 or 1,3 or 1,2,3 (overrides render.bounces)")
    g.add_argument("--elevation-samples", type=int, default=None, metavar="N",
                   help="rays per beam across the elevation aperture (overrides render.elevation_samples)")
    g.add_argument("--backend", choices=("embree", "numpy"), default="embree",
                   help="ray-casting engine (numpy: slow reference)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sonarsim",
        description="Simulate 2D forward-looking sonar images (with ground echoes) from 3D scenes.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("render", help="render a scene file to polar.png, fan.png and render.npz",
                       description="Render a YAML/JSON scene file. Writes polar.png, fan.png and render.npz into --out.")
    p.add_argument("scene", help="scene file (YAML or JSON)")
    p.add_argument("--out", required=True, help="output folder (created if missing)")
    _add_render_options(p)
    _add_image_options(p)

    p = sub.add_parser("demo", help="render the built-in water-tank scene (needs no files)",
                       description="Render the built-in water-tank scene: an ARIS 3000 1 m above a concrete floor, "
                       "tilted 20 degrees down, with a block, a drum, a pipe and a buoy. Writes scene.yaml, "
                       "polar.png, fan.png, render.npz and ground_echo.png (fan views of single, single + triple "
                       "and all bounces side by side, as in the paper's Fig. 9) into --out.")
    p.add_argument("--out", default="sonarsim-demo", help="output folder (default: ./sonarsim-demo)")
    _add_render_options(p)
    _add_image_options(p)

    p = sub.add_parser("presets", help="list the sonar presets",
                       description="List the built-in sonar presets with their main figures.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")

    # Real data: reading recordings, comparing images, fitting the pose.
    from .compare_cli import add_compare_parser
    from .fit_cli import add_fit_parser
    from .readers.show import add_show_parser

    add_show_parser(sub)
    add_compare_parser(sub)
    add_fit_parser(sub)
    return parser


def _override_render(scene, args):
    from dataclasses import replace

    changes = {}
    if args.bounces is not None:
        changes["bounces"] = tuple(args.bounces)
    if args.elevation_samples is not None:
        changes["elevation_samples"] = args.elevation_samples
    if not changes:
        return scene
    from .config.loader import _prefixed
    from .config.scene import RenderSettings

    render = _prefixed("render", RenderSettings, **{**scene.render.__dict__, **changes})
    return replace(scene, render=render)


def _render_and_write(scene, out: Path, args) -> None:
    from .output import to_uint8, write_png
    from .render.simulator import Simulator

    t0 = time.perf_counter()
    sim = Simulator(scene, backend=args.backend)
    t1 = time.perf_counter()
    image = sim.render()
    t2 = time.perf_counter()
    s = image.sonar
    _log(f"scene built in {t1 - t0:.3f} s; rendered {s.n_range_bins} x {s.n_beams} image "
         f"({sim.ray_fan(s).n_rays} rays) in {t2 - t1:.3f} s")
    out.mkdir(parents=True, exist_ok=True)

    def write(name: str, polar, label: str) -> None:
        # The polar PNG shows far range at the top, like the fan, so both read the same way.
        write_png(out / f"polar{name}.png", to_uint8(polar[::-1], args.mapping, args.gain_db, args.dynamic_range_db))
        fan = image.fan(pixel_size_m=args.pixel_size, component=label)
        write_png(out / f"fan{name}.png",
                  to_uint8(fan.image, args.mapping, args.gain_db, args.dynamic_range_db, mask=fan.mask))

    write("", image.polar, None)
    if args.components:
        for key, comp in image.components.items():
            if key != "total":  # that is polar.png / fan.png (less any speckle)
                write(f"_{key}", comp, key)
    image.save_npz(out / "render.npz")
    _log(f"wrote {out / 'polar.png'}, {out / 'fan.png'}, {out / 'render.npz'} in {time.perf_counter() - t2:.3f} s")
    return image


def cmd_render(args) -> None:
    from .config.loader import load_scene

    scene = _override_render(load_scene(args.scene), args)
    _render_and_write(scene, Path(args.out), args)


def cmd_demo(args) -> None:
    import yaml

    from .demo import demo_scene_dict
    from .config.loader import scene_from_dict
    from .output import atomic_write

    doc = demo_scene_dict()
    # The scene.yaml written must reproduce this render, command-line overrides included.
    if args.bounces is not None:
        doc["render"]["bounces"] = list(args.bounces)
    if args.elevation_samples is not None:
        doc["render"]["elevation_samples"] = args.elevation_samples
    scene = scene_from_dict(doc)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "scene.yaml", "w") as f:
        yaml.safe_dump(doc, f, sort_keys=False)
    image = _render_and_write(scene, out, args)
    from .figures import bounce_comparison
    from .output import write_png

    write_png(out / "ground_echo.png", bounce_comparison(image, args.pixel_size, args.mapping, args.gain_db, args.dynamic_range_db))
    _log(f"wrote {out / 'ground_echo.png'} (fan views: single | single + triple | all bounces)")


def cmd_presets(args) -> None:
    import json

    from .config.presets import PRESETS

    rows = []
    for name, p in PRESETS.items():
        from .config.loader import parse_sonar

        s = parse_sonar({"preset": name}, None)
        rows.append({
            "name": name, "n_beams": s.n_beams, "azimuth_fov_deg": round(s.azimuth_fov_deg, 2),
            "elevation_fov_deg": s.elevation_fov_deg, "range_min_m": s.range_min_m, "range_max_m": s.range_max_m,
            "n_range_bins": s.n_range_bins, "frequency_khz": s.frequency_khz, "description": p.description,
        })
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    head = f"{'name':<20} {'beams':>5} {'az fov':>7} {'el fov':>6} {'range m':>11} {'bins':>5} {'kHz':>6}  description"
    print(head)
    for r in rows:
        rng = f"{r['range_min_m']:g}-{r['range_max_m']:g}"
        khz = f"{r['frequency_khz']:g}" if r["frequency_khz"] else "-"
        print(f"{r['name']:<20} {r['n_beams']:>5} {r['azimuth_fov_deg']:>7g} {r['elevation_fov_deg']:>6g} "
              f"{rng:>11} {r['n_range_bins']:>5} {khz:>6}  {r['description']}")


COMMANDS = {"render": cmd_render, "demo": cmd_demo, "presets": cmd_presets}


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sonarsim`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        handler = getattr(args, "func", None) or COMMANDS[args.command]
        handler(args)
    except SonarsimError as exc:
        _log(f"error: {exc}")
        return EXIT_BAD_INPUT
    except OSError as exc:  # e.g. an output folder that cannot be written
        # A failed rename names the temporary file first; the user wants the destination.
        name = exc.filename2 or exc.filename or ""
        _log(f"error: {name}: {exc.strerror or exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
