"""A COCO-style JSON of the objects in a dataset's images, for detection and segmentation users.

One ``image`` per frame (``id`` = frame index, ``file_name`` the frame's PNG the annotations are
drawn on, relative to the dataset folder; ``width``/``height`` its size in pixels) and one
``annotation`` per object whose DIRECT echo (the object's single-bounce paths, the renderer's
``object`` instance map: :mod:`sonarsim.image.labels`) dominates at least one pixel of it:
``bbox`` = ``[x, y, width, height]`` in pixels (x the column, y the row), ``segmentation`` the
object's pixels as COCO's uncompressed run-length encoding (``{"size": [height, width],
"counts": [...]}``, column-major runs starting with background, what ``pycocotools`` reads),
``area`` the number of those pixels, ``iscrowd`` 0; ``object`` its name, ``path`` its path
signature (``O-[objects]-O``), ``ghost`` false. One ``category`` per object kind: objects that a
scenario's variation adds are named ``<group>_<i>`` (:mod:`sonarsim.dataset.variation`) and their
category is the group's name, so all rocks are one category. Planes (the ground, walls) are not
objects and get no annotation.

Multipath ghosts (with the dataset's ``ghosts`` option, ``sonarsim dataset --coco-ghosts``) are
annotations of their own, one per object and path signature (``O-surface-[objects]-surface-O``:
the echo of an object seen by way of the water surface), in categories named
``<category>/<signature>`` (supercategory the object's category), with ``ghost`` true: a
ghost's pixels are those where the object dominates the paths of the ghost's order and that
signature's image has energy. Without the option the ghosts get nothing, and a box never spans
them (the total's map would: a 0.3 m buoy's box 2.9-7.6 m long and 136 of 256 beams wide in
the demo's walled tank, against 2.9-3.0 m and 25 beams for its direct echo).

Two images, chosen by the dataset's ``coco`` option (``sonarsim dataset --coco``):

* ``fan`` (default): ``frames/NNNNNN_fan.png``, the fan of :meth:`SonarImage.fan` (one pixel
  per range resolution, the sonar at the bottom centre, row 0 the far range at the top, the
  left-most beam on the left); an object's pixels are those whose nearest polar cell it
  dominates;
* ``polar``: ``frames/NNNNNN_polar.png``, one column per beam (column 0 the left-most) and one
  row per range bin, row 0 the FARTHEST bin (far range at the top, as sonarsim draws polar
  images); an object's pixels are the cells it dominates.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Any

import numpy as np

from ..errors import SonarsimError

__all__ = ["DIRECT_PATH", "category_of", "coco_from_records", "fan_boxes", "rle", "read_categories", "scenario_categories", "write_coco"]

_NUMBERED = re.compile(r"^(?P<base>.+)_[0-9]+$")
#: The path signature of an object's direct echo (:mod:`sonarsim.renderer.components`).
DIRECT_PATH = "O-[objects]-O"


def rle(ids: np.ndarray, k: int, box: Any = None) -> tuple[dict[str, Any], int]:
    """COCO's uncompressed run-length encoding of the pixels of ``ids`` equal to ``k``.

    Parameters
    ----------
    ids : (height, width) int array
        An instance map in the image's pixels.
    k : int
    box : [row_min, col_min, row_max, col_max], optional
        Where those pixels lie (inclusive); only these columns are scanned.

    Returns
    -------
    segmentation : dict
        ``{"size": [height, width], "counts": [...]}``: the lengths of the alternating runs of
        background and of the object in column-major order (down each column, columns left to
        right), the first run background (0 when the first pixel is the object's).
    area : int
        The object's pixels.
    """
    h, w = ids.shape
    c0, c1 = (0, w - 1) if box is None else (int(box[1]), int(box[3]))
    # Column-major over the columns of the box; the columns before and after it are background.
    return _counts((ids[:, c0:c1 + 1] == k).T.reshape(-1), h, w, c0, c1)


def rle_window(window: np.ndarray, k: int, box: Any, shape: tuple[int, int]) -> tuple[dict[str, Any], int]:
    """:func:`rle` of an image of ``shape`` known only inside ``box``, which holds every pixel
    of id ``k``: ``window`` is the box's part of the instance map, everything outside it
    background. The counts :func:`rle` gives for the whole map, from the box's pixels alone
    (an instance map resampled for one object's box, not for the whole fan).

    Parameters
    ----------
    window : (row_max - row_min + 1, col_max - col_min + 1) int array
    k : int
    box : [row_min, col_min, row_max, col_max]
        Inclusive, within ``shape``.
    shape : (height, width)
    """
    h, w = int(shape[0]), int(shape[1])
    r0, c0, r1, c1 = (int(v) for v in box)
    columns = np.zeros((c1 - c0 + 1, h), bool)  # the box's columns, whole, column-major
    columns[:, r0:r1 + 1] = (np.asarray(window) == k).T
    return _counts(columns.reshape(-1), h, w, c0, c1)


def _counts(inside: np.ndarray, h: int, w: int, c0: int, c1: int) -> tuple[dict[str, Any], int]:
    """COCO's counts of an object's pixels: ``inside``, columns ``c0 .. c1`` of an ``h x w``
    image flattened column-major; the other columns background."""
    edges = np.flatnonzero(inside[1:] != inside[:-1]) + 1
    bounds = np.concatenate([[0], edges, [inside.size]])
    runs = np.diff(bounds).tolist()
    if inside.size and inside[0]:
        runs.insert(0, 0)  # COCO's counts start with background
    runs[0] += h * c0
    if len(runs) % 2:  # the last run is background: the columns after the box join it
        runs[-1] += h * (w - 1 - c1)
    elif c1 < w - 1:
        runs.append(h * (w - 1 - c1))
    return {"size": [int(h), int(w)], "counts": [int(r) for r in runs]}, int(np.count_nonzero(inside))


def category_of(name: str) -> str:
    """The category of an object named ``name``: the name less a trailing ``_<number>``."""
    match = _NUMBERED.match(name)
    return match["base"] if match else name


def scenario_categories(specs: Iterable[Any]) -> tuple[str, ...]:
    """The object categories of a scenario's frames, in order of first appearance: each frame's
    scene objects (:attr:`FrameSpec.scene`, ``objects[i].name``, ``object<i>`` unnamed, as the
    scene loader names them) in frame order, by :func:`category_of`. The one class table of a
    dataset: ``coco.json``'s category ids (from 1) and YOLO's class numbers (from 0) index it."""
    seen: dict[str, None] = {}
    for spec in specs:
        for i, obj in enumerate(spec.scene.get("objects") or []):
            name = obj.get("name", f"object{i}") if isinstance(obj, Mapping) else f"object{i}"
            seen.setdefault(category_of(str(name)), None)
    return tuple(seen)


def coco_from_records(records: Iterable[Mapping[str, Any]], image: str = "fan",
                      categories: Iterable[str] = ()) -> dict[str, Any]:
    """The COCO document of a dataset's manifest records (each with ``boxes``, see manifest).

    Parameters
    ----------
    records : iterable of mapping
        Manifest lines in frame order, each with ``files``, ``boxes`` and the image's shape
        (``fan_shape`` or ``polar_shape``, ``[height, width]``).
    image : {"fan", "polar"}
        The image ``file_name`` names and the boxes are in: the frame's ``*_fan.png`` (boxes
        from each box's ``fan`` pixels) or its ``*_polar.png`` (boxes from its ``polar`` cells,
        rows counted from the far range, as the PNG is drawn).
    categories : iterable of str
        The objects' categories to number first, in this order (:func:`scenario_categories`:
        the class table YOLO's labels share), whether or not any is annotated.

    Returns
    -------
    dict
        ``{"info", "images", "annotations", "categories"}``; category ids start at 1, those of
        ``categories`` first, then any other in order of first appearance (ghosts' categories
        among them); annotation ids at 1 in frame order (a frame's direct echoes, then its
        ghosts: a record's ``ghosts``).

    Raises
    ------
    ValueError
        ``image`` is neither.
    SonarsimError
        A record lacks that PNG or the image's shape (a manifest written before the COCO file
        named images; make the dataset again).
    """
    images, annotations = [], []
    table = _table(image, categories)
    for entry, found in _entries(records, image, table, 1):
        images.append(entry)
        annotations += found
    return {"info": _info(image), "images": images, "annotations": annotations, "categories": _categories(table)}


def write_coco(handle: Any, records: Callable[[], Iterable[Mapping[str, Any]]], image: str = "fan",
               categories: Iterable[str] = ()) -> None:
    """Write the COCO document of :func:`coco_from_records` to the text stream ``handle``, a
    frame at a time: the same text as its canonical JSON
    (:func:`~sonarsim.dataset.manifest.canonical_json`) and a newline, without the document in
    memory (``coco.json`` of 100,000 frames is half a GB of text, several of Python objects).

    Parameters
    ----------
    handle : text stream
    records : callable
        Each call gives the records anew, in frame order (they are read twice: annotations,
        then images, in the canonical document's key order).
    image, categories
        As :func:`coco_from_records`.
    """
    from .manifest import canonical_json

    table = _table(image, categories)
    handle.write('{"annotations":[')
    next_id = 1
    for _, found in _entries(records(), image, table, 1):
        for annotation in found:
            handle.write(("," if next_id > 1 else "") + canonical_json(annotation))
            next_id += 1
    handle.write('],"categories":' + canonical_json(_categories(table)) + ',"images":[')
    for i, (entry, _) in enumerate(_entries(records(), image, table, 1)):
        handle.write(("," if i else "") + canonical_json(entry))
    handle.write('],"info":' + canonical_json(_info(image)) + "}\n")


def read_categories(path: Any) -> list[dict[str, Any]]:
    """The ``categories`` of a ``coco.json``, without parsing its annotations (half a GB for
    100,000 frames): :func:`write_coco` writes them after the annotations, behind the one
    ``],"categories":`` of the file (a string in JSON cannot hold an unescaped quote, so no
    annotation text can look like it); any other COCO file is parsed whole.

    Raises
    ------
    SonarsimError
        A file that cannot be read or holds no categories, naming it.
    """
    import json

    marker = b'],"categories":'
    try:
        with open(path, "rb") as handle:
            head = handle.read(len('{"annotations":['))
            if head == b'{"annotations":[':
                tail = b""
                while True:
                    chunk = handle.read(1 << 20)
                    if not chunk:
                        break
                    tail = tail[-len(marker):] + chunk
                    at = tail.find(marker)
                    if at >= 0:
                        rest = tail[at + len(marker):] + handle.read(1 << 20)
                        return json.JSONDecoder().raw_decode(rest.decode("utf-8", "replace"))[0]
                # the empty list of annotations: '{"annotations":[' then '],"categories":' at once
            handle.seek(0)
            doc = json.load(handle)
        return doc["categories"]
    except FileNotFoundError:
        raise SonarsimError(f"{path}: COCO file not found") from None
    except (OSError, ValueError, TypeError, KeyError) as exc:
        raise SonarsimError(f"{path}: no readable categories: {exc}") from None


def _table(image: str, categories: Iterable[str]) -> dict[str, tuple[int, str]]:
    if image not in ("fan", "polar"):
        raise ValueError(f"image must be 'fan' or 'polar', got {image!r}")
    table: dict[str, tuple[int, str]] = {}
    for name in categories:
        table.setdefault(str(name), (len(table) + 1, "object"))
    return table


def _info(image: str) -> dict[str, str]:
    return {"description": f"sonarsim dataset: objects' direct echoes (and ghosts, if asked) in the {image} images",
            "version": "2"}


def _categories(table: Mapping[str, tuple[int, str]]) -> list[dict[str, Any]]:
    return [{"id": cid, "name": name, "supercategory": sup} for name, (cid, sup) in table.items()]


def _entries(records: Iterable[Mapping[str, Any]], image: str, table: dict[str, tuple[int, str]],
             first_id: int) -> Iterator[tuple[dict[str, Any], list[dict[str, Any]]]]:
    """Per record: its COCO image and its annotations (ids from ``first_id`` on), adding new
    categories to ``table`` as they appear."""
    next_id = first_id
    for record in records:
        k = int(record["frame"])
        name = next((f for f in record["files"] if f.endswith(f"_{image}.png")), None)
        shape = record.get(f"{image}_shape")
        if name is None or not shape:
            raise SonarsimError(f"frame {k}: the manifest names no {image} PNG or its shape (files "
                             f"{record['files']}); coco.json must name images that exist")
        height, width = (int(v) for v in shape)
        entry = {"id": k, "file_name": name, "height": height, "width": width, "time_s": record.get("time_s")}
        found = []
        boxes = [(box, False) for box in record.get("boxes") or []]
        boxes += [(box, True) for box in record.get("ghosts") or []]
        for box, ghost in boxes:
            if image == "fan":
                row0, col0, row1, col1 = (int(v) for v in box["fan"])
            else:
                # Cells [bin_min, beam_min, bin_max, beam_max]; the PNG's row 0 is the last bin.
                bin0, col0, bin1, col1 = (int(v) for v in box["polar"])
                row0, row1 = (height - 1 - bin1, height - 1 - bin0) if bin0 >= 0 else (-1, -1)
            if row0 < 0:  # dominates polar cells but no fan pixel (outside the fan's sampling)
                continue
            category = category_of(str(box["name"]))
            path = str(box.get("path", DIRECT_PATH))
            label = f"{category}/{path}" if ghost else category
            cid = table.setdefault(label, (len(table) + 1, category if ghost else "object"))[0]
            w, h = col1 - col0 + 1, row1 - row0 + 1
            annotation = {"id": next_id, "image_id": k, "category_id": cid,
                          "bbox": [col0, row0, w, h], "area": w * h, "iscrowd": 0,
                          "object": str(box["name"]), "path": path, "ghost": ghost}
            if "segmentation" in box:
                annotation["segmentation"], annotation["area"] = box["segmentation"], int(box["area"])
            found.append(annotation)
            next_id += 1
        yield entry, found


@functools.lru_cache(maxsize=8)
def _cell_extents(grid: Any, pixel_size_m: float | None) -> np.ndarray:
    """Per polar cell, the inclusive box ``[row_min, col_min, row_max, col_max]`` of the fan
    pixels whose nearest cell it is (the fan of :meth:`SonarImage.fan`); -1 for a cell that no
    pixel samples. (n_range_bins * n_beams, 4) int32, built once per grid."""
    from ..image.fan import FanMapper

    nearest = FanMapper.from_grid(grid, pixel_size_m, "nearest")
    n_cells = int(np.prod(nearest.polar_shape))
    # Cell index + 1 per pixel (float32 holds integers below 2**24 exactly); 0 outside the fan.
    cell = nearest(np.arange(1, n_cells + 1, dtype=np.float32).reshape(nearest.polar_shape)).image
    rows, cols = np.nonzero(cell)
    owner = cell[rows, cols].astype(np.int64) - 1
    out = np.full((n_cells, 4), -1, np.int64)
    big = np.iinfo(np.int64).max
    lo = np.full((n_cells, 2), big, np.int64)
    hi = np.full((n_cells, 2), -1, np.int64)
    np.minimum.at(lo, (owner, 0), rows)
    np.minimum.at(lo, (owner, 1), cols)
    np.maximum.at(hi, (owner, 0), rows)
    np.maximum.at(hi, (owner, 1), cols)
    seen = hi[:, 0] >= 0
    out[seen] = np.concatenate([lo[seen], hi[seen]], axis=1)
    return out.astype(np.int32)


def fan_boxes(instance: np.ndarray, grid: Any, n_ids: int, pixel_size_m: float | None = None) -> np.ndarray:
    """Boxes of each id in the fan image, from the polar instance map alone.

    Equal to the boxes of the instance map resampled to the fan by nearest neighbour
    (:meth:`SonarImage.fan_labels`), without resampling it: the pixels of an id are those whose
    nearest cell holds the id, so its box spans the boxes of its cells' pixels
    (:func:`_cell_extents`, built once per grid). 0.2 ms for 128 x 1288 cells (compiled; 4 ms
    for its NumPy twin), against tens of ms for the resampling.

    Parameters
    ----------
    instance : (n_range_bins, n_beams) int array
        Ids, -1 none.
    grid : PolarGrid
        The image's grid (``image.sonar.grid``).
    n_ids : int
    pixel_size_m : float, optional
        Fan pixel size; default the range resolution (as :meth:`SonarImage.fan`).

    Returns
    -------
    (n_ids, 4) int32 ndarray
        ``[row_min, col_min, row_max, col_max]`` inclusive fan pixels; -1 for an id with no pixel.
    """
    extents = _cell_extents(grid, pixel_size_m)
    from ..renderer import compiled

    if compiled.AVAILABLE:  # one pass over the cells (the reduction below: 4 ms on 128 x 1288)
        return compiled.id_extents(instance, extents, n_ids)
    return _id_extents(np.asarray(instance).reshape(-1), extents, n_ids)


def _id_extents(ids: np.ndarray, extents: np.ndarray, n_ids: int) -> np.ndarray:
    """NumPy twin of ``compiled.id_extents`` (the union of the cells' boxes per id)."""
    keep = (ids >= 0) & (ids < n_ids) & (extents[:, 0] >= 0)
    ids, ext = ids[keep].astype(np.intp), extents[keep].astype(np.int64)
    big = np.iinfo(np.int64).max
    lo = np.full((n_ids, 2), big, np.int64)
    hi = np.full((n_ids, 2), -1, np.int64)
    np.minimum.at(lo, ids, ext[:, :2])
    np.maximum.at(hi, ids, ext[:, 2:])
    out = np.concatenate([lo, hi], axis=1)
    out[hi[:, 0] < 0] = -1
    return out.astype(np.int32)
