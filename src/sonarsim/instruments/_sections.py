"""What every instrument type's scene-file section shares: value checks, a preset's defaults,
the section parsed into its spec and written back.

A type's spec (a frozen dataclass, :class:`~sonarsim.config.instruments.InstrumentSpec`)
validates its fields in ``__post_init__`` with :func:`check_range` / :func:`check_integer`
(errors name the field; :func:`parse_section` puts the section's key in front), parses with
:func:`parse_section` (a ``preset`` gives defaults, the section's keys override them; a type
converts its own special keys with ``convert``) and writes with :func:`section_dict`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from ..config.loader import _integer, _number
from ..config.sensor import PatternSpec, parse_sensor
from ..core.rays import make_ray_fan
from ..core.transforms import Pose
from ..errors import ConfigError, shown
from ..sensor.patterns import pattern_gain

__all__ = ["LineArrayBeam", "check_range", "check_integer", "check_window", "preset_values", "parse_section", "section_dict"]


class LineArrayBeam:
    """For a spec whose one beam is a line array's (a side-scan's side, a scanning sonar's head):
    its two-way vertical pattern of ``vertical_beam_width_deg`` in its rays' weights, on the fan
    of its ``channel_sonar()``."""

    def make_fan(self, render):
        """The channel's rays weighted by the vertical pattern."""
        return make_ray_fan(self.channel_sonar(), render, self.vertical_gain)

    def vertical_gain(self, elevation_rad):
        """The two-way vertical pattern at elevations from the axis (power, 1 on axis)."""
        spec = PatternSpec(shape="line", width_deg=self.vertical_beam_width_deg, window="rect")
        return pattern_gain(elevation_rad, spec, self.vertical_beam_width_deg, ways=2)


def check_range(spec, name: str, lo: float, hi: float, lo_open: bool = True) -> None:
    """Raise ``ConfigError(name)`` unless ``spec.<name>`` is a finite number in the interval."""
    v = getattr(spec, name)
    ok = (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
          and (v > lo if lo_open else v >= lo) and v <= hi)
    if not ok:
        raise ConfigError(name, f"must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {shown(v)}")


def check_integer(spec, name: str, lo: int, hi: int) -> None:
    """Raise ``ConfigError(name)`` unless ``spec.<name>`` is an integer in ``[lo, hi]``."""
    v = getattr(spec, name)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ConfigError(name, f"must be an integer in [{lo}, {hi}], got {shown(v)}")


def check_window(spec) -> None:
    """The carrier, sound speed, range window and samples every instrument has."""
    check_range(spec, "frequency_khz", 1.0, 1e5)
    check_range(spec, "sound_speed_m_s", 1300.0, 1700.0, lo_open=False)
    check_range(spec, "range_max_m", 0.0, 1e4)
    check_range(spec, "range_min_m", 0.0, spec.range_max_m, lo_open=False)
    if spec.range_min_m >= spec.range_max_m:
        raise ConfigError("range_min_m", f"must be below range_max_m ({spec.range_max_m:g}), got {spec.range_min_m:g}")
    check_integer(spec, "n_samples", 1, 1_000_000)


def preset_values(name: Any, key: str, cls) -> dict:
    """A device preset's values for the keys of ``cls`` (:mod:`sonarsim.config.instrument_presets`).

    Raises
    ------
    ConfigError
        ``key``: no preset of that name for the type, with the allowed ones.
    """
    from ..config.instrument_presets import instrument_preset

    try:
        entry = instrument_preset(name, cls.type_name)
    except ConfigError as exc:
        raise ConfigError(key, exc.detail) from None
    return {k: entry[k] for k in cls.keys if k in entry and k not in ("preset", "sensor") and entry[k] is not None}


def parse_section(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose,
                  integers: tuple[str, ...] = (), nullable: tuple[str, ...] = (), strings: tuple[str, ...] = (),
                  convert: Callable[[str, Any, str], Any] | None = None, preset_keys: Callable | None = None):
    """The spec of a scene-file section ``d`` of the instrument type ``cls``.

    A ``preset`` gives defaults; the section's keys override them. ``convert(k, value, key)``
    converts a type's own keys (returning ``NotImplemented`` for the others); ``preset_keys(values,
    d)`` may adjust a preset's defaults to the keys given (a swath replacing a beam table).
    Every error names its key under ``key`` (``sonar.n_samples``).
    """
    values: dict[str, Any] = {}
    preset = d.get("preset")
    if preset is not None:
        values.update(preset_values(preset, f"{key}.preset", cls))
        if preset_keys is not None:
            preset_keys(values, d)
    for k in cls.keys:
        if k in ("preset", "sensor") or k not in d:
            continue
        v = d[k]
        converted = convert(k, v, f"{key}.{k}") if convert is not None else NotImplemented
        if converted is not NotImplemented:
            values[k] = converted
        elif k in nullable and v is None:
            values[k] = None
        elif k in integers:
            values[k] = _integer(v, f"{key}.{k}")
        elif k in strings:
            if not isinstance(v, str):
                raise ConfigError(f"{key}.{k}", f"must be a string, got {shown(v)}")
            values[k] = v
        else:
            values[k] = _number(v, f"{key}.{k}")
    try:
        sensor = parse_sensor(d.get("sensor"), base_dir) if d.get("sensor") is not None else None
    except ConfigError as exc:
        raise ConfigError(f"{key}.{exc.key}", exc.detail) from None
    try:
        return cls(name=name, mount=mount, sensor=sensor, preset=preset, **values)
    except ConfigError as exc:
        raise ConfigError(f"{key}.{exc.key}", exc.detail) from None


def section_dict(spec, convert: Callable[[Any], Any] | None = None) -> dict:
    """The scene-file section of an instrument: its header and every key set (``convert`` turns
    a type's own values into plain data)."""
    out = spec._header()
    for k in spec.keys:
        v = getattr(spec, k)
        if k == "sensor":
            if v is not None:
                out[k] = v.to_dict()
        elif v is not None:
            out[k] = convert(v) if convert is not None else v
    return out
