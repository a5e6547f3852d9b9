"""The paper's ground echo (Section IV, Algorithm 2), kept literally as the ground-only reference.

The renderer forms every path, over any planes, with :mod:`sonarsim.paths.engine`; this module
is what that engine is checked against on the paper's own case, a flat ground alone.

Notation: O the sonar, A a point on an object, A' its mirror image across the ground plane,
G where a path meets the ground; R the ground's specular reflectance. Only the ground's
specular part causes multipath; objects are diffuse.

* case 4 (triple, O-G-A-G-O): range OA', in the beam of the ray that reached A', weight
  ``R**2 * I_f`` of that ray;
* cases 2/3 (double, O-G-A-O and O-A-G-O): range (OA + OA')/2, in the beam of that ray (or
  split, see ``render.double_beam``), weight ``R * I_f``, only where A lies in the sonar's
  field of view and range window (and, optionally, in its line of sight).

* :func:`render_paper` -- Algorithm 2 literally: single-bounce renders of S1 (objects + ground),
  S2 (objects) and S3 (objects + mirrored objects), difference images and per-ray differences;
  it hands a :class:`MirrorPaths` to :func:`ground_echo_images`, which forms the images.

The path engine's images are compared with these on the ground-only scenes
(``tests/reference/test_algorithm2.py``), and with the brute-force reference
(:mod:`sonarsim.reference.brute_force`, ``tests/reference/test_brute_force.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.radiometry import SurfaceLaws, backscatter
from ..core.splat import RayEnergy, accumulate, continuity, form_image
from ..config.scene import RenderSettings
from ..config.sonar import SonarConfig
from ..core.transforms import Pose
from ..image.grid import beam_azimuth_deg, beam_index
from ..trace.surfaces import GROUND_ID, NO_HIT, ground_distance, trace
from ..paths.planes import PlaneSet, apply

# Secondary rays start this far off the ground so that they cannot hit the plane's own
# neighbourhood (the base of an object resting on it) through round-off, metres.
SURFACE_OFFSET_M = 1e-5


@dataclass(frozen=True)
class MirrorPaths:
    """Rays (shaped ``(...)`` like the ray fan) that reach an object's mirror point A'.

    Attributes
    ----------
    distance_m : (...) float64 ndarray
        OA' (= OG + GA), metres; ``inf`` where the ray reaches no mirror point.
    intensity : (...) float64 ndarray
        I_f^{o'}: the ray's single-bounce intensity at A' (R not applied).
    surface_id : (...) int32 ndarray
        The object reached (k + 1), -1 for none.
    point_virtual : (..., 3) float64 ndarray
        A' in the world frame (on the straight ray), metres.
    normal_virtual : (..., 3) float64 ndarray
        Unit normal of the mirrored surface at A'.
    point_real : (..., 3) float64 ndarray
        A, the real point on the object, metres.
    """

    distance_m: np.ndarray
    intensity: np.ndarray
    surface_id: np.ndarray
    point_virtual: np.ndarray
    normal_virtual: np.ndarray
    point_real: np.ndarray


def ground_echo_rays(
    paths: MirrorPaths,
    sonar: SonarConfig,
    pose: Pose,
    render: RenderSettings,
    specular: float,
    caster=None,
    labels: tuple[int, int] = (0, 1),
) -> list[RayEnergy]:
    """The double (cases 2/3) and triple (case 4) echoes as ray energies for :func:`accumulate`.

    Parameters
    ----------
    paths : MirrorPaths
        Shaped like the ray fan ``(n_beams, n_azimuth_samples, n_elevation_samples)``.
    sonar : SonarConfig
        The sonar's intrinsics (beams, elevation aperture, range window).
    pose : Pose
        The sonar's pose in the world frame.
    render : RenderSettings
        ``range_splat``, ``double_beam`` and ``double_line_of_sight`` are used.
    specular : float
        R: double bounces are scaled by R, triple by R**2.
    caster : RayCaster, optional
        Needed for ``double_line_of_sight``.
    labels : (int, int)
        Image labels of the double and the triple echoes.
    """
    label_double, label_triple = labels
    beam = np.arange(sonar.n_beams)[:, None, None]
    cont = None
    if render.range_splat:
        cont = continuity(paths.point_virtual, paths.normal_virtual, paths.surface_id)
    out = [RayEnergy(paths.distance_m, specular**2 * paths.intensity, beam, label_triple, cont)]

    # Cases 2/3: A must lie in the field of view and the range window.
    reached = np.isfinite(paths.distance_m)
    if not reached.any():
        return out
    origin = pose.translation
    sel = np.nonzero(reached)
    rel = (paths.point_real[sel] - origin) @ pose.rotation  # sonar frame
    oa = np.linalg.norm(rel, axis=-1)
    az = beam_azimuth_deg(rel, getattr(sonar, "beam_shape", "plane") == "cone")
    el = np.degrees(np.arcsin(np.clip(rel[:, 2] / oa, -1.0, 1.0)))
    beam_a = beam_index(sonar.beam_edges_deg, np.nan_to_num(az, nan=1e9))  # (NaN: behind a cone array)
    in_view = (
        (beam_a >= 0)
        & (np.abs(el) <= sonar.elevation_fov_deg / 2)
        & (oa >= sonar.range_min_m)
        & (oa < sonar.range_max_m)
    )
    if render.double_line_of_sight and caster is not None and in_view.any():
        to_a = (rel[in_view] / oa[in_view, None]) @ pose.rotation.T
        hit = caster.intersect(origin, to_a, float(oa[in_view].max()) + 1.0)
        # Visible when the first thing on the way is A itself (to float32 precision).
        visible = hit.distance >= oa[in_view] - 1e-3 * np.maximum(oa[in_view], 1.0)
        in_view[np.flatnonzero(in_view)[~visible]] = False
    shape = paths.distance_m.shape
    r23 = np.full(shape, np.inf)
    r23[sel] = np.where(in_view, 0.5 * (oa + paths.distance_m[sel]), np.inf)
    e23 = np.zeros(shape)
    e23[sel] = np.where(in_view, specular * paths.intensity[sel], 0.0)
    if render.double_beam == "paper":
        out.append(RayEnergy(r23, e23, beam, label_double, cont))
    else:
        beam_of_a = np.zeros(shape, dtype=np.int64)
        beam_of_a[sel] = np.maximum(beam_a, 0)
        out.append(RayEnergy(r23, 0.5 * e23, beam, label_double, cont))
        out.append(RayEnergy(r23, 0.5 * e23, beam_of_a, label_double, cont))
    return out


def ground_echo_images(
    paths: MirrorPaths,
    sonar: SonarConfig,
    pose: Pose,
    render: RenderSettings,
    specular: float,
    caster=None,
) -> tuple[np.ndarray, np.ndarray]:
    """The double and triple images, each (n_range_bins, n_beams) float64 (see :func:`ground_echo_rays`)."""
    rays = ground_echo_rays(paths, sonar, pose, render, specular, caster)
    img = accumulate(rays, sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams, 2)
    return img[0], img[1]


def render_paper(
    objects_caster,
    mirrored_caster,
    origin: np.ndarray,
    directions: np.ndarray,
    sonar: SonarConfig,
    pose: Pose,
    render: RenderSettings,
    ground,
    weight: np.ndarray,
    laws: SurfaceLaws | np.ndarray,
    n_objects: int,
    max_distance_m: float,
    texture=None,
) -> dict[str, np.ndarray]:
    """Algorithm 2 of the paper, literally: three single-bounce renders and their differences.

    ``mirrored_caster`` holds the objects (mesh k = object k) followed by their mirror images
    (mesh n_objects + k = mirror of object k). ``origin`` (3,) and ``directions`` (..., 3), world
    frame, are the rays of ``sonar`` (intrinsics) at ``pose``. ``texture``: the ground's
    :class:`~sonarsim.scene.floor_texture.ReflectivityField` (None: uniform); in Algorithm 2
    only the direct ground echo scatters off the ground (S1's ground hits take its factor).

    Returns
    -------
    dict with ``object``, ``ground``, ``double``, ``triple`` images, (n_range_bins, n_beams).
    """
    n_beams = sonar.n_beams
    beam = np.arange(n_beams)[:, None, None]
    geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, n_beams)

    def single_bounce(caster, with_ground, laws):
        hits = trace(caster, origin, directions, ground if with_ground else None, max_distance_m)
        i_f = backscatter(weight, hits.cos_incidence, laws, hits.surface_id + 1, hits.distance_m, render.tvg,
                          hits.texel)
        if with_ground and texture is not None:
            on = hits.surface_id == GROUND_ID
            i_f[on] *= texture.factor(hits.point[on])
        cont = continuity(hits.point, hits.normal, hits.surface_id) if render.range_splat else None
        return hits, i_f, form_image(hits.distance_m, i_f, beam, *geometry, continuous=cont)[0]

    laws = SurfaceLaws.of(laws)
    _, _, i_a_og = single_bounce(objects_caster, True, laws)  # S1
    hits_o, i_f_o, i_a_o = single_bounce(objects_caster, False, laws)  # S2
    # Mirror k has surface id n_objects + k + 1 and the law of object k.
    hits_oo, i_f_oo, i_a_oo = single_bounce(mirrored_caster, False, laws.concat(laws, 2))  # S3
    out = {"object": i_a_o, "ground": i_a_og - i_a_o}
    i_a_mirror = i_a_oo - i_a_o  # Eq. 8: case 4
    i_f_mirror = i_f_oo - i_f_o  # Eq. 10
    reached = (i_f_mirror > 0) & (hits_oo.surface_id > n_objects)
    # The loop of Algorithm 2 over the rays with I_f^{o'} > 0, vectorised: A' from D_f^{oo'},
    # A its mirror image.
    a_virtual = np.where(reached[..., None], hits_oo.point, np.nan)
    paths = MirrorPaths(
        distance_m=np.where(reached, hits_oo.distance_m, np.inf),
        intensity=np.where(reached, i_f_mirror, 0.0),
        surface_id=np.where(reached, hits_oo.surface_id - n_objects, NO_HIT).astype(np.int32),
        point_virtual=a_virtual,
        normal_virtual=hits_oo.normal,
        point_real=apply(PlaneSet.from_specs([ground]).mirror(0), a_virtual),
    )
    double, _ = ground_echo_images(paths, sonar, pose, render, ground.specular, objects_caster)
    out["double"] = double
    out["triple"] = ground.specular**2 * i_a_mirror
    return out


__all__ = ["MirrorPaths", "ground_distance", "ground_echo_images", "ground_echo_rays", "render_paper"]
