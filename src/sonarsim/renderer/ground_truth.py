"""Ground truth of a frame from its paths: :class:`~sonarsim.image.labels.Labels`.

Formed from the frame's receive legs and path sets (:mod:`sonarsim.paths.engine`) with the
image's own range cells (the neighbours and cells of ``splat_events``), so that each label map
has a value exactly where its component's image has energy. Per path set:

* each path's energy goes to its surface id in the map of its order and, for the paths of the
  total, in the total's map; a map's value in a cell is the id of largest energy (``object``
  and ``ground``: order 1 restricted to objects or planes);
* for the paths of the total, their energy and energy x arrival elevation (the weighted
  mean) and the least and greatest elevation of every cell their range cell overlaps.

Two routes give the same labels. The NumPy route (:func:`splat_truth`, then :func:`dominant`)
forms a dense energy stack ``(n_ids, n_range_bins, n_beams)`` per order and is the reference.
The compiled route (``_kernels.LabelMaps``, :class:`sonarsim.renderer.compiled.FrameTruth`)
never forms them: a cell keeps the first id that deposits and its float32 sum, and only a
cell where a second id arrives gets a row of per-id sums; the same float32 additions in the
same order, so the same dominant ids, ties included, at a fraction of the memory traffic. The
compiled engine deposits in the frame's own pass, each block of beams as it splats its paths
(the very range cells and float32 parts of the image); where the blocks do not splat
(``double_beam: split``, ``double_line_of_sight``) and with the NumPy kernels the labels are
formed from the frame's path sets after it (:func:`frame_labels`), in the same order.

The points are each path's scatterer, surface, image row and cell. No Python loop per ray:
one per path set (a handful per frame) and one per id.
"""

from __future__ import annotations

import functools

from dataclasses import dataclass

import numpy as np

from ..config.sonar import SonarConfig
from ..core.memory import require
from ..core.rays import RayFan
from ..image.labels import Labels, boxes_of
from ..paths.engine import Leg, PathSet, set_continuity
from . import compiled
from .components import component_table, order_name
from .formation import RayEnergy, expand_cells, range_cells


@functools.lru_cache(maxsize=16)  # a scene's: the same every frame
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


def splat_truth(points: np.ndarray, normals: np.ndarray, key: np.ndarray, ray: np.ndarray, distance: np.ndarray,
                energy: np.ndarray, beam: np.ndarray, ident: np.ndarray, elevation: np.ndarray, spread: bool,
                n_elevation: int, range_min_m: float, range_resolution_m: float, n_range_bins: int, n_beams: int,
                out: np.ndarray, moments: bool, total: np.ndarray, weight: np.ndarray, weighted: np.ndarray,
                el_min: np.ndarray, el_max: np.ndarray, continuous: np.ndarray | None = None) -> None:
    """Ground truth of one compact path set, in place (twin of ``_kernels.splat_truth``).

    The set is made dense over the fan and cut into range cells as
    :func:`~sonarsim.renderer.formation.accumulate` cuts it (:func:`range_cells`,
    :func:`expand_cells`).

    Parameters
    ----------
    points, normals : (n, 3) float64 arrays
        The leg's scatterers and normals, dense over the fan's ``n`` rays.
    key : (n,) int array
        :meth:`Leg.key`.
    ray, distance, energy, beam : (m,) arrays
        The path set (:class:`~sonarsim.paths.engine.PathSet`), rays ascending.
    ident : (m,) int array
        Label id of each path's scatterer (:func:`surface_ids`).
    elevation : (m,) float array
        Arrival elevation of each path, degrees.
    spread : bool
    n_elevation : int
    range_min_m, range_resolution_m : float
    n_range_bins, n_beams : int
    out : (n_ids * n_range_bins * n_beams,) or (0,) float array
        Receives each path's energy in the image of its id (empty: not formed).
    moments : bool
        The set's paths enter the total: also add to ``total`` (like ``out``), ``weight``
        (energy), ``weighted`` (energy x elevation), ``el_min`` and ``el_max`` (running
        extremes over the bins each cell overlaps, NaN where none yet), the last four ``(n_range_bins * n_beams,)``.
    continuous : optional
        :func:`~sonarsim.paths.engine.set_continuity` of the leg, when already formed.
    """
    n = len(key)
    dist = np.full(n, np.inf)
    e = np.zeros(n)
    b = np.zeros(n, dtype=np.int64)
    where = np.full(n, -1, dtype=np.intp)
    dist[ray], e[ray], b[ray], where[ray] = distance, energy, beam, np.arange(len(ray))
    shape = (-1, n_elevation)
    cont = None
    if spread:
        cont = continuous if continuous is not None else set_continuity(points, normals, key, n_elevation)
    cells = RayEnergy(dist.reshape(shape), e.reshape(shape), b.reshape(shape), 0, cont)
    lo, hi, density, column = range_cells(cells, range_min_m, range_resolution_m, n_range_bins, n_beams)
    owner, bins, overlap = expand_cells(lo, hi, n_range_bins)
    cell = column[owner] + bins * n_beams
    path = where[owner]
    part = density[owner] * overlap
    plane = n_range_bins * n_beams
    if len(out) or moments:
        by_id = np.bincount(np.asarray(ident)[path] * plane + cell, weights=part,
                            minlength=len(out) or len(total)).astype(total.dtype)
        if len(out):
            out += by_id
    if moments:
        total += by_id
        el = np.asarray(elevation, dtype=np.float64)[path]
        weight += np.bincount(cell, weights=part, minlength=plane)
        weighted += np.bincount(cell, weights=part * el, minlength=plane)
        np.fmin.at(el_min, cell, el)  # fmin: NaN (nothing yet) gives way to any elevation
        np.fmax.at(el_max, cell, el)


class _Truth:
    """The per-set pass of the NumPy route (:func:`splat_truth`), continuity formed once per leg."""

    def __init__(self, legs: list[Leg], n_surfaces: int, n_elevation: int, geometry: tuple, spread: bool) -> None:
        self.legs, self.n_el, self.geometry, self.spread = legs, n_elevation, geometry, spread
        self.keys = {leg.gen: leg.key(n_surfaces) for leg in legs}
        self._cont: dict = {}

    def __call__(self, s: PathSet, ident: np.ndarray, elevation: np.ndarray, out: np.ndarray, moments: bool,
                 acc: tuple) -> None:
        leg = self.legs[s.gen]
        if self.spread and s.gen not in self._cont:
            self._cont[s.gen] = set_continuity(leg.point, leg.normal, self.keys[s.gen], self.n_el)
        splat_truth(leg.point, leg.normal, self.keys[s.gen], s.ray, s.distance, s.energy, s.beam, ident, elevation,
                    self.spread, self.n_el, *self.geometry, out.reshape(-1), moments, *acc,
                    continuous=self._cont.get(s.gen))



def require_label_maps(n_ids: int, max_order: int, n_rows: int, n_beams: int, components: bool = True,
                       key: str = "objects") -> None:
    """Refuse label maps that would not fit the memory budget, before any is made.

    Parameters
    ----------
    n_ids : int
        Surfaces that can be labelled (objects and planes).
    max_order : int
    n_rows, n_beams : int
        The maps' window: range bins and beams.
    components : bool
        Maps of every component (``max_order + 1``) or of the total only.
    key : str
        The key named in the refusal.

    Raises
    ------
    ConfigError
        Naming ``key``, the surfaces and orders, and the size against the budget.
    """
    require(label_map_bytes(n_ids, max_order, n_rows, n_beams, components),
            f"label maps of {n_ids} surfaces x {max_order} orders", key)


def label_map_bytes(n_ids: int, max_order: int, n_rows: int, n_beams: int, components: bool = True) -> float:
    """The most bytes a frame's label maps take (:func:`require_label_maps`'s parameters)."""
    n_maps = max_order + 1 if components else 1
    # Either route: per map, at worst a row of ids per cell (dense stacks, or the compiled
    # route's table if every cell were mixed), and four per-cell accumulators.
    return (n_maps * n_ids * 4.0 + 4 * 8.0) * n_rows * n_beams

@dataclass(frozen=True)
class LabelSpec:
    """What ground truth a frame forms, and the label ids of its surfaces.

    Attributes
    ----------
    lut : (n_surfaces,) int32 ndarray
        Label id of each surface id (:func:`surface_ids`: objects ``0 .. K-1``, then planes).
    elevation_deg : (n_elevation,) float64 ndarray
        Arrival elevation of each elevation row of the fan, degrees.
    n_objects : int
        Label ids below it are objects, the others planes.
    max_order : int
    bounces : tuple of int
        Orders of the total.
    components : bool
        Also an instance map per order (and the first order's objects and planes).
    """

    lut: np.ndarray
    elevation_deg: np.ndarray
    n_objects: int
    max_order: int
    bounces: tuple[int, ...]
    components: bool = True

    @classmethod
    def of(cls, fan: RayFan, n_objects: int, n_planes: int, max_order: int, bounces: tuple[int, ...],
           components: bool = True) -> LabelSpec:
        """The spec of a frame whose rays are ``fan`` (their elevations are the arrival elevations)."""
        lut = surface_ids(np.arange(n_planes + n_objects), n_planes, n_objects)  # one gather per set
        return cls(lut, np.degrees(fan.elevation_rad), int(n_objects), int(max_order), tuple(bounces),
                   bool(components))


def frame_labels(
    sets: list[PathSet] | None,
    legs: list[Leg] | None,
    spec: LabelSpec,
    sonar: SonarConfig,
    object_names: tuple[str, ...],
    plane_names: tuple[str, ...],
    spread: bool,
    kernels: str,
    formed: tuple | None = None,
) -> Labels:
    """The :class:`~sonarsim.image.labels.Labels` of a frame from its paths.

    Parameters
    ----------
    sets : list of PathSet
        Every path set of the frame (as the image was formed from them); unused with ``formed``.
    legs : list of Leg
        Its receive legs (``legs[s.gen]`` for each set).
    spec : LabelSpec
        What to form (the surfaces' ids, the orders, components or the total only).
    sonar : SonarConfig
        The image's grid: range window, bins, beams.
    object_names, plane_names : tuple of str
        Surfaces: object ``k`` is surface ``P + k``, plane ``p`` surface ``p``.
    spread : bool
        ``render.range_splat``.
    kernels : {'compiled', 'numpy'}
        The route (see the module docstring): the compiled one sums float32 as the image
        stack does, the NumPy one float64, so a near tie may go either way between them.
    formed : tuple, optional
        The maps already formed in the frame's own pass (``compiled.render_paths`` with
        ``labels``): ``(orders, objects, planes, total, elevation, boxes, points)``.

    Returns
    -------
    Labels
    """
    n_obj, n_pl = len(object_names), len(plane_names)
    geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams)
    if formed is None:
        require_label_maps(n_obj + n_pl, spec.max_order, sonar.n_range_bins, sonar.n_beams, spec.components)
        route = compiled.frame_truth if kernels == "compiled" and compiled.AVAILABLE else _frame_truth
        formed = route(sets, legs, n_obj + n_pl, spec, geometry, spread)
    orders, obj, gnd, total, maps, boxes, points = formed
    instance = {}
    for comp in component_table(spec.max_order) if spec.components else ():
        if comp.name == "object":
            instance[comp.name] = obj
        elif comp.name == "ground":
            instance[comp.name] = gnd
        elif comp.name != "total":  # "single" is order 1: the stronger of object and ground
            instance[comp.name] = orders[comp.order - 1]
    instance["total"] = total  # last, as in the component table
    return Labels(
        ids=tuple(object_names) + tuple(plane_names),
        instance=instance,
        elevation_deg=maps[0],
        elevation_min_deg=maps[1],
        elevation_max_deg=maps[2],
        points_world=points[0],
        points_object=points[1],
        points_component=points[2],
        points_cell=points[3],
        point_components=point_component_names(spec.max_order),
        boxes_polar=boxes,
    )


def _frame_truth(sets: list[PathSet], legs: list[Leg], n_surfaces: int, spec: LabelSpec, geometry: tuple,
                 spread: bool) -> tuple:
    """The NumPy route of :func:`frame_labels` (twin of :func:`compiled.frame_truth`, whose
    arguments and results it takes): a dense float64 energy stack ``(ids, bins, beams)`` per
    order and for the total, then :func:`dominant` of each."""
    range_min_m, dr, n_r, n_b = geometry
    lut, elevation_deg, n_obj = spec.lut, spec.elevation_deg, spec.n_objects
    max_order, bounces, components = spec.max_order, spec.bounces, spec.components
    n_ids = len(lut)
    n_el = len(elevation_deg)
    truth = _Truth(legs, n_surfaces, n_el, geometry, spread)
    # Rows 0 .. max_order - 1 per order (when the components' maps are formed), the last the total.
    energy = np.zeros((max_order + 1 if components else 1, n_ids, n_r, n_b))
    no_order = energy[:0].reshape(-1)
    # The total's energy and energy x elevation, and the running extremes, per cell.
    acc = (np.zeros(n_r * n_b), np.zeros(n_r * n_b), np.full(n_r * n_b, np.nan), np.full(n_r * n_b, np.nan))
    points, ids_out, rows_out, cells_out = [], [], [], []
    for s in sets:
        if not len(s.ray):
            continue
        ident = lut[legs[s.gen].sid[s.ray]]
        order = max(int(s.label[0]), 1)  # rows 0 (objects) and 1 (planes) are order 1
        if n_r * n_b and (components or order in bounces):
            truth(s, ident, elevation_deg[s.ray % n_el], energy[order - 1] if components else no_order,
                  order in bounces, (energy[-1].reshape(-1),) + acc)
        b = np.floor((s.distance - range_min_m) / dr)
        keep = (b >= 0) & (b < n_r) & (s.energy != 0)
        points.append(legs[s.gen].point[s.ray[keep]])
        ids_out.append(ident[keep])
        rows_out.append(s.label[keep])
        cells_out.append(np.stack([b[keep].astype(np.int32), s.beam[keep]], axis=1))

    orders, obj, gnd = np.zeros((0, n_r, n_b), np.int32), None, None
    if components:
        obj, o_top = dominant(energy[0, :n_obj], 0)
        gnd, g_top = dominant(energy[0, n_obj:], n_obj)
        single = np.where(g_top > o_top, gnd, obj)  # a tie goes to the object (lower id)
        orders = np.stack([single] + [dominant(energy[k], 0)[0] for k in range(1, max_order)])
    total = dominant(energy[-1], 0)[0]
    boxes = boxes_of(total, n_ids)

    weight, weighted, el_min, el_max = acc
    maps = np.full((3, n_r, n_b), np.nan, np.float32)
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN where nothing lands (0 / 0)
        np.divide(weighted, weight, out=maps[0].reshape(-1), casting="same_kind")
    maps[1] = el_min.reshape(n_r, n_b)
    maps[2] = el_max.reshape(n_r, n_b)

    def cat(parts, shape, dt):
        return np.concatenate(parts).astype(dt) if parts else np.zeros(shape, dt)

    points = (cat(points, (0, 3), np.float32), cat(ids_out, (0,), np.int32), cat(rows_out, (0,), np.int8),
              cat(cells_out, (0, 2), np.int32))
    return orders, obj, gnd, total, maps, boxes, points


def dominant(energy: np.ndarray, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """The id of largest energy in each cell, and that energy (twin of ``_kernels.dominant``).

    Parameters
    ----------
    energy : (m, n_r, n_b) float array
        Energy per id (``offset + index``) and cell.

    Returns
    -------
    best : (n_r, n_b) int32 ndarray
        ``offset +`` the index of the largest energy; -1 where all are 0. Ties go to the
        lower id.
    top : (n_r, n_b) ndarray
        The largest energy (0 where none).

    A running maximum over the ids (a few passes over contiguous images): ``argmax(axis=0)``
    is a strided reduction several times slower.
    """
    best = np.full(energy.shape[1:], -1, np.int32)
    top = np.zeros(energy.shape[1:], energy.dtype)
    for k in range(len(energy)):
        win = np.greater(energy[k], top)  # strict: zero energy never wins, a tie keeps the lower id
        np.copyto(best, np.int32(k + offset), where=win)
        np.maximum(top, energy[k], out=top)
    return best, top
