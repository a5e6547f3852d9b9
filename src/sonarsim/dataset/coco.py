"""A COCO-style JSON of the objects' boxes in a dataset's fan images, for detection users.

One ``image`` per frame (``id`` = frame index, ``file_name`` its fan PNG when the dataset has
PNGs, else its NPZ; ``width``/``height`` of the fan image), one ``annotation`` per object that
dominates at least one fan pixel (``bbox`` = ``[x, y, width, height]`` in pixels: x the
column, y the row, row 0 the far range at the top of the fan; ``area`` = width * height;
``iscrowd`` 0) and one ``category`` per object kind. Objects that a scenario's variation adds
are named ``<group>_<i>`` (:mod:`sonarsim.dataset.variation`); their category is the group's
name, so all rocks are one category. Planes (the ground, walls) are not objects and get no box.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

__all__ = ["category_of", "coco_from_records", "fan_boxes"]

_NUMBERED = re.compile(r"^(?P<base>.+)_[0-9]+$")


def category_of(name: str) -> str:
    """The category of an object named ``name``: the name less a trailing ``_<number>``."""
    match = _NUMBERED.match(name)
    return match["base"] if match else name


def coco_from_records(records: Iterable[Mapping[str, Any]], fan_shape: tuple[int, int] | None = None,
                      image_file: str = "npz") -> dict[str, Any]:
    """The COCO document of a dataset's manifest records (each with ``boxes``, see manifest).

    Parameters
    ----------
    records : iterable of mapping
        Manifest lines in frame order.
    fan_shape : (height, width), optional
        Fan image size in pixels (the same for every frame of a scenario); taken from the
        records' ``fan_shape`` when not given.
    image_file : {"npz", "png"}
        Which of the frame's files ``file_name`` names: its NPZ, or its fan PNG.

    Returns
    -------
    dict
        ``{"info", "images", "annotations", "categories"}``; category ids start at 1 in order of
        first appearance, annotation ids at 1 in frame order.
    """
    images, annotations, categories = [], [], {}
    for record in records:
        k = int(record["frame"])
        shape = fan_shape or tuple(record.get("fan_shape") or (0, 0))
        files = record["files"]
        name = next((f for f in files if f.endswith("_fan.png")), None) if image_file == "png" else None
        images.append({"id": k, "file_name": name or files[0], "height": int(shape[0]), "width": int(shape[1]),
                       "time_s": record.get("time_s")})
        for box in record.get("boxes") or []:
            row0, col0, row1, col1 = (int(v) for v in box["fan"])
            if row0 < 0:  # dominates polar cells but no fan pixel (outside the fan's sampling)
                continue
            category = category_of(str(box["name"]))
            cid = categories.setdefault(category, len(categories) + 1)
            w, h = col1 - col0 + 1, row1 - row0 + 1
            annotations.append({"id": len(annotations) + 1, "image_id": k, "category_id": cid,
                                "bbox": [col0, row0, w, h], "area": w * h, "iscrowd": 0,
                                "object": str(box["name"])})
    return {
        "info": {"description": "sonarsim dataset: object boxes in the fan images", "version": "1"},
        "images": images,
        "annotations": annotations,
        "categories": [{"id": cid, "name": name} for name, cid in categories.items()],
    }


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
