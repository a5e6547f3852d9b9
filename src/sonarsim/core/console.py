"""How sonarsim speaks on stderr: ``sonarsim: MESSAGE`` lines, and warnings as one line.

The command line's form (:mod:`sonarsim.cli`) and that of the processes it starts (the dataset
writer's workers install the same warning format): it sits in core, below both, so that
:mod:`sonarsim.dataset` need not import the command line for it. Standard library only.
"""

from __future__ import annotations

import logging
import sys
import warnings
from typing import TextIO

__all__ = ["WarningLogHandler", "install_warning_format", "log", "one_line", "show_warning"]


def log(msg: str) -> None:
    """Say ``sonarsim: MSG`` on stderr: progress, timing and errors of a command."""
    print(f"sonarsim: {msg}", file=sys.stderr, flush=True)


def one_line(text: str) -> str:
    """``text`` with every run of whitespace (newlines too) as one space: a message is one line."""
    return " ".join(str(text).split())


def show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
    """:func:`warnings.showwarning` for the command line: ``sonarsim: warning: MESSAGE``.

    Python's own format names the source file and line that warned and repeats that line of
    code, which says nothing to someone running a command. The category is added only when it
    is not the plain :class:`UserWarning` sonarsim raises (e.g. a NumPy ``RuntimeWarning``),
    where it tells what kind of problem it is.

    Parameters
    ----------
    message, category, filename, lineno, file, line
        As :func:`warnings.showwarning` receives them; ``file`` defaults to ``sys.stderr``
        at the time of the warning.
    """
    stream = file if file is not None else sys.stderr
    if stream is None:  # pythonw, or stderr closed by the caller: nowhere to say it
        return
    kind = "" if category is UserWarning else f" ({category.__name__})"
    try:
        stream.write(f"sonarsim: warning: {one_line(message)}{kind}\n")
        stream.flush()
    except (OSError, ValueError):  # a closed or broken stderr must not end the command
        pass


class WarningLogHandler(logging.Handler):
    """Log records of sonarsim's loggers as ``sonarsim: warning: MESSAGE`` (or ``error``) lines
    on ``sys.stderr``, the same form as :func:`show_warning` gives Python warnings.

    ``sys.stderr`` is looked up at each record (not kept), so a redirected stderr is honoured.
    """

    def emit(self, record: logging.LogRecord) -> None:
        try:
            level = "warning" if record.levelno < logging.ERROR else "error"
            stream = sys.stderr
            if stream is not None:
                stream.write(f"sonarsim: {level}: {one_line(record.getMessage())}\n")
                stream.flush()
        except Exception:  # noqa: BLE001 - logging's own rule: a handler never raises
            self.handleError(record)


def install_warning_format() -> None:
    """Show Python warnings and sonarsim's log warnings as one ``sonarsim: warning: ...`` line.

    Done by the ``sonarsim`` executable (:func:`sonarsim.cli.main.console_main`) only, not by
    :func:`sonarsim.cli.main.main`: a program or test calling that keeps its own warning
    machinery (pytest records warnings by the very hook this replaces).
    """
    warnings.showwarning = show_warning
    logger = logging.getLogger("sonarsim")
    if not any(isinstance(h, WarningLogHandler) for h in logger.handlers):
        handler = WarningLogHandler(logging.WARNING)
        logger.addHandler(handler)
    # Without a level of its own the logger would follow the root's (WARNING unless changed);
    # set it so that warnings are shown whatever the root logger says.
    if logger.level == logging.NOTSET:
        logger.setLevel(logging.WARNING)
