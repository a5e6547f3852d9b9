"""``--use-sim-time`` (issue 40 item 1): frames paced and stamped by /clock."""

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

from .receive import receive  # noqa: E402
from .test_live import SCENE  # noqa: E402

CLOCK_PUBLISHER = textwrap.dedent("""
    import sys, time
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from sonarsim.io.rosbag_instruments import instrument_typestore
    from sonarsim.live import dds
    domain, speed, start_s, seconds = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
    T = instrument_typestore().types
    dp = DomainParticipant(domain)
    q = dds.qos("tf")
    w = DataWriter(dp, Topic(dp, "rt/clock", dds.dds_type("rosgraph_msgs/msg/Clock"), qos=q), qos=q)
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        sim_ns = int((start_s + speed * (time.monotonic() - t0)) * 1e9)
        msg = T["rosgraph_msgs/msg/Clock"](clock=T["builtin_interfaces/msg/Time"](sec=sim_ns // 10**9,
                                                                                 nanosec=sim_ns % 10**9))
        w.write(dds.to_sample(msg, "rosgraph_msgs/msg/Clock"))
        time.sleep(0.002)
""")


def test_frames_follow_a_simulated_clock_running_twice_as_fast(tmp_path):
    """A /clock at twice the wall clock's pace from 1000 s: 20 frames at 10 Hz of simulated time
    take about 1 s of wall time, and their stamps are simulated times 100 ms apart from 1000 s."""
    import yaml
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from sonarsim.live import dds

    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    (tmp_path / "clock.py").write_text(CLOCK_PUBLISHER)
    domain = 50 + (int(time.time()) + 11) % 40
    dp = DomainParticipant(domain)
    q = dds.qos("sensor")
    reader = DataReader(dp, Topic(dp, "rt/sonar/image", dds.dds_type("marine_acoustic_msgs/msg/ProjectedSonarImage"),
                                  qos=q), qos=q)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    clock = subprocess.Popen([sys.executable, str(tmp_path / "clock.py"), str(domain), "2.0", "1000.0", "40"], env=env)
    live = subprocess.Popen([sys.executable, "-m", "sonarsim", "live", str(scene), "--rate", "10", "--frames", "20",
                             "--use-sim-time", "--no-fan"], env=env, stderr=subprocess.PIPE, text=True)
    received, err = receive({"image": reader}, live, (clock,))
    arrivals, got = [a for a, _ in received["image"]], [s for _, s in received["image"]]
    assert live.returncode == 0, err
    assert len(got) >= 10, err
    stamps = np.array([s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in got]) / 1e9
    assert np.all((stamps > 1000.0) & (stamps < 1100.0))  # simulated time, not the wall clock's
    steps = np.diff(stamps) / 0.1
    assert np.allclose(steps, np.round(steps), atol=1e-6) and np.all(steps >= 1 - 1e-6)
    # simulated seconds passed per wall second between the first and last image received: 2
    rate = (stamps[-1] - stamps[0]) / (arrivals[-1] - arrivals[0])
    assert 1.6 < rate < 2.4, rate
