"""Ground echo (paper Algorithm 2): hand-computed geometry, fast vs literal method, traps."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import sonarsim
from sonarsim.scene.meshes import TriangleMesh, clip_to_water
from sonarsim.config.examples import demo_scene_dict
from tests.conftest import sonar_dict

POSE = {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [8.0, 15.0, 4.0]}  # rolled, pitched, yawed


def sphere_scene(centre, radius=0.05, **render):
    return {
        "sonar": sonar_dict(n_beams=96, elevation_fov_deg=26.0, n_range_bins=1000, pose=POSE),
        "ground": {"albedo": 0.5, "specular": 1.0},
        "render": {"elevation_samples": 600, "double_beam": "paper", **render},  # the paper's convention
        "objects": [{"name": "ball", "primitive": "sphere", "radius_m": radius, "pose": {"position_m": list(centre)}}],
    }


def sonar_frame(img, p):
    return (np.asarray(p) - img.pose.translation) @ img.pose.rotation


def beam_of(img, p):
    q = sonar_frame(img, p)
    az = np.degrees(np.arctan2(q[1], q[0]))
    edges = img.sonar.beam_edges_deg
    return int(np.searchsorted(-edges, -az, side="right") - 1)


def energy_range(img, comp):
    rows = np.flatnonzero(img.components[comp].sum(axis=1) > 0)
    return img.range_m[rows[0]], img.range_m[rows[-1]]


def test_single_double_triple_land_where_the_geometry_says():
    c = np.array([3.0, 0.3, 0.35])
    r = 0.05
    img = sonarsim.render(sphere_scene(c, r))
    s = img.sonar
    o = img.pose.translation
    c_mirror = c * [1, 1, -1]
    oc, oc_m = np.linalg.norm(c - o), np.linalg.norm(c_mirror - o)
    for p in (c, c_mirror):  # the set-up keeps both in the aperture
        q = sonar_frame(img, p)
        assert abs(np.degrees(np.arcsin(q[2] / np.linalg.norm(q)))) < s.elevation_fov_deg / 2 - 2
    dr = s.range_resolution_m
    lo, hi = energy_range(img, "object")  # OA in [|OC| - r, |OC|]
    # (bin centres: half a bin; the silhouette's extrapolated half-interval: up to one more)
    assert oc - r - dr <= lo and hi <= oc + 2 * dr
    lo, hi = energy_range(img, "triple")  # OA' in [|OC'| - r, |OC'|]
    assert oc_m - r - dr <= lo and hi <= oc_m + 2 * dr
    mid = 0.5 * (oc + oc_m)  # (OA + OA')/2, with OA in [|OC| - r, |OC| + r]
    lo, hi = energy_range(img, "double")
    assert mid - r - dr <= lo and hi <= mid + r / 2 + 2 * dr
    # Beams: the object in the beam of C, both ghosts in the beam of C' (the paper's choice).
    assert np.argmax(img.components["object"].sum(axis=0)) == beam_of(img, c)
    assert np.argmax(img.components["triple"].sum(axis=0)) == beam_of(img, c_mirror)
    assert np.argmax(img.components["double"].sum(axis=0)) == beam_of(img, c_mirror)
    assert beam_of(img, c) != beam_of(img, c_mirror)  # the roll separates them
    # Weights: with R = 1 the double carries the mirror rays' energy, as does the triple.
    assert img.components["double"].sum() == pytest.approx(img.components["triple"].sum(), rel=1e-3)


def test_split_double_beams_puts_case_2_in_the_beam_of_a():
    c = np.array([3.0, 0.3, 0.35])
    img = sonarsim.render(sphere_scene(c, double_beam="split"))
    split = img.components["double"].astype(float)
    paper = sonarsim.render(sphere_scene(c)).components["double"].astype(float)
    assert split.sum() == pytest.approx(paper.sum(), rel=1e-6)
    # split = half of the paper's image (case 3, beam of A') + case 2 moved to the beam of A.
    case2 = split - 0.5 * paper
    assert case2.sum() == pytest.approx(0.5 * paper.sum(), rel=1e-5)
    assert np.argmax(case2.sum(axis=0)) == beam_of(img, c)
    assert np.argmax(paper.sum(axis=0)) == beam_of(img, c * [1, 1, -1])
    # Same ranges, other beams: the range profiles agree.
    np.testing.assert_allclose(case2.sum(axis=1), 0.5 * paper.sum(axis=1), rtol=1e-4, atol=1e-12)


def test_specular_reflectance_scales_double_by_r_and_triple_by_r_squared():
    c = [3.0, 0.3, 0.35]
    full = sonarsim.render(sphere_scene(c))
    doc = sphere_scene(c)
    doc["ground"]["specular"] = 0.5
    half = sonarsim.render(doc)
    np.testing.assert_allclose(half.components["double"], 0.5 * full.components["double"], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(half.components["triple"], 0.25 * full.components["triple"], rtol=1e-5, atol=1e-12)
    np.testing.assert_array_equal(half.components["single"], full.components["single"])


def test_components_sum_to_the_total_and_bounces_select_them():
    doc = demo_scene_dict()
    img = sonarsim.render(doc)
    comp = img.components
    signatures = {"O-[objects]-O": "object", "O-[ground]-O": "ground", "O-ground-[objects]-ground-O": "triple"}
    pair = ("O-[objects]-ground-O", "O-ground-[objects]-O")  # coherent: both of the reciprocal pair
    assert set(comp) == {"object", "ground", "single", "double", "triple", "total"} | set(signatures) | set(pair)
    for sig, name in signatures.items():
        np.testing.assert_allclose(comp[sig], comp[name], rtol=1e-5, atol=1e-7 * comp[name].max())
    np.testing.assert_allclose(comp[pair[0]] + comp[pair[1]], comp["double"], rtol=1e-5,
                               atol=1e-7 * comp["double"].max())
    assert comp["double"].any() and comp["triple"].any()
    np.testing.assert_allclose(comp["single"], comp["object"] + comp["ground"], rtol=1e-6)
    np.testing.assert_allclose(img.polar, comp["single"] + comp["double"] + comp["triple"], rtol=1e-5, atol=1e-9)
    np.testing.assert_array_equal(img.polar, comp["total"])
    for bounces, keys in (([1], ["single"]), ([1, 3], ["single", "triple"])):
        doc["render"]["bounces"] = bounces
        other = sonarsim.render(doc)
        np.testing.assert_allclose(other.polar, sum(comp[k] for k in keys), rtol=1e-5, atol=1e-9)


def _scenes():
    demo = demo_scene_dict()
    rolled = demo_scene_dict()
    rolled["sonar"]["pose"] = {"position_m": [0.2, -0.1, 1.2], "rpy_deg": [12.0, 25.0, -6.0]}
    crossing = demo_scene_dict()
    crossing["objects"].append(
        {"name": "half_buried", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [3.6, 0.6, 0.05]}})
    crossing["objects"].append(
        {"name": "tilted_post", "primitive": "box", "size_m": [0.1, 0.1, 1.0],
         "pose": {"position_m": [3.0, -0.1, 0.2], "rpy_deg": [0, 25, 0]}})
    nosplat = demo_scene_dict()
    nosplat["render"]["range_splat"] = False
    tvg_off = copy.deepcopy(rolled)
    tvg_off["render"]["tvg"] = False
    return {"demo": demo, "rolled": rolled, "crossing": crossing, "algorithm1": nosplat, "no_tvg": tvg_off}


@pytest.mark.parametrize("name", list(_scenes()))
def test_fast_method_equals_the_literal_algorithm_2(name):
    # Tolerance: both cast float32 rays, but against different geometry (mirrored triangles at
    # A' vs reflected rays from G), so hit distances differ by ~1e-6 m and a few rays' energy
    # moves to the neighbouring bin: 1e-3 of each component's energy covers that with room.
    doc = _scenes()[name]
    doc["render"]["method"] = "fast"
    doc["render"]["double_beam"] = "paper"  # Algorithm 2's convention for the pairs (the default is coherent)
    fast = sonarsim.render(doc)
    doc["render"]["method"] = "paper"
    paper = sonarsim.render(doc)
    assert paper.components["triple"].any()
    for key in fast.components:
        a, b = fast.components[key].astype(float), paper.components[key].astype(float)
        assert np.abs(a - b).sum() <= 1e-3 * np.abs(b).sum() + 1e-12, key


@pytest.mark.filterwarnings("ignore:the sonar is on the dry side")  # a sonar below a plane, on purpose
@pytest.mark.filterwarnings("ignore:objects .* lie entirely beyond")  # a ground above them, on purpose
def test_no_multipath_without_ground_below_the_sonar_or_with_r_zero():
    doc = demo_scene_dict()
    for variant in ("no_ground", "below", "r0"):
        d = copy.deepcopy(doc)
        if variant == "no_ground":
            del d["ground"]
        elif variant == "below":
            d["ground"]["height_m"] = 1.5  # the sonar at 1 m is under it
        else:
            d["ground"]["specular"] = 0.0
        for method in ("fast", "paper"):
            d["render"]["method"] = method
            img = sonarsim.render(d)
            assert not img.components["double"].any() and not img.components["triple"].any(), (variant, method)
        if variant == "below":
            assert not img.components["ground"].any()


def test_line_of_sight_option_drops_double_bounces_from_hidden_points():
    scene = {
        "sonar": sonar_dict(n_beams=32, elevation_fov_deg=20.0, n_range_bins=600,
                            pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 18, 0]}),
        "ground": {},
        "render": {"elevation_samples": 400},
        "objects": [
            {"name": "ball", "primitive": "sphere", "radius_m": 0.1, "pose": {"position_m": [3.0, 0, 0.5]}},
            # Hides the ball from the sonar but not the floor patch that reflects towards it.
            {"name": "screen", "primitive": "box", "size_m": [0.02, 0.6, 0.3], "pose": {"position_m": [1.5, 0, 0.75]}},
        ],
    }
    paper = sonarsim.render(scene)
    scene["render"]["double_line_of_sight"] = True
    strict = sonarsim.render(scene)
    assert paper.components["double"].sum() > 0
    # Only the ball's mirror paths are double bounces here; all of them start at a hidden A.
    ball_part = paper.components["double"].sum() - strict.components["double"].sum()
    assert ball_part > 0.5 * paper.components["double"].sum()
    np.testing.assert_array_equal(paper.components["triple"], strict.components["triple"])


def test_clipping_keeps_only_geometry_above_the_plane():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    mesh = TriangleMesh(np.asarray(m.vertices), np.asarray(m.faces, np.int32))
    clipped = clip_to_water(mesh, (0, 0, 0.25), (0, 0, 1))
    used = clipped.vertices[np.unique(clipped.faces)]
    assert used[:, 2].min() >= 0.25 - 1e-9
    # Area of a spherical cap of height 0.75 on a unit sphere: 2 pi R h.
    tri = clipped.triangles
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(2 * np.pi * 0.75, rel=0.01)
    # A box resting on the floor loses exactly its two base triangles.
    box = trimesh.creation.box(extents=[1, 1, 1])
    resting = TriangleMesh(np.asarray(box.vertices) + [0, 0, 0.5], np.asarray(box.faces, np.int32))
    assert len(clip_to_water(resting, (0, 0, 0), (0, 0, 1)).faces) == 10


@pytest.mark.parametrize("method", ["fast", "paper"])
def test_objects_resting_on_the_floor_make_no_echo_nearer_than_themselves(method):
    # Mirror geometry above the plane, or a base face coinciding with the floor, would put echo
    # energy at ranges shorter than the object itself: every real multipath path is longer
    # (OA' >= OA), so nothing may arrive before the object's own nearest echo.
    doc = {
        "sonar": sonar_dict(n_beams=48, elevation_fov_deg=20.0, n_range_bins=900,
                            pose={"position_m": [0, 0, 1.0], "rpy_deg": [0, 18, 0]}),
        "ground": {"albedo": 0.5, "specular": 1.0},
        "render": {"method": method},
        "objects": [
            {"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.3], "pose": {"position_m": [3.0, 0.2, 0.15]}},
            {"name": "half_buried", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [3.5, -0.4, 0.0]}},
        ],
    }
    img = sonarsim.render(doc)
    obj = img.components["object"]
    for j in range(img.sonar.n_beams):
        rows = np.flatnonzero(obj[:, j] > 0)
        ghost = np.flatnonzero((img.components["double"][:, j] > 0) | (img.components["triple"][:, j] > 0))
        if ghost.size:
            assert rows.size and ghost.min() >= rows.min(), j
    assert img.components["triple"].any() and img.components["double"].any()
    # The paper's difference images (ground = S1 - S2) go negative if S2 sees below the floor.
    for key, comp in img.components.items():
        assert comp.min() >= -1e-6 * comp.max(), key
