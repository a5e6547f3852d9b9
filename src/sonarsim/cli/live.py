"""``sonarsim live SCENE``: the scene's sonar published as ROS 2 topics over DDS, in real time,
without ROS installed (:mod:`sonarsim.live`; the ``live`` extra).

Wiring (in :mod:`sonarsim.cli.main`)::

    from .live import add_live_parser
    add_live_parser(sub)
"""

from __future__ import annotations

import argparse
from typing import Any

from ..core.console import log as _log
from .argtypes import positive_float

__all__ = ["add_live_parser", "cmd_live"]


def add_live_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``live`` sub-command; sets ``func=cmd_live``."""
    from .dataset import _names
    from .render import add_render_options

    p = subparsers.add_parser(
        "live", help="publish the scene's sonar as ROS 2 topics over DDS, in real time (no ROS needed)",
        description="Render the scene's sonar frame after frame and publish each frame as ROS 2 topics over DDS "
        "(Cyclone DDS; the 'live' extra), on ROS_DOMAIN_ID's domain: /sonar/image "
        "(marine_acoustic_msgs/ProjectedSonarImage), /sonar/fan (sensor_msgs/Image), /sonar/pose, /tf "
        "(world -> sonar) and /tf_static (sonar -> sonar_image), /sonar/image/unit (latched). A ROS 2 node on "
        "rmw_cyclonedds_cpp or rmw_fastrtps_cpp receives them (docs/ros2.md). Runs until Ctrl-C or --frames.")
    p.add_argument("scene", help="scene file (YAML or JSON)")
    g = p.add_argument_group("timing")
    g.add_argument("--rate", type=positive_float, default=None, metavar="HZ",
                   help="frames a second (default 10; with --trajectory its own times, or resampled at HZ)")
    g.add_argument("--fast", action="store_true",
                   help="publish each frame as soon as it is rendered (stamps stay 1/rate apart)")
    g.add_argument("--frames", type=int, default=None, metavar="N",
                   help="stop after N frames (default: the trajectory's, or until Ctrl-C)")
    g.add_argument("--trajectory", default=None, metavar="FILE",
                   help="the sonar's timestamped poses (CSV t,x,y,z,roll_deg,pitch_deg,yaw_deg or TUM); default "
                   "the scene's pose at every frame")
    g = p.add_argument_group("topics")
    g.add_argument("--no-fan", action="store_true", help="do not publish the fan image")
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
    options = LiveOptions(rate_hz=args.rate, fast=args.fast, n_frames=args.frames, fan=not args.no_fan,
                          speckle=False if args.no_speckle else None, frame_ids=frame_ids, topics=topics)
    scene = override_render(load_scene(args.scene), args)
    if scene.instruments:
        raise ConfigError("instruments", "sonarsim live publishes the scene's sonar; a scene of instruments is not "
                          "published live yet (write their bags with sonarsim render --rosbag)")
    trajectory = None
    if args.trajectory is not None:
        from ..dataset.trajectory import read_trajectory

        trajectory = read_trajectory(args.trajectory, key="--trajectory")
    with Simulator(scene, backend=args.backend) as sim, Publisher(args.domain) as publisher:
        _log(f"live: publishing {topics.image} and its companions on DDS domain {publisher.domain}"
             + (f" for {args.frames} frames" if args.frames else ", Ctrl-C to stop"))
        stats = stream(sim, publisher, options, trajectory, say=lambda line: _log(f"live: {line}"))
        _log(f"live: {stats.summary()}")
