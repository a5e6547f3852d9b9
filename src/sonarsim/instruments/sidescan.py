"""Side-scan sonar: a port and a starboard transducer, slant-range lines stacked into a waterfall.

Each side is one channel of the engine: one beam, narrow along track
(``horizontal_beam_width_deg``), whose rays span the vertical plane across track from nadir up
past the horizontal (the vertical pattern, ``vertical_beam_width_deg`` at -3 dB, tilted
``depression_deg`` below the horizontal, weighs them: a line array's two-way pattern, its side
lobes reaching nadir as a real transducer's do). The channel's axis is the vehicle's +y (port)
or -y (starboard) turned down by the depression; its range bins are the line's samples. So the
water column before the first bottom return is dark, the first return comes at the altitude
(where the pattern reaches nadir), the surface's multipath ghost and objects' shadows come from
the engine's paths as in any frame.

Scene section (``type: sidescan``)::

    {type: sidescan, preset: seascan_hds_600, range_max_m: 30, n_samples: 1024,
     depression_deg: 15, vertical_beam_width_deg: 50, horizontal_beam_width_deg: 0.5,
     frequency_khz: 600, ping_rate_hz: 25, sound_speed_m_s: 1500, sensor: {...}}

Refraction (``sound_speed_profile``: the true water, depth below the surface -> speed, as the
multibeam's; default the scene's ``water.profile``; ``surface_height_m``: where the surface is,
default the head's own height at each ping). The engine casts straight rays, so each side's
line is formed on straight-ray ranges and then mapped onto the device's time axis: the echo at
straight range ``rho`` is taken from the floor under the head at that range (at the ping's
altitude; straight down before the first return) and arrives at the one-way time ``T`` of the
ray through the profile to that point (two-point ray tracing,
:meth:`~sonarsim.instruments.multibeam.SoundSpeedProfile.solve`); the device reports it at
``sound_speed_m_s T``. An object above the floor moves as the floor at its range does (an
approximation: the offset of a target 1 m above a 10 m altitude floor in a 0.5 s^-1 gradient
is millimetres), and each sample keeps its intensity (the stretch, ``c_device / c_water``, is
within 2 % of 1). The straight-ray line is rendered far enough to fill the device's window
where the water is faster than the speed the device ranges with.

Known simplification: the rays of a beam sample azimuth about the channel's own axis, so the
beam's along-track width narrows as ``cos`` of the angle from the axis towards nadir (a line
array's beam is a cone of constant along-track width); it changes the intensity near nadir, not
where anything lies (issue 39, "arrays as built").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..config.instruments import Channel, InstrumentSpec, mounted, register
from ..config.sensor import SensorSpec
from ..config.sonar import SonarConfig
from ..core.transforms import Pose
from ..image.films import Waterfall
from ..image.units import instrument_unit
from ..sensor.model import SensorModel
from . import ping_geometry, pose_frames, renders
from .multibeam import SoundSpeedProfile
from ._sections import LineArrayBeam, check_range, check_window, parse_section, section_dict

__all__ = ["SidescanSpec", "render_sidescan", "floor_shadow", "ping_geometry"]

SIDES = ("port", "starboard")
# The rays reach this far past nadir (degrees): the first return's bin sees both its sides.
NADIR_MARGIN_DEG = 0.5


@register
@dataclass(frozen=True)
class SidescanSpec(LineArrayBeam, InstrumentSpec):
    """A side-scan sonar's configuration (validated here: a frozen configuration).

    Attributes
    ----------
    frequency_khz : float
        The carrier, kHz.
    horizontal_beam_width_deg : float
        Along-track -3 dB width, degrees, in (0.01, 20].
    vertical_beam_width_deg : float
        Across-track -3 dB width of the two-way vertical pattern, degrees, in (1, 120].
    depression_deg : float
        The beam axis below the horizontal, degrees, in [1, 60].
    range_min_m, range_max_m : float
        The slant-range window, metres.
    n_samples : int
        Samples per side per ping.
    ping_rate_hz : float or None
        Pings per second; default ``sound_speed_m_s / (2 range_max_m)`` (the next ping leaves
        when the last echo is in).
    sound_speed_m_s : float
        The speed the device ranges with (the ping rate's default).
    sensor : SensorSpec or None
        The sensor chain on the waterfall (TVG, speckle, noise, counts): each side's line is a
        one-beam image of ``n_samples`` range bins.
    sound_speed_profile : SoundSpeedProfile or None
        The true water (scene files: ``[[depth_m, speed_m_s], ...]``; default the scene's
        ``water.profile``); None: straight rays, ranges as the engine's.
    surface_height_m : float or None
        The world height of the water's surface (the profile counts depth from it); None: at
        the head every ping.
    preset : str or None
    """

    type_name: ClassVar[str] = "sidescan"
    keys: ClassVar[tuple[str, ...]] = (
        "preset", "frequency_khz", "horizontal_beam_width_deg", "vertical_beam_width_deg", "depression_deg",
        "range_min_m", "range_max_m", "n_samples", "ping_rate_hz", "sound_speed_m_s", "sensor",
        "sound_speed_profile", "surface_height_m",
    )

    frequency_khz: float = 600.0
    horizontal_beam_width_deg: float = 0.5
    vertical_beam_width_deg: float = 50.0
    depression_deg: float = 15.0
    range_min_m: float = 0.0
    range_max_m: float = 30.0
    n_samples: int = 1024
    ping_rate_hz: float | None = None
    sound_speed_m_s: float = 1500.0
    sensor: SensorSpec | None = None
    sound_speed_profile: SoundSpeedProfile | None = None
    surface_height_m: float | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        if self.sound_speed_profile is not None and not isinstance(self.sound_speed_profile, SoundSpeedProfile):
            object.__setattr__(self, "sound_speed_profile",
                               SoundSpeedProfile.parse(self.sound_speed_profile, "sound_speed_profile"))
        if self.surface_height_m is not None:
            check_range(self, "surface_height_m", -1e5, 1e5)
        check_window(self)
        check_range(self, "horizontal_beam_width_deg", 0.01, 20.0)
        check_range(self, "vertical_beam_width_deg", 1.0, 120.0)
        check_range(self, "depression_deg", 1.0, 60.0, lo_open=False)
        if self.ping_rate_hz is not None:
            check_range(self, "ping_rate_hz", 0.0, 1e3)

    # -- geometry --------------------------------------------------------------------------

    @property
    def half_span_deg(self) -> float:
        """Half the rays' elevation span about the axis: from the axis down to nadir, and as far up."""
        return 90.0 - self.depression_deg + NADIR_MARGIN_DEG

    def channel_sonar(self) -> SonarConfig:
        """Each side's fan and grid: one beam, ``n_samples`` range bins."""
        return SonarConfig.uniform(
            n_beams=1, azimuth_fov_deg=self.horizontal_beam_width_deg, elevation_fov_deg=2.0 * self.half_span_deg,
            range_min_m=self.range_min_m, range_max_m=self.range_max_m, n_range_bins=self.n_samples,
            frequency_khz=self.frequency_khz,
            # its own width (a lone beam's grid is 1 degree wide): the rays across it span it
            beam_width_deg=self.horizontal_beam_width_deg,
        )

    def channels(self) -> tuple[Channel, ...]:
        sonar = self.channel_sonar()
        # Turned to its side (yaw +-90 deg: the channel's x along the vehicle's +-y), then
        # down by the depression (pitch > 0 looks down): R = Rz(yaw) Ry(pitch).
        return tuple(Channel(side, sonar, mounted(self.mount, Pose((0.0, 0.0, 0.0), (0.0, self.depression_deg, yaw))))
                     for side, yaw in zip(SIDES, (90.0, -90.0)))

    def ping_period_s(self) -> float:
        if self.ping_rate_hz:
            return 1.0 / self.ping_rate_hz
        return 2.0 * self.range_max_m / self.sound_speed_m_s

    # -- files -----------------------------------------------------------------------------

    def traced_sonar(self) -> SonarConfig:
        """The grid each side's straight-ray line is rendered on: the channel's, its window
        reaching as far as the profile's fastest water sends the device's last sample."""
        sonar = self.channel_sonar()
        if self.sound_speed_profile is None:
            return sonar
        speeds = self.sound_speed_profile.speed_m_s
        low = min(1.0, min(speeds) / self.sound_speed_m_s)  # slower water: the device's first samples are nearer
        high = max(1.0, max(speeds) / self.sound_speed_m_s)  # faster: its last ones farther
        if low == 1.0 and high == 1.0:
            return sonar
        dr = sonar.range_resolution_m
        r0 = max(self.range_min_m * low - dr, 0.0)
        n = int(math.ceil((self.range_max_m * high - r0) / dr)) + 1
        return SonarConfig.uniform(
            n_beams=1, azimuth_fov_deg=self.horizontal_beam_width_deg, elevation_fov_deg=2.0 * self.half_span_deg,
            range_min_m=r0, range_max_m=r0 + n * dr, n_range_bins=n, frequency_khz=self.frequency_khz,
            beam_width_deg=self.horizontal_beam_width_deg,
        )

    # -- files -----------------------------------------------------------------------------

    @classmethod
    def parse(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose) -> "SidescanSpec":
        def convert(k: str, v: Any, where: str) -> Any:
            if v is None and k in ("sound_speed_profile", "surface_height_m"):
                return None
            if k == "sound_speed_profile":
                return SoundSpeedProfile.parse(v, where)
            return NotImplemented

        return parse_section(cls, d, key, base_dir, name, mount, integers=("n_samples",), nullable=("ping_rate_hz",),
                             convert=convert)

    def to_dict(self) -> dict:
        return section_dict(self, lambda v: v.to_list() if isinstance(v, SoundSpeedProfile) else v)


# -- rendering ---------------------------------------------------------------------------

_FANS: dict = {}  # (render settings, spec's channel grid and pattern) -> RayFan: shared by every ping


def _fan(sim, spec: SidescanSpec, sonar: SonarConfig):
    key = (sim.scene.render, sonar, spec.vertical_beam_width_deg)
    fan = _FANS.get(key)
    if fan is None:
        sim.require_frame_memory(sonar)
        fan = spec.make_fan(sim.scene.render)
        _FANS.clear()  # one side-scan at a time is the common case: keep memory flat
        _FANS[key] = fan
    return fan


def floor_shadow(paths, sim, objects_image: np.ndarray | None = None) -> np.ndarray:
    """Samples of a line where the floor is in the beam but hidden behind an object.

    A ray whose first surface is an object, and which would have met the ground plane farther
    on, shadows the ground at that farther range; a sample is shadow where such rays land, no
    ray sees the ground directly and no object echoes (``objects_image``: the frame's direct
    echo of the objects). Neighbouring rays of a ray column that are both hidden (or both on
    the ground) cover the samples between their ranges, as range splatting covers an echo.

    Returns
    -------
    (n_range_bins, n_beams) bool ndarray
    """
    sonar = paths.sonar
    shape = (sonar.n_range_bins, sonar.n_beams)
    ground = sim.scene.ground
    if ground is None:
        return np.zeros(shape, bool)
    distance, sid, _ = paths.first_hits()
    origin, d = paths.world_rays()  # world frame, fan.shape + (3,)
    dz = d[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(dz < 0, (ground.height_m - origin[..., 2]) / dz, np.inf)
    n_planes = len(sim.planes)
    beams = np.broadcast_to(np.arange(sonar.n_beams)[:, None, None], sid.shape)
    dr = sonar.range_resolution_m

    def covered(t: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Samples at the ranges ``t`` of the masked rays and between masked neighbours."""
        k = np.floor((np.where(mask, t, np.nan) - sonar.range_min_m) / dr)
        lo = np.concatenate([k, np.fmin(k[..., :-1], k[..., 1:])], axis=-1)
        hi = np.concatenate([k, np.fmax(k[..., :-1], k[..., 1:])], axis=-1)
        pair = np.concatenate([mask, mask[..., :-1] & mask[..., 1:]], axis=-1)
        b = np.concatenate([beams, beams[..., :-1]], axis=-1)
        keep = pair & np.isfinite(lo) & (hi >= 0) & (lo < sonar.n_range_bins)
        lo = np.clip(lo[keep], 0, sonar.n_range_bins - 1).astype(np.int64)
        hi = np.clip(hi[keep], 0, sonar.n_range_bins - 1).astype(np.int64)
        marks = np.zeros((sonar.n_range_bins + 1, sonar.n_beams), np.int64)
        np.add.at(marks, (lo, b[keep]), 1)
        np.add.at(marks, (hi + 1, b[keep]), -1)
        return np.cumsum(marks, axis=0)[:-1] > 0

    on_object = sid >= n_planes
    hidden = on_object & np.isfinite(t_ground) & (t_ground > distance)
    lit = sid == 0  # the ground is plane 0
    shadow = covered(t_ground, hidden) & ~covered(distance, lit)
    if objects_image is not None:  # an object's own echo is no shadow (the floor beneath it is hidden too)
        shadow &= ~(objects_image > 0)
    return shadow


@renders("sidescan")
def render_sidescan(sim, spec: SidescanSpec, poses: list[Pose], times_s: np.ndarray, first_ping: int,
                    speckle: bool | None, labels: bool) -> Waterfall:
    """A side-scan's pings, one per vehicle pose, stacked into a :class:`Waterfall`.

    Each side of each ping is one frame of the engine (:meth:`Simulator.trace`,
    :meth:`Simulator.form`) at the channel's pose; ping ``k``'s side ``s`` draws its speckle and
    noise from ``(render.seed, 2 (first_ping + k) + s)``. With ``labels``, the waterfall's
    ``labels`` hold per sample ``instance`` (int32: the id of :attr:`Waterfall.ids` bringing the
    most energy, -1 none) and ``shadow`` (bool: the floor hidden behind an object), and
    ``boxes`` per object id and side ``[ping_min, sample_min, ping_max, sample_max]``.
    """
    channels = spec.channels()
    sonar = channels[0].sonar
    traced = spec.traced_sonar()  # the straight-ray lines' grid (the device's, or longer)
    fan = _fan(sim, spec, sonar)
    model = SensorModel(spec.sensor, sonar, sim.scene.render.seed) if spec.sensor is not None else False
    n = len(poses)
    from ..core.memory import require

    require(n * 2 * spec.n_samples * 4 * (3 if labels else 1), f"a waterfall of {n} pings x 2 x {spec.n_samples}",
            "n_pings")
    out = np.empty((n, 2, spec.n_samples), np.float32)
    instance = np.full((n, 2, spec.n_samples), -1, np.int32) if labels else None
    shadow = np.zeros((n, 2, spec.n_samples), bool) if labels else None
    # Ping k's side s is the frame 2 k + s, its pose the vehicle's at the ping, mounted: many
    # of them go through the engine in one frame (pose_frames), each side's line a column.
    at = [mounted(vehicle, channel.mount) for vehicle in poses for channel in channels]
    model = model or None
    refracts = spec.sound_speed_profile is not None
    at_times = np.repeat(np.asarray(times_s, np.float64), len(channels))  # one per line, as ``at``
    for start, stop, paths, image in pose_frames(sim, at, traced, fan, labels="total" if labels else False,
                                                 times_s=at_times):
        lines = image.components["total"]
        source = None
        if refracts:  # the straight-ray lines onto the device's time axis (the batch's frames: memory flat)
            source = refraction_map(spec, sim, at[start:stop], traced.range_m, sonar.range_m)
            lines = refract_lines(lines, traced.range_m, source)
        flat = out.reshape(2 * n, spec.n_samples)  # frame f = 2 k + s is row f
        if model is None and not (sim.scene.render.speckle and speckle is not False):
            flat[start:stop] = lines.T  # no sensor, no draws: the expected lines as they are
        else:
            for j, f in enumerate(range(start, stop)):
                flat[f] = sim.sense(lines[:, j:j + 1], at[f], 2 * first_ping + f, speckle, model)[:, 0]
        if labels:
            inst = image.labels.instance["total"]
            hidden = floor_shadow(paths, sim, image.components.get("object"))
            if source is not None:
                inst, hidden = (refract_lines(x, traced.range_m, source, nearest=True) for x in (inst, hidden))
            instance.reshape(2 * n, -1)[start:stop] = inst.T
            shadow.reshape(2 * n, -1)[start:stop] = hidden.T
    extra: dict = {}
    if labels:
        ids = tuple(o.name for o in sim.scene.objects) + tuple(p.name for p in sim.scene.reflecting_planes)
        extra = {"labels": {"instance": instance, "shadow": shadow, "boxes": waterfall_boxes(instance, len(ids))},
                 "ids": ids}
    return Waterfall(out, spec.range_min_m, spec.range_max_m, ping_geometry(sim, poses, times_s, spec),
                     source="render", unit_name=instrument_unit(spec.sensor, sim.scene.render.tvg).name, **extra)


def refraction_map(spec: SidescanSpec, sim, heads: list[Pose], straight_m: np.ndarray,
                   device_m: np.ndarray) -> np.ndarray:
    """Where each of the device's samples finds its echo on the straight-ray line, per frame.

    The echo at straight range ``rho`` comes from the floor under the head (at the ping's
    altitude above the scene's ground; straight down before the first return, and along the
    beam's axis where there is no ground) and arrives after the one-way time ``T(rho)`` of the
    ray through the true profile to that point; the device reports it at ``c T``, c its
    ``sound_speed_m_s``. ``T`` grows with ``rho``: the device's sample at ``R`` holds the
    straight-ray line's echo at ``T^-1(R / c)``.

    Parameters
    ----------
    spec : SidescanSpec
        With its ``sound_speed_profile``.
    sim : Simulator
        The scene (its ground).
    heads : list of Pose
        Each frame's channel pose, world frame.
    straight_m : (m,) float array
        The straight-ray line's sample centres, metres.
    device_m : (n,) float array
        The device's sample centres, metres (``c t / 2``).

    Returns
    -------
    (len(heads), n) float64 ndarray
        The straight range (metres) each device sample reads; NaN beyond the line's ends (a
        shadow zone inside the line, where no ray reaches a range, is bridged between its edges).
    """
    profile = spec.sound_speed_profile
    z = np.array([h.translation[2] for h in heads], np.float64)
    depth = (spec.surface_height_m - z) if spec.surface_height_m is not None else np.zeros_like(z)
    ground = sim.scene.ground
    rho = np.asarray(straight_m, np.float64)[None, :]
    if ground is not None:
        altitude = np.maximum(z - ground.height_m, 0.0)[:, None]
        down = np.minimum(rho, altitude)  # to the floor, or straight down in the water before it
        across = np.sqrt(np.maximum(rho * rho - altitude * altitude, 0.0))
    else:
        dip = math.radians(spec.depression_deg)
        down, across = rho * math.sin(dip), rho * math.cos(dip) + 0.0 * depth[:, None]
    _, t = profile.solve(depth[:, None] + 0.0 * rho, depth[:, None] + down, across)
    reported = spec.sound_speed_m_s * t  # (frames, m): where the device puts each straight range
    out = np.full((len(heads), len(device_m)), np.nan)
    for f in range(len(heads)):  # per frame: one interpolation over its samples
        ok = np.isfinite(reported[f])
        if ok.sum() >= 2:
            at = reported[f, ok]
            out[f] = np.interp(device_m, at, rho[0, ok])
            # beyond the line's ends (by more than rounding): nothing reaches those samples
            slack = 1e-9 * max(1.0, float(np.abs(at).max()))
            out[f, (device_m < at[0] - slack) | (device_m > at[-1] + slack)] = np.nan
    return out


def refract_lines(lines: np.ndarray, straight_m: np.ndarray, source_m: np.ndarray, nearest: bool = False) -> np.ndarray:
    """The straight-ray lines ``(m, frames)`` read at the straight ranges ``source_m`` ``(frames, n)``
    (:func:`refraction_map`): ``(n, frames)``, linear between samples (``nearest``: the nearest
    sample, for labels); 0 (or the lines' empty value) where ``source_m`` is NaN."""
    lines = np.asarray(lines)
    r0, dr = float(straight_m[0]), float(straight_m[1] - straight_m[0]) if len(straight_m) > 1 else 1.0
    pos = (source_m.T - r0) / dr  # (n, frames), in samples of the line
    ok = np.isfinite(pos) & (pos >= -0.5) & (pos <= lines.shape[0] - 0.5)
    cols = np.broadcast_to(np.arange(lines.shape[1])[None, :], pos.shape)
    empty = -1 if lines.dtype.kind == "i" else 0
    if nearest:
        i = np.clip(np.rint(np.where(ok, pos, 0.0)).astype(np.int64), 0, lines.shape[0] - 1)
        return np.where(ok, lines[i, cols], np.asarray(empty, lines.dtype)).astype(lines.dtype)
    p = np.clip(np.where(ok, pos, 0.0), 0.0, lines.shape[0] - 1)
    i0 = np.floor(p).astype(np.int64)
    i1 = np.minimum(i0 + 1, lines.shape[0] - 1)
    w = (p - i0).astype(np.float32)
    value = lines[i0, cols] * (1.0 - w) + lines[i1, cols] * w
    return np.where(ok, value, 0.0).astype(lines.dtype)


def waterfall_boxes(instance: np.ndarray, n_ids: int) -> np.ndarray:
    """Per id and side, ``[ping_min, sample_min, ping_max, sample_max]`` (inclusive) of the
    samples the id dominates; -1 where it dominates none. ``(n_ids, 2, 4)`` int32."""
    boxes = np.full((n_ids, 2, 4), -1, np.int32)
    for side in range(2):
        ping, sample = np.nonzero(instance[:, side] >= 0)
        ids = instance[:, side][ping, sample]
        for i in np.unique(ids):  # per id present (few), each a NumPy reduction
            m = ids == i
            boxes[i, side] = (ping[m].min(), sample[m].min(), ping[m].max(), sample[m].max())
    return boxes
