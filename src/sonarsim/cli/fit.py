"""``sonarsim fit``: find the sonar pose that makes a scene look like a real recording.

Writes the scene with the fitted pose and the recording's geometry (the user's own scene
document with its ``sonar`` section replaced by the recording's beams, range window and bins,
the scene's elevation aperture, and the fitted pose; as ``sonarsim calibrate`` does) and a
side-by-side picture: the real image with the fitted floor-band edges drawn
on it, and the render at the fitted pose. A fit that :func:`~sonarsim.analysis.fitting.fit_problems`
finds meaningless writes nothing and ends with exit status 3.
"""

from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .argtypes import frame_index, integer_at_least
from ..core.console import log as _log
from ..core.extras import install_command
from ..errors import SonarsimError

if TYPE_CHECKING:
    from ..analysis.fitting import FitProgress, FitResult

# Exit status of a fit that ran but found no meaningful pose (bad input is 2, as everywhere).
EXIT_NO_FIT = 3
# Least time between two progress reports on stderr.
PROGRESS_INTERVAL_S = 1.0

EXIT_CODES = """exit status:
  0  fitted: the scene with the fitted pose and the picture are written
  2  bad input: an unreadable recording or scene, an unknown parameter, a recording
     whose range window or fan the scene's sonar does not cover
  3  the fit found no meaningful pose (nothing written): the recording holds no echo
     (a silent, saturated or noise-only frame), nothing echoes at the fitted
     pose, the render's echo does not line up with the recording's, the band edges
     differ by more than a tenth of the range window, the search ended worse than it
     started (or used its budget without finding anything better), a free parameter
     ran away, or a free parameter does not change the render (x, y, yaw over a flat
     floor); the message says which, and what to try"""


def _render_budget(text: str) -> int:
    """A number of renders >= 1."""
    return integer_at_least(text, 1, "number of renders")


def add_fit_parser(sub) -> argparse.ArgumentParser:
    """Add the ``fit`` sub-command to an argparse sub-parser collection."""
    p = sub.add_parser(
        "fit", help="fit the sonar pose of a scene to a real recording",
        description="Find the sonar pose parameters (--free) that make the rendered scene match a real "
        "image, starting from the scene's pose. Writes the scene with the fitted pose and the recording's "
        "beams, range window and bins (so that it renders on the recording's grid) to --out and a "
        "side-by-side picture (real | fitted) next to it. Progress goes to stderr (--quiet: none).",
        epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("real", help="real recording (.aris, Oculus .raw) or a sonarsim render.npz")
    p.add_argument("--scene", required=True, help="scene file (YAML or JSON); its sonar pose is the start")
    p.add_argument("--free", default="z,pitch", help="pose parameters to fit, from x,y,z,roll,pitch,yaw (default: z,pitch)")
    p.add_argument("--out", required=True, help="where to write the fitted scene (YAML)")
    p.add_argument("--frame", type=frame_index, default=0, help="frame of the recording (default: 0)")
    p.add_argument("--domain", choices=("auto", "edges", "band"), default="auto",
                   help="compare edge maps of whole images (edges), or the near and far edges of the floor band "
                   "(band); auto (default): band for a scene whose echo is one floor band, edges otherwise "
                   "(the choice and its reason go to stderr)")
    p.add_argument("--method", choices=("auto", "search", "gradient"), default="auto",
                   help="auto (default): gradient where JAX is installed and --domain is auto, search otherwise "
                   "(said on stderr); search: a simplex search on edges or the floor band (--domain, --max-renders); "
                   "gradient: Levenberg-Marquardt on the floor band's edges or on blurred images with the differentiable "
                   "engine's gradients, coarse to fine (needs the diff extra; --domain and --max-renders "
                   "do not apply)")
    p.add_argument("--max-renders", type=_render_budget, default=600, help="render budget of the search (default: 600)")
    p.add_argument("--quiet", action="store_true", help="no progress or notes on stderr (errors still)")
    p.add_argument("--image", default=None, help="side-by-side PNG (default: next to --out, *_fit.png); the "
                   "annotated figure goes beside it as *_fit_figure.png")
    from .figures import add_figure_options

    add_figure_options(p)
    p.set_defaults(func=cmd_fit)
    return p


def free_parameters(text: str, allow_none: bool) -> tuple[str, ...]:
    """``--free`` parsed; an error names the option (the library's key is ``free``)."""
    from ..analysis.fitting import parse_free
    from ..errors import ConfigError

    try:
        return parse_free(text, allow_none=allow_none)
    except ConfigError as exc:
        raise ConfigError("--free", exc.detail) from None


def _load_real(path: str, frame: int):
    from ..analysis.comparison import load_image

    image = load_image(path, frame=frame)
    if getattr(image, "sonar", None) is None:
        raise SonarsimError(f"{path}: has no sonar geometry (range and beam axes); give a recording or an NPZ")
    return image


def _fitted_document(scene_path: Path, out_path: Path, pose) -> dict:
    """The user's scene document with the fitted pose; relative paths still resolve from out."""
    from ..config.loader import read_document

    doc = copy.deepcopy(read_document(scene_path))
    sonar = doc.setdefault("sonar", {})
    sonar["pose"] = pose.to_dict()
    base, new_base = scene_path.resolve().parent, out_path.resolve().parent
    if base != new_base:
        for obj in doc.get("objects") or []:
            if isinstance(obj, dict) and isinstance(obj.get("mesh"), str) and not Path(obj["mesh"]).is_absolute():
                obj["mesh"] = str(base / obj["mesh"])
        if isinstance(sonar.get("beam_angles_file"), str) and not Path(sonar["beam_angles_file"]).is_absolute():
            sonar["beam_angles_file"] = str(base / sonar["beam_angles_file"])
    return doc


def recording_document(scene_path: Path, out_path: Path, scene) -> dict:
    """The user's scene document with ``scene``'s sonar: its intrinsics and pose.

    ``scene`` is a fit's or a calibration's result, whose intrinsics are the recording's
    (:func:`~sonarsim.analysis.fitting.recording_geometry`): the document then renders on the
    recording's grid, so that ``compare`` sets render and recording side by side without
    resampling. The sonar section is written out in full (beam table, range window, bins,
    elevation aperture, frequency) and without ``preset``, whose beams and window were not the
    recording's; the rest of the document is the user's (objects, planes, render settings).

    Parameters
    ----------
    scene_path : Path
        The user's scene file.
    out_path : Path
        Where the document goes (relative mesh and table paths are made to resolve from there).
    scene : Scene
        The fitted scene.

    Returns
    -------
    dict
    """
    doc = _fitted_document(scene_path, out_path, scene.sonar_pose)
    sonar = scene.sonar.to_dict()
    sonar.pop("pose", None)
    sonar.pop("preset", None)
    new = {k: v for k, v in sonar.items() if v is not None}
    new["pose"] = doc["sonar"]["pose"]
    doc["sonar"] = new
    return doc


def side_by_side(real, fitted, gap_px: int = 8) -> np.ndarray:
    """RGB picture: the real fan with the fitted band edges (red: near, yellow: far) | the
    fitted render's fan.

    Returns
    -------
    (H, 2 W + gap_px, 3) uint8 ndarray
    """
    from ..analysis.fitting import floor_band_m
    from ..io.output import to_uint8

    pixel = max(real.sonar.range_resolution_m, real.sonar.range_max_m / 1000.0)
    fan_r, fan_s = real.fan(pixel_size_m=pixel), fitted.fan(pixel_size_m=pixel)
    left = np.repeat(to_uint8(fan_r.image, "linear", 0.0, mask=fan_r.mask)[..., None], 3, axis=2)
    right = np.repeat(to_uint8(fan_s.image, "db", 0.0, 40.0, mask=fan_s.mask)[..., None], 3, axis=2)
    onset, end = floor_band_m(fitted)
    az = np.radians(fitted.azimuth_deg)
    for ranges, colour in ((onset, (255, 0, 0)), (end, (255, 220, 0))):
        ok = np.isfinite(ranges)
        x = ranges[ok] * np.cos(az[ok])  # forward
        y = ranges[ok] * np.sin(az[ok])  # left
        rows = np.round((fan_r.x_m[0] - x) / pixel).astype(int)
        cols = np.round((fan_r.y_m[0] - y) / pixel).astype(int)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = rows + dr, cols + dc
                inside = (rr >= 0) & (rr < left.shape[0]) & (cc >= 0) & (cc < left.shape[1])
                left[rr[inside], cc[inside]] = colour
    h = max(left.shape[0], right.shape[0])

    def pad(a):
        return np.pad(a, ((0, h - a.shape[0]), (0, 0), (0, 0)))

    gap = np.full((h, gap_px, 3), 255, dtype=np.uint8)
    return np.concatenate([pad(left), gap, pad(right)], axis=1)


class _Progress:
    """Progress of the search on stderr, at most once per :data:`PROGRESS_INTERVAL_S`: a status
    line rewritten in place (``\r``) on a terminal, whole lines elsewhere (logs)."""

    def __init__(self, stream=None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.last = float("-inf")
        self.pending = False

    @staticmethod
    def line(p: FitProgress) -> str:
        what = "band-edge RMS" if p.stage == "band" else "1 - edge correlation"
        unit = " m" if p.stage == "band" else ""
        return (f"sonarsim: fit ({p.stage}): {p.renders}/{p.budget} renders, best {what} {p.best_cost:.4g}{unit}, "
                f"{p.elapsed_s:.1f} s")

    def __call__(self, p: FitProgress) -> None:
        now = time.monotonic()
        if now - self.last < PROGRESS_INTERVAL_S:
            return
        self.last = now
        if self.tty:
            self.stream.write("\r" + self.line(p) + "\033[K")
            self.pending = True
        else:
            self.stream.write(self.line(p) + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the status line (terminal) so that what follows starts on its own."""
        if self.pending:
            self.stream.write("\n")
            self.stream.flush()
            self.pending = False


def _what_to_try(args: argparse.Namespace, result: FitResult) -> str:
    if result.domain == "image":
        return (f"try a starting pose nearer the recording's (sonar.pose in {args.scene}), fewer --free parameters, "
                "or --method search")
    other = "band" if result.domain == "edges" else "edges"
    budget = "" if result.converged else f"a larger --max-renders (the search used all {args.max_renders}), "
    return (f"try a starting pose nearer the recording's (sonar.pose in {args.scene}), {budget}fewer --free "
            f"parameters, or --domain {other}")


def jax_available() -> bool:
    """Whether the differentiable engine can be imported (JAX installed)."""
    import importlib.util

    return importlib.util.find_spec("jax") is not None


def resolve_method(asked: str, note=None) -> str:
    """``--method`` of ``fit`` and ``calibrate``: ``auto`` is ``gradient`` where JAX is
    installed and ``search`` otherwise (``note`` receives a line saying which); ``gradient``
    without JAX is refused by name, before any work.

    Parameters
    ----------
    asked : {'auto', 'search', 'gradient'}
    note : callable, optional
        Receives one line when ``auto`` chose.

    Returns
    -------
    {'search', 'gradient'}
    """
    if asked == "auto":
        method = "gradient" if jax_available() else "search"
        if note is not None:
            why = ("JAX is installed" if method == "gradient"
                   else f"JAX is not installed; {install_command('diff')} for the gradient method")
            note(f"method {method} (--method auto: {why})")
        return method
    if asked == "gradient" and not jax_available():
        raise SonarsimError(f"--method gradient: the differentiable engine needs JAX: {install_command('diff')}")
    return asked


def cmd_fit(args) -> None:
    import yaml

    from ..analysis.fitting import MIN_BAND_BEAMS, UNITS, FitError, band_view, fit_pose, floor_band_m
    from ..config.loader import load_scene
    from ..io.output import atomic_write, write_png
    from ..io.run_record import OutputRun, record_beside

    from ..plot.figures import fit_figure
    from .figures import figure_paths, write_figure

    out = Path(args.out)
    image_path = Path(args.image) if args.image else out.with_name(out.stem + "_fit.png")
    figure_stem = image_path.with_name(image_path.stem + "_figure")
    figures = [(p, "--image") for p in figure_paths(args, figure_stem)]
    # Every output checked before the search, which can take minutes (sonarsim.io.run_record).
    run = OutputRun(record_beside(out), [(out, "--out"), (image_path, "--image"), *figures],
                    command=getattr(args, "command_line", None)).protect([(args.real, "the recording")])
    free_parameters(args.free, allow_none=False)  # before the recording is read
    real = _load_real(args.real, args.frame)
    scene = load_scene(args.scene)
    quiet = getattr(args, "quiet", False)
    progress = None if quiet else _Progress()
    # (which method auto chose is said with the result: a refusal stays one line)
    asked = getattr(args, "method", "auto")
    # --domain chooses among the search's domains; the gradient chooses its own (band or images).
    method = "search" if asked == "auto" and getattr(args, "domain", "auto") != "auto" else resolve_method(asked)
    try:
        if method == "gradient":
            from ..diff.inverse import fit_recording

            def levels(k, level, loss):
                if not quiet:
                    _log(f"fit (gradient): start {k + 1}, level {level + 1}: loss {loss:.4g}")

            result = fit_recording(real, scene, free=free_parameters(args.free, allow_none=False), progress=levels)
        else:
            result = fit_pose(real, scene, free=args.free, domain=args.domain, max_renders=args.max_renders,
                              progress=progress)
    except FitError as exc:  # it ran, and found nothing: not bad input
        _log(f"error: {args.real}: {exc}")
        raise SystemExit(EXIT_NO_FIT) from None
    finally:
        if progress is not None:  # end a status line before anything else is written
            progress.close()
    if progress is not None:
        _log(f"fit: method {method}; {result.renders} {'searches' if result.domain == 'image' else 'renders'}; "
             f"domain {result.domain}: "
             f"{result.domain_reason}")
        if not result.converged:
            _log(f"note: the search stopped at the render budget (--max-renders {args.max_renders}) before "
                 "converging; a larger budget may improve the fit")
    onset_r, end_r = floor_band_m(real)
    onset_s, end_s = floor_band_m(result.image)
    end_rms = float(np.sqrt(np.nanmean((end_s - end_r) ** 2))) if np.isfinite(end_s - end_r).any() else float("nan")
    for name in result.free:
        print(f"{name:6s} {result.start[name]:10.4f} -> {result.values[name]:10.4f} {UNITS[name]}")
    what = {"edges": "1 - edge correlation", "band": "band-edge RMS, m", "image": "blurred-image loss"}[result.domain]
    print(f"cost ({what}): {result.cost_start:.4g} -> {result.cost:.4g} in {result.renders} "
          f"{'searches' if result.domain == 'image' else 'renders'}")
    if not (np.isfinite(onset_r).any() or np.isfinite(end_r).any()):
        if np.mean(band_view(real).lit_start) >= MIN_BAND_BEAMS:
            # A sea bed lit across the whole window (grazing angle): no edge to compare.
            print(f"floor band: the recording shows no band edge over its {len(onset_r)} beams (lit from "
                  f"{real.sonar.range_min_m:.2f} m, fading with range); the fit bounds height and tilt (near edge before "
                  f"the window, far edge beyond it), it does not fix them")
        else:  # not a grazing sea bed: no band at all, or a window too short to tell one
            print(f"floor band: the recording shows no clear band edge in any of its {len(onset_r)} beams and is "
                  f"not lit from its first range bin: no band to compare")
    else:
        print(f"floor band residual over {len(onset_r)} beams: near edge RMS {result.onset_rms_m:.4f} m, far edge RMS {end_rms:.4f} m")
    if result.problems:
        # Free parameters no recording determines: the advice is to hold them, said in the clause.
        only_loose = all("out of --free" in p for p in result.problems)
        _log(f"error: {args.real}: the fit found no meaningful pose: {'; '.join(result.problems)}; nothing written"
             + ("" if only_loose else "; " + _what_to_try(args, result)))
        raise SystemExit(EXIT_NO_FIT)
    # The recording's beams and range window, as calibrate writes them: the scene renders on
    # the recording's grid (the preset's 512 beams against a 256-beam recording did not).
    doc = recording_document(Path(args.scene), out, result.scene)
    with run:
        with atomic_write(out, "w") as f:
            yaml.safe_dump(doc, f, sort_keys=False)
        write_png(image_path, side_by_side(real, result.image))
        # Planned above under --image; write_figure reports it on stderr.
        write_figure(args, figure_stem, lambda: fit_figure(real, result.image, colormap=args.colormap,
                                                           frame=args.frame, band=(onset_s, end_s)))
    if not quiet:
        print(f"sonarsim: wrote {out} and {image_path}", file=sys.stderr)
