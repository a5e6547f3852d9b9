"""Write the README's figures into docs/images/: the demo's annotated fan, its ground-echo
comparison and the tank's multipath comparison, as ``sonarsim demo`` draws them.

Run from the repository root after a change to the figures or the demo scenes::

    python docs/make_figures.py
"""

from __future__ import annotations

import time
from pathlib import Path

import sonarsim
from sonarsim.cli.demo import demo_scene_dict, tank_scene_dict
from sonarsim.plot.figures import fan_figure, ground_echo_figure, multipath_figure, save_figure

IMAGES = Path(__file__).resolve().parent / "images"


def main() -> None:
    demo = sonarsim.render(demo_scene_dict())
    tank = sonarsim.render(tank_scene_dict())
    for name, build in (("demo_fan_figure.png", lambda: fan_figure(demo)),
                        ("demo_ground_echo_figure.png", lambda: ground_echo_figure(demo)),
                        ("demo_multipath_figure.png", lambda: multipath_figure(tank))):
        t0 = time.perf_counter()
        save_figure(build(), IMAGES / name)
        print(f"wrote {IMAGES / name} in {time.perf_counter() - t0:.2f} s")


if __name__ == "__main__":
    main()
