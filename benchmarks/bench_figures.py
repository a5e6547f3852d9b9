"""Time the annotated figures: build and write each of ``sonarsim demo``'s figures (best of N).

Wall time on a shared machine swings with the load; CPU time (process) is printed beside it.

    python benchmarks/bench_figures.py [--repeat 5] [--format png]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import sonarsim
from sonarsim.config.examples import demo_scene_dict, tank_scene_dict
from sonarsim.plot import figures as F


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--format", default="png", choices=F.FIGURE_FORMATS)
    args = parser.parse_args()
    demo = sonarsim.render(demo_scene_dict())
    tank = sonarsim.render(tank_scene_dict())
    aris = {**demo_scene_dict(), "sensor": {"preset": "aris3000-128"}}
    with sonarsim.Simulator(sonarsim.load_scene(aris)) as sim:
        recorded, expected = sim.render(), sim.render(speckle=False)
    import numpy as np

    x, y = np.linspace(1.0, 3.0, 201), np.linspace(-0.8, 0.8, 161)  # a 1 cm grid, as reconstruct writes
    heights = 0.1 * np.exp(-((x[None, :] - 2.0) ** 2 + y[:, None] ** 2) / 0.05)
    cases = {
        "fan_figure": lambda: F.fan_figure(demo),
        "polar_figure": lambda: F.polar_figure(demo),
        "ground_echo_figure": lambda: F.ground_echo_figure(demo),
        "multipath_figure": lambda: F.multipath_figure(tank),
        "aris3000_figure": lambda: F.sensor_figure(recorded, expected, "an ARIS 3000", ideal=demo),
        "compare_figure": lambda: F.comparison_figure([recorded, expected], ["A", "B"], difference=True,
                                                      metrics={"polar": {"mse": 1.0, "psnr": 48.1, "ssim": 0.9}}),
        "reconstruction_figure": lambda: F.reconstruction_figure(heights, x, y, heights > -1, truth_m=heights * 0.9),
    }
    F.save_figure(F.fan_figure(demo), Path(tempfile.gettempdir()) / f"warm.{args.format}")  # imports, fonts
    print(f"{'figure':<22} {'build s':>8} {'write s':>8} {'total s':>8} {'cpu s':>7}")
    with tempfile.TemporaryDirectory() as tmp:
        for name, build in cases.items():
            best = None
            for _ in range(args.repeat):
                c0, t0 = time.process_time(), time.perf_counter()
                fig = build()
                t1 = time.perf_counter()
                F.save_figure(fig, Path(tmp) / f"{name}.{args.format}")
                t2, c2 = time.perf_counter(), time.process_time()
                row = (t1 - t0, t2 - t1, t2 - t0, c2 - c0)
                best = row if best is None or row[2] < best[2] else best
            print(f"{name:<22} {best[0]:8.3f} {best[1]:8.3f} {best[2]:8.3f} {best[3]:7.3f}")


if __name__ == "__main__":
    main()
