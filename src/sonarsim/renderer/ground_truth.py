"""Ground truth of a frame from its paths: :class:`~sonarsim.image.labels.Labels`.

Formed from the frame's receive legs and path sets (:mod:`sonarsim.paths.engine`), with the
same deposit as the image (``splat_events``, or its NumPy twin ``splat_set``), so that each
label map has a value exactly where its component's image has energy:

* per path order, one energy image per id (``(n_ids, n_range_bins, n_beams)``): the path's
  surface id is the splat's label. The instance map of a component is the argmax over ids of
  the energy of its orders (``object`` and ``ground``: order 1 restricted to objects or planes);
* the energy-weighted mean elevation: two more deposits of the total's paths, their energy and
  their energy times (elevation + 90 degrees) (positive, so that no path drops out of the
  splat's neighbour test, which skips paths without energy), divided;
* the least and greatest elevation per cell: each path's range cell (as
  :func:`~sonarsim.renderer.formation.accumulate` spreads it) expanded into the bins it
  overlaps, then ``np.minimum.at`` / ``np.maximum.at`` (NumPy for both kernels);
* the points: each path's scatterer, surface, image row and cell.

Only arrays per path and per cell: no Python loop per ray, one per path set (a handful per
frame).
"""

from __future__ import annotations

import numpy as np

from ..config.sonar import SonarConfig
from ..core.memory import require
from ..core.rays import RayFan
from ..image.labels import Labels, boxes_of
from ..paths.engine import Leg, PathSet, set_continuity, splat_set
from .components import component_table, order_name
from .formation import RayEnergy, expand_cells, range_cells
from . import compiled

# Elevations are shifted by this before weighting so that every weight is positive.
ELEVATION_SHIFT_DEG = 90.0

# The compiled deposit takes labels as int8.
INT8_LABELS = 127


def point_component_names(max_order: int) -> tuple[str, ...]:
    """Names of the image rows, by row: ``object``, ``ground``, then one per order >= 2."""
    return ("object", "ground") + tuple(order_name(k) for k in range(2, max_order + 1))


def surface_ids(sid: np.ndarray, n_planes: int, n_objects: int) -> np.ndarray:
    """Label ids of surface ids: objects ``0 .. K-1``, planes ``K .. K+P-1``, -1 none.

    Parameters
    ----------
    sid : int array
        Surface ids of the path engine: planes ``0 .. P-1``, object ``k`` at ``P + k``.
    """
    sid = np.asarray(sid)
    return np.where(sid < 0, -1, np.where(sid >= n_planes, sid - n_planes, sid + n_objects)).astype(np.int32)


class _Deposit:
    """Splats path sets into float images with the frame's kernel (compiled or its NumPy twin)."""

    def __init__(self, legs: list[Leg], n_surfaces: int, n_elevation: int, geometry: tuple, spread: bool,
                 kernels: str) -> None:
        self.legs, self.n_el, self.geometry, self.spread = legs, n_elevation, geometry, spread
        self.compiled = kernels == "compiled" and compiled.AVAILABLE
        self.keys = {leg.gen: leg.key(n_surfaces) for leg in legs}
        self._cont: dict = {}

    def __call__(self, s: PathSet, energy: np.ndarray, label: np.ndarray, out: np.ndarray) -> None:
        """Add the paths of ``s`` with ``energy`` (m,) into ``out[label]`` (out: (L, bins, beams))."""
        leg = self.legs[s.gen]
        n_labels = out.shape[0]
        if self.compiled:
            flat = out.reshape(-1)
            energy = np.ascontiguousarray(energy, dtype=np.float64)
            for base in range(0, n_labels, INT8_LABELS):  # int8 labels: ids in chunks of 127
                k = np.flatnonzero((label >= base) & (label < base + INT8_LABELS))
                if not len(k):
                    continue
                whole = len(k) == len(label)
                pick = (lambda a: a) if whole else (lambda a: np.ascontiguousarray(a[k]))
                part = flat[base * self.geometry[2] * self.geometry[3]:]
                compiled.splat_labelled(leg.point, leg.normal, self.keys[s.gen], pick(s.ray), pick(s.distance),
                                        pick(energy), pick(s.beam), (pick(label) - base).astype(np.int8),
                                        self.spread, self.n_el, self.geometry, part)
            return
        if self.spread and s.gen not in self._cont:
            self._cont[s.gen] = set_continuity(leg.point, leg.normal, self.keys[s.gen], self.n_el)
        out += splat_set(leg.point, leg.normal, self.keys[s.gen], s.ray, s.distance, energy, s.beam, label, 1.0,
                         self.spread, self.n_el, *self.geometry, n_labels, continuous=self._cont.get(s.gen))

    def cells(self, s: PathSet) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cells each path of ``s`` covers: (path index, flat cell ``bin * n_beams + beam``)."""
        leg = self.legs[s.gen]
        n = len(leg.distance)
        dist = np.full(n, np.inf)
        e = np.zeros(n)
        beam = np.zeros(n, dtype=np.int64)
        dist[s.ray], e[s.ray], beam[s.ray] = s.distance, s.energy, s.beam
        shape = (-1, self.n_el)
        cont = None
        if self.spread:
            if s.gen not in self._cont:
                self._cont[s.gen] = set_continuity(leg.point, leg.normal, self.keys[s.gen], self.n_el)
            cont = self._cont[s.gen]
        rays = RayEnergy(dist.reshape(shape), e.reshape(shape), beam.reshape(shape), 0, cont)
        lo, hi, _, column = range_cells(rays, *self.geometry)
        owner, bins, _ = expand_cells(lo, hi, self.geometry[2])
        # Dense ray -> index of the path in the set.
        where = np.full(n, -1, dtype=np.intp)
        where[s.ray] = np.arange(len(s.ray))
        return where[owner], column[owner] + bins * self.geometry[3]


def frame_labels(
    sets: list[PathSet],
    legs: list[Leg],
    fan: RayFan,
    sonar: SonarConfig,
    object_names: tuple[str, ...],
    plane_names: tuple[str, ...],
    max_order: int,
    bounces: tuple[int, ...],
    spread: bool,
    kernels: str,
) -> Labels:
    """The :class:`~sonarsim.image.labels.Labels` of a frame from its paths.

    Parameters
    ----------
    sets : list of PathSet
        Every path set of the frame (as the image was formed from them).
    legs : list of Leg
        Its receive legs (``legs[s.gen]`` for each set).
    fan : RayFan
        The rays the legs were traced along (their elevations are the arrival elevations).
    sonar : SonarConfig
        The image's grid: range window, bins, beams.
    object_names, plane_names : tuple of str
        Surfaces: object ``k`` is surface ``P + k``, plane ``p`` surface ``p``.
    max_order : int
    bounces : tuple of int
        Orders of the total.
    spread : bool
        ``render.range_splat``.
    kernels : {'compiled', 'numpy'}
        The deposit used (the twins give the same labels to float32 round-off).

    Returns
    -------
    Labels
    """
    n_obj, n_pl = len(object_names), len(plane_names)
    n_ids = n_obj + n_pl
    n_r, n_b = sonar.n_range_bins, sonar.n_beams
    geometry = (sonar.range_min_m, sonar.range_resolution_m, n_r, n_b)
    require((max_order * n_ids + 2) * n_r * n_b * 4.0, f"label maps of {n_ids} surfaces x {max_order} orders",
            "objects")
    deposit = _Deposit(legs, n_obj + n_pl, fan.shape[2], geometry, spread, kernels)
    dtype = np.float32 if deposit.compiled else np.float64
    energy = np.zeros((max_order, n_ids, n_r, n_b), dtype)  # per order, per id
    moments = np.zeros((2, n_r, n_b), dtype)  # the total's energy and energy x shifted elevation
    el_min = np.full(n_r * n_b, np.inf)
    el_max = np.full(n_r * n_b, -np.inf)
    elevation_deg = np.degrees(fan.elevation_rad)
    n_el = fan.shape[2]
    points, ids_out, rows_out, cells_out = [], [], [], []
    for s in sets:
        if not len(s.ray):
            continue
        ident = surface_ids(legs[s.gen].sid[s.ray], n_pl, n_obj)
        order = max(int(s.label[0]), 1)  # rows 0 (objects) and 1 (planes) are order 1
        deposit(s, s.energy, ident, energy[order - 1])
        if order in bounces:
            el = elevation_deg[s.ray % n_el]
            zeros = np.zeros(len(s.ray), np.int32)
            deposit(s, s.energy, zeros, moments[0:1])
            deposit(s, s.energy * (el + ELEVATION_SHIFT_DEG), zeros, moments[1:2])
            path, cell = deposit.cells(s)
            np.minimum.at(el_min, cell, el[path])
            np.maximum.at(el_max, cell, el[path])
        b = np.floor((s.distance - sonar.range_min_m) / sonar.range_resolution_m)
        keep = (b >= 0) & (b < n_r) & (s.energy != 0)
        points.append(legs[s.gen].point[s.ray[keep]])
        ids_out.append(ident[keep])
        rows_out.append(s.label[keep])
        cells_out.append(np.stack([b[keep], s.beam[keep]], axis=1))

    instance = {}
    for comp in component_table(max_order):
        if comp.name == "object":
            instance[comp.name] = _dominant(energy[0, :n_obj], 0)
        elif comp.name == "ground":
            instance[comp.name] = _dominant(energy[0, n_obj:], n_obj)
        elif comp.name == "total":
            orders = [k for k in bounces if k <= max_order]
            total = energy[orders[0] - 1].copy() if orders else np.zeros((n_ids, n_r, n_b), dtype)
            for k in orders[1:]:
                total += energy[k - 1]
            instance["total"] = _dominant(total, 0)
        else:
            instance[comp.name] = _dominant(energy[comp.order - 1], 0)

    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(moments[0] > 0, moments[1] / moments[0] - ELEVATION_SHIFT_DEG, np.nan)
    seen = np.isfinite(el_min)
    el_min = np.where(seen, el_min, np.nan).reshape(n_r, n_b)
    el_max = np.where(seen, el_max, np.nan).reshape(n_r, n_b)

    def cat(parts, shape, dt):
        return np.concatenate(parts).astype(dt) if parts else np.zeros(shape, dt)

    return Labels(
        ids=tuple(object_names) + tuple(plane_names),
        instance=instance,
        elevation_deg=mean.astype(np.float32),
        elevation_min_deg=el_min.astype(np.float32),
        elevation_max_deg=el_max.astype(np.float32),
        points_world=cat(points, (0, 3), np.float32),
        points_object=cat(ids_out, (0,), np.int32),
        points_component=cat(rows_out, (0,), np.int8),
        points_cell=cat(cells_out, (0, 2), np.int32),
        point_components=point_component_names(max_order),
        boxes_polar=boxes_of(instance["total"], n_ids),
    )


def _dominant(energy: np.ndarray, offset: int) -> np.ndarray:
    """(n_r, n_b) int32: ``offset +`` the index of the largest of ``energy`` (m, n_r, n_b); -1 where all are 0."""
    if not len(energy):
        return np.full(energy.shape[1:], -1, np.int32)
    best = np.argmax(energy, axis=0)
    some = np.take_along_axis(energy, best[None], axis=0)[0] > 0
    return np.where(some, best + offset, -1).astype(np.int32)
