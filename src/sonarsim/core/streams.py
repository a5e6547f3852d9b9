"""Every random stream of the package: from a seed and a frame, effect or key to a generator.

One home for the stream ids and for the derivations (issue 23, item 5): the renderer, the sensor,
the floor textures and the datasets all take their generators from here, so two streams cannot
be given the same id by two modules that do not know of each other.

Each generator is ``numpy.random.default_rng(entropy)`` with ``entropy`` a list of integers,
``[seed, stream, ...]``: numpy's ``SeedSequence`` hashes the whole list, so generators whose lists
differ in any word draw independent numbers. Streams, by id:

======  ======================  ==================================================================
id      entropy                 what it feeds
======  ======================  ==================================================================
(none)  ``seed``                :func:`sequential_rng`: the renderer's generator when no frame
                                index is given (one generator, frame after frame), and the
                                K-distributed speckle field a sensor draws, without its pool, to
                                tabulate its law
1       ``[seed, 1, frame]``    :func:`frame_rng`: a frame's speckle (``anchor: frame``), noise,
                                common noise and, without a sensor, the renderer's exponential
                                speckle; frame 0 is the sensor's default
2       ``[seed, 2]``           :func:`pool_rng`: the sensor's pool of filtered speckle and noise
                                fields (drawn once per sonar)
3       ``[seed, 3, key]``      :func:`world_rng`: world-anchored speckle (``anchor: world``), key
                                a hash of the pose quantised to half a resolution cell
4       ``[seed, 4, k]``        :func:`beam_rng`: the seeded per-beam factors, ``k`` one of
                                :data:`BEAM_DRAWS` (0 the channels' gain stripes, 1 the bang's
                                pattern across beams)
5       ``[seed, 5]`` or        :func:`texture_entropy`, :func:`texture_rng`: a floor texture's
        ``[render.seed, 5,      tile (its own seed given, or ``render.seed`` and the plane's index
        plane + 1]``            + 1)
(none)  ``SeedSequence(         :func:`frame_seed`, :func:`scenario_rng`: a dataset scenario's
        [seed, k])``            per-frame scene draws (pose, objects, materials); the renderer's
                                own draws for frame ``k`` come from :func:`frame_rng`
======  ======================  ==================================================================

Known overlaps:

* Before issue 23, a floor texture's tile used the beam factors' id (4): ``SeedSequence`` pads
  entropy shorter than four words with zeros, so a texture with its own seed ``s`` (``[s, 4]``)
  drew the numbers of the gain stripes of a scene seeded ``s``, and plane 0's texture without a
  seed (``[render.seed, 4, 1]``) those of the same scene's bang pattern. Textures have their own
  id (5) since; textured images differ from earlier releases' by their draws only.
* :func:`sequential_rng` feeds both the renderer's frame-after-frame generator and a K-speckle
  sensor's law (the two read the same numbers for different purposes).
* Seeds of 2**32 and above are two or more words to ``SeedSequence``: ``[seed, stream, ...]``
  then no longer keeps the stream in the second word. Scene seeds are small in practice.

Only :mod:`numpy` and the standard library: core imports nothing of the package above it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from types import MappingProxyType

import numpy as np

__all__ = [
    "BEAM_DRAWS", "BEAM_STREAM", "FRAME_STREAM", "POOL_STREAM", "STREAMS", "TEXTURE_STREAM", "WORLD_STREAM",
    "beam_rng", "frame_rng", "frame_seed", "pool_rng", "scenario_rng", "sequential_rng", "texture_entropy",
    "texture_rng", "world_key", "world_rng",
]

#: The second word of a frame's generator: ``[seed, FRAME_STREAM, frame]`` (:func:`frame_rng`).
FRAME_STREAM = 1
#: The sensor's pool of speckle and noise fields: ``[seed, POOL_STREAM]`` (:func:`pool_rng`).
POOL_STREAM = 2
#: World-anchored speckle: ``[seed, WORLD_STREAM, key]`` (:func:`world_rng`).
WORLD_STREAM = 3
#: The seeded per-beam factors: ``[seed, BEAM_STREAM, BEAM_DRAWS[effect]]`` (:func:`beam_rng`).
BEAM_STREAM = 4
#: A floor texture's tile (:func:`texture_entropy`); its own id (it was BEAM_STREAM's: see above).
TEXTURE_STREAM = 5
#: The third word of :func:`beam_rng`'s entropy for each seeded per-beam effect.
BEAM_DRAWS: Mapping[str, int] = MappingProxyType({"beam_gain": 0, "bang": 1})
#: Every stream id by name.
STREAMS: Mapping[str, int] = MappingProxyType({"frame": FRAME_STREAM, "pool": POOL_STREAM, "world": WORLD_STREAM,
                                               "beam": BEAM_STREAM, "texture": TEXTURE_STREAM})


def sequential_rng(seed: int) -> np.random.Generator:
    """The plain seed's generator, ``numpy.random.default_rng(seed)``.

    Parameters
    ----------
    seed : int
        ``render.seed`` (or a sensor's seed).

    Returns
    -------
    numpy.random.Generator
        Feeds the renderer's draws when no frame index is given (one generator that advances
        frame after frame, so a sequence of renders is reproducible but a frame is not on its
        own), and the K-distributed speckle field a sensor built without its pool draws to
        tabulate the law of its expected output.
    """
    return np.random.default_rng(int(seed))


def frame_rng(seed: int, frame: int = 0) -> np.random.Generator:
    """The generator of frame ``frame``: ``default_rng([seed, FRAME_STREAM, frame])``.

    Parameters
    ----------
    seed : int
        ``render.seed`` (a dataset's scenes take the scenario's seed).
    frame : int
        The frame index; 0 is also what a sensor draws when given no generator.

    Returns
    -------
    numpy.random.Generator
        Feeds a frame's speckle window (``anchor: frame``), its receiver and common noise, and,
        without a sensor, the renderer's exponential speckle. A function of ``(seed, frame)``
        alone: the same whatever frames were asked for before, in any process.
    """
    return np.random.default_rng([int(seed), FRAME_STREAM, int(frame)])


def pool_rng(seed: int) -> np.random.Generator:
    """The generator of a sensor's speckle and noise pool: ``default_rng([seed, POOL_STREAM])``.

    Parameters
    ----------
    seed : int
        The sensor's seed (``render.seed``).

    Returns
    -------
    numpy.random.Generator
        Feeds the few filtered speckle and noise fields a
        :class:`~sonarsim.sensor.speckle.SpecklePool` holds, drawn once per sonar.
    """
    return np.random.default_rng([int(seed), POOL_STREAM])


def world_key(cell: np.ndarray) -> int:
    """A 64-bit key of a quantised pose: BLAKE2b (8 bytes, little-endian) of its int64 words.

    Parameters
    ----------
    cell : array of int
        The pose (position and roll, pitch, yaw) divided by the anchoring cell and floored.

    Returns
    -------
    int
        In ``[0, 2**64)``.
    """
    words = np.asarray(cell).astype(np.int64).tobytes()
    return int.from_bytes(hashlib.blake2b(words, digest_size=8).digest(), "little")


def world_rng(seed: int, cell: np.ndarray) -> np.random.Generator:
    """The generator of a quantised pose: ``default_rng([seed, WORLD_STREAM, world_key(cell)])``.

    Parameters
    ----------
    seed : int
        The sensor's seed (``render.seed``).
    cell : array of int
        The pose quantised to half a resolution cell (see
        :meth:`~sonarsim.sensor.model.SensorModel.anchored_rng`).

    Returns
    -------
    numpy.random.Generator
        Feeds world-anchored speckle (``anchor: world``): a still sonar reads the same speckle
        window frame after frame.
    """
    return np.random.default_rng([int(seed), WORLD_STREAM, world_key(cell)])


def beam_rng(seed: int, effect: str) -> np.random.Generator:
    """The generator of a scene's seeded per-beam factors: ``[seed, BEAM_STREAM, BEAM_DRAWS[effect]]``.

    Parameters
    ----------
    seed : int
        The sensor's seed (``render.seed``).
    effect : {'beam_gain', 'bang'}
        A key of :data:`BEAM_DRAWS`.

    Returns
    -------
    numpy.random.Generator
        Feeds the channels' gain stripes (``beam_gain.std_db``) or the bang's pattern across beams
        (``bang.beam_std_db``): fixed for the scene's seed, the same in every frame.

    Raises
    ------
    KeyError
        ``effect`` is not a key of :data:`BEAM_DRAWS`.
    """
    return np.random.default_rng([int(seed), BEAM_STREAM, BEAM_DRAWS[effect]])


def texture_entropy(render_seed: int, plane_index: int, seed: int | None = None) -> tuple[int, ...]:
    """The entropy of a plane's floor texture.

    Parameters
    ----------
    render_seed : int
        ``render.seed``.
    plane_index : int
        The plane's index among the scene's reflecting planes.
    seed : int, optional
        The texture's own ``seed``.

    Returns
    -------
    tuple of int
        ``(seed, TEXTURE_STREAM)`` with a seed of its own, else
        ``(render_seed, TEXTURE_STREAM, plane_index + 1)`` (two such planes differ). A tuple, so
        that the tile it seeds can be cached by it (:func:`texture_rng` makes the generator).
    """
    if seed is not None:
        return (int(seed), TEXTURE_STREAM)
    return (int(render_seed), TEXTURE_STREAM, int(plane_index) + 1)


def texture_rng(entropy: tuple[int, ...]) -> np.random.Generator:
    """The generator of a floor texture's tile: ``default_rng(list(entropy))``.

    Parameters
    ----------
    entropy : tuple of int
        From :func:`texture_entropy`.

    Returns
    -------
    numpy.random.Generator
        Feeds the white noise that, filtered, is the texture's periodic tile (anchored in the
        world: the same every frame).
    """
    return np.random.default_rng([int(e) for e in entropy])


def frame_seed(seed: int, k: int) -> int:
    """The seed of frame ``k`` of a scenario seeded with ``seed``: a 63-bit integer.

    Parameters
    ----------
    seed : int
        The scenario's ``seed``.
    k : int
        The frame index.

    Returns
    -------
    int
        ``SeedSequence([seed, k])``'s first 64-bit word with the top bit cleared (so that it is
        a non-negative int64 wherever it is stored: JSON, NPZ, ROS messages). The frame's scene
        draws come from ``numpy.random.default_rng(frame_seed(seed, k))`` (:func:`scenario_rng`).
    """
    word = np.random.SeedSequence([int(seed), int(k)]).generate_state(1, np.uint64)[0]
    return int(word) & (2**63 - 1)


def scenario_rng(seed: int, k: int) -> np.random.Generator:
    """The generator of frame ``k``'s scene draws: ``default_rng(frame_seed(seed, k))``.

    Parameters
    ----------
    seed : int
        The scenario's ``seed``.
    k : int
        The frame index.

    Returns
    -------
    numpy.random.Generator
        Feeds the frame's pose (random trajectories) and then its variation (objects, materials,
        sensor keys). The renderer's own draws for the frame come from :func:`frame_rng` with the
        scenario's seed as ``render.seed``.
    """
    return np.random.default_rng(frame_seed(seed, k))
