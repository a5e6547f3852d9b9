"""YOLO labels: outlines against their masks, a dataset read back by supervision's YOLO reader
against coco.json read by pycocotools, data.yaml, resuming."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from matplotlib.path import Path as MplPath
from scipy import ndimage

from sonarsim.config.examples import tank_scene_dict
from sonarsim.dataset import generate
from sonarsim.dataset.encoding import DatasetOptions
from sonarsim.dataset.yolo import label_text, outline, val_frames
from sonarsim.errors import ConfigError


def _centres_inside(ring: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Which pixel centres of an image of ``shape`` lie inside the polygon ``ring``."""
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    centres = np.column_stack([cols.ravel() + 0.5, rows.ravel() + 0.5])
    return MplPath(ring).contains_points(centres).reshape(shape)


def _on_boundary(ring: np.ndarray, point: tuple[float, float]) -> bool:
    a, b = ring, np.roll(ring, -1, axis=0)
    p = np.asarray(point)
    t = np.clip(((p - a) * (b - a)).sum(1) / np.maximum(((b - a) ** 2).sum(1), 1e-12), 0, 1)
    return bool((np.hypot(*(a + t[:, None] * (b - a) - p).T) < 1e-9).any())


def _near_cut(ring: np.ndarray, point: tuple[float, float], reach: float = 1.5) -> bool:
    """Whether ``point`` lies within ``reach`` pixels of a cut: an edge the ring runs both ways."""
    a, b = ring, np.roll(ring, -1, axis=0)
    edges = {(tuple(p), tuple(q)) for p, q in zip(a, b)}
    cut = np.array([(p, q) for p, q in edges if (q, p) in edges]).reshape(-1, 2, 2)
    if not len(cut):
        return False
    a, b, p = cut[:, 0], cut[:, 1], np.asarray(point)
    t = np.clip(((p - a) * (b - a)).sum(1) / np.maximum(((b - a) ** 2).sum(1), 1e-12), 0, 1)
    return bool((np.hypot(*(a + t[:, None] * (b - a) - p).T) <= reach).any())


def test_a_pixel_is_a_diamond_through_its_edge_midpoints():
    mask = np.zeros((4, 5), bool)
    mask[2, 3] = True
    ring = outline(mask, (10, 20))  # the window's top-left pixel is (row 10, col 20)
    assert sorted(map(tuple, ring)) == [(23.0, 12.5), (23.5, 12.0), (23.5, 13.0), (24.0, 12.5)]
    assert outline(np.zeros((3, 3), bool)).shape == (0, 2)


def test_outlines_hold_exactly_their_pixels_and_span_their_boxes():
    rng = np.random.default_rng(11)
    tried = 0
    for _ in range(300):
        h, w = (int(v) for v in rng.integers(2, 14, 2))
        mask = ndimage.binary_opening(rng.random((h, w)) < 0.6, iterations=int(rng.integers(0, 2)))
        labelled, n = ndimage.label(mask)  # one 4-connected piece without holes
        if n != 1 or not np.array_equal(ndimage.binary_fill_holes(mask), mask):
            continue
        if (ndimage.label(mask, np.ones((3, 3)))[1] != 1):
            continue
        tried += 1
        ring = outline(mask)
        assert np.all(ring * 2 == np.round(ring * 2))  # on the half-pixel grid
        np.testing.assert_array_equal(_centres_inside(ring, mask.shape), mask)
        rows, cols = np.nonzero(mask)
        assert (ring[:, 0].min(), ring[:, 1].min(), ring[:, 0].max(), ring[:, 1].max()) == (
            cols.min(), rows.min(), cols.max() + 1, rows.max() + 1)
    assert tried > 30


def test_pieces_are_joined_into_one_polygon_spanning_all():
    mask = np.zeros((9, 12), bool)
    mask[1:3, 1:4] = True  # the larger piece
    mask[6:8, 8:10] = True
    mask[7, 1] = True
    ring = outline(mask)
    rows, cols = np.nonzero(mask)
    assert (ring[:, 0].min(), ring[:, 1].min(), ring[:, 0].max(), ring[:, 1].max()) == (
        cols.min(), rows.min(), cols.max() + 1, rows.max() + 1)
    # Every pixel of every piece is inside; the cuts between them have no width: a background
    # pixel is inside only where a cut runs through its very centre (on the boundary).
    inside = _centres_inside(ring, mask.shape)
    assert inside[mask].all()
    for row, col in np.argwhere(inside & ~mask):
        assert _on_boundary(ring, (col + 0.5, row + 0.5)), (row, col)
    assert len(ring) < 40  # collinear vertices dropped


def test_label_lines_are_normalised_by_the_image():
    ring = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 2.0]])
    text = label_text([(3, ring), (1, np.zeros((0, 2)))], (2, 8)).decode()
    assert text == "3 0.000000 0.000000 0.500000 0.000000 0.500000 1.000000\n"
    assert label_text([], (2, 2)) == b""
    assert [val_frames(n) for n in (0, 1, 2, 10, 25)] == [0, 0, 1, 1, 2]


def test_yolo_needs_ground_truth():
    with pytest.raises(ConfigError, match="formats.*ground truth"):
        DatasetOptions(labels="none", formats=("npz", "yolo"))


@pytest.fixture(scope="module")
def yolo_set(tmp_path_factory):
    """Three frames of the demo's walled tank with YOLO labels."""
    folder = tmp_path_factory.mktemp("yolo")
    track = folder / "track.csv"
    track.write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.4,0.0,2.0,0.0\n"
                     "0.5,0.1,0.05,1.4,0.0,2.0,4.0\n1.0,0.2,-0.05,1.35,0.0,3.0,-3.0\n")
    scenario = {"scene": tank_scene_dict(), "seed": 4, "trajectory": {"file": str(track), "rate_hz": 2.0}}
    out = folder / "ds"
    generate(scenario, out, progress=False, formats=("npz", "yolo"))
    return scenario, out


def test_supervision_reads_the_labels_as_coco_json_has_them(yolo_set):
    sv = pytest.importorskip("supervision")
    coco_mod = pytest.importorskip("pycocotools.coco")
    _, out = yolo_set
    gt = coco_mod.COCO(str(out / "coco.json"))
    data = yaml.safe_load((out / "data.yaml").read_text())
    names = {c["id"] - 1: c["name"] for c in gt.dataset["categories"]}
    assert data["names"] == names and data["nc"] == len(names)  # one class table
    assert (data["train"], data["val"]) == ("yolo-train.txt", "yolo-val.txt") and "path" not in data
    train = (out / "yolo-train.txt").read_text().split()
    val = (out / "yolo-val.txt").read_text().split()
    assert train + val == [f"./{im['file_name']}" for im in gt.dataset["images"]] and len(val) == 1
    ds = sv.DetectionDataset.from_yolo(images_directory_path=str(out / "frames"),
                                       annotations_directory_path=str(out / "frames"),
                                       data_yaml_path=str(out / "data.yaml"), force_masks=True)
    assert ds.classes == [names[i] for i in range(len(names))]
    checked = 0
    for path, _, det in ds:
        file_name = "frames/" + path.replace("\\", "/").rsplit("/", 1)[-1]
        (image,) = [im for im in gt.dataset["images"] if im["file_name"] == file_name]
        anns = gt.loadAnns(gt.getAnnIds(imgIds=[image["id"]]))
        assert len(det) == len(anns) > 0
        for ann in anns:
            x, y, w, h = ann["bbox"]
            match = np.flatnonzero(np.all(np.abs(det.xyxy - [x, y, x + w, y + h]) < 1e-3 * max(image["width"], 1), axis=1))
            assert len(match) == 1, (ann["object"], det.xyxy)
            k = int(match[0])
            assert int(det.class_id[k]) == ann["category_id"] - 1
            truth = gt.annToMask(ann).astype(bool)
            drawn = det.mask[k]
            # The reader rounds the vertices to whole pixels (half-pixel ones either way) and
            # draws the edges too: nearly the mask's pixels, and at most a pixel's border more (a
            # small object's IoU 0.85; exact where pixel centres are sampled, the next test).
            assert drawn[truth].mean() > 0.9, ann["object"]
            near = ndimage.binary_dilation(ndimage.binary_fill_holes(truth), np.ones((3, 3)))
            # Beyond that border, only the lines the reader draws along the cuts between pieces
            # (the edges the polygon runs both ways).
            values = (out / file_name.replace(".png", ".txt")).read_text().splitlines()
            ring = np.array(values[anns.index(ann)].split()[1:], float).reshape(-1, 2) * [image["width"], image["height"]]
            for row, col in np.argwhere(drawn & ~near):
                assert _near_cut(ring, (col + 0.5, row + 0.5)), (ann["object"], row, col)
            checked += 1
    assert checked >= 3


def test_the_outline_in_the_file_holds_the_coco_mask_pixels(yolo_set):
    coco_mod = pytest.importorskip("pycocotools.coco")
    _, out = yolo_set
    gt = coco_mod.COCO(str(out / "coco.json"))
    image = gt.dataset["images"][0]
    h, w = image["height"], image["width"]
    lines = (out / image["file_name"].replace(".png", ".txt")).read_text().splitlines()
    anns = gt.loadAnns(gt.getAnnIds(imgIds=[image["id"]]))
    assert len(lines) == len(anns)
    for line, ann in zip(lines, anns):
        values = line.split()
        assert int(values[0]) == ann["category_id"] - 1
        ring = np.array(values[1:], float).reshape(-1, 2) * [w, h]
        truth = gt.annToMask(ann).astype(bool)
        inside = _centres_inside(ring, (h, w))
        filled = ndimage.binary_fill_holes(truth)
        # Every pixel of the mask is inside; outside it only its holes (a YOLO polygon has none)
        # and the pixels a zero-width cut between two pieces passes through.
        assert inside[truth].all()
        assert (inside & ~filled).sum() <= 0.02 * truth.sum() + 4


def test_labels_are_frame_files_resumed_like_the_others(yolo_set):
    scenario, out = yolo_set
    records = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    label = "frames/000001_fan.txt"
    assert label in records[1]["files"] and label in records[1]["sha256"]
    before = {p.name: p.read_bytes() for p in (out / "frames").iterdir()}
    before_yaml = (out / "data.yaml").read_bytes()
    (out / label).unlink()
    (out / "data.yaml").unlink()
    summary = generate(scenario, out, progress=False, formats=("npz", "yolo"))
    assert summary.rendered == 1 and summary.reused == 2
    assert {p.name: p.read_bytes() for p in (out / "frames").iterdir()} == before
    assert (out / "data.yaml").read_bytes() == before_yaml


def test_a_lone_frame_trains_and_validates():
    from sonarsim.dataset.yolo import image_lists

    files = [["frames/000000.npz", "frames/000000_fan.png"]]
    assert image_lists(files, "fan") == ("./frames/000000_fan.png\n", "./frames/000000_fan.png\n")
    two = files + [["frames/000001.npz", "frames/000001_fan.png"]]
    assert image_lists(two, "fan") == ("./frames/000000_fan.png\n", "./frames/000001_fan.png\n")


def test_a_worker_with_another_deflate_refuses_to_encode(yolo_set):
    from sonarsim.dataset import frames
    from sonarsim.dataset.encoding import encode_frame
    from sonarsim.errors import SonarsimError

    scenario, _ = yolo_set
    frame = next(frames(scenario, stop=1))
    with pytest.raises(SonarsimError, match="frame 0: this worker's deflate is zlib-ng.*the dataset's zlib-ng-0.0"):
        encode_frame(frame.spec, frame.image, DatasetOptions(encoder="zlib-ng-0.0-level2-arm64"), 6)
