"""Tests of sonarsim.image.grid.PolarGrid: hand-computed axes and edges, validation messages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.config.sonar import SonarConfig
from sonarsim.image.grid import PolarGrid, beam_edges_deg, sector_area_m2


def test_range_axis_of_a_hand_computed_grid():
    g = PolarGrid(1.0, 3.0, 4, (10.0, 0.0, -10.0))
    assert g.range_resolution_m == 0.5
    np.testing.assert_allclose(g.range_edges_m, [1.0, 1.5, 2.0, 2.5, 3.0])
    np.testing.assert_allclose(g.range_m, [1.25, 1.75, 2.25, 2.75])
    assert g.shape == (4, 3) and g.n_beams == 3


def test_beam_edges_of_an_uneven_table_lie_midway_and_half_a_spacing_outside():
    g = PolarGrid(0.0, 1.0, 1, [12.0, 4.0, 0.0, -6.0])
    # Midways 8, 2, -3; outer edges 12 + 8/2 and -6 - 6/2.
    np.testing.assert_allclose(g.beam_edges_deg, [16.0, 8.0, 2.0, -3.0, -9.0])
    assert (g.left_edge_deg, g.right_edge_deg) == (16.0, -9.0)
    assert g.azimuth_fov_deg == 25.0
    np.testing.assert_array_equal(g.azimuth_deg, [12.0, 4.0, 0.0, -6.0])
    assert g.beam_angles_deg == (12.0, 4.0, 0.0, -6.0)


def test_a_single_beam_takes_its_given_width():
    g = PolarGrid(0.5, 2.0, 3, [5.0], single_beam_width_deg=4.0)
    np.testing.assert_allclose(g.beam_edges_deg, [7.0, 3.0])
    np.testing.assert_allclose(beam_edges_deg([5.0]), [5.5, 4.5])  # default 1 degree


def test_area_is_the_annular_sector():
    g = PolarGrid(1.0, 3.0, 10, (15.0, -15.0))  # edges +30, -30: 60 degrees
    assert g.area_m2 == pytest.approx(0.5 * math.radians(60.0) * (9.0 - 1.0))
    assert sector_area_m2(2.0, 1.0, 10.0, -10.0) == 0.0
    assert sector_area_m2(1.0, 2.0, -10.0, 10.0) == 0.0


def test_describe():
    g = PolarGrid(0.5, 5.0, 400, (10.0, 0.0, -10.0))
    assert g.describe() == "0.5-5 m in 400 bins, 3 beams over 30 deg (+15 to -15)"


def test_grids_are_frozen_hashable_and_compare_by_value():
    a = PolarGrid(0.5, 5.0, 10, [1.0, 0.0])
    b = PolarGrid(0.5, 5, np.int64(10), np.array([1.0, 0.0]))
    assert a == b and hash(a) == hash(b)
    assert a != PolarGrid(0.5, 5.0, 11, [1.0, 0.0])
    with pytest.raises(AttributeError):
        a.n_range_bins = 3


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_range_bins": 0}, "n_range_bins must be a positive integer, got 0"),
        ({"n_range_bins": 2.0}, "n_range_bins must be a positive integer, got 2.0"),
        ({"n_range_bins": True}, "n_range_bins must be a positive integer, got True"),
        ({"range_min_m": -1.0}, "range_min_m must be finite and >= 0, got -1.0"),
        ({"range_max_m": 0.5}, r"range_max_m must be finite and > range_min_m \(0.5\), got 0.5"),
        ({"range_max_m": "far"}, "range_min_m and range_max_m must be numbers"),
        ({"beam_angles_deg": []}, r"azimuth_deg must be a non-empty 1-D array, got shape \(0,\)"),
        ({"beam_angles_deg": [1.0, math.nan]}, "azimuth_deg must contain only finite values"),
        ({"beam_angles_deg": [-1.0, 1.0]}, "azimuth_deg must be strictly descending"),
        ({"beam_angles_deg": [2.0]}, "single_beam_width_deg is required when azimuth_deg has a single beam"),
        ({"beam_angles_deg": [2.0], "single_beam_width_deg": 0.0}, "single_beam_width_deg must be finite and > 0"),
    ],
)
def test_validation_messages(kwargs, message):
    args = {"range_min_m": 0.5, "range_max_m": 5.0, "n_range_bins": 10, "beam_angles_deg": [1.0, 0.0]}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        PolarGrid(**args)


def test_the_sonar_delegates_its_grid_properties():
    s = SonarConfig.uniform(4, 20.0, 14.0, 0.5, 2.5, 8)
    g = s.grid
    assert g == PolarGrid(0.5, 2.5, 8, (7.5, 2.5, -2.5, -7.5), single_beam_width_deg=1.0)
    np.testing.assert_allclose(s.range_m, 0.5 + (np.arange(8) + 0.5) * 0.25)
    np.testing.assert_allclose(s.range_edges_m, np.linspace(0.5, 2.5, 9))
    np.testing.assert_allclose(s.beam_edges_deg, [10.0, 5.0, 0.0, -5.0, -10.0])
    assert s.azimuth_fov_deg == pytest.approx(20.0)
    assert s.range_resolution_m == 0.25
    # The grid is the beams and the range window alone: another elevation aperture, the same grid.
    from dataclasses import replace

    assert replace(s, elevation_fov_deg=20.0).grid == g


def test_beam_index_of_azimuths_hand_computed():
    from sonarsim.image.grid import beam_index

    edges = np.array([15.0, 5.0, -5.0, -15.0])  # three beams, left-most first
    az = np.array([16.0, 15.0, 10.0, 5.0, 0.0, -5.0, -14.9, -15.0, -20.0])
    # An edge belongs to the beam on its right (edges[j] >= az > edges[j + 1]).
    np.testing.assert_array_equal(beam_index(edges, az), [-1, 0, 0, 1, 1, 2, 2, -1, -1])
