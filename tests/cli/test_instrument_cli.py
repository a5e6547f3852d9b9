"""``sonarsim render`` for instruments and ``--along`` a recording, ``sonarsim show`` for the
films of side-scan, multibeam and echo-sounder recordings (issue 38 item 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from sonarsim.cli.main import main

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
SIDESCAN = REAL / "sidescan" / "iver2_seascan_pings_0-179.xtf"
needs_data = pytest.mark.skipif(not SIDESCAN.is_file(), reason="needs ../shared/data/real")

SCENE = {"sonar": {"type": "sidescan", "preset": "seascan_hds_600", "n_samples": 512, "ping_rate_hz": 10,
                   "pose": {"position_m": [0, 0, 10]}},
         "vehicle": {"speed_m_s": 2.0}, "ground": {"height_m": 0.0},
         "objects": [{"name": "box", "primitive": "box", "size_m": [1, 1, 1], "pose": {"position_m": [2, 12, 0.5]}}]}


def write_scene(tmp_path: Path, doc: dict = SCENE) -> Path:
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_render_writes_a_side_scans_waterfall(tmp_path):
    out = tmp_path / "out"
    assert main(["render", str(write_scene(tmp_path)), "--out", str(out), "--pings", "20"]) == 0
    png = np.asarray(Image.open(out / "sidescan_waterfall.png"))
    assert png.shape == (20, 1024)
    z = np.load(out / "sidescan.npz")
    assert z["samples"].shape == (20, 2, 512)
    np.testing.assert_allclose(z["geometry/x_m"], 0.2 * np.arange(20), atol=1e-9)  # 2 m/s at 10 pings a second
    box = z["labels/instance"] == 0  # object 0, the box, to port
    assert box[:, 0].any() and not box[:, 1].any()
    assert not (out / "polar.png").exists()


def test_render_refuses_what_it_cannot_do(tmp_path, capsys):
    scene = write_scene(tmp_path)
    with pytest.raises(SystemExit) as exc:  # (argparse's own usage error)
        main(["render", str(scene), "--out", str(tmp_path / "a"), "--pings", "3:1"])
    assert exc.value.code == 2 and "--pings" in capsys.readouterr().err
    assert main(["render", str(scene), "--out", str(tmp_path / "b"), "--instrument", "nope"]) == 2
    assert "no instrument 'nope'" in capsys.readouterr().err
    assert main(["render", str(scene), "--out", str(tmp_path / "c"), "--pings", "0:5"]) == 2
    assert "with --along" in capsys.readouterr().err


@needs_data
def test_render_along_a_recording_replays_its_pings(tmp_path, capsys):
    pytest.importorskip("pyxtf")
    from sonarsim.io.readers.xtf import read_waterfall

    out = tmp_path / "along"
    assert main(["render", str(write_scene(tmp_path)), "--out", str(out), "--along", str(SIDESCAN),
                 "--pings", "1:41", "--no-speckle"]) == 0
    rec = read_waterfall(SIDESCAN, slice(1, 41))
    z = np.load(out / "sidescan.npz")
    assert z["samples"].shape == rec.samples.shape  # the recording's layout, not the scene's 512 samples
    np.testing.assert_allclose(z["geometry/altitude_m"], rec.geometry.altitude_m, rtol=1e-6)
    np.testing.assert_allclose(z["geometry/roll_deg"], rec.geometry.roll_deg, atol=1e-6)
    np.testing.assert_allclose(z["geometry/heading_deg"], rec.geometry.heading_deg, atol=1e-6)
    # each line dark before the floor: nothing nearer than the logged altitude
    r = (np.arange(rec.n_samples) + 0.5) * rec.range_max_m / rec.n_samples
    for p in range(40):
        assert not z["samples"][p][:, r < rec.geometry.altitude_m[p] - 0.1].any()
    other = REAL / "aris" / "sample.aris"
    assert main(["render", str(write_scene(tmp_path)), "--out", str(tmp_path / "x"), "--along", str(other)]) == 2
    assert "--along" in capsys.readouterr().err


@needs_data
@pytest.mark.parametrize("path, film, shape", [
    (SIDESCAN, "waterfall", (180, 2048)),
    (REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf", "soundings", (460, 256)),
    (REAL / "singlebeam" / "imagenex852_2016-11-18.852", "envelope", (500, 917)),
])
def test_show_draws_each_film(tmp_path, path, film, shape):
    pytest.importorskip("pyxtf")
    out = tmp_path / film
    assert main(["show", str(path), "--out", str(out)]) == 0
    assert np.asarray(Image.open(out / f"{film}.png")).shape == shape
    assert (out / f"{film}_figure.png").stat().st_size > 10_000
    assert main(["show", str(path), "--out", str(tmp_path / "some"), "--pings", "10:30"]) == 0
    some = np.asarray(Image.open(tmp_path / "some" / f"{film}.png")).shape
    assert some == ((20, shape[1]) if film != "envelope" else (shape[0], 20))


@needs_data
def test_calibrate_fits_a_side_scan_on_some_pings_and_scores_it_on_others(tmp_path, capsys):
    pytest.importorskip("pyxtf")
    import json

    import sonarsim

    scene = tmp_path / "cal.yaml"
    scene.write_text(yaml.safe_dump({"sonar": {"type": "sidescan", "preset": "seascan_hds_600"},
                                     "ground": {"height_m": 0.0, "material": {"law": "lambert", "mu": 0.01}}}))
    out, figures = tmp_path / "fitted.yaml", tmp_path / "fit.json"
    assert main(["calibrate", str(SIDESCAN), "--scene", str(scene), "--out", str(out), "--json", str(figures),
                 "--pings", "1:60", "--evaluate-pings", "120:180"]) == 0
    fitted = sonarsim.load_scene(out).instruments[0]
    s = json.loads(figures.read_text())
    assert s["calibration_pings"] == [1, 59] and s["test_pings"] == [120, 179]
    assert fitted.depression_deg == pytest.approx(s["fit"]["depression_deg"], abs=1e-3)
    assert s["first_return"]["model_m"] < s["first_return"]["geometry_m"] < s["first_return"]["altitude_m"]
    assert main(["calibrate", str(SIDESCAN), "--scene", str(scene), "--out", str(tmp_path / "x.yaml"),
                 "--pings", "1:60", "--evaluate-pings", "50:80"]) == 2
    assert "--evaluate-pings" in capsys.readouterr().err and not (tmp_path / "x.yaml").exists()


def test_render_writes_every_instruments_film(tmp_path):
    doc = {"vehicle": {"pose": {"position_m": [0, 0, 6]}, "speed_m_s": 1.0}, "ground": {"height_m": 0.0},
           "instruments": [
               {"type": "sidescan", "name": "sss", "preset": "seascan_hds_600", "n_samples": 256},
               {"type": "scanning", "name": "head", "preset": "ping360", "range_max_m": 10, "n_samples": 200,
                "mount": {"rpy_deg": [0, 30, 0]}},
               {"type": "singlebeam", "name": "alt", "preset": "ping2", "range_max_m": 10},
               {"type": "multibeam", "name": "mbes", "preset": "r2sonic_2026_400", "range_max_m": 12, "n_samples": 256},
               {"type": "fls", "name": "front", "preset": "oculus-m1200d-lf", "mount": {"rpy_deg": [0, 20, 0]}}]}
    out = tmp_path / "mix"
    assert main(["render", str(write_scene(tmp_path, doc)), "--out", str(out), "--pings", "6", "--no-figures"]) == 0
    assert np.load(out / "sss.npz")["samples"].shape == (6, 2, 256)
    assert np.asarray(Image.open(out / "head_scan.png")).shape == (200, 6)
    alt = np.load(out / "alt.npz")
    np.testing.assert_allclose(alt["bottom_range_m"], 6.0, atol=2 * 10 / alt["samples"].shape[1])  # level, 6 m up
    mbes = np.load(out / "mbes.npz")
    assert mbes["two_way_time_s"].shape == (6, 256)
    nadir = np.nanmin(mbes["two_way_time_s"] * mbes["geometry/sound_speed_m_s"][:, None] / 2.0, axis=1)
    np.testing.assert_allclose(nadir, 6.0, atol=0.05)
    assert (out / "front" / "polar.png").is_file() and (out / "front" / "render.npz").is_file()
    record = (out / "sonarsim-run.json").read_text()
    assert '"complete"' in record and "mbes.npz" in record


def test_render_along_a_trajectory_file(tmp_path):
    track = tmp_path / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0,0,0,10,0,0,0\n10,0,20,10,0,0,90\n")
    out = tmp_path / "t"
    assert main(["render", str(write_scene(tmp_path)), "--out", str(out), "--trajectory", str(track),
                 "--no-figures"]) == 0
    z = np.load(out / "sidescan.npz")
    assert z["samples"].shape[0] == 101  # 10 s at the scene's 10 pings a second
    np.testing.assert_allclose(z["geometry/y_m"], 2.0 * z["geometry/time_s"], atol=1e-9)
    np.testing.assert_allclose(z["geometry/heading_deg"][[0, -1]], [90.0, 0.0], atol=1e-9)


@needs_data
def test_calibrate_fits_a_multibeam_floor_and_an_echo_sounders_detector(tmp_path):
    import json

    import sonarsim

    pytest.importorskip("pyxtf")
    mb = tmp_path / "mb.yaml"
    mb.write_text(yaml.safe_dump({"vehicle": {"pose": {"position_m": [0, 0, 0]}},
                                  "instruments": [{"type": "multibeam", "name": "head", "preset": "r2sonic_2026_400",
                                                   "range_max_m": 32.0}]}))
    out, figures = tmp_path / "mb_fitted.yaml", tmp_path / "mb.json"
    assert main(["calibrate", str(REAL / "multibeam" / "r2sonic2026_pings_0-459.xtf"), "--scene", str(mb),
                 "--out", str(out), "--json", str(figures), "--pings", "0:230", "--evaluate-pings", "230:300"]) == 0
    s = json.loads(figures.read_text())
    assert s["range_m"]["model"] < s["range_m"]["calibration_mean_per_beam"] < s["range_m"]["level_floor"]
    fitted = sonarsim.load_scene(out)
    floor = [p for p in fitted.planes if p.name == "floor"][0]
    assert -11.5 < floor.point_m[2] < -10.0
    sb = tmp_path / "sb.yaml"
    sb.write_text(yaml.safe_dump({"vehicle": {"pose": {"position_m": [0, 0, 0]}},
                                  "instruments": [{"type": "singlebeam", "name": "echo", "preset": "imagenex_852"}]}))
    out = tmp_path / "sb_fitted.yaml"
    assert main(["calibrate", str(REAL / "singlebeam" / "imagenex852_2016-11-18.852"), "--scene", str(sb),
                 "--out", str(out)]) == 0
    assert -10.0 < sonarsim.load_scene(out).instruments[0].threshold_db < 0.0
