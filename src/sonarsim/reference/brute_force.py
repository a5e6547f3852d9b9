"""A slow, plainly written reference of the path model, for tests of the fast path engine.

The fast path (:mod:`sonarsim.paths.engine` and its compiled kernels) forms every path of a
frame with tricks: chains numbered as the tracing meets them, transmit legs only for the chains
some receive ray followed, image sources composed as affine maps, twins of compiled loops.
This module computes the same images from first principles, with none of that machinery, so
that the two can be compared image by image:

* **Receive legs** are traced explicitly: every ray of the fan leaves the sonar O; the nearest
  surface (an object through the simulator's caster, an active plane by its own ray-plane
  formula) is a scatterer; on a plane with specular reflectance R > 0 the ray is also
  reflected (``d - 2 (d.n) n``) and goes on, until ``max_order - 1`` reflections or the reach.
* **Mesh mirrors.** The triangles of an object with a specular reflectance are mirrors too,
  flat facets; an object's triangles in one plane are one mirror (numbered ``P + m``, m by
  the mirror's first triangle over the specular objects' triangles in scene order, as
  :mod:`sonarsim.paths.facets` numbers them). A receive ray that meets one both scatters and
  reflects about the triangle's normal, computed here from its corners.
* **Transmit legs** are enumerated over *every* chain of active mirror planes and facets (no
  mirror twice in a row), not only those the receive rays followed. Each is found by
  mirroring the sonar across the chain's mirrors (image sources), walking back from the
  scatterer A towards them, and then **verified** by tracing a ray from O in the departure
  direction found: it must meet the chain's mirrors in order, each nearer than any plane (a
  facet: the ray must cross the triangle itself, by its own ray-triangle formula), and then
  pass within :data:`VERIFY_TOLERANCE_M` of A. The transmit length is the traced length.
* Every path goes into the single range bin of half its length (paper Algorithm 1, no range
  splatting), in the beam of the ray it arrives along.
* A scatter on a textured plane takes the texture's factor at its point
  (:mod:`sonarsim.scene.floor_texture`), whatever path it belongs to.

The model and its conventions (surface ids, reciprocal pairs, apertures, image rows) are those
of :mod:`sonarsim.paths.engine` (README, "Paths over any reflecting planes"). Only
:func:`~sonarsim.paths.engine.path_name` is taken from there, so that the per-signature images
carry the same names.

Everything here is float64 NumPy and loops over generations and chains; it is meant for
small images in tests (a few thousand rays), not for rendering.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..image.grid import beam_azimuth_deg
from ..scene.floor_texture import texture_fields
from ..scene.meshes import object_mesh_world, outer_side
from ..paths.engine import path_name

# Reflected receive rays are cast against the objects from this far off the plane, metres (an
# object resting on the plane must not be met at distance 0).
OFF_PLANE_M = 1e-5

# A traced transmit leg must pass this close to the scatterer, metres.
VERIFY_TOLERANCE_M = 1e-6

# A transmit leg meeting an object this close before A (relative to the leg's last segment,
# at least 1 mm) is taken to meet A itself (the caster reports A to float32 precision).
SELF_HIT_M = 1e-3

# Reach of the receive legs: the range window times this, times 2 when there is multipath
# (a reciprocal pair is recorded at (L_rx + L_tx) / 2 with L_tx >= range_min).
REACH_MARGIN = 1.25
MULTIPATH_FACTOR = 2.0

# Ray-plane distances below this are the plane the ray starts on, metres.
MIN_STEP_M = 1e-9


@dataclass
class ReferencePaths:
    """Every path the reference recorded (also those outside the range window), one row each.

    Attributes
    ----------
    tx_chain, rx_chain : list of tuple of int
        Planes of the transmit and receive legs, both listed going out from the sonar.
    scatterer : (m,) int ndarray
        Surface id of A: plane ``p`` is ``p``, object ``k`` is ``P + k``.
    range_m : (m,) float64 ndarray
        Recorded range ``(L_rx + L_tx) / 2``, metres.
    tx_length_m, rx_length_m : (m,) float64 ndarray
        Leg lengths, metres.
    energy : (m,) float64 ndarray
        Energy of the path (before any split between beams).
    beam : (m,) int ndarray
        Beam of the arriving ray.
    beam_tx : (m,) int ndarray
        Beam the transmit leg leaves the sonar in.
    order : (m,) int ndarray
        Planes met on both legs + 1.
    ray : (m,) int ndarray
        Flat index of the fan ray the path arrives along.
    same : (m,) bool ndarray
        ``True`` where the transmit leg is the receive leg reversed.
    tx_vertices, rx_vertices : list of (k + 2, 3) float64 ndarray
        ``O, q_1, ..., q_k, A``: the legs' corners from the sonar out, metres (only with
        ``keep_legs``; empty lists otherwise).
    """

    tx_chain: list = field(default_factory=list)
    rx_chain: list = field(default_factory=list)
    scatterer: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    range_m: np.ndarray = field(default_factory=lambda: np.empty(0))
    tx_length_m: np.ndarray = field(default_factory=lambda: np.empty(0))
    rx_length_m: np.ndarray = field(default_factory=lambda: np.empty(0))
    energy: np.ndarray = field(default_factory=lambda: np.empty(0))
    beam: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    beam_tx: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    order: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    ray: np.ndarray = field(default_factory=lambda: np.empty(0, int))
    same: np.ndarray = field(default_factory=lambda: np.empty(0, bool))
    tx_vertices: list = field(default_factory=list)
    rx_vertices: list = field(default_factory=list)


@dataclass
class ReferenceImage:
    """What :func:`render_reference` returns.

    Attributes
    ----------
    stack : (max_order + 1, n_range_bins, n_beams) float64 ndarray
        Row 0 the objects' single paths, row 1 the planes' single paths, row k >= 2 order k.
    components : dict of str to (n_range_bins, n_beams) float64 ndarray
        ``object``, ``ground``, ``single``, ``double``, ``triple``, ``order4`` ... and
        ``total`` (every order), as :mod:`sonarsim.renderer.components` names them.
    signatures : dict of str to (n_range_bins, n_beams) float64 ndarray
        One image per path signature, named by :func:`~sonarsim.paths.engine.path_name`.
    paths : ReferencePaths
    rx_chains : set of tuple of int
        The chains some receive ray of the fan travelled along (the fast path tries only
        these as transmit chains; the reference tries every chain).
    plane_names : tuple of str
    """

    stack: np.ndarray
    components: dict
    signatures: dict
    paths: ReferencePaths
    rx_chains: set
    plane_names: tuple


# Geometry, written out ------------------------------------------------------------------


def mirror_point(x: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Mirror image of points across the plane ``n . x = offset``.

    Parameters
    ----------
    x : (..., 3) float array, metres
    normal : (3,) float array, unit
    offset : float, metres

    Returns
    -------
    (..., 3) float64 ndarray: ``x - 2 (n . x - offset) n``.
    """
    x = np.asarray(x, dtype=float)
    h = np.sum(x * normal, axis=-1) - offset
    return x - 2.0 * h[..., None] * normal


def reflect_direction(d: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Specular reflection of directions ``d`` (m, 3) off a plane of unit normal (3,): ``d - 2 (d.n) n``."""
    return d - 2.0 * (d @ normal)[:, None] * normal


def ray_plane_distance(origin: np.ndarray, d: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Distance along rays to a plane met from its water side; ``inf`` where it is not.

    Parameters
    ----------
    origin, d : (m, 3) float arrays
        Ray origins (metres) and unit directions.
    normal : (3,) float array
        Unit normal into the water.
    offset : float
        ``n . x`` on the plane, metres.

    Returns
    -------
    (m,) float64 ndarray, metres: ``(offset - n.o) / (n.d)`` where ``n.d < 0`` and the
    distance exceeds :data:`MIN_STEP_M`.
    """
    dn = d @ normal
    height = origin @ normal - offset  # >= 0 for an origin in the water
    out = np.full(len(d), np.inf)
    towards = dn < 0.0
    t = -height[towards] / dn[towards]
    out[towards] = np.where(t > MIN_STEP_M, t, np.inf)
    return out


def ray_triangle_distance(origin: np.ndarray, d: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Distance along rays to one triangle (either side), ``inf`` where they miss it.

    Parameters
    ----------
    origin, d : (m, 3) float arrays
        Ray origins (metres) and unit directions.
    corners : (3, 3) float array
        The triangle's corners, metres.

    Returns
    -------
    (m,) float64 ndarray, metres: the Moller-Trumbore distance where the ray crosses the
    triangle (edges included) beyond :data:`MIN_STEP_M`.
    """
    a, b, c = (np.asarray(x, dtype=float) for x in corners)
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = p @ e1
    out = np.full(len(d), np.inf)
    ok = np.abs(det) > 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origin - a
        u = np.sum(s * p, axis=1) * inv
        q = np.cross(s, e1)
        v = np.sum(d * q, axis=1) * inv
        t = (q @ e2) * inv
        edge = 1e-9
        ok &= (u >= -edge) & (v >= -edge) & (u + v <= 1.0 + edge) & (t > MIN_STEP_M)
    out[ok] = t[ok]
    return out


class _Facets:
    """The specular objects' triangles as flat mirrors (mirror ``P + m``, an object's triangles
    in one plane), from the simulator's world meshes (clipped to the water, as its caster's); a
    closed object's mirror on their outside only (``side``: +1 the normal's side, -1 the other,
    0 both)."""

    def __init__(self, sim, n_planes: int) -> None:
        objects = sim.scene.objects
        if any(o.specular > 0 and o.normals != "flat" for o in objects):
            raise ValueError("the reference mirrors about flat facets only (normals: flat)")
        self.n_planes = n_planes
        self.object_specular = np.array([o.specular for o in objects], dtype=float)
        counts = [len(m.faces) if o.specular > 0 else 0 for m, o in zip(sim.meshes, objects)]
        self.start = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        tri = [m.vertices[m.faces] for m, c in zip(sim.meshes, counts) if c]
        self.corners = np.concatenate(tri).astype(float) if tri else np.empty((0, 3, 3))
        n = np.cross(self.corners[:, 1] - self.corners[:, 0], self.corners[:, 2] - self.corners[:, 0])
        self.normal = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        self.offset = np.sum(self.normal * self.corners[:, 0], axis=1)
        owner = np.repeat(np.arange(len(objects)), counts)
        # An object's triangles in one plane (normals and offsets within 1e-9) are one mirror,
        # numbered by its first triangle.
        group = np.full(len(owner), -1)
        heads: list = []
        for f in range(len(owner)):
            if group[f] >= 0:
                continue
            same = ((owner == owner[f]) & (np.abs(self.normal - self.normal[f]).max(axis=1) < 1e-9)
                    & (np.abs(self.offset - self.offset[f]) < 1e-9) & (group < 0))
            group[same] = len(heads)
            heads.append(f)
        self.group = group
        self.members = [np.flatnonzero(group == g) for g in range(len(heads))]
        heads = np.array(heads, dtype=int)
        self.normal, self.offset = self.normal[heads], self.offset[heads]  # by mirror from here on
        owner = owner[heads]
        self.specular = self.object_specular[owner] if len(owner) else np.empty(0)
        self.owner_spec = [objects[k] for k in owner]  # each mirror's object (its reflection)
        # A closed object mirrors on its outside only (its whole mesh, before clipping, tells).
        sides = [outer_side(object_mesh_world(o)) if c else 0 for o, c in zip(objects, counts)]
        self.side = np.array(sides, dtype=int)[owner] if len(owner) else np.empty(0, int)
        self.names = tuple(objects[k].name for k in owner)

    def __len__(self) -> int:
        """The number of mirrors."""
        return len(self.members)

    def distance(self, origin: np.ndarray, d: np.ndarray, m: int) -> np.ndarray:
        """(k,) distance along rays to the nearest of mirror ``m``'s triangles (``inf``: none)."""
        out = np.full(len(d), np.inf)
        for f in self.members[m]:
            out = np.minimum(out, ray_triangle_distance(origin, d, self.corners[f]))
        return out


def all_chains(mirrors: list[int], longest: int) -> list[tuple[int, ...]]:
    """Every sequence of the mirrors with no mirror twice in a row, empty first, by length."""
    out: list[tuple[int, ...]] = [()]
    for k in range(1, longest + 1):
        out += [c for c in itertools.product(mirrors, repeat=k) if all(a != b for a, b in zip(c, c[1:]))]
    return out


def chain_key(chain: tuple[int, ...]) -> tuple:
    """Order of chains for the reciprocal-pair conventions: more planes first, then by ids."""
    return (len(chain), chain)


# The reference --------------------------------------------------------------------------


class _Planes:
    """The scene's planes as plain arrays (the ground first, as ``Scene.reflecting_planes``)."""

    def __init__(self, specs) -> None:
        self.names = tuple(p.name for p in specs)
        self.normal = np.array([p.normal for p in specs], dtype=float).reshape(-1, 3)
        self.normal /= np.maximum(np.linalg.norm(self.normal, axis=1, keepdims=True), 1e-300)
        point = np.array([p.point_m for p in specs], dtype=float).reshape(-1, 3)
        self.offset = np.sum(self.normal * point, axis=1)
        self.specular = np.array([p.specular for p in specs], dtype=float)
        self.specs = tuple(specs)

    def __len__(self) -> int:
        return len(self.names)


def _reflectance(spec, cos_incidence: np.ndarray, frequency_hz: float | None, sound_speed_m_s: float) -> np.ndarray:
    """A mirror's reflectance at ``|cos(incidence)|``: its ``reflection``'s formulas
    (``Reflection.evaluate``, not the kernels' table), else its constant ``specular``."""
    c = np.asarray(cos_incidence, dtype=float)
    if spec.reflection is None:
        return np.full(c.shape, float(spec.specular))
    return spec.reflection.evaluate(c, spec.material, frequency_hz, sound_speed_m_s)


def _medium(sim, sonar) -> tuple[float | None, float]:
    """``(frequency Hz or None, the water's sound speed m/s)`` the mirrors reflect at (the
    sonar's frequency, else the sensor's, as the simulator's)."""
    spec = sim.scene.sensor
    khz = sonar.frequency_khz if sonar.frequency_khz is not None else (spec.frequency_khz if spec else None)
    return (None if khz is None else khz * 1e3), sim.water_speed_m_s()


def _receive_legs(sim, planes: _Planes, facets: _Facets, active: np.ndarray, origin: np.ndarray,
                  directions: np.ndarray, weight: np.ndarray, tvg: bool, reach: float, n_reflections: int,
                  keep_legs: bool, medium: tuple[float | None, float] = (None, 1500.0)) -> dict:
    """Trace the fan's rays with reflections; one scatter event per ray and generation.

    Returns
    -------
    dict of arrays over the events: ``ray``, ``gen``, ``chain`` (list of tuples), ``sid``,
    ``facet`` (the mirror ``P + f`` of the scatterer's triangle on a specular object, else -1),
    ``point`` (m, 3), ``length`` (receive leg, metres), ``atten`` (product of R),
    ``weight`` (diffuse weight at A), ``vertices`` (list of (g + 2, 3) arrays, or empty);
    ``followed``: the set of chains some ray travelled along (whether or not it met anything).
    """
    n_planes = len(planes)
    # Surface id s: plane s, then object s - P.
    materials = [p.backscatter for p in sim.scene.reflecting_planes] + [o.backscatter for o in sim.scene.objects]
    # Reflectivity textures, made here from the scene (not taken from the simulator).
    textures = texture_fields(sim.scene.reflecting_planes, sim.scene.render.seed)
    n = len(directions)
    ray = np.arange(n)
    start = np.repeat(origin[None, :], n, axis=0)
    d = directions.copy()
    before = np.zeros(n)
    atten = np.ones(n)
    chains: list[tuple[int, ...]] = [()] * n
    corners = np.repeat(origin[None, None, :], n, axis=0)  # (m, g + 1, 3): the leg's corners so far
    events: dict = {k: [] for k in ("ray", "gen", "sid", "facet", "point", "length", "atten", "weight")}
    events["chain"], events["vertices"] = [], []
    followed: set = set()
    for gen in range(n_reflections + 1):
        if not len(ray):
            break
        followed.update(chains)
        # Objects: from O itself, or just off the plane the ray was reflected at.
        lift = 0.0 if gen == 0 else OFF_PLANE_M
        cast_from = (start + lift * d).astype(np.float32)
        hits = sim.caster.intersect(cast_from, d.astype(np.float32), float(reach - before.min()), with_uv=True)
        hit = np.asarray(hits.mesh_id) >= 0
        t = np.where(hit, np.asarray(hits.distance, dtype=float) + lift, np.inf)
        sid = np.where(hit, n_planes + np.asarray(hits.mesh_id), -1)
        nrm = np.where(hit[:, None], np.asarray(hits.normal, dtype=float), 0.0)
        # Planes: the nearest active one met from the water side, if nearer than the object.
        for p in range(n_planes):
            if not active[p]:
                continue
            tp = ray_plane_distance(start, d, planes.normal[p], planes.offset[p])
            nearer = tp < t
            t[nearer] = tp[nearer]
            sid[nearer] = p
            nrm[nearer] = planes.normal[p]
        length = before + t
        ok = (sid >= 0) & (length <= reach)
        k = np.flatnonzero(ok)
        a = start[k] + t[k, None] * d[k]
        cos = np.abs(np.sum(nrm[k] * d[k], axis=1))
        s = sid[k]
        # The scatterer's triangle, where its object mirrors: mirror P + start + triangle.
        mirror = np.full(len(k), -1)
        if len(facets):
            obj = np.clip(s - n_planes, 0, len(facets.object_specular) - 1)
            on = (s >= n_planes) & (facets.object_specular[obj] > 0)
            mirror[on] = n_planes + facets.group[facets.start[obj[on]] + np.asarray(hits.primitive_id)[k][on]]
            # Met from the side it mirrors on.
            f = mirror[on] - n_planes
            side = facets.side[f]
            dn = np.sum(d[k][on] * facets.normal[f], axis=1)
            mirror[np.flatnonzero(on)[(side != 0) & (side * dn >= 0)]] = -1
        texel = np.ones(len(k)) if hits.texel is None else np.where(s >= n_planes, hits.texel[k], 1.0)
        law = np.zeros(len(k))
        for q in np.unique(s):
            on = s == q
            law[on] = materials[q].evaluate(cos[on], texel[on], *medium)
        for q, field in enumerate(textures):
            if field is not None:
                on = s == q
                law[on] *= field.factor(a[on])
        w = weight[ray[k]] * law
        if not tvg:
            w = w / length[k] ** 2
        events["ray"].append(ray[k])
        events["gen"].append(np.full(len(k), gen))
        events["sid"].append(s)
        events["facet"].append(mirror)
        events["point"].append(a)
        events["length"].append(length[k])
        events["atten"].append(atten[k])
        events["weight"].append(w)
        events["chain"] += [chains[i] for i in k]
        if keep_legs:  # corners from the sonar out: O, reflection points, A
            events["vertices"] += list(np.concatenate([corners[k], a[:, None, :]], axis=1))
        # Reflect off mirror planes, while reflections and reach remain.
        if gen == n_reflections:
            break
        go = (s < n_planes) & (length[k] < reach)
        if n_planes:
            go &= planes.specular[np.minimum(s, n_planes - 1)] > 0.0
        go |= (mirror >= 0) & (length[k] < reach)
        g = k[go]
        p = np.where(mirror[go] >= 0, mirror[go], s[go])
        new_d = np.empty((len(g), 3))
        r = np.empty(len(g))
        for q in np.unique(p):
            sel = p == q
            n = planes.normal[q] if q < n_planes else facets.normal[q - n_planes]
            spec = planes.specs[q] if q < n_planes else facets.owner_spec[q - n_planes]
            new_d[sel] = reflect_direction(d[g[sel]], n)
            r[sel] = _reflectance(spec, np.abs(d[g[sel]] @ n), *medium)
        ray, start, d = ray[g], a[go], new_d
        before, atten = length[g], atten[g] * r
        chains = [chains[i] + (int(q),) for i, q in zip(g, p)]
        corners = np.concatenate([corners[g], start[:, None, :]], axis=1)
    out = {key: (np.concatenate(v) if v else np.empty(0)) for key, v in events.items()
           if key not in ("chain", "vertices")}
    out["point"] = out["point"].reshape(-1, 3)
    out["ray"] = out["ray"].astype(int)
    out["gen"] = out["gen"].astype(int)
    out["sid"] = out["sid"].astype(int)
    out["facet"] = out["facet"].astype(int)
    out["chain"], out["vertices"] = events["chain"], events["vertices"]
    out["followed"] = followed
    return out


def _transmit_legs(planes: _Planes, facets: _Facets, active: np.ndarray, origin: np.ndarray,
                   chain: tuple[int, ...], a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Transmit legs from the sonar to scatterers ``a`` via ``chain``: image sources, then a traced check.

    Parameters
    ----------
    planes : _Planes
    facets : _Facets
    active : (P,) bool array
    origin : (3,) float array
        The sonar O, metres.
    chain : tuple of int
        Mirrors in the order the sound meets them leaving O (``P + f``: facet f).
    a : (m, 3) float array
        Scatterers, metres.

    Returns
    -------
    valid : (m,) bool ndarray
        The traced ray meets the chain's mirrors in order, each nearer than any other active
        plane (a facet: crossing its triangle), then passes within :data:`VERIFY_TOLERANCE_M`
        of A before any plane.
    length : (m,) float64 ndarray
        Traced length from O to A, metres (NaN where not valid).
    departure : (m, 3) float64 ndarray
        Unit direction the leg leaves O in (world frame).
    vertices : (m, len(chain) + 2, 3) float64 ndarray
        ``O, q_1, ..., q_k, A`` along the traced leg (the last is the point of the traced ray
        nearest A).
    """
    m, k = len(a), len(chain)
    n_planes = len(planes)

    def plane_of(p: int) -> tuple[np.ndarray, float]:
        if p < n_planes:
            return planes.normal[p], planes.offset[p]
        return facets.normal[p - n_planes], facets.offset[p - n_planes]

    # Image sources: the sonar mirrored across the chain's mirrors in turn.
    sources = [origin]
    for p in chain:
        sources.append(mirror_point(sources[-1], *plane_of(p)))
    # Walk back from A towards the images: the straight line from A to the last image crosses
    # the last plane at the last reflection point, and so on back to the sonar.
    x = np.array(a, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(k, 0, -1):
            n, off = plane_of(chain[j - 1])
            towards = sources[j] - x
            s = (off - x @ n) / (towards @ n)
            x = x + s[:, None] * towards
        first = x if k else np.array(a, dtype=float)
        departure = first - origin
        departure = departure / np.linalg.norm(departure, axis=1, keepdims=True)
    valid = np.all(np.isfinite(departure), axis=1)
    departure = np.where(valid[:, None], departure, np.array([1.0, 0.0, 0.0]))
    # Verify: trace a ray from O along the departure direction, reflecting at each plane met.
    pos = np.repeat(origin[None, :], m, axis=0)
    d = departure.copy()
    length = np.zeros(m)
    vertices = np.empty((m, k + 2, 3))
    vertices[:, 0] = origin
    act = np.flatnonzero(active)
    for j in range(k + 1):
        dist = np.full((m, len(act)), np.inf)
        for col, p in enumerate(act):
            dist[:, col] = ray_plane_distance(pos, d, planes.normal[p], planes.offset[p])
        nearest = act[np.argmin(dist, axis=1)] if len(act) else np.full(m, -1)
        t_near = dist.min(axis=1) if len(act) else np.full(m, np.inf)
        if j < k:
            p = chain[j]
            if p < n_planes:
                valid &= (nearest == p) & np.isfinite(t_near)
                t_step = np.where(np.isfinite(t_near), t_near, 0.0)
            else:  # the facet's triangle, met before any plane
                t_facet = facets.distance(pos, d, p - n_planes)
                valid &= np.isfinite(t_facet) & (t_facet < t_near)
                side = facets.side[p - n_planes]
                if side:  # from the side it mirrors on
                    valid &= side * (d @ facets.normal[p - n_planes]) < 0
                t_step = np.where(np.isfinite(t_facet), t_facet, 0.0)
            pos = pos + t_step[:, None] * d
            length += t_step
            vertices[:, j + 1] = pos
            d = reflect_direction(d, plane_of(p)[0])
        else:
            # The last segment must pass through A, before it leaves the water.
            rel = a - pos
            along = np.sum(rel * d, axis=1)
            miss = np.linalg.norm(rel - along[:, None] * d, axis=1)
            valid &= (along > 0.0) & (miss <= VERIFY_TOLERANCE_M) & (along <= t_near + VERIFY_TOLERANCE_M)
            length += along
            vertices[:, k + 1] = pos + along[:, None] * d
    return valid, np.where(valid, length, np.nan), departure, vertices


def _in_aperture(sonar, pose, departure: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which world directions (m, 3) leave the sonar inside its fan and elevation aperture.

    Returns
    -------
    inside : (m,) bool ndarray
    beam : (m,) int ndarray
        Beam whose azimuth edges contain the direction (-1 outside the fan).
    """
    v = departure @ np.asarray(pose.rotation, dtype=float)  # R^T d, row by row
    azimuth = beam_azimuth_deg(v, getattr(sonar, "beam_shape", "plane") == "cone")
    elevation = np.degrees(np.arcsin(np.clip(v[:, 2] / np.linalg.norm(v, axis=1), -1.0, 1.0)))
    edges = np.asarray(sonar.beam_edges_deg, dtype=float)  # descending, left-most beam first
    beam = np.full(len(v), -1)
    for j in range(len(edges) - 1):
        beam[(azimuth <= edges[j]) & (azimuth > edges[j + 1])] = j
    inside = (beam >= 0) & (np.abs(elevation) <= sonar.elevation_fov_deg / 2.0)
    return inside, beam


def _unoccluded(sim, vertices: np.ndarray, on_mirror: list | None = None) -> np.ndarray:
    """(m,) bool: no object lies on any segment of legs given by their corners (m, k + 2, 3).

    The last segment ends on the scatterer A itself, which the caster may report a little
    before A: a hit within :data:`SELF_HIT_M` (relative, at least 1 mm) of A counts as A.
    ``on_mirror[j]``: corner j is a reflection point on a mesh mirror, itself an object: a
    segment leaves it from :data:`OFF_PLANE_M` on, and one ending on it may meet it within
    ``1e-5`` of its length (float32 hits).
    """
    m, n_corners = vertices.shape[:2]
    on_mirror = on_mirror or [False] * n_corners
    free = np.ones(m, dtype=bool)
    for j in range(n_corners - 1):
        seg = vertices[:, j + 1] - vertices[:, j]
        span = np.linalg.norm(seg, axis=1)
        unit = seg / span[:, None]
        lift = OFF_PLANE_M if on_mirror[j] else 0.0
        hits = sim.caster.intersect((vertices[:, j] + lift * unit).astype(np.float32), unit.astype(np.float32),
                                    float(span.max()) + 1.0)
        t = np.asarray(hits.distance, dtype=float) + lift
        if j == n_corners - 2:
            slack = SELF_HIT_M * np.maximum(span, 1.0)
        else:
            slack = 1e-5 * np.maximum(span, 1.0) if on_mirror[j + 1] else 0.0
        free &= ~(t < span - slack)
    return free


def render_reference(sim, sonar=None, pose=None, *, max_order: int | None = None, double_beam: str | None = None,
                     double_line_of_sight: bool | None = None, keep_legs: bool = False) -> ReferenceImage:
    """Render one frame with the reference path model (Algorithm 1, no range splatting).

    Parameters
    ----------
    sim : Simulator
        Gives the scene (planes, objects' albedo, render settings), the ray fan
        (``sim.ray_fan``) and the objects' caster (``sim.caster``, meshes clipped to the water).
    sonar : SonarConfig, optional
        The sonar's intrinsics; default the scene's.
    pose : Pose, optional
        The sonar's pose; default the scene's (``scene.sonar_pose``).
    max_order, double_beam, double_line_of_sight : optional
        Override the scene's ``render`` settings of those names.
    keep_legs : bool
        Keep every path's corners (:attr:`ReferencePaths.tx_vertices`, ``rx_vertices``).

    Returns
    -------
    ReferenceImage
        Images of shape ``(n_range_bins, n_beams)`` in float64.
    """
    render = sim.scene.render
    sonar = sim.scene.sonar if sonar is None else sonar
    pose = sim.scene.sonar_pose if pose is None else pose
    max_order = render.max_order if max_order is None else int(max_order)
    double_beam = render.double_beam if double_beam is None else double_beam
    los = render.double_line_of_sight if double_line_of_sight is None else bool(double_line_of_sight)
    if double_beam not in ("coherent", "paper", "split", "separate"):
        raise ValueError(f"double_beam must be 'coherent', 'paper', 'split' or 'separate', got {double_beam!r}")

    planes = _Planes(sim.scene.reflecting_planes)
    n_planes = len(planes)
    facets = _Facets(sim, n_planes)
    origin = np.asarray(pose.translation, dtype=float).reshape(3)
    rotation = np.asarray(pose.rotation, dtype=float)
    # A plane takes part only when the sonar is on its water side.
    active = (planes.normal @ origin - planes.offset) > 0.0 if n_planes else np.zeros(0, bool)
    mirrors = [p for p in range(n_planes) if active[p] and planes.specular[p] > 0.0]
    mirrors += [n_planes + f for f in range(len(facets))]
    multipath = max_order > 1 and bool(mirrors)
    reach = sonar.range_max_m * REACH_MARGIN * (MULTIPATH_FACTOR if multipath else 1.0)
    n_reflections = max_order - 1 if multipath else 0

    fan = sim.ray_fan(sonar)
    directions = fan.directions.reshape(-1, 3) @ rotation.T
    weight = np.asarray(fan.weight, dtype=float).reshape(-1)
    per_beam = len(directions) // sonar.n_beams
    medium = _medium(sim, sonar)
    ev = _receive_legs(sim, planes, facets, active, origin, directions, weight, render.tvg, reach, n_reflections,
                       keep_legs, medium)
    rx_chains = ev["followed"]

    # One row per path: (tx chain, rx chain, sid, range, L_tx, L_rx, energy, beam, beam_tx, order,
    # ray, same, event, tx corners).
    rows: list = []
    chains = all_chains(mirrors, n_reflections)
    number = {c: i for i, c in enumerate(chains)}
    rank = np.empty(len(chains), dtype=int)
    rank[sorted(range(len(chains)), key=lambda i: chain_key(chains[i]))] = np.arange(len(chains))
    rx_id = np.array([number[c] for c in ev["chain"]], dtype=int)
    for c, tx in enumerate(chains):
        allowed = ev["gen"] + len(tx) + 1 <= max_order
        same = (rx_id == c) & allowed
        # The receive leg reversed: the same chain, the same length, always valid.
        for i in np.flatnonzero(same & (ev["weight"] != 0.0)):
            rows.append((tx, tx, ev["sid"][i], ev["length"][i], ev["length"][i], ev["length"][i],
                         ev["atten"][i] ** 2 * ev["weight"][i], ev["ray"][i] // per_beam, ev["ray"][i] // per_beam,
                         2 * len(tx) + 1, ev["ray"][i], True, i, None))
        other = allowed & ~same & (ev["weight"] != 0.0)
        if tx:
            # The chain ends on the scatterer's own plane or triangle.
            other &= (ev["sid"] != tx[-1]) if tx[-1] < n_planes else (ev["facet"] != tx[-1])
        if double_beam not in ("separate", "coherent"):
            other &= rank[rx_id] > rank[c]  # each reciprocal pair once, from the greater receive chain
        idx = np.flatnonzero(other)
        if not len(idx):
            continue
        valid, length, departure, vertices = _transmit_legs(planes, facets, active, origin, tx, ev["point"][idx])
        inside, beam_tx = _in_aperture(sonar, pose, departure)
        ok = valid & inside & (length >= sonar.range_min_m) & (length < sonar.range_max_m)
        if los and ok.any():
            sel = np.flatnonzero(ok)
            ok[sel] &= _unoccluded(sim, vertices[sel], [False] + [p >= n_planes for p in tx] + [True])
        # Each reflection of the traced transmit leg at its own incidence: the segment arriving
        # at corner j + 1 against mirror tx[j]'s normal.
        r_tx = np.ones(len(idx))
        for j, p in enumerate(tx):
            seg = vertices[:, j + 1] - vertices[:, j]
            with np.errstate(invalid="ignore", divide="ignore"):
                seg = seg / np.linalg.norm(seg, axis=1, keepdims=True)
            n = planes.normal[p] if p < n_planes else facets.normal[p - n_planes]
            spec = planes.specs[p] if p < n_planes else facets.owner_spec[p - n_planes]
            with np.errstate(invalid="ignore"):
                r_tx *= np.nan_to_num(_reflectance(spec, np.abs(seg @ n), *medium), nan=0.0)
        for j in np.flatnonzero(ok):
            i = idx[j]
            # coherent: the partner arrives in the same beam with the same length, amplitudes add
            both = 2.0 if double_beam == "coherent" and beam_tx[j] == ev["ray"][i] // per_beam else 1.0
            rows.append((tx, ev["chain"][i], ev["sid"][i], 0.5 * (ev["length"][i] + length[j]), length[j],
                         ev["length"][i], both * ev["atten"][i] * r_tx[j] * ev["weight"][i], ev["ray"][i] // per_beam,
                         beam_tx[j], len(tx) + ev["gen"][i] + 1, ev["ray"][i], False, i, vertices[j]))

    paths = ReferencePaths()
    if rows:
        cols = list(zip(*rows))
        paths = ReferencePaths(
            tx_chain=list(cols[0]), rx_chain=list(cols[1]), scatterer=np.array(cols[2], int),
            range_m=np.array(cols[3], float), tx_length_m=np.array(cols[4], float),
            rx_length_m=np.array(cols[5], float), energy=np.array(cols[6], float), beam=np.array(cols[7], int),
            beam_tx=np.array(cols[8], int), order=np.array(cols[9], int), ray=np.array(cols[10], int),
            same=np.array(cols[11], bool),
        )
        if keep_legs:
            for r in rows:
                rx_leg = ev["vertices"][r[12]]
                paths.rx_vertices.append(rx_leg)
                paths.tx_vertices.append(rx_leg if r[11] else r[13])

    # Algorithm 1: each path's energy into the bin of its range, in its beam.
    n_bins, n_beams = sonar.n_range_bins, sonar.n_beams
    dr = (sonar.range_max_m - sonar.range_min_m) / n_bins
    stack = np.zeros((max_order + 1, n_bins, n_beams))
    signatures: dict = {}
    names = planes.names + facets.names  # a facet is named by its object
    for k in range(len(paths.energy)):
        b = int(np.floor((paths.range_m[k] - sonar.range_min_m) / dr))
        if not 0 <= b < n_bins:
            continue
        order = int(paths.order[k])
        sid = int(paths.scatterer[k])
        row = order if order > 1 else (1 if sid < n_planes else 0)
        at = names[sid] if sid < n_planes else "objects"
        name = path_name([names[p] for p in paths.tx_chain[k]], at, [names[p] for p in paths.rx_chain[k]])
        image = signatures.setdefault(name, np.zeros((n_bins, n_beams)))
        e = float(paths.energy[k])
        if double_beam == "split" and not paths.same[k]:
            deposits = ((int(paths.beam[k]), 0.5 * e), (int(paths.beam_tx[k]), 0.5 * e))
        else:
            deposits = ((int(paths.beam[k]), e),)
        for beam, energy in deposits:
            stack[row, b, beam] += energy
            image[b, beam] += energy

    components = {"object": stack[0], "ground": stack[1], "single": stack[0] + stack[1]}
    for k in range(2, max_order + 1):
        components[{2: "double", 3: "triple"}.get(k, f"order{k}")] = stack[k]
    components["total"] = stack.sum(axis=0)
    return ReferenceImage(stack, components, signatures, paths, rx_chains, planes.names)
