"""The viewer with a vehicle's instruments: each channel's fan at its world pose (hand-computed
corners), mirrored scenes mirrored, the session and the page on side-scan and mixed scenes."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import yaml

from sonarsim import Pose
from sonarsim.config.loader import load_scene
from sonarsim.config.instruments import mounted
from sonarsim.errors import ConfigError
from sonarsim.instruments.multibeam import MultibeamSpec
from sonarsim.instruments.scanning import ScanningSpec
from sonarsim.instruments.sidescan import SidescanSpec
from sonarsim.instruments.singlebeam import SinglebeamSpec
from sonarsim.plot.viewer.geometry import fov_segments, instrument_fans, to_world
from sonarsim.plot.viewer.state import SceneSession

needs_viser = pytest.mark.skipif(importlib.util.find_spec("viser") is None, reason="the viewer extra is not installed")

C, S = (lambda deg: math.cos(math.radians(deg))), (lambda deg: math.sin(math.radians(deg)))


def sss(**kw) -> SidescanSpec:
    values = dict(name="sss", horizontal_beam_width_deg=0.5, vertical_beam_width_deg=50.0, depression_deg=15.0,
                  range_min_m=0.0, range_max_m=30.0, n_samples=64)
    values.update(kw)
    return SidescanSpec(**values)


# ---------------------------------------------------------------------------- fan geometry


def test_sidescan_port_fan_corners_at_a_known_vehicle_pose():
    # Vehicle 10 m up heading east (+x), the transducers 0.5 m ahead, 0.1 m below its origin.
    # Port looks along +y, its axis 15 deg below the horizontal; its main lobe spans 50 deg in
    # the vertical plane (from 10 deg above the horizontal to 40 deg below) and 0.5 deg along
    # track (port's azimuth > 0 is its own left: aft, -x).
    spec = sss(mount=Pose((0.5, 0.0, -0.1)))
    vehicle = Pose((0.0, 0.0, 10.0), (0.0, 0.0, 0.0))
    port, starboard = instrument_fans([spec])
    assert (port.name, starboard.name) == ("sss/port", "sss/starboard")
    corners = port.corners(vehicle)  # [range, side (left, right), edge (low, high)]
    apex = np.array([0.5, 0.0, 9.9])
    assert np.allclose(corners[0], apex)  # range_min 0: the near corners are the transducer
    d, r = 15.0, 30.0
    for j, az in enumerate((0.25, -0.25)):
        for k, e in enumerate((-25.0, 25.0)):
            # elevation e about the axis: the ray's depression is d - e, in the plane x = 0,
            # turned aft by the azimuth.
            expected = apex + r * np.array([-C(e) * S(az), C(e) * C(az) * C(d) + S(e) * S(d),
                                            -C(e) * C(az) * S(d) + S(e) * C(d)])
            assert np.allclose(corners[1, j, k], expected, atol=1e-9), (j, k)
    far = corners[1].reshape(-1, 3) - apex
    assert np.allclose(np.linalg.norm(far, axis=1), r)
    assert np.all(far[:, 1] > 0)  # port: +y
    depression = np.degrees(np.arctan2(-far[:, 2], np.hypot(far[:, 0], far[:, 1])))
    # (a quarter degree off the plane x = 0: within 2e-4 deg of 40 and -10)
    assert depression.max() == pytest.approx(40.0, abs=1e-3) and depression.min() == pytest.approx(-10.0, abs=1e-3)
    # Starboard: the same fan mirrored in the vertical plane along track.
    mirrored = starboard.corners(vehicle) * np.array([1.0, -1.0, 1.0])
    assert np.allclose(np.sort(mirrored[1].reshape(-1, 3), axis=0), np.sort(corners[1].reshape(-1, 3), axis=0))
    # Every outline point lies within its fan: range window and angles.
    seg = port.segments(vehicle).reshape(-1, 3) - apex
    assert np.linalg.norm(seg, axis=1).max() == pytest.approx(r)
    assert np.all(seg[:, 1] >= -1e-9) and np.abs(seg[:, 0]).max() <= r * S(0.25) + 1e-9


def test_heading_turns_every_fan_about_the_vehicle():
    # Heading north (yaw 90): port looks west, starboard east; the axis 15 deg down.
    spec = sss()
    vehicle = Pose((3.0, -2.0, 10.0), (0.0, 0.0, 90.0))
    port, starboard = instrument_fans([spec])
    for fan, sign in ((port, -1.0), (starboard, 1.0)):
        axis = fan.world_pose(vehicle).rotation[:, 0]
        assert np.allclose(axis, (sign * C(15.0), 0.0, -S(15.0)), atol=1e-12)
        far = fan.corners(vehicle)[1].reshape(-1, 3) - (3.0, -2.0, 10.0)
        assert np.all(sign * far[:, 0] > 0) and np.abs(far[:, 1]).max() <= 30.0 * S(0.25) + 1e-9


def test_multibeam_swath_edges_from_the_vertical():
    # 11 beams, centres +-50 deg (10 deg apart): the outer beam edges lie half a spacing outside,
    # 55 deg either side of the vertical, across track; the transmit's 2 deg along track.
    spec = MultibeamSpec(name="mb", n_beams=11, swath_deg=100.0, tx_beam_width_along_deg=2.0, range_max_m=40.0,
                         n_samples=64)
    vehicle = Pose((0.0, 0.0, 10.0))
    (fan,) = instrument_fans([spec])
    corners = fan.corners(vehicle)
    r = 40.0
    for j, side in enumerate((55.0, -55.0)):  # left (port, +y) first
        for k, e in enumerate((-1.0, 1.0)):  # elevation > 0 forward
            expected = (0.0, 0.0, 10.0) + r * np.array([S(e), C(e) * S(side), -C(e) * C(side)])
            assert np.allclose(corners[1, j, k], expected, atol=1e-9), (j, k)
    far = fan.segments(vehicle).reshape(-1, 3) - (0.0, 0.0, 10.0)
    far = far[np.linalg.norm(far, axis=1) > 1e-9]  # (range_min 0: the apex has no direction)
    from_vertical = np.degrees(np.arctan2(far[:, 1], -far[:, 2]))
    assert from_vertical.max() == pytest.approx(55.0) and from_vertical.min() == pytest.approx(-55.0)
    assert np.all(far[:, 2] <= 1e-9)  # all below the transducer


def test_singlebeam_cone_and_scanning_head():
    # A 10 deg echo sounder looks straight down: its rim 5 deg from the vertical at 30 m.
    beam = SinglebeamSpec(name="alt", beam_width_deg=10.0, range_max_m=30.0, n_samples=64)
    vehicle = Pose((0.0, 0.0, 12.0))
    (cone,) = instrument_fans([beam])
    seg = cone.segments(vehicle).reshape(-1, 3) - (0.0, 0.0, 12.0)
    dist = np.linalg.norm(seg, axis=1)
    rim = seg[np.isclose(dist, 30.0)]
    assert len(rim) > 20
    assert np.allclose(np.degrees(np.arccos(-rim[:, 2] / 30.0)), 5.0)
    corners = cone.corners(vehicle)[1].reshape(-1, 3) - (0.0, 0.0, 12.0)
    assert np.allclose(corners[:, 2], -30.0 * C(5.0))
    # A scanning head at step 0 looks forward, tilted 10 deg down, 25 deg high.
    head = ScanningSpec(name="msis", horizontal_beam_width_deg=2.0, vertical_beam_width_deg=25.0, tilt_deg=10.0,
                        range_max_m=20.0, n_samples=64)
    (fan,) = instrument_fans([head])
    far = fan.corners(Pose())[1]
    depression = np.degrees(np.arctan2(-far[..., 2], np.hypot(far[..., 0], far[..., 1])))
    assert np.allclose(depression[:, 0], 22.5, atol=0.01) and np.allclose(depression[:, 1], -2.5, atol=0.01)
    # Seen from above, the low edge's rays (e = -12.5 deg about the axis, a = +-1 deg) turned
    # down by the tilt t (Ry(t)): x = cos e cos a cos t + sin e sin t, y = cos e sin a.
    e, a, t = -12.5, 1.0, 10.0
    bearing = math.degrees(math.atan2(C(e) * S(a), C(e) * C(a) * C(t) + S(e) * S(t)))
    assert np.all(far[..., 0] > 0)
    assert np.allclose(np.degrees(np.arctan2(far[:, 0, 1], far[:, 0, 0])), (bearing, -bearing), atol=1e-3)


def _mirror(pose: Pose) -> Pose:
    """The pose mirrored in the world's x-z plane (y -> -y): roll and yaw change sign."""
    x, y, z = pose.position_m
    r, p, yaw = pose.rpy_deg
    return Pose((x, -y, z), (-r, p, -yaw))


def test_a_mirrored_scene_draws_mirrored_fans():
    # A vehicle rolled, pitched and turned, instruments on offset mounts; mirrored in y, every
    # instrument's outline is the original mirrored (side-scan port <-> starboard).
    mounts = [Pose((0.5, 0.3, -0.1), (2.0, 1.0, 4.0)), Pose((-0.4, -0.2, -0.3)),
              Pose((1.0, 0.1, 0.0), (0.0, 20.0, 5.0)), Pose((0.0, 0.4, -0.2))]
    make = [lambda m: sss(mount=m),
            lambda m: MultibeamSpec(name="mb", n_beams=9, beam_angles_deg=(60.0, -40.0), range_max_m=40.0,
                                    n_samples=64, mount=m),
            lambda m: ScanningSpec(name="msis", tilt_deg=10.0, range_max_m=20.0, n_samples=64, mount=m),
            lambda m: SinglebeamSpec(name="alt", range_max_m=30.0, n_samples=64, mount=m)]
    vehicle = Pose((3.0, 1.5, 10.0), (4.0, -3.0, 35.0))
    flip = np.array([1.0, -1.0, 1.0])

    def points(fans, v):
        out = np.concatenate([f.segments(v, arc_points=5).reshape(-1, 3) for f in fans])
        return out[np.lexsort(np.round(out, 6).T)]

    for build, mount in zip(make, mounts):
        spec = build(mount)
        fans = instrument_fans([spec])
        # The mirrored device: a beam table mirrored is the other way round (port <-> starboard).
        mirrored_spec = build(_mirror(mount))
        if isinstance(spec, MultibeamSpec):
            mirrored_spec = MultibeamSpec(name="mb", n_beams=9, beam_angles_deg=(40.0, -60.0), range_max_m=40.0,
                                          n_samples=64, mount=_mirror(mount))
        mirrored = instrument_fans([mirrored_spec])
        a = points(fans, vehicle) * flip
        b = points(mirrored, _mirror(vehicle))
        assert np.allclose(a[np.lexsort(np.round(a, 6).T)], b, atol=1e-6), spec.type_name
        assert not np.allclose(points(fans, vehicle), b, atol=1e-3)  # (the scene is not symmetric itself)


def test_an_fls_instrument_is_drawn_as_todays_fls(tmp_path):
    scene = load_scene(mixed_scene())
    fls = next(f for f in instrument_fans(scene.instruments) if f.type_name == "fls")
    spec = next(i for i in scene.instruments if i.name == "front")
    world = mounted(scene.vehicle_pose, spec.mount)
    assert np.allclose(fls.segments(scene.vehicle_pose), to_world(world, fov_segments(spec.sonar)))


# ---------------------------------------------------------------------------- the session (no browser)


def sidescan_scene() -> dict:
    return {"sonar": {"type": "sidescan", "preset": "seascan_hds_600", "n_samples": 128,
                      "pose": {"position_m": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, 45.0]}},
            "ground": {"height_m": 0.0},
            "objects": [{"name": "crate", "primitive": "box", "size_m": [1.5, 1.0, 1.0],
                         "pose": {"position_m": [7.0, 18.0, 0.5]}}],
            "render": {"max_order": 1}}


def mixed_scene() -> dict:
    return {
        "vehicle": {"pose": {"position_m": [0.0, 0.0, 10.0], "rpy_deg": [0.0, 0.0, 0.0]}},
        "instruments": [
            {"type": "sidescan", "name": "sss", "preset": "seascan_hds_600", "n_samples": 128,
             "mount": {"position_m": [0.5, 0.0, -0.1]}},
            {"type": "fls", "name": "front", "n_beams": 32, "azimuth_fov_deg": 60.0, "elevation_fov_deg": 12.0,
             "range_min_m": 0.5, "range_max_m": 20.0, "n_range_bins": 200,
             "mount": {"position_m": [1.0, 0.0, 0.0], "rpy_deg": [0.0, 30.0, 0.0]}},
            {"type": "multibeam", "name": "mbes", "preset": "r2sonic_2026_400", "n_samples": 256},
            {"type": "singlebeam", "name": "alt", "preset": "ping2"},
        ],
        "ground": {"height_m": 0.0},
        "render": {"max_order": 2, "bounces": [1, 2], "elevation_samples": 16},
    }


@pytest.fixture
def sidescan_session():
    s = SceneSession(sidescan_scene())
    yield s
    s.close()


def test_sidescan_session_moves_the_vehicle_names_the_film_and_saves(sidescan_session, tmp_path):
    s = sidescan_session
    assert s.has_vehicle and s.fls is None and not s.shows_images and not s.sensor_available
    frame = s.render()
    assert frame.image is None and "no live image" in frame.title
    assert len(frame.notes) == 1 and "sidescan 'sidescan'" in frame.notes[0] and "sonarsim render" in frame.notes[0]
    with pytest.raises(ConfigError, match="vehicle"):
        s.set_sonar_pose((0.0, 0.0, 9.0), (0.0, 0.0, 0.0))
    v0 = s.version
    s.set_carrier_pose((1.0, 2.0, 8.0), (0.0, 0.0, 30.0))
    assert s.version == v0 + 1 and s.vehicle_pose == Pose((1.0, 2.0, 8.0), (0.0, 0.0, 30.0))
    assert s.render().title.startswith("vehicle at (1.00, 2.00, 8.00) m")
    files = s.save(tmp_path / "out")
    assert [f.name for f in files] == ["scene.yaml"]
    saved = load_scene(tmp_path / "out" / "scene.yaml")
    assert saved.vehicle_pose == s.vehicle_pose and saved.instruments[0].type_name == "sidescan"
    assert saved.instruments[0].n_samples == 128


def test_mixed_session_renders_its_fls_at_its_mount(tmp_path):
    from sonarsim.instruments import render_pings
    from sonarsim.renderer.simulator import Simulator

    s = SceneSession(mixed_scene())
    try:
        assert s.has_vehicle and s.fls.name == "front" and s.shows_images
        s.set_vehicle_pose((1.0, -2.0, 9.0), (0.0, 0.0, 30.0))
        frame = s.render()
        want = mounted(Pose((1.0, -2.0, 9.0), (0.0, 0.0, 30.0)), s.fls.mount)
        assert frame.image.polar.shape == (200, 32)
        assert np.allclose(frame.image.pose.matrix(), want.matrix())
        assert "fls 'front'" in frame.title
        assert any("sidescan 'sss'" in n and "multibeam 'mbes'" in n and "singlebeam 'alt'" in n
                   and "sonarsim render" in n for n in frame.notes)
        # The image is the FLS's own ping (render_pings) at that vehicle pose.
        with Simulator(s.scene()) as sim:
            (ping,) = render_pings(sim, "front", poses=[s.vehicle_pose], speckle=False)
        assert np.allclose(frame.image.polar, ping.polar, rtol=1e-5, atol=1e-12 * float(ping.polar.max()))
        assert float(frame.image.polar.max()) > 0
        files = s.save(tmp_path / "out")
        assert [f.name for f in files] == ["scene.yaml", "polar.png", "fan.png"]
        saved = load_scene(tmp_path / "out" / "scene.yaml")
        assert saved.vehicle_pose == s.vehicle_pose
        assert [i.name for i in saved.instruments] == ["sss", "front", "mbes", "alt"]
        assert saved.instruments[1].sonar == s.fls.sonar
    finally:
        s.close()


def test_a_plain_fls_scene_still_moves_its_sonar():
    from ..conftest import block_scene_dict

    s = SceneSession(block_scene_dict())
    try:
        assert not s.has_vehicle and s.shows_images and s.saved_files == ("scene.yaml", "polar.png", "fan.png")
        assert s.carrier_pose == s.sonar_pose and s.film_notes() == ()
        with pytest.raises(ConfigError, match="no vehicle"):
            s.set_vehicle_pose((0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
        s.set_carrier_pose((0.0, 0.1, 1.0), (0.0, 10.0, 0.0))
        assert s.sonar_pose == Pose((0.0, 0.1, 1.0), (0.0, 10.0, 0.0))
    finally:
        s.close()


# ---------------------------------------------------------------------------- the page (viser, no browser)


@needs_viser
@pytest.mark.parametrize("doc", [sidescan_scene, mixed_scene], ids=["sidescan", "mixed"])
def test_page_draws_every_fan_under_the_vehicle(doc):
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server

    server = start_server("127.0.0.1", 0)
    try:
        viewer = SceneViewer(server, SceneSession(doc()), out="unused")
        try:
            assert viewer.wait(60) and viewer.error is None
            names = list(viewer.fan_nodes)
            if doc is sidescan_scene:
                assert names == ["/vehicle/sidescan/port", "/vehicle/sidescan/starboard"]
                assert not viewer.fan_image.visible and "no live image" in viewer.title.content
                assert "sonarsim render" in viewer.status.content
            else:
                assert names == ["/vehicle/sss/port", "/vehicle/sss/starboard", "/vehicle/front/fls",
                                 "/vehicle/mbes/multibeam", "/vehicle/alt/beam"]
                assert viewer.fan_image.visible and viewer.frame.image.polar.shape == (200, 32)
            handles = getattr(server.scene, "_handle_from_transform_controls_name", None)  # (private)
            if handles is not None:  # one gizmo for the vehicle, none per instrument
                assert set(handles) == {"/vehicle", *(f"/objects/{o}" for o in viewer.session.object_poses)}
            viewer.set_vehicle_pose((2.0, 1.0, 9.5), (0.0, 0.0, 20.0))
            assert viewer.wait(30) and viewer.error is None
            assert np.allclose(viewer.sonar_control.position, (2.0, 1.0, 9.5))
            assert [sl.value for sl in viewer.pose_sliders] == [2.0, 1.0, 9.5, 0.0, 0.0, 20.0]
            if viewer.session.fls is not None:
                want = mounted(Pose((2.0, 1.0, 9.5), (0.0, 0.0, 20.0)), viewer.session.fls.mount)
                assert np.allclose(viewer.frame.image.pose.matrix(), want.matrix())
            # A drag of the vehicle's gizmo, handed to viser's own handler (private: skipped if moved).
            handler = getattr(server.scene, "_handle_transform_controls_updates", None)
            if handler is not None:
                import asyncio

                from viser import _messages

                from sonarsim.plot.viewer.state import wxyz_of

                pose = Pose((-1.0, 0.5, 9.0), (0.0, 0.0, -15.0))
                asyncio.run(handler(0, _messages.TransformControlsUpdateMessage("/vehicle", wxyz_of(pose),
                                                                                pose.position_m)))
                assert viewer.wait(30) and viewer.error is None
                assert viewer.session.vehicle_pose == pose
                assert [sl.value for sl in viewer.pose_sliders] == [-1.0, 0.5, 9.0, 0.0, 0.0, -15.0]
        finally:
            viewer.close()
    finally:
        stop_server(server)


def test_an_fls_first_on_the_vehicle_offers_its_sensor_and_saves_its_preset(tmp_path):
    # The top-level sensor is the first instrument's: with the FLS first, the switch offers
    # the sensor preset named like its sonar's preset, and the saved file keeps that preset.
    doc = mixed_scene()
    fls = {"type": "fls", "name": "front", "preset": "oculus-m1200d-hf", "range_max_m": 10.0, "n_range_bins": 200,
           "mount": {"position_m": [1.0, 0.0, 0.0], "rpy_deg": [0.0, 30.0, 0.0]}}
    doc["instruments"] = [fls, doc["instruments"][0]]
    s = SceneSession(doc)
    try:
        assert s.fls.name == "front" and s.sensor_available
        s.set_options(sensor=True, speckle=False)
        frame = s.render()
        assert frame.image.polar.shape[0] == 200 and "sensor on" in frame.title
        s.save(tmp_path / "out")
        saved = yaml.safe_load((tmp_path / "out" / "scene.yaml").read_text())
        assert saved["instruments"][0]["preset"] == "oculus-m1200d-hf" and "sensor" in saved
        again = SceneSession(tmp_path / "out" / "scene.yaml")
        try:
            assert again.sensor_available and again.fls.sonar == s.fls.sonar
        finally:
            again.close()
    finally:
        s.close()
    # The FLS second: no sensor switch (a scene file's top-level sensor would be the side-scan's).
    doc["instruments"].reverse()
    s = SceneSession(doc)
    try:
        assert s.fls.name == "front" and not s.sensor_available
        with pytest.raises(ConfigError, match="sensor"):
            s.set_options(sensor=True)
    finally:
        s.close()
