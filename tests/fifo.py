"""A guard for tests that hand sonarsim a pipe (FIFO): the call must not block on it.

Opening a FIFO for reading blocks until a writer opens it. A regression would hang the test
run; :func:`no_hang` runs the call in a thread and, if it has not returned in time, opens each
FIFO for writing (which releases a reader blocked on it) and fails the test.
"""

from __future__ import annotations

import os
import threading
from typing import Any, Callable, Sequence

import pytest


def no_hang(call: Callable[[], Any], fifos: Sequence[os.PathLike | str], seconds: float = 4.0) -> Any:
    """``call()``'s result, or the exception it raised; fails the test if it is still running
    after ``seconds`` (blocked on one of ``fifos``, which are then released)."""
    outcome: dict[str, Any] = {}

    def run() -> None:
        try:
            outcome["value"] = call()
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test's thread
            outcome["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        for fifo in fifos:
            try:  # a reader blocked in open() wakes once a writer opens the pipe; closing gives it EOF
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        thread.join(seconds)
        pytest.fail(f"still running after {seconds} s: it opened one of the pipes {[str(f) for f in fifos]}")
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")
