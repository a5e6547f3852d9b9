"""Reader of Imagenex 852 echo-sounder files (``.852``) into :class:`~sonarsim.image.films.Envelope`.

A file is a sequence of fixed-size records, one per ping (big-endian where multi-byte;
Imagenex's 852 file format as CIDCO's Imagenex852 reader describes it, checked on the test
data ``imagenex852_2016-11-18.852``)::

    file header (100 bytes)   '852' @0, nToReadIndex u8 @3 (0: no echo data, 2: 252 bytes,
                              3: 500 bytes), TotalBytes u16 @4 (the record size: 128, 384
                              or 640), nToRead u16 @6 (echo bytes + 13), date char[12] @8
                              ("18-Nov-2016"), time char[9] @20 ("19:29:10"), hundredths
                              char[4] @29 (".17"), reserved @33, mode @37, start gain @38,
                              pulse length u8 @44 (us), SoundSpeed u16 @46 (bit 15 set:
                              bits 14-0 are c x 10; clear: 1500 m/s), user text @48,
                              operating frequency @87, head id @88
    return header (12 bytes)  'IGX' @100, head id @103, serial status @104, 2 reserved,
                              range u8 @107 (m), profile range @108 and data bytes @110, each
                              two 7-bit bytes (low first: (hi & 0x7F) << 7 | (lo & 0x7F))
    echo data                 data-bytes u8 samples @112 (nearest first), then 0xFC, then zeros

The range window is ``[0, range]`` (the return header's range, 10 m in the test data), the
samples equally spaced over it. The profile range is the sounder's own bottom detection in
centimetres: on the test data it lies where each ping's envelope peaks (median difference
-1 cm over the 452 pings that have one), and 0 where the sounder found no bottom (NaN here).
The sound speed reads 1460.0 m/s (0xB908) in the test data. The file records no attitude, so
the geometry has the time, the sound speed and the window only.

Damage follows :class:`~sonarsim.io.readers._common.Recording`: a record with a bad magic
('852', 'IGX', the 0xFC terminator), an impossible field, another size than record 0, or cut
short, ends the good pings.
"""

from __future__ import annotations

import calendar
import math
import struct

import numpy as np

from ._common import FilmRecording, RecordingError, check_within, require_memory

__all__ = ["MAGIC", "RANGE_M_LIMITS", "SOUND_SPEED_LIMITS", "ImagenexRecording", "imagenex_problem", "is_imagenex852", "read_envelope"]

#: The first bytes of every record.
MAGIC = b"852"
RETURN_MAGIC = b"IGX"
FILE_HEADER_SIZE = 100
RETURN_HEADER_SIZE = 12
TERMINATOR = 0xFC
#: nToReadIndex -> (record size, echo bytes).
RECORD_KINDS = {0: (128, 0), 2: (384, 252), 3: (640, 500)}
#: Range settings allowed, metres (the 852 offers 5 to 50 m; margin).
RANGE_M_LIMITS = (1.0, 200.0)
#: Sound speed allowed, m/s.
SOUND_SPEED_LIMITS = (1300.0, 1800.0)
_MONTHS = {m: i for i, m in enumerate(("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov",
                                        "Dec"), 1)}


def is_imagenex852(head: bytes) -> bool:
    """Whether ``head`` (at least 103 bytes) starts like an Imagenex 852 record."""
    return head[:3] == MAGIC and head[FILE_HEADER_SIZE:FILE_HEADER_SIZE + 3] == RETURN_MAGIC


def imagenex_problem(head: bytes) -> str | None:
    """Why ``head``, which starts with the record magic '852', is no 852 file sonarsim can read;
    None when it does not start so (or is one)."""
    if head[:3] != MAGIC or is_imagenex852(head):
        return None
    if len(head) < FILE_HEADER_SIZE + 3:
        return (f"truncated: it starts like an Imagenex 852 record ('852') but ends at byte {len(head)}, before "
                f"the return header ('IGX' at byte {FILE_HEADER_SIZE})")
    return (f"it starts like an Imagenex 852 record ('852') but bytes {FILE_HEADER_SIZE}-{FILE_HEADER_SIZE + 2} "
            f"hold {head[FILE_HEADER_SIZE:FILE_HEADER_SIZE + 3]!r}, not the return header's 'IGX'")


def _seven_bit(lo: int, hi: int) -> int | None:
    if (lo | hi) & 0x80:
        return None
    return (hi << 7) | lo


class ImagenexRecording(FilmRecording):
    """An open Imagenex 852 file; a frame is one ping (one record).

    ``read(k)`` gives ping ``k`` as a one-ping :class:`~sonarsim.image.films.Envelope`;
    :meth:`envelope` gives a range of pings.

    Raises
    ------
    RecordingError
        Not an 852 file, or its first record is unreadable.
    """

    format = "imagenex852"
    film = "envelope"
    unit, units = "ping", "pings"

    def _open(self) -> None:
        self._record: int | None = None  # record 0's size: every record must have it
        self._pings: dict[int, dict] = {}
        if self._file_size == 0:
            raise RecordingError(self._source, "the file is empty")

    def _check(self, k: int) -> bool:
        size = self._record
        offset = 0 if size is None else k * size
        if offset == self._file_size:
            return False
        where = f"ping {k} (byte {offset})"
        src = self._source
        if offset + FILE_HEADER_SIZE + RETURN_HEADER_SIZE > self._file_size:
            raise RecordingError(src, f"truncated: the file ends at byte {self._file_size}, inside the record's "
                                 "headers", where)
        self._handle.seek(offset)
        head = self._handle.read(FILE_HEADER_SIZE + RETURN_HEADER_SIZE)
        if head[:3] != MAGIC:
            raise RecordingError(src, f"{head[:3]!r} is not the record magic {MAGIC!r}", where, "magic")
        kind = head[3]
        if kind not in RECORD_KINDS:
            raise RecordingError(src, f"{kind} is not an 852 record kind (0, 2 or 3)", where, "nToReadIndex")
        rec_size, n_data = RECORD_KINDS[kind]
        (total,) = struct.unpack_from(">H", head, 4)
        if total != rec_size:
            raise RecordingError(src, f"{total} bytes, but nToReadIndex {kind} means {rec_size}", where, "TotalBytes")
        if size is not None and rec_size != size:
            raise RecordingError(src, f"a record of {rec_size} bytes, but ping 0's has {size}; the pings of one "
                                 "envelope must share their samples", where, "TotalBytes")
        if offset + rec_size > self._file_size:
            raise RecordingError(src, f"truncated: the {rec_size}-byte record needs the file to reach byte "
                                 f"{offset + rec_size}, but it ends at byte {self._file_size}", where)
        if head[100:103] != RETURN_MAGIC:
            raise RecordingError(src, f"{head[100:103]!r} is not the return header's {RETURN_MAGIC!r}", where,
                                 "IGX")
        range_m = float(head[107])
        check_within(src, where, "range", range_m, RANGE_M_LIMITS, "m", "the range settings of 852 sounders")
        profile = _seven_bit(head[108], head[109])
        n_bytes = _seven_bit(head[110], head[111])
        if profile is None:
            raise RecordingError(src, "a high bit is set in a 7-bit byte", where, "profile range")
        if n_bytes != n_data:
            raise RecordingError(src, f"{n_bytes} echo bytes, but nToReadIndex {kind} means {n_data}", where,
                                 "data bytes")
        if profile > range_m * 100.0:
            raise RecordingError(src, f"a bottom at {profile} cm lies beyond the {range_m:g} m window", where,
                                 "profile range")
        self._handle.seek(offset + FILE_HEADER_SIZE + RETURN_HEADER_SIZE + n_data)
        end = self._handle.read(1)
        if end != bytes([TERMINATOR]):
            raise RecordingError(src, f"{end.hex() or 'nothing'} where the echo data's terminator 0xfc belongs "
                                 f"(byte {FILE_HEADER_SIZE + RETURN_HEADER_SIZE + n_data} of the record)", where,
                                 "terminator")
        (raw_c,) = struct.unpack_from(">H", head, 46)
        c = (raw_c & 0x7FFF) / 10.0 if raw_c & 0x8000 else 1500.0
        check_within(src, where, "SoundSpeed", c, SOUND_SPEED_LIMITS, "m/s", "sound speeds in water")
        t = _time(head)
        if t is None:
            raise RecordingError(src, f"{head[8:33]!r} is not a date and time like '18-Nov-2016 19:29:10.17'",
                                 where, "date")
        self._record = rec_size
        self._pings[k] = {"offset": offset, "n": n_data, "range_m": range_m, "time_s": t, "sound_speed": c,
                          "bottom_m": profile / 100.0 if profile else math.nan, "pulse_us": head[44],
                          "head_id": head[88]}
        if k == 0 and n_data == 0:
            raise RecordingError(src, "the records carry no echo data (nToReadIndex 0)", where, "nToReadIndex")
        if k > 0 and range_m != self._pings[0]["range_m"]:
            raise RecordingError(src, f"a {range_m:g} m window, but ping 0 has {self._pings[0]['range_m']:g} m; the "
                                 "pings of one envelope share their window", where, "range")
        return True

    def _envelope(self, ks: range):
        from ...image.films import Envelope, PingGeometry

        size, n = self._record, self._pings[0]["n"]
        require_memory(self._source, (size + 4.0 * n) * len(ks), f"an envelope of {len(ks)} pings x {n} samples",
                       "nToReadIndex")
        first = self._pings[ks[0]]["offset"]
        # One read for consecutive pings (every record is good and of one size): the echo bytes
        # of each are one column block of the (pings, record) array.
        self._handle.seek(first)
        raw = np.frombuffer(self._handle.read(len(ks) * size), np.uint8).reshape(len(ks), size)
        samples = raw[:, FILE_HEADER_SIZE + RETURN_HEADER_SIZE:FILE_HEADER_SIZE + RETURN_HEADER_SIZE + n]
        p = [self._pings[k] for k in ks]
        r = p[0]["range_m"]
        geometry = PingGeometry.of(len(ks), time_s=[q["time_s"] for q in p],
                                   sound_speed_m_s=[q["sound_speed"] for q in p], range_min_m=0.0, range_max_m=r)
        return Envelope(samples=samples.astype(np.float32), range_min_m=0.0, range_max_m=r,
                        bottom_range_m=np.array([q["bottom_m"] for q in p]), geometry=geometry, source=self._source)

    def _read(self, k: int):
        return self._envelope(range(k, k + 1))

    def read(self, frame: int = 0):
        """Ping ``frame`` as a one-ping Envelope (``samples`` ``(1, n_samples)`` float32 counts)."""
        return super().read(frame)

    def envelope(self, pings=None):
        """Pings ``pings`` (None: every good ping; a slice; an int) as one Envelope.

        Returns
        -------
        Envelope
            ``samples`` ``(n, n_samples)`` float32; ``bottom_range_m`` ``(n,)`` (NaN: none found).
        """
        ks = self._ping_range(pings)
        if len(ks) == 0:
            raise RecordingError(self._source, f"pings {pings!r} select none of the {self.n_frames} good pings")
        if ks.step != 1:
            parts = [self._envelope(range(k, k + 1)) for k in ks]
            from ...image.films import Envelope, PingGeometry

            return Envelope(samples=np.concatenate([e.samples for e in parts]), range_min_m=0.0,
                            range_max_m=parts[0].range_max_m,
                            bottom_range_m=np.concatenate([e.bottom_range_m for e in parts]),
                            geometry=PingGeometry.concatenate([e.geometry for e in parts]), source=self._source)
        return self._envelope(ks)


def _time(head: bytes) -> float | None:
    """Seconds since 1970 from the record's date, time and hundredths (taken as UTC)."""
    try:
        date = head[8:20].split(b"\0")[0].decode("ascii")
        clock = head[20:29].split(b"\0")[0].decode("ascii")
        hundredths = head[29:33].split(b"\0")[0].decode("ascii")
        day, month, year = date.split("-")
        hh, mm, ss = (int(v) for v in clock.split(":"))
        frac = float(hundredths) if hundredths else 0.0
        if not (0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 61 and 0.0 <= frac < 1.0):
            return None
        return calendar.timegm((int(year), _MONTHS[month], int(day), hh, mm, ss, 0, 0, 0)) + frac
    except (ValueError, KeyError, UnicodeDecodeError, OverflowError):
        return None


def read_envelope(path, pings=None):
    """The pings ``pings`` of an Imagenex 852 file as an :class:`~sonarsim.image.films.Envelope`."""
    with ImagenexRecording(path) as recording:
        return recording.envelope(pings)
