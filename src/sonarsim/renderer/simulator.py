"""The renderer: a :class:`Simulator` holds the acceleration structure and renders poses.

Pipeline per frame: rays of the sonar (cached per sonar) -> rotate to the pose -> receive legs
(closest surfaces: Embree for the objects, the planes analytically; reflected off the planes,
generation after generation) -> transmit legs by image sources -> paths into an image stack
(one row per order) -> components -> :class:`SonarImage`.
"""

from __future__ import annotations

import functools
import time
import warnings
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from ..config.loader import load_scene, parse_pose
from ..config.scene import Scene, sonar_section
from ..config.sonar import SonarConfig, image_bytes
from ..core.memory import keep_freed_memory, require_together
from ..scene.cost import check_scene_cost, leg_bytes
from ..core.radiometry import SEDIMENT, SurfaceLaws, backscatter
from ..core import reflection
from ..core.rays import BYTES_PER_RAY, RayFan, make_ray_fan, ray_bytes, ray_size_key
from ..core.streams import frame_rng, sequential_rng
from ..core.transforms import Pose
from ..errors import ConfigError
from ..image.result import RayMaps, SonarImage
from ..config.scene import ON_PLANE_TOLERANCE_M, check_sonar_position
from ..reference.algorithm2 import render_paper
from ..paths.engine import (
    Leg, SonarView, accumulate_paths, drop_occluded, form_paths, ground_signatures, probe_chains, renumber_chains,
    glint_sets, split_by_signature, trace_legs,
)
from ..paths.buffer import FramePaths
from ..paths.facets import FacetSet
from ..paths.planes import ChainTable, PlaneSet
from ..sensor.model import SensorModel, elevation_span_deg
from ..sensor.speckle import pool_bytes
from ..scene.inside import InsideTest
from ..scene.meshes import clip_to_water, mirror_across_plane, object_mesh_scaled, object_mesh_world, outer_side, posed_mesh
from ..scene.floor_texture import scale_by_texture, texture_fields
from ..scene.textures import with_textures
from ..trace import available_cores, make_caster
from ..trace.surfaces import trace
from . import compiled
from .components import component_table, frame_components, stack_rows, total_rows
from .ground_truth import LabelSpec, frame_labels, require_label_maps

# Rays are cast this far past the range window so that range splatting sees the neighbour of a
# ray that ends just inside it.
RANGE_MARGIN = 1.25

# Unfolded ground-echo paths OA' matter up to 2 * range_max - range_min (cases 2/3 land at
# (OA + OA') / 2 with OA >= range_min); cast that far when there is multipath to form.
MULTIPATH_REACH = 2.0

# The grid of a frame of several poses (Simulator.trace_poses) spans this many degrees: its
# columns are the poses' beams side by side, and its azimuths name no direction.
BATCH_GRID_FOV_DEG = 90.0


def mirror_reflectance(mirrors, frequency_hz: float | None, sound_speed_m_s: float) -> dict[str, np.ndarray]:
    """``SurfaceLaws``' ``reflectance`` and ``reflect_q`` rows (row 0: nothing hit) of surfaces
    given as ``(specular, reflection or None, material)`` in surface-id order: a constant row
    where there is no reflection, the medium's ``|V|^2`` table and roughness exponent where
    there is one."""
    table = np.zeros((len(mirrors) + 1, reflection.TABLE_SIZE))
    q = np.zeros(len(mirrors) + 1)
    for i, (specular, refl, material) in enumerate(mirrors):
        if refl is None:
            table[i + 1] = specular
        else:
            table[i + 1] = refl.table(material, sound_speed_m_s)
            q[i + 1] = refl.exponent(material, frequency_hz, sound_speed_m_s)
    return {"reflectance": table, "reflect_q": q}


@functools.lru_cache(maxsize=8)
def batch_grid(sonar: SonarConfig, n_beams: int, n_poses: int) -> SonarConfig:
    """The grid of a frame of ``n_poses`` poses of ``sonar`` (:meth:`Simulator.trace_poses`):
    its range bins, ``n_poses n_beams`` beams side by side (their azimuths name no direction)."""
    return SonarConfig.uniform(
        n_beams=n_poses * n_beams, azimuth_fov_deg=BATCH_GRID_FOV_DEG, elevation_fov_deg=sonar.elevation_fov_deg,
        range_min_m=sonar.range_min_m, range_max_m=sonar.range_max_m, n_range_bins=sonar.n_range_bins,
        frequency_khz=sonar.frequency_khz,
    )


def check_labels(labels: Any) -> None:
    """Refuse a ``labels`` argument other than False, True, 'all' or 'total' (ConfigError ``labels``)."""
    if labels not in (False, True, "all", "total"):
        raise ConfigError("labels", f"unknown labels {labels!r}; allowed: False, True, 'all', 'total'")


def as_pose(pose: Any) -> Pose:
    """A :class:`Pose` from a Pose, a ``{position_m, rpy_deg | quat_xyzw}`` dict or a 4x4 matrix."""
    if isinstance(pose, Pose):
        return pose
    if isinstance(pose, Mapping):
        return parse_pose(pose, "pose")
    m = np.asarray(pose, dtype=float)
    if m.shape != (4, 4):
        raise TypeError("pose must be a Pose, a dict with position_m and rpy_deg/quat_xyzw, or a 4x4 matrix")
    return Pose.from_matrix(m)


def frame_memory_parts(scene: Scene, sonar: SonarConfig) -> list[tuple[float, str, str]]:
    """What a frame of ``sonar`` in ``scene`` holds at once: ``(bytes, what, key)`` for its images,
    its rays (over a sensor's elevation span) and the sensor's speckle and noise fields."""
    spec, render = scene.sensor, scene.render
    traced = sonar
    parts = [(image_bytes(sonar.n_range_bins, sonar.n_beams), "images", "sonar.n_range_bins")]
    if spec is not None:
        span = elevation_span_deg(spec, sonar)
        if span != sonar.elevation_fov_deg:
            traced = replace(sonar, elevation_fov_deg=span)
        parts.append((pool_bytes((sonar.n_range_bins, sonar.n_beams), spec.speckle is not None,
                                 spec.noise is not None, looks=1.0 if spec.speckle is None else spec.speckle.looks),
                      "speckle and noise fields", "sensor.speckle"))
    parts.insert(1, (ray_bytes(traced, render), "rays", ray_size_key(traced, render)))
    # Paths of high order (mirrors) keep every generation's legs: 900 mirror boxes at max_order 5
    # with glints trace six generations of every ray.
    legs = leg_bytes(ray_bytes(traced, render) // BYTES_PER_RAY, render.max_order, render.glints)
    if legs:
        parts.append((legs, f"path legs ({render.max_order + (1 if render.glints else 0)} generations)",
                      "render.max_order"))
    return parts


def require_frame_memory(scene: Scene, sonar: SonarConfig) -> None:
    """Check what a frame of ``sonar`` in ``scene`` holds at once (:func:`frame_memory_parts`)
    against the memory budget, before any of it is allocated. Each part is also checked alone
    where it is made; here their sum (a scene whose parts each fit could still not fit together).

    Raises
    ------
    ConfigError
        Naming the key of the largest part.
    """
    require_together(frame_memory_parts(scene, sonar), f"a frame of {sonar.n_range_bins} x {sonar.n_beams}")


#: Time to form a path signature's image, per pixel (compiled kernels: the splat, the copy of
#: its row, the memory it takes; 1e-8 s measured here with 2,255 signatures of 1288 x 128 at
#: max_order 5 with the machine loaded five times over).
SECONDS_PER_SIGNATURE_PIXEL = 5e-9


def check_signature_images(n_signatures: int, n_range_bins: int, n_beams: int, max_order: int) -> None:
    """Refuse a frame whose path-signature images (one float32 image each, formed when the
    components are listed, as writing an NPZ does) would exceed the memory or time budget.

    Raises
    ------
    ConfigError
        ``render.max_order``: the signatures, the estimate and the budget.
    """
    from ..core.memory import require, require_time

    pixels = float(n_range_bins) * n_beams
    what = (f"the images of the frame's {n_signatures:,} path signatures ({n_range_bins} x {n_beams}; "
            f"mirrors at max_order {max_order})")
    require(n_signatures * pixels * 4 + (max_order + 1) * pixels * 4, what, "render.max_order")
    require_time(n_signatures * pixels * SECONDS_PER_SIGNATURE_PIXEL, "forming " + what, "render.max_order")


class Simulator:
    """Renders a scene from many sonar poses, building the acceleration structure once.

    Parameters
    ----------
    scene : Scene, mapping or path
        Anything :func:`sonarsim.load_scene` accepts.
    backend : {'embree', 'embree4', 'embreex', 'numpy'}
        Ray-casting engine. ``embree`` is Embree through sonarsim's own binding to its C API
        (``embree4``) where that loads, else through embreex (``embreex``; the environment
        variable ``SONARSIM_EMBREE=embreex`` forces it); ``numpy`` is a slow reference for tests.
    kernels : {'compiled', 'numpy'}
        Per-ray arithmetic of the default (fast) method: compiled loops, or the NumPy reference
        they are tested against. ``compiled`` falls back to ``numpy`` (with a warning) when the
        extension is not built.

    Notes
    -----
    A simulator is not thread-safe: it renders one frame at a time (it keeps the frame's
    per-ray buffers and uses its own worker thread). Render from several threads with one
    simulator each, or from several processes (:mod:`sonarsim.dataset` does).

    Examples
    --------
    >>> sim = Simulator("tank.yaml")                       # doctest: +SKIP
    >>> img = sim.render(pose={"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]})  # doctest: +SKIP
    """

    def __init__(self, scene: Any, backend: str = "embree", kernels: str = "compiled") -> None:
        keep_freed_memory()  # per-frame temporaries would otherwise page-fault every frame
        if kernels not in ("compiled", "numpy"):
            raise ConfigError("kernels", f"unknown kernels {kernels!r}; allowed: compiled, numpy")
        if kernels == "compiled" and not compiled.AVAILABLE:
            warnings.warn("sonarsim's compiled kernels are not built; using the NumPy kernels", stacklevel=2)
            kernels = "numpy"
        self.kernels = kernels
        self._work: compiled.Workspace | None = None
        # The columns' traces (an azimuth pattern weighing a beam's columns of rays apart) run in
        # a workspace of their own: the frame's paths, read later, stay in the frame's.
        self._column_work: compiled.Workspace | None = None
        self._column_fans: tuple | None = None
        # Frames of several poses (trace_poses): the fans repeated and their workspaces, the
        # last two kept (a run of full batches and the shorter last one).
        self._batch_fans: list[tuple] = []  # (fan, n_poses, the fan repeated n_poses times)
        self._batch_works: dict[tuple, compiled.Workspace] = {}  # Workspace.layout -> workspace
        self.scene: Scene = load_scene(scene)
        self.backend = backend
        # What the scene and a frame will hold, before any of it is built (issue 21: 20,000
        # spheres ran for minutes into 10 GB before anything was refused).
        try:
            check_scene_cost(self.scene)
            self.require_frame_memory(self.scene.sonar)
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.detail, exc.source or self.scene.source) from None
        self.planes = PlaneSet.from_specs(self.scene.reflecting_planes)
        self.meshes = [object_mesh_world(o) for o in self.scene.objects]
        # The side each mirror mirrors on, from its whole mesh (clipping opens a closed one).
        sides = [outer_side(m) if o.specular > 0 else 0 for m, o in zip(self.meshes, self.scene.objects)]
        for plane in self.scene.reflecting_planes:
            # Nothing beyond a floor, wall or surface can be seen; removing it (and faces lying
            # in the plane) keeps mirror geometry and coincident faces from making echoes.
            self.meshes = [clip_to_water(m, plane.point_m, plane.normal) for m in self.meshes]
        # The objects that mirror (``specular`` > 0), their triangles as mirrors of the paths;
        # None where none does (the planes' engine, unchanged).
        objects = self.scene.objects
        self.facets: FacetSet | None = None
        if any(o.specular > 0 for o in objects):
            self.facets = FacetSet.of(self.meshes, [o.name for o in objects], [o.specular for o in objects],
                                      [o.normals for o in objects], sides)
        # The ground is the only mirror: Algorithm 2 (``method: paper``) applies.
        self._ground_only = (self.scene.ground is not None and not self.scene.planes and self.facets is None
                             and not self.scene.render.glints)
        self._warn_about_planes()
        self._sides = sides
        # Objects with their own tracks move every frame (at_time): their caster is built for it
        # (each object refitted in place); a scene without tracks gets the static, faster tree,
        # and is rebuilt once for motion on its first move_objects.
        self.tracked: tuple[str, ...] = tuple(o.name for o in objects if o.track is not None)
        self._base_caster = make_caster(backend, self.meshes, self.scene.render.threads, dynamic=bool(self.tracked))
        self.caster = with_textures(self._base_caster, self.meshes)
        self.last_moves: dict[str, str] = {}
        self._scaled: dict[int, tuple] = {}  # by object index: (scaled mesh, its box's corners), once moved
        # A sonar inside a closed object sees only its inside: said once per object, for the
        # scene's pose now and for each pose rendered (scene.inside: cheap outside the objects' boxes).
        self._inside = InsideTest(self.caster, self.meshes, [o.name for o in self.scene.objects])
        self._inside_warned: frozenset[str] = frozenset()
        self._warn_if_inside(self.scene.sonar_pose.translation, stacklevel=3)
        self._mirrored_caster = None
        self._kept_label_spec: tuple | None = None  # (fan, key, LabelSpec): _label_spec()
        threads = self.scene.render.threads or available_cores()
        # One worker: the second core of the compiled path (tasks run in order on it); the
        # compiled kernels' worker watches for the frame's next hand-off instead of sleeping.
        self._pool = None
        if threads > 1:
            self._pool = compiled.SecondCore() if self.kernels == "compiled" else ThreadPoolExecutor(1)
        # Backscatter laws by surface id + 1: index 0 is "no hit", p + 1 plane p, P + k + 1 object k.
        self._materials = ([p.backscatter for p in self.scene.reflecting_planes]
                           + [o.backscatter for o in self.scene.objects])
        # The mirrors' reflectances, in the same order: a constant, or a reflection by the physics.
        self._mirrors = ([(p.specular, p.reflection, p.backscatter) for p in self.scene.reflecting_planes]
                         + [(o.specular, o.reflection, o.backscatter) for o in self.scene.objects])
        self._reflecting = any(r is not None for _, r, _ in self._mirrors)
        # A sediment's law and a rough mirror's reflectance depend on the sonar's frequency:
        # tabulated per frequency, on first use.
        self._tabulated = any(m.code == SEDIMENT for m in self._materials) or self._reflecting
        self._laws = None if self._tabulated else SurfaceLaws.of(self._materials)
        self._laws_by_frequency: dict[float | None, SurfaceLaws] = {}
        # The planes' reflectivity textures by plane index (None: untextured), fixed for the
        # simulator's life: anchored in the world, the same every frame.
        self.textures = texture_fields(self.scene.reflecting_planes, self.scene.render.seed)
        self._textured = any(f is not None for f in self.textures)
        self._rng = sequential_rng(self.scene.render.seed)  # speckle, frame after frame
        self._fans: dict[SonarConfig, RayFan] = {}  # by intrinsics: every pose shares the fan
        # The channels of the instruments that make their own fans, by their sonar.
        self._instrument_fans = {c.sonar: i for i in self.scene.instruments for c in i.channels()}
        self._sensor_models: dict[SonarConfig, SensorModel] = {}
        self._last_fan: tuple[SonarConfig, RayFan] | None = None
        self.last_timing: dict[str, float] = {}
        self._config = self.scene.to_dict()  # the scene-file form; each frame adds its sonar and pose

    @property
    def path_kernels(self) -> str:
        """The kernels the path engine runs on (:attr:`kernels`)."""
        return self.kernels

    def _warn_if_inside(self, position: np.ndarray, stacklevel: int) -> None:
        """Warn (once per object) when the sonar at ``position`` lies inside a closed object."""
        if not self.meshes:
            return
        names = self._inside.holding(position, self._inside_warned)
        if names:
            self._inside_warned = self._inside_warned | frozenset(names)
            which = ", ".join(map(repr, names))
            warnings.warn(
                f"the sonar at {[round(float(v), 6) for v in position]} lies inside the object{'s' * (len(names) > 1)} "
                f"{which} (a closed surface around it): its rays end on the inside, and the image shows nothing "
                "of the rest of the scene; move the sonar or the object", stacklevel=stacklevel,
            )

    def _warn_about_planes(self) -> None:
        """Say so when the planes hide what the user probably meant to see (a normal the wrong way)."""
        planes = self.scene.reflecting_planes
        if not planes:
            return
        gone = [o.name for o, m in zip(self.scene.objects, self.meshes) if not len(m.faces)]
        if gone:
            warnings.warn(
                f"objects {', '.join(map(repr, gone))} lie entirely beyond the reflecting planes and cannot echo "
                "(a plane's normal points into the water)", stacklevel=3,
            )
        d = self.planes.signed_distance(self.scene.sonar_pose.translation)
        dry = [p.name for p, dist in zip(planes, d) if dist < 0]
        if dry:
            warnings.warn(
                f"the sonar is on the dry side of the planes {', '.join(map(repr, dry))} (their normals point away "
                "from it): for this sonar they neither echo nor reflect, and it sees through them", stacklevel=3,
            )

    def close(self) -> None:
        """Stop the worker threads now (they also stop when the simulator is collected)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        for caster in (self.caster, self._mirrored_caster):
            if hasattr(caster, "close"):
                caster.close()

    # A world that moves ---------------------------------------------------------------------

    def move_objects(self, poses: Mapping[str, Any]) -> None:
        """Put objects at new poses for the frames that follow, without rebuilding the scene.

        Each moved object's mesh is posed again (and clipped by the planes); the ray caster
        refits that object's tree alone (Embree 4; a caster built static is rebuilt once for
        motion, and engines that cannot move meshes are rebuilt); its mirror facets, the
        inside test and the frames' recorded scene follow. Labels follow by construction:
        an object keeps its label id wherever it goes.

        Parameters
        ----------
        poses : mapping of str to pose
            Object name -> its new object-to-world pose (a :class:`~sonarsim.core.transforms.Pose`
            or a pose mapping ``{position_m, rpy_deg | quat_xyzw}``).

        Raises
        ------
        ConfigError
            An unknown object name (the scene's names are listed), or a bad pose.
        """
        index = {o.name: k for k, o in enumerate(self.scene.objects)}
        objects = list(self.scene.objects)
        moved: dict[int, Any] = {}
        boxes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for name, pose in poses.items():
            if name not in index:
                raise ConfigError(f"objects.{name}", f"no object named {name!r} to move; the scene's objects: "
                                  f"{', '.join(map(repr, index)) or 'none'}")
            k = index[name]
            p = as_pose(pose)
            if p == objects[k].pose:
                continue
            objects[k] = replace(objects[k], pose=p)
            if k not in self._scaled:  # the object's mesh, scaled, and the 8 corners of its box
                scaled = object_mesh_scaled(objects[k])
                lo, hi = scaled.vertices.min(axis=0), scaled.vertices.max(axis=0)
                corners = np.array([[(lo, hi)[(c >> i) & 1][i] for i in range(3)] for c in range(8)])
                self._scaled[k] = (scaled, corners)
            mesh = posed_mesh(objects[k], self._scaled[k][0])
            for plane in self.scene.reflecting_planes:
                mesh = clip_to_water(mesh, plane.point_m, plane.normal)
            moved[k] = mesh
            corners = self._scaled[k][1] @ p.rotation.T + p.translation
            boxes[k] = (corners.min(axis=0), corners.max(axis=0))
        if not moved:
            self.last_moves = {}
            return
        for k, mesh in moved.items():
            self.meshes[k] = mesh
        self.scene = replace(self.scene, objects=tuple(objects))
        # The frames' record: a still scene at this moment (its objects' poses, no tracks), so
        # that a frame's scene, read back, renders that frame.
        recorded = list(self._config.get("objects", []))
        for k in moved:
            entry = {key: v for key, v in recorded[k].items() if key != "track"}
            entry["pose"] = objects[k].pose.to_dict()
            recorded[k] = entry
        self._config = {**self._config, "objects": recorded}
        base = self._base_caster
        if getattr(base, "dynamic", False):
            done = base.replace_meshes(moved)
        else:
            threads = self.scene.render.threads
            self._base_caster = make_caster(self.backend, self.meshes, threads, dynamic=True)
            (getattr(base, "release", None) or getattr(base, "close", lambda: None))()
            done = {k: "rebuilt" for k in moved}
        self.last_moves = {objects[k].name: what for k, what in done.items()}
        self.caster = with_textures(self._base_caster, self.meshes)
        names = [o.name for o in objects]
        if self.facets is not None and any(objects[k].specular > 0 for k in moved):
            self.facets = FacetSet.of(self.meshes, names, [o.specular for o in objects],
                                      [o.normals for o in objects], self._sides)
        self._inside.moved(self.caster, moved, boxes)
        if self._mirrored_caster is not None:  # method: paper's mirror images, built again on use
            (getattr(self._mirrored_caster, "release", None) or self._mirrored_caster.close)()
            self._mirrored_caster = None

    def object_poses_at(self, t_s: float) -> dict[str, Pose]:
        """The tracked objects' poses at ``t_s`` seconds of the scene's clock (their ``track``)."""
        return {o.name: o.track.pose_at(t_s) for o in self.scene.objects if o.track is not None}

    def at_time(self, t_s: float | None) -> None:
        """Move every object that has a ``track`` to its pose at ``t_s`` (seconds of the scene's
        clock: a trajectory's time, a dataset frame's, ``live``'s since it started); ``None``
        leaves them where they are."""
        if t_s is not None and self.tracked:
            self.move_objects(self.object_poses_at(float(t_s)))

    def __enter__(self) -> "Simulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def sensor_model(self, sonar: SonarConfig | None = None) -> SensorModel | None:
        """The scene's sensor made concrete for a sonar (cached); ``None`` without a sensor section."""
        if self.scene.sensor is None:
            return None
        sonar = sonar if sonar is not None else self.scene.sonar
        model = self._sensor_models.get(sonar)
        if model is None:
            self.require_frame_memory(sonar)
            model = SensorModel(self.scene.sensor, sonar, self.scene.render.seed)
            self._sensor_models = {sonar: model}  # like the fans: one sonar at a time
        return model

    def require_frame_memory(self, sonar: SonarConfig) -> None:
        """:func:`require_frame_memory` for this simulator's scene."""
        require_frame_memory(self.scene, sonar)

    def traced_sonar(self, sonar: SonarConfig) -> SonarConfig:
        """The sonar whose rays are cast: with a sensor's elevation pattern, over its wider span."""
        model = self.sensor_model(sonar)
        return sonar if model is None else model.trace_sonar(sonar)

    def ray_fan(self, sonar: SonarConfig) -> RayFan:
        """The (cached) rays of a sonar (its intrinsics) in its own frame.

        With a sensor's elevation pattern the rays span the pattern's ``span_deg`` and their
        weights carry its two-way gain; an instrument's channel (a side-scan's side, a
        single-beam's cone) has its instrument's own rays (``InstrumentSpec.make_fan``).
        """
        if self._last_fan is not None and self._last_fan[0] is sonar:
            return self._last_fan[1]
        fan = self._fans.get(sonar)
        if fan is None:
            self.require_frame_memory(sonar)
            model = self.sensor_model(sonar)
            own = self._instrument_fans.get(sonar)
            # an instrument's channel: its own pattern in the rays (a side-scan's vertical
            # pattern, a single-beam's cone), as the instrument's pings cast them
            fan = own.make_fan(self.scene.render) if own is not None else None
            if fan is not None:
                pass
            elif model is None:
                fan = make_ray_fan(sonar, self.scene.render)
            else:
                fan = make_ray_fan(model.trace_sonar(sonar), self.scene.render, model.elevation_gain)
            self._fans = {sonar: fan}  # one sonar at a time is the common case; keep memory flat
        self._last_fan = (sonar, fan)
        return fan

    def mirrored_caster(self):
        """Objects followed by their mirror images (``method: paper`` only), built on first use."""
        if self._mirrored_caster is None:
            g = self.scene.ground
            mirrored = self.meshes + [mirror_across_plane(m, g.point_m, g.normal) for m in self.meshes]
            self._mirrored_caster = with_textures(make_caster(self.backend, mirrored, self.scene.render.threads), mirrored)
        return self._mirrored_caster

    def surface_laws(self, sonar: SonarConfig) -> SurfaceLaws:
        """The surfaces' backscatter laws by surface id + 1, at ``sonar``'s frequency (that of
        ``sonar.frequency_khz``, else ``sensor.frequency_khz``; only a sediment's law depends
        on it) and the water's sound speed (:meth:`water_speed_m_s`).

        Raises
        ------
        ConfigError
            ``sonar.frequency_khz`` where a sediment's law needs a frequency and none is set.
        """
        if not self._tabulated:
            return self._laws
        spec = self.scene.sensor
        khz = sonar.frequency_khz if sonar.frequency_khz is not None else (spec.frequency_khz if spec else None)
        laws = self._laws_by_frequency.get(khz)
        if laws is None:
            hz = None if khz is None else khz * 1e3
            laws = SurfaceLaws.of(self._materials, hz, self.water_speed_m_s())
            if self._reflecting:
                laws = replace(laws, **mirror_reflectance(self._mirrors, hz, self.water_speed_m_s()))
            if len(self._laws_by_frequency) >= 8:  # instruments of a few frequencies: kept, not more
                self._laws_by_frequency.pop(next(iter(self._laws_by_frequency)))
            self._laws_by_frequency[khz] = laws
        return laws

    def _intensity(self, sonar: SonarConfig, fan: RayFan, hits) -> np.ndarray:
        out = backscatter(fan.weight, hits.cos_incidence, self.surface_laws(sonar), hits.surface_id + 1, hits.distance_m,
                          self.scene.render.tvg, hits.texel)
        if self._textured:  # the ground (surface id 0) is plane 0
            flat = out.reshape(-1)
            scale_by_texture(flat, hits.surface_id.reshape(-1), hits.point.reshape(-1, 3), self.textures)
        return out

    # The ways to form the image stack; each takes the frame's view (its pose and fan: one
    # carrier, the rays rotated once) and returns (stack, legs, path sets, chain table, total,
    # labels), total None where not already summed, labels None where not formed in the pass.

    def _render_paper(self, sonar: SonarConfig, view: SonarView, reach: float):
        """``method: paper``: Algorithm 2 literally (NumPy; the ground is the only plane)."""
        fan, pose = view.fan, view.pose
        origin, directions = view.origin, view.directions
        ground = self.scene.ground
        hits = trace(self.caster, origin, directions, ground, reach)
        images = render_paper(
            self.caster, self.mirrored_caster(), origin, directions, sonar, pose, self.scene.render, ground,
            fan.weight, self.surface_laws(sonar), len(self.meshes), reach, texture=self.textures[0],
        )
        # Rows of the orders formed (a ground alone makes no path beyond order 3).
        stack = np.zeros((stack_rows(self.scene.render.max_order), sonar.n_range_bins, sonar.n_beams), np.float32)
        for row, k in enumerate(("object", "ground", "double", "triple")[: len(stack)]):
            stack[row] = images[k]
        leg = Leg(0, hits.distance_m.reshape(-1), hits.surface_id.reshape(-1), hits.point.reshape(-1, 3),
                  hits.normal.reshape(-1, 3).astype(np.float32), self._intensity(sonar, fan, hits).reshape(-1), np.ones(fan.n_rays),
                  np.zeros(fan.n_rays, np.int32))
        return stack, [leg], None, None, None, None

    def frame_reach(self, sonar: SonarConfig, pose: Pose) -> tuple[np.ndarray, bool, float]:
        """What a frame at ``pose`` traces: the planes the sonar faces ((P,) bool), whether a
        mirror among them makes multipath (with ``max_order`` > 1), and the longest receive
        leg followed, metres."""
        active = self.planes.facing(pose.translation)
        mirrors = bool((active & (self.planes.specular > 0)).any()) or self.facets is not None
        render = self.scene.render
        # (a specular return of order 1 comes back from twice the range, as multipath does)
        multipath = (render.max_order > 1 or render.glints) and mirrors
        return active, multipath, sonar.range_max_m * RANGE_MARGIN * (MULTIPATH_REACH if multipath else 1.0)

    def _render_paths(self, sonar: SonarConfig, view: SonarView, reach: float, active: np.ndarray,
                      n_generations: int, labels: LabelSpec | None = None, primitives: bool = False,
                      poses: tuple[np.ndarray, np.ndarray] | None = None):
        """``method: fast``: receive legs traced, transmit legs by image sources (any planes).

        Returns ``(stack, legs, sets, table, total, truth)``: ``truth`` the label maps where
        the compiled engine formed them in the frame's own pass (``labels``), else None. With
        ``primitives`` the legs record the search's triangles and barycentrics (the NumPy twin
        always does). ``poses``: ``(rotations (P, 3, 3), origins (P, 3))`` of a frame of P
        poses (:meth:`trace_poses`; compiled kernels and direct paths only)."""
        render = self.scene.render
        fan, origin = view.fan, view.origin
        table = ChainTable(self.planes, origin, max(render.max_order - 1, 0), facets=self.facets)
        # Transmit legs leaving just inside the aperture's edges (outside the rays' samples).
        probe_chains(table, view, active, render.max_order - 1 if n_generations > 1 else 0,
                     kernel=compiled.probe_kernel() if self.kernels == "compiled" else None)
        n_planes = len(self.planes)
        n_surfaces = n_planes + len(self.meshes)
        weight = fan.weight.reshape(-1)
        per_beam = fan.n_rays // sonar.n_beams
        geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams)
        rows = stack_rows(render.max_order)
        occlusion = None
        if render.double_line_of_sight:
            occlusion = functools.partial(drop_occluded, table=table, view=view, active=active, caster=self.caster)
        if self.path_kernels == "compiled":
            if poses is None:
                work = self._work = compiled.Workspace.for_fan(self._work, fan)
            else:  # their own workspaces: the single-pose frames between batches keep theirs
                layout = (fan.n_rays, fan.shape[0], fan.n_rays // fan.shape[0])
                work = self._batch_works.pop(layout, None) or compiled.Workspace.for_fan(None, fan)
                self._batch_works[layout] = work
                while len(self._batch_works) > 2:
                    self._batch_works.pop(next(iter(self._batch_works)))
            stack = np.empty((rows,) + geometry[2:], dtype=np.float32)  # fresh: components are views of it
            legs, sets, table, total, truth = compiled.render_paths(
                self.caster, self.planes, active, sonar, view, work, self.surface_laws(sonar), render, reach,
                n_generations, table, n_surfaces, stack, pool=self._pool, occlusion=occlusion,
                textures=self.textures, sum_rows=total_rows(render.bounces, render.max_order), labels=labels,
                primitives=primitives, glint_radius_m=render.glint_radius_m if render.glints else None,
                poses=poses,
            )
            return stack, legs, sets, table, total, truth
        directions = view.directions.reshape(-1, 3)
        glint = render.glint_radius_m if render.glints else None
        laws = self.surface_laws(sonar)
        legs = trace_legs(self.caster, self.planes, active, origin, directions, weight, laws,
                          render.tvg, reach, n_generations, table, self.textures, glint_radius_m=glint)
        table = renumber_chains(table, legs)
        sets = form_paths(legs, table, view, active, n_planes, per_beam, render.max_order, render.double_beam,
                          None if laws.reflectance is None else (laws.reflectance, laws.reflect_q))
        if glint is not None:
            sets += glint_sets(legs, view, n_planes, per_beam, render.max_order, weight, glint, render.tvg)
        if occlusion is not None:
            sets = occlusion(sets, legs, table=table)
        stack = accumulate_paths(sets, legs, n_surfaces, fan.shape, geometry, rows, render.range_splat)
        return stack.astype(np.float32), legs, sets, table, None, None

    def _label_spec(self, fan: RayFan, sonar: SonarConfig, n_objects: int, n_planes: int,
                    components: bool) -> LabelSpec:
        """The frame's :class:`LabelSpec`, checked against the memory budget before the frame
        (``frame_labels`` checks again where it forms the maps); the last one is kept, as the
        fans are: a loop of frames forms it once."""
        render = self.scene.render
        key = (n_objects, n_planes, components, sonar.n_range_bins, sonar.n_beams)
        kept = self._kept_label_spec
        if kept is not None and kept[0] is fan and kept[1] == key:
            return kept[2]
        spec = LabelSpec.of(fan, n_objects, n_planes, render.max_order, render.bounces, components)
        require_label_maps(len(spec.lut), render.max_order, sonar.n_range_bins, sonar.n_beams, spec.components)
        self._kept_label_spec = (fan, key, spec)
        return spec

    def _signature_images(self, sonar: SonarConfig, fan: RayFan, legs, sets, table) -> dict[str, np.ndarray]:
        """One image per path signature (formed on demand; see :class:`Components`).

        A signature lies in one row of the stack; the compiled kernels splat it as they splat
        the stack (float32, in the same order), so a signature that alone fills a row (the
        ground-only frame's four) is that row, bit for bit.
        """
        geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams)
        n_planes = len(self.planes)
        n_surfaces = n_planes + len(self.meshes)
        render = self.scene.render
        groups = split_by_signature(sets() if callable(sets) else sets, legs, table, n_planes)
        # Known only now (the frame's chains decide them), and checked before any is formed:
        # 900 small mirror boxes at max_order 5 meet thousands of signatures, an image each.
        check_signature_images(len(groups), sonar.n_range_bins, sonar.n_beams, render.max_order)
        out = {}
        shape = (stack_rows(render.max_order),) + geometry[2:]
        stack = np.zeros(shape, np.float32) if self.path_kernels == "compiled" else None
        keys: dict = {}  # the legs' surface keys, formed once for all the groups
        for name, group in groups.items():
            if stack is not None:
                # One stack for all: a signature fills the rows of its paths' orders only, so
                # those are summed (the same float32 sums as over every row: the others are
                # zeros) and set back to zero (a full stack per signature: 14 ms each).
                rows = np.unique(np.concatenate([np.asarray(g.label, np.int64) for g in group]))
                compiled.splat_paths(group, legs, n_surfaces, fan.shape[2], geometry, render.range_splat, stack, keys)
                if len(rows) == 1:  # (most signatures: one order)
                    image = stack[rows[0]].copy()
                    stack[rows[0]] = 0.0
                else:
                    image = stack[rows].sum(axis=0).astype(np.float32)
                    stack[rows] = 0.0
            else:
                image = accumulate_paths(group, legs, n_surfaces, fan.shape, geometry, stack_rows(render.max_order),
                                         render.range_splat).sum(axis=0).astype(np.float32)
            if image.any():  # a path whose energy all fell outside the window leaves no image
                out[name] = image
        return out

    def trace(self, pose: Any = None, sonar: SonarConfig | None = None, labels: bool | str = False,
              primitives: bool = False, paths: bool = False, fan: RayFan | None = None,
              traced: SonarConfig | None = None) -> FramePaths:
        """The search: the frame's paths for the sonar at ``pose`` (the first step of :meth:`render`).

        Parameters
        ----------
        pose : Pose, dict or (4, 4) array, optional
            Sonar pose in the world frame (sonar-to-world); default the scene's.
        sonar : SonarConfig, optional
            Other intrinsics (beams, elevation aperture, range window); default the scene's.
        labels : bool or {'all', 'total'}
            Prepare the frame's ground truth (formed by :meth:`form`); see :meth:`render`.
        primitives : bool
            Record the triangle and barycentrics each receive leg meets (the differentiable
            engine holds them fixed).
        paths : bool
            Form paths even where ``render.method: paper`` forms Algorithm 2's images instead.
        fan : RayFan, optional
            The rays to cast, in the sonar's frame, made for ``sonar`` as it is traced (an
            instrument's own fan, its pattern in the rays' weights: :func:`~sonarsim.core.rays.make_ray_fan`).
            Default: the scene's rays for ``sonar`` (:meth:`ray_fan`, with the sensor's pattern).
        traced : SonarConfig, optional
            With ``fan``: the sonar whose aperture the fan spans (a sensor pattern's wider
            span); default ``sonar``.

        Returns
        -------
        FramePaths
            The paths and the image stack they were splatted into (:mod:`sonarsim.paths.buffer`).

        Raises
        ------
        ConfigError
            The sonar lies on one of the scene's planes; unknown ``labels``.
        """
        t0 = time.perf_counter()
        check_labels(labels)
        sonar = sonar if sonar is not None else self.scene.sonar
        pose_given = pose is not None
        pose = as_pose(pose) if pose_given else self.scene.sonar_pose
        if len(self.planes) and np.abs(self.planes.signed_distance(pose.translation)).min() < ON_PLANE_TOLERANCE_M:
            check_sonar_position(self.scene.reflecting_planes, pose.position_m,
                                 "pose" if pose_given else "sonar.pose.position_m")
        if pose_given:
            self._warn_if_inside(pose.translation, stacklevel=4)
        render = self.scene.render
        fan, image_sonar, sonar = self._cast_fan(sonar, fan, traced)
        t1 = time.perf_counter()
        active, multipath, reach = self.frame_reach(sonar, pose)
        spec = None
        if labels:
            spec = self._label_spec(fan, sonar, len(self.scene.objects), len(self.scene.reflecting_planes),
                                    labels != "total")
        n_gen = render.max_order if multipath else 1
        view = SonarView.of(sonar, pose, fan)  # the frame's pose and fan, its rays rotated once
        if render.method == "paper" and multipath and self._ground_only and not paths:
            stack, legs, sets, table, total, formed = self._render_paper(sonar, view, reach)
        else:
            stack, legs, sets, table, total, formed = self._render_paths(sonar, view, reach, active, n_gen, spec,
                                                                         primitives=primitives)
        t2 = time.perf_counter()
        return FramePaths(sonar=image_sonar, traced=sonar, pose=pose, view=view, stack=stack, legs=legs, sets=sets,
                          table=table, total=total, formed=formed, label_spec=spec, labels=labels,
                          active=active, n_generations=n_gen, reach_m=reach,
                          timing={"t0": t0, "setup": t1 - t0, "render": t2 - t1})

    def _cast_fan(self, sonar: SonarConfig, fan: RayFan | None, traced: SonarConfig | None):
        """``(fan, image grid, traced sonar)`` of a trace: the scene's rays for ``sonar`` (a
        sensor's pattern widening their aperture) or an instrument's own ``fan``; the traced
        sonar's range window in true metres (:meth:`true_ranges`)."""
        if fan is None:
            # the image's grid; the rays' aperture
            return self.ray_fan(sonar), sonar, self.true_ranges(self.traced_sonar(sonar))
        return fan, sonar, self.true_ranges(traced if traced is not None else sonar)

    def true_ranges(self, sonar: SonarConfig) -> SonarConfig:
        """``sonar`` with its range window in the water's true metres: a device set to
        ``sonar.sound_speed_m_s`` reports ``c_device t / 2``, so its bin ``[r0, r1)`` holds the
        echoes from ``[r0, r1) * c_water / c_device`` (the same bins, each scaled). Unchanged
        without a ``water:`` section or a device speed, or where the two agree."""
        water = self.scene.water
        if water is None or sonar.sound_speed_m_s is None:
            return sonar
        k = water.speed_m_s / sonar.sound_speed_m_s
        if k == 1.0:
            return sonar
        return replace(sonar, range_min_m=sonar.range_min_m * k, range_max_m=sonar.range_max_m * k)

    def water_speed_m_s(self) -> float:
        """The speed of sound in the scene's water, m/s: ``water:``'s, else the sensor's
        ``sound_speed_m_s``, else 1500."""
        if self.scene.water is not None:
            return self.scene.water.speed_m_s
        return self.scene.sensor.sound_speed_m_s if self.scene.sensor is not None else 1500.0

    def batch_fan(self, fan: RayFan, n_poses: int) -> RayFan:
        """``fan`` repeated ``n_poses`` times along its beams (the rays of a frame of several
        poses, :meth:`trace_poses`); the last two kept (full batches and the last one)."""
        for kept in self._batch_fans:
            if kept[0] is fan and kept[1] == n_poses:
                return kept[2]
        batch = RayFan(np.tile(fan.directions, (n_poses, 1, 1, 1)), np.tile(fan.azimuth_rad, (n_poses, 1)),
                       fan.elevation_rad, np.tile(fan.weight, (n_poses, 1, 1)))
        self._batch_fans = self._batch_fans[-1:] + [(fan, n_poses, batch)]
        return batch

    def trace_poses(self, poses: Any, sonar: SonarConfig | None = None, labels: bool | str = False,
                    fan: RayFan | None = None, traced: SonarConfig | None = None) -> FramePaths | None:
        """The search for several poses in one frame: each pose's direct paths, the frame's grid
        their images side by side (an instrument's pings batched: one cast, one pass of the
        kernels, where a frame per ping spends most of its time around them).

        Parameters
        ----------
        poses : sequence of Pose (or what :meth:`trace` takes as a pose)
            Sonar-to-world, P of them.
        sonar, labels, fan, traced
            As :meth:`trace`.

        Returns
        -------
        FramePaths or None
            Its ``sonar`` the frame's grid: ``n_range_bins`` x ``P n_beams`` beams, pose ``p``'s
            beams the columns ``p n_beams`` to ``(p + 1) n_beams`` (its azimuths name no
            direction); ``poses`` the poses. :meth:`form` makes its image, components and
            labels as for one pose (pose p's columns are bit for bit what :meth:`trace` and
            :meth:`form` give at that pose). None where one frame cannot hold the poses: a pose
            that faces a mirror with ``max_order`` > 1 (its transmit legs come from image
            sources of its own origin), glints, ``double_line_of_sight``, the NumPy twin, poses
            facing different planes: trace each pose then.

        Raises
        ------
        ConfigError
            A pose lies on one of the scene's planes; unknown ``labels``.
        """
        check_labels(labels)
        poses = [as_pose(p) for p in poses]
        render = self.scene.render
        if not poses or self.path_kernels != "compiled" or render.glints or render.double_line_of_sight:
            return None
        t0 = time.perf_counter()
        sonar = sonar if sonar is not None else self.scene.sonar
        fan, image_sonar, sonar = self._cast_fan(sonar, fan, traced)
        origins = np.array([p.translation for p in poses], dtype=float).reshape(-1, 3)
        # Refused before the poses are checked one by one: trace checks them again
        active, multipath, reach = self.frame_reach(sonar, poses[0])
        distance = self.planes.signed_distance(origins)  # (P, planes)
        if multipath or (distance.size and ((distance > 0.0) != active[None, :]).any()):
            return None
        if distance.size:
            near = np.abs(distance).min(axis=1) < ON_PLANE_TOLERANCE_M
            for k in np.flatnonzero(near):
                check_sonar_position(self.scene.reflecting_planes, poses[k].position_m, f"poses[{k}]")
        for p in poses:
            self._warn_if_inside(p.translation, stacklevel=4)
        n = len(poses)
        grid = batch_grid(sonar, image_sonar.n_beams, n)
        batch = self.batch_fan(fan, n)
        spec = None
        if labels:
            spec = self._label_spec(batch, grid, len(self.scene.objects), len(self.scene.reflecting_planes),
                                    labels != "total")
        view = SonarView.of(grid, poses[0], batch)
        rotations = np.ascontiguousarray(np.array([p.rotation for p in poses], dtype=float))
        t1 = time.perf_counter()
        stack, legs, sets, table, total, formed = self._render_paths(grid, view, reach, active, 1, spec,
                                                                     poses=(rotations, origins))
        t2 = time.perf_counter()
        return FramePaths(sonar=grid, traced=grid, pose=poses[0], view=view, stack=stack, legs=legs, sets=sets,
                          table=table, total=total, formed=formed, label_spec=spec, labels=labels, active=active,
                          n_generations=1, reach_m=reach, timing={"t0": t0, "setup": t1 - t0, "render": t2 - t1},
                          poses=tuple(poses))

    def form(self, paths: FramePaths, keep_rays: bool = True, speckle: bool | None = None,
             frame: int | None = None, sensor: SensorModel | bool = True) -> SonarImage:
        """Image formation: a frame's paths (:meth:`trace`) -> the image, its components and labels,
        through the sensor (the second step of :meth:`render`; arguments as there).

        ``sensor``: ``True`` the scene's sensor (if any), ``False`` none (the expected echo),
        or a :class:`~sonarsim.sensor.model.SensorModel` made for the paths' grid (an
        instrument's own chain)."""
        t2 = time.perf_counter()
        render = self.scene.render
        sonar, image_sonar, pose, fan = paths.traced, paths.sonar, paths.pose, paths.fan
        stack, legs, sets, table, total, formed = (paths.stack, paths.legs, paths.sets, paths.table, paths.total,
                                                   paths.formed)
        labels, spec = paths.labels, paths.label_spec
        truth = None
        if labels:
            names = (tuple(o.name for o in self.scene.objects), tuple(p.name for p in self.scene.reflecting_planes))
            label_legs, label_sets = legs, sets
            if sets is None:  # Algorithm 2 forms no paths: the general engine's, for the labels only
                # (the frame's own legs and sets stay None: its signature images are the ground's)
                _, label_legs, label_sets, _, _, formed = self._render_paths(
                    sonar, paths.view, paths.reach_m, paths.active, paths.n_generations, spec)
            if formed is None and callable(label_sets):
                label_sets = label_sets()
            truth = frame_labels(label_sets, label_legs, spec, image_sonar, *names, render.range_splat, self.path_kernels,
                                 formed)
        t3 = time.perf_counter()
        if sets is None:  # ground only: its four images are the four ground-only signatures
            rows = {c.name: stack[c.rows[0]] for c in component_table(render.max_order) if len(c.rows) == 1}
            signatures = functools.partial(ground_signatures, rows)
        else:
            signatures = functools.partial(self._signature_images, sonar, fan, legs, sets, table)
        components = frame_components(stack, render.bounces, render.max_order, signatures, total)
        model = self.sensor_model(image_sonar) if sensor is True else (sensor or None)
        columns = self.ray_columns(paths) if sensor is True and model is not None else None
        if columns is None:
            total = self.sense(components["total"], pose, frame, speckle, model)
        else:
            total = self.sense(columns[0], pose, frame, speckle, model, column_offsets_deg=columns[1])
        rays = None
        if keep_rays:
            primary = legs[0]
            rays = RayMaps(
                distance_m=primary.distance.reshape(fan.shape).astype(np.float32),
                intensity=np.where(primary.sid >= 0, primary.intensity, 0.0).reshape(fan.shape).astype(np.float32),
                surface_id=primary.sid.reshape(fan.shape).astype(np.int16),
                azimuth_deg=np.degrees(fan.azimuth_rad),
                elevation_deg=np.degrees(fan.elevation_rad),
            )
        sonar = image_sonar
        config = {**self._config, "sonar": sonar_section(sonar, pose)}
        t4 = time.perf_counter()
        timing = paths.timing or {}
        self.last_timing = {"setup": timing.get("setup", 0.0), "render": timing.get("render", 0.0),
                            "labels": t3 - t2, "assemble": t4 - t3,
                            "total": t4 - timing.get("t0", t2)}
        return SonarImage(
            polar=total, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg,
            components=components, sonar=sonar, pose=pose, rays=rays, config=config, labels=truth,
        )

    def ray_columns(self, paths: FramePaths) -> tuple[np.ndarray, np.ndarray] | None:
        """A frame's total image, one for each column of its beams' rays, where the sensor's
        azimuth pattern weighs them apart (``render.azimuth_samples`` above 1).

        The pattern then acts on each column at its own angle, so that a point target is heard
        at the pattern's value at its own azimuth, not at its beam's average
        (:meth:`~sonarsim.sensor.model.SensorModel.fold_columns`). Each column's rays are traced
        once more, on their own (the frame's cost once more, in a workspace of their own);
        the components and labels stay the frame's.

        Returns
        -------
        None where nothing is weighed apart (no azimuth pattern, one column, an instrument's
        own rays), else ``(columns, offsets_deg)``: ``(n_range_bins, n_beams, S)`` float32
        totals (their mean the frame's total) and ``(S,)`` each column's angle from its
        beam's centre, degrees.
        """
        model = self.sensor_model(paths.sonar)
        fan = paths.fan
        if (model is None or model.spec.azimuth_pattern is None or fan.shape[1] < 2
                or fan is not self._fans.get(paths.sonar)):
            return None
        n_sub = fan.shape[1]
        if self._column_fans is None or self._column_fans[0] is not fan:
            subs = [RayFan(directions=np.ascontiguousarray(fan.directions[:, s:s + 1]),
                           azimuth_rad=np.ascontiguousarray(fan.azimuth_rad[:, s:s + 1]),
                           elevation_rad=fan.elevation_rad,
                           weight=np.ascontiguousarray(fan.weight[:, s:s + 1] * n_sub)) for s in range(n_sub)]
            centre = np.radians(paths.sonar.azimuth_deg)[:, None]
            offsets = np.degrees(np.median(fan.azimuth_rad - centre, axis=0))
            self._column_fans = (fan, subs, offsets)
        _, subs, offsets = self._column_fans
        render = self.scene.render
        traced = self.traced_sonar(paths.sonar)
        out = np.empty(paths.total.shape + (n_sub,) if paths.total is not None
                       else (paths.sonar.n_range_bins, paths.sonar.n_beams, n_sub), np.float32)
        own, self._work = self._work, self._column_work
        try:
            for s, sub in enumerate(subs):
                p = self.trace(paths.pose, paths.sonar, fan=sub, traced=traced)
                out[..., s] = frame_components(p.stack, render.bounces, render.max_order, None, p.total)["total"]
        finally:
            self._column_work, self._work = self._work, own
        return out, offsets

    def sense(self, total: np.ndarray, pose: Pose, frame: int | None, speckle: bool | None,
              model: SensorModel | None, column_offsets_deg: np.ndarray | None = None) -> np.ndarray:
        """A frame's expected echo through the sensor ``model`` (or, without one, the
        ``render.speckle`` draw): the last step of :meth:`form`, which an instrument that forms
        several poses in one frame (:meth:`trace_poses`) takes pose by pose.

        Parameters
        ----------
        total : (n_range_bins, n_beams) float32 ndarray
            Or ``(n_range_bins, n_beams, S)``, the total of each column of rays apart, with
            ``column_offsets_deg`` (:meth:`ray_columns`).
        pose : Pose
            The frame's (``sensor.speckle.anchor: world`` draws from it).
        frame : int or None
            The frame's index: its draws come from ``(render.seed, frame)``; None: the
            simulator's own generator.
        speckle : bool or None
            ``False``: no draws (the sensor's expected output).
        model : SensorModel or None

        Returns
        -------
        (n_range_bins, n_beams) float32 ndarray
        """
        render = self.scene.render
        if model is None and not (render.speckle and speckle is not False):
            return total  # nothing drawn: no generator made (a few microseconds a ping and side)
        rng = self._rng if frame is None else frame_rng(render.seed, frame)
        if model is not None:
            speckle_rng = rng
            if model.spec.speckle is not None and model.spec.speckle.anchor == "world":
                speckle_rng = model.anchored_rng(pose.position_m, pose.rpy_deg)  # still sonar, still speckle
            return model.apply(total, speckle_rng, speckle is not False, pool=self._pool, noise_rng=rng,
                               warn_saturation=True, column_offsets_deg=column_offsets_deg)
        return (total * rng.exponential(1.0, total.shape)).astype(np.float32)

    def render(self, pose: Any = None, sonar: SonarConfig | None = None, keep_rays: bool = True,
               speckle: bool | None = None, frame: int | None = None, labels: bool | str = False) -> SonarImage:
        """Render one image: :meth:`trace` the frame's paths, then :meth:`form` its image.

        Parameters
        ----------
        pose : Pose, dict or (4, 4) array, optional
            Sonar pose in the world frame (sonar-to-world); default the scene's
            (``scene.sonar_pose``).
        sonar : SonarConfig, optional
            Other intrinsics (beams, elevation aperture, range window); default the scene's.
        keep_rays : bool
            Attach the per-ray maps (D_f, I_f, labels) to the result.
        speckle : bool, optional
            ``False``: no random draws: with a sensor, its expected (mean) output; without,
            the noise-free total. Default: as configured (a sensor draws speckle and noise;
            ``render.speckle``).
        frame : int, optional
            Frame index: the frame's draws come from the generator seeded with
            ``(render.seed, frame)``, so that a frame is the same whoever renders it and in
            whatever order. Default: the simulator's own generator, frame after frame.
            (``sensor.speckle.anchor: world`` draws from the pose instead.)
        labels : bool or {'all', 'total'}
            Attach the frame's ground truth (:class:`~sonarsim.image.labels.Labels`: instance
            maps, elevation per cell, points in view, boxes) as ``labels``. ``True`` or
            ``'all'``: an instance map per component; ``'total'``: of the total only (two thirds
            of the cost on the demo tank; everything else is the same). Labels come from
            the path engine's paths; with ``method: paper`` the image is still Algorithm 2's
            and the path engine runs once more for the labels.

        Returns
        -------
        SonarImage
            With ``sonar`` the intrinsics and ``pose`` the pose rendered.

        Raises
        ------
        ConfigError
            The sonar lies on one of the scene's planes.
        """
        return self.form(self.trace(pose, sonar, labels), keep_rays=keep_rays, speckle=speckle, frame=frame)


def render(scene: Any, pose: Any = None, backend: str = "embree", speckle: bool | None = None,
           frame: int | None = None, labels: bool | str = False) -> SonarImage:
    """Load (if needed) and render a scene once. For many poses, use :class:`Simulator`.

    ``speckle=False``: the expected output, without speckle and noise draws; ``labels=True``:
    with the frame's ground truth (see :meth:`Simulator.render`).
    """
    with Simulator(scene, backend=backend) as sim:
        return sim.render(pose=pose, speckle=speckle, frame=frame, labels=labels)
