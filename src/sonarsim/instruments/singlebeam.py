"""Single-beam echosounder / altimeter: one conical beam looking down, an envelope per ping.

The transducer is mounted looking down (the mount's pose, then pitch +90 deg: the beam's axis
along the vehicle's -z). Its beam is a cone: a circular piston's two-way power pattern

    G(alpha) = |2 J1(x) / x|^4,   x = k a sin(alpha),

with ``k a`` set so that ``G`` falls to one half (-3 dB two-way) at ``alpha = beam_width_deg /
2`` (``x = 1.616``: ``k a = 1.616 / sin(W / 2)``), or (``pattern: gaussian``) ``G = exp(-ln 2 (2
alpha / W)^2)``. ``alpha`` is the angle from the axis. The rays are cast over the cone out to
:attr:`SinglebeamSpec.cone_half_angle_deg`: the piston's first null (``x = 3.832``: the main lobe;
its first side lobe is -35 dB two-way, left out), or where the gaussian is -30 dB. Beyond it the
rays carry no weight.

On the engine the cone is one frame of an FLS-like fan: :data:`CONE_BEAMS` beams across the cone
(azimuth) times the elevation rays (``render.elevation_samples``), both spanning twice the cone's
half-angle, each ray weighted by ``G`` of its angle from the axis (and zero outside the cone).
The beams' images are summed, each times its width in radians (the rays' weights are per radian
of beam width), into the ping's envelope against range; the sensor chain (TVG, speckle, noise,
counts), if any, acts on that envelope as a one-beam image.

Bottom detection (:func:`detect_bottom`): the near edge of the first sample whose envelope
reaches ``threshold_db`` (default -10 dB) below the ping's own peak; NaN for a ping with no echo.
A threshold relative to the peak finds the leading edge of the strongest echo's rise whatever the
gain; a first return weaker than the threshold (a far, faint edge of the cone) is passed over,
as a device's detector passes over it.

Scene section (``type: singlebeam``)::

    {type: singlebeam, preset: ..., frequency_khz: 200, beam_width_deg: 10, pattern: piston,
     range_min_m: 0, range_max_m: 30, n_samples: 1000, ping_rate_hz: 10, sound_speed_m_s: 1500,
     threshold_db: -10, sensor: {...}}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..config.instruments import Channel, InstrumentSpec, mounted, register
from ..config.sensor import SensorSpec
from ..config.sonar import SonarConfig
from ..core.rays import make_ray_fan
from ..core.streams import frame_rng
from ..core.transforms import Pose
from ..errors import ConfigError, shown
from ..image.films import Envelope
from ..image.units import instrument_unit
from ..sensor.model import SensorModel
from . import renders
from . import ping_geometry, pose_frames
from ._sections import check_range, check_window, parse_section, section_dict

__all__ = ["SinglebeamSpec", "render_singlebeam", "detect_bottom", "cone_gain", "CONE_BEAMS", "PATTERNS"]

#: Beams across the cone (odd: one along the axis); with the elevation rays they sample the cone.
CONE_BEAMS = 15
PATTERNS = ("piston", "gaussian")
#: The piston's first null, ``x = k a sin(alpha)``: the first zero of J1.
PISTON_NULL_X = 3.8317059702075125
#: Where the gaussian cone is cut, dB (two-way).
GAUSSIAN_EDGE_DB = -30.0


@lru_cache(maxsize=None)
def piston_half_power_x() -> float:
    """``x`` at which the two-way piston power ``|2 J1(x) / x|^4`` is one half (1.616)."""
    from scipy import optimize, special

    return float(optimize.brentq(lambda x: (2.0 * special.j1(x) / x) ** 4 - 0.5, 0.1, 3.0))


def cone_gain(alpha_rad: np.ndarray, beam_width_deg: float, pattern: str = "piston") -> np.ndarray:
    """Two-way power gain (1 on axis) at angles ``alpha_rad`` from the beam's axis.

    Parameters
    ----------
    alpha_rad : (...) array
        Angles from the axis, radians, in [0, pi].
    beam_width_deg : float
        The -3 dB (two-way) full width, degrees.
    pattern : {'piston', 'gaussian'}

    Returns
    -------
    (...) float64 ndarray in [0, 1]; 0.5 at ``alpha = beam_width / 2``.
    """
    a = np.asarray(alpha_rad, dtype=np.float64)
    half = math.radians(beam_width_deg) / 2.0
    if pattern == "gaussian":
        return np.exp(-math.log(2.0) * (a / half) ** 2)
    from scipy import special

    x = piston_half_power_x() / math.sin(half) * np.sin(a)
    safe = np.where(np.abs(x) < 1e-8, 1.0, x)
    amp = np.where(np.abs(x) < 1e-8, 1.0, 2.0 * special.j1(safe) / safe)
    return amp ** 4


def detect_bottom(envelope: np.ndarray, range_min_m: float, range_max_m: float, threshold_db: float) -> np.ndarray:
    """The bottom's range per ping: the near edge of the first sample at or above ``threshold_db``
    relative to that ping's peak.

    Parameters
    ----------
    envelope : (n_pings, n_samples) array
    range_min_m, range_max_m : float
    threshold_db : float
        Negative: dB below the peak.

    Returns
    -------
    (n_pings,) float64 ndarray, metres; NaN where a ping has no positive sample.
    """
    e = np.asarray(envelope, dtype=np.float64)
    peak = e.max(axis=1)
    above = e >= (peak * 10.0 ** (threshold_db / 10.0))[:, None]
    k = np.argmax(above, axis=1)
    dr = (range_max_m - range_min_m) / e.shape[1]
    return np.where(peak > 0, range_min_m + k * dr, np.nan)


@register
@dataclass(frozen=True)
class SinglebeamSpec(InstrumentSpec):
    """A single-beam echosounder's (or altimeter's) configuration.

    Attributes
    ----------
    frequency_khz : float
        The carrier, kHz.
    beam_width_deg : float
        The conical beam's -3 dB two-way full width, degrees, in [1, 60].
    pattern : {'piston', 'gaussian'}
        The conical pattern (see the module's notes).
    range_min_m, range_max_m : float
        The range window, metres.
    n_samples : int
        Envelope samples per ping.
    ping_rate_hz : float or None
        Pings per second; default ``sound_speed_m_s / (2 range_max_m)``.
    sound_speed_m_s : float
    threshold_db : float
        The bottom detector's threshold relative to each ping's peak, dB, in [-60, 0).
    sensor : SensorSpec or None
        The sensor chain on the envelope (a one-beam image of ``n_samples`` bins).
    preset : str or None
    """

    type_name: ClassVar[str] = "singlebeam"
    keys: ClassVar[tuple[str, ...]] = (
        "preset", "frequency_khz", "beam_width_deg", "pattern", "range_min_m", "range_max_m", "n_samples",
        "ping_rate_hz", "sound_speed_m_s", "threshold_db", "sensor",
    )

    frequency_khz: float = 200.0
    beam_width_deg: float = 10.0
    pattern: str = "piston"
    range_min_m: float = 0.0
    range_max_m: float = 30.0
    n_samples: int = 1000
    ping_rate_hz: float | None = None
    sound_speed_m_s: float = 1500.0
    threshold_db: float = -10.0
    sensor: SensorSpec | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        check_window(self)
        check_range(self, "beam_width_deg", 1.0, 60.0, lo_open=False)
        if self.pattern not in PATTERNS:
            raise ConfigError("pattern", f"unknown pattern {shown(self.pattern)}; allowed: {', '.join(PATTERNS)}")
        if self.ping_rate_hz is not None:
            check_range(self, "ping_rate_hz", 0.0, 1e3)
        check_range(self, "threshold_db", -60.0, 0.0, lo_open=False)
        if self.threshold_db == 0.0:
            raise ConfigError("threshold_db", "must be below 0 dB (relative to the peak), got 0")

    @property
    def cone_half_angle_deg(self) -> float:
        """How far from the axis the rays reach, degrees: the piston's first null, or the
        gaussian's -30 dB angle (at most 85)."""
        half = math.radians(self.beam_width_deg) / 2.0
        if self.pattern == "gaussian":
            edge = half * math.sqrt(-GAUSSIAN_EDGE_DB / (10.0 * math.log10(2.0)))
        else:
            edge = math.asin(min(1.0, PISTON_NULL_X / piston_half_power_x() * math.sin(half)))
        return min(math.degrees(edge), 85.0)

    def channel_sonar(self) -> SonarConfig:
        """The cone's fan and grid: :data:`CONE_BEAMS` beams and the elevation both spanning the cone."""
        span = 2.0 * self.cone_half_angle_deg
        return SonarConfig.uniform(
            n_beams=CONE_BEAMS, azimuth_fov_deg=span, elevation_fov_deg=span, range_min_m=self.range_min_m,
            range_max_m=self.range_max_m, n_range_bins=self.n_samples, frequency_khz=self.frequency_khz,
        )

    def envelope_sonar(self) -> SonarConfig:
        """The envelope's grid (one beam): what the sensor chain acts on."""
        return SonarConfig.uniform(
            n_beams=1, azimuth_fov_deg=self.beam_width_deg, elevation_fov_deg=self.beam_width_deg,
            range_min_m=self.range_min_m, range_max_m=self.range_max_m, n_range_bins=self.n_samples,
            frequency_khz=self.frequency_khz,
        )

    def make_fan(self, render):
        """The cone's rays: the square fan, each ray weighted by the conical pattern (0 outside)."""
        fan = make_ray_fan(self.channel_sonar(), render)
        alpha = np.arccos(np.clip(fan.directions[..., 0], -1.0, 1.0))  # angle from the axis (x)
        gain = cone_gain(alpha, self.beam_width_deg, self.pattern)
        gain = np.where(alpha <= math.radians(self.cone_half_angle_deg), gain, 0.0)
        return replace(fan, weight=fan.weight * gain)

    def channels(self) -> tuple[Channel, ...]:
        # Looking down: pitch +90 deg turns the channel's x onto the mount's -z.
        return (Channel("beam", self.channel_sonar(), mounted(self.mount, Pose((0.0, 0.0, 0.0), (0.0, 90.0, 0.0)))),)

    def ping_period_s(self) -> float:
        if self.ping_rate_hz:
            return 1.0 / self.ping_rate_hz
        return 2.0 * self.range_max_m / self.sound_speed_m_s

    @classmethod
    def parse(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose) -> "SinglebeamSpec":
        return parse_section(cls, d, key, base_dir, name, mount, integers=("n_samples",),
                             nullable=("ping_rate_hz",), strings=("pattern",))

    def to_dict(self) -> dict:
        return section_dict(self)


# -- rendering ---------------------------------------------------------------------------

_FANS: dict = {}


def _fan(sim, spec: SinglebeamSpec, sonar: SonarConfig):
    """The cone's rays: the square fan, each ray weighted by the conical pattern (0 outside)."""
    key = (sim.scene.render, sonar, spec.beam_width_deg, spec.pattern)
    fan = _FANS.get(key)
    if fan is None:
        sim.require_frame_memory(sonar)
        fan = spec.make_fan(sim.scene.render)
        _FANS.clear()
        _FANS[key] = fan
    return fan


@renders("singlebeam")
def render_singlebeam(sim, spec: SinglebeamSpec, poses: list[Pose], times_s: np.ndarray, first_ping: int,
                      speckle: bool | None, labels: bool) -> Envelope:
    """A single-beam's pings, one per vehicle pose, as an :class:`Envelope` with the detector's
    bottom range per ping.

    Ping ``k`` draws its speckle and noise from ``(render.seed, first_ping + k)``; the draws act
    on the summed envelope (the beam is one receiver). ``labels`` is not supported.
    """
    if labels:
        raise ConfigError("labels", "a single-beam's film has no labels; render with labels=False")
    channel = spec.channels()[0]
    sonar = channel.sonar
    fan = _fan(sim, spec, sonar)
    model = SensorModel(spec.sensor, spec.envelope_sonar(), sim.scene.render.seed) if spec.sensor is not None else None
    n = len(poses)
    from ..core.memory import require

    require(n * spec.n_samples * 4, f"an envelope of {n} pings x {spec.n_samples} samples", "n_pings")
    width = np.radians(sonar.effective_beam_width_deg())  # (CONE_BEAMS,): the rays' weights are per radian
    out = np.empty((n, spec.n_samples), np.float32)
    render = sim.scene.render
    at = [mounted(vehicle, channel.mount) for vehicle in poses]
    nb = sonar.n_beams
    # Many pings go through the engine in one frame (pose_frames): ping j's cone is the
    # columns j nb to (j + 1) nb, summed into its envelope, then drawn from its own frame.
    for start, stop, _, image in pose_frames(sim, at, sonar, fan, times_s=times_s):
        polar = image.polar.astype(np.float64)
        for j, k in enumerate(range(start, stop)):
            env = (polar[:, j * nb:(j + 1) * nb] @ width)[:, None]
            if model is not None or (render.speckle and speckle is not False):
                rng = frame_rng(render.seed, first_ping + k)
                if model is not None:
                    env = model.apply(env, rng, speckle is not False, noise_rng=rng)
                else:
                    env = env * rng.exponential(1.0, env.shape)
            out[k] = np.asarray(env, np.float32)[:, 0]
    bottom = detect_bottom(out, spec.range_min_m, spec.range_max_m, spec.threshold_db)
    # (without a sensor the envelope is the cone's backscatter summed over its width: per bin, not per radian)
    unit = instrument_unit(spec.sensor).name if spec.sensor is not None else "cross_section_per_r2"
    return Envelope(out, spec.range_min_m, spec.range_max_m, bottom, ping_geometry(sim, poses, times_s, spec),
                    unit_name=unit)
