"""One loader of stored images for every command (issue 37): ``compare``, ``show`` and
``sonarsim.read`` take the same echo components from a labelled frame (never its label maps),
refuse an image holding NaN with the same one-line message, and ``show`` names the file it
shows."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.comparison import load_image
from sonarsim.cli.main import main
from sonarsim.io.output import read_npz, write_npz
from sonarsim.io.readers import RecordingError, open_recording
from sonarsim.io.readers.npz import echo_components, load_stored_image
from tests.io.test_stored_frames import SCENE


@pytest.fixture(scope="module")
def labelled(tmp_path_factory):
    """A frame rendered with its labels (instance and elevation maps), saved as NPZ."""
    image = sonarsim.Simulator(SCENE).render(labels=True)
    path = tmp_path_factory.mktemp("labelled") / "frame.npz"
    image.save_npz(path)
    return image, path


def test_a_labelled_frame_gives_the_same_components_to_every_reader(labelled):
    image, path = labelled
    arrays, _ = read_npz(path)
    labels = {k for k in arrays if k.startswith(("instance", "elevation")) and arrays[k].shape == image.polar.shape}
    # The frame does hold label maps of the image's shape, some of them float like the echoes.
    assert {"instance", "elevation_deg", "elevation_min_deg"} <= labels
    assert arrays["elevation_deg"].dtype.kind == "f"
    echoes = {"object", "ground", "single", "double", "triple", "total"} | set(image.components.signatures)
    read = sonarsim.read(path)
    with open_recording(path) as recording:  # what show reads
        shown = recording.read(0)
    compared = load_image(path)  # what compare reads
    for back in (read, shown, compared):
        assert set(back.components) == echoes and not labels & set(back.components)
        for name in echoes:
            np.testing.assert_array_equal(back.components[name], np.asarray(image.components[name], np.float32))
        np.testing.assert_array_equal(back.polar, image.polar)
    assert set(echo_components(arrays, image.polar.shape)) == echoes


def test_compare_refuses_a_label_map_as_a_component(labelled, capsys):
    _, path = labelled
    with pytest.raises(RecordingError, match=r"no image 'elevation_deg' \(a label map, not an echo image\)"):
        load_image(path, component="elevation_deg")
    assert main(["compare", str(path), str(path), "--component-a", "instance"]) == 2
    assert "a label map" in capsys.readouterr().err


def _nan_image(tmp_path):
    image = sonarsim.render(SCENE)
    arrays = image.arrays()
    arrays["polar"] = np.full_like(arrays["polar"], np.nan)
    path = tmp_path / "nan.npz"
    write_npz(path, arrays, image.config)
    return path


def test_show_and_compare_refuse_a_nan_image_with_the_same_message(tmp_path, capsys):
    path = _nan_image(tmp_path)
    capsys.readouterr()
    assert main(["show", str(path), "--out", str(tmp_path / "shown")]) == 2
    shown = capsys.readouterr().err.strip()
    assert main(["compare", str(path), str(path)]) == 2
    compared = capsys.readouterr().err.strip()
    assert len(shown.splitlines()) == 1 and shown == compared
    assert f"{path}: polar: holds NaN or infinite values (1080 of 1080 pixels)" in shown
    assert not (tmp_path / "shown").exists() or not list((tmp_path / "shown").iterdir())  # no black PNGs
    with pytest.raises(RecordingError, match="holds NaN or infinite values"):
        sonarsim.read(path)


def test_an_infinite_component_is_refused_only_when_it_is_the_image(tmp_path):
    image = sonarsim.render(SCENE)
    arrays = image.arrays()
    arrays["triple"] = np.full_like(arrays["triple"], np.inf)
    path = tmp_path / "inf.npz"
    write_npz(path, arrays, image.config)
    assert load_stored_image(path).polar.shape == image.polar.shape
    with pytest.raises(RecordingError, match=r"triple: holds NaN or infinite values"):
        load_stored_image(path, "triple", geometry="axes")


def test_show_titles_a_dataset_frame_by_its_file_frame_and_time(tmp_path, monkeypatch):
    from sonarsim.dataset import generate
    from sonarsim.plot import figures

    scenario = {"scene": SCENE, "seed": 4,
                "trajectory": {"generate": {"kind": "orbit", "centre_m": [2.5, 0.0, 0.15], "radius_m": 2.0,
                                            "z_m": 1.0, "frames": 4}}}
    generate(scenario, tmp_path / "ds", frames=2, progress=False)
    titles = []
    for name in ("fan_figure", "polar_figure"):
        original = getattr(figures, name)
        monkeypatch.setattr(figures, name, lambda image, *, _f=original, **kw: titles.append(kw["title"]) or _f(image, **kw))
    path = tmp_path / "ds" / "frames" / "000001.npz"
    assert main(["show", str(path), "--out", str(tmp_path / "shown")]) == 0
    assert len(titles) == 2 and titles[0] == titles[1]
    first = titles[0].split("\n")[0]
    assert first.startswith("000001.npz, dataset frame 1 at t = ") and "12 beams, 0.5\u20134 m" in first
    assert not first.startswith("sonar")
