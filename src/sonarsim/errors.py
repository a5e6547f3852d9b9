"""Exceptions raised by sonarsim.

Every error a user can cause by bad input is a :class:`SonarsimError`; the CLI prints its
message and exits non-zero without a traceback. Programming errors stay ordinary exceptions.
"""

from __future__ import annotations


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
