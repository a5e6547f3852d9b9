"""The viser page of ``sonarsim view``: controls forwarded to the sessions of :mod:`.state`.

The server is guarded (:mod:`.guard`): it serves only requests that name it in ``Host`` and
come from its own page (``Origin``), and its controls' callbacks only see values within the
controls' bounds.

Re-rendering runs in one background thread (:class:`LatestOnly`): every change (a gizmo drag,
a slider, a switch) asks for an update, and requests that arrive while a frame is being
rendered and sent collapse into one more update with the newest state, so that a fast drag
never queues stale frames (viser also drops a queued image that a newer one replaces).
"""

from __future__ import annotations

import collections
import contextlib
import errno
import io
import math
import socket
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import ConfigError, SonarsimError
from . import require_viser
from .geometry import fan_surface, fov_segments, fov_surface, instrument_fans, plane_face, scene_extent
from .guard import start_guarded_server
from .state import (VIEWER_MAX_ORDER, RecordingSession, SceneSession, ViewFrame, component_names, rpy_from_wxyz,
                    wxyz_of)
from ..style import COLORMAPS

__all__ = ["LatestOnly", "RecordingViewer", "SceneViewer", "check_port", "start_server", "stop_server", "url_of"]

# Quality of the JPEG images sent to the page: sharp enough to read, a few tens of kB a frame.
JPEG_QUALITY = 90
# Colours of the 3D view (RGB).
FOV_COLOUR = (255, 140, 0)
SONAR_COLOUR = (250, 200, 40)
OBJECT_COLOURS = ((120, 160, 220), (150, 200, 120), (220, 150, 110), (190, 140, 210), (110, 200, 200))
# The instruments' fans, one colour per instrument (the first the FLS's own orange).
INSTRUMENT_COLOURS = ((255, 140, 0), (230, 40, 120), (40, 170, 240), (120, 200, 40), (150, 90, 230),
                      (240, 210, 30), (30, 200, 170))
VEHICLE_COLOUR = (200, 200, 60)


def node_name(text: str) -> str:
    """A name usable as one level of the scene tree (viser splits names at ``/``)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in str(text)) or "_"


def check_port(host: str, port: int) -> None:
    """Refuse an address the server could not listen on, before the server starts: a host that
    does not resolve or is not one of this machine's addresses, or a port another program
    listens on.

    Port 0 (any free port) is checked too: viser tries a thousand ports on any bind error and
    then waits forever, so an address it cannot bind must be refused here.

    Raises
    ------
    SonarsimError
        Naming ``--host`` (cannot resolve it, not an address of this machine) or ``--port``
        (in use), and what to do.
    """
    try:
        # "" (as asyncio reads it): every address, like 0.0.0.0.
        infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        raise SonarsimError(f"--host {host}: cannot resolve it ({reason}); give a host name or an address of this "
                            "machine without port or scheme (e.g. 127.0.0.1, localhost, 0.0.0.0)") from None
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        # As the server binds (SO_REUSEADDR): a port left in TIME_WAIT is free, a listener is not.
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise SonarsimError(f"--port {port}: port {port} on {host} is in use ({exc.strerror or exc}); "
                                    "choose another with --port N, or --port 0 for any free port") from None
            if exc.errno == errno.EACCES:
                raise SonarsimError(f"--port {port}: not allowed to listen on port {port} ({exc.strerror}); "
                                    "choose a port above 1023 with --port N, or --port 0 for any free port") from None
            raise SonarsimError(f"--host {host}: cannot listen on it ({exc.strerror or exc}); give an address of "
                                "this machine (127.0.0.1: this machine only, 0.0.0.0: every address)") from None


def start_server(host: str = "127.0.0.1", port: int = 8080, log: Callable[[str], None] | None = None):
    """A viser server on ``host:port`` (port 0: any free port), quiet, its panel docked right,
    guarded (:mod:`.guard`): it serves only requests that name it in ``Host`` and come from its
    own page (``Origin``), and passes on only messages whose values its controls allow.

    Parameters
    ----------
    host : str
        Address to listen on (127.0.0.1: this machine only).
    port : int
        Port; 0 for any free one (:func:`url_of` tells which).
    log : callable, optional
        Receives a line for the first refused connection of each reason (a foreign page, a
        name the server does not know as its own).

    Returns
    -------
    viser.ViserServer
        Running; stop it with :func:`stop_server`.

    Raises
    ------
    SonarsimError
        viser is missing (naming the extra), the port is in use, or this viser cannot be
        guarded (:func:`.guard.start_guarded_server`).
    """
    require_viser()
    check_port(host, port)
    server = start_guarded_server(host, port, log=log)
    server.scene.set_up_direction("+z")
    # The controls and images docked on the right, beside the 3D view, not floating over it.
    main_panel = getattr(server.gui, "main_panel", None)
    if main_panel is not None and hasattr(main_panel, "dock_right"):
        main_panel.dock_right()
        server.gui.configure_theme(control_width="large", show_share_button=False)
    else:  # older viser
        server.gui.configure_theme(control_layout="fixed", control_width="large", show_share_button=False)
    return server


def stop_server(server) -> None:
    """Stop a server from :func:`start_server` and wait for its thread (quietly)."""
    with contextlib.redirect_stdout(io.StringIO()):
        server.stop()
        thread = getattr(getattr(server, "_websock_server", None), "_server_thread", None)
        if thread is not None:
            thread.join(timeout=5.0)


def url_of(server, host: str) -> str:
    """The address to point the browser at (``http://127.0.0.1:PORT/`` for a server on all
    addresses)."""
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else ("[::1]" if host in ("::", "::1") else host)
    return f"http://{shown}:{server.get_port()}/"


def _from_gizmo(position, wxyz) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A gizmo's pose as position and roll-pitch-yaw, rounded to a micrometre and a micro-degree
    (a drag is not finer; the scene file then reads 15.0, not 14.999999999999998)."""
    return (tuple(round(float(v), 6) + 0.0 for v in position),
            tuple(round(float(v), 6) + 0.0 for v in rpy_from_wxyz(wxyz)))


class LatestOnly:
    """Runs ``job`` in a background thread on request, coalescing requests.

    A request made while the job runs is served by one more run after it, whatever the number
    of requests: the job always works on the newest state and never on a backlog.

    Parameters
    ----------
    job : callable
        Does one update (render, encode, send).
    on_error : callable
        Receives an exception the job raised (the thread goes on).
    """

    def __init__(self, job: Callable[[], None], on_error: Callable[[BaseException], None]) -> None:
        self._job = job
        self._on_error = on_error
        self._cond = threading.Condition()
        self._requested = 0
        self._done = 0
        self._stop = False
        #: perf_counter() times at which updates completed (the last few hundred).
        self.completed = collections.deque(maxlen=512)
        self.runs = 0
        self._thread = threading.Thread(target=self._loop, name="sonarsim-viewer-render", daemon=True)
        self._thread.start()

    def request(self) -> int:
        """Ask for an update; returns the request's number (see :meth:`wait`)."""
        with self._cond:
            self._requested += 1
            self._cond.notify_all()
            return self._requested

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._stop and self._done >= self._requested:
                    self._cond.wait()
                if self._stop:
                    return
                target = self._requested
            try:
                self._job()
            except Exception as exc:  # noqa: BLE001 - reported on the page; the viewer goes on
                self._on_error(exc)
            with self._cond:
                self._done = target
                self.runs += 1
                self.completed.append(time.perf_counter())
                self._cond.notify_all()

    def wait(self, timeout: float = 10.0) -> bool:
        """Wait until every request made so far is served; ``False`` on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            target = self._requested
            while self._done < target:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def rate(self, window_s: float = 1.0) -> float:
        """Updates per second over the last ``window_s`` seconds."""
        now = time.perf_counter()
        recent = [t for t in list(self.completed) if now - t <= window_s]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def stop(self) -> None:
        """End the thread (after the update in progress)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        self._thread.join(timeout=5.0)


class _Page:
    """What both viewers share: the images, the title, the status line, the update thread."""

    def __init__(self, server, session) -> None:
        self.server = server
        self.session = session
        self.frame: ViewFrame | None = None
        self.error: str | None = None
        self._seconds: dict = {}
        gui = server.gui
        with gui.add_folder("Sonar images"):
            self.title = gui.add_markdown("*rendering...*")
            blank = np.full((8, 8, 3), 255, np.uint8)
            self.fan_image = gui.add_image(blank, label="fan (apex at the bottom, the sonar's left on the left)",
                                           format="jpeg", jpeg_quality=JPEG_QUALITY)
            self.polar_image = gui.add_image(blank, label="polar (far range at the top, left-most beam on the left)",
                                             format="jpeg", jpeg_quality=JPEG_QUALITY)
            self.status = gui.add_markdown("")
        self.worker = LatestOnly(self._update, self._failed)

    def _update(self) -> None:
        frame = self.session.render()
        t0 = time.perf_counter()
        # Both images before the text: a page that shows the title shows its images.
        self.fan_image.image = frame.fan_rgb  # JPEG-encoded here, queued to every client
        self.polar_image.image = frame.polar_rgb
        self.frame, self.error = frame, None
        self._seconds = {**frame.seconds, "send": time.perf_counter() - t0}
        self.title.content = f"**{frame.title}**"
        self._show_status(frame.notes)

    def _show_status(self, notes: Sequence[str] = ()) -> None:
        parts = [f"{k} {1000 * v:.0f} ms" for k, v in self._seconds.items()]
        rate = self.worker.rate()
        if rate:
            parts.append(f"{rate:.0f} updates/s")
        text = " · ".join(parts)
        if self.error:
            text = f"**error:** {self.error}  \n{text}"
        for note in notes:
            text += f"  \n*note:* {note}"
        self.status.content = text

    def _failed(self, exc: BaseException) -> None:
        # Bad input (a sonar on a plane) is said on the page; the images keep the last state.
        self.error = str(exc) if isinstance(exc, SonarsimError) else f"{type(exc).__name__}: {exc}"
        with contextlib.suppress(Exception):
            self._show_status()

    def request_update(self) -> int:
        """Ask for the images of the current state (coalesced; see :class:`LatestOnly`)."""
        return self.worker.request()

    def wait(self, timeout: float = 10.0) -> bool:
        """Wait until the page shows the current state; ``False`` on timeout."""
        return self.worker.wait(timeout)

    def close(self) -> None:
        """Stop the update thread and the session (the server is the caller's)."""
        self.worker.stop()
        self.session.close()


class SceneViewer(_Page):
    """The page of a scene: the 3D view with gizmos, the live images, pose sliders and switches.

    A scene with instruments shows its vehicle (``/vehicle``, its gizmo and its frame's axes)
    and under it every channel's fan at its mount (``/vehicle/INSTRUMENT/CHANNEL``: outline,
    far cap, label; one colour per instrument; :func:`.geometry.instrument_fans`); the gizmo
    and the sliders move the vehicle, the images are its first FLS's (none without an FLS:
    the page names the instruments and ``sonarsim render``).

    Parameters
    ----------
    server : viser.ViserServer
    session : SceneSession
    out : path-like
        Folder the save button writes into (:meth:`SceneSession.save`).
    command : sequence of str, optional
        The command line, for the run record of a save.
    log : callable, optional
        Receives one-line messages (a save's files).
    """

    def __init__(self, server, session: SceneSession, out: str | Path = "sonarsim-view",
                 command: Sequence[str] | None = None, log: Callable[[str], None] | None = None) -> None:
        super().__init__(server, session)
        self.out = Path(out)
        self.command = command
        self.log = log or (lambda msg: None)
        self._build_scene()
        self._build_controls()
        self.request_update()

    # ------------------------------------------------------------------ 3D

    def _build_scene(self) -> None:
        scene, api = self.session.base, self.server.scene
        if self.session.has_vehicle:
            fans = instrument_fans(scene.instruments)
            pose = self.session.vehicle_pose
            reach = max(f.limits.range_max_m for f in fans)
            points = [pose.translation] + [f.world_pose(pose).translation + f.world_pose(pose).rotation[:, 0]
                                           * f.limits.range_max_m for f in fans]
        else:
            sonar = scene.sonar
            pose = self.session.sonar_pose
            reach = sonar.range_max_m
            points = [pose.translation, pose.translation + pose.rotation[:, 0] * sonar.range_max_m]
        forward = pose.rotation[:, 0]
        points += [o.pose.translation for o in scene.objects]
        centre, half = scene_extent(points, 0.5 * reach + 1.0)
        api.add_frame("/world", axes_length=0.3, axes_radius=0.01)
        planes = scene.reflecting_planes
        for plane in planes:
            vertices, faces = plane_face(plane, planes, centre, half)
            water = "surface" in plane.name
            colour = (110, 160, 230) if water else ((190, 175, 140) if plane.name == "ground" else (170, 170, 175))
            api.add_mesh_simple(f"/planes/{plane.name}", vertices, faces, color=colour,
                                opacity=0.35 if water else (0.9 if plane.name == "ground" else 0.3), side="double")
        self._build_objects()
        if self.session.has_vehicle:
            self._build_vehicle(fans)
        else:
            # The sonar: a small body and its field of view, under its gizmo.
            self.sonar_control = api.add_transform_controls("/sonar", scale=0.45, position=pose.position_m,
                                                            wxyz=wxyz_of(pose), line_width=3.0)
            api.add_box("/sonar/body", color=SONAR_COLOUR, dimensions=(0.16, 0.1, 0.1), position=(-0.08, 0.0, 0.0))
            api.add_line_segments("/sonar/fov", fov_segments(sonar), FOV_COLOUR, thickness=2.0,
                                  thickness_units="screen")
            vertices, faces = fov_surface(sonar)
            api.add_mesh_simple("/sonar/fov_far", vertices, faces, color=FOV_COLOUR, opacity=0.2, side="double")

        async def sonar_dragged(event) -> None:
            self.set_sonar_pose(*_from_gizmo(event.target.position, event.target.wxyz), source="gizmo")

        self.sonar_control.on_update(sonar_dragged)
        # The camera: behind and above the sonar (the vehicle), looking down the range window.
        look = pose.translation + forward * (reach / 2)
        eye = pose.translation - 0.35 * reach * forward + np.array([0.0, 0.3 * reach, 0.35 * reach])
        # (behind the sonar, above it and a little to its left, so that heights read)

        def place_camera(client) -> None:
            client.camera.position = tuple(eye)
            client.camera.look_at = tuple(look)

        self.server.on_client_connect(place_camera)

    def _build_objects(self) -> None:
        from ...scene.meshes import object_mesh_local

        scene, api = self.session.base, self.server.scene
        # Objects: the renderer's own triangles (scene.meshes), in object coordinates, under a
        # gizmo that carries the object's pose.
        self.object_controls = {}
        for k, obj in enumerate(scene.objects):
            local = object_mesh_local(obj)
            scale = np.broadcast_to(np.asarray(obj.scale, dtype=float), (3,))
            vertices = local.vertices * scale
            size = float(np.ptp(vertices, axis=0).max())
            p = self.session.object_poses[obj.name]
            control = api.add_transform_controls(f"/objects/{obj.name}", scale=max(0.25, 0.8 * size),
                                                 position=p.position_m, wxyz=wxyz_of(p), line_width=2.0)
            api.add_mesh_simple(f"/objects/{obj.name}/mesh", vertices, local.faces,
                                color=OBJECT_COLOURS[k % len(OBJECT_COLOURS)])
            api.add_label(f"/objects/{obj.name}/label", obj.name, position=(0.0, 0.0, size / 2 + 0.05))
            control.on_update(self._object_dragged(obj.name))
            self.object_controls[obj.name] = control

    def _build_vehicle(self, fans) -> None:
        """The vehicle under its gizmo, its frame's axes, and under it every channel's fan at
        its mount (``/vehicle/INSTRUMENT/CHANNEL``), coloured per instrument."""
        api = self.server.scene
        pose = self.session.vehicle_pose
        reach = max(f.limits.range_max_m for f in fans)
        self.sonar_control = api.add_transform_controls("/vehicle", scale=max(0.6, 0.05 * reach),
                                                        position=pose.position_m, wxyz=wxyz_of(pose), line_width=3.0)
        api.add_frame("/vehicle/frame", axes_length=max(0.5, 0.04 * reach), axes_radius=0.02)
        api.add_box("/vehicle/body", color=VEHICLE_COLOUR, dimensions=(1.0, 0.3, 0.3), opacity=0.6)
        api.add_label("/vehicle/label", "vehicle", position=(0.0, 0.0, 0.3))
        #: Scene-tree name -> the fan drawn there (InstrumentFan).
        self.fan_nodes = {}
        for fan in fans:
            colour = INSTRUMENT_COLOURS[fan.index % len(INSTRUMENT_COLOURS)]
            node = f"/vehicle/{node_name(fan.instrument)}/{node_name(fan.channel)}"
            if node in self.fan_nodes:  # two names the same once made tree-safe: keep both
                node = f"{node}_{len(self.fan_nodes)}"
            api.add_frame(node, show_axes=False, position=fan.mount.position_m, wxyz=wxyz_of(fan.mount))
            api.add_line_segments(f"{node}/fov", fan.segments(), colour, thickness=2.0, thickness_units="screen")
            vertices, faces = fan_surface(fan.limits)
            api.add_mesh_simple(f"{node}/fov_far", vertices, faces, color=colour, opacity=0.2, side="double")
            api.add_label(f"{node}/label", f"{fan.type_name} {fan.name}",
                          position=tuple(0.6 * fan.limits.range_max_m * np.array([1.0, 0.0, 0.0])))
            self.fan_nodes[node] = fan

    def _object_dragged(self, name: str):
        async def dragged(event) -> None:
            self.set_object_pose(name, *_from_gizmo(event.target.position, event.target.wxyz), source="gizmo")
        return dragged

    # ------------------------------------------------------------------ controls

    def _build_controls(self) -> None:
        gui = self.server.gui
        session = self.session
        pose = session.carrier_pose
        if session.has_vehicle:
            reach = max(f.limits.range_max_m for f in self.fan_nodes.values()) * 1.5
        else:
            reach = session.base.sonar.range_max_m * 1.5
        with gui.add_folder("Vehicle pose" if session.has_vehicle else "Sonar pose"):
            self.pose_sliders = []
            for label, value in zip(("x (m)", "y (m)", "z (m)"), pose.position_m):
                lo, hi = math.floor(value - reach), math.ceil(value + reach)
                self.pose_sliders.append(gui.add_slider(label, lo, hi, 0.01, round(value, 2)))
            for label, value, limit in zip(("roll (deg)", "pitch (deg)", "yaw (deg)"), pose.rpy_deg, (180, 90, 180)):
                self.pose_sliders.append(gui.add_slider(label, -limit, limit, 0.5, float(np.clip(value, -limit, limit))))
        for slider in self.pose_sliders:
            slider.on_update(self._slider_moved)
        #: The scene's clock, where objects move on their tracks (None: nothing moves on its own).
        self.time_slider = self.play = None
        if session.tracks:
            with gui.add_folder("Time"):
                self.time_slider = gui.add_slider("time (s)", 0.0, round(session.time_span_s, 2), 0.05, 0.0,
                                                  hint="the scene's clock: " + ", ".join(session.tracks)
                                                  + " on their tracks")
                self.play = gui.add_checkbox("play", False, hint="run the clock in real time (looping)")

            async def time_moved(event) -> None:
                if event.client is not None:
                    self.set_time(float(self.time_slider.value), source="slider")

            self.time_slider.on_update(time_moved)
            self._playing = True
            self._player = threading.Thread(target=self._play, name="sonarsim-viewer-clock", daemon=True)
            self._player.start()
        o = session.options
        with gui.add_folder("Image"):
            self.component = gui.add_dropdown("component", component_names(o.max_order), initial_value=o.component)
            self.max_order = gui.add_slider("max order", 1, VIEWER_MAX_ORDER, 1, o.max_order)
            self.bounce_boxes = [gui.add_checkbox(f"order {k} in the total", k in o.bounces, visible=k <= o.max_order)
                                 for k in range(1, VIEWER_MAX_ORDER + 1)]
            self.sensor = gui.add_checkbox("sensor", o.sensor, disabled=not session.sensor_available,
                                           hint="the device model (beam patterns, noise, TVG, output)")
            self.speckle = gui.add_checkbox("speckle", o.speckle, hint="random draws: speckle (and the sensor's noise)")
            self.colormap = gui.add_dropdown("colour map", COLORMAPS, initial_value=o.colormap)
            self.dynamic_range = gui.add_slider("dB window", 10.0, 90.0, 1.0, o.dynamic_range_db)
            self.gain = gui.add_slider("gain (dB)", -30.0, 30.0, 0.5, o.gain_db)
        for handle in (self.component, self.max_order, *self.bounce_boxes, self.sensor, self.speckle, self.colormap,
                       self.dynamic_range, self.gain):
            handle.on_update(self._switched)
        with gui.add_folder("Save"):
            files = session.saved_files
            self.save_button = gui.add_button("save scene and images" if len(files) > 1 else "save scene",
                                              hint=f"into {self.out}")
            listed = ", ".join(files[:-1]) + " and " + files[-1] if len(files) > 1 else files[0]
            self.save_status = gui.add_markdown(f"writes {listed} into `{self.out}`")
        if not session.shows_images:  # a vehicle without an FLS: the title and notes say why
            self.fan_image.visible = self.polar_image.visible = False
        self.save_button.on_click(lambda event: self.save())

    async def _slider_moved(self, event) -> None:
        if event.client is None:  # set by the server to follow a gizmo: nothing new
            return
        # Only the coordinate of the slider moved changes: the others are the session's (a
        # slider may show a clipped value, and would pull the sonar back to it).
        pose = self.session.carrier_pose
        values = [*pose.position_m, *pose.rpy_deg]
        k = next(k for k, slider in enumerate(self.pose_sliders) if slider is event.target)
        values[k] = float(event.target.value)
        self.set_sonar_pose(values[:3], values[3:], source="slider")

    async def _switched(self, event) -> None:
        if event.client is None:
            return
        max_order = int(self.max_order.value)
        bounces = tuple(k for k, box in enumerate(self.bounce_boxes, 1) if box.value and k <= max_order)
        changes: dict[str, Any] = dict(
            component=self.component.value, max_order=max_order, sensor=bool(self.sensor.value),
            speckle=bool(self.speckle.value), colormap=self.colormap.value,
            dynamic_range_db=float(self.dynamic_range.value), gain_db=float(self.gain.value))
        if bounces:
            changes["bounces"] = bounces
        # Its components listed only for an order the viewer offers (the list is as long as the
        # order); any other is refused by set_options, and said on the page.
        if 1 <= max_order <= VIEWER_MAX_ORDER and changes["component"] not in component_names(max_order):
            changes["component"] = "total"
        self.set_options(**changes)

    # ------------------------------------------------------------------ the API (what the page's controls call)

    def set_sonar_pose(self, position_m: Sequence[float], rpy_deg: Sequence[float], source: str = "api") -> None:
        """Move the sonar (with instruments: the vehicle, and every instrument with it) as a
        drag of its gizmo does: the session, the gizmo and the sliders follow, and the images
        are re-rendered (asynchronously; :meth:`wait` for them)."""
        pose = self.session.set_carrier_pose(position_m, rpy_deg)
        if source != "gizmo":
            self.sonar_control.position = pose.position_m
            self.sonar_control.wxyz = wxyz_of(pose)
        if source != "slider":
            for k, (slider, value) in enumerate(zip(self.pose_sliders, (*pose.position_m, *pose.rpy_deg))):
                if k < 3 and not slider.min <= value <= slider.max:  # dragged beyond: widen the range
                    slider.min, slider.max = min(slider.min, math.floor(value)), max(slider.max, math.ceil(value))
                slider.value = float(np.clip(value, slider.min, slider.max))
        self.request_update()

    def set_vehicle_pose(self, position_m: Sequence[float], rpy_deg: Sequence[float], source: str = "api") -> None:
        """Move the vehicle of a scene with instruments (its gizmo, ``/vehicle``, does the same):
        every fan follows at its mount, and the FLS's images are re-rendered.

        Raises
        ------
        ConfigError
            A scene without instruments (it has a sonar to move: :meth:`set_sonar_pose`).
        """
        if not self.session.has_vehicle:
            raise ConfigError("pose", "this scene has no vehicle (no instruments): move its sonar")
        self.set_sonar_pose(position_m, rpy_deg, source)

    def set_object_pose(self, name: str, position_m: Sequence[float], rpy_deg: Sequence[float],
                        source: str = "api") -> None:
        """Move an object as a drag of its gizmo does; the images are re-rendered."""
        pose = self.session.set_object_pose(name, position_m, rpy_deg)
        if source != "gizmo":
            control = self.object_controls[name]
            control.position = pose.position_m
            control.wxyz = wxyz_of(pose)
        self.request_update()

    def set_time(self, t_s: float, source: str = "api") -> None:
        """Move the scene's clock (:meth:`SceneSession.set_time`): the tracked objects' gizmos
        follow, the images are re-rendered."""
        try:
            t = self.session.set_time(t_s)
        except SonarsimError as exc:
            self.error = str(exc)
            self._show_status()
            return
        for name in self.session.tracks:
            pose = self.session.object_poses[name]
            control = self.object_controls[name]
            control.position = pose.position_m
            control.wxyz = wxyz_of(pose)
        if source != "slider" and self.time_slider is not None:
            self.time_slider.value = float(min(t, self.time_slider.max))
        self.request_update()

    def _play(self) -> None:
        # Runs the clock while "play" is ticked, 10 steps a second, looping over the slider's span.
        while self._playing:
            time.sleep(0.1)
            if self.play is not None and self.play.value:
                span = float(self.time_slider.max)
                self.set_time(round((self.session.time_s + 0.1) % span, 6) if span > 0 else 0.0)

    def close(self) -> None:
        self._playing = False
        super().close()

    def set_options(self, **changes: Any) -> None:
        """Change switches (see :meth:`SceneSession.set_options`); the controls follow."""
        try:
            o = self.session.set_options(**changes)
        except SonarsimError as exc:
            self.error = str(exc)
            self._show_status()
            return
        names = component_names(o.max_order)
        if tuple(self.component.options) != names:
            self.component.options = names
        self.component.value = o.component
        self.max_order.value = o.max_order
        for k, box in enumerate(self.bounce_boxes, 1):
            box.visible = k <= o.max_order
            box.value = k in o.bounces
        self.sensor.value, self.speckle.value, self.colormap.value = o.sensor, o.speckle, o.colormap
        self.request_update()

    def save(self) -> list[Path]:
        """Write the scene file with the current poses and the current images into :attr:`out`."""
        try:
            files = self.session.save(self.out, self.command, self.log)
        except (SonarsimError, OSError) as exc:
            self.save_status.content = f"**not saved:** {exc}"
            self.log(f"not saved: {exc}")
            return []
        self.save_status.content = "saved " + ", ".join(f"`{f}`" for f in files)
        self.log(f"saved {', '.join(map(str, files))}")
        return files


class RecordingViewer(_Page):
    """The page of a recording: its polar and fan images with a frame slider (no 3D scene)."""

    def __init__(self, server, session: RecordingSession) -> None:
        super().__init__(server, session)
        gui = server.gui
        with gui.add_folder("Frames"):
            self.frame_slider = gui.add_slider("frame", 0, max(session.n_frames - 1, 1), 1, 0,
                                               disabled=session.n_frames < 2)
            self.play = gui.add_checkbox("play", False)
        with gui.add_folder("Image"):
            o = session.options
            self.mapping = gui.add_dropdown("mapping", ("linear", "db"), initial_value=o.mapping)
            self.colormap = gui.add_dropdown("colour map", COLORMAPS, initial_value=o.colormap)
            self.dynamic_range = gui.add_slider("dB window", 10.0, 90.0, 1.0, o.dynamic_range_db)
            self.gain = gui.add_slider("gain (dB)", -30.0, 30.0, 0.5, o.gain_db)

        async def frame_moved(event) -> None:
            if event.client is not None:
                self.set_frame(int(self.frame_slider.value))

        async def switched(event) -> None:
            if event.client is not None:
                self.session.set_options(mapping=self.mapping.value, colormap=self.colormap.value,
                                         dynamic_range_db=float(self.dynamic_range.value),
                                         gain_db=float(self.gain.value))
                self.request_update()

        self.frame_slider.on_update(frame_moved)
        for handle in (self.mapping, self.colormap, self.dynamic_range, self.gain):
            handle.on_update(switched)
        self._player = threading.Thread(target=self._play, name="sonarsim-viewer-play", daemon=True)
        self._playing = True
        self._player.start()
        self.request_update()

    def set_frame(self, frame: int) -> None:
        """Show another frame (the slider follows)."""
        shown = self.session.set_frame(frame)
        self.frame_slider.value = shown
        self.request_update()

    def _play(self) -> None:
        # Steps through the frames while "play" is ticked, at up to 10 frames a second.
        while self._playing:
            time.sleep(0.1)
            if self.play.value and self.session.n_frames > 1:
                self.set_frame((self.session.frame + 1) % self.session.n_frames)

    def close(self) -> None:
        self._playing = False
        super().close()
