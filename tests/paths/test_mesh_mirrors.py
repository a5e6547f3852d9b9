"""Mesh mirrors: objects with a specular reflectance reflect as the planes do (issue 25).

Checked against what needs no implementation of them: the same wall given as a plane and as a
large box, a scene and its mirror image, the law of reflection at every mirror vertex of every
path, image sources written out for a sphere in front of a mirroring box, Fermat's principle on
a pipe lying on the floor; and against the brute-force reference (every chain of planes and
facets tried, each transmit leg traced), image by image and path by path.
"""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.errors import ConfigError
from sonarsim.paths.engine import SAME, SonarView, parse_path_name, path_corners
from sonarsim.reference.brute_force import render_reference
from tests.paths.test_multipath_geometry import assert_sphere_paths_as_predicted, sphere_scene
from tests.reference.test_brute_force import SONAR, _engine_paths, compare, tank_dict


def mirror_tank(max_order: int = 3, double_beam: str = "paper", line_of_sight: bool = False) -> dict:
    """The reference tank (floor, surface, three walls; a ball, a block, a post) with the block
    a mirror (R 0.7) and a thin mirror plate (R 0.9) standing at an angle near the right wall."""
    doc = tank_dict(max_order, double_beam, line_of_sight)
    doc["objects"][1]["specular"] = 0.7
    doc["objects"].append({"name": "plate", "primitive": "box", "size_m": [0.05, 1.0, 0.8],
                           "pose": {"position_m": [3.2, -0.9, 0.8], "rpy_deg": [0, 0, -30]},
                           "albedo": 0.3, "specular": 0.9})
    return doc


# --- the same wall, a plane or a box --------------------------------------------------------

def wall_scene(as_box: bool, max_order: int, double_beam: str = "paper", line_of_sight: bool = False) -> dict:
    """A floor, a far wall at x = 4 (a plane, or the front face of a box 0.5 m thick and 40 m
    wide) with the same albedo and R, a ball and a block; the sonar pitched down, yawed."""
    objects = [
        {"name": "ball", "primitive": "sphere", "radius_m": 0.15, "pose": {"position_m": [2.5, 0.3, 0.6]},
         "albedo": 0.7},
        {"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
         "pose": {"position_m": [2.9, -0.4, 0.2], "rpy_deg": [0, 0, 30]}},
    ]
    planes = []
    wall = {"albedo": 0.4, "specular": 0.8}
    if as_box:
        objects.append({"name": "wall", "primitive": "box", "size_m": [0.5, 40.0, 10.0],
                        "pose": {"position_m": [4.25, 0.0, 2.0]}, **wall})
    else:
        planes.append({"name": "wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], **wall})
    return {
        "sonar": {**SONAR, "elevation_fov_deg": 30.0, "pose": {"position_m": [0.0, 0.1, 1.1], "rpy_deg": [0, 12, 6]}},
        "render": {"elevation_samples": 64, "max_order": max_order, "double_beam": double_beam,
                   "double_line_of_sight": line_of_sight},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": planes, "objects": objects,
    }


@pytest.mark.parametrize("max_order,double_beam,los", [(1, "paper", False), (2, "paper", False), (3, "paper", False),
                                                       (4, "paper", False), (3, "separate", False),
                                                       (3, "separate", True)])
def test_a_wall_given_as_a_box_renders_as_the_wall_given_as_a_plane(max_order, double_beam, los):
    """(With ``double_line_of_sight`` the box is an object the transmit legs are cast against:
    a leg's reflection point on it must not count as blocking the leg.)"""
    plane = sonarsim.Simulator(wall_scene(False, max_order, double_beam, los)).render().components
    box = sonarsim.Simulator(wall_scene(True, max_order, double_beam, los)).render().components
    names = ["single", "total"] + [n for n in ("double", "triple", "order4") if n in plane]
    for name in names:
        a, b = plane[name].astype(float), box[name].astype(float)
        assert a.sum() > 0, name
        assert np.abs(a - b).sum() <= 0.005 * a.sum(), (name, np.abs(a - b).sum() / a.sum())
    if max_order > 1:  # the box's paths are named by the object, as the plane's by the plane
        assert any("wall" in parse_path_name(n)[0] + parse_path_name(n)[2] for n in box.signatures)


def test_an_object_without_specular_reflectance_keeps_todays_image():
    doc = wall_scene(False, 3)
    zero = wall_scene(False, 3)
    for o in zero["objects"]:
        o["specular"] = 0.0
    a, b = sonarsim.Simulator(doc), sonarsim.Simulator(zero)
    assert b.facets is None and b.path_kernels == a.path_kernels
    np.testing.assert_array_equal(a.render().polar, b.render().polar)


# --- against the reference ------------------------------------------------------------------

@pytest.mark.parametrize("max_order,double_beam,los", [(2, "paper", False), (3, "paper", False),
                                                       (4, "paper", False), (3, "split", False),
                                                       (3, "separate", False), (3, "separate", True)])
def test_the_engine_equals_the_reference_with_mesh_mirrors(max_order, double_beam, los):
    worst = compare(mirror_tank(max_order, double_beam, los), "compiled")
    # Paths via each mirror object were formed, on the receive leg (and at order 3 the transmit).
    for mirror in ("block", "plate"):
        assert any(mirror in k.split("]")[-1] for k in worst), mirror
        assert max_order < 3 or any(mirror in k.split("[")[0] for k in worst), mirror


def test_the_engine_holds_the_reference_paths_one_by_one_with_mesh_mirrors():
    sim = sonarsim.Simulator(mirror_tank(3, "separate"))
    got = _engine_paths(sim)
    ref = render_reference(sim).paths
    n_planes = len(sim.planes)
    matched = via_facets = 0
    for k in range(len(ref.energy)):
        if ref.energy[k] <= 0:
            continue
        key = (int(ref.ray[k]), tuple(ref.tx_chain[k]), tuple(ref.rx_chain[k]))
        assert key in got, f"the engine lacks the path {key}"
        sid, distance, energy, beam = got.pop(key)
        assert sid == ref.scatterer[k] and beam == ref.beam[k], key
        assert abs(distance - ref.range_m[k]) <= 1e-5, (key, distance, ref.range_m[k])
        assert abs(energy - ref.energy[k]) <= 1e-4 * ref.energy[k], (key, energy, ref.energy[k])
        matched += 1
        via_facets += any(p >= n_planes for p in key[1] + key[2])
    assert all(v[2] == 0 for v in got.values())
    assert matched > 1000 and via_facets > 200


def _law_of_reflection(corners: np.ndarray, chain, normal_of, tol: float) -> int:
    """Check every reflection of one leg (corners from the sonar out); returns their count."""
    seg = np.diff(corners, axis=0)
    unit = seg / np.linalg.norm(seg, axis=1)[:, None]
    for j, p in enumerate(chain):
        n = normal_of(p)
        u, v = unit[j], unit[j + 1]
        # Angle of incidence = angle of reflection, in the plane of incidence.
        np.testing.assert_allclose(v, u - 2.0 * (u @ n) * n, atol=tol)
    return len(chain)


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_every_path_obeys_the_law_of_reflection_at_every_mesh_vertex(kernels):
    sim = sonarsim.Simulator(mirror_tank(4, "separate"), kernels=kernels)
    assert sim.path_kernels == kernels
    n_planes = len(sim.planes)
    facets = sim.facets

    def normal_of(p):
        return sim.planes.normal[p] if p < n_planes else facets.mirror_normal[p - n_planes]

    # The reference's paths (float64 throughout).
    ref = render_reference(sim, keep_legs=True).paths
    on_facets = 0
    for k in range(len(ref.energy)):
        for chain, corners in ((ref.tx_chain[k], ref.tx_vertices[k]), (ref.rx_chain[k], ref.rx_vertices[k])):
            for j, p in enumerate(chain):
                if p >= n_planes:  # on its triangle
                    q = corners[j + 1]
                    # (a receive leg's points are the caster's, float32)
                    assert abs(q @ facets.mirror_normal[p - n_planes] - facets.mirror_offset[p - n_planes]) < 1e-6
                    assert facets.contains_mirror(p - n_planes, q[None])[0]
                    on_facets += 1
            _law_of_reflection(corners, chain, normal_of, 1e-9)
    assert on_facets > 500

    # The engine's own paths (its first generation's points are float32, as the caster's).
    sonar, pose = sim.scene.sonar, sim.scene.sonar_pose
    active, _, reach = sim.frame_reach(sonar, pose)
    view = SonarView.of(sonar, pose, sim.ray_fan(sonar))
    _, legs, sets, table, _, _ = sim._render_paths(sonar, view, reach, active, 4)
    on_facets = 0
    for s in (sets() if callable(sets) else sets):
        tx, rx = path_corners(s, legs, table, view, active)
        rx_chain = legs[s.gen].chain[s.ray]
        for i in range(len(s.ray)):
            c_rx = table.chains[int(rx_chain[i])]
            c_tx = c_rx if s.tx == SAME else table.chains[s.tx]
            for chain, corners in ((c_tx, tx[i]), (c_rx, rx[i])):
                on_facets += _law_of_reflection(corners, chain, normal_of, 2e-5) and any(p >= n_planes for p in chain)
    assert on_facets > 500


# --- by hand ----------------------------------------------------------------------------------

@pytest.mark.parametrize("range_splat", [False, True])
def test_a_sphere_in_front_of_a_mirroring_box_has_its_ghosts_where_image_sources_put_them(range_splat):
    """The sphere test of the planes (test_multipath_geometry), its wall now the front face of a
    box named ``wall`` that only mirrors (albedo 0): every path of the sphere up to order 3
    lands at the range and in the beam the image sources give, and nowhere else."""
    doc = sphere_scene(range_splat)
    wall = doc["planes"].pop()
    doc["objects"].append({"name": "wall", "primitive": "box", "size_m": [1.0, 30.0, 6.0],
                           "pose": {"position_m": [4.5, 0.0, 1.0]}, "albedo": 0.0, "specular": wall["specular"]})
    comps = sonarsim.Simulator(doc).render().components
    images = {n: comps[n].astype(float) for n in comps.signatures}
    predicted = assert_sphere_paths_as_predicted(images)
    assert sum("wall" in n for n in predicted) >= 6


def _mirror_y(doc: dict) -> dict:
    """The scene mirrored across the plane y = 0 (sonar and objects; roll and yaw negated)."""
    import copy
    out = copy.deepcopy(doc)
    for item in [out["sonar"]] + out["objects"]:
        pose = item.setdefault("pose", {})
        p = pose.get("position_m", [0, 0, 0])
        pose["position_m"] = [p[0], -p[1], p[2]]
        r = pose.get("rpy_deg", [0, 0, 0])
        pose["rpy_deg"] = [-r[0], r[1], -r[2]]
    for plane in out.get("planes", []):
        plane["point_m"] = [plane["point_m"][0], -plane["point_m"][1], plane["point_m"][2]]
        plane["normal"] = [plane["normal"][0], -plane["normal"][1], plane["normal"][2]]
    return out


def test_a_mirrored_scene_gives_the_mirrored_image():
    doc = wall_scene(True, 3)
    doc["objects"] = [o for o in doc["objects"] if o["name"] != "ball"]  # an icosphere is not symmetric
    doc["objects"][0]["specular"] = 0.6
    doc["objects"].append({"name": "post", "primitive": "cylinder", "radius_m": 0.1, "height_m": 0.8,
                           "pose": {"position_m": [3.0, 0.5, 0.4]}, "specular": 0.9, "albedo": 0.2})
    a = sonarsim.Simulator(doc).render().components
    b = sonarsim.Simulator(_mirror_y(doc)).render().components
    assert set(a.signatures) == set(b.signatures)
    assert a["triple"].sum() > 0 and any("post" in n for n in a.signatures)
    for name in list(a):
        x, y = a[name].astype(float), b[name].astype(float)[:, ::-1]
        assert np.abs(x - y).sum() <= 1e-4 * x.sum() + 1e-12, (name, np.abs(x - y).sum() / max(x.sum(), 1e-300))


PIPE_C = np.array([2.4, 0.0, 0.2])  # axis along y
PIPE_R = 0.2


def pipe_scene() -> dict:
    return {
        "sonar": {**SONAR, "elevation_fov_deg": 30.0, "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0, 20, 0]}},
        "render": {"elevation_samples": 96, "max_order": 2, "double_beam": "separate", "range_splat": False},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "objects": [{"name": "pipe", "primitive": "cylinder", "radius_m": PIPE_R, "height_m": 1.6,
                     "pose": {"position_m": PIPE_C.tolist(), "rpy_deg": [90, 0, 0]}, "albedo": 0.3, "specular": 0.9}],
    }


def _fermat_length(o: np.ndarray, a: np.ndarray, start: np.ndarray) -> tuple[float, np.ndarray]:
    """The shortest O -> Q -> A over Q on the (smooth) pipe near ``start``: the specular path."""
    from scipy.optimize import minimize

    def q_of(x):
        return np.array([PIPE_C[0] + PIPE_R * np.cos(x[0]), x[1], PIPE_C[2] + PIPE_R * np.sin(x[0])])

    def length(x):
        q = q_of(x)
        return np.linalg.norm(q - o) + np.linalg.norm(a - q)

    rel = start - PIPE_C
    x0 = np.array([np.arctan2(rel[2], rel[0]), start[1]])
    res = minimize(length, x0, method="Nelder-Mead", options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 4000})
    return float(res.fun), q_of(res.x)


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_a_mirroring_pipe_on_the_floor_shows_the_floor_where_fermat_puts_it(kernels):
    """The floor seen in a pipe lying on it (O-pipe-[ground]-O and O-[ground]-pipe-O): each
    path's range is that of the specular path over the smooth cylinder through its floor point
    (the mesh's facets sag 0.2 mm at most), its reflection point on the pipe's lit side."""
    sim = sonarsim.Simulator(pipe_scene(), kernels=kernels)
    sonar, pose = sim.scene.sonar, sim.scene.sonar_pose
    active, _, reach = sim.frame_reach(sonar, pose)
    view = SonarView.of(sonar, pose, sim.ray_fan(sonar))
    _, legs, sets, table, _, _ = sim._render_paths(sonar, view, reach, active, 2)
    o = np.asarray(pose.translation, float)
    checked = {"tx": 0, "rx": 0}
    rng = np.random.default_rng(0)
    for s in (sets() if callable(sets) else sets):
        leg = legs[s.gen]
        on_floor = leg.sid[s.ray] == 0
        if s.tx == SAME:
            continue
        tx_chain = table.chains[s.tx]
        rx_chain = [table.chains[int(c)] for c in leg.chain[s.ray]]
        tx, rx = path_corners(s, legs, table, view, active)
        for i in rng.permutation(np.flatnonzero(on_floor))[:60]:
            legs_ = {"tx": (tx_chain, tx[i]), "rx": (rx_chain[i], rx[i])}
            via = [k for k, (c, _) in legs_.items() if len(c) == 1 and table.name_of(c[0]) == "pipe"]
            direct = [k for k, (c, _) in legs_.items() if len(c) == 0]
            if len(via) != 1 or len(direct) != 1:
                continue
            a = rx[i][-1]
            corners = legs_[via[0]][1]
            length, q = _fermat_length(o, a, corners[1])
            expected = 0.5 * (length + np.linalg.norm(a - o))
            assert abs(s.distance[i] - expected) < 1e-3, (s.distance[i], expected)
            assert np.linalg.norm(q - corners[1]) < 0.02  # on the same part of the pipe
            n = (q - PIPE_C) * np.array([1, 0, 1]) / PIPE_R
            assert (o - q) @ n > 0 and (a - q) @ n > 0  # the lit side, facing both
            checked[via[0]] += 1
    assert checked["tx"] >= 30 and checked["rx"] >= 30, checked


# --- smooth normals, and the scene file --------------------------------------------------------

def test_smooth_normals_on_a_cylinder_are_its_radial_normals():
    doc = pipe_scene()
    doc["objects"][0]["normals"] = "smooth"
    sim = sonarsim.Simulator(doc)
    facets = sim.facets
    rng = np.random.default_rng(1)
    f = rng.integers(0, len(facets), 400)
    uv = rng.uniform(0, 0.5, (400, 2))
    n = facets.reflecting_normal(f, uv)
    a, b, c = facets.corners[f, 0], facets.corners[f, 1], facets.corners[f, 2]
    p = (1 - uv[:, :1] - uv[:, 1:]) * a + uv[:, :1] * b + uv[:, 1:] * c
    radial = (p - PIPE_C) * np.array([1, 0, 1])
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    side = np.abs(facets.normal[f, 1]) < 0.5  # the curved side (the caps keep their flat normal)
    assert side.sum() > 100 and (~side).sum() > 10
    np.testing.assert_allclose(np.abs(np.sum(n[side] * radial[side], axis=1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(n[~side], facets.normal[f[~side]], atol=1e-12)
    # A smooth pipe renders the floor in it as the flat one does (paper's pairs: from the leg
    # via the pipe, traced either way; measured 0.2454 against 0.2382).
    doc["render"]["double_beam"] = "paper"
    flat_doc = pipe_scene()
    flat_doc["render"]["double_beam"] = "paper"
    smooth = sonarsim.render(doc).components
    flat = sonarsim.render(flat_doc).components
    name = "O-[ground]-pipe-O"
    assert float(smooth[name].sum()) == pytest.approx(float(flat[name].sum()), rel=0.05)
    # In 'separate' each member is formed: the one whose transmit leg meets the smooth pipe
    # (no image source) from its partner's traced leg, recorded in the beam it arrives in.
    separate = sim.render().components
    assert float(separate["O-pipe-[ground]-O"].sum()) == pytest.approx(float(separate[name].sum()), rel=1e-6)
    assert not np.array_equal(np.asarray(separate["O-pipe-[ground]-O"]), np.asarray(separate[name]))


@pytest.mark.parametrize("edit,key", [({"specular": 1.5}, "specular"), ({"specular": -0.1}, "specular"),
                                      ({"normals": "curved"}, "normals"),
                                      ({"name": "my-pipe", "specular": 0.5}, "name")])
def test_bad_mirror_settings_are_refused_naming_the_key(edit, key):
    doc = pipe_scene()
    doc["objects"][0].update(edit)
    with pytest.raises(ConfigError) as err:
        sonarsim.Simulator(doc)
    assert f"objects[0].{key}" in str(err.value)


def test_mirror_settings_survive_the_scene_file():
    doc = pipe_scene()
    doc["objects"][0]["normals"] = "smooth"
    scene = sonarsim.load_scene(doc)
    again = sonarsim.load_scene(scene.to_dict())
    assert again.objects[0].specular == 0.9 and again.objects[0].normals == "smooth"


# --- specular returns (render.glints) ------------------------------------------------------

GLINT_SONAR = {"n_beams": 16, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 20.0, "range_min_m": 0.5,
               "range_max_m": 5.0, "n_range_bins": 500}


def square_wall(as_box: bool, tvg: bool, distance_m: float = 3.0, plate_m: float = 20.0) -> dict:
    """A mirror wall (R 0.8, no diffuse part) ``distance_m`` ahead of a level sonar, met square
    on: a plane, or the front face of a box ``plate_m`` wide and high (a plate)."""
    wall = {"albedo": 0.0, "specular": 0.8}
    doc = {"sonar": {**GLINT_SONAR, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 0, 0]}},
           "render": {"elevation_samples": 256, "azimuth_samples": 16, "max_order": 1, "glints": True, "tvg": tvg}}
    if as_box:
        doc["objects"] = [{"name": "wall", "primitive": "box", "size_m": [0.2, plate_m, plate_m],
                           "pose": {"position_m": [distance_m + 0.1, 0, 1]}, **wall}]
    else:
        doc["planes"] = [{"name": "wall", "point_m": [distance_m, 0, 0], "normal": [-1, 0, 0], **wall}]
    return doc


@pytest.mark.parametrize("as_box,tvg,distance_m,plate_m", [(False, True, 3.0, 20.0), (False, False, 3.0, 20.0),
                                                           (True, True, 3.0, 20.0), (True, True, 1.5, 0.6),
                                                           (True, False, 2.2, 0.6)])
def test_a_mirror_met_square_on_returns_what_its_image_source_sends(as_box, tvg, distance_m, plate_m):
    """A plate square on in the near field (its Fresnel zones far smaller than it) is a mirror:
    the sonar's image in it is a source 2 D away, and the sonar equation gives the echo level
    ``SL + 10 log10 R - 20 log10(2 D)``. In the image's units (``sigma / r**2`` per radian of
    beam width, see :func:`sonarsim.sensor.acoustics.echo_level_offset_db`) that is
    ``R / (2 D)**2`` summed over the beams it lands in times their width in radians (times
    ``D**2`` with TVG), at range D, in the beams either side of the axis. (Issue 37: it was
    ``pi`` times that, the disc's area taken as ``a**2``.)"""
    from sonarsim.sensor.acoustics import echo_level_offset_db

    im = sonarsim.render(square_wall(as_box, tvg, distance_m, plate_m))
    total = im.components["total"].astype(float)
    d, r = distance_m, 0.8
    width = np.radians(GLINT_SONAR["azimuth_fov_deg"] / GLINT_SONAR["n_beams"])
    x = total.sum() * width / (d * d if tvg else 1.0)  # sigma / r**2 of the range-compensated image
    assert x == pytest.approx(r / (2 * d) ** 2, rel=0.05)
    source_level = 200.0
    level = float(echo_level_offset_db(np.array([d]), source_level, 0.0)[0]) + 10 * np.log10(x * d * d)
    assert level == pytest.approx(source_level + 10 * np.log10(r) - 20 * np.log10(2 * d), abs=0.2)
    rows, cols = np.flatnonzero(total.sum(axis=1)), np.flatnonzero(total.sum(axis=0))
    assert np.all(np.abs(im.range_m[rows] - d) < 0.006) and set(cols) <= {7, 8}  # (bins of 9 mm)
    assert set(im.components.signatures) == {"O-wall-O"}
    assert parse_path_name("O-wall-O") == (["wall"], "", [])


C_CORNER = np.array([3.0, 0.0, 1.0])


def corner_reflector(direction, r=0.9) -> tuple[dict, np.ndarray]:
    """Three mirror plates (0.5 m, R 0.9, no diffuse part) in the planes x, y, z through
    C_CORNER, open towards -x, -y, -z; the sonar 2.5 m from C along ``direction``, aimed at C."""
    size, t = 0.5, 0.02
    plates = [("back", [t, size, size], [t / 2, -size / 2, -size / 2]),
              ("side", [size, t, size], [-size / 2, t / 2, -size / 2]),
              ("top", [size, size, t], [-size / 2, -size / 2, t / 2])]
    objects = [{"name": n, "primitive": "box", "size_m": s, "pose": {"position_m": (C_CORNER + o).tolist()},
                "albedo": 0.0, "specular": r} for n, s, o in plates]
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    o = C_CORNER + 2.5 * u
    look = C_CORNER - o
    pose = {"position_m": o.tolist(), "rpy_deg": [0.0, -np.degrees(np.arcsin(look[2] / 2.5)),
                                                 np.degrees(np.arctan2(look[1], look[0]))]}
    doc = {"sonar": {**GLINT_SONAR, "n_beams": 15, "azimuth_fov_deg": 30.0, "pose": pose},
           "render": {"elevation_samples": 256, "azimuth_samples": 16, "max_order": 3, "glints": True},
           "objects": objects}
    return doc, o


@pytest.mark.parametrize("direction", [(-1, -1, -1), (-1, -0.3, -0.3), (-0.3, -1, -0.5), (-0.5, -0.4, -1),
                                       (-1, -0.5, -0.7)])
def test_a_corner_reflector_returns_at_its_range_from_every_direction_in_its_quadrant(direction):
    """Three reflections invert the sonar through the corner C: its image is a source at 2 |OC|
    whatever the direction in the quadrant, so the return lies at the corner's range, in the
    beam of C, with R**3 / 4 per radian of beam width (TVG: R**3 / (2 |OC|)**2 times |OC|**2),
    in all six orders of the plates."""
    doc, o = corner_reflector(direction)
    im = sonarsim.render(doc)
    total = im.components["total"].astype(float)
    width = np.radians(2.0)
    r = 0.9
    assert total.sum() * width == pytest.approx(r ** 3 / 4, rel=0.05)
    rng = np.linalg.norm(C_CORNER - o)
    rows, cols = np.flatnonzero(total.sum(axis=1)), np.flatnonzero(total.sum(axis=0))
    assert np.all(np.abs(im.range_m[rows] - rng) < 0.006) and cols.tolist() == [7]  # (bins of 9 mm)
    triples = [n for n in im.components.signatures if len(parse_path_name(n)[0]) == 3]
    assert len(triples) == 6 and {frozenset(parse_path_name(n)[0]) for n in triples} == {
        frozenset({"back", "side", "top"})}


@pytest.mark.parametrize("direction", [(1, 1, 1), (-1, 0.3, -0.3), (-1, -0.3, 0.4)])
def test_a_corner_reflector_returns_nothing_from_outside_its_quadrant(direction):
    doc, _ = corner_reflector(direction)
    assert not sonarsim.render(doc).components["total"].any()


@pytest.mark.parametrize("case", ["corner", "wall_box", "mirror_tank"])
def test_the_specular_returns_on_the_compiled_kernels_equal_the_numpy_twins(case):
    """The returns are traced in the compiled blocks (one generation more, its rays checked
    against the sonar's disc) as ``engine.returns_to_sonar`` traces them: the same images,
    signatures and labels."""
    if case == "corner":
        doc, _ = corner_reflector((-1, -0.5, -0.7))
    elif case == "wall_box":
        doc = square_wall(True, True)
    else:
        doc = mirror_tank(3, "separate")
        doc["render"].update(glints=True, glint_radius_m=0.2)
    a = sonarsim.Simulator(doc, kernels="compiled").render(speckle=False, labels=True)
    b = sonarsim.Simulator(doc, kernels="numpy").render(speckle=False, labels=True)
    assert a.components.signatures == b.components.signatures
    assert any(n.count("[") == 0 for n in b.components.signatures)  # returns were formed
    for key in b.components:
        x, y = a.components[key].astype(float), b.components[key].astype(float)
        assert np.abs(x - y).sum() <= 1e-6 * np.abs(y).sum() + 1e-12, key
    for key, value in b.labels.arrays().items():
        if key.startswith("points"):
            continue  # (the same points, listed in the order each engine formed them)
        np.testing.assert_array_equal(a.labels.arrays()[key], value, err_msg=key)


def test_bad_glint_settings_are_refused_naming_the_key():
    for edit, key in (({"glints": "yes"}, "render.glints"), ({"glint_radius_m": 0.0}, "render.glint_radius_m"),
                      ({"glint_radius_m": 2.0}, "render.glint_radius_m")):
        doc = square_wall(False, True)
        doc["render"].update(edit)
        with pytest.raises(ConfigError) as err:
            sonarsim.Simulator(doc)
        assert key in str(err.value)


def test_labels_cover_the_paths_via_mesh_mirrors_and_the_specular_returns():
    """The demo's tank with its steel plate, and the specular returns on: every component's
    instance map is set exactly where it has energy; the cells that only the plate's ghosts
    reach are labelled with what scattered there (the post among them, not the plate alone),
    with the elevation the ghost arrives at, and points in them."""
    from sonarsim.config.examples import tank_scene_dict

    doc = tank_scene_dict(mirror=True)
    doc["render"].update(elevation_samples=40, glints=True)
    img = sonarsim.Simulator(doc).render(speckle=False, labels=True)
    lab = img.labels
    assert lab.ids[:4] == ("buoy", "post", "block", "steel_plate")
    for name, inst in lab.instance.items():
        np.testing.assert_array_equal(inst >= 0, img.components[name] > 0, err_msg=name)
    comp = img.components
    plate = sum(np.asarray(comp[n], float) for n in comp.signatures
                if "steel_plate" in parse_path_name(n)[0] + parse_path_name(n)[2])
    others = np.asarray(comp["total"], float) - plate
    ghost_only = (plate > 0) & (others <= 1e-6 * plate)
    assert ghost_only.sum() > 50
    ids = set(np.unique(lab.instance["total"][ghost_only]).tolist())
    assert lab.ids.index("post") in ids and ids - {lab.ids.index("steel_plate")}
    el = lab.elevation_deg[ghost_only]
    assert np.all(np.isfinite(el)) and np.all(np.abs(el) <= 10.0 + 1e-6)
    cells = {tuple(c) for c in lab.points_cell.tolist()}
    assert sum((r, b) in cells for r, b in zip(*np.nonzero(ghost_only))) > 20
    # Specular returns are labelled too (the plate met square on, a wall's corner...).
    glints = [n for n in comp.signatures if parse_path_name(n)[1] == ""]
    assert glints
    assert all(np.all(lab.instance["total"][np.asarray(comp[n]) > 0] >= 0) for n in glints)


def test_a_fan_of_many_faces_keeps_its_apex_flat_and_a_huge_mirror_is_refused_before_building():
    """Smooth normals pair each corner with the faces around its vertex: a fan's apex (more than
    MAX_SMOOTH_DEGREE faces) keeps its face's own normal instead of 4e10 pairs; and the mirror
    tables count in the scene's memory estimate, refused before anything is built."""
    import trimesh

    from sonarsim.core.memory import memory_budget
    from sonarsim.core.triangles import TriangleMesh
    from sonarsim.paths.facets import MAX_SMOOTH_DEGREE, FacetSet
    from sonarsim.scene import cost

    cone = trimesh.creation.cone(radius=1.0, height=1.0, sections=400)
    mesh = TriangleMesh(np.asarray(cone.vertices, float), np.asarray(cone.faces, np.int32))
    facets = FacetSet.of([mesh], ["cone"], [0.5], ["smooth"])
    apex = np.argmax(mesh.vertices[:, 2])
    at_apex = mesh.faces == apex
    assert at_apex.sum() > MAX_SMOOTH_DEGREE
    np.testing.assert_allclose(facets.corner_normals[at_apex], np.repeat(facets.normal, 3, axis=0).reshape(-1, 3, 3)[at_apex])
    assert cost.BYTES_PER_SMOOTH_TRIANGLE >= 3 * MAX_SMOOTH_DEGREE * 48
    n = int(memory_budget() / cost.BYTES_PER_TRIANGLE * 0.8)  # fits as a scatterer, not as a smooth mirror
    from dataclasses import replace

    base = sonarsim.load_scene(pipe_scene())
    big = replace(base, objects=(replace(base.objects[0], normals="smooth"),))
    plain = replace(base, objects=(replace(base.objects[0], specular=0.0),))
    import unittest.mock as mock

    with mock.patch.object(cost, "object_triangles", return_value=n):
        cost.check_scene_cost(plain)
        with pytest.raises(ConfigError) as err:
            cost.check_scene_cost(big)
    assert "objects" in str(err.value)
