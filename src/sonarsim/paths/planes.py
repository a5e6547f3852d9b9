"""Reflecting planes as arrays, their mirror maps, and the plane sequences (chains) of path legs.

A path leg meets planes in order; a *chain* is that order, listed going out from the sonar
(``(floor, surface)``: the sound leaves the sonar, meets the floor, then the surface). Mirror
maps make the image-source method a matter of 3 x 4 affine maps:

* ``unfold[c]`` maps a point A to ``A* = M_p1 M_p2 ... M_pk A``: the straight line from the
  sonar O to A* leaves O in the direction the leg leaves it, and ``|A* - O|`` is the leg's
  length (mirror maps are isometries);
* ``source[c, j]`` is the image of O after its first ``j`` mirrors, ``M_pj ... M_p1 O``: walking
  back from A towards those images finds the reflection points (:func:`reflection_points`).

Surface ids of the per-ray labels: -1 nothing, ``p`` the plane ``p`` of the scene's
:attr:`~sonarsim.scene.Scene.reflecting_planes` (the ground first), ``P + k`` object ``k``.

A chain's mirrors are planes (``p < P``) or, where objects mirror, their triangles (mirror
``P + m`` is mirror ``m`` of :class:`~sonarsim.paths.facets.FacetSet`, an object's triangles
in one plane): every map below is the same for both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

# A reflection point may lie this far outside the water (round-off at a corner of two planes).
WATER_TOLERANCE_M = 1e-7


@dataclass(frozen=True)
class PlaneSet:
    """The scene's reflecting planes as arrays; plane ``p`` has surface id ``p``.

    Attributes
    ----------
    names : tuple of str
    normal : (P, 3) float64 ndarray
        Unit normals into the water.
    offset : (P,) float64 ndarray
        ``n . x`` on each plane, metres; the water is ``n . x > offset``.
    albedo, specular : (P,) float64 ndarray
        Diffuse coefficient of the plane's backscatter law (the albedo, or Lambert's mu) and
        specular reflectance R.
    """

    names: tuple[str, ...]
    normal: np.ndarray
    offset: np.ndarray
    albedo: np.ndarray
    specular: np.ndarray

    @classmethod
    def from_specs(cls, planes: Sequence) -> "PlaneSet":
        """From :class:`~sonarsim.scene.PlaneSpec` objects (any number, also none)."""
        normal = np.array([p.normal for p in planes], dtype=float).reshape(-1, 3)
        return cls(
            names=tuple(p.name for p in planes),
            normal=normal,
            offset=np.array([p.offset_m for p in planes], dtype=float),
            albedo=np.array([p.backscatter.coefficient for p in planes], dtype=float),
            specular=np.array([p.specular for p in planes], dtype=float),
        )

    def __len__(self) -> int:
        return len(self.names)

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """(..., P) signed distances of points (..., 3) from every plane, positive in the water."""
        return np.asarray(points, dtype=float) @ self.normal.T - self.offset

    def facing(self, position: np.ndarray) -> np.ndarray:
        """(P,) bool: the planes whose water side the sonar at ``position`` is on.

        A sonar on the wrong side of a plane sees neither the plane nor any path through it.
        """
        return self.signed_distance(np.asarray(position, dtype=float).reshape(3)) > 0.0

    def mirror(self, p: int) -> np.ndarray:
        """(3, 4) affine map of the reflection across plane ``p`` (:func:`mirror_map`)."""
        return mirror_map(self.normal[p], float(self.offset[p]))


def mirror_map(normal: np.ndarray, offset: float) -> np.ndarray:
    """(3, 4) affine map of the reflection across the plane ``n . x = offset``:
    ``x - 2 (n.x - offset) n`` (n a unit normal)."""
    n = np.asarray(normal, dtype=float)
    out = np.empty((3, 4))
    out[:, :3] = np.eye(3) - 2.0 * np.outer(n, n)
    out[:, 3] = 2.0 * offset * n
    return out


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The (3, 4) affine map ``x -> a(b(x))``."""
    out = np.empty((3, 4))
    out[:, :3] = a[:, :3] @ b[:, :3]
    out[:, 3] = a[:, :3] @ b[:, 3] + a[:, 3]
    return out


def apply(affine: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (3, 4) affine map to points (..., 3)."""
    return np.asarray(points, dtype=float) @ affine[:, :3].T + affine[:, 3]


IDENTITY = np.hstack([np.eye(3), np.zeros((3, 1))])


@dataclass
class ChainTable:
    """The chains met in one frame, each with its mirror maps; chain 0 is the empty chain.

    Grows as the receive tracing finds new chains (:meth:`child`); the compiled tracing fills
    ``children`` itself and :meth:`sync` then adds the new entries. Mirror maps are formed
    when first asked for.

    Attributes
    ----------
    planes : PlaneSet
    origin : (3,) float64 ndarray
        The sonar O, metres.
    max_length : int
        Longest chain kept.
    children : (capacity, P) int32 ndarray
        ``children[c, p]``: the chain ``c + (p,)``, -1 where not met yet (planes).
    facets : FacetSet or None
        The mesh mirrors (mirror ``P + m`` is the facets' mirror ``m``); None: planes only.
    facet_children : dict
        ``(c, P + m)`` to the chain ``c + (P + m,)`` (mesh mirrors are too many for a dense table).
    """

    planes: PlaneSet
    origin: np.ndarray
    max_length: int
    capacity: int = 64
    facets: object = None
    chains: list = field(default_factory=list)
    children: np.ndarray = field(init=False)
    facet_children: dict = field(default_factory=dict)
    _unfold: dict = field(default_factory=dict)
    _sources: dict = field(default_factory=dict)
    _flat_index: tuple = (0, {})

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=float).reshape(3)
        self.children = np.full((self.capacity, max(len(self.planes), 1)), -1, dtype=np.int32)
        self.facet_children = {}
        self.chains = [()]
        # Maps are formed when first asked for: most chains of a frame never need them.
        self._unfold = {0: IDENTITY}
        self._sources = {0: self.origin[None, :].copy()}

    def __len__(self) -> int:
        return len(self.chains)

    def child(self, c: int, p: int) -> int:
        """Id of the chain ``chains[c] + (p,)``, added if new."""
        if p >= len(self.planes):
            k = self.facet_children.get((c, p), -1)
            if k < 0:
                k = len(self.chains)
                if k >= self.capacity:
                    self._grow()
                self.facet_children[(c, p)] = k
                self.chains.append(self.chains[c] + (p,))
            return k
        k = int(self.children[c, p])
        if k < 0:
            k = len(self.chains)
            if k >= self.capacity:
                self._grow()
            self.children[c, p] = k
            self.chains.append(self.chains[c] + (p,))
        return k

    def _grow(self) -> None:
        bigger = np.full((2 * self.capacity, self.children.shape[1]), -1, dtype=np.int32)
        bigger[: self.capacity] = self.children
        self.children, self.capacity = bigger, 2 * self.capacity

    def sync(self, n_chains: int) -> None:
        """Add the chains ``len(self) .. n_chains - 1`` that the kernel entered in ``children``."""
        if n_chains <= len(self.chains):
            return
        parent = {}
        rows = self.children[: len(self.chains) + n_chains]
        for c, p in zip(*np.nonzero(rows >= 0)):
            parent[int(rows[c, p])] = (int(c), int(p))
        for k in range(len(self.chains), n_chains):
            c, p = parent[k]
            self.chains.append(self.chains[c] + (p,))

    def add(self, chain: tuple) -> int:
        """Id of ``chain`` (a tuple of plane indices), added with its prefixes if new."""
        c = 0
        for p in chain:
            c = self.child(c, int(p))
        return c

    def canonical(self) -> tuple["ChainTable", np.ndarray]:
        """The same chains numbered canonically: by :meth:`key` (length, then planes from the
        sonar), so that a chain's id does not depend on which ray met it first (the blocks of a
        frame meet them in any order). Returns the new table and ``remap`` (int32, old id to
        new id)."""
        order = sorted(range(len(self.chains)), key=self.key)
        out = ChainTable(self.planes, self.origin, self.max_length, capacity=max(self.capacity, 1), facets=self.facets)
        remap = np.empty(len(self.chains), dtype=np.int32)
        for c in order:  # a prefix sorts before its chain: each is added after its parent
            remap[c] = out.add(self.chains[c])
        return out, remap

    def at(self, origin: np.ndarray) -> "ChainTable":
        """The same chains, numbered the same, for a sonar at ``origin``: the unfolding maps
        are kept (they do not depend on the sonar), the sonar's images are formed anew."""
        # Every field set here (not through __init__, whose table of -1 would be replaced at
        # once): a frame forms one of these with its caches cold.
        out = object.__new__(ChainTable)
        origin = np.asarray(origin, dtype=float).reshape(3)
        out.__dict__.update(planes=self.planes, origin=origin, max_length=self.max_length, capacity=self.capacity,
                            facets=self.facets, children=self.children.copy(), facet_children=dict(self.facet_children),
                            chains=list(self.chains), _unfold=dict(self._unfold), _sources={0: origin[None, :].copy()})
        return out

    @staticmethod
    def local_chains(parent: np.ndarray, last: np.ndarray, n_chains: int) -> list[tuple]:
        """The chains of a block's own numbering, by local id: chain ``c`` (0 < c < n_chains)
        is chain ``parent[c]`` followed by mirror ``last[c]``; 0 is the empty chain
        (``_kernels.PathBlocks.chain_parents``)."""
        chains: list = [()]
        for c in range(1, n_chains):  # a child's id is above its parent's
            chains.append(chains[int(parent[c])] + (int(last[c]),))
        return chains

    # A chain's mirrors, planes and facets alike -------------------------------------------

    def normal_of(self, p: int) -> np.ndarray:
        """(3,) unit normal of mirror ``p`` (a plane's into the water; a facet's own)."""
        n_planes = len(self.planes)
        return self.planes.normal[p] if p < n_planes else self.facets.mirror_normal[p - n_planes]

    def offset_of(self, p: int) -> float:
        """``n . x`` on mirror ``p``'s plane, metres."""
        n_planes = len(self.planes)
        return float(self.planes.offset[p] if p < n_planes else self.facets.mirror_offset[p - n_planes])

    def specular_of(self, p: int) -> float:
        """Specular reflectance R of mirror ``p``."""
        n_planes = len(self.planes)
        if p < n_planes:
            return float(self.planes.specular[p])
        return float(self.facets.specular[self.facets.mirror_obj[p - n_planes]])

    def name_of(self, p: int) -> str:
        """Name of mirror ``p``: the plane's, or the facet's object's."""
        n_planes = len(self.planes)
        return self.planes.names[p] if p < n_planes else self.facets.names[self.facets.mirror_obj[p - n_planes]]

    def mirror(self, p: int) -> np.ndarray:
        """(3, 4) affine map of the reflection across mirror ``p``'s plane."""
        return mirror_map(self.normal_of(p), self.offset_of(p))

    def flat(self, c: int) -> bool:
        """Chain ``c``'s mirrors all have point images (planes and flat facets): transmit legs
        along it can come from image sources."""
        n_planes = len(self.planes)
        facets = self.facets
        return all(p < n_planes or not facets.smooth[facets.mirror_obj[p - n_planes]] for p in self.chains[c])

    def flat_of_length(self, g: int) -> np.ndarray:
        """Ids (ascending) of the flat chains (:meth:`flat`) of length ``g``.

        Indexed once for the table as it stands (again when it has grown): asked once per
        smooth chain, a scan of every chain made the reciprocal pairs quadratic in the chains
        (a sphere of 82k smooth facets: 8 s of a frame's 8.1)."""
        n, index = self._flat_index
        if n != len(self.chains):
            lengths = np.fromiter((len(c) for c in self.chains), np.int64, len(self.chains))
            flat = np.fromiter((self.flat(c) for c in range(len(self.chains))), bool, len(self.chains))
            index = {int(k): np.flatnonzero(flat & (lengths == k)) for k in np.unique(lengths)}
            self._flat_index = (len(self.chains), index)
        return index.get(int(g), np.zeros(0, np.int64))

    # Views used by the path formation -----------------------------------------------------

    def length(self, c: int) -> int:
        return len(self.chains[c])

    def unfold(self, c: int) -> np.ndarray:
        """(3, 4) map A -> A* of chain ``c`` (see the module docstring)."""
        if c not in self._unfold:
            m = IDENTITY
            for p in self.chains[c]:
                m = compose(m, self.mirror(p))
            self._unfold[c] = m
        return self._unfold[c]

    def sources(self, c: int) -> np.ndarray:
        """(len + 1, 3) images of the sonar after 0, 1, ... mirrors of chain ``c``: each the
        last reflected across the next plane, ``x - 2 (n.x - offset) n``, in this order of
        operations (``_kernels.PathBlocks.options`` forms them the same way: the same bits)."""
        if c not in self._sources:
            src = [tuple(float(v) for v in self.origin)]
            for p in self.chains[c]:
                x0, x1, x2 = src[-1]
                n0, n1, n2 = (float(v) for v in self.normal_of(p))
                twice = 2.0 * (((x0 * n0 + x1 * n1) + x2 * n2) - self.offset_of(p))
                src.append((x0 - twice * n0, x1 - twice * n1, x2 - twice * n2))
            self._sources[c] = np.array(src)
        return self._sources[c]

    def specular(self, c: int) -> float:
        """Product of the specular reflectances along chain ``c``."""
        if not self.chains[c]:
            return 1.0
        if all(p < len(self.planes) for p in self.chains[c]):
            return float(np.prod(self.planes.specular[list(self.chains[c])]))
        return float(np.prod([self.specular_of(p) for p in self.chains[c]]))

    def key(self, c: int) -> tuple:
        """Sort key of chains for the reciprocal-pair convention: by number of planes, then by
        plane ids from the sonar outwards (lexicographic); a pair is formed from the greater."""
        return (len(self.chains[c]), self.chains[c])

    def name(self, c: int) -> str:
        """``surface-ground``: the planes in the order the sonar's side meets them."""
        return "-".join(self.name_of(p) for p in self.chains[c])


def reflection_points(
    planes: PlaneSet, chain: tuple[int, ...], sources: np.ndarray, points: np.ndarray, active: np.ndarray,
    facets=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Reflection points of the transmit legs from the sonar to ``points`` via ``chain``.

    Walks back from each point A towards the sonar's images (the image-source method) and
    checks that every reflection point lies on its mirror between its neighbours and inside the
    water (on the water side of every active plane); on a facet, inside its triangle.

    Parameters
    ----------
    planes : PlaneSet
    chain : tuple of int
        Mirrors in the order the sound meets them going out from the sonar (``P + m``: mesh mirror m).
    sources : (len(chain) + 1, 3) float array
        Images of the sonar (:meth:`ChainTable.sources`).
    points : (m, 3) float array
        Scatterers A, metres.
    active : (P,) bool array
        Planes that bound the water this frame.
    facets : FacetSet, optional
        The mesh mirrors, where ``chain`` holds some.

    Returns
    -------
    q : (m, len(chain), 3) float64 ndarray
        Reflection points, in the order met from the sonar.
    valid : (m,) bool ndarray
    """
    a = np.asarray(points, dtype=float)
    m, k = len(a), len(chain)
    n_planes = len(planes)
    q = np.full((m, k, 3), np.nan)
    valid = np.ones(m, dtype=bool)
    x = a
    for j in range(k - 1, -1, -1):
        p = chain[j]
        if p < n_planes:
            n, off = planes.normal[p], planes.offset[p]
        else:
            n, off = facets.mirror_normal[p - n_planes], facets.mirror_offset[p - n_planes]
        towards = sources[j + 1] - x
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (off - x @ n) / (towards @ n)
        ok = (t > 0.0) & (t < 1.0)
        x = x + t[:, None] * towards
        dist = planes.signed_distance(x)[:, active]
        ok &= np.all(dist >= -WATER_TOLERANCE_M * np.maximum(1.0, np.abs(x).max(axis=1))[:, None], axis=1)
        if p >= n_planes:
            ok &= facets.contains_mirror(p - n_planes, x)
        valid &= ok
        q[:, j] = x
    return q, valid
