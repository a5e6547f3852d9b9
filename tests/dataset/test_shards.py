"""WebDataset shards: read back by the webdataset library, the same bytes after a resume or a
change of shard size, refused sizes."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from sonarsim.config.examples import tank_scene_dict
from sonarsim.dataset import generate
from sonarsim.dataset.shards import SHARD_INDEX, member_name, shard_urls
from sonarsim.errors import ConfigError, SonarsimError


def test_member_names_follow_webdatasets_key_and_kind():
    assert member_name("frames/000123.npz") == "000123.npz"
    assert member_name("frames/000123_fan.png") == "000123.fan.png"
    assert member_name("frames/0000123_polar.txt") == "0000123.polar.txt"


@pytest.mark.parametrize("bad", [0, -3, 2.5, True, "8", 10**6])
def test_bad_shard_sizes_are_refused_by_name(tmp_path, bad):
    with pytest.raises(ConfigError, match="shards"):
        generate({"scene": tank_scene_dict(), "trajectory": {"file": "x.csv"}}, tmp_path / "ds", shards=bad,
                 progress=False)
    assert not (tmp_path / "ds").exists()  # refused before the folder is touched


@pytest.fixture(scope="module")
def sharded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("shards")
    track = folder / "track.csv"
    rows = [f"{0.5 * k},{0.05 * k},0.0,1.4,0.0,2.0,{3.0 * k - 6.0}" for k in range(5)]
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n" + "\n".join(rows) + "\n")
    scenario = {"scene": tank_scene_dict(), "seed": 2, "trajectory": {"file": str(track), "rate_hz": 2.0}}
    out = folder / "ds"
    summary = generate(scenario, out, progress=False, formats=("npz", "yolo"), shards=2)
    return scenario, out, summary


def _records(out):
    return [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]


def test_the_webdataset_library_reads_one_sample_per_frame(sharded):
    wds = pytest.importorskip("webdataset")
    _, out, summary = sharded
    assert summary.shards == ("shards/000000.tar", "shards/000001.tar", "shards/000002.tar")
    urls = shard_urls(out)
    assert urls == [str(out / s) for s in summary.shards]
    records = {r["frame"]: r for r in _records(out)}
    samples = list(wds.WebDataset(urls, shardshuffle=False))
    assert [s["__key__"] for s in samples] == [f"{k:06d}" for k in range(5)]
    for sample in samples:
        k = int(sample["__key__"])
        record = records[k]
        for name in record["files"]:
            assert sample[member_name(name).split(".", 1)[1]] == (out / name).read_bytes(), name
        meta = json.loads(sample["json"])
        assert meta == {key: v for key, v in record.items() if key != "check"}
        assert set(sample) - {"__key__", "__url__", "__local_path__"} == {"npz", "fan.png", "fan.txt", "json"}
    lines = [json.loads(t) for t in (out / SHARD_INDEX).read_text().splitlines()]
    assert [line["frames"] for line in lines] == [[0, 1], [2, 3], [4, 4]]


def test_a_resumed_run_rewrites_what_is_missing_with_the_same_bytes(sharded):
    scenario, out, _ = sharded
    before = {p.name: p.read_bytes() for p in (out / "shards").iterdir()}
    index = (out / SHARD_INDEX).read_text()
    (out / "shards/000001.tar").unlink()
    (out / "shards/000002.tar").write_bytes(b"damaged")
    (out / SHARD_INDEX).write_text(index[:-20])  # a torn last line
    (out / "frames/000000.npz").unlink()  # and a frame to make again
    summary = generate(scenario, out, progress=False, formats=("npz", "yolo"), shards=2)
    assert (summary.rendered, summary.reused) == (1, 4)
    assert {p.name: p.read_bytes() for p in (out / "shards").iterdir()} == before
    assert (out / SHARD_INDEX).read_text() == index


def test_another_shard_size_repacks_the_same_frames(sharded, tmp_path):
    scenario, out, _ = sharded
    frames_before = {p.name: p.read_bytes() for p in (out / "frames").iterdir()}
    summary = generate(scenario, out, progress=False, formats=("npz", "yolo"), shards=4)
    assert summary.rendered == 0 and summary.shards == ("shards/000000.tar", "shards/000001.tar")
    assert sorted(p.name for p in (out / "shards").iterdir()) == ["000000.tar", "000001.tar"]
    assert {p.name: p.read_bytes() for p in (out / "frames").iterdir()} == frames_before
    wds = pytest.importorskip("webdataset")
    assert [s["__key__"] for s in wds.WebDataset(shard_urls(out), shardshuffle=False)] == [f"{k:06d}" for k in range(5)]
    generate(scenario, out, progress=False, formats=("npz", "yolo"), shards=2)  # (back, for the other tests)


def test_a_folder_without_shards_says_so(tmp_path):
    with pytest.raises(SonarsimError, match="shards.jsonl.*--shards"):
        shard_urls(tmp_path)


def test_the_cli_takes_shards(tmp_path):
    track = tmp_path / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.4,0.0,2.0,0.0\n")
    (tmp_path / "s.yaml").write_text(json.dumps({"scene": tank_scene_dict(), "trajectory": {"file": str(track)}}))
    bad = subprocess.run([sys.executable, "-m", "sonarsim", "dataset", str(tmp_path / "s.yaml"), "--out",
                          str(tmp_path / "ds"), "--shards", "0", "--no-progress"], capture_output=True, text=True)
    assert bad.returncode == 2 and "shards" in bad.stderr and "Traceback" not in bad.stderr


def test_a_run_without_shards_removes_an_earlier_runs(tmp_path):
    track = tmp_path / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.4,0.0,2.0,0.0\n")
    scenario = {"scene": tank_scene_dict(), "seed": 3, "trajectory": {"file": str(track)}}
    out = tmp_path / "ds"
    generate(scenario, out, progress=False, shards=4)
    assert (out / SHARD_INDEX).exists() and (out / "shards/000000.tar").exists()
    said = []
    generate(scenario, out, progress=False, log=said.append)
    assert not (out / SHARD_INDEX).exists() and not (out / "shards").exists()
    assert any("removed the shards" in line for line in said)


def test_a_shard_list_that_is_not_one_is_said(tmp_path):
    (tmp_path / SHARD_INDEX).write_text('[1, 2]\n')
    with pytest.raises(SonarsimError, match="not a list of shards"):
        shard_urls(tmp_path)
