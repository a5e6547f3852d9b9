"""Benchmark of the multibeam echosounder (``sonarsim.instruments.multibeam``): a ping's time
against the bare casting of its rays, and how it grows with beams and samples.

Measures, in one run on this machine:

* an R2Sonic-like ping: 256 beams over 130 deg (0.5 deg across, 1 deg along), 50 m window of
  1,024 samples, 20 m over a flat floor with a box on it: the ping's time (``render_pings`` of
  five pings, per ping: trace, form, pulse, footprints, detection) against the bare
  casting of the very rays it cast (Embree alone, on fresh copies, the faster of one thread and
  the frame's threads, as ``benchmarks/bench_render.py`` measures a frame), the engine's part
  (trace and form of the frame) and the multibeam's own per-beam work (footprints, arrivals,
  detection);
* the same ping through a sound-speed profile (two-point ray tracing per beam, the columns
  mapped to time);
* sweeps: beams (64 to 512) and samples (512 to 4,096), each with its bare cast and ratio
  (the automatic rays per beam grow as 1 / the sample's length across and along: rays grow as
  samples squared).

Usage::

    python benchmarks/bench_multibeam.py [--repeats 15] [--json bench_multibeam.json] [--quick]

Times are medians over warm repeats, pings and bare casts interleaved in blocks (the machine
is shared: the ratio is what holds). Nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import numpy as np

import sonarsim
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_render import record_casts  # noqa: E402 (one recorder of a frame's casts, for any frame)
from sonarsim.instruments import render_pings
from sonarsim.instruments import multibeam as mb


#: Pings per render call measured (the steady state of a survey's pings).
PINGS = 5


def scene(n_beams: int = 256, n_samples: int = 1024, profile: bool = False, refraction: str = "arrival") -> dict:
    section = {"type": "multibeam", "frequency_khz": 400.0, "n_beams": n_beams, "swath_deg": 130.0,
               "beam_spacing": "equiangular", "tx_beam_width_along_deg": 1.0, "rx_beam_width_across_deg": 0.5,
               "pulse_length_us": 50.0, "range_min_m": 0.0, "range_max_m": 50.0, "n_samples": n_samples,
               "ping_rate_hz": 10.0, "sound_speed_m_s": 1500.0, "detection": "amplitude",
               "pose": {"position_m": [0.0, 0.0, 20.0], "rpy_deg": [3.0, 2.0, 0.0]}}
    if profile:
        section.update(sound_speed_profile=[[0.0, 1500.0], [10.0, 1495.0], [30.0, 1520.0]],
                       processing_profile=[[0.0, 1500.0], [30.0, 1515.0]], surface_height_m=25.0,
                       refraction=refraction)
    return {"sonar": section, "ground": {"height_m": 0.0},
            "objects": [{"name": "box", "primitive": "box", "size_m": [2.0, 2.0, 1.0],
                         "pose": {"position_m": [0.0, 8.0, 0.5]}}],
            "render": {"max_order": 1}}


def own_work_s(sim, spec, repeats: int) -> float:
    """The multibeam's own per-beam work on one ping (:func:`ping_soundings`: footprints,
    arrivals, the profile's column mapping, detection), outside the engine's trace and form."""
    channel = spec.channels()[0]
    vehicle = sim.scene.vehicle_pose
    paths = sim.trace(mb.mounted(vehicle, channel.mount), sonar=channel.sonar, fan=mb._fan(sim, spec, channel.sonar))
    wc = sim.form(paths, keep_rays=False, speckle=False, frame=0, sensor=False).polar
    head = mb.mounted(vehicle, spec.mount)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        mb.ping_soundings(spec, paths, wc, head)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def engine_s(sim, spec, repeats: int) -> float:
    """The engine's part of a ping: :meth:`Simulator.trace` and :meth:`Simulator.form` of its frame."""
    channel = spec.channels()[0]
    pose = mb.mounted(sim.scene.vehicle_pose, channel.mount)
    fan = mb._fan(sim, spec, channel.sonar)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        sim.form(sim.trace(pose, sonar=channel.sonar, fan=fan), keep_rays=False, speckle=False, frame=0, sensor=False)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def measure(name: str, doc: dict, repeats: int) -> dict:
    sim = sonarsim.Simulator(doc)
    spec = sim.scene.instruments[0]

    def ping():  # a survey's steady state: PINGS pings per call, the call's own set-up shared
        return render_pings(sim, n_pings=PINGS, speckle=False)

    for _ in range(2):
        ping()
    recorded = record_casts(sim, ping)
    n_rays = sum(len(d) for _, _, d, _, _ in recorded)
    pings, casts = [], {1: [], 2: []}
    block = 5
    for _ in range(max(1, repeats // block)):
        for _ in range(block):
            t = time.perf_counter()
            ping()
            pings.append(time.perf_counter() - t)
        for split in (1, 2):
            for _ in range(block):
                fresh = [tfar.copy() for _, _, _, tfar, _ in recorded]  # Embree writes hits into tfar
                t = time.perf_counter()
                for (caster, o, d, _, threads), tfar in zip(recorded, fresh):
                    if split == 1:
                        caster.cast_raw(o, d, tfar, 1)
                    else:
                        caster.cast_raw(o, d, tfar, threads, min_chunk=4096)
                casts[split].append(time.perf_counter() - t)
    frame = statistics.median(pings) / PINGS
    cast = min(statistics.median(v) for v in casts.values()) / PINGS
    n_rays //= PINGS
    own = own_work_s(sim, spec, max(3, repeats // 3))
    engine = engine_s(sim, spec, max(3, repeats // 3))
    sim.close()
    across, along = spec.ray_counts()
    return {"case": name, "n_beams": spec.n_beams, "n_samples": spec.n_samples, "rays_across": across,
            "rays_along": along, "rays_per_ping": n_rays, "ping_ms": 1e3 * frame, "bare_cast_ms": 1e3 * cast,
            "ping_over_cast": frame / cast, "engine_trace_form_ms": 1e3 * engine, "engine_over_cast": engine / cast,
            "own_per_beam_work_ms": 1e3 * own,
            "profile": spec.sound_speed_profile is not None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--json", default=None)
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test)")
    args = ap.parse_args(argv)
    repeats = 5 if args.quick else args.repeats
    beams = (16, 32) if args.quick else (64, 128, 256, 512)
    samples = (256, 512) if args.quick else (512, 1024, 2048, 4096)
    main_beams = 32 if args.quick else 256
    rows = [measure("r2sonic-like", scene(main_beams), repeats),
            measure("r2sonic-like, profile", scene(main_beams, profile=True), repeats),
            measure("profile, bent beams", scene(main_beams, profile=True, refraction="beam"), repeats)]
    sweep_beams = [measure(f"beams {b}", scene(b), repeats) for b in beams]
    sweep_samples = [measure(f"samples {s}", scene(main_beams, s), repeats) for s in samples]

    def exponent(xs, ys):
        return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])

    results = {
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform(),
                    "load_average_1_5_15": list(os.getloadavg())},
        "cases": rows, "beams": sweep_beams, "samples": sweep_samples,
        "exponents": {
            "beams": {"ping": exponent(beams, [r["ping_ms"] for r in sweep_beams]),
                      "bare_cast": exponent(beams, [r["bare_cast_ms"] for r in sweep_beams])},
            "samples": {"ping": exponent(samples, [r["ping_ms"] for r in sweep_samples]),
                        "bare_cast": exponent(samples, [r["bare_cast_ms"] for r in sweep_samples])},
        },
    }
    print(f"{'case':<22} {'beams':>5} {'samples':>7} {'rays':>7} {'ping ms':>8} {'cast ms':>8} {'ratio':>6} "
          f"{'engine ms':>9} {'own ms':>7}")
    for r in rows + sweep_beams + sweep_samples:
        print(f"{r['case']:<22} {r['n_beams']:>5} {r['n_samples']:>7} {r['rays_per_ping']:>7,} {r['ping_ms']:>8.2f} "
              f"{r['bare_cast_ms']:>8.2f} {r['ping_over_cast']:>6.2f} {r['engine_trace_form_ms']:>9.2f} "
              f"{r['own_per_beam_work_ms']:>7.2f}")
    print("(ping: per ping of a 5-ping call; cast: the bare casting of its rays; engine: trace + form of its frame; "
          "own: the multibeam's per-beam work)")
    e = results["exponents"]
    print(f"ping time ~ beams^{e['beams']['ping']:.2f} (bare cast ^{e['beams']['bare_cast']:.2f}), "
          f"~ samples^{e['samples']['ping']:.2f} (bare cast ^{e['samples']['bare_cast']:.2f})")
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(results, f, indent=2)
        os.replace(tmp, args.json)
        print(f"wrote {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
