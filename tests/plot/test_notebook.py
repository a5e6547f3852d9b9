"""Notebook displays: SonarImage, FanImage and recordings show a small annotated figure, print a
short repr, and offer plot / save / to_pil."""

from __future__ import annotations

import numpy as np
import pytest

from sonarsim.io.output import to_uint8

from tests.plot.test_figures import point_target, synthetic

PNG = b"\x89PNG\r\n\x1a\n"


def test_sonar_image_repr_is_short_and_says_what_it_is():
    image = synthetic(point_target(), preset="aris3000-128", single=point_target())
    text = repr(image)
    assert len(text.splitlines()) <= 2 and len(text) < 400
    assert "array" not in text and "0.001" not in text  # never the arrays
    assert "aris3000-128" in text and "200 ranges x 40 beams" in text and "0.7-5 m" in text
    assert "total" in text and "single" in text


def test_sonar_image_displays_plots_saves_and_converts(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    image = synthetic(point_target())
    png = image._repr_png_()
    assert png.startswith(PNG)
    ax = image.plot()
    assert ax.get_xlabel() == "lateral (m), + = sonar's left"
    ax = image.plot(kind="polar", colormap="grey")
    assert ax.get_ylabel() == "range (m)"
    image.save(tmp_path / "fan.svg")
    assert (tmp_path / "fan.svg").read_bytes().startswith(b"<?xml")
    pil = image.to_pil()
    fan = image.fan()
    assert pil.mode == "L" and pil.size == (fan.shape[1], fan.shape[0])
    # Exactly the exact-pixel PNG: to_uint8 of the fan at the range resolution, 40 dB.
    np.testing.assert_array_equal(np.asarray(pil), to_uint8(fan.image, "db", 0.0, 40.0, mask=fan.mask))
    polar = np.asarray(image.to_pil(kind="polar"))
    assert polar.shape == (200, 40) and polar[200 - 1 - 100, 4] == 255  # far range at the top
    with pytest.raises(ValueError, match="kind must be one of 'fan', 'polar'"):
        image.to_pil(kind="cartesian")


def test_fan_image_displays_and_converts(tmp_path):
    fan = synthetic(point_target()).fan(pixel_size_m=0.02)
    text = repr(fan)
    assert text.startswith("FanImage(") and "20 mm" in text and len(text.splitlines()) == 1
    assert fan._repr_png_().startswith(PNG)
    ax = fan.plot()
    labels = [t.get_text() for t in ax.texts]
    assert " 5 m" in labels and "+15°" in labels  # its window, recovered from the mask
    fan.save(tmp_path / "fan.pdf")
    assert (tmp_path / "fan.pdf").read_bytes().startswith(b"%PDF")
    assert np.asarray(fan.to_pil()).shape == fan.shape


def test_recordings_display_their_first_frame(shared_data, tmp_path):
    from sonarsim.io.readers import open_recording

    with open_recording(shared_data / "real" / "aris" / "sample.aris") as rec:
        text = repr(rec)
        assert text.startswith("ArisRecording('sample.aris': 6 frames of 2000 ranges x 48 beams")
        assert len(text.splitlines()) <= 2
        assert rec._repr_png_().startswith(PNG)
        ax = rec.plot(3)
        assert "frame 3" in ax.get_title() and "aris recording sample.aris" in ax.get_title()
        rec.save(tmp_path / "f.png", frame=1)
        assert (tmp_path / "f.png").read_bytes().startswith(PNG)
        assert rec.to_pil(2, kind="polar").size == (48, 2000)
        assert "frame 2" in repr(rec.read(2))
