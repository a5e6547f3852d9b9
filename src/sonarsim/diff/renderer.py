"""The differentiable renderer: :class:`Renderer`, ``params()`` and ``render(params)``.

The compiled engine does the discrete search once (:func:`~sonarsim.diff.search.record_search`);
the continuous rest of the frame is a JAX function of the parameters
(:mod:`sonarsim.diff.forward`, then :mod:`sonarsim.diff.sensor` where the scene has a sensor),
compiled by ``jax.jit`` on first use, differentiable by ``jax.grad`` and batched by ``jax.vmap``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from ..config.loader import load_scene
from ..errors import ConfigError, SonarsimError
from ..renderer.components import component_table, total_rows
from ..renderer.simulator import Simulator
from ..scene.meshes import object_mesh_local
from . import forward
from .cost import check_diff_cost
from .params import check_diff_laws, check_value, parameter_bounds, scene_params, scene_with, surface_laws
from .search import Search, padded_size, record_search


#: The parameters that move the search (the rest are re-formed on the held search exactly).
GEOMETRY = (".position_m", ".rpy_deg", ".scale", ".vertices_m", ".offset_m", ".normal")

#: How far is far from the held search (:meth:`Renderer.refresh`): the sonar moved by more than
#: this fraction of the range window's far end, or turned by more than this fraction of the
#: narrower of its fields of view; a plane's points within the window moved by more than this
#: fraction of the window's far end.
FAR_FRACTION = 0.1
#: An object whose vertices moved by more than this fraction of its size (the largest side of
#: its box at the held search) has left the triangles the held paths meet.
FAR_OBJECT_FRACTION = 0.5


class StaleSearchWarning(UserWarning):
    """The parameters rendered have moved the sonar, an object or a plane far from where the
    held search was taken: the image still shows the held paths (what the sonar met there),
    not what it would meet now. :meth:`Renderer.refresh` searches again."""


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
    cone: bool = False  # the sonar's beams are cones (sonar.beam_shape): a scatterer's beam azimuth is asin(y)


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

    Raises
    ------
    ConfigError
        The renderer's memory or time, estimated from the scene and the sonar's grid before
        it is built (:func:`sonarsim.diff.cost.check_diff_cost`; again from the search's
        counts before JAX compiles), exceeds the budgets (``--max-memory`` /
        ``$SONARSIM_MAX_MEMORY``, ``--max-build-time`` / ``$SONARSIM_MAX_BUILD_TIME``); and
        what the scene format or the differentiable engine does not take.

    Attributes
    ----------
    cost : DiffCost
        The estimate checked (:mod:`sonarsim.diff.cost`).

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
        check_diff_laws(self.scene)
        # Memory and time estimated from the scene and the sonar's grid before anything is
        # built (and again from the search's counts before JAX compiles anything).
        self.cost = check_diff_cost(self.scene)
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
            reflective=tuple(reflectivity), cone=sonar.beam_shape == "cone",
        )
        self._local_faces = [np.asarray(object_mesh_local(o).faces, np.int64) for o in scene.objects]
        counts = [len(self._defaults[f"objects.{o.name}.vertices_m"]) for o in scene.objects]
        self._vertex_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self._jitted: dict = {}
        self.search: Search | None = None
        self._capacity = 1024
        self.searches = 0  # searches run (refresh): what a fit reports as its renders
        self._face_capacity = 64
        self.refresh()

    # Parameters ------------------------------------------------------------------------------

    def params(self) -> dict[str, jax.Array]:
        """The scene's parameters (see :mod:`sonarsim.diff.params`), as JAX arrays."""
        return {k: jnp.asarray(v, self.dtype) for k, v in self._defaults.items()}

    @property
    def names(self) -> tuple[str, ...]:
        """Every parameter's key."""
        return tuple(self._defaults)

    def _complete(self, params: Mapping[str, Any] | None, bounds: bool = True) -> dict[str, Any]:
        """``params`` over the defaults; an unknown key is refused by name, and so is a value
        that is not finite or (``bounds``) lies outside the scene format's bounds
        (:func:`~sonarsim.diff.params.check_value`), wherever the value is concrete: given
        directly, or traced by ``jax.grad``, ``jax.jacfwd`` or ``jax.vmap`` outside ``jit``.
        Inside ``jit`` values are abstract and cannot be checked here; the forward then keeps
        degenerate geometry from turning into NaN (:func:`sonarsim.diff.forward.path_ranges`)."""
        out: dict[str, Any] = dict(self._defaults)
        if params is None:
            return {k: jnp.asarray(v, self.dtype) for k, v in out.items()}
        unknown = [k for k in params if k not in out]
        if unknown:
            raise ConfigError(unknown[0], f"no such parameter in this scene; its parameters: {', '.join(out)}")
        table = parameter_bounds()
        concrete = {}
        for k, v in params.items():
            shape = np.shape(self._defaults[k])
            if not isinstance(v, (jax.Array, jax.core.Tracer, np.ndarray)):
                v = np.asarray(v, float)  # a list or a number
            if jnp.shape(v) != shape:
                raise ConfigError(k, f"has shape {jnp.shape(v)}; expected {shape}")
            value = concrete_value(v)
            if value is not None:
                check_value(k, value, table if bounds else {})
                concrete[k] = value
            out[k] = v
        if bounds:
            self._check_reach(concrete)
        return {k: v if isinstance(v, jax.core.Tracer) else jnp.asarray(v, self.dtype) for k, v in out.items()}

    def check_params(self, params: Mapping[str, Any]) -> None:
        """Refuse what :meth:`render` would refuse of ``params`` (unknown keys, shapes, values
        not finite or beyond the scene format's bounds, where concrete), without rendering and
        without a :class:`StaleSearchWarning`: for a fit's start before its first refresh.

        Raises
        ------
        ConfigError
        """
        self._complete(params)

    def _check_reach(self, concrete: Mapping[str, np.ndarray]) -> None:
        """Refuse an object whose vertices, scaled and posed, reach beyond the scene's extent
        (as the scene format refuses its mesh: ``MAX_COORDINATE_M`` along any axis)."""
        from ..config.scene import MAX_COORDINATE_M
        from ..core.transforms import rpy_to_matrix

        parts = ("vertices_m", "scale", "rpy_deg", "position_m")
        for obj in self.scene.objects:
            p = f"objects.{obj.name}"
            given = [f"{p}.{part}" for part in parts if f"{p}.{part}" in concrete]
            if not given:
                continue
            v = {part: np.asarray(concrete.get(f"{p}.{part}", self._defaults[f"{p}.{part}"]), float) for part in parts}
            # A batch (jax.vmap's): each member (the parts not batched are shared).
            batched = {part: x.ndim > np.ndim(self._defaults[f"{p}.{part}"]) for part, x in v.items()}
            n = max([len(x) for part, x in v.items() if batched[part]] + [1])
            reach = 0.0
            for b in range(n):
                m = {part: x[b] if batched[part] else x for part, x in v.items()}
                world = (m["vertices_m"] * m["scale"]) @ rpy_to_matrix(*np.radians(m["rpy_deg"])).T + m["position_m"]
                reach = max(reach, float(np.abs(world).max()) if len(world) else 0.0)
            if reach > MAX_COORDINATE_M:
                # Named by a part that moved (all may be given, as to jax.grad).
                moved = [k for k in given if np.any(np.asarray(concrete[k]) != self._defaults[k])]  # (a batch too)
                raise ConfigError((moved or given)[0], f"the vertices of object {obj.name!r}, scaled and posed, reach "
                                  f"{reach:.3g} m from the origin; allowed: within [{-MAX_COORDINATE_M:g}, "
                                  f"{MAX_COORDINATE_M:g}] m along each axis (the scene format's bound; mind scale and "
                                  "pose)")

    def _checked(self, params: Mapping[str, Any] | None) -> dict[str, Any]:
        """:meth:`_complete` with the bounds, and a :class:`StaleSearchWarning` where the
        concrete parameters are far from the held search."""
        out = self._complete(params)
        if params is not None and not self._stale_warned:
            far = self.distance_from_search(params)
            if far:
                self._stale_warned = True  # once per held search: a loop of renders says it once
                warnings.warn(f"{far}: the image shows the paths held where the search was taken, not what would be "
                              "met here; call refresh(params) to search again at these parameters (one frame of "
                              "the compiled engine)", StaleSearchWarning, stacklevel=3)
        return out

    def distance_from_search(self, params: Mapping[str, Any]) -> str:
        """How far ``params`` (concrete values) have moved the geometry from the held search,
        where it is far (see :data:`FAR_FRACTION`, :data:`FAR_OBJECT_FRACTION`): one clause
        per thing moved far, e.g. ``"the sonar moved 500 m (far: beyond 0.8 m)"``; empty where
        nothing is, or where the values are abstract (inside ``jit``)."""
        from ..core.transforms import rpy_to_matrix

        held, sonar = self._held, self.scene.sonar
        reach = float(sonar.range_max_m)
        values = {}
        for k, v in params.items():
            if k.endswith(GEOMETRY):
                c = concrete_value(v)
                if c is None:
                    return ""
                if c.shape == np.shape(held[k]) and not np.array_equal(c, held[k]):
                    values[k] = np.asarray(c, float)
        if not values:
            return ""

        def get(k):
            return values.get(k, held[k])

        def turn_deg(a, b):
            ra, rb = rpy_to_matrix(*np.radians(a)), rpy_to_matrix(*np.radians(b))
            return float(np.degrees(np.arccos(np.clip((np.trace(ra.T @ rb) - 1.0) / 2.0, -1.0, 1.0))))

        out = []
        if "sonar.position_m" in values or "sonar.rpy_deg" in values:
            moved = float(np.linalg.norm(get("sonar.position_m") - held["sonar.position_m"]))
            turned = turn_deg(held["sonar.rpy_deg"], get("sonar.rpy_deg"))
            fov = min(float(sonar.azimuth_fov_deg), float(sonar.elevation_fov_deg))
            if moved > FAR_FRACTION * reach or turned > FAR_FRACTION * fov:
                out.append(f"the sonar moved {moved:.3g} m and turned {turned:.3g} degrees from the held search "
                           f"(far: beyond {FAR_FRACTION * reach:.3g} m, {FAR_FRACTION:g} of the range window's far end, "
                           f"or {FAR_FRACTION * fov:.3g} degrees, {FAR_FRACTION:g} of the narrower field of view)")
        for obj in self.scene.objects:
            p = f"objects.{obj.name}"
            if not any(f"{p}.{part}" in values for part in ("position_m", "rpy_deg", "scale", "vertices_m")):
                continue

            def world(get):
                v = get(f"{p}.vertices_m") * get(f"{p}.scale")
                return v @ rpy_to_matrix(*np.radians(get(f"{p}.rpy_deg"))).T + get(f"{p}.position_m")

            before, after = world(lambda k: held[k]), world(get)
            size = float(np.max(before.max(axis=0) - before.min(axis=0))) if len(before) else 0.0
            moved = float(np.max(np.linalg.norm(after - before, axis=1))) if len(before) else 0.0
            if moved > FAR_OBJECT_FRACTION * size:
                out.append(f"object {obj.name!r} moved {moved:.3g} m (its vertices; far: beyond "
                           f"{FAR_OBJECT_FRACTION * size:.3g} m, {FAR_OBJECT_FRACTION:g} of its size)")
        for name in self.static.planes:
            p = f"planes.{name}"
            if f"{p}.offset_m" in values or f"{p}.normal" in values:
                def unit(n):  # (scaled first: the squares of a normal's huge components overflow)
                    n = n / max(float(np.max(np.abs(n))), 1e-300)
                    return n / max(float(np.linalg.norm(n)), 1e-300)

                n0, n1 = unit(held[f"{p}.normal"]), unit(get(f"{p}.normal"))
                moved = abs(float(get(f"{p}.offset_m")) - float(held[f"{p}.offset_m"])) + reach * float(
                    np.linalg.norm(n1 - n0))
                if moved > FAR_FRACTION * reach:
                    out.append(f"plane {name!r} moved about {moved:.3g} m within the range window (far: beyond "
                               f"{FAR_FRACTION * reach:.3g} m)")
        return "; ".join(out)

    # The held search -------------------------------------------------------------------------

    def refresh(self, params: Mapping[str, Any] | None = None) -> Search:
        """Run the discrete search again at ``params`` (default: the scene's values): after
        large steps the held search no longer matches what the parameters would meet. The
        sonar's pose, the objects and the planes are searched where ``params`` puts them; the
        sensor's parameters do not move the search (the rays stay the scene's fan)."""
        self.searches += 1
        # Unknown keys, shapes and values that are not finite are refused by name, and
        # geometry beyond the scene format's bounds (the compiled engine searches a scene
        # made of it); the other bounds are not checked here, so that an optimiser's trial
        # step beyond one is evaluated (by its own function, or refused by render), not a fit
        # that stops.
        self._complete(params, bounds=False)
        table = parameter_bounds()
        geometry = {k: np.asarray(v, float) for k, v in (params or {}).items() if k.endswith(GEOMETRY)}
        for k, v in geometry.items():
            check_value(k, v, table)
        self._check_reach(geometry)
        # Only geometry moves the search (laws, reflectances and the sensor do not: they are
        # not even checked against the scene format's bounds here); a value within float32's
        # round-off of the scene's has not moved.
        values = {k: np.asarray(v, float) for k, v in (params or {}).items() if k.endswith(GEOMETRY)}
        moved = [k for k, v in values.items() if not k.startswith("sonar.")
                 and not np.allclose(v, self._defaults[k], rtol=1e-6, atol=1e-9)]
        values = {k: v for k, v in values.items() if k.startswith("sonar.") or k in moved}
        if moved:
            try:
                scene = scene_with(self.scene, values)
                sim = Simulator(replace(scene, sensor=self.scene.sensor))
            except SonarsimError as exc:
                # What the scene format refuses of the moved geometry (a mesh posed beyond the
                # scene's extent, ...), named by the parameter that moved it.
                raise ConfigError(moved[0], f"the scene at these parameters is refused: {exc}") from None
            with sim:
                search = record_search(sim, scene.sonar_pose, self._capacity)
        else:
            scene = scene_with(self.scene, values) if values else self.scene
            search = record_search(self.sim, scene.sonar_pose, self._capacity)
        # Sizes only grow: a refreshed search of the same size or smaller reuses the compiled
        # functions (a new size compiles them again, a second or more).
        if search.capacity > self._capacity or self.search is None:
            self.cost = check_diff_cost(self.scene, n_paths=max(search.capacity, self._capacity),
                                        n_faces=max(padded_size(len(search.faces), 64), self._face_capacity),
                                        n_images=search.n_rows + max(len(search.signatures), 1),
                                        legs=search.rx_planes.shape[1] + search.tx_planes.shape[1])
        self._capacity = max(self._capacity, search.capacity)
        self.search = search
        self._held = {**{k: v for k, v in self._defaults.items() if k.endswith(GEOMETRY)},
                      **{k: np.asarray(v, float) for k, v in (params or {}).items() if k.endswith(GEOMETRY)}}
        self._stale_warned = False
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
        # The hit triangles of every object in one table, as the search numbers them (so the
        # paths' rows need no moving), padded (with its first row) to a size that only grows,
        # their corners as indices into the objects' vertices concatenated in object order.
        n_faces = len(search.faces)
        self._face_capacity = max(self._face_capacity, padded_size(n_faces, 64))
        rows = np.zeros(self._face_capacity if self.scene.objects else 0, np.int64)
        rows[:n_faces] = np.arange(n_faces)
        obj = search.faces[rows, 0] if n_faces else np.zeros(len(rows), np.int64)
        local = search.faces[rows, 1] if n_faces else np.zeros(len(rows), np.int64)
        corners = np.zeros((len(rows), 3), np.int64)
        for k in np.unique(obj):
            at = obj == k
            corners[at] = self._local_faces[k][local[at]] + self._vertex_start[k]
        data["faces"] = jnp.asarray(corners)
        data["face_object"] = jnp.asarray(obj)
        # Where a path meets degenerate geometry inside jit, it keeps the range the search
        # recorded (its neighbours' range cells stay where they were; padding: 0).
        data["held_distance"] = jnp.asarray(np.where(np.isfinite(search.distance), search.distance, 0.0), self.dtype)
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
        with a ``sensor:`` section, the sensor's expected output (no speckle, no noise draws).

        ``params`` (any subset of :meth:`params`' keys) are checked where they are concrete:
        given as values, or traced by ``jax.grad``, ``jax.jacfwd`` or ``jax.vmap`` called
        outside ``jit``. A value that is not finite or lies outside the scene format's bounds
        (:func:`~sonarsim.diff.params.parameter_bounds`) raises :class:`~sonarsim.errors.ConfigError`
        naming the key and the range; geometry far from the held search warns
        (:class:`StaleSearchWarning`, see :meth:`distance_from_search`). Inside ``jit`` the
        values are abstract and cannot be checked: the forward keeps degenerate geometry
        (collapsed triangles, a zero scale, a zero width) from turning into NaN, but a NaN
        given there passes into the image.
        """
        return self._function("image")(self._checked(params), self._data, self._image_static()).astype(self.dtype)

    def echo(self, params: Mapping[str, Any] | None = None) -> jax.Array:
        """The image (n_range_bins, n_beams) before the sensor stage: the total of
        ``render.bounces`` that :func:`sonarsim.diff.sensor.expected_output` takes (the same as
        :meth:`render` without a ``sensor:`` section)."""
        return self._function("echo")(self._checked(params), self._data, self._image_static()).astype(self.dtype)

    def paths(self, params: Mapping[str, Any] | None = None) -> dict[str, jax.Array]:
        """The frame's paths as the forward forms them, one entry per path of the held search:
        ``distance`` (m, half the path's length), ``energy``, ``point`` (the scatterer, (n, 3),
        m), ``receive_m`` (the receive leg's length), ``cos`` (the incidence at the
        scatterer); and, held, ``ray``, ``beam``, ``label`` (the image-stack row) and
        ``signature`` (an index into ``search.signatures``)."""
        distance, energy, parts = self._function("paths")(self._checked(params), self._data, self.static)
        n = self.search.n_paths
        s = self.search
        return {"distance": distance[:n], "energy": energy[:n], "point": parts["point"][:n],
                "receive_m": parts["rx"][:n], "cos": parts["cos"][:n], "ray": s.ray[:n], "beam": s.beam[:n],
                "label": s.label[:n], "signature": s.signature[:n]}

    def components(self, params: Mapping[str, Any] | None = None) -> dict[str, jax.Array]:
        """Every component of the frame (``object``, ``ground``, ``single``, ``double``, ...,
        ``total`` and one image per path signature), before any sensor."""
        stack, sigs = self._function("components")(self._checked(params), self._data, self.static)
        out = {}
        for comp in component_table(max(self.static.n_rows - 1, 1)):
            if comp.name == "total":
                out["total"] = sum(stack[r] for r in self.static.total_rows)
            else:
                out[comp.name] = sum(stack[r] for r in comp.rows)
        for i, name in enumerate(self.search.signatures):
            out[name] = sigs[i]
        return out


def concrete_value(value: Any) -> np.ndarray | None:
    """The value behind a parameter as a NumPy array, or None inside ``jit`` (abstract).

    A plain array is its value; a tracer of ``jax.grad`` or ``jax.jacfwd`` taken outside
    ``jit`` carries its concrete primal, and one of ``jax.vmap`` its batch (every member is
    then checked).
    """
    if not isinstance(value, jax.core.Tracer):
        return np.asarray(value)
    try:
        concrete = value.to_concrete_value()
    except Exception:  # noqa: BLE001 - a tracer that has none
        concrete = None
    if concrete is not None:
        return np.asarray(concrete)
    batch = getattr(value, "val", None)  # jax.vmap's tracer: the batch it maps over
    if batch is not None and type(value).__name__ == "BatchTracer":
        return concrete_value(batch)
    return None


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
