"""Radiometry: the backscattered energy a ray carries (paper Eq. 3-6).

A ray hitting a surface at incidence alpha returns ``beta * l(r) * f(alpha) * cos(phi) dphi``, where
``beta * cos(phi) dphi`` is the ray's weight (beam pattern times the solid angle it stands for),
``l(r)`` the range compensation and ``f`` the surface's backscatter law
(:mod:`sonarsim.config.materials`): the paper's Lambertian ``rho * cos(alpha)`` by default,
Lambert's ``mu * cos(alpha)**2``, a diffuse part plus a specular lobe, or a sea bed's sediment
(:mod:`sonarsim.core.seabed`), tabulated in incidence at the sonar's frequency.

:class:`SurfaceLaws` holds the laws of a scene's surfaces by surface id, as the compiled
kernels take them (a law code and its parameters per surface); :func:`backscatter` is their
NumPy twin.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import numpy as np

# The backscatter laws' codes in the compiled kernels (``renderer/_kernels.pyx``) and in
# :class:`SurfaceLaws`. :mod:`sonarsim.config.materials` gives the same codes
# (``Material.code``); they are repeated here because core imports nothing of the package
# above it (tests/core/test_core_imports_nothing.py checks that the two agree).
LAMBERTIAN, LAMBERT, ROUGH, SEDIMENT = 0, 1, 2, 3


class SurfaceMaterial(Protocol):
    """What :meth:`SurfaceLaws.of` reads of a surface's material
    (:class:`~sonarsim.config.materials.Material` has it)."""

    @property
    def coefficient(self) -> float: ...
    @property
    def code(self) -> int: ...
    @property
    def lobe(self) -> tuple[float, float]: ...
    def table(self, frequency_hz: float | None, sound_speed_m_s: float) -> np.ndarray | None: ...


@dataclass(frozen=True)
class SurfaceLaws:
    """Backscatter laws indexed by surface id + 1 (row 0: nothing hit; it scatters nothing).

    Attributes
    ----------
    coefficient : (n_surfaces + 1,) float64 ndarray
        The diffuse coefficient: ``albedo`` (lambertian, rough), ``mu`` (lambert) or the
        sediment law's level (``10**(level_db / 10)``).
    law : (n_surfaces + 1,) int32 ndarray
        Law code (:data:`LAMBERTIAN`, :data:`LAMBERT`, :data:`ROUGH`, :data:`SEDIMENT`).
    lobe : (n_surfaces + 1, 2) or (n_surfaces + 1, 2 + T) float64 ndarray
        ``(specular_strength, roughness)`` of the rough law's lobe (0 for the others); where a
        surface's law is tabulated (``SEDIMENT``), ``T`` more columns hold its per-ray law
        ``f(alpha)`` at ``T`` incidences evenly from 0 to 90 degrees (0 in the other rows).
    reflectance : (n_surfaces + 1, T) float64 ndarray or None
        Where some mirror reflects by the physics (``reflection``): each surface's coherent
        reflectance ``|V|^2`` against ``c = |cos(incidence)|`` on T points evenly from 0 to 1
        (:func:`sonarsim.core.reflection.reflectance_table`; a constant ``specular`` as a
        constant row, 0 for a surface that does not mirror); ``None``: the constants.
    reflect_q : (n_surfaces + 1,) float64 ndarray or None
        The roughness loss's ``q = 4 k^2 h^2`` by row (``exp(-q c^2)``; 0 for a constant).
    """

    coefficient: np.ndarray
    law: np.ndarray
    lobe: np.ndarray
    reflectance: np.ndarray | None = None
    reflect_q: np.ndarray | None = None

    @classmethod
    def of(cls, materials: "Sequence[SurfaceMaterial] | np.ndarray | SurfaceLaws",
           frequency_hz: float | None = None, sound_speed_m_s: float = 1500.0) -> "SurfaceLaws":
        """From the surfaces' materials in surface-id order (row 0 is added), or pass a table
        through; a plain float array is the Lambertian albedo by surface id + 1 (row 0 included).

        ``frequency_hz`` and ``sound_speed_m_s``: the sonar's frequency and the water's speed,
        which a tabulated law (``SEDIMENT``) is evaluated at (its material's ``table`` raises
        where it needs a frequency and none is given)."""
        if isinstance(materials, SurfaceLaws):
            return materials
        if isinstance(materials, np.ndarray):
            n = len(materials)
            return cls(np.asarray(materials, dtype=np.float64), np.zeros(n, np.int32), np.zeros((n, 2)))
        mats = list(materials)
        coefficient = np.array([0.0] + [m.coefficient for m in mats], dtype=np.float64)
        law = np.array([LAMBERTIAN] + [m.code for m in mats], dtype=np.int32)
        lobe = np.array([(0.0, 0.0)] + [m.lobe for m in mats], dtype=np.float64).reshape(-1, 2)
        tables = [m.table(frequency_hz, sound_speed_m_s) if m.code == SEDIMENT else None for m in mats]
        if any(t is not None for t in tables):
            width = max(len(t) for t in tables if t is not None)
            wide = np.zeros((len(lobe), 2 + width))
            wide[:, :2] = lobe
            grid = np.linspace(0.0, 1.0, width)
            for i, t in enumerate(tables):
                if t is not None:  # a coarser table onto the finest's incidences (linear in alpha, as read)
                    wide[i + 1, 2:] = t if len(t) == width else np.interp(grid, np.linspace(0.0, 1.0, len(t)), t)
            lobe = wide
        return cls(coefficient, law, lobe)

    @property
    def tabulated(self) -> bool:
        """Some surface's law is a table (``SEDIMENT``): the kernels read ``lobe``'s extra columns."""
        return self.lobe.shape[1] > 2

    def __len__(self) -> int:
        return len(self.coefficient)

    @property
    def lambertian_only(self) -> bool:
        """Every surface follows the paper's law (the kernels' fast case)."""
        return not np.any(self.law != LAMBERTIAN)

    def concat(self, other: "SurfaceLaws", skip: int = 0) -> "SurfaceLaws":
        """This table followed by ``other``'s rows from ``skip`` on (mirror images of surfaces)."""
        a, b = self.lobe, other.lobe[skip:]
        if a.shape[1] != b.shape[1]:  # one of the two tabulates a law: widen the other with zeros
            width = max(a.shape[1], b.shape[1])
            a = np.pad(a, ((0, 0), (0, width - a.shape[1])))
            b = np.pad(b, ((0, 0), (0, width - b.shape[1])))
        # (Mirror images serve the paper's method, whose one reflection is its constant R: the
        # joined table has no reflectance.)
        return SurfaceLaws(np.concatenate([self.coefficient, other.coefficient[skip:]]),
                           np.concatenate([self.law, other.law[skip:]]),
                           np.concatenate([a, b]))


def tabulated_law(cos_incidence: np.ndarray, table: np.ndarray) -> np.ndarray:
    """A tabulated per-ray law at cos(alpha): ``table`` (..., T) holds ``f`` at ``T``
    incidences evenly from 0 to 90 degrees, read linearly in ``alpha = arccos(c)`` (the
    kernels' operations in their order).

    Parameters
    ----------
    cos_incidence : (...) float array
        cos(alpha), clipped to [0, 1].
    table : (..., T) float array
        Per-ray law samples, broadcast against ``cos_incidence``.

    Returns
    -------
    (...) float64 ndarray
    """
    c = np.clip(np.asarray(cos_incidence, dtype=np.float64), 0.0, 1.0)
    table = np.asarray(table, dtype=np.float64)
    last = table.shape[-1] - 1
    a = np.arccos(c) * (last / (np.pi / 2))
    shape = np.broadcast_shapes(c.shape, table.shape[:-1])
    a = np.broadcast_to(a, shape)
    i = np.minimum(a.astype(np.int64), last - 1)
    t = a - i
    full = np.broadcast_to(table, shape + table.shape[-1:])
    lo = np.take_along_axis(full, i[..., None], -1)[..., 0]
    hi = np.take_along_axis(full, i[..., None] + 1, -1)[..., 0]
    return lo + (hi - lo) * t


def specular_lobe(cos_incidence: np.ndarray, roughness: np.ndarray) -> np.ndarray:
    """The Kirchhoff lobe per ray, ``exp(-tan(alpha)**2 / (2 s**2)) / cos(alpha)**5``, 1 at normal incidence.

    (Per unit area the lobe falls as ``1 / cos^4``; a ray's footprint adds ``1 / cos``.)

    Parameters
    ----------
    cos_incidence : (...) float array
        cos(alpha), in [0, 1].
    roughness : (...) float array
        Rms facet slope s > 0 (dimensionless).

    Returns
    -------
    (...) float64 ndarray; 0 at grazing incidence (cos(alpha) = 0).
    """
    c = np.asarray(cos_incidence, dtype=np.float64)
    s = np.asarray(roughness, dtype=np.float64)
    c2 = c * c
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t2 = (1.0 - c2) / c2
        out = np.exp(-t2 / (2.0 * s * s)) / (c2 * c2 * c)
    return np.where((c2 > 0) & (s > 0), out, 0.0)


def backscatter(
    weight: np.ndarray,
    cos_incidence: np.ndarray,
    laws: SurfaceLaws,
    index: np.ndarray,
    distance_m: np.ndarray,
    tvg: bool,
    texel: np.ndarray | None = None,
) -> np.ndarray:
    """Per-ray backscatter ``beta * l(r) * f(alpha) * cos(phi) dphi`` under each surface's law.

    The NumPy twin of the kernels' law (same operations in the same order: the Lambertian
    case is exactly :func:`lambertian_intensity`).

    Parameters
    ----------
    weight : (...) float array
        Ray weight ``beta(theta, phi) * cos(phi) dphi`` (radians).
    cos_incidence : (...) float array
        cos(alpha) in [0, 1].
    laws : SurfaceLaws
    index : (...) int array
        Surface id + 1 of each ray's hit (0: nothing).
    distance_m : (...) float array
        Range of the hit, metres (``inf`` where nothing is hit).
    tvg : bool
        ``True``: ``l(r) = 1``; ``False``: ``l(r) = 1 / r**2``.
    texel : (...) float array, optional
        Brightness in [0, 1] scaling the diffuse coefficient (a texture); default 1.

    Returns
    -------
    (...) float64 ndarray: the intensity map I_f (0 where nothing is hit).
    """
    index = np.asarray(index)
    coefficient = laws.coefficient[index]
    if texel is not None:
        coefficient = coefficient * np.asarray(texel, dtype=np.float64)
    if laws.lambertian_only:
        return lambertian_intensity(weight, cos_incidence, coefficient, distance_m, tvg)
    law = laws.law[index]
    w = np.asarray(weight, dtype=np.float64)
    c = np.asarray(cos_incidence).astype(np.float64)
    diffuse = w * coefficient * c
    lobe = laws.lobe[index]
    out = diffuse  # lambertian and lambert: the same per-ray form (see config.materials)
    rough = law == ROUGH
    if np.any(rough):
        out = np.where(rough, w * (coefficient * c + lobe[..., 0] * specular_lobe(c, lobe[..., 1])), out)
    tab = law == SEDIMENT
    if np.any(tab):
        out = np.where(tab, w * coefficient * tabulated_law(c, lobe[..., 2:]), out)
    hit = np.isfinite(distance_m)
    out = np.where(hit, out, 0.0)
    if not tvg:
        r = np.where(hit, distance_m, 1.0)
        out = out / np.maximum(r, 1e-6) ** 2
    return out


def lambertian_intensity(
    weight: np.ndarray,
    cos_incidence: np.ndarray,
    albedo: np.ndarray,
    distance_m: np.ndarray,
    tvg: bool,
) -> np.ndarray:
    """Per-ray backscatter ``beta * l(r) * rho * cos(alpha) * cos(phi) dphi`` (paper Eq. 3-6).

    Parameters
    ----------
    weight : (...) float array
        Ray weight ``beta(theta, phi) * cos(phi) dphi`` (radians), see :class:`sonarsim.core.rays.RayFan`.
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
