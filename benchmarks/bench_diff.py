"""The differentiable engine's cost (issue 24 item 4), in one run on this machine.

For the demo (ARIS 3000, 128 beams x 1288 range bins) and the calibrated Oculus floor (512 x
669, with its sensor):

* the compiled engine's forward frame (``Simulator.render(speckle=False)``), the reference;
* the differentiable forward (``Renderer.render``) and its value and gradient with respect to
  every parameter (``jax.value_and_grad`` of a squared error), after compilation, and the
  ratio of the latter to the compiled frame (target: within 10x);
* the compilation times, and the search the renderer holds (``Renderer.refresh``);
* ``jax.vmap`` over a batch of sonar poses: frames per second, forward and value-and-gradient.

Frames are timed in alternation (compiled, forward, value and gradient) in blocks, so that the
machine's load drifts hit all of them alike; medians are reported.

Usage::

    python benchmarks/bench_diff.py [--repeats 20] [--batch 8] [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from bench_render import cpu_model  # noqa: E402

OCULUS = {"sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 0.433], "rpy_deg": [1.42, 29.06, 0]}},
          "ground": {}, "sensor": {"preset": "oculus-m1200d-hf"}}


def _median_ms(fns: dict, repeats: int) -> dict:
    """Median wall time (ms) of each function, called in alternation."""
    times: dict = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t)
    return {k: float(np.median(v)) * 1e3 for k, v in times.items()}


def measure(name: str, doc: dict, repeats: int, batch: int) -> dict:
    import jax
    import jax.numpy as jnp

    import sonarsim
    import sonarsim.diff as sd

    t0 = time.perf_counter()
    r = sd.Renderer(doc)
    setup_s = time.perf_counter() - t0
    p = r.params()
    t0 = time.perf_counter()
    target = jax.block_until_ready(r.render(p)) * 1.05
    compile_forward_s = time.perf_counter() - t0

    def loss(q):
        return jnp.sum((r.render(q) - target) ** 2)

    value_and_grad = jax.jit(jax.value_and_grad(loss))
    t0 = time.perf_counter()
    jax.block_until_ready(value_and_grad(p))
    compile_grad_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    r.refresh(p)
    refresh_s = time.perf_counter() - t0

    sim = sonarsim.Simulator(doc)
    sim.render(speckle=False, keep_rays=False)
    times = _median_ms({
        "compiled": lambda: sim.render(speckle=False, keep_rays=False),
        "forward": lambda: jax.block_until_ready(r.render(p)),
        "value_and_grad": lambda: jax.block_until_ready(value_and_grad(p)),
    }, repeats)
    sim.close()

    # A batch of poses (a trajectory's neighbourhood): vmap over the sonar's position.
    offsets = jnp.asarray(np.random.default_rng(0).normal(0.0, 0.01, (batch, 3)))

    def image_at(offset):
        return r.render({**p, "sonar.position_m": p["sonar.position_m"] + offset})

    batched = jax.jit(jax.vmap(image_at))
    batched_grad = jax.jit(jax.vmap(jax.value_and_grad(lambda o: jnp.sum((image_at(o) - target) ** 2))))
    jax.block_until_ready(batched(offsets))
    jax.block_until_ready(batched_grad(offsets))
    bt = _median_ms({"batch": lambda: jax.block_until_ready(batched(offsets)),
                     "batch_grad": lambda: jax.block_until_ready(batched_grad(offsets))}, max(repeats // 4, 2))
    n_params = int(sum(np.size(v) for v in p.values()))
    return {
        "scene": name, "image": list(r.render(p).shape), "paths": r.search.n_paths, "capacity": r.search.capacity,
        "parameters": len(p), "parameter_values": n_params,
        "setup_s": setup_s, "compile_forward_s": compile_forward_s, "compile_value_and_grad_s": compile_grad_s,
        "refresh_s": refresh_s,
        "compiled_frame_ms": times["compiled"], "forward_ms": times["forward"],
        "value_and_grad_ms": times["value_and_grad"],
        "forward_over_compiled": times["forward"] / times["compiled"],
        "value_and_grad_over_compiled": times["value_and_grad"] / times["compiled"],
        "batch": batch, "batch_forward_ms": bt["batch"], "batch_value_and_grad_ms": bt["batch_grad"],
        "batch_frames_per_s": batch / (bt["batch"] / 1e3),
        "batch_value_and_grad_frames_per_s": batch / (bt["batch_grad"] / 1e3),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--quick", action="store_true", help="tiny repeats (a smoke test)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    try:
        import jax  # noqa: F401
    except ImportError:
        print("bench_diff: JAX is not installed (pip install 'sonarsim[diff]')", file=sys.stderr)
        return 2
    from sonarsim.config.examples import demo_scene_dict

    repeats = 3 if args.quick else args.repeats
    batch = 2 if args.quick else args.batch
    scenes = [("demo", demo_scene_dict())] + ([] if args.quick else [("oculus floor (sensor)", OCULUS)])
    rows = [measure(name, doc, repeats, batch) for name, doc in scenes]
    out = {"machine": {"cpu_cores": os.cpu_count(), "cpu_model": cpu_model(), "jax": jax.__version__,
                       "device": str(jax.devices()[0])}, "cases": rows}
    for r in rows:
        print(f"{r['scene']}: {r['image'][0]} x {r['image'][1]}, {r['paths']} paths, {r['parameters']} parameters "
              f"({r['parameter_values']} values)")
        print(f"  compiled frame {r['compiled_frame_ms']:.2f} ms | forward {r['forward_ms']:.2f} ms "
              f"({r['forward_over_compiled']:.1f}x) | value and gradient {r['value_and_grad_ms']:.2f} ms "
              f"({r['value_and_grad_over_compiled']:.1f}x)")
        print(f"  compilation: forward {r['compile_forward_s']:.1f} s, value and gradient {r['compile_value_and_grad_s']:.1f} s;"
              f" setup {r['setup_s']:.2f} s, refresh {r['refresh_s']:.3f} s")
        print(f"  vmap over {r['batch']} poses: {r['batch_frames_per_s']:.0f} frames/s forward, "
              f"{r['batch_value_and_grad_frames_per_s']:.0f} frames/s value and gradient")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
