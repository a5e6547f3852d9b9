"""Radiometry: the backscattered energy a ray carries (paper Eq. 3-6).

Objects are Lambertian: a ray hitting a surface of albedo rho at incidence alpha returns
``beta * l(r) * rho * cos(alpha) * dphi``, where ``beta * dphi`` is the ray's weight (beam
pattern times the elevation interval it stands for) and ``l(r)`` the range compensation.
"""

from __future__ import annotations

import numpy as np


def lambertian_intensity(
    weight: np.ndarray,
    cos_incidence: np.ndarray,
    albedo: np.ndarray,
    distance_m: np.ndarray,
    tvg: bool,
) -> np.ndarray:
    """Per-ray backscatter ``beta * l(r) * rho * cos(alpha) * dphi`` (paper Eq. 3-6).

    Parameters
    ----------
    weight : (...) float array
        Ray weight ``beta(theta, phi) * dphi`` (radians), see :class:`sonarsim.core.rays.RayFan`.
    cos_incidence : (...) float array
        cos of the angle between the ray and the surface normal, in [0, 1].
    albedo : (...) float array
        Diffuse albedo rho of the surface hit (0 where nothing is hit).
    distance_m : (...) float array
        Range of the hit, metres (``inf`` where nothing is hit).
    tvg : bool
        ``True``: ``l(r) = 1``; ``False``: ``l(r) = 1 / r**2``.

    Returns
    -------
    (...) float64 ndarray: the intensity map I_f (0 where nothing is hit).
    """
    hit = np.isfinite(distance_m)
    out = np.where(hit, weight * albedo * cos_incidence, 0.0)
    if not tvg:
        r = np.where(hit, distance_m, 1.0)
        out = out / np.maximum(r, 1e-6) ** 2
    return out
