"""ROS 2 bags (sonarsim.io.rosbag): every field read back by rosbags' reader and by the mcap
ROS 2 decoder, the message conventions against hand-computed vectors, a real render, atomicity."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import sonarsim
from sonarsim.core.transforms import Pose, quat_to_matrix
from sonarsim.errors import ConfigError, SonarsimError
from sonarsim.io import rosbag as rb
from sonarsim.io.rosbag import BagFrame, BagFrameIds, BagWriter, beam_directions, frame_from_image

from tests.conftest import sonar_dict

rosbags_highlevel = pytest.importorskip("rosbags.highlevel")

N_RANGES, N_BEAMS = 5, 4
AZIMUTH_DEG = np.array([30.0, 10.0, -10.0, -30.0])
RANGE_M = np.array([1.0, 1.5, 2.0, 2.5, 3.0])


def synthetic_frame(i: int, dtype=np.float32, **overrides) -> BagFrame:
    """Frame i: cell (r, b) holds 100 i + 10 r + b, so any reordering of rows or beams shows."""
    r, b = np.mgrid[0:N_RANGES, 0:N_BEAMS]
    kw = dict(
        stamp_ns=1_700_000_000_000_000_000 + i * 100_000_000,
        pose=Pose((1.0 + i, -2.0, 3.0), (5.0, 20.0, 30.0 + i)),
        polar=(100 * i + 10 * r + b).astype(dtype),
        range_m=RANGE_M,
        azimuth_deg=AZIMUTH_DEG,
        tx_beamwidth_deg=14.0,
        rx_beamwidth_deg=[1.0, 2.0, 3.0, 4.0],
        frequency_hz=1.2e6,
        sound_speed_m_s=1480.0,
        fan=np.arange(6 * 7, dtype=np.uint8).reshape(6, 7) + i,
        points_world=np.array([[1.0, 2.0, 3.0], [-4.5, 0.25, 7.0], [0.0, 0.0, float(i)]]),
        points_object=np.array([2, -1, 7]),
    )
    kw.update(overrides)
    return BagFrame(**kw)


def write_bag(path, storage, frames, **kw):
    with BagWriter(path, storage=storage, **kw) as bag:
        for frame in frames:
            bag.write_frame(frame)
    return path


def read_bag(path) -> dict[str, list]:
    """{topic: [(bag time, message), ...]} read with rosbags' AnyReader."""
    out: dict[str, list] = {}
    with rosbags_highlevel.AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, conn.msgtype, reader.deserialize(raw, conn.msgtype)))
    return out


def cloud_array(msg) -> np.ndarray:
    """A PointCloud2's points as a structured array built from its own field table."""
    types = {7: "<f4", 5: "<i4"}
    dtype = np.dtype({"names": [f.name for f in msg.fields], "formats": [types[f.datatype] for f in msg.fields],
                      "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_step})
    return np.frombuffer(np.asarray(msg.data, dtype=np.uint8).tobytes(), dtype=dtype)


# Conventions ---------------------------------------------------------------------------------


def test_beam_directions_hand_computed():
    # Z forward, X up, Y right: a beam to the left (theta > 0) points to -Y.
    dirs = beam_directions([0.0, 30.0, -45.0, 90.0])
    h = math.sqrt(0.5)
    expected = [[0, 0, 1], [0, -0.5, math.sqrt(3) / 2], [0, h, h], [0, -1, 0]]
    np.testing.assert_allclose(dirs, expected, atol=1e-15)


def test_image_frame_transform_maps_beam_directions_to_the_sonar_frame():
    # The sonar -> sonar_image rotation takes the message's direction of a beam at azimuth
    # theta to (cos theta, sin theta, 0) in sonarsim's sonar frame (x forward, y left).
    rot = quat_to_matrix(np.array(rb.SONAR_TO_IMAGE_QUAT_XYZW))
    np.testing.assert_allclose(rot, [[0, 0, 1], [0, -1, 0], [1, 0, 0]], atol=1e-15)
    theta = np.radians(AZIMUTH_DEG)
    in_sonar = beam_directions(AZIMUTH_DEG) @ rot.T
    np.testing.assert_allclose(in_sonar, np.stack([np.cos(theta), np.sin(theta), 0 * theta], 1), atol=1e-15)


# Round trips -----------------------------------------------------------------------------------


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_every_field_reads_back_with_rosbags(tmp_path, storage):
    frames = [synthetic_frame(i) for i in range(3)]
    ids = BagFrameIds(world="map", sonar="sonar_link", image="sonar_link_image")
    path = write_bag(tmp_path / "rosbag", storage, frames, frame_ids=ids)
    suffix = {"mcap": ".mcap", "sqlite3": ".db3"}[storage]
    assert sorted(p.name for p in path.iterdir()) == sorted(["metadata.yaml", "rosbag" + suffix])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rosbag"]  # no temporary folder left
    topics = read_bag(path)
    assert {t: [m[1] for m in v][0] for t, v in topics.items()} == {
        "/sonar/image": "marine_acoustic_msgs/msg/ProjectedSonarImage",
        "/sonar/fan": "sensor_msgs/msg/Image",
        "/sonar/pose": "geometry_msgs/msg/PoseStamped",
        "/tf": "tf2_msgs/msg/TFMessage",
        "/sonar/points": "sensor_msgs/msg/PointCloud2",
    }
    assert all(len(v) == 3 for v in topics.values())
    for i, frame in enumerate(frames):
        stamp = frame.stamp_ns
        sec, nanosec = 1_700_000_000 + i // 10, (i * 100_000_000) % 1_000_000_000
        for topic, msgs in topics.items():
            t, _, msg = msgs[i]
            assert t == stamp, topic
            headers = [tr.header for tr in msg.transforms] if topic == "/tf" else [msg.header]
            assert all((h.stamp.sec, h.stamp.nanosec) == (sec, nanosec) for h in headers), topic

        img = topics["/sonar/image"][i][2]
        assert img.header.frame_id == "sonar_link_image"
        assert img.image.is_bigendian is False
        assert img.image.dtype == 8  # DTYPE_FLOAT32
        assert img.image.beam_count == N_BEAMS
        # Range-major: cell (r, b) at index r * beam_count + b, value 100 i + 10 r + b.
        data = np.frombuffer(np.asarray(img.image.data, dtype=np.uint8).tobytes(), dtype="<f4")
        r, b = np.divmod(np.arange(N_RANGES * N_BEAMS), N_BEAMS)
        np.testing.assert_array_equal(data, 100 * i + 10 * r + b)
        np.testing.assert_array_equal(img.ranges, RANGE_M.astype(np.float32))
        dirs = np.array([[v.x, v.y, v.z] for v in img.beam_directions])
        theta = np.radians(AZIMUTH_DEG)
        np.testing.assert_allclose(dirs, np.stack([0 * theta, -np.sin(theta), np.cos(theta)], 1), atol=1e-15)
        np.testing.assert_allclose(np.degrees(np.arctan2(-dirs[:, 1], dirs[:, 2])), AZIMUTH_DEG, atol=1e-12)
        assert img.ping_info.frequency == pytest.approx(1.2e6)
        assert img.ping_info.sound_speed == pytest.approx(1480.0)
        np.testing.assert_allclose(img.ping_info.tx_beamwidths, np.radians([14.0] * 4), rtol=1e-7)
        np.testing.assert_allclose(img.ping_info.rx_beamwidths, np.radians([1.0, 2.0, 3.0, 4.0]), rtol=1e-7)

        fan = topics["/sonar/fan"][i][2]
        assert (fan.header.frame_id, fan.encoding, fan.height, fan.width, fan.step, fan.is_bigendian) == \
            ("sonar_link", "mono8", 6, 7, 7, 0)
        np.testing.assert_array_equal(np.asarray(fan.data).reshape(6, 7), frame.fan)

        pose = topics["/sonar/pose"][i][2]
        assert pose.header.frame_id == "map"
        p, q = pose.pose.position, pose.pose.orientation
        np.testing.assert_allclose([p.x, p.y, p.z], [1.0 + i, -2.0, 3.0], atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(np.array([q.x, q.y, q.z, q.w])), frame.pose.rotation, atol=1e-12)

        tf = topics["/tf"][i][2].transforms
        assert [(x.header.frame_id, x.child_frame_id) for x in tf] == \
            [("map", "sonar_link"), ("sonar_link", "sonar_link_image")]
        tr, rot = tf[0].transform.translation, tf[0].transform.rotation
        np.testing.assert_allclose([tr.x, tr.y, tr.z], [1.0 + i, -2.0, 3.0], atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(np.array([rot.x, rot.y, rot.z, rot.w])), frame.pose.rotation,
                                   atol=1e-12)
        rot = tf[1].transform.rotation
        assert [rot.x, rot.y, rot.z, rot.w] == pytest.approx(rb.SONAR_TO_IMAGE_QUAT_XYZW, abs=1e-15)

        cloud = topics["/sonar/points"][i][2]
        assert cloud.header.frame_id == "map"
        assert [f.name for f in cloud.fields] == ["x", "y", "z", "object"]
        assert (cloud.height, cloud.width, cloud.point_step, cloud.row_step, cloud.is_dense) == (1, 3, 16, 48, True)
        pts = cloud_array(cloud)
        np.testing.assert_array_equal(np.stack([pts["x"], pts["y"], pts["z"]], 1), frame.points_world)
        np.testing.assert_array_equal(pts["object"], [2, -1, 7])


def test_uint8_image_and_optional_messages(tmp_path):
    # A device model's 8-bit output: DTYPE_UINT8, one byte per cell; no fan, no points.
    frames = [synthetic_frame(i, dtype=np.uint8, fan=None, points_world=None, points_object=None) for i in range(2)]
    path = write_bag(tmp_path / "bag", "sqlite3", frames)
    with rosbags_highlevel.AnyReader([path]) as reader:  # no empty /sonar/fan or /sonar/points
        assert sorted(c.topic for c in reader.connections) == ["/sonar/image", "/sonar/pose", "/tf"]
    topics = read_bag(path)
    img = topics["/sonar/image"][1][2]
    assert img.image.dtype == 0
    np.testing.assert_array_equal(np.asarray(img.image.data), frames[1].polar.reshape(-1))


def test_float32_fan_is_32FC1(tmp_path):
    fan = np.linspace(0, 1, 12, dtype=np.float32).reshape(3, 4)
    topics = read_bag(write_bag(tmp_path / "bag", "mcap", [synthetic_frame(0, fan=fan)]))
    msg = topics["/sonar/fan"][0][2]
    assert (msg.encoding, msg.step) == ("32FC1", 16)
    np.testing.assert_array_equal(np.frombuffer(np.asarray(msg.data).tobytes(), "<f4").reshape(3, 4), fan)


def test_mcap_reads_back_with_the_mcap_ros2_decoder(tmp_path):
    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    frames = [synthetic_frame(i) for i in range(3)]
    path = write_bag(tmp_path / "rosbag", "mcap", frames)
    seen = {}
    with open(path / "rosbag.mcap", "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    assert seen["/sonar/image"][0][0] == "marine_acoustic_msgs/msg/ProjectedSonarImage"
    assert [m[1] for m in seen["/sonar/image"]] == [f.stamp_ns for f in frames]
    for i, (_, _, msg) in enumerate(seen["/sonar/image"]):
        values = np.frombuffer(bytes(msg.image.data), dtype="<f4").reshape(-1, msg.image.beam_count)
        np.testing.assert_array_equal(values, frames[i].polar)
        left = msg.beam_directions[0]  # azimuth +30 degrees
        assert (left.x, left.y, left.z) == pytest.approx((0.0, -0.5, math.sqrt(3) / 2), abs=1e-15)
    assert len(seen["/sonar/points"]) == 3 and seen["/sonar/points"][2][2].width == 3


def test_real_render_round_trip(tmp_path):
    # A block 0.6 m to the LEFT of the axis, 2.3 m ahead (nearest corner at 2.335 m), no
    # ground: its echo lies in the left-hand columns, which the bag must give y < 0, and in
    # the rows near 2.33 m, which must come first in the data (nearest row first).
    scene = {
        "sonar": sonar_dict(n_range_bins=100),
        "render": {"elevation_samples": 8},
        "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                     "pose": {"position_m": [2.5, 0.6, 0.0], "rpy_deg": [0, 0, 0]}}],
    }
    image = sonarsim.render(scene)
    frame = frame_from_image(image, stamp_ns=rb.DEFAULT_START_NS, fan=True, frequency_hz=900e3,
                             points_world=np.zeros((1, 3), np.float32), points_object=np.zeros(1, np.int32))
    topics = read_bag(write_bag(tmp_path / "rosbag", "mcap", [frame]))
    msg = topics["/sonar/image"][0][2]
    n_beams = msg.image.beam_count
    assert n_beams == 32 and len(msg.ranges) == 100
    data = np.frombuffer(np.asarray(msg.image.data, dtype=np.uint8).tobytes(), dtype="<f4")
    np.testing.assert_array_equal(data[0:n_beams], image.polar[0])  # the nearest range row
    cells = data.reshape(len(msg.ranges), n_beams)
    dirs = np.array([[v.x, v.y, v.z] for v in msg.beam_directions])
    assert image.azimuth_deg[0] > 0 and dirs[0, 1] < 0  # left-most beam, column 0
    left = dirs[:, 1] < 0
    assert cells[:, left].sum() > 0 and cells[:, ~left].sum() == 0
    first = np.nonzero(cells.sum(axis=1))[0][0]
    assert 2.3 <= msg.ranges[first] < 2.4
    bearing = np.degrees(np.arctan2(-dirs[:, 1], dirs[:, 2]))
    hit = bearing[np.nonzero(cells.sum(axis=0))[0]]
    # The block spans azimuths atan(0.4 / 2.7) = 8.4 to atan(0.8 / 2.3) = 19.2 degrees (clipped
    # by the 15-degree edge of the fan).
    assert hit.min() > 7.0 and hit.max() <= 15.0
    ping = msg.ping_info
    assert ping.frequency == pytest.approx(900e3) and ping.sound_speed == pytest.approx(1500.0)
    np.testing.assert_allclose(ping.tx_beamwidths, np.radians(14.0), rtol=1e-6)
    np.testing.assert_allclose(ping.rx_beamwidths, np.radians(30.0 / 32), rtol=1e-6)
    fan = topics["/sonar/fan"][0][2]
    assert (fan.height, fan.width) == image.fan().image.shape and fan.encoding == "32FC1"
    # the unit beside the image (no sensor, TVG on: sigma / r^2 per bin and radian)
    (stamp, msgtype, unit), = topics["/sonar/image/unit"]
    assert (stamp, msgtype, unit.data) == (rb.DEFAULT_START_NS, "std_msgs/msg/String", "backscatter")


def test_the_unit_is_written_with_the_first_frame_and_when_it_changes(tmp_path):
    frames = [synthetic_frame(i, unit=u) for i, u in enumerate(["counts", "counts", "uPa^2", ""])]
    topics = read_bag(write_bag(tmp_path / "rosbag", "mcap", frames))
    assert [(t, m.data) for t, _, m in topics["/sonar/image/unit"]] == [(frames[0].stamp_ns, "counts"),
                                                                       (frames[2].stamp_ns, "uPa^2")]
    # beside a remapped image topic
    topics = read_bag(write_bag(tmp_path / "remapped", "mcap", frames[:1], topics=rb.BagTopics(image="/aris/image")))
    assert "/aris/image/unit" in topics


# Safety --------------------------------------------------------------------------------------


def test_an_error_inside_the_block_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with BagWriter(tmp_path / "rosbag", storage="mcap") as bag:
            bag.write_frame(synthetic_frame(0))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_a_killed_run_leaves_no_bag_under_the_final_name(tmp_path):
    # The child writes a frame, says so and waits to be killed: the bag is only a hidden
    # temporary folder, which remove_abandoned_bags clears once the child is gone.
    code = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {os.path.dirname(os.path.dirname(os.path.dirname(__file__)))!r})
        from tests.io.test_rosbag import synthetic_frame
        from sonarsim.io.rosbag import BagWriter
        with BagWriter({str(tmp_path / "rosbag")!r}, storage="mcap") as bag:
            bag.write_frame(synthetic_frame(0))
            print("written", flush=True)
            time.sleep(60)
    """)
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "written"
        assert rb.remove_abandoned_bags(tmp_path) == []  # its writer is alive
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
        child.stdout.close()
    leftovers = [p.name for p in tmp_path.iterdir()]
    assert "rosbag" not in leftovers and len(leftovers) == 1 and leftovers[0].startswith(".rosbag.sonarsim-")
    assert rb.remove_abandoned_bags(tmp_path) == leftovers
    assert list(tmp_path.iterdir()) == []


def test_refuses_an_existing_bag_and_a_missing_parent(tmp_path):
    (tmp_path / "rosbag").mkdir()
    with pytest.raises(SonarsimError, match="exists already"):
        BagWriter(tmp_path / "rosbag").open()
    with pytest.raises(SonarsimError, match="no such folder"):
        BagWriter(tmp_path / "missing" / "rosbag").open()
    with pytest.raises(ConfigError, match="mcap, sqlite3"):
        BagWriter(tmp_path / "b", storage="bag")


def test_missing_rosbags_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)  # import fails
    rb._import_rosbags.cache_clear()
    try:
        with pytest.raises(SonarsimError, match=r"the 'rosbags' library .*install the ROS extra: pip install .*\[ros\]'$"):
            BagWriter(tmp_path / "rosbag").open()
    finally:
        rb._import_rosbags.cache_clear()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("override, key", [
    ({"range_m": RANGE_M[:4]}, "range_m"),
    ({"range_m": RANGE_M[::-1]}, "range_m"),
    ({"azimuth_deg": AZIMUTH_DEG[::-1]}, "azimuth_deg"),  # right-most first: the peers' mistake
    ({"polar": np.zeros((5, 4), np.complex64)}, "polar"),
    ({"polar": np.full((5, 4), np.nan, np.float32)}, "polar"),
    ({"rx_beamwidth_deg": [1.0, 2.0]}, "rx_beamwidth_deg"),
    ({"points_object": None}, "points_object"),
    ({"points_world": np.zeros((3, 2))}, "points_world"),
    ({"fan": np.zeros((3, 3), np.int16)}, "fan"),
    ({"stamp_ns": -1}, "stamp_ns"),
    ({"stamp_ns": 0}, "stamp_ns"),  # tf2 reads a zero stamp as "the latest transform"
    ({"stamp_ns": 2**31 * 10**9}, "stamp_ns"),  # builtin_interfaces/Time: int32 seconds
    ({"stamp_ns": 1.5}, "stamp_ns"),
    ({"sound_speed_m_s": 0.0}, "sound_speed_m_s"),
    ({"pose": (0, 0, 0)}, "pose"),
])
def test_bad_frames_are_refused_naming_the_field(override, key):
    with pytest.raises(ConfigError) as info:
        synthetic_frame(0, **override)
    assert info.value.key == f"bag_frame.{key}"


def test_frames_must_come_in_time_order(tmp_path):
    with pytest.raises(ConfigError, match="time order"):
        with BagWriter(tmp_path / "rosbag", storage="mcap") as bag:
            bag.write_frame(synthetic_frame(1))
            bag.write_frame(synthetic_frame(0))
    assert list(tmp_path.iterdir()) == []


def test_frame_ids_must_be_distinct_ros_names():
    with pytest.raises(ConfigError, match="distinct"):
        BagFrameIds(world="a", sonar="a")
    with pytest.raises(ConfigError, match="frame name"):
        BagFrameIds(world="my world")


def test_an_image_without_pose_cannot_make_a_frame():
    image = sonarsim.render({"sonar": sonar_dict(n_range_bins=20, n_beams=8), "render": {"elevation_samples": 4}})
    frame_from_image(image, stamp_ns=rb.DEFAULT_START_NS)  # a render carries its pose
    with pytest.raises(SonarsimError, match="pose"):
        frame_from_image(dataclasses.replace(image, pose=None), stamp_ns=rb.DEFAULT_START_NS)


def test_a_bag_without_frames_is_a_valid_empty_bag(tmp_path):
    path = write_bag(tmp_path / "rosbag", "mcap", [])
    with rosbags_highlevel.AnyReader([path]) as reader:
        assert reader.message_count == 0 and reader.connections == []


# Start time -----------------------------------------------------------------------------------

NOON = 1_714_564_800 * 10**9  # 2024-05-01T12:00:00Z


@pytest.mark.parametrize("value, expected", [
    ("2024-05-01T12:00:00Z", NOON),
    ("2024-05-01T14:00:00+02:00", NOON),
    ("2024-05-01T12:00:00", NOON),  # no offset: UTC, as YAML reads it
    ("20240501T120000Z", NOON),
    ("2024-05-01", NOON - 12 * 3600 * 10**9),
    ("2024-05-01T12:00:00.123456789Z", NOON + 123_456_789),  # nanoseconds kept (datetime: micro)
    ("2024-05-01T12:00:00,5Z", NOON + 500_000_000),
    ("1714564800", NOON),
    (" 1714564800.000000001 ", NOON + 1),
    ("1.7145648e9", NOON),
    (1714564800, NOON),
    (1714564800.25, NOON + 250_000_000),
    (np.int64(1714564800), NOON),
    ("2038-01-19T03:14:07.999999999Z", 2**31 * 10**9 - 1),
    ("1970-01-01T00:00:00.000000001Z", 1),
])
def test_start_times_in_iso_8601_or_seconds(value, expected):
    assert rb.parse_start_time(value) == expected


def test_start_times_from_yaml_timestamps():
    import datetime as dt

    assert rb.parse_start_time(dt.datetime(2024, 5, 1, 12)) == NOON  # naive: UTC
    assert rb.parse_start_time(dt.datetime(2024, 5, 1, 14, tzinfo=dt.timezone(dt.timedelta(hours=2)))) == NOON
    assert rb.parse_start_time(dt.date(2024, 5, 1)) == NOON - 12 * 3600 * 10**9


@pytest.mark.parametrize("value", ["now", "", "yesterday", "2024-13-01", "2024-05-01T25:00:00Z", "nan", "inf",
                                   "1e999999999", "-1", "0", 0, 0.0, -5, True, None, [2024], float("nan"),
                                   "1970-01-01T00:00:00Z", "2038-01-19T03:14:08Z", 2**31, "x" * 1000])
def test_bad_start_times_are_one_line_naming_the_option(value):
    with pytest.raises(ConfigError) as info:
        rb.parse_start_time(value, "--start-time")
    message = str(info.value)
    assert info.value.key == "--start-time" and "\n" not in message and len(message) < 400
    assert "ISO 8601" in message and "seconds since 1970-01-01T00:00:00Z" in message


def test_the_default_start_is_2000_not_zero():
    assert rb.DEFAULT_START_NS == rb.parse_start_time(rb.DEFAULT_START_TIME) == 946_684_800 * 10**9
    assert rb.format_stamp(rb.DEFAULT_START_NS) == "2000-01-01T00:00:00Z"
    assert rb.format_stamp(NOON + 123_000_000) == "2024-05-01T12:00:00.123Z"


def test_frame_stamps_start_at_the_start_and_step_as_the_times():
    assert rb.frame_stamps(NOON, [0.0, 0.25, 0.5]) == [NOON, NOON + 250_000_000, NOON + 500_000_000]
    # Times that do not start at zero (a track logged in seconds since 1970): frame 0 at the start.
    assert rb.frame_stamps(NOON, [1e9 + 0.5, 1e9 + 0.75]) == [NOON, NOON + 250_000_000]
    assert rb.frame_stamps(NOON, []) == []
    last = 2**31 * 10**9 - 10**9  # 2038-01-19T03:14:07Z
    assert rb.frame_stamps(last, [0.0, 0.5])[-1] == last + 500_000_000
    with pytest.raises(ConfigError) as info:
        rb.frame_stamps(last, [0.0, 0.5, 1.0], "--start-time")
    assert info.value.key == "--start-time" and "the last of 3 frames (1 s later)" in str(info.value)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_bag_is_byte_identical_when_written_again(tmp_path, storage):
    """Nothing in a bag comes from the clock: the same frames, the same files."""
    frames = [synthetic_frame(i) for i in range(3)]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    # The same folder name in both: the storage file is named after it.
    a = write_bag(tmp_path / "a" / "rosbag", storage, frames)
    b = write_bag(tmp_path / "b" / "rosbag", storage, frames)
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir()) and "metadata.yaml" in names
    for name in names:
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_an_8_bit_devices_image_is_bagged_as_uint8_and_its_fan_as_mono8(tmp_path):
    # Issue 37: a sensor model's 8-bit output was written as float32 (DTYPE_FLOAT32).
    scene = {"sonar": sonar_dict(n_range_bins=100), "render": {"elevation_samples": 8},
             "sensor": {"preset": "aris3000-64"},
             "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                          "pose": {"position_m": [2.5, 0.3, 0.0]}}]}
    sim = sonarsim.Simulator(scene)
    image = sim.render()
    assert image.polar.dtype == np.float32 and np.array_equal(image.polar, np.round(image.polar))
    frame = frame_from_image(image, stamp_ns=rb.DEFAULT_START_NS, fan=True)
    assert frame.polar.dtype == np.uint8 and frame.fan.dtype == np.uint8
    np.testing.assert_array_equal(frame.polar, image.polar.astype(np.uint8))
    topics = read_bag(write_bag(tmp_path / "rosbag", "mcap", [frame]))
    msg = topics["/sonar/image"][0][2]
    assert msg.image.dtype == 0  # DTYPE_UINT8
    data = np.asarray(msg.image.data, dtype=np.uint8).reshape(-1, msg.image.beam_count)
    np.testing.assert_array_equal(data, image.polar.astype(np.uint8))
    fan = topics["/sonar/fan"][0][2]
    assert fan.encoding == "mono8"
    # The expected output (a mean over the speckle: fractional counts) stays float32.
    expected = sim.render(speckle=False)
    assert rb.device_polar(expected).dtype == np.float32


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_write_cdr_stores_a_recorders_bytes_as_they_came(tmp_path, storage):
    """Messages already serialised (a recorder's) are stored byte for byte, one connection per
    topic beside the frames' own, at the stamps given; a type change on a topic and a type the
    typestore lacks are refused by name."""
    from rosbags.rosbag2 import Reader

    from sonarsim.io.rosbag_instruments import instrument_typestore

    store = instrument_typestore()
    string_t = store.types["std_msgs/msg/String"]
    sent = [(f"/chat/{k % 2}", 10 + k, bytes(store.serialize_cdr(string_t(data="x" * k), "std_msgs/msg/String")))
            for k in range(5)]
    path = tmp_path / "bag"
    with BagWriter(path, storage=storage) as bag:
        bag.write_frame(synthetic_frame(0))
        for topic, stamp, cdr in sent:
            bag.write_cdr(topic, "std_msgs/msg/String", stamp, cdr)
        with pytest.raises(ConfigError, match=r"/chat/0 carries std_msgs/msg/String, not std_msgs/msg/Header"):
            bag.write_cdr("/chat/0", "std_msgs/msg/Header", 20, sent[0][2])
        with pytest.raises(ConfigError, match=r"/x: no_pkg/msg/Nothing is not a message"):
            bag.write_cdr("/x", "no_pkg/msg/Nothing", 20, b"")
    with BagWriter(tmp_path / "closed") as bag:
        pass
    with pytest.raises(SonarsimError, match="not open"):
        bag.write_cdr("/chat/0", "std_msgs/msg/String", 1, sent[0][2])
    with Reader(path) as reader:
        got = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages() if c.topic.startswith("/chat/")]
        topics = sorted(c.topic for c in reader.connections)
    assert sorted(got, key=lambda g: g[1]) == sent
    assert "/sonar/image" in topics and topics.count("/chat/0") == 1 and topics.count("/chat/1") == 1
    assert [store.deserialize_cdr(raw, "std_msgs/msg/String").data for _, _, raw in sorted(got, key=lambda g: g[1])] == \
        ["x" * k for k in range(5)]
