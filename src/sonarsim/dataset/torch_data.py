"""PyTorch datasets over sonarsim datasets: a folder on disk, or frames rendered on the fly.

Needs PyTorch (``pip install 'sonarsim[torch]'``), but this module imports without it: torch
is imported by the functions and classes that use it, and the two dataset classes are built on
first access (a missing torch is then a :class:`~sonarsim.errors.SonarsimError` saying what to
install, not an ``ImportError`` at ``import sonarsim.dataset.torch_data``).

* :class:`SonarDatasetFolder` (a ``torch.utils.data.Dataset``): frame ``k`` of a finished
  dataset folder written by :func:`sonarsim.dataset.generate`, read from its files;
* :class:`RenderedFrames` (a ``torch.utils.data.IterableDataset``): a scenario's frames
  rendered and encoded in memory as :func:`~sonarsim.dataset.generate` would write them, each
  DataLoader worker rendering its share;
* :func:`frame_sample`: the one function both use to turn a frame's file bytes and manifest
  record into a sample, so a rendered sample equals the folder's for the same frame and options;
* :func:`collate`: a DataLoader ``collate_fn`` that stacks the images and keeps the detection
  targets as a list (frames have different numbers of objects).

A sample is a dict::

    {"image": uint8 (H, W)            the PNG coco.json names (frames/NNNNNN_fan.png, or _polar.png
                                      with coco="polar"); far range at the top
     "polar": float32 (n_range_bins, n_beams)   the device image, as in the NPZ
     "instance": int32 (n_range_bins, n_beams)  with ground truth: the total's instance map (-1 none)
     "elevation_deg": float32 (n_range_bins, n_beams)   with ground truth (NaN where nothing lands)
     "target": {"boxes": float32 (N, 4), "labels": int64 (N,), "masks": uint8 (N, H, W), "frame": int}
     "frame": int, "time_s": float}

``target`` is a torchvision-style detection target of the objects ``coco.json`` annotates in
that image: ``boxes`` ``[x_min, y_min, x_max, y_max]`` in the image's pixels (COCO's ``[x, y,
w, h]`` as ``[x, y, x + w, y + h]``: ``x_max`` is the last column + 1), ``labels`` the category
ids as ``coco.json`` numbers them, ``masks`` (with ``masks=True``) each annotation's pixels
decoded from its run-length encoding. A dataset without ground truth (``labels="none"``) has no
``instance``, ``elevation_deg`` or ``target``, and no ``image`` unless it has PNGs.
"""

from __future__ import annotations

import hashlib
import io
import json
import operator
import os
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ConfigError, SonarsimError, regular_file_bytes, shown

if TYPE_CHECKING:
    from .encoding import DatasetOptions
    from .scenario import Scenario

__all__ = ["RenderedFrames", "SonarDatasetFolder", "collate", "frame_sample", "rle_mask"]


# Arrays of a frame's NPZ that a sample carries (the rest -- points, component images -- stay
# in the file: loading them would cost every sample for what few training loops use).
_SAMPLE_ARRAYS = {"polar": np.float32, "instance": np.int32, "elevation_deg": np.float32}


def _import_torch() -> Any:
    """The ``torch`` module, or a SonarsimError saying how to install it."""
    try:
        import torch
    except ImportError as exc:
        from ..core.extras import install_command

        raise SonarsimError(f"sonarsim.dataset.torch_data needs PyTorch ({exc}): {install_command('torch')}") from None
    return torch


# The samples ---------------------------------------------------------------------------------

def _npz_arrays(data: bytes, name: str) -> dict[str, np.ndarray]:
    """The sample's arrays of an NPZ's bytes (only those are decompressed)."""
    from ..io.output import _check_npz_sizes

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            # A folder may come from elsewhere: refuse arrays whose headers declare more than
            # the memory budget before NumPy allocates them (as read_npz does).
            _check_npz_sizes(archive.zip, name)
            return {key: np.asarray(archive[key], dtype=dtype) for key, dtype in _SAMPLE_ARRAYS.items()
                    if key in archive.files}
    except (OSError, ValueError, EOFError) as exc:
        raise SonarsimError(f"{name}: not a readable NPZ ({exc})") from None


def _png_array(data: bytes, name: str) -> np.ndarray:
    """An 8-bit grey PNG's pixels, (H, W) uint8."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as png:
            # np.array copies: the tensor made from it must own writable memory.
            return np.array(png if png.mode == "L" else png.convert("L"), dtype=np.uint8)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise SonarsimError(f"{name}: not a readable PNG ({exc})") from None


def rle_mask(segmentation: Mapping[str, Any]) -> np.ndarray:
    """The pixels of COCO's uncompressed run-length encoding as a (height, width) uint8 mask.

    ``counts`` are the lengths of alternating runs of background (first) and object down each
    column, columns left to right (:func:`sonarsim.dataset.coco.rle`); what ``pycocotools``'
    ``annToMask`` gives for it.
    """
    h, w = (int(v) for v in segmentation["size"])
    counts = np.asarray(segmentation["counts"], dtype=np.int64)
    if counts.ndim != 1 or (counts < 0).any() or int(counts.sum()) != h * w:
        raise SonarsimError(f"a segmentation's counts do not cover its {h} x {w} pixels")
    flat = np.repeat((np.arange(counts.size) % 2).astype(np.uint8), counts)
    return flat.reshape(w, h).T.copy()  # column-major runs


def frame_sample(files: Mapping[str, bytes], record: Mapping[str, Any], image: str,
                 categories: Mapping[str, int], masks: bool = False) -> dict[str, Any]:
    """One frame's sample from its files' bytes and its manifest record (no file is opened).

    Parameters
    ----------
    files : mapping of str to bytes
        The frame's files by their names in ``record["files"]`` (relative to the dataset
        folder): at least its NPZ and, when it has one, the PNG ``coco.json`` names.
    record : mapping
        Its manifest line (:mod:`sonarsim.dataset.manifest`): ``frame``, ``time_s``, ``files``
        and, with ground truth, ``boxes`` and the image's shape (``fan_shape`` or
        ``polar_shape``).
    image : {"fan", "polar"}
        The dataset's ``coco`` option: the PNG that ``coco.json`` names and whose pixels the
        boxes are in.
    categories : mapping of str to int
        Category name to id (``coco.json``'s ``categories``; the datasets' ``categories``).
    masks : bool
        Also decode each annotation's mask (``target["masks"]``).

    Returns
    -------
    dict
        ``image`` uint8 tensor (H, W) (the PNG, far range at the top; absent for a frame without
        that PNG), ``polar`` float32 tensor (n_range_bins, n_beams) (the device image: a sensor
        model's counts, or a render's linear intensity), ``instance`` int32 and
        ``elevation_deg`` float32 tensors like ``polar`` (with ground truth), ``target`` (with
        ground truth: ``boxes`` float32 (N, 4) ``[x_min, y_min, x_max, y_max]`` pixels of
        ``image``, ``x_max``/``y_max`` exclusive; ``labels`` int64 (N,); ``masks`` uint8
        (N, H, W) with ``masks``; ``frame`` int), ``frame`` int and ``time_s`` float (seconds
        from the trajectory's start). The annotations are ``coco.json``'s for the frame, in
        its order (:func:`~sonarsim.dataset.coco.coco_from_records` of this record).

    Raises
    ------
    SonarsimError
        A file missing from ``files`` or unreadable, a category not in ``categories``.
    """
    from .coco import coco_from_records
    from .encoding import COCO_IMAGES

    torch = _import_torch()
    if image not in COCO_IMAGES:
        raise ConfigError("image", f"allowed: {', '.join(COCO_IMAGES)}; got {shown(image)}")
    k = int(record["frame"])
    names = list(record["files"])

    def content(name: str) -> bytes:
        try:
            return files[name]
        except KeyError:
            raise SonarsimError(f"frame {k}: no bytes given for its file {name}") from None

    npz = next((n for n in names if n.endswith(".npz")), None)
    if npz is None:
        raise SonarsimError(f"frame {k}: its record names no NPZ (files {shown(names)})")
    sample: dict[str, Any] = {}
    png = next((n for n in names if n.endswith(f"_{image}.png")), None)
    if png is not None:
        sample["image"] = torch.from_numpy(_png_array(content(png), png))
    for key, value in _npz_arrays(content(npz), npz).items():
        sample[key] = torch.from_numpy(value)
    if "boxes" in record:  # a frame with ground truth: coco.json's annotations of it
        doc = coco_from_records([record], image=image)
        local = {c["id"]: c["name"] for c in doc["categories"]}
        boxes, labels, pixels = [], [], []
        for ann in doc["annotations"]:
            name = local[ann["category_id"]]
            if name not in categories:
                raise SonarsimError(f"frame {k}: category {name!r} is not among the dataset's categories "
                                    f"({', '.join(map(repr, categories)) or 'none'})")
            x, y, w, h = ann["bbox"]
            boxes.append([x, y, x + w, y + h])
            labels.append(int(categories[name]))
            if masks:
                pixels.append(rle_mask(ann["segmentation"]))
        target: dict[str, Any] = {
            "boxes": torch.tensor(boxes, dtype=torch.float32).reshape(-1, 4),
            "labels": torch.tensor(labels, dtype=torch.int64),
        }
        if masks:
            shape = record.get(f"{image}_shape") or [0, 0]
            stack = np.stack(pixels) if pixels else np.zeros((0, *(int(v) for v in shape)), np.uint8)
            target["masks"] = torch.from_numpy(stack)
        target["frame"] = k
        sample["target"] = target
    sample["frame"] = k
    sample["time_s"] = float(record["time_s"])
    return sample


def collate(batch: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """A DataLoader ``collate_fn`` for samples of :func:`frame_sample`.

    Tensors are stacked along a new first axis (``image`` (B, H, W), ``polar``, ``instance``,
    ``elevation_deg`` (B, n_range_bins, n_beams): the frames must share their sizes, which a
    scenario that varies the sonar's does not); ``frame`` becomes an int64 tensor (B,),
    ``time_s`` a float64 tensor (B,); ``target`` stays a list of B dicts (their N differ),
    as torchvision's detection models take them.
    """
    torch = _import_torch()
    if not batch:
        return {}
    out: dict[str, Any] = {}
    for key in batch[0]:
        values = [sample[key] for sample in batch]
        if key != "target" and all(isinstance(v, torch.Tensor) for v in values):
            out[key] = torch.stack(values)
        elif all(isinstance(v, int) and not isinstance(v, bool) for v in values):
            out[key] = torch.tensor(values, dtype=torch.int64)
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
            out[key] = torch.tensor(values, dtype=torch.float64)  # times of long runs need float64
        else:
            out[key] = values
    return out


# A dataset folder ----------------------------------------------------------------------------

def _json_file(path: Path, what: str) -> Any:
    data = regular_file_bytes(path, what)
    if data is None:
        raise SonarsimError(f"{path}: {what} not found; {path.parent} is not a finished sonarsim dataset "
                            "folder (sonarsim.dataset.generate writes one)")
    try:
        return json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise SonarsimError(f"{path}: not a readable {what} ({exc})") from None


class _FolderBody:
    """Frame ``k`` of a finished dataset folder (:func:`sonarsim.dataset.generate`), read from
    its files: a map-style ``torch.utils.data.Dataset``.

    ``dataset.json``, ``manifest.jsonl`` and ``coco.json`` are read once, here; each item reads
    the frame's NPZ and the PNG ``coco.json`` names, checks them against the manifest's sha256
    and returns :func:`frame_sample` of them. The dataset holds no open file, so it pickles to
    DataLoader workers (any start method).

    Parameters
    ----------
    root : path
        The dataset folder.
    masks : bool
        Also decode each object's mask (``target["masks"]``, uint8 (N, H, W)).
    transform : callable, optional
        Applied to each sample dict before it is returned.

    Attributes
    ----------
    root : Path
    categories : dict of str to int
        Category name to id, as ``coco.json`` numbers them (empty without ground truth).
    image : {"fan", "polar"}
        The PNG of each frame ``coco.json`` names (the dataset's ``coco`` option).
    records : list of dict
        The manifest's lines in frame order.

    Raises
    ------
    SonarsimError
        Naming the file: no ``dataset.json`` or ``manifest.jsonl`` (not a dataset folder), a
        manifest without every frame (an unfinished run: run ``generate`` again to finish),
        a damaged line, no ``coco.json`` for a dataset with ground truth.

    Examples
    --------
    ::

        from torch.utils.data import DataLoader
        from sonarsim.dataset.torch_data import SonarDatasetFolder, collate

        data = SonarDatasetFolder("orbit", masks=True)   # a folder made by `sonarsim dataset`
        for batch in DataLoader(data, batch_size=8, shuffle=True, num_workers=2, collate_fn=collate):
            images, targets = batch["image"], batch["target"]   # (8, H, W) uint8; 8 dicts
    """

    def __init__(self, root: str | os.PathLike, masks: bool = False,
                 transform: Callable[[dict[str, Any]], Any] | None = None) -> None:
        from .manifest import INFO_NAME, MANIFEST_NAME, ManifestLines, scan_manifest, seal_record
        from .writer import COCO_NAME

        self.root = Path(root)
        self.masks = bool(masks)
        self.transform = transform
        info_path = self.root / INFO_NAME
        info = _json_file(info_path, "dataset description")
        n = info.get("n_frames") if isinstance(info, dict) else None
        options = info.get("options") if isinstance(info, dict) else None
        if isinstance(n, bool) or not isinstance(n, int) or n < 0 or not isinstance(options, dict):
            raise SonarsimError(f"{info_path}: not a sonarsim dataset description (no n_frames or options)")
        self.image = str(options.get("coco", "fan"))
        labelled = options.get("labels", "total") != "none"

        manifest_path = self.root / MANIFEST_NAME
        if not os.path.lexists(manifest_path):
            raise SonarsimError(f"{manifest_path}: dataset manifest not found; {self.root} is not a finished "
                                "sonarsim dataset folder (sonarsim.dataset.generate writes one)")
        # Where each frame's line lies, not the records (60 kB a frame as objects: 6 GB for
        # 100,000 frames, and a copy in every spawned DataLoader worker).
        by_frame = ManifestLines(manifest_path)
        for offset, length, record in scan_manifest(manifest_path):
            if record is None:
                continue  # (a torn last line: its frame is missing, said below)
            # Each line carries its own checksum: a damaged line is said, not read as boxes.
            try:
                sealed = isinstance(record, dict) and seal_record(record)["check"] == record.get("check")
            except (TypeError, ValueError):
                sealed = False
            k = record.get("frame") if sealed else None
            if not sealed or isinstance(k, bool) or not isinstance(k, int):
                raise SonarsimError(f"{manifest_path}: a damaged line (its check fails); run "
                                    "sonarsim.dataset.generate on the folder again to redo its frame")
            by_frame.at[k] = (offset, length)
        missing = [k for k in range(n) if k not in by_frame]
        if missing:
            raise SonarsimError(f"{manifest_path}: holds {n - len(missing)} of the {n} frames {INFO_NAME} names "
                                f"(frame {missing[0]} missing): the dataset is not finished; run "
                                "sonarsim.dataset.generate on it again to finish it")
        self.lines, self.n_frames = by_frame, n

        self.categories: dict[str, int] = {}
        if labelled:
            coco_path = self.root / COCO_NAME
            from .coco import read_categories

            try:
                self.categories = {str(c["name"]): int(c["id"]) for c in read_categories(coco_path)}
            except (TypeError, KeyError, ValueError):
                raise SonarsimError(f"{coco_path}: no readable categories (each with a name and an id)") from None

    def __len__(self) -> int:
        return self.n_frames

    def __getitem__(self, k: int) -> Any:
        try:
            k = operator.index(k)
        except TypeError:
            raise TypeError(f"a frame index is an integer, got {type(k).__name__}") from None
        n = self.n_frames
        if not -n <= k < n:
            raise IndexError(f"frame {k} out of range: {self.root} holds {n} frames")
        record = self.lines.record(k % n)
        # The NPZ and the PNG coco.json names; a second PNG or YOLO labels are not read.
        wanted = [name for name in record["files"] if name.endswith((".npz", f"_{self.image}.png"))]
        files = {name: self._read(name, record) for name in wanted}
        sample = frame_sample(files, record, self.image, self.categories, self.masks)
        return self.transform(sample) if self.transform is not None else sample

    def _read(self, name: str, record: Mapping[str, Any]) -> bytes:
        """A frame's file, checked against the manifest's sha256 (half a millisecond a
        megabyte: a damaged file is said, naming it, rather than trained on)."""
        path = self.root / name
        data = regular_file_bytes(path, "dataset file")
        if data is None:
            raise SonarsimError(f"{path}: not found (the manifest names it); run sonarsim.dataset.generate "
                                "on the folder again to redo it")
        expected = (record.get("sha256") or {}).get(name)
        if expected is not None and hashlib.sha256(data).hexdigest() != expected:
            raise SonarsimError(f"{path}: its sha256 differs from the manifest's (damaged or changed); run "
                                "sonarsim.dataset.generate on the folder again to redo it")
        return data

    def __repr__(self) -> str:
        return f"SonarDatasetFolder({os.fspath(self.root)!r}, {len(self)} frames, image={self.image!r})"


# Frames rendered on the fly ------------------------------------------------------------------

class _RenderedBody:
    """A scenario's frames rendered and encoded on the fly: a ``torch.utils.data.IterableDataset``.

    Each frame is rendered as :func:`sonarsim.dataset.generate` renders it
    (:func:`~sonarsim.dataset.frames.render_frame`, ground truth for every component), encoded
    in memory (:func:`~sonarsim.dataset.encoding.encode_frame`: the NPZ and PNG bytes and the
    manifest record the folder would hold) and turned into :func:`frame_sample` of those bytes:
    a sample equals :class:`SonarDatasetFolder`'s for the same frame of a folder made from the
    same scenario with the same options.

    In a DataLoader worker (``torch.utils.data.get_worker_info()``) the dataset takes the frames
    ``k`` with ``k % num_workers == worker_id`` and renders them on one ray-casting thread
    (the workers share the cores); outside workers (``num_workers=0``) it renders them all with
    the scene's ``render.threads``. Each process builds its simulators once and keeps them
    between epochs (:class:`~sonarsim.dataset.frames.SimulatorCache`). A frame is a function of
    the scenario and its index alone (the scenario's seed gives each frame its seed), so the
    samples are the same whatever ``num_workers``; only their order differs: the DataLoader
    interleaves its workers' streams (with ``num_workers=0``, frame order).

    Parameters
    ----------
    scenario : Scenario, path or mapping
        A loaded scenario, or what :func:`~sonarsim.dataset.load_scenario` reads.
    start, stop : int
        Frames ``start .. stop - 1``; ``stop=None``: to the scenario's last. Clipped to it.
    options : DatasetOptions or mapping, optional
        What a frame's files hold (:class:`~sonarsim.dataset.encoding.DatasetOptions`; a
        mapping is its keyword arguments): ``labels``, ``coco`` (``"fan"``: ``image`` is the
        fan, ``"polar"``: the polar PNG), ``formats``, ``signatures``. Default the defaults
        (:func:`~sonarsim.dataset.generate`'s). ``ghosts`` is refused: the ghosts' categories
        are known only once rendered, so their ids would depend on the frames seen so far.
    masks : bool
        Also decode each object's mask (``target["masks"]``).
    transform : callable, optional
        Applied to each sample dict before it is yielded.

    Attributes
    ----------
    scenario : Scenario
    indices : range
        The frames this dataset yields (over all its workers).
    options : DatasetOptions
        As given, with ``classes`` the categories below.
    categories : dict of str to int
        Category name to id (from 1): the scenario's object categories
        (:func:`~sonarsim.dataset.coco.category_of` of each object's name, ``object<i>``
        unnamed) in order of first appearance over the scene documents of frames
        ``0 .. stop - 1``. ``generate`` numbers ``coco.json``'s categories the same way (its
        class table, over the folder's frames), so a category has the same id in both; a folder
        made with ``ghosts`` adds ghost categories after them, and a ``coco.json`` written by
        another version may number them in order of first appearance among annotated objects
        instead: map by name (``categories`` of both datasets) where they could differ.

    Raises
    ------
    ConfigError
        Bad options (naming the key); frames that would not fit the memory budget.
    ValueError
        A bad ``start`` or ``stop``.

    Examples
    --------
    ::

        from torch.utils.data import DataLoader
        from sonarsim.dataset.torch_data import RenderedFrames, collate

        data = RenderedFrames("examples/scenarios/orbit_tank.yaml", stop=64)
        for batch in DataLoader(data, batch_size=8, num_workers=4, collate_fn=collate):
            batch["polar"].shape, batch["frame"]   # (8, n_range_bins, n_beams); which frames
    """

    def __init__(self, scenario: Scenario | str | os.PathLike | Mapping, start: int = 0, stop: int | None = None,
                 options: DatasetOptions | Mapping[str, Any] | None = None, masks: bool = False,
                 transform: Callable[[dict[str, Any]], Any] | None = None) -> None:
        from .coco import scenario_categories
        from .encoding import DatasetOptions
        from .frames import as_scenario, require_dataset_memory

        self.scenario = as_scenario(scenario)
        for name, value in (("start", start), ("stop", stop)):
            if value is None and name == "stop":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be a frame index >= 0, got {value!r}")
        n = self.scenario.n_frames
        end = n if stop is None else min(int(stop), n)
        self.indices = range(int(start), max(int(start), end))
        if options is None:
            options = DatasetOptions()
        elif isinstance(options, Mapping):
            options = DatasetOptions(**options)
        elif not isinstance(options, DatasetOptions):
            raise TypeError(f"options must be DatasetOptions or a mapping, got {type(options).__name__}")
        if options.ghosts:
            raise ConfigError("ghosts", "not with RenderedFrames: the ghosts' categories appear as frames render, "
                              "so their ids would depend on the frames each worker has seen; read a folder made "
                              "with ghosts (SonarDatasetFolder) instead")
        require_dataset_memory(self.scenario, options.labels)  # before any worker starts
        # The class table generate gives the same scenario (first appearance, frame order):
        # over frames 0 .. end - 1, which holds every frame yielded, and numbers each category
        # as any folder of this scenario does (a longer prefix only adds categories after).
        names = scenario_categories(self.scenario.frame_specs(0, end))
        self.options = replace(options, classes=names)
        self.categories = {name: i + 1 for i, name in enumerate(names)}
        self.width = max(6, len(str(n - 1)))  # digits of the file names, as generate's
        self.masks = bool(masks)
        self.transform = transform
        self._cache: Any = None
        self._cache_pid: int | None = None

    def __len__(self) -> int:
        return len(self.indices)

    def _simulators(self, threads: int | None) -> Any:
        """This process's simulator cache (a forked worker must not use its parent's: the
        simulators' thread pools do not survive a fork)."""
        from .frames import SimulatorCache

        if self._cache is None or self._cache_pid != os.getpid():
            self._cache, self._cache_pid = SimulatorCache(threads=threads), os.getpid()
        return self._cache

    def __iter__(self) -> Iterator[Any]:
        from .workers import rendered_frames

        torch = _import_torch()
        info = torch.utils.data.get_worker_info()
        worker, workers = (0, 1) if info is None else (info.id, info.num_workers)
        mine = [k for k in self.indices if k % workers == worker]
        cache = self._simulators(None if info is None else 1)
        # generate's own render-and-encode loop (without a folder: the bytes stay in memory),
        # each frame encoded on a writer thread while the next renders.
        for encoded in rendered_frames(mine, self.scenario, self.options, self.width, cache):
            sample = frame_sample(dict(encoded.files), encoded.record, self.options.coco, self.categories,
                                  self.masks)
            yield self.transform(sample) if self.transform is not None else sample

    def close(self) -> None:
        """Close this process's simulators (their ray-casting threads stop); the next iteration
        builds them again."""
        if self._cache is not None and self._cache_pid == os.getpid():
            self._cache.close()
        self._cache = self._cache_pid = None

    def __getstate__(self) -> dict[str, Any]:
        # Simulators stay in the process that built them; a worker builds its own.
        return {**self.__dict__, "_cache": None, "_cache_pid": None}

    def __repr__(self) -> str:
        return (f"RenderedFrames({self.scenario.source or 'scenario'!r}, frames [{self.indices.start}, "
                f"{self.indices.stop}), image={self.options.coco!r})")


# The classes, built on first access ------------------------------------------------------------

# Name -> (body, base class in torch.utils.data). The classes subclass torch's, so they are made
# when first asked for (torch imported then); this module imports without torch.
_LAZY = {"SonarDatasetFolder": (_FolderBody, "Dataset"), "RenderedFrames": (_RenderedBody, "IterableDataset")}
_BUILD_LOCK = threading.Lock()


def __getattr__(name: str) -> Any:
    """:class:`SonarDatasetFolder` and :class:`RenderedFrames`, made at first access (a
    SonarsimError without torch). Named as module attributes, so pickle finds them in a
    DataLoader worker started by spawn or forkserver."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    torch = _import_torch()
    with _BUILD_LOCK:  # one class per name: pickle checks it is the module's
        cls = globals().get(name)
        if cls is None:
            body, base = _LAZY[name]
            cls = type(name, (body, getattr(torch.utils.data, base)),
                       {"__module__": __name__, "__qualname__": name, "__doc__": body.__doc__})
            globals()[name] = cls
    return cls


if TYPE_CHECKING:  # for type checkers and editors: the classes' own bodies
    SonarDatasetFolder = _FolderBody
    RenderedFrames = _RenderedBody
