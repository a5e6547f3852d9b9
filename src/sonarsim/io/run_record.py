"""The output side of a command: its files checked before the work, and a record of each run.

Every sonarsim command that writes files goes through an :class:`OutputRun`:

1. ``OutputRun(record, files)`` checks, before anything is read or rendered, that every output
   can be written: its folder exists or can be created, is a folder and is writable (a probe
   file is created and removed), no output path is a folder, no two outputs are the same file,
   and no live sonarsim process is writing the same outputs. A problem raises
   :class:`OutputError` naming the option and the user's path.
2. ``with run:`` starts the run: it removes temporary files that killed runs left
   (:func:`~sonarsim.io.output.remove_abandoned_temp_files`), replaces the previous record
   with one whose status is ``"running"`` and that lists the files this run will write, and
   removes the files that the previous record lists and this run will not write, so a reused
   folder does not end up holding new files beside stale ones. Files no record lists were
   never sonarsim's and are never touched; a file that a complete record lists but that has
   changed since (another size or checksum) is the user's now, and is kept.
3. Leaving the block normally writes the record once more, last, with status ``"complete"``
   and each file's size and sha256. Leaving it by an exception records ``"failed"`` or
   ``"interrupted"`` (Ctrl-C, or a signal the CLI turns into ``KeyboardInterrupt``) and the
   error. A folder whose record is missing or says anything but ``"complete"`` is therefore
   recognisably incomplete, even after SIGKILL or a power cut.

The record is a small JSON file: :data:`RECORD_NAME` (``sonarsim-run.json``) in an output
folder, or ``NAME.sonarsim-run.json`` beside a single output file NAME
(:func:`record_beside`). Example::

    {"sonarsim_run": 1, "status": "complete", "command": ["sonarsim", "render", "s.yaml",
     "--out", "out"], "version": "0.1.0", "pid": 4242, "host": "lab1",
     "started_utc": "2026-11-23T15:02:11Z", "finished_utc": "2026-11-23T15:02:13Z",
     "files": [{"name": "polar.png", "bytes": 10473, "sha256": "9f2c..."}, ...]}

Files are listed by ``name`` when they lie in the record's folder and by absolute ``path``
otherwise (e.g. ``fit --image`` elsewhere); only ``name`` entries are ever removed as stale.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import socket
import stat
import sys
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, Callable

from ..errors import SonarsimError, interrupt_of, regular_file_bytes, shown
from .output import _pid_alive, atomic_write, file_digest, remove_abandoned_temp_files, temp_prefix

__all__ = ["RECORD_NAME", "STATUSES", "OutputError", "OutputRun", "read_record", "record_beside"]

#: Name of the record in an output folder.
RECORD_NAME = "sonarsim-run.json"

#: Values of the record's ``status``: only ``"complete"`` means every listed file is there.
STATUSES = ("running", "complete", "failed", "interrupted")

# Version of the record's layout, stored under this key (which also marks the file as ours).
_FORMAT_KEY = "sonarsim_run"
_FORMAT = 1

PathLike = str | os.PathLike


class OutputError(SonarsimError):
    """An output path that cannot be written, found before the command does its work.

    Parameters
    ----------
    option : str
        The command-line option that gave the path (e.g. ``"--out"``); may be empty.
    path : str or os.PathLike
        The path as the user gave it (or an output file inside it).
    message : str
        What was found there and what is allowed.
    """

    def __init__(self, option: str, path: PathLike, message: str) -> None:
        self.option = option
        self.path = os.fspath(path)
        where = f"{option} {self.path}" if option else self.path
        super().__init__(f"{where}: {message}")


def record_beside(path: PathLike) -> Path:
    """The record of a command whose main output is the single file ``path``.

    ``fit --out fitted.yaml`` keeps its record in ``fitted.yaml.sonarsim-run.json``, so that
    runs writing different files into one folder keep separate records.
    """
    target = Path(path)
    return target.with_name(f"{target.name}.{RECORD_NAME}")


def read_record(path: PathLike) -> dict[str, Any] | None:
    """The record at ``path``, or None if there is none or the file is not a sonarsim record."""
    try:
        data = regular_file_bytes(path, "run record")  # a pipe in its place is not waited on
        doc = json.loads(data.decode("utf-8")) if data is not None else None
    except (SonarsimError, OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get(_FORMAT_KEY) != _FORMAT or not isinstance(doc.get("files"), list):
        return None
    return doc


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _log(msg: str) -> None:
    print(f"sonarsim: {msg}", file=sys.stderr, flush=True)


def _check_folder(folder: Path, option: str, shown: PathLike) -> None:
    """``folder`` is, or can be created as, a writable folder; else :class:`OutputError`.

    ``shown`` is what the user named: the folder itself, or an output file inside it.
    """
    itself = Path(shown) == folder
    existing = folder
    while not os.path.lexists(existing):
        if existing.parent == existing:
            break
        existing = existing.parent
    try:
        is_dir = existing.is_dir()
    except OSError as exc:  # e.g. a symbolic link loop, a path that is too long
        raise OutputError(option, shown, f"cannot use this path: {exc.strerror or exc}") from None
    if not is_dir:
        if existing == folder and itself:
            raise OutputError(option, shown, "is a file, not a folder (allowed: a folder, or a path where one "
                                             "can be created)")
        what = "this folder" if itself else "its folder"
        raise OutputError(option, shown, f"cannot create {what}: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=temp_prefix("write-probe"), suffix=".tmp", dir=existing)
    except OSError as exc:
        if existing == folder:
            what = "cannot write into this folder" if itself else f"cannot write into its folder {folder}"
        else:
            what = f"cannot create {'this' if itself else 'its'} folder in {existing}"
        raise OutputError(option, shown, f"{what}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(probe)


def _check_file(path: Path, option: str) -> None:
    """An output file's path is free for a file: missing, or not a folder."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except NotADirectoryError:  # a parent is a file; the folder check says so
        return
    except OSError as exc:  # a name too long for the file system, a symbolic link loop
        raise OutputError(option, shown(os.fspath(path)), f"cannot use this path: {exc.strerror or exc}") from None
    if stat.S_ISDIR(mode):
        raise OutputError(option, path, "is a folder; this command writes a file of that name there (allowed: a "
                                        "missing or regular file; move the folder away or choose another path)")


class OutputRun:
    """The files one command writes, checked up front, and the record of the run.

    Constructing it checks everything (see the module notes); ``with run:`` does the work
    between the "running" record and the "complete" one.

    Parameters
    ----------
    record : str or os.PathLike
        Where the record goes: ``OUT / RECORD_NAME`` for a folder of outputs, or
        :func:`record_beside` of a single main output file.
    files : Iterable of path or of (path, str)
        The files the command will write, each alone (named by ``option``) or with the option
        that named it. :meth:`add` plans more once they are known.
    option : str
        Option named in errors about the record's folder and about files given without one.
    command : Sequence[str], optional
        The command line, stored in the record (``null`` there when not given).
    log : callable, optional
        Receives one-line notes (files removed as stale, or kept because changed); default:
        ``sonarsim: ...`` on stderr.
    folder_named : bool
        Whether ``option`` named the record's folder itself (``render --out DIR``) rather than
        files in it (``fit --out FILE``); errors about the folder name what the user gave.

    Raises
    ------
    OutputError
        If an output cannot be written, or a live sonarsim process is writing these outputs.
    """

    def __init__(
        self,
        record: PathLike,
        files: Iterable[PathLike | tuple[PathLike, str]],
        *,
        option: str = "--out",
        command: Sequence[str] | None = None,
        log: Callable[[str], None] | None = None,
        folder_named: bool = False,
    ) -> None:
        self.record = Path(record)
        self.folder = self.record.parent
        self.option = option
        # Not guessed from sys.argv: called from Python (or from pytest), that is someone else's.
        self.command = list(command) if command is not None else None
        self._log = log or _log
        self._files: dict[Path, str] = {}
        self._started = ""
        self._active = False
        # (size, mtime_ns) of each planned file that existed before this run, stored in the
        # records of an unfinished run: a file still as it was then was not written by this
        # run, so a later run must not remove it as this run's.
        self._before: dict[Path, list[int]] = {}
        # Pairs rather than a mapping, so that two options naming one file both arrive here.
        pairs = [(Path(f[0]), f[1]) if isinstance(f, tuple) else (Path(f), option) for f in files]
        # Errors about the record's folder name what the user gave: the folder (``--out DIR``)
        # or, for a single output file (``fit --out FILE``), that file.
        shown: Path = self.folder
        shown_option = option
        if not folder_named:
            shown, shown_option = next(((p, o) for p, o in pairs if self._here(p)), (shown, shown_option))
        _check_folder(self.folder, shown_option, shown)
        _check_file(self.record, shown_option)  # the record is an output too
        for path, opt in pairs:
            self._plan(path, opt)
        self._check_not_in_use()

    def protect(self, inputs: Iterable[tuple[PathLike, str]]) -> "OutputRun":
        """Refuse outputs that are one of the command's input files (``fit --image REC.raw``
        wrote a PNG over the recording), each input given with what it is (``"the recording"``).

        Returns
        -------
        OutputRun
            ``self``, so that it chains after the constructor.

        Raises
        ------
        OutputError
            Naming the option and the path of the output that is an input.
        """
        for source, what in inputs:
            for path, option in [(self.record, self.option), *self._files.items()]:
                with contextlib.suppress(OSError, ValueError):
                    if os.path.samefile(path, source):
                        raise OutputError(option, path, f"is {what} ({os.fspath(source)}); sonarsim never writes over "
                                                        "its inputs: choose another path")
        return self

    @classmethod
    def for_folder(cls, folder: PathLike, names: Iterable[str], *, option: str = "--out",
                   command: Sequence[str] | None = None, log: Callable[[str], None] | None = None) -> "OutputRun":
        """The run of a command that writes the files ``names`` into the folder ``folder``.

        Its record is ``folder / RECORD_NAME``; see the class for the checks and parameters.
        """
        out = Path(folder)
        return cls(out / RECORD_NAME, [out / n for n in names], option=option, command=command, log=log,
                   folder_named=True)

    # ------------------------------------------------------------------ planning

    @property
    def files(self) -> list[Path]:
        """The files this run writes, in the order planned."""
        return list(self._files)

    def _here(self, path: Path) -> bool:
        """Whether ``path`` lies directly in the record's folder."""
        return Path(os.path.abspath(path)).parent == Path(os.path.abspath(self.folder))

    def _plan(self, path: Path, option: str) -> None:
        key = Path(os.path.abspath(path))
        if key in self._files:
            if self._files[key] != option:
                raise OutputError(option, path, f"is also the file of {self._files[key]}; give each output its own "
                                                "path")
            return
        if key == Path(os.path.abspath(self.record)):
            raise OutputError(option, path, f"is the name of sonarsim's run record ({self.record.name}); choose "
                                            "another name")
        if not self._here(path):
            _check_folder(path.parent, option, path)
        _check_file(path, option)
        self._files[key] = option
        with contextlib.suppress(OSError):
            st = os.lstat(key)
            if stat.S_ISREG(st.st_mode):
                self._before[key] = [st.st_size, st.st_mtime_ns]

    def add(self, path: PathLike, option: str | None = None) -> Path:
        """Plan one more file (e.g. a per-component image known only after rendering).

        Inside ``with run:`` the "running" record is rewritten first, so that the file is
        accounted for even if the process dies while writing it.

        Returns
        -------
        Path
            ``path``, to write to.
        """
        target = Path(path)
        self._plan(target, option or self.option)
        if self._active:
            self._write_record("running")
        return target

    def _check_not_in_use(self) -> None:
        previous = read_record(self.record)
        if not previous or previous.get("status") != "running":
            return
        pid = previous.get("pid")
        if (isinstance(pid, int) and pid != os.getpid() and previous.get("host") == socket.gethostname()
                and _pid_alive(pid)):
            raise OutputError(self.option, self.folder, f"sonarsim process {pid} is writing these outputs now "
                              f"({self.record.name} says running); wait for it, or choose another path")

    # ------------------------------------------------------------------ the record

    def _entry(self, path: Path, with_checksum: bool) -> dict[str, Any]:
        folder = Path(os.path.abspath(self.folder))
        entry: dict[str, Any] = {"name": path.name} if path.parent == folder else {"path": str(path)}
        if with_checksum:
            entry["bytes"], entry["sha256"] = file_digest(path)
        elif path in self._before:
            entry["before"] = self._before[path]
        return entry

    def _write_record(self, status: str, extra: Sequence[dict[str, Any]] = (), error: str | None = None) -> None:
        from .. import __version__

        doc: dict[str, Any] = {
            _FORMAT_KEY: _FORMAT,
            "status": status,
            "command": self.command,
            "version": __version__,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "started_utc": self._started,
        }
        if status != "running":
            doc["finished_utc"] = _utc_now()
        if error is not None:
            doc["error"] = error
        # Checksums only in the complete record: a planned file may be half-way between its
        # old and new content until then.
        doc["files"] = [self._entry(p, status == "complete") for p in self._files] + list(extra)
        with atomic_write(self.record, "w") as handle:
            json.dump(doc, handle, indent=1)
            handle.write("\n")

    def _stale_entries(self, previous: dict[str, Any] | None) -> list[dict[str, Any]]:
        """Entries of the previous record naming files in the folder that this run will not write."""
        if previous is None:
            return []
        folder = Path(os.path.abspath(self.folder))
        stale = []
        for entry in previous["files"]:
            name = entry.get("name") if isinstance(entry, dict) else None
            # Plain names only: a record cannot send us outside its folder or onto itself.
            if (not isinstance(name, str) or not name or name in (".", "..") or "/" in name or os.sep in name
                    or name == self.record.name or (folder / name) in self._files):
                continue
            stale.append({k: entry[k] for k in ("name", "bytes", "sha256", "before") if k in entry})
        return stale

    def _remove_stale(self, stale: Sequence[dict[str, Any]]) -> None:
        removed, kept, never = [], [], []
        for entry in stale:
            path = self.folder / entry["name"]
            try:
                if not stat.S_ISREG(os.lstat(path).st_mode):
                    continue
                if "sha256" in entry and (entry.get("bytes"), entry["sha256"]) != file_digest(path):
                    kept.append(entry["name"])  # changed since sonarsim wrote it: the user's now
                    continue
                if "sha256" not in entry and isinstance(entry.get("before"), list):
                    st = os.lstat(path)
                    if entry["before"] == [st.st_size, st.st_mtime_ns]:
                        # An unfinished run planned it but never replaced it: not sonarsim's.
                        never.append(entry["name"])
                        continue
                os.unlink(path)
            except FileNotFoundError:
                continue
            removed.append(entry["name"])
        if removed:
            self._log(f"removed {len(removed)} file(s) of an earlier run in {self.folder} that this run does not "
                      f"write: {', '.join(sorted(removed))}")
        if kept:
            self._log(f"kept {', '.join(sorted(kept))} in {self.folder}: listed by an earlier run but changed since")
        if never:
            self._log(f"kept {', '.join(sorted(never))} in {self.folder}: an unfinished earlier run meant to replace "
                      "it but never did")

    # ------------------------------------------------------------------ the run

    def __enter__(self) -> "OutputRun":
        folders = {self.folder, *(p.parent for p in self._files)}
        for folder in sorted(folders):
            try:
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as exc:  # changed since the check
                raise OutputError(self.option, folder, f"cannot create this folder: {exc.strerror or exc}") from None
        previous = read_record(self.record)
        names = {p.name for p in self._files}
        if previous is not None:
            names |= {e["name"] for e in previous["files"] if isinstance(e, dict) and isinstance(e.get("name"), str)}
        for folder in folders:
            remove_abandoned_temp_files(folder, names)
        self._started = _utc_now()
        stale = self._stale_entries(previous)
        # While stale files are being removed the record still lists them (with the checksums
        # that prove them sonarsim's), so a run killed meanwhile loses track of nothing.
        if stale:
            self._write_record("running", extra=stale)
            self._remove_stale(stale)
        self._write_record("running")
        self._active = True
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        self._active = False
        if exc is None:
            missing = [str(p) for p in self._files if not p.is_file()]
            if missing:
                # A command that plans a file and does not write it is a bug, not bad input.
                self._write_record("failed", error=f"not written: {', '.join(missing)}")
                raise RuntimeError(f"planned outputs were not written: {', '.join(missing)}")
            self._write_record("complete")
            return False
        status = "interrupted" if interrupt_of(exc) is not None else "failed"
        message = str(exc) or type(exc).__name__
        # Best effort: a full disk must not hide the error that stopped the run.
        with contextlib.suppress(OSError):
            self._write_record(status, error=message)
            _add_note(exc, f"{self.record} records the run as {status}")
        return False


def _add_note(exc: BaseException, note: str) -> None:
    """``exc.add_note(note)``, also on Python 3.10 (where only the attribute exists)."""
    if hasattr(exc, "add_note"):
        exc.add_note(note)
    else:  # pragma: no cover - Python 3.10
        exc.__notes__ = [*getattr(exc, "__notes__", []), note]
