"""ROS 2 bags of every instrument (sonarsim.io.rosbag_instruments), read back with rosbags.

Films are built by hand with values that show any reordering (sample ``k`` of side ``s`` of ping
``p`` holds ``1000 p + 10 s + k`` scaled), so every field is checked against the film: samples,
sample rate and first sample (the range of each row by the reference viewer's formula), angles,
widths, stamps, frame ids; the TF chain world -> vehicle -> mount -> image frame, applied to each
beam's direction, gives the channel's axis and position in the world; a multibeam's point cloud,
moved by world -> vehicle, lands on the soundings' world points.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from types import SimpleNamespace
from typing import ClassVar

import numpy as np
import pytest

import sonarsim
from sonarsim.config.instruments import Channel, InstrumentSpec, mounted
from sonarsim.config.sonar import SonarConfig
from sonarsim.core.transforms import Pose, quat_to_matrix
from sonarsim.errors import ConfigError
from sonarsim.image.films import Envelope, PingGeometry, Soundings, Waterfall, range_axis
from sonarsim.instruments import vehicle_poses
from sonarsim.instruments.scanning import ScanImage
from sonarsim.io import rosbag as rb
from sonarsim.io import rosbag_instruments as ri

rosbags_highlevel = pytest.importorskip("rosbags.highlevel")

START = rb.DEFAULT_START_NS
C = 1500.0

SCENE = {
    "vehicle": {"pose": {"position_m": [3.0, -2.0, 12.0], "rpy_deg": [4.0, -3.0, 30.0]}, "speed_m_s": 1.5},
    "instruments": [
        {"type": "sidescan", "name": "sss", "range_max_m": 20.0, "n_samples": 40, "ping_rate_hz": 10,
         "depression_deg": 12.0, "horizontal_beam_width_deg": 0.7, "vertical_beam_width_deg": 45.0,
         "frequency_khz": 600, "mount": {"position_m": [0.5, 0.0, -0.1], "rpy_deg": [0.0, 2.0, 0.0]}},
        {"type": "scanning", "name": "head", "range_min_m": 0.5, "range_max_m": 10.5, "n_samples": 50,
         "tilt_deg": 10.0, "mount": {"position_m": [0.2, 1.0, 0.3], "rpy_deg": [0.0, 0.0, 15.0]}},
        {"type": "singlebeam", "name": "alt", "beam_width_deg": 8.0, "range_max_m": 30.0, "n_samples": 60,
         "ping_rate_hz": 4, "mount": {"position_m": [0.5, 0.0, -0.2]}},
    ],
    "ground": {"height_m": 0.0},
}


def read_bag(path) -> dict[str, list]:
    """{topic: [(bag time, msgtype, message), ...]} in bag order."""
    out: dict[str, list] = {}
    with rosbags_highlevel.AnyReader([path]) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, conn.msgtype, reader.deserialize(raw, conn.msgtype)))
    return out


def geometry(n: int, t0: float, period: float, c=C, lo=0.0, hi=20.0) -> PingGeometry:
    return PingGeometry.of(n, time_s=t0 + period * np.arange(n), sound_speed_m_s=c, range_min_m=lo, range_max_m=hi)


def waterfall(n=3, n_samples=40) -> Waterfall:
    p, s, k = np.mgrid[0:n, 0:2, 0:n_samples]
    return Waterfall((1000 * p + 10 * s + k).astype(np.float32) * 1e-3, 0.0, 20.0, geometry(n, 0.0, 0.1))


def scan(n=4, n_samples=50, angles=(0.0, 90.0, 200.0, 359.1)) -> ScanImage:
    k, p = np.mgrid[0:n_samples, 0:n]
    g = geometry(n, 0.05, 0.2, lo=0.5, hi=10.5)
    return ScanImage((100 * p + k).astype(np.float32), np.array(angles[:n], float), 0.5, 10.5, g, 0.9)


def envelope(n=2, n_samples=60) -> Envelope:
    p, k = np.mgrid[0:n, 0:n_samples]
    return Envelope((100 * p + k).astype(np.float32), 0.0, 30.0, np.array([11.75, np.nan])[:n],
                    geometry(n, 0.02, 0.25, c=1490.0, hi=30.0), unit_name="cross_section_per_r2")


def transform_matrix(tf) -> np.ndarray:
    m = np.eye(4)
    q = tf.transform.rotation
    m[:3, :3] = quat_to_matrix(np.array([q.x, q.y, q.z, q.w]))
    v = tf.transform.translation
    m[:3, 3] = (v.x, v.y, v.z)
    return m


def tf_tree(bag: dict) -> tuple[dict, dict]:
    """(static {child: (parent, matrix)}, dynamic {stamp: {child: (parent, matrix)}})."""
    static = {}
    for _, _, msg in bag["/tf_static"]:
        for tf in msg.transforms:
            static[tf.child_frame_id] = (tf.header.frame_id, transform_matrix(tf))
    dynamic: dict = {}
    for t, _, msg in bag["/tf"]:
        for tf in msg.transforms:
            stamp = tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec
            assert stamp == t
            dynamic.setdefault(stamp, {})[tf.child_frame_id] = (tf.header.frame_id, transform_matrix(tf))
    return static, dynamic


def world_from(frame: str, stamp: int, static: dict, dynamic: dict) -> np.ndarray:
    """The frame's pose in 'world' at ``stamp``, composed along the tree."""
    m = np.eye(4)
    while frame != "world":
        parent, local = static[frame] if frame in static else dynamic[stamp][frame]
        m = local @ m
        frame = parent
    return m


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def image_array(img, n_rows: int) -> np.ndarray:
    assert img.dtype == 8 and not img.is_bigendian
    return np.frombuffer(np.asarray(img.data, np.uint8).tobytes(), "<f4").reshape(n_rows, img.beam_count)


def write(tmp_path, films, scene, **kw):
    return ri.write_instrument_bag(tmp_path / "bag", films, scene, **kw)


@pytest.fixture(scope="module")
def scene():
    return sonarsim.load_scene(SCENE)


# Types ---------------------------------------------------------------------------------------


def test_types_are_registered_with_marine_acoustic_msgs_field_layout(tmp_path, scene):
    write(tmp_path, {"sss": waterfall(1)}, scene)
    _, _, store = rb._import_rosbags()
    fields = lambda name: [f[0] for f in store.fielddefs[name][1]]  # noqa: E731
    assert fields("marine_acoustic_msgs/msg/RawSonarImage") == [
        "header", "ping_info", "sample_rate", "samples_per_beam", "sample0", "tx_delays", "tx_angles", "rx_angles",
        "image"]
    assert fields("marine_acoustic_msgs/msg/SonarDetections") == [
        "header", "ping_info", "flags", "two_way_travel_times", "tx_delays", "intensities", "tx_angles", "rx_angles"]
    assert fields("marine_acoustic_msgs/msg/DetectionFlag") == ["flag"]
    flag = store.types["marine_acoustic_msgs/msg/DetectionFlag"]
    assert (flag.DETECT_OK, flag.DETECT_BAD_SONAR, flag.DETECT_BAD_FILTER, flag.DETECT_BAD_USER) == (0, 1, 2, 4)
    assert fields("marine_acoustic_msgs/msg/PingInfo") == ["frequency", "sound_speed", "tx_beamwidths",
                                                         "rx_beamwidths"]
    with rosbags_highlevel.AnyReader([tmp_path / "bag"]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types == {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage",
                     "/sss/raw": "marine_acoustic_msgs/msg/RawSonarImage", "/sss/unit": "std_msgs/msg/String"}


def test_beam_unit_vectors_hand_computed():
    v = ri.beam_unit_vectors([0.0, 0.0, -math.pi / 2, math.radians(30)], [0.0, math.pi / 2, 0.0, math.radians(-60)])
    np.testing.assert_allclose(v, [[0, 0, 1], [0, 1, 0], [-1, 0, 0],
                                   [0.5, math.cos(math.radians(30)) * -math.sin(math.radians(60)),
                                    math.cos(math.radians(30)) * 0.5]], atol=1e-15)


# Side-scan, scanning, single-beam -------------------------------------------------------------


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_every_field_of_three_instruments_round_trips(tmp_path, scene, storage):
    w, s, e = waterfall(), scan(), envelope()
    write(tmp_path, {"sss": w, "head": s, "alt": e}, scene, storage=storage)
    bag = read_bag(tmp_path / "bag")
    specs = {i.name: i for i in scene.instruments}
    assert set(bag) == {"/tf_static", "/tf", "/sss/raw", "/head/raw", "/alt/raw", "/alt/range",
                        "/sss/unit", "/head/unit", "/alt/unit"}
    # Each film's unit, once, with its first ping (issue 39 item 6).
    for topic, film in (("/sss/unit", w), ("/head/unit", s), ("/alt/unit", e)):
        assert [(m.data, t) for t, _, m in bag[topic]] == [(film.unit_name, bag[topic.replace("unit", "raw")][0][0])]
    assert bag["/alt/unit"][0][2].data == "cross_section_per_r2" and bag["/sss/unit"][0][2].data == "counts"

    # Stamps: the earliest ping (the waterfall's, t = 0) at START; the others by their times.
    def expected(film):
        return [START + round(float(t) * 1e9) for t in film.geometry.time_s]
    for topic, film in (("/sss/raw", w), ("/head/raw", s), ("/alt/raw", e), ("/alt/range", e)):
        assert [t for t, _, _ in bag[topic]] == expected(film), topic
        assert [stamp_of(m) for _, _, m in bag[topic]] == expected(film), topic
    # One world -> vehicle per distinct stamp, in time order.
    all_stamps = sorted(set(expected(w) + expected(s) + expected(e)))
    assert [t for t, _, _ in bag["/tf"]] == all_stamps

    # Side-scan: 2 beams per ping, sample-major, port beam 0.
    sss = specs["sss"]
    dr = 20.0 / 40
    for p, (_, _, m) in enumerate(bag["/sss/raw"]):
        assert m.header.frame_id == "sss_image"
        assert m.samples_per_beam == 40 and m.image.beam_count == 2 and m.sample0 == 0
        np.testing.assert_array_equal(image_array(m.image, 40), w.samples[p].T)
        # the reference viewer's range of sample number n: n c / (2 sample_rate) = n dr
        assert m.sample_rate == pytest.approx(C / (2 * dr), rel=1e-7)
        assert 17 * m.ping_info.sound_speed / (2 * m.sample_rate) == pytest.approx(17 * dr, rel=1e-6)
        np.testing.assert_allclose(m.rx_angles, np.radians([-78.0, 78.0]), rtol=1e-6)
        np.testing.assert_array_equal(m.tx_angles, [0, 0])
        np.testing.assert_array_equal(m.tx_delays, [0, 0])
        assert m.ping_info.frequency == 600e3 and m.ping_info.sound_speed == C
        np.testing.assert_allclose(m.ping_info.tx_beamwidths, np.radians([0.7, 0.7]), rtol=1e-6)
        np.testing.assert_allclose(m.ping_info.rx_beamwidths, np.radians([45.0, 45.0]), rtol=1e-6)

    # Scanning: one beam per step at -head angle (wrapped), tilt as -tx; window from 0.5 m.
    head = specs["head"]
    for p, (_, _, m) in enumerate(bag["/head/raw"]):
        assert m.header.frame_id == "head_image" and m.image.beam_count == 1
        np.testing.assert_array_equal(image_array(m.image, 50)[:, 0], s.samples[:, p])
        dr = 10.0 / 50
        assert m.sample0 == 3  # 0.5 m / 0.2 m = 2.5 -> 3 (the exact window is in custom_data)
        wrapped = -((s.angle_deg[p] + 180.0) % 360.0 - 180.0)
        assert m.rx_angles[0] == pytest.approx(math.radians(wrapped), abs=1e-6)
        assert -math.pi < m.rx_angles[0] <= math.pi
        assert m.tx_angles[0] == pytest.approx(math.radians(-10.0), rel=1e-6)
        np.testing.assert_allclose(m.ping_info.rx_beamwidths, [math.radians(head.horizontal_beam_width_deg)], rtol=1e-6)
        np.testing.assert_allclose(m.ping_info.tx_beamwidths, [math.radians(head.vertical_beam_width_deg)], rtol=1e-6)
        assert m.ping_info.frequency == head.frequency_khz * 1e3
    assert [round(math.degrees(m.rx_angles[0]), 4) for _, _, m in bag["/head/raw"]] == [0.0, -90.0, 160.0, 0.9]

    # Single-beam: its envelope and a Range of the bottom (+inf where none).
    for p, (_, _, m) in enumerate(bag["/alt/raw"]):
        np.testing.assert_array_equal(image_array(m.image, 60)[:, 0], e.samples[p])
        assert m.ping_info.sound_speed == 1490.0
        assert m.sample_rate == pytest.approx(1490.0 / (2 * 0.5), rel=1e-7)
    ranges = [m for _, _, m in bag["/alt/range"]]
    assert ranges[0].range == 11.75 and math.isinf(ranges[1].range) and ranges[1].range > 0
    assert ranges[0].header.frame_id == "alt_beam" and ranges[0].radiation_type == 0
    assert ranges[0].field_of_view == pytest.approx(math.radians(8.0)) and ranges[0].max_range == 30.0

    # custom_data: the exact windows.
    import yaml

    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    info = json.loads(meta["custom_data"]["sonarsim.instruments"])
    assert info["head"]["range_min_m"] == 0.5 and info["head"]["n_samples"] == 50
    assert info["sss"]["topics"] == {"raw": "/sss/raw", "unit": "/sss/unit"} and info["alt"]["beam_frame"] == "alt_beam"
    assert info["alt"]["unit"] == "cross_section_per_r2" and info["sss"]["unit"] == "counts"


def test_tf_chain_gives_each_channel_its_world_pose(tmp_path, scene):
    """Per message: world -> vehicle (its stamp) -> mount -> image frame, applied to each beam's
    (tx, rx) direction and origin, is the channel's axis and position in the world."""
    w, s, e = waterfall(), scan(), envelope()
    write(tmp_path, {"sss": w, "head": s, "alt": e}, scene)
    bag = read_bag(tmp_path / "bag")
    static, dynamic = tf_tree(bag)
    specs = {i.name: i for i in scene.instruments}
    assert static["sss"][0] == "vehicle" and static["sss_image"][0] == "sss" and dynamic[START]["vehicle"][0] == "world"
    # The vehicle the renders would have used: the scene's, running ahead at 1.5 m/s.
    sim_like = SimpleNamespace(scene=scene)

    def check(name, topic, film, channel_world):
        poses, _ = vehicle_poses(sim_like, specs[name], times_s=film.geometry.time_s)
        for p, (_, _, m) in enumerate(bag[topic]):
            stamp = stamp_of(m)
            img = world_from(m.header.frame_id, stamp, static, dynamic)
            dirs = ri.beam_unit_vectors(m.tx_angles, m.rx_angles)
            for b, d in enumerate(dirs):
                want = channel_world(poses[p], p, b)
                np.testing.assert_allclose(img[:3, :3] @ d, want.rotation[:, 0], atol=1e-6)
                np.testing.assert_allclose(img[:3, 3], want.translation, atol=1e-9)

    channels = specs["sss"].channels()
    check("sss", "/sss/raw", w, lambda v, p, b: mounted(v, channels[b].mount))
    check("head", "/head/raw", s, lambda v, p, b: mounted(v, specs["head"].step_mount(s.angle_deg[p])))
    check("alt", "/alt/raw", e, lambda v, p, b: mounted(v, specs["alt"].channels()[0].mount))
    # The Range's frame has x along the beam.
    poses, _ = vehicle_poses(sim_like, specs["alt"], times_s=e.geometry.time_s)
    m = bag["/alt/range"][0][2]
    beam = world_from(m.header.frame_id, stamp_of(m), static, dynamic)
    np.testing.assert_allclose(beam[:3, 0], mounted(poses[0], specs["alt"].channels()[0].mount).rotation[:, 0],
                               atol=1e-9)
    np.testing.assert_allclose(beam[:3, 0], [0, 0, -1], atol=0.1)  # about straight down


def test_given_poses_are_the_vehicle_transforms(tmp_path, scene):
    w = waterfall(2)
    poses = [Pose((1.0, 2.0, 3.0), (10.0, 20.0, 30.0)), Pose((4.0, 5.0, 6.0), (-5.0, 0.0, 170.0))]
    write(tmp_path, {"sss": w}, scene, poses={"sss": poses}, start_ns=1_700_000_000_123_456_789)
    bag = read_bag(tmp_path / "bag")
    _, dynamic = tf_tree(bag)
    for k, stamp in enumerate(sorted(dynamic)):
        assert stamp == 1_700_000_000_123_456_789 + k * 100_000_000
        np.testing.assert_allclose(dynamic[stamp]["vehicle"][1], poses[k].matrix(), atol=1e-12)


# Multibeam -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class StubMultibeam(InstrumentSpec):
    """A multibeam as the tests need one (not registered: the real type is another module's)."""

    type_name: ClassVar[str] = "multibeam"
    frequency_khz: float = 400.0
    sound_speed_m_s: float = C

    def channels(self):
        sonar = SonarConfig.uniform(n_beams=5, azimuth_fov_deg=100.0, elevation_fov_deg=1.0, range_min_m=0.0,
                                    range_max_m=30.0, n_range_bins=8, frequency_khz=self.frequency_khz)
        return (Channel("swath", sonar, mounted(self.mount, Pose((0, 0, 0), (0.0, 90.0, 0.0)))),)

    def ping_period_s(self):
        return 0.5


def soundings(vehicles, mount, altitude=10.0, water_column=True) -> Soundings:
    """A flat floor ``altitude`` below a level head: beam at angle a meets it at r = h / cos a."""
    n = len(vehicles)
    angle = np.tile(np.array([40.0, 20.0, 0.0, -20.0, -40.0]), (n, 1))
    r = altitude / np.cos(np.radians(angle))
    twtt = 2 * r / C
    twtt[1, 4] = np.nan  # no detection
    a = np.radians(angle)
    head = np.stack([np.zeros_like(r), r * np.sin(a), -r * np.cos(a)], axis=-1)
    world = np.stack([[mounted(v, mount).matrix()[:3, :3] @ q + mounted(v, mount).translation for q in head[p]]
                      for p, v in enumerate(vehicles)])
    wc = None
    if water_column:
        k, b = np.mgrid[0:8, 0:5]
        wc = np.stack([(100 * p + 10 * k + b).astype(np.float32) for p in range(n)])
    g = PingGeometry.of(n, time_s=0.5 * np.arange(n), sound_speed_m_s=C, range_min_m=0.0, range_max_m=30.0)
    return Soundings(angle, twtt, np.arange(n * 5, dtype=float).reshape(n, 5) + 0.25, g, wc, world)


def test_multibeam_detections_points_and_water_column(tmp_path):
    mount = Pose((0.3, -0.2, -0.5), (0.0, 0.0, 0.0))
    spec = StubMultibeam(name="mbes", mount=mount)
    vehicle = [Pose((10.0, 5.0, 10.5), (0.0, 0.0, 60.0)), Pose((11.0, 5.5, 10.5), (0.0, 0.0, 62.0))]
    film = soundings(vehicle, mount)
    fake_scene = SimpleNamespace(instruments=(spec,), vehicle_pose=vehicle[0], vehicle_speed_m_s=0.0)
    write(tmp_path, {"mbes": film}, fake_scene, poses={"mbes": vehicle})
    bag = read_bag(tmp_path / "bag")
    assert {t: bag[t][0][1] for t in ("/mbes/detections", "/mbes/points", "/mbes/water_column")} == {
        "/mbes/detections": "marine_acoustic_msgs/msg/SonarDetections", "/mbes/points": "sensor_msgs/msg/PointCloud2",
        "/mbes/water_column": "marine_acoustic_msgs/msg/ProjectedSonarImage"}
    static, dynamic = tf_tree(bag)
    for p in range(2):
        d = bag["/mbes/detections"][p][2]
        assert d.header.frame_id == "mbes_image" and stamp_of(d) == START + p * 500_000_000
        np.testing.assert_allclose(d.two_way_travel_times, film.two_way_time_s[p].astype(np.float32))
        np.testing.assert_allclose(d.rx_angles, -np.radians(film.angle_deg[p]), rtol=1e-6)  # + starboard
        assert [f.flag for f in d.flags] == ([0, 0, 0, 0, 0] if p == 0 else [0, 0, 0, 0, 1])
        np.testing.assert_array_equal(d.intensities, film.intensity[p].astype(np.float32))
        assert d.ping_info.frequency == 400e3
        np.testing.assert_allclose(d.ping_info.tx_beamwidths, np.radians([1.0] * 5), rtol=1e-6)
        np.testing.assert_allclose(d.ping_info.rx_beamwidths, np.radians([20.0] * 5), rtol=1e-6)
        # the detections' directions (tx, rx) times c t / 2 from the image frame: the world points
        img = world_from("mbes_image", stamp_of(d), static, dynamic)
        ok = np.isfinite(film.two_way_time_s[p])
        dirs = ri.beam_unit_vectors(d.tx_angles, d.rx_angles)[ok]
        r = (np.asarray(d.two_way_travel_times, float) * d.ping_info.sound_speed / 2)[ok]
        np.testing.assert_allclose((img[:3, :3] @ (dirs * r[:, None]).T).T + img[:3, 3], film.points_m[p][ok],
                                   atol=1e-4)
        # the cloud: vehicle frame, x y z intensity; moved by world -> vehicle it is the truth
        c = bag["/mbes/points"][p][2]
        assert c.header.frame_id == "vehicle" and c.width == ok.sum() and c.point_step == 16
        assert [(f.name, f.offset, f.datatype) for f in c.fields] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7),
                                                                    ("intensity", 12, 7)]
        pts = np.frombuffer(np.asarray(c.data, np.uint8).tobytes(), "<f4").reshape(-1, 4)
        veh = world_from("vehicle", stamp_of(c), static, dynamic)
        np.testing.assert_allclose(pts[:, :3] @ veh[:3, :3].T + veh[:3, 3], film.points_m[p][ok], atol=1e-4)
        np.testing.assert_array_equal(pts[:, 3], film.intensity[p][ok].astype(np.float32))
        # the water column: the FLS's conventions in the image frame (beam at a: (0, -sin a, cos a))
        wc = bag["/mbes/water_column"][p][2]
        assert wc.header.frame_id == "mbes_image" and wc.image.beam_count == 5
        np.testing.assert_array_equal(image_array(wc.image, 8), film.water_column[p])
        np.testing.assert_allclose(wc.ranges, range_axis(0.0, 30.0, 8), rtol=1e-6)
        a = np.radians(film.angle_deg[p])
        np.testing.assert_allclose([[v.x, v.y, v.z] for v in wc.beam_directions],
                                   np.stack([0 * a, -np.sin(a), np.cos(a)], -1), atol=1e-12)
    # the image frame of a down-looking head: forward, starboard, down
    np.testing.assert_allclose(static["mbes_image"][1][:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)


# FLS -----------------------------------------------------------------------------------------


def test_an_fls_on_the_vehicle_writes_its_projected_image(tmp_path):
    doc = {"vehicle": {"pose": {"position_m": [0.0, 0.0, 2.0]}},
           "instruments": [{"type": "fls", "name": "fls", "n_beams": 16, "azimuth_fov_deg": 60,
                            "elevation_fov_deg": 12, "range_min_m": 0.5, "range_max_m": 6.0, "n_range_bins": 32,
                            "mount": {"position_m": [0.4, 0.0, 0.0], "rpy_deg": [0, 20, 0]}}],
           "ground": {"height_m": 0.0}, "render": {"max_order": 1, "elevation_samples": 16}}
    from sonarsim.instruments import render_pings

    with sonarsim.Simulator(doc) as sim:
        images = render_pings(sim, "fls", n_pings=2, speckle=False)
        write(tmp_path, {"fls": images}, sim, times_s={"fls": [0.0, 0.1]})
    bag = read_bag(tmp_path / "bag")
    static, dynamic = tf_tree(bag)
    for p, (t, _, m) in enumerate(bag["/fls/image"]):
        assert t == START + p * 100_000_000 and m.header.frame_id == "fls_image"
        np.testing.assert_array_equal(image_array(m.image, 32), images[p].polar)
        np.testing.assert_allclose(m.ranges, images[p].range_m, rtol=1e-6)
        # world -> vehicle -> fls is the image's own pose (the render's)
        np.testing.assert_allclose(world_from("fls", t, static, dynamic), images[p].pose.matrix(), atol=1e-9)
        np.testing.assert_allclose(static["fls_image"][1][:3, :3], quat_to_matrix(np.array(rb.SONAR_TO_IMAGE_QUAT_XYZW)),
                                   atol=1e-12)


# Errors and atomicity ------------------------------------------------------------------------


def test_wrong_inputs_are_named(tmp_path, scene):
    with pytest.raises(ConfigError, match=r"films\.nope.*sss, head, alt"):
        write(tmp_path, {"nope": waterfall()}, scene)
    with pytest.raises(ConfigError, match=r"films\.head.*scanning.*Waterfall"):
        write(tmp_path, {"head": waterfall()}, scene)
    with pytest.raises(ConfigError, match=r"poses\.sss.*3 Poses"):
        write(tmp_path, {"sss": waterfall()}, scene, poses={"sss": [Pose()]})
    # Two instruments pinging at one time must agree where the vehicle is.
    with pytest.raises(ConfigError, match=r"poses\.head.*ping 0.*sss's ping 0.*elsewhere"):
        write(tmp_path, {"sss": waterfall(1), "head": scan(1)}, scene, times_s={"head": [0.0]},
              poses={"sss": [Pose()], "head": [Pose((1.0, 0.0, 0.0))]})
    assert not (tmp_path / "bag").exists()


def test_a_failure_while_writing_leaves_no_bag(tmp_path):
    mount = Pose()
    spec = StubMultibeam(name="mbes", mount=mount)
    vehicle = [Pose(), Pose()]
    film = soundings(vehicle, mount)
    bad = Soundings(film.angle_deg, film.two_way_time_s, film.intensity,
                    PingGeometry.of(2, time_s=[0.0, 0.5], sound_speed_m_s=C, range_min_m=[0.0, np.nan],
                                    range_max_m=30.0), film.water_column, film.points_m)
    fake_scene = SimpleNamespace(instruments=(spec,), vehicle_pose=Pose(), vehicle_speed_m_s=0.0)
    with pytest.raises(ConfigError, match=r"mbes.*ping 1.*range window"):
        write(tmp_path, {"mbes": bad}, fake_scene, poses={"mbes": vehicle})
    assert list(tmp_path.iterdir()) == []  # neither the bag nor its temporary folder


def test_the_mcap_ros2_decoder_reads_the_new_types(tmp_path, scene):
    """An independent decoder (mcap_ros2, from the definitions the bag carries) reads the same values."""
    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    mount = Pose((0.3, -0.2, -0.5), (0.0, 0.0, 0.0))
    spec = StubMultibeam(name="mbes", mount=mount)
    vehicle = [Pose((10.0, 5.0, 10.5), (0.0, 0.0, 60.0)), Pose((11.0, 5.5, 10.5), (0.0, 0.0, 62.0))]
    film = soundings(vehicle, mount)
    fake_scene = SimpleNamespace(instruments=(spec, *scene.instruments), vehicle_pose=vehicle[0],
                                 vehicle_speed_m_s=0.0)
    w = waterfall()
    write(tmp_path, {"mbes": film, "sss": w}, fake_scene, poses={"mbes": vehicle, "sss": vehicle + vehicle[:1]})
    seen: dict = {}
    with open(tmp_path / "bag" / "bag.mcap", "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    assert seen["/sss/raw"][0][0] == "marine_acoustic_msgs/msg/RawSonarImage"
    assert seen["/mbes/detections"][0][0] == "marine_acoustic_msgs/msg/SonarDetections"
    for p, (_, _, m) in enumerate(seen["/sss/raw"]):
        np.testing.assert_array_equal(np.frombuffer(bytes(m.image.data), "<f4").reshape(40, 2), w.samples[p].T)
        assert m.samples_per_beam == 40 and list(m.rx_angles) == pytest.approx(np.radians([-78.0, 78.0]), rel=1e-6)
    m = seen["/mbes/detections"][1][2]
    assert [f.flag for f in m.flags] == [0, 0, 0, 0, 1]
    np.testing.assert_allclose(m.two_way_travel_times, film.two_way_time_s[1].astype(np.float32))


# Real recordings -----------------------------------------------------------------------------

from pathlib import Path  # noqa: E402

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"


def test_recording_poses_from_logged_geometry():
    g = PingGeometry.of(3, time_s=[0, 1, 2], x_m=[np.nan, 1.0, 2.0], y_m=[np.nan, 5.0, np.nan],
                        depth_m=[np.nan, 10.0, 12.0], roll_deg=[1.0, 2.0, 3.0], pitch_deg=0.0,
                        heading_deg=[np.nan, 0.0, 90.0])
    film = Envelope(np.zeros((3, 4), np.float32), 0.0, 1.0, np.full(3, np.nan), g)
    poses = ri.recording_poses(film)
    assert [p.position_m for p in poses] == [(1.0, 5.0, -10.0), (1.0, 5.0, -10.0), (2.0, 5.0, -12.0)]
    # heading 0 (north, +y) is yaw 90; heading 90 (east, +x) yaw 0
    np.testing.assert_allclose([p.rpy_deg for p in poses], [[1, 0, 90], [2, 0, 90], [3, 0, 0]], atol=1e-9)


@pytest.mark.skipif(not (REAL / "sidescan").is_dir(), reason="../shared/data/real is absent")
def test_a_real_side_scan_recording_converts_to_a_bag(tmp_path):
    """The Sea Scan HDS XTF (180 pings, 1024 samples a side): every ping's two lines, its real
    time (seconds since 1970, kept with start_ns) and its logged pose reach the bag."""
    pytest.importorskip("pyxtf")
    from sonarsim.io.readers.xtf import read_waterfall

    w = read_waterfall(REAL / "sidescan" / "iver2_seascan_pings_0-179.xtf")
    doc = {"instruments": [{"type": "sidescan", "name": "seascan", "preset": "seascan_hds_600",
                            "range_max_m": float(w.range_max_m), "n_samples": int(w.n_samples)}]}
    poses = ri.recording_poses(w)
    ns = lambda t: rb._seconds_ns(repr(float(t)))  # noqa: E731 - the logged decimal seconds, to the ns
    t0_ns = ns(w.geometry.time_s[0])
    write(tmp_path, {"seascan": w}, sonarsim.load_scene(doc), poses={"seascan": poses}, start_ns=t0_ns)
    bag = read_bag(tmp_path / "bag")
    msgs = [m for _, _, m in bag["/seascan/raw"]]
    assert len(msgs) == w.n_pings == 180
    for k in (0, 1, 90, 179):
        np.testing.assert_array_equal(image_array(msgs[k].image, 1024), w.samples[k].T)
        assert stamp_of(msgs[k]) == ns(w.geometry.time_s[k])  # the recording's own time
    assert msgs[1].sample_rate == pytest.approx(1500.0 / (2 * w.range_max_m / 1024), rel=1e-6)
    _, dynamic = tf_tree(bag)
    m = dynamic[stamp_of(msgs[1])]["vehicle"][1]
    np.testing.assert_allclose(m[:3, 3], [w.geometry.x_m[1], w.geometry.y_m[1], -w.geometry.depth_m[1]], atol=1e-9)
    # the logged heading (354 deg, about north) and pitch (20.7 deg, nose down) in the vehicle's x
    heading = math.degrees(math.atan2(m[0, 0], m[1, 0])) % 360.0  # clockwise from north (+y)
    assert heading == pytest.approx(w.geometry.heading_deg[1], abs=1e-6)
    assert math.degrees(math.asin(-m[2, 0])) == pytest.approx(w.geometry.pitch_deg[1], abs=1e-6)


@pytest.mark.skipif(not (REAL / "multibeam").is_dir(), reason="../shared/data/real is absent")
def test_a_real_multibeam_recording_converts_to_a_bag(tmp_path):
    """R2Sonic 2026 soundings: travel times, angles (+ starboard in the bag), intensities, the
    beams without a detection flagged; the cloud's points at the straight-ray soundings."""
    pytest.importorskip("pyxtf")
    from sonarsim.io.readers.r2sonic import read_soundings

    s = read_soundings(REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf", pings=slice(0, 4))
    spec = StubMultibeam(name="r2sonic", mount=Pose())
    fake_scene = SimpleNamespace(instruments=(spec,), vehicle_pose=Pose(), vehicle_speed_m_s=0.0)
    write(tmp_path, {"r2sonic": s}, fake_scene, poses={"r2sonic": ri.recording_poses(s)})
    bag = read_bag(tmp_path / "bag")
    for k, (_, _, d) in enumerate(bag["/r2sonic/detections"]):
        t = s.two_way_time_s[k]
        np.testing.assert_array_equal(np.asarray(d.two_way_travel_times), t.astype(np.float32))
        np.testing.assert_allclose(d.rx_angles, -np.radians(s.angle_deg[k]).astype(np.float32), rtol=1e-6, atol=1e-7)
        assert [f.flag for f in d.flags] == [0 if np.isfinite(v) else 1 for v in t]
        c = bag["/r2sonic/points"][k][2]
        pts = np.frombuffer(np.asarray(c.data, np.uint8).tobytes(), "<f4").reshape(-1, 4)
        head = s.head_points()[k][np.isfinite(t)]
        np.testing.assert_allclose(pts[:, :3], head, atol=1e-3)  # identity mount: vehicle = head frame
    assert np.isfinite(s.two_way_time_s).sum() > 100


def test_a_rendered_multibeam_survey_round_trips(tmp_path):
    """A real multibeam render (the R2Sonic preset 10 m over a flat floor, rolled 3 degrees), its
    bag read back: each detection's direction and range from the image frame, moved through the
    TF chain, lands on the floor (z = 0) within a few range samples."""
    import sonarsim
    from sonarsim.instruments import render_pings

    doc = {"vehicle": {"pose": {"position_m": [0.0, 0.0, 10.0], "rpy_deg": [3.0, 0.0, 30.0]}},
           "ground": {"height_m": 0.0},
           "instruments": [{"type": "multibeam", "name": "mbes", "preset": "r2sonic_2026_400", "range_max_m": 25.0,
                            "n_samples": 1024, "mount": {"position_m": [0.2, 0.0, -0.3]}}]}
    with sonarsim.Simulator(doc) as sim:
        film = render_pings(sim, "mbes", n_pings=2, speckle=False)
        write(tmp_path, {"mbes": film}, sim.scene)
    bag = read_bag(tmp_path / "bag")
    static, dynamic = tf_tree(bag)
    for p in range(2):
        d = bag["/mbes/detections"][p][2]
        img = world_from("mbes_image", stamp_of(d), static, dynamic)
        ok = np.isfinite(np.asarray(d.two_way_travel_times, float)) & (np.asarray(d.two_way_travel_times) > 0)
        dirs = ri.beam_unit_vectors(d.tx_angles, d.rx_angles)[ok]
        r = (np.asarray(d.two_way_travel_times, float) * d.ping_info.sound_speed / 2)[ok]
        world = (img[:3, :3] @ (dirs * r[:, None]).T).T + img[:3, 3]
        assert ok.sum() > 200
        np.testing.assert_allclose(world[:, 2], 0.0, atol=4 * 25.0 / 1024)
