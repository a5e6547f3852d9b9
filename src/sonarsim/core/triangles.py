"""A plain triangle mesh: vertices, faces and, for a textured mesh, its UV coordinates and
texture brightness.

:class:`TriangleMesh` is what a mesh file reads into (:mod:`sonarsim.config.meshfiles`), what
the scene's objects become in the world frame (:mod:`sonarsim.scene.meshes`) and what every
ray caster (:mod:`sonarsim.trace`) is built from. A plain data type of arrays, it lives here,
at the bottom; :mod:`sonarsim.scene.meshes` re-exports it, where it was.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TriangleMesh"]


@dataclass(frozen=True)
class TriangleMesh:
    """A plain triangle mesh.

    Attributes
    ----------
    vertices : (n_vertices, 3) float64 ndarray, metres
    faces : (n_faces, 3) int32 ndarray, indices into ``vertices``
    uv : (n_vertices, 2) float64 ndarray or None
        Texture coordinates of each vertex (u right, v up the image), with ``texture``.
    texture : (height, width) float32 ndarray or None
        Brightness in [0, 1] of the texture image, row 0 at the image's top.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    texture: np.ndarray | None = None

    @property
    def triangles(self) -> np.ndarray:
        """(n_faces, 3, 3) corner coordinates."""
        return self.vertices[self.faces]
