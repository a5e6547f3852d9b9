"""Datasets written by sonarsim.dataset.generate and frames from sonarsim.dataset.frames: the
same frames bit for bit whatever the workers, the order or the interruptions (SIGKILL at random
moments), damaged files and manifest lines redone, other scenarios refused, full disks."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

import sonarsim.dataset as ds
from sonarsim.dataset import frames, generate, load_scenario
from sonarsim.dataset.coco import category_of, coco_from_records
from sonarsim.dataset.frames import SimulatorCache, labels_supported, render_frame
from sonarsim.dataset.manifest import (
    Fingerprint,
    ManifestAppender,
    read_manifest,
    seal_record,
    spec_digest,
    verify_record,
)
from sonarsim.dataset.writer import npz_bytes
from sonarsim.errors import ConfigError, SonarsimError
from sonarsim.io.output import read_npz
from sonarsim.io.rosbag import DEFAULT_START_NS

from .test_scenario import SCENE, VARIED

REPO = Path(__file__).resolve().parents[2]

# The same scene for every frame (one simulator), poses on a circle around the block.
ORBIT = {
    "scene": SCENE,
    "seed": 5,
    "trajectory": {"rate_hz": 4.0, "generate": {"kind": "orbit", "centre_m": [2.5, 0.0, 0.15], "radius_m": 2.0,
                                                "z_m": 1.0, "frames": 10}},
}


def folder_bytes(folder: Path, skip=("sonarsim-run.json",)) -> dict[str, bytes]:
    """Every file under ``folder`` except the bag and the run record, by relative path."""
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.is_file() and rel not in skip and not rel.startswith("rosbag"):
            out[rel] = path.read_bytes()
    return out


# Every per-frame format and WebDataset shards: what the runs below must reproduce bit for bit.
FULL = {"formats": ("npz", "png", "yolo"), "shards": 5}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, bytes]:
    """An uninterrupted single-process run of VARIED with PNGs, YOLO labels and shards."""
    out = tmp_path_factory.mktemp("ref") / "ds"
    summary = generate(VARIED, out, **FULL, progress=False)
    assert summary.rendered == summary.n_frames == 12 and summary.reused == 0
    return folder_bytes(out)


# frames(): rendering from the spec alone ---------------------------------------------------

def test_frames_yields_each_frame_as_rendered_alone_and_in_the_dataset(tmp_path, reference):
    all_frames = list(frames(VARIED))
    assert [f.index for f in all_frames] == list(range(12))
    late = list(frames(VARIED, start=7, stop=9))  # a fresh process state: no earlier frames rendered
    assert [f.index for f in late] == [7, 8]
    for f in late:
        np.testing.assert_array_equal(f.image.polar, all_frames[f.index].image.polar)
    arrays, config = read_npz(_npz(tmp_path, reference, 8))
    np.testing.assert_array_equal(arrays["polar"], all_frames[8].image.polar)
    np.testing.assert_array_equal(arrays["range_m"], all_frames[8].image.range_m)
    assert config["dataset"] == {"frame": 8, "seed": all_frames[8].spec.seed, "time_s": all_frames[8].spec.time_s}
    assert not any(k.startswith("rays_") for k in arrays)  # per-ray maps are not part of a dataset


def _npz(tmp_path: Path, files: dict[str, bytes], k: int) -> Path:
    path = tmp_path / f"{k}.npz"
    path.write_bytes(files[f"frames/{k:06d}.npz"])
    return path


def test_frames_carry_labels_when_the_renderer_has_them():
    frame = next(frames(ORBIT, stop=1))
    if not labels_supported():
        pytest.skip("this renderer has no labels yet (render(..., labels=True))")
    arrays = frame.arrays()
    assert arrays["instance"].dtype == np.int32 and arrays["instance"].shape == frame.image.polar.shape
    assert arrays["elevation_deg"].dtype == np.float32
    assert arrays["points_world"].shape[1:] == (3,) and arrays["points_object"].dtype == np.int32
    # Where the image has energy, a cell has an instance; the block (id 0) is seen from the orbit.
    assert 0 in np.unique(arrays["instance"])


def test_simulators_are_built_once_per_scene():
    scenario = load_scenario(ORBIT)
    with SimulatorCache(threads=1) as cache:
        for spec in scenario.frame_specs(stop=4):
            render_frame(spec, cache, labels=False)
        assert cache.built == 1  # nothing varies: one scene, one simulator
    varied = load_scenario(VARIED)
    with SimulatorCache(threads=1, max_size=2) as cache:
        for spec in varied.frame_specs(stop=3):
            render_frame(spec, cache, labels=False)
        assert cache.built == 3 and len(cache._sims) == 2  # every frame its own scene; two kept


# The files ---------------------------------------------------------------------------------

def test_dataset_layout_and_manifest(tmp_path, reference):
    scenario = load_scenario(VARIED)
    lines = [json.loads(line) for line in reference["manifest.jsonl"].decode().splitlines()]
    assert [r["frame"] for r in lines] == list(range(12))
    for record in lines:
        spec = scenario.frame(record["frame"])
        assert record["seed"] == spec.seed and record["time_s"] == spec.time_s
        assert record["pose"] == {"position_m": list(spec.pose.position_m), "rpy_deg": list(spec.pose.rpy_deg)}
        assert record["spec_sha256"] == spec_digest(spec)
        k = record["frame"]
        assert record["files"] == [f"frames/{k:06d}.npz", f"frames/{k:06d}_polar.png", f"frames/{k:06d}_fan.png",
                                   f"frames/{k:06d}_fan.txt"]
        for name in record["files"]:
            assert record["bytes"][name] == len(reference[name])
            assert record["sha256"][name] == hashlib.sha256(reference[name]).hexdigest()
        assert seal_record(record)["check"] == record["check"]
    info = json.loads(reference["dataset.json"])
    assert info["n_frames"] == 12 and info["options"]["formats"] == ["npz", "png", "yolo"]
    assert set(reference) == {"dataset.json", "manifest.jsonl", *(f for r in lines for f in r["files"])} | (
        {"coco.json"} if labels_supported() else set()) | {"data.yaml", "yolo-train.txt", "yolo-val.txt"} | {
        "shards.jsonl", "shards/000000.tar", "shards/000001.tar", "shards/000002.tar"}


def test_npz_bytes_depend_on_the_content_alone(tmp_path):
    arrays = {"polar": np.arange(12, dtype=np.float32).reshape(3, 4), "ids": np.array(["a", "bc"])}
    first = npz_bytes(arrays, {"k": 1})
    time.sleep(2.1)  # zip dates have a 2-second resolution
    assert npz_bytes(arrays, {"k": 1}) == first
    assert npz_bytes({**arrays, "polar": arrays["polar"] + 1}, {"k": 1}) != first
    path = tmp_path / "a.npz"
    path.write_bytes(first)
    back, config = read_npz(path)
    assert config == {"k": 1}
    np.testing.assert_array_equal(back["polar"], arrays["polar"])
    np.testing.assert_array_equal(back["ids"], arrays["ids"])


def test_a_second_run_equals_the_first_bit_for_bit(tmp_path, reference):
    generate(VARIED, tmp_path / "ds", **FULL, progress=False)
    assert folder_bytes(tmp_path / "ds") == reference


def test_two_workers_give_the_same_files_as_one(tmp_path, reference):
    summary = generate(VARIED, tmp_path / "ds", **FULL, workers=2, batch_size=2, progress=False)
    assert summary.rendered == 12
    assert folder_bytes(tmp_path / "ds") == reference


def test_a_single_threaded_lone_worker_with_two_writers_gives_the_same_files(tmp_path, reference, monkeypatch):
    """One worker rendering on one thread gets two writer threads (frames encoded out of
    order, yielded in order): the same files as the reference."""
    from sonarsim.dataset import workers

    calls = []
    real = workers.lone_writers
    monkeypatch.setattr(workers, "lone_writers", lambda *a, **k: calls.append(real(*a, cores=2, **k)) or calls[-1])
    summary = generate(VARIED, tmp_path / "ds", **FULL, workers=1, threads=1, progress=False)
    assert summary.rendered == 12 and calls == [2]
    assert folder_bytes(tmp_path / "ds") == reference


# Full-size frames (an ARIS 3000's 128 x 1288): where the encoder's streams once varied with the
# process's history (issue 37: 1-2 frames in 10 of a resumed or two-worker run).
FULL_SIZE = {
    "scene": {"sonar": {"preset": "aris3000-128", "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}},
              "render": {"bounces": [1, 2]}, "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.6},
              "objects": [{"name": "block", "primitive": "box", "size_m": [0.5, 0.4, 0.35],
                           "pose": {"position_m": [0, 0, 0.175]}}]},
    "seed": 99,
    "trajectory": {"generate": {"kind": "random", "frames": 8, "bounds_m": [[-3.5, -3.5, 0.8], [-1.5, 3.5, 1.5]],
                                "look_at_bounds_m": [[-0.2, -0.15, 0.1], [0.2, 0.15, 0.3]], "jitter_deg": [3, 5]}},
    "variation": {"objects": [{"name": "debris", "count": {"choice": [0, 1, 2]},
                               "pool": [{"primitive": "sphere", "radius_m": 0.1}],
                               "pose": {"position_m": [{"uniform": [-1, 1]}, {"uniform": [-1, 1]}, 0.1]}}]},
}


def _digests(folder: Path) -> dict[str, str]:
    return {name: hashlib.sha256(content).hexdigest() for name, content in folder_bytes(folder).items()}


def test_full_size_frames_have_the_same_sha256_in_repeat_two_worker_and_resumed_runs(tmp_path):
    generate(FULL_SIZE, tmp_path / "a", progress=False)
    first = _digests(tmp_path / "a")
    assert len([n for n in first if n.endswith(".npz")]) == 8
    generate(FULL_SIZE, tmp_path / "b", progress=False)
    generate(FULL_SIZE, tmp_path / "c", workers=2, batch_size=1, progress=False)
    # A resume: frames 1, 4 and 6 lost (and the manifest torn after frame 5's line) are made
    # again by a process that has rendered nothing else.
    shutil.copytree(tmp_path / "a", tmp_path / "d")
    for k in (1, 4, 6):
        (tmp_path / "d" / f"frames/{k:06d}.npz").unlink()
    manifest = tmp_path / "d/manifest.jsonl"
    manifest.write_text("".join(manifest.read_text().splitlines(keepends=True)[:6]))
    summary = generate(FULL_SIZE, tmp_path / "d", progress=False)
    assert (summary.rendered, summary.reused) == (4, 4)
    for run in "bcd":
        assert _digests(tmp_path / run) == first, run


# Resuming ----------------------------------------------------------------------------------

def test_rerun_keeps_verified_frames_and_redoes_damaged_ones(tmp_path, reference):
    out = tmp_path / "ds"
    for name, content in reference.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_bytes(content)
    # Damage: a flipped byte in frame 2's NPZ, frame 5's fan PNG deleted, frame 7's line edited
    # (still valid JSON, its check no longer matches), frame 9's line with a forged check, and
    # a torn last line (frame 11's, cut in the middle).
    npz = out / "frames/000002.npz"
    data = bytearray(npz.read_bytes())
    data[len(data) // 2] ^= 0x01
    npz.write_bytes(bytes(data))
    (out / "frames/000005_fan.png").unlink()
    lines = reference["manifest.jsonl"].decode().splitlines()
    r7 = json.loads(lines[7])
    r7["seed"] += 1
    lines[7] = json.dumps(r7)
    r9 = json.loads(lines[9])
    r9["pose"]["position_m"][0] += 1e-9
    lines[9] = json.dumps(seal_record(r9))  # sealed, but not this scenario's frame 9
    lines[11] = lines[11][: len(lines[11]) // 2]
    (out / "manifest.jsonl").write_text("\n".join(lines))
    summary = generate(VARIED, out, **FULL, progress=False)
    assert (summary.rendered, summary.reused) == (5, 7)
    assert folder_bytes(out) == reference


def test_killed_at_random_moments_and_resumed_equals_an_uninterrupted_run(tmp_path, reference):
    out = tmp_path / "ds"
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        from tests.dataset.test_scenario import VARIED
        from sonarsim.dataset import generate
        print("ready", flush=True)
        generate(VARIED, {str(out)!r}, formats=("npz", "png", "yolo"), shards=5, progress=False, log=lambda m: None)
    """)
    rng = np.random.default_rng(2026)
    partial = 0
    # Kills land at random moments: once during start-up and the check of the folder, then
    # each time a few milliseconds (random) after the manifest reached a target count, i.e.
    # anywhere in the next frame's rendering, writing or manifest line.
    for target in (0, 2, 5, 8, 11):
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE)
        assert proc.stdout.readline() == b"ready\n"  # imports done
        deadline = time.monotonic() + 30.0
        while len(read_manifest(out / "manifest.jsonl")) < target and proc.poll() is None:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        time.sleep(float(rng.uniform(0.0, 0.04)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        n_lines = len(read_manifest(out / "manifest.jsonl"))
        partial += 0 < n_lines < 12
    assert partial >= 3, "the kills did not land while frames were being made; the test proves nothing"
    summary = generate(VARIED, out, **FULL, progress=False)
    assert summary.rendered + summary.reused == 12
    assert folder_bytes(out) == reference
    assert not [p for p in out.rglob("*.tmp")]  # no temporary file left behind


def test_another_scenario_or_other_options_are_refused_and_more_frames_extend(tmp_path):
    out = tmp_path / "ds"
    generate(ORBIT, out, frames=4, progress=False)
    before = folder_bytes(out)
    for kwargs in ({"scenario": {**ORBIT, "seed": 6}}, {"formats": ("npz", "png")}, {"frames": 3},
                   {"coco": "polar"}):
        args = {"scenario": ORBIT, "frames": 4, **kwargs}
        with pytest.raises(SonarsimError, match="holds another dataset"):
            generate(args.pop("scenario"), out, progress=False, **args)
        assert folder_bytes(out) == before  # refused before anything was touched
    summary = generate(ORBIT, out, frames=6, progress=False)
    assert (summary.rendered, summary.reused) == (2, 4)
    fresh = tmp_path / "fresh"
    generate(ORBIT, fresh, frames=6, progress=False)
    assert folder_bytes(out) == folder_bytes(fresh)


def test_a_full_disk_stops_with_a_clear_message_and_no_half_written_frame(tmp_path, monkeypatch):
    import sonarsim.io.output as output

    out = tmp_path / "ds"
    real_replace = os.replace
    calls = {"n": 0}

    def full_disk(src, dst):
        if str(dst).endswith("000003.npz"):
            raise OSError(errno.ENOSPC, "No space left on device", src)
        calls["n"] += 1
        return real_replace(src, dst)

    monkeypatch.setattr(output.os, "replace", full_disk)
    with pytest.raises(SonarsimError, match=r"000003\.npz: cannot write: No space left on device.*resume"):
        generate(ORBIT, out, progress=False)
    monkeypatch.undo()
    assert not [p for p in out.rglob("*.tmp")]
    # Frames 0-2 whole (with labels, each its NPZ and the fan PNG coco.json names), no NPZ of 3;
    # a frame after it that a second writer thread had finished meanwhile may be there, whole
    # (atomic files), without a manifest line: a resume makes it again, the same bytes.
    pngs = ["_fan.png"] if labels_supported() else []
    names = {p.name for p in (out / "frames").iterdir()}
    assert {f"{k:06d}{end}" for k in range(3) for end in [".npz", *pngs]} <= names
    assert "000003.npz" not in names and all(int(n[:6]) < 3 or int(n[:6]) > 3 for n in names)
    assert [r["frame"] for r in read_manifest(out / "manifest.jsonl")] == [0, 1, 2]
    summary = generate(ORBIT, out, progress=False)
    assert (summary.rendered, summary.reused) == (7, 3)
    generate(ORBIT, tmp_path / "fresh", progress=False)
    assert folder_bytes(out) == folder_bytes(tmp_path / "fresh")


def test_bad_options_name_their_key(tmp_path):
    for kwargs, key in (({"workers": 0}, "workers"), ({"formats": ("npz", "tiff")}, "formats"),
                        ({"rosbag": "bag"}, "rosbag"), ({"frames": 0}, "frames"), ({"labels": "some"}, "labels"),
                        ({"coco": "cartesian"}, "coco")):
        with pytest.raises(ConfigError) as info:
            generate(ORBIT, tmp_path / "ds", progress=False, **kwargs)
        assert info.value.key == key
    assert not (tmp_path / "ds").exists()


def test_an_output_path_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "ds").write_text("not a folder")
    with pytest.raises(SonarsimError, match="is a file"):
        generate(ORBIT, tmp_path / "ds", progress=False)


# Manifest pieces ---------------------------------------------------------------------------

def test_manifest_lines_verify_only_when_everything_matches(tmp_path):
    (tmp_path / "f.bin").write_bytes(b"abc")
    header = {"frame": 0, "spec_sha256": "s", "files": ["f.bin"]}
    record = seal_record({**header, "bytes": {"f.bin": 3}, "sha256": {"f.bin": hashlib.sha256(b"abc").hexdigest()}})
    assert verify_record(record, tmp_path, header)
    assert not verify_record(record, tmp_path, {**header, "spec_sha256": "t"})  # another frame spec
    assert not verify_record(record, tmp_path, {**header, "files": ["f.bin", "g.png"]})  # other options
    assert not verify_record(record, tmp_path, None)
    assert not verify_record({**record, "frame": 1}, tmp_path, {**header, "frame": 1})  # check broken
    (tmp_path / "f.bin").write_bytes(b"abd")
    assert not verify_record(record, tmp_path, header)
    path = tmp_path / "m.jsonl"
    with ManifestAppender(path) as m:
        m.append({"frame": 0})
        m.append({"frame": 1})
    with open(path, "ab") as handle:
        handle.write(b'{"frame": 2, "fi')  # a torn last line
    assert [r["frame"] for r in read_manifest(path)] == [0, 1]


def test_fingerprint_of_a_prefix():
    a, b = Fingerprint({"x": 1}), Fingerprint({"x": 1})
    for d in ("d0", "d1", "d2"):
        a.add(d)
    b.add("d0")
    assert a.at(1) == b.value and a.at(3) == a.value and a.at(4) is None
    assert Fingerprint({"x": 2}).at(0) != a.at(0)


def test_coco_boxes_from_records():
    records = [
        {"frame": 0, "files": ["frames/000000.npz", "frames/000000_polar.png", "frames/000000_fan.png"],
         "fan_shape": [50, 80], "polar_shape": [30, 16], "time_s": 0.0,
         "boxes": [{"id": 0, "name": "block", "polar": [1, 2, 3, 4], "fan": [10, 20, 14, 29]},
                   {"id": 1, "name": "rock_0", "polar": [1, 1, 1, 1], "fan": [-1, -1, -1, -1]}]},
        {"frame": 1, "files": ["frames/000001.npz", "frames/000001_fan.png"], "fan_shape": [50, 80],
         "polar_shape": [30, 16], "time_s": 0.5,
         "boxes": [{"id": 2, "name": "rock_12", "polar": [0, 0, 0, 0], "fan": [0, 0, 0, 0]}]},
    ]
    doc = coco_from_records(records)
    assert [i["file_name"] for i in doc["images"]] == ["frames/000000_fan.png", "frames/000001_fan.png"]
    assert doc["images"][0]["width"] == 80 and doc["images"][0]["height"] == 50
    assert [a["bbox"] for a in doc["annotations"]] == [[20, 10, 10, 5], [0, 0, 1, 1]]
    assert [a["area"] for a in doc["annotations"]] == [50, 1]
    assert doc["categories"] == [{"id": 1, "name": "block", "supercategory": "object"},
                                 {"id": 2, "name": "rock", "supercategory": "object"}]
    assert [category_of(n) for n in ("rock_3", "rock", "pipe_a", "_7")] == ["rock", "rock", "pipe_a", "_7"]
    # Polar pixels: a column per beam, row 0 the farthest of the 30 bins (bins 1-3 are rows 26-28).
    polar = coco_from_records(records[:1], image="polar")
    assert polar["images"][0]["file_name"] == "frames/000000_polar.png"
    assert (polar["images"][0]["height"], polar["images"][0]["width"]) == (30, 16)
    assert [a["bbox"] for a in polar["annotations"]] == [[2, 26, 3, 3], [1, 28, 1, 1]]
    # A frame without the PNG asked for: no file_name that does not exist.
    with pytest.raises(SonarsimError, match="frame 1: the manifest names no polar PNG"):
        coco_from_records(records, image="polar")


# Two objects either side of the fan's centre line, one near and one far (away from the middle
# of the range window, so that rows counted from the wrong end would miss), seen from a few
# nearby poses: their boxes must land on their own echoes, in the image coco.json names.
HALF_SIZE_M = 0.15
TWO_OBJECTS = {
    "scene": {**SCENE, "objects": [
        {"name": "block", "primitive": "box", "size_m": [2 * HALF_SIZE_M] * 3,
         "pose": {"position_m": [2.0, 0.35, HALF_SIZE_M]}},
        {"name": "ball", "primitive": "sphere", "radius_m": HALF_SIZE_M,
         "pose": {"position_m": [3.6, -0.4, HALF_SIZE_M]}}]},
    "seed": 3,
    "trajectory": {"generate": {"kind": "random", "frames": 3, "bounds_m": [[-0.2, -0.2, 0.9], [0.2, 0.2, 1.1]],
                                "look_at_m": [2.7, 0.0, 0.1], "jitter_deg": [1, 1]}},
}


@pytest.mark.parametrize("coco", ["fan", "polar"])
def test_coco_names_images_that_exist_and_its_boxes_land_on_the_objects(tmp_path, coco):
    from PIL import Image

    if not labels_supported():
        pytest.skip("this renderer has no labels yet (render(..., labels=True))")
    out = tmp_path / "ds"
    summary = generate(TWO_OBJECTS, out, progress=False, coco=coco)  # no --png: the PNG is written anyway
    doc = json.loads(summary.coco.read_text())
    rendered = {f.index: f for f in frames(TWO_OBJECTS)}
    assert [i["id"] for i in doc["images"]] == sorted(rendered)
    for entry in doc["images"]:
        k = entry["id"]
        path = out / entry["file_name"]
        assert path.is_file() and entry["file_name"] == f"frames/{k:06d}_{coco}.png"
        with Image.open(path) as im:
            assert im.size == (entry["width"], entry["height"])
            pixels = np.asarray(im)
        image, spec = rendered[k].image, rendered[k].spec
        # The objects' own echo (the renderer's object component, not the labels), on the
        # named image's pixels: the fan of SonarImage.fan(), or the polar image far range up.
        if coco == "fan":
            fan = image.fan(component="object")
            echo, x_m, y_m = fan.image, fan.x_m, fan.y_m
            pixel_m = fan.pixel_size_m
        else:
            echo = image.components["object"][::-1]
            pixel_m = float(image.range_m[1] - image.range_m[0])
        # The echo comes from the faces the sonar sees, up to half the object's size from its
        # centre: that many pixels of slack (a few; mirrored boxes would miss by tens).
        slack = int(np.ceil(HALF_SIZE_M / pixel_m))
        boxes = {a["object"]: a["bbox"] for a in doc["annotations"] if a["image_id"] == k}
        assert set(boxes) == {"block", "ball"}, boxes
        inside = np.zeros(echo.shape, bool)
        world_to_sonar = np.linalg.inv(spec.pose.matrix())
        # (The fan's linear interpolation spreads an echo one pixel past the cells whose
        # nearest pixels the boxes span.)
        grow = 1 if coco == "fan" else 0
        for obj in spec.scene["objects"]:
            x, y, w, h = boxes[obj["name"]]
            inside[max(0, y - grow):y + h + grow, max(0, x - grow):x + w + grow] = True
            # The object's centre, projected as a 2D sonar images it (range, azimuth), falls in
            # its own box.
            p = world_to_sonar @ np.array([*obj["pose"]["position_m"], 1.0])
            r, azimuth = float(np.linalg.norm(p[:3])), float(np.arctan2(p[1], p[0]))
            if coco == "fan":
                row = int(np.argmin(np.abs(x_m - r * np.cos(azimuth))))
                col = int(np.argmin(np.abs(y_m - r * np.sin(azimuth))))
            else:
                row = echo.shape[0] - 1 - int(np.argmin(np.abs(image.range_m - r)))
                col = int(np.argmin(np.abs(image.azimuth_deg - np.degrees(azimuth))))
            if coco == "polar":  # across beams the slack is the beams the half size spans
                slack_cols = int(np.ceil(np.degrees(HALF_SIZE_M / r) / abs(image.azimuth_deg[0] - image.azimuth_deg[1])))
            else:
                slack_cols = slack
            assert y - slack <= row < y + h + slack and x - slack_cols <= col < x + w + slack_cols, (
                k, obj["name"], (row, col), boxes[obj["name"]])
            # The PNG is bright there: the object's echo is drawn inside its box.
            assert pixels[y:y + h, x:x + w].max() >= 0.8 * pixels.max()
        # Nearly all the objects' echo energy lies inside their boxes.
        assert echo[inside].sum() >= 0.95 * echo.sum()
        assert boxes["block"][0] + boxes["block"][2] <= boxes["ball"][0]  # the block on the left


def test_coco_file_of_a_labelled_dataset(tmp_path):
    if not labels_supported():
        pytest.skip("this renderer has no labels yet (render(..., labels=True))")
    summary = generate(ORBIT, tmp_path / "ds", frames=3, progress=False)
    doc = json.loads(summary.coco.read_text())
    assert [i["id"] for i in doc["images"]] == [0, 1, 2]
    assert doc["categories"] == [{"id": 1, "name": "block", "supercategory": "object"}]
    assert len(doc["annotations"]) == 3  # the block is seen in every frame of the orbit


# The bag -----------------------------------------------------------------------------------

def test_bag_holds_every_frame_in_order_and_is_rewritten_on_resume(tmp_path):
    highlevel = pytest.importorskip("rosbags.highlevel")
    out = tmp_path / "ds"
    generate(ORBIT, out, frames=3, rosbag="mcap", progress=False)
    summary = generate(ORBIT, out, frames=5, rosbag="mcap", progress=False)
    assert summary.rosbag == out / "rosbag"
    scenario = load_scenario(ORBIT)
    stamps, polars = [], []
    with highlevel.AnyReader([summary.rosbag]) as reader:
        for conn, t, raw in reader.messages():
            if conn.topic == "/sonar/image":
                msg = reader.deserialize(raw, conn.msgtype)
                stamps.append(t)
                polars.append(np.frombuffer(bytes(msg.image.data), np.float32).reshape(-1, msg.image.beam_count))
            if conn.topic == "/sonar/fan":
                assert reader.deserialize(raw, conn.msgtype).encoding == "mono8"
    # From the default start (2000-01-01T00:00:00Z), as the frame times say.
    assert stamps == [DEFAULT_START_NS + round(scenario.frame(k).time_s * 1e9) for k in range(5)]
    for k, polar in enumerate(polars):
        arrays, _ = read_npz(out / f"frames/{k:06d}.npz")
        np.testing.assert_array_equal(polar, arrays["polar"])
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


# Bag time: a start the user sets (or a fixed default), every stamp and the metadata from it.


def read_mcap(bag: Path) -> dict:
    """Everything about time in an MCAP bag, read with the mcap library and its ROS 2 decoder
    (independent of rosbags, which wrote it): per topic the log and publish times and the
    decoded messages, the summary's statistics, and metadata.yaml."""
    import yaml

    mcap_reader = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    (path,) = bag.glob("*.mcap")
    topics: dict[str, list] = {}
    with open(path, "rb") as handle:
        reader = mcap_reader.make_reader(handle, decoder_factories=[decoder.DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages():
            topics.setdefault(channel.topic, []).append((message.log_time, message.publish_time, msg))
        statistics = reader.get_summary().statistics
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {"topics": topics, "statistics": statistics, "metadata": meta}


def stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def assert_stamped(bag: Path, expected: list[int]) -> None:
    """Every message of frame k, its header and TF stamps, bag times, metadata.yaml and the MCAP
    summary, at ``expected[k]``."""
    seen = read_mcap(bag)
    topics = seen["topics"]
    assert set(topics) == {"/sonar/image", "/sonar/fan", "/sonar/pose", "/tf", "/sonar/image/unit"}
    # the image's unit once, with the first frame (no sensor: sigma / r^2 per bin)
    assert [(log, msg.data) for log, _, msg in topics.pop("/sonar/image/unit")] == [(expected[0], "backscatter")]
    for topic, messages in topics.items():
        assert [log for log, _, _ in messages] == expected, topic
        assert [pub for _, pub, _ in messages] == expected, topic
        for (log, _, msg) in messages:
            if topic == "/tf":
                assert [stamp_ns(t.header.stamp) for t in msg.transforms] == [log, log]
            else:
                assert stamp_ns(msg.header.stamp) == log, topic
    stats = seen["statistics"]
    assert (stats.message_start_time, stats.message_end_time) == (expected[0], expected[-1])
    meta = seen["metadata"]
    assert meta["starting_time"]["nanoseconds_since_epoch"] == expected[0]
    assert meta["duration"]["nanoseconds"] == expected[-1] - expected[0]
    assert meta["files"][0]["starting_time"]["nanoseconds_since_epoch"] == expected[0]
    assert meta["files"][0]["duration"]["nanoseconds"] == expected[-1] - expected[0]


def test_bag_stamps_start_at_the_scenario_start_time_and_repeat_byte_for_byte(tmp_path):
    pytest.importorskip("rosbags")
    # Frame times 0, 0.25, 0.5 s (rate 4 Hz); frame 0 at 2024-05-01T12:00:00.5Z.
    scenario = {**ORBIT, "start_time": "2024-05-01T12:00:00.5Z"}
    start = 1_714_564_800_500_000_000
    runs = []
    for name in ("a", "b"):
        summary = generate(scenario, tmp_path / name, frames=3, rosbag="mcap", labels="none", progress=False)
        assert summary.rosbag_start_ns == start
        runs.append(summary.rosbag)
    assert_stamped(runs[0], [start, start + 250_000_000, start + 500_000_000])
    files = sorted(p.name for p in runs[0].iterdir())
    assert files == ["metadata.yaml", "rosbag.mcap"]
    for name in files:  # the same scenario, the same bag: nothing comes from the clock
        assert (runs[0] / name).read_bytes() == (runs[1] / name).read_bytes(), name


def test_bag_start_defaults_to_2000_and_the_argument_overrides_the_scenario(tmp_path):
    from sonarsim.io.rosbag import DEFAULT_START_NS, DEFAULT_START_TIME

    pytest.importorskip("rosbags")
    assert DEFAULT_START_TIME == "2000-01-01T00:00:00Z" and DEFAULT_START_NS == 946_684_800 * 10**9
    summary = generate(ORBIT, tmp_path / "default", frames=2, rosbag="mcap", labels="none", progress=False)
    assert_stamped(summary.rosbag, [DEFAULT_START_NS, DEFAULT_START_NS + 250_000_000])
    scenario = {**ORBIT, "start_time": "2024-05-01T12:00:00Z"}
    summary = generate(scenario, tmp_path / "given", frames=2, rosbag="mcap", labels="none", progress=False,
                       start_time=1_600_000_000)
    assert_stamped(summary.rosbag, [1_600_000_000 * 10**9, 1_600_000_000 * 10**9 + 250_000_000])


def test_bag_stamps_follow_a_track_file_whose_times_are_absolute(tmp_path):
    """A CSV track logged in seconds since 1970: frame 0 goes to the start time, the others keep
    their steps (not the track's own epoch added to the start)."""
    pytest.importorskip("rosbags")
    t0 = 1_700_000_000.0
    lines = ["t,x,y,z,roll_deg,pitch_deg,yaw_deg"] + [f"{t0 + dt},0,{0.1 * i},1,0,20,0"
                                                      for i, dt in enumerate((0.0, 0.1, 0.3))]
    (tmp_path / "track.csv").write_text("\n".join(lines) + "\n")
    scenario = {"scene": SCENE, "seed": 1, "trajectory": {"file": "track.csv"}, "start_time": 1_000_000_000}
    summary = generate(load_scenario(scenario, base_dir=tmp_path), tmp_path / "ds", rosbag="mcap", labels="none",
                       progress=False)
    start = 10**18
    # Float seconds of 1.7e9 carry about 0.2 us: the steps to within that.
    log_times = [log for log, _, _ in read_mcap(summary.rosbag)["topics"]["/sonar/image"]]
    assert log_times[0] == start
    np.testing.assert_allclose(np.diff(log_times), [100_000_000, 200_000_000], atol=1000)


def test_a_start_time_whose_last_frame_is_past_2038_is_refused_before_rendering(tmp_path):
    pytest.importorskip("rosbags")
    scenario = {**ORBIT, "start_time": "2038-01-19T03:14:07Z"}  # 10 frames at 4 Hz: 2.25 s later
    with pytest.raises(ConfigError) as info:
        generate(scenario, tmp_path / "ds", rosbag="mcap", progress=False)
    assert info.value.key == "start_time" and "2038-01-19T03:14:07Z" in str(info.value)
    assert not (tmp_path / "ds").exists()
    # Without a bag the start time stamps nothing, and nothing is refused.
    generate(scenario, tmp_path / "nobag", frames=1, labels="none", progress=False)
    with pytest.raises(ConfigError, match="start_time"):
        generate(ORBIT, tmp_path / "bad", rosbag="mcap", progress=False, start_time="yesterday")


def test_torch_example_imports_without_torch_and_makes_samples():
    import importlib.util

    spec = importlib.util.spec_from_file_location("dataset_torch", REPO / "examples" / "dataset_torch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # torch is imported only by main()
    frame = next(frames(ORBIT, stop=1))
    image, target = module.to_sample(frame.arrays())
    assert image.shape == (1, *frame.image.polar.shape) and image.dtype == np.float32
    assert np.isfinite(image).all()
    assert ("instance" in target) == labels_supported()


def test_ray_gives_the_same_files_as_local_processes(tmp_path, reference):
    ray = pytest.importorskip("ray")
    try:
        summary = generate(VARIED, tmp_path / "ds", **FULL, ray="local", workers=2, batch_size=2,
                           progress=False)
    finally:
        ray.shutdown()
    assert summary.rendered == 12
    assert folder_bytes(tmp_path / "ds") == reference


def test_a_ray_run_killed_mid_way_resumes_to_the_same_files(tmp_path, reference):
    pytest.importorskip("ray")
    out = tmp_path / "ds"
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        from tests.dataset.test_scenario import VARIED
        from sonarsim.dataset import generate
        generate(VARIED, {str(out)!r}, formats=("npz", "png", "yolo"), shards=5, ray="local", workers=2,
                 batch_size=1, progress=False, log=lambda m: None)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + 120.0
    while len(read_manifest(out / "manifest.jsonl")) < 6 and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and the local Ray instance it started
    proc.wait()
    assert 0 < len(read_manifest(out / "manifest.jsonl")) < 12
    summary = generate(VARIED, out, **FULL, workers=2, progress=False)
    assert summary.reused >= 6
    assert folder_bytes(out) == reference


def test_fan_boxes_equal_the_boxes_of_the_resampled_instance_map():
    from sonarsim.dataset.coco import fan_boxes

    frame = next(frames(ORBIT, stop=1))
    image = frame.image
    rng = np.random.default_rng(3)
    # A random map: ids in blobs and single cells, many ids absent; checked against boxes of
    # the map resampled pixel by pixel (nearest), computed independently here.
    instance = np.full(image.polar.shape, -1, np.int32)
    for k in range(6):
        r, b = rng.integers(0, instance.shape[0] - 8), rng.integers(0, instance.shape[1] - 3)
        instance[r:r + rng.integers(1, 8), b:b + rng.integers(1, 3)] = k
    instance[rng.integers(0, instance.shape[0]), 0] = 7
    from sonarsim.image.fan import FanMapper

    nearest = FanMapper.from_grid(image.sonar.grid, None, "nearest")
    fan_ids = nearest(instance.astype(np.float32) + 1).image.astype(np.int64) - 1
    expected = np.full((9, 4), -1)
    for k in range(9):
        rows, cols = np.nonzero(fan_ids == k)
        if rows.size:
            expected[k] = [rows.min(), cols.min(), rows.max(), cols.max()]
    np.testing.assert_array_equal(fan_boxes(instance, image.sonar.grid, 9), expected)
    assert (expected[:8, 0] >= 0).sum() >= 6 and expected[8, 0] == -1
    if frame.labels is not None:
        np.testing.assert_array_equal(fan_boxes(frame.labels.instance["total"], image.sonar.grid,
                                                len(frame.labels.ids)), image.fan_labels().boxes)


def descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (children, grandchildren, ...)."""
    table = subprocess.run(["ps", "-e", "-o", "pid=,ppid="], capture_output=True, text=True).stdout.split()
    parent = dict(zip(map(int, table[0::2]), map(int, table[1::2])))
    out, frontier = [], {pid}
    while frontier:
        frontier = {p for p, q in parent.items() if q in frontier}
        out += sorted(frontier)
    return out


def test_killing_a_run_with_workers_leaves_no_process_and_resumes(tmp_path, reference):
    out = tmp_path / "ds"
    code = textwrap.dedent(f"""
        import sys
        sys.path.insert(0, {str(REPO)!r})
        from tests.dataset.test_scenario import VARIED
        from sonarsim.dataset import generate
        generate(VARIED, {str(out)!r}, formats=("npz", "png", "yolo"), shards=5, workers=2, batch_size=1, progress=False,
                 log=lambda m: None)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO)
    deadline = time.monotonic() + 60.0
    while len(read_manifest(out / "manifest.jsonl")) < 2 and proc.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    children = descendants(proc.pid)  # the workers, the fork server they come from, ...
    assert len(children) >= 2
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 0 < len(read_manifest(out / "manifest.jsonl")) < 12
    deadline = time.monotonic() + 10.0
    while any(Path(f"/proc/{pid}").exists() for pid in children):
        assert time.monotonic() < deadline, "worker processes outlived their killed parent"
        time.sleep(0.1)
    summary = generate(VARIED, out, **FULL, workers=2, progress=False)
    assert summary.reused >= 2
    assert folder_bytes(out) == reference


def test_label_modes(tmp_path):
    if not labels_supported():
        pytest.skip("this renderer has no labels yet (render(..., labels=True))")
    names = {}
    for mode in ("all", "total", "none"):
        generate(ORBIT, tmp_path / mode, frames=1, labels=mode, progress=False)
        arrays, _ = read_npz(tmp_path / mode / "frames/000000.npz")
        names[mode] = set(arrays)
        assert (tmp_path / mode / "coco.json").exists() == (mode != "none")
    assert {"instance", "elevation_deg", "points_world", "points_object", "instance_object"} <= names["all"]
    assert {"instance", "elevation_deg", "points_world", "points_object"} <= names["total"]
    assert "instance_object" not in names["total"] and "instance" not in names["none"]
    # The component images come with every per-component map (--labels all) only: the default
    # (total) is issue 12's contract, and none the device image alone.
    components = {"object", "ground", "single", "double", "triple", "total"}
    assert components <= names["all"] and not components & (names["total"] | names["none"])
    assert names["none"] == {"polar", "range_m", "azimuth_deg"}
    all_arrays, _ = read_npz(tmp_path / "all" / "frames/000000.npz")
    total_arrays, _ = read_npz(tmp_path / "total" / "frames/000000.npz")
    for name in ("polar", "instance", "elevation_deg", "points_world"):
        np.testing.assert_array_equal(all_arrays[name], total_arrays[name])


def test_path_signature_images_are_stored_only_on_request(tmp_path):
    arrays = {}
    for signatures in (False, True):
        generate(ORBIT, tmp_path / str(signatures), frames=1, signatures=signatures, progress=False)
        arrays[signatures], _ = read_npz(tmp_path / str(signatures) / "frames/000000.npz")
    (frame,) = list(frames(ORBIT, stop=1))
    table = frame.image.components.table
    assert {"object", "ground", "single", "double", "triple", "total"} <= set(table)
    signature_names = set(frame.image.components.signatures)
    assert signature_names and not signature_names & set(arrays[False])  # the ground's bounces, by name
    assert not set(table) & set(arrays[False])  # the default: the device image and its labels
    assert set(arrays[True]) == set(arrays[False]) | signature_names | set(table)
    for name in table:
        np.testing.assert_array_equal(arrays[True][name], frame.image.components[name])
    for name in signature_names:
        np.testing.assert_array_equal(arrays[True][name], frame.image.components[name])
    assert set(frame.arrays(signatures=True)) == set(arrays[True])
    info = json.loads((tmp_path / "True" / "dataset.json").read_text())
    assert info["options"]["signatures"] is True
    with pytest.raises(ConfigError, match="signatures"):
        generate(ORBIT, tmp_path / "bad", frames=1, signatures="yes", progress=False)


def test_fan_box_reduction_compiled_equals_its_numpy_twin():
    from sonarsim.dataset.coco import _id_extents
    from sonarsim.renderer import compiled

    if not compiled.AVAILABLE:
        pytest.skip("compiled kernels not built")
    rng = np.random.default_rng(8)
    n = 5000
    ids = rng.integers(-2, 9, n).astype(np.int32)  # -1 none, ids 0..6 and two beyond n_ids
    lo = rng.integers(0, 400, (n, 2))
    extents = np.concatenate([lo, lo + rng.integers(0, 5, (n, 2))], axis=1).astype(np.int32)
    extents[rng.random(n) < 0.2] = -1  # cells no fan pixel samples
    ids[:40] = 3  # an id whose first cells have no box
    extents[:40] = -1
    ours = compiled.id_extents(ids, extents, 7)
    np.testing.assert_array_equal(ours, _id_extents(ids, extents, 7))
    k = 3  # by hand
    mine = extents[(ids == k) & (extents[:, 0] >= 0)]
    np.testing.assert_array_equal(ours[k], [*mine[:, :2].min(axis=0), *mine[:, 2:].max(axis=0)])
    sparse = np.full(n, 5, np.int32)
    sparse[7] = 2
    assert (compiled.id_extents(sparse, extents, 7)[[0, 1, 3, 4, 6]] == -1).all()


def test_a_sensor_models_frames_are_drawn_and_bagged_in_the_devices_counts(tmp_path):
    # Issue 37: the PNGs and the bag's fan were dB-mapped on top of the device's compression,
    # and the bag held an 8-bit device's image as float32. Frame names and topics come from the
    # scenario's rosbag section, then from generate's arguments (the command line's options).
    highlevel = pytest.importorskip("rosbags.highlevel")
    from PIL import Image

    scenario = {**ORBIT, "scene": {**SCENE, "sensor": {"preset": "aris3000-64"}},
                "rosbag": {"frame_ids": {"world": "map"}, "topics": {"image": "/aris/image", "fan": "/x/fan"}}}
    out = tmp_path / "ds"
    generate(scenario, out, frames=2, formats=("npz", "png"), rosbag="mcap", progress=False,
             frame_ids={"sonar": "aris"}, topics={"fan": "/aris/fan"})
    counts = {k: read_npz(out / f"frames/{k:06d}.npz")[0]["polar"] for k in range(2)}
    for k, polar in counts.items():
        assert np.array_equal(polar, np.round(polar)) and polar.max() <= 255 and polar.max() > 0
        np.testing.assert_array_equal(np.asarray(Image.open(out / f"frames/{k:06d}_polar.png")),
                                      polar[::-1].astype(np.uint8))
    fans = [np.asarray(Image.open(out / f"frames/{k:06d}_fan.png")) for k in range(2)]
    seen: dict[str, list] = {}
    with highlevel.AnyReader([out / "rosbag"]) as reader:
        for conn, _, raw in reader.messages():
            seen.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert set(seen) == {"/aris/image", "/aris/fan", "/sonar/pose", "/tf", "/sonar/points", "/aris/image/unit"}
    for k, msg in enumerate(seen["/aris/image"]):
        assert msg.image.dtype == 0 and msg.header.frame_id == "sonar_image"  # DTYPE_UINT8
        data = np.frombuffer(bytes(msg.image.data), np.uint8).reshape(-1, msg.image.beam_count)
        np.testing.assert_array_equal(data, counts[k].astype(np.uint8))
    for k, msg in enumerate(seen["/aris/fan"]):
        assert msg.encoding == "mono8" and msg.header.frame_id == "aris"
        np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.width),
                                      fans[k])
    assert {m.header.frame_id for m in seen["/sonar/pose"]} == {"map"}
    with pytest.raises(ConfigError, match=r"rosbag\.topics\.imgae.*unknown name"):
        generate(scenario, tmp_path / "bad", frames=1, rosbag="mcap", progress=False, topics={"imgae": "/a"})
    with pytest.raises(ConfigError, match=r"rosbag\.frame_ids\.world.*ROS frame name"):
        load_scenario({**scenario, "rosbag": {"frame_ids": {"world": "9 lives"}}})
