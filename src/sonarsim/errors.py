"""Exceptions raised by sonarsim.

Every error a user can cause by bad input is a :class:`SonarsimError`; the CLI prints its
message and exits non-zero without a traceback. Programming errors stay ordinary exceptions.
"""

from __future__ import annotations

import os


class SonarsimError(Exception):
    """Base class of the errors caused by bad input (files, keys, values)."""


class ConfigError(SonarsimError, ValueError):
    """A scene or sonar configuration is invalid.

    Parameters
    ----------
    key : str
        Dotted path of the offending key, e.g. ``"objects[1].albedo"``; empty for the whole
        document.
    message : str
        What is wrong and what is allowed.
    source : str, optional
        The file the configuration came from.
    """

    def __init__(self, key: str, message: str, source: str | None = None) -> None:
        self.key = key
        self.detail = message
        self.source = source
        where = f"{source}: " if source else ""
        what = f"{key}: " if key else ""
        super().__init__(f"{where}{what}{message}")


class MeshFileError(SonarsimError):
    """A mesh file is missing, unreadable or empty."""


# How a user's value appears in a message: a scene file may hold a 100,000-character string, a
# list of a million numbers or a list nested a thousand deep, and the message must stay one
# readable line (and repr of the deep list would itself fail).
_SHOWN_LIMIT = 80


def shown(value: object, limit: int = _SHOWN_LIMIT) -> str:
    """``repr(value)`` abbreviated for an error message: one line of at most about ``limit`` characters.

    Parameters
    ----------
    value : object
        A value from the user's input (any size, any nesting).
    limit : int
        Characters kept; longer representations end in ``...``.

    Returns
    -------
    str
        E.g. ``[0.0, 0.0, -1.0, 0.0, ...]`` or ``'xxxxxxxx...'`` (100000 characters).
    """
    import reprlib

    r = reprlib.Repr()
    r.maxlevel, r.maxlist, r.maxtuple, r.maxdict, r.maxset = 3, 6, 6, 4, 4
    r.maxstring, r.maxother, r.maxlong = limit, limit, 40
    try:
        text = r.repr(value)
    except Exception:  # noqa: BLE001 - a value whose repr fails is still shown by its type
        text = f"<{type(value).__name__}>"
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    if isinstance(value, str) and len(value) > limit:
        text += f" ({len(value)} characters)"
    elif isinstance(value, (list, tuple)) and len(value) > r.maxlist:
        text += f" ({len(value)} items)"
    return text


def key_text(key: object) -> str:
    """A mapping key as it appears in an error's key path: as written when it is a short,
    printable string, else :func:`shown` (a key may be a number, hold a newline, or be huge)."""
    if isinstance(key, str) and key.isprintable() and 0 < len(key) <= _SHOWN_LIMIT:
        return key
    return shown(key)


def check_input_file(path: str | os.PathLike, what: str) -> os.stat_result:
    """Stat an input file before opening it, so that what is not a readable regular file ends
    in one clear message instead of a hang or a misleading one.

    Opening a FIFO blocks until someone writes to it, and ``Path.exists`` calls a symbolic
    link loop "not found"; both are told apart here.

    Parameters
    ----------
    path : str or os.PathLike
        The file the user named.
    what : str
        What it should be, for the messages: ``"scene file"``, ``"mesh file"``, ``"recording"``.

    Returns
    -------
    os.stat_result
        The file's status (size, modification time).

    Raises
    ------
    SonarsimError
        ``PATH: WHAT not found``, ``PATH: is a directory, not a WHAT``, ``PATH: not a regular
        file (a device or pipe?); give a WHAT`` or ``PATH: cannot read the WHAT: REASON`` (a
        symbolic link loop, a name too long, a folder that cannot be searched).
    """
    import stat

    name = os.fspath(path)
    try:
        st = os.stat(name)
    except FileNotFoundError:
        raise SonarsimError(f"{name}: {what} not found") from None
    except OSError as exc:
        raise SonarsimError(f"{key_text(name)}: cannot read the {what}: {exc.strerror or exc}") from None
    except ValueError as exc:  # an embedded NUL character
        raise SonarsimError(f"{key_text(name)}: cannot read the {what}: {exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise SonarsimError(f"{name}: is a directory, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise SonarsimError(f"{name}: not a regular file (a device or pipe?); give a {what}")
    return st


def regular_file_bytes(path: str | os.PathLike, what: str) -> bytes | None:
    """The bytes of a file sonarsim itself keeps (a dataset's manifest, a run record), or None
    when there is none; what is not a regular file (a pipe someone put there, which ``open``
    would wait on forever) is refused.

    Raises
    ------
    SonarsimError
        As :func:`check_input_file`, naming the file and ``what``; or it cannot be read.
    """
    if not os.path.lexists(path):
        return None
    check_input_file(path, what)
    try:
        with open(path, "rb") as handle:
            return handle.read()
    except OSError as exc:
        raise SonarsimError(f"{key_text(os.fspath(path))}: cannot read the {what}: {exc.strerror or exc}") from None


def interrupt_of(exc: BaseException | None) -> KeyboardInterrupt | None:
    """The ``KeyboardInterrupt`` (Ctrl-C, or a signal the CLI turns into one) behind ``exc``.

    ``exc`` itself, or one in its chain of causes and contexts: a Ctrl-C that lands while
    Python imports a compiled module surfaces as ``ImportError: initialization failed`` caused
    by the ``KeyboardInterrupt``, and it must stop a command as a Ctrl-C does, not as a bug.
    """
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None

