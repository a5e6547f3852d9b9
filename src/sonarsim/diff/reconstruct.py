"""The sea floor's height field (and, optionally, its reflectivity per vertex) from sonar images
with known poses, by gradient (``sonarsim reconstruct``).

The floor is a mesh object over a rectangle (``extent``), a grid of ``resolution`` metres
whose vertices' heights are the unknowns; each image's renderer holds its own search (its
pose's). The loss is the images' blurred, log-compressed mean squared differences (as
:func:`sonarsim.diff.inverse.fit`'s) plus a smoothness term (the squared differences of
neighbouring heights, times ``smoothness``): one view cannot tell a height from a tilt along
its beams' elevation arcs, and the term fills what the images leave open. L-BFGS (SciPy's,
with JAX's reverse-mode gradient over all heights), in rounds between which every view's search
is refreshed at the current heights.

What it will cost is estimated from the grid, the views and the scene before anything is built
(:func:`plan_grid`) and refused beyond the memory and build-time budgets
(:mod:`sonarsim.core.memory`); views that cannot see the extent, and a reconstruction whose
views saw too few of the grid's vertices (:data:`MIN_SEEN_VERTICES`,
:data:`MIN_SEEN_FRACTION`), end in :class:`ReconstructionRefused` (exit status 3) rather than
in a flat floor nobody looked at.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from ..config.scene import MAX_COORDINATE_M, ObjectSpec
from ..core.memory import require, require_time
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError
from .inverse import blur, compress_scale

SEABED = "seabed"
#: The fitted reflectivity stays within exp(+-LOG_REFLECTIVITY) of the ground's (+-26 dB).
LOG_REFLECTIVITY = 3.0
#: The optimiser's unknown is the log-reflectivity over this: a metre of height moves the image
#: far more than a unit of log-reflectivity, and L-BFGS's first steps follow the gradient.
REFLECTIVITY_SCALE = 3.0
#: The log-reflectivity's smoothness weight relative to the heights'.
REFLECTIVITY_SMOOTHNESS = 1.0
#: A level ends when a round moved no height by more than this fraction of ``max_step``.
SETTLED = 0.1

#: The smoothness weights allowed: 0 (the images alone) up to a weight that holds the floor
#: level whatever the images say (the data term is a mean of squared log differences, of order
#: 0.01-1; the smoothness term a sum over the grid). A negative weight rewards roughness (-10
#: made 0.72 m of relief out of a 0.1 m bump), NaN or infinity gives no heights at all.
SMOOTHNESS_RANGE = (0.0, 1e3)

# The cost of a reconstruction, measured here (2 shared cores) on grids of 32,000 to 513,000
# vertices over one to three views (benchmarks: tests/cli/test_reconstruct_cli.py's scene):
#: Memory per grid vertex held once: the grid mesh and its copies, the optimiser's L-BFGS
#: history and bounds, the gradient and the smoothness term's temporaries.
BYTES_PER_VERTEX = 1800.0
#: Memory per grid vertex of the mesh alone (:func:`grid_mesh`: vertices, two faces, the
#: coordinate grids and the trimesh's copies).
BYTES_PER_MESH_VERTEX = 200.0
#: Memory per grid vertex per view: the view's scene (the floor's triangles built for ray
#: tracing, the renderer's copy of its faces) and its search's tables.
BYTES_PER_VERTEX_VIEW = 1000.0
#: Time per floor triangle per search of a view: building the view's scene with the floor
#: where the heights are (a refresh), and the search's walk over every face (12-16 us).
SECONDS_PER_TRIANGLE_SEARCH = 1.6e-5
def min_searches(levels: int) -> int:
    """Searches of every view in the shortest reconstruction of ``levels`` blur levels (one
    round each): the first, then per level one at its start and one after its round."""
    return 1 + 2 * int(levels)


#: A reconstruction means something only where its views saw the floor: at least this many
#: of the grid's vertices (two triangles' corners)...
MIN_SEEN_VERTICES = 4
#: ...and at least this fraction of them (elsewhere the heights are the smoothness term's
#: fill, which a 1 % of seen floor would be nearly all of).
MIN_SEEN_FRACTION = 0.01


class ReconstructionRefused(SonarsimError):
    """A reconstruction that would mean nothing: no view sees the extent, too few of the grid's
    vertices were seen, an image holds no echo, the loss is not a number (exit status 3)."""

    exit_status = 3


@dataclass(frozen=True)
class GridPlan:
    """A reconstruction's grid and its estimated cost (:func:`plan_grid`).

    Attributes
    ----------
    nx, ny : int
        Vertices along x and y.
    views : int
    triangles : int
        The floor's, ``2 (nx - 1) (ny - 1)``.
    bytes : float
        Memory the reconstruction holds at its peak (estimated).
    seconds : float
        Time its views' searches take at the least (estimated; each further round of
        L-BFGS adds one search per view).
    """

    nx: int
    ny: int
    views: int
    triangles: int
    bytes: float
    seconds: float

    @property
    def vertices(self) -> int:
        return self.nx * self.ny


def check_smoothness(smoothness: float, key: str = "smoothness") -> float:
    """``smoothness`` as a float within :data:`SMOOTHNESS_RANGE`; else a ConfigError naming ``key``."""
    lo, hi = SMOOTHNESS_RANGE
    try:
        value = float(smoothness)
    except (TypeError, ValueError):
        value = math.nan
    if not lo <= value <= hi:  # (NaN fails both)
        raise ConfigError(key, f"must be a number from {lo:g} (the images alone) to {hi:g} (a level floor), "
                          f"got {smoothness!r}")
    return value


def _vertices(f: float) -> int:
    """Vertices along a side of ``f - 1`` cells (a float; 1e300 stays an int Python holds)."""
    return int(round(f - 1.0)) + 1 if math.isfinite(f) else 2**62


def _grid_counts(extent: Sequence[float], resolution: float, keys: tuple[str, str]):
    """The extent and the resolution checked, and the vertices along x and y as floats (a
    resolution of 1e-300 m is 1e300 vertices, no integer to allocate): ``x0, x1, y0, y1, res,
    fx, fy``; see :func:`plan_grid` for the refusals."""
    extent_key, resolution_key = keys
    try:
        x0, x1, y0, y1 = (float(v) for v in extent)
    except (TypeError, ValueError):
        raise ConfigError(extent_key, f"must be four numbers x0, x1, y0, y1, got {extent!r}") from None
    if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_M for v in (x0, x1, y0, y1)):
        raise ConfigError(extent_key, f"must lie within {MAX_COORDINATE_M:g} m of the origin, got "
                          f"{x0:g},{x1:g},{y0:g},{y1:g}")
    if not (x1 > x0 and y1 > y0):
        raise ConfigError(extent_key, f"must be x0 < x1 and y0 < y1 (metres), got {x0:g},{x1:g},{y0:g},{y1:g}")
    try:
        res = float(resolution)
    except (TypeError, ValueError):
        res = math.nan
    if not (math.isfinite(res) and res > 0):
        raise ConfigError(resolution_key, f"must be a positive number of metres, got {resolution!r}")
    fx, fy = (x1 - x0) / res + 1.0, (y1 - y0) / res + 1.0
    # (the vertices are round(side / resolution) + 1: below half a cell, a side has one)
    if min(_vertices(fx), _vertices(fy)) < 2:
        raise ConfigError(resolution_key, f"{res:g} m leaves fewer than two vertices along a side of the "
                          f"{x1 - x0:g} m x {y1 - y0:g} m extent; allowed: less than {2 * min(x1 - x0, y1 - y0):g} m")
    return x0, x1, y0, y1, res, fx, fy


def plan_grid(extent: Sequence[float], resolution: float, views: int, scene=None, levels: int = 2,
              keys: tuple[str, str] = ("extent", "resolution")) -> GridPlan:
    """The grid over ``extent`` at ``resolution`` and what reconstructing it from ``views``
    views costs, refused beyond the memory and build-time budgets before anything is built.

    Parameters
    ----------
    extent : (x0, x1, y0, y1) floats, metres
        Within :data:`~sonarsim.config.scene.MAX_COORDINATE_M` of the origin, x0 < x1, y0 < y1.
    resolution : float
        Grid spacing, metres; at least two vertices along each side.
    views : int
        Images (each has its renderer and its searches).
    scene : Scene, optional
        Every view holds its sonar's rays and images (:func:`sonarsim.core.rays.ray_bytes`), and
        its objects built with the floor (:func:`sonarsim.scene.cost.scene_cost`).
    levels : int
        Blur levels (each refreshes every view's search at least twice).
    keys : (str, str)
        The names of the extent and the resolution in the messages (the CLI's options).

    Returns
    -------
    GridPlan

    Raises
    ------
    ConfigError
        Naming ``keys[0]`` for an extent that is not a rectangle within reach, ``keys[1]`` for
        a resolution that is not a positive number, gives fewer than two vertices along a
        side, or a grid whose estimated memory or time is beyond the budget (the estimate, the
        budget and how to raise it).
    """
    extent_key, resolution_key = keys
    x0, x1, y0, y1, res, fx, fy = _grid_counts(extent, resolution, keys)
    vertices = fx * fy
    triangles = 2.0 * (fx - 1.0) * (fy - 1.0)
    views = max(int(views), 1)
    obj_bytes = obj_seconds = 0.0
    if scene is not None:
        from ..config.sonar import image_bytes
        from ..core.rays import ray_bytes

        # Each view's simulator: its ray fan and its frame's images; and the scene's objects.
        sonar = scene.sonar
        obj_bytes = float(ray_bytes(sonar, scene.render) + image_bytes(sonar.n_range_bins, sonar.n_beams))
    if scene is not None and scene.objects:
        from ..scene.cost import scene_cost

        cost = scene_cost(replace(scene, ground=None))
        obj_bytes, obj_seconds = obj_bytes + cost.bytes, cost.seconds
    nbytes = vertices * (BYTES_PER_VERTEX + views * BYTES_PER_VERTEX_VIEW) + views * obj_bytes
    searches = min_searches(levels)
    seconds = views * searches * (triangles * SECONDS_PER_TRIANGLE_SEARCH + obj_seconds)
    shape = f"a grid of {fx:.3g} x {fy:.3g} vertices" if vertices > 1e9 else \
        f"a grid of {round(fx):,} x {round(fy):,} vertices"
    what = f"{shape} ({res:g} m over {x1 - x0:g} m x {y1 - y0:g} m) seen by {views} view(s)"
    require(nbytes, what, resolution_key)
    require_time(seconds, f"searching {what} at least {searches} times each", resolution_key)
    return GridPlan(_vertices(fx), _vertices(fy), views, int(min(triangles, 2**62)), nbytes, seconds)


def out_of_reach(scene, poses: Sequence[Pose], extent: Sequence[float]) -> list[tuple[int, float]]:
    """The views whose sonar is farther from the extent (at height 0, the start) than its
    maximum range: ``(index, distance in metres)`` for each; they cannot see the floor."""
    x0, x1, y0, y1 = map(float, extent)
    far = []
    for k, pose in enumerate(poses):
        px, py, pz = pose.position_m
        dx = max(x0 - px, 0.0, px - x1)
        dy = max(y0 - py, 0.0, py - y1)
        distance = math.sqrt(dx * dx + dy * dy + pz * pz)
        if distance > scene.sonar.range_max_m:
            far.append((k, distance))
    return far


def seen_enough(seen: np.ndarray, when: str) -> None:
    """Refuse (exit status 3) a grid of which the views saw fewer than :data:`MIN_SEEN_VERTICES`
    or :data:`MIN_SEEN_FRACTION` of the vertices."""
    need = max(MIN_SEEN_VERTICES, math.ceil(MIN_SEEN_FRACTION * seen.size))
    if int(seen.sum()) < need:
        raise ReconstructionRefused(
            f"{when}, the views saw {int(seen.sum())} of the grid's {seen.size} vertices, fewer than the "
            f"{need} needed (at least {MIN_SEEN_VERTICES}, and {MIN_SEEN_FRACTION:.0%} of the grid): the poses do not "
            "look at the extent, or the sonar's range does not reach it (check the poses and the extent)")


@dataclass(frozen=True)
class HeightField:
    """The result of :func:`reconstruct_heights`.

    Attributes
    ----------
    heights_m : (ny, nx) ndarray
        Heights of the grid's vertices, metres.
    x_m, y_m : (nx,), (ny,) ndarrays
    seen : (ny, nx) bool ndarray
        Vertices of a triangle some view's paths met.
    loss : (k,) ndarray
        The loss after each round.
    seconds : float
    reflectivity : (ny, nx) ndarray or None
        The floor's reflectivity at the vertices, relative to the scene's ground (1: as its
        albedo), where it was fitted too.
    """

    heights_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    seen: np.ndarray
    loss: np.ndarray
    seconds: float
    reflectivity: np.ndarray | None = None


def _rounds(renderers, params_of, value_and_grad, value_at, h: np.ndarray, n: int, rounds: int, iterations: int,
            max_step: float, sigma, progress) -> tuple[np.ndarray, list[float]]:
    """One level's rounds: each refreshes every view's search at the current unknowns, checks
    the loss there, and runs L-BFGS within a trust region of ``step`` metres on the heights
    (a far step loses the floor the searches found). A round that raised the loss with the
    refreshed searches is undone and the region halved; the level ends when a round moves no
    height by more than :data:`SETTLED` of ``max_step``, the region has shrunk below that, or
    after ``rounds`` rounds."""
    def refreshed(x):
        for r in renderers:
            r.refresh(params_of(r, jnp.asarray(x)))
        return float(value_at(jnp.asarray(x), [r.data for r in renderers]))

    best_value, best = refreshed(h), h.copy()
    step, losses = max_step, []
    log_bound = LOG_REFLECTIVITY / REFLECTIVITY_SCALE
    for _ in range(rounds):
        datas = [r.data for r in renderers]

        def fun(v):
            value, g = value_and_grad(jnp.asarray(v), datas)
            return float(value), np.asarray(g, float)

        # (as arrays: a list of a million pairs took SciPy seconds to convert, each round)
        lower = np.concatenate([best[:n] - step, np.full(len(best) - n, -log_bound)])
        bounds = optimize.Bounds(lower, np.concatenate([best[:n] + step, np.full(len(best) - n, log_bound)]))
        res = optimize.minimize(fun, best, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": iterations})
        moved = float(np.max(np.abs(res.x[:n] - best[:n]))) if n else 0.0
        losses.append(float(res.fun))
        if progress is not None:
            progress(sigma, float(res.fun))
        value = refreshed(res.x)
        if value < best_value:
            best_value, best = value, res.x.copy()
            if moved < SETTLED * max_step:
                break
        else:  # undone: the searches back at the best heights, a smaller region
            refreshed(best)
            step *= 0.5
            if step < SETTLED * max_step:
                break
    return best, losses


def _seen(renderers, faces: np.ndarray, k: int, n: int) -> np.ndarray:
    """(n,) bool: the floor's (object ``k``'s) vertices of a triangle some view's held search met."""
    seen = np.zeros(n, bool)
    for r in renderers:
        hit = r.search.faces[r.search.faces[:, 0] == k, 1]
        seen[faces[hit].ravel()] = True
    return seen


def grid_axes(extent: Sequence[float], resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The grid's vertices along x and along y, metres: ``(nx,), (ny,)`` arrays.

    Raises
    ------
    ConfigError
        As :func:`plan_grid`'s for the extent and the resolution; a grid whose mesh alone
        (:data:`BYTES_PER_MESH_VERTEX`) is beyond the memory budget.
    """
    x0, x1, y0, y1, res, fx, fy = _grid_counts(extent, resolution, ("extent", "resolution"))
    require(fx * fy * BYTES_PER_MESH_VERTEX, f"a grid of {fx:.3g} x {fy:.3g} vertices ({res:g} m)", "resolution")
    return np.linspace(x0, x1, _vertices(fx)), np.linspace(y0, y1, _vertices(fy))


def grid_mesh(extent: Sequence[float], resolution: float, heights: np.ndarray | None = None):
    """A trimesh height field over ``extent`` = (x0, x1, y0, y1) at ``resolution`` metres."""
    import trimesh

    x, y = grid_axes(extent, resolution)
    nx, ny = len(x), len(y)
    gx, gy = np.meshgrid(x, y)
    z = np.zeros_like(gx) if heights is None else np.asarray(heights, float).reshape(ny, nx)
    vertices = np.stack([gx.ravel(), gy.ravel(), z.ravel()], axis=1)
    i = np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + nx, i.ravel() + nx + 1
    faces = np.concatenate([np.stack([a, b, d], axis=1), np.stack([a, d, c], axis=1)])
    return trimesh.Trimesh(vertices, faces, process=False), x, y


def reconstruct_heights(scene, images: Sequence[np.ndarray], poses: Sequence[Pose], extent: Sequence[float],
                        resolution: float, start: np.ndarray | None = None, smoothness: float = 1e-3,
                        blurs: Sequence[tuple[float, float]] = ((4.0, 2.0), (1.5, 1.0)), rounds: int = 12,
                        iterations: int = 20, max_step: float = 0.03, progress=None,
                        reflectivity: bool = False) -> HeightField:
    """Heights of the sea floor over ``extent`` from ``images`` seen from ``poses``.

    Parameters
    ----------
    scene : Scene
        The sonar and everything else in the water; its ground (if any) is replaced by the
        height field.
    images : sequence of (n_range_bins, n_beams) arrays
        On the scene's sonar's grid, in the renderer's units.
    poses : sequence of Pose
        Each image's sonar pose.
    extent : (x0, x1, y0, y1)
    resolution : float
        Grid spacing, metres.
    start : (ny, nx) array, optional
        Start heights (default flat at 0).
    smoothness : float
        Weight of the squared differences of neighbouring heights, within
        :data:`SMOOTHNESS_RANGE`.
    rounds : int
        At most this many rounds per level (see :func:`_rounds`: a round that raised the loss
        with the refreshed searches is undone and the trust region halved; a level ends once
        a round moves no height by more than :data:`SETTLED` of ``max_step``).
    max_step : float
        How far a height may move in one round, metres (the views' searches are refreshed
        between rounds).
    reflectivity : bool
        Also fit the floor's reflectivity per vertex (relative to the ground's albedo; as its
        logarithm, with the same smoothness term): a patch of brighter floor is otherwise
        explained as relief.

    Raises
    ------
    ConfigError
        A smoothness outside :data:`SMOOTHNESS_RANGE`, an image that is not finite, an extent
        or resolution that :func:`plan_grid` refuses (the budgets included).
    ReconstructionRefused
        An image without echo, views that cannot see the extent or saw too few of its vertices
        (:func:`seen_enough`), a loss that is not a number.
    """
    from .renderer import Renderer

    t0 = time.perf_counter()
    if len(images) != len(poses) or not len(images):
        raise ConfigError("images", f"{len(images)} images and {len(poses)} poses: give one pose per image")
    smoothness = check_smoothness(smoothness)
    for k, img in enumerate(images):
        a = np.asarray(img, float)
        if a.ndim != 2 or not np.all(np.isfinite(a)):
            raise ConfigError(f"images[{k}]", "must be a finite 2D image (n_range_bins, n_beams)")
        if not np.any(a > 0):
            raise ReconstructionRefused(f"images[{k}]: holds no echo (no pixel above 0): nothing to reconstruct from")
    plan_grid(extent, resolution, len(images), scene, levels=len(blurs))
    far = out_of_reach(scene, poses, extent)
    if len(far) == len(poses):
        k, distance = min(far, key=lambda f: f[1])
        raise ReconstructionRefused(
            f"no view can see the extent: the nearest, view {k}, is {distance:.1f} m from it, beyond the sonar's "
            f"range of {scene.sonar.range_max_m:g} m (check the poses and the extent)")
    mesh, x, y = grid_mesh(extent, resolution, start)
    ny, nx = len(y), len(x)
    floor = ObjectSpec(name=SEABED, mesh=mesh, albedo=scene.ground.backscatter.coefficient if scene.ground else 0.8)
    base = replace(scene, ground=None, objects=tuple(scene.objects) + (floor,))
    reflective = (SEABED,) if reflectivity else ()
    renderers = [Renderer(replace(base, sonar_pose=pose), attach="surfaces", reflectivity=reflective)
                 for pose in poses]
    xy = np.asarray(mesh.vertices)[:, :2]
    key = f"objects.{SEABED}.vertices_m"
    scales = [compress_scale(np.asarray(img, float)) for img in images]
    n = len(xy)
    # The unknowns: the heights, then (with ``reflectivity``) the logarithms of the reflectivity.
    h = np.concatenate([np.asarray(mesh.vertices)[:, 2], np.zeros(n if reflectivity else 0)])

    def params_of(r, unknowns):
        p = {**r.params(), key: jnp.concatenate([jnp.asarray(xy), unknowns[:n, None]], axis=1)}
        if reflectivity:
            p[f"objects.{SEABED}.reflectivity"] = jnp.exp(REFLECTIVITY_SCALE * unknowns[n:])
        return p

    def smooth(unknowns):
        out = 0.0
        parts = ((unknowns[:n], 1.0), (REFLECTIVITY_SCALE * unknowns[n:], REFLECTIVITY_SMOOTHNESS)) if reflectivity \
            else ((unknowns, 1.0),)
        for part, weight in parts:
            g = part.reshape(ny, nx)
            out = out + weight * (jnp.sum((g[1:] - g[:-1]) ** 2) + jnp.sum((g[:, 1:] - g[:, :-1]) ** 2))
        return out

    faces = np.asarray(mesh.faces)
    # The views' first searches, at the start: a grid they do not meet is refused before the
    # optimiser spends its rounds on it.
    seen_enough(_seen(renderers, faces, len(scene.objects), ny * nx), "at the start")
    fns = [r.image_function() for r in renderers]
    losses = []
    for sigma in blurs:
        targets = [jnp.log1p(jnp.maximum(blur(jnp.asarray(img, float), sigma), 0.0) / s) for img, s in zip(images, scales)]

        def total(heights, datas, sigma=sigma, targets=targets):
            out = smoothness * smooth(heights)
            for fn, r, data, t, s in zip(fns, renderers, datas, targets, scales):
                sim = jnp.log1p(jnp.maximum(blur(fn(params_of(r, heights), data), sigma), 0.0) / s)
                out = out + jnp.mean((sim - t) ** 2)
            return out

        value_and_grad = jax.jit(jax.value_and_grad(total))
        value_at = jax.jit(total)
        # (``h`` comes back from the level with every view's search made at it)
        h, level_losses = _rounds(renderers, params_of, value_and_grad, value_at, h, n, rounds, iterations,
                                  max_step, sigma, progress)
        losses.extend(level_losses)
    seen = _seen(renderers, faces, len(scene.objects), ny * nx)
    seen_enough(seen, "at the reconstructed heights")
    if not (np.all(np.isfinite(losses)) and np.all(np.isfinite(h))):
        raise ReconstructionRefused("the loss or the heights became NaN or infinite: no reconstruction")
    return HeightField(h[:n].reshape(ny, nx), x, y, seen.reshape(ny, nx), np.asarray(losses), time.perf_counter() - t0,
                       reflectivity=np.exp(REFLECTIVITY_SCALE * h[n:]).reshape(ny, nx) if reflectivity else None)
