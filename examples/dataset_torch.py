"""Training on sonarsim frames with PyTorch: a Dataset over a scenario, rendered on the fly, or
over a dataset folder written by ``sonarsim dataset``.

torch is not a dependency of sonarsim; this example imports it only when run::

    pip install torch
    python examples/dataset_torch.py examples/scenarios/orbit_tank.yaml          # render on the fly
    python examples/dataset_torch.py --folder out/tank                           # read NPZ files

Each item is ``(image, target)``: the polar image as a (1, n_range_bins, n_beams) float32
tensor in dB, and a dict with the instance map (int64, -1 where nothing lands) and the
elevation per cell (float32, NaN where nothing lands) when the frames have labels.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def to_sample(arrays: dict) -> tuple[np.ndarray, dict]:
    """(image, target) arrays of one frame's named arrays (``Frame.arrays()`` or an NPZ)."""
    polar = arrays["polar"].astype(np.float32)
    image = 10.0 * np.log10(np.maximum(polar, 1e-12 * max(float(polar.max()), 1e-30)))[None]
    target = {}
    if "instance" in arrays:
        target["instance"] = arrays["instance"].astype(np.int64)
        target["elevation_deg"] = arrays["elevation_deg"].astype(np.float32)
    return image, target


def main(argv=None) -> int:
    import torch  # only here: importing this file needs nothing beyond numpy
    from torch.utils.data import DataLoader, Dataset

    from sonarsim.dataset import Frame, load_scenario
    from sonarsim.dataset.frames import SimulatorCache, render_frame

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scenario", nargs="?", help="scenario file: render frames on the fly")
    p.add_argument("--folder", help="a dataset folder written by `sonarsim dataset`")
    p.add_argument("--batch", type=int, default=4)
    args = p.parse_args(argv)

    class ScenarioFrames(Dataset):
        """Frame k of a scenario, rendered when asked (each DataLoader worker keeps its simulators)."""

        def __init__(self, path: str) -> None:
            self.scenario = load_scenario(path)
            self.cache = None  # built in the process that renders (a DataLoader worker)

        def __len__(self) -> int:
            return self.scenario.n_frames

        def __getitem__(self, k: int):
            if self.cache is None:
                self.cache = SimulatorCache()
            spec = self.scenario.frame(k)  # frame k alone: any order, any worker
            frame = Frame(spec, render_frame(spec, self.cache))
            image, target = to_sample(frame.arrays())
            return torch.from_numpy(image), {key: torch.from_numpy(v) for key, v in target.items()}

    class FolderFrames(Dataset):
        """Frame k of a dataset folder, read from the NPZ its manifest names."""

        def __init__(self, folder: str) -> None:
            self.folder = Path(folder)
            lines = (self.folder / "manifest.jsonl").read_text().splitlines()
            self.records = sorted((json.loads(line) for line in lines if line.strip()), key=lambda r: r["frame"])

        def __len__(self) -> int:
            return len(self.records)

        def __getitem__(self, k: int):
            with np.load(self.folder / self.records[k]["files"][0], allow_pickle=False) as npz:
                image, target = to_sample({name: npz[name] for name in npz.files})
            return torch.from_numpy(image), {key: torch.from_numpy(v) for key, v in target.items()}

    if (args.scenario is None) == (args.folder is None):
        p.error("give a scenario file or --folder")
    data = FolderFrames(args.folder) if args.folder else ScenarioFrames(args.scenario)
    for images, targets in DataLoader(data, batch_size=args.batch):
        print("batch", tuple(images.shape), {k: tuple(v.shape) for k, v in targets.items()})
        break
    return 0


if __name__ == "__main__":
    sys.exit(main())
