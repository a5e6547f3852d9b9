"""Comparing two sonar images whatever their geometry, and loading them from files.

:func:`compare_images` runs the metrics of :mod:`sonarsim.analysis.metrics` (MSE, PSNR, SSIM) in the
polar domain, on image A's grid (B resampled if the geometries differ), and in the fan-shaped
(Cartesian) domain, on the pixels inside both fans, and with ``stats`` or ``regions`` describes
texture and distributions per region (:mod:`sonarsim.analysis.realism`), and what the score means
beside the trivial images, per range band and to a classifier (:mod:`sonarsim.analysis.bands`,
issue 22). :func:`load_image` reads
a sonarsim NPZ, a PNG, or a real recording (:mod:`sonarsim.io.readers`), recognised from the
first bytes; :func:`load_region` reads a region mask (.npy or PNG).
"""

from __future__ import annotations

import importlib
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import tokenize

import numpy as np
from scipy import ndimage

from ..errors import SonarsimError, shown
from ..image.grid import PolarGrid, sector_area_m2
from .metrics import NORMALIZATIONS, mse, normalize_255, psnr, ssim_map, ssim_support
from .metrics import scores as _metrics

__all__ = [
    "DOMAINS", "MAX_FAN_PIXELS", "MIN_OVERLAP", "PlainImage", "compare_images", "load_image", "load_region",
]

#: Domains :func:`compare_images` can compare in.
DOMAINS = ("polar", "fan")

#: Smallest fraction of image A's coverage (area of its annular sector) that image B must cover
#: for :func:`compare_images` to resample B onto A's grid. Below it the comparison would rest on
#: a small corner of A and say little about the images.
MIN_OVERLAP = 0.5

#: Largest fan image (pixels) :func:`compare_images` builds: some ten float64 arrays of this
#: size are alive at once, so a pixel size typed in millimetres instead of metres must fail
#: with a message, not exhaust the memory.
MAX_FAN_PIXELS = 50_000_000
# Peak memory of a comparison per pixel of the larger polar image: the float64 copies, SSIM's
# filtered maps and the regions' masks. Measured: 20.6 GB peak for two 12000 x 12000 PNGs
# (143 bytes a pixel).
BYTES_PER_COMPARED_PIXEL = 160

# Geometry of two images is "the same" when their axes agree to these tolerances (metres,
# degrees): far below any bin or beam width, far above float round-off of a saved file.
_RANGE_ATOL_M = 1e-6
_AZIMUTH_ATOL_DEG = 1e-6



# --------------------------------------------------------------------------------------------
# Images with and without geometry
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PlainImage:
    """An image without sonar geometry (e.g. read from a PNG): a polar array only.

    It has the attributes :func:`compare_images` looks for, with ``None`` for the geometry,
    so it compares only with images of the same shape, and only in the polar domain.

    Attributes
    ----------
    polar : np.ndarray, shape (n_rows, n_cols), float32
        The pixel values, as read (0-255 for an 8-bit PNG).
    source : str
        Where it came from (a file name), for messages.
    range_m, azimuth_deg, sonar : None
        No geometry.
    """

    polar: np.ndarray
    source: str = ""
    range_m: None = None
    azimuth_deg: None = None
    sonar: None = None


def _name(image: Any, default: str) -> str:
    return str(getattr(image, "source", "") or default)


def _polar_of(image: Any, name: str) -> np.ndarray:
    polar = getattr(image, "polar", None)
    if polar is None:
        raise SonarsimError(f"{name}: not an image (no polar array)")
    arr = np.asarray(polar)
    if arr.ndim != 2 or arr.dtype.kind not in "biuf" or 0 in arr.shape:
        raise SonarsimError(
            f"{name}: the polar image must be a non-empty 2-D real array, got shape "
            f"{arr.shape} of {arr.dtype}"
        )
    if not np.all(np.isfinite(arr)):
        raise SonarsimError(f"{name}: the image contains NaN or infinite values")
    return arr


def _geometry_of(image: Any, polar: np.ndarray, name: str) -> PolarGrid | None:
    """The polar grid of a SonarImage-like object, or None for an image without one."""
    sonar = getattr(image, "sonar", None)
    if sonar is not None:
        geom = sonar.grid
    else:
        range_m = getattr(image, "range_m", None)
        azimuth = getattr(image, "azimuth_deg", None)
        if range_m is None or azimuth is None:
            return None
        rmin, rmax = _range_window(np.asarray(range_m, dtype=np.float64), name)
        az = np.asarray(azimuth, dtype=np.float64).ravel()
        if az.size > 1 and not np.all(np.diff(az) < 0):
            raise SonarsimError(f"{name}: azimuth_deg must be strictly descending (left beam first)")
        try:
            # A lone beam is 1 degree wide, as for a sonar.
            geom = PolarGrid(rmin, rmax, int(np.size(range_m)), az, single_beam_width_deg=1.0)
        except ValueError as exc:
            raise SonarsimError(f"{name}: {exc}") from None
    if polar.shape != (geom.n_range_bins, geom.n_beams):
        raise SonarsimError(
            f"{name}: the polar image has shape {polar.shape} but its geometry has "
            f"{geom.n_range_bins} range bins and {geom.n_beams} beams"
        )
    return geom


def _range_window(range_m: np.ndarray, name: str) -> tuple[float, float]:
    """``(range_min_m, range_max_m)`` from uniformly spaced bin centres
    (:func:`sonarsim.io.readers.npz.range_window`, naming ``name``)."""
    from ..io.readers.npz import range_window

    try:
        return range_window(range_m)
    except ValueError as exc:
        raise SonarsimError(f"{name}: {exc}") from None


def _same_grid(ga: PolarGrid, gb: PolarGrid) -> bool:
    return (
        ga.n_range_bins == gb.n_range_bins
        and ga.n_beams == gb.n_beams
        and np.allclose(ga.range_m, gb.range_m, rtol=0.0, atol=_RANGE_ATOL_M)
        and np.allclose(ga.azimuth_deg, gb.azimuth_deg, rtol=0.0, atol=_AZIMUTH_ATOL_DEG)
    )


def _overlap_fraction(ga: PolarGrid, gb: PolarGrid) -> float:
    """Fraction of A's coverage (annular sector area) that B's coverage also covers."""
    inter = sector_area_m2(
        max(ga.range_min_m, gb.range_min_m), min(ga.range_max_m, gb.range_max_m),
        min(ga.left_edge_deg, gb.left_edge_deg), max(ga.right_edge_deg, gb.right_edge_deg),
    )
    return inter / ga.area_m2


def _differences(ga: PolarGrid, gb: PolarGrid) -> str:
    """What differs between two grids, for messages."""
    out = []
    if not (
        math.isclose(ga.range_min_m, gb.range_min_m, abs_tol=_RANGE_ATOL_M)
        and math.isclose(ga.range_max_m, gb.range_max_m, abs_tol=_RANGE_ATOL_M)
    ):
        out.append(
            f"ranges {ga.range_min_m:g}-{ga.range_max_m:g} m vs {gb.range_min_m:g}-{gb.range_max_m:g} m"
        )
    if ga.n_range_bins != gb.n_range_bins:
        out.append(f"range bins {ga.n_range_bins} vs {gb.n_range_bins}")
    if not (
        math.isclose(ga.left_edge_deg, gb.left_edge_deg, abs_tol=_AZIMUTH_ATOL_DEG)
        and math.isclose(ga.right_edge_deg, gb.right_edge_deg, abs_tol=_AZIMUTH_ATOL_DEG)
    ):
        out.append(
            f"fields of view {ga.azimuth_fov_deg:.4g} deg ({ga.left_edge_deg:+.4g} to "
            f"{ga.right_edge_deg:+.4g}) vs {gb.azimuth_fov_deg:.4g} deg ({gb.left_edge_deg:+.4g} to "
            f"{gb.right_edge_deg:+.4g})"
        )
    if ga.n_beams != gb.n_beams:
        out.append(f"beams {ga.n_beams} vs {gb.n_beams}")
    elif not np.allclose(ga.azimuth_deg, gb.azimuth_deg, rtol=0.0, atol=_AZIMUTH_ATOL_DEG):
        out.append("beam angle tables differ")
    return "; ".join(out) or "no difference"


def _resample_polar(polar: np.ndarray, src: PolarGrid, dst: PolarGrid) -> tuple[np.ndarray, np.ndarray]:
    """Image ``polar`` on grid ``src`` sampled at the bin centres of grid ``dst``.

    Bilinear in (range, azimuth): the fractional range index is linear in range, the
    fractional beam index piecewise linear in azimuth between ``src``'s beam centres (as in
    :mod:`sonarsim.image.fan`, so non-uniform lens tables work). Between ``src``'s outermost
    centres and its coverage edges the edge bin/beam is used; outside its coverage the result
    is 0 and the returned mask is False.

    Returns
    -------
    values : np.ndarray, shape (dst.n_range_bins, dst.n_beams), float64
    covered : np.ndarray, same shape, bool
    """
    r = dst.range_m
    theta = dst.azimuth_deg
    r_idx = (r - src.range_min_m) / src.range_resolution_m - 0.5
    # np.interp wants increasing sample points: feed the descending table reversed.
    b_idx = np.interp(theta, src.azimuth_deg[::-1], np.arange(src.n_beams, dtype=np.float64)[::-1])
    rr, bb = np.meshgrid(r_idx, b_idx, indexing="ij")
    values = ndimage.map_coordinates(
        np.asarray(polar, dtype=np.float64), [rr, bb], order=1, mode="nearest"
    )
    covered = ((r >= src.range_min_m) & (r <= src.range_max_m))[:, None] & (
        (theta <= src.left_edge_deg) & (theta >= src.right_edge_deg)
    )[None, :]
    values[~covered] = 0.0
    return values, covered


def _fan_pixels(geom: PolarGrid, pixel_size_m: float) -> float:
    """Size of the fan image of ``geom`` (as :func:`sonarsim.image.fan.fan_geometry` lays it out)."""
    half_fov = math.radians(max(abs(geom.left_edge_deg), abs(geom.right_edge_deg)))
    # In floats: a pixel of 5e-324 m makes the ratio infinite, which no integer (math.ceil) holds.
    rows = max(1.0, geom.range_max_m / pixel_size_m)
    return rows * 2.0 * max(1.0, geom.range_max_m * math.sin(half_fov) / pixel_size_m)


def _fan(polar: np.ndarray, geom: PolarGrid, pixel_size_m: float):
    from ..image.fan import FanMapper

    return FanMapper.from_grid(geom, pixel_size_m, "linear")(polar)


def _onto_grid(values: np.ndarray, src, dst) -> np.ndarray:
    """Copy an array on fan grid ``src`` onto fan grid ``dst`` (zeros where ``src`` has none).

    ``src`` and ``dst`` are :class:`~sonarsim.image.fan.FanImage` objects with the same pixel size.
    Such grids are aligned (pixel centres at half-integer multiples of the pixel size from
    the apex), so this is a shift by whole pixels, with no interpolation.
    """
    p = dst.pixel_size_m
    # Row i of dst has x = dst.x_m[i]; the same x is row i + dr of src (rows count from the far
    # end, so a longer fan has more rows above). Likewise for columns from the left.
    dr = round(float(src.x_m[0] - dst.x_m[0]) / p)
    dc = round(float(src.y_m[0] - dst.y_m[0]) / p)
    h, w = dst.shape
    out = np.zeros((h, w), dtype=values.dtype)
    i0, i1 = max(0, -dr), min(h, src.shape[0] - dr)
    j0, j1 = max(0, -dc), min(w, src.shape[1] - dc)
    if i1 > i0 and j1 > j0:
        out[i0:i1, j0:j1] = values[i0 + dr:i1 + dr, j0 + dc:j1 + dc]
    return out


def compare_images(
    a: Any,
    b: Any,
    domains: tuple[str, ...] = DOMAINS,
    pixel_size_m: float | None = None,
    *,
    normalize: str | None = "max",
    data_range: float = 255.0,
    names: tuple[str, str] | None = None,
    stats: bool = False,
    regions: Mapping[str, Any] | None = None,
    held_out: Sequence[Any] | None = None,
    frame_numbers: Sequence[int] | None = None,
) -> dict[str, Any]:
    """MSE, PSNR and SSIM between two sonar images, in the polar and fan domains.

    Each image is normalised to 0-255 (:func:`normalize_255`, ``normalize`` mode) over the
    pixels compared in each domain, then compared there (the paper's Table I):

    * ``"polar"``: on A's polar grid. If B's grid differs (range window, number of bins, beam
      angles), B is resampled onto A's bin centres (bilinear in range and azimuth, zero
      outside B's coverage) and only A's bins inside B's coverage count.
    * ``"fan"``: both images scan-converted (:mod:`sonarsim.image.fan`, linear) to Cartesian fans
      with the same pixel size, on A's fan grid; only pixels inside both fans count. B is
      converted from its own polar grid, so it is interpolated once, not twice.

    Parameters
    ----------
    a, b : SonarImage or SonarImage-like
        Objects with ``polar`` ((n_range_bins, n_beams) array) and either ``sonar`` (a
        :class:`~sonarsim.SonarConfig`) or ``range_m`` (uniform bin centres, metres) and
        ``azimuth_deg`` (descending beam centres, degrees), as returned by
        :func:`load_image`. A :class:`PlainImage` (no geometry) compares only with an image of
        the same shape, pixel by pixel, and only in the polar domain.
    domains : tuple of {"polar", "fan"}
        Domains to compare in. ``"fan"`` is skipped (see ``info["skipped"]``) when an image
        has no geometry.
    pixel_size_m : float, optional
        Fan pixel edge, metres, > 0. Default: A's range resolution.
    normalize : {"max", "minmax"} or None
        Normalisation to 0-255 of each image (see :func:`normalize_255`); None compares the
        values as they are (e.g. two 8-bit images already on the same scale).
    data_range : float
        Peak value for PSNR and SSIM: 255 for normalised images.
    names : (str, str), optional
        What to call A and B in messages (e.g. their file names). Default: a PlainImage's
        ``source``, else "image A" and "image B".
    stats : bool
        Also describe texture and distributions per region of A (``"all"`` and the regions of
        :func:`sonarsim.analysis.realism.auto_regions`), in the images' own units, as
        ``"stats": {region: region_statistics(...)}``.
    regions : dict of str to (n_range_bins, n_beams) bool array, optional
        More regions for the statistics (implies ``stats``), given as masks on A's polar grid
        (e.g. hand-labelled objects and shadows; :func:`load_region` reads them from files).
        Each is reported after the automatic ones, restricted, like them, to A's bins inside
        B's coverage. Their names must differ from ``"all"`` and those of
        :data:`sonarsim.analysis.realism.REGIONS`.
    held_out : sequence of SonarImage-like, optional
        With ``stats``: other real frames of A's recording, on A's grid (implies ``stats``).
        A is then the reference (calibration) frame and B the model, and
        ``"realism"`` holds :func:`sonarsim.analysis.bands.realism_report` of B against them: the
        trivial images and the ceiling made from A, scored with B (in the images' own units,
        data range ``data_range``) on these frames, the margin over the best trivial image, the
        statistics per range band, the beam profile and the classifier two-sample test. Without
        held-out frames (None or empty) everything is scored against A itself, which favours
        the trivial images made from A and a B calibrated on A: the report says so
        (``optimistic``). B serves as both the expected and the speckled model.
    frame_numbers : sequence of int, optional
        The recording's numbers of A and of the ``held_out`` frames, for the report's labels.

    Returns
    -------
    dict
        ``{domain: {"mse", "psnr", "ssim", "n_pixels", "n_ssim_pixels"}}`` for each domain
        compared (MSE in squared grey levels, PSNR in dB (``inf`` if identical), SSIM
        (NaN when no 11 x 11 window fits in the compared region), the number of compared
        pixels and of pixels SSIM is averaged over); with ``stats``, ``"stats"`` (per region) and
        ``"realism"`` (see ``held_out``); and ``"info"``: ``{"normalize",
        "resampled" (bool: B was resampled onto A's grid), "overlap" (fraction of A's coverage
        area that B covers, 1 for the same grid; None without geometry), "pixel_size_m"
        (fan pixel size, None if no fan), "skipped" ({domain: reason})}``.

    Raises
    ------
    SonarsimError
        When the images cannot be compared: different shapes without geometry, coverages
        overlapping on less than :data:`MIN_OVERLAP` of A's area (the message says what
        differs), unknown domains or normalisation, a bad pixel size or one that would make a
        fan image of more than :data:`MAX_FAN_PIXELS` pixels, non-finite values; a region
        that is not a boolean array of A's shape or has an automatic region's name.
    """
    domains = tuple(domains)
    unknown = [d for d in domains if d not in DOMAINS]
    if unknown or not domains:
        raise SonarsimError(
            f"domains must be a non-empty selection of {', '.join(DOMAINS)}, got {list(domains)}"
        )
    if normalize is not None and normalize not in NORMALIZATIONS:
        raise SonarsimError(
            f"normalize must be one of {', '.join(NORMALIZATIONS)} or None, got {normalize!r}"
        )
    if pixel_size_m is not None:
        try:
            pixel_size_m = float(pixel_size_m)
        except (TypeError, ValueError):
            raise SonarsimError(f"pixel size must be a positive number of metres, got {pixel_size_m!r}") from None
        if not (math.isfinite(pixel_size_m) and pixel_size_m > 0.0):
            raise SonarsimError(f"pixel size must be a positive number of metres, got {pixel_size_m!r}")

    if names is not None:
        name_a, name_b = map(str, names)
    else:
        name_a, name_b = _name(a, "image A"), _name(b, "image B")
    pa, pb = _polar_of(a, name_a), _polar_of(b, name_b)
    from ..core.memory import require

    require(float(max(pa.size, pb.size)) * BYTES_PER_COMPARED_PIXEL,
            f"comparing images of {pa.shape[0]} x {pa.shape[1]} and {pb.shape[0]} x {pb.shape[1]} pixels", "")
    ga, gb = _geometry_of(a, pa, name_a), _geometry_of(b, pb, name_b)
    given = _given_regions(regions, pa.shape, name_a)
    held = _held_out_frames(held_out, pa.shape, ga, name_a)
    info: dict[str, Any] = {
        "normalize": normalize, "resampled": False, "overlap": None, "pixel_size_m": None,
        "skipped": {},
    }
    result: dict[str, Any] = {}

    if ga is None or gb is None:
        if pa.shape != pb.shape:
            which = name_a if ga is None else name_b
            raise SonarsimError(
                f"cannot compare {name_a} (shape {pa.shape}) with {name_b} (shape {pb.shape}): "
                f"{which} has no sonar geometry (range bins and beam angles, e.g. a PNG), so it "
                "can only be compared with an image of the same shape"
            )
        b_on_a = pb.astype(np.float64)
        polar_mask = np.ones(pa.shape, dtype=bool)
    elif _same_grid(ga, gb):
        info["overlap"] = 1.0
        b_on_a = pb.astype(np.float64)
        polar_mask = np.ones(pa.shape, dtype=bool)
    else:
        overlap = _overlap_fraction(ga, gb)
        info["overlap"] = overlap
        if overlap < MIN_OVERLAP:
            raise SonarsimError(
                f"cannot compare {name_a} with {name_b}: their geometries differ "
                f"({_differences(ga, gb)}) and {name_b} covers only {100 * overlap:.3g} % of "
                f"the area seen by {name_a} (at least {100 * MIN_OVERLAP:g} % is needed to "
                f"resample it onto {name_a}'s grid)"
            )
        b_on_a, polar_mask = _resample_polar(pb, gb, ga)
        info["resampled"] = True

    if "polar" in domains:
        result["polar"] = _metrics(pa, b_on_a, polar_mask, normalize, data_range)
    if stats or given or held:
        # Texture and distributions per region of A, in the images' own units (no renormalising:
        # compare a simulation in the device's counts with a recording).
        from .bands import realism_report
        from .realism import auto_regions, region_statistics

        masks = {"all": polar_mask, **auto_regions(pa, polar_mask)}
        masks.update((name, m & polar_mask) for name, m in given.items())
        result["stats"] = {name: region_statistics(pa, b_on_a, m) for name, m in masks.items()}
        try:
            result["realism"] = realism_report(
                [pa, *held], b_on_a, b_on_a, 0, mask=polar_mask, data_range=data_range,
                range_m=None if ga is None else ga.range_m, frame_numbers=frame_numbers)
        except ValueError as exc:
            raise SonarsimError(f"cannot score {name_b} against {name_a}'s baselines: {exc}") from None

    if "fan" in domains:
        if ga is None or gb is None:
            info["skipped"]["fan"] = (
                f"{name_a if ga is None else name_b} has no sonar geometry (e.g. a PNG)"
            )
        else:
            p = pixel_size_m if pixel_size_m is not None else ga.range_resolution_m
            info["pixel_size_m"] = p
            for g, n in ((ga, name_a), (gb, name_b)):
                if _fan_pixels(g, p) > MAX_FAN_PIXELS:
                    raise SonarsimError(
                        f"a fan pixel size of {p:g} m is too small for {n}: its fan image "
                        f"would have {_fan_pixels(g, p):.3g} pixels (at most "
                        f"{MAX_FAN_PIXELS:.3g}); give a larger pixel size"
                    )
            fa, fb = _fan(pa, ga, p), _fan(pb, gb, p)
            image_b = _onto_grid(fb.image, fb, fa)
            mask_b = _onto_grid(np.asarray(fb.mask), fb, fa)
            mask = np.asarray(fa.mask) & mask_b
            if not mask.any():
                raise SonarsimError(
                    f"no fan pixel of {p:g} m lies inside both fans; use a smaller pixel size"
                )
            result["fan"] = _metrics(fa.image, image_b, mask, normalize, data_range)

    result["info"] = info
    return result


def _held_out_frames(frames: Sequence[Any] | None, shape: tuple[int, int], grid: PolarGrid | None,
                     name_a: str) -> list[np.ndarray]:
    """``held_out`` checked: polar arrays on A's grid (a baseline is scored pixel by pixel)."""
    out = []
    for k, frame in enumerate(frames or ()):
        name = _name(frame, f"held-out frame {k}")
        polar = _polar_of(frame, name)
        g = _geometry_of(frame, polar, name)
        if polar.shape != shape or (grid is not None and g is not None and not _same_grid(grid, g)):
            raise SonarsimError(
                f"{name}: a held-out frame must lie on {name_a}'s grid ({shape[0]} range bins x {shape[1]} beams"
                + ("" if grid is None or g is None else f"; {_differences(grid, g)}") + f"), got {polar.shape}")
        out.append(polar.astype(np.float64))
    return out


def _given_regions(regions: Mapping[str, Any] | None, shape: tuple[int, int], name_a: str) -> dict[str, np.ndarray]:
    """``regions`` checked: names free, boolean masks of A's shape."""
    from .realism import REGIONS

    if regions is None:
        return {}
    if not isinstance(regions, Mapping):
        raise SonarsimError(f"regions must be a dict of name to boolean mask, got {type(regions).__name__}")
    out = {}
    for name, mask in regions.items():
        if not isinstance(name, str) or not name:
            raise SonarsimError(f"region names must be non-empty strings, got {name!r}")
        if name in ("all", *REGIONS):
            raise SonarsimError(
                f"region {name!r}: the name of an automatic region ({', '.join(('all', *REGIONS))}); "
                "choose another"
            )
        m = np.asarray(mask)
        if m.dtype != bool:
            raise SonarsimError(f"region {name!r}: the mask must be a boolean array, got {m.dtype}")
        if m.shape != shape:
            raise SonarsimError(
                f"region {name!r}: the mask has shape {m.shape} but {name_a}'s polar image has "
                f"{shape[0]} range bins and {shape[1]} beams {shape}"
            )
        out[name] = m
    return out


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------

_ZIP_MAGIC = b"PK\x03\x04"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_NPY_MAGIC = b"\x93NUMPY"


def _check_npy_size(path: str | os.PathLike, name: str) -> None:
    """Refuse a ``.npy`` file whose header declares more than the memory budget (NumPy would
    allocate it before reading: a 100-byte file can ask for terabytes)."""
    from ..core.memory import require

    try:
        with open(path, "rb") as handle:
            version = np.lib.format.read_magic(handle)
            read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                           else np.lib.format.read_array_header_2_0)
            shape, _, dtype = read_header(handle)
    except (OSError, ValueError) as exc:
        raise SonarsimError(f"{name}: cannot read the .npy array: {exc}") from None
    require(float(math.prod(shape)) * dtype.itemsize, f"the region {name}, an array of shape {shape},", "")


def load_region(path: str | os.PathLike) -> np.ndarray:
    """Read a region (a mask on a polar grid) from a file, for ``compare_images(regions=...)``.

    The format is told by the file's first bytes:

    * a ``.npy`` array (:func:`numpy.save`), 2-D, of booleans, or of integers whose non-zero
      values are the region; row 0 is the nearest range bin, column 0 the left-most beam, as
      in a polar image;
    * a PNG whose non-zero pixels (in any colour channel; alpha is ignored) are the region,
      drawn as sonarsim draws polar PNGs: far range at the top, so its rows are flipped on
      reading (as :func:`load_image` does), and a mask painted over A's polar PNG fits A.

    Returns
    -------
    (n_range_bins, n_beams) bool ndarray

    Raises
    ------
    SonarsimError
        Naming the file: missing or unreadable, neither format, not 2-D, not boolean or
        integer.
    """
    from ..errors import check_input_file

    name = os.fspath(path)
    if os.path.lexists(path):  # a FIFO would block the open below for ever (missing: "no such file")
        check_input_file(path, "region file (.npy or PNG)")
    try:
        with open(path, "rb") as handle:
            head = handle.read(8)
    except FileNotFoundError:
        raise SonarsimError(f"{name}: no such file") from None
    except OSError as exc:
        raise SonarsimError(f"{name}: cannot read: {exc.strerror or exc}") from None
    if head.startswith(_NPY_MAGIC):
        _check_npy_size(path, name)
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, SyntaxError, tokenize.TokenError) as exc:  # (a mangled header)
            raise SonarsimError(f"{name}: cannot read the .npy array: {exc}") from None
        if arr.ndim != 2:
            raise SonarsimError(f"{name}: a region must be a 2-D array (range bins, beams), got shape {arr.shape}")
        if arr.dtype.kind not in "biu":
            raise SonarsimError(
                f"{name}: a region must hold booleans (or integers, non-zero in the region), got {arr.dtype}"
            )
        return arr != 0
    if head.startswith(_PNG_MAGIC):
        from PIL import UnidentifiedImageError

        try:
            with _open_png(path, name, "the region") as im:
                im.load()
                if im.mode in ("1", "L", "I", "I;16", "I;16B", "I;16L", "F"):
                    arr = np.asarray(im)
                else:
                    arr = np.asarray(im.convert("RGB")).any(axis=2)
        except SonarsimError:  # the budget's refusal (a ValueError too) says enough
            raise
        except (OSError, UnidentifiedImageError, ValueError) as exc:
            raise SonarsimError(f"{name}: cannot read the PNG: {exc}") from None
        return np.ascontiguousarray(arr[::-1] != 0)
    raise SonarsimError(f"{name}: not a region: expected a .npy array (numpy.save) or a PNG")


def load_image(path: str | os.PathLike, frame: int | None = None, component: str | None = None):
    """Read one sonar image from a file, for :func:`compare_images`.

    The format is told by the file's first bytes, not its name:

    * an NPZ written by sonarsim (:meth:`SonarImage.save_npz`, :func:`sonarsim.io.output.read_npz`;
      keys ``polar``, ``range_m``, ``azimuth_deg``, ``config_json``): a
      :class:`~sonarsim.SonarImage` whose :class:`~sonarsim.SonarConfig` is rebuilt from the
      axes (range window from the uniform bin centres, beam table from ``azimuth_deg``) and
      from the configuration (elevation aperture, 14 deg if absent; beam width); its ``pose``
      is the configuration's ``sonar.pose`` (None if absent or unreadable). Its
      ``components`` are the stored echo components (not the label maps); ``rays`` is None.
      Read by :func:`sonarsim.io.readers.npz.load_stored_image`, the loader ``sonarsim.read``
      and ``show`` use (``geometry="axes"``); an image holding NaN or infinities is refused.
    * a PNG: a :class:`PlainImage` (no geometry) holding the grey levels as float32 (colour is
      converted to luma by Pillow; 16-bit and float images keep their values). Rows are
      flipped on reading, because sonarsim draws polar PNGs with far range at the top, so that
      row 0 is the nearest range bin as in a polar array. A flip does not change MSE, PSNR or
      SSIM between two PNGs.
    * anything else: a real recording, read by ``sonarsim.io.readers.read(path, frame)``
      (ARIS, Oculus, ...).

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    frame : int, optional
        Frame of a recording, from 0 (default 0). NPZ and PNG files hold one frame: only 0
        or None is accepted.
    component : str, optional
        NPZ only: the array to compare instead of ``polar``, e.g. ``"single"`` (the paper's
        "Single" rows of Table I) or ``"triple"``.

    Returns
    -------
    SonarImage, PlainImage or what ``sonarsim.io.readers.read`` returns
        An object with ``polar`` and, where known, the geometry (``sonar``, ``range_m``,
        ``azimuth_deg``); it also has ``source`` set to the path when it is a PlainImage.

    Raises
    ------
    SonarsimError
        For a missing or unreadable file, an NPZ that is not sonarsim's, a frame other than 0
        of a one-frame file, an unknown component, or a recording when
        :mod:`sonarsim.io.readers` is not available.
    """
    p = Path(path)
    name = os.fspath(path)
    if frame is not None and (
        isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer)) or frame < 0
    ):
        raise SonarsimError(f"{name}: frame must be an integer >= 0, got {frame!r}")
    from ..errors import check_input_file

    if os.path.lexists(p):  # a FIFO would block the open below for ever (missing: "no such file")
        check_input_file(p, "image file (NPZ, PNG or recording)")
    try:
        with open(p, "rb") as handle:
            head = handle.read(8)
    except FileNotFoundError:
        raise SonarsimError(f"{name}: no such file") from None
    except OSError as exc:
        raise SonarsimError(f"{name}: cannot read: {exc.strerror or exc}") from None

    if head.startswith((_ZIP_MAGIC, _PNG_MAGIC)):
        if frame not in (None, 0):
            raise SonarsimError(f"{name}: holds a single frame; frame {frame} does not exist")
        if component is not None and not head.startswith(_ZIP_MAGIC):
            raise SonarsimError(f"{name}: a PNG has no components; {component!r} was asked for")
        if head.startswith(_ZIP_MAGIC):
            return _load_npz(p, name, component)
        return _load_png(p, name)

    if component is not None:
        raise SonarsimError(f"{name}: components ({component!r}) exist only in sonarsim NPZ files")
    try:
        # Imported here, through sys.modules: the readers are not needed to compare simulated
        # images, and a missing or broken readers module must only fail this case.
        readers = importlib.import_module("sonarsim.io.readers")
    except ImportError as exc:
        raise SonarsimError(
            f"{name}: not a sonarsim NPZ or a PNG, and the readers of sonar recordings "
            f"(sonarsim.io.readers) are not available ({exc})"
        ) from None
    return readers.read(p, 0 if frame is None else int(frame))


def _open_png(path: str | os.PathLike, name: str, what: str):
    """``Image.open(path)`` whose size is checked against the memory budget before its pixels
    are decoded (``what`` and :data:`BYTES_PER_COMPARED_PIXEL` a pixel); SonarsimError naming
    ``name`` for a file Pillow cannot read or refuses as a decompression bomb."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    from ..core.memory import require

    try:
        # Our memory budget decides what is too large, so Pillow's decompression-bomb warning
        # (at 89 Mpx) is not shown; its error (at 179 Mpx, whatever the budget) is one line.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path)
    except Image.DecompressionBombError as exc:
        raise SonarsimError(f"{name}: too large a PNG to read: {exc}") from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise SonarsimError(f"{name}: cannot read the PNG: {exc}") from None
    width, height = im.size
    try:
        require(float(width) * height * BYTES_PER_COMPARED_PIXEL, f"{what} {name}, a PNG of {width} x {height} "
                "pixels,", "")
    except SonarsimError:
        im.close()
        raise
    return im


def _load_png(p: Path, name: str) -> PlainImage:
    from PIL import UnidentifiedImageError

    try:
        with _open_png(p, name, "comparing") as im:
            im.load()
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):
                arr = np.asarray(im)
            else:
                arr = np.asarray(im.convert("L"))
    except SonarsimError:  # the budget's refusal (a ValueError too) says enough
        raise
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise SonarsimError(f"{name}: cannot read the PNG: {exc}") from None
    polar = np.ascontiguousarray(arr[::-1], dtype=np.float32)
    return PlainImage(polar=polar, source=name)


def _load_npz(p: Path, name: str, component: str | None):
    # The one loader of stored images (sonarsim.read and show use it too); the geometry from
    # the axes, so that any image with axes compares.
    from ..io.readers.npz import load_stored_image

    return load_stored_image(p, component, geometry="axes")
