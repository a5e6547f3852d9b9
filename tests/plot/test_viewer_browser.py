"""The viewer in a real browser: headless Chromium (Debian's ``chromium``) opens the page, the
sonar is moved through the viewer's API (as a drag of its gizmo does), and screenshots show the
3D view and both images drawn, and changed by the move.

Chromium is driven over its DevTools protocol (a websocket; viser brings the ``websockets``
package): it tells when the page is connected and its images are loaded, where they are on
the page, and takes the screenshots. Skipped where no chromium binary is found.
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra is not installed")
sync_client = pytest.importorskip("websockets.sync.client", reason="websockets without its sync client")

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium binary (Debian: apt-get install chromium)")

# The page's size: the 3D view on the left, the panel with both images on the right.
WIDTH, HEIGHT = 900, 800

# Where the page's images are, whether they are loaded, and whether the page is connected.
PAGE_STATE = """JSON.stringify({
  connected: document.body !== null && document.body.innerText.includes('Connected'),
  images: Array.from(document.images).filter(i => i.src.startsWith('blob:')).map(i => ({
      src: i.src, ok: i.complete && i.naturalWidth > 8, w: i.naturalWidth, h: i.naturalHeight,
      box: [i.getBoundingClientRect().left, i.getBoundingClientRect().top,
            i.getBoundingClientRect().right, i.getBoundingClientRect().bottom]})),
})"""


class Browser:
    """A headless Chromium with one page, driven over the DevTools protocol."""

    def __init__(self, binary: str) -> None:
        self.profile = tempfile.mkdtemp(prefix="sonarsim-chromium-")
        # Its own session, so that the browser and every helper process it starts end together.
        self.proc = subprocess.Popen(
            [binary, "--headless=new", "--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
             f"--window-size={WIDTH},{HEIGHT}", "--remote-debugging-port=0", f"--user-data-dir={self.profile}",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        self._id = 0
        try:
            port = self._devtools_port(timeout=20.0)
            targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10))
            page = next(t for t in targets if t["type"] == "page")
            self.ws = sync_client.connect(page["webSocketDebuggerUrl"], max_size=2**26, open_timeout=10)
            self.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT, deviceScaleFactor=1,
                      mobile=False)
        except BaseException:
            self.close()
            raise

    def _devtools_port(self, timeout: float) -> int:
        path = os.path.join(self.profile, "DevToolsActivePort")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"chromium exited with status {self.proc.returncode}")
            try:
                with open(path) as handle:
                    first = handle.readline().strip()
                if first:
                    return int(first)
            except FileNotFoundError:
                pass
            time.sleep(0.05)
        raise TimeoutError("chromium did not open its DevTools port")

    def call(self, method: str, **params):
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:  # events come in between; the answer carries our id
            message = json.loads(self.ws.recv(timeout=60))
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"]
        return result.get("value")

    def screenshot(self) -> np.ndarray:
        from PIL import Image

        data = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(np.int16)

    def close(self) -> None:
        ws = getattr(self, "ws", None)
        if ws is not None:
            try:
                self.call("Browser.close")
            except Exception:  # noqa: BLE001 - it may be gone already
                pass
            ws.close()
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)  # the group of the browser started above
            self.proc.wait(timeout=5)
        shutil.rmtree(self.profile, ignore_errors=True)


def page_images(browser: Browser, previous: dict | None, timeout: float = 20.0) -> dict:
    """The page's fan and polar images (boxes, sources) once connected and loaded; with
    ``previous``, once both show new images."""
    deadline = time.monotonic() + timeout
    state = None
    while time.monotonic() < deadline:
        raw = browser.evaluate(PAGE_STATE)
        if raw:
            state = json.loads(raw)
            images = [i for i in state["images"] if i["ok"]]
            if state["connected"] and len(images) >= 2:
                # The fan is the tall one, the polar image the wide one.
                found = {"fan": max(images, key=lambda i: i["h"] / i["w"]),
                         "polar": min(images, key=lambda i: i["h"] / i["w"])}
                if previous is None or all(found[k]["src"] != previous[k]["src"] for k in found):
                    return found
        time.sleep(0.1)
    raise TimeoutError(f"the page did not show its images in {timeout} s (last state: {state})")


def saturated(pixels: np.ndarray) -> int:
    """Pixels of a strong colour (the field of view, the gizmos, the objects): none while the
    3D view is blank or still fading in."""
    return int(((pixels.max(axis=2) - pixels.min(axis=2)) > 80).sum())


def drawn_screenshot(browser: Browser, region: tuple[int, int, int, int], previous: np.ndarray | None = None,
                     timeout: float = 40.0) -> np.ndarray:
    """A screenshot once the 3D view (``region``) is drawn in full colour (viser fades the scene
    in, slowly under a software renderer); with ``previous``, once it differs from it."""
    x0, y0, x1, y1 = region
    deadline = time.monotonic() + timeout
    while True:
        shot = browser.screenshot()
        view = shot[y0:y1, x0:x1]
        ready = saturated(view) > 500
        if ready and previous is not None:
            ready = (np.abs(view - previous[y0:y1, x0:x1]).max(axis=2) > 40).mean() > 0.002
        if ready or time.monotonic() > deadline:
            return shot
        time.sleep(0.3)


def crop(shot: np.ndarray, box) -> np.ndarray:
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    x0, y0 = max(x0 + 2, 0), max(y0 + 2, 0)  # inside the element's border
    return shot[y0:min(y1 - 2, shot.shape[0]), x0:min(x1 - 2, shot.shape[1])]


def drawn(pixels: np.ndarray) -> bool:
    """Not blank: varied values and many colours."""
    colours = np.unique(pixels.reshape(-1, 3), axis=0)
    return pixels.size > 0 and float(pixels.std()) > 10 and len(colours) > 50


def look_and_move(viewer, url: str) -> None:
    browser = Browser(CHROMIUM)
    try:
        browser.call("Page.navigate", url=url)
        before_images = page_images(browser, None)
        # The 3D view: left of the panel that holds the images.
        left = int(min(i["box"][0] for i in before_images.values()))
        view = (10, 160, left - 40, HEIGHT - 60)  # below the notices at its top left
        before = drawn_screenshot(browser, view)
        viewer.set_sonar_pose((0.8, 0.9, 1.4), (0.0, 30.0, 40.0))  # as a drag of the gizmo
        assert viewer.wait(20)
        after_images = page_images(browser, before_images)
        after = drawn_screenshot(browser, view, before)
    finally:
        browser.close()
    keep = os.environ.get("SONARSIM_SCREENSHOTS")  # a folder to keep the screenshots in, to look at
    if keep:
        from PIL import Image

        for name, shot in (("before", before), ("after", after)):
            Image.fromarray(shot.astype(np.uint8)).save(os.path.join(keep, f"viewer_{name}.png"))
    x0, y0, x1, y1 = view
    for name in ("fan", "polar"):
        a, b = crop(before, before_images[name]["box"]), crop(after, after_images[name]["box"])
        assert a.shape[0] > 100 and a.shape[1] > 100, f"the {name} image is not on the page: {a.shape}"
        assert drawn(a) and drawn(b), f"the {name} image is blank"
        assert a.shape == b.shape and np.abs(a - b).mean() > 3, f"the {name} image did not change"
    a, b = before[y0:y1, x0:x1], after[y0:y1, x0:x1]
    assert drawn(a) and drawn(b) and saturated(a) > 500 and saturated(b) > 500, "the 3D view is blank"
    # The sonar, its gizmo and its field of view moved: many pixels changed.
    assert (np.abs(a - b).max(axis=2) > 40).mean() > 0.002, "the 3D view did not change"


def test_the_page_draws_the_scene_and_the_images_and_follows_the_sonar():
    from sonarsim.config.examples import demo_scene_dict
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server, url_of
    from sonarsim.plot.viewer.state import SceneSession

    server = start_server("127.0.0.1", 0)
    viewer = SceneViewer(server, SceneSession(demo_scene_dict()), out="unused")
    try:
        assert viewer.wait(30)
        try:
            look_and_move(viewer, url_of(server, "127.0.0.1"))
        except (TimeoutError, ConnectionError, OSError):  # a slow start of the browser: once more
            viewer.set_sonar_pose((0.0, 0.0, 1.0), (0.0, 20.0, 0.0))
            assert viewer.wait(20)
            look_and_move(viewer, url_of(server, "127.0.0.1"))
    finally:
        viewer.close()
        stop_server(server)


def test_what_the_page_sends_passes_the_guard():
    """The page's own messages -- its camera, a checkbox clicked, a slider moved by the keyboard
    -- are taken by the viewer's guard (plot/viewer/guard.py), none refused."""
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server, url_of
    from sonarsim.plot.viewer.guard import gate_of, guard_of
    from sonarsim.plot.viewer.state import SceneSession

    from ..conftest import block_scene_dict

    def until(condition, timeout: float = 20.0) -> bool:
        deadline = time.monotonic() + timeout
        while not condition() and time.monotonic() < deadline:
            time.sleep(0.05)
        return condition()

    server = start_server("127.0.0.1", 0)
    viewer = SceneViewer(server, SceneSession(block_scene_dict()), out="unused")
    browser = None
    try:
        assert viewer.wait(30)
        browser = Browser(CHROMIUM)
        browser.call("Page.navigate", url=url_of(server, "127.0.0.1"))
        page_images(browser, None)
        # The checkbox's input carries the control's uuid as its id.
        uuid = next(u for u, h in server.gui._gui_input_handle_from_uuid.items() if h is viewer.speckle)
        browser.evaluate(f"document.getElementById({json.dumps(uuid)}).click()")
        assert until(lambda: viewer.session.options.speckle)
        # The "max order" slider (1 to 6), one step down with the arrow key.
        focused = browser.evaluate("(() => { const s = Array.from(document.querySelectorAll('[role=slider]'))"
                                   ".find(e => e.getAttribute('aria-valuemax') === '6'); s.focus();"
                                   " return document.activeElement === s; })()")
        assert focused
        for kind in ("keyDown", "keyUp"):
            browser.call("Input.dispatchKeyEvent", type=kind, key="ArrowLeft", code="ArrowLeft",
                         windowsVirtualKeyCode=37)
        assert until(lambda: viewer.session.options.max_order == 2)
    finally:
        if browser is not None:
            browser.close()
        viewer.close()
        stop_server(server)
    gate = gate_of(server)
    assert gate.accepted["ViewerCameraMessage"] >= 1 and gate.accepted["GuiUpdateMessage"] == 2
    assert not gate.refused and not guard_of(server).refused
