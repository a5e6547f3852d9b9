"""Timed poses: the :class:`Trajectory` type and the files it is read from (CSV, TUM).

A trajectory is a sequence of timestamped poses (DESIGN.md section 1: ``R = Rz(yaw) Ry(pitch)
Rx(roll)``, x forward, positive pitch looks down): the sonar's or the vehicle's path in a
dataset, ``render --along`` or ``live``, and an object's own ``track`` in a scene. Here, in the
configuration layer, so that a scene's objects can carry one; :mod:`sonarsim.dataset.trajectory`
adds the generators and the scenario's section, and re-exports every name.
"""

from __future__ import annotations

import bisect
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.memory import require
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError, check_input_file, shown
from .parameters import MAX_COORDINATE_M

__all__ = ["CSV_HEADER", "RATE_RANGE_HZ", "Trajectory", "read_csv_trajectory", "read_trajectory", "read_tum_trajectory"]

#: The header a CSV trajectory must start with (exactly these columns, in this order).
CSV_HEADER = ("t", "x", "y", "z", "roll_deg", "pitch_deg", "yaw_deg")
# What one pose costs in memory while a trajectory is built: time, position, quaternion and the
# interpolation's temporaries (scipy's Rotation holds a few copies), as float64.
_BYTES_PER_POSE = 8 * 8 * 4
# Reading a file holds each row as Python floats (about 8 objects of ~30 bytes); a row is at
# least 14 characters ("0,0,0,0,0,0,0\n"), so a file of S bytes may hold S / 14 rows.
_BYTES_PER_FILE_BYTE = 8 * 32 // 14 + 1
#: Ping rates, Hz: sonars ping a few to a few tens of times a second; 1e-300 Hz stamped frames
#: 1e300 s apart, 1e300 Hz made every frame's time the same.
RATE_RANGE_HZ = (1e-3, 1e4)


def _quats_from_rpy_deg(rpy_deg: np.ndarray) -> np.ndarray:
    """(n, 3) roll, pitch, yaw in degrees -> (n, 4) unit quaternions (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    # Extrinsic x-y-z (lower case in scipy) is R = Rz(yaw) Ry(pitch) Rx(roll), DESIGN.md section 1.
    return Rotation.from_euler("xyz", rpy_deg, degrees=True).as_quat()


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions, row by row, the short way round.

    Parameters
    ----------
    q0, q1 : (n, 4) float arrays
        Unit quaternions (x, y, z, w) at the two ends.
    w : (n,) float array
        Fraction of the way from ``q0`` (0) to ``q1`` (1).

    Returns
    -------
    (n, 4) float64 ndarray of unit quaternions.
    """
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    w = np.asarray(w, np.float64)[:, None]
    dot = np.sum(q0 * q1, axis=1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)  # q and -q are one rotation: take the shorter arc
    dot = np.abs(dot)
    angle = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(angle)
    close = sin < 1e-9  # (nearly) the same rotation: the chord is the arc
    safe = np.where(close, 1.0, sin)
    a = np.where(close, 1.0 - w, np.sin((1.0 - w) * angle) / safe)
    b = np.where(close, w, np.sin(w * angle) / safe)
    q = a * q0 + b * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _check_rate(rate_hz: Any, key: str) -> float:
    """``rate_hz`` within :data:`RATE_RANGE_HZ`, or a ConfigError naming ``key``."""
    lo, hi = RATE_RANGE_HZ
    if not (isinstance(rate_hz, (int, float)) and lo <= rate_hz <= hi):
        raise ConfigError(key, f"must be within [{lo:g}, {hi:g}] pings per second, got {shown(rate_hz)}")
    return float(rate_hz)



@dataclass(frozen=True, eq=False)
class Trajectory:
    """Timestamped sonar poses, held as arrays (read-only).

    Attributes
    ----------
    times_s : (n,) float64 ndarray
        Strictly increasing timestamps, seconds.
    positions_m : (n, 3) float64 ndarray
        Sonar positions in the world frame, metres.
    quats_xyzw : (n, 4) float64 ndarray
        Unit quaternions (x, y, z, w) of the sonar-to-world rotations.
    rpy_deg : (n, 3) float64 ndarray or None
        The roll, pitch, yaw the poses were given with (CSV files, generators), returned
        exactly by :meth:`pose`; ``None`` where only quaternions are known.
    """

    times_s: np.ndarray
    positions_m: np.ndarray
    quats_xyzw: np.ndarray
    rpy_deg: np.ndarray | None = field(default=None)

    def __post_init__(self) -> None:
        t = np.array(self.times_s, dtype=np.float64)
        p = np.array(self.positions_m, dtype=np.float64).reshape(-1, 3)
        q = np.array(self.quats_xyzw, dtype=np.float64).reshape(-1, 4)
        rpy = None if self.rpy_deg is None else np.array(self.rpy_deg, dtype=np.float64).reshape(-1, 3)
        n = len(t)
        if t.ndim != 1 or len(p) != n or len(q) != n or (rpy is not None and len(rpy) != n):
            raise ValueError("times, positions, quaternions (and angles) must have one row per pose")
        if n == 0:
            raise ValueError("a trajectory needs at least one pose")
        if n > 1 and not np.all(np.diff(t) > 0):
            raise ValueError("trajectory times must be strictly increasing")
        q, norms = _unit_quaternions(q)
        if not np.all(norms > 1e-9):
            raise ValueError("a trajectory quaternion is zero")
        for name, a in (("times_s", t), ("positions_m", p), ("quats_xyzw", q), ("rpy_deg", rpy)):
            if a is not None:
                a.setflags(write=False)
                object.__setattr__(self, name, a)

    @property
    def n_frames(self) -> int:
        """Number of poses."""
        return len(self.times_s)

    def time_s(self, k: int) -> float:
        """Timestamp of pose ``k``, seconds."""
        return float(self.times_s[k])

    def pose(self, k: int, rng: np.random.Generator | None = None) -> Pose:
        """Pose ``k`` (``rng`` is unused: these poses are fixed)."""
        position = tuple(float(v) for v in self.positions_m[k])
        if self.rpy_deg is not None:
            return Pose(position, tuple(float(v) for v in self.rpy_deg[k]))
        return Pose.from_quaternion(position, self.quats_xyzw[k])

    def at(self, times_s: Any) -> list[Pose]:
        """The poses at ``times_s`` (clipped to the span): positions interpolated linearly,
        orientations by slerp between the neighbouring poses.

        Parameters
        ----------
        times_s : float or (n,) float array, seconds

        Returns
        -------
        list of Pose, one per time
        """
        if np.ndim(times_s) == 0:
            return [self._at_one(float(times_s))]
        t = np.clip(np.atleast_1d(np.asarray(times_s, np.float64)), self.times_s[0], self.times_s[-1])
        pos = np.column_stack([np.interp(t, self.times_s, self.positions_m[:, i]) for i in range(3)])
        if self.n_frames == 1:
            quats = np.repeat(self.quats_xyzw, len(t), axis=0)
        else:
            # The segment each time falls in, and how far along it: one slerp per time (scipy's
            # Slerp, built per call, cost a millisecond a frame for one moving object).
            i = np.clip(np.searchsorted(self.times_s, t, side="right") - 1, 0, self.n_frames - 2)
            w = (t - self.times_s[i]) / (self.times_s[i + 1] - self.times_s[i])
            quats = slerp(self.quats_xyzw[i], self.quats_xyzw[i + 1], w)
        return [Pose.from_quaternion(p, q) for p, q in zip(pos, quats)]

    def _at_one(self, t: float) -> Pose:
        """:meth:`at` for one time, in scalars (a frame's object poses: NumPy's per-call cost
        on arrays of one was most of a moving object's frame overhead)."""
        times = self.times_s
        if self.n_frames == 1 or t <= times[0]:
            return Pose.from_quaternion(self.positions_m[0], self.quats_xyzw[0])
        if t >= times[-1]:
            return Pose.from_quaternion(self.positions_m[-1], self.quats_xyzw[-1])
        i = min(bisect.bisect_right(times, t) - 1, self.n_frames - 2)
        w = (t - times[i]) / (times[i + 1] - times[i])
        p0, p1 = self.positions_m[i].tolist(), self.positions_m[i + 1].tolist()
        position = [a + w * (b - a) for a, b in zip(p0, p1)]
        q0, q1 = self.quats_xyzw[i].tolist(), self.quats_xyzw[i + 1].tolist()
        dot = sum(a * b for a, b in zip(q0, q1))
        if dot < 0:
            q1, dot = [-b for b in q1], -dot
        angle = math.acos(min(dot, 1.0))
        if math.sin(angle) < 1e-9:
            a, b = 1.0 - w, w
        else:
            a, b = math.sin((1.0 - w) * angle) / math.sin(angle), math.sin(w * angle) / math.sin(angle)
        return Pose.from_quaternion(position, [a * x + b * y for x, y in zip(q0, q1)])

    def resampled(self, rate_hz: float, key: str = "trajectory.rate_hz") -> "Trajectory":
        """The trajectory at a ping rate: times ``t0 + i / rate_hz`` up to the last timestamp.

        Positions are interpolated linearly, orientations by spherical linear interpolation
        (slerp) between the two neighbouring poses.

        Parameters
        ----------
        rate_hz : float
            Pings per second, within ``RATE_RANGE_HZ`` (0.001 to 10000).
        key : str
            Key named in errors (the rate's place in the scenario file).

        Raises
        ------
        ConfigError
            ``rate_hz`` is not positive, or gives more poses than the memory budget holds.
        """
        from scipy.spatial.transform import Rotation, Slerp

        _check_rate(rate_hz, key)
        duration = float(self.times_s[-1] - self.times_s[0])
        # The 1e-9 keeps a last sample that lands on the final timestamp up to round-off.
        n_float = math.floor(duration * rate_hz * (1 + 1e-12) + 1e-9) + 1
        require(n_float * _BYTES_PER_POSE, f"{n_float:.3g} poses at {rate_hz:g} Hz over {duration:g} s", key)
        n = int(n_float)
        t = self.times_s[0] + np.arange(n) / rate_hz
        t = np.minimum(t, self.times_s[-1])  # round-off past the end would be an extrapolation
        positions = np.column_stack([np.interp(t, self.times_s, self.positions_m[:, i]) for i in range(3)])
        if self.n_frames == 1:
            quats = np.repeat(self.quats_xyzw, n, axis=0)
        else:
            quats = Slerp(self.times_s, Rotation.from_quat(self.quats_xyzw))(t).as_quat()
        return Trajectory(t, positions, quats)


def _file_rows(path: Path, key: str) -> list[tuple[int, str]]:
    """Non-blank, non-comment lines of a trajectory file with their 1-based line numbers.

    The file is UTF-8 text; a byte-order mark before it (spreadsheets write one) is skipped.
    """
    try:  # missing, a directory, a pipe or a device: one message each, nothing opened
        size = check_input_file(path, "trajectory file").st_size
    except SonarsimError as exc:
        raise ConfigError(key, str(exc)) from None
    require(size * _BYTES_PER_FILE_BYTE, f"reading the trajectory file {path} ({size / 2**20:.3g} MiB)", key)
    try:
        # utf-8-sig: a CSV saved with a byte-order mark had the header '\ufefft,x,...' refused.
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(key, f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(key, f"{path}: cannot read the trajectory file: {exc.strerror or exc}") from None
    rows = []
    for i, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped and not stripped.startswith("#"):
            rows.append((i, stripped))
    if not rows:
        raise ConfigError(key, f"{path}: the trajectory file has no poses")
    return rows


def _numbers(fields: list[str], n: int, path: Path, line: int, key: str, what: str) -> list[float]:
    if len(fields) != n:
        raise ConfigError(key, f"{path}: line {line}: expected {n} values ({what}), got {len(fields)}")
    out = []
    for name, text in zip(what.split(), fields):
        try:
            v = float(text)
        except ValueError:
            raise ConfigError(key, f"{path}: line {line}: {name} is not a number: {shown(text)}") from None
        if not math.isfinite(v):
            raise ConfigError(key, f"{path}: line {line}: {name} must be finite, got {shown(text)}")
        out.append(v)
    return out


def _check_rows(path: Path, lines: list[int], t: np.ndarray, p: np.ndarray, key: str) -> None:
    """Times strictly increasing and positions within the scene's plausible extent, naming the line."""
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise ConfigError(key, f"{path}: line {lines[i]}: time {t[i]:g} s does not follow the previous "
                          f"{t[i - 1]:g} s (times must increase strictly)")
    far = np.flatnonzero(np.abs(p).max(axis=1) > MAX_COORDINATE_M)
    if len(far):
        i = int(far[0])
        raise ConfigError(key, f"{path}: line {lines[i]}: position {p[i].tolist()} lies beyond "
                          f"{MAX_COORDINATE_M:g} m of the origin")


def read_csv_trajectory(path: str | os.PathLike, key: str = "trajectory.file") -> Trajectory:
    """Read a CSV trajectory: the header ``t,x,y,z,roll_deg,pitch_deg,yaw_deg``, then one pose a row.

    ``t`` in seconds (strictly increasing), position in metres (world frame), angles in degrees
    (DESIGN.md section 1). Blank lines and lines starting with ``#`` are skipped; spaces
    around values are allowed.

    Raises
    ------
    ConfigError
        ``key``, with the file and line: a missing or different header, a row without 7
        numbers, times not increasing, a directory or missing file, no rows.
    """
    p = Path(path)
    rows = _file_rows(p, key)
    header_line, header = rows[0]
    names = tuple(h.strip() for h in header.split(","))
    if names != CSV_HEADER:
        raise ConfigError(key, f"{p}: line {header_line}: the header must be exactly {','.join(CSV_HEADER)}, "
                          f"got {shown(header)}")
    if len(rows) == 1:
        raise ConfigError(key, f"{p}: the trajectory file has a header but no poses")
    values = np.array([_numbers(text.split(","), 7, p, line, key, " ".join(CSV_HEADER)) for line, text in rows[1:]])
    lines = [line for line, _ in rows[1:]]
    _check_rows(p, lines, values[:, 0], values[:, 1:4], key)
    angles = values[:, 4:7]
    big = np.flatnonzero(np.abs(angles).max(axis=1) > 720.0)
    if len(big):
        raise ConfigError(key, f"{p}: line {lines[int(big[0])]}: angles must lie within +-720 degrees")
    return Trajectory(values[:, 0], values[:, 1:4], _quats_from_rpy_deg(angles), angles)


def read_tum_trajectory(path: str | os.PathLike, key: str = "trajectory.file") -> Trajectory:
    """Read a TUM trajectory: ``t x y z qx qy qz qw`` per line (whitespace-separated).

    The quaternion is in ROS order (x, y, z, w), scalar last, and is normalised; ``#`` starts a
    comment line.

    Raises
    ------
    ConfigError
        ``key``, with the file and line: a row without 8 numbers, a zero quaternion, times not
        increasing, a directory or missing file, no rows.
    """
    p = Path(path)
    rows = _file_rows(p, key)
    values = np.array([_numbers(text.split(), 8, p, line, key, "t x y z qx qy qz qw") for line, text in rows])
    lines = [line for line, _ in rows]
    _check_rows(p, lines, values[:, 0], values[:, 1:4], key)
    quats, norms = _unit_quaternions(values[:, 4:8])
    zero = np.flatnonzero(~(norms > 1e-9))
    if len(zero):
        raise ConfigError(key, f"{p}: line {lines[int(zero[0])]}: the quaternion must not be zero")
    return Trajectory(values[:, 0], values[:, 1:4], quats)


def _unit_quaternions(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``q`` scaled to unit length, and their lengths, without overflow.

    Each row is divided by its largest magnitude before its length is taken: the squares of
    ``1e308`` overflow (a quaternion of four 1e308 was called zero). Rows of zeros stay zeros
    (length 0).
    """
    q = np.asarray(q, dtype=np.float64)
    big = np.abs(q).max(axis=1)
    safe = np.where(big > 0, big, 1.0)
    scaled = q / safe[:, None]
    length = np.sqrt(np.sum(scaled * scaled, axis=1))
    unit = scaled / np.where(length > 0, length, 1.0)[:, None]
    with np.errstate(over="ignore"):  # four 1e308 are 2e308 long: inf, still a direction
        return unit, big * length


def read_trajectory(path: str | os.PathLike, fmt: str | None = None, key: str = "trajectory.file") -> Trajectory:
    """Read a trajectory file, CSV or TUM.

    ``fmt`` ``None`` guesses: CSV when the name ends in ``.csv`` or the first line that is not a
    comment starts with ``t,``; TUM otherwise.
    """
    p = Path(path)
    if fmt is None:
        fmt = "csv"
        if p.suffix.lower() != ".csv":
            rows = _file_rows(p, key)
            fmt = "csv" if rows[0][1].replace(" ", "").startswith("t,") else "tum"
    return read_csv_trajectory(p, key) if fmt == "csv" else read_tum_trajectory(p, key)




#: The keys of an object's ``track`` (one of ``file``, ``keys``, ``velocity_m_s``).
TRACK_KEYS = ("file", "format", "keys", "repeat", "velocity_m_s", "yaw_rate_deg_s")


@dataclass(frozen=True, eq=False)
class Track:
    """An object's own path through the scene: its pose at any time of the scene's clock.

    Either timed poses (a :class:`Trajectory`: a file or ``keys``), interpolated between them
    and held at the ends (or, ``repeat``, run again from the start), or a constant velocity and
    yaw rate from the object's ``pose`` at time 0.

    Attributes
    ----------
    trajectory : Trajectory or None
        The timed poses (object-to-world), seconds of the scene's clock.
    repeat : bool
        Times wrap round the trajectory's span (a patrol that loops).
    velocity_m_s : (3,) tuple of float or None
        World-frame velocity from ``start`` (no trajectory), metres per second.
    yaw_rate_deg_s : float
        Turn about the world's z axis, degrees per second (with ``velocity_m_s``).
    start : Pose or None
        The pose at time 0 (with ``velocity_m_s``: the object's ``pose``).
    source : str or None
        The file the trajectory came from (said back in the scene-file form).
    """

    trajectory: Trajectory | None = None
    repeat: bool = False
    velocity_m_s: tuple[float, float, float] | None = None
    yaw_rate_deg_s: float = 0.0
    start: Pose | None = None
    source: str | None = None

    def __post_init__(self) -> None:
        if (self.trajectory is None) == (self.velocity_m_s is None):
            raise ConfigError("track", "give timed poses (file or keys) or a velocity_m_s, exactly one")
        if self.velocity_m_s is not None and self.start is None:
            object.__setattr__(self, "start", Pose())

    def time_in_span(self, t_s: np.ndarray) -> np.ndarray:
        """``t_s`` mapped into the trajectory's span (wrapped when ``repeat``)."""
        t = np.asarray(t_s, np.float64)
        tr = self.trajectory
        if tr is None or not self.repeat or tr.n_frames == 1:
            return t
        t0, span = tr.times_s[0], tr.times_s[-1] - tr.times_s[0]
        return t0 + np.mod(t - t0, span)

    def poses_at(self, times_s: Any) -> list[Pose]:
        """The object's poses at ``times_s`` (seconds of the scene's clock), object-to-world."""
        t = np.atleast_1d(np.asarray(times_s, np.float64))
        if self.trajectory is not None:
            return self.trajectory.at(self.time_in_span(t))
        from scipy.spatial.transform import Rotation

        start = self.start
        out = []
        turns = Rotation.from_euler("z", (self.yaw_rate_deg_s * t).reshape(-1, 1), degrees=True).as_matrix().reshape(-1, 3, 3)
        for tk, rz in zip(t, turns):
            m = np.eye(4)
            m[:3, :3] = rz @ start.rotation
            m[:3, 3] = start.translation + np.asarray(self.velocity_m_s) * tk
            out.append(Pose.from_matrix(m))
        return out

    def pose_at(self, t_s: float) -> Pose:
        """The object's pose at ``t_s`` seconds (object-to-world)."""
        if self.trajectory is not None:
            return self.trajectory.at(float(self.time_in_span(float(t_s))))[0]
        return self.poses_at(float(t_s))[0]

    def to_dict(self) -> dict:
        """The scene-file form."""
        if self.trajectory is None:
            return {"velocity_m_s": list(self.velocity_m_s), "yaw_rate_deg_s": self.yaw_rate_deg_s}
        out: dict = {"repeat": self.repeat} if self.repeat else {}
        if self.source is not None:
            return {"file": self.source, **out}
        tr = self.trajectory
        keys = [{"t": float(t), **Pose.from_quaternion(p, q).to_dict()}
                for t, p, q in zip(tr.times_s, tr.positions_m, tr.quats_xyzw)]
        return {"keys": keys, **out}
