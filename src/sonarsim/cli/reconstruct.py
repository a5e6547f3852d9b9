"""``sonarsim reconstruct``: the sea floor's height field from images with known sonar poses.

Writes ``heights_m`` (ny, nx), ``x_m``, ``y_m``, ``seen`` (the grid's vertices some image's
paths met), ``loss`` (per round) and, with ``--reflectivity``, ``reflectivity`` (ny, nx) to
``--out`` (an NPZ), and a figure beside it: start | reconstructed | error where ``--truth``
gives the true floor (a mesh file), else start | reconstructed (and the reflectivity). Needs the differentiable engine (the ``diff`` extra: :func:`sonarsim.core.extras.install_command`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..core.extras import install_command
from ..errors import ConfigError, SonarsimError


def _floats(text: str, n: int, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected {n} numbers separated by commas, got {text!r}") from None
    if len(values) != n or not all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"{what}: expected {n} finite numbers separated by commas, got {text!r}")
    return values


def _extent(text: str) -> tuple[float, ...]:
    return _floats(text, 4, "--extent x0,x1,y0,y1")


def _resolution(text: str) -> float:
    (value,) = _floats(text, 1, "--resolution")
    if value <= 0:
        raise argparse.ArgumentTypeError(f"--resolution: must be positive, got {text!r}")
    return value


def add_reconstruct_parser(sub) -> argparse.ArgumentParser:
    """Add the ``reconstruct`` sub-command to an argparse sub-parser collection."""
    p = sub.add_parser(
        "reconstruct", help="the sea floor's height field from images with known sonar poses (needs the diff extra)",
        description="Reconstruct the sea floor's heights over --extent, on a grid of --resolution metres, from "
        "one or more images (render.npz files, which carry their sonar pose, or recordings with --poses) by "
        "gradient with the differentiable engine. Writes heights_m, x_m, y_m, seen and loss to --out (NPZ) and "
        "a figure beside it (start | reconstructed | error with --truth). Exit status 3 when the result would "
        "mean nothing: an image without echo, no view within range of the extent, or views that see fewer than "
        "4 of its vertices or 1%% of them.",
    )
    p.add_argument("images", nargs="+", help="render.npz files (their poses are read) or recordings (with --poses)")
    p.add_argument("--scene", required=True, help="the starting scene (its sonar, objects; its ground is replaced)")
    p.add_argument("--extent", required=True, type=_extent, help="x0,x1,y0,y1 of the floor to reconstruct, metres")
    p.add_argument("--resolution", required=True, type=_resolution, help="grid spacing, metres; the grid's memory and "
                   "time (with the views and the scene) are estimated and checked against --max-memory and "
                   "--max-build-time before anything is built")
    p.add_argument("--out", required=True, help="where to write the heights (NPZ)")
    p.add_argument("--poses", default=None, help="YAML or JSON list of {position_m, rpy_deg}, one per image "
                   "(default: each render.npz's own pose)")
    p.add_argument("--truth", default=None, help="a mesh file of the true floor: the figure shows the error")
    p.add_argument("--smoothness", type=float, default=1e-3, help="weight of the heights' smoothness, from 0 (the "
                   "images alone) to 1000 (a level floor) (default 1e-3)")
    p.add_argument("--reflectivity", action="store_true", help="also fit the floor's reflectivity per grid vertex "
                   "(relative to the scene ground's albedo; written as `reflectivity` and shown in the figure)")
    p.set_defaults(func=cmd_reconstruct)
    return p


def _poses(args, images) -> list:
    from ..config.loader import parse_pose, read_document

    if args.poses is None:
        missing = [path for path, img in zip(args.images, images) if getattr(img, "pose", None) is None]
        if missing:
            raise SonarsimError(f"{missing[0]}: carries no sonar pose (a recording); give --poses")
        return [img.pose for img in images]
    doc = read_document(Path(args.poses))
    if not isinstance(doc, list) or len(doc) != len(images):
        raise ConfigError("--poses", f"must list one pose per image ({len(images)}), got "
                          f"{len(doc) if isinstance(doc, list) else type(doc).__name__}")
    return [parse_pose(d, f"--poses[{k}]") for k, d in enumerate(doc)]


def truth_heights(path: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The true floor's heights at the grid's vertices: the mesh's highest surface over each."""
    from ..config.meshfiles import load_mesh_file
    from ..trace import make_caster

    mesh = load_mesh_file(path)
    caster = make_caster("embree", [mesh], None)
    gx, gy = np.meshgrid(x, y)
    top = float(np.max(mesh.vertices[:, 2])) + 1.0
    # (a hair off the grid: a ray straight through a vertex or along an edge of the truth's own
    # grid can slip between its triangles)
    origins = np.stack([gx.ravel() + 1e-5, gy.ravel() + 0.7e-5, np.full(gx.size, top)], axis=1).astype(np.float32)
    down = np.tile(np.array([0.0, 0.0, -1.0], np.float32), (gx.size, 1))
    hits = caster.intersect(origins, down, 1e4)
    z = np.where(hits.mesh_id >= 0, top - hits.distance.astype(float), np.nan)
    return z.reshape(gx.shape)


def _images(paths: list[str]) -> list:
    """The images, each refused by file where it is not finite (exit 2) or holds no echo (exit 3)."""
    from ..analysis.comparison import load_image
    from ..diff.reconstruct import ReconstructionRefused

    images = []
    for path in paths:
        img = load_image(path)
        polar = np.asarray(img.polar, float)
        bad = ~np.isfinite(polar)
        if bad.any():
            rows = np.flatnonzero(bad.any(axis=1))
            raise SonarsimError(f"{path} (frame 0): {int(bad.sum())} pixels are NaN or infinite, in {len(rows)} "
                                f"range bins from {rows[0]} to {rows[-1]}: give images of finite values")
        if not np.any(polar > 0):
            raise ReconstructionRefused(f"{path} (frame 0): holds no echo (no pixel above 0): nothing to "
                                        "reconstruct from")
        images.append(img)
    return images


def _truth(path: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``--truth`` read and laid on the grid before any reconstruction: a mesh that is missing,
    unreadable or covers none of the grid is refused by name."""
    from ..errors import MeshFileError

    try:
        z = truth_heights(path, x, y)
    except MeshFileError as exc:
        raise SonarsimError(f"--truth: {exc}") from None
    if not np.isfinite(z).any():
        raise SonarsimError(f"--truth: {path}: the mesh lies over none of the grid's vertices (--extent "
                            f"{x[0]:g},{x[-1]:g},{y[0]:g},{y[-1]:g}): give the true floor under the extent")
    return z


def cmd_reconstruct(args) -> None:
    import importlib.util

    if importlib.util.find_spec("jax") is None:
        raise SonarsimError(f"sonarsim reconstruct needs the differentiable engine (JAX): {install_command('diff')}")
    from dataclasses import replace

    from ..config.loader import load_scene
    from ..diff import enable_compilation_cache
    from ..diff.reconstruct import (ReconstructionRefused, check_smoothness, grid_axes, out_of_reach, plan_grid,
                                    reconstruct_heights)
    from ..io.output import atomic_write
    from ..io.run_record import OutputRun, record_beside

    # Everything the user gave is checked, and the cost estimated against the budgets, before
    # anything is built: a run of minutes must not end in a refusal of its options.
    smoothness = check_smoothness(args.smoothness, "--smoothness")
    scene = load_scene(args.scene)
    plan_grid(args.extent, args.resolution, len(args.images), scene, keys=("--extent", "--resolution"))
    out = Path(args.out)
    figure = out.with_name(out.stem + "_figure.png")
    run = OutputRun(record_beside(out), [(out, "--out"), (figure, "--out")], command=getattr(args, "command_line", None))
    images = _images(args.images)
    grids = {(img.polar.shape, tuple(np.round(img.range_m[[0, -1]], 9))) for img in images}
    if len(grids) != 1:
        raise SonarsimError("the images have different grids (range bins, beams): give images of one sonar")
    poses = _poses(args, images)
    if images[0].sonar is not None:
        scene = replace(scene, sonar=replace(images[0].sonar, elevation_fov_deg=scene.sonar.elevation_fov_deg))
    far = out_of_reach(scene, poses, args.extent)
    if len(far) == len(poses):
        k, distance = min(far, key=lambda f: f[1])
        raise ReconstructionRefused(
            f"no image can see --extent: the nearest, {args.images[k]}, was taken {distance:.1f} m from it, beyond "
            f"the sonar's range of {scene.sonar.range_max_m:g} m (check --poses or the images' poses, and --extent)")
    truth = _truth(args.truth, *grid_axes(args.extent, args.resolution)) if args.truth else None
    enable_compilation_cache()
    result = reconstruct_heights(scene, [img.polar for img in images], poses, args.extent, args.resolution,
                                 smoothness=smoothness, reflectivity=args.reflectivity,
                                 progress=lambda sigma, loss: print(
                                     f"sonarsim reconstruct: blur {sigma[0]:g} x {sigma[1]:g}: loss {loss:.4g}",
                                     file=sys.stderr, flush=True))
    with run:
        extra = {} if result.reflectivity is None else {"reflectivity": result.reflectivity}
        with atomic_write(out, "wb") as f:
            np.savez(f, heights_m=result.heights_m, x_m=result.x_m, y_m=result.y_m, seen=result.seen, loss=result.loss,
                     **extra)
        with atomic_write(figure, "wb") as f:
            _figure(result, truth).savefig(f, format="png", dpi=100)
    line = f"{result.seen.sum()} of {result.seen.size} grid vertices seen by {len(images)} image(s), {result.seconds:.1f} s"
    if truth is not None:
        ok = result.seen & np.isfinite(truth)
        if ok.any():
            rms = float(np.sqrt(np.mean((result.heights_m - truth)[ok] ** 2)))
            line += f"; RMS height error over the {int(ok.sum())} seen vertices under --truth {rms:.4f} m"
        else:
            line += "; no seen vertex lies under the --truth mesh: no height error to give"
    print(line)
    print(f"sonarsim: wrote {out} and {figure}", file=sys.stderr)


def _figure(result, truth):
    from ..plot.figures import reconstruction_figure

    return reconstruction_figure(result.heights_m, result.x_m, result.y_m, result.seen, truth_m=truth,
                                 reflectivity=result.reflectivity)
