"""core.streams: the one home of the random streams (issue 23, item 5).

The streams are distinct, a frame's generator is a function of (seed, frame) alone, and the ids
and derivations are what they were before they moved here (so every rendered image, speckled
frame, dataset frame and texture stays bit-identical).
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from sonarsim.core import streams
from sonarsim.core.streams import (
    BEAM_DRAWS, BEAM_STREAM, FRAME_STREAM, POOL_STREAM, TEXTURE_STREAM, WORLD_STREAM, beam_rng, frame_rng, frame_seed,
    pool_rng, scenario_rng, sequential_rng, texture_entropy, texture_rng, world_key, world_rng,
)


def first(rng: np.random.Generator, n: int = 3) -> list[int]:
    return rng.integers(0, 2**32, n).tolist()


def test_the_ids_are_what_they_were():
    assert (FRAME_STREAM, POOL_STREAM, WORLD_STREAM, BEAM_STREAM, TEXTURE_STREAM) == (1, 2, 3, 4, 5)
    assert dict(BEAM_DRAWS) == {"beam_gain": 0, "bang": 1}
    assert dict(streams.STREAMS) == {"frame": 1, "pool": 2, "world": 3, "beam": 4, "texture": 5}


def test_old_homes_still_export_the_names():
    from sonarsim.dataset import scenario
    from sonarsim.scene import floor_texture
    from sonarsim.sensor import model, speckle
    assert model.beam_rng is beam_rng and model.BEAM_DRAWS is BEAM_DRAWS
    assert (model.FRAME_STREAM, model.POOL_STREAM, model.WORLD_STREAM, model.BEAM_STREAM) == (1, 2, 3, 4)
    assert speckle.POOL_STREAM == POOL_STREAM
    assert floor_texture.TEXTURE_STREAM == TEXTURE_STREAM
    assert scenario.frame_seed is frame_seed


@pytest.mark.parametrize("seed", [0, 7, 2**31 + 5])
def test_the_derivations_are_the_entropy_lists_they_were(seed):
    """Each generator is default_rng of the same entropy list as before the move."""
    same = lambda a, b: first(a, 8) == first(b, 8)  # noqa: E731
    assert same(frame_rng(seed, 5), np.random.default_rng([seed, 1, 5]))
    assert same(frame_rng(seed), np.random.default_rng([seed, 1, 0]))
    assert same(pool_rng(seed), np.random.default_rng([seed, 2]))
    assert same(beam_rng(seed, "beam_gain"), np.random.default_rng([seed, 4, 0]))
    assert same(beam_rng(seed, "bang"), np.random.default_rng([seed, 4, 1]))
    assert same(sequential_rng(seed), np.random.default_rng(seed))
    cell = np.array([3.0, -2.0, 7.0, 0.0, 40.0, -1.0])
    key = int.from_bytes(hashlib.blake2b(cell.astype(np.int64).tobytes(), digest_size=8).digest(), "little")
    assert world_key(cell) == key
    assert same(world_rng(seed, cell), np.random.default_rng([seed, 3, key]))
    assert texture_entropy(seed, 0) == (seed, 5, 1)
    assert texture_entropy(seed, 2) == (seed, 5, 3)
    assert texture_entropy(seed, 2, seed=9) == (9, 5)
    assert same(texture_rng((seed, 5, 1)), np.random.default_rng([seed, 5, 1]))
    word = np.random.SeedSequence([seed, 3]).generate_state(1, np.uint64)[0]
    assert frame_seed(seed, 3) == int(word) & (2**63 - 1)
    assert same(scenario_rng(seed, 3), np.random.default_rng(frame_seed(seed, 3)))


def test_regression_first_draws():
    """First draws, integers(0, 2**32, 3), computed with the code before the streams moved here
    (sensor.model.beam_rng, np.random.default_rng([...]) at each former site, and
    dataset.scenario.frame_seed, at commit 7959c61): they must never change."""
    assert first(beam_rng(7, "beam_gain")) == [2282365616, 878185625, 3240726578]
    assert first(beam_rng(7, "bang")) == [4130747303, 2126796130, 1066150179]
    assert first(frame_rng(11, 3)) == [747860122, 1829800634, 954030950]
    assert first(pool_rng(7)) == [1208267292, 1193873271, 656516905]
    assert first(np.random.default_rng([7, WORLD_STREAM, 12345])) == [709444461, 3893859095, 430774392]
    # The texture's, since its own id (5; before, under 4: [1932154149, ...] and [3070425964, ...]).
    assert first(texture_rng(texture_entropy(11, 0))) == [1402971697, 1355046252, 195275963]
    assert first(texture_rng(texture_entropy(11, 0, seed=5))) == [2241889808, 2947759701, 3794413493]
    assert [frame_seed(99, k) for k in range(3)] == [1680710531199098514, 588121100675164068,
                                                     5778322905919529231]
    assert first(scenario_rng(99, 0)) == [172224518, 516281451, 3522509968]
    assert first(sequential_rng(11)) == [574671950, 552204816, 3423435367]


def test_different_streams_draw_differently_for_one_seed():
    seed, word = 7, 1
    draws = {
        "frame": first(frame_rng(seed, word), 4),
        "pool": first(pool_rng(seed), 4),
        "world": first(np.random.default_rng([seed, WORLD_STREAM, word]), 4),
        "beam": first(beam_rng(seed, "bang"), 4),
        "sequential": first(sequential_rng(seed), 4),
        "scenario": first(scenario_rng(seed, word), 4),
    }
    assert len({tuple(d) for d in draws.values()}) == len(draws), draws
    # the same extra word under each id differs too
    by_id = [tuple(first(np.random.default_rng([seed, s, word]), 4)) for s in (FRAME_STREAM, POOL_STREAM,
                                                                               WORLD_STREAM, BEAM_STREAM)]
    assert len(set(by_id)) == 4
    # within a stream: frames, effects, keys and seeds differ
    assert first(frame_rng(seed, 0)) != first(frame_rng(seed, 1)) != first(frame_rng(seed + 1, 1))
    assert first(beam_rng(seed, "beam_gain")) != first(beam_rng(seed, "bang"))
    assert first(world_rng(seed, np.zeros(6))) != first(world_rng(seed, np.ones(6)))
    assert texture_entropy(seed, 0) != texture_entropy(seed, 1)
    assert len({frame_seed(seed, k) for k in range(100)}) == 100


def test_the_texture_no_longer_reads_the_beam_factors_streams():
    """Textures had the beam factors' id (4): plane 0's texture without a seed of its own read
    the bang pattern's numbers, and a texture seeded s the stripes of a scene seeded s. Their
    own id (5) since."""
    for s in (0, 11, 12345):
        beams = [first(beam_rng(s, "bang")), first(beam_rng(s, "beam_gain"))]
        assert first(texture_rng(texture_entropy(s, 0))) not in beams
        assert first(texture_rng(texture_entropy(0, 0, seed=s))) not in beams


def test_a_frame_is_the_same_whatever_order_frames_are_asked_in():
    frames = [0, 1, 2, 5, 40]
    forward = {f: first(frame_rng(3, f), 5) for f in frames}
    backward = {f: first(frame_rng(3, f), 5) for f in reversed(frames)}
    assert forward == backward
    # and whatever else was drawn in between
    for f in frames:
        pool_rng(3).random(100)
        beam_rng(3, "bang").random(7)
        assert first(frame_rng(3, f), 5) == forward[f]
    scen = {k: first(scenario_rng(3, k)) for k in frames}
    assert {k: first(scenario_rng(3, k)) for k in reversed(frames)} == scen
    # numpy integers and Python integers name the same frame
    assert first(frame_rng(np.int64(3), np.int32(5)), 5) == forward[5]


def test_unknown_beam_effect_is_refused():
    with pytest.raises(KeyError):
        beam_rng(0, "stripes")

