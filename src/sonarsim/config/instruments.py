"""Instruments on a vehicle: what each sonar type is, as configuration, and the registry of types.

A scene names a vehicle (its pose; a trajectory moves it) and the instruments it carries. An
instrument is a mount (its pose in the vehicle's frame), one or more channels (each a fan of
rays: a :class:`~sonarsim.config.sonar.SonarConfig` and the channel's own pose on the mount) and
a film its pings are recorded on; its sensor chain acts on that film's range x channel grid.

Scene files::

    sonar: {type: fls, preset: oculus-m1200d-hf, pose: {...}}   # one instrument: today's FLS
    sonar: {type: sidescan, preset: seascan-hds-600, pose: {...}}  # one instrument of another type
    vehicle: {pose: {position_m: [0, 0, 10], rpy_deg: [0, 0, 0]}}
    instruments:                                               # several, each on its mount
      - {type: sidescan, name: sss, preset: seascan-hds-600, mount: {position_m: [0.5, 0, -0.1]}}
      - {type: fls, name: fls, preset: oculus-m1200d-hf, mount: {rpy_deg: [0, 20, 0]}}

``sonar:`` without ``type`` (or with ``type: fls``) means what it always meant. The types
register themselves (:func:`register`); a type's module is :mod:`sonarsim.instruments.<type>`,
imported when a scene first names it, as a plugin is: adding a type is one module (its
configuration class and its renderer) plus its tests.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from ..core.transforms import Pose
from ..errors import ConfigError, shown
from .sonar import SonarConfig

__all__ = ["Channel", "InstrumentSpec", "FlsSpec", "register", "instrument_class", "known_types", "mounted"]

#: The registered types: name -> configuration class.
_TYPES: dict[str, type["InstrumentSpec"]] = {}


def register(cls: type["InstrumentSpec"]) -> type["InstrumentSpec"]:
    """Class decorator: make an :class:`InstrumentSpec` subclass known by its ``type_name``."""
    if not cls.type_name:
        raise TypeError(f"{cls.__name__} has no type_name")
    _TYPES[cls.type_name] = cls
    return cls


def known_types() -> list[str]:
    """Every instrument type: those registered and the modules of :mod:`sonarsim.instruments`."""
    names = set(_TYPES)
    try:
        package = importlib.import_module("sonarsim.instruments")
        names |= {m.name for m in pkgutil.iter_modules(package.__path__) if not m.name.startswith("_")
                  and m.name not in ("base", "registry")}
    except ImportError:  # pragma: no cover - the package is part of sonarsim
        pass
    return sorted(names)


def instrument_class(name: Any, key: str) -> type["InstrumentSpec"]:
    """The configuration class of the type ``name``, importing its module on first use.

    Raises
    ------
    ConfigError
        ``key``: an unknown type, with the types allowed.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(key, f"must be one of {', '.join(known_types())}; got {shown(name)}")
    if name not in _TYPES:
        try:
            # A plugin's module, found by the type's name (a string: no import edge from config).
            importlib.import_module(f"sonarsim.instruments.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"sonarsim.instruments.{name}":
                raise
    if name not in _TYPES:
        raise ConfigError(key, f"unknown instrument type {shown(name)}; allowed: {', '.join(known_types())}")
    return _TYPES[name]


@dataclass(frozen=True)
class Channel:
    """One fan of an instrument: the rays of a :class:`SonarConfig` from a pose on the vehicle.

    Attributes
    ----------
    name : str
        ``port``, ``starboard``, ``fls``, ...
    sonar : SonarConfig
        The channel's beams, elevation aperture and range window (its film's grid).
    mount : Pose
        The channel's pose in the vehicle's frame (the instrument's mount times the channel's
        own rotation).
    """

    name: str
    sonar: SonarConfig
    mount: Pose


def mounted(vehicle: Pose, mount: Pose) -> Pose:
    """The world pose of something at ``mount`` on a vehicle at ``vehicle`` (vehicle-to-world)."""
    if mount == _IDENTITY:  # the same pose, bit for bit (a product would round its angles)
        return vehicle
    return vehicle.compose(mount)


_IDENTITY = Pose()


@dataclass(frozen=True)
class InstrumentSpec:
    """An instrument: a name, a mount on the vehicle and the channels it pings.

    Subclasses add their type's keys, validated in ``__post_init__`` (frozen: a configuration),
    set ``type_name``, and implement :meth:`channels`, :meth:`parse` and :meth:`to_dict`.

    Attributes
    ----------
    name : str
        Unique among the scene's instruments (files, topics and frames are named by it).
    mount : Pose
        The instrument's pose in the vehicle's frame (x forward, y port, z up).
    """

    type_name: ClassVar[str] = ""
    #: Keys of the type's scene-file section (besides ``type``, ``name``, ``mount``).
    keys: ClassVar[tuple[str, ...]] = ()

    name: str
    mount: Pose = field(default_factory=Pose)

    def channels(self) -> tuple[Channel, ...]:
        """The instrument's fans, each with its pose on the vehicle."""
        raise NotImplementedError

    @property
    def primary(self) -> Channel:
        """The first channel: the fan a scene's cost checks count (``Scene.sonar``)."""
        return self.channels()[0]

    def ping_period_s(self) -> float:
        """Seconds between pings (or scan steps)."""
        raise NotImplementedError

    def make_fan(self, render):
        """The rays of the instrument's channels (they share one fan), with its own pattern in
        their weights; ``None``: the scene's rays for the channel's sonar (an FLS's)."""
        return None

    @classmethod
    def parse(cls, d: Mapping, key: str, base_dir: Path | None, name: str, mount: Pose) -> "InstrumentSpec":
        """The spec of a scene-file section ``d`` (its type-specific keys), named at ``key``."""
        raise NotImplementedError

    def to_dict(self) -> dict:
        """The scene-file section (with ``type``, ``name`` and ``mount``)."""
        raise NotImplementedError

    def _header(self) -> dict:
        return {"type": self.type_name, "name": self.name, "mount": self.mount.to_dict()}


@register
@dataclass(frozen=True)
class FlsSpec(InstrumentSpec):
    """A forward-looking sonar: one polar fan (:class:`SonarConfig`), today's sonar.

    Parsed by the loader (``config.loader.parse_instrument``: the ``sonar:`` section's keys).

    Attributes
    ----------
    sonar : SonarConfig
        Its intrinsics.
    ping_rate_hz : float or None
        Frames per second; default the two-way travel time of the range window.
    """

    type_name: ClassVar[str] = "fls"

    sonar: SonarConfig | None = None
    ping_rate_hz: float | None = None
    sound_speed_m_s: float = 1500.0

    def __post_init__(self) -> None:
        if not isinstance(self.sonar, SonarConfig):
            raise ConfigError(f"{self.name}", "an fls instrument needs its sonar intrinsics")

    def channels(self) -> tuple[Channel, ...]:
        return (Channel("fls", self.sonar, self.mount),)

    def ping_period_s(self) -> float:
        if self.ping_rate_hz:
            return 1.0 / self.ping_rate_hz
        return 2.0 * self.sonar.range_max_m / self.sound_speed_m_s

    def to_dict(self) -> dict:
        out = {**self._header(), **self.sonar.to_dict()}
        if self.ping_rate_hz is not None:
            out["ping_rate_hz"] = self.ping_rate_hz
        return out
