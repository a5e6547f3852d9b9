"""Seeded mutations of the real recordings and the check every mutated file must pass.

Shared by the CI fuzz test (``tests/fuzz/test_recordings_fuzz.py``, a few thousand cases) and
the long run (``benchmarks/fuzz_recordings.py``, 100,000 cases): the same generator and the same
check, so a failure found by one reproduces in the other from its seed and case number.

A case is a real recording (``../shared/data/real``) with one to three mutations: bit flips,
header fields overwritten with extreme values (0, all ones, the largest signed value, NaN,
infinities, 1e300, 1e-300 ...) at the offsets the readers decode, cuts, inserted random bytes,
deleted ranges, and duplicated byte ranges, frames and messages. The check reads every frame
both ways - ``read(path, k)`` for each ``k`` and by iterating ``read_frames(path)`` - and
requires that

* every failure is a :class:`~sonarsim.io.readers.RecordingError` (never another exception,
  a ``MemoryError`` included);
* every reader agrees on the good frames (issue 21): iteration yields exactly the frames
  ``read`` returns, and stops where ``read`` first fails, with the same error class (or, after
  at least one frame, where ``read`` says the frame is out of range); ``read`` refuses every
  frame after that one too; ``open_recording(path).n_frames`` and ``n_frames(path)`` count the
  frames iteration gave, and the recording's ``damage`` is the error iteration ended with
  (``None`` when it ended cleanly); a file that ``open_recording`` refuses gave no frame, and
  is refused with the error iteration raised;
* with ``show_dir``, ``sonarsim show FILE --frame 0`` (in this process) shows frame 0 exactly
  when ``read(path, 0)`` returns it, says it is frame 0 of ``n_frames`` and names the damage,
  or exits 2 with ``read``'s error on one line;
* every image returned has a plausible geometry: within the reader's own limits, a finite,
  non-empty range window, finite strictly descending azimuths within +-90 deg, and a ``polar``
  of the shape the header gives;
* no case takes longer than ``time_limit_s`` (a hang is stopped by an alarm);
* the memory the case allocates (``tracemalloc`` peak, when tracing) stays within the budget
  set for the run.
"""

from __future__ import annotations

import dataclasses
import math
import random
import signal
import struct
import time
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from sonarsim.io import readers
from sonarsim.io.readers import RecordingError
from sonarsim.io.readers import aris as aris_reader
from sonarsim.io.readers import oculus as oculus_reader

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "real"
SOURCES = {
    "aris": DATA / "aris" / "sample.aris",
    "oculus1": DATA / "oculus" / "one_ping_8bit.raw",
    "oculus3": DATA / "oculus" / "three_pings_8bit.raw",
}

# --------------------------------------------------------------------------------------------
# Where the header fields are
# --------------------------------------------------------------------------------------------

Field = tuple[str, int, str]  # (name, byte offset in the file, struct format character)


def _struct_fields(fmt: str, names: tuple[str, ...], at: int) -> list[Field]:
    """(name, offset, format) of each field of a packed little-endian struct at byte ``at``."""
    out, offset = [], at
    codes = fmt.lstrip("<")
    assert len(codes) == len(names)
    for code, name in zip(codes, names):
        out.append((name, offset, code))
        offset += struct.calcsize("<" + code)
    return out


def aris_fields(data: bytes) -> list[Field]:
    """The header fields the ARIS reader decodes, in the file header and every frame header."""
    fields = [(f"file.{name}", offset, fmt[-1]) for name, offset, fmt in aris_reader._FILE_FIELDS]
    frame_size = _aris_frame_size(data)
    if frame_size:
        for k in range((len(data) - aris_reader.FILE_HEADER_SIZE) // frame_size):
            base = aris_reader.FILE_HEADER_SIZE + k * frame_size
            fields += [(f"frame{k}.{name}", base + offset, fmt[-1])
                       for name, offset, fmt in aris_reader._FRAME_FIELDS]
    return fields


def _aris_frame_size(data: bytes) -> int:
    n_samples = struct.unpack_from("<I", data, aris_reader.FILE_HEADER_SIZE + 468)[0]
    mode = struct.unpack_from("<I", data, aris_reader.FILE_HEADER_SIZE + 436)[0]
    return aris_reader.FRAME_HEADER_SIZE + n_samples * aris_reader.PING_MODE_BEAMS[mode]


def oculus_messages(data: bytes) -> list[tuple[int, int]]:
    """(offset, size) of each message of a well-formed Oculus file."""
    out, offset = [], 0
    while offset + oculus_reader.MESSAGE_HEADER_SIZE <= len(data):
        payload = struct.unpack_from("<I", data, offset + 10)[0]
        size = oculus_reader.MESSAGE_HEADER_SIZE + payload
        out.append((offset, size))
        offset += size
    return out


def oculus_fields(data: bytes) -> list[Field]:
    """The fields the Oculus reader decodes (version 1 layout) and the bearing table entries."""
    header = ("oculusId", "srcDeviceId", "dstDeviceId", "msgId", "msgVersion", "payloadSize", "spare")
    fields: list[Field] = []
    for m, (offset, _size) in enumerate(oculus_messages(data)):
        ping_at, ping_struct, names, bearings_at = oculus_reader._LAYOUTS[1]
        per = _struct_fields(oculus_reader._HEADER.format, header, 0)
        per += _struct_fields(oculus_reader._FIRE.format, oculus_reader._FIRE_FIELDS, 16)
        per += _struct_fields(ping_struct.format, names, ping_at)
        n_beams = struct.unpack_from("<H", data, offset + 108)[0]
        per += [(f"bearing{b}", bearings_at + 2 * b, "h") for b in range(n_beams)]
        fields += [(f"message{m}.{name}", offset + at, code) for name, at, code in per]
    return fields


# --------------------------------------------------------------------------------------------
# Mutations
# --------------------------------------------------------------------------------------------

_INT_BITS = {"B": 8, "h": 16, "H": 16, "I": 32, "Q": 64}

#: Fields that set a frame's geometry or where its data lie (both formats).
GEOMETRY_FIELDS = frozenset({
    "Version", "PingMode", "SamplePeriod", "SampleStartDelay", "SamplesPerBeam", "SoundSpeed",
    "LargeLens", "TheSystemType", "FrequencyHiLow", "ReorderedSamples",
    "oculusId", "msgId", "msgVersion", "payloadSize", "masterMode", "flags", "frequency",
    "dataSize", "rangeResolution", "nRanges", "nBeams", "imageOffset", "imageSize",
})


def extreme_value(code: str, old: float, rng: random.Random) -> float:
    """A hostile value for a field of struct format ``code`` whose current value is ``old``."""
    if code in "fd":
        big = 3.0e38 if code == "f" else 1e300
        tiny = 1e-40 if code == "f" else 1e-300  # a denormal float32; 1e-300 underflows it
        return rng.choice([
            math.nan, math.inf, -math.inf, big, -big, tiny, 0.0, -0.0, -1.0,
            old * 2.0, old / 2.0, old * 1e6, old * 1e-6, rng.uniform(-1e4, 1e4),
        ])
    bits = _INT_BITS[code]
    signed = code == "h"
    top = (1 << (bits - 1)) - 1 if signed else (1 << bits) - 1
    low = -(1 << (bits - 1)) if signed else 0
    choices = [0, 1, top, low, (1 << (bits - 1)) - 1 if not signed else -1, int(old) + 1,
               int(old) - 1, int(old) * 2, int(old) // 2, rng.randint(low, top)]
    return min(max(rng.choice(choices), low), top)


def overwrite_field(data: bytearray, field: Field, rng: random.Random) -> str:
    name, offset, code = field
    fmt = "<" + code
    if offset + struct.calcsize(fmt) > len(data):
        return f"field {name} (absent)"
    (old,) = struct.unpack_from(fmt, data, offset)
    value = extreme_value(code, old, rng)
    try:
        struct.pack_into(fmt, data, offset, value)
    except OverflowError:  # old * 1e6 beyond float32: what a float32 overflow gives
        value = math.copysign(math.inf, value)
        struct.pack_into(fmt, data, offset, value)
    return f"field {name}={value!r}"


def _random_span(rng: random.Random, n: int, max_len: int) -> tuple[int, int]:
    start = rng.randrange(n)
    return start, min(n, start + rng.randint(1, max_len))


def mutate(data: bytes, kind: str, rng: random.Random) -> tuple[bytes, list[str]]:
    """Apply one to three seeded mutations to ``data`` (a recording of ``kind``)."""
    out = bytearray(data)
    done = []
    fields = aris_fields(data) if kind == "aris" else oculus_fields(data)
    units = _units(data, kind)
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        op = rng.choices(
            ["field", "bits", "truncate", "insert", "delete", "duplicate", "unit"],
            weights=[40, 15, 10, 10, 8, 8, 9],
        )[0]
        n = len(out)
        if n == 0:
            break
        if op == "field":
            # Half the overwrites hit a field the geometry or layout comes from, one in ten a
            # bearing (there are hundreds: drawn uniformly, they would crowd out the rest).
            u = rng.random()
            if u < 0.5:
                pool = [f for f in fields if f[0].split(".")[-1] in GEOMETRY_FIELDS]
            elif u < 0.6:
                pool = [f for f in fields if "bearing" in f[0]]
            else:
                pool = fields
            done.append(overwrite_field(out, rng.choice(pool or fields), rng))
        elif op == "bits":
            # Half the flips land in the first 2 KiB (the headers), half anywhere.
            for _ in range(rng.randint(1, 8)):
                at = rng.randrange(min(n, 2048)) if rng.random() < 0.5 else rng.randrange(n)
                out[at] ^= 1 << rng.randrange(8)
            done.append("bit flips")
        elif op == "truncate":
            # Cuts near the unit boundaries (headers, frames) are the interesting ones.
            edges = [u for u, _ in units] + [n]
            at = max(0, min(n - 1, rng.choice(edges) + rng.randint(-32, 1100))) if rng.random() < 0.6 else rng.randrange(n)
            del out[at:]
            done.append(f"truncate at {at}")
        elif op == "insert":
            at = rng.randrange(n + 1)
            out[at:at] = rng.randbytes(rng.randint(1, 64))
            done.append(f"insert at {at}")
        elif op == "delete":
            start, end = _random_span(rng, n, 256)
            del out[start:end]
            done.append(f"delete {start}-{end}")
        elif op == "duplicate":
            start, end = _random_span(rng, n, 4096)
            at = rng.randrange(n + 1)
            out[at:at] = out[start:end]
            done.append(f"duplicate {start}-{end} at {at}")
        elif op == "unit":
            # Copy a whole frame or message to another boundary: a well-formed file again.
            (start, size), (at, _) = rng.choice(units), rng.choice(units)
            out[at:at] = out[start:start + size]
            done.append(f"duplicate unit at {start} to {at}")
    return bytes(out), done


def _units(data: bytes, kind: str) -> list[tuple[int, int]]:
    """(offset, size) of the frames (ARIS) or messages (Oculus) of an unmutated file."""
    if kind == "aris":
        size = _aris_frame_size(data)
        start = aris_reader.FILE_HEADER_SIZE
        return [(start + k * size, size) for k in range((len(data) - start) // size)]
    return oculus_messages(data)


@dataclasses.dataclass(frozen=True)
class Case:
    """One mutated recording: ``seed`` and ``index`` regenerate it exactly."""

    seed: int
    index: int
    source: str
    mutations: tuple[str, ...]
    data: bytes


def cases(seed: int, n: int, sources: dict[str, bytes] | None = None) -> Iterator[Case]:
    """``n`` seeded cases, cycling over the real recordings.

    Parameters
    ----------
    seed : int
        Case ``i`` depends only on ``(seed, i)``.
    n : int
        Number of cases.
    sources : dict, optional
        Name -> bytes of each real recording (read from :data:`SOURCES` if not given).
    """
    if sources is None:
        sources = load_sources()
    names = sorted(sources)
    for i in range(n):
        rng = random.Random(f"{seed}:{i}")
        name = names[i % len(names)]
        kind = "aris" if name.startswith("aris") else "oculus"
        data, done = mutate(sources[name], kind, rng)
        yield Case(seed, i, name, tuple(done), data)


def load_sources() -> dict[str, bytes]:
    """The real recordings' bytes (raises FileNotFoundError when ../shared/data is absent)."""
    return {name: path.read_bytes() for name, path in SOURCES.items()}


# --------------------------------------------------------------------------------------------
# The check
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Outcome:
    """What reading a case gave.

    ``kind`` is ``"ok"`` (every frame read), ``"partial"`` (frames read, then a
    RecordingError) or ``"refused"`` (no frame read); ``field`` is the RecordingError's field
    (or the first words of its message when it names none); ``failure`` is None when the case
    passed the check, else what went wrong.
    """

    kind: str
    field: str | None
    frames: int
    seconds: float
    peak_bytes: int
    failure: str | None = None


class _Hang(Exception):
    pass


def _on_alarm(signum, frame):  # pragma: no cover - only when a case hangs
    raise _Hang()


def _error_key(exc: RecordingError) -> str:
    if exc.field:
        return exc.field
    if "truncated" in exc.detail:
        return "truncated"
    words = exc.detail.split(":")[0].split()
    return " ".join(words[:3]) or "?"


def check_plausible(image, kind: str) -> str | None:
    """None if ``image`` has a geometry some real sonar of ``kind`` could give, else why not."""
    s = image.sonar
    h = image.config["header"]
    polar = image.polar
    if kind == "aris":
        shape = (h["SamplesPerBeam"], h["BeamCount"])
        end_max = aris_reader.WINDOW_END_MAX_M
    else:
        shape = (h["nRanges"], h["nBeams"])
        end_max = oculus_reader.RANGE_MAX_M
    if polar.shape != shape or polar.dtype != np.float32:
        return f"polar {polar.shape} {polar.dtype}, header says {shape}"
    if s.n_range_bins != shape[0] or s.n_beams != shape[1]:
        return f"sonar {s.n_range_bins} x {s.n_beams}, header says {shape}"
    if not np.all(np.isfinite(polar)):
        return "non-finite values in polar"
    lo, hi = s.range_min_m, s.range_max_m
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo < hi <= end_max):
        return f"range window {lo!r}-{hi!r} m"
    r = image.range_m
    if r.shape != (shape[0],) or not (np.all(np.diff(r) > 0) and lo <= r[0] and r[-1] <= hi):
        return "range axis not increasing within the window"
    az = image.azimuth_deg
    if az.shape != (shape[1],) or not np.all(np.isfinite(az)) or np.any(np.abs(az) >= 90.0):
        return f"azimuths {az[:3]}... outside +-90 deg"
    if shape[1] > 1 and not np.all(np.diff(az) < 0):
        return "azimuths not strictly descending"
    if not (0.0 < s.elevation_fov_deg < 180.0):
        return f"elevation aperture {s.elevation_fov_deg!r}"
    return None


def _attempt(fn: Callable[[], object]) -> tuple[object | None, BaseException | None]:
    try:
        return fn(), None
    except _Hang:
        raise
    except BaseException as exc:  # noqa: BLE001 - the check classifies every exception
        if isinstance(exc, KeyboardInterrupt):
            raise
        return None, exc


def _iterate(path: Path) -> tuple[list, BaseException | None]:
    images: list = []
    try:
        for image in readers.read_frames(path):
            images.append(image)
    except _Hang:
        raise
    except Exception as exc:  # noqa: BLE001
        return images, exc
    return images, None


def check_file(path: Path, kind: str, budget_bytes: int, time_limit_s: float = 5.0,
               trace_memory: bool = False, show_dir: Path | None = None) -> Outcome:
    """Read ``path`` every way and check the result (see the module notes).

    Parameters
    ----------
    path : Path
        The mutated recording.
    kind : {"aris", "oculus"}
        What it was before mutation (sets which plausibility limits apply).
    budget_bytes : int
        Most memory a case may allocate (checked when ``trace_memory``).
    time_limit_s : float
        Most seconds a case may take; an alarm stops a hang.
    trace_memory : bool
        Measure the case's allocation peak with ``tracemalloc`` (started and stopped here:
        tracing slows every allocation, so a run traces only some cases).
    show_dir : Path, optional
        Also run ``sonarsim show`` on the case (:func:`check_show`), writing into this folder
        (emptied after); outside the timed and traced part (it draws images, which the readers'
        limits do not cover).
    """
    if trace_memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    previous = signal.signal(signal.SIGALRM, _on_alarm)
    signal.setitimer(signal.ITIMER_REAL, time_limit_s)
    try:
        outcome = _check(path, kind)
    except _Hang:
        outcome = Outcome("hang", None, 0, 0.0, 0, f"no result within {time_limit_s} s")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
    outcome.seconds = time.perf_counter() - t0
    if trace_memory:
        outcome.peak_bytes = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        if outcome.failure is None and outcome.peak_bytes > budget_bytes:
            outcome.failure = f"allocated {outcome.peak_bytes} bytes, budget {budget_bytes}"
    if outcome.failure is None and outcome.seconds > time_limit_s:
        outcome.failure = f"took {outcome.seconds:.2f} s (limit {time_limit_s} s)"
    if outcome.failure is None and show_dir is not None:
        outcome.failure = check_show(path, show_dir)
    return outcome


#: Memory budget of the ``show`` check: a fan image of the ARIS sample (2330 x 607 pixels and
#: its resampling tables) needs more than the readers' 64 MiB.
SHOW_BUDGET_BYTES = 512 * 2**20


def check_show(path: Path, out: Path, budget_bytes: int = SHOW_BUDGET_BYTES) -> str | None:
    """Run ``sonarsim show PATH --frame 0`` in this process; None if it agrees with the readers.

    Under the same memory budget as ``show`` (``budget_bytes``, restored to the caller's after),
    ``read(path, 0)`` and the recording's ``n_frames`` and ``damage`` are what ``show`` must
    report: exit 0 with ``polar.png`` of frame 0's shape, "frame 0 of <n_frames>" and a note
    naming the damage when there is one; or, when ``read(path, 0)`` raises, exit 2 with that
    error on one line and nothing left in ``out``. The one other way to exit 2: the fan image
    does not fit the budget (a mutated range window can ask for a huge one).
    """
    import contextlib
    import io
    import shutil

    from PIL import Image

    from sonarsim.cli.main import main
    from sonarsim.core.memory import memory_budget, set_memory_budget

    previous = memory_budget()
    set_memory_budget(budget_bytes)
    try:
        image, error = _attempt(lambda: readers.read(path, 0))
        n, damage = 0, None
        if error is None:
            with readers.open_recording(path) as recording:
                n, damage = recording.n_frames, recording.damage
        shutil.rmtree(out, ignore_errors=True)
        stderr = io.StringIO()
        with contextlib.redirect_stderr(stderr):
            code = main(["--max-memory", str(budget_bytes), "show", str(path), "--frame", "0",
                         "--out", str(out), "--no-figures"])
    finally:
        set_memory_budget(previous)
    lines = stderr.getvalue().strip().splitlines()
    try:
        if code == 0:
            if error is not None:
                return f"show exits 0, but read(path, 0) raises: {error}"
            if not any(f"frame 0 of {n} from" in line for line in lines):
                return f"show does not say frame 0 of {n}: {lines}"
            notes = [line for line in lines if "note:" in line]
            if (damage is None) != (not notes) or (damage is not None and damage.detail not in notes[0]):
                return f"show's note {notes} does not match the damage {damage}"
            with Image.open(out / "polar.png") as png:
                if png.size[::-1] != image.polar.shape:
                    return f"show's polar.png is {png.size}, frame 0 is {image.polar.shape[::-1]}"
            return None
        if code != 2:
            return f"show exits {code}: {lines}"
        if len(lines) != 1:
            return f"show exits 2 with {len(lines)} lines: {lines}"
        left = sorted(p.name for p in out.rglob("*")) if out.exists() else []
        if left:
            return f"show failed but left {left}"
        if error is None:
            if "memory budget" in lines[0] and "pixel" in lines[0]:
                return None  # the fan image, not the recording
            return f"show exits 2 ({lines[0]}), but read(path, 0) succeeds"
        if str(error) not in lines[0]:
            return f"show's error ({lines[0]}) is not read's ({error})"
        return None
    finally:
        shutil.rmtree(out, ignore_errors=True)


_IMPOSSIBLE = "gives an impossible sonar"


def _check(path: Path, kind: str) -> Outcome:
    def fail(why: str) -> Outcome:
        return Outcome("failure", None, 0, 0.0, 0, why)

    iterated, it_error = _iterate(path)
    if it_error is not None and not isinstance(it_error, RecordingError):
        return fail(f"read_frames raised {type(it_error).__name__}: {it_error}")
    if it_error is not None and _IMPOSSIBLE in str(it_error):
        # The readers wrap SonarConfig's own refusal defensively; reaching it means their
        # checks let an impossible field through without naming it.
        return fail(f"a reader check missed what SonarConfig refused: {it_error}")
    j = len(iterated)
    # read(path, k) for every frame iteration gave, the frame where it stopped, and one more.
    for k in range(j + 2):
        image, error = _attempt(lambda: readers.read(path, k))
        if error is not None and not isinstance(error, RecordingError):
            return fail(f"read(path, {k}) raised {type(error).__name__}: {error}")
        if k < j:
            if error is not None:
                return fail(f"read_frames yielded frame {k}, read(path, {k}) raised: {error}")
            if not np.array_equal(image.polar, iterated[k].polar) or image.config["frame"] != k:
                return fail(f"read(path, {k}) differs from the frame read_frames yielded")
            why = check_plausible(image, kind)
            if why:
                return fail(f"frame {k} read with an implausible geometry: {why}")
        elif k == j:
            if error is None:
                stop = f"raised {it_error}" if it_error else "stopped"
                return fail(f"read_frames {stop} at frame {k}, but read(path, {k}) succeeds")
            if it_error is None and (j == 0 or "out of range" not in str(error)):
                return fail(f"read_frames stopped silently at frame {k}; read(path, {k}) raises: {error}")
            if it_error is not None and type(it_error) is not type(error):
                return fail(f"at frame {k} read_frames raised {type(it_error).__name__}, read "
                            f"{type(error).__name__}")
        elif error is None:  # nothing after the first unreadable frame is a good frame
            return fail(f"read_frames stopped after {j} frames, but read(path, {k}) succeeds")
    why = _check_open(path, j, it_error)
    if why:
        return fail(why)
    if it_error is None:
        return Outcome("ok", None, j, 0.0, 0)
    return Outcome("partial" if j else "refused", _error_key(it_error), j, 0.0, 0)


def _check_open(path: Path, j: int, it_error: BaseException | None) -> str | None:
    """None if ``open_recording`` / ``n_frames`` agree with iteration (``j`` frames, then
    ``it_error``), else what differs."""
    opened, open_error = _attempt(lambda: readers.open_recording(path))
    if open_error is not None:
        if not isinstance(open_error, RecordingError):
            return f"open_recording raised {type(open_error).__name__}: {open_error}"
        if j:
            return f"open_recording refuses the file ({open_error}), but read_frames gave {j} frames"
        if str(open_error) != str(it_error):
            return f"open_recording raised {open_error}, read_frames {it_error}"
        counted, count_error = _attempt(lambda: readers.n_frames(path))
        if count_error is None or str(count_error) != str(open_error):
            return f"n_frames(path) gave {counted if count_error is None else count_error}, open_recording raised {open_error}"
        return None
    with opened:
        n, n_error = _attempt(lambda: opened.n_frames)
        damage, damage_error = _attempt(lambda: opened.damage)
    for what, exc in (("n_frames", n_error), ("damage", damage_error)):
        if exc is not None:
            return f"open_recording(path).{what} raised {type(exc).__name__}: {exc}"
    if n != j:
        return f"open_recording(path).n_frames is {n}, but read_frames gave {j} frames"
    counted, count_error = _attempt(lambda: readers.n_frames(path))
    if counted != n:
        return f"n_frames(path) gave {counted if count_error is None else count_error}, the open recording {n}"
    if damage is None:
        # A clean end: iteration ended without error, or a file without frames raised.
        if it_error is not None and j:
            return f"read_frames raised after {j} frames ({it_error}), but the recording reports no damage"
        return None
    if not isinstance(damage, RecordingError) or str(damage) != str(it_error):
        return f"the recording's damage ({damage}) is not the error read_frames ended with ({it_error})"
    return None
