"""argparse value types shared by the sub-commands: each names what it expected."""

from __future__ import annotations

import argparse
import math


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def integer_at_least(text: str, minimum: int, what: str) -> int:
    """``text`` as an integer >= ``minimum``; the error says ``expected a {what} >= {minimum}``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a {what} >= {minimum}, got {text!r}") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"expected a {what} >= {minimum}, got {text!r}")
    return value


def frame_index(text: str) -> int:
    """A frame number >= 0."""
    return integer_at_least(text, 0, "frame number")


# Display levels, dB: beyond these a PNG is all white or all black (float32 powers span about
# 770 dB), and a range of less than a thousandth of a dB is no scale at all.
DISPLAY_GAIN_DB = (-400.0, 400.0)
DISPLAY_RANGE_DB = (1e-3, 800.0)


def _db_within(text: str, lo: float, hi: float) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of dB from {lo:g} to {hi:g}, got {text!r}") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise argparse.ArgumentTypeError(f"expected a number of dB from {lo:g} to {hi:g}, got {text!r}")
    return value


def display_gain_db(text: str) -> float:
    """A display gain in dB within :data:`DISPLAY_GAIN_DB`."""
    return _db_within(text, *DISPLAY_GAIN_DB)


def display_range_db(text: str) -> float:
    """A display dynamic range in dB within :data:`DISPLAY_RANGE_DB`."""
    return _db_within(text, *DISPLAY_RANGE_DB)
