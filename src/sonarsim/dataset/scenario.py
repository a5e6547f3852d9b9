"""Scenario files: what a dataset renders, frame by frame, as a pure function of the frame index.

A scenario (YAML or JSON, or the same dict from Python) holds::

    scene: tank.yaml            # a scene file (relative to the scenario) or an inline scene
    seed: 7                     # every frame's randomness comes from (seed, frame index)
    trajectory:                 # where the sonar is (sonarsim.dataset.trajectory)
      file: survey.csv          # CSV t,x,y,z,roll_deg,pitch_deg,yaw_deg or TUM t x y z qx qy qz qw
      rate_hz: 10               # optional: resample to this ping rate
      # or generate: {kind: lawnmower | orbit | random, ...}
    variation: {...}            # optional: what is drawn per frame (sonarsim.dataset.variation)
    start_time: 2024-05-01T12:00:00Z  # optional: the ROS 2 bag's stamp of frame 0 (ISO 8601 or
                                # seconds since 1970; default 2000-01-01T00:00:00Z, never the clock)
    rosbag:                     # optional: the bag's frame names and topics (sonarsim.io.rosbag)
      frame_ids: {world: map, sonar: sonar, image: sonar_image}
      topics: {image: /sonar/image, fan: /sonar/fan, pose: /sonar/pose, tf: /tf, points: /sonar/points}
    description: "..."          # optional, free text

:meth:`Scenario.frame` gives, for frame ``k``, everything needed to render it without any
shared state (:class:`FrameSpec`): the scene document with this frame's objects and materials,
the sonar pose, the timestamp and the frame's seed. Its draws come from
``numpy.random.default_rng(seed_k)`` where ``seed_k`` is derived from
``SeedSequence([seed, k])`` (:func:`~sonarsim.core.streams.frame_seed`,
:func:`~sonarsim.core.streams.scenario_rng`); the renderer's own draws (speckle, noise) come
from ``(render.seed, k)`` through ``Simulator.render(frame=k)``, with ``render.seed`` set to the
scenario's seed (:func:`~sonarsim.core.streams.frame_rng`). So the same scenario gives the
same frames whatever the number of workers and whatever order they finish in.
"""

from __future__ import annotations

import copy
import hashlib
import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..config.loader import _check_keys, _integer, _string, read_document, scene_from_dict
from ..config.scene import Scene
# frame_seed: defined with every other stream in core.streams, importable here as before.
from ..core.streams import frame_seed, scenario_rng
from ..core.transforms import Pose
from ..errors import ConfigError, SonarsimError, shown
from ..scene.cost import check_scene_cost
from .trajectory import PoseSource, parse_trajectory
from .variation import Variation, parse_variation

__all__ = ["SCENARIO_KEYS", "FrameSpec", "Scenario", "frame_seed", "load_scenario"]

SCENARIO_KEYS = ("scene", "seed", "trajectory", "variation", "description", "start_time", "rosbag")
# SeedSequence takes any non-negative integer; a seed beyond 2**128 is a typo, not entropy.
MAX_SEED = 2**128 - 1


@dataclass(frozen=True)
class FrameSpec:
    """Everything needed to render one frame of a scenario, with no shared state.

    Attributes
    ----------
    index : int
        Frame index ``k``, 0-based.
    seed : int
        The frame's seed (:func:`frame_seed`): its scene draws came from
        ``numpy.random.default_rng(seed)``.
    time_s : float
        Timestamp, seconds (from the trajectory).
    pose : Pose
        Sonar pose (sonar-to-world).
    scene : dict
        Scene document (what :func:`sonarsim.load_scene` accepts) with this frame's objects,
        materials and sensor parameters, and ``render.seed`` the scenario's seed. Its
        ``sonar.pose`` is the scene file's: the frame's pose is :attr:`pose`, so that frames
        that vary nothing share one document (and one simulator).
    base_dir : str or None
        Folder the scene document's relative paths (meshes, tables) are relative to.
    """

    index: int
    seed: int
    time_s: float
    pose: Pose
    scene: dict = field(repr=False)
    base_dir: str | None = None

    @property
    def scene_key(self) -> str:
        """A digest of :attr:`scene` and :attr:`base_dir`: frames with equal keys can share
        one :class:`~sonarsim.Simulator` (workers cache simulators by it)."""
        text = json.dumps([self.scene, self.base_dir], sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    def load_scene(self) -> Scene:
        """The frame's :class:`~sonarsim.Scene`, posed at :attr:`pose`, its objects on tracks
        where they are at :attr:`time_s`."""
        scene = scene_from_dict(self.scene, base_dir=self.base_dir, source=f"frame {self.index}")
        if any(o.track is not None for o in scene.objects):
            scene = replace(scene, objects=tuple(o if o.track is None else replace(o, pose=o.track.pose_at(self.time_s))
                                                 for o in scene.objects))
        return scene.with_pose(self.pose)

    def render(self, simulator: Any, **kwargs: Any):
        """Render this frame with a simulator built from :attr:`scene` (same :attr:`scene_key`).

        ``simulator.render(pose=self.pose, frame=self.index, **kwargs)``: the renderer's draws
        come from ``(render.seed, index)``; objects on tracks are first moved to where they are
        at :attr:`time_s` (:meth:`Simulator.at_time`: whatever frame the simulator rendered
        before, in whatever worker). Returns the :class:`~sonarsim.SonarImage`.
        """
        simulator.at_time(self.time_s)
        return simulator.render(pose=self.pose, frame=self.index, **kwargs)


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario (see the module docs); frames come from :meth:`frame`.

    Attributes
    ----------
    scene : dict
        The scene document every frame starts from (``render.seed`` = :attr:`seed`).
    seed : int
        The scenario seed (>= 0).
    trajectory : PoseSource
        The sonar poses (:class:`~sonarsim.dataset.trajectory.Trajectory` or
        :class:`~sonarsim.dataset.trajectory.RandomPoses`).
    variation : Variation
        What is drawn per frame.
    base_dir : str or None
        Folder of the scene's relative paths.
    max_frames : int or None
        Cap on the number of frames (``--frames N``); ``None``: the trajectory's count.
    source : str or None
        The scenario file, for messages.
    description : str or None
    start_time_ns : int or None
        The ROS 2 bag's stamp of frame 0, nanoseconds since 1970 (the ``start_time`` key,
        :func:`sonarsim.io.rosbag.parse_start_time`); later frames follow the trajectory's
        times. ``None``: :data:`sonarsim.io.rosbag.DEFAULT_START_TIME`.
    rosbag : dict
        The ``rosbag`` section (checked): ``frame_ids`` and ``topics`` of the bag
        (:func:`sonarsim.io.rosbag.bag_naming`); empty for the defaults.
    """

    scene: dict = field(repr=False)
    seed: int
    trajectory: PoseSource = field(repr=False)
    variation: Variation = field(default_factory=Variation, repr=False)
    base_dir: str | None = None
    max_frames: int | None = None
    source: str | None = None
    description: str | None = None
    start_time_ns: int | None = None
    rosbag: dict = field(default_factory=dict, repr=False)

    @property
    def n_frames(self) -> int:
        """Number of frames: the trajectory's, capped by :attr:`max_frames`."""
        n = self.trajectory.n_frames
        return n if self.max_frames is None else min(n, self.max_frames)

    def __len__(self) -> int:
        return self.n_frames

    def with_seed(self, seed: int) -> "Scenario":
        """The same scenario under another seed: its frames' draws and the renderer's
        (``render.seed``) both follow it.

        Raises
        ------
        ConfigError
            ``seed`` not an integer in [0, 2**128).
        """
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
            raise ConfigError("seed", f"must be an integer in [0, 2**128), got {shown(seed)}")
        scene = dict(self.scene)
        scene["render"] = {**(scene.get("render") or {}), "seed": int(seed)}
        return replace(self, seed=int(seed), scene=scene)

    def capped(self, frames: int | None) -> "Scenario":
        """The same scenario with at most ``frames`` frames (``None``: no cap); frames keep their
        indices and contents.

        Raises
        ------
        ConfigError
            ``frames`` below 1.
        """
        if frames is not None:
            if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
                raise ConfigError("frames", f"must be a positive integer, got {shown(frames)}")
            frames = int(frames)
        return replace(self, max_frames=frames)

    def probe(self, side: str | None = None) -> tuple[dict, list[str]]:
        """The scene document of frame 0, or (``side``) with every distribution at its low or
        high end and every pool entry used (:meth:`Variation.apply`): the high end holds the
        most objects a frame can.

        Returns
        -------
        document : dict
        origins : list of str
            The scenario key each object came from.
        """
        rng = scenario_rng(self.seed, 0)
        self.trajectory.pose(0, rng)  # the same draws as frame 0
        return self.variation.apply(self.scene, rng, side)

    def frame(self, k: int) -> FrameSpec:
        """Frame ``k``: a pure function of the scenario and ``k`` (any order, any process).

        Draws, from ``default_rng(frame_seed(seed, k))``: the pose (random trajectories only),
        then the variation (see :mod:`sonarsim.dataset.variation`).

        Raises
        ------
        IndexError
            ``k`` outside ``[0, n_frames)``.
        """
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise TypeError(f"a frame index is an integer, got {type(k).__name__}")
        k = int(k)
        if not 0 <= k < self.n_frames:
            raise IndexError(f"frame {k} is outside the scenario's {self.n_frames} frames")
        seed = frame_seed(self.seed, k)
        rng = scenario_rng(self.seed, k)  # default_rng(seed)
        pose = self.trajectory.pose(k, rng)
        doc, _ = self.variation.apply(self.scene, rng)
        return FrameSpec(k, seed, self.trajectory.time_s(k), pose, doc, self.base_dir)

    def frame_specs(self, start: int = 0, stop: int | None = None) -> Iterator[FrameSpec]:
        """Iterate over :meth:`frame` for ``k`` in ``[start, stop)`` (default: all)."""
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for k in range(start, stop):
            yield self.frame(k)


def _distinct_objects(doc: dict, origins: list[str]) -> tuple[dict, list[str], list[int]]:
    """``doc`` with one object of each distinct spec (names aside), their origins and counts.

    At a distribution's end every object a group draws from one pool entry is the same: checking
    10,000 of them took seconds, checking one says as much.
    """
    kept: dict[str, int] = {}
    objects, kept_origins, counts = [], [], []
    for obj, origin in zip(doc.get("objects") or [], origins):
        spec = {k: v for k, v in obj.items() if k != "name"} if isinstance(obj, Mapping) else obj
        key = json.dumps([origin.split(".pool[")[0], spec], sort_keys=True, default=repr)
        if key in kept:
            counts[kept[key]] += 1
            continue
        kept[key] = len(objects)
        objects.append(obj)
        kept_origins.append(origin)
        counts.append(1)
    return {**doc, "objects": objects}, kept_origins, counts


def _check_variation(scenario: Scenario) -> None:
    """Build the scenes of frame 0 and of every distribution at its low and high end, so that
    a bad value fails now, naming its key in the scenario rather than an object index."""
    for side in ("low", "high", None):
        origins: list[str] = []
        try:
            doc, origins = scenario.probe(side)
            counts = None
            if side is not None:  # every object of a group alike: one of each is checked
                doc, origins, counts = _distinct_objects(doc, origins)
            scene = scene_from_dict(doc, base_dir=scenario.base_dir)
            # A frame's objects at the counts' high end, refused now if building them would not
            # fit the budgets (a group of 10,000 objects ran 300 s into 7 GB before).
            check_scene_cost(scene, "variation.objects" if scenario.variation.objects else "scene.objects", counts)
        except ConfigError as exc:
            key = exc.key
            if key.startswith("objects["):
                i = int(key[len("objects["):key.index("]")])
                if i < len(origins):
                    rest = key[key.index("]") + 1:]
                    origin = origins[i]
                    if rest == ".name" and ".pool[" in origin:  # the group names its objects
                        origin = origin[:origin.index(".pool[")]
                    key = origin + rest
            elif key.split(".")[0].split("[")[0] in ("ground", "planes", "sensor"):
                key = f"variation.{key}"
            what = {"low": " (every distribution at its low end)", "high": " (every distribution at its high end)",
                    None: " (as drawn for frame 0)"}[side]
            raise ConfigError(key, exc.detail + what, scenario.source) from None


def load_scenario(source: str | os.PathLike | Mapping, frames: int | None = None,
                  base_dir: str | os.PathLike | None = None) -> Scenario:
    """Load and check a scenario from a YAML/JSON file or a dict of the same shape.

    Parameters
    ----------
    source : path or mapping
        The scenario file, or its document.
    frames : int, optional
        Cap on the number of frames (the CLI's ``--frames N``).
    base_dir : path, optional
        For a dict: the folder its relative paths (scene file, trajectory file, meshes) are
        relative to; default the current folder. A file's own folder otherwise.

    Returns
    -------
    Scenario

    Raises
    ------
    ConfigError
        Unknown keys, wrong types, impossible values, bad trajectory files (naming file and
        line), variations that give invalid scenes; the message names the key (and file).
    SonarsimError
        The scenario or scene file is missing, a directory, or not valid YAML/JSON.
    """
    src = None
    if isinstance(source, Mapping):
        doc: Any = source
        base = Path(base_dir) if base_dir is not None else Path.cwd()
    else:
        path = Path(source)
        doc = read_document(path)
        src = str(path)
        base = path.parent if base_dir is None else Path(base_dir)
        if doc is None:
            raise ConfigError("", "the scenario file is empty", src)
    try:
        scenario = _from_dict(doc, base, src)
        _check_variation(scenario)
        return scenario.capped(frames)
    except ConfigError as exc:
        if src and exc.source is None:
            raise ConfigError(exc.key, exc.detail, src) from None
        raise


def _from_dict(d: Any, base: Path, source: str | None) -> Scenario:
    _check_keys(d, SCENARIO_KEYS, "")
    for key in ("scene", "seed", "trajectory"):
        if key not in d:
            raise ConfigError(key, {"scene": "required: a scene file or an inline scene",
                                    "seed": "required: the integer every frame's randomness comes from",
                                    "trajectory": "required: `file` or `generate`"}[key])
    seed = _integer(d["seed"], "seed")
    if not 0 <= seed <= MAX_SEED:
        raise ConfigError("seed", f"must be an integer in [0, 2**128), got {shown(seed)}")
    description = _string(d["description"], "description") if "description" in d else None
    start_time_ns = None
    if "start_time" in d:
        from ..io.rosbag import parse_start_time

        start_time_ns = parse_start_time(d["start_time"], "start_time")
    bag: dict = {}
    if d.get("rosbag") is not None:
        from ..io.rosbag import bag_naming

        bag_naming(d["rosbag"], "rosbag")  # checked now, used when the bag is written
        bag = {k: dict(v) for k, v in d["rosbag"].items() if v}
    scene_doc, scene_dir = _scene_document(d["scene"], base)
    scene_doc = copy.deepcopy(dict(scene_doc))
    render = scene_doc.get("render") or {}
    if not isinstance(render, Mapping):
        raise ConfigError("scene.render", f"must be a mapping, got {shown(render)}")
    # The scenario's seed replaces the scene's: the renderer's draws for frame k come from
    # (render.seed, k), so they too follow the scenario's seed alone.
    scene_doc["render"] = {**render, "seed": seed}
    try:
        scene = scene_from_dict(scene_doc, base_dir=scene_dir)
    except ConfigError as exc:
        raise ConfigError(f"scene.{exc.key}" if exc.key else "scene", exc.detail,
                          exc.source if exc.source else None) from None
    if not isinstance(d["trajectory"], Mapping):
        raise ConfigError("trajectory", f"must be a mapping with `file` or `generate`, got {shown(d['trajectory'])}")
    # An orbit's centre must lie beyond the sonar's blind zone (sonar sections are not varied).
    trajectory = parse_trajectory(d["trajectory"], base, range_min_m=scene.sonar.range_min_m)
    variation = parse_variation(d.get("variation"), scene_doc, base)
    return Scenario(scene_doc, seed, trajectory, variation, str(scene_dir), None, source, description,
                    start_time_ns, bag)


def _scene_document(value: Any, base: Path) -> tuple[Mapping, Path]:
    """The scene document and the folder its relative paths refer to."""
    if isinstance(value, Mapping):
        return value, base.resolve()
    path = Path(_string(value, "scene"))
    if not path.is_absolute():
        path = base / path
    try:
        doc = read_document(path)
    except SonarsimError as exc:
        raise ConfigError("scene", str(exc)) from None
    if not isinstance(doc, Mapping):
        raise ConfigError("scene", f"{path}: the scene file must hold a mapping, got {shown(doc)}")
    return doc, path.parent.resolve()
