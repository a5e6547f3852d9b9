"""Sea-floor heights by gradient from known poses (issue 24 item 6): how well, and what one view
leaves undetermined.

Synthetic seabeds (a Gaussian bump of several amplitudes and widths on a 3 % slope, and the
slope alone; the truth meshed at 2 cm) are rendered noise-free by the compiled engine (an ARIS
3000, 128 beams, 0.7-3.5 m, from 1 m up pitched 25 degrees) from 1 view and from 4 (the sonar
moved sideways and turned), and reconstructed on a 10 cm grid from a flat start with
:func:`sonarsim.diff.reconstruct.reconstruct_heights`. Reported per case: the RMS height error
over the seen vertices, beside the trivial answer (a flat floor at 0, the start) and the
amplitude.

The elevation ambiguity: at the reconstructed heights of one view and of four, the
Gauss-Newton matrix of the images' loss over the seen vertices' heights (``J^T J``, by forward
over reverse differentiation); its eigenvalues say how many combinations of heights the images
fix (above a thousandth of the largest), and the error's share in the rest says how much of
what is left is what the images cannot see (the smoothness term fills it).

Usage::

    python benchmarks/bench_reconstruct.py [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

EXTENT = (1.0, 3.0, -0.8, 0.8)
RESOLUTION = 0.1
SLOPE = 0.03
# (name, amplitude m, width m): a bump's height and its Gaussian's standard deviation.
CASES = (("bump 5 cm, narrow", 0.05, 0.15), ("bump 10 cm", 0.10, 0.25), ("bump 20 cm, wide", 0.20, 0.40),
         ("slope only", 0.0, 0.25))
VIEWS = {1: ((0.0, 0.0),), 4: ((0.0, 0.0), (-0.5, 12.0), (0.5, -12.0), (-0.25, 6.0))}
DETERMINED = 1e-3  # eigenvalues above this fraction of the largest: a combination the images fix


def heights_of(amp: float, width: float):
    def heights(x, y):
        gx, gy = np.meshgrid(x, y)
        return amp * np.exp(-((gx - 2.0) ** 2 + (gy - 0.1) ** 2) / (2 * width ** 2)) + SLOPE * (gx - 2.0)
    return heights


def case(amp: float, width: float, n_views: int, rounds: int):
    from sonarsim.config.loader import load_scene
    from sonarsim.config.scene import ObjectSpec
    from sonarsim.core.transforms import Pose
    from sonarsim.diff.reconstruct import grid_mesh, reconstruct_heights
    from sonarsim.renderer.simulator import Simulator

    base = load_scene({"sonar": {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 600},
                       "render": {"bounces": [1], "max_order": 1}, "ground": {"albedo": 0.6}})
    heights = heights_of(amp, width)
    _, xt, yt = grid_mesh(EXTENT, 0.02)
    truth_mesh, _, _ = grid_mesh(EXTENT, 0.02, heights(xt, yt))
    truth = replace(base, ground=None, objects=(ObjectSpec(name="seabed", mesh=truth_mesh, albedo=0.6),))
    poses = [Pose((0.0, y, 1.0), (0.0, 25.0, yaw)) for y, yaw in VIEWS[n_views]]
    with Simulator(truth) as sim:
        images = [sim.render(pose=p, speckle=False).polar for p in poses]
    t0 = time.perf_counter()
    out = reconstruct_heights(base, images, poses, EXTENT, RESOLUTION, rounds=rounds)
    seconds = time.perf_counter() - t0
    want = heights(out.x_m, out.y_m)
    seen = out.seen
    error = out.heights_m - want
    row = {"views": n_views, "amplitude_m": amp, "width_m": width, "seen_vertices": int(seen.sum()),
           "rms_m": float(np.sqrt(np.mean(error[seen] ** 2))), "flat_rms_m": float(np.sqrt(np.mean(want[seen] ** 2))),
           "seconds": seconds}
    row.update(ambiguity(base, images, poses, out, error))
    return row


def ambiguity(base, images, poses, out, error) -> dict:
    """The Gauss-Newton matrix of the data term over the seen heights, at the result."""
    import jax
    import jax.numpy as jnp

    from sonarsim.config.scene import ObjectSpec
    from sonarsim.diff import Renderer
    from sonarsim.diff.inverse import blur, compress_scale
    from sonarsim.diff.reconstruct import SEABED, grid_mesh

    mesh, _, _ = grid_mesh(EXTENT, RESOLUTION, out.heights_m)
    scene = replace(base, ground=None, objects=(ObjectSpec(name=SEABED, mesh=mesh, albedo=0.6),))
    key = f"objects.{SEABED}.vertices_m"
    seen = np.flatnonzero(out.seen.ravel())
    h0 = jnp.asarray(out.heights_m.ravel())
    xy = jnp.asarray(np.asarray(mesh.vertices)[:, :2])
    total = None
    for img, pose in zip(images, poses):
        r = Renderer(replace(scene, sonar_pose=pose), attach="surfaces")
        fn, data, p0 = r.image_function(), r.data, r.params()
        s = compress_scale(np.asarray(img, float))

        def residual(hs, fn=fn, data=data, p0=p0, s=s):
            h = h0.at[seen].set(hs)
            sim = fn({**p0, key: jnp.concatenate([xy, h[:, None]], axis=1)}, data)
            return jnp.log1p(jnp.maximum(blur(sim, (1.5, 1.0)), 0.0) / s).ravel()

        # J^T J one column at a time (forward over the residual: the matrix, not J, is kept).
        jvp = jax.jit(lambda v, residual=residual: jax.jvp(residual, (h0[seen],), (v,))[1])
        cols = [np.asarray(jvp(jnp.eye(len(seen))[j]), float) for j in range(len(seen))]
        jm = np.stack(cols, axis=1)
        gn = jm.T @ jm
        total = gn if total is None else total + gn
    w, v = np.linalg.eigh(total)
    keep = w > DETERMINED * w[-1]
    e = error.ravel()[seen]
    weak = v[:, ~keep]
    share = float(np.sum((weak.T @ e) ** 2) / max(float(e @ e), 1e-30))
    smallest = v[:, 0]
    return {"heights": int(len(seen)), "determined": int(keep.sum()),
            "determined_at": {f"{t:g}": int(np.sum(w > t * w[-1])) for t in (1e-2, 1e-3, 1e-4, 1e-5)},
            "error_share_undetermined": share,
            "condition": float(w[-1] / max(w[0], 1e-300)),
            "weakest_mode_range_correlation": weakest_direction(smallest, out, seen)}


def weakest_direction(mode: np.ndarray, out, seen: np.ndarray) -> float:
    """The correlation of the weakest mode's magnitude with the vertices' ground distance
    from the first view (1: it lives where the range is large)."""
    gx, gy = np.meshgrid(out.x_m, out.y_m)
    dist = np.hypot(gx.ravel()[seen], gy.ravel()[seen])
    return float(np.corrcoef(np.abs(mode), dist)[0, 1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="the 10 cm bump only")
    ap.add_argument("--rounds", type=int, default=12)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    rows = []
    for name, amp, width in CASES if not args.quick else CASES[1:2]:
        for n in (1, 4):
            row = {"case": name, **case(amp, width, n, args.rounds)}
            rows.append(row)
            print(f"{name:18s} {n} view(s): RMS {1e3 * row['rms_m']:6.1f} mm over {row['seen_vertices']} vertices "
                  f"(flat floor {1e3 * row['flat_rms_m']:6.1f} mm, amplitude {1e3 * amp:5.0f} mm) in "
                  f"{row['seconds']:5.1f} s; {row['determined']} of {row['heights']} height combinations fixed "
                  f"by the images, {100 * row['error_share_undetermined']:.0f} % of the error outside them "
                  f"(eigenvalues above 1e-2/1e-3/1e-4/1e-5 of the largest: "
                  f"{'/'.join(str(v) for v in row['determined_at'].values())}; weakest mode's correlation "
                  f"with ground range {row['weakest_mode_range_correlation']:.2f})",
                  flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
