"""What the differentiable renderer costs, estimated before it is built (no JAX needed).

:class:`~sonarsim.diff.Renderer` builds the compiled engine's scene (:mod:`sonarsim.scene.cost`
estimates and checks it), runs its search once and then compiles the forward (and, on first
use, its gradient) with JAX. The compiled function's memory grows with the held paths (every
path's geometry, formed again, and what its gradient keeps of it), the hit triangles and the
images it forms; its compile time with the paths and the objects. Both are estimated here from
the scene and the sonar's grid and checked against the memory and time budgets
(:mod:`sonarsim.core.memory`: ``--max-memory``, ``--max-build-time``) before anything is
built, and again, with the search's exact counts, before JAX compiles anything.

Before the search the paths are estimated from the ray fan: a ray's path at each order of
``render.max_order`` where the scene mirrors (planes or mesh mirrors), one where it does not,
twice with ``render.double_beam: separate`` or ``coherent`` (each transmit option its own path).

The rates were measured here (2 cores shared with other work, JAX 0.10 on the CPU, float64):
spheres by the ten and the hundred, sonar grids, the demo and the tank, each built, rendered
and differentiated once (``benchmarks/bench_diff_cost.py`` prints the measured and the
estimated figures side by side).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..config.scene import Scene
from ..core.memory import require_time, require_together
from ..core.rays import ray_size_key, samples_per_beam
from ..errors import ConfigError

__all__ = ["DiffCost", "check_diff_cost", "diff_cost", "expected_paths"]

#: The compiled forward and gradient's memory per held path: its geometry along each leg, the
#: splat's scattered values and what the gradient keeps of them (float64).
BYTES_PER_PATH = 2000.0
#: ... and per mirror of its receive or transmit chain (a leg formed again).
BYTES_PER_PATH_LEG = 500.0
#: Per cell of an image (range bin x beam) per image held: the image, its running sums and
#: their gradient (the tank, its images of 750 x 256 and 98,000 paths, held 0.39 GB in all
#: beyond its build: the estimate is about twice that).
BYTES_PER_CELL = 32.0
#: Per hit triangle (its corners, plane and gradient).
BYTES_PER_FACE = 600.0
#: Per object: XLA's compilation of the gradient keeps a few megabytes for each object's
#: parameters (gathered into the tables, and their gradients taken apart again): 3 MB each
#: measured between 10 and 300 small spheres (see below), 4 MB counted.
BYTES_PER_OBJECT = 4e6
#: JAX's and XLA's own memory for compiling the forward and its gradient.
BYTES_BASE = 250 * 2 ** 20

#: Compile time of the forward and its gradient: a base, per object (linear and quadratic:
#: XLA's passes over the gradient's many small outputs grow faster than their count), per
#: held path and per mirror of the chains (each leg is unrolled into the function). Measured
#: here at a load of about 4 (build, first render, first gradient; estimated in brackets):
#: 10 spheres 9.3 s (10.6 s), 258 MiB (304); 100 spheres 16.8 s (15.6), 485 MiB (671); 300
#: spheres 31.6 s (27.2 before this rate's last step to 0.07), 1,115 MiB (1,484); a box
#: under 32 x 128 bins 9.5 s (10.1), 296 MiB (259).
SECONDS_BASE = 8.0
SECONDS_PER_OBJECT = 0.07
SECONDS_PER_OBJECT_SQUARED = 1e-5
SECONDS_PER_PATH = 2e-5
SECONDS_PER_LEG = 1.0
#: The search: the compiled engine's frame and its record, per ray and per path.
SECONDS_PER_RAY = 2e-6
SECONDS_PER_PATH_RECORD = 4e-6


@dataclass(frozen=True)
class DiffCost:
    """Estimated size and time of a differentiable renderer.

    Attributes
    ----------
    paths : int
        Held paths (estimated from the rays before the search; counted after it).
    faces : int
        Hit triangles held.
    objects : int
    cells : int
        Image cells (range bins x beams) per image.
    images : int
        Images formed at once (the components' stack and the signatures').
    legs : int
        Mirrors of the longest receive and transmit chains.
    bytes : float
        Memory of the compiled forward and gradient, with the compiled engine's scene.
    seconds : float
        Building the scene, the search and compiling the forward and gradient.
    parts : tuple of (float, str, str)
        ``(bytes, what, key)`` of each part, the key that sets its size.
    """

    paths: int
    faces: int
    objects: int
    cells: int
    images: int
    legs: int
    bytes: float
    seconds: float
    parts: tuple = ()


def _mirrors(scene: Scene) -> bool:
    return bool(scene.reflecting_planes) or any(o.specular > 0 for o in scene.objects)


def expected_paths(scene: Scene) -> int:
    """The held paths the search of ``scene`` is expected to find, from its ray fan: one per
    ray and order of ``render.max_order`` where the scene mirrors (one per ray where it does
    not), two where ``render.double_beam`` is ``separate`` or ``coherent``.

    Returns
    -------
    int
    """
    sonar, render = scene.sonar, scene.render
    n_az, n_el = samples_per_beam(sonar, render)
    rays = int(sonar.n_beams) * n_az * n_el
    orders = int(render.max_order) if _mirrors(scene) else 1
    return rays * orders * (2 if render.double_beam in ("separate", "coherent") else 1)


def diff_cost(scene: Scene, n_paths: int | None = None, n_faces: int | None = None, n_images: int | None = None,
              legs: int | None = None) -> DiffCost:
    """The estimated memory and time of a :class:`~sonarsim.diff.Renderer` of ``scene``.

    Parameters
    ----------
    scene : Scene
    n_paths, n_faces, n_images, legs : int, optional
        The search's counts where it has run (held paths, hit triangles, images of the
        components' stack and signatures, mirrors of the longest chains); estimated from the
        scene where not given.

    Returns
    -------
    DiffCost
    """
    from ..scene.cost import scene_cost

    sonar, render = scene.sonar, scene.render
    n_az, n_el = samples_per_beam(sonar, render)
    rays = int(sonar.n_beams) * n_az * n_el
    paths = expected_paths(scene) if n_paths is None else int(n_paths)
    built = scene_cost(scene)
    faces = min(built.triangles, paths) if n_faces is None else int(n_faces)
    mirrored = _mirrors(scene)
    if legs is None:
        legs = 2 * (int(render.max_order) - 1) if mirrored else 0
    if n_images is None:  # the stack's rows (orders, kinds) and, where the scene mirrors, signatures
        n_images = int(render.max_order) + 1 + (2 * int(render.max_order) ** 2 if mirrored else 1)
    cells = int(sonar.n_range_bins) * int(sonar.n_beams)
    objects = len(scene.objects)
    key_paths = ray_size_key(sonar, render)
    parts = (
        (built.bytes, f"the compiled engine's scene ({built.triangles:,} triangles)", "objects"),
        (paths * (BYTES_PER_PATH + BYTES_PER_PATH_LEG * legs), f"{paths:,} held paths", key_paths),
        (cells * n_images * BYTES_PER_CELL, f"{n_images} images of {sonar.n_range_bins} x {sonar.n_beams}",
         "sonar.n_range_bins"),
        (faces * BYTES_PER_FACE + objects * BYTES_PER_OBJECT, f"{objects:,} objects' tables", "objects"),
        (float(BYTES_BASE), "JAX's compilation", ""),
    )
    seconds = (built.seconds + rays * SECONDS_PER_RAY + paths * SECONDS_PER_PATH_RECORD + SECONDS_BASE
               + objects * SECONDS_PER_OBJECT + objects ** 2 * SECONDS_PER_OBJECT_SQUARED + paths * SECONDS_PER_PATH
               + legs * SECONDS_PER_LEG)
    return DiffCost(paths, faces, objects, cells, n_images, legs, float(sum(p[0] for p in parts)), float(seconds),
                    parts)


def check_diff_cost(scene: Scene, n_paths: int | None = None, n_faces: int | None = None,
                    n_images: int | None = None, legs: int | None = None) -> DiffCost:
    """Refuse a differentiable renderer estimated beyond the memory or the time budget.

    Parameters
    ----------
    scene : Scene
    n_paths, n_faces, n_images, legs : int, optional
        See :func:`diff_cost`.

    Returns
    -------
    DiffCost
        When it fits.

    Raises
    ------
    ConfigError
        Naming the key of the largest part (``objects``, ``render.elevation_samples``,
        ``sonar.n_range_bins``, ...), the estimate, the budget and how to raise it.
    """
    cost = diff_cost(scene, n_paths, n_faces, n_images, legs)
    what = (f"the differentiable renderer of {cost.objects:,} objects, {cost.paths:,} paths and "
            f"{cost.images} images of {scene.sonar.n_range_bins} x {scene.sonar.n_beams}")
    try:
        require_together([p for p in cost.parts if p[2]] + [(p[0], p[1], "objects") for p in cost.parts if not p[2]],
                         what)
        # The time's largest part names the key: the objects, or the paths (the rays' key).
        per_object = cost.objects * SECONDS_PER_OBJECT + cost.objects ** 2 * SECONDS_PER_OBJECT_SQUARED
        key = "objects" if per_object > cost.paths * (SECONDS_PER_PATH + SECONDS_PER_PATH_RECORD) \
            else ray_size_key(scene.sonar, scene.render)
        require_time(cost.seconds, what, key)
    except ConfigError as exc:
        raise ConfigError(exc.key, exc.detail, scene.source) from None
    return cost
