"""A world that moves (issue 40 item 3): objects moved in place, without a new simulator.

The invariant: a simulator whose object was moved renders exactly what a new simulator built
with the object at that pose renders (every engine, mirrors, planes that clip the object); the
tracks' poses against hand-computed ones; labels that follow the object.
"""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.config.tracks import Trajectory
from sonarsim.core.transforms import Pose
from sonarsim.errors import ConfigError
from sonarsim.renderer.simulator import Simulator
from sonarsim.trace.base import Hits  # noqa: F401  (the casters' answer, compared below)

from ..conftest import still_doc


def tank(track: dict | None = None, specular: bool = False) -> dict:
    """A floor, a wall and two objects before an ARIS 3000: the box rests on the floor (the
    floor clips it), the sphere floats (and mirrors, with ``specular``)."""
    sphere = {"name": "ball", "primitive": "sphere", "radius_m": 0.25, "pose": {"position_m": [3.0, 0.4, 0.5]}}
    if specular:
        sphere["specular"] = 0.8
    if track is not None:
        sphere["track"] = track
        if "keys" in track or "file" in track:
            sphere.pop("pose")
    return {
        "sonar": {"preset": "aris3000-64", "range_min_m": 0.5, "range_max_m": 6.0,
                  "pose": {"position_m": [0, 0, 1.0], "rpy_deg": [0, 15, 0]}},
        "ground": {"height_m": 0.0, "albedo": 0.6, "specular": 0.5},
        "planes": [{"name": "wall", "point_m": [6.5, 0, 0], "normal": [-1, 0, 0], "albedo": 0.3, "specular": 0.3}],
        "objects": [
            {"name": "block", "primitive": "box", "size_m": [0.6, 0.4, 0.4], "pose": {"position_m": [2.5, -0.5, 0.1],
                                                                                    "rpy_deg": [0, 0, 30]}},
            sphere,
        ],
        "render": {"max_order": 3, "seed": 3},
    }


@pytest.mark.parametrize("backend, specular", [("embree", False), ("embree", True), ("numpy", False)])
def test_a_moved_object_renders_as_a_new_simulator_would(backend, specular):
    doc = tank(specular=specular)
    if backend == "numpy":  # every ray against every triangle: a coarser fan, to stay quick
        doc["render"] = {**doc["render"], "elevation_samples": 16, "max_order": 2}
    sim = Simulator(doc, backend=backend)
    sim.render(speckle=False)
    # Along, then down through the floor (the clip changes its triangles), then up again.
    for name, pose in [("ball", Pose((3.4, -0.2, 0.6), (10, 0, 40))), ("block", Pose((2.0, 0.3, 0.05), (0, 0, 75))),
                       ("block", Pose((2.1, 0.3, 0.1), (0, 0, 80))), ("ball", Pose((2.8, 0.0, 0.1), (0, 0, 0)))]:
        sim.move_objects({name: pose})
        doc = still_doc(doc, name, pose)
        moved = sim.render(speckle=False)
        with Simulator(doc, backend=backend) as fresh:
            want = fresh.render(speckle=False)
        assert want.polar.max() > 0
        np.testing.assert_allclose(moved.polar, want.polar, rtol=1e-5, atol=1e-9 * float(want.polar.max()))
        for key in want.components:
            np.testing.assert_allclose(moved.components[key], want.components[key], rtol=1e-5,
                                       atol=1e-9 * float(want.polar.max()))


def test_moves_refit_in_place_and_the_record_is_the_moment():
    doc = tank(track={"velocity_m_s": [0.0, -0.2, 0.0]})
    sim = Simulator(doc)
    assert sim.tracked == ("ball",) and sim._base_caster.dynamic
    caster = sim._base_caster
    sim.at_time(1.0)
    assert sim.last_moves == {"ball": "refit"}  # a floating ball keeps its triangles
    assert sim._base_caster is caster  # no new caster, no new Embree scene
    assert sim.scene.objects[1].pose.position_m == pytest.approx((3.0, 0.2, 0.5))
    img = sim.render(speckle=False)
    # The frame's recorded scene is a still scene at that moment: read back, it renders the frame.
    ball = img.config["objects"][1]
    assert "track" not in ball and ball["pose"]["position_m"] == pytest.approx([3.0, 0.2, 0.5])
    with Simulator(img.config) as again:
        np.testing.assert_allclose(again.render(speckle=False).polar, img.polar, rtol=1e-5, atol=1e-12)
    sim.move_objects({"ball": sim.scene.objects[1].pose})  # the same pose: nothing to do
    assert sim.last_moves == {}


def test_a_static_caster_is_rebuilt_once_for_motion():
    sim = Simulator(tank())
    assert not sim._base_caster.dynamic
    sim.move_objects({"ball": Pose((3.0, 0.3, 0.5))})
    assert sim.last_moves == {"ball": "rebuilt"} and sim._base_caster.dynamic
    sim.move_objects({"ball": Pose((3.0, 0.2, 0.5))})
    assert sim.last_moves == {"ball": "refit"}


def test_an_object_moved_beyond_a_plane_vanishes_and_comes_back():
    sim = Simulator(tank(track={"velocity_m_s": [0, 0, 0]}))  # built for motion
    sim.move_objects({"ball": Pose((3.0, 0.4, -1.0))})  # wholly below the floor
    assert sim.last_moves == {"ball": "disabled"}
    under = sim.render(labels=True, speckle=False)
    assert not np.any(under.labels.instance["object"] == 1)
    sim.move_objects({"ball": Pose((3.0, 0.4, 0.5))})
    back = sim.render(labels=True, speckle=False)
    assert np.any(back.labels.instance["object"] == 1)


def test_labels_follow_the_object():
    sim = Simulator(tank())
    ranges = []
    for x in (2.5, 3.5):  # 1 m further along the ground, straight ahead
        sim.move_objects({"ball": Pose((x, 0.0, 0.5))})
        img = sim.render(labels=True, speckle=False)
        rows = np.flatnonzero(np.any(img.labels.instance["object"] == 1, axis=1))
        ranges.append(img.range_m[rows].min())
    # The ball's nearest point: hand computed from the sonar at (0, 0, 1).
    want = [np.hypot(x, 0.5) - 0.25 for x in (2.5, 3.5)]
    bin_m = sim.scene.sonar.range_resolution_m
    assert ranges == pytest.approx(want, abs=2.5 * bin_m)
    assert ranges[1] - ranges[0] == pytest.approx(want[1] - want[0], abs=2 * bin_m)


def test_an_unknown_object_is_refused_by_name():
    sim = Simulator(tank())
    with pytest.raises(ConfigError, match=r"objects\.boat: no object named 'boat'.*'block', 'ball'"):
        sim.move_objects({"boat": Pose((1, 0, 0))})


def test_track_keys_interpolate_and_repeat():
    doc = tank(track={"keys": [{"t": 0, "position_m": [3.0, -1.0, 0.5]},
                               {"t": 4, "position_m": [3.0, 1.0, 0.5], "rpy_deg": [0, 0, 90]}], "repeat": True})
    scene = sonarsim.load_scene(doc)
    ball = scene.objects[1]
    assert ball.pose.position_m == pytest.approx((3.0, -1.0, 0.5))  # the track's first pose
    p = ball.track.pose_at(1.0)
    assert p.position_m == pytest.approx((3.0, -0.5, 0.5))
    assert p.rpy_deg[2] == pytest.approx(22.5)  # slerp about one axis: linear in angle
    assert ball.track.pose_at(5.0).position_m == pytest.approx((3.0, -0.5, 0.5))  # repeated
    # Read back from the scene-file form, the same track.
    again = sonarsim.load_scene(scene.to_dict()).objects[1].track
    assert again.pose_at(3.0).position_m == pytest.approx(ball.track.pose_at(3.0).position_m)


def test_track_velocity_turns_about_the_vertical():
    scene = sonarsim.load_scene(tank(track={"velocity_m_s": [0.5, 0, 0], "yaw_rate_deg_s": 10}))
    p = scene.objects[1].track.pose_at(3.0)
    assert p.position_m == pytest.approx((4.5, 0.4, 0.5))
    assert p.rpy_deg == pytest.approx((0.0, 0.0, 30.0), abs=1e-9)


def test_track_file(tmp_path):
    path = tmp_path / "ball.csv"
    path.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0,3,-1,0.5,0,0,0\n2,3,1,0.5,0,0,0\n")
    doc = tank(track={"file": str(path)})
    sim = Simulator(doc)
    sim.at_time(0.5)
    assert sim.scene.objects[1].pose.position_m == pytest.approx((3.0, -0.5, 0.5))
    sim.at_time(10.0)  # held at the last pose
    assert sim.scene.objects[1].pose.position_m == pytest.approx((3.0, 1.0, 0.5))


@pytest.mark.parametrize("track, key, match", [
    ({"keys": [{"t": 1, "position_m": [0, 0, 0]}, {"t": 1, "position_m": [1, 0, 0]}]}, "keys[1].t", "increase"),
    ({"keys": []}, "keys", "non-empty"),
    ({"velocity_m_s": [0, 0, 0], "repeat": True}, "repeat", "timed poses"),
    ({"velocity_m_s": [500, 0, 0]}, "velocity_m_s", "100"),
    ({"file": "x.csv", "keys": []}, "track", "exactly one"),
    ({"speed": 1}, "speed", "unknown key"),
    ({"keys": [{"position_m": [0, 0, 0]}]}, "keys[0]", "mapping with t"),
    ({"file": "missing.csv"}, "file", "missing.csv"),
])
def test_bad_tracks_are_refused_by_key(track, key, match):
    doc = tank()
    doc["objects"][1]["track"] = track
    with pytest.raises(ConfigError) as info:
        sonarsim.load_scene(doc)
    assert info.value.key.startswith("objects[1].track") and info.value.key.endswith(key)
    assert match in str(info.value)


def test_timed_poses_and_a_pose_together_are_refused():
    doc = tank(track={"keys": [{"t": 0, "position_m": [3, 0, 0.5]}]})
    doc["objects"][1]["pose"] = {"position_m": [3, 0, 0.5]}
    with pytest.raises(ConfigError, match=r"objects\[1\]\.pose: an object with timed poses"):
        sonarsim.load_scene(doc)


def test_the_caster_moves_meshes_as_a_new_one_casts():
    """Ray by ray: a dynamic Embree 4 caster after refits, a rebuild and a disable, against a
    caster built afresh over the moved meshes."""
    pytest.importorskip("embreex")
    from sonarsim.scene.meshes import object_mesh_world
    from sonarsim.trace.embree4 import Embree4Caster

    scene = sonarsim.load_scene(tank())
    meshes = [object_mesh_world(o) for o in scene.objects]
    caster = Embree4Caster(meshes, threads=1, dynamic=True)
    rng = np.random.default_rng(1)
    origin = np.array([0.0, 0.0, 0.5])
    # Rays at points scattered about the two objects (and where the ball goes), some missing.
    centres = np.array([[2.5, -0.5, 0.1], [3.0, 0.4, 0.5], [3.3, 0.2, 0.6]])
    d = centres[rng.integers(0, 3, 4000)] + rng.normal(scale=0.3, size=(4000, 3)) - origin
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    shifted = type(meshes[1])(meshes[1].vertices + [0.3, -0.2, 0.1], meshes[1].faces)
    fewer = type(meshes[0])(meshes[0].vertices, meshes[0].faces[:6])
    empty = type(meshes[0])(meshes[0].vertices, meshes[0].faces[:0])
    for change, want in [({1: shifted}, "refit"), ({0: fewer}, "rebuilt"), ({0: empty}, "disabled"),
                         ({0: meshes[0]}, "rebuilt")]:
        assert set(caster.replace_meshes(change).values()) == {want}
        meshes = [change.get(k, m) for k, m in enumerate(meshes)]
        fresh = Embree4Caster(meshes, threads=1)
        a = caster.intersect(origin, d, 50.0)
        b = fresh.intersect(origin, d, 50.0)
        np.testing.assert_array_equal(a.mesh_id, b.mesh_id)
        np.testing.assert_allclose(a.distance, b.distance, rtol=1e-5)
        assert (a.mesh_id >= 0).sum() > 100
        fresh.release()


def test_trajectory_at_matches_scipy_slerp():
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(0)
    tr = Trajectory(np.arange(6.0) * 1.5, rng.normal(size=(6, 3)), Rotation.random(6, random_state=1).as_quat())
    t = np.linspace(-1.0, 9.0, 101)
    want = Slerp(tr.times_s, Rotation.from_quat(tr.quats_xyzw))(np.clip(t, 0, 7.5)).as_matrix()
    many = tr.at(t)
    for k, tk in enumerate(t):
        one = tr.at(float(tk))[0]  # the scalar path a frame's object takes
        np.testing.assert_allclose(many[k].rotation, want[k], atol=1e-12)
        np.testing.assert_allclose(one.matrix(), many[k].matrix(), atol=1e-12)


def sidescan_scene(box: dict) -> dict:
    return {"sonar": {"type": "sidescan", "frequency_khz": 600, "horizontal_beam_width_deg": 0.5,
                      "vertical_beam_width_deg": 50, "depression_deg": 15, "range_max_m": 30.0, "n_samples": 1024,
                      "ping_rate_hz": 5.0, "pose": {"position_m": [0.0, 0.0, 10.0]}},
            "ground": {"height_m": 0.0}, "objects": [box], "render": {"max_order": 1}}


def test_a_side_scan_sees_a_target_towed_beside_it_on_every_ping():
    """A box on a track that keeps pace with the vehicle (2 m/s east, 15 m to port) is seen on
    every ping at one range; left still, only on the pings passing it."""
    from sonarsim.dataset.trajectory import Trajectory
    from sonarsim.instruments import render_pings

    vehicle = Trajectory(times_s=[0.0, 10.0], positions_m=[[0, 0, 10.0], [20, 0, 10.0]],
                         quats_xyzw=[[0, 0, 0, 1], [0, 0, 0, 1]])
    box = {"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [0.0, 15.0, 0.5]}}
    seen = {}
    for name, extra in (("towed", {"track": {"velocity_m_s": [2.0, 0.0, 0.0]}}), ("still", {})):
        with sonarsim.Simulator(sidescan_scene({**box, **extra})) as sim:
            w = render_pings(sim, trajectory=vehicle, speckle=False, labels=True)
        hit = w.labels["instance"][:, 0] == w.ids.index("box")
        seen[name] = hit.any(axis=1)
        if name == "towed":
            first = np.array([np.argmax(row) for row in hit])
            assert np.ptp(first) <= 1  # the same range on every ping
            # The near top edge: slant range from 10 m up to the box's top 1 m high, 14.5 m across.
            assert first[0] * 30.0 / 1024 == pytest.approx(np.hypot(14.5, 9.0), abs=0.1)
    assert seen["towed"].all()
    assert 2 <= seen["still"].sum() <= 6 and seen["still"][:3].any() and not seen["still"][10:].any()


def test_instrument_pings_move_objects_to_their_own_times():
    """A forward-looking instrument's pings: each rendered with the objects where their tracks
    put them at its time, as a still scene at that moment renders it."""
    from sonarsim.instruments import render_pings

    def on_vehicle(doc: dict) -> dict:
        sonar = dict(doc.pop("sonar"))
        pose = sonar.pop("pose")
        return {**doc, "vehicle": {"pose": pose}, "instruments": [{"type": "fls", "name": "fls", **sonar,
                                                                    "ping_rate_hz": 2.0}]}

    with sonarsim.Simulator(on_vehicle(tank(track={"velocity_m_s": [0.0, -0.3, 0.0]}))) as sim:
        pings = render_pings(sim, n_pings=3, speckle=False)
    for k, ping in enumerate(pings):
        still = on_vehicle(still_doc(tank(), "ball", Pose((3.0, 0.4 - 0.3 * 0.5 * k, 0.5))))
        with sonarsim.Simulator(still) as fresh:
            want = render_pings(fresh, n_pings=1, speckle=False)[0]
        np.testing.assert_allclose(ping.polar, want.polar, rtol=1e-5, atol=1e-12)
    assert not np.allclose(pings[0].polar, pings[2].polar)


def test_dataset_frames_see_objects_where_their_tracks_put_them(tmp_path):
    """A scenario whose ball patrols: each frame (one simulator for all, or two workers in any
    order) equals a still scene at that frame's time; frame 0 and frame 3 differ."""
    from sonarsim.dataset import frames, generate
    from sonarsim.io.output import read_npz

    scene = tank(track={"keys": [{"t": 0, "position_m": [3.0, -0.8, 0.5]}, {"t": 1.5, "position_m": [3.0, 0.8, 0.5]}]})
    scene["sonar"]["preset"] = "aris3000-64"
    scenario = {"scene": scene, "seed": 4, "trajectory": {"rate_hz": 2.0, "generate": {
        "kind": "orbit", "centre_m": [3.0, 0.0, 0.3], "radius_m": 3.0, "z_m": 1.0, "frames": 4, "sweep_deg": 6}}}
    rendered = list(frames(scenario))
    assert [f.spec.time_s for f in rendered] == [0.0, 0.5, 1.0, 1.5]
    for f in rendered:
        y = -0.8 + 1.6 * f.spec.time_s / 1.5
        still = still_doc(scene, "ball", Pose((3.0, y, 0.5)))
        with Simulator(still) as fresh:
            want = fresh.render(pose=f.spec.pose, frame=f.index)
        np.testing.assert_allclose(f.image.polar, want.polar, rtol=1e-5, atol=1e-12)
    assert not np.allclose(rendered[0].image.polar, rendered[3].image.polar)
    generate(scenario, tmp_path / "two", workers=2, batch_size=1, progress=False)
    for f in rendered:
        arrays, _ = read_npz(tmp_path / "two" / "frames" / f"{f.index:06d}.npz")
        np.testing.assert_array_equal(arrays["polar"], f.image.polar)
