"""``sonarsim live`` measured (issue 40 item 5): latency from a pose to the image published, the
rate held, under load, and what a slow subscriber loses.

Three processes on the loopback, as a robot's stack would have them: a pose publisher standing
in for a simulator (``geometry_msgs/PoseStamped`` at 100 Hz, 1 m/s along x), ``sonarsim live
--pose-topic`` rendering the scene at ``--rate``, and this script subscribing to the image. Per
image received: the latency, the wall clock at its arrival less its stamp (the frame's time,
whose pose it rendered: the pose's wait, the render and the publishing); the frames published
(from live's summary) against those received.

Runs:

* ``idle``: the machine otherwise idle;
* ``load``: beside two processes that spin (the machine's two cores busy);
* ``slow``: the subscriber takes one sample every 0.25 s (a consumer four times slower than
  10 Hz): best effort, keep last 5, the renderer never waits, the subscriber loses frames.

Usage::

    python benchmarks/bench_live.py [--scene examples/first_scene.yaml] [--rate 10] [--seconds 10]
        [--json benchmarks/live.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import re
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

POSE_PUBLISHER = textwrap.dedent("""
    import sys, time
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic
    from sonarsim.io.rosbag_instruments import instrument_typestore
    from sonarsim.live import dds
    domain, seconds = int(sys.argv[1]), float(sys.argv[2])
    T = instrument_typestore().types
    dp = DomainParticipant(domain)
    q = dds.qos("sensor")
    w = DataWriter(dp, Topic(dp, "rt/vehicle/pose", dds.dds_type("geometry_msgs/msg/PoseStamped"), qos=q), qos=q)
    t0, end = time.time_ns(), time.monotonic() + seconds
    while time.monotonic() < end:
        now = time.time_ns()
        msg = T["geometry_msgs/msg/PoseStamped"](
            header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=now // 10**9, nanosec=now % 10**9),
                                            frame_id="world"),
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=(now - t0) / 1e9, y=0.0, z=0.5),
                                             orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
        w.write(dds.to_sample(msg, "geometry_msgs/msg/PoseStamped"))
        time.sleep(0.01)
""")


def _spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    x = 0
    while time.monotonic() < end:
        x += 1


def run(scene: Path, rate: float, seconds: float, mode: str, domain: int) -> dict:
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from sonarsim.live import dds

    dp = DomainParticipant(domain)
    q = dds.qos("sensor")
    reader = DataReader(dp, Topic(dp, "rt/sonar/image", dds.dds_type("marine_acoustic_msgs/msg/ProjectedSonarImage"),
                                  qos=q), qos=q)
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    frames = int(rate * seconds)
    hogs = [multiprocessing.Process(target=_spin, args=(seconds + 8,)) for _ in range(2 if mode == "load" else 0)]
    for h in hogs:
        h.start()
    with tempfile.TemporaryDirectory() as tmp:
        pub_py = Path(tmp) / "pub.py"
        pub_py.write_text(POSE_PUBLISHER)
        pub = subprocess.Popen([sys.executable, str(pub_py), str(domain), str(seconds + 10)], env=env)
        live = subprocess.Popen([sys.executable, "-m", "sonarsim", "live", str(scene), "--rate", str(rate),
                                 "--frames", str(frames), "--pose-topic", "/vehicle/pose", "--pose-type", "pose_stamped"],
                                env=env, stderr=subprocess.PIPE, text=True)
        latencies, stamps = [], []
        try:
            while live.poll() is None:
                for s in reader.take(N=1 if mode == "slow" else 64):
                    if hasattr(s, "header"):
                        now = time.time_ns()
                        stamp = s.header.stamp.sec * 10**9 + s.header.stamp.nanosec
                        latencies.append((now - stamp) / 1e6)
                        stamps.append(stamp)
                time.sleep(0.25 if mode == "slow" else 0.002)
            err = live.communicate(timeout=60)[1]
        finally:
            for p in (pub, live):
                if p.poll() is None:
                    p.kill()
            for h in hogs:
                h.terminate()
    summary = [line for line in err.splitlines() if "frames in" in line]
    m = re.search(r"(\d+) frames in ([0-9.]+) s \(([0-9.]+) frames/s\), (\d+) late(?:, (\d+) skipped)?", summary[-1]) \
        if summary else None
    lat = np.array(latencies)
    return {"mode": mode, "rate_hz": rate, "frames_asked": frames,
            "published": int(m.group(1)) if m else None, "published_rate_hz": float(m.group(3)) if m else None,
            "skipped_stale": int(m.group(5) or 0) if m else None,
            "received": len(latencies),
            "latency_ms": {"median": float(np.median(lat)) if lat.size else None,
                           "p99": float(np.percentile(lat, 99)) if lat.size else None,
                           "max": float(lat.max()) if lat.size else None},
            "live_summary": summary[-1].split("live: ", 1)[-1] if summary else err[-400:]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT / "examples" / "first_scene.yaml")
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    import importlib.util

    if importlib.util.find_spec("cyclonedds") is None:
        print("bench_live: skipped: needs the live extra (cyclonedds)", file=sys.stderr)
        return 0
    out = {"benchmark": "issue 40 item 5: sonarsim live, a pose publisher and a subscriber on the loopback",
           "scene": str(args.scene.relative_to(ROOT)) if args.scene.is_relative_to(ROOT) else str(args.scene),
           "date": time.strftime("%Y-%m-%d %H:%M"), "cpus": os.cpu_count(), "runs": []}
    for k, mode in enumerate(("idle", "load", "slow")):
        r = run(args.scene, args.rate, args.seconds, mode, 60 + 20 * k + int(time.time()) % 20)
        out["runs"].append(r)
        lat = r["latency_ms"]
        print(f"{mode:5s}: published {r['published']}/{r['frames_asked']} at {r['published_rate_hz']} frames/s "
              f"({r['skipped_stale']} skipped stale), received {r['received']}; latency pose -> image received: median "
              f"{lat['median']:.1f} ms, p99 {lat['p99']:.1f} ms, max {lat['max']:.1f} ms", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
