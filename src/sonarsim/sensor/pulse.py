"""The range point-spread of the transmitted pulse, sampled on the range bins.

A CW pulse of length tau ensonifies ``c tau / 2`` of range at a time: the echo envelope of a
point is a gate that long (no matched filter). A linear FM chirp of bandwidth B, after
matched filtering, compresses to the inverse Fourier transform of its (windowed) spectrum: a
main lobe about ``c / (2 B)`` wide with range sidelobes set by the window.
"""

from __future__ import annotations

import numpy as np

from ..config.sensor import MAX_KERNEL_HALF_WIDTH, PulseSpec
from ..errors import ConfigError
from .patterns import aperture_positions, aperture_weights

# Sub-samples per range bin when averaging the envelope over a bin.
OVERSAMPLE = 32
# Range sidelobes below this fraction of the peak amplitude are dropped.
TAIL_AMPLITUDE = 1e-3


def envelope(delay_m: np.ndarray, spec: PulseSpec, sound_speed_m_s: float) -> np.ndarray:
    """Amplitude of a point's echo at range offsets ``delay_m`` (metres of range), peak 1."""
    d = np.asarray(delay_m, dtype=float)
    if spec.kind == "cw":
        half = sound_speed_m_s * spec.length_us * 1e-6 / 4.0  # c tau / 2 of range, centred
        return (np.abs(d) <= half).astype(float)
    w = aperture_weights(spec.window, spec.sidelobe_db)
    f = aperture_positions() * spec.bandwidth_khz * 1e3  # Hz about the carrier: the band, weighted
    t = 2.0 * d / sound_speed_m_s  # two-way delay
    out = np.cos(2.0 * np.pi * t.reshape(-1, 1) * f[None, :]) @ w / w.sum()
    return out.reshape(d.shape)


def range_kernels(spec: PulseSpec | None, range_resolution_m: float,
                  sound_speed_m_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The pulse's kernels over range bins ``-R..R``.

    Returns
    -------
    intensity : (2R + 1,) float64 ndarray, sums to 1
        How the mean echo power of a bin spreads over its neighbours (the envelope's square
        averaged over a bin, centred on the echo's bin).
    amplitude : (2R + 1,) float64 ndarray, squares sum to 1
        The envelope averaged over each bin: the filter that gives white scatterer amplitudes
        the correlation along range of the detected echo.

    Both are ``[1]`` for a pulse shorter than two of the ``OVERSAMPLE`` sub-samples of a bin: it
    stays within its bin.

    Raises
    ------
    ConfigError
        ``sensor.pulse.length_us`` (CW) or ``sensor.pulse.bandwidth_khz`` (chirp): the pulse
        spans more than ``2 MAX_KERNEL_HALF_WIDTH + 1`` range bins.
    """
    if spec is None:
        return np.ones(1), np.ones(1)
    extent = sound_speed_m_s * spec.length_us * 1e-6 / 2.0 if spec.kind == "cw" else \
        8.0 * sound_speed_m_s / (2.0 * spec.bandwidth_khz * 1e3)
    half = int(np.ceil(extent / range_resolution_m)) + 1
    if half > MAX_KERNEL_HALF_WIDTH:
        key = "sensor.pulse.length_us" if spec.kind == "cw" else "sensor.pulse.bandwidth_khz"
        raise ConfigError(key, f"the pulse spans {2 * half + 1} range bins of "
                          f"{range_resolution_m * 1e3:.3g} mm; at most {2 * MAX_KERNEL_HALF_WIDTH + 1} are allowed")
    # A pulse (a CW gate, or a chirp's compressed main lobe, about c / (2 B)) shorter than two of
    # the sub-samples below falls within one bin: sampled, a gate narrower than them was missed by
    # every sub-sample (0 / 0: NaN kernels) and a chirp's carrier aliased. It spreads nothing.
    main_lobe = extent if spec.kind == "cw" else extent / 8.0
    if main_lobe < 2.0 * range_resolution_m / OVERSAMPLE:
        return np.ones(1), np.ones(1)
    n = np.arange(-half, half + 1, dtype=float)
    sub = (np.arange(OVERSAMPLE) + 0.5) / OVERSAMPLE - 0.5
    env = envelope((n[:, None] + sub[None, :]) * range_resolution_m, spec, sound_speed_m_s)
    intensity = (env ** 2).mean(axis=1)
    amplitude = env.mean(axis=1)
    keep = np.flatnonzero((np.abs(amplitude) > TAIL_AMPLITUDE) | (intensity > TAIL_AMPLITUDE ** 2))
    r = int(max(np.abs(n[keep]).max(), 0)) if len(keep) else 0
    sl = slice(half - r, half + r + 1)
    intensity, amplitude = intensity[sl], amplitude[sl]
    return intensity / intensity.sum(), amplitude / np.sqrt(np.sum(amplitude ** 2))
