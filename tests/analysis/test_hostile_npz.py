"""NPZ files that sonarsim did not write, or that were tampered with (issue 11 review): loading
them for ``compare`` / ``fit`` ends in one SonarsimError naming the file and what is wrong,
never a traceback, a MemoryError or a silently converted image."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.comparison import load_image
from sonarsim.cli.main import main
from sonarsim.errors import SonarsimError

SCENE = {
    "sonar": {"n_beams": 8, "azimuth_fov_deg": 20.0, "elevation_fov_deg": 10.0, "range_min_m": 0.5,
              "range_max_m": 3.0, "n_range_bins": 50},
    "render": {"elevation_samples": 8},
    "ground": {"height_m": -1.0},
}


@pytest.fixture(scope="module")
def arrays():
    image = sonarsim.render(SCENE)
    return {"polar": image.polar, "range_m": image.range_m, "azimuth_deg": image.azimuth_deg}


def _save(path, arrays, config_text="{}", **changed):
    np.savez(path, **{**arrays, **changed, "config_json": np.array(config_text)})
    return path


@pytest.mark.parametrize("config_text, changed, message", [
    ("[" * 100000 + "]" * 100000, {}, "nested too deeply"),
    ('{"sonar": ' + "{\"a\": " * 50000 + "1" + "}" * 50001, {}, "nested too deeply"),
    ("{}", {"polar": np.full((50, 8), "x")}, "polar: holds <U1 values"),
    ("{}", {"polar": np.ones((50, 8), np.complex64)}, "polar: holds complex64 values"),
    ("{}", {"range_m": np.array(["a"] * 50)}, "range_m: holds <U1 values"),
    ("{}", {"polar": np.ones((1, 50, 8), np.float32)}, r"polar: has shape \(1, 50, 8\); an image has 2 dimensions"),
    ('{"sonar": {"elevation_fov_deg": "wide"}}', {}, "sonar.elevation_fov_deg is 'wide'; allowed: a number"),
    ('{"sonar": {"elevation_fov_deg": [1, 2]}}', {}, r"sonar.elevation_fov_deg is \[1, 2\]"),
])
def test_malformed_npz_contents_are_refused_naming_the_file(tmp_path, arrays, config_text, changed, message):
    path = _save(tmp_path / "x.npz", arrays, config_text, **changed)
    with pytest.raises(SonarsimError, match=message) as e:
        load_image(path)
    assert str(path) in str(e.value)


def test_a_config_that_is_not_text_is_refused(tmp_path, arrays):
    path = tmp_path / "x.npz"
    np.savez(path, **arrays, config_json=np.zeros(3))
    with pytest.raises(SonarsimError, match="'config_json' is not a JSON text"):
        load_image(path)


def _npy(value) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, value)
    return buffer.getvalue()


def test_an_array_header_declaring_terabytes_is_refused_before_allocating(tmp_path, arrays, capsys):
    # A zip bomb in miniature: a header asking for 4 TB of float32 and a few bytes of data. NumPy
    # would allocate the 4 TB first (MemoryError) or, within the machine's overcommit, the
    # gigabytes a compressed run of zeros unpacks to.
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for k, v in {**arrays, "config_json": np.array("{}")}.items():
            z.writestr(k + ".npy", _npy(v))
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                      "shape": (10**6, 10**6)})
        z.writestr("huge.npy", header.getvalue() + b"\0" * 1000)
    with pytest.raises(SonarsimError, match=r"would need 3.73e\+03 GiB, more than the memory budget"):
        load_image(path)
    assert main(["compare", str(path), str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "memory budget" in err


def test_a_tampered_npz_still_compares_when_only_its_config_is_odd(tmp_path, arrays):
    # A large but flat configuration is no reason to refuse the image.
    path = _save(tmp_path / "x.npz", arrays, json.dumps({"note": "a" * 1_000_000}))
    assert load_image(path).polar.shape == (50, 8)


def _png_header_only(path, width, height):
    """A PNG whose header declares ``width`` x ``height`` grey pixels and whose data is a stub."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 100))
                     + chunk(b"IEND", b""))
    return path


def test_pngs_beyond_the_budget_or_pillows_limit_are_one_line(tmp_path, arrays, monkeypatch, capsys):
    from PIL import Image

    from sonarsim.core import memory

    # 10^10 pixels: Pillow's own decompression-bomb error (was a traceback).
    bomb = _png_header_only(tmp_path / "bomb.png", 100000, 100000)
    with pytest.raises(SonarsimError, match="bomb.png: too large a PNG"):
        load_image(bomb)
    # Within Pillow's limit but beyond the budget: refused before decoding (a pair of 12000 x
    # 12000 PNGs peaked at 20.6 GB while the budget was 8 GiB).
    monkeypatch.setenv(memory.ENV_VAR, "2M")
    big = tmp_path / "big.png"
    Image.fromarray(np.zeros((200, 200), np.uint8)).save(big)
    with pytest.raises(SonarsimError, match=r"comparing .*big.png, a PNG of 200 x 200 pixels, would need") as e:
        load_image(big)
    assert "cannot read" not in str(e.value)
    monkeypatch.delenv(memory.ENV_VAR)
    assert load_image(big).polar.shape == (200, 200)


def test_compare_images_checks_the_budget_for_arrays_given_directly(monkeypatch):
    from sonarsim.analysis.comparison import PlainImage, compare_images
    from sonarsim.core import memory

    a = PlainImage(polar=np.ones((200, 200), np.float32))
    monkeypatch.setenv(memory.ENV_VAR, "2M")
    with pytest.raises(SonarsimError, match=r"comparing images of 200 x 200 and 200 x 200 pixels would need"):
        compare_images(a, a)
    monkeypatch.delenv(memory.ENV_VAR)
    assert compare_images(a, a)["polar"]["mse"] == 0.0


def test_regions_declaring_terabytes_are_refused_before_allocating(tmp_path, arrays, capsys):
    from sonarsim.analysis.comparison import load_region

    npy = tmp_path / "r.npy"
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "|b1", "fortran_order": False, "shape": (10**7, 10**7)})
    npy.write_bytes(header.getvalue() + b"\0" * 100)
    with pytest.raises(SonarsimError, match=r"r.npy, an array of shape \(10000000, 10000000\), would need"):
        load_region(npy)
    with pytest.raises(SonarsimError, match="too large a PNG"):
        load_region(_png_header_only(tmp_path / "r.png", 100000, 100000))
    a = _save(tmp_path / "a.npz", arrays)
    assert main(["compare", str(a), str(a), "--region", f"x={npy}"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
