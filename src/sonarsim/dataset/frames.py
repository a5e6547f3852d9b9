"""Rendering a scenario's frames: one simulator per scene, each frame from its FrameSpec alone.

:func:`frames` is the in-memory side of a dataset (training loops, notebooks): it yields
:class:`Frame` objects (the rendered :class:`~sonarsim.image.result.SonarImage` and the
:class:`~sonarsim.dataset.scenario.FrameSpec` it came from) without writing anything.
:func:`sonarsim.dataset.generate` renders the same frames through the same
:func:`render_frame`, so a frame from :func:`frames` equals the one in the dataset's NPZ.

Ground truth (``labels=True``) comes from the renderer (``Simulator.render(..., labels=True)``,
:mod:`sonarsim.image.labels`) where it is available; :func:`frame_arrays` is the one place
that turns a rendered frame into the named arrays of a dataset file.
"""

from __future__ import annotations

import functools
import inspect
import os
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .scenario import FrameSpec, Scenario, load_scenario

if TYPE_CHECKING:
    from ..image.result import SonarImage
    from ..renderer.simulator import Simulator

__all__ = ["LABEL_MODES", "Frame", "SimulatorCache", "as_scenario", "frame_arrays", "frame_memory_bytes", "frames", "label_mode", "labels_supported", "render_frame", "rendered_labels",
           "require_manifest_memory"]

# Simulators kept per process: frames that vary their scene each get their own key, and a
# simulator holds its meshes and ray-casting structures; a few cover a scenario that cycles
# through a handful of scenes without letting memory grow with the frame count.
DEFAULT_CACHE_SIZE = 4


@functools.lru_cache(maxsize=1)
def labels_supported() -> bool:
    """Whether this sonarsim's renderer can attach ground truth (``render(..., labels=True)``)."""
    from ..renderer.simulator import Simulator

    return "labels" in inspect.signature(Simulator.render).parameters


def as_scenario(scenario: Scenario | str | os.PathLike | Mapping, frames: int | None = None) -> Scenario:
    """A :class:`Scenario` from a loaded scenario, a scenario file or its document.

    Parameters
    ----------
    scenario : Scenario, path or mapping
        What :func:`~sonarsim.dataset.load_scenario` accepts, or a scenario already loaded.
    frames : int, optional
        Cap on the number of frames (``--frames N``).
    """
    if isinstance(scenario, Scenario):
        return scenario.capped(frames) if frames is not None else scenario
    return load_scenario(scenario, frames=frames)


class SimulatorCache:
    """Simulators by :attr:`FrameSpec.scene_key`, built once and kept between frames.

    Parameters
    ----------
    threads : int, optional
        Ray-casting threads of each simulator; ``None``: the scene's ``render.threads``.
        A worker process of :func:`sonarsim.dataset.generate` sets it to its share of the
        cores. Threads change how fast a frame renders, never what it holds.
    max_size : int
        Simulators kept; the least recently used one is closed beyond that.
    backend : {"embree", "numpy"}
        Ray-casting engine.
    """

    def __init__(self, threads: int | None = None, max_size: int = DEFAULT_CACHE_SIZE,
                 backend: str = "embree") -> None:
        self.threads = threads
        self.max_size = max(1, int(max_size))
        self.backend = backend
        self._sims: OrderedDict[str, Simulator] = OrderedDict()
        self.built = 0  # simulators built so far (tests check the reuse)

    def get(self, spec: FrameSpec) -> Simulator:
        """The simulator of ``spec``'s scene (built at first use)."""
        from ..renderer.simulator import Simulator

        key = spec.scene_key
        sim = self._sims.get(key)
        if sim is not None:
            self._sims.move_to_end(key)
            return sim
        scene = spec.load_scene()
        if self.threads is not None:
            scene = replace(scene, render=replace(scene.render, threads=int(self.threads)))
        sim = Simulator(scene, backend=self.backend)
        self.built += 1
        self._sims[key] = sim
        while len(self._sims) > self.max_size:
            _, old = self._sims.popitem(last=False)
            old.close()
        return sim

    def close(self) -> None:
        """Close every simulator (their worker threads stop)."""
        while self._sims:
            _, sim = self._sims.popitem()
            sim.close()

    def __enter__(self) -> SimulatorCache:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Ground-truth modes: ``"all"`` (an instance map per component), ``"total"`` (of the total
#: only; the rest of the labels alike, for about two thirds of the cost), ``"none"``.
LABEL_MODES = ("all", "total", "none")


def label_mode(labels: bool | str) -> str:
    """``labels`` as one of :data:`LABEL_MODES` (``True``: ``"all"``, ``False``: ``"none"``).

    Raises
    ------
    ConfigError
        Any other value.
    """
    from ..errors import ConfigError, shown

    if labels is True or labels is False:
        return "all" if labels else "none"
    if labels not in LABEL_MODES:
        raise ConfigError("labels", f"allowed: True, False, {', '.join(map(repr, LABEL_MODES))}; got {shown(labels)}")
    return str(labels)


def _largest_frame(scenario: Scenario) -> tuple[dict, Any]:
    """The document of a frame of ``scenario`` with the most of everything (its variation at the
    high end), and its scene without objects (they are counted, not built: the scenario's check
    built one of each kind)."""
    from ..config.loader import scene_from_dict

    doc = scenario.probe("high")[0]
    return doc, scene_from_dict({**doc, "objects": []}, base_dir=scenario.base_dir)


def frame_memory_bytes(scenario: Scenario, labels: bool | str) -> float:
    """The most bytes one frame of ``scenario`` holds at once while it renders: its images,
    rays and sensor fields, and its label maps for the most objects a frame can hold (what
    :func:`require_dataset_memory` checks against the budget)."""
    from ..renderer.ground_truth import label_map_bytes
    from ..renderer.simulator import frame_memory_parts

    doc, scene = _largest_frame(scenario)
    total = sum(float(n) for n, _, _ in frame_memory_parts(scene, scene.sonar))
    mode = label_mode(labels)
    if mode != "none" and labels_supported():
        total += label_map_bytes(len(doc.get("objects") or []) + len(scene.reflecting_planes), scene.render.max_order,
                                 scene.sonar.n_range_bins, scene.sonar.n_beams, components=True)
    return total


#: What a dataset holds per frame while it is made, besides the frames being rendered: each
#: frame's spec digest and manifest header (1.3 kB measured), its finished manifest line with
#: its boxes and masks, and the fingerprint's digests; a floor, which a random trajectory of
#: 10**9 frames once spun past (an hour a million frames, and memory without end).
MANIFEST_BYTES_PER_FRAME = 4096


def require_manifest_memory(scenario: Scenario) -> None:
    """Refuse a dataset of more frames than the memory budget can list (their specs and
    manifest lines, :data:`MANIFEST_BYTES_PER_FRAME` each), before any frame is listed.

    Raises
    ------
    ConfigError
        Naming ``trajectory.generate.frames`` (random poses) or ``trajectory``, and the file.
    """
    from ..core.memory import require
    from ..errors import ConfigError
    from .trajectory import RandomPoses

    n = scenario.n_frames
    key = "trajectory.generate.frames" if isinstance(scenario.trajectory, RandomPoses) else "trajectory"
    # (a count of 400 digits is no float)
    count = str(n) if n < 10**6 else f"{float(n):.3g}" if n < 10**300 else f"about 1e{len(str(n)) - 1}"
    try:
        require(n * MANIFEST_BYTES_PER_FRAME, f"the manifest of {count} frames", key)
    except ConfigError as exc:
        raise ConfigError(key, f"{exc.detail}; make fewer frames (or the first N: --frames N)",
                          scenario.source) from None


def require_dataset_memory(scenario: Scenario, labels: bool | str) -> None:
    """Refuse, before the first frame, frames that would not fit the memory budget: their
    images, rays and sensor fields, and their label maps for the most objects a frame of
    ``scenario`` can hold (its variation at the high end).

    Raises
    ------
    ConfigError
        Naming the key (``variation.objects`` or ``scene.objects`` for the labels) and the file.
    """
    from ..errors import ConfigError
    from ..renderer.ground_truth import require_label_maps
    from ..renderer.simulator import require_frame_memory

    mode = label_mode(labels)
    require_manifest_memory(scenario)
    doc, scene = _largest_frame(scenario)
    try:
        require_frame_memory(scene, scene.sonar)
    except ConfigError as exc:
        raise ConfigError(f"scene.{exc.key}", exc.detail, scenario.source) from None
    if mode == "none" or not labels_supported():
        return
    try:
        # Every component's maps (rendered_labels): the boxes are the direct echoes'.
        require_label_maps(len(doc.get("objects") or []) + len(scene.reflecting_planes), scene.render.max_order,
                           scene.sonar.n_range_bins, scene.sonar.n_beams, components=True,
                           key="variation.objects" if scenario.variation.objects else "scene.objects")
    except ConfigError as exc:
        raise ConfigError(exc.key, f"{exc.detail}; or ask for no labels (--labels none)",
                          scenario.source) from None


def rendered_labels(labels: bool | str) -> str:
    """What a dataset asks the renderer for, to store ``labels`` (:func:`label_mode`): every
    component's instance map whenever it has ground truth, since its boxes and masks are the
    objects' direct echoes (the ``object`` map); the NPZ keeps what ``labels`` says
    (:func:`frame_arrays`)."""
    return "none" if label_mode(labels) == "none" else "all"


def render_frame(spec: FrameSpec, cache: SimulatorCache, labels: bool | str = "total") -> SonarImage:
    """Render one frame from its spec alone (pose, seed, scene), without per-ray maps.

    Parameters
    ----------
    spec : FrameSpec
    cache : SimulatorCache
        Where the frame's simulator comes from.
    labels : bool or {"all", "total", "none"}
        Ask the renderer for ground truth (:func:`label_mode`); ignored by a renderer without
        it (:func:`labels_supported`).

    Returns
    -------
    SonarImage
        The frame; its draws (speckle, noise) come from ``(render.seed, spec.index)``.
    """
    kwargs: dict[str, Any] = {"keep_rays": False}
    mode = label_mode(labels)
    if mode != "none" and labels_supported():
        kwargs["labels"] = mode
    return spec.render(cache.get(spec), **kwargs)


def frame_arrays(image: SonarImage, signatures: bool = False, components: bool = True) -> dict[str, np.ndarray]:
    """The named arrays of a rendered frame, as a dataset's NPZ holds them.

    ``polar`` (n_range_bins, n_beams) float32, ``range_m`` (n_range_bins,) metres,
    ``azimuth_deg`` (n_beams,) degrees, one image per component of the table (``object``,
    ``ground``, ``single``, ``double``, ..., ``total``), and with ground truth its arrays
    (``instance`` int32 like ``polar``, ``elevation_deg`` float32, ``points_world`` (n, 3)
    float32, ``points_object`` (n,) int32, ``boxes_polar``, ...; see
    :mod:`sonarsim.image.labels`).

    Parameters
    ----------
    image : SonarImage
    signatures : bool
        Also one image per path signature (``O-[objects]-ground-O``, ...). They cost a pass
        over the frame's paths each time (twice the labelled render on the demo tank) and,
        with the ground as the only mirror, repeat the table's images; with tank walls or a
        water surface they tell the bounces apart.
    components : bool
        The component table's images (a dataset stores them with ``labels: all`` only; the
        signatures come with them).

    This is the one place that knows where labels live on a rendered image.
    """
    names = getattr(image.components, "table", None)
    if signatures or (names is None and components):  # (a plain mapping of components: all of them)
        out = dict(image.arrays())
    else:
        out = {"polar": image.polar, "range_m": image.range_m, "azimuth_deg": image.azimuth_deg}
        if components:
            out.update((name, image.components[name]) for name in names)
    labels = getattr(image, "labels", None)
    if labels is not None:
        # Renderers whose arrays() already include the labels give the same names again.
        for name, value in labels.arrays().items():
            out.setdefault(name, value)
    if not components:
        # The components' instance maps come with their images: a dataset frame, rendered with
        # every map for its boxes (rendered_labels), stores the total's alone without them.
        out = {name: value for name, value in out.items() if not name.startswith("instance_")}
    return out


@dataclass(frozen=True)
class Frame:
    """One rendered frame of a scenario.

    Attributes
    ----------
    spec : FrameSpec
        What was rendered (index, seed, time, pose, scene).
    image : SonarImage
        The rendered image, with ``labels`` when the renderer provides them.
    """

    spec: FrameSpec
    image: Any

    @property
    def index(self) -> int:
        """The frame index ``k``."""
        return self.spec.index

    @property
    def labels(self) -> Any:
        """The frame's ground truth, or ``None`` (renderer without labels, or ``labels=False``)."""
        return getattr(self.image, "labels", None)

    def arrays(self, signatures: bool = False, components: bool = True) -> dict[str, np.ndarray]:
        """:func:`frame_arrays` of the image: what the dataset's NPZ holds when made with the
        same ``signatures`` and labels (``components``: the component images, which a dataset
        stores with ``labels="all"`` only)."""
        return frame_arrays(self.image, signatures, components)


def frames(scenario: Scenario | str | os.PathLike | Mapping, start: int = 0, stop: int | None = None,
           labels: bool | str = "total", threads: int | None = None) -> Iterator[Frame]:
    """Render a scenario's frames ``start .. stop - 1`` in order, without writing anything.

    Each frame is rendered from its :class:`FrameSpec` alone (a simulator is built once per
    scene and kept), so frame ``k`` is the same here, in :func:`sonarsim.dataset.generate`'s
    files, and whatever frames were rendered before it.

    Parameters
    ----------
    scenario : Scenario, path or mapping
        A loaded scenario, or what :func:`~sonarsim.dataset.load_scenario` reads.
    start, stop : int
        Frame range; ``stop=None``: to the scenario's last frame. Clipped to the scenario.
    labels : bool or {"total", "all", "none"}
        With ground truth (``frame.labels``) where the renderer provides it (:func:`label_mode`):
        the total's instance map with the elevation maps, points and boxes (default), also an
        instance map per component (``"all"``, ``True``), or none.
    threads : int, optional
        Ray-casting threads per simulator (default: the scene's ``render.threads``).

    Yields
    ------
    Frame
    """
    scenario = as_scenario(scenario)
    label_mode(labels)  # a bad value fails here, not at the first frame
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
        raise ValueError(f"start must be a frame index >= 0, got {start!r}")
    with SimulatorCache(threads=threads) as cache:
        for spec in scenario.frame_specs(int(start), stop):
            yield Frame(spec, render_frame(spec, cache, labels))
