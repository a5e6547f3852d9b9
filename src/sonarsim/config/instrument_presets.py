"""Device presets for the sonar types beyond the FLS: side-scan, multibeam, scanning, single-beam.

Each preset is plain data: a name, a type, the device figures under fixed key names (units in the
names), a ``source`` saying where each figure comes from and a ``notes`` string saying which
figures are inferred or our own choice. Nothing here depends on the renderer; the renderer and
the scene loader read these tables.

Words used in ``source`` and ``notes`` (as in ``docs/presets.md``):

- *recording*: read from the recordings in ``../shared/data/real`` (design notes, section 6);
- *confirmed*: read in a manufacturer's document, software or data during this work;
- *secondary*: stated by a third party (a data set's description, a driver, a simulator);
- *not confirmed*: the figure commonly quoted for the device, no copy of the data sheet found;
- *inferred*: computed from other documented figures (the computation is given);
- *our choice*: not a device property (a default window, a sample count).

Keys per type (:data:`INSTRUMENT_KEYS`; optional extras in :data:`OPTIONAL_KEYS`):

- ``sidescan``: ``frequency_khz``, ``horizontal_beam_width_deg`` (along track, -3 dB),
  ``vertical_beam_width_deg`` (across track, -3 dB), ``depression_deg`` (beam axis below the
  horizontal), ``range_max_m`` (the default slant range), ``n_samples`` (per side per ping),
  ``pulse_length_us``, ``ping_rate_hz`` (``None``: derived from the range, see
  :func:`ping_rate_hz`).
- ``multibeam``: ``frequency_khz``, ``n_beams``, ``swath_deg`` (outermost beam centres, total),
  ``tx_beam_width_along_deg``, ``rx_beam_width_across_deg``, ``pulse_length_us``,
  ``range_max_m``, ``ping_rate_hz_max``, ``beam_spacing`` (``"equiangular"`` or
  ``"equidistant"``).
- ``scanning``: ``frequency_khz``, ``horizontal_beam_width_deg``, ``vertical_beam_width_deg``,
  ``steps_per_turn``, ``range_max_m``, ``n_samples_max``, ``n_samples`` (default),
  ``step_overhead_s`` (time per step besides listening, for a one-step move; see
  :func:`scan_step_period_s`).
- ``singlebeam``: ``frequency_khz``, ``beam_width_deg`` (conical, -3 dB), ``range_max_m``,
  ``n_samples``, ``ping_rate_hz``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping, Optional

from sonarsim.errors import ConfigError, shown

__all__ = [
    "INSTRUMENT_TYPES",
    "INSTRUMENT_KEYS",
    "OPTIONAL_KEYS",
    "BEAM_SPACINGS",
    "InstrumentPreset",
    "INSTRUMENT_PRESETS",
    "instrument_preset",
    "instrument_presets",
    "check_instrument_preset",
    "ping_rate_hz",
    "scan_step_period_s",
    "Ping360Settings",
    "ping360_settings",
]

#: The sonar types this module describes, in the order the tables list them.
INSTRUMENT_TYPES: tuple[str, ...] = ("sidescan", "multibeam", "scanning", "singlebeam")

#: The keys every preset of a type gives.
INSTRUMENT_KEYS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "sidescan": (
            "frequency_khz",
            "horizontal_beam_width_deg",
            "vertical_beam_width_deg",
            "depression_deg",
            "range_max_m",
            "n_samples",
            "pulse_length_us",
            "ping_rate_hz",
        ),
        "multibeam": (
            "frequency_khz",
            "n_beams",
            "swath_deg",
            "tx_beam_width_along_deg",
            "rx_beam_width_across_deg",
            "pulse_length_us",
            "range_max_m",
            "ping_rate_hz_max",
            "beam_spacing",
        ),
        "scanning": (
            "frequency_khz",
            "horizontal_beam_width_deg",
            "vertical_beam_width_deg",
            "steps_per_turn",
            "range_max_m",
            "n_samples_max",
            "n_samples",
            "step_overhead_s",
        ),
        "singlebeam": (
            "frequency_khz",
            "beam_width_deg",
            "range_max_m",
            "n_samples",
            "ping_rate_hz",
        ),
    }
)

#: Keys a preset of a type may give besides :data:`INSTRUMENT_KEYS` (device limits some
#: presets know).
OPTIONAL_KEYS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "sidescan": ("range_limit_m",),
        "multibeam": ("range_limit_m",),
        "scanning": (
            "range_min_m",
            "n_samples_min",
            "motor_time_per_step_s",
            "sample_period_tick_ns",
            "sample_period_ticks_min",
            "sample_period_ticks_max",
            "transmit_duration_us_min",
            "transmit_duration_us_max",
        ),
        "singlebeam": ("range_min_m", "range_limit_m"),
    }
)

#: Allowed ``beam_spacing`` values of a multibeam preset.
BEAM_SPACINGS: tuple[str, ...] = ("equiangular", "equidistant")

# Keys whose values are counts (positive integers, bool excluded).
_INTEGER_KEYS = frozenset(
    {
        "n_samples",
        "n_beams",
        "steps_per_turn",
        "n_samples_max",
        "n_samples_min",
        "sample_period_ticks_min",
        "sample_period_ticks_max",
    }
)
# Keys that may be 0 (a motor that adds no time per extra step).
_NON_NEGATIVE_KEYS = frozenset({"motor_time_per_step_s"})
# Keys that may be None (derived at use).
_NULLABLE_KEYS = frozenset({"ping_rate_hz"})


@dataclass(frozen=True)
class InstrumentPreset:
    """A named device configuration of one of the :data:`INSTRUMENT_TYPES`.

    Parameters
    ----------
    name : str
        Key in :data:`INSTRUMENT_PRESETS`, e.g. ``"ping360"``.
    type : str
        One of :data:`INSTRUMENT_TYPES`.
    description : str
        Device and operating mode in words.
    values : mapping of str to object
        The figures under the keys of :data:`INSTRUMENT_KEYS` for the type (and any of
        :data:`OPTIONAL_KEYS`), stored read-only. Units are in the key names.
    source : str
        Where each figure comes from (document name, version, year; or the recording).
    notes : str
        Which figures are inferred, secondary or our choice, and how inferred ones were
        computed. Empty only when every figure is confirmed.

    Notes
    -----
    ``preset["frequency_khz"]`` reads a figure; :meth:`as_dict` returns a mutable copy of
    ``values`` together with ``type``, ``source`` and ``notes``.
    """

    name: str
    type: str
    description: str
    values: Mapping[str, object]
    source: str
    notes: str = ""

    def __post_init__(self) -> None:
        # The dataclass is frozen; object.__setattr__ is the documented way to store the
        # read-only copy during construction.
        object.__setattr__(self, "values", MappingProxyType(dict(self.values)))
        check_instrument_preset(self)

    def __getitem__(self, key: str) -> object:
        return self.values[key]

    def __contains__(self, key: object) -> bool:
        return key in self.values

    def get(self, key: str, default: object = None) -> object:
        """``values.get(key, default)``."""
        return self.values.get(key, default)

    def as_dict(self) -> dict[str, object]:
        """The preset as one plain dict: ``type``, the values, ``source``, ``notes``."""
        return {"type": self.type, **self.values, "source": self.source, "notes": self.notes}


def check_instrument_preset(preset: InstrumentPreset) -> None:
    """Check a preset against its type's keys and value rules.

    Parameters
    ----------
    preset : InstrumentPreset

    Raises
    ------
    ConfigError
        With key ``preset.NAME.KEY`` (or ``preset.NAME``) on an unknown type, a missing or
        unknown key, a count that is not a positive integer, a figure that is not a positive
        finite number, a ``beam_spacing`` outside :data:`BEAM_SPACINGS`, or an empty source.
    """
    where = f"preset.{preset.name}"
    if preset.type not in INSTRUMENT_TYPES:
        raise ConfigError(
            where, f"unknown type {shown(preset.type)}; allowed: {', '.join(INSTRUMENT_TYPES)}"
        )
    required = INSTRUMENT_KEYS[preset.type]
    allowed = set(required) | set(OPTIONAL_KEYS[preset.type])
    for key in required:
        if key not in preset.values:
            raise ConfigError(f"{where}.{key}", f"missing (a {preset.type} preset gives it)")
    for key, value in preset.values.items():
        if key not in allowed:
            raise ConfigError(
                f"{where}.{key}",
                f"unknown key for a {preset.type} preset; allowed: {', '.join(sorted(allowed))}",
            )
        if key == "beam_spacing":
            if value not in BEAM_SPACINGS:
                raise ConfigError(
                    f"{where}.{key}", f"{shown(value)}; allowed: {', '.join(BEAM_SPACINGS)}"
                )
            continue
        if value is None and key in _NULLABLE_KEYS:
            continue
        if key in _INTEGER_KEYS:
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{where}.{key}", f"{shown(value)}; give a positive integer")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}.{key}", f"{shown(value)}; give a finite number")
        if value < 0 or (value == 0 and key not in _NON_NEGATIVE_KEYS):
            raise ConfigError(f"{where}.{key}", f"{shown(value)}; give a positive number")
    if not isinstance(preset.source, str) or not preset.source.strip():
        raise ConfigError(f"{where}.source", "empty; say where the figures come from")
    if not isinstance(preset.notes, str):
        raise ConfigError(f"{where}.notes", "must be a string")


# --------------------------------------------------------------------------------------------
# The table
# --------------------------------------------------------------------------------------------

_SEASCAN_RECORDING = (
    "recording ../shared/data/real/sidescan/iver2_seascan_pings_0-179.xtf (CIDCO OpenSidescan "
    "test data, Marine Sonic Sea Scan HDS on an Iver2 AUV, 2013; design notes section 6): "
    "file header SonarName 'HDS', channel frequency 600 kHz, NumSamples 1024 per side, "
    "SlantRange 29.98 m, SecondsPerPing 0.03998 s"
)

_R2SONIC_RECORDING = (
    "recording ../shared/data/real/multibeam/r2sonic2026_pings_0-459.xtf (CIDCO MBES-lib test "
    "data, San Francisco Bay 2015; design notes section 6), BTH0 H0 section of every ping: model "
    "'2026', frequency 400 kHz, TxPulseWidth 35 us, TxBeamwidthVert 1.0 deg, TxBeamwidthHoriz "
    "0.5 deg, 256 points, ping period 0.0522 s; A2 section (equidistant mode), beam centres "
    "-61.54 .. +61.98 deg"
)

_IMAGENEX_DATASHEET = (
    "Imagenex Technology Corp., 'Model 852 ultra-miniature 11000 m echo sounder' data sheet "
    "445-060 (March 2009, revised May 2017): 330 kHz, 30 deg conical beam, 20 mm range "
    "resolution, 0.5 m minimum detectable range, 50 m maximum range, range scales 5-50 m"
)

_PING360_DOCS = (
    "Blue Robotics: Ping360 protocol documentation (ping-protocol, 'Ping360 messages': head "
    "angle in gradians 0-399, sample period in 25 ns ticks 80-40000, 200-1200 samples, "
    "transmit 1-1000 us, 500-1000 kHz with 650-850 kHz practical); Ping Viewer source "
    "(src/sensor/ping360.h: viewer default 750 kHz and 1200 samples, firmware transmit limits "
    "5-500 us and at most 64 sample periods, the automatic transmit rule); Blue Robotics forum "
    "staff replies ('Understanding the Ping 360 specifications', 2 deg horizontal beam, 0.9 deg "
    "mechanical step, up to 1200 samples; 'Ping360 effective range', 50 m maximum range; "
    "'Ping 360 time info/split image', measured full-turn times over Ethernet)"
)

_INSTRUMENT_PRESET_LIST: tuple[InstrumentPreset, ...] = (
    # ---------------------------------------------------------------- side-scan
    InstrumentPreset(
        name="seascan_hds_600",
        type="sidescan",
        description="Marine Sonic Sea Scan HDS side-scan, 600 kHz, as recorded on an Iver2 AUV",
        values={
            "frequency_khz": 600.0,
            "horizontal_beam_width_deg": 0.5,
            "vertical_beam_width_deg": 50.0,
            "depression_deg": 10.0,
            "range_max_m": 29.98,
            "n_samples": 1024,
            "pulse_length_us": 40.0,
            "ping_rate_hz": 8.13,
        },
        source=_SEASCAN_RECORDING,
        notes=(
            "From the recording: frequency, samples per side, slant range, and the ping rate: "
            "the ping times are 0.123 s apart on average (180 consecutive ping numbers over 22 s), "
            "8.13 pings a second; the header's 0.04 s per ping is the listening time "
            "(2 x 29.98 m / 1500 m/s), not the ping interval. No Marine "
            "Sonic data sheet was found: the beam widths (0.5 deg along track, 50 deg across) "
            "and the 10 deg depression are typical values for a 600 kHz AUV side-scan (design "
            "notes section 13: 0.2-1 deg, 40-60 deg, 10-20 deg), not device figures. The 40 us "
            "pulse is inferred: the pulse whose range extent equals the recording's sample "
            "spacing, 2 x (29.98 m / 1024) / 1500 m/s = 39 us."
        ),
    ),
    InstrumentPreset(
        name="edgetech_4125_400",
        type="sidescan",
        description="EdgeTech 4125 dual-frequency side-scan towfish, 400 kHz channel (400/900 kHz set)",
        values={
            "frequency_khz": 400.0,
            "horizontal_beam_width_deg": 0.46,
            "vertical_beam_width_deg": 50.0,
            "depression_deg": 20.0,
            "range_max_m": 150.0,
            "n_samples": 4096,
            "pulse_length_us": 31.0,
            "ping_rate_hz": None,
        },
        source=(
            "EdgeTech 4125 data-sheet values as commonly quoted (not confirmed: of EdgeTech's "
            "'4125i/4125 Side Scan Sonar System User Hardware Manual' 0004823 rev K, September "
            "2024, only the title and towing pages were found, and they give no beam figures)"
        ),
        notes=(
            "Not confirmed: the 400/900 kHz frequency set (a 600/1600 kHz set is also quoted), "
            "0.46 deg horizontal beam, 50 deg vertical beam, 20 deg "
            "depression (the 4125 towfish's tilt down as commonly quoted), 150 m maximum range "
            "per side, 2.3 cm across-track resolution. The 4125 transmits FM (CHIRP) pulses of "
            "milliseconds; pulse_length_us is inferred as the equivalent compressed pulse of the "
            "quoted 2.3 cm resolution, 2 x 0.023 m / 1500 m/s = 31 us. n_samples is our choice "
            "(150 m / 4096 = 3.7 cm, about the quoted resolution)."
        ),
    ),
    InstrumentPreset(
        name="edgetech_4125_900",
        type="sidescan",
        description="EdgeTech 4125 dual-frequency side-scan towfish, 900 kHz channel (400/900 kHz set)",
        values={
            "frequency_khz": 900.0,
            "horizontal_beam_width_deg": 0.28,
            "vertical_beam_width_deg": 50.0,
            "depression_deg": 20.0,
            "range_max_m": 75.0,
            "n_samples": 4096,
            "pulse_length_us": 20.0,
            "ping_rate_hz": None,
        },
        source=(
            "EdgeTech 4125 data-sheet values as commonly quoted (not confirmed; see "
            "edgetech_4125_400)"
        ),
        notes=(
            "Not confirmed: 900 kHz, 0.28 deg horizontal beam, 50 deg vertical beam, 20 deg "
            "depression, 75 m maximum range per side, 1.5 cm across-track resolution. "
            "pulse_length_us is inferred as the compressed pulse of that resolution, 2 x 0.015 m "
            "/ 1500 m/s = 20 us. n_samples is our choice (75 m / 4096 = 1.8 cm)."
        ),
    ),
    InstrumentPreset(
        name="klein_3000_100",
        type="sidescan",
        description="Klein System 3000 dual-frequency side-scan towfish, 100 kHz channel",
        values={
            "frequency_khz": 100.0,
            "horizontal_beam_width_deg": 1.0,
            "vertical_beam_width_deg": 40.0,
            "depression_deg": 10.0,
            "range_max_m": 600.0,
            "n_samples": 2048,
            "pulse_length_us": 100.0,
            "ping_rate_hz": None,
        },
        source=(
            "Secondary: the device table of CCOM/UNH's CUBE library (libccom device.c, 'Klein "
            "3000', figures marked there as from product literature or guessed): 100/500 kHz, "
            "40 deg across-track and 1.0 deg along-track beam widths, 0.025 ms shortest pulse "
            "(guessed there). Otherwise the Klein 3000 data-sheet values as commonly quoted (not "
            "confirmed)"
        ),
        notes=(
            "Not confirmed: the 600 m maximum range at 100 kHz; the depression (the tilt is "
            "commonly quoted as adjustable, 5-25 deg; 10 deg is our choice). The nominal 100 kHz "
            "is sometimes quoted as 132 kHz actual (not confirmed). The 100 us pulse is our "
            "choice inside the commonly quoted selectable 25-400 us. n_samples is our choice."
        ),
    ),
    InstrumentPreset(
        name="klein_3000_500",
        type="sidescan",
        description="Klein System 3000 dual-frequency side-scan towfish, 500 kHz channel",
        values={
            "frequency_khz": 500.0,
            "horizontal_beam_width_deg": 0.2,
            "vertical_beam_width_deg": 40.0,
            "depression_deg": 10.0,
            "range_max_m": 150.0,
            "n_samples": 2048,
            "pulse_length_us": 25.0,
            "ping_rate_hz": None,
        },
        source=(
            "Secondary: CUBE library device table (libccom device.c, 'Klein 3000'): 100/500 kHz, "
            "40 deg across-track beam width, 0.025 ms shortest pulse. Otherwise the Klein 3000 "
            "data-sheet values as commonly quoted (not confirmed)"
        ),
        notes=(
            "Not confirmed: 0.2 deg along-track beam at 500 kHz (CUBE lists one along-track "
            "width, 1.0 deg, which fits the 100 kHz channel), 150 m maximum range; the nominal "
            "500 kHz is sometimes quoted as 445 kHz actual. The 10 deg depression is our choice "
            "(adjustable 5-25 deg as commonly quoted). The 25 us pulse is the shortest pulse "
            "CUBE gives (guessed there). n_samples is our choice."
        ),
    ),
    # ---------------------------------------------------------------- multibeam
    InstrumentPreset(
        name="r2sonic_2026_400",
        type="multibeam",
        description="R2Sonic Sonic 2026 multibeam echosounder at 400 kHz, as recorded (equidistant beams)",
        values={
            "frequency_khz": 400.0,
            "n_beams": 256,
            "swath_deg": 123.5,
            "tx_beam_width_along_deg": 1.0,
            "rx_beam_width_across_deg": 0.5,
            "pulse_length_us": 35.0,
            "range_max_m": 32.0,
            "ping_rate_hz_max": 60.0,
            "beam_spacing": "equidistant",
            "range_limit_m": 500.0,
        },
        source=(
            _R2SONIC_RECORDING
            + "; R2Sonic 'Sonic 2026/2024/2022 Operation Manual' V6.3 (rev r012, 2022): sector "
            "10-160 deg with all 256 beams, 170-450 kHz; 'Sonic 2024/2022 Operation Manual' V3.0 "
            "(2010), head commands: range 2-500 m, ping rate limit 0.1-60 Hz, 'narrow (1 deg)' "
            "projector"
        ),
        notes=(
            "Which width is which: the head reports TxBeamwidthVert = 1.0 deg and "
            "TxBeamwidthHoriz = 0.5 deg. The 1.0 deg is the projector's fan thickness, i.e. along "
            "track (the V3.0 manual's 'narrow (1 deg)' projector); the 0.5 deg is the receive "
            "beam width across track (a Mills cross: the transmit fan is narrow along track, the "
            "receive beams narrow across it). So tx_beam_width_along_deg = 1.0, "
            "rx_beam_width_across_deg = 0.5. swath_deg is the recording's span of beam centres "
            "(the design notes' 'about -60 to +63 deg' are roll-affected); range_max_m is the "
            "recording's RxRange (31.9 m) rounded up; the recording pinged at 19.2 Hz. The 500 m "
            "range limit and 60 Hz ping-rate limit are the 2010 manual's command bounds (Sonic "
            "2024/2022); that the 2026 has the same bounds is an assumption."
        ),
    ),
    InstrumentPreset(
        name="kongsberg_em2040",
        type="multibeam",
        description="Kongsberg EM 2040 multibeam echosounder, single swath, 0.5 x 1 deg configuration",
        values={
            "frequency_khz": 300.0,
            "n_beams": 400,
            "swath_deg": 140.0,
            "tx_beam_width_along_deg": 0.5,
            "rx_beam_width_across_deg": 1.0,
            "pulse_length_us": 25.0,
            "range_max_m": 600.0,
            "ping_rate_hz_max": 50.0,
            "beam_spacing": "equidistant",
        },
        source=(
            "Kongsberg 'EM 2040 Multibeam echo sounder' brochure (as published on yumpu, 2014): "
            "200-400 kHz operating band, beam widths 0.5 x 1 deg or 1 x 1 deg, the 0.5 deg being "
            "the transmit fan; otherwise EM 2040 data-sheet values as commonly quoted (not "
            "confirmed)"
        ),
        notes=(
            "300 kHz is our choice (the middle of the confirmed 200-400 kHz band); the beam "
            "widths are taken as nominal at that frequency (not confirmed). Not confirmed: 400 "
            "beams per swath, 140 deg swath for one receiver, 25 us shortest CW pulse, 600 m "
            "depth range, 50 Hz maximum ping rate. Equidistant spacing is our choice (the system "
            "offers equiangular and equidistant)."
        ),
    ),
    # ---------------------------------------------------------------- mechanical scanning
    InstrumentPreset(
        name="ping360",
        type="scanning",
        description="Blue Robotics Ping360 mechanical scanning imaging sonar",
        values={
            "frequency_khz": 750.0,
            "horizontal_beam_width_deg": 2.0,
            "vertical_beam_width_deg": 25.0,
            "steps_per_turn": 400,
            "range_max_m": 50.0,
            "n_samples_max": 1200,
            "n_samples": 1200,
            "step_overhead_s": 0.0254,
            "range_min_m": 0.3,
            "n_samples_min": 200,
            "motor_time_per_step_s": 0.0060,
            "sample_period_tick_ns": 25.0,
            "sample_period_ticks_min": 80,
            "sample_period_ticks_max": 40000,
            "transmit_duration_us_min": 5.0,
            "transmit_duration_us_max": 500.0,
        },
        source=_PING360_DOCS,
        notes=(
            "Not confirmed here: the 25 deg vertical beam (Blue Robotics' quoted 2 x 25 deg; the "
            "design notes section 13). Inferred: step_overhead_s and motor_time_per_step_s, a "
            "least-squares fit of the forum's six full-turn times (Ping Viewer over Ethernet, "
            "1200 samples, 1500 m/s: 10.74, 20.57, 37.6 s at 2, 20, 50 m with 1-gradian steps; "
            "3.29, 4.19, 5.89 s with 10-gradian steps) to 'listening time + 19.4 ms + 6.0 ms per "
            "gradian moved': 25.4 ms per ping at one-gradian steps, within 5 % of every "
            "measurement. range_min_m is inferred: 200 samples at the shortest sample period "
            "(80 ticks) span 0.3 m. Sample period and transmit rules: see ping360_settings."
        ),
    ),
    InstrumentPreset(
        name="tritech_micron",
        type="scanning",
        description="Tritech Micron (DST, CHIRP) mechanical scanning imaging sonar, 1.8 deg steps",
        values={
            "frequency_khz": 700.0,
            "horizontal_beam_width_deg": 3.0,
            "vertical_beam_width_deg": 35.0,
            "steps_per_turn": 200,
            "range_max_m": 75.0,
            "n_samples_max": 1500,
            "n_samples": 400,
            "step_overhead_s": 0.025,
            "motor_time_per_step_s": 0.0,
        },
        source=(
            "Secondary: the sonar table of the Girona underwater caves data set (Mallios et al., "
            "2017; as repeated in the NautiloPy project's README): Micron DST chirped 650-750 kHz, "
            "75 m maximum range, 3 deg horizontal and 35 deg vertical beam widths, 5-20 s per "
            "360 deg scan; the Rock sonar simulator's Micron DST settings (3 x 35 deg beam, "
            "1.8 deg angular resolution); McGill's ros-tritech-micron driver (head angles in "
            "1/16 gradian, 6400 per turn; steps of 4-255 units; 200-400 bins by default, up to "
            "1500 configurable)"
        ),
        notes=(
            "No Tritech data sheet was found. 700 kHz is the middle of the secondary 650-750 "
            "kHz chirp. steps_per_turn = 200 is the 1.8 deg step (32 of the head's 1/16-gradian "
            "units; the driver's default 'low' resolution), our choice among the head's steps "
            "(0.225-3.6 deg are common). n_samples_max = 1500 is the driver's configurable upper "
            "bound, not a confirmed device limit; n_samples = 400 is the driver's default. "
            "step_overhead_s is inferred: the fastest quoted full scan, 5 s over 200 steps, "
            "gives 25 ms per step at short range (where listening takes a few ms); no per-step "
            "motor figure is known (motor_time_per_step_s = 0)."
        ),
    ),
    # ---------------------------------------------------------------- single-beam
    InstrumentPreset(
        name="imagenex_852",
        type="singlebeam",
        description="Imagenex 852 ultra-miniature echo sounder, 10 m range scale, as recorded",
        values={
            "frequency_khz": 330.0,
            "beam_width_deg": 30.0,
            "range_max_m": 10.0,
            "n_samples": 500,
            "ping_rate_hz": 1.0,
            "range_min_m": 0.5,
            "range_limit_m": 50.0,
        },
        source=(
            _IMAGENEX_DATASHEET
            + "; recording ../shared/data/real/singlebeam/imagenex852_2016-11-18.852 (CIDCO "
            "Imagenex852 test data; design notes section 6): 917 records, each with range 10 m "
            "and 500 echo bytes in its return header, time stamps 1.0 s apart"
        ),
        notes=(
            "The 10 m window, 500 samples (20 mm each, the data sheet's range resolution) and 1 "
            "ping per second are the recording's settings; the sounder may ping faster at this "
            "range (no maximum ping rate is published in the data sheet seen). The 30 deg beam "
            "is the data sheet's; that it is a -3 dB width is an assumption (the data sheet does "
            "not say)."
        ),
    ),
    InstrumentPreset(
        name="ping2",
        type="singlebeam",
        description="Blue Robotics Ping2 sonar altimeter and echosounder",
        values={
            "frequency_khz": 115.0,
            "beam_width_deg": 25.0,
            "range_max_m": 100.0,
            "n_samples": 200,
            "ping_rate_hz": 10.0,
            "range_min_m": 0.3,
        },
        source=(
            "Blue Robotics 'Ping Echosounder Sonar User Manual' (bluerobotics.com/learn/"
            "ping-sonar-technical-guide, current revision): 115 kHz pulse, 25 deg beam width, "
            "100 m range (an older revision of the same page gave 30 m and 30 deg); Ping Viewer "
            "documentation (2019 data sheet copy): profiles of 200 samples over the scan range; "
            "Blue Robotics ping-protocol 'Ping1d messages': scan length at least 1 m, ping "
            "interval set in ms (no default or limit stated)"
        ),
        notes=(
            "The 25 deg beam width's level (-3 dB or otherwise) is not stated. Not confirmed: "
            "the 0.3 m minimum range; ping_rate_hz = 10 is a typical profile rate (our choice; "
            "the device pings as fast as its range and ping-interval setting allow)."
        ),
    ),
)

#: All presets by name (read-only), in table order: side-scan, multibeam, scanning, single-beam.
INSTRUMENT_PRESETS: Mapping[str, InstrumentPreset] = MappingProxyType(
    {preset.name: preset for preset in _INSTRUMENT_PRESET_LIST}
)
if len(INSTRUMENT_PRESETS) != len(_INSTRUMENT_PRESET_LIST):  # pragma: no cover - table typo
    raise RuntimeError("two instrument presets share a name")


def instrument_presets(type: Optional[str] = None) -> tuple[str, ...]:
    """Names of the built-in instrument presets, in table order.

    Parameters
    ----------
    type : str, optional
        One of :data:`INSTRUMENT_TYPES`; None lists every preset.

    Returns
    -------
    tuple of str

    Raises
    ------
    ConfigError
        With key ``type`` for an unknown type; the message lists the types.
    """
    if type is None:
        return tuple(INSTRUMENT_PRESETS)
    if not isinstance(type, str) or type not in INSTRUMENT_TYPES:
        raise ConfigError(
            "type", f"unknown sonar type {shown(type)}; allowed: {', '.join(INSTRUMENT_TYPES)}"
        )
    return tuple(name for name, preset in INSTRUMENT_PRESETS.items() if preset.type == type)


def instrument_preset(name: str, type: Optional[str] = None) -> InstrumentPreset:
    """Look up a built-in instrument preset.

    Parameters
    ----------
    name : str
        Preset name, e.g. ``"seascan_hds_600"`` (see :func:`instrument_presets`).
    type : str, optional
        The sonar type the caller needs (one of :data:`INSTRUMENT_TYPES`); the preset must be
        of that type. None accepts any type.

    Returns
    -------
    InstrumentPreset

    Raises
    ------
    ConfigError
        With key ``preset`` when there is no preset of that name, or when it is of another type
        than ``type``; the message names the preset and lists the allowed ones (those of
        ``type``, or all of them by type). With key ``type`` for an unknown type.
    """
    allowed = instrument_presets(type)  # checks the type first
    preset = INSTRUMENT_PRESETS.get(name) if isinstance(name, str) else None
    if preset is not None and (type is None or preset.type == type):
        return preset
    if type is not None:
        what = (
            f"{shown(name)} is a {preset.type} preset, not a {type} one"
            if preset is not None
            else f"unknown {type} preset {shown(name)}"
        )
        raise ConfigError("preset", f"{what}; allowed: {', '.join(allowed)}")
    by_type = "; ".join(f"{t}: {', '.join(instrument_presets(t))}" for t in INSTRUMENT_TYPES)
    raise ConfigError("preset", f"unknown instrument preset {shown(name)}; allowed: {by_type}")


# --------------------------------------------------------------------------------------------
# Derived timing
# --------------------------------------------------------------------------------------------


def _positive(key: str, value: float) -> float:
    """``value`` as a float, refused with a ConfigError naming ``key`` unless positive finite."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ConfigError(key, f"{shown(value)}; give a positive finite number")
    return float(value)


def ping_rate_hz(
    preset: InstrumentPreset, range_m: Optional[float] = None, sound_speed_m_s: float = 1500.0
) -> float:
    """A side-scan or single-beam preset's ping rate, derived from the range where it gives none.

    Parameters
    ----------
    preset : InstrumentPreset
        A ``sidescan`` or ``singlebeam`` preset.
    range_m : float, optional
        Slant range, metres; defaults to the preset's ``range_max_m``.
    sound_speed_m_s : float, optional
        Sound speed, m/s (default 1500).

    Returns
    -------
    float
        The preset's ``ping_rate_hz`` if it gives one, else ``c / (2 range)``: the next ping is
        sent as soon as the echo of the farthest range is in, as side-scans do.

    Raises
    ------
    ConfigError
        With key ``preset`` for a preset of another type, or ``range_m`` / ``sound_speed_m_s``
        for a value that is not positive and finite.
    """
    if preset.type not in ("sidescan", "singlebeam"):
        raise ConfigError("preset", f"{preset.name!r} is a {preset.type} preset; ping_rate_hz is "
                          "defined for sidescan and singlebeam presets")
    rate = preset.get("ping_rate_hz")
    if rate is not None:
        return float(rate)
    r = _positive("range_m", preset["range_max_m"] if range_m is None else range_m)
    c = _positive("sound_speed_m_s", sound_speed_m_s)
    return c / (2.0 * r)


def scan_step_period_s(
    preset: InstrumentPreset,
    range_m: Optional[float] = None,
    steps: int = 1,
    sound_speed_m_s: float = 1500.0,
) -> float:
    """Time from one ping of a scanning sonar to the next.

    Parameters
    ----------
    preset : InstrumentPreset
        A ``scanning`` preset.
    range_m : float, optional
        The range listened to, metres; defaults to the preset's ``range_max_m``.
    steps : int, optional
        Head steps moved between pings (1 = the finest step; Ping360: gradians).
    sound_speed_m_s : float, optional
        Sound speed, m/s (default 1500).

    Returns
    -------
    float
        Seconds: the listening time ``2 range / c`` plus ``step_overhead_s`` plus
        ``motor_time_per_step_s * (steps - 1)``. A full turn takes
        ``steps_per_turn / steps`` such periods.

    Raises
    ------
    ConfigError
        With key ``preset`` for a preset of another type; ``range_m``, ``steps`` or
        ``sound_speed_m_s`` for a value out of range.
    """
    if preset.type != "scanning":
        raise ConfigError("preset", f"{preset.name!r} is a {preset.type} preset, not a scanning one")
    r = _positive("range_m", preset["range_max_m"] if range_m is None else range_m)
    c = _positive("sound_speed_m_s", sound_speed_m_s)
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= preset["steps_per_turn"]:
        raise ConfigError("steps", f"{shown(steps)}; give an integer from 1 to {preset['steps_per_turn']}")
    motor = float(preset.get("motor_time_per_step_s", 0.0))
    return 2.0 * r / c + float(preset["step_overhead_s"]) + motor * (steps - 1)


@dataclass(frozen=True)
class Ping360Settings:
    """The Ping360 acquisition settings for a range, as Ping Viewer chooses them.

    Parameters
    ----------
    n_samples : int
        Samples per ping (200-1200).
    sample_period_ticks : int
        Sample period in the device's 25 ns ticks (80-40000).
    sample_period_s : float
        The same in seconds.
    transmit_duration_us : int
        Transmit pulse length, microseconds.
    range_m : float
        The range the settings cover, ``n_samples * sample_period_s * c / 2`` (slightly under
        the requested range: the tick count is rounded down).
    """

    n_samples: int
    sample_period_ticks: int
    sample_period_s: float
    transmit_duration_us: int
    range_m: float


def ping360_settings(
    range_m: float, sound_speed_m_s: float = 1500.0, n_samples: int = 1200
) -> Ping360Settings:
    """Sample period and transmit duration of a Ping360 for a range, by the documented rules.

    The rules (Blue Robotics' Ping360 protocol and Ping Viewer's automatic settings): the
    sample period is ``2 range / (n_samples c)`` in whole 25 ns ticks, rounded down; when that is
    under the 80-tick minimum, fewer samples are taken (the most that keep the period at or
    above 80 ticks). The transmit duration starts at ``8000 range / c`` microseconds, is at least
    2.5 sample periods, and is kept within the firmware's limits: at least 5 us, at most 500 us
    and at most 64 sample periods.

    Parameters
    ----------
    range_m : float
        Range, metres (0.3 to 50: the fewest samples at the shortest period, and the
        documented maximum range).
    sound_speed_m_s : float, optional
        Sound speed, m/s (default 1500).
    n_samples : int, optional
        Samples wanted (200-1200; default 1200, Ping Viewer's choice).

    Returns
    -------
    Ping360Settings

    Raises
    ------
    ConfigError
        With key ``range_m``, ``sound_speed_m_s`` or ``n_samples`` for a value out of range.
    """
    preset = INSTRUMENT_PRESETS["ping360"]
    r = _positive("range_m", range_m)
    c = _positive("sound_speed_m_s", sound_speed_m_s)
    n_min, n_max = preset["n_samples_min"], preset["n_samples_max"]
    if isinstance(n_samples, bool) or not isinstance(n_samples, int) or not n_min <= n_samples <= n_max:
        raise ConfigError("n_samples", f"{shown(n_samples)}; give an integer from {n_min} to {n_max}")
    tick_s = preset["sample_period_tick_ns"] * 1e-9
    ticks_min, ticks_max = preset["sample_period_ticks_min"], preset["sample_period_ticks_max"]
    two_way_s = 2.0 * r / c
    # The largest sample count whose period is still at least the minimum tick count.
    # (The 1e-9 keeps an exact quotient such as 0.3 m -> 200 samples from rounding down.)
    n = min(n_samples, int(two_way_s / (ticks_min * tick_s) * (1 + 1e-9)))
    if n < n_min or r > preset["range_max_m"]:
        raise ConfigError(
            "range_m",
            f"{shown(range_m)}; the Ping360 covers {n_min * ticks_min * tick_s * c / 2:.2f} to "
            f"{preset['range_max_m']:g} m at {c:g} m/s",
        )
    ticks = min(int(two_way_s / (n * tick_s) * (1 + 1e-9)), ticks_max)
    period_s = ticks * tick_s
    covered_m = n * period_s * c / 2.0
    period_us = period_s * 1e6
    tx = max(int(round(8000.0 * covered_m / c)), int(2.5 * period_us))
    tx_max = min(int(preset["transmit_duration_us_max"]), int(64.0 * period_us))
    tx = max(int(preset["transmit_duration_us_min"]), min(tx_max, tx))
    return Ping360Settings(
        n_samples=n,
        sample_period_ticks=ticks,
        sample_period_s=period_s,
        transmit_duration_us=tx,
        range_m=covered_m,
    )
