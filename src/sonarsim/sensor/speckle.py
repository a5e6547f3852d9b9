"""Coherent speckle and receiver noise as complex fields on the polar grid.

Each resolution cell's echo is a coherent sum of many scatterers: a complex Gaussian
amplitude (Goodman's fully developed speckle: Rayleigh magnitude, exponential intensity).
Passing white complex amplitudes through the range point-spread (the pulse) and the azimuth
point-spread (the receive beam) gives speckle its grain: its correlation lengths follow the
resolution cell.

A device that averages L independent looks in intensity (pings, sub-apertures, frequency bands)
records ``S = sum_l w_l |F_l|^2`` over ``ceil(L)`` independently filtered fields, the weights
summing to 1 with ``sum_l w_l^2 = 1 / L`` (:func:`look_weights`): S has unit mean and contrast
``1 / sqrt(L)`` exactly (the gamma law of shape L for an integer L), and the grain of one look
(each look's field has the same point-spread). The stored field is ``sqrt(S)`` with the first
look's phase, so that the compiled stage's ``|sqrt(mu) F + sqrt(N) W|^2`` reads ``mu S`` where the
echo dominates; the noise fields are formed alike (the device averages its noise over the same
looks). Where echo and noise are comparable the cross term keeps one look's spread
(:meth:`sonarsim.sensor.model.SensorModel.reference` averages L full looks).

For few scatterers per cell (the K model) the cell's intensity is the speckle's times a gamma
texture of shape nu (the compound representation of the K law): the texture is the number of
scatterers in the cell, so it multiplies the speckle after the point-spread, once per cell and
common to the looks. Drawn per scatterer before the point-spread, as before, it was averaged over
the cells the point-spread spans and the law drifted towards Rayleigh.

Filtering a fresh field for every frame would cost more than the whole sensor stage may take,
so a :class:`SpecklePool` filters a few independent fields once per sonar (circularly, so each
is stationary; stored with 8 bits per part) and a frame reads one of them from a random cyclic
offset: for a locally uniform
scene, ``PSF * (sqrt(mean) w) = sqrt(mean) (PSF * w)`` exactly, which is what the fast path
computes (:func:`sonarsim.sensor.model.SensorModel.reference` filters afresh, for comparison).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config.sensor import SpeckleSpec
from ..core.memory import require
from ..core.streams import POOL_STREAM, pool_rng  # noqa: F401 (POOL_STREAM: importable here as before)

POOL_FIELDS = 4
FIELD_BITS = 8  # bits per stored part (real or imaginary) of a pool field
FIELD_MAX = 2 ** (FIELD_BITS - 1) - 1


def complex_gaussian(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Unit-power circular complex Gaussian samples: ``E|z|^2 = 1``."""
    z = rng.standard_normal(shape + (2,), dtype=np.float32)
    return (z[..., 0] + 1j * z[..., 1]).astype(np.complex64) * np.float32(np.sqrt(0.5))


def scatterer_amplitudes(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """White complex amplitudes of unit mean power (one look's scatterers, before the point-spread)."""
    return complex_gaussian(rng, shape)


def look_weights(looks: float) -> np.ndarray:
    """Weights of ``ceil(looks)`` independent unit-mean intensities whose weighted sum has unit
    mean and contrast ``1 / sqrt(looks)``.

    ``n - 1`` equal weights ``a`` and a last weight ``b = 1 - (n - 1) a`` with
    ``(n - 1) a^2 + b^2 = 1 / L``, the root that gives ``a = b = 1/n`` at ``L = n`` and
    ``a = 1/(n-1), b = 0`` as L falls to ``n - 1``.

    Parameters
    ----------
    looks : float
        L >= 1.

    Returns
    -------
    (ceil(L),) float64 ndarray, summing to 1.
    """
    L = float(looks)
    if not L >= 1.0:
        raise ValueError(f"looks must be at least 1, got {looks!r}")
    n = int(np.ceil(L - 1e-12))
    if n == 1:
        return np.ones(1)
    root = np.sqrt(max(1.0 - n * (L - 1.0) / (L * (n - 1)), 0.0))
    a = (1.0 + root) / n
    return np.append(np.full(n - 1, a), 1.0 - (n - 1) * a)


def multi_look(make_look, weights: np.ndarray) -> np.ndarray:
    """``sqrt(sum_l w_l |F_l|^2)`` with the first look's phase: a complex field whose intensity
    is the looks' weighted average (one look: itself).

    Parameters
    ----------
    make_look : callable () -> (n_r, n_b) complex64 ndarray
        Draws one look's filtered field; called ``len(weights)`` times, in order (one look is
        held at a time besides the first: the memory of :func:`pool_bytes`).
    weights : (n_looks,) array
        :func:`look_weights`.
    """
    first = make_look()
    if len(weights) == 1:
        return first
    s = np.float32(weights[0]) * (first.real * first.real + first.imag * first.imag)
    for w in weights[1:]:
        f = make_look()
        s += np.float32(w) * (f.real * f.real + f.imag * f.imag)
    mag = np.abs(first)
    phase = np.where(mag > 0, first / np.where(mag > 0, mag, 1.0), np.complex64(1.0))
    return (np.sqrt(s) * phase).astype(np.complex64)


def texture(rng: np.random.Generator, shape: tuple[int, int], spec: SpeckleSpec | None) -> np.ndarray | None:
    """The K model's per-cell intensity texture (gamma, shape ``k_shape``, unit mean); ``None`` otherwise."""
    if spec is None or spec.model != "k":
        return None
    return rng.gamma(spec.k_shape, 1.0 / spec.k_shape, size=shape).astype(np.float32)


def speckle_field(rng: np.random.Generator, shape: tuple[int, int], spec: SpeckleSpec | None,
                  range_amplitude: np.ndarray, beam_amplitude: np.ndarray, circular: bool = True) -> np.ndarray:
    """One unit-power speckle field as the device records it: its looks, each through the
    point-spread, averaged in intensity, then the K texture per cell (see the module's notes).

    Parameters
    ----------
    rng : numpy Generator
    shape : (n_range_bins, n_beams)
    spec : SpeckleSpec or None
        ``None``: one Rayleigh look.
    range_amplitude, beam_amplitude : (odd,) arrays
        The point-spread's amplitude kernels (squares summing to 1).
    circular : bool
        See :func:`filter_field`.

    Returns
    -------
    (n_range_bins, n_beams) complex64 ndarray, ``E|F|^2 = 1``.
    """
    weights = look_weights(1.0 if spec is None else spec.looks)
    f = multi_look(lambda: filter_field(scatterer_amplitudes(rng, shape), range_amplitude, beam_amplitude, circular),
                   weights)
    t = texture(rng, shape, spec)
    return f if t is None else (f * np.sqrt(t)).astype(np.complex64)


def noise_field(rng: np.random.Generator, shape: tuple[int, int], looks: float,
                range_amplitude: np.ndarray, beam_amplitude: np.ndarray, circular: bool = True) -> np.ndarray:
    """One unit-power receiver-noise field: element noise through the beamformer and the receiver
    band (the point-spread), averaged over the device's looks like the echo."""
    return multi_look(lambda: filter_field(complex_gaussian(rng, shape), range_amplitude, beam_amplitude, circular),
                      look_weights(looks))


def filter_field(w: np.ndarray, range_amplitude: np.ndarray, beam_amplitude: np.ndarray,
                 circular: bool = True) -> np.ndarray:
    """Convolve a complex field with the range and across-beam amplitude kernels.

    Parameters
    ----------
    w : (n_range_bins, n_beams) complex array
    range_amplitude, beam_amplitude : (odd,) float arrays, centred
    circular : bool
        Wrap around the edges (a stationary field) rather than pad with zeros.
    """
    out = w.astype(np.complex64)
    for axis, kernel in ((0, range_amplitude), (1, beam_amplitude)):
        if len(kernel) == 1:
            out = out * np.float32(kernel[0])
            continue
        half = len(kernel) // 2
        acc = np.zeros_like(out)
        for m, k in enumerate(kernel):
            shift = m - half  # out[i] += k[m] * w[i + shift]
            if k == 0:
                continue
            if circular:
                acc += np.float32(k) * np.roll(out, -shift, axis=axis)
            else:
                src = [slice(None)] * 2
                dst = [slice(None)] * 2
                n = out.shape[axis]
                if shift >= 0:
                    src[axis], dst[axis] = slice(shift, n), slice(0, n - shift)
                else:
                    src[axis], dst[axis] = slice(0, n + shift), slice(-shift, n)
                acc[tuple(dst)] += np.float32(k) * out[tuple(src)]
        out = acc
    return out


def pool_bytes(shape: tuple[int, int], speckle: bool, noise: bool, n_fields: int = POOL_FIELDS,
               looks: float = 1.0) -> int:
    """Bytes a :class:`SpecklePool` takes: the stored fields (one byte per part, beams twice),
    and while one field is made its complex samples, their filtered copy and the filter's
    accumulator; with several looks also the first look and the looks' summed intensity."""
    n_r, n_b = int(shape[0]), int(shape[1])
    n_kinds = int(speckle) + int(noise)
    if n_kinds == 0:
        return 0
    making = 3 if float(looks) <= 1.0 else 5
    return n_kinds * n_fields * n_r * 4 * n_b + making * n_r * n_b * 8


@dataclass(frozen=True)
class FieldDraw:
    """Which pool field a frame reads, and from which cyclic offset (rows, beams)."""

    field: int
    row: int
    beam: int


class SpecklePool:
    """A few independent filtered fields (speckle) and white fields (noise) of one grid.

    The fields are stored quantised to 8 bits per part (see :data:`FIELD_BITS`): a frame reads
    two of them, and at float precision reading them from memory was the sensor stage's largest
    cost. Each field is stored per range row as its real parts, then its imaginary parts, each
    row repeated twice across beams, so that a frame's window starting at any beam is one
    contiguous run per part; the rows wrap around (the fields are circular).

    Parameters
    ----------
    shape : (n_range_bins, n_beams)
    range_amplitude, beam_amplitude : (odd,) arrays
        The point-spread kernels (squares summing to 1: unit-power output).
    spec : SpeckleSpec or None
        ``None``: no speckle fields (the echo amplitude is deterministic).
    noise : bool
        Also hold white noise fields.
    seed : int
        The pool is a function of the seed: renders are reproducible.

    Attributes
    ----------
    speckle, noise : (n_fields, n_range_bins, 2, 2 n_beams) int8 arrays or None
        The quantised fields: ``field = scale * (re + 1j im)``.
    speckle_scale, noise_scale : float
        The value of one step.
    """

    def __init__(self, shape: tuple[int, int], range_amplitude: np.ndarray, beam_amplitude: np.ndarray,
                 spec: SpeckleSpec | None, noise: bool, seed: int, n_fields: int = POOL_FIELDS) -> None:
        n_r, n_b = shape
        require(pool_bytes(shape, spec is not None, noise, n_fields, 1.0 if spec is None else spec.looks),
                f"the speckle and noise fields of a {n_r} x {n_b} image", "sensor.speckle")
        rng = pool_rng(seed)  # [seed, POOL_STREAM]: see core.streams
        self.shape = shape
        self.n_fields = n_fields
        self.speckle, self.speckle_scale = None, 0.0
        self.noise, self.noise_scale = None, 0.0
        if spec is not None:
            fields = [speckle_field(rng, shape, spec, range_amplitude, beam_amplitude) for _ in range(n_fields)]
            self.speckle, self.speckle_scale = self._quantised(fields)
        if noise:
            # Element noise reaches each beam through the beamformer: it is correlated across
            # beams like the speckle (and band-limited like the pulse), and averaged over the
            # same looks.
            looks = 1.0 if spec is None else spec.looks
            self.noise, self.noise_scale = self._quantised(
                [noise_field(rng, shape, looks, range_amplitude, beam_amplitude) for _ in range(n_fields)])

    @staticmethod
    def _quantised(fields: list[np.ndarray]) -> tuple[np.ndarray, float]:
        """The fields as (n_fields, n_r, 2, 2 n_b) int8 and the value of one step.

        The step is the largest part's magnitude over 127: nothing is clipped, and for a unit-power
        Gaussian field (parts of standard deviation 0.71, largest about 3.7 in a 165,000-cell pool)
        the rounding adds noise about 40 dB below the field's power.
        """
        top = max(float(np.max(np.abs(f.real))) for f in fields)
        top = max([top] + [float(np.max(np.abs(f.imag))) for f in fields])
        scale = top / FIELD_MAX if top > 0 else 1.0
        n_r, n_b = fields[0].shape
        out = np.empty((len(fields), n_r, 2, 2 * n_b), np.int8)
        for k, f in enumerate(fields):
            for part, values in ((0, f.real), (1, f.imag)):
                q = np.rint(values / scale).astype(np.int8)
                out[k, :, part, :n_b] = q
                out[k, :, part, n_b:] = q
        return out, scale

    def draw(self, rng: np.random.Generator) -> FieldDraw:
        # One raw 64-bit draw split three ways (per frame: a Generator call costs ~10 us; the
        # modulo bias of 64 random bits over a few million cells is below 1e-12).
        n_r, n_b = self.shape
        x = int(rng.bit_generator.random_raw())
        return FieldDraw(x % self.n_fields, (x // self.n_fields) % n_r, (x // (self.n_fields * n_r)) % n_b)

    def field(self, kind: str, index: int) -> np.ndarray:
        """Field ``index`` of ``kind`` (``"speckle"`` or ``"noise"``), (n_r, n_b) complex64."""
        stored, scale = (self.speckle, self.speckle_scale) if kind == "speckle" else (self.noise, self.noise_scale)
        n_b = self.shape[1]
        f = stored[index, :, :, :n_b].astype(np.float32) * np.float32(scale)
        return (f[:, 0] + 1j * f[:, 1]).astype(np.complex64)

    def window(self, kind: str, d: FieldDraw) -> np.ndarray:
        """The (n_r, n_b) complex64 field a draw selects: rows and beams read cyclically from its offset."""
        f = self.field(kind, d.field)
        return np.roll(f, (-d.row, -d.beam), axis=(0, 1))
