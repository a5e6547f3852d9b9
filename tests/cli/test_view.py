"""``sonarsim view`` from the command line: its messages, the port check, Ctrl-C, recordings."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

from sonarsim.cli.main import main
from sonarsim.cli.view import target_kind
from sonarsim.errors import SonarsimError
from sonarsim.plot.viewer import VIEWER_EXTRA_MESSAGE

from ..conftest import block_scene_dict


@pytest.fixture
def scene_file(tmp_path) -> Path:
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(block_scene_dict()))
    return path


def test_without_the_extra_it_says_which_to_install(scene_file, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    assert main(["view", str(scene_file)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"sonarsim: error: {VIEWER_EXTRA_MESSAGE}"
    assert "[viewer]'" in err and "pip install" in err  # (-e and this clone's path from a checkout)


def test_a_port_in_use_is_refused(scene_file, tmp_path, capsys):
    pytest.importorskip("viser")
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["view", str(scene_file), "--port", str(port), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(rf"sonarsim: error: --port {port}: port {port} on 127.0.0.1 is in use \(.*\); choose another "
                        r"with --port N, or --port 0 for any free port\n", err), err


def test_bad_targets_and_ports(tmp_path, capsys):
    pytest.importorskip("viser")  # without it, the missing extra is said first
    assert main(["view", str(tmp_path / "missing.yaml")]) == 2
    assert "missing.yaml: no such file (give a scene file or a recording)" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["view", "x.yaml", "--port", "70000"])
    assert "port number from 0" in capsys.readouterr().err
    junk = tmp_path / "junk.raw"
    junk.write_bytes(b"not a sonar file at all")
    with pytest.raises(SonarsimError, match="not a recognised sonar recording"):
        target_kind(str(junk))


def test_targets_are_told_apart(scene_file, shared_data):
    assert target_kind(str(scene_file)) == "scene"
    assert target_kind(str(shared_data / "real" / "aris" / "sample.aris")) == "recording"
    assert target_kind(str(shared_data / "real" / "oculus" / "one_ping_8bit.raw")) == "recording"


def test_a_recording_is_served_until_stopped(shared_data, monkeypatch, capsys):
    pytest.importorskip("viser")
    from sonarsim.cli.main import build_parser
    from sonarsim.cli.view import serve
    from sonarsim.plot.viewer.app import RecordingViewer

    args = build_parser().parse_args(["view", str(shared_data / "real" / "aris" / "sample.aris"), "--port", "0"])
    stop, seen = threading.Event(), {}

    def ready(viewer, url):
        seen["viewer"], seen["url"] = viewer, url
        assert viewer.wait(10)
        seen["page"] = urllib.request.urlopen(url, timeout=10).read()
        viewer.set_frame(5)
        assert viewer.wait(10)
        seen["title"] = viewer.frame.title
        stop.set()

    serve(args, stop=stop, ready=ready)
    assert isinstance(seen["viewer"], RecordingViewer)
    assert b"<html" in seen["page"].lower()
    assert seen["title"].startswith("aris frame 5 of 6")
    assert f"point your browser at {seen['url']}" in capsys.readouterr().err


def test_a_foreign_page_is_refused_and_the_user_told_once(scene_file, tmp_path, capsys):
    # Any page open in the browser could connect to the viewer on 127.0.0.1 and set its
    # controls; now the handshake is refused (403) and the command says so, once per reason.
    pytest.importorskip("viser")
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from sonarsim.cli.main import build_parser
    from sonarsim.cli.view import serve

    args = build_parser().parse_args(["view", str(scene_file), "--port", "0", "--out", str(tmp_path / "out")])
    stop, seen = threading.Event(), {}

    def ready(viewer, url):
        seen["url"] = url
        ws_url = url.replace("http://", "ws://")
        try:
            for _ in range(2):
                with pytest.raises(InvalidStatus) as info:
                    connect(ws_url, origin="http://evil.example.com", proxy=None, open_timeout=10)
                seen.setdefault("status", []).append(info.value.response.status_code)
            with connect(ws_url, origin=url.rstrip("/"), proxy=None, open_timeout=10):
                seen["own page"] = True
        finally:
            stop.set()

    serve(args, stop=stop, ready=ready)
    assert seen["status"] == [403, 403] and seen["own page"]
    err = capsys.readouterr().err
    line = (f"sonarsim: refused a connection: Origin 'http://evil.example.com' is not this viewer's page "
            f"({seen['url'].rstrip('/')})\n")
    assert err.count(line) == 1, err


def test_ctrl_c_stops_it_cleanly(scene_file, tmp_path):
    pytest.importorskip("viser")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "sonarsim", "view", str(scene_file), "--port", "0",
                             "--out", str(tmp_path / "out")], stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env)
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "point your browser at" not in line and time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line and proc.poll() is not None:
                break
        match = re.search(r"point your browser at (http://127\.0\.0\.1:\d+/)", line)
        assert match, line
        assert b"<html" in urllib.request.urlopen(match.group(1), timeout=10).read().lower()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130
    assert err.strip() == "sonarsim: interrupted by Ctrl-C (SIGINT); the viewer stopped"
    assert "Traceback" not in out + err and out == ""


@pytest.mark.parametrize("host", ["192.0.2.1", "127.0.0.1:8080", "http://127.0.0.1"])
@pytest.mark.parametrize("port", [0, 8080])
def test_a_host_it_cannot_listen_on_is_refused_at_once_even_with_any_port(host, port):
    # viser tries a thousand ports on any bind error, then waits forever: with --port 0 the
    # command hung, silent, on an address of another machine (192.0.2.1: TEST-NET-1) or a
    # host written with its port or scheme.
    pytest.importorskip("viser")
    from sonarsim.plot.viewer.app import check_port

    t0 = time.monotonic()
    with pytest.raises(SonarsimError) as info:
        check_port(host, port)
    assert time.monotonic() - t0 < 30  # a hang guard (viser's own search waited forever); milliseconds here
    message = str(info.value)
    assert message.startswith(f"--host {host}: cannot ")
    assert "in use" not in message  # the address is wrong, not the port
    assert "127.0.0.1" in message  # says what to give instead


def test_every_address_and_loopback_names_still_pass_the_check():
    pytest.importorskip("viser")
    from sonarsim.plot.viewer.app import check_port

    for host in ("127.0.0.1", "localhost", "0.0.0.0", ""):
        check_port(host, 0)


def test_a_second_ctrl_c_while_the_viewer_stops_still_says_it_stopped(scene_file, tmp_path, monkeypatch):
    # An impatient user presses Ctrl-C twice; the second lands while the server thread is
    # joined. main() prints the notes of the interrupt that reaches it: it said "nothing was
    # written" instead of "the viewer stopped".
    pytest.importorskip("viser")
    from sonarsim.cli.main import build_parser
    from sonarsim.cli.view import serve
    from sonarsim.plot.viewer import app

    real_stop = app.stop_server

    def interrupted_stop(server):
        real_stop(server)
        raise KeyboardInterrupt  # the second Ctrl-C

    def first_ctrl_c(viewer, url):
        raise KeyboardInterrupt

    monkeypatch.setattr(app, "stop_server", interrupted_stop)
    args = build_parser().parse_args(["view", str(scene_file), "--port", "0", "--out", str(tmp_path / "out")])
    with pytest.raises(KeyboardInterrupt) as info:
        serve(args, stop=threading.Event(), ready=first_ctrl_c)
    assert getattr(info.value, "__notes__", []) == ["the viewer stopped"]


def test_a_sidescan_survey_is_served_with_its_fans_and_named_film(tmp_path, capsys):
    # The example survey (a side-scan alone on its vehicle): the page draws both fans, says
    # where the waterfall comes from, moves the vehicle and saves the scene file alone.
    pytest.importorskip("viser")
    from sonarsim.cli.main import build_parser
    from sonarsim.cli.view import serve
    from sonarsim.config.loader import load_scene

    example = Path(__file__).resolve().parents[2] / "examples" / "sidescan_survey.yaml"
    args = build_parser().parse_args(["view", str(example), "--port", "0", "--out", str(tmp_path / "out")])
    stop, seen = threading.Event(), {}

    def ready(viewer, url):
        try:
            assert viewer.wait(30)
            seen["fans"] = list(viewer.fan_nodes)
            seen["status"] = viewer.status.content
            viewer.set_vehicle_pose((5.0, 5.0, 9.0), (0.0, 0.0, 45.0))
            assert viewer.wait(30)
            seen["files"] = [f.name for f in viewer.save()]
        finally:
            stop.set()

    serve(args, stop=stop, ready=ready)
    assert seen["fans"] == ["/vehicle/sidescan/port", "/vehicle/sidescan/starboard"]
    assert "no live image of sidescan 'sidescan'" in seen["status"] and f"sonarsim render {example}" in seen["status"]
    assert seen["files"] == ["scene.yaml"]
    saved = load_scene(tmp_path / "out" / "scene.yaml")
    assert saved.vehicle_pose.position_m == (5.0, 5.0, 9.0) and saved.vehicle_speed_m_s == 2.0
    assert "point your browser at" in capsys.readouterr().err
