"""Tests of sonarsim.io.output: display mapping and atomic PNG/NPZ writing."""

from __future__ import annotations

import os
import re
import stat
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sonarsim.io import output
from sonarsim.io import npz
from sonarsim.io.output import atomic_write, read_npz, to_uint8, write_npz, write_png

# --------------------------------------------------------------------------- to_uint8


def test_linear_mapping_hand_computed() -> None:
    img = np.array([0.0, 0.25, 0.5, 1.0, 2.0, -1.0], np.float32)
    # 255 * [0, 0.25, 0.5, 1, clip 2 -> 1, clip -1 -> 0], rounded half up: 63.75 -> 64,
    # 127.5 -> 128.
    np.testing.assert_array_equal(
        to_uint8(img, "linear", reference=1.0), [0, 64, 128, 255, 255, 0]
    )
    # Default reference = image maximum (2.0).
    np.testing.assert_array_equal(to_uint8(img, "linear"), [0, 32, 64, 128, 255, 0])
    # +10 dB gain multiplies the intensity by 10: 0.02 -> 0.2 -> 51; 0.05 -> 0.5 -> 128.
    np.testing.assert_array_equal(
        to_uint8(np.array([0.02, 0.05, 0.2]), "linear", gain_db=10.0, reference=1.0),
        [51, 128, 255],
    )


def test_db_mapping_hand_computed() -> None:
    img = np.array([1.0, 1e-3, 10**-1.5, 1e-6, 1e-7, 0.0, -1.0, 2.0])
    # 10*log10: 0, -30, -15, -60, -70, -inf, -inf, +3 dB; window [-60, 0] -> [0, 1]:
    # 1, 0.5, 0.75, 0, 0, 0, 0, 1 -> 255, 128 (127.5 up), 191 (191.25), 0, 0, 0, 0, 255.
    np.testing.assert_array_equal(
        to_uint8(img, "db", reference=1.0), [255, 128, 191, 0, 0, 0, 0, 255]
    )
    # Gain and a 40 dB window: 1e-3 * 10**(-0.6) is -36 dB, +6 dB gain -> -30 dB -> 10/40
    # -> 63.75 -> 64; 1e-2 -> -20 + 6 = -14 dB -> 26/40 -> 165.75 -> 166.
    np.testing.assert_array_equal(
        to_uint8(np.array([10**-3.6, 1e-2, 1e-5]), "db", gain_db=6.0, dynamic_range_db=40.0,
                 reference=1.0),
        [64, 166, 0],
    )


def test_default_mapping_is_db_with_max_reference() -> None:
    img = np.array([[4.0, 4e-3], [0.0, 4e-6]])
    np.testing.assert_array_equal(to_uint8(img), [[255, 128], [0, 0]])


def test_gain_means_the_same_in_both_mappings() -> None:
    # A pixel saturates in "linear" when it reaches 0 dB in "db" (away from the last
    # rounding step): +3.0103 dB doubles the intensity in both.
    img = np.array([0.3, 0.44, 0.55, 0.9])
    lin = to_uint8(img, "linear", gain_db=3.0103, reference=1.0)  # x2
    db = to_uint8(img, "db", gain_db=3.0103, reference=1.0)
    np.testing.assert_array_equal(lin == 255, db == 255)
    np.testing.assert_array_equal(lin == 255, [False, False, True, True])


@pytest.mark.parametrize("mapping", ["db", "linear"])
def test_all_zero_image_gives_zeros_without_warnings(mapping: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = to_uint8(np.zeros((4, 5), np.float32), mapping)
        out_nan = to_uint8(np.array([np.nan, 0.0, -2.0]), mapping)
        out_mixed = to_uint8(np.array([np.nan, 0.0, 1.0, np.inf]), mapping)
    assert out.dtype == np.uint8 and out.shape == (4, 5)
    assert not out.any()
    np.testing.assert_array_equal(out_nan, 0)
    np.testing.assert_array_equal(out_mixed, [0, 0, 255, 255])


def test_mask_zeroes_outside_and_sets_reference() -> None:
    img = np.array([[1.0, 100.0], [0.5, 0.25]])
    mask = np.array([[True, False], [True, True]])
    out = to_uint8(img, "linear", mask=mask)
    # Reference is the maximum inside the mask (1.0), not the masked-out 100.
    np.testing.assert_array_equal(out, [[255, 0], [128, 64]])
    with pytest.raises(ValueError, match="mask"):
        to_uint8(img, mask=np.ones((3, 2), bool))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mapping": "log"}, "mapping.*'db'.*'linear'"),
        ({"dynamic_range_db": 0.0}, "dynamic_range_db"),
        ({"reference": 0.0}, "reference"),
        ({"reference": -1.0}, "reference"),
        ({"gain_db": float("inf")}, "gain_db"),
    ],
)
def test_to_uint8_rejects_bad_arguments(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        to_uint8(np.ones((2, 2)), **kwargs)


# --------------------------------------------------------------------------- PNG


def test_png_round_trip(tmp_path: Path) -> None:
    img = (np.arange(6 * 7).reshape(6, 7) * 5).astype(np.uint8)
    target = tmp_path / "frame.png"
    write_png(target, img)
    with Image.open(target) as back:
        assert back.format == "PNG"
        np.testing.assert_array_equal(np.asarray(back), img)
    assert os.listdir(tmp_path) == ["frame.png"]

    rgb = np.zeros((3, 4, 3), np.uint8)
    rgb[..., 0] = 200
    write_png(str(target), rgb)  # overwrite, str path
    with Image.open(target) as back:
        np.testing.assert_array_equal(np.asarray(back), rgb)


def test_png_rejects_non_uint8_before_touching_files(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="uint8"):
        write_png(tmp_path / "x.png", np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="shape"):
        write_png(tmp_path / "x.png", np.zeros((3, 3, 2), np.uint8))
    assert os.listdir(tmp_path) == []


def test_png_failure_leaves_old_file_and_no_temp(tmp_path: Path, monkeypatch) -> None:
    target = tmp_path / "frame.png"
    target.write_bytes(b"old contents")

    def broken_save(self, fp, *args, **kwargs):
        fp.write(b"\x89PNG partial")
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.zeros((2, 2, 3), np.uint8))  # RGB: Pillow's encoder
    assert os.listdir(tmp_path) == ["frame.png"]
    assert target.read_bytes() == b"old contents"


def test_a_grey_png_that_cannot_be_put_in_place_leaves_the_old_file_and_no_temp(tmp_path: Path, monkeypatch) -> None:
    target = tmp_path / "frame.png"
    target.write_bytes(b"old contents")

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        write_png(target, np.zeros((2, 2), np.uint8))  # grey: sonarsim.io.png
    assert os.listdir(tmp_path) == ["frame.png"]
    assert target.read_bytes() == b"old contents"


# --------------------------------------------------------------------------- atomic_write


def test_atomic_write_success_and_text_mode(tmp_path: Path) -> None:
    target = tmp_path / "a.txt"
    with atomic_write(target, "w") as fh:
        fh.write("héllo\n")
        # Nothing visible under the final name until the block ends.
        assert not target.exists()
    assert target.read_text(encoding="utf-8") == "héllo\n"
    assert os.listdir(tmp_path) == ["a.txt"]


def test_atomic_write_exception_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "b.bin"
    with pytest.raises(RuntimeError):
        with atomic_write(target) as fh:
            fh.write(b"partial")
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []


def test_atomic_write_permissions_follow_umask(tmp_path: Path) -> None:
    old = os.umask(0o027)
    try:
        with atomic_write(tmp_path / "c.bin") as fh:
            fh.write(b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "c.bin").stat().st_mode) == 0o640


def test_atomic_write_keeps_mode_of_replaced_file(tmp_path: Path) -> None:
    target = tmp_path / "d.bin"
    target.write_bytes(b"old")
    target.chmod(0o604)
    with atomic_write(target) as fh:
        fh.write(b"new")
    assert target.read_bytes() == b"new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o604


def test_atomic_write_bad_mode(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="mode"):
        with atomic_write(tmp_path / "e", "a"):
            pass
    assert os.listdir(tmp_path) == []


def test_atomic_write_temp_name_carries_the_pid(tmp_path: Path) -> None:
    with atomic_write(tmp_path / "polar.png") as fh:
        fh.write(b"x")
        (temp,) = os.listdir(tmp_path)
    assert re.fullmatch(rf"\.polar\.png\.sonarsim-{os.getpid()}-[A-Za-z0-9_]{{8}}\.tmp", temp)
    # A name too long for the prefix is shortened in the temporary name only (255-byte limit).
    long_name = "n" * 250
    with atomic_write(tmp_path / long_name) as fh:
        fh.write(b"x")
    assert (tmp_path / long_name).read_bytes() == b"x"


@pytest.mark.parametrize("stop", [KeyboardInterrupt, SystemExit])
def test_atomic_write_ctrl_c_leaves_nothing(tmp_path: Path, stop: type) -> None:
    (tmp_path / "b.bin").write_bytes(b"old")
    with pytest.raises(stop):
        with atomic_write(tmp_path / "b.bin") as fh:
            fh.write(b"partial")
            raise stop()
    assert os.listdir(tmp_path) == ["b.bin"] and (tmp_path / "b.bin").read_bytes() == b"old"


def test_atomic_write_errors_name_the_destination(tmp_path: Path, monkeypatch) -> None:
    # A disk that fills up: the error raised inside the block names no file at all.
    with pytest.raises(OSError) as info:
        with atomic_write(tmp_path / "full.bin"):
            raise OSError(28, "No space left on device")
    assert info.value.errno == 28 and info.value.filename == str(tmp_path / "full.bin")
    # A folder where the file should go: os.replace names the temporary file first.
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(IsADirectoryError) as info:
        with atomic_write(tmp_path / "dir.png") as fh:
            fh.write(b"x")
    assert info.value.filename == str(tmp_path / "dir.png") and ".tmp" not in str(info.value)
    # A folder that refuses new files (as root, permission bits do not; simulate it).
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(tmp_path / ".x.sonarsim-1-abc.tmp"))

    monkeypatch.setattr(output.tempfile, "mkstemp", refuse)
    with pytest.raises(PermissionError) as info:
        with atomic_write(tmp_path / "x"):
            pass
    assert info.value.filename == str(tmp_path / "x")
    assert sorted(os.listdir(tmp_path)) == ["dir.png"]


def _dead_pid() -> int:
    """The PID of a process that has exited (and been reaped)."""
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    return int(proc.stdout)


def test_remove_abandoned_temp_files(tmp_path: Path) -> None:
    dead = _dead_pid()
    names = {
        f".fan.png.sonarsim-{dead}-abcd1234.tmp": True,  # killed run: removed
        f".render.npz.sonarsim-{dead}-x_9Q0000.tmp": True,
        f".fan.png.sonarsim-{os.getpid()}-abcd1234.tmp": False,  # live process: kept
        ".fan.png.abcd1234.tmp": False,  # old style, but new
        ".polar.png.abcd1234.tmp": True,  # old style, old, and a name that the run writes
        ".other.png.abcd1234.tmp": False,  # old style, old, but not a name of this run
        f".fan.png.sonarsim-{dead}-abcd1234.tmpx": False,
        f"fan.png.sonarsim-{dead}-abcd1234.tmp": False,  # not hidden: not ours
        ".bashrc": False,
        "fan.png": False,
    }
    for name in names:
        (tmp_path / name).write_bytes(b"")
    hour_ago = time.time() - 7200
    for name in (".polar.png.abcd1234.tmp", ".other.png.abcd1234.tmp"):
        os.utime(tmp_path / name, (hour_ago, hour_ago))
    (tmp_path / f".sub.sonarsim-{dead}-abcd1234.tmp").mkdir()  # not a file: kept
    removed = output.remove_abandoned_temp_files(tmp_path, ["polar.png", "fan.png"])
    assert removed == sorted(n for n, gone in names.items() if gone)
    assert sorted(os.listdir(tmp_path)) == sorted([n for n, gone in names.items() if not gone]
                                                  + [f".sub.sonarsim-{dead}-abcd1234.tmp"])
    assert output.remove_abandoned_temp_files(tmp_path / "missing") == []


# --------------------------------------------------------------------------- NPZ


def test_npz_round_trip(tmp_path: Path) -> None:
    arrays = {
        "polar": np.random.default_rng(1).random((16, 8), dtype=np.float32),
        "fan_mask": np.eye(4, dtype=bool),
        "azimuth_deg": np.linspace(10, -10, 8),
        "frame": np.int64(7),
    }
    config = {
        "sonar": {"name": "ARIS", "range_m": [1.0, 10.0], "n_beams": 8},
        "gain_db": np.float32(3.5),
        "seed": np.int64(42),
        "flag": True,
        "note": None,
        "path": tmp_path / "scene.yaml",
    }
    target = tmp_path / "run.npz"
    write_npz(target, arrays, config)
    got_arrays, got_config = read_npz(target)
    assert set(got_arrays) == set(arrays)
    for name, value in arrays.items():
        assert got_arrays[name].dtype == np.asarray(value).dtype
        np.testing.assert_array_equal(got_arrays[name], value)
    assert got_config == {
        "sonar": {"name": "ARIS", "range_m": [1.0, 10.0], "n_beams": 8},
        "gain_db": 3.5,
        "seed": 42,
        "flag": True,
        "note": None,
        "path": str(tmp_path / "scene.yaml"),
    }
    # Stored as a 0-d unicode array, readable without pickle.
    with np.load(target, allow_pickle=False) as raw:
        cfg = raw["config_json"]
        assert cfg.shape == () and cfg.dtype.kind == "U"
    assert os.listdir(tmp_path) == ["run.npz"]


def test_npz_path_used_as_given(tmp_path: Path) -> None:
    write_npz(tmp_path / "noext", {"a": np.zeros(3)}, {})
    assert os.listdir(tmp_path) == ["noext"]
    arrays, config = read_npz(tmp_path / "noext")
    assert config == {} and list(arrays) == ["a"]


def test_npz_failure_leaves_no_partial_or_temp_file(tmp_path: Path, monkeypatch) -> None:
    def broken_encoder(payload, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(npz, "encode_npz", broken_encoder)
    target = tmp_path / "run.npz"
    with pytest.raises(OSError, match="disk full"):
        write_npz(target, {"a": np.ones(3)}, {"k": 1})
    assert os.listdir(tmp_path) == []

    # An existing file survives a failed overwrite unchanged.
    monkeypatch.undo()
    write_npz(target, {"a": np.ones(3)}, {"k": 1})
    before = target.read_bytes()
    monkeypatch.setattr(npz, "encode_npz", broken_encoder)
    with pytest.raises(OSError):
        write_npz(target, {"a": np.zeros(5)}, {"k": 2})
    assert os.listdir(tmp_path) == ["run.npz"]
    assert target.read_bytes() == before


@pytest.mark.parametrize(
    ("arrays", "config", "match"),
    [
        ({"config_json": np.zeros(2)}, {}, "reserved"),
        ({"": np.zeros(2)}, {}, "keys"),
        ({"obj": np.array([{}, 1], dtype=object)}, {}, "object"),
        ({"a": np.zeros(2)}, {"bad": object()}, "config.*JSON"),
        ({"a": np.zeros(2)}, ["not", "a", "mapping"], "config"),
    ],
)
def test_npz_rejects_bad_input_before_writing(
    tmp_path: Path, arrays: dict, config: object, match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        write_npz(tmp_path / "x.npz", arrays, config)  # type: ignore[arg-type]
    assert os.listdir(tmp_path) == []


def test_read_npz_without_config_is_rejected(tmp_path: Path) -> None:
    np.savez(tmp_path / "plain.npz", a=np.zeros(2))
    with pytest.raises(ValueError, match="config_json"):
        read_npz(tmp_path / "plain.npz")


def test_module_exports() -> None:
    assert output.CONFIG_KEY == "config_json"
