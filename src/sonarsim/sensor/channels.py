"""The receive channels' own structure: gain across the fan, stripes, the bang's pattern, common noise.

A forward-looking sonar forms each beam in its own channel. What a channel adds is fixed per
beam or per range row, not per pixel, so each effect here is a vector that the sensor stage
(:mod:`sonarsim.sensor.model`) applies per beam or per row:

* the across-fan gain ``G_j`` (power, per beam): the element's directivity, roughly
  ``cos(theta)^n``, lowers the gain of beams steered off the axis, and fixed per-beam gain errors
  show as stripes. It multiplies everything the channel carries (echo, bang, noise), as a gain
  after the beamformer would: ``P = t(r) G_j |a|^2``;
* the bang's profile in range (power, per row: the transmit bang and the near-range ringing)
  and its pattern across beams (per beam), the same from ping to ping:
  ``bang(r, j) = bang_row(r) B_j``;
* noise common to the beams of a row (interference reaching every channel alike), decaying with
  range: one complex Gaussian per row and frame, added to every beam's amplitude.

These functions return those vectors from a spec, so that a calibration can form or fit them
alone. Seeded draws take a generator; :class:`~sonarsim.sensor.model.SensorModel` passes one of
the scene's seed (:func:`sonarsim.core.streams.beam_rng`, ``default_rng([seed, BEAM_STREAM, k])``),
so a scene's stripes are the same in every frame and every process.
"""

from __future__ import annotations

import numpy as np

from ..config.sensor import BangSpec, BeamGainSpec, NoiseSpec
from .speckle import complex_gaussian


def steering_gain_db(azimuth_deg: np.ndarray, exponent: float) -> np.ndarray:
    """The power gain of beams steered off the axis, ``10 n log10 cos(theta)``.

    Parameters
    ----------
    azimuth_deg : (n_beams,) float array, degrees
        The beams' steering angles (their centres; inside (-90, 90)).
    exponent : float
        n, the exponent of the element's directivity ``cos(theta)^n`` (power).

    Returns
    -------
    (n_beams,) float64 ndarray, dB (0 on the axis, negative off it).
    """
    c = np.cos(np.radians(np.asarray(azimuth_deg, dtype=float)))
    return 10.0 * float(exponent) * np.log10(c)


def seeded_beam_db(std_db: float, n_beams: int, rng: np.random.Generator | None) -> np.ndarray:
    """Per-beam offsets drawn normal in dB, less their mean over beams.

    Removing the mean keeps the fan's mean level where the other gains set it, so that stripes
    do not trade off against ``gain_db`` in a calibration.

    Parameters
    ----------
    std_db : float
        Standard deviation, dB; 0 draws nothing.
    n_beams : int
    rng : numpy Generator or None
        Required when ``std_db > 0``.

    Returns
    -------
    (n_beams,) float64 ndarray, dB.
    """
    if std_db == 0.0:
        return np.zeros(n_beams)
    if rng is None:
        raise ValueError("seeded per-beam offsets (std_db > 0) need a generator")
    e = rng.standard_normal(n_beams) * float(std_db)
    return e - e.mean()


def beam_gain_db(spec: BeamGainSpec | None, azimuth_deg: np.ndarray, rng: np.random.Generator | None = None
                 ) -> np.ndarray:
    """Each receive channel's power gain across the fan, ``10 log10 G_j``.

    ``G_j = cos(theta_j)^n 10^((s_j + e_j) / 10)``: the steering loss of ``steering_exponent``
    n, the given ``gain_db`` s_j and seeded stripes e_j of ``std_db`` (:func:`seeded_beam_db`).

    Parameters
    ----------
    spec : BeamGainSpec or None
        ``None``: every gain 0 dB.
    azimuth_deg : (n_beams,) float array, degrees
        The beams' centres (``SonarConfig.azimuth_deg``), left-most first.
    rng : numpy Generator, optional
        Draws the stripes (required with ``std_db > 0``).

    Returns
    -------
    (n_beams,) float64 ndarray, dB.

    Raises
    ------
    ValueError
        ``gain_db`` of another length than ``azimuth_deg`` (validated against the sonar before,
        by :func:`sonarsim.config.sensor.check_beam_count`).
    """
    az = np.asarray(azimuth_deg, dtype=float)
    if spec is None:
        return np.zeros(len(az))
    db = steering_gain_db(az, spec.steering_exponent) if spec.steering_exponent else np.zeros(len(az))
    if spec.gain_db is not None:
        if len(spec.gain_db) != len(az):
            raise ValueError(f"gain_db has {len(spec.gain_db)} values for {len(az)} beams")
        db = db + np.asarray(spec.gain_db, dtype=float)
    return db + seeded_beam_db(spec.std_db, len(az), rng)


def bang_row(spec: BangSpec | None, range_m: np.ndarray) -> np.ndarray:
    """The bang's power in each range bin, before its pattern across beams.

    ``L exp(-max(r - hold_m, 0) / length_m) + R exp(-r / ringing_length_m) cos^2(pi r / ringing_period_m)``
    (``L``, ``R`` the levels ``level_db``, ``ringing_db`` as powers; the cosine is 1 without a
    period, the second term 0 without ``ringing_db``).

    Parameters
    ----------
    spec : BangSpec or None
        ``None``: no bang (zeros).
    range_m : (n_range_bins,) float array, metres
        The bins' ranges.

    Returns
    -------
    (n_range_bins,) float64 ndarray, uPa^2 at the receiver (before TVG).
    """
    r = np.asarray(range_m, dtype=float)
    if spec is None:
        return np.zeros(len(r))
    p = 10.0 ** (spec.level_db / 10.0) * np.exp(-np.maximum(r - spec.hold_m, 0.0) / spec.length_m)
    if spec.ringing_db is not None:
        ring = 10.0 ** (spec.ringing_db / 10.0) * np.exp(-r / spec.ringing_length_m)
        if spec.ringing_period_m is not None:
            ring = ring * np.cos(np.pi * r / spec.ringing_period_m) ** 2
        p = p + ring
    return p


def bang_beam_db(spec: BangSpec | None, n_beams: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """The bang's pattern across beams, ``10 log10 B_j``: ``beam_db`` plus seeded offsets of
    ``beam_std_db`` (:func:`seeded_beam_db`).

    Parameters
    ----------
    spec : BangSpec or None
        ``None``: 0 dB everywhere.
    n_beams : int
    rng : numpy Generator, optional
        Draws the seeded pattern (required with ``beam_std_db > 0``).

    Returns
    -------
    (n_beams,) float64 ndarray, dB.
    """
    if spec is None:
        return np.zeros(n_beams)
    db = np.zeros(n_beams) if spec.beam_db is None else np.asarray(spec.beam_db, dtype=float)
    if len(db) != n_beams:
        raise ValueError(f"beam_db has {len(db)} values for {n_beams} beams")
    return db + seeded_beam_db(spec.beam_std_db, n_beams, rng)


def common_noise_power(spec: NoiseSpec | None, range_m: np.ndarray) -> np.ndarray:
    """The power of the noise common to all beams of a range bin, ``C exp(-r / common_length_m)``.

    Parameters
    ----------
    spec : NoiseSpec or None
        ``None`` or no ``common_db``: zeros.
    range_m : (n_range_bins,) float array, metres

    Returns
    -------
    (n_range_bins,) float64 ndarray, uPa^2 at the receiver (before TVG).
    """
    r = np.asarray(range_m, dtype=float)
    if spec is None or spec.common_db is None:
        return np.zeros(len(r))
    p = np.full(len(r), 10.0 ** (spec.common_db / 10.0))
    if spec.common_length_m is not None:
        p = p * np.exp(-r / spec.common_length_m)
    return p


def common_noise_amplitude(power: np.ndarray, range_amplitude: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One frame's common noise: a complex amplitude per range bin, the same in every beam.

    White complex Gaussian samples through the receiver's band (the pulse's range amplitude
    kernel, whose squares sum to 1: the power is kept), scaled to ``power``. The samples run
    past both ends of the window, so the first and last bins are as noisy as the others.

    Parameters
    ----------
    power : (n_range_bins,) float array, uPa^2
        :func:`common_noise_power`.
    range_amplitude : (odd,) float array
        The range amplitude kernel (``sonarsim.sensor.pulse.range_kernels``), centred.
    rng : numpy Generator
        The frame's noise generator.

    Returns
    -------
    (n_range_bins,) complex128 ndarray, sqrt(uPa^2).
    """
    n = len(power)
    k = np.asarray(range_amplitude, dtype=float)
    z = complex_gaussian(rng, (n + len(k) - 1,)).astype(np.complex128)
    if len(k) > 1:
        z = np.convolve(z, k[::-1], mode="valid")  # out[i] = sum_m k[m] z[i + m], as filter_field
    else:
        z = z * k[0]
    return np.sqrt(np.asarray(power, dtype=float)) * z
