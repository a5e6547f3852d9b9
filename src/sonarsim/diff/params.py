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

import numpy as np

from ..config.scene import Scene
from ..scene.meshes import object_mesh_local


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
    for plane in scene.reflecting_planes:
        p = f"planes.{plane.name}"
        out[f"{p}.offset_m"] = np.asarray(plane.offset_m, float)
        out[f"{p}.normal"] = np.asarray(plane.normal, float)
        out[f"{p}.specular"] = np.asarray(plane.specular, float)
        out.update({k: np.asarray(v, float) for k, v in material_params(p, plane.backscatter).items()})
    return out


def surface_laws(scene: Scene) -> tuple[tuple[str, str], ...]:
    """``(parameter prefix, law)`` of every surface, by surface id (planes, then objects)."""
    rows = [(f"planes.{p.name}", p.backscatter.law) for p in scene.reflecting_planes]
    rows += [(f"objects.{o.name}", o.backscatter.law) for o in scene.objects]
    return tuple(rows)
