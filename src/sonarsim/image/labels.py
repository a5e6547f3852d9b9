"""Ground truth of a rendered frame: instance maps, elevation per cell, points in view, boxes.

A render with ``labels=True`` (:meth:`sonarsim.Simulator.render`) attaches a :class:`Labels`
to its :class:`~sonarsim.image.result.SonarImage`. Everything here is measured on the frame's
paths (:mod:`sonarsim.paths.engine`), before speckle and the sensor model.

Identifiers
    ``ids[k]`` names id ``k``: the scene's objects first, ``0 .. K-1`` in scene order (their
    ``name``), then the reflecting planes ``K .. K+P-1`` in the order of
    ``scene.reflecting_planes`` (the ground first, named ``ground``, then ``planes:`` by name).
    ``-1`` is "nothing".

What lands in a cell
    A path (transmit leg, one diffuse scatter at a point A, receive leg) is recorded at half its
    length, in the beam of the ray it arrives along; with range splatting (``render.range_splat``,
    the default) its energy covers a range interval, exactly as the image is formed. The label
    maps are formed the same way, so a cell has an instance exactly where its image has energy.

Elevation
    The elevation of a path is the elevation, in the sonar frame, of the direction in which its
    echo *arrives* at the sonar: the elevation of the fan ray its receive leg was traced along.
    For a direct echo that is the elevation of the scatterer A itself (A lies on the ray);
    for multipath it is where the echo seems to come from (a ghost's apparent elevation, which
    is what an elevation-estimating method sees), not A's elevation. With
    ``render.double_beam: split`` the half of a pair recorded in the transmit beam carries the
    receive ray's elevation as well.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from .fan import FanMapper

#: NPZ name of the total's instance map (issue 12 item 6); other components: ``instance_<name>``.
INSTANCE_KEY = "instance"


@dataclass(frozen=True)
class FanLabels:
    """Labels resampled to a fan image (nearest neighbour: ids and elevations are not blended).

    Attributes
    ----------
    instance : (H, W) int32 ndarray
        The total's instance map; -1 outside the fan and where nothing lands.
    elevation_deg : (H, W) float32 ndarray
        Energy-weighted mean elevation, degrees; NaN outside the fan and where nothing lands.
    boxes : (n_ids, 4) int32 ndarray
        Per id: ``[row_min, col_min, row_max, col_max]`` (inclusive, fan pixel indices: row 0
        is the far range at the top) of the pixels of ``instance`` equal to the id; -1 for
        an id that owns no pixel.
    mask : (H, W) bool ndarray
        Pixels inside the fan.
    """

    instance: np.ndarray
    elevation_deg: np.ndarray
    boxes: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True)
class Labels:
    """Ground truth of one frame, on the polar grid ``(n_range_bins, n_beams)`` of its image.

    Attributes
    ----------
    ids : tuple of str
        ``ids[k]`` is the name of id ``k``: objects ``0 .. K-1`` in scene order, then the
        reflecting planes by name (see the module docstring).
    instance : mapping of str to (n_range_bins, n_beams) int32 ndarray
        Per component (``object``, ``ground``, ``single``, ``double``, ``triple``, ...,
        ``total``, the names of :mod:`sonarsim.renderer.components`): in each cell, the id
        that brings the most energy to that component's image (ties: the lower id); -1 where
        the component has no energy. ``ground`` covers every plane's direct echo. Rendered
        with ``labels='total'``: ``total`` only.
    elevation_deg : (n_range_bins, n_beams) float32 ndarray
        Energy-weighted mean arrival elevation (sonar frame, degrees, up positive) of the
        paths of the total in each cell; NaN where nothing lands.
    elevation_min_deg, elevation_max_deg : (n_range_bins, n_beams) float32 ndarray
        Least and greatest arrival elevation of those paths (of every path whose range
        interval overlaps the cell); NaN where nothing lands.
    points_world : (n, 3) float32 ndarray
        The scatterer A of every path of the frame that lands in the image (any order,
        whether or not it enters the total), world frame, metres. A point appears once per
        path through it.
    points_object : (n,) int32 ndarray
        Id of the surface at each point.
    points_component : (n,) int8 ndarray
        Index into :attr:`point_components` of the component each point's path feeds
        (``object``/``ground`` for direct echoes, then the order's name).
    points_cell : (n, 2) int32 ndarray
        ``(range bin, beam)`` of the path's recorded range (half its length) and beam of
        arrival: for a direct echo, the cell of the point itself.
    point_components : tuple of str
        Names of the codes of :attr:`points_component`.
    boxes_polar : (n_ids, 4) int32 ndarray
        Per id: ``[bin_min, beam_min, bin_max, beam_max]`` (inclusive) of the cells where the
        id dominates the total (``instance["total"]``); -1 for an id that dominates no cell.
    """

    ids: tuple[str, ...]
    instance: Mapping[str, np.ndarray]
    elevation_deg: np.ndarray
    elevation_min_deg: np.ndarray
    elevation_max_deg: np.ndarray
    points_world: np.ndarray
    points_object: np.ndarray
    points_component: np.ndarray
    points_cell: np.ndarray
    point_components: tuple[str, ...]
    boxes_polar: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """The labels as named arrays, under the NPZ names of issue 12 item 6.

        ``instance`` (the total's), ``instance_<component>`` for the others,
        ``elevation_deg``, ``elevation_min_deg``, ``elevation_max_deg``, ``points_world``,
        ``points_object``, ``points_component``, ``points_cell``, ``boxes_polar``,
        ``label_ids`` (unicode, the names of the ids) and ``point_components`` (unicode).
        """
        out = {INSTANCE_KEY: self.instance["total"]}
        out.update({f"{INSTANCE_KEY}_{name}": m for name, m in self.instance.items() if name != "total"})
        out.update(
            elevation_deg=self.elevation_deg,
            elevation_min_deg=self.elevation_min_deg,
            elevation_max_deg=self.elevation_max_deg,
            points_world=self.points_world,
            points_object=self.points_object,
            points_component=self.points_component,
            points_cell=self.points_cell,
            boxes_polar=self.boxes_polar,
            label_ids=np.array(self.ids, dtype=str),
            point_components=np.array(self.point_components, dtype=str),
        )
        return out

    def fan(self, mapper: FanMapper) -> FanLabels:
        """The total's instance map, mean elevation and boxes resampled to a fan image.

        Parameters
        ----------
        mapper : FanMapper
            The scan converter of the frame's images (any interpolation: the labels are
            always resampled by nearest neighbour, the range bin and beam containing each
            pixel's centre). ``SonarImage.fan_labels`` builds it.

        Returns
        -------
        FanLabels
        """
        nearest = mapper if mapper.interpolation == "nearest" else FanMapper.from_grid(
            mapper.grid, mapper.pixel_size_m, "nearest")
        mask = nearest.mask
        # float32 holds every id + 1 exactly (ids < 2**24); 0 is "nothing" and outside the fan.
        instance = nearest(self.instance["total"].astype(np.float32) + 1.0).image.astype(np.int32) - 1
        elevation = nearest(self.elevation_deg).image
        elevation = np.where(mask, elevation, np.float32(np.nan)).astype(np.float32)
        return FanLabels(instance, elevation, boxes_of(instance, len(self.ids)), mask)


def boxes_of(instance: np.ndarray, n_ids: int) -> np.ndarray:
    """Inclusive bounding boxes of each id's cells in a 2D instance map.

    Parameters
    ----------
    instance : (H, W) int array
        Ids, -1 none.
    n_ids : int

    Returns
    -------
    (n_ids, 4) int32 ndarray
        Per id ``[row_min, col_min, row_max, col_max]``; -1 for an id absent from the map.
    """
    h, w = instance.shape
    if not h or not w:
        return np.full((n_ids, 4), -1, np.int32)
    # Which ids occur in each row and each column (id + 1: 0 is "nothing"), by two bincounts.
    code = instance.astype(np.int64) + 1
    m = n_ids + 1
    rows = np.bincount((code + (np.arange(h) * m)[:, None]).reshape(-1), minlength=h * m).reshape(h, m)[:, 1:] > 0
    cols = np.bincount((code + np.arange(w) * m).reshape(-1), minlength=w * m).reshape(w, m)[:, 1:] > 0
    out = np.stack([rows.argmax(axis=0), cols.argmax(axis=0),
                    h - 1 - rows[::-1].argmax(axis=0), w - 1 - cols[::-1].argmax(axis=0)], axis=1)
    out[~rows.any(axis=0)] = -1
    return out.astype(np.int32)
