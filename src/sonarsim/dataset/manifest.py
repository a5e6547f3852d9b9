"""A dataset folder's manifest (``manifest.jsonl``) and identity (``dataset.json``).

``manifest.jsonl`` holds one JSON object per finished frame, one per line::

    {"frame": 3, "time_s": 1.5, "seed": 8431..., "pose": {"position_m": [...], "rpy_deg": [...]},
     "spec_sha256": "...", "files": ["frames/000003.npz"], "bytes": {"frames/000003.npz": 912345},
     "sha256": {"frames/000003.npz": "..."}, "boxes": [...], "check": "..."}

``files`` are relative to the dataset folder; ``bytes`` and ``sha256`` give each file's size and
checksum; ``spec_sha256`` is :func:`spec_digest` of the frame's :class:`FrameSpec` (index, seed,
time, pose, scene), so a line made by another scenario is recognised; ``check`` is the sha256 of
the line's other keys (canonical JSON: sorted keys, no spaces), so a damaged line is recognised
even when it still parses. ``boxes`` (with ground truth): per object whose direct echo (the
renderer's ``object`` instance map) dominates some cells, ``{"id", "name", "polar": [bin_min,
beam_min, bin_max, beam_max], "fan": [row_min, col_min, row_max, col_max], "segmentation",
"area"}`` (inclusive pixel indices; the object's pixels in the image ``coco.json`` names as
COCO's uncompressed RLE, and their count: :mod:`sonarsim.dataset.coco`); ``ghosts`` (with the
``ghosts`` option): the same per object and path signature of its multipath echoes, each with
its ``path``.

While frames are being made, lines are appended in the order frames finish, each written with
one ``write`` and flushed to disk (``fsync``) before the next frame is committed; a run killed
mid-line leaves a torn last line, which does not parse and is dropped. When all frames are done,
the manifest is rewritten in frame order (temporary file and rename), so a finished manifest
is the same whatever the number of workers and the order they finished in.

``dataset.json`` holds the dataset's fingerprint: the sha256 of the options that shape its
files and of every frame's :func:`spec_digest` in order (:class:`Fingerprint`). A later run in
the same folder must have the same fingerprint (or extend the same frames further).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any, Iterator

from ..errors import SonarsimError, check_input_file, key_text
from ..io.output import file_digest
from .scenario import FrameSpec

__all__ = [
    "INFO_NAME",
    "MANIFEST_NAME",
    "Fingerprint",
    "ManifestAppender",
    "ManifestLines",
    "canonical_json",
    "frame_header",
    "read_manifest",
    "rewrite_manifest",
    "scan_manifest",
    "seal_record",
    "spec_digest",
    "verify_record",
]

#: The manifest's name in a dataset folder.
MANIFEST_NAME = "manifest.jsonl"
#: The dataset's identity (fingerprint, options, frame count) in a dataset folder.
INFO_NAME = "dataset.json"
#: Layout version of the files, part of the fingerprint.
DATASET_FORMAT = 1


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no spaces: equal values give equal text (and digests)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def spec_digest(spec: FrameSpec) -> str:
    """sha256 (hex) of everything that makes frame ``spec.index``: index, seed, time, pose, scene.

    The pose enters as its 4 x 4 matrix, exactly (JSON writes floats so that they read back
    bit for bit).
    """
    doc = {"index": spec.index, "seed": spec.seed, "time_s": spec.time_s,
           "pose": spec.pose.matrix().tolist(), "scene_key": spec.scene_key}
    return hashlib.sha256(canonical_json(doc).encode()).hexdigest()


class Fingerprint:
    """The running sha256 of a dataset's options and its frames' spec digests, in frame order.

    ``Fingerprint(options)``, then :meth:`add` each frame's :func:`spec_digest` in order;
    :meth:`at` gives the fingerprint of the first ``n`` frames (so that a dataset asked for
    more frames can be recognised as the same dataset, extended).
    """

    def __init__(self, options: Mapping[str, Any]) -> None:
        self._hash = hashlib.sha256(canonical_json({"format": DATASET_FORMAT, "options": dict(options)}).encode())
        self._at: list[str] = [self._hash.hexdigest()]

    def add(self, digest: str) -> None:
        """Append the next frame's spec digest."""
        self._hash.update(digest.encode())
        self._at.append(self._hash.hexdigest())

    def at(self, n: int) -> str | None:
        """Fingerprint of the first ``n`` frames; ``None`` beyond the frames added."""
        return self._at[n] if 0 <= n < len(self._at) else None

    @property
    def value(self) -> str:
        """Fingerprint of every frame added."""
        return self._at[-1]


def seal_record(record: Mapping[str, Any]) -> dict[str, Any]:
    """``record`` with its ``check``: the sha256 of its canonical JSON (without ``check``)."""
    body = {k: v for k, v in record.items() if k != "check"}
    return {**body, "check": hashlib.sha256(canonical_json(body).encode()).hexdigest()}


def frame_header(spec: FrameSpec, files: Sequence[str]) -> dict[str, Any]:
    """The part of frame ``spec.index``'s manifest line that follows from its spec and options:
    ``frame``, ``time_s``, ``seed``, ``pose`` (``position_m``, ``rpy_deg``), ``spec_sha256``,
    ``files``."""
    return {
        "frame": spec.index,
        "time_s": spec.time_s,
        "seed": spec.seed,
        "pose": {"position_m": list(spec.pose.position_m), "rpy_deg": list(spec.pose.rpy_deg)},
        "spec_sha256": spec_digest(spec),
        "files": list(files),
    }


def verify_record(record: Any, folder: Path, expected: Mapping[str, Any] | None) -> bool:
    """Whether a manifest line can be trusted: sealed, this frame's, its files intact.

    Parameters
    ----------
    record : Any
        The parsed line.
    folder : Path
        The dataset folder its ``files`` are relative to.
    expected : mapping or None
        :func:`frame_header` of the frame this run would make at ``record["frame"]`` (its
        files under this run's options); ``None``: the frame is not part of this dataset.

    Notes
    -----
    Every file is read in full and hashed: a manifest is never trusted on its own word.
    The seal (``check``) detects damage to the other keys (``boxes``); it is no signature.
    """
    if not isinstance(record, dict) or expected is None:
        return False
    try:
        if seal_record(record)["check"] != record.get("check"):
            return False
    except (TypeError, ValueError):  # NaN or other values canonical JSON refuses
        return False
    if any(record.get(key) != value for key, value in expected.items()):
        return False
    sizes, sums = record.get("bytes"), record.get("sha256")
    if not isinstance(sizes, dict) or not isinstance(sums, dict):
        return False
    for name in expected["files"]:
        try:
            if file_digest(folder / name) != (sizes.get(name), sums.get(name)):
                return False
        except OSError:
            return False
    return True


def read_manifest(path: Path) -> list[Any]:
    """The parsed lines of a manifest; lines that are not JSON (a torn last line) are dropped.

    A missing manifest has no lines; one that is not a regular file is refused (SonarsimError).
    (:func:`scan_manifest` reads it as a stream, with where each line lies.)
    """
    return [parsed for _, _, parsed in scan_manifest(path) if parsed is not None]


def scan_manifest(path: Path) -> Iterator[tuple[int, int, Any]]:
    """Each line of a manifest as ``(offset, length, parsed)``, read as a stream (a manifest of
    100,000 frames is half a GB: never held whole); ``parsed`` is None for a line that is not
    JSON (a torn last line). A missing manifest has no lines; one that is not a regular file
    is refused (SonarsimError)."""
    if not os.path.lexists(path):
        return
    check_input_file(path, "dataset manifest")
    offset = 0
    try:
        with open(path, "rb") as handle:
            for line in handle:
                length = len(line)
                if line.strip():
                    try:
                        parsed = json.loads(line)
                    except (UnicodeDecodeError, ValueError):
                        parsed = None
                    yield offset, length, parsed
                offset += length
    except OSError as exc:
        raise SonarsimError(f"{key_text(os.fspath(path))}: cannot read the dataset manifest: "
                            f"{exc.strerror or exc}") from None


class ManifestLines:
    """Where each frame's line lies in a manifest file (frame -> offset and length), so that
    a run holds a few integers per frame instead of its records (60 kB a frame as Python
    objects: 6 GB for 100,000 frames), and reads a record back when it needs it.

    Parameters
    ----------
    path : Path
        The manifest file the offsets are into.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.at: dict[int, tuple[int, int]] = {}

    def __contains__(self, k: int) -> bool:
        return k in self.at

    def __len__(self) -> int:
        return len(self.at)

    def record(self, k: int) -> dict[str, Any]:
        """Frame ``k``'s record, without its ``check``."""
        return next(self.records([k]))

    def records(self, frames: Iterable[int]) -> Iterator[dict[str, Any]]:
        """The records of ``frames``, in that order, read one at a time (without ``check``)."""
        with open(self.path, "rb") as handle:
            for k in frames:
                offset, length = self.at[k]
                handle.seek(offset)
                record = json.loads(handle.read(length))
                record.pop("check", None)
                yield record


def rewrite_manifest(path: Path, lines: ManifestLines, frames: Iterable[int]) -> ManifestLines:
    """Replace the manifest at ``path`` by the lines of ``frames`` (in that order) from
    ``lines``, each sealed anew in canonical form, atomically and durably, a line at a time.

    Returns
    -------
    ManifestLines
        Where each of those frames' lines lies in the new file.
    """
    from ..io.output import atomic_write

    frames = list(frames)
    out = ManifestLines(path)
    offset = 0
    with atomic_write(path, "wb", fsync=True) as handle:
        for k, record in zip(frames, lines.records(frames)):
            data = (canonical_json(seal_record(record)) + "\n").encode()
            handle.write(data)
            out.at[k] = (offset, len(data))
            offset += len(data)
    return out


class ManifestAppender:
    """Append sealed records to a manifest, one durable line per frame.

    Each record is written with a single ``write`` of the whole line and flushed, so that a
    kill leaves at most one torn last line (:func:`read_manifest` drops it). Lines are not
    ``fsync``-ed one by one (on a slow disk that would cost more than the frame): a line that
    a power cut tears or loses fails its check, or is missing, on resume, and its frame is
    made again, as any line that does not verify.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._handle: IO[bytes] | None = open(path, "ab")

    def append(self, record: Mapping[str, Any]) -> tuple[int, int]:
        """Write one record (sealed with :func:`seal_record`) as a line; where it lies in the
        file (offset and length, bytes)."""
        assert self._handle is not None, "the manifest is closed"
        data = (canonical_json(seal_record(record)) + "\n").encode()
        offset = self._handle.seek(0, 2)  # (append mode writes at the end whatever the position)
        self._handle.write(data)
        self._handle.flush()
        return offset, len(data)

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None

    def __enter__(self) -> ManifestAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_manifest(path: Path, records: Iterable[Mapping[str, Any]]) -> None:
    """Replace the manifest with ``records`` (sealed), atomically and durably."""
    from ..io.output import atomic_write

    with atomic_write(path, "w", fsync=True) as handle:
        for record in records:
            handle.write(canonical_json(seal_record(record)) + "\n")
