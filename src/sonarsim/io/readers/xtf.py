"""Reader of XTF (eXtended Triton Format) side-scan recordings into :class:`~sonarsim.image.films.Waterfall`.

Layout (little-endian, packed; Triton Imaging's XTF specification as pyxtf implements it; the
structures are decoded with pyxtf's ``ctypes`` definitions, the optional ``xtf`` extra)::

    file header (1024 bytes)    FileFormat u8 @0 = 0x7B (123), SystemType @1, ...,
                                NavUnits u16 @152 (0 metres, 3 lat/lon),
                                NumberOfSonarChannels u16 @154, ..., ChanInfo[6] @256
                                (TypeOfChannel: 1 port, 2 starboard; BytesPerSample)
    packets, back to back       MagicNumber u16 @0 = 0xFACE, HeaderType u8 @2 (0 sonar,
                                3 attitude, 65 R2Sonic bathymetry, 107 raw position),
                                NumChansToFollow u16 @4, NumBytesThisRecord u32 @10
    a sonar ping (type 0)       a 256-byte ping header (date and time, SoundVelocity,
                                SensorDepth, SensorPrimaryAltitude, SensorPitch, SensorRoll,
                                SensorHeading, SensorSpeed, position), then per channel a
                                64-byte channel header (ChannelNumber, SlantRange, TimeDelay,
                                TimeDuration, NumSamples) and NumSamples x BytesPerSample samples

A frame of :class:`XtfSidescanRecording` is one sonar ping (a type-0 packet; other packets are
skipped). Its port and starboard channels (``ChanInfo[ChannelNumber].TypeOfChannel`` 1 and 2)
become ``samples[0]`` and ``samples[1]``; XTF stores port samples far -> nadir and starboard
nadir -> far, so the port line is reversed: sample 0 is the nearest on both sides.

Geometry, per ping, in sonarsim's conventions (:mod:`sonarsim.image.films`), as checked on the
Iver2 / Sea Scan HDS recording in the test data (``iver2_seascan_pings_0-179.xtf``):

* ``time_s``: the ping header's Year, Month, Day, Hour, Minute, Second and HSeconds (UTC,
  seconds since 1970);
* ``sound_speed_m_s``: XTF's ``SoundVelocity`` is the one-way value c/2 in files like this one:
  the channels' ``SlantRange`` (29.98 m) is ``TimeDuration`` (0.03998 s, the two-way listening
  time) x ``SoundVelocity`` (750): hence c = 2 x 750 = 1500 m/s. The reader decides per ping:
  when ``SlantRange`` = ``TimeDuration`` x ``SoundVelocity`` (within 2 %) the field is c/2 and
  is doubled; when it is ``TimeDuration`` x ``SoundVelocity`` / 2 it is c; without a
  ``TimeDuration``, a value under 1000 m/s is taken as c/2;
* range window ``[TimeDelay c / 2, SlantRange]``, metres;
* ``altitude_m`` = ``SensorPrimaryAltitude``, ``depth_m`` = ``SensorDepth``;
* ``pitch_deg`` = -``SensorPitch``: XTF's pitch is positive nose UP, sonarsim's nose DOWN. The
  data say so: over the file the vehicle descends (``SensorDepth`` 14.0 -> 19.9 m in 22 s,
  0.27 m/s, at 0.96 m/s over ground from its positions: a path 15 deg below the horizontal)
  while ``SensorPitch`` reads -20 to -23 deg, i.e. nose down by 20-23 deg;
* ``roll_deg`` = ``SensorRoll``: XTF's roll is positive "roll to starboard" (starboard down,
  port up), which is REP-103's positive roll (port up). The data agree, weakly (the rolls are
  only -1.4 to 3.9 deg): just beyond nadir (slant ranges 1.0-1.1 x the altitude) the
  starboard line is brighter than the port line when the roll is positive (correlation of the
  log ratio with the roll +0.60 over the pings, +0.79 with slow trends removed): the lowered
  side's beam looks closer to nadir. The multibeam recording in XTF confirms the convention
  firmly for its attitude packets (:mod:`sonarsim.io.readers.r2sonic`);
* ``heading_deg`` = ``SensorHeading`` (compass degrees);
* ``speed_m_s`` = ``SensorSpeed`` in knots x 0.514444: XTF gives knots, and the data agree
  (1.71-1.97, while the logged positions advance 21 m in 22 s: 0.96 m/s = 1.87 kn);
* position: ``NavUnits`` 3: ``latitude_deg`` = ``SensorYcoordinate``, ``longitude_deg`` =
  ``SensorXcoordinate``, and ``x_m``, ``y_m`` east and north of the first ping with a position
  (equirectangular, Earth radius 6371 km: side-scan lines span metres, not degrees);
  ``NavUnits`` 0: ``x_m``, ``y_m`` are the coordinates themselves (metres), latitude and
  longitude NaN. A latitude beyond 90 deg or a longitude beyond 360 deg is NaN.

Unknown values are NaN. A ping whose position, depth, altitude, pitch, roll, heading and speed
are all exactly 0 carries no navigation at all (ping 0 of the test file: the vehicle's
computer had not sent any yet), and all of them are NaN; otherwise a position of (0, 0) and an
altitude of 0 (no bottom lock: a side-scan is never at altitude 0) are NaN.

Damaged files follow :class:`~sonarsim.io.readers._common.Recording`: the pings before the
first packet that cannot be read (cut short, a bad ``0xFACE``, an impossible header, a ping of
another size than ping 0) are the recording's good pings. Header values are checked against
module limits (``N_SAMPLES_LIMITS``, ``SLANT_RANGE_M_LIMITS``, ``SOUND_SPEED_LIMITS``) and
the memory budget before samples are read.
"""

from __future__ import annotations

import calendar
import math
import struct
from dataclasses import dataclass

import numpy as np

from ...errors import SonarsimError
from ._common import (FilmRecording, RecordingError, check_within, read_at, require_frame_memory,
                      require_memory)

__all__ = [
    "FILE_HEADER_SIZE",
    "PACKET_MAGIC",
    "XTF_FILE_FORMAT",
    "N_SAMPLES_LIMITS",
    "SLANT_RANGE_M_LIMITS",
    "SOUND_SPEED_LIMITS",
    "XtfSidescanRecording",
    "is_xtf",
    "xtf_problem",
    "xtf_kind",
    "read_waterfall",
]

#: ``FileFormat`` of an XTF file header (its first byte).
XTF_FILE_FORMAT = 0x7B
#: The magic number that starts every XTF packet.
PACKET_MAGIC = 0xFACE
FILE_HEADER_SIZE = 1024
PACKET_START_SIZE = 14
PING_HEADER_SIZE = 256
CHANNEL_HEADER_SIZE = 64

#: Packet types (``HeaderType``) read here.
SONAR, ATTITUDE, R2SONIC_BATHY, POSITION = 0, 3, 65, 107

# Plausibility (a wide margin around real side-scans: 100-2000 kHz systems reach a few hundred
# metres per side with up to tens of thousands of samples).
#: ``NumSamples`` per channel allowed.
N_SAMPLES_LIMITS = (1, 1 << 18)
#: ``SlantRange`` allowed, metres.
SLANT_RANGE_M_LIMITS = (0.1, 3000.0)
#: Sound speed allowed (after the c/2 decision), m/s.
SOUND_SPEED_LIMITS = (1300.0, 1800.0)
#: Largest packet accepted (``NumBytesThisRecord``), bytes.
MAX_PACKET_BYTES = 1 << 26
_KNOT_M_S = 1852.0 / 3600.0
_EARTH_RADIUS_M = 6371.0e3


def _pyxtf():
    """The pyxtf module, or a clear error naming the extra that brings it."""
    try:
        import pyxtf
    except ImportError as exc:
        from ...core.extras import install_hint

        raise SonarsimError(f"reading XTF files needs the 'pyxtf' library ({exc}); {install_hint('xtf')}") from None
    return pyxtf


def is_xtf(head: bytes) -> bool:
    """Whether ``head`` (the file's first 1026 bytes or more) starts like an XTF file: FileFormat
    0x7B and a packet magic 0xFACE right after the 1024-byte file header. (0x7B alone is ``{``,
    the first byte of every JSON file.)"""
    return (len(head) >= FILE_HEADER_SIZE + 2 and head[0] == XTF_FILE_FORMAT
            and int.from_bytes(head[FILE_HEADER_SIZE:FILE_HEADER_SIZE + 2], "little") == PACKET_MAGIC)


def xtf_problem(head: bytes) -> str | None:
    """Why ``head`` (the file's first bytes, up to 1040), which starts like an XTF file header,
    is no XTF file sonarsim can read; None when it does not look like one at all.

    An XTF file header is binary (``FileFormat`` 0x7B, then names padded with NUL bytes); a
    JSON file also starts with 0x7B (``{``) but holds no NUL byte.
    """
    if not head or head[0] != XTF_FILE_FORMAT or b"\0" not in head[:FILE_HEADER_SIZE]:
        return None
    if len(head) < FILE_HEADER_SIZE + 2:
        return (f"truncated: it starts like an XTF file header (FileFormat 0x7B) but ends at byte {len(head)}, "
                f"before its first packet (byte {FILE_HEADER_SIZE})")
    magic = int.from_bytes(head[FILE_HEADER_SIZE:FILE_HEADER_SIZE + 2], "little")
    if magic != PACKET_MAGIC:
        return (f"it starts like an XTF file header (FileFormat 0x7B) but byte {FILE_HEADER_SIZE} holds 0x{magic:04x}, "
                "not the packet magic 0xface")
    return None


def xtf_kind(path, max_packets: int = 256) -> str:
    """``"r2sonic"`` if the first ping packet of an XTF file is R2Sonic bathymetry (type 65),
    else ``"xtf"`` (side-scan sonar pings, or no ping among the first ``max_packets``)."""
    with open(path, "rb") as handle:
        handle.seek(FILE_HEADER_SIZE)
        for _ in range(max_packets):
            start = handle.read(PACKET_START_SIZE)
            if len(start) < PACKET_START_SIZE:
                break
            magic, kind = struct.unpack_from("<HB", start)
            size = struct.unpack_from("<I", start, 10)[0]
            if magic != PACKET_MAGIC or size < PACKET_START_SIZE:
                break
            if kind == R2SONIC_BATHY:
                return "r2sonic"
            if kind == SONAR:
                return "xtf"
            handle.seek(size - PACKET_START_SIZE, 1)
    return "xtf"


@dataclass(frozen=True)
class Packet:
    """One indexed XTF packet: its position among all packets, byte offset, type and size."""

    index: int
    offset: int
    kind: int
    size: int


def utc_seconds(year: int, month: int, day: int, hour: int, minute: int, second: float) -> float:
    """Seconds since 1970 (UTC) of a calendar date and time; NaN for an impossible date."""
    try:
        whole = calendar.timegm((int(year), int(month), int(day), int(hour), int(minute), 0, 0, 0, 0))
    except (ValueError, OverflowError):
        return math.nan
    if not (1 <= month <= 12 and 1 <= day <= 31 and hour <= 23 and minute <= 59 and 0 <= second < 61):
        return math.nan
    return whole + float(second)


class XtfPackets(FilmRecording):
    """What the XTF readers share: the file header and a lazy index of the packets.

    Subclasses set :attr:`ping_kind` (the packet type that is a frame) and implement
    :meth:`_ping` (check one ping packet and return what :meth:`_read` needs).
    """

    format = "xtf"
    unit, units = "ping", "pings"
    ping_kind = SONAR

    def _open(self) -> None:
        self._x = _pyxtf()
        head = read_at(self._handle, 0, FILE_HEADER_SIZE, self._file_size, self._source, "file header",
                       f"XTF file header ({FILE_HEADER_SIZE} bytes)")
        if head[0] != XTF_FILE_FORMAT:
            raise RecordingError(self._source, f"{head[0]} is not XTF's FileFormat {XTF_FILE_FORMAT} (0x7B)",
                                 "file header", "FileFormat")
        self.file_header = self._x.XTFFileHeader.from_buffer_copy(head)
        self._packets: list[Packet] = []
        self._pings: list[Packet] = []
        self._next_offset = FILE_HEADER_SIZE
        self._done = False
        self._tail: RecordingError | None = None  # why the packets stop (a cut or a corrupt packet)
        self._layouts: dict[int, dict] = {}

    # -- indexing ----------------------------------------------------------------------------

    def _scan_next(self) -> None:
        """Index one more packet, or record the end: clean, or the error that stops the index."""
        offset = self._next_offset
        index = len(self._packets)
        where = f"packet {index} (byte {offset})"
        if offset == self._file_size:
            self._done = True
            return
        try:
            start = read_at(self._handle, offset, PACKET_START_SIZE, self._file_size, self._source, where,
                            f"packet start ({PACKET_START_SIZE} bytes)")
            magic, kind = struct.unpack_from("<HB", start)
            (size,) = struct.unpack_from("<I", start, 10)
            if magic != PACKET_MAGIC:
                raise RecordingError(self._source, f"0x{magic:04x} is not the XTF packet magic 0xface (corrupt file, "
                                     "or the previous packet's NumBytesThisRecord is wrong)", where, "MagicNumber")
            if not PACKET_START_SIZE <= size <= MAX_PACKET_BYTES:
                raise RecordingError(self._source, f"{size} bytes is outside the allowed {PACKET_START_SIZE} to "
                                     f"{MAX_PACKET_BYTES} bytes", where, "NumBytesThisRecord")
            if offset + size > self._file_size:
                raise RecordingError(self._source, f"truncated: NumBytesThisRecord {size} needs the packet to end at "
                                     f"byte {offset + size}, but the file ends at byte {self._file_size}",
                                     where, "NumBytesThisRecord")
        except RecordingError as exc:
            self._done = True
            self._tail = exc
            return
        packet = Packet(index, offset, kind, size)
        self._packets.append(packet)
        if kind == self.ping_kind:
            self._pings.append(packet)
        self._next_offset = offset + size

    def _scan_to(self, n_pings: float) -> None:
        while len(self._pings) < n_pings and not self._done:
            self._scan_next()

    def _scan_all_good(self) -> list[Packet]:
        """Every packet before the damage (all of them for a clean file): the attitude and
        position packets among the good pings."""
        n = self.n_frames
        while not self._done:
            self._scan_next()
        if self._damage is not None and n < len(self._pings):
            end = self._pings[n].offset  # the damaged ping and what follows are not used
            return [p for p in self._packets if p.offset < end]
        return list(self._packets)

    def _check(self, k: int) -> bool:
        self._scan_to(k + 1)
        if k < len(self._pings):
            self._layouts[k] = self._ping(self._pings[k], k)
            return True
        if self._tail is not None:
            t = self._tail
            raise RecordingError(self._source, f"ping {k} would follow, but {t.where} is unreadable: {t.detail}",
                                 f"ping {k}", t.field)
        return False

    def _no_frames(self, k: int) -> RecordingError:
        kinds = sorted({p.kind for p in self._packets})
        return RecordingError(self._source, f"ping {k} requested, but the file has no packet of type "
                              f"{self.ping_kind} ({self._what}); packet types found: {kinds or 'none'}")

    _what = "sonar pings"

    def _ping(self, packet: Packet, k: int) -> dict:
        raise NotImplementedError

    def _bytes(self, packet: Packet, k: int, start: int, size: int, what: str) -> bytes:
        return read_at(self._handle, packet.offset + start, size, self._file_size, self._source,
                       f"ping {k} (packet {packet.index}, byte {packet.offset})", what)


class XtfSidescanRecording(XtfPackets):
    """An open XTF side-scan recording; a frame is one sonar ping (see the module notes).

    ``read(k)`` gives ping ``k`` as a one-ping :class:`~sonarsim.image.films.Waterfall`;
    :meth:`waterfall` gives a range of pings.

    Parameters
    ----------
    path : str or os.PathLike
        The XTF file.

    Raises
    ------
    RecordingError
        Not an XTF file, or its first ping is unreadable.
    SonarsimError
        pyxtf (the ``xtf`` extra) is not installed.
    """

    format = "xtf"
    film = "waterfall"

    def _open(self) -> None:
        super()._open()
        fh = self.file_header
        self._chan_types = [int(fh.ChanInfo[i].TypeOfChannel) for i in range(6)]
        self._chan_bytes = [int(fh.ChanInfo[i].BytesPerSample) for i in range(6)]
        self._chan_formats = [int(fh.ChanInfo[i].SampleFormat) for i in range(6)]
        self._shape: tuple[int, float, float] | None = None  # ping 0's (n_samples, window): all must match
        self._origin: tuple[float, float] | None = None

    def _ping(self, packet: Packet, k: int) -> dict:
        """Check ping ``k``'s headers; returns its header, channels and sample layout."""
        x, src = self._x, self._source
        where = f"ping {k} (packet {packet.index}, byte {packet.offset})"
        head = self._bytes(packet, k, 0, PING_HEADER_SIZE, f"ping header ({PING_HEADER_SIZE} bytes)")
        if packet.size < PING_HEADER_SIZE:
            raise RecordingError(src, f"{packet.size} bytes is shorter than a ping header ({PING_HEADER_SIZE})",
                                 where, "NumBytesThisRecord")
        h = x.XTFPingHeader.from_buffer_copy(head)
        n_chans = int(h.NumChansToFollow)
        if not 2 <= n_chans <= 6:
            raise RecordingError(src, f"{n_chans} channels; a side-scan ping has 2 to 6 (port and starboard first)",
                                 where, "NumChansToFollow")
        at = PING_HEADER_SIZE
        sides: dict[int, tuple] = {}
        for c in range(n_chans):
            ch = x.XTFPingChanHeader.from_buffer_copy(
                self._bytes(packet, k, at, CHANNEL_HEADER_SIZE, f"channel {c} header ({CHANNEL_HEADER_SIZE} bytes)"))
            number = int(ch.ChannelNumber)
            if number >= 6:
                raise RecordingError(src, f"channel {c}: {number} is not a channel of the file header (0-5)",
                                     where, "ChannelNumber")
            n = int(ch.NumSamples)
            check_within(src, where, f"channel {c} NumSamples", n, N_SAMPLES_LIMITS, "", "the sample counts of side-scans")
            bps = self._chan_bytes[number]
            dtype = sample_dtype(src, number, bps, self._chan_formats[number])
            data_at = at + CHANNEL_HEADER_SIZE
            at = data_at + n * bps
            if at > packet.size:
                raise RecordingError(src, f"channel {c}'s {n} samples of {bps} bytes end at byte {at} of the "
                                     f"packet, which has {packet.size}", where, "NumSamples")
            side = {1: 0, 2: 1}.get(self._chan_types[number])
            if side is not None and side not in sides:
                sides[side] = (ch, n, bps, data_at, c, dtype)
        if set(sides) != {0, 1}:
            raise RecordingError(src, "the ping has no port and starboard channel pair (ChanInfo.TypeOfChannel 1 "
                                 f"and 2; channel types {self._chan_types})", where, "ChannelNumber")
        (cp, n_p, *_), (cs, n_s, *_) = sides[0], sides[1]
        if n_p != n_s:
            raise RecordingError(src, f"port has {n_p} samples and starboard {n_s}; a waterfall needs both alike",
                                 where, "NumSamples")
        slant = float(cp.SlantRange)
        check_within(src, where, "SlantRange", slant, SLANT_RANGE_M_LIMITS, "m", "the slant ranges of side-scans")
        c = sound_speed(float(h.SoundVelocity), slant, float(cp.TimeDuration))
        check_within(src, where, "SoundVelocity", c, SOUND_SPEED_LIMITS, "m/s",
                     "sound speeds in water, after doubling a stored c/2")
        r0 = float(cp.TimeDelay) * c / 2.0
        if not (math.isfinite(r0) and 0.0 <= r0 < slant):
            raise RecordingError(src, f"a window start of {r0!r} m (TimeDelay x c / 2) does not lie before the "
                                 f"slant range {slant:g} m", where, "TimeDelay")
        shape = (n_p, r0, slant)
        if self._shape is None:
            require_frame_memory(src, where, "NumSamples", n_p, 2, 2 * 4 + 4)
            self._shape = shape
        elif shape[0] != self._shape[0] or not np.allclose(shape[1:], self._shape[1:], rtol=1e-5, atol=1e-6):
            raise RecordingError(src, f"{n_p} samples over {r0:g}-{slant:g} m, but ping 0 has {self._shape[0]} over "
                                 f"{self._shape[1]:g}-{self._shape[2]:g} m; the pings of one waterfall must share their "
                                 "samples and window", where, "NumSamples")
        return {"header": h, "sides": sides, "sound_speed": c, "where": where}

    def _samples(self, k: int) -> np.ndarray:
        """Ping ``k``'s ``(2, n_samples)`` float32 samples, sample 0 nearest on both sides."""
        packet, g = self._pings[k], self._layouts[k]
        out = []
        for side in (0, 1):
            _ch, n, bps, data_at, c, dtype = g["sides"][side]
            raw = self._bytes(packet, k, data_at, n * bps, f"channel {c} samples ({n * bps} bytes)")
            line = np.frombuffer(raw, dtype=dtype, count=n)
            out.append(line[::-1] if side == 0 else line)  # port is stored far -> nadir
        return np.asarray(out, dtype=np.float32)

    def _geometry(self, ks: range):
        """The :class:`PingGeometry` of pings ``ks`` (one Python step per ping: pings are few)."""
        from ...image.films import PingGeometry

        fields = ("Year", "Month", "Day", "Hour", "Minute", "Second", "HSeconds", "SensorDepth",
                  "SensorPrimaryAltitude", "SensorPitch", "SensorRoll", "SensorHeading", "SensorSpeed",
                  "SensorXcoordinate", "SensorYcoordinate")
        v = {f: np.array([float(getattr(self._layouts[k]["header"], f)) for k in ks]) for f in fields}
        c = np.array([self._layouts[k]["sound_speed"] for k in ks])
        t = np.array([utc_seconds(*[v[f][i] for f in fields[:5]], v["Second"][i] + v["HSeconds"][i] / 100.0)
                      for i in range(len(ks))])
        nav = ("SensorDepth", "SensorPrimaryAltitude", "SensorPitch", "SensorRoll", "SensorHeading", "SensorSpeed",
               "SensorXcoordinate", "SensorYcoordinate")
        # All navigation exactly 0: the vehicle sent none for this ping (ping 0 of the test file).
        none = np.all([v[f] == 0.0 for f in nav], axis=0)

        def known(a, also=None):
            a = np.where(none, np.nan, a)
            return a if also is None else np.where(also, np.nan, a)

        no_fix = (v["SensorXcoordinate"] == 0.0) & (v["SensorYcoordinate"] == 0.0)
        x, y = known(v["SensorXcoordinate"], no_fix), known(v["SensorYcoordinate"], no_fix)
        r0 = self._shape[1]
        geo = dict(
            time_s=t,
            altitude_m=known(v["SensorPrimaryAltitude"], v["SensorPrimaryAltitude"] == 0.0),  # 0: no bottom lock
            depth_m=known(v["SensorDepth"]),
            pitch_deg=known(-v["SensorPitch"]),  # XTF: > 0 nose up; ours: > 0 nose down
            roll_deg=known(v["SensorRoll"]),  # XTF: > 0 port up, as REP-103
            heading_deg=known(v["SensorHeading"]),
            speed_m_s=known(v["SensorSpeed"] * _KNOT_M_S),
            sound_speed_m_s=c,
            range_min_m=np.full(len(ks), r0),
            range_max_m=np.full(len(ks), self._shape[2]),
        )
        if int(self.file_header.NavUnits) == 3:
            off_earth = ~((np.abs(y) <= 90.0) & (np.abs(x) <= 360.0))  # (NaN included)
            x, y = np.where(off_earth, np.nan, x), np.where(off_earth, np.nan, y)
            geo["latitude_deg"], geo["longitude_deg"] = y, x
            origin = self._position_origin()
            if origin is not None:
                lat0, lon0 = origin
                geo["x_m"] = np.radians(x - lon0) * _EARTH_RADIUS_M * math.cos(math.radians(lat0))
                geo["y_m"] = np.radians(y - lat0) * _EARTH_RADIUS_M
        else:
            geo["x_m"], geo["y_m"] = x, y
        return PingGeometry.of(len(ks), **geo)

    def _position_origin(self) -> tuple[float, float] | None:
        """(latitude, longitude) of the first good ping with a position: the origin of x_m, y_m."""
        if self._origin is None:
            for k in range(self.n_frames):
                h = self._layouts[k]["header"]
                lat, lon = float(h.SensorYcoordinate), float(h.SensorXcoordinate)
                if (lat, lon) != (0.0, 0.0) and abs(lat) <= 90.0 and abs(lon) <= 360.0:
                    self._origin = (lat, lon)
                    break
        return self._origin

    def _read(self, k: int):
        return self._waterfall(range(k, k + 1))

    def _waterfall(self, ks: range):
        from ...image.films import Waterfall

        n = self._shape[0]
        require_memory(self._source, 4.0 * len(ks) * 2 * n, f"a waterfall of {len(ks)} pings x 2 x {n} samples",
                       "NumSamples")
        samples = np.empty((len(ks), 2, n), np.float32)
        for i, k in enumerate(ks):
            samples[i] = self._samples(k)
        return Waterfall(samples=samples, range_min_m=float(self._shape[1]), range_max_m=float(self._shape[2]),
                         geometry=self._geometry(ks), source=self._source)

    def read(self, frame: int = 0):
        """Ping ``frame`` as a one-ping :class:`~sonarsim.image.films.Waterfall`, ``samples``
        ``(1, 2, n_samples)`` float32 (the recorded counts).

        Raises
        ------
        RecordingError
            ``frame`` is not among the good pings (see :class:`~sonarsim.io.readers._common.Recording`).
        """
        return super().read(frame)

    def waterfall(self, pings=None):
        """Pings ``pings`` (None: every good ping; a slice; an int) as one Waterfall.

        Returns
        -------
        Waterfall
            ``samples`` ``(n, 2, n_samples)`` float32, side 0 port, sample 0 nearest; geometry per ping.

        Raises
        ------
        RecordingError
            A slice reaching beyond a damaged file's good pings (naming the damaged ping), or an
            int out of range.
        """
        ks = self._ping_range(pings)
        if len(ks) == 0:
            raise RecordingError(self._source, f"pings {pings!r} select none of the {self.n_frames} good pings")
        return self._waterfall(ks)


def sample_dtype(source: str, channel: int, bytes_per_sample: int, sample_format: int) -> str:
    """The NumPy dtype of a channel's samples from the file header's ``ChanInfo``.

    ``SampleFormat`` (XTF X41: 2 = 4-byte integer, 3 = 2-byte integer, 5 = 4-byte IEEE float,
    8 = 1-byte integer; 0 = legacy, where ``BytesPerSample`` alone decides) must agree with
    ``BytesPerSample``. Integers are read unsigned, as pyxtf reads them (the test data's
    samples run 0 to 32767 with ``UniPolar`` 1). IBM floats (1) are not supported.

    Raises
    ------
    RecordingError
        An unknown or unsupported format, or one that contradicts ``BytesPerSample``.
    """
    known = {2: (4, "<u4"), 3: (2, "<u2"), 5: (4, "<f4"), 8: (1, "u1")}
    if sample_format in known:
        size, dtype = known[sample_format]
        if size == bytes_per_sample:
            return dtype
        raise RecordingError(source, f"channel {channel}: SampleFormat {sample_format} has {size}-byte samples, but "
                             f"BytesPerSample is {bytes_per_sample}", "file header", "ChanInfo.SampleFormat")
    if sample_format == 0 and bytes_per_sample in (1, 2, 4):
        return f"<u{bytes_per_sample}"
    raise RecordingError(source, f"channel {channel}: SampleFormat {sample_format} with {bytes_per_sample} bytes per "
                         "sample is not supported (known: 2, 3, 5, 8, or 0 with 1, 2 or 4 bytes)", "file header",
                         "ChanInfo.SampleFormat")


def sound_speed(stored: float, slant_range_m: float, duration_s: float) -> float:
    """The sound speed of a ping from XTF's ``SoundVelocity`` (c/2 or c; see the module notes), m/s.

    Parameters
    ----------
    stored : float
        ``SoundVelocity``, m/s.
    slant_range_m : float
        The channel's ``SlantRange``, metres.
    duration_s : float
        The channel's ``TimeDuration`` (two-way listening time), seconds; 0 if not recorded.
    """
    if duration_s > 0.0 and stored > 0.0:
        half = duration_s * stored  # the range if `stored` is c/2
        if abs(half - slant_range_m) <= 0.02 * slant_range_m:
            return 2.0 * stored
        if abs(half / 2.0 - slant_range_m) <= 0.02 * slant_range_m:
            return stored
    return 2.0 * stored if stored < 1000.0 else stored


def read_waterfall(path, pings=None):
    """The side-scan pings ``pings`` of an XTF file as a :class:`~sonarsim.image.films.Waterfall`.

    Parameters
    ----------
    path : str or os.PathLike
        The XTF file.
    pings : None, slice or int
        The pings (default: every good ping).

    Returns
    -------
    Waterfall
    """
    with XtfSidescanRecording(path) as recording:
        return recording.waterfall(pings)
