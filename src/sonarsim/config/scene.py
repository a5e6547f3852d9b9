"""Scene description: objects, the ground plane, render settings and the sonar (its intrinsics
and its pose).

These frozen dataclasses are what the rest of sonarsim trusts. They check their own values on
construction (so Python callers get the same messages as scene files); :mod:`sonarsim.config.loader`
turns YAML/JSON/dicts into them and rejects unknown keys and wrong types.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, shown
from .materials import Material, Reflection
# Objects larger than MAX_LENGTH_M are not objects of a sonar scene (a typo or a unit mistake),
# nor smaller than MIN_LENGTH_M (a micron; also the smallest scale factor: a sphere of 1e-300 m
# was accepted and, its vertices all equal in float32, silently invisible); a sonar scene spans
# kilometres at most. From the one table of fittable parameters.
from .parameters import MAX_COORDINATE_M, MAX_LENGTH_M, MIN_LENGTH_M  # noqa: F401
from .sensor import SensorSpec, check_azimuth_width, check_bandwidth
from .sonar import SonarConfig
from .tracks import Track
from .water import WaterSpec, fold_into_sensor
from ..core.rays import check_ray_budget
from ..core.transforms import Pose

PRIMITIVES = ("box", "sphere", "cylinder")
METHODS = ("fast", "paper")
BEAM_PATTERNS = ("uniform", "gaussian")
DOUBLE_BEAMS = ("coherent", "paper", "split", "separate")
MIRROR_NORMALS = ("flat", "smooth")
# Plane names become parts of component names (``O-surface-[objects]-O``): keep them plain.
PLANE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
RESERVED_PLANE_NAMES = ("objects", "O")
# The ground's name: the plane a scene file's ``ground:`` section stands for.
GROUND = "ground"
TEXTURE_COVARIANCES = ("gaussian", "exponential")
# A reflectivity texture's spread: beyond 20 dB the log-normal's mean is carried by rare bright
# spots that no frame samples (at 20 dB the median factor is 3e-5 of the mean).
MAX_TEXTURE_STD_DB = 20.0
# Correlation lengths of a sea-floor texture: from a centimetre (below, it is speckle, not
# texture) to ten kilometres (beyond, one frame sees a uniform floor).
MIN_CORRELATION_M, MAX_CORRELATION_M = 1e-2, 1e4
# Path orders beyond this cost more than they show (R**order of an echo that is already faint).
MAX_ORDER_LIMIT = 9
# Ray-casting threads a scene may ask for: more than the cores of large machines only costs
# threads' memory and start-up (1,000,000 was accepted and handed to Embree); ``null`` takes
# every core of any machine.
MAX_THREADS = 256


def _check_unit_interval(key: str, value: float) -> None:
    if not (np.isfinite(value) and 0.0 <= value <= 1.0):
        raise ConfigError(key, f"must be within [0, 1], got {value}")


def _check_material(spec, prefix: str = "", texture_allowed: bool = False) -> None:
    """``material`` is a Material, given instead of a non-default ``albedo`` (its shorthand)."""
    material = spec.material
    if material is None:
        return
    if not isinstance(material, Material):
        raise ConfigError(f"{prefix}material", f"must be a Material, got {type(material).__name__}")
    if spec.albedo != type(spec).__dataclass_fields__["albedo"].default:
        raise ConfigError(f"{prefix}albedo", "give either albedo (the Lambertian shorthand) or material, not both")
    if material.texture and not texture_allowed:
        raise ConfigError(f"{prefix}material.texture", "only objects (with a textured mesh) have a texture")
    if material.law == "plate" and not texture_allowed:  # (planes: texture_allowed is False)
        raise ConfigError(f"{prefix}material.law", "a plate is an object's flat face of a given area, not an "
                                                   "infinite plane: give the plane another law")


def _resolve_reflection(spec, mirror_by_default: float) -> None:
    """``specular`` and ``reflection`` (an object's or a plane's): ``specular`` None is the
    constant ``mirror_by_default`` without a reflection, and 1 (the reflection's scale) with
    one; a plane or ground of the ``sediment`` law reflects by its sediment's physics unless a
    constant ``specular`` is given. Both given: refused."""
    if spec.reflection is not None and not isinstance(spec.reflection, Reflection):
        raise ConfigError("reflection", f"must be a Reflection, got {type(spec.reflection).__name__}")
    if spec.specular is not None and spec.reflection is not None:
        raise ConfigError("reflection", "give either specular (one constant R) or reflection (R by the Rayleigh "
                                        "coefficient and roughness), not both")
    if spec.specular is None and spec.reflection is None and mirror_by_default > 0 and spec.material is not None \
            and spec.material.law == "sediment":
        object.__setattr__(spec, "reflection", Reflection())
    if spec.reflection is not None:
        try:
            spec.reflection.check_material(spec.material)
        except ConfigError as exc:
            raise ConfigError(f"reflection.{exc.key}", exc.detail) from None
        object.__setattr__(spec, "specular", 1.0)
    elif spec.specular is None:
        object.__setattr__(spec, "specular", float(mirror_by_default))


@dataclass(frozen=True)
class TextureSpec:
    """A plane's reflectivity texture: a world-anchored, log-normal random field.

    The plane's backscatter is multiplied, at each point where a path scatters off it, by
    ``F = 10 ** (std_db * g / 10) / E``: ``g`` a stationary Gaussian field of zero mean and unit
    variance over the plane, ``E`` the normalisation that makes the mean of ``F`` exactly 1 (the
    floor's expected level is that of the untextured plane). See
    :mod:`sonarsim.scene.floor_texture`.

    Attributes
    ----------
    std_db : float
        Standard deviation of the reflectivity in dB (of ``10 log10 F``), within [0, 20]; 0 is
        the untextured plane.
    correlation_m : (2,) tuple of float
        Correlation lengths of ``g`` along the field's two axes, metres, each within
        [0.01, 1e4]: the lag at which the correlation of ``g`` falls to ``1/e``.
    angle_deg : float
        Direction of the first axis, degrees, counter-clockwise from the plane's first axis
        (for the ground: the world x axis, towards y), within [-360, 360].
    seed : int or None
        Seed of the field (non-negative); ``None``: derived from ``render.seed`` and the plane's
        index, so two textured planes differ.
    covariance : {'gaussian', 'exponential'}
        Correlation of ``g`` at lag ``h`` (metres along the axes):
        ``exp(-|h / l|**2)`` (smooth patches) or ``exp(-|h / l|)`` (rough, patchy at every
        scale), with ``|h / l| = hypot(h_1 / l_1, h_2 / l_2)``.
    """

    std_db: float = 0.0
    correlation_m: tuple[float, float] = (1.0, 1.0)
    angle_deg: float = 0.0
    seed: int | None = None
    covariance: str = "gaussian"

    def __post_init__(self) -> None:
        v = self.std_db
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (
                math.isfinite(v) and 0.0 <= v <= MAX_TEXTURE_STD_DB):
            raise ConfigError("texture.std_db", f"must be a number of dB within [0, {MAX_TEXTURE_STD_DB:g}] (beyond, "
                              f"the mean is carried by rare bright spots), got {shown(v)}")
        object.__setattr__(self, "std_db", float(v))
        c = self.correlation_m
        if isinstance(c, (int, float)) and not isinstance(c, bool):
            c = (c, c)  # one length: isotropic
        try:
            lengths = tuple(float(x) for x in c)
        except (TypeError, ValueError):
            lengths = ()
        if len(lengths) != 2 or not all(math.isfinite(x) and MIN_CORRELATION_M <= x <= MAX_CORRELATION_M for x in lengths):
            raise ConfigError("texture.correlation_m", f"must be one or two lengths within [{MIN_CORRELATION_M:g}, "
                              f"{MAX_CORRELATION_M:g}] metres, got {shown(self.correlation_m)}")
        object.__setattr__(self, "correlation_m", lengths)
        a = self.angle_deg
        if isinstance(a, bool) or not isinstance(a, (int, float, np.floating, np.integer)) or not (
                math.isfinite(a) and abs(a) <= 360.0):
            raise ConfigError("texture.angle_deg", f"must be an angle within [-360, 360] degrees, got {shown(a)}")
        object.__setattr__(self, "angle_deg", float(a))
        s = self.seed
        if s is not None and (isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 0):
            raise ConfigError("texture.seed", f"must be a non-negative integer or null, got {shown(s)}")
        if self.covariance not in TEXTURE_COVARIANCES:
            raise ConfigError("texture.covariance", f"unknown covariance {shown(self.covariance)}; allowed: "
                              f"{', '.join(TEXTURE_COVARIANCES)}")

    @property
    def active(self) -> bool:
        """Whether the texture changes anything (``std_db > 0``)."""
        return self.std_db > 0.0

    def to_dict(self) -> dict:
        out: dict = {"std_db": self.std_db, "correlation_m": list(self.correlation_m), "angle_deg": self.angle_deg}
        if self.seed is not None:
            out["seed"] = int(self.seed)
        out["covariance"] = self.covariance
        return out


def _check_texture(texture, prefix: str) -> None:
    if texture is not None and not isinstance(texture, TextureSpec):
        raise ConfigError(f"{prefix}texture", f"must be a TextureSpec, got {type(texture).__name__}")


@dataclass(frozen=True)
class ObjectSpec:
    """One object of the scene: a primitive or a mesh, with pose, scale and albedo.

    Attributes
    ----------
    name : str
        Label, unique in the scene, and neither ``ground`` nor the name of one of its planes
        (checked by :class:`Scene`: objects and planes share the label ids).
    primitive : {'box', 'sphere', 'cylinder'} or None
        Shape, centred on the object's origin (a cylinder's axis is its z axis).
    size_m : (3,) tuple of float or None
        Box edge lengths along its x, y, z axes, each within [1e-6, 1e4] metres.
    radius_m, height_m : float or None
        Sphere/cylinder radius and cylinder height, within [1e-6, 1e4] metres.
    mesh : str, pathlib.Path or trimesh.Trimesh or None
        A mesh file (anything trimesh loads) or an in-memory mesh, in object coordinates.
    pose : Pose
        Object-to-world pose.
    scale : float or (3,) tuple of float
        Scale applied in object coordinates before the pose, within [1e-6, 1e4].
    albedo : float
        Diffuse albedo rho in [0, 1] (paper: concrete 0.8, smooth plastic 0.4): shorthand for
        the Lambertian ``material``, used when ``material`` is None.
    material : Material or None
        The backscatter law (:mod:`sonarsim.config.materials`); give it or ``albedo``, not both.
    specular : float
        Specular reflectance R in [0, 1]: a ray meeting the object also reflects off it, as off
        a plane, with R times its weight (:mod:`sonarsim.paths.facets`); 0 (the default): the
        object only scatters. With ``reflection``: 1 (the reflectance is the reflection's).
    normals : {'flat', 'smooth'}
        What a specular object reflects about: each triangle's own normal, or the normal
        interpolated across it from its corners (a smooth mesh of a curved surface).
    reflection : Reflection or None
        The object mirrors with the reflectance of its medium's Rayleigh coefficient against
        grazing angle and its roughness loss (:class:`~sonarsim.config.materials.Reflection`;
        the medium by default its material's ``preset``), instead of a constant ``specular``.
    track : Track or None
        The object's own path (:class:`~sonarsim.config.tracks.Track`): its pose at each
        frame's time, moved without rebuilding the scene (:meth:`Simulator.at_time
        <sonarsim.renderer.simulator.Simulator.at_time>`); ``pose`` is then its pose at time 0.
    """

    name: str
    primitive: str | None = None
    size_m: tuple[float, float, float] | None = None
    radius_m: float | None = None
    height_m: float | None = None
    mesh: Any = None
    pose: Pose = field(default_factory=Pose)
    scale: float | tuple[float, float, float] = 1.0
    albedo: float = 0.8
    material: Material | None = None
    specular: float | None = None
    normals: str = "flat"
    reflection: Reflection | None = None
    track: Track | None = None

    def __post_init__(self) -> None:
        if self.track is not None and not isinstance(self.track, Track):
            raise ConfigError("track", f"must be a Track, got {type(self.track).__name__}")
        if (self.primitive is None) == (self.mesh is None):
            raise ConfigError("primitive", "give exactly one of `primitive` or `mesh`")
        if self.primitive is not None:
            if self.primitive not in PRIMITIVES:
                raise ConfigError(
                    "primitive", f"unknown primitive {shown(self.primitive)}; allowed: {', '.join(PRIMITIVES)}"
                )
            needed = {"box": ("size_m",), "sphere": ("radius_m",), "cylinder": ("radius_m", "height_m")}
            for key in needed[self.primitive]:
                if getattr(self, key) is None:
                    raise ConfigError(key, f"required for a {self.primitive}")
            for key in ("size_m", "radius_m", "height_m"):
                if key not in needed[self.primitive] and getattr(self, key) is not None:
                    raise ConfigError(key, f"not used by a {self.primitive}; allowed: {', '.join(needed[self.primitive])}")
            if self.size_m is not None:
                size = tuple(float(v) for v in self.size_m)
                if len(size) != 3 or not all(np.isfinite(v) and MIN_LENGTH_M <= v <= MAX_LENGTH_M for v in size):
                    raise ConfigError("size_m", f"must be three lengths within [{MIN_LENGTH_M:g}, {MAX_LENGTH_M:g}] "
                                      f"metres, got {self.size_m}")
                object.__setattr__(self, "size_m", size)
            for key in ("radius_m", "height_m"):
                v = getattr(self, key)
                if v is not None and not (np.isfinite(v) and MIN_LENGTH_M <= v <= MAX_LENGTH_M):
                    raise ConfigError(key, f"must be a length within [{MIN_LENGTH_M:g}, {MAX_LENGTH_M:g}] metres, got {v}")
        scale = np.atleast_1d(np.asarray(self.scale, dtype=float))
        if scale.size not in (1, 3) or not np.all(np.isfinite(scale) & (scale >= MIN_LENGTH_M) & (scale <= MAX_LENGTH_M)):
            raise ConfigError("scale", f"must be a number or three numbers within [{MIN_LENGTH_M:g}, {MAX_LENGTH_M:g}], "
                              f"got {self.scale}")
        _check_unit_interval("albedo", self.albedo)
        if self.specular is not None:
            _check_unit_interval("specular", self.specular)
        _resolve_reflection(self, 0.0)
        if self.specular > 0 and (not PLANE_NAME.match(str(self.name)) or self.name in RESERVED_PLANE_NAMES):
            # A mirror's name is part of the path names (``O-pipe-[ground]-O``), as a plane's is.
            raise ConfigError("name", f"a specular object's name must be a letter followed by letters, digits or "
                              f"underscores, and neither of {', '.join(RESERVED_PLANE_NAMES)}; got {shown(self.name)}")
        if self.normals not in MIRROR_NORMALS:
            raise ConfigError("normals", f"unknown normals {shown(self.normals)}; allowed: {', '.join(MIRROR_NORMALS)}")
        _check_material(self, texture_allowed=True)
        if self.material is not None and self.material.texture and self.primitive is not None:
            raise ConfigError("material.texture", "a primitive has no texture; give a `mesh` with one")

    @property
    def backscatter(self) -> Material:
        """The backscatter law: ``material``, or the Lambertian law of ``albedo``."""
        return self.material if self.material is not None else Material.lambertian(self.albedo)

    def to_dict(self) -> dict:
        out: dict = {"name": self.name}
        if self.primitive is not None:
            out["primitive"] = self.primitive
            for key in ("size_m", "radius_m", "height_m"):
                v = getattr(self, key)
                if v is not None:
                    out[key] = list(v) if isinstance(v, tuple) else v
        elif isinstance(self.mesh, (str, Path)):
            out["mesh"] = str(self.mesh)
        else:
            out["mesh"] = "<in-memory mesh>"
        if self.track is None or self.track.trajectory is None:  # timed poses give the pose themselves
            out["pose"] = self.pose.to_dict()
        out["scale"] = list(self.scale) if isinstance(self.scale, tuple) else self.scale
        if self.material is None:
            out["albedo"] = self.albedo
        else:
            out["material"] = self.material.to_dict()
        if self.reflection is not None:
            out["reflection"] = self.reflection.to_dict()
        elif self.specular:
            out["specular"] = self.specular
        if self.normals != "flat":
            out["normals"] = self.normals
        if self.track is not None:
            out["track"] = self.track.to_dict()
        return out


@dataclass(frozen=True)
class PlaneSpec:
    """An infinite reflecting plane: a floor, the water surface, a tank wall.

    Attributes
    ----------
    name : str
        Label, unique among the scene's planes (letters, digits, ``_``; it becomes part of the
        path component names, e.g. ``O-surface-[objects]-O``). ``ground`` is the name of the
        plane that the ``ground:`` section stands for.
    point_m : (3,) tuple of float
        Any point of the plane in the world frame, metres.
    normal : (3,) tuple of float
        Normal pointing into the water (normalised on construction; the water is the side it
        points to). A horizontal floor has ``[0, 0, 1]``, the water surface ``[0, 0, -1]``.
    albedo : float
        Diffuse albedo in [0, 1]: the plane's own direct echo (0 for the water surface);
        shorthand for the Lambertian ``material``, used when ``material`` is None.
    specular : float or None
        Specular reflectance R in [0, 1]: each reflection off the plane scales a path by R.
        ``None`` (the default): 1, or where the material is the ``sediment`` law its
        ``reflection`` by the physics; 1 with a ``reflection`` (its scale).
    material : Material or None
        The backscatter law of the plane's direct echo; give it or ``albedo``, not both.
    texture : TextureSpec or None
        A world-anchored reflectivity texture over the plane (its axes:
        :func:`sonarsim.scene.floor_texture.plane_axes`); ``None``: uniform.
    reflection : Reflection or None
        The plane reflects by the Rayleigh coefficient of its medium against grazing angle and
        the roughness loss of its rms height at the sonar's frequency
        (:class:`~sonarsim.config.materials.Reflection`; the water surface: ``medium:
        pressure-release`` with a wind speed), instead of a constant ``specular``.
    """

    name: str
    point_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    albedo: float = 0.0
    specular: float | None = None
    material: Material | None = None
    texture: TextureSpec | None = None
    reflection: Reflection | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not PLANE_NAME.fullmatch(self.name) or self.name in RESERVED_PLANE_NAMES:
            raise ConfigError(
                "name",
                f"must start with a letter and hold only letters, digits and _ (not "
                f"{' or '.join(RESERVED_PLANE_NAMES)}), got {shown(self.name)}",
            )
        point = np.asarray(self.point_m, dtype=float).ravel()
        if point.size != 3 or not np.all(np.isfinite(point)):
            raise ConfigError("point_m", f"must be three finite coordinates in metres, got {self.point_m}")
        if np.abs(point).max() > MAX_COORDINATE_M:
            raise ConfigError("point_m", f"must lie within 1e6 m of the origin, got {self.point_m}")
        normal = np.asarray(self.normal, dtype=float).ravel()
        if normal.size != 3 or not np.all(np.isfinite(normal)):
            raise ConfigError("normal", f"must be three finite numbers, got {self.normal}")
        # hypot, not the root of the sum of squares: those of [1, 1e300, 0] overflow, and the
        # normal divided by an infinite length was the zero vector.
        length = math.hypot(*normal)
        if not length > 1e-9 * max(1.0, float(np.abs(normal).max())):
            raise ConfigError("normal", f"must not be the zero vector, got {self.normal}")
        object.__setattr__(self, "point_m", tuple(float(v) for v in point))
        object.__setattr__(self, "normal", tuple(float(v) for v in normal / length))
        _check_unit_interval("albedo", self.albedo)
        if self.specular is not None:
            _check_unit_interval("specular", self.specular)
        _check_material(self)
        _resolve_reflection(self, 1.0)
        _check_texture(self.texture, "")

    @property
    def backscatter(self) -> Material:
        """The backscatter law: ``material``, or the Lambertian law of ``albedo``."""
        return self.material if self.material is not None else Material.lambertian(self.albedo)

    @property
    def height_m(self) -> float:
        """The height of a horizontal plane (the ground's ``height_m``), metres.

        Raises
        ------
        AttributeError
            The plane is not horizontal (it has no one height).
        """
        if self.normal[0] != 0.0 or self.normal[1] != 0.0:
            raise AttributeError(f"plane {self.name!r} is not horizontal: it has no height_m (see offset_m)")
        return self.point_m[2]

    @property
    def offset_m(self) -> float:
        """``n . p``: the plane is ``n . x = offset_m``; the water is ``n . x > offset_m``."""
        return float(np.dot(self.normal, self.point_m))

    def signed_distance_m(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of points from the plane, positive in the water, metres.

        Parameters
        ----------
        points : (..., 3) float array, metres

        Returns
        -------
        (...) float64 ndarray
        """
        return np.asarray(points, dtype=float) @ np.asarray(self.normal) - self.offset_m

    def to_dict(self) -> dict:
        out = {"name": self.name, "point_m": list(self.point_m), "normal": list(self.normal)}
        if self.material is None:
            out["albedo"] = self.albedo
        else:
            out["material"] = self.material.to_dict()
        if self.reflection is not None:
            out["reflection"] = self.reflection.to_dict()
        else:
            out["specular"] = self.specular
        if self.texture is not None:
            out["texture"] = self.texture.to_dict()
        return out


#: The ground's albedo where none is given (the plane's own default, 0, is the water surface's).
GROUND_ALBEDO = 0.8


def ground_plane(height_m: float = 0.0, albedo: float | None = None, specular: float | None = None,
                 material: Material | None = None, texture: TextureSpec | None = None,
                 reflection: Reflection | None = None) -> PlaneSpec:
    """The ground: the horizontal plane ``z = height_m`` (normal +z) named ``ground``, what a
    scene file's ``ground:`` section stands for.

    Parameters
    ----------
    height_m : float
        Height of the plane in the world frame, metres.
    albedo : float, optional
        Diffuse albedo in [0, 1] of the direct ground echo (the Lambertian shorthand of
        ``material``); default 0.8 without a ``material``.
    specular : float, optional
        Specular reflectance R in [0, 1] that drives the multipath; default 1, or the
        sediment's physics (``reflection``) where ``material`` is the ``sediment`` law.
    material : Material, optional
        The backscatter law of the direct ground echo; give it or ``albedo``, not both.
    texture : TextureSpec, optional
        A world-anchored reflectivity texture; ``None``: uniform.
    reflection : Reflection, optional
        The specular reflectance by the physics (:class:`PlaneSpec`), instead of ``specular``.

    Returns
    -------
    PlaneSpec
        Errors name the ``ground.`` keys.
    """
    try:
        height = float(height_m)
    except (TypeError, ValueError):
        raise ConfigError("ground.height_m", f"must be a finite number, got {shown(height_m)}") from None
    if not np.isfinite(height):
        raise ConfigError("ground.height_m", f"must be a finite number, got {height_m}")
    if abs(height) > MAX_COORDINATE_M:
        raise ConfigError("ground.height_m", f"must lie within 1e6 m of the origin, got {height_m}")
    if albedo is None:
        albedo = GROUND_ALBEDO if material is None else PlaneSpec.__dataclass_fields__["albedo"].default
    try:
        return PlaneSpec(GROUND, (0.0, 0.0, height), (0.0, 0.0, 1.0), albedo, specular, material, texture, reflection)
    except ConfigError as exc:
        raise ConfigError(f"ground.{exc.key}", exc.detail) from None


#: Earlier name of :func:`ground_plane` (it was a class of its own; the ground is now a
#: :class:`PlaneSpec` named ``ground``): ``GroundSpec(height_m=..., albedo=...)`` still works.
GroundSpec = ground_plane


def is_ground(plane: PlaneSpec) -> bool:
    """Whether ``plane`` is a ground: the horizontal plane named ``ground``, normal +z."""
    return isinstance(plane, PlaneSpec) and plane.name == GROUND and plane.normal == (0.0, 0.0, 1.0)


def ground_section(plane: PlaneSpec) -> dict:
    """The ``ground:`` section of a scene file that stands for ``plane`` (:func:`is_ground`)."""
    out: dict = {"height_m": plane.point_m[2]}
    if plane.material is not None:
        out.update(material=plane.material.to_dict())
    else:
        out.update(albedo=plane.albedo)
    if plane.reflection is not None:
        out["reflection"] = plane.reflection.to_dict()
    else:
        out["specular"] = plane.specular
    if plane.texture is not None:
        out["texture"] = plane.texture.to_dict()
    return out


@dataclass(frozen=True)
class RenderSettings:
    """How to sample and form the image.

    Attributes
    ----------
    elevation_samples : int or 'auto'
        Rays per beam across the elevation aperture. ``'auto'``: enough that neighbouring rays
        are at most about two range bins apart across the aperture at the far range (see
        :func:`sonarsim.core.rays.auto_elevation_samples`).
    azimuth_samples : int
        Rays per beam across its azimuth width (1: along the beam centre only).
    tvg : bool
        Time-variant gain: ``l(r) = 1``; ``False`` gives ``l(r) = 1/r**2`` (paper Eq. 5).
    max_order : int
        Longest path formed, in surface interactions: 1 single (O-A-O), 2 double, 3 triple
        (the paper's three), 4 and more over any sequence of the scene's planes.
    bounces : tuple of int or None
        Which orders make the total image (1 single, 2 double, 3 triple, ...); all orders are
        formed anyway, as components. ``None``: every order up to ``max_order``.
    method : {'fast', 'paper'}
        Ground-echo implementation (see :mod:`sonarsim.reference.algorithm2`).
    beam_pattern : {'uniform', 'gaussian'}
        beta(theta, phi): uniform (paper Eq. 4), or Gaussian falling to -3 dB at the edges of the
        elevation aperture and of each beam's azimuth width.
    range_splat : bool
        Spread the energy between neighbouring rays on one surface over the range interval they
        span (no stripes on grazing surfaces). ``False`` is the paper's Algorithm 1: each ray
        deposits at its own range.
    double_beam : {'coherent', 'paper', 'split', 'separate'} or None
        Paths whose two legs meet different planes come in reciprocal pairs (O-G-A-O and
        O-A-G-O, the paper's cases 2 and 3), of equal length, arriving from different
        directions. ``None`` (the default): ``'coherent'``, or ``'paper'`` with ``method:
        paper``. ``'coherent'``: every path of the pair is formed from its own receive ray, in
        the beam it arrives from, and where both arrive in one beam each carries twice its
        energy: of one length, they arrive in phase, their amplitudes add and the pair returns
        ``|a + a|^2 = 4 |a|^2``, four times one path's intensity (in two beams, each beam sees
        one path: 1x each). They stop adding coherently where their phases part: a rough
        mirror (the two paths meet it at different points: its roughness's phases differ) or a
        sonar that moves while the sound travels (the pair's lengths differ by about
        ``v t (cos b1 - cos b2)`` for speed ``v``, travel time ``t`` and the legs' angles to
        the motion; once that exceeds a quarter wavelength, ``separate``'s 2x is the better
        model). ``'paper'``: each pair is recorded once, in the beam of the leg with more
        reflections (ties: the leg whose planes, from the sonar outwards, come later in scene
        order, compared plane by plane), as Algorithm 2 records cases 2/3 in
        the beam of A'. ``'split'``: the same, half the energy in that beam and half in the beam
        the other leg leaves the sonar in. ``'separate'``: every path of the pair is formed from
        its own receive ray, in the beam it arrives from (two independent paths: the pair then
        carries twice the paper's energy).
    double_line_of_sight : bool
        Also require every transmit leg that is not the receive leg reversed to be unoccluded
        by objects (the paper only requires A to lie in the field of view and range window).
    speckle : bool
        Multiply the total image by fully developed speckle: independent, unit-mean exponential
        factors per pixel (the intensity statistics of many random scatterers per resolution
        cell). The components stay noise-free, as ground truth.
    seed : int
        Seed of the speckle: a :class:`~sonarsim.Simulator` draws frame after frame from one
        generator seeded with it, so a sequence of renders is reproducible.
    threads : int or None
        Ray-casting threads, 1 to ``MAX_THREADS`` (256); ``None``: all CPU cores, however many.
    glints : bool
        Also form the specular returns: sound that reflects off mirrors (planes or specular
        objects) and comes back to the sonar without scattering -- a corner reflector's
        retro-reflection, a wall met square on. Each of the fan's rays that returns, after one
        to ``max_order`` reflections, within ``glint_radius_m`` of the sonar carries
        ``R ... R w / (pi glint_radius_m**2)`` (w the ray's weight, the disc's area below it;
        :mod:`sonarsim.paths.engine`).
        Off by default (the paper's model has none).
    glint_radius_m : float
        Radius of the receiving disc of the specular returns, metres, in (0, 1]: about the
        array's half-length; it must exceed the spacing of the returning rays (range times
        the ray spacing in radians), or the returns are undersampled.
    """

    elevation_samples: int | str = "auto"
    azimuth_samples: int = 1
    tvg: bool = True
    max_order: int = 3
    bounces: tuple[int, ...] | None = None
    method: str = "fast"
    beam_pattern: str = "uniform"
    range_splat: bool = True
    double_beam: str | None = None
    double_line_of_sight: bool = False
    speckle: bool = False
    seed: int = 0
    threads: int | None = None
    glints: bool = False
    glint_radius_m: float = 0.05

    def __post_init__(self) -> None:
        es = self.elevation_samples
        if es != "auto" and (isinstance(es, bool) or not isinstance(es, (int, np.integer)) or es < 1):
            raise ConfigError("render.elevation_samples", f"must be 'auto' or a positive integer, got {shown(es)}")
        az = self.azimuth_samples
        if isinstance(az, bool) or not isinstance(az, (int, np.integer)) or az < 1:
            raise ConfigError("render.azimuth_samples", f"must be a positive integer, got {shown(az)}")
        mo = self.max_order
        if isinstance(mo, bool) or not isinstance(mo, (int, np.integer)) or not 1 <= mo <= MAX_ORDER_LIMIT:
            raise ConfigError("render.max_order", f"must be an integer from 1 to {MAX_ORDER_LIMIT}, got {shown(mo)}")
        object.__setattr__(self, "max_order", int(mo))
        orders = list(range(1, int(mo) + 1))
        bounces = tuple(orders) if self.bounces is None else tuple(sorted(set(int(b) for b in self.bounces)))
        if not bounces or any(b not in orders for b in bounces):
            raise ConfigError(
                "render.bounces",
                f"must be a non-empty subset of the orders up to render.max_order, {orders}, got {shown(list(self.bounces))}",
            )
        object.__setattr__(self, "bounces", bounces)
        if self.method not in METHODS:
            raise ConfigError("render.method", f"unknown method {shown(self.method)}; allowed: {', '.join(METHODS)}")
        if self.beam_pattern not in BEAM_PATTERNS:
            raise ConfigError(
                "render.beam_pattern", f"unknown pattern {shown(self.beam_pattern)}; allowed: {', '.join(BEAM_PATTERNS)}"
            )
        if self.double_beam is None:
            object.__setattr__(self, "double_beam", "paper" if self.method == "paper" else "coherent")
        if self.double_beam not in DOUBLE_BEAMS:
            raise ConfigError(
                "render.double_beam", f"unknown choice {shown(self.double_beam)}; allowed: {', '.join(DOUBLE_BEAMS)}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ConfigError("render.seed", f"must be a non-negative integer, got {shown(self.seed)}")
        th = self.threads
        if th is not None and (isinstance(th, bool) or not isinstance(th, (int, np.integer)) or not 1 <= th <= MAX_THREADS):
            raise ConfigError("render.threads", f"must be an integer from 1 to {MAX_THREADS} or null (all cores), "
                              f"got {shown(th)}")
        if not isinstance(self.glints, (bool, np.bool_)):
            raise ConfigError("render.glints", f"must be true or false, got {shown(self.glints)}")
        gr = self.glint_radius_m
        if isinstance(gr, bool) or not isinstance(gr, (int, float, np.number)) or not (np.isfinite(gr) and 0 < gr <= 1):
            raise ConfigError("render.glint_radius_m", f"must be a length in (0, 1] metres, got {shown(gr)}")

    def to_dict(self) -> dict:
        out = {
            "elevation_samples": self.elevation_samples if self.elevation_samples == "auto" else int(self.elevation_samples),
            "azimuth_samples": int(self.azimuth_samples),
            "tvg": self.tvg,
            "max_order": self.max_order,
            "bounces": list(self.bounces),
            "method": self.method,
            "beam_pattern": self.beam_pattern,
            "range_splat": self.range_splat,
            "double_beam": self.double_beam,
            "double_line_of_sight": self.double_line_of_sight,
            "speckle": self.speckle,
            "seed": int(self.seed),
            "threads": self.threads,
        }
        if self.glints:  # (written only when on: the scene files before them stay as they were)
            out.update(glints=True, glint_radius_m=float(self.glint_radius_m))
        return out


@dataclass(frozen=True)
class Scene:
    """Everything needed to render: sonar and its pose, objects, optional ground, render settings.

    Attributes
    ----------
    sonar : SonarConfig
        The sonar's intrinsics (beams, elevation aperture, range window).
    sonar_pose : Pose
        The sonar's pose in the world frame (sonar-to-world; the sonar frame is x forward,
        y left, z up). Scene files give it as ``sonar.pose``. Default: the origin, looking
        along +x.
    objects : tuple of ObjectSpec
    ground : PlaneSpec or None
        The ground (:func:`ground_plane`: the horizontal plane named ``ground``, what a scene
        file's ``ground:`` section stands for), or ``None``: no ground. It is reflecting plane
        0 (:attr:`reflecting_planes`).
    planes : tuple of PlaneSpec
        Further reflecting planes (water surface, tank walls, a sloping bed).
    render : RenderSettings
    source : str or None
        File the scene was read from (mesh paths are relative to its folder).
    water : WaterSpec or None
        The water (``water:``, :mod:`sonarsim.config.water`): the speed of sound and the
        properties the sensor's absorption takes (folded into ``sensor`` here); ``None``: the
        sensor's own absorption section and speed, and no range scaling.
    sensor : SensorSpec or None
        The device model applied after image formation (``sensor:``); ``None``: the image is
        the renderer's noise-free expected backscatter. With ``instruments``, the FLS's.
    instruments : tuple of InstrumentSpec
        The instruments on the vehicle (``instruments:``, or ``sonar:`` with a ``type`` other
        than ``fls``); empty for today's ``sonar:`` scene (one FLS, :attr:`sonar` at
        :attr:`sonar_pose`). With instruments, :attr:`sonar` and :attr:`sonar_pose` are the
        first instrument's first channel (what the scene's cost checks count).
    vehicle_pose : Pose
        The vehicle's pose in the world frame (``vehicle.pose``; with ``sonar:`` of another
        type, its ``pose``), at time 0.
    vehicle_speed_m_s : float
        ``vehicle.speed_m_s``: without a trajectory the vehicle runs straight ahead (along its
        x axis) at this speed from ``vehicle_pose``; 0 stands still.
    """

    sonar: SonarConfig
    objects: tuple[ObjectSpec, ...] = ()
    ground: PlaneSpec | None = None
    render: RenderSettings = field(default_factory=RenderSettings)
    source: str | None = None
    planes: tuple[PlaneSpec, ...] = ()
    # Last, so that the fields before them keep their positions.
    sonar_pose: Pose = field(default_factory=Pose)
    sensor: SensorSpec | None = None
    instruments: tuple = ()
    vehicle_pose: Pose = field(default_factory=Pose)
    vehicle_speed_m_s: float = 0.0
    water: WaterSpec | None = None

    def __post_init__(self) -> None:
        # The water's properties replace the sensor's own (its absorption, its speed): one water;
        # its profile is the true water of an instrument that refracts (a multibeam, a side-scan) and has none.
        object.__setattr__(self, "sensor", fold_into_sensor(self.sensor, self.water))
        if self.water is not None and self.water.profile is not None:
            object.__setattr__(self, "instruments", tuple(
                replace(i, sound_speed_profile=[list(p) for p in self.water.profile])
                if getattr(i, "sound_speed_profile", False) is None else i for i in self.instruments))
        object.__setattr__(self, "objects", tuple(self.objects))
        object.__setattr__(self, "planes", tuple(self.planes))
        seen: set[str] = set()  # a set: 20,000 objects took 8 s with a list
        for i, obj in enumerate(self.objects):
            if obj.name in seen:
                raise ConfigError(f"objects[{i}].name", f"duplicate object name {shown(obj.name)}; names must be unique")
            seen.add(obj.name)
        if self.ground is not None and not is_ground(self.ground):
            raise ConfigError("ground", f"must be the horizontal plane named 'ground' with normal +z "
                              f"(ground_plane(height_m=...)), got {shown(self.ground)}")
        taken = ["ground"] if self.ground is not None else []
        for i, plane in enumerate(self.planes):
            if plane.name in taken:
                earlier = [p.name for p in self.planes[:i]]
                why = "names must be unique" if plane.name in earlier else "the ground: section is the plane 'ground'"
                raise ConfigError(f"planes[{i}].name", f"duplicate plane name {shown(plane.name)}; {why}")
            taken.append(plane.name)
        # Labels number the objects and then the planes, naming each id (Labels.ids): an object
        # called ``ground`` gave two ids of that name. ``ground`` is refused even without a ground
        # section: it is also the name of the planes' direct-echo component.
        plane_names = set(taken) | {"ground"}
        for i, obj in enumerate(self.objects):
            if obj.name in plane_names:
                raise ConfigError(f"objects[{i}].name", f"{shown(obj.name)} is a reflecting plane's name; an object's "
                                  f"name must differ from 'ground' and the planes' ({', '.join(taken) or 'none'})")
        if self.render.method == "paper" and self.render.double_beam in ("separate", "coherent"):
            raise ConfigError(
                "render.double_beam",
                f"{self.render.double_beam!r} is not a convention of Algorithm 2 (method: paper); allowed with it: "
                f"paper, split",
            )
        if self.sensor is not None:
            if not self.render.tvg:
                raise ConfigError("render.tvg", "must be true with a sensor section: the sensor's sonar equation "
                                  "applies the spreading loss (and sensor.tvg compensates it)")
            if self.render.speckle:
                raise ConfigError("render.speckle", "with a sensor section, speckle is the sensor's: configure "
                                  "sensor.speckle and leave render.speckle false")
            if self.sensor.elevation_pattern is not None and self.render.beam_pattern != "uniform":
                raise ConfigError("render.beam_pattern", "the sensor's elevation_pattern is the beam pattern; "
                                  "leave render.beam_pattern uniform")
            try:  # the carrier and the beams are the sonar's: known only here
                check_bandwidth(self.sensor, self.sonar.frequency_khz)
                if self.sonar.n_beams > 1:
                    check_azimuth_width(self.sensor, float(np.median(np.abs(np.diff(self.sonar.azimuth_deg)))),
                                        float(np.median(self.sonar.effective_beam_width_deg())))
            except ConfigError as exc:
                raise ConfigError(exc.key if exc.key.startswith("sonar.") else f"sensor.{exc.key}", exc.detail) from None
        # The rays are counted now, so that a command refuses them before its run starts.
        check_ray_budget(self.sonar, self.render)
        if self.render.method == "paper" and self.planes:
            raise ConfigError(
                "render.method",
                f"'paper' is Algorithm 2, which mirrors the ground alone; this scene also has the planes "
                f"{', '.join(p.name for p in self.planes)}: use method: fast (the default)",
            )

    @property
    def reflecting_planes(self) -> tuple[PlaneSpec, ...]:
        """Every reflecting plane: the ground first (if any), then ``planes`` in order.

        A plane's index here is its surface id in the per-ray labels.
        """
        return ((self.ground,) if self.ground is not None else ()) + self.planes

    def with_pose(self, pose: Pose) -> "Scene":
        """The same scene with the sonar at another pose (``sonar_pose``); intrinsics unchanged."""
        return replace(self, sonar_pose=pose)

    def to_dict(self) -> dict:
        """The scene-file form (JSON/YAML-serialisable); the pose is ``sonar.pose`` (with
        instruments: ``vehicle.pose`` and each instrument's ``mount``)."""
        if self.instruments:
            vehicle = {"pose": self.vehicle_pose.to_dict()}
            if self.vehicle_speed_m_s:
                vehicle["speed_m_s"] = self.vehicle_speed_m_s
            out: dict = {"vehicle": vehicle, "instruments": [i.to_dict() for i in self.instruments]}
        else:
            out = {"sonar": sonar_section(self.sonar, self.sonar_pose)}
        out.update({
            "render": self.render.to_dict(),
            "objects": [o.to_dict() for o in self.objects],
        })
        if self.ground is not None:
            out["ground"] = ground_section(self.ground)
        if self.planes:
            out["planes"] = [p.to_dict() for p in self.planes]
        if self.sensor is not None:
            out["sensor"] = self.sensor.to_dict()
        if self.water is not None:
            out["water"] = self.water.to_dict()
        return out


def sonar_section(sonar: SonarConfig, pose: Pose) -> dict:
    """The ``sonar`` section of a scene file: the intrinsics of ``sonar`` and ``pose``.

    Returns
    -------
    dict
        :meth:`SonarConfig.to_dict` with ``pose`` (:meth:`Pose.to_dict`) after
        ``n_range_bins``, where scene files have always had it.
    """
    out: dict = {}
    for key, value in sonar.to_dict().items():
        out[key] = value
        if key == "n_range_bins":
            out["pose"] = pose.to_dict()
    return out


# A sonar closer than this to a plane is "on" it: neither side can be told apart at float32.
ON_PLANE_TOLERANCE_M = 1e-6


def check_sonar_position(planes: tuple[PlaneSpec, ...], position_m, key: str) -> None:
    """Refuse a sonar that lies on a plane (which side sees what would be undefined).

    Raises
    ------
    ConfigError
        Naming ``key`` and the plane.
    """
    for plane in planes:
        d = float(plane.signed_distance_m(np.asarray(position_m, dtype=float)))
        if abs(d) < ON_PLANE_TOLERANCE_M:
            raise ConfigError(
                key,
                f"the sonar at {list(position_m)} lies on the plane {shown(plane.name)} (distance {d:.2g} m); "
                f"move it at least {ON_PLANE_TOLERANCE_M:g} m to either side",
            )
