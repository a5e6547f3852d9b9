"""The ``sonarsim compare`` command: MSE, PSNR and SSIM between two sonar images.

With ``--stats`` A is taken as a real frame and B as a model in A's units, and the scores are
put beside what they mean (issue 22; :func:`sonarsim.analysis.bands.realism_report`): B's PSNR
and SSIM beside those of the trivial images made from A's frame (its range profile in every
beam, its separable range x beam image) and of the ceiling (A's own 15 x 9 local mean), all
scored on a held-out frame of A's recording (``--held-out``; by default the nearest later frame
that is not B's), B's margin over the best trivial image (a one-line warning on stderr when it
is negative), statistics in 8 range bands of the lit region and the water column, the
across-fan beam profile, and the classifier two-sample test. With a single real frame all of it
is scored on A itself, and the output says that this is optimistic.

A thin layer over :mod:`sonarsim.analysis.comparison`. Wire it into the main parser with::

    from .compare import add_compare_parser, cmd_compare
    add_compare_parser(sub)          # sub = parser.add_subparsers(...)
    COMMANDS["compare"] = cmd_compare  # or dispatch on args.func, which the parser sets

Results go to stdout (a table, or JSON with ``--json``); notes go to stderr. Bad input raises
:class:`~sonarsim.errors.SonarsimError`, which the main CLI prints without a traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from ..errors import SonarsimError
from .argtypes import frame_index, positive_float

__all__ = ["add_compare_parser", "cmd_compare"]

_NORMALIZE_CHOICES = ("max", "minmax", "none")


def _region_spec(text: str) -> tuple[str, str]:
    """``NAME=PATH`` of ``--region``."""
    name, sep, path = text.partition("=")
    if not (sep and name.strip() and path):
        raise argparse.ArgumentTypeError(f"expected NAME=PATH (e.g. wreck=wreck.png), got {text!r}")
    return name.strip(), path


def add_compare_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``compare`` sub-command to an ``add_subparsers()`` object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The new sub-parser; its defaults set ``func=cmd_compare``.
    """
    p = subparsers.add_parser(
        "compare",
        help="MSE, PSNR and SSIM between two sonar images (polar and fan)",
        description=(
            "Compare two sonar images as in the paper's Table I: MSE and PSNR (data range 255) "
            "and SSIM (11x11 Gaussian window, sigma 1.5), after normalising each image to "
            "0-255, in the polar domain and in the fan-shaped Cartesian domain (pixels inside "
            "both fans). A and B are sonarsim NPZ files (render.npz), PNGs (no geometry: "
            "same shape only, polar only) or recordings that sonarsim.io.readers can read. If "
            "the geometries differ, B is resampled onto A's grid when it covers at least half "
            "of A's area."
        ),
    )
    p.add_argument("a", metavar="A", help="reference image file (e.g. a real recording)")
    p.add_argument("b", metavar="B", help="image file compared with A (e.g. a simulation)")
    p.add_argument("--frame-a", type=frame_index, default=None, metavar="N",
                   help="frame of A, for recordings (default: 0)")
    p.add_argument("--frame-b", type=frame_index, default=None, metavar="N",
                   help="frame of B, for recordings (default: 0)")
    p.add_argument("--component-a", default=None, metavar="NAME",
                   help="NPZ only: compare this component of A instead of the total image "
                   "(object, ground, single, double, triple, total)")
    p.add_argument("--component-b", default=None, metavar="NAME",
                   help="NPZ only: compare this component of B instead of the total image")
    p.add_argument("--pixel-size", type=positive_float, default=None, metavar="M",
                   help="fan pixel size in metres (default: A's range resolution)")
    p.add_argument("--normalize", choices=_NORMALIZE_CHOICES, default="max",
                   help="normalisation of each image to 0-255: divide by its maximum (default), "
                   "min-max, or none (compare the values as stored)")
    p.add_argument("--stats", action="store_true",
                   help="also compare texture and distributions per region of A (all, lit, water, shadow), in the "
                   "images' own units: mean, speckle contrast, grain (correlation lengths), KS and Wasserstein distances, "
                   "range-profile difference in dB; and, taking A as a real frame and B as a model in its units: "
                   "PSNR and SSIM of B beside the trivial images made from A (its range profile in every beam, its "
                   "separable range x beam image) and the ceiling (A's 15 x 9 local mean), all scored on a held-out "
                   "frame (--held-out), B's margin over the best trivial image (a warning when negative), "
                   "statistics in 8 range bands of the lit region and the water column, the across-fan beam "
                   "profile, and a classifier two-sample test (0.5 = B's patches indistinguishable from A's)")
    p.add_argument("--region", type=_region_spec, action="append", default=[], metavar="NAME=PATH",
                   help="also compare a region of your own (implies --stats; repeatable): PATH is a .npy "
                   "array (numpy.save) of booleans or integers, non-zero in the region, rows from the "
                   "nearest range bin, or a PNG whose non-zero pixels are the region, far range at the "
                   "top as sonarsim draws polar PNGs; either on A's polar grid (A's shape)")
    p.add_argument("--held-out", type=frame_index, action="append", default=None, metavar="N",
                   help="with --stats (implied): a frame of A's recording, other than --frame-a, on which the trivial "
                   "images and the ceiling made from A's frame, and B, are scored (repeatable). Default: the nearest "
                   "frame after --frame-a (else before it) that is not B's frame of the same file, when the recording "
                   "has one; without one, "
                   "everything is scored against A's frame itself, which favours the trivial images made from it "
                   "(said in the output)")
    p.add_argument("--json", action="store_true",
                   help="print JSON instead of a table (infinite PSNR and undefined SSIM as null)")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="also write the annotated figure compare_figure.png into DIR, compare's only image (no "
                   "exact-pixel PNGs): A | B side by side on the "
                   "scale the metrics see (each image over its maximum, or as stored with --normalize none; "
                   "both in a device's counts when both are); then DIR/sonarsim-run.json")
    from .figures import add_figure_options

    add_figure_options(p, exact_pixels=False)  # compare writes its figure and nothing else
    p.set_defaults(func=cmd_compare)
    return p


def _describe(image: Any) -> dict[str, Any]:
    """Shape and geometry of an image, JSON-ready."""
    polar = image.polar
    out: dict[str, Any] = {"shape": [int(polar.shape[0]), int(polar.shape[1])]}
    sonar = getattr(image, "sonar", None)
    if sonar is not None:
        edges = sonar.beam_edges_deg
        out.update(
            range_min_m=float(sonar.range_min_m), range_max_m=float(sonar.range_max_m),
            n_range_bins=int(sonar.n_range_bins), n_beams=int(sonar.n_beams),
            left_edge_deg=float(edges[0]), right_edge_deg=float(edges[-1]),
        )
    return out


def _finite_or_none(value: Any) -> Any:
    """Strict JSON has no inf or NaN."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _fmt(value: float, spec: str) -> str:
    if math.isnan(value):
        return "n/a"
    if math.isinf(value):
        return "inf"
    return format(value, spec)


def _summary(path: str, frame: int | None, component: str | None, desc: dict[str, Any]) -> str:
    what = path
    if frame is not None:
        what += f" frame {frame}"
    if component is not None:
        what += f" [{component}]"
    rows, cols = desc["shape"]
    if "n_beams" in desc:
        return (f"{what}: {rows} x {cols}, {desc['range_min_m']:g}-{desc['range_max_m']:g} m, "
                f"{desc['n_beams']} beams {desc['left_edge_deg']:+.4g} to {desc['right_edge_deg']:+.4g} deg")
    return f"{what}: {rows} x {cols}, no geometry"


def _load_regions(specs: list[tuple[str, str]], shape: tuple[int, ...], path_a: str) -> dict[str, Any]:
    """The masks of ``--region NAME=PATH``, checked against A's polar shape."""
    from ..analysis.comparison import load_region
    from ..analysis.realism import REGIONS

    taken = ("all", *REGIONS)
    regions: dict[str, Any] = {}
    for name, path in specs:
        what = f"--region {name}={path}"
        if name in taken:
            raise SonarsimError(f"{what}: {name!r} is an automatic region ({', '.join(taken)}); choose another name")
        if name in regions:
            raise SonarsimError(f"{what}: region {name!r} is given twice")
        try:
            mask = load_region(path)
        except SonarsimError as exc:
            raise SonarsimError(f"{what}: {exc}") from None
        if mask.shape != tuple(shape):
            raise SonarsimError(
                f"{what}: {path}: the mask has shape {mask.shape} but A ({path_a}) has {shape[0]} range "
                f"bins and {shape[1]} beams; a region is drawn on A's polar grid"
            )
        regions[name] = mask
    return regions


def _held_out_indices(args: argparse.Namespace) -> list[int]:
    """Frames of A's recording to score on: --held-out, or by default the nearest frame after
    --frame-a (else before it) that is not B's frame when B is the same recording."""
    import os

    frame_a = args.frame_a or 0
    if args.held_out:
        if frame_a in args.held_out:
            raise SonarsimError(f"--held-out {frame_a}: that is A's frame (--frame-a), which the trivial images are "
                                "made from; hold out another frame")
        return list(dict.fromkeys(args.held_out))
    try:
        from ..io.readers import n_frames

        count = n_frames(args.a)
    except (SonarsimError, OSError, ImportError):
        return []  # a PNG, or no readers: one frame, said in the output
    try:
        same = os.path.samefile(args.a, args.b)
    except OSError:
        same = False
    # B scored on its own frame would say nothing about B.
    taken = {frame_a, args.frame_b or 0} if same else {frame_a}
    after = [k for k in range(frame_a + 1, count) if k not in taken]
    before = [k for k in range(frame_a - 1, -1, -1) if k not in taken]
    return (after or before)[:1]


def _write_figure(args: argparse.Namespace, run: Any, image_a: Any, image_b: Any, normalize: str | None,
                  metrics: Any = None) -> None:
    """compare_figure.* in --out: A | B | A - B on the scale the metrics see, the metrics under the title."""
    from pathlib import Path

    from ..plot.figures import comparison_figure
    from .figures import write_figure

    def titled(label: str, path: str, frame: int | None, component: str | None) -> str:
        from os.path import basename

        return f"{label}: {basename(path)}" + (f" frame {frame}" if frame is not None else "") + (
            f" [{component}]" if component else "")

    titles = [titled("A", args.a, args.frame_a, args.component_a), titled("B", args.b, args.frame_b, args.component_b)]
    with run:
        write_figure(args, Path(args.out) / "compare_figure",
                     lambda: comparison_figure([image_a, image_b], titles, normalize=normalize, colormap=args.colormap,
                                               pixel_size_m=args.pixel_size, title="sonarsim compare",
                                               metrics=metrics, difference=True), run)


def cmd_compare(args: argparse.Namespace) -> None:
    """Run ``sonarsim compare`` with parsed arguments; print the result to stdout.

    Raises
    ------
    SonarsimError
        For files that cannot be read (images or ``--region`` masks), regions that do not fit
        A, or images that cannot be compared.
    """
    from ..analysis.comparison import DOMAINS, compare_images, load_image
    from .figures import figure_names

    run = None
    names = figure_names(args, ("compare_figure",)) if args.out else []
    if names:
        from ..io.run_record import OutputRun

        # Checked before the images are read (sonarsim.io.run_record).
        run = OutputRun.for_folder(args.out, names, command=getattr(args, "command_line", None))
        run.protect([(args.a, "image A"), (args.b, "image B")])
    image_a = load_image(args.a, args.frame_a, args.component_a)
    image_b = load_image(args.b, args.frame_b, args.component_b)
    regions = _load_regions(args.region, image_a.polar.shape, args.a)
    normalize = None if args.normalize == "none" else args.normalize
    stats = args.stats or bool(args.region) or bool(args.held_out)
    held_numbers = _held_out_indices(args) if stats else []
    held = [load_image(args.a, n) for n in held_numbers]
    result = compare_images(
        image_a, image_b, DOMAINS, args.pixel_size, normalize=normalize, names=(args.a, args.b),
        stats=stats, regions=regions, held_out=held, frame_numbers=[args.frame_a or 0, *held_numbers],
    )
    info = result["info"]
    desc_a, desc_b = _describe(image_a), _describe(image_b)
    if run is not None:
        _write_figure(args, run, image_a, image_b, normalize, {d: result[d] for d in DOMAINS if d in result})

    if args.json:
        doc = {
            "a": {"path": args.a, "frame": args.frame_a, "component": args.component_a, **desc_a},
            "b": {"path": args.b, "frame": args.frame_b, "component": args.component_b, **desc_b},
            **info,
            "metrics": {
                d: {k: _finite_or_none(v) for k, v in result[d].items()}
                for d in DOMAINS if d in result
            },
        }
        if "stats" in result:
            doc["stats"] = {r: {k: _finite_or_none(v) for k, v in st.items()} for r, st in result["stats"].items()}
        if "realism" in result:
            doc["realism"] = _jsonable(result["realism"])
        print(json.dumps(doc, indent=2, allow_nan=False))
        _warn(result)
        return

    print(f"A: {_summary(args.a, args.frame_a, args.component_a, desc_a)}")
    print(f"B: {_summary(args.b, args.frame_b, args.component_b, desc_b)}")
    if info["resampled"]:
        print(f"B resampled onto A's polar grid; B covers {100 * info['overlap']:.3g} % of A's area")
    norm = {"max": "each image / its maximum x 255", "minmax": "each image min-max to 0-255",
            None: "none (values as stored)"}[normalize]
    print(f"normalisation: {norm}; PSNR and SSIM with data range 255")
    print()
    print(f"{'domain':<8} {'MSE':>12} {'PSNR dB':>9} {'SSIM':>8} {'pixels':>9}")
    for d in DOMAINS:
        if d in result:
            m = result[d]
            print(f"{d:<8} {_fmt(m['mse'], '.4f'):>12} {_fmt(m['psnr'], '.3f'):>9} "
                  f"{_fmt(m['ssim'], '.4f'):>8} {m['n_pixels']:>9}")
    if info["pixel_size_m"] is not None:
        print(f"(fan pixel size {info['pixel_size_m']:.4g} m)")
    for d, why in info["skipped"].items():
        print(f"sonarsim: note: {d} domain skipped: {why}", file=sys.stderr)
    if "realism" in result:
        _print_scores(result["realism"])
    if "stats" in result:
        print()
        print("per region of A, in the images' own units (A | B):")
        w = max(7, *map(len, result["stats"]))
        print(f"{'region':<{w}} {'pixels':>8} {'mean':>17} {'contrast':>13} {'grain bins':>13} "
              f"{'grain beams':>13} {'KS':>6} {'W1':>9} {'profile dB':>10}")
        for region, st in result["stats"].items():
            def pair(key: str, spec: str) -> str:
                return f"{_fmt(st[key + '_a'], spec)} | {_fmt(st[key + '_b'], spec)}"

            print(f"{region:<{w}} {int(st['pixels']):>8} {pair('mean', '.4g'):>17} {pair('contrast', '.3f'):>13} "
                  f"{pair('grain_range', '.2f'):>13} {pair('grain_beams', '.2f'):>13} {_fmt(st['ks'], '.3f'):>6} "
                  f"{_fmt(st['wasserstein'], '.4g'):>9} {_fmt(st['range_profile_rms_db'], '.2f'):>10}")
    if "realism" in result:
        _print_realism(result["realism"])
    _warn(result)


def _jsonable(value: Any) -> Any:
    """A report's nested dicts and lists with strict JSON's null for NaN and infinities."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return _finite_or_none(value)


def _warn(result: dict[str, Any]) -> None:
    warning = result.get("realism", {}).get("warning")
    if warning:
        print(f"sonarsim: warning: B: {warning}", file=sys.stderr)


def _print_scores(rep: dict[str, Any]) -> None:
    """B's PSNR and SSIM beside the trivial images' and the ceiling's (in the images' units)."""
    print()
    print(f"B against A's trivial images, in the images' own units (data range {rep['data_range']:g}): {rep['note']}")
    names = {"model": "B", "range profile": "range profile", "separable": "separable", "ceiling": "ceiling"}
    print(f"{'image':<14} {'PSNR dB':>9} {'SSIM':>8} {'margin dB':>10}")
    for key, label in names.items():
        sc = rep["scores"][key]
        tag = "  (best trivial image)" if key == rep["best_baseline"] else ""
        print(f"{label:<14} {_fmt(sc['psnr'], '.3f'):>9} {_fmt(sc['ssim'], '.4f'):>8} "
              f"{_fmt(sc['margin_db'], '+.3f'):>10}{tag}")


def _print_realism(rep: dict[str, Any]) -> None:
    """The band table, the beam profile and the C2ST, compactly."""
    print()
    print("per range band of A's lit region and water column (A | B; rel: B's contrast / A's - 1):")
    print(f"{'band':<8} {'range m':>13} {'pixels':>7} {'KS':>6} {'W1':>8} {'contrast':>13} {'rel':>7} "
          f"{'grain bins':>13} {'grain beams':>13}")
    for region, rows in rep["bands"].items():
        for b in rows:
            span = (f"{b['range_m'][0]:.3f}-{b['range_m'][1]:.3f}" if b["range_m"] is not None
                    else f"rows {b['rows'][0]}-{b['rows'][1]}")
            head = f"{region + '/' + str(b['band']):<8} {span:>13} {b['pixels']:>7}"
            if not b["ok"]:
                print(f"{head}  ({b['reason']})")
                continue

            def pair(key: str, spec: str) -> str:
                return f"{_fmt(b[key + '_real'], spec)} | {_fmt(b[key + '_model'], spec)}"

            print(f"{head} {_fmt(b['ks'], '.3f'):>6} {_fmt(b['wasserstein'], '.4g'):>8} {pair('contrast', '.3f'):>13} "
                  f"{_fmt(b['contrast_rel_diff'], '+.2f'):>7} {pair('grain_range', '.2f'):>13} "
                  f"{pair('grain_beams', '.2f'):>13}" + (f"  ({b['reason']})" if b["reason"] else ""))
    for region, s in rep["band_summary"].items():
        print(f"{region}: {s['bands_ok']} of {s['bands']} bands with enough pixels; worst KS {_fmt(s['max_ks'], '.3f')}, "
              f"worst |rel| contrast {_fmt(s['max_abs_contrast_rel_diff'], '.2f')}")
    beam = rep["beam_profile"]
    print(f"beam profile over the lit region: B - A RMS {_fmt(beam['rms_db'], '.2f')} dB over {beam['beams']} beams"
          + (f" ({beam['reason']})" if beam["reason"] else ""))
    c = rep["c2st"]
    if "reason" in c:
        print(f"classifier two-sample test: not run ({c['reason']})")
    else:
        print(f"classifier two-sample test (0.5 = indistinguishable): accuracy {c['accuracy']:.3f} +- "
              f"{c['null_standard_error']:.3f} (SE under the null; spread over {c['seeds']} seeds "
              f"{c['seed_std']:.3f}), {c['n_tested']} patches of {c['patch'][0]} x {c['patch'][1]}, "
              f"{c['folds']}-fold logistic regression")
        if c["accuracy"] < 0.5 - 3 * c["null_standard_error"]:
            # Cross-validation on copies of the same patches falls below chance (twosample's notes).
            print("  (below chance: the two sets share (nearly) the same patches, e.g. frozen speckle)")
