"""The renderer: a :class:`Simulator` holds the acceleration structure and renders poses.

Pipeline per frame: rays of the sonar (cached per sonar) -> rotate to the pose -> closest
surfaces (Embree + analytic ground) -> per-ray intensities (D_f, I_f) -> polar images per
component (one bincount) -> ground echoes -> :class:`SonarImage`.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np

from ..config.loader import load_scene, parse_pose
from ..config.scene import Scene
from ..config.sonar import SonarConfig
from ..core.memory import keep_freed_memory
from ..core.radiometry import lambertian_intensity
from ..core.rays import RayFan, make_ray_fan
from ..core.transforms import Pose
from ..errors import ConfigError
from ..image.result import RayMaps, SonarImage
from ..paths.algorithm2 import fast_mirror_paths, ground_echo_rays, render_paper, sonar_above_ground
from ..scene.meshes import clip_above_plane, mirror_across_plane, object_mesh_world
from ..trace import available_cores, make_caster
from ..trace.surfaces import GROUND_ID, trace
from . import compiled
from .components import COMPONENTS, assemble
from .formation import RayEnergy, accumulate, continuity

# Rays are cast this far past the range window so that range splatting sees the neighbour of a
# ray that ends just inside it.
RANGE_MARGIN = 1.25

# Unfolded ground-echo paths OA' matter up to 2 * range_max - range_min (cases 2/3 land at
# (OA + OA') / 2 with OA >= range_min); cast that far when there is multipath to form.
MULTIPATH_REACH = 2.0


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


class Simulator:
    """Renders a scene from many sonar poses, building the acceleration structure once.

    Parameters
    ----------
    scene : Scene, mapping or path
        Anything :func:`sonarsim.load_scene` accepts.
    backend : {'embree', 'numpy'}
        Ray-casting engine; ``numpy`` is a slow reference for tests.
    kernels : {'compiled', 'numpy'}
        Per-ray arithmetic of the default (fast) method: compiled loops, or the NumPy reference
        they are tested against. ``compiled`` falls back to ``numpy`` (with a warning) when the
        extension is not built.

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
        self.scene: Scene = load_scene(scene)
        self.backend = backend
        self.meshes = [object_mesh_world(o) for o in self.scene.objects]
        if self.scene.ground is not None:
            # Nothing below the floor can be seen; removing it (and faces lying on the floor)
            # keeps mirror geometry and coincident faces from making echoes.
            self.meshes = [clip_above_plane(m, self.scene.ground.height_m) for m in self.meshes]
        self.caster = make_caster(backend, self.meshes, self.scene.render.threads)
        self._mirrored_caster = None
        threads = self.scene.render.threads or available_cores()
        # One worker: the second core of the compiled path (tasks run in order on it).
        self._pool = ThreadPoolExecutor(1) if threads > 1 else None
        ground_albedo = self.scene.ground.albedo if self.scene.ground is not None else 0.0
        # Albedo by surface id + 1: index 0 is "no hit", 1 the ground, k + 2 object k.
        self._albedo = np.array([0.0, ground_albedo] + [o.albedo for o in self.scene.objects])
        self._rng = np.random.default_rng(self.scene.render.seed)  # speckle, frame after frame
        self._fans: dict[SonarConfig, RayFan] = {}
        self._last_fan: tuple[SonarConfig, RayFan] | None = None
        self.last_timing: dict[str, float] = {}

    def close(self) -> None:
        """Stop the worker threads now (they also stop when the simulator is collected)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        for caster in (self.caster, self._mirrored_caster):
            if hasattr(caster, "close"):
                caster.close()

    def __enter__(self) -> "Simulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def ray_fan(self, sonar: SonarConfig) -> RayFan:
        """The (cached) rays of a sonar in its own frame."""
        if self._last_fan is not None and self._last_fan[0] is sonar:
            return self._last_fan[1]
        key = replace(sonar, pose=Pose())
        fan = self._fans.get(key)
        if fan is None:
            fan = make_ray_fan(sonar, self.scene.render)
            self._fans = {key: fan}  # one sonar at a time is the common case; keep memory flat
        self._last_fan = (sonar, fan)
        return fan

    def mirrored_caster(self):
        """Objects followed by their mirror images (``method: paper`` only), built on first use."""
        if self._mirrored_caster is None:
            h = self.scene.ground.height_m
            mirrored = self.meshes + [mirror_across_plane(m, h) for m in self.meshes]
            self._mirrored_caster = make_caster(self.backend, mirrored, self.scene.render.threads)
        return self._mirrored_caster

    def _intensity(self, fan: RayFan, hits) -> np.ndarray:
        albedo = self._albedo[hits.surface_id + 1]
        return lambertian_intensity(fan.weight, hits.cos_incidence, albedo, hits.distance_m, self.scene.render.tvg)

    # The three ways to form the images; each returns (images by name, (D_f, I_f, surface ids)).

    def _render_paper(self, sonar: SonarConfig, fan: RayFan, reach: float):
        """``method: paper``: Algorithm 2 literally (NumPy)."""
        origin, directions = sonar.pose.translation, fan.directions @ sonar.pose.rotation.T
        hits = trace(self.caster, origin, directions, self.scene.ground, reach)
        images = render_paper(
            self.caster, self.mirrored_caster(), origin, directions, sonar, self.scene.render, self.scene.ground,
            fan.weight, self._albedo, len(self.meshes), reach,
        )
        return images, (hits.distance_m, self._intensity(fan, hits), hits.surface_id)

    def _render_compiled(self, sonar: SonarConfig, fan: RayFan, reach: float, multipath: bool):
        """``method: fast`` with the compiled kernels (the default)."""
        if self._work is None or self._work.n != fan.n_rays:
            self._work = compiled.Workspace(fan.n_rays, sonar.n_beams, fan.n_rays // sonar.n_beams)
        shape = (sonar.n_range_bins, sonar.n_beams)
        out = np.zeros((4,) + shape, dtype=np.float32)  # fresh: the components are views of it
        render = self.scene.render
        compiled.render_fast(
            self.caster, sonar, fan, self.scene.ground, render, self._albedo, reach, multipath, self._work, out,
            pool=self._pool,
        )
        images = dict(zip(("object", "ground", "double", "triple"), out))
        images["single"], images["total"] = np.empty(shape, np.float32), np.empty(shape, np.float32)
        b = render.bounces
        compiled.combine(out, images["single"], images["total"], 1 in b, 2 in b, 3 in b)
        w = self._work
        return images, (w.dist.reshape(fan.shape), w.intensity.reshape(fan.shape), w.sid.reshape(fan.shape))

    def _render_numpy(self, sonar: SonarConfig, fan: RayFan, reach: float, multipath: bool):
        """``method: fast`` with the NumPy reference of the compiled kernels."""
        origin, directions = sonar.pose.translation, fan.directions @ sonar.pose.rotation.T
        render, ground = self.scene.render, self.scene.ground
        hits = trace(self.caster, origin, directions, ground, reach)
        intensity = self._intensity(fan, hits)
        cont = continuity(hits.point, hits.normal, hits.surface_id) if render.range_splat else None
        # Labels: 0 object, 1 ground, 2 double, 3 triple; -1 nothing.
        label = np.where(hits.surface_id > GROUND_ID, 0, np.where(hits.surface_id == GROUND_ID, 1, -1))
        rays = [RayEnergy(hits.distance_m, intensity, np.arange(sonar.n_beams)[:, None, None], label, cont)]
        if multipath:
            paths = fast_mirror_paths(
                self.caster, origin, directions, hits, ground.height_m, fan.weight, self._albedo, render.tvg, reach,
            )
            rays += ground_echo_rays(paths, sonar, render, ground.specular, self.caster, labels=(2, 3))
        img = accumulate(
            rays, sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams, n_labels=4
        )
        return dict(zip(("object", "ground", "double", "triple"), img)), (hits.distance_m, intensity, hits.surface_id)

    def render(self, pose: Any = None, sonar: SonarConfig | None = None, keep_rays: bool = True) -> SonarImage:
        """Render one image.

        Parameters
        ----------
        pose : Pose, dict or (4, 4) array, optional
            Sonar pose in the world frame; default the scene's.
        sonar : SonarConfig, optional
            Another sonar (its pose is used unless ``pose`` is given); default the scene's.
        keep_rays : bool
            Attach the per-ray maps (D_f, I_f, labels) to the result.
        """
        t0 = time.perf_counter()
        sonar = sonar if sonar is not None else self.scene.sonar
        if pose is not None:
            sonar = sonar.with_pose(as_pose(pose))
        render = self.scene.render
        fan = self.ray_fan(sonar)
        t1 = time.perf_counter()
        ground = self.scene.ground
        multipath = sonar_above_ground(sonar, ground) and ground.specular > 0
        reach = sonar.range_max_m * RANGE_MARGIN * (MULTIPATH_REACH if multipath else 1.0)
        if render.method == "paper" and multipath:
            images, primary = self._render_paper(sonar, fan, reach)
        elif self.kernels == "compiled":
            images, primary = self._render_compiled(sonar, fan, reach, multipath)
        else:
            images, primary = self._render_numpy(sonar, fan, reach, multipath)
        t3 = time.perf_counter()
        if "total" not in images:
            images = assemble(images, render.bounces)
        components = {k: images[k] for k in COMPONENTS}
        total = components["total"]
        if render.speckle:
            total = (total * self._rng.exponential(1.0, total.shape)).astype(np.float32)
        rays = None
        if keep_rays:
            rays = RayMaps(
                distance_m=primary[0].astype(np.float32),
                intensity=primary[1].astype(np.float32),
                surface_id=primary[2].astype(np.int16),
                azimuth_deg=np.degrees(fan.azimuth_rad),
                elevation_deg=np.degrees(fan.elevation_rad),
            )
        config = replace(self.scene, sonar=sonar).to_dict()
        t4 = time.perf_counter()
        self.last_timing = {"setup": t1 - t0, "render": t3 - t1, "assemble": t4 - t3, "total": t4 - t0}
        return SonarImage(
            polar=total, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg,
            components=components, sonar=sonar, rays=rays, config=config,
        )


def render(scene: Any, pose: Any = None, backend: str = "embree") -> SonarImage:
    """Load (if needed) and render a scene once. For many poses, use :class:`Simulator`."""
    return Simulator(scene, backend=backend).render(pose=pose)
