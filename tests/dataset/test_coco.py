"""coco.json: each object's direct echo (box and RLE mask), its multipath ghosts on request, and
the file read and evaluated by pycocotools (issue 37)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sonarsim.config.examples import tank_scene_dict
from sonarsim.dataset import frames, generate
from sonarsim.dataset.coco import DIRECT_PATH, coco_from_records, rle
from sonarsim.errors import SonarsimError
from sonarsim.io.output import read_npz

mask_utils = pytest.importorskip("pycocotools.mask")


def test_rle_by_hand_and_as_pycocotools_decodes_it():
    ids = np.array([[-1, 2, 2, -1],
                    [2, -1, 2, -1],
                    [-1, -1, 2, 7]])
    # Column-major, is 2: col 0 (0 1 0), col 1 (1 0 0), col 2 (1 1 1), col 3 (0 0 0): runs of
    # 0 1 0 1 00 111 000.
    segmentation, area = rle(ids, 2)
    assert segmentation == {"size": [3, 4], "counts": [1, 1, 1, 1, 2, 3, 3]} and area == 5
    assert rle(ids, 2, [0, 0, 2, 2]) == (segmentation, 5)  # scanning the box's columns only
    assert rle(ids, 7, [2, 3, 2, 3]) == ({"size": [3, 4], "counts": [11, 1]}, 1)
    first, _ = rle(np.array([[5, 5], [5, -1]]), 5)
    assert first["counts"] == [0, 3, 1]  # counts start with background, here none
    rng = np.random.default_rng(3)
    for _ in range(20):
        ids = rng.integers(-1, 3, (int(rng.integers(1, 9)), int(rng.integers(1, 9))))
        for k in range(3):
            if not (ids == k).any():
                continue
            cols = np.flatnonzero((ids == k).any(axis=0))
            segmentation, area = rle(ids, k, [0, cols[0], 0, cols[-1]])
            h, w = segmentation["size"]
            decoded = mask_utils.decode(mask_utils.frPyObjects(segmentation, h, w))
            np.testing.assert_array_equal(decoded, (ids == k).astype(np.uint8))
            assert area == int((ids == k).sum())


@pytest.fixture(scope="module")
def tank(tmp_path_factory):
    """One frame of the demo's walled tank (floor, water surface, three walls, buoy, post and
    block), with ghosts annotated."""
    folder = tmp_path_factory.mktemp("tank")
    track = folder / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.4,0.0,2.0,0.0\n")
    scenario = {"scene": tank_scene_dict(), "seed": 4, "trajectory": {"file": str(track)}}
    out = folder / "ds"
    generate(scenario, out, progress=False, ghosts=True)
    return scenario, out


def test_boxes_and_masks_are_the_direct_echoes_not_the_ghosts(tank):
    scenario, out = tank
    (frame,) = list(frames(scenario, labels="all"))
    labels, r = frame.image.labels, frame.image.range_m
    record = json.loads((out / "manifest.jsonl").read_text().splitlines()[0])
    box = {b["name"]: b for b in record["boxes"]}["buoy"]
    bin0, beam0, bin1, beam1 = box["polar"]
    # The 0.3 m buoy 3 m ahead: its direct echo 2.9-3.0 m and 25 beams (measured; the total's map
    # gave 2.9-7.6 m and 136 of 256 beams, its ghosts by the walls and the surface).
    assert r[bin1] - r[bin0] < 0.4 and 2.7 < r[bin0] < 3.1 and beam1 - beam0 + 1 <= 30
    total_bins = np.nonzero((labels.instance["total"] == 0).any(axis=1))[0]
    assert r[total_bins[-1]] - r[total_bins[0]] > 4.0  # what the box would have spanned
    # Exactly the cells where the buoy dominates the objects' single-bounce paths.
    cells = np.argwhere(labels.instance["object"] == 0)
    assert [bin0, beam0, bin1, beam1] == [*cells.min(axis=0), *cells.max(axis=0)]
    arrays, _ = read_npz(out / "frames/000000.npz")
    assert "instance_object" not in arrays  # the NPZ holds the total's map alone (--labels total)


def test_coco_json_reads_and_evaluates_with_pycocotools(tank):
    coco_mod = pytest.importorskip("pycocotools.coco")
    cocoeval = pytest.importorskip("pycocotools.cocoeval")
    scenario, out = tank
    gt = coco_mod.COCO(str(out / "coco.json"))
    (frame,) = list(frames(scenario, labels="all"))
    fan_ids = frame.image.fan_labels().instance  # nearest-neighbour resampling of the total's map
    assert fan_ids.shape == (gt.imgs[0]["height"], gt.imgs[0]["width"])
    direct = [a for a in gt.dataset["annotations"] if not a["ghost"]]
    ghosts = [a for a in gt.dataset["annotations"] if a["ghost"]]
    assert {a["object"] for a in direct} == {"buoy", "post", "block"}
    assert all(a["path"] == DIRECT_PATH for a in direct)
    names = {c["id"]: c for c in gt.dataset["categories"]}
    for a in gt.dataset["annotations"]:
        mask = gt.annToMask(a)
        assert mask.sum() == a["area"] > 0
        rows, cols = np.nonzero(mask)
        x, y, w, h = a["bbox"]
        assert (rows.min(), cols.min(), rows.max(), cols.max()) == (y, x, y + h - 1, x + w - 1)  # the mask's box
        if a["ghost"]:
            assert names[a["category_id"]]["name"] == f"{a['object']}/{a['path']}"
            assert names[a["category_id"]]["supercategory"] == a["object"]
    # Ghosts by path signature: the buoy seen by way of the water surface, and others.
    buoy_paths = {a["path"] for a in ghosts if a["object"] == "buoy"}
    assert buoy_paths and all("[objects]" in p and p != DIRECT_PATH for p in buoy_paths), buoy_paths
    assert any("surface" in p for p in buoy_paths), buoy_paths
    # A ghost lies farther than its object's direct echo (a longer path).
    direct_row = {a["object"]: a["bbox"][1] + a["bbox"][3] for a in direct}  # bottom row: the nearest range
    assert all(a["bbox"][1] < direct_row[a["object"]] for a in ghosts)
    # The ground truth evaluated against itself as detections: AP 1 for boxes and masks.
    results = [{"image_id": a["image_id"], "category_id": a["category_id"], "bbox": a["bbox"],
                "segmentation": a["segmentation"], "score": 1.0} for a in gt.dataset["annotations"]]
    for kind in ("bbox", "segm"):
        evaluator = cocoeval.COCOeval(gt, gt.loadRes(results), kind)
        evaluator.params.areaRng = [[0, 1e10]] * 4  # (all sizes)
        evaluator.evaluate()
        evaluator.accumulate()
        evaluator.summarize()
        assert evaluator.stats[0] == pytest.approx(1.0), kind


def test_without_the_option_no_ghost_is_annotated(tmp_path):
    track = tmp_path / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.4,0.0,2.0,0.0\n")
    summary = generate({"scene": tank_scene_dict(), "seed": 4, "trajectory": {"file": str(track)}}, tmp_path / "ds",
                       progress=False, coco="polar")
    doc = json.loads(summary.coco.read_text())
    assert doc["annotations"] and not any(a["ghost"] for a in doc["annotations"])
    assert {c["supercategory"] for c in doc["categories"]} == {"object"}
    record = json.loads((tmp_path / "ds/manifest.jsonl").read_text().splitlines()[0])
    assert "ghosts" not in record
    for a in doc["annotations"]:  # polar pixels: the mask's rows counted from the far range
        h, w = a["segmentation"]["size"]
        mask = mask_utils.decode(mask_utils.frPyObjects(a["segmentation"], h, w))
        assert mask.sum() == a["area"] and (h, w) == (750, 256)


def test_masks_from_each_objects_box_alone_are_the_whole_fans():
    """rle_window over FanMapper.window_ids of an object's box gives the counts rle gives over
    the whole fan's nearest-neighbour instance map (what encoding did before), for every id."""
    import sonarsim
    from sonarsim.config.examples import demo_scene_dict
    from sonarsim.dataset.coco import fan_boxes, rle, rle_window
    from sonarsim.image.result import _fan_mapper

    with sonarsim.Simulator(demo_scene_dict()) as sim:
        image = sim.render(frame=0, labels="total")
    ids = image.labels.instance["total"]
    mapper = _fan_mapper(image.sonar.grid, None, "nearest")
    whole = mapper.ids(ids)
    boxes = fan_boxes(ids, image.sonar.grid, len(image.labels.ids))
    seen = 0
    for k, box in enumerate(boxes):
        if box[0] < 0:
            continue
        window = mapper.window_ids(ids, box)
        assert np.array_equal(window, whole[box[0]:box[2] + 1, box[1]:box[3] + 1])
        assert rle_window(window, k, box, mapper.shape) == rle(whole, k, box)
        seen += 1
    assert seen >= 4  # the demo's objects and the floor


def test_written_a_frame_at_a_time_equals_the_documents_canonical_json(tank):
    import io

    from sonarsim.dataset.coco import write_coco
    from sonarsim.dataset.manifest import canonical_json

    _, out = tank
    records = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()] * 3
    records = [{**r, "frame": k} for k, r in enumerate(records)]  # (three frames' worth)
    for image in ("fan",):  # (the polar PNG's path is tested by the polar datasets' tests)
        for categories in ((), ("post", "nothing_seen")):
            text = io.StringIO()
            write_coco(text, lambda: iter(records), image=image, categories=categories)
            doc = coco_from_records(records, image=image, categories=categories)
            assert text.getvalue() == canonical_json(doc) + "\n"
            assert len(doc["annotations"]) > 3
    assert (out / "coco.json").read_text() == canonical_json(coco_from_records(
        [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()],
        categories=[c["name"] for c in json.loads((out / "coco.json").read_text())["categories"]
                    if c["supercategory"] == "object"])) + "\n"


def test_categories_are_read_without_the_annotations(tank, tmp_path):
    import io

    from sonarsim.dataset.coco import read_categories, write_coco

    _, out = tank
    assert read_categories(out / "coco.json") == json.loads((out / "coco.json").read_text())["categories"]
    record = json.loads((out / "manifest.jsonl").read_text().splitlines()[0])
    text = io.StringIO()
    write_coco(text, lambda: iter([{**record, "boxes": [], "ghosts": []}]), categories=("a", "b"))
    (tmp_path / "empty.json").write_text(text.getvalue())  # no annotation at all
    assert [c["name"] for c in read_categories(tmp_path / "empty.json")] == ["a", "b"]
    (tmp_path / "indented.json").write_text(json.dumps({"images": [], "categories": [{"id": 1, "name": "x"}]},
                                                       indent=2))
    assert read_categories(tmp_path / "indented.json") == [{"id": 1, "name": "x"}]
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(SonarsimError, match="bad.json: no readable categories"):
        read_categories(tmp_path / "bad.json")
