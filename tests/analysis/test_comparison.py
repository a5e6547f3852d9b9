"""Tests of sonarsim.analysis.comparison: comparing images of any geometry, and loading them.

Resampling is checked against images that bilinear interpolation reproduces exactly.
"""

from __future__ import annotations

import math
import sys
import types
from types import SimpleNamespace

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.comparison import PlainImage, compare_images, load_image
from sonarsim.errors import SonarsimError
from sonarsim.io.output import to_uint8, write_npz, write_png
from tests.conftest import block_scene_dict as _scene

# --------------------------------------------------------------------------------------------
# compare_images: geometry and resampling
# --------------------------------------------------------------------------------------------


def _grid(range_min, range_max, n_bins, azimuth_deg, fn):
    """A SonarImage-like object whose polar image samples fn(range, azimuth) at bin centres."""
    dr = (range_max - range_min) / n_bins
    r = range_min + (np.arange(n_bins) + 0.5) * dr
    az = np.asarray(azimuth_deg, dtype=float)
    return SimpleNamespace(polar=fn(r[:, None], az[None, :]), range_m=r, azimuth_deg=az)


def test_a_render_compared_with_itself_is_identical_in_both_domains(renders):
    a = renders["full"]
    res = compare_images(a, a)
    for domain in ("polar", "fan"):
        assert res[domain]["mse"] == 0.0
        assert res[domain]["psnr"] == math.inf
        assert res[domain]["ssim"] == pytest.approx(1.0, abs=1e-12)
    assert res["polar"]["n_pixels"] == a.polar.size
    assert res["fan"]["n_pixels"] == int(a.fan().mask.sum())
    assert res["info"]["resampled"] is False and res["info"]["overlap"] == 1.0
    assert res["info"]["pixel_size_m"] == pytest.approx(a.sonar.range_resolution_m)


def test_half_the_range_bins_compares_with_high_ssim_after_resampling(renders):
    res = compare_images(renders["full"], renders["half"])
    assert res["info"]["resampled"] is True
    assert res["info"]["overlap"] == pytest.approx(1.0)
    assert res["polar"]["n_pixels"] == renders["full"].polar.size
    assert res["polar"]["ssim"] > 0.9
    assert res["fan"]["ssim"] > 0.95
    # And much closer than the scene compared with a different scene (the floor alone).
    other = sonarsim.render({k: v for k, v in _scene(n_range_bins=200).items() if k != "objects"})
    assert compare_images(renders["full"], other)["polar"]["ssim"] < res["polar"]["ssim"] - 0.02


def test_resampling_reproduces_an_image_linear_in_range_and_azimuth():
    fn = lambda r, az: 10.0 + 20.0 * r + 0.7 * az  # bilinear interpolation is exact on this
    # A lies strictly inside B's bin and beam centres: no clamping, every bin of A counts.
    a = _grid(1.0, 4.0, 120, np.linspace(10, -10, 21), fn)
    b = _grid(0.5, 5.0, 317, np.linspace(14, -14, 33), fn)
    res = compare_images(a, b, domains=("polar",), normalize=None)
    assert res["info"]["resampled"] is True
    assert res["polar"]["n_pixels"] == a.polar.size
    assert res["polar"]["mse"] < 1e-20


def test_only_the_bins_of_a_inside_b_coverage_count():
    fn = lambda r, az: r + 0 * az
    a = _grid(0.5, 4.5, 40, np.linspace(15, -15, 16), fn)  # 0.1 m bins, 2 deg beams
    # B covers 1.0-5.0 m and azimuths -10.5 to +19.5 deg (edges; beam spacing 2 deg).
    b = _grid(1.0, 5.0, 80, np.linspace(18.5, -9.5, 15), fn)
    res = compare_images(a, b, domains=("polar",), normalize=None)
    in_range = int(np.sum((a.range_m >= 1.0) & (a.range_m <= 5.0)))
    in_azimuth = int(np.sum((a.azimuth_deg <= 19.5) & (a.azimuth_deg >= -10.5)))
    assert (in_range, in_azimuth) == (35, 13)
    assert res["polar"]["n_pixels"] == in_range * in_azimuth
    # A's first counted centre (1.05 m) lies past B's first centre (1.025 m): no clamping.
    assert res["polar"]["mse"] < 1e-20


def test_the_fan_domain_counts_the_pixels_inside_both_fans(renders):
    a, b = renders["full"], renders["narrow"]
    res = compare_images(a, b)
    fan = a.fan()
    # Pixel centres of A's fan inside B's window (0.5-4.5 m, +-12 deg), computed here from
    # A's fan axes rather than by shifting B's fan as compare_images does.
    r = np.hypot(fan.x_m[:, None], fan.y_m[None, :])
    az = np.degrees(np.arctan2(fan.y_m[None, :], fan.x_m[:, None]))
    inside_b = (r >= 0.5) & (r <= 4.5) & (np.abs(az) <= 12.0)
    assert res["fan"]["n_pixels"] == int((fan.mask & inside_b).sum())
    assert res["info"]["overlap"] == pytest.approx(0.8 * (4.5**2 - 0.25) / (25 - 0.25))
    assert res["polar"]["ssim"] > 0.9 and res["fan"]["ssim"] > 0.9
    with pytest.raises(SonarsimError, match="too small"):
        compare_images(a, b, pixel_size_m=1e-5)


def test_a_disjoint_range_window_is_refused_with_a_message(renders):
    with pytest.raises(SonarsimError, match=r"ranges 0\.5-5 m vs 6-9 m") as info:
        compare_images(renders["full"], renders["far"])
    assert "range bins 400 vs 100" in str(info.value)
    assert "0 %" in str(info.value)


def test_little_overlap_in_azimuth_is_refused_and_names_the_fields_of_view():
    fn = lambda r, az: r + az
    a = _grid(0.5, 5.0, 50, np.linspace(14.5, -14.5, 30), fn)
    b = _grid(0.5, 5.0, 50, np.linspace(39.5, 10.5, 30), fn)  # 10 to 40 deg: a third of A
    with pytest.raises(SonarsimError, match="fields of view 30 deg") as info:
        compare_images(a, b, names=("real.aris", "sim.npz"))
    message = str(info.value)
    assert "real.aris" in message and "sim.npz" in message and "ranges" not in message
    assert "16.7 %" in message


def test_images_without_geometry_compare_only_with_the_same_shape(renders):
    a = PlainImage(np.random.default_rng(0).uniform(0, 255, (400, 32)), "a.png")
    res = compare_images(a, renders["full"])
    assert set(res) == {"polar", "info"}
    assert "a.png" in res["info"]["skipped"]["fan"]
    with pytest.raises(SonarsimError, match="a.png has no sonar geometry"):
        compare_images(a, renders["half"])
    with pytest.raises(SonarsimError, match="domains"):
        compare_images(renders["full"], renders["full"], domains=("cartesian",))


# --------------------------------------------------------------------------------------------
# load_image
# --------------------------------------------------------------------------------------------


def test_load_image_rebuilds_the_geometry_of_an_npz(renders, npz_files):
    original = renders["half"]
    loaded = load_image(npz_files["half"])
    s, t = loaded.sonar, original.sonar
    assert (s.range_min_m, s.range_max_m, s.n_range_bins) == (0.5, 5.0, 200)
    assert s.beam_angles_deg == pytest.approx(t.beam_angles_deg)
    assert s.elevation_fov_deg == t.elevation_fov_deg
    assert loaded.pose == original.pose  # the configuration's sonar.pose
    assert np.array_equal(loaded.polar, original.polar)
    assert np.array_equal(loaded.components["triple"], original.components["triple"])
    # The same grid, so no resampling and an exact match with the in-memory render.
    res = compare_images(original, loaded)
    assert res["info"]["resampled"] is False and res["polar"]["mse"] == 0.0
    single = load_image(npz_files["half"], component="single")
    assert np.array_equal(single.polar, original.components["single"])


def test_load_image_without_elevation_in_the_config_uses_14_degrees(tmp_path):
    path = tmp_path / "bare.npz"
    write_npz(path, {"polar": np.ones((10, 4)), "range_m": np.linspace(1.05, 1.95, 10),
                     "azimuth_deg": np.array([3.0, 1.0, -1.0, -3.0])}, {})
    image = load_image(path)
    assert image.sonar.elevation_fov_deg == 14.0
    assert (image.sonar.range_min_m, image.sonar.range_max_m) == (1.0, 2.0)


def test_load_image_refuses_what_it_cannot_read(tmp_path, npz_files, monkeypatch):
    with pytest.raises(SonarsimError, match="no such file"):
        load_image(tmp_path / "missing.npz")
    with pytest.raises(SonarsimError, match="single frame"):
        load_image(npz_files["full"], frame=1)
    with pytest.raises(SonarsimError, match="no image 'echo'"):
        load_image(npz_files["full"], component="echo")
    foreign = tmp_path / "foreign.npz"
    np.savez(foreign, polar=np.zeros((3, 3)))
    with pytest.raises(SonarsimError, match="not a readable NPZ written by sonarsim"):
        load_image(foreign)
    # Anything else goes to sonarsim.io.readers; simulate it being absent.
    other = tmp_path / "recording.aris"
    other.write_bytes(b"\x00" * 64)
    monkeypatch.setitem(sys.modules, "sonarsim.io.readers", None)
    with pytest.raises(SonarsimError, match="sonarsim.io.readers"):
        load_image(other)


def test_load_image_hands_recordings_to_the_readers(tmp_path, renders, monkeypatch):
    calls = []

    def read(path, frame):
        calls.append((str(path), frame))
        return renders["full"]

    monkeypatch.setitem(sys.modules, "sonarsim.io.readers", types.SimpleNamespace(read=read))
    other = tmp_path / "recording.aris"
    other.write_bytes(b"\x05DDF" + b"\x00" * 60)
    assert load_image(other, frame=3) is renders["full"]
    assert load_image(other) is renders["full"]
    assert calls == [(str(other), 3), (str(other), 0)]


def test_load_image_reads_png_rows_nearest_range_first(tmp_path, renders):
    polar = renders["full"].polar
    png = tmp_path / "polar.png"
    # As `sonarsim render` writes it: far range at the top of the picture.
    write_png(png, to_uint8(polar[::-1], "linear"))
    image = load_image(png)
    assert isinstance(image, PlainImage) and image.sonar is None
    assert np.array_equal(image.polar, to_uint8(polar, "linear"))
    # Linear 8-bit mapping = max normalisation up to rounding: |error| <= 0.5 grey level.
    res = compare_images(renders["full"], image)
    assert res["polar"]["mse"] <= 0.25
    assert res["polar"]["ssim"] > 0.99


# --------------------------------------------------------------------------------------------
# Regions given as masks
# --------------------------------------------------------------------------------------------


def _speckled_pair(shape=(200, 48)):
    rng = np.random.default_rng(11)
    level = np.where(np.arange(shape[0])[:, None] >= 80, 100.0, 2.0) * np.ones(shape)
    return PlainImage(level * rng.exponential(1.0, shape)), PlainImage(level * rng.exponential(1.0, shape))


def test_given_regions_get_the_statistics_of_the_automatic_ones_after_them():
    from sonarsim.analysis.realism import region_statistics

    a, b = _speckled_pair()
    wreck = np.zeros(a.polar.shape, dtype=bool)
    wreck[100:140, 10:20] = True
    res = compare_images(a, b, normalize=None, regions={"wreck": wreck})  # implies stats
    assert list(res["stats"]) == ["all", "lit", "water", "shadow", "wreck"]
    assert res["stats"]["wreck"] == region_statistics(a.polar, b.polar, wreck)
    assert res["stats"]["wreck"]["pixels"] == 400
    # Without regions or stats, no statistics; with stats alone, the automatic regions.
    assert "stats" not in compare_images(a, b)
    assert list(compare_images(a, b, stats=True)["stats"]) == ["all", "lit", "water", "shadow"]


def test_given_regions_count_only_the_bins_inside_b_coverage():
    fn = lambda r, az: 1.0 + r + 0 * az
    a = _grid(0.5, 4.5, 40, np.linspace(15, -15, 16), fn)
    b = _grid(1.0, 5.0, 80, np.linspace(18.5, -9.5, 15), fn)  # covers A's bins 5- and beams 0-12
    everywhere = np.ones(a.polar.shape, dtype=bool)
    res = compare_images(a, b, domains=("polar",), normalize=None, regions={"everywhere": everywhere})
    assert res["stats"]["everywhere"]["pixels"] == 35 * 13 == res["polar"]["n_pixels"]
    assert res["stats"]["everywhere"]["wasserstein"] < 1e-9


@pytest.mark.parametrize("regions, message", [
    ({"wreck": np.ones((3, 3), dtype=bool)}, r"region 'wreck'.*shape \(3, 3\).*200 range bins and 48 beams"),
    ({"wreck": np.ones((200, 48), dtype=np.uint8)}, r"region 'wreck'.*boolean.*uint8"),
    ({"shadow": np.ones((200, 48), dtype=bool)}, r"region 'shadow'.*automatic region"),
    ({"all": np.ones((200, 48), dtype=bool)}, r"region 'all'.*automatic region"),
    ({"": np.ones((200, 48), dtype=bool)}, r"non-empty strings"),
    ([np.ones((200, 48), dtype=bool)], r"dict of name to boolean mask"),
])
def test_bad_regions_are_refused_with_their_name(regions, message):
    a, b = _speckled_pair()
    with pytest.raises(SonarsimError, match=message):
        compare_images(a, b, regions=regions)


def test_load_region_reads_npy_and_png_masks_on_the_polar_grid(tmp_path):
    from PIL import Image

    from sonarsim.analysis.comparison import load_region

    mask = np.zeros((30, 8), dtype=bool)
    mask[2:5, 1:3] = True  # near range, left beams
    np.save(tmp_path / "bool.npy", mask)
    np.save(tmp_path / "int.npy", mask.astype(np.int16) * 7)
    for name in ("bool.npy", "int.npy"):
        region = load_region(tmp_path / name)
        assert region.dtype == bool and np.array_equal(region, mask)
    # A PNG is drawn far range at the top, as sonarsim draws polar PNGs.
    Image.fromarray((mask[::-1] * 255).astype(np.uint8)).save(tmp_path / "grey.png")
    rgba = np.zeros((30, 8, 4), dtype=np.uint8)
    rgba[..., 3] = 255  # opaque black: alpha does not count
    rgba[mask[::-1], 2] = 1  # the faintest blue does
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    Image.fromarray(mask[::-1]).save(tmp_path / "bilevel.png")
    for name in ("grey.png", "rgba.png", "bilevel.png"):
        assert np.array_equal(load_region(tmp_path / name), mask), name


def test_load_region_names_the_file_it_cannot_use(tmp_path):
    from sonarsim.analysis.comparison import load_region

    np.save(tmp_path / "float.npy", np.ones((4, 4)))
    np.save(tmp_path / "cube.npy", np.ones((2, 4, 4), dtype=bool))
    (tmp_path / "notes.txt").write_text("the wreck is at 3 m\n")
    np.save(tmp_path / "cut.npy", np.ones((40, 40), dtype=bool))
    (tmp_path / "cut.npy").write_bytes((tmp_path / "cut.npy").read_bytes()[:200])
    (tmp_path / "cut.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)
    cases = {
        "missing.npy": "no such file", "float.npy": "booleans.*float64", "cube.npy": r"2-D.*\(2, 4, 4\)",
        "notes.txt": "not a region", "cut.npy": "cannot read the .npy", "cut.png": "cannot read the PNG",
    }
    for name, message in cases.items():
        with pytest.raises(SonarsimError, match=f"{name}: .*{message}"):
            load_region(tmp_path / name)
