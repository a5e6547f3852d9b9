"""Render and publish, frame after frame, in real time: the loop of ``sonarsim live``.

Each frame ``k`` has a time ``t_k`` (``k / rate_hz``, or a trajectory's own times) and a pose
(the trajectory's at ``t_k``, or the scene's); it is rendered (:meth:`Simulator.render` with
``frame=k``: the same draws whoever renders it), then published when the wall clock reaches
``t_k`` after the start (``fast``: at once), stamped ``start + t_k`` in the wall clock's time, as
a ROS 2 sensor driver stamps its data. A frame whose render ends after its time is published at
once and counted late; the loop never sleeps while behind and never spins while ahead.

Per frame, on the topics of :class:`~sonarsim.io.rosbag.BagTopics` (as a bag holds them:
:class:`~sonarsim.io.rosbag.FrameMessages`): the ``ProjectedSonarImage``, the fan
(``sensor_msgs/Image``, ``mono8`` as ``fan.png`` draws it, unless ``fan=False``), the pose (``PoseStamped``), ``/tf`` (world ->
sonar) and the image's unit (latched, with the first frame and whenever it changes); once, at
the start, ``/tf_static`` (sonar -> sonar_image, latched). With ``points``, the frame's labelled
points too (``PointCloud2``, world frame, each point's surface id) and, once, the ids' names.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..core.transforms import Pose
from ..io.rosbag import MSGTYPES, BagFrameIds, BagTopics, frame_from_image
from ..io.rosbag_instruments import InstrumentMessages

__all__ = ["LiveOptions", "LiveStats", "stream", "MAX_RATE_HZ", "points_ids_topic"]

#: The highest frame rate ``rate_hz`` takes (frames a second).
MAX_RATE_HZ = 1000.0
# The QoS kind of each topic of a frame (dds.qos).
_KINDS = {"tf": "tf", "unit": "latched"}


@dataclass(frozen=True)
class LiveOptions:
    """What ``sonarsim live`` publishes, and when.

    Attributes
    ----------
    rate_hz : float
        Frames a second, in (0, :data:`MAX_RATE_HZ`]; with a trajectory, it is resampled at
        this rate (``None``: the trajectory's own times; without one, 10 Hz).
    fast : bool
        Publish each frame as soon as it is rendered (stamps still ``t_k`` apart).
    n_frames : int or None
        Stop after this many frames (``None``: the trajectory's, or until stopped).
    fan : bool
        Publish the fan image too.
    speckle : bool or None
        As :meth:`Simulator.render`'s (``False``: the expected image).
    frame_ids, topics : BagFrameIds, BagTopics
    max_staleness_s : float
        With poses from a topic: the oldest a frame's pose may be, seconds, in (0, 60].
    points : bool
        Publish each frame's ground truth: the points in view (``PointCloud2``: x, y, z in the
        world frame and ``object``, the id of the surface hit), from the frame's labels, and once,
        latched, the names of the ids (``std_msgs/String``, JSON, on the points' topic + ``/ids``).
    """

    rate_hz: float | None = None
    fast: bool = False
    n_frames: int | None = None
    fan: bool = True
    speckle: bool | None = None
    frame_ids: BagFrameIds = field(default_factory=BagFrameIds)
    topics: BagTopics = field(default_factory=BagTopics)
    max_staleness_s: float = 0.5
    points: bool = False

    def __post_init__(self) -> None:
        m = self.max_staleness_s
        if isinstance(m, bool) or not isinstance(m, (int, float)) or not math.isfinite(m) or not 0.0 < m <= 60.0:
            raise ConfigError("max_staleness_s", f"must be a number of seconds in (0, 60], got {m!r}")
        if self.rate_hz is not None:
            r = self.rate_hz
            if isinstance(r, bool) or not isinstance(r, (int, float)) or not math.isfinite(r) \
                    or not 0.0 < r <= MAX_RATE_HZ:
                raise ConfigError("rate_hz", f"must be a number of frames a second in (0, {MAX_RATE_HZ:g}], got {r!r}")
        n = self.n_frames
        if n is not None and (isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1):
            raise ConfigError("n_frames", f"must be a whole number of at least 1, got {n!r}")


@dataclass
class LiveStats:
    """What a :func:`stream` did: frames published, those late, and per-frame seconds (of
    :func:`~sonarsim.live.instruments.stream_instruments`: pings, of all the instruments)."""

    frames: int = 0
    late: int = 0
    stale: int = 0
    render_s: list[float] = field(default_factory=list)
    publish_s: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    interrupted: bool = False
    #: Pings published per instrument (:func:`sonarsim.live.instruments.stream_instruments`).
    pings: dict[str, int] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: frames, rate held, late frames, render and publish times (median)."""
        if not self.frames:
            return "no frame published"
        med = lambda x: 1e3 * float(np.median(x))  # noqa: E731
        rate = self.frames / self.wall_s if self.wall_s > 0 else float("inf")
        return (("stopped by a signal after " if self.interrupted else "") + f"{self.frames} frames in {self.wall_s:.2f} s ({rate:.1f} frames/s), {self.late} late"
                + (f", {self.stale} skipped for a stale pose" if self.stale else "") + "; render "
                f"{med(self.render_s):.1f} ms, publish {med(self.publish_s):.1f} ms a frame (median)")


def stream(sim: Any, publisher: Any, options: LiveOptions = LiveOptions(), trajectory: Any = None,
           start_ns: int | None = None, stop: Callable[[], bool] | None = None,
           say: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic,
           sleep: Callable[[float], None] = time.sleep, poses: Any = None, mount: Any = None,
           now_ns: Callable[[], int] = time.time_ns, object_poses: Mapping[str, Any] | None = None,
           vehicle_frame: str = "vehicle", vehicle_tf: bool = True) -> LiveStats:
    """Render ``sim``'s frames and publish them in real time (module notes).

    Parameters
    ----------
    sim : Simulator
    publisher : Publisher
        Where the messages go (:class:`sonarsim.live.publisher.Publisher`).
    options : LiveOptions
    trajectory : Trajectory, optional
        The sonar's timestamped poses (:func:`sonarsim.dataset.trajectory.read_trajectory`);
        default the scene's pose at every frame.
    start_ns : int, optional
        The first frame's stamp, ns since the Unix epoch (default: ``now_ns()`` as the clock
        starts, after the warm-up).
    stop : callable, optional
        Asked before each frame; ``True`` ends the stream.
    say : callable, optional
        Called with a line when nothing subscribes to the image two seconds after the start.
    clock, sleep, now_ns : callables
        Monotonic seconds, a sleep, and the time frames are stamped in, ns (the wall clock's;
        :class:`sonarsim.live.simclock.SimClock`'s simulated time with ``--use-sim-time``).
    poses : TopicPoses, optional
        The vehicle's poses from a topic (:class:`sonarsim.live.poses.TopicPoses`): each frame
        waits for its time, then takes the pose at its stamp; a frame whose newest pose is older
        than ``options.max_staleness_s`` (or that has none yet) is skipped and counted stale.
    mount : Pose, optional
        The sonar on the vehicle (with ``poses``): the sonar's pose is the vehicle's composed
        with it (default: the vehicle's own frame).
    vehicle_frame : str
        With ``poses``: the vehicle's frame. The TF tree is then world -> ``vehicle_frame`` on
        ``/tf`` per frame, and ``vehicle_frame`` -> sonar (the mount) -> sonar_image on
        ``/tf_static``; without ``poses``, world -> sonar per frame.
    vehicle_tf : bool
        Publish world -> ``vehicle_frame`` (``False`` where the vehicle's pose comes from TF,
        whose tree already holds it).
    object_poses : mapping of str to TopicPoses, optional
        Objects of the scene driven by topics (another vehicle, a diver): each frame moves them
        to their poses at its stamp (:meth:`Simulator.move_objects`). Objects with a ``track``
        move by it, at the frame's time on the scene's clock (the trajectory's time, else the
        seconds since the first frame). Every moving object's pose goes out on ``/tf``
        (world -> its name) with the frame.

    Returns
    -------
    LiveStats
    """
    from ..io.rosbag_instruments import instrument_typestore

    if trajectory is not None and options.rate_hz is not None:
        trajectory = trajectory.resampled(options.rate_hz, key="--rate")
    rate = options.rate_hz if options.rate_hz is not None else 10.0
    n = options.n_frames
    if trajectory is not None:
        n = trajectory.n_frames if n is None else min(n, trajectory.n_frames)
    messages = InstrumentMessages(instrument_typestore(), options.frame_ids)  # (cached: built once)
    stats = LiveStats()
    # Before the clock starts: the writers (discovery begins, so the first frames reach the
    # subscribers already there) and one render and serialisation (the first call's costs:
    # tables, message classes), so that frame 0 is as late as any other.
    for key, ros_type in MSGTYPES.items():
        if (key != "points" or options.points) and (key != "fan" or options.fan):
            publisher.writer(getattr(options.topics, key), ros_type, _KINDS.get(key, "sensor"))
    first = sim.render(pose=trajectory.pose(0) if trajectory is not None else None, frame=0, speckle=options.speckle,
                       labels="total" if options.points else False)
    warm = _frame(first, 1, options)
    store = instrument_typestore()
    for key, msg in messages.frame_messages(warm, tf="pose"):
        store.serialize_cdr(msg, MSGTYPES[key])
    start_ns = int(now_ns()) if start_ns is None else int(start_ns)
    t_wall0 = clock()
    if poses is not None and trajectory is not None:
        raise ConfigError("--pose-topic", "the poses come from a topic or from a trajectory: give one of the two")
    state = {"warned": False, "last_unit": "", "stale": False, "objects_said": set()}
    try:
        _loop(sim, publisher, options, trajectory, messages, stats, n, rate, start_ns, t_wall0, stop, say, clock,
              sleep, state, poses, mount, dict(object_poses or {}), (vehicle_frame, vehicle_tf))
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM: stop between or inside frames, say so
        stats.interrupted = True
    stats.wall_s = clock() - t_wall0
    return stats


def points_ids_topic(topics: BagTopics) -> str:
    """The latched topic naming the ids of the points' ``object`` field: the points' + ``/ids``."""
    return topics.points.rstrip("/") + "/ids"


def _frame(image: Any, stamp_ns: int, options: LiveOptions) -> Any:
    """The BagFrame of a rendered frame: its fan as drawn (unless ``fan`` is off), its labels'
    points (with ``points``)."""
    points = {}
    if options.points:
        points = {"points_world": image.labels.points_world, "points_object": image.labels.points_object}
    return frame_from_image(image, stamp_ns, fan=_fan_levels(image) if options.fan else False, **points)


def _fan_levels(image: Any) -> np.ndarray:
    """The fan as ``sonarsim render`` draws ``fan.png``: 8-bit levels (``mono8``), a device's
    counts where a sensor model makes them, a render's 40 dB below its maximum otherwise: an
    image a viewer shows as it is, where a float fan (``32FC1``) needs a range set by hand."""
    from ..image.levels import default_fan_levels

    return default_fan_levels(image)


def topic_pose(poses: Any, stamp_ns: int, due_s: float, options: LiveOptions, clock: Callable[[], float],
               sleep: Callable[[float], None], stats: LiveStats, say: Callable[[str], None] | None, state: dict,
               what: str) -> Any:
    """The vehicle's pose at a frame's (or ping's) stamp from its topic, taken once that time
    has come (``due_s`` on ``clock``; at once with ``fast``): the pose at a moment is known only
    after it. ``None`` where there is none yet or the newest is staler than
    ``options.max_staleness_s``: counted in ``stats.stale`` and said once per stale spell
    (``what``: "frames" or "pings")."""
    if not options.fast:
        wait = due_s - clock()
        if wait > 0:
            sleep(wait)
    pose, stale_s = poses.pose_at(stamp_ns)
    if pose is None or stale_s > options.max_staleness_s:
        stats.stale += 1
        if say is not None and not state["stale"]:
            say(f"no pose on {poses.topic} yet: {what} wait for one" if pose is None else
                f"the newest pose on {poses.topic} is {stale_s:.2f} s old, more than --max-staleness "
                f"{options.max_staleness_s:g} s: {what} are skipped until poses come again")
        state["stale"] = True
        return None
    state["stale"] = False
    return pose


def _move_objects(sim, object_poses: dict, stamp_ns: int, t_scene: float, options, say, state) -> dict:
    """The world at a frame's time: objects on tracks at ``t_scene`` (the scene's clock), objects
    on topics at ``stamp_ns`` (interpolated; one that has no pose yet stays where it is, one
    whose newest pose is staler than the bound keeps it; each said once). Returns the moving
    objects' poses now (for ``/tf``)."""
    sim.at_time(t_scene)
    found = {}
    for name, source in object_poses.items():
        pose, stale_s = source.pose_at(stamp_ns)
        if pose is None or stale_s > options.max_staleness_s:
            key = (name, pose is None)
            if say is not None and key not in state["objects_said"]:
                state["objects_said"].add(key)
                say(f"no pose for the object {name!r} on {source.topic} yet: it stays where the scene puts it"
                    if pose is None else f"the newest pose of the object {name!r} on {source.topic} is {stale_s:.2f} s "
                    f"old (more than --max-staleness {options.max_staleness_s:g} s): it is held there")
            if pose is None:
                continue
        found[name] = pose
    if found:
        sim.move_objects(found)
    moving = set(sim.tracked) | set(object_poses)
    return {o.name: o.pose for o in sim.scene.objects if o.name in moving}


def _loop(sim, publisher, options, trajectory, messages, stats, n, rate, start_ns, t_wall0, stop, say, clock, sleep,
          state, poses, mount, object_poses, vehicle) -> None:
    topics = options.topics
    vehicle_frame, vehicle_tf = vehicle
    ids = options.frame_ids
    mount_pose = mount if mount is not None else Pose()
    t_first = trajectory.time_s(0) if trajectory is not None else 0.0
    k = 0
    while n is None or k < n:
        if stop is not None and stop():
            break
        if trajectory is not None:
            t_k, pose = trajectory.time_s(k) - t_first, trajectory.pose(k)
        else:
            t_k, pose = k / rate, None
        stamp_ns = start_ns + round(t_k * 1e9)
        if poses is not None:
            pose = topic_pose(poses, stamp_ns, t_wall0 + t_k, options, clock, sleep, stats, say, state, "frames")
            if pose is None:
                k += 1
                continue
            vehicle_pose = pose
            pose = pose.compose(mount_pose)
        r0 = clock()
        moving = _move_objects(sim, object_poses, stamp_ns, t_first + t_k, options, say, state)
        image = sim.render(pose=pose, frame=k, speckle=options.speckle, labels="total" if options.points else False)
        frame = _frame(image, stamp_ns, options)
        batch = messages.frame_messages(frame, state["last_unit"], tf="pose")
        if poses is not None:  # the tree: world -> vehicle per frame, the mount static below it
            batch = [(key, msg) for key, msg in batch if key != "tf"]
            if vehicle_tf:
                batch.append(("tf", messages.transforms_message([messages.transform(
                    stamp_ns, ids.world, vehicle_frame, vehicle_pose.position_m, vehicle_pose.quat_xyzw)])))
        r1 = clock()
        stats.render_s.append(r1 - r0)
        if k == 0:
            static = messages.tf_message(frame, "image")
            if poses is not None:
                static = messages.transforms_message([messages.transform(stamp_ns, vehicle_frame, ids.sonar, mount_pose.position_m,
                                                                 mount_pose.quat_xyzw), *static.transforms])
            publisher.publish("/tf_static", "tf2_msgs/msg/TFMessage", static, "tf_static")
            if options.points:  # what the points' ids name, once (latched)
                publisher.publish(points_ids_topic(topics), MSGTYPES["unit"],
                                  messages._types["std_msgs/msg/String"](data=json.dumps(list(image.labels.ids))),
                                  "latched")
        if not options.fast and poses is None:
            wait = t_wall0 + t_k - clock()
            if wait > 0:
                sleep(wait)
            elif k > 0:
                stats.late += 1
        p0 = clock()
        for key, msg in batch:
            publisher.publish(getattr(topics, key), MSGTYPES[key], msg, _KINDS.get(key, "sensor"))
        if moving:  # the moving objects' poses: ground truth on /tf, world -> each object
            publisher.publish(topics.tf, MSGTYPES["tf"], messages.objects_tf(stamp_ns, moving), _KINDS.get("tf", "sensor"))
        stats.publish_s.append(clock() - p0)
        state["last_unit"] = frame.unit or state["last_unit"]
        stats.frames += 1
        k += 1
        if say is not None and not state["warned"] and clock() - t_wall0 > 2.0:
            state["warned"] = True
            if publisher.subscribers(topics.image) == 0:
                say(f"no subscriber on {topics.image} yet (ROS_DOMAIN_ID {publisher.domain}); publishing anyway")
