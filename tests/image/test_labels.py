"""The :class:`~sonarsim.image.labels.Labels` container: boxes, NPZ names, fan resampling.

Hand-made label maps (no renderer), so that each expectation is written out.
"""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.image.fan import FanMapper
from sonarsim.image.grid import PolarGrid
from sonarsim.image.labels import Labels, boxes_of


def test_boxes_of_hand_made_map():
    inst = np.full((6, 5), -1, np.int32)
    inst[1:3, 2] = 0  # rows 1-2, column 2
    inst[4, 0] = 0  # widens id 0 to rows 1-4, columns 0-2
    inst[5, 4] = 2
    got = boxes_of(inst, 4)
    assert got.dtype == np.int32
    assert got.tolist() == [[1, 0, 4, 2], [-1, -1, -1, -1], [5, 4, 5, 4], [-1, -1, -1, -1]]


def test_boxes_of_agrees_with_a_loop_on_random_maps():
    rng = np.random.default_rng(5)
    for _ in range(20):
        h, w, n = rng.integers(1, 30), rng.integers(1, 30), int(rng.integers(1, 7))
        inst = rng.integers(-1, n, (h, w)).astype(np.int32)
        inst[rng.uniform(size=(h, w)) < 0.7] = -1
        got = boxes_of(inst, n)
        for k in range(n):
            rows, cols = np.nonzero(inst == k)
            want = [rows.min(), cols.min(), rows.max(), cols.max()] if len(rows) else [-1] * 4
            assert got[k].tolist() == want


def test_boxes_of_an_empty_map():
    assert boxes_of(np.zeros((0, 4), np.int32), 2).tolist() == [[-1] * 4] * 2


def _labels(n_r=40, n_b=8):
    rng = np.random.default_rng(1)
    total = np.full((n_r, n_b), -1, np.int32)
    total[10:20, 2:5] = 1
    total[25:30, 0:2] = 0
    elev = np.where(total >= 0, rng.uniform(-7, 7, total.shape), np.nan).astype(np.float32)
    n = 6
    return Labels(
        ids=("rock", "ground"),
        instance={"object": total, "ground": np.full_like(total, -1), "single": total, "total": total},
        elevation_deg=elev, elevation_min_deg=elev - 1, elevation_max_deg=elev + 1,
        points_world=rng.normal(size=(n, 3)).astype(np.float32), points_object=np.zeros(n, np.int32),
        points_component=np.zeros(n, np.int8), points_cell=np.zeros((n, 2), np.int32),
        point_components=("object", "ground"), boxes_polar=boxes_of(total, 2),
    )


def test_arrays_use_the_contract_names():
    lab = _labels()
    a = lab.arrays()
    assert a["instance"] is lab.instance["total"]
    assert "instance_total" not in a and "instance_object" in a and "instance_single" in a
    assert a["elevation_deg"].dtype == np.float32
    assert a["label_ids"].tolist() == ["rock", "ground"] and a["label_ids"].dtype.kind == "U"
    assert a["point_components"].tolist() == ["object", "ground"]
    for key in ("points_world", "points_object", "points_component", "points_cell", "boxes_polar",
                "elevation_min_deg", "elevation_max_deg"):
        assert key in a


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_fan_labels_are_nearest_neighbour_whatever_the_mapper(interpolation):
    lab = _labels()
    az = 15.0 - (np.arange(8) + 0.5) * 30.0 / 8
    grid = PolarGrid(1.0, 5.0, 40, az)
    fan = lab.fan(FanMapper.from_grid(grid, 0.05, interpolation))
    ids = set(np.unique(fan.instance).tolist())
    assert ids == {-1, 0, 1}  # no blended ids
    assert fan.instance.shape == fan.mask.shape == fan.elevation_deg.shape
    assert (fan.instance[~fan.mask] == -1).all()
    # Every elevation in the fan is one of the polar cells' (nothing interpolated).
    inside = np.isfinite(fan.elevation_deg)
    assert np.isin(fan.elevation_deg[inside], lab.elevation_deg).all()
    np.testing.assert_array_equal(np.isfinite(fan.elevation_deg), fan.instance >= 0)
    np.testing.assert_array_equal(fan.boxes, boxes_of(fan.instance, 2))
