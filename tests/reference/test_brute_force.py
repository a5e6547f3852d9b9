"""The fast path engine against the slow reference of :mod:`sonarsim.reference.brute_force`.

The reference traces every receive leg with its own loop, tries every chain of mirror planes
as a transmit leg (image sources, then a traced check) and forms the images with Algorithm 1.
The fast path (compiled kernels and their NumPy twins) must give the same images, order by
order and signature by signature, on tanks with several planes, any pose, every
``double_beam`` mode and ``double_line_of_sight``.

Both form each path into the bin of its range (``range_splat: false``), so the images differ
only where float32 round-off (the caster reports hits in float32) moves a path across a bin
boundary: the L1 difference of every image must stay below :data:`L1_TOLERANCE` of its energy
(measured: about 1e-7 on these scenes).

The fast path tries only the transmit chains some receive ray followed this frame (documented
culling); each comparison first checks that the scene does not depend on it.
"""

from __future__ import annotations


import numpy as np
import pytest

import sonarsim
from sonarsim.reference.brute_force import all_chains, mirror_point, render_reference

# L1 difference allowed, relative to the image's energy: a few paths across a bin boundary.
L1_TOLERANCE = 1e-4

SONAR = {"n_beams": 16, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 20.0, "range_min_m": 0.3,
         "range_max_m": 5.0, "n_range_bins": 250}


def tank_dict(max_order: int = 3, double_beam: str = "paper", line_of_sight: bool = False,
              rpy_deg=(0.0, 10.0, 0.0), position_m=(0.0, 0.2, 1.2)) -> dict:
    """A tank 2 m deep with a floor, a water surface and three walls, and three objects.

    The sonar is pitched down; a sphere floats in mid-water, a box and a short cylinder stand
    on the floor (their bases lie in the floor plane).
    """
    wall = {"albedo": 0.6, "specular": 0.5}
    return {
        "sonar": {**SONAR, "pose": {"position_m": list(position_m), "rpy_deg": list(rpy_deg)}},
        "render": {"elevation_samples": 48, "max_order": max_order, "range_splat": False,
                   "double_beam": double_beam, "double_line_of_sight": line_of_sight},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
        "planes": [
            {"name": "surface", "point_m": [0, 0, 2.0], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9},
            {"name": "far_wall", "point_m": [4.0, 0, 0], "normal": [-1, 0, 0], **wall},
            {"name": "left_wall", "point_m": [0, 1.5, 0], "normal": [0, -1, 0], **wall},
            {"name": "right_wall", "point_m": [0, -1.5, 0], "normal": [0, 1, 0], **wall},
        ],
        "objects": [
            {"name": "ball", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [2.5, 0.4, 1.3]},
             "albedo": 0.7},
            {"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
             "pose": {"position_m": [2.8, -0.3, 0.2], "rpy_deg": [0, 0, 30]}, "albedo": 0.8},
            {"name": "post", "primitive": "cylinder", "radius_m": 0.08, "height_m": 0.6,
             "pose": {"position_m": [3.3, 0.6, 0.3]}, "albedo": 0.6},
        ],
    }


def channel_dict(max_order: int = 3, double_beam: str = "paper") -> dict:
    """Floor and water surface only (shallow water, 1.3 m), a box on the floor and a buoy near the surface."""
    doc = tank_dict(max_order, double_beam, rpy_deg=(0.0, 2.0, 0.0), position_m=(0.0, 0.0, 0.8))
    doc["sonar"].update(elevation_fov_deg=40.0, range_max_m=8.0, n_range_bins=320)
    doc["planes"] = [{"name": "surface", "point_m": [0, 0, 1.3], "normal": [0, 0, -1], "albedo": 0.0,
                      "specular": 0.9}]
    doc["objects"] = [
        {"name": "block", "primitive": "box", "size_m": [0.5, 0.5, 0.3],
         "pose": {"position_m": [3.5, 0.3, 0.15], "rpy_deg": [0, 0, 20]}},
        {"name": "buoy", "primitive": "sphere", "radius_m": 0.12, "pose": {"position_m": [2.0, -0.3, 1.1]},
         "albedo": 0.6},
    ]
    return doc


def turned_dict(max_order: int = 3, double_beam: str = "paper") -> dict:
    """The tank seen from a rolled, yawed, pitched sonar off the tank's axis."""
    return tank_dict(max_order, double_beam, rpy_deg=(15.0, 12.0, 25.0), position_m=(0.4, -0.6, 0.9))


def ground_dict(max_order: int = 3, double_beam: str = "paper") -> dict:
    """The paper's case, the ground alone, from a rolled sonar (the compiled path uses its ground kernels at order 3)."""
    doc = tank_dict(max_order, double_beam, position_m=(0.0, 0.0, 1.0), rpy_deg=(12.0, 20.0, 0.0))
    doc["planes"] = []
    return doc


SCENES = {"tank": tank_dict, "channel": channel_dict, "turned": turned_dict, "ground": ground_dict}


def compare(doc: dict, kernels: str) -> dict:
    """Render ``doc`` with the fast path and the reference; assert equal images; return the worst L1s."""
    sim = sonarsim.Simulator(doc, kernels=kernels)
    fast = sim.render().components
    ref = render_reference(sim)
    # The scene must not depend on the fast path's culling of transmit chains.
    paths = ref.paths
    unfollowed = [k for k in range(len(paths.energy))
                  if not paths.same[k] and paths.energy[k] > 0 and paths.tx_chain[k] not in ref.rx_chains]
    assert not unfollowed, f"{len(unfollowed)} paths use transmit chains no receive ray followed"
    worst = {}
    for name, image in ref.components.items():
        got = fast[name].astype(float)
        energy = image.sum()
        l1 = np.abs(got - image).sum()
        assert l1 <= L1_TOLERANCE * energy + 1e-12, (name, l1 / max(energy, 1e-300))
        worst[name] = l1 / max(energy, 1e-300)
    assert (ref.stack >= 0).all()
    names = set(ref.signatures) | set(fast.signatures)
    for name in names:
        image = ref.signatures.get(name)
        got = fast[name].astype(float) if name in fast.signatures else np.zeros_like(ref.components["total"])
        image = np.zeros_like(got) if image is None else image
        energy = image.sum()
        l1 = np.abs(got - image).sum()
        assert l1 <= L1_TOLERANCE * energy + 1e-12 * max(ref.components["total"].sum(), 1.0), (
            name, l1, energy)
        worst[name] = l1 / max(energy, 1e-300)
    # The signatures add up to the orders.
    np.testing.assert_allclose(sum(ref.signatures.values()), ref.components["total"], rtol=1e-12, atol=1e-15)
    return worst


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("max_order", [1, 2, 3, 4])
@pytest.mark.parametrize("scene", list(SCENES))
def test_fast_path_equals_the_reference(scene, max_order, kernels):
    worst = compare(SCENES[scene](max_order), kernels)
    if max_order > 1 and scene != "ground":
        # Multipath was formed (the comparison is not empty).
        assert any(k.count("-") > 2 for k in worst)


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("double_beam", ["coherent", "paper", "split", "separate"])
@pytest.mark.parametrize("scene", ["tank", "turned", "ground", "channel"])
def test_fast_path_equals_the_reference_in_every_double_beam_mode(scene, double_beam, kernels):
    compare(SCENES[scene](3, double_beam), kernels)


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("double_beam", ["paper", "separate", "coherent"])
@pytest.mark.parametrize("scene", ["tank", "turned", "ground", "channel"])
def test_fast_path_equals_the_reference_with_line_of_sight(scene, double_beam, kernels):
    doc = SCENES[scene](3, double_beam)
    doc["render"]["double_line_of_sight"] = True
    compare(doc, kernels)


def test_line_of_sight_removes_paths_in_the_reference():
    # The check must bite: a box on the floor hides part of the floor's mirror paths.
    doc = tank_dict(3)
    sim = sonarsim.Simulator(doc)
    free = render_reference(sim, double_line_of_sight=False)
    seen = render_reference(sim, double_line_of_sight=True)
    for name in ("double", "triple"):
        assert seen.components[name].sum() < free.components[name].sum()
    np.testing.assert_array_equal(seen.components["single"], free.components["single"])


def test_max_order_four_adds_paths_in_the_tank():
    ref3 = render_reference(sonarsim.Simulator(tank_dict(3)))
    ref4 = render_reference(sonarsim.Simulator(tank_dict(4)))
    assert ref4.components["order4"].sum() > 0
    for name in ("object", "ground", "double", "triple"):
        np.testing.assert_allclose(ref4.components[name], ref3.components[name], rtol=1e-12, atol=0)
    assert all(n in ref4.signatures for n in ref3.signatures)


@pytest.mark.parametrize("double_beam", ["paper", "split"])
def test_reciprocal_pairs_are_recorded_once_from_the_longer_receive_leg(double_beam):
    # The ground alone: O-A-G-O (receive via the ground) is kept, O-G-A-O (transmit via the
    # ground) is its reciprocal and is recorded only by 'separate'.
    sim = sonarsim.Simulator(ground_dict(3, double_beam))
    pair = render_reference(sim)
    both = render_reference(sim, double_beam="separate")
    kept, dropped = "O-[objects]-ground-O", "O-ground-[objects]-O"
    assert dropped not in pair.signatures and both.signatures[dropped].sum() > 0
    if double_beam == "paper":
        np.testing.assert_array_equal(pair.signatures[kept], both.signatures[kept])
    else:  # half in the arrival beam, half in the beam the transmit leg leaves in
        np.testing.assert_allclose(pair.signatures[kept].sum(axis=1), both.signatures[kept].sum(axis=1), rtol=1e-12)
        assert not np.allclose(pair.signatures[kept], both.signatures[kept])
    np.testing.assert_array_equal(pair.components["triple"], both.components["triple"])


def test_the_reference_tries_chains_the_fan_never_followed():
    # Independent of the fast path's culling: every chain of the mirror planes, by length.
    chains = all_chains([0, 1, 2], 3)
    assert chains[0] == () and len(chains) == 1 + 3 + 6 + 12
    assert all(a != b for c in chains for a, b in zip(c, c[1:]))
    # The mirror formula: across z = 2 with the normal down.
    np.testing.assert_allclose(mirror_point(np.array([1.0, 2.0, 0.5]), np.array([0.0, 0.0, -1.0]), -2.0),
                               [1.0, 2.0, 3.5])


def test_transmit_lengths_are_image_source_distances():
    # Each traced transmit leg is as long as the straight line from O to the scatterer
    # unfolded across the chain's planes (mirrored here with a formula of the test's own).
    doc = tank_dict(4, "separate")
    sim = sonarsim.Simulator(doc)
    ref = render_reference(sim, keep_legs=True)
    planes = sim.scene.reflecting_planes
    origin = np.asarray(doc["sonar"]["pose"]["position_m"], float)
    n_checked = 0
    for k in range(len(ref.paths.energy)):
        if ref.paths.same[k]:
            continue
        a = ref.paths.tx_vertices[k][-1]
        for p in reversed(ref.paths.tx_chain[k]):  # unfold: mirror across the last plane first
            n, q = np.asarray(planes[p].normal), np.asarray(planes[p].point_m)
            a = a - 2.0 * np.dot(a - q, n) * n
        assert abs(np.linalg.norm(a - origin) - ref.paths.tx_length_m[k]) < 1e-9
        n_checked += 1
    assert n_checked > 100


def corner_dict() -> dict:
    """A far wall 3 m ahead and a left wall 1.05 m aside: the left wall is met first only at
    azimuths between 19.3 deg and the fan's edge at 20 deg, beyond the edge beam's ray column
    at 18.75 deg (one ray column per beam)."""
    return {
        "sonar": {**SONAR, "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 0.0, 0.0]}},
        "render": {"elevation_samples": 24, "max_order": 3, "range_splat": False, "double_beam": "separate"},
        "planes": [
            {"name": "far_wall", "point_m": [3.0, 0, 0], "normal": [-1, 0, 0], "albedo": 0.5, "specular": 0.8},
            {"name": "left_wall", "point_m": [0, 1.05, 0], "normal": [0, -1, 0], "albedo": 0.5, "specular": 0.8},
        ],
        "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [2.2, 0.2, 1.0]}}],
    }


def test_the_corner_scene_has_a_transmit_chain_no_receive_ray_followed():
    ref = render_reference(sonarsim.Simulator(corner_dict()))
    left = ref.plane_names.index("left_wall")
    assert (left,) not in ref.rx_chains
    assert ref.signatures["O-left_wall-[far_wall]-O"].sum() > 0


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_fast_path_forms_transmit_chains_no_receive_ray_followed(kernels):
    # Regression: O-left_wall-[far_wall]-O leaves the sonar inside the aperture (azimuth
    # 19.3-20 deg) but no ray column of the fan meets the left wall first; the fast path, which
    # tries the chains the receive rays followed, missed it until it also probed the edges of
    # the aperture (engine.probe_chains).
    sim = sonarsim.Simulator(corner_dict(), kernels=kernels)
    fast = sim.render().components
    ref = render_reference(sim)
    name = "O-left_wall-[far_wall]-O"
    got = fast[name].astype(float) if name in fast.signatures else 0.0
    assert np.abs(got - ref.signatures[name]).sum() <= L1_TOLERANCE * ref.signatures[name].sum()


@pytest.mark.parametrize("max_order", [2, 3])
def test_every_plane_of_the_channel_carries_paths(max_order):
    # A guard for the comparisons above: a plane whose paths are all empty in a scene lets a
    # fault of that plane pass them (the tank's water surface is never reached from its pose;
    # the channel's is, both ways).
    c = sonarsim.render(channel_dict(max_order)).components
    for plane in ("ground", "surface"):
        lit = [s for s in c.signatures if plane in s.split("-") and c[s].sum() > 0]
        assert lit, f"no path via or on the {plane}"
    if max_order == 3:  # both legs via the surface: the receive leg reflected there too
        assert c["O-surface-[ground]-surface-O"].sum() > 0


def _engine_paths(sim) -> dict:
    """The path engine's paths of the scene's frame, read from its path buffer: ``{(ray,
    transmit chain, receive chain): (scatterer, range, energy, beam)}``."""
    from sonarsim.paths.engine import SAME, SonarView
    render, sonar, pose = sim.scene.render, sim.scene.sonar, sim.scene.sonar_pose
    fan = sim.ray_fan(sonar)
    active, multipath, reach = sim.frame_reach(sonar, pose)
    _, legs, sets, table, _, _ = sim._render_paths(sonar, SonarView.of(sonar, pose, fan), reach, active,
                                                   render.max_order if multipath else 1)
    out = {}
    for s in (sets() if callable(sets) else sets):
        leg = legs[s.gen]
        for j, ray in enumerate(s.ray):
            rx = table.chains[int(leg.chain[ray])]
            tx = rx if s.tx == SAME else table.chains[s.tx]
            key = (int(ray), tuple(tx), tuple(rx))
            assert key not in out, f"path {key} formed twice"
            out[key] = (int(leg.sid[ray]), float(s.distance[j]), float(s.energy[j]), int(s.beam[j]))
    return out


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
@pytest.mark.parametrize("scene", ["tank", "channel", "turned", "ground"])
def test_the_path_buffer_holds_the_reference_paths_one_by_one(scene, kernels):
    """Path by path, not image by image: the same fan ray, transmit and receive chains,
    scatterer, recorded range, energy and beam. The engine tries only the chains some ray or
    the aperture's edges followed, so the reference may hold more (never with a chain the
    engine tried); the energies differ by the float32 points of the first generation."""
    sim = sonarsim.Simulator(SCENES[scene](3), kernels=kernels)
    got = _engine_paths(sim)
    ref = render_reference(sim).paths
    window = sim.scene.sonar.range_min_m, sim.scene.sonar.range_max_m
    tried = {tx for _, tx, _ in got}
    matched = 0
    for k in range(len(ref.energy)):
        if ref.energy[k] <= 0:
            continue
        key = (int(ref.ray[k]), tuple(ref.tx_chain[k]), tuple(ref.rx_chain[k]))
        if key not in got:
            # Missing only where the engine never tried that transmit chain, or at the edge of
            # the range window (float32 rounding of a range right on it).
            on_edge = min(abs(ref.range_m[k] - w) for w in window) < 1e-5
            assert ref.tx_chain[k] not in tried or on_edge, f"the engine lacks the path {key}"
            continue
        sid, distance, energy, beam = got.pop(key)
        assert sid == ref.scatterer[k] and beam == ref.beam[k], key
        assert abs(distance - ref.range_m[k]) <= 1e-5, (key, distance, ref.range_m[k])
        assert abs(energy - ref.energy[k]) <= 1e-4 * ref.energy[k], (key, energy, ref.energy[k])
        matched += 1
    # What the engine formed beyond the reference: nothing that carries energy.
    assert all(v[2] == 0 for v in got.values()), [k for k, v in got.items() if v[2] != 0][:5]
    assert matched > 500
