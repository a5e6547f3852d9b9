"""Ray casting through our own binding to Embree 4's C API (:mod:`sonarsim.trace._embree4`).

The Embree library is the one the embreex wheel bundles (``embreex.libs/libembree4-*.so*``),
opened at run time. Compared with :class:`~sonarsim.trace.embree.EmbreeCaster` (embreex's
one-ray-at-a-time ``run``): packets of 8 rays, a high-quality BVH, and the conversion to
:class:`~sonarsim.trace.base.Hits` done per packet while it is in cache. Same interface, same
answers (tests/trace/test_embree4.py compares the two ray by ray and frame by frame).
"""

from __future__ import annotations

import glob
import importlib
import importlib.util
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..errors import SonarsimError
from ..scene.meshes import TriangleMesh
from .base import Hits, available_cores, nonempty_meshes

# Below this many rays per thread, waking a sleeping thread costs more than it saves: on the
# project's machine 38,500 rays cast in 0.95 ms on one thread and 1.18 ms on two, whose second
# thread had slept between casts (as between a frame's casts); two only win from ~80,000 rays.
MIN_RAYS_PER_CHUNK = 40_000


def find_library() -> str | None:
    """Path of the Embree 4 library inside the installed embreex wheel, or None.

    auditwheel puts it in ``embreex.libs/`` beside the ``embreex`` package, named
    ``libembree4-<hash>.so.<major>``; the hash changes with every wheel, hence the pattern.
    """
    spec = importlib.util.find_spec("embreex")
    if spec is None or not spec.submodule_search_locations:
        return None
    for package_dir in spec.submodule_search_locations:
        libs = os.path.join(os.path.dirname(os.path.abspath(package_dir)), "embreex.libs")
        found = sorted(glob.glob(os.path.join(libs, "libembree4*.so*")))
        if found:
            return found[0]
    return None


# Embree 4's ray-hit structures (include/embree4/rtcore_ray.h) as the library in the embreex
# wheel is built: with instance arrays (an ``instPrimID`` after ``instID``) and one instance
# level. Byte offsets of the first lane of each field; a packet field is 8 lanes x 4 bytes.
LAYOUT8 = {"tfar": 8 * 32, "Ng_x": 12 * 32, "u": 15 * 32, "v": 16 * 32, "primID": 17 * 32, "geomID": 18 * 32,
           "instID": 19 * 32, "instPrimID": 20 * 32}
SIZE8 = 21 * 32
LAYOUT1 = {"tfar": 32, "Ng_x": 48, "u": 60, "v": 64, "primID": 68, "geomID": 72, "instID": 76, "instPrimID": 80}
SIZE1 = 96
INVALID_ID = 0xFFFFFFFF
CANARY = 0xA5


def _square_rays() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """8 rays straight down onto the square ``|x|, |y| <= 1, z = 0`` from 1 m above it."""
    xy = np.linspace(-0.4, 0.4, 8)
    o = np.column_stack([xy, xy[::-1], np.ones(8)]).astype(np.float32)
    return o, np.tile(np.array([0, 0, -1], np.float32), (8, 1)), np.full(8, 10.0, np.float32)


def verify_layout(binding) -> None:
    """Check the declared ray-hit structures against what the loaded library writes.

    The declared sizes and offsets must be Embree 4's (:data:`LAYOUT8`, :data:`LAYOUT1`). Then,
    on a one-square scene, a packet of 8 and a single ray are cast into structures filled with
    canary bytes and followed by 64 more: Embree must write ``geomID``, ``instID`` and
    ``instPrimID`` (as invalid: no instances) where declared, leave the lanes a partial packet
    marks inactive alone, and write nothing past the structure. A library built otherwise (no
    instance arrays, or more instance levels) fails here instead of corrupting memory later.

    Raises
    ------
    SonarsimError
        What differs.
    """
    declared = (binding.RAYHIT8_SIZE, binding.RAYHIT8_OFFSETS, binding.RAYHIT1_SIZE, binding.RAYHIT1_OFFSETS)
    if declared != (SIZE8, LAYOUT8, SIZE1, LAYOUT1):
        raise SonarsimError(f"the binding's ray-hit structures are not Embree 4's: declared {declared}")
    square = binding.Scene([np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)],
                           [np.array([[0, 1, 2], [0, 2, 3]], np.int32)], device_config(1))
    problems = []
    try:
        o, d, tfar = _square_rays()
        for m in (8, 3):
            raw = square.probe_packet(o, d, tfar, m)

            def lanes(field, dtype=np.uint32):
                return np.frombuffer(raw, dtype=dtype, count=8, offset=LAYOUT8[field])

            if raw[SIZE8:] != bytes([CANARY]) * 64:
                problems.append("Embree wrote past the 672-byte RTCRayHit8")
            for field, want in (("geomID", 0), ("instID", INVALID_ID), ("instPrimID", INVALID_ID)):
                if not np.all(lanes(field)[:m] == want):
                    problems.append(f"packet lanes' {field} not written as expected")
                if not np.all(lanes(field)[m:] == int.from_bytes(bytes([CANARY]) * 4, "little")):
                    problems.append(f"inactive lanes' {field} written")
            if not np.allclose(lanes("tfar", np.float32)[:m], 1.0):
                problems.append("packet hit distances wrong")
        raw = square.probe_single(0.2, -0.3, 2.0, 0.0, 0.0, -1.0, 10.0)
        single = {f: int.from_bytes(raw[LAYOUT1[f]:LAYOUT1[f] + 4], "little") for f in ("geomID", "instID", "instPrimID")}
        if single != {"geomID": 0, "instID": INVALID_ID, "instPrimID": INVALID_ID} or raw[SIZE1:] != bytes([CANARY]) * 64:
            problems.append(f"single ray: {single}, bytes past the 96-byte RTCRayHit written: {raw[SIZE1:] != bytes([CANARY]) * 64}")
    finally:
        square.close()
    if problems:
        raise SonarsimError("the Embree library does not answer packets as declared "
                            f"(instance arrays, one instance level, a valid mask per lane): {'; '.join(sorted(set(problems)))}")


def device_config(threads: int) -> str:
    """Embree's device configuration for a caster of ``threads`` threads (it sets the build's).

    Never ``threads=1``: with it, the bundled Embree and TBB keep one TBB worker spinning in
    ``sched_yield`` for as long as the device lives, a whole core burnt even while idle (it made
    two single-threaded workers share one core with two spinners). One thread leaves TBB its
    default, so a one-thread caster's build (once, before the first frame) may use every core;
    its casts still run on the calling thread alone.
    """
    return f"threads={threads}" if threads > 1 else ""


_verified: set = set()


def load_binding():
    """The compiled binding with Embree 4 bound and its ray-hit layout verified (once per process).

    Raises
    ------
    SonarsimError
        The extension was not built, the library cannot be found or opened, or it lays out ray
        hits otherwise than declared (:func:`verify_layout`).
    """
    try:
        # By name, not ``from . import _embree4``: the compiled extension imports nothing of
        # sonarsim, but a static import of it reads, to an import graph of the .py files, as an
        # import of this package, whose make_caster imports this module (a false cycle).
        _embree4 = importlib.import_module(f"{__package__}._embree4")
    except ImportError as exc:
        raise SonarsimError(f"the 'embree4' backend's extension sonarsim.trace._embree4 is not built ({exc}); "
                            "reinstall sonarsim from source, or use backend 'embree' with SONARSIM_EMBREE=embreex") from None
    if _embree4.loaded_path() is None:
        path = find_library()
        if path is None:
            raise SonarsimError("the 'embree4' backend found no Embree 4 library: it looks for "
                                "embreex.libs/libembree4-*.so* beside the installed embreex package "
                                "(`pip install embreex`); set SONARSIM_EMBREE=embreex to use embreex's own caster")
        _embree4.load(path)
    if _embree4.loaded_path() not in _verified:
        verify_layout(_embree4)
        _verified.add(_embree4.loaded_path())
    return _embree4


class Embree4Caster:
    """Closest-hit queries against a static Embree 4 scene, in packets of 8 rays.

    Parameters
    ----------
    meshes : sequence of TriangleMesh
        World-frame meshes; a hit's ``mesh_id`` is the index in this sequence.
    threads : int, optional
        Worker threads; default: the number of CPU cores available to this process.
    coherent : bool
        Tell Embree that the 8 rays of a packet are coherent (neighbours in a sonar's fan:
        nearly the same origin and direction), which selects its packet traversal that shares
        the BVH walk between lanes: 1.5x faster on a demo frame than the incoherent default, the
        same hits. False for rays in random order.
    dynamic : bool
        Meshes that move (:meth:`replace_meshes`): every mesh, empty or not, is its own Embree
        geometry (id = mesh index) in a two-level BVH, so that moving one refits its tree
        alone. A static caster (the default) builds one high-quality tree over them all.
    """

    name = "embree4"

    def __init__(self, meshes: Sequence[TriangleMesh], threads: int | None = None, coherent: bool = True,
                 dynamic: bool = False) -> None:
        binding = load_binding()
        self._binding = binding
        self.coherent = coherent
        self.dynamic = bool(dynamic)
        self.threads = threads or available_cores()
        self.n_meshes = len(meshes)
        if self.dynamic:
            self._ids, kept = np.arange(len(meshes), dtype=np.int32), list(meshes)
        else:
            self._ids, kept = nonempty_meshes(meshes)
        self._scene = None
        self._closed = False
        if kept:
            self._scene = binding.Scene(
                [np.ascontiguousarray(m.vertices, dtype=np.float32) for m in kept],
                [np.ascontiguousarray(m.faces, dtype=np.int32) for m in kept],
                # Dynamic: the scene's own quality is that of the tree over the geometries, built
                # again at every commit: high (spatial splits) made a commit 5 ms, low 0.05 ms;
                # each geometry keeps its own tree (refitted), and casts stay as fast.
                device_config(self.threads), "low" if self.dynamic else "high", self.dynamic,
            )
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def _chunks(self, n: int, threads: int | None, min_chunk: int | None = None) -> np.ndarray:
        n_chunks = min(threads or self.threads, self.threads, max(1, n // (min_chunk or MIN_RAYS_PER_CHUNK)))
        return np.linspace(0, n, n_chunks + 1).astype(int)

    def _map(self, fn, bounds: np.ndarray) -> None:
        if len(bounds) == 2 or self._pool is None:
            fn(bounds[0], bounds[-1])
        else:
            # The binding releases the GIL for the whole chunk: the pool runs them in parallel.
            list(self._pool.map(lambda ab: fn(*ab), zip(bounds[:-1], bounds[1:])))

    def cast_raw(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray, threads: int | None = None,
                 with_uv: bool = False, min_chunk: int | None = None) -> dict:
        """Embree's raw answer, as :meth:`EmbreeCaster.cast_raw` gives it (for benchmarks).

        Parameters
        ----------
        origins, directions : (n, 3) float32 C-contiguous ndarrays, metres and unit vectors
        tfar : (n,) float32 ndarray, metres
            Per-ray maximum distance; cut to the hit distances in place, as embreex does.
        threads : int, optional
            At most this many threads (default: the caster's).
        with_uv : bool
            Not supported by the raw path (raises).
        min_chunk : int, optional
            Split over the threads only from this many rays per thread (default
            :data:`MIN_RAYS_PER_CHUNK`).

        Returns
        -------
        dict with ``tfar`` (n,), ``geomID`` (n,) int32 (-1 for a miss), ``Ng`` (n, 3) float32.
        """
        if self._closed:
            raise SonarsimError("this Embree4Caster is released")
        if with_uv:
            raise NotImplementedError("Embree4Caster.cast_raw gives no u, v; use intersect(..., with_uv=True)")
        n = len(directions)
        geom = np.full(n, -1, np.int32)
        ng = np.zeros((n, 3), np.float32)
        if self._scene is not None and n:
            scene = self._scene
            coherent = self.coherent
            self._map(lambda a, b: scene.cast_raw(origins[a:b], directions[a:b], tfar[a:b], geom[a:b], ng[a:b], coherent),
                      self._chunks(n, threads, min_chunk))
        return {"tfar": tfar, "geomID": geom, "Ng": ng}

    def intersect(self, origins: np.ndarray, directions: np.ndarray, max_distance: float,
                  threads: int | None = None, with_uv: bool = False) -> Hits:
        """Closest hits (see :meth:`sonarsim.trace.base.RayCaster.intersect`).

        Parameters
        ----------
        origins : (n, 3) or (3,) float array, metres
        directions : (n, 3) float array, unit vectors
        max_distance : float, metres
        threads : int, optional
        with_uv : bool
            Also the triangle hit and its barycentric ``(u, v)``.

        Returns
        -------
        Hits
        """
        if self._closed:
            raise SonarsimError("this Embree4Caster is released")
        n = len(directions)
        if self._scene is None or n == 0:
            return Hits.misses(n, with_uv)
        o = np.ascontiguousarray(np.broadcast_to(origins, (n, 3)), dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.full(n, max_distance, dtype=np.float32)
        hits = Hits(np.empty(n, np.float32), np.empty(n, np.int32), np.empty((n, 3), np.float32))
        if with_uv:
            hits = replace(hits, primitive_id=np.empty(n, np.int32), barycentric=np.empty((n, 2), np.float32))
        scene, ids, h, coherent = self._scene, self._ids, hits, self.coherent
        if with_uv:
            def run(a, b):
                scene.cast(o[a:b], d[a:b], tfar[a:b], ids, h.distance[a:b], h.mesh_id[a:b], h.normal[a:b],
                           h.primitive_id[a:b], h.barycentric[a:b], coherent)
        else:
            def run(a, b):
                scene.cast(o[a:b], d[a:b], tfar[a:b], ids, h.distance[a:b], h.mesh_id[a:b], h.normal[a:b],
                           coherent=coherent)
        self._map(run, self._chunks(n, threads))
        return hits

    def replace_meshes(self, meshes: dict[int, TriangleMesh]) -> dict[int, str]:
        """Move meshes in place: mesh ``k`` becomes ``meshes[k]`` for the next casts.

        Only the moved meshes' trees change (refitted where the faces are the same, rebuilt where
        a plane's clip changed them); the scene's address, which the compiled kernels hold,
        stays. Casts must not run meanwhile (a simulator moves objects between frames).

        Parameters
        ----------
        meshes : dict of int to TriangleMesh
            Mesh index -> its new world-frame mesh.

        Returns
        -------
        dict of int to str
            What each geometry went through: ``'refit'``, ``'rebuilt'`` or ``'disabled'``.

        Raises
        ------
        SonarsimError
            The caster is not dynamic, or is released.
        """
        if self._closed:
            raise SonarsimError("this Embree4Caster is released")
        if not self.dynamic:
            raise SonarsimError("this Embree4Caster is static (dynamic=False): its meshes cannot move")
        done = {}
        if self._scene is None:
            return done
        for k, mesh in meshes.items():
            if not 0 <= k < self.n_meshes:
                raise ValueError(f"mesh index {k} out of range 0..{self.n_meshes - 1}")
            done[k] = self._scene.replace(int(k), np.asarray(mesh.vertices, dtype=np.float32),
                                          np.ascontiguousarray(mesh.faces, dtype=np.int32))
        if done:
            self._scene.commit()
        return done

    def packet_loop(self) -> tuple | None:
        """What the compiled kernels need to cast through the binding's packet loop themselves
        (:class:`sonarsim.renderer._kernels.PathBlocks`).

        Returns
        -------
        (scene, scene_address, cast_address, ids, coherent) or None
            The binding's ``Scene`` (to keep alive), its address, the address of the packet loop
            ``cast_rays``, the mesh index of each Embree geometry and the coherence flag; None
            when the caster has no triangles.
        """
        if self._closed:
            raise SonarsimError("this Embree4Caster is released")
        if self._scene is None:
            return None
        return self._scene, self._scene.address(), self._binding.cast_rays_address(), self._ids, self.coherent

    @property
    def released(self) -> bool:
        """Whether :meth:`release` has freed the Embree scene (nothing may cast through it)."""
        return self._closed

    def close(self) -> None:
        """Stop the worker threads; later casts run on the calling thread (as EmbreeCaster's).

        A closed simulator still renders (it closes its casters), so the Embree scene stays:
        it is released with the caster (garbage collection) or at once by :meth:`release`.
        """
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    def release(self) -> None:
        """Stop the threads and release Embree's scene and device now; the caster is done (idempotent)."""
        self.close()
        self._closed = True
        if getattr(self, "_scene", None) is not None:
            self._scene.close()
            self._scene = None

    def __del__(self) -> None:
        self.close()  # the binding's Scene releases Embree's objects when it is collected
