"""Mesh files: reading one into a :class:`~sonarsim.core.triangles.TriangleMesh` (object
coordinates), checked, and how far it reaches once scaled and posed.

The scene loader (:mod:`sonarsim.config.loader`) reads each object's mesh file when it loads the
scene, so that a bad file fails naming its key (``objects[1].mesh``) rather than at render time;
the scene's geometry (:mod:`sonarsim.scene.meshes`) reads it again (from the cache) to build the
object. Reading sits here, below both, so that config imports nothing of scene;
:mod:`sonarsim.scene.meshes` re-exports every name, where it was.

Mesh files are what trimesh reads triangles from, by suffix (:data:`MESH_SUFFIXES`: OBJ, STL,
PLY, OFF, GLB/glTF, and Collada ``.dae`` with the ``gazebo`` extra's pycollada); multi-part
files (a trimesh Scene) are flattened with their transforms. A Collada file's ``<unit meter>``
and ``<up_axis>`` are applied (trimesh leaves both to the caller): its vertices come out in
metres, z up (:func:`collada_frame`).
Files a mesh refers to (an OBJ's material library and the images it names, a glTF's buffers
and images) are opened only after :func:`~sonarsim.errors.check_input_file` (a pipe named there
blocked forever); vertices must lie within ``MAX_COORDINATE_M`` of the origin, in the file and
once scaled and posed.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from ..errors import MeshFileError, SonarsimError, check_input_file, shown
from ..core.triangles import TriangleMesh
from .scene import MAX_COORDINATE_M
from .xmlfiles import XmlFileError, local_name, read_xml

#: File suffixes of the mesh formats read: those trimesh reads triangles from (``.xyz``, which
#: trimesh also knows, holds points: an OBJ named ``.xyz`` failed with "could not convert string
#: to float: 'v'").
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".dae")

#: Collada's up axes and the rotation that takes each to z up (the spec's table: Y_UP has x
#: right, y up, z toward the viewer; Z_UP has x right, z up, -y toward the viewer; X_UP has -y
#: right, x up, z toward the viewer).
COLLADA_UP_AXES = {
    "Z_UP": np.eye(3),
    "Y_UP": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "X_UP": np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
}


def collada_frame(path: str | os.PathLike, max_bytes: int) -> np.ndarray:
    """The (3, 3) matrix that takes a Collada file's coordinates to metres, z up: its
    ``<asset><unit meter=...>`` (default 1) times the rotation of its ``<up_axis>`` (default
    ``Y_UP``, the spec's).

    The file is parsed by :func:`~sonarsim.config.xmlfiles.read_xml` first, which also refuses a
    document type declaration before pycollada sees the file.

    Raises
    ------
    MeshFileError
        Not well-formed XML, not Collada, a document type declaration, a unit that is not a
        positive number, an unknown up axis.
    """
    try:
        root = read_xml(path, "Collada file", max_bytes)
    except XmlFileError as exc:
        raise MeshFileError(str(exc)) from None
    if local_name(root) != "COLLADA":
        raise MeshFileError(f"{path}: not a Collada file: the root element is <{root.tag}>, not <COLLADA>")
    meter, up = 1.0, "Y_UP"
    asset = next((c for c in root if local_name(c) == "asset"), None)
    for child in asset if asset is not None else ():
        if local_name(child) == "unit":
            text = child.get("meter", "1")
            try:
                meter = float(text)
            except ValueError:
                meter = float("nan")
            if not (np.isfinite(meter) and 0 < meter <= 1e4):
                raise MeshFileError(f"{path}: <unit meter={shown(text)}> must be a positive number of metres "
                                    "(at most 10000)")
        elif local_name(child) == "up_axis":
            up = (child.text or "").strip()
            if up not in COLLADA_UP_AXES:
                raise MeshFileError(f"{path}: <up_axis> {shown(up)} is not one of {', '.join(COLLADA_UP_AXES)}")
    return meter * COLLADA_UP_AXES[up]


def _require_collada() -> None:
    """trimesh reads Collada through pycollada (the ``gazebo`` extra): say so when it is missing."""
    import importlib

    try:
        importlib.import_module("collada")
    except ImportError:
        from ..core.extras import install_hint

        raise MeshFileError(f"Collada (.dae) meshes need pycollada; {install_hint('gazebo')}") from None


def brightness(image) -> np.ndarray:
    """(height, width) float32 luminance in [0, 1] of a PIL image (row 0 at the top).

    Also :func:`sonarsim.scene.textures.brightness`: it is here because loading a textured mesh
    needs it, and this module sits below :mod:`~sonarsim.scene.textures` (which wraps casters)."""
    return (np.asarray(image.convert("L"), dtype=np.float32) / np.float32(255.0)).astype(np.float32)


def _texture_of(mesh, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(uv, brightness)`` of a trimesh mesh's texture; MeshFileError naming ``where`` without one."""
    visual = getattr(mesh, "visual", None)
    uv = getattr(visual, "uv", None)
    material = getattr(visual, "material", None)
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if uv is None or image is None:
        raise MeshFileError(f"{where}: the mesh has no texture (UV coordinates and a texture image)")
    uv = np.asarray(uv, dtype=float)
    if uv.shape != (len(mesh.vertices), 2) or not np.all(np.isfinite(uv)):
        raise MeshFileError(f"{where}: the mesh's UV coordinates do not match its vertices")
    uv.setflags(write=False)
    return uv, brightness(image)


def _trimesh():
    """The ``trimesh`` module, imported with Ctrl-C held back (:mod:`sonarsim.core.interrupts`).

    trimesh imports its optional dependencies inside ``except BaseException``: a Ctrl-C during
    that second would be swallowed. Held back, it stops the command right after the import.
    """
    import sys

    module = sys.modules.get("trimesh")
    if module is not None:
        return module
    from ..core.interrupts import signals_deferred

    with signals_deferred():
        import trimesh
    return trimesh


def _checked_resolver(path: str):
    """A trimesh resolver for the files next to ``path`` that opens a file only after
    :func:`~sonarsim.errors.check_input_file`, and records what it was asked for.

    trimesh opens what a mesh refers to itself (an OBJ's ``mtllib`` and ``map_Kd``, a glTF's
    buffers and images) and ignores most failures: an image that is a pipe blocked forever, a
    missing material library left an OBJ with UVs on a made-up grey texture. This resolver
    refuses what is not a regular file (recorded in ``refused``, and trimesh told it is not
    found), and records the names it ``read`` and those ``missing``.
    """
    trimesh = _trimesh()

    class CheckedFiles(trimesh.resolvers.FilePathResolver):
        def __init__(self, source: str) -> None:
            super().__init__(source)
            self.refused: list[str] = []
            self.missing: list[str] = []
            self.read: list[str] = []

        def get(self, name: str) -> bytes:
            # As written, then by its base name alone (as trimesh looks for it).
            for candidate in dict.fromkeys((name.strip(), os.path.basename(name.strip()))):
                try:
                    target = self.absolute(candidate)
                except ValueError:  # a name leading out of the mesh's folder
                    continue
                if not os.path.lexists(target):
                    continue
                try:
                    check_input_file(target, "regular file")
                    with open(target, "rb") as f:
                        data = f.read()
                except (SonarsimError, OSError) as exc:
                    self.refused.append(str(exc) if isinstance(exc, SonarsimError) else f"{target}: {exc}")
                    raise FileNotFoundError(name) from None
                self.read.append(name)
                return data
            self.missing.append(name)
            raise FileNotFoundError(name)

    return CheckedFiles(path)


@functools.lru_cache(maxsize=32)
def _load_mesh_file_cached(path: str, mtime_ns: int, size: int, texture: bool = False) -> TriangleMesh:
    trimesh = _trimesh()

    collada = path.lower().endswith(".dae")
    if collada:
        _require_collada()
        to_metres = collada_frame(path, max(size, 1))
    resolver = _checked_resolver(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False, resolver=resolver)
    except ImportError:  # trimesh reaching for an optional text decoder: the bytes are not a mesh it knows
        raise MeshFileError(f"{path}: not a mesh file trimesh can read (OBJ, STL, PLY, GLB/glTF, OFF, DAE)") from None
    except Exception as exc:  # trimesh raises many types for unreadable files
        if resolver.refused:
            raise MeshFileError(f"{path}: refers to {resolver.refused[0]}") from None
        if isinstance(exc, IndexError):  # (trimesh's words for a face past the vertices: numpy's)
            raise MeshFileError(f"{path}: a face refers to a vertex the file does not define ({exc})") from None
        raise MeshFileError(f"{path}: cannot read mesh ({type(exc).__name__}: {exc})") from None
    if resolver.refused:
        raise MeshFileError(f"{path}: refers to {resolver.refused[0]}")
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshFileError(f"{path}: no triangle mesh found in the file")
    vertices = np.asarray(loaded.vertices, dtype=float)
    if collada:
        vertices = vertices @ to_metres.T
    faces = np.asarray(loaded.faces, dtype=np.int32)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshFileError(f"{path}: the mesh is empty (no triangles)")
    if not np.all(np.isfinite(vertices)):
        raise MeshFileError(f"{path}: the mesh has non-finite vertex coordinates")
    reach = float(np.abs(vertices).max())
    if reach > MAX_COORDINATE_M:  # 1e30 m: beyond any scene, and past what float32 rays can meet
        raise MeshFileError(f"{path}: vertex coordinates reach {reach:.3g} m; allowed: within "
                            f"{MAX_COORDINATE_M:g} m of the mesh's origin")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshFileError(f"{path}: faces refer to vertices that do not exist")
    v = vertices[faces]
    proper = np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) > 0
    del v
    if not np.any(proper):
        raise MeshFileError(f"{path}: every triangle of the mesh is degenerate (zero area)")
    faces = distinct_faces(faces, proper)
    vertices.setflags(write=False)
    faces.setflags(write=False)
    if texture:
        if path.lower().endswith(".obj") and not any(not n.lower().endswith(".mtl") for n in resolver.read):
            # No image was read: trimesh would give the UVs its own 2 x 2 grey image.
            if resolver.missing:
                raise MeshFileError(f"{path}: texture: true needs the OBJ's material library and its texture "
                                    f"image; {', '.join(map(repr, resolver.missing))} not found beside the mesh")
            raise MeshFileError(f"{path}: the mesh has no texture (its material library names no map_Kd image)")
        return TriangleMesh(vertices, faces, *_texture_of(loaded, path))
    return TriangleMesh(vertices, faces)


def distinct_faces(faces: np.ndarray, proper: np.ndarray | None = None) -> np.ndarray:
    """The faces without repeats (the same corners in the same winding, whichever corner is
    written first) and, given ``proper``, without the degenerate ones.

    A face repeated a million times is one surface for the sonar, but a pile of coincident
    triangles that no bounding-volume hierarchy can separate: each ray tested every copy
    (1 million copies of one triangle: 30 s a frame). Degenerate faces (zero area) are never hit.

    Parameters
    ----------
    faces : (n, 3) int32 ndarray
    proper : (n,) bool ndarray, optional
        Which faces have a non-zero area.

    Returns
    -------
    (m, 3) int32 ndarray
        The kept faces in their order (``faces`` itself when nothing is dropped).
    """
    # Each face rotated so that its smallest index leads: same corners and winding (and so the
    # same normal), same row. Contiguous columns: strided ones cost five times as much here.
    a, b, c = faces.T.astype(np.int64)
    lead_a = (a <= b) & (a <= c)
    lead_b = ~lead_a & (b <= c)
    first = np.where(lead_a, a, np.where(lead_b, b, c))
    second = np.where(lead_a, b, np.where(lead_b, c, a))
    third = np.where(lead_a, c, np.where(lead_b, a, b))
    del a, b, c, lead_a, lead_b
    # A 64-bit hash of the row (wrapping), sorted: no two equal is the common case, settled by
    # one sort; otherwise the rows themselves are compared.
    hashed = first * np.int64(-7046029254386353131)
    hashed ^= second * np.int64(-4658895280553007687)
    hashed ^= third
    ordered = np.sort(hashed)
    if not (ordered[1:] == ordered[:-1]).any():
        keep = np.ones(len(faces), bool) if proper is None else np.asarray(proper, bool)
        return faces if keep.all() else np.ascontiguousarray(faces[keep])
    _, first_of = np.unique(np.stack([first, second, third], axis=1), axis=0, return_index=True)
    keep = np.zeros(len(faces), bool)
    keep[first_of] = True
    if proper is not None:
        keep &= proper
    if keep.all():
        return faces
    return np.ascontiguousarray(faces[keep])


# Memory a mesh file takes to load, per byte of the file (an estimate: the bytes read, the
# parsed vertex and face arrays, and trimesh's processed copies).
MESH_BYTES_PER_FILE_BYTE = 4
# Time to parse it, per byte: trimesh reads an OBJ at 3 to 7 MB/s here (short lines slowest).
MESH_SECONDS_PER_FILE_BYTE = 4e-7


def load_mesh_file(path: str | os.PathLike, texture: bool = False) -> TriangleMesh:
    """Read a mesh file into object coordinates, cached by path and modification time.

    With ``texture``, also its UV coordinates and texture brightness (an error without them).

    Raises
    ------
    MeshFileError
        The file is missing, unreadable, not of a format in :data:`MESH_SUFFIXES`, holds no
        triangles or vertices beyond ``MAX_COORDINATE_M``, or refers to a file that is not a
        regular file (a pipe, a device); with ``texture``, an OBJ whose material library or
        texture image is missing. The message names the file.
    """
    p = Path(path)
    try:
        st = check_input_file(p, "mesh file")
    except SonarsimError as exc:
        raise MeshFileError(str(exc)) from None
    if p.suffix.lower() not in MESH_SUFFIXES:
        raise MeshFileError(f"{p}: {shown(p.suffix) if p.suffix else 'a name without a suffix'} is not a mesh format "
                            f"sonarsim reads; allowed: {', '.join(MESH_SUFFIXES)}")
    if st.st_size == 0:
        raise MeshFileError(f"{p}: the mesh file is empty")
    from ..core.memory import require, require_time

    try:
        # The whole file is read and parsed (a 10 GB file of zeros ended in a MemoryError after
        # reading until memory ran out); its arrays and trimesh's copies take a few times its size.
        what = f"reading a mesh file of {st.st_size / 2**20:.4g} MiB"
        require(float(st.st_size) * MESH_BYTES_PER_FILE_BYTE, what, "")
        require_time(float(st.st_size) * MESH_SECONDS_PER_FILE_BYTE, what, "")
    except SonarsimError as exc:
        raise MeshFileError(f"{p}: {exc}") from None
    return _load_mesh_file_cached(str(p.resolve()), st.st_mtime_ns, st.st_size, texture)


def world_reach_m(local: TriangleMesh, scale, pose) -> float:
    """How far from the world origin, along any axis, a mesh reaches once scaled and posed:
    ``max |R (scale v) + t|`` over its vertices (exact).

    The corners of the mesh's bounding box answer first (the box holds every vertex, and a
    linear map takes its extremes at corners); the vertices only when a corner lies beyond
    ``MAX_COORDINATE_M``, so that checking a 5-million-triangle mesh in every frame's scene
    costs nothing.

    Parameters
    ----------
    local : TriangleMesh
        In object coordinates.
    scale : float or (3,) float
    pose : Pose
        Object-to-world.
    """
    s = np.broadcast_to(np.asarray(scale, dtype=float), (3,))
    lo, hi = local.vertices.min(axis=0), local.vertices.max(axis=0)
    corners = np.array([[(lo, hi)[(k >> i) & 1][i] for i in range(3)] for k in range(8)])
    reach = float(np.abs((corners * s) @ pose.rotation.T + pose.translation).max())
    if reach <= MAX_COORDINATE_M:
        return reach
    return float(np.abs((local.vertices * s) @ pose.rotation.T + pose.translation).max())
