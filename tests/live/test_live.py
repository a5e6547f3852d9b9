"""``sonarsim live`` (issue 40 item 1): a publisher process, a subscriber here, on the loopback;
the messages' contents, stamps, frame ids and TF checked against the scene."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.io import rosbag as rb  # noqa: E402
from sonarsim.live import dds  # noqa: E402
from sonarsim.live.stream import LiveOptions, LiveStats, stream  # noqa: E402

from .receive import receive  # noqa: E402

SCENE = {
    "sonar": {"preset": "oculus-m1200d-hf", "n_range_bins": 200, "pose": {"position_m": [0.0, 0.0, 0.6],
                                                                          "rpy_deg": [0.0, 25.0, 0.0]}},
    "ground": {"height_m": 0.0},
    "objects": [{"name": "box", "primitive": "box", "size_m": [0.3, 0.3, 0.3],
                 "pose": {"position_m": [2.0, 0.0, 0.15]}}],
    "render": {"seed": 7},
}


class _Recorder:
    """A stand-in publisher: what stream() publishes, in order."""

    domain = 0

    def __init__(self):
        self.sent = []

    def writer(self, topic, ros_type, kind="sensor"):
        self.writers = getattr(self, "writers", []) + [topic]

    def publish(self, topic, ros_type, msg, kind="sensor"):
        self.sent.append((topic, ros_type, msg, kind))

    def subscribers(self, topic):
        return 0


def test_live_options_are_checked_naming_the_key():
    for bad in (0.0, -1.0, float("nan"), 5000.0, True):
        with pytest.raises(ConfigError, match="rate_hz"):
            LiveOptions(rate_hz=bad)
    with pytest.raises(ConfigError, match="n_frames"):
        LiveOptions(n_frames=0)


def test_stream_paces_frames_stamps_them_and_publishes_what_a_bag_holds():
    """Frames at 20 Hz on a fake clock: stamps 50 ms apart from the start, each frame published
    at its time (the sleeps fill the gap), /tf_static once first, the unit once, and messages
    equal to what the bag writer builds from the same render."""
    import sonarsim

    now = [100.0]
    sleeps = []

    def clock():
        return now[0]

    def sleep(s):
        sleeps.append(s)
        now[0] += s

    rec = _Recorder()
    with sonarsim.Simulator(SCENE) as sim:
        stats = stream(sim, rec, LiveOptions(rate_hz=20.0, n_frames=4), start_ns=5_000_000_000, clock=clock, sleep=sleep)
        image2 = sim.render(frame=2)
    assert isinstance(stats, LiveStats) and stats.frames == 4 and stats.late == 0 and not stats.interrupted
    assert sleeps == pytest.approx([0.05, 0.05, 0.05])  # frame 0 at once; the clock stands still while rendering
    topics = [s[0] for s in rec.sent]
    assert topics[0] == "/tf_static" and topics.count("/tf_static") == 1 and topics.count("/sonar/image/unit") == 1
    assert topics.count("/sonar/image") == topics.count("/sonar/fan") == topics.count("/tf") == 4
    images = [s[2] for s in rec.sent if s[0] == "/sonar/image"]
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in images]
    assert stamps == [5_000_000_000 + k * 50_000_000 for k in range(4)]
    assert {m.header.frame_id for m in images} == {"sonar_image"}
    # frame 2 is what render(frame=2) gives, byte for byte as the bag would hold it
    store = rb._import_rosbags()[2]
    want = rb.FrameMessages(store).frame_messages(rb.frame_from_image(image2, stamps[2], fan=True))
    want = dict(want)
    got = {s[0]: s[2] for s in rec.sent}
    assert bytes(images[2].image.data) == bytes(want["image"].image.data)
    assert bytes(store.serialize_cdr(images[2], rb.MSGTYPES["image"])) == \
        bytes(store.serialize_cdr(want["image"], rb.MSGTYPES["image"]))
    # /tf holds the pose alone; /tf_static the constant sonar -> sonar_image
    tf = [s[2] for s in rec.sent if s[0] == "/tf"][0]
    assert [t.child_frame_id for t in tf.transforms] == ["sonar"]
    assert tf.transforms[0].transform.translation.z == pytest.approx(0.6)
    static = rec.sent[0][2]
    assert [t.child_frame_id for t in static.transforms] == ["sonar_image"] and rec.sent[0][3] == "tf_static"
    q = static.transforms[0].transform.rotation
    assert (q.x, q.y, q.z, q.w) == pytest.approx(rb.SONAR_TO_IMAGE_QUAT_XYZW)
    assert got["/sonar/image/unit"].data == image2.unit.name
    # the fan as fan.png draws it: 8-bit levels, legible as they come
    from sonarsim.image.levels import default_fan_levels

    fan = [s[2] for s in rec.sent if s[0] == "/sonar/fan"][2]
    want_fan = default_fan_levels(image2)
    assert fan.encoding == "mono8" and (fan.height, fan.width) == want_fan.shape
    assert bytes(fan.data) == want_fan.tobytes() and want_fan.max() > 100


def test_points_carry_each_frames_labelled_ground_truth():
    """With ``points``: per frame a PointCloud2 (x, y, z world, object id) that is the bag's of
    render(frame=k, labels='total'), the box's points on the box and the floor's on z = 0, and
    once, latched, the ids' names."""
    import json

    import sonarsim

    now = [0.0]
    rec = _Recorder()

    def sleep(s):
        now[0] += s

    with sonarsim.Simulator(SCENE) as sim:
        stream(sim, rec, LiveOptions(rate_hz=20.0, n_frames=3, points=True), start_ns=5_000_000_000,
               clock=lambda: now[0], sleep=sleep)
        image1 = sim.render(frame=1, labels="total")
    clouds = [s[2] for s in rec.sent if s[0] == "/sonar/points"]
    (ids,) = [s for s in rec.sent if s[0] == "/sonar/points/ids"]
    assert len(clouds) == 3 and ids[3] == "latched"
    names = json.loads(ids[2].data)
    assert names == list(image1.labels.ids) and names[0] == "box"
    store = rb._import_rosbags()[2]
    want = dict(rb.FrameMessages(store).frame_messages(rb.frame_from_image(
        image1, 5_050_000_000, fan=False, points_world=image1.labels.points_world,
        points_object=image1.labels.points_object)))["points"]
    assert bytes(store.serialize_cdr(clouds[1], rb.MSGTYPES["points"])) == \
        bytes(store.serialize_cdr(want, rb.MSGTYPES["points"]))
    cloud = np.frombuffer(bytes(clouds[1].data), rb._POINT_DTYPE)
    assert clouds[1].header.frame_id == "world" and len(cloud) > 100
    on_box = cloud[cloud["object"] == 0]
    floor = cloud[cloud["object"] == names.index("ground")] if "ground" in names else cloud[cloud["object"] == 1]
    assert len(on_box) > 10 and len(floor) > 10
    np.testing.assert_allclose(floor["z"], 0.0, atol=1e-4)
    assert np.all(np.abs(on_box["x"] - 2.0) <= 0.15 + 1e-4) and np.all(on_box["z"] <= 0.3 + 1e-4)


def test_a_slow_render_is_counted_late_and_never_waited_for():
    import sonarsim

    now = [0.0]

    def clock():
        now[0] += 0.03  # every look at the clock: 30 ms pass (rendering, publishing)
        return now[0]

    rec = _Recorder()
    with sonarsim.Simulator(SCENE) as sim:
        stats = stream(sim, rec, LiveOptions(rate_hz=50.0, n_frames=5), clock=clock, sleep=lambda s: None)
    assert stats.frames == 5 and stats.late == 4


def test_ctrl_c_stops_the_stream_cleanly():
    import sonarsim

    calls = [0]

    def stop():
        calls[0] += 1
        if calls[0] == 3:
            raise KeyboardInterrupt
        return False

    rec = _Recorder()
    with sonarsim.Simulator(SCENE) as sim:
        stats = stream(sim, rec, LiveOptions(fast=True), stop=stop)
    assert stats.interrupted and stats.frames == 2 and "stopped by a signal after 2 frames" in stats.summary()


def test_sonarsim_live_publishes_to_a_subscriber_in_another_process(tmp_path):
    """``sonarsim live`` in its own process; a subscriber here receives the image, the fan, the
    pose, /tf and /tf_static (late-joining: latched), with stamps 1/rate apart and contents
    equal to the scene's render of the same frame."""
    import yaml
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    import sonarsim

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    domain = 150 + int(time.time()) % 50
    dp = DomainParticipant(domain)
    kinds = {"/sonar/image": ("marine_acoustic_msgs/msg/ProjectedSonarImage", "sensor"),
             "/sonar/fan": ("sensor_msgs/msg/Image", "sensor"), "/sonar/pose": ("geometry_msgs/msg/PoseStamped", "sensor"),
             "/tf": ("tf2_msgs/msg/TFMessage", "tf"), "/tf_static": ("tf2_msgs/msg/TFMessage", "tf_static")}
    readers = {t: DataReader(dp, Topic(dp, dds.dds_topic(t), dds.dds_type(ty), qos=dds.qos(q)), qos=dds.qos(q))
               for t, (ty, q) in kinds.items()}
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    proc = subprocess.Popen([sys.executable, "-m", "sonarsim", "live", str(scene), "--rate", "10", "--frames", "30"],
                            env=env, stderr=subprocess.PIPE, text=True, cwd=Path(__file__).parent)
    received, err = receive(readers, proc)
    got = {t: [s for _, s in samples] for t, samples in received.items()}
    assert proc.returncode == 0, err
    assert "30 frames" in err
    images = got["/sonar/image"]
    assert len(images) >= 10, err  # best effort: the frames before discovery may be lost
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in images])
    steps = np.diff(stamps) / 1e8  # in frames of 100 ms
    assert np.all(steps >= 0.999) and np.allclose(steps, np.round(steps), atol=1e-6)
    assert {m.header.frame_id for m in images} == {"sonar_image"}
    assert len(got["/tf_static"]) == 1 and got["/tf_static"][0].transforms[0].child_frame_id == "sonar_image"
    assert got["/sonar/fan"] and got["/sonar/pose"] and got["/tf"]
    pose = got["/sonar/pose"][-1].pose.position
    assert (pose.x, pose.y, pose.z) == pytest.approx((0.0, 0.0, 0.6))
    # the last image received is frame k of the render: its data equals render(frame=k)'s
    k = round((stamps[-1] - stamps[0]) / 1e8)  # frames from the first received to the last
    last = images[-1]
    with sonarsim.Simulator(SCENE) as sim:
        first_k = None
        for j in range(30):  # which frame the first received one is: the one whose data matches
            if bytes(images[0].image.data) == rb.device_polar(sim.render(frame=j)).tobytes():
                first_k = j
                break
        assert first_k is not None
        want = rb.device_polar(sim.render(frame=first_k + k)).tobytes()
    assert bytes(last.image.data) == want
