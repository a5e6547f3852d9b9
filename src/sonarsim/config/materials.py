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
``sediment`` (a sea bed by its sediment, after the APL-UW high-frequency model)
    ``sigma = 10**(level_db / 10) * sigma_b(90 deg - alpha; sediment, f)``: interface roughness
    (small-slope approximation: Kirchhoff's peak near normal incidence, perturbation theory
    elsewhere) plus the sediment volume, with the Rayleigh coefficient of the sediment's
    impedance, at the sonar's frequency ``f`` (:mod:`sonarsim.core.seabed`, which gives every
    equation and its source). ``sediment`` names a class (``rock``, ``cobble``, ``sandy-gravel``
    ... ``medium-sand`` ... ``clay``: :data:`~sonarsim.core.seabed.SEDIMENT_NAMES`) or
    ``grain_size_phi`` gives the mean grain size (-1 to 9 phi); ``level_db`` (default 0, within
    [-30, 30]) shifts the level, as a fit to a recording does. The model was fitted on 10 to
    100 kHz (:func:`~sonarsim.core.seabed.model_range`); above, it is extrapolated. The
    renderer evaluates the law once per sonar frequency into a table of
    :data:`~sonarsim.core.seabed.TABLE_SIZE` incidences (a quarter degree apart) that the kernels
    interpolate linearly.

Energy: a surface scattering by Lambert's law returns the fraction ``pi mu`` of what it
receives, so ``lambert``'s ``mu`` is at most ``1 / pi`` (-5 dB). The paper's ``albedo`` (up to
1, default 0.8: ``pi * 0.8`` = +4 dB above that bound) is kept as the paper has it.

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

from ..core import seabed
# Bounds of the laws' parameters: the one table of fittable parameters. The roughness: above 0.5
# the Kirchhoff lobe no longer peaks at normal incidence; below 1e-3 the lobe is a glint narrower
# than the rays' spacing (at 1e-300 its exponent, -tan^2 / (2 s^2), was 0 / 0: NaN). The lobe's
# strength: a mirror-smooth facet's Kirchhoff peak, R^2 / (2 s^2), is about 5e5 at the smoothest
# roughness; 1e300 made the image infinite.
from .parameters import MAX_LAMBERT_MU, MAX_ROUGHNESS, MAX_SPECULAR_STRENGTH, MIN_ROUGHNESS  # noqa: F401
from .parameters import SEDIMENT_LEVEL_RANGE_DB as LEVEL_RANGE_DB
from ..core.radiometry import LAMBERT, LAMBERTIAN, ROUGH, SEDIMENT
from ..errors import ConfigError, shown

LAWS = ("lambertian", "lambert", "rough", "sediment")
# Law codes of the compiled kernels (index into LAWS): LAMBERTIAN, LAMBERT, ROUGH, SEDIMENT,
# defined once in core.radiometry (imported above).
# Parameters each law uses (beyond ``law`` and ``texture``).
LAW_KEYS = {"lambertian": ("albedo",), "lambert": ("mu",), "rough": ("albedo", "specular_strength", "roughness"),
            "sediment": ("sediment", "grain_size_phi", "level_db")}
REQUIRED_KEYS = {"lambertian": (), "lambert": ("mu",), "rough": ("specular_strength", "roughness"), "sediment": ()}
DEFAULT_SEDIMENT = "medium-sand"
DEFAULT_ALBEDO = 0.8


@dataclass(frozen=True)
class Material:
    """The backscatter law of a surface (see the module's docstring for the formulas).

    Attributes
    ----------
    law : {'lambertian', 'lambert', 'rough', 'sediment'}
    albedo : float or None
        Diffuse albedo in [0, 1] (``lambertian``, ``rough``); ``None``: 0.8.
    mu : float or None
        Lambert's parameter in [0, 1 / pi], linear (``lambert``; required there): at most
        Lambert's energy bound.
    specular_strength : float or None
        The lobe's value at normal incidence, in [0, 1e6] (``rough``; required there).
    roughness : float or None
        Rms facet slope ``s`` (dimensionless, tan of the rms slope angle), in [0.001, 0.5]
        (``rough``; required there).
    sediment : str or None
        ``sediment``: the class (:data:`~sonarsim.core.seabed.SEDIMENT_NAMES`); ``None`` with
        no ``grain_size_phi``: ``medium-sand``.
    grain_size_phi : float or None
        ``sediment``: the mean grain size, phi, within [-1, 9], instead of a class.
    level_db : float or None
        ``sediment``: dB added to the model's level, within [-30, 30]; ``None``: 0.
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
    sediment: str | None = None
    grain_size_phi: float | None = None
    level_db: float | None = None

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ConfigError("law", f"unknown law {shown(self.law)}; allowed: {', '.join(LAWS)}")
        used = LAW_KEYS[self.law]
        if self.sediment is not None:
            if "sediment" not in used:
                raise ConfigError("sediment", f"not used by the law {shown(self.law)}; its parameters: {', '.join(used)}")
            if not isinstance(self.sediment, str) or self.sediment not in seabed.SEDIMENT_NAMES:
                raise ConfigError("sediment", f"unknown sediment {shown(self.sediment)}; allowed: "
                                              f"{', '.join(seabed.SEDIMENT_NAMES)}")
            if self.grain_size_phi is not None:
                raise ConfigError("grain_size_phi", "give either sediment (a class) or grain_size_phi, not both")
        for key in ("albedo", "mu", "specular_strength", "roughness", "grain_size_phi", "level_db"):
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
        if self.albedo is not None and not 0.0 <= self.albedo <= 1.0:
            raise ConfigError("albedo", f"must be within [0, 1], got {self.albedo}")
        if self.mu is not None and not 0.0 <= self.mu <= MAX_LAMBERT_MU:
            raise ConfigError("mu", f"must be within [0, 1/pi = {MAX_LAMBERT_MU:.4f}] (Lambert's law returns pi mu "
                                    f"of what it receives; -4.97 dB at most), got {self.mu}")
        if self.grain_size_phi is not None:
            lo, hi = seabed.GRAIN_SIZE_RANGE_PHI
            if not lo <= self.grain_size_phi <= hi:
                raise ConfigError("grain_size_phi", f"must be within [{lo:g}, {hi:g}] phi (sandy gravel to clay), "
                                                    f"got {self.grain_size_phi}")
        if self.level_db is not None and not LEVEL_RANGE_DB[0] <= self.level_db <= LEVEL_RANGE_DB[1]:
            raise ConfigError("level_db", f"must be within [{LEVEL_RANGE_DB[0]:g}, {LEVEL_RANGE_DB[1]:g}] dB, "
                                          f"got {self.level_db}")
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
        """The law's code in the compiled kernels (:data:`LAMBERTIAN`, :data:`LAMBERT`, :data:`ROUGH`,
        :data:`SEDIMENT`)."""
        return LAWS.index(self.law)

    @property
    def coefficient(self) -> float:
        """The diffuse coefficient: ``albedo`` (default 0.8), ``mu``, or the sediment law's
        ``10**(level_db / 10)``; the part a texture scales."""
        if self.law == "lambert":
            return float(self.mu)
        if self.law == "sediment":
            return 10.0 ** ((self.level_db or 0.0) / 10.0)
        return DEFAULT_ALBEDO if self.albedo is None else float(self.albedo)

    def sediment_model(self, water_sound_speed_m_s: float = 1500.0) -> "seabed.Sediment":
        """The sediment law's parameters (:class:`~sonarsim.core.seabed.Sediment`)."""
        if self.law != "sediment":
            raise ValueError(f"the law {self.law!r} has no sediment")
        if self.grain_size_phi is not None:
            return seabed.sediment_from_grain_size(self.grain_size_phi, water_sound_speed_m_s=water_sound_speed_m_s)
        return seabed.sediment(self.sediment or DEFAULT_SEDIMENT, water_sound_speed_m_s)

    def table(self, frequency_hz: float | None, sound_speed_m_s: float = 1500.0) -> np.ndarray | None:
        """The tabulated per-ray law ``f(alpha)`` of ``sediment`` at ``frequency_hz``
        (:func:`sonarsim.core.seabed.law_table`, without ``level_db``); ``None`` for the laws
        the kernels evaluate from their formulas.

        Raises
        ------
        ConfigError
            ``sonar.frequency_khz`` when the law needs a frequency and none is given.
        """
        if self.law != "sediment":
            return None
        if frequency_hz is None:
            raise ConfigError("sonar.frequency_khz", "the sediment law scatters by frequency: set the sonar's "
                                                     "frequency_khz (or sensor.frequency_khz)")
        return seabed.law_table(self.sediment_model(sound_speed_m_s), float(frequency_hz), float(sound_speed_m_s))

    @property
    def lobe(self) -> tuple[float, float]:
        """``(specular_strength, roughness)`` of the specular lobe; ``(0, 0)`` without one."""
        if self.law != "rough":
            return (0.0, 0.0)
        return (float(self.specular_strength), float(self.roughness))

    def evaluate(self, cos_incidence, texel=None, frequency_hz: float | None = None,
                 sound_speed_m_s: float = 1500.0) -> np.ndarray:
        """The per-ray law ``f(alpha) = sigma(alpha) / cos(alpha)``, from its formula (the reference
        the renderer is tested against).

        Parameters
        ----------
        cos_incidence : (...) float array
            cos(alpha) in [0, 1].
        texel : (...) float array, optional
            Texture brightness scaling the diffuse part (default 1).
        frequency_hz, sound_speed_m_s : float
            The sonar's frequency (Hz) and the water's sound speed (m/s): the sediment law's.

        Returns
        -------
        (...) float64 ndarray, dimensionless.
        """
        c = np.clip(np.asarray(cos_incidence, dtype=np.float64), 0.0, 1.0)
        coef = self.coefficient * (1.0 if texel is None else np.asarray(texel, dtype=np.float64))
        if self.law in ("lambertian", "lambert"):
            return coef * c
        if self.law == "sediment":
            if frequency_hz is None:
                raise ConfigError("sonar.frequency_khz", "the sediment law scatters by frequency")
            grazing = np.pi / 2 - np.arccos(c)
            sigma = seabed.backscatter(grazing, self.sediment_model(sound_speed_m_s), frequency_hz, sound_speed_m_s)
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(c > 1e-12, coef * sigma / c, 0.0)
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


# Objects' materials --------------------------------------------------------------------------

#: Water's characteristic impedance, MRayl (1000 kg/m^3 x 1480 m/s).
WATER_IMPEDANCE_MRAYL = 1.48


@dataclass(frozen=True)
class ObjectMaterial:
    """A solid's acoustic make-up, for :func:`object_material`.

    Attributes
    ----------
    impedance_mrayl : float
        Characteristic (longitudinal) impedance ``rho c``, MRayl (handbook values: Kinsler et
        al., *Fundamentals of Acoustics*, 4th ed., Appendix A10; Selfridge 1985, IEEE SU-32).
    roughness : float
        Rms facet slope of a typical finish (our choice: the lobe must be wider than a few rays).
    diffuse_db : float
        The diffuse part, Lambert's ``10 log10 mu``, dB (our choice: a rough-surface floor well
        below the specular lobe).
    """

    impedance_mrayl: float
    roughness: float
    diffuse_db: float

    @property
    def reflection(self) -> float:
        """The normal-incidence reflection coefficient against water, ``(Z - Z_w) / (Z + Z_w)``."""
        return (self.impedance_mrayl - WATER_IMPEDANCE_MRAYL) / (self.impedance_mrayl + WATER_IMPEDANCE_MRAYL)


#: Named materials of objects: ``material: {preset: steel}``. Impedances from handbook densities
#: and longitudinal speeds (steel 7850 kg/m^3 x 5900 m/s, concrete 2400 x 3500, granite 2700 x
#: 6000, PVC 1380 x 2380, neoprene rubber 1300 x 1600, oak across the grain 720 x 1500...4000 taken
#: at 2.9); ``rigid`` is the ideal reflector (R = 1) of textbook target strengths.
OBJECT_MATERIALS: dict[str, ObjectMaterial] = {
    "rigid": ObjectMaterial(1e9, 0.1, -60.0),
    "steel": ObjectMaterial(46.3, 0.1, -30.0),
    "concrete": ObjectMaterial(8.4, 0.2, -20.0),
    "rock": ObjectMaterial(16.2, 0.3, -15.0),
    "plastic": ObjectMaterial(3.3, 0.1, -30.0),
    "rubber": ObjectMaterial(2.1, 0.15, -40.0),
    "wood": ObjectMaterial(2.9, 0.2, -35.0),
}


def object_material(name: str, texture: bool = False) -> Material:
    """The ``rough`` law of a named solid (:data:`OBJECT_MATERIALS`): a Kirchhoff lobe of its
    finish's rms slope ``s`` at Kirchhoff's own scale, ``|R|^2 / (8 pi s^2)`` (``R`` its
    normal-incidence reflection coefficient), over a weak diffuse part.

    At that scale the lobe integrates, over any smooth convex surface, to the geometric-optics
    echo of its specular point: ``|R|^2 a1 a2 / 4`` for principal radii ``a1, a2`` (a sphere:
    ``TS = 10 log10(|R|^2 a^2 / 4)``), whatever ``s`` (tests/renderer/test_object_materials.py).
    A flat face seen square on gives ``|R|^2 A / (8 pi s^2)``: the incoherent facet picture, not
    a plate's coherent ``A^2 / lambda^2`` lobe (not modelled).
    """
    if name not in OBJECT_MATERIALS:
        raise ConfigError("preset", f"unknown material {shown(name)}; allowed: {', '.join(OBJECT_MATERIALS)}")
    m = OBJECT_MATERIALS[name]
    s = m.roughness
    return Material("rough", albedo=10.0 ** (m.diffuse_db / 10.0), specular_strength=m.reflection**2 / (8 * math.pi * s * s),
                    roughness=s, texture=texture)
