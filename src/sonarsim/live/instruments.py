"""Every instrument of a scene, live: each pings at its own rate, in real time, and its pings go
out as ROS 2 topics, the messages its bag would hold (:mod:`sonarsim.io.rosbag_instruments`).

Instrument ``i`` pings every ``T_i`` seconds (its ``ping_period_s``: ``1 / ping_rate_hz``, or
the two-way travel time of its range): ping ``k`` is at ``t = k T_i`` after the start. The pings
of all the instruments are taken in time order (ties: the scene's order). For each one:

1. the vehicle's pose at ``t`` (the scene's vehicle, running ahead at ``vehicle.speed_m_s``; a
   trajectory's, interpolated at its time; or, with a pose topic, the pose at the ping's stamp
   once that time has come, skipped when staler than ``max_staleness_s``);
2. the world at ``t``: objects on tracks at the ping's time on the scene's clock, objects on
   topics at its stamp (as :func:`sonarsim.live.stream.stream` moves them);
3. the ping rendered alone (:func:`~sonarsim.instruments.render_pings` with ``first_ping=k``:
   the same draws, the same scanning head angle, as ping ``k`` of the whole film);
4. published when the wall clock (or ``/clock``) reaches ``t`` after the start (``fast``: at
   once; one that misses its time by more than half its period is counted late), stamped
   ``start + t``: ``/tf`` (world -> vehicle, once per stamp, unless the vehicle's
   pose comes from TF, whose tree already holds it), then the instrument's messages on
   ``/NAME/...`` (sensor QoS), the moving objects' poses on ``/tf``.

Once, before the clock starts: ``/tf_static`` (vehicle -> each mount -> its image frame,
latched) and each instrument's unit on ``/NAME/unit`` (latched). The payloads are what a bag of
the same pings holds, byte for byte (the same message parts, :class:`~sonarsim.io.rosbag_instruments.InstrumentMessages`;
tested against :func:`~sonarsim.io.rosbag_instruments.write_instrument_bag`).
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from ..errors import ConfigError
from .stream import LiveOptions, LiveStats, _move_objects, topic_pose

__all__ = ["instrument_periods", "stream_instruments"]

# The QoS kind of each instrument topic's messages (dds.qos): the unit is latched, the rest are
# sensor data, as a ROS 2 driver publishes them.
_UNIT_KIND, _SENSOR_KIND = "latched", "sensor"


def instrument_periods(scene: Any) -> dict[str, float]:
    """Instrument name -> seconds between its pings (``ping_period_s``), in the scene's order."""
    from ..io.rosbag_instruments import _specs

    return {name: float(spec.ping_period_s()) for name, spec in _specs(scene).items()}


class _Pinger:
    """One instrument's live state: its spec, period, pings done and the message builder's view
    of it (:class:`~sonarsim.io.rosbag_instruments._Instrument` per ping)."""

    def __init__(self, name: str, spec: Any, vehicle_frame: str) -> None:
        from ..io.rosbag_instruments import instrument_topics

        self.name, self.spec = name, spec
        self.kind = spec.type_name
        self.period_s = float(spec.ping_period_s())
        if not np.isfinite(self.period_s) or self.period_s <= 0:
            raise ConfigError(f"instruments.{name}", f"needs a ping period > 0 s, got {self.period_s!r}")
        self.topics = instrument_topics(name, self.kind)
        self.vehicle_frame = vehicle_frame
        self.pings = 0  # pings due so far (published, or skipped for a stale pose)
        self.unit = ""

    def messages(self, builder: Any, film: Any, vehicle: Any, stamp_ns: int) -> tuple[list, Any]:
        """``(ping messages, the instrument's view)`` of a one-ping film."""
        from ..io.rosbag_instruments import _Instrument

        inst = _Instrument(self.name, self.spec, film, self.kind, [vehicle], [int(stamp_ns)], self.vehicle_frame)
        return inst.ping_messages(builder, 0), inst


def stream_instruments(sim: Any, publisher: Any, options: LiveOptions = LiveOptions(), trajectory: Any = None,
                       start_ns: int | None = None, stop: Callable[[], bool] | None = None,
                       say: Callable[[str], None] | None = None, clock: Callable[[], float] = time.monotonic,
                       sleep: Callable[[float], None] = time.sleep, poses: Any = None,
                       now_ns: Callable[[], int] = time.time_ns, object_poses: Mapping[str, Any] | None = None,
                       vehicle_frame: str = "vehicle", vehicle_tf: bool = True) -> LiveStats:
    """Render the scene's instruments ping by ping and publish them in real time (module notes).

    Parameters
    ----------
    sim : Simulator
        A scene with ``instruments`` (or its FLS ``sonar``, as one instrument named ``sonar``).
    publisher : Publisher
        Where the messages go (:class:`sonarsim.live.publisher.Publisher`).
    options : LiveOptions
        ``fast``, ``n_frames`` (pings per instrument; ``None``: the trajectory's span, or until
        stopped), ``speckle``, ``frame_ids`` (its ``world``), ``max_staleness_s``.
    trajectory : Trajectory, optional
        The vehicle's timestamped poses; pings past its end are not made.
    start_ns : int, optional
        The stamp of time 0, ns since the Unix epoch (default ``now_ns()`` as the clock starts).
    stop, say, clock, sleep, now_ns, object_poses
        As :func:`sonarsim.live.stream.stream`'s.
    poses : TopicPoses, optional
        The vehicle's poses from a topic: each ping waits for its time, then takes the pose at
        its stamp; a ping whose newest pose is older than ``options.max_staleness_s`` (or that
        has none yet) is skipped and counted stale.
    vehicle_frame : str
        The vehicle's frame: ``world -> vehicle_frame`` on ``/tf``, the mounts below it.
    vehicle_tf : bool
        Publish ``world -> vehicle_frame`` (``False`` where the vehicle's pose comes from TF).

    Returns
    -------
    LiveStats
        ``frames`` counts pings, of all the instruments.
    """
    from ..instruments import poses_at, render_pings, vehicle_poses
    from ..io import rosbag as rb
    from ..io.rosbag_instruments import InstrumentBagNames, InstrumentMessages, _specs, instrument_typestore

    if poses is not None and trajectory is not None:
        raise ConfigError("--pose-topic", "the poses come from a topic or from a trajectory: give one of the two")
    world = options.frame_ids.world
    names = InstrumentBagNames(world=world, vehicle=vehicle_frame)
    store = instrument_typestore()
    builder = InstrumentMessages(store, options.frame_ids)
    pingers = [_Pinger(name, spec, names.vehicle) for name, spec in _specs(sim).items()]
    t_first = float(trajectory.times_s[0]) if trajectory is not None else 0.0
    t_last = float(trajectory.times_s[-1]) if trajectory is not None else float("inf")
    stats = LiveStats()

    def vehicle_at(pinger: _Pinger, t_scene: float) -> Any:
        if trajectory is not None:
            return poses_at(trajectory, np.array([t_scene]))[0]
        return vehicle_poses(sim, pinger.spec, times_s=np.array([t_scene]))[0][0]

    # Before the clock starts: the writers (discovery begins), one ping of each instrument
    # rendered and serialised (the first call's costs), the static transforms and the units.
    publisher.writer("/tf", "tf2_msgs/msg/TFMessage", "tf")
    views = []
    for p in pingers:
        film = render_pings(sim, p.name, poses=[vehicle_at(p, t_first)], times_s=np.array([t_first]), first_ping=0,
                            speckle=options.speckle)
        msgs, inst = p.messages(builder, film, vehicle_at(p, t_first), 1)
        for topic, ros_type, msg in msgs:
            publisher.writer(topic, ros_type, _SENSOR_KIND)
            store.serialize_cdr(msg, ros_type)
        views.append(inst)
        p.unit = inst.unit
    start_ns = int(now_ns()) if start_ns is None else int(start_ns)
    static = [tf for inst in views for tf in inst.static_transforms(builder, start_ns, names.vehicle)]
    publisher.publish("/tf_static", "tf2_msgs/msg/TFMessage", builder.transforms_message(static), "tf_static")
    for inst in views:
        topic, ros_type, msg = inst.unit_message(builder)
        publisher.publish(topic, ros_type, msg, _UNIT_KIND)
    t_wall0 = clock()
    state = {"stale": False, "objects_said": set(), "warned": False}
    queue = [(0.0, i) for i in range(len(pingers))]  # (time since the start, instrument)
    heapq.heapify(queue)
    last_tf_stamp = None
    n = options.n_frames
    try:
        while queue:
            if stop is not None and stop():
                break
            t, i = heapq.heappop(queue)
            p = pingers[i]
            k = p.pings
            p.pings += 1
            if (n is None or p.pings < n) and t_first + (k + 1) * p.period_s <= t_last + 1e-9:
                heapq.heappush(queue, ((k + 1) * p.period_s, i))
            stamp_ns = start_ns + rb._seconds_ns(repr(t))  # (decimal-exact, as a bag of the film stamps it)
            t_scene = t_first + t
            if poses is not None:
                vehicle = topic_pose(poses, stamp_ns, t_wall0 + t, options, clock, sleep, stats, say, state, "pings")
                if vehicle is None:
                    continue
            else:
                vehicle = vehicle_at(p, t_scene)
            r0 = clock()
            moving = _move_objects(sim, dict(object_poses or {}), stamp_ns, t_scene, options, say, state)
            film = render_pings(sim, p.name, poses=[vehicle], times_s=np.array([t_scene]), first_ping=k,
                                speckle=options.speckle)
            msgs, inst = p.messages(builder, film, vehicle, stamp_ns)
            stats.render_s.append(clock() - r0)
            if not options.fast and poses is None:
                wait = t_wall0 + t - clock()
                if wait > 0:
                    sleep(wait)
                elif -wait > p.period_s / 2:  # it missed its slot (pings due together wait their turn)
                    stats.late += 1
            p0 = clock()
            if vehicle_tf and stamp_ns != last_tf_stamp:  # one world -> vehicle per stamp
                publisher.publish("/tf", "tf2_msgs/msg/TFMessage", builder.transforms_message(
                    [builder.transform(stamp_ns, names.world, names.vehicle, vehicle.position_m, vehicle.quat_xyzw)]),
                    "tf")
                last_tf_stamp = stamp_ns
            for topic, ros_type, msg in msgs:
                publisher.publish(topic, ros_type, msg, _SENSOR_KIND)
            if inst.unit != p.unit:  # (a film whose unit changed: said again, latched)
                p.unit = inst.unit
                topic, ros_type, msg = inst.unit_message(builder)
                publisher.publish(topic, ros_type, msg, _UNIT_KIND)
            if moving:  # the moving objects' poses: ground truth on /tf, world -> each object
                publisher.publish("/tf", "tf2_msgs/msg/TFMessage", builder.objects_tf(stamp_ns, moving), "tf")
            stats.publish_s.append(clock() - p0)
            stats.frames += 1
            stats.pings[p.name] = stats.pings.get(p.name, 0) + 1
            if say is not None and not state["warned"] and clock() - t_wall0 > 2.0:
                state["warned"] = True
                quiet = [p.topics[next(iter(p.topics))] for p in pingers
                         if publisher.subscribers(p.topics[next(iter(p.topics))]) == 0]
                if quiet:
                    say(f"no subscriber on {', '.join(quiet)} yet (ROS_DOMAIN_ID {publisher.domain}); "
                        "publishing anyway")
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM: stop between or inside pings, say so
        stats.interrupted = True
    stats.wall_s = clock() - t_wall0
    return stats
