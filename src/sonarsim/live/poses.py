"""Poses in: the vehicle's pose from a ROS 2 topic, at each frame's own time (issue 40 item 2).

:class:`TopicPoses` reads ``nav_msgs/Odometry`` or ``geometry_msgs/PoseStamped`` from a topic
(any QoS a simulator publishes with: the reader is best effort, which matches both reliable and
best-effort writers), keeps the most recent :data:`KEEP` poses by their header stamps, and
gives the pose at a time: interpolated between the two poses around it (positions linearly,
orientations by slerp: :func:`sonarsim.instruments.poses_at`), or the newest one and how old it
is when the time lies beyond it. ``sonarsim live`` skips a frame whose pose is older than its
bound (``--max-staleness``) and says so, rather than render the vehicle where it no longer is.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.transforms import Pose
from ..errors import ConfigError
from . import dds

__all__ = ["POSE_TYPES", "KEEP", "TopicPoses"]

#: The message types a pose topic may carry (``--pose-type``); ``tf``: a named frame's
#: transform on ``/tf`` (``tf2_msgs/TFMessage``), from the world frame.
POSE_TYPES = {"odometry": "nav_msgs/msg/Odometry", "pose_stamped": "geometry_msgs/msg/PoseStamped",
              "tf": "tf2_msgs/msg/TFMessage"}
#: How many of the newest poses are kept for interpolation.
KEEP = 512


class TopicPoses:
    """The poses a ROS 2 topic brings, by their stamps.

    Parameters
    ----------
    participant : cyclonedds DomainParticipant
        Where to read (:attr:`sonarsim.live.publisher.Publisher.participant`).
    topic : str
        A ROS 2 topic name (``/odom``).
    kind : {'odometry', 'pose_stamped', 'tf'}
    frame : str, optional
        With ``tf``: the frame whose transform from ``world`` (its parent) is the pose, e.g.
        ``base_link`` as a simulator's ground truth publishes it on ``/tf``.
    world : str
        With ``tf``: the world frame's id (transforms from other parents are not poses in it).
    """

    def __init__(self, participant: Any, topic: str, kind: str = "odometry", frame: str | None = None,
                 world: str = "map") -> None:
        if kind not in POSE_TYPES:
            raise ConfigError("--pose-type", f"must be one of {', '.join(POSE_TYPES)}, got {kind!r}")
        if (kind == "tf") != (frame is not None):
            raise ConfigError("--pose-frame", "a pose from TF names its frame (and only then)")
        self.frame, self.world = frame, world
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        from cyclonedds.qos import Policy, Qos

        self.topic, self.kind = (topic if kind != "tf" else f"/tf ({frame})"), kind
        # (a best-effort reader matches reliable writers too; keep more than a frame's worth)
        q = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(64), Policy.Durability.Volatile)
        name = dds.dds_topic(topic if kind != "tf" else "/tf")
        # A topic's QoS must agree within a participant: /tf's is the one its writer (sonarsim
        # live's own, in the same participant) gives it; the reader stays best effort.
        topic_qos = dds.qos("tf") if kind == "tf" else q
        self._reader = DataReader(participant, Topic(participant, name, dds.dds_type(POSE_TYPES[kind]), qos=topic_qos),
                                  qos=q)
        self.times_ns = np.empty(0, np.int64)
        self.positions = np.empty((0, 3))
        self.quats = np.empty((0, 4))
        self.received = 0

    def add(self, stamp_ns: int, position: tuple, quat_xyzw: tuple) -> None:
        """Keep one pose (in stamp order; a stamp already held replaces nothing)."""
        if np.any(self.times_ns == stamp_ns):
            return
        q = np.asarray(quat_xyzw, float)
        norm = float(np.linalg.norm(q))
        if not np.all(np.isfinite(position)) or not np.isfinite(norm) or norm < 1e-6:
            return  # (a pose with NaN or a zero quaternion says nothing)
        k = int(np.searchsorted(self.times_ns, stamp_ns))
        self.times_ns = np.insert(self.times_ns, k, stamp_ns)[-KEEP:]
        self.positions = np.insert(self.positions, k, np.asarray(position, float), axis=0)[-KEEP:]
        self.quats = np.insert(self.quats, k, q / norm, axis=0)[-KEEP:]
        self.received += 1

    def poll(self) -> int:
        """Take what has arrived; returns how many poses."""
        n = 0
        for s in self._reader.take(N=256):
            if self.kind == "tf":
                for t in getattr(s, "transforms", ()):
                    if t.child_frame_id == self.frame and t.header.frame_id.lstrip("/") == self.world.lstrip("/"):
                        tr, q = t.transform.translation, t.transform.rotation
                        self.add(int(t.header.stamp.sec) * 1_000_000_000 + int(t.header.stamp.nanosec),
                                 (tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w))
                        n += 1
                continue
            if not hasattr(s, "header"):
                continue  # (a writer that went away)
            p = s.pose.pose if self.kind == "odometry" else s.pose
            self.add(int(s.header.stamp.sec) * 1_000_000_000 + int(s.header.stamp.nanosec),
                     (p.position.x, p.position.y, p.position.z),
                     (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
            n += 1
        return n

    def pose_at(self, t_ns: int) -> tuple[Pose | None, float]:
        """``(pose, staleness_s)`` at ``t_ns``: interpolated within the poses held (staleness 0),
        the newest beyond them (staleness: how much older it is), the oldest before them; ``(None,
        inf)`` before any pose arrived."""
        self.poll()
        if not len(self.times_ns):
            return None, float("inf")
        from ..dataset.trajectory import Trajectory
        from ..instruments import poses_at

        newest = int(self.times_ns[-1])
        if len(self.times_ns) == 1 or t_ns >= newest:
            k = len(self.times_ns) - 1
            return Pose.from_quaternion(tuple(self.positions[k]), tuple(self.quats[k])), max(0.0, (t_ns - newest) / 1e9)
        base = self.times_ns[0]
        track = Trajectory((self.times_ns - base) / 1e9, self.positions, self.quats)
        return poses_at(track, np.array([(t_ns - base) / 1e9]))[0], 0.0
