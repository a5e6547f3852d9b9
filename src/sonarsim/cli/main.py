"""Command-line interface: a thin layer over the library; one module per command.

Results go to files; progress and timing go to stderr. Bad input ends with a one-line message
naming the key or file, exit status 2, and no traceback. A warning (Python's ``warnings`` or a
sonarsim logger's) is one line, ``sonarsim: warning: ...``. Ctrl-C, SIGTERM and SIGHUP end the
command cleanly (temporary files removed, the run recorded as interrupted) with a one-line
message and exit status 128 + the signal's number (130, 143, 129).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from typing import Iterator, Sequence

# The message and warning forms are core.console's (the dataset's workers use them too);
# re-exported here, where they were defined before.
from ..core.console import WarningLogHandler, install_warning_format, show_warning  # noqa: F401
from ..core.console import log as _log
from ..errors import SonarsimError, interrupt_of

EXIT_BAD_INPUT = 2

# Signals that stop a command the way Ctrl-C does: unwinding, so that every ``finally`` and
# ``atomic_write`` cleans up, instead of dying on the spot and leaving temporary files.
_STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


class Terminated(KeyboardInterrupt):
    """A stop signal (SIGTERM, SIGHUP) turned into an exception; a KeyboardInterrupt, so code
    that cleans up after Ctrl-C cleans up after it too."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated(signum)


@contextlib.contextmanager
def _stop_signals_raise() -> Iterator[None]:
    """Turn SIGTERM and SIGHUP into :class:`Terminated` for the duration of the block."""
    previous = {}
    try:
        for signum in _STOP_SIGNALS:
            previous[signum] = signal.signal(signum, _raise_terminated)
    except ValueError:  # not the main thread (e.g. main() called from a worker thread)
        pass
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _memory_size(text: str) -> int:
    from ..core.memory import parse_size

    try:
        return parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _seconds(text: str) -> float:
    from ..core.memory import parse_seconds

    try:
        return parse_seconds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    """The ``sonarsim`` parser: one sub-command per module of :mod:`sonarsim.cli`."""
    from .calibrate import add_calibrate_parser
    from .compare import add_compare_parser
    from .dataset import add_dataset_parser
    from .demo import add_demo_parser
    from .fit import add_fit_parser
    from .live import add_live_demo_parser, add_live_parser
    from .presets import add_presets_parser
    from .reconstruct import add_reconstruct_parser
    from .render import add_render_parser
    from .show import add_show_parser
    from .view import add_view_parser

    from .argtypes import Parser

    # (values that begin with a minus, --extent -1,3,0,1, in every sub-command: see Parser)
    parser = Parser(
        prog="sonarsim",
        description="Simulate 2D forward-looking sonar images (with ground echoes) from 3D scenes.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"sonarsim {__version__}")
    parser.add_argument("--max-memory", type=_memory_size, default=None, metavar="SIZE",
                        help="memory budget that sizes are checked against before allocating, e.g. 4G "
                        "(default: $SONARSIM_MAX_MEMORY, else 8 GiB or 80%% of the machine's memory)")
    parser.add_argument("--max-build-time", type=_seconds, default=None, metavar="SECONDS",
                        help="time budget that building a scene (its objects and triangles, a mesh file) and a "
                        "reconstruction's searches of its grid are estimated against before they start, e.g. 300 or "
                        "5min (default: $SONARSIM_MAX_BUILD_TIME, else 120 s)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    add_render_parser(sub)
    add_demo_parser(sub)
    add_presets_parser(sub)
    add_dataset_parser(sub)
    # Real data: reading recordings, comparing images, fitting the pose.
    add_show_parser(sub)
    add_compare_parser(sub)
    add_fit_parser(sub)
    add_calibrate_parser(sub)
    add_reconstruct_parser(sub)
    # Looking: a scene in 3D with its live images, or a recording's frames, in the browser.
    add_view_parser(sub)
    # Live: ROS 2 topics over DDS.
    add_live_parser(sub)
    add_live_demo_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sonarsim`` command; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:  # building the parser imports the commands' modules: Ctrl-C may come in that time
        args = build_parser().parse_args(argv)
        from ..core import memory  # (an import too: inside the guard)

        memory.set_memory_budget(args.max_memory)
        memory.set_time_budget(args.max_build_time)
    except Exception as exc:
        if interrupt_of(exc) is None:  # (a Ctrl-C during an import can arrive as an ImportError)
            raise
        _log("interrupted by Ctrl-C (SIGINT); nothing was written")
        return 128 + int(signal.SIGINT)
    except KeyboardInterrupt:
        _log("interrupted by Ctrl-C (SIGINT); nothing was written")
        return 128 + int(signal.SIGINT)
    # Stored in each run's record (sonarsim.io.run_record), so a folder says what made it.
    args.command_line = ["sonarsim", *map(str, argv)]
    # The budgets also for the processes this command starts (dataset workers come from a fork
    # server and share this process's environment, not its settings), for this command only:
    # main() is called in-process too (tests, notebooks).
    chosen = {memory.ENV_VAR: args.max_memory, memory.TIME_ENV_VAR: args.max_build_time}
    saved = {name: os.environ.get(name) for name in chosen}
    try:
        for name, value in chosen.items():
            if value is not None:
                os.environ[name] = str(value)
        return _run(args)
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        memory.set_memory_budget(None)
        memory.set_time_budget(None)


def _run(args) -> int:
    """Run the parsed command; returns the exit status (errors and signals as one line)."""
    from ..core.interrupts import ctrl_c_received, release_ctrl_c_hold

    # The command's start (imports, parsing) held Ctrl-C (core.interrupts); from here it raises.
    release_ctrl_c_hold()
    try:
        with _stop_signals_raise():
            args.func(args)
    except SonarsimError as exc:
        _log(f"error: {exc}")
        # A refused result (a degenerate calibration) says so with its own status (3).
        return int(getattr(exc, "exit_status", EXIT_BAD_INPUT))
    except OSError as exc:  # e.g. a disk that filled up while writing
        # atomic_write names the destination, never its temporary file.
        name = exc.filename2 or exc.filename or ""
        _log(f"error: {name}: {exc.strerror or exc}" if name else f"error: {exc.strerror or exc}")
        return EXIT_BAD_INPUT
    except MemoryError as exc:
        # Sizes are checked against the budget first; this happens only when the budget was
        # raised beyond what the machine can give (--max-memory 10T), so say that, in one line.
        from ..core.memory import memory_budget

        _log(f"error: out of memory ({exc or 'MemoryError'}) within the memory budget of "
             f"{memory_budget() / 2**30:.3g} GiB; this machine cannot give that much: lower the sizes "
             "or --max-memory / $SONARSIM_MAX_MEMORY")
        return EXIT_BAD_INPUT
    except BaseException as exc:
        # Ctrl-C, SIGTERM/SIGHUP (Terminated), or an error caused by one: a Ctrl-C that lands
        # while a compiled module is imported surfaces as "ImportError: initialization failed".
        interrupt = interrupt_of(exc)
        if interrupt is None and ctrl_c_received() and not isinstance(exc, SystemExit):
            interrupt = KeyboardInterrupt()  # turned into another error where it landed (a module's import)
        if interrupt is None or isinstance(exc, SystemExit):
            raise
        signum = interrupt.signum if isinstance(interrupt, Terminated) else signal.SIGINT
        what = "Ctrl-C (SIGINT)" if signum == signal.SIGINT else signal.Signals(signum).name
        notes = "; ".join(getattr(exc, "__notes__", []) or getattr(interrupt, "__notes__", []))
        _log(f"interrupted by {what}; {notes or 'nothing was written'}")
        return 128 + int(signum)
    return 0


def console_main() -> None:
    """The ``sonarsim`` executable (and ``python -m sonarsim``): :func:`main`, then exit.

    Warnings are shown as one ``sonarsim: warning: ...`` line each (:func:`install_warning_format`).

    A command stopped by a signal exits at once with 128 + its number, after flushing its
    output: the interpreter's own shutdown, which may still see the interrupt that the command
    handled (one that arrived during an import), would otherwise end the process by SIGINT.
    """
    install_warning_format()
    code = main()
    if code >= 128:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


if __name__ == "__main__":  # pragma: no cover
    console_main()
