"""Ray casting with Intel Embree through ``embreex``, called directly, over all CPU cores.

``embreex`` releases the GIL inside ``EmbreeScene.run``, so a thread pool over chunks of rays
uses every core. Calling it directly (not through trimesh's wrapper) avoids the wrapper's
per-call overhead and its multi-hit machinery, 3-5x faster here.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Sequence

import numpy as np

from ..errors import SonarsimError
from ..scene.meshes import TriangleMesh
from .base import Hits, available_cores, nonempty_meshes

try:  # the same post-processing as below, as one compiled loop
    from . import _hits
except ImportError:  # not built (a source tree used without installing)
    _hits = None

# Below this many rays per thread, the thread hand-off costs more than it saves.
MIN_RAYS_PER_CHUNK = 8192


def embree_hits(tfar: np.ndarray, geom_id: np.ndarray, ng: np.ndarray, ids: np.ndarray) -> Hits:
    """Embree's raw answer as :class:`~sonarsim.trace.base.Hits` (NumPy twin of ``trace._hits.embree_hits``).

    Parameters
    ----------
    tfar : (n,) float32 array
        Distance to the hit, metres (meaningless for a miss).
    geom_id : (n,) int32 array
        Embree's geometry id, -1 for a miss.
    ng : (n, 3) float32 array
        Unnormalised geometric normal (meaningless for a miss).
    ids : (n_geometries,) int32 array
        Mesh index of each Embree geometry (empty meshes are not given to Embree).

    Returns
    -------
    Hits
        float32 distance (``inf`` for a miss), mesh index (-1), unit normal (0).
    """
    tfar = np.asarray(tfar, dtype=np.float32)
    ng = np.asarray(ng, dtype=np.float32).reshape(-1, 3)
    hit = np.asarray(geom_id) >= 0
    mesh_id = np.full(len(hit), -1, dtype=np.int32)
    mesh_id[hit] = np.asarray(ids, dtype=np.int32)[np.asarray(geom_id)[hit]]
    distance = np.where(hit, tfar, np.float32(np.inf)).astype(np.float32)
    g = ng[hit]
    with np.errstate(divide="ignore", invalid="ignore"):
        # float32 sum of squares and root; the division is correctly rounded either way.
        inv = (1.0 / np.sqrt(g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1] + g[:, 2] * g[:, 2]).astype(np.float64)).astype(np.float32)
    normal = np.zeros((len(hit), 3), dtype=np.float32)
    normal[hit] = g * inv[:, None]
    return Hits(distance, mesh_id, normal)



class EmbreeCaster:
    """Closest-hit queries against a static Embree scene.

    Parameters
    ----------
    meshes : sequence of TriangleMesh
        World-frame meshes; a hit's ``mesh_id`` is the index in this sequence.
    threads : int, optional
        Worker threads; default: the number of CPU cores available to this process.
    """

    name = "embree"

    def __init__(self, meshes: Sequence[TriangleMesh], threads: int | None = None) -> None:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh as EmbreeMesh
        except ImportError as exc:  # pragma: no cover - embreex is a core dependency
            raise SonarsimError(
                f"the 'embree' backend needs the embreex package ({exc}); install it with "
                "`pip install embreex`, or use backend='numpy'"
            ) from None
        self.threads = threads or available_cores()
        self.n_meshes = len(meshes)
        self._scene = None
        self._ids, meshes = nonempty_meshes(meshes)
        if meshes:
            # robust=False: 15-35% faster; closed meshes lose no hits at this precision.
            self._scene = rtcore_scene.EmbreeScene(robust=False)
            for m in meshes:
                EmbreeMesh(
                    scene=self._scene,
                    vertices=np.ascontiguousarray(m.vertices, dtype=np.float32),
                    indices=np.ascontiguousarray(m.faces, dtype=np.int32),
                )
            # Commit now (the first query would), so that no query pays for the build.
            self._scene.run(np.zeros((1, 3), np.float32), np.full((1, 3), 0.5773503, np.float32))
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None

    def _run(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray) -> dict:
        return self._scene.run(origins, directions, dists=tfar, output=1)

    def cast_raw(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray, threads: int | None = None,
                 with_uv: bool = False, min_chunk: int | None = None) -> dict:
        """Embree's own answer for contiguous float32 rays, over the thread pool.

        This is the bare ray-casting cost that benchmarks compare a whole frame against.

        Parameters
        ----------
        origins, directions : (n, 3) float32 C-contiguous ndarrays
        tfar : (n,) float32 ndarray
            Per-ray maximum distance.
        threads : int, optional
            At most this many threads (default: the caster's).
        with_uv : bool
            Also keep ``primID`` and the barycentric ``u``, ``v`` of each hit.
        min_chunk : int, optional
            Split over the threads only from this many rays per thread (default
            :data:`MIN_RAYS_PER_CHUNK`).

        Returns
        -------
        dict with ``tfar`` (n,), ``geomID`` (n,), ``Ng`` (n, 3) as embreex returns them (and
        ``primID``, ``u``, ``v`` with ``with_uv``).
        """
        o, d, n = origins, directions, len(directions)
        n_chunks = min(threads or self.threads, self.threads, max(1, n // (min_chunk or MIN_RAYS_PER_CHUNK)))
        if n_chunks == 1 or self._pool is None:
            res = self._run(o, d, tfar)
        else:
            bounds = np.linspace(0, n, n_chunks + 1).astype(int)
            parts = list(
                self._pool.map(
                    lambda ab: self._run(o[ab[0]:ab[1]], d[ab[0]:ab[1]], tfar[ab[0]:ab[1]]),
                    zip(bounds[:-1], bounds[1:]),
                )
            )
            keys = ("tfar", "geomID", "Ng") + (("primID", "u", "v") if with_uv else ())
            res = {k: np.concatenate([p[k] for p in parts]) for k in keys}
        return res

    def intersect(self, origins: np.ndarray, directions: np.ndarray, max_distance: float,
                  threads: int | None = None, with_uv: bool = False) -> Hits:
        n = len(directions)
        if self._scene is None or n == 0:
            return Hits.misses(n, with_uv)
        o = np.ascontiguousarray(np.broadcast_to(origins, (n, 3)), dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        tfar = np.full(n, max_distance, dtype=np.float32)
        res = self.cast_raw(o, d, tfar, threads, with_uv=True) if with_uv else self.cast_raw(o, d, tfar, threads)
        if _hits is not None:
            hits = Hits(np.empty(n, np.float32), np.empty(n, np.int32), np.empty((n, 3), np.float32))
            _hits.embree_hits(res["tfar"], res["geomID"], res["Ng"], self._ids, hits.distance, hits.mesh_id, hits.normal)
        else:
            hits = embree_hits(res["tfar"], res["geomID"], res["Ng"], self._ids)
        if not with_uv:
            return hits
        miss = hits.mesh_id < 0
        prim = np.where(miss, -1, res["primID"]).astype(np.int32)
        bary = np.column_stack([res["u"], res["v"]]).astype(np.float32)
        bary[miss] = 0.0
        return replace(hits, primitive_id=prim, barycentric=bary)

    def close(self) -> None:
        if getattr(self, "_pool", None) is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    def __del__(self) -> None:
        self.close()
