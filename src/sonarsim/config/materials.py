"""Materials: the backscatter law of a surface (an object, a plane, the ground).

A law is a backscattering cross-section per unit area and unit solid angle, ``sigma(alpha)``
(dimensionless; ``10 log10 sigma`` is the backscattering strength, the quantity sea-bed
measurements report), at incidence ``alpha`` (the angle between the ray and the surface
normal). A ray of weight ``w = beta(theta, phi) * cos(phi) dphi`` meets an area that grows as
``1 / cos(alpha)`` (``dA = r^2 dOmega / cos(alpha)``), so it carries
``w * l(r) * f(alpha)`` with ``f = sigma / cos(alpha)`` (paper Eq. 3-6 with ``f = rho cos``):

``lambertian`` (the paper's, the default)
    ``sigma = albedo * cos(alpha)**2``, i.e. ``f = albedo * cos(alpha)``: the paper's
    ``rho cos(alpha)`` per ray is Lambert's law per unit area.
``lambert`` (Lambert's law for sea beds, Mackenzie 1961)
    ``sigma = mu * cos(alpha)**2``, i.e. ``f = mu * cos(alpha)``: the same angular law as the
    paper's, given by the measured parameter ``mu`` (linear) or ``mu_db = 10 log10(mu)``
    (Mackenzie measured about -27 dB at 24 kHz in deep water; sandy and muddy beds range over
    roughly -40 to -15 dB). With ``mu = albedo`` the two laws give the same image.
``rough`` (a rough surface: a diffuse part and a specular lobe, for smooth objects)
    ``sigma = albedo * cos(alpha)**2 + specular_strength * exp(-tan(alpha)**2 / (2 s**2)) / cos(alpha)**4``
    with ``s = roughness``. The lobe is the Kirchhoff (geometric-optics, facet) backscatter of
    a surface whose facet slopes are Gaussian with rms slope ``s`` along each axis: only facets
    facing the sonar reflect back, their density falls as ``exp(-tan^2 / 2 s^2)``, and the
    Jacobian from slopes to solid angle gives ``1 / cos^4`` (Jackson & Richardson, *High-Frequency
    Seafloor Acoustics*, 2007, Sect. 13.1; Kirchhoff's own scale is ``|R(0)|^2 / (8 pi s^2)``,
    here the free ``specular_strength``: the lobe's value at normal incidence). It peaks at normal
    incidence for ``s <= 1/2`` (rms slope up to about 27 degrees), the range allowed: rougher
    surfaces are no longer "smooth objects" and the single-facet picture fails.

The sensor stage (:mod:`sonarsim.sensor`) reads the image formed with these laws as
``sigma / r^2`` summed over each bin, so its target strengths are those of the laws' sigma.

A texture (``texture: true``, objects with a textured mesh only) scales the diffuse part
(``albedo`` or ``mu``) by the brightness in [0, 1] of the texel the ray meets; the specular lobe
is a property of the surface's slopes and is not scaled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.radiometry import LAMBERT, LAMBERTIAN, ROUGH
from ..errors import ConfigError, shown

LAWS = ("lambertian", "lambert", "rough")
# Law codes of the compiled kernels (index into LAWS): LAMBERTIAN, LAMBERT, ROUGH, defined once in
# core.radiometry (imported above).
# Parameters each law uses (beyond ``law`` and ``texture``).
LAW_KEYS = {"lambertian": ("albedo",), "lambert": ("mu",), "rough": ("albedo", "specular_strength", "roughness")}
REQUIRED_KEYS = {"lambertian": (), "lambert": ("mu",), "rough": ("specular_strength", "roughness")}
# Rms slope above which the Kirchhoff lobe no longer peaks at normal incidence.
MAX_ROUGHNESS = 0.5
# The smoothest facets: below this the lobe is a glint narrower than the rays' spacing (and at
# 1e-300 its exponent, -tan^2 / (2 s^2), was 0 / 0 at normal incidence: NaN).
MIN_ROUGHNESS = 1e-3
# The largest lobe at normal incidence (per unit area): a mirror-smooth facet's Kirchhoff peak,
# R^2 / (2 s^2), is about 5e5 at the smoothest roughness; 1e300 made the image infinite.
MAX_SPECULAR_STRENGTH = 1e6
DEFAULT_ALBEDO = 0.8


@dataclass(frozen=True)
class Material:
    """The backscatter law of a surface (see the module's docstring for the formulas).

    Attributes
    ----------
    law : {'lambertian', 'lambert', 'rough'}
    albedo : float or None
        Diffuse albedo in [0, 1] (``lambertian``, ``rough``); ``None``: 0.8.
    mu : float or None
        Lambert's parameter in [0, 1], linear (``lambert``; required there).
    specular_strength : float or None
        The lobe's value at normal incidence, in [0, 1e6] (``rough``; required there).
    roughness : float or None
        Rms facet slope ``s`` (dimensionless, tan of the rms slope angle), in [0.001, 0.5]
        (``rough``; required there).
    texture : bool
        Scale the diffuse part by the mesh's texture (objects whose mesh has UV coordinates and
        a texture image).
    """

    law: str = "lambertian"
    albedo: float | None = None
    mu: float | None = None
    specular_strength: float | None = None
    roughness: float | None = None
    texture: bool = False

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ConfigError("law", f"unknown law {shown(self.law)}; allowed: {', '.join(LAWS)}")
        used = LAW_KEYS[self.law]
        for key in ("albedo", "mu", "specular_strength", "roughness"):
            value = getattr(self, key)
            if value is None:
                if key in REQUIRED_KEYS[self.law]:
                    raise ConfigError(key, f"required by the law {shown(self.law)}")
                continue
            if key not in used:
                raise ConfigError(key, f"not used by the law {shown(self.law)}; its parameters: {', '.join(used)}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(key, f"must be a finite number, got {shown(value)}")
            object.__setattr__(self, key, float(value))
        for key in ("albedo", "mu"):
            v = getattr(self, key)
            if v is not None and not 0.0 <= v <= 1.0:
                raise ConfigError(key, f"must be within [0, 1], got {v}")
        if self.specular_strength is not None and not 0.0 <= self.specular_strength <= MAX_SPECULAR_STRENGTH:
            raise ConfigError("specular_strength", f"must be within [0, {MAX_SPECULAR_STRENGTH:g}] (the lobe at normal "
                              f"incidence), got {self.specular_strength}")
        if self.roughness is not None and not MIN_ROUGHNESS <= self.roughness <= MAX_ROUGHNESS:
            raise ConfigError(
                "roughness",
                f"must be an rms slope in [{MIN_ROUGHNESS:g}, {MAX_ROUGHNESS}] (beyond it the lobe no longer peaks at "
                f"normal incidence; below, a glint narrower than the rays sample), got {self.roughness}",
            )
        if not isinstance(self.texture, bool):
            raise ConfigError("texture", f"must be true or false, got {shown(self.texture)}")

    @classmethod
    def lambertian(cls, albedo: float) -> "Material":
        """The paper's law ``albedo * cos(alpha)`` (what the ``albedo:`` shorthand means)."""
        return cls("lambertian", albedo=albedo)

    @property
    def code(self) -> int:
        """The law's code in the compiled kernels (:data:`LAMBERTIAN`, :data:`LAMBERT`, :data:`ROUGH`)."""
        return LAWS.index(self.law)

    @property
    def coefficient(self) -> float:
        """The diffuse coefficient: ``albedo`` (default 0.8) or ``mu``; the part a texture scales."""
        if self.law == "lambert":
            return float(self.mu)
        return DEFAULT_ALBEDO if self.albedo is None else float(self.albedo)

    @property
    def lobe(self) -> tuple[float, float]:
        """``(specular_strength, roughness)`` of the specular lobe; ``(0, 0)`` without one."""
        if self.law != "rough":
            return (0.0, 0.0)
        return (float(self.specular_strength), float(self.roughness))

    def evaluate(self, cos_incidence, texel=None) -> np.ndarray:
        """The per-ray law ``f(alpha) = sigma(alpha) / cos(alpha)``, from its formula (the reference
        the renderer is tested against).

        Parameters
        ----------
        cos_incidence : (...) float array
            cos(alpha) in [0, 1].
        texel : (...) float array, optional
            Texture brightness scaling the diffuse part (default 1).

        Returns
        -------
        (...) float64 ndarray, dimensionless.
        """
        c = np.clip(np.asarray(cos_incidence, dtype=np.float64), 0.0, 1.0)
        coef = self.coefficient * (1.0 if texel is None else np.asarray(texel, dtype=np.float64))
        if self.law in ("lambertian", "lambert"):
            return coef * c
        strength, s = self.lobe
        alpha = np.arccos(c)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            lobe = np.exp(-np.tan(alpha) ** 2 / (2.0 * s**2)) / np.cos(alpha) ** 5
        return coef * c + strength * np.where(c > 0, np.nan_to_num(lobe, nan=0.0, posinf=0.0), 0.0)

    def to_dict(self) -> dict:
        """The scene-file form (``mu`` linear; keys not given stay out)."""
        out: dict = {"law": self.law}
        for key in LAW_KEYS[self.law]:
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.texture:
            out["texture"] = True
        return out


def mu_from_db(mu_db: float) -> float:
    """Lambert's ``mu`` from ``10 log10(mu)`` (dB)."""
    return 10.0 ** (mu_db / 10.0)
