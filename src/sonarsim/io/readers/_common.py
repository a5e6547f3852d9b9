"""Shared pieces of the recording readers: the error type and careful byte access.

Recordings come from disks and networks: files are cut short by a full disk or a crash, copied
half-way, or are not recordings at all. Every read here checks that the bytes exist before
decoding them, so that a bad file ends with a :class:`RecordingError` naming the file, the
frame (or message) and the field, never with an ``IndexError`` or a ``struct.error``.
"""

from __future__ import annotations

import math
import operator
import os
from collections.abc import Iterator
from typing import BinaryIO

from ...errors import SonarsimError

__all__ = ["RecordingError", "recording_repr"]


class RecordingError(SonarsimError, ValueError):
    """A sonar recording is unreadable: truncated, corrupt, of an unknown kind or unsupported.

    Parameters
    ----------
    source : str or os.PathLike
        The file.
    message : str
        What is wrong (and, where it helps, what would be right).
    where : str, optional
        The part of the file, e.g. ``"frame 3"`` or ``"message 2 (byte 182016)"``.
    field : str, optional
        The header field at fault, e.g. ``"PingMode"``.

    Attributes
    ----------
    source, where, field, detail : str or None
        The parts of the message, for programs that want them separately.
    """

    def __init__(
        self,
        source: str | os.PathLike,
        message: str,
        where: str | None = None,
        field: str | None = None,
    ) -> None:
        self.source = os.fspath(source)
        self.where = where
        self.field = field
        self.detail = message
        parts = [self.source]
        if where:
            parts.append(where)
        if field:
            parts.append(field)
        super().__init__(": ".join(parts) + ": " + message)


def frame_index(frame: object) -> int:
    """``frame`` as an int; bools and floats are refused (``frame=1.0`` is a caller's bug)."""
    if isinstance(frame, bool):
        raise TypeError(f"frame must be an integer, got {frame!r}")
    try:
        return operator.index(frame)  # accepts int and numpy integers only
    except TypeError:
        raise TypeError(f"frame must be an integer, got {type(frame).__name__} {frame!r}") from None


def read_at(
    handle: BinaryIO,
    offset: int,
    size: int,
    file_size: int,
    source: str,
    where: str,
    what: str,
) -> bytes:
    """Read exactly ``size`` bytes at ``offset`` or raise a :class:`RecordingError`.

    Parameters
    ----------
    handle : binary file
        Open for reading; seekable.
    offset, size : int
        Byte range wanted.
    file_size : int
        Size of the file (known from ``fstat``), to word the error precisely.
    source, where : str
        Error context (file name; frame or message).
    what : str
        Name of the part being read, e.g. ``"frame header (1024 bytes)"``.
    """
    if offset + size > file_size:
        missing = offset + size - file_size
        raise RecordingError(
            source,
            f"truncated: the file ends at byte {file_size}, {missing} bytes short of the end "
            f"of the {what} (bytes {offset}-{offset + size - 1})",
            where,
        )
    handle.seek(offset)
    data = handle.read(size)
    if len(data) != size:  # the file shrank while we read it
        raise RecordingError(
            source, f"truncated: read {len(data)} of the {size} bytes of the {what}", where
        )
    return data


def check_range_window(
    source: str,
    where: str,
    field: str,
    start_m: float,
    length_m: float,
    end_max_m: float,
    derivation: str = "",
) -> None:
    """Refuse a range window that no sonar records, before it reaches :class:`SonarConfig`.

    Parameters
    ----------
    source, where : str
        Error context (file name; frame or ping).
    field : str
        The header field named in the error (the one that sets the window's far end).
    start_m, length_m : float
        The window, in metres.
    end_max_m : float
        The farthest window end the format's sonars can produce (the reader's limit).
    derivation : str, optional
        How the window follows from the header, appended to the message in parentheses.

    Raises
    ------
    RecordingError
        A non-finite or negative start, a non-finite or non-positive length, or an end beyond
        ``end_max_m``.
    """
    how = f" ({derivation})" if derivation else ""
    if not (math.isfinite(start_m) and start_m >= 0.0):
        raise RecordingError(source, f"gives a window start of {start_m!r} m{how}", where, field)
    if not (math.isfinite(length_m) and length_m > 0.0):
        raise RecordingError(source, f"gives a window length of {length_m!r} m{how}", where, field)
    end_m = start_m + length_m
    if not end_m <= end_max_m:
        raise RecordingError(
            source,
            f"gives a range window of {start_m:.6g}-{end_m:.6g} m{how}, but these sonars record "
            f"no farther than {end_max_m:g} m",
            where, field,
        )


def check_within(
    source: str,
    where: str,
    field: str,
    value: float,
    limits: tuple[float, float],
    unit: str,
    what: str,
) -> None:
    """Refuse a header value outside the interval real devices produce.

    Parameters
    ----------
    source, where, field : str
        Error context (file name; frame or ping; header field).
    value : float
        The decoded value (NaN and infinities are refused too).
    limits : (float, float)
        Inclusive interval allowed.
    unit : str
        Unit shown after the numbers ("us", "m", "" for counts).
    what : str
        What the interval is, e.g. ``"the sample periods ARIS sonars use"``.

    Raises
    ------
    RecordingError
        ``"<file>: <where>: <field>: 4294967295 us is outside the allowed 1 to 400 us (...)"``.
    """
    lo, hi = limits
    if not (math.isfinite(value) and lo <= value <= hi):
        u = f" {unit}" if unit else ""
        raise RecordingError(
            source, f"{value!r}{u} is outside the allowed {lo:g} to {hi:g}{u} ({what})", where,
            field,
        )


def require_frame_memory(
    source: str, where: str, field: str, n_rows: int, n_beams: int, read_bytes: int
) -> None:
    """Refuse a frame whose arrays would exceed the memory budget (:mod:`sonarsim.core.memory`).

    A frame costs ``read_bytes`` per value while it is decoded, and then what its
    :class:`~sonarsim.config.sonar.SonarConfig` plans for the images made from it (a few dozen
    float32 images of the same size, ``IMAGES_PER_FRAME``): checking both here, before the
    samples are read, names the header field at fault rather than ``sonar.n_range_bins``.

    Parameters
    ----------
    source, where, field : str
        Error context; ``field`` is the count that sets the size.
    n_rows, n_beams : int
        The frame's range samples and beams.
    read_bytes : int
        Bytes held per value while decoding (raw and float32 copies).

    Raises
    ------
    RecordingError
        Naming ``field``, the size and the budget (and how to raise it).
    """
    from ...config.sonar import IMAGES_PER_FRAME
    from ...core.memory import require
    from ...errors import ConfigError

    values = float(n_rows) * n_beams
    try:
        require(values * (read_bytes + 4 * IMAGES_PER_FRAME),
                f"a frame of {n_rows} x {n_beams} values and its images", field)
    except ConfigError as exc:
        raise RecordingError(source, exc.detail, where, field) from None


def require_memory(source: str, nbytes: float, what: str, field: str) -> None:
    """Refuse an array beyond the memory budget (:mod:`sonarsim.core.memory`) before allocating it."""
    from ...core.memory import require
    from ...errors import ConfigError

    try:
        require(nbytes, what, field)
    except ConfigError as exc:
        raise RecordingError(source, exc.detail, None, field) from None


class Recording:
    """An open recording file, read on demand with seeks: the rule every format follows.

    **Good frames.** A recording is read from its start, and the first frame that cannot be
    read ends it: the frames before it are the recording's good frames, everywhere alike.
    :attr:`n_frames` counts them; :meth:`read` returns them (and refuses every frame from the
    first unreadable one on, naming it); iteration yields them, then raises the error that
    ended them; :attr:`damage` is that error (``None`` for a file that ends cleanly). So a
    file damaged at frame ``k`` (a corrupt or impossible header, a cut, frames that change
    size) is a recording of ``k`` frames that says why it stops there, whichever way it is
    read. A file whose very first frame is unreadable has nothing to offer and is refused
    when opened, with that frame's error; a file that ends cleanly without any frame opens,
    with ``n_frames == 0``, and reading it raises.

    Frames are checked lazily, in order, as far as a call needs (``read(k)`` checks the
    headers of frames ``0 .. k``, never their samples; :attr:`n_frames` and :attr:`damage`
    check them all), and what was found is kept.

    Subclasses index the file in :meth:`_open` and implement :meth:`_check` (is frame ``k``
    there and good?), :meth:`_read` (decode a good frame) and :meth:`_no_frames` (the error
    for a clean file without frames). The file is held open (closed by :meth:`close` or a
    ``with`` block) and closed again if opening fails.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Raises
    ------
    RecordingError
        The file is not of the subclass's format, or its first frame is unreadable.
    OSError
        The file cannot be opened.
    """

    format = ""
    #: What one frame is called in messages, and several.
    unit, units = "frame", "frames"
    #: The film a frame is: ``"polar"`` (a SonarImage), or a one-ping ``"waterfall"``,
    #: ``"soundings"`` or ``"envelope"`` (:mod:`sonarsim.image.films`).
    film = "polar"

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = path
        self._source = os.fspath(path)
        self._handle = open(path, "rb")  # noqa: SIM115 (held open for seeks; close())
        try:
            self._file_size = os.fstat(self._handle.fileno()).st_size
            self._good = 0  # frames 0 .. _good - 1 are checked and readable
            self._ended = False  # the check reached the end: a clean end or the damage
            self._damage: RecordingError | None = None
            self._open()
            if self._verify_to(1) == 0 and self._damage is not None:
                raise self._damage_error()
        except BaseException:
            self._handle.close()
            raise

    # -- what a format provides --------------------------------------------------------------

    def _open(self) -> None:
        """Read what the format needs to find its frames (file header, first frame's size)."""
        raise NotImplementedError

    def _check(self, k: int) -> bool:
        """Check frame ``k`` (called once per frame, in order, after frames ``0 .. k - 1``).

        Returns
        -------
        bool
            True if frame ``k`` exists and :meth:`_read` can decode it; False if the file ends
            cleanly before it.

        Raises
        ------
        RecordingError
            Frame ``k`` is damaged: exactly the error reading it gives.
        """
        raise NotImplementedError

    def _read(self, k: int):
        """Decode frame ``k``, already found good by :meth:`_check`."""
        raise NotImplementedError

    def _no_frames(self, k: int) -> RecordingError:
        """The error for frame ``k`` of a file that ends cleanly without any frame."""
        return RecordingError(self._source, f"{self.unit} {k} requested, but the file has no {self.units}")

    # -- the rule ----------------------------------------------------------------------------

    def _verify_to(self, n: float) -> int:
        """Check frames in order until ``n`` are good or the file ends; returns the good count."""
        while self._good < n and not self._ended:
            try:
                more = self._check(self._good)
            except RecordingError as exc:
                self._damage = exc
                self._ended = True
                break
            if more:
                self._good += 1
            else:
                self._ended = True
        return self._good

    def _damage_error(self) -> RecordingError:
        # A new exception each time it is raised (its traceback is the caller's), same content.
        d = self._damage
        assert d is not None
        return RecordingError(d.source, d.detail, d.where, d.field)

    @property
    def n_frames(self) -> int:
        """Number of good frames: those before the first unreadable one (see :attr:`damage`).

        Checks every frame's header the first time (not their samples).
        """
        return self._verify_to(math.inf)

    @property
    def damage(self) -> RecordingError | None:
        """Why the recording ends after :attr:`n_frames` frames, or ``None`` if it ends cleanly.

        The :class:`RecordingError` that reading frame ``n_frames`` raises: a cut (truncated
        last frame or message), a corrupt or impossible header, a frame of another size, a
        frame beyond the memory budget. Its ``where``, ``field`` and ``detail`` name the frame
        (or message), the header field and what is wrong.
        """
        self._verify_to(math.inf)
        return self._damage

    def __len__(self) -> int:
        return self.n_frames

    def read(self, frame: int = 0):
        """Frame ``frame`` (0-based) as a :class:`~sonarsim.image.result.SonarImage`.

        Raises
        ------
        RecordingError
            ``frame`` is the first unreadable frame (its own error), lies beyond it, or is out
            of range (the message gives the good frames, and the damage after them).
        TypeError
            ``frame`` is not an integer.
        """
        k = frame_index(frame)
        if k >= 0 and self._verify_to(k + 1) > k:
            return self._read(k)
        raise self._unreadable(k)

    def _unreadable(self, k: int) -> RecordingError:
        """The error for frame ``k``, which is not among the good frames."""
        n = self.n_frames
        if self._damage is not None and k == n:
            return self._damage_error()
        if n == 0:
            return self._no_frames(k)
        message = f"{self.unit} {k} is out of range: the file has {n} {self.units} (valid: 0 to {n - 1})"
        if self._damage is not None:
            d = self._damage
            what = ": ".join(part for part in (d.where, d.field, d.detail) if part)
            message += f"; it is damaged after them ({what})"
        return RecordingError(self._source, message)

    def __iter__(self) -> Iterator:
        """Every good frame in order, then the error that ends them (:attr:`damage`), if any.

        Iteration fails exactly where :meth:`read` fails first: a file without frames raises
        (as ``read(0)`` does) rather than yielding nothing.
        """
        k = 0
        while self._verify_to(k + 1) > k:
            yield self._read(k)
            k += 1
        if self._damage is not None or k == 0:
            raise self._unreadable(k)

    def close(self) -> None:
        """Close the file."""
        self._handle.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- pictures (through the frames' own, sonarsim.image.display's hooks) -------------------

    def __repr__(self) -> str:
        return recording_repr(self)

    def _repr_png_(self) -> bytes:
        """What a notebook shows: the annotated fan of frame 0, in the device's counts."""
        return self.read(0)._repr_png_()

    def plot(self, frame: int = 0, ax=None, **options):
        """Draw frame ``frame``'s annotated figure on ``ax`` (default: a new pyplot figure);
        ``options`` as :meth:`sonarsim.image.result.SonarImage.plot` (``kind="polar"``, ...).

        Returns
        -------
        matplotlib.axes.Axes
        """
        return self.read(frame).plot(ax, **options)

    def save(self, path, frame: int = 0, **options) -> None:
        """Write frame ``frame``'s annotated figure: PNG, SVG or PDF after the suffix of ``path``."""
        self.read(frame).save(path, **options)

    def to_pil(self, frame: int = 0, **options):
        """Frame ``frame`` as an exact-pixel PIL image (fan, or ``kind="polar"``), in the device's
        counts as ``sonarsim show`` writes them."""
        return self.read(frame).to_pil(**options)


class FilmRecording(Recording):
    """A recording whose frames are pings of a film (:mod:`sonarsim.image.films`), not polar
    frames: the picture hooks of :class:`Recording` (fan images) do not apply to it."""

    def __repr__(self) -> str:
        name = os.path.basename(os.fspath(self.path))
        try:
            n = self.n_frames
        except Exception as exc:  # a repr must not raise
            return f"{type(self).__name__}({name!r}: unreadable: {exc})"
        more = f", damaged after them: {self._damage.detail}" if self._damage is not None else ""
        return f"{type(self).__name__}({name!r}: {n} {self.units}, film {self.film!r}{more})"

    def _repr_png_(self):
        return None  # no fan to show

    def _ping_range(self, pings) -> range:
        """The good pings selected by ``pings`` (None: all; a slice; an int), as a range."""
        n = self.n_frames
        if pings is None:
            return range(n)
        if isinstance(pings, slice):
            r = range(*pings.indices(n))
            if pings.stop is not None and pings.stop > n and self._damage is not None:
                raise self._unreadable(n)
            return r
        k = frame_index(pings)
        self._verify_to(k + 1)
        if not 0 <= k < n:
            raise self._unreadable(k)
        return range(k, k + 1)

    def _not_polar(self, what: str):
        raise RecordingError(self._source, f"{what} draws FLS frames; this recording's pings are a {self.film} "
                             "(sonarsim.image.films)")

    def plot(self, frame: int = 0, ax=None, **options):
        self._not_polar("plot")

    def save(self, path, frame: int = 0, **options) -> None:
        self._not_polar("save")

    def to_pil(self, frame: int = 0, **options):
        self._not_polar("to_pil")


def recording_repr(recording: Recording) -> str:
    """One or two lines about an open recording: format, file, frames, grid of its first frame.

    Plain text, nothing drawn: it lives with the recordings (re-exported by
    :mod:`sonarsim.plot.notebook`, its former home).
    """
    import numpy as np

    name = os.path.basename(os.fspath(recording.path))
    head = f"{type(recording).__name__}({name!r}"
    try:
        n = recording.n_frames
        image = recording.read(0)
    except Exception as exc:  # a repr must not raise: say what is wrong instead
        return f"{head}: unreadable: {exc})"
    s = image.sonar
    rows, cols = np.shape(image.polar)
    return (f"{head}: {n} frames of {rows} ranges x {cols} beams,\n  {s.range_min_m:.4g}-{s.range_max_m:.4g} m, "
            f"{float(s.beam_edges_deg[0]):+.4g} to {float(s.beam_edges_deg[-1]):+.4g} deg)")
