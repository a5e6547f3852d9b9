"""Fuzz the viewer's WebSocket at length: the CI fuzz test's generator and checks, for many messages.

Serves the demo scene with ``sonarsim view``'s server (:func:`sonarsim.plot.viewer.app.start_server`,
guarded) on a free port of 127.0.0.1 and sends it seeded random messages from one client, as
a page would send them (see ``tests/fuzz/viewer.py``): controls set to valid values, to random
ones (extreme numbers, wrong types) and with other properties than their value; unknown
controls; gizmo poses, valid (near and far) and random; drags' starts and ends; camera
messages; message types the viewer does not take; messages with fields deleted, added or of the
wrong type; malformed msgpack and text frames. Each verdict of the server's gate is compared
with an oracle's at the same moment; after each batch the clients must still be connected, a
new connection must get a valid state equal to the server's (no 1011), the session must agree
with the page, the images must be rendered and nothing may have raised on the server.

Usage (from the repository root)::

    python benchmarks/fuzz_viewer.py                          # 20,000 messages, seed 0
    python benchmarks/fuzz_viewer.py --messages 5000 --seed 3 --json /tmp/x/fuzz_viewer.json

Prints a summary and writes it as JSON (messages by what was generated and verdict, the gate's
counts by message type and by reason, failures -- 0 expected -- with the batch and case that
regenerate them, the slowest check, wall time). Exits 1 if anything failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # for tests.fuzz.viewer


def main(argv: list[str] | None = None) -> int:
    """Run the fuzzing; returns the exit status (0: no failures)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--messages", type=int, default=20_000, help="number of messages (default 20000)")
    p.add_argument("--batch", type=int, default=250, help="messages between two checks (default 250)")
    p.add_argument("--seed", type=int, default=0, help="seed of the message generator (default 0)")
    p.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "fuzz_viewer.json",
                   help="where to write the summary (default benchmarks/fuzz_viewer.json)")
    args = p.parse_args(argv)

    import viser

    from sonarsim.config.examples import demo_scene_dict
    from sonarsim.plot.viewer.app import SceneViewer, start_server, stop_server
    from sonarsim.plot.viewer.state import SceneSession
    from tests.fuzz import viewer as fuzz

    # A check's client closes while viser places its camera: viser warns, nothing is wrong.
    warnings.filterwarnings("ignore", "Queued a SetCamera.*on a closed connection", UserWarning)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonarsim-fuzz-viewer-") as tmp:
        server = start_server("127.0.0.1", 0)
        page = SceneViewer(server, SceneSession(demo_scene_dict()), out=Path(tmp) / "saved")
        try:
            if not page.wait(60):
                raise SystemExit("the viewer did not render its first images in 60 s")
            run = fuzz.Fuzz(page, seed=args.seed)
            try:
                while run.cases < args.messages:
                    failures = run.batch(min(args.batch, args.messages - run.cases))
                    for f in failures[:3]:
                        print(f"FAILED batch {f['batch']} case {f['case']} ({f['what']}): {f['detail']}",
                              file=sys.stderr)
                    if run.batches % 20 == 0:
                        print(f"{run.cases} messages, {len(run.failures)} failures, "
                              f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
                summary = run.summary()
                saves = len(list((Path(tmp) / "saved").glob("*.png")))
            finally:
                run.close()
        finally:
            page.close()
            stop_server(server)
    wall = time.perf_counter() - t0
    summary = {
        **summary,
        "batch": args.batch,
        "new_connections_checked": summary["batches"],
        "scene": "the demo (sonarsim demo)",
        "viser": viser.__version__,
        "saved_images_present": saves,
        "wall_s": round(wall, 1),
        "ms_per_message": round(1e3 * wall / max(args.messages, 1), 3),
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "failed"}, indent=2))
    print(f"wrote {args.json}", file=sys.stderr)
    return 1 if summary["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
