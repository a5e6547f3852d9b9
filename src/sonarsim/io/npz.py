"""NPZ files encoded deterministically (what :func:`numpy.load` reads).

An NPZ is a zip archive of ``.npy`` files. ``numpy.savez_compressed`` deflates with zlib at
level 6 and stamps each entry with the current time, so two runs never write the same bytes.
Here each entry is deflated by :mod:`sonarsim.io.codec` (zlib-ng; why, and what "the same
bytes" rests on, is said there) and the zip container is laid out directly, with a fixed date,
so the bytes depend on the arrays alone. :mod:`zipfile` has no way to take an entry already
deflated, hence the few lines of container below; the tests read every file back with
:mod:`zipfile` (CRC checked) and :func:`numpy.load`.

Archives beyond the plain zip format's limits (4 GiB entries, 65,535 entries) are written by
:mod:`zipfile` (zip64) instead: slower, equally valid.
"""

from __future__ import annotations

import io
import struct
import zipfile
from collections.abc import Mapping

import numpy as np

from .codec import DEFLATE_LEVEL, crc32 as _crc32, raw_deflate

__all__ = ["DEFLATE_LEVEL", "encode_npz"]

_STORED, _DEFLATED = 0, 8
_VERSION = 20  # "2.0": deflate, no zip64
_MADE_BY = (3 << 8) | _VERSION  # Unix, so that the external attributes are file modes
_DOS_DATE = (0 << 9) | (1 << 5) | 1  # 1980-01-01, the earliest a zip can hold
_DOS_TIME = 0
_MODE = 0o100644 << 16  # a regular file, rw-r--r--
_LIMIT = 0xFFFFFFFF


def _npy_header(array: np.ndarray) -> bytes:
    """The ``.npy`` header of a C-contiguous array (format 1.0, or 2.0 when it needs it)."""
    buffer = io.BytesIO()
    info = np.lib.format.header_data_from_array_1_0(array)
    try:
        np.lib.format.write_array_header_1_0(buffer, info)
    except ValueError:  # a header beyond 64 KiB (thousands of fields): format 2.0
        buffer = io.BytesIO()
        np.lib.format.write_array_header_2_0(buffer, info)
    return buffer.getvalue()


def _raw(array: np.ndarray) -> memoryview:
    """The bytes of a C-contiguous array, without a copy (any dtype, any number of dimensions)."""
    return memoryview(array.reshape(-1).view(np.uint8))


def _entries(arrays: Mapping[str, np.ndarray]) -> list[tuple[bytes, bytes, np.ndarray]]:
    out = []
    for name, value in arrays.items():
        array = np.asarray(value)
        if not array.flags.c_contiguous:  # (not ascontiguousarray: it makes 0-d arrays 1-d)
            array = array.copy(order="C")
        if array.dtype.hasobject:
            raise ValueError(f"arrays[{name!r}] has object dtype, which cannot be stored without pickle")
        out.append((f"{name}.npy".encode(), _npy_header(array), array))
    return out


def encode_npz(arrays: Mapping[str, np.ndarray], stored: frozenset[str] | set[str] = frozenset(),
               level: int = DEFLATE_LEVEL) -> bytes:
    """An NPZ archive of ``arrays``, as bytes that depend on the arrays alone.

    Parameters
    ----------
    arrays : mapping of str to array_like
        Entry name (without ``.npy``) to array, any shape, any non-object dtype; entries in
        mapping order. Non-contiguous arrays are stored C-ordered.
    stored : set of str
        Names stored without compression (data that deflate cannot shrink, such as float
        coordinates: they would cost time for nothing).
    level : int
        The deflate level (1-9) of the other entries (:data:`sonarsim.io.codec.DEFLATE_LEVEL`).

    Returns
    -------
    bytes
        A zip archive (entries dated 1980-01-01, mode 0644) that ``numpy.load`` reads.

    Raises
    ------
    ValueError
        An object-dtype array.
    """
    entries = _entries(arrays)
    if len(entries) >= 0xFFFF or any(len(h) + a.nbytes >= _LIMIT for _, h, a in entries):
        return _encode_zip64(entries, stored, level)
    parts: list[bytes | memoryview] = []
    central: list[bytes] = []
    offset = 0
    for name, header, array in entries:
        data = _raw(array)
        crc = _crc32(data, _crc32(header))
        size = len(header) + len(data)
        if name[:-4].decode() in stored:
            method, body = _STORED, [header, data]
        else:
            method, body = _DEFLATED, [_deflate(header, data, level)]
        packed = sum(len(b) for b in body)
        if offset + packed + 30 + len(name) >= _LIMIT:
            return _encode_zip64(entries, stored, level)
        local = struct.pack("<IHHHHHIIIHH", 0x04034B50, _VERSION, 0, method, _DOS_TIME, _DOS_DATE, crc, packed,
                            size, len(name), 0)
        central.append(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, _MADE_BY, _VERSION, 0, method, _DOS_TIME,
                                   _DOS_DATE, crc, packed, size, len(name), 0, 0, 0, 0, _MODE, offset) + name)
        parts += [local, name, *body]
        offset += len(local) + len(name) + packed
    directory = b"".join(central)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(central), len(central), len(directory), offset, 0)
    return b"".join(parts) + directory + end


def _deflate(header: bytes, data: memoryview, level: int) -> bytes:
    """A raw deflate stream of ``header`` then ``data`` (one call: one fresh compressor)."""
    return raw_deflate(header + data, level)


def _encode_zip64(entries: list[tuple[bytes, bytes, np.ndarray]], stored: frozenset[str] | set[str],
                  level: int) -> bytes:
    """Archives beyond the plain format's limits, through :mod:`zipfile` (zip64, zlib)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", allowZip64=True) as archive:
        for name, header, array in entries:
            info = zipfile.ZipInfo(name.decode(), date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = _MODE
            if name[:-4].decode() in stored:
                info.compress_type = zipfile.ZIP_STORED
            else:
                info.compress_type = zipfile.ZIP_DEFLATED
                info._compresslevel = max(1, min(level, 9))  # what ZipFile.open(str) sets; a ZipInfo must be told
            with archive.open(info, "w", force_zip64=True) as handle:
                handle.write(header)
                handle.write(_raw(array))
    return buffer.getvalue()
