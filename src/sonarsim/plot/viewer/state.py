"""The viewer's state and work, without a browser: poses and switches, re-rendering, saving.

:class:`SceneSession` holds a scene with the sonar's and the objects' current poses and the
switches of the image (component, bounces, sensor, speckle, colours); :meth:`SceneSession.render`
renders the current state into a :class:`ViewFrame` (the coloured polar and fan images the page
shows); :meth:`SceneSession.save` writes the scene file with the current poses and the images.
:class:`RecordingSession` does the same for the frames of a real recording. The viser page
(:mod:`sonarsim.plot.viewer.app`) only forwards its controls to these classes, so that all of
this is tested without a browser.

A scene whose sonars ride a vehicle (``instruments:``, or ``sonar:`` of another type than the
FLS) is moved by its vehicle (:meth:`SceneSession.set_vehicle_pose`): every instrument's mount
follows it. The live images are those of its first FLS, at its mount; the films of the other
types (a side-scan's waterfall, a multibeam's soundings, ...) are pings along a track that
``sonarsim render`` writes, and the page names them with that command.

Images are rendered with ``frame=0``: a frame's random draws (speckle, noise) then depend on the
scene and the pose alone, the picture does not flicker while nothing moves, and the saved scene
renders the same image (``sonarsim render scene.yaml --frame 0``).
"""

from __future__ import annotations

import functools
import math
import os
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ...config.loader import load_scene
from ...config.scene import MAX_ORDER_LIMIT, Scene
from ...core.transforms import Pose
from ...errors import ConfigError, SonarsimError
from ...image.fan import FanMapper
from ...image.grid import PolarGrid
from ..style import DEFAULT_COLORMAP, colorize, colormap_lut

__all__ = ["DisplayMapper", "RecordingOptions", "RecordingSession", "SAVED_FILES", "SceneSession", "ViewFrame",
           "ViewOptions", "component_names", "rpy_from_wxyz", "wxyz_of"]

#: The files :meth:`SceneSession.save` writes into its folder (and the run record).
SAVED_FILES = ("scene.yaml", "polar.png", "fan.png")
#: The time slider's reach where a track runs on at a constant velocity (seconds).
OPEN_TRACK_SPAN_S = 60.0
#: The latest time :meth:`SceneSession.set_time` takes (seconds).
MAX_TIME_S = 1e6

# Largest path order the viewer offers (each order costs a generation of reflected rays).
VIEWER_MAX_ORDER = min(6, MAX_ORDER_LIMIT)

# Display sizes in the page: rows of the fan image and of the polar image. The images are
# sent as JPEG at every change; these keep a frame's encoding and transfer at a few ms.
FAN_ROWS = 360
# The saved fan.png has a pixel of one range bin, but at most this many rows: a finely
# sampled range (8000 bins over 40 m) would otherwise need a fan of 8000 x 14600 pixels, more
# memory than the budget allows, and the save button refused to save anything.
SAVED_FAN_ROWS = 2000
POLAR_ROWS = 240
POLAR_MIN_WIDTH = 320


def _check_colormap(name: str) -> None:
    try:
        colormap_lut(name)
    except ValueError as exc:
        raise ConfigError("colormap", str(exc)) from None


def _check_max_order(mo: Any) -> None:
    """Refuse a longest path that is not an integer the viewer offers (ConfigError naming ``max_order``)."""
    if isinstance(mo, bool) or not isinstance(mo, (int, np.integer)) or not 1 <= mo <= VIEWER_MAX_ORDER:
        raise ConfigError("max_order", f"must be an integer from 1 to {VIEWER_MAX_ORDER}, got {mo!r}")


def component_names(max_order: int) -> tuple[str, ...]:
    """The components a frame formed up to ``max_order`` offers (``total`` first)."""
    from ...renderer.components import component_table

    names = [c.name for c in component_table(max_order)]
    return ("total", *[n for n in names if n != "total"])


@dataclass(frozen=True)
class ViewOptions:
    """The switches of the images.

    Attributes
    ----------
    component : str
        Which image: ``total`` (what the sonar records), or a component (``object``,
        ``ground``, ``single``, ``double``, ``triple``, ``order4``, ...).
    max_order : int
        Longest path formed (``render.max_order``).
    bounces : tuple of int
        Orders that make the total (``render.bounces``).
    sensor : bool
        Apply the device model (the scene's ``sensor:`` section, else the sensor preset named
        like the sonar's preset).
    speckle : bool
        Random draws: with the sensor, its speckle and noise (off: its expected output);
        without, ``render.speckle`` (unit-mean exponential speckle on the total).
    colormap : str
        A colour map of :mod:`sonarsim.plot.style`.
    gain_db, dynamic_range_db : float
        Display gain and width of the dB window (:func:`sonarsim.io.output.to_uint8`).
    """

    component: str = "total"
    max_order: int = 3
    bounces: tuple[int, ...] = (1, 2, 3)
    sensor: bool = False
    speckle: bool = False
    colormap: str = DEFAULT_COLORMAP
    gain_db: float = 0.0
    dynamic_range_db: float = 40.0

    def __post_init__(self) -> None:
        mo = self.max_order
        _check_max_order(mo)
        bounces = tuple(sorted({int(b) for b in self.bounces}))
        if not bounces or bounces[0] < 1 or bounces[-1] > mo:
            raise ConfigError("bounces", f"must be a non-empty subset of 1..{mo}, got {list(self.bounces)}")
        object.__setattr__(self, "bounces", bounces)
        if self.component not in component_names(mo):
            raise ConfigError("component", f"unknown component {self.component!r}; allowed: "
                              f"{', '.join(component_names(mo))}")
        _check_colormap(self.colormap)
        if not (math.isfinite(self.gain_db) and math.isfinite(self.dynamic_range_db) and self.dynamic_range_db > 0):
            raise ConfigError("dynamic_range_db", "gain and dynamic range must be finite, the range > 0")


@dataclass(frozen=True, eq=False)
class ViewFrame:
    """One update of the page: the images shown and what they show.

    Attributes
    ----------
    polar_rgb : (H, W, 3) uint8 ndarray
        The polar image coloured: far range at the top, the left-most beam on the left.
    fan_rgb : (H, W, 3) uint8 ndarray
        The fan image coloured: apex at the bottom centre, the sonar's left on the left,
        white outside the fan.
    title : str
        One line saying what is shown.
    image : SonarImage or None
        The rendered (or read) frame.
    seconds : dict of str to float
        ``render`` (or ``read``) and ``display`` (scan conversion, colours) times.
    notes : tuple of str
        Warnings met on the way (e.g. the sonar on the dry side of a plane).
    """

    polar_rgb: np.ndarray
    fan_rgb: np.ndarray
    title: str
    image: Any = None
    seconds: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()


class DisplayMapper:
    """Polar intensities of one polar grid to the coloured polar and fan images the page shows.

    The fan is scan-converted by :class:`~sonarsim.image.fan.FanMapper` (its pixel chosen so
    that the fan is at most ``fan_rows`` tall); the polar image keeps the brightest bin of each
    group of range bins (so thin echoes stay visible) and repeats beams to a readable width.

    Parameters
    ----------
    grid : PolarGrid
    fan_rows, polar_rows, polar_min_width : int or None
        Display sizes; ``None``: full resolution (a fan pixel of one range bin, one pixel per
        bin and beam), for saved images.
    """

    def __init__(self, grid: PolarGrid, fan_rows: int | None = FAN_ROWS, polar_rows: int | None = POLAR_ROWS,
                 polar_min_width: int | None = POLAR_MIN_WIDTH) -> None:
        pixel = grid.range_resolution_m
        if fan_rows is not None:
            pixel = max(pixel, grid.range_max_m / fan_rows)
        self.fan = FanMapper.from_grid(grid, pixel)
        n_r, n_b = grid.n_range_bins, len(grid.azimuth_deg)
        self.pool = 1 if polar_rows is None else max(1, math.ceil(n_r / polar_rows))
        self.repeat = 1 if polar_min_width is None else max(1, math.ceil(polar_min_width / n_b))
        self.polar_shape = (n_r, n_b)

    def polar_display(self, polar: np.ndarray) -> np.ndarray:
        """(n_range_bins, n_beams) intensities -> the polar image as shown (float32), far range on top.

        Returns
        -------
        (ceil(n_range_bins / pool), n_beams * repeat) float32 ndarray
        """
        p = np.asarray(polar, dtype=np.float32)
        if self.pool > 1:
            n_r, n_b = p.shape
            padded = np.zeros((math.ceil(n_r / self.pool) * self.pool, n_b), np.float32)
            padded[:n_r] = p
            p = padded.reshape(-1, self.pool, n_b).max(axis=1)
        p = p[::-1]
        if self.repeat > 1:
            p = np.repeat(p, self.repeat, axis=1)
        return p

    def __call__(self, polar: np.ndarray, mapping: str = "db", gain_db: float = 0.0, dynamic_range_db: float = 40.0,
                 reference: float | None = None, colormap: str = DEFAULT_COLORMAP) -> tuple[np.ndarray, np.ndarray]:
        """The coloured polar and fan images of one polar frame.

        Parameters
        ----------
        polar : (n_range_bins, n_beams) array_like
            Intensities (any linear unit) or device values.
        mapping, gain_db, dynamic_range_db, reference
            As :func:`sonarsim.io.output.to_uint8`; one reference for both images (default:
            the frame's largest value).
        colormap : str

        Returns
        -------
        polar_rgb, fan_rgb : (H, W, 3) uint8 ndarrays
        """
        from ...io.output import to_uint8

        p = np.asarray(polar, dtype=np.float32)
        if reference is None:
            finite = p[np.isfinite(p)]
            top = float(finite.max()) if finite.size else 0.0
            reference = top if top > 0 else None
        shown = self.polar_display(p)
        polar_u8 = to_uint8(shown, mapping, gain_db, dynamic_range_db, reference=reference)
        fan = self.fan(p)
        fan_u8 = to_uint8(fan.image, mapping, gain_db, dynamic_range_db, reference=reference, mask=fan.mask)
        return colorize(polar_u8, colormap), colorize(fan_u8, colormap, mask=fan.mask)


@functools.lru_cache(maxsize=8)
def _display_mapper(grid: PolarGrid, full: bool) -> DisplayMapper:
    """Scan-conversion tables cost more than a frame: one per grid (and size), kept."""
    return DisplayMapper(grid, SAVED_FAN_ROWS, None, None) if full else DisplayMapper(grid)


def _pose_of(position_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
    """A pose from a position and roll-pitch-yaw, checked finite (a ConfigError naming ``pose``)."""
    values = [float(v) for v in (*position_m, *rpy_deg)]
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ConfigError("pose", f"position and rpy must be three finite numbers each, got {position_m}, {rpy_deg}")
    return Pose(values[:3], values[3:])


def rpy_from_wxyz(wxyz: Sequence[float]) -> tuple[float, float, float]:
    """Roll, pitch, yaw in degrees of a ``(w, x, y, z)`` quaternion (viser's order)."""
    w, x, y, z = (float(v) for v in wxyz)
    return Pose.from_quaternion((0.0, 0.0, 0.0), (x, y, z, w)).rpy_deg


def wxyz_of(pose: Pose) -> tuple[float, float, float, float]:
    """The ``(w, x, y, z)`` quaternion of a pose's rotation (viser's order)."""
    x, y, z, w = pose.quat_xyzw
    return (w, x, y, z)


def _exact(pose: Pose) -> Pose:
    """The same pose built from its position and angles, so that its scene-file form (which
    writes those) gives back exactly the pose that was rendered."""
    return Pose(pose.position_m, pose.rpy_deg)


def _rebased(path: str, folder: Path) -> str:
    """A file path of the scene (relative to the working folder) relative to ``folder``."""
    return os.path.relpath(os.path.abspath(path), os.path.abspath(folder))


class SceneSession:
    """A scene being looked at: the sonar's and objects' current poses, the switches, renders.

    Thread-safe: the setters may be called from any thread (the page's callbacks) while
    another renders; renders and saves run one at a time.

    Parameters
    ----------
    scene : Scene, mapping or path
        Anything :func:`sonarsim.load_scene` accepts.
    backend : {'embree', 'numpy'}
        Ray caster of the renders.

    Attributes
    ----------
    base : Scene
        The scene as loaded.
    sonar_pose : Pose
        The sonar's pose (without instruments; with, the first channel's as loaded: the FLS
        rendered sits at its mount on :attr:`vehicle_pose`, ``scene().sonar_pose``).
    object_poses : dict of str to Pose
        By object name.
    tracks : dict of str to Track
        The objects that move on their own (a ``track``), by name.
    time_s : float
        The scene's clock (seconds): where the tracked objects are (:meth:`set_time`).
    vehicle_pose : Pose
        With instruments: the vehicle's pose (what the page moves; each instrument rides at its
        mount). Without, unused.
    fls : FlsSpec or None
        With instruments: the first FLS, whose images are rendered; None: no live image.
    options : ViewOptions
    version : int
        Counts the changes of state (a frame rendered at version v shows the state of v).
    """

    def __init__(self, scene: Any, backend: str = "embree") -> None:
        self.base: Scene = load_scene(scene)
        self.backend = backend
        self.sonar_pose = _exact(self.base.sonar_pose)
        self.vehicle_pose = _exact(self.base.vehicle_pose)
        from ...config.instruments import FlsSpec

        #: The FLS whose images the page shows (the first one on the vehicle), or None.
        self.fls = next((i for i in self.base.instruments if isinstance(i, FlsSpec)), None)
        #: Objects with a ``track``, by name: the time slider moves them.
        self.tracks = {o.name: o.track for o in self.base.objects if o.track is not None}
        self.time_s = 0.0
        self.object_poses = {o.name: _exact(self.tracks[o.name].pose_at(0.0) if o.name in self.tracks else o.pose)
                             for o in self.base.objects}
        self.sensor_spec = self._find_sensor()
        render = self.base.render
        has_sensor = self.base.sensor is not None
        self.options = ViewOptions(
            max_order=min(render.max_order, VIEWER_MAX_ORDER),
            bounces=tuple(b for b in render.bounces if b <= VIEWER_MAX_ORDER) or (1,),
            sensor=has_sensor, speckle=render.speckle or has_sensor,
        )
        self.version = 0
        self._lock = threading.RLock()  # the state
        self._render_lock = threading.Lock()  # the simulator: one render at a time
        self._sim = None
        self._sim_key: Any = None
        self._sim_notes: tuple[str, ...] = ()

    # ------------------------------------------------------------------ state

    def _find_sensor(self):
        """The sensor the switch turns on: the scene's, else the preset named like the sonar's
        preset; ``None`` when there is none or the scene cannot take one (``render.tvg`` off)."""
        from ...config.sensor import SENSOR_PRESETS, parse_sensor

        if self.base.instruments and (self.fls is None or self.fls is not self.base.instruments[0]):
            # A top-level sensor is the first instrument's, an FLS's: a scene file could not
            # hold one for an FLS further down (and the other types' films are not shown).
            return None
        spec = self.base.sensor
        if spec is None and self.base.sonar.preset in SENSOR_PRESETS:
            spec = parse_sensor({"preset": self.base.sonar.preset})
        if spec is None:
            return None
        try:
            replace(self.base, sensor=spec, render=replace(self.base.render, speckle=False))
        except ConfigError:
            return None
        return spec

    @property
    def sensor_available(self) -> bool:
        """Whether the sensor switch can be turned on."""
        return self.sensor_spec is not None

    def _changed(self) -> None:
        self.version += 1

    @property
    def has_vehicle(self) -> bool:
        """Whether the scene's sonars ride a vehicle (instruments): the page then moves the vehicle."""
        return bool(self.base.instruments)

    @property
    def carrier_pose(self) -> Pose:
        """What the page's gizmo and sliders move: the vehicle's pose with instruments, else the sonar's."""
        return self.vehicle_pose if self.has_vehicle else self.sonar_pose

    def set_carrier_pose(self, position_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
        """Move the vehicle (with instruments) or the sonar (without); see :meth:`set_vehicle_pose`."""
        if self.has_vehicle:
            return self.set_vehicle_pose(position_m, rpy_deg)
        return self.set_sonar_pose(position_m, rpy_deg)

    def set_vehicle_pose(self, position_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
        """Move and turn the vehicle (world frame: metres; roll, pitch, yaw in degrees); every
        instrument follows at its mount.

        Raises
        ------
        ConfigError
            Non-finite values, or a scene without instruments (``pose``: move its sonar).
        """
        if not self.has_vehicle:
            raise ConfigError("pose", "this scene has no vehicle (no instruments): move its sonar")
        pose = _pose_of(position_m, rpy_deg)
        with self._lock:
            if pose != self.vehicle_pose:
                self.vehicle_pose = pose
                self._changed()
        return pose

    def set_sonar_pose(self, position_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
        """Move and turn the sonar (world frame: metres; roll, pitch, yaw in degrees).

        Raises
        ------
        ConfigError
            Non-finite values, or a scene whose sonars ride a vehicle (``pose``: move the
            vehicle, :meth:`set_vehicle_pose`).
        """
        if self.has_vehicle:
            raise ConfigError("pose", "this scene's sonars ride a vehicle: move the vehicle (set_vehicle_pose)")
        pose = _pose_of(position_m, rpy_deg)
        with self._lock:
            if pose != self.sonar_pose:
                self.sonar_pose = pose
                self._changed()
        return pose

    def set_object_pose(self, name: str, position_m: Sequence[float], rpy_deg: Sequence[float]) -> Pose:
        """Move and turn an object (by name; world frame: metres, degrees).

        Raises
        ------
        ConfigError
            An unknown object or non-finite values.
        """
        if name not in self.object_poses:
            raise ConfigError("object", f"no object named {name!r}; the scene has: {', '.join(self.object_poses)}")
        pose = _pose_of(position_m, rpy_deg)
        with self._lock:
            if pose != self.object_poses[name]:
                self.object_poses[name] = pose
                self._changed()
        return pose

    @property
    def time_span_s(self) -> float:
        """How far the time slider reaches, seconds: the longest timed track's end (a looping
        one's too), or :data:`OPEN_TRACK_SPAN_S` where a track runs at a constant velocity."""
        ends = [float(t.trajectory.times_s[-1]) for t in self.tracks.values() if t.trajectory is not None]
        if any(t.trajectory is None for t in self.tracks.values()):
            ends.append(OPEN_TRACK_SPAN_S)
        return max([1.0, *ends])

    def set_time(self, t_s: float) -> float:
        """Move the scene's clock: every object with a ``track`` goes where its track has it at
        ``t_s`` seconds (a drag of a tracked object holds only until the clock moves again).

        Raises
        ------
        ConfigError
            A time that is not a number of seconds in ``[0, MAX_TIME_S]``.
        """
        if isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.floating, np.integer)) \
                or not math.isfinite(float(t_s)) or not 0.0 <= float(t_s) <= MAX_TIME_S:
            raise ConfigError("time_s", f"must be a number of seconds in [0, {MAX_TIME_S:g}], got {t_s!r}")
        t = float(t_s)
        with self._lock:
            poses = {name: _exact(track.pose_at(t)) for name, track in self.tracks.items()}
            if t != self.time_s or any(p != self.object_poses[n] for n, p in poses.items()):
                self.time_s = t
                self.object_poses.update(poses)
                self._changed()
        return t

    def set_options(self, **changes: Any) -> ViewOptions:
        """Change switches (fields of :class:`ViewOptions`); returns the options now in force.

        A new ``max_order`` keeps the bounces it allows (all orders when none is left) and
        falls back to ``total`` when the component shown no longer exists.

        Raises
        ------
        ConfigError
            An unknown switch or value, or the sensor where there is none.
        """
        unknown = set(changes) - set(ViewOptions.__dataclass_fields__)
        if unknown:
            raise ConfigError(sorted(unknown)[0], f"unknown switch; allowed: {', '.join(ViewOptions.__dataclass_fields__)}")
        if changes.get("sensor") and not self.sensor_available:
            raise ConfigError("sensor", "this scene has no sensor section and its sonar no sensor preset")
        with self._lock:
            current = self.options
            if "max_order" in changes and "bounces" not in changes:
                mo = changes["max_order"]
                if isinstance(mo, (int, np.integer)) and not isinstance(mo, bool):
                    # Checked before its components are listed: the list is as long as the
                    # order (max_order=2**63 took all memory before ViewOptions refused it).
                    _check_max_order(mo)
                    changes["bounces"] = tuple(b for b in current.bounces if b <= mo) or tuple(range(1, int(mo) + 1))
                    if changes.get("component", current.component) not in component_names(int(mo)):
                        changes["component"] = "total"
            options = replace(current, **changes)
            if options != current:
                self.options = options
                self._changed()
            return self.options

    def scene(self) -> Scene:
        """The current state as a :class:`~sonarsim.config.scene.Scene` (poses, render settings, sensor)."""
        with self._lock:
            o = self.options
            objects = tuple(replace(obj, pose=self.object_poses[obj.name]) for obj in self.base.objects)
            render = replace(self.base.render, max_order=o.max_order, bounces=o.bounces,
                             speckle=o.speckle and not o.sensor)
            sensor = self.sensor_spec if o.sensor else None
            if not self.has_vehicle:
                return replace(self.base, objects=objects, render=render, sensor=sensor, sonar_pose=self.sonar_pose)
            # The sonar rendered is the FLS shown (else the first channel, as the loader
            # sets it), at its mount on the vehicle where it is now.
            from ...config.instruments import mounted

            channel = (self.fls or self.base.instruments[0]).primary
            return replace(self.base, objects=objects, render=render, sensor=sensor, sonar=channel.sonar,
                           sonar_pose=mounted(self.vehicle_pose, channel.mount), vehicle_pose=self.vehicle_pose)

    def scene_dict(self, folder: str | os.PathLike | None = None) -> dict:
        """The current scene in scene-file form, its file paths relative to ``folder``.

        Mesh files and pattern tables are named relative to the folder the scene file will
        be written to (a scene file's paths are relative to the file), and the sonar keeps its
        preset's name (so that a viewer of the saved file offers the same sensor).

        Raises
        ------
        SonarsimError
            An object whose mesh was given in memory, which a file cannot hold.
        """
        scene = self.scene()
        doc = scene.to_dict()
        base = Path(folder) if folder is not None else Path.cwd()
        for spec, entry in zip(scene.objects, doc["objects"]):
            if "mesh" in entry:
                if not isinstance(spec.mesh, (str, os.PathLike)):
                    raise SonarsimError(f"object {spec.name!r} has a mesh given in memory: a scene file cannot "
                                        "hold it (give the mesh as a file)")
                entry["mesh"] = _rebased(os.fspath(spec.mesh), base)
        sensor = doc.get("sensor")
        if isinstance(sensor, dict):
            for value in sensor.values():
                if isinstance(value, dict) and isinstance(value.get("table"), str):
                    value["table"] = _rebased(value["table"], base)
        if not scene.instruments and scene.sonar.preset is not None:
            doc["sonar"] = {"preset": scene.sonar.preset, **doc["sonar"]}
        for spec, entry in zip(scene.instruments, doc.get("instruments", ())):
            sonar = getattr(spec, "sonar", None)  # an FLS keeps its preset's name, as sonar: does
            if spec.type_name == "fls" and sonar is not None and sonar.preset is not None and "preset" not in entry:
                entry["preset"] = sonar.preset  # (its explicit keys, written too, take precedence)
        return doc

    # ------------------------------------------------------------------ rendering

    def _simulator(self, scene: Scene):
        """The simulator of the scene's settings: kept while only poses change. A new sonar pose
        is a new render; an object moved (dragged, or by the clock) is moved in it
        (:meth:`Simulator.move_objects`: its own tree refitted), not a new acceleration
        structure."""
        from ...renderer.simulator import Simulator

        key = (scene.render, scene.sensor is not None)
        if key == self._sim_key:
            now = {o.name: o.pose for o in self._sim.scene.objects}
            moved = {o.name: o.pose for o in scene.objects if o.pose != now[o.name]}
            if moved:
                self._sim.move_objects(moved)
            return self._sim
        if self._sim is not None:
            self._sim.close()
            self._sim = None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            self._sim = Simulator(scene, backend=self.backend)
        self._sim_key = key
        self._sim_notes = tuple(str(w.message) for w in caught)
        return self._sim

    def render_image(self):
        """Render the current state; returns ``(SonarImage, options, notes)``."""
        with self._lock:
            scene, options = self.scene(), self.options
        with self._render_lock:
            sim = self._simulator(scene)
            image = sim.render(pose=scene.sonar_pose, keep_rays=False, frame=0,
                               speckle=None if options.speckle else False)
            return image, options, self._sim_notes

    def _display_args(self, image, options: ViewOptions) -> tuple[np.ndarray, dict]:
        """The polar image to show and its mapping: device values linearly against the
        device's full scale, everything else in dB below the frame's maximum."""
        if options.component == "total":
            polar = image.polar
            output = self.sensor_spec.output if (options.sensor and self.sensor_spec is not None) else None
            if output is not None:
                return polar, {"mapping": "linear", "reference": float(output.full_scale), "gain_db": options.gain_db}
        else:
            polar = image.components[options.component]
        return polar, {"mapping": "db", "gain_db": options.gain_db, "dynamic_range_db": options.dynamic_range_db}

    def title(self, options: ViewOptions, pose: Pose) -> str:
        """One line saying what the images show."""
        x, y, z = pose.position_m
        r, p, yaw = pose.rpy_deg
        what = options.component if options.component != "total" else f"total of orders {list(options.bounces)}"
        sensor = "sensor on" if options.sensor else "sensor off"
        who = "sonar" if not self.has_vehicle or self.fls is None else f"fls {self.fls.name!r}"
        return (f"{what} | {sensor}, speckle {'on' if options.speckle else 'off'} | {who} at ({x:.2f}, {y:.2f}, "
                f"{z:.2f}) m, roll {r:.1f}, pitch {p:.1f}, yaw {yaw:.1f} deg")

    def film_notes(self) -> tuple[str, ...]:
        """What the page says of the instruments it shows no live image of (all but the FLS
        shown): their films come from ``sonarsim render``."""
        others = [i for i in self.base.instruments if i is not self.fls]
        if not others:
            return ()
        scene = self.base.source or "SCENE"
        names = ", ".join(f"{i.type_name} {i.name!r}" for i in others)
        its, films = ("its", "film") if len(others) == 1 else ("their", "films")
        return (f"no live image of {names} here ({its} fans are drawn in 3D); `sonarsim render {scene} --out DIR` "
                f"renders {its} {films}",)

    @property
    def saved_files(self) -> tuple[str, ...]:
        """The files :meth:`save` writes: the scene file, and the images when there are any."""
        return SAVED_FILES if self.shows_images else SAVED_FILES[:1]

    @property
    def shows_images(self) -> bool:
        """Whether there is a live FLS image (a scene with instruments but no FLS has none)."""
        return not self.has_vehicle or self.fls is not None

    def _no_image(self) -> ViewFrame:
        """The page's update for a vehicle without an FLS: no images, the instruments named."""
        blank = np.full((8, 8, 3), 255, np.uint8)
        x, y, z = self.vehicle_pose.position_m
        r, p, yaw = self.vehicle_pose.rpy_deg
        title = (f"vehicle at ({x:.2f}, {y:.2f}, {z:.2f}) m, roll {r:.1f}, pitch {p:.1f}, yaw {yaw:.1f} deg | "
                 f"no FLS on it: no live image")
        return ViewFrame(blank, blank.copy(), title, None, {}, self.film_notes())

    def render(self, full: bool = False) -> ViewFrame:
        """Render the current state into the page's images.

        Parameters
        ----------
        full : bool
            Full-resolution images (one pixel per range bin and beam; a fan pixel of one range
            bin, coarser where the fan would be taller than ``SAVED_FAN_ROWS``), as saved;
            default the page's display sizes.

        Raises
        ------
        SonarsimError
            The state cannot be rendered (e.g. the sonar on a plane); the page shows the message.
        """
        if not self.shows_images:
            return self._no_image()
        t0 = time.perf_counter()
        image, options, notes = self.render_image()
        t1 = time.perf_counter()
        polar, mapping = self._display_args(image, options)
        polar_rgb, fan_rgb = _display_mapper(image.sonar.grid, full)(polar, colormap=options.colormap, **mapping)
        t2 = time.perf_counter()
        return ViewFrame(polar_rgb, fan_rgb, self.title(options, image.pose), image,
                         {"render": t1 - t0, "display": t2 - t1}, (*notes, *self.film_notes()))

    def save(self, folder: str | os.PathLike, command: Sequence[str] | None = None,
             log: Callable[[str], None] | None = None) -> list[Path]:
        """Write the scene file with the current poses and switches, and the current images.

        Writes ``scene.yaml`` (loads with :func:`sonarsim.load_scene` and renders the image
        shown: ``render(frame=0)``, with ``speckle=False`` when the speckle switch is off and
        the sensor on), ``polar.png`` and ``fan.png`` (the images shown, coloured, at full
        resolution; the fan at most ``SAVED_FAN_ROWS`` tall; only the scene file for a vehicle
        without an FLS: :attr:`saved_files`) and the run record, each atomically
        (:class:`~sonarsim.io.run_record.OutputRun`).

        Returns
        -------
        list of Path
            The files written.
        """
        import yaml

        from ...io.output import atomic_write, write_png
        from ...io.run_record import OutputRun

        out = Path(folder)
        images = self.shows_images
        run = OutputRun.for_folder(out, self.saved_files, command=command, log=log)
        with self._lock:  # the file and the images of one state
            doc = self.scene_dict(out)
            frame = self.render(full=True) if images else None
        with run:
            with atomic_write(out / "scene.yaml", "w") as handle:
                yaml.safe_dump(doc, handle, sort_keys=False)
            if frame is not None:
                write_png(out / "polar.png", frame.polar_rgb)
                write_png(out / "fan.png", frame.fan_rgb)
        return run.files

    def close(self) -> None:
        """Stop the simulator's threads."""
        with self._render_lock:
            if self._sim is not None:
                self._sim.close()
                self._sim = None
                self._sim_key = None


@dataclass(frozen=True)
class RecordingOptions:
    """The switches of a recording's images (see :func:`sonarsim.io.output.to_uint8`).

    ``linear`` against the data type's full scale shows recorded 8-bit values as they are
    (as ``sonarsim show`` does); ``db`` compresses them once more.
    """

    colormap: str = DEFAULT_COLORMAP
    mapping: str = "linear"
    gain_db: float = 0.0
    dynamic_range_db: float = 40.0

    def __post_init__(self) -> None:
        from ...io.output import MAPPINGS

        _check_colormap(self.colormap)
        if self.mapping not in MAPPINGS:
            raise ConfigError("mapping", f"unknown mapping {self.mapping!r}; allowed: {', '.join(MAPPINGS)}")
        if not (math.isfinite(self.gain_db) and math.isfinite(self.dynamic_range_db) and self.dynamic_range_db > 0):
            raise ConfigError("dynamic_range_db", "gain and dynamic range must be finite, the range > 0")


class RecordingSession:
    """The frames of a real recording (ARIS, Oculus), one at a time.

    Parameters
    ----------
    path : str or os.PathLike
        A recording :func:`sonarsim.io.readers.open_recording` opens.

    Attributes
    ----------
    n_frames : int
    frame : int
        The frame shown (0-based).
    options : RecordingOptions
    """

    def __init__(self, path: str | os.PathLike) -> None:
        from ...io.readers import open_recording

        self.path = Path(path)
        self._recording = open_recording(path)
        try:
            self.n_frames = int(self._recording.n_frames)
        except BaseException:
            self._recording.close()
            raise
        self.frame = 0
        # A recording is shown in its counts (linear against full scale), a stored render in dB
        # below its maximum, as ``sonarsim show`` draws each (figures.default_scale).
        self.options = RecordingOptions(mapping=self._scale(self._recording.read(0)).mapping
                                        if self.n_frames else "linear")
        self.version = 0
        self._lock = threading.RLock()

    @staticmethod
    def _scale(image):
        from ..figures import default_scale

        return default_scale(image)

    def set_frame(self, frame: int) -> int:
        """Show another frame; returns it.

        Raises
        ------
        ConfigError
            A frame outside ``0 .. n_frames - 1``.
        """
        if isinstance(frame, bool) or int(frame) != frame or not 0 <= frame < self.n_frames:
            raise ConfigError("frame", f"must be an integer from 0 to {self.n_frames - 1}, got {frame!r}")
        with self._lock:
            if int(frame) != self.frame:
                self.frame = int(frame)
                self.version += 1
        return self.frame

    def set_options(self, **changes: Any) -> RecordingOptions:
        """Change switches (fields of :class:`RecordingOptions`)."""
        with self._lock:
            options = replace(self.options, **changes)
            if options != self.options:
                self.options = options
                self.version += 1
            return self.options

    def render(self) -> ViewFrame:
        """Read the current frame into the page's images."""
        t0 = time.perf_counter()
        with self._lock:
            frame, options = self.frame, self.options
            image = self._recording.read(frame)
        t1 = time.perf_counter()
        # Device output against its full scale (255 for 8-bit data, whatever the frame holds),
        # a stored render against its own maximum, as sonarsim show draws them.
        reference = self._scale(image).reference
        polar_rgb, fan_rgb = _display_mapper(image.sonar.grid, False)(
            image.polar, options.mapping, options.gain_db, options.dynamic_range_db, reference, options.colormap)
        t2 = time.perf_counter()
        s = image.sonar
        # Frames counted from 0, as the slider, --frame and sonarsim show count them.
        title = (f"{image.config.get('format', '?')} frame {frame} of {self.n_frames} | {s.n_range_bins} ranges x "
                 f"{s.n_beams} beams, {s.range_min_m:.2f}-{s.range_max_m:.2f} m, {s.azimuth_fov_deg:.1f} deg wide")
        return ViewFrame(polar_rgb, fan_rgb, title, image, {"read": t1 - t0, "display": t2 - t1})

    def close(self) -> None:
        """Close the recording."""
        self._recording.close()

