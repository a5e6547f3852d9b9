"""What the 3D view draws, as plain arrays: the sonar's field of view, the fans of a vehicle's
instruments, finite plane quads.

Everything is in metres. The field of view is in the sonar frame of DESIGN.md section 1
(x forward, y left, z up; positive azimuth to the left, positive elevation up), so that the
viewer hangs it under the sonar's node and moving the sonar moves it. A vehicle's instruments
(:func:`instrument_fans`) have one fan per channel, each in its channel's frame, hung under the
vehicle's node at the channel's mount (the instrument's mount times the channel's own rotation):
moving the vehicle moves them all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...config.scene import PlaneSpec
from ...config.sonar import SonarConfig
from ...core.transforms import Pose

__all__ = ["FanLimits", "InstrumentFan", "clip_polygon", "cone_directions", "fan_corners", "fan_limits",
           "fan_segments", "fan_surface", "fov_directions", "fov_segments", "fov_surface", "instrument_fans",
           "plane_face", "plane_quad", "scene_extent", "to_world"]

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


@dataclass(frozen=True)
class FanLimits:
    """The volume a fan covers, in its channel's frame: a range window times an angular span.

    Attributes
    ----------
    range_min_m, range_max_m : float
        The range window, metres.
    right_deg, left_deg : float
        Azimuth of the outer beam edges, degrees (left > 0, to the channel's +y).
    low_deg, high_deg : float
        Elevation of the aperture's edges, degrees (up > 0, to the channel's +z).
    cone : bool
        A cone about the channel's x axis instead (a single-beam's): its half angle is
        ``left_deg`` (and ``high_deg``); ``right_deg`` and ``low_deg`` are its negatives.
    """

    range_min_m: float
    range_max_m: float
    right_deg: float
    left_deg: float
    low_deg: float
    high_deg: float
    cone: bool = False

    @classmethod
    def of_sonar(cls, sonar: SonarConfig) -> "FanLimits":
        """A sonar's beams edge to edge times its elevation aperture, over its range window."""
        return cls(*_limits(sonar))


def fan_segments(limits: FanLimits, arc_points: int = ARC_POINTS) -> np.ndarray:
    """Line segments outlining a fan (its frustum, or its cone) in the channel's frame.

    A frustum: four edge rays from the near to the far range, and at both ranges the arcs
    along azimuth (top and bottom) and along elevation (left and right sides). A cone: eight
    edge rays at 45 degree steps about the axis and the rims at both ranges.

    Parameters
    ----------
    limits : FanLimits
    arc_points : int
        Points per arc (>= 2).

    Returns
    -------
    (n_segments, 2, 3) float64 ndarray, metres
    """
    r0, r1 = limits.range_min_m, limits.range_max_m
    segments = []
    if limits.cone:
        half = limits.left_deg
        for d in cone_directions(half, np.arange(8) * 45.0):
            segments.append(np.stack([r0 * d, r1 * d])[None])
        # From +z round: the points are symmetric about the x-z plane, so that a mirrored
        # scene draws the mirrored points.
        rim = cone_directions(half, np.linspace(90.0, 450.0, 4 * arc_points))
        for r in (r0, r1):
            if r > 0:
                p = r * rim
                segments.append(np.stack([p[:-1], p[1:]], axis=1))
        return np.concatenate(segments, axis=0)
    right, left, low, high = limits.right_deg, limits.left_deg, limits.low_deg, limits.high_deg
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


def fan_surface(limits: FanLimits, arc_points: int = ARC_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A fan's far cap as a triangle mesh (the surface it sees at ``range_max_m``).

    Returns
    -------
    vertices : (arc_points ** 2, 3) float64 ndarray, metres, in the channel's frame
    faces : (2 (arc_points - 1) ** 2, 3) int32 ndarray
    """
    r1 = limits.range_max_m
    if limits.cone:
        # Polar grid: angle from the axis (0 .. half) times the turn about it.
        alpha, phi = np.meshgrid(np.linspace(0.0, limits.left_deg, arc_points),
                                 np.linspace(90.0, 450.0, arc_points), indexing="ij")
        vertices = r1 * cone_directions(alpha, phi).reshape(-1, 3)
    else:
        az, el = np.meshgrid(np.linspace(limits.right_deg, limits.left_deg, arc_points),
                             np.linspace(limits.low_deg, limits.high_deg, arc_points), indexing="ij")
        vertices = r1 * fov_directions(az, el).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(arc_points - 1), np.arange(arc_points - 1), indexing="ij")
    k = (i * arc_points + j).ravel()
    faces = np.concatenate([np.stack([k, k + arc_points, k + 1], axis=1),
                            np.stack([k + 1, k + arc_points, k + arc_points + 1], axis=1)])
    return vertices, faces.astype(np.int32)


def fan_corners(limits: FanLimits) -> np.ndarray:
    """A fan's corners in the channel's frame: the ends of its edge rays.

    Returns
    -------
    (2, 2, 2, 3) float64 ndarray, metres
        ``[range, side, edge]``: range 0 near (``range_min_m``), 1 far; side 0 left (the
        larger azimuth), 1 right; edge 0 low (the lower elevation), 1 high. A cone's are the
        rays of its rim midway between +y (left), -y, -z (low) and +z: 45 degrees about the
        axis from each.
    """
    out = np.empty((2, 2, 2, 3))
    for i, r in enumerate((limits.range_min_m, limits.range_max_m)):
        for j, az in enumerate((limits.left_deg, limits.right_deg)):
            for k, el in enumerate((limits.low_deg, limits.high_deg)):
                if limits.cone:
                    # A cone has no corners: the rim's rays midway between its sides and edges.
                    d = cone_directions(limits.left_deg, ((315.0, 45.0), (225.0, 135.0))[j][k])
                else:
                    d = fov_directions(az, el)
                out[i, j, k] = r * d
    return out


def cone_directions(alpha_deg, phi_deg) -> np.ndarray:
    """Unit vectors at ``alpha_deg`` from the x axis, turned ``phi_deg`` about it from +y
    towards +z (broadcast together).

    Returns
    -------
    (..., 3) float64 ndarray
    """
    a = np.radians(np.asarray(alpha_deg, dtype=float))
    f = np.radians(np.asarray(phi_deg, dtype=float))
    a, f = np.broadcast_arrays(a, f)
    return np.stack([np.cos(a), np.sin(a) * np.cos(f), np.sin(a) * np.sin(f)], axis=-1)


def to_world(pose: Pose, points_m: np.ndarray) -> np.ndarray:
    """Points in a frame at ``pose`` (frame-to-world) in world coordinates, same shape."""
    p = np.asarray(points_m, dtype=float)
    return p @ pose.rotation.T + pose.translation


def fov_segments(sonar: SonarConfig, arc_points: int = ARC_POINTS) -> np.ndarray:
    """Line segments outlining the sonar's field of view (its frustum) in the sonar frame.

    The volume is the range window ``[range_min, range_max]`` times the azimuth span between
    the outer beam edges times the elevation aperture (:func:`fan_segments`).

    Parameters
    ----------
    sonar : SonarConfig
    arc_points : int
        Points per arc (>= 2).

    Returns
    -------
    (n_segments, 2, 3) float64 ndarray, metres
    """
    return fan_segments(FanLimits.of_sonar(sonar), arc_points)


def fov_surface(sonar: SonarConfig, arc_points: int = ARC_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """The far cap of the field of view as a triangle mesh (the sector the sonar sees at range_max).

    Returns
    -------
    vertices : (arc_points ** 2, 3) float64 ndarray, metres, in the sonar frame
    faces : (2 (arc_points - 1) ** 2, 3) int32 ndarray
    """
    return fan_surface(FanLimits.of_sonar(sonar), arc_points)


def fan_limits(spec, channel) -> FanLimits:
    """What the viewer draws of an instrument's channel.

    An FLS's, a multibeam's (and an unknown type's) fan is its channel's rays: the beams edge
    to edge times the elevation aperture. A side-scan's and a scanning sonar's channel casts
    rays well beyond its beam (from nadir up past the horizontal, weighed by the vertical
    pattern, so that side lobes reach nadir): the drawn fan is the main lobe, the beam's
    width along track times ``vertical_beam_width_deg`` (-3 dB) about its axis. A single-beam
    echo sounder's is the cone of its -3 dB width (``beam_width_deg``).

    Parameters
    ----------
    spec : InstrumentSpec
    channel : Channel
        One of ``spec.channels()``.
    """
    grid = channel.sonar.grid
    r0, r1 = grid.range_min_m, grid.range_max_m
    if spec.type_name == "singlebeam":
        half = float(spec.beam_width_deg) / 2.0
        return FanLimits(r0, r1, -half, half, -half, half, cone=True)
    vertical = getattr(spec, "vertical_beam_width_deg", None)
    horizontal = getattr(spec, "horizontal_beam_width_deg", None)
    if spec.type_name in ("sidescan", "scanning") and vertical is not None and horizontal is not None:
        # The device's widths: the channel's one-beam grid has a nominal 1 deg between its
        # edges whatever the beam (its rays are one column at azimuth 0).
        half, side = float(vertical) / 2.0, float(horizontal) / 2.0
        return FanLimits(r0, r1, -side, side, -half, half)
    return FanLimits.of_sonar(channel.sonar)


@dataclass(frozen=True)
class InstrumentFan:
    """One channel's fan on the vehicle: what the viewer hangs under the vehicle's node.

    Attributes
    ----------
    instrument, type_name, channel : str
        The instrument's name and type, the channel's name (``port``, ``starboard``, ...).
    index : int
        The instrument's position in the scene (its colour).
    mount : Pose
        The channel's pose in the vehicle's frame (the instrument's mount times the channel's
        own rotation).
    limits : FanLimits
        In the channel's frame.
    """

    instrument: str
    type_name: str
    channel: str
    index: int
    mount: Pose
    limits: FanLimits

    @property
    def name(self) -> str:
        """``instrument/channel``."""
        return f"{self.instrument}/{self.channel}"

    def world_pose(self, vehicle: Pose) -> Pose:
        """The channel's pose in the world for the vehicle at ``vehicle`` (vehicle-to-world)."""
        return Pose.from_matrix(vehicle.matrix() @ self.mount.matrix())

    def segments(self, vehicle: Pose | None = None, arc_points: int = ARC_POINTS) -> np.ndarray:
        """The outline (:func:`fan_segments`): in the channel's frame, or in the world for the
        vehicle at ``vehicle``; ``(n_segments, 2, 3)``, metres."""
        seg = fan_segments(self.limits, arc_points)
        return seg if vehicle is None else to_world(self.world_pose(vehicle), seg)

    def corners(self, vehicle: Pose | None = None) -> np.ndarray:
        """The corners (:func:`fan_corners`), in the channel's frame or in the world; ``(2, 2, 2, 3)``."""
        c = fan_corners(self.limits)
        return c if vehicle is None else to_world(self.world_pose(vehicle), c)


def instrument_fans(instruments: Sequence) -> tuple[InstrumentFan, ...]:
    """Every channel's fan of a scene's instruments (``Scene.instruments``), in their order.

    A scanning sonar's is its head at step 0 (every step's fan is this one, turned about the
    mount's z).
    """
    out = []
    for k, spec in enumerate(instruments):
        for channel in spec.channels():
            out.append(InstrumentFan(spec.name, spec.type_name, channel.name, k, channel.mount,
                                     fan_limits(spec, channel)))
    return tuple(out)


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
