"""Textures: the brightness of a mesh's texture image scales its diffuse backscatter, texel by texel.

An object with ``material: {texture: true}`` whose mesh carries UV coordinates and a texture
image (an OBJ with its MTL and image, a GLB/glTF with a base-colour texture, or an in-memory
``trimesh.Trimesh`` with ``TextureVisuals``) backscatters, at a hit on triangle ``f`` with
barycentric coordinates ``(u, v)``, its law with the diffuse coefficient (``albedo`` or ``mu``)
times the brightness of the texel at

    uv = (1 - u - v) * uv[f0] + u * uv[f1] + v * uv[f2]

(nearest texel; coordinates wrap, so tiled textures repeat; v runs up the image, the OpenGL and
glTF/OBJ convention as trimesh reads them). Brightness is the image's luminance (ITU-R 601-2,
Pillow's ``L`` mode) over 255, in [0, 1]; an alpha channel is ignored. The specular lobe of the
rough law is not scaled: it is a property of the surface's slopes, not of its colour.

:class:`TexturedCaster` wraps any ray caster: it asks for the triangle and barycentric
coordinates of each hit and returns the brightness as :attr:`Hits.texel
<sonarsim.core.hits.Hits.texel>`, which every kernel and twin applies. Scenes without textures
never build it, and render as before.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from ..core.hits import Hits  # the casters' answer (below trace, which imports scene)
# brightness lives with the meshes that read texture images; re-exported here, where it was.
from .meshes import brightness


def sample(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-texel brightness at texture coordinates.

    Parameters
    ----------
    texture : (height, width) float32 array
        Brightness, row 0 at the image's top.
    uv : (n, 2) float array
        Texture coordinates; u runs right, v up; both wrap (``u = 1.25`` is ``u = 0.25``).

    Returns
    -------
    (n,) float32 ndarray
    """
    h, w = texture.shape
    uv = np.asarray(uv, dtype=np.float64)
    u = uv[:, 0] - np.floor(uv[:, 0])
    v = uv[:, 1] - np.floor(uv[:, 1])
    col = np.minimum((u * w).astype(np.int64), w - 1)
    row = np.minimum(((1.0 - v) * h).astype(np.int64), h - 1)
    return texture[row, col]


def texel_at(mesh, primitive_id: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """Brightness of ``mesh``'s texture at hits on its triangles.

    Parameters
    ----------
    mesh : TriangleMesh
        With ``uv`` and ``texture``.
    primitive_id : (n,) int array
        Triangle hit (index into ``mesh.faces``).
    barycentric : (n, 2) float array
        ``(u, v)`` of the hit: ``p = (1 - u - v) a + u b + v c`` for the triangle's corners ``a, b, c``.

    Returns
    -------
    (n,) float32 ndarray
    """
    corners = mesh.uv[mesh.faces[np.asarray(primitive_id)]]  # (n, 3, 2)
    b = np.asarray(barycentric, dtype=np.float64)
    uv = (1.0 - b[:, 0:1] - b[:, 1:2]) * corners[:, 0] + b[:, 0:1] * corners[:, 1] + b[:, 1:2] * corners[:, 2]
    return sample(mesh.texture, uv)


class TexturedCaster:
    """A ray caster whose hits carry the texture brightness of the meshes that have a texture.

    Parameters
    ----------
    caster : RayCaster
        Built over ``meshes`` (it must answer ``intersect(..., with_uv=True)``).
    meshes : sequence of TriangleMesh
        The meshes, in the caster's order; those with a ``texture`` are sampled.
    """

    #: Its hits carry ``texel`` (the engine then records the factor in the legs it traces).
    carries_texel = True

    def __init__(self, caster, meshes: Sequence) -> None:
        self.caster = caster
        self.name = caster.name
        self._textured = [(k, m) for k, m in enumerate(meshes) if m.texture is not None and len(m.faces)]

    def intersect(self, origins: np.ndarray, directions: np.ndarray, max_distance: float,
                  threads: int | None = None, with_uv: bool = False) -> Hits:
        """The caster's hits with ``texel``: the brightness at textured hits, 1 elsewhere (and,
        whatever ``with_uv`` says, the triangles and barycentric coordinates it was read at)."""
        hits = self.caster.intersect(origins, directions, max_distance, threads=threads, with_uv=True)
        texel = np.ones(len(hits.distance), dtype=np.float32)
        for k, mesh in self._textured:
            on = np.flatnonzero(hits.mesh_id == k)
            if len(on):
                texel[on] = texel_at(mesh, hits.primitive_id[on], hits.barycentric[on])
        return replace(hits, texel=texel)

    def __getattr__(self, name: str):
        if name == "caster":  # not set yet (copying): no recursion
            raise AttributeError(name)
        return getattr(self.caster, name)  # cast_raw, threads, close, ...


def with_textures(caster, meshes: Sequence):
    """``caster`` wrapped in a :class:`TexturedCaster` when some mesh has a texture; else itself."""
    if any(m.texture is not None for m in meshes):
        return TexturedCaster(caster, meshes)
    return caster
