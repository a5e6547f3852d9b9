"""``sonarsim live`` with a scene's instruments (issue 40 item 1): each pings at its own rate, in
time order; the pings rendered one at a time are the film's pings, and their messages are what
a bag of the film holds, byte for byte; a subscriber in this process receives them from a
``sonarsim live`` process."""

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

import sonarsim  # noqa: E402
from sonarsim.core.transforms import quat_to_matrix  # noqa: E402
from sonarsim.io import rosbag_instruments as ri  # noqa: E402
from sonarsim.live import dds  # noqa: E402
from sonarsim.live.instruments import instrument_periods, stream_instruments  # noqa: E402
from sonarsim.live.stream import LiveOptions  # noqa: E402

from .receive import receive  # noqa: E402
from .test_live import _Recorder  # noqa: E402  (a stand-in publisher: what is published, in order)

START = 1_700_000_000_000_000_000
SCENE = {
    "vehicle": {"pose": {"position_m": [3.0, -2.0, 12.0], "rpy_deg": [4.0, -3.0, 30.0]}, "speed_m_s": 1.5},
    "ground": {"height_m": 0.0},
    "objects": [{"name": "rock", "primitive": "box", "size_m": [2.0, 2.0, 1.0],
                 "pose": {"position_m": [6.0, -10.0, 0.5]}}],
    "render": {"seed": 11},
    "instruments": [
        {"type": "sidescan", "name": "sss", "range_max_m": 20.0, "n_samples": 80, "ping_rate_hz": 10,
         "depression_deg": 12.0, "horizontal_beam_width_deg": 0.7, "vertical_beam_width_deg": 45.0,
         "frequency_khz": 600, "mount": {"position_m": [0.5, 0.0, -0.1], "rpy_deg": [0.0, 2.0, 0.0]}},
        {"type": "scanning", "name": "head", "range_min_m": 0.5, "range_max_m": 10.5, "n_samples": 50,
         "tilt_deg": 10.0, "mount": {"position_m": [0.2, 1.0, 0.3], "rpy_deg": [0.0, 0.0, 15.0]}},
        {"type": "singlebeam", "name": "alt", "beam_width_deg": 8.0, "range_max_m": 30.0, "n_samples": 60,
         "ping_rate_hz": 4, "mount": {"position_m": [0.5, 0.0, -0.2]}},
        {"type": "multibeam", "name": "mbes", "preset": "r2sonic_2026_400", "range_max_m": 25.0, "n_samples": 256,
         "ping_rate_hz": 5, "mount": {"position_m": [0.2, 0.0, -0.3]}},
        {"type": "fls", "name": "fls", "n_beams": 16, "azimuth_fov_deg": 60, "elevation_fov_deg": 12,
         "range_min_m": 0.5, "range_max_m": 20.0, "n_range_bins": 32, "ping_rate_hz": 8,
         "mount": {"position_m": [0.4, 0.0, 0.0], "rpy_deg": [0, 40, 0]}},
    ],
}


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def _fake_clock():
    now = [100.0]
    sleeps = []

    def clock():
        return now[0]

    def sleep(s):
        sleeps.append(s)
        now[0] += s

    return clock, sleep, sleeps


@pytest.fixture(scope="module")
def sim():
    with sonarsim.Simulator(SCENE) as s:
        yield s


def test_each_instrument_pings_at_its_own_rate_in_time_order(sim):
    clock, sleep, sleeps = _fake_clock()
    rec = _Recorder()
    periods = instrument_periods(sim)
    assert periods["sss"] == pytest.approx(0.1) and periods["alt"] == pytest.approx(0.25)
    assert periods["head"] > 0 and periods["mbes"] == pytest.approx(0.2)
    stats = stream_instruments(sim, rec, LiveOptions(n_frames=4), start_ns=START, clock=clock, sleep=sleep)
    assert stats.pings == {name: 4 for name in periods} and stats.frames == 20 and stats.late == 0
    # first: /tf_static (latched), then each unit (latched), before any ping
    assert [t for t, *_ in rec.sent[:6]] == ["/tf_static"] + [f"/{n}/unit" for n in periods]
    assert rec.sent[0][3] == "tf_static" and all(k == "latched" for *_, k in rec.sent[1:6])
    pings = [(t, _stamp(m)) for t, _, m, k in rec.sent[6:] if k == "sensor"]
    stamps = [s for _, s in pings]
    assert stamps == sorted(stamps)  # time order across the instruments
    for name, period in periods.items():
        mine = sorted({s for t, s in pings if t.startswith(f"/{name}/")})
        assert mine == [START + round(k * period * 1e9) for k in range(4)], name
    # paced: the fake clock has reached the last ping's time, and no more
    assert sum(sleeps) == pytest.approx(max(3 * p for p in periods.values()))
    # one world -> vehicle per stamp, at the scene's vehicle running ahead at 1.5 m/s
    tfs = [m for t, _, m, k in rec.sent if t == "/tf"]
    assert len(tfs) == len(set(stamps))
    v0 = sim.scene.vehicle_pose
    for m in tfs:
        (tf,) = m.transforms
        assert (tf.header.frame_id, tf.child_frame_id) == ("world", "vehicle")
        t = (_stamp(tf) - START) / 1e9
        want = np.asarray(v0.position_m) + 1.5 * t * v0.rotation[:, 0]
        got = tf.transform.translation
        np.testing.assert_allclose([got.x, got.y, got.z], want, atol=1e-9)


def test_tf_static_hangs_each_mount_from_the_vehicle(sim):
    rec = _Recorder()
    clock, sleep, _ = _fake_clock()
    stream_instruments(sim, rec, LiveOptions(n_frames=1, fast=True), start_ns=START, clock=clock, sleep=sleep)
    (msg,) = [m for t, _, m, _ in rec.sent if t == "/tf_static"]
    by_child = {tf.child_frame_id: tf for tf in msg.transforms}
    for spec in sim.scene.instruments:
        tf = by_child[spec.name]
        assert tf.header.frame_id == "vehicle" and _stamp(tf) == START
        q = tf.transform.rotation
        np.testing.assert_allclose(quat_to_matrix(np.array([q.x, q.y, q.z, q.w])), spec.mount.rotation, atol=1e-12)
        v = tf.transform.translation
        np.testing.assert_allclose([v.x, v.y, v.z], spec.mount.position_m, atol=1e-12)
        assert by_child[f"{spec.name}_image"].header.frame_id == spec.name
    assert by_child["alt_beam"].header.frame_id == "alt"


def test_live_pings_are_the_films_pings_as_its_bag_holds_them(sim, tmp_path):
    """Each instrument's film of 3 pings, rendered at once and written to a bag, against the same
    pings rendered one at a time live: every topic's payloads equal byte for byte (the draws,
    the scanning head's angle, the stamps, /tf and /tf_static included)."""
    from rosbags.rosbag2 import Reader

    from sonarsim.instruments import render_pings

    n = 3
    films = {s.name: render_pings(sim, s.name, n_pings=n) for s in sim.scene.instruments}
    periods = instrument_periods(sim)
    times = {name: periods[name] * np.arange(n) for name in films}
    ri.write_instrument_bag(tmp_path / "bag", films, sim, times_s=times, start_ns=START)
    want: dict[str, list[bytes]] = {}
    with Reader(tmp_path / "bag") as reader:
        for c, _, raw in reader.messages():
            want.setdefault(c.topic, []).append(bytes(raw))
    rec = _Recorder()
    clock, sleep, _ = _fake_clock()
    stream_instruments(sim, rec, LiveOptions(n_frames=n), start_ns=START, clock=clock, sleep=sleep)
    store = ri.instrument_typestore()
    got: dict[str, list[bytes]] = {}
    for topic, ros_type, msg, _ in rec.sent:
        got.setdefault(topic, []).append(bytes(store.serialize_cdr(msg, ros_type)))
    assert set(got) == set(want)
    for topic in want:
        assert len(got[topic]) == len(want[topic]), topic
        for k, (a, b) in enumerate(zip(got[topic], want[topic])):
            assert a == b, f"{topic} message {k}"
    assert len(want["/head/raw"]) == n and len(want["/mbes/points"]) == n


def test_a_ping_without_a_fresh_pose_is_skipped_and_said(sim):
    class Poses:
        topic = "/odom"

        def pose_at(self, t_ns):
            if t_ns < START + 150_000_000:
                return None, float("inf")
            return sim.scene.vehicle_pose, 0.0

    rec, said = _Recorder(), []
    clock, sleep, _ = _fake_clock()
    stats = stream_instruments(sim, rec, LiveOptions(n_frames=3), start_ns=START, clock=clock, sleep=sleep,
                               poses=Poses(), say=said.append)
    # sss pings at 0, 100, 200 ms: the first two have no pose yet
    assert stats.pings["sss"] == 1 and stats.stale >= 2
    assert any("no pose on /odom yet" in line for line in said)


SUBSCRIBED = {
    "/sss/raw": ("marine_acoustic_msgs/msg/RawSonarImage", "sensor"),
    "/alt/range": ("sensor_msgs/msg/Range", "sensor"),
    "/mbes/points": ("sensor_msgs/msg/PointCloud2", "sensor"),
    "/mbes/detections": ("marine_acoustic_msgs/msg/SonarDetections", "sensor"),
    "/fls/image": ("marine_acoustic_msgs/msg/ProjectedSonarImage", "sensor"),
    "/tf_static": ("tf2_msgs/msg/TFMessage", "tf_static"),
    "/sss/unit": ("std_msgs/msg/String", "latched"),
}


def test_sonarsim_live_publishes_the_instruments_to_another_process(tmp_path):
    import yaml
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    domain = 170 + (os.getpid() + int(time.time())) % 30
    dp = DomainParticipant(domain)
    readers = {t: DataReader(dp, Topic(dp, dds.dds_topic(t), dds.dds_type(ty), qos=dds.qos(q)), qos=dds.qos(q))
               for t, (ty, q) in SUBSCRIBED.items()}
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    proc = subprocess.Popen([sys.executable, "-m", "sonarsim", "live", str(scene), "--frames", "12"],
                            env=env, stderr=subprocess.PIPE, text=True, cwd=Path(__file__).parent)
    received, err = receive(readers, proc)
    got = {t: [s for _, s in samples] for t, samples in received.items()}
    assert proc.returncode == 0, err
    assert "60 pings" in err and "sss 12" in err and "Traceback" not in err
    raw = got["/sss/raw"]
    assert len(raw) >= 6, err  # best effort: pings before discovery may be lost
    steps = np.diff([_stamp(m) for m in raw]) / 1e8  # in sss periods of 100 ms
    assert np.all(steps >= 0.999) and np.allclose(steps, np.round(steps), atol=1e-6)
    assert {m.header.frame_id for m in raw} == {"sss_image"}
    assert all(m.image.beam_count == 2 and m.samples_per_beam == 80 for m in raw)
    assert {m.header.frame_id for m in got["/alt/range"]} == {"alt_beam"}
    ranges = [m.range for m in got["/alt/range"]]
    assert ranges and all(11.0 < r < 13.5 for r in ranges)  # 12 m over a flat floor, pitched and rolled a little
    clouds = got["/mbes/points"]
    assert clouds and {m.header.frame_id for m in clouds} == {"vehicle"} and all(m.width > 100 for m in clouds)
    assert got["/mbes/detections"] and got["/fls/image"]
    (static,) = got["/tf_static"]
    assert {tf.child_frame_id for tf in static.transforms} >= {"sss", "head", "alt", "mbes", "fls", "alt_beam"}
    assert got["/sss/unit"] and got["/sss/unit"][0].data


@pytest.mark.parametrize("args, key", [
    (["--rate", "5"], "--rate"),
    (["--topics", "image=/x"], "--topics"),
    (["--frame-ids", "sonar=s"], "--frame-ids"),
    (["--no-fan"], "--no-fan"),
    (["--points"], "--points"),
    (["--pose-topic", "/odom", "--mount", "0,0,0,0,0,0"], "--mount"),
])
def test_options_that_mean_nothing_for_instruments_are_refused(tmp_path, args, key):
    import yaml

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    done = subprocess.run([sys.executable, "-m", "sonarsim", "live", str(scene), "--frames", "1", *args],
                          capture_output=True, text=True, timeout=120, env={**os.environ, "ROS_DOMAIN_ID": "231"})
    assert done.returncode == 2, done.stderr
    assert key in done.stderr and "Traceback" not in done.stderr
