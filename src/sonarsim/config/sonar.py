"""The sonar's intrinsics: beam geometry, elevation aperture and range window.

Where the sonar is (its pose) is not part of it: a :class:`~sonarsim.core.transforms.Pose` held
next to it (``Scene.sonar_pose``, ``SonarImage.pose``, ``Simulator.render(pose=...)``), so that
one :class:`SonarConfig` serves every pose (the renderer keys its ray fans by it).

Beam angles are azimuths in degrees, LEFT-most (port) beam first; a positive azimuth is to the
sonar's left, so the list descends. Range bin ``i`` covers
``[range_min_m + i*dr, range_min_m + (i+1)*dr)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.memory import require
from ..errors import ConfigError, shown

IMAGES_PER_FRAME = 40
from ..image.grid import PolarGrid, beam_edges_deg
from .parameters import MIN_BEAM_WIDTH_DEG

__all__ = ["MAX_RANGE_M", "MIN_BEAM_WIDTH_DEG", "MIN_RELATIVE_BIN_WIDTH", "FREQUENCY_RANGE_KHZ", "RangeBinError",
           "SonarConfig", "beam_edges_deg", "check_range_bins", "check_range_window", "uniform_beam_angles_deg"]

# The far end of a range window. Forward-looking sonars see tens to a few hundred metres (the
# recordings' readers accept 400-500 m); 10 km leaves room for long-range sonars while keeping
# ranges, which the renderer holds in float32, exact to a millimetre. (Scene coordinates reach
# farther, config.scene.MAX_COORDINATE_M: a sonar may sit anywhere in a large scene.)
MAX_RANGE_M = 1e4
# The narrowest range bin, relative to the window's far end: ray distances are float32 (about
# 7 significant digits), so bins narrower than a few of their steps at the far range would
# share out the energy by round-off (all of it in a few bins, the others empty).
MIN_RELATIVE_BIN_WIDTH = 1e-6
# Carrier frequencies, kHz: imaging sonars run at tens of kHz to a few MHz; this leaves a
# margin either side. Shared by ``sonar.frequency_khz`` and ``sensor.frequency_khz``.
FREQUENCY_RANGE_KHZ = (1.0, 1e5)
# Speeds of sound in water, m/s: fresh water near freezing to warm, deep sea water (and the
# sensor section's own bounds for its sound_speed_m_s).
SOUND_SPEED_RANGE_M_S = (1300.0, 1700.0)
# A beam's shape in space: the plane of its azimuth (a lens), or a cone about the array's axis
# (a beamformed line array).
BEAM_SHAPES = ("plane", "cone")
# The narrowest beam, degrees (``beam_width_deg``, a sensor's beam pattern widths), and the
# narrowest fan and elevation aperture (1e-300 degrees was accepted: every ray on one line):
# MIN_BEAM_WIDTH_DEG, from the one table of fittable parameters (imported above).


class RangeBinError(ConfigError):
    """The range bins are too fine to be told apart (a :class:`ConfigError` naming
    ``sonar.n_range_bins``; the loader names ``sonar.range_resolution_m`` where that was given)."""


def check_range_window(range_min_m: float, range_max_m: float) -> None:
    """Refuse a range window that is not ``0 <= range_min_m < range_max_m <= MAX_RANGE_M``.

    Raises
    ------
    ConfigError
        Naming ``sonar.range_min_m`` or ``sonar.range_max_m`` and the range allowed.
    """
    if not (np.isfinite(range_min_m) and range_min_m >= 0.0):
        raise ConfigError("sonar.range_min_m", f"must be >= 0 metres, got {range_min_m}")
    if not (np.isfinite(range_max_m) and range_min_m < range_max_m <= MAX_RANGE_M):
        raise ConfigError(
            "sonar.range_max_m",
            f"must be greater than range_min_m ({range_min_m}) and at most {MAX_RANGE_M:g} metres "
            f"(a sonar sees at most kilometres), got {range_max_m}",
        )


def check_range_bins(range_min_m: float, range_max_m: float, n_range_bins: int) -> None:
    """Refuse range bins narrower than :data:`MIN_RELATIVE_BIN_WIDTH` of the far range.

    The window must already be valid (:func:`check_range_window`).

    Raises
    ------
    RangeBinError
        Naming ``sonar.n_range_bins``, the bin width and the most bins the window allows.
    """
    width = (range_max_m - range_min_m) / n_range_bins
    finest = MIN_RELATIVE_BIN_WIDTH * range_max_m
    if not (math.isfinite(width) and width >= finest):
        most = max(1, math.floor((range_max_m - range_min_m) / finest))
        raise RangeBinError(
            "sonar.n_range_bins",
            f"{n_range_bins} range bins over {range_min_m:g}-{range_max_m:g} m are {width:.3g} m wide: finer "
            f"than float32 ranges resolve at {range_max_m:g} m (at least {finest:.3g} m, "
            f"{MIN_RELATIVE_BIN_WIDTH:g} of range_max_m); allowed: 1 to {most} bins",
        )


def uniform_beam_angles_deg(n_beams: int, azimuth_fov_deg: float) -> np.ndarray:
    """Centres of ``n_beams`` equal beams spanning ``azimuth_fov_deg`` edge to edge.

    Returns
    -------
    (n_beams,) float64 ndarray, degrees, left-most first:
    ``theta_j = F/2 - (j + 0.5) F/N``.
    """
    j = np.arange(n_beams)
    return azimuth_fov_deg / 2.0 - (j + 0.5) * azimuth_fov_deg / n_beams


def _require_images(n_range_bins: int, n_beams: int) -> None:
    """Check the images of one frame against the memory budget (before allocating them).

    Raises
    ------
    ConfigError
        ``sonar.n_range_bins``: the images would need more than the budget.
    """
    # A frame holds a few dozen images of this size (path orders, components, sensor). Exact
    # integers: float() of a 400-digit n_range_bins raises OverflowError.
    require(image_bytes(n_range_bins, n_beams),
            f"images of {shown(n_range_bins)} range bins x {shown(n_beams)} beams", "sonar.n_range_bins")


def image_bytes(n_range_bins: int, n_beams: int) -> int:
    """Bytes the images of one frame may take (``IMAGES_PER_FRAME`` float32 images)."""
    return int(n_range_bins) * int(n_beams) * 4 * IMAGES_PER_FRAME


@dataclass(frozen=True)
class SonarConfig:
    """A forward-looking sonar's intrinsics. Construct with :meth:`uniform` or an explicit beam table.

    Frozen and hashable (equal configurations hash alike): a dict key for what depends on the
    sonar alone, such as its ray fan. It holds no pose.

    Attributes
    ----------
    beam_angles_deg : tuple of float, (n_beams,)
        Beam centre azimuths in degrees, left-most first (strictly descending).
    elevation_fov_deg : float
        Full elevation aperture E, within [0.01, 180) degrees; rays span [-E/2, +E/2].
    range_min_m, range_max_m : float
        The range window, metres: ``0 <= range_min_m < range_max_m <= MAX_RANGE_M`` (10 km).
    n_range_bins : int
        Number of range bins (rows of the polar image), at least 1; a bin at least
        ``MIN_RELATIVE_BIN_WIDTH * range_max_m`` wide (what float32 ranges resolve).
    beam_width_deg : float or None
        Azimuth width of one beam, within [0.01, 90) degrees, used to spread rays across a beam
        (``render.azimuth_samples > 1``); ``None`` means the spacing between beam centres.
    frequency_khz : float or None
        The carrier frequency, within ``FREQUENCY_RANGE_KHZ`` (1 kHz to 100 MHz); the sensor
        model's absorption uses it.
    beam_shape : {'plane', 'cone'}
        ``plane``: each beam is the fan plane of its azimuth (an acoustic lens, as the ARIS's
        and DIDSON's, focuses the horizontal projection of each direction). ``cone``: a
        beamformed (phased) line array's beam is the cone of directions whose cosine along the
        array is ``sin(theta)``: at elevation ``phi`` it lies at azimuth
        ``asin(sin(theta) / cos(phi))``, off the plane's by 1.5-1.8 degrees at the 60-65 degree
        edges of a 20 degree fan (:func:`sonarsim.core.rays.make_ray_fan`).
    sound_speed_m_s : float or None
        The speed the device assumes, m/s, within [1300, 1700]: it reports an echo at
        ``c_device t / 2``. With a ``water:`` section of another speed every range is scaled
        by ``c_device / c_water`` (:func:`sonarsim.core.water.range_scale`); ``None``: the
        water's own (a device set right).
    preset : str or None
        Name of the preset the configuration came from, if any.
    """

    beam_angles_deg: tuple[float, ...]
    elevation_fov_deg: float
    range_min_m: float
    range_max_m: float
    n_range_bins: int
    beam_width_deg: float | None = None
    frequency_khz: float | None = None
    preset: str | None = None
    sound_speed_m_s: float | None = None
    beam_shape: str = "plane"
    _grid: PolarGrid = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        angles = tuple(float(a) for a in np.ravel(self.beam_angles_deg))
        object.__setattr__(self, "beam_angles_deg", angles)
        a = np.asarray(angles)
        if a.size == 0:
            raise ConfigError("sonar.n_beams", "must be at least 1")
        if not np.all(np.isfinite(a)):
            raise ConfigError("sonar.beam_angles_deg", "must be finite numbers")
        if a.size > 1 and not np.all(np.diff(a) < 0):
            raise ConfigError(
                "sonar.beam_angles_deg",
                "must be strictly descending (left-most beam first; positive = sonar's left)",
            )
        edges = beam_edges_deg(a)
        if edges[0] - edges[-1] >= 180.0 or np.max(np.abs(edges)) >= 90.0:
            raise ConfigError(
                "sonar.azimuth_fov_deg",
                f"the fan spans {edges[0]:.3g} to {edges[-1]:.3g} deg; allowed: inside (-90, 90), "
                "i.e. a field of view below 180 degrees",
            )
        if not MIN_BEAM_WIDTH_DEG <= self.elevation_fov_deg < 180.0:
            raise ConfigError(
                "sonar.elevation_fov_deg",
                f"must be within [{MIN_BEAM_WIDTH_DEG:g}, 180) degrees, got {self.elevation_fov_deg}",
            )
        check_range_window(self.range_min_m, self.range_max_m)
        if int(self.n_range_bins) != self.n_range_bins or self.n_range_bins < 1:
            raise ConfigError(
                "sonar.n_range_bins", f"must be a positive integer, got {self.n_range_bins}"
            )
        object.__setattr__(self, "n_range_bins", int(self.n_range_bins))
        _require_images(self.n_range_bins, a.size)
        check_range_bins(self.range_min_m, self.range_max_m, self.n_range_bins)
        lo, hi = FREQUENCY_RANGE_KHZ
        if self.frequency_khz is not None and not (np.isfinite(self.frequency_khz)
                                                   and lo <= self.frequency_khz <= hi):
            raise ConfigError("sonar.frequency_khz",
                              f"must be within [{lo:g}, {hi:g}] kHz (sonars run at tens of kHz to a few MHz), "
                              f"got {self.frequency_khz}")
        if self.beam_shape not in BEAM_SHAPES:
            raise ConfigError("sonar.beam_shape", f"unknown beam shape {self.beam_shape!r}; allowed: "
                                                  f"{', '.join(BEAM_SHAPES)}")
        c = self.sound_speed_m_s
        if c is not None and not (np.isfinite(c) and SOUND_SPEED_RANGE_M_S[0] <= c <= SOUND_SPEED_RANGE_M_S[1]):
            raise ConfigError("sonar.sound_speed_m_s", f"must be within [{SOUND_SPEED_RANGE_M_S[0]:g}, "
                                                       f"{SOUND_SPEED_RANGE_M_S[1]:g}] m/s (water), got {c}")
        # As a beam pattern's width (config.sensor.PATTERN_WIDTH_RANGE_DEG): no sonar's beam is
        # far narrower than 0.1 degree.
        if self.beam_width_deg is not None and not MIN_BEAM_WIDTH_DEG <= self.beam_width_deg < 90.0:
            raise ConfigError(
                "sonar.beam_width_deg", f"must be within [{MIN_BEAM_WIDTH_DEG:g}, 90) degrees, got {self.beam_width_deg}"
            )
        # Checked above with the messages of scene files; the grid cannot fail now. A lone beam
        # is 1 degree wide, as it has always been.
        grid = PolarGrid(self.range_min_m, self.range_max_m, self.n_range_bins, angles, 1.0)
        object.__setattr__(self, "_grid", grid)

    @classmethod
    def uniform(
        cls,
        n_beams: int,
        azimuth_fov_deg: float,
        elevation_fov_deg: float,
        range_min_m: float,
        range_max_m: float,
        n_range_bins: int,
        **kwargs,
    ) -> "SonarConfig":
        """Equal beams spanning ``azimuth_fov_deg`` edge to edge."""
        if int(n_beams) != n_beams or n_beams < 1:
            raise ConfigError("sonar.n_beams", f"must be a positive integer, got {n_beams}")
        # Before the beam table is built: n_beams 10**12 would allocate 8 TB for it.
        if int(n_range_bins) == n_range_bins and n_range_bins >= 1:
            _require_images(int(n_range_bins), int(n_beams))
        if not MIN_BEAM_WIDTH_DEG <= azimuth_fov_deg < 180.0:
            raise ConfigError(
                "sonar.azimuth_fov_deg", f"must be within [{MIN_BEAM_WIDTH_DEG:g}, 180) degrees, got {azimuth_fov_deg}"
            )
        return cls(
            beam_angles_deg=tuple(uniform_beam_angles_deg(int(n_beams), azimuth_fov_deg)),
            elevation_fov_deg=elevation_fov_deg,
            range_min_m=range_min_m,
            range_max_m=range_max_m,
            n_range_bins=n_range_bins,
            **kwargs,
        )

    # Derived geometry -------------------------------------------------------------------

    @property
    def grid(self) -> PolarGrid:
        """The polar grid of the sonar's images (range bins and beams)."""
        return self._grid

    @property
    def n_beams(self) -> int:
        return self._grid.n_beams

    @property
    def azimuth_deg(self) -> np.ndarray:
        """(n_beams,) beam centres in degrees, left-most first."""
        return self._grid.azimuth_deg

    @property
    def beam_edges_deg(self) -> np.ndarray:
        """(n_beams + 1,) beam edges in degrees, descending."""
        return self._grid.beam_edges_deg

    @property
    def azimuth_fov_deg(self) -> float:
        """Edge-to-edge azimuth extent of the fan, degrees."""
        return self._grid.azimuth_fov_deg

    @property
    def range_resolution_m(self) -> float:
        """Width dr of one range bin, metres."""
        return self._grid.range_resolution_m

    @property
    def range_edges_m(self) -> np.ndarray:
        """(n_range_bins + 1,) bin edges, metres."""
        return self._grid.range_edges_m

    @property
    def range_m(self) -> np.ndarray:
        """(n_range_bins,) bin centres, metres."""
        return self._grid.range_m

    def effective_beam_width_deg(self) -> np.ndarray:
        """(n_beams,) azimuth width of each beam: ``beam_width_deg`` or the local spacing."""
        if self.beam_width_deg is not None:
            return np.full(self.n_beams, self.beam_width_deg)
        return -np.diff(self.beam_edges_deg)

    def to_dict(self) -> dict:
        """Scene-file form of the intrinsics, with the beam table written out explicitly.

        The ``sonar`` section of a scene file also holds the pose: see
        :func:`sonarsim.config.scene.sonar_section`.
        """
        out: dict = {
            "beam_angles_deg": list(self.beam_angles_deg),
            "elevation_fov_deg": self.elevation_fov_deg,
            "range_min_m": self.range_min_m,
            "range_max_m": self.range_max_m,
            "n_range_bins": self.n_range_bins,
        }
        for key in ("beam_width_deg", "frequency_khz", "sound_speed_m_s"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.beam_shape != "plane":  # (written only when not the default: older files unchanged)
            out["beam_shape"] = self.beam_shape
        return out
