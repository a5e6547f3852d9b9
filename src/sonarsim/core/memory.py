"""Keep freed heap memory in the process between frames (glibc only).

Each frame allocates tens of megabytes of short-lived NumPy temporaries. With glibc's default
settings the heap top is handed back to the kernel when they are freed, and the next frame pays
a page fault (and the kernel's zeroing) for every 4 KiB page again: measured here, that made
image formation three times slower (11 ms instead of 3.5 ms per frame of the demo). Asking
malloc to keep a pad of free memory at the heap top removes that cost; it only keeps memory
the process has already used.

Large frames need more than the pad: glibc serves blocks above its mmap threshold (which it
raises by itself only up to 32 MiB) with fresh mappings, returned to the kernel when freed, so
a 1024-beam frame page-faulted 2,300 times per frame. Setting the mmap and trim thresholds
fixes both (and stops glibc from adjusting them): blocks up to 256 MiB come from the heap, and
the heap keeps up to 256 MiB of freed memory for the next frame (0 faults per frame at 1024
beams, tested).
"""

from __future__ import annotations

import ctypes
import sys

# glibc's mallopt parameter numbers.
M_TRIM_THRESHOLD = -1
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
TOP_PAD_BYTES = 64 * 2**20
#: Blocks up to this size come from the heap, and this much freed memory stays in it.
KEEP_BYTES = 256 * 2**20

_done = False


def keep_freed_memory(top_pad_bytes: int = TOP_PAD_BYTES, keep_bytes: int = KEEP_BYTES) -> bool:
    """Tune glibc's heap once per process (top pad, mmap and trim thresholds); returns whether
    it was done.

    A no-op (returning False) off Linux or where the C library has no ``mallopt``.
    """
    global _done
    if _done:
        return True
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _done = all([bool(mallopt(M_TOP_PAD, int(top_pad_bytes))), bool(mallopt(M_MMAP_THRESHOLD, int(keep_bytes))),
                 bool(mallopt(M_TRIM_THRESHOLD, int(keep_bytes)))])
    return _done


# The memory budget ------------------------------------------------------------------------
#
# Sizes a user controls (range bins, beams, rays per beam, fan pixel size, speckle fields) are
# checked against a budget before anything is allocated, so that a typo (n_range_bins: 1e9)
# ends in a clear error instead of a MemoryError traceback or a machine swapping.

ENV_VAR = "SONARSIM_MAX_MEMORY"
DEFAULT_BUDGET_BYTES = 8 * 2**30
# The largest budget accepted: far beyond any machine, yet a finite integer.
MAX_BUDGET_BYTES = 2**60
_UNITS = {"": 1, "b": 1, "k": 2**10, "kb": 2**10, "kib": 2**10, "m": 2**20, "mb": 2**20, "mib": 2**20,
          "g": 2**30, "gb": 2**30, "gib": 2**30, "t": 2**40, "tb": 2**40, "tib": 2**40}
_budget_override: int | None = None


def parse_size(text: str) -> int:
    """``"4G"``, ``"512 MiB"``, ``"1e9"`` -> bytes. Raises ValueError naming what is allowed."""
    import re

    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([a-zA-Z]*)\s*", str(text))
    if not m or m.group(2).lower() not in _UNITS:
        raise ValueError(f"a memory size is a number with an optional unit (K, M, G, T), e.g. 4G; got {text!r}")
    value = float(m.group(1)) * _UNITS[m.group(2).lower()]
    if not value >= 2**20:
        raise ValueError(f"a memory budget below 1 MiB cannot render anything; got {text!r}")
    # A budget is a number of bytes: 1e400 reads as an infinite float, which no integer holds.
    if not value <= MAX_BUDGET_BYTES:
        raise ValueError(f"a memory budget above 1 EiB (2**60 bytes) is no budget; got {text!r}")
    return int(value)


def set_memory_budget(nbytes: int | None) -> None:
    """Set the budget for this process (``None``: back to the environment's or the default)."""
    global _budget_override
    _budget_override = None if nbytes is None else int(nbytes)


def memory_budget() -> int:
    """Bytes a single allocation plan may use: ``set_memory_budget``, else ``$SONARSIM_MAX_MEMORY``,
    else 8 GiB or 80 % of the machine's memory, whichever is less."""
    import os

    chosen = _chosen(_budget_override, ENV_VAR, parse_size)
    if chosen is not None:
        return chosen
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = DEFAULT_BUDGET_BYTES
    return int(min(DEFAULT_BUDGET_BYTES, 0.8 * total))


def _chosen(override, env_var: str, parse):
    """A budget set in this process, else the environment's (parsed), else None.

    Raises
    ------
    SonarsimError
        The environment variable does not parse, naming it.
    """
    import os

    from ..errors import SonarsimError

    if override is not None:
        return override
    env = os.environ.get(env_var)
    if not env:
        return None
    try:
        return parse(env)
    except ValueError as exc:
        raise SonarsimError(f"{env_var}: {exc}") from None


def require(nbytes: float, what: str, key: str) -> None:
    """Refuse a plan that would need more than the budget, naming the key that sets its size.

    Raises
    ------
    ConfigError
        ``key``: what would be allocated, how much, the budget, and how to raise it.
    """
    from ..errors import ConfigError

    budget = memory_budget()
    if nbytes > budget:
        try:
            need = f"{nbytes / 2**30:.3g} GiB"
        except OverflowError:  # an exact integer beyond a float (a 400-digit size)
            need = f"about 1e{len(str(int(nbytes))) - 10} GiB"
        if need == "inf GiB":  # a float size that overflowed while being counted
            need = "more than 1e300 GiB"
        raise ConfigError(key, f"{what} would need {need}, more than the memory budget of "
                          f"{budget / 2**30:.3g} GiB (raise it with --max-memory or ${ENV_VAR})")


def require_together(parts: list[tuple[float, str, str]], what: str) -> None:
    """Refuse plans that fit the budget one by one but not together (held at the same time).

    Parameters
    ----------
    parts : list of (nbytes, description, key)
        What one frame holds at once (its images, its rays, the sensor's fields), each with the
        key that sets its size.
    what : str
        What holds them, for the message (e.g. ``"a frame"``).

    Raises
    ------
    ConfigError
        Naming the key of the largest part, and every part's share.
    """
    from ..errors import ConfigError

    total = sum(float(n) for n, _, _ in parts)
    budget = memory_budget()
    if total <= budget:
        return
    largest = max(parts, key=lambda p: float(p[0]))
    shares = ", ".join(f"{d} {float(n) / 2**30:.3g} GiB" for n, d, _ in parts if n)
    raise ConfigError(largest[2], f"{what} would hold {total / 2**30:.3g} GiB at once ({shares}), more than the "
                      f"memory budget of {budget / 2**30:.3g} GiB (raise it with --max-memory or ${ENV_VAR})")


# The time budget ----------------------------------------------------------------------------
#
# Some work grows with what a scene holds rather than with memory: building thousands of
# objects, a ray-tracing structure of millions of triangles, parsing a large mesh file. Such
# work is estimated from the document before it starts (with rates measured on a 2-core
# laptop-class machine) and refused beyond this budget, so that a scene of a million pebbles
# says so at once instead of running for an hour.

TIME_ENV_VAR = "SONARSIM_MAX_BUILD_TIME"
DEFAULT_TIME_BUDGET_S = 120.0
_time_override: float | None = None


def parse_seconds(text: str) -> float:
    """``"120"``, ``"90s"``, ``"5 min"`` -> seconds. Raises ValueError naming what is allowed."""
    import re

    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*(s|sec|min|m|h)?\s*", str(text))
    if not m:
        raise ValueError(f"a time is a number of seconds with an optional unit (s, min, h), e.g. 300; got {text!r}")
    value = float(m.group(1)) * {None: 1, "s": 1, "sec": 1, "min": 60, "m": 60, "h": 3600}[m.group(2)]
    if not 1.0 <= value <= 7 * 24 * 3600:
        raise ValueError(f"a build-time budget lies between 1 s and a week; got {text!r}")
    return value


def set_time_budget(seconds: float | None) -> None:
    """Set the time budget for this process (``None``: back to the environment's or the default)."""
    global _time_override
    _time_override = None if seconds is None else float(seconds)


def time_budget() -> float:
    """Seconds one step of building (a scene, a mesh file) may be estimated to take:
    ``set_time_budget``, else ``$SONARSIM_MAX_BUILD_TIME``, else 120 s."""
    chosen = _chosen(_time_override, TIME_ENV_VAR, parse_seconds)
    return DEFAULT_TIME_BUDGET_S if chosen is None else chosen


def require_time(seconds: float, what: str, key: str) -> None:
    """Refuse work estimated to take longer than the time budget, naming the key that sets it.

    Raises
    ------
    ConfigError
        ``key``: what would be done, its estimated time, the budget, and how to raise it.
    """
    from ..errors import ConfigError

    budget = time_budget()
    if seconds > budget:
        raise ConfigError(key, f"{what} would take about {seconds:.3g} s, more than the build-time budget of "
                          f"{budget:g} s (raise it with --max-build-time or ${TIME_ENV_VAR})")
