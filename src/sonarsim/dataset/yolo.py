"""YOLO labels of a dataset's images: one text file per frame, and ``data.yaml``.

With ``yolo`` in a dataset's formats (``sonarsim dataset --yolo``) each frame gets
``frames/NNNNNN_fan.txt`` beside the PNG that ``coco.json`` names (``_polar.txt`` with
``coco: polar``), written by the worker with the frame's other files (listed, sized and hashed in
its manifest line, so a resumed run keeps or redoes it like them), and the finished folder gets
``data.yaml``, ``yolo-train.txt`` and ``yolo-val.txt``.

A label file has one line per object whose direct echo has pixels in the image, the objects as
``coco.json`` has them::

    <class> x1 y1 x2 y2 ... xn yn

the object's outline as a polygon in coordinates normalised by the image's width and height
(Ultralytics' segmentation format; its detection training takes each line's box as the
polygon's extent). ``class`` is the COCO category id less one: both come from the same table
(:func:`sonarsim.dataset.coco.scenario_categories`). The polygon is the outline of the
object's pixels (the mask of its COCO annotation): pixel ``(row, col)`` covers ``[col, col + 1]``
x ``[row, row + 1]``, and the outline runs through the midpoints of the edges between the
object's pixels and the others, so its extent is the pixel box, ``bbox`` of ``coco.json``
(tested). Holes are filled (a YOLO polygon has none); an object seen in several pieces is one
polygon, the pieces joined by zero-width cuts from each piece to the nearest point of those
before it (what Ultralytics' COCO converter does), so that its box spans them all.

``data.yaml`` (what Ultralytics' ``YOLO(...).train(data=...)`` reads): ``train`` and ``val``
the image lists (relative paths, ``./frames/...``), ``names`` the class table, ``nc`` its
length; no ``path``, so that readers take the folder of ``data.yaml`` (Ultralytics does; a
relative ``path`` it would resolve against its own datasets folder) and the folder can move,
its bytes the same wherever it was made. Ultralytics looks for an image's labels by replacing the last
``/images/`` of its path by ``/labels/``; these paths have none, so it reads the ``.txt`` beside
each PNG: keep the dataset out of folders named ``images``. The validation frames are the last
tenth of the frames (at least one frame when there are two or more; a lone frame is both), a block rather than every
tenth frame because neighbouring frames of a trajectory see nearly the same thing.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["OUTLINE_TRACER", "VAL_FRACTION", "data_yaml", "image_lists", "label_text", "outline", "val_frames"]

def _tracer() -> str:
    try:
        from importlib.metadata import version

        return f"contourpy-{version('contourpy')}"
    except Exception:  # pragma: no cover - contourpy comes with matplotlib, a dependency
        return "contourpy-unknown"


#: What traces the outlines, with its version (a dataset's fingerprint names it with ``yolo``).
OUTLINE_TRACER = _tracer()
#: The fraction of the frames, the last ones, that ``data.yaml`` names for validation.
VAL_FRACTION = 0.1
# Decimals of the normalised coordinates: a 1/100,000 of a side, below a pixel of any image
# that fits in memory, and exact for the half-pixel grid of the outlines up to 2^5 * 5^5 px.
_DECIMALS = 6


def outline(mask: np.ndarray, origin: Sequence[int] = (0, 0)) -> np.ndarray:
    """The outline of the pixels of ``mask`` as one closed polygon, in image pixels.

    Parameters
    ----------
    mask : (h, w) bool array
        The object's pixels in a window of the image.
    origin : (row, col)
        The window's top-left pixel in the image.

    Returns
    -------
    (n, 2) float64 array
        Vertices ``(x, y)`` in image pixel coordinates (pixel ``(row, col)`` covers
        ``[col, col + 1] x [row, row + 1]``), in order, the first not repeated at the end,
        without vertices that lie on a straight line between their neighbours; every
        coordinate is a multiple of 0.5. Empty (0, 2) for an empty mask.
    """
    import contourpy

    m = np.asarray(mask, bool)
    if not m.any():
        return np.zeros((0, 2))
    # Padded so that every piece closes; the level 0.5 between pixel centres 0 and 1 runs
    # through the edge midpoints (pixel centre (c + 0.5, r + 0.5)).
    z = np.pad(m, 1).astype(np.float64)
    generator = contourpy.contour_generator(z=z, fill_type=contourpy.FillType.OuterOffset, corner_mask=True)
    points, offsets = generator.filled(0.5, 1.5)
    shift = np.array([origin[1] - 0.5, origin[0] - 0.5])
    pieces = [_simplified(p[o[0]:o[1] - 1] + shift) for p, o in zip(points, offsets)]  # outer rings only
    pieces.sort(key=lambda p: -abs(_area(p)))
    merged = pieces[0]
    for piece in pieces[1:]:
        merged = _joined(merged, piece)
    return merged


def _area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _simplified(ring: np.ndarray) -> np.ndarray:
    """``ring`` without the vertices collinear with their neighbours (exact on the half-pixel grid)."""
    before, after = np.roll(ring, 1, axis=0), np.roll(ring, -1, axis=0)
    cross = (ring[:, 0] - before[:, 0]) * (after[:, 1] - ring[:, 1]) - (ring[:, 1] - before[:, 1]) * (after[:, 0] - ring[:, 0])
    keep = cross != 0
    return ring[keep] if keep.sum() >= 3 else ring


def _joined(ring: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """``ring`` and ``piece`` as one polygon: out to ``piece`` along the shortest cut between
    their vertices, round it, and back along the same cut."""
    d = ((ring[:, None, :] - piece[None, :, :]) ** 2).sum(-1)
    i, j = np.unravel_index(int(np.argmin(d)), d.shape)
    around = np.concatenate([piece[j:], piece[:j + 1]])
    return np.concatenate([ring[:i + 1], around, ring[i:]])


def label_text(objects: Sequence[tuple[int, np.ndarray]], shape: Sequence[int]) -> bytes:
    """A frame's YOLO label file.

    Parameters
    ----------
    objects : sequence of (class, (n, 2) array)
        Each object's class (COCO category id - 1) and outline (:func:`outline`), in image pixels.
    shape : (height, width)
        The image's size, pixels.

    Returns
    -------
    bytes
        One line per object with an outline, ``class x1 y1 ... xn yn`` normalised to 0..1,
        ``\\n``-terminated; empty for none.
    """
    h, w = float(shape[0]), float(shape[1])
    lines = []
    for cls, ring in objects:
        if len(ring) < 3:
            continue
        xy = np.column_stack([ring[:, 0] / w, ring[:, 1] / h]).clip(0.0, 1.0).reshape(-1)
        lines.append(" ".join([str(int(cls))] + [f"{v:.{_DECIMALS}f}" for v in xy]))
    return "".join(line + "\n" for line in lines).encode()


def val_frames(n: int) -> int:
    """How many of ``n`` frames, the last ones, ``data.yaml`` names for validation."""
    return 0 if n < 2 else max(1, int(round(VAL_FRACTION * n)))


def data_yaml(classes: Sequence[str]) -> str:
    """``data.yaml`` of a dataset folder whose lists are ``yolo-train.txt`` and ``yolo-val.txt``."""
    import yaml

    doc: dict[str, Any] = {"train": "yolo-train.txt", "val": "yolo-val.txt",
                           "nc": len(classes), "names": {i: str(name) for i, name in enumerate(classes)}}
    return yaml.safe_dump(doc, sort_keys=False)


def image_lists(files: Sequence[Sequence[str]], image: str) -> tuple[str, str]:
    """The contents of ``yolo-train.txt`` and ``yolo-val.txt``: each frame's image, ``./``-relative.

    Parameters
    ----------
    files : sequence of sequence of str
        Each frame's files (:func:`~sonarsim.dataset.encoding.frame_files`), in frame order.
    image : {"fan", "polar"}
        The image ``coco.json`` names.
    """
    names = [next(f for f in frame if f.endswith(f"_{image}.png")) for frame in files]
    cut = len(names) - val_frames(len(names))
    train, val = names[:cut], names[cut:] or names  # one frame: it validates too (a list must not be empty)
    return "".join(f"./{n}\n" for n in train), "".join(f"./{n}\n" for n in val)
