"""Scan conversion: polar sonar images to Cartesian fan images.

A polar sonar image is a float32 array of shape ``(n_range_bins, n_beams)``. Row ``i`` is the
range bin ``[range_min + i*dr, range_min + (i+1)*dr)`` with
``dr = (range_max - range_min) / n_range_bins``; column 0 is the left-most (port) beam.
Beam centre angles ``azimuth_deg`` are strictly *descending* (positive azimuth = the sonar's
left) and may be non-uniformly spaced, as in the lens tables of ARIS/DIDSON-type sonars.

The fan image is a top-down Cartesian picture of the same data in the sonar frame (x forward,
y left): the apex (the sonar) sits at the centre of the bottom edge, far range is at the top
and the sonar's left is on the image's left. Pixels outside the fan are 0 and a boolean mask
tells which pixels are inside.

Geometry of the fan image, with pixel size ``p``:

* height ``H = ceil(range_max / p)`` rows; row ``r`` has its centre at forward distance
  ``x = (H - r - 0.5) * p`` (row 0 is the far row, the bottom row is half a pixel in front of
  the apex);
* width ``W = 2 * ceil(range_max * sin(max |edge angle|) / p)`` columns (at least 2); column
  ``c`` has its centre at lateral distance ``y = (W/2 - c - 0.5) * p``, so the apex lies on the
  boundary between the two middle columns and the image is symmetric about it;
* a pixel is inside the fan when its centre's range lies in ``[range_min, range_max]`` and its
  azimuth lies between the outer edges of the outermost beams (both bounds inclusive).

The per-frame work is a gather from precomputed indices, so build a :class:`FanMapper` once
and call it on every frame; :func:`polar_to_fan` is the one-off convenience wrapper.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .display import fan_image_repr, hook
from .grid import PolarGrid, _check_azimuth, _check_count
from .levels import to_uint8

__all__ = [
    "FanImage",
    "FanGeometry",
    "FanMapper",
    "beam_edges_deg",
    "check_fan_size",
    "fan_geometry",
    "polar_to_fan",
    "INTERPOLATIONS",
]

#: Interpolation methods accepted by :class:`FanMapper` and :func:`polar_to_fan`.
INTERPOLATIONS = ("nearest", "linear")


@dataclass(frozen=True, eq=False)
class FanImage:
    """A Cartesian fan image of one polar sonar frame.

    ``eq=False`` because element-wise array comparison has no single truth value; compare the
    fields with numpy instead.

    Attributes
    ----------
    image : np.ndarray, shape (H, W), float32
        Intensity, in the units of the polar image; exactly 0 outside the fan.
    mask : np.ndarray, shape (H, W), bool
        True for the pixels whose centre lies inside the fan.
    x_m : np.ndarray, shape (H,), float64
        Forward distance from the sonar of each row's centre, in metres. Decreasing: row 0 is
        the far row, the last row is nearest the apex.
    y_m : np.ndarray, shape (W,), float64
        Lateral coordinate of each column's centre, in metres, positive = the sonar's left.
        Decreasing from left to right.
    pixel_size_m : float
        Edge length of a (square) pixel, in metres.

    Notes
    -----
    Images made by one :class:`FanMapper` share their ``mask``, ``x_m`` and ``y_m`` arrays,
    which are therefore read-only; ``image`` is a fresh writable array for every frame.
    """

    image: np.ndarray
    mask: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    pixel_size_m: float

    def __post_init__(self) -> None:
        # Cheap consistency checks; a mismatch here is a programming error in the caller.
        h, w = self.x_m.shape[0], self.y_m.shape[0]
        if self.image.shape != (h, w) or self.mask.shape != (h, w):
            raise ValueError(
                f"image {self.image.shape} and mask {self.mask.shape} must both have shape "
                f"(len(x_m), len(y_m)) = {(h, w)}"
            )

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``, the image shape in pixels."""
        return (int(self.x_m.shape[0]), int(self.y_m.shape[0]))

    # -- pictures (sonarsim.plot, through the hooks of sonarsim.image.display; matplotlib is
    # imported only when a picture is made) ----------------------------------------------------

    def __repr__(self) -> str:
        return fan_image_repr(self)

    def _repr_png_(self) -> bytes:
        """What a notebook shows: the annotated fan (dB re its maximum)."""
        return hook("fan_repr_png", "FanImage._repr_png_")(self)

    def plot(self, ax=None, **options):
        """Draw the annotated fan (metres, rings, spokes, colour bar in dB re its maximum) on
        ``ax`` (default: a new pyplot figure) and return the axes.

        The window (range and edges) is taken from the pixels inside :attr:`mask`, so the
        outline is exact within a pixel. ``options``: those of
        :func:`sonarsim.plot.notebook.fan_image_figure` (``colormap``, ``mapping``, ...).

        Returns
        -------
        matplotlib.axes.Axes
        """
        return hook("fan_plot", "FanImage.plot")(self, ax, **options)

    def save(self, path, **options) -> None:
        """Write the annotated figure: PNG, SVG or PDF after the suffix of ``path``, atomically."""
        hook("fan_save", "FanImage.save")(self, path, **options)

    def to_pil(self, mapping: str = "db", gain_db: float = 0.0, dynamic_range_db: float = 40.0):
        """The exact-pixel image as an 8-bit grey PIL image (0 outside the fan), through
        :func:`sonarsim.io.output.to_uint8` (:func:`sonarsim.image.levels.to_uint8`).

        Returns
        -------
        PIL.Image.Image
        """
        from PIL import Image

        return Image.fromarray(to_uint8(self.image, mapping, gain_db, dynamic_range_db, mask=self.mask))


@dataclass(frozen=True, eq=False)
class FanGeometry:
    """Pixel grid of a fan image and where each pixel samples the polar image.

    Attributes
    ----------
    x_m : np.ndarray, shape (H,), float64
        Forward distance of each row's centre in metres (decreasing; row 0 is far).
    y_m : np.ndarray, shape (W,), float64
        Lateral coordinate of each column's centre in metres (positive = left; decreasing).
    pixel_size_m : float
        Pixel edge length in metres.
    range_m : np.ndarray, shape (H, W), float64
        Distance of each pixel centre from the apex, in metres.
    azimuth_px_deg : np.ndarray, shape (H, W), float64
        Azimuth of each pixel centre in degrees, positive = left.
    beam_index : np.ndarray, shape (H, W), float64
        Fractional beam (column) index of each pixel: beam ``j``'s centre is at ``j``, and the
        index is linear in azimuth between neighbouring beam centres. Pixels beyond the
        outermost beam centres are clamped to ``0`` or ``n_beams - 1``.
    mask : np.ndarray, shape (H, W), bool
        True where the pixel centre lies inside the fan.
    range_min_m, range_max_m : float
        Range interval covered by the polar image, metres.
    azimuth_deg : np.ndarray, shape (n_beams,), float64
        The beam centre angles, descending, degrees.
    left_edge_deg, right_edge_deg : float
        Azimuth of the fan's left (port, positive) and right (starboard) outer edges, degrees.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    pixel_size_m: float
    range_m: np.ndarray
    azimuth_px_deg: np.ndarray
    beam_index: np.ndarray
    mask: np.ndarray
    range_min_m: float
    range_max_m: float
    azimuth_deg: np.ndarray
    left_edge_deg: float
    right_edge_deg: float

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)``, the fan image shape in pixels."""
        return (int(self.x_m.shape[0]), int(self.y_m.shape[0]))

    def range_index(self, n_range_bins: int) -> np.ndarray:
        """Fractional range-bin index of each pixel for a polar image with ``n_range_bins`` rows.

        Bin ``i``'s centre (``range_min + (i + 0.5) * dr``) maps to ``i``, so the result is a
        sample coordinate in the sense of :func:`scipy.ndimage.map_coordinates`. The range
        index is not stored because it depends on the number of range bins, which the
        geometry does not.

        Parameters
        ----------
        n_range_bins : int
            Number of rows of the polar image, >= 1.

        Returns
        -------
        np.ndarray, shape (H, W), float64
            Unclamped; inside the fan it lies in ``[-0.5, n_range_bins - 0.5]``.
        """
        n = _check_count(n_range_bins, "n_range_bins")
        dr = (self.range_max_m - self.range_min_m) / n
        return (self.range_m - self.range_min_m) / dr - 0.5


def _check_pixel_size(pixel_size_m: float) -> float:
    try:
        p = float(pixel_size_m)
    except (TypeError, ValueError):
        raise ValueError(f"pixel_size_m must be a positive number, got {pixel_size_m!r}") from None
    if not (math.isfinite(p) and p > 0.0):
        raise ValueError(f"pixel_size_m must be finite and > 0, got {pixel_size_m!r}")
    return p


def _check_interpolation(interpolation: str) -> str:
    if interpolation not in INTERPOLATIONS:
        raise ValueError(
            f"interpolation must be one of {', '.join(map(repr, INTERPOLATIONS))}, "
            f"got {interpolation!r}"
        )
    return interpolation


def _cells(length: float, size: float) -> int:
    """Number of cells of ``size`` needed to cover ``length``, at least 1.

    The ratio is rounded to 9 decimals first so that e.g. 10 m / 0.1 m gives 100 cells, not
    101 because of the binary representation of 0.1.
    """
    return max(1, math.ceil(round(length / size, 9)))


def check_fan_size(grid: PolarGrid, pixel_size_m: float) -> None:
    """Refuse a fan pixel size that would draw nothing or need more than the memory budget.

    Cheap (nothing is allocated), so that a command can check its ``--pixel-size`` before a
    long render rather than after it.

    Parameters
    ----------
    grid : PolarGrid
        The polar image's grid (e.g. ``SonarConfig.grid``).
    pixel_size_m : float
        Edge length of a fan pixel, metres.

    Raises
    ------
    ConfigError
        Key ``pixel_size_m``: a pixel longer than the range window, or a fan image whose
        scan-conversion tables exceed :func:`sonarsim.core.memory.memory_budget`.
    ValueError
        For a pixel size that is not a finite number > 0.
    """
    from ..core.memory import require
    from ..errors import ConfigError

    p = _check_pixel_size(pixel_size_m)
    rmin, rmax = grid.range_min_m, grid.range_max_m
    half_fov = max(abs(grid.left_edge_deg), abs(grid.right_edge_deg))
    # A pixel longer than the range window draws the whole image as one or two pixels.
    if p > rmax - rmin:
        raise ConfigError("pixel_size_m", f"{p:g} m is longer than the range window ({rmin:g}-{rmax:g} m), so the "
                          f"fan image would show nothing; allowed: up to {rmax - rmin:g} m")
    # Counted in floats: a tiny pixel (1e-300 m, 5e-324 m) makes counts of hundreds of digits,
    # or an infinite ratio that no integer holds.
    rows_f = rmax / p
    cols_f = 2.0 * max(1.0, rmax * math.sin(math.radians(min(half_fov, 90.0))) / p)
    # The scan-conversion tables hold about a dozen float64 values per pixel.
    require(rows_f * cols_f * 100, f"a fan image of {rows_f:.3g} x {cols_f:.3g} pixels", "pixel_size_m")


def beam_edges_deg(
    azimuth_deg: np.ndarray, single_beam_width_deg: float | None = None
) -> tuple[float, float]:
    """Azimuths of the fan's outer edges (see :class:`~sonarsim.image.grid.PolarGrid`).

    The edge of each outermost beam is its centre plus/minus half the spacing to its only
    neighbour.

    Parameters
    ----------
    azimuth_deg : array_like, shape (n_beams,)
        Beam centre angles in degrees, strictly descending (positive = left).
    single_beam_width_deg : float, optional
        Full angular width of the beam, degrees, > 0. Required when ``n_beams == 1`` (there
        is no neighbour to take a spacing from) and ignored otherwise.

    Returns
    -------
    left_edge_deg, right_edge_deg : float
        Left (positive side) and right edge, degrees; ``left_edge_deg > right_edge_deg``.
    """
    grid = PolarGrid(0.0, 1.0, 1, azimuth_deg, single_beam_width_deg)  # the edges need no ranges
    return grid.left_edge_deg, grid.right_edge_deg


def fan_geometry(
    range_min_m: float,
    range_max_m: float,
    azimuth_deg: np.ndarray,
    pixel_size_m: float,
    *,
    single_beam_width_deg: float | None = None,
) -> FanGeometry:
    """Pixel grid of the fan image and the polar coordinates each pixel samples.

    Parameters
    ----------
    range_min_m, range_max_m : float
        Range interval of the polar image, metres; ``0 <= range_min_m < range_max_m``.
    azimuth_deg : array_like, shape (n_beams,)
        Beam centre angles, degrees, strictly descending (positive = left), possibly
        non-uniformly spaced. The fan edges (see :func:`beam_edges_deg`) must lie within
        [-90, 90] degrees: the image only extends forward of the apex.
    pixel_size_m : float
        Edge length of a square fan pixel, metres, > 0.
    single_beam_width_deg : float, optional
        Full beam width in degrees; required only for a single-beam table.

    Returns
    -------
    FanGeometry
        Grid coordinates, per-pixel range, azimuth and fractional beam index, and the mask.
        The fractional range index depends on the number of range bins; get it with
        :meth:`FanGeometry.range_index`.

    Raises
    ------
    ValueError
        For a non-positive pixel size, bad ranges, an azimuth table that is not strictly
        descending, or a fan wider than +-90 degrees.
    """
    # The fan's layout does not depend on the number of range bins.
    grid = PolarGrid(range_min_m, range_max_m, 1, azimuth_deg, single_beam_width_deg)
    return _fan_geometry(grid, pixel_size_m)


def _fan_geometry(grid: PolarGrid, pixel_size_m: float) -> FanGeometry:
    rmin, rmax = grid.range_min_m, grid.range_max_m
    p = _check_pixel_size(pixel_size_m)
    az = grid.azimuth_deg
    left, right = grid.left_edge_deg, grid.right_edge_deg
    half_fov = max(abs(left), abs(right))
    if half_fov > 90.0:
        raise ValueError(
            f"azimuth_deg: the fan edges ({left:g}, {right:g} deg) must lie within [-90, 90] "
            "degrees because the fan image only covers the half-plane in front of the sonar"
        )

    check_fan_size(grid, p)
    n_rows = _cells(rmax, p)
    # The widest lateral extent of a sector of radius rmax whose edges are within +-90 deg is
    # reached on its far arc at the edge with the largest |angle|.
    half_cols = _cells(rmax * math.sin(math.radians(half_fov)), p)
    n_cols = 2 * half_cols

    x_m = (n_rows - 0.5 - np.arange(n_rows, dtype=np.float64)) * p
    y_m = (half_cols - 0.5 - np.arange(n_cols, dtype=np.float64)) * p

    xx = x_m[:, None]
    yy = y_m[None, :]
    range_m = np.hypot(xx, yy)
    # arctan2(y, x) with y positive to the left gives positive azimuth to the left, matching
    # the beam table's convention.
    azimuth_px = np.degrees(np.arctan2(yy, xx))

    # np.interp needs increasing sample points, so feed it the table reversed; this is what
    # makes non-uniform (lens) tables work: the index is piecewise linear in azimuth between
    # actual beam centres. Beyond the outermost centres it clamps to 0 or n_beams - 1.
    beam_idx = np.arange(az.size, dtype=np.float64)
    beam_index = np.interp(azimuth_px, az[::-1], beam_idx[::-1])

    mask = (
        (range_m >= rmin)
        & (range_m <= rmax)
        & (azimuth_px <= left)
        & (azimuth_px >= right)
    )
    return FanGeometry(
        x_m=x_m,
        y_m=y_m,
        pixel_size_m=p,
        range_m=range_m,
        azimuth_px_deg=azimuth_px,
        beam_index=beam_index,
        mask=mask,
        range_min_m=rmin,
        range_max_m=rmax,
        azimuth_deg=az,
        left_edge_deg=left,
        right_edge_deg=right,
    )


class FanMapper:
    """Reusable polar-to-fan scan converter for one sonar geometry.

    All geometry (pixel grid, mask, source indices and interpolation weights of the pixels
    inside the fan) is computed once here; each call then costs one or four gathers over the
    in-fan pixels. Nothing is cached globally: keep the mapper as long as the geometry holds.

    Parameters
    ----------
    n_range_bins : int
        Number of rows of the polar images that will be converted.
    range_min_m, range_max_m : float
        Range interval of the polar image, metres.
    azimuth_deg : array_like, shape (n_beams,)
        Beam centre angles, degrees, strictly descending (positive = left).
    pixel_size_m : float, optional
        Fan pixel edge length, metres. Default: the range resolution
        ``dr = (range_max_m - range_min_m) / n_range_bins``.
    interpolation : {"linear", "nearest"}
        ``"nearest"``: each pixel takes the range bin containing its range and the beam whose
        centre is nearest in beam-index space (i.e. the beam whose edges contain it).
        ``"linear"``: bilinear in (range index, beam index), bin centres as the sample points;
        values beyond the outermost bin/beam centres are those of the edge bin/beam.
    single_beam_width_deg : float, optional
        Full beam width, degrees; required only for a single-beam table.

    Attributes
    ----------
    polar_shape : tuple of int
        ``(n_range_bins, n_beams)``, the shape :meth:`__call__` accepts.
    shape : tuple of int
        ``(H, W)``, the fan image shape.
    x_m, y_m, mask, pixel_size_m
        As in :class:`FanImage` (arrays read-only, shared by all images made).
    interpolation : str
    """

    def __init__(
        self,
        n_range_bins: int,
        range_min_m: float,
        range_max_m: float,
        azimuth_deg: np.ndarray,
        pixel_size_m: float | None = None,
        interpolation: str = "linear",
        *,
        single_beam_width_deg: float | None = None,
    ) -> None:
        grid = PolarGrid(range_min_m, range_max_m, n_range_bins, azimuth_deg, single_beam_width_deg)
        self._build(grid, pixel_size_m, interpolation)

    @classmethod
    def from_grid(
        cls, grid: PolarGrid, pixel_size_m: float | None = None, interpolation: str = "linear"
    ) -> "FanMapper":
        """The scan converter of images on ``grid`` (see the class for the parameters)."""
        self = cls.__new__(cls)
        self._build(grid, pixel_size_m, interpolation)
        return self

    def _build(self, grid: PolarGrid, pixel_size_m: float | None, interpolation: str) -> None:
        n_r = grid.n_range_bins
        rmin, rmax = grid.range_min_m, grid.range_max_m
        self.interpolation = _check_interpolation(interpolation)
        if pixel_size_m is None:
            pixel_size_m = grid.range_resolution_m
        geom = _fan_geometry(grid, pixel_size_m)
        self.grid = grid
        n_b = int(geom.azimuth_deg.size)
        self.polar_shape = (n_r, n_b)
        self.shape = geom.shape
        self.pixel_size_m = geom.pixel_size_m
        self.range_min_m = rmin
        self.range_max_m = rmax
        self.azimuth_deg = geom.azimuth_deg
        self.left_edge_deg = geom.left_edge_deg
        self.right_edge_deg = geom.right_edge_deg

        # Shared between all images this mapper makes, so freeze them against accidental
        # writes through one frame's FanImage.
        self.x_m = _readonly(geom.x_m)
        self.y_m = _readonly(geom.y_m)
        self.mask = _readonly(geom.mask)

        # Only pixels inside the fan are ever computed; keep their flat positions.
        self._dest = _readonly(np.flatnonzero(geom.mask))
        r_idx = geom.range_index(n_r)[geom.mask]
        b_idx = geom.beam_index[geom.mask]
        index_dtype = np.int32 if n_r * n_b < 2**31 else np.int64

        if self.interpolation == "nearest":
            # floor(idx + 0.5) rather than np.rint: deterministic at exact halves, and for
            # range it equals floor((r - rmin) / dr), i.e. the bin whose half-open interval
            # contains r. Clipping handles r == range_max (and the beam edge pixels).
            i = np.clip(np.floor(r_idx + 0.5), 0, n_r - 1).astype(np.intp)
            j = np.clip(np.floor(b_idx + 0.5), 0, n_b - 1).astype(np.intp)
            self._src = _readonly((i * n_b + j).astype(index_dtype))
        else:
            i0, i1, fr = _bracket(r_idx, n_r)
            j0, j1, fb = _bracket(b_idx, n_b)
            self._k00 = _readonly((i0 * n_b + j0).astype(index_dtype))
            self._k01 = _readonly((i0 * n_b + j1).astype(index_dtype))
            self._k10 = _readonly((i1 * n_b + j0).astype(index_dtype))
            self._k11 = _readonly((i1 * n_b + j1).astype(index_dtype))
            self._fr = _readonly(fr.astype(np.float32))
            self._fb = _readonly(fb.astype(np.float32))

    def __call__(self, polar: np.ndarray) -> FanImage:
        """Convert one polar frame.

        Parameters
        ----------
        polar : array_like, shape (n_range_bins, n_beams)
            Real-valued polar image; converted to float32.

        Returns
        -------
        FanImage
            ``image`` of shape :attr:`shape`, float32, zero outside :attr:`mask`.
        """
        arr = np.asarray(polar)
        if arr.dtype.kind not in "biuf":
            raise ValueError(f"polar must be a real-valued array, got dtype {arr.dtype}")
        if arr.shape != self.polar_shape:
            raise ValueError(
                f"polar must have shape (n_range_bins, n_beams) = {self.polar_shape}, "
                f"got {arr.shape}"
            )
        flat = np.ascontiguousarray(arr, dtype=np.float32).reshape(-1)

        if self.interpolation == "nearest":
            values = flat[self._src]
        else:
            # Lerp form a + (b - a) * t instead of a weighted sum: one multiply fewer per
            # stage, and a constant image comes back exactly constant (no weight round-off).
            p00 = flat[self._k00]
            p01 = flat[self._k01]
            p10 = flat[self._k10]
            p11 = flat[self._k11]
            near = p00 + (p01 - p00) * self._fb
            far = p10 + (p11 - p10) * self._fb
            values = near + (far - near) * self._fr

        out = np.zeros(self.shape[0] * self.shape[1], dtype=np.float32)
        out[self._dest] = values
        return FanImage(
            image=out.reshape(self.shape),
            mask=self.mask,
            x_m=self.x_m,
            y_m=self.y_m,
            pixel_size_m=self.pixel_size_m,
        )

    def levels(self, polar_levels: np.ndarray, compiled: bool | None = None) -> np.ndarray:
        """8-bit display levels on the polar grid, resampled to the fan: the display mapping
        done on the polar grid's few cells rather than the fan's many pixels, then one gather.

        ``linear`` mappers blend the four levels around each pixel with 8-bit fixed-point
        weights (``round(256 t)``; the result rounded half up), ``nearest`` ones take the
        nearest level. Integer arithmetic: the compiled kernel (``sonarsim.image._fan_levels``)
        and the NumPy path give the same bytes.

        Parameters
        ----------
        polar_levels : (n_range_bins, n_beams) uint8 array
        compiled : bool, optional
            Force the compiled kernel (``True``) or the NumPy path (``False``); default the
            kernel where it is built.

        Returns
        -------
        (height, width) uint8 ndarray
            0 outside :attr:`mask`.
        """
        arr = np.asarray(polar_levels)
        if arr.dtype != np.uint8 or arr.shape != self.polar_shape:
            raise ValueError(f"polar_levels must be uint8 of shape {self.polar_shape}, got {arr.dtype} {arr.shape}")
        flat = np.ascontiguousarray(arr).reshape(-1)
        out = np.zeros(self.shape[0] * self.shape[1], dtype=np.uint8)
        if self.interpolation == "nearest":
            out[self._dest] = flat[self._src]
            return out.reshape(self.shape)
        tables = self._level_tables()
        kernel = _fan_levels_kernel() if compiled is not False else None
        if compiled and kernel is None:
            raise RuntimeError("the compiled fan kernel (sonarsim.image._fan_levels) is not built")
        if kernel is not None:
            kernel.bilinear_levels(flat, *tables, out)
            return out.reshape(self.shape)
        k00, k01, k10, k11, wb, wr, dest = tables
        b, r = wb.astype(np.uint32), wr.astype(np.uint32)
        near = flat[k00] * (256 - b) + flat[k01] * b
        far = flat[k10] * (256 - b) + flat[k11] * b
        out[dest] = ((near * (256 - r) + far * r + 32768) >> 16).astype(np.uint8)
        return out.reshape(self.shape)

    def _level_tables(self) -> tuple[np.ndarray, ...]:
        """The gather of :meth:`levels`: int32 source cells, uint16 weights in 1/256, int32
        destinations (made once per mapper)."""
        tables = getattr(self, "_levels_tables", None)
        if tables is None:
            as32 = lambda a: _readonly(np.ascontiguousarray(a, dtype=np.int32))  # noqa: E731
            weight = lambda f: _readonly(np.rint(np.asarray(f, np.float64) * 256.0).astype(np.uint16))  # noqa: E731
            tables = (as32(self._k00), as32(self._k01), as32(self._k10), as32(self._k11), weight(self._fb),
                      weight(self._fr), as32(self._dest))
            self._levels_tables = tables
        return tables

    def ids(self, polar_ids: np.ndarray, fill: int = -1) -> np.ndarray:
        """An integer map (instance ids) on the polar grid resampled to the fan by nearest
        neighbour, without a round trip through float32 (a ``nearest`` mapper only).

        Parameters
        ----------
        polar_ids : (n_range_bins, n_beams) int array
        fill : int
            The value outside the fan.

        Returns
        -------
        (height, width) int32 ndarray
        """
        if self.interpolation != "nearest":
            raise ValueError(f"ids() resamples by nearest neighbour: build the mapper with interpolation='nearest', "
                             f"not {self.interpolation!r}")
        arr = np.asarray(polar_ids)
        if arr.dtype.kind not in "iu" or arr.shape != self.polar_shape:
            raise ValueError(f"polar_ids must be integers of shape {self.polar_shape}, got {arr.dtype} {arr.shape}")
        out = np.full(self.shape[0] * self.shape[1], fill, dtype=np.int32)
        out[self._dest] = arr.reshape(-1)[self._src]
        return out.reshape(self.shape)

    def window_ids(self, polar_ids: np.ndarray, box: Sequence[int], fill: int = -1) -> np.ndarray:
        """:meth:`ids` inside ``box`` alone (``[row_min, col_min, row_max, col_max]``,
        inclusive fan pixels): the same values as ``ids(polar_ids)[row_min:row_max + 1,
        col_min:col_max + 1]``, for the box's pixels only."""
        if self.interpolation != "nearest":
            raise ValueError("window_ids() resamples by nearest neighbour: build the mapper with interpolation='nearest'")
        arr = np.asarray(polar_ids)
        if arr.dtype.kind not in "iu" or arr.shape != self.polar_shape:
            raise ValueError(f"polar_ids must be integers of shape {self.polar_shape}, got {arr.dtype} {arr.shape}")
        source = getattr(self, "_source_map", None)
        if source is None:  # each fan pixel's polar cell, -1 outside the fan (made once)
            source = np.full(self.shape[0] * self.shape[1], -1, np.int32)
            source[self._dest] = self._src
            source = self._source_map = _readonly(source.reshape(self.shape))
        r0, c0, r1, c1 = (int(v) for v in box)
        cells = source[r0:r1 + 1, c0:c1 + 1]
        values = arr.reshape(-1)[np.maximum(cells, 0)].astype(np.int32)
        return np.where(cells >= 0, values, np.int32(fill))

    def __repr__(self) -> str:
        return (
            f"FanMapper(polar_shape={self.polar_shape}, shape={self.shape}, "
            f"pixel_size_m={self.pixel_size_m:g}, interpolation={self.interpolation!r})"
        )


def _fan_levels_kernel():
    """The compiled fan-levels kernel, or None where it is not built."""
    try:
        from . import _fan_levels
    except ImportError:
        return None
    return _fan_levels


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _bracket(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower/upper sample index and fraction for linear interpolation along one axis.

    Clamps so that coordinates beyond the first/last sample take the edge sample's value
    (the half bin/beam between the outermost centre and the fan edge), and handles ``n == 1``.
    """
    lo = np.clip(np.floor(idx), 0, max(n - 2, 0)).astype(np.intp)
    hi = np.minimum(lo + 1, n - 1)
    frac = np.clip(idx - lo, 0.0, 1.0)
    return lo, hi, frac


def polar_to_fan(
    polar: np.ndarray,
    range_min_m: float,
    range_max_m: float,
    azimuth_deg: np.ndarray,
    pixel_size_m: float | None = None,
    interpolation: str = "linear",
    *,
    single_beam_width_deg: float | None = None,
) -> FanImage:
    """Scan-convert one polar sonar image into a Cartesian fan image.

    One-off convenience wrapper; to convert many frames with the same geometry build a
    :class:`FanMapper` once and call it per frame.

    Parameters
    ----------
    polar : array_like, shape (n_range_bins, n_beams)
        Polar image; row 0 nearest range, column 0 the left (port) beam.
    range_min_m, range_max_m : float
        Range interval of the polar image, metres.
    azimuth_deg : array_like, shape (n_beams,)
        Beam centre angles, degrees, strictly descending (positive = left).
    pixel_size_m : float, optional
        Fan pixel edge length, metres, > 0. Default: the range resolution ``dr``.
    interpolation : {"linear", "nearest"}
        See :class:`FanMapper`.
    single_beam_width_deg : float, optional
        Full beam width, degrees; required only for a single-beam table.

    Returns
    -------
    FanImage

    Raises
    ------
    ValueError
        For a polar image that is not 2-D or does not match ``azimuth_deg``, a non-positive
        pixel size, bad ranges, an unknown interpolation, or a bad azimuth table.
    """
    arr = np.asarray(polar)
    if arr.ndim != 2:
        raise ValueError(
            f"polar must be a 2-D array (n_range_bins, n_beams), got shape {arr.shape}"
        )
    az = _check_azimuth(azimuth_deg)
    if arr.shape[1] != az.size:
        raise ValueError(
            f"polar has {arr.shape[1]} columns but azimuth_deg has {az.size} beams; "
            "they must match"
        )
    if arr.shape[0] < 1:
        raise ValueError("polar must have at least one range bin")
    mapper = FanMapper(
        arr.shape[0],
        range_min_m,
        range_max_m,
        az,
        pixel_size_m,
        interpolation,
        single_beam_width_deg=single_beam_width_deg,
    )
    return mapper(arr)
