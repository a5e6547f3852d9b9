"""The path engine with its per-ray loops compiled (:mod:`sonarsim.renderer._kernels`).

:func:`render_paths` forms every frame, over any set of planes and any ``max_order``: the
beams are cut into blocks, and each block goes whole through rotate, cast, the receive legs
of every generation with their reflected casts (``_kernels.PathBlocks``, casting through the
Embree 4 binding's packet loop where it loads, else Python casts between the same stages),
then through its paths and their splatting, the two cores taking blocks in turn. The NumPy
twin of each kernel is in :mod:`sonarsim.paths.engine`; ``docs/path-buffer.md`` describes the
arrays that pass between the search and image formation.
"""

from __future__ import annotations

import collections
import functools
import itertools
import sys
import threading
import time
import weakref
from collections.abc import Sequence
from concurrent.futures import Executor, Future
from concurrent.futures import TimeoutError as FuturesTimeout

import numpy as np

from ..paths.engine import PAIR_MODES, Leg, glint_sets
from ..core.radiometry import SurfaceLaws

from ..core.rays import RayFan
from ..config.scene import RenderSettings
from ..config.sonar import SonarConfig
from ..scene.floor_texture import scale_by_texture
from ..core.memory import memory_budget, require, require_time

try:
    from . import _kernels
except ImportError:  # not built (e.g. a source tree used without installing)
    _kernels = None

AVAILABLE = _kernels is not None

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
        # The fan at the pose (float64, and float32 for the caster) and the first rays' origins.
        self.d64 = np.empty((n, 3))
        self.d32 = np.empty((n, 3), dtype=np.float32)
        self.o32 = np.empty((n, 3), dtype=np.float32)
        # The casts' hits (each block's rays, every generation, in the block's rows).
        self.h_dist = np.empty(n, dtype=np.float32)
        self.h_mesh = np.empty(n, dtype=np.int32)
        self.h_normal = np.empty((n, 3), dtype=np.float32)
        self.h_prim = np.empty(n, dtype=np.int32)  # the triangle hit and its barycentric (u, v)
        self.h_uv = np.empty((n, 2), dtype=np.float32)
        # The rays of each block's current and next generation (two buffers, a block's rows at
        # its own rays).
        self.ray0 = np.arange(n, dtype=np.intp)
        self.r_ray = np.empty((2, n), dtype=np.intp)
        self.r_org, self.r_dir = np.empty((2, n, 3)), np.empty((2, n, 3))
        self.r_org32, self.r_dir32 = np.empty((2, n, 3), np.float32), np.empty((2, n, 3), np.float32)
        self.r_before, self.r_atten = np.empty((2, n)), np.empty((2, n))
        self.r_chain = np.empty((2, n), dtype=np.int32)
        self.ones = np.ones(n)  # attenuation of the first generation's legs
        self.zeros_i32 = np.zeros(n, dtype=np.int32)  # their chain (none)
        self.engine: tuple | None = None  # (caster, fan, laws, planes, PathBlocks, n_blocks, facets), path_engine()
        self.chains: tuple | None = None  # (planes, key, canonical table, remap), _frame_chains()
        self.options: tuple | None = None  # (planes, chains, n_gen, max_order, double_beam, arrays, sources)
        self.legs_pool, self.paths_pool = ArrayPool(), ArrayPool()  # the frames' legs and path buffers
        self.cut: tuple | None = None  # the beams' cut into blocks (blocks(), balance())
        self._spent: list = []  # the blocks' times of the last frames at the cut
        self.labels_scratch = LabelScratch()

    def blocks(self, n_beams: int, n_blocks: int) -> tuple[tuple[int, int], ...]:
        """The cut of the beams into blocks the next frame uses: even (:func:`beam_blocks`) at
        first, then as :meth:`balance` moves it."""
        cut = self.cut
        if cut is None or len(cut) != min(n_blocks, n_beams) or cut[-1][1] != n_beams:
            cut = self.cut = beam_blocks(n_beams, n_blocks)
            self._spent = []
        return cut

    def balance(self, blocks: tuple[tuple[int, int], ...], seconds: Sequence[float]) -> None:
        """Move the cut towards blocks of equal work, from the time each block of a frame cut
        as ``blocks`` took (its tracing and its paths): where the multipath gathers on one side
        of the fan (a mirror there), the even cut leaves one core waiting for the other. The
        image does not depend on the cut (tested); only its speed does.

        The work is taken as spread evenly over each block's beams, each block's time as the
        median of :data:`BALANCE_FRAMES` frames at the cut; the cut moves to equal shares where
        that promises the slowest block :data:`BALANCE_GAIN` less (a frame delayed by the
        machine's load does not move it, nor round-off in the model move it to and fro)."""
        spent = np.asarray(seconds, dtype=float)
        if blocks is not self.cut or len(blocks) < 2 or not np.all(spent > 0.0):
            return
        self._spent.append(spent)
        if len(self._spent) < BALANCE_FRAMES:
            return
        spent = np.median(self._spent, axis=0)
        self._spent.clear()
        edges = np.array([b0 for b0, _ in blocks] + [blocks[-1][1]], dtype=float)
        work = np.concatenate([[0.0], np.cumsum(spent)])
        new = np.round(np.interp(np.linspace(0.0, work[-1], len(blocks) + 1), work, edges)).astype(int)
        new[0], new[-1] = 0, int(edges[-1])
        for j in range(1, len(new) - 1):  # a beam at least in every block
            new[j] = min(max(new[j], new[j - 1] + 1), int(edges[-1]) - (len(new) - 1 - j))
        if np.diff(np.interp(new, edges, work)).max() < (1.0 - BALANCE_GAIN) * spent.max():
            self.cut = tuple((int(a), int(b)) for a, b in zip(new[:-1], new[1:]))


# A frame's cut moves only where the slowest block would take this much less, judged on the
# median times of this many frames at the cut (Workspace.balance).
BALANCE_GAIN = 0.1
BALANCE_FRAMES = 4


@functools.lru_cache(maxsize=16)  # a sonar's: the same every frame
def beam_blocks(n_beams: int, n_blocks: int) -> tuple[tuple[int, int], ...]:
    """``n_blocks`` (at most ``n_beams``) contiguous ranges of beams covering ``0:n_beams``, of
    near-equal sizes."""
    cuts = np.linspace(0, n_beams, min(n_blocks, n_beams) + 1).round().astype(int)
    return tuple((int(a), int(b)) for a, b in zip(cuts[:-1], cuts[1:]) if b > a)


class SecondCore(Executor):
    """The compiled frame's second core: one worker thread running its tasks in order (an
    :class:`~concurrent.futures.Executor`, as ``ThreadPoolExecutor(1)`` is).

    A frame hands it work twice (its two phases, :func:`on_both_cores`), a few hundred
    microseconds apart, and a thread that sleeps -- on a lock, a condition or the GIL -- takes
    50-100 us to wake on the machines this was measured on (virtual ones). So neither thread
    of a frame sleeps while the machine is idle: after each task the worker watches for the
    next one without the GIL (``_kernels.watch_flag``: a load and a pause instruction in a
    loop, offering its core between short runs) for :attr:`SPIN_S` before it sleeps, as
    OpenMP runtimes do; the frame's thread watches for the worker's end for
    :attr:`JOIN_SPIN_S` (:meth:`join`); and in :meth:`hand_off` each thread raises the flag
    the other watches only once it has let go of the GIL, so that the other takes the GIL
    without waiting. On a busy machine both fall back to sleeping. An idle simulator's worker
    sleeps. The thread stops when the executor is shut down or collected.
    """

    #: Seconds a worker watches for its next task before it sleeps: a frame's gap between its
    #: phases, and between the frames of a render loop.
    SPIN_S = 0.001
    #: Seconds the frame's thread watches for the worker to finish before it sleeps (:meth:`join`).
    JOIN_SPIN_S = 0.0005

    def __init__(self) -> None:
        queue, wake = collections.deque(), threading.Event()
        go, idle = np.zeros(1, np.uint8), np.ones(1, np.uint8)
        self._state = (queue, go, idle, wake)
        self._shutdown = False
        self._lock = threading.Lock()  # a task is queued before the stop, or refused
        # The thread holds the queue, not the executor: collecting the executor stops it.
        self._thread = threading.Thread(target=_second_core_loop, args=(queue, go, idle, wake, self.SPIN_S),
                                        name="sonarsim-second-core", daemon=True)
        self._thread.start()
        self._stop = weakref.finalize(self, _second_core_stop, queue, go, wake)

    def _queue(self, fn, args, kwargs) -> Future:
        future: Future = Future()
        queue, go, idle, wake = self._state
        with self._lock:
            if self._shutdown:
                raise RuntimeError("cannot schedule new futures after shutdown")
            if not self._thread.is_alive():
                raise RuntimeError(_GONE)
            idle[0] = 0
            queue.append((future, fn, args, kwargs))
        wake.set()  # only where the worker sleeps (its watch has timed out) does this wake it
        return future

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future = self._queue(fn, args, kwargs)
        self._state[1][0] = 1  # after the task is queued: the worker takes what it finds once it sees the flag
        return future

    def hand_off(self, fn) -> tuple[Future, np.ndarray]:
        """Queue ``fn()`` without raising the worker's flag: the caller raises ``go[0]`` (the
        array returned) once it has let go of the GIL, in a kernel, and waits with :meth:`join`."""
        return self._queue(fn, (), {}), self._state[1]

    def join(self, future: Future):
        """Wait for ``future`` (queued by :meth:`hand_off`): watching without the GIL for the
        worker to be idle again for :attr:`JOIN_SPIN_S`, then sleeping; its result. Raises the
        worker's flag where the caller's task did not (it failed before it could)."""
        go, idle = self._state[1], self._state[2]
        if not go[0] and not future.running() and not future.done():
            go[0] = 1
        # Watched briefly: a block ends within a few hundred microseconds of the other. Past
        # that the machine is busy and the worker waits for a core: sleep, not take it.
        if idle[0] or _kernels.watch_flag(idle, self.JOIN_SPIN_S):
            return future.result()
        while True:
            try:
                return future.result(timeout=1.0)
            except FuturesTimeout:
                if not self._thread.is_alive():
                    raise RuntimeError(_GONE) from None

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        with self._lock:
            self._shutdown = True
            if cancel_futures:
                for future, *_ in list(self._state[0]):
                    if future is not None:
                        future.cancel()
            self._stop()
        if wait and self._thread is not threading.current_thread():
            self._thread.join()


_GONE = ("the simulator's worker thread is gone (a process forked from one that had started it): make the "
         "simulator in the process that renders")


def _second_core_loop(queue: collections.deque, go: np.ndarray, idle: np.ndarray, wake: threading.Event,
                      spin_s: float) -> None:
    while True:
        # Idle (raised once the GIL is let go), watching for the next task.
        if not queue and not _kernels.watch_flag(go, spin_s, idle):
            wake.wait()
        # Cleared before the queue is read: a task queued after this raises them again.
        wake.clear()
        go[0] = 0
        while queue:
            future, fn, args, kwargs = queue.popleft()
            if future is None:
                # Stopped: what was queued after the stop fails rather than waits for ever.
                while queue:
                    left = queue.popleft()[0]
                    if left is not None and left.set_running_or_notify_cancel():
                        left.set_exception(RuntimeError("the worker stopped before this task ran"))
                return
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(fn(*args, **kwargs))
                except BaseException as exc:  # the caller sees it in result()
                    future.set_exception(exc)
                    del exc
            # Let go of the task and what it holds (a frame's arrays) while the worker waits.
            del future, fn, args, kwargs


def _second_core_stop(queue: collections.deque, go: np.ndarray, wake: threading.Event) -> None:
    queue.append((None, None, None, None))
    go[0] = 1
    wake.set()


def on_both_cores(task, n_tasks: int, pool=None, signals: bool = False) -> None:
    """Run ``task(0) .. task(n_tasks - 1)`` on this thread and ``pool``'s worker, each thread
    taking the next task when it is free (kernels release the GIL; no order between tasks).

    One hand-off per call: waking a sleeping thread costs more than a small task, so a frame
    gives the other core one long list of work instead of many short ones. The other thread
    has finished before this returns, also when a task raised. With ``signals`` and a
    :class:`SecondCore`, this thread's first task is called as ``task(k, go)`` and raises
    ``go[0]`` once its kernel has let go of the GIL (``PathBlocks.trace``, ``.paths``): the
    worker, watching ``go``, then takes the GIL without waiting for it.
    """
    claimed = itertools.count()

    def drain() -> None:
        while (k := next(claimed)) < n_tasks:  # next() on a count is atomic under the GIL
            task(k)

    if pool is None or n_tasks < 2:
        drain()
        return
    if not (signals and isinstance(pool, SecondCore)):
        other = pool.submit(drain)
        try:
            drain()
        finally:
            _wait_through_interrupts(other.result)
        return
    other, go = pool.hand_off(drain)
    try:
        k = next(claimed)
        if k < n_tasks:
            task(k, go)  # raises go (once only: a second raise has the worker wait for the GIL)
        else:
            go[0] = 1
        drain()
    finally:
        _wait_through_interrupts(lambda: pool.join(other))


def _wait_through_interrupts(wait) -> None:
    """``wait()``, again if Ctrl-C interrupts it, then the interrupt: the other thread writes
    into the frame's arrays until its tasks end, so the frame must not let go of them before."""
    interrupted = None
    while True:
        try:
            wait()
            break
        except KeyboardInterrupt as exc:
            interrupted = exc
    if interrupted is not None:
        raise interrupted


# Blocks of beams a frame is cut into, whatever the number of threads (the image does not
# depend on the cut; a fixed cut keeps that plain). One per core measured fastest on the demo
# and the six-plane tank (each block's columns are strided in the image, and a block's fixed
# costs -- its calls, its share of the casting's packets -- outweigh finer balancing).
N_BLOCKS = 2

# Rows of each block's own chain table at first (it grows on overflow).
CHAIN_CAPACITY = 256


def _most_refs(arrays: dict) -> int:
    """The largest reference count among a set's arrays, as this very expression sees it."""
    return max(sys.getrefcount(a) for a in arrays.values())


class ArrayPool:
    """Per-frame arrays kept between frames: a set is handed out again once nothing outside the
    pool refers to any of its arrays (the frame's legs, paths and their views died with its
    image), else a new set is made. A loop of frames then allocates nothing, where fresh
    arrays of a 1024-beam frame (tens of megabytes) page-faulted every frame.
    """

    KEEP = 3  # sets kept: the frame being formed, the one still held by the previous image, a spare

    # The count of an array that only its set holds, measured by the same expression rather than
    # assumed: what a reference count includes (the loop variable, the argument) varies between
    # Python versions.
    FREE_REFS = _most_refs({"probe": np.empty(1)})

    def __init__(self) -> None:
        # (kind, shapes, arrays): kind names each array's dtype and rank, shapes its shape.
        self._sets: list[tuple] = []

    def _free(self, arrays: dict) -> bool:
        return _most_refs(arrays) <= self.FREE_REFS

    def take(self, shapes: dict) -> dict:
        """A set of arrays of at least the given sizes: ``{name: (shape, dtype)}``, taken from
        the first free set whose arrays are as large, else new (contents undefined). The pool
        keeps the :attr:`KEEP` most recently taken sets."""
        # Compared as tuples: a frame's few calls here run with the caches cold after its kernels.
        kind = tuple((name, np.dtype(dt).char, len(shape)) for name, (shape, dt) in shapes.items())
        want = tuple(shape for shape, _ in shapes.values())
        taken = None
        for k, (have_kind, have, arrays) in enumerate(self._sets):
            if (have_kind == kind and (have == want or all(a >= b for hs, ws in zip(have, want) for a, b in zip(hs, ws)))
                    and self._free(arrays)):
                taken = self._sets.pop(k)
                break
        if taken is None:
            taken = (kind, want, {name: np.empty(shape, dt) for name, (shape, dt) in shapes.items()})
        self._sets.append(taken)  # most recently used last
        # The oldest beyond KEEP are let go: a free one is freed, a held one lives on with the
        # image that holds it (only the pool forgets it).
        del self._sets[: max(len(self._sets) - self.KEEP, 0)]
        return taken[2]


class FrameLegs:
    """The receive legs of a frame, dense over the fan's ``n`` rays, generation by generation
    (written by :class:`~sonarsim.renderer._kernels.PathBlocks`; see :class:`~sonarsim.paths.engine.Leg`).

    Attributes
    ----------
    dist, cosine, intensity, atten : (G, n) float64 ndarrays
        ``cosine`` (the incidence, as the search recorded it) is what the weighing turns into
        ``intensity``.
    sid, chain, key : (G, n) int32 ndarrays
    point : (G, n, 3) float64 ndarray
    normal : (G, n, 3) float32 ndarray
    texel : (G, n) float32 ndarray or None
        Where the objects are textured (``textured``), the texture's factor at each object's
        scatterer (the search records it, the weighing reads it); None otherwise.
    prim : (G, n) int32 ndarray or None
        The discrete search's triangle: the index into the object's mesh faces where an object
        scatters, -1 where a plane does or nothing (``sid`` says which); recorded on request
        (``primitives``: about 5 % of a demo frame).
    uv : (G, n, 2) float32 ndarray or None
        Where on that triangle (the caster's barycentric ``(u, v)``: ``p = (1 - u - v) a + u b
        + v c``), 0 elsewhere.
    live : (G, n) intp ndarray
        Block k's live rays of generation g at ``live[g, a:a + n_live[k, g]]`` (a: its first ray).
    n_live, n_cast : (n_blocks, G) intp ndarrays
        Live rays, and rays cast, per block and generation.
    """

    def __init__(self, n_gen: int, n: int, n_blocks: int, pool: ArrayPool | None = None,
                 primitives: bool = False, textured: bool = False, glints: bool = False,
                 n_legs: int | None = None) -> None:
        f, i = np.float64, np.int32
        shapes = {"dist": ((n_gen, n), f), "cosine": ((n_gen, n), f), "intensity": ((n_gen, n), f),
                  "atten": ((n_gen, n), f), "sid": ((n_gen, n), i), "chain": ((n_gen, n), i), "key": ((n_gen, n), i),
                  "point": ((n_gen, n, 3), f), "normal": ((n_gen, n, 3), np.float32), "live": ((n_gen, n), np.intp)}
        self.prim = self.uv = self.texel = None
        if primitives:
            shapes.update(prim=((n_gen, n), i), uv=((n_gen, n, 2), np.float32))
        if textured:
            shapes.update(texel=((n_gen, n), np.float32))
        self.back_length = self.back_atten = self.back_dir = self.back_chain = None
        if glints:
            shapes.update(back_length=((n_gen, n), f), back_atten=((n_gen, n), f), back_dir=((n_gen, n, 3), f),
                          back_chain=((n_gen, n), i))
        # The generations that are the frame's legs: with the specular returns, one more is
        # traced for the returns of the last one's reflections alone.
        self.n_legs = n_gen if n_legs is None else n_legs
        arrays = pool.take(shapes) if pool is not None else {k: np.empty(*v) for k, v in shapes.items()}
        for name, (shape, _) in shapes.items():  # views of exactly the frame's shape
            a = arrays[name]
            setattr(self, name, a if a.shape == shape else a[tuple(slice(0, m) for m in shape)])
        self.n_live, self.n_cast = np.zeros((n_blocks, n_gen), np.intp), np.zeros((n_blocks, n_gen), np.intp)

    def legs(self, work: Workspace) -> "LegViews":
        """The generations that cast any ray, as :class:`Leg` views (formed on first use)."""
        return LegViews(self, work)

    def views(self, work: Workspace) -> list[Leg]:
        """The generations that cast any ray, as :class:`Leg` views."""
        out = []
        for g in range(self.n_legs):
            if g and not self.n_cast[:, g].any():
                break
            first = g == 0
            out.append(Leg(g, self.dist[g], self.sid[g], self.point[g], self.normal[g], self.intensity[g],
                           work.ones if first else self.atten[g], work.zeros_i32 if first else self.chain[g],
                           keys=self.sid[g] if first else self.key[g],
                           prim=None if self.prim is None else self.prim[g], uv=None if self.uv is None else self.uv[g],
                           cosine=self.cosine[g], texel=None if self.texel is None else self.texel[g]))
            if self.back_length is not None:
                out[-1].back_length, out[-1].back_atten = self.back_length[g], self.back_atten[g]
                out[-1].back_dir, out[-1].back_chain = self.back_dir[g], self.back_chain[g]
        return out


class LegViews(Sequence):
    """A frame's receive legs as a sequence of :class:`Leg` (:meth:`FrameLegs.views`), formed
    when first read: a frame whose legs nobody reads (no ray maps, no signature images, labels
    formed in the pass) does not form them."""

    def __init__(self, legs: FrameLegs, work: Workspace) -> None:
        self._source: tuple | None = (legs, work)
        self._views: list[Leg] = []

    def _all(self) -> list[Leg]:
        if self._source is not None:
            self._views = self._source[0].views(self._source[1])
            self._source = None
        return self._views

    def __getitem__(self, index):
        return self._all()[index]

    def __len__(self) -> int:
        return len(self._all())


def probe_kernel():
    """``_kernels.probe_chains``, the compiled twin of :func:`sonarsim.paths.engine.probe_chains`' loop."""
    return _kernels.probe_chains


def packet_loop(caster) -> tuple | None:
    """The caster's packet loop for the compiled blocks (``Embree4Caster.packet_loop``), None
    where it has none (embreex, the NumPy caster) or no triangles."""
    loop = getattr(type(caster), "packet_loop", None)  # on the type: a wrapper forwards attributes
    return loop(caster) if loop is not None else None


def path_engine(caster, work: Workspace, fan: RayFan, laws: SurfaceLaws, planes, facets=None):
    """The block engine (:class:`~sonarsim.renderer._kernels.PathBlocks`) for this caster,
    workspace, fan, laws, planes and mesh mirrors (``paths.facets.FacetSet``, or None), built
    on first use and kept on the workspace; it casts through the caster's
    packet loop where it lends one (the Embree 4 binding), else Python casts between its
    stages (embreex, the NumPy caster, textures)."""
    handle = packet_loop(caster)
    cached = work.engine
    n_blocks = min(N_BLOCKS, fan.shape[0])
    if (cached is not None and cached[0] is caster and cached[1] is fan and cached[2] is laws
            and cached[3] is planes and cached[4].fused == (handle is not None) and cached[5] == n_blocks
            and cached[6] is facets):
        return cached[4]
    law_by_id, lobe_by_id, _ = _law_args(laws, None)
    mirrors = _kernels.Mirrors.of(facets) if facets is not None and facets.any else None
    reflectance = None if laws.reflectance is None else _kernels.ReflectanceTable(laws.reflectance, laws.reflect_q)
    engine = _kernels.PathBlocks(work, fan.directions.reshape(-1, 3), fan.weight.reshape(-1), laws.coefficient,
                                 law_by_id, lobe_by_id, planes.normal, planes.offset, planes.specular, n_blocks,
                                 CHAIN_CAPACITY, *(handle or ()), mirrors=mirrors, reflectance=reflectance)
    work.engine = (caster, fan, laws, planes, engine, n_blocks, facets)
    return engine


def _frame_chains(table, engine, work: Workspace):
    """The frame's chains -- the probes' (in ``table``) and every block's -- numbered
    canonically, and each block's local ids to those: ``(table, remap)``, remap (n_blocks,
    capacity) int32. Kept on ``work`` while the frames meet the same chains in every block."""
    parent, last, n_local = engine.chain_parents()
    n = int(n_local.max())
    key = (tuple(table.chains), parent[:, :n].tobytes(), last[:, :n].tobytes(), n_local.tobytes(), parent.shape)
    cached = work.chains
    if cached is not None and cached[0] is table.planes and cached[1] == key:
        return cached[2].at(table.origin), cached[3]
    local = [table.local_chains(parent[k], last[k], int(n_local[k])) for k in range(len(n_local))]
    for chains in local:
        for c in chains:
            table.add(c)
    canonical, _ = table.canonical()
    remap = np.zeros(parent.shape, np.int32)
    for k, chains in enumerate(local):
        remap[k, : len(chains)] = [canonical.add(c) for c in chains]
    work.chains = (table.planes, key, canonical, remap)  # (its unfolding maps grow as options ask)
    return canonical, remap


def _option_table(table, n_gen: int, max_order: int, double_beam: str) -> tuple:
    """The frame's transmit options (:func:`sonarsim.paths.engine.frame_options`, in its order)
    as the arrays of ``PathBlocks.options``: ``(gen, tx, same, label, length, unfold,
    chain_planes, specular, only)``. Depends on the chains, not on the pose (see :func:`_options`).

    An option whose transmit chain meets a smooth mirror (no image source) is formed from its
    reciprocal partners, after the others, as ``engine.reciprocal_sets`` forms them: the receive
    legs that followed it (``only``: that chain; -1 for the others) with a transmit leg along
    each flat chain that pairs with it."""
    from ..paths.engine import SAME, chain_ranks, frame_options, partner_chains

    rows, smooth = [], []  # rows: (generation, chain, same, image row, only)
    for g, tx, row in frame_options(table, n_gen, max_order, double_beam):
        if tx != SAME and not table.flat(tx):
            smooth.append((g, tx, row))
            continue
        rows.append((g, 0 if tx == SAME else tx, tx == SAME, row, -1))
    if smooth:
        rank = chain_ranks(table)
        for g, tx, row in smooth:
            if table.length(tx) < n_gen:
                rows += [(table.length(tx), c, False, row, tx) for c in partner_chains(table, g, tx, rank, double_beam)]
    n_opt = len(rows)
    length = np.array([0 if r[2] else table.length(r[1]) for r in rows], np.int32)
    unfold = np.zeros((n_opt, 3, 4))
    chain_planes = np.zeros((n_opt, max(int(length.max(initial=0)), 1)), np.int32)
    specular = np.ones(n_opt)
    for o, (_, c, same, _, _) in enumerate(rows):
        unfold[o] = table.unfold(c)
        if not same:
            chain_planes[o, : length[o]] = table.chains[c]
            specular[o] = table.specular(c)
    columns = [np.array([r[k] for r in rows], np.int32) for k in range(5)]
    return (*columns[:4], length, unfold, chain_planes, specular, columns[4])


def _options(table, n_gen: int, max_order: int, double_beam: str, engine, work: Workspace):
    """The arrays of ``PathBlocks.options`` (see :func:`_option_table`, kept on ``work`` while
    the frames meet the same chains), the sonar's images along each option's chain, and the
    path buffer's offsets and size (option-major; a block's capacity for an option is its
    generation's live rays): those two formed by ``engine.layout`` in one call (twin:
    ``ChainTable.sources``, and the live rays summed); and each option's ``only`` chain."""
    key = (table.planes, tuple(table.chains), n_gen, max_order, double_beam)
    cached = work.options
    if cached is None or cached[0] is not key[0] or cached[1:4] != key[1:4] or cached[4] != double_beam:
        arrays = _option_table(table, n_gen, max_order, double_beam)
        # The sonar's images' room, overwritten each frame: only this frame's blocks read
        # them (PathBlocks.paths), before the next frame's layout.
        cached = work.options = (*key, arrays, np.zeros((len(arrays[0]), arrays[6].shape[1] + 1, 3)))
    gen, tx, same, label, length, unfold, chain_planes, specular, only = cached[5]
    sources = cached[6]
    offset = np.empty(len(gen) * engine.n_blocks, np.intp)  # the frame's own: its path buffer keeps it
    size = engine.layout(gen, same, length, chain_planes, sources, offset)
    return (gen, tx, same, label, length, unfold, sources, chain_planes, specular), offset, size, only


# Bytes of one path in the path buffer (:class:`PathBuffer`: ray, distance, energy, beam,
# transmit beam, label).
PATH_BYTES = 8 + 8 + 8 + 4 + 4 + 1

# A frame whose path buffer, laid out with room for every candidate (each option's
# generation's live rays), would be larger than this counts its paths first and lays out room
# for them alone (:func:`_counted_layout`): many transmit options (the chains of mesh mirrors,
# ``double_beam: separate``) have many candidates and few paths.
PATH_BUFFER_BYTES = 64 * 2**20
#: Time to try one candidate path (a live ray against a transmit option), both passes of a
#: counted layout included: 38 million candidates of 300 mirror boxes at order 5 took 5 s here
#: with the machine loaded five times over (1.3e-7 s each); about this on a quiet one.
SECONDS_PER_CANDIDATE = 5e-8
#: ... or than the memory budget over this (a small budget counts the paths first sooner).
PATH_BUFFER_BUDGET_SHARE = 8


def _counted_layout(engine, remap: np.ndarray, rank: np.ndarray, options: tuple, offset: np.ndarray,
                    only: np.ndarray, paths, n_blocks: int, pool) -> tuple[np.ndarray, int, np.ndarray]:
    """Count the frame's paths option by option and block by block (a pass of ``engine.paths``
    that forms them into the engine's scratch, on both cores), and lay the path buffer out for
    them: ``(offset, size, capacity)``, each option's room in each block its count. ``paths(k,
    signal)`` runs block k's pass."""
    count = np.zeros(len(offset), np.intp)
    none = (np.empty(0, np.intp), np.empty(0), np.empty(0), np.empty(0, np.int32), np.empty(0, np.int32),
            np.empty(0, np.int8))
    engine.options(remap, rank, *options, offset, count, *none, False, counting=True, only=only)
    on_both_cores(paths, n_blocks, pool, signals=True)
    exact = np.zeros(len(count), np.intp)
    np.cumsum(count[:-1], out=exact[1:])  # option-major, block after block
    return exact, int(count.sum()), count


class PathBuffer:
    """The paths of a frame as the blocks wrote them (see ``docs/path-buffer.md``): fields of
    one path per entry, option-major, each option's paths block after block in ray order.

    Attributes
    ----------
    gen, tx, same : (n_options,) int32 ndarrays
        Each transmit option's receive generation, transmit chain and whether the transmit leg
        is the receive leg reversed.
    swap : (n_options,) bool ndarray
        The option's paths are a smooth mirror's reciprocal partners (``PathSet.swap``): formed
        along its receive legs, recorded in their transmit beams.
    offset, count : (n_options * n_blocks,) intp ndarrays
        Where option o of block k starts (``o * n_blocks + k``) and how many paths it holds.
    ray, distance, energy, beam, beam_tx, label : ndarrays
        Per path: the fan ray it arrives along, half its length (m), its energy, its beam of
        arrival, its transmit beam, its image row.
    """

    def __init__(self, options: tuple, offset: np.ndarray, size: int, n_blocks: int,
                 pool: ArrayPool | None = None, swap: np.ndarray | None = None) -> None:
        self.gen, self.tx, self.same = options[0], options[1], options[2]
        self.swap = np.zeros(len(self.gen), bool) if swap is None else np.asarray(swap, bool)
        self.n_blocks = n_blocks
        self.offset, self.count = offset, np.zeros(len(offset), np.intp)
        cap = 1 << max(size - 1, 0).bit_length()  # sizes vary from frame to frame: the pool's sets in powers of 2
        shapes = {"ray": ((cap,), np.intp), "distance": ((cap,), np.float64), "energy": ((cap,), np.float64),
                  "beam": ((cap,), np.int32), "beam_tx": ((cap,), np.int32), "label": ((cap,), np.int8)}
        arrays = pool.take(shapes) if pool is not None else {k: np.empty(*v) for k, v in shapes.items()}
        for name in shapes:
            setattr(self, name, arrays[name][:size])

    def sets(self, double_beam: str = "paper") -> list:
        """The frame's :class:`~sonarsim.paths.engine.PathSet` list, as ``form_paths`` forms it."""
        from ..paths.engine import SAME, option_sets

        out = []
        K = self.n_blocks
        for o in range(len(self.gen)):
            parts = [slice(self.offset[o * K + k], self.offset[o * K + k] + self.count[o * K + k]) for k in range(K)]
            parts = [p for p in parts if p.stop > p.start]
            if not parts:
                continue

            def cat(a):
                return a[parts[0]].copy() if len(parts) == 1 else np.concatenate([a[p] for p in parts])

            beam, beam_tx = cat(self.beam), cat(self.beam_tx)
            if self.swap[o]:  # a smooth mirror's reciprocal partners: in the beam they arrive in
                beam, beam_tx = beam_tx, beam
            sets = option_sets(int(self.gen[o]), SAME if self.same[o] else int(self.tx[o]), cat(self.ray),
                               cat(self.distance), cat(self.energy), beam, beam_tx, cat(self.label), double_beam)
            for s in sets:
                s.swap = bool(self.swap[o])
            out += sets
        return out


def render_paths(caster, planes, active, sonar: SonarConfig, view, work: Workspace,
                 laws: SurfaceLaws, render: RenderSettings, reach_m: float, n_generations: int, table,
                 n_surfaces: int, stack: np.ndarray, pool=None, occlusion=None, textures: tuple = (),
                 sum_rows: tuple[int, ...] = (), labels=None, primitives: bool = False,
                 glint_radius_m: float | None = None, poses: tuple[np.ndarray, np.ndarray] | None = None):
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
    view : sonarsim.paths.engine.SonarView
        The frame's pose and fan (each block rotates its own rays in the kernel).
    table : ChainTable
        The chains the aperture's edges follow (``probe_chains``).
    stack : (rows, n_range_bins, n_beams) float32 ndarray
        Receives the image stack (its content is overwritten).
    sum_rows : tuple of int
        Stack rows whose sum is the frame's total, added by the blocks where they splat.
    labels : sonarsim.renderer.ground_truth.LabelSpec, optional
        Form the frame's ground truth in the same pass: each block deposits its paths into the
        label maps as it splats them (:class:`FrameTruth`). Not where the blocks do not splat
        (``double_beam: split``, ``double_line_of_sight``): the caller forms it from ``sets``.
    primitives : bool
        Record the discrete search's triangles and barycentrics in the legs (``Leg.prim``,
        ``Leg.uv``), for what re-evaluates the hit points (the differentiable engine).
    poses : ((P, 3, 3), (P, 3)) float64 ndarrays, optional
        A frame of P poses (``view.fan`` P copies of one pose's rays, the grid's beams P
        copies of its beams): each pose's rays rotated and cast from their own pose instead of
        ``view``'s (``PathBlocks.frame``; one generation, no specular returns).

    Returns
    -------
    legs : list of Leg
    sets : callable
        Forms the frame's path sets from the path buffer (for labels and signatures).
    table : ChainTable
        The frame's chains, canonically numbered (the ids of ``sets``).
    total : (n_range_bins, n_beams) float32 ndarray or None
        The sum of ``sum_rows`` (as ``components._sum_rows`` adds them), or None: not formed.
    truth : tuple or None
        With ``labels``, :meth:`FrameTruth.finish`'s maps where they were formed in the pass.
    """
    laws = SurfaceLaws.of(laws)
    fan = view.fan
    facets = table.facets if table.facets is not None and table.facets.any else None
    engine = path_engine(caster, work, fan, laws, planes, facets)
    primitives = primitives or facets is not None  # a mirror is found by its triangle
    n_beams = sonar.n_beams
    n_blocks = min(N_BLOCKS, n_beams)
    blocks = work.blocks(n_beams, n_blocks)
    spent = np.zeros(len(blocks))  # each block's seconds, tracing and forming paths (Workspace.balance)
    overflowed = False
    per_beam = fan.n_rays // n_beams
    # A caster whose hits carry a texture's factor (scene.textures.TexturedCaster) casts in
    # Python between the stages; the legs then record the factor for the weighing.
    textured = bool(getattr(type(caster), "carries_texel", False))
    glints = glint_radius_m is not None
    # The specular returns: one generation more is traced, for the returns of the last one's
    # reflections alone (engine.trace_legs).
    n_traced = n_generations + (1 if glints else 0)
    legs_out = FrameLegs(n_traced, fan.n_rays, n_blocks, work.legs_pool, primitives, textured, glints,
                         n_legs=n_generations)
    active8 = np.ascontiguousarray(active, dtype=np.uint8)
    # Each block splats its own beams, but for paths that arrive in others' (the specular
    # returns, 'split') or that a cast may yet remove.
    in_blocks = render.double_beam != "split" and occlusion is None and not glints
    if not stack.flags.c_contiguous:
        raise ValueError("the image stack must be C-contiguous (the blocks splat into it in place)")
    textures = textures if any(f is not None for f in textures) else ()
    fused = engine.fused and not textures
    w = work

    def staged(k: int) -> bool:
        """Block k with Python casting between the stages (the same code as the fused block)."""
        b0, b1 = blocks[k]
        a = b0 * per_beam
        buffer, m, limit = engine.begin(k, b0, b1)
        for g in range(n_traced):
            if not m:
                break
            if buffer < 0:
                o32, d32 = w.o32[a:a + m], w.d32[a:a + m]
            else:
                o32, d32 = w.r_org32[buffer, a:a + m], w.r_dir32[buffer, a:a + m]
            hits = caster.intersect(o32, d32, float(limit), threads=1, with_uv=primitives)
            w.h_dist[a:a + m], w.h_mesh[a:a + m], w.h_normal[a:a + m] = hits.distance, hits.mesh_id, hits.normal
            if primitives:
                w.h_prim[a:a + m], w.h_uv[a:a + m] = hits.primitive_id, hits.barycentric
            if not engine.step(k, b0, b1, g, *_law_args(laws, hits)):
                return False
            buffer, m, limit = engine.pending(k)
        return True

    def trace(k: int, signal=None) -> None:
        start = time.perf_counter()
        if fused:
            ok[k] = engine.trace(k, *blocks[k], signal)
        else:
            if signal is not None:  # Python casts between the stages: the other thread may start now
                signal[0] = 1
            ok[k] = staged(k)
        spent[k] += time.perf_counter() - start

    def paths(k: int, signal=None) -> None:
        start = time.perf_counter()
        engine.paths(k, *blocks[k], signal)
        spent[k] += time.perf_counter() - start

    engine.frame(legs_out, active8, view.rotation, view.origin,
                 reach_m, render.tvg, n_traced, fan.shape[2], sonar.range_min_m, sonar.range_resolution_m,
                 sonar.n_range_bins, n_beams, sonar.range_max_m, sonar.elevation_fov_deg / 2.0,
                 np.ascontiguousarray(sonar.beam_edges_deg), render.range_splat, PAIR_MODES[render.double_beam],
                 n_surfaces, stack.reshape(-1) if in_blocks else None, primitives,
                 glint_radius_m if glints else 0.0,
                 *((None, None) if poses is None else poses), cone=view.cone)
    try:  # the engine lets go of the frame's arrays whatever happens (they go back to the pool)
        while True:
            ok = [True] * len(blocks)
            on_both_cores(trace, len(blocks), pool, signals=True)
            if all(ok):
                break
            overflowed = True  # (the blocks' times include a trace that was thrown away)
            engine.grow(4 * engine.chain_tables()[0].shape[1])  # a block met more chains than its table holds
        if textures:
            # Each generation's scatterers on textured planes take their factor, over the whole
            # frame at once as the NumPy twin does (the factor's matrix products are not the same
            # bits row by row); only the paths, formed after, read the intensity.
            for g in range(n_generations):
                if legs_out.n_cast[:, g].any():
                    scale_by_texture(legs_out.intensity[g], legs_out.sid[g], legs_out.point[g], textures)
        table, remap = _frame_chains(table, engine, work)
        options, offset, size, only = _options(table, n_generations, render.max_order, render.double_beam, engine,
                                               work)
        # Every live ray of a generation is a candidate of every transmit option of it: known
        # once the chains are, checked before the paths are formed (900 mirror boxes at order 5
        # seen by an ARIS: 150 million candidates, 19 s).
        require_time(size * SECONDS_PER_CANDIDATE, f"forming the frame's paths ({size:,} candidates of "
                     f"{len(options[0]):,} transmit options; mirrors at max_order {render.max_order})", "render.max_order")
        # A smooth mirror's reciprocal partners arrive in their partners' transmit beams, which
        # may be another block's: such a frame splats after its blocks, as 'split' does.
        in_blocks = in_blocks and not (only >= 0).any()
        rank = np.arange(len(table), dtype=np.int32)  # canonical ids are ranks (ChainTable.key)
        capacity = None
        # Many transmit options: room for the paths, not the candidates (and within a small
        # memory budget: a buffer of 64 MiB for 672 rays broke a 64 MiB budget in the mirror fuzz).
        if size * PATH_BYTES > min(PATH_BUFFER_BYTES, memory_budget() // PATH_BUFFER_BUDGET_SHARE):
            offset, size, capacity = _counted_layout(engine, remap, rank, options, offset, only, paths, len(blocks),
                                                     pool)
            require(size * PATH_BYTES, f"the frame's {size} paths", "render.max_order")
        buffer = PathBuffer(options, offset, size, len(blocks), work.paths_pool, swap=only >= 0)
        total = np.empty(stack.shape[1] * stack.shape[2], np.float32) if in_blocks and sum_rows else None
        truth, deposit = None, ()
        if labels is not None and in_blocks:
            truth = FrameTruth(size, labels, (sonar.range_min_m, sonar.range_resolution_m, sonar.n_range_bins,
                                              n_beams), render.range_splat, blocks, work.labels_scratch)
            deposit = (truth.maps, *truth.option_maps(options[3]))
        engine.options(remap, rank, *options, buffer.offset, buffer.count, buffer.ray, buffer.distance,
                       buffer.energy, buffer.beam, buffer.beam_tx, buffer.label, in_blocks, total, tuple(sum_rows),
                       *(deposit or (None, None, None)), capacity=capacity, only=only)
        on_both_cores(paths, len(blocks), pool, signals=True)
    finally:
        engine.release()
    if pool is not None and not overflowed:
        work.balance(blocks, spent)
    if truth is not None:
        truth.maps.compact(buffer.offset)
        truth = truth.finish()
    legs = legs_out.legs(work)
    sets = functools.partial(buffer.sets, render.double_beam)
    if not in_blocks:
        stack[:] = 0.0
        frame_sets = buffer.sets(render.double_beam)
        if glints:
            frame_sets += glint_sets(legs, view, len(planes), per_beam, render.max_order, fan.weight.reshape(-1),
                                     glint_radius_m, render.tvg)
        if occlusion is not None:
            frame_sets = occlusion(frame_sets, legs, table=table)
        splat_paths(frame_sets, legs, n_surfaces, fan.shape[2], (sonar.range_min_m, sonar.range_resolution_m,
                                                                 sonar.n_range_bins, n_beams), render.range_splat,
                    stack)
        sets = functools.partial(lambda s: s, frame_sets)
    return legs, sets, table, None if total is None else total.reshape(stack.shape[1:]), truth


def splat_paths(sets, legs, n_surfaces: int, n_elevation: int, geometry: tuple, spread: bool, out: np.ndarray,
                keys: dict | None = None) -> None:
    """Accumulate path sets into the float32 image stack ``out`` (labels x bins x beams).

    ``keys``: the legs' surface keys by generation, kept by a caller that splats many groups
    of one frame's paths (each a pass over the leg's rays)."""
    flat = out.reshape(-1)
    keys = {} if keys is None else keys
    for s in sets:
        leg = legs[s.gen]
        if s.gen not in keys:
            keys[s.gen] = leg.key(n_surfaces)
        _kernels.splat_events(leg.point, leg.normal, keys[s.gen], s.ray, s.distance, s.energy, s.beam, s.label,
                              1.0, spread, n_elevation, *geometry, flat)



class LabelScratch:
    """The label maps' scratch, kept between frames: the dominance state of every cell of every
    map and the flags of the tiles a path reached (-1 and 0 throughout while the scratch is not
    in use: each block's ``LabelMaps.resolve`` sets the cells and tiles it reached back, so no
    frame fills them), the table of mixed cells and the moments (uninitialised; written where
    first reached).
    """

    def __init__(self) -> None:
        self._arrays: dict | None = None
        self._clean = False

    def take(self, n_maps: int, n_rows: int, n_beams: int, n_ids: int) -> dict:
        """Arrays for ``n_maps`` maps of ``n_rows x n_beams`` cells and ``n_ids`` ids; new ones
        (their state filled) unless the kept ones fit and the last frame gave them back clean."""
        a = self._arrays
        n_cells, n_tiles = n_rows * n_beams, n_beams * _kernels.tiles_of(n_rows)
        if (a is None or not self._clean or a["cells"].shape[0] < n_maps or a["cells"].shape[1] != 2 * n_cells
                or a["touched"].shape[1] != n_tiles or a["table"].shape[1] != n_ids):
            a = self._arrays = {"cells": np.full((n_maps, 2 * n_cells), -1, np.int32),
                                "touched": np.zeros((n_maps, n_tiles), np.uint8),
                                "table": np.empty((n_maps * n_cells, n_ids), np.float32),
                                "moments": np.empty(3 * n_cells)}
        self._clean = False  # until every block has finished (a failed frame leaves it dirty)
        return a

    def give_back(self, arrays: dict) -> None:
        """Every block of the frame that took ``arrays`` resolved its cells: their state is -1
        again (only if they are still the kept set: a frame that took them is not the last
        word on a newer set)."""
        if arrays is self._arrays:
            self._clean = True


class FrameTruth:
    """The ground truth of one frame being formed: ``_kernels.LabelMaps`` with its outputs and
    scratch (twin: ``sonarsim.renderer.ground_truth._frame_truth``: dense stacks and ``dominant``).

    Deposited in the frame's own pass by the blocks as they splat (:func:`render_paths` with
    ``labels``), or afterwards from path sets (:meth:`add`, one block of every beam).

    Parameters
    ----------
    n_paths : int
        Room for the points: at least the frame's paths (the path buffer's size).
    spec : LabelSpec
        What to form, and the surfaces' label ids.
    geometry : (range_min_m, range_resolution_m, n_range_bins, n_beams)
        The image's grid.
    spread : bool
    blocks : tuple of (int, int)
        The engine's blocks of beams (default: one block of every beam, for :meth:`add`).
    scratch : LabelScratch, optional
        Kept between frames (default: a new one). The outputs are always new: the labels keep
        them.
    """

    def __init__(self, n_paths: int, spec, geometry: tuple, spread: bool,
                 blocks: tuple = (), scratch: LabelScratch | None = None) -> None:
        range_min_m, dr, n_r, n_b = geometry
        n_ids = len(spec.lut)
        n_maps = spec.max_order + 1 if spec.components else 1  # the orders, then the total
        blocks = blocks or ((0, n_b),)
        self.spec, self.n_blocks = spec, len(blocks)
        self._added = False  # path sets deposited by add() (the engine's blocks resolve their own)
        self.scratch = scratch if scratch is not None else LabelScratch()
        # Outputs: each block resolves every cell of its beams' columns (LabelMaps.resolve:
        # "nothing" where its paths reached none).
        self.instance = np.empty((n_maps, n_r, n_b), np.int32)
        self.split = np.empty((2, n_r if spec.components else 0, n_b), np.int32)
        self.elevation = np.empty((3, n_r, n_b), np.float32)
        self.boxes = np.full((len(blocks), n_ids, 4), -1, np.int32)
        self.points = (np.empty((n_paths, 3), np.float32), np.empty(n_paths, np.int32), np.empty(n_paths, np.int8),
                       np.empty((n_paths, 2), np.int32))
        work = self._work = self.scratch.take(n_maps, n_r, n_b, n_ids)
        edges = _block_edges(tuple(int(b0) for b0, _ in blocks), n_b)
        self.maps = _kernels.LabelMaps(self.instance, self.split[0], self.split[1], self.elevation, self.boxes,
                                       work["cells"], work["touched"], work["table"], work["moments"],
                                       np.ascontiguousarray(spec.lut, np.int32),
                                       np.ascontiguousarray(spec.elevation_deg, np.float64), spread, range_min_m, dr,
                                       edges, spec.n_objects, *self.points)

    def option_maps(self, label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per transmit option of image row ``label``: its order's map (-1: none) and whether it
        enters the total (``PathBlocks.options``' ``order_map`` and ``moments``)."""
        return _option_maps(tuple(int(v) for v in np.asarray(label).reshape(-1)), self.spec.components,
                            tuple(self.spec.bounces))

    def add(self, sets, legs, n_surfaces: int) -> None:
        """Deposit path sets formed after the frame (their receive legs ``legs[s.gen]``), one
        block of every beam."""
        self._added = True
        keys = {}
        for s in sets:
            if not len(s.ray):
                continue
            leg = legs[s.gen]
            if s.gen not in keys:
                keys[s.gen] = leg.key(n_surfaces)
            order_map, moments = self.option_maps(s.label[:1])
            self.maps.add(leg.point, leg.normal, keys[s.gen], leg.sid, s.ray, s.distance, s.energy, s.beam, s.label,
                          int(order_map[0]), bool(moments[0]))

    def finish(self) -> tuple:
        """The resolved maps: ``(orders, objects, planes, total, elevation, boxes, points)``.

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
        maps = self.maps
        maps.check()
        if self._added:  # deposited by add(): resolved here (the engine's blocks resolve their own)
            maps.finish(0)
        if not maps.resolved():
            raise ValueError("a block of the label maps was not resolved")
        self.scratch.give_back(self._work)
        n = maps.n_points
        boxes = np.empty((len(self.spec.lut), 4), np.int32)
        maps.united_boxes(boxes)
        self.maps = None
        objects, planes = (self.split[0], self.split[1]) if self.spec.components else (None, None)
        return (self.instance[:-1], objects, planes, self.instance[-1], self.elevation, boxes,
                tuple(p[:n] for p in self.points))


@functools.lru_cache(maxsize=16)  # a sonar's: the same every frame
def _block_edges(starts: tuple, n_beams: int) -> np.ndarray:
    """The blocks' first beams, then ``n_beams`` (read-only: shared)."""
    edges = np.array(list(starts) + [n_beams], np.intp)
    edges.flags.writeable = False
    return edges


@functools.lru_cache(maxsize=64)  # a frame's options' rows: the same frame after frame
def _option_maps(label: tuple, components: bool, bounces: tuple) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`FrameTruth.option_maps` (read-only arrays: they are shared)."""
    order = np.maximum(np.asarray(label, np.int32), 1)  # rows 0 (objects) and 1 (planes) are order 1
    order_map = (order - 1 if components else np.full(len(order), -1)).astype(np.int32)
    moments = np.isin(order, bounces).astype(np.uint8)
    order_map.flags.writeable = moments.flags.writeable = False
    return order_map, moments


def frame_truth(sets, legs, n_surfaces: int, spec, geometry: tuple, spread: bool) -> tuple:
    """The label maps and points of a frame from its path sets, formed after the frame: one
    pass per path set, then one over the cells (:meth:`FrameTruth.finish`'s tuple;
    twin: ``sonarsim.renderer.ground_truth._frame_truth``, which takes the same arguments).

    Parameters
    ----------
    sets, legs : the frame's path sets and receive legs
    n_surfaces : int
        Planes + objects (for :meth:`Leg.key`).
    spec : LabelSpec
    geometry : (range_min_m, range_resolution_m, n_range_bins, n_beams)
        The image's grid.
    spread : bool
    """
    truth = FrameTruth(sum(len(s.ray) for s in sets), spec, geometry, spread)
    truth.add(sets, legs, n_surfaces)
    return truth.finish()


def id_extents(ids: np.ndarray, extents: np.ndarray, n_ids: int) -> np.ndarray:
    """``_kernels.id_extents``: per id ``0 .. n_ids - 1``, the union of the inclusive boxes
    ``extents`` (n, 4) of the cells whose id ``ids`` (n,) it is; -1 rows for absent ids."""
    out = np.full((n_ids, 4), -1, np.int32)
    _kernels.id_extents(np.ascontiguousarray(ids, np.int32).reshape(-1), np.ascontiguousarray(extents, np.int32),
                        out)
    return out
