"""Gradient checks: the differentiable engine's gradients against central finite differences.

:func:`check_gradients` compares ``jax.grad`` of a smooth linear functional of the image,
``L = sum(W * image)``, with central differences ``(L(p + h e) - L(p - h e)) / 2h`` along each
parameter's axes (or a random direction for vertex arrays), taken either

* of the **compiled engine** (``reference="compiled"``): the scene rebuilt at ``p +- h e``
  (:func:`~sonarsim.diff.params.scene_with`) and rendered from scratch, the search included.
  Where the step moves the search (a ray crossing a silhouette or a facet's edge), the
  difference holds a jump the held search has no derivative for; each row says whether the
  search stayed the same (``search_held``), and only those rows are evidence; or
* of the **differentiable forward** itself (``reference="held"``): the same held search at
  ``p +- h e``, which checks the derivatives of everything continuous, the splat and the
  sensor included.

``W`` defaults to a smooth field over the image (:func:`smooth_weights`): a functional that
weighs neighbouring bins alike, so that a path's energy moving across a bin edge counts for its
distance moved, not for the edge it crossed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..renderer.simulator import Simulator
from .params import bound_of, scene_with
from .search import record_search

#: Default central-difference steps by the parameter's last name part.
STEPS = {
    # Geometry: steps well above the float32 round-off of the caster's hits (1e-7 of a range),
    # which a central difference divides by 2h.
    "position_m": 1e-4, "offset_m": 1e-4, "vertices_m": 1e-4, "rpy_deg": 1e-2, "scale": 1e-3, "normal": 1e-4,
    "albedo": 1e-4, "mu": 1e-4, "specular": 1e-4, "specular_strength": 1e-3, "roughness": 1e-5,
    "gain_db": 1e-3, "source_level_db": 1e-3, "tvg_spreading": 1e-3, "noise_db": 1e-3, "noise_after_tvg_db": 1e-3,
    "elevation_width_deg": 1e-3, "azimuth_width_deg": 3e-3, "gamma": 1e-4, "beam_gain_db": 1e-2,
}


# The held forward is float64 throughout; its differences take steps this much smaller, so
# that few paths' range cells cross a bin edge (where the splat has a kink, and an isolated
# path's bin a jump) within the step.
HELD_STEP_FACTOR = 1e-2

def bounds_of(key: str) -> tuple[float, float]:
    """``(lo, hi)`` of a parameter: the scene format's bounds (:func:`~sonarsim.diff.params.parameter_bounds`,
    the ones :meth:`~sonarsim.diff.Renderer.render` checks). A difference at a bound is taken
    beside it (an error of the order of the step in the derivative of a polynomial law)."""
    bound = bound_of(key)
    return (-np.inf, np.inf) if bound is None else (bound.lo, bound.hi)


@dataclass(frozen=True)
class GradientCheck:
    """One parameter direction checked.

    Attributes
    ----------
    key : str
    index : tuple of int
        The component checked (empty for a scalar, or for a random direction of an array).
    gradient : float
        ``jax.grad`` along the direction.
    finite_difference : float
        The central difference along it.
    step : float
    search_held : bool
        The search at ``p + h e`` and ``p - h e`` is the search at ``p`` (always true of the
        ``held`` reference).
    reference : {'compiled', 'held'}
        What was differenced: ``held`` also where the compiled engine was asked for but cannot
        take the value (a key whose values the scene format restricts, as the TVG law's
        ``spreading`` is to 0, 20, 30 or 40).
    """

    key: str
    index: tuple
    gradient: float
    finite_difference: float
    step: float
    search_held: bool
    reference: str = "compiled"

    @property
    def relative_error(self) -> float:
        """``|gradient - fd| / |fd|`` (0 where both are 0)."""
        if self.finite_difference == 0.0:
            return 0.0 if self.gradient == 0.0 else float("inf")
        return abs(self.gradient - self.finite_difference) / abs(self.finite_difference)


def smooth_weights(shape: tuple[int, int]) -> np.ndarray:
    """A smooth positive field over an image (n_range_bins, n_beams), the same for a shape."""
    nr, nb = shape
    r, b = np.meshgrid(np.linspace(0.0, 1.0, nr), np.linspace(0.0, 1.0, nb), indexing="ij")
    return 1.0 + 0.5 * np.sin(2 * np.pi * (1.3 * r + 0.2)) * np.cos(2 * np.pi * (0.7 * b + 0.1)) + 0.3 * r


def _search_rows(search) -> dict:
    """What the search decided, path by path: ``(ray, generation, transmit option) -> (the
    scatterer's plane or triangle, receive chain, neighbours)``, with the range it recorded."""
    n = search.n_paths
    faces = np.concatenate([np.stack([np.full(search.n_planes, -1), np.arange(search.n_planes)], axis=1),
                            search.faces]).astype(np.int64)
    where = faces[search.surface[:n]]

    def mirrors(chains: np.ndarray) -> np.ndarray:
        # A chain's mesh mirror is a row of this search's triangle table: named by its triangle.
        tri = faces[np.clip(chains, 0, len(faces) - 1)]
        return np.where((chains >= search.n_planes)[..., None], tri, np.stack([np.full_like(chains, -1), chains], -1)
                        ).reshape(len(chains), -1)

    keys = np.concatenate([search.ray[:n, None], search.gen[:n, None], search.same[:n, None], search.beam[:n, None],
                           mirrors(search.tx_planes[:n])], axis=1)
    values = np.concatenate([where, mirrors(search.rx_planes[:n]), search.has_down[:n, None], search.has_up[:n, None]],
                            axis=1)
    return {tuple(k): (tuple(v), d) for k, v, d in zip(keys.tolist(), values.tolist(), search.distance[:n].tolist())}


def same_search(a: dict, b: dict, range_max_m: float) -> bool:
    """Whether two searches (:func:`_search_rows`) agree on every path that reaches the image
    (a path beyond the window, where the tracing's reach cuts legs off, cannot change it; nor
    can one beyond the window's end without neighbours, whose bin is beyond it: a transmit leg
    that crosses the window's end as a mirror turns makes such a path come and go)."""
    far = 1.05 * range_max_m
    for x, y in ((a, b), (b, a)):
        for key, (value, distance) in x.items():
            isolated = not value[-2] and not value[-1]  # (has_down, has_up)
            if distance > far or (distance >= range_max_m and isolated):
                continue
            if key not in y or y[key][0] != value:
                return False
    return True


def check_gradients(renderer, keys: Iterable[str] | None = None, *, reference: str = "compiled",
                    weights: np.ndarray | None = None, steps: dict | None = None, seed: int = 0,
                    per_component: bool = True) -> list[GradientCheck]:
    """Check ``renderer``'s gradients at its scene's parameters (see the module docstring).

    Parameters
    ----------
    renderer : Renderer
    keys : iterable of str, optional
        Parameters to check (default: all).
    reference : {'compiled', 'held'}
    weights : (n_range_bins, n_beams) array, optional
        ``W``; default :func:`smooth_weights`.
    steps : dict, optional
        Steps by key or by the key's last part, over :data:`STEPS`.
    seed : int
        Seeds the random direction of vertex arrays.
    per_component : bool
        Check each component of a vector parameter (else one random direction).

    Returns
    -------
    list of GradientCheck
    """
    if reference not in ("compiled", "held"):
        raise ValueError(f"unknown reference {reference!r}; allowed: compiled, held")
    p0 = renderer.params()
    keys = list(renderer.names if keys is None else keys)
    image = np.asarray(renderer.render(p0))
    w = smooth_weights(image.shape) if weights is None else np.asarray(weights, float)
    wj = jnp.asarray(w)
    grad = jax.grad(lambda p: jnp.sum(wj * renderer.render(p)))(p0)
    steps = {**STEPS, **(steps or {})}
    rng = np.random.default_rng(seed)
    range_max = renderer.scene.sonar.range_max_m
    held = _search_rows(renderer.search)

    def loss(values: dict, reference: str = reference) -> tuple[float, bool]:
        if reference == "held":
            return float(jnp.sum(wj * renderer.render({**p0, **{k: jnp.asarray(v) for k, v in values.items()}}))), True
        try:
            scene = scene_with(renderer.scene, values)
        except ConfigError:
            return loss(values, "held")
        with Simulator(scene) as sim:
            out = float(np.sum(w * sim.render(speckle=False).polar.astype(np.float64)))
            same = same_search(_search_rows(record_search(sim, scene.sonar_pose)), held, range_max)
        return out, same

    out = []
    for key in keys:
        v0 = np.asarray(p0[key], float)
        g = np.asarray(grad[key], float)
        h = steps.get(key, steps.get(key.rsplit(".", 1)[-1], 1e-5))
        if reference == "held":  # float64 throughout: a step small enough to cross no bin edge
            h = h * HELD_STEP_FACTOR
        if v0.ndim == 0:
            directions = [((), np.ones(()))]
        elif per_component and v0.size <= 3:
            directions = [(tuple(int(i) for i in np.unravel_index(j, v0.shape)), np.eye(v0.size)[j].reshape(v0.shape))
                          for j in range(v0.size)]
        else:
            e = rng.standard_normal(v0.shape)
            directions = [((), e / np.linalg.norm(e))]
        for index, e in directions:
            kind = reference
            if reference == "compiled":
                try:
                    scene_with(renderer.scene, {key: v0 + h * e})
                except ConfigError:
                    kind, h = "held", h * HELD_STEP_FACTOR
            centre = v0
            lo, hi = bounds_of(key)
            if np.any(v0 + h * e > hi) or np.any(v0 - h * e < lo):  # at a bound: the difference beside it
                centre = v0 - h * e if np.any(v0 + h * e > hi) else v0 + h * e
            up, same_up = loss({key: centre + h * e}, kind)
            down, same_down = loss({key: centre - h * e}, kind)
            out.append(GradientCheck(key, index, float(np.sum(g * e)), (up - down) / (2.0 * h), h, same_up and same_down,
                                     kind))
    return out


def report(rows: Sequence[GradientCheck]) -> str:
    """The checks as a table, one row each."""
    lines = [f"{'parameter':44s} {'index':8s} {'gradient':>13s} {'finite diff.':>13s} {'rel. error':>10s}  search"]
    for r in rows:
        lines.append(f"{r.key:44s} {str(r.index):8s} {r.gradient:13.6g} {r.finite_difference:13.6g} "
                     f"{r.relative_error:10.2e}  {'held' if r.search_held else 'moved'}"
                     f"{'' if r.reference == 'compiled' else ' (held forward)'}")
    return "\n".join(lines)


def scaled_errors(rows: Sequence[GradientCheck]) -> list[float]:
    """Each row's error relative to its parameter's gradient: ``|gradient - fd| / max(|fd|,
    |fd over the key's components|)`` (a vector parameter's components are judged against the
    vector's size: a component whose derivative is nearly zero, such as a rotation about a
    flat board's normal, is not judged by its own round-off), 0 where the key's differences
    are all 0 and its gradient too."""
    norms: dict[str, float] = {}
    for r in rows:
        norms[r.key] = norms.get(r.key, 0.0) + r.finite_difference ** 2
    out = []
    for r in rows:
        scale = max(abs(r.finite_difference), norms[r.key] ** 0.5)
        err = abs(r.gradient - r.finite_difference)
        out.append(0.0 if err == 0.0 else (err / scale if scale > 0 else float("inf")))
    return out


def failures(rows: Sequence[GradientCheck], tolerance: float = 0.02) -> list[tuple[GradientCheck, float]]:
    """The rows whose :func:`scaled_errors` exceed ``tolerance``, or whose search moved."""
    return [(r, e) for r, e in zip(rows, scaled_errors(rows)) if e > tolerance or not r.search_held]
