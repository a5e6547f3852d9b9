"""Ground truth per frame (``Simulator.render(..., labels=True)``, issue 12 item 1).

Analytic scenes with expectations worked out by hand: a sphere's elevation per cell, a floor's
elevation curve, a box's instance map, a double bounce's cells; invariants on the demo tank
(points land in the cells they claim, instance maps where the images have energy); the compiled
kernels against their NumPy twins.
"""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim import Simulator
from sonarsim.config.examples import demo_scene_dict
from sonarsim.image.fan import FanMapper
from sonarsim.renderer import compiled
from sonarsim.paths.engine import Leg, PathSet
from sonarsim.renderer.ground_truth import LabelSpec, _frame_truth, dominant, surface_ids

N_BEAMS = 33  # odd: beam 16 is centred on the acoustic axis


def sonar(pose, **kw):
    out = {"azimuth_fov_deg": 33.0, "n_beams": N_BEAMS, "elevation_fov_deg": 20.0, "range_min_m": 0.5,
           "range_max_m": 5.0, "n_range_bins": 450, "pose": pose}
    out.update(kw)
    return out


def scene(objects=(), ground=None, planes=(), render=None, **sonar_kw):
    doc = {
        "sonar": sonar({"position_m": [0.0, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]}, **sonar_kw),
        "render": {"elevation_samples": 400, "bounces": [1, 2, 3], **(render or {})},
        "objects": list(objects),
    }
    if ground is not None:
        doc["ground"] = ground
    if planes:
        doc["planes"] = list(planes)
    return doc


def render(doc, **kw):
    with Simulator(doc) as sim:
        return sim.render(speckle=False, labels=True, **kw)


def bin_of(r, img):
    return int(np.floor((r - img.sonar.range_min_m) / img.sonar.range_resolution_m))


# --- analytic scenes ---------------------------------------------------------------------


@pytest.mark.parametrize("h", [0.0, 0.25])
def test_a_sphere_has_the_elevations_of_its_near_side(h):
    """Sphere of radius R centred at (d, 0, h): the ray at elevation phi in the vertical plane
    of the centre beam meets it at range r where cos(phi - phi_c) = (r^2 + D^2 - R^2) / (2 r D),
    phi_c = atan2(h, d), D = |centre|: the cell at range r holds the two elevations
    phi_c +- alpha(r). On the axis (h = 0) the two arcs weigh the same: their mean is 0."""
    d, radius = 3.0, 0.3
    img = render(scene([{"name": "ball", "primitive": "sphere", "radius_m": radius,
                         "pose": {"position_m": [d, 0.0, h]}}]))
    lab = img.labels
    assert lab.ids == ("ball",)
    D = np.hypot(d, h)
    phi_c = np.degrees(np.arctan2(h, d))
    j = N_BEAMS // 2
    edges = img.range_edges_m

    def alpha(r):
        return np.degrees(np.arccos(np.clip((r * r + D * D - radius**2) / (2 * r * D), -1, 1)))

    step = 20.0 / 400  # elevation spacing of the rays, degrees
    near, tangent = D - radius, np.sqrt(D * D - radius**2)
    # Cells whose two arcs lie inside the aperture (+-10 degrees), away from the sphere's rim.
    rows = [i for i in range(len(edges) - 1) if near + 0.02 < edges[i] and edges[i + 1] < tangent - 0.05
            and phi_c + alpha(edges[i + 1] + img.sonar.range_resolution_m) < 9.5]
    assert len(rows) > 5
    for i in rows:
        lo, hi = alpha(edges[i] - img.sonar.range_resolution_m), alpha(edges[i + 1] + img.sonar.range_resolution_m)
        assert lab.instance["total"][i, j] == 0
        assert phi_c + lo - step <= lab.elevation_max_deg[i, j] <= phi_c + hi + step, i
        assert phi_c - hi - step <= lab.elevation_min_deg[i, j] <= phi_c - lo + step, i
        mean = lab.elevation_deg[i, j]
        assert lab.elevation_min_deg[i, j] <= mean <= lab.elevation_max_deg[i, j]
        if h == 0.0:  # symmetric arcs, symmetric weights (up to the mesh's facets)
            assert abs(mean) < 0.1 * lab.elevation_max_deg[i, j] + step, i
    # Nothing in front of the sphere.
    first = bin_of(near, img)
    assert (lab.instance["total"][: first - 1] == -1).all()
    assert np.isnan(lab.elevation_deg[: first - 1]).all()


def floor_elevation_deg(r, theta_deg, height, pitch_deg):
    """Sonar-frame elevation of the floor point at range r, azimuth theta, seen from height h
    with the nose pitched down: -sin(p) cos(phi) cos(theta) + cos(p) sin(phi) = -h / r."""
    p, t = np.radians(pitch_deg), np.radians(theta_deg)
    a, b = np.cos(p), np.sin(p) * np.cos(t)
    return np.degrees(np.arctan2(b, a) + np.arcsin(-height / (r * np.hypot(a, b))))


@pytest.mark.parametrize("pitch", [0.0, 20.0])
def test_a_floor_seen_from_above_follows_its_elevation_curve(pitch):
    """The direct floor echo at range r comes from asin(-h/r) (rotated by the pitch, per beam)."""
    height = 0.5
    doc = scene(ground={"height_m": 0.0, "albedo": 0.5, "specular": 0.0})
    doc["sonar"]["pose"] = {"position_m": [0.0, 0.0, height], "rpy_deg": [0.0, pitch, 0.0]}
    img = render(doc)
    lab = img.labels
    assert lab.ids == ("ground",)
    r = img.range_m[:, None]
    want = floor_elevation_deg(r, img.azimuth_deg[None, :], height, pitch)
    lit = lab.instance["total"] == 0
    assert lit.sum() > 2000
    # Away from the aperture's edges, where a cell can be partly lit.
    inner = lit & (np.abs(want) < 9.0)
    got = lab.elevation_deg[inner]
    # One bin spans up to d(phi)/dr * dr of elevation; the mean sits inside it.
    slope = np.abs(np.gradient(want, img.range_m, axis=0))[inner] * img.sonar.range_resolution_m
    assert np.all(np.abs(got - want[inner]) <= slope + 0.05)
    assert np.all(lab.elevation_min_deg[inner] <= got + 1e-4)
    assert np.all(lab.elevation_max_deg[inner] >= got - 1e-4)
    # Nothing lands where the floor is out of the aperture, and elevation is NaN there.
    assert np.isnan(lab.elevation_deg[~lit]).all()
    assert (lab.instance["total"][~lit] == -1).all()
    assert np.array_equal(lit, img.components["total"] > 0)


def test_a_box_occupies_the_beams_and_bins_of_its_front_face():
    """Box face at x = d, half-width w: beam j (centre ray at azimuth theta_j) sees it where
    |d tan(theta_j)| < w, first at range d / cos(theta_j) (the face's nearest point in the beam's
    vertical plane, at elevation 0)."""
    d, w = 2.5, 0.4
    img = render(scene([{"name": "crate", "primitive": "box", "size_m": [0.5, 2 * w, 0.6],
                         "pose": {"position_m": [d + 0.25, 0.0, 0.0]}}]))
    lab = img.labels
    inst = lab.instance["total"]
    y = d * np.tan(np.radians(img.azimuth_deg))
    beams_in = np.flatnonzero(np.abs(y) < w - 0.02)
    beams_out = np.flatnonzero(np.abs(y) > w + 0.02)
    assert len(beams_in) > 5 and len(beams_out) > 5
    assert (inst[:, beams_out] == -1).all()
    for j in beams_in:
        rows = np.flatnonzero(inst[:, j] == 0)
        assert len(rows)
        assert abs(rows[0] - bin_of(d / np.cos(np.radians(img.azimuth_deg[j])), img)) <= 1, j
    assert set(np.unique(inst)) == {-1, 0}
    b = lab.boxes_polar[0]
    assert b[1] <= beams_in[0] and b[3] >= beams_in[-1]
    assert not np.any((beams_out >= b[1]) & (beams_out <= b[3]))
    assert abs(b[0] - bin_of(d, img)) <= 1
    # The farthest point of the face: its corner.
    far = np.sqrt(d**2 + w**2 + 0.3**2)
    assert abs(b[2] - bin_of(far, img)) <= 2


def test_ids_name_objects_in_scene_order_then_planes_by_name():
    doc = scene(
        [{"name": "a", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [2.0, 0.5, 0.0]}},
         {"name": "b", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [3.0, -0.5, 0.0]}}],
        ground={"height_m": -1.0, "albedo": 0.5, "specular": 0.5},
        planes=[{"name": "far_wall", "point_m": [4.5, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0], "albedo": 0.5,
                 "specular": 0.0}],
    )
    lab = render(doc).labels
    assert lab.ids == ("a", "b", "ground", "far_wall")
    # The wall is the only thing at 4.5 m on the centre beam; the spheres are off it.
    j = N_BEAMS // 2
    img_bins = np.flatnonzero(lab.instance["total"][:, j] == 3)
    assert len(img_bins)
    assert set(np.unique(lab.instance["object"])) == {-1, 0, 1}
    assert set(np.unique(lab.instance["ground"])) <= {-1, 2, 3}
    assert surface_ids(np.array([-1, 0, 1, 2, 3]), 2, 2).tolist() == [-1, 2, 3, 0, 1]


def test_a_double_bounce_lands_at_half_its_unfolded_length():
    """Sphere above a mirror floor: the receive leg A -> G -> O is A -> O' unfolded (O' the
    sonar mirrored in the floor), the transmit leg O -> A direct; the path is recorded at
    (|OA| + |AO'|) / 2 and arrives from the elevation of A mirrored in the floor."""
    height = 0.6
    doc = scene([{"name": "ball", "primitive": "sphere", "radius_m": 0.25, "pose": {"position_m": [3.0, 0.0, 0.4]}}],
                ground={"height_m": 0.0, "albedo": 0.0, "specular": 1.0})
    doc["sonar"]["pose"] = {"position_m": [0.0, 0.0, height], "rpy_deg": [0.0, 10.0, 0.0]}
    doc.setdefault("render", {})["double_beam"] = "paper"  # each pair once, from the leg via the floor
    img = render(doc)
    lab = img.labels
    names = lab.point_components
    double = lab.points_component == names.index("double")
    assert double.sum() > 50
    assert (lab.points_object[double] == 0).all()  # scattered by the ball
    o = np.array([0.0, 0.0, height])
    o_mirror = np.array([0.0, 0.0, -height])
    a = lab.points_world[double].astype(np.float64)
    r = 0.5 * (np.linalg.norm(a - o, axis=1) + np.linalg.norm(a - o_mirror, axis=1))
    want = np.floor((r - img.sonar.range_min_m) / img.sonar.range_resolution_m)
    assert np.abs(lab.points_cell[double, 0] - want).max() <= 1
    assert np.mean(lab.points_cell[double, 0] == want) > 0.95
    # Those cells: the double image has energy and the ball dominates it.
    cells = lab.points_cell[double]
    assert (img.components["double"][cells[:, 0], cells[:, 1]] > 0).all()
    assert (lab.instance["double"][cells[:, 0], cells[:, 1]] == 0).all()
    # Where only the double lands (below the direct echo), the elevation is the mirrored A's.
    only = (img.components["double"] > 0) & (img.components["single"] == 0) & (img.components["triple"] == 0)
    assert only.sum() >= 5
    a_m = a * np.array([1.0, 1.0, -1.0])  # A mirrored in z = 0
    pose = img.pose
    v = (a_m - pose.translation) @ pose.rotation  # R^T (a - o): the sonar frame
    apparent = np.degrees(np.arcsin(v[:, 2] / np.linalg.norm(v, axis=1)))
    at = only[cells[:, 0], cells[:, 1]]
    lo = lab.elevation_min_deg[cells[at, 0], cells[at, 1]]
    hi = lab.elevation_max_deg[cells[at, 0], cells[at, 1]]
    step = 20.0 / 400
    assert np.all((lo - 2 * step <= apparent[at]) & (apparent[at] <= hi + 2 * step))
    # A ghost below the floor's direct elevation: negative, unlike the ball itself.
    assert np.nanmax(lab.elevation_deg[only]) < 0


# --- invariants on the demo tank ---------------------------------------------------------


@pytest.fixture(scope="module")
def demo():
    with Simulator(demo_scene_dict()) as sim:
        img = sim.render(speckle=False, labels=True)
        plain = sim.render(speckle=False)
    return img, plain


def test_labels_are_opt_in_and_leave_the_image_unchanged(demo):
    img, plain = demo
    assert plain.labels is None
    assert img.labels is not None
    for name in ("total", "object", "ground", "double", "triple"):
        np.testing.assert_allclose(img.components[name], plain.components[name], rtol=1e-5, atol=1e-9,
                                   err_msg=name)


def test_instance_maps_are_set_exactly_where_each_component_has_energy(demo):
    img, _ = demo
    lab = img.labels
    assert set(lab.instance) == {"object", "ground", "single", "double", "triple", "total"}
    for name, inst in lab.instance.items():
        assert inst.dtype == np.int32 and inst.shape == img.polar.shape
        np.testing.assert_array_equal(inst >= 0, img.components[name] > 0, err_msg=name)
    n_obj = 4
    assert set(np.unique(lab.instance["object"])) == {-1, 0, 1, 2, 3}
    assert set(np.unique(lab.instance["ground"])) == {-1, n_obj}
    # The single's id is the object's or the ground's, whichever component is stronger.
    single = lab.instance["single"]
    stronger = np.where(img.components["ground"] > img.components["object"], lab.instance["ground"],
                        lab.instance["object"])
    assert np.mean(single == stronger) > 0.999
    # Where one order alone makes the total, the total's id is that order's.
    for name, others in (("single", ("double", "triple")), ("double", ("single", "triple")),
                         ("triple", ("single", "double"))):
        alone = (img.components[name] > 0) & np.all([img.components[o] == 0 for o in others], axis=0)
        assert alone.any(), name
        np.testing.assert_array_equal(lab.instance["total"][alone], lab.instance[name][alone], err_msg=name)


def test_points_land_in_the_cells_they_claim(demo):
    img, _ = demo
    lab = img.labels
    n = len(lab.points_world)
    assert lab.points_world.dtype == np.float32 and lab.points_world.shape == (n, 3)
    assert lab.points_object.dtype == np.int32 and lab.points_cell.shape == (n, 2)
    direct = lab.points_component <= 1  # object, ground: the point is where the echo comes from
    assert direct.sum() > 1000
    v = (lab.points_world[direct].astype(np.float64) - img.pose.translation) @ img.pose.rotation
    r = np.linalg.norm(v, axis=1)
    az = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    b = np.floor((r - img.sonar.range_min_m) / img.sonar.range_resolution_m)
    beam = img.sonar.grid.beam_edges_deg
    j = np.searchsorted(-beam, -az) - 1  # edges descend
    cells = lab.points_cell[direct]
    # float32 points: a bin boundary may round either way.
    assert np.abs(cells[:, 0] - b).max() <= 1 and np.mean(cells[:, 0] == b) > 0.99
    assert np.abs(cells[:, 1] - j).max() <= 1 and np.mean(cells[:, 1] == j) > 0.99
    # Object points are the objects': the ground points lie on the floor.
    ground = lab.points_object[direct] == 4
    assert np.abs(lab.points_world[direct][ground, 2]).max() < 1e-5
    assert (lab.points_world[direct][~ground, 2] > 0.0).all()
    # Points in a cell's total match the cell's id most of the time (the id dominates).
    c = lab.points_cell
    assert np.mean(lab.instance["total"][c[:, 0], c[:, 1]] >= 0) > 0.99


def test_boxes_enclose_the_cells_each_id_dominates(demo):
    img, _ = demo
    lab = img.labels
    inst = lab.instance["total"]
    for k in range(len(lab.ids)):
        rows, cols = np.nonzero(inst == k)
        assert lab.boxes_polar[k].tolist() == [rows.min(), cols.min(), rows.max(), cols.max()]


def test_npz_holds_the_contract_names(demo, tmp_path):
    img, _ = demo
    path = tmp_path / "frame.npz"
    img.save_npz(path)
    with np.load(path, allow_pickle=False) as f:
        assert f["instance"].dtype == np.int32 and f["instance"].shape == f["polar"].shape
        np.testing.assert_array_equal(f["instance"], img.labels.instance["total"])
        assert f["elevation_deg"].dtype == np.float32 and f["elevation_deg"].shape == f["polar"].shape
        np.testing.assert_array_equal(np.isnan(f["elevation_deg"]), img.labels.instance["total"] < 0)
        assert f["points_world"].dtype == np.float32 and f["points_world"].shape[1] == 3
        assert f["points_object"].dtype == np.int32 and len(f["points_object"]) == len(f["points_world"])
        assert list(f["label_ids"]) == list(img.labels.ids)
        np.testing.assert_array_equal(f["instance_double"], img.labels.instance["double"])
        for key in ("range_m", "azimuth_deg", "elevation_min_deg", "elevation_max_deg", "points_cell",
                    "points_component", "boxes_polar"):
            assert key in f.files


def test_fan_labels_take_the_polar_cell_of_each_pixel(demo):
    img, _ = demo
    fan = img.fan_labels()
    ref = img.fan(interpolation="nearest")
    assert fan.instance.shape == ref.image.shape and fan.instance.dtype == np.int32
    assert (fan.instance[~fan.mask] == -1).all() and np.isnan(fan.elevation_deg[~fan.mask]).all()
    # Each pixel's polar cell, through the same scan conversion (cell index as a float32 image).
    n_r, n_b = img.polar.shape
    cell = FanMapper.from_grid(img.sonar.grid, None, "nearest")(
        np.arange(n_r * n_b, dtype=np.float32).reshape(n_r, n_b))
    k = cell.image[fan.mask].astype(np.int64)
    np.testing.assert_array_equal(fan.instance[fan.mask], img.labels.instance["total"].reshape(-1)[k])
    np.testing.assert_array_equal(fan.elevation_deg[fan.mask], img.labels.elevation_deg.reshape(-1)[k])
    for k_id in range(len(img.labels.ids)):
        rows, cols = np.nonzero(fan.instance == k_id)
        assert fan.boxes[k_id].tolist() == [rows.min(), cols.min(), rows.max(), cols.max()]


def test_an_image_without_labels_says_so():
    with Simulator(scene([{"name": "ball", "primitive": "sphere", "radius_m": 0.3,
                           "pose": {"position_m": [3.0, 0.0, 0.0]}}])) as sim:
        img = sim.render(speckle=False)
    assert img.labels is None and "instance" not in img.arrays()
    with pytest.raises(ValueError, match="labels=True"):
        img.fan_labels()


def test_paper_method_keeps_its_image_and_gains_the_labels():
    doc = demo_scene_dict()
    doc["render"]["method"] = "paper"
    doc["render"]["elevation_samples"] = 60
    with Simulator(doc) as sim:
        img = sim.render(speckle=False, labels=True)
        plain = sim.render(speckle=False)
    np.testing.assert_array_equal(img.components["total"], plain.components["total"])
    assert set(np.unique(img.labels.instance["total"])) == {-1, 0, 1, 2, 3, 4}


# --- the compiled kernels against their NumPy twins --------------------------------------


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
@pytest.mark.parametrize("bounces", [None, [1, 3]])
def test_compiled_labels_equal_the_numpy_twins(bounces):
    """Frame after frame with one compiled simulator (its label scratch kept between frames)
    against the NumPy twin's dense stacks; with every order in the total, and with the double
    bounce left out of it (its map formed, its energy not in the total's)."""
    doc = demo_scene_dict()
    doc["render"]["elevation_samples"] = 120
    if bounces is not None:
        doc["render"]["bounces"] = bounces
    poses = [None, {"position_m": [0.2, 0.3, 1.1], "rpy_deg": [4.0, 24.0, -9.0]}, None]
    with Simulator(doc, kernels="compiled") as a:
        frames = [a.render(pose=p, speckle=False, labels=True).labels for p in poses]
    for la, pose in zip(frames, poses):
        with Simulator(doc, kernels="numpy") as b:
            lb = b.render(pose=pose, speckle=False, labels=True).labels
        _assert_labels_agree(la, lb)
    if bounces is not None:  # the total leaves the double bounce out: its cells alone are not labelled
        only_double = (frames[0].instance["double"] >= 0) & (frames[0].instance["single"] < 0) & (
            frames[0].instance["triple"] < 0)
        assert only_double.any() and (frames[0].instance["total"][only_double] == -1).all()


def _assert_labels_agree(la, lb):
    assert la.ids == lb.ids
    for name in la.instance:
        # float32 against float64 sums: a near tie may go either way.
        assert np.mean(la.instance[name] == lb.instance[name]) > 0.999, name
        np.testing.assert_array_equal(la.instance[name] >= 0, lb.instance[name] >= 0, err_msg=name)
    for name in ("elevation_deg", "elevation_min_deg", "elevation_max_deg"):
        np.testing.assert_allclose(getattr(la, name), getattr(lb, name), atol=1e-4, err_msg=name)
    def key(lab):  # one row per path: sort by where it lands, then by the point
        return np.lexsort((*lab.points_world.T, lab.points_component, lab.points_cell[:, 1], lab.points_cell[:, 0]))

    order, order_b = key(la), key(lb)
    assert len(order) == len(order_b)
    np.testing.assert_allclose(la.points_world[order], lb.points_world[order_b], atol=1e-5)
    np.testing.assert_array_equal(la.points_cell[order], lb.points_cell[order_b])


def test_dominant_is_the_argmax_with_ties_to_the_lower_id():
    rng = np.random.default_rng(3)
    e = rng.uniform(0.0, 1.0, (6, 40, 30)).astype(np.float32)
    e[rng.uniform(size=e.shape) < 0.6] = 0.0
    e[:, :3] = 0.0  # rows with nothing
    e[2, 5, 5] = e[4, 5, 5] = 2.0  # a tie goes to the lower id
    best, top = dominant(e, 7)
    assert best[5, 5] == 9 and (best[:3] == -1).all()
    np.testing.assert_array_equal(best, np.where(e.max(axis=0) > 0, e.argmax(axis=0) + 7, -1))
    np.testing.assert_array_equal(top, e.max(axis=0))


# A hand-made frame for the two routes of frame_labels (compiled.frame_truth and its NumPy twin
# ground_truth._frame_truth): range bins of 0.5 m from 1 m, 3 beams, a fan of 6 columns of 4
# elevation rows. Surfaces: plane 0, objects 1 and 2 (label ids: objects 0, 1, the plane 2).
N_EL, N_COLS = 4, 6
GRID = (1.0, 0.5, 8, 3)  # range_min_m, range_resolution_m, n_range_bins, n_beams
ELEVATION_DEG = np.array([-3.0, -1.0, 1.0, 3.0])


def _leg(gen, sid, rng):
    n = N_EL * N_COLS
    points = rng.normal(0.0, 1.0, (n, 3))
    normals = np.tile(np.float32([0.0, 0.0, 1.0]), (n, 1))
    return Leg(gen, np.full(n, 2.0), np.asarray(sid, np.int32), points, normals, np.ones(n), np.ones(n),
               np.zeros(n, np.int32))


def _set(gen, rows):
    """rows: (ray, range_m, energy, beam, label) per path, rays ascending."""
    ray, dist, energy, beam, label = zip(*rows)
    return PathSet(gen, -1, np.array(ray, np.intp), np.array(dist), np.array(energy), np.array(beam, np.int32),
                   np.array(label, np.int8))


def _hand_made_frame():
    rng = np.random.default_rng(7)
    # Surface of each ray of each generation (rays of one path set are distinct).
    legs = [_leg(0, rng.integers(0, 3, N_EL * N_COLS), rng), _leg(1, rng.integers(0, 3, N_EL * N_COLS), rng)]
    legs[0].sid[:12] = [1, 2, 2, 1, 2, 1, 1, 0, 1, 0, 2, 0]
    legs[1].sid[:4] = [2, 1, 1, 2]
    # Bin b holds [1 + 0.5 b, 1.5 + 0.5 b): 2.1 m is bin 2, 2.6 m bin 3, ...; no range splat.
    order1 = _set(0, [
        (0, 2.1, 1.0, 0, 0), (1, 2.2, 1.0, 0, 0),  # (2, 0): ids 0 and 1 tie -> 0
        (2, 2.6, 0.5, 1, 0), (3, 2.7, 0.25, 1, 0), (4, 2.8, 0.25, 1, 0),  # (3, 1): 1 has 0.75, 0 has 0.25
        (5, 3.1, 0.0, 2, 0),  # (4, 2): only a path without energy: nothing, but its elevation counts
        (6, 3.6, 0.0, 0, 0), (7, 3.7, 0.5, 0, 1),  # (5, 0): a zero-energy object, then the plane
        (8, 4.1, 0.5, 1, 0), (9, 4.2, 0.5, 1, 1),  # (6, 1): an object and the plane tie -> object
        (10, 9.0, 1.0, 2, 0),  # beyond the window: no cell, no point
        (11, 1.2, 0.25, 2, 1),  # (0, 2): the plane alone
    ])
    order2 = _set(1, [(0, 2.3, 4.0, 0, 2), (1, 4.3, 0.125, 1, 2)])  # (2, 0): id 1 with 4; (6, 1): id 0
    order3 = _set(1, [(2, 2.9, 1.0, 1, 3), (3, 2.9, 0.0, 1, 3)])  # (3, 1): id 0 with 1, id 1 with 0
    return [order1, order2, order3], legs


def _both(sets, legs, bounces=(1, 2, 3), components=True, spread=False, n_obj=2, n_pl=1, grid=GRID,
          elevation=ELEVATION_DEG):
    spec = LabelSpec(surface_ids(np.arange(n_obj + n_pl), n_pl, n_obj), elevation, n_obj, 3, bounces, components)
    args = (sets, legs, n_obj + n_pl, spec, grid, spread)
    return compiled.frame_truth(*args), _frame_truth(*args)


def _assert_routes_agree(kernel, twin, exact=True):
    names = ("orders", "objects", "planes", "total", "elevation", "boxes")
    for name, a, b in zip(names, kernel[:6], twin[:6]):
        if a is None or b is None:
            assert a is None and b is None, name
        elif name == "elevation":
            assert a.dtype == b.dtype == np.float32
            np.testing.assert_array_equal(a[1:], b[1:], err_msg="least and greatest elevation")
            # The mean: float64 sums in either route, in another order in the twin.
            np.testing.assert_allclose(a[0], b[0], rtol=0 if exact else 1e-6, atol=0, err_msg="mean elevation")
        else:
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
    for a, b in zip(kernel[6], twin[6]):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b, err_msg="points")


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
@pytest.mark.parametrize("bounces", [(1, 2, 3), (1, 2)])
@pytest.mark.parametrize("components", [True, False])
def test_compiled_label_maps_equal_the_numpy_twin_on_hand_made_paths(bounces, components):
    """Energies that float32 and float64 sum exactly: the two routes agree bit for bit, and
    with the values worked out by hand (mixed cells, ties, zero-energy paths, three orders)."""
    sets, legs = _hand_made_frame()
    kernel, twin = _both(sets, legs, bounces=bounces, components=components)
    # A path without energy lands nowhere: (4, 2) has only such a path (no elevation at all),
    # (5, 0) one at 1 degree beside the plane's at 3 (the extremes are the plane's alone).
    assert np.isnan(kernel[4][:, 4, 2]).all() and np.isnan(twin[4][:, 4, 2]).all()
    assert kernel[4][1, 5, 0] == twin[4][1, 5, 0] == 3.0 and kernel[4][2, 5, 0] == twin[4][2, 5, 0] == 3.0
    _assert_routes_agree(kernel, twin)
    orders, objects, planes, total, elevation, boxes, points = kernel
    expect = {(2, 0): 1, (3, 1): 1 if bounces == (1, 2) else 0, (4, 2): -1, (5, 0): 2, (6, 1): 0,
              (0, 2): 2}
    # (6, 1): the object (0.5, id 0) ties the plane in order 1 and order 2 adds 0.125 to id 0.
    for cell, want in expect.items():
        assert total[cell] == want, cell
    assert (total >= 0).sum() == 5
    if components:
        single, double, triple = orders
        assert single[2, 0] == 0 and single[3, 1] == 1 and single[5, 0] == 2 and single[6, 1] == 0
        assert single[4, 2] == -1 and single[0, 2] == 2
        assert objects[5, 0] == -1 and planes[5, 0] == 2  # a zero-energy object never wins
        assert objects[6, 1] == 0 and planes[6, 1] == 2
        assert double[2, 0] == 1 and double[6, 1] == 0 and (double >= 0).sum() == 2
        assert triple[3, 1] == 0 and (triple >= 0).sum() == 1
    else:
        assert len(orders) == 0 and objects is None
    assert np.isnan(elevation[0, 4, 2])  # one path without energy: no mean (0 / 0)
    # (2, 0): rays 0 and 1 (-3 and -1 degrees, energy 1 each) and ray 0 of generation 1 (-3, 4).
    assert elevation[0, 2, 0] == np.float32((-3.0 - 1.0 - 12.0) / 6.0)
    assert elevation[1, 2, 0] == -3.0 and elevation[2, 2, 0] == -1.0
    np.testing.assert_array_equal(boxes[2], [0, 0, 5, 2])  # the plane: (0, 2) and (5, 0)
    assert len(points[0]) == 9 + 2 + 1  # every path with energy inside the image


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_label_maps_equal_the_numpy_twin_on_random_paths(seed):
    """Many ids, spread range cells: float32 against float64 sums, so the means agree to
    round-off and the ids exactly (no near tie in these draws)."""
    rng = np.random.default_rng(100 + seed)
    n_obj, n_pl, n_el, n_cols = 5, 2, 8, 30
    n = n_el * n_cols
    legs = []
    for gen in range(2):
        step = rng.uniform(0.01, 0.05, n)
        points = np.cumsum(step)[:, None] * np.array([1.0, 0.2, 0.1]) + rng.normal(0, 1e-4, (n, 3))
        normals = np.tile(np.float32([0.0, 0.0, 1.0]), (n, 1))
        sid = np.repeat(rng.integers(0, n_obj + n_pl, n // 4), 4).astype(np.int32)
        legs.append(Leg(gen, np.full(n, 2.0), sid, points, normals, np.ones(n), np.ones(n), np.zeros(n, np.int32)))
    sets = []
    for gen, label in ((0, 0), (0, 1), (1, 2), (1, 3), (1, 2)):
        ray = np.flatnonzero(rng.random(n) < 0.6).astype(np.intp)
        m = len(ray)
        energy = rng.uniform(0.1, 1.0, m)  # (paths without energy: the hand-made test)
        lab = np.full(m, label, np.int8)
        if label < 2:
            lab[:] = np.where(legs[gen].sid[ray] >= n_pl, 0, 1)
        sets.append(PathSet(gen, -1, ray, rng.uniform(0.5, 3.4, m), energy, rng.integers(0, 6, m).astype(np.int32),
                            lab))
    grid = (0.6, 0.05, 60, 6)
    el = np.linspace(-10.0, 10.0, n_el)
    kernel, twin = _both(sets, legs, spread=True, n_obj=n_obj, n_pl=n_pl, grid=grid, elevation=el)
    _assert_routes_agree(kernel, twin, exact=False)
    assert (kernel[3] >= 0).sum() > 100 and set(kernel[3].ravel()) >= set(range(n_obj + n_pl))


@pytest.mark.skipif(not compiled.AVAILABLE, reason="compiled kernels not built")
def test_compiled_label_maps_on_an_empty_window_and_no_paths():
    sets, legs = _hand_made_frame()
    for grid, s in (((1.0, 0.5, 0, 3), sets), (GRID, [])):
        kernel, twin = _both(s, legs, grid=grid)
        _assert_routes_agree(kernel, twin)
        assert (kernel[3] == -1).all() and np.isnan(kernel[4]).all()


@pytest.mark.parametrize("double_beam", ["paper", "split"])
def test_a_tank_with_walls_and_a_surface_labels_every_component(double_beam):
    """Five planes, order 3: ids name the planes after the objects; each component's map is set
    where its image has energy, in both kernels."""
    from sonarsim.config.examples import tank_scene_dict

    doc = tank_scene_dict()
    doc["render"].update(elevation_samples=40, double_beam=double_beam)
    maps = {}
    for kernels in ("compiled", "numpy") if compiled.AVAILABLE else ("numpy",):
        with Simulator(doc, kernels=kernels) as sim:
            img = sim.render(speckle=False, labels=True)
        lab = img.labels
        assert lab.ids == ("buoy", "post", "block", "ground", "surface", "far_wall", "left_wall", "right_wall")
        for name, inst in lab.instance.items():
            np.testing.assert_array_equal(inst >= 0, img.components[name] > 0, err_msg=f"{kernels} {name}")
        assert set(np.unique(lab.instance["ground"])) <= {-1, 3, 4, 5, 6, 7}
        assert (lab.instance["triple"] >= 0).any()
        maps[kernels] = lab
    if len(maps) == 2:
        for name in maps["compiled"].instance:
            assert np.mean(maps["compiled"].instance[name] == maps["numpy"].instance[name]) > 0.999, name


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_total_only_labels_equal_the_full_labels_less_the_components(kernels):
    from sonarsim.errors import ConfigError

    if kernels == "compiled" and not compiled.AVAILABLE:
        pytest.skip("compiled kernels not built")
    doc = demo_scene_dict()
    doc["render"]["elevation_samples"] = 120
    with Simulator(doc, kernels=kernels) as sim:
        full = sim.render(speckle=False, labels=True).labels
        total = sim.render(speckle=False, labels="total").labels
        with pytest.raises(ConfigError, match="labels"):
            sim.render(labels="some")
    assert list(total.instance) == ["total"]
    np.testing.assert_array_equal(total.instance["total"], full.instance["total"])
    for name in ("elevation_deg", "elevation_min_deg", "elevation_max_deg", "points_world", "points_cell",
                 "points_object", "points_component", "boxes_polar"):
        np.testing.assert_array_equal(getattr(total, name), getattr(full, name), err_msg=name)
    assert "instance" in total.arrays() and "instance_double" not in total.arrays()


def test_labels_of_a_paper_frame_leave_its_components_as_they_are():
    """``method: paper`` (Algorithm 2) forms no path sets; the labels form the general engine's
    for themselves. The frame's signature images stay the ground's, as without labels (they
    were taken from the labels' paths with no chain table: an AttributeError)."""
    import sonarsim

    doc = demo_scene_dict()
    doc.setdefault("render", {})["method"] = "paper"
    doc.pop("planes", None)
    plain = sonarsim.render(doc, speckle=False)
    labelled = sonarsim.render(doc, speckle=False, labels=True)
    arrays = labelled.arrays()
    assert {"instance", "elevation_deg", "points_world", "boxes_polar"} <= set(arrays)
    assert arrays["instance"].max() > 0  # the demo's objects are labelled
    assert sorted(labelled.components.keys()) == sorted(plain.components.keys())
    for name in plain.components.keys():
        np.testing.assert_array_equal(labelled.components[name], plain.components[name])
