"""Sea-floor texture: a world-anchored, log-normal reflectivity field over a plane.

Real sea floors are patchy: their backscatter varies over metres, roughly log-normally, often
with an anisotropic correlation (sand ripples, trawl marks, patches of shell or mud). A plane's
``texture`` (:class:`~sonarsim.config.scene.TextureSpec`) models this with a few parameters:

    F(x) = 10 ** (std_db * g(x) / 10) / E = exp(s g(x) - s**2 / 2),   s = std_db ln(10) / 10,

where ``g`` is a stationary Gaussian field of zero mean and unit variance over the plane, and
``E = exp(s**2 / 2)`` makes the mean of ``F`` exactly 1 (the expected level of the floor is the
untextured plane's). The correlation of ``g`` at a lag ``h`` (metres, along the field's two
axes, which are turned by ``angle_deg`` from the plane's axes) is ``rho(|h / l|)`` with
``|h / l| = hypot(h_1 / l_1, h_2 / l_2)``, ``rho(q) = exp(-q**2)`` (``gaussian``) or
``exp(-q)`` (``exponential``): it falls to ``1/e`` at one correlation length along each axis.
``F`` itself has the correlation ``(exp(s**2 rho) - 1) / (exp(s**2) - 1)``.

The field lives in WORLD coordinates of the plane (:func:`plane_axes`), not in the sonar's: a
still scene shows the same texture every ping, and a moved sonar sees the same floor. It is
made once per field, deterministically from its seed: a periodic tile of ``TILE_CELLS**2``
cells (in units of the correlation lengths, so anisotropy costs nothing), ``g`` on the tile
drawn exactly by circulant embedding (seeded white noise filtered with the square root of the
covariance's discrete spectrum), looked up with bilinear interpolation and divided by the
interpolant's exact standard deviation at that point (bilinear interpolation of a correlated
field loses some variance between grid nodes; this restores unit variance everywhere, so that
``std_db`` and the mean of ``F`` hold exactly). The tile WRAPS: the texture repeats every
:attr:`ReflectivityField.period_m` (128 correlation lengths along each axis for the Gaussian
covariance, 64 for the exponential one, whose finer cells resolve its rough small scales).

Where a texture applies: each path that scatters off the plane (its direct echo, and every
multipath whose scattering point lies on it) takes the factor ``F`` at its scattering point;
the factor scales the plane's whole backscatter law (a patch of coarser sediment is brighter at
every angle), unlike a mesh texture's brightness, which scales only the diffuse part of an
object's law. Reflections (the specular reflectance R) are not textured.

:func:`estimate_texture` estimates ``std_db`` and the correlation lengths from speckled images
of a floor (what ``calibrate`` can fit the texture with).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..config.scene import TEXTURE_COVARIANCES, PlaneSpec, TextureSpec
from ..core.memory import require

# The texture's random stream: ``[seed, TEXTURE_STREAM]`` (a seed given) or
# ``[render.seed, TEXTURE_STREAM, plane index + 1]``; defined with every other stream in
# core.streams (TEXTURE_STREAM stays importable from here).
from ..core.streams import TEXTURE_STREAM, texture_entropy, texture_rng

# Cells along each axis of the periodic tile.
TILE_CELLS = 1024
# Tile cells per correlation length: enough that bilinear interpolation keeps the covariance at
# one cell's lag within 2 % (Gaussian: 1 - exp(-1/64)); the exponential covariance is rough at
# every scale and gets finer cells.
CELLS_PER_LENGTH = {"gaussian": 8, "exponential": 16}
LN10_OVER_10 = math.log(10.0) / 10.0


def correlation(q: np.ndarray, covariance: str) -> np.ndarray:
    """The correlation of the unit field ``g`` at normalised lags ``q = |h / l|`` (closed form).

    Parameters
    ----------
    q : (...) float array
        Lag in correlation lengths, dimensionless, >= 0.
    covariance : {'gaussian', 'exponential'}

    Returns
    -------
    (...) float64 ndarray, in [0, 1]
    """
    q = np.asarray(q, dtype=np.float64)
    if covariance == "gaussian":
        return np.exp(-q * q)
    if covariance == "exponential":
        return np.exp(-q)
    raise ValueError(f"unknown covariance {covariance!r}; allowed: {', '.join(TEXTURE_COVARIANCES)}")


def field_correlation(spec: TextureSpec, lag_m: np.ndarray) -> np.ndarray:
    """Correlation of ``g`` between two points of the plane ``lag_m`` apart (closed form).

    Parameters
    ----------
    spec : TextureSpec
    lag_m : (..., 2) float array
        Lags in the PLANE's coordinates (:func:`plane_axes`), metres.

    Returns
    -------
    (...) float64 ndarray
    """
    lag = np.asarray(lag_m, dtype=np.float64)
    a = math.radians(spec.angle_deg)
    c, s = math.cos(a), math.sin(a)
    along = (c * lag[..., 0] + s * lag[..., 1]) / spec.correlation_m[0]
    across = (-s * lag[..., 0] + c * lag[..., 1]) / spec.correlation_m[1]
    return correlation(np.hypot(along, across), spec.covariance)


def plane_axes(normal) -> np.ndarray:
    """Two orthonormal axes ``(u, v)`` in a plane with unit normal ``normal``, world frame.

    ``u`` is the world x axis projected onto the plane (the y axis where x is nearly normal to
    it), ``v = normal x u``: for the ground (normal +z) the axes are world x and y. A point
    ``p`` has plane coordinates ``(u . p, v . p)``, metres (their origin: the world origin's
    projection onto the plane).

    Parameters
    ----------
    normal : (3,) float array, unit vector

    Returns
    -------
    (2, 3) float64 ndarray, rows u and v
    """
    n = np.asarray(normal, dtype=np.float64)
    axis = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = axis - np.dot(axis, n) * n
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)])


@functools.lru_cache(maxsize=4)
def unit_tile(covariance: str, entropy: tuple[int, ...]) -> tuple[np.ndarray, tuple[float, ...]]:
    """The periodic tile of a unit-variance field with unit correlation lengths (cached).

    Circulant embedding: the covariance at the tile's wrapped lags has a real, non-negative
    discrete spectrum ``lambda`` (negative round-off clipped to 0); white noise filtered with
    ``sqrt(lambda)`` has exactly that circulant covariance.

    Parameters
    ----------
    covariance : {'gaussian', 'exponential'}
    entropy : tuple of int
        Seeds the generator (``numpy.random.default_rng(list(entropy))``,
        :func:`~sonarsim.core.streams.texture_rng`).

    Returns
    -------
    tile : (TILE_CELLS, TILE_CELLS) float64 ndarray, read-only
        ``g`` at the nodes; axis 0 along the field's first axis.
    lags : tuple of 5 float
        The tile's covariance at node lags (0, 0), (1, 0), (0, 1), (1, 1), (1, -1): what the
        bilinear interpolant's variance is made of.
    """
    n = TILE_CELLS
    # The lag grid, the spectrum, the noise, its transform and the field, float64 / complex128.
    require(6 * n * n * 8, "a floor texture's tile", "texture")
    per = CELLS_PER_LENGTH[covariance]
    k = np.minimum(np.arange(n), n - np.arange(n)) / per
    lam = np.fft.rfft2(correlation(np.hypot(k[:, None], k[None, :]), covariance)).real
    np.maximum(lam, 0.0, out=lam)
    rng = texture_rng(entropy)
    tile = np.fft.irfft2(np.sqrt(lam) * np.fft.rfft2(rng.standard_normal((n, n))), s=(n, n))
    cov = np.fft.irfft2(lam, s=(n, n))
    lags = tuple(float(cov[i, j]) for i, j in ((0, 0), (1, 0), (0, 1), (1, 1), (1, n - 1)))
    tile.setflags(write=False)
    return tile, lags


class ReflectivityField:
    """The texture of one plane: ``g`` and the factor ``F`` at world points on it.

    Parameters
    ----------
    spec : TextureSpec
    normal : (3,) float array
        The plane's unit normal (its axes: :func:`plane_axes`).
    entropy : tuple of int
        Seeds the tile (see :func:`texture_fields`).

    Notes
    -----
    The tile is made on first use and shared (:func:`unit_tile`, cached) between fields with
    the same covariance and seed; lengths and angle only scale and turn the lookup.
    """

    def __init__(self, spec: TextureSpec, normal, entropy: tuple[int, ...]) -> None:
        self.spec = spec
        self.entropy = tuple(int(e) for e in entropy)
        self.axes = plane_axes(normal)
        a = math.radians(spec.angle_deg)
        turn = np.array([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]])
        per = CELLS_PER_LENGTH[spec.covariance]
        # World point -> tile cells along the field's axes, in one (2, 3) matrix.
        self._to_cells = (np.array([per / spec.correlation_m[0], per / spec.correlation_m[1]])[:, None]
                          * (turn @ self.axes))
        self.s = spec.std_db * LN10_OVER_10  # std of ln F

    @property
    def period_m(self) -> tuple[float, float]:
        """The distance after which the texture repeats along each of its axes, metres."""
        cells = TILE_CELLS / CELLS_PER_LENGTH[self.spec.covariance]
        return (cells * self.spec.correlation_m[0], cells * self.spec.correlation_m[1])

    def plane_coordinates(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) float64: the plane coordinates (:func:`plane_axes`) of world points (n, 3), metres."""
        return np.asarray(points, dtype=np.float64).reshape(-1, 3) @ self.axes.T

    def log_field(self, points: np.ndarray) -> np.ndarray:
        """``g`` (zero mean, unit variance) at world points.

        Parameters
        ----------
        points : (n, 3) float array, metres
            Points on the plane (a point off it takes the value of its projection).

        Returns
        -------
        (n,) float64 ndarray
        """
        tile, (c0, cx, cy, cd, ca) = unit_tile(self.spec.covariance, self.entropy)
        n = TILE_CELLS
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        x = p @ self._to_cells[0]
        y = p @ self._to_cells[1]
        fx, fy = np.floor(x), np.floor(y)
        i0 = np.mod(fx, n).astype(np.intp)
        j0 = np.mod(fy, n).astype(np.intp)
        fx, fy = x - fx, y - fy
        i1 = np.where(i0 == n - 1, 0, i0 + 1)  # the tile wraps
        j1 = np.where(j0 == n - 1, 0, j0 + 1)
        flat = tile.reshape(-1)
        w00, w10, w01, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
        value = (w00 * flat[i0 * n + j0] + w10 * flat[i1 * n + j0] + w01 * flat[i0 * n + j1]
                 + w11 * flat[i1 * n + j1])
        # The interpolant's variance at this point within its cell, from the tile's own
        # covariance: dividing by its root gives unit variance everywhere.
        var = (c0 * (w00 * w00 + w10 * w10 + w01 * w01 + w11 * w11)
               + 2.0 * (cx * (w00 * w10 + w01 * w11) + cy * (w00 * w01 + w10 * w11) + cd * w00 * w11 + ca * w10 * w01))
        return value / np.sqrt(var)

    def factor(self, points: np.ndarray) -> np.ndarray:
        """The reflectivity factor ``F = exp(s g - s**2 / 2)`` (mean 1) at world points (n, 3).

        Returns
        -------
        (n,) float64 ndarray, > 0
        """
        return np.exp(self.s * self.log_field(points) - 0.5 * self.s * self.s)


def texture_fields(planes: Sequence[PlaneSpec], render_seed: int) -> tuple[ReflectivityField | None, ...]:
    """The fields of a scene's reflecting planes (``Scene.reflecting_planes``), by plane index.

    Parameters
    ----------
    planes : sequence of PlaneSpec
    render_seed : int
        ``render.seed``: seeds the textures that give no seed of their own (with the plane's
        index, so two such planes differ).

    Returns
    -------
    tuple of ReflectivityField or None
        None for a plane without texture or with ``std_db = 0`` (it renders as untextured,
        bit for bit).
    """
    out: list[ReflectivityField | None] = []
    for i, plane in enumerate(planes):
        t = plane.texture
        if t is None or not t.active:
            out.append(None)
            continue
        entropy = texture_entropy(render_seed, i, t.seed)
        out.append(ReflectivityField(t, plane.normal, entropy))
    return tuple(out)


def scale_by_texture(intensity: np.ndarray, sid: np.ndarray, points: np.ndarray,
                     fields: Sequence[ReflectivityField | None]) -> None:
    """Multiply, in place, the diffuse weight of the scatterers on textured planes by ``F``.

    Parameters
    ----------
    intensity : (n,) float64 ndarray
        Diffuse weights (a leg's ``intensity``), modified in place.
    sid : (n,) int array
        Surface of each scatterer: plane ``p`` is ``p`` (the index into ``fields``), -1 none,
        objects ``>= len(fields)``.
    points : (n, 3) float array
        The scatterers, world frame, metres.
    fields : sequence of ReflectivityField or None
        :func:`texture_fields`.
    """
    for p, field in enumerate(fields):
        if field is None:
            continue
        on = np.flatnonzero(sid == p)
        if len(on):
            intensity[on] *= field.factor(points[on])


# Estimating a texture from images -----------------------------------------------------------


@dataclass(frozen=True)
class TextureEstimate:
    """What :func:`estimate_texture` found.

    Attributes
    ----------
    std_db : float
        Standard deviation of the floor's reflectivity, dB.
    correlation_range_m, correlation_across_m : float
        Correlation lengths along the range direction and across the beams, metres on the floor.
    n_blocks : int
        Local-mean blocks used (over all frames).
    lags_range_m, lags_across_m : (k,) float64 ndarray
        Lags of the covariances below, metres.
    covariance_range, covariance_across : (k,) float64 ndarray
        Empirical covariance of the residual log local means at those lags (ln units squared).
    model_range, model_across : (k,) float64 ndarray
        The fitted model's covariance at those lags (texture plus speckle, after the trend's removal).
    """

    std_db: float
    correlation_range_m: float
    correlation_across_m: float
    n_blocks: int
    lags_range_m: np.ndarray
    lags_across_m: np.ndarray
    covariance_range: np.ndarray
    covariance_across: np.ndarray
    model_range: np.ndarray
    model_across: np.ndarray


def _block_means(image: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    """(n_bins // w_r, n_beams // w_b) means of non-overlapping blocks of ``window`` cells."""
    wr, wb = window
    nr, nb = image.shape[0] // wr, image.shape[1] // wb
    return image[: nr * wr, : nb * wb].reshape(nr, wr, nb, wb).mean(axis=(1, 3))


def _lag_covariance(res: np.ndarray, valid: np.ndarray, max_lag: int, axis: int,
                    start_valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sums of products of residuals ``lag`` blocks apart along ``axis`` over valid pairs, and
    their counts; ``start_valid`` restricts where a pair may start (default ``valid``)."""
    sums, counts = np.zeros(max_lag + 1), np.zeros(max_lag + 1)
    n = res.shape[axis]
    start_valid = valid if start_valid is None else start_valid
    for k in range(min(max_lag, n - 1) + 1):  # a handful of lags, each a whole-array product
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(0, n - k), slice(k, n)
        both = start_valid[tuple(a)] & valid[tuple(b)]
        sums[k] = float(np.sum(res[tuple(a)] * res[tuple(b)], where=both))
        counts[k] = float(both.sum())
    return sums, counts


def _triangle(w: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``d`` between two cells of blocks of ``w`` cells and how often each occurs (sums to 1)."""
    d = np.arange(-(w - 1), w)
    return d, (w - np.abs(d)) / float(w * w)


def _model(lr: float, lb: float, covariance: str, window: tuple[int, int], cell_m: tuple[float, float],
           max_lag: tuple[int, int], n_row: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Texture part of the model covariances (unit variance) along range and across beams.

    The correlation of two block means is the mean of ``rho`` over their cells' pairs; removing
    each block row's mean (over ``n_row`` blocks) subtracts that row's mean covariance ``B``.
    """
    (dr, wr), (db, wb) = _triangle(window[0]), _triangle(window[1])
    kr = np.arange(max_lag[0] + 1)
    nb = max(int(round(n_row)), 1)
    kb = np.arange(-(nb - 1), nb)
    # (lags along range, lags across, offsets along, offsets across), metres -> correlation lengths.
    u = (kr[:, None, None, None] * window[0] + dr[None, None, :, None]) * cell_m[0] / lr
    v = (kb[None, :, None, None] * window[1] + db[None, None, None, :]) * cell_m[1] / lb
    rho = np.einsum("abij,i,j->ab", correlation(np.hypot(u, v), covariance), wr, wb)  # (range lag, across lag)
    weights = (nb - np.abs(kb)) / float(nb * nb)
    row_mean = rho @ weights  # B at each range lag
    centre = nb - 1
    along = rho[:, centre] - row_mean
    across = rho[0, centre: centre + max_lag[1] + 1] - row_mean[0]
    if len(across) < max_lag[1] + 1:
        across = np.pad(across, (0, max_lag[1] + 1 - len(across)), constant_values=np.nan)
    return along, across, float(row_mean[0])


def estimate_texture(
    image: np.ndarray,
    range_m: np.ndarray,
    azimuth_deg: np.ndarray,
    *,
    mask: np.ndarray | None = None,
    expected: np.ndarray | None = None,
    window: tuple[int, int] = (2, 2),
    looks: float = 1.0,
    covariance: str = "gaussian",
    height_m: float | None = None,
    max_lag: tuple[int, int] = (24, 24),
    bands: int = 6,
) -> TextureEstimate:
    """Estimate a floor texture's ``std_db`` and correlation lengths from speckled images.

    In the lit floor band, the local mean of a speckled image varies from block to block more
    than speckle alone explains; the excess is the texture. Per frame: the image's means over
    non-overlapping blocks of ``window`` cells, their logarithm, minus the logarithm of the
    ``expected`` image's block means (if given: the untextured model image, which removes the
    band's shape, the beam pattern and the range law), minus each block row's mean over its
    valid blocks (the range trend and the gain). The residuals' covariance at lags along range
    and across beams is fitted (least squares, the variance profiled out, the two lengths
    searched on a grid and refined) by the model: the texture's ``s**2`` times the correlation
    of two block means (``rho`` averaged over their cells' pairs, cells in metres on the
    floor), plus the speckle's variance of a block's log mean, ``trigamma(cells * looks)``
    (exact for independent gamma-distributed cells), both passed through the same row-mean
    removal. The fan widens with range: the model is formed for ``bands`` range bands, each
    with its own cell size across the beams, and pooled as the empirical covariances are.

    Parameters
    ----------
    image : (n_bins, n_beams) or (n_frames, n_bins, n_beams) float array
        Intensity (linear, not dB) with speckle; the frames' statistics are pooled (frames of
        a moving sonar add floor; frames of a still one only average the speckle).
    range_m : (n_bins,) float array
        Centre of each range bin, metres (slant range).
    azimuth_deg : (n_beams,) float array
        Beam centres, degrees.
    mask : bool array shaped like one frame, optional
        The cells of the lit floor band to use (default: every cell above 0). A block is used
        when all its cells are.
    expected : float array shaped like one frame (or like ``image``), optional
        The expected, untextured image (the model's, without speckle).
    window : (int, int)
        Block size in range bins and beams. Larger blocks shrink the speckle's share (and its
        correlation between neighbouring cells, which the model assumes absent between blocks),
        but average the texture over more floor.
    looks : float
        Independent speckle looks per cell: 1 for fully developed speckle, independent from
        cell to cell (the renderer's ``speckle``); real sonars' speckle correlated over ``c``
        cells has about ``1 / c``.
    covariance : {'gaussian', 'exponential'}
        The correlation model fitted.
    height_m : float, optional
        The sonar's height above the floor: cells are mapped to metres on the floor with the
        ground range ``g = sqrt(r**2 - h**2)`` (along range ``dr * r / g``, across
        ``g * beam spacing``); without it, with the slant range (grazing incidence).
    max_lag : (int, int)
        Most block lags fitted along range and across beams.
    bands : int
        Range bands of the model (see above).

    Returns
    -------
    TextureEstimate

    Raises
    ------
    ValueError
        Shapes that do not match, or fewer than 9 blocks inside the mask.

    Notes
    -----
    Assumptions: the floor is flat; the texture's axes run along range and across the beams
    (a field turned against them shows its lengths projected onto those directions, and the fan
    turns the across direction by its width); cells are small against the correlation lengths
    (a cell's footprint averages the texture, which then looks smoother and weaker); the
    expected image is right up to a gain per range row (what it gets wrong across the beams
    is taken for texture); speckle is independent between blocks. Removing each row's mean also
    removes the texture's variation that is constant along a row, which the model accounts for,
    but with few blocks per row the correlation across is poorly determined. Uncertainty:
    about ``sqrt(2 / N)`` relative in the variance for ``N`` independent patches (the floor's
    area over the correlation area), more in the lengths.
    """
    img = np.asarray(image, dtype=np.float64)
    frames = img[None] if img.ndim == 2 else img
    if frames.ndim != 3:
        raise ValueError(f"image must be (n_bins, n_beams) or (n_frames, n_bins, n_beams), got shape {img.shape}")
    n_bins, n_beams = frames.shape[1:]
    rng_m = np.asarray(range_m, dtype=np.float64)
    az = np.asarray(azimuth_deg, dtype=np.float64)
    if rng_m.shape != (n_bins,) or az.shape != (n_beams,):
        raise ValueError("range_m and azimuth_deg must give one value per range bin and per beam")
    if covariance not in TEXTURE_COVARIANCES:
        raise ValueError(f"unknown covariance {covariance!r}; allowed: {', '.join(TEXTURE_COVARIANCES)}")
    wr, wb = (int(w) for w in window)
    if wr < 1 or wb < 1 or n_bins // wr < 3 or n_beams // wb < 3:
        raise ValueError(f"window {window} must be positive and leave at least 3 x 3 blocks")
    exp_frames = None
    if expected is not None:
        exp_frames = np.broadcast_to(np.asarray(expected, dtype=np.float64), frames.shape)
    cell_mask = np.ones((n_bins, n_beams), bool) if mask is None else np.asarray(mask, bool)
    kmax = (int(max_lag[0]), int(max_lag[1]))
    from scipy.optimize import minimize
    from scipy.special import polygamma

    # The speckle's variance of the log of a mean of N independent gamma(looks) cells.
    nugget = float(polygamma(1, wr * wb * looks))
    n_rows = n_bins // wr
    block_range = _block_means(np.broadcast_to(rng_m[:, None], (n_bins, n_beams)), (wr, wb))[:, 0]
    band_of_row = np.minimum((np.arange(n_rows) * bands) // n_rows, bands - 1)
    sums_r, counts_r = np.zeros((bands, kmax[0] + 1)), np.zeros((bands, kmax[0] + 1))
    sums_b, counts_b = np.zeros((bands, kmax[1] + 1)), np.zeros((bands, kmax[1] + 1))
    blocks_in_band = np.zeros(bands)
    rows_in_band = np.zeros(bands)
    for f in range(len(frames)):
        m = _block_means(frames[f], (wr, wb))
        ok = _block_means((cell_mask & (frames[f] > 0)).astype(np.float64), (wr, wb)) == 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            log_m = np.log(m)
            if exp_frames is not None:
                e = _block_means(exp_frames[f], (wr, wb))
                ok &= e > 0
                log_m = log_m - np.log(e)
        ok &= (ok.sum(axis=1) >= 2)[:, None]
        log_m = np.where(ok, log_m, 0.0)
        row_mean = log_m.sum(axis=1) / np.maximum(ok.sum(axis=1), 1)
        res = np.where(ok, log_m - row_mean[:, None], 0.0)
        for b in range(bands):  # a few bands, each a few whole-array products
            rows = band_of_row == b
            # Pairs along range start in the band and may end beyond it.
            first, last = np.flatnonzero(rows)[[0, -1]]
            part = slice(first, min(last + 1 + kmax[0], n_rows))
            keep = ok[part] & (np.arange(part.start, part.stop) <= last)[:, None]
            s, c = _lag_covariance(res[part], ok[part], kmax[0], 0, start_valid=keep)
            sums_r[b], counts_r[b] = sums_r[b] + s, counts_r[b] + c
            s, c = _lag_covariance(res[rows], ok[rows], kmax[1], 1)
            sums_b[b], counts_b[b] = sums_b[b] + s, counts_b[b] + c
            blocks_in_band[b] += ok[rows].sum()
            rows_in_band[b] += np.count_nonzero(ok[rows].any(axis=1))
    n_blocks = int(blocks_in_band.sum())
    if n_blocks < 9:
        raise ValueError(f"only {n_blocks} blocks of {window} cells lie in the mask; give a larger lit region")
    dr = float(np.median(np.diff(rng_m)))
    dtheta = math.radians(float(np.median(np.abs(np.diff(az))))) if n_beams > 1 else 1.0
    # Each band's cell size on the floor (at its middle range) and blocks per row.
    geometry = []
    for b in range(bands):
        if not rows_in_band[b]:
            geometry.append(None)
            continue
        r_mid = float(np.median(block_range[band_of_row == b]))
        ground = math.sqrt(max(r_mid**2 - height_m**2, 1e-12)) if height_m is not None else r_mid
        geometry.append(((dr * r_mid / ground, ground * dtheta), blocks_in_band[b] / rows_in_band[b]))
    emp_r = counts_r.sum(0)
    emp_r = np.where(emp_r > 0, sums_r.sum(0) / np.maximum(emp_r, 1), np.nan)
    emp_b = counts_b.sum(0)
    emp_b = np.where(emp_b > 0, sums_b.sum(0) / np.maximum(emp_b, 1), np.nan)
    emp = np.concatenate([emp_r, emp_b[1:]])
    use = np.isfinite(emp)

    def model(lengths: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
        """Pooled texture (unit variance) and speckle parts of the model, at the fitted lags."""
        tex = np.zeros(len(emp))
        nug = np.zeros(len(emp))
        weight = np.zeros(len(emp))
        for b, g in enumerate(geometry):
            if g is None:
                continue
            cell_m, n_row = g
            along, across, _ = _model(lengths[0], lengths[1], covariance, (wr, wb), cell_m, kmax, n_row)
            w = np.concatenate([counts_r[b], counts_b[b, 1:]])
            nb = np.zeros(len(emp))
            # The speckle through the row-mean removal: independent between blocks.
            nb[0] = nugget * (1.0 - 1.0 / n_row)
            nb[kmax[0] + 1:] = -nugget / n_row
            tex += w * np.nan_to_num(np.concatenate([along, across[1:]]))
            nug += w * nb
            weight += w
        weight = np.maximum(weight, 1e-300)
        return tex / weight, nug / weight

    def fit(lengths: tuple[float, float]) -> tuple[float, float]:
        x, nug = model(lengths)
        e = emp[use] - nug[use]
        var = max(float(x[use] @ e) / max(float(x[use] @ x[use]), 1e-300), 0.0)
        return float(np.sum((e - var * x[use]) ** 2)), var

    # Lengths from half a cell to twice the image's extent, on a log grid, then refined.
    cell_mid = next(g for g in geometry if g is not None)[0]
    grid_r = np.geomspace(0.5 * cell_mid[0], 2.0 * cell_mid[0] * n_bins, 12)
    grid_b = np.geomspace(0.5 * cell_mid[1], 2.0 * cell_mid[1] * n_beams, 12)
    best = min((fit((a, b))[0], a, b) for a in grid_r for b in grid_b)
    res = minimize(lambda t: fit((math.exp(t[0]), math.exp(t[1])))[0], [math.log(best[1]), math.log(best[2])],
                   method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-14, "maxiter": 300})
    lr, lb = (math.exp(t) for t in res.x) if res.fun <= best[0] else (best[1], best[2])
    _, var = fit((lr, lb))
    x, nug = model((lr, lb))
    fitted = var * x + nug
    return TextureEstimate(
        std_db=math.sqrt(var) / LN10_OVER_10, correlation_range_m=float(lr), correlation_across_m=float(lb),
        n_blocks=n_blocks, lags_range_m=np.arange(kmax[0] + 1) * wr * cell_mid[0],
        lags_across_m=np.arange(kmax[1] + 1) * wb * cell_mid[1], covariance_range=emp_r, covariance_across=emp_b,
        model_range=fitted[: kmax[0] + 1], model_across=np.concatenate([fitted[:1], fitted[kmax[0] + 1:]]),
    )


__all__ = [
    "CELLS_PER_LENGTH", "ReflectivityField", "TEXTURE_STREAM", "TILE_CELLS", "TextureEstimate", "correlation",
    "estimate_texture", "field_correlation", "plane_axes", "scale_by_texture", "texture_fields", "unit_tile",
]
