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

import re
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["category_of", "coco_from_records"]

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
