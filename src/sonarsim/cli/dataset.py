"""The ``sonarsim dataset`` command: a scenario's frames written to a resumable dataset folder.

A thin layer over :func:`sonarsim.dataset.generate` (see :mod:`sonarsim.dataset.writer` for
the folder's layout and how a run resumes).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .argtypes import integer_at_least

__all__ = ["add_dataset_parser", "cmd_dataset"]


def _count(text: str) -> int:
    return integer_at_least(text, 1, "count")


def _seed(text: str) -> int:
    return integer_at_least(text, 0, "seed")


def _address(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a Ray cluster address, 'auto' or 'local', got {text!r}")
    return text


def _names(option: str) -> Any:
    """An argparse type: ``name=value,name=value`` as a dict (each name once)."""

    def parse(text: str) -> dict[str, str]:
        out: dict[str, str] = {}
        for item in text.split(","):
            name, sep, value = item.partition("=")
            name, value = name.strip(), value.strip()
            if not sep or not name or not value or name in out:
                raise argparse.ArgumentTypeError(f"{option} must be NAME=VALUE pairs separated by commas, each "
                                                 f"name once (e.g. world=map,sonar=sonar_link), got {text!r}")
            out[name] = value
        return out

    return parse


def add_dataset_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``dataset`` sub-command; sets ``func=cmd_dataset``."""
    p = subparsers.add_parser(
        "dataset", help="render a scenario's frames into a dataset folder (NPZ, manifest, COCO, ROS 2 bag)",
        description="Render every frame of a scenario file into --out: frames/NNNNNN.npz (the image and its "
        "labels; the component images with --labels all), manifest.jsonl (pose, seed, files, sha256 per frame), dataset.json, coco.json (with labels: "
        "each object's direct echo, box and mask, on frames/NNNNNN_fan.png, written for it, or with --coco polar on "
        "frames/NNNNNN_polar.png; its ghosts too with --coco-ghosts) "
        "and optionally PNGs and a ROS 2 bag. Killed and started again with the same command, it "
        "keeps the frames that verify and makes the rest; a folder of another scenario or other options is "
        "refused.")
    p.add_argument("scenario", help="scenario file (YAML or JSON)")
    p.add_argument("--out", required=True, help="dataset folder (created if missing; resumed if it holds this dataset)")
    p.add_argument("--frames", type=_count, default=None, metavar="N",
                   help="make at most the first N frames (default: all the scenario's)")
    p.add_argument("--workers", type=_count, default=None, metavar="N",
                   help="render in N processes (default 1; at most the CPU cores, and as many as the memory "
                   "budget holds: a cap is said on stderr), or with --ray N actors (default: the cluster's CPUs); "
                   "the frames are the same whatever N")
    p.add_argument("--ray", type=_address, default=None, metavar="ADDRESS",
                   help="render on a Ray cluster: its address, 'auto' (the cluster this machine belongs to) or "
                   "'local' (a new Ray instance here); needs the ray extra (pip install -e '.[ray]' in a clone)")
    p.add_argument("--rosbag", choices=("mcap", "sqlite3"), default=None,
                   help="also write a ROS 2 bag into OUT/rosbag with this storage (needs the ros extra: pip install -e '.[ros]' "
                   "in a clone, pip install 'sonarsim[ros]' for an installed package)")
    p.add_argument("--start-time", default=None, metavar="TIME",
                   help="the bag's stamp of frame 0, the others following the trajectory's times: ISO 8601 "
                   "(2024-05-01T12:00:00Z; UTC where no offset is given) or seconds since 1970 (default: the "
                   "scenario's start_time, else 2000-01-01T00:00:00Z: fixed, so that the same scenario gives the "
                   "same bag byte for byte; \"$(date +%%s)\" for now)")
    p.add_argument("--frame-ids", type=_names("--frame-ids"), default=None, metavar="NAME=ID,...",
                   help="the bag's frame names, e.g. world=map,sonar=sonar_link (names: world, sonar, image; "
                   "default world, sonar, sonar_image, or the scenario's rosbag.frame_ids)")
    p.add_argument("--topics", type=_names("--topics"), default=None, metavar="NAME=TOPIC,...",
                   help="the bag's topics, e.g. image=/oculus/image,fan=/oculus/fan (names: image, fan, pose, tf, "
                   "points; default /sonar/image, /sonar/fan, /sonar/pose, /tf, /sonar/points, or the scenario's "
                   "rosbag.topics)")
    p.add_argument("--png", action="store_true", help="also write each frame's polar and fan images as PNG")
    p.add_argument("--shards", type=int, default=None, metavar="N",
                   help="also pack the frames into WebDataset tar shards of N frames (shards/000000.tar, ...; "
                   "listed in shards.jsonl), each written when its last frame is done: what the webdataset "
                   "library and Hugging Face datasets stream")
    p.add_argument("--yolo", action="store_true",
                   help="also write YOLO labels: frames/NNNNNN_fan.txt beside the image coco.json names (each "
                   "object's outline as a polygon, class = COCO category id - 1), and data.yaml with "
                   "yolo-train.txt and yolo-val.txt (the last tenth of the frames) for Ultralytics")
    p.add_argument("--seed", type=_seed, default=None, metavar="S",
                   help="replace the scenario's seed (every frame's draws come from it and the frame index)")
    p.add_argument("--labels", choices=("total", "all", "none"), default="total",
                   help="what each NPZ holds besides the device image (polar, range_m, azimuth_deg): the total's "
                   "instance map, the elevation maps, the points and the boxes (total, the default); also the "
                   "component images and an instance map per component (all); or nothing more (none)")
    p.add_argument("--coco", choices=("fan", "polar"), default="fan",
                   help="the image each frame's entry in coco.json names, and the pixels its boxes are in: fan "
                   "(default: frames/NNNNNN_fan.png, the fan at the range resolution, far range at the top) or polar "
                   "(frames/NNNNNN_polar.png: a column per beam, left-most first, a row per range bin, far range at "
                   "the top); that PNG is written with labels even without --png")
    p.add_argument("--coco-ghosts", action="store_true",
                   help="also annotate each object's multipath ghosts in coco.json, one annotation per path "
                   "signature (categories CATEGORY/SIGNATURE, e.g. buoy/O-surface-[objects]-surface-O); the boxes "
                   "and masks are the objects' direct echoes either way")
    p.add_argument("--signatures", action="store_true",
                   help="also store one image per path signature (which planes each echo bounced off), and the "
                   "component images (object, ground, single, double, ..., total)")
    p.add_argument("--chunk", type=_count, default=64, metavar="N",
                   help="for a scene with instruments (side-scan, scanning, single-beam, multibeam): pings per file "
                   "(a side-scan's waterfall of N pings with its labels; default 64); see docs/datasets.md")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.set_defaults(func=cmd_dataset)
    return p


def cmd_dataset(args: argparse.Namespace) -> None:
    from ..dataset import generate, load_scenario
    from ..dataset.scenario import MAX_SEED
    from ..errors import ConfigError

    start_ns = None
    if args.start_time is not None:  # checked before the scenario is read: it is cheap
        from ..io.rosbag import parse_start_time

        if args.rosbag is None:
            raise ConfigError("--start-time", "sets the ROS 2 bag's stamps: give --rosbag mcap or sqlite3 too")
        start_ns = parse_start_time(args.start_time, "--start-time")
    for option, value in (("--frame-ids", args.frame_ids), ("--topics", args.topics)):
        if value is not None:
            from ..io.rosbag import bag_naming

            if args.rosbag is None:
                raise ConfigError(option, "names the ROS 2 bag's frames and topics: give --rosbag mcap or sqlite3 too")
            try:  # the names checked before the scenario is read (the scenario's checked with it)
                bag_naming(**{option[2:].replace("-", "_"): value})
            except ConfigError as exc:
                raise ConfigError(option, f"{exc.key.rsplit('.', 1)[-1]}: {exc.detail}") from None
    scenario = load_scenario(args.scenario, frames=args.frames)
    if start_ns is not None:
        from ..dataset.frames import require_manifest_memory

        require_manifest_memory(scenario)  # before every frame's time is listed
        from ..io.rosbag import frame_stamps

        # The last frame's stamp too, here to name the option (generate names start_time).
        frame_stamps(start_ns, [scenario.trajectory.time_s(k) for k in range(scenario.n_frames)], "--start-time")
    if args.seed is not None:
        if args.seed > MAX_SEED:
            raise ConfigError("--seed", f"must be below 2**128, got {args.seed}")
        scenario = scenario.with_seed(args.seed)
    from ..dataset.instruments import has_instruments

    if has_instruments(scenario.scene):
        _instrument_dataset(scenario, args, start_ns)
        return
    summary = generate(
        scenario, args.out, workers=args.workers, formats=("npz",) + (("png",) if args.png else ()) + (("yolo",) if args.yolo else ()),
        rosbag=args.rosbag, ray=args.ray, labels=args.labels, signatures=args.signatures, coco=args.coco,
        ghosts=args.coco_ghosts, shards=args.shards,
        progress=not args.no_progress,
        command=getattr(args, "command_line", None), start_time=args.start_time, frame_ids=args.frame_ids,
        topics=args.topics,
    )
    rate = f" ({summary.frames_per_s:.2f} frames/s)" if summary.rendered else ""
    print(f"sonarsim: {summary.out}: {summary.n_frames} frames ({summary.rendered} made, {summary.reused} kept) "
          f"in {summary.seconds:.1f} s{rate}", file=sys.stderr, flush=True)
    if summary.rosbag is not None:
        from ..io.rosbag import format_stamp

        # Said every time: a bag stamped 2000 surprises whoever expected today.
        print(f"sonarsim: {summary.rosbag}: stamped from {format_stamp(summary.rosbag_start_ns)} (--start-time)",
              file=sys.stderr, flush=True)


def _instrument_dataset(scenario: Any, args: argparse.Namespace, start_ns: int | None) -> None:
    """A scenario whose scene has instruments: :func:`sonarsim.dataset.instruments.write_scenario_instruments`."""
    import time

    from ..dataset.instruments import write_scenario_instruments
    from ..errors import ConfigError

    # What only the FLS's frames have: refused rather than ignored.
    for option, given in (("--ray", args.ray is not None), ("--labels", args.labels != "total"),
                          ("--coco", args.coco != "fan"), ("--coco-ghosts", args.coco_ghosts),
                          ("--signatures", args.signatures), ("--frame-ids", args.frame_ids is not None),
                          ("--topics", args.topics is not None), ("--yolo", args.yolo),
                          ("--shards", args.shards is not None)):
        if given:
            raise ConfigError(option, "applies to an FLS's frames; this scenario's scene has instruments (side-scan, "
                              "scanning, single-beam, multibeam), whose datasets are written per instrument in "
                              "chunks of pings (--chunk)")
    t0 = time.perf_counter()
    summary = write_scenario_instruments(scenario, args.out, chunk=args.chunk, workers=args.workers,
                                         rosbag=args.rosbag, start_ns=start_ns)
    pings = ", ".join(f"{name} {n} pings" for name, n in summary.pings.items())
    print(f"sonarsim: {summary.out}: {pings} in {len(summary.records)} chunks ({summary.rendered} made, "
          f"{summary.kept} kept) in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    if summary.bag is not None:
        from ..io.rosbag import DEFAULT_START_NS, format_stamp

        first = start_ns if start_ns is not None else (scenario.start_time_ns or DEFAULT_START_NS)
        print(f"sonarsim: {summary.bag}: stamped from {format_stamp(first)} (--start-time)", file=sys.stderr,
              flush=True)
