"""The differentiable engine's parameters: flat names, units, values from a scene.

Every parameter is a JAX array under a flat key (the scene file's path to it, dotted):

==========================================  ======  =============================================
key                                         shape   meaning, unit
==========================================  ======  =============================================
``sonar.position_m``                        (3,)    the sonar's position, world frame, metres
``sonar.rpy_deg``                           (3,)    roll, pitch, yaw, degrees (ROS fixed axes;
                                                    positive pitch looks down)
``objects.<name>.position_m``               (3,)    the object's pose, metres
``objects.<name>.rpy_deg``                  (3,)    degrees
``objects.<name>.scale``                    (3,)    per-axis scale (dimensionless)
``objects.<name>.vertices_m``               (V, 3)  its mesh's vertices in its own frame, before
                                                    scale and pose, metres (primitives: as
                                                    tessellated)
``objects.<name>.albedo`` / ``.mu``         ()      diffuse coefficient (``lambertian`` and
                                                    ``rough``: albedo; ``lambert``: mu)
``objects.<name>.specular``                 ()      a mirroring object's specular reflectance R
                                                    (only where the scene's is above 0)
``objects.<name>.specular_strength``        ()      ``rough`` law only: the lobe at normal incidence
``objects.<name>.roughness``                ()      ``rough`` law only: rms facet slope
``planes.<name>.offset_m``                  ()      ``n . x`` on the plane, metres (the ground:
                                                    its height)
``planes.<name>.normal``                    (3,)    normal into the water (normalised inside)
``planes.<name>.specular``                  ()      specular reflectance R
``planes.<name>.albedo`` / ``.mu`` / ...    ()      its law's parameters, as for objects
``sensor.*``                                        see :mod:`sonarsim.diff.sensor`
==========================================  ======  =============================================
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..config.parameters import PARAMETERS, Parameter
from ..config.scene import Scene
from ..errors import ConfigError
from ..scene.meshes import object_mesh_local


#: A parameter's bounds: an entry of the one table of fittable parameters
#: (:class:`sonarsim.config.parameters.Parameter`: ``lo``, ``hi``, ``unit``, ``field``,
#: ``open_hi``, ``text()``), under the differentiable engine's key.
Bound = Parameter

#: The differentiable engine's keys (by their last part, or whole for the sensor) and the table's
#: entries whose bounds they take, with the scene field a message names.
_TABLE_KEYS = {
    "position_m": ("pose.x", "pose.position_m"),
    "rpy_deg": ("pose.roll", "pose.rpy_deg"),
    "scale": ("objects.scale", "objects[].scale"),
    "vertices_m": ("pose.x", "objects[].mesh (its vertices' reach)"),
    "albedo": ("material.albedo", "albedo"),
    "mu": ("material.mu", "material.mu"),
    "specular": ("material.specular", "specular"),
    "specular_strength": ("material.specular_strength", "material.specular_strength"),
    "roughness": ("material.roughness", "material.roughness"),
    "offset_m": ("planes.offset_m", "planes[].point_m"),
    "sensor.gain_db": ("sensor.gain_db", "sensor.gain_db"),
    "sensor.source_level_db": ("sensor.source_level_db", "sensor.source_level_db"),
    "sensor.noise_db": ("sensor.noise.level_db", "sensor.noise.level_db"),
    "sensor.noise_after_tvg_db": ("sensor.noise.after_tvg_db", "sensor.noise.after_tvg_db"),
    "sensor.tvg_spreading": ("sensor.tvg.spreading", "sensor.tvg.spreading"),
    "sensor.elevation_width_deg": ("sensor.elevation_pattern.width_deg", "sensor.elevation_pattern.width_deg"),
    "sensor.azimuth_width_deg": ("sensor.azimuth_pattern.width_deg", "sensor.azimuth_pattern.width_deg"),
    "sensor.gamma": ("sensor.output.gamma", "sensor.output.gamma"),
    "sensor.beam_gain_db": ("sensor.beam_gain.gain_db", "sensor.beam_gain.gain_db"),
}


def parameter_bounds() -> dict[str, Bound]:
    """Every parameter's bounds by the last part of its key (``albedo``, ``scale``, ...) or,
    for the sensor, by its whole key: the entries of the one table of fittable parameters
    (:data:`sonarsim.config.parameters.PARAMETERS`), which the scene format validates against,
    so that a value the scene format refuses is refused here too.

    Three are the engine's own: ``sensor.tvg_spreading`` (the scene format takes 0, 20, 30 or
    40) may lie anywhere between those, a plane's ``normal`` is any direction (not the zero
    vector), and an object's ``reflectivity`` (which the scene format does not have) is any
    factor of 0 or more.
    """
    out = {key: replace(PARAMETERS[name], name=key, field=field) for key, (name, field) in _TABLE_KEYS.items()}
    out["normal"] = Bound("normal", "", -np.inf, np.inf, 0.0, "planes[].normal", "a plane's normal into the water")
    out["reflectivity"] = Bound("reflectivity", "", 0.0, np.inf, 0.0, "(the differentiable engine's own)",
                                "an object's factor on its echo")
    return out


def bound_of(key: str, bounds: dict[str, Bound] | None = None) -> Bound | None:
    """The :class:`Bound` of a parameter key (None for a key without one)."""
    bounds = parameter_bounds() if bounds is None else bounds
    return bounds.get(key) or bounds.get(key.rsplit(".", 1)[-1])


def check_value(key: str, value: np.ndarray, bounds: dict[str, Bound] | None = None) -> None:
    """Refuse a parameter's value that is not finite or lies outside the scene format's bounds.

    Parameters
    ----------
    key : str
        The parameter (``objects.buoy.albedo``).
    value : ndarray
        Its concrete value (any shape: a batch of values is checked member by member).

    Raises
    ------
    ConfigError
        Naming the key (and the component, for a vector), the allowed range and the value.
    """
    from ..errors import ConfigError, shown

    v = np.asarray(value, dtype=float)
    bound = bound_of(key, bounds)
    finite = np.isfinite(v)
    inside = finite if bound is None else finite & (v >= bound.lo) & ((v < bound.hi) if bound.open_hi else (v <= bound.hi))
    allowed = "finite" if bound is None else f"finite, within {bound.text()} (the scene format's bounds of {bound.field})"
    if not inside.all():
        at = np.unravel_index(int(np.flatnonzero(~inside.reshape(-1))[0]), v.shape) if v.ndim else ()
        which = f" (at {list(map(int, at))})" if v.ndim else ""
        raise ConfigError(key, f"must be {allowed}; got {shown(float(v[at]))}{which}")
    if key.endswith(".normal") and v.shape[-1:] == (3,):
        # As the scene format has it (PlaneSpec): the length relative to the largest component
        # (whose squares may overflow), above 1e-9 of it.
        big = np.max(np.abs(v), axis=-1, keepdims=True)
        length = big[..., 0] * np.linalg.norm(v / np.where(big > 0, big, 1.0), axis=-1)
        if not (length > 1e-9 * np.maximum(1.0, big[..., 0])).all():
            raise ConfigError(key, f"must not be the zero vector (a plane's normal); got {shown(v.tolist())}")


def material_params(prefix: str, material) -> dict[str, float]:
    """A surface law's parameters under ``prefix`` (``objects.<name>`` or ``planes.<name>``)."""
    out = {}
    if material.law == "lambert":
        out[f"{prefix}.mu"] = float(material.coefficient)
    else:
        out[f"{prefix}.albedo"] = float(material.coefficient)
    if material.law == "rough":
        strength, roughness = material.lobe
        out[f"{prefix}.specular_strength"] = strength
        out[f"{prefix}.roughness"] = roughness
    return out


def scene_params(scene: Scene) -> dict[str, np.ndarray]:
    """The parameters' values in ``scene`` (float64 NumPy arrays), without the sensor's."""
    pose = scene.sonar_pose
    out: dict[str, np.ndarray] = {
        "sonar.position_m": np.asarray(pose.position_m, float),
        "sonar.rpy_deg": np.asarray(pose.rpy_deg, float),
    }
    for obj in scene.objects:
        p = f"objects.{obj.name}"
        out[f"{p}.position_m"] = np.asarray(obj.pose.position_m, float)
        out[f"{p}.rpy_deg"] = np.asarray(obj.pose.rpy_deg, float)
        out[f"{p}.scale"] = np.broadcast_to(np.asarray(obj.scale, float), (3,)).copy()
        out[f"{p}.vertices_m"] = np.asarray(object_mesh_local(obj).vertices, float).copy()
        out.update({k: np.asarray(v, float) for k, v in material_params(p, obj.backscatter).items()})
        if obj.specular > 0:  # a mesh mirror's R (an object that does not mirror has none to move)
            out[f"{p}.specular"] = np.asarray(obj.specular, float)
    for plane in scene.reflecting_planes:
        p = f"planes.{plane.name}"
        out[f"{p}.offset_m"] = np.asarray(plane.offset_m, float)
        out[f"{p}.normal"] = np.asarray(plane.normal, float)
        out[f"{p}.specular"] = np.asarray(plane.specular, float)
        out.update({k: np.asarray(v, float) for k, v in material_params(p, plane.backscatter).items()})
    return out


#: The laws the differentiable engine has a formula for (forward.law_table).
DIFF_LAWS = ("lambertian", "lambert", "rough")


def check_diff_laws(scene: Scene) -> None:
    """Refuse a surface whose law the differentiable engine does not take (ConfigError naming
    its ``material.law``): the sediment law is a table evaluated per frequency, which only the
    compiled and NumPy renderers read."""
    rows = [("ground" if p is scene.ground else f"planes.{p.name}", p.backscatter.law) for p in scene.reflecting_planes]
    rows += [(f"objects.{o.name}", o.backscatter.law) for o in scene.objects]
    for where, law in rows:
        if law not in DIFF_LAWS:
            raise ConfigError(f"{where}.material.law",
                              f"the differentiable engine takes the laws {', '.join(DIFF_LAWS)}, not {law!r}: render "
                              f"a {law} surface with sonarsim.Simulator, or give it a lambert law for the fit")
    mirrors = [("ground" if p is scene.ground else f"planes.{p.name}", p) for p in scene.reflecting_planes]
    mirrors += [(f"objects.{o.name}", o) for o in scene.objects]
    for where, spec in mirrors:
        if spec.reflection is not None:
            raise ConfigError(f"{where}.reflection",
                              "the differentiable engine reflects with a constant specular R: render a reflection "
                              "by the physics with sonarsim.Simulator, or give the surface a specular for the fit")


def surface_laws(scene: Scene) -> tuple[tuple[str, str], ...]:
    """``(parameter prefix, law)`` of every surface, by surface id (planes, then objects)."""
    rows = [(f"planes.{p.name}", p.backscatter.law) for p in scene.reflecting_planes]
    rows += [(f"objects.{o.name}", o.backscatter.law) for o in scene.objects]
    return tuple(rows)


def _material_with(material, prefix: str, values: dict):
    """``material`` with the law parameters found under ``prefix`` in ``values``."""
    from dataclasses import replace

    changes = {}
    for key in ("albedo", "mu", "specular_strength", "roughness"):
        if f"{prefix}.{key}" in values:
            changes[key] = float(values[f"{prefix}.{key}"])
    return replace(material, **changes) if changes else material


def scene_with(scene: Scene, params: dict) -> Scene:
    """``scene`` with the values of ``params`` (any subset of :func:`scene_params`' keys and
    the sensor's): the scene the compiled engine renders at those parameters.

    An object whose vertices or scale change becomes a mesh object (its faces kept), so that
    its triangles stay the ones the parameters name; a ground whose normal tilts becomes a
    plane named ``ground``.
    """
    from dataclasses import replace

    from ..core.transforms import Pose

    v = {k: np.asarray(x, float) for k, x in params.items()}
    base = scene_params(scene)

    def changed(key: str) -> bool:
        return key in v and not np.array_equal(v[key], base[key])

    sonar_pose = scene.sonar_pose
    if changed("sonar.position_m") or changed("sonar.rpy_deg"):
        sonar_pose = Pose(tuple(v.get("sonar.position_m", base["sonar.position_m"])),
                          tuple(v.get("sonar.rpy_deg", base["sonar.rpy_deg"])))
    objects = []
    for obj in scene.objects:
        p = f"objects.{obj.name}"
        changes: dict = {}
        if changed(f"{p}.position_m") or changed(f"{p}.rpy_deg"):
            changes["pose"] = Pose(tuple(v.get(f"{p}.position_m", base[f"{p}.position_m"])),
                                   tuple(v.get(f"{p}.rpy_deg", base[f"{p}.rpy_deg"])))
        if changed(f"{p}.vertices_m") or changed(f"{p}.scale"):
            import trimesh

            local = object_mesh_local(obj)
            vertices = v.get(f"{p}.vertices_m", base[f"{p}.vertices_m"])
            visual = None
            if local.uv is not None and local.texture is not None:  # a textured mesh keeps its texture
                from PIL import Image

                image = Image.fromarray(np.round(np.clip(local.texture, 0.0, 1.0) * 255.0).astype(np.uint8))
                visual = trimesh.visual.TextureVisuals(uv=np.asarray(local.uv), image=image)
            changes.update(primitive=None, size_m=None, radius_m=None, height_m=None,
                           mesh=trimesh.Trimesh(vertices, np.asarray(local.faces), visual=visual, process=False),
                           scale=tuple(float(s) for s in v.get(f"{p}.scale", base[f"{p}.scale"])))
        if changed(f"{p}.specular"):
            changes["specular"] = float(v[f"{p}.specular"])
        material = _material_with(obj.backscatter, p, v)
        if material != obj.backscatter:  # the albedo shorthand stays one
            changes.update(albedo=material.coefficient) if obj.material is None else changes.update(material=material)
        objects.append(replace(obj, **changes) if changes else obj)
    planes, ground = [], scene.ground
    for plane in scene.reflecting_planes:
        p = f"planes.{plane.name}"
        normal = v.get(f"{p}.normal", np.asarray(plane.normal, float))
        normal = normal / np.max(np.abs(normal))  # (first: the squares of a huge normal's parts overflow)
        normal = normal / np.linalg.norm(normal)
        offset = float(v.get(f"{p}.offset_m", plane.offset_m))
        material = _material_with(plane.backscatter, p, v)
        changes = {}
        if changed(f"{p}.normal") or changed(f"{p}.offset_m"):
            changes.update(point_m=tuple(float(x) for x in normal * offset), normal=tuple(float(x) for x in normal))
        if changed(f"{p}.specular"):
            changes["specular"] = float(v[f"{p}.specular"])
        if material != plane.backscatter:
            changes.update(albedo=material.coefficient) if plane.material is None else changes.update(material=material)
        new = replace(plane, **changes) if changes else plane
        if plane is scene.ground and np.allclose(new.normal, (0.0, 0.0, 1.0), rtol=0.0, atol=1e-15):
            ground = new  # still the horizontal ground
        else:
            if plane is scene.ground:
                ground = None  # tilted: a plane named ground, first, so that the surface ids stay
            planes.append(new)
    sensor = scene.sensor
    if sensor is not None:
        sensor = sensor_with(sensor, v)
    return replace(scene, sonar_pose=sonar_pose, objects=tuple(objects), ground=ground, planes=tuple(planes),
                   sensor=sensor)


def sensor_with(spec, values: dict):
    """A :class:`~sonarsim.config.sensor.SensorSpec` with the ``sensor.*`` values given."""
    from dataclasses import replace

    def get(key, default):
        return float(values[key]) if key in values else default

    changes: dict = {}
    for key in ("gain_db", "source_level_db"):
        if f"sensor.{key}" in values:
            changes[key] = get(f"sensor.{key}", None)
    if spec.tvg is not None and "sensor.tvg_spreading" in values:
        changes["tvg"] = replace(spec.tvg, spreading=get("sensor.tvg_spreading", spec.tvg.spreading))
    if spec.noise is not None and ("sensor.noise_db" in values or "sensor.noise_after_tvg_db" in values):
        changes["noise"] = replace(spec.noise, level_db=get("sensor.noise_db", spec.noise.level_db),
                                   after_tvg_db=get("sensor.noise_after_tvg_db", spec.noise.after_tvg_db))
    if spec.elevation_pattern is not None and "sensor.elevation_width_deg" in values:
        changes["elevation_pattern"] = replace(spec.elevation_pattern, width_deg=get("sensor.elevation_width_deg", None))
    if spec.azimuth_pattern is not None and "sensor.azimuth_width_deg" in values:
        changes["azimuth_pattern"] = replace(spec.azimuth_pattern, width_deg=get("sensor.azimuth_width_deg", None))
    if spec.output is not None and "sensor.gamma" in values:
        changes["output"] = replace(spec.output, gamma=get("sensor.gamma", spec.output.gamma))
    if "sensor.beam_gain_db" in values:
        from ..config.sensor import BeamGainSpec

        db = tuple(float(x) for x in np.ravel(np.asarray(values["sensor.beam_gain_db"], float)))
        bg = spec.beam_gain if spec.beam_gain is not None else BeamGainSpec()
        changes["beam_gain"] = replace(bg, gain_db=db if any(db) or bg.gain_db is not None else None)
    return replace(spec, **changes) if changes else spec
