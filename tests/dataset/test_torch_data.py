"""PyTorch datasets (sonarsim.dataset.torch_data): the folder's samples against pycocotools
reading its coco.json, DataLoader workers, frames rendered on the fly equal to the folder's
whatever the number of workers, the module without torch, bad folders."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from sonarsim.dataset import generate  # noqa: E402
from sonarsim.dataset.frames import labels_supported  # noqa: E402
from sonarsim.errors import ConfigError, SonarsimError  # noqa: E402
from sonarsim.io.output import read_npz  # noqa: E402

from .test_scenario import VARIED  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
# VARIED's first frames: a block and one to three rocks each (categories block, rock), a small
# sonar (16 beams, 120 bins): 5 frames render and encode in half a second.
N_FRAMES = 5

pytestmark = pytest.mark.skipif(not labels_supported(), reason="this renderer has no labels")


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """VARIED's first frames written by generate: with the default options (fan PNG), and with
    coco="polar" and both PNGs."""
    root = tmp_path_factory.mktemp("torch")
    generate(VARIED, root / "fan", frames=N_FRAMES, progress=False)
    generate(VARIED, root / "polar", frames=N_FRAMES, coco="polar", formats=("npz", "png"), progress=False)
    return {"fan": root / "fan", "polar": root / "polar"}


def assert_same_sample(a: dict, b: dict) -> None:
    """Equal keys and values, tensors bit for bit (NaN equal to NaN), targets alike."""
    assert set(a) == set(b)
    for key in a:
        if key == "target":
            assert_same_sample(a[key], b[key])
        elif isinstance(a[key], torch.Tensor):
            assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, key
            np.testing.assert_array_equal(a[key].numpy(), b[key].numpy(), err_msg=key)
        else:
            assert a[key] == b[key], key


# The folder against coco.json --------------------------------------------------------------

# pycocotools' mask decoding warns under NumPy 2 (its __array__); nothing of ours.
@pytest.mark.filterwarnings("ignore:__array__ implementation:DeprecationWarning")
@pytest.mark.parametrize("kind", ["fan", "polar"])
def test_folder_samples_equal_coco_json_read_by_pycocotools(folders, kind):
    from pycocotools.coco import COCO
    from PIL import Image

    from sonarsim.dataset.torch_data import SonarDatasetFolder

    folder = folders[kind]
    data = SonarDatasetFolder(folder, masks=True)
    assert isinstance(data, torch.utils.data.Dataset) and len(data) == N_FRAMES and data.image == kind
    coco = COCO(str(folder / "coco.json"))
    assert data.categories == {c["name"]: c["id"] for c in coco.loadCats(coco.getCatIds())}
    assert set(data.categories) == {"block", "rock"}
    n_boxes = 0
    for k in range(N_FRAMES):
        sample = data[k]
        info = coco.loadImgs([k])[0]
        assert info["file_name"] == f"frames/{k:06d}_{kind}.png"
        png = np.asarray(Image.open(folder / info["file_name"]))
        assert sample["image"].dtype == torch.uint8 and sample["image"].shape == (info["height"], info["width"])
        np.testing.assert_array_equal(sample["image"].numpy(), png)
        arrays, config = read_npz(folder / f"frames/{k:06d}.npz")
        assert sample["polar"].dtype == torch.float32 and sample["instance"].dtype == torch.int32
        np.testing.assert_array_equal(sample["polar"].numpy(), arrays["polar"])
        np.testing.assert_array_equal(sample["instance"].numpy(), arrays["instance"])
        np.testing.assert_array_equal(sample["elevation_deg"].numpy(), arrays["elevation_deg"])
        assert sample["frame"] == k and sample["time_s"] == config["dataset"]["time_s"]

        anns = coco.loadAnns(coco.getAnnIds(imgIds=[k]))
        target = sample["target"]
        assert target["frame"] == k
        assert target["boxes"].dtype == torch.float32 and target["boxes"].shape == (len(anns), 4)
        assert target["labels"].dtype == torch.int64 and target["masks"].dtype == torch.uint8
        expected = [[x, y, x + w, y + h] for x, y, w, h in (a["bbox"] for a in anns)]
        np.testing.assert_array_equal(target["boxes"].numpy(), np.asarray(expected, np.float32).reshape(-1, 4))
        assert target["labels"].tolist() == [a["category_id"] for a in anns]
        assert target["masks"].shape == (len(anns), info["height"], info["width"])
        for mask, ann in zip(target["masks"].numpy(), anns):
            np.testing.assert_array_equal(mask, coco.annToMask(ann))
            # The box is the mask's extent: x_max and y_max one past its last column and row.
            rows, cols = np.nonzero(mask)
            x0, y0, x1, y1 = (float(v) for v in target["boxes"][anns.index(ann)])
            assert (cols.min(), rows.min(), cols.max() + 1, rows.max() + 1) == (x0, y0, x1, y1)
        n_boxes += len(anns)
    assert n_boxes >= N_FRAMES  # every frame sees something
    assert "masks" not in SonarDatasetFolder(folder)[0]["target"]  # masks only when asked


def test_dataloader_with_two_workers_gives_the_same_batches_as_none(folders):
    from torch.utils.data import DataLoader

    from sonarsim.dataset.torch_data import SonarDatasetFolder, collate

    data = SonarDatasetFolder(folders["fan"], masks=True)
    runs = []
    for workers in (0, 2):
        runs.append(list(DataLoader(data, batch_size=2, num_workers=workers, collate_fn=collate)))
    assert len(runs[0]) == len(runs[1]) == 3  # 2 + 2 + 1 frames
    for one, two in zip(*runs):
        assert one["image"].dtype == torch.uint8 and one["image"].ndim == 3
        assert one["polar"].shape[1:] == (120, 16) and one["frame"].dtype == torch.int64
        assert one["time_s"].dtype == torch.float64 and isinstance(one["target"], list)
        assert_same_sample({k: v for k, v in one.items() if k != "target"},
                           {k: v for k, v in two.items() if k != "target"})
        for a, b in zip(one["target"], two["target"]):
            assert_same_sample(a, b)
    assert torch.cat([b["frame"] for b in runs[1]]).tolist() == list(range(N_FRAMES))


# Frames rendered on the fly ----------------------------------------------------------------

def tag_worker(sample: dict) -> dict:
    """A transform that says which DataLoader worker made the sample (-1: none)."""
    info = torch.utils.data.get_worker_info()
    return {**sample, "worker": -1 if info is None else info.id}


@pytest.mark.parametrize("kind", ["fan", "polar"])
def test_rendered_frames_equal_the_folders_whatever_the_workers(folders, kind):
    from torch.utils.data import DataLoader

    from sonarsim.dataset.torch_data import RenderedFrames, SonarDatasetFolder

    options = {} if kind == "fan" else {"coco": "polar", "formats": ("npz", "png")}
    data = RenderedFrames(VARIED, stop=N_FRAMES, options=options, masks=True, transform=tag_worker)
    folder = SonarDatasetFolder(folders[kind], masks=True)
    assert isinstance(data, torch.utils.data.IterableDataset) and len(data) == N_FRAMES
    assert data.categories == folder.categories
    for workers in ((0, 1, 2) if kind == "fan" else (2,)):
        loader = DataLoader(data, batch_size=None, num_workers=workers)
        samples = list(loader)
        by_frame = {s["frame"]: s for s in samples}
        assert sorted(by_frame) == list(range(N_FRAMES)) and len(samples) == N_FRAMES, workers
        for k, sample in by_frame.items():
            # Each worker took the frames k % num_workers == its id.
            assert sample.pop("worker") == (k % workers if workers else -1)
            assert_same_sample(sample, folder[k])


def test_rendered_frames_pickle_to_spawned_workers(folders):
    """The classes are built on first access: a spawned worker finds them by name (the start
    method Python 3.14 makes the default on Linux is forkserver, which pickles them too)."""
    from torch.utils.data import DataLoader

    from sonarsim.dataset.torch_data import RenderedFrames, SonarDatasetFolder

    data = RenderedFrames(VARIED, start=3, stop=N_FRAMES)
    samples = list(DataLoader(data, batch_size=None, num_workers=1, multiprocessing_context="spawn"))
    folder = SonarDatasetFolder(folders["fan"])
    assert [s["frame"] for s in samples] == [3, 4]
    for sample in samples:
        assert_same_sample(sample, folder[sample["frame"]])


def test_rendered_frames_options_and_ranges():
    from sonarsim.dataset.torch_data import RenderedFrames

    assert list(RenderedFrames(VARIED, start=10, stop=99).indices) == [10, 11]  # clipped to 12 frames
    assert len(RenderedFrames(VARIED, start=12)) == 0
    with pytest.raises(ConfigError, match="ghosts"):
        RenderedFrames(VARIED, options={"ghosts": True})
    with pytest.raises(ConfigError, match="coco"):
        RenderedFrames(VARIED, options={"coco": "side"})
    with pytest.raises(ValueError, match="start"):
        RenderedFrames(VARIED, start=-1)
    plain = next(iter(RenderedFrames(VARIED, stop=1, options={"labels": "none", "formats": ("npz", "png")})))
    assert set(plain) == {"image", "polar", "frame", "time_s"}  # no ground truth: no target


# Without torch, and bad folders -------------------------------------------------------------

def test_the_module_imports_without_torch_and_says_what_to_install():
    code = textwrap.dedent("""
        import sys
        sys.modules["torch"] = None  # import torch fails as if it were not installed
        import sonarsim.dataset.torch_data as td
        from sonarsim.errors import SonarsimError
        for use in (lambda: td.SonarDatasetFolder, lambda: td.collate([]),
                    lambda: td.frame_sample({}, {"frame": 0, "files": []}, "fan", {})):
            try:
                use()
            except SonarsimError as exc:
                print(exc)
            else:
                print("no error")
        try:
            from sonarsim.dataset.torch_data import RenderedFrames
        except SonarsimError as exc:
            print(exc)
        try:
            td.NoSuchThing
        except AttributeError:
            print("AttributeError")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 5 and lines[-1] == "AttributeError", out.stdout
    for line in lines[:4]:
        assert "needs PyTorch" in line and "pip install" in line and "[torch]" in line
    # Importing the module does not import torch.
    quiet = subprocess.run([sys.executable, "-c", "import sys, sonarsim.dataset.torch_data; "
                            "print('torch' in sys.modules)"], capture_output=True, text=True, timeout=60)
    assert quiet.stdout.strip() == "False", quiet.stderr


def test_a_folder_that_is_not_a_finished_dataset_is_refused_naming_the_file(folders, tmp_path):
    from sonarsim.dataset.torch_data import SonarDatasetFolder

    with pytest.raises(SonarsimError, match=r"dataset\.json: dataset description not found"):
        SonarDatasetFolder(tmp_path)
    bad = tmp_path / "copy"
    shutil.copytree(folders["fan"], bad)
    data = SonarDatasetFolder(bad)
    with pytest.raises(IndexError, match="frame 5 out of range"):
        data[N_FRAMES]
    assert data[-1]["frame"] == N_FRAMES - 1

    npz = bad / "frames" / "000002.npz"
    raw = bytearray(npz.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    npz.write_bytes(bytes(raw))
    with pytest.raises(SonarsimError, match=r"000002\.npz: its sha256 differs"):
        data[2]
    (bad / "frames" / "000003_fan.png").unlink()
    with pytest.raises(SonarsimError, match=r"000003_fan\.png: not found"):
        data[3]

    (bad / "coco.json").unlink()
    with pytest.raises(SonarsimError, match=r"coco\.json: COCO file not found"):
        SonarDatasetFolder(bad)
    manifest = bad / "manifest.jsonl"
    lines = manifest.read_text().splitlines()
    manifest.write_text("\n".join(lines[:-1]) + "\n")  # an unfinished run's manifest
    with pytest.raises(SonarsimError, match=r"manifest\.jsonl: holds 4 of the 5 frames .* not finished"):
        SonarDatasetFolder(bad)
    record = json.loads(lines[0])
    record["time_s"] = 9.0  # edited: its check fails
    manifest.write_text("\n".join([json.dumps(record)] + lines[1:]) + "\n")
    with pytest.raises(SonarsimError, match=r"manifest\.jsonl: a damaged line"):
        SonarDatasetFolder(bad)
    manifest.unlink()
    with pytest.raises(SonarsimError, match=r"manifest\.jsonl: dataset manifest not found"):
        SonarDatasetFolder(bad)
