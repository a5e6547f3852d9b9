"""Writing simulation results: 8-bit display mapping, PNG and NPZ files.

Every file is written atomically: the data goes to a temporary file in the destination's
directory, which then replaces the destination with :func:`os.replace`. A reader (e.g. a
viewer polling the output folder while the simulator renders) therefore sees either the old
file or the complete new one, never a partial file, and a failed or interrupted write
(exception, Ctrl-C) leaves nothing behind.

Temporary files are named ``.NAME.sonarsim-PID-XXXXXXXX.tmp`` (:func:`temp_prefix`): only a
process killed outright (SIGKILL, power loss) can leave one, and the PID in the name lets a
later run tell it from the file of a run still in progress and remove it
(:func:`remove_abandoned_temp_files`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import re
import stat
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any

import numpy as np
from PIL import Image

# The 8-bit display mapping lives in the image layer (the image types use it); kept here for
# the readers of this module's API.
from ..image.levels import MAPPINGS, to_uint8

__all__ = [
    "CONFIG_KEY",
    "MAPPINGS",
    "atomic_write",
    "npz_payload",
    "read_npz",
    "remove_abandoned_temp_files",
    "temp_prefix",
    "to_uint8",
    "write_npz",
    "write_png",
]

#: Key under which :func:`write_npz` stores the configuration (a 0-d unicode array of JSON).
CONFIG_KEY = "config_json"

PathLike = str | os.PathLike


def _current_umask() -> int:
    """The process umask, read without changing it where the OS allows."""
    # /proc avoids the set-and-restore dance, which would briefly change the umask for
    # other threads.
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)
    os.umask(old)
    return old


#: What marks a temporary file of :func:`atomic_write` (between the name and the PID).
TEMP_MARK = ".sonarsim-"

# .NAME.sonarsim-PID-RANDOM.tmp; NAME may itself contain dots and dashes.
_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.sonarsim-(?P<pid>[0-9]+)-[A-Za-z0-9_]+\.tmp$")

# Temporary files of sonarsim versions before the PID was in the name: .NAME.XXXXXXXX.tmp
# (tempfile.mkstemp's 8 random characters). Removed only for names a run writes, and only
# when old enough that no older sonarsim can still be writing them.
_LEGACY_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}\.tmp$")
_LEGACY_TEMP_AGE_S = 3600.0

# Room for the prefix in a 255-byte file name; a longer destination name is shortened in the
# temporary name only.
_TEMP_NAME_KEEP = 120


def temp_prefix(name: str) -> str:
    """The start of the name of :func:`atomic_write`'s temporary file for destination ``name``.

    Parameters
    ----------
    name : str
        The destination's file name (no folder).

    Returns
    -------
    str
        ``".NAME.sonarsim-PID-"``; :func:`tempfile.mkstemp` appends random characters and
        ``".tmp"``.
    """
    return f".{name[:_TEMP_NAME_KEEP]}{TEMP_MARK}{os.getpid()}-"


def _pid_alive(pid: int) -> bool:
    """Whether a process with this PID exists (on this machine); True when unsure."""
    if os.name != "posix" or pid <= 0:
        # Elsewhere os.kill(pid, 0) would not be a harmless probe.
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # PermissionError: it exists, under another user
        return True
    return True


def remove_abandoned_temp_files(folder: PathLike, names: Iterable[str] = ()) -> list[str]:
    """Remove temporary files that killed sonarsim processes left in ``folder``.

    A file counts as abandoned when its name is ``.NAME.sonarsim-PID-XXXXXXXX.tmp`` and no
    process ``PID`` exists; files of live processes (another render writing into the same
    folder) are left alone. Temporary files of older sonarsim versions (``.NAME.XXXXXXXX.tmp``,
    no PID) are removed only for a NAME in ``names`` and when over an hour old.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder to clean; a missing folder holds nothing to clean.
    names : iterable of str
        Destination names whose old-style temporary files may be removed.

    Returns
    -------
    list of str
        The names of the removed files, sorted.
    """
    wanted = set(names)
    removed = []
    try:
        entries = list(os.scandir(folder))
    except (FileNotFoundError, NotADirectoryError):
        return []
    now = time.time()
    for entry in entries:
        if not (entry.name.startswith(".") and entry.name.endswith(".tmp")):
            continue
        match = _TEMP_RE.match(entry.name)
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            if match:
                if _pid_alive(int(match["pid"])):
                    continue
            else:
                legacy = _LEGACY_TEMP_RE.match(entry.name)
                if not (legacy and legacy["name"] in wanted
                        and now - entry.stat(follow_symlinks=False).st_mtime > _LEGACY_TEMP_AGE_S):
                    continue
            os.unlink(entry.path)
        except FileNotFoundError:  # its process finished (or another run cleaned) meanwhile
            continue
        removed.append(entry.name)
    return sorted(removed)


def _naming(exc: OSError, target: Path) -> OSError:
    """``exc`` about ``target`` instead of a temporary file (the user never named that file)."""
    try:
        return type(exc)(exc.errno, exc.strerror or str(exc), os.fspath(target))
    except TypeError:  # a subclass with another constructor
        return OSError(exc.errno, exc.strerror or str(exc), os.fspath(target))


@contextlib.contextmanager
def atomic_write(path: PathLike, mode: str = "wb", *, fsync: bool = False) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces ``path`` only if the ``with`` block succeeds.

    The temporary file lives in the destination's directory (so :func:`os.replace` is an
    atomic rename on the same file system) and is removed if the block raises; an existing
    ``path`` is then left untouched. The new file gets the permissions of the file it
    replaces, or ``0o666 & ~umask`` for a new file, as a plain ``open`` would give it (the
    temporary file itself is created private). Errors about the temporary file (permission,
    disk full, a folder where the destination should be) name ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination. Its directory must exist.
    mode : {"wb", "w"}
        Binary, or text (UTF-8, ``"\\n"`` newlines).
    fsync : bool
        Flush the data to disk before the rename, so that after a power failure the file is
        either old or new, never empty. Off by default because it costs a disk sync per file,
        which is slow when writing many frames; the rename is atomic for other processes
        either way.

    Yields
    ------
    file object
        Write to it; do not close it.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    target = Path(path)
    directory = target.parent
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=temp_prefix(target.name), suffix=".tmp", dir=directory)
    except OSError as exc:
        raise _naming(exc, target) from None
    try:
        if mode == "w":
            handle: IO[Any] = os.fdopen(fd, "w", encoding="utf-8", newline="\n")
        else:
            handle = os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        os.unlink(tmp_name)
        raise
    try:
        with handle:
            yield handle
            handle.flush()
            if fsync:
                os.fsync(handle.fileno())
        try:
            file_mode = stat.S_IMODE(os.stat(target).st_mode)
        except FileNotFoundError:
            file_mode = 0o666 & ~_current_umask()
        os.chmod(tmp_name, file_mode)
        os.replace(tmp_name, target)
    except BaseException as exc:
        # BaseException so that Ctrl-C (or SIGTERM, which the CLI turns into an exception)
        # during a long write also leaves no temp file.
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        if isinstance(exc, OSError) and exc.filename in (None, tmp_name):
            raise _naming(exc, target) from exc
        raise


def write_png(path: PathLike, image_uint8: np.ndarray) -> None:
    """Write an 8-bit image to a PNG file, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file; its directory must exist. Written as PNG whatever the suffix.
    image_uint8 : np.ndarray, shape (H, W), (H, W, 3) or (H, W, 4), uint8
        Grey-scale, RGB or RGBA image; row 0 is the top of the picture. Use
        :func:`to_uint8` to make one from intensities.

    Raises
    ------
    ValueError
        If the array is not uint8 or has another shape. Checked before any file is touched.
    """
    arr = np.asarray(image_uint8)
    # No silent casting: float images in [0, 1] or int images above 255 would be wrapped or
    # truncated into garbage; make the caller choose a mapping.
    if arr.dtype != np.uint8:
        raise ValueError(f"image_uint8 must have dtype uint8, got {arr.dtype}; see to_uint8")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (3, 4))):
        raise ValueError(
            f"image_uint8 must have shape (H, W), (H, W, 3) or (H, W, 4), got {arr.shape}"
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"image_uint8 must not be empty, got shape {arr.shape}")
    if arr.ndim == 2:  # grey: the fast encoder of the datasets' PNGs (sonarsim.io.png)
        from .png import gray_png_bytes

        data = gray_png_bytes(arr)
        with atomic_write(path, "wb") as handle:
            handle.write(data)
        return
    picture = Image.fromarray(np.ascontiguousarray(arr))
    with atomic_write(path, "wb") as handle:
        picture.save(handle, format="PNG")


def _json_default(value: Any) -> Any:
    """Make numpy values and paths JSON-serialisable (as their plain Python equivalents)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"object of type {type(value).__name__} is not JSON serialisable")


def write_npz(
    path: PathLike, arrays: Mapping[str, np.ndarray], config: Mapping[str, Any]
) -> None:
    """Save arrays and the configuration that produced them to a compressed ``.npz``, atomically.

    The archive is deflated by :func:`sonarsim.io.npz.encode_npz` (zlib level 1, fixed entry dates:
    the same arrays give the same bytes); ``numpy.load`` reads it like any NPZ.

    The configuration is stored as JSON text in a 0-d unicode array under :data:`CONFIG_KEY`
    (``"config_json"``), so the file loads with ``allow_pickle=False``. JSON has no tuples,
    so tuples come back as lists; numpy scalars/arrays and paths are stored as plain numbers,
    lists and strings.

    Parameters
    ----------
    path : str or os.PathLike
        Destination, used exactly as given (unlike :func:`numpy.savez_compressed`, no
        ``.npz`` suffix is appended). Its directory must exist.
    arrays : Mapping[str, array_like]
        Name -> array (any shape, any non-object dtype), e.g. ``{"polar": (n_range_bins,
        n_beams) float32, "fan": (H, W) float32}``.
    config : Mapping[str, Any]
        JSON-serialisable configuration (nested dicts/lists of str, numbers, bools, None).

    Raises
    ------
    ValueError
        For a key that is not a non-empty string or is :data:`CONFIG_KEY`, an object-dtype
        array, or a configuration that cannot be serialised. Checked before any file is
        touched.
    """
    from . import npz

    payload = npz_payload(arrays, config)
    with atomic_write(path, "wb") as handle:
        # Looked up on the module at call time on purpose (tests replace it to simulate failures).
        handle.write(npz.encode_npz(payload))


def npz_payload(arrays: Mapping[str, np.ndarray], config: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The entries of a :func:`write_npz` file: ``arrays`` checked, and the configuration as
    JSON under :data:`CONFIG_KEY` (sorted keys: the same configuration, the same bytes).

    Raises
    ------
    ValueError
        As :func:`write_npz`.
    """
    if not isinstance(config, Mapping):
        raise ValueError(f"config must be a mapping, got {type(config).__name__}")
    payload: dict[str, np.ndarray] = {}
    for name, value in arrays.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"arrays keys must be non-empty strings, got {name!r}")
        if name == CONFIG_KEY:
            raise ValueError(f"arrays must not use the reserved key {CONFIG_KEY!r}")
        arr = np.asarray(value)
        if arr.dtype.hasobject:
            raise ValueError(
                f"arrays[{name!r}] has object dtype, which cannot be stored without pickle"
            )
        payload[name] = arr
    try:
        text = json.dumps(dict(config), sort_keys=True, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"config is not JSON-serialisable: {exc}") from exc
    payload[CONFIG_KEY] = np.array(text, dtype=np.str_)
    return payload


def _check_npz_sizes(archive: Any, path: PathLike) -> None:
    """Refuse an NPZ whose arrays, as their headers declare them, exceed the memory budget.

    An NPZ is a zip of ``.npy`` files; NumPy allocates what a header declares before reading
    the data, and zeros compress a thousandfold, so a 5 MB file can ask for 5 GB or 4 TB.
    """
    from ..core.memory import require

    total = 0.0
    for info in archive.infolist():
        declared = float(info.file_size)  # what the zip says the member unpacks to
        with contextlib.suppress(Exception), archive.open(info) as member:
            version = np.lib.format.read_magic(member)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(member)
            declared = max(declared, float(math.prod(shape)) * dtype.itemsize)
        total += declared
    require(total, "its arrays", "")


def read_npz(path: PathLike) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a file written by :func:`write_npz`.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.npz`` file.

    Returns
    -------
    arrays : dict[str, np.ndarray]
        All stored arrays except the configuration, fully loaded into memory.
    config : dict
        The decoded configuration.

    Raises
    ------
    ValueError
        If the file has no :data:`CONFIG_KEY` entry or it is not a JSON object.
    """
    # allow_pickle=False: an npz from elsewhere must not be able to run code on load.
    with np.load(path, allow_pickle=False) as archive:
        if CONFIG_KEY not in archive.files:
            raise ValueError(
                f"{os.fspath(path)}: no {CONFIG_KEY!r} entry; not written by write_npz"
            )
        _check_npz_sizes(archive.zip, path)
        arrays = {name: archive[name] for name in archive.files if name != CONFIG_KEY}
        text = archive[CONFIG_KEY]
    if text.dtype.kind != "U" or text.ndim != 0:
        raise ValueError(f"{os.fspath(path)}: {CONFIG_KEY!r} is not a JSON text but a {text.dtype} array of shape "
                         f"{text.shape}")
    try:
        config = json.loads(str(text[()]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{os.fspath(path)}: {CONFIG_KEY!r} is not valid JSON: {exc}") from exc
    except RecursionError:  # [[[[... 100,000 deep
        raise ValueError(f"{os.fspath(path)}: {CONFIG_KEY!r} is nested too deeply to be a configuration") from None
    if not isinstance(config, dict):
        raise ValueError(f"{os.fspath(path)}: {CONFIG_KEY!r} is not a JSON object")
    return arrays, config


def file_digest(path: PathLike) -> tuple[int, str]:
    """Size in bytes and sha256 (hex) of a file, read in 1 MiB pieces."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 20):
            digest.update(chunk)
            size += len(chunk)
    return size, digest.hexdigest()


# SonarImage.save_npz writes through this (the image layer does not import io): its hook in
# sonarsim.image.display (sonarsim.plot.hooks installs it too, without loading this module).
from ..image.display import register as _register  # noqa: E402

_register("write_npz", write_npz)
