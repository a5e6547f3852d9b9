"""Reader of Blueprint Subsea Oculus "simple ping result" network messages (``.raw``).

A file holds one or more messages back to back, exactly as the sonar sends them (this is what
liboculus records). Little-endian and packed; layouts from ``Oculus.h`` (Blueprint Subsea, as
shipped in the University of Washington's liboculus, ``thirdparty/Oculus/Oculus.h``)::

    message header (16 bytes)   oculusId u16 @0 = 0x4f53, srcDeviceId @2, dstDeviceId @4,
                                msgId u16 @6, msgVersion u16 @8, payloadSize u32 @10, spare @14
    simple fire message         masterMode u8 @16, pingRate @17, networkSpeed @18,
                                gammaCorrection @19, flags @20, range f64 @21, gainPercent @29,
                                speedOfSound @37, salinity @45 (v2 adds extFlags u32 @53 and
                                8 reserved u32)
    version 1 (msgVersion 0/1)  pingId u32 @53, status @57, frequency f64 @61, temperature @69,
                                pressure @77, speedOfSoundUsed @85, pingStartTime u32 @93,
                                dataSize u8 @97, rangeResolution f64 @98, nRanges u16 @106,
                                nBeams u16 @108, imageOffset u32 @110, imageSize @114,
                                messageSize @118; bearings int16 (0.01 deg) x nBeams @122
    version 2 (msgVersion 2)    pingId u32 @89, status @93, frequency f64 @97, temperature @105,
                                pressure @113, heading @121, pitch @129, roll @137,
                                speedOfSoundUsed @145, pingStartTime f64 @153, dataSize u8 @161,
                                rangeResolution f64 @162, nRanges u16 @170, nBeams u16 @172,
                                4 spare u32 @174, imageOffset u32 @190, imageSize @194,
                                messageSize @198; bearings int16 (0.01 deg) x nBeams @202

The image is ``nRanges`` rows (nearest first) of ``nBeams`` values at ``imageOffset`` from the
start of the message, in the order of the bearing table. ``dataSize`` 0/1/2/3 means 1/2/3/4
bytes per value (``DataSizeType``: 8, 16, 24, 32 bit, unsigned little-endian). When bit 2 of
the fire-message ``flags`` ("send gain") is set, every row starts with a 4-byte gain; the reader
drops it (its meaning is not documented in these sources, so it is not applied; the raw words
are kept in the header). ``imageSize`` must equal ``nRanges * (nBeams * bytes + gain bytes)``,
as liboculus also requires. Messages other than simple ping results (id 0x23) are skipped.

Bearing sign. A positive Oculus bearing is to the sonar's RIGHT (starboard). Evidence:
Blueprint Subsea's own Oculus Viewer (``SonarSurface.cpp``) draws beam ``b`` at screen
``x = range * sin(bearing_b)`` on an orthographic projection from ``-range`` (left) to
``+range`` (right), and labels ``bearings[0]`` (the most negative) the "left" edge of the fan;
the University of Washington's ``sonar_image_proc`` draws Oculus azimuths the same way
(``x = origin + range * sin(azimuth)``). A fan drawn that way shows the scene as seen from
behind the sonar, so negative bearings are to port. sonarsim's azimuth is positive to the LEFT,
hence ``azimuth_deg = -bearing``; the recorded bearings ascend (-30 ... +30 deg in the test
data), so the azimuths descend in the file's own column order and column 0 stays the
left-most beam. (UW's ROS driver writes ``beam_direction.y = -sin(bearing)`` into a
``ProjectedSonarImage``, whose frame is z forward and x up; that is y = starboard only if the
frame is right-handed, which that message does not state, so it was not taken as evidence.)

Geometry: range line ``i`` covers ``[i dr, (i + 1) dr)`` with ``dr`` = ``rangeResolution``
(the messages carry no minimum range; liboculus assumes 0 too). Assumed elevation apertures
(not in the messages; liboculus ``Constants.h``): 12 deg for the M1200d's 2.1 MHz mode and the
M750d's 1.2 MHz high-frequency mode, 20 deg otherwise (750 kHz, the M1200d's 1.2 MHz
low-frequency mode, the M3000d). An M750d in high-frequency mode and an M1200d in
low-frequency mode both ping at about 1.2 MHz; ``masterMode`` (2 = high frequency) tells them
apart.

Header values no Oculus produces are refused with a :class:`RecordingError` naming the field,
the value and the allowed interval (``RANGE_RESOLUTION_M_LIMITS``, ``RANGE_MAX_M``,
``N_BEAMS_LIMITS``, ``FREQUENCY_HZ_LIMITS``); the bearing table must be strictly monotonic and
within +-90 deg.

Values wider than 24 bits lose precision in the float32 image (float32 has a 24-bit mantissa).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...errors import ConfigError
from ...image.grid import beam_edges_deg
from ._common import (
    Recording,
    RecordingError,
    check_range_window,
    check_within,
    frame_index,
    read_at,
    require_frame_memory,
)

__all__ = [
    "FREQUENCY_HZ_LIMITS",
    "MESSAGE_HEADER_SIZE",
    "N_BEAMS_LIMITS",
    "OCULUS_ID",
    "RANGE_MAX_M",
    "RANGE_RESOLUTION_M_LIMITS",
    "SIMPLE_PING_RESULT",
    "OculusRecording",
]

#: ``oculusId`` of every Oculus message (bytes ``53 4f``, "SO").
OCULUS_ID = 0x4F53
#: ``msgId`` of a simple ping result.
SIMPLE_PING_RESULT = 0x23
MESSAGE_HEADER_SIZE = 16

_HEADER = struct.Struct("<HHHHHIH")
_FIRE = struct.Struct("<BBBBBdddd")  # @16, both versions
_FIRE_V2_EXT = struct.Struct("<I")  # extFlags @53 (v2 only)
_PING_V1 = struct.Struct("<IIddddIBdHHIII")  # @53
_PING_V2 = struct.Struct("<IIddddddddBdHHIIIIIII")  # @89
_V1_FIELDS = (
    "pingId", "status", "frequency", "temperature", "pressure", "speedOfSoundUsed",
    "pingStartTime", "dataSize", "rangeResolution", "nRanges", "nBeams", "imageOffset",
    "imageSize", "messageSize",
)
_V2_FIELDS = (
    "pingId", "status", "frequency", "temperature", "pressure", "heading", "pitch", "roll",
    "speedOfSoundUsed", "pingStartTime", "dataSize", "rangeResolution", "nRanges", "nBeams",
    "spare0", "spare1", "spare2", "spare3", "imageOffset", "imageSize", "messageSize",
)
_FIRE_FIELDS = (
    "masterMode", "pingRate", "networkSpeed", "gammaCorrection", "flags", "range",
    "gainPercent", "speedOfSound", "salinity",
)
# version -> (offset of the ping fields, their struct, their names, offset of the bearings)
_LAYOUTS = {
    1: (53, _PING_V1, _V1_FIELDS, 122),
    2: (89, _PING_V2, _V2_FIELDS, 202),
}
_BYTES_PER_VALUE = {0: 1, 1: 2, 2: 3, 3: 4}  # DataSizeType: 8, 16, 24, 32 bit
_FLAG_SEND_GAIN = 0x04
_GAIN_BYTES = 4

# Physical plausibility of the fields the geometry comes from. Blueprint Subsea's multibeam
# imaging sonars as their data sheets are commonly quoted: the M750d pings at 750 kHz / 1.2 MHz
# and reaches 120 m, the M1200d pings at 1.2 / 2.1 MHz, the M3000d at 1.2 / 3.0 MHz (30 m at
# most); all form 256 or 512 beams over at most 130 deg; the real M1200d recording in the test
# data has 703 range lines of 2.84 mm. The limits leave a wide margin (about 4x), so that other
# models and modes are not refused, while a corrupt field (1e-300 m, 6e9 m) is.

#: ``rangeResolution`` allowed, metres (a few mm at short range; 120 m over a few hundred
#: range lines is a few decimetres).
RANGE_RESOLUTION_M_LIMITS = (5e-5, 1.0)
#: Farthest window end (``nRanges * rangeResolution``), metres (device: 120 m).
RANGE_MAX_M = 500.0
#: ``nBeams`` allowed (device: 256 or 512).
N_BEAMS_LIMITS = (1, 2048)
#: ``frequency`` allowed, Hz (device: 750 kHz-3 MHz); it sets the assumed elevation aperture.
FREQUENCY_HZ_LIMITS = (150e3, 12e6)
# Bytes per value held while a ping is decoded: up to 4 widened bytes and the float32 image.
_BYTES_PER_VALUE_READ = 4 + 4


def elevation_fov_deg(frequency_hz: float, master_mode: int) -> float:
    """Elevation aperture assumed for an Oculus ping (see the module notes).

    Parameters
    ----------
    frequency_hz : float
        The ping's acoustic frequency.
    master_mode : int
        1 low-frequency, 2 high-frequency mode.

    Returns
    -------
    float
        12 for the M1200d at 2.1 MHz and the M750d at 1.2 MHz in high-frequency mode, else 20.
    """
    if 1.9e6 <= frequency_hz <= 2.3e6:
        return 12.0
    if 1.0e6 <= frequency_hz <= 1.4e6 and master_mode == 2:
        return 12.0
    return 20.0


@dataclass(frozen=True)
class _Message:
    index: int  # position among all messages in the file
    offset: int
    msg_id: int
    version: int
    size: int  # header + payload


class OculusRecording(Recording):
    """An open file of Oculus messages; pings are read on demand with seeks.

    The messages are indexed lazily (16 bytes read per message, and a ping's header and
    bearing table when it is checked), so opening a long log and reading its first ping costs
    little. A corrupt or cut message ends the good pings (the rule of
    :class:`~sonarsim.io.readers._common.Recording`): ``n_frames`` counts the pings before it,
    ``damage`` says what is wrong with it, and ``read`` and iteration stop there.

    Parameters
    ----------
    path : str or os.PathLike
        The file (recognised by its content, whatever its name).

    Raises
    ------
    RecordingError
        If the first message header is not an Oculus header, or the first ping (or the message
        before it) is unreadable.
    OSError
        If the file cannot be opened.
    """

    format = "oculus"

    def _open(self) -> None:
        self._messages: list[_Message] = []
        self._pings: list[_Message] = []
        self._next_offset = 0
        self._done = False
        self._tail_error: RecordingError | None = None

    # -- indexing -------------------------------------------------------------------------

    def _scan_next(self) -> None:
        """Index one more message, or mark the end (clean, or a truncated last message)."""
        if self._done:
            return
        offset = self._next_offset
        index = len(self._messages)
        where = f"message {index} (byte {offset})"
        if offset == self._file_size:
            self._done = True
            if index == 0:
                raise RecordingError(self._source, "the file is empty")
            return
        try:
            head = read_at(
                self._handle, offset, MESSAGE_HEADER_SIZE, self._file_size, self._source, where,
                f"message header ({MESSAGE_HEADER_SIZE} bytes)",
            )
        except RecordingError as exc:
            self._end_with(exc, index)
            return
        oculus_id, _src, _dst, msg_id, version, payload, _spare = _HEADER.unpack(head)
        if oculus_id != OCULUS_ID:
            raise RecordingError(
                self._source,
                f"0x{oculus_id:04x} is not the Oculus message id 0x{OCULUS_ID:04x} (corrupt "
                "file, or the previous message's payloadSize is wrong)",
                where, "oculusId",
            )
        size = MESSAGE_HEADER_SIZE + payload
        if offset + size > self._file_size:
            self._end_with(
                RecordingError(
                    self._source,
                    f"truncated: payloadSize {payload} needs the message to end at byte "
                    f"{offset + size}, but the file ends at byte {self._file_size}",
                    where, "payloadSize",
                ),
                index,
            )
            return
        message = _Message(index, offset, msg_id, version, size)
        self._messages.append(message)
        if msg_id == SIMPLE_PING_RESULT:
            self._pings.append(message)
        self._next_offset = offset + size

    def _end_with(self, error: RecordingError, index: int) -> None:
        # A cut last message: the complete ones stay readable; asking for it raises.
        if index == 0:
            raise error
        self._done = True
        self._tail_error = error

    def _scan_to(self, n_pings: int) -> None:
        while len(self._pings) < n_pings and not self._done:
            self._scan_next()

    # -- reading --------------------------------------------------------------------------

    unit, units = "ping", "simple ping results"

    def _check(self, k: int) -> bool:
        """Ping ``k`` is good when its message is complete and its header and bearing table
        pass :meth:`_layout` (see :class:`~sonarsim.io.readers._common.Recording`)."""
        self._scan_to(k + 1)  # raises for a message header that is not an Oculus one
        if k < len(self._pings):
            self._layout(self._pings[k], k)
            return True
        if self._tail_error is not None:
            tail = self._tail_error
            raise RecordingError(
                self._source,
                f"ping {k} would follow, but the last message is cut: {tail.detail}",
                tail.where, tail.field,
            )
        return False

    def _no_frames(self, k: int) -> RecordingError:
        kinds = sorted({f"0x{m.msg_id:02x}" for m in self._messages})
        return RecordingError(
            self._source,
            f"no simple ping result (message id 0x{SIMPLE_PING_RESULT:02x}) in the file; "
            f"message ids found: {', '.join(kinds)}",
        )

    def read(self, frame: int = 0):
        """Ping ``frame`` (0-based, counting simple ping results only) as a SonarImage.

        Returns
        -------
        SonarImage
            ``polar`` float32 ``(nRanges, nBeams)`` of the recorded values, row 0 nearest,
            column 0 the left-most beam; ``azimuth_deg = -bearing`` (see the module notes);
            ``config["header"]`` holds the decoded message fields.

        Raises
        ------
        RecordingError
            Ping out of range, truncated, of an unsupported version, with an impossible
            header, or after such a ping (see :class:`~sonarsim.io.readers._common.Recording`:
            the good frames).
        """
        return super().read(frame)

    def _layout(self, m: _Message, k: int) -> dict[str, Any]:
        """Ping ``k``'s checked header and bearing table, read from its message ``m``: all but
        the image, which is read only by :meth:`_read`.

        Raises
        ------
        RecordingError
            An unsupported version, an impossible header or bearing table, an image that
            does not fit the message, a ping beyond the memory budget.
        """
        src = self._source
        where = f"ping {k} (message {m.index}, byte {m.offset})"
        if m.version in (0, 1):
            version = 1
        elif m.version == 2:
            version = 2
        else:
            raise RecordingError(
                src, f"simple ping result version {m.version} is not supported (known: 1, 2)",
                where, "msgVersion",
            )
        ping_at, ping_struct, names, bearings_at = _LAYOUTS[version]
        if m.size < bearings_at:
            raise RecordingError(
                src,
                f"{m.size - MESSAGE_HEADER_SIZE} bytes is too short for a version {version} "
                f"simple ping result ({bearings_at - MESSAGE_HEADER_SIZE} bytes before the "
                "bearings)",
                where, "payloadSize",
            )
        # Only the header and the bearings are read here: checking every ping of a long log
        # (n_frames) must not read its images.
        data = read_at(
            self._handle, m.offset, bearings_at, self._file_size, src, where,
            f"ping header ({bearings_at} bytes)",
        )
        h: dict[str, Any] = dict(zip(_FIRE_FIELDS, _FIRE.unpack_from(data, MESSAGE_HEADER_SIZE)))
        if version == 2:
            (h["extFlags"],) = _FIRE_V2_EXT.unpack_from(data, 53)
        h.update(zip(names, ping_struct.unpack_from(data, ping_at)))
        h["msgVersion"] = m.version
        h["msgId"] = m.msg_id

        n_ranges, n_beams = h["nRanges"], h["nBeams"]
        if n_beams == 0:
            raise RecordingError(src, "is 0: the ping has no beams", where, "nBeams")
        if n_ranges == 0:
            raise RecordingError(src, "is 0: the ping has no range lines", where, "nRanges")
        check_within(src, where, "nBeams", n_beams, N_BEAMS_LIMITS, "", "Oculus sonars form 256 or 512 beams")
        if h["dataSize"] not in _BYTES_PER_VALUE:
            raise RecordingError(
                src,
                f"{h['dataSize']} is not a known sample size (0 = 8, 1 = 16, 2 = 24, 3 = 32 bit)",
                where, "dataSize",
            )
        bpv = _BYTES_PER_VALUE[h["dataSize"]]
        dr = h["rangeResolution"]
        check_within(
            src, where, "rangeResolution", dr, RANGE_RESOLUTION_M_LIMITS, "m",
            "Oculus range lines are a few millimetres to decimetres long",
        )
        check_range_window(
            src, where, "rangeResolution", 0.0, n_ranges * dr, RANGE_MAX_M,
            f"nRanges {n_ranges} x rangeResolution {dr:.6g} m",
        )
        frequency_hz = h["frequency"]
        check_within(
            src, where, "frequency", frequency_hz, FREQUENCY_HZ_LIMITS, "Hz",
            "Oculus sonars ping at 750 kHz-3 MHz",
        )

        bearings_end = bearings_at + 2 * n_beams
        if bearings_end > m.size:
            raise RecordingError(
                src,
                f"{n_beams} beams need bearings up to byte {bearings_end} of the message, but it "
                f"has {m.size} bytes",
                where, "nBeams",
            )
        gain = bool(h["flags"] & _FLAG_SEND_GAIN)
        row_bytes = n_beams * bpv + (_GAIN_BYTES if gain else 0)
        expected = n_ranges * row_bytes
        if h["imageSize"] != expected:
            raise RecordingError(
                src,
                f"{h['imageSize']} bytes, but {n_ranges} ranges x ({n_beams} beams x {bpv} "
                f"bytes{' + 4 gain bytes' if gain else ''}) = {expected} (dataSize "
                f"{h['dataSize']})",
                where, "imageSize",
            )
        image_at = h["imageOffset"]
        if image_at < bearings_end or image_at + expected > m.size:
            raise RecordingError(
                src,
                f"the image at bytes {image_at}-{image_at + expected - 1} does not lie between "
                f"the bearing table (ends at byte {bearings_end}) and the end of the message "
                f"({m.size} bytes)",
                where, "imageOffset",
            )

        table = read_at(
            self._handle, m.offset + bearings_at, 2 * n_beams, self._file_size, src, where,
            f"bearing table ({2 * n_beams} bytes)",
        )
        bearings = np.frombuffer(table, dtype="<i2", count=n_beams) / 100.0
        if np.any(np.abs(bearings) >= 90.0):
            raise RecordingError(
                src, f"bearings reach {np.abs(bearings).max():g} deg (|bearing| < 90 expected)",
                where, "bearings",
            )
        # A sonar's beams are formed in order across the fan: a table that is not strictly
        # ascending or descending is corrupt, not a beam order to sort out.
        steps = np.diff(bearings)
        if n_beams > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
            i = int(np.flatnonzero(steps == 0)[0] if np.any(steps == 0)
                    else np.flatnonzero(np.sign(steps) != np.sign(steps[0]))[0])
            what = "share a bearing" if steps[i] == 0 else "reverse the order of the table"
            raise RecordingError(
                src,
                f"beams {i} and {i + 1} ({bearings[i]:g} and {bearings[i + 1]:g} deg) {what}; "
                "the beam table must be strictly monotonic",
                where, "bearings",
            )
        # Positive bearing = starboard; sonarsim's azimuth is positive to port.
        azimuth = -bearings
        order = np.arange(n_beams) if n_beams == 1 or steps[0] > 0 else np.arange(n_beams)[::-1]
        # The outer beams reach half a spacing beyond their centres: the whole fan, not only the
        # centres, must lie inside +-90 deg (found by fuzzing: a last bearing overwritten with
        # 89 deg passed the check above and failed later, in SonarConfig).
        edges = beam_edges_deg(azimuth[order])
        if np.max(np.abs(edges)) >= 90.0:
            raise RecordingError(
                src,
                f"the fan's outer beam edges lie at bearings {-edges[0]:.4g} and {-edges[-1]:.4g} "
                "deg (half a beam spacing beyond the outer bearings); a fan must lie inside "
                "+-90 deg",
                where, "bearings",
            )
        require_frame_memory(src, where, "nRanges", n_ranges, n_beams, _BYTES_PER_VALUE_READ)
        return {
            "header": h, "where": where, "bearings": bearings, "azimuth": azimuth, "order": order,
            "bpv": bpv, "gain": gain, "row_bytes": row_bytes, "image_at": image_at,
            "image_bytes": expected, "range_max_m": n_ranges * dr,
        }

    def _read(self, k: int):
        from ...image.result import SonarImage
        from ...config.sonar import SonarConfig

        m = self._pings[k]
        g = self._layout(m, k)
        h, where, src = g["header"], g["where"], self._source
        n_ranges, n_beams, bpv = h["nRanges"], h["nBeams"], g["bpv"]
        raw = read_at(
            self._handle, m.offset + g["image_at"], g["image_bytes"], self._file_size, src, where,
            f"image ({g['image_bytes']} bytes)",
        )
        rows = np.frombuffer(raw, dtype=np.uint8).reshape(n_ranges, g["row_bytes"])
        if g["gain"]:
            h["rowGainsRaw"] = rows[:, :_GAIN_BYTES].copy().view("<u4").ravel().tolist()
            rows = rows[:, _GAIN_BYTES:]
        values = _unpack_values(rows, n_ranges, n_beams, bpv)
        order = g["order"]
        polar = np.ascontiguousarray(values[:, order], dtype=np.float32)

        elevation = elevation_fov_deg(h["frequency"], h["masterMode"])
        try:
            sonar = SonarConfig(
                beam_angles_deg=tuple(g["azimuth"][order]),
                elevation_fov_deg=elevation,
                range_min_m=0.0,
                range_max_m=g["range_max_m"],
                n_range_bins=n_ranges,
                frequency_khz=h["frequency"] / 1e3,
            )
        except ConfigError as exc:
            raise RecordingError(src, f"gives an impossible sonar: {exc}", where) from exc

        h.update(
            bearings_deg=g["bearings"].tolist(),
            bits_per_value=8 * bpv,
            range_max_m=g["range_max_m"],
            elevation_fov_deg_assumed=elevation,
            message_offset=m.offset,
            message_index=m.index,
        )
        return SonarImage(
            polar=polar,
            range_m=sonar.grid.range_m,
            azimuth_deg=sonar.grid.azimuth_deg,
            components={"total": polar},
            sonar=sonar,
            pose=None,  # not recorded
            rays=None,
            config={"source": src, "format": self.format, "frame": k, "header": h},
        )


def _unpack_values(rows: np.ndarray, n_ranges: int, n_beams: int, bpv: int) -> np.ndarray:
    """(n_ranges, n_beams) unsigned values from little-endian rows of ``bpv``-byte values."""
    if bpv == 1:
        return rows
    if bpv in (2, 4):
        return np.ascontiguousarray(rows).view(f"<u{bpv}").reshape(n_ranges, n_beams)
    # 24-bit: widen each 3-byte group to 4 bytes.
    triples = rows.reshape(n_ranges, n_beams, 3).astype(np.uint32)
    return triples[..., 0] | (triples[..., 1] << 8) | (triples[..., 2] << 16)
