"""Mesh mirrors: the triangles of the objects with a specular reflectance, as mirrors of path chains.

An object with ``specular: R > 0`` (:class:`~sonarsim.config.scene.ObjectSpec`) reflects as
well as scatters: a receive ray that meets one of its triangles both scatters (the object's
diffuse law, as before) and goes on in the mirrored direction, carrying R times its weight;
a transmit leg may meet its triangles by image sources, each triangle a small mirror.

Each triangle is a *facet*, numbered over the specular objects in scene order (object ``k``'s
triangle ``j`` is facet ``start[k] + j``); in a chain (:class:`~sonarsim.paths.planes.ChainTable`)
facet ``f`` is the mirror ``P + f``, after the ``P`` planes. A facet mirrors about:

A facet of a closed object mirrors on the object's outside only (``side``): a ray meeting it
from inside does not reflect, and a transmit leg must meet it from outside; an open sheet
mirrors on both sides.

* ``flat`` normals (the default): its own plane, the law of reflection about the triangle's
  normal. The image of a point across it is a point, so transmit legs come from image sources
  as for planes, with one more check: the reflection point must lie on the triangle itself
  (:meth:`FacetSet.contains`), not just on its plane.
* ``smooth`` normals: the normal interpolated from the corners' normals (each the area-weighted
  mean of the normals of the faces around the corner within :data:`CREASE_DEG` of the face's
  own, so a box's or a cylinder's edges stay sharp). A receive ray reflects about it; the image
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

    @classmethod
    def of(cls, meshes: Sequence[TriangleMesh], names: Sequence[str], specular: Sequence[float],
           normals: Sequence[str], sides: Sequence[int] | None = None) -> "FacetSet":
        """The facets of ``meshes`` (world frame, one per object) whose ``specular`` is above 0,
        each object mirroring on ``sides`` (default: both).

        Degenerate triangles (no area) are kept, with a zero normal: no ray meets them and no
        point lies on them.
        """
        spec = np.asarray(specular, dtype=float).reshape(-1)
        smooth = np.array([n == "smooth" for n in normals], dtype=bool).reshape(-1)
        counts = [len(m.faces) if r > 0 else 0 for m, r in zip(meshes, spec)]
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        corners = [m.vertices[m.faces] for m, c in zip(meshes, counts) if c]
        tri = np.concatenate(corners).astype(float) if corners else np.empty((0, 3, 3))
        raw = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(raw, axis=1)
        normal = np.divide(raw, length[:, None], out=np.zeros_like(raw), where=length[:, None] > 0)
        obj = np.repeat(np.arange(len(counts), dtype=np.int32), counts)
        corner_normals = None
        if np.any(smooth & (spec > 0)):
            corner_normals = np.concatenate([
                _corner_normals(m) if smooth[k] else np.repeat(normal[start[k]:start[k + 1], None, :], 3, axis=1)
                for k, m in enumerate(meshes) if counts[k]
            ])
        side = np.zeros(len(spec), np.int8) if sides is None else np.asarray(sides, np.int8).reshape(-1)
        return cls(tuple(names), spec, smooth, side, start, tri, normal, np.einsum("ij,ij->i", normal, tri[:, 0]), obj,
                   corner_normals)

    def __len__(self) -> int:
        return len(self.obj)

    @property
    def any(self) -> bool:
        """Some object mirrors."""
        return len(self.obj) > 0

    def facet(self, obj: np.ndarray, prim: np.ndarray) -> np.ndarray:
        """Facet ids of triangle ``prim`` of object ``obj`` (arrays; -1 where the object does
        not mirror)."""
        obj = np.asarray(obj)
        mirror = self.specular[obj] > 0
        return np.where(mirror, self.start[obj] + np.asarray(prim), -1).astype(np.int64)

    def facing(self, f: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """(m,) bool: rays along ``direction`` (m, 3) meet facet ``f`` (m,) on a side it
        mirrors on."""
        side = self.side[self.obj[np.asarray(f, dtype=np.intp)]]
        dn = np.einsum("ij,ij->i", np.asarray(direction, dtype=float), self.normal[f])
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
        m /= np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-300)
        return np.where(smooth[:, None], m, n)

    def contains(self, f: int, points: np.ndarray) -> np.ndarray:
        """(m,) bool: points (m, 3) on facet ``f``'s plane lie inside the triangle (edges
        included, within :data:`EDGE_TOLERANCE` of its size)."""
        a, b, c = self.corners[f]
        e1, e2 = b - a, c - a
        p = np.asarray(points, dtype=float) - a
        d11, d12, d22 = e1 @ e1, e1 @ e2, e2 @ e2
        det = d11 * d22 - d12 * d12
        if det <= 0.0:
            return np.zeros(len(p), dtype=bool)
        p1, p2 = p @ e1, p @ e2
        u = (d22 * p1 - d12 * p2) / det
        v = (d11 * p2 - d12 * p1) / det
        tol = EDGE_TOLERANCE * max(1.0, np.sqrt(max(d11, d22)))
        return (u >= -tol) & (v >= -tol) & (u + v <= 1.0 + tol)


def _corner_normals(mesh: TriangleMesh) -> np.ndarray:
    """(n_faces, 3, 3): each corner's smooth normal, the area-weighted mean of the normals of
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
    reps = degree[corner_v]
    corner_id = np.repeat(np.arange(len(corner_v)), reps)
    offsets = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
    g = face_s[np.repeat(first[corner_v], reps) + offsets]
    own = unit[corner_f[corner_id]]
    close = np.einsum("ij,ij->i", own, unit[g]) >= np.cos(np.radians(CREASE_DEG))
    acc = np.zeros((len(corner_v), 3))
    np.add.at(acc, corner_id[close], raw[g[close]])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    out = np.where(norm > 0, acc / np.maximum(norm, 1e-300), unit[corner_f])
    return out.reshape(n_faces, 3, 3)
