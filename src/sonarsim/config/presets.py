"""Built-in sonar presets: the geometry of common forward-looking sonars.

A preset is a named, read-only set of ``sonar`` keys (the keys of the ``sonar`` section of a
scene file) taken from the manufacturers' published figures. A scene selects one with
``sonar: {preset: aris3000-128}`` and may override any key next to it.

Conventions (see the design notes): angles are in degrees; beam angles are listed left-most
(port) beam first and a positive azimuth is to the sonar's left, so ``beam_angles_deg`` is
strictly descending; ``azimuth_fov_deg`` spans the fan edge to edge, with beam ``j`` centred at
``F/2 - (j + 0.5) F/N``; the elevation aperture spans ``[-E/2, +E/2]``.

Where each figure comes from, and which figures are our own choices, is written in each
preset's ``source`` and in ``docs/presets.md``.

ARIS beams are not uniformly spaced (the acoustic lens distorts them). Sound Metrics publishes
measured beam-centre tables; this module carries closed-form fits of those tables, not the
tables themselves, so that the package ships no third-party data. Users with their own measured
table can read it with :func:`beam_angles_from_table`.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping, Union

import numpy as np

from sonarsim.errors import ConfigError, shown

__all__ = [
    "SONAR_KEYS",
    "Preset",
    "PRESETS",
    "get_preset",
    "BeamAngleFit",
    "ARIS_BEAM_ANGLE_FITS",
    "ARIS_ELEVATION_FOV_DEG",
    "ARIS_MODELS",
    "ARIS_MODES",
    "ArisMode",
    "aris_preset_name",
    "aris_beam_angles_deg",
    "beam_angles_from_table",
    "fit_beam_angles",
    "normalised_beam_index",
    "sine_spaced_beam_angles_deg",
]

#: The keys a preset's ``sonar`` mapping may contain.
SONAR_KEYS: frozenset[str] = frozenset(
    {
        "n_beams",
        "azimuth_fov_deg",
        "beam_angles_deg",
        "beam_width_deg",
        "elevation_fov_deg",
        "range_min_m",
        "range_max_m",
        "n_range_bins",
        "range_resolution_m",
        "frequency_khz",
        "beam_shape",
    }
)

# Pairs of keys that describe the same thing two ways; a preset gives exactly one of each.
_ONE_OF: tuple[tuple[str, str], ...] = (
    ("azimuth_fov_deg", "beam_angles_deg"),
    ("n_range_bins", "range_resolution_m"),
)

# Keys every preset gives (besides one key of each pair above).
_REQUIRED: tuple[str, ...] = (
    "n_beams",
    "beam_width_deg",
    "elevation_fov_deg",
    "range_min_m",
    "range_max_m",
    "frequency_khz",
)


def _freeze_sonar(sonar: Mapping[str, object]) -> Mapping[str, object]:
    """Check a preset's sonar keys and return them as a read-only mapping.

    Parameters
    ----------
    sonar : mapping
        Sonar keys (see :data:`SONAR_KEYS`); sequences become tuples.

    Returns
    -------
    mapping
        A :class:`types.MappingProxyType` over a private copy.

    Raises
    ------
    ConfigError
        On an unknown key, or when both or neither keys of a pair such as
        ``azimuth_fov_deg`` / ``beam_angles_deg`` are given.
    """
    frozen: dict[str, object] = {}
    for key, value in sonar.items():
        if key not in SONAR_KEYS:
            raise ConfigError(
                f"sonar.{key}", f"unknown key; allowed: {', '.join(sorted(SONAR_KEYS))}"
            )
        # Lists (and arrays) would let a caller mutate a shared preset; tuples cannot change.
        if isinstance(value, (list, tuple, np.ndarray)):
            value = tuple(float(v) for v in value)
        frozen[key] = value
    for first, second in _ONE_OF:
        if (first in frozen) == (second in frozen):
            raise ConfigError(f"sonar.{first}", f"give exactly one of {first} and {second}")
    for key in _REQUIRED:
        if key not in frozen:
            raise ConfigError(f"sonar.{key}", "missing")
    return MappingProxyType(frozen)


@dataclass(frozen=True)
class Preset:
    """A named sonar configuration taken from a manufacturer's figures.

    Parameters
    ----------
    name : str
        Key in :data:`PRESETS`, e.g. ``"aris3000-128"``.
    description : str
        Device and operating mode in words.
    source : str
        Where each figure comes from; figures that are our own choices are marked as such.
    sonar : mapping of str to object
        Sonar keys (a subset of :data:`SONAR_KEYS`), stored read-only with tuples for
        sequences. ``beam_angles_deg`` is in degrees, left-most beam first (descending).
    """

    name: str
    description: str
    source: str
    sonar: Mapping[str, object]

    def __post_init__(self) -> None:
        # The dataclass is frozen; object.__setattr__ is the documented way to normalise a
        # field during construction.
        object.__setattr__(self, "sonar", _freeze_sonar(self.sonar))


# --------------------------------------------------------------------------------------------
# Beam-angle laws
# --------------------------------------------------------------------------------------------


def normalised_beam_index(n_beams: int) -> np.ndarray:
    """Normalised beam coordinate used by the beam-angle fits.

    Parameters
    ----------
    n_beams : int
        Number of beams N.

    Returns
    -------
    (N,) float ndarray
        ``u_j = 1 - (2 j + 1) / N`` for beam ``j`` counted from the left-most beam, so ``u``
        runs from just below +1 (left) to just above -1 (right). A uniform fan of width F is
        ``theta = (F / 2) u``, which makes the fitted coefficients easy to read.
    """
    if n_beams < 1:
        raise ValueError(f"n_beams must be at least 1, got {n_beams}")
    return 1.0 - (2.0 * np.arange(n_beams) + 1.0) / n_beams


def fit_beam_angles(angles_deg: np.ndarray, degree: int, *, odd: bool = True) -> np.ndarray:
    """Least-squares polynomial fit of beam centre against normalised beam index.

    This is how the coefficients in :data:`ARIS_BEAM_ANGLE_FITS` were obtained; it is kept so
    that the fit can be repeated on a newer or another measured table.

    Parameters
    ----------
    angles_deg : (N,) float array, degrees
        Beam centres, left-most first (descending).
    degree : int
        Highest power of ``u`` (see :func:`normalised_beam_index`).
    odd : bool, optional
        If True (default) fit a constant plus odd powers only, the natural form for a lens
        that is symmetric up to a small offset; even-power coefficients are returned as 0.

    Returns
    -------
    (degree + 1,) float ndarray
        Coefficients ``a_k`` of ``theta(u) = sum_k a_k u**k``, lowest power first.
    """
    angles = np.asarray(angles_deg, dtype=float)
    u = normalised_beam_index(angles.size)
    powers = [0, *range(1, degree + 1, 2)] if odd else list(range(degree + 1))
    design = np.stack([u**k for k in powers], axis=1)
    solved, *_ = np.linalg.lstsq(design, angles, rcond=None)
    coefficients = np.zeros(degree + 1)
    coefficients[powers] = solved
    return coefficients


@dataclass(frozen=True)
class BeamAngleFit:
    """Closed-form fit of a measured ARIS beam-centre table.

    ``theta(u) = sum_k coefficients[k] * u**k`` degrees, with ``u`` from
    :func:`normalised_beam_index` (beam 0 = left-most).

    Parameters
    ----------
    model : str
        Lens / sonar model in words, e.g. ``"ARIS 3000"``.
    n_beams : int
        Beam count of the table.
    table : str
        File name of the measured table in Sound Metrics' aris-file-sdk
        (``beam-width-metrics/``), as a CSV ``beam,center_deg,left_deg,right_deg``.
    coefficients : tuple of float
        Polynomial coefficients, lowest power first, degrees.
    max_error_deg, rms_error_deg : float
        Largest and RMS difference between the fit and the table's centres, degrees.
    """

    model: str
    n_beams: int
    table: str
    coefficients: tuple[float, ...]
    max_error_deg: float
    rms_error_deg: float

    def angles_deg(self) -> np.ndarray:
        """Fitted beam centres, left-most first (descending), degrees, shape ``(n_beams,)``."""
        u = normalised_beam_index(self.n_beams)
        return np.polynomial.polynomial.polyval(u, np.asarray(self.coefficients))


# Fits of Sound Metrics' measured beam-centre tables (aris-file-sdk, beam-width-metrics, MIT;
# the CSV copies in ../shared/data/aris_beam_widths/). Form and order were chosen per table as
# the fewest coefficients whose largest error is at most 1/20 of the table's narrowest beam
# spacing (half of "a tenth of a beam spacing"); among forms with as many coefficients, the
# smaller largest error wins. Forms tried: constant + odd powers, and full polynomials. The
# coefficients are rounded to 1e-6 degrees; the errors below were computed after that rounding
# and are rounded up to 1e-4 degrees:
#
#   table                   form           max err   RMS err   (degrees; max / narrowest spacing)
#   ARIS3000_128            c + u, u^3, u^5  0.0054  0.0022    (2.3 %)
#   ARIS3000_64             c + u, u^3       0.0083  0.0031    (1.8 %)
#   ARIS1800_1200_48        c + u, u^3, u^5  0.0093  0.0042    (2.2 %)
#   ARIS1800_96             full quintic     0.0082  0.0035    (3.8 %; this table is asymmetric)
#   ARIS_Telephoto_48       c + u, u^3       0.0041  0.0023    (1.4 %)
#   ARIS_Telephoto_96       c + u, u^3       0.0043  0.0024    (2.8 %)
#
# The table values themselves are given to 1e-4 degrees (1e-3 for the telephoto tables), so the
# fits are within a few times the tables' own rounding.
_FIT_ARIS3000_128 = BeamAngleFit(
    model="ARIS 3000",
    n_beams=128,
    table="ARIS3000_128.csv",
    coefficients=(0.001227, 15.25101, 0.0, -0.066317, 0.0, -0.05588),
    max_error_deg=0.0054,
    rms_error_deg=0.0022,
)
_FIT_ARIS3000_64 = BeamAngleFit(
    model="ARIS 3000",
    n_beams=64,
    table="ARIS3000_64.csv",
    coefficients=(0.0, 15.262139, 0.0, -0.134459),
    max_error_deg=0.0083,
    rms_error_deg=0.0031,
)
_FIT_ARIS1800_48 = BeamAngleFit(
    model="ARIS 1800 / 1200",
    n_beams=48,
    table="ARIS1800_1200_48.csv",
    coefficients=(0.0, 16.432464, 0.0, -3.547921, 0.0, 0.910493),
    max_error_deg=0.0093,
    rms_error_deg=0.0042,
)
_FIT_ARIS1800_96 = BeamAngleFit(
    model="ARIS 1800",
    n_beams=96,
    table="ARIS1800_96.csv",
    coefficients=(-0.001104, 16.494042, 0.103588, -3.366347, -0.0391, 0.797615),
    max_error_deg=0.0082,
    rms_error_deg=0.0035,
)
_FIT_TELEPHOTO_48 = BeamAngleFit(
    model="ARIS telephoto lens",
    n_beams=48,
    table="ARIS_Telephoto_48.csv",
    coefficients=(0.0, 7.681583, 0.0, -0.190791),
    max_error_deg=0.0041,
    rms_error_deg=0.0023,
)
_FIT_TELEPHOTO_96 = BeamAngleFit(
    model="ARIS telephoto lens",
    n_beams=96,
    table="ARIS_Telephoto_96.csv",
    coefficients=(0.0, 7.683342, 0.0, -0.185951),
    max_error_deg=0.0043,
    rms_error_deg=0.0024,
)

#: Beam-angle fits keyed by (normalised model name, beam count). The ARIS 1200 uses the
#: 48-beam ARIS 1800 lens table (Sound Metrics publishes one table for both).
ARIS_BEAM_ANGLE_FITS: Mapping[tuple[str, int], BeamAngleFit] = MappingProxyType(
    {
        ("ARIS3000", 128): _FIT_ARIS3000_128,
        ("ARIS3000", 64): _FIT_ARIS3000_64,
        ("ARIS1800", 96): _FIT_ARIS1800_96,
        ("ARIS1800", 48): _FIT_ARIS1800_48,
        ("ARIS1200", 48): _FIT_ARIS1800_48,
        ("ARISTELEPHOTO", 96): _FIT_TELEPHOTO_96,
        ("ARISTELEPHOTO", 48): _FIT_TELEPHOTO_48,
    }
)


def _normalise_model(model: str) -> str:
    # "ARIS 3000", "aris-3000", "Aris3000" and "telephoto" should all find their table.
    key = re.sub(r"[^0-9A-Z]", "", model.upper())
    return "ARISTELEPHOTO" if key == "TELEPHOTO" else key


def aris_beam_angles_deg(model: str, n_beams: int) -> np.ndarray:
    """Beam centres of an ARIS lens from the closed-form fit of Sound Metrics' measured table.

    Parameters
    ----------
    model : str
        ``"ARIS3000"``, ``"ARIS1800"``, ``"ARIS1200"`` or ``"ARIS-telephoto"`` (case, spaces,
        hyphens and underscores are ignored).
    n_beams : int
        64 or 128 for the ARIS 3000; 48 or 96 for the ARIS 1800 and the telephoto lens; 48 for
        the ARIS 1200.

    Returns
    -------
    (n_beams,) float ndarray, degrees
        Beam centres, left-most (port) beam first, strictly descending. Accurate to the fit's
        ``max_error_deg`` (see :data:`ARIS_BEAM_ANGLE_FITS`).

    Raises
    ------
    ConfigError
        For a model and beam count with no measured table.
    """
    fit = ARIS_BEAM_ANGLE_FITS.get((_normalise_model(model), int(n_beams)))
    if fit is None:
        known = ", ".join(f"{m} x {n}" for m, n in ARIS_BEAM_ANGLE_FITS)
        raise ConfigError(
            "sonar.beam_angles_deg",
            f"no measured ARIS beam table for model {model!r} with {n_beams} beams; "
            f"known: {known}",
        )
    return fit.angles_deg()


def sine_spaced_beam_angles_deg(aperture_deg: float, n_beams: int) -> np.ndarray:
    """Beam centres equally spaced in sin(azimuth), the outermost centres at +-aperture/2.

    An electronically beamformed line array (Oculus) spaces its beams evenly in the sine of
    the azimuth, not in the azimuth itself. The bearings an Oculus M1200d reports in its ping
    messages (2.1 MHz, 256 beams, +-30 degrees; ``../shared/data/real/oculus``) follow this law
    to within their 0.01 degree quantisation, whereas even spacing in angle misses by 0.55 deg.

    Parameters
    ----------
    aperture_deg : float
        Angle between the two outermost beam centres, degrees.
    n_beams : int
        Number of beams (at least 2).

    Returns
    -------
    (n_beams,) float ndarray, degrees
        Beam centres, left-most first (descending).
    """
    half = math.sin(math.radians(aperture_deg / 2.0))
    return np.degrees(np.arcsin(np.linspace(half, -half, n_beams)))


# --------------------------------------------------------------------------------------------
# Reading a user's own beam table
# --------------------------------------------------------------------------------------------

_CELL_SPLIT = re.compile(r"[,;\s]+")
MAX_TABLE_BYTES = 2**20  # a beam table has hundreds of rows


def beam_angles_from_table(
    path: Union[str, os.PathLike[str]], *, key: str = "sonar.beam_angles_deg"
) -> np.ndarray:
    """Read measured beam centres from a file and return them left-most first.

    Two layouts are accepted; blank lines and lines starting with ``#`` are ignored and cells
    may be separated by commas, semicolons or white space:

    - a table with a header row naming a ``center_deg`` column, such as Sound Metrics' ARIS
      beam-width tables (``beam,center_deg,left_deg,right_deg``, beam 0 = right-most);
    - a single column of angles, with or without a one-word header.

    The angles may be listed in either order: since a positive azimuth is to the left, the
    left-most beam is the largest angle, and the result is sorted that way.

    Parameters
    ----------
    path : str or path-like
        The file.
    key : str, optional
        Configuration key named in errors (the key that pointed at the file).

    Returns
    -------
    (N,) float ndarray, degrees
        Beam centres, strictly descending.

    Raises
    ------
    ConfigError
        If the file is missing or unreadable, has no angles, has a malformed or non-numeric
        row, angles outside (-90, 90) degrees, or angles that are not strictly monotonic
        (two beams at the same angle, or a table out of order). The error names the file.
    """
    source = os.fspath(path)
    p = Path(source)
    try:
        if p.exists() and not p.is_file():
            raise ConfigError(key, "beam-angle table is a directory or device, not a file", source=source)
        if p.is_file() and p.stat().st_size > MAX_TABLE_BYTES:
            raise ConfigError(key, f"beam-angle table of {p.stat().st_size} bytes; a table of beams is at most "
                              f"{MAX_TABLE_BYTES // 2**20} MiB", source=source)
    except OSError as exc:  # a name too long, a folder that cannot be searched
        raise ConfigError(key, f"cannot read beam-angle table: {exc.strerror or exc}", source=shown(source)) from None
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(key, "beam-angle table not found", source=source) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(key, f"cannot read beam-angle table: {exc}", source=source) from None

    rows = [
        (number, [cell for cell in _CELL_SPLIT.split(line.strip()) if cell])
        for number, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not rows:
        raise ConfigError(key, "beam-angle table is empty", source=source)

    column = 0
    n_columns = len(rows[0][1])
    if not all(_is_number(cell) for cell in rows[0][1]):
        names = [cell.lower() for cell in rows[0][1]]
        if "center_deg" in names:
            column = names.index("center_deg")
        elif n_columns != 1:
            raise ConfigError(
                key,
                f"line {rows[0][0]}: header has no 'center_deg' column "
                f"(columns: {', '.join(rows[0][1])})",
                source=source,
            )
        rows = rows[1:]
    elif n_columns != 1:
        raise ConfigError(
            key,
            "a table with several columns needs a header row naming 'center_deg'",
            source=source,
        )
    if not rows:
        raise ConfigError(key, "beam-angle table has a header but no angles", source=source)

    angles = np.empty(len(rows))
    for i, (number, cells) in enumerate(rows):
        if len(cells) != n_columns:
            raise ConfigError(
                key, f"line {number}: expected {n_columns} values, found {len(cells)}",
                source=source,
            )
        try:
            angles[i] = float(cells[column])
        except ValueError:
            raise ConfigError(
                key, f"line {number}: {shown(cells[column])} is not a number", source=source
            ) from None

    if not np.all(np.isfinite(angles)) or np.any(np.abs(angles) >= 90.0):
        raise ConfigError(
            key, "beam angles must be finite and inside (-90, 90) degrees", source=source
        )
    steps = np.diff(angles)
    if angles.size > 1 and not (np.all(steps > 0) or np.all(steps < 0)):
        raise ConfigError(
            key,
            "beam angles must be strictly increasing or strictly decreasing",
            source=source,
        )
    # Files from ARIS tools list the right-most beam first (ascending); flip to left-most first.
    return angles[::-1].copy() if angles.size > 1 and steps[0] > 0 else angles


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------------------------
# The presets
# --------------------------------------------------------------------------------------------


def _angles(values: np.ndarray) -> tuple[float, ...]:
    # Six decimals (3.6 milli-arcseconds) keep the tuples readable and cost nothing in accuracy.
    return tuple(round(float(v), 6) for v in values)


#: Elevation (vertical) aperture of each ARIS lens, degrees.
#:
#: - ``standard`` 14 deg: Sound Metrics' quoted field of view of the ARIS Explorer models
#:   ("30 x 14 deg"); secondary here: Ocean Networks Canada's ARIS 3000 instrument page (stored
#:   public page, wiki.oceannetworks.ca "ARIS Sonar Data": "covers 28 degrees horizontally and 14
#:   degrees vertically") -- its 28 deg horizontal is contradicted by Sound Metrics' own measured
#:   tables (30.25 deg), the 14 deg has no contradiction. Not confirmed from a Sound Metrics
#:   document here.
#: - ``telephoto`` 3 deg: NOT CONFIRMED. The telephoto lens halves the horizontal fan (Sound
#:   Metrics' measured tables ARIS_Telephoto_48 / _96 span 15.0 deg edge to edge against 27.7 deg
#:   for the standard ARIS 1800 / 1200 lens), and it is quoted as narrowing the vertical beam to
#:   about 3 deg; no Sound Metrics document or stored page giving the vertical figure could be
#:   found (searches of the docs and pages corpora, 2026-11-26, returned only the 14 deg of the
#:   standard lens). Override ``elevation_fov_deg`` when the lens's own figure is known.
ARIS_ELEVATION_FOV_DEG: Mapping[str, float] = MappingProxyType({"standard": 14.0, "telephoto": 3.0})


@dataclass(frozen=True)
class ArisMode:
    """One ARIS model x beam count x lens that Sound Metrics publishes a beam table for.

    Parameters
    ----------
    model : str
        Fit key of the model: ``"ARIS1200"``, ``"ARIS1800"`` or ``"ARIS3000"``.
    n_beams : int
        Beam count (ping modes 1-2: 48, 3-5: 96, 6-8: 64, 9-12: 128).
    lens : {'standard', 'telephoto'}
        The acoustic lens.
    frequency_khz : float
        The carrier of the preset's range window (the model's high or low frequency).
    range_min_m, range_max_m : float
        The preset's range window, metres (our choice, inside the model's limits; see the
        preset's ``source``).
    n_range_bins : int
        Range bins of the preset.
    """

    model: str
    n_beams: int
    lens: str
    frequency_khz: float
    range_min_m: float
    range_max_m: float
    n_range_bins: int

    @property
    def name(self) -> str:
        """The preset's name, e.g. ``aris1800-96`` or ``aris1800-96-telephoto``."""
        base = f"aris{self.model[4:]}-{self.n_beams}"
        return base + ("-telephoto" if self.lens == "telephoto" else "")

    @property
    def fit(self) -> "BeamAngleFit":
        """The beam-angle fit of this lens and beam count."""
        key = ("ARISTELEPHOTO" if self.lens == "telephoto" else self.model, self.n_beams)
        return ARIS_BEAM_ANGLE_FITS[key]


# Each ARIS model's limits (Sound Metrics' ARIS Integration SDK, SystemConfiguration, stored copy
# of SoundMetrics/aris-integration-sdk): window start and end (m), the range beyond which ARIS
# tools switch to the low frequency (m), ping modes; the frequencies (kHz, high / low).
# Frequencies: ARIS 3000 3.0 / 1.8 MHz confirmed (SDK FrequencyHigh / FrequencyLow); ARIS 1800
# 1.8 / 1.1 MHz and ARIS 1200 1.2 / 0.7 MHz as commonly quoted (not confirmed here).
ARIS_MODELS: Mapping[str, Mapping[str, object]] = MappingProxyType({
    "ARIS3000": MappingProxyType({"name": "ARIS Explorer 3000", "window_start_m": (0.7, 12.0),
                                  "window_end_m": (1.3, 20.0), "crossover_m": 5.0, "khz": (3000.0, 1800.0),
                                  "ping_modes": (6, 9)}),
    "ARIS1800": MappingProxyType({"name": "ARIS Explorer 1800", "window_start_m": (0.7, 25.0),
                                  "window_end_m": (1.3, 50.0), "crossover_m": 15.0, "khz": (1800.0, 1100.0),
                                  "ping_modes": (1, 3)}),
    "ARIS1200": MappingProxyType({"name": "ARIS Explorer 1200", "window_start_m": (0.7, 40.0),
                                  "window_end_m": (1.3, 100.0), "crossover_m": 25.0, "khz": (1200.0, 700.0),
                                  "ping_modes": (1,)}),
})

# The modes with a preset: every model x beam count x lens of Sound Metrics' lookup table
# (aris-file-sdk SoundMetrics.Aris.BeamWidths Metrics.cs: ARIS 1200 x 48 and ARIS 1800 x 48 / 96
# with either lens, ARIS 3000 x 64 / 128 with the standard lens only). Windows (our choice):
# the high-frequency beam count from the SDK's smallest window start to the frequency crossover,
# the low-frequency one from the crossover to the largest window end (as for the ARIS 3000,
# whose 128 beams are its 3 MHz mode and 64 its 1.8 MHz); the ARIS 1200 has one beam count, at
# its high frequency. Bins: about 1 cm for the 1800 and 1200 windows (the SDK's sample periods of
# 4-40 us give 3-30 mm at 1500 m/s).
ARIS_MODES: tuple[ArisMode, ...] = (
    ArisMode("ARIS3000", 128, "standard", 3000.0, 0.7, 5.0, 1288),
    ArisMode("ARIS3000", 64, "standard", 1800.0, 5.0, 20.0, 1500),
    ArisMode("ARIS1800", 96, "standard", 1800.0, 0.7, 15.0, 1430),
    ArisMode("ARIS1800", 48, "standard", 1100.0, 15.0, 50.0, 1750),
    ArisMode("ARIS1200", 48, "standard", 1200.0, 0.7, 25.0, 2000),
    ArisMode("ARIS1800", 96, "telephoto", 1800.0, 0.7, 15.0, 1430),
    ArisMode("ARIS1800", 48, "telephoto", 1100.0, 15.0, 50.0, 1750),
    ArisMode("ARIS1200", 48, "telephoto", 1200.0, 0.7, 25.0, 2000),
)


def aris_preset_name(model: str, n_beams: int, telephoto: bool) -> str | None:
    """The preset of an ARIS model, beam count and lens, or None where there is none.

    Parameters
    ----------
    model : str
        ``"ARIS 3000"``, ``"aris1800"``, ... (case, spaces, hyphens and underscores ignored).
    n_beams : int
    telephoto : bool
        The telephoto lens (an ARIS file's ``LargeLens`` 1).

    Returns
    -------
    str or None
    """
    key, lens = _normalise_model(model), "telephoto" if telephoto else "standard"
    for mode in ARIS_MODES:
        if (mode.model, mode.n_beams, mode.lens) == (key, int(n_beams), lens):
            return mode.name
    return None


# Beam widths: the mean left-to-right width of each measured table's beams (they tile the fan;
# not a -3 dB figure), except ARIS_Telephoto_48, whose left/right columns do not bracket its
# centres (widths about half the spacing): its mean centre spacing instead.
_ARIS_BEAM_WIDTH_DEG = {
    "ARIS3000_128.csv": 0.236, "ARIS3000_64.csv": 0.472, "ARIS1800_96.csv": 0.290,
    "ARIS1800_1200_48.csv": 0.575, "ARIS_Telephoto_96.csv": 0.156, "ARIS_Telephoto_48.csv": 0.312,
}


def _aris_preset(mode: ArisMode) -> Preset:
    facts = ARIS_MODELS[mode.model]
    fit = mode.fit
    high = mode.frequency_khz == facts["khz"][0]
    lens = "telephoto lens" if mode.lens == "telephoto" else "standard lens"
    confirmed = "confirmed (SDK FrequencyHigh / FrequencyLow)" if mode.model == "ARIS3000" else \
        "as commonly quoted, not confirmed from a Sound Metrics document here"
    source = (
        f"Model limits: Sound Metrics ARIS Integration SDK SystemConfiguration ({facts['name']}: ping modes "
        f"{', '.join(map(str, facts['ping_modes']))}; window start {facts['window_start_m'][0]:g}-"
        f"{facts['window_start_m'][1]:g} m, window end {facts['window_end_m'][0]:g}-{facts['window_end_m'][1]:g} m, "
        f"frequency crossover {facts['crossover_m']:g} m). Frequencies {facts['khz'][0]:g} / {facts['khz'][1]:g} kHz: "
        f"{confirmed}. Beam centres: closed-form fit of Sound Metrics' measured table {fit.table[:-4]} "
        f"(aris-file-sdk beam-width-metrics; fit max error {fit.max_error_deg} deg, RMS {fit.rms_error_deg} deg); "
        f"Sound Metrics' lookup (aris-file-sdk Metrics.cs) gives this table to the {facts['name']} with "
        f"{mode.n_beams} beams and the {lens}. beam_width_deg: mean beam width of that table (its centre spacing "
        f"for ARIS_Telephoto_48, whose edge columns are inconsistent). elevation_fov_deg "
        f"{ARIS_ELEVATION_FOV_DEG[mode.lens]:g}: "
        + ("Sound Metrics' quoted 30 x 14 deg field of view (secondary: Ocean Networks Canada's instrument "
           "page; not confirmed from a Sound Metrics document here)." if mode.lens == "standard" else
           "NOT CONFIRMED: the telephoto lens is quoted as narrowing the vertical beam to about 3 deg, but no "
           "document giving it could be found here; override elevation_fov_deg when it is known.")
        + f" Range window (our choice): {mode.range_min_m:g}-{mode.range_max_m:g} m, "
        + ("from the smallest window start to the frequency crossover" if high and mode.range_min_m < facts["crossover_m"]
           else "from the frequency crossover to the largest window end")
        + f", {mode.n_range_bins} bins."
    )
    return Preset(
        name=mode.name,
        description=(f"Sound Metrics {facts['name']}, {mode.frequency_khz / 1000:g} MHz "
                     f"{'high' if high else 'low'}-frequency mode, {mode.n_beams} beams, {lens}"),
        source=source,
        sonar={
            "n_beams": mode.n_beams,
            "beam_angles_deg": _angles(fit.angles_deg()),
            "beam_width_deg": _ARIS_BEAM_WIDTH_DEG[fit.table],
            "elevation_fov_deg": ARIS_ELEVATION_FOV_DEG[mode.lens],
            "range_min_m": mode.range_min_m,
            "range_max_m": mode.range_max_m,
            "n_range_bins": mode.n_range_bins,
            "frequency_khz": mode.frequency_khz,
        },
    )


def _build_presets() -> Mapping[str, Preset]:
    presets = [
        *(_aris_preset(mode) for mode in ARIS_MODES),
        Preset(
            name="didson300",
            description=(
                "Sound Metrics DIDSON 300 m (standard lens), 1.8 MHz high-frequency "
                "(identification) mode, 96 beams"
            ),
            source=(
                "96 beams, each 0.3 deg wide and 14 deg high, spaced 0.3 deg; 512 samples per "
                "beam: Sound Metrics, 'DIDSON Resolution' (soundmetrics.com/SONAR101). Field of "
                "view 96 x 0.3 = 28.8 deg (Sound Metrics quotes 29 x 14 deg, e.g. on the "
                "BCO-DMO DIDSON instrument page). Beams assumed evenly spaced (no measured "
                "table). 1.8 MHz: the DIDSON high frequency (not confirmed from a Sound Metrics "
                "document here). Range window 1-11 m (our choice; the high-frequency mode is "
                "meant for the first ~12 m)."
            ),
            sonar={
                "n_beams": 96,
                "azimuth_fov_deg": 28.8,
                "beam_width_deg": 0.3,
                "elevation_fov_deg": 14.0,
                "range_min_m": 1.0,
                "range_max_m": 11.0,
                "n_range_bins": 512,
                "frequency_khz": 1800.0,
            },
        ),
        Preset(
            name="oculus-m750d-lf",
            description="Blueprint Subsea Oculus M750d, 750 kHz low-frequency mode, 512 beams",
            source=(
                "512 beams: Blueprint Subsea / VideoRay Oculus training notes. 130 x 20 deg: "
                "Oculus M-series user manual ('up to 130 deg horizontally and 20 deg "
                "vertically'). 750 kHz, 1.0 deg angular resolution, 120 m maximum range, 4 mm "
                "range resolution: Blueprint Subsea M750d data sheet as commonly quoted (not "
                "confirmed from a stored copy here). Beams spaced evenly in sin(azimuth) with "
                "the outermost centres at +-65 deg, as the bearings of a recorded M1200d show "
                "(assumed for this mode). Range window 0.1-40 m, 2000 bins: our choice."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 512,
                "beam_angles_deg": _angles(sine_spaced_beam_angles_deg(130.0, 512)),
                "beam_width_deg": 1.0,
                "elevation_fov_deg": 20.0,
                "range_min_m": 0.1,
                "range_max_m": 40.0,
                "n_range_bins": 2000,
                "frequency_khz": 750.0,
            },
        ),
        Preset(
            name="oculus-m750d-hf",
            description="Blueprint Subsea Oculus M750d, 1.2 MHz high-frequency mode, 512 beams",
            source=(
                "512 beams: Blueprint Subsea / VideoRay Oculus training notes. 1.2 MHz, "
                "70 x 12 deg, 0.6 deg angular resolution, 40 m maximum range: Blueprint Subsea "
                "M750d data sheet as commonly quoted (not confirmed from a stored copy here). "
                "Beams spaced evenly in sin(azimuth), outermost centres at +-35 deg (law "
                "measured on an M1200d; assumed here). Range window 0.1-10 m, 1000 bins: our "
                "choice."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 512,
                "beam_angles_deg": _angles(sine_spaced_beam_angles_deg(70.0, 512)),
                "beam_width_deg": 0.6,
                "elevation_fov_deg": 12.0,
                "range_min_m": 0.1,
                "range_max_m": 10.0,
                "n_range_bins": 1000,
                "frequency_khz": 1200.0,
            },
        ),
        Preset(
            name="oculus-m1200d-lf",
            description="Blueprint Subsea Oculus M1200d, 1.2 MHz low-frequency mode, 512 beams",
            source=(
                "512 beams: Blueprint Subsea / VideoRay Oculus training notes. 130 x 20 deg: "
                "Oculus M-series user manual. 1.2 MHz, 0.6 deg angular resolution, 30 m "
                "maximum range: Blueprint Subsea M1200d data sheet as commonly quoted (not "
                "confirmed from a stored copy here). Beams spaced evenly in sin(azimuth), "
                "outermost centres at +-65 deg (law measured on this sonar's 2.1 MHz mode; "
                "assumed here). Range window 0.1-10 m, 1000 bins: our choice."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 512,
                "beam_angles_deg": _angles(sine_spaced_beam_angles_deg(130.0, 512)),
                "beam_width_deg": 0.6,
                "elevation_fov_deg": 20.0,
                "range_min_m": 0.1,
                "range_max_m": 10.0,
                "n_range_bins": 1000,
                "frequency_khz": 1200.0,
            },
        ),
        Preset(
            name="oculus-m1200d-hf",
            description="Blueprint Subsea Oculus M1200d, 2.1 MHz high-frequency mode, 512 beams",
            source=(
                "2.1 MHz and a 60 deg aperture with beams evenly spaced in sin(azimuth) between "
                "+-30 deg: a recorded M1200d ping (University of Washington liboculus test data: "
                "2.099 MHz, 256 beams, 703 ranges of 2.842 mm). 512 beams (the recording used "
                "256): Blueprint Subsea / VideoRay Oculus training notes. 12 deg vertical, "
                "0.4 deg angular resolution, 10 m maximum range: Blueprint Subsea M1200d data "
                "sheet as commonly quoted (not confirmed from a stored copy here). Range window "
                "0.1-2 m, 669 bins of 2.84 mm (the recording's range resolution): our choice."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 512,
                "beam_angles_deg": _angles(sine_spaced_beam_angles_deg(60.0, 512)),
                "beam_width_deg": 0.4,
                "elevation_fov_deg": 12.0,
                "range_min_m": 0.1,
                "range_max_m": 2.0,
                "n_range_bins": 669,
                "frequency_khz": 2100.0,
            },
        ),
        Preset(
            name="blueview-p900-130",
            description="Teledyne BlueView P900-130, 900 kHz, 130 deg, 768 beams",
            source=(
                "900 kHz and 130 deg: the model designation (P900 series, 130 deg head). 768 "
                "beams, 1 deg x 20 deg beams, 100 m maximum range, 2.54 cm range resolution: "
                "Teledyne BlueView P900 data sheet as commonly quoted (not confirmed from a "
                "stored copy here). Beams assumed evenly spaced. Range window 1-50 m (the "
                "ARACATI 2017 data set was recorded with a P900-130 at 50 m), 1929 bins of "
                "2.54 cm: our choice."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 768,
                "azimuth_fov_deg": 130.0,
                "beam_width_deg": 1.0,
                "elevation_fov_deg": 20.0,
                "range_min_m": 1.0,
                "range_max_m": 50.0,
                "n_range_bins": 1929,
                "frequency_khz": 900.0,
            },
        ),
        Preset(
            name="gemini-720i",
            description="Tritech Gemini 720i, 720 kHz, 120 deg, 256 beams",
            source=(
                "720 kHz, 120 deg scanning sector, 20 deg vertical beam width, 1.0 deg acoustic "
                "angular resolution: Tritech Gemini 720is product manual (0703-SOM-00002), whose "
                "software notes say the Gemini imagers have a fixed 120 deg sector (130 deg is "
                "the Gemini Narrow Beam Imager's). 256 beams: secondary sources describing "
                "Gemini 720i data (DeeperSense data-set notes; Cerqueira et al.'s simulator "
                "defaults) - not confirmed from a Tritech document here. Beams assumed evenly "
                "spaced. Range window 0.2-30 m, 1490 bins of 2 cm: our choice (Tritech quotes "
                "120 m maximum range and 8 mm range resolution; not confirmed here)."
                " Cone-shaped beams: a beamformed line array selects the direction cosine along "
                "the array (sin theta_s = cos phi sin theta; H. L. Van Trees, Optimum Array "
                "Processing, 2002, Ch. 2)."
            ),
            sonar={
                "beam_shape": "cone",
                "n_beams": 256,
                "azimuth_fov_deg": 120.0,
                "beam_width_deg": 1.0,
                "elevation_fov_deg": 20.0,
                "range_min_m": 0.2,
                "range_max_m": 30.0,
                "n_range_bins": 1490,
                "frequency_khz": 720.0,
            },
        ),
    ]
    return MappingProxyType({preset.name: preset for preset in presets})


#: The built-in presets, keyed by name (read-only).
PRESETS: Mapping[str, Preset] = _build_presets()


def get_preset(name: str) -> Preset:
    """Look up a built-in preset.

    Parameters
    ----------
    name : str
        Preset name, e.g. ``"aris3000-128"`` (see :data:`PRESETS`).

    Returns
    -------
    Preset

    Raises
    ------
    ConfigError
        With key ``sonar.preset`` when there is no preset of that name; the message lists the
        known presets.
    """
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise ConfigError(
            "sonar.preset",
            f"unknown preset {shown(name)}; known presets: {', '.join(PRESETS)}",
        ) from None
