"""ROS 2 over DDS without ROS (issue 40 item 1): names, QoS, and samples whose CDR is the bags'."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.io import rosbag as rb  # noqa: E402
from sonarsim.io.rosbag_instruments import INSTRUMENT_MSGTYPES, instrument_typestore  # noqa: E402
from sonarsim.live import dds  # noqa: E402

# Every message type sonarsim writes, and the ones nested in them.
WRITTEN = sorted(set(rb._MSGTYPES.values()) | set(INSTRUMENT_MSGTYPES.values()))


def test_topic_and_type_names_follow_the_ros2_dds_mapping():
    assert dds.dds_topic("/sonar/image") == "rt/sonar/image"
    assert dds.dds_topic("tf_static") == "rt/tf_static"
    assert dds.dds_typename("marine_acoustic_msgs/msg/ProjectedSonarImage") == \
        "marine_acoustic_msgs::msg::dds_::ProjectedSonarImage_"
    assert dds.dds_type("sensor_msgs/msg/Image").__idl_typename__ == "sensor_msgs::msg::dds_::Image_"
    for bad in ("/sonar/", "sonar//image", "/so nar", "", 3):
        with pytest.raises(ConfigError, match="topic"):
            dds.dds_topic(bad)
    for bad in ("sensor_msgs/Image", "sensor_msgs/msg/", "Image"):
        with pytest.raises(ConfigError, match="type"):
            dds.dds_typename(bad)
    with pytest.raises(ConfigError, match="not a message sonarsim knows"):
        dds.dds_type("nobody_msgs/msg/Nothing")


def test_domain_id_is_read_from_ros_domain_id():
    assert dds.domain_id({}) == 0
    assert dds.domain_id({"ROS_DOMAIN_ID": " 42 "}) == 42
    for bad in ("-1", "233", "x"):
        with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
            dds.domain_id({"ROS_DOMAIN_ID": bad})


def test_qos_is_what_ros2_gives_sensor_data_and_tf_static():
    from cyclonedds.qos import Policy

    sensor = dds.qos("sensor")
    assert sensor[Policy.Reliability] == Policy.Reliability.BestEffort
    assert sensor[Policy.History] == Policy.History.KeepLast(5)
    assert sensor[Policy.Durability] == Policy.Durability.Volatile
    static = dds.qos("tf_static")
    assert static[Policy.Durability] == Policy.Durability.TransientLocal
    assert static[Policy.History] == Policy.History.KeepLast(1)
    with pytest.raises(ConfigError, match="qos"):
        dds.qos("fast")


def _random_message(store, ros_type: str, rng: np.random.Generator):
    """A message of ``ros_type`` with seeded random contents in every field (sequences of
    random lengths, strings of random lengths: every alignment the CDR has to pad)."""
    _, fields = store.fielddefs[ros_type]
    values = {}
    for name, node in fields:
        values[name] = _random_value(store, node, rng)
    return store.types[ros_type](**values)


_NUMPY = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "octet": np.uint8, "int8": np.int8,
          "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
          "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64}


def _random_scalar(name: str, rng):
    if name == "string":
        return "".join(rng.choice(list("abcxyz_/019"), size=int(rng.integers(0, 9))))
    if name == "bool":
        return bool(rng.integers(0, 2))
    if name.startswith("float"):
        return float(np.asarray(rng.normal() * 100, _NUMPY[name]))
    info = np.iinfo(_NUMPY[name])
    return int(rng.integers(info.min, info.max, endpoint=True, dtype=np.int64 if info.max < 2**63 else np.uint64))


def _random_value(store, node, rng):
    kind, arg = node
    kind = int(kind)
    if kind == 1:
        return _random_scalar(arg[0], rng)
    if kind == 2:
        return _random_message(store, arg, rng)
    sub, n = arg
    length = n if kind == 3 else int(rng.integers(0, 7))
    if int(sub[0]) == 1 and sub[1][0] != "string":
        return np.array([_random_scalar(sub[1][0], rng) for _ in range(length)], dtype=_NUMPY[sub[1][0]])
    return [_random_value(store, sub, rng) for _ in range(length)]


@pytest.mark.parametrize("ros_type", WRITTEN)
def test_a_sample_serialises_to_the_bags_cdr_byte_for_byte(ros_type):
    """Random contents (seeded, 20 draws) of every type sonarsim writes: the DDS sample's CDR is
    rosbags' CDR of the same message, header included."""
    store = instrument_typestore()
    rng = np.random.default_rng(abs(hash(ros_type)) % 2**32)
    for _ in range(20):
        msg = _random_message(store, ros_type, rng)
        want = bytes(store.serialize_cdr(msg, ros_type))
        got = dds.to_sample(msg, ros_type).serialize()
        assert got == want


def test_a_rendered_frame_serialises_as_its_bag_does(tmp_path):
    """The messages of a rendered frame as the bag writer builds them (image, fan, pose, TF,
    points): their samples' CDR is what the bag stores."""
    import sonarsim

    doc = {"sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 20, 0]}},
           "ground": {"height_m": 0.0}}
    with sonarsim.Simulator(doc) as sim:
        image = sim.render()
    pts = np.array([[1.0, 0.5, 0.0], [2.0, -0.5, 0.1]])
    frame = rb.frame_from_image(image, 1_000_000_123, fan=True, points_world=pts, points_object=np.array([0, 3]))
    with rb.BagWriter(tmp_path / "bag") as bag:
        store = bag._typestore
        built = {"image": bag._image_msg(frame), "fan": bag._fan_msg(frame), "pose": bag._pose_msg(frame),
                 "tf": bag._tf_msg(frame), "points": bag._points_msg(frame)}
    for key, msg in built.items():
        ros_type = rb._MSGTYPES[key]
        assert dds.to_sample(msg, ros_type).serialize() == bytes(store.serialize_cdr(msg, ros_type)), key


SUBSCRIBER = textwrap.dedent("""
    import sys, time
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from sonarsim.live import dds
    domain, n = int(sys.argv[1]), int(sys.argv[2])
    dp = DomainParticipant(domain)
    reader = DataReader(dp, Topic(dp, dds.dds_topic("/sonar/fan"), dds.dds_type("sensor_msgs/msg/Image"),
                                  qos=dds.qos("sensor")), qos=dds.qos("sensor"))
    print("ready", flush=True)
    got, t0 = [], time.monotonic()
    while len(got) < n and time.monotonic() - t0 < 20:
        for s in reader.take(N=16):
            if hasattr(s, "header"):
                got.append(s)
        time.sleep(0.005)
    for s in got:
        print(s.header.stamp.sec, s.header.frame_id, s.encoding, s.width, s.height, bytes(s.data).hex(), flush=True)
""")


def test_a_second_process_receives_the_samples_over_the_loopback(tmp_path):
    """A subscriber process (Cyclone DDS, as rmw_cyclonedds_cpp is) on a domain of its own
    receives the fan images a publisher writes, with their stamps, frame ids and data."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    domain = 100 + int(time.time()) % 100  # apart from other runs on this machine
    script = tmp_path / "sub.py"
    script.write_text(SUBSCRIBER)
    sub = subprocess.Popen([sys.executable, str(script), str(domain), "3"], stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout.readline().strip() == "ready"
        store = instrument_typestore()
        image_t, header_t, time_t = (store.types[n] for n in ("sensor_msgs/msg/Image", "std_msgs/msg/Header",
                                                              "builtin_interfaces/msg/Time"))
        dp = DomainParticipant(domain)
        writer = DataWriter(dp, Topic(dp, "rt/sonar/fan", dds.dds_type("sensor_msgs/msg/Image"), qos=dds.qos("sensor")),
                            qos=dds.qos("sensor"))
        sent = {}
        deadline = time.monotonic() + 15
        k = 0
        while sub.poll() is None and time.monotonic() < deadline:  # best effort: until the subscriber has 3
            data = np.arange(6, dtype=np.uint8) + k
            msg = image_t(header=header_t(stamp=time_t(sec=k, nanosec=5), frame_id="sonar"), height=2, width=3,
                          encoding="mono8", is_bigendian=0, step=3, data=data)
            writer.write(dds.to_sample(msg, "sensor_msgs/msg/Image"))
            sent[k] = data.tobytes().hex()
            k += 1
            time.sleep(0.05)
        out, _ = sub.communicate(timeout=20)
    finally:
        if sub.poll() is None:
            sub.kill()
    lines = [line.split() for line in out.strip().splitlines()]
    assert len(lines) == 3, out
    for sec, frame_id, encoding, width, height, data in lines:
        assert (frame_id, encoding, width, height) == ("sonar", "mono8", "3", "2")
        assert data == sent[int(sec)]


def test_without_cyclone_dds_the_error_names_the_live_extra(monkeypatch):
    from sonarsim.errors import SonarsimError
    from sonarsim.live.publisher import Publisher

    for name in ("cyclonedds", "cyclonedds.domain", "cyclonedds.idl"):
        monkeypatch.setitem(sys.modules, name, None)  # an import of it now fails
    with pytest.raises(SonarsimError, match=r"live.*pip install"):
        Publisher(0)
    with pytest.raises(SonarsimError, match="live"):
        dds._cyclonedds()


def test_a_serialized_sample_carries_the_bags_bytes():
    store = instrument_typestore()
    rng = np.random.default_rng(3)
    msg = _random_message(store, "sensor_msgs/msg/PointCloud2", rng)
    cdr = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    sample = dds.serialized_sample("sensor_msgs/msg/PointCloud2", cdr)
    assert isinstance(sample, dds.dds_type("sensor_msgs/msg/PointCloud2"))  # a writer of the type takes it
    # on the wire: padded to 4 bytes, the padding counted in the encapsulation options
    assert len(sample.serialize()) % 4 == 0
    assert dds.unpadded(sample.serialize()) == cdr == dds.to_sample(msg, "sensor_msgs/msg/PointCloud2").serialize()


def test_padding_is_counted_in_the_encapsulation_options_and_dropped_again():
    """DDS-XTypes 7.6.3.1.2: a payload of 10 bytes goes out as 12 with options byte 3 = 2."""
    cdr = bytes([0, 1, 0, 0, 2, 0, 0, 0, 0x61, 0])  # std_msgs/String "a", little-endian CDR
    wire = dds.padded(cdr)
    assert wire == cdr[:3] + b"\x02" + cdr[4:] + b"\0\0"
    assert dds.unpadded(wire) == cdr
    for n in range(4, 12):  # every remainder, and the aligned case left alone
        body = bytes([0, 1, 0, 0]) + bytes(range(1, n - 3))
        assert len(dds.padded(body)) % 4 == 0
        assert dds.unpadded(dds.padded(body)) == body
    aligned = bytes([0, 1, 0, 0, 4, 0, 0, 0, 0x61, 0x62, 0x63, 0])
    assert dds.padded(aligned) == aligned == dds.unpadded(aligned)


def test_a_raw_reader_receives_the_bags_bytes_as_they_were_sent():
    """A recorder's reader (:func:`dds.raw_type`) matched with a writer of the decoded type gets
    exactly rosbags' CDR, strings of every length mod 4 included, while a decoding reader of the
    same topic still reads the message."""
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    store = instrument_typestore()
    ros_type = "std_msgs/msg/String"
    dp = DomainParticipant(150 + os.getpid() % 50)
    for text in ("a", "ab", "abc", "abcd"):
        name = f"rt/sonarsim_test/raw{len(text)}"
        writer = DataWriter(dp, Topic(dp, name, dds.dds_type(ros_type)), qos=dds.qos("latched"))
        raw = DataReader(dp, Topic(dp, name, dds.raw_type(ros_type)), qos=dds.qos("latched"))
        decoded = DataReader(dp, Topic(dp, name, dds.dds_type(ros_type)), qos=dds.qos("latched"))
        cdr = bytes(store.serialize_cdr(store.types[ros_type](data=text), ros_type))
        writer.write(dds.serialized_sample(ros_type, cdr))
        got, seen, deadline = [], [], time.monotonic() + 5
        while (not got or not seen) and time.monotonic() < deadline:
            got += [s for s in raw.take(N=4) if isinstance(s, dds.RawSample)]
            seen += [s.data for s in decoded.take(N=4) if hasattr(s, "data")]
            time.sleep(0.01)
        assert [s.cdr for s in got] == [cdr], text
        assert seen == [text]
