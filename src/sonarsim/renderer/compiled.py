"""The default render path with its per-ray loops compiled (:mod:`sonarsim.renderer._kernels`).

General planes (:func:`render_paths`): the kernels ``trace_leg`` (one generation of receive
legs), ``path_events`` (the paths of one generation and one transmit option) and
``splat_events`` (paths into the image stack), twinned by the NumPy code of
:mod:`sonarsim.paths.engine` and :mod:`sonarsim.renderer.formation`. Per frame: cast the fan,
trace its legs, cast the reflected rays (split over both cores while this one forms the direct
image), trace them, and so on up to ``max_order - 1`` reflections; then form and splat the paths.

The ground alone at order 3 (:func:`render_fast`): the kernels ``primary``, ``mirror_paths``
and ``splat`` written for the flat ground before the general engine, run over blocks of beams
that the two cores take in turn; with the Embree 4 binding each block is one call of
``_kernels.GroundBlocks``, which also casts. Same images as the general path (the tests compare
them); kept as a specialisation until the general path is as fast on that case.
"""

from __future__ import annotations

import functools
import itertools

import numpy as np

from ..paths.engine import Leg
from ..paths.planes import ChainTable
from ..core.radiometry import SurfaceLaws

from ..core.rays import RayFan
from ..config.scene import GroundSpec, RenderSettings
from ..config.sonar import SonarConfig
from ..core.transforms import Pose
from ..scene.floor_texture import scale_by_texture

try:
    from . import _kernels
except ImportError:  # not built (e.g. a source tree used without installing)
    _kernels = None

AVAILABLE = _kernels is not None

# Blocks of beams per core in the ground specialisation (render_fast): a few, so that a core
# finishing early takes another block, but few enough that the per-block Python calls stay small.
BLOCKS_PER_CORE = 2
# Share of a frame's reflected rays cast on the other core while this one forms the direct image.
OTHER_CORE_SHARE = 0.65


def _law_args(laws: SurfaceLaws, hits) -> tuple:
    """The kernels' optional law arguments: ``(law_by_id, lobe_by_id, hit_texel)``, None where
    not needed (Lambertian surfaces, no texture: the paper's arithmetic exactly)."""
    texel = None if hits is None else hits.texel
    if laws.lambertian_only:
        return None, None, texel
    return laws.law, laws.lobe, texel


class Workspace:
    """Per-frame arrays, kept between frames of the same fan layout (no allocation per frame)."""

    @classmethod
    def for_fan(cls, work: "Workspace | None", fan: RayFan) -> "Workspace":
        """``work`` where it fits ``fan`` (the same rays per beam and beams), else a new one.

        The ray count alone is not enough: a sonar with other beams can cast as many rays (64
        beams x 366 elevation rays against 128 x 183), and the per-ray beam index would be the
        other sonar's.
        """
        n_beams = fan.shape[0]
        per_beam = fan.n_rays // n_beams
        if work is not None and work.layout == (fan.n_rays, n_beams, per_beam):
            return work
        return cls(fan.n_rays, n_beams, per_beam)

    def __init__(self, n: int, n_beams: int, n_per_beam: int) -> None:
        self.n = n
        self.layout = (n, n_beams, n_per_beam)
        self.d64 = np.empty((n, 3))
        self.d32 = np.empty((n, 3), dtype=np.float32)
        self.o32 = np.empty((n, 3), dtype=np.float32)
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
        # The casts' hits (primary rays; reflected rays in the rows of their block).
        self.h_dist, self.h2_dist = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
        self.h_mesh, self.h2_mesh = np.empty(n, dtype=np.int32), np.empty(n, dtype=np.int32)
        self.h_normal, self.h2_normal = np.empty((n, 3), dtype=np.float32), np.empty((n, 3), dtype=np.float32)
        self.ground_blocks: tuple | None = None  # (caster, fan, laws, GroundBlocks), see ground_blocks()
        # The general engine's: its block engine (path_engine()), the rays of each block's
        # current and next generation (two buffers, a block's rows at its own rays).
        self.engine: tuple | None = None
        self.options: tuple | None = None  # (planes, chains, n_gen, max_order, double_beam, arrays), _options()
        self.chains: tuple | None = None  # (planes, key, chains, remap), _frame_chains()
        self.ray0 = np.arange(n, dtype=np.intp)
        self.r_ray = np.empty((2, n), dtype=np.intp)
        self.r_org, self.r_dir = np.empty((2, n, 3)), np.empty((2, n, 3))
        self.r_org32, self.r_dir32 = np.empty((2, n, 3), np.float32), np.empty((2, n, 3), np.float32)
        self.r_before, self.r_atten = np.empty((2, n)), np.empty((2, n))
        self.r_chain = np.empty((2, n), dtype=np.int32)
        self.beam = np.repeat(np.arange(n_beams, dtype=np.int32), n_per_beam)
        self.no_label = np.empty(0, dtype=np.int8)
        self.ones = np.ones(n)  # attenuation of the first generation's legs
        self.zeros_i32 = np.zeros(n, dtype=np.int32)  # their chain (none)
        self.empty_f64 = np.empty(0)
        self.empty_i32 = np.empty(0, dtype=np.int32)


@functools.lru_cache(maxsize=16)
def beam_blocks(n_beams: int, n_blocks: int) -> tuple[tuple[int, int], ...]:
    """``n_blocks`` (at most ``n_beams``) contiguous ranges of beams covering ``0:n_beams``, of
    near-equal sizes."""
    cuts = np.linspace(0, n_beams, min(n_blocks, n_beams) + 1).round().astype(int)
    return tuple((int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a)


def on_both_cores(task, n_tasks: int, pool=None) -> None:
    """Run ``task(0) .. task(n_tasks - 1)`` on this thread and ``pool``'s worker, each thread
    taking the next task when it is free (kernels release the GIL; no order between tasks).

    One hand-off per call: waking a sleeping thread costs more than a small task, so a frame
    gives the other core one long list of work instead of many short ones. The other thread
    has finished before this returns, also when a task raised.
    """
    claimed = itertools.count()

    def drain() -> None:
        while (k := next(claimed)) < n_tasks:  # next() on a count is atomic under the GIL
            task(k)

    if pool is None or n_tasks < 2:
        drain()
        return
    other = pool.submit(drain)
    try:
        drain()
    finally:
        other.result()


def ground_blocks(caster, work: Workspace, fan: RayFan, laws: SurfaceLaws):
    """The fused block pipeline (:class:`~sonarsim.renderer._kernels.GroundBlocks`) for this
    caster, workspace, fan and laws, built on first use and kept on the workspace; None where
    the caster offers no packet loop (embreex, the NumPy caster, a scene with textures, whose
    texels are looked up in Python)."""
    loop = getattr(type(caster), "packet_loop", None)  # on the type: a wrapper forwards attributes
    if loop is None:
        return None
    cached = work.ground_blocks
    if cached is not None and cached[0] is caster and cached[1] is fan and cached[2] is laws and not caster.released:
        return cached[3]
    handle = loop(caster)
    if handle is None:
        return None
    law_by_id, lobe_by_id, _ = _law_args(laws, None)
    blocks = _kernels.GroundBlocks(*handle, work, fan.directions.reshape(-1, 3), fan.weight.reshape(-1),
                                   laws.coefficient, law_by_id, lobe_by_id)
    work.ground_blocks = (caster, fan, laws, blocks)
    return blocks


def render_fast(
    caster,
    sonar: SonarConfig,
    pose: Pose,
    fan: RayFan,
    ground: GroundSpec | None,
    render: RenderSettings,
    laws: SurfaceLaws | np.ndarray,
    reach_m: float,
    multipath: bool,
    work: Workspace,
    pool=None,
    sum_rows: tuple[int, ...] = (),
) -> tuple[np.ndarray, np.ndarray | None]:
    """Render the object, ground, double and triple images (labels 0-3).

    Parameters
    ----------
    caster : RayCaster
    sonar, pose, fan, render : the sonar's intrinsics, its pose (world frame), its rays (sonar
        frame), the settings
    ground : GroundSpec or None
    laws : SurfaceLaws or (n_objects + 2,) float64 ndarray
        Backscatter laws indexed by surface id + 1 (an array: Lambertian albedo).
    reach_m : float
        Longest path followed, metres.
    multipath : bool
        Form the ground echoes.
    work : Workspace
        Receives the per-ray results (``d64``: world directions; ``dist``, ``sid``,
        ``intensity``: D_f, labels, I_f).
    pool : concurrent.futures.ThreadPoolExecutor with one worker, optional
        The other core: it takes blocks of beams as this one does.
    sum_rows : tuple of int
        The rows whose sum is the frame's total (``components.total_rows``); the fused blocks
        add them up while a block's columns are in cache, where nothing lands there later.

    Returns
    -------
    stack : (4, n_range_bins, n_beams) float32 ndarray
        The images. float32 sums lose nothing here that the float32 result would keep.
    total : (n_range_bins, n_beams) float32 ndarray or None
        The sum of ``sum_rows`` (as ``components._sum_rows`` adds them), or None: not formed.

    Notes
    -----
    The beams are cut into blocks, and each block goes whole through the pipeline on one
    thread: rotate its rays, cast them, find the closest surfaces, splat the direct image, cast
    the reflected rays, form the echo paths, splat the echoes. A block writes only its own
    rays' entries and (with ``double_beam`` ``paper``) only its own beams' image columns, in ray
    order, so the image is the same bits whichever thread took which block, and the same as on
    one thread. The blocks that write into other beams' columns (``split``: the double bounce
    also lands in the beam of A) and ``double_line_of_sight`` (a cast after all paths) are done
    after the blocks, on this thread.
    """
    laws = SurfaceLaws.of(laws)
    albedo_by_id = laws.coefficient
    origin = pose.translation
    ox, oy, oz = float(origin[0]), float(origin[1]), float(origin[2])
    rotation = np.ascontiguousarray(pose.rotation)
    directions = fan.directions.reshape(-1, 3)
    weight = fan.weight.reshape(-1)
    has_ground = ground is not None
    n_beams, n_az, n_el = fan.shape
    geometry = (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins, sonar.n_beams)
    spread = render.range_splat
    half_el = sonar.elevation_fov_deg / 2.0
    edges = np.ascontiguousarray(sonar.beam_edges_deg)
    own_beam = render.double_beam == "paper"
    pipelined = not render.double_line_of_sight  # that option casts again after all paths
    # The echo images go with their block where they land in the block's own beams; otherwise
    # (``split``, ``double_line_of_sight``) after every block, on this thread.
    echoes_in_blocks = own_beam and pipelined
    w = work
    fused = ground_blocks(caster, work, fan, laws)
    shape = (4, sonar.n_range_bins, sonar.n_beams)
    total = None
    if fused is not None:
        out = np.empty(shape, dtype=np.float32)  # each block zeroes its own columns
        if sum_rows and echoes_in_blocks:
            total = np.empty(shape[1:], dtype=np.float32)
    else:
        out = np.zeros(shape, dtype=np.float32)
    flat_out = out.reshape(-1)

    def splat(points, normals, sid, set1, set2=None, columns=(0, -1)):
        """Run the splat kernel: ``set = (distance, energy, beams, label array, label)``."""
        d2, e2, b2, _, l2 = set2 if set2 is not None else (w.empty_f64, w.empty_f64, w.empty_i32, None, -1)
        _kernels.splat(points, normals, sid, *set1, d2, e2, b2, l2, spread, n_el, *geometry, flat_out, *columns)

    mirror = (w.v_point, w.v_normal, w.v_sid)
    triple = (w.tri_dist, w.tri_energy, w.beam, w.no_label, 3)

    def echoes(columns):
        """The echo images of ray ``columns``."""
        if own_beam:
            splat(*mirror, triple, (w.r23, w.e23, w.beam, None, 2), columns=columns)
            return
        half = 0.5 * w.e23
        splat(*mirror, triple, (w.r23, half, w.beam, None, 2), columns=columns)
        splat(*mirror, (w.r23, half, w.beam_a, w.no_label, 2), columns=columns)  # case 2: beam of A

    blocks = beam_blocks(n_beams, 1 if pool is None else BLOCKS_PER_CORE * 2)
    echo_rays = [0] * len(blocks)

    if fused is not None:
        fused.frame(flat_out, rotation, ox, oy, oz, has_ground, ground.height_m if has_ground else 0.0, reach_m,
                    render.tvg, multipath, ground.specular if has_ground else 0.0, spread, echoes_in_blocks, n_az,
                    n_el, *geometry[:2], *geometry[2:], sonar.range_max_m, half_el, edges,
                    None if total is None else total.reshape(-1), tuple(sum_rows) if total is not None else ())

        def block(k: int) -> None:
            echo_rays[k] = fused.block(*blocks[k])
    else:
        def block(k: int) -> None:
            c0, c1 = blocks[k][0] * n_az, blocks[k][1] * n_az  # ray columns
            a, b = c0 * n_el, c1 * n_el  # rays
            _kernels.rotate(directions[a:b], rotation, ox, oy, oz, w.d64[a:b], w.d32[a:b], w.o32[a:b])
            hits = caster.intersect(w.o32[a:b], w.d32[a:b], reach_m, threads=1)
            n_g, t_min = _kernels.primary(
                hits.distance, hits.mesh_id, hits.normal, w.d64[a:b], ox, oy, oz,
                has_ground, ground.height_m if has_ground else 0.0, reach_m, albedo_by_id, weight[a:b], render.tvg,
                w.dist[a:b], w.sid[a:b], w.point[a:b], w.normal[a:b], w.intensity[a:b], w.label[a:b],
                w.g_index[a:b], w.g_t[a:b], w.g_start[a:b], w.g_dir[a:b], *_law_args(laws, hits), offset=a,
            )
            splat(w.point, w.normal, w.sid, (w.dist, w.intensity, w.beam, w.label, 0), columns=(c0, c1))
            if not (multipath and n_g):
                return
            echo_rays[k] = n_g
            _kernels.clear_mirror(a, b, w.tri_dist, w.tri_energy, w.r23, w.e23)
            g = slice(a, a + n_g)
            # The block's nearest ground hit bounds its reflected rays (a hit further than the
            # reach allows is dropped ray by ray in mirror_paths anyway: the same answer).
            hits2 = caster.intersect(w.g_start[g], w.g_dir[g], float(reach_m - t_min), threads=1)
            _kernels.mirror_paths(
                w.g_index[g], w.g_t[g], w.g_start[g], hits2.distance, hits2.mesh_id, hits2.normal,
                w.d64, w.point, ox, oy, oz, rotation, edges, half_el, sonar.range_min_m, sonar.range_max_m,
                reach_m, albedo_by_id, weight, render.tvg, ground.specular,
                w.tri_dist, w.tri_energy, w.v_point, w.v_normal, w.v_sid,
                w.r23, w.e23, w.beam_a, *_law_args(laws, hits2),
            )
            if echoes_in_blocks:
                echoes((c0, c1))

    on_both_cores(block, len(blocks), pool)
    if not any(echo_rays) or echoes_in_blocks:
        return out, total
    # Blocks without echo rays skipped clearing their share of the mirror outputs.
    for k, (b0, b1) in enumerate(blocks):
        if not echo_rays[k]:
            _kernels.clear_mirror(b0 * n_az * n_el, b1 * n_az * n_el, w.tri_dist, w.tri_energy, w.r23, w.e23)
    if not pipelined:
        _drop_hidden(caster, pose, ground.height_m, work)
    echoes((0, -1))
    return out, None


def _drop_hidden(caster, pose: Pose, ground_height_m: float, work: Workspace) -> None:
    """``double_line_of_sight``: no double bounce from an A that the sonar (at ``pose``) cannot see."""
    cand = np.flatnonzero(work.e23 > 0)
    if not cand.size:
        return
    origin = pose.translation
    a_point = work.v_point[cand].copy()  # A', mirrored back across the ground: A
    a_point[:, 2] = 2.0 * ground_height_m - a_point[:, 2]
    to_a = a_point - origin
    oa = np.linalg.norm(to_a, axis=1)
    hit = caster.intersect(origin, to_a / oa[:, None], float(oa.max()) + 1.0)
    # Visible when the first thing on the way is A itself (to float32 precision).
    hidden = hit.distance < oa - 1e-3 * np.maximum(oa, 1.0)
    work.e23[cand[hidden]] = 0.0
    work.r23[cand[hidden]] = np.inf


# Blocks of beams a frame is cut into, whatever the number of threads (the image does not
# depend on the cut; a fixed cut keeps that plain). One per core measured fastest on the demo
# and the six-plane tank (each block's columns are strided in the image, and a block's fixed
# costs -- its calls, its share of the casting's packets -- outweigh finer balancing).
N_BLOCKS = 2

# Rows of each block's own chain table at first (it grows on overflow).
CHAIN_CAPACITY = 256


class FrameLegs:
    """The receive legs of a frame, dense over the fan's ``n`` rays, generation by generation
    (written by :class:`~sonarsim.renderer._kernels.PathBlocks`; see :class:`~sonarsim.paths.engine.Leg`).

    Attributes
    ----------
    dist, intensity, atten : (G, n) float64 ndarrays
    sid, chain, key : (G, n) int32 ndarrays
    point, normal : (G, n, 3) float64 ndarrays
    live : (G, n) intp ndarray
        Block k's live rays of generation g at ``live[g, a:a + n_live[k, g]]`` (a: its first ray).
    n_live, n_cast : (n_blocks, G) intp ndarrays
        Live rays, and rays cast, per block and generation.
    """

    def __init__(self, n_gen: int, n: int, n_blocks: int) -> None:
        self.dist, self.intensity, self.atten = np.empty((n_gen, n)), np.empty((n_gen, n)), np.empty((n_gen, n))
        self.sid, self.chain = np.empty((n_gen, n), np.int32), np.empty((n_gen, n), np.int32)
        self.key = np.empty((n_gen, n), np.int32)
        self.point, self.normal = np.empty((n_gen, n, 3)), np.empty((n_gen, n, 3))
        self.live = np.empty((n_gen, n), np.intp)
        self.n_live, self.n_cast = np.zeros((n_blocks, n_gen), np.intp), np.zeros((n_blocks, n_gen), np.intp)

    def legs(self, work: Workspace) -> list[Leg]:
        """The generations that cast any ray, as :class:`Leg` views."""
        out = []
        for g in range(self.dist.shape[0]):
            if g and not self.n_cast[:, g].any():
                break
            first = g == 0
            out.append(Leg(g, self.dist[g], self.sid[g], self.point[g], self.normal[g], self.intensity[g],
                           work.ones if first else self.atten[g], work.zeros_i32 if first else self.chain[g],
                           keys=self.sid[g] if first else self.key[g]))
        return out


def probe_kernel():
    """``_kernels.probe_chains``, the compiled twin of :func:`sonarsim.paths.engine.probe_chains`' loop."""
    return _kernels.probe_chains


def packet_loop(caster) -> tuple | None:
    """The caster's packet loop for the compiled blocks (``Embree4Caster.packet_loop``), None
    where it has none (embreex, the NumPy caster) or no triangles."""
    loop = getattr(type(caster), "packet_loop", None)  # on the type: a wrapper forwards attributes
    return loop(caster) if loop is not None else None


def path_engine(caster, work: Workspace, fan: RayFan, laws: SurfaceLaws, planes):
    """The block engine (:class:`~sonarsim.renderer._kernels.PathBlocks`) for this caster,
    workspace, fan, laws and planes, built on first use and kept on the workspace; it casts
    through the caster's packet loop where it lends one (the Embree 4 binding), else Python
    casts between its stages (embreex, the NumPy caster, textures)."""
    handle = packet_loop(caster)
    cached = work.engine
    if (cached is not None and cached[0] is caster and cached[1] is fan and cached[2] is laws
            and cached[3] is planes and cached[4].fused == (handle is not None)):
        return cached[4]
    law_by_id, lobe_by_id, _ = _law_args(laws, None)
    n_blocks = min(N_BLOCKS, fan.shape[0])
    engine = _kernels.PathBlocks(work, fan.directions.reshape(-1, 3), fan.weight.reshape(-1), laws.coefficient,
                                 law_by_id, lobe_by_id, planes.normal, planes.offset, planes.specular, n_blocks,
                                 CHAIN_CAPACITY, *(handle or ()))
    work.engine = (caster, fan, laws, planes, engine)
    return engine


def _frame_chains(table, engine, work: Workspace):
    """The frame's chains -- the probes' (in ``table``) and every block's -- numbered
    canonically, and each block's local ids to those: ``(table, remap)``, remap (n_blocks,
    capacity) int32. Kept on ``work`` while the frames meet the same chains in every block."""
    children, n_local = engine.chain_tables()
    key = (tuple(table.chains), children[:, : int(n_local.max())].tobytes(), n_local.tobytes(), children.shape)
    cached = work.chains
    if cached is not None and cached[0] is table.planes and cached[1] == key:
        chains, remap = cached[2], cached[3]
        canonical = ChainTable(table.planes, table.origin, table.max_length)
        for c in chains:
            canonical.add(c)
        return canonical, remap
    local = [table.local_chains(children[k], int(n_local[k])) for k in range(len(n_local))]
    for chains in local:
        for c in chains:
            table.add(c)
    canonical, _ = table.canonical()
    remap = np.zeros(children.shape[:2], np.int32)
    for k, chains in enumerate(local):
        remap[k, : len(chains)] = [canonical.add(c) for c in chains]
    work.chains = (table.planes, key, list(canonical.chains), remap)
    return canonical, remap


def _option_table(table, n_gen: int, max_order: int, double_beam: str) -> tuple:
    """The frame's transmit options, as :func:`sonarsim.paths.engine.form_paths` tries them and
    in its order: ``(gen, tx, same, label, length, unfold, chain_planes, specular)`` arrays of
    ``PathBlocks.options``. Depends on the chains, not on the pose (see :func:`_options`)."""
    from ..paths.engine import LABEL_PLANE, SAME, label_of_order, transmit_options

    rows = []
    for g in range(n_gen):
        options = transmit_options(table, g, max_order)
        if double_beam != "separate":
            options = [tx for tx in options if tx == SAME or table.length(tx) <= g]
        for tx in options:
            same = tx == SAME
            c = 0 if same else tx
            order = 2 * g + 1 if same else g + table.length(c) + 1
            rows.append((g, c, same, label_of_order(order) if order > 1 else LABEL_PLANE))
    n_opt = len(rows)
    length = np.array([0 if r[2] else table.length(r[1]) for r in rows], np.int32)
    longest = int(length.max(initial=0))
    unfold = np.zeros((n_opt, 3, 4))
    chain_planes = np.zeros((n_opt, max(longest, 1)), np.int32)
    specular = np.ones(n_opt)
    for o, (g, c, sm, _) in enumerate(rows):
        unfold[o] = table.unfold(c)
        if not sm:
            chain_planes[o, : length[o]] = table.chains[c]
            specular[o] = table.specular(c)
    columns = [np.array([r[k] for r in rows], np.int32) for k in range(4)]
    return (*columns, length, unfold, chain_planes, specular)


def _options(table, n_gen: int, max_order: int, double_beam: str, n_live: np.ndarray, work: Workspace):
    """The arrays of ``PathBlocks.options`` (see :func:`_option_table`, kept on ``work`` while
    the frames meet the same chains), the sonar's images along each option's chain, and the
    path buffer's offsets and size (option-major; a block's capacity for an option is its
    generation's live rays)."""
    key = (table.planes, tuple(table.chains), n_gen, max_order, double_beam)
    cached = work.options
    if cached is None or cached[0] is not key[0] or cached[1:4] != key[1:4] or cached[4] != double_beam:
        cached = work.options = (*key, _option_table(table, n_gen, max_order, double_beam))
    gen, tx, same, label, length, unfold, chain_planes, specular = cached[5]
    sources = np.zeros((len(gen), chain_planes.shape[1] + 1, 3))
    for o in np.flatnonzero(same == 0):
        sources[o, : length[o] + 1] = table.sources(int(tx[o]))
    capacity = n_live[:, gen].T.reshape(-1)  # option-major
    offset = np.zeros(len(capacity), np.intp)
    np.cumsum(capacity[:-1], out=offset[1:])
    return (gen, tx, same, label, length, unfold, sources, chain_planes, specular), offset, int(capacity.sum())


class PathBuffer:
    """The paths of a frame as the blocks wrote them (see ``docs/path-buffer.md``): fields of
    one path per entry, option-major, each option's paths block after block in ray order.

    Attributes
    ----------
    gen, tx, same : (n_options,) int32 ndarrays
        Each transmit option's receive generation, transmit chain and whether the transmit leg
        is the receive leg reversed.
    offset, count : (n_options * n_blocks,) intp ndarrays
        Where option o of block k starts (``o * n_blocks + k``) and how many paths it holds.
    ray, distance, energy, beam, beam_tx, label : ndarrays
        Per path: the fan ray it arrives along, half its length (m), its energy, its beam of
        arrival, its transmit beam, its image row.
    """

    def __init__(self, options: tuple, offset: np.ndarray, size: int, n_blocks: int) -> None:
        self.gen, self.tx, self.same = options[0], options[1], options[2]
        self.n_blocks = n_blocks
        self.offset, self.count = offset, np.zeros(len(offset), np.intp)
        self.ray, self.distance, self.energy = np.empty(size, np.intp), np.empty(size), np.empty(size)
        self.beam, self.beam_tx = np.empty(size, np.int32), np.empty(size, np.int32)
        self.label = np.empty(size, np.int8)

    def sets(self, double_beam: str = "paper") -> list:
        """The frame's :class:`~sonarsim.paths.engine.PathSet` list, as ``form_paths`` forms it."""
        from ..paths.engine import SAME, PathSet

        out = []
        K = self.n_blocks
        for o in range(len(self.gen)):
            parts = [slice(self.offset[o * K + k], self.offset[o * K + k] + self.count[o * K + k]) for k in range(K)]
            parts = [p for p in parts if p.stop > p.start]
            if not parts:
                continue

            def cat(a):
                return a[parts[0]].copy() if len(parts) == 1 else np.concatenate([a[p] for p in parts])

            g, tx = int(self.gen[o]), SAME if self.same[o] else int(self.tx[o])
            ray, dist, energy, beam, label = (cat(self.ray), cat(self.distance), cat(self.energy), cat(self.beam),
                                              cat(self.label))
            if double_beam == "split" and tx != SAME:
                out.append(PathSet(g, tx, ray, dist, 0.5 * energy, beam, label))
                out.append(PathSet(g, tx, ray, dist, 0.5 * energy, cat(self.beam_tx), label))
            else:
                out.append(PathSet(g, tx, ray, dist, energy, beam, label))
        return out


def render_paths(caster, planes, active, sonar: SonarConfig, pose: Pose, fan: RayFan, work: Workspace,
                 laws: SurfaceLaws, render: RenderSettings, reach_m: float, n_generations: int, table,
                 n_surfaces: int, stack: np.ndarray, pool=None, occlusion=None, textures: tuple = (),
                 sum_rows: tuple[int, ...] = ()):
    """The whole compiled frame in blocks of beams (:class:`~sonarsim.renderer._kernels.PathBlocks`):
    receive legs, paths, and the image stack.

    Each block of beams goes whole through rotate, cast, the receive legs of every generation
    (casting the reflected rays), on one thread, the two cores taking blocks in turn; then,
    once the frame's chains are known and numbered canonically (with ``table``'s probes), each
    block's paths are formed into the path buffer and splatted into its own beams' columns
    (``double_beam: split`` and ``double_line_of_sight`` splat after every block, on this
    thread: they write into other beams or cast once more).

    Parameters
    ----------
    table : ChainTable
        The chains the aperture's edges follow (``probe_chains``).
    stack : (rows, n_range_bins, n_beams) float32 ndarray
        Receives the image stack (its content is overwritten).
    sum_rows : tuple of int
        Stack rows whose sum is the frame's total, added by the blocks where they splat.

    Returns
    -------
    legs : list of Leg
    sets : callable
        Forms the frame's path sets from the path buffer (for labels and signatures).
    table : ChainTable
        The frame's chains, canonically numbered (the ids of ``sets``).
    total : (n_range_bins, n_beams) float32 ndarray or None
        The sum of ``sum_rows`` (as ``components._sum_rows`` adds them), or None: not formed.
    """
    laws = SurfaceLaws.of(laws)
    engine = path_engine(caster, work, fan, laws, planes)
    n_beams = sonar.n_beams
    n_blocks = min(N_BLOCKS, n_beams)
    blocks = beam_blocks(n_beams, n_blocks)
    per_beam = fan.n_rays // n_beams
    legs_out = FrameLegs(n_generations, fan.n_rays, n_blocks)
    active8 = np.ascontiguousarray(active, dtype=np.uint8)
    in_blocks = render.double_beam != "split" and occlusion is None  # each block splats its own beams
    engine.frame(legs_out, active8, np.ascontiguousarray(pose.rotation), np.asarray(pose.translation, float),
                 reach_m, render.tvg, n_generations, fan.shape[2], sonar.range_min_m, sonar.range_resolution_m,
                 sonar.n_range_bins, n_beams, sonar.range_max_m, sonar.elevation_fov_deg / 2.0,
                 np.ascontiguousarray(sonar.beam_edges_deg), render.range_splat, render.double_beam == "separate",
                 n_surfaces, stack.reshape(-1) if in_blocks else None)
    textures = textures if any(f is not None for f in textures) else ()
    fused = engine.fused and not textures
    w = work

    def staged(k: int) -> bool:
        """Block k with Python casting between the stages (the same code as the fused block)."""
        b0, b1 = blocks[k]
        a, b = b0 * per_beam, b1 * per_beam
        buffer, m, limit = engine.begin(k, b0, b1)
        for g in range(n_generations):
            if not m:
                break
            if buffer < 0:
                o32, d32 = w.o32[a:a + m], w.d32[a:a + m]
            else:
                o32, d32 = w.r_org32[buffer, a:a + m], w.r_dir32[buffer, a:a + m]
            hits = caster.intersect(o32, d32, float(limit), threads=1)
            w.h_dist[a:a + m], w.h_mesh[a:a + m], w.h_normal[a:a + m] = hits.distance, hits.mesh_id, hits.normal
            if not engine.step(k, b0, b1, g, *_law_args(laws, hits)):
                return False
            if textures:
                scale_by_texture(legs_out.intensity[g, a:b], legs_out.sid[g, a:b], legs_out.point[g, a:b], textures)
            buffer, m, limit = engine.pending(k)
        return True

    def trace(k: int) -> None:
        ok[k] = engine.trace(k, *blocks[k]) if fused else staged(k)

    while True:
        ok = [True] * len(blocks)
        on_both_cores(trace, len(blocks), pool)
        if all(ok):
            break
        engine.grow(4 * engine.chain_tables()[0].shape[1])  # a block met more chains than its table holds: again, larger
    table, remap = _frame_chains(table, engine, work)
    options, offset, size = _options(table, n_generations, render.max_order, render.double_beam, legs_out.n_live,
                                     work)
    buffer = PathBuffer(options, offset, size, len(blocks))
    total = np.empty(stack.shape[1] * stack.shape[2], np.float32) if in_blocks and sum_rows else None
    rank = np.arange(len(table), dtype=np.int32)  # canonical ids are ranks (ChainTable.key)
    engine.options(remap, rank, *options, buffer.offset, buffer.count, buffer.ray, buffer.distance, buffer.energy,
                   buffer.beam, buffer.beam_tx, buffer.label, in_blocks, total, tuple(sum_rows))
    on_both_cores(lambda k: engine.paths(k, *blocks[k]), len(blocks), pool)
    legs = legs_out.legs(work)
    sets = functools.partial(buffer.sets, render.double_beam)
    if not in_blocks:
        stack[:] = 0.0
        frame_sets = buffer.sets(render.double_beam)
        if occlusion is not None:
            frame_sets = occlusion(frame_sets, legs, table=table)
        splat_paths(frame_sets, legs, n_surfaces, fan.shape[2], (sonar.range_min_m, sonar.range_resolution_m,
                                                                 sonar.n_range_bins, n_beams), render.range_splat,
                    stack)
        sets = functools.partial(lambda s: s, frame_sets)
    return legs, sets, table, None if total is None else total.reshape(stack.shape[1:])


def option_paths(live, leg, same, tx, unfold, sources, tx_planes, tx_specular, rank, separate, label, n_planes,
                 rays_per_beam, view, planes, active):
    """``_kernels.path_events`` with the arguments and results of its twin
    :func:`sonarsim.paths.engine.option_paths`."""
    m = len(live)
    buf = (np.empty(m, np.intp), np.empty(m), np.empty(m), np.empty(m, np.int32), np.empty(m, np.int32),
           np.empty(m, np.int8))
    k = _kernels.path_events(
        live, leg.distance, leg.sid, leg.point, leg.intensity, leg.atten, leg.chain, same, tx, unfold, sources,
        tx_planes, tx_specular, rank, separate, label, n_planes, rays_per_beam, *view.origin, view.rotation,
        view.beam_edges_deg, view.half_elevation_deg, view.range_min_m, view.range_max_m, planes.normal,
        planes.offset, np.ascontiguousarray(active, dtype=np.uint8), *buf,
    )
    return tuple(a[:k] for a in buf)


def form_paths(legs, table, view, active, n_planes: int, rays_per_beam: int, max_order: int,
               double_beam: str, only_same: bool = False, skip_first_same: bool = False) -> list:
    """Every path of the frame with the compiled kernel: :func:`sonarsim.paths.engine.form_paths`
    with :func:`option_paths` (``_kernels.path_events``) for each transmit option."""
    from ..paths.engine import form_paths as form

    return form(legs, table, view, active, n_planes, rays_per_beam, max_order, double_beam, only_same=only_same,
                skip_first_same=skip_first_same, paths_of_option=option_paths)


def splat_paths(sets, legs, n_surfaces: int, n_elevation: int, geometry: tuple, spread: bool, out: np.ndarray) -> None:
    """Accumulate path sets into the float32 image stack ``out`` (labels x bins x beams)."""
    flat = out.reshape(-1)
    keys = {}
    for s in sets:
        leg = legs[s.gen]
        if s.gen not in keys:
            keys[s.gen] = leg.key(n_surfaces)
        _kernels.splat_events(leg.point, leg.normal, keys[s.gen], s.ray, s.distance, s.energy, s.beam, s.label,
                              1.0, spread, n_elevation, *geometry, flat)



def frame_truth(sets, legs, n_surfaces: int, lut: np.ndarray, elevation_deg: np.ndarray, n_objects: int,
                geometry: tuple, rows: tuple[int, int], max_order: int, bounces: tuple[int, ...], spread: bool,
                components: bool) -> tuple:
    """The label maps and points of a frame with ``_kernels.LabelMaps``: one pass per path set,
    then one over the reached cells (twin: ``sonarsim.renderer.ground_truth._frame_truth``,
    which takes the same arguments: dense stacks and ``dominant``).

    Parameters
    ----------
    sets, legs : the frame's path sets and receive legs
    n_surfaces : int
        Planes + objects (for :meth:`Leg.key`).
    lut : (n_surfaces,) int32 ndarray
        Label id of each surface id.
    elevation_deg : (n_elevation,) float64 ndarray
        Arrival elevation of each row of the fan, degrees.
    n_objects : int
        Ids below it are objects, the others planes.
    geometry : (range_min_m, range_resolution_m, n_range_bins, n_beams)
        The image's grid.
    rows : (int, int)
        ``[first, end)`` of the range bins where paths may deposit (the lit rows).
    max_order : int
    bounces : tuple of int
        Orders of the total.
    spread : bool
    components : bool
        Also form a map per order (and the first order's objects and planes).

    Returns
    -------
    orders : (max_order, n_range_bins, n_beams) int32 ndarray
        Dominant id per order (order 1: objects and planes together); empty without components.
    objects, planes : (n_range_bins, n_beams) int32 ndarrays or None
        The first order's dominant object and dominant plane (None without components).
    total : (n_range_bins, n_beams) int32 ndarray
    elevation : (3, n_range_bins, n_beams) float32 ndarray
        Mean, least and greatest arrival elevation of the total's paths, degrees, NaN none.
    boxes : (n_ids, 4) int32 ndarray
        Boxes of the ids in ``total`` (see :func:`sonarsim.image.labels.boxes_of`).
    points : tuple of (n, 3) float32, (n,) int32, (n,) int8 and (n, 2) int32 ndarrays
        World position, id, component row and (bin, beam) of each path that lands in the image.
    """
    range_min_m, dr, n_r, n_b = geometry
    r0, r1 = rows
    n_w = max(r1 - r0, 0)
    n_ids = len(lut)
    n_maps = max_order + 1 if components else 1  # the orders, then the total
    # Outputs filled once; the kernel writes only the cells that paths reach.
    instance = np.full((n_maps, n_r, n_b), -1, np.int32)
    split = np.full((2, n_r if components else 0, n_b), -1, np.int32)
    elevation = np.full((3, n_r, n_b), np.nan, np.float32)
    n_paths = sum(len(s.ray) for s in sets)
    points = (np.empty((n_paths, 3), np.float32), np.empty(n_paths, np.int32), np.empty(n_paths, np.int8),
              np.empty((n_paths, 2), np.int32))
    # Scratch left uninitialised: the kernel writes a cell's entries when it first reaches it,
    # and a row of the table only for a cell where a second id arrives (so none is filled).
    truth = _kernels.LabelMaps(
        instance[:, r0:r1], np.empty((n_maps, n_w, n_b), np.float32), np.empty((n_maps, n_w * n_b, 2), np.int32),
        np.zeros(n_maps, np.intp), np.empty((n_maps * n_w * n_b, n_ids), np.float32), np.empty((n_w, n_b, 2)),
        elevation[1, r0:r1], elevation[2, r0:r1], np.ascontiguousarray(lut, np.int32),
        np.ascontiguousarray(elevation_deg, np.float64), spread, range_min_m + r0 * dr, dr, range_min_m, n_r, *points)
    keys = {}
    for s in sets:
        if not len(s.ray):
            continue
        leg = legs[s.gen]
        if s.gen not in keys:
            keys[s.gen] = leg.key(n_surfaces)
        order = max(int(s.label[0]), 1)  # labels 0 (objects) and 1 (planes) are order 1
        truth.add(leg.point, leg.normal, keys[s.gen], leg.sid, s.ray, s.distance, s.energy, s.beam, s.label,
                  order - 1 if components else -1, order in bounces)
    boxes = np.full((n_ids, 4), -1, np.int32)
    truth.finish(split[0, r0:r1], split[1, r0:r1], n_objects, elevation[0, r0:r1], boxes, r0)
    n = truth.n_points
    objects, planes = (split[0], split[1]) if components else (None, None)
    return instance[:-1], objects, planes, instance[-1], elevation, boxes, tuple(p[:n] for p in points)


def lit_rows(stack: np.ndarray) -> tuple[int, int]:
    """``_kernels.lit_rows`` (float32 C-contiguous stacks) with the result of its twin
    :func:`sonarsim.renderer.ground_truth.lit_rows`."""
    return _kernels.lit_rows(stack)


def id_extents(ids: np.ndarray, extents: np.ndarray, n_ids: int) -> np.ndarray:
    """``_kernels.id_extents``: per id ``0 .. n_ids - 1``, the union of the inclusive boxes
    ``extents`` (n, 4) of the cells whose id ``ids`` (n,) it is; -1 rows for absent ids."""
    out = np.full((n_ids, 4), -1, np.int32)
    _kernels.id_extents(np.ascontiguousarray(ids, np.int32).reshape(-1), np.ascontiguousarray(extents, np.int32),
                        out)
    return out
