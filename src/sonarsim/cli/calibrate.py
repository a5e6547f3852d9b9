"""``sonarsim calibrate``: fit the sensor model (and pose parameters) to a real recording.

Writes a scene that ``sonarsim render`` turns into frames in the recording's units (the
user's scene document with the recording's grid, the calibrated ``sensor`` section and pose),
prints the realism figures of the calibrated frame (and of held-out frames) and writes a
side-by-side picture: real | expected render | speckled render.
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np

from .argtypes import frame_index, ping_count_or_range
from ..errors import ConfigError, SonarsimError


def frame_list(text: str) -> tuple[int, ...]:
    """``"1,2"`` -> frame numbers >= 0."""
    out = []
    for t in text.split(","):
        t = t.strip()
        if t:
            out.append(frame_index(t))
    if not out:
        raise argparse.ArgumentTypeError(f"expected frame numbers separated by commas, got {text!r}")
    return tuple(out)


def add_calibrate_parser(sub) -> argparse.ArgumentParser:
    """Add the ``calibrate`` sub-command to an argparse sub-parser collection."""
    p = sub.add_parser(
        "calibrate", help="fit the sensor model (and pose parameters) to a real recording",
        description="Fit the sensor parameters (gain, TVG law, noise before and after the TVG, bang, "
        "elevation width, gamma, azimuth width) and the pose parameters named by --free so that the "
        "scene's expected render matches a frame of a recording. Writes the calibrated scene to --out "
        "(it renders frames in the recording's units), prints the realism figures, and writes a "
        "side-by-side picture (real | expected | speckled) next to it.",
    )
    p.add_argument("real", help="real recording (.aris, Oculus .raw) or a sonarsim render.npz")
    p.add_argument("--scene", required=True, help="scene file (YAML or JSON); its pose (and sensor, if any) is the start")
    p.add_argument("--out", required=True, help="where to write the calibrated scene (YAML)")
    p.add_argument("--frame", type=frame_index, default=0, help="frame of the recording to calibrate on (default: 0)")
    p.add_argument("--free", default="", help="pose parameters to fit as well, from x,y,z,roll,pitch,yaw (default: none)")
    p.add_argument("--evaluate-frames", type=frame_list, default=(), metavar="N,M",
                   help="held-out frames of the recording to report the figures for")
    p.add_argument("--max-iterations", type=int, default=None,
                   help="search: budget of each simplex search (default: 400); gradient: Levenberg-Marquardt steps "
                   "per blur level (default: 10)")
    p.add_argument("--method", choices=("auto", "search", "gradient"), default="auto",
                   help="auto (default): gradient where JAX is installed, search otherwise (said on stderr); "
                   "search: simplex searches over the sensor's laws, starts and pose family, with the "
                   "channels, common noise, texture and range law; gradient: Levenberg-Marquardt with the "
                   "differentiable engine (gain, TVG law, noise before and after the TVG, elevation width, gamma and "
                   "the free pose, from the floor band's closed-form start; needs the diff extra). "
                   "Both refuse (exit 3, nothing written) the same frames: no echo, pose parameters the frame "
                   "does not identify, a model no better than the frame's mean level")
    p.add_argument("--image", default=None, help="side-by-side PNG (default: --out with .png for .yaml); the "
                   "annotated figure goes beside it as *_figure.png")
    p.add_argument("--json", default=None, help="also write the figures as JSON to this file")
    g = p.add_argument_group("side-scan, multibeam and echo-sounder recordings (XTF, R2Sonic in XTF, Imagenex 852)")
    g.add_argument("--pings", type=ping_count_or_range, default=None, metavar="A:B",
                   help="the pings to fit on (default: the first half of the pings with navigation); the vehicle is "
                   "where each ping's navigation and attitude put it")
    g.add_argument("--evaluate-pings", type=ping_count_or_range, default=None, metavar="C:D",
                   help="the pings to score the fit on (default: the pings after --pings, else before)")
    from .figures import add_figure_options

    add_figure_options(p)
    p.set_defaults(func=cmd_calibrate)
    return p


def calibrated_document(scene_path: Path, out_path: Path, scene) -> dict:
    """The user's scene document with the recording's grid, the calibrated sensor and pose."""
    from .fit import recording_document

    doc = recording_document(scene_path, out_path, scene)  # the grid and pose, as fit writes them
    doc["sensor"] = scene.sensor.to_dict()
    render = doc.setdefault("render", {})
    if isinstance(render, dict):
        render["speckle"] = False  # speckle is the sensor's
    return copy.deepcopy(doc)


def side_by_side(real, expected, speckled, peak: float, frame: int = 0) -> np.ndarray:
    """Titled picture: the real fan | the expected render's | the speckled render's, in the
    recording's units on one scale (0..peak -> black..white).

    Returns
    -------
    (H, 3 W + 2 gaps) uint8 ndarray
    """
    from ..io.figures import device_tile, labelled_row

    pixel = max(real.sonar.range_resolution_m, real.sonar.range_max_m / 1000.0)
    tiles = [device_tile(img.polar, img, peak, pixel) for img in (real, expected, speckled)]
    return labelled_row(tiles, [f"real (frame {frame})", "calibrated model: expected (no speckle)",
                                "calibrated model: speckled frame"])


def format_value(name: str, value) -> str:
    """One line of the calibrated values: a number, or a per-beam table summarised (the
    channels' gains: their count, RMS and range)."""
    if np.ndim(value) == 0:
        return f"{name:20s} {float(value):10.4f}"
    v = np.asarray(value, dtype=float)
    if v.size == 0:
        return f"{name:20s} (none)"
    return (f"{name:20s} {v.size} values, RMS {float(np.sqrt(np.mean(v ** 2))):.4f}, "
            f"from {float(v.min()):.4f} to {float(v.max()):.4f}")


def format_family(family: dict, method: str = "search", free: tuple = ()) -> str:
    """One line on the poses a flat floor cannot tell apart (or why none was scanned)."""
    if not family:
        if method == "gradient" and {"z", "pitch"} <= set(free):
            return ("pose family: not scanned by the gradient method (--method search scans it); one flat floor does "
                    "not tell height, pitch and elevation width apart, so the pose above is the fit from the floor "
                    "band's closed-form start with its edges at +-5 deg (the middle of the search's scan), one of "
                    "the equally good poses, not a measurement")
        return "pose family: not scanned (needs z and pitch free and a floor band with both edges)"
    parts = [f"{k} {lo:.3g}-{hi:.3g}" for k, (lo, hi) in
             ((k, family[k]) for k in ("z", "pitch", "roll", "elevation_width_deg") if k in family)]
    tail = " (and beyond: the scan's widest or narrowest width is one of them)" if family.get("open_ended") else ""
    chosen = family.get("chosen") or {}
    which = ("the pose above is the family's middle" + (f" (elevation width {chosen['elevation_width_deg']:.3g} deg)"
                                                        if "elevation_width_deg" in chosen else ""))
    return (f"pose family: equally good within {family['within_db']:g} dB: " + ", ".join(parts) + tail +
            f"; one flat floor does not tell these apart: {which}, not a measurement")


def cmd_calibrate(args) -> None:
    import json

    from .show import _film_of

    film = _film_of(args.real)
    if film == "waterfall":
        return calibrate_sidescan(args)
    if film in ("soundings", "envelope"):
        return calibrate_survey(args, film)

    import yaml

    from ..analysis.calibration import CalibrationFailed, calibrate, evaluate, format_evaluation
    from ..analysis.comparison import load_image
    from ..config.loader import load_scene
    from ..io.output import atomic_write, write_png
    from ..io.run_record import OutputRun, record_beside
    from ..renderer.simulator import Simulator
    from .fit import _load_real, free_parameters, resolve_method

    if args.max_iterations is not None and args.max_iterations < 1:
        raise ConfigError("--max-iterations", f"must be at least 1, got {args.max_iterations}")
    from ..plot.figures import calibration_figure
    from .figures import figure_paths, write_figure

    out = Path(args.out)
    image_path = Path(args.image) if args.image else out.with_suffix(".png")
    figure_stem = image_path.with_name(image_path.stem + "_figure")
    outputs = [(out, "--out"), (image_path, "--image"), *((p, "--image") for p in figure_paths(args, figure_stem))]
    if args.json:
        outputs.append((Path(args.json), "--json"))
    # Every output checked before the calibration, which can take minutes (sonarsim.io.run_record).
    run = OutputRun(record_beside(out), outputs, command=getattr(args, "command_line", None))
    run.protect([(args.real, "the recording")])
    free = free_parameters(args.free, allow_none=True)
    real = _load_real(args.real, args.frame)
    held_out = []
    for n in args.evaluate_frames:
        try:
            held_out.append((n, load_image(args.real, frame=n)))
        except (SonarsimError, IndexError, ValueError) as exc:
            raise SonarsimError(f"--evaluate-frames: {args.real}: no frame {n} ({exc})") from None
    scene = load_scene(args.scene)
    # (which method auto chose is said with the result: a refusal stays one line)
    method = resolve_method(getattr(args, "method", "auto"))
    try:
        if method == "gradient":
            from ..diff import enable_compilation_cache
            from ..diff.inverse import calibrate_recording

            enable_compilation_cache()
            res = calibrate_recording(real, scene, free=free, iterations=args.max_iterations or 10,
                                      progress=lambda k, level, loss: print(
                f"sonarsim calibrate: gradient, start {k + 1}, level {level + 1}: loss {loss:.4g}", file=sys.stderr,
                flush=True))
        else:
            # Progress on stderr: a calibration makes thousands of renders over a minute or more.
            res = calibrate(real, scene, free=free, max_iterations=args.max_iterations or 400,
                            progress=lambda line: print(f"sonarsim calibrate: {line}", file=sys.stderr, flush=True))
    except CalibrationFailed as exc:  # the recording named first (exit status 3)
        raise CalibrationFailed(exc.reasons, exc.result, source=str(args.real)) from None
    peak = res.scene.sensor.output.full_scale
    with Simulator(res.scene) as sim:
        speckled = sim.render(res.scene.sonar_pose, keep_rays=False)
    doc = calibrated_document(Path(args.scene), out, res.scene)

    # Beside the scores: the trivial images of the calibration frame and the ceiling, the range
    # bands, the beam profile and the C2ST, on the held-out frames (on the calibration frame
    # itself, said to be optimistic, without any).
    from ..analysis.bands import realism_report

    frames = [np.asarray(real.polar, dtype=float)] + [np.asarray(img.polar, dtype=float) for _, img in held_out
                                                      if np.asarray(img.polar).shape == res.expected.polar.shape]
    report = realism_report(frames, res.expected.polar, speckled.polar, 0, range_m=res.expected.range_m,
                            data_range=peak, frame_numbers=[args.frame] + [n for n, _ in held_out][:len(frames) - 1])
    if report.get("warning"):
        res.warnings.append(report["warning"])
    figures = {"frame": args.frame, "values": res.values, "law": res.law, "baselines_db": res.baselines,
               "family": res.family, "starts": res.starts, "warnings": res.warnings,
               "realism": None,
               "calibrated": evaluate(real.polar, res.expected.polar, speckled.polar, peak), "held_out": {}}
    for n, img in held_out:
        if np.asarray(img.polar).shape != res.expected.polar.shape:
            raise SonarsimError(f"--evaluate-frames: frame {n} of {args.real} has another grid than frame {args.frame}")
        figures["held_out"][str(n)] = evaluate(img.polar, res.expected.polar, speckled.polar, peak)
    from .compare import _jsonable, _print_realism, _print_scores

    figures["realism"] = _jsonable(report)
    figures["method"] = method
    figures["at_bounds"] = list(getattr(res, "at_bounds", []))
    # Everything is computed and formatted before the first file is written (the report's
    # lines included: a value that cannot be printed once crashed after the scene was written
    # and its run record said "complete"); a refused held-out frame leaves nothing behind.
    import contextlib
    import io

    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        for name, value in res.values.items():
            print(format_value(name, value))
        print(f"PSNR of the expected render on frame {args.frame}: {res.psnr_start_db:.2f} -> {res.psnr_db:.2f} dB "
              f"({res.renders} renders, method {method})")
        b = res.baselines
        print(f"beside it, on the same frame: its range profile in every beam {b['range profile']:.2f} dB, its "
              f"separable range x beam image {b['separable']:.2f} dB, its 15 x 9 local mean (the ceiling) "
              f"{b['ceiling']:.2f} dB")
        print(format_family(res.family, method, free))
        _print_scores(report)
        _print_realism(report)
        print(format_evaluation(figures["calibrated"], f"frame {args.frame} (calibrated): "))
        for n, ev in figures["held_out"].items():
            print(format_evaluation(ev, f"frame {n} (held out): "))
    json_text = json.dumps(figures, indent=1, default=_json_default) if args.json else None
    scene_text = yaml.safe_dump(doc, sort_keys=False)
    with run:
        # The calibrated scene last: a failure writing the pictures leaves no scene behind.
        write_png(image_path, side_by_side(real, res.expected, speckled, peak, args.frame))
        write_figure(args, figure_stem, lambda: calibration_figure(real, res.expected, speckled, peak, args.frame,
                                                                   colormap=args.colormap))
        if json_text is not None:
            with atomic_write(Path(args.json), "w") as f:
                f.write(json_text)
        with atomic_write(out, "w") as f:
            f.write(scene_text)
    sys.stdout.write(text.getvalue())
    for w in res.warnings:
        print(f"sonarsim: warning: {w}", file=sys.stderr)
    print(f"sonarsim: wrote {out} and {image_path}", file=sys.stderr)


def _json_default(value):
    """Numbers and arrays of numpy in the JSON figures."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    return float(value)


def calibrate_sidescan(args) -> None:
    """``calibrate`` on a side-scan recording: its unknowns (the depression and vertical width of
    the transducers; the device's gain, time-varied gain and noise) fitted on ``--pings`` with the
    vehicle where each ping's navigation and attitude put it (:mod:`sonarsim.analysis.sidescan`),
    scored on ``--evaluate-pings`` beside the trivial predictions. Writes the scene with the
    fitted side-scan (``--out``) and every figure (``--json``)."""
    import json

    import yaml

    from ..analysis import sidescan as A
    from ..config.loader import load_scene
    from ..io.output import atomic_write
    from ..io.readers.xtf import read_waterfall
    from ..io.run_record import OutputRun, record_beside
    from ..instruments.replay import ping_slice

    out = Path(args.out)
    outputs = [(out, "--out")] + ([(Path(args.json), "--json")] if args.json else [])
    run = OutputRun(record_beside(out), outputs, command=getattr(args, "command_line", None))
    run.protect([(args.real, "the recording")])
    scene = load_scene(args.scene)
    specs = [s for s in scene.instruments if s.type_name == "sidescan"]
    if not specs:
        raise ConfigError("--scene", "has no sidescan instrument to calibrate on a side-scan recording")
    rec = read_waterfall(args.real)
    navigated = np.nonzero(np.isfinite(rec.geometry.altitude_m))[0]
    if len(navigated) < 4:
        raise ConfigError(str(args.real), f"only {len(navigated)} pings log an altitude: nothing to fit on")
    half = navigated[len(navigated) // 2]
    cal = ping_slice(rec.n_pings, args.pings, str(args.real)) if args.pings is not None else range(navigated[0], half)
    if args.evaluate_pings is not None:
        test = ping_slice(rec.n_pings, args.evaluate_pings, str(args.real))
    else:
        test = range(cal.stop, rec.n_pings) if cal.stop < rec.n_pings - 1 else range(navigated[0], cal.start)
    for name, pings in (("--pings", cal), ("--evaluate-pings", test)):
        known = np.isfinite(rec.geometry.altitude_m[list(pings)]) if len(pings) else np.zeros(0, bool)
        if known.sum() < 2:
            raise ConfigError(name, f"pings {pings.start}:{pings.stop} hold {int(known.sum())} with navigation; "
                              "give at least two")
    cal = np.array([k for k in cal if np.isfinite(rec.geometry.altitude_m[k])])
    test = np.array([k for k in test if np.isfinite(rec.geometry.altitude_m[k])])
    overlap = np.intersect1d(cal, test)
    if overlap.size:
        raise ConfigError("--evaluate-pings", f"shares {overlap.size} pings with --pings: score on pings not fitted on")
    fit = A.calibrate(rec, cal)
    figures = A.score(rec, fit, cal, test)
    f, i = figures["first_return"], figures["intensity_db"]
    print(f"fitted on pings {cal.min()}-{cal.max()}: depression {fit.depression_deg:.1f} deg, vertical width "
          f"{fit.vertical_beam_width_deg:.1f} deg, gain {fit.gain_db:.1f} dB, TVG r^{fit.range_exponent:.2f}, "
          f"noise {fit.noise_db:.1f} dB")
    print(f"scored on pings {test.min()}-{test.max()}: first return median |error| {f['model_m']:.2f} m (logged "
          f"altitude {f['altitude_m']:.2f} m, flat-floor geometry {f['geometry_m']:.2f} m); intensity rms "
          f"{i['model_db']:.2f} dB (calibration mean profile {i['mean_profile_db']:.2f}, shifted to each ping's "
          f"first return {i['shifted_profile_db']:.2f}, ceiling {i['ceiling_neighbours_db']:.2f})")
    doc = scene.to_dict()
    section = doc["sonar"] if "sonar" in doc else next(x for x in doc["instruments"] if x["name"] == specs[0].name)
    section["depression_deg"] = round(fit.depression_deg, 3)
    section["vertical_beam_width_deg"] = round(fit.vertical_beam_width_deg, 3)
    with run:
        with atomic_write(out, "w") as fh:
            fh.write(f"# calibrated on {Path(args.real).name} pings {cal.min()}-{cal.max()} by sonarsim calibrate; the "
                     f"device's gain law (gain {fit.gain_db:.2f} dB, TVG r^{fit.range_exponent:.3f}, noise "
                     f"{fit.noise_db:.2f} dB) is in the JSON figures\n")
            yaml.safe_dump(doc, fh, sort_keys=False)
        if args.json:
            with atomic_write(Path(args.json), "w") as fh:
                json.dump(figures, fh, indent=1)


def _ping_split(n: int, args, usable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The calibration and evaluation pings of ``--pings`` / ``--evaluate-pings`` (default: the
    first and second half of the ``usable`` pings), refusing overlaps and empty choices by name."""
    from ..instruments.replay import ping_slice

    good = np.nonzero(usable)[0]
    if len(good) < 4:
        raise ConfigError(str(args.real), f"only {len(good)} pings can be fitted on: nothing to calibrate")
    half = good[len(good) // 2]
    cal = ping_slice(n, args.pings, str(args.real)) if args.pings is not None else range(good[0], half)
    if args.evaluate_pings is not None:
        test = ping_slice(n, args.evaluate_pings, str(args.real))
    else:
        test = range(cal.stop, n) if cal.stop < n - 1 else range(good[0], cal.start)
    cal = np.array([k for k in cal if usable[k]], dtype=np.int64)
    test = np.array([k for k in test if usable[k]], dtype=np.int64)
    for name, pings in (("--pings", cal), ("--evaluate-pings", test)):
        if len(pings) < 2:
            raise ConfigError(name, f"holds {len(pings)} usable pings; give at least two")
    if np.intersect1d(cal, test).size:
        raise ConfigError("--evaluate-pings", "shares pings with --pings: score on pings not fitted on")
    return cal, test


def calibrate_survey(args, film: str) -> None:
    """``calibrate`` on a multibeam recording (the floor's plane fitted on ``--pings``, the other
    pings rendered over it with their attitude and scored) or an echo sounder's (the bottom
    detector's threshold fitted on ``--pings``, scored against the sounder's own bottom on
    ``--evaluate-pings``). Writes the scene with what was fitted (``--out``: the floor as a plane
    ``floor``, or the single-beam's ``threshold_db``) and every figure (``--json``)."""
    import json

    import yaml

    from ..config.loader import load_scene
    from ..io.output import atomic_write
    from ..io.run_record import OutputRun, record_beside

    out = Path(args.out)
    outputs = [(out, "--out")] + ([(Path(args.json), "--json")] if args.json else [])
    run = OutputRun(record_beside(out), outputs, command=getattr(args, "command_line", None))
    run.protect([(args.real, "the recording")])
    scene = load_scene(args.scene)
    kind = {"soundings": "multibeam", "envelope": "singlebeam"}[film]
    specs = [s for s in scene.instruments if s.type_name == kind]
    if not specs:
        raise ConfigError("--scene", f"has no {kind} instrument to calibrate on this {kind} recording")
    doc = scene.to_dict()
    section = next(x for x in doc["instruments"] if x["name"] == specs[0].name)
    if film == "soundings":
        from ..analysis.multibeam import fit_floor, score
        from ..io.readers.r2sonic import read_soundings

        rec = read_soundings(args.real)
        usable = np.isfinite(rec.two_way_time_s).any(axis=1) & np.isfinite(rec.geometry.roll_deg)
        cal, test = _ping_split(rec.n_pings, args, usable)
        figures = score(rec, cal, test)
        r, b, f = figures["range_m"], figures["backscatter_db"], figures["floor"]
        print(f"fitted on pings {cal.min()}-{cal.max()}: a floor {f['depth_m']:.3f} m below the heads, tilted "
              f"{f['tilt_east_deg']:.2f} deg east and {f['tilt_north_deg']:.2f} deg north")
        print(f"scored on pings {test.min()}-{test.max()}: per-beam range median |error| {r['model']:.3f} m "
              f"(calibration mean per beam {r['calibration_mean_per_beam']:.3f} m, level floor {r['level_floor']:.3f} m); "
              f"backscatter rms {b['model']:.2f} dB (per-beam mean {b['calibration_mean_per_beam']:.2f} dB, ceiling "
              f"{b['ceiling_neighbours']:.2f} dB)")
        ar = figures["angular_response_db"]
        fit = ar["fit"]
        bed = fit["sediment"] or f"grain size {fit['grain_size_phi']:g} phi"
        print(f"angular response: the sediment law ({bed}, fitted on the calibration pings) rms {ar['sediment']:.2f} dB "
              f"over {ar['bins']} bins of incidence (per-beam mean {ar['calibration_mean_per_beam']:.2f} dB, flat "
              f"{ar['flat']:.2f} dB, ceiling {ar['ceiling_calibration_response']:.2f} dB)")
        a, bx, cy = fit_floor(rec, cal)
        normal = np.array([-bx, -cy, 1.0]) / np.linalg.norm([-bx, -cy, 1.0])
        doc.pop("ground", None)
        planes = [p for p in doc.get("planes", []) if p.get("name") != "floor"]
        doc["planes"] = planes + [{"name": "floor", "point_m": [0.0, 0.0, float(a)], "normal": normal.tolist()}]
        note = f"the floor fitted on {Path(args.real).name} pings {cal.min()}-{cal.max()}"
    else:
        from ..analysis.singlebeam import bottom_check
        from ..io.readers.imagenex import read_envelope

        rec = read_envelope(args.real)
        usable = np.isfinite(rec.bottom_range_m)
        cal, test = _ping_split(rec.n_pings, args, usable)
        figures = bottom_check(rec, cal, test)
        d = figures["detector"]
        print(f"fitted on pings {cal.min()}-{cal.max()}: bottom detector threshold {figures['threshold_db']:g} dB")
        print(f"scored on pings {test.min()}-{test.max()}: bottom median |error| {d['median_m']:.3f} m "
              f"({100 * d['within_0.1_m']:.0f} % within 0.1 m); constant {figures['constant']['median_m']:.2f} m, "
              f"previous ping {figures['persistence']['median_m']:.2f} m")
        section["threshold_db"] = figures["threshold_db"]
        note = f"the bottom detector's threshold fitted on {Path(args.real).name} pings {cal.min()}-{cal.max()}"
    with run:
        with atomic_write(out, "w") as fh:
            fh.write(f"# {note} by sonarsim calibrate; every figure in the JSON\n")
            yaml.safe_dump(doc, fh, sort_keys=False)
        if args.json:
            with atomic_write(Path(args.json), "w") as fh:
                json.dump(figures, fh, indent=1)
