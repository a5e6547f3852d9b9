"""Datasets of every instrument (sonarsim.dataset.instruments): the files are the same bytes
whatever the workers; chunking does not change a ping; ping k's draws are (seed, k)'s; the
side-scan's labels and boxes agree with each other and with the box the vehicle passes; the
manifest's checksums are the files'; the bag holds what the NPZ hold."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

import sonarsim
from sonarsim.errors import ConfigError
from sonarsim.dataset.instruments import write_instrument_dataset
from sonarsim.dataset.manifest import seal_record
from sonarsim.instruments import render_pings, vehicle_poses
from sonarsim.instruments.sidescan import waterfall_boxes
from sonarsim.io.output import read_npz

# The vehicle runs along +x at 2 m/s, 5 m up; a 1 m box 6 m to port spans x in [0.5, 1.5], so
# the side-scan's pings at x = 0.6, 0.8, 1.0 (pings 3-5 at 10 Hz) see it, the first ones do not.
DOC = {
    "vehicle": {"pose": {"position_m": [0.0, 0.0, 5.0]}, "speed_m_s": 2.0},
    "instruments": [
        {"type": "sidescan", "name": "sss", "range_max_m": 15.0, "n_samples": 150, "ping_rate_hz": 10,
         "depression_deg": 20, "vertical_beam_width_deg": 60},
        {"type": "scanning", "name": "head", "range_max_m": 8.0, "n_samples": 80, "tilt_deg": 20,
         "mount": {"position_m": [0.3, 0.0, 0.2]}},
        {"type": "singlebeam", "name": "alt", "beam_width_deg": 10, "range_max_m": 10.0, "n_samples": 100},
    ],
    "objects": [{"name": "box", "primitive": "box", "size_m": [1.0, 1.0, 1.0],
                 "pose": {"position_m": [1.0, 6.0, 0.5]}}],
    "ground": {"height_m": 0.0},
    "render": {"max_order": 1, "elevation_samples": 48, "speckle": True},
}
PINGS = {"sss": 6, "head": 5, "alt": 3}


def files_of(out) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def one_worker(tmp_path_factory):
    out = tmp_path_factory.mktemp("one")
    summary = write_instrument_dataset(DOC, out, PINGS, chunk=4, seed=11, rosbag="mcap")
    return out, summary


def test_the_same_files_whatever_the_number_of_workers(one_worker, tmp_path):
    out, _ = one_worker
    write_instrument_dataset(DOC, tmp_path, PINGS, chunk=4, seed=11, workers=2, rosbag="mcap")
    a, b = files_of(out), files_of(tmp_path)
    assert sorted(a) == sorted(b)
    assert "sss/000001_labels.png" in a and "head/000001.npz" in a and "alt/000000.npz" in a
    for name in a:
        if not name.startswith("rosbag/"):  # the bag's storage file carries no clock either, but
            assert a[name] == b[name], name  # its metadata names its own folder's file: compared below
    assert a["rosbag/rosbag.mcap"] == b["rosbag/rosbag.mcap"]


def test_chunks_hold_the_pings_a_whole_render_gives_and_ping_k_draws_from_seed_k(one_worker, tmp_path):
    out, summary = one_worker
    sss = [read_npz(out / r["files"][0])[0] for r in summary.records if r["instrument"] == "sss"]
    assert [len(a["samples"]) for a in sss] == [4, 2]
    samples = np.concatenate([a["samples"] for a in sss])
    instance = np.concatenate([a["labels/instance"] for a in sss])
    # Another chunk size: the same pings.
    write_instrument_dataset(DOC, tmp_path, {"sss": 6}, chunk=3, seed=11, instruments=["sss"])
    other = [read_npz(tmp_path / "sss" / f"{c:06d}.npz")[0] for c in range(2)]
    np.testing.assert_array_equal(np.concatenate([a["samples"] for a in other]), samples)
    # The whole waterfall rendered at once with the same seed: the same pings (speckle on).
    doc = {**DOC, "render": {**DOC["render"], "seed": 11}}
    with sonarsim.Simulator(doc) as sim:
        whole = render_pings(sim, "sss", n_pings=6, labels=True)
        # Ping 5 alone, at its own pose and time, first_ping=5: its draws are (seed, 5)'s.
        poses, times = vehicle_poses(sim, sim.scene.instruments[0], 6)
        alone = render_pings(sim, "sss", poses=poses[5:], times_s=times[5:], first_ping=5)
        as_ping0 = render_pings(sim, "sss", poses=poses[5:], times_s=times[5:], first_ping=0)
    np.testing.assert_array_equal(whole.samples, samples)
    np.testing.assert_array_equal(whole.labels["instance"], instance)
    np.testing.assert_array_equal(alone.samples[0], samples[5])
    assert not np.array_equal(as_ping0.samples[0], samples[5])  # another ping's draws differ
    # Another seed: other speckle.
    write_instrument_dataset(DOC, tmp_path / "seed12", {"sss": 6}, chunk=4, seed=12, instruments=["sss"])
    assert not np.array_equal(read_npz(tmp_path / "seed12" / "sss" / "000000.npz")[0]["samples"], samples[:4])


def test_side_scan_labels_boxes_and_the_box_passed(one_worker):
    out, summary = one_worker
    records = [r for r in summary.records if r["instrument"] == "sss"]
    box_id = 0  # the scene's first object; then the planes (ground)
    pings_seen = []
    for r in records:
        arrays, config = read_npz(out / r["files"][0])
        assert config["ids"][box_id] == "box" and config["film"] == "waterfall"
        inst, shadow = arrays["labels/instance"], arrays["labels/shadow"]
        # The boxes are the instance map's, in the chunk's own pings; the manifest lists them.
        np.testing.assert_array_equal(arrays["labels/boxes"], waterfall_boxes(inst, len(config["ids"])))
        listed = {(b["name"], b["side"]): b["box"] for b in r["boxes"]}
        for s, side in enumerate(("port", "starboard")):  # the objects' (the box), not the floor's
            if arrays["labels/boxes"][box_id, s, 0] >= 0:
                assert listed[("box", side)] == list(arrays["labels/boxes"][box_id, s])
            else:
                assert ("box", side) not in listed
        assert all(b["name"] == "box" for b in r["boxes"])
        pings_seen += [r["first_ping"] + p for p in np.nonzero((inst[:, 0] == box_id).any(axis=1))[0]]
        # The box is to port: never on the starboard side; its shadow lies beyond its echo.
        assert not (inst[:, 1] == box_id).any()
        for p in np.nonzero((inst[:, 0] == box_id).any(axis=1))[0]:
            last_echo = np.nonzero(inst[p, 0] == box_id)[0].max()
            assert shadow[p, 0].any() and np.nonzero(shadow[p, 0])[0].min() > last_echo
        # The labels PNG: the object's grey (255 for id 0) where it dominates, the floor's 128, shadow 64.
        from PIL import Image

        png = np.asarray(Image.open(out / r["files"][2]))
        disp = np.concatenate([inst[:, 0, ::-1], inst[:, 1]], axis=1)
        assert png.shape == disp.shape and (png[disp == box_id] == 255).all() and (png[disp == 1] == 128).all()
        sh = np.concatenate([shadow[:, 0, ::-1], shadow[:, 1]], axis=1)
        assert (png[(disp < 0) & sh] == 64).all() and (png[(disp < 0) & ~sh] == 0).all()
    # Vehicle x at ping k is 0.2 k: the box (x in [0.5, 1.5]) is in the beam from ping 3 on.
    assert pings_seen == [3, 4, 5]
    # Its echo's near edge: slant range to the box's near top edge (5.5 m across, 4 m down).
    arrays, _ = read_npz(out / records[1]["files"][0])
    first = np.nonzero(arrays["labels/instance"][0, 0] == box_id)[0].min()
    assert abs(first * 0.1 - np.hypot(5.5, 4.0)) <= 0.25


def test_manifest_lines_are_sealed_and_name_their_files(one_worker):
    out, summary = one_worker
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert lines == list(summary.records)
    assert [(r["instrument"], r["chunk"]) for r in lines] == [("sss", 0), ("sss", 1), ("head", 0), ("head", 1),
                                                              ("alt", 0)]
    for r in lines:
        assert seal_record(r)["check"] == r["check"]
        for f in r["files"]:
            data = (out / f).read_bytes()
            assert r["bytes"][f] == len(data) and r["sha256"][f] == hashlib.sha256(data).hexdigest()
        arrays, _ = read_npz(out / r["files"][0])
        t = arrays["geometry/time_s"]
        assert len(t) == r["n_pings"] and r["time_s"] == [t[0], t[-1]] and r["seed"] == 11
    # the scanning chunks: head angles continue across chunks (step k at k * 0.9 deg)
    head = np.concatenate([read_npz(out / r["files"][0])[0]["angle_deg"] for r in lines if r["instrument"] == "head"])
    np.testing.assert_allclose(head, 0.9 * np.arange(5))
    info = json.loads((out / "dataset.json").read_text())
    assert info["seed"] == 11 and info["instruments"]["sss"] == {"type": "sidescan", "pings": 6, "chunk": 4}


def test_the_bag_holds_the_chunks(one_worker):
    from rosbags.highlevel import AnyReader

    out, summary = one_worker
    samples = np.concatenate([read_npz(out / r["files"][0])[0]["samples"] for r in summary.records
                              if r["instrument"] == "sss"])
    envelope = read_npz(out / "alt" / "000000.npz")[0]
    with AnyReader([out / "rosbag"]) as reader:
        got = {}
        for conn, t, raw in reader.messages():
            got.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert len(got["/sss/raw"]) == 6 and len(got["/head/raw"]) == 5 and len(got["/alt/range"]) == 3
    for p, m in enumerate(got["/sss/raw"]):
        np.testing.assert_array_equal(np.frombuffer(np.asarray(m.image.data, np.uint8).tobytes(), "<f4")
                                      .reshape(150, 2), samples[p].T)
    assert [m.range for m in got["/alt/range"]] == pytest.approx(list(envelope["bottom_range_m"]))


def test_bad_requests_are_named(tmp_path):
    with pytest.raises(ConfigError, match=r"instruments.*'nope'.*sss, head, alt"):
        write_instrument_dataset(DOC, tmp_path, 2, instruments=["nope"])
    with pytest.raises(ConfigError, match=r"n_pings\.sss"):
        write_instrument_dataset(DOC, tmp_path, None)
    with pytest.raises(ConfigError, match=r"chunk\.head"):
        write_instrument_dataset(DOC, tmp_path, 2, chunk={"head": 0})
    with pytest.raises(ConfigError, match=r"n_pings\.typo"):
        write_instrument_dataset(DOC, tmp_path, {"typo": 3})
    assert list(tmp_path.iterdir()) == []


# The scenario and the command ---------------------------------------------------------------

SCENARIO = """\
seed: 5
start_time: 2024-05-01T12:00:00Z
scene:
  vehicle: {pose: {position_m: [0.0, 0.0, 5.0]}}
  instruments:
    - {type: sidescan, name: sss, range_max_m: 15.0, n_samples: 150, ping_rate_hz: 10}
    - {type: singlebeam, name: alt, beam_width_deg: 10, range_max_m: 10.0, n_samples: 100, ping_rate_hz: 4}
  ground: {height_m: 0.0}
  objects: [{name: box, primitive: box, size_m: [1, 1, 1], pose: {position_m: [1.0, 6.0, 0.5]}}]
  render: {max_order: 1, elevation_samples: 48}
trajectory:
  file: track.csv
  rate_hz: 10
"""


def scenario_file(folder, extra: str = "") -> str:
    (folder / "track.csv").write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0,0,0,5,0,0,0\n1,2,0,5,0,0,0\n")
    (folder / "survey.yaml").write_text(SCENARIO + extra)
    return str(folder / "survey.yaml")


def test_sonarsim_dataset_writes_a_scenario_with_instruments(tmp_path, capsys):
    """The trajectory is the vehicle's (1 s at 2 m/s along x): the side-scan pings 11 times at
    10 Hz, the altimeter 5 times at 4 Hz, each at the track's pose at its time; the bag starts
    at the scenario's start_time."""
    from rosbags.highlevel import AnyReader

    from sonarsim.cli.main import main
    from sonarsim.io.rosbag import parse_start_time

    path = scenario_file(tmp_path)
    out = tmp_path / "out"
    assert main(["dataset", path, "--out", str(out), "--chunk", "4", "--rosbag", "mcap", "--no-progress"]) == 0
    assert "sss 11 pings, alt 5 pings" in capsys.readouterr().err
    lines = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    assert [(r["instrument"], r["first_ping"], r["n_pings"]) for r in lines] == [
        ("sss", 0, 4), ("sss", 4, 4), ("sss", 8, 3), ("alt", 0, 4), ("alt", 4, 1)]
    x = np.concatenate([read_npz(out / r["files"][0])[0]["geometry/x_m"] for r in lines if r["instrument"] == "sss"])
    np.testing.assert_allclose(x, 0.2 * np.arange(11), atol=1e-12)  # the vehicle at 2 m/s, each ping at its time
    t = read_npz(out / "alt" / "000001.npz")[0]["geometry/time_s"]
    assert list(t) == [1.0]
    # box seen to port at x in [0.5, 1.5]: pings 3..7
    seen = [r["first_ping"] + b["box"][0] for r in lines for b in r.get("boxes", []) if b["name"] == "box"]
    assert seen == [3, 4]  # the first ping of each chunk where the box is (chunks 0 and 1)
    with AnyReader([out / "rosbag"]) as reader:
        stamps = [t for conn, t, _ in reader.messages() if conn.topic == "/sss/raw"]
    start = parse_start_time("2024-05-01T12:00:00Z")
    assert stamps == [start + k * 100_000_000 for k in range(11)]
    # --frames 6 keeps the first 6 poses of the track (0.5 s): 6 side-scan pings, 3 altimeter pings
    assert main(["dataset", path, "--out", str(tmp_path / "six"), "--frames", "6", "--no-progress"]) == 0
    info = json.loads((tmp_path / "six" / "dataset.json").read_text())
    assert info["instruments"]["sss"]["pings"] == 6 and info["instruments"]["alt"]["pings"] == 3
    # Again in the same folder with another chunk: refused; with the same, the same bytes.
    before = files_of(out)
    assert main(["dataset", path, "--out", str(out), "--chunk", "5", "--no-progress"]) == 2
    assert "holds another dataset" in capsys.readouterr().err
    assert main(["dataset", path, "--out", str(out), "--chunk", "4", "--rosbag", "mcap", "--no-progress"]) == 0
    assert files_of(out) == before


def test_what_a_scene_with_instruments_cannot_take_is_named(tmp_path, capsys):
    from sonarsim.cli.main import main

    path = scenario_file(tmp_path)
    assert main(["dataset", path, "--out", str(tmp_path / "a"), "--labels", "all"]) == 2
    assert "--labels: applies to an FLS's frames" in capsys.readouterr().err
    for option in (["--yolo"], ["--shards", "8"]):  # (ML formats of an FLS's frames, not yet of pings)
        assert main(["dataset", path, "--out", str(tmp_path / "a"), *option]) == 2
        assert f"{option[0]}: applies to an FLS's frames" in capsys.readouterr().err
    varied = scenario_file(tmp_path, "variation: {ground: {albedo: {uniform: [0.3, 0.6]}}}\n")
    assert main(["dataset", varied, "--out", str(tmp_path / "b")]) == 2
    assert "variation" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_the_side_scan_survey_example_writes_its_first_pings(tmp_path):
    from pathlib import Path

    from sonarsim.dataset import load_scenario
    from sonarsim.dataset.instruments import write_scenario_instruments

    example = Path(__file__).resolve().parents[2] / "examples" / "scenarios" / "sidescan_survey.yaml"
    s = load_scenario(example, frames=3)  # the first 0.2 s of the track
    summary = write_scenario_instruments(s, tmp_path, chunk=8)
    specs = sonarsim.load_scene(s.scene).instruments
    # each instrument pings at its own period over the track's 0.2 s
    assert summary.pings == {i.name: int(np.floor(0.2 / i.ping_period_s() + 1e-9)) + 1 for i in specs}
    assert summary.pings["sss"] == 3 and summary.pings["altimeter"] == 2
    sss = read_npz(tmp_path / "sss" / "000000.npz")[0]
    # 6 m up, the mount 0.2 m below: the floor's first return near 5.8 m slant on both sides
    dr = 30.0 / 1024
    for side in range(2):
        first = np.argmax(sss["samples"][0, side] > 0) * dr
        assert abs(first - 5.8) < 0.3, first
    alt = read_npz(tmp_path / "altimeter" / "000000.npz")[0]
    assert abs(alt["bottom_range_m"][0] - 5.7) < 0.1


def test_a_damaged_or_interrupted_run_resumes_to_the_same_bytes(one_worker, tmp_path):
    """Chunks whose manifest lines verify are kept; a flipped byte, a missing file and a torn
    last line (a killed run) each send their chunk back to be made; the end is byte-identical."""
    out, _ = one_worker
    import shutil

    shutil.copytree(out, tmp_path / "d")
    d = tmp_path / "d"
    shutil.rmtree(d / "rosbag")
    reference = {k: v for k, v in files_of(out).items() if not k.startswith("rosbag/")}
    npz = bytearray((d / "sss" / "000001.npz").read_bytes())
    npz[100] ^= 0xFF
    (d / "sss" / "000001.npz").write_bytes(bytes(npz))
    (d / "alt" / "000000.png").unlink()
    lines = (d / "manifest.jsonl").read_text().splitlines()
    # the manifest as a killed run leaves it: head's chunk 1 torn mid-line, in finishing order
    (d / "manifest.jsonl").write_text("\n".join(lines[:3] + [lines[4]] + [lines[3][:40]]))
    summary = write_instrument_dataset(DOC, d, PINGS, chunk=4, seed=11)
    assert (summary.kept, summary.rendered) == (2, 3)  # sss 0 and head 0 kept; sss 1, head 1, alt 0 made
    assert files_of(d) == reference
    again = write_instrument_dataset(DOC, d, PINGS, chunk=4, seed=11)
    assert (again.kept, again.rendered) == (5, 0) and files_of(d) == reference


def test_coco_boxes_and_masks_are_the_side_scan_labels_on_the_pngs(one_worker):
    from PIL import Image

    mask_api = pytest.importorskip("pycocotools.mask")
    out, summary = one_worker
    coco = json.loads((out / "coco.json").read_text())
    assert [c["name"] for c in coco["categories"]] == ["box"]
    assert [i["file_name"] for i in coco["images"]] == ["sss/000000.png", "sss/000001.png"]
    by_image = {}
    for a in coco["annotations"]:
        by_image.setdefault(a["image_id"], []).append(a)
    assert sorted(by_image) == [0, 1]  # pings 3 (chunk 0) and 4-5 (chunk 1)
    for image in coco["images"]:
        arrays, _ = read_npz(out / image["file_name"].replace(".png", ".npz"))
        inst = arrays["labels/instance"]
        disp = np.concatenate([inst[:, 0, ::-1], inst[:, 1]], axis=1)
        png = np.asarray(Image.open(out / image["file_name"]))
        assert png.shape == (image["height"], image["width"]) == disp.shape
        (a,) = by_image[image["id"]]  # port only
        assert a["side"] == "port" and a["object"] == "box"
        rows, cols = np.nonzero(disp == 0)
        assert a["bbox"] == [cols.min(), rows.min(), cols.max() - cols.min() + 1, rows.max() - rows.min() + 1]
        assert cols.max() < 150  # port: left of nadir
        rle = mask_api.frPyObjects(a["segmentation"], image["height"], image["width"])
        np.testing.assert_array_equal(mask_api.decode(rle).astype(bool), disp == 0)
        assert a["area"] == int((disp == 0).sum())


def test_a_multibeam_chunk_round_trips_through_its_npz(tmp_path):
    """The multibeam's layout (its renderer is another module's): a hand-built Soundings chunk,
    its NPZ and back, every array equal; the bag's films are rebuilt so."""
    from sonarsim.dataset.encoding import npz_bytes
    from sonarsim.dataset.instruments import _film_from_npz, chunk_arrays
    from sonarsim.image.films import PingGeometry, Soundings

    rng = np.random.default_rng(3)
    n, b = 3, 5
    g = PingGeometry.of(n, time_s=0.5 * np.arange(n), sound_speed_m_s=1490.0, range_min_m=0.0, range_max_m=40.0)
    twtt = rng.uniform(0.01, 0.05, (n, b))
    twtt[1, 2] = np.nan
    film = Soundings(np.tile(np.linspace(60, -60, b), (n, 1)), twtt, rng.random((n, b)), g,
                     rng.random((n, 16, b)).astype(np.float32), rng.random((n, b, 3)))
    arrays, config = chunk_arrays(film, "multibeam")
    (tmp_path / "c.npz").write_bytes(npz_bytes(arrays, config))
    back = _film_from_npz("multibeam", [read_npz(tmp_path / "c.npz")] * 2)  # two chunks
    assert back.n_pings == 2 * n and config["film"] == "soundings"
    for name in ("angle_deg", "two_way_time_s", "intensity", "water_column", "points_m"):
        np.testing.assert_array_equal(getattr(back, name)[:n], getattr(film, name), err_msg=name)
    np.testing.assert_array_equal(read_npz(tmp_path / "c.npz")[0]["range_m"], film.range_m)
    np.testing.assert_array_equal(back.geometry.sound_speed_m_s[n:], g.sound_speed_m_s)
