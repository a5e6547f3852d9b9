"""Is the sonar inside an object? A closed surface around the sonar hides the whole scene.

A sonar placed inside an object (a pose inside a sphere, a track through a block) sees only the
object's inside: its image shows nothing of the scene, and nothing says why. The
:class:`~sonarsim.renderer.simulator.Simulator` asks :class:`InsideTest` when it is built (the
scene's pose) and for every other pose it renders, and warns once per object.

The test is the parity of crossings: from a point inside a closed surface, any ray crosses it
an odd number of times. Six rays (three directions and their opposites) are followed through
the scene with its own ray caster, surface after surface; an object holds the point when every
ray crosses it an odd number of times and meets it first from its inside (the back of its
faces, which point outwards on a solid). So an open mesh (a terrain, a bowl: some ray leaves
through the open side) is never said to hold the sonar, nor is a room or a tank modelled with
its faces towards the inside (the sonar is meant to be in there).

Cost: a point outside every object's bounding box (the usual pose) is settled by one
comparison per object (about 15 us in all). Within a box, one cast of the six rays settles most
points: a ray that meets nothing, or meets the object first from the front, shows the point is
outside it (a sonar above a terrain whose hills rise above it: the rays upwards meet nothing).
Only a point every ray finds enclosed is followed surface after surface (a few casts, under a
millisecond). The last position is cached.

Limits: the objects are tested as the caster holds them, clipped to the water side of the
planes: a ball sunk into the floor is open at the floor, and a sonar inside it is not reported.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

# Three directions, off the axes and the diagonals (along which the edges of boxes and of
# regular tessellations lie: a ray through an edge meets two faces), and their opposites.
_DIRECTIONS = np.array([[0.5377, 0.8284, -0.1566], [-0.6711, 0.2137, 0.7099], [0.3126, -0.5902, 0.7443]])
_DIRECTIONS = _DIRECTIONS / np.linalg.norm(_DIRECTIONS, axis=1, keepdims=True)
_DIRECTIONS = np.vstack([_DIRECTIONS, -_DIRECTIONS])
# A ray that crosses more surfaces than this is given up on (the point is then "not inside").
_MAX_CROSSINGS = 256


class InsideTest:
    """Which objects enclose a point: closed surfaces around it, by the parity of crossings.

    Parameters
    ----------
    caster : RayCaster
        Built over ``meshes`` (answers ``intersect(..., with_uv=True)`` with mesh ids in their
        order).
    meshes : sequence of TriangleMesh
        The objects in world coordinates, as the caster holds them.
    names : sequence of str
        The objects' names, in the same order.
    reach_m : float
        How far the rays are followed (beyond every object).
    """

    def __init__(self, caster, meshes: Sequence, names: Sequence[str], reach_m: float = 4e6) -> None:
        self._caster = caster
        self._meshes = list(meshes)
        self._names = list(names)
        self._reach = float(reach_m)
        boxes = [(m.vertices.min(axis=0), m.vertices.max(axis=0)) if len(m.faces) else
                 (np.full(3, np.inf), np.full(3, -np.inf)) for m in self._meshes]
        self._lo = np.array([b[0] for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._hi = np.array([b[1] for b in boxes], dtype=np.float64).reshape(-1, 3)
        self._last: tuple[tuple, list[str]] | None = None
        self._ignored: tuple[frozenset[str], np.ndarray] | None = None

    def moved(self, caster, meshes: dict, boxes: dict | None = None) -> None:
        """Objects moved (mesh index -> its new mesh), cast through ``caster`` from now on.

        ``boxes`` (mesh index -> (lo, hi), metres) may give boxes that hold the meshes (the
        posed corners of the object's own box: no pass over its vertices); by default the
        meshes' own."""
        self._caster = caster
        for k, m in meshes.items():
            self._meshes[k] = m
            if not len(m.faces):
                self._lo[k], self._hi[k] = np.inf, -np.inf
            elif boxes is not None and k in boxes:
                self._lo[k], self._hi[k] = boxes[k]
            else:
                self._lo[k], self._hi[k] = m.vertices.min(axis=0), m.vertices.max(axis=0)
        self._last = None

    def holding(self, point, ignore: frozenset[str] = frozenset()) -> list[str]:
        """Names of the objects whose closed surface encloses ``point`` (world, metres).

        Objects named in ``ignore`` are not tested (a simulator that has warned about them).
        """
        key = (tuple(float(v) for v in np.ravel(point)), ignore)
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        p = np.asarray(key[0], dtype=np.float64)
        inside_box = np.all((self._lo <= p) & (p <= self._hi), axis=1)
        if ignore:
            if self._ignored is None or self._ignored[0] != ignore:  # once per set, not per frame
                self._ignored = (ignore, np.array([name not in ignore for name in self._names], dtype=bool))
            inside_box &= self._ignored[1]
        out = self._parity(p, inside_box) if inside_box.any() else []
        self._last = (key, out)
        return out

    def _parity(self, p: np.ndarray, candidate: np.ndarray) -> list[str]:
        n_rays, n_meshes = len(_DIRECTIONS), len(self._meshes)
        counts = np.zeros((n_rays, n_meshes), dtype=np.int64)
        candidate = candidate.copy()
        origins = np.tile(p, (n_rays, 1))
        travelled = np.zeros(n_rays)
        alive = np.arange(n_rays)
        for crossing in range(_MAX_CROSSINGS):
            hits = self._caster.intersect(origins[alive], _DIRECTIONS[alive], self._reach, with_uv=True)
            hit = np.isfinite(hits.distance) & (hits.mesh_id >= 0)
            if crossing == 0 and not hit.all():
                return []  # a ray that meets nothing left every closed surface, if it was in one
            for r, k, f in zip(alive[hit], hits.mesh_id[hit], hits.primitive_id[hit]):
                # From inside a solid, a ray meets it first from behind (its faces point
                # outwards); a room or tank modelled with its faces inwards is met from the front.
                if counts[r, k] == 0 and candidate[k] and not self._faces_away(int(k), int(f), _DIRECTIONS[r]):
                    candidate[k] = False
                counts[r, k] += 1
            if not candidate.any():
                return []
            alive, dist = alive[hit], hits.distance[hit].astype(np.float64)
            if not len(alive):
                break
            # On past the surface just met: a step of a few float32 steps of the coordinates
            # (the caster's precision), so that the same face is not met again.
            travelled[alive] += dist
            step = 1e-6 * np.maximum(1.0, np.abs(origins[alive]).max(axis=1)) + 1e-6 * dist
            origins[alive] = origins[alive] + _DIRECTIONS[alive] * (dist + step)[:, None]
            if np.all(travelled[alive] > self._reach):
                break
        else:
            return []  # too many surfaces to count: say nothing
        inside = candidate & np.all(counts % 2 == 1, axis=0)
        return [self._names[k] for k in np.flatnonzero(inside)]

    def _faces_away(self, k: int, face: int, direction: np.ndarray) -> bool:
        """Whether triangle ``face`` of mesh ``k`` faces away from a ray along ``direction``
        (its winding's normal, outward for a solid, points the way the ray goes)."""
        a, b, c = self._meshes[k].vertices[self._meshes[k].faces[face]]
        return float(np.dot(np.cross(b - a, c - a), direction)) > 0.0
