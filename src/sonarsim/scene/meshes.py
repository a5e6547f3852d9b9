"""Triangle meshes of the scene objects, in world coordinates.

Primitives are built with trimesh; mesh files are anything trimesh loads (OBJ, STL, PLY,
GLB/glTF, OFF). Multi-part files (a trimesh Scene) are flattened with their transforms.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MeshFileError
from ..config.scene import ObjectSpec

# Sphere tessellation: subdivision 4 gives 5120 faces, with facet normals within about 2 degrees
# of the true normal -- far below what the elevation sampling resolves.
SPHERE_SUBDIVISIONS = 4
CYLINDER_SECTIONS = 64


@dataclass(frozen=True)
class TriangleMesh:
    """A plain triangle mesh.

    Attributes
    ----------
    vertices : (n_vertices, 3) float64 ndarray, metres
    faces : (n_faces, 3) int32 ndarray, indices into ``vertices``
    """

    vertices: np.ndarray
    faces: np.ndarray

    @property
    def triangles(self) -> np.ndarray:
        """(n_faces, 3, 3) corner coordinates."""
        return self.vertices[self.faces]


@functools.lru_cache(maxsize=32)
def _load_mesh_file_cached(path: str, mtime_ns: int, size: int) -> TriangleMesh:
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshFileError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshFileError(f"{path}: no triangle mesh found in the file")
    vertices = np.asarray(loaded.vertices, dtype=float)
    faces = np.asarray(loaded.faces, dtype=np.int32)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshFileError(f"{path}: the mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        raise MeshFileError(f"{path}: the mesh has non-finite vertex coordinates")
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return TriangleMesh(vertices, faces)


def load_mesh_file(path: str | os.PathLike) -> TriangleMesh:
    """Read a mesh file into object coordinates, cached by path and modification time.

    Raises
    ------
    MeshFileError
        The file is missing, unreadable, or holds no triangles; the message names the file.
    """
    p = Path(path)
    if not p.is_file():
        raise MeshFileError(f"{p}: mesh file not found")
    st = p.stat()
    if st.st_size == 0:
        raise MeshFileError(f"{p}: the mesh file is empty")
    return _load_mesh_file_cached(str(p.resolve()), st.st_mtime_ns, st.st_size)


def object_mesh_local(obj: ObjectSpec) -> TriangleMesh:
    """The object's mesh in its own coordinates, before scale and pose."""
    import trimesh

    if obj.primitive == "box":
        m = trimesh.creation.box(extents=obj.size_m)
    elif obj.primitive == "sphere":
        m = trimesh.creation.icosphere(subdivisions=SPHERE_SUBDIVISIONS, radius=obj.radius_m)
    elif obj.primitive == "cylinder":
        m = trimesh.creation.cylinder(radius=obj.radius_m, height=obj.height_m, sections=CYLINDER_SECTIONS)
    elif isinstance(obj.mesh, trimesh.Trimesh):
        if len(obj.mesh.faces) == 0:
            raise MeshFileError(f"object {obj.name!r}: the in-memory mesh is empty")
        return TriangleMesh(np.asarray(obj.mesh.vertices, float), np.asarray(obj.mesh.faces, np.int32))
    else:
        return load_mesh_file(obj.mesh)
    return TriangleMesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int32))


def object_mesh_world(obj: ObjectSpec) -> TriangleMesh:
    """The object's mesh in world coordinates: ``R @ (scale * v) + t``."""
    local = object_mesh_local(obj)
    scale = np.broadcast_to(np.asarray(obj.scale, dtype=float), (3,))
    v = (local.vertices * scale) @ obj.pose.rotation.T + obj.pose.translation
    return TriangleMesh(v, np.ascontiguousarray(local.faces, dtype=np.int32))


def clip_to_water(mesh: TriangleMesh, point_m, normal) -> TriangleMesh:
    """The part of a mesh on the water side of a plane (possibly no faces at all).

    Geometry beyond a floor, wall or water surface can never be seen, but mirror images of it
    would rise into the water, and faces lying in the plane (the base of an object resting on
    the floor) coincide with the plane and with their own mirror image. Both are removed here
    so that no method produces echoes from them.

    Parameters
    ----------
    mesh : TriangleMesh
    point_m : (3,) float array
        A point of the plane, metres.
    normal : (3,) float array
        Unit normal pointing into the water.
    """
    n = np.asarray(normal, dtype=float)
    p = np.asarray(point_m, dtype=float)
    h = mesh.vertices @ n - float(n @ p)  # signed height above the plane
    tol = 1e-9 * max(1.0, float(np.abs(mesh.vertices).max()), float(np.abs(p).max()))
    if h.min() >= tol:
        return mesh
    th = h[mesh.faces]
    keep = ~np.all(th <= tol, axis=1)  # drop faces on or beyond the plane
    crossing = keep & np.any(th < -tol, axis=1)
    faces = mesh.faces[keep & ~crossing]
    if not crossing.any():
        return TriangleMesh(mesh.vertices, np.ascontiguousarray(faces, dtype=np.int32))
    from trimesh.intersections import slice_faces_plane

    cut_v, cut_f, _ = slice_faces_plane(mesh.vertices, mesh.faces[crossing], n, p)
    n0 = len(mesh.vertices)
    verts = np.concatenate([mesh.vertices, np.asarray(cut_v, float)])
    faces = np.concatenate([faces, np.asarray(cut_f, np.int32) + n0]) if len(cut_f) else faces
    return TriangleMesh(verts, np.ascontiguousarray(faces, dtype=np.int32))


def mirror_across_plane(mesh: TriangleMesh, point_m, normal) -> TriangleMesh:
    """Mirror image across a plane (winding reversed so normals stay outward).

    Parameters
    ----------
    point_m, normal : (3,) float arrays
        A point of the plane (metres) and its unit normal.
    """
    n = np.asarray(normal, dtype=float)
    h = mesh.vertices @ n - float(n @ np.asarray(point_m, dtype=float))
    v = mesh.vertices - 2.0 * h[:, None] * n
    return TriangleMesh(v, np.ascontiguousarray(mesh.faces[:, ::-1]))
