"""The discrete search of one frame, held fixed: what the differentiable engine re-forms.

The compiled engine (:class:`~sonarsim.renderer.simulator.Simulator`) finds every path of a
frame: which surfaces its receive leg meets and in which order (``sid``, ``prim``, ``uv``,
``chain``), which transmit option it takes, which fan ray it arrives along (see
``docs/path-buffer.md``). :func:`record_search` copies that answer into a :class:`Search`:
flat NumPy arrays, one entry per path, that name surfaces, triangles and planes by index and
hold nothing continuous that the parameters could move. Everything continuous (points, lengths,
incidences, weights, ranges, energies, the splat) is formed again from the parameters by
:mod:`sonarsim.diff.forward`.

What the search decides and the record keeps:

* per path: its fan ray, its receive generation ``g`` and the ``g`` mirrors its receive leg
  reflects off (from the sonar: a plane, or the triangle of a mirroring object it met), the
  surface it scatters on (a plane, or an object's triangle: an index into the object's own
  mesh faces, before the planes clip it), its transmit leg (the receive leg reversed, or a
  chain of mirrors: planes, and for a mesh mirror its first triangle, whose plane it is), its
  image row, the beam it is recorded in, and which signature it belongs to;
* the continuity of range splatting: which path is each path's neighbour in its ray column
  (``continuity`` tests on the frame's points, held like the rest: the splat's support moves
  with the ranges, its topology does not);
* factors that are functions of position but not parameters here: a textured object's texel
  and a textured plane's reflectivity at the scatterer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config.scene import ON_PLANE_TOLERANCE_M, check_sonar_position
from ..errors import ConfigError
from ..paths.engine import SAME, path_name, set_continuity
from ..renderer.components import stack_rows
from ..renderer.simulator import Simulator
from ..scene.floor_texture import scale_by_texture
from ..scene.meshes import object_mesh_local


@dataclass(frozen=True)
class Search:
    """One frame's paths as the discrete search found them (NumPy, read-only by convention).

    Attributes
    ----------
    n_paths : int
        Real paths; the arrays are padded to ``capacity`` with paths of no energy (``live``
        False), so that frames of similar size share one compiled function.
    ray : (C,) int64
        Fan ray each path arrives along (beam-major, ``ray // n_elevation`` its ray column).
    gen : (C,) int64
        Reflections on the receive leg.
    rx_planes : (C, G - 1) int64
        The receive leg's mirrors from the sonar (``-1`` beyond ``gen``): plane ``p`` is ``p``,
        the ``k``-th triangle of :attr:`faces` is ``P + k`` (a mesh mirror's, as it met it).
    surface : (C,) int64
        Row of the scatterer in the frame's scatterer table: plane ``p`` is ``p``, the
        ``k``-th triangle of :attr:`faces` is ``P + k``.
    sid : (C,) int64
        Surface id of the scatterer (plane ``p``, object ``P + k``): its law.
    same : (C,) bool
        The transmit leg is the receive leg reversed.
    tx_planes : (C, L) int64
        The transmit chain's mirrors from the sonar (``-1`` beyond its length), numbered as
        ``rx_planes`` (a mesh mirror by its first triangle).
    label : (C,) int64
        Image-stack row.
    beam : (C,) int64
        Beam the path is recorded in.
    factor : (C,) float64
        Held factors of the whole weight: 0.5 for each half of a ``double_beam: split`` pair,
        a textured plane's reflectivity at the scatterer; 0 on padding.
    down, up : (C,) int64
        The path's neighbour below and above in its ray column within its path set (itself
        where there is none).
    has_down, has_up : (C,) bool
        Whether that neighbour is on one continuous surface (range splatting).
    signature : (C,) int64
        Index into :attr:`signatures`.
    live : (C,) bool
    texel : (C,) float64
        A textured object's texture at its scatterer (1 elsewhere): it scales the law's
        diffuse coefficient only, not a rough law's lobe.
    uv : (C, 2) float64
        Where an object's scatterer lies on its triangle of :attr:`faces` (its own face's
        corners ``a, b, c``: ``A = (1 - u - v) a + u b + v c``); 0 for planes.
    distance : (C,) float64
        The range the compiled engine recorded for each path, metres (for diagnostics: the
        forward forms its own).
    faces : (F, 2) int64
        The triangles scattered on or reflected off: ``(object index, face index into its
        local mesh)``, sorted.
    signatures : tuple of str
        Path-signature names (:func:`~sonarsim.paths.engine.path_name`).
    n_rows : int
        Rows of the image stack.
    n_planes : int
        Planes of the scene (scatterer rows below it are planes).
    """

    n_paths: int
    ray: np.ndarray
    gen: np.ndarray
    rx_planes: np.ndarray
    surface: np.ndarray
    sid: np.ndarray
    same: np.ndarray
    tx_planes: np.ndarray
    label: np.ndarray
    beam: np.ndarray
    factor: np.ndarray
    down: np.ndarray
    up: np.ndarray
    has_down: np.ndarray
    has_up: np.ndarray
    signature: np.ndarray
    live: np.ndarray
    uv: np.ndarray
    texel: np.ndarray
    distance: np.ndarray
    faces: np.ndarray
    signatures: tuple[str, ...]
    n_rows: int
    n_planes: int = 0

    @property
    def capacity(self) -> int:
        return len(self.ray)

    def arrays(self) -> dict[str, np.ndarray]:
        """The per-path arrays and :attr:`faces`, by name (what the forward function reads)."""
        names = ("ray", "gen", "rx_planes", "surface", "sid", "same", "tx_planes", "label", "beam", "factor",
                 "down", "up", "has_down", "has_up", "signature", "live", "uv", "texel")
        return {k: getattr(self, k) for k in names}


def barycentric(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 2) barycentric ``(u, v)`` of points (m, 3) on triangles (m, 3, 3): ``p = (1 - u - v)
    a + u b + v c`` for the point's projection on the triangle's plane."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2, d = b - a, c - a, points - a
    d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
    den = d11 * d22 - d12 * d12
    den = np.where(den == 0, 1.0, den)
    return np.stack([(d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den], axis=1)


def padded_size(n: int, minimum: int = 1024) -> int:
    """The capacity for ``n`` paths: the next multiple of an eighth of the power of two below
    it (at most an eighth more than needed; a refreshed search of about the same size reuses
    the compiled function)."""
    if n <= minimum:
        return minimum
    step = 1 << max(int(n).bit_length() - 4, 0)
    return -(-n // step) * step


def clipped_face_sources(sim: Simulator) -> list[np.ndarray]:
    """For each object, the face of its local mesh that each face of the caster's mesh lies
    in (the planes clip a mesh: kept faces are a subset in order, cut pieces are appended).

    Returns
    -------
    list of (n_faces_k,) int64 ndarrays
    """
    out = []
    for obj, mesh in zip(sim.scene.objects, sim.meshes):
        local = object_mesh_local(obj)
        faces0 = np.asarray(local.faces, np.int64)
        n0 = len(local.vertices)
        src = np.empty(len(mesh.faces), np.int64)
        world0 = np.asarray(mesh.vertices[:n0], float)  # the clip keeps the posed vertices first
        tri0 = world0[faces0]
        e1, e2 = tri0[:, 1] - tri0[:, 0], tri0[:, 2] - tri0[:, 0]
        nrm = np.cross(e1, e2)
        # Kept faces, all at once: a face's sorted corners as one integer, looked up among the
        # local faces' (a scene of thousands of objects has millions of faces).
        faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
        found = np.zeros(len(faces), bool)
        if len(faces0) and len(faces) and n0 < 2 ** 20:
            def code(f):
                f = np.sort(f, axis=1)
                return (f[:, 0] * n0 + f[:, 1]) * n0 + f[:, 2]

            keys0 = code(faces0)
            order = np.argsort(keys0, kind="stable")
            keys = code(np.minimum(faces, n0 - 1))
            # (the last of equal keys, as the dictionary below keeps it)
            at = np.maximum(np.searchsorted(keys0[order], keys, side="right") - 1, 0)
            found = (faces.max(axis=1) < n0) & (keys0[order][at] == keys)
            src[found] = order[at[found]]
        rest = np.flatnonzero(~found).tolist()
        index = {tuple(sorted(f)): i for i, f in enumerate(faces0.tolist())} if rest else {}
        for j in rest:
            f = faces[j].tolist()
            key = tuple(sorted(f))
            if max(f) < n0 and key in index:
                src[j] = index[key]
                continue
            # A piece cut from a face: the face whose plane holds its centroid, and which holds it.
            c = np.asarray(mesh.vertices, float)[f].mean(axis=0)
            off = np.abs(np.einsum("ij,ij->i", c - tri0[:, 0], nrm)) / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)
            d = c - tri0[:, 0]
            d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
            p1, p2 = (d * e1).sum(1), (d * e2).sum(1)
            den = np.where(d11 * d22 - d12 * d12 == 0, 1e-300, d11 * d22 - d12 * d12)
            u, v = (d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den
            outside = np.maximum.reduce([-u, -v, u + v - 1.0, np.zeros_like(u)])
            src[j] = int(np.argmin(off + outside))
        out.append(src)
    return out


def record_search(sim: Simulator, pose=None, minimum_capacity: int = 1024) -> Search:
    """Run the compiled engine once at ``pose`` (default the scene's) and record its paths.

    Parameters
    ----------
    sim : Simulator
    pose : Pose, optional
    minimum_capacity : int
        The smallest padded size.

    Returns
    -------
    Search
    """
    scene = sim.scene
    render = scene.render
    if render.glints:
        raise ConfigError("render.glints", "the differentiable engine forms no specular returns; set it false")
    for k, obj in enumerate(scene.objects):
        if obj.specular > 0 and obj.normals != "flat":
            raise ConfigError(f"objects[{k}].normals", "the differentiable engine mirrors about flat triangles "
                              "only; allowed here: flat")
    given = pose is not None
    pose = pose if given else scene.sonar_pose
    if len(sim.planes) and np.abs(sim.planes.signed_distance(pose.translation)).min() < ON_PLANE_TOLERANCE_M:
        # As Simulator.render refuses it: a sonar on a plane sees nothing it can be sure of.
        check_sonar_position(scene.reflecting_planes, pose.position_m, "sonar.position_m" if given else
                             "sonar.pose.position_m")
    paths = sim.trace(pose, primitives=True, paths=True)
    sonar, fan, view = paths.traced, paths.fan, paths.view
    legs, table = paths.legs, paths.table
    sets = paths.sets() if callable(paths.sets) else paths.sets
    n_planes = len(sim.planes)
    n_surfaces = n_planes + len(sim.meshes)
    n_el = fan.shape[2]
    sources = clipped_face_sources(sim)
    facets = sim.facets
    names = tuple(sim.planes.names)
    if facets is not None:  # chain mirror P + m: named by its object
        names += tuple(facets.names[k] for k in facets.mirror_obj)
    # The mesh mirrors' triangles, (object, local face), as the legs meet them; coded
    # -(2 + index) in the chains until the triangle table is formed.
    mirror_pairs: list[tuple[int, int]] = []

    def mirror_codes(obj: np.ndarray, prim: np.ndarray) -> np.ndarray:
        local = [int(sources[k][f]) for k, f in zip(obj.tolist(), prim.tolist())]
        codes = -(2 + len(mirror_pairs) + np.arange(len(local), dtype=np.int64))
        mirror_pairs.extend(zip(obj.tolist(), local))
        return codes

    # Per generation: what every path of it reads of its receive leg (copied: the legs are the
    # engine's pooled buffers, reused by the next frame).
    per_gen = []
    for g, leg in enumerate(legs):
        key = np.asarray(leg.key(n_surfaces)).copy()
        cont = set_continuity(np.asarray(leg.point), np.asarray(leg.normal), key, n_el)
        texture = np.ones(len(leg.sid))
        if any(f is not None for f in sim.textures):  # a plane's texture scales its whole weight
            scale_by_texture(texture, np.asarray(leg.sid), np.asarray(leg.point), sim.textures)
        texel = np.ones(len(leg.sid))  # an object's texture scales its diffuse part only
        if leg.texel is not None:  # (read where an object scatters: elsewhere the pooled buffer holds anything)
            on_object = np.asarray(leg.sid) >= n_planes
            texel[on_object] = np.asarray(leg.texel)[on_object]
        per_gen.append(dict(sid=np.asarray(leg.sid).copy(), chain=np.asarray(leg.chain).copy(),
                            prim=None if leg.prim is None else np.asarray(leg.prim).copy(), cont=cont,
                            texture=texture, texel=texel))

    max_rx = max(len(legs) - 1, 0)
    max_tx = max([len(c) for c in table.chains] + [1]) if table is not None else 1
    cols: dict[str, list] = {k: [] for k in ("ray", "gen", "rx", "sid", "prim", "same", "tx", "label", "beam",
                                             "factor", "down", "up", "has_down", "has_up", "sig", "distance",
                                             "point", "texel")}
    signatures: dict[str, int] = {}
    start = 0
    for s in sets:
        g = per_gen[s.gen]
        ray = np.asarray(s.ray, np.int64)
        m = len(ray)
        sid = g["sid"][ray].astype(np.int64)
        chains = g["chain"][ray] if s.gen else np.zeros(m, np.int64)
        rx = np.full((m, max_rx), -1, np.int64)
        for c in np.unique(chains):
            planes = table.chains[int(c)] if s.gen else ()
            rx[chains == c, :len(planes)] = planes
        for j in range(max_rx):  # a mesh mirror on the receive leg: the triangle the ray met
            at = rx[:, j] >= n_planes
            if at.any():
                rx[at, j] = mirror_codes(per_gen[j]["sid"][ray[at]] - n_planes, per_gen[j]["prim"][ray[at]])
        tx = np.full((m, max_tx), -1, np.int64)
        if s.tx != SAME:
            chain = list(table.chains[s.tx])
            for j, e in enumerate(chain):  # a mesh mirror on the transmit leg: its first triangle
                if e >= n_planes:
                    f = int(facets.mirror_facets[facets.mirror_start[e - n_planes]])
                    k = int(facets.obj[f])
                    chain[j] = int(mirror_codes(np.array([k]), np.array([f - facets.start[k]]))[0])
            tx[:] = -1
            tx[:, :len(chain)] = chain
        factor = g["texture"][ray].copy()
        if render.double_beam == "split" and s.tx != SAME:
            factor *= 0.5
        if render.double_beam == "coherent" and s.tx != SAME and s.beam_tx is not None:
            # the pair arrives in one beam with one length: amplitudes add (paths.engine.option_paths)
            factor *= np.where(np.asarray(s.beam_tx) == np.asarray(s.beam), 2.0, 1.0)
        # Neighbours within the set: consecutive rays of one column, both in the set.
        pos = np.arange(m)
        nxt = np.zeros(m, bool)
        nxt[:-1] = (ray[1:] == ray[:-1] + 1) & (ray[1:] // n_el == ray[:-1] // n_el)
        cont = g["cont"].reshape(-1)  # (columns * (n_el - 1)): the pair (ray, ray + 1)
        pair = np.where(nxt[:-1], (ray[:-1] // n_el) * (n_el - 1) + ray[:-1] % n_el, 0)
        link = np.zeros(m, bool)
        if m > 1 and n_el > 1:
            link[:-1] = nxt[:-1] & cont[pair]
        up = np.where(link, pos + 1, pos) + start
        has_down = np.zeros(m, bool)
        has_down[1:] = link[:-1]
        down = np.where(has_down, pos - 1, pos) + start
        # Signatures: (receive chain, what scatters) within the option.
        kind = np.minimum(sid, n_planes)
        sig = np.empty(m, np.int64)
        for c in np.unique(chains):
            rx_chain = table.chains[int(c)] if s.gen else ()
            tx_chain = rx_chain if s.tx == SAME else table.chains[s.tx]
            for q in np.unique(kind[chains == c]):
                name = path_name([names[p] for p in tx_chain], "objects" if q == n_planes else names[q],
                                 [names[p] for p in rx_chain])
                sig[(chains == c) & (kind == q)] = signatures.setdefault(name, len(signatures))
        prim = np.full(m, -1, np.int64)
        if g["prim"] is not None:
            obj = sid >= n_planes
            k = sid[obj] - n_planes
            prim[obj] = [int(sources[kk][pp]) for kk, pp in zip(k.tolist(), g["prim"][ray][obj].tolist())]
        for name, v in (("ray", ray), ("gen", np.full(m, s.gen)), ("rx", rx), ("sid", sid), ("prim", prim),
                        ("same", np.full(m, s.tx == SAME)), ("tx", tx), ("label", np.asarray(s.label, np.int64)),
                        ("beam", np.asarray(s.beam, np.int64)), ("factor", factor), ("down", down), ("up", up),
                        ("has_down", has_down), ("has_up", link), ("sig", sig),
                        ("distance", np.asarray(s.distance, np.float64)), ("texel", g["texel"][ray]),
                        ("point", np.asarray(legs[s.gen].point)[ray].astype(np.float64))):
            cols[name].append(v)
        start += m

    n = start
    cap = padded_size(n, minimum_capacity)

    def cat(name, shape_tail=(), dtype=np.int64, fill=0):
        parts = cols[name]
        a = np.concatenate(parts) if parts else np.zeros((0,) + shape_tail, dtype)
        out = np.full((cap,) + a.shape[1:] if a.ndim > 1 else (cap,) + shape_tail, fill, dtype=dtype)
        out[:n] = a
        return out

    sid = cat("sid")
    prim = cat("prim", fill=-1)
    on_object = sid >= n_planes
    faces = np.stack([sid[:n][on_object[:n]] - n_planes, prim[:n][on_object[:n]]], axis=1) if n else np.zeros((0, 2), np.int64)
    n_scatter = len(faces)
    if mirror_pairs:  # one table for the triangles scattered on and reflected off
        faces = np.concatenate([faces, np.asarray(mirror_pairs, np.int64).reshape(-1, 2)])
    faces, row = (np.unique(faces, axis=0, return_inverse=True) if len(faces) else (np.zeros((0, 2), np.int64),
                                                                                   np.zeros(0, np.int64)))
    row = np.asarray(row).reshape(-1)
    surface = np.where(sid >= 0, np.minimum(sid, n_planes), 0)
    surface_n = surface[:n]
    surface_n[on_object[:n]] = n_planes + row[:n_scatter]
    surface[:n] = surface_n
    mirror_row = n_planes + row[n_scatter:]
    # Where on its triangle each object's scatterer lies: barycentric (u, v) on the object's
    # own face (a piece the planes cut from it lies in it), from the point the search found.
    uv = np.zeros((cap, 2))
    points = np.concatenate(cols["point"]) if cols["point"] else np.zeros((0, 3))
    obj = np.flatnonzero(on_object[:n])
    if len(obj):
        k, face = sid[obj] - n_planes, prim[obj]
        tri = np.empty((len(obj), 3, 3))
        for kk in np.unique(k):
            local = np.asarray(object_mesh_local(scene.objects[kk]).faces, np.int64)
            posed = np.asarray(sim.meshes[kk].vertices, float)  # the posed vertices come first
            tri[k == kk] = posed[local[face[k == kk]]]
        uv[obj] = barycentric(points[obj], tri)
    pad = np.arange(n, cap)
    down, up = cat("down"), cat("up")
    down[n:], up[n:] = pad, pad
    live = np.zeros(cap, bool)
    live[:n] = True
    rx_planes, tx_planes = cat("rx", (max_rx,), fill=-1), cat("tx", (max_tx,), fill=-1)
    for chains in (rx_planes, tx_planes):  # the mesh mirrors' codes to their triangles' rows
        coded = chains <= -2
        chains[coded] = mirror_row[-chains[coded] - 2]
    arrays = dict(ray=cat("ray"), gen=cat("gen"), rx_planes=rx_planes, surface=surface,
                  sid=np.where(sid >= 0, sid, 0), same=cat("same", dtype=bool, fill=True),
                  tx_planes=tx_planes, label=cat("label"), beam=cat("beam"))
    if n:  # padding repeats the first path's geometry (finite everywhere) with no energy
        for a in arrays.values():
            a[n:] = a[0]
    return Search(
        n_paths=n, **arrays, factor=cat("factor", dtype=np.float64, fill=0.0), down=down, up=up,
        has_down=cat("has_down", dtype=bool, fill=False), has_up=cat("has_up", dtype=bool, fill=False),
        signature=cat("sig"), live=live, uv=uv, texel=cat("texel", dtype=np.float64, fill=1.0),
        distance=cat("distance", dtype=np.float64, fill=np.inf), faces=np.asarray(faces, np.int64).reshape(-1, 2),
        signatures=tuple(signatures), n_rows=stack_rows(render.max_order), n_planes=n_planes,
    )
