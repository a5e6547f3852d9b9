"""The viewer's guard over a real WebSocket: whose connections it takes (``Origin``, ``Host``) and
which values (issue 21 item 1). Before it, any web page open in the browser could connect to the
viewer on 127.0.0.1, and one message setting a slider to ``1e308`` made the server close every
later connection with 1011 until it was restarted.

The wire client is :mod:`tests.fuzz.viewer` (viser's msgpack format). The rules of
:class:`~sonarsim.plot.viewer.guard.HandshakeGuard` are tested without viser, the rest needs it.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import time
import urllib.error
import urllib.request

import pytest

from sonarsim.plot.viewer.guard import (GIZMO_LIMIT_M, LOOPBACK_NAMES, TAKEN_MESSAGES, HandshakeGuard, listen_names,
                                        normal_host, split_authority)

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
    assert state.control("max order").value == 3 and not state.problems(GIZMO_LIMIT_M)


@needs_viser
def test_the_page_itself_is_served_only_by_its_names(page):
    port = page.server.get_port()
    assert b"<html" in urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=10).read().lower()
    request = urllib.request.Request(f"http://127.0.0.1:{port}/", headers={"Host": f"evil.example.com:{port}"})
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(request, timeout=10)
    assert info.value.code == 403


def send_and_wait_for_resync(ws, frame: bytes, uuid: str, timeout: float = 5.0) -> dict | None:
    """Send ``frame``; the message that gives the control ``uuid`` back its value (the gate's reply)."""
    ws.send(frame)
    return wire.wait_for(ws, lambda m: m.get("type") == "GuiUpdateMessage" and m.get("uuid") == uuid
                         and set(m["updates"]) == {"value"}, timeout)


BAD_SLIDER_VALUES = [1e308, -1e308, float("inf"), float("-inf"), float("nan"), 2**63, 2**64 - 1, -(2**63), "3",
                     None, [3], {"value": 3}, True, b"3"]


@needs_viser
@pytest.mark.parametrize("label, in_range", [("max order", (0, 7, 2.5)), ("dB window", (9.99, 90.5, -40.0))])
def test_a_slider_refuses_values_it_cannot_take(page, label, in_range):
    """1e308, inf, nan, 2**63, a string, out of range, ...: refused, the state unchanged, the
    client given the current value back; a new connection still gets the whole state."""
    v = page
    handle = v.max_order if label == "max order" else v.dynamic_range
    before = (handle.value, v.session.options, v.session.version)
    state = initial_page(v)
    uuid = state.control(label).uuid
    with wire.connect(v.server.get_port()) as ws, wire.connect(v.server.get_port()) as other:
        wire.read_replay(ws)
        wire.read_replay(other)
        for value in [*BAD_SLIDER_VALUES, *in_range]:
            reply = send_and_wait_for_resync(ws, wire.gui_update(uuid, value), uuid)
            assert reply is not None, f"no reply to {value!r}"
            assert reply["updates"]["value"] == before[0], value
            assert (handle.value, v.session.options, v.session.version) == before, value
        # The other client saw only the current value (restated), and is still served.
        assert wire.wait_for(other, lambda m: m.get("uuid") == uuid and m["updates"] != {"value": before[0]},
                             timeout=0.3) is None
        assert other.ping().wait(5)
    assert v.server.gui._gui_input_handle_from_uuid[uuid].value == before[0]
    # A new connection gets the initial state, with no 1011 (the audit's failure).
    fresh = initial_page(v)
    assert fresh.control(label).value == before[0] and not fresh.problems(GIZMO_LIMIT_M)
    from sonarsim.plot.viewer.guard import gate_of

    assert gate_of(v.server).refused["bad value"] >= len(BAD_SLIDER_VALUES)


@needs_viser
def test_a_value_within_bounds_is_applied_and_reaches_the_other_clients(page):
    v = page
    uuid = initial_page(v).control("max order").uuid
    try:
        with wire.connect(v.server.get_port()) as ws, wire.connect(v.server.get_port()) as other:
            wire.read_replay(ws)
            wire.read_replay(other)
            ws.send(wire.gui_update(uuid, 2))
            seen = wire.wait_for(other, lambda m: m.get("uuid") == uuid and m["updates"].get("value") == 2)
            assert seen is not None
            deadline = time.monotonic() + 5
            while v.session.options.max_order != 2 and time.monotonic() < deadline:
                time.sleep(0.02)
            assert v.session.options.max_order == 2 and v.max_order.value == 2
            assert v.session.options.bounces == (1, 2)
        assert initial_page(v).control("max order").value == 2
    finally:
        v.set_options(max_order=3, bounces=(1, 2, 3))
        assert v.wait(10)


@needs_viser
@pytest.mark.parametrize("label, value", [
    ("speckle", 1), ("speckle", "true"), ("speckle", None), ("speckle", [True]),
    ("component", "quadruple"), ("component", 3), ("component", "TOTAL"),
    ("colour map", "no_such_map"),
    ("sensor", True),  # disabled: the block scene has no sensor
    ("save scene and images", False), ("save scene and images", "click"),
])
def test_checkboxes_dropdowns_and_buttons_take_only_their_values(page, label, value, tmp_path):
    v = page
    state = initial_page(v)
    control = state.control(label)
    before = (v.session.options, v.session.version)
    v.out = tmp_path / "out"
    with wire.connect(v.server.get_port()) as ws:
        wire.read_replay(ws)
        if control.kind == "button":
            ws.send(wire.gui_update(control.uuid, value))
            assert ws.ping().wait(5)
            time.sleep(0.2)
        else:
            reply = send_and_wait_for_resync(ws, wire.gui_update(control.uuid, value), control.uuid)
            assert reply is not None and reply["updates"]["value"] == control.value
    assert (v.session.options, v.session.version) == before
    assert not v.out.exists() and not v.save_status.content.startswith("saved")


@needs_viser
@pytest.mark.parametrize("updates", [{"min": -1e308}, {"max": 2**63}, {"disabled": False}, {"options": ["x"]},
                                     {"value": 2, "label": "x"}, {}, {"visible": True}])
def test_only_a_controls_value_may_be_changed(page, updates):
    import msgspec

    v = page
    control = initial_page(v).control("max order" if "options" not in updates else "component")
    handle = v.server.gui._gui_input_handle_from_uuid[control.uuid]
    props = (handle.value, handle.disabled, handle.visible, handle.label)
    with wire.connect(v.server.get_port()) as ws:
        wire.read_replay(ws)
        frame = msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": control.uuid, "updates": updates})
        assert send_and_wait_for_resync(ws, frame, control.uuid) is not None
    assert (handle.value, handle.disabled, handle.visible, handle.label) == props
    assert not initial_page(v).problems(GIZMO_LIMIT_M)


@needs_viser
@pytest.mark.parametrize("position, wxyz", [
    ((float("nan"), 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, float("inf"), 1.0), (1.0, 0.0, 0.0, 0.0)),
    ((1e300, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),  # slider ranges widened to 10**300: 1011 for all
    ((2 * GIZMO_LIMIT_M, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 1.0), (2.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 1.0), (float("nan"), 0.0, 0.0, 0.0)),
    ((0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
    ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0)),
    (("0", 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),
    ((True, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),
    ((2**64 - 1, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)),
])
def test_a_gizmo_refuses_poses_that_are_not_finite_or_absurd(page, position, wxyz):
    v = page
    pose = v.session.sonar_pose
    with wire.connect(v.server.get_port()) as ws:
        wire.read_replay(ws)
        ws.send(wire.gizmo_update("/sonar", position, wxyz))
        back = wire.wait_for(ws, lambda m: m.get("type") == "SetPositionMessage" and m.get("name") == "/sonar")
    assert back is not None and back["position"] == list(pose.position_m)  # the sender's gizmo put back
    assert v.session.sonar_pose == pose
    assert all(math.isfinite(float(x)) for x in v.sonar_control.position)
    state = initial_page(v)
    assert not state.problems(GIZMO_LIMIT_M) and state.gizmos["/sonar"]["position"] == list(pose.position_m)


@needs_viser
def test_a_gizmo_drag_within_bounds_moves_the_sonar(page):
    from sonarsim import Pose
    from sonarsim.plot.viewer.state import wxyz_of

    v = page
    target = Pose((0.5, -0.2, 1.2), (0.0, 15.0, 20.0))
    try:
        with wire.connect(v.server.get_port()) as ws:
            wire.read_replay(ws)
            ws.send(wire.gizmo_update("/sonar", target.position_m, wxyz_of(target)))
            deadline = time.monotonic() + 5
            while v.session.sonar_pose.position_m != target.position_m and time.monotonic() < deadline:
                time.sleep(0.02)
        assert v.session.sonar_pose == target
        assert initial_page(v).control("yaw (deg)").value == 20.0
    finally:
        v.set_sonar_pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))
        assert v.wait(10)


@needs_viser
@pytest.mark.parametrize("frame", [
    {"type": "ShareUrlRequest"},  # would open a public tunnel to the viewer
    {"type": "FileTransferStartUpload", "source_component_uuid": "x", "transfer_uuid": "y", "filename": "a",
     "mime_type": "b", "part_count": 10**9, "size_bytes": 10**12},
    {"type": "GuiButtonHoldMessage", "uuid": "x", "frequency": 1e9},
    {"type": "NoSuchMessage"}, {"no": "type"}, [1, 2, 3],
    b"\xc1", b"\x91" * 5000 + b"\xc0", b"\x91" * 100_000 + b"\xc0", "a text frame",
    {"type": "ViewerCameraMessage", "padding": [0] * 1_000_000},  # msgpack would make a million objects
    {"type": "GuiUpdateMessage", "uuid": "no-such-control", "updates": {"value": 1}},
    {"type": "GuiUpdateMessage", "uuid": "x"},
    {"type": "GuiUpdateMessage", "uuid": "x", "updates": {"value": 1}, "excluded_self_client": 3},
    {"type": "TransformControlsUpdateMessage", "name": "/nothing", "wxyz": [1, 0, 0, 0], "position": [0, 0, 0]},
    {"type": "ViewerCameraMessage", "wxyz": [1, 0, 0, 0], "position": [0, 0, float("nan")], "fov": 1.0,
     "near": 0.01, "far": 100.0, "image_height": 10, "image_width": 10, "look_at": [0, 0, 0],
     "up_direction": [0, 0, 1]},
])
def test_other_messages_are_dropped_and_the_connection_stays(page, frame):
    from sonarsim.plot.viewer.guard import gate_of

    v = page
    gate = gate_of(v.server)
    refused = sum(gate.refused.values())
    before = (v.session.options, v.session.version, v.session.sonar_pose)
    with wire.connect(v.server.get_port()) as ws:
        wire.read_replay(ws)
        ws.send(frame if isinstance(frame, (bytes, str)) else wire.encode(frame))
        deadline = time.monotonic() + 5
        while sum(gate.refused.values()) == refused and time.monotonic() < deadline:
            time.sleep(0.01)
        assert ws.ping().wait(5)  # still connected: a malformed message costs the client that message only
    assert sum(gate.refused.values()) == refused + 1
    assert (v.session.options, v.session.version, v.session.sonar_pose) == before
    assert not initial_page(v).problems(GIZMO_LIMIT_M)


def test_a_message_beyond_a_mebibyte_ends_that_connection_alone(page):
    # websockets buffers a message whole before the gate sees it: viser let it grow to 50 MB.
    import websockets

    from sonarsim.plot.viewer.guard import MAX_FRAME_BYTES

    v = page
    before = (v.session.options, v.session.version, v.session.sonar_pose)
    with wire.connect(v.server.get_port()) as other, wire.connect(v.server.get_port()) as ws:
        wire.read_replay(other)
        wire.read_replay(ws)
        with pytest.raises(websockets.exceptions.ConnectionClosedError, match="1009"):
            ws.send(b"\x91" * (MAX_FRAME_BYTES + 1) + b"\xc0")
            ws.recv(timeout=5)
        assert other.ping().wait(5)  # the other page is still served
    assert (v.session.options, v.session.version, v.session.sonar_pose) == before
    assert not initial_page(v).problems(GIZMO_LIMIT_M)


# ---------------------------------------------------------------------------- what the guard relies on in viser


@needs_viser
def test_what_the_guard_relies_on_in_viser_is_there():
    """A viser upgrade that changes any of these makes the guard fail here (and the viewer
    refuse to start), never serve unguarded."""
    import inspect

    import viser
    from viser import _messages
    from viser.infra import _infra

    from sonarsim.plot.viewer.guard import VISER_HANDLER

    source = inspect.getsource(_infra.WebsockServer._background_worker)
    assert "websockets.asyncio.server.serve(" in source and "process_request=" in source
    assert "async def ws_handler(" in source and "websocket.recv()" in inspect.getsource(_infra._message_consumer)
    assert VISER_HANDLER.startswith(_infra.WebsockServer._background_worker.__qualname__)
    # The fields of the messages the gate takes are viser's.
    for name, schema in TAKEN_MESSAGES.items():
        cls = getattr(_messages, name)
        fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
        assert set(fields) == set(schema), name
        optional = {k for k, v in schema.items() if isinstance(v, str) and v.endswith("?")}
        assert {k for k, f in fields.items() if f.default is not dataclasses.MISSING} == optional, name
    for name in ("GuiSliderHandle", "GuiCheckboxHandle", "GuiDropdownHandle", "GuiButtonHandle"):
        assert isinstance(getattr(viser, name), type)
    assert {"on_client_connect"} <= set(dir(_infra.WebsockServer))


@needs_viser
def test_a_viser_that_starts_its_server_otherwise_is_refused(monkeypatch):
    from sonarsim.errors import SonarsimError
    from sonarsim.plot.viewer import guard

    monkeypatch.setattr(guard, "VISER_HANDLER", "SomethingElse.ws_handler")
    with pytest.raises(SonarsimError, match="cannot check .* does not serve the page"):
        guard.start_guarded_server("127.0.0.1", 0)


@needs_viser
def test_a_viser_without_the_registries_the_gate_reads_is_refused(monkeypatch):
    from viser._gui_api import GuiApi

    from sonarsim.errors import SonarsimError
    from sonarsim.plot.viewer import guard

    real_init = GuiApi.__init__

    def init_without_registry(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        del self._gui_input_handle_from_uuid  # as a viser that renamed it

    monkeypatch.setattr(GuiApi, "__init__", init_without_registry)
    with pytest.raises(SonarsimError, match="does not serve the page"):
        guard.start_guarded_server("127.0.0.1", 0)


@needs_viser
def test_a_started_viewer_has_its_checks_in_place(page):
    from sonarsim.plot.viewer.guard import gate_of, guard_of

    server = page.server
    assert guard_of(server).names == LOOPBACK_NAMES
    # 6 pose sliders; component, max order, 6 bounce boxes, sensor, speckle, colour map, dB window, gain; save
    assert len(server.gui._gui_input_handle_from_uuid) == 20
    assert set(server.scene._handle_from_transform_controls_name) == {"/objects/block", "/sonar"}
    assert gate_of(server).server is server
    import websockets.asyncio.server as ws_server

    assert isinstance(ws_server.serve, type)  # websockets' own class, put back after the start
