"""The deflate of every file sonarsim compresses: NPZ entries and PNG image data.

One home for the compressor, its level and its name, so that a dataset's NPZs and PNGs come
from the same encoder and ``dataset.json`` can say which (:data:`ENCODER`).

Why zlib-ng (the ``zlib-ng`` package), measured on a demo frame's arrays (128 x 1288, every
label) and its 1498 x 782 fan on a 2-core machine (``benchmarks/bench_dataset.py`` reports the
parts): at level 2 the NPZ's entries deflate in 5.5 ms instead of libdeflate's 8.0 ms at its
fastest level (11 % larger) and the fan PNG in 1.0 ms instead of 3.6 ms (the same size); ISA-L
was faster still but its streams varied with the process's memory (issue 37, below).

Same bytes: a stream here is a function of the input, the level and the zlib-ng version. Each
call is a fresh one-shot compression (no compressor reused across calls: zlib-ng has had a bug
where a reset compressor's output depended on its past), and a test compresses frames in
processes whose memory was churned and compares. zlib-ng does not promise the same stream on
every processor architecture (its streams may differ between x86-64 and ARM for the same
input; both decode to the same bytes), which is why :data:`ENCODER` names the version and the
machine's architecture: it is part of a dataset's fingerprint, so a folder is resumed only by
the same encoder, and each worker (a Ray node) checks that its own is the dataset's before it
encodes a frame. Python-isal, used before, handed ISA-L a compressor state from ``malloc``
without clearing it, and 1-2 frames in 10 of a dataset came out with a few bytes changed
depending on what the process had done before (issue 37).

Without zlib-ng (a core dependency; only a broken install lacks it) the standard library's
zlib compresses, slower and with other bytes; :data:`ENCODER` says so.
"""

from __future__ import annotations

import platform
import zlib

__all__ = ["DEFLATE_LEVEL", "ENCODER", "crc32", "raw_deflate", "zlib_stream"]

#: The deflate level of NPZ entries and PNG data. zlib-ng's levels 1 (a static Huffman code:
#: about 30 % larger on sonar frames for 30 % less time) to 9; 2 is its fastest with a code made
#: for the data, as small as libdeflate's level 1.
DEFLATE_LEVEL = 2

try:
    from zlib_ng import zlib_ng as _zng
except ImportError:  # pragma: no cover - a core dependency
    _zng = None


def _encoder_name() -> str:
    if _zng is None:  # pragma: no cover
        return f"zlib-{zlib.ZLIB_RUNTIME_VERSION}-level{DEFLATE_LEVEL}"
    return f"zlib-ng-{_zng.ZLIBNG_VERSION}-level{DEFLATE_LEVEL}-{platform.machine().lower() or 'unknown'}"


#: The encoder, its version and level, and the machine's architecture (``zlib-ng-2.3.3-level2-x86_64``):
#: said in a dataset's ``dataset.json``, part of its fingerprint.
ENCODER = _encoder_name()


def raw_deflate(data: bytes | bytearray | memoryview, level: int = DEFLATE_LEVEL) -> bytes:
    """A raw deflate stream of ``data`` (no zlib header: a zip entry's content).

    Parameters
    ----------
    data : bytes-like
    level : int
        1 (fastest) to 9.

    Returns
    -------
    bytes
    """
    if _zng is not None:
        return _zng.compress(data, level, wbits=-15)
    squeeze = zlib.compressobj(level, zlib.DEFLATED, -15)  # pragma: no cover
    return squeeze.compress(data) + squeeze.flush()  # pragma: no cover


def zlib_stream(data: bytes | bytearray | memoryview, level: int = DEFLATE_LEVEL) -> bytes:
    """A zlib stream of ``data`` (header, deflate, Adler-32: a PNG's image data)."""
    if _zng is not None:
        return _zng.compress(data, level)
    return zlib.compress(data, level)  # pragma: no cover


def crc32(data: bytes | bytearray | memoryview, value: int = 0) -> int:
    """The CRC-32 of ``data`` continuing from ``value`` (zip entries, PNG chunks): zlib's
    checksum, computed with zlib-ng's SIMD (a checksum has one answer on any processor)."""
    if _zng is not None:
        return _zng.crc32(data, value)
    return zlib.crc32(data, value)  # pragma: no cover
