"""Training on sonarsim frames with PyTorch (``sonarsim.dataset.torch_data``): frames rendered on
the fly from a scenario, or read from a dataset folder written by ``sonarsim dataset``.

torch is not a dependency of sonarsim; this example imports it only when run::

    pip install 'sonarsim[torch]'
    python examples/dataset_torch.py examples/scenarios/orbit_tank.yaml          # render on the fly
    python examples/dataset_torch.py --folder out/tank                           # read a folder

Each batch (``collate``) holds ``image`` (B, H, W) uint8, the fan PNG ``coco.json`` names;
``polar`` (B, n_range_bins, n_beams) float32; ``instance`` and ``elevation_deg`` with labels;
``target``, a list of B detection targets (``boxes`` [x_min, y_min, x_max, y_max] in fan pixels,
``labels``, ``masks``) as torchvision's detection models take them; and, added by this example's
transform, ``polar_db``: the polar image in dB as a (1, n_range_bins, n_beams) float32 tensor.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def to_sample(arrays: dict) -> tuple[np.ndarray, dict]:
    """(image, target) arrays of one frame's named arrays (``Frame.arrays()`` or an NPZ): the
    polar image in dB, (1, n_range_bins, n_beams) float32, and the instance (int64) and
    elevation (float32) maps when the frame has labels."""
    polar = arrays["polar"].astype(np.float32)
    image = 10.0 * np.log10(np.maximum(polar, 1e-12 * max(float(polar.max()), 1e-30)))[None]
    target = {}
    if "instance" in arrays:
        target["instance"] = arrays["instance"].astype(np.int64)
        target["elevation_deg"] = arrays["elevation_deg"].astype(np.float32)
    return image, target


def add_db(sample: dict) -> dict:
    """A dataset transform: the sample with its polar image in dB (``polar_db``)."""
    import torch

    return {**sample, "polar_db": torch.from_numpy(to_sample({"polar": sample["polar"].numpy()})[0])}


def main(argv=None) -> int:
    from torch.utils.data import DataLoader  # only here: importing this file needs nothing beyond numpy

    from sonarsim.dataset.torch_data import RenderedFrames, SonarDatasetFolder, collate

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenario", nargs="?", help="scenario file: render frames on the fly")
    p.add_argument("--folder", help="a dataset folder written by `sonarsim dataset`")
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--workers", type=int, default=2, help="DataLoader workers (each renders k %% workers)")
    args = p.parse_args(argv)
    if (args.scenario is None) == (args.folder is None):
        p.error("give a scenario file or --folder")
    if args.folder:
        data = SonarDatasetFolder(args.folder, masks=True, transform=add_db)
    else:
        data = RenderedFrames(args.scenario, stop=2 * args.batch, masks=True, transform=add_db)
    print("categories", data.categories)
    for batch in DataLoader(data, batch_size=args.batch, num_workers=args.workers, collate_fn=collate):
        print("batch", {k: tuple(v.shape) for k, v in batch.items() if hasattr(v, "shape")},
              "boxes", [tuple(t["boxes"].shape) for t in batch.get("target", [])])
        break
    return 0


if __name__ == "__main__":
    sys.exit(main())
