"""What the 3D view draws, as plain arrays: the sonar's field of view, finite plane quads.

Everything is in metres. The field of view is in the sonar frame of DESIGN.md section 1
(x forward, y left, z up; positive azimuth to the left, positive elevation up), so that the
viewer hangs it under the sonar's node and moving the sonar moves it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ...config.scene import PlaneSpec
from ...config.sonar import SonarConfig

__all__ = ["clip_polygon", "fov_directions", "fov_segments", "fov_surface", "plane_face", "plane_quad", "scene_extent"]

# Points per arc of the drawn field of view: smooth at a glance, a few hundred segments in all.
ARC_POINTS = 24


def fov_directions(azimuth_deg: np.ndarray, elevation_deg: np.ndarray) -> np.ndarray:
    """Unit vectors in the sonar frame for azimuth/elevation pairs (broadcast together).

    Parameters
    ----------
    azimuth_deg, elevation_deg : array_like, degrees
        Positive azimuth = the sonar's left (+y), positive elevation = up (+z).

    Returns
    -------
    (..., 3) float64 ndarray
    """
    a = np.radians(np.asarray(azimuth_deg, dtype=float))
    e = np.radians(np.asarray(elevation_deg, dtype=float))
    a, e = np.broadcast_arrays(a, e)
    return np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1)


def _limits(sonar: SonarConfig) -> tuple[float, float, float, float, float, float]:
    grid = sonar.grid
    half_el = sonar.elevation_fov_deg / 2.0
    return (grid.range_min_m, grid.range_max_m, grid.right_edge_deg, grid.left_edge_deg, -half_el, half_el)


def fov_segments(sonar: SonarConfig, arc_points: int = ARC_POINTS) -> np.ndarray:
    """Line segments outlining the sonar's field of view (its frustum) in the sonar frame.

    The volume is the range window ``[range_min, range_max]`` times the azimuth span between
    the outer beam edges times the elevation aperture: four edge rays from the near to the far
    range, and at both ranges the arcs along azimuth (top and bottom) and along elevation
    (left and right sides).

    Parameters
    ----------
    sonar : SonarConfig
    arc_points : int
        Points per arc (>= 2).

    Returns
    -------
    (n_segments, 2, 3) float64 ndarray, metres
    """
    r0, r1, right, left, low, high = _limits(sonar)
    segments = []
    # The four edge rays, near range to far range.
    for az in (left, right):
        for el in (low, high):
            d = fov_directions(az, el)
            segments.append(np.stack([r0 * d, r1 * d])[None])
    az = np.linspace(right, left, arc_points)
    el = np.linspace(low, high, arc_points)
    for r in (r0, r1):
        for e in (low, high):  # top and bottom arcs
            p = r * fov_directions(az, e)
            segments.append(np.stack([p[:-1], p[1:]], axis=1))
        for a in (left, right):  # the sides
            p = r * fov_directions(a, el)
            segments.append(np.stack([p[:-1], p[1:]], axis=1))
    return np.concatenate(segments, axis=0)


def fov_surface(sonar: SonarConfig, arc_points: int = ARC_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The far cap of the field of view as a triangle mesh (the sector the sonar sees at range_max).

    Returns
    -------
    vertices : (arc_points ** 2, 3) float64 ndarray, metres, in the sonar frame
    faces : (2 (arc_points - 1) ** 2, 3) int32 ndarray
    """
    _, r1, right, left, low, high = _limits(sonar)
    az, el = np.meshgrid(np.linspace(right, left, arc_points), np.linspace(low, high, arc_points), indexing="ij")
    vertices = r1 * fov_directions(az, el).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(arc_points - 1), np.arange(arc_points - 1), indexing="ij")
    k = (i * arc_points + j).ravel()
    faces = np.concatenate([np.stack([k, k + arc_points, k + 1], axis=1),
                            np.stack([k + 1, k + arc_points, k + arc_points + 1], axis=1)])
    return vertices, faces.astype(np.int32)


def scene_extent(points_m: Sequence[np.ndarray] | np.ndarray, margin_m: float) -> tuple[np.ndarray, float]:
    """Centre and half-size of a box around points, with a margin: where to draw the planes.

    Parameters
    ----------
    points_m : (n, 3) array_like, metres
    margin_m : float

    Returns
    -------
    centre : (3,) float64 ndarray
    half_size_m : float
        Half the largest side of the bounding box, plus ``margin_m``.
    """
    p = np.asarray(points_m, dtype=float).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return (lo + hi) / 2.0, float((hi - lo).max() / 2.0 + margin_m)


def plane_quad(plane: PlaneSpec, centre_m: np.ndarray, half_size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """An infinite plane drawn as a finite square, centred on a point's projection onto it.

    The square's sides follow the plane's horizontal direction (for a wall) or the world's x
    and y (for a floor or a water surface), so that walls stand upright and floors line up
    with the axes.

    Parameters
    ----------
    plane : PlaneSpec
    centre_m : (3,) array_like, metres
        The square is centred on this point's orthogonal projection onto the plane.
    half_size_m : float
        Half the side of the square, metres.

    Returns
    -------
    vertices : (4, 3) float64 ndarray, metres, in the world frame
    faces : (2, 3) int32 ndarray
        Wound counter-clockwise seen from the water side (the side the normal points to).
    """
    n = np.asarray(plane.normal, dtype=float)
    c = np.asarray(centre_m, dtype=float)
    c = c - (c @ n - plane.offset_m) * n
    # u: horizontal in the plane when the plane is not horizontal, else the world's x.
    u = np.cross([0.0, 0.0, 1.0], n)
    if np.linalg.norm(u) < 1e-6:
        u = np.array([1.0, 0.0, 0.0]) - n[0] * n
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    h = float(half_size_m)
    vertices = np.stack([c - h * u - h * v, c + h * u - h * v, c + h * u + h * v, c - h * u + h * v])
    faces = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    return vertices, faces


def clip_polygon(vertices: np.ndarray, plane: PlaneSpec) -> np.ndarray:
    """The part of a convex polygon on a plane's water side (where its normal points).

    Parameters
    ----------
    vertices : (n, 3) array_like, metres
        The polygon's corners in order.
    plane : PlaneSpec

    Returns
    -------
    (m, 3) float64 ndarray
        The clipped polygon's corners in the same order (``m`` may be 0).
    """
    v = np.asarray(vertices, dtype=float)
    if len(v) == 0:
        return v.reshape(0, 3)
    d = plane.signed_distance_m(v)
    out = []
    for i in range(len(v)):  # Sutherland-Hodgman against one plane: a handful of corners
        j = (i + 1) % len(v)
        if d[i] >= 0:
            out.append(v[i])
        if (d[i] >= 0) != (d[j] >= 0):
            t = d[i] / (d[i] - d[j])
            out.append(v[i] + t * (v[j] - v[i]))
    return np.asarray(out, dtype=float).reshape(-1, 3)


def plane_face(plane: PlaneSpec, others: Sequence[PlaneSpec], centre_m: np.ndarray,
               half_size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A plane drawn as the part of its square (:func:`plane_quad`) on the water side of the
    other planes: a tank's floor, walls and surface meet at their edges instead of crossing.

    Falls back to the whole square when the other planes leave nothing of it.

    Returns
    -------
    vertices : (n, 3) float64 ndarray, metres
    faces : (n - 2, 3) int32 ndarray
        A fan over the convex polygon, counter-clockwise seen from the water.
    """
    quad, faces = plane_quad(plane, centre_m, half_size_m)
    polygon = quad
    for other in others:
        if other is not plane:
            polygon = clip_polygon(polygon, other)
    if len(polygon) < 3:
        return quad, faces
    k = np.arange(1, len(polygon) - 1)
    return polygon, np.stack([np.zeros_like(k), k, k + 1], axis=1).astype(np.int32)
