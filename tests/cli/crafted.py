"""Recordings crafted from the real ones in ../shared/data: the same headers (the readers'
format, byte for byte), other pixels. For the refusals of ``fit`` and ``calibrate`` on a frame
that holds no echo."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np


def crafted_oculus(source: Path, out: Path, pixels: Callable[[np.ndarray], np.ndarray]) -> Path:
    """``source`` (an Oculus .raw) with each ping's image bytes replaced by ``pixels(rows)``.

    ``rows`` is a ping's (n_ranges, n_beams) uint8 values as stored (a gain word before each row
    is kept as it is); ``pixels`` returns the new values, of the same shape.
    """
    from sonarsim.io.readers.oculus import _GAIN_BYTES, OculusRecording

    data = bytearray(Path(source).read_bytes())
    with OculusRecording(source) as rec:
        for k in range(len(rec)):
            rec.read(k)  # checks ping k and every message before it
            m = rec._pings[k]
            g = rec._layout(m, k)
            assert g["bpv"] == 1, "8-bit pings only"
            start = m.offset + g["image_at"]
            rows = np.frombuffer(bytes(data[start:start + g["image_bytes"]]), np.uint8).reshape(
                -1, g["row_bytes"]).copy()
            skip = _GAIN_BYTES if g["gain"] else 0
            new = np.asarray(pixels(rows[:, skip:].copy()), dtype=np.uint8)
            assert new.shape == rows[:, skip:].shape
            rows[:, skip:] = new
            data[start:start + g["image_bytes"]] = rows.tobytes()
    out.write_bytes(bytes(data))
    return out


def zeros(rows: np.ndarray) -> np.ndarray:
    return np.zeros_like(rows)


def saturated(rows: np.ndarray) -> np.ndarray:
    return np.full_like(rows, 255)


def random_bytes(rows: np.ndarray) -> np.ndarray:
    return np.random.default_rng(37).integers(0, 256, rows.shape, dtype=np.uint8)


def one_bright_pixel(rows: np.ndarray) -> np.ndarray:
    out = np.zeros_like(rows)
    out[rows.shape[0] // 2, rows.shape[1] // 2] = 255
    return out
