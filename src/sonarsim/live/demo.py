"""The live demo (``sonarsim live-demo``): a vehicle driven by a scripted pose publisher past
the demo tank's objects, ``sonarsim live`` rendering and publishing, and a recorder writing what
it received into a ROS 2 bag.

Three parts on the loopback, as on a robot:

- :class:`ScriptedVehicle` stands in for a simulator (Gazebo, Stonefish, HoloOcean's bridge):
  the vehicle's ``geometry_msgs/PoseStamped`` at 50 Hz on :data:`POSE_TOPIC`, stamped by the
  wall clock, running along x past the tank's objects with a slow yaw sway;
- ``sonarsim live`` (its own process) renders :func:`demo_scene` (the tank, its buoy
  patrolling across the fan on a ``track``) at the pose of each frame's time, the sonar on its
  mount pitched 20 degrees down, and publishes the image, the fan, the pose and ``/tf``;
- :class:`Recorder` subscribes to :data:`RECORDED` with each topic's QoS and writes every
  sample's CDR as it arrived (``ros2 bag record``'s way) into a bag
  (:meth:`~sonarsim.io.rosbag.BagWriter.write_cdr`), stamped with its arrival time.

The vehicle and the recorder each hold their own DDS participant, in the demo's process; a ROS 2
user replaces the first with a simulator and the second with ``ros2 bag record``
(``docs/ros2.md``). :func:`read_back` reads the bag with ``rosbags``: what a user's tools see.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SonarsimError

__all__ = ["MOUNT", "POSE_TOPIC", "RECORDED", "Recorder", "ScriptedVehicle", "demo_scene", "read_back",
           "vehicle_pose_at"]

#: The scripted vehicle's pose topic.
POSE_TOPIC = "/demo/vehicle/pose"
#: What the recorder keeps: topic -> (ROS 2 type, QoS kind of :func:`~sonarsim.live.dds.qos`).
RECORDED: dict[str, tuple[str, str]] = {
    "/sonar/image": ("marine_acoustic_msgs/msg/ProjectedSonarImage", "sensor"),
    "/sonar/fan": ("sensor_msgs/msg/Image", "sensor"),
    "/sonar/pose": ("geometry_msgs/msg/PoseStamped", "sensor"),
    "/tf": ("tf2_msgs/msg/TFMessage", "tf"),
    "/tf_static": ("tf2_msgs/msg/TFMessage", "tf_static"),
    "/sonar/image/unit": ("std_msgs/msg/String", "latched"),
    POSE_TOPIC: ("geometry_msgs/msg/PoseStamped", "tf"),
}
#: The vehicle's run: from x = START_X_M at SPEED_M_S, HEIGHT_M above the floor, its yaw swaying
#: by YAW_SWAY_DEG over SWAY_PERIOD_S.
START_X_M, SPEED_M_S, HEIGHT_M, YAW_SWAY_DEG, SWAY_PERIOD_S = -0.6, 0.25, 1.0, 6.0, 8.0
#: The sonar on the vehicle (``sonarsim live --mount``): at its origin, pitched 20 degrees down.
MOUNT = "0,0,0,0,20,0"
#: The buoy's patrol across the fan: y from -0.4 m to +0.8 m and back in PATROL_S seconds.
PATROL_S = 6.0


def demo_scene() -> dict:
    """The demo tank in scene-file form, lighter for the wire (the ARIS 3000's 128 beams over
    0.7-5 m in 500 bins rather than 1288), its buoy patrolling across the fan on a track
    (repeating every :data:`PATROL_S`).

    (The 64-beam preset is the ARIS's long-range mode, 5-20 m: it would see nothing of a tank
    floor lit from 2.2 m to 4.4 m.)"""
    from ..config.examples import demo_scene_dict

    doc = demo_scene_dict()
    doc["sonar"] = {**doc["sonar"], "n_range_bins": 500}
    doc["render"] = {**doc["render"], "bounces": [1, 2]}
    for o in doc["objects"]:
        if o["name"] == "buoy":
            x, _, z = o.pop("pose")["position_m"]
            o["track"] = {"keys": [{"t": 0.0, "position_m": [x, -0.4, z]},
                                   {"t": PATROL_S / 2, "position_m": [x, 0.8, z]},
                                   {"t": PATROL_S, "position_m": [x, -0.4, z]}], "repeat": True}
    return doc


def vehicle_pose_at(t_s: float) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """The scripted vehicle ``t_s`` seconds after it started: position (m, world frame) and
    orientation (quaternion x, y, z, w; REP-103: yaw about z up)."""
    yaw = math.radians(YAW_SWAY_DEG) * math.sin(2 * math.pi * t_s / SWAY_PERIOD_S)
    return (START_X_M + SPEED_M_S * t_s, 0.0, HEIGHT_M), (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


class _Worker:
    """A thread with a stop flag; :meth:`stop` ends it and re-raises what it raised."""

    def __init__(self, name: str) -> None:
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)

    def start(self) -> Any:
        self._thread.start()
        return self

    def _main(self) -> None:
        try:
            self.run(self._stop)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller by stop()
            self._error = exc

    def run(self, stop: threading.Event) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout_s)
        if self._error is not None:
            raise self._error


class ScriptedVehicle(_Worker):
    """Publish :func:`vehicle_pose_at` on :data:`POSE_TOPIC` at ``rate_hz`` until stopped,
    stamped by the wall clock (``t = 0`` at :meth:`start`), as a simulator's odometry.

    Parameters
    ----------
    domain : int
        The DDS domain.
    rate_hz : float
        Poses a second.
    """

    def __init__(self, domain: int, rate_hz: float = 50.0) -> None:
        super().__init__("sonarsim-demo-vehicle")
        from .publisher import Publisher

        self._publisher = Publisher(domain)
        self.rate_hz = float(rate_hz)
        self.sent = 0
        self.t0_ns = 0

    def run(self, stop: threading.Event) -> None:
        from .dds import _typestore

        T = _typestore().types
        ros_type = RECORDED[POSE_TOPIC][0]
        self.t0_ns = time.time_ns()
        try:
            while not stop.is_set():
                now = time.time_ns()
                (x, y, z), (qx, qy, qz, qw) = vehicle_pose_at((now - self.t0_ns) / 1e9)
                msg = T[ros_type](
                    header=T["std_msgs/msg/Header"](
                        stamp=T["builtin_interfaces/msg/Time"](sec=now // 10**9, nanosec=now % 10**9), frame_id="world"),
                    pose=T["geometry_msgs/msg/Pose"](
                        position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
                        orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))
                self._publisher.publish(POSE_TOPIC, ros_type, msg, kind=RECORDED[POSE_TOPIC][1])
                self.sent += 1
                stop.wait(1.0 / self.rate_hz)
        finally:
            self._publisher.close()


class Recorder(_Worker):
    """Subscribe to :data:`RECORDED` and write each sample into the open ``bag`` as it arrived.

    Parameters
    ----------
    domain : int
        The DDS domain.
    bag : sonarsim.io.rosbag.BagWriter
        Open; the recorder writes into it from its thread until :meth:`stop`.
    poll_s : float
        How long the thread sleeps between takes (seconds).
    """

    def __init__(self, domain: int, bag: Any, poll_s: float = 0.005) -> None:
        super().__init__("sonarsim-demo-recorder")
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from . import dds

        self._bag, self.poll_s = bag, poll_s
        self._participant = DomainParticipant(domain)
        self._readers = {}
        for topic, (ros_type, kind) in RECORDED.items():
            q = dds.qos(kind)
            self._readers[topic] = DataReader(
                self._participant, Topic(self._participant, dds.dds_topic(topic), dds.raw_type(ros_type), qos=q), qos=q)
        self.counts = {topic: 0 for topic in RECORDED}

    def _take(self) -> None:
        from .dds import RawSample

        for topic, reader in self._readers.items():
            for sample in reader.take(N=64):
                if isinstance(sample, RawSample):  # (not a writer's disposal)
                    self._bag.write_cdr(topic, RECORDED[topic][0], time.time_ns(), sample.cdr)
                    self.counts[topic] += 1

    def run(self, stop: threading.Event) -> None:
        while not stop.wait(self.poll_s):
            self._take()
        self._take()

    def matched(self, topic: str) -> int:
        """How many writers of ``topic`` the recorder's reader is matched with now."""
        return int(self._readers[topic].get_subscription_matched_status().current_count)


def read_back(bag: str | Path) -> dict[str, Any]:
    """What ``rosbags`` reads of a recorded bag.

    Returns
    -------
    dict
        ``messages`` (topic -> count), ``vehicle`` and ``sonar`` (lists of (stamp ns, x m, y m,
        yaw deg) from :data:`POSE_TOPIC` and ``/sonar/pose``), ``buoy`` (list of (stamp ns, y m)
        from ``/tf``), ``images`` (list of (stamp ns, beams, bins)), ``fans`` (list of (stamp ns,
        uint8 array of shape (height, width))) and ``frame_ids`` (topic -> set of ``header.frame_id``).
    """
    from rosbags.rosbag2 import Reader

    from ..io.rosbag_instruments import instrument_typestore

    def stamp(header: Any) -> int:
        return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)

    def pose_row(msg: Any) -> tuple[int, float, float, float]:
        q = msg.pose.orientation
        yaw = math.degrees(math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z)))
        return stamp(msg.header), float(msg.pose.position.x), float(msg.pose.position.y), yaw

    store = instrument_typestore()
    out: dict[str, Any] = {"messages": {}, "vehicle": [], "sonar": [], "buoy": [], "images": [], "fans": [],
                           "frame_ids": {}}
    try:
        reader_cm = Reader(bag)
    except Exception as exc:  # noqa: BLE001 - rosbags' own errors, said with the path
        raise SonarsimError(f"{bag}: not a readable ROS 2 bag: {exc}") from None
    with reader_cm as reader:
        for connection, _, raw in reader.messages():
            topic = connection.topic
            out["messages"][topic] = out["messages"].get(topic, 0) + 1
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if hasattr(msg, "header"):
                out["frame_ids"].setdefault(topic, set()).add(msg.header.frame_id)
            if topic == POSE_TOPIC:
                out["vehicle"].append(pose_row(msg))
            elif topic == "/sonar/pose":
                out["sonar"].append(pose_row(msg))
            elif topic == "/tf":
                out["buoy"] += [(stamp(t.header), float(t.transform.translation.y)) for t in msg.transforms
                                if t.child_frame_id == "buoy"]
            elif topic == "/sonar/image":
                out["images"].append((stamp(msg.header), len(msg.beam_directions), len(msg.ranges)))
            elif topic == "/sonar/fan":
                fan = np.frombuffer(bytes(msg.data), np.uint8).reshape(int(msg.height), int(msg.step))
                out["fans"].append((stamp(msg.header), fan[:, : int(msg.width)]))
    return out


def wait_for(condition: Callable[[], bool], timeout_s: float, poll_s: float = 0.05) -> bool:
    """Poll ``condition`` until it holds or ``timeout_s`` passes; whether it held."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(poll_s)
    return bool(condition())
