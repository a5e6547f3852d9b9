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
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from ..config.scene import ObjectSpec
from ..core.transforms import Pose
from ..errors import ConfigError
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

        bounds = list(zip(best[:n] - step, best[:n] + step)) + [(-log_bound, log_bound)] * (len(best) - n)
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


def grid_mesh(extent: Sequence[float], resolution: float, heights: np.ndarray | None = None):
    """A trimesh height field over ``extent`` = (x0, x1, y0, y1) at ``resolution`` metres."""
    import trimesh

    x0, x1, y0, y1 = map(float, extent)
    if not (x1 > x0 and y1 > y0 and resolution > 0):
        raise ConfigError("extent", f"must be x0 < x1, y0 < y1 and a positive resolution, got {extent}, {resolution}")
    nx, ny = int(round((x1 - x0) / resolution)) + 1, int(round((y1 - y0) / resolution)) + 1
    x, y = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
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
        Weight of the squared differences of neighbouring heights.
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
    """
    from .renderer import Renderer

    t0 = time.perf_counter()
    if len(images) != len(poses) or not len(images):
        raise ConfigError("images", f"{len(images)} images and {len(poses)} poses: give one pose per image")
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
    seen = np.zeros(ny * nx, bool)
    faces = np.asarray(mesh.faces)
    for r in renderers:
        k = len(scene.objects)
        hit = r.search.faces[r.search.faces[:, 0] == k, 1]
        seen[faces[hit].ravel()] = True
    return HeightField(h[:n].reshape(ny, nx), x, y, seen.reshape(ny, nx), np.asarray(losses), time.perf_counter() - t0,
                       reflectivity=np.exp(REFLECTIVITY_SCALE * h[n:]).reshape(ny, nx) if reflectivity else None)
