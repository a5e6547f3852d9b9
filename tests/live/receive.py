"""The tests' subscriber side: samples taken while a ``sonarsim live`` process runs."""

from __future__ import annotations

import time


def receive(readers: dict, live, others=(), timeout_s: float = 60.0, poll_s: float = 0.005):
    """Take what ``readers`` (name -> DataReader) receive while ``live`` (a Popen with stderr
    piped) runs, and what is left once it ended; kill ``live`` and ``others`` if they outlast it.

    Returns
    -------
    (dict of name -> list of (arrival seconds, sample), str)
        Valid samples only (not a writer's disposal), and ``live``'s stderr.
    """
    got = {name: [] for name in readers}

    def take():
        for name, reader in readers.items():
            got[name] += [(time.monotonic(), s) for s in reader.take(N=64) if type(s).__name__ != "InvalidSample"]

    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and live.poll() is None:
            take()
            time.sleep(poll_s)
        take()
        err = live.communicate(timeout=30)[1]
    finally:
        for p in (live, *others):
            if p.poll() is None:
                p.kill()
    return got, err
