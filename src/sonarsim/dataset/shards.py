"""WebDataset shards of a dataset folder: tar files of whole frames, for streaming large sets.

With ``shards=N`` (``sonarsim dataset --shards N``) :func:`~sonarsim.dataset.generate` packs
the frames into ``shards/000000.tar``, ``shards/000001.tar``, ... of ``N`` frames each (the last
one may hold fewer), each written as soon as its last frame is done, and lists them in
``shards.jsonl``. A shard holds, per frame in frame order, the frame's files under the frame's
key (``000123.npz``, ``000123.fan.png``, ``000123.fan.txt``, ...: the key, a dot, the file's
kind) and ``000123.json``, the frame's manifest record (pose, time, seed, boxes with their
masks, the files' sizes and checksums). Those are the WebDataset conventions: the ``webdataset``
library (``webdataset.WebDataset("DIR/shards/{000000..000009}.tar")``) and Hugging Face
``datasets`` (``load_dataset("webdataset", data_files=...)``) read them as they are, one sample
per frame. Why tar shards and not Parquet, HDF5 or Zarr: ``benchmarks/bench_shards.py``
measures their reading in a PyTorch DataLoader; tar shards also cost the writer nothing but the
copy (the frame's bytes as they are, no second encoding) and stream sequentially.

Same bytes: every member is dated 0 (1970-01-01), owned by 0:0 without names, mode 0644, in
frame order then manifest order, so a shard is a function of its frames' files alone, whatever
the number of workers or how often the run was resumed.

Resuming: ``shards.jsonl`` holds one line per shard written (its name, first and last frame,
size, sha256, and the digest of its frames' files' checksums). A later run keeps a shard whose
line verifies (the file's size and sha256, read in full, and its frames' checksums those of
the manifest) and writes the others; a shard of a different size, a torn line, a changed frame
are redone. When the run ends the list is rewritten in order and files in ``shards/`` that it
does not name (another shard size) are removed.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import tarfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from ..errors import ConfigError, SonarsimError, shown

__all__ = ["SHARDS_DIR", "SHARD_INDEX", "ShardWriter", "check_shard_frames", "member_name", "remove_shards", "shard_urls", "write_shard"]

#: The shards' folder and their list, in a dataset folder.
SHARDS_DIR = "shards"
SHARD_INDEX = "shards.jsonl"
# Frames per shard allowed: a shard of one frame is a tar per frame (no gain); beyond 100,000
# a shard is tens of GB, past what a DataLoader worker should hold one file open for.
_FRAMES_RANGE = (1, 100_000)


def check_shard_frames(value: Any, key: str = "shards") -> int:
    """``value`` as frames per shard, or a :class:`ConfigError` naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, int) or not _FRAMES_RANGE[0] <= value <= _FRAMES_RANGE[1]:
        raise ConfigError(key, f"frames per shard: an integer {_FRAMES_RANGE[0]}-{_FRAMES_RANGE[1]}, got {shown(value)}")
    return value


def member_name(file_name: str) -> str:
    """A frame file's name in a shard: ``frames/000123_fan.png`` -> ``000123.fan.png``
    (WebDataset's key, the part before the first dot, is the frame number)."""
    base = file_name.rsplit("/", 1)[-1]
    stem, _, ext = base.partition(".")
    key, _, kind = stem.partition("_")
    return f"{key}.{kind}.{ext}" if kind else f"{key}.{ext}"


def _key(record: Mapping[str, Any]) -> str:
    return member_name(record["files"][0]).split(".", 1)[0]


def _member_line(record: Mapping[str, Any]) -> bytes:
    """A frame's part of a shard's members digest: its number and its files' checksums."""
    return (f"{int(record['frame'])}:" + ",".join(record["sha256"][f] for f in record["files"]) + "\n").encode()


def _members_digest(records: Iterable[Mapping[str, Any]]) -> str:
    """A digest of the frames' files' checksums (what a shard was made from), read as a stream."""
    sha = hashlib.sha256()
    for record in records:
        sha.update(_member_line(record))
    return sha.hexdigest()


class _Hashing(io.RawIOBase):
    """A write-only stream that hashes and counts what passes to ``target``."""

    def __init__(self, target: Any) -> None:
        self.target, self.sha, self.size = target, hashlib.sha256(), 0

    def writable(self) -> bool:
        return True

    def tell(self) -> int:  # (tarfile asks where it starts)
        return self.size

    def write(self, data: Any) -> int:
        self.target.write(data)
        self.sha.update(data)
        self.size += len(data)
        return len(data)


def _info(name: str, size: int) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.size, info.mtime, info.mode, info.uid, info.gid, info.uname, info.gname = size, 0, 0o644, 0, 0, "", ""
    return info


def write_shard(out: Path, name: str, records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Write shard ``name`` (relative to ``out``) of the frames of ``records`` (manifest lines,
    in frame order, read one at a time: a shard of 100,000 frames is never held) from their files
    in ``out``; atomically (temporary file, then rename).

    Returns
    -------
    dict
        Its ``shards.jsonl`` line: ``shard``, ``frames`` [first, last], ``bytes``, ``sha256``,
        ``members_sha256``.

    Raises
    ------
    SonarsimError
        A frame file that cannot be read or that is not what its manifest line says, or a
        shard that cannot be written (naming the file).
    """
    from ..io.output import atomic_write
    from .manifest import canonical_json

    path = out / name
    members, frames = hashlib.sha256(), []
    try:
        path.parent.mkdir(exist_ok=True)
        with atomic_write(path, "wb") as handle:
            sink = _Hashing(handle)
            with tarfile.open(fileobj=sink, mode="w", format=tarfile.USTAR_FORMAT) as tar:
                for record in records:
                    members.update(_member_line(record))
                    frames = [frames[0] if frames else int(record["frame"]), int(record["frame"])]
                    for file_name in record["files"]:
                        data = (out / file_name).read_bytes()
                        if hashlib.sha256(data).hexdigest() != record["sha256"][file_name]:
                            raise SonarsimError(f"{out / file_name}: changed since frame {record['frame']} was "
                                                "written (its sha256 is not the manifest's); run again to redo it")
                        tar.addfile(_info(member_name(file_name), len(data)), io.BytesIO(data))
                    meta = canonical_json({k: v for k, v in record.items() if k != "check"}).encode()
                    tar.addfile(_info(f"{_key(record)}.json", len(meta)), io.BytesIO(meta))
    except OSError as exc:
        raise SonarsimError(f"{getattr(exc, 'filename', None) or path}: cannot write shard {name}: "
                            f"{exc.strerror or exc} (no partial shard is left; run again to resume)") from None
    return {"shard": name, "frames": frames, "bytes": sink.size, "sha256": sink.sha.hexdigest(),
            "members_sha256": members.hexdigest()}


class ShardWriter:
    """Shards written as their frames finish (:func:`~sonarsim.dataset.generate`).

    Parameters
    ----------
    out : Path
        The dataset folder.
    n_frames : int
    size : int
        Frames per shard.
    lines : ManifestLines
        Where the frames done so far lie in the manifest (kept from an earlier run, and those
        this run appends: the caller adds each before :meth:`add`). Records are read back from
        the manifest when a shard is written, not held.
    """

    def __init__(self, out: Path, n_frames: int, size: int, lines: Any) -> None:
        self.out, self.n, self.size = out, n_frames, check_shard_frames(size)
        self.width = max(6, len(str(max(0, (n_frames - 1) // size))))
        self.lines_of = lines
        self.lines: dict[int, dict[str, Any]] = {}
        # Frames done per shard (a count, not a scan of the shard's frames at each frame).
        self.done: dict[int, int] = {}
        for k in lines.at:
            self.done[k // self.size] = self.done.get(k // self.size, 0) + 1
        if (out / SHARDS_DIR).is_dir():
            from ..io.output import remove_abandoned_temp_files

            remove_abandoned_temp_files(out / SHARDS_DIR)  # a killed run's half-written shard
        for line in self._read_index():
            s = self._verified(line)
            if s is not None:
                self.lines[s] = line
        self._rewrite_index()  # only verified lines stay

    def name(self, s: int) -> str:
        """Shard ``s``'s path relative to the dataset folder."""
        return f"{SHARDS_DIR}/{s:0{self.width}d}.tar"

    def frames_of(self, s: int) -> range:
        return range(s * self.size, min(self.n, (s + 1) * self.size))

    def _read_index(self) -> list[Any]:
        path = self.out / SHARD_INDEX
        if not path.exists():
            return []
        try:
            text_lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError as exc:
            raise SonarsimError(f"{path}: cannot read the shards' list: {exc.strerror or exc}") from None
        lines = []
        for text in text_lines:
            try:
                lines.append(json.loads(text))
            except ValueError:  # a torn or damaged line: its shard is redone
                continue
        return lines

    def _verified(self, line: Any) -> int | None:
        """The shard number of an index line that holds, else None."""
        from ..io.output import file_digest

        if not isinstance(line, dict) or not isinstance(line.get("frames"), list) or len(line["frames"]) != 2:
            return None
        first = line["frames"][0]
        if not isinstance(first, int) or first % self.size:
            return None
        s = first // self.size
        frames = self.frames_of(s)
        if not frames or line.get("shard") != self.name(s) or line["frames"] != [frames[0], frames[-1]]:
            return None
        if any(k not in self.lines_of for k in frames):
            return None
        if line.get("members_sha256") != _members_digest(self.lines_of.records(frames)):
            return None
        path = self.out / line["shard"]
        try:
            if not path.is_file() or path.stat().st_size != line.get("bytes"):
                return None
            size, digest = file_digest(path)
        except OSError:
            return None
        return s if (size, digest) == (line.get("bytes"), line.get("sha256")) else None

    def add(self, k: int) -> None:
        """Frame ``k`` is done (its line in the manifest): write its shard if that completes it."""
        s = k // self.size
        self.done[s] = self.done.get(s, 0) + 1
        if s not in self.lines and self.done[s] >= len(self.frames_of(s)):
            self._write(s)

    def _write(self, s: int) -> None:
        line = write_shard(self.out, self.name(s), self.lines_of.records(self.frames_of(s)))
        self.lines[s] = line
        # One write per shard, after its file is complete: a kill mid-line tears the last line,
        # which a later run drops (and redoes that shard).
        with open(self.out / SHARD_INDEX, "a", encoding="utf-8") as index:
            index.write(json.dumps(line, sort_keys=True) + "\n")

    def finish(self) -> list[str]:
        """Write the shards not yet written (all frames done), rewrite the list in order,
        remove files of ``shards/`` it does not name; the shards' names in order."""
        for s in range((self.n + self.size - 1) // self.size):
            if s not in self.lines:
                self._write(s)
        self._rewrite_index()
        names = [self.lines[s]["shard"] for s in sorted(self.lines)]
        keep = {n.rsplit("/", 1)[-1] for n in names}
        for entry in (self.out / SHARDS_DIR).iterdir():
            if entry.is_file() and entry.suffix == ".tar" and entry.name not in keep:
                entry.unlink()
        return names

    def _rewrite_index(self) -> None:
        from ..io.output import atomic_write

        with atomic_write(self.out / SHARD_INDEX, "w") as handle:
            for s in sorted(self.lines):
                handle.write(json.dumps(self.lines[s], sort_keys=True) + "\n")


def remove_shards(out: Path) -> bool:
    """Remove the shards of an earlier run (``shards.jsonl`` first, then ``shards/*.tar``): a
    run without ``shards`` leaves none that would no longer cover the frames. Whether there were."""
    index, folder = out / SHARD_INDEX, out / SHARDS_DIR
    found = index.exists() or folder.is_dir()
    index.unlink(missing_ok=True)
    if folder.is_dir():
        for entry in folder.iterdir():
            if entry.is_file() and (entry.suffix == ".tar" or entry.name.endswith(".tmp")):
                entry.unlink()
        if not any(folder.iterdir()):
            folder.rmdir()
    return found


def shard_urls(folder: str | os.PathLike) -> list[str]:
    """The shards of a finished dataset folder, in order, as paths the ``webdataset`` library
    and Hugging Face ``datasets`` take (from ``shards.jsonl``).

    Raises
    ------
    SonarsimError
        A folder without shards (made without ``--shards``), naming the file.
    """
    folder = Path(folder)
    path = folder / SHARD_INDEX
    try:
        lines = [json.loads(t) for t in path.read_text(encoding="utf-8").splitlines() if t.strip()]
    except FileNotFoundError:
        raise SonarsimError(f"{path}: no such file: this dataset has no shards (make it with --shards N)") from None
    except (OSError, ValueError) as exc:
        raise SonarsimError(f"{path}: cannot read: {exc}") from None
    try:
        ordered = sorted(lines, key=lambda line: int(line["frames"][0]))
        return [str(folder / str(line["shard"])) for line in ordered]
    except (TypeError, KeyError, IndexError, ValueError):
        raise SonarsimError(f"{path}: not a list of shards (each line a JSON object with 'shard' and 'frames'); "
                            "make the dataset again with --shards N to rewrite it") from None
