"""The default render path with its per-ray loops compiled (:mod:`sonarsim._kernels`).

Same physics, same images as the NumPy path (``Simulator(kernels="numpy")``: ``tracing.trace``,
``multipath.fast_mirror_paths``, ``multipath.ground_echo_rays``, ``imaging.accumulate``), which
the tests compare it against. Per frame: cast the primary rays, one kernel for the closest
surfaces and intensities, cast the reflected rays of those that reached the ground, one kernel
for the ground echoes, one kernel per set of rays to spread them into the images.
"""

from __future__ import annotations

import numpy as np

from .rays import RayFan
from .scene import GroundSpec, RenderSettings
from .sonar import SonarConfig

try:
    from . import _kernels
except ImportError:  # not built (e.g. a source tree used without installing)
    _kernels = None

AVAILABLE = _kernels is not None


class Workspace:
    """Per-frame arrays, kept between frames of the same ray count (no allocation per frame)."""

    def __init__(self, n: int, n_beams: int, n_per_beam: int) -> None:
        self.n = n
        self.dist = np.empty(n)
        self.sid = np.empty(n, dtype=np.int32)
        self.point = np.empty((n, 3), dtype=np.float32)
        self.normal = np.empty((n, 3), dtype=np.float32)
        self.intensity = np.empty(n)
        self.label = np.empty(n, dtype=np.int8)
        self.g_index = np.empty(n, dtype=np.intp)
        self.g_t = np.empty(n)
        self.g_start = np.empty((n, 3), dtype=np.float32)
        self.g_dir = np.empty((n, 3), dtype=np.float32)
        self.tri_dist = np.empty(n)
        self.tri_energy = np.empty(n)
        self.v_point = np.empty((n, 3))
        self.v_normal = np.empty((n, 3))
        self.v_sid = np.empty(n, dtype=np.int32)
        self.r23 = np.empty(n)
        self.e23 = np.empty(n)
        self.beam_a = np.empty(n, dtype=np.int32)
        self.beam = np.repeat(np.arange(n_beams, dtype=np.int32), n_per_beam)
        self.no_label = np.empty(0, dtype=np.int8)

    def reset_mirror(self) -> None:
        self.tri_dist.fill(np.inf)
        self.tri_energy.fill(0.0)
        self.v_point.fill(np.nan)
        self.v_normal.fill(0.0)
        self.v_sid.fill(-1)
        self.r23.fill(np.inf)
        self.e23.fill(0.0)
        self.beam_a.fill(0)


def render_fast(
    caster,
    sonar: SonarConfig,
    fan: RayFan,
    directions: np.ndarray,
    ground: GroundSpec | None,
    render: RenderSettings,
    albedo_by_id: np.ndarray,
    reach_m: float,
    multipath: bool,
    work: Workspace,
    out: np.ndarray,
) -> None:
    """Render the object, ground, double and triple images into ``out`` (labels 0-3).

    Parameters
    ----------
    caster : RayCaster
    sonar, fan, render : the sonar at its pose, its rays, the settings
    directions : (n_beams, n_azimuth, n_elevation, 3) float64 ndarray
        World-frame ray directions.
    ground : GroundSpec or None
    albedo_by_id : (n_objects + 2,) float64 ndarray, indexed by surface id + 1
    reach_m : float
        Longest path followed, metres.
    multipath : bool
        Form the ground echoes.
    work : Workspace
        Receives the per-ray results (``dist``, ``sid``, ``intensity``: D_f, labels, I_f).
    out : (4, n_range_bins, n_beams) float64 C-contiguous ndarray
    """
    n = fan.n_rays
    d64 = np.ascontiguousarray(directions.reshape(n, 3))
    origin = sonar.pose.translation
    o32 = np.empty((n, 3), dtype=np.float32)
    o32[:] = origin
    hits = caster.intersect(o32, d64.astype(np.float32), reach_m)
    weight = fan.weight.reshape(n)
    has_ground = ground is not None
    n_g, t_min = _kernels.primary(
        hits.distance, hits.mesh_id, hits.normal, d64, origin[0], origin[1], origin[2],
        has_ground, ground.height_m if has_ground else 0.0, reach_m, albedo_by_id, weight, render.tvg,
        work.dist, work.sid, work.point, work.normal, work.intensity, work.label,
        work.g_index, work.g_t, work.g_start, work.g_dir,
    )
    n_el = fan.shape[2]
    geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams)
    flat_out = out.reshape(-1)
    out.fill(0.0)
    spread = render.range_splat
    _kernels.splat(work.dist, work.intensity, work.beam, work.label, 0, work.point, work.normal, work.sid,
                   spread, n_el, *geometry, flat_out)
    if not (multipath and n_g):
        return
    hits2 = caster.intersect(work.g_start[:n_g], work.g_dir[:n_g], float(reach_m - t_min))
    work.reset_mirror()
    half_el = sonar.elevation_fov_deg / 2.0
    _kernels.mirror_paths(
        work.g_index[:n_g], work.g_t[:n_g], work.g_start[:n_g], hits2.distance, hits2.mesh_id, hits2.normal,
        d64, work.point, origin[0], origin[1], origin[2], np.ascontiguousarray(sonar.pose.rotation),
        np.ascontiguousarray(sonar.beam_edges_deg), half_el, sonar.range_min_m, sonar.range_max_m,
        reach_m, albedo_by_id, weight, render.tvg, ground.specular,
        work.tri_dist, work.tri_energy, work.v_point, work.v_normal, work.v_sid,
        work.r23, work.e23, work.beam_a,
    )
    if render.double_line_of_sight:
        _drop_hidden(caster, sonar, ground.height_m, work)
    _kernels.splat(work.tri_dist, work.tri_energy, work.beam, work.no_label, 3, work.v_point, work.v_normal,
                   work.v_sid, spread, n_el, *geometry, flat_out)
    if render.double_beam == "paper":
        _kernels.splat(work.r23, work.e23, work.beam, work.no_label, 2, work.v_point, work.v_normal,
                       work.v_sid, spread, n_el, *geometry, flat_out)
    else:
        half = 0.5 * work.e23
        for beams in (work.beam, work.beam_a):
            _kernels.splat(work.r23, half, beams, work.no_label, 2, work.v_point, work.v_normal,
                           work.v_sid, spread, n_el, *geometry, flat_out)


def _drop_hidden(caster, sonar: SonarConfig, ground_height_m: float, work: Workspace) -> None:
    """``double_line_of_sight``: no double bounce from an A that the sonar cannot see."""
    cand = np.flatnonzero(work.e23 > 0)
    if not cand.size:
        return
    origin = sonar.pose.translation
    a_point = work.v_point[cand].copy()  # A', mirrored back across the ground: A
    a_point[:, 2] = 2.0 * ground_height_m - a_point[:, 2]
    to_a = a_point - origin
    oa = np.linalg.norm(to_a, axis=1)
    hit = caster.intersect(origin, to_a / oa[:, None], float(oa.max()) + 1.0)
    # Visible when the first thing on the way is A itself (to float32 precision).
    hidden = hit.distance < oa - 1e-3 * np.maximum(oa, 1.0)
    work.e23[cand[hidden]] = 0.0
    work.r23[cand[hidden]] = np.inf
