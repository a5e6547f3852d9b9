"""Realism statistics against closed forms and seeded statistics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from sonarsim.analysis.realism import (
    beam_profile_db, correlation_lengths, distribution_distances, range_profile_db, speckle_contrast,
)

SHAPE = (400, 256)


def test_fully_developed_speckle_has_contrast_one_in_intensity_and_0_52_in_amplitude():
    rng = np.random.default_rng(1)
    intensity = rng.exponential(1.0, SHAPE)
    # The local mean is estimated from 45 pixels, which adds a little variance: ~1/45.
    assert speckle_contrast(intensity) == pytest.approx(1.0, abs=0.06)
    amplitude = np.sqrt(intensity)  # Rayleigh: std/mean = sqrt(4/pi - 1)
    assert speckle_contrast(amplitude) == pytest.approx(np.sqrt(4 / np.pi - 1), abs=0.04)
    assert speckle_contrast(np.full(SHAPE, 3.0)) == pytest.approx(0.0, abs=1e-12)


def test_contrast_ignores_a_smooth_trend_and_follows_the_mask():
    rng = np.random.default_rng(2)
    trend = np.linspace(1.0, 50.0, SHAPE[0])[:, None] * np.ones(SHAPE)
    speckled = trend * rng.exponential(1.0, SHAPE)
    assert speckle_contrast(speckled) == pytest.approx(1.0, abs=0.06)
    mixed = np.where(np.arange(SHAPE[1]) < 128, speckled, trend)  # left half speckle, right smooth
    left = np.zeros(SHAPE, dtype=bool)
    left[:, 10:118] = True
    right = np.zeros(SHAPE, dtype=bool)
    right[:, 138:246] = True
    assert speckle_contrast(mixed, left) == pytest.approx(1.0, abs=0.08)
    assert speckle_contrast(mixed, right) < 0.02  # a ramp reflected at its ends bends the local mean a little


@pytest.mark.parametrize("sigma_range, sigma_beam", [(3.0, 1.5), (5.0, 2.0)])
def test_correlation_lengths_of_smoothed_noise_match_the_closed_form(sigma_range, sigma_beam):
    # White noise through a Gaussian of width sigma has autocorrelation exp(-lag^2 / (4 sigma^2)):
    # 1/e at lag 2 sigma. A wide local-mean window keeps the high-pass of the residual negligible.
    rng = np.random.default_rng(3)
    noise = gaussian_filter(rng.normal(size=(1200, 600)), (sigma_range, sigma_beam), mode="wrap")
    image = 1.0 + 0.1 * noise / noise.std()
    lengths = correlation_lengths(image, window=(101, 61))
    assert lengths.range_bins == pytest.approx(2 * sigma_range, rel=0.1)
    assert lengths.beams == pytest.approx(2 * sigma_beam, rel=0.1)


def test_white_speckle_has_a_grain_below_one_pixel():
    rng = np.random.default_rng(4)
    lengths = correlation_lengths(rng.exponential(1.0, SHAPE))
    assert lengths.range_bins < 1.0 and lengths.beams < 1.0


def test_distribution_distances():
    rng = np.random.default_rng(5)
    a = rng.exponential(2.0, SHAPE)
    b = rng.exponential(2.0, SHAPE)
    same = distribution_distances(a, b)
    assert same.ks < 0.01 and same.wasserstein < 0.03
    shifted = distribution_distances(a, b + 3.0)  # the earth mover moves every pixel by 3
    assert shifted.wasserstein == pytest.approx(3.0, abs=0.03)
    assert shifted.ks > 0.7
    # Regions of images of different shapes.
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:100] = True
    part = distribution_distances(a, b[:50, :60], mask_a=mask)
    assert part.ks < 0.05


def test_profiles_in_db():
    rows = np.logspace(-2, 1, SHAPE[0])
    image = rows[:, None] * np.ones(SHAPE)
    np.testing.assert_allclose(range_profile_db(image), 10 * np.log10(rows), rtol=1e-12)
    np.testing.assert_allclose(beam_profile_db(image), 10 * np.log10(rows.mean()), rtol=1e-12)
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:10, :] = True
    profile = range_profile_db(image, mask)
    np.testing.assert_allclose(profile[:10], 10 * np.log10(rows[:10]))
    assert np.all(np.isnan(profile[10:]))


def test_bad_regions_are_refused():
    image = np.ones(SHAPE)
    with pytest.raises(ValueError, match="shape"):
        speckle_contrast(image, np.ones((3, 3), dtype=bool))
    with pytest.raises(ValueError, match="fewer than two"):
        speckle_contrast(image, np.zeros(SHAPE, dtype=bool))
    with pytest.raises(ValueError, match="at least one pixel"):
        distribution_distances(image, image, mask_a=np.zeros(SHAPE, dtype=bool))
    dark_beside_echo = np.zeros(SHAPE)  # a noise-free shadow: zeros whose local mean is not 0
    dark_beside_echo[:, 0] = 1.0
    mask = np.zeros(SHAPE, dtype=bool)
    mask[:, 1:3] = True
    with pytest.raises(ValueError, match="no echo"):
        speckle_contrast(dark_beside_echo, mask)


def test_the_real_oculus_floor_band_has_the_measured_speckle_contrast(shared_data):
    # DESIGN.md section 8 measured 0.29 in the floor band of the real M1200d ping (std/mean
    # after removing a 9 x 5 local mean): far below exponential speckle's 1.
    import sonarsim
    from sonarsim.analysis.realism import local_mean

    polar = sonarsim.read(shared_data / "real" / "oculus" / "one_ping_8bit.raw").polar.astype(float)
    band = local_mean(polar) > np.percentile(polar, 80)
    assert speckle_contrast(polar, band) == pytest.approx(0.29, abs=0.02)
    lengths = correlation_lengths(polar, band)
    assert 0.0 < lengths.range_bins < 3.0 and 0.5 < lengths.beams < 4.0


def _floor_band(rng, onset=None):
    """A synthetic polar image: weak water column, then a bright speckled band from ``onset``."""
    rows, beams = SHAPE
    onset = np.full(beams, 150) if onset is None else onset
    level = np.where(np.arange(rows)[:, None] >= onset[None, :], 100.0, 2.0)
    return level * rng.exponential(1.0, SHAPE), onset


def test_auto_regions_find_the_band_and_the_water_column_before_it():
    from sonarsim.analysis.realism import auto_regions

    rng = np.random.default_rng(6)
    onset = (150 + 40 * np.sin(np.linspace(0, np.pi, SHAPE[1]))).astype(int)  # a curved floor onset
    image, onset = _floor_band(rng, onset)
    regions = auto_regions(image)
    lit, water = regions["lit"], regions["water"]
    first_lit = lit.argmax(axis=0)
    # The local mean blurs the onset by half its window (9 bins) at most.
    assert np.all(np.abs(first_lit - onset) <= 5)
    rows = np.arange(SHAPE[0])[:, None]
    assert not (water & (rows >= onset[None, :] + 5)).any()  # (the same blur)
    assert water[: onset.min() - 5].all()
    assert lit[onset.max() + 10:].mean() > 0.95


def test_region_statistics_of_an_image_against_itself_and_against_another_draw():
    from sonarsim.analysis.realism import auto_regions, region_statistics

    rng = np.random.default_rng(7)
    a, _ = _floor_band(rng)
    same = region_statistics(a, a, auto_regions(a)["lit"])
    assert same["ks"] == 0.0 and same["wasserstein"] == 0.0 and same["range_profile_rms_db"] == 0.0
    assert same["contrast_a"] == same["contrast_b"]
    b, _ = _floor_band(rng)  # another speckle draw of the same scene
    other = region_statistics(a, b, auto_regions(a)["lit"])
    assert other["ks"] < 0.02 and abs(other["contrast_a"] - other["contrast_b"]) < 0.03
    brighter = region_statistics(a, 2 * b, auto_regions(a)["lit"])  # 3 dB too bright
    assert brighter["range_profile_rms_db"] == pytest.approx(10 * np.log10(2), abs=0.3)
    assert brighter["ks"] > 0.2


def test_compare_reports_region_statistics(tmp_path, capsys):
    import json

    from sonarsim.cli.main import main

    rng = np.random.default_rng(8)
    a, _ = _floor_band(rng)
    b, _ = _floor_band(rng)
    for name, img in (("a.npy", a), ("b.npy", b)):
        from PIL import Image

        Image.fromarray(np.clip(img, 0, 255).astype(np.uint8)[::-1]).save(tmp_path / name.replace(".npy", ".png"))
    assert main(["compare", str(tmp_path / "a.png"), str(tmp_path / "b.png"), "--normalize", "none", "--stats",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["stats"]) == {"all", "lit", "water", "shadow"}
    assert doc["stats"]["lit"]["ks"] < 0.05 and doc["stats"]["lit"]["pixels"] > 1000


# --------------------------------------------------------------------------------------------
# The shadow region
# --------------------------------------------------------------------------------------------


def _patch_and_shadow(behind=1.0):
    """Water 1, floor 50 from bin 60, an object 100 at bins 100-119 of beams 20-39 and behind it,
    bins 120-169, a shadow of level ``behind``; returns the image and the shadow's box."""
    image = np.full((200, 64), 1.0)
    image[60:] = 50.0
    image[100:120, 20:40] = 100.0
    image[120:170, 20:40] = behind
    return image, (slice(120, 170), slice(20, 40))


def test_shadow_behind_a_bright_patch_is_the_dark_box_less_half_the_window():
    from sonarsim.analysis.realism import auto_regions

    image, box = _patch_and_shadow()
    regions = auto_regions(image)
    # A 9 x 5 mean touching the floor or the object is above 1 + 49/45 > 2 (3 dB over the
    # water's 1); inside the box it is 1. So the shadow is the box less 4 bins and 2 beams.
    expected = np.zeros(image.shape, dtype=bool)
    expected[124:166, 22:38] = True
    np.testing.assert_array_equal(regions["shadow"], expected)
    assert not (regions["shadow"] & (regions["lit"] | regions["water"])).any()
    # The same with speckle: within the box, and nearly all of its core.
    rng = np.random.default_rng(9)
    shadow = auto_regions(image * rng.exponential(1.0, image.shape))["shadow"]
    inside = np.zeros(image.shape, dtype=bool)
    inside[box] = True
    assert not (shadow & ~inside).any()
    assert shadow[expected].mean() > 0.95


@pytest.mark.parametrize("behind, found", [(1.8, True), (4.0, False)])
def test_shadow_is_within_3_db_of_the_water_column(behind, found):
    from sonarsim.analysis.realism import auto_regions

    image, box = _patch_and_shadow(behind)
    shadow = auto_regions(image)["shadow"]
    assert shadow[124:166, 22:38].all() == found and shadow.any() == found


def test_an_unlit_floor_behind_the_shadow_is_not_shadow():
    # An object so bright that the floor is not lit (under a quarter of it): the beams without
    # the object are floor from bin 60 on, and their "water" (the whole beam) must not set the
    # level of no echo, or the floor would be at it.
    from sonarsim.analysis.realism import auto_regions

    image, _ = _patch_and_shadow()
    image[100:120, 20:40] = 1000.0
    regions = auto_regions(image)
    assert not regions["lit"][130:].any()
    expected = np.zeros(image.shape, dtype=bool)
    expected[124:166, 22:38] = True
    np.testing.assert_array_equal(regions["shadow"], expected)


def test_no_shadow_without_a_drop_or_without_a_water_column():
    from sonarsim.analysis.realism import auto_regions

    rng = np.random.default_rng(10)
    band, _ = _floor_band(rng)  # lit from bin 150 to the far end
    assert not auto_regions(band)["shadow"].any()
    image, _ = _patch_and_shadow()
    assert not auto_regions(image[60:])["shadow"].any()  # lit from the first bin: no level to go by
    mask = np.ones(image.shape, dtype=bool)
    mask[:, 30:] = False
    shadow = auto_regions(image, mask)["shadow"]
    assert shadow.any() and not shadow[:, 30:].any()


def test_a_noise_free_render_has_its_shadow_behind_the_object():
    # A block on a floor whose lit band runs past the far range: every pixel of the shadow lies
    # farther than the block's echo in its beam, inside the shadow the block casts (floor echo
    # without the block, none with it), and covers that cast shadow but for half a window.
    import sonarsim
    from scipy.ndimage import binary_erosion
    from sonarsim.analysis.realism import auto_regions

    from tests.conftest import block_scene_dict

    scene = block_scene_dict(range_max_m=4.0, n_range_bins=350)
    image = sonarsim.Simulator(scene).render()
    bare = sonarsim.Simulator({**scene, "objects": []}).render()
    shadow = auto_regions(image.polar)["shadow"]
    block = image.components["object"] > 0
    cast = (bare.components["ground"] > 0) & (image.polar == 0)
    assert shadow.sum() > 500
    rows = np.arange(shadow.shape[0])[:, None]
    last_echo = np.where(block.any(axis=0), block.shape[0] - 1 - block[::-1].argmax(axis=0), block.shape[0])
    assert not (shadow & (rows <= last_echo[None, :])).any()
    assert not (shadow & ~cast).any()
    core = binary_erosion(cast, np.ones((9, 5), dtype=bool), border_value=1)
    assert core.sum() > 300 and shadow[core].mean() > 0.95


def test_the_dark_beyond_a_floor_band_counts_as_shadow(renders):
    # The documented limit: in the test scene the floor band ends (top of the vertical beam)
    # before the far range, and behind a lit bin that dark is shadow as well.
    from sonarsim.analysis.realism import auto_regions

    image = renders["full"]
    shadow = auto_regions(image.polar)["shadow"]
    block_beams = (image.components["object"] > 0).any(axis=0)
    beyond = (image.components["ground"] == 0) & (np.arange(image.polar.shape[0])[:, None] > 300)
    assert (shadow & ~block_beams[None, :]).any()
    assert not (shadow & ~block_beams[None, :] & ~beyond).any()


def test_the_real_oculus_ping_has_next_to_no_shadow(shared_data):
    # What is not lit behind its floor band stays 4-6 dB above its water column (DESIGN
    # section 8: the elevation pattern's echo): not a shadow.
    import sonarsim
    from sonarsim.analysis.realism import auto_regions

    polar = sonarsim.read(shared_data / "real" / "oculus" / "one_ping_8bit.raw").polar
    regions = auto_regions(polar)
    assert regions["lit"].sum() > 50_000 and regions["water"].sum() > 50_000
    assert regions["shadow"].sum() < 100
