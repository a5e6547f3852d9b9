"""sonarsim.plot.style: one colour table for figures and the viewer."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.plot.style import DEFAULT_COLORMAP, colorize, colormap_lut


def test_grey_is_the_identity_and_the_default_map_rises_in_lightness():
    grey = colormap_lut("grey")
    np.testing.assert_array_equal(grey, np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1))
    lut = colormap_lut(DEFAULT_COLORMAP).astype(float)
    # Perceptual maps rise steadily in lightness: luma increases from every 16th entry to the next.
    luma = lut @ [0.299, 0.587, 0.114]
    assert (np.diff(luma[::16]) > 0).all() and luma[0] < 10  # black-ish at "no echo"


def test_colorize_maps_values_and_marks_outside_the_fan():
    image = np.array([[0, 255], [128, 7]], np.uint8)
    mask = np.array([[True, True], [False, True]])
    rgb = colorize(image, "grey", mask, outside=(1, 2, 3))
    assert rgb.shape == (2, 2, 3) and rgb.dtype == np.uint8
    np.testing.assert_array_equal(rgb[0, 1], [255, 255, 255])
    np.testing.assert_array_equal(rgb[1, 0], [1, 2, 3])
    np.testing.assert_array_equal(rgb[1, 1], [7, 7, 7])


def test_unknown_colour_map_names_the_allowed_ones():
    with pytest.raises(ValueError, match="unknown colour map 'sonarpink'.*inferno"):
        colormap_lut("sonarpink")
