"""A survey replayed in simulation: the vehicle's poses from a recording's logged geometry.

A recording's film (:mod:`sonarsim.image.films`) logs each ping's navigation and attitude
(:class:`~sonarsim.image.films.PingGeometry`). Rendering a scene ``--along`` it puts the vehicle,
ping by ping, where the recording says it was:

* horizontally at ``(x_m, y_m)`` relative to the first ping replayed (east, north: the scene's
  x, y), or at the scene's vehicle position where the recording logs no position;
* vertically at the logged ``altitude_m`` above the scene's ground (a recording's altitude is its
  height above the floor it saw), else ``depth_m`` below ``z = 0`` (the scene's surface);
* with the logged roll and pitch (REP-103) and the yaw of the logged heading (``90 - heading``;
  no heading logged: the scene's yaw).

Unknown values (NaN) fall back to the scene's vehicle pose, each field alone.
"""

from __future__ import annotations

import numpy as np

from ..core.transforms import Pose
from ..errors import ConfigError
from ..image.films import PingGeometry

__all__ = ["poses_from_geometry", "ping_slice"]


def ping_slice(n_pings: int, pings, source: str) -> range:
    """The pings ``A:B`` (a ``(A, B)`` pair, B exclusive) of a recording of ``n_pings``; ``None`` all.

    Raises
    ------
    ConfigError
        ``--pings``: outside the recording, naming its good pings.
    """
    if pings is None:
        return range(n_pings)
    lo, hi = (0, int(pings)) if isinstance(pings, int) else pings
    if not 0 <= lo < hi <= n_pings:
        raise ConfigError("--pings", f"{lo}:{hi} is outside {source}, which has pings 0:{n_pings}")
    return range(lo, hi)


def poses_from_geometry(scene, geometry: PingGeometry) -> list[Pose]:
    """The vehicle's pose (vehicle-to-world) at each ping of ``geometry`` in ``scene``.

    Parameters
    ----------
    scene : Scene
        Its ground (for altitudes) and its vehicle pose (for what the recording does not log).
    geometry : PingGeometry
        ``n`` pings.

    Returns
    -------
    list of Pose, ``n`` long.

    Raises
    ------
    ConfigError
        ``--along``: a ping with neither altitude (over a scene with a ground) nor depth.
    """
    base = scene.vehicle_pose if scene.instruments else scene.sonar_pose
    bx, by, bz = base.position_m
    broll, bpitch, byaw = base.rpy_deg
    n = len(geometry)
    x, y = geometry.x_m.copy(), geometry.y_m.copy()
    known = np.isfinite(x) & np.isfinite(y)
    if known.any():
        first = int(np.argmax(known))
        x, y = x - x[first] + bx, y - y[first] + by
    x = np.where(np.isfinite(x), x, bx)
    y = np.where(np.isfinite(y), y, by)
    ground = scene.ground
    if ground is not None:
        z = ground.height_m + geometry.altitude_m
        z = np.where(np.isfinite(z), z, -geometry.depth_m)
    else:
        z = -geometry.depth_m
    bad = ~np.isfinite(z)
    if bad.any():
        k = int(np.argmax(bad))
        raise ConfigError("--along", f"ping {k} logs neither an altitude (over the scene's ground) nor a depth: "
                          "nowhere to put the vehicle")
    roll = np.where(np.isfinite(geometry.roll_deg), geometry.roll_deg, broll)
    pitch = np.where(np.isfinite(geometry.pitch_deg), geometry.pitch_deg, bpitch)
    yaw = np.where(np.isfinite(geometry.heading_deg), 90.0 - geometry.heading_deg, byaw)
    return [Pose((float(x[i]), float(y[i]), float(z[i])), (float(roll[i]), float(pitch[i]), float(yaw[i])))
            for i in range(n)]
