"""Ctrl-C (and the stop signals) at the two moments a plain ``KeyboardInterrupt`` goes wrong.

**While the command starts.** The ``sonarsim`` command's own handler (:func:`sonarsim.cli.main.main`)
is in place only once its modules are imported; a Ctrl-C before that (during ``import sonarsim``,
``import argparse``: a tenth of a second on a quiet machine, several on a loaded one) printed a
traceback. :func:`hold_ctrl_c_while_the_command_starts`, called on the first line of
``import sonarsim`` when the process is that command (``python -m sonarsim``, ``python -m
sonarsim.cli.main`` or the ``sonarsim`` executable), makes Ctrl-C say the command's one line
and exit with 130 at once: nothing has been written yet, so there is nothing to clean up.
:func:`release_ctrl_c_hold` hands Ctrl-C back to Python (a ``KeyboardInterrupt``) once the
command line is parsed and the command about to run (everything before is imports and parsing). Only a Ctrl-C in the interpreter's own start, before
``import sonarsim`` begins, is beyond reach. This module imports only ``os``, ``signal`` and
``sys`` at its top, so that the hold is in place after as little work as possible.

**While a library that would swallow it runs.** Some libraries cannot take an exception in the
middle of their work: trimesh imports its optional dependencies inside ``try: ... except
BaseException`` (a Ctrl-C during that second is caught as if the dependency were missing, and
the command runs on), and matplotlib's C code turns one raised inside it into its own error.
:func:`signals_deferred` records such signals during the block and delivers them, to the
handlers that were in place, as soon as it ends.
"""

from __future__ import annotations

import os
import signal
import sys

# Not ``typing.TYPE_CHECKING``: importing typing costs more than the rest of this module, before
# the hold is in place (type checkers read a module-level TYPE_CHECKING of this name alike).
TYPE_CHECKING = False
if TYPE_CHECKING:
    from contextlib import AbstractContextManager
    from types import FrameType

__all__ = ["DEFERRED_SIGNALS", "STARTING_MESSAGE", "command_is_starting", "ctrl_c_received",
           "hold_ctrl_c_while_the_command_starts", "release_ctrl_c_hold", "signals_deferred"]

#: What is held back: Ctrl-C, and the signals the command line turns into exceptions.
DEFERRED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))

#: The line a Ctrl-C during the command's start prints (the one :func:`sonarsim.cli.main.main`
#: prints for a Ctrl-C while it parses the command line).
STARTING_MESSAGE = "sonarsim: interrupted by Ctrl-C (SIGINT); nothing was written"

# The modules whose ``python -m`` is the command (sonarsim/__main__.py, cli/main.py's __main__).
_COMMAND_MODULES = ("sonarsim", "sonarsim.cli.main")


def command_is_starting(orig_argv: list[str] | None = None, argv0: str | None = None) -> bool:
    """Whether this process is the ``sonarsim`` command (so far as its command line tells).

    Parameters
    ----------
    orig_argv : list of str, optional
        The interpreter's own command line (default :data:`sys.orig_argv`): ``python [options]
        -m sonarsim ...`` or ``-m sonarsim.cli.main``.
    argv0 : str, optional
        The program's name (default ``sys.argv[0]``): the ``sonarsim`` executable's script.

    Returns
    -------
    bool
    """
    orig = list(getattr(sys, "orig_argv", []) if orig_argv is None else orig_argv)
    name = (sys.argv[0] if sys.argv else "") if argv0 is None else argv0
    args = iter(orig[1:])
    for arg in args:
        if arg == "-m":
            return next(args, None) in _COMMAND_MODULES
        if arg.startswith("-m"):  # -msonarsim
            return arg[2:] in _COMMAND_MODULES
        if arg in ("-X", "-W", "--check-hash-based-pycs"):  # an option's value follows
            next(args, None)
        elif arg == "-c" or arg == "-" or not arg.startswith("-"):  # a program: what follows is its own
            break
    return os.path.basename(name) in ("sonarsim", "sonarsim.exe", "sonarsim-script.py")


def _stop_while_starting(signum: int, frame: FrameType | None) -> None:
    # os.write: the sys.stderr object may not exist yet or be half-set-up; the descriptor is there.
    try:
        os.write(2, (STARTING_MESSAGE + "\n").encode())
    except OSError:  # a closed stderr: the exit status still says it
        pass
    os._exit(128 + int(signum))


def hold_ctrl_c_while_the_command_starts() -> bool:
    """In the ``sonarsim`` command (:func:`command_is_starting`), make Ctrl-C print
    :data:`STARTING_MESSAGE` and exit with 130 at once, until :func:`release_ctrl_c_hold`.

    Elsewhere (a program or notebook importing sonarsim, the dataset's worker processes) it
    does nothing: a library leaves the signal handlers of its host alone.

    Returns
    -------
    bool
        Whether the hold was put in place.
    """
    if not command_is_starting():
        return False
    try:
        if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
            return False  # the host chose its own handling (or ignores Ctrl-C): keep it
        signal.signal(signal.SIGINT, _stop_while_starting)
    except ValueError:  # imported outside the main thread: handlers cannot be set there
        return False
    return True


# Ctrl-Cs received since the command's start (the command line's process only: see
# release_ctrl_c_hold).
_received = 0


def _ctrl_c_remembered(signum: int, frame: FrameType | None) -> None:
    global _received
    _received += 1
    raise KeyboardInterrupt


def release_ctrl_c_hold() -> None:
    """Ctrl-C raises ``KeyboardInterrupt`` again, where
    :func:`hold_ctrl_c_while_the_command_starts` held it (otherwise nothing changes), and is
    remembered (:func:`ctrl_c_received`).

    A Ctrl-C that lands while a compiled module initialises may be turned into another error
    by it, its cause lost (NumPy's ``PyCapsule_Import could not import module "datetime"``, seen
    on a loaded machine): the command then still knows that Ctrl-C is what stopped it.
    """
    try:
        if signal.getsignal(signal.SIGINT) is _stop_while_starting:
            signal.signal(signal.SIGINT, _ctrl_c_remembered)
    except ValueError:  # not the main thread: the hold, if any, was not set from here either
        pass


def ctrl_c_received() -> bool:
    """Whether Ctrl-C has reached the command since :func:`release_ctrl_c_hold` (always False in
    a process that is not the ``sonarsim`` command: there the handlers are its host's)."""
    return _received > 0


class _Deferred:
    """The context manager of :func:`signals_deferred`."""

    def __enter__(self) -> None:
        import threading

        self.pending: list[int] = []
        self.previous: dict[int, object] = {}
        if threading.current_thread() is not threading.main_thread():
            return
        for signum in DEFERRED_SIGNALS:
            self.previous[signum] = signal.signal(signum, lambda s, _frame: self.pending.append(s))

    def __exit__(self, *exc: object) -> None:
        for signum, handler in self.previous.items():
            # None: a handler set from C, not Python (it cannot be put back; the default can).
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        for signum in dict.fromkeys(self.pending):  # once each
            handler = self.previous[signum]
            if callable(handler):
                handler(signum, None)  # e.g. default_int_handler raises KeyboardInterrupt here
            elif handler != signal.SIG_IGN:
                os.kill(os.getpid(), signum)  # what would have happened: now, handlers restored


def signals_deferred() -> AbstractContextManager[None]:
    """Within the block, :data:`DEFERRED_SIGNALS` are recorded instead of handled; at its end
    the handlers in place before it get them, in arrival order. Outside the main thread (where
    handlers cannot be set) it does nothing.

    Returns
    -------
    context manager
        For ``with signals_deferred(): ...``.
    """
    return _Deferred()
