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
  2/3. Only chains that some receive ray followed this frame are tried: a chain that no ray
  of the fan followed leaves the sonar outside the aperture (up to the ray spacing).
* A path is recorded at half its total length, in the beam of the ray it arrives along,
  weighted by the product of the specular reflectances of both legs times the diffuse
  weight of that ray at A (``beta l(r) rho cos(alpha) dphi``, r the receive leg's length).

When both legs follow the same chain, the transmit leg is the receive leg reversed (the path
O-G-A-G-O of the paper): its length and validity are the ray's own. Legs on different chains
come in reciprocal pairs (O-G-A-O and O-A-G-O, the paper's cases 2 and 3); how they are recorded
is ``render.double_beam`` (see :class:`~sonarsim.scene.RenderSettings`). The default, the
paper's, records each pair once from the leg with more reflections (``ChainTable.key``).

This module is the NumPy twin of the compiled kernels (``_kernels.trace_leg``,
``_kernels.path_events``, ``_kernels.splat_events``); both produce the same :class:`Leg` and
:class:`PathSet` arrays, compared piece by piece in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.radiometry import lambertian_intensity
from ..renderer.formation import RayEnergy, accumulate, continuity
from .planes import ChainTable, PlaneSet, apply, reflection_points

# Reflected rays start this far off the plane so that round-off cannot make them meet it
# again (or the base of an object resting on it), metres.
SURFACE_OFFSET_M = 1e-5

# ``PathSet.tx`` of the paths whose transmit leg is the receive leg reversed.
SAME = -1

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
    normal : (n, 3) float64 ndarray
        Unit normal of the surface at A (either orientation).
    intensity : (n,) float64 ndarray
        Diffuse weight of the ray at A: ``beta l(r) rho cos(alpha) dphi``.
    atten : (n,) float64 ndarray
        Product of the specular reflectances along the leg.
    chain : (n,) int32 ndarray
        Chain id of the leg (:class:`ChainTable`), -1 none.
    """

    gen: int
    distance: np.ndarray
    sid: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    intensity: np.ndarray
    atten: np.ndarray
    chain: np.ndarray

    def key(self, n_surfaces: int) -> np.ndarray:
        """(n,) int32: rays on one surface via one chain share a key (-1 none): continuity."""
        return np.where(self.sid >= 0, self.chain * n_surfaces + self.sid, -1).astype(np.int32)


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
    """

    gen: int
    tx: int
    ray: np.ndarray
    distance: np.ndarray
    energy: np.ndarray
    beam: np.ndarray
    label: np.ndarray


@dataclass(frozen=True)
class SonarView:
    """What the path formation needs of the sonar at its pose.

    Attributes
    ----------
    origin : (3,) float64 ndarray, metres
    rotation : (3, 3) float64 ndarray, sonar-to-world
    beam_edges_deg : (n_beams + 1,) float64 ndarray, descending
    half_elevation_deg : float
    range_min_m, range_max_m : float
    """

    origin: np.ndarray
    rotation: np.ndarray
    beam_edges_deg: np.ndarray
    half_elevation_deg: float
    range_min_m: float
    range_max_m: float

    @classmethod
    def of(cls, sonar) -> "SonarView":
        return cls(
            np.asarray(sonar.pose.translation, float), np.ascontiguousarray(sonar.pose.rotation),
            np.ascontiguousarray(sonar.beam_edges_deg), sonar.elevation_fov_deg / 2.0,
            sonar.range_min_m, sonar.range_max_m,
        )

    def beam_of(self, azimuth_deg: np.ndarray) -> np.ndarray:
        """Beam whose edges contain each azimuth; -1 outside the fan."""
        e = self.beam_edges_deg
        j = np.searchsorted(-e, -np.asarray(azimuth_deg), side="right") - 1
        return np.where((j >= 0) & (j < len(e) - 1), j, -1)


def plane_distances(
    planes: PlaneSet, active: np.ndarray, origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest active plane along each ray, met from the water side.

    Parameters
    ----------
    origins, directions : (m, 3) float arrays (metres; unit vectors)

    Returns
    -------
    t : (m,) float64 ndarray, metres; ``inf`` for none
    plane : (m,) int32 ndarray, -1 for none
    """
    m = len(directions)
    best_t = np.full(m, np.inf)
    best_p = np.full(m, -1, dtype=np.int32)
    for p in np.flatnonzero(active):
        n = planes.normal[p]
        dn = directions @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (planes.offset[p] - origins @ n) / dn
        closer = (dn < 0) & (t > 0) & (t < best_t)
        best_t[closer] = t[closer]
        best_p[closer] = p
    return best_t, best_p


def trace_legs(
    caster,
    planes: PlaneSet,
    active: np.ndarray,
    origin: np.ndarray,
    directions: np.ndarray,
    weight: np.ndarray,
    albedo_by_id: np.ndarray,
    tvg: bool,
    reach_m: float,
    n_generations: int,
    table: ChainTable,
) -> list[Leg]:
    """Receive legs of the fan's rays, generation by generation (NumPy reference).

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
        Ray weights ``beta dphi``.
    albedo_by_id : (P + n_objects + 1,) float array
        Diffuse albedo indexed by surface id + 1.
    tvg : bool
    reach_m : float
        Longest receive leg followed, metres.
    n_generations : int
        1 + the most reflections followed on a receive leg.
    table : ChainTable
        Receives the chains met.
    """
    n = len(directions)
    n_planes = len(planes)
    origin = np.asarray(origin, dtype=float)
    ray = np.arange(n)
    org = np.broadcast_to(origin, (n, 3)).astype(np.float64)
    d = np.asarray(directions, dtype=np.float64)
    before = np.zeros(n)
    atten = np.ones(n)
    chain = np.zeros(n, dtype=np.int32)
    legs = []
    for g in range(n_generations):
        if not len(ray):
            break  # no generation after an empty one
        leg = Leg(
            g, np.full(n, np.inf), np.full(n, -1, np.int32), np.full((n, 3), np.nan), np.zeros((n, 3)),
            np.zeros(n), np.zeros(n), np.full(n, -1, np.int32),
        )
        legs.append(leg)
        limit = float(reach_m - before.min()) if g else float(reach_m)
        hits = caster.intersect(org.astype(np.float32), d.astype(np.float32), limit)
        t = hits.distance.astype(np.float64)
        sid = np.where(hits.mesh_id >= 0, hits.mesh_id + n_planes, -1).astype(np.int32)
        normal = hits.normal.astype(np.float64)
        tp, pp = plane_distances(planes, active, org, d)
        on_plane = (tp < t) & (before + tp <= reach_m)
        t = np.where(on_plane, tp, t)
        sid = np.where(on_plane, pp, sid)
        normal[on_plane] = planes.normal[pp[on_plane]]
        total = before + t
        ok = (sid >= 0) & (total <= reach_m)
        r, t, sid, normal, total = ray[ok], t[ok], sid[ok], normal[ok], total[ok]
        dd, oo = d[ok], org[ok]
        point = oo + dd * t[:, None]
        if g == 0:
            # As the caster reports them: float32 points, normals and incidence.
            point = point.astype(np.float32).astype(np.float64)
            cos = np.abs(np.einsum("ij,ij->i", normal.astype(np.float32), dd.astype(np.float32))).astype(np.float64)
        else:
            cos = np.abs(np.einsum("ij,ij->i", normal, dd))
        leg.distance[r] = total
        leg.sid[r] = sid
        leg.point[r] = point
        leg.normal[r] = normal
        leg.intensity[r] = lambertian_intensity(weight[r], cos, albedo_by_id[sid + 1], total, tvg)
        leg.atten[r] = atten[ok]
        leg.chain[r] = chain[ok]
        # Specular reflection off planes, on to the next generation.
        go = (sid < n_planes) & (total < reach_m)
        go &= planes.specular[np.minimum(sid, n_planes - 1)] > 0 if n_planes else False
        if g + 1 >= n_generations or not np.any(go):
            ray = ray[:0]
            continue
        p = sid[go]
        nrm = planes.normal[p]
        d_ref = dd[go] - 2.0 * np.einsum("ij,ij->i", dd[go], nrm)[:, None] * nrm
        start = point[go].astype(np.float32).astype(np.float64) + SURFACE_OFFSET_M * d_ref
        new_chain = np.array([table.child(int(c), int(q)) for c, q in zip(chain[ok][go], p)], dtype=np.int32)
        ray, org, d = r[go], start, d_ref
        before = total[go] + SURFACE_OFFSET_M
        atten = atten[ok][go] * planes.specular[p]
        chain = new_chain
    return legs


def transmit_legs(
    leg: Leg, tx: int, table: ChainTable, view: SonarView, active: np.ndarray, rays: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Transmit legs via chain ``tx`` to the scatterers of ``rays``.

    Returns
    -------
    length : (m,) float64 ndarray, metres
    beam : (m,) int ndarray
        Beam the leg leaves the sonar in (-1 outside the fan).
    valid : (m,) bool ndarray
        Inside the aperture and range window, reflection points inside the water.
    """
    a = leg.point[rays]
    unfolded = apply(table.unfold(tx), a)
    rel = (unfolded - view.origin) @ view.rotation  # sonar frame
    length = np.linalg.norm(rel, axis=1)
    valid = (length >= view.range_min_m) & (length < view.range_max_m)
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.degrees(np.arcsin(np.clip(rel[:, 2] / length, -1.0, 1.0)))
    valid &= np.abs(el) <= view.half_elevation_deg
    beam = view.beam_of(np.degrees(np.arctan2(rel[:, 1], rel[:, 0])))
    valid &= beam >= 0
    if table.length(tx) and valid.any():
        sel = np.flatnonzero(valid)
        _, ok = reflection_points(table.planes, table.chains[tx], table.sources(tx), a[sel], active)
        valid[sel[~ok]] = False
    return length, beam, valid


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


def form_paths(
    legs: list[Leg],
    table: ChainTable,
    view: SonarView,
    active: np.ndarray,
    n_planes: int,
    beam_of_ray: np.ndarray,
    max_order: int,
    double_beam: str,
) -> list[PathSet]:
    """Every path of the frame, as compact sets (NumPy reference of ``_kernels.path_events``).

    Parameters
    ----------
    legs : list of Leg
    table : ChainTable
    view : SonarView
    active : (P,) bool array
    n_planes : int
    beam_of_ray : (n,) int array
        Beam of each fan ray.
    max_order : int
    double_beam : {'paper', 'split', 'separate'}
    """
    rank = chain_ranks(table)
    out: list[PathSet] = []
    for leg in legs:
        g = leg.gen
        live = np.flatnonzero(np.isfinite(leg.distance) & (leg.intensity != 0))
        for tx in transmit_options(table, g, max_order):
            if tx == SAME:
                rays = live
                label = np.full(len(rays), label_of_order(2 * g + 1), np.int8)
                if g == 0:
                    label = np.where(leg.sid[rays] >= n_planes, LABEL_OBJECT, LABEL_PLANE).astype(np.int8)
                energy = leg.atten[rays] ** 2 * leg.intensity[rays]
                out.append(PathSet(g, SAME, rays, leg.distance[rays], energy, beam_of_ray[rays].astype(np.int32), label))
                continue
            chain = table.chains[tx]
            rc = leg.chain[live]
            keep = rc != tx
            if double_beam != "separate":
                keep &= rank[rc] > rank[tx]
            if chain:
                keep &= leg.sid[live] != chain[-1]
            rays = live[keep]
            length, beam, valid = transmit_legs(leg, tx, table, view, active, rays)
            rays, length, beam = rays[valid], length[valid], beam[valid]
            distance = 0.5 * (leg.distance[rays] + length)
            energy = leg.atten[rays] * table.specular(tx) * leg.intensity[rays]
            label = np.full(len(rays), label_of_order(g + len(chain) + 1), np.int8)
            arrival = beam_of_ray[rays].astype(np.int32)
            if double_beam == "split":
                out.append(PathSet(g, tx, rays, distance, 0.5 * energy, arrival, label))
                out.append(PathSet(g, tx, rays, distance, 0.5 * energy, beam.astype(np.int32), label))
            else:
                out.append(PathSet(g, tx, rays, distance, energy, arrival, label))
    return out


def drop_occluded(sets: list[PathSet], legs: list[Leg], *, table: ChainTable, view: SonarView, active, caster) -> list[PathSet]:
    """``double_line_of_sight``: keep only the paths whose transmit leg no object blocks.

    Every segment of the leg (O -> reflection points -> A) is cast against the objects; the
    last one may end on A itself (to float32 precision).
    """
    out = []
    for s in sets:
        if s.tx == SAME or not len(s.ray):
            out.append(s)
            continue
        a = legs[s.gen].point[s.ray]
        chain = table.chains[s.tx]
        q, _ = reflection_points(table.planes, chain, table.sources(s.tx), a, active)
        corners = [np.broadcast_to(view.origin, a.shape)] + [q[:, j] for j in range(len(chain))] + [a]
        free = np.ones(len(a), dtype=bool)
        for k in range(len(corners) - 1):
            seg = corners[k + 1] - corners[k]
            length = np.linalg.norm(seg, axis=1)
            hit = caster.intersect(corners[k], seg / length[:, None], float(length.max()) + 1.0)
            last = k == len(corners) - 2
            slack = 1e-3 * np.maximum(length, 1.0) if last else 0.0
            free &= hit.distance >= length - slack
        out.append(PathSet(s.gen, s.tx, s.ray[free], s.distance[free], s.energy[free], s.beam[free], s.label[free]))
    return out


def accumulate_paths(
    sets: list[PathSet], legs: list[Leg], n_surfaces: int, fan_shape: tuple[int, int, int], geometry: tuple,
    n_labels: int, spread: bool,
) -> np.ndarray:
    """Form the image stack of path sets with :func:`~sonarsim.imaging.accumulate` (NumPy reference).

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
    n = int(np.prod(fan_shape))
    cont = {}
    rays = []
    for s in sets:
        if s.gen not in cont and spread:
            leg = legs[s.gen]
            key = leg.key(n_surfaces).reshape(fan_shape)
            cont[s.gen] = continuity(leg.point.reshape(fan_shape + (3,)), leg.normal.reshape(fan_shape + (3,)), key)
        dist = np.full(n, np.inf)
        energy = np.zeros(n)
        beam = np.zeros(n, dtype=np.int64)
        label = np.full(n, -1, dtype=np.int64)
        dist[s.ray], energy[s.ray], beam[s.ray], label[s.ray] = s.distance, s.energy, s.beam, s.label
        rays.append(RayEnergy(
            dist.reshape(fan_shape), energy.reshape(fan_shape), beam.reshape(fan_shape), label.reshape(fan_shape),
            cont.get(s.gen),
        ))
    if not rays:
        return np.zeros((n_labels, geometry[2], geometry[3]))
    return accumulate(rays, *geometry, n_labels=n_labels)


def split_by_signature(sets: list[PathSet], legs: list[Leg], table: ChainTable, n_planes: int) -> dict[str, list[PathSet]]:
    """The frame's paths grouped by signature (transmit chain, scatterer, receive chain).

    Returns
    -------
    dict of :func:`path_name` to the path sets (subsets of ``sets``) of that signature.
    """
    groups: dict[str, list[PathSet]] = {}
    names = table.planes.names
    for s in sets:
        leg = legs[s.gen]
        rx = leg.chain[s.ray].astype(np.int64)
        kind = np.minimum(leg.sid[s.ray], n_planes).astype(np.int64)
        code = rx * (n_planes + 1) + kind
        for c in np.unique(code):
            rx_chain = table.chains[int(c) // (n_planes + 1)]
            q = int(c) % (n_planes + 1)
            tx_chain = rx_chain if s.tx == SAME else table.chains[s.tx]
            name = path_name([names[p] for p in tx_chain], "objects" if q == n_planes else names[q],
                             [names[p] for p in rx_chain])
            k = code == c
            groups.setdefault(name, []).append(
                PathSet(s.gen, s.tx, s.ray[k], s.distance[k], s.energy[k], s.beam[k], s.label[k])
            )
    return groups


#: The ground-only signatures and the component each equals (Algorithm 2 forms those four).
GROUND_SIGNATURES = {
    "O-[objects]-O": "object", "O-[ground]-O": "ground",
    "O-[objects]-ground-O": "double", "O-ground-[objects]-ground-O": "triple",
}


def ground_signatures(images: dict) -> dict[str, np.ndarray]:
    """Path-signature images of a ground-only frame from its order images (Algorithm 2)."""
    return {sig: images[name] for sig, name in GROUND_SIGNATURES.items() if name in images and images[name].any()}


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
    """Inverse of :func:`path_name`: ``(tx planes, scatterer, rx planes)``.

    Raises
    ------
    ValueError
        ``name`` is not a path-signature name.
    """
    parts = name.split("-")
    at = [k for k, p in enumerate(parts) if p.startswith("[") and p.endswith("]")]
    if len(parts) < 3 or parts[0] != "O" or parts[-1] != "O" or len(at) != 1:
        raise ValueError(f"not a path-signature name: {name!r}")
    k = at[0]
    return parts[1:k], parts[k][1:-1], list(reversed(parts[k + 1:-1]))
