"""The viewer over its WebSocket, as its page talks to it, and a seeded fuzz of what a client sends.

Shared by ``tests/plot/test_viewer_guard.py`` (the guard's tests), ``tests/fuzz/test_viewer_fuzz.py``
(a short fuzz) and ``benchmarks/fuzz_viewer.py`` (a long one).

viser's wire format (1.x; its client ``viser/client/src/WebsocketClientWorker.ts`` and its server
``viser/infra/_infra.py``):

* client to server: one binary frame per message, the msgpack of ``{"type": CLASS NAME, FIELD: VALUE, ...}``;
* server to client: binary frames ``[u64 length of a msgpack][u64 length of its zstd
  compression][the compressed msgpack of {"messages": [...], ...}][binary buffers]``
  (little-endian); a connection's first frames replay the page's state and end with a
  ``ReplayDoneMessage``. The WebSocket subprotocol names viser's version (``viser-v1.1.1``).

The fuzz (:class:`Fuzz`) sends seeded random messages from one client -- controls set to valid
and random values (extreme numbers, wrong types, other properties than ``value``), gizmo poses,
camera messages, the message types the viewer does not take, fields deleted, added or of the
wrong type, malformed msgpack and text frames -- and checks each verdict of the server's
:class:`~sonarsim.plot.viewer.guard.MessageGate` against an oracle written here, evaluated
at the same moment (the handles' bounds change as the state does): every message it accepts
must be sound, every sound one accepted. After each batch: the sending client is still
connected, a second one that only listens is too and holds a valid page, a new connection gets
the whole state (no 1011), its values are valid and those of the server, the session agrees
with the controls, the images are rendered, and nothing raised on the server.

Imports of viser's dependencies (websockets, msgspec, zstandard) are made where used, so that
this module imports without the viewer extra.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import random
import socket
import threading
import time
from collections import Counter
from typing import Any

SUBPROTOCOL_PREFIX = "viser-v"


def subprotocol() -> str:
    """The WebSocket subprotocol viser's page asks for (``viser-v<version>``)."""
    import viser

    return f"{SUBPROTOCOL_PREFIX}{viser.__version__}"


def connect(port: int, origin: str | None = None, host: str | None = None, timeout: float = 10.0,
            camera: bool = True):
    """A WebSocket client of the viewer on ``127.0.0.1:port``, as its page is one.

    Parameters
    ----------
    origin : str, optional
        The ``Origin`` header (a browser's page sends its own; default none, as a program).
    host : str, optional
        The ``Host`` header (default ``127.0.0.1:PORT``): the connection still goes to
        ``127.0.0.1:port``, as after a DNS rebinding.
    camera : bool
        Send a camera message first, as the page does: viser counts a client as connected,
        and calls the page's callbacks for its changes, from its first camera message on.

    Returns
    -------
    websockets.sync.client.ClientConnection

    Raises
    ------
    websockets.exceptions.InvalidStatus
        The server refused the handshake (``.response.status_code``: 403).
    """
    from websockets.sync.client import connect as ws_connect

    sock = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    try:
        ws = ws_connect(f"ws://{host or f'127.0.0.1:{port}'}/", sock=sock, origin=origin,
                        subprotocols=[subprotocol()], compression=None, max_size=2**27, open_timeout=timeout,
                        close_timeout=2, proxy=None)
    except BaseException:
        sock.close()
        raise
    if camera:
        ws.send(encode(camera_message(random.Random(0))))
    return ws


def encode(message: Any) -> bytes:
    """The frame a client sends for ``message`` (msgpack, as viser's page encodes it)."""
    import msgspec

    return msgspec.msgpack.encode(message)


def gui_update(uuid: str, value: Any) -> bytes:
    """A control set to ``value``, as the page sends it."""
    return encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": value}})


def gizmo_update(name: str, position, wxyz) -> bytes:
    """A gizmo dragged to ``position`` and ``wxyz``, as the page sends it."""
    return encode({"type": "TransformControlsUpdateMessage", "name": name, "wxyz": list(wxyz),
                   "position": list(position), "owner": ""})


def unit_quaternion(rng: random.Random) -> list[float]:
    """A random rotation (w, x, y, z), normalised."""
    q = [rng.gauss(0.0, 1.0) for _ in range(4)]
    norm = math.sqrt(sum(x * x for x in q)) or 1.0
    return [x / norm for x in q]


def camera_message(rng: random.Random) -> dict:
    """A camera message as the page sends it when the view moves."""
    return {"type": "ViewerCameraMessage", "wxyz": unit_quaternion(rng),
            "position": [rng.uniform(-5, 5) for _ in range(3)], "fov": 1.0, "near": 0.01, "far": 1000.0,
            "image_height": 800, "image_width": 900, "look_at": [0.0, 0.0, 0.0], "up_direction": [0.0, 0.0, 1.0]}


def decode_frame(raw: bytes) -> list[dict]:
    """The messages of one frame the server sent."""
    import msgspec
    import zstandard

    if not isinstance(raw, bytes) or len(raw) < 16:
        raise ValueError(f"not a frame of viser's: {type(raw).__name__} of {len(raw)}")
    size = int.from_bytes(raw[:8], "little")
    packed = int.from_bytes(raw[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[16:16 + packed], max_output_size=size)
    return list(msgspec.msgpack.decode(inner)["messages"])


def read_replay(ws, timeout: float = 10.0) -> list[dict]:
    """The messages of a new connection up to its ``ReplayDoneMessage`` (the page's state).

    Raises
    ------
    TimeoutError
        It did not come in ``timeout`` seconds.
    websockets.exceptions.ConnectionClosed
        The server closed the connection (1011 when it cannot send its state).
    """
    messages: list[dict] = []
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"no ReplayDoneMessage in {timeout} s ({len(messages)} messages)")
        messages += decode_frame(ws.recv(timeout=left))
        if any(m.get("type") == "ReplayDoneMessage" for m in messages):
            return messages


def wait_for(ws, predicate, timeout: float = 5.0) -> dict | None:
    """The first message the server sends that ``predicate`` accepts; ``None`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        try:
            frame = ws.recv(timeout=left)
        except TimeoutError:
            return None
        for message in decode_frame(frame):
            if predicate(message):
                return message


# ---------------------------------------------------------------------------- the page as a client holds it


CONTROL_KINDS = {"GuiSliderMessage": "slider", "GuiCheckboxMessage": "checkbox", "GuiDropdownMessage": "dropdown",
                 "GuiButtonMessage": "button"}


@dataclasses.dataclass
class Control:
    """A control of the page: its uuid, kind, label, value and properties (min, max, options, ...)."""

    uuid: str
    kind: str
    label: str
    value: Any
    props: dict


class Page:
    """The controls and gizmos of the page as the messages a client received describe them."""

    def __init__(self, messages: list[dict] = ()) -> None:
        self.controls: dict[str, Control] = {}
        self.gizmos: dict[str, dict] = {}
        self.messages = 0
        self.update(messages)

    def update(self, messages: list[dict]) -> None:
        """Apply more messages (in the order received)."""
        for m in messages:
            self.messages += 1
            kind = m.get("type")
            if kind in CONTROL_KINDS:
                props = dict(m.get("props") or {})
                self.controls[m["uuid"]] = Control(m["uuid"], CONTROL_KINDS[kind], props.get("label", ""),
                                                   m.get("value"), props)
            elif kind == "GuiUpdateMessage" and m.get("uuid") in self.controls:
                control = self.controls[m["uuid"]]
                for key, value in m["updates"].items():
                    if key == "value":
                        control.value = value
                    else:
                        control.props[key] = value
            elif kind == "TransformControlsMessage":
                self.gizmos.setdefault(m["name"], {"position": [0.0, 0.0, 0.0], "wxyz": [1.0, 0.0, 0.0, 0.0]})
            elif kind in ("SetPositionMessage", "SetOrientationMessage") and m.get("name") in self.gizmos:
                key = "position" if kind == "SetPositionMessage" else "wxyz"
                self.gizmos[m["name"]][key] = list(m[key])

    def control(self, label: str) -> Control:
        """The control labelled ``label``."""
        return next(c for c in self.controls.values() if c.label == label)

    def problems(self, gizmo_limit_m: float) -> list[str]:
        """What is not a valid state: a slider value not finite or outside its range, a checkbox
        not a bool, a dropdown value not among its options, a gizmo pose not finite, beyond the
        limit or not a unit quaternion."""
        out = []
        for c in self.controls.values():
            v = c.value
            if c.kind == "slider":
                lo, hi = c.props.get("min"), c.props.get("max")
                if not (_real(v) and _real(lo) and _real(hi) and lo <= v <= hi):
                    out.append(f"slider {c.label!r}: {v!r} not within {lo!r}..{hi!r}")
            elif c.kind in ("checkbox", "button") and not isinstance(v, bool):
                out.append(f"{c.kind} {c.label!r}: {v!r}")
            elif c.kind == "dropdown" and v not in (c.props.get("options") or ()):
                out.append(f"dropdown {c.label!r}: {v!r} not in {c.props.get('options')}")
        for name, pose in self.gizmos.items():
            p, q = pose["position"], pose["wxyz"]
            if not (len(p) == 3 and all(_real(x) and abs(x) <= gizmo_limit_m for x in p)):
                out.append(f"gizmo {name}: position {p}")
            if not (len(q) == 4 and all(_real(x) for x in q) and abs(math.hypot(*q) - 1) < 1e-3):
                out.append(f"gizmo {name}: quaternion {q}")
        return out


def _real(v: Any) -> bool:
    return (isinstance(v, int) and not isinstance(v, bool)) or (isinstance(v, float) and math.isfinite(v))


# ---------------------------------------------------------------------------- the oracle


def sound(data: Any, server, gizmo_limit_m: float) -> bool:
    """Whether a client's message is one the gate must pass, judged from the server's handles now.

    Written apart from the gate (and more plainly): a binary message of at most 64 KiB, of a
    taken type with exactly its fields, each of its kind; a control update of ``value`` alone, for an enabled control of
    the page, within its bounds; a gizmo pose finite, within the limit, of unit quaternion; a
    camera with finite numbers and image sizes from 0 to 65536.
    """
    import msgspec
    import viser

    if not isinstance(data, bytes) or len(data) > 65536:
        return False
    try:
        m = msgspec.msgpack.decode(data)
    except Exception:  # noqa: BLE001 - anything msgspec refuses is malformed
        return False
    if not isinstance(m, dict):
        return False
    kind = m.get("type")

    def vec(value, n):
        return isinstance(value, list) and len(value) == n and all(_real(x) for x in value)

    def fields(required, optional=()):
        return set(required) <= set(m) - {"type"} <= set(required) | set(optional)

    if kind == "GuiUpdateMessage":
        if not (fields(("uuid", "updates")) and isinstance(m["uuid"], str) and isinstance(m["updates"], dict)):
            return False
        handle = server.gui._gui_input_handle_from_uuid.get(m["uuid"])
        if handle is None or list(m["updates"]) != ["value"] or handle.disabled:
            return False
        v = m["updates"]["value"]
        if isinstance(handle, viser.GuiSliderHandle):
            integer = type(handle.value) is int
            return _real(v) and handle.min <= v <= handle.max and (not integer or float(v).is_integer())
        if isinstance(handle, viser.GuiCheckboxHandle):
            return isinstance(v, bool)
        if isinstance(handle, viser.GuiDropdownHandle):
            return isinstance(v, str) and v in handle.options
        if isinstance(handle, viser.GuiButtonHandle):
            return v is True
        return False
    if kind in ("TransformControlsUpdateMessage", "TransformControlsDragStartMessage",
                "TransformControlsDragEndMessage"):
        pose = kind == "TransformControlsUpdateMessage"
        if not fields(("name", "wxyz", "position") if pose else ("name",), ("owner",)):
            return False
        if not isinstance(m["name"], str) or not isinstance(m.get("owner", ""), str):
            return False
        if m["name"] not in server.scene._handle_from_transform_controls_name:
            return False
        if not pose:
            return True
        p, q = m["position"], m["wxyz"]
        return (vec(p, 3) and vec(q, 4) and max(abs(x) for x in p) <= gizmo_limit_m
                and abs(math.sqrt(sum(x * x for x in q)) - 1.0) <= 1e-3)
    if kind == "ViewerCameraMessage":
        names = ("wxyz", "position", "fov", "near", "far", "image_height", "image_width", "look_at", "up_direction")
        if not fields(names):
            return False
        sizes = [m["image_height"], m["image_width"]]
        return (vec(m["wxyz"], 4) and vec(m["position"], 3) and vec(m["look_at"], 3) and vec(m["up_direction"], 3)
                and all(_real(m[k]) for k in ("fov", "near", "far"))
                and all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= 65536 for s in sizes))
    return False


# ---------------------------------------------------------------------------- random messages

NUMBERS = (0, -0.0, 1, -1, 2, 3, 6, 7, 0.5, 2.5, 10.0, 40.0, 90.0, 95.0, -30.0, 30.5, 179.5, 1e-9, 5e-324, 1e-308,
           1e6, 1e300, 1e308, -1e308, float("inf"), float("-inf"), float("nan"), 2**31, 2**53 + 1, 2**63 - 1,
           2**63, 2**64 - 1, -(2**63), 1e4, 1e4 + 1e-6, -1e4)
STRINGS = ("", "value", "total", "ground", "triple", "order9", "inferno", "grey", "no_such_map", "linear", "db",
           "true", "3", "1e308", "NaN", "\x00", "é" * 3, "\U0001F600", "a" * 5000, "/sonar", "/objects/buoy",
           "__proto__", "constructor")
OTHER_TYPES = ("ShareUrlRequest", "ShareUrlDisconnect", "FileTransferStartUpload", "FileTransferPart",
               "GuiButtonHoldMessage", "GuiFormSubmitMessage", "GuiFormDirtyMessage", "CommandTriggerMessage",
               "SceneNodeClickMessage", "SceneNodeDragMessage", "ScenePointerMessage", "GetRenderResponseMessage",
               "LocalStorageGetItemResponseMessage", "SceneNodeUpdateMessage", "GuiRemoveMessage", "ResetGuiMessage",
               "RunJavascriptMessage", "SetPositionMessage", "GuiSliderMessage", "NoSuchMessage", "", "Message")
# What a number of a valid message is replaced by, one at a time: what the gate must catch.
EXTREMES = (float("nan"), float("inf"), float("-inf"), 1e308, -1e308, 1e300, 2**63, 2**64 - 1, -(2**63), 5e-324,
            1e4 + 1, "1", None, True, [], {})
PROPS = ("value", "min", "max", "step", "options", "label", "disabled", "visible", "hint", "order", "_marks",
         "precision", "uuid", "type", "", "__proto__")


def random_value(rng: random.Random, depth: int = 0) -> Any:
    """A value of any kind msgpack carries: numbers (extreme ones often), bools, None, strings
    (huge ones), bytes, lists and maps (nested)."""
    pick = rng.random()
    if pick < 0.35:
        return rng.choice(NUMBERS)
    if pick < 0.45:
        return rng.uniform(-1e3, 1e3) if rng.random() < 0.7 else rng.choice((-1, 1)) * 10 ** rng.uniform(-320, 308)
    if pick < 0.52:
        return rng.randint(-(2**63), 2**64 - 1)
    if pick < 0.6:
        return rng.choice((True, False, None))
    if pick < 0.72:
        return rng.choice(STRINGS)
    if pick < 0.76:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(12)))
    if depth > 3:
        return None
    if pick < 0.9:
        return [random_value(rng, depth + 1) for _ in range(rng.randrange(6))]
    return {rng.choice(STRINGS + PROPS): random_value(rng, depth + 1) for _ in range(rng.randrange(4))}


def valid_value(rng: random.Random, handle) -> Any:
    """A value ``handle`` (a viser control) takes: in range, one of its options, a bool."""
    import viser

    if isinstance(handle, viser.GuiSliderHandle):
        lo, hi = float(handle.min), float(handle.max)
        if type(handle.value) is int:
            return rng.randint(int(math.ceil(lo)), int(math.floor(hi)))
        return rng.choice((lo, hi, round(rng.uniform(lo, hi), 2), rng.uniform(lo, hi)))
    if isinstance(handle, viser.GuiCheckboxHandle):
        return rng.random() < 0.5
    if isinstance(handle, viser.GuiDropdownHandle):
        return rng.choice(tuple(handle.options))
    return True  # a button


def mutate_fields(rng: random.Random, message: dict) -> dict:
    """A taken message with a field deleted, added, renamed or given a random value."""
    m = dict(message)
    keys = [k for k in m if k != "type"]
    how = rng.randrange(4)
    if how == 0 and keys:
        del m[rng.choice(keys)]
    elif how == 1:
        m[rng.choice(PROPS + STRINGS)] = random_value(rng)
    elif how == 2 and keys:
        key = rng.choice(keys)
        m[key + rng.choice(("_", "s", " "))] = m.pop(key)
    elif keys:
        m[rng.choice(keys)] = random_value(rng)
    return m


def malformed(rng: random.Random, valid: bytes) -> bytes | str:
    """Bytes that are no message: random bytes, a valid message cut, bit-flipped or grown,
    msgpack of a non-map, very deep nesting, a text frame."""
    how = rng.randrange(8)
    if how == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    if how == 1:
        return valid[: rng.randrange(len(valid))]
    if how == 2:
        flipped = bytearray(valid)
        for _ in range(rng.randint(1, 4)):
            flipped[rng.randrange(len(flipped))] ^= 1 << rng.randrange(8)
        return bytes(flipped)
    if how == 3:
        return valid + bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
    if how == 4:
        return encode(rng.choice(([1, 2], 3, "GuiUpdateMessage", None, [{"type": "GuiUpdateMessage"}])))
    if how == 5:
        return b"\x91" * rng.choice((100, 5000, 200_000)) + b"\xc0"  # arrays nested that deep
    if how == 6:
        return encode({"uuid": "x", "updates": {"value": 1}})  # no type
    return "text frame " + rng.choice(STRINGS)[:50]


def make_case(rng: random.Random, server, gizmo_limit_m: float) -> tuple[str, bytes | str]:
    """One random message for the page of ``server``: ``(what, frame)``."""
    controls = list(server.gui._gui_input_handle_from_uuid.items())
    gizmos = list(server.scene._handle_from_transform_controls_name)
    pick = rng.random()
    uuid, handle = rng.choice(controls)
    if pick < 0.2:
        # Valid values for each control, the save button rarely (a save takes a full render).
        import viser

        while isinstance(handle, viser.GuiButtonHandle) and rng.random() < 0.95:
            uuid, handle = rng.choice(controls)
        return "control, valid value", gui_update(uuid, valid_value(rng, handle))
    if pick < 0.38:
        value = rng.choice(EXTREMES) if rng.random() < 0.4 else random_value(rng)
        return "control, random value", gui_update(uuid, value)
    if pick < 0.44:
        updates = {rng.choice(PROPS[1:]): random_value(rng) for _ in range(rng.randint(1, 3))}  # not "value" alone
        if rng.random() < 0.5:
            updates["value"] = valid_value(rng, handle)
        return "control, other properties", encode({"type": "GuiUpdateMessage", "uuid": uuid, "updates": updates})
    if pick < 0.48:
        wrong = rng.choice(STRINGS + (uuid[:-1] + "0", uuid.upper()))
        wrong = wrong if wrong != uuid else uuid + "0"  # a uuid that ends in 0 (all digits: its upper case)
        return "unknown control", gui_update(wrong, valid_value(rng, handle))
    name = rng.choice(gizmos)
    if pick < 0.55:
        position = [rng.uniform(-3.0, 3.0), rng.uniform(-3.0, 3.0), rng.uniform(-1.0, 3.0)]
        return "gizmo, valid pose", gizmo_update(name, position, unit_quaternion(rng))
    if pick < 0.58:
        # Valid, yet far: up to the limit (the sliders that follow widen, the scene is far away).
        position = [rng.choice((-1, 1)) * gizmo_limit_m * rng.random() ** 4 for _ in range(3)]
        return "gizmo, far valid pose", gizmo_update(name, position, unit_quaternion(rng))
    if pick < 0.7:
        # A valid pose with one number extreme, of the wrong type, or the wrong length; or random.
        position, wxyz = [rng.uniform(-3.0, 3.0) for _ in range(3)], unit_quaternion(rng)
        how = rng.randrange(5)
        if how == 0:
            position[rng.randrange(3)] = rng.choice(EXTREMES)
        elif how == 1:
            wxyz[rng.randrange(4)] = rng.choice(EXTREMES)
        elif how == 2:
            wxyz = [x * rng.choice((0.0, 0.5, 0.998, 1.002, 2.0, -1.0)) for x in wxyz]  # -1: a unit one still
        elif how == 3:
            position, wxyz = rng.choice(((position[:2], wxyz), (position + [0.0], wxyz), (position, wxyz[:3]),
                                         (position, wxyz + [0.0])))
        else:
            position = [random_value(rng) for _ in range(rng.choice((3, 3, 2, 4)))]
            wxyz = [random_value(rng) for _ in range(rng.choice((4, 4, 3)))]
        return "gizmo, random pose", gizmo_update(name, position, wxyz)
    if pick < 0.73:
        kind = rng.choice(("TransformControlsDragStartMessage", "TransformControlsDragEndMessage"))
        message = {"type": kind, "name": rng.choice((name, name, "/nothing")), "owner": ""}
        return "gizmo drag start or end", encode(message)
    if pick < 0.77:
        camera = camera_message(rng)
        if rng.random() < 0.6:
            key = rng.choice(list(camera)[1:])
            if isinstance(camera[key], list) and rng.random() < 0.7:
                camera[key][rng.randrange(len(camera[key]))] = rng.choice(EXTREMES)
            else:
                camera[key] = rng.choice(EXTREMES) if rng.random() < 0.7 else random_value(rng)
        return "camera", encode(camera)
    if pick < 0.84:
        message = {"type": rng.choice(OTHER_TYPES)}
        for _ in range(rng.randrange(4)):
            key = rng.choice(("uuid", "name", "value", "frequency", "transfer_uuid", "part", "content"))
            message[key] = random_value(rng)
        return "message type not taken", encode(message)
    base = rng.choice((
        {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": valid_value(rng, handle)}},
        {"type": "TransformControlsUpdateMessage", "name": name, "wxyz": [1.0, 0.0, 0.0, 0.0],
         "position": [0.0, 0.0, 1.0], "owner": ""},
        camera_message(rng)))
    if pick < 0.93:
        return "fields mutated", encode(mutate_fields(rng, base))
    return "malformed", malformed(rng, encode(base))


# ---------------------------------------------------------------------------- the run


class Listener:
    """A client that holds the page as the server describes it, reading in a thread."""

    def __init__(self, port: int, camera: bool = True) -> None:
        self.ws = connect(port, camera=camera)
        self.page = Page(read_replay(self.ws))
        self.closed: str | None = None
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, daemon=True, name="viewer-fuzz-listener")
        self._thread.start()

    def _read(self) -> None:
        from websockets.exceptions import ConnectionClosed

        while True:
            try:
                frame = self.ws.recv()
            except ConnectionClosed as exc:
                self.closed = f"closed: {exc}"
                return
            except Exception as exc:  # noqa: BLE001 - said by the check
                self.closed = f"{type(exc).__name__}: {exc}"
                return
            try:
                messages = decode_frame(frame)
            except Exception as exc:  # noqa: BLE001
                self.closed = f"undecodable frame: {exc}"
                return
            with self._lock:
                self.page.update(messages)

    def problems(self, gizmo_limit_m: float, page: bool = True) -> list[str]:
        """The page's problems (with ``page``), and a closed connection."""
        with self._lock:
            out = self.page.problems(gizmo_limit_m) if page else []
        if self.closed is not None:
            out.append(f"connection {self.closed}")
        return out

    def close(self) -> None:
        self.ws.close()
        self._thread.join(timeout=5)


@dataclasses.dataclass
class Fuzz:
    """A fuzz of a running viewer's WebSocket: seeded messages in batches, checked after each.

    Parameters
    ----------
    viewer : SceneViewer
        Served by :func:`sonarsim.plot.viewer.app.start_server` (its gate is looked at).
    seed : int
    """

    viewer: Any
    seed: int = 0
    verdict_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        from sonarsim.plot.viewer.guard import GIZMO_LIMIT_M, gate_of

        self.server = self.viewer.server
        self.port = self.server.get_port()
        self.limit = GIZMO_LIMIT_M
        self.gate = gate_of(self.server)
        self.rng = random.Random(self.seed)
        self.sent: Counter = Counter()  # by what was generated
        self.verdicts: Counter = Counter()  # (what, "accepted"/"refused")
        self.failures: list[dict] = []
        self.errors: list[str] = []  # raised on the server
        self.cases = 0
        self.batches = 0
        self.slowest_check_s = 0.0
        self._what: list[str] = []  # what each message the sender sent was generated as
        self._record: list[tuple[bool, bool]] = []  # (the gate's verdict, the oracle's) of each
        self._checked = 0  # messages whose verdicts were checked
        self._cond = threading.Condition()
        self._hook()
        # The sender's camera message (it counts as connected from it on) is its first verdict;
        # the listener sends nothing.
        self._what.append("camera on connecting")
        self.sent["camera on connecting"] += 1
        self.sender = Listener(self.port)
        self.listener = Listener(self.port, camera=False)

    def _hook(self) -> None:
        # Every verdict of the gate, beside the oracle's at the same moment (on viser's loop).
        gate, server, limit = self.gate, self.server, self.limit
        admit = gate.admit

        def recorded_admit(data):
            expected = sound(data, server, limit)
            verdict = admit(data)
            with self._cond:
                self._record.append((verdict, expected))
                self._cond.notify_all()
            return verdict

        gate.admit = recorded_admit
        loop = server._websock_server._background_event_loop
        loop.set_exception_handler(lambda _loop, context: self.errors.append(
            f"event loop: {context.get('message')}: {context.get('exception')!r}"))
        worker = self.viewer.worker
        on_error = worker._on_error

        def render_failed(exc):
            from sonarsim.errors import SonarsimError

            if not isinstance(exc, SonarsimError):
                self.errors.append(f"render: {type(exc).__name__}: {exc}")
            on_error(exc)

        worker._on_error = render_failed
        save = self.viewer.save

        def checked_save():
            try:
                return save()
            except Exception as exc:  # noqa: BLE001 - recorded, then as viser would
                self.errors.append(f"save: {type(exc).__name__}: {exc}")
                raise

        self.viewer.save = checked_save

    def batch(self, n: int) -> list[dict]:
        """Send ``n`` messages, then check; returns this batch's failures."""
        for _ in range(n):
            what, frame = make_case(self.rng, self.server, self.limit)
            self._what.append(what)
            self.sent[what] += 1
            self.sender.ws.send(frame)
        self.cases += n
        self.batches += 1
        t0 = time.perf_counter()
        failures = self._check()
        self.slowest_check_s = max(self.slowest_check_s, time.perf_counter() - t0)
        self.failures += failures
        return failures

    def _fail(self, what: str, detail: str, case: int | None = None) -> dict:
        return {"batch": self.batches, "case": case, "what": what, "detail": detail[:500]}

    def _check(self) -> list[dict]:
        out = []
        start = self._checked
        with self._cond:
            done = self._cond.wait_for(lambda: len(self._record) >= len(self._what), self.verdict_timeout_s)
            record = list(self._record[start:len(self._what)])
        self._checked = start + len(record)
        if not done:
            out.append(self._fail("no verdict", f"{len(self._what) - len(self._record)} messages unanswered "
                                  f"after {self.verdict_timeout_s} s"))
        for k, (verdict, expected) in enumerate(record, start):
            what = self._what[k]
            self.verdicts[(what, "accepted" if verdict else "refused")] += 1
            if verdict != expected:
                out.append(self._fail(what, "accepted an unsound message" if verdict else "refused a sound message", k))
        # Let the handlers of what was accepted run (viser's loop, then the render thread).
        self._settle()
        # The sender's connection is open and what it was sent decodes; its page is not
        # checked: viser does not echo a client's own changes, which its page applies itself.
        out += [self._fail("sender", p) for p in self.sender.problems(self.limit, page=False)]
        out += [self._fail("listener's page", p) for p in self.listener.problems(self.limit)]
        out += self._fresh_connection()
        out += self._server_state()
        while self.errors:
            out.append(self._fail("raised on the server", self.errors.pop(0)))
        return out

    def _settle(self) -> None:
        loop = self.server._websock_server._background_event_loop
        for _ in range(3):
            asyncio.run_coroutine_threadsafe(asyncio.sleep(0), loop).result(timeout=10)
        if not self.viewer.wait(60):
            self.errors.append("the images were not rendered within 60 s")

    def _fresh_connection(self) -> list[dict]:
        try:
            ws = connect(self.port, camera=False)  # sends nothing: the verdicts stay the sender's
        except Exception as exc:  # noqa: BLE001
            return [self._fail("new connection", f"{type(exc).__name__}: {exc}")]
        try:
            page = Page(read_replay(ws))
        except Exception as exc:  # noqa: BLE001 - 1011, a timeout
            return [self._fail("new connection's replay", f"{type(exc).__name__}: {exc}")]
        finally:
            ws.close()
        out = [self._fail("new connection's page", p) for p in page.problems(self.limit)]
        handles = self.server.gui._gui_input_handle_from_uuid
        for uuid, control in page.controls.items():
            handle = handles.get(uuid)
            if handle is not None and control.kind != "button" and control.value != handle.value:
                out.append(self._fail("new connection's page", f"{control.label!r} shows {control.value!r}, "
                                      f"the server holds {handle.value!r}"))
        return out

    def _server_state(self) -> list[dict]:
        v, out = self.viewer, []
        o = v.session.options
        shown = {"component": v.component.value, "max_order": v.max_order.value, "sensor": v.sensor.value,
                 "speckle": v.speckle.value, "colormap": v.colormap.value,
                 "dynamic_range_db": v.dynamic_range.value, "gain_db": v.gain.value}
        for key, value in shown.items():
            if getattr(o, key) != value:
                out.append(self._fail("session", f"{key}: the page shows {value!r}, "
                                      f"the session has {getattr(o, key)!r}"))
        poses = [v.session.sonar_pose, *v.session.object_poses.values()]
        if not all(math.isfinite(x) for p in poses for x in (*p.position_m, *p.rpy_deg)):
            out.append(self._fail("session", f"a pose not finite: {poses}"))
        position = [float(x) for x in v.sonar_control.position]
        if max(abs(a - b) for a, b in zip(position, v.session.sonar_pose.position_m)) > 1e-5:
            out.append(self._fail("session", f"sonar gizmo at {position}, the session's sonar at "
                                  f"{v.session.sonar_pose.position_m}"))
        return out

    def summary(self) -> dict:
        """Counts of the run so far, as JSON-ready."""
        accepted = sum(n for (_, verdict), n in self.verdicts.items() if verdict == "accepted")
        refused = sum(n for (_, verdict), n in self.verdicts.items() if verdict == "refused")
        return {
            "seed": self.seed, "messages": self.cases, "batches": self.batches,
            "verdicts": {"accepted": accepted, "refused": refused},
            "by_kind": {what: {"sent": n, "accepted": self.verdicts[(what, "accepted")],
                               "refused": self.verdicts[(what, "refused")]} for what, n in sorted(self.sent.items())},
            "gate_accepted_by_type": dict(self.gate.accepted.most_common()),
            "gate_refused_by_reason": dict(self.gate.refused.most_common()),
            "failures": len(self.failures), "failed": self.failures[:50],
            "slowest_check_s": round(self.slowest_check_s, 3),
        }

    def close(self) -> None:
        """Close both clients (the viewer is the caller's)."""
        self.sender.close()
        self.listener.close()
