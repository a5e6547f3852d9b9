"""The `sonarsim dataset` command: its files, resuming, one-line errors with exit status 2."""

from __future__ import annotations

import json

import pytest
import yaml

from sonarsim.cli.main import main
from sonarsim.dataset.manifest import read_manifest

from tests.dataset.test_scenario import VARIED


@pytest.fixture()
def scenario_file(tmp_path):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(VARIED))
    return path


def test_dataset_command_writes_resumes_and_records(tmp_path, scenario_file, capsys):
    out = tmp_path / "ds"
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "3", "--png"]) == 0
    err = capsys.readouterr().err
    assert "frame" in err and "3 frames (3 made, 0 kept)" in err  # the bar and the summary, on stderr
    assert [r["frame"] for r in read_manifest(out / "manifest.jsonl")] == [0, 1, 2]
    assert (out / "frames" / "000002_fan.png").is_file()
    record = json.loads((out / "sonarsim-run.json").read_text())
    assert record["status"] == "complete"
    assert record["command"][:2] == ["sonarsim", "dataset"]
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "5", "--png", "--no-progress"]) == 0
    assert "5 frames (2 made, 3 kept)" in capsys.readouterr().err


def test_seed_option_makes_another_dataset(tmp_path, scenario_file, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["dataset", str(scenario_file), "--out", str(a), "--frames", "2", "--no-progress"]) == 0
    assert main(["dataset", str(scenario_file), "--out", str(b), "--frames", "2", "--seed", "12",
                 "--no-progress"]) == 0
    seeds_a = [r["seed"] for r in read_manifest(a / "manifest.jsonl")]
    seeds_b = [r["seed"] for r in read_manifest(b / "manifest.jsonl")]
    assert seeds_a != seeds_b
    # The same folder with another seed: refused in one line, exit status 2.
    capsys.readouterr()
    assert main(["dataset", str(scenario_file), "--out", str(a), "--frames", "2", "--seed", "12"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sonarsim: error:") and "holds another dataset" in err and "\n" not in err


def test_bad_input_exits_2_with_one_line(tmp_path, scenario_file, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({**VARIED, "seed": -1}))
    assert main(["dataset", str(bad), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip()
    assert "seed" in err and "\n" not in err
    assert main(["dataset", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "x")]) == 2
    (tmp_path / "file").write_text("")
    capsys.readouterr()
    assert main(["dataset", str(scenario_file), "--out", str(tmp_path / "file")]) == 2
    assert "--out" in capsys.readouterr().err
    with pytest.raises(SystemExit) as info:
        main(["dataset", str(scenario_file), "--out", str(tmp_path / "x"), "--workers", "0"])
    assert info.value.code == 2


def test_rosbag_option_writes_the_bag(tmp_path, scenario_file):
    pytest.importorskip("rosbags")
    out = tmp_path / "ds"
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "2", "--rosbag", "sqlite3",
                 "--no-progress"]) == 0
    assert (out / "rosbag" / "metadata.yaml").is_file()
    assert list((out / "rosbag").glob("*.db3"))


def test_start_time_option_stamps_the_bag(tmp_path, scenario_file, capsys):
    pytest.importorskip("rosbags")
    out = tmp_path / "ds"
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "2", "--rosbag", "mcap",
                 "--labels", "none", "--no-progress", "--start-time", "2024-05-01T14:00:00+02:00"]) == 0
    assert f"{out / 'rosbag'}: stamped from 2024-05-01T12:00:00Z (--start-time)" in capsys.readouterr().err
    meta = yaml.safe_load((out / "rosbag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["starting_time"]["nanoseconds_since_epoch"] == 1_714_564_800 * 10**9
    # Without the option: the documented default, said on stderr too.
    assert main(["dataset", str(scenario_file), "--out", str(tmp_path / "d2"), "--frames", "1", "--rosbag", "mcap",
                 "--labels", "none", "--no-progress"]) == 0
    assert "stamped from 2000-01-01T00:00:00Z" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--rosbag", "mcap", "--start-time", "now"], "--start-time: must be an ISO 8601 time"),
    (["--rosbag", "mcap", "--start-time", "0"], "--start-time: must be an ISO 8601 time"),
    (["--rosbag", "mcap", "--start-time", "2038-01-19T03:14:00Z"], "--start-time: starting at 2038-01-19T03:14:00Z"),
    (["--start-time", "2024-05-01"], "--start-time: sets the ROS 2 bag's stamps: give --rosbag mcap or sqlite3 too"),
])
def test_bad_start_times_exit_2_in_one_line_before_anything_is_written(tmp_path, scenario_file, capsys, argv, message):
    out = tmp_path / "ds"
    # 12 frames at the random trajectory's 1 Hz: the last 11 s after a start 68 s before 2038's end.
    assert main(["dataset", str(scenario_file), "--out", str(out), "--no-progress", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sonarsim: error: " + message) and "\n" not in err and "Traceback" not in err
    assert not out.exists()


def test_ray_option(tmp_path, scenario_file, capsys):
    ray = pytest.importorskip("ray")
    out = tmp_path / "ds"
    try:
        assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "3", "--ray", "local",
                     "--workers", "2", "--no-progress"]) == 0
    finally:
        ray.shutdown()
    assert [r["frame"] for r in read_manifest(out / "manifest.jsonl")] == [0, 1, 2]


def test_ray_missing_is_one_line(tmp_path, scenario_file, capsys, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    assert main(["dataset", str(scenario_file), "--out", str(tmp_path / "ds"), "--ray", "auto"]) == 2
    err = capsys.readouterr().err.strip()
    from sonarsim.core.extras import install_command

    assert install_command("ray") in err and "\n" not in err
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("coco", [None, "polar"])
def test_coco_json_names_pngs_that_exist_without_png(tmp_path, scenario_file, capsys, coco):
    # Issue 21: coco.json named frames/NNNNNN.npz while its boxes were in fan pixels, and no fan
    # image existed without --png. Now it names the PNG its boxes are on, written for it.
    from PIL import Image

    from sonarsim.dataset.frames import labels_supported

    if not labels_supported():
        pytest.skip("this renderer has no labels yet (render(..., labels=True))")
    out = tmp_path / "ds"
    option = [] if coco is None else ["--coco", coco]
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "2", "--no-progress", *option]) == 0
    doc = json.loads((out / "coco.json").read_text())
    kind = coco or "fan"
    assert [i["file_name"] for i in doc["images"]] == [f"frames/{k:06d}_{kind}.png" for k in range(2)]
    for entry in doc["images"]:
        with Image.open(out / entry["file_name"]) as im:
            assert im.size == (entry["width"], entry["height"])
    for a in doc["annotations"]:  # every box within its image
        image = doc["images"][a["image_id"]]
        x, y, w, h = a["bbox"]
        assert 0 <= x and 0 <= y and x + w <= image["width"] and y + h <= image["height"] and w > 0 and h > 0
    other = "polar" if kind == "fan" else "fan"
    assert not list((out / "frames").glob(f"*_{other}.png"))  # only the image coco.json names
    assert json.loads((out / "dataset.json").read_text())["options"]["coco"] == kind


def test_help_documents_the_coco_option(capsys):
    with pytest.raises(SystemExit):
        main(["dataset", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--coco {fan,polar}" in text and "frames/NNNNNN_polar.png" in text and "even without --png" in text


def test_workers_are_capped_by_the_cores_and_the_memory_budget_saying_so(tmp_path, scenario_file, capsys,
                                                                         monkeypatch):
    # --workers 1000 once started a process per frame and passed 6 GB.
    import concurrent.futures as cf

    import sonarsim.dataset.workers as workers

    started = []

    class Recording(cf.ProcessPoolExecutor):
        def __init__(self, max_workers=None, **kwargs):
            started.append(max_workers)
            super().__init__(max_workers, **kwargs)

    monkeypatch.setattr(workers.cf, "ProcessPoolExecutor", Recording)
    monkeypatch.setattr(workers, "available_cores", lambda: 2)
    out = tmp_path / "ds"
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "4", "--workers", "1000",
                 "--no-progress"]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "--workers" in line]
    assert len(lines) == 1 and "--workers 1000: starting 2 (2 CPU cores here" in lines[0], lines
    assert started == [2]
    assert len(read_manifest(out / "manifest.jsonl")) == 4
    # A budget that holds one worker's frames only: one process (this one), said so.
    started.clear()
    budget = int(workers.worker_bytes(1e6) * 1.5)
    assert main(["--max-memory", str(budget), "dataset", str(scenario_file), "--out", str(tmp_path / "one"),
                 "--frames", "2", "--workers", "2", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "--workers 2: starting 1 (the memory budget of" in err and "holds 1 of about" in err
    assert started == []


def test_cap_workers_by_hand():
    from sonarsim.dataset.workers import WORKER_BASE_BYTES, cap_workers, worker_bytes

    frame = 10 * 2**20
    each = WORKER_BASE_BYTES + 5 * frame  # a frame rendering, its copies, and one at the writer thread
    assert worker_bytes(frame) == each
    assert cap_workers(3, frame, cores=4, budget=10 * each) == (3, None)
    n, note = cap_workers(1000, frame, cores=16, budget=int(5.5 * each))
    assert n == 5 and note.startswith("--workers 1000: starting 5 (16 CPU cores here; the memory budget")
    assert cap_workers(8, frame, cores=16, budget=each // 2)[0] == 1  # never below one


def test_frame_ids_and_topics_options_name_the_bags_frames_and_topics(tmp_path, scenario_file, capsys):
    highlevel = pytest.importorskip("rosbags.highlevel")
    out = tmp_path / "ds"
    assert main(["dataset", str(scenario_file), "--out", str(out), "--frames", "1", "--rosbag", "mcap",
                 "--frame-ids", "world=map,image=sonar_optical", "--topics", "image=/oculus/image,pose=/oculus/pose",
                 "--no-progress"]) == 0
    with highlevel.AnyReader([out / "rosbag"]) as reader:
        topics = {c.topic for c in reader.connections}
        ids = {c.topic: reader.deserialize(raw, c.msgtype).header.frame_id
               for c, _, raw in reader.messages() if c.topic in ("/oculus/image", "/oculus/pose")}
    assert {"/oculus/image", "/oculus/pose", "/tf"} <= topics and "/sonar/image" not in topics
    assert ids == {"/oculus/image": "sonar_optical", "/oculus/pose": "map"}
    capsys.readouterr()
    for options, needle in ((["--frame-ids", "world=map"], "--frame-ids: names the ROS 2 bag"),
                            (["--rosbag", "mcap", "--topics", "imgae=/a"], "--topics: imgae: unknown name"),
                            (["--rosbag", "mcap", "--topics", "image=/a b"], "--topics: image: must be a ROS topic")):
        assert main(["dataset", str(scenario_file), "--out", str(tmp_path / "x"), *options]) == 2
        err = capsys.readouterr().err.strip()
        assert needle in err and "\n" not in err, err
    assert not (tmp_path / "x").exists()  # refused before anything was touched
    with pytest.raises(SystemExit) as info:
        main(["dataset", str(scenario_file), "--out", str(tmp_path / "x"), "--rosbag", "mcap", "--topics", "image"])
    assert info.value.code == 2


def test_install_hints_work_from_a_checkout_and_from_a_package(tmp_path, monkeypatch):
    # Issue 37: from a clone, pip install 'sonarsim[ros]' fetched another package from the index.
    import shlex

    import sonarsim.core.extras as extras
    from sonarsim.dataset.workers import RAY_HINT

    root = extras.checkout_root()
    assert root is not None and (root / "pyproject.toml").is_file()  # the tests run from a clone
    monkeypatch.chdir(root)
    assert extras.install_command("ros") == "pip install -e '.[ros]'"
    monkeypatch.chdir(tmp_path)
    command = extras.install_command("ros")
    assert command == f"pip install -e {shlex.quote(str(root) + '[ros]')}"
    assert shlex.split(command)[-1] == f"{root}[ros]"  # one argument: the clone with the extra
    assert RAY_HINT.startswith("install the Ray extra: pip install -e ")
    monkeypatch.setattr(extras, "checkout_root", lambda: None)  # an installed package
    assert extras.install_hint("viewer") == "install the viewer extra: pip install 'sonarsim[viewer]'"
    with pytest.raises(ValueError, match="extra must be one of ros, ray, viewer, diff"):
        extras.install_command("gpu")


def test_the_missing_rosbags_hint_names_this_checkout(tmp_path, scenario_file, capsys, monkeypatch):
    import sys

    from sonarsim.core.extras import install_command
    from sonarsim.io import rosbag

    monkeypatch.setitem(sys.modules, "rosbags", None)  # import rosbags -> ImportError
    monkeypatch.setitem(sys.modules, "rosbags.rosbag2", None)
    rosbag._import_rosbags.cache_clear()
    try:
        assert main(["dataset", str(scenario_file), "--out", str(tmp_path / "ds"), "--rosbag", "mcap"]) == 2
    finally:
        rosbag._import_rosbags.cache_clear()
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"install the ROS extra: {install_command('ros')}") and "\n" not in err, err
    assert "pip install -e" in err


def test_a_lone_worker_gets_a_second_writer_only_where_a_core_and_the_budget_allow():
    from sonarsim.dataset.workers import lone_writers, worker_bytes

    frame = 10 * 2**20
    room = int(worker_bytes(frame) + frame)
    assert lone_writers(1, frame, cores=2, budget=room) == 2
    assert lone_writers(1, frame, cores=2, budget=room - 1) == 1  # the second frame would not fit
    assert lone_writers(1, frame, cores=1, budget=10 * room) == 1  # no idle core
    assert lone_writers(2, frame, cores=2, budget=10 * room) == 1  # the render takes both cores


def test_a_lone_worker_renders_on_a_third_of_the_cores_when_encoding_is_the_larger_part():
    from sonarsim.dataset.encoding import DatasetOptions
    from sonarsim.dataset.workers import lone_threads, lone_writers, worker_bytes

    labelled, bare = DatasetOptions(), DatasetOptions(labels="none")
    assert [lone_threads(labelled, cores=c) for c in (1, 2, 3, 8, 16)] == [1, 1, 1, 3, 5]
    assert [lone_threads(bare, cores=c) for c in (1, 2, 8)] == [1, 2, 8]
    assert lone_threads(DatasetOptions(labels="none", formats=("npz", "png")), cores=6) == 2  # PNGs to encode
    frame = 10 * 2**20
    plenty = int(10 * worker_bytes(frame) + 20 * frame)
    assert lone_writers(3, frame, cores=8, budget=plenty) == 6  # the 5 cores left, and one
    # As many writers as frames waiting fit: the worker and its first frame, then one a writer.
    assert lone_writers(3, frame, cores=8, budget=int(worker_bytes(frame) + 2 * frame)) == 3
