"""Sonar trajectories for datasets: poses read from files or generated, one per ping.

A trajectory is a sequence of timestamped sonar poses (sonar-to-world, DESIGN.md section 1:
``R = Rz(yaw) Ry(pitch) Rx(roll)``, x forward, positive pitch looks down). Sources:

- files: CSV with the header ``t,x,y,z,roll_deg,pitch_deg,yaw_deg``, or TUM
  (``t x y z qx qy qz qw`` per line, quaternion in ROS order x, y, z, w; ``#`` comments);
  optionally resampled to a ping rate (linear in position, slerp in orientation);
- generators: a lawnmower survey, an orbit looking at a point, random poses within bounds
  looking at a target point or region (with a pitch/yaw jitter).

File and generated trajectories are arrays (:class:`Trajectory`); random poses are drawn per
frame (:class:`RandomPoses`) from the frame's own generator, so that no frame depends on another.
Both answer ``n_frames``, ``time_s(k)`` and ``pose(k, rng)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..config.loader import _check_keys, _integer, _number, _string, _vector
from ..config.scene import MAX_COORDINATE_M
from ..config.tracks import (  # noqa: F401  (re-exported: their home before objects had tracks)
    _BYTES_PER_POSE, CSV_HEADER, RATE_RANGE_HZ, Trajectory, _check_rate, _quats_from_rpy_deg, _unit_quaternions,
    read_csv_trajectory, read_trajectory, read_tum_trajectory,
)
from ..core.memory import require
from ..core.transforms import Pose
from ..errors import ConfigError, shown

__all__ = [
    "CSV_HEADER", "TRAJECTORY_KEYS", "GENERATORS", "PoseSource", "RandomPoses", "Trajectory", "look_at", "look_at_rpy_deg",
    "lawnmower", "orbit", "parse_trajectory", "read_csv_trajectory", "read_trajectory", "read_tum_trajectory",
]

#: The header a CSV trajectory must start with (exactly these columns, in this order).
TRAJECTORY_KEYS = ("file", "format", "rate_hz", "generate")
FORMATS = ("csv", "tum")
GENERATORS = ("lawnmower", "orbit", "random")
GENERATE_KEYS = {
    "lawnmower": ("kind", "area_m", "spacing_m", "z_m", "speed_m_s", "pitch_deg", "legs_along"),
    "orbit": ("kind", "centre_m", "radius_m", "z_m", "frames", "start_deg", "sweep_deg", "roll_deg"),
    "random": ("kind", "frames", "bounds_m", "look_at_m", "look_at_bounds_m", "jitter_deg", "roll_deg"),
}
# Random poses redraw a position that coincides with its target (no direction to look along).
_MAX_REDRAWS = 100
#: The fastest survey, m/s: no vehicle a sonar rides goes faster (1e300 m/s was accepted).
MAX_SPEED_M_S = 100.0
#: The smallest orbit radius, metres: below it the poses are one point turning on the spot (an
#: orbit of 1e-12 m put the sonar on its own target). The scene's sonar adds its own floor: the
#: centre must lie beyond its ``range_min_m`` (:func:`orbit_radius_range`).
MIN_ORBIT_RADIUS_M = 1e-3


# Orientation helpers --------------------------------------------------------------------

def look_at_rpy_deg(position_m: Any, target_m: Any, roll_deg: float = 0.0) -> tuple[float, float, float]:
    """Roll, pitch, yaw (degrees) that point the sonar's x axis from ``position_m`` at ``target_m``.

    Parameters
    ----------
    position_m, target_m : (3,) array_like, metres, world frame
    roll_deg : float
        Roll about the acoustic axis (0: the fan plane contains the horizontal).

    Returns
    -------
    (roll, pitch, yaw) : tuple of float, degrees
        ``yaw = atan2(dy, dx)``; ``pitch = atan2(-dz, hypot(dx, dy))``: positive when the
        target lies below (positive pitch looks down). A target straight above or below gives
        pitch -90 / 90 and yaw 0.

    Raises
    ------
    ValueError
        The two points coincide (no direction to look along).
    """
    d = np.asarray(target_m, dtype=float) - np.asarray(position_m, dtype=float)
    horizontal = math.hypot(d[0], d[1])
    if horizontal == 0.0 and d[2] == 0.0:
        raise ValueError("look-at target coincides with the position")
    yaw = math.degrees(math.atan2(d[1], d[0])) if horizontal > 0 else 0.0
    pitch = math.degrees(math.atan2(-d[2], horizontal))
    return float(roll_deg), pitch, yaw


def look_at(position_m: Any, target_m: Any, roll_deg: float = 0.0) -> Pose:
    """The sonar pose at ``position_m`` whose acoustic axis (x) points at ``target_m``.

    See :func:`look_at_rpy_deg` for the angles.
    """
    return Pose(tuple(float(v) for v in position_m), look_at_rpy_deg(position_m, target_m, roll_deg))


# Trajectories ---------------------------------------------------------------------------

class PoseSource(Protocol):
    """What a scenario needs of a trajectory: frame count, timestamps and poses by frame index."""

    @property
    def n_frames(self) -> int: ...

    def time_s(self, k: int) -> float: ...

    def pose(self, k: int, rng: np.random.Generator | None = None) -> Pose: ...


@dataclass(frozen=True)
class RandomPoses:
    """Poses drawn per frame: positions uniform in a box, looking at a target point or region.

    Frame ``k``'s pose comes from that frame's generator only (see :meth:`pose`), so any frame
    can be drawn alone, in any order, by any process.

    Attributes
    ----------
    frames : int
        Number of frames.
    bounds_m : ((3,), (3,)) tuple of float
        Lower and upper corners of the box the positions are drawn from (uniform), metres.
    target_bounds_m : ((3,), (3,)) tuple of float
        Lower and upper corners of the target region (equal corners: a target point).
    jitter_deg : (2,) tuple of float
        Half-widths of the uniform jitter added to the look-at pitch and yaw, degrees (>= 0).
    roll_deg : float
        Roll of every pose, degrees.
    rate_hz : float
        Ping rate: frame ``k`` is at time ``k / rate_hz``.
    """

    frames: int
    bounds_m: tuple[tuple[float, float, float], tuple[float, float, float]]
    target_bounds_m: tuple[tuple[float, float, float], tuple[float, float, float]]
    jitter_deg: tuple[float, float] = (0.0, 0.0)
    roll_deg: float = 0.0
    rate_hz: float = 1.0

    @property
    def n_frames(self) -> int:
        return self.frames

    def time_s(self, k: int) -> float:
        return k / self.rate_hz

    def pose(self, k: int, rng: np.random.Generator | None = None) -> Pose:
        """Draw frame ``k``'s pose from ``rng`` (the frame's generator; required).

        Draws, in this order: position (3 uniforms), target (3 uniforms), pitch and yaw jitter
        (2 uniforms in [-1, 1] scaled by ``jitter_deg``); a position that coincides with its
        target is drawn again.
        """
        if rng is None:
            raise ValueError("random poses need the frame's generator")
        lo, hi = np.array(self.bounds_m[0]), np.array(self.bounds_m[1])
        tlo, thi = np.array(self.target_bounds_m[0]), np.array(self.target_bounds_m[1])
        for _ in range(_MAX_REDRAWS):
            position = rng.uniform(lo, hi)
            target = rng.uniform(tlo, thi)
            jitter = rng.uniform(-1.0, 1.0, 2) * np.asarray(self.jitter_deg)
            if np.linalg.norm(target - position) > 1e-6:
                roll, pitch, yaw = look_at_rpy_deg(position, target, self.roll_deg)
                return Pose(tuple(float(v) for v in position), (roll, pitch + float(jitter[0]), yaw + float(jitter[1])))
        raise ConfigError("trajectory.generate.look_at_bounds_m", "the positions keep coinciding with their targets")


# Generators -----------------------------------------------------------------------------

def orbit(centre_m: Any, radius_m: float, z_m: float, frames: int, rate_hz: float = 1.0, start_deg: float = 0.0,
          sweep_deg: float = 360.0, roll_deg: float = 0.0) -> Trajectory:
    """Poses on a horizontal circle around ``centre_m``, each looking at ``centre_m``.

    Parameters
    ----------
    centre_m : (3,) array_like, metres
        The point orbited and looked at.
    radius_m : float
        Horizontal distance from the centre, > 0.
    z_m : float
        World height of the sonar, metres.
    frames : int
        Number of poses, >= 1.
    rate_hz : float
        Ping rate: pose ``i`` at time ``i / rate_hz``.
    start_deg, sweep_deg : float
        Angle of the first position around the centre (0: on the +x side, 90: on the +y side)
        and the angle swept, counter-clockwise when positive. A full turn (|sweep| = 360)
        spaces the frames by sweep / frames (the last does not repeat the first); a partial
        sweep includes both ends.
    roll_deg : float
        Roll of every pose.

    Returns
    -------
    Trajectory
        Pose ``i`` at ``centre + radius (cos a_i, sin a_i)`` and height ``z_m``, yaw
        ``a_i + 180`` degrees (facing the centre), pitch looking at the centre's height.
    """
    centre = np.asarray(centre_m, dtype=float)
    full = abs(abs(sweep_deg) - 360.0) < 1e-9
    steps = frames if full else max(frames - 1, 1)
    a = np.radians(start_deg + sweep_deg * np.arange(frames) / steps)
    positions = np.column_stack([centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a),
                                 np.full(frames, float(z_m))])
    rpy = np.array([look_at_rpy_deg(p, centre, roll_deg) for p in positions])
    return Trajectory(np.arange(frames) / rate_hz, positions, _quats_from_rpy_deg(rpy), rpy)


def orbit_radius_range(centre_m: Any, z_m: float, range_min_m: float = 0.0) -> tuple[float, float]:
    """The radii an orbit around ``centre_m`` at height ``z_m`` may have.

    Parameters
    ----------
    centre_m : (3,) array_like, metres
    z_m : float
        The sonar's height, metres.
    range_min_m : float
        The sonar's nearest range: the centre, which every pose looks at, must be at least this
        far from the sonar (nearer, it lies in the blind zone before the range window).

    Returns
    -------
    (lo, hi) : tuple of float, metres
        ``lo``: :data:`MIN_ORBIT_RADIUS_M`, or more where the height difference alone leaves the
        centre within ``range_min_m``; ``hi``: every position within ``MAX_COORDINATE_M`` of the
        origin (an orbit of 1e7 m rendered empty frames from beyond the scene).
    """
    c = np.asarray(centre_m, dtype=float)
    dz = float(z_m) - float(c[2])
    lo = max(MIN_ORBIT_RADIUS_M, math.sqrt(max(float(range_min_m) ** 2 - dz * dz, 0.0)))
    hi = MAX_COORDINATE_M - max(abs(float(c[0])), abs(float(c[1])))
    return lo, hi


def lawnmower(area_m: Any, spacing_m: float, z_m: float, speed_m_s: float, rate_hz: float, pitch_deg: float = 0.0,
              legs_along: str = "x", key: str = "trajectory.generate") -> Trajectory:
    """A lawnmower (boustrophedon) survey of a rectangle, sampled at a ping rate.

    Legs run parallel to the x axis (``legs_along='x'``) or the y axis, from the first corner of
    ``area_m`` towards the second: the first leg starts at ``area_m[0]``, the legs are
    ``spacing_m`` apart (the last within the area), and each turn is a straight crossing of
    ``spacing_m`` at the end of a leg. The sonar looks along its direction of motion (yaw of
    the leg or crossing it is on; at a corner it already faces the next segment), pitched by
    ``pitch_deg`` (positive: down), at constant speed.

    Parameters
    ----------
    area_m : ((2,), (2,)) array_like
        Start corner ``(x0, y0)`` and opposite corner ``(x1, y1)``, metres.
    spacing_m : float
        Distance between legs, > 0.
    z_m : float
        World height of the sonar, metres.
    speed_m_s, rate_hz : float
        Speed along the path and ping rate (> 0): pose ``i`` is ``i * speed / rate`` metres
        along the path, at time ``i / rate``.
    pitch_deg : float
    legs_along : {'x', 'y'}
    key : str
        Key named in errors.

    Returns
    -------
    Trajectory

    Raises
    ------
    ConfigError
        Too many legs or poses for the memory budget.
    """
    (x0, y0), (x1, y1) = np.asarray(area_m, dtype=float)
    along = (x0, x1) if legs_along == "x" else (y0, y1)
    across = (y0, y1) if legs_along == "x" else (x0, x1)
    width = abs(across[1] - across[0])
    n_legs_float = math.floor(width / spacing_m + 1e-9) + 1
    require(n_legs_float * 2 * 3 * 8 * 4, f"{n_legs_float:.3g} legs {spacing_m:g} m apart", f"{key}.spacing_m")
    n_legs = int(n_legs_float)
    sign = 1.0 if across[1] >= across[0] else -1.0
    offsets = across[0] + sign * spacing_m * np.arange(n_legs)
    ends = np.where(np.arange(n_legs) % 2 == 0, along[1], along[0])
    starts = np.where(np.arange(n_legs) % 2 == 0, along[0], along[1])
    # Waypoints (along, across): start and end of each leg; consecutive legs joined by a crossing.
    a_coord = np.column_stack([starts, ends]).ravel()
    c_coord = np.repeat(offsets, 2)
    xy = np.column_stack([a_coord, c_coord]) if legs_along == "x" else np.column_stack([c_coord, a_coord])
    seg = np.diff(xy, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    keep = length > 0  # a zero-length leg (area of zero width along the legs) has no heading
    if not keep.any():
        raise ConfigError(f"{key}.area_m", "the area has no extent to survey (its corners coincide)")
    xy = np.vstack([xy[:1], xy[1:][keep]])
    seg, length = seg[keep], length[keep]
    cum = np.concatenate([[0.0], np.cumsum(length)])
    total = float(cum[-1])
    n_float = math.floor(total / speed_m_s * rate_hz * (1 + 1e-12) + 1e-9) + 1
    require(n_float * _BYTES_PER_POSE, f"{n_float:.3g} poses over {total:g} m at {speed_m_s:g} m/s and {rate_hz:g} Hz",
            f"{key}.speed_m_s")
    n = int(n_float)
    s = np.minimum(np.arange(n) * (speed_m_s / rate_hz), total)
    x = np.interp(s, cum, xy[:, 0])
    y = np.interp(s, cum, xy[:, 1])
    which = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    yaw = np.degrees(np.arctan2(seg[which, 1], seg[which, 0]))
    rpy = np.column_stack([np.zeros(n), np.full(n, float(pitch_deg)), yaw])
    positions = np.column_stack([x, y, np.full(n, float(z_m))])
    return Trajectory(np.arange(n) / rate_hz, positions, _quats_from_rpy_deg(rpy), rpy)


# The scenario's ``trajectory`` section --------------------------------------------------

def _positive(value: Any, key: str) -> float:
    v = _number(value, key)
    if v <= 0:
        raise ConfigError(key, f"must be > 0, got {shown(value)}")
    return v


def _speed(value: Any, key: str) -> float:
    v = _positive(value, key)
    if v > MAX_SPEED_M_S:
        raise ConfigError(key, f"must be within (0, {MAX_SPEED_M_S:g}] m/s, got {shown(value)}")
    return v


def _corners(value: Any, key: str, n: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(key, f"must be two corners [[{', '.join('lo' for _ in range(n))}], "
                          f"[{', '.join('hi' for _ in range(n))}]], got {shown(value)}")
    lo = _vector(value[0], f"{key}[0]", n)
    hi = _vector(value[1], f"{key}[1]", n)
    for v in (*lo, *hi):
        if abs(v) > MAX_COORDINATE_M:
            raise ConfigError(key, f"must lie within {MAX_COORDINATE_M:g} m of the origin, got {shown(value)}")
    return lo, hi


def _frames(d: Mapping, key: str) -> int:
    if "frames" not in d:
        raise ConfigError(f"{key}.frames", "required: the number of frames to generate")
    n = _integer(d["frames"], f"{key}.frames")
    if n < 1:
        raise ConfigError(f"{key}.frames", f"must be at least 1, got {n}")
    require(n * _BYTES_PER_POSE, f"{n} poses", f"{key}.frames")
    return n


def _angle(d: Mapping, name: str, key: str, default: float = 0.0) -> float:
    v = _number(d.get(name, default), f"{key}.{name}")
    if abs(v) > 720.0:
        raise ConfigError(f"{key}.{name}", f"must lie within +-720 degrees, got {shown(v)}")
    return v


def _coordinate(d: Mapping, name: str, key: str) -> float:
    if name not in d:
        raise ConfigError(f"{key}.{name}", "required")
    v = _number(d[name], f"{key}.{name}")
    if abs(v) > MAX_COORDINATE_M:
        raise ConfigError(f"{key}.{name}", f"must lie within {MAX_COORDINATE_M:g} m of the origin, got {shown(v)}")
    return v


def _required(d: Mapping, name: str, key: str) -> Any:
    if name not in d:
        raise ConfigError(f"{key}.{name}", "required")
    return d[name]


def _parse_generate(d: Any, rate_hz: float | None, key: str = "trajectory.generate",
                    range_min_m: float = 0.0) -> PoseSource:
    if not isinstance(d, Mapping):
        raise ConfigError(key, f"must be a mapping with a `kind` ({', '.join(GENERATORS)}), got {shown(d)}")
    kind = _string(_required(d, "kind", key), f"{key}.kind")
    if kind not in GENERATORS:
        raise ConfigError(f"{key}.kind", f"unknown generator {shown(kind)}; allowed: {', '.join(GENERATORS)}")
    _check_keys(d, GENERATE_KEYS[kind], key)
    if kind == "orbit":
        centre = _vector(_required(d, "centre_m", key), f"{key}.centre_m", 3)
        if max(abs(v) for v in centre) > MAX_COORDINATE_M:  # 1e300 ended in "look-at target coincides"
            raise ConfigError(f"{key}.centre_m", f"must lie within {MAX_COORDINATE_M:g} m of the origin, "
                              f"got {list(centre)}")
        sweep = _angle(d, "sweep_deg", key, 360.0)
        if sweep == 0 or abs(sweep) > 360.0:
            raise ConfigError(f"{key}.sweep_deg", f"must be non-zero and within +-360 degrees, got {sweep:g}")
        radius = _number(_required(d, "radius_m", key), f"{key}.radius_m")
        z = _coordinate(d, "z_m", key)
        lo, hi = orbit_radius_range(centre, z, range_min_m)
        if not lo <= radius <= hi:
            if radius > hi:
                why = f"the orbit must stay within {MAX_COORDINATE_M:g} m of the origin"
            elif lo > MIN_ORBIT_RADIUS_M:
                why = (f"nearer, the centre every pose looks at lies within the sonar's range_min_m "
                       f"({range_min_m:g} m), in its blind zone")
            else:
                why = f"below {MIN_ORBIT_RADIUS_M:g} m the sonar sits on its own target"
            raise ConfigError(f"{key}.radius_m", f"must be within [{lo:.4g}, {hi:.7g}] m: {why}; got {shown(radius)}")
        return orbit(centre, radius, z, _frames(d, key), rate_hz or 1.0, _angle(d, "start_deg", key), sweep,
                     _angle(d, "roll_deg", key))
    if kind == "lawnmower":
        if rate_hz is None:
            raise ConfigError("trajectory.rate_hz", "required with a lawnmower: the ping rate that, with the speed, "
                              "spaces the poses along the path")
        legs_along = _string(d.get("legs_along", "x"), f"{key}.legs_along")
        if legs_along not in ("x", "y"):
            raise ConfigError(f"{key}.legs_along", f"must be 'x' or 'y', got {shown(legs_along)}")
        area = _corners(_required(d, "area_m", key), f"{key}.area_m", 2)
        return lawnmower(area, _positive(_required(d, "spacing_m", key), f"{key}.spacing_m"), _coordinate(d, "z_m", key),
                         _speed(_required(d, "speed_m_s", key), f"{key}.speed_m_s"), rate_hz,
                         _angle(d, "pitch_deg", key), legs_along, key)
    # random
    frames = _integer(_required(d, "frames", key), f"{key}.frames")
    if frames < 1:
        raise ConfigError(f"{key}.frames", f"must be at least 1, got {frames}")
    bounds = _corners(_required(d, "bounds_m", key), f"{key}.bounds_m", 3)
    if ("look_at_m" in d) == ("look_at_bounds_m" in d):
        raise ConfigError(f"{key}.look_at_m", "give exactly one of look_at_m (a point) and look_at_bounds_m (a box)")
    if "look_at_m" in d:
        point = _vector(d["look_at_m"], f"{key}.look_at_m", 3)
        if max(abs(v) for v in point) > MAX_COORDINATE_M:  # as look_at_bounds_m (1e300 was accepted)
            raise ConfigError(f"{key}.look_at_m", f"must lie within {MAX_COORDINATE_M:g} m of the origin, "
                              f"got {list(point)}")
        target = (point, point)
    else:
        target = _corners(d["look_at_bounds_m"], f"{key}.look_at_bounds_m", 3)
    for name, (lo, hi) in (("bounds_m", bounds), ("look_at_bounds_m", target)):
        if any(a > b for a, b in zip(lo, hi)):
            raise ConfigError(f"{key}.{name}", f"the first corner must be the lower one on every axis, got {[lo, hi]}")
    jitter = _vector(d.get("jitter_deg", [0.0, 0.0]), f"{key}.jitter_deg", 2)
    if any(not 0 <= j <= 180 for j in jitter):
        raise ConfigError(f"{key}.jitter_deg", f"pitch and yaw jitter must lie in [0, 180] degrees, got {list(jitter)}")
    return RandomPoses(frames, bounds, target, jitter, _angle(d, "roll_deg", key), rate_hz or 1.0)


def parse_trajectory(d: Any, base_dir: Path | None, range_min_m: float = 0.0) -> PoseSource:
    """The scenario's ``trajectory`` section.

    Keys: ``file`` (CSV or TUM; relative to ``base_dir``) with an optional ``format``
    (``csv`` | ``tum``; guessed otherwise), or ``generate`` (a mapping with ``kind``:
    ``lawnmower`` | ``orbit`` | ``random``); ``rate_hz`` resamples a file's poses to that ping
    rate (optional), and is the ping rate of the generators (required for ``lawnmower``,
    1 Hz by default for the others).

    Parameters
    ----------
    d : mapping
        The section.
    base_dir : Path or None
        Folder a relative ``file`` is relative to.
    range_min_m : float
        The scene's sonar's nearest range: an orbit's centre must lie at least this far from
        the sonar (:func:`orbit_radius_range`).
    """
    _check_keys(d, TRAJECTORY_KEYS, "trajectory")
    if ("file" in d) == ("generate" in d):
        raise ConfigError("trajectory", "give exactly one of `file` (a CSV or TUM trajectory) and `generate`")
    rate_hz = None
    if "rate_hz" in d:
        rate_hz = _check_rate(_number(d["rate_hz"], "trajectory.rate_hz"), "trajectory.rate_hz")
    if "generate" in d:
        if "format" in d:
            raise ConfigError("trajectory.format", "only with `file`")
        return _parse_generate(d["generate"], rate_hz, range_min_m=range_min_m)
    path = Path(_string(d["file"], "trajectory.file"))
    if base_dir is not None and not path.is_absolute():
        path = base_dir / path
    fmt = None
    if "format" in d:
        fmt = _string(d["format"], "trajectory.format")
        if fmt not in FORMATS:
            raise ConfigError("trajectory.format", f"unknown format {shown(fmt)}; allowed: {', '.join(FORMATS)}")
    trajectory = read_trajectory(path, fmt)
    return trajectory.resampled(rate_hz) if rate_hz is not None else trajectory

