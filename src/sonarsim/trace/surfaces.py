"""Closest surfaces along rays: the scene's meshes (through a ray caster) and the ground plane.

This is the tracing of the paper's literal Algorithm 2 (:mod:`sonarsim.reference.algorithm2`), the
ground-only reference; the renderer's general path engine meets any planes itself
(:func:`sonarsim.paths.engine.trace_legs`).

The ground is intersected analytically, never as triangles: exact at any distance, no float32
trouble with huge triangles, and the multipath code needs the plane itself anyway.
Surface ids: -1 nothing, 0 the ground, ``k + 1`` the scene's object ``k``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import RayCaster
from ..config.scene import PlaneSpec

GROUND_ID = 0
NO_HIT = -1


@dataclass(frozen=True)
class SurfaceHits:
    """Closest hits of rays shaped ``(...)``.

    Attributes
    ----------
    distance_m : (...) float64 ndarray
        Distance to the hit, metres; ``inf`` for none.
    surface_id : (...) int32 ndarray
        -1 none, 0 ground, k + 1 object k.
    point : (..., 3) float32 ndarray
        Hit point in the world frame, metres (NaN for none).
    normal : (..., 3) float32 ndarray
        Unit normal of the surface hit (0 for none).
    cos_incidence : (...) float32 ndarray
        ``|n . d|``: cosine of the angle between the ray and the normal (0 for none).
    texel : (...) float32 ndarray or None
        Texture brightness at object hits (1 elsewhere); None: no textures (see
        :attr:`sonarsim.trace.base.Hits.texel`).
    """

    distance_m: np.ndarray
    surface_id: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    cos_incidence: np.ndarray
    texel: np.ndarray | None = None


def ground_distance(origins: np.ndarray, directions: np.ndarray, height_m: float) -> np.ndarray:
    """Distance along each ray to the plane ``z = height_m``, seen from above only.

    Parameters
    ----------
    origins : (..., 3) float array, metres
    directions : (..., 3) float array, unit vectors

    Returns
    -------
    (...) float64 ndarray, metres; ``inf`` where the ray does not go down onto the plane from
    above (a source below the floor sees no floor).
    """
    oz = np.asarray(origins, dtype=float)[..., 2]
    dz = np.asarray(directions, dtype=float)[..., 2]
    above = oz > height_m
    down = dz < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (height_m - oz) / dz
    return np.where(above & down & (t > 0), t, np.inf)


def trace(
    caster: RayCaster,
    origins: np.ndarray,
    directions: np.ndarray,
    ground: PlaneSpec | None,
    max_distance_m: float,
) -> SurfaceHits:
    """Closest surface along each ray, objects and ground together.

    Parameters
    ----------
    caster : RayCaster
        Built over the objects' meshes (mesh k = object k).
    origins : (3,) or (..., 3) float array, metres
    directions : (..., 3) float array, unit vectors
    ground : PlaneSpec or None
        The ground (``Scene.ground``: horizontal, normal +z), or none.
    max_distance_m : float
        Hits further away count as none.
    """
    d = np.asarray(directions)
    shape = d.shape[:-1]
    o = np.asarray(origins, dtype=float)
    hits = caster.intersect(np.broadcast_to(o, d.shape).reshape(-1, 3), d.reshape(-1, 3), max_distance_m)
    dist = hits.distance.astype(float).reshape(shape)
    sid = hits.mesh_id.reshape(shape) + np.int32(1)  # -1 (none) becomes 0: fixed below
    sid[sid == 0] = NO_HIT
    normal = hits.normal.reshape(shape + (3,))
    texel = None if hits.texel is None else hits.texel.reshape(shape).copy()
    if ground is not None:
        if tuple(ground.normal) != (0.0, 0.0, 1.0):
            raise ValueError(f"the ground must be horizontal (normal +z), got normal {ground.normal}")
        tg = ground_distance(o, d, ground.offset_m)  # (normal +z: its offset is its height)
        on_ground = (tg < dist) & (tg <= max_distance_m)
        dist[on_ground] = tg[on_ground]
        sid[on_ground] = GROUND_ID
        normal[on_ground] = (0.0, 0.0, 1.0)
        if texel is not None:
            texel[on_ground] = 1.0
    hit = sid != NO_HIT
    # Points in float32, like the ray caster: 0.3 micrometres at 5 m.
    point = (o + d * np.where(hit, dist, 0.0)[..., None]).astype(np.float32)
    point[~hit] = np.nan
    cos_inc = np.abs(np.einsum("...k,...k->...", normal, d.astype(np.float32, copy=False)))
    return SurfaceHits(distance_m=dist, surface_id=sid, point=point, normal=normal, cos_incidence=cos_inc, texel=texel)
