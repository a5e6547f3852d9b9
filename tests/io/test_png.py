"""The fast grey PNG encoder (sonarsim.io.png): any reader gets the pixels back, the same image
gives the same bytes (whatever its memory layout), and the header is a plain 8-bit grey PNG."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from sonarsim.io.png import PNG_ENCODER, gray_png_bytes


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (9, 1), (57, 113), (600, 301)])
def test_pillow_reads_the_pixels_back(shape):
    rng = np.random.default_rng(sum(shape))
    a = rng.integers(0, 256, shape, dtype=np.uint8)
    a[: shape[0] // 2] = 0  # a run of zeros, as outside a fan
    img = Image.open(io.BytesIO(gray_png_bytes(a)))
    assert img.mode == "L" and img.size == (shape[1], shape[0])
    assert np.array_equal(np.asarray(img), a)


def test_the_same_image_gives_the_same_bytes_whatever_its_layout():
    rng = np.random.default_rng(1)
    a = (rng.normal(100, 20, (400, 300)).clip(0, 255)).astype(np.uint8)
    once = gray_png_bytes(a)
    big = np.zeros((410, 333), np.uint8)
    big[3:403, 7:307] = a
    assert gray_png_bytes(big[3:403, 7:307]) == once  # a non-contiguous view
    assert gray_png_bytes(np.asfortranarray(a)) == once
    assert gray_png_bytes(a.copy()) == once


def test_the_header_is_an_8_bit_grey_png_with_valid_crcs():
    data = gray_png_bytes(np.full((5, 4), 9, np.uint8))
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, kinds = 8, []
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF
        kinds.append(kind)
        if kind == b"IHDR":
            assert struct.unpack(">IIBBBBB", body) == (4, 5, 8, 0, 0, 0, 0)
        pos += 12 + n
    assert kinds == [b"IHDR", b"IDAT", b"IEND"]
    assert PNG_ENCODER.startswith("zlib-ng-") and "-level" in PNG_ENCODER


def test_bad_images_are_refused():
    for bad in (np.zeros((3, 3), np.float32), np.zeros((3, 3, 3), np.uint8), np.zeros((0, 4), np.uint8)):
        with pytest.raises(ValueError, match="uint8 array"):
            gray_png_bytes(bad)
