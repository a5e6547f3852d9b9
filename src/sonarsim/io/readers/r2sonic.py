"""Reader of R2Sonic multibeam bathymetry recorded in XTF (QINSy) into :class:`~sonarsim.image.films.Soundings`.

QINSy writes each ping of an R2Sonic echosounder as an XTF packet of type 65: a 256-byte XTF
ping header (decoded with pyxtf's structures, the ``xtf`` extra) followed by the sonar's own
``BTH0`` record. ``BTH0`` is big-endian: the tag, its size u32 and a stream id u32, then
sections, each a 2-character name and its size u16 (R2Sonic's published data format, as CIDCO
MBES-lib describes it)::

    H0  header        ModelNumber char[12], SerialNumber char[12], TimeSeconds u32,
                      TimeNanoseconds u32 (since 1970), PingNumber u32, PingPeriod f32 (s),
                      SoundSpeed f32 (m/s), Frequency f32 (Hz), TxPower f32 (dB), TxPulseWidth
                      f32 (s), Tx beam widths and steering f32 x 4 (rad), ProjTemp u16,
                      VTXOffset i16, RxBandwidth, RxSampleRate, RxRange (m), RxGain, RxSpreading,
                      RxAbsorption, RxMountTilt f32, RxMiscInfo u32, reserved u16, Points u16
    R0  ranges        ScalingFactor f32, Points x u16: two-way travel time = u16 x scale (s)
    A0  angles        AngleFirst f32, AngleLast f32 (rad), 6 f32 reserved: equally spaced
    A2  angles        AngleFirst f32, ScalingFactor f32, 6 f32 reserved, Points x u16 steps:
                      angle[n] = AngleFirst + (steps[0] + ... + steps[n]) x scale (rad)
    I1  intensity     ScalingFactor f32, Points x u16: intensity = u16 x scale (micropascal)
    (G0, G1, Q0 gates and quality flags are skipped.)

Each section's size covers its arrays (rounded to 4 bytes); a section that does not fit the
record, or whose arrays do not fit the section, is refused naming it.

Conventions. R2Sonic's angles are relative to the array's centre line, the first (port) beam's
the most negative: positive to STARBOARD. sonarsim's are positive to port
(:class:`~sonarsim.image.films.Soundings`), so ``angle_deg = -angle``, and beam 0 stays the
port-most. The angles are the head's, not stabilised: over the 460 pings of the test data the
across-track slope of each ping's soundings follows the logged roll (correlation -0.997); with
each beam's angle corrected by the roll of the XTF attitude packets, as REP-103 wants it
(:meth:`~sonarsim.image.films.Soundings.level_points`: the level angle is ``angle + roll``),
the slope is constant (standard deviation 0.17 deg over the pings, against 2.2 deg
uncorrected and 4.4 deg with the roll's sign reversed), and a plane through 20 consecutive
pings' soundings leaves 3.7 cm rms (median; 55 cm with the roll's sign reversed). So XTF's attitude roll (documented as
"positive roll to starboard", i.e. port up) is REP-103's roll as it stands; XTF's pitch is
positive nose up and is negated; heave is positive up, as ours.

Two-way times of 0 are beams without a detection: NaN. A ping without an ``I1`` section has
NaN intensities; without ``A0`` or ``A2`` (angles), ``R0`` or ``H0`` it is refused.

Attitude (type 3, ``XTFAttitudeData``: Pitch, Roll, Heave, Heading in degrees and metres, time
from its date fields and Millisecond) and position (type 107, ``XTFPosRawNavigation``:
RawYcoordinate latitude, RawXcoordinate longitude; time from its date fields and the field
pyxtf calls Microsecond, which counts 0.1 ms in QINSy's files: 9080 beside the attitude's 908
ms of the same second) are interpolated linearly to each ping's time (``H0``'s TimeSeconds +
TimeNanoseconds; headings unwrapped first). A ping more than ``ATTITUDE_GAP_S`` from the
nearest attitude record (``POSITION_GAP_S`` for positions) gets NaN: the records of the test
data come at 25 Hz (attitude and position alike), pings at 19 Hz. Only the records before a
damaged ping are used; records with impossible values (a roll or pitch beyond 90 deg, a latitude
beyond 90 deg, ...) are skipped. (QINSy's own XTF ping header repeats the attitude record before the ping,
e.g. the roll of 23:52:15.908 for the ping of 15.920, and ``SoundVelocity`` as c/2; the reader
uses neither. The ping header's time agrees with H0's to 0.01 s.)
"""

from __future__ import annotations

import math
import struct

import numpy as np

from ._common import RecordingError, check_within, require_memory
from .xtf import (ATTITUDE, PING_HEADER_SIZE, POSITION, R2SONIC_BATHY, XtfPackets, _EARTH_RADIUS_M, utc_seconds)

__all__ = ["ATTITUDE_GAP_S", "POSITION_GAP_S", "N_POINTS_LIMITS", "R2SonicRecording", "read_soundings"]

#: Largest gap between a ping and the nearest attitude record for it to get an attitude, s.
ATTITUDE_GAP_S = 0.2
#: Largest gap between a ping and the nearest position record, s.
POSITION_GAP_S = 2.0
#: ``Points`` allowed in H0 (R2Sonic heads form at most 1024 beams).
N_POINTS_LIMITS = (1, 4096)
#: ``SoundSpeed`` allowed, m/s.
SOUND_SPEED_LIMITS = (1300.0, 1800.0)
_H0 = struct.Struct(">12s12sIIIfffffffffHhfffffffIHH")
_H0_FIELDS = ("ModelNumber", "SerialNumber", "TimeSeconds", "TimeNanoseconds", "PingNumber", "PingPeriod",
              "SoundSpeed", "Frequency", "TxPower", "TxPulseWidth", "TxBeamwidthVert", "TxBeamwidthHoriz",
              "TxSteeringVert", "TxSteeringHoriz", "ProjTemp", "VTXOffset", "RxBandwidth", "RxSampleRate",
              "RxRange", "RxGain", "RxSpreading", "RxAbsorption", "RxMountTilt", "RxMiscInfo", "reserved", "Points")
_BTH0 = b"BTH0"
# Scales of the u16 arrays (the test data: R0 3.8e-6 s, A2 7.0e-7 rad, I1 1.0 uPa), with margins
# that keep every decoded value plausible (two-way times under 65 s, angles under 90 deg
# after 1024 steps of 65535) rather than letting a corrupt scale overflow.
_SCALE_LIMITS = {"R0": (1e-10, 1e-3), "A2": (1e-12, 2e-8 * 1024), "I1": (1e-9, 1e9)}
_SCALE_WHAT = {"R0": "two-way times under 65 s", "A2": "beam angles within reach of 90 deg",
               "I1": "intensities finite"}


class R2SonicRecording(XtfPackets):
    """An open XTF file of R2Sonic bathymetry; a frame is one ping (a type-65 packet).

    ``read(k)`` gives ping ``k`` as a one-ping :class:`~sonarsim.image.films.Soundings`;
    :meth:`soundings` gives a range of pings with their attitude and position.

    Parameters
    ----------
    path : str or os.PathLike

    Raises
    ------
    RecordingError
        Not an XTF file, or its first ping is unreadable.
    SonarsimError
        pyxtf (the ``xtf`` extra) is not installed.
    """

    format = "r2sonic"
    film = "soundings"
    ping_kind = R2SONIC_BATHY
    _what = "R2Sonic bathymetry"

    def _ping(self, packet, k: int) -> dict:
        """Check and decode ping ``k``'s BTH0 record (it is small: a few kB)."""
        src = self._source
        where = f"ping {k} (packet {packet.index}, byte {packet.offset})"
        if packet.size < PING_HEADER_SIZE + 12:
            raise RecordingError(src, f"{packet.size} bytes cannot hold a ping header and a BTH0 record",
                                 where, "NumBytesThisRecord")
        body = self._bytes(packet, k, 0, packet.size, f"packet ({packet.size} bytes)")
        at = body.find(_BTH0, PING_HEADER_SIZE)
        if at < 0:
            raise RecordingError(src, "no BTH0 record in the packet", where, "BTH0")
        size = struct.unpack_from(">I", body, at + 4)[0]
        if not 12 <= size <= len(body) - at:
            raise RecordingError(src, f"BTH0 size {size} does not fit the packet ({len(body) - at} bytes from the tag)",
                                 where, "BTH0.PacketSize")
        rec = body[at:at + size]
        sections: dict[str, tuple[int, int]] = {}
        j = 12
        while j + 4 <= size:
            name, ssize = struct.unpack_from(">2sH", rec, j)
            if ssize < 4 or j + ssize > size:
                raise RecordingError(src, f"section {name!r} at byte {j} of BTH0 claims {ssize} bytes; the record has "
                                     f"{size - j} left", where, "BTH0.SectionSize")
            sections.setdefault(name.decode("latin-1"), (j, ssize))
            j += ssize
        for need in ("H0", "R0"):
            if need not in sections:
                raise RecordingError(src, f"BTH0 has no {need} section (sections: {', '.join(sections)})", where, need)
        j, ssize = sections["H0"]
        if ssize < 4 + _H0.size:
            raise RecordingError(src, f"H0 has {ssize} bytes, fewer than its {4 + _H0.size}", where, "H0.SectionSize")
        h = dict(zip(_H0_FIELDS, _H0.unpack_from(rec, j + 4)))
        n = h["Points"]
        check_within(src, where, "H0.Points", n, N_POINTS_LIMITS, "", "the beam counts of R2Sonic heads")
        check_within(src, where, "H0.SoundSpeed", h["SoundSpeed"], SOUND_SPEED_LIMITS, "m/s", "sound speeds in water")

        def array(name: str, skip: int) -> tuple[float, np.ndarray]:
            # The scale is the section's float after `skip` bytes, its u16 array the bytes after it.
            j, ssize = sections[name]
            if ssize < 8 + skip + (24 if name == "A2" else 0) + 2 * n:
                raise RecordingError(src, f"{name} has {ssize} bytes, too few for its {n} points", where,
                                     f"{name}.SectionSize")
            scale = struct.unpack_from(">f", rec, j + 4 + skip)[0]
            check_within(src, where, f"{name}.ScalingFactor", scale, _SCALE_LIMITS[name], "",
                         f"the scales that keep {_SCALE_WHAT[name]}")
            data_at = j + 8 + skip + (24 if name == "A2" else 0)  # A2: 6 reserved floats after the scale
            return scale, np.frombuffer(rec, ">u2", n, data_at)

        scale, counts = array("R0", 0)
        twt = np.where(counts == 0, np.nan, counts * float(scale))  # 0: no detection
        if "A2" in sections:
            j, ssize = sections["A2"]
            first = struct.unpack_from(">f", rec, j + 4)[0]
            a_scale, steps = array("A2", 4)  # AngleFirst before the scale
            # Cumulative 32-bit sum as R2Sonic defines it (int64 here: no overflow).
            angle = first + np.cumsum(steps.astype(np.int64)) * float(a_scale)
        elif "A0" in sections:
            j, ssize = sections["A0"]
            if ssize < 12:
                raise RecordingError(src, f"A0 has {ssize} bytes", where, "A0.SectionSize")
            first, last = struct.unpack_from(">ff", rec, j + 4)
            angle = np.linspace(first, last, n)
        else:
            raise RecordingError(src, "BTH0 has no beam angles (neither A0 nor A2)", where, "A0")
        if not np.all(np.isfinite(angle)) or np.max(np.abs(angle)) >= math.pi / 2:
            raise RecordingError(src, f"beam angles reach {np.degrees(np.max(np.abs(angle))):.4g} deg (|angle| < 90 "
                                 "expected)", where, "A2" if "A2" in sections else "A0")
        if "I1" in sections:
            i_scale, i_counts = array("I1", 0)
            intensity = i_counts * float(i_scale)
        else:
            intensity = np.full(n, np.nan)
        h["ModelNumber"] = h["ModelNumber"].rstrip(b"\0").decode("latin-1")
        h["SerialNumber"] = h["SerialNumber"].rstrip(b"\0").decode("latin-1")
        return {"header": h, "where": where, "two_way_time_s": twt, "angle_deg": -np.degrees(angle),
                "intensity": np.asarray(intensity, np.float64), "sections": sorted(sections)}

    # -- attitude and position ----------------------------------------------------------------

    def _records(self):
        """(attitude, position) records among the good pings: times and values, sorted by time."""
        if getattr(self, "_aux", None) is not None:
            return self._aux
        x = self._x
        att, pos = [], []
        for p in self._scan_all_good():
            if p.kind == ATTITUDE and p.size >= 64:
                a = x.XTFAttitudeData.from_buffer_copy(self._raw(p, 64))
                t = utc_seconds(a.Year, a.Month, a.Day, a.Hour, a.Minute, a.Second + a.Millisecond / 1e3)
                att.append((t, a.Pitch, a.Roll, a.Heave, a.Heading))
            elif p.kind == POSITION and p.size >= 64:
                q = x.XTFPosRawNavigation.from_buffer_copy(self._raw(p, 64))
                t = utc_seconds(q.Year, q.Month, q.Day, q.Hour, q.Minute, q.Second + q.Microsecond / 1e4)
                pos.append((t, q.RawYcoordinate, q.RawXcoordinate))
        att_a = np.array(att, np.float64).reshape(-1, 5)
        pos_a = np.array(pos, np.float64).reshape(-1, 3)
        # Records with impossible values are skipped, not refused: they only feed the
        # interpolation (a ping without a record near it gets NaN).
        with np.errstate(invalid="ignore"):
            att_ok = (np.isfinite(att_a).all(1) & (np.abs(att_a[:, 1:3]) <= 90.0).all(1)
                      & (np.abs(att_a[:, 3]) <= 100.0) & (np.abs(att_a[:, 4]) <= 720.0))
            pos_ok = (np.isfinite(pos_a).all(1) & (np.abs(pos_a[:, 1]) <= 90.0) & (np.abs(pos_a[:, 2]) <= 360.0)
                      & ~((pos_a[:, 1] == 0) & (pos_a[:, 2] == 0)))
        att_a, pos_a = att_a[att_ok], pos_a[pos_ok]
        self._aux = (att_a[np.argsort(att_a[:, 0], kind="stable")], pos_a[np.argsort(pos_a[:, 0], kind="stable")])
        return self._aux

    def _raw(self, p, n: int) -> bytes:
        self._handle.seek(p.offset)
        return self._handle.read(n)

    def _geometry(self, ks: range):
        from ...image.films import PingGeometry

        hs = [self._layouts[k]["header"] for k in ks]
        t = np.array([h["TimeSeconds"] + h["TimeNanoseconds"] * 1e-9 for h in hs])
        c = np.array([h["SoundSpeed"] for h in hs], np.float64)
        att, pos = self._records()
        geo = {"time_s": t, "sound_speed_m_s": c, "range_min_m": 0.0,
               "range_max_m": np.array([h["RxRange"] for h in hs], np.float64)}
        if len(att):
            ok = _near(att[:, 0], t, ATTITUDE_GAP_S)
            heading = np.degrees(np.unwrap(np.radians(att[:, 4])))
            for name, col, sign in (("pitch_deg", att[:, 1], -1.0), ("roll_deg", att[:, 2], 1.0),
                                    ("heave_m", att[:, 3], 1.0), ("heading_deg", heading, 1.0)):
                v = sign * np.interp(t, att[:, 0], col)
                geo[name] = np.where(ok, v, np.nan)
            geo["heading_deg"] = np.mod(geo["heading_deg"], 360.0)
        if len(pos):
            ok = _near(pos[:, 0], t, POSITION_GAP_S)
            lat = np.where(ok, np.interp(t, pos[:, 0], pos[:, 1]), np.nan)
            lon = np.where(ok, np.interp(t, pos[:, 0], pos[:, 2]), np.nan)
            lat0, lon0 = pos[0, 1], pos[0, 2]
            geo.update(latitude_deg=lat, longitude_deg=lon,
                       x_m=np.radians(lon - lon0) * _EARTH_RADIUS_M * math.cos(math.radians(lat0)),
                       y_m=np.radians(lat - lat0) * _EARTH_RADIUS_M)
        return PingGeometry.of(len(ks), **geo)

    # -- films ---------------------------------------------------------------------------------

    def _soundings(self, ks: range):
        from ...image.films import Soundings

        n_beams = max(len(self._layouts[k]["two_way_time_s"]) for k in ks)
        require_memory(self._source, 3 * 8.0 * len(ks) * n_beams, f"soundings of {len(ks)} pings x {n_beams} beams",
                       "H0.Points")
        out = {name: np.full((len(ks), n_beams), np.nan) for name in ("angle_deg", "two_way_time_s", "intensity")}
        for i, k in enumerate(ks):  # per ping (a ping's beams are one array)
            g = self._layouts[k]
            for name, a in out.items():
                a[i, :len(g[name])] = g[name]  # pings with fewer points: NaN beyond them
        return Soundings(geometry=self._geometry(ks), source=self._source, unit_name="uPa", **out)

    def _read(self, k: int):
        return self._soundings(range(k, k + 1))

    def read(self, frame: int = 0):
        """Ping ``frame`` as a one-ping :class:`~sonarsim.image.films.Soundings` (``(1, n_beams)``)."""
        return super().read(frame)

    def header(self, frame: int = 0) -> dict:
        """Ping ``frame``'s decoded H0 fields (and the BTH0 section names), for inspection."""
        self.read(frame)
        g = self._layouts[frame]
        return dict(g["header"], sections=g["sections"])

    def soundings(self, pings=None):
        """Pings ``pings`` (None: every good ping; a slice; an int) as one Soundings.

        Returns
        -------
        Soundings
            ``(n, n_beams)`` arrays (NaN beyond a ping's own beam count); geometry with the
            interpolated attitude and position.
        """
        ks = self._ping_range(pings)
        if len(ks) == 0:
            raise RecordingError(self._source, f"pings {pings!r} select none of the {self.n_frames} good pings")
        return self._soundings(ks)


def _near(times: np.ndarray, t: np.ndarray, gap: float) -> np.ndarray:
    """Whether each ``t`` lies within ``gap`` of one of the sorted ``times`` (and inside their span
    by no more than ``gap``: np.interp would otherwise repeat the end values)."""
    i = np.clip(np.searchsorted(times, t), 1, len(times) - 1) if len(times) > 1 else np.zeros(len(t), int)
    lo = np.abs(t - times[i - 1]) if len(times) > 1 else np.abs(t - times[0])
    hi = np.abs(times[i] - t)
    return np.minimum(lo, hi) <= gap


def read_soundings(path, pings=None):
    """The R2Sonic pings ``pings`` of an XTF file as :class:`~sonarsim.image.films.Soundings`.

    Parameters
    ----------
    path : str or os.PathLike
    pings : None, slice or int
        The pings (default: every good ping).
    """
    with R2SonicRecording(path) as recording:
        return recording.soundings(pings)
