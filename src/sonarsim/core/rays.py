"""Ray sampling of the sonar's beams: directions over azimuth x elevation, with their weights.

Ray ``(j, a, k)`` belongs to beam ``j``, azimuth sub-sample ``a`` across the beam's width and
elevation sample ``k``. Elevation samples are the centres of equal sub-intervals of the aperture,
ascending (k = 0 is the lowest), so neighbouring rays on one surface are neighbours in the last
axis -- which is what range splatting walks along.

This module reads a sonar's geometry and a scene's render settings by their attributes only
(:class:`SonarGeometry`, :class:`RaySettings`): core imports nothing of the package above it,
and :class:`~sonarsim.config.sonar.SonarConfig` and :class:`~sonarsim.config.scene.RenderSettings`
are what :mod:`sonarsim.config` passes in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .memory import require


class SonarGeometry(Protocol):
    """What ray sampling reads of a sonar (:class:`~sonarsim.config.sonar.SonarConfig` has it)."""

    @property
    def n_beams(self) -> int: ...
    @property
    def elevation_fov_deg(self) -> float: ...
    @property
    def range_max_m(self) -> float: ...
    @property
    def range_resolution_m(self) -> float: ...
    @property
    def azimuth_deg(self) -> np.ndarray: ...

    def effective_beam_width_deg(self) -> np.ndarray: ...


class RaySettings(Protocol):
    """What ray sampling reads of the render settings
    (:class:`~sonarsim.config.scene.RenderSettings` has it)."""

    @property
    def elevation_samples(self) -> int | str: ...
    @property
    def azimuth_samples(self) -> int: ...
    @property
    def beam_pattern(self) -> str: ...


BYTES_PER_RAY = 600
AUTO_MIN_SAMPLES = 32
AUTO_MAX_SAMPLES = 1024


def auto_elevation_samples(sonar: SonarGeometry) -> int:
    """Elevation rays per beam for ``elevation_samples: auto``.

    Neighbouring rays are at most about two range bins apart (arc length) at the far end of the
    range window, so small objects are hit by several rays; continuous surfaces need no more,
    because range splatting fills the bins between neighbouring rays.
    """
    arc = math.radians(sonar.elevation_fov_deg) * sonar.range_max_m
    n = math.ceil(arc / (2.0 * sonar.range_resolution_m))
    return int(min(max(n, AUTO_MIN_SAMPLES), AUTO_MAX_SAMPLES))


def samples_per_beam(sonar: SonarGeometry, render: RaySettings) -> tuple[int, int]:
    """``(n_azimuth_samples, n_elevation_samples)`` of each beam's rays."""
    n_el = auto_elevation_samples(sonar) if render.elevation_samples == "auto" else int(render.elevation_samples)
    return int(render.azimuth_samples), n_el


def ray_bytes(sonar: SonarGeometry, render: RaySettings) -> int:
    """Bytes a frame's rays take: each its direction and weight here, and its legs' hits,
    points and normals per frame (``BYTES_PER_RAY`` in all).

    An exact integer: ``azimuth_samples`` of 400 digits times the beams is beyond a float
    (OverflowError), and :func:`~sonarsim.core.memory.require` compares integers of any size."""
    n_az, n_el = samples_per_beam(sonar, render)
    return int(sonar.n_beams) * n_az * n_el * BYTES_PER_RAY


def ray_size_key(sonar: SonarGeometry, render: RaySettings) -> str:
    """The key to name when there are too many rays: the largest factor of the count
    (``azimuth_samples: 1e9`` with 8 elevation samples is about ``render.azimuth_samples``)."""
    n_az, n_el = samples_per_beam(sonar, render)
    auto = render.elevation_samples == "auto"
    factors = [(sonar.n_beams, "sonar.n_beams"), (n_az, "render.azimuth_samples"),
               (n_el, "sonar.n_beams" if auto else "render.elevation_samples")]
    return max(factors, key=lambda f: f[0])[1]


def check_ray_budget(sonar: SonarGeometry, render: RaySettings) -> tuple[int, int]:
    """Refuse a ray fan beyond the memory budget, naming the key that makes it large.

    Nothing is allocated: :class:`~sonarsim.config.scene.Scene` calls it when a scene is
    built, so that a command refuses ``elevation_samples: 1e9`` before it starts its run.

    Parameters
    ----------
    sonar : SonarGeometry
        A :class:`~sonarsim.config.sonar.SonarConfig`.
    render : RaySettings
        A :class:`~sonarsim.config.scene.RenderSettings`.

    Returns
    -------
    n_azimuth_samples, n_elevation_samples : int
        Rays per beam across its width and across the elevation aperture.

    Raises
    ------
    ConfigError
        Keyed by the largest factor of the count: ``render.elevation_samples``,
        ``render.azimuth_samples`` or ``sonar.n_beams``.
    """
    n_az, n_el = samples_per_beam(sonar, render)
    require(ray_bytes(sonar, render), f"{sonar.n_beams} beams x {n_az} x {n_el} rays", ray_size_key(sonar, render))
    return n_az, n_el


@dataclass(frozen=True)
class RayFan:
    """The rays of one sonar configuration, in the sonar frame.

    Attributes
    ----------
    directions : (n_beams, n_azimuth_samples, n_elevation_samples, 3) float64 ndarray
        Unit vectors ``(cos phi cos theta, cos phi sin theta, sin phi)``.
    azimuth_rad : (n_beams, n_azimuth_samples) float64 ndarray
        theta of each ray column.
    elevation_rad : (n_elevation_samples,) float64 ndarray
        phi of each elevation sample, ascending.
    weight : (n_beams, n_azimuth_samples, n_elevation_samples) float64 ndarray
        ``beta(theta, phi) * cos(phi) * dphi / n_azimuth_samples`` in radians: the solid angle
        of the ray's cell (``cos(phi) dphi dtheta``) per radian of beam width, times the beam
        pattern; with these weights the image approximates the integral of paper Eq. 3 over
        solid angle whatever the number of rays.
    """

    directions: np.ndarray
    azimuth_rad: np.ndarray
    elevation_rad: np.ndarray
    weight: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n_beams, n_azimuth_samples, n_elevation_samples)``."""
        return self.weight.shape  # type: ignore[return-value]

    @property
    def n_rays(self) -> int:
        return int(self.weight.size)


def make_ray_fan(sonar: SonarGeometry, render: RaySettings, elevation_gain=None) -> RayFan:
    """Sample every beam over its azimuth width and the elevation aperture.

    Parameters
    ----------
    sonar : SonarGeometry
        A :class:`~sonarsim.config.sonar.SonarConfig`.
    render : RaySettings
        A :class:`~sonarsim.config.scene.RenderSettings`: ``elevation_samples``,
        ``azimuth_samples`` and ``beam_pattern`` are used.
    elevation_gain : callable, optional
        ``(n,) elevation (rad) -> (n,) power gain``: a sensor's two-way elevation pattern,
        multiplied into the weights (the sonar's aperture is then the span it acts over).
    """
    n_az, n_el = check_ray_budget(sonar, render)
    half_el = math.radians(sonar.elevation_fov_deg) / 2.0
    dphi = 2.0 * half_el / n_el
    phi = -half_el + (np.arange(n_el) + 0.5) * dphi

    centre = np.radians(sonar.azimuth_deg)[:, None]
    width = np.radians(sonar.effective_beam_width_deg())[:, None]
    frac = (np.arange(n_az) + 0.5) / n_az - 0.5  # sub-sample offsets across the beam, in widths
    theta = centre + frac[None, :] * width  # (n_beams, n_az)

    cphi, sphi = np.cos(phi), np.sin(phi)
    directions = np.empty(theta.shape + (n_el, 3))
    cone = getattr(sonar, "beam_shape", "plane") == "cone"
    if cone:
        # A phased array's beam: the directions whose cosine along the array (y) is sin(theta),
        # at every elevation: x = sqrt(cos^2 phi - sin^2 theta), y = sin(theta), z = sin(phi).
        # Where sin(theta) exceeds cos(phi) the cone has left the fan's elevation: no ray.
        u = np.sin(theta)[..., None] * np.ones_like(cphi)
        x2 = cphi**2 - u**2
        inside = x2 > 0.0
        directions[..., 0] = np.sqrt(np.where(inside, x2, 0.0))
        directions[..., 1] = np.where(inside, u, np.sign(u) * cphi)
        directions[..., 2] = sphi
    else:
        directions[..., 0] = np.cos(theta)[..., None] * cphi
        directions[..., 1] = np.sin(theta)[..., None] * cphi
        directions[..., 2] = sphi

    beta = np.ones(theta.shape + (n_el,))
    if render.beam_pattern == "gaussian":
        # -3 dB (half power) at the aperture edge and at the beam's azimuth edges.
        ln2 = math.log(2.0)
        beta = beta * np.exp(-ln2 * (phi / half_el) ** 2)[None, None, :]
        beta = beta * np.exp(-ln2 * (2.0 * frac) ** 2)[None, :, None]
    if elevation_gain is not None:
        beta = beta * np.asarray(elevation_gain(phi), dtype=float)[None, None, :]
    # A ray stands for the solid angle cos(phi) dphi dtheta of its cell: the cos(phi) is the
    # sphere's metric (a cell of one dphi x dtheta narrows towards the poles), so that the image
    # is the integral of paper Eq. 3 over solid angle, per radian of beam width.
    weight = beta * (cphi * (dphi / n_az))[None, None, :]
    if cone:
        # On a cone the cell is dphi by du = cos(theta) dtheta in the direction cosine; its solid
        # angle is dphi du / cos(theta'), cos(theta') = x / cos(phi) the cosine of the ray's own
        # azimuth: cos(phi) dphi dtheta (the plane's) times cos(theta) / x. (At phi = 0 that is
        # 1; on the axis 1 / cos(phi): a cone's azimuth width grows as 1 / cos(phi).)
        c_theta = np.cos(theta)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            stretch = np.where(inside, c_theta / directions[..., 0], 0.0)
        weight = weight * stretch
    return RayFan(directions=directions, azimuth_rad=theta, elevation_rad=phi, weight=weight)
