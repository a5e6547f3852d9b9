"""A mechanical scanning sonar's full turn and a single-beam's ping: render time against the device's.

The scene is a 30 x 20 m basin 6 m deep (floor, four walls as boxes, a few objects); the scanning
sonar is Ping360-like (750 kHz, 2 x 25 deg beam, 400 steps a turn, 1200 samples, ``--range``
metres, head 2 m above the floor); the device's own turn takes 400 step periods, each the
window's two-way travel time plus ``--overhead`` seconds. The single-beam (200 kHz, 10 deg piston
cone, 1000 samples over 30 m) pings from the same vehicle.

Usage::

    python benchmarks/bench_scanning.py [--repeats 3] [--range 50] [--overhead 0] [--json out.json]

Output (JSON): the median render time of a turn and of a ping, the device's turn time and ping
period, and their ratios (render / device: below 1 is faster than the device).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time


def basin(sonar: dict) -> dict:
    def box(name, size, at, yaw=0.0):
        return {"name": name, "primitive": "box", "size_m": list(size), "pose": {"position_m": list(at), "rpy_deg": [0, 0, yaw]}}

    walls = [box("north", (30.4, 0.2, 6.0), (0, 10.1, 3.0)), box("south", (30.4, 0.2, 6.0), (0, -10.1, 3.0)),
             box("east", (0.2, 20.0, 6.0), (15.1, 0, 3.0)), box("west", (0.2, 20.0, 6.0), (-15.1, 0, 3.0))]
    things = [box("crate", (1.0, 1.0, 1.0), (4.0, 3.0, 0.5), 30.0), box("pipe", (6.0, 0.4, 0.4), (-5.0, -4.0, 0.2), -15.0),
              {"name": "ball", "primitive": "sphere", "radius_m": 0.5, "pose": {"position_m": [2.0, -6.0, 0.5]}}]
    return {"sonar": sonar, "ground": {"height_m": 0.0}, "objects": walls + things, "render": {"max_order": 1}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--range", type=float, default=50.0, dest="range_m")
    ap.add_argument("--overhead", type=float, default=0.0, help="step_overhead_s of the scanning sonar")
    ap.add_argument("--pings", type=int, default=50, help="single-beam pings per repeat")
    ap.add_argument("--json", default=None, help="write the result here (default: stdout only)")
    args = ap.parse_args(argv)

    import numpy as np

    import sonarsim
    from sonarsim.core.rays import samples_per_beam
    from sonarsim.instruments import render_pings

    pose = {"position_m": [0.0, 0.0, 2.0]}
    scanning = {"type": "scanning", "frequency_khz": 750, "horizontal_beam_width_deg": 2, "vertical_beam_width_deg": 25,
                "tilt_deg": 0, "steps_per_turn": 400, "step": 1, "sector_deg": 360, "range_min_m": 0.5,
                "range_max_m": args.range_m, "n_samples": 1200, "sound_speed_m_s": 1500,
                "step_overhead_s": args.overhead, "pose": pose}
    single = {"type": "singlebeam", "frequency_khz": 200, "beam_width_deg": 10, "pattern": "piston",
              "range_min_m": 0.0, "range_max_m": 30.0, "n_samples": 1000, "ping_rate_hz": 10,
              "sound_speed_m_s": 1500, "threshold_db": -10, "pose": pose}

    out: dict = {"machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                             "cpus": os.cpu_count()}}
    with sonarsim.Simulator(basin(scanning)) as sim:
        spec = sim.scene.instruments[0]
        n = spec.steps_per_scan()
        render_pings(sim, n_pings=4, speckle=False)  # warm: the fan, the caster
        turns = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            img = render_pings(sim, n_pings=n, speckle=False)
            turns.append(time.perf_counter() - t0)
        assert img.samples.shape == (1200, n)
        turn = statistics.median(turns)
        out["scanning"] = {"steps": n, "n_samples": 1200, "range_max_m": args.range_m,
                           "rays_per_step": int(np.prod(samples_per_beam(spec.channel_sonar(), sim.scene.render))),
                           "render_turn_s": turn, "render_turns_s": turns, "render_step_ms": 1e3 * turn / n,
                           "device_step_s": spec.ping_period_s(), "device_turn_s": spec.turn_time_s(),
                           "ratio_render_to_device": turn / spec.turn_time_s()}
    with sonarsim.Simulator(basin(single)) as sim:
        spec = sim.scene.instruments[0]
        render_pings(sim, n_pings=2, speckle=False)
        runs = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            env = render_pings(sim, n_pings=args.pings, speckle=False)
            runs.append((time.perf_counter() - t0) / args.pings)
        ping = statistics.median(runs)
        out["singlebeam"] = {"pings": args.pings,
                             "rays_per_ping": int(np.prod(samples_per_beam(spec.channel_sonar(), sim.scene.render)))
                             * spec.channel_sonar().n_beams, "render_ping_ms": 1e3 * ping, "device_ping_s": spec.ping_period_s(),
                             "ratio_render_to_device": ping / spec.ping_period_s(),
                             "bottom_range_m": float(env.bottom_range_m[0])}
    text = json.dumps(out, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
