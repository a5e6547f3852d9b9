"""``sonarsim live SCENE``: the scene's sonar published as ROS 2 topics over DDS, in real time,
without ROS installed (:mod:`sonarsim.live`; the ``live`` extra).

Wiring (in :mod:`sonarsim.cli.main`)::

    from .live import add_live_parser
    add_live_parser(sub)
"""

from __future__ import annotations

import argparse
import time
from typing import Any

from ..core.console import log as _log
from .argtypes import positive_float

__all__ = ["LIVE_DEMO_FILES", "add_live_demo_parser", "add_live_parser", "cmd_live", "cmd_live_demo"]


def add_live_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``live`` sub-command; sets ``func=cmd_live``."""
    from .dataset import _names
    from .render import add_render_options

    p = subparsers.add_parser(
        "live", help="publish the scene's sonar as ROS 2 topics over DDS, in real time (no ROS needed)",
        description="Render the scene's sonar frame after frame and publish each frame as ROS 2 topics over DDS "
        "(Cyclone DDS; the 'live' extra), on ROS_DOMAIN_ID's domain: /sonar/image "
        "(marine_acoustic_msgs/ProjectedSonarImage), /sonar/fan (sensor_msgs/Image), /sonar/pose, /tf "
        "(world -> sonar) and /tf_static (sonar -> sonar_image), /sonar/image/unit (latched), paced by the wall "
        "clock or, with --use-sim-time, by /clock. A scene with instruments (side-scan, multibeam, scanning, "
        "single-beam, FLS) publishes each at its own ping rate on /NAME/... (RawSonarImage, SonarDetections, "
        "PointCloud2, Range, ProjectedSonarImage, as their bags hold them), /tf (world -> vehicle) and /tf_static "
        "(vehicle -> mounts). A ROS 2 node on "
        "rmw_cyclonedds_cpp or rmw_fastrtps_cpp receives them (docs/ros2.md). Runs until Ctrl-C or --frames.")
    p.add_argument("scene", help="scene file (YAML or JSON)")
    g = p.add_argument_group("timing")
    g.add_argument("--rate", type=positive_float, default=None, metavar="HZ",
                   help="frames a second (default 10; with --trajectory its own times, or resampled at HZ)")
    g.add_argument("--fast", action="store_true",
                   help="publish each frame as soon as it is rendered (stamps stay 1/rate apart)")
    g.add_argument("--frames", type=int, default=None, metavar="N",
                   help="stop after N frames (instruments: N pings each; default: the trajectory's, or until Ctrl-C)")
    g.add_argument("--use-sim-time", action="store_true",
                   help="pace and stamp the frames by the simulated time on /clock (rosgraph_msgs/Clock), as a ROS 2 "
                   "node with use_sim_time does")
    g.add_argument("--trajectory", default=None, metavar="FILE",
                   help="the sonar's timestamped poses (CSV t,x,y,z,roll_deg,pitch_deg,yaw_deg or TUM); default "
                   "the scene's pose at every frame")
    g = p.add_argument_group("poses in")
    g.add_argument("--pose-topic", default=None, metavar="TOPIC",
                   help="the vehicle's pose from this topic (a simulator's /odom): each frame waits for its time and "
                   "takes the pose at its stamp, interpolated")
    g.add_argument("--pose-type", choices=("odometry", "pose_stamped"), default="odometry",
                   help="what --pose-topic carries: nav_msgs/Odometry (default) or geometry_msgs/PoseStamped")
    g.add_argument("--pose-frame", default=None, metavar="FRAME",
                   help="the vehicle's pose from TF instead: FRAME's transform from the world frame on /tf (a "
                   "simulator's ground truth, e.g. base_link)")
    g.add_argument("--object-pose", action="append", default=[], metavar="NAME=SOURCE",
                   help="move the scene's object NAME by a topic: SOURCE is TOPIC (nav_msgs/Odometry), "
                   "TOPIC:pose_stamped, or tf:FRAME; repeat for more objects (objects with a track in the scene "
                   "move by it)")
    g.add_argument("--max-staleness", type=positive_float, default=0.5, metavar="S",
                   help="skip a frame whose newest pose is older than S seconds (default 0.5), and say so")
    g.add_argument("--mount", type=_mount, default=None, metavar="X,Y,Z,ROLL,PITCH,YAW",
                   help="with --pose-topic: the sonar on the vehicle (metres, degrees; REP-103), default the "
                   "vehicle's own frame")
    g = p.add_argument_group("topics")
    g.add_argument("--no-fan", action="store_true", help="do not publish the fan image")
    g.add_argument("--points", action="store_true",
                   help="publish each frame's ground truth on /sonar/points (sensor_msgs/PointCloud2: x, y, z in the "
                   "world frame, object id) and the ids' names on /sonar/points/ids (latched JSON)")
    g.add_argument("--frame-ids", type=_names("--frame-ids"), default=None, metavar="NAME=ID,...",
                   help="frame names (world, sonar, image), e.g. world=map,sonar=sonar_link")
    g.add_argument("--topics", type=_names("--topics"), default=None, metavar="NAME=TOPIC,...",
                   help="topic names (image, fan, pose, tf, points, unit), e.g. image=/oculus/image")
    g.add_argument("--domain", type=int, default=None, metavar="ID",
                   help="the DDS domain (default: $ROS_DOMAIN_ID, else 0)")
    g.add_argument("--no-speckle", action="store_true", help="publish the expected (mean) image, no random draws")
    add_render_options(p)
    p.set_defaults(func=cmd_live)
    return p


def _mount(text: str) -> Any:
    """An argparse type: ``x,y,z,roll,pitch,yaw`` (metres, degrees) as a Pose."""
    from ..core.transforms import Pose

    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    import math

    if len(v) != 6 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"--mount must be six numbers x,y,z,roll,pitch,yaw (metres, degrees), "
                                         f"got {text!r}")
    return Pose(tuple(v[:3]), tuple(v[3:]))


def _object_sources(items: list[str]) -> dict[str, tuple[str, str, str | None]]:
    """``--object-pose NAME=SOURCE`` values: name -> (topic, kind, TF frame or None)."""
    from ..errors import ConfigError
    from ..live.dds import dds_topic

    out: dict[str, tuple[str, str, str | None]] = {}
    for item in items:
        name, sep, source = item.partition("=")
        if not sep or not name or not source:
            raise ConfigError("--object-pose", f"must be NAME=TOPIC, NAME=TOPIC:pose_stamped or NAME=tf:FRAME, "
                              f"got {item!r}")
        if name in out:
            raise ConfigError("--object-pose", f"object {name!r} is given twice")
        if source.startswith("tf:"):
            if not source[3:]:
                raise ConfigError("--object-pose", f"{item!r}: tf: needs a frame name (tf:FRAME)")
            out[name] = ("/tf", "tf", source[3:])
            continue
        topic, _, kind = source.partition(":")
        kind = kind or "odometry"
        if kind not in ("odometry", "pose_stamped"):
            raise ConfigError("--object-pose", f"{item!r}: the type after ':' must be odometry or pose_stamped")
        dds_topic(topic)  # (checked, naming the value)
        out[name] = (topic, kind, None)
    return out


def cmd_live(args: Any) -> None:
    """Run ``sonarsim live`` (:func:`sonarsim.live.stream.stream`)."""
    from ..config.loader import load_scene
    from ..errors import ConfigError
    from ..io.rosbag import bag_naming
    from ..live.publisher import Publisher
    from ..live.stream import LiveOptions, stream
    from ..renderer.simulator import Simulator
    from .render import override_render

    if args.frames is not None and args.frames < 1:
        raise ConfigError("--frames", f"must be at least 1, got {args.frames}")
    frame_ids, topics = bag_naming(frame_ids=args.frame_ids, topics=args.topics)
    if args.pose_topic is not None and args.pose_frame is not None:
        raise ConfigError("--pose-frame", "the vehicle's pose comes from --pose-topic or from --pose-frame: give one")
    if args.mount is not None and args.pose_topic is None and args.pose_frame is None:
        raise ConfigError("--mount", "places the sonar on a vehicle whose pose comes from --pose-topic or --pose-frame: "
                          "give one of those too")
    if (args.pose_topic or args.pose_frame) is not None and args.trajectory is not None:
        raise ConfigError("--pose-topic" if args.pose_topic else "--pose-frame",
                          "the poses come from a topic or from --trajectory: give one of the two")
    object_sources = _object_sources(args.object_pose)
    options = LiveOptions(rate_hz=args.rate, fast=args.fast, n_frames=args.frames, fan=not args.no_fan,
                          speckle=False if args.no_speckle else None, frame_ids=frame_ids, topics=topics,
                          max_staleness_s=args.max_staleness, points=args.points)
    scene = override_render(load_scene(args.scene), args)
    if scene.instruments:
        _check_instrument_options(args)
    trajectory = None
    if args.trajectory is not None:
        from ..dataset.trajectory import read_trajectory

        trajectory = read_trajectory(args.trajectory, key="--trajectory")
    names = [o.name for o in scene.objects]
    for name in object_sources:
        if name not in names:
            raise ConfigError("--object-pose", f"the scene has no object {name!r}; its objects: "
                              f"{', '.join(map(repr, names)) or 'none'}")
    with Simulator(scene, backend=args.backend) as sim, Publisher(args.domain) as publisher:
        if scene.instruments:
            _log(f"live: publishing {len(scene.instruments)} instruments on DDS domain {publisher.domain}"
                 + (f" for {args.frames} pings each" if args.frames else ", Ctrl-C to stop"))
        else:
            _log(f"live: publishing {topics.image} and its companions on DDS domain {publisher.domain}"
                 + (f" for {args.frames} frames" if args.frames else ", Ctrl-C to stop"))
        from ..live.dds import dds_topic
        from ..live.poses import TopicPoses

        poses = None
        if args.pose_topic is not None:
            dds_topic(args.pose_topic)  # (checked, naming the option's value)
            poses = TopicPoses(publisher.participant, args.pose_topic, args.pose_type)
            _log(f"live: poses from {args.pose_topic} ({args.pose_type})")
        elif args.pose_frame is not None:
            poses = TopicPoses(publisher.participant, "/tf", "tf", frame=args.pose_frame, world=frame_ids.world)
            _log(f"live: poses from TF, {frame_ids.world} -> {args.pose_frame}")
        object_poses = {}
        for name, (topic, kind, frame) in object_sources.items():
            object_poses[name] = TopicPoses(publisher.participant, topic, kind, frame=frame, world=frame_ids.world)
            _log(f"live: object {name!r} moves by {object_poses[name].topic}")
        if sim.tracked:
            _log(f"live: objects on tracks: {', '.join(sim.tracked)}")
        timing = {}
        if args.use_sim_time:
            from ..live.simclock import SimClock

            sim_clock = SimClock(publisher.participant)
            _log("live: waiting for /clock")
            sim_clock.wait_first()
            timing = {"now_ns": sim_clock.now_ns, "clock": sim_clock.seconds, "sleep": sim_clock.sleep}
        if scene.instruments:
            from ..live.instruments import instrument_periods, stream_instruments

            _log("live: instruments, each at its own rate: " + ", ".join(
                f"{name} every {1e3 * period:.4g} ms on /{name}/..." for name, period in instrument_periods(sim).items()))
            stats = stream_instruments(sim, publisher, options, trajectory, say=lambda line: _log(f"live: {line}"),
                                       poses=poses, object_poses=object_poses, vehicle_frame=args.pose_frame or "vehicle",
                                       vehicle_tf=args.pose_frame is None, **timing)
            _log(f"live: {_pings_summary(stats)}")
            return
        stats = stream(sim, publisher, options, trajectory, say=lambda line: _log(f"live: {line}"), poses=poses,
                       mount=args.mount, object_poses=object_poses, vehicle_frame=args.pose_frame or "vehicle",
                       vehicle_tf=args.pose_frame is None, **timing)
        _log(f"live: {stats.summary()}")


def _check_instrument_options(args: Any) -> None:
    """Options that mean nothing for a scene's instruments are refused, naming what does."""
    from ..errors import ConfigError

    if args.rate is not None:
        raise ConfigError("--rate", "each instrument pings at its own rate (its ping_rate_hz in the scene, or its "
                          "range's two-way time); use --fast to publish as fast as they render")
    if args.mount is not None:
        raise ConfigError("--mount", "the instruments are mounted on the vehicle in the scene (their 'mount')")
    if args.no_fan:
        raise ConfigError("--no-fan", "the instruments publish no fan image; leave it out")
    if args.points:
        raise ConfigError("--points", "the instruments' ground truth is not published live; a multibeam's soundings "
                          "go out on /NAME/points")
    if args.topics is not None:
        raise ConfigError("--topics", "an instrument's topics are /NAME/... after its name in the scene")
    extra = sorted(set(args.frame_ids or {}) - {"world"})
    if extra:
        raise ConfigError("--frame-ids", f"with instruments only world=... is taken (the vehicle is 'vehicle', or "
                          f"--pose-frame; the mounts are named after the instruments), not {', '.join(extra)}")


def _pings_summary(stats: Any) -> str:
    """One line of what :func:`~sonarsim.live.instruments.stream_instruments` did."""
    import numpy as np

    if not stats.frames:
        return "no ping published" + (f", {stats.stale} skipped for a stale pose" if stats.stale else "")
    med = lambda x: 1e3 * float(np.median(x))  # noqa: E731
    return (("stopped by a signal after " if stats.interrupted else "") + f"{stats.frames} pings in {stats.wall_s:.2f} s ("
            + ", ".join(f"{name} {n}" for name, n in stats.pings.items()) + f"), {stats.late} late"
            + (f", {stats.stale} skipped for a stale pose" if stats.stale else "")
            + f"; render {med(stats.render_s):.1f} ms, publish {med(stats.publish_s):.1f} ms a ping (median)")


def add_live_demo_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``live-demo`` sub-command; sets ``func=cmd_live_demo``."""
    p = subparsers.add_parser(
        "live-demo", help="a scripted vehicle past the demo tank, sonarsim live publishing, a recorder writing a bag",
        description="The live demo, on the loopback: a scripted pose publisher (standing in for a simulator) drives a "
        "vehicle past the demo tank's objects on /demo/vehicle/pose (geometry_msgs/PoseStamped, 50 Hz); 'sonarsim "
        "live' renders the tank, its buoy patrolling across the fan, from those poses and publishes; a recorder "
        "writes every topic it received into a ROS 2 bag. Writes into --out: scene.yaml (what live renders), bag/ "
        "(the recording, read with rosbags or 'ros2 bag info'), fan_first.png and fan_last.png (the first and last "
        "fans received, as rviz2 shows them) and live-demo.json (what the bag holds). Needs the live extra.")
    p.add_argument("--out", default="sonarsim-live-demo", help="output folder (default: ./sonarsim-live-demo)")
    p.add_argument("--seconds", type=positive_float, default=8.0, metavar="S",
                   help="how long the vehicle runs, seconds (default 8, at most 120)")
    p.add_argument("--rate", type=positive_float, default=10.0, metavar="HZ",
                   help="sonar frames a second (default 10, at most 50)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="the bag's storage (default mcap)")
    p.add_argument("--domain", type=int, default=None, metavar="ID",
                   help="the DDS domain (default: $ROS_DOMAIN_ID, else 0)")
    p.set_defaults(func=cmd_live_demo)
    return p


#: The files ``live-demo`` writes into --out (and the bag folder, ``bag``).
LIVE_DEMO_FILES = ("scene.yaml", "fan_first.png", "fan_last.png", "live-demo.json")


def cmd_live_demo(args: Any) -> None:
    """Run ``sonarsim live-demo`` (:mod:`sonarsim.live.demo`)."""
    import json
    import os
    import shutil
    import tempfile
    from pathlib import Path

    import yaml

    from ..errors import ConfigError, SonarsimError
    from ..io.output import atomic_write, write_png
    from ..io.run_record import OutputRun
    from ..live import dds
    from ..live.demo import MOUNT, POSE_TOPIC, demo_scene, read_back

    if args.seconds > 120:
        raise ConfigError("--seconds", f"must be at most 120, got {args.seconds:g}")
    if args.rate > 50:
        raise ConfigError("--rate", f"must be at most 50 frames a second, got {args.rate:g}")
    domain = dds.domain_id() if args.domain is None else args.domain
    lo, hi = dds.ROS_DOMAIN_ID_RANGE
    if not lo <= domain <= hi:
        raise ConfigError("--domain", f"must be from {lo} to {hi}, got {domain}")
    dds.qos("sensor")  # (Cyclone DDS is there, or the live extra is named)
    from ..io.rosbag_instruments import instrument_typestore

    instrument_typestore()  # (rosbags is there; the recorder's types are known)
    out = Path(args.out)
    run = OutputRun.for_folder(out, LIVE_DEMO_FILES, command=getattr(args, "command_line", None))
    n_frames = max(1, round(args.seconds * args.rate))
    with run:
        doc = demo_scene()
        with atomic_write(out / "scene.yaml", "w") as f:
            yaml.safe_dump(doc, f, sort_keys=False)
        tmp = Path(tempfile.mkdtemp(prefix=".bag-", suffix=".tmp", dir=out))
        try:
            bag_path = _record_demo(args, out, tmp / "bag", domain, n_frames)
            got = read_back(bag_path)
            if not got["images"]:
                raise SonarsimError(f"live-demo: the recorder received no sonar image on domain {domain} in "
                                    f"{args.seconds:g} s (is the loopback's multicast blocked?)")
            # The new bag replaces the previous run's only now that it is complete.
            old = out / "bag"
            if old.exists():
                shutil.rmtree(old)
            os.rename(bag_path, old)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        write_png(out / "fan_first.png", got["fans"][0][1])
        write_png(out / "fan_last.png", got["fans"][-1][1])
        summary = _demo_summary(got, args, domain, n_frames)
        with atomic_write(out / "live-demo.json", "w") as f:
            json.dump(summary, f, indent=2)
    _log(f"live-demo: the bag {out / 'bag'} holds " + ", ".join(f"{n} on {t}" for t, n in sorted(got["messages"].items())))
    _log(f"live-demo: the vehicle ran x {summary['vehicle_x_m'][0]:.2f} -> {summary['vehicle_x_m'][1]:.2f} m; the buoy "
         f"moved y {summary['buoy_y_m'][0]:.2f} .. {summary['buoy_y_m'][1]:.2f} m; fans in {out / 'fan_first.png'} "
         f"and {out / 'fan_last.png'}")
    _log("live-demo: with ROS 2 installed, the same by hand (docs/ros2.md, 'The live demo'): "
         f"sonarsim live {out / 'scene.yaml'} --pose-topic {POSE_TOPIC} --pose-type pose_stamped --mount {MOUNT}; "
         "ros2 bag record /sonar/image /sonar/fan /sonar/pose /tf /tf_static")


def _record_demo(args: Any, out: Any, bag_path: Any, domain: int, n_frames: int) -> Any:
    """The three parts of the demo, the bag written at ``bag_path``; returns it."""
    import os
    import subprocess
    import sys

    from ..errors import SonarsimError
    from ..io.rosbag import BagWriter
    from ..live.demo import MOUNT as mount
    from ..live.demo import POSE_TOPIC as pose_topic
    from ..live.demo import Recorder, ScriptedVehicle, wait_for

    with BagWriter(bag_path, storage=args.storage) as bag:
        recorder = Recorder(domain, bag).start()
        vehicle = ScriptedVehicle(domain).start()
        live = None
        try:
            # Discovery first, so that the first frames are not lost to a recorder not yet matched.
            if not wait_for(lambda: recorder.matched(pose_topic) > 0, 10.0):
                raise SonarsimError(f"live-demo: the recorder found no pose publisher on domain {domain} within 10 s "
                                    "(is the loopback's multicast blocked?)")
            cmd = [sys.executable, "-m", "sonarsim", "live", str(out / "scene.yaml"), "--pose-topic", pose_topic,
                   "--pose-type", "pose_stamped", "--mount", mount, "--rate", f"{args.rate:g}",
                   "--frames", str(n_frames)]
            _log(f"live-demo: the vehicle publishes {pose_topic} on DDS domain {domain}; starting "
                 f"sonarsim live for {n_frames} frames at {args.rate:g} Hz")
            live = subprocess.Popen(cmd, env={**os.environ, "ROS_DOMAIN_ID": str(domain)})
            rc = live.wait(timeout=args.seconds + 120)
            if rc != 0:
                raise SonarsimError(f"live-demo: sonarsim live exited with status {rc} (its messages are above)")
            time.sleep(0.3)  # (the last frame's samples in flight)
        except subprocess.TimeoutExpired:
            raise SonarsimError(f"live-demo: sonarsim live did not finish {n_frames} frames in "
                                f"{args.seconds + 120:g} s") from None
        finally:
            if live is not None and live.poll() is None:
                live.terminate()
                try:
                    live.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    live.kill()
            vehicle.stop()
            recorder.stop()
    return bag_path


def _demo_summary(got: dict, args: Any, domain: int, n_frames: int) -> dict:
    """live-demo.json: what the bag holds, in numbers a reader checks by eye."""
    stamps = [s for s, _, _ in got["images"]]
    span = (stamps[-1] - stamps[0]) / 1e9 if len(stamps) > 1 else 0.0
    xs = [x for _, x, _, _ in got["sonar"]] or [float("nan")]
    ys = [y for _, y in got["buoy"]] or [float("nan")]
    return {
        "domain": domain, "seconds": args.seconds, "rate_hz": args.rate, "frames_asked": n_frames,
        "messages": dict(sorted(got["messages"].items())),
        "images_received": len(stamps), "image_rate_hz": (len(stamps) - 1) / span if span > 0 else None,
        "image_shape_beams_bins": list(got["images"][0][1:]),
        "vehicle_x_m": [min(xs), max(xs)], "buoy_y_m": [min(ys), max(ys)],
        "frame_ids": {t: sorted(v) for t, v in sorted(got["frame_ids"].items())},
    }
