"""One frame of a dataset encoded: its files' bytes and its manifest record.

What a worker does with a rendered frame (:mod:`sonarsim.dataset.workers`) and what
:func:`~sonarsim.dataset.writer.generate` checks and writes: the options that shape a frame's
files (:class:`DatasetOptions`), their names (:func:`frame_files`), their bytes
(:func:`encode_frame`, :func:`npz_bytes`) and their atomic writing. Apart from the writer so
that the workers need not import it (the writer starts the workers). Everything here is also
importable from :mod:`sonarsim.dataset.writer`, where it was defined before.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, SonarsimError, shown
from .frames import frame_arrays, label_mode, labels_supported
from .manifest import frame_header
from .scenario import FrameSpec

__all__ = ["COCO_IMAGES", "FORMATS", "FRAMES_DIR", "DatasetOptions", "EncodedFrame", "encode_frame", "frame_files",
           "npz_bytes"]

#: File formats per frame: ``npz`` (always), ``png`` (polar and fan images, 8-bit: a sensor
#: model's output in the device's counts, a render without one in dB) and ``yolo`` (a label
#: file beside the PNG that ``coco.json`` names, and ``data.yaml``: :mod:`sonarsim.dataset.yolo`;
#: with ground truth only).
FORMATS = ("npz", "png", "yolo")
#: The images ``coco.json`` names and boxes: each frame's fan PNG (boxes in fan pixels, the
#: default) or its polar PNG (boxes in polar pixels). A dataset with ground truth always
#: writes that PNG, so that every ``file_name`` in ``coco.json`` is a file of the dataset.
COCO_IMAGES = ("fan", "polar")
#: Name of the frames' folder inside a dataset folder.
FRAMES_DIR = "frames"
# dB window of the PNGs and of the bag's 8-bit fan of a render without a sensor model (`render`'s default).
_DYNAMIC_RANGE_DB = 40.0
# Entries stored without compression: float coordinates and axes, which deflate shrinks by
# 1.3x at most (points_world: 0.6 ms of a frame's encoding for nothing); every image and label
# map compresses 6-150x and is deflated.
_STORED_ENTRIES = frozenset({"points_world", "range_m", "azimuth_deg"})


@dataclass(frozen=True)
class DatasetOptions:
    """What shapes a dataset's files (part of its fingerprint). Validated on construction.

    Attributes
    ----------
    labels : {"total", "all", "none"}
        Ground truth from the renderer (stored in the NPZs, boxes in the manifest and
        ``coco.json``): the total's instance map, the elevation maps, the points and boxes
        (``"total"``, the default: issue 12's contract), also the component images and an
        instance map per component (``"all"``), or none (the device image alone)
        (:func:`~sonarsim.dataset.frames.label_mode`; ``True``/``False`` are taken for
        ``"all"``/``"none"``). A renderer without labels: ``"none"``.
    formats : tuple of str
        Subset of :data:`FORMATS`; ``npz`` is always written; ``yolo`` needs ground truth.
    rosbag : {None, "mcap", "sqlite3"}
        Write ``DIR/rosbag`` with this storage.
    signatures : bool
        Also store one image per path signature in the NPZs
        (:func:`~sonarsim.dataset.frames.frame_arrays`), and the component table's images.
    coco : {"fan", "polar"}
        The image of each frame that ``coco.json`` names, and whose pixels its boxes are in
        (:data:`COCO_IMAGES`); with ground truth that PNG is written even without ``png`` in
        ``formats``.
    ghosts : bool
        Also annotate each object's multipath ghosts in ``coco.json``, one annotation per path
        signature (:mod:`sonarsim.dataset.coco`); the boxes are the direct echoes' either way.
    classes : tuple of str
        The object categories in id order (:func:`~sonarsim.dataset.coco.scenario_categories`),
        which YOLO's class numbers index; set by :func:`~sonarsim.dataset.generate` from the
        scenario (not an option of the user's: the scenario, in the fingerprint, fixes it).
    encoder : str
        The deflate encoder the dataset's fingerprint names (:data:`sonarsim.io.codec.ENCODER`
        of the process that started the run), set by :func:`~sonarsim.dataset.generate`; a
        worker whose own differs (another zlib-ng, another architecture: other bytes for the
        same frame) refuses to encode. Empty: not checked.
    """

    labels: bool | str = "total"
    formats: tuple[str, ...] = ("npz",)
    rosbag: str | None = None
    signatures: bool = False
    coco: str = "fan"
    ghosts: bool = False
    classes: tuple[str, ...] = ()
    encoder: str = ""

    def __post_init__(self) -> None:
        from ..io.rosbag import BAG_STORAGES

        formats = (self.formats,) if isinstance(self.formats, str) else tuple(self.formats)
        bad = [f for f in formats if f not in FORMATS]
        if bad:
            raise ConfigError("formats", f"allowed: {', '.join(FORMATS)}; got {shown(bad[0])}")
        object.__setattr__(self, "formats", tuple(f for f in FORMATS if f in formats or f == "npz"))
        if self.rosbag is not None and self.rosbag not in BAG_STORAGES:
            raise ConfigError("rosbag", f"allowed: {', '.join(BAG_STORAGES)} (or none); got {shown(self.rosbag)}")
        # What this renderer can do: a dataset asked for labels on a renderer without them is
        # an image-only dataset, and says so in its fingerprint.
        mode = label_mode(self.labels)
        object.__setattr__(self, "labels", mode if labels_supported() else "none")
        if not isinstance(self.signatures, bool):
            raise ConfigError("signatures", f"must be true or false, got {shown(self.signatures)}")
        if self.coco not in COCO_IMAGES:
            raise ConfigError("coco", f"allowed: {', '.join(COCO_IMAGES)}; got {shown(self.coco)}")
        if not isinstance(self.ghosts, bool):
            raise ConfigError("ghosts", f"must be true or false, got {shown(self.ghosts)}")
        if "yolo" in self.formats and self.labels == "none":
            raise ConfigError("formats", "yolo labels need ground truth: labels 'total' or 'all', not 'none'")
        classes = (self.classes,) if isinstance(self.classes, str) else tuple(self.classes)
        object.__setattr__(self, "classes", tuple(str(c) for c in classes))

    def document(self) -> dict[str, Any]:
        """The options as JSON (``dataset.json`` and the fingerprint). ``boxes: direct`` marks
        datasets whose boxes are the direct echoes' (a folder made before, whose boxes spanned
        the ghosts, is another dataset). ``deflate`` names the compressor of the NPZs and PNGs (its bytes are the
        dataset's: a folder written by another encoder is another dataset, not resumed with
        these)."""
        from ..io.png import PNG_ENCODER

        doc = {"labels": self.labels, "formats": list(self.formats), "rosbag": self.rosbag,
               "signatures": self.signatures, "coco": self.coco, "boxes": "direct", "ghosts": self.ghosts,
               "deflate": PNG_ENCODER}
        if "yolo" in self.formats:
            # The outlines are contourpy's (sonarsim.dataset.yolo): another version may order
            # a polygon's vertices otherwise, so it is part of what the label files are.
            from .yolo import OUTLINE_TRACER

            doc["yolo_outlines"] = OUTLINE_TRACER
        return doc

    @property
    def pngs(self) -> tuple[str, ...]:
        """The PNGs of each frame (``"polar"``, ``"fan"``): both with ``png`` in ``formats``;
        otherwise, with ground truth, the one ``coco.json`` names."""
        if "png" in self.formats:
            return ("polar", "fan")
        return (self.coco,) if self.labels != "none" else ()


def frame_files(k: int, width: int, options: DatasetOptions) -> list[str]:
    """Files of frame ``k``, relative to the dataset folder, in manifest order."""
    stem = f"{FRAMES_DIR}/{k:0{width}d}"
    yolo = [f"{stem}_{options.coco}.txt"] if "yolo" in options.formats else []
    return [f"{stem}.npz"] + [f"{stem}_{kind}.png" for kind in options.pngs] + yolo


def npz_bytes(arrays: Mapping[str, np.ndarray], config: Mapping[str, Any]) -> bytes:
    """The NPZ of ``arrays`` and ``config`` (as :func:`sonarsim.io.output.write_npz` stores
    them), whose bytes depend on the content alone (:func:`sonarsim.io.npz.encode_npz`: fixed
    entry dates, zlib deflate; float coordinates and axes stored).

    ``numpy.savez_compressed`` stamps each entry with the current time, so two runs would
    write different files for the same frame; :func:`sonarsim.io.output.read_npz` and
    ``numpy.load`` read these files alike.
    """
    from ..io.npz import encode_npz
    from ..io.output import npz_payload

    return encode_npz(npz_payload(arrays, config), stored=_STORED_ENTRIES)


def _png_bytes(image_uint8: np.ndarray) -> bytes:
    from ..io.png import gray_png_bytes

    return gray_png_bytes(image_uint8)


def _image_png(image: Any, kind: str) -> bytes:
    """A frame's polar or fan image as an 8-bit PNG, as ``sonarsim render`` draws them: a sensor
    model's output in the device's counts (an 8-bit device's values as they are, as a real
    recording shows), a render without one in dB (:func:`~sonarsim.image.levels.default_levels`);
    the far range at the top; the fan of :meth:`SonarImage.fan`, whose pixels the fan boxes are in,
    its levels made on the polar grid and resampled (:func:`~sonarsim.image.levels.default_fan_levels`)."""
    from ..image.levels import default_fan_levels, default_levels

    if kind == "polar":
        return _png_bytes(default_levels(image, image.polar[::-1], dynamic_range_db=_DYNAMIC_RANGE_DB))
    return _png_bytes(default_fan_levels(image, dynamic_range_db=_DYNAMIC_RANGE_DB))


@dataclass(frozen=True)
class EncodedFrame:
    """A frame ready to be written: its files' bytes and its manifest record (unsealed).

    Attributes
    ----------
    index : int
    files : tuple of (str, bytes)
        Relative path and content of each file, in :func:`frame_files` order.
    record : dict
        The manifest line (see :mod:`sonarsim.dataset.manifest`), with sizes and checksums.
    seconds : dict
        ``render`` and ``encode`` times of the frame, seconds (not part of the record).
    """

    index: int
    files: tuple[tuple[str, bytes], ...]
    record: dict
    seconds: dict = field(default_factory=dict)


def _signature_order(signature: str) -> int:
    """The order of a path signature (``O-surface-[objects]-surface-O``: 3): its surfaces."""
    return len(signature.split("-")) - 2


def _annotated(id_map: np.ndarray, image: Any, n_objects: int, names: tuple[str, ...], coco: str,
               path: str | None = None, outlines: bool = False) -> list[dict]:
    """Per object of ``id_map`` (polar cells: ids, -1 none): its polar and fan boxes, and its
    pixels in the image ``coco.json`` names (RLE) with their count; with ``outlines``, their
    outline in that image's pixels too (``outline``: :func:`sonarsim.dataset.yolo.outline`, for
    the YOLO labels; not part of the manifest record)."""
    from ..image.labels import boxes_of
    from ..image.result import _fan_mapper
    from .coco import fan_boxes, rle_window

    n_ids = len(names)
    grid = image.sonar.grid
    polar = boxes_of(id_map, n_ids)
    # The boxes of SonarImage.fan_labels(), without resampling the maps (a test compares them).
    fan = fan_boxes(id_map, grid, n_ids)
    present = [k for k in range(min(n_objects, n_ids)) if polar[k][0] >= 0]
    if not present:
        return []
    if coco == "fan":
        # Resampled by nearest neighbour, as the boxes are: each object's box alone
        # (FanMapper.window_ids), not the whole fan.
        mapper = _fan_mapper(grid, None, "nearest")
        pixels = None
    else:
        pixels = id_map[::-1]  # the polar PNG: far range at the top
    out = []
    for k in present:
        entry: dict[str, Any] = {"id": k, "name": str(names[k]), "polar": [int(v) for v in polar[k]],
                                 "fan": [int(v) for v in fan[k]]}
        if path is not None:
            entry["path"] = path
        if coco == "fan":
            box = fan[k]
        else:
            h = id_map.shape[0]
            box = [h - 1 - polar[k][2], polar[k][1], h - 1 - polar[k][0], polar[k][3]]
        if box[0] >= 0:
            r0, c0, r1, c1 = (int(v) for v in box)
            window = mapper.window_ids(id_map, box) if coco == "fan" else pixels[r0:r1 + 1, c0:c1 + 1]
            shape = mapper.shape if coco == "fan" else pixels.shape
            entry["segmentation"], entry["area"] = rle_window(window, k, box, shape)
            if outlines:
                from .yolo import outline

                entry["outline"] = outline(np.asarray(window) == k, (r0, c0))
        out.append(entry)
    return out


def _annotations(spec: FrameSpec, image: Any, options: DatasetOptions) -> tuple[list[dict], list[dict], list[int] | None]:
    """A labelled frame's objects: their direct echoes (boxes and pixels), their ghosts per path
    signature (with ``options.ghosts``), and the fan's shape."""
    from ..image.result import _fan_mapper
    from ..renderer.components import order_name

    labels = getattr(image, "labels", None)
    if labels is None:
        return [], [], None
    n_objects = len(spec.scene.get("objects") or [])  # ids 0..K-1 are objects, then planes
    # The objects' single-bounce paths (the renderer's ``object`` map); the total's map would
    # give each object the cells of its ghosts too. A renderer without it: the total's.
    direct = labels.instance.get("object", labels.instance["total"])
    boxes = _annotated(np.asarray(direct), image, n_objects, labels.ids, options.coco,
                       outlines="yolo" in options.formats)
    ghosts: list[dict] = []
    if options.ghosts:
        components = image.components
        table = set(getattr(components, "table", None) or ())
        for signature in [name for name in components if name not in table]:
            order = _signature_order(signature)
            by_order = labels.instance.get(order_name(order))
            if order < 2 or "[objects]" not in signature or by_order is None:
                continue
            # Where an object dominates this order and this signature brings energy.
            ghost = np.where(np.asarray(components[signature]) > 0, by_order, -1)
            ghosts += _annotated(ghost, image, n_objects, labels.ids, options.coco, signature)
    return boxes, ghosts, [int(v) for v in _fan_mapper(image.sonar.grid, None, "nearest").shape]


def encode_frame(spec: FrameSpec, image: Any, options: DatasetOptions, width: int) -> EncodedFrame:
    """Encode a rendered frame's files and manifest record (done in the worker that rendered it).

    Parameters
    ----------
    spec : FrameSpec
        The frame rendered.
    image : SonarImage
        Its render (:func:`~sonarsim.dataset.frames.render_frame`).
    options : DatasetOptions
    width : int
        Digits of the frame number in file names.
    """
    t0 = time.perf_counter()
    if options.encoder:
        from ..io.codec import ENCODER

        if ENCODER != options.encoder:
            raise SonarsimError(f"frame {spec.index}: this worker's deflate is {ENCODER}, the dataset's {options.encoder}: "
                                "its bytes would differ from the other frames'; give every node the same zlib-ng "
                                "package and processor architecture")
    arrays = frame_arrays(image, options.signatures, components=options.labels == "all")
    config = dict(image.config)
    # A worker renders with its share of the cores: the scene's own setting goes in the file,
    # so that a frame's bytes do not depend on the number of workers.
    render = dict(config.get("render") or {})
    render["threads"] = (spec.scene.get("render") or {}).get("threads")
    config["render"] = render
    config["dataset"] = {"frame": spec.index, "seed": spec.seed, "time_s": spec.time_s}
    names = frame_files(spec.index, width, options)
    contents = [npz_bytes(arrays, config)] + [_image_png(image, kind) for kind in options.pngs]
    labelled = options.labels != "none"
    if labelled:
        boxes, ghosts, fan_shape = _annotations(spec, image, options)
        polar_shape = [int(v) for v in np.shape(image.polar)]
        if "yolo" in options.formats:
            contents.append(_yolo_labels(boxes, options, fan_shape if options.coco == "fan" else polar_shape))
    record: dict[str, Any] = {
        **frame_header(spec, names),
        "bytes": {n: len(c) for n, c in zip(names, contents)},
        "sha256": {n: hashlib.sha256(c).hexdigest() for n, c in zip(names, contents)},
    }
    if labelled:
        record["boxes"], record["fan_shape"] = boxes, fan_shape
        if options.ghosts:
            record["ghosts"] = ghosts
        record["polar_shape"] = polar_shape
    return EncodedFrame(spec.index, tuple(zip(names, contents)), record,
                        {"encode": time.perf_counter() - t0, **getattr(image, "timing", {})})


def _yolo_labels(boxes: list[dict], options: DatasetOptions, shape: list[int] | None) -> bytes:
    """The frame's YOLO label file from its direct echoes' outlines (taken out of the entries:
    the manifest record keeps boxes and masks, not polygons)."""
    from .coco import category_of
    from .yolo import label_text

    classes = {name: i for i, name in enumerate(options.classes)}
    objects = []
    for entry in boxes:
        ring = entry.pop("outline", None)
        if ring is None:
            continue
        category = category_of(entry["name"])
        if category not in classes:
            raise SonarsimError(f"object {entry['name']!r}: its category {category!r} is not in the dataset's class "
                                f"table ({', '.join(options.classes) or 'empty'}): the scene's objects must be listed "
                                "in its scene document for YOLO labels")
        objects.append((classes[category], ring))
    return label_text(objects, shape or (1, 1))


def _write_files(out: Path, encoded: EncodedFrame) -> None:
    from ..io.output import atomic_write

    for name, content in encoded.files:
        try:
            with atomic_write(out / name, "wb") as handle:
                handle.write(content)
        except OSError as exc:
            raise SonarsimError(f"{out / name}: cannot write: {exc.strerror or exc} (no partial file is left; "
                                "frames written so far are kept: run the same command again to resume)") from None
