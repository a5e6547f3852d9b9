"""``sonarsim live-demo`` (issue 40 item 6): a scripted vehicle, ``sonarsim live`` in its own
process and a recorder, on the loopback; the bag they leave read back with ``rosbags`` and
checked against the scene: the vehicle's run, the patrolling buoy, the sonar on its mount, and
one frame's image against a still render at the recorded poses."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from sonarsim.core.transforms import Pose  # noqa: E402
from sonarsim.io import rosbag as rb  # noqa: E402
from sonarsim.io.rosbag_instruments import instrument_typestore  # noqa: E402
from sonarsim.live import demo  # noqa: E402

SECONDS, RATE = 3.0, 10.0


def _domain() -> int:
    return 200 + os.getpid() % 30  # apart from the other live tests and other runs here


def _sonarsim(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "sonarsim", *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("live-demo")
    done = _sonarsim("live-demo", "--out", str(out), "--seconds", f"{SECONDS:g}", "--rate", f"{RATE:g}",
                     "--domain", str(_domain()))
    assert done.returncode == 0, done.stderr
    return out, done.stderr


def _stamp(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _messages(bag):
    """topic -> list of (stamp ns, message), as rosbags reads them."""
    from rosbags.rosbag2 import Reader

    store = instrument_typestore()
    got: dict[str, list] = {}
    with Reader(bag) as reader:
        for connection, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, connection.msgtype)
            stamp = _stamp(msg.header) if hasattr(msg, "header") else None
            got.setdefault(connection.topic, []).append((stamp, msg))
    return got


def test_the_demo_writes_a_bag_rosbags_reads_with_every_topic(demo_run):
    out, err = demo_run
    assert {p.name for p in out.iterdir()} >= {"bag", *rb_files()}
    got = _messages(out / "bag")
    n = round(SECONDS * RATE)
    # best effort on the loopback: nearly every frame arrives, none twice
    images = got["/sonar/image"]
    assert 0.8 * n <= len(images) <= n
    stamps = [s for s, _ in images]
    assert stamps == sorted(set(stamps))
    steps = np.diff(stamps) / 1e9
    assert np.allclose(steps[steps < 1.5 / RATE], 1 / RATE, atol=1e-6)  # frames 1/rate apart (a lost one: 2/rate)
    for topic in ("/sonar/fan", "/sonar/pose"):
        assert sorted(s for s, _ in got[topic]) == sorted(stamps) or len(got[topic]) >= 0.8 * n, topic
    assert len(got["/tf_static"]) == 1 and len(got["/sonar/image/unit"]) == 1
    assert len(got[demo.POSE_TOPIC]) > 20 * SECONDS  # 50 Hz, minus discovery
    ids = rb.BagFrameIds()
    assert {m.header.frame_id for _, m in images} == {ids.image}
    assert {m.header.frame_id for _, m in got["/sonar/fan"]} == {ids.sonar}
    assert {m.header.frame_id for _, m in got["/sonar/pose"]} == {ids.world}
    assert {m.header.frame_id for _, m in got[demo.POSE_TOPIC]} == {ids.world}  # one tree: world -> sonar
    summary = json.loads((out / "live-demo.json").read_text())
    assert summary["images_received"] == len(images)
    assert summary["messages"] == {t: len(v) for t, v in got.items()}
    assert "live-demo: the bag" in err and "Traceback" not in err


def rb_files():
    from sonarsim.cli.live import LIVE_DEMO_FILES

    return LIVE_DEMO_FILES


def _yaw_deg(q) -> float:
    return math.degrees(math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z)))


def test_the_sonar_rides_the_vehicle_on_its_mount_at_each_frames_time(demo_run):
    """Each frame's sonar pose is the vehicle's pose received at or before the frame's stamp
    (the newest live held, no staler than --max-staleness, 0.5 s), composed with the mount
    (pitched 20 degrees down); the vehicle moves forward along x at its speed, its yaw swaying."""
    out, _ = demo_run
    got = _messages(out / "bag")
    stamps = np.array([s for s, _ in got[demo.POSE_TOPIC]], np.int64)
    order = np.argsort(stamps)
    t_ref = int(stamps.min())
    vt = (stamps[order] - t_ref) / 1e9  # seconds (float64 of nanoseconds since 1970 is 256 ns coarse)
    vx = np.array([m.pose.position.x for _, m in got[demo.POSE_TOPIC]])[order]
    vyaw = np.array([_yaw_deg(m.pose.orientation) for _, m in got[demo.POSE_TOPIC]])[order]
    assert np.all(np.diff(vx) > 0)
    assert np.allclose(np.diff(vx) / np.diff(vt), demo.SPEED_M_S, rtol=1e-6)
    mount = Pose((0.0, 0.0, 0.0), (0.0, 20.0, 0.0))
    for stamp, msg in got["/sonar/pose"]:
        p = msg.pose
        t = (stamp - t_ref) / 1e9
        # the time of the vehicle pose used: x grows with time, so x tells it
        t_used = float(np.interp(p.position.x, vx, vt))
        assert t - 0.5 <= t_used <= t + 1e-3, (t, t_used)
        yaw = np.interp(t_used, vt, vyaw)
        want = Pose((p.position.x, 0.0, demo.HEIGHT_M), (0.0, 0.0, yaw)).compose(mount)
        assert (p.position.x, p.position.y, p.position.z) == pytest.approx(want.position_m, abs=1e-6)
        q = (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
        assert abs(float(np.dot(q, want.quat_xyzw))) == pytest.approx(1.0, abs=1e-5)
    xs = [m.pose.position.x for _, m in sorted(got["/sonar/pose"], key=lambda g: g[0])]
    assert xs[-1] - xs[0] == pytest.approx(demo.SPEED_M_S * (len(xs) - 1) / RATE, rel=0.3)


def test_the_buoy_patrols_on_its_track_and_tf_says_where(demo_run):
    out, _ = demo_run
    got = _messages(out / "bag")
    buoy = [(s, t.transform.translation) for _, m in got["/tf"] for t in m.transforms if t.child_frame_id == "buoy"
            for s in [_stamp(t.header)]]
    assert len(buoy) >= 0.8 * SECONDS * RATE
    image_stamps = {s for s, _ in got["/sonar/image"]}
    assert {s for s, _ in buoy} <= image_stamps | {s for s, _ in got["/sonar/pose"]}
    track = demo.demo_scene()
    keys = next(o for o in track["objects"] if o["name"] == "buoy")["track"]["keys"]
    kt, ky = [k["t"] for k in keys], [k["position_m"][1] for k in keys]
    for stamp, tr in buoy:
        assert (tr.x, tr.z) == pytest.approx((2.4, 0.4))
    # live's track time is 0 at its first frame: the first received is frame j (0 unless lost)
    stamps = np.array([s for s, _ in buoy], np.int64)
    ys = np.array([tr.y for _, tr in buoy])

    def track_y(j):
        t = ((stamps - stamps.min()) / 1e9 + j / RATE) % demo.PATROL_S
        return np.interp(t, kt, ky)

    assert min(np.abs(track_y(j) - ys).max() for j in range(4)) < 1e-6
    assert max(ys) - min(ys) > 0.6  # it moved across the fan in 3 s (1.2 m in 3 s)


def test_the_fans_show_the_tank_and_one_image_matches_a_still_render(demo_run):
    """The fans are not blank (the floor and objects in counts), and one recorded image's
    payload is a still render of the scene at that frame's recorded sonar pose, with the buoy
    where /tf put it."""
    import sonarsim
    from PIL import Image

    out, _ = demo_run
    for name in ("fan_first.png", "fan_last.png"):
        fan = np.asarray(Image.open(out / name))
        assert fan.dtype == np.uint8 and fan.max() > 100 and (fan > 0).mean() > 0.05, name
    got = _messages(out / "bag")
    poses = {s: m.pose for s, m in got["/sonar/pose"]}
    buoys = {_stamp(t.header): t.transform for _, m in got["/tf"] for t in m.transforms if t.child_frame_id == "buoy"}
    stamp, msg = next((s, m) for s, m in sorted(got["/sonar/image"], key=lambda g: g[0])[len(got["/sonar/image"]) // 2:]
                      if s in poses and s in buoys)
    p, b = poses[stamp], buoys[stamp]
    pose = Pose.from_quaternion((p.position.x, p.position.y, p.position.z),
                                (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
    buoy = Pose.from_quaternion((b.translation.x, b.translation.y, b.translation.z),
                                (b.rotation.x, b.rotation.y, b.rotation.z, b.rotation.w))
    with sonarsim.Simulator(demo.demo_scene()) as sim:
        sim.move_objects({"buoy": buoy})
        still = rb.frame_from_image(sim.render(pose=pose), stamp).polar
        sim.move_objects({"buoy": Pose((2.4, 5.0, 0.4), (0.0, 0.0, 0.0))})  # the buoy elsewhere: another image
        elsewhere = rb.frame_from_image(sim.render(pose=pose), stamp).polar
    assert msg.image.dtype == 8 and msg.image.beam_count == still.shape[1]  # float32, beams across
    recorded = np.frombuffer(bytes(msg.image.data), "<f4").reshape(len(msg.ranges), msg.image.beam_count)
    assert recorded.max() > 0
    scale = float(np.abs(still).max())
    assert np.abs(recorded - still).max() <= 1e-3 * scale
    assert np.abs(recorded - elsewhere).max() > 1e-2 * scale


def test_bad_options_are_refused_by_name_without_a_traceback(tmp_path):
    for args, key in ((["--seconds", "500"], "--seconds"), (["--seconds", "0"], "--seconds"),
                      (["--rate", "80"], "--rate"), (["--domain", "999"], "--domain"),
                      (["--storage", "zip"], "--storage")):
        done = _sonarsim("live-demo", "--out", str(tmp_path / "o"), *args, timeout=60)
        assert done.returncode != 0, args
        assert key in done.stderr and "Traceback" not in done.stderr, (args, done.stderr)
        assert not (tmp_path / "o" / "bag").exists()
