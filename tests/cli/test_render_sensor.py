"""``sonarsim render --no-speckle / --frame N``: the expected output of a sensor, and seeded frames."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import yaml

from sonarsim.cli.main import main
from sonarsim.renderer.simulator import Simulator
from tests.cli.test_cli import TINY_SCENE


def _scene(tmp_path: Path, **sections) -> Path:
    doc = copy.deepcopy(TINY_SCENE)
    doc.update(sections)
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _polar(out: Path) -> np.ndarray:
    with np.load(out / "render.npz") as z:
        return z["polar"]


def _render(scene: Path, out: Path, *options: str) -> np.ndarray:
    assert main(["render", str(scene), "--out", str(out), *options]) == 0
    return _polar(out)


def test_no_speckle_writes_the_sensors_expected_output(tmp_path, capsys):
    scene = _scene(tmp_path, sensor={"preset": "aris3000-64"})
    a = _render(scene, tmp_path / "a", "--no-speckle")
    b = _render(scene, tmp_path / "b", "--no-speckle")
    np.testing.assert_array_equal(a, b)
    # An expected 8-bit value is a mean over the speckle: mostly not an integer.
    lit = a[a > 0]
    assert lit.size and np.mean(lit != np.round(lit)) > 0.5
    with Simulator(scene) as sim:
        np.testing.assert_array_equal(a, sim.render(speckle=False).polar)
    for name in ("polar.png", "fan.png"):
        assert (tmp_path / "a" / name).is_file()


def test_without_no_speckle_a_sensor_writes_device_counts(tmp_path, capsys):
    scene = _scene(tmp_path, sensor={"preset": "aris3000-64"})
    p = _render(scene, tmp_path / "s")
    assert p.min() >= 0 and p.max() <= 255 and (p > 0).any()
    np.testing.assert_array_equal(p, np.round(p))
    assert not np.array_equal(p, _render(scene, tmp_path / "e", "--no-speckle"))


def test_frame_draws_the_frames_speckle(tmp_path, capsys):
    # Frame-anchored speckle: the frame index (with render.seed) chooses the draws.
    scene = _scene(tmp_path, sensor={"preset": "aris3000-64", "speckle": {"anchor": "frame"}})
    f3 = _render(scene, tmp_path / "f3", "--frame", "3")
    np.testing.assert_array_equal(f3, _render(scene, tmp_path / "f3b", "--frame", "3"))
    assert not np.array_equal(f3, _render(scene, tmp_path / "f4", "--frame", "4"))
    with Simulator(scene) as sim:
        sim.render()  # the simulator's own generator moves on; frame 3 does not depend on it
        np.testing.assert_array_equal(f3, sim.render(frame=3).polar)


def test_no_speckle_without_a_sensor_writes_the_noise_free_total(tmp_path, capsys):
    scene = _scene(tmp_path, render={"elevation_samples": 8, "speckle": True})
    for options, same in ((("--no-speckle",), True), ((), False)):
        out = tmp_path / ("n" if same else "s")
        assert main(["render", str(scene), "--out", str(out), *options]) == 0
        with np.load(out / "render.npz") as z:
            assert np.array_equal(z["polar"], z["total"]) == same, options


def test_bad_frame_is_named(tmp_path, capsys):
    scene = _scene(tmp_path)
    try:
        code = main(["render", str(scene), "--out", str(tmp_path / "o"), "--frame", "-1"])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and "--frame" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_seed_and_sensor_switches_on_the_command_line(tmp_path, capsys):
    import numpy as np
    import yaml

    from sonarsim.cli.main import main

    scene = tmp_path / "s.yaml"
    scene.write_text(yaml.safe_dump({"sonar": {"preset": "aris3000-128", "n_range_bins": 300},
                                     "ground": {"height_m": -1.0}, "render": {"elevation_samples": 16}}))

    def run(*opts):
        out = tmp_path / ("o" + "_".join(o.replace("-", "") for o in opts))
        assert main(["render", str(scene), "--out", str(out), *opts]) == 0
        with np.load(out / "render.npz") as z:
            return z["polar"].copy(), z["total"].copy()

    ideal, total = run()
    a, _ = run("--sensor", "aris3000-128", "--seed", "1")
    b, _ = run("--sensor", "aris3000-128", "--seed", "1")
    c, _ = run("--sensor", "aris3000-128", "--seed", "2", "--frame", "0")
    d, _ = run("--sensor", "aris3000-128", "--seed", "1", "--frame", "0")
    np.testing.assert_array_equal(ideal, total)  # no sensor: the noise-free image
    assert np.array_equal(a, b) and np.all(a == np.round(a)) and a.max() <= 255
    assert not np.array_equal(c, d)  # another seed, other draws
    none, _ = run("--sensor", "none")
    np.testing.assert_array_equal(none, total)
    capsys.readouterr()
    assert main(["render", str(scene), "--out", str(tmp_path / "x"), "--sensor", "nope"]) == 2
    err = capsys.readouterr().err
    assert "--sensor" in err and "Traceback" not in err


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im)


def test_a_sensor_models_pngs_are_its_counts_and_look_like_the_real_recording(tmp_path, shared_data):
    # Issue 37: the PNGs of a sensor model's output were dB-mapped on top of the device's own
    # compression (median pixel above 200 of 255: pale, objects hidden). Drawn in the device's
    # counts, as `sonarsim show` draws the real ping of the same floor, the two compare.
    sim, real = tmp_path / "sim", tmp_path / "real"
    assert main(["render", str(EXAMPLES / "oculus_floor.yaml"), "--sensor", "oculus-m1200d-hf", "--out", str(sim),
                 "--no-figures"]) == 0
    assert main(["show", str(shared_data / "real/oculus/one_ping_8bit.raw"), "--out", str(real), "--no-figures"]) == 0
    counts = _polar(sim)
    np.testing.assert_array_equal(_png(sim / "polar.png"), counts[::-1].astype(np.uint8))  # the counts themselves
    for kind in ("polar", "fan"):
        ours, theirs = _png(sim / f"{kind}.png"), _png(real / f"{kind}.png")
        # Measured: polar median 52 vs 43, std 50.7 vs 52.1; fan median 13 vs 12, std 45.6 vs 45.8.
        assert abs(float(np.median(ours)) - float(np.median(theirs))) <= 20, kind
        assert 0.75 <= ours.std() / theirs.std() <= 1.33, kind
        assert abs(np.percentile(ours, 95) - np.percentile(theirs, 95)) <= 30, kind
    # What the dB mapping on top gave (the test can fail): far brighter than the recording.
    from sonarsim.image.levels import to_uint8

    assert np.median(to_uint8(counts[::-1], "db", 0.0, 40.0)) > 150


def test_a_render_without_a_sensor_and_the_components_stay_in_db(tmp_path):
    scene = _scene(tmp_path, sensor={"preset": "aris3000-64"})
    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out), "--components", "--no-figures"]) == 0
    from sonarsim.image.levels import to_uint8

    with np.load(out / "render.npz") as z:
        single = z["single"]  # a component: echo intensity, in dB
    np.testing.assert_array_equal(_png(out / "polar.png"), _polar(out)[::-1].astype(np.uint8))
    np.testing.assert_array_equal(_png(out / "polar_single.png"), to_uint8(single[::-1], "db", 0.0, 40.0))
    ideal = tmp_path / "ideal"
    assert main(["render", str(_scene(tmp_path)), "--out", str(ideal), "--no-figures"]) == 0
    np.testing.assert_array_equal(_png(ideal / "polar.png"), to_uint8(_polar(ideal)[::-1], "db", 0.0, 40.0))
