"""The viewer's guard over a real WebSocket: whose connections it takes (``Origin``, ``Host``;
issue 21 item 1). Before it, any web page open in the browser could connect to the viewer on
127.0.0.1 and change its controls.

The wire client is :mod:`tests.fuzz.viewer` (viser's msgpack format). The rules of
:class:`~sonarsim.plot.viewer.guard.HandshakeGuard` are tested without viser, the rest needs it.
"""

from __future__ import annotations

import importlib.util
import urllib.error
import urllib.request

import pytest

from sonarsim.plot.viewer.guard import LOOPBACK_NAMES, HandshakeGuard, listen_names, normal_host, split_authority

from ..conftest import block_scene_dict
from ..fuzz import viewer as wire

needs_viser = pytest.mark.skipif(importlib.util.find_spec("viser") is None, reason="the viewer extra is not installed")
# The test clients behave as pages (a camera message first, so that viser calls the viewer's
# callbacks for them) and close at once: viser warns when the viewer places the camera of a
# client already gone.
pytestmark = pytest.mark.filterwarnings("ignore:Queued a SetCamera.*on a closed connection:UserWarning")


# ---------------------------------------------------------------------------- the rules, without viser


def test_host_names_are_compared_in_one_form():
    assert normal_host("LocalHost.") == "localhost"
    assert normal_host("[::1]") == "::1" and normal_host("0:0:0:0:0:0:0:1") == "::1"
    assert normal_host("::ffff:127.0.0.1") == "127.0.0.1"
    assert split_authority("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert split_authority("[::1]:8080") == ("::1", 8080) and split_authority("localhost") == ("localhost", None)
    for bad in ("", "a b:80", "user@127.0.0.1:80", "127.0.0.1:80/x", "127.0.0.1:99999", "127.0.0.1:", "[::1",
                "127.0.0.1:８０", "[nothost]:80"):
        assert split_authority(bad) is None, bad


def test_the_names_a_server_answers_to():
    assert listen_names("127.0.0.1") == LOOPBACK_NAMES  # 127.0.0.1, localhost, ::1: one server
    assert listen_names("::1") == LOOPBACK_NAMES and listen_names("localhost") == LOOPBACK_NAMES
    assert listen_names("192.0.2.7") == {"192.0.2.7"}
    every = listen_names("0.0.0.0")
    assert LOOPBACK_NAMES <= every and listen_names("") == every == listen_names("::")
    import socket

    assert normal_host(socket.gethostname()) in every


PORT = 8080
LOCAL = ("127.0.0.1", PORT)


@pytest.mark.parametrize("host, origin", [
    ("127.0.0.1:8080", None),  # a program: no Origin
    ("127.0.0.1:8080", "http://127.0.0.1:8080"),
    ("localhost:8080", "http://localhost:8080"),
    ("[::1]:8080", "http://[::1]:8080"),
    ("LOCALHOST:8080", "http://localhost:8080"),
    ("127.0.0.1:8080", "http://localhost:8080"),  # the loopback names are one server
])
def test_the_pages_own_origin_passes(host, origin):
    assert HandshakeGuard("127.0.0.1").check([host], [origin] if origin else [], LOCAL) is None


@pytest.mark.parametrize("host, origin, reason", [
    ("evil.example.com:8080", "http://evil.example.com:8080", "Host 'evil.example.com:8080' does not name this"),
    ("127.0.0.1:8080", "http://evil.example.com", "Origin 'http://evil.example.com' is not this viewer's page"),
    ("127.0.0.1:8080", "http://evil.example.com:8080", "Origin"),
    ("127.0.0.1:8080", "http://127.0.0.1:9090", "Origin"),  # another server of this machine
    ("127.0.0.1:8080", "https://127.0.0.1:8080", "Origin"),
    ("127.0.0.1:8080", "null", "Origin 'null'"),  # a sandboxed page, a file
    ("127.0.0.1:8080", "http://127.0.0.1:8080/", "Origin"),
    ("127.0.0.1:8080", "http://user@127.0.0.1:8080", "Origin"),
    ("127.0.0.1:9090", None, "Host"),  # a tunnel to another port
    ("127.0.0.1", None, "Host"),  # port 80 implied
    ("192.0.2.7:8080", None, "Host"),
    ("127.0.0.1:8080:8080", None, "Host"),
])
def test_foreign_pages_and_names_are_refused(host, origin, reason):
    found = HandshakeGuard("127.0.0.1").check([host], [origin] if origin else [], LOCAL)
    assert found is not None and found.startswith(reason), found
    assert "(http://127.0.0.1:8080)" in found  # says where the page is


def test_headers_missing_or_doubled_are_refused():
    guard = HandshakeGuard("127.0.0.1")
    assert guard.check([], [], LOCAL) == "no Host header"
    assert guard.check(["127.0.0.1:8080"] * 2, [], LOCAL) == "more than one Host header"
    assert guard.check(["127.0.0.1:8080"], ["http://127.0.0.1:8080"] * 2, LOCAL) == "more than one Origin header"


def test_a_server_on_every_address_answers_to_the_address_reached_and_this_machines_names():
    import socket

    guard = HandshakeGuard("0.0.0.0")
    lan = ("192.0.2.7", PORT)  # the address a connection arrived at
    assert guard.check(["192.0.2.7:8080"], ["http://192.0.2.7:8080"], lan) is None
    assert guard.check(["127.0.0.1:8080"], [], LOCAL) is None
    name = normal_host(socket.gethostname())
    assert guard.check([f"{name}:8080"], [f"http://{name}:8080"], lan) is None
    assert guard.check(["192.0.2.8:8080"], [], lan) is not None  # not the address it came to
    assert guard.check(["evil.example.com:8080"], [], lan) is not None  # DNS rebinding
    assert guard.check(["192.0.2.7:8080"], ["http://evil.example.com:8080"], lan) is not None
    assert guard.check(["[::ffff:192.0.2.7]:8080"], [], ("::ffff:192.0.2.7", PORT, 0, 0)) is None
    # A server on one address of the network answers to that address only.
    assert HandshakeGuard("192.0.2.7").check(["localhost:8080"], [], lan) is not None


def test_port_80_may_be_left_out():
    guard = HandshakeGuard("127.0.0.1")
    assert guard.check(["localhost"], ["http://localhost"], ("127.0.0.1", 80)) is None


# ---------------------------------------------------------------------------- over a real WebSocket


@pytest.fixture(scope="module")
def page():
    """A viewer of the block scene on a free port, with its messages as a first client gets them."""
    pytest.importorskip("viser", reason="the viewer extra is not installed")
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server
    from sonarsim.plot.viewer.state import SceneSession

    logged = []
    server = start_server("127.0.0.1", 0, log=logged.append)
    viewer = SceneViewer(server, SceneSession(block_scene_dict()), out="unused")
    assert viewer.wait(30)
    viewer.logged = logged
    try:
        yield viewer
    finally:
        viewer.close()
        stop_server(server)


def initial_page(viewer) -> wire.Page:
    with wire.connect(viewer.server.get_port()) as ws:
        return wire.Page(wire.read_replay(ws))


def status_of(excinfo) -> int:
    return excinfo.value.response.status_code


@needs_viser
@pytest.mark.parametrize("origin", ["http://evil.example.com", "http://evil.example.com:{port}", "null",
                                    "http://127.0.0.1:{other}"])
def test_a_foreign_origin_is_refused_with_403(page, origin):
    from websockets.exceptions import InvalidStatus

    port = page.server.get_port()
    with pytest.raises(InvalidStatus) as info:
        wire.connect(port, origin=origin.format(port=port, other=port % 60000 + 1))
    assert status_of(info) == 403
    assert b"is not this viewer's page" in info.value.response.body
    assert any("refused a connection: Origin" in line for line in page.logged)  # said once to the user


@needs_viser
@pytest.mark.parametrize("host", ["evil.example.com:{port}", "127.0.0.1:{other}", "10.1.2.3:{port}"])
def test_a_host_that_does_not_name_the_server_is_refused_with_403(page, host):
    from websockets.exceptions import InvalidStatus

    port = page.server.get_port()
    with pytest.raises(InvalidStatus) as info:
        wire.connect(port, host=host.format(port=port, other=port % 60000 + 1), origin=None)
    assert status_of(info) == 403 and b"does not name this viewer" in info.value.response.body


@needs_viser
@pytest.mark.parametrize("name", ["127.0.0.1", "localhost", "[::1]"])
def test_the_pages_own_origin_is_accepted(page, name):
    port = page.server.get_port()
    with wire.connect(port, origin=f"http://{name}:{port}", host=f"{name}:{port}") as ws:
        state = wire.Page(wire.read_replay(ws))
    assert state.control("max order").value == 3


@needs_viser
def test_the_page_itself_is_served_only_by_its_names(page):
    port = page.server.get_port()
    assert b"<html" in urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10).read().lower()
    request = urllib.request.Request(f"http://127.0.0.1:{port}/", headers={"Host": f"evil.example.com:{port}"})
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(request, timeout=10)
    assert info.value.code == 403


# ---------------------------------------------------------------------------- what the guard relies on in viser


@needs_viser
def test_what_the_guard_relies_on_in_viser_is_there():
    """A viser upgrade that changes this makes the guard fail here (and the viewer refuse to
    start), never serve unguarded."""
    import inspect

    from viser.infra import _infra

    from sonarsim.plot.viewer.guard import VISER_HANDLER

    source = inspect.getsource(_infra.WebsockServer._background_worker)
    assert "websockets.asyncio.server.serve(" in source and "process_request=" in source
    assert "async def ws_handler(" in source
    assert VISER_HANDLER.startswith(_infra.WebsockServer._background_worker.__qualname__)


@needs_viser
def test_a_viser_that_starts_its_server_otherwise_is_refused(monkeypatch):
    from sonarsim.errors import SonarsimError
    from sonarsim.plot.viewer import guard

    monkeypatch.setattr(guard, "VISER_HANDLER", "SomethingElse.ws_handler")
    with pytest.raises(SonarsimError, match="cannot check .* does not serve the page"):
        guard.start_guarded_server("127.0.0.1", 0)


@needs_viser
def test_a_started_viewer_has_its_checks_in_place(page):
    import websockets.asyncio.server as ws_server

    from sonarsim.plot.viewer.guard import guard_of

    assert guard_of(page.server).names == LOOPBACK_NAMES
    assert isinstance(ws_server.serve, type)  # websockets' own class, put back after the start
