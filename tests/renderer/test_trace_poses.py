"""Several poses in one frame (``Simulator.trace_poses``): each pose's share of the frame is,
bit for bit, the frame of that pose alone (image, components, labels, first hits), and the
frames it cannot hold (multipath, poses facing different planes) are refused with None."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.core.transforms import Pose
from sonarsim.instruments import pose_frames

SONAR = {"n_beams": 4, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 30.0, "range_min_m": 0.5,
         "range_max_m": 20.0, "n_range_bins": 200}
OBJECTS = [{"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0], "pose": {"position_m": [6.0, 0.5, 0.5]}},
           {"name": "ball", "primitive": "sphere", "radius_m": 0.6, "pose": {"position_m": [8.0, -2.0, 0.6]}}]


def scene(**extra) -> dict:
    doc = {"sonar": {**SONAR, "pose": {"position_m": [0.0, 0.0, 3.0], "rpy_deg": [0.0, 20.0, 0.0]}},
           "ground": {"height_m": 0.0}, "objects": OBJECTS, "render": {"max_order": 1}}
    doc.update(extra)
    return doc


def poses(n: int = 5) -> list[Pose]:
    """Poses that differ in every coordinate (position, roll, pitch, yaw), all above the ground."""
    return [Pose((0.7 * k - 1.0, 0.3 * k, 2.0 + 0.4 * k), (3.0 * k - 4.0, 15.0 + 2.0 * k, 7.0 * k - 10.0))
            for k in range(n)]


def alone(sim, pose, labels):
    paths = sim.trace(pose, labels=labels)
    return paths, sim.form(paths, keep_rays=False, speckle=False, sensor=False)


@pytest.mark.parametrize("doc", [
    scene(),
    # the floor as a mesh: Embree meets every ray
    {**{k: v for k, v in scene().items() if k != "ground"},
     "objects": OBJECTS + [{"name": "seabed", "primitive": "box", "size_m": [80.0, 80.0, 1.0],
                            "pose": {"position_m": [0.0, 0.0, -0.5]}}]},
    # a textured floor: the casts go through Python between the kernel's stages
    {**scene(), "ground": {"height_m": 0.0, "texture": {"std_db": 4.0, "correlation_m": [3.0, 1.0], "seed": 3}}},
], ids=["plane", "mesh_floor", "textured"])
def test_each_pose_share_is_its_own_frame_bit_for_bit(doc):
    with sonarsim.Simulator(doc) as sim:
        ps = poses()
        batch = sim.trace_poses(ps, labels="total")
        assert batch is not None and len(batch.poses) == len(ps)
        image = sim.form(batch, keep_rays=False, speckle=False, sensor=False)
        nb = sim.scene.sonar.n_beams
        assert image.polar.shape == (200, len(ps) * nb)
        d_all, sid_all, i_all = batch.first_hits()
        origins, dirs = batch.world_rays()
        for k, pose in enumerate(ps):
            paths, one = alone(sim, pose, "total")
            cols = slice(k * nb, (k + 1) * nb)
            assert np.array_equal(image.polar[:, cols], one.polar)
            assert one.polar.max() > 0
            for name, comp in one.components.items():
                assert np.array_equal(image.components[name][:, cols], comp), name
            assert np.array_equal(image.labels.instance["total"][:, cols], one.labels.instance["total"])
            d, sid, inten = paths.first_hits()
            assert np.array_equal(d_all[cols], d) and np.array_equal(sid_all[cols], sid)
            assert np.array_equal(i_all[cols], inten)
            assert np.allclose(origins[cols], pose.translation)
            assert np.allclose(dirs[cols], paths.view.directions, atol=1e-12)


def test_frames_it_cannot_hold_are_refused():
    ps = poses(3)
    surface = [{"name": "surface", "point_m": [0, 0, 12.0], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9}]
    with sonarsim.Simulator(scene(planes=surface, render={"max_order": 3})) as sim:
        assert sim.trace_poses(ps) is None  # multipath: transmit legs from each pose's own image sources
    wall = [{"name": "wall", "point_m": [0.5, 0, 0], "normal": [1, 0, 0], "albedo": 0.3}]
    doc = scene(planes=wall)
    doc["sonar"]["pose"]["position_m"] = [2.0, 0.0, 3.0]
    with sonarsim.Simulator(doc) as sim:
        # the first pose behind the wall (x < 0.5) faces other planes than the rest
        assert sim.trace_poses([Pose((0.0, 0, 2.0), (0, 20, 0)), Pose((2.0, 0, 2.0), (0, 20, 0))]) is None
        assert sim.trace_poses([Pose((1.0, 0, 2.0), (0, 20, 0)), Pose((2.0, 0, 2.0), (0, 20, 0))]) is not None


def test_unknown_labels_are_refused_by_name():
    from sonarsim.errors import ConfigError

    with sonarsim.Simulator(scene()) as sim, pytest.raises(ConfigError) as err:
        sim.trace_poses(poses(2), labels="boxes")
    assert err.value.key == "labels"


def test_pose_frames_cover_every_pose_once_in_order_whatever_the_batch(monkeypatch):
    import sonarsim.instruments as inst

    with sonarsim.Simulator(scene()) as sim:
        ps = poses(7)
        fan = sim.ray_fan(sim.scene.sonar)
        reference = [alone(sim, p, False)[1].polar for p in ps]
        for rays in (fan.n_rays, 2 * fan.n_rays, 3 * fan.n_rays, 100 * fan.n_rays):
            monkeypatch.setattr(inst, "BATCH_RAYS", rays)
            seen = []
            for start, stop, paths, image in pose_frames(sim, ps, sim.scene.sonar, fan):
                assert stop - start == min(rays // fan.n_rays, len(ps) - start)
                for j, k in enumerate(range(start, stop)):
                    assert np.array_equal(image.polar[:, 4 * j:4 * j + 4], reference[k])
                seen += list(range(start, stop))
            assert seen == list(range(len(ps)))


def test_the_kernel_refuses_several_poses_with_multipath():
    from sonarsim.renderer import compiled

    with sonarsim.Simulator(scene()) as sim:
        batch = sim.trace_poses(poses(2))
        work = next(iter(sim._batch_works.values()))
        engine = work.engine[4]
        legs = compiled.FrameLegs(2, batch.fan.n_rays, 2)
        with pytest.raises(ValueError, match="direct paths only"):
            engine.frame(legs, np.ones(1, np.uint8), np.eye(3), np.zeros(3), 20.0, False, 2, batch.fan.shape[2],
                         0.5, 0.1, 200, 8, 20.0, 15.0, np.linspace(10, -10, 9), False, False, 3,
                         pose_rotation=np.stack([np.eye(3)] * 2), pose_origin=np.zeros((2, 3)))


def test_compose_is_the_checked_product():
    a, b = Pose((1.0, -2.0, 3.0), (10.0, -20.0, 30.0)), Pose((0.1, 0.2, -0.3), (0.0, 15.0, 90.0))
    assert a.compose(b) == Pose.from_matrix(a.matrix() @ b.matrix())
    assert a.moved([1.0, 2.0, 3.0]).position_m == pytest.approx((2.0, 0.0, 6.0))
    assert a.moved([1.0, 2.0, 3.0]).rpy_deg == pytest.approx(a.rpy_deg)
