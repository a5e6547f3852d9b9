"""Images sonarsim stored as NPZ (a dataset's frames, ``render.npz``, ``SonarImage.save_npz``)
read back by ``sonarsim.read``, ``read_frames``, ``open_recording`` and ``sonarsim show``
(issue 21): the same arrays, sonar and pose; and hostile NPZs refused in one line, without
pickle and before allocating what they declare."""

from __future__ import annotations

import io
import json
import tracemalloc
import zipfile

import numpy as np
import pytest
import yaml
from PIL import Image

import sonarsim
from sonarsim.cli.main import main
from sonarsim.io.output import read_npz, to_uint8, write_npz
from sonarsim.io import readers
from sonarsim.io.readers import NpzRecording, RecordingError

SCENE = {
    "sonar": {"n_beams": 12, "azimuth_fov_deg": 24.0, "elevation_fov_deg": 12.0, "range_min_m": 0.5,
              "range_max_m": 4.0, "n_range_bins": 90, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 3]}},
    "render": {"elevation_samples": 8},
    "ground": {"height_m": 0.0},
    "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.3],
                 "pose": {"position_m": [2.5, 0.2, 0.15]}}],
}


def assert_same_image(back, image, stored_arrays):
    """``back`` (read from the NPZ) holds ``image``'s arrays, sonar and pose."""
    np.testing.assert_array_equal(back.polar, image.polar)
    assert back.polar.dtype == np.float32
    np.testing.assert_array_equal(back.range_m, image.range_m)
    np.testing.assert_array_equal(back.azimuth_deg, image.azimuth_deg)
    assert back.sonar == image.sonar
    np.testing.assert_allclose(back.pose.matrix(), image.pose.matrix(), atol=1e-12)
    # Every echo image stored comes back as a component; the labels and ray maps do not.
    echoes = {k for k, v in stored_arrays.items() if k != "polar" and np.shape(v) == image.polar.shape
              and np.asarray(v).dtype.kind == "f" and not k.startswith(("rays_", "instance", "elevation"))}
    assert set(back.components) == echoes and "total" in echoes
    for name in echoes:
        np.testing.assert_array_equal(back.components[name], stored_arrays[name])


def test_save_npz_round_trip(tmp_path):
    image = sonarsim.render(SCENE)
    path = tmp_path / "image.npz"
    image.save_npz(path)
    back = sonarsim.read(path)
    assert_same_image(back, image, image.arrays())
    assert back.config == json.loads(json.dumps(image.config))  # JSON: tuples come back as lists
    assert readers.n_frames(path) == 1
    assert [im.polar.shape for im in sonarsim.read_frames(path)] == [image.polar.shape]
    with sonarsim.open_recording(path) as recording:
        assert isinstance(recording, NpzRecording) and recording.damage is None
        first, second = recording.read(0), recording.read(0)
        assert first.polar is not second.polar  # each read its own arrays
    with pytest.raises(RecordingError, match=r"frame 1 is out of range: the file has 1 frames \(valid: 0 to 0\)"):
        sonarsim.read(path, 1)


def test_render_npz_round_trip_and_show(tmp_path, capsys):
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump(SCENE))
    assert main(["render", str(scene), "--out", str(tmp_path / "r"), "--no-figures"]) == 0
    path = tmp_path / "r" / "render.npz"
    arrays, _ = read_npz(path)
    back = sonarsim.read(path)
    image = sonarsim.render(SCENE)
    np.testing.assert_array_equal(arrays["polar"], image.polar)  # (the render is deterministic)
    assert_same_image(back, image, arrays)
    # show writes what render wrote: the same PNGs from the stored frame, and its figures.
    out = tmp_path / "shown"
    capsys.readouterr()
    assert main(["show", str(path), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"read npz frame 0 of 1 from {path}" in err and "note:" not in err
    for name in ("polar.png", "fan.png", "fan_figure.png", "polar_figure.png", "sonarsim-run.json"):
        assert (out / name).is_file(), name
    np.testing.assert_array_equal(np.asarray(Image.open(out / "polar.png")),
                                  np.asarray(Image.open(tmp_path / "r" / "polar.png")))
    np.testing.assert_array_equal(np.asarray(Image.open(out / "fan.png")),
                                  np.asarray(Image.open(tmp_path / "r" / "fan.png")))


def test_dataset_frame_round_trip_and_show(tmp_path, capsys):
    from sonarsim.dataset import frames, generate

    scenario = {"scene": SCENE, "seed": 4,
                "trajectory": {"generate": {"kind": "orbit", "centre_m": [2.5, 0.0, 0.15], "radius_m": 2.0,
                                            "z_m": 1.0, "frames": 4}}}
    out = tmp_path / "ds"
    generate(scenario, out, frames=2, formats=("npz", "png"), progress=False, labels="all")  # with components
    rendered = list(frames(scenario, stop=2, labels="all"))
    for frame in rendered:
        path = out / "frames" / f"{frame.index:06d}.npz"
        arrays, config = read_npz(path)
        back = sonarsim.read(path)
        assert_same_image(back, frame.image, arrays)
        np.testing.assert_allclose(back.pose.matrix(), frame.spec.pose.matrix(), atol=1e-12)
        assert back.config["dataset"]["frame"] == frame.index == config["dataset"]["frame"]
    # A dataset's default frame (the device image and its labels) reads back without components.
    generate(scenario, tmp_path / "default", frames=1, progress=False)
    back = sonarsim.read(tmp_path / "default" / "frames" / "000000.npz")
    np.testing.assert_array_equal(back.polar, rendered[0].image.polar)
    assert not set(back.components)
    # show on a stored frame: its figures, and the PNGs the dataset itself wrote.
    path = out / "frames" / "000001.npz"
    shown = tmp_path / "shown"
    capsys.readouterr()
    assert main(["show", str(path), "--out", str(shown)]) == 0
    assert "read npz frame 0 of 1" in capsys.readouterr().err
    assert (shown / "fan_figure.png").stat().st_size > 1000 and (shown / "polar_figure.png").is_file()
    np.testing.assert_array_equal(np.asarray(Image.open(shown / "polar.png")),
                                  np.asarray(Image.open(out / "frames" / "000001_polar.png")))
    np.testing.assert_array_equal(np.asarray(Image.open(shown / "fan.png")),
                                  np.asarray(Image.open(out / "frames" / "000001_fan.png")))
    # (the pixels sonarsim render draws: dB, 40 dB below the image's maximum)
    np.testing.assert_array_equal(np.asarray(Image.open(shown / "polar.png")),
                                  to_uint8(rendered[1].image.polar[::-1], "db", 0.0, 40.0))
    capsys.readouterr()
    assert main(["show", str(path), "--frame", "1", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "0 to 0" in err and str(path) in err


# Hostile NPZs ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stored():
    """A stored image's arrays and configuration (as written), to tamper with."""
    image = sonarsim.render(SCENE)
    return image.arrays(), json.loads(json.dumps(image.config))


def _write(path, arrays, config):
    write_npz(path, arrays, config)
    return path


def _npy(value) -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, value, allow_pickle=True)
    return buffer.getvalue()


def _cases(tmp_path, arrays, config):
    """(name, path, text the one-line error must hold)."""
    sonar = config["sonar"]
    cases = [
        ("no-sonar", _write(tmp_path / "a.npz", arrays, {k: v for k, v in config.items() if k != "sonar"}),
         "config_json: has no 'sonar' section"),
        ("beam-file", _write(tmp_path / "b.npz", arrays,
                             {**config, "sonar": {**sonar, "beam_angles_file": "/etc/passwd"}}),
         "sonar.beam_angles_file names a file"),
        ("bad-sonar", _write(tmp_path / "c.npz", arrays, {**config, "sonar": {**sonar, "elevation_fov_deg": "wide"}}),
         "config_json: sonar.elevation_fov_deg"),
        ("other-bins", _write(tmp_path / "d.npz", arrays, {**config, "sonar": {**sonar, "n_range_bins": 91}}),
         "polar: has shape (90, 12), but the configuration's sonar has 91 range bins x 12 beams"),
        ("moved-axis", _write(tmp_path / "e.npz", {**arrays, "range_m": arrays["range_m"] + 0.01}, config),
         "range_m: is not the axis of the configuration's sonar"),
        ("no-polar", _write(tmp_path / "f.npz", {k: v for k, v in arrays.items() if k != "polar"}, config),
         "polar: missing"),
        ("text-polar", _write(tmp_path / "g.npz", {**arrays, "polar": np.full((90, 12), "x")}, config),
         "polar: holds <U1 values"),
        ("3-d", _write(tmp_path / "h.npz", {**arrays, "polar": arrays["polar"][None]}, config),
         "polar: has shape (1, 90, 12); an image has 2 dimensions"),
    ]
    np.savez(tmp_path / "i.npz", **arrays)
    cases.append(("no-config", tmp_path / "i.npz", "no 'config_json' entry"))
    pickled = tmp_path / "j.npz"  # an object array: loading it would unpickle (run code)
    with zipfile.ZipFile(pickled, "w") as z:
        z.writestr("polar.npy", _npy(np.array([{"a": 1}], dtype=object)))
        z.writestr("config_json.npy", _npy(np.array(json.dumps(config))))
    cases.append(("pickle", pickled, "allow_pickle"))
    good = _write(tmp_path / "good.npz", arrays, config).read_bytes()
    (tmp_path / "k.npz").write_bytes(good[: len(good) // 2])
    cases.append(("cut", tmp_path / "k.npz", "not a readable NPZ written by sonarsim"))
    flipped = bytearray(good)
    for at in range(200, len(flipped) // 2, 997):  # inside the first entries' deflated data
        flipped[at] ^= 0xFF
    (tmp_path / "l.npz").write_bytes(bytes(flipped))
    cases.append(("flipped", tmp_path / "l.npz", "not a readable NPZ written by sonarsim"))
    with zipfile.ZipFile(tmp_path / "m.npz", "w") as z:  # a zip, but no .npy in it
        z.writestr("notes.txt", "hello")
    cases.append(("plain-zip", tmp_path / "m.npz", "no 'config_json' entry"))
    np.savez(tmp_path / "n.npz", **arrays, config_json=np.array("[" * 100000 + "]" * 100000))
    cases.append(("deep-json", tmp_path / "n.npz", "nested too deeply"))
    # Names and headers quoted in a message come out on one line of printable characters.
    with zipfile.ZipFile(tmp_path / "o.npz", "w") as z:
        z.writestr("po\nlar\x1b[2J.npy", _npy(arrays["polar"]))
        z.writestr("config_json.npy", _npy(np.array(json.dumps(config))))
    cases.append(("control-characters", tmp_path / "o.npz", "this file holds po\\x0alar\\x1b[2J"))
    return cases


def test_hostile_npzs_are_refused_in_one_line(tmp_path, stored, capsys):
    arrays, config = stored
    for name, path, text in _cases(tmp_path, arrays, config):
        with pytest.raises(RecordingError) as err:
            sonarsim.read(path)
        message = str(err.value)
        assert str(path) in message and text in message and "\n" not in message, (name, message)
        for call in (lambda: sonarsim.open_recording(path), lambda: list(sonarsim.read_frames(path)),
                     lambda: readers.n_frames(path)):
            with pytest.raises(RecordingError) as again:
                call()
            assert str(again.value) == message, name
        capsys.readouterr()
        out = tmp_path / f"out-{name}"
        assert main(["show", str(path), "--out", str(out)]) == 2, name
        err_text = capsys.readouterr().err.strip()
        assert len(err_text.splitlines()) == 1 and text in err_text, (name, err_text)
        assert not out.exists() or not list(out.iterdir()), name


def test_an_npz_declaring_terabytes_is_refused_before_allocating(tmp_path, stored):
    # A zip bomb in miniature: a header asking for 4 TB of float32 and a few bytes of data.
    arrays, config = stored
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for k in ("polar", "range_m", "azimuth_deg"):
            z.writestr(k + ".npy", _npy(arrays[k]))
        z.writestr("config_json.npy", _npy(np.array(json.dumps(config))))
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                      "shape": (10**6, 10**6)})
        z.writestr("huge.npy", header.getvalue() + b"\0" * 1000)
    tracemalloc.start()
    try:
        with pytest.raises(RecordingError, match=r"bomb.npz: .*memory budget"):
            sonarsim.read(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20 * 2**20  # nothing near what the header declares was allocated
