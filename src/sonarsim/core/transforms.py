"""Rigid poses: ROS fixed-axis roll-pitch-yaw, quaternions and mirror images.

World frame: right-handed, z up. A pose maps body coordinates to world coordinates,
``p_world = R @ p_body + t`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``. With z up, a positive
pitch turns the body's x axis (the sonar's acoustic axis) DOWN.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
    x, y, z, w = np.asarray(quat_xyzw, dtype=float) / np.linalg.norm(quat_xyzw)
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


@dataclass(frozen=True)
class Pose:
    """A rigid pose in the world frame.

    Attributes
    ----------
    position_m : (3,) tuple of float
        Origin of the body frame in world coordinates, metres.
    rpy_deg : (3,) tuple of float
        Roll, pitch, yaw in degrees (``R = Rz(yaw) Ry(pitch) Rx(roll)``).
    """

    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _rotation: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position_m", tuple(float(v) for v in self.position_m))
        object.__setattr__(self, "rpy_deg", tuple(float(v) for v in self.rpy_deg))
        rot = rpy_to_matrix(*np.radians(self.rpy_deg))
        rot.setflags(write=False)
        object.__setattr__(self, "_rotation", rot)

    @classmethod
    def from_quaternion(cls, position_m, quat_xyzw) -> "Pose":
        """Pose from a position and a ``(x, y, z, w)`` quaternion."""
        rpy = np.degrees(matrix_to_rpy(quat_to_matrix(quat_xyzw)))
        return cls(tuple(position_m), tuple(rpy))

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) body-to-world rotation matrix (read-only)."""
        return self._rotation

    @property
    def translation(self) -> np.ndarray:
        """(3,) body origin in the world frame, metres."""
        return np.array(self.position_m)

    def matrix(self) -> np.ndarray:
        """(4, 4) homogeneous body-to-world transform."""
        out = np.eye(4)
        out[:3, :3] = self._rotation
        out[:3, 3] = self.position_m
        return out

    def to_dict(self) -> dict:
        """The scene-file form ``{position_m: [...], rpy_deg: [...]}``."""
        return {"position_m": list(self.position_m), "rpy_deg": list(self.rpy_deg)}
