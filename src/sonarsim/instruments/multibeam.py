"""Multibeam echosounder: a swath of beams across track, each beam's bottom detected.

The head is one channel of the engine: an FLS-like fan looking straight down (the channel's x
is the vehicle's -z: mount pitch +90 deg), its beams across track (the channel's azimuth is the
across-track angle, > 0 to port, beam 0 the port-most: the convention of
:class:`~sonarsim.image.films.Soundings`), its elevation aperture the transmit beam's
along-track width, each beam ``rx_beam_width_across_deg`` wide. One ping is one engine frame
(:meth:`Simulator.trace`, :meth:`Simulator.form`): its polar image is the ping's water column
(``n_samples x n_beams``). From it each beam's bottom is detected, and each detection is a
sounding: a two-way travel time, an angle across track (and one along: the tilt), a
backscatter, and where it lies once turned into a point (:func:`georeference`: roll, pitch,
heave, the lever arm and the sound-speed profile applied, as survey software does).

Scene section (``type: multibeam``)::

    {type: multibeam, preset: r2sonic-2026, frequency_khz: 400, n_beams: 256, swath_deg: 130,
     beam_spacing: equiangular, tx_beam_width_along_deg: 1, rx_beam_width_across_deg: 0.5,
     pulse_length_us: 50, range_min_m: 0, range_max_m: 100, n_samples: 2048, ping_rate_hz: 10,
     sound_speed_m_s: 1500, sound_speed_profile: [[0, 1500], [30, 1530]],
     processing_profile: [[0, 1500]], surface_height_m: 30, refraction: arrival, detection: amplitude,
     detection_window_db: 10, sensor: {...}}

``beam_angles_deg: [first, last]`` (port-most, starboard-most beam centre, degrees, > 0 to port)
instead of ``swath_deg`` (centres from ``+swath/2`` to ``-swath/2``) gives an asymmetric swath
(the R2Sonic 2026 in the recording spans about +63 to -60 deg).

Bottom detection (``detection: amplitude``): in each beam's column, the samples around the
peak that stay within ``detection_window_db`` (default 10 dB) of it -- the contiguous run
containing the peak -- are the detection window; the range is their energy-weighted centroid
(power-weighted mean of the sample centres; the peak and window are found on the column
smoothed over three samples), the two-way time ``2 r / sound_speed_m_s`` (the
speed the head ranges with); the backscatter is the mean power over the window (less
speckle-bound than the peak). A beam whose column is empty has no detection (NaN).

Refraction (``sound_speed_profile``: the TRUE water, depth below the surface -> speed, linear
between knots, constant beyond the first and last; ``surface_height_m``: where the surface is
in the world, default the head's own height at each ping, a hull mount). The engine casts
straight rays, so the forward model (``refraction: arrival``, the default) is: each beam's
truth is the point the engine's rays found (the energy-weighted first hits of the beam's rays
within the detection's window, :func:`footprint_points`: where the energy the detector weighed
came from); its one-way time and the direction the echo arrives from are re-solved through
the true profile (two-point ray tracing, :meth:`SoundSpeedProfile.solve`: Newton on the
ray parameter, vectorised over beams); the beam's water column is mapped onto the head's time
axis by that time (each column stretched by ``c_head T / |P - O|``: a target elsewhere in the
beam moves with the bottom's ratio, an approximation), and the detection on it gives the
two-way time. The sounding's angles are those of the arrival, so the processing
(:func:`georeference` with ``processing_profile``, default the true one) turns them back into
the truth point (up to the detection's error) when the two profiles agree, and into the curled
outer beams surveyors recognise ("smile" or "frown") when they do not.

``refraction: beam`` instead keeps each beam's direction (the straight ray to its footprint,
the beam table's angle as a device reports it) and bends that ray through the true profile to
the tangent plane of the footprint (the energy-weighted normal of the hits there,
:func:`bent_to_plane`): the same on planar facets, a curvature-sized error on curved surfaces,
and no occlusion along the bent path (the engine's straight ray decided what was hit).

Without a profile the water is uniform at ``sound_speed_m_s`` and rays are straight: the angles
are the directions of the truth points (within a fraction of a beam width of the beam table,
the footprint's centroid).

Rays per beam (``rays_across``, ``rays_along``): the engine spreads a ray's echo over range
only between neighbours along the elevation axis (along track here), so the rays across a
beam must be dense enough that a slant footprint is one echo, not a comb (the ``auto`` rule).

Known simplifications: the receive beams are planes of constant azimuth over the transmit's
width, not cones, and one width (a steered beam widens by ``1 / cos``: DESIGN.md section 15);
one ray count for every beam (the nadir beams get as many rays across as the outermost);
``detection: phase`` is not implemented; the water column itself is straight-ray (only its
mapping to time per beam is refracted); ``labels`` are not formed (``points_m`` is the truth).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..config.instruments import Channel, InstrumentSpec, mounted, register
from ..config.loader import _integer, _number
from ..config.sensor import PulseSpec, SensorSpec
from ..config.sonar import SonarConfig
from ..core.rays import make_ray_fan
from ..core.transforms import Pose, rpy_to_matrix
from ..errors import ConfigError, shown
from ..image.films import PingGeometry, Soundings, range_axis
from ..image.units import instrument_unit
from ..sensor.model import SensorModel
from . import renders
from ._sections import parse_section, section_dict
from . import ping_geometry

__all__ = ["MultibeamSpec", "SoundSpeedProfile", "render_multibeam", "ping_soundings", "detect_bottom",
           "footprint_points", "FrameHits", "bent_to_plane",
           "georeference", "arrivals", "beam_table_deg", "head_angles_deg"]

SPACINGS = ("equiangular", "equidistant")
DETECTIONS = ("amplitude",)
REFRACTIONS = ("arrival", "beam")
# The widest beam from the vertical, degrees (the fan must stay inside +-90: SonarConfig).
MAX_BEAM_ANGLE_DEG = 80.0
# Roll the auto ray count across a beam allows for (degrees added to the widest beam's angle).
ATTITUDE_MARGIN_DEG = 10.0
# The detection finds its peak and window on the column smoothed over this many samples
# (bridging a one-sample gap between the echoes of neighbouring rays, or of speckle), and
# weighs the raw samples within it.
DETECTION_SMOOTHING = 3
# Samples about each beam's peak the detection works on (a window reaching the band's edge is
# redone on the whole column).
DETECTION_BAND = 128
# A layer whose gradient is below this (1/s) is uniform: the straight-ray forms are exact to
# c g t^2, below a micrometre over a second's travel.
FLAT_GRADIENT = 1e-9
# Far depths standing for the half-infinite layers above the first knot and below the last.
_FAR_M = 1e7
# Two-point ray tracing: Newton steps at most, and the horizontal miss accepted (metres).
_SOLVE_STEPS = 60
_SOLVE_TOL_M = 1e-9
# The bent ray's crossing of a plane: the miss accepted (metres).
_PLANE_TOL_M = 1e-7


# -- the water ----------------------------------------------------------------------------

def _log1p_over(u: np.ndarray) -> np.ndarray:
    """``log1p(u) / u``, 1 at ``u = 0`` (a layer's time without the 0/0 of a small gradient)."""
    small = np.abs(u) < 1e-8
    safe = np.where(small, 1.0, u)
    return np.where(small, 1.0 - u / 2.0, np.log1p(safe) / safe)


def _expm1_over(u: np.ndarray) -> np.ndarray:
    """``expm1(u) / u``, 1 at ``u = 0``."""
    small = np.abs(u) < 1e-8
    safe = np.where(small, 1.0, u)
    return np.where(small, 1.0 + u / 2.0, np.expm1(safe) / safe)


@dataclass(frozen=True)
class SoundSpeedProfile:
    """Sound speed against depth: knots joined linearly (a constant gradient per layer).

    Above the first knot the speed is the first knot's, below the last the last's. In a layer of
    gradient ``g`` a ray is a circular arc (radius ``1 / (p |g|)``); Snell's law keeps the ray
    parameter ``p = sin(beta) / c`` (``beta`` the angle from the vertical) along it. The closed
    forms per layer (``c1, c2`` the speeds, ``cos1, cos2`` the cosines at its two ends, ``dz``
    its thickness crossed), written so that they hold as ``g -> 0`` and ``p -> 0``:

    * horizontal offset ``x = p dz (c1 + c2) / (cos1 + cos2)``;
    * time ``t = [ln(c2 / c1) + ln((1 + cos1) / (1 + cos2))] / g`` (``dz / (c cos)`` at g = 0);
    * ``dx / dp = dz (c1 + c2) / ((cos1 + cos2) cos1 cos2)`` (for Newton's steps).

    Attributes
    ----------
    depth_m : tuple of float, (k,)
        Knot depths below the surface, metres, strictly increasing, >= 0.
    speed_m_s : tuple of float, (k,)
        Speeds at the knots, m/s, within [1300, 1700].
    """

    depth_m: tuple
    speed_m_s: tuple
    _layers: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        z = tuple(float(v) for v in np.ravel(self.depth_m))
        c = tuple(float(v) for v in np.ravel(self.speed_m_s))
        object.__setattr__(self, "depth_m", z)
        object.__setattr__(self, "speed_m_s", c)
        if not z or len(z) != len(c):
            raise ConfigError("", f"needs at least one [depth_m, speed_m_s] knot, got {len(z)} depths and "
                              f"{len(c)} speeds")
        if not all(math.isfinite(v) and 0.0 <= v <= 1.2e4 for v in z):
            raise ConfigError("", f"depths must lie in [0, 12000] m, got {list(z)}")
        if any(b <= a for a, b in zip(z, z[1:])):
            raise ConfigError("", f"depths must increase strictly, got {list(z)}")
        if not all(math.isfinite(v) and 1300.0 <= v <= 1700.0 for v in c):
            raise ConfigError("", f"speeds must lie in [1300, 1700] m/s, got {list(c)}")
        za, ca = np.array(z), np.array(c)
        lo = np.concatenate([[-_FAR_M], za])
        hi = np.concatenate([za, [_FAR_M]])
        c_lo = np.concatenate([[ca[0]], ca])
        g = np.zeros(len(lo))
        if len(za) > 1:
            g[1:-1] = np.diff(ca) / np.diff(za)
        object.__setattr__(self, "_layers", (lo, hi, c_lo, g))

    @classmethod
    def parse(cls, value: Any, key: str) -> "SoundSpeedProfile":
        """A profile from a scene file's list of ``[depth_m, speed_m_s]`` pairs (or a profile).

        Raises
        ------
        ConfigError
            ``key``: not a list of pairs, or the knots out of range.
        """
        if isinstance(value, SoundSpeedProfile):
            return value
        if not isinstance(value, (list, tuple)) or not value or not all(
                isinstance(k, (list, tuple)) and len(k) == 2 for k in value):
            raise ConfigError(key, f"must be a list of [depth_m, speed_m_s] pairs, got {shown(value)}")
        z = [_number(k[0], f"{key}[{i}][0]") for i, k in enumerate(value)]
        c = [_number(k[1], f"{key}[{i}][1]") for i, k in enumerate(value)]
        try:
            return cls(tuple(z), tuple(c))
        except ConfigError as exc:
            raise ConfigError(key, exc.detail) from None

    def to_list(self) -> list:
        return [[z, c] for z, c in zip(self.depth_m, self.speed_m_s)]

    @classmethod
    def uniform(cls, speed_m_s: float) -> "SoundSpeedProfile":
        return cls((0.0,), (float(speed_m_s),))

    def speed(self, depth_m: np.ndarray) -> np.ndarray:
        """Speed at ``depth_m`` (any shape), m/s."""
        return np.interp(np.asarray(depth_m, np.float64), self.depth_m, self.speed_m_s)

    # Each method works on arrays of one shape S (broadcast), the layers along a last axis.

    def _segments(self, za: np.ndarray, zb: np.ndarray, p: np.ndarray):
        """Per layer the part of ``[za, zb]`` inside it: thickness, end speeds and cosines
        (``(*S, L)``); a cosine is NaN where the ray would be horizontal or past it there."""
        lo, hi, c_lo, g = self._layers
        a = np.clip(za[..., None], lo, hi)
        b = np.clip(zb[..., None], lo, hi)
        dz = b - a
        c1 = c_lo + g * (a - lo)
        c2 = c_lo + g * (b - lo)
        pp = p[..., None]
        with np.errstate(invalid="ignore"):
            cos1 = np.sqrt(1.0 - (pp * c1) ** 2)
            cos2 = np.sqrt(1.0 - (pp * c2) ** 2)
        return dz, c1, c2, cos1, cos2, g, pp

    def travel(self, p: np.ndarray, za: np.ndarray, zb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A ray of parameter ``p`` between depths ``za <= zb``.

        Parameters
        ----------
        p : array, s/m
            ``sin(beta) / c``, the same at every depth (Snell).
        za, zb : arrays, metres
            The depths it crosses (the ray's direction does not matter: the path is the same).

        Returns
        -------
        x : array, metres
            The horizontal distance covered; NaN where the ray turns before ``zb``.
        t : array, seconds
            The one-way travel time.
        dx_dp : array, m^2/s
        """
        p, za, zb = np.broadcast_arrays(np.asarray(p, np.float64), np.asarray(za, np.float64),
                                        np.asarray(zb, np.float64))
        dz, c1, c2, cos1, cos2, g, pp = self._segments(za, zb, p)
        on = dz > 0
        s = cos1 + cos2
        with np.errstate(invalid="ignore", divide="ignore"):
            x = np.where(on, pp * dz * (c1 + c2) / s, 0.0)
            k = pp ** 2 * (c1 + c2) / (s * (1.0 + cos2))
            t = np.where(on, dz * (_log1p_over(g * dz / c1) / c1 + k * _log1p_over(k * g * dz)), 0.0)
            dxdp = np.where(on, dz * (c1 + c2) / (s * cos1 * cos2), 0.0)
        return x.sum(-1), t.sum(-1), dxdp.sum(-1)

    def trace(self, p: np.ndarray, z0: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where a downgoing ray of parameter ``p`` from depth ``z0`` is after one-way time ``t``.

        Parameters
        ----------
        p : array, s/m
        z0 : array, metres
            The launch depth.
        t : array, seconds

        Returns
        -------
        x : array, metres
            Horizontal distance from the launch point.
        z : array, metres
            Depth reached. Both NaN where the ray turns (horizontal) before ``t`` is spent, or
            where ``t`` is NaN.
        """
        p, z0, t = np.broadcast_arrays(np.asarray(p, np.float64), np.asarray(z0, np.float64),
                                       np.asarray(t, np.float64))
        lo, hi, c_lo, g = self._layers
        dz, c1, c2, cos1, cos2, _, pp = self._segments(z0, np.full_like(z0, _FAR_M), p)
        s = cos1 + cos2
        with np.errstate(invalid="ignore", divide="ignore"):
            k = pp ** 2 * (c1 + c2) / (s * (1.0 + cos2))
            t_layer = np.where(dz > 0, dz * (_log1p_over(g * dz / c1) / c1 + k * _log1p_over(k * g * dz)), 0.0)
            x_layer = np.where(dz > 0, pp * dz * (c1 + c2) / s, 0.0)
        t_layer = np.where(np.isnan(t_layer), np.inf, t_layer)  # a layer the ray turns in: it ends there
        t_end = np.cumsum(t_layer, axis=-1)
        x_end = np.cumsum(x_layer, axis=-1)
        n_layers = len(lo)
        i = np.minimum(np.sum(t_end < t[..., None], axis=-1), n_layers - 1)[..., None]  # the layer t ends in
        before = i - 1
        t_before = np.where(before >= 0, np.take_along_axis(t_end, np.maximum(before, 0), -1), 0.0)[..., 0]
        x_before = np.where(before >= 0, np.take_along_axis(x_end, np.maximum(before, 0), -1), 0.0)[..., 0]
        tau = t - t_before
        z_s = np.clip(z0, lo[i[..., 0]], hi[i[..., 0]])
        gi = g[i[..., 0]]
        c_s = c_lo[i[..., 0]] + gi * (z_s - lo[i[..., 0]])
        with np.errstate(invalid="ignore", over="ignore"):
            cos_s = np.sqrt(1.0 - (p * c_s) ** 2)
            # tan(beta / 2) grows as exp(g tau) along an arc; the depth from it without the
            # cancellation of (c - c_s) / g: see the class notes.
            q1 = p * c_s / (1.0 + cos_s)
            e = np.exp(gi * tau)
            d = c_s * tau * _expm1_over(gi * tau) * (2.0 - (1.0 + cos_s) * q1 ** 2 * (e + 1.0)) / (
                (1.0 + cos_s) * (1.0 + (q1 * e) ** 2))
            d = np.where(np.abs(gi) < FLAT_GRADIENT, c_s * tau * cos_s, d)
            turned = (q1 * e >= 1.0) & (gi * p > 0)
            c_e = c_s + gi * d
            cos_e = np.sqrt(1.0 - (p * c_e) ** 2)
            x = x_before + p * d * (c_s + c_e) / (cos_s + cos_e)
        bad = turned | ~np.isfinite(x) | ~np.isfinite(t) | (tau < 0)
        return np.where(bad, np.nan, x), np.where(bad, np.nan, z_s + d)

    def solve(self, z0: np.ndarray, z1: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Two-point ray tracing: the ray from depth ``z0`` that reaches depth ``z1`` at a
        horizontal distance ``x``.

        Newton's steps on ``p`` (``x(p)`` grows from 0 and is convex: from a start above the
        root the steps descend to it without overshooting; any step outside the bracket is a
        bisection), vectorised over the arrays.

        Returns
        -------
        p : array, s/m
            The ray parameter; NaN where no ray reaches (the point is in a shadow zone) or
            ``z1 == z0`` with ``x > 0``.
        t : array, seconds
            The one-way travel time.
        """
        z0, z1, x = np.broadcast_arrays(np.asarray(z0, np.float64), np.asarray(z1, np.float64),
                                        np.asarray(x, np.float64))
        za, zb = np.minimum(z0, z1), np.maximum(z0, z1)
        # The fastest water on the way bounds p (the ray turns where p c = 1).
        knots = np.array(self.depth_m)
        inside = (knots > za[..., None]) & (knots < zb[..., None])
        c_max = np.maximum(np.maximum(self.speed(za), self.speed(zb)),
                           np.where(inside, np.array(self.speed_m_s), 0.0).max(-1, initial=0.0))
        p_hi = 1.0 / c_max
        lo = np.zeros_like(x)
        hi = p_hi.copy()
        straight = x / np.maximum(np.hypot(x, zb - za), 1e-300)
        p = np.clip(straight / self.speed(z0), 0.0, p_hi * (1.0 - 1e-12))
        done = x <= 0
        p = np.where(done, 0.0, p)
        done = done | ~np.isfinite(x) | ~np.isfinite(z0) | ~np.isfinite(z1)  # nothing to solve (NaN out)
        for _ in range(_SOLVE_STEPS):
            xi, _, dxdp = self.travel(p, za, zb)
            f = np.where(np.isnan(xi), np.inf, xi - x)  # turned: too steep a p
            done = done | (np.abs(f) <= _SOLVE_TOL_M)
            if done.all():
                break
            hi = np.where(f > 0, p, hi)
            lo = np.where(f < 0, p, lo)
            with np.errstate(invalid="ignore", divide="ignore"):
                newton = p - f / dxdp
            step = np.where(np.isfinite(newton) & (newton > lo) & (newton < hi), newton, 0.5 * (lo + hi))
            p = np.where(done, p, step)
        xi, t, _ = self.travel(p, za, zb)
        ok = np.abs(xi - x) <= max(1e3 * _SOLVE_TOL_M, 0.0) + 1e-9 * np.abs(x)
        return np.where(ok, p, np.nan), np.where(ok, t, np.nan)


# -- the head ------------------------------------------------------------------------------

def beam_table_deg(n_beams: int, first_deg: float, last_deg: float, spacing: str = "equiangular") -> np.ndarray:
    """Beam centres from ``first_deg`` (port-most) to ``last_deg``, both included.

    ``equiangular``: equal steps of angle; ``equidistant``: equal steps of ``tan(angle)`` (equal
    steps across track on a flat floor under a level head).

    Returns
    -------
    (n_beams,) float64 ndarray, degrees, > 0 to port, descending.
    """
    if n_beams == 1:
        return np.array([(first_deg + last_deg) / 2.0])
    if spacing == "equidistant":
        return np.degrees(np.arctan(np.linspace(math.tan(math.radians(first_deg)), math.tan(math.radians(last_deg)),
                                                n_beams)))
    return np.linspace(first_deg, last_deg, n_beams)


@register
@dataclass(frozen=True)
class MultibeamSpec(InstrumentSpec):
    """A multibeam echosounder's configuration (validated here: a frozen configuration).

    Attributes
    ----------
    frequency_khz : float
        The carrier, kHz.
    n_beams : int
        Receive beams, in [1, 4096].
    swath_deg : float or None
        Beam centres from ``+swath/2`` (port) to ``-swath/2``, degrees, in (0, 160]; or
    beam_angles_deg : (first, last) or None
        The port-most and starboard-most beam centres, degrees, > 0 to port, first > last,
        each within +-80.
    beam_spacing : {'equiangular', 'equidistant'}
    tx_beam_width_along_deg : float
        The transmit beam's along-track width (the fan's elevation aperture), degrees.
    rx_beam_width_across_deg : float
        Each receive beam's across-track width, degrees.
    pulse_length_us : float
        The CW pulse, microseconds: spreads the water column over ``c tau / 2`` of range (the
        sensor's pulse stage if the instrument has a sensor without a pulse of its own, else
        its intensity kernel on the expected column).
    range_min_m, range_max_m : float
        The range window, metres.
    n_samples : int
        Water-column samples per beam.
    ping_rate_hz : float or None
        Default: the two-way time of the window.
    sound_speed_m_s : float
        The speed the head ranges with (time <-> range), m/s.
    sound_speed_profile : SoundSpeedProfile or None
        The true water (scene files: ``[[depth_m, speed_m_s], ...]``); None: uniform at
        ``sound_speed_m_s``.
    processing_profile : SoundSpeedProfile or None
        The profile the survey software ray-traces with; None: the true one.
    surface_height_m : float or None
        The world height of the water's surface (profiles count depth from it); None: at the
        head (a hull mount: the head at depth 0 every ping).
    refraction : {'arrival', 'beam'}
        How a true profile acts on the engine's straight rays (module notes): ``arrival`` keeps
        each beam's truth point and re-solves the path to it (exact on any surface; the angles
        are the arrival's, off the beam table by the bending); ``beam`` keeps the beam's
        direction and bends its ray to the tangent plane of the surface at that point (the
        angles stay the table's, as a device's; exact over planar facets, off by about the
        surface's curvature times the bend's offset squared elsewhere).
    detection : {'amplitude'}
    detection_window_db : float
        The detection window: samples within this of the beam's peak, dB, in (0, 60].
    rays_across, rays_along : int or 'auto'
        Rays per beam across its receive width and along the transmit's width. The engine
        spreads a ray's echo over range only between neighbours along track, so the rays
        across a beam must be dense enough that its footprint on an inclined floor is one
        echo, not a comb: ``auto`` puts neighbours at most two range samples apart (the
        detection's envelope bridges the sample between) at the far range in the outermost
        beam, rolled 10 deg further, over a floor normal to the head's axis
        (``range_max tan(max angle + 10 deg) width / (2 dr)``, 1 to 64); along track, ``auto`` puts
        neighbours at most two samples apart at the far range (``render.elevation_samples:
        auto``'s rule without its floor of 32 rays: along track the footprint spreads in range
        only as ``r phi^2 / 2``), 3 to 64.
    sensor : SensorSpec or None
    preset : str or None
    """

    type_name: ClassVar[str] = "multibeam"
    keys: ClassVar[tuple[str, ...]] = (
        "preset", "frequency_khz", "n_beams", "swath_deg", "beam_angles_deg", "beam_spacing",
        "tx_beam_width_along_deg", "rx_beam_width_across_deg", "pulse_length_us", "range_min_m", "range_max_m",
        "n_samples", "ping_rate_hz", "sound_speed_m_s", "sound_speed_profile", "processing_profile",
        "surface_height_m", "refraction", "detection", "detection_window_db", "rays_across", "rays_along",
        "sensor",
    )

    frequency_khz: float = 400.0
    n_beams: int = 256
    swath_deg: float | None = None
    beam_angles_deg: tuple | None = None
    beam_spacing: str = "equiangular"
    tx_beam_width_along_deg: float = 1.0
    rx_beam_width_across_deg: float = 0.5
    pulse_length_us: float = 50.0
    range_min_m: float = 0.0
    range_max_m: float = 100.0
    n_samples: int = 2048
    ping_rate_hz: float | None = None
    sound_speed_m_s: float = 1500.0
    sound_speed_profile: SoundSpeedProfile | None = None
    processing_profile: SoundSpeedProfile | None = None
    surface_height_m: float | None = None
    refraction: str = "arrival"
    detection: str = "amplitude"
    detection_window_db: float = 10.0
    rays_across: int | str = "auto"
    rays_along: int | str = "auto"
    sensor: SensorSpec | None = None
    preset: str | None = None
    _sonar: SonarConfig = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        def check(name: str, lo: float, hi: float, lo_open: bool = True) -> None:
            v = getattr(self, name)
            ok = (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                  and (v > lo if lo_open else v >= lo) and v <= hi)
            if not ok:
                raise ConfigError(name, f"must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {shown(v)}")
        check("frequency_khz", 1.0, 1e5)
        if isinstance(self.n_beams, bool) or not isinstance(self.n_beams, int) or not 1 <= self.n_beams <= 4096:
            raise ConfigError("n_beams", f"must be an integer in [1, 4096], got {shown(self.n_beams)}")
        if self.swath_deg is not None and self.beam_angles_deg is not None:
            raise ConfigError("beam_angles_deg", "give either swath_deg or beam_angles_deg, not both")
        if self.beam_angles_deg is None:
            object.__setattr__(self, "swath_deg", 130.0 if self.swath_deg is None else self.swath_deg)
            check("swath_deg", 0.0, 2.0 * MAX_BEAM_ANGLE_DEG)
        else:
            a = self.beam_angles_deg
            if (not isinstance(a, (list, tuple)) or len(a) != 2
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                               and abs(v) <= MAX_BEAM_ANGLE_DEG for v in a)):
                raise ConfigError("beam_angles_deg", "must be [first, last]: the port-most and starboard-most beam "
                                  f"centres, degrees within +-{MAX_BEAM_ANGLE_DEG:g}; got {shown(a)}")
            if not a[0] > a[1] and self.n_beams > 1:
                raise ConfigError("beam_angles_deg",
                                  f"the first (port-most, > 0 to port) must exceed the last; got {list(a)}")
            object.__setattr__(self, "beam_angles_deg", (float(a[0]), float(a[1])))
        if self.beam_spacing not in SPACINGS:
            raise ConfigError("beam_spacing", f"must be one of {', '.join(SPACINGS)}; got {shown(self.beam_spacing)}")
        check("tx_beam_width_along_deg", 0.01, 30.0, lo_open=False)
        check("rx_beam_width_across_deg", 0.01, 30.0, lo_open=False)
        check("pulse_length_us", 0.1, 1e5, lo_open=False)
        check("sound_speed_m_s", 1300.0, 1700.0, lo_open=False)
        check("range_max_m", 0.0, 1e4)
        check("range_min_m", 0.0, self.range_max_m, lo_open=False)
        if self.range_min_m >= self.range_max_m:
            raise ConfigError("range_min_m", f"must be below range_max_m ({self.range_max_m:g}), got {self.range_min_m:g}")
        if isinstance(self.n_samples, bool) or not isinstance(self.n_samples, int) or not 1 <= self.n_samples <= 1_000_000:
            raise ConfigError("n_samples", f"must be an integer in [1, 1000000], got {shown(self.n_samples)}")
        if self.ping_rate_hz is not None:
            check("ping_rate_hz", 0.0, 1e3)
        for name in ("sound_speed_profile", "processing_profile"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, SoundSpeedProfile):
                object.__setattr__(self, name, SoundSpeedProfile.parse(v, name))
        if self.surface_height_m is not None:
            check("surface_height_m", -1e5, 1e5)
        if self.refraction not in REFRACTIONS:
            raise ConfigError("refraction", f"must be one of {', '.join(REFRACTIONS)}; got {shown(self.refraction)}")
        if self.detection not in DETECTIONS:
            raise ConfigError("detection", f"must be one of {', '.join(DETECTIONS)} (phase detection is not "
                              f"implemented); got {shown(self.detection)}")
        check("detection_window_db", 0.0, 60.0)
        for name in ("rays_across", "rays_along"):
            v = getattr(self, name)
            if v != "auto" and (isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1024):
                raise ConfigError(name, f"must be 'auto' or an integer in [1, 1024], got {shown(v)}")
        try:
            sonar = SonarConfig(beam_angles_deg=tuple(self.beam_table_deg()),
                                elevation_fov_deg=self.tx_beam_width_along_deg, range_min_m=self.range_min_m,
                                range_max_m=self.range_max_m, n_range_bins=self.n_samples,
                                beam_width_deg=self.rx_beam_width_across_deg, frequency_khz=self.frequency_khz)
        except ConfigError as exc:  # the fan's keys are this section's
            names = {"sonar.n_range_bins": "n_samples", "sonar.beam_width_deg": "rx_beam_width_across_deg",
                     "sonar.elevation_fov_deg": "tx_beam_width_along_deg"}
            raise ConfigError(names.get(exc.key, "swath_deg" if self.beam_angles_deg is None else "beam_angles_deg"),
                              exc.detail) from None
        object.__setattr__(self, "_sonar", sonar)

    # -- geometry --------------------------------------------------------------------------

    def beam_table_deg(self) -> np.ndarray:
        """The beams' centres across track, degrees, > 0 to port, port-most first, ``(n_beams,)``."""
        first, last = (self.swath_deg / 2.0, -self.swath_deg / 2.0) if self.beam_angles_deg is None \
            else self.beam_angles_deg
        return beam_table_deg(self.n_beams, first, last, self.beam_spacing)

    def ray_counts(self) -> tuple[int, int]:
        """Rays per beam ``(across, along)`` (``rays_across``, ``rays_along`` resolved)."""
        across = self.rays_across
        if across == "auto":
            dr = (self.range_max_m - self.range_min_m) / self.n_samples
            widest = math.radians(min(float(np.max(np.abs(self.beam_table_deg()))) + ATTITUDE_MARGIN_DEG,
                                      MAX_BEAM_ANGLE_DEG))
            # two samples apart: the detection's 3-sample envelope bridges the one between
            across = int(min(max(math.ceil(self.range_max_m * math.tan(widest)
                                           * math.radians(self.rx_beam_width_across_deg) / (2.0 * dr)), 1), 64))
        along = self.rays_along
        if along == "auto":
            dr = (self.range_max_m - self.range_min_m) / self.n_samples
            along = int(min(max(math.ceil(math.radians(self.tx_beam_width_along_deg) * self.range_max_m / (2.0 * dr)),
                                3), 64))
        return int(across), int(along)

    def channel_sonar(self) -> SonarConfig:
        """The fan and grid: the beam table, the transmit's along-track width as elevation
        aperture, ``n_samples`` range bins."""
        return self._sonar

    def channels(self) -> tuple[Channel, ...]:
        # Pitched +90 deg (down): the channel's x is the vehicle's -z, its y the vehicle's y
        # (port: azimuth > 0 to port), its z the vehicle's x (elevation > 0 forward).
        return (Channel("multibeam", self._sonar, mounted(self.mount, Pose((0.0, 0.0, 0.0), (0.0, 90.0, 0.0)))),)

    def ping_period_s(self) -> float:
        if self.ping_rate_hz:
            return 1.0 / self.ping_rate_hz
        return 2.0 * self.range_max_m / self.sound_speed_m_s

    @property
    def processing(self) -> SoundSpeedProfile | None:
        """The profile the processing ray-traces with (None: straight at ``sound_speed_m_s``)."""
        return self.processing_profile if self.processing_profile is not None else self.sound_speed_profile

    def sensor_with_pulse(self) -> SensorSpec | None:
        """The sensor chain, its pulse the instrument's CW pulse unless it has its own."""
        if self.sensor is None or self.sensor.pulse is not None:
            return self.sensor
        return replace(self.sensor, pulse=PulseSpec(kind="cw", length_us=self.pulse_length_us))

    def soundings_points(self, film: Soundings, vehicle_poses: list[Pose],
                         profile: SoundSpeedProfile | None | str = "processing") -> tuple[np.ndarray, np.ndarray]:
        """A film's soundings as points (:func:`georeference`) for the vehicle at ``vehicle_poses``.

        ``profile``: ``'processing'`` (default: :attr:`processing`), ``'true'``, None (straight)
        or a profile. Returns ``(world, vehicle)``, each ``(n_pings, n_beams, 3)``, metres.
        """
        prof = {"processing": self.processing, "true": self.sound_speed_profile}.get(profile, profile) \
            if isinstance(profile, str) else profile
        return georeference(film.two_way_time_s, film.angle_deg, [v.rpy_deg for v in vehicle_poses], self.mount,
                            position_m=[v.position_m for v in vehicle_poses], heave_m=film.geometry.heave_m,
                            tilt_deg=film.tilt_deg, profile=prof, sound_speed_m_s=self.sound_speed_m_s,
                            head_depth_m=np.nan_to_num(film.geometry.depth_m, nan=0.0))

    # -- files -----------------------------------------------------------------------------

    @classmethod
    def parse(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose) -> "MultibeamSpec":
        def preset_keys(values: dict, section: Mapping) -> None:
            if "swath_deg" in section and "beam_angles_deg" not in section:
                values.pop("beam_angles_deg", None)  # the file's swath replaces a preset's table
            if "beam_angles_deg" in section and "swath_deg" not in section:
                values.pop("swath_deg", None)

        def convert(k: str, v: Any, where: str) -> Any:
            if v is None and k in ("surface_height_m", "processing_profile", "sound_speed_profile", "swath_deg",
                                   "beam_angles_deg"):
                return None
            if k in ("beam_spacing", "detection", "refraction") or (k in ("rays_across", "rays_along") and v == "auto"):
                return v
            if k in ("rays_across", "rays_along"):
                return _integer(v, where)
            if k == "beam_angles_deg":
                if not isinstance(v, (list, tuple)) or len(v) != 2:
                    raise ConfigError(where, f"must be [first, last] (degrees, > 0 to port), got {shown(v)}")
                return (_number(v[0], f"{where}[0]"), _number(v[1], f"{where}[1]"))
            if k in ("sound_speed_profile", "processing_profile"):
                return SoundSpeedProfile.parse(v, where)
            return NotImplemented

        return parse_section(cls, d, key, base_dir, name, mount, integers=("n_beams", "n_samples"),
                             nullable=("ping_rate_hz",), convert=convert, preset_keys=preset_keys)

    def to_dict(self) -> dict:
        return section_dict(self, lambda v: v.to_list() if isinstance(v, SoundSpeedProfile)
                            else list(v) if isinstance(v, tuple) else v)


# -- per-beam work (vectorised over beams) -------------------------------------------------

def detect_bottom(water_column: np.ndarray, range_min_m: float, range_max_m: float, window_db: float = 10.0,
                  smoothing: int = 1, band: int | None = DETECTION_BAND) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Amplitude bottom detection in each beam's column.

    Parameters
    ----------
    water_column : (n_samples, n_beams) array
        Power per sample (sample 0 the nearest).
    range_min_m, range_max_m : float
        The window the samples cover.
    window_db : float
        The detection window: the contiguous samples around the peak within this of it.
    smoothing : int
        The peak and the window are found on the column's moving average over this many
        samples (odd); the centroid weighs the raw samples inside the window.
    band : int or None
        Work on the ``band`` samples about each beam's peak (the window is the same: a beam
        whose window reaches the band's edge is done again on its whole column); None: whole
        columns. Only the speed differs.

    Returns
    -------
    range_m : (n_beams,) float64 ndarray
        The window's energy-weighted centroid (sample centres), metres; NaN: no echo.
    intensity : (n_beams,) float64 ndarray
        The mean power over the window; NaN: no echo.
    window : (2, n_beams) int64 ndarray
        The window's first and one-past-last sample.
    """
    wc = np.asarray(water_column, np.float32)
    n, m = wc.shape
    env = wc
    if smoothing > 1:  # a moving sum over the shifted columns (the threshold is relative: a sum will do)
        env = wc.copy()
        for shift in range(1, int(smoothing) // 2 + 1):
            env[shift:] += wc[:-shift]
            env[:-shift] += wc[shift:]
    peak = np.argmax(env, axis=0)
    if band is None or band >= n:
        lo, hi, total = _windows(wc, env, peak, window_db)
    else:
        # The band about each peak, (band, n_beams), gathered: the full-column passes are the
        # smoothing and the peak's search alone.
        start = np.clip(peak - band // 2, 0, n - band)
        rows = start[None, :] + np.arange(band)[:, None]
        cols = np.arange(m)[None, :]
        lo, hi, total = _windows(wc[rows, cols], env[rows, cols], peak - start, window_db)
        lo, hi = lo + start, hi + start
        redo = np.nonzero(((lo == start) & (start > 0)) | ((hi == start + band) & (start + band < n)))[0]
        if len(redo):  # windows longer than the band (rare: a long slant footprint)
            lo[redo], hi[redo], total[redo] = _windows(wc[:, redo], env[:, redo], peak[redo], window_db)
    r = range_axis(range_min_m, range_max_m, n)
    found = np.isfinite(total) & (total > 0)
    if band is None or band >= n:
        idx = np.arange(n)[:, None]
        rw = r @ np.where((idx >= lo) & (idx < hi), wc, np.float32(0.0))
    else:  # the window lies in the band from lo on, except for the beams redone
        at = lo[None, :] + np.arange(band)[:, None]
        rows = np.minimum(at, n - 1)
        wb = np.where(at < hi[None, :], wc[rows, np.arange(m)[None, :]], np.float32(0.0))
        rw = (r[rows] * wb).sum(axis=0)
        if len(redo):
            idx = np.arange(n)[:, None]
            rw[redo] = r @ np.where((idx >= lo[redo]) & (idx < hi[redo]), wc[:, redo], np.float32(0.0))
    size = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        rng = rw / total
        level = total / np.maximum(size, 1)
    return np.where(found, rng, np.nan), np.where(found, level, np.nan), np.stack([lo, hi])


def _windows(wc: np.ndarray, env: np.ndarray, peak: np.ndarray, window_db: float):
    """The run of samples about ``peak`` (per column) where ``env`` stays within ``window_db``
    of its value there: ``(lo, hi, total power of wc in [lo, hi))``, vectorised over columns."""
    cols = np.arange(wc.shape[1])
    top = env[peak, cols]
    below = ~(env >= top * np.float32(10.0 ** (-window_db / 10.0)))  # NaN counts as below
    # The samples with as many below the threshold before them as the peak has (one cumulative
    # count, no per-beam search), and not below themselves.
    count = np.cumsum(below, axis=0, dtype=np.int32)
    inside = (count == count[peak, cols]) & ~below
    size = inside.sum(axis=0)
    lo = np.argmax(inside, axis=0)
    total = np.where(inside, wc, np.float32(0.0)).sum(axis=0, dtype=np.float64)
    return lo.astype(np.int64), (lo + size).astype(np.int64), np.where(size > 0, total, 0.0)


class FrameHits:
    """A frame's first hits per beam, ready for weighted sums (made once per ping).

    Attributes
    ----------
    distance : (n_beams, k) float64 ndarray
        Each ray's first-hit distance, metres (0 where none or outside the window).
    weight : (n_beams, k) float64 ndarray
        The intensity the engine gave the ray there (0 where none or outside the window).
    """

    def __init__(self, paths, range_min_m: float = 0.0, range_max_m: float = np.inf) -> None:
        distance, sid, intensity = paths.first_hits()
        n_beams = distance.shape[0]
        dist = distance.reshape(n_beams, -1)
        ok = (sid.reshape(n_beams, -1) >= 0) & np.isfinite(dist) & (dist >= range_min_m) & (dist <= range_max_m)
        self.paths = paths
        self.distance = np.where(ok, dist, 0.0).astype(np.float64)
        self.weight = np.where(ok, intensity.reshape(n_beams, -1), 0.0).astype(np.float64)
        # In the channel's frame (the fan's own directions), one rotation per beam after the
        # sums: rotating every ray into the world would cost as much as the rest of the ping.
        self.directions = paths.fan.directions.reshape(n_beams, -1, 3)
        self.rotation = np.asarray(paths.view.rotation, np.float64)
        self.origin = np.asarray(paths.view.origin, np.float64).reshape(3)
        self._normals = None

    def normals(self) -> np.ndarray:
        """Each ray's surface normal turned towards the head, the channel's frame, ``(n_beams, k, 3)``."""
        if self._normals is None:
            n = np.nan_to_num(np.asarray(self.paths.primary.normal, np.float64)).reshape(self.directions.shape)
            n = n @ self.rotation  # R^T n: into the channel's frame, beside the rays
            facing = np.where(np.einsum("bkj,bkj->bk", n, self.directions) > 0, -1.0, 1.0)
            self._normals = n * facing[..., None]
        return self._normals

    def points(self, gate_m: np.ndarray | None = None, normals: bool = False):
        """:func:`footprint_points` of these hits."""
        w = self.weight
        if gate_m is not None:
            gate = np.asarray(gate_m, np.float64)
            w = np.where((self.distance >= gate[0][:, None]) & (self.distance < gate[1][:, None]), w, 0.0)
        total = w.sum(axis=1)
        offset = np.einsum("bk,bkj->bj", w * self.distance, self.directions)
        found = (total > 0)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(found, self.origin + (offset / total[:, None]) @ self.rotation.T, np.nan)
        if not normals:
            return p
        nw = np.einsum("bk,bkj->bj", w, self.normals()) @ self.rotation.T
        with np.errstate(invalid="ignore", divide="ignore"):
            nw /= np.linalg.norm(nw, axis=1, keepdims=True)
        return p, np.where(found, nw, np.nan)


def footprint_points(paths, range_min_m: float = 0.0, range_max_m: float = np.inf, gate_m: np.ndarray | None = None,
                     normals: bool = False):
    """Each beam's truth: the energy-weighted mean of its rays' first hits, world frame.

    A beam's rays that meet a surface within the range window (and within its ``gate_m``),
    weighted by the intensity the engine gave them (pattern, backscatter): a point on the floor
    where the floor is flat (a mean of points on a plane).

    Parameters
    ----------
    paths : FramePaths
    range_min_m, range_max_m : float
        The window, metres.
    gate_m : (2, n_beams) array, optional
        Per beam the first hits' distances kept, ``[near, far)`` metres (the detection's window:
        where the energy the detector weighed came from, so that a beam half on an object and
        half on the floor behind it has its truth on the one it detected, not between).
    normals : bool
        Also return each beam's energy-weighted surface normal (unit, towards the head).

    Returns
    -------
    (n_beams, 3) float64 ndarray, metres; NaN for a beam whose rays meet nothing (in its gate).
    With ``normals``, ``(points, normals)``.
    """
    return FrameHits(paths, range_min_m, range_max_m).points(gate_m, normals)


def head_angles_deg(u_world: np.ndarray, head_rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Across-track angle and tilt of world directions in a head's frame (x forward, y port, z up).

    ``angle = atan2(v_y, -v_z)`` (0 down, > 0 port), ``tilt = asin(v_x)`` (> 0 forward), with
    ``v = R^T u``. ``u_world``: ``(..., 3)``; ``head_rotation``: ``(3, 3)`` head-to-world.
    """
    v = np.asarray(u_world, np.float64) @ np.asarray(head_rotation, np.float64)  # R^T u, row vectors
    return np.degrees(np.arctan2(v[..., 1], -v[..., 2])), np.degrees(np.arcsin(np.clip(v[..., 0], -1.0, 1.0)))


def bent_to_plane(origin_m: np.ndarray, direction: np.ndarray, points_m: np.ndarray, normals: np.ndarray,
                  profile: SoundSpeedProfile, head_depth_m: float = 0.0) -> np.ndarray:
    """Where refracted rays meet planes: each ray launched from the head along ``direction``,
    bent through ``profile``, met with the plane through ``points_m`` normal to ``normals``.

    The crossing time is found by Newton's steps on ``n . (ray(t) - point)`` (its rate
    ``n . velocity``, the velocity ``c (sin b cos a, sin b sin a, -cos b)`` by Snell), kept in a
    bracket (the straight ray's time +-10 %, else ``[0, 3 |point - head| / c_min]``; a step
    outside it is a bisection), vectorised over rays.

    Parameters
    ----------
    origin_m : (3,) array
        The head, world frame.
    direction, points_m, normals : (n, 3) arrays
        Unit launch directions (downwards), the planes' points and unit normals.
    profile : SoundSpeedProfile
    head_depth_m : float

    Returns
    -------
    points : (n, 3) float64 ndarray
        The crossings, metres; NaN where the ray turns or meets the plane beyond the bracket.
    time_s : (n,) float64 ndarray
        The one-way travel time to them.
    """
    o = np.asarray(origin_m, np.float64).reshape(3)
    u = np.asarray(direction, np.float64)
    rel = np.asarray(points_m, np.float64) - o
    nrm = np.asarray(normals, np.float64)
    c0 = float(profile.speed(head_depth_m))
    sin_b = np.hypot(u[:, 0], u[:, 1])
    p = sin_b / c0
    alpha = np.arctan2(u[:, 1], u[:, 0])
    d0 = np.full(len(u), float(head_depth_m))

    ca, sa = np.cos(alpha), np.sin(alpha)

    def f(t):
        """The signed distance past the plane at time t, and its rate (n . velocity)."""
        x, z = profile.trace(p, d0, t)
        r = np.stack([x * ca, x * sa, -(z - head_depth_m)], axis=-1)
        c = profile.speed(z)
        sb = p * c
        cb = np.sqrt(np.clip(1.0 - sb ** 2, 0.0, 1.0))
        v = c[:, None] * np.stack([sb * ca, sb * sa, -cb], axis=-1)
        return np.einsum("ij,ij->i", nrm, r - rel), np.einsum("ij,ij->i", nrm, v), r

    # A bracket about the straight ray's time first (most rays bend by a few per cent), the
    # wide one where that does not hold the crossing; then Newton's steps on t inside it
    # (bisection where a step leaves it).
    straight = np.linalg.norm(rel, axis=1) / c0
    lo, hi = 0.9 * straight, 1.1 * straight
    f_lo, f_hi = f(lo)[0], f(hi)[0]
    wide = ~(np.isfinite(f_lo) & np.isfinite(f_hi) & (f_lo * f_hi <= 0))
    if wide.any():
        lo = np.where(wide, 0.0, lo)
        hi = np.where(wide, 3.0 * np.linalg.norm(rel, axis=1) / min(profile.speed_m_s), hi)
        f_lo, f_hi = f(lo)[0], f(hi)[0]
    ok = np.isfinite(f_lo) & np.isfinite(f_hi) & (f_lo * f_hi <= 0) & (u[:, 2] < 0)
    rising = f_hi > f_lo  # the sign of f after the crossing
    t = np.where(ok, straight, 0.0)
    for _ in range(_SOLVE_STEPS):
        ft, dft, r = f(t)
        ft = np.where(ok, ft, 0.0)
        done = np.abs(ft) <= _PLANE_TOL_M
        if done.all():
            break
        past = (ft > 0) == rising
        hi, lo = np.where(past, t, hi), np.where(past, lo, t)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = t - ft / dft
        step = np.where(np.isfinite(step) & (step > lo) & (step < hi), step, 0.5 * (lo + hi))
        t = np.where(done, t, step)
    hit = ok & (np.abs(ft) <= 1e3 * _PLANE_TOL_M)
    return np.where(hit[:, None], o + r, np.nan), np.where(hit, t, np.nan)


def arrivals(origin_m: np.ndarray, points_m: np.ndarray, sound_speed_m_s: float,
             profile: SoundSpeedProfile | None = None, head_depth_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The one-way travel time and the arrival direction of sound from points to a head.

    Parameters
    ----------
    origin_m : (3,) array
        The head, world frame, metres.
    points_m : (n, 3) array
        The points (NaN rows give NaN).
    sound_speed_m_s : float
        The uniform water's speed (used without a profile).
    profile : SoundSpeedProfile, optional
        The water: rays refracted through it (two-point ray tracing).
    head_depth_m : float
        The head's depth below the profile's surface.

    Returns
    -------
    time_s : (n,) float64 ndarray
        One-way time, seconds.
    direction : (n, 3) float64 ndarray
        Unit vectors from the head along the ray's start (world frame).
    """
    o = np.asarray(origin_m, np.float64).reshape(3)
    rel = np.asarray(points_m, np.float64) - o
    if profile is None:
        r = np.linalg.norm(rel, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return r / sound_speed_m_s, rel / r[:, None]
    x = np.hypot(rel[:, 0], rel[:, 1])
    z1 = head_depth_m - rel[:, 2]
    p, t = profile.solve(np.full_like(x, head_depth_m), z1, x)
    sin_b = p * float(profile.speed(head_depth_m))
    cos_b = np.sqrt(np.clip(1.0 - sin_b ** 2, 0.0, 1.0))
    alpha = np.arctan2(rel[:, 1], rel[:, 0])
    down = np.where(rel[:, 2] <= 0, -1.0, 1.0)
    u = np.stack([sin_b * np.cos(alpha), sin_b * np.sin(alpha), down * cos_b], axis=-1)
    return t, u


def georeference(two_way_time_s, angle_deg, rpy_deg, mount: Pose = Pose(), position_m=None, heave_m=0.0,
                 tilt_deg=None, profile: SoundSpeedProfile | None = None, sound_speed_m_s: float = 1500.0,
                 head_depth_m=0.0) -> tuple[np.ndarray, np.ndarray]:
    """Soundings -> points: a beam's time and angles, the ping's attitude and the head's mount.

    The beam's direction in the head's frame (x forward, y port, z up) is ``(sin b, cos b sin a,
    -cos b cos a)`` (``a`` across, ``b`` the tilt); the vehicle's attitude and the mount turn
    it into the world. Without a profile the sounding lies ``c t / 2`` along it; with one, the
    ray of that launch angle (``p = sin(beta0) / c(head depth)``) is traced for ``t / 2``
    through the profile's layers (:meth:`SoundSpeedProfile.trace`) in the vertical plane of the
    direction.

    Parameters
    ----------
    two_way_time_s, angle_deg : (n_pings, n_beams) arrays
        Seconds; degrees, > 0 to port.
    rpy_deg : (n_pings, 3) array
        The vehicle's roll, pitch, yaw (scene convention: pitch > 0 nose down), degrees.
    mount : Pose
        The head on the vehicle (lever arm and rotation).
    position_m : (n_pings, 3) array, optional
        The vehicle's reference point in the world; default the origin.
    heave_m : (n_pings,) array or float
        Added to the vehicle's height (> 0 up).
    tilt_deg : (n_pings, n_beams) array, optional
        The along-track angle of each beam, degrees (default 0).
    profile : SoundSpeedProfile, optional
        The processing profile; None: straight rays at ``sound_speed_m_s``.
    head_depth_m : (n_pings,) array or float
        The head's depth below the profile's surface.

    Returns
    -------
    world : (n_pings, n_beams, 3) float64 ndarray
        The soundings in the world frame, metres.
    vehicle : (n_pings, n_beams, 3) float64 ndarray
        In the (heaved) vehicle's frame, metres.
    """
    t = np.atleast_2d(np.asarray(two_way_time_s, np.float64))
    n, m = t.shape
    a = np.radians(np.broadcast_to(np.asarray(angle_deg, np.float64), (n, m)))
    b = np.zeros((n, m)) if tilt_deg is None else np.radians(np.broadcast_to(np.asarray(tilt_deg, np.float64), (n, m)))
    rpy = np.radians(np.asarray(rpy_deg, np.float64).reshape(n, 3))
    pos = np.zeros((n, 3)) if position_m is None else np.asarray(position_m, np.float64).reshape(n, 3).copy()
    pos[:, 2] += np.broadcast_to(np.asarray(heave_m, np.float64), (n,))
    rv = np.stack([rpy_to_matrix(*r) for r in rpy])  # per ping: (n, 3, 3) vehicle-to-world
    rh = rv @ mount.rotation
    origin = pos + rv @ mount.translation
    v = np.stack([np.sin(b), np.cos(b) * np.sin(a), -np.cos(b) * np.cos(a)], axis=-1)
    u = np.einsum("pij,pbj->pbi", rh, v)
    if profile is None:
        world = origin[:, None, :] + u * (sound_speed_m_s * t / 2.0)[..., None]
    else:
        d0 = np.broadcast_to(np.asarray(head_depth_m, np.float64), (n,))[:, None] * np.ones((1, m))
        cos_b = -u[..., 2]
        sin_b = np.hypot(u[..., 0], u[..., 1])
        p = sin_b / profile.speed(d0)
        x, z = profile.trace(p, d0, t / 2.0)
        alpha = np.arctan2(u[..., 1], u[..., 0])
        rel = np.stack([x * np.cos(alpha), x * np.sin(alpha), -(z - d0)], axis=-1)
        rel = np.where((cos_b > 0)[..., None], rel, np.nan)  # a ray launched upwards: no sounding
        world = origin[:, None, :] + rel
    vehicle = np.einsum("pji,pbj->pbi", rv, world - pos[:, None, :])  # R^T (P - vehicle)
    return world, vehicle


# -- rendering ---------------------------------------------------------------------------

_FANS: dict = {}


def _fan(sim, spec: MultibeamSpec, sonar: SonarConfig):
    across, along = spec.ray_counts()
    render = replace(sim.scene.render, azimuth_samples=across, elevation_samples=along)
    key = (render, sonar)
    fan = _FANS.get(key)
    if fan is None:
        sim.require_frame_memory(sonar)
        fan = make_ray_fan(sonar, render)
        _FANS.clear()  # one multibeam at a time is the common case: keep memory flat
        _FANS[key] = fan
    return fan


def _pulse_kernel(spec: MultibeamSpec) -> np.ndarray:
    from ..sensor.pulse import range_kernels

    dr = (spec.range_max_m - spec.range_min_m) / spec.n_samples
    kernel, _ = range_kernels(PulseSpec(kind="cw", length_us=spec.pulse_length_us), dr, spec.sound_speed_m_s)
    return kernel


@renders("multibeam")
def render_multibeam(sim, spec: MultibeamSpec, poses: list[Pose], times_s: np.ndarray, first_ping: int,
                     speckle: bool | None, labels: bool) -> Soundings:
    """A multibeam's pings, one per vehicle pose, as :class:`Soundings` with their water column.

    Ping ``k`` is one engine frame at the head's pose; its draws (speckle, noise) come from
    ``(render.seed, first_ping + k)``. ``labels`` is accepted for the renderers' signature; a
    sounding's truth is ``points_m`` (:func:`footprint_points`).
    """
    from scipy.ndimage import convolve1d

    from ..core.memory import require

    channel = spec.channels()[0]
    sonar = channel.sonar
    n, m, ns = len(poses), spec.n_beams, spec.n_samples
    require(n * ns * m * 4 + n * m * 8 * 8, f"the water column and soundings of {n} pings x {m} beams x {ns} samples",
            "n_pings")
    fan = _fan(sim, spec, sonar)
    sensor = spec.sensor_with_pulse()
    model = SensorModel(sensor, sonar, sim.scene.render.seed) if sensor is not None else False
    kernel = (_pulse_kernel(spec) if sensor is None else np.ones(1)).astype(np.float32)
    water = np.empty((n, ns, m), np.float32)
    angle = np.empty((n, m))
    tilt = np.empty((n, m))
    twt = np.empty((n, m))
    level = np.empty((n, m))
    truth = np.empty((n, m, 3))
    depth = np.full(n, np.nan)
    for k, vehicle in enumerate(poses):  # per ping: one engine frame; the beams vectorised
        sim.at_time(float(times_s[k]))  # objects on tracks, where they are at the ping
        head = mounted(vehicle, spec.mount)
        paths = sim.trace(mounted(vehicle, channel.mount), sonar=sonar, fan=fan)
        image = sim.form(paths, keep_rays=False, speckle=speckle, frame=first_ping + k, sensor=model)
        wc = image.polar
        if len(kernel) > 1:
            wc = convolve1d(wc, kernel, axis=0, mode="constant")
        if spec.surface_height_m is not None:
            depth[k] = spec.surface_height_m - head.translation[2]
        water[k], angle[k], tilt[k], twt[k], level[k], truth[k] = ping_soundings(spec, paths, wc, head)
    geometry = ping_geometry(sim, poses, times_s, spec)
    geometry = PingGeometry(**{**geometry.as_dict(), "depth_m": depth})
    return Soundings(angle, twt, level, geometry, water_column=water, points_m=truth, source="render", tilt_deg=tilt,
                     unit_name=instrument_unit(sensor, sim.scene.render.tvg).name)


def ping_soundings(spec: MultibeamSpec, paths, water_column: np.ndarray, head: Pose):
    """One ping's soundings from its paths and water column (the per-beam work, vectorised).

    Parameters
    ----------
    spec : MultibeamSpec
    paths : FramePaths
        The ping's frame (its first hits give each beam's truth, :func:`footprint_points`).
    water_column : (n_samples, n_beams) float32 array
        The formed column (after the pulse).
    head : Pose
        The head in the world (its frame: x forward, y port, z up).

    Returns
    -------
    water_column : (n_samples, n_beams) float32 ndarray
        On the head's time axis (mapped through the true profile, if any).
    angle_deg, tilt_deg : (n_beams,) float64 ndarrays
        The arrival's angles in the head's frame (the beam table's where a beam sees nothing).
    two_way_time_s, intensity : (n_beams,) float64 ndarrays
        The detection's (NaN: none).
    points_m : (n_beams, 3) float64 ndarray
        The truth, world frame: where the detected echo's energy came from (the beam's first
        hits within the detection window, :func:`footprint_points`); NaN where no ray of the
        window met a surface (a multipath echo).
    """
    c_head = spec.sound_speed_m_s
    dr = (spec.range_max_m - spec.range_min_m) / spec.n_samples
    origin = np.asarray(head.translation, np.float64)
    profile = spec.sound_speed_profile
    d0 = 0.0 if spec.surface_height_m is None else spec.surface_height_m - origin[2]
    bend = profile is not None and spec.refraction == "beam"

    def paths_to(points, normal):
        """One-way time, direction at the head and the truth of each beam's footprint."""
        if bend:
            u = (points - origin) / np.linalg.norm(points - origin, axis=1, keepdims=True)
            truth, t = bent_to_plane(origin, u, points, normal, profile, d0)
            return t, u, truth
        t, u = arrivals(origin, points, c_head, profile, d0)
        return t, u, points

    hits = FrameHits(paths, spec.range_min_m, spec.range_max_m)
    found_all = hits.points(normals=bend)
    points, normal = found_all if bend else (found_all, None)
    wc = water_column
    factor = np.ones(spec.n_beams)
    if profile is not None:
        # The head's time axis: each beam's echo at c_head T instead of the straight |P - O|.
        t_one, _, _ = paths_to(points, normal)
        straight = np.linalg.norm(points - origin, axis=1)
        ok = np.isfinite(t_one) & (straight > 0)
        factor = np.where(ok, c_head * np.where(ok, t_one, 0.0) / np.where(ok, straight, 1.0), 1.0)
        wc = _stretch(wc, factor, spec.range_min_m, dr)
    rng, level, window = detect_bottom(wc, spec.range_min_m, spec.range_max_m, spec.detection_window_db,
                                       DETECTION_SMOOTHING)
    # The truth of what was detected: the first hits within the detection's window (a sample
    # more either side: range splatting and the pulse spread an echo that far), mapped back to
    # straight distances. A beam that detected nothing keeps the truth of all its hits.
    gate = (spec.range_min_m + (window + np.array([[-1], [1]])) * dr) / factor
    gated = hits.points(gate, normals=bend)
    detected = np.isfinite(rng)[:, None]
    if bend:
        points, normal = np.where(detected, gated[0], points), np.where(detected, gated[1], normal)
    else:
        points = np.where(detected, gated, points)
    _, u, truth = paths_to(points, normal)
    a, b = head_angles_deg(u, head.rotation)
    seen = np.isfinite(a) & np.isfinite(b)
    return (wc, np.where(seen, a, spec.beam_table_deg()), np.where(seen, b, 0.0), 2.0 * rng / c_head, level,
            truth)


def _stretch(wc: np.ndarray, factor: np.ndarray, range_min_m: float, dr: float) -> np.ndarray:
    """Each beam's column with its range axis scaled by ``factor`` (an echo at range ``r``
    moves to ``factor r``), linearly interpolated between samples, zero outside the window.

    ``wc``: ``(n_samples, n_beams)``; ``factor``: ``(n_beams,)``. Returns float32.
    """
    n, m = wc.shape
    # Zero rows about the column (one before, two after): every index below lands on a row,
    # those outside the window on a zero one, without masks.
    pad = np.zeros((n + 3, m), np.float32)
    pad[1:n + 1] = wc
    # The fractional source sample of each output sample, (k + 0.5 + r0/dr) / factor - r0/dr - 0.5,
    # in float32 where that resolves a sample to 1/256 (up to 65,536 samples).
    dtype = np.float32 if n <= 65536 else np.float64
    offset = range_min_m / dr + 0.5
    src = (np.arange(n, dtype=dtype) + dtype(offset))[:, None] * (1.0 / np.asarray(factor)).astype(dtype)[None, :]
    src -= dtype(offset)
    np.clip(src, -1.0, float(n), out=src)
    i0 = np.floor(src)
    f = (src - i0).astype(np.float32)
    flat = (i0.astype(np.intp) + 1) * m + np.arange(m)  # row i0 + 1 of pad, flattened
    flat_pad = pad.reshape(-1)
    return (1.0 - f) * flat_pad[flat] + f * flat_pad[flat + m]
