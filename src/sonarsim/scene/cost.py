"""What a scene costs to build, estimated from its specs before anything is built.

A :class:`~sonarsim.Simulator` turns every object into world-frame triangles and builds one
ray-tracing structure over them; both grow with the objects and their triangles. Both are
estimated here from the scene (primitives by their tessellation, mesh files by their face count,
already read when the scene was loaded) and checked against the memory budget and the time
budget (:mod:`sonarsim.core.memory`) before the first mesh is made, so that a scene of a
million pebbles is refused in a second, naming ``objects`` and the figures, instead of running
out of memory after an hour.

The rates were measured here (2 cores) on the heaviest cases seen: 20,000 spheres of 1 cm
(6.4 million triangles: 12 s, 135 bytes a triangle), 1,000 overlapping spheres of 10 cm
(5.1 million: 18 s, 131 bytes), 20,000 small boxes (52 microseconds an object).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..config.scene import ObjectSpec, Scene
from ..core.memory import require, require_time
from ..errors import ConfigError
from .meshes import CYLINDER_SECTIONS, cylinder_sections, load_mesh_file, sphere_subdivisions

__all__ = ["BYTES_PER_LEG_RAY", "BYTES_PER_TRIANGLE", "SceneCost", "check_scene_cost", "leg_bytes", "object_triangles",
           "scene_cost"]

#: Memory a mirror's triangle (an object with ``specular`` > 0) takes beyond that, in the path
#: engine's tables (:mod:`sonarsim.paths.facets`: corners, normal, plane, mirror and their sort),
#: and with smooth normals the corners' normals and the pairs that average them (each corner
#: with at most ``paths.facets.MAX_SMOOTH_DEGREE``, 32, faces, 64 bytes a pair).
BYTES_PER_MIRROR_TRIANGLE = 400.0
BYTES_PER_SMOOTH_TRIANGLE = 3 * 32 * 64.0
#: Memory a triangle takes once built: world vertices and faces, Embree's copies and its
#: high-quality BVH (with spatial splits), and the temporaries of the build.
BYTES_PER_TRIANGLE = 200.0
#: Build time of a triangle (Embree's high-quality BVH dominates: 2 to 3.5 microseconds here).
SECONDS_PER_TRIANGLE = 3e-6
#: Build time of a mirror's triangle beyond that (its facet, plane and mirror tables; with smooth
#: normals its corners' normals): 4.8 s for a sphere of 327,680 smooth mirror triangles here
#: with the machine loaded five times over, about 3 microseconds a triangle on a quiet one.
SECONDS_PER_MIRROR_TRIANGLE = 3e-6
#: Build time of an object beyond its triangles (its spec, its mesh placed in the world).
SECONDS_PER_OBJECT = 1e-4
BYTES_PER_OBJECT = 4096.0


#: Memory a ray takes per traced generation of a frame with paths beyond the first bounce
#: (``renderer.compiled.FrameLegs``: range, cosine, intensity, attenuation, surface, chain,
#: key, point, normal, live index: 88 bytes; primitives, texels and the specular returns' 44
#: more), rounded up.
BYTES_PER_LEG_RAY = 150.0
#: Generations that :data:`sonarsim.core.rays.BYTES_PER_RAY` already counts.
LEGS_IN_RAY_BYTES = 3


def leg_bytes(n_rays: int, max_order: int, glints: bool) -> float:
    """Memory of a frame's traced legs beyond what :data:`~sonarsim.core.rays.BYTES_PER_RAY`
    counts: ``max_order`` generations (one more with ``glints``, traced for the specular
    returns), ``BYTES_PER_LEG_RAY`` a ray each.

    Returns
    -------
    float
        Bytes; 0 for a frame of up to ``LEGS_IN_RAY_BYTES`` generations.
    """
    generations = int(max_order) + (1 if glints else 0)
    return float(n_rays) * max(0, generations - LEGS_IN_RAY_BYTES) * BYTES_PER_LEG_RAY


@dataclass(frozen=True)
class SceneCost:
    """Estimated size and build time of a scene.

    Attributes
    ----------
    objects : int
    triangles : int
        Of every object, before clipping at the planes.
    bytes : float
        Memory the built scene holds.
    seconds : float
        Time to build it.
    """

    objects: int
    triangles: int
    bytes: float
    seconds: float


def object_triangles(obj: ObjectSpec) -> int:
    """Triangles of an object's mesh, without building it (a mesh file's are read once and
    cached when the scene is loaded).

    Returns
    -------
    int
    """
    scale = float(np.max(np.abs(np.asarray(obj.scale, dtype=float))))
    if obj.primitive == "box":
        return 12
    if obj.primitive == "sphere":
        return 20 * 4 ** sphere_subdivisions(obj.radius_m * scale)
    if obj.primitive == "cylinder":
        return 4 * min(cylinder_sections(obj.radius_m * scale), CYLINDER_SECTIONS)
    faces = getattr(obj.mesh, "faces", None)  # an in-memory trimesh
    if faces is not None:
        return len(faces)
    return len(load_mesh_file(obj.mesh, texture=obj.backscatter.texture).faces)


def scene_cost(scene: Scene, counts: Sequence[int] | None = None) -> SceneCost:
    """The estimated memory and build time of a scene's objects (see the module's rates).

    Parameters
    ----------
    scene : Scene
    counts : sequence of int, optional
        How many times each object stands in the scene to be built (a scenario's check builds
        one object of each distinct spec); default once each.

    Returns
    -------
    SceneCost
    """
    counts = [1] * len(scene.objects) if counts is None else list(counts)
    n = sum(counts)
    each = [object_triangles(o) for o in scene.objects]
    triangles = sum(c * t for c, t in zip(counts, each))
    # A mirror's triangles also fill the path engine's tables (paths.facets).
    mirrors = sum(c * t * (BYTES_PER_MIRROR_TRIANGLE + (BYTES_PER_SMOOTH_TRIANGLE if o.normals == "smooth" else 0.0))
                  for c, t, o in zip(counts, each, scene.objects) if o.specular > 0)
    mirror_triangles = sum(c * t for c, t, o in zip(counts, each, scene.objects) if o.specular > 0)
    return SceneCost(n, triangles, n * BYTES_PER_OBJECT + triangles * BYTES_PER_TRIANGLE + mirrors,
                     n * SECONDS_PER_OBJECT + triangles * SECONDS_PER_TRIANGLE
                     + mirror_triangles * SECONDS_PER_MIRROR_TRIANGLE)


def check_scene_cost(scene: Scene, key: str = "objects", counts: Sequence[int] | None = None) -> SceneCost:
    """Refuse a scene whose objects would take more than the memory or the time budget to build.

    Parameters
    ----------
    scene : Scene
    key : str
        The key named in the refusal (``objects``; a scenario's variation group).
    counts : sequence of int, optional
        See :func:`scene_cost`.

    Returns
    -------
    SceneCost
        When it fits.

    Raises
    ------
    ConfigError
        Naming ``key``, the objects and triangles, and the estimate against the budget.
    """
    cost = scene_cost(scene, counts)
    what = f"building {cost.objects:,} objects of {cost.triangles:,} triangles"
    try:
        require(cost.bytes, what, key)
        require_time(cost.seconds, what, key)
    except ConfigError as exc:
        raise ConfigError(exc.key, exc.detail, scene.source) from None
    return cost
