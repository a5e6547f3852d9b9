"""Update rate of ``sonarsim view`` while dragging (issue 13 item 3: at least 20 a second).

The demo scene (ARIS 3000 preset, 128 beams x 1288 bins, all bounces) in the viewer, served on
a free local port; a drag is simulated by setting poses through the viewer's API (what a drag
of a gizmo does) every 2 ms, far faster than frames can follow, for ``--seconds``. Measured on
the server: completed updates per second (render + scan conversion and colours + JPEG encoding
and queueing to the page; requests that arrive meanwhile are coalesced), and the mean time of
each stage. Cases: dragging the sonar; dragging an object (a new acceleration structure every
frame); the sonar with the sensor and speckle on. ``--browser`` keeps a headless Chromium
connected to the page meanwhile, so that every frame is also sent over the websocket.

Usage::

    python benchmarks/bench_viewer.py [--seconds 3] [--browser] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time

import numpy as np

from sonarsim.config.examples import demo_scene_dict
from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server, url_of
from sonarsim.plot.viewer.state import SceneSession


def drag(viewer: SceneViewer, seconds: float, what: str) -> dict:
    """Poses every 2 ms for ``seconds``; returns updates/s and the stages' mean times (ms)."""
    stages: dict[str, list[float]] = {}
    runs, requests, t0 = viewer.worker.runs, 0, time.perf_counter()
    last = None
    while time.perf_counter() - t0 < seconds:
        requests += 1
        s = requests
        if what == "object":
            viewer.set_object_pose("plastic_drum", (3.3 + 0.3 * np.sin(s / 40), 0.45 + 0.3 * np.cos(s / 50), 0.25),
                                   (0.0, 0.0, 3.0 * s % 360))
        else:
            viewer.set_sonar_pose((0.4 * np.sin(s / 40), 0.3 * np.cos(s / 55), 1.0 + 0.1 * np.sin(s / 30)),
                                  (0.0, 20.0 + 5.0 * np.sin(s / 35), 12.0 * np.sin(s / 60)))
        if viewer._seconds is not last:
            last = viewer._seconds
            for k, v in last.items():
                stages.setdefault(k, []).append(v)
        time.sleep(0.002)
    viewer.wait(10)
    elapsed = time.perf_counter() - t0
    updates = viewer.worker.runs - runs
    return {"case": what, "requests": requests, "updates": updates, "updates_per_s": updates / elapsed,
            **{f"{k}_ms": 1000 * float(np.mean(v)) for k, v in stages.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--browser", action="store_true", help="keep headless Chromium connected to the page")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    server = start_server("127.0.0.1", 0)
    session = SceneSession(demo_scene_dict())
    viewer = SceneViewer(server, session, out=tempfile.mkdtemp(prefix="sonarsim-bench-view-"))
    browser, profile = None, None
    try:
        assert viewer.wait(60)
        if args.browser:
            profile = tempfile.mkdtemp(prefix="sonarsim-bench-chromium-")
            browser = subprocess.Popen(
                ["chromium", "--headless=new", "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
                 "--window-size=1280,800", f"--user-data-dir={profile}", "--remote-debugging-port=0",
                 url_of(server, "127.0.0.1")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True)
            deadline = time.monotonic() + 30
            while not server.get_clients() and time.monotonic() < deadline:
                time.sleep(0.1)
            print(f"browser connected: {bool(server.get_clients())}")
            time.sleep(3.0)
        results = [drag(viewer, args.seconds, "sonar"), drag(viewer, args.seconds, "object")]
        viewer.set_options(sensor=True, speckle=True)
        viewer.wait(10)
        results.append(drag(viewer, args.seconds, "sonar, sensor and speckle on"))
    finally:
        if browser is not None:
            os.killpg(browser.pid, signal.SIGTERM)  # the browser started above, with its helpers
            browser.wait(10)
            shutil.rmtree(profile, ignore_errors=True)
        viewer.close()
        stop_server(server)
    for r in results:
        stages = ", ".join(f"{k[:-3]} {v:.1f} ms" for k, v in r.items() if k.endswith("_ms"))
        print(f"{r['case']:<32} {r['updates_per_s']:6.1f} updates/s ({r['updates']} updates for {r['requests']} "
              f"pose changes; {stages})")
    if args.json:
        with open(args.json, "w") as handle:
            json.dump({"browser": args.browser, "results": results}, handle, indent=1)


if __name__ == "__main__":
    main()
