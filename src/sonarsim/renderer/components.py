"""The table of image components: which rows of the frame's image stack each name sums.

A frame is formed as an image stack ``(max_order + 1, n_range_bins, n_beams)``: row 0 the
single-bounce echo of the objects, row 1 that of the planes (the direct ground echo), row
``k >= 2`` the paths of order ``k``. Every component is named here, and only here:

==========  =====  =============================================================
name        order  what
==========  =====  =============================================================
object      1      direct echo of the objects (O-A-O)
ground      1      direct (diffuse) echo of the reflecting planes (O-G-O)
single      1      object + ground
double      2      paths with two surface interactions (the paper's cases 2/3)
triple      3      paths with three (the paper's case 4)
order4 ...  4 ...  paths with four and more
total       --     the orders selected by ``render.bounces``
==========  =====  =============================================================

Paths by signature (which planes, in which order, on which leg) are further components named
by :func:`sonarsim.paths.engine.path_name`, e.g. ``O-ground-[objects]-ground-O``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

ORDER_NAMES = {1: "single", 2: "double", 3: "triple"}
ROW_OBJECT, ROW_PLANE = 0, 1


def order_name(order: int) -> str:
    """``single``, ``double``, ``triple``, then ``order4``, ``order5``, ..."""
    return ORDER_NAMES.get(order, f"order{order}")


@dataclass(frozen=True)
class Component:
    """One named image of a frame.

    Attributes
    ----------
    name : str
    order : int or None
        Path order (None for ``total``).
    rows : tuple of int
        Rows of the image stack it sums (empty for ``total``: the selected orders).
    """

    name: str
    order: int | None
    rows: tuple[int, ...]


def component_table(max_order: int) -> tuple[Component, ...]:
    """Every component of a frame formed up to ``max_order``, ``total`` last."""
    out = [Component("object", 1, (ROW_OBJECT,)), Component("ground", 1, (ROW_PLANE,)),
           Component("single", 1, (ROW_OBJECT, ROW_PLANE))]
    out += [Component(order_name(k), k, (k,)) for k in range(2, max_order + 1)]
    out.append(Component("total", None, ()))
    return tuple(out)


def stack_rows(max_order: int) -> int:
    """Rows of the image stack of a frame formed up to ``max_order``."""
    return max_order + 1


def assemble(stack: np.ndarray, bounces: tuple[int, ...], max_order: int) -> dict[str, np.ndarray]:
    """Named float32 components from the image stack.

    Parameters
    ----------
    stack : (max_order + 1, n_range_bins, n_beams) float32 ndarray
        Rows as in the module docstring; single rows are returned as views.
    bounces : tuple of int
        Orders that make ``total``.

    Returns
    -------
    dict of str to (n_range_bins, n_beams) float32 ndarray
    """
    components = frame_components(stack, bounces, max_order)
    return {comp.name: components[comp.name] for comp in component_table(max_order)}


def _sum_rows(stack: np.ndarray, rows: tuple[int, ...], copy: bool) -> np.ndarray:
    """Sum of stack rows, in row order; one row is a view unless ``copy``."""
    if len(rows) == 1:
        return stack[rows[0]].copy() if copy else stack[rows[0]]
    if rows == tuple(range(rows[0], rows[-1] + 1)):
        # One pass over a contiguous block, added row after row (as a loop of np.add would).
        return np.add.reduce(stack[rows[0]:rows[-1] + 1], axis=0)
    acc = stack[rows[0]] + stack[rows[1]]
    for r in rows[2:]:
        np.add(acc, stack[r], out=acc)
    return acc


def total_rows(bounces: tuple[int, ...], max_order: int) -> tuple[int, ...]:
    """The stack rows that ``total`` sums (those of the orders in ``bounces``), ascending: the
    order in which they are added."""
    by_name = {c.name: c for c in component_table(max_order)}
    return tuple(sorted(r for k in bounces for r in by_name[order_name(k)].rows))


def frame_components(stack: np.ndarray, bounces: tuple[int, ...], max_order: int,
                     paths: Callable[[], dict] | None = None, total: np.ndarray | None = None) -> "Components":
    """The :class:`Components` of a frame: ``total`` now, the rest when first looked up.

    Single rows are views of ``stack``; sums of rows (``single``) and the path-signature
    images (``paths()``) are formed on first access (:func:`assemble` forms them all now).
    ``total``: already summed (the rows of :func:`total_rows`, added in that order in float32,
    as here), e.g. by the fused ground blocks while the rows were in cache.
    """
    table = component_table(max_order)
    images: dict = {}
    for comp in table:
        if comp.name == "total":
            images["total"] = total if total is not None else _sum_rows(stack, total_rows(bounces, max_order), copy=True)
        elif len(comp.rows) == 1:
            images[comp.name] = stack[comp.rows[0]]
        else:
            images[comp.name] = functools.partial(_sum_rows, stack, comp.rows, False)
    return Components(images, paths)


class Components(Mapping):
    """The components of a frame: the table's images, and path-signature images on demand.

    Images given as zero-argument callables are formed when first looked up. Path-signature
    images cost a pass over the frame's paths; they are formed, all at once, when one is first
    looked up or the names are listed (as writing an NPZ does). Everything formed is kept.

    Parameters
    ----------
    images : dict of str to ndarray or callable
        The table's components.
    paths : callable, optional
        ``paths() -> dict`` of path-signature name to image.
    """

    def __init__(self, images: dict, paths: Callable[[], dict] | None = None) -> None:
        self._images = dict(images)
        self._paths = paths
        self._signatures: dict | None = None if paths is not None else {}

    def _formed(self) -> dict:
        if self._signatures is None:
            self._signatures = {k: v for k, v in self._paths().items() if k not in self._images}
        return self._signatures

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self._images:
            img = self._images[name]
            if callable(img):
                img = self._images[name] = img()
            return img
        return self._formed()[name]

    def __contains__(self, name: object) -> bool:
        return name in self._images or name in self._formed()

    def __iter__(self) -> Iterator[str]:
        yield from self._images
        yield from self._formed()

    def __len__(self) -> int:
        return len(self._images) + len(self._formed())

    @property
    def table(self) -> tuple[str, ...]:
        """Names of the component table's images (``object``, ``ground``, ..., ``total``), in
        table order: what listing them costs nothing beyond the sums of rows."""
        return tuple(self._images)

    @property
    def signatures(self) -> tuple[str, ...]:
        """Names of the path-signature components of the frame."""
        return tuple(self._formed())

    def __repr__(self) -> str:
        n = "?" if self._signatures is None else len(self._signatures)
        return f"Components({', '.join(self._images)}, + {n} path signatures)"
