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

``plate`` (an object's flat face: its coherent, physical-optics lobe)
    ``sigma = albedo cos^2(alpha) + sigma_bs(alpha) / A`` with the face's far-field
    ``sigma_bs = |R|^2 A^2 / lambda^2 (2 J1(x) / x)^2 cos^2(alpha)``, ``x = 2 k a sin(alpha)``,
    ``a = sqrt(A / pi)`` (:func:`sonarsim.core.reflection.face_cross_section`): ``area_m2`` is A,
    ``reflectance`` ``|R|^2`` (default 1). The rays meeting the face add up to its far-field target
    strength, and in its near field to the infinite mirror's ``r^2 / 4``. Tabulated per
    frequency, finely enough for the lobe.

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

from ..core import reflection, seabed
# Bounds of the laws' parameters: the one table of fittable parameters. The roughness: above 0.5
# the Kirchhoff lobe no longer peaks at normal incidence; below 1e-3 the lobe is a glint narrower
# than the rays' spacing (at 1e-300 its exponent, -tan^2 / (2 s^2), was 0 / 0: NaN). The lobe's
# strength: a mirror-smooth facet's Kirchhoff peak, R^2 / (2 s^2), is about 5e5 at the smoothest
# roughness; 1e300 made the image infinite.
from .parameters import MAX_LAMBERT_MU, MAX_ROUGHNESS, MAX_SPECULAR_STRENGTH, MIN_ROUGHNESS  # noqa: F401
from .parameters import SEDIMENT_LEVEL_RANGE_DB as LEVEL_RANGE_DB
from ..core.radiometry import LAMBERT, LAMBERTIAN, ROUGH, SEDIMENT
from ..errors import ConfigError, shown

LAWS = ("lambertian", "lambert", "rough", "sediment", "plate")
# Law codes of the compiled kernels (index into LAWS): LAMBERTIAN, LAMBERT, ROUGH, SEDIMENT,
# defined once in core.radiometry (imported above).
# Parameters each law uses (beyond ``law`` and ``texture``).
LAW_KEYS = {"lambertian": ("albedo",), "lambert": ("mu",), "rough": ("albedo", "specular_strength", "roughness"),
            "sediment": ("sediment", "grain_size_phi", "level_db"), "plate": ("area_m2", "reflectance", "albedo")}
REQUIRED_KEYS = {"lambertian": (), "lambert": ("mu",), "rough": ("specular_strength", "roughness"), "sediment": (),
                 "plate": ("area_m2",)}
#: The laws the kernels read from a table per frequency (their code is SEDIMENT's: "tabulated").
TABULATED_LAWS = ("sediment", "plate")
#: Bounds of a plate's face area, m^2.
PLATE_AREA_RANGE_M2 = (1e-6, 100.0)
DEFAULT_SEDIMENT = "medium-sand"
DEFAULT_ALBEDO = 0.8


@dataclass(frozen=True)
class Material:
    """The backscatter law of a surface (see the module's docstring for the formulas).

    Attributes
    ----------
    law : {'lambertian', 'lambert', 'rough', 'sediment', 'plate'}
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
    area_m2 : float or None
        ``plate``: the area of the flat face, m^2, within [1e-6, 100] (required there).
    reflectance : float or None
        ``plate``: the face's ``|R|^2`` in [0, 1]; ``None``: 1 (rigid).
    preset : str or None
        The named solid (:data:`OBJECT_MATERIALS`) this ``rough`` law was made from
        (:func:`object_material`): the medium of its mirrors' coherent reflection
        (:class:`Reflection`); ``None``: none.
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
    preset: str | None = None
    area_m2: float | None = None
    reflectance: float | None = None

    def __post_init__(self) -> None:
        if self.law not in LAWS:
            raise ConfigError("law", f"unknown law {shown(self.law)}; allowed: {', '.join(LAWS)}")
        if self.preset is not None and (self.law != "rough" or self.preset not in OBJECT_MATERIALS):
            raise ConfigError("preset", f"unknown material {shown(self.preset)} for the law {shown(self.law)}; "
                                        f"allowed: {', '.join(OBJECT_MATERIALS)} (law rough)")
        used = LAW_KEYS[self.law]
        if self.sediment is not None:
            if "sediment" not in used:
                raise ConfigError("sediment", f"not used by the law {shown(self.law)}; its parameters: {', '.join(used)}")
            if not isinstance(self.sediment, str) or self.sediment not in seabed.SEDIMENT_NAMES:
                raise ConfigError("sediment", f"unknown sediment {shown(self.sediment)}; allowed: "
                                              f"{', '.join(seabed.SEDIMENT_NAMES)}")
            if self.grain_size_phi is not None:
                raise ConfigError("grain_size_phi", "give either sediment (a class) or grain_size_phi, not both")
        for key in ("albedo", "mu", "specular_strength", "roughness", "grain_size_phi", "level_db", "area_m2",
                    "reflectance"):
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
        if self.area_m2 is not None and not PLATE_AREA_RANGE_M2[0] <= self.area_m2 <= PLATE_AREA_RANGE_M2[1]:
            raise ConfigError("area_m2", f"must be a face's area within [{PLATE_AREA_RANGE_M2[0]:g}, "
                                         f"{PLATE_AREA_RANGE_M2[1]:g}] m^2, got {self.area_m2}")
        if self.reflectance is not None and not 0.0 <= self.reflectance <= 1.0:
            raise ConfigError("reflectance", f"must be |R|^2 within [0, 1], got {self.reflectance}")
        if self.law == "plate" and self.texture:
            raise ConfigError("texture", "a plate's lobe is one face's: it takes no texture")
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
        :data:`SEDIMENT`, which every tabulated law takes: :data:`TABULATED_LAWS`)."""
        return SEDIMENT if self.law in TABULATED_LAWS else LAWS.index(self.law)

    @property
    def coefficient(self) -> float:
        """The diffuse coefficient: ``albedo`` (default 0.8), ``mu``, or the sediment law's
        ``10**(level_db / 10)``; the part a texture scales."""
        if self.law == "lambert":
            return float(self.mu)
        if self.law == "sediment":
            return 10.0 ** ((self.level_db or 0.0) / 10.0)
        if self.law == "plate":  # its table holds both parts
            return 1.0
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
        if self.law not in TABULATED_LAWS:
            return None
        if frequency_hz is None:
            raise ConfigError("sonar.frequency_khz", f"the {self.law} law scatters by frequency: set the sonar's "
                                                     "frequency_khz (or sensor.frequency_khz)")
        if self.law == "plate":
            return reflection.face_lobe_table(self.area_m2, 2.0 * math.pi * float(frequency_hz) / sound_speed_m_s,
                                              self.plate_reflectance, self.albedo or 0.0)
        return seabed.law_table(self.sediment_model(sound_speed_m_s), float(frequency_hz), float(sound_speed_m_s))

    @property
    def plate_reflectance(self) -> float:
        """``plate``: the face's ``|R|^2`` (1 where not given)."""
        return 1.0 if self.reflectance is None else float(self.reflectance)

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
        if self.law == "plate":
            if frequency_hz is None:
                raise ConfigError("sonar.frequency_khz", "the plate law scatters by frequency")
            k = 2.0 * math.pi * float(frequency_hz) / sound_speed_m_s
            alpha = np.arccos(c)
            with np.errstate(divide="ignore", invalid="ignore"):
                lobe = np.where(c > 1e-12, reflection.face_cross_section(alpha, self.area_m2, k, self.plate_reflectance)
                                / (self.area_m2 * np.where(c > 1e-12, c, 1.0)), 0.0)
            return (self.albedo or 0.0) * c + lobe
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
        if self.preset is not None:  # the named solid stands for its law's parameters
            return {"preset": self.preset, **({"texture": True} if self.texture else {})}
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
    density_kg_m3 : float
        Density, kg/m^3 (``inf``: the ideal rigid reflector).
    sound_speed_m_s : float
        Longitudinal sound speed, m/s (handbook values: Kinsler et al., *Fundamentals of
        Acoustics*, 4th ed., Appendix A10; Selfridge 1985, IEEE SU-32).
    roughness : float
        Rms facet slope of a typical finish (our choice: the lobe must be wider than a few rays).
    diffuse_db : float
        The diffuse part, Lambert's ``10 log10 mu``, dB (our choice: a rough-surface floor well
        below the specular lobe).
    rms_height_m : float
        Rms height of a typical finish, metres: the coherent reflection's roughness loss of a
        mirror of it (:class:`Reflection`; our choice, order-of-magnitude values: rolled or
        painted steel and moulded plastic 0.1 mm, rubber 0.2 mm, planed wood 0.5 mm, cast
        concrete 1 mm, rough rock 5 mm).
    """

    density_kg_m3: float
    sound_speed_m_s: float
    roughness: float
    diffuse_db: float
    rms_height_m: float = 0.0

    @property
    def impedance_mrayl(self) -> float:
        """Characteristic (longitudinal) impedance ``rho c``, MRayl."""
        return self.density_kg_m3 * self.sound_speed_m_s * 1e-6

    @property
    def reflection(self) -> float:
        """The normal-incidence reflection coefficient against water, ``(Z - Z_w) / (Z + Z_w)``."""
        if math.isinf(self.density_kg_m3):
            return 1.0
        return (self.impedance_mrayl - WATER_IMPEDANCE_MRAYL) / (self.impedance_mrayl + WATER_IMPEDANCE_MRAYL)


#: Named materials of objects: ``material: {preset: steel}``. Impedances from handbook densities
#: and longitudinal speeds (steel 7850 kg/m^3 x 5900 m/s, concrete 2400 x 3500, granite 2700 x
#: 6000, PVC 1380 x 2380, neoprene rubber 1300 x 1600, oak across the grain 720 x 1500...4000 taken
#: at 2.9); ``rigid`` is the ideal reflector (R = 1) of textbook target strengths.
OBJECT_MATERIALS: dict[str, ObjectMaterial] = {
    "rigid": ObjectMaterial(math.inf, math.inf, 0.1, -60.0, 0.0),
    "steel": ObjectMaterial(7850.0, 5900.0, 0.1, -30.0, 1e-4),
    "concrete": ObjectMaterial(2400.0, 3500.0, 0.2, -20.0, 1e-3),
    "rock": ObjectMaterial(2700.0, 6000.0, 0.3, -15.0, 5e-3),
    "plastic": ObjectMaterial(1380.0, 2380.0, 0.1, -30.0, 1e-4),
    "rubber": ObjectMaterial(1300.0, 1600.0, 0.15, -40.0, 2e-4),
    "wood": ObjectMaterial(720.0, 4028.0, 0.2, -35.0, 5e-4),
}

#: Water's density, kg/m^3, for the density ratio of an object's material (the impedance above).
WATER_DENSITY_KG_M3 = 1000.0


def object_material(name: str, texture: bool = False) -> Material:
    """The ``rough`` law of a named solid (:data:`OBJECT_MATERIALS`): a Kirchhoff lobe of its
    finish's rms slope ``s`` at Kirchhoff's own scale, ``|R|^2 / (8 pi s^2)`` (``R`` its
    normal-incidence reflection coefficient), over a weak diffuse part.

    At that scale the lobe integrates, over any smooth convex surface, to the geometric-optics
    echo of its specular point: ``|R|^2 a1 a2 / 4`` for principal radii ``a1, a2`` (a sphere:
    ``TS = 10 log10(|R|^2 a^2 / 4)``), whatever ``s`` (tests/renderer/test_object_materials.py).
    A flat face seen square on gives ``|R|^2 A / (8 pi s^2)``: the incoherent facet picture, not
    a plate's coherent ``A^2 / lambda^2`` lobe (the ``plate`` law's).
    """
    if name not in OBJECT_MATERIALS:
        raise ConfigError("preset", f"unknown material {shown(name)}; allowed: {', '.join(OBJECT_MATERIALS)}")
    m = OBJECT_MATERIALS[name]
    s = m.roughness
    return Material("rough", albedo=10.0 ** (m.diffuse_db / 10.0), specular_strength=m.reflection**2 / (8 * math.pi * s * s),
                    roughness=s, texture=texture, preset=name)


# Coherent reflection of mirrors (planes and mesh mirrors) ------------------------------------

#: The boundary that is not a medium: the water surface seen from below (``V = -1``).
PRESSURE_RELEASE = "pressure-release"

#: The longest roughness wavelength a sediment's rms height counts, metres: the first Fresnel
#: zone's size, ``sqrt(lambda r)``, at a forward-looking sonar's ranges and frequencies (4 to 9
#: cm at 1 to 3 MHz, 5 to 20 m). Longer undulations tilt the mirror rather than scatter its
#: coherent reflection (our choice; ``rms_height_m`` overrides it).
SEDIMENT_PATCH_M = 0.1

#: Upper bounds of the keys of :class:`Reflection` (a sea far above hurricane force; a metre of
#: rms height removes every coherent reflection above 1 kHz).
MAX_WIND_SPEED_M_S = 50.0
MAX_RMS_HEIGHT_M = 1.0


@dataclass(frozen=True)
class Reflection:
    """A mirror's coherent reflectance by the physics: the Rayleigh coefficient of its medium
    against grazing angle times the roughness loss of its rms height at the sonar's frequency,
    ``R = |V(theta)|^2 exp(-4 k^2 h^2 sin^2(theta))`` (:mod:`sonarsim.core.reflection`), instead
    of one constant ``specular: R``.

    Attributes
    ----------
    medium : str or None
        What lies behind the boundary: a sediment class (:data:`~sonarsim.core.seabed.SEDIMENT_NAMES`,
        looked up first: ``rock`` is the sediment's), a solid (:data:`OBJECT_MATERIALS`: treated
        as a fast fluid, without shear), or ``pressure-release`` (the water surface seen from
        below, ``|V| = 1``). ``None``: the surface's own material (a ``sediment`` law, or a
        ``rough`` law made from a solid's ``preset``).
    rms_height_m : float or None
        Rms height of the boundary's roughness, metres, in [0, 1]. ``None``: the medium's own: a
        sediment's roughness spectrum over wavelengths up to :data:`SEDIMENT_PATCH_M` (medium
        sand 1.6 mm), a solid's finish (:attr:`ObjectMaterial.rms_height_m`), the sea's from
        ``wind_speed_m_s`` (0 without one).
    wind_speed_m_s : float or None
        ``pressure-release`` only: the wind speed, m/s in [0, 50], whose fully developed sea
        (Pierson-Moskowitz) gives the surface's rms height ``0.21 U^2 / (4 g)``; give it or
        ``rms_height_m``.
    """

    medium: str | None = None
    rms_height_m: float | None = None
    wind_speed_m_s: float | None = None

    def __post_init__(self) -> None:
        if self.medium is not None:
            known = (*seabed.SEDIMENT_NAMES, *OBJECT_MATERIALS, PRESSURE_RELEASE)
            if not isinstance(self.medium, str) or self.medium not in known:
                raise ConfigError("medium", f"unknown medium {shown(self.medium)}; allowed: {', '.join(known)}")
        for key, top in (("rms_height_m", MAX_RMS_HEIGHT_M), ("wind_speed_m_s", MAX_WIND_SPEED_M_S)):
            value = getattr(self, key)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= top:
                raise ConfigError(key, f"must be a number within [0, {top:g}], got {shown(value)}")
            object.__setattr__(self, key, float(value))
        if self.wind_speed_m_s is not None:
            if self.medium != PRESSURE_RELEASE:
                raise ConfigError("wind_speed_m_s", f"only for the water surface (medium: {PRESSURE_RELEASE})")
            if self.rms_height_m is not None:
                raise ConfigError("wind_speed_m_s", "give either wind_speed_m_s or rms_height_m, not both")

    def check_material(self, material: "Material | None") -> None:
        """Refuse a reflection without a medium on a surface whose material names none.

        Raises
        ------
        ConfigError
            ``medium``, with what is allowed.
        """
        if self.medium is None and not (material is not None and (material.law == "sediment" or material.preset)):
            raise ConfigError("medium", f"required where the surface's material is neither a sediment nor a named "
                                        f"solid (a sediment class, one of {', '.join(OBJECT_MATERIALS)}, or "
                                        f"{PRESSURE_RELEASE})")

    def _medium(self, material: "Material | None", sound_speed_m_s: float):
        """``(density ratio or None, sound-speed ratio, loss parameter, default rms height m)``."""
        self.check_material(material)
        if self.medium == PRESSURE_RELEASE:
            h = 0.0 if self.wind_speed_m_s is None else reflection.wind_sea_rms_height_m(self.wind_speed_m_s)
            return None, 1.0, 0.0, h
        if self.medium is None and material.law == "sediment":
            sed = material.sediment_model(sound_speed_m_s)
        elif self.medium in seabed.SEDIMENT_NAMES:
            sed = seabed.sediment(self.medium, sound_speed_m_s)
        else:
            solid = OBJECT_MATERIALS[self.medium or material.preset]
            return (solid.density_kg_m3 / WATER_DENSITY_KG_M3, solid.sound_speed_m_s / sound_speed_m_s, 0.0,
                    solid.rms_height_m)
        return (sed.density_ratio, sed.sound_speed_ratio, sed.loss_parameter,
                seabed.rms_height_m(sed, SEDIMENT_PATCH_M))

    def table(self, material: "Material | None", sound_speed_m_s: float = 1500.0) -> np.ndarray:
        """``|V|^2`` against ``c = sin(grazing)`` (:func:`sonarsim.core.reflection.reflectance_table`)."""
        rho, nu, delta, _ = self._medium(material, sound_speed_m_s)
        return reflection.reflectance_table(rho, nu, delta)

    def exponent(self, material: "Material | None", frequency_hz: float | None,
                 sound_speed_m_s: float = 1500.0) -> float:
        """The roughness loss's ``q = 4 k^2 h^2`` (``exp(-q sin^2 theta)``), at ``frequency_hz``.

        Raises
        ------
        ConfigError
            ``sonar.frequency_khz`` when the boundary is rough and no frequency is given.
        """
        h = self.rms_height(material, sound_speed_m_s)
        if h == 0.0:
            return 0.0
        if frequency_hz is None:
            raise ConfigError("sonar.frequency_khz", "a rough mirror's coherent reflection depends on frequency: set "
                                                     "the sonar's frequency_khz (or sensor.frequency_khz)")
        k = 2.0 * math.pi * float(frequency_hz) / sound_speed_m_s
        return 4.0 * (k * h) ** 2

    def rms_height(self, material: "Material | None", sound_speed_m_s: float = 1500.0) -> float:
        """The rms height used, metres (``rms_height_m`` or the medium's own)."""
        return self.rms_height_m if self.rms_height_m is not None else self._medium(material, sound_speed_m_s)[3]

    def evaluate(self, cos_incidence, material: "Material | None", frequency_hz: float | None,
                 sound_speed_m_s: float = 1500.0) -> np.ndarray:
        """The reflectance at ``|cos(incidence)|`` = ``sin(grazing)`` from the formulas (the
        reference the kernels' tables are tested against).

        Parameters
        ----------
        cos_incidence : (...) float array, in [0, 1]
        material : Material or None
            The surface's own (for ``medium: None``).
        frequency_hz, sound_speed_m_s : float

        Returns
        -------
        (...) float64 ndarray, in [0, 1].
        """
        rho, nu, delta, _ = self._medium(material, sound_speed_m_s)
        grazing = np.arcsin(np.clip(np.asarray(cos_incidence, dtype=np.float64), 0.0, 1.0))
        v2 = np.ones_like(grazing) if rho is None or math.isinf(rho) else np.abs(
            reflection.rayleigh_fluid(grazing, rho, nu, delta)) ** 2
        q = self.exponent(material, frequency_hz, sound_speed_m_s)
        return v2 * np.exp(-q * np.sin(grazing) ** 2)

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("medium", "rms_height_m", "wind_speed_m_s") if getattr(self, k) is not None}
