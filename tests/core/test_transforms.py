"""Tests of sonarsim.core.transforms.Pose: the matrix as the state, rpy and quaternion as views."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

from sonarsim.config.sonar import SonarConfig
from sonarsim.core.transforms import Pose, quat_to_matrix, rpy_to_matrix
from sonarsim.renderer.simulator import as_pose

RPYS = [(0.0, 0.0, 0.0), (10.0, 20.0, 30.0), (-45.0, 80.0, 170.0), (5.0, -30.0, -120.0)]


def test_a_pose_holds_the_matrix_of_its_angles():
    p = Pose((1.0, 2.0, 3.0), (0.0, 90.0, 0.0))
    m = p.matrix()
    # Positive pitch turns the body's x axis down (z up).
    np.testing.assert_allclose(m[:3, 0], [0.0, 0.0, -1.0], atol=1e-15)
    np.testing.assert_array_equal(m[:3, 3], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(m[3], [0.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(p.rotation, m[:3, :3])
    np.testing.assert_array_equal(p.translation, [1.0, 2.0, 3.0])
    assert p.position_m == (1.0, 2.0, 3.0)


def test_the_angles_given_come_back_exactly():
    p = Pose([0, 0, 1], [0, 20, 0])
    assert p.rpy_deg == (0.0, 20.0, 0.0)
    assert p.to_dict() == {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}
    assert Pose() == Pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


@pytest.mark.parametrize("rpy", RPYS)
def test_matrix_round_trip_through_rpy(rpy):
    p = Pose((0.5, -1.0, 2.0), rpy)
    q = Pose.from_matrix(p.matrix())
    assert q.rpy_deg == pytest.approx(rpy, abs=1e-9)
    np.testing.assert_allclose(Pose(q.position_m, q.rpy_deg).matrix(), p.matrix(), atol=1e-12)


@pytest.mark.parametrize("rpy", RPYS)
def test_matrix_round_trip_through_the_quaternion(rpy):
    p = Pose((0.5, -1.0, 2.0), rpy)
    quat = p.quat_xyzw
    assert np.linalg.norm(quat) == pytest.approx(1.0) and quat[3] >= 0.0
    np.testing.assert_allclose(quat_to_matrix(quat), p.rotation, atol=1e-12)
    q = Pose.from_quaternion(p.position_m, quat)
    np.testing.assert_allclose(q.matrix(), p.matrix(), atol=1e-12)
    assert q.rpy_deg == pytest.approx(rpy, abs=1e-9)


def test_a_hand_computed_quaternion():
    # 90 degrees about z: (0, 0, sin 45, cos 45).
    p = Pose.from_quaternion((0, 0, 0), (0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert p.rpy_deg == pytest.approx((0.0, 0.0, 90.0))
    np.testing.assert_allclose(p.rotation, rpy_to_matrix(0.0, 0.0, math.pi / 2), atol=1e-15)
    # An unnormalised quaternion is normalised.
    q = Pose.from_quaternion((0, 0, 0), (0.0, 0.0, 2.0, 2.0))
    np.testing.assert_allclose(q.rotation, p.rotation, atol=1e-15)


def test_equality_and_hash_follow_the_matrix():
    a = Pose((1.0, 2.0, 3.0), (10.0, 20.0, 30.0))
    b = Pose([1, 2, 3], np.array([10, 20, 30]))
    assert a == b and hash(a) == hash(b)
    assert Pose.from_matrix(a.matrix()) == a  # the same matrix is the same pose
    assert a != Pose((1.0, 2.0, 3.0), (10.0, 20.0, 31.0))
    assert a != Pose((1.0, 2.0, 3.5), (10.0, 20.0, 30.0))
    assert Pose((0.0, -0.0, 0.0)) == Pose() and hash(Pose((0.0, -0.0, 0.0))) == hash(Pose())
    assert len({a, b, Pose()}) == 2


def test_a_sonar_and_its_pose_are_a_dict_key():
    s = SonarConfig.uniform(8, 20.0, 14.0, 0.5, 5.0, 100), Pose((0, 0, 1), (0, 20, 0))
    t = SonarConfig.uniform(8, 20.0, 14.0, 0.5, 5.0, 100), Pose((0, 0, 1), (0, 20, 0))
    assert {s: 1}[t] == 1


def test_poses_are_immutable_and_copy_and_pickle():
    p = Pose((1.0, 2.0, 3.0), (10.0, 20.0, 30.0))
    with pytest.raises(AttributeError):
        p.rpy_deg = (0.0, 0.0, 0.0)
    with pytest.raises(ValueError):
        p.rotation[0, 0] = 2.0
    m = p.matrix()
    m[0, 3] = 99.0  # a copy: the pose is unchanged
    assert p.position_m == (1.0, 2.0, 3.0)
    for q in (copy.deepcopy(p), pickle.loads(pickle.dumps(p))):
        assert q == p and q.rpy_deg == p.rpy_deg


def test_from_matrix_refuses_what_is_not_a_rigid_transform():
    with pytest.raises(ValueError, match="4x4"):
        Pose.from_matrix(np.eye(3))
    with pytest.raises(ValueError, match="rigid"):
        Pose.from_matrix(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="rigid"):
        Pose.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]))  # a mirror


def test_as_pose_takes_a_matrix_as_it_is():
    p = Pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))
    q = as_pose(p.matrix())
    np.testing.assert_array_equal(q.matrix(), p.matrix())
    assert as_pose(p) is p
    assert as_pose({"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}) == p
    with pytest.raises(TypeError):
        as_pose(np.eye(3))
