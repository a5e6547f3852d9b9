"""Primitive tessellation: as coarse as the tolerance allows, never coarser (issue 21: a scene of
20,000 pebbles of 1 cm was 100 million triangles)."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.config.scene import ObjectSpec
from sonarsim.scene.meshes import (CYLINDER_SECTIONS, PRIMITIVE_TOLERANCE_M, SPHERE_SUBDIVISIONS, cylinder_sections,
                                   object_mesh_local, primitive_mesh, sphere_subdivisions)


def _sag(mesh, radius):
    """How far inside the sphere (or the cylinder's side, in x-y) the face centres lie, at most."""
    centres = mesh.vertices[mesh.faces].mean(axis=1)
    return radius - np.linalg.norm(centres, axis=1).min()


@pytest.mark.parametrize("radius", [0.001, 0.004, 0.01, 0.02, 0.04, 0.05, 0.2, 1.0])
def test_sphere_facets_within_the_tolerance_and_no_finer_than_needed(radius):
    level = sphere_subdivisions(radius)
    mesh = primitive_mesh("sphere", radius_m=radius)
    assert len(mesh.faces) == 20 * 4 ** level
    if level < SPHERE_SUBDIVISIONS:
        assert _sag(mesh, radius) <= PRIMITIVE_TOLERANCE_M * (1 + 1e-9)
    if level > 0:  # one level coarser would have been beyond the tolerance
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=level - 1, radius=radius)
        assert radius - np.linalg.norm(m.triangles_center, axis=1).min() > PRIMITIVE_TOLERANCE_M


def test_spheres_of_5_cm_and_more_keep_the_finest_tessellation():
    # The images of every scene before this change (spheres of 8 cm and more) are unchanged.
    for radius in (0.05, 0.08, 0.15, 0.3, 2.0):
        assert len(primitive_mesh("sphere", radius_m=radius).faces) == 20 * 4 ** SPHERE_SUBDIVISIONS
        assert len(primitive_mesh("cylinder", radius_m=radius, height_m=0.5).faces) == 4 * CYLINDER_SECTIONS


@pytest.mark.parametrize("radius", [0.002, 0.01, 0.03, 0.1])
def test_cylinder_chords_within_the_tolerance(radius):
    n = cylinder_sections(radius)
    assert radius * (1 - np.cos(np.pi / n)) <= PRIMITIVE_TOLERANCE_M or n == CYLINDER_SECTIONS
    if n > 8:
        assert radius * (1 - np.cos(np.pi / (n // 2))) > PRIMITIVE_TOLERANCE_M


def test_tessellation_follows_the_scale():
    # A 1 cm sphere drawn ten times larger is tessellated as a 10 cm sphere.
    small = ObjectSpec(name="s", primitive="sphere", radius_m=0.01)
    scaled = ObjectSpec(name="s", primitive="sphere", radius_m=0.01, scale=(1.0, 10.0, 1.0))
    assert len(object_mesh_local(small).faces) < len(object_mesh_local(scaled).faces)
    assert len(object_mesh_local(scaled).faces) == 20 * 4 ** sphere_subdivisions(0.1)


def test_primitive_meshes_are_shared_and_read_only():
    a = object_mesh_local(ObjectSpec(name="a", primitive="sphere", radius_m=0.01))
    b = object_mesh_local(ObjectSpec(name="b", primitive="sphere", radius_m=0.01))
    assert a is b
    with pytest.raises(ValueError):
        a.vertices[0, 0] = 1.0
