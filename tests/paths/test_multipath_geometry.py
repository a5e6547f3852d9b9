"""Multipath geometry checked without any implementation of the path model.

* A small sphere in a tank with a floor, a water surface and a wall: every path up to order 3
  is predicted here by image sources written out for these three planes, and its echo must
  land at ``(|transmit leg| + |receive leg|) / 2`` in the beam of its arrival direction, and
  nowhere else.
* A scene turned upside down (the floor's plane above, the surface's below, the sonar and the
  objects mirrored) gives the same image.
* The traps: objects resting on a wall or hanging from the surface, a sonar on the wrong side
  of a plane, a plane with R = 0, an object crossing a wall.
* Every path of the reference obeys the law of reflection (the invariant Sionna RT checks).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import sonarsim
from sonarsim.paths.engine import parse_path_name
from sonarsim.reference.brute_force import render_reference

# --- the small sphere --------------------------------------------------------------------

O = np.array([0.0, 0.0, 1.0])  # the sonar, looking along +x, level
SPHERE_C = np.array([3.0, 0.33, 0.9])
SPHERE_R = 0.04
RANGE_MIN, RANGE_MAX, N_BINS = 0.5, 6.0, 300
DR = (RANGE_MAX - RANGE_MIN) / N_BINS
N_BEAMS, AZ_FOV, EL_FOV = 15, 45.0, 80.0  # 3-degree beams, beam 7 centred on the axis


def sphere_scene(range_splat: bool) -> dict:
    return {
        "sonar": {"n_beams": N_BEAMS, "azimuth_fov_deg": AZ_FOV, "elevation_fov_deg": EL_FOV,
                  "range_min_m": RANGE_MIN, "range_max_m": RANGE_MAX, "n_range_bins": N_BINS,
                  "pose": {"position_m": O.tolist(), "rpy_deg": [0.0, 0.0, 0.0]}},
        # Ray columns 3/7 deg apart, rows 0.5 deg: every image of the sphere is hit.
        "render": {"elevation_samples": 160, "azimuth_samples": 7, "max_order": 3, "double_beam": "separate",
                   "range_splat": range_splat},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": [
            {"name": "surface", "point_m": [0, 0, 2.0], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9},
            {"name": "wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], "albedo": 0.6, "specular": 0.5},
        ],
        "objects": [{"name": "ball", "primitive": "sphere", "radius_m": SPHERE_R,
                     "pose": {"position_m": SPHERE_C.tolist()}, "albedo": 1.0}],
    }


# Mirror images across the three planes, written out.
MIRROR = {
    "ground": lambda p: np.array([p[0], p[1], -p[2]]),           # z = 0
    "surface": lambda p: np.array([p[0], p[1], 4.0 - p[2]]),     # z = 2
    "wall": lambda p: np.array([8.0 - p[0], p[1], p[2]]),        # x = 4
}


def in_water(p, tol=1e-9):
    return -tol <= p[2] <= 2.0 + tol and p[0] <= 4.0 + tol


def crossing(a, b, plane):
    """Where the segment a -> b crosses a plane, or None."""
    axis, level = {"ground": (2, 0.0), "surface": (2, 2.0), "wall": (0, 4.0)}[plane]
    if b[axis] == a[axis]:
        return None
    s = (level - a[axis]) / (b[axis] - a[axis])
    return a + s * (b - a) if 0.0 < s < 1.0 else None


def image_leg(chain):
    """The sphere centre seen via ``chain`` (planes from the sonar out): (image point, valid).

    The image is the centre mirrored across the chain's last plane first; the leg aims at it
    from O, and is valid when each reflection point lies on its plane inside the water.
    """
    image = SPHERE_C
    for plane in reversed(chain):
        image = MIRROR[plane](image)
    pos, target = O, image
    for plane in chain:
        q = crossing(pos, target, plane)
        if q is None or not in_water(q):
            return image, False
        pos, target = q, MIRROR[plane](target)
    return image, True


def angles(v):
    """Azimuth and elevation (deg) of a direction in the sonar frame (here the world frame)."""
    return np.degrees(np.arctan2(v[1], v[0])), np.degrees(np.arcsin(v[2] / np.linalg.norm(v)))


def beam_of(azimuth_deg):
    edges = AZ_FOV / 2.0 - np.arange(N_BEAMS + 1) * AZ_FOV / N_BEAMS
    inside = np.flatnonzero((azimuth_deg <= edges[:-1]) & (azimuth_deg > edges[1:]))
    return int(inside[0]) if len(inside) else -1


def predicted_paths():
    """Signature name -> (range, beam) of every sphere path up to order 3 (double_beam: separate)."""
    names = ("ground", "surface", "wall")
    chains = [()] + [(p,) for p in names] + [c for c in itertools.product(names, repeat=2) if c[0] != c[1]]
    out = {}
    for tx, rx in itertools.product(chains, repeat=2):
        if len(tx) + len(rx) + 1 > 3:
            continue
        img_rx, ok_rx = image_leg(rx)
        img_tx, ok_tx = image_leg(tx)
        d_rx, d_tx = np.linalg.norm(img_rx - O), np.linalg.norm(img_tx - O)
        az_rx, el_rx = angles(img_rx - O)
        az_tx, el_tx = angles(img_tx - O)
        margin_rx, margin_tx = np.degrees(SPHERE_R / d_rx), np.degrees(SPHERE_R / d_tx)
        # The scene is built so that no leg grazes an aperture edge, a beam edge or the window.
        for az, el, m in ((az_rx, el_rx, margin_rx), (az_tx, el_tx, margin_tx)):
            assert abs(abs(el) - EL_FOV / 2) > m and abs(abs(az) - AZ_FOV / 2) > m
        seen = ok_rx and abs(az_rx) < AZ_FOV / 2 and abs(el_rx) < EL_FOV / 2
        lit = ok_tx and abs(az_tx) < AZ_FOV / 2 and abs(el_tx) < EL_FOV / 2 and RANGE_MIN < d_tx < RANGE_MAX
        if tx == rx:
            lit = ok_rx  # the receive leg reversed
        rng = 0.5 * (d_rx + d_tx)
        if seen and lit and rng < RANGE_MAX:
            edges = AZ_FOV / 2.0 - np.arange(N_BEAMS + 1) * AZ_FOV / N_BEAMS
            assert np.abs(edges - az_rx).min() > margin_rx, "the sphere's image straddles a beam edge"
            name = "-".join(["O", *tx, "[objects]", *reversed(rx), "O"])
            out[name] = (rng, beam_of(az_rx))
    return out


def test_the_predicted_sphere_paths_cover_every_plane_and_order():
    paths = predicted_paths()
    orders = {n.count("-") - 1 for n in paths}
    assert orders == {1, 2, 3}
    for plane in ("ground", "surface", "wall"):
        assert any(plane in n for n in paths), plane
    assert len({b for _, b in paths.values()}) >= 2  # the wall moves the arrival beam


@pytest.mark.parametrize("renderer, range_splat", [("compiled", False), ("compiled", True), ("numpy", False),
                                                   ("numpy", True), ("reference", False)])
def test_sphere_echoes_land_where_the_image_sources_put_them(range_splat, renderer):
    doc = sphere_scene(range_splat)
    if renderer == "reference":  # Algorithm 1 only
        images = render_reference(sonarsim.Simulator(doc)).signatures
    else:
        comps = sonarsim.Simulator(doc, kernels=renderer).render().components
        images = {n: comps[n].astype(float) for n in comps.signatures}
    assert_sphere_paths_as_predicted(images)


def assert_sphere_paths_as_predicted(images: dict) -> dict:
    """Every sphere path of :func:`predicted_paths`, and no other, in ``images`` (signature
    name -> image); returns the prediction."""
    predicted = predicted_paths()
    got = {n for n, img in images.items() if "[objects]" in n and img.sum() > 0}
    assert got == set(predicted)
    centres = RANGE_MIN + (np.arange(N_BINS) + 0.5) * DR
    for name, (rng, beam) in predicted.items():
        img = images[name]
        assert (img >= 0).all()
        # Only the predicted beam, only the sphere's own extent (+- its radius, a bin of
        # Algorithm 1, a bin of splatting) around the predicted range.
        cols = np.flatnonzero(img.sum(axis=0))
        assert cols.tolist() == [beam], (name, cols, beam)
        rows = np.flatnonzero(img.sum(axis=1))
        lo, hi = rng - SPHERE_R - 2 * DR, rng + SPHERE_R + 2 * DR
        assert centres[rows].min() >= lo and centres[rows].max() <= hi, (name, centres[rows], rng)
        # The echo comes from the near side of the sphere: within a radius short of the centre's range.
        mean = (img.sum(axis=1) * centres).sum() / img.sum()
        assert rng - SPHERE_R - DR <= mean <= rng + DR, (name, mean, rng)
    return predicted


# --- upside down --------------------------------------------------------------------------

def _tank(flip: bool, range_splat: bool) -> dict:
    """A tank whose floor (``bottom``) is at z = 0 and surface (``top``) at z = 2, or the same
    tank mirrored across z = 1 (``flip``): the floor's plane above, the surface's below."""
    z = (lambda v: 2.0 - v) if flip else (lambda v: v)
    s = -1.0 if flip else 1.0

    def pose(p, rpy):
        return {"position_m": [p[0], p[1], z(p[2])], "rpy_deg": [s * rpy[0], s * rpy[1], rpy[2]]}

    return {
        "sonar": {"n_beams": 16, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 30.0, "range_min_m": 0.3,
                  "range_max_m": 5.0, "n_range_bins": 250, "pose": pose((0.0, 0.1, 1.2), (6.0, 5.0, 4.0))},
        "render": {"elevation_samples": 48, "max_order": 4, "range_splat": range_splat, "double_beam": "separate"},
        "planes": [
            {"name": "bottom", "point_m": [0, 0, z(0.0)], "normal": [0, 0, s], "albedo": 0.5, "specular": 0.6},
            {"name": "top", "point_m": [0, 0, z(2.0)], "normal": [0, 0, -s], "albedo": 0.0, "specular": 0.9},
            {"name": "wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], "albedo": 0.6, "specular": 0.5},
        ],
        "objects": [
            {"name": "ball", "primitive": "sphere", "radius_m": 0.2, "pose": pose((2.5, 0.4, 1.2), (0, 0, 0))},
            {"name": "block", "primitive": "box", "size_m": [0.4, 0.3, 0.4],
             "pose": pose((2.8, -0.3, 0.2), (0.0, 0.0, 30.0))},
            {"name": "float", "primitive": "cylinder", "radius_m": 0.1, "height_m": 0.6,
             "pose": pose((3.2, 0.5, 1.7), (0.0, 0.0, 0.0))},
        ],
    }


@pytest.mark.parametrize("range_splat", [False, True])
def test_a_scene_turned_upside_down_gives_the_same_image(range_splat):
    a = sonarsim.Simulator(_tank(False, range_splat)).render().components
    b = sonarsim.Simulator(_tank(True, range_splat)).render().components
    assert set(a.signatures) == set(b.signatures)
    assert a["order4"].sum() > 0
    for plane in ("top", "bottom", "wall"):  # paths via every plane, on both legs
        assert any(plane in parse_path_name(n)[0] for n in a.signatures), plane
        assert any(plane in parse_path_name(n)[2] for n in a.signatures), plane
    for name in list(a):
        x, y = a[name].astype(float), b[name].astype(float)
        assert np.abs(x - y).sum() <= 1e-4 * x.sum() + 1e-12, (name, np.abs(x - y).sum() / max(x.sum(), 1e-300))


# --- traps --------------------------------------------------------------------------------

def _trap_tank(objects, **plane_edits) -> dict:
    doc = {
        "sonar": {"n_beams": 16, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 30.0, "range_min_m": 0.3,
                  "range_max_m": 5.0, "n_range_bins": 250,
                  "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 0.0, 0.0]}},
        "render": {"elevation_samples": 64, "max_order": 3, "range_splat": False, "double_beam": "separate"},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": [
            {"name": "surface", "point_m": [0, 0, 2.0], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9},
            {"name": "wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], "albedo": 0.6, "specular": 0.5},
        ],
        "objects": objects,
    }
    for name, edit in plane_edits.items():
        for plane in doc["planes"]:
            if plane["name"] == name:
                plane.update(edit)
    return doc


def _nearest_distance(mesh, origin) -> float:
    """A lower bound of the distance from ``origin`` to a mesh's surface (dense samples less their spacing)."""
    tri = mesh.vertices[mesh.faces]  # (f, 3, 3)
    u, v = np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    pts = tri[:, 0, None] + u[None, :, None] * (tri[:, 1] - tri[:, 0])[:, None] + v[None, :, None] * (
        tri[:, 2] - tri[:, 0])[:, None]
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max()
    return float(np.linalg.norm(pts.reshape(-1, 3) - origin, axis=1).min() - edge / 10.0)


TOUCHING = {
    "on the wall": {"name": "crate", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                    "pose": {"position_m": [3.8, 0.2, 0.9]}},
    "from the surface": {"name": "buoy", "primitive": "cylinder", "radius_m": 0.12, "height_m": 0.8,
                         "pose": {"position_m": [2.6, -0.2, 1.6]}},
    "on the floor": {"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.3],
                     "pose": {"position_m": [2.8, 0.2, 0.15], "rpy_deg": [0, 0, 25]}},
}


@pytest.mark.parametrize("where", list(TOUCHING))
def test_an_object_touching_a_plane_gives_no_echo_nearer_than_itself(where):
    sim = sonarsim.Simulator(_trap_tank([TOUCHING[where]]))
    img = sim.render().components
    nearest = _nearest_distance(sim.meshes[0], np.array([0.0, 0.0, 1.0]))
    centres = sim.scene.sonar.range_m
    dr = sim.scene.sonar.range_resolution_m
    assert img["object"].sum() > 0
    for name in list(img):
        assert (img[name] >= 0).all(), name
        if "[objects]" in name or name == "object":
            rows = np.flatnonzero(img[name].sum(axis=1))
            assert not len(rows) or centres[rows].min() >= nearest - dr, (name, centres[rows].min(), nearest)


@pytest.mark.filterwarnings("ignore:the sonar is on the dry side")  # a sonar below a plane, on purpose
def test_a_sonar_on_the_wrong_side_of_a_plane_sees_neither_it_nor_paths_through_it():
    obj = [TOUCHING["on the floor"]]
    doc = _trap_tank(obj)
    doc["sonar"]["pose"] = {"position_m": [0.0, 0.0, 1.7], "rpy_deg": [0.0, 20.0, 0.0]}
    without = sonarsim.Simulator(doc).render().components
    # A shelf at z = 1.5 whose water is below it: the sonar at z = 1.7 is on its dry side.
    doc["planes"].append({"name": "shelf", "point_m": [0, 0, 1.5], "normal": [0, 0, -1], "albedo": 0.7,
                          "specular": 0.8})
    with_shelf = sonarsim.Simulator(doc).render().components
    assert not any("shelf" in n for n in with_shelf.signatures)
    assert set(with_shelf.signatures) == set(without.signatures)
    for name in list(without):
        np.testing.assert_array_equal(with_shelf[name], without[name], err_msg=name)
    assert without["double"].sum() > 0


def test_a_plane_with_no_specular_reflectance_makes_no_path_through_it():
    doc = _trap_tank([TOUCHING["on the floor"], {"name": "ball", "primitive": "sphere", "radius_m": 0.15,
                                                  "pose": {"position_m": [3.5, -0.3, 1.0]}}],
                     wall={"specular": 0.0})
    img = sonarsim.Simulator(doc).render().components
    ref = render_reference(sonarsim.Simulator(doc))
    for names in (img.signatures, ref.signatures):
        assert "O-[wall]-O" in names
        for name in names:
            tx, _, rx = parse_path_name(name)
            assert "wall" not in tx and "wall" not in rx, name
        assert any("surface" in n for n in names) and any("-ground-" in n for n in names)
    doc["planes"][1]["specular"] = 0.5  # the control: with R > 0 the wall makes paths
    assert any("wall-" in n for n in sonarsim.Simulator(doc).render().components.signatures)


def test_an_object_crossing_a_wall_is_clipped_to_the_water_side():
    # A box across the wall x = 4 gives the image of the half inside the water.
    across = {"name": "crate", "primitive": "box", "size_m": [0.4, 0.4, 0.4], "pose": {"position_m": [4.0, 0.2, 0.9]}}
    half = {"name": "crate", "primitive": "box", "size_m": [0.2, 0.4, 0.4], "pose": {"position_m": [3.9, 0.2, 0.9]}}
    a = sonarsim.Simulator(_trap_tank([across])).render().components
    b = sonarsim.Simulator(_trap_tank([half])).render().components
    assert a["object"].sum() > 0 and a["double"].sum() > 0
    assert set(a.signatures) == set(b.signatures)
    for name in list(a):
        x, y = a[name].astype(float), b[name].astype(float)
        assert np.abs(x - y).sum() <= 1e-4 * y.sum() + 1e-12, name
    sim = sonarsim.Simulator(_trap_tank([across]))
    assert sim.meshes[0].vertices[sim.meshes[0].faces][..., 0].max() <= 4.0 + 1e-9


# --- the law of reflection ----------------------------------------------------------------

def test_every_path_obeys_the_law_of_reflection():
    from tests.reference.test_brute_force import turned_dict

    doc = turned_dict(4, "separate")
    sim = sonarsim.Simulator(doc)
    ref = render_reference(sim, keep_legs=True)
    planes = sim.scene.reflecting_planes
    normal = np.array([p.normal for p in planes])
    offset = np.array([p.offset_m for p in planes])
    paths = ref.paths
    assert (paths.order == 4).any()
    n_reflections = 0
    for k in range(len(paths.energy)):
        for chain, corners, length in ((paths.tx_chain[k], paths.tx_vertices[k], paths.tx_length_m[k]),
                                       (paths.rx_chain[k], paths.rx_vertices[k], paths.rx_length_m[k])):
            assert len(corners) == len(chain) + 2
            seg = np.diff(corners, axis=0)
            span = np.linalg.norm(seg, axis=1)
            assert abs(span.sum() - length) < 1e-9
            unit = seg / span[:, None]
            for j, p in enumerate(chain):
                q, n = corners[j + 1], normal[p]
                assert abs(q @ n - offset[p]) < 1e-9  # on its plane
                assert np.all(normal @ q - offset >= -1e-9)  # inside the water
                u, v = unit[j], unit[j + 1]
                # Angle of incidence = angle of reflection, in the plane of incidence.
                np.testing.assert_allclose(v, u - 2.0 * (u @ n) * n, atol=1e-9)
                assert u @ n < 0 < v @ n
                n_reflections += 1
        # Both legs end on the same scatterer.
        assert np.linalg.norm(paths.tx_vertices[k][-1] - paths.rx_vertices[k][-1]) < 1e-6
        np.testing.assert_allclose(paths.tx_vertices[k][0], doc["sonar"]["pose"]["position_m"])
    assert n_reflections > 1000
