"""Mechanical scanning sonar (Ping360, Tritech Micron): one beam stepped in azimuth, a ping per step.

The head carries one transducer: a beam narrow in azimuth (``horizontal_beam_width_deg``, Ping360
2 deg) and wide in elevation (``vertical_beam_width_deg``, Ping360 25 deg), its axis
``tilt_deg`` below the horizontal. A motor steps the head about the mount's z axis; step ``i``
points at head angle ``i * 360 / steps_per_turn`` degrees (a sector scan sweeps back and forth,
see :meth:`ScanningSpec.head_steps`). Head angles follow REP-103 yaw: 0 along the mount's x
(forward), increasing counter-clockwise seen from above, so +90 deg looks to port.

Each step is one ping at its own time, one engine frame (:meth:`Simulator.trace`,
:meth:`Simulator.form`) at the vehicle's pose at that time: with a trajectory the vehicle moves
between steps, so a full turn of a moving vehicle is smeared as a real scan is. Step ``k``
(counted from the scan's first step) draws its speckle and noise from ``(render.seed, k)``.

The step period is the two-way travel time of the range window plus ``step_overhead_s``::

    period = 2 range_max_m / sound_speed_m_s + step_overhead_s

The device's protocol (Blue Robotics ping-protocol, ``ping360`` messages) gives the acoustic
part: a transmit of 1-1000 us, ``number_of_samples`` (200-1200) samples at ``sample_period`` (25 ns
ticks, 2-1000 us), so the listening time is ``n_samples * sample_period`` = the window's two-way
time; its ``auto_transmit`` adds an optional ``delay`` (0-100 ms) between transmits. What the motor
step and the data upload take is not documented there: ``step_overhead_s`` is that time,
inferred (default 0: the acoustic limit; set it from a device's measured turn time).

Scene section (``type: scanning``)::

    {type: scanning, preset: ping360, frequency_khz: 750, horizontal_beam_width_deg: 2,
     vertical_beam_width_deg: 25, tilt_deg: 0, steps_per_turn: 400, step: 1, sector_deg: 360,
     range_min_m: 0.5, range_max_m: 20, n_samples: 1200, sound_speed_m_s: 1500,
     step_overhead_s: 0.0, sensor: {...}}

Render a scan with :func:`sonarsim.instruments.render_pings` (``n_pings``: the steps; a turn is
:meth:`ScanningSpec.steps_per_scan`); the film is a :class:`ScanImage`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from ..config.instruments import Channel, InstrumentSpec, mounted, register
from ..config.sensor import SensorSpec
from ..config.sonar import SonarConfig
from ..core.transforms import Pose
from ..errors import ConfigError
from ..image.films import PingGeometry, range_axis
from ..image.units import UNITS, check_unit, instrument_unit
from ..sensor.model import SensorModel
from ..sensor.patterns import half_power_u
from ._sections import LineArrayBeam, check_integer, check_range, check_window, parse_section, section_dict  # noqa: F401 (re-exported)
from . import ping_geometry, pose_frames, renders

step_geometry = ping_geometry  # (its name here before: one home now, instruments.ping_geometry)

__all__ = ["ScanningSpec", "ScanImage", "render_scanning", "parse_section", "check_range", "step_geometry"]

#: The rays' elevation span stops this far short of straight up and down (degrees): a line
#: array's pattern is symmetric about its plane, and the poles add rays that see nothing new.
POLE_MARGIN_DEG = 5.0


@register
@dataclass(frozen=True)
class ScanningSpec(LineArrayBeam, InstrumentSpec):
    """A mechanical scanning sonar's configuration (validated here: a frozen configuration).

    Attributes
    ----------
    frequency_khz : float
        The carrier, kHz (Ping360: 750).
    horizontal_beam_width_deg : float
        Azimuth -3 dB width, degrees, in (0.01, 30] (Ping360: 2).
    vertical_beam_width_deg : float
        Elevation -3 dB width of the two-way vertical pattern, degrees, in (1, 120] (Ping360: 25).
    tilt_deg : float
        The beam axis below the head's horizontal plane, degrees, in [-90, 90] (default 0).
    steps_per_turn : int
        Motor steps in a full turn, in [4, 100000] (Ping360: 400, one gradian each).
    step : int
        Steps the head advances per ping, in [1, steps_per_turn / 2] (Ping360's ``num_steps``: 1-10).
    sector_deg : float
        The swept sector, degrees, in (0, 360]: 360 turns round and round; less sweeps back and
        forth over ``[-sector / 2, +sector / 2]`` about the mount's forward axis.
    range_min_m, range_max_m : float
        The range window, metres.
    n_samples : int
        Samples per step (Ping360: 200-1200).
    sound_speed_m_s : float
        The speed the device ranges with (and its step period's).
    step_overhead_s : float
        Seconds each step takes beyond the two-way travel time (motor, upload), in [0, 10];
        inferred, not from a datasheet (see the module's notes).
    sensor : SensorSpec or None
        The sensor chain on each step's line (a one-beam image of ``n_samples`` range bins).
    preset : str or None
    """

    type_name: ClassVar[str] = "scanning"
    keys: ClassVar[tuple[str, ...]] = (
        "preset", "frequency_khz", "horizontal_beam_width_deg", "vertical_beam_width_deg", "tilt_deg",
        "steps_per_turn", "step", "sector_deg", "range_min_m", "range_max_m", "n_samples", "sound_speed_m_s",
        "step_overhead_s", "sensor",
    )

    frequency_khz: float = 750.0
    horizontal_beam_width_deg: float = 2.0
    vertical_beam_width_deg: float = 25.0
    tilt_deg: float = 0.0
    steps_per_turn: int = 400
    step: int = 1
    sector_deg: float = 360.0
    range_min_m: float = 0.0
    range_max_m: float = 20.0
    n_samples: int = 1200
    sound_speed_m_s: float = 1500.0
    step_overhead_s: float = 0.0
    sensor: SensorSpec | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        check_window(self)
        check_range(self, "horizontal_beam_width_deg", 0.01, 30.0)
        check_range(self, "vertical_beam_width_deg", 1.0, 120.0)
        check_range(self, "tilt_deg", -90.0, 90.0, lo_open=False)
        check_integer(self, "steps_per_turn", 4, 100_000)
        check_integer(self, "step", 1, self.steps_per_turn // 2)
        check_range(self, "sector_deg", 0.0, 360.0)
        check_range(self, "step_overhead_s", 0.0, 10.0, lo_open=False)
        if self.sector_deg < 360.0 and self.sector_steps < 2 * self.step:
            raise ConfigError("sector_deg", f"must span at least two pings ({2 * self.step} steps of "
                              f"{self.step_deg:g} deg), got {self.sector_deg:g}")

    # -- the head's steps ------------------------------------------------------------------

    @property
    def step_deg(self) -> float:
        """One motor step, degrees (Ping360: 0.9)."""
        return 360.0 / self.steps_per_turn

    @property
    def sector_steps(self) -> int:
        """The sector's length in motor steps (even: symmetric about forward)."""
        return 2 * int(math.floor(self.sector_deg / 2.0 / self.step_deg + 1e-9))

    def steps_per_scan(self) -> int:
        """Pings in one full image: a turn (``steps_per_turn / step``, rounded up), or one sweep
        of the sector one way (``sector_steps / step + 1``)."""
        if self.sector_deg >= 360.0:
            return -(-self.steps_per_turn // self.step)
        return self.sector_steps // self.step + 1

    def head_steps(self, pings: np.ndarray) -> np.ndarray:
        """The head's position, in motor steps, at each ping.

        A full turn: ``(k * step) mod steps_per_turn``. A sector of ``L`` steps sweeps from
        ``-L/2`` to ``+L/2`` and back, reflecting at its ends: ``-L/2 + tri(k * step)`` with
        ``tri(u) = u mod 2L`` folded about ``L``.

        Parameters
        ----------
        pings : (n,) int array
            Ping indices from the scan's first.

        Returns
        -------
        (n,) int64 ndarray, in ``[0, steps_per_turn)`` for a turn, ``[-L/2, L/2]`` for a sector.
        """
        u = np.asarray(pings, np.int64) * self.step
        if self.sector_deg >= 360.0:
            return np.mod(u, self.steps_per_turn)
        length = self.sector_steps
        q = np.mod(u, 2 * length)
        return -length // 2 + np.where(q <= length, q, 2 * length - q)

    def head_angles_deg(self, pings: np.ndarray) -> np.ndarray:
        """The head angle at each ping, degrees (REP-103 yaw about the mount's z; 0 forward,
        > 0 to port), ``(n,)`` float64, in ``[0, 360)`` for a turn."""
        return self.head_steps(pings) * self.step_deg

    # -- the beam --------------------------------------------------------------------------

    @property
    def half_span_deg(self) -> float:
        """Half the rays' elevation span: to the vertical pattern's second null (the first side
        lobes' outer edge), at most ``90 - POLE_MARGIN_DEG``."""
        u3 = half_power_u("rect", None, 2)
        scale = u3 / math.sin(math.radians(self.vertical_beam_width_deg) / 2.0)  # L / lambda
        return min(math.degrees(math.asin(min(1.0, 2.0 / scale))), 90.0 - POLE_MARGIN_DEG)

    def channel_sonar(self) -> SonarConfig:
        """The head's fan and grid: one beam, ``n_samples`` range bins."""
        return SonarConfig.uniform(
            n_beams=1, azimuth_fov_deg=self.horizontal_beam_width_deg, elevation_fov_deg=2.0 * self.half_span_deg,
            range_min_m=self.range_min_m, range_max_m=self.range_max_m, n_range_bins=self.n_samples,
            frequency_khz=self.frequency_khz,
            # its own width (a lone beam's grid is 1 degree wide): the rays across it span it
            beam_width_deg=self.horizontal_beam_width_deg,
        )

    def step_mount(self, angle_deg: float) -> Pose:
        """The beam's pose on the vehicle at head angle ``angle_deg``: the mount, turned by the
        head angle about its z, then down by the tilt (``R = Rz(angle) Ry(tilt)``)."""
        return mounted(self.mount, Pose((0.0, 0.0, 0.0), (0.0, self.tilt_deg, float(angle_deg))))

    def channels(self) -> tuple[Channel, ...]:
        """The head at angle 0 (every step's fan is this one, turned)."""
        return (Channel("head", self.channel_sonar(), self.step_mount(0.0)),)

    def ping_period_s(self) -> float:
        """Seconds per step: the window's two-way travel time plus ``step_overhead_s``."""
        return 2.0 * self.range_max_m / self.sound_speed_m_s + self.step_overhead_s

    def turn_time_s(self) -> float:
        """Seconds the device takes for :meth:`steps_per_scan` steps."""
        return self.steps_per_scan() * self.ping_period_s()

    # -- files -----------------------------------------------------------------------------

    @classmethod
    def parse(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose) -> "ScanningSpec":
        return parse_section(cls, d, key, base_dir, name, mount, integers=("n_samples", "steps_per_turn", "step"))

    def to_dict(self) -> dict:
        return section_dict(self)


@dataclass(frozen=True)
class ScanImage:
    """A scanning sonar's steps: per step one range line, its head angle, time and geometry.

    Attributes
    ----------
    samples : (n_samples, n_steps) float32 ndarray
        Column ``i`` is step ``i``'s line; row 0 the nearest range sample.
    angle_deg : (n_steps,) float64 ndarray
        Each step's head angle, degrees (REP-103 yaw in the mount's frame: 0 forward, > 0 to port).
    range_min_m, range_max_m : float
        The range window, metres.
    geometry : PingGeometry
        One entry per step (``time_s``: the step's time).
    step_deg : float
        The angle between neighbouring steps (motor step times ``step``), degrees.
    source : str
    labels : dict or None
        Renders with labels: ``instance`` (int32 ``(n_samples, n_steps)``, ids of :attr:`ids`, -1 none).
    ids : tuple of str
        Names of the label ids: the scene's objects in order, then its reflecting planes.
    unit_name : str
        What :attr:`samples` are (:mod:`sonarsim.image.units`; :attr:`unit`): a render's
        :func:`~sonarsim.image.units.instrument_unit`, a recording's ``counts``.
    """

    samples: np.ndarray
    angle_deg: np.ndarray
    range_min_m: float
    range_max_m: float
    geometry: PingGeometry
    step_deg: float
    source: str = "render"
    labels: dict | None = None
    ids: tuple = ()
    unit_name: str = "counts"

    @property
    def unit(self):
        """What :attr:`samples` are (:mod:`sonarsim.image.units`)."""
        return UNITS[self.unit_name]

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array, by name (``geometry/<field>`` for the steps' geometry)."""
        from ..image.films import film_arrays

        out = film_arrays({"samples": self.samples, "angle_deg": self.angle_deg}, self.geometry)
        out.update({f"labels/{k}": v for k, v in (self.labels or {}).items()})
        out["unit"] = np.array(self.unit_name)
        return out

    def save_npz(self, path) -> None:
        """Write :meth:`arrays` to an NPZ file, atomically."""
        from ..image.display import hook

        hook("write_npz", "ScanImage.save_npz")(path, self.arrays(), {"film": "scan", "source": self.source,
                                                                       "range_min_m": self.range_min_m,
                                                                       "range_max_m": self.range_max_m,
                                                                       "step_deg": self.step_deg,
                                                                       "unit": self.unit_name})

    def __post_init__(self) -> None:
        check_unit(self.unit_name, "ScanImage")
        s = np.asarray(self.samples)
        if s.ndim != 2:
            raise ValueError(f"ScanImage.samples must be (n_samples, n_steps), got {s.shape}")
        if np.shape(self.angle_deg) != (s.shape[1],) or len(self.geometry) != s.shape[1]:
            raise ValueError(f"ScanImage has {s.shape[1]} steps but {np.shape(self.angle_deg)} angles and "
                             f"geometry for {len(self.geometry)}")

    @property
    def n_steps(self) -> int:
        return self.samples.shape[1]

    @property
    def n_samples(self) -> int:
        return self.samples.shape[0]

    @property
    def times_s(self) -> np.ndarray:
        """Each step's time, seconds, ``(n_steps,)``."""
        return self.geometry.time_s

    @property
    def range_m(self) -> np.ndarray:
        """Centre of each sample, metres, ``(n_samples,)``."""
        return range_axis(self.range_min_m, self.range_max_m, self.n_samples)

    def cartesian(self, size_px: int = 512) -> np.ndarray:
        """The scan as a top view: the head at the centre, forward up, port left.

        Pixel ``(row, col)`` of a ``size_px`` square spanning ``2 range_max_m`` lies at
        ``x = (size_px / 2 - row - 0.5) p`` forward and ``y = (size_px / 2 - col - 0.5) p`` to
        port (``p = 2 range_max_m / size_px``); it takes the sample at its range of the step
        nearest its angle ``atan2(y, x)`` (the latest such step where several share an angle:
        a second turn overwrites the first, as a display does). Pixels outside the window, or
        farther than half a step's angle from every step (outside a sector), are 0.

        Returns
        -------
        (size_px, size_px) float32 ndarray
        """
        from ..core.memory import require

        if isinstance(size_px, bool) or not isinstance(size_px, (int, np.integer)) or not 2 <= size_px <= 16384:
            raise ValueError(f"size_px must be an integer in [2, 16384], got {size_px!r}")
        require(int(size_px) ** 2 * 8 * 6, f"a {size_px} x {size_px} Cartesian scan image", "size_px")
        n = int(size_px)
        p = 2.0 * self.range_max_m / n
        c = n / 2.0 - np.arange(n) - 0.5
        x, y = c[:, None] * p, c[None, :] * p  # forward (rows, up), port (columns, left)
        r = np.hypot(x, y)
        theta = np.mod(np.degrees(np.arctan2(y, x)), 360.0)
        # The latest step per distinct angle, sorted by angle.
        a = np.mod(np.asarray(self.angle_deg, np.float64), 360.0)
        order = np.arange(self.n_steps)[::-1]  # latest first: np.unique keeps each angle's first
        ang, first = np.unique(np.round(a[order], 9), return_index=True)
        steps = order[first]
        # Nearest angle with wrap-around: the neighbours either side in the sorted table.
        ext = np.concatenate([ang - 360.0, ang, ang + 360.0])
        ext_steps = np.concatenate([steps, steps, steps])
        hi = np.clip(np.searchsorted(ext, theta), 1, len(ext) - 1)
        lo = hi - 1
        pick_hi = (ext[hi] - theta) < (theta - ext[lo])
        nearest = np.where(pick_hi, hi, lo)
        gap = np.abs(ext[nearest] - theta)
        step_index = ext_steps[nearest]
        dr = (self.range_max_m - self.range_min_m) / self.n_samples
        k = np.floor((r - self.range_min_m) / dr).astype(np.int64)
        inside = (k >= 0) & (k < self.n_samples) & (gap <= self.step_deg / 2.0 + 1e-9)
        out = np.zeros((n, n), np.float32)
        out[inside] = self.samples[k[inside], step_index[inside]]
        return out


# -- rendering ---------------------------------------------------------------------------

_FANS: dict = {}  # (render settings, grid, vertical width) -> RayFan: shared by every step


def _fan(sim, spec: ScanningSpec, sonar: SonarConfig):
    key = (sim.scene.render, sonar, spec.vertical_beam_width_deg)
    fan = _FANS.get(key)
    if fan is None:
        sim.require_frame_memory(sonar)
        fan = spec.make_fan(sim.scene.render)
        _FANS.clear()  # one scanning sonar at a time is the common case: keep memory flat
        _FANS[key] = fan
    return fan


@renders("scanning")
def render_scanning(sim, spec: ScanningSpec, poses: list[Pose], times_s: np.ndarray, first_ping: int,
                    speckle: bool | None, labels: bool) -> ScanImage:
    """A scanning sonar's steps, one per vehicle pose (each at its own time), as a :class:`ScanImage`.

    Step ``k`` of the call is scan step ``first_ping + k``: its head angle is
    :meth:`ScanningSpec.head_angles_deg` of that index, its draws come from ``(render.seed,
    first_ping + k)``, so that a step renders alike alone or within its turn. With ``labels``,
    the scan's ``labels`` hold ``instance`` (int32 ``(n_samples, n_steps)``: per sample the id of
    :attr:`ScanImage.ids` bringing the most energy, -1 none; the engine's labels of each step).
    """
    sonar = spec.channel_sonar()
    fan = _fan(sim, spec, sonar)
    model = SensorModel(spec.sensor, sonar, sim.scene.render.seed) if spec.sensor is not None else False
    n = len(poses)
    from ..core.memory import require

    require(n * spec.n_samples * 4 * (2 if labels else 1), f"a scan of {n} steps x {spec.n_samples} samples", "n_pings")
    pings = first_ping + np.arange(n)
    angles = spec.head_angles_deg(pings)
    out = np.empty((spec.n_samples, n), np.float32)
    instance = np.full((spec.n_samples, n), -1, np.int32) if labels else None
    # Each step at its own pose and time; many steps go through the engine in one frame
    # (pose_frames), each step's line a column, and through the sensor with its own draws.
    at = [mounted(vehicle, spec.step_mount(angles[k])) for k, vehicle in enumerate(poses)]
    model = model or None
    draws = model is not None or (sim.scene.render.speckle and speckle is not False)
    for start, stop, _, image in pose_frames(sim, at, sonar, fan, labels="total" if labels else False,
                                             times_s=times_s):
        lines = image.components["total"]
        if not draws:
            out[:, start:stop] = lines
        else:
            for j, k in enumerate(range(start, stop)):
                out[:, k] = sim.sense(lines[:, j:j + 1], at[k], int(pings[k]), speckle, model)[:, 0]
        if labels:
            instance[:, start:stop] = image.labels.instance["total"]
    ids = tuple(o.name for o in sim.scene.objects) + tuple(p.name for p in sim.scene.reflecting_planes)
    return ScanImage(out, angles, spec.range_min_m, spec.range_max_m, ping_geometry(sim, poses, times_s, spec),
                     spec.step_deg * spec.step, labels={"instance": instance} if labels else None,
                     ids=ids if labels else (), unit_name=instrument_unit(spec.sensor, sim.scene.render.tvg).name)

