"""Every sonar a robot carries, on one engine: the instruments and how each pings.

An instrument (:class:`~sonarsim.config.instruments.InstrumentSpec`) is a mount on the vehicle,
one or more channels (fans of rays) and a film. Each ping of a channel is one frame of the
engine: :meth:`Simulator.trace` (the scene's surfaces, the channel's fan, its pose in the world
-> the frame's paths, :mod:`sonarsim.paths.buffer`), then :meth:`Simulator.form` (paths -> the
channel's image on its range x beam grid, components and labels). The instrument stacks its
channels' images into its film (:mod:`sonarsim.image.films`) and applies its sensor chain there.

Types register themselves by name: a module here defines its configuration class (registered
with :func:`sonarsim.config.instruments.register`) and its renderer (registered with
:func:`renders`). A scene that names a type imports its module (see
:func:`sonarsim.config.instruments.instrument_class`).

Examples
--------
>>> from sonarsim import Simulator                            # doctest: +SKIP
>>> from sonarsim.instruments import render_pings              # doctest: +SKIP
>>> sim = Simulator("survey.yaml")                           # doctest: +SKIP
>>> waterfall = render_pings(sim, "sss", n_pings=200)          # doctest: +SKIP
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..config.instruments import FlsSpec, InstrumentSpec, instrument_class, mounted
from ..core.transforms import Pose
from ..errors import ConfigError, shown

__all__ = ["RENDERERS", "renders", "render_pings", "instrument", "vehicle_poses", "pose_frames"]

#: The most rays one frame of several pings casts (:func:`pose_frames`): a side-scan side of
#: 1,024 rays batches 128 pings, a dense one of 16,384 rays 8 (about 600 bytes a ray: 80 MB).
BATCH_RAYS = 1 << 17

#: Type name -> ``render(sim, spec, poses, times_s, first_ping, speckle, labels) -> film``.
RENDERERS: dict[str, Callable] = {}


def renders(type_name: str) -> Callable:
    """Decorator: the renderer of an instrument type."""
    def wrap(fn: Callable) -> Callable:
        RENDERERS[type_name] = fn
        return fn
    return wrap


def instrument(sim, name: str | None = None) -> InstrumentSpec:
    """The scene's instrument called ``name`` (default: the first); a scene with only a
    ``sonar:`` section has one, its FLS, called ``sonar``.

    Raises
    ------
    ConfigError
        ``instrument``: no such name, with the names the scene has.
    """
    specs = sim.scene.instruments or (FlsSpec(name="sonar", sonar=sim.scene.sonar),)
    if name is None:
        return specs[0]
    for s in specs:
        if s.name == name:
            return s
    raise ConfigError("instrument", f"no instrument {shown(name)} in the scene; it has: "
                      f"{', '.join(s.name for s in specs)}")


def vehicle_poses(sim, spec: InstrumentSpec, n_pings: int | None = None, trajectory=None,
                  times_s: np.ndarray | None = None) -> tuple[list[Pose], np.ndarray]:
    """The vehicle's pose at each of an instrument's pings.

    Parameters
    ----------
    sim : Simulator
    spec : InstrumentSpec
    n_pings : int, optional
        Pings at the instrument's ping period from the trajectory's start (or, without a
        trajectory, from the scene's vehicle pose, running ahead at ``vehicle.speed_m_s``).
    trajectory : sonarsim.dataset.trajectory.Trajectory, optional
        The vehicle's timestamped poses: each ping's pose is interpolated at its own time
        (positions linearly, attitudes by slerp), so a moving vehicle moves between pings.
    times_s : (n,) array, optional
        The pings' times instead of ``n_pings`` (within the trajectory's span).

    Returns
    -------
    poses : list of Pose
        Vehicle-to-world, one per ping.
    times_s : (n,) float64 ndarray
    """
    period = spec.ping_period_s()
    if times_s is None:
        if n_pings is None:
            n_pings = 1 if trajectory is None else max(1, int(np.floor(
                (trajectory.times_s[-1] - trajectory.times_s[0]) / period + 1e-9)) + 1)
        t0 = 0.0 if trajectory is None else float(trajectory.times_s[0])
        times_s = t0 + period * np.arange(int(n_pings))
    times_s = np.asarray(times_s, np.float64)
    if trajectory is None:
        pose = sim.scene.vehicle_pose if sim.scene.instruments else sim.scene.sonar_pose
        speed = sim.scene.vehicle_speed_m_s
        if not speed:
            return [pose] * len(times_s), times_s
        # straight ahead along the vehicle's x axis (vehicle.speed_m_s)
        forward = pose.rotation[:, 0]
        return [pose.moved(speed * t * forward) for t in times_s], times_s
    return poses_at(trajectory, times_s), times_s


def poses_at(trajectory, times_s: np.ndarray) -> list[Pose]:
    """A trajectory's poses at ``times_s`` (clipped to its span): positions interpolated
    linearly, orientations by slerp (:meth:`~sonarsim.config.tracks.Trajectory.at`)."""
    return trajectory.at(times_s)


def render_pings(sim, name: str | None = None, n_pings: int | None = None, trajectory=None,
                 times_s: np.ndarray | None = None, poses: list | None = None, first_ping: int = 0,
                 speckle: bool | None = None, labels: bool = False) -> Any:
    """Render an instrument's pings into its film.

    Parameters
    ----------
    sim : Simulator
        The scene, built once.
    name : str, optional
        The instrument (default the scene's first).
    n_pings, trajectory, times_s
        When the pings happen and where the vehicle is then (:func:`vehicle_poses`).
    poses : list of Pose, optional
        The vehicle's pose at each ping instead (with ``times_s``, or at the ping period).
    first_ping : int
        Index of the first ping: ping ``k``'s random draws come from ``(render.seed, k)``,
        whoever renders it.
    speckle : bool, optional
        ``False``: the expected film (no random draws).
    labels : bool
        Attach the ground truth per sample (the film's type says which).

    Returns
    -------
    The instrument's film: a :class:`~sonarsim.image.films.Waterfall` (side-scan), ...
    """
    spec = instrument(sim, name)
    instrument_class(spec.type_name, "instrument.type")  # the type's module, and so its renderer
    if spec.type_name not in RENDERERS:
        import importlib

        importlib.import_module(f"sonarsim.instruments.{spec.type_name}")
    if poses is None:
        poses, times_s = vehicle_poses(sim, spec, n_pings, trajectory, times_s)
    elif times_s is None:
        times_s = spec.ping_period_s() * np.arange(len(poses))
    return RENDERERS[spec.type_name](sim, spec, list(poses), np.asarray(times_s, np.float64), first_ping,
                                     speckle, labels)


def ping_geometry(sim, vehicle_poses: list[Pose], times_s: np.ndarray, spec):
    """What a recording would log of rendered pings: the instrument's height above the ground,
    the vehicle's attitude and heading (``heading = 90 - yaw``), position, speed, the sound speed
    and the range window (``spec``'s)."""
    from ..image.films import PingGeometry

    n = len(vehicle_poses)
    at = np.array([mounted(v, spec.mount).position_m for v in vehicle_poses], np.float64).reshape(n, 3)
    rpy = np.array([v.rpy_deg for v in vehicle_poses], np.float64).reshape(n, 3)
    ground = sim.scene.ground
    altitude = at[:, 2] - ground.height_m if ground is not None else np.full(n, np.nan)
    speed = np.full(n, np.nan)
    if n > 1:
        step = np.linalg.norm(np.diff(at[:, :2], axis=0), axis=1) / np.maximum(np.diff(times_s), 1e-12)
        speed = np.concatenate([step[:1], step])
    return PingGeometry.of(
        n, time_s=times_s, altitude_m=altitude, roll_deg=rpy[:, 0], pitch_deg=rpy[:, 1],
        heading_deg=np.mod(90.0 - rpy[:, 2], 360.0), heave_m=0.0, sound_speed_m_s=spec.sound_speed_m_s,
        range_min_m=spec.range_min_m, range_max_m=spec.range_max_m, x_m=at[:, 0], y_m=at[:, 1], speed_m_s=speed,
    )


def channel_pose(vehicle: Pose, channel) -> Pose:
    """A channel's pose in the world for the vehicle at ``vehicle``."""
    return mounted(vehicle, channel.mount)


def pose_frames(sim, poses: list[Pose], sonar, fan, labels: bool | str = False, times_s=None):
    """Frames of consecutive poses of one channel, formed without a sensor: as many poses in one
    frame as :data:`BATCH_RAYS` allows where the scene lets one frame hold several
    (:meth:`Simulator.trace_poses`: direct paths), else a frame per pose (the same bits).

    With ``times_s`` (one per pose, seconds) and objects on tracks, the objects are moved to
    each pose's time first (:meth:`Simulator.at_time`), and only poses of one time share a frame.

    Yields
    ------
    start, stop : int
        The poses ``poses[start:stop]`` the frame holds.
    paths : FramePaths
        Its paths (``paths.poses`` the poses where several).
    image : SonarImage
        Its image, components and labels, pose ``start + j``'s in the columns ``j n_beams`` to
        ``(j + 1) n_beams``: the expected echo (no sensor: :meth:`Simulator.sense` takes each
        pose's share through its chain with its own frame's draws).
    """
    per = max(1, BATCH_RAYS // max(fan.n_rays, 1))
    runs = [(0, len(poses))]
    if times_s is not None and getattr(sim, "tracked", ()):
        t = np.asarray(times_s, np.float64)
        cuts = np.flatnonzero(np.diff(t) != 0) + 1  # runs of one time: a moment of the world
        edges = [0, *cuts.tolist(), len(poses)]
        runs = list(zip(edges[:-1], edges[1:]))
    for first, last in runs:
        if times_s is not None and getattr(sim, "tracked", ()):
            sim.at_time(float(times_s[first]))
        yield from _pose_batches(sim, poses, sonar, fan, labels, per, first, last)


def _pose_batches(sim, poses, sonar, fan, labels, per: int, first: int, last: int):
    """:func:`pose_frames` over ``poses[first:last]`` (one moment of the world)."""
    for start in range(first, last, per):
        stop = min(last, start + per)
        paths = sim.trace_poses(poses[start:stop], sonar=sonar, labels=labels, fan=fan) if stop - start > 1 else None
        if paths is not None:
            yield start, stop, paths, sim.form(paths, keep_rays=False, speckle=False, sensor=False)
            continue
        # One frame cannot hold them (multipath, say): the batch's poses one by one, asked once
        for k in range(start, stop):
            paths = sim.trace(poses[k], sonar=sonar, labels=labels, fan=fan)
            yield k, k + 1, paths, sim.form(paths, keep_rays=False, speckle=False, sensor=False)
