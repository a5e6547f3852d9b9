"""What the viewer takes from the network: whose connections, and which messages.

viser, as it comes, accepts a WebSocket connection from any web page (any ``Origin``) and by
any name (any ``Host``), and applies what a client sends before looking at it: a slider set to
``1e308`` was cast to an integer of 1024 bits, kept in viser's persistent message buffer, and
sent to every client that connected later, whose connection then closed with 1011 (msgpack
cannot hold it) until the server was restarted. Any page open in the user's browser could send
that to ``127.0.0.1``. Two checks now stand in front of viser:

* :class:`HandshakeGuard`, at the opening handshake of every request (the page's files and the
  WebSocket): the ``Host`` header must name an address the server listens on, and an
  ``Origin`` header, where there is one, must be the page's own origin, ``http://HOST:PORT``.
  Refused requests get ``403 Forbidden``. See :class:`HandshakeGuard` for the names accepted.
* :class:`MessageGate`, on every message a client sends, before viser decodes or applies it:
  only the messages the page needs are taken (a control's new value, a gizmo's pose, a gizmo
  drag's start and end, the client's camera), each field of the type viser expects, and a value
  within its control's own bounds (a slider's range, a dropdown's options; a gizmo's pose
  finite, within :data:`GIZMO_LIMIT_M`, its quaternion of unit norm). Anything else is dropped
  for that client alone, and the current value of what it named is sent again (so that the
  sender's page shows the state); the state, the other clients and later connections never
  see the message.

How they are put in front of viser (1.x), which has no hook for either: :func:`start_guarded_server`.
"""

from __future__ import annotations

import collections
import http
import ipaddress
import logging
import math
import socket
import threading
import weakref
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from ...errors import SonarsimError

__all__ = ["GIZMO_LIMIT_M", "HandshakeGuard", "MessageGate", "TAKEN_MESSAGES", "gate_of", "guard_of",
           "start_guarded_server"]

LOG = logging.getLogger("sonarsim.viewer")

#: Largest coordinate (m) a client may drag a gizmo to: far beyond any sonar's range, far
#: within what every consumer of a pose (the renderer, the sliders that follow it, msgpack)
#: handles. A drag in the page never comes near it.
GIZMO_LIMIT_M = 1e4
#: How far from 1 a gizmo quaternion's norm may be (the page sends unit quaternions, exact to
#: float rounding; a client that sends another would scale the object on every page).
QUATERNION_TOLERANCE = 1e-3
#: Largest image size (pixels) a client may report for its camera.
MAX_CAMERA_PIXELS = 1 << 16
#: Largest message a client may send (bytes). The page's messages take a few hundred; viser
#: takes up to 50 MB, which msgpack may unpack into hundreds of millions of objects.
MAX_MESSAGE_BYTES = 64 * 1024
#: The largest message a client's connection survives (refused by the gate); larger ones end it.
MAX_FRAME_BYTES = 2**20

# Names by which every loopback server may be reached: a page loaded from one of them is the
# viewer's own page, whichever of the three the user typed.
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
# Hosts that mean "every address of this machine".
WILDCARD_HOSTS = frozenset({"", "0.0.0.0", "::"})

# The messages a client may send and their fields, as viser 1.x defines them (a test compares
# these with viser's own dataclasses, so that an upgrade that changes them fails loudly):
# "str", "dict", "real" (a finite number), "int", an integer n (n finite numbers), and a
# trailing "?" for a field that may be left out. Everything else a client may send -- uploads,
# share-URL requests (which open a public tunnel), clicks, forms, commands -- is not used by
# the viewer and is refused.
TAKEN_MESSAGES: dict[str, dict[str, Any]] = {
    "GuiUpdateMessage": {"uuid": "str", "updates": "dict"},
    "TransformControlsUpdateMessage": {"name": "str", "wxyz": 4, "position": 3, "owner": "str?"},
    "TransformControlsDragStartMessage": {"name": "str", "owner": "str?"},
    "TransformControlsDragEndMessage": {"name": "str", "owner": "str?"},
    "ViewerCameraMessage": {"wxyz": 4, "position": 3, "fov": "real", "near": "real", "far": "real",
                            "image_height": "int", "image_width": "int", "look_at": 3, "up_direction": 3},
}

# The handler viser hands to ``websockets.asyncio.server.serve`` (see start_guarded_server).
VISER_HANDLER = "WebsockServer._background_worker.<locals>.ws_handler"


# ---------------------------------------------------------------------------- names and addresses


def normal_host(text: str) -> str | None:
    """A host as compared here: lower case, without a final dot, an IP address in its short
    form (an IPv4 address mapped into IPv6 as the IPv4 address); ``None`` for an empty one."""
    host = text.strip().lower()
    if host.endswith("."):
        host = host[:-1]
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    if not host:
        return None
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return host
    mapped = getattr(address, "ipv4_mapped", None)
    return str(mapped if mapped is not None else address)


def split_authority(text: str) -> tuple[str, int | None] | None:
    """``host``, ``host:port``, ``[v6]`` or ``[v6]:port`` as (normal host, port or ``None``);
    ``None`` for anything else (user info, a path, a bad port, spaces)."""
    if not text or any(c in text for c in "/?#@\\ \t\r\n"):
        return None
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            return None
        host, rest = text[1:end], text[end + 1:]
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            return None
    else:
        host, colon, port = text.partition(":")
        rest = colon + port
    if not rest:
        port_number = None
    elif rest.startswith(":") and 1 < len(rest) <= 6 and rest[1:].isascii() and rest[1:].isdigit():
        port_number = int(rest[1:])
        if port_number > 65535:
            return None
    else:
        return None
    name = normal_host(host)
    return None if name is None else (name, port_number)


def machine_names() -> frozenset[str]:
    """This machine's own names, without asking DNS: its host name, the short name and the
    short name under ``.local`` (mDNS). Addresses are not listed: :class:`HandshakeGuard`
    accepts the address each connection arrived at."""
    names = set()
    try:
        hostname = socket.gethostname()
    except OSError:
        return frozenset()
    for name in (hostname, hostname.split(".")[0], hostname.split(".")[0] + ".local"):
        normal = normal_host(name)
        if normal:
            names.add(normal)
    return frozenset(names)


def listen_names(host: str) -> frozenset[str]:
    """The names a request to a server listening on ``host`` may use in ``Host`` and ``Origin``
    (besides the address each connection arrived at).

    * A loopback address (``127.0.0.1``, ``::1``, ``localhost``): the three loopback names,
      which all reach the same server.
    * Every address (``0.0.0.0``, ``::``, ``""``): the loopback names and this machine's own
      names (:func:`machine_names`).
    * Another address or name: that one.
    """
    if host.strip() in WILDCARD_HOSTS or normal_host(host) in ("0.0.0.0", "::"):
        return LOOPBACK_NAMES | machine_names()
    name = normal_host(host)
    if name is None:
        return LOOPBACK_NAMES | machine_names()
    try:
        loopback = name == "localhost" or ipaddress.ip_address(name).is_loopback
    except ValueError:
        loopback = False
    return LOOPBACK_NAMES | {name} if loopback else frozenset({name})


# ---------------------------------------------------------------------------- the handshake


class HandshakeGuard:
    """Refuses, at the opening handshake, requests that are not the viewer's own page's.

    A request is served only if

    * its one ``Host`` header names this server: a name of :func:`listen_names` or the address
      the connection arrived at, and the port it arrived at (no port: 80). A browser always
      sends the name the user typed, so a page of another site whose name was made to resolve
      to this machine (DNS rebinding: ``Host: evil.example.com:8080``) is refused, while every
      way of typing this machine's address is not;
    * its ``Origin`` header, where it has one, is ``http://NAME:PORT`` with a name and port as
      above: every browser sends the origin of the page that opens a WebSocket, so a page of
      any other site (``Origin: http://evil.example.com``), a page of another port of this
      machine and a sandboxed page (``Origin: null``) are refused.

    A request without ``Origin`` is served: browsers always send one, so it comes from a
    program (a script, a test), which can send any ``Origin`` it likes -- refusing it would
    protect nothing. (On ``--host 0.0.0.0`` such programs on other machines can connect: that
    is the "without any authentication" the command warns about.)

    What is refused with this: a page reached through a name this machine does not know as its
    own (a DNS alias, a reverse proxy that rewrites ``Host``, a tunnel or NAT to another port:
    forward the same port number, ``ssh -L 8080:127.0.0.1:8080``, and open
    ``http://127.0.0.1:8080/``).

    Parameters
    ----------
    host : str
        The address the server listens on (``--host``).
    log : callable, optional
        Receives one line for the first refusal of each reason (not every one: a page that
        retries must not flood the terminal).

    Attributes
    ----------
    names : frozenset of str
        :func:`listen_names` of ``host``.
    refused : collections.Counter
        Refused requests by reason (its first words).
    """

    def __init__(self, host: str, log: Callable[[str], None] | None = None) -> None:
        self.host = host
        self.names = listen_names(host)
        self.log = log
        self.refused: collections.Counter = collections.Counter()
        self._said: set[str] = set()
        self._lock = threading.Lock()

    def check(self, hosts: list[str], origins: list[str], local_address: Any) -> str | None:
        """Why a request with these ``Host`` and ``Origin`` headers, arrived at
        ``local_address`` (the socket's ``(address, port, ...)``), is refused; ``None`` if it is not.
        """
        port = int(local_address[1])
        reached = normal_host(str(local_address[0]))
        names = self.names | {reached} if reached else self.names
        shown = f"http://{_shown(self.host)}:{port}"
        if len(hosts) != 1:
            return f"{'no' if not hosts else 'more than one'} Host header"
        authority = split_authority(hosts[0])
        if authority is None or authority[0] not in names or _port(authority[1]) != port:
            return f"Host {_quoted(hosts[0])} does not name this viewer ({shown})"
        if len(origins) > 1:
            return "more than one Origin header"
        if origins:
            origin = _origin(origins[0])
            if origin is None or origin[0] not in names or origin[1] != port:
                return f"Origin {_quoted(origins[0])} is not this viewer's page ({shown})"
        return None

    def __call__(self, connection, request):
        """``process_request`` of :mod:`websockets`: ``None`` (go on) or a 403 response."""
        reason = self.check(request.headers.get_all("Host"), request.headers.get_all("Origin"),
                            connection.local_address)
        if reason is None:
            return None
        with self._lock:
            self.refused[reason.split(" (")[0].split(" '")[0]] += 1
            first = reason not in self._said and len(self._said) < 100
            if first:
                self._said.add(reason)
        LOG.info("refused a request: %s", reason)
        if first and self.log is not None:
            self.log(f"refused a connection: {reason}")
        return connection.respond(http.HTTPStatus.FORBIDDEN, f"sonarsim view refused this request: {reason}\n")

    def wrap(self, process_request):
        """``process_request`` that checks first, then hands what passes to ``process_request``
        (viser's: it serves the page's files)."""

        def guarded(connection, request):
            response = self(connection, request)
            if response is not None or process_request is None:
                return response
            return process_request(connection, request)

        return guarded


def _port(port: int | None) -> int:
    return 80 if port is None else port


def _shown(host: str) -> str:
    name = normal_host(host)
    if host.strip() in WILDCARD_HOSTS or name in (None, "0.0.0.0", "::"):
        return "127.0.0.1"
    return f"[{name}]" if ":" in name else name


def _quoted(text: str) -> str:
    """An untrusted header value in a message: quoted, escaped, cut to 80 characters."""
    shown = repr(text[:80])
    return shown + ("..." if len(text) > 80 else "")


def _origin(text: str) -> tuple[str, int] | None:
    """``http://host[:port]`` as (normal host, port); ``None`` for anything else (another
    scheme, a path, user info, ``null``)."""
    try:
        parts = urlsplit(text)
    except ValueError:
        return None
    if parts.scheme != "http" or parts.path or parts.query or parts.fragment or text != f"http://{parts.netloc}":
        return None
    authority = split_authority(parts.netloc)
    return None if authority is None else (authority[0], _port(authority[1]))


# ---------------------------------------------------------------------------- the messages


class Refused(Exception):
    """A message the gate does not pass on: ``reason`` (a category, for the counts) and
    ``detail``; ``resync``: viser messages that restate the current state of what it named."""

    def __init__(self, reason: str, detail: str = "", resync: tuple = ()) -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.resync = resync


class MessageGate:
    """Passes to viser only the messages of :data:`TAKEN_MESSAGES` whose every field is sound.

    Each message a client sends is decoded (msgpack, as viser does) and checked before viser
    sees it:

    * it is at most :data:`MAX_MESSAGE_BYTES` long;
    * its type is one of :data:`TAKEN_MESSAGES`, with exactly those fields, each of its kind;
    * a control's update (``GuiUpdateMessage``) names a control of the page that is not
      disabled and changes its ``value`` alone, to a value of the control's type within its
      bounds: a slider a finite number from its ``min`` to its ``max`` (an integer for an
      integer slider), a checkbox ``true`` or ``false``, a dropdown one of its options, a
      button ``true``;
    * a gizmo's pose (``TransformControlsUpdateMessage``) names a gizmo of the page, with a
      position within :data:`GIZMO_LIMIT_M` of the origin and a unit quaternion;
    * a camera's numbers are finite, its image size from 0 to :data:`MAX_CAMERA_PIXELS`.

    A message that fails is dropped -- viser never decodes it, the state and every other
    client are untouched -- and the current value of the control or the pose of the gizmo it
    named is queued again, so that the sender's page, which shows what its user did, shows the
    state again. It is queued for every client, in viser's broadcast buffer, where it is
    ordered with every other change (sent to the sender alone, through its own buffer, it
    could arrive after a later change and show a stale value); the others hold that value
    already, and viser coalesces repeats. The connection stays open (a malformed message
    costs the client nothing but that message).

    The controls and gizmos are viser's own registries of the server's page (what viser itself
    would dispatch to), read at each message: a slider whose range widens, a dropdown whose
    options change, are checked against their bounds of the moment.

    Attributes
    ----------
    accepted, refused : collections.Counter
        Messages passed by type; dropped by reason.
    """

    def __init__(self) -> None:
        self.server = None
        self.accepted: collections.Counter = collections.Counter()
        self.refused: collections.Counter = collections.Counter()
        self._lock = threading.Lock()

    def attach(self, server) -> None:
        """Check the messages against the controls of ``server`` (a ``viser.ViserServer``);
        until then every control update is refused (no control is known)."""
        self.server = server

    def wrap_handler(self, handler):
        """viser's connection handler with the gate in front of its ``recv``: each message
        viser's consumer reads has passed :meth:`admit`."""
        gate = self

        async def gated_handler(connection) -> None:
            recv = connection.recv

            async def gated_recv(*args, **kwargs):
                while True:
                    data = await recv(*args, **kwargs)
                    if gate.admit(data):
                        return data

            # An attribute of this one connection: viser's consumer calls connection.recv().
            connection.recv = gated_recv
            await handler(connection)

        return gated_handler

    def admit(self, data: Any) -> bool:
        """Whether viser may have the message ``data``; counts it, and queues the current
        state of what a refused message named (see the class)."""
        try:
            kind = self.check(data)
        except Refused as refusal:
            with self._lock:
                self.refused[refusal.reason] += 1
            LOG.debug("refused a message: %s", refusal)
            if self.server is not None:
                for message in refusal.resync:
                    self.server._websock_server.queue_message(message)
            return False
        except Exception as exc:  # noqa: BLE001 - a bug of the gate: the message is refused (fail closed)
            with self._lock:
                self.refused["error in the check"] += 1
            LOG.warning("refused a message the check failed on: %s: %s", type(exc).__name__, exc)
            return False
        with self._lock:
            self.accepted[kind] += 1
        return True

    # ------------------------------------------------------------------ the checks

    def check(self, data: Any) -> str:
        """The type of a message that may pass.

        Raises
        ------
        Refused
            Naming why not, with the messages that resynchronise its sender.
        """
        import msgspec

        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise Refused("not a binary message", type(data).__name__)
        if len(data) > MAX_MESSAGE_BYTES:
            raise Refused("too large", f"{len(data)} bytes")
        try:
            raw = msgspec.msgpack.decode(data)
        except (msgspec.DecodeError, RecursionError, ValueError, MemoryError) as exc:
            raise Refused("malformed msgpack", str(exc)) from None
        if not isinstance(raw, dict) or not isinstance(raw.get("type"), str):
            raise Refused("not a message", "a map with a string 'type'")
        kind = raw["type"]
        schema = TAKEN_MESSAGES.get(kind)
        if schema is None:
            raise Refused("message type not taken", kind[:80])
        try:
            _check_fields(raw, schema)
            if kind == "GuiUpdateMessage":
                self._check_control(raw["uuid"], raw["updates"])
            elif kind.startswith("TransformControls"):
                self._check_gizmo(raw)
            else:  # ViewerCameraMessage
                for name in ("image_height", "image_width"):
                    if not 0 <= raw[name] <= MAX_CAMERA_PIXELS:
                        raise Refused("bad camera", f"{name} {raw[name]}")
        except Refused as refusal:
            # Whatever was wrong with it, a message that names a control or a gizmo of the
            # page gets the sender the current state of that one back.
            if not refusal.resync:
                refusal.resync = self._current_state(raw)
            raise
        # Last: viser's own decoding of what passes must not fail (it would close the
        # connection with 1011 and print a traceback).
        from viser import _messages

        try:
            _messages.Message.deserialize(bytes(data))
        except Exception as exc:  # noqa: BLE001 - whatever viser would have raised
            raise Refused("not decodable by viser", f"{type(exc).__name__}: {exc}") from None
        return kind

    def _controls(self) -> dict:
        gui = getattr(self.server, "gui", None)
        return getattr(gui, "_gui_input_handle_from_uuid", {}) if gui is not None else {}

    def _gizmos(self) -> dict:
        scene = getattr(self.server, "scene", None)
        return getattr(scene, "_handle_from_transform_controls_name", {}) if scene is not None else {}

    def _current_state(self, raw: dict) -> tuple:
        """The messages that give a client back the current value of the control or the pose of
        the gizmo that ``raw`` names (none for a button, or a name the page does not have)."""
        from viser import _messages

        if raw.get("type") == "GuiUpdateMessage" and isinstance(raw.get("uuid"), str):
            handle = self._controls().get(raw["uuid"])
            if handle is not None and not _is_instance(handle, "GuiButtonHandle"):
                return (_messages.GuiUpdateMessage(raw["uuid"], {"value": handle.value}),)
        elif raw.get("type") == "TransformControlsUpdateMessage" and isinstance(raw.get("name"), str):
            handle = self._gizmos().get(raw["name"])
            if handle is not None:
                name = raw["name"]
                return (_messages.SetPositionMessage(name, tuple(float(v) for v in handle.position)),
                        _messages.SetOrientationMessage(name, tuple(float(v) for v in handle.wxyz)))
        return ()

    def _check_control(self, uuid: str, updates: dict) -> None:
        handle = self._controls().get(uuid)
        if handle is None:
            raise Refused("unknown control", uuid[:80])
        if set(updates) != {"value"}:
            keys = ", ".join(sorted(repr(k)[:40] for k in updates)[:5])
            raise Refused("not a value update", f"{handle.label!r}: {keys}")
        if handle.disabled:
            raise Refused("disabled control", repr(handle.label))
        problem = _value_problem(handle, updates["value"])
        if problem is not None:
            raise Refused("bad value", f"{handle.label!r}: {problem}")

    def _check_gizmo(self, raw: dict) -> None:
        name = raw["name"]
        if name not in self._gizmos():
            raise Refused("unknown gizmo", name[:80])
        if raw["type"] != "TransformControlsUpdateMessage":
            return  # a drag's start or end: the name is all it carries
        position, wxyz = raw["position"], raw["wxyz"]
        if max(abs(v) for v in position) > GIZMO_LIMIT_M:
            raise Refused("bad pose", f"{name}: position {position} beyond {GIZMO_LIMIT_M:g} m")
        norm = math.sqrt(math.fsum(v * v for v in wxyz))
        if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:
            raise Refused("bad pose", f"{name}: quaternion of norm {norm:.6g}")


def _is_instance(handle, name: str) -> bool:
    import viser

    cls = getattr(viser, name, None)
    return cls is not None and isinstance(handle, cls)


def _is_real(value: Any) -> bool:
    """A finite int or float (not a bool: msgpack's true is no number)."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return True
    return isinstance(value, float) and math.isfinite(value)


def _check_fields(raw: dict, schema: dict[str, Any]) -> None:
    """The fields of ``raw`` (besides ``type``) are those of ``schema``, each of its kind."""
    kind = raw["type"]
    given = set(raw) - {"type"}
    required = {k for k, v in schema.items() if not (isinstance(v, str) and v.endswith("?"))}
    unknown = given - set(schema)
    if unknown:
        raise Refused("unknown field", f"{kind}: {sorted(repr(k)[:40] for k in unknown)[:5]}")
    if required - given:
        raise Refused("missing field", f"{kind}: {sorted(required - given)}")
    for name in given:
        want, value = schema[name], raw[name]
        want = want.rstrip("?") if isinstance(want, str) else want
        if want == "str":
            ok = isinstance(value, str)
        elif want == "dict":
            ok = isinstance(value, dict)
        elif want == "real":
            ok = _is_real(value)
        elif want == "int":
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:  # n finite numbers
            ok = isinstance(value, (list, tuple)) and len(value) == want and all(_is_real(v) for v in value)
        if not ok:
            shown = f"{type(value).__name__} {repr(value)[:60]}"
            wanted = want if isinstance(want, str) else f"{want} numbers"
            raise Refused("bad field", f"{kind}.{name}: {shown}, not {wanted}")


def _value_problem(handle, value: Any) -> str | None:
    """Why ``value`` cannot be the value of the control ``handle``; ``None`` if it can."""
    if _is_instance(handle, "GuiSliderHandle"):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"{type(value).__name__} for a slider"
        if not _is_real(value):
            return f"{value!r} is not finite"
        lo, hi = handle.min, handle.max
        if not lo <= value <= hi:
            return f"{repr(value)[:40]} outside {lo}..{hi}"
        current = handle.value
        if isinstance(current, int) and not isinstance(current, bool) and value != int(value):
            return f"{value!r} for an integer slider"
        return None
    if _is_instance(handle, "GuiCheckboxHandle"):
        return None if isinstance(value, bool) else f"{type(value).__name__} for a checkbox"
    if _is_instance(handle, "GuiDropdownHandle"):
        if isinstance(value, str) and value in tuple(handle.options):
            return None
        return f"{repr(value)[:60]} is not one of its options"
    if _is_instance(handle, "GuiButtonHandle"):
        return None if value is True else f"{repr(value)[:40]} for a button (true)"
    return f"the viewer takes no input from a {type(handle).__name__}"


# ---------------------------------------------------------------------------- the hook into viser


_GUARDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_SERVE_LOCK = threading.Lock()


def start_guarded_server(host: str, port: int, log: Callable[[str], None] | None = None):
    """A ``viser.ViserServer`` on ``host:port`` with a :class:`HandshakeGuard` and a
    :class:`MessageGate` in front of it.

    viser (1.x) builds its server in ``WebsockServer._background_worker``, a thread that its
    constructor starts and waits for, as
    ``websockets.asyncio.server.serve(ws_handler, host, port, process_request=..., ...)`` with
    ``ws_handler`` and ``process_request`` (it serves the page's files) local functions: there
    is no hook to add a check to either. For the duration of the constructor (and under a lock,
    one such start at a time), ``websockets.asyncio.server.serve`` is replaced by a function
    that hands every call on unchanged except viser's own -- its handler is
    :data:`VISER_HANDLER`, its host ``host`` -- to which it gives the guard in front of
    viser's ``process_request`` and the gate in front of the handler's ``recv``. The original
    is back when the constructor returns. If viser did not start its server through it (a
    viser that starts it otherwise), or lacks the registries of controls and gizmos the gate
    reads, the server is stopped and this refuses: the viewer is never served unguarded. ``tests/plot/test_viewer_guard.py`` pins each of these points.

    Returns
    -------
    server : viser.ViserServer
        Running; :func:`guard_of` and :func:`gate_of` give its checks.

    Raises
    ------
    SonarsimError
        This viser starts its server in a way the guard cannot hook into.
    """
    import contextlib
    import io

    import viser
    import websockets.asyncio.server as ws_server

    guard = HandshakeGuard(host, log=log)
    gate = MessageGate()
    hooked: list[int] = []
    with _SERVE_LOCK:
        real_serve = ws_server.serve

        def serve(handler, *args, **kwargs):
            if getattr(handler, "__qualname__", "") == VISER_HANDLER and args[:1] == (host,):
                kwargs["process_request"] = guard.wrap(kwargs.get("process_request"))
                # websockets buffers a whole message before the gate sees it, and viser allows
                # 50 MB a message: up to MAX_FRAME_BYTES the gate refuses what is over
                # MAX_MESSAGE_BYTES and the connection stays; beyond, websockets closes that
                # client alone (1009) without buffering it.
                kwargs["max_size"] = MAX_FRAME_BYTES
                handler = gate.wrap_handler(handler)
                hooked.append(threading.get_ident())
            return real_serve(handler, *args, **kwargs)

        ws_server.serve = serve
        try:
            # viser prints its own address box on stdout; the command says where to point the browser.
            with contextlib.redirect_stdout(io.StringIO()):
                server = viser.ViserServer(host=host, port=port, verbose=False)
        finally:
            ws_server.serve = real_serve
    websock = getattr(server, "_websock_server", None)
    thread = getattr(websock, "_server_thread", None)
    # What the gate reads (viser's registries of the page's controls and gizmos, what viser
    # itself dispatches to) and where it restates a value: without them it would refuse every
    # change, and the page would not respond.
    found = (hasattr(server.gui, "_gui_input_handle_from_uuid")
             and hasattr(server.scene, "_handle_from_transform_controls_name") and hasattr(websock, "queue_message"))
    if thread is None or thread.ident not in hooked or not found:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
        raise SonarsimError(
            f"viser {getattr(viser, '__version__', '?')} starts its server in a way sonarsim's viewer cannot check "
            "(the origin of connections, the values clients send), so it does not serve the page; install the "
            "viser the viewer is tested with: pip install 'viser>=1.0,<2'")
    gate.attach(server)
    _GUARDS[server] = (guard, gate)
    return server


def guard_of(server) -> HandshakeGuard:
    """The :class:`HandshakeGuard` of a server from :func:`start_guarded_server`."""
    return _GUARDS[server][0]


def gate_of(server) -> MessageGate:
    """The :class:`MessageGate` of a server from :func:`start_guarded_server`."""
    return _GUARDS[server][1]
