"""Rigid poses: ROS fixed-axis roll-pitch-yaw, quaternions and mirror images.

World frame: right-handed, z up. A pose maps body coordinates to world coordinates,
``p_world = R @ p_body + t`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``. With z up, a positive
pitch turns the body's x axis (the sonar's acoustic axis) DOWN.
"""

from __future__ import annotations

import math

import numpy as np


def rpy_to_matrix(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Parameters
    ----------
    roll_rad, pitch_rad, yaw_rad : float
        Angles in radians about the fixed x, y and z axes, applied in that order.

    Returns
    -------
    (3, 3) float64 ndarray
    """
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def quat_to_matrix(quat_xyzw: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion given as ``(x, y, z, w)`` (ROS order).

    The quaternion is normalised first; a zero quaternion is the caller's error.
    """
    q = np.asarray(quat_xyzw, dtype=float)
    # hypot, not np.linalg.norm: the squares of (1e300, 1e300, 0, 0) overflow, and the
    # quaternion divided by an infinite norm was silently the identity.
    x, y, z, w = q / math.hypot(*q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_rpy(rotation: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rpy_to_matrix`: ``(roll, pitch, yaw)`` in radians.

    Pitch is returned in [-pi/2, pi/2]; at exactly +-90 degrees roll is set to 0.
    """
    r = np.asarray(rotation, dtype=float)
    pitch = float(np.arcsin(np.clip(-r[2, 0], -1.0, 1.0)))
    if abs(r[2, 0]) < 1.0 - 1e-12:
        roll = float(np.arctan2(r[2, 1], r[2, 2]))
        yaw = float(np.arctan2(r[1, 0], r[0, 0]))
    else:  # gimbal lock: only roll +- yaw is defined
        roll = 0.0
        yaw = float(np.arctan2(-r[0, 1], r[1, 1]))
    return roll, pitch, yaw


def matrix_to_quat(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """Unit quaternion ``(x, y, z, w)`` (ROS order, ``w >= 0``) of a rotation matrix.

    Inverse of :func:`quat_to_matrix` up to the sign of the quaternion.
    """
    r = np.asarray(rotation, dtype=float)
    t = r[0, 0] + r[1, 1] + r[2, 2]
    # Shepperd's method: divide by the largest of the four candidates for accuracy.
    if t > max(r[0, 0], r[1, 1], r[2, 2]):
        w = 0.5 * np.sqrt(1.0 + t)
        x, y, z = (r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w)
    elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
        x = 0.5 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        y, z, w = (r[0, 1] + r[1, 0]) / (4 * x), (r[0, 2] + r[2, 0]) / (4 * x), (r[2, 1] - r[1, 2]) / (4 * x)
    elif r[1, 1] >= r[2, 2]:
        y = 0.5 * np.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        x, z, w = (r[0, 1] + r[1, 0]) / (4 * y), (r[1, 2] + r[2, 1]) / (4 * y), (r[0, 2] - r[2, 0]) / (4 * y)
    else:
        z = 0.5 * np.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        x, y, w = (r[0, 2] + r[2, 0]) / (4 * z), (r[1, 2] + r[2, 1]) / (4 * z), (r[1, 0] - r[0, 1]) / (4 * z)
    q = np.array([x, y, z, w], dtype=float)
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    return tuple(float(v) for v in q)


# Largest deviation from orthonormality accepted by Pose.from_matrix: round-off of a matrix
# written out to ~9 digits, far below any rotation that means something else.
_RIGID_ATOL = 1e-6


class Pose:
    """A rigid pose in the world frame: the 4x4 body-to-world transform.

    ``p_world = R @ p_body + t``. The matrix is the pose's state; the roll-pitch-yaw angles and
    the quaternion are views of it. Immutable, compared and hashed by its matrix (so that a
    :class:`~sonarsim.config.scene.Scene` holding it, as ``sonar_pose``, can be a dict key).

    Parameters
    ----------
    position_m : (3,) sequence of float
        Origin of the body frame in world coordinates, metres.
    rpy_deg : (3,) sequence of float
        Roll, pitch, yaw in degrees (``R = Rz(yaw) Ry(pitch) Rx(roll)``).

    See Also
    --------
    Pose.from_quaternion, Pose.from_matrix : the other constructors.
    """

    __slots__ = ("_matrix", "_rpy_deg")

    def __init__(
        self,
        position_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        rpy = tuple(float(v) for v in rpy_deg)
        m = np.eye(4)
        m[:3, :3] = rpy_to_matrix(*np.radians(rpy))
        m[:3, 3] = [float(v) for v in position_m]
        # The angles given are kept so that rpy_deg (and the scene files written from it) gives
        # them back exactly instead of with the round-off of the matrix.
        self._init(m, rpy)

    def _init(self, m: np.ndarray, rpy_deg: tuple[float, float, float] | None) -> None:
        m = np.array(m, dtype=np.float64) + 0.0  # + 0.0: no -0.0, so equal poses hash equal
        m.setflags(write=False)
        object.__setattr__(self, "_matrix", m)
        object.__setattr__(self, "_rpy_deg", rpy_deg)

    @classmethod
    def from_quaternion(cls, position_m, quat_xyzw) -> "Pose":
        """Pose from a position (metres) and a ``(x, y, z, w)`` quaternion (normalised here)."""
        m = np.eye(4)
        m[:3, :3] = quat_to_matrix(quat_xyzw)
        m[:3, 3] = [float(v) for v in position_m]
        return cls.from_matrix(m)

    @classmethod
    def from_matrix(cls, matrix) -> "Pose":
        """Pose from a (4, 4) homogeneous body-to-world transform.

        Raises
        ------
        ValueError
            When the matrix is not (4, 4), not finite, or not a rigid transform (rotation part
            orthonormal with determinant +1, last row ``[0, 0, 0, 1]``, within 1e-6).
        """
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"a pose matrix must be 4x4, got shape {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValueError("a pose matrix must be finite")
        r = m[:3, :3]
        if not (
            np.allclose(r @ r.T, np.eye(3), rtol=0.0, atol=_RIGID_ATOL)
            and abs(np.linalg.det(r) - 1.0) <= _RIGID_ATOL
            and np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=_RIGID_ATOL)
        ):
            raise ValueError("a pose matrix must be a rigid transform (rotation and translation)")
        pose = cls.__new__(cls)
        pose._init(m, None)
        return pose

    def compose(self, other: "Pose") -> "Pose":
        """``self @ other``: the pose of a frame placed at ``other`` in this pose's frame (a
        mount on a vehicle at this pose). A product of rigid transforms is one: not re-checked
        (:meth:`from_matrix`'s check costs more than the product, once per ping and channel)."""
        pose = Pose.__new__(Pose)
        pose._init(self._matrix @ other._matrix, None)
        return pose

    def moved(self, offset_m) -> "Pose":
        """This pose translated by ``offset_m`` (3,), world frame, metres (attitude unchanged)."""
        m = self._matrix.copy()
        m[:3, 3] += np.asarray(offset_m, dtype=np.float64)
        pose = Pose.__new__(Pose)
        pose._init(m, None)
        return pose

    # Views ------------------------------------------------------------------------------

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous body-to-world transform (a fresh, writable copy)."""
        return self._matrix.copy()

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) body-to-world rotation matrix (read-only)."""
        return self._matrix[:3, :3]

    @property
    def translation(self) -> np.ndarray:
        """(3,) body origin in the world frame, metres (a fresh array)."""
        return self._matrix[:3, 3].copy()

    @property
    def position_m(self) -> tuple[float, float, float]:
        """Body origin in the world frame, metres."""
        return tuple(float(v) for v in self._matrix[:3, 3])

    @property
    def rpy_deg(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw in degrees (pitch in [-90, 90]; see :func:`matrix_to_rpy`)."""
        if self._rpy_deg is not None:
            return self._rpy_deg
        return tuple(float(v) for v in np.degrees(matrix_to_rpy(self.rotation)))

    @property
    def quat_xyzw(self) -> tuple[float, float, float, float]:
        """Unit quaternion ``(x, y, z, w)`` of the rotation, ``w >= 0``."""
        return matrix_to_quat(self.rotation)

    def to_dict(self) -> dict:
        """The scene-file form ``{position_m: [...], rpy_deg: [...]}``."""
        return {"position_m": list(self.position_m), "rpy_deg": list(self.rpy_deg)}

    # Value semantics --------------------------------------------------------------------

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"Pose is immutable; cannot set {name!r}")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"Pose is immutable; cannot delete {name!r}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Pose):
            return NotImplemented
        return self._matrix.tobytes() == other._matrix.tobytes()

    def __hash__(self) -> int:
        return hash(self._matrix.tobytes())

    def __repr__(self) -> str:
        return f"Pose(position_m={self.position_m!r}, rpy_deg={self.rpy_deg!r})"

    def __reduce__(self):
        return (_restore_pose, (self._matrix.copy(), self._rpy_deg))


def _restore_pose(matrix: np.ndarray, rpy_deg: tuple[float, float, float] | None) -> Pose:
    pose = Pose.__new__(Pose)
    pose._init(matrix, rpy_deg)
    return pose
