"""Paths of any order over any set of reflecting planes: receive legs traced, transmit legs by image sources.

A path is: transmit leg (sonar O -> planes ... -> scatterer A), one diffuse scatter at A (an
object, or a plane's diffuse part), receive leg (A -> planes ... -> O). Its order is the number
of surface interactions: the planes met on both legs plus the scatter.

* **Receive legs** are traced: each of the beam's rays goes out from O, and wherever it meets a
  plane it both scatters (the plane's diffuse part) and, with the plane's specular
  reflectance, reflects and goes on (:func:`trace_legs`). Generation ``g`` of the tracing holds
  the scatterers reached after ``g`` reflections, one per ray at most.
* **Transmit legs** come from image sources (:mod:`sonarsim.paths.planes`): for a scatterer A
  and a chain of planes, the leg leaves O towards ``A*`` (A unfolded by the chain's mirrors),
  is ``|A* - O|`` long, is valid when every reflection point lies on its plane inside the
  water, and must leave O inside the transmit aperture (the sonar's fan and elevation
  aperture) with a length inside the range window, as the paper requires of A for its cases
  2/3. Only chains that some receive ray followed this frame, or that rays along the edges of
  the aperture follow (:func:`probe_chains`), are tried: a chain that none of them followed
  leaves the sonar inside the aperture only within a region narrower than the ray spacing.
* A path is recorded at half its total length, in the beam of the ray it arrives along,
  weighted by the product of the specular reflectances of both legs times the diffuse
  weight of that ray at A (``beta l(r) rho cos(alpha) cos(phi) dphi``, r the receive leg's length).

When both legs follow the same chain, the transmit leg is the receive leg reversed (the path
O-G-A-G-O of the paper): its length and validity are the ray's own. Legs on different chains
come in reciprocal pairs (O-G-A-O and O-A-G-O, the paper's cases 2 and 3); how they are recorded
is ``render.double_beam`` (see :class:`~sonarsim.scene.RenderSettings`). The default,
``coherent``, forms each path of the pair from its own receive ray and, where both arrive in
one beam, doubles each: the two paths have one length, so their amplitudes add and the pair
returns ``|a + a|^2 = 4 |a|^2``, four times one path's intensity (two independent paths, at
random phases, return 2x: ``separate``). ``paper`` (the default of ``method: paper``) records
each pair once from the leg with more reflections (``ChainTable.key``), as Algorithm 2 does.

This module is the NumPy twin of the path engine's compiled kernels, one function per kernel
with the same inputs and outputs (``rotate``: :func:`rotate`, ``trace_leg``:
:func:`trace_generation`, ``probe_chains``: :func:`probe_chains`, ``path_events``:
:func:`option_paths`, ``splat_events``: :func:`splat_set`; the casters' ``trace._hits.embree_hits``:
:func:`sonarsim.trace.embree.embree_hits`), compared kernel by kernel on random inputs in the
tests; the frame (:func:`trace_legs`, :func:`form_paths`,
:func:`accumulate_paths`) is a loop over them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from ..config.sonar import SonarConfig
from ..core.radiometry import SurfaceLaws, backscatter
from ..core.rays import RayFan
from ..image.grid import beam_azimuth_deg, beam_index
from ..core.transforms import Pose
from ..core.splat import RayEnergy, accumulate, continuity
from ..scene.floor_texture import scale_by_texture
from ..trace.base import Hits
from .planes import WATER_TOLERANCE_M, ChainTable, PlaneSet, reflection_points

# How each ``render.double_beam`` forms reciprocal pairs (the kernels' codes, renderer/_kernels.pyx):
# once (from the leg with more reflections), each path from its own receive ray, or so with the
# partners' amplitudes added where they arrive in one beam.
PAIRS_ONCE, PAIRS_SEPARATE, PAIRS_COHERENT = 0, 1, 2
PAIR_MODES = {"paper": PAIRS_ONCE, "split": PAIRS_ONCE, "separate": PAIRS_SEPARATE, "coherent": PAIRS_COHERENT}

# Reflected rays start this far off the plane so that round-off cannot make them meet it
# again (or the base of an object resting on it), metres.
SURFACE_OFFSET_M = 1e-5

# A transmit leg's segment that ends on a mesh mirror may meet it this much before its end,
# relative to its length (at least 1 m): the caster reports hits in float32.
MIRROR_HIT = 1e-5

# ``PathSet.tx`` of the paths whose transmit leg is the receive leg reversed.
SAME = -1

# ``PathSet.tx`` of the specular returns (``render.glints``): no scatter, the set's leg holds
# the last mirror each returning ray met (:func:`glint_sets`).
GLINT = -2

# Image rows ("labels") of the frame's image stack: order 1 is split by what scatters.
LABEL_OBJECT, LABEL_PLANE = 0, 1


def label_of_order(order: int) -> int:
    """Image row of the paths of ``order`` >= 2 (rows 0 and 1 are the single paths)."""
    return order


@dataclass
class Leg:
    """Receive legs of one generation (``gen`` reflections), dense over the fan's ``n`` rays.

    Attributes
    ----------
    gen : int
    distance : (n,) float64 ndarray
        Length of the receive leg from O to the scatterer, metres; ``inf``: none.
    sid : (n,) int32 ndarray
        Surface scattering (see :mod:`sonarsim.paths.planes`), -1 none.
    point : (n, 3) float64 ndarray
        The scatterer A, metres (NaN: none).
    normal : (n, 3) float32 ndarray
        Unit normal of the surface at A (either orientation): an object's as the caster reports
        it, a plane's rounded to float32 (it serves the continuity of range splatting only).
    intensity : (n,) float64 ndarray
        Diffuse weight of the ray at A: ``beta l(r) rho cos(alpha) cos(phi) dphi``.
    atten : (n,) float64 ndarray
        Product of the specular reflectances along the leg (1 everywhere in generation 0).
    chain : (n,) int32 ndarray
        Chain id of the leg (:class:`ChainTable`), -1 none (0 everywhere in generation 0).
    live : (l,) intp ndarray or None
        The rays that scatter some energy, ascending (None: found from the arrays).
    keys : (n,) int32 ndarray or None
        :meth:`key` as the tracing listed it (None: computed).
    prim : (n,) int32 ndarray or None
        The discrete search's triangle where an object scatters (an index into its mesh's
        faces), -1 where a plane does or nothing (None: not recorded).
    uv : (n, 2) float32 ndarray or None
        Where on that triangle: the caster's barycentric ``(u, v)``, ``A = (1 - u - v) a + u b +
        v c``; 0 elsewhere.
    cosine : (n,) float64 ndarray or None
        The incidence ``|cos(alpha)|`` at A, as the search recorded it (generation 0: from the
        float32 normal and direction, as the caster reports them); :func:`weigh_leg` turns it
        into ``intensity`` (None: not recorded).
    texel : (n,) float32 ndarray or None
        Where the objects are textured, the texture's factor at each object's scatterer (the
        search records it, the weighing reads it); None: no texture.
    back_length : (n,) float64 ndarray or None
        With ``render.glints``: the length of the specular return of the ray that reflects at
        this generation's mirror and comes back to the sonar (``inf``: none). None: not traced.
    back_atten : (n,) float64 ndarray or None
        Its product of specular reflectances (the last mirror's included).
    back_dir : (n, 3) float64 ndarray or None
        The direction it travels as it reaches the sonar (it arrives from ``-back_dir``).
    back_chain : (n,) int32 ndarray or None
        Its chain (every mirror it met).
    """

    gen: int
    distance: np.ndarray
    sid: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    intensity: np.ndarray
    atten: np.ndarray
    chain: np.ndarray
    live: np.ndarray | None = None
    keys: np.ndarray | None = None
    prim: np.ndarray | None = None
    uv: np.ndarray | None = None
    cosine: np.ndarray | None = None
    texel: np.ndarray | None = None
    back_length: np.ndarray | None = None
    back_atten: np.ndarray | None = None
    back_dir: np.ndarray | None = None
    back_chain: np.ndarray | None = None

    def key(self, n_surfaces: int) -> np.ndarray:
        """(n,) int32: rays on one surface via one chain share a key (-1 none): continuity."""
        if self.keys is not None:
            return self.keys
        # (int64 while formed: many chains times many surfaces would wrap in int32)
        key = np.where(self.sid >= 0, self.chain.astype(np.int64) * n_surfaces + self.sid, -1)
        return key.astype(np.int64 if key.max(initial=0) > np.iinfo(np.int32).max else np.int32)

    def live_rays(self) -> np.ndarray:
        """(l,) intp: the rays that scatter some energy, ascending."""
        if self.live is None:
            self.live = np.flatnonzero(np.isfinite(self.distance) & (self.intensity != 0))
        return self.live


@dataclass
class PathSet:
    """Paths of one generation of receive legs and one transmit option, compact.

    Attributes
    ----------
    gen : int
        Receive-leg generation (index into the frame's legs).
    tx : int
        Transmit chain id, or :data:`SAME` (the receive leg reversed).
    ray : (m,) intp ndarray
        The fan ray each path arrives along, ascending.
    distance : (m,) float64 ndarray
        Recorded range: half the path's length, metres.
    energy : (m,) float64 ndarray
    beam : (m,) int32 ndarray
        Beam the path is recorded in.
    label : (m,) int8 ndarray
        Image row (:data:`LABEL_OBJECT`, :data:`LABEL_PLANE`, or the order).
    swap : bool
        The paths are the reciprocal partners of the ones formed: the sound goes out along
        the set's receive legs (a smooth mirror's, which has no image source) and comes back
        along its transmit chain, in whose beam they are recorded (:func:`form_paths`).
    beam_tx : (m,) int32 ndarray or None
        The beam each path's other leg leaves the sonar in (``coherent`` pairs carry twice
        their energy where it is ``beam``: the differentiable engine holds that factor).
    """

    gen: int
    tx: int
    ray: np.ndarray
    distance: np.ndarray
    energy: np.ndarray
    beam: np.ndarray
    label: np.ndarray
    swap: bool = False
    beam_tx: np.ndarray | None = None


@dataclass(frozen=True)
class SonarView:
    """One frame's sonar: its pose, what the path formation needs of its intrinsics, and its
    fan of rays, rotated to the pose once (the frame's one carrier of pose and fan: the
    renderer, its NumPy twin, Algorithm 2, the probes and the line-of-sight test read it).

    Attributes
    ----------
    origin : (3,) float64 ndarray, metres
    rotation : (3, 3) float64 ndarray, sonar-to-world
    beam_edges_deg : (n_beams + 1,) float64 ndarray, descending
    half_elevation_deg : float
    range_min_m, range_max_m : float
    fan : RayFan or None
        The rays in the sonar's frame (None: a view for the path formation alone).
    pose : Pose or None
        The pose ``origin`` and ``rotation`` come from.
    cone : bool
        The beams are cones (a phased array's, ``sonar.beam_shape``): a direction's beam is
        that of its direction cosine along the array (:func:`~sonarsim.image.grid.beam_azimuth_deg`).
    """

    origin: np.ndarray
    rotation: np.ndarray
    beam_edges_deg: np.ndarray
    half_elevation_deg: float
    range_min_m: float
    range_max_m: float
    fan: RayFan | None = field(default=None, compare=False, repr=False)
    pose: Pose | None = field(default=None, compare=False, repr=False)
    cone: bool = False

    @classmethod
    def of(cls, sonar: SonarConfig, pose: Pose, fan: RayFan | None = None) -> "SonarView":
        """The view of ``sonar`` (its intrinsics) at ``pose`` (sonar-to-world, world frame),
        casting ``fan``."""
        return cls(
            np.asarray(pose.translation, float), np.ascontiguousarray(pose.rotation),
            np.ascontiguousarray(sonar.beam_edges_deg), sonar.elevation_fov_deg / 2.0,
            sonar.range_min_m, sonar.range_max_m, fan, pose, getattr(sonar, "beam_shape", "plane") == "cone",
        )

    @functools.cached_property
    def directions(self) -> np.ndarray:
        """The fan's rays at the pose, world frame: ``R @ d`` for each ray (:func:`rotate`),
        shape ``fan.shape + (3,)``, float64; formed on first use, once per frame. The compiled
        engine rotates each block's share inside its kernel (``_kernels.rotate``, of which
        :func:`rotate` is the twin): the same bits."""
        if self.fan is None:
            raise ValueError("a view without a fan has no rays")
        d = self.fan.directions
        return rotate(d.reshape(-1, 3), self.rotation, self.origin)[0].reshape(d.shape)

    def beam_of(self, azimuth_deg: np.ndarray) -> np.ndarray:
        """Beam whose edges contain each azimuth; -1 outside the fan."""
        return beam_index(self.beam_edges_deg, azimuth_deg)

    def beam_of_direction(self, v: np.ndarray) -> np.ndarray:
        """Beam of each direction ``v`` (..., 3) in the sonar frame (plane or cone beams); -1
        outside the fan."""
        az = beam_azimuth_deg(v, self.cone)
        return np.where(np.isfinite(az), self.beam_of(np.nan_to_num(az, nan=1e9)), -1)


# The twins of the compiled kernels, one to one -------------------------------------------
#
# Each function below has the inputs and outputs of one kernel of ``renderer/_kernels.pyx``
# and does the same arithmetic in the same order and precision (so most outputs agree to the
# bit; tests/renderer/test_kernels.py compares them on random inputs):
#
# =======================  ==========================  =====================================
# kernel                   twin                        what
# =======================  ==========================  =====================================
# ``rotate``               :func:`rotate`              fan directions to the world frame
# ``trace._hits.embree_hits`` ``trace.embree.embree_hits`` Embree's raw answer to hits
# ``trace_leg``            :func:`trace_generation`    one generation of receive legs
# ``path_events``          :func:`option_paths`        paths of one generation, one transmit
# ``returns_impl``         :func:`returns_to_sonar`    the specular returns of one generation
# ``splat_events``         :func:`splat_set`           one path set into the image stack
# =======================  ==========================  =====================================
#
# Dot products are written out term by term, left to right, as the kernels sum them (a matmul
# or einsum may sum in another order, or fuse a multiply and an add).


def _dot(a: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Rows of ``a`` (m, 3) dotted with ``n`` (3,), summed as the kernels sum: (x + y) + z."""
    return a[:, 0] * n[0] + a[:, 1] * n[1] + a[:, 2] * n[2]


def _rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot of two (m, 3) arrays, summed as the kernels sum."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def rotate(directions: np.ndarray, rotation: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame ray directions ``R @ d`` and the float32 copies Embree takes (twin of ``_kernels.rotate``).

    Parameters
    ----------
    directions : (n, 3) float64 array
        Unit directions in the sonar frame.
    rotation : (3, 3) float64 array
        Sonar-to-world rotation R.
    origin : (3,) float array
        The sonar O, metres.

    Returns
    -------
    d64 : (n, 3) float64 ndarray
    d32 : (n, 3) float32 ndarray
    o32 : (n, 3) float32 ndarray
        ``origin`` for every ray.
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(rotation, dtype=np.float64)
    d64 = d[:, 0:1] * r[:, 0] + d[:, 1:2] * r[:, 1] + d[:, 2:3] * r[:, 2]
    o32 = np.empty((len(d), 3), dtype=np.float32)
    o32[:] = np.asarray(origin, dtype=np.float64).astype(np.float32)
    return d64, d64.astype(np.float32), o32


@dataclass
class Rays:
    """The rays of one generation of receive legs, compact: row ``k`` goes along fan ray ``ray[k]``.

    The first generation gives one row of ``origin``, ``before``, ``atten`` and ``chain`` for
    all its rays (they all leave the sonar).

    Attributes
    ----------
    ray : (m,) intp ndarray
        Fan ray of each row, ascending.
    origin : (m, 3) or (1, 3) float64 ndarray
        Where the rays start, metres.
    direction : (m, 3) float64 ndarray
        Unit directions.
    before : (m,) or (1,) float64 ndarray
        Length of the leg before the start, metres.
    atten : (m,) or (1,) float64 ndarray
        Product of the specular reflectances before the start.
    chain : (m,) or (1,) int32 ndarray
        Chain id of the leg so far (:class:`ChainTable`).
    """

    ray: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    before: np.ndarray
    atten: np.ndarray
    chain: np.ndarray

    @classmethod
    def from_sonar(cls, origin: np.ndarray, directions: np.ndarray) -> "Rays":
        """The first generation: every fan ray from the sonar O."""
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        return cls(np.arange(len(d), dtype=np.intp), np.asarray(origin, dtype=np.float64).reshape(1, 3), d,
                   np.zeros(1), np.ones(1), np.zeros(1, dtype=np.int32))

    def __len__(self) -> int:
        return len(self.ray)

    @property
    def origin32(self) -> np.ndarray:
        """(m, 3) float32 origins for the caster (the first generation's one row, repeated)."""
        return np.broadcast_to(self.origin, (len(self.ray), 3)).astype(np.float32)

    @property
    def direction32(self) -> np.ndarray:
        """(m, 3) float32 directions for the caster."""
        return self.direction.astype(np.float32)


def trace_generation(
    rays: Rays,
    hits: Hits,
    planes: PlaneSet,
    active: np.ndarray,
    reach_m: float,
    laws: SurfaceLaws | np.ndarray,
    weight: np.ndarray,
    tvg: bool,
    first: bool,
    reflect: bool,
    table: ChainTable,
    leg: Leg,
    facets=None,
) -> tuple[Rays, np.ndarray]:
    """One generation of receive legs (twin of ``_kernels.trace_leg``): the search, then
    :func:`weigh_leg` over what it recorded.

    Each ray ends at the closest of its object hit and the active planes it meets from the
    water side within ``reach_m``; there it scatters (the diffuse weight, formed by the
    weighing from the recorded incidence) and, on a plane with some specular reflectance,
    reflects and goes on as a ray of the next generation.

    Parameters
    ----------
    rays : Rays
        This generation's rays.
    hits : Hits
        The objects along ``rays`` (row by row; mesh k is surface ``P + k``).
    planes : PlaneSet
    active : (P,) bool array
        Planes the sonar faces.
    reach_m : float
        Longest receive leg followed, metres.
    laws : SurfaceLaws or (n_surfaces + 1,) float array
        Backscatter laws by surface id + 1 (an array: the Lambertian albedo).
    weight : (n,) float array
        Weight ``beta cos(phi) dphi`` of each fan ray.
    tvg : bool
    first : bool
        The first generation: points and incidence as the caster reports them (float32), and
        the rays that reach nothing are given "nothing" (distance ``inf``, sid -1) in ``leg``.
    reflect : bool
        Form the next generation.
    table : ChainTable
        Receives the chains met, numbered in the order of the rows that first meet them.
    leg : Leg
        Dense over the fan; written at the rays reached (distance, sid, point, normal, cosine,
        intensity, texel where the hits carry a texture's factor; ``atten`` and ``chain``
        except in the first generation, where they are 1 and 0). Its :meth:`Leg.key` is the
        kernel's ``key``. A missing ``cosine`` (or ``texel``) is allocated.
    facets : FacetSet, optional
        The mesh mirrors (:mod:`sonarsim.paths.facets`): a ray that meets one of their
        triangles also reflects, about the triangle's normal (or the interpolated one), into
        chain mirror ``P + m`` (m the triangle's mirror). ``hits`` must carry the triangles and
        barycentrics (the kernel's tables: ``_kernels.Mirrors``).

    Returns
    -------
    next : Rays
        The reflected rays, in row order (they start :data:`SURFACE_OFFSET_M` off the plane,
        from the float32-rounded point, as the caster would report it).
    live : (l,) intp ndarray
        The fan rays reached that scatter some energy, in row order.
    """
    n_planes = len(planes)
    m = len(rays)
    ray, d = rays.ray, rays.direction
    org = np.broadcast_to(rays.origin, (m, 3))
    before = np.broadcast_to(rays.before, (m,))
    hit = hits.mesh_id >= 0
    t = np.where(hit, hits.distance.astype(np.float64), np.inf)
    sid = np.where(hit, hits.mesh_id + n_planes, -1).astype(np.int32)
    normal = np.where(hit[:, None], hits.normal.astype(np.float64), 0.0)
    best = np.full(m, -1, dtype=np.int32)
    for p in np.flatnonzero(active):
        n = planes.normal[p]
        dn = _dot(d, n)
        with np.errstate(divide="ignore", invalid="ignore"):
            tp = (planes.offset[p] - _dot(org, n)) / dn
        # Met from the water side, closer than anything so far (earlier planes win ties).
        closer = (dn < 0) & (tp > 0) & (tp < t) & (before + tp <= reach_m)
        t = np.where(closer, tp, t)
        best[closer] = p
    on = best >= 0
    sid[on] = best[on]
    normal[on] = planes.normal[best[on]]
    total = before + t
    ok = (sid >= 0) & (total <= reach_m)
    if first:
        leg.distance[ray[~ok]] = np.inf
        leg.sid[ray[~ok]] = -1
    k = np.flatnonzero(ok)
    r, t, sid, normal, total, dd, oo = ray[k], t[k], sid[k], normal[k], total[k], d[k], org[k]
    point = oo + dd * t[:, None]
    if first:
        # As the caster reports them: float32 points and incidence.
        point = point.astype(np.float32).astype(np.float64)
        cos = np.abs(_rowdot(normal.astype(np.float32), dd.astype(np.float32))).astype(np.float64)
    else:
        cos = np.abs(_rowdot(normal, dd))
    atten = np.broadcast_to(rays.atten, (m,))[k]
    chain = np.broadcast_to(rays.chain, (m,))[k]
    if leg.cosine is None:
        leg.cosine = np.zeros(len(leg.distance))
    leg.distance[r] = total
    leg.sid[r] = sid
    leg.point[r] = point
    leg.normal[r] = normal
    leg.cosine[r] = cos
    if hits.texel is not None:  # a texture scales the objects' diffuse coefficient, not the planes'
        if leg.texel is None:
            leg.texel = np.ones(len(leg.distance), np.float32)
        on_object = sid >= n_planes
        leg.texel[r[on_object]] = hits.texel[k][on_object]
    if leg.prim is not None:  # the search's triangle and barycentrics where an object scatters
        on_object = sid >= n_planes
        leg.prim[r] = np.where(on_object, hits.primitive_id[k], -1)
        leg.uv[r] = np.where(on_object[:, None], hits.barycentric[k], np.float32(0.0))
    if not first:
        leg.atten[r] = atten
        leg.chain[r] = chain
    live = weigh_leg(leg, r, laws, weight, tvg, n_planes)
    go = (sid < n_planes) & (total < reach_m)
    if n_planes:
        go &= planes.specular[np.minimum(sid, n_planes - 1)] > 0
    mirrors = facets is not None and facets.any
    if mirrors:  # a mesh mirror's triangle reflects as a plane does (chain mirror P + its mirror)
        facet = np.full(len(sid), -1, dtype=np.int64)
        on_object = sid >= n_planes
        facet[on_object] = facets.facet(sid[on_object] - n_planes, hits.primitive_id[k][on_object])
        mirror = facet >= 0
        mirror[mirror] = facets.facing(facet[mirror], dd[mirror])  # a closed object's outside only
        facet[~mirror] = -1
        go |= mirror & (total < reach_m)
    if not (reflect and go.any()):
        return Rays(r[:0], np.empty((0, 3)), np.empty((0, 3)), np.empty(0), np.empty(0), np.empty(0, np.int32)), live
    p, c, d_go = sid[go], chain[go], dd[go]
    if mirrors:
        f = facet[go]
        on_facet = f >= 0
        p = np.where(on_facet, n_planes + facets.mirror[np.maximum(f, 0)], p)
    # New chains are numbered in the order of the rows that first meet them, as the kernel does.
    pair = c.astype(np.int64) * (n_planes + (facets.n_mirrors if mirrors else 0)) + p
    _, first_row, back = np.unique(pair, return_index=True, return_inverse=True)
    child = np.empty(len(first_row), dtype=np.int32)
    for u in np.argsort(first_row, kind="stable"):
        child[u] = table.child(int(c[first_row[u]]), int(p[first_row[u]]))
    if not mirrors:
        nrm = planes.normal[p]
        spec = planes.specular[p]
        row = p + 1
    else:
        nrm = np.empty((len(p), 3))
        spec = np.empty(len(p))
        nrm[~on_facet] = planes.normal[p[~on_facet]]
        spec[~on_facet] = planes.specular[p[~on_facet]]
        ff = f[on_facet]
        uv = hits.barycentric[k][go][on_facet].astype(np.float64)
        bent = facets.reflecting_normal(ff, uv)
        flat = facets.normal[ff]
        # An interpolated normal may turn a grazing ray into the surface: there the facet's own
        # normal reflects it (the ray must leave on the side it came from).
        d_in = d_go[on_facet]
        into = _rowdot(d_in - (2.0 * _rowdot(d_in, bent))[:, None] * bent, flat) * _rowdot(d_in, flat) > 0
        nrm[on_facet] = np.where(into[:, None], flat, bent)
        spec[on_facet] = facets.specular[facets.obj[ff]]
        row = np.where(on_facet, n_planes + facets.obj[np.maximum(f, 0)] + 1, p + 1)
    if isinstance(laws, SurfaceLaws) and laws.reflectance is not None:
        # the mirrors' reflectance at each ray's incidence on the normal it reflects about
        spec = mirror_reflectance(np.abs(_rowdot(d_go, nrm)), row, laws.reflectance, laws.reflect_q)
    twice = 2.0 * _rowdot(d_go, nrm)
    d_ref = d_go - twice[:, None] * nrm
    start = point[go].astype(np.float32).astype(np.float64) + SURFACE_OFFSET_M * d_ref
    nxt = Rays(r[go], start, d_ref, total[go] + SURFACE_OFFSET_M, atten[go] * spec, child[back.reshape(-1)])
    return nxt, live


def weigh_leg(leg: Leg, reached: np.ndarray, laws: SurfaceLaws | np.ndarray, weight: np.ndarray, tvg: bool,
              n_planes: int) -> np.ndarray:
    """The diffuse weight of the rays a generation's search reached, from what it recorded
    (twin of ``_kernels.weigh_impl``): ``leg.intensity[reached]``, from the surface, the
    incidence, the leg's length and, on a textured object, the texture's factor.

    Parameters
    ----------
    leg : Leg
        With ``cosine`` (and ``texel`` where the objects are textured) written at ``reached``.
    reached : (m,) intp ndarray
        The fan rays the search reached, ascending.
    laws : SurfaceLaws or (n_surfaces + 1,) float array
        Backscatter laws by surface id + 1 (an array: the Lambertian albedo).
    weight : (n,) float array
        Weight ``beta cos(phi) dphi`` of each fan ray.
    tvg : bool
        Without TVG, the weight is divided by the leg's length squared.
    n_planes : int

    Returns
    -------
    (l,) intp ndarray
        The rays of ``reached`` that scatter some energy.
    """
    sid = leg.sid[reached]
    texel = None
    if leg.texel is not None:
        texel = np.where(sid >= n_planes, leg.texel[reached], np.float32(1.0))
    intensity = backscatter(np.asarray(weight)[reached], leg.cosine[reached], SurfaceLaws.of(laws), sid + 1,
                            leg.distance[reached], tvg, texel)
    leg.intensity[reached] = intensity
    return reached[intensity != 0]


RAD2DEG = 180.0 / np.pi


def mirror_reflectance(c: np.ndarray, row: np.ndarray, table: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Reflectances at incidences ``c = |cos|`` of surfaces ``row - 1`` (twin of the kernels'
    ``reflect_at``: :func:`sonarsim.core.reflection.reflectance` row by row)."""
    c = np.clip(np.nan_to_num(np.asarray(c, dtype=np.float64), nan=0.0), 0.0, 1.0)
    row = np.asarray(row, dtype=np.intp)
    x = c * (table.shape[1] - 1)
    j = np.minimum(x.astype(np.intp), table.shape[1] - 2)
    f = x - j
    return (table[row, j] + f * (table[row, j + 1] - table[row, j])) * np.exp(-q[row] * c * c)


def transmit_reflectance(u: np.ndarray, tx_planes: np.ndarray, n_planes: int, planes: PlaneSet, facets,
                         table: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The product of the reflectances along transmit legs of chain ``tx_planes`` (twin of the
    kernels' ``transmit_reflectance``): the first segment runs along ``u`` (k, 3), the unfolded
    line from the sonar to each scatterer's image; each reflection meets its mirror at
    ``|d . n|`` and turns ``d`` about ``n``."""
    norm = np.sqrt(_rowdot(u, u))
    with np.errstate(divide="ignore", invalid="ignore"):
        d = u / norm[:, None]
    r = np.ones(len(u))
    for p in (int(v) for v in tx_planes):
        if p < n_planes:
            n, row = planes.normal[p], p + 1
        else:
            n, row = facets.mirror_normal[p - n_planes], n_planes + int(facets.mirror_obj[p - n_planes]) + 1
        dn = d @ n
        r *= mirror_reflectance(np.abs(dn), np.full(len(u), row), table, q)
        d = d - 2.0 * dn[:, None] * n
    return np.where(norm > 0.0, r, 0.0)


def option_paths(
    live: np.ndarray,
    leg: Leg,
    same: bool,
    tx: int,
    unfold: np.ndarray,
    sources: np.ndarray,
    tx_planes: np.ndarray,
    tx_specular: float,
    rank: np.ndarray,
    separate: bool,
    label: int,
    n_planes: int,
    rays_per_beam: int,
    view: SonarView,
    planes: PlaneSet,
    active: np.ndarray,
    facets=None,
    reflectance: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paths of one generation's receive legs and one transmit option (twin of ``_kernels.path_events``).

    Parameters
    ----------
    live : (l,) intp array
        The fan rays whose scatterers make paths, ascending.
    leg : Leg
        Their receive legs.
    same : bool
        The transmit leg is the receive leg reversed; otherwise it follows chain ``tx``.
    tx : int
        Transmit chain id (ignored when ``same``).
    unfold : (3, 4) float64 array
        The chain's map A -> A* (:meth:`ChainTable.unfold`).
    sources : (K + 1, 3) float64 array
        The sonar's images along the chain (:meth:`ChainTable.sources`).
    tx_planes : (K,) int array
        The chain's planes, from the sonar.
    tx_specular : float
        Product of the chain's specular reflectances.
    rank : (n_chains,) int array
        :func:`chain_ranks`.
    separate : int
        :data:`PAIR_MODES` of ``double_beam``: 0 (``paper``, ``split``) each receive chain pairs
        only with transmit chains of lower rank (each reciprocal pair once); 1 (``separate``)
        with every transmit chain; 2 (``coherent``) so, and a path whose transmit leg leaves
        in its own beam carries twice its energy (its partner's amplitude adds to its own).
    label : int
        Image row of the paths; 1 with ``same`` means order 1: row 0 on objects, 1 on planes.
    n_planes : int
    rays_per_beam : int
        Fan ray ``i`` arrives in beam ``i // rays_per_beam``.
    view : SonarView
    planes : PlaneSet
    active : (P,) bool array
    facets : FacetSet, optional
        The mesh mirrors, where the chain holds some (chain mirror ``P + m``: the facets' mirror
        ``m``; the leg must record its triangles, ``leg.prim``).
    reflectance : (table, q), optional
        ``SurfaceLaws.reflectance`` and ``reflect_q``: the transmit leg's reflectances at its
        incidences (:func:`transmit_reflectance`) instead of ``tx_specular``.

    Returns
    -------
    ray : (k,) intp ndarray
    distance : (k,) float64 ndarray
        Half the path's length, metres.
    energy : (k,) float64 ndarray
    beam : (k,) int32 ndarray
        Beam of arrival.
    beam_tx : (k,) int32 ndarray
        Beam the transmit leg leaves the sonar in.
    label : (k,) int8 ndarray
    """
    i = np.asarray(live, dtype=np.intp)
    s = leg.sid[i]
    if same:
        energy = leg.atten[i] * leg.atten[i] * leg.intensity[i]
        beam = (i // rays_per_beam).astype(np.int32)
        lab = np.where(s >= n_planes, LABEL_OBJECT, LABEL_PLANE) if label == 1 else np.full(len(i), label)
        return i, leg.distance[i], energy, beam, beam.copy(), lab.astype(np.int8)
    c = leg.chain[i]
    last = int(tx_planes[-1]) if len(tx_planes) else -1
    if last < n_planes:
        keep = (c != tx) & (s != last)
    else:  # a mesh mirror: not the one the scatterer lies on (its plane, t = 0 up to round-off)
        on = s >= n_planes
        own = np.full(len(i), -1, dtype=np.int64)
        own[on] = facets.mirror_of(s[on] - n_planes, leg.prim[i][on])
        keep = (c != tx) & (own != last - n_planes)
    if not separate:
        keep &= rank[c] > rank[tx]
    i = i[keep]
    a = leg.point[i]
    u = a[:, 0:1] * unfold[:, 0] + a[:, 1:2] * unfold[:, 1] + a[:, 2:3] * unfold[:, 2] + unfold[:, 3] - view.origin
    rot = view.rotation
    v = u[:, 0:1] * rot[0] + u[:, 1:2] * rot[1] + u[:, 2:3] * rot[2]  # R^T u: the sonar frame
    length = np.sqrt(_rowdot(v, v))
    ok = (length >= view.range_min_m) & (length < view.range_max_m)
    with np.errstate(divide="ignore", invalid="ignore"):
        el = np.arcsin(np.clip(v[:, 2] / length, -1.0, 1.0)) * RAD2DEG
    ok &= np.abs(el) <= view.half_elevation_deg
    beam_tx = view.beam_of_direction(v)
    ok &= beam_tx >= 0
    # Walk back from A towards the sonar's images: each reflection point must lie on its
    # plane, between its neighbours, inside the water.
    w = a
    for j in range(len(tx_planes) - 1, -1, -1):
        q = int(tx_planes[j])
        if q < n_planes:
            n, offset = planes.normal[q], planes.offset[q]
        else:
            n, offset = facets.mirror_normal[q - n_planes], facets.mirror_offset[q - n_planes]
            side = int(facets.side[facets.mirror_obj[q - n_planes]])
            if side:  # a closed object's facet is met from outside: the leg beyond it is there
                ok &= side * (_dot(w, n) - offset) > 0.0
        towards = sources[j + 1] - w
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (offset - _dot(w, n)) / _dot(towards, n)
            ok &= (t > 0.0) & (t < 1.0)
            w = w + t[:, None] * towards
            tol = WATER_TOLERANCE_M * np.maximum(np.abs(w).max(axis=1), 1.0)
            for p in np.flatnonzero(active):
                ok &= ~(_dot(w, planes.normal[p]) - planes.offset[p] < -tol)
        if q >= n_planes:  # on one of its triangles, not only their plane
            ok &= facets.contains_mirror(q - n_planes, w)
    k = np.flatnonzero(ok)
    i = i[k]
    distance = 0.5 * (leg.distance[i] + length[k])
    tx_r = tx_specular
    if reflectance is not None and len(tx_planes):
        tx_r = transmit_reflectance(u[k], tx_planes, n_planes, planes, facets, *reflectance)
    energy = leg.atten[i] * tx_r * leg.intensity[i]
    beam = (i // rays_per_beam).astype(np.int32)
    beam_tx = beam_tx[k].astype(np.int32)
    if separate == PAIRS_COHERENT:
        energy = np.where(beam_tx == beam, 2.0 * energy, energy)
    return i, distance, energy, beam, beam_tx, np.full(len(i), label, dtype=np.int8)


def set_continuity(points: np.ndarray, normals: np.ndarray, key: np.ndarray, n_elevation: int) -> np.ndarray:
    """(n_columns, n_elevation - 1) bool: neighbouring fan rays of a leg on one continuous
    surface via one chain (:func:`~sonarsim.core.splat.continuity` on ray columns)."""
    shape = (-1, n_elevation)
    return continuity(points.reshape(shape + (3,)), normals.reshape(shape + (3,)), key.reshape(shape))


def splat_set(
    points: np.ndarray,
    normals: np.ndarray,
    key: np.ndarray,
    ray: np.ndarray,
    distance: np.ndarray,
    energy: np.ndarray,
    beam: np.ndarray,
    label: np.ndarray,
    scale: float,
    spread: bool,
    n_elevation: int,
    range_min_m: float,
    range_resolution_m: float,
    n_range_bins: int,
    n_beams: int,
    n_labels: int,
    continuous: np.ndarray | None = None,
) -> np.ndarray:
    """One compact path set into an image stack (twin of ``_kernels.splat_events``).

    The set is made dense over the fan and given to
    :func:`~sonarsim.core.splat.accumulate`: two paths are neighbours when their rays
    are neighbours in one ray column with the same ``key`` and the chord between their
    scatterers passes the continuity test; each path's energy is ``scale * energy``.

    Parameters
    ----------
    points, normals : (n, 3) float64 arrays
        The leg's scatterers and their normals, dense over the fan's ``n`` rays.
    key : (n,) int array
        :meth:`Leg.key`.
    ray, distance, energy, beam, label : (m,) arrays
        The path set (:class:`PathSet`), rays ascending.
    scale : float
    spread : bool
        Range splatting; ``False``: each path in the bin of its range.
    n_elevation : int
        Rays per ray column (the fan's last axis).
    range_min_m, range_resolution_m : float
    n_range_bins, n_beams, n_labels : int
    continuous : (n // n_elevation, n_elevation - 1) bool array, optional
        :func:`set_continuity` of the leg, when already formed.

    Returns
    -------
    (n_labels, n_range_bins, n_beams) float64 ndarray
    """
    n = len(points)
    dist = np.full(n, np.inf)
    e = np.zeros(n)
    b = np.zeros(n, dtype=np.int64)
    lab = np.full(n, -1, dtype=np.int64)
    dist[ray], e[ray], b[ray], lab[ray] = distance, scale * np.asarray(energy), beam, label
    shape = (-1, n_elevation)
    cont = None
    if spread:
        cont = continuous if continuous is not None else set_continuity(points, normals, key, n_elevation)
    rays = RayEnergy(dist.reshape(shape), e.reshape(shape), b.reshape(shape), lab.reshape(shape), cont)
    return accumulate([rays], range_min_m, range_resolution_m, n_range_bins, n_beams, n_labels=n_labels)


# The frame, as loops over the twins --------------------------------------------------------


def trace_legs(
    caster,
    planes: PlaneSet,
    active: np.ndarray,
    origin: np.ndarray,
    directions: np.ndarray,
    weight: np.ndarray,
    laws: SurfaceLaws | np.ndarray,
    tvg: bool,
    reach_m: float,
    n_generations: int,
    table: ChainTable,
    textures: tuple = (),
    glint_radius_m: float | None = None,
) -> list[Leg]:
    """Receive legs of the fan's rays, generation by generation (:func:`trace_generation` in a loop).

    Parameters
    ----------
    caster : RayCaster
        The objects (mesh k = object k, surface id ``P + k``).
    planes : PlaneSet
    active : (P,) bool array
        Planes the sonar faces (the others are neither seen nor reflect).
    origin : (3,) float array
        The sonar O, metres.
    directions : (n, 3) float64 array
        Unit ray directions in the world frame.
    weight : (n,) float array
        Ray weights ``beta cos(phi) dphi``.
    laws : SurfaceLaws or (P + n_objects + 1,) float array
        Backscatter laws indexed by surface id + 1 (an array: the Lambertian albedo).
    tvg : bool
    reach_m : float
        Longest receive leg followed, metres.
    n_generations : int
        1 + the most reflections followed on a receive leg.
    table : ChainTable
        Receives the chains met; its ``facets``, the mesh mirrors, reflect as planes do.
    textures : tuple of ReflectivityField or None
        The planes' textures (:func:`~sonarsim.scene.floor_texture.texture_fields`, by plane
        index; empty: none): each scatterer on a textured plane takes its factor, so every path
        formed from it does.
    glint_radius_m : float, optional
        Also trace the specular returns (``render.glints``): each reflected ray that comes back
        within this distance of the sonar before it meets anything, after at most
        ``n_generations`` reflections, is written into the ``back_*`` arrays of the leg where
        it last reflected (:func:`returns_to_sonar`).
    """
    rays = Rays.from_sonar(origin, directions)
    n = len(rays)
    legs = []
    glints = glint_radius_m is not None
    for g in range(n_generations + (1 if glints else 0)):
        if not len(rays):
            break  # no generation after an empty one
        first = g == 0
        leg = Leg(
            g, np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan), np.zeros((n, 3), np.float32),
            np.zeros(n), np.ones(n) if first else np.zeros(n), np.zeros(n, np.int32) if first else np.full(n, -1, np.int32),
            prim=np.full(n, -1, np.int32), uv=np.zeros((n, 2), np.float32), cosine=np.zeros(n),
        )
        limit = float(reach_m - rays.before.min())
        hits = caster.intersect(rays.origin32, rays.direction32, limit, with_uv=True)
        reflected = rays
        rays, _ = trace_generation(rays, hits, planes, active, reach_m, laws, weight, tvg, first,
                                   g + 1 < n_generations or (glints and g + 1 == n_generations), table, leg,
                                   facets=table.facets)
        if glints and not first:  # the rays reflected at the last generation's mirrors
            returns_to_sonar(legs[-1], reflected, leg, origin, glint_radius_m, reach_m)
        if g == n_generations:
            break  # traced for its returns only: these rays' scatterers are beyond max_order
        legs.append(leg)
        if any(f is not None for f in textures):
            scale_by_texture(leg.intensity, leg.sid, leg.point, textures)
    return legs


def returns_to_sonar(mirror: Leg, rays: Rays, reached: Leg, origin: np.ndarray, radius_m: float,
                     reach_m: float) -> None:
    """The specular returns among rays reflected at ``mirror``'s scatterers (``render.glints``;
    twin of ``_kernels.returns_impl``, which ``PathBlocks`` runs after each generation's search).

    A ray returns when its line passes within ``radius_m`` of the sonar O, ahead of it and
    before the surface it reaches (``reached``: its next generation, whose ``distance`` is
    ``inf`` where it met nothing within the reach). Its length is the leg so far plus the
    distance along the ray to O's foot on it. Written into ``mirror.back_*``.

    Why a disc: a point receiver meets a ray with probability zero; the rays that cross a disc
    of radius a around O estimate the intensity there as ``sum(R w) / (pi a**2)`` in the
    image's units (each ray carries the solid angle of its weight, and a flux density is the
    flux through the disc over its area, ``pi a**2``). The image-source picture gives the same
    for a flat mirror met square on at range r: the sonar's image is a source ``2 r`` away, so
    ``R / (2 r)**2`` summed over the beams it lands in, times the beam width in radians (the
    sonar equation's ``SL - 20 log10(2 r)`` for R = 1; tested), without the image source's
    degeneracy at a corner reflector's apex, where every reflection point is the apex.
    """
    n = len(mirror.distance)
    if mirror.back_length is None:
        mirror.back_length = np.full(n, np.inf)
        mirror.back_atten = np.zeros(n)
        mirror.back_dir = np.zeros((n, 3))
        mirror.back_chain = np.full(n, -1, np.int32)
    m = len(rays)
    if not m:
        return
    org = np.broadcast_to(rays.origin, (m, 3))
    before = np.broadcast_to(rays.before, (m,))
    d = rays.direction
    w = np.asarray(origin, float) - org
    t = _rowdot(w, d)
    miss2 = _rowdot(w, w) - t * t
    ahead = reached.distance[rays.ray] - before  # inf: met nothing
    ok = (t > 0.0) & (t < ahead) & (miss2 <= radius_m * radius_m) & (before + t <= reach_m)
    k = np.flatnonzero(ok)
    r = rays.ray[k]
    mirror.back_length[r] = before[k] + t[k]
    mirror.back_atten[r] = np.broadcast_to(rays.atten, (m,))[k]
    mirror.back_dir[r] = d[k]
    mirror.back_chain[r] = np.broadcast_to(rays.chain, (m,))[k]


def glint_sets(legs: list[Leg], view: SonarView, n_planes: int, rays_per_beam: int, max_order: int,
               weight: np.ndarray, radius_m: float, tvg: bool) -> list[PathSet]:
    """The specular returns as path sets (``tx`` :data:`GLINT`), one per generation of mirrors.

    A return after k reflections is of order k; it is recorded at half its length, in the beam
    it arrives from (``-back_dir`` inside the receive aperture: the fan and the elevation
    aperture), with ``R ... R w / (pi radius_m**2)`` (times the range squared with TVG, as the
    scattered paths' ``l(r)``); w the weight of the fan ray it left along. Its set's leg is
    the one where it last reflected (its point and surface label it); order 1 goes to the
    objects' or planes' row by that surface.
    """
    out = []
    for leg in legs:
        if leg.back_length is None or leg.gen + 1 > max_order:
            continue
        ray = np.flatnonzero(np.isfinite(leg.back_length))
        if not len(ray):
            continue
        arrive = -leg.back_dir[ray]
        rot = view.rotation
        v = arrive[:, 0:1] * rot[0] + arrive[:, 1:2] * rot[1] + arrive[:, 2:3] * rot[2]  # R^T: the sonar frame
        el = np.degrees(np.arcsin(np.clip(v[:, 2], -1.0, 1.0)))
        beam = view.beam_of_direction(v)
        keep = (beam >= 0) & (np.abs(el) <= view.half_elevation_deg)
        ray, beam = ray[keep], beam[keep].astype(np.int32)
        distance = 0.5 * leg.back_length[ray]
        energy = leg.back_atten[ray] * np.asarray(weight)[ray] / (np.pi * radius_m * radius_m)
        if tvg:
            energy = energy * distance * distance
        order = leg.gen + 1
        if order == 1:
            label = np.where(leg.sid[ray] >= n_planes, LABEL_OBJECT, LABEL_PLANE).astype(np.int8)
        else:
            label = np.full(len(ray), label_of_order(order), np.int8)
        out.append(PathSet(leg.gen, GLINT, ray, distance, energy, beam, label))
    return out


def renumber_chains(table: ChainTable, legs: list[Leg]) -> ChainTable:
    """The frame's chains numbered canonically (:meth:`ChainTable.canonical`), the legs' chain
    ids and keys made those: a chain's id then does not depend on which ray met it first, as
    in the compiled engine's blocks."""
    table, remap = table.canonical()
    for leg in legs[1:]:
        reached = leg.chain >= 0
        leg.chain[reached] = remap[leg.chain[reached]]
        leg.keys = None
    for leg in legs:  # the specular returns' chains
        if leg.back_chain is not None:
            back = leg.back_chain >= 0
            leg.back_chain[back] = remap[leg.back_chain[back]]
    return table


# Rays along each edge of the transmit aperture that :func:`probe_chains` traces.
PROBES_PER_EDGE = 48


@functools.lru_cache(maxsize=8)  # a sonar's intrinsics: the same every frame
def _aperture_edges(right_deg: float, left_deg: float, half_elevation_deg: float, per_edge: int) -> np.ndarray:
    """(4 per_edge, 3) unit vectors in the sonar frame along the four edges of the aperture
    (read-only)."""
    az = np.radians(np.linspace(right_deg, left_deg, per_edge))
    half = np.radians(half_elevation_deg)
    el = np.linspace(-half, half, per_edge)
    theta = np.concatenate([az, az, np.full(per_edge, az[0]), np.full(per_edge, az[-1])])
    phi = np.concatenate([np.full(per_edge, -half), np.full(per_edge, half), el, el])
    out = np.stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta), np.sin(phi)], axis=1)
    out.setflags(write=False)
    return out


def probe_chains(table: ChainTable, view: SonarView, active: np.ndarray, max_length: int,
                 per_edge: int = PROBES_PER_EDGE, kernel=None) -> None:
    """Add to ``table`` the chains of planes that the edges of the transmit aperture follow.

    Transmit legs are tried along the chains that some ray followed. The beams' rays sample
    the aperture at cell centres, half a cell in from its edges; a chain met only in that strip
    (a side wall seen just inside the fan's outer edge) would be missed. Rays along the four
    edges of the aperture (azimuth at the fan's outer beam edges, elevation at +-E/2), traced
    through the planes alone (objects may hide a transmit leg only with
    ``double_line_of_sight``, which checks each leg anyway), close that gap. Legs are followed
    no further than the range window reaches (a longer transmit leg is never recorded).

    Parameters
    ----------
    table : ChainTable
        Receives the chains (numbered after the ones it holds).
    view : SonarView
    active : (P,) bool array
        Planes the sonar faces.
    max_length : int
        Most reflections on a transmit leg (``max_order - 1``).
    per_edge : int
        Rays along each edge.
    kernel : callable, optional
        ``_kernels.probe_chains`` (the compiled twin of the loop below, step for step).
    """
    planes = table.planes
    if max_length < 1 or not len(planes) or not np.any(active & (planes.specular > 0)):
        return
    rot = view.rotation
    e = _aperture_edges(float(view.beam_edges_deg[-1]), float(view.beam_edges_deg[0]), view.half_elevation_deg,
                        per_edge)
    if kernel is not None:  # the kernel turns the edges' rays itself, as below
        origin = np.asarray(view.origin, float).reshape(1, 3)
        while True:
            n_chains, overflow = kernel(origin, e, planes.normal, planes.offset, np.ascontiguousarray(active, np.uint8),
                                        planes.specular, view.range_max_m, max_length, table.children, len(table),
                                        np.ascontiguousarray(rot, float))
            table.sync(n_chains)
            if not overflow:
                return
            table._grow()
    d = e[:, 0:1] * rot[:, 0] + e[:, 1:2] * rot[:, 1] + e[:, 2:3] * rot[:, 2]  # R d, as _kernels.rotate sums
    o = np.broadcast_to(np.asarray(view.origin, float), d.shape).copy()
    chain = np.zeros(len(d), dtype=np.int64)
    travelled = np.zeros(len(d))
    index = np.flatnonzero(active)
    for _ in range(max_length):
        # Every active plane at once; the dot products summed as the kernel sums them.
        t_all = np.full((len(d), len(index)), np.inf)
        for j, p in enumerate(index):
            n = planes.normal[p]
            dn = _dot(d, n)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (planes.offset[p] - _dot(o, n)) / dn
            t_all[:, j] = np.where((dn < 0) & (t > 0), t, np.inf)
        nearest = np.argmin(t_all, axis=1)  # the first of equal distances, as the kernel's strict <
        best_t = t_all[np.arange(len(d)), nearest]
        best_p = index[nearest]
        go = np.isfinite(best_t) & (travelled + best_t < view.range_max_m) & (planes.specular[best_p] > 0)
        if not go.any():
            return
        o, d, t, p = o[go], d[go], best_t[go], best_p[go]
        for c, q in set(zip(chain[go].tolist(), p.tolist())):  # a handful of distinct steps
            table.child(c, q)
        chain = table.children[chain[go], p].astype(np.int64)
        travelled = travelled[go] + t
        n = planes.normal[p]
        o = o + d * t[:, None]
        d = d - (2.0 * _rowdot(d, n))[:, None] * n
        o = o + SURFACE_OFFSET_M * d


def transmit_options(table: ChainTable, gen: int, max_order: int) -> list[int]:
    """Transmit options of generation ``gen``: :data:`SAME`, then chain ids, by order."""
    out = [SAME] if 2 * gen + 1 <= max_order else []
    out += [c for c in range(len(table)) if gen + table.length(c) + 1 <= max_order and not (gen == 0 and c == 0)]
    return out


def chain_ranks(table: ChainTable) -> np.ndarray:
    """(n_chains,) rank of each chain in the reciprocal-pair order (``ChainTable.key``)."""
    order = sorted(range(len(table)), key=table.key)
    rank = np.empty(len(table), dtype=np.int32)
    rank[order] = np.arange(len(table), dtype=np.int32)
    return rank


def frame_options(table: ChainTable, n_gen: int, max_order: int, double_beam: str) -> list[tuple[int, int, int]]:
    """The frame's transmit options, in the order its paths are formed: ``(generation, transmit
    option, image row)``, the option :data:`SAME` or a chain id (generation by generation, SAME
    first, then chains by id: :func:`transmit_options`). Row 1 of the first generation's SAME
    paths means order 1 (row 0 on objects, 1 on planes, per path)."""
    out = []
    for g in range(n_gen):
        options = transmit_options(table, g, max_order)
        if PAIR_MODES[double_beam] == PAIRS_ONCE:
            # A pair is formed from the leg with more reflections (ChainTable.key): transmit
            # chains longer than this generation's receive chains never qualify.
            options = [tx for tx in options if tx == SAME or table.length(tx) <= g]
        for tx in options:
            order = 2 * g + 1 if tx == SAME else g + table.length(tx) + 1
            out.append((g, tx, label_of_order(order) if order > 1 else LABEL_PLANE))
    return out


def option_sets(gen: int, tx: int, ray: np.ndarray, distance: np.ndarray, energy: np.ndarray, beam: np.ndarray,
                beam_tx: np.ndarray, label: np.ndarray, double_beam: str) -> list[PathSet]:
    """The :class:`PathSet` list of one option's paths: with ``double_beam`` ``split``, the
    paths whose legs differ go half to the beam of arrival and half to the transmit beam."""
    if double_beam == "split" and tx != SAME:
        half = 0.5 * energy
        return [PathSet(gen, tx, ray, distance, half, beam, label), PathSet(gen, tx, ray, distance, half, beam_tx, label)]
    return [PathSet(gen, tx, ray, distance, energy, beam, label, beam_tx=beam_tx)]


def form_paths(
    legs: list[Leg],
    table: ChainTable,
    view: SonarView,
    active: np.ndarray,
    n_planes: int,
    rays_per_beam: int,
    max_order: int,
    double_beam: str,
    reflectance: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[PathSet]:
    """Every path of the frame, as compact sets (:func:`option_paths` for each of
    :func:`frame_options`); ``reflectance``: the mirrors' (``SurfaceLaws``), else their constants.

    Parameters
    ----------
    legs : list of Leg
    table : ChainTable
    view : SonarView
    active : (P,) bool array
    n_planes : int
    rays_per_beam : int
        Rays of the fan per beam: ray ``i`` is in beam ``i // rays_per_beam`` (beam-major).
    max_order : int
    double_beam : {'coherent', 'paper', 'split', 'separate'}
    """
    rank = chain_ranks(table)
    no_planes = np.empty(0, np.int32)
    out: list[PathSet] = []
    facets = table.facets
    smooth = []
    for g, tx, row in frame_options(table, len(legs), max_order, double_beam):
        leg = legs[g]
        same = tx == SAME
        c = 0 if same else tx
        if facets is not None and not same and not table.flat(c):
            smooth.append((g, tx, row))  # no image source across a smooth mirror: formed reversed below
            continue
        chain = table.chains[c]
        ray, distance, energy, beam, beam_tx, label = option_paths(
            leg.live_rays(), leg, same, c, table.unfold(c), table.sources(c),
            np.asarray(chain, np.int32) if chain else no_planes, 1.0 if same else table.specular(tx),
            rank, PAIR_MODES[double_beam], row, n_planes, rays_per_beam, view, table.planes, active, facets,
            reflectance,
        )
        if len(ray):
            out += option_sets(g, tx, ray, distance, energy, beam, beam_tx, label, double_beam)
    for g, tx, row in smooth:
        out += reciprocal_sets(legs, table, g, tx, row, rank, view, active, n_planes, rays_per_beam, double_beam,
                               reflectance)
    return out


def reciprocal_sets(legs: list[Leg], table: ChainTable, g: int, tx: int, row: int, rank: np.ndarray, view: SonarView,
                    active: np.ndarray, n_planes: int, rays_per_beam: int, double_beam: str,
                    reflectance: tuple[np.ndarray, np.ndarray] | None = None) -> list[PathSet]:
    """The paths of option ``(g, tx)`` whose transmit chain ``tx`` meets a smooth mirror, formed
    from their reciprocal partners: the receive legs that followed ``tx`` (traced: no image
    source needed), with a transmit leg by image sources along each flat chain ``c`` of
    generation ``g`` that pairs with ``tx`` in this ``double_beam`` mode. A partner has the
    path's length; its energy is weighed, as every path's, by its traced leg (here the one via
    the smooth mirror: the model weighs a path by the ray it traces, so that the two members
    of a pair differ where the mirror is curved, as they do for planes at different ranges);
    the path arrives along ``c``, in the beam its partner's transmit leg leaves in (``swap``)."""
    k = table.length(tx)
    if k >= len(legs):
        return []
    leg = legs[k]
    live = leg.live_rays()
    live = live[leg.chain[live] == tx]
    if not len(live):
        return []
    out: list[PathSet] = []
    for c in partner_chains(table, g, tx, rank, double_beam):
        chain = table.chains[c]
        ray, distance, energy, beam, beam_tx, label = option_paths(
            live, leg, False, c, table.unfold(c), table.sources(c), np.asarray(chain, np.int32), table.specular(c),
            rank, max(PAIR_MODES[double_beam], PAIRS_SEPARATE), row, n_planes, rays_per_beam, view, table.planes,
            active, table.facets, reflectance,
        )
        if len(ray):
            for s in option_sets(k, c, ray, distance, energy, beam_tx, beam, label, double_beam):
                s.swap = True
                out.append(s)
    return out


def partner_chains(table: ChainTable, g: int, tx: int, rank: np.ndarray, double_beam: str) -> list[int]:
    """The flat chains of length ``g`` whose transmit legs pair with the receive legs that
    followed smooth chain ``tx`` (:func:`reciprocal_sets`; the compiled engine's options with
    an ``only`` chain): every one in ``separate``, else those that outrank ``tx`` (the pair is
    formed from the other member, or not at all); a pair of two smooth chains has no image
    source on either side."""
    c = table.flat_of_length(g)
    c = c[c != tx]
    if PAIR_MODES[double_beam] == PAIRS_ONCE:
        c = c[np.asarray(rank)[c] > rank[tx]]
    return c.tolist()


def drop_occluded(sets: list[PathSet], legs: list[Leg], *, table: ChainTable, view: SonarView, active, caster) -> list[PathSet]:
    """``double_line_of_sight``: keep only the paths whose transmit leg no object blocks.

    Every segment of the leg (O -> reflection points -> A) is cast against the objects; the
    last one may end on A itself (to float32 precision). A reflection point on a mesh mirror is
    on an object too: a segment leaves it from :data:`SURFACE_OFFSET_M` along the segment, and
    one that ends on it may meet it within :data:`MIRROR_HIT` of its length.
    """
    n_planes = len(table.planes)
    out = []
    for s in sets:
        if s.tx in (SAME, GLINT) or not len(s.ray):  # (a specular return is traced: seen)
            out.append(s)
            continue
        a = legs[s.gen].point[s.ray]
        chain = table.chains[s.tx]
        q, _ = reflection_points(table.planes, chain, table.sources(s.tx), a, active, table.facets)
        corners = [np.broadcast_to(view.origin, a.shape)] + [q[:, j] for j in range(len(chain))] + [a]
        on_mesh = [False] + [p >= n_planes for p in chain] + [True]  # corners on an object
        free = np.ones(len(a), dtype=bool)
        for k in range(len(corners) - 1):
            seg = corners[k + 1] - corners[k]
            length = np.linalg.norm(seg, axis=1)
            unit = seg / length[:, None]
            lift = SURFACE_OFFSET_M if on_mesh[k] else 0.0
            hit = caster.intersect(corners[k] + lift * unit, unit, float(length.max()) + 1.0)
            last = k == len(corners) - 2
            slack = 1e-3 * np.maximum(length, 1.0) if last else (MIRROR_HIT * np.maximum(length, 1.0)
                                                                 if on_mesh[k + 1] else 0.0)
            free &= hit.distance + lift >= length - slack
        out.append(PathSet(s.gen, s.tx, s.ray[free], s.distance[free], s.energy[free], s.beam[free], s.label[free],
                           s.swap, None if s.beam_tx is None else s.beam_tx[free]))
    return out


def path_corners(s: PathSet, legs: list[Leg], table: ChainTable, view: SonarView, active: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The corners of a path set's legs, from the sonar out: ``O, q_1, ..., q_k, A``.

    The receive leg's corners are where its ray met each earlier generation's surface (where it
    reflected); the transmit leg's are its reflection points (:func:`~sonarsim.paths.planes.reflection_points`),
    or the receive leg's own for :data:`SAME`.

    A specular return (:data:`GLINT`) has no scatterer: its ``tx`` is the traced leg to its
    last mirror and ``rx`` that leg and the point nearest O on the way back.

    Returns
    -------
    tx, rx : (m, k + 2, 3) and (m, gen + 2, 3) float64 ndarrays, metres
    """
    ray = s.ray
    origin = np.broadcast_to(np.asarray(view.origin, float), (len(ray), 3))
    rx = np.stack([origin] + [legs[g].point[ray] for g in range(s.gen + 1)], axis=1)
    if s.tx == GLINT:  # the traced leg out, and back from its last mirror to O's foot on it
        leg = legs[s.gen]
        foot = rx[:, -1] + (leg.back_length[ray] - leg.distance[ray])[:, None] * leg.back_dir[ray]
        return rx, np.concatenate([rx, foot[:, None]], axis=1)
    if s.tx == SAME:
        return rx, rx
    chain = table.chains[s.tx]
    q, _ = reflection_points(table.planes, chain, table.sources(s.tx), rx[:, -1], active, table.facets)
    tx = np.concatenate([origin[:, None, :], q, rx[:, -1:, :]], axis=1)
    return tx, rx


def accumulate_paths(
    sets: list[PathSet], legs: list[Leg], n_surfaces: int, fan_shape: tuple[int, int, int], geometry: tuple,
    n_labels: int, spread: bool,
) -> np.ndarray:
    """Form the image stack of path sets (:func:`splat_set` in a loop).

    Parameters
    ----------
    fan_shape : (n_beams, n_azimuth, n_elevation)
    geometry : (range_min_m, range_resolution_m, n_range_bins, n_beams)
    n_labels : int
    spread : bool
        Range splatting (continuity along the elevation axis).

    Returns
    -------
    (n_labels, n_range_bins, n_beams) float64 ndarray
    """
    n_el = fan_shape[2]
    out = np.zeros((n_labels, geometry[2], geometry[3]))
    keys: dict = {}
    cont: dict = {}
    for s in sets:
        leg = legs[s.gen]
        if s.gen not in keys:
            keys[s.gen] = leg.key(n_surfaces)
            if spread:  # once per generation: every set of it shares the scatterers
                cont[s.gen] = set_continuity(leg.point, leg.normal, keys[s.gen], n_el)
        out += splat_set(leg.point, leg.normal, keys[s.gen], s.ray, s.distance, s.energy, s.beam, s.label, 1.0,
                         spread, n_el, *geometry, n_labels, continuous=cont.get(s.gen))
    return out


def split_by_signature(sets: list[PathSet], legs: list[Leg], table: ChainTable, n_planes: int) -> dict[str, list[PathSet]]:
    """The frame's paths grouped by signature (transmit chain, scatterer, receive chain).

    Returns
    -------
    dict of :func:`path_name` to the path sets (subsets of ``sets``) of that signature.
    """
    groups: dict[str, list[PathSet]] = {}
    names = table.planes.names
    if table.facets is not None:  # mirrors P + m are named by their object
        names = tuple(names) + tuple(table.facets.names[k] for k in table.facets.mirror_obj)
    for s in sets:
        leg = legs[s.gen]
        if s.tx == GLINT:  # no scatterer: named by the mirrors met, ``O-wall-O``
            for c in np.unique(leg.back_chain[s.ray]):
                k = leg.back_chain[s.ray] == c
                name = "-".join(["O", *(names[p] for p in table.chains[int(c)]), "O"])
                groups.setdefault(name, []).append(
                    PathSet(s.gen, s.tx, s.ray[k], s.distance[k], s.energy[k], s.beam[k], s.label[k]))
            continue
        rx = leg.chain[s.ray].astype(np.int64)
        kind = np.minimum(leg.sid[s.ray], n_planes).astype(np.int64)
        code = rx * (n_planes + 1) + kind
        for c in np.unique(code):
            rx_chain = table.chains[int(c) // (n_planes + 1)]
            q = int(c) % (n_planes + 1)
            tx_chain = rx_chain if s.tx == SAME else table.chains[s.tx]
            if s.swap:  # formed from its reciprocal partner: its legs the other way round
                tx_chain, rx_chain = rx_chain, tx_chain
            name = path_name([names[p] for p in tx_chain], "objects" if q == n_planes else names[q],
                             [names[p] for p in rx_chain])
            k = code == c
            groups.setdefault(name, []).append(
                PathSet(s.gen, s.tx, s.ray[k], s.distance[k], s.energy[k], s.beam[k], s.label[k], s.swap,
                        None if s.beam_tx is None else s.beam_tx[k])
            )
    return groups


def path_name(tx: list[str], at: str, rx: list[str]) -> str:
    """Component name of a path signature: the path as the sound travels it.

    ``O-<planes of the transmit leg>-[<scatterer>]-<planes of the receive leg>-O``, e.g.
    ``O-[objects]-O`` (single), ``O-[ground]-O`` (the ground's direct echo),
    ``O-[objects]-ground-O`` (O-A-G-O), ``O-ground-[objects]-ground-O`` (O-G-A-G-O, the
    paper's triple), ``O-surface-[ground]-O`` (the floor lit via the water surface).

    Parameters
    ----------
    tx : list of str
        Planes of the transmit leg in the order the sound meets them.
    at : str
        ``objects`` or the name of the plane whose diffuse part scatters.
    rx : list of str
        Planes of the receive leg in the order met going out from the sonar (the reverse of
        the sound's order).
    """
    return "-".join(["O", *tx, f"[{at}]", *reversed(rx), "O"])


def parse_path_name(name: str) -> tuple[list[str], str, list[str]]:
    """Inverse of :func:`path_name`: ``(tx planes, scatterer, rx planes)``; a specular return's
    name (``O-north-east-O``, no scatterer) gives ``(its mirrors, "", [])``.

    Raises
    ------
    ValueError
        ``name`` is not a path-signature name.
    """
    parts = name.split("-")
    at = [k for k, p in enumerate(parts) if p.startswith("[") and p.endswith("]")]
    if len(parts) >= 3 and parts[0] == "O" and parts[-1] == "O" and not at and "" not in parts:
        return parts[1:-1], "", []  # a specular return (``O-wall-O``): its mirrors, no scatterer
    if len(parts) < 3 or parts[0] != "O" or parts[-1] != "O" or len(at) != 1:
        raise ValueError(f"not a path-signature name: {name!r}")
    k = at[0]
    return parts[1:k], parts[k][1:-1], list(reversed(parts[k + 1:-1]))


#: The ground-only signatures and the component each equals (Algorithm 2 forms those four).
GROUND_SIGNATURES = {
    path_name([], "objects", []): "object", path_name([], "ground", []): "ground",
    path_name([], "objects", ["ground"]): "double", path_name(["ground"], "objects", ["ground"]): "triple",
}


def ground_signatures(images: dict) -> dict[str, np.ndarray]:
    """Path-signature images of a ground-only frame from its order images (Algorithm 2)."""
    return {sig: images[name] for sig, name in GROUND_SIGNATURES.items() if name in images and images[name].any()}
