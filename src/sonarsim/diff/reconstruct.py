"""The sea floor's height field from sonar images with known poses, by gradient (issue 24 item 6;
work in progress: the Python function, no command yet).

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
    """

    heights_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    seen: np.ndarray
    loss: np.ndarray
    seconds: float


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
                        blurs: Sequence[tuple[float, float]] = ((4.0, 2.0), (1.5, 1.0)), rounds: int = 4,
                        iterations: int = 20, max_step: float = 0.03, progress=None) -> HeightField:
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
    max_step : float
        How far a height may move in one round, metres (the views' searches are refreshed
        between rounds).
    """
    from .renderer import Renderer

    t0 = time.perf_counter()
    if len(images) != len(poses) or not len(images):
        raise ConfigError("images", f"{len(images)} images and {len(poses)} poses: give one pose per image")
    mesh, x, y = grid_mesh(extent, resolution, start)
    ny, nx = len(y), len(x)
    floor = ObjectSpec(name=SEABED, mesh=mesh, albedo=scene.ground.backscatter.coefficient if scene.ground else 0.8)
    base = replace(scene, ground=None, objects=tuple(scene.objects) + (floor,))
    renderers = [Renderer(replace(base, sonar_pose=pose), attach="surfaces") for pose in poses]
    xy = np.asarray(mesh.vertices)[:, :2]
    key = f"objects.{SEABED}.vertices_m"
    scales = [compress_scale(np.asarray(img, float)) for img in images]
    h = np.asarray(mesh.vertices)[:, 2].copy()

    def params_of(r, heights):
        return {**r.params(), key: jnp.concatenate([jnp.asarray(xy), heights[:, None]], axis=1)}

    def smooth(heights):
        g = heights.reshape(ny, nx)
        return jnp.sum((g[1:] - g[:-1]) ** 2) + jnp.sum((g[:, 1:] - g[:, :-1]) ** 2)

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
        best = None
        for k in range(rounds + 1):  # the last pass only checks the last round
            for r in renderers:
                r.refresh(params_of(r, jnp.asarray(h)))
            datas = [r.data for r in renderers]
            # The loss at these heights with the searches made here: a round that raised it
            # (its held searches led the heights where the refreshed ones see worse) is undone.
            here = float(value_at(jnp.asarray(h), datas))
            if best is not None and here >= best[0]:
                h = best[1]
                for r in renderers:
                    r.refresh(params_of(r, jnp.asarray(h)))
                break
            best = (here, h.copy())
            if k == rounds:
                break

            def fun(v):
                value, g = value_and_grad(jnp.asarray(v), datas)
                return float(value), np.asarray(g, float)

            # A trust region per round (the heights move at most ``max_step`` from where the
            # views' searches were made): a far step loses the floor the searches found.
            bounds = list(zip(h - max_step, h + max_step))
            res = optimize.minimize(fun, h, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": iterations})
            h = res.x
            losses.append(float(res.fun))
            if progress is not None:
                progress(sigma, float(res.fun))
    seen = np.zeros(ny * nx, bool)
    faces = np.asarray(mesh.faces)
    for r in renderers:
        k = len(scene.objects)
        hit = r.search.faces[r.search.faces[:, 0] == k, 1]
        seen[faces[hit].ravel()] = True
    return HeightField(h.reshape(ny, nx), x, y, seen.reshape(ny, nx), np.asarray(losses), time.perf_counter() - t0)
