"""Fuzzing the viewer's WebSocket with seeded messages of a client (issue 21 item 1).

The generator, the oracle and the checks live in :mod:`tests.fuzz.viewer` (shared with
``benchmarks/fuzz_viewer.py``, which sends 20,000). Every verdict of the gate must be the
oracle's (sound messages accepted, all others refused), and after each batch the clients stay
connected, a new connection gets a valid state (no 1011) equal to the server's, the session
agrees with the page, and nothing raised on the server. A failure names the batch, the case
number and what was generated: ``Fuzz(viewer, SEED)`` sends the same messages again.
"""

from __future__ import annotations

import pytest

pytest.importorskip("viser", reason="the viewer extra is not installed")

from . import viewer as fuzz  # noqa: E402

SEED = 20261201
BATCHES = 6
BATCH = 250

# The test clients close while viser places their camera (a warning of viser's, not a fault).
pytestmark = pytest.mark.filterwarnings("ignore:Queued a SetCamera.*on a closed connection:UserWarning")


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    from sonarsim.config.examples import demo_scene_dict
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server
    from sonarsim.plot.viewer.state import SceneSession

    doc = demo_scene_dict()  # it has a sensor: every switch can be turned
    doc["sonar"]["n_range_bins"] = 320
    doc["render"]["elevation_samples"] = 24
    server = start_server("127.0.0.1", 0)
    page = SceneViewer(server, SceneSession(doc), out=tmp_path_factory.mktemp("saved"))
    assert page.wait(30)
    yield page
    page.close()
    stop_server(server)


def test_the_viewer_takes_only_sound_messages_and_keeps_serving(viewer):
    run = fuzz.Fuzz(viewer, seed=SEED)
    try:
        for _ in range(BATCHES):
            failures = run.batch(BATCH)
            assert not failures, f"seed {SEED}: {failures[:5]}"
        summary = run.summary()
    finally:
        run.close()
    assert summary["messages"] == BATCHES * BATCH
    kinds = summary["by_kind"]
    # Every kind of message was sent; sound ones were taken (a valid value may have become
    # invalid before it arrived: the options of "component" change with "max order"), the
    # rest dropped.
    assert len(kinds) == 13, sorted(kinds)
    assert kinds["control, valid value"]["accepted"] >= 0.98 * kinds["control, valid value"]["sent"]
    assert kinds["gizmo, valid pose"]["refused"] == 0 and kinds["gizmo, far valid pose"]["refused"] == 0
    for what in ("message type not taken", "unknown control", "control, other properties"):
        assert kinds[what]["accepted"] == 0, what
    assert kinds["malformed"]["refused"] >= 0.9 * kinds["malformed"]["sent"]
    assert {"bad value", "bad field", "malformed msgpack", "message type not taken"} <= set(
        summary["gate_refused_by_reason"])


def test_the_long_run_script_runs_and_writes_its_record(tmp_path):
    import json
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "fuzz_viewer.json"
    proc = subprocess.run([sys.executable, str(root / "benchmarks" / "fuzz_viewer.py"), "--messages", "300",
                           "--batch", "150", "--seed", "5", "--json", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=root)
    assert proc.returncode == 0, proc.stderr[-2000:]
    record = json.loads(out.read_text())
    assert record["messages"] == 300 and record["batches"] == 2 and record["failures"] == 0
    assert record["verdicts"]["accepted"] + record["verdicts"]["refused"] == 301  # and the camera on connecting
