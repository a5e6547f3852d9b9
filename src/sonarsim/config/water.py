"""The ``water:`` section: the water the sound travels in.

```yaml
water: {preset: sea}                                   # 10 degC, salinity 35, 10 m, pH 8.0
water: {preset: fresh, temperature_c: 20}              # a preset with one key changed
water: {temperature_c: 12, salinity_psu: 33, depth_m: 40, ph: 7.9,
        profile: [[0, 1500], [30, 1485]]}              # depth below the surface -> speed, m/s
```

It gives the speed of sound (:func:`sonarsim.core.water.sound_speed_m_s`: Mackenzie 1981 for
sea water, Marczak 1997 for fresh; or ``sound_speed_m_s`` given), which the renderer's ranges
and the sea bed's wavenumber use, and the temperature, salinity, depth and pH that the sensor's
absorption formulas take (they replace those of the sensor's ``absorption`` section, whose
presets assume fresh water at 15 degC). A device ranges with the speed it is set to
(``sonar.sound_speed_m_s``): where that differs from the water's, every range it reports is
scaled by ``c_device / c_water``. ``profile`` (a layered, piecewise-linear sound-speed profile)
is the true water of the multibeam's and the side-scan's refraction where their sections give none.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from ..core import water as physics
from ..errors import ConfigError, shown
from .sonar import SOUND_SPEED_RANGE_M_S

#: The presets: ``sea`` (open coastal water) and ``fresh`` (a lake or a test tank).
WATER_PRESETS: dict[str, dict[str, float]] = {
    "sea": {"temperature_c": 10.0, "salinity_psu": 35.0, "depth_m": 10.0, "ph": 8.0},
    "fresh": {"temperature_c": 15.0, "salinity_psu": 0.0, "depth_m": 2.0, "ph": 7.0},
}
WATER_KEYS = ("preset", "temperature_c", "salinity_psu", "depth_m", "ph", "sound_speed_m_s", "profile")
# The absorption formulas' bounds (config.sensor.AbsorptionSpec): one water for both.
_BOUNDS = {"temperature_c": (-2.0, 40.0, "degC"), "salinity_psu": (0.0, 45.0, ""), "depth_m": (0.0, 11000.0, "m"),
           "ph": (6.0, 9.0, "")}
MAX_PROFILE_POINTS = 10_000


@dataclass(frozen=True)
class WaterSpec:
    """The water (see the module's docstring).

    Attributes
    ----------
    temperature_c : float
        degC, within [-2, 40].
    salinity_psu : float
        Practical salinity, within [0, 45] (below 5: fresh water).
    depth_m : float
        The depth the properties are taken at (the sonar's, roughly), metres in [0, 11000].
    ph : float
        Within [6, 9] (the absorption's boric-acid term).
    sound_speed_m_s : float or None
        Given speed, m/s in [1300, 1700]; ``None``: from the equations.
    profile : tuple of (depth_m, speed_m_s) or None
        A layered profile, depths rising from the surface (the multibeam's and side-scan's true water).
    preset : str or None
        The preset the section started from.
    """

    temperature_c: float = 10.0
    salinity_psu: float = 35.0
    depth_m: float = 10.0
    ph: float = 8.0
    sound_speed_m_s: float | None = None
    profile: tuple[tuple[float, float], ...] | None = None
    preset: str | None = None

    def __post_init__(self) -> None:
        for key, (lo, hi, unit) in _BOUNDS.items():
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
                raise ConfigError(f"water.{key}", f"must be a number within [{lo:g}, {hi:g}]{' ' + unit if unit else ''}, "
                                                  f"got {shown(v)}")
            object.__setattr__(self, key, float(v))
        c = self.sound_speed_m_s
        if c is not None:
            if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) \
                    or not SOUND_SPEED_RANGE_M_S[0] <= c <= SOUND_SPEED_RANGE_M_S[1]:
                raise ConfigError("water.sound_speed_m_s", f"must be within [{SOUND_SPEED_RANGE_M_S[0]:g}, "
                                                           f"{SOUND_SPEED_RANGE_M_S[1]:g}] m/s, got {shown(c)}")
            object.__setattr__(self, "sound_speed_m_s", float(c))
        if self.profile is not None:
            object.__setattr__(self, "profile", _profile(self.profile))

    @property
    def speed_m_s(self) -> float:
        """The speed of sound, m/s: ``sound_speed_m_s``, or the equations' at the water's properties."""
        if self.sound_speed_m_s is not None:
            return self.sound_speed_m_s
        return physics.sound_speed_m_s(self.temperature_c, self.salinity_psu, self.depth_m)[0]

    @property
    def extrapolated(self) -> bool:
        """The equation is used outside the range it was fitted on (brackish water, ...)."""
        return self.sound_speed_m_s is None and physics.sound_speed_m_s(
            self.temperature_c, self.salinity_psu, self.depth_m)[1]

    def to_dict(self) -> dict:
        """The scene-file form (every key explicit; no preset)."""
        out: dict[str, Any] = {k: getattr(self, k) for k in ("temperature_c", "salinity_psu", "depth_m", "ph")}
        if self.sound_speed_m_s is not None:
            out["sound_speed_m_s"] = self.sound_speed_m_s
        if self.profile is not None:
            out["profile"] = [list(p) for p in self.profile]
        return out


def _profile(raw: Any) -> tuple[tuple[float, float], ...]:
    if not isinstance(raw, (list, tuple)) or not raw or len(raw) > MAX_PROFILE_POINTS:
        raise ConfigError("water.profile", f"must be a list of 1 to {MAX_PROFILE_POINTS} [depth_m, speed_m_s] pairs, "
                                           f"got {shown(raw)}")
    out = []
    for i, p in enumerate(raw):
        if not isinstance(p, (list, tuple)) or len(p) != 2 or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in p):
            raise ConfigError(f"water.profile[{i}]", f"must be [depth_m, speed_m_s], two numbers, got {shown(p)}")
        z, c = float(p[0]), float(p[1])
        if not 0.0 <= z <= 11000.0:
            raise ConfigError(f"water.profile[{i}]", f"depth must be within [0, 11000] m, got {z:g}")
        if not SOUND_SPEED_RANGE_M_S[0] <= c <= SOUND_SPEED_RANGE_M_S[1]:
            raise ConfigError(f"water.profile[{i}]", f"speed must be within [{SOUND_SPEED_RANGE_M_S[0]:g}, "
                                                     f"{SOUND_SPEED_RANGE_M_S[1]:g}] m/s, got {c:g}")
        if out and z <= out[-1][0]:
            raise ConfigError(f"water.profile[{i}]", f"depths must rise: {z:g} m follows {out[-1][0]:g} m")
        out.append((z, c))
    return tuple(out)


def parse_water(d: Any) -> WaterSpec | None:
    """The ``water:`` section (``None`` without one)."""
    if d is None:
        return None
    if not isinstance(d, dict):
        raise ConfigError("water", f"must be a mapping (preset, temperature_c, ...), got {shown(d)}")
    unknown = [k for k in d if k not in WATER_KEYS]
    if unknown:
        raise ConfigError(f"water.{unknown[0]}", f"unknown key; allowed: {', '.join(WATER_KEYS)}")
    kw: dict[str, Any] = {}
    preset = d.get("preset")
    if preset is not None:
        if preset not in WATER_PRESETS:
            raise ConfigError("water.preset", f"unknown preset {shown(preset)}; allowed: {', '.join(WATER_PRESETS)}")
        kw.update(WATER_PRESETS[preset])
        kw["preset"] = preset
    kw.update({k: v for k, v in d.items() if k != "preset"})
    return WaterSpec(**kw)


def fold_into_sensor(sensor, water: WaterSpec | None):
    """The sensor section with the water's properties in its absorption and its speed: with a
    ``water:`` section, the absorption formulas take the water's temperature, salinity, depth
    and pH, and ``sound_speed_m_s`` (the pulse's extent, the absorption's speed) is the water's."""
    if sensor is None or water is None:
        return sensor
    changes: dict[str, Any] = {"sound_speed_m_s": water.speed_m_s}
    if sensor.absorption is not None and sensor.absorption.model != "constant":
        changes["absorption"] = dataclasses.replace(sensor.absorption, temperature_c=water.temperature_c,
                                                    salinity_psu=water.salinity_psu, depth_m=water.depth_m,
                                                    ph=water.ph)
    return dataclasses.replace(sensor, **changes)
