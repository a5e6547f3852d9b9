"""Bare ray casting of a demo frame, embreex's caster against our Embree 4 binding, and whole frames.

Usage::

    python benchmarks/bench_cast.py [--repeats 300] [--frames 200] [--out benchmarks/cast.json]

1. The rays: every batch one demo frame hands to its caster (recorded through embreex).
2. Casting them, timed per frame's worth of batches, for each caster on 1 and 2 threads:
   ``raw`` is Embree's bare answer (``cast_raw``: embreex's ``run``; the binding's packet loop
   with no hit processing), ``hits`` is :meth:`intersect`, what a frame pays (embreex: ``run`` then
   the compiled conversion to ``Hits``; the binding: the conversion fused into the packet loop).
   ``embree4 incoherent``: the binding without Embree's coherent-packet flag.
   Every repetition casts FRESH rays: embreex writes the hit distances back into the ``tfar``
   array it is given, so replaying one array would cut the rays short at their previous hits;
   each cast gets its own copy of the limits, made before the clock starts.
3. Whole frames: ``Simulator(demo).render(keep_rays=False)`` with each caster, 1 and 2 threads.

All configurations are interleaved repetition by repetition (the machine is shared: load drifts
hit every median alike); medians are reported, in milliseconds.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import sonarsim
from sonarsim.config.examples import demo_scene_dict
from sonarsim.trace.embree import EmbreeCaster
from sonarsim.trace.embree4 import Embree4Caster


class Recorder:
    """Wraps a caster and keeps every batch of rays a frame casts (float32, contiguous)."""

    def __init__(self, caster) -> None:
        self.caster, self.calls = caster, []

    def intersect(self, origins, directions, max_distance, threads=None, with_uv=False):
        d = np.ascontiguousarray(directions, np.float32)
        o = np.ascontiguousarray(np.broadcast_to(origins, d.shape), np.float32)
        self.calls.append((o, d, np.full(len(d), max_distance, np.float32)))
        return self.caster.intersect(origins, directions, max_distance, threads=threads, with_uv=with_uv)

    def __getattr__(self, name):
        return getattr(self.caster, name)


def frame_batches() -> tuple[list, list]:
    """The demo scene's meshes and the ray batches ``(origins, directions, tfar)`` of one frame."""
    with sonarsim.Simulator(demo_scene_dict(), backend="embreex") as sim:
        sim.caster = Recorder(sim.caster)
        sim.render(keep_rays=False)
        return sim.meshes, sim.caster.calls


def time_casts(casters: dict, batches: list, repeats: int) -> dict:
    """Median milliseconds per frame's worth of batches for each ``(name, mode, threads)``."""
    times = {key: [] for key in casters}
    for _ in range(repeats):
        for key, (caster, mode, threads) in casters.items():
            fresh = [t.copy() for _, _, t in batches]  # outside the clock
            start = time.perf_counter()
            if mode == "raw":
                for (o, d, _), t in zip(batches, fresh):
                    caster.cast_raw(o, d, t, threads)
            else:
                for (o, d, t), _ in zip(batches, fresh):
                    caster.intersect(o, d, float(t[0]), threads=threads)
            times[key].append(time.perf_counter() - start)
    return {key: 1e3 * statistics.median(v) for key, v in times.items()}


def time_frames(frames: int) -> dict:
    """Median milliseconds per demo frame, each caster, 1 and 2 threads, interleaved."""
    sims = {}
    for backend in ("embreex", "embree4"):
        for threads in (1, 2):
            doc = demo_scene_dict()
            doc["render"]["threads"] = threads
            sim = sonarsim.Simulator(doc, backend=backend)
            for _ in range(5):  # warm: buffers, fans, pools
                sim.render(keep_rays=False)
            sims[(backend, threads)] = sim
    times = {key: [] for key in sims}
    for _ in range(frames):
        for key, sim in sims.items():
            start = time.perf_counter()
            sim.render(keep_rays=False)
            times[key].append(time.perf_counter() - start)
    for sim in sims.values():
        sim.close()
    return {key: 1e3 * statistics.median(v) for key, v in times.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeats", type=int, default=300, help="casts of the frame's rays per configuration")
    p.add_argument("--frames", type=int, default=200, help="rendered frames per configuration")
    p.add_argument("--out", type=Path, help="also write the figures as JSON here")
    args = p.parse_args(argv)

    meshes, batches = frame_batches()
    n_rays = sum(len(d) for _, d, _ in batches)
    embreex, ours = EmbreeCaster(meshes, threads=2), Embree4Caster(meshes, threads=2)
    ours_incoherent = Embree4Caster(meshes, threads=2, coherent=False)
    # The two agree on these rays (tests/trace/test_embree4.py checks it ray by ray).
    for o, d, t in batches:
        a, b = embreex.intersect(o, d, float(t[0])), ours.intersect(o, d, float(t[0]))
        assert np.array_equal(a.mesh_id, b.mesh_id)
    casters = {(name, mode, threads): (caster, mode, threads)
               for name, caster in (("embreex", embreex), ("embree4", ours), ("embree4 incoherent", ours_incoherent))
               for mode in ("raw", "hits") for threads in (1, 2)}
    time_casts(casters, batches, 10)  # warm
    cast = time_casts(casters, batches, args.repeats)
    frame = time_frames(args.frames)

    print(f"demo frame: {n_rays} rays in {len(batches)} batches; {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs; medians of {args.repeats} casts / {args.frames} frames, interleaved")
    print(f"{'':32}{'1 thread':>10}{'2 threads':>11}")
    for name in ("embreex", "embree4", "embree4 incoherent"):
        for mode in ("raw", "hits"):
            print(f"{name + ' cast ' + mode:32}{cast[(name, mode, 1)]:9.3f} {cast[(name, mode, 2)]:10.3f}  ms")
    for name in ("embreex", "embree4"):
        print(f"{name + ' frame':32}{frame[(name, 1)]:9.3f} {frame[(name, 2)]:10.3f}  ms")
    for threads in (1, 2):
        print(f"{threads} thread(s): cast raw {cast[('embreex', 'raw', threads)] / cast[('embree4', 'raw', threads)]:.2f}x, "
              f"cast to hits {cast[('embreex', 'hits', threads)] / cast[('embree4', 'hits', threads)]:.2f}x, "
              f"frame {frame[('embreex', threads)] / frame[('embree4', threads)]:.2f}x faster with embree4; "
              f"frame / bare cast (embree4) {frame[('embree4', threads)] / cast[('embree4', 'raw', threads)]:.2f}")
    if args.out:
        doc = {"machine": {"processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                           "python": sys.version.split()[0]},
               "rays": n_rays, "batches": len(batches), "repeats": args.repeats, "frames": args.frames,
               "cast_ms": {f"{n} {m} {t}": v for (n, m, t), v in cast.items()},
               "frame_ms": {f"{n} {t}": v for (n, t), v in frame.items()}}
        args.out.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
