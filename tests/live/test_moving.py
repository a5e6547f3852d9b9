"""A world that moves, live (issue 40 items 2 and 3): objects driven by topics or by their
tracks, the vehicle by TF; each frame as a still scene at that moment renders it, and the
moving objects' poses on /tf."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

import sonarsim  # noqa: E402
from sonarsim.core.transforms import Pose  # noqa: E402
from sonarsim.live.stream import LiveOptions, stream  # noqa: E402

from .test_live import SCENE, _Recorder  # noqa: E402
from ..conftest import still_doc  # noqa: E402

START_NS = 2_000_000_000


class _Diver:
    """A stand-in pose source: y = 0.5 m/s from -0.5 m since START_NS, at x 1.8 m."""

    topic = "/diver/odom"

    def pose_at(self, t_ns):
        return Pose((1.8, -0.5 + 0.5 * (t_ns - START_NS) / 1e9, 0.3)), 0.0


def _images(rec):
    return [m for topic, _, m, _ in rec.sent if topic == "/sonar/image"]


def _payload(sim_doc) -> np.ndarray:
    """What the image message of a still render of ``sim_doc`` carries (its device polar)."""
    from sonarsim.io import rosbag as rb

    with sonarsim.Simulator(sim_doc) as sim:
        return rb.device_polar(sim.render(speckle=False))


def test_objects_move_by_their_topics_and_tracks_and_go_out_on_tf():
    scene = {**SCENE, "objects": SCENE["objects"] + [
        {"name": "diver", "primitive": "cylinder", "radius_m": 0.15, "height_m": 0.6, "pose": {"position_m": [1.8, -0.5, 0.3]}},
        {"name": "ball", "primitive": "sphere", "radius_m": 0.1, "pose": {"position_m": [2.4, 0.3, 0.4]},
         "track": {"velocity_m_s": [0.0, -1.0, 0.0]}}]}
    rec, said = _Recorder(), []
    with sonarsim.Simulator(scene) as sim:
        stats = stream(sim, rec, LiveOptions(rate_hz=10.0, n_frames=4, fast=True, speckle=False), start_ns=START_NS,
                       object_poses={"diver": _Diver()}, say=said.append)
    assert stats.frames == 4
    tfs = [m for topic, _, m, _ in rec.sent if topic == "/tf" and m.transforms[0].child_frame_id != "sonar"]
    assert len(tfs) == 4
    for k, tf in enumerate(tfs):
        t = 0.1 * k
        by = {x.child_frame_id: x for x in tf.transforms}
        assert set(by) == {"diver", "ball"}
        assert by["diver"].transform.translation.y == pytest.approx(-0.5 + 0.5 * t)
        assert by["ball"].transform.translation.y == pytest.approx(0.3 - t)
        assert by["diver"].header.stamp.sec * 10**9 + by["diver"].header.stamp.nanosec == START_NS + round(t * 1e9)
    # Each frame as a still scene at its moment renders it.
    for k in (0, 3):
        t = 0.1 * k
        doc = still_doc(still_doc(scene, "diver", Pose((1.8, -0.5 + 0.5 * t, 0.3))), "ball", Pose((2.4, 0.3 - t, 0.4)))
        want = _payload(doc)
        got = np.frombuffer(bytes(_images(rec)[k].image.data), want.dtype).reshape(want.shape)
        assert want.max() > 0
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-12)
    assert not np.array_equal(bytes(_images(rec)[0].image.data), bytes(_images(rec)[3].image.data))


class _Nothing:
    topic = "/nobody"

    def pose_at(self, t_ns):
        return None, math.inf


def test_an_object_whose_topic_is_silent_stays_put_and_is_said_once():
    rec, said = _Recorder(), []
    with sonarsim.Simulator(SCENE) as sim:
        stream(sim, rec, LiveOptions(rate_hz=10.0, n_frames=3, fast=True), start_ns=START_NS,
               object_poses={"box": _Nothing()}, say=said.append)
        assert sim.scene.objects[0].pose.position_m == (2.0, 0.0, 0.15)
    assert sum("no pose for the object 'box' on /nobody" in line for line in said) == 1


def test_tf_gives_a_named_frame_pose_from_the_world_frame():
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    from sonarsim.io.rosbag_instruments import instrument_typestore
    from sonarsim.live import dds
    from sonarsim.live.poses import TopicPoses

    dp = DomainParticipant(203)
    src = TopicPoses(dp, "/tf", "tf", frame="base_link", world="map")
    T = instrument_typestore().types
    q = dds.qos("tf")
    writer = DataWriter(dp, Topic(dp, "rt/tf", dds.dds_type("tf2_msgs/msg/TFMessage"), qos=q), qos=q)

    def transform(parent, child, sec, x):
        return T["geometry_msgs/msg/TransformStamped"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=0), frame_id=parent),
            child_frame_id=child, transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=-1.0),
                rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))

    for sec, x in ((1, 0.0), (2, 2.0)):  # base_link from map, and other frames that are not it
        msg = T["tf2_msgs/msg/TFMessage"](transforms=[transform("map", "base_link", sec, x),
                                                      transform("map", "buoy", sec, 9.0),
                                                      transform("odom", "base_link", sec, 7.0)])
        writer.write(dds.to_sample(msg, "tf2_msgs/msg/TFMessage"))
    for _ in range(200):
        pose, stale = src.pose_at(1_500_000_000)
        if pose is not None and len(src.times_ns) == 2:
            break
        import time

        time.sleep(0.01)
    assert list(src.times_ns) == [1_000_000_000, 2_000_000_000]
    assert pose.position_m == pytest.approx((1.0, 0.0, -1.0)) and stale == 0.0


@pytest.mark.parametrize("args, match", [
    (["--object-pose", "boat=/boat/odom"], "--object-pose: the scene has no object 'boat'; its objects: 'box'"),
    (["--object-pose", "box"], "--object-pose: must be NAME=TOPIC"),
    (["--object-pose", "box=/b:twist"], "must be odometry or pose_stamped"),
    (["--pose-topic", "/odom", "--pose-frame", "base_link"], "--pose-frame: the vehicle's pose comes from"),
])
def test_bad_live_motion_options_are_refused_by_name(tmp_path, args, match):
    import subprocess
    import sys

    import yaml

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    run = subprocess.run([sys.executable, "-m", "sonarsim", "live", str(scene), "--frames", "1", *args],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode != 0 and match in run.stderr and "Traceback" not in run.stderr
