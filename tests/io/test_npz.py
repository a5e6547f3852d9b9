"""sonarsim.io.npz: fast, deterministic NPZ archives that zipfile and numpy.load read."""

from __future__ import annotations

import io
import subprocess
import sys
import textwrap
import time
import zipfile
import zlib

import numpy as np
import pytest

from sonarsim.io import npz
from sonarsim.io.npz import encode_npz


def sample() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(4)
    image = rng.exponential(1.0, (97, 13)).astype(np.float32)
    image[:40] = 0.0  # the unlit near range of a sonar image
    return {
        "polar": image,
        "instance": np.where(image > 1.0, 3, -1).astype(np.int32),
        "fortran": np.asfortranarray(rng.random((4, 5))),
        "strided": np.arange(20.0)[::3],
        "names": np.array(["concrete_block", "ground"]),
        "config_json": np.array('{"a": 1}'),  # 0-d unicode, as write_npz stores the configuration
        "empty": np.zeros((0, 3), np.float32),
        "flags": np.array([True, False, True]),
        "scalar": np.float64(2.5),
        "record": np.array([(1, 2.0)], dtype=[("k", "<i4"), ("v", "<f8")]),
    }


def read(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as f:
        return {k: f[k] for k in f.files}


def assert_same(back: dict, arrays: dict) -> None:
    assert list(back) == list(arrays)
    for name, value in arrays.items():
        value = np.asarray(value)
        assert back[name].dtype == value.dtype and back[name].shape == value.shape, name
        np.testing.assert_array_equal(back[name], value, err_msg=name)


def test_numpy_reads_back_every_array_exactly_and_zipfile_checks_every_crc():
    arrays = sample()
    data = encode_npz(arrays)
    assert_same(read(data), arrays)
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        assert archive.testzip() is None  # every entry inflates and matches its CRC-32
        infos = archive.infolist()
    assert [i.filename for i in infos] == [f"{k}.npy" for k in arrays]
    assert {i.date_time for i in infos} == {(1980, 1, 1, 0, 0, 0)}
    assert {i.external_attr >> 16 for i in infos} == {0o100644}
    assert {i.compress_type for i in infos} == {zipfile.ZIP_DEFLATED}


def test_each_entry_holds_what_numpy_itself_writes_for_the_array():
    # The same .npy bytes as numpy.savez (the container differs: dates, deflate), except that a
    # Fortran-ordered array is stored C-ordered (the values read back alike: test above).
    arrays = sample()
    del arrays["fortran"]
    reference = io.BytesIO()
    np.savez(reference, **arrays)
    with zipfile.ZipFile(reference) as ref, zipfile.ZipFile(io.BytesIO(encode_npz(arrays))) as ours:
        for name in ref.namelist():
            assert ours.read(name) == ref.read(name), name


def test_stored_entries_are_not_compressed_and_read_back_alike():
    arrays = sample()
    data = encode_npz(arrays, stored={"polar", "names"})
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        kinds = {i.filename: i.compress_type for i in archive.infolist()}
        assert archive.testzip() is None
    assert kinds["polar.npy"] == kinds["names.npy"] == zipfile.ZIP_STORED
    assert kinds["instance.npy"] == zipfile.ZIP_DEFLATED
    assert_same(read(data), arrays)


def test_the_bytes_depend_on_the_arrays_alone():
    arrays = sample()
    first = encode_npz(arrays)
    time.sleep(2.1)  # zip dates have a 2-second resolution: a clock in the bytes would show
    assert encode_npz(arrays) == first
    changed = dict(arrays, polar=arrays["polar"] + np.float32(1e-3))
    assert encode_npz(changed) != first
    # The image deflates (zeros and speckle), far below its raw size.
    assert len(encode_npz({"polar": arrays["polar"]})) < 0.8 * arrays["polar"].nbytes


def test_archives_beyond_the_plain_zip_limits_are_written_as_zip64(monkeypatch):
    arrays = sample()
    monkeypatch.setattr(npz, "_LIMIT", 600)  # as if the larger entries passed 4 GiB
    data = encode_npz(arrays, stored={"names"})
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        assert archive.testzip() is None
        assert archive.getinfo("names.npy").compress_type == zipfile.ZIP_STORED
    assert_same(read(data), arrays)


def test_object_arrays_are_refused():
    with pytest.raises(ValueError, match="'bad'.*object"):
        encode_npz({"ok": np.zeros(2), "bad": np.array([{}, 1], dtype=object)})


def _streams(data: bytes) -> dict[str, tuple[bytes, bytes]]:
    """Each deflated entry's raw deflate stream and its content."""
    out = {}
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        for info in archive.infolist():
            if info.compress_type == zipfile.ZIP_DEFLATED:
                start = info.header_offset + 30 + len(info.filename)  # local header, no extra field
                out[info.filename] = (data[start:start + info.compress_size], archive.read(info))
    return out


def test_entries_are_the_codecs_streams_that_no_memory_state_can_change():
    # Regression (issue 37): ISA-L's streams for the same content changed in a few bytes with
    # what the process had done before (its compressor state comes from malloc uncleared), so
    # 1-2 frames in 10 of a resumed or multi-worker dataset failed the manifest's SHA-256.
    # Each entry is one fresh zlib-ng compression of its content at the codec's level: the
    # stream a call of zlib-ng's own gives here, after other compressions.
    from zlib_ng import zlib_ng

    from sonarsim.io.codec import DEFLATE_LEVEL

    zlib_ng.compress(np.random.default_rng(3).bytes(200_000), 1, wbits=-15)  # (other work first)
    streams = _streams(encode_npz(sample()))
    assert len(streams) == len(sample())
    for name, (stream, content) in streams.items():
        assert stream == zlib_ng.compress(content, DEFLATE_LEVEL, wbits=-15), name
        assert zlib.decompress(stream, -15) == content, name


_SONAR_FRAME = """
import hashlib, sys
import numpy as np
from sonarsim.io.npz import encode_npz
rng = np.random.default_rng(7)
polar = np.zeros((1288, 128), np.float32)
polar[300:] = rng.exponential(1e-3, (988, 128)).astype(np.float32)
arrays = {"polar": polar, "instance": np.where(polar > 2e-3, 1, -1).astype(np.int32),
          "elevation_deg": np.where(polar > 0, rng.normal(0, 5, polar.shape), np.nan).astype(np.float32)}
seen = set()
keep = []
for k in range(12):
    # Churn the heap between encodes, as a worker's renders do between frames.
    keep = [np.frombuffer(rng.bytes(int(n)), np.uint8).copy() for n in rng.integers(1000, 400000, 30)]
    seen.add(hashlib.sha256(encode_npz(arrays)).hexdigest())
print(" ".join(sorted(seen)))
"""


def test_the_same_frame_gives_the_same_bytes_in_any_process_after_anything():
    # Three processes (other addresses, other heaps), twelve encodes each between allocations.
    runs = [subprocess.run([sys.executable, "-c", textwrap.dedent(_SONAR_FRAME)], capture_output=True, text=True,
                           check=True).stdout.split() for _ in range(3)]
    assert all(len(r) == 1 for r in runs), runs
    assert len({r[0] for r in runs}) == 1, runs
