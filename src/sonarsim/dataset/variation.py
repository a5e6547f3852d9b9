"""Scene variation: what a scenario draws anew for every frame, and how.

A value in the ``variation`` section is either a literal (number, string, list, mapping) or a
*distribution*, a mapping with one of these keys:

===================================  =====================================================
``{uniform: [lo, hi]}``               a float uniform in [lo, hi)
``{normal: [mean, std]}``             a normal float; optional ``min``/``max`` clip it
``{randint: [lo, hi]}``               an integer uniform in [lo, hi] (both ends included)
``{choice: [a, b, ...]}``             one of the options (any values, distributions too);
                                      optional ``weights`` (non-negative, not all zero)
===================================  =====================================================

Lists and mappings may hold distributions at any depth (``position_m: [{uniform: [0, 4]},
0, 0.2]``). The section::

    variation:
      objects:                    # groups of objects added to the scene, drawn per frame
        - name: rock              # objects rock_0, rock_1, ...
          count: {randint: [1, 4]}
          pool:                   # each object is one of these (mesh or primitive entries)
            - {primitive: sphere, radius_m: {uniform: [0.1, 0.25]}}
            - {mesh: meshes/rock.obj}
          weights: [3, 1]         # optional: how often each pool entry is chosen
          pose: {position_m: [...], rpy_deg: [...]}   # optional, replaces the entry's
          scale: {uniform: [0.8, 1.2]}                # optional
          albedo: ... | material: {...}               # optional
      ground: {albedo: ..., specular: ..., material: ...}   # merged into the scene's ground
      planes: {surface: {specular: ...}}                    # by plane name
      sensor: {gain_db: ..., noise: {level_db: ...}}        # merged into the scene's sensor

Draws happen in document order from the frame's generator: for each group its count, then for
each object the pool entry, the entry's values and the group's; then ground, planes, sensor.
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config.loader import OBJECT_KEYS, _check_keys, _number, _string, _vector
from ..errors import ConfigError, shown

__all__ = ["DISTRIBUTIONS", "ObjectGroup", "Variation", "draw", "parse_value", "parse_variation", "probabilities",
           "probe"]

DISTRIBUTIONS = {"uniform": ("uniform",), "normal": ("normal", "min", "max"), "randint": ("randint",),
                 "choice": ("choice", "weights")}
VARIATION_KEYS = ("objects", "ground", "planes", "sensor")
GROUP_KEYS = ("name", "count", "pool", "weights", "pose", "scale", "albedo", "material")
POOL_KEYS = tuple(k for k in OBJECT_KEYS if k != "name")
# A group adds at most this many objects to a frame: beyond that a typo, not a scene.
MAX_OBJECTS_PER_GROUP = 10_000


# Distributions ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Uniform:
    """A float uniform in ``[lo, hi)``."""

    lo: float
    hi: float


@dataclass(frozen=True)
class Normal:
    """A normal float of mean ``mean`` and standard deviation ``std``, clipped to ``[lo, hi]``."""

    mean: float
    std: float
    lo: float | None = None
    hi: float | None = None


@dataclass(frozen=True)
class RandInt:
    """An integer uniform in ``[lo, hi]``, both ends included."""

    lo: int
    hi: int


@dataclass(frozen=True)
class Choice:
    """One of ``options`` (each a template), with optional relative ``weights``."""

    options: tuple
    weights: tuple[float, ...] | None = None


def _pair(value: Any, key: str, what: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(key, f"must be [{what}], two numbers, got {shown(value)}")
    a, b = _vector(value, key, 2)
    return a, b


def _is_distribution(value: Any) -> bool:
    return isinstance(value, Mapping) and any(k in DISTRIBUTIONS for k in value)


def parse_value(value: Any, key: str) -> Any:
    """A literal or distribution (at any depth) as a *template* for :func:`draw`.

    Parameters
    ----------
    value : any
        As read from the scenario file.
    key : str
        Its place in the file, for errors.

    Returns
    -------
    template
        Literals as they are (lists and dicts copied), distributions as :class:`Uniform`,
        :class:`Normal`, :class:`RandInt` or :class:`Choice`.

    Raises
    ------
    ConfigError
        A mapping that mixes two distributions or has other keys, bounds in the wrong order,
        a negative standard deviation, no options, bad weights.
    """
    if _is_distribution(value):
        kinds = [k for k in value if k in DISTRIBUTIONS]
        if len(kinds) > 1:
            raise ConfigError(key, f"give one distribution, not {' and '.join(kinds)}")
        kind = kinds[0]
        _check_keys(value, DISTRIBUTIONS[kind], key)
        where = f"{key}.{kind}"
        if kind == "uniform":
            lo, hi = _pair(value[kind], where, "lo, hi")
            if lo > hi:
                raise ConfigError(where, f"the lower bound must not exceed the upper one, got [{lo:g}, {hi:g}]")
            return Uniform(lo, hi)
        if kind == "normal":
            mean, std = _pair(value[kind], where, "mean, std")
            if std < 0:
                raise ConfigError(where, f"the standard deviation must be >= 0, got {std:g}")
            lo = _number(value["min"], f"{key}.min") if "min" in value else None
            hi = _number(value["max"], f"{key}.max") if "max" in value else None
            if lo is not None and hi is not None and lo > hi:
                raise ConfigError(f"{key}.max", f"must not be below min ({lo:g}), got {hi:g}")
            return Normal(mean, std, lo, hi)
        if kind == "randint":
            raw = value[kind]
            if (not isinstance(raw, (list, tuple)) or len(raw) != 2
                    or any(isinstance(v, bool) or not isinstance(v, int) for v in raw)):
                raise ConfigError(where, f"must be [lo, hi], two integers, got {shown(raw)}")
            if raw[0] > raw[1]:
                raise ConfigError(where, f"the lower bound must not exceed the upper one, got {list(raw)}")
            return RandInt(int(raw[0]), int(raw[1]))
        options = value[kind]
        if not isinstance(options, (list, tuple)) or not options:
            raise ConfigError(where, f"must be a non-empty list of options, got {shown(options)}")
        weights = None
        if "weights" in value:
            weights = _weights(value["weights"], f"{key}.weights", len(options))
        return Choice(tuple(parse_value(o, f"{where}[{i}]") for i, o in enumerate(options)), weights)
    if isinstance(value, Mapping):
        return {k: parse_value(v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [parse_value(v, f"{key}[{i}]") for i, v in enumerate(value)]
    return value


def _weights(value: Any, key: str, n: int) -> tuple[float, ...]:
    w = _vector(value, key, n)
    # max, not sum: weights of [1e308, 1e308] sum to inf (and were refused by NumPy's choice).
    if any(v < 0 for v in w) or not max(w) > 0:
        raise ConfigError(key, f"must be {n} non-negative finite numbers, not all zero, got {shown(value)}")
    return w


def probabilities(weights: tuple[float, ...] | None) -> np.ndarray | None:
    """Relative weights as probabilities summing to 1 (``None`` stays ``None``: equal).

    Where their sum overflows (weights of ``[1e308, 1e308]``) or is too small to divide by
    exactly, the weights are first divided by the largest; otherwise by their sum, as always
    (the same draws as before for the weights that worked).
    """
    if weights is None:
        return None
    w = np.asarray(weights, dtype=np.float64)
    total = sum(weights)  # Python's float sum: inf without a NumPy overflow warning
    if not (math.isfinite(total) and total >= sys.float_info.min):
        w = w / w.max()
        total = sum(w.tolist())
    return w / total


def draw(template: Any, rng: np.random.Generator) -> Any:
    """A value drawn from a template (:func:`parse_value`): plain Python numbers, lists, dicts.

    Draws in document order (mappings in their key order, lists front to back), one draw per
    distribution met (a choice draws its index, then whatever its chosen option holds).
    """
    if isinstance(template, Uniform):
        return float(rng.uniform(template.lo, template.hi))
    if isinstance(template, Normal):
        v = float(rng.normal(template.mean, template.std))
        if template.lo is not None:
            v = max(v, template.lo)
        if template.hi is not None:
            v = min(v, template.hi)
        return v
    if isinstance(template, RandInt):
        return int(rng.integers(template.lo, template.hi, endpoint=True))
    if isinstance(template, Choice):
        return draw(template.options[int(rng.choice(len(template.options), p=probabilities(template.weights)))], rng)
    if isinstance(template, dict):
        return {k: draw(v, rng) for k, v in template.items()}
    if isinstance(template, list):
        return [draw(v, rng) for v in template]
    return copy.deepcopy(template)


def probe(template: Any, side: str) -> Any:
    """The template with every distribution at one end (``side``: ``'low'`` or ``'high'``):
    uniform and randint bounds, a normal's clip (its mean where unclipped), a choice's first or
    last option. Used to check, when a scenario is loaded, that the extremes make valid scenes."""
    high = side == "high"
    if isinstance(template, (Uniform, RandInt)):
        return template.hi if high else template.lo
    if isinstance(template, Normal):
        bound = template.hi if high else template.lo
        return float(template.mean if bound is None else bound)
    if isinstance(template, Choice):
        return probe(template.options[-1 if high else 0], side)
    if isinstance(template, dict):
        return {k: probe(v, side) for k, v in template.items()}
    if isinstance(template, list):
        return [probe(v, side) for v in template]
    return copy.deepcopy(template)


# The variation section ------------------------------------------------------------------

@dataclass(frozen=True)
class ObjectGroup:
    """Objects added to every frame: ``count`` of them, each an entry of ``pool``.

    Attributes
    ----------
    name : str
        Object ``i`` of the group is named ``{name}_{i}``.
    count : template
        An integer or an integer distribution (randint, choice of integers).
    pool : tuple of templates
        Object entries (scene-file object keys except ``name``; values may be distributions).
    weights : tuple of float or None
        Relative frequency of each pool entry; ``None``: equal.
    overrides : template
        ``pose``, ``scale``, ``albedo``, ``material`` set on every object of the group,
        replacing the entry's (``albedo`` and ``material`` replace each other).
    """

    name: str
    count: Any
    pool: tuple
    weights: tuple[float, ...] | None
    overrides: dict


@dataclass(frozen=True)
class Variation:
    """What a scenario varies per frame (see the module docs); empty: nothing."""

    objects: tuple[ObjectGroup, ...] = ()
    ground: dict | None = None
    planes: dict | None = None
    sensor: dict | None = None

    def apply(self, scene: Mapping, rng: np.random.Generator, side: str | None = None) -> tuple[dict, list[str]]:
        """Frame's scene document: ``scene`` (not modified) with this variation drawn into it.

        Parameters
        ----------
        scene : mapping
            The scenario's scene document.
        rng : numpy.random.Generator
            The frame's generator (draws in the order of the module docs).
        side : {'low', 'high'}, optional
            Instead of drawing, put every distribution at that end (:func:`probe`) and every
            pool entry in the scene at least once (to check that they all make valid scenes).

        Returns
        -------
        document : dict
            A new scene document.
        origins : list of str
            For each object the document holds, the scenario key it came from (``scene`` for
            the scene's own, ``variation.objects[g].pool[j]`` for drawn ones): error messages
            about ``objects[i]`` name it.
        """
        value = (lambda t: draw(t, rng)) if side is None else (lambda t: probe(t, side))
        doc = copy.deepcopy(dict(scene))
        objects = list(doc.get("objects") or [])
        origins = [f"scene.objects[{i}]" for i in range(len(objects))]
        for g, group in enumerate(self.objects):
            count = value(group.count)
            if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= MAX_OBJECTS_PER_GROUP:
                raise ConfigError(f"variation.objects[{g}].count",
                                  f"must give an integer in [0, {MAX_OBJECTS_PER_GROUP}], got {shown(count)}")
            # Probing puts every pool entry in the scene at least once, whatever the count.
            for i in range(count if side is None else max(count, len(group.pool))):
                if side is None:
                    j = int(rng.choice(len(group.pool), p=probabilities(group.weights)))
                else:
                    j = (i % len(group.pool)) if side == "low" else len(group.pool) - 1 - (i % len(group.pool))
                entry = value(group.pool[j])
                extra = value(group.overrides)
                if "material" in extra:
                    entry.pop("albedo", None)
                if "albedo" in extra:
                    entry.pop("material", None)
                objects.append({"name": f"{group.name}_{i}", **entry, **extra})
                origins.append(f"variation.objects[{g}].pool[{j}]")
        if self.objects:
            doc["objects"] = objects
        if self.ground is not None:
            doc["ground"] = _merged(doc["ground"], value(self.ground), deep=False)
        if self.planes is not None:
            drawn = value(self.planes)
            doc["planes"] = [_merged(p, drawn[p["name"]], deep=False) if p.get("name") in drawn else p
                             for p in doc["planes"]]
        if self.sensor is not None:
            doc["sensor"] = _merged(doc["sensor"], value(self.sensor), deep=True)
        return doc, origins


def _merged(base: Mapping, extra: Mapping, deep: bool) -> dict:
    """``base`` updated by ``extra``; ``albedo`` and ``material`` replace each other; ``deep``
    merges nested mappings (the sensor's sub-sections) instead of replacing them."""
    out = dict(base)
    if "material" in extra:
        out.pop("albedo", None)
    if "albedo" in extra:
        out.pop("material", None)
    for k, v in extra.items():
        if deep and isinstance(v, Mapping) and isinstance(out.get(k), Mapping):
            out[k] = _merged(out[k], v, deep=True)
        else:
            out[k] = v
    return out


def _parse_group(d: Any, g: int, base_dir: Path | None) -> ObjectGroup:
    where = f"variation.objects[{g}]"
    _check_keys(d, GROUP_KEYS, where)
    name = _string(d.get("name", f"varied{g}"), f"{where}.name")
    if "pool" not in d:
        raise ConfigError(f"{where}.pool", "required: a list of object entries (primitive or mesh) to draw from")
    pool_raw = d["pool"]
    if not isinstance(pool_raw, list) or not pool_raw:
        raise ConfigError(f"{where}.pool", f"must be a non-empty list of object entries, got {shown(pool_raw)}")
    pool = []
    for j, entry in enumerate(pool_raw):
        key = f"{where}.pool[{j}]"
        _check_keys(entry, POOL_KEYS, key)
        entry = dict(entry)
        if "mesh" in entry:
            # Meshes of a pool are relative to the scenario file; the frame's document holds
            # them absolute, so that it does not depend on where it is loaded from.
            path = Path(_string(entry["mesh"], f"{key}.mesh"))
            entry["mesh"] = str(path if path.is_absolute() or base_dir is None else (base_dir / path).resolve())
        pool.append(parse_value(entry, key))
    weights = _weights(d["weights"], f"{where}.weights", len(pool)) if "weights" in d else None
    count = parse_value(d.get("count", 1), f"{where}.count")
    if isinstance(count, (Uniform, Normal)):
        raise ConfigError(f"{where}.count", "must be an integer, randint or choice of integers, not a float distribution")
    if isinstance(count, RandInt) and (count.lo < 0 or count.hi > MAX_OBJECTS_PER_GROUP):
        raise ConfigError(f"{where}.count.randint", f"must lie within [0, {MAX_OBJECTS_PER_GROUP}]")
    overrides = {k: parse_value(d[k], f"{where}.{k}") for k in ("pose", "scale", "albedo", "material") if k in d}
    if "albedo" in overrides and "material" in overrides:
        raise ConfigError(f"{where}.albedo", "give either albedo (the Lambertian shorthand) or material, not both")
    return ObjectGroup(name, count, tuple(pool), weights, overrides)


def parse_variation(d: Any, scene: Mapping, base_dir: Path | None) -> Variation:
    """The scenario's ``variation`` section (``None`` or empty: nothing varies).

    ``scene`` is the scenario's scene document: ground, planes and sensor can only be varied
    where it has them. Values are checked for their form here; whether the scenes they give are
    valid is checked by :func:`sonarsim.dataset.scenario.load_scenario` (drawn at both ends).
    """
    if d is None:
        return Variation()
    _check_keys(d, VARIATION_KEYS, "variation")
    groups_raw = d.get("objects") or []
    if not isinstance(groups_raw, list):
        raise ConfigError("variation.objects", f"must be a list of object groups, got {shown(groups_raw)}")
    groups = tuple(_parse_group(g, i, base_dir) for i, g in enumerate(groups_raw))
    names = [g.name for g in groups]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ConfigError(f"variation.objects[{i}].name", f"duplicate group name {shown(n)}")
    ground = planes = sensor = None
    if d.get("ground") is not None:
        if not isinstance(d["ground"], Mapping):
            raise ConfigError("variation.ground", f"must be a mapping of ground keys, got {shown(d['ground'])}")
        if not scene.get("ground"):
            raise ConfigError("variation.ground", "the scene has no ground to vary (give it a `ground` section)")
        ground = parse_value(d["ground"], "variation.ground")
    if d.get("planes") is not None:
        if not isinstance(d["planes"], Mapping):
            raise ConfigError("variation.planes", f"must be a mapping from plane name to plane keys, got {shown(d['planes'])}")
        known = [p.get("name") for p in scene.get("planes") or [] if isinstance(p, Mapping)]
        for name, value in d["planes"].items():
            if name not in known:
                raise ConfigError(f"variation.planes.{name}", f"the scene has no plane of that name; its planes: "
                                  f"{', '.join(map(str, known)) or 'none'}")
            if not isinstance(value, Mapping):
                raise ConfigError(f"variation.planes.{name}", f"must be a mapping of plane keys, got {shown(value)}")
        planes = parse_value(d["planes"], "variation.planes")
    if d.get("sensor") is not None:
        if not isinstance(d["sensor"], Mapping):
            raise ConfigError("variation.sensor", f"must be a mapping of sensor keys, got {shown(d['sensor'])}")
        if not isinstance(scene.get("sensor"), Mapping):
            raise ConfigError("variation.sensor", "the scene has no sensor section to vary (give it one, e.g. "
                              "`sensor: {preset: ...}`)")
        sensor = parse_value(d["sensor"], "variation.sensor")
    return Variation(groups, ground, planes, sensor)
