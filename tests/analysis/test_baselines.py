"""The trivial images a realism score is reported beside, and the ceiling (issue 22 item 1)."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.baselines import (baseline_images, held_out_scores, local_mean_image, range_profile_image,
                                         separable_image)


def test_the_range_profile_is_each_rows_mean_in_every_beam():
    x = np.arange(12, dtype=float).reshape(3, 4)
    assert np.array_equal(range_profile_image(x), np.repeat([[1.5], [5.5], [9.5]], 4, axis=1))
    mask = np.zeros((3, 4), bool)
    mask[:2, :2] = True  # row 2 has no cell: 0
    assert np.array_equal(range_profile_image(x, mask)[:, 0], [0.5, 4.5, 0.0])


def test_a_separable_image_is_its_own_separable_baseline_and_a_row_constant_one_its_range_profile():
    rows, cols = np.linspace(1, 5, 20), np.linspace(0.5, 2, 8)
    separable = np.outer(rows, cols)
    assert np.allclose(separable_image(separable), separable)
    assert not np.allclose(range_profile_image(separable), separable)
    constant_rows = np.repeat(rows[:, None], 8, axis=1)
    assert np.allclose(range_profile_image(constant_rows), constant_rows)
    assert np.allclose(local_mean_image(np.full((30, 20), 7.0)), 7.0)


def _frames(structure: bool, n: int, seed: int = 0):
    """A pattern in counts (a band along range; with ``structure`` also an object's echo in a
    few beams beyond it, which no range or separable profile holds) under unit-mean gamma
    speckle (contrast 0.32) drawn anew in each frame."""
    rng = np.random.default_rng(seed)
    rows, cols = np.arange(200)[:, None], np.arange(64)[None, :]
    truth = 30.0 + 120.0 * np.exp(-0.5 * ((rows - 80) / 15.0) ** 2) + 0.0 * cols
    if structure:
        truth = truth + 300.0 * np.exp(-0.5 * (((rows - 150) / 6.0) ** 2 + ((cols - 40) / 4.0) ** 2))
    return truth, [truth * rng.gamma(10.0, 0.1, size=truth.shape) for _ in range(n)]


def test_the_true_pattern_beats_the_trivial_images_only_where_it_has_structure_they_lack():
    # A seeded statistic: speckle drawn anew per frame, the images made from frame 0 and scored on
    # frames 1-3. The true pattern's margin over the best trivial image is clear when the
    # pattern has 2D structure, and nothing when it is a range profile alone; nothing made from
    # one noisy frame beats the truth.
    for structure, lo, hi in ((True, 1.5, 20.0), (False, -0.05, 0.3)):
        truth, frames = _frames(structure, 4)
        scores = held_out_scores({"truth": truth, **baseline_images(frames[0])}, frames[1:])
        assert lo < scores["truth"]["margin_db"] < hi, (structure, scores)
        assert scores["ceiling"]["psnr"] < scores["truth"]["psnr"], (structure, scores)


def test_scores_need_held_out_frames():
    with pytest.raises(ValueError, match="no held-out frames"):
        held_out_scores({"a": np.zeros((4, 4))}, [])


@pytest.mark.parametrize("name, n, expected", [
    # DESIGN.md section 10 and the figures: range profile, separable, ceiling (dB).
    ("oculus/three_pings_8bit.raw", 3, {"range profile": 19.1, "separable": 19.2, "ceiling": 21.4}),
    ("aris/sample.aris", 6, {"range profile": 24.8, "separable": 25.55, "ceiling": 25.8}),
])
def test_the_baselines_of_the_real_recordings(shared_data, name, n, expected):
    path = shared_data / "real" / name
    frames = [np.asarray(sonarsim.read(path, k).polar, float) for k in range(n)]
    scores = held_out_scores(baseline_images(frames[0]), frames[1:])
    for key, value in expected.items():
        assert scores[key]["psnr"] == pytest.approx(value, abs=0.15), (key, scores)
