"""Frame-rate benchmark of ``Simulator.render`` (issue: real time on 2 CPU cores).

Measures, in one run on this machine:

* (a) the demo tank, ARIS 3000 preset, 128 beams x 1288 bins, all bounces, default ray density;
* (b) the same scene with a ~500,000-triangle mesh added (a bumpy rock on the floor);
* (c) the same tank seen by an Oculus M1200d (low-frequency mode, 512 beams);
* (d) the demo tank with a water surface (floor + surface) and (e) with a water surface and
  four walls, paths up to order 3;
* (f, g) the demo with 512 and 1024 beams, (h) with 8000 range bins, (i) the demo's sonar
  over a 5-million-triangle seabed made from a height field (with its build time);
* for each, the bare ray-casting time of the very rays the frame cast (Embree alone, same
  threads), replayed outside the renderer on fresh copies of the rays, and the ratio frame
  time / bare casting time; and the time to build the simulator (meshes, Embree's tree);
* ``method: paper`` (Algorithm 2 literally) on (a), and the speed-up of the default over it;
* the sensor stage (issue: at most 1 ms per 128 x 1288 frame): (a) without a sensor, with
  ``sensor: {preset: aris3000-64, elevation_pattern: false}`` (the same rays: the difference
  is the stage) and with ``speckle=False``; the stage alone (``SensorModel.apply`` on the
  frame's total, with speckle and expected); and the full preset, whose elevation pattern
  widens the rays' span to 42 degrees (its cost is in ray casting);
* peak memory (Python heap via tracemalloc, and the process's peak resident set);
* sweeps: frame time against the number of rays, beams, range bins, triangles, reflecting
  planes (order 3) and the path order (six planes), and the cost model fitted to them (the
  exponent of frame time against each, least squares in log-log);
* two single-threaded worker processes rendering the demo at once against one simulator on
  every core (frames/s). Dataset throughput: ``benchmarks/bench_dataset.py``.

Usage::

    python benchmarks/bench_render.py [--repeats 30] [--json bench.json] [--quick]

Times are medians over warm repeats; ratios are taken within one run because this machine is
shared and noisy. ``--quick`` runs tiny sizes (used by the test suite as a smoke test).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import resource
import statistics
import sys
import time
import tracemalloc

import numpy as np

import sonarsim
from sonarsim.config.examples import demo_scene_dict
from sonarsim.config.loader import scene_from_dict
from sonarsim.config.scene import ObjectSpec
from sonarsim.core.transforms import Pose

# The default backend's caster is measured (the Embree 4 binding where it loads);
# SONARSIM_EMBREE=embreex in the environment measures embreex's. benchmarks/bench_cast.py
# compares the two casters alone.


def rock_mesh(n_triangles: int, radius: float = 0.25, seed: int = 0):
    """A bumpy closed mesh with about ``n_triangles`` faces (a UV sphere with radial noise)."""
    import trimesh

    count = max(8, int(np.sqrt(n_triangles / 4)))
    m = trimesh.creation.uv_sphere(radius=radius, count=[count, count])
    while len(m.faces) < n_triangles:  # about 4 count^2 faces; step up to the first mesh >= n
        count = int(count * np.sqrt(n_triangles / len(m.faces))) + 1
        m = trimesh.creation.uv_sphere(radius=radius, count=[count, count])
    rng = np.random.default_rng(seed)
    v = np.asarray(m.vertices)
    # Smooth bumps: a few random low-order modes, so the surface stays a plausible rock.
    d = v / np.linalg.norm(v, axis=1, keepdims=True)
    bump = sum(0.08 * rng.normal() * np.sin(k * d @ rng.normal(size=3)) for k in (2, 3, 5, 7))
    return trimesh.Trimesh(v * (1 + bump)[:, None], m.faces, process=False)


def scene_with_mesh(n_triangles: int) -> sonarsim.Scene:
    base = scene_from_dict(demo_scene_dict())
    mesh = rock_mesh(n_triangles)
    # Resting on the floor (touching it at its lowest point), so that no part is clipped away.
    z = 1e-3 - float(np.asarray(mesh.vertices)[:, 2].min())
    rock = ObjectSpec(name="rock", mesh=mesh, pose=Pose((3.5, -0.05, z)), albedo=0.7)
    return sonarsim.Scene(sonar=base.sonar, sonar_pose=base.sonar_pose, objects=base.objects + (rock,),
                          ground=base.ground, render=base.render)


def terrain_mesh(n_triangles: int, size_m: tuple = (6.0, 6.0), seed: int = 0):
    """A seabed from a height field: a regular grid of about ``n_triangles`` triangles over
    ``x`` in [0.3, 0.3 + size_m[0]], ``y`` centred, heights 1-9 cm of smooth random relief."""
    import trimesh

    n = max(2, int(round(np.sqrt(n_triangles / 2.0)))) + 1  # 2 (n - 1)^2 triangles
    x = np.linspace(0.3, 0.3 + size_m[0], n)
    y = np.linspace(-size_m[1] / 2, size_m[1] / 2, n)
    xx, yy = np.meshgrid(x, y, indexing="ij")
    rng = np.random.default_rng(seed)
    z = 0.05 + sum(0.01 * np.sin(k * (xx * a + yy * b) + p)
                   for k, (a, b), p in zip((1.3, 2.9, 5.1, 9.7), rng.normal(size=(4, 2)), rng.uniform(0, 6, 4)))
    vertices = np.column_stack([xx.ravel(), yy.ravel(), z.ravel()])
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    quads = np.stack([i, i + n, i + n + 1, i + 1], axis=-1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return trimesh.Trimesh(vertices, faces, process=False)


def terrain_scene(n_triangles: int) -> sonarsim.Scene:
    """The demo's sonar over a height-field seabed of ``n_triangles`` (no other objects)."""
    base = scene_from_dict(demo_scene_dict())
    seabed = ObjectSpec(name="seabed", mesh=terrain_mesh(n_triangles), pose=Pose((0.0, 0.0, 0.0)), albedo=0.5)
    return sonarsim.Scene(sonar=base.sonar, sonar_pose=base.sonar_pose, objects=(seabed,), ground=base.ground,
                          render=base.render)


def with_elevation_samples(scene, n: int):
    """``scene`` (a dict or a Scene) with ``render.elevation_samples = n`` (a copy)."""
    if isinstance(scene, dict):
        doc = copy.deepcopy(scene)
        doc["render"]["elevation_samples"] = n
        return doc
    from dataclasses import replace

    return replace(scene, render=replace(scene.render, elevation_samples=n))


def demo_with(**sonar) -> dict:
    """The demo tank with other sonar intrinsics (``n_beams``, ``n_range_bins``, ...)."""
    doc = demo_scene_dict()
    doc["sonar"].update(sonar)
    return doc


def oculus_scene() -> dict:
    doc = demo_scene_dict()
    doc["sonar"] = {"preset": "oculus-m1200d-lf", "range_max_m": 6.0,
                    "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}}
    return doc


def bare_cast_s(recorded: list, split: int = 1) -> float:
    """Seconds to cast the recorded rays bare once: on one thread (``split`` 1), or spread over
    the frame's threads from 4,096 rays a thread (2; the casters split only from more, where
    waking a sleeping thread pays)."""
    # Fresh rays each time: Embree writes each hit's distance back into tfar, so a replay of
    # the same array would cast rays already cut at their hits (3-4 % faster).
    fresh = [tfar.copy() for _, _, _, tfar, _ in recorded]
    t = time.perf_counter()
    for (caster, o, d, _, threads), tfar in zip(recorded, fresh):
        if split == 1:
            caster.cast_raw(o, d, tfar, 1)
        else:
            caster.cast_raw(o, d, tfar, threads, min_chunk=4096)
    return time.perf_counter() - t


def record_casts(sim: sonarsim.Simulator, frame=None) -> list:
    """Every ray that one frame casts, as ``(caster, origins, directions, tfar, None)`` per
    caster, ready for the caster's bare casting (``cast_raw``: Embree's answer alone, no
    conversion to hits) on the frame's threads. ``frame``: what renders the frame (default
    ``sim.render(keep_rays=False)``; an instrument's ping, say).

    Recorded at ``intersect``, which every caster has (a textured scene wraps it). The path
    engine's fused blocks cast from compiled code, past ``intersect``: the recording frame
    takes the same blocks with Python casting between their stages, which cast the very same
    rays (the tests require the same bits). The batches of one caster are joined into one call, which
    the caster spreads over its threads as evenly as one batch can be: the bare casting is
    given every advantage of the frame's threads.
    """
    from sonarsim.renderer import compiled

    caster_cls = type(getattr(sim.caster, "caster", sim.caster))
    recorded = []
    original = caster_cls.intersect
    loop = compiled.packet_loop

    def recording(self, origins, directions, max_distance, threads=None, *args, **kwargs):
        n = len(directions)
        o = np.ascontiguousarray(np.broadcast_to(origins, (n, 3)), dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        recorded.append((self, o, d, np.full(n, max_distance, np.float32), threads))
        return original(self, origins, directions, max_distance, threads, *args, **kwargs)

    caster_cls.intersect = recording
    compiled.packet_loop = lambda caster: None  # the blocks cast through caster.intersect
    try:
        sim.render(keep_rays=False) if frame is None else frame()
    finally:
        caster_cls.intersect = original
        compiled.packet_loop = loop
    joined = []
    for caster in dict.fromkeys(r[0] for r in recorded):
        mine = [r for r in recorded if r[0] is caster and len(r[2])]
        if mine:
            joined.append((caster, *(np.concatenate([r[k] for r in mine]) for k in (1, 2, 3)), None))
    return joined


# Reflecting planes of the benchmark tank, in the order the planes sweep adds them (the demo
# tank is 2 m deep; the sonar at x = 0 looks along +x at a floor lit from 2.2 m to 4.4 m).
TANK_PLANES = (
    {"name": "surface", "point_m": [0.0, 0.0, 2.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0, "specular": 0.9},
    {"name": "far_wall", "point_m": [4.6, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.6, "specular": 0.5},
    {"name": "left_wall", "point_m": [0.0, 1.5, 0.0], "normal": [0.0, -1.0, 0.0], "albedo": 0.6, "specular": 0.5},
    {"name": "right_wall", "point_m": [0.0, -1.5, 0.0], "normal": [0.0, 1.0, 0.0], "albedo": 0.6, "specular": 0.5},
    {"name": "back_wall", "point_m": [-0.5, 0.0, 0.0], "normal": [1.0, 0.0, 0.0], "albedo": 0.6, "specular": 0.5},
)


def tank_scene(n_planes: int, max_order: int = 3) -> dict:
    """The demo tank with the ground and the first ``n_planes - 1`` of :data:`TANK_PLANES`."""
    doc = demo_scene_dict()
    doc["planes"] = [dict(p) for p in TANK_PLANES[: n_planes - 1]]
    doc["render"]["max_order"] = max_order
    doc["render"].pop("bounces", None)
    return doc


def measure(name: str, scene, repeats: int) -> dict:
    """Median frame time and median bare casting time of the same rays, interleaved.

    Blocks of frames and blocks of bare casts alternate, so that the machine's load drifts (it
    is shared) hit both medians alike and their ratio holds; within a block each runs back to
    back, as in a renderer's steady state.
    """
    t_build = time.perf_counter()
    sim = sonarsim.Simulator(scene)
    build_s = time.perf_counter() - t_build  # meshes, clipping and the acceleration structure
    for _ in range(3):
        sim.render(keep_rays=False)
    recorded = record_casts(sim)
    n_rays = sum(len(d) for _, _, d, _, _ in recorded)
    frames, casts = [], {1: [], 2: []}
    block = 5
    for _ in range(max(1, repeats // block)):
        for _ in range(block):
            t = time.perf_counter()
            sim.render(keep_rays=False)
            frames.append(time.perf_counter() - t)
        # The bare casting two ways, the faster counted: the rays on one thread, and spread over
        # the frame's threads from 4,096 rays a thread (the casters split only from more, where
        # waking a sleeping thread pays; here the threads are kept busy back to back).
        for split in (1, 2):
            for _ in range(block):
                casts[split].append(bare_cast_s(recorded, split))
    frame = statistics.median(frames)
    cast_by = {k: statistics.median(v) for k, v in casts.items()}
    cast = min(cast_by.values())
    s = sim.scene.sonar
    return {
        "case": name,
        "image": f"{s.n_range_bins} x {s.n_beams}",
        "triangles": int(sum(len(m.faces) for m in sim.meshes)),
        "rays_per_frame": n_rays,
        "frame_ms": 1e3 * frame,
        "fps": 1.0 / frame,
        "bare_cast_ms": 1e3 * cast,
        "bare_cast_one_thread_ms": 1e3 * cast_by[1],
        "bare_cast_split_ms": 1e3 * cast_by[2],
        "frame_over_cast": frame / cast,
        "build_s": build_s,
    }


def _worker_rate(scene, frames: int, barrier, results) -> None:
    sim = sonarsim.Simulator(replace_threads(scene, 1))
    for _ in range(3):
        sim.render(keep_rays=False)
    barrier.wait()  # both workers render at the same time
    t = time.perf_counter()
    for _ in range(frames):
        sim.render(keep_rays=False)
    results.put(frames / (time.perf_counter() - t))


def replace_threads(scene: sonarsim.Scene, threads: int) -> sonarsim.Scene:
    from dataclasses import replace

    return replace(scene, render=replace(scene.render, threads=threads))


def workers_rate(scene, frames: int, workers: int = 2) -> dict:
    """Frames/s of ``workers`` single-threaded processes rendering at once (summed), against
    one simulator using every core, measured back to back."""
    import multiprocessing

    from sonarsim.dataset.workers import worker_context

    scene = scene_from_dict(scene) if isinstance(scene, dict) else scene
    ctx = worker_context()
    barrier, results = ctx.Barrier(workers), ctx.Queue()
    procs = [ctx.Process(target=_worker_rate, args=(scene, frames, barrier, results)) for _ in range(workers)]
    for p in procs:
        p.start()
    rates = [results.get(timeout=600) for _ in procs]
    for p in procs:
        p.join()
    sim = sonarsim.Simulator(scene)
    for _ in range(3):
        sim.render(keep_rays=False)
    t = time.perf_counter()
    for _ in range(workers * frames):
        sim.render(keep_rays=False)
    one = workers * frames / (time.perf_counter() - t)
    return {"workers": workers, "single_threaded_workers_fps": float(sum(rates)),
            "one_simulator_all_cores_fps": one, "ratio": float(sum(rates)) / one}


def fitted_exponent(xs, ys) -> float:
    """Slope of log y against log x (least squares): cost ~ x ** slope over the sweep."""
    return float(np.polyfit(np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float)), 1)[0])


def interleaved(fns: dict, repeats: int, block: int = 5) -> dict:
    """Median seconds of each callable, run in alternating blocks (as :func:`measure` does)."""
    times: dict = {name: [] for name in fns}
    for _ in range(max(1, repeats // block)):
        for name, fn in fns.items():
            for _ in range(block):
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
    return {name: statistics.median(ts) for name, ts in times.items()}


SENSOR_PRESET = "aris3000-128"  # the demo sonar is the ARIS 3000 at 3 MHz


def measure_sensor(demo: dict, repeats: int) -> dict:
    """Cost of the sensor stage on the demo tank: frames with and without it, and the stage alone.

    With ``elevation_pattern: false`` the sensor casts the very rays of the scene without one,
    so the difference in frame time is the stage's; the stage is also timed alone, as the
    renderer calls it (``SensorModel.apply`` on the frame's total, rows split with its worker).
    The full preset's elevation pattern casts rays over a wider span: reported as a frame time.
    """
    with_sensor = copy.deepcopy(demo)
    with_sensor["sensor"] = {"preset": SENSOR_PRESET, "elevation_pattern": False}
    full = copy.deepcopy(demo)
    full["sensor"] = {"preset": SENSOR_PRESET}
    plain_sim, sensor_sim, full_sim = (sonarsim.Simulator(doc) for doc in (demo, with_sensor, full))
    for sim in (plain_sim, sensor_sim, full_sim):
        for _ in range(3):
            sim.render(keep_rays=False)
    total = np.array(sensor_sim.render(keep_rays=False, speckle=False).components["total"])
    model = sensor_sim.sensor_model()
    rng = np.random.default_rng(0)
    pool = sensor_sim._pool
    for _ in range(3):
        model.apply(total, rng, True, pool=pool)
        model.apply(total, rng, False, pool=pool)
    t = interleaved({
        "frame_no_sensor": lambda: plain_sim.render(keep_rays=False),
        "frame_sensor": lambda: sensor_sim.render(keep_rays=False),
        "frame_sensor_expected": lambda: sensor_sim.render(keep_rays=False, speckle=False),
        "stage": lambda: model.apply(total, rng, True, pool=pool),
        "stage_expected": lambda: model.apply(total, rng, False, pool=pool),
        "frame_full_preset": lambda: full_sim.render(keep_rays=False),
    }, repeats)
    s = sensor_sim.scene.sonar
    out = {
        "preset": SENSOR_PRESET,
        "image": f"{s.n_range_bins} x {s.n_beams}",
        "primary_rays": sensor_sim.ray_fan(s).n_rays,
        "primary_rays_full_preset": full_sim.ray_fan(full_sim.scene.sonar).n_rays,
        "elevation_span_deg_full_preset": full_sim.sensor_model().elevation_span_deg(),
    }
    out.update({f"{k}_ms": 1e3 * v for k, v in t.items()})
    out["frame_added_ms"] = out["frame_sensor_ms"] - out["frame_no_sensor_ms"]
    out["frame_added_expected_ms"] = out["frame_sensor_expected_ms"] - out["frame_no_sensor_ms"]
    out["stage_fraction_of_frame"] = t["stage"] / t["frame_sensor"]
    out["stage_expected_fraction_of_frame"] = t["stage_expected"] / t["frame_sensor_expected"]
    for sim in (plain_sim, sensor_sim, full_sim):
        sim.close()
    return out


def peak_memory(scene) -> dict:
    tracemalloc.start()
    sim = sonarsim.Simulator(scene)
    for _ in range(3):
        sim.render(keep_rays=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return {"python_heap_peak_mb": peak / 2**20,
            "process_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def cpu_model() -> str:
    """The processor's model name (Linux), else the platform's machine type."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.machine()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--json", default="benchmarks/results.json", help="where to write the results")
    ap.add_argument("--quick", action="store_true", help="tiny sizes, a smoke test")
    args = ap.parse_args(argv)
    quick = args.quick
    repeats = 2 if quick else args.repeats

    demo = demo_scene_dict()
    if quick:
        demo["render"]["elevation_samples"] = 16
    results: dict = {
        "machine": {"cpu_cores": os.cpu_count(), "cpu_model": cpu_model(),
                    "processor": platform.processor() or platform.machine(),
                    "python": sys.version.split()[0], "numpy": np.__version__, "sonarsim": sonarsim.__version__},
        "cases": [],
    }
    n_mesh = 2_000 if quick else 500_000
    n_terrain = 20_000 if quick else 5_000_000
    cases = [("a: demo tank, ARIS 3000, all bounces", demo),
             (f"b: (a) + {n_mesh:,}-triangle mesh", "mesh"),
             ("c: Oculus M1200d lf, 512 beams", oculus_scene()),
             ("d: (a) + water surface, order 3", tank_scene(2)),
             ("e: (a) + surface + 4 walls, order 3", tank_scene(6)),
             ("f: (a) with 512 beams", demo_with(n_beams=512)),
             ("g: (a) with 1024 beams", demo_with(n_beams=1024)),
             ("h: (a) with 8000 range bins", demo_with(n_range_bins=8000)),
             (f"i: {n_terrain:,}-triangle seabed (height field)", "terrain")]
    for name, scene in cases:
        if isinstance(scene, str):
            scene = scene_with_mesh(n_mesh) if scene == "mesh" else terrain_scene(n_terrain)
            if quick:
                from dataclasses import replace
                scene = replace(scene, render=replace(scene.render, elevation_samples=16))
        if quick and isinstance(scene, dict):
            scene = copy.deepcopy(scene)
            scene["render"]["elevation_samples"] = 16
        results["cases"].append(measure(name, scene, repeats))
        print(f"  measured {name}", file=sys.stderr)

    paper = copy.deepcopy(demo)
    paper["render"]["method"] = "paper"
    res_paper = measure("a with method: paper", paper, max(2, repeats // 3))
    results["cases"].append(res_paper)
    results["speedup_fast_over_paper"] = res_paper["frame_ms"] / results["cases"][0]["frame_ms"]

    results["sensor"] = measure_sensor(demo, 2 * repeats)  # sub-millisecond stage: more samples, cheap
    print("  measured the sensor stage", file=sys.stderr)

    results["peak_memory_b"] = peak_memory(scene_with_mesh(n_mesh))

    # Sweeps: frame time against one parameter at a time (the cost model below fits them).
    def sweep(name, key, values, scene_of, fields=("rays_per_frame", "frame_ms", "bare_cast_ms")):
        rows = []
        for value in values:
            sc = scene_of(value)
            if quick and key != "elevation_samples":
                sc = with_elevation_samples(sc, 16)
            r = measure(f"{name}: {value}", sc, max(2, repeats // 3))
            rows.append({k: r[k] for k in fields} | ({} if key in fields else {key: value}))
        return rows

    sweep_rays = sweep("rays per beam", "elevation_samples", (8, 16) if quick else (50, 100, 200, 400, 800),
                       lambda n_el: with_elevation_samples(demo, n_el))
    sweep_tris = sweep("mesh triangles", "triangles", (500, 2_000) if quick else (1_000, 10_000, 100_000, 500_000, 2_000_000),
                       scene_with_mesh, ("triangles", "frame_ms", "bare_cast_ms"))
    sweep_planes = sweep("planes", "planes", (1, 3) if quick else (1, 2, 3, 4, 5, 6), tank_scene)
    sweep_order = sweep("order", "max_order", (1, 3) if quick else (1, 2, 3, 4, 5), lambda order: tank_scene(6, order))
    sweep_beams = sweep("beams", "beams", (32, 64) if quick else (64, 128, 256, 512, 1024),
                        lambda beams: demo_with(n_beams=beams))
    sweep_bins = sweep("bins", "range_bins", (322, 644) if quick else (322, 1288, 4000, 8000),
                       lambda bins: demo_with(n_range_bins=bins), ("frame_ms", "bare_cast_ms"))
    results.update(sweep_rays=sweep_rays, sweep_triangles=sweep_tris, sweep_planes=sweep_planes,
                   sweep_order=sweep_order, sweep_beams=sweep_beams, sweep_bins=sweep_bins)
    # The cost model: frame time ~ x ** exponent along each sweep (least squares in log-log).
    def model(rows, key):
        return {"frame": fitted_exponent([r[key] for r in rows], [r["frame_ms"] for r in rows]),
                "bare_cast": fitted_exponent([r[key] for r in rows], [r["bare_cast_ms"] for r in rows])}
    results["cost_model_exponents"] = {
        "rays (elevation samples)": model(sweep_rays, "rays_per_frame"),
        "beams": model(sweep_beams, "beams"),
        "range bins": model(sweep_bins, "range_bins"),
        "triangles": model(sweep_tris, "triangles"),
        "reflecting planes (order 3)": model(sweep_planes, "planes"),
        "path order (6 planes)": model(sweep_order, "max_order"),
    }
    results["two_single_threaded_workers"] = workers_rate(demo, 10 if quick else 300)

    print(f"\nsonarsim {sonarsim.__version__} on {results['machine']['cpu_cores']} cores, {results['machine']['cpu_model']}, "
          f"{results['machine']['processor']}, Python {results['machine']['python']}, NumPy {np.__version__}")
    print(f"{'case':<42} {'image':>11} {'triangles':>10} {'rays':>8} {'frame ms':>9} {'fps':>7} {'cast ms':>8} {'frame/cast':>10}")
    for c in results["cases"]:
        print(f"{c['case']:<42} {c['image']:>11} {c['triangles']:>10,} {c['rays_per_frame']:>8,} "
              f"{c['frame_ms']:>9.2f} {c['fps']:>7.1f} {c['bare_cast_ms']:>8.2f} {c['frame_over_cast']:>10.2f}")
    print(f"speed-up of method fast over method paper: {results['speedup_fast_over_paper']:.2f}x")
    r = results["sensor"]
    print(f"sensor stage ({r['preset']}, {r['image']}, {r['primary_rays']:,} rays; medians, ms):")
    print(f"  frame without a sensor {r['frame_no_sensor_ms']:.2f}; with the sensor, elevation_pattern false: "
          f"{r['frame_sensor_ms']:.2f} (+{r['frame_added_ms']:.2f}), speckle=False {r['frame_sensor_expected_ms']:.2f} "
          f"(+{r['frame_added_expected_ms']:.2f})")
    print(f"  stage alone: {r['stage_ms']:.3f} ({100 * r['stage_fraction_of_frame']:.1f} % of the frame), "
          f"expected output {r['stage_expected_ms']:.3f} ({100 * r['stage_expected_fraction_of_frame']:.1f} %)")
    print(f"  full preset (elevation span {r['elevation_span_deg_full_preset']:g} deg, "
          f"{r['primary_rays_full_preset']:,} rays): frame {r['frame_full_preset_ms']:.2f}")
    m = results["peak_memory_b"]
    print(f"peak memory, case b: Python heap {m['python_heap_peak_mb']:.0f} MB, process RSS {m['process_peak_rss_mb']:.0f} MB")
    print("\nrays per frame -> frame ms (bare cast ms)")
    for r in sweep_rays:
        print(f"  {r['rays_per_frame']:>8,} -> {r['frame_ms']:7.2f} ({r['bare_cast_ms']:.2f})")
    print("triangles -> frame ms (bare cast ms)")
    for r in sweep_tris:
        print(f"  {r['triangles']:>10,} -> {r['frame_ms']:7.2f} ({r['bare_cast_ms']:.2f})")
    print("planes (order 3) -> rays cast per frame, frame ms (bare cast ms)")
    for r in sweep_planes:
        print(f"  {r['planes']:>3} -> {r['rays_per_frame']:>8,} {r['frame_ms']:7.2f} ({r['bare_cast_ms']:.2f})")
    print("max_order (6 planes) -> rays cast per frame, frame ms (bare cast ms)")
    for r in sweep_order:
        print(f"  {r['max_order']:>3} -> {r['rays_per_frame']:>8,} {r['frame_ms']:7.2f} ({r['bare_cast_ms']:.2f})")
    for label, rows, key in (("beams", sweep_beams, "beams"), ("range bins", sweep_bins, "range_bins")):
        print(f"{label} -> frame ms (bare cast ms)")
        for r in rows:
            print(f"  {r[key]:>6} -> {r['frame_ms']:7.2f} ({r['bare_cast_ms']:.2f})")
    print("cost model: frame time ~ x ** exponent (bare casting's exponent in brackets)")
    for what, e in results["cost_model_exponents"].items():
        print(f"  {what:<30} {e['frame']:5.2f} ({e['bare_cast']:.2f})")
    w = results["two_single_threaded_workers"]
    print(f"two single-threaded workers: {w['single_threaded_workers_fps']:.0f} frames/s; one simulator on every core: "
          f"{w['one_simulator_all_cores_fps']:.0f} frames/s ({w['ratio']:.2f}x)")
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(results, f, indent=2)
        os.replace(tmp, args.json)
        print(f"\nwrote {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
