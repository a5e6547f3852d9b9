"""The differentiable renderer: :class:`Renderer`, ``params()`` and ``render(params)``.

The compiled engine does the discrete search once (:func:`~sonarsim.diff.search.record_search`);
the continuous rest of the frame is a JAX function of the parameters
(:mod:`sonarsim.diff.forward`, then :mod:`sonarsim.diff.sensor` where the scene has a sensor),
compiled by ``jax.jit`` on first use, differentiable by ``jax.grad`` and batched by ``jax.vmap``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..config.loader import load_scene
from ..errors import ConfigError
from ..renderer.components import component_table, total_rows
from ..renderer.simulator import Simulator
from ..scene.meshes import object_mesh_local
from . import forward
from .params import scene_params, scene_with, surface_laws
from .search import Search, padded_size, record_search


#: The parameters that move the search (the rest are re-formed on the held search exactly).
GEOMETRY = (".position_m", ".rpy_deg", ".scale", ".vertices_m", ".offset_m", ".normal")


@dataclass(frozen=True)
class Static:
    """What the forward function is compiled for (hashable: ``jax.jit``'s static argument)."""

    planes: tuple[str, ...]
    objects: tuple[str, ...]
    surfaces: tuple[tuple[str, str], ...]
    rough: bool
    tvg: bool
    spread: bool
    geometry: tuple[float, float, int, int]
    n_rows: int
    total_rows: tuple[int, ...]
    n_signatures: int
    sensor: Any = None  # sonarsim.diff.sensor.SensorStatic or None
    attach: str = "rays"
    reflective: tuple[str, ...] = ()  # objects with a reflectivity per vertex


class Renderer:
    """A scene made differentiable: the expected image as a JAX function of its parameters.

    Parameters
    ----------
    scene : Scene, mapping or path
        Anything :func:`sonarsim.load_scene` accepts.
    dtype : {'float64', 'float32'}
        The arithmetic. ``float64`` (the default, and what the finite-difference checks need)
        turns on JAX's 64-bit mode (``jax_enable_x64``) for the process; ``float32`` leaves
        JAX's settings alone (GPUs are faster in it).

    attach : {'rays', 'surfaces'}
        Where an object's scatterer is held (:mod:`sonarsim.diff.forward`): on its fan ray
        (the default: exact at the aperture's edges and the floor's onset; an object moving
        across the beams moves no ray), or on its triangle (its echo moves across the beams as
        the object or the sonar moves: what pose fitting needs; the fan's and the aperture's
        edges, where no held path stands for what enters, are then approximate). Planes'
        scatterers stay on their rays in both.
    reflectivity : sequence of str
        Objects that get a reflectivity per vertex, ``objects.<name>.reflectivity``
        (n_vertices,), dimensionless, 1 by default: it multiplies the object's law (its albedo
        or mu, and a rough law's lobe) at each scatterer, interpolated over its triangle
        (barycentric). A sea floor's reflectivity per cell, for one; the scene format has no
        such field, so it exists here only.

    Examples
    --------
    >>> r = Renderer("tank.yaml")                                   # doctest: +SKIP
    >>> p = r.params()
    >>> image = r.render(p)                                          # (n_range_bins, n_beams)
    >>> g = jax.grad(lambda q: jnp.sum(r.render(q)))(p)              # a dict like p
    """

    def __init__(self, scene: Any, dtype: str = "float64", attach: str = "rays",
                 reflectivity: tuple[str, ...] = ()) -> None:
        if dtype not in ("float64", "float32"):
            raise ConfigError("dtype", f"unknown dtype {dtype!r}; allowed: float64, float32")
        if attach not in ("rays", "surfaces"):
            raise ConfigError("attach", f"unknown attach {attach!r}; allowed: rays, surfaces")
        if dtype == "float64":
            jax.config.update("jax_enable_x64", True)
        self.dtype = jnp.float64 if dtype == "float64" else jnp.float32
        self.scene = load_scene(scene)
        self.sim = Simulator(self.scene)
        scene = self.scene
        render = scene.render
        sonar = scene.sonar
        self._fan = self.sim.ray_fan(sonar)
        self._defaults = scene_params(scene)
        from . import sensor as sensor_mod

        self._sensor = sensor_mod.SensorPart(self.sim, self._fan) if scene.sensor is not None else None
        if self._sensor is not None:
            self._defaults.update(self._sensor.params())
        laws = surface_laws(scene)
        by_name = {o.name: o for o in scene.objects}
        unknown = [n for n in reflectivity if n not in by_name]
        if unknown:
            raise ConfigError("reflectivity", f"no object {unknown[0]!r} in the scene; its objects: "
                              f"{', '.join(by_name) or 'none'}")
        for name in reflectivity:
            self._defaults[f"objects.{name}.reflectivity"] = np.ones(len(object_mesh_local(by_name[name]).vertices))
        self.static = Static(
            planes=tuple(self.sim.planes.names), objects=tuple(o.name for o in scene.objects), surfaces=laws,
            rough=any(law == "rough" for _, law in laws), tvg=bool(render.tvg), spread=bool(render.range_splat),
            geometry=(float(sonar.range_min_m), float(sonar.range_resolution_m), int(sonar.n_range_bins),
                      int(sonar.n_beams)),
            n_rows=0, total_rows=total_rows(render.bounces, render.max_order), n_signatures=0,
            sensor=None if self._sensor is None else self._sensor.static, attach=attach,
            reflective=tuple(reflectivity),
        )
        self._local_faces = [np.asarray(object_mesh_local(o).faces, np.int64) for o in scene.objects]
        self._jitted: dict = {}
        self.search: Search | None = None
        self._capacity = 1024
        self.searches = 0  # searches run (refresh): what a fit reports as its renders
        self._face_capacity = [64] * len(scene.objects)
        self.refresh()

    # Parameters ------------------------------------------------------------------------------

    def params(self) -> dict[str, jax.Array]:
        """The scene's parameters (see :mod:`sonarsim.diff.params`), as JAX arrays."""
        return {k: jnp.asarray(v, self.dtype) for k, v in self._defaults.items()}

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter's key."""
        return tuple(self._defaults)

    def _complete(self, params: Mapping[str, Any] | None) -> dict[str, Any]:
        """``params`` over the defaults; an unknown key is refused by name."""
        out: dict[str, Any] = dict(self._defaults)
        if params is None:
            return {k: jnp.asarray(v, self.dtype) for k, v in out.items()}
        unknown = [k for k in params if k not in out]
        if unknown:
            raise ConfigError(unknown[0], f"no such parameter in this scene; its parameters: {', '.join(out)}")
        for k, v in params.items():
            shape = np.shape(self._defaults[k])
            if not isinstance(v, (jax.Array, jax.core.Tracer, np.ndarray)):
                v = np.asarray(v, float)  # a list or a number
            if jnp.shape(v) != shape:
                raise ConfigError(k, f"has shape {jnp.shape(v)}; expected {shape}")
            if not isinstance(v, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(v))):
                raise ConfigError(k, "must be finite")
            out[k] = v
        return {k: v if isinstance(v, jax.core.Tracer) else jnp.asarray(v, self.dtype) for k, v in out.items()}

    # The held search -------------------------------------------------------------------------

    def refresh(self, params: Mapping[str, Any] | None = None) -> Search:
        """Run the discrete search again at ``params`` (default: the scene's values): after
        large steps the held search no longer matches what the parameters would meet. The
        sonar's pose, the objects and the planes are searched where ``params`` puts them; the
        sensor's parameters do not move the search (the rays stay the scene's fan)."""
        self.searches += 1
        self._complete(params)  # unknown keys and shapes refused by name
        # Only geometry moves the search (laws, reflectances and the sensor do not: they are
        # not even checked against the scene format's bounds here); a value within float32's
        # round-off of the scene's has not moved.
        values = {k: np.asarray(v, float) for k, v in (params or {}).items() if k.endswith(GEOMETRY)}
        moved = [k for k, v in values.items() if not k.startswith("sonar.")
                 and not np.allclose(v, self._defaults[k], rtol=1e-6, atol=1e-9)]
        values = {k: v for k, v in values.items() if k.startswith("sonar.") or k in moved}
        scene = scene_with(self.scene, values) if values else self.scene
        if moved:
            with Simulator(replace(scene, sensor=self.scene.sensor)) as sim:
                search = record_search(sim, scene.sonar_pose, self._capacity)
        else:
            search = record_search(self.sim, scene.sonar_pose, self._capacity)
        # Sizes only grow: a refreshed search of the same size or smaller reuses the compiled
        # functions (a new size compiles them again, a second or more).
        self._capacity = max(self._capacity, search.capacity)
        self.search = search
        self._data = self._arrays(search)
        self.static = Static(**{**self.static.__dict__, "n_rows": search.n_rows,
                                "n_signatures": max(len(search.signatures), 1)})
        return search

    def _arrays(self, search: Search) -> dict:
        fan = self._fan
        data = {k: jnp.asarray(v) for k, v in search.arrays().items()}
        data["direction"] = jnp.asarray(fan.directions.reshape(-1, 3)[search.ray], self.dtype)
        data["weight"] = jnp.asarray(fan.weight.reshape(-1)[search.ray], self.dtype)
        data["factor"] = jnp.asarray(search.factor, self.dtype)
        if self.static.attach == "surfaces":  # the beams an object's echo moves across
            n_el = fan.shape[2]
            centre = np.radians(self.scene.sonar.azimuth_deg)
            nb = len(centre)
            beam = search.beam
            plus, minus = np.minimum(beam + 1, nb - 1), np.maximum(beam - 1, 0)
            data["ray_azimuth"] = jnp.asarray(fan.azimuth_rad.reshape(-1)[search.ray // n_el], self.dtype)
            data["beam_plus"], data["beam_minus"] = jnp.asarray(plus), jnp.asarray(minus)
            data["step_plus"] = jnp.asarray(np.where(plus != beam, centre[plus] - centre[beam], np.inf), self.dtype)
            data["step_minus"] = jnp.asarray(np.where(minus != beam, centre[minus] - centre[beam], np.inf), self.dtype)
        # The hit triangles of each object, padded (with its first face) to a size that only
        # grows, and the paths' scatterer rows moved to the padded table.
        # (at least one row: an empty search's padding points at row 0, which the plane table
        # always has, a stand-in where there is no plane)
        faces, start, row_of = [], search.n_planes, np.arange(max(search.n_planes + len(search.faces), 1))
        for k in range(len(self.scene.objects)):
            rows = np.flatnonzero(search.faces[:, 0] == k)
            hit = search.faces[rows, 1]
            self._face_capacity[k] = max(self._face_capacity[k], padded_size(len(hit), 64))
            padded = np.zeros(self._face_capacity[k], np.int64)
            padded[:len(hit)] = hit
            faces.append(jnp.asarray(self._local_faces[k][padded]))
            row_of[search.n_planes + rows] = start + np.arange(len(rows))
            start += self._face_capacity[k]
        data["local_faces"] = tuple(faces)
        data["surface"] = jnp.asarray(row_of[search.surface])
        for key in ("rx_planes", "tx_planes"):  # a mesh mirror's triangle: its row in the padded table
            chains = getattr(search, key)
            data[key] = jnp.asarray(np.where(chains >= search.n_planes, row_of[np.maximum(chains, 0)], chains))
        if self._sensor is not None:
            data.update(self._sensor.arrays(search))
        # One precision throughout (with JAX's 64-bit mode on, a float32 renderer's constants
        # would otherwise be float64).
        return jax.tree_util.tree_map(lambda a: a.astype(self.dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a,
                                      data)

    # Rendering -------------------------------------------------------------------------------

    def _function(self, what: str):
        fn = self._jitted.get(what)
        if fn is None:
            fn = jax.jit(_FORMS[what], static_argnums=2)
            self._jitted[what] = fn
        return fn

    @property
    def data(self) -> dict:
        """The held search's arrays (a pytree of JAX arrays): what :meth:`image_function`
        takes beside the parameters. A new object after each :meth:`refresh`."""
        return self._data

    def _image_static(self) -> Static:
        """What the image alone is compiled for: the signatures' count and the stack's rows
        are the components' (a refresh that changes them does not compile the image again)."""
        return Static(**{**self.static.__dict__, "n_rows": 0, "n_signatures": 0})

    def image_function(self):
        """The pure function ``f(params, data) -> image`` behind :meth:`render` (``params``
        complete: every key of :meth:`params`).

        Inside a function of your own that ``jax.jit`` compiles, pass :attr:`data` as an
        argument: a ``jit`` that calls :meth:`render` reads the search as it was when the
        function was traced, and a later :meth:`refresh` does not reach it.
        """
        fn, static = self._function("image"), self._image_static()
        dtype = self.dtype
        return lambda params, data: fn(params, data, static).astype(dtype)

    def echo_function(self):
        """The pure function ``f(params, data) -> image`` behind :meth:`echo` (see
        :meth:`image_function`)."""
        fn, static = self._function("echo"), self._image_static()
        dtype = self.dtype
        return lambda params, data: fn(params, data, static).astype(dtype)

    def render(self, params: Mapping[str, Any] | None = None) -> jax.Array:
        """The expected image (n_range_bins, n_beams): the total of ``render.bounces``, or,
        with a ``sensor:`` section, the sensor's expected output (no speckle, no noise draws)."""
        return self._function("image")(self._complete(params), self._data, self._image_static()).astype(self.dtype)

    def echo(self, params: Mapping[str, Any] | None = None) -> jax.Array:
        """The image (n_range_bins, n_beams) before the sensor stage: the total of
        ``render.bounces`` that :func:`sonarsim.diff.sensor.expected_output` takes (the same as
        :meth:`render` without a ``sensor:`` section)."""
        return self._function("echo")(self._complete(params), self._data, self._image_static()).astype(self.dtype)

    def paths(self, params: Mapping[str, Any] | None = None) -> dict[str, jax.Array]:
        """The frame's paths as the forward forms them, one entry per path of the held search:
        ``distance`` (m, half the path's length), ``energy``, ``point`` (the scatterer, (n, 3),
        m), ``receive_m`` (the receive leg's length), ``cos`` (the incidence at the
        scatterer); and, held, ``ray``, ``beam``, ``label`` (the image-stack row) and
        ``signature`` (an index into ``search.signatures``)."""
        distance, energy, parts = self._function("paths")(self._complete(params), self._data, self.static)
        n = self.search.n_paths
        s = self.search
        return {"distance": distance[:n], "energy": energy[:n], "point": parts["point"][:n],
                "receive_m": parts["rx"][:n], "cos": parts["cos"][:n], "ray": s.ray[:n], "beam": s.beam[:n],
                "label": s.label[:n], "signature": s.signature[:n]}

    def components(self, params: Mapping[str, Any] | None = None) -> dict[str, jax.Array]:
        """Every component of the frame (``object``, ``ground``, ``single``, ``double``, ...,
        ``total`` and one image per path signature), before any sensor."""
        stack, sigs = self._function("components")(self._complete(params), self._data, self.static)
        out = {}
        for comp in component_table(max(self.static.n_rows - 1, 1)):
            if comp.name == "total":
                out["total"] = sum(stack[r] for r in self.static.total_rows)
            else:
                out[comp.name] = sum(stack[r] for r in comp.rows)
        for i, name in enumerate(self.search.signatures):
            out[name] = sigs[i]
        return out


def _shift(parts: dict, static: Static):
    return parts["shift"] if static.attach == "surfaces" else None


def _stack(params: dict, data: dict, static: Static):
    distance, energy, parts = forward.path_ranges(params, data, static)
    return forward.splat(distance, energy, data["label"], static.n_rows, data, static.geometry, static.spread,
                         _shift(parts, static)), (distance, energy, parts)


def _echo(params: dict, data: dict, static: Static):
    distance, energy, parts = forward.path_ranges(params, data, static)
    # One image: the paths of the orders in ``render.bounces``, added as they are splatted.
    in_total = jnp.isin(data["label"], jnp.asarray(static.total_rows))
    total = forward.splat(distance, jnp.where(in_total, energy, 0.0), jnp.zeros_like(data["label"]), 1, data,
                          static.geometry, static.spread, _shift(parts, static))[0]
    return total


def _image(params: dict, data: dict, static: Static):
    total = _echo(params, data, static)
    if static.sensor is not None:
        from . import sensor as sensor_mod

        total = sensor_mod.expected_output(total, params, data, static.sensor)
    return total


def _components(params: dict, data: dict, static: Static):
    stack, (distance, energy, parts) = _stack(params, data, static)
    sigs = forward.splat(distance, energy, data["signature"], static.n_signatures, data, static.geometry,
                         static.spread, _shift(parts, static))
    return stack, sigs


_FORMS = {"image": _image, "echo": _echo, "components": _components, "paths": forward.path_ranges}
