"""Rendering and encoding a dataset's frames, in this process or in N worker processes.

The work is cut into tasks of a few frames (batches). A worker process builds each scene's
simulator once (:class:`~sonarsim.dataset.frames.SimulatorCache`) and keeps it between tasks;
it renders, encodes the frame's files (NPZ, PNG bytes) and their checksums, and sends them back
to the single writer in the parent (:func:`sonarsim.dataset.generate`), which only writes
bytes. Results arrive in the order tasks finish; what a frame holds depends only on the
scenario and its index, never on the worker or the order.

Processes come from a ``forkserver`` (``spawn`` where there is none): never ``fork`` from the
parent, which may hold threads (ray-casting pools, the progress bar's monitor) that a forked
child would inherit half-way. The fork server is a fresh, single-threaded process that has
imported the renderer once, so a worker starts in milliseconds instead of the second that
importing sonarsim, NumPy and Embree takes (a whole short run, with ``spawn``).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import threading
import time
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

from ..core.console import install_warning_format, show_warning
from ..core.extras import install_hint
from .encoding import _write_files, encode_frame
from .frames import SimulatorCache, frame_memory_bytes, render_frame, rendered_labels
from .scenario import Scenario

__all__ = ["RAY_HINT", "WORKER_BASE_BYTES", "available_cores", "batches", "cap_workers", "lone_threads", "lone_writers", "worker_bytes", "encoded_frames", "encoded_frames_ray", "render_batch",
           "rendered_frames"]

#: What to install for ``--ray`` (:mod:`sonarsim.core.extras`: right for a clone and for an installed package).
RAY_HINT = install_hint("ray")

# Per worker process: the scenario and options it was started with, and its simulators.
_STATE: dict[str, Any] = {}


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


#: A worker process's memory besides its frames: the interpreter, NumPy, SciPy, Embree and the
#: renderer (128 MiB measured after four 16 x 120 frames), with some room.
WORKER_BASE_BYTES = 160 * 2**20
#: A worker holds about this many frames' worth of a frame's render memory at its peak: the
#: render's buffers, the image and its labels, and their copies while they are encoded
#: (measured: 270 and 430 MiB resident for frames estimated at 46 and 86 MiB, with the base),
#: and one more: the frame the writer thread encodes while the next renders.
FRAME_COPIES = 5


def worker_bytes(frame_bytes: float) -> float:
    """A worker process's memory at its peak, for frames that hold ``frame_bytes`` while they
    render (:func:`~sonarsim.dataset.frames.frame_memory_bytes`)."""
    return WORKER_BASE_BYTES + FRAME_COPIES * float(frame_bytes)


def lone_threads(options: Any, cores: int | None = None) -> int:
    """Ray-casting threads of a lone worker that was not told how many: a third of the cores (at
    least one) where its frames' encoding is the larger part (labels and PNGs: 14.5 ms a demo
    frame against a 6.6 ms single-threaded labelled render), so that the other cores encode;
    every core where it is not (an image-only dataset: the NPZ of the device image)."""
    cores = available_cores() if cores is None else cores
    heavy = options.labels != "none" or bool(options.pngs)
    return max(1, round(cores / 3)) if heavy else max(1, cores)


def lone_writers(threads: int, frame_bytes: float, cores: int | None = None, budget: int | None = None) -> int:
    """Writer threads of a lone worker (:func:`rendered_frames`): one more than the cores its
    render leaves (a writer that waits on the disk or the GIL leaves its core to another), where
    the budget holds that many frames waiting (each writer's frame past the first costs
    ``frame_bytes``); one where the render takes every core."""
    from ..core.memory import memory_budget

    cores = available_cores() if cores is None else cores
    budget = memory_budget() if budget is None else budget
    if threads >= cores:
        return 1
    writers = cores - threads + 1
    while writers > 1 and worker_bytes(frame_bytes) + (writers - 1) * float(frame_bytes) > budget:
        writers -= 1
    return writers


def cap_workers(requested: int, frame_bytes: float, cores: int | None = None,
                budget: int | None = None) -> tuple[int, str | None]:
    """The worker processes to start for ``requested``: no more than the cores, nor than the
    memory budget holds.

    Parameters
    ----------
    requested : int
        ``--workers`` (>= 1).
    frame_bytes : float
        What one frame holds at once while it renders.
    cores : int, optional
        Default :func:`available_cores`.
    budget : int, optional
        Bytes; default :func:`sonarsim.core.memory.memory_budget` (``--max-memory``).

    Returns
    -------
    workers : int
        At least 1 (a frame that does not fit alone was refused before).
    note : str or None
        One line saying what capped the request, or None when nothing did.
    """
    from ..core.memory import ENV_VAR, memory_budget

    cores = available_cores() if cores is None else cores
    budget = memory_budget() if budget is None else budget
    each = worker_bytes(frame_bytes)
    by_memory = max(1, int(budget // each))
    workers = max(1, min(requested, cores, by_memory))
    if workers == requested:
        return workers, None
    why = []
    if cores < requested:
        why.append(f"{cores} CPU core{'s' if cores != 1 else ''} here")
    if by_memory < requested:
        why.append(f"the memory budget of {budget / 2**30:.3g} GiB holds {by_memory} of about "
                   f"{each / 2**20:.0f} MiB each (--max-memory or ${ENV_VAR} to change it)")
    return workers, f"--workers {requested}: starting {workers} ({'; '.join(why)})"


def batches(indices: Sequence[int], size: int) -> list[list[int]]:
    """``indices`` cut into consecutive runs of at most ``size`` (>= 1)."""
    size = max(1, int(size))
    return [list(indices[i:i + size]) for i in range(0, len(indices), size)]


# Imported once by the fork server: what every worker needs before its first frame.
_PRELOAD = ["sonarsim.dataset.workers", "sonarsim.dataset.writer", "sonarsim.renderer.simulator"]


def worker_context() -> multiprocessing.context.BaseContext:
    """The multiprocessing context of the worker processes (see the module docstring)."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(_PRELOAD)
        return context
    return multiprocessing.get_context("spawn")  # pragma: no cover - Windows


def _running(pid: int) -> bool:
    """Whether process ``pid`` is alive (not gone, not a zombie awaiting its reaper)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - someone else's process: alive
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as handle:
            return handle.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):  # no /proc (macOS): kill(0) said enough
        return True


def _exit_with_parent(parent: int) -> None:
    """End this worker once the process that started the pool is gone (SIGKILL leaves no one to
    shut the pool down, and an idle worker would wait for tasks forever). Its pid is watched,
    not this process's parent: a worker's parent is the fork server, which outlives it."""
    while _running(parent):
        time.sleep(0.5)
    os._exit(1)


def _cli_warnings() -> bool:
    """Whether this process shows warnings in the command line's one-line form
    (:func:`sonarsim.core.console.install_warning_format`), which its workers should then share."""
    return warnings.showwarning is show_warning


def _init_worker(scenario: Scenario, options: Any, width: int, threads: int | None, parent: int,
                 out: Any = None, cli_warnings: bool = False) -> None:
    if cli_warnings:
        # A worker starts from the fork server, not from the command: without this its
        # warnings (a plane facing away, say) would print in Python's raw form.
        install_warning_format()
    _STATE.update(scenario=scenario, options=options, width=width, cache=SimulatorCache(threads=threads), out=out)
    threading.Thread(target=_exit_with_parent, args=(parent,), daemon=True).start()


def render_batch(indices: Sequence[int], scenario: Scenario | None = None, options: Any = None,
                 width: int | None = None, cache: SimulatorCache | None = None) -> list[Any]:
    """Render and encode frames ``indices``: a list of :class:`~sonarsim.dataset.encoding.EncodedFrame`.

    In a worker process the arguments after ``indices`` come from its start-up state. A local
    worker that was given the dataset folder writes each frame's files itself (atomically, as
    the parent would) and sends back the record alone: the parent, one process for all the
    workers, then only appends manifest lines instead of receiving and writing a megabyte a
    frame (which held two workers to 1.3-1.7x one once frames took 3 ms).
    """
    scenario = scenario if scenario is not None else _STATE["scenario"]
    options = options if options is not None else _STATE["options"]
    width = width if width is not None else _STATE["width"]
    cache = cache if cache is not None else _STATE["cache"]
    folder = _STATE.get("out") if cache is _STATE.get("cache") else None
    return list(rendered_frames(indices, scenario, options, width, cache, folder))


def rendered_frames(indices: Sequence[int], scenario: Scenario, options: Any, width: int, cache: SimulatorCache,
                    folder: Any = None, writers: int = 1) -> Iterator[Any]:
    """Render frames ``indices`` in order and encode each (and write its files into ``folder``,
    sending back ``files == ()``) on writer threads, while the next frames render.

    Encoding is deflate (NPZ entries, PNGs), digests and file writes, which release the GIL: a
    frame's encoding overlaps the next one's render. ``writers`` frames wait for the writers
    at most (:data:`FRAME_COPIES` counts one; :func:`encoded_frames` gives a lone worker two
    writers only where a core would idle otherwise), and the frames come out in order, their
    bytes what one thread would make (each is encoded from its own render alone).
    """
    from dataclasses import replace

    labels = rendered_labels(options.labels)

    def finish(spec: Any, image: Any) -> Any:
        encoded = encode_frame(spec, image, options, width)
        if folder is not None:
            _write_files(folder, encoded)
            encoded = replace(encoded, files=())
        return encoded

    from collections import deque

    writers = max(1, int(writers))
    with cf.ThreadPoolExecutor(writers, thread_name_prefix="sonarsim-encode") as pool:
        pending: deque = deque()
        for k in indices:
            spec = scenario.frame(k)
            image = render_frame(spec, cache, labels)
            if len(pending) >= writers:
                yield pending.popleft().result()
            pending.append(pool.submit(finish, spec, image))
        while pending:
            yield pending.popleft().result()


def encoded_frames(scenario: Scenario, indices: Sequence[int], options: Any, width: int, workers: int = 1,
                   threads: int | None = None, batch_size: int | None = None, out: Any = None) -> Iterator[Any]:
    """Render and encode ``indices``, yielding each frame's result as soon as its task is done.

    Parameters
    ----------
    scenario : Scenario
    indices : sequence of int
        Frames to make.
    options : DatasetOptions
    width : int
        Digits of the frame numbers in file names.
    workers : int
        1: in this process, frame after frame; N > 1: N worker processes.
    threads : int, optional
        Ray-casting threads per simulator; default: the cores divided among the workers.
    batch_size : int, optional
        Frames per task; default: small enough that every worker gets several tasks.
    out : path, optional
        The dataset folder: worker processes write each frame's files there themselves and
        yield frames without file contents (``files == ()``; their record names them).

    Yields
    ------
    EncodedFrame
        In the order tasks finish (by index within a task).
    """
    workers = max(1, min(workers, len(indices)))  # an idle process is memory for nothing
    if threads is None:
        threads = lone_threads(options) if workers <= 1 else max(1, available_cores() // workers)
    if workers <= 1:
        writers = lone_writers(threads, frame_memory_bytes(scenario, options.labels))
        with SimulatorCache(threads=threads) as cache:
            yield from rendered_frames(indices, scenario, options, width, cache, out, writers)
        return
    if batch_size is None:
        batch_size = max(1, min(8, len(indices) // (4 * workers)))
    tasks = batches(indices, batch_size)
    context = worker_context()
    pool = cf.ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker,
                                  initargs=(scenario, options, width, threads, os.getpid(), out,
                                            _cli_warnings()))
    try:
        pending: set[cf.Future] = set()
        queue = iter(tasks)
        # A bounded number of tasks in flight: results are consumed as they come, and a stop
        # (Ctrl-C, an error) leaves little queued work to cancel.
        for task in queue:
            pending.add(pool.submit(render_batch, task))
            if len(pending) >= 2 * workers:
                break
        while pending:
            done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for future in done:
                task = next(queue, None)
                if task is not None:
                    pending.add(pool.submit(render_batch, task))
                try:
                    result = future.result()
                except cf.process.BrokenProcessPool:
                    from ..errors import SonarsimError

                    raise SonarsimError("a worker process died (killed, or out of memory: try fewer --workers); "
                                        "the frames written so far are kept: run again to resume") from None
                yield from result
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _import_ray() -> Any:
    """The ``ray`` module, or a SonarsimError naming the extra."""
    from ..errors import SonarsimError

    try:
        import ray
    except ImportError as exc:
        raise SonarsimError(f"--ray needs the 'ray' library ({exc}); {RAY_HINT}") from None
    return ray


class _RayRenderer:
    """A Ray actor: one scenario, its simulators kept between tasks (as a worker process)."""

    def __init__(self, scenario: Scenario, options: Any, width: int, threads: int | None) -> None:
        self.scenario, self.options, self.width = scenario, options, width
        self.cache = SimulatorCache(threads=threads)

    def render(self, indices: Sequence[int]) -> list[Any]:
        return render_batch(indices, self.scenario, self.options, self.width, self.cache)


def encoded_frames_ray(scenario: Scenario, indices: Sequence[int], options: Any, width: int, address: str,
                       workers: int | None = None, threads: int | None = None,
                       batch_size: int | None = None) -> Iterator[Any]:
    """As :func:`encoded_frames`, on a Ray cluster: ``workers`` actors, results streamed back.

    Parameters
    ----------
    address : str
        The cluster (``ray.init(address=...)``: ``"auto"`` for the cluster this machine belongs
        to, ``"ray://host:10001"``, ...), or ``"local"``: a new Ray instance on this machine.
    workers : int, optional
        Actors (one CPU each); default: the cluster's CPUs.
    threads : int, optional
        Ray-casting threads per actor (default 1: one actor per CPU).

    Notes
    -----
    Ray is started here if it is not running in this process yet, and left running (a later
    call reuses it); ``ray.shutdown()`` ends it.
    """
    ray = _import_ray()
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address != "local":
            kwargs["address"] = address
        ray.init(**kwargs)
    if workers is None:
        workers = max(1, int(ray.cluster_resources().get("CPU", 1)))
    if batch_size is None:
        batch_size = max(1, min(8, len(indices) // (4 * workers)))
    actor_cls = ray.remote(num_cpus=1)(_RayRenderer)
    scenario_ref = ray.put(scenario)
    actors = [actor_cls.remote(scenario_ref, options, width, threads or 1) for _ in range(workers)]
    queue = iter(batches(indices, batch_size))
    pending: dict[Any, Any] = {}
    try:
        # Two tasks per actor in flight: an actor never waits for the writer, and the writer
        # gets results as they finish (ray.wait), not in submission order.
        for actor in actors:
            for _ in range(2):
                task = next(queue, None)
                if task is not None:
                    pending[actor.render.remote(task)] = actor
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            ref = done[0]
            actor = pending.pop(ref)
            task = next(queue, None)
            if task is not None:
                pending[actor.render.remote(task)] = actor
            yield from ray.get(ref)
    finally:
        for ref in pending:
            ray.cancel(ref, force=True)
        for actor in actors:
            ray.kill(actor)
