"""What the viewer takes from the network: whose connections.

viser, as it comes, accepts a WebSocket connection from any web page (any ``Origin``) and by
any name (any ``Host``): any page open in the user's browser could connect to the viewer on
``127.0.0.1`` and change its controls. :class:`HandshakeGuard` now stands in front of viser,
at the opening handshake of every request (the page's files and the WebSocket): the ``Host``
header must name an address the server listens on, and an ``Origin`` header, where there is
one, must be the page's own origin, ``http://HOST:PORT``. Refused requests get
``403 Forbidden``. See :class:`HandshakeGuard` for the names accepted.

How it is put in front of viser (1.x), which has no hook for it: :func:`start_guarded_server`.
"""

from __future__ import annotations

import collections
import http
import ipaddress
import logging
import socket
import threading
import weakref
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from ...errors import SonarsimError

__all__ = ["HandshakeGuard", "guard_of", "start_guarded_server"]

LOG = logging.getLogger("sonarsim.viewer")

# Names by which every loopback server may be reached: a page loaded from one of them is the
# viewer's own page, whichever of the three the user typed.
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
# Hosts that mean "every address of this machine".
WILDCARD_HOSTS = frozenset({"", "0.0.0.0", "::"})

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


# ---------------------------------------------------------------------------- the hook into viser


_GUARDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_SERVE_LOCK = threading.Lock()


def start_guarded_server(host: str, port: int, log: Callable[[str], None] | None = None):
    """A ``viser.ViserServer`` on ``host:port`` with a :class:`HandshakeGuard` in front of it.

    viser (1.x) builds its server in ``WebsockServer._background_worker``, a thread that its
    constructor starts and waits for, as
    ``websockets.asyncio.server.serve(ws_handler, host, port, process_request=..., ...)`` with
    ``ws_handler`` and ``process_request`` (it serves the page's files) local functions: there
    is no hook to add a check to either. For the duration of the constructor (and under a lock,
    one such start at a time), ``websockets.asyncio.server.serve`` is replaced by a function
    that hands every call on unchanged except viser's own -- its handler is
    :data:`VISER_HANDLER`, its host ``host`` -- to which it gives the guard in front of
    viser's ``process_request``. The original
    is back when the constructor returns. If viser did not start its server through it (a
    viser that starts it otherwise), the server is stopped and this refuses: the viewer is
    never served unguarded. ``tests/plot/test_viewer_guard.py`` pins each of these points.

    Returns
    -------
    server : viser.ViserServer
        Running; :func:`guard_of` gives its guard.

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
    hooked: list[int] = []
    with _SERVE_LOCK:
        real_serve = ws_server.serve

        def serve(handler, *args, **kwargs):
            if getattr(handler, "__qualname__", "") == VISER_HANDLER and args[:1] == (host,):
                kwargs["process_request"] = guard.wrap(kwargs.get("process_request"))
                hooked.append(threading.get_ident())
            return real_serve(handler, *args, **kwargs)

        ws_server.serve = serve
        try:
            # viser prints its own address box on stdout; the command says where to point the browser.
            with contextlib.redirect_stdout(io.StringIO()):
                server = viser.ViserServer(host=host, port=port, verbose=False)
        finally:
            ws_server.serve = real_serve
    thread = getattr(getattr(server, "_websock_server", None), "_server_thread", None)
    if thread is None or thread.ident not in hooked:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
        raise SonarsimError(
            f"viser {getattr(viser, '__version__', '?')} starts its server in a way sonarsim's viewer cannot check "
            "(the origin of connections), so it does not serve the page; install the "
            "viser the viewer is tested with: pip install 'viser>=1.0,<2'")
    _GUARDS[server] = guard
    return server


def guard_of(server) -> HandshakeGuard:
    """The :class:`HandshakeGuard` of a server from :func:`start_guarded_server`."""
    return _GUARDS[server]
