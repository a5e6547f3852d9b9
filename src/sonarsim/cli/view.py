"""``sonarsim view``: a scene in 3D in the browser with its live sonar images, or a recording.

``sonarsim view SCENE`` serves a page (viser) with the scene in 3D -- objects, planes, the sonar
and its field of view -- gizmos and sliders to move the sonar and the objects, the polar and fan
images re-rendered at every change, switches for the components, bounces and sensor effects,
and a button that saves the scene file with the current poses and the images into ``--out``.
``sonarsim view RECORDING`` (an ARIS or Oculus file, recognised by content) shows its frames
with a frame slider. The page is served on 127.0.0.1 by default; the command says where to
point the browser and runs until Ctrl-C (exit status 130).

The server takes connections only from its own page: a request whose ``Host`` header does not
name the server (DNS rebinding) or whose ``Origin`` is another site's is refused with 403, and
the command says so once per reason; the values a page sends are checked against each
control's bounds before they are applied (:mod:`sonarsim.plot.viewer.guard`).

Needs the ``viewer`` extra (:func:`sonarsim.core.extras.install_command`: ``pip install -e '.[viewer]'``
in a clone).
"""

from __future__ import annotations

import argparse
import ipaddress
import threading
import time
from pathlib import Path

from ..core.console import log as _log
from ..core.extras import install_command

__all__ = ["add_view_parser", "cmd_view", "serve", "target_kind"]

#: Suffixes of scene files: never read as recordings.
SCENE_SUFFIXES = (".yaml", ".yml", ".json")
#: Suffixes of recordings: a file so named that is no recording is reported as such.
RECORDING_SUFFIXES = (".aris", ".raw", ".ddf")


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number from 0 (any free port) to 65535, got {text!r}")
    return value


def add_view_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``view`` sub-command to an ``add_subparsers()`` object; sets ``func=cmd_view``."""
    p = subparsers.add_parser(
        "view", help="look at a scene in 3D in the browser with its live sonar images, or at a recording",
        description="Serve a local web page (viser) showing a scene in 3D -- objects, planes, the sonar and its "
        "field of view -- with gizmos and sliders to move the sonar and the objects, the live polar and fan images, "
        "switches for components, bounces and sensor effects, and a button that saves scene.yaml (the current "
        "poses), polar.png and fan.png into --out. Given a recording (ARIS .aris, Oculus .raw; recognised by "
        "content), shows its frames with a frame slider. Runs until Ctrl-C. Needs the viewer extra: "
        f"{install_command('viewer')}.")
    p.add_argument("target", metavar="SCENE|RECORDING", help="a scene file (YAML/JSON) or a recording")
    p.add_argument("--port", type=_port, default=8080, metavar="N",
                   help="port of the page (default: 8080; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", metavar="H",
                   help="address to listen on (default: 127.0.0.1, this machine only; 0.0.0.0 opens the viewer "
                   "to the network, without any authentication). Browsers are served only the page opened by a "
                   "name of this address (127.0.0.1, localhost and [::1] for a loopback address; this machine's "
                   "name and the address reached for 0.0.0.0) on the same port")
    p.add_argument("--out", default="sonarsim-view", metavar="DIR",
                   help="folder the save button writes into (default: ./sonarsim-view)")
    p.add_argument("--backend", choices=("embree", "embree4", "embreex", "numpy"), default="embree",
                   help="ray-casting engine: embree (Embree 4 through sonarsim's binding where it loads, else "
                   "embreex), embree4 or embreex (that one only), numpy (slow reference)")
    p.set_defaults(func=cmd_view)
    return p


def target_kind(path: str) -> str:
    """``"scene"`` or ``"recording"``: scene files by suffix, recordings by content.

    Raises
    ------
    SonarsimError
        The file does not exist, or is named like a recording and is none (RecordingError).
    """
    from ..errors import SonarsimError
    from ..io.readers import RecordingError, detect_format

    p = Path(path)
    if not p.exists():
        raise SonarsimError(f"{path}: no such file (give a scene file or a recording)")
    if p.suffix.lower() in SCENE_SUFFIXES:
        return "scene"
    try:
        detect_format(p)
    except RecordingError:
        if p.suffix.lower() in RECORDING_SUFFIXES:
            raise
        return "scene"  # not a recording: loading it as a scene names what is wrong with it
    return "recording"


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def serve(args, stop: threading.Event | None = None, ready=None) -> None:
    """Run the viewer of ``args`` until Ctrl-C (or until ``stop`` is set).

    Parameters
    ----------
    args : argparse.Namespace
        ``target``, ``port``, ``host``, ``out``, ``backend`` (see :func:`add_view_parser`).
    stop : threading.Event, optional
        Ends the viewer when set (tests); default: run until interrupted.
    ready : callable, optional
        Called with the viewer and its URL once the page is served (tests).
    """
    from ..io.run_record import _add_note
    from ..plot.viewer import require_viser

    require_viser()  # first: without the extra, nothing else is worth doing
    from ..plot.viewer.app import RecordingViewer, SceneViewer, start_server, stop_server, url_of
    from ..plot.viewer.state import SAVED_FILES, RecordingSession, SceneSession

    kind = target_kind(args.target)
    command = getattr(args, "command_line", None)
    if kind == "scene":
        from ..io.run_record import OutputRun

        # The save button's folder is checked now, not when the first save fails.
        OutputRun.for_folder(args.out, SAVED_FILES, command=command)
        session = SceneSession(args.target, backend=args.backend)
    else:
        session = RecordingSession(args.target)
    try:
        server = start_server(args.host, args.port, log=_log)
    except BaseException:
        session.close()
        raise
    viewer = None
    try:
        if kind == "scene":
            viewer = SceneViewer(server, session, out=args.out, command=command, log=_log)
        else:
            viewer = RecordingViewer(server, session)
        url = url_of(server, args.host)
        what = f"the scene {args.target}" if kind == "scene" else f"the recording {args.target} ({session.n_frames} frames)"
        _log(f"viewing {what}: point your browser at {url}  (Ctrl-C stops the viewer)")
        if not _is_loopback(args.host):
            _log(f"note: --host {args.host} serves the viewer to other machines, without any authentication")
        if ready is not None:
            ready(viewer, url)
        while stop is None or not stop.is_set():
            if stop is None:
                time.sleep(3600)
            else:
                stop.wait(0.1)
    except KeyboardInterrupt as exc:
        _add_note(exc, "the viewer stopped")
        raise
    finally:
        try:
            if viewer is not None:
                viewer.close()
            else:
                session.close()
            stop_server(server)
        except KeyboardInterrupt as again:  # Ctrl-C twice: the second lands while stopping
            _add_note(again, "the viewer stopped")
            raise


def cmd_view(args) -> None:
    """Run ``sonarsim view`` (see :func:`serve`)."""
    serve(args)
