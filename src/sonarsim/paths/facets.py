"""Mesh mirrors: the triangles of the objects with a specular reflectance, as mirrors of path chains.

An object with ``specular: R > 0`` (:class:`~sonarsim.config.scene.ObjectSpec`) reflects as
well as scatters: a receive ray that meets one of its triangles both scatters (the object's
diffuse law, as before) and goes on in the mirrored direction, carrying R times its weight;
a transmit leg may meet its triangles by image sources, each triangle a small mirror.

Each triangle is a *facet*, numbered over the specular objects in scene order (object ``k``'s
triangle ``j`` is facet ``start[k] + j``). An object's facets that lie in one plane (a box's
face, cut in two or more triangles) form one *mirror*, as a plane is one: the same image
sources, one chain for the rays that meet either triangle, one continuous surface for range
splatting. In a chain (:class:`~sonarsim.paths.planes.ChainTable`) mirror ``m`` is ``P + m``,
after the ``P`` planes; mirrors are numbered by their first facet. A facet mirrors about:

A facet of a closed object mirrors on the object's outside only (``side``): a ray meeting it
from inside does not reflect, and a transmit leg must meet it from outside; an open sheet
mirrors on both sides.

* ``flat`` normals (the default): its own plane, the law of reflection about the triangle's
  normal. The image of a point across it is a point, so transmit legs come from image sources
  as for planes, with one more check: the reflection point must lie on one of the mirror's
  triangles (:meth:`FacetSet.contains`), not just on its plane.
* ``smooth`` normals: the normal interpolated from the corners' normals (each the area-weighted
  mean of the normals of the faces around the corner within :data:`CREASE_DEG` of the face's
  own, so a box's or a cylinder's edges stay sharp). Each smooth facet is a mirror of its own.
  A receive ray reflects about it; the image
  of a point across a curved mirror is not a point, so no transmit leg is formed by image
  sources across a smooth facet: those paths come from the receive legs that followed it
  (the pair's other member, by reciprocity: :mod:`sonarsim.paths.engine`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..core.triangles import TriangleMesh

#: Normal conventions of a mesh mirror.
NORMALS = ("flat", "smooth")

#: Faces around a corner whose normals turn more than this from a face's own are not
#: averaged into its smooth normal there (the edge is a crease), degrees.
CREASE_DEG = 45.0

#: A reflection point may lie this far outside its triangle, relative to the triangle's
#: longest edge (round-off on the edge two coplanar triangles share must leave no gap).
EDGE_TOLERANCE = 1e-9

#: Facets of one object whose unit normals and offsets (metres) agree to this many decimals
#: lie in one plane: one mirror.
COPLANAR_DECIMALS = 9

#: A corner whose vertex more faces than this meet at (a cone's apex, a fan) keeps its face's
#: own normal: averaging pairs every corner of a vertex with every face around it, D^2 pairs
#: for a vertex of D faces (a 200,000-face fan would be 4e10).
MAX_SMOOTH_DEGREE = 32


@dataclass(frozen=True)
class FacetSet:
    """The specular objects' triangles, as mirrors.

    Attributes
    ----------
    names : tuple of str
        Every object's name, by object index (the specular ones and the others).
    specular : (K,) float64 ndarray
        Each object's specular reflectance R (0: not a mirror, no facets).
    smooth : (K,) bool ndarray
        The object mirrors about interpolated normals.
    side : (K,) int8 ndarray
        The side of its facets each object mirrors on: +1 where ``normal`` points out of it,
        -1 where it points in, 0 both (an open mesh; :func:`~sonarsim.scene.meshes.outer_side`).
    start : (K + 1,) int64 ndarray
        Object ``k``'s facets are ``start[k] .. start[k + 1] - 1`` (none where R = 0).
    corners : (F, 3, 3) float64 ndarray
        Each facet's corners ``a, b, c``, metres.
    normal : (F, 3) float64 ndarray
        Unit normal of each facet's plane, ``(b - a) x (c - a)`` normalised.
    offset : (F,) float64 ndarray
        ``normal . a``, metres.
    obj : (F,) int32 ndarray
        Object index of each facet.
    corner_normals : (F, 3, 3) float64 ndarray or None
        The smooth normal at each corner (None: no object is smooth).
    mirror : (F,) int64 ndarray
        The mirror of each facet (its object's facets in its plane).
    mirror_normal : (G, 3) float64 ndarray
    mirror_offset : (G,) float64 ndarray
        Each mirror's plane: its first facet's.
    mirror_obj : (G,) int32 ndarray
    mirror_start : (G + 1,) int64 ndarray
    mirror_facets : (F,) int64 ndarray
        Mirror ``m``'s facets are ``mirror_facets[mirror_start[m]:mirror_start[m + 1]]``.
    """

    names: tuple[str, ...]
    specular: np.ndarray
    smooth: np.ndarray
    side: np.ndarray
    start: np.ndarray
    corners: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    obj: np.ndarray
    corner_normals: np.ndarray | None
    mirror: np.ndarray
    mirror_normal: np.ndarray
    mirror_offset: np.ndarray
    mirror_obj: np.ndarray
    mirror_start: np.ndarray
    mirror_facets: np.ndarray

    @classmethod
    def of(cls, meshes: Sequence[TriangleMesh], names: Sequence[str], specular: Sequence[float],
           normals: Sequence[str], sides: Sequence[int] | None = None) -> "FacetSet":
        """The facets of ``meshes`` (world frame, one per object) whose ``specular`` is above 0,
        each object mirroring on ``sides`` (default: both).

        Degenerate triangles (no area) are kept, with a zero normal: no ray meets them and no
        point lies on them.
        """
        spec = np.asarray(specular, dtype=float).reshape(-1)
        counts = [len(m.faces) if r > 0 else 0 for m, r in zip(meshes, spec)]
        # Smooth where the object mirrors (a smooth object without R, or one the planes clipped
        # away, has no facets: nothing of it is interpolated).
        smooth = np.array([n == "smooth" for n in normals], dtype=bool).reshape(-1) & (np.asarray(counts) > 0)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        corners = [m.vertices[m.faces] for m, c in zip(meshes, counts) if c]
        tri = np.concatenate(corners).astype(float) if corners else np.empty((0, 3, 3))
        raw = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(raw, axis=1)
        normal = np.divide(raw, length[:, None], out=np.zeros_like(raw), where=length[:, None] > 0)
        obj = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
        corner_normals = None
        if np.any(smooth):
            corner_normals = np.concatenate([
                _corner_normals(m) if smooth[k] else np.repeat(normal[start[k]:start[k + 1], None, :], 3, axis=1)
                for k, m in enumerate(meshes) if counts[k]
            ])
        side = np.zeros(len(spec), np.int8) if sides is None else np.asarray(sides, np.int8).reshape(-1)
        offset = np.einsum("ij,ij->i", normal, tri[:, 0])
        # Mirrors: a flat object's facets in one plane; each smooth facet alone.
        alone = smooth[obj] if len(obj) else np.zeros(0, bool)
        key = np.column_stack([obj, np.round(normal, COPLANAR_DECIMALS), np.round(offset, COPLANAR_DECIMALS),
                               np.where(alone, np.arange(len(obj)), -1)])
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        order = np.argsort(first, kind="stable")  # mirrors numbered by their first facet
        rank = np.empty(len(order), np.int64)
        rank[order] = np.arange(len(order))
        mirror = rank[inverse.reshape(-1)] if len(obj) else np.empty(0, np.int64)
        heads = first[order]
        members = np.argsort(mirror, kind="stable")
        mirror_start = np.searchsorted(mirror[members], np.arange(len(heads) + 1)).astype(np.int64)
        return cls(tuple(names), spec, smooth, side, start, tri, normal, offset, obj, corner_normals,
                   mirror, normal[heads], offset[heads], obj[heads], mirror_start, members.astype(np.int64))

    def __len__(self) -> int:
        return len(self.obj)

    @property
    def any(self) -> bool:
        """Some object mirrors."""
        return len(self.obj) > 0

    @property
    def n_mirrors(self) -> int:
        return len(self.mirror_obj)

    def facet(self, obj: np.ndarray, prim: np.ndarray) -> np.ndarray:
        """Facet ids of triangle ``prim`` of object ``obj`` (arrays; -1 where the object does
        not mirror)."""
        obj = np.asarray(obj)
        mirror = self.specular[obj] > 0
        return np.where(mirror, self.start[obj] + np.asarray(prim), -1).astype(np.int64)

    def mirror_of(self, obj: np.ndarray, prim: np.ndarray) -> np.ndarray:
        """Mirror ids of triangle ``prim`` of object ``obj`` (-1 where the object does not mirror)."""
        f = self.facet(obj, prim)
        return np.where(f >= 0, self.mirror[np.maximum(f, 0)] if len(self.mirror) else -1, -1)

    def facing(self, f: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """(m,) bool: rays along ``direction`` (m, 3) meet facet ``f`` (m,) on a side it
        mirrors on."""
        side = self.side[self.obj[np.asarray(f, dtype=np.intp)]]
        d, n = np.asarray(direction, dtype=float), self.normal[f]
        dn = d[:, 0] * n[:, 0] + d[:, 1] * n[:, 1] + d[:, 2] * n[:, 2]  # summed as the kernels sum
        return (side == 0) | (side * dn < 0)

    def reflecting_normal(self, f: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """(m, 3) the normal a ray meeting facet ``f`` at barycentric ``uv`` (m, 2) reflects
        about: the facet's own, or on a smooth object the corners' normals interpolated."""
        f = np.asarray(f, dtype=np.intp)
        n = self.normal[f]
        if self.corner_normals is None:
            return n
        smooth = self.smooth[self.obj[f]]
        if not smooth.any():
            return n
        u = np.asarray(uv, dtype=float)[:, 0:1]
        v = np.asarray(uv, dtype=float)[:, 1:2]
        c = self.corner_normals[f]
        m = (1.0 - u - v) * c[:, 0] + u * c[:, 1] + v * c[:, 2]
        m /= np.maximum(np.sqrt(_dot3(m, m)), 1e-300)[:, None]  # (summed as the kernels sum)
        return np.where(smooth[:, None], m, n)

    def contains_mirror(self, m: int, points: np.ndarray) -> np.ndarray:
        """(k,) bool: points (k, 3) on mirror ``m``'s plane lie on one of its triangles."""
        facets = self.mirror_facets[self.mirror_start[m]:self.mirror_start[m + 1]]
        inside = self.contains(int(facets[0]), points)
        for f in facets[1:]:
            inside |= self.contains(int(f), points)
        return inside

    def contains(self, f: int, points: np.ndarray) -> np.ndarray:
        """(m,) bool: points (m, 3) on facet ``f``'s plane lie inside the triangle (edges
        included, within :data:`EDGE_TOLERANCE` of its size)."""
        a, b, c = self.corners[f]
        e1, e2 = b - a, c - a
        p = np.asarray(points, dtype=float) - a
        # Every dot product summed as the kernels sum, (x + y) + z: their decisions are these.
        d11, d12, d22 = _dot3(e1, e1), _dot3(e1, e2), _dot3(e2, e2)
        det = d11 * d22 - d12 * d12
        if not det > 0.0:
            return np.zeros(len(p), dtype=bool)
        with np.errstate(invalid="ignore"):  # (points already refused are NaN: not inside)
            p1, p2 = _dot3(p, e1), _dot3(p, e2)
            u = (d22 * p1 - d12 * p2) / det
            v = (d11 * p2 - d12 * p1) / det
            tol = EDGE_TOLERANCE * max(1.0, np.sqrt(max(d11, d22)))
            return (u >= -tol) & (v >= -tol) & (u + v <= 1.0 + tol)


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a . b`` over the last axis of length 3, summed ``(x + y) + z``."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _corner_normals(mesh: TriangleMesh) -> np.ndarray:
    """(n_faces, 3, 3): each corner's smooth normal, the angle-weighted mean of the normals of
    the faces around its vertex that turn less than :data:`CREASE_DEG` from the face's own."""
    tri = mesh.vertices[mesh.faces]
    raw = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length: twice the area
    length = np.linalg.norm(raw, axis=1)
    unit = np.divide(raw, length[:, None], out=np.zeros_like(raw), where=length[:, None] > 0)
    n_faces = len(mesh.faces)
    # Vertex -> incident faces, as a sorted list of (vertex, face) pairs.
    vert = mesh.faces.reshape(-1).astype(np.int64)
    face = np.repeat(np.arange(n_faces), 3)
    order = np.argsort(vert, kind="stable")
    vert_s, face_s = vert[order], face[order]
    first = np.searchsorted(vert_s, np.arange(len(mesh.vertices)))
    degree = np.bincount(vert_s, minlength=len(mesh.vertices))
    # Every corner (face f, its vertex v) paired with every face g around v.
    corner_v = vert
    corner_f = face
    reps = np.where(degree[corner_v] <= MAX_SMOOTH_DEGREE, degree[corner_v], 0)  # (a fan's apex: its own normal)
    corner_id = np.repeat(np.arange(len(corner_v)), reps)
    offsets = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
    g = face_s[np.repeat(first[corner_v], reps) + offsets]
    own = unit[corner_f[corner_id]]
    close = np.einsum("ij,ij->i", own, unit[g]) >= np.cos(np.radians(CREASE_DEG))
    # Each face weighted by its angle at the vertex: a quad cut in two triangles then counts
    # as much as its neighbour cut the other way (area weights would tilt the normal).
    angle = _corner_angles(tri)  # (n_faces, 3)
    slot = np.argmax(mesh.faces[g] == corner_v[corner_id][:, None], axis=1)
    acc = np.zeros((len(corner_v), 3))
    np.add.at(acc, corner_id[close], unit[g[close]] * angle[g[close], slot[close]][:, None])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    out = np.where(norm > 0, acc / np.maximum(norm, 1e-300), unit[corner_f])
    return out.reshape(n_faces, 3, 3)


def _corner_angles(tri: np.ndarray) -> np.ndarray:
    """(n, 3) the angle of each triangle (n, 3, 3) at each of its corners, radians."""
    out = np.empty(tri.shape[:2])
    for j in range(3):
        u = tri[:, (j + 1) % 3] - tri[:, j]
        v = tri[:, (j + 2) % 3] - tri[:, j]
        nu, nv = np.linalg.norm(u, axis=1), np.linalg.norm(v, axis=1)
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(nu * nv, 1e-300)
        out[:, j] = np.arccos(np.clip(cos, -1.0, 1.0))
    return out
