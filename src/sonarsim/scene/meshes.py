"""Triangle meshes of the scene objects, in world coordinates.

Primitives are built with trimesh; mesh files are read by :mod:`sonarsim.config.meshfiles`
(which the scene loader checks them with when it loads a scene), by suffix
(:data:`MESH_SUFFIXES`: OBJ, STL, PLY, OFF, GLB/glTF, Collada). An object whose material asks for its
texture (``material: {texture: true}``) keeps the mesh's UV coordinates and the brightness of
its texture image (see :mod:`sonarsim.scene.textures`). Vertices must lie within
``MAX_COORDINATE_M`` of the origin, in the file and once scaled and posed.

:class:`TriangleMesh` lives in :mod:`sonarsim.core.triangles` and the reading of mesh files
(:func:`load_mesh_file`, :func:`world_reach_m`, :func:`distinct_faces`, :func:`brightness`) in
:mod:`sonarsim.config.meshfiles`, below config's loader; both are re-exported here, where they
were.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..errors import MeshFileError
from ..config.scene import MAX_COORDINATE_M, ObjectSpec
from ..core.triangles import TriangleMesh  # noqa: F401 - re-exported
from ..config.meshfiles import (  # noqa: F401 - re-exported
    MESH_BYTES_PER_FILE_BYTE,
    MESH_SECONDS_PER_FILE_BYTE,
    MESH_SUFFIXES,
    _checked_resolver,
    _load_mesh_file_cached,
    _texture_of,
    _trimesh,
    brightness,
    distinct_faces,
    load_mesh_file,
    world_reach_m,
)

# Primitive tessellation. A facet may lie at most PRIMITIVE_TOLERANCE_M inside the true
# surface: well under a tenth of the finest range bin of the devices we model (an ARIS 3000 at
# 5 m: 3.3 mm), and below what the elevation sampling resolves. Within that, the coarsest tessellation is
# used, up to the finest below: a sphere of 5 cm or more keeps subdivision 4 (5120 faces, facet
# normals within about 2 degrees), a 1 cm pebble gets 320 faces instead of 5120 (a scene of
# 20,000 pebbles was 100 million triangles).
PRIMITIVE_TOLERANCE_M = 2e-4
SPHERE_SUBDIVISIONS = 4
CYLINDER_SECTIONS = 64
MIN_CYLINDER_SECTIONS = 8


def object_mesh_local(obj: ObjectSpec) -> TriangleMesh:
    """The object's mesh in its own coordinates, before scale and pose."""
    trimesh = _trimesh()

    if obj.primitive is not None:
        # The tessellation follows the size the object is drawn at (its radius times its scale).
        largest_scale = float(np.max(np.abs(np.asarray(obj.scale, dtype=float))))
        return primitive_mesh(obj.primitive, obj.size_m, obj.radius_m, obj.height_m, largest_scale)
    if isinstance(obj.mesh, trimesh.Trimesh):
        if len(obj.mesh.faces) == 0:
            raise MeshFileError(f"object {obj.name!r}: the in-memory mesh is empty")
        textured = _texture_of(obj.mesh, f"object {obj.name!r}") if obj.backscatter.texture else ()
        return TriangleMesh(np.asarray(obj.mesh.vertices, float), np.asarray(obj.mesh.faces, np.int32), *textured)
    return load_mesh_file(obj.mesh, texture=obj.backscatter.texture)


def sphere_subdivisions(radius_m: float) -> int:
    """Icosphere subdivision level of a sphere primitive: the coarsest whose facets lie within
    :data:`PRIMITIVE_TOLERANCE_M` of the sphere, at most :data:`SPHERE_SUBDIVISIONS`."""
    for level in range(SPHERE_SUBDIVISIONS):
        if radius_m * _icosphere_sag(level) <= PRIMITIVE_TOLERANCE_M:
            return level
    return SPHERE_SUBDIVISIONS


def cylinder_sections(radius_m: float) -> int:
    """Sections of a cylinder primitive: the fewest (a power of two from
    :data:`MIN_CYLINDER_SECTIONS`) whose chords lie within :data:`PRIMITIVE_TOLERANCE_M` of the
    circle, at most :data:`CYLINDER_SECTIONS`."""
    sections = MIN_CYLINDER_SECTIONS
    while sections < CYLINDER_SECTIONS and radius_m * (1.0 - np.cos(np.pi / sections)) > PRIMITIVE_TOLERANCE_M:
        sections *= 2
    return sections


@functools.lru_cache(maxsize=None)
def _icosphere_sag(level: int) -> float:
    """How far inside the unit sphere an icosphere's face centres lie, at most."""
    m = _trimesh().creation.icosphere(subdivisions=level, radius=1.0)
    return float(1.0 - np.linalg.norm(m.triangles_center, axis=1).min())


@functools.lru_cache(maxsize=256)
def primitive_mesh(primitive: str, size_m=None, radius_m=None, height_m=None, scale: float = 1.0) -> TriangleMesh:
    """A primitive's mesh in object coordinates (read-only arrays, cached: a scene of many equal
    rocks builds one).

    Parameters
    ----------
    primitive : {"box", "sphere", "cylinder"}
    size_m : (3,) tuple of float, metres, for a box
    radius_m, height_m : float, metres, for a sphere (radius) or a cylinder (both)
    scale : float
        The largest factor the object is scaled by: the tessellation is chosen for the radius
        times this (the mesh itself is not scaled).

    Returns
    -------
    TriangleMesh
        Tessellated as :func:`sphere_subdivisions` and :func:`cylinder_sections` say.
    """
    trimesh = _trimesh()
    if primitive == "box":
        m = trimesh.creation.box(extents=size_m)
    elif primitive == "sphere":
        m = trimesh.creation.icosphere(subdivisions=sphere_subdivisions(radius_m * scale), radius=radius_m)
    elif primitive == "cylinder":
        m = trimesh.creation.cylinder(radius=radius_m, height=height_m, sections=cylinder_sections(radius_m * scale))
    else:
        raise ValueError(f"unknown primitive {primitive!r}")
    vertices = np.asarray(m.vertices, float)
    faces = np.asarray(m.faces, np.int32)
    vertices.setflags(write=False)
    faces.setflags(write=False)
    return TriangleMesh(vertices, faces)


def object_mesh_world(obj: ObjectSpec) -> TriangleMesh:
    """The object's mesh in world coordinates: ``R @ (scale * v) + t``.

    Raises
    ------
    MeshFileError
        A mesh object reaches beyond ``MAX_COORDINATE_M`` of the origin (naming it and its file).
    """
    return posed_mesh(obj, object_mesh_scaled(obj))


def object_mesh_scaled(obj: ObjectSpec) -> TriangleMesh:
    """The object's mesh in its own coordinates, scaled: what its pose places (kept by a
    simulator for the objects it moves)."""
    local = object_mesh_local(obj)
    scale = np.broadcast_to(np.asarray(obj.scale, dtype=float), (3,))
    return TriangleMesh(local.vertices * scale, np.ascontiguousarray(local.faces, dtype=np.int32), local.uv,
                        local.texture)


def posed_mesh(obj: ObjectSpec, scaled: TriangleMesh) -> TriangleMesh:
    """``scaled`` (:func:`object_mesh_scaled` of ``obj``) at ``obj``'s pose, in world coordinates.

    Raises
    ------
    MeshFileError
        A mesh object reaches beyond ``MAX_COORDINATE_M`` of the origin.
    """
    v = scaled.vertices @ obj.pose.rotation.T + obj.pose.translation
    local = scaled
    # Primitives are bounded by their sizes and positions; a mesh (a file, or a Trimesh from
    # Python, scaled up to 1e4) is not.
    if obj.primitive is None and len(v) and np.abs(v).max() > MAX_COORDINATE_M:
        source = f" ({obj.mesh})" if isinstance(obj.mesh, (str, Path)) else ""
        raise MeshFileError(f"object {obj.name!r}{source}: scaled and posed, its vertices reach "
                            f"{float(np.abs(v).max()):.3g} m from the origin; allowed: within {MAX_COORDINATE_M:g} m")
    return TriangleMesh(v, np.ascontiguousarray(local.faces, dtype=np.int32), local.uv, local.texture)


def outer_side(mesh: TriangleMesh) -> int:
    """Which side of its triangles a closed mesh's outside is on: +1 where the normals
    ``(b - a) x (c - a)`` point out of the volume, -1 where they point in, 0 where the mesh
    encloses no volume (an open sheet: both sides face the water)."""
    if not len(mesh.faces):
        return 0
    m = _trimesh().Trimesh(mesh.vertices, mesh.faces, process=False)
    if not (m.is_watertight and m.is_winding_consistent):
        return 0
    volume = float(m.volume)
    return 0 if volume == 0.0 else (1 if volume > 0.0 else -1)


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
        return TriangleMesh(mesh.vertices, np.ascontiguousarray(faces, dtype=np.int32), mesh.uv, mesh.texture)
    from trimesh.intersections import slice_faces_plane

    # The cut faces' new corners get texture coordinates interpolated along the cut edges.
    cut_v, cut_f, cut_uv = slice_faces_plane(mesh.vertices, mesh.faces[crossing], n, p, uv=mesh.uv)
    n0 = len(mesh.vertices)
    verts = np.concatenate([mesh.vertices, np.asarray(cut_v, float)])
    faces = np.concatenate([faces, np.asarray(cut_f, np.int32) + n0]) if len(cut_f) else faces
    uv = None if mesh.uv is None else np.concatenate([mesh.uv, np.asarray(cut_uv, float).reshape(-1, 2)])
    return TriangleMesh(verts, np.ascontiguousarray(faces, dtype=np.int32), uv, mesh.texture)


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
    return TriangleMesh(v, np.ascontiguousarray(mesh.faces[:, ::-1]), mesh.uv, mesh.texture)
