"""A textured floor in the renderer: every path that scatters off it takes the world-anchored factor.

Checks: the fast engine (compiled kernels and NumPy twins) equals the slow reference with
textures on; a zero spread renders bit for bit as no texture (also on the specialised ground
kernels); a textured ground takes the general engine; the factor a ray takes is a function of
its world hit point alone, whatever the pose; a still scene shows the same texture frame after
frame; a sonar moved along x sees the floor's pattern moved in its image; Algorithm 2 (``method:
paper``) textures its direct ground echo as the fast method does.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.core.transforms import Pose
from tests.reference.test_brute_force import compare, ground_dict, tank_dict

TEXTURE = {"std_db": 4.0, "correlation_m": [0.3, 0.1], "angle_deg": 20.0, "seed": 3}


def textured(doc: dict, wall: bool = True) -> dict:
    doc = copy.deepcopy(doc)
    doc["ground"]["texture"] = dict(TEXTURE)
    if wall and doc.get("planes"):
        doc["planes"][1]["texture"] = {"std_db": 3.0, "correlation_m": 0.2, "covariance": "exponential"}
    return doc


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("scene", [tank_dict, ground_dict])
def test_fast_path_equals_the_reference_with_textured_planes(scene, kernels):
    doc = textured(scene(3))
    compare(doc, kernels)
    # And the texture changed what scatters off the textured planes, in every order.
    plain = sonarsim.Simulator(scene(3), kernels=kernels).render().components
    tex = sonarsim.Simulator(doc, kernels=kernels).render().components
    changed = [n for n in plain.signatures if "[ground]" in n or "[far_wall]" in n]
    assert changed
    if scene is tank_dict:  # multipath that scatters off the textured planes (via the water surface, a wall)
        assert any(n.count("-") > 2 for n in changed)
    for name in plain.signatures:
        a, b = tex[name].astype(float), plain[name].astype(float)
        if "[ground]" in name or "[far_wall]" in name:
            assert np.abs(a - b).sum() > 0.05 * b.sum(), name
        else:  # objects and untextured planes scatter as before (the plain ground alone takes the
            # specialised kernels: float32 round-off apart)
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7 * b.max(), err_msg=name)


@pytest.mark.parametrize("scene", [tank_dict, ground_dict])
def test_zero_spread_renders_bit_for_bit_as_no_texture(scene):
    zero = copy.deepcopy(scene(3))
    zero["ground"]["texture"] = {**TEXTURE, "std_db": 0.0}
    for kernels in ("compiled", "numpy"):
        a = sonarsim.Simulator(scene(3), kernels=kernels).render()
        b = sonarsim.Simulator(zero, kernels=kernels).render()
        np.testing.assert_array_equal(a.polar, b.polar)
        for name in a.components:
            np.testing.assert_array_equal(a.components[name], b.components[name])


def test_a_textured_ground_equals_the_numpy_engine():
    doc = textured(ground_dict(3))
    fast = sonarsim.Simulator(doc).render().polar
    general = sonarsim.Simulator(doc, kernels="numpy").render().polar
    np.testing.assert_allclose(fast, general, rtol=1e-5, atol=1e-6 * general.max())


def floor_doc(texture: dict | None, **render) -> dict:
    """A floor alone seen from 1 m, pitched 15 degrees down, the texture varying along x only."""
    doc = {
        "sonar": {"n_beams": 32, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 30.0, "range_min_m": 1.5,
                  "range_max_m": 8.0, "n_range_bins": 520,
                  "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 15.0, 0.0]}},
        "render": {"max_order": 1, **render},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.0},
    }
    if texture is not None:
        doc["ground"]["texture"] = texture
    return doc


STRIPES = {"std_db": 5.0, "correlation_m": [0.25, 1e4], "seed": 1}  # ridges along y: a pattern in x


def test_each_ray_takes_the_factor_of_its_world_hit_point_whatever_the_pose():
    tex = sonarsim.Simulator(floor_doc({**STRIPES, "correlation_m": [0.25, 0.4], "angle_deg": 30.0}))
    plain = sonarsim.Simulator(floor_doc(None))
    field = tex.textures[0]
    fan = tex.ray_fan(tex.scene.sonar)
    for pose in (Pose([0.0, 0.0, 1.0], [0.0, 15.0, 0.0]), Pose([3.2, -1.7, 1.4], [5.0, 25.0, 70.0])):
        a, b = tex.render(pose=pose).rays, plain.render(pose=pose).rays
        on = a.surface_id.reshape(-1) == 0
        assert on.sum() > 1000
        # The hit points from the rays' lengths and the fan's directions at this pose.
        d = (fan.directions @ pose.rotation.T).reshape(-1, 3)[on]
        points = pose.translation + d * a.distance_m.reshape(-1)[on, None].astype(float)
        ratio = a.intensity.reshape(-1)[on].astype(float) / b.intensity.reshape(-1)[on]
        np.testing.assert_allclose(ratio, field.factor(points), rtol=1e-4)


def test_a_still_scene_shows_the_same_texture_frame_after_frame():
    doc = floor_doc(STRIPES, speckle=True, seed=4)
    sim = sonarsim.Simulator(doc)
    first, second = sim.render(), sim.render()
    np.testing.assert_array_equal(first.components["ground"], second.components["ground"])
    assert not np.array_equal(first.polar, second.polar)  # the speckle is drawn afresh
    again = sonarsim.Simulator(doc).render()  # another simulator, the same floor
    np.testing.assert_array_equal(again.components["ground"], first.components["ground"])
    other = copy.deepcopy(doc)
    other["ground"]["texture"]["seed"] = 2
    assert not np.allclose(sonarsim.Simulator(other).render().components["ground"], first.components["ground"])


def centre_profile(image, sonar, x0: float) -> tuple[np.ndarray, np.ndarray]:
    """The log texture along the two centre beams against world x of the floor (sonar at height 1 m)."""
    beams = slice(sonar.n_beams // 2 - 1, sonar.n_beams // 2 + 1)
    r = sonar.range_m
    return x0 + np.sqrt(r**2 - 1.0), image[:, beams].mean(axis=1)


def test_a_sonar_moved_along_x_sees_the_same_floor_moved_in_its_image():
    tex = sonarsim.Simulator(floor_doc(STRIPES))
    plain = sonarsim.Simulator(floor_doc(None))
    sonar = tex.scene.sonar
    profiles = []
    for x0 in (0.0, 1.5):
        pose = Pose([x0, 0.0, 1.0], [0.0, 15.0, 0.0])
        a, b = tex.render(pose=pose).polar, plain.render(pose=pose).polar
        lit = b > 0.05 * b.max()
        ratio = np.where(lit, np.log(np.where(lit, a, 1.0) / np.where(lit, b, 1.0)), np.nan)
        profiles.append(centre_profile(ratio, sonar, x0))
    (xa, pa), (xb, pb) = profiles
    # Where both see the floor: the second image's pattern at world x is the first's.
    both = np.isfinite(pa) & (xa > xb[0] + 0.1) & (xa < xb[-1] - 0.1)
    moved = np.interp(xa[both], xb[np.isfinite(pb)], pb[np.isfinite(pb)])
    assert both.sum() > 150
    assert np.corrcoef(pa[both], moved)[0, 1] > 0.9
    # The same images compared cell by cell, as if the floor had moved with the sonar: no match.
    still = np.isfinite(pa) & np.isfinite(pb)
    assert abs(np.corrcoef(pa[still], pb[still])[0, 1]) < 0.5


def test_algorithm_2_textures_the_direct_ground_echo_as_the_fast_method():
    from tests.reference.test_algorithm2 import _scenes

    doc = _scenes()["demo"]
    doc["ground"]["texture"] = dict(TEXTURE)
    doc["render"]["double_beam"] = "paper"  # Algorithm 2's convention for the pairs
    fast = sonarsim.render(doc)
    doc["render"]["method"] = "paper"
    paper = sonarsim.render(doc)
    for key in fast.components:
        a, b = fast.components[key].astype(float), paper.components[key].astype(float)
        assert np.abs(a - b).sum() <= 1e-3 * np.abs(b).sum() + 1e-12, key
    del doc["ground"]["texture"]
    assert not np.allclose(sonarsim.render(doc).components["ground"], paper.components["ground"])
