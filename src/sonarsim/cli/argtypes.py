"""argparse value types shared by the sub-commands: each names what it expected; and the
parser class every command's parser is (:class:`Parser`: values that begin with a minus)."""

from __future__ import annotations

import argparse
import math
import re

#: A token that is a value, not an option, though it begins with a minus: a number in any form
#: Python's ``float`` reads (``-1``, ``-.5``, ``-1e20``, ``-inf``, ``-nan``) or a comma list
#: that begins with one (``-1,3,-0.8,0.8``). No option of sonarsim's begins with a minus and
#: a digit or spells a number.
NEGATIVE_VALUE = re.compile(r"^-(?:\.?[0-9]|(?:inf|infinity|nan)(?:,|$))", re.IGNORECASE)


class Parser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` that takes ``--extent -1,3,-0.8,0.8`` and ``--start-time
    -1e20`` as an option and its value, as it takes ``--gain-db -5``.

    argparse reads a token that begins with a minus as an option unless it is a plain decimal
    (``-5``, ``-0.5``): ``--extent -1,3,...`` then ends in "expected one argument". This
    parser reads every token in :data:`NEGATIVE_VALUE`'s form as a value, so that each option
    that takes a number or a list of numbers accepts a leading minus in the separate-token
    form too, in every sub-command (``add_subparsers`` makes its parsers of this class). The
    value then meets the option's own check, which says what is allowed.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # argparse's hook for "looks like a negative number" (its own pattern takes only
        # plain decimals); set before any option is added, so that none is mistaken for one.
        self._negative_number_matcher = NEGATIVE_VALUE


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


def ping_count_or_range(text: str) -> int | tuple[int, int]:
    """``N`` (a number of pings, >= 1) or ``A:B`` (pings A to B - 1 of a recording, 0 <= A < B)."""
    if ":" in text:
        a, _, b = text.partition(":")
        try:
            lo, hi = int(a or 0), int(b)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected N or A:B (pings A to B - 1), got {text!r}") from None
        if not 0 <= lo < hi:
            raise argparse.ArgumentTypeError(f"expected A:B with 0 <= A < B, got {text!r}")
        return lo, hi
    return integer_at_least(text, 1, "number of pings")


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
