"""The fan's 8-bit levels resampled from the polar grid's (FanMapper.levels): the compiled
kernel and its NumPy twin give the same bytes; constants stay constant; a ramp across range
comes out as the hand-computed blend; nothing outside the fan."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.image.fan import FanMapper, _fan_levels_kernel
from sonarsim.image.grid import PolarGrid

GRIDS = [
    PolarGrid(0.5, 6.0, 120, np.linspace(14.0, -14.0, 32)),
    PolarGrid(1.0, 30.0, 333, np.linspace(60.0, -60.0, 97)),  # odd sizes, a wide fan
    PolarGrid(0.2, 2.0, 40, np.linspace(5.0, -5.0, 3)),
]

needs_kernel = pytest.mark.skipif(_fan_levels_kernel() is None, reason="the compiled fan kernel is not built")


@needs_kernel
@pytest.mark.parametrize("grid", GRIDS, ids=["aris-like", "wide-odd", "three-beams"])
def test_the_kernel_and_its_numpy_twin_give_the_same_bytes(grid):
    rng = np.random.default_rng(5)
    mapper = FanMapper.from_grid(grid)
    for _ in range(3):
        levels = rng.integers(0, 256, grid.shape, dtype=np.uint8)
        a = mapper.levels(levels, compiled=True)
        b = mapper.levels(levels, compiled=False)
        assert a.dtype == np.uint8 and a.shape == mapper.shape
        assert np.array_equal(a, b)


@pytest.mark.parametrize("compiled", [pytest.param(True, marks=needs_kernel), False])
def test_a_constant_stays_constant_inside_the_fan_and_zero_outside(compiled):
    grid = GRIDS[0]
    mapper = FanMapper.from_grid(grid)
    out = mapper.levels(np.full(grid.shape, 173, np.uint8), compiled=compiled)
    assert np.all(out[mapper.mask] == 173) and np.all(out[~mapper.mask] == 0)


@pytest.mark.parametrize("compiled", [pytest.param(True, marks=needs_kernel), False])
def test_a_ramp_across_range_is_the_hand_computed_blend(compiled):
    """Levels 2 r (row r) blend linearly across range: a pixel at fractional range index
    ``r + f`` gets ``2 r + 2 f``, to the rounding of 8-bit weights (within 1 level)."""
    grid = GRIDS[0]
    mapper = FanMapper.from_grid(grid)
    levels = np.repeat((2 * np.arange(grid.n_range_bins)).astype(np.uint8)[:, None], grid.n_beams, axis=1)
    out = mapper.levels(levels, compiled=compiled)
    rng = np.hypot(mapper.x_m[:, None], mapper.y_m[None, :])[mapper.mask]  # (x down the rows, y across)
    index = np.clip((rng - grid.range_min_m) / grid.range_resolution_m - 0.5, 0, grid.n_range_bins - 1)
    np.testing.assert_allclose(out[mapper.mask], 2 * index, atol=1.0)


def test_nearest_takes_the_nearest_level_and_bad_input_is_refused():
    grid = GRIDS[2]
    mapper = FanMapper.from_grid(grid, interpolation="nearest")
    levels = np.arange(np.prod(grid.shape), dtype=np.uint8).reshape(grid.shape)
    ids = mapper.ids(levels.astype(np.int32))
    out = mapper.levels(levels)
    assert np.array_equal(out[mapper.mask], ids[mapper.mask].astype(np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        mapper.levels(levels.astype(np.float32))
    with pytest.raises(ValueError, match="shape"):
        mapper.levels(levels[:-1])
