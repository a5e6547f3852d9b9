"""Holding Ctrl-C (and the stop signals) back while a library that would swallow it runs.

Some libraries cannot take an exception in the middle of their work: trimesh imports its
optional dependencies inside ``try: ... except BaseException`` (a Ctrl-C during that second is
caught as if the dependency were missing, and the command runs on), and matplotlib's C code
turns one raised inside it into its own error. :func:`signals_deferred` records such signals
during the block and delivers them, to the handlers that were in place, as soon as it ends.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator

__all__ = ["DEFERRED_SIGNALS", "signals_deferred"]

#: What is held back: Ctrl-C, and the signals the command line turns into exceptions.
DEFERRED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Within the block, :data:`DEFERRED_SIGNALS` are recorded instead of handled; at its end
    the handlers in place before it get them, in arrival order. Outside the main thread (where
    handlers cannot be set) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    previous = {}
    for signum in DEFERRED_SIGNALS:
        previous[signum] = signal.signal(signum, lambda s, _frame: pending.append(s))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            # None: a handler set from C, not Python (it cannot be put back; the default can).
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        for signum in dict.fromkeys(pending):  # once each
            handler = previous[signum]
            if callable(handler):
                handler(signum, None)  # e.g. default_int_handler raises KeyboardInterrupt here
            elif handler != signal.SIG_IGN:
                os.kill(os.getpid(), signum)  # what would have happened: now, handlers restored
