"""The viewer over its WebSocket, as its page talks to it.

Used by ``tests/plot/test_viewer_guard.py`` (the guard's tests).

viser's wire format (1.x; its client ``viser/client/src/WebsocketClientWorker.ts`` and its server
``viser/infra/_infra.py``):

* client to server: one binary frame per message, the msgpack of ``{"type": CLASS NAME, FIELD: VALUE, ...}``;
* server to client: binary frames ``[u64 length of a msgpack][u64 length of its zstd
  compression][the compressed msgpack of {"messages": [...], ...}][binary buffers]``
  (little-endian); a connection's first frames replay the page's state and end with a
  ``ReplayDoneMessage``. The WebSocket subprotocol names viser's version (``viser-v1.1.1``).

Imports of viser's dependencies (websockets, msgspec, zstandard) are made where used, so that
this module imports without the viewer extra.
"""

from __future__ import annotations

import dataclasses
import math
import random
import socket
import time
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
