"""Texture lookup: conventions of the texture coordinates, and UVs carried through clipping and mirroring."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from sonarsim.errors import MeshFileError
from sonarsim.scene.meshes import TriangleMesh, clip_to_water, load_mesh_file, mirror_across_plane
from sonarsim.scene.textures import TexturedCaster, brightness, sample, texel_at
from sonarsim.trace import make_caster

# 2 x 4 texture: rows top to bottom, columns left to right.
TEX = np.array([[0.0, 0.1, 0.2, 0.3],
                [0.4, 0.5, 0.6, 0.7]], dtype=np.float32)


def test_sample_reads_u_to_the_right_and_v_up():
    uv = np.array([[0.01, 0.99], [0.99, 0.99], [0.01, 0.01], [0.99, 0.01], [0.3, 0.7], [0.6, 0.2]])
    np.testing.assert_array_equal(sample(TEX, uv), np.float32([0.0, 0.3, 0.4, 0.7, 0.1, 0.6]))


def test_sample_wraps_and_keeps_the_edges_inside():
    np.testing.assert_array_equal(sample(TEX, [[1.01, 0.99], [-0.99, 1.99], [0.0, 0.0], [1.0, 1.0]]),
                                  np.float32([0.0, 0.0, 0.4, 0.4]))


def test_brightness_is_the_luminance_over_255():
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[0, 0] = (255, 255, 255)
    rgb[0, 1] = (255, 0, 0)
    out = brightness(Image.fromarray(rgb))
    assert out.dtype == np.float32 and out.shape == (2, 2)
    np.testing.assert_allclose(out, [[1.0, 76 / 255], [0.0, 0.0]], atol=1 / 255)


def quad(texture=TEX) -> TriangleMesh:
    """The unit square in the plane x = 0, y and z in [0, 1]: u along y, v along z."""
    v = np.array([[0.0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]])
    return TriangleMesh(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), v[:, 1:].copy(), texture)


def cast_at(mesh, points_yz, backend="numpy"):
    """Texture brightness where rays along +x meet the quad at (y, z)."""
    o = np.column_stack([np.full(len(points_yz), -1.0), points_yz])
    d = np.tile([1.0, 0.0, 0.0], (len(o), 1))
    return TexturedCaster(make_caster(backend, [mesh]), [mesh]).intersect(o, d, 5.0)


@pytest.mark.parametrize("backend", ["embree", "numpy"])
def test_the_texel_under_each_hit(backend):
    yz = np.array([[0.1, 0.9], [0.9, 0.9], [0.1, 0.1], [0.9, 0.1], [0.4, 0.6]])
    hits = cast_at(quad(), yz, backend)
    np.testing.assert_array_equal(hits.texel, sample(TEX, yz))
    assert hits.texel.dtype == np.float32
    # Rays that miss get 1 (the diffuse coefficient unchanged).
    assert cast_at(quad(), np.array([[2.0, 2.0]]), backend).texel[0] == 1.0


def test_texel_at_interpolates_the_corners_uv():
    m = quad()
    # Triangle 1 is (0, 2, 3): corners (y, z) = (0, 0), (1, 1), (0, 1).
    out = texel_at(m, np.array([1, 1]), np.array([[0.1, 0.8], [0.8, 0.1]]))
    np.testing.assert_array_equal(out, sample(TEX, [[0.1, 0.9], [0.8, 0.9]]))


def test_clipping_keeps_each_points_texel():
    # The plane z = 0.3 cuts the quad; above it, every point keeps its texel.
    m = quad()
    cut = clip_to_water(m, (0.0, 0.0, 0.3), (0.0, 0.0, 1.0))
    assert cut.texture is m.texture and len(cut.uv) == len(cut.vertices) > len(m.vertices)
    rng = np.random.default_rng(0)
    yz = np.column_stack([rng.uniform(0.01, 0.99, 500), rng.uniform(0.31, 0.99, 500)])
    np.testing.assert_array_equal(cast_at(cut, yz).texel, cast_at(m, yz).texel)
    # ... and the part below is gone.
    assert np.all(cast_at(cut, np.array([[0.5, 0.2]])).mesh_id == -1)


def test_a_mirror_image_shows_the_mirrored_texture():
    m = quad()
    mirrored = mirror_across_plane(m, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))  # z -> -z
    yz = np.array([[0.1, 0.9], [0.6, 0.2]])
    np.testing.assert_array_equal(cast_at(mirrored, yz * [1, -1]).texel, cast_at(m, yz).texel)


def test_mesh_files_keep_their_texture(tmp_path):
    mesh = trimesh.Trimesh(vertices=quad().vertices, faces=quad().faces, process=False)
    image = Image.fromarray((TEX * 255).round().astype(np.uint8))
    mesh.visual = trimesh.visual.TextureVisuals(uv=quad().uv, image=image)
    for name in ("quad.glb", "quad.obj"):
        path = tmp_path / name
        mesh.export(path)
        loaded = load_mesh_file(path, texture=True)
        np.testing.assert_allclose(loaded.texture, TEX, atol=0.5 / 255)
        yz = np.array([[0.1, 0.9], [0.9, 0.1], [0.6, 0.3]])
        np.testing.assert_allclose(cast_at(loaded, yz).texel, sample(TEX, yz), atol=0.5 / 255)
        assert load_mesh_file(path).texture is None  # only when asked for
    plain = tmp_path / "plain.stl"
    trimesh.Trimesh(vertices=quad().vertices, faces=quad().faces).export(plain)
    with pytest.raises(MeshFileError, match="no texture"):
        load_mesh_file(plain, texture=True)
