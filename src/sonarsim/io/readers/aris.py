"""Reader of Sound Metrics ARIS recordings (``.aris``, file format DDF_05).

Layout (little-endian; Sound Metrics aris-file-sdk, ``type_definitions`` and
``docs/understanding-aris-data.md``)::

    1024-byte file header            Version = 0x05464444 ("DDF", 5) at byte 0
    frame 0: 1024-byte frame header  Version again at byte 12
             SamplesPerBeam x BeamCount uint8 samples
    frame 1: ...

The samples of a frame are stored sample-major: all beams of the nearest sample, then all
beams of the next one (``data[sample, beam]``), beam 0 being the RIGHT-most beam. This was
checked on the SDK's ``sample.aris`` (a sea bed seen by an ARIS 1200): read sample-major, every
beam shows the same fall of intensity with range and the bottom features run continuously
across beams; read beam-major, the "beams" show no range structure at all. The reader flips the
beams so that column 0 is the left-most beam (sonarsim's convention).

Geometry, per frame (the frame header, not the file header, is authoritative):

* beam count from ``PingMode`` (1-2: 48, 3-5: 96, 6-8: 64, 9-12: 128; SDK ``FrameFuncs.c``);
* range window ``[d c / 2, (d + n p) c / 2]`` with ``d`` = ``SampleStartDelay`` (us), ``p`` =
  ``SamplePeriod`` (us), ``n`` = ``SamplesPerBeam`` and ``c`` = ``SoundSpeed``; range bin ``i``
  is ``[start + i dr, start + (i + 1) dr)`` with ``dr = p c / 2`` (the SDK puts sample ``i`` at
  ``start + i dr``, the near edge of our bin). The header's own ``WindowStart`` and
  ``WindowLength`` are rounded display values (3.33 m and 20.3 m in the SDK's sample, whose
  samples span 3.298-23.401 m) and are only reported, not used;
* beam angles from the closed-form fits of Sound Metrics' measured tables
  (:func:`sonarsim.config.presets.aris_beam_angles_deg`), chosen as the SDK's ``Metrics.cs`` does from
  ``TheSystemType`` (0 = ARIS 1800, 1 = ARIS 3000, 2 = ARIS 1200; ``FrameHeader.h`` and
  ``ArisSystemType.cs``), ``LargeLens`` (1 = telephoto lens) and the beam count. Sound Metrics
  has tables for 1200/1800 x 48, 1800 x 96, 3000 x 64/128 and the telephoto lens x 48/96; other
  combinations (e.g. an ARIS 3000 with a telephoto lens) have no table and are refused rather
  than drawn with guessed angles.

The lens is taken from the frame header (``LargeLens`` 1: the telephoto lens), and with it the
elevation aperture, which is not in the file: Sound Metrics' published vertical beam width of
that lens (:data:`sonarsim.config.presets.ARIS_ELEVATION_FOV_DEG`: 14 degrees for the standard
lens, Sound Metrics' quoted 30 x 14 deg field of view; about 3 degrees for the telephoto lens, a
figure that could not be confirmed here). The image's sonar names the preset of its model, beam
count and lens (``preset``, :func:`sonarsim.config.presets.aris_preset_name`); its range window
and bins are the recording's, not the preset's. The carrier frequency is taken from ``FrequencyHiLow`` and the
model: 3.0 / 1.8 MHz (ARIS 3000, Integration SDK), 1.8 / 1.1 MHz (ARIS 1800), 1.2 / 0.7 MHz
(ARIS 1200, as commonly quoted; not confirmed from a Sound Metrics document here); it is
informational only.

Header values no ARIS produces are refused with a :class:`RecordingError` naming the field,
the value and the allowed interval (``SAMPLES_PER_BEAM_LIMITS``, ``SAMPLE_PERIOD_US_LIMITS``,
``SAMPLE_START_DELAY_US_LIMITS``, ``SOUND_SPEED_LIMITS``, ``WINDOW_END_MAX_M``: Sound Metrics'
device limits with a margin of about 4).

Frames are read one at a time with seeks: ARIS files reach gigabytes. The frames a file
can hold follow from its size (the SDK advises against trusting the file header's
``FrameCount``); of those, the good ones are the frames before the first whose header is
impossible or that is cut short (the rule of :class:`~sonarsim.io.readers._common.Recording`:
``n_frames``, ``read``, iteration and ``damage`` agree on them).
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np

from ...errors import ConfigError
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
    "ARIS_SIGNATURE",
    "FILE_HEADER_SIZE",
    "FRAME_HEADER_SIZE",
    "PING_MODE_BEAMS",
    "SAMPLES_PER_BEAM_LIMITS",
    "SAMPLE_PERIOD_US_LIMITS",
    "SAMPLE_START_DELAY_US_LIMITS",
    "SOUND_SPEED_LIMITS",
    "SYSTEM_TYPES",
    "WINDOW_END_MAX_M",
    "ArisRecording",
]

#: "DDF" + format version 5, little-endian, at byte 0 of the file header and byte 12 of every
#: frame header.
ARIS_SIGNATURE = 0x05464444

FILE_HEADER_SIZE = 1024
FRAME_HEADER_SIZE = 1024

#: Beam count of each ping mode (aris-file-sdk ``get_beams_from_pingmode``).
PING_MODE_BEAMS: dict[int, int] = {
    **dict.fromkeys((1, 2), 48),
    **dict.fromkeys((3, 4, 5), 96),
    **dict.fromkeys((6, 7, 8), 64),
    **dict.fromkeys((9, 10, 11, 12), 128),
}

#: ``TheSystemType`` -> (model name, key of the beam-angle fit, (HF, LF) frequency in kHz).
SYSTEM_TYPES: dict[int, tuple[str, str, tuple[float, float]]] = {
    0: ("ARIS 1800", "ARIS1800", (1800.0, 1100.0)),
    1: ("ARIS 3000", "ARIS3000", (3000.0, 1800.0)),
    2: ("ARIS 1200", "ARIS1200", (1200.0, 700.0)),
}

#: Elevation aperture of the standard lens (see the module notes; the telephoto lens's is
#: :data:`sonarsim.config.presets.ARIS_ELEVATION_FOV_DEG` ``["telephoto"]``).
ELEVATION_FOV_DEG = 14.0

# Physical plausibility of the frame-header fields the geometry comes from. Sound Metrics'
# own acoustic-settings limits (ARIS Integration SDK, ``SystemConfiguration``) are 200-4000
# samples per beam, sample periods of 4-100 us, sample start delays of 930-60000 us and
# windows ending at 20 m (ARIS 3000), 50 m (ARIS 1800) or 100 m (ARIS 1200). The limits here
# leave about a factor of 4 on every side, so that other firmware, DIDSON-derived settings or
# hand-made test files are not refused, while a corrupt field (0xFFFFFFFF us, a window of
# 6e9 m) is. The lower bounds of 1 keep files with short frames (tests, crops) readable.

#: Sound speeds (m/s) outside this interval mean a corrupt header, not water (1400-1560 m/s in
#: fresh to salt water, 0-35 degC).
SOUND_SPEED_LIMITS = (1000.0, 2000.0)
#: ``SamplesPerBeam`` allowed (device: 200-4000).
SAMPLES_PER_BEAM_LIMITS = (1, 16_000)
#: ``SamplePeriod`` allowed, microseconds (device: 4-100 us).
SAMPLE_PERIOD_US_LIMITS = (1, 400)
#: ``SampleStartDelay`` allowed, microseconds (device: 930-60000 us; 0 is harmless: 0 m).
SAMPLE_START_DELAY_US_LIMITS = (0, 240_000)
#: Farthest window end, metres (device: 100 m, the ARIS 1200's longest window).
WINDOW_END_MAX_M = 400.0
#: Bytes held per sample while a frame is read: the uint8 samples and the float32 image.
_BYTES_PER_SAMPLE_READ = 1 + 4

# (name, byte offset, struct format) of the frame-header fields decoded into the image's
# ``config["header"]``: the geometry, and what users ask for next (time, sonar state, the
# platform's attitude when an integration wrote it).
_FRAME_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("FrameIndex", 0, "<I"),
    ("FrameTime", 4, "<Q"),
    ("Version", 12, "<I"),
    ("Status", 16, "<I"),
    ("sonarTimeStamp", 20, "<Q"),
    ("WindowStart", 52, "<f"),
    ("WindowLength", 56, "<f"),
    ("ReceiverGain", 68, "<I"),
    ("Depth", 128, "<f"),
    ("Altitude", 132, "<f"),
    ("Pitch", 136, "<f"),
    ("Roll", 144, "<f"),
    ("Heading", 152, "<f"),
    ("CompassHeading", 160, "<f"),
    ("CompassPitch", 164, "<f"),
    ("CompassRoll", 168, "<f"),
    ("BeamTilt", 196, "<f"),
    ("WaterTemp", 224, "<f"),
    ("SampleRate", 420, "<f"),
    ("PingMode", 436, "<I"),
    ("FrequencyHiLow", 440, "<I"),
    ("PulseWidth", 444, "<I"),
    ("CyclePeriod", 448, "<I"),
    ("SamplePeriod", 452, "<I"),
    ("TransmitEnable", 456, "<I"),
    ("FrameRate", 460, "<f"),
    ("SoundSpeed", 464, "<f"),
    ("SamplesPerBeam", 468, "<I"),
    ("Enable150V", 472, "<I"),
    ("SampleStartDelay", 476, "<I"),
    ("LargeLens", 480, "<I"),
    ("TheSystemType", 484, "<I"),
    ("SonarSerialNumber", 488, "<I"),
    ("ArisErrorFlagsUint", 500, "<I"),
    ("MissedPackets", 504, "<I"),
    ("ArisAppVersion", 508, "<I"),
    ("ReorderedSamples", 516, "<I"),
    ("Salinity", 520, "<I"),
    ("Pressure", 524, "<f"),
)

# File-header fields kept for reference (most are obsolete; the frame headers rule).
_FILE_FIELDS: tuple[tuple[str, int, str], ...] = (
    ("Version", 0, "<I"),
    ("FrameCount", 4, "<I"),
    ("NumRawBeams", 16, "<I"),
    ("SamplesPerChannel", 24, "<I"),
    ("SN", 44, "<I"),
)
_FILE_DATE = (48, 32)  # strDate: char[32]


def _decode(buffer: bytes, fields: tuple[tuple[str, int, str], ...]) -> dict[str, Any]:
    # The buffer always has the full header size here, so unpack_from cannot fail.
    return {name: struct.unpack_from(fmt, buffer, offset)[0] for name, offset, fmt in fields}


class ArisRecording(Recording):
    """An open ARIS file; frames are read on demand with seeks.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.aris`` file (recognised by its signature, whatever its name).

    Raises
    ------
    RecordingError
        If the file is not an ARIS DDF_05 file, or its file header or first frame is truncated
        or impossible (nothing in it is readable). A damaged later frame ends the good frames
        instead (``n_frames``, ``damage``).
    OSError
        If the file cannot be opened.

    Examples
    --------
    >>> with ArisRecording("sample.aris") as rec:        # doctest: +SKIP
    ...     image = rec.read(0)
    """

    format = "aris"

    # -- layout ---------------------------------------------------------------------------

    def _open(self) -> None:
        head = read_at(
            self._handle, 0, FILE_HEADER_SIZE, self._file_size, self._source, "file header",
            f"ARIS file header ({FILE_HEADER_SIZE} bytes)",
        )
        (version,) = struct.unpack_from("<I", head, 0)
        if version != ARIS_SIGNATURE:
            raise RecordingError(
                self._source,
                f"signature 0x{version:08x} at byte 0 is not the ARIS DDF_05 signature "
                f"0x{ARIS_SIGNATURE:08x}",
                "file header", "Version",
            )
        self.file_header = _decode(head, _FILE_FIELDS)
        date = head[_FILE_DATE[0]:_FILE_DATE[0] + _FILE_DATE[1]].split(b"\0", 1)[0]
        self.file_header["strDate"] = date.decode("latin-1")

        data_bytes = self._file_size - FILE_HEADER_SIZE
        if data_bytes == 0:
            self._frame_size = 0
            self._n_complete = 0
            self._tail = 0
            return
        # Frame 0 fixes the frame size; every frame must share it (the SDK computes frame
        # offsets the same way), which _geometry() checks.
        self._frame_size = 0
        header = self._frame_header(0)
        self._n_beams = header["BeamCount"]
        self._n_samples = header["SamplesPerBeam"]
        self._frame_size = FRAME_HEADER_SIZE + self._n_samples * self._n_beams
        self._n_complete, self._tail = divmod(data_bytes, self._frame_size)
        if self._n_complete == 0:
            # Frame 0 itself does not fit: say which field asks for more than the file holds.
            raise RecordingError(
                self._source,
                f"SamplesPerBeam {self._n_samples} x {self._n_beams} beams (PingMode "
                f"{header['PingMode']}) = {self._n_samples * self._n_beams} sample bytes, but "
                f"the file holds only {data_bytes - FRAME_HEADER_SIZE} after the frame header "
                f"(truncated file or corrupt header)",
                "frame 0", "SamplesPerBeam",
            )

    def _where(self, frame: int) -> str:
        return f"frame {frame}"

    def _frame_header(self, frame: int) -> dict[str, Any]:
        """Decode and check frame ``frame``'s header; adds ``BeamCount``."""
        where = self._where(frame)
        offset = FILE_HEADER_SIZE + frame * self._frame_size
        raw = read_at(
            self._handle, offset, FRAME_HEADER_SIZE, self._file_size, self._source, where,
            f"frame header ({FRAME_HEADER_SIZE} bytes)",
        )
        h = _decode(raw, _FRAME_FIELDS)
        if h["Version"] != ARIS_SIGNATURE:
            raise RecordingError(
                self._source,
                f"signature 0x{h['Version']:08x} at byte {offset + 12} is not 0x{ARIS_SIGNATURE:08x}"
                " (corrupt file, or the frame size changed within the file)",
                where, "Version",
            )
        mode = h["PingMode"]
        if mode not in PING_MODE_BEAMS:
            raise RecordingError(
                self._source,
                f"unknown ping mode {mode} (known: 1-12, which give 48, 96, 64 or 128 beams); "
                "the beam count cannot be known",
                where, "PingMode",
            )
        h["BeamCount"] = PING_MODE_BEAMS[mode]
        if h["SamplesPerBeam"] == 0:
            raise RecordingError(self._source, "is 0: the frame has no samples", where, "SamplesPerBeam")
        if h["SamplePeriod"] == 0:
            raise RecordingError(self._source, "is 0 us: no range axis", where, "SamplePeriod")
        for name, limits, unit, what in (
            ("SamplesPerBeam", SAMPLES_PER_BEAM_LIMITS, "", "ARIS sonars record 200-4000"),
            ("SamplePeriod", SAMPLE_PERIOD_US_LIMITS, "us", "ARIS sonars use 4-100 us"),
            ("SampleStartDelay", SAMPLE_START_DELAY_US_LIMITS, "us", "ARIS sonars use 930-60000 us"),
        ):
            check_within(self._source, where, name, h[name], limits, unit, what)
        c = h["SoundSpeed"]
        lo, hi = SOUND_SPEED_LIMITS
        if not (math.isfinite(c) and lo <= c <= hi):
            raise RecordingError(
                self._source, f"{c!r} m/s is not a speed of sound in water ({lo:g}-{hi:g} m/s)",
                where, "SoundSpeed",
            )
        if h["ReorderedSamples"] == 0:
            # Recordings made by Sound Metrics' tools are always reordered; 0 means raw sonar
            # order, which needs the (unpublished here) reordering of the Integration SDK.
            raise RecordingError(
                self._source,
                "is 0: the samples are in the sonar's raw transmission order, which this reader "
                "does not undo",
                where, "ReorderedSamples",
            )
        if h["LargeLens"] not in (0, 1):
            raise RecordingError(
                self._source, f"is {h['LargeLens']}; expected 0 (no lens) or 1 (telephoto lens)",
                where, "LargeLens",
            )
        if h["TheSystemType"] not in SYSTEM_TYPES:
            raise RecordingError(
                self._source,
                f"unknown system type {h['TheSystemType']} (known: 0 = ARIS 1800, 1 = ARIS 3000, "
                "2 = ARIS 1200)",
                where, "TheSystemType",
            )
        return h

    # -- reading --------------------------------------------------------------------------

    def _check(self, k: int) -> bool:
        """Frame ``k`` is good when it is complete and its header passes :meth:`_geometry`
        (see :class:`~sonarsim.io.readers._common.Recording`); the samples are not read."""
        if k < self._n_complete:
            self._geometry(k)
            return True
        if k == self._n_complete and self._tail:
            part = "header" if self._tail < FRAME_HEADER_SIZE else "samples"
            raise RecordingError(
                self._source,
                f"truncated: the file ends {self._tail} bytes into this frame, in its {part} (a "
                f"frame is {self._frame_size} bytes: a {FRAME_HEADER_SIZE}-byte header and "
                f"{self._n_samples} x {self._n_beams} samples); the {self._n_complete} frames "
                "before it are complete",
                self._where(k),
            )
        return False

    def _geometry(self, k: int) -> dict[str, Any]:
        """Frame ``k``'s checked header and what the image is built from (all but the samples).

        Raises
        ------
        RecordingError
            An impossible header, a frame size other than frame 0's, a window beyond any ARIS,
            a frame beyond the memory budget, or a lens without a beam table.
        """
        where = self._where(k)
        h = self._frame_header(k)
        for name, first in (("PingMode", self._n_beams), ("SamplesPerBeam", self._n_samples)):
            value = h["BeamCount"] if name == "PingMode" else h[name]
            if value != first:
                raise RecordingError(
                    self._source,
                    f"gives {value} {'beams' if name == 'PingMode' else 'samples per beam'}, "
                    f"frame 0 {first}: frames of different sizes in one file are not supported",
                    where, name,
                )
        n_samples, n_beams = self._n_samples, self._n_beams
        # The window first: a frame with an impossible range axis is refused before its
        # samples are read.
        c = h["SoundSpeed"]
        start = h["SampleStartDelay"] * 1e-6 * c / 2.0
        dr = h["SamplePeriod"] * 1e-6 * c / 2.0
        check_range_window(
            self._source, where, "SamplePeriod", start, n_samples * dr, WINDOW_END_MAX_M,
            f"SampleStartDelay {h['SampleStartDelay']} us + SamplesPerBeam {n_samples} x "
            f"SamplePeriod {h['SamplePeriod']} us at SoundSpeed {c:.6g} m/s",
        )
        require_frame_memory(
            self._source, where, "SamplesPerBeam", n_samples, n_beams, _BYTES_PER_SAMPLE_READ
        )
        model, fit_key, (hf_khz, lf_khz) = SYSTEM_TYPES[h["TheSystemType"]]
        telephoto = h["LargeLens"] == 1
        angles = self._beam_angles(model, "ARIS-telephoto" if telephoto else fit_key, n_beams, h, where)
        from ...config.presets import ARIS_ELEVATION_FOV_DEG, aris_preset_name

        return {
            "header": h, "where": where, "start": start, "end": start + n_samples * dr, "dr": dr,
            "model": model, "telephoto": telephoto, "angles": angles,
            "elevation": ARIS_ELEVATION_FOV_DEG["telephoto" if telephoto else "standard"],
            "preset": aris_preset_name(fit_key, n_beams, telephoto),
            "frequency": hf_khz if h["FrequencyHiLow"] == 1 else lf_khz,
        }

    def read(self, frame: int = 0):
        """Frame ``frame`` (0-based) as a :class:`~sonarsim.image.result.SonarImage`.

        Returns
        -------
        SonarImage
            ``polar`` float32 ``(SamplesPerBeam, BeamCount)`` of the recorded 8-bit values,
            row 0 nearest, column 0 the left-most beam; ``config`` holds the source, format,
            frame and the decoded frame header (plus ``model``, ``lens``, ``preset``,
            ``elevation_fov_deg_assumed``, ``BeamCount``,
            ``window_start_m``, ``window_end_m``, ``sample_length_m`` and ``file_header``).

        Raises
        ------
        RecordingError
            Frame out of range, truncated, with an impossible header, or after such a frame
            (see :class:`~sonarsim.io.readers._common.Recording`: the good frames).
        """
        return super().read(frame)

    def _read(self, k: int):
        from ...image.result import SonarImage
        from ...config.sonar import SonarConfig

        g = self._geometry(k)
        h, where, start, end = g["header"], g["where"], g["start"], g["end"]
        n_samples, n_beams = self._n_samples, self._n_beams
        offset = FILE_HEADER_SIZE + k * self._frame_size + FRAME_HEADER_SIZE
        raw = read_at(
            self._handle, offset, n_samples * n_beams, self._file_size, self._source, where,
            f"samples ({n_samples} x {n_beams} bytes)",
        )
        # data[sample, beam], beam 0 right-most -> flip so column 0 is the left-most beam.
        samples = np.frombuffer(raw, dtype=np.uint8).reshape(n_samples, n_beams)[:, ::-1]
        polar = np.ascontiguousarray(samples, dtype=np.float32)
        try:
            sonar = SonarConfig(
                beam_angles_deg=tuple(g["angles"]),
                elevation_fov_deg=g["elevation"],
                range_min_m=start,
                range_max_m=end,
                n_range_bins=n_samples,
                frequency_khz=g["frequency"],
                preset=g["preset"],
            )
        except ConfigError as exc:  # defensive: the checks above should make this impossible
            raise RecordingError(self._source, f"gives an impossible sonar: {exc}", where) from exc

        header = dict(h)
        header.update(
            model=g["model"],
            lens="telephoto" if g["telephoto"] else "standard",
            window_start_m=start,
            window_end_m=end,
            sample_length_m=g["dr"],
            frequency_khz=g["frequency"],
            bits_per_value=8,
            elevation_fov_deg_assumed=g["elevation"],
            preset=g["preset"],
            file_header=dict(self.file_header),
        )
        return SonarImage(
            polar=polar,
            range_m=sonar.grid.range_m,
            azimuth_deg=sonar.grid.azimuth_deg,
            components={"total": polar},
            sonar=sonar,
            pose=None,  # not recorded
            rays=None,
            config={"source": self._source, "format": self.format, "frame": k, "header": header},
        )

    def _beam_angles(self, model: str, fit_key: str, n_beams: int, h: dict, where: str) -> np.ndarray:
        from ...config.presets import aris_beam_angles_deg

        try:
            return aris_beam_angles_deg(fit_key, n_beams)
        except ConfigError:
            lens = "telephoto lens" if h["LargeLens"] else "standard lens"
            raise RecordingError(
                self._source,
                f"{model} ({lens}, TheSystemType {h['TheSystemType']}, LargeLens "
                f"{h['LargeLens']}) with {n_beams} beams (PingMode {h['PingMode']}): Sound "
                "Metrics publishes no beam-angle table for this combination (known: ARIS "
                "1200/1800 x 48, ARIS 1800 x 96, ARIS 3000 x 64/128, telephoto lens x 48/96)",
                where, "PingMode",
            ) from None
