"""Poses in (issue 40 item 2): the vehicle's pose from a topic, at each frame's own time."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from sonarsim.core.transforms import Pose  # noqa: E402
from sonarsim.live.stream import LiveOptions, stream  # noqa: E402

from .receive import receive  # noqa: E402
from .test_live import SCENE, _Recorder  # noqa: E402


@pytest.fixture(scope="module")
def participant():
    from cyclonedds.domain import DomainParticipant

    return DomainParticipant(201)


def test_poses_are_interpolated_at_a_frame_time_and_their_age_said_beyond(participant):
    from sonarsim.live.poses import TopicPoses

    src = TopicPoses(participant, "/test/odom", "odometry")
    assert src.pose_at(0) == (None, math.inf)
    yaw90 = (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5))
    src.add(2_000_000_000, (1.0, 0.0, -2.0), yaw90)  # out of order: kept in stamp order
    src.add(1_000_000_000, (0.0, 0.0, -2.0), (0.0, 0.0, 0.0, 1.0))
    src.add(1_500_000_000, (float("nan"), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))  # says nothing: ignored
    src.add(1_600_000_000, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))  # a zero quaternion: ignored
    assert list(src.times_ns) == [1_000_000_000, 2_000_000_000]
    pose, stale = src.pose_at(1_250_000_000)
    assert stale == 0.0
    assert pose.position_m == pytest.approx((0.25, 0.0, -2.0))
    assert pose.rpy_deg == pytest.approx((0.0, 0.0, 22.5))  # slerp: a quarter of the 90-degree turn
    pose, stale = src.pose_at(2_300_000_000)
    assert stale == pytest.approx(0.3) and pose.position_m == pytest.approx((1.0, 0.0, -2.0))
    assert pose.rpy_deg == pytest.approx((0.0, 0.0, 90.0))


START_NS = 1_000_000_000


class _Poses:
    """A stand-in pose source: x = 1 m/s since 0, the newest pose at ``newest_s``."""

    topic = "/odom"

    def __init__(self, newest_s):
        self.newest_s = newest_s

    def pose_at(self, t_ns):
        t = (t_ns - START_NS) / 1e9
        if t > self.newest_s:
            return Pose((self.newest_s, 0.0, 1.0)), t - self.newest_s
        return Pose((t, 0.0, 1.0)), 0.0


def test_frames_take_the_pose_at_their_stamp_through_the_mount_and_skip_stale_ones():
    import sonarsim

    now = [0.0]

    def clock():
        return now[0]

    def sleep(s):
        now[0] += s

    rec, said = _Recorder(), []
    mount = Pose((0.5, 0.0, -0.2), (0.0, 30.0, 0.0))
    with sonarsim.Simulator(SCENE) as sim:
        stats = stream(sim, rec, LiveOptions(rate_hz=10.0, n_frames=10, max_staleness_s=0.25), start_ns=START_NS,
                       clock=clock, sleep=sleep, poses=_Poses(newest_s=0.5), mount=mount, say=said.append)
    # frames at 0.0 .. 0.9 s: poses up to 0.5 s, and fresh enough to 0.75 s: frames 0-7 published
    assert stats.frames == 8 and stats.stale == 2
    assert any("more than --max-staleness 0.25 s" in line for line in said)
    poses = [s[2].pose for s in rec.sent if s[0] == "/sonar/pose"]
    want = [Pose((min(0.1 * k, 0.5), 0.0, 1.0)).compose(mount) for k in range(8)]
    for got, w in zip(poses, want):
        assert (got.position.x, got.position.y, got.position.z) == pytest.approx(w.position_m, abs=1e-9)
        q = got.orientation
        assert (q.x, q.y, q.z, q.w) == pytest.approx(w.quat_xyzw, abs=1e-9)
    # the TF tree: world -> vehicle per frame (the vehicle's pose), vehicle -> sonar (the mount)
    # and sonar -> sonar_image static: composed, the sonar pose published
    tfs = [s[2] for s in rec.sent if s[0] == "/tf"]
    assert len(tfs) == 8
    for k, m in enumerate(tfs):
        (tf,) = m.transforms
        assert (tf.header.frame_id, tf.child_frame_id) == ("world", "vehicle")
        v = tf.transform.translation
        assert (v.x, v.y, v.z) == pytest.approx((min(0.1 * k, 0.5), 0.0, 1.0), abs=1e-9)
    (static,) = [s[2] for s in rec.sent if s[0] == "/tf_static"]
    by_child = {t.child_frame_id: t for t in static.transforms}
    assert by_child["sonar"].header.frame_id == "vehicle" and by_child["sonar_image"].header.frame_id == "sonar"
    m = by_child["sonar"].transform
    assert (m.translation.x, m.translation.y, m.translation.z) == pytest.approx(mount.position_m, abs=1e-12)
    assert (m.rotation.x, m.rotation.y, m.rotation.z, m.rotation.w) == pytest.approx(mount.quat_xyzw, abs=1e-12)


def test_with_the_vehicle_from_tf_its_frame_carries_the_mount_and_world_to_it_is_left_alone():
    import sonarsim

    now = [0.0]
    rec = _Recorder()
    mount = Pose((0.5, 0.0, -0.2), (0.0, 30.0, 0.0))

    def sleep(s):
        now[0] += s

    with sonarsim.Simulator(SCENE) as sim:
        stream(sim, rec, LiveOptions(rate_hz=10.0, n_frames=3), start_ns=START_NS, clock=lambda: now[0], sleep=sleep,
               poses=_Poses(newest_s=1.0), mount=mount, vehicle_frame="base_link", vehicle_tf=False)
    assert not [s for s in rec.sent if s[0] == "/tf"]  # the simulator's TF has world -> base_link
    (static,) = [s[2] for s in rec.sent if s[0] == "/tf_static"]
    assert {(t.header.frame_id, t.child_frame_id) for t in static.transforms} == {
        ("base_link", "sonar"), ("sonar", "sonar_image")}


POSE_PUBLISHER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from sonarsim.io.rosbag_instruments import instrument_typestore
    from sonarsim.live import dds
    domain, t0_ns, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    store = instrument_typestore()
    T = store.types
    dp = DomainParticipant(domain)
    q = dds.qos("tf")  # reliable, as a simulator's odometry often is
    w = DataWriter(dp, Topic(dp, "rt/vehicle/pose", dds.dds_type("geometry_msgs/msg/PoseStamped"), qos=q), qos=q)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        now = time.time_ns()
        x = (now - t0_ns) / 1e9  # 1 m/s along x since t0
        msg = T["geometry_msgs/msg/PoseStamped"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=now // 10**9, nanosec=now % 10**9),
                                            frame_id="world"),
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.6),
                                             orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
        w.write(dds.to_sample(msg, "geometry_msgs/msg/PoseStamped"))
        time.sleep(0.02)
""")


def test_sonarsim_live_follows_a_pose_topic_from_another_process(tmp_path):
    """A pose publisher (50 Hz, 1 m/s along x), ``sonarsim live --pose-topic`` and a subscriber
    here, three processes on the loopback: each published sonar pose is the vehicle's at the
    frame's stamp (within the 20 ms between poses: 2 cm)."""
    import yaml
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from sonarsim.live import dds

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    (tmp_path / "pub.py").write_text(POSE_PUBLISHER)
    domain = 100 + (int(time.time()) + 37) % 50
    dp = DomainParticipant(domain)
    q = dds.qos("sensor")
    reader = DataReader(dp, Topic(dp, "rt/sonar/pose", dds.dds_type("geometry_msgs/msg/PoseStamped"), qos=q), qos=q)
    t0 = time.time_ns()
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    pub = subprocess.Popen([sys.executable, str(tmp_path / "pub.py"), str(domain), str(t0), "12"], env=env)
    live = subprocess.Popen([sys.executable, "-m", "sonarsim", "live", str(scene), "--rate", "10", "--frames", "40",
                             "--pose-topic", "/vehicle/pose", "--pose-type", "pose_stamped"],
                            env=env, stderr=subprocess.PIPE, text=True)
    received, err = receive({"pose": reader}, live, (pub,))
    got = [s for _, s in received["pose"]]
    assert live.returncode == 0, err
    assert len(got) >= 10, err
    stamps = np.array([s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in got])
    x = np.array([s.pose.position.x for s in got])
    np.testing.assert_allclose(x, (stamps - t0) / 1e9, atol=0.025)
    assert np.all(np.diff(x) > 0.05)  # the vehicle moved between frames
