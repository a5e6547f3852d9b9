"""Tests of the polar -> fan scan conversion (sonarsim.image.fan)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sonarsim.image.fan import (
    FanImage,
    FanMapper,
    beam_edges_deg,
    fan_geometry,
    polar_to_fan,
)

# A uniform 31-beam table, 1 deg spacing: fan edges at +-15.5 deg.
AZ_UNIFORM = np.linspace(15.0, -15.0, 31)


def _pixel_polar(fan: FanImage) -> tuple[np.ndarray, np.ndarray]:
    """Range (m) and azimuth (deg, positive left) of every pixel centre, from x_m / y_m."""
    xx, yy = np.meshgrid(fan.x_m, fan.y_m, indexing="ij")
    return np.hypot(xx, yy), np.degrees(np.arctan2(yy, xx))


# --------------------------------------------------------------------------- grid geometry


def test_grid_layout_hand_computed() -> None:
    # rmax 10 m, pixel 0.1 m -> 100 rows; half width 10*sin(15.5 deg) = 2.672 m -> 27 columns
    # per side -> 54 columns.
    geom = fan_geometry(1.0, 10.0, AZ_UNIFORM, 0.1)
    assert geom.shape == (100, 54)
    np.testing.assert_allclose(geom.x_m[[0, 1, -1]], [9.95, 9.85, 0.05], atol=1e-12)
    np.testing.assert_allclose(geom.y_m[[0, 26, 27, -1]], [2.65, 0.05, -0.05, -2.65], atol=1e-12)
    # Symmetric about the apex, which is at the bottom edge centre.
    np.testing.assert_allclose(geom.y_m, -geom.y_m[::-1], atol=1e-12)
    assert geom.x_m[-1] - geom.pixel_size_m / 2 == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.diff(geom.x_m) < 0) and np.all(np.diff(geom.y_m) < 0)
    assert (geom.left_edge_deg, geom.right_edge_deg) == pytest.approx((15.5, -15.5))


def test_image_covers_fan_exactly() -> None:
    fan = polar_to_fan(np.ones((40, 31), np.float32), 1.0, 10.0, AZ_UNIFORM, pixel_size_m=0.1)
    h, w = fan.image.shape
    half_width = 10.0 * math.sin(math.radians(15.5))
    # Wide and tall enough, but no spare column pair / row beyond one pixel of rounding.
    assert h * 0.1 >= 10.0 - 1e-9 and (h - 1) * 0.1 < 10.0
    assert (w / 2) * 0.1 >= half_width and (w / 2 - 1) * 0.1 < half_width
    # The mask reaches the top row and to within one pixel of the sides (the outermost
    # columns are only partly covered by the fan, maybe not at their centres).
    assert fan.mask[0].any()
    assert fan.mask[:, :2].any() and fan.mask[:, -2:].any()


def test_mask_hand_computed_pixels() -> None:
    # Grid as in test_grid_layout_hand_computed: x = (99.5 - row) * 0.1, y = (26.5 - col) * 0.1.
    m = fan_geometry(1.0, 10.0, AZ_UNIFORM, 0.1).mask
    # Far range: (x, y) = (9.95, 0.05): r = 9.95013 < 10, inside.
    assert m[0, 26]
    # (9.95, 1.05): r = sqrt(99.0025 + 1.1025) = 10.0052 > 10, azimuth 6.0 deg: outside.
    assert not m[0, 16]
    # (9.95, 0.95): r = 9.99525, inside.
    assert m[0, 17]
    # Near range 1 m: (0.95, 0.05): r = 0.9513 < 1 outside; (1.05, 0.05): r = 1.0512 inside.
    assert not m[90, 26]
    assert m[89, 26]
    # Left edge 15.5 deg at x = 5.05 (row 49) is at y = 5.05*tan(15.5 deg) = 1.4005:
    # y = 1.35 (col 13, 14.97 deg) inside, y = 1.45 (col 12, 16.02 deg) outside.
    assert m[49, 13]
    assert not m[49, 12]
    # Mirror image on the right edge: y = -1.35 (col 40) inside, y = -1.45 (col 41) outside.
    assert m[49, 40]
    assert not m[49, 41]
    # Mask is symmetric for a symmetric table.
    np.testing.assert_array_equal(m, m[:, ::-1])


# --------------------------------------------------------------------------- placement


@pytest.mark.parametrize("bin_index", [3, 17, 38])
def test_arc_lands_at_its_range(bin_index: int) -> None:
    n_r, rmin, rmax = 40, 1.0, 9.0
    dr = (rmax - rmin) / n_r
    polar = np.zeros((n_r, AZ_UNIFORM.size), np.float32)
    polar[bin_index, :] = 1.0
    centre = rmin + (bin_index + 0.5) * dr

    near = polar_to_fan(polar, rmin, rmax, AZ_UNIFORM, pixel_size_m=0.05, interpolation="nearest")
    r, _ = _pixel_polar(near)
    lit = near.image > 0
    assert lit.any()
    # Nearest: exactly the pixels whose centre lies in the bin's half-open interval.
    expected = near.mask & (r >= rmin + bin_index * dr) & (r < rmin + (bin_index + 1) * dr)
    np.testing.assert_array_equal(lit, expected)

    lin = polar_to_fan(polar, rmin, rmax, AZ_UNIFORM, pixel_size_m=0.05, interpolation="linear")
    # Down the apex column the brightest pixel is within half a pixel of the bin centre.
    col = lin.image.shape[1] // 2
    row = int(np.argmax(lin.image[:, col]))
    radius = math.hypot(lin.x_m[row], lin.y_m[col])
    assert abs(radius - centre) <= 0.5 * lin.pixel_size_m + 1e-9
    # Everywhere: bilinear weight > 0.5 means within half a bin of the arc.
    r, _ = _pixel_polar(lin)
    bright = lin.image > 0.5
    assert bright.any()
    assert np.all(np.abs(r[bright] - centre) < dr / 2 + 1e-9)
    # Linear and nearest agree on where the arc is: every pixel inside the bin is lit.
    assert np.all(lin.image[lit] > 0)
    # The arc spans the whole fan: lit pixels reach both outer edges (+-15.5 deg).
    _, az = _pixel_polar(near)
    assert az[lit].max() > 15.0 and az[lit].min() < -15.0


@pytest.mark.parametrize("beam", [2, 9, 22])
def test_single_beam_lands_on_its_ray(beam: int) -> None:
    polar = np.zeros((100, AZ_UNIFORM.size), np.float32)
    polar[:, beam] = 1.0
    angle = math.radians(AZ_UNIFORM[beam])
    fan = polar_to_fan(polar, 0.5, 10.0, AZ_UNIFORM, pixel_size_m=0.02, interpolation="linear")
    p = fan.pixel_size_m
    checked = 0
    for row in range(0, fan.image.shape[0], 25):
        x = fan.x_m[row]
        if x < 3.0:  # near the apex the beam is narrower than a pixel; skip
            continue
        line = fan.image[row]
        if line.max() < 0.5:
            continue  # row beyond the far arc along this ray
        col = int(np.argmax(line))
        # The ray crosses this row at y = x * tan(angle); the brightest pixel is the one
        # whose centre is nearest to that crossing.
        assert abs(fan.y_m[col] - x * math.tan(angle)) <= 0.5 * p + 0.05 * p
        checked += 1
    assert checked > 10

    near = polar_to_fan(polar, 0.5, 10.0, AZ_UNIFORM, pixel_size_m=0.02, interpolation="nearest")
    _, az = _pixel_polar(near)
    lit = near.image > 0
    assert lit.any()
    # Nearest: every lit pixel is within the beam's own edges (+-0.5 deg around its centre).
    assert np.all(np.abs(az[lit] - AZ_UNIFORM[beam]) <= 0.5 + 1e-9)


def test_left_beam_is_on_image_left() -> None:
    polar = np.zeros((50, AZ_UNIFORM.size), np.float32)
    polar[:, 0] = 1.0  # column 0 = left-most (port) beam, +15 deg
    for interpolation in ("nearest", "linear"):
        fan = polar_to_fan(polar, 1.0, 10.0, AZ_UNIFORM, interpolation=interpolation)
        rows, cols = np.nonzero(fan.image > 0)
        assert rows.size > 0
        assert np.all(fan.y_m[cols] > 0)
        assert np.all(cols < fan.image.shape[1] // 2)
    # And the right-most beam on the right.
    polar = polar[:, ::-1].copy()
    fan = polar_to_fan(polar, 1.0, 10.0, AZ_UNIFORM)
    _, cols = np.nonzero(fan.image > 0)
    assert np.all(fan.y_m[cols] < 0)
    assert np.all(cols >= fan.image.shape[1] // 2)


def test_far_range_is_at_the_top() -> None:
    polar = np.zeros((50, AZ_UNIFORM.size), np.float32)
    polar[-1, :] = 1.0
    fan = polar_to_fan(polar, 1.0, 10.0, AZ_UNIFORM, interpolation="nearest")
    rows, _ = np.nonzero(fan.image)
    assert rows.max() < fan.image.shape[0] // 5


# --------------------------------------------------------------------------- lens tables


AZ_LENS = np.array([20.0, 12.0, 6.0, 2.0, 0.0, -2.0, -6.0, -12.0, -20.0])


def test_non_uniform_table_edges_and_mask() -> None:
    assert beam_edges_deg(AZ_LENS) == pytest.approx((24.0, -24.0))
    geom = fan_geometry(0.0, 5.0, AZ_LENS, 0.05)
    inside = geom.mask
    az = geom.azimuth_px_deg
    r = geom.range_m
    assert np.all(np.abs(az[inside]) <= 24.0)
    # Every pixel within range and within 23.5 deg is inside.
    assert np.all(inside[(r <= 5.0) & (np.abs(az) <= 23.5)])
    # And nothing beyond 24.5 deg.
    assert not np.any(inside & (np.abs(az) > 24.0))


def test_non_uniform_table_beam_index() -> None:
    polar = np.tile(np.arange(AZ_LENS.size, dtype=np.float32), (30, 1))  # value = beam index
    fan = polar_to_fan(polar, 0.5, 5.0, AZ_LENS, pixel_size_m=0.02, interpolation="linear")
    r, az = _pixel_polar(fan)
    m = fan.mask
    # Piecewise linear between the actual centres: 16 deg is half way between beam 0 (20)
    # and beam 1 (12) -> 0.5; 4 deg between beam 2 (6) and beam 3 (2) -> 2.5; 1 deg -> 3.5.
    for angle, expected in [(16.0, 0.5), (4.0, 2.5), (1.0, 3.5), (-9.0, 6.5), (22.0, 0.0)]:
        near_ray = m & (np.abs(az - angle) < 0.05)
        assert near_ray.any()
        # +-0.05 deg off the ray, and beams here are >= 2 deg apart: index within 0.025.
        np.testing.assert_allclose(fan.image[near_ray], expected, atol=0.05 / 2 + 1e-4)
    # Globally equal to the azimuth interpolated over the (reversed, ascending) table.
    want = np.interp(az, AZ_LENS[::-1], np.arange(AZ_LENS.size)[::-1])
    np.testing.assert_allclose(fan.image[m], want[m], atol=1e-5)

    # Nearest: a lit beam covers exactly the angles between its edges (9 .. 16 deg for 12).
    polar = np.zeros((30, AZ_LENS.size), np.float32)
    polar[:, 1] = 1.0
    fan = polar_to_fan(polar, 0.5, 5.0, AZ_LENS, pixel_size_m=0.02, interpolation="nearest")
    lit = fan.image > 0
    assert np.all((az[lit] >= 9.0 - 1e-9) & (az[lit] <= 16.0 + 1e-9))
    assert np.all(lit[m & (az > 9.05) & (az < 15.95)])


# --------------------------------------------------------------------------- values


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_constant_image_is_constant_inside_mask(interpolation: str) -> None:
    polar = np.full((64, AZ_LENS.size), 0.37, np.float32)
    fan = polar_to_fan(polar, 0.3, 6.0, AZ_LENS, interpolation=interpolation)
    assert fan.image.dtype == np.float32 and fan.mask.dtype == bool
    assert fan.image.shape == fan.mask.shape == (fan.x_m.size, fan.y_m.size)
    np.testing.assert_array_equal(fan.image[fan.mask], np.float32(0.37))
    np.testing.assert_array_equal(fan.image[~fan.mask], 0.0)


def test_linear_ramp_in_range_is_reproduced() -> None:
    n_r, rmin, rmax = 50, 2.0, 12.0
    dr = (rmax - rmin) / n_r
    polar = np.tile(np.arange(n_r, dtype=np.float32)[:, None], (1, AZ_UNIFORM.size))
    fan = polar_to_fan(polar, rmin, rmax, AZ_UNIFORM, pixel_size_m=0.05)
    r, _ = _pixel_polar(fan)
    want = np.clip((r - rmin) / dr - 0.5, 0, n_r - 1)
    np.testing.assert_allclose(fan.image[fan.mask], want[fan.mask], atol=1e-4)


def test_default_pixel_size_is_range_resolution() -> None:
    fan = polar_to_fan(np.ones((80, 31)), 1.0, 9.0, AZ_UNIFORM)
    assert fan.pixel_size_m == pytest.approx(0.1)
    assert fan.image.shape[0] == 90


def test_mapper_reuse_matches_and_shares_readonly_geometry() -> None:
    rng = np.random.default_rng(0)
    mapper = FanMapper(60, 0.5, 8.0, AZ_LENS, 0.04, "linear")
    assert mapper.polar_shape == (60, AZ_LENS.size)
    a = rng.random((60, AZ_LENS.size), dtype=np.float32)
    b = rng.random((60, AZ_LENS.size), dtype=np.float32)
    fa, fb = mapper(a), mapper(b)
    np.testing.assert_array_equal(
        fa.image, polar_to_fan(a, 0.5, 8.0, AZ_LENS, 0.04, "linear").image
    )
    assert fa.mask is fb.mask
    assert not fa.mask.flags.writeable
    assert fa.image is not fb.image and fa.image.flags.writeable
    with pytest.raises(ValueError, match="polar"):
        mapper(a[:, :-1])


def test_wide_fan_up_to_almost_90_degrees() -> None:
    az = np.linspace(85.0, -85.0, 35)  # 5 deg spacing, edges at +-87.5 deg
    fan = polar_to_fan(np.ones((20, 35)), 0.0, 4.0, az, pixel_size_m=0.1)
    assert fan.image.shape == (40, 80)  # 4 m * sin(87.5 deg) = 3.996 m -> 40 columns a side
    r, a = _pixel_polar(fan)
    assert np.all(np.abs(a[fan.mask]) <= 87.5)
    # Low rows far out to the sides are inside: (x, y) = (0.15, -3.95) is at 87.8 deg -> out,
    # (0.25, -3.85) is at 86.3 deg, r = 3.858 -> in.
    assert not fan.mask[38, 79]
    assert fan.mask[37, 78]
    np.testing.assert_array_equal(fan.image[fan.mask], 1.0)


def test_single_beam_needs_width() -> None:
    with pytest.raises(ValueError, match="single_beam_width_deg"):
        polar_to_fan(np.ones((10, 1)), 1.0, 5.0, [0.0])
    fan = polar_to_fan(np.ones((10, 1)), 1.0, 5.0, [0.0], single_beam_width_deg=10.0)
    _, a = _pixel_polar(fan)
    assert np.all(np.abs(a[fan.mask]) <= 5.0)
    assert fan.mask.any()
    np.testing.assert_array_equal(fan.image[fan.mask], 1.0)


# --------------------------------------------------------------------------- bad arguments


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"pixel_size_m": 0.0}, "pixel_size_m"),
        ({"pixel_size_m": -0.1}, "pixel_size_m"),
        ({"pixel_size_m": float("nan")}, "pixel_size_m"),
        ({"interpolation": "cubic"}, "interpolation.*'nearest'.*'linear'"),
        ({"range_max_m": 1.0}, "range_max_m"),
        ({"range_min_m": -1.0}, "range_min_m"),
        ({"azimuth_deg": AZ_UNIFORM[::-1]}, "azimuth_deg.*descending"),
        ({"azimuth_deg": AZ_UNIFORM[:-1]}, "azimuth_deg"),
        ({"polar": np.ones((5, 31, 2))}, "polar.*2-D"),
        ({"azimuth_deg": np.linspace(89.0, -89.0, 31)}, "azimuth_deg.*90"),
        ({"polar": np.ones((5, 31), complex)}, "polar.*real"),
    ],
)
def test_bad_arguments_raise_value_error(kwargs: dict, match: str) -> None:
    args = {
        "polar": np.ones((5, 31)),
        "range_min_m": 1.0,
        "range_max_m": 10.0,
        "azimuth_deg": AZ_UNIFORM,
        "pixel_size_m": 0.1,
        "interpolation": "linear",
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        polar_to_fan(**args)


def test_fan_geometry_rejects_bad_pixel_size() -> None:
    with pytest.raises(ValueError, match="pixel_size_m"):
        fan_geometry(1.0, 10.0, AZ_UNIFORM, 0)


def test_ids_resample_an_integer_map_as_the_float_nearest_mapping_does():
    from sonarsim.image.fan import FanMapper

    rng = np.random.default_rng(0)
    n_r, n_b = 40, 9
    mapper = FanMapper(n_r, 1.0, 5.0, np.linspace(10, -10, n_b), interpolation="nearest")
    ids = rng.integers(-1, 5, (n_r, n_b)).astype(np.int32)
    via_float = mapper(ids.astype(np.float32) + 1.0).image.astype(np.int32) - 1
    np.testing.assert_array_equal(mapper.ids(ids), via_float)
    assert (mapper.ids(ids, fill=-7)[~mapper.mask] == -7).all()
    with pytest.raises(ValueError, match="nearest"):
        FanMapper(n_r, 1.0, 5.0, np.linspace(10, -10, n_b)).ids(ids)  # a linear mapper blends ids
