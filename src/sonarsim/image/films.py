"""The films of sonars other than the FLS: what a side-scan, a multibeam echosounder and a
single-beam echosounder record, with the geometry of every ping.

The forward-looking sonar's film is the polar frame (:class:`~sonarsim.image.result.SonarImage`);
a mechanical scanning sonar's is :class:`~sonarsim.instruments.scanning.ScanImage` (a range line
per step, with its head angle and time; its top view by ``cartesian()``). The others record per ping:

* :class:`Waterfall` (side-scan): per ping a port and a starboard slant-range line, stacked
  along the track: ``samples[ping, side, k]``, side 0 port and 1 starboard, sample 0 the
  nearest (nadir) on both sides. :meth:`Waterfall.display` lays it out as surveyors see it
  (port on the left, far to near, then starboard near to far: nadir in the middle).
* :class:`Soundings` (multibeam): per ping and beam the two-way travel time, the beam's angle
  across track, the backscatter, and where the beam met the bottom.
* :class:`Envelope` (single-beam echosounder, altimeter): per ping one envelope against range
  and the bottom's range.

Renders (:mod:`sonarsim.instruments`) and recordings (:mod:`sonarsim.io.readers`) give the same
films, so that the two are shown, compared and scored with the same code.

Conventions (``docs/conventions.md``): range sample ``k`` covers ``[range_min_m + k dr,
range_min_m + (k + 1) dr)``; attitudes follow REP-103 (the vehicle's x forward, y to port, z up;
roll > 0 lifts port, pitch > 0 puts the nose DOWN, as a sonar's pitch in a scene file does);
``heading_deg`` is the compass heading (clockwise from north; in the world frame x east, y north
the vehicle's yaw is ``90 - heading``). Values a recording does not log are NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .display import hook
from .units import UNITS, Unit, check_unit

__all__ = ["GEOMETRY_FIELDS", "PingGeometry", "Waterfall", "Soundings", "Envelope", "film_arrays", "range_axis"]

#: The per-ping geometry a film carries: field -> (unit, meaning).
GEOMETRY_FIELDS = {
    "time_s": ("s", "the ping's time (seconds since 1970 where the recording says, else since its first ping)"),
    "altitude_m": ("m", "the sonar's height above the floor, as the vehicle logged it"),
    "depth_m": ("m", "the sonar's depth below the surface"),
    "roll_deg": ("deg", "roll, REP-103: > 0 lifts port"),
    "pitch_deg": ("deg", "pitch, REP-103: > 0 puts the nose down"),
    "heading_deg": ("deg", "compass heading, clockwise from north"),
    "heave_m": ("m", "heave, > 0 up"),
    "sound_speed_m_s": ("m/s", "the sound speed the device ranged with"),
    "range_min_m": ("m", "near end of the range window"),
    "range_max_m": ("m", "far end of the range window"),
    "x_m": ("m", "position east (or longitude-derived easting), metres"),
    "y_m": ("m", "position north, metres"),
    "latitude_deg": ("deg", "latitude"),
    "longitude_deg": ("deg", "longitude"),
    "speed_m_s": ("m/s", "the vehicle's speed over ground"),
}


@dataclass(frozen=True)
class PingGeometry:
    """The geometry of ``n`` pings, one array per field (float64, ``(n,)``, NaN where unknown).

    See :data:`GEOMETRY_FIELDS` for each field's unit and meaning.
    """

    time_s: np.ndarray
    altitude_m: np.ndarray
    depth_m: np.ndarray
    roll_deg: np.ndarray
    pitch_deg: np.ndarray
    heading_deg: np.ndarray
    heave_m: np.ndarray
    sound_speed_m_s: np.ndarray
    range_min_m: np.ndarray
    range_max_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    latitude_deg: np.ndarray
    longitude_deg: np.ndarray
    speed_m_s: np.ndarray

    def __post_init__(self) -> None:
        n = None
        for f in fields(self):
            a = np.atleast_1d(np.asarray(getattr(self, f.name), dtype=np.float64))
            if a.ndim != 1:
                raise ValueError(f"PingGeometry.{f.name} must be one value per ping, got shape {a.shape}")
            if n is None:
                n = len(a)
            elif len(a) != n:
                raise ValueError(f"PingGeometry.{f.name} has {len(a)} values, {fields(self)[0].name} has {n}")
            a.setflags(write=False)
            object.__setattr__(self, f.name, a)

    @classmethod
    def of(cls, n: int, **values) -> "PingGeometry":
        """``n`` pings with the fields given (arrays or scalars) and NaN for the rest."""
        unknown = set(values) - set(GEOMETRY_FIELDS)
        if unknown:
            raise TypeError(f"unknown geometry fields {sorted(unknown)}; allowed: {', '.join(GEOMETRY_FIELDS)}")
        return cls(**{k: np.broadcast_to(np.asarray(values.get(k, np.nan), np.float64), (n,)).copy()
                      for k in GEOMETRY_FIELDS})

    def __len__(self) -> int:
        return len(self.time_s)

    def __getitem__(self, index) -> "PingGeometry":
        """The pings at ``index`` (a slice, an index array or a boolean mask)."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return PingGeometry(**{k: getattr(self, k)[index] for k in GEOMETRY_FIELDS})

    @staticmethod
    def concatenate(parts: "list[PingGeometry]") -> "PingGeometry":
        return PingGeometry(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in GEOMETRY_FIELDS})

    def as_dict(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in GEOMETRY_FIELDS}


def film_arrays(arrays: dict, geometry: "PingGeometry") -> dict:
    """A film's arrays with its geometry's under ``geometry/<field>`` (what its NPZ holds)."""
    out = {k: v for k, v in arrays.items() if v is not None}
    out.update({f"geometry/{k}": v for k, v in geometry.as_dict().items()})
    return out


def range_axis(range_min_m: float, range_max_m: float, n_samples: int) -> np.ndarray:
    """Centres of ``n_samples`` equal range samples over the window, metres, ``(n_samples,)``."""
    dr = (range_max_m - range_min_m) / n_samples
    return range_min_m + (np.arange(n_samples) + 0.5) * dr


@dataclass(frozen=True)
class Waterfall:
    """Side-scan pings stacked along the track.

    Attributes
    ----------
    samples : (n_pings, 2, n_samples) float32 ndarray
        Side 0 port, 1 starboard; sample 0 the nearest range on both sides.
    range_min_m, range_max_m : float
        The slant-range window of every ping, metres.
    geometry : PingGeometry
        One entry per ping.
    labels : dict of str to ndarray, optional
        Ground truth per sample (renders only): ``instance`` (int32, ``(n_pings, 2,
        n_samples)``: the id of :attr:`ids` bringing the most energy, -1 none), ``shadow``
        (bool, same shape: the floor in the beam but hidden behind an object) and ``boxes``
        (int32 ``(n_ids, 2, 4)``: per id and side ``[ping_min, sample_min, ping_max,
        sample_max]``, -1 where the id dominates no sample).
    source : str
        Where it came from (a file, or ``"render"``).
    ids : tuple of str
        Names of the label ids: the scene's objects in order, then its reflecting planes.
    unit_name : str
        What :attr:`samples` are (:mod:`sonarsim.image.units`; :attr:`unit`): a render's
        :func:`~sonarsim.image.units.instrument_unit`, a recording's ``counts``.
    """

    samples: np.ndarray
    range_min_m: float
    range_max_m: float
    geometry: PingGeometry
    labels: dict | None = None
    source: str = "render"
    ids: tuple = ()
    unit_name: str = "counts"

    @property
    def unit(self) -> Unit:
        """What :attr:`samples` are (:mod:`sonarsim.image.units`)."""
        return UNITS[self.unit_name]

    def __post_init__(self) -> None:
        check_unit(self.unit_name, "Waterfall")
        s = np.asarray(self.samples)
        if s.ndim != 3 or s.shape[1] != 2:
            raise ValueError(f"Waterfall.samples must be (n_pings, 2, n_samples), got {s.shape}")
        if len(self.geometry) != s.shape[0]:
            raise ValueError(f"Waterfall has {s.shape[0]} pings but geometry for {len(self.geometry)}")

    @property
    def n_pings(self) -> int:
        return self.samples.shape[0]

    @property
    def n_samples(self) -> int:
        return self.samples.shape[2]

    @property
    def slant_range_m(self) -> np.ndarray:
        """Centre of each sample, metres, ``(n_samples,)``."""
        return range_axis(self.range_min_m, self.range_max_m, self.n_samples)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name: ``samples``, ``geometry/<field>``, ``labels/<name>``."""
        out = film_arrays({"samples": self.samples, "slant_range_m": self.slant_range_m}, self.geometry)
        out.update({f"labels/{k}": v for k, v in (self.labels or {}).items()})
        out["unit"] = np.array(self.unit_name)
        return out

    def config(self) -> dict:
        return {"film": "waterfall", "range_min_m": self.range_min_m, "range_max_m": self.range_max_m,
                "source": self.source, "ids": list(self.ids), "unit": self.unit_name}

    def save_npz(self, path) -> None:
        """Write :meth:`arrays` and :meth:`config` to an NPZ file, atomically."""
        hook("write_npz", "Waterfall.save_npz")(path, self.arrays(), self.config())

    def display(self, samples: np.ndarray | None = None) -> np.ndarray:
        """``(n_pings, 2 n_samples)``: port far -> near, then starboard near -> far."""
        s = self.samples if samples is None else samples
        return np.concatenate([s[:, 0, ::-1], s[:, 1]], axis=1)

    def ground_range(self, altitude_m: np.ndarray | None = None, n_samples: int | None = None,
                     ground_max_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The slant-range corrected waterfall over a flat floor at each ping's altitude.

        Sample ``k`` at slant range ``r`` lies at ground range ``sqrt(r^2 - h^2)``; samples
        before the first bottom return (``r < h``: the water column) have no ground range and
        are dropped. Each output bin takes the linear interpolation of the slant samples.

        Parameters
        ----------
        altitude_m : (n_pings,) array, optional
            The height above the floor per ping; default the geometry's ``altitude_m``.
        n_samples : int, optional
            Ground-range bins per side; default as many as the slant samples.
        ground_max_m : float, optional
            The far ground range; default the slant window's far end.

        Returns
        -------
        samples : (n_pings, 2, n_samples) float32 ndarray
            NaN where a bin lies beyond the slant window (or the altitude is unknown).
        ground_range_m : (n_samples,) ndarray
            Each bin's centre, metres.
        """
        h = self.geometry.altitude_m if altitude_m is None else np.asarray(altitude_m, np.float64)
        n = self.n_samples if n_samples is None else int(n_samples)
        g_max = self.range_max_m if ground_max_m is None else float(ground_max_m)
        ground = range_axis(0.0, g_max, n)
        r = self.slant_range_m
        out = np.full((self.n_pings, 2, n), np.nan, np.float32)
        for p in range(self.n_pings):  # per ping: one np.interp per side (pings are few; samples many)
            if not np.isfinite(h[p]):
                continue
            slant = np.sqrt(ground ** 2 + h[p] ** 2)
            inside = (slant >= r[0]) & (slant <= r[-1])
            for side in range(2):
                out[p, side, inside] = np.interp(slant[inside], r, self.samples[p, side])
        return out, ground


@dataclass(frozen=True)
class Soundings:
    """Multibeam pings: per beam a two-way time, an angle and a backscatter.

    Attributes
    ----------
    angle_deg : (n_pings, n_beams) float64 ndarray
        Each beam's angle across track in the head's frame, degrees: 0 straight down, > 0 to
        port (the azimuth convention of an FLS looking down); beam 0 the port-most.
    two_way_time_s : (n_pings, n_beams) float64 ndarray
        The bottom detection's two-way travel time, seconds; NaN where the beam found none.
    intensity : (n_pings, n_beams) float64 ndarray
        Backscatter at the detection (the recording's units: micropascal for an R2Sonic).
    geometry : PingGeometry
        One entry per ping; its ``sound_speed_m_s`` turns times into ranges.
    water_column : (n_pings, n_samples, n_beams) float32 ndarray, optional
        The beams' envelopes against range (renders; a recording that stores it).
    points_m : (n_pings, n_beams, 3) float64 ndarray, optional
        Where each beam met the bottom, the world frame, metres (renders: the truth).
    source : str
    tilt_deg : (n_pings, n_beams) float64 ndarray, optional
        Each sounding's angle along track in the head's frame, degrees, > 0 forward (the
        transmit's tilt, as Kongsberg files log it; a render's refracted arrivals); None: 0.
    unit_name : str
        What :attr:`intensity` and :attr:`water_column` are (:mod:`sonarsim.image.units`;
        :attr:`unit`): a render's :func:`~sonarsim.image.units.instrument_unit`, an R2Sonic's
        ``uPa``.
    """

    angle_deg: np.ndarray
    two_way_time_s: np.ndarray
    intensity: np.ndarray
    geometry: PingGeometry
    water_column: np.ndarray | None = None
    points_m: np.ndarray | None = None
    source: str = "render"
    tilt_deg: np.ndarray | None = None
    unit_name: str = "counts"

    @property
    def unit(self) -> Unit:
        """What :attr:`intensity` and :attr:`water_column` are (:mod:`sonarsim.image.units`)."""
        return UNITS[self.unit_name]

    def __post_init__(self) -> None:
        check_unit(self.unit_name, "Soundings")
        shape = np.shape(self.two_way_time_s)
        if len(shape) != 2 or np.shape(self.angle_deg) != shape or np.shape(self.intensity) != shape:
            raise ValueError("Soundings.angle_deg, two_way_time_s and intensity must share one (n_pings, n_beams) "
                             f"shape, got {np.shape(self.angle_deg)}, {shape}, {np.shape(self.intensity)}")
        if len(self.geometry) != shape[0]:
            raise ValueError(f"Soundings has {shape[0]} pings but geometry for {len(self.geometry)}")
        if self.tilt_deg is not None and np.shape(self.tilt_deg) != shape:
            raise ValueError(f"Soundings.tilt_deg must be {shape} like two_way_time_s, got {np.shape(self.tilt_deg)}")

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name (``geometry/<field>`` for the pings' geometry)."""
        out = film_arrays({"angle_deg": self.angle_deg, "two_way_time_s": self.two_way_time_s,
                           "intensity": self.intensity, "water_column": self.water_column, "points_m": self.points_m,
                           "tilt_deg": getattr(self, "tilt_deg", None)}, self.geometry)
        out["unit"] = np.array(self.unit_name)
        return out

    def save_npz(self, path) -> None:
        """Write :meth:`arrays` to an NPZ file, atomically."""
        hook("write_npz", "Soundings.save_npz")(path, self.arrays(), {"film": "soundings", "source": self.source,
                                                                       "unit": self.unit_name})

    @property
    def n_pings(self) -> int:
        return self.two_way_time_s.shape[0]

    @property
    def n_beams(self) -> int:
        return self.two_way_time_s.shape[1]

    @property
    def range_m(self) -> np.ndarray:
        """Slant range per beam, ``c t / 2`` with the ping's sound speed, metres."""
        return self.two_way_time_s * self.geometry.sound_speed_m_s[:, None] / 2.0

    def head_points(self, refracted: bool = False) -> np.ndarray:
        """Where each beam met the bottom in the head's frame (x forward, y port, z up) with
        straight rays, metres, ``(n_pings, n_beams, 3)``: ``(0, r sin a, -r cos a)``
        (``r (sin b, cos b sin a, -cos b cos a)`` with a tilt ``b``)."""
        a = np.radians(self.angle_deg)
        r = self.range_m
        if self.tilt_deg is None:
            return np.stack([np.zeros_like(r), r * np.sin(a), -r * np.cos(a)], axis=-1)
        b = np.radians(self.tilt_deg)
        return np.stack([r * np.sin(b), r * np.cos(b) * np.sin(a), -r * np.cos(b) * np.cos(a)], axis=-1)

    def level_points(self) -> np.ndarray:
        """:meth:`head_points` turned by each ping's roll and pitch into the level frame (x forward
        along the heading, y to port, z up; heading not applied), metres, ``(n_pings, n_beams, 3)``.

        ``p_level = Ry(pitch) Rx(roll) p_head`` (REP-103: roll > 0 lifts port, pitch > 0 puts the
        nose down); a beam at ``angle_deg`` a reaches the level angle ``a + roll`` across track.
        NaN where the ping's roll or pitch is unknown.
        """
        p = self.head_points()
        roll = np.radians(self.geometry.roll_deg)[:, None]
        pitch = np.radians(self.geometry.pitch_deg)[:, None]
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        y, z = y * np.cos(roll) - z * np.sin(roll), y * np.sin(roll) + z * np.cos(roll)
        x, z = x * np.cos(pitch) + z * np.sin(pitch), -x * np.sin(pitch) + z * np.cos(pitch)
        return np.stack([x, y, z], axis=-1)


@dataclass(frozen=True)
class Envelope:
    """Single-beam pings: an envelope against range and the bottom's range.

    Attributes
    ----------
    samples : (n_pings, n_samples) float32 ndarray
        Sample 0 the nearest range.
    range_min_m, range_max_m : float
        The range window, metres.
    bottom_range_m : (n_pings,) float64 ndarray
        The bottom's range per ping (the device's own detection for a recording, the
        detector's for a render); NaN where none was found.
    geometry : PingGeometry
    source : str
    unit_name : str
        What :attr:`samples` are (:mod:`sonarsim.image.units`; :attr:`unit`): a render's
        :func:`~sonarsim.image.units.instrument_unit`, a recording's ``counts``.
    """

    samples: np.ndarray
    range_min_m: float
    range_max_m: float
    bottom_range_m: np.ndarray
    geometry: PingGeometry
    source: str = "render"
    unit_name: str = "counts"

    @property
    def unit(self) -> Unit:
        """What :attr:`samples` are (:mod:`sonarsim.image.units`)."""
        return UNITS[self.unit_name]

    def __post_init__(self) -> None:
        check_unit(self.unit_name, "Envelope")
        s = np.asarray(self.samples)
        if s.ndim != 2:
            raise ValueError(f"Envelope.samples must be (n_pings, n_samples), got {s.shape}")
        if np.shape(self.bottom_range_m) != (s.shape[0],) or len(self.geometry) != s.shape[0]:
            raise ValueError("Envelope.bottom_range_m and geometry must have one entry per ping")

    @property
    def n_pings(self) -> int:
        return self.samples.shape[0]

    @property
    def range_m(self) -> np.ndarray:
        return range_axis(self.range_min_m, self.range_max_m, self.samples.shape[1])

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name (``geometry/<field>`` for the pings' geometry)."""
        out = film_arrays({"samples": self.samples, "range_m": self.range_m, "bottom_range_m": self.bottom_range_m},
                          self.geometry)
        out["unit"] = np.array(self.unit_name)
        return out

    def save_npz(self, path) -> None:
        """Write :meth:`arrays` to an NPZ file, atomically."""
        hook("write_npz", "Envelope.save_npz")(path, self.arrays(), {"film": "envelope", "source": self.source,
                                                                      "range_min_m": self.range_min_m,
                                                                      "range_max_m": self.range_max_m,
                                                                      "unit": self.unit_name})
