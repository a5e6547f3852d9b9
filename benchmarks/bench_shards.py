"""Sharded dataset formats (issue 41 item 3): pack time, size on disk and DataLoader read speed.

A dataset folder written by :func:`sonarsim.dataset.generate` (one ``frames/NNNNNN.npz`` and one
``frames/NNNNNN_fan.png`` a frame, ``manifest.jsonl``) is packed, ``--shard-frames`` frames a shard,
into each candidate:

* ``webdataset_tar``: WebDataset tar shards (stdlib :mod:`tarfile`, USTAR, mtime 0, uid/gid 0):
  per sample ``KEY.npz`` and ``KEY.fan.png`` (the files' bytes as they are) and ``KEY.json`` (the
  frame's manifest line: pose, seed, boxes with their RLE masks, digests);
* ``parquet``: one Parquet file a shard (pyarrow), one row a frame (``key``, ``frame``, binary
  ``npz`` and ``fan_png``, string ``json``), row groups of 16 rows, no Parquet compression
  (the payloads are already deflated);
* ``hdf5_gzip1`` / ``hdf5_lzf``: one HDF5 file a shard (h5py): the NPZ's arrays decoded and
  stacked (fixed-shape arrays as ``(n, ...)`` datasets chunked one frame a chunk; ragged ones,
  e.g. the point cloud, concatenated with an ``NAME_offsets`` dataset), gzip level 1 or LZF; the
  fan PNG as variable-length uint8, the JSON and the NPZ's string arrays as variable-length
  strings;
* ``zarr_v3``: one Zarr v3 group a shard (zarr-python 3), the same layout with zarr's default
  codec (zstd); bytes and text as uint8 blobs with offsets (zarr's variable-length bytes data
  type has no v3 specification yet).

Each candidate is packed ``--repeats`` times (median pack time; whether the repacks are
byte-identical is recorded), then read back through a ``torch.utils.data.DataLoader``
(batch size 8, ``num_workers`` 0, 2 and 4, the default fork start) with every sample decoded to
the same content: the frame number, the polar image (float32 1288 x 128), the instance map
(int32) and the fan image (uint8, PNG decoded with Pillow). WebDataset is read with the
``webdataset`` library (``WebDataset(urls, shardshuffle=False)``, its own split of shards by
worker, a ``.map`` over the raw bytes); Parquet with pyarrow (an ``IterableDataset`` reading the
row groups, split round-robin by worker, one thread); HDF5 and Zarr with a map-style dataset that
opens its files once in each worker process (h5py handles are not fork-safe). The rate is
samples/s after the first batch (the workers' start-up excluded; the whole-pass rate is recorded
too); every pass is checked to see each frame exactly once and to decode frame 0 to the dataset's
own ``numpy.load(frames/000000.npz)`` polar and instance arrays and its PNG. Read passes are
interleaved (repeat, workers, candidate) so that a noisy machine hits them alike; medians over
``--repeats`` are reported. If the Hugging Face ``datasets`` package is importable, whether
``datasets.load_dataset("parquet", data_files=...)`` reads the Parquet shards is recorded.

Usage::

    python benchmarks/bench_shards.py [--frames 240] [--dataset DIR] [--shard-frames 64]
                                      [--repeats 3] [--json out.json]

Without ``--dataset`` it generates ``--frames`` frames of ``bench_dataset.py``'s scenario (the
demo tank orbit) with 2 workers into a temporary folder; everything is written under a temporary
folder that is removed at the end.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import platform
import shutil
import statistics
import sys
import tarfile
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

BATCH = 8


# --------------------------------------------------------------------------- source frames


def source_frames(dataset: Path) -> list[dict]:
    """The dataset's frames in order: frame number, key, NPZ and PNG paths, manifest line."""
    out = []
    for line in (dataset / "manifest.jsonl").read_text().splitlines():
        if not line.strip():
            continue
        rec = json.loads(line)
        files = rec["files"]
        npz = next(f for f in files if f.endswith(".npz"))
        png = next(f for f in files if f.endswith("_fan.png"))
        out.append({"frame": int(rec["frame"]), "key": f"{int(rec['frame']):06d}", "npz": dataset / npz,
                    "png": dataset / png, "json": line.strip()})
    out.sort(key=lambda r: r["frame"])
    return out


def shards_of(frames: list[dict], n: int) -> list[list[dict]]:
    return [frames[i:i + n] for i in range(0, len(frames), n)]


def npz_arrays(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data)) as z:
        return {k: z[k] for k in z.files}


def split_arrays(recs: list[dict[str, np.ndarray]]):
    """A shard's arrays as fixed-shape stacks, ragged concatenations (with offsets) and text."""
    names = list(recs[0])
    for r in recs:
        assert list(r) == names, "frames of one shard must hold the same arrays"
    fixed, ragged, text = {}, {}, {}
    for name in names:
        arrs = [r[name] for r in recs]
        if arrs[0].dtype.kind in "USO":
            text[name] = [a.tolist() for a in arrs]
        elif all(a.shape == arrs[0].shape for a in arrs):
            fixed[name] = np.stack(arrs)
        else:
            sizes = [a.shape[0] for a in arrs]
            ragged[name] = (np.concatenate(arrs, axis=0), np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64))
    return fixed, ragged, text


def blob(parts: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    return np.frombuffer(b"".join(parts), dtype=np.uint8), offsets


# --------------------------------------------------------------------------- packers


def _tar_add(tf: tarfile.TarFile, name: str, data: bytes) -> None:
    ti = tarfile.TarInfo(name)
    ti.size, ti.mtime, ti.mode, ti.uid, ti.gid, ti.uname, ti.gname = len(data), 0, 0o644, 0, 0, "", ""
    tf.addfile(ti, io.BytesIO(data))


def pack_tar(shard: list[dict], path: Path) -> Path:
    path = path.with_suffix(".tar")
    with tarfile.open(path, "w", format=tarfile.USTAR_FORMAT) as tf:
        for f in shard:
            _tar_add(tf, f"{f['key']}.npz", f["npz"].read_bytes())
            _tar_add(tf, f"{f['key']}.fan.png", f["png"].read_bytes())
            _tar_add(tf, f"{f['key']}.json", f["json"].encode())
    return path


def pack_parquet(shard: list[dict], path: Path) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = path.with_suffix(".parquet")
    table = pa.table({
        "key": pa.array([f["key"] for f in shard], pa.string()),
        "frame": pa.array([f["frame"] for f in shard], pa.int64()),
        "npz": pa.array([f["npz"].read_bytes() for f in shard], pa.binary()),
        "fan_png": pa.array([f["png"].read_bytes() for f in shard], pa.binary()),
        "json": pa.array([f["json"] for f in shard], pa.string()),
    })
    pq.write_table(table, path, row_group_size=16, compression="none", use_dictionary=False,
                   write_statistics=["key", "frame"])
    return path


def _pack_hdf5(shard: list[dict], path: Path, comp: dict) -> Path:
    import h5py

    path = path.with_suffix(".h5")
    fixed, ragged, text = split_arrays([npz_arrays(f["npz"].read_bytes()) for f in shard])
    with h5py.File(path, "w") as h:
        h.create_dataset("frame", data=np.array([f["frame"] for f in shard], np.int64))
        for name, a in fixed.items():
            if a.ndim >= 2:
                h.create_dataset(name, data=a, chunks=(1,) + a.shape[1:], **comp)
            else:
                h.create_dataset(name, data=a)
        for name, (a, offsets) in ragged.items():
            h.create_dataset(name, data=a, chunks=True, **comp)
            h.create_dataset(f"{name}_offsets", data=offsets)
        png = h.create_dataset("fan_png", (len(shard),), dtype=h5py.vlen_dtype(np.uint8))
        for i, f in enumerate(shard):
            png[i] = np.frombuffer(f["png"].read_bytes(), np.uint8)
        h.create_dataset("json", data=np.array([f["json"] for f in shard], dtype=object),
                         dtype=h5py.string_dtype())
        strings = [json.dumps({k: v[i] for k, v in text.items()}) for i in range(len(shard))]
        h.create_dataset("npz_strings", data=np.array(strings, dtype=object), dtype=h5py.string_dtype())
    return path


def pack_hdf5_gzip1(shard, path):
    return _pack_hdf5(shard, path, {"compression": "gzip", "compression_opts": 1})


def pack_hdf5_lzf(shard, path):
    return _pack_hdf5(shard, path, {"compression": "lzf"})


def pack_zarr(shard: list[dict], path: Path) -> Path:
    import zarr

    path = path.with_suffix(".zarr")
    fixed, ragged, text = split_arrays([npz_arrays(f["npz"].read_bytes()) for f in shard])
    g = zarr.open_group(str(path), mode="w", zarr_format=3)

    def put(name, a, chunks):
        arr = g.create_array(name, shape=a.shape, chunks=chunks, dtype=a.dtype)
        arr[...] = a

    put("frame", np.array([f["frame"] for f in shard], np.int64), (len(shard),))
    for name, a in fixed.items():
        put(name, a, (1,) + a.shape[1:] if a.ndim >= 2 else a.shape)
    for name, (a, offsets) in ragged.items():
        put(name, a, (min(32768, max(1, a.shape[0])),) + a.shape[1:])
        put(f"{name}_offsets", offsets, offsets.shape)
    strings = [json.dumps({k: v[i] for k, v in text.items()}).encode() for i in range(len(shard))]
    for name, parts in (("fan_png", [f["png"].read_bytes() for f in shard]),
                        ("json", [f["json"].encode() for f in shard]), ("npz_strings", strings)):
        data, offsets = blob(parts)
        put(name, data, (min(65536, max(1, data.size)),))
        put(f"{name}_offsets", offsets, offsets.shape)
    return path


PACKERS = {"webdataset_tar": pack_tar, "parquet": pack_parquet, "hdf5_gzip1": pack_hdf5_gzip1,
           "hdf5_lzf": pack_hdf5_lzf, "zarr_v3": pack_zarr}


def files_under(paths: list[Path]) -> list[Path]:
    out = []
    for p in paths:
        out.extend(sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p])
    return out


def digest(paths: list[Path], root: Path) -> str:
    h = hashlib.sha256()
    for f in files_under(paths):
        h.update(str(f.relative_to(root)).encode())
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


# --------------------------------------------------------------------------- readers


def decode_png(data: bytes) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        return np.array(im)


def decode_bytes(frame: int, npz: bytes, png: bytes):
    with np.load(io.BytesIO(npz)) as z:
        polar, instance = z["polar"], z["instance"]
    return frame, polar, instance, decode_png(png)


def _wds_decode(sample):
    return decode_bytes(int(sample["__key__"].rsplit("/", 1)[-1]), sample["npz"], sample["fan.png"])


def wds_dataset(paths: list[Path], counts: list[int]):
    import webdataset as wds

    return wds.WebDataset([str(p) for p in paths], shardshuffle=False, workersplitter=wds.split_by_worker,
                          empty_check=False).map(_wds_decode)


def _worker_part():
    from torch.utils.data import get_worker_info

    info = get_worker_info()
    return (info.id, info.num_workers) if info is not None else (0, 1)


def _iterable_base():
    from torch.utils.data import IterableDataset

    return IterableDataset


def _map_base():
    from torch.utils.data import Dataset

    return Dataset


class ParquetFrames(_iterable_base()):
    """The Parquet shards' row groups, split round-robin among the DataLoader's workers."""

    def __init__(self, paths: list[Path], counts: list[int]):
        self.units = [(str(p), rg) for p, c in zip(paths, counts) for rg in range((c + 15) // 16)]

    def __iter__(self):
        import pyarrow.parquet as pq

        wid, nw = _worker_part()
        files = {}
        for u, (path, rg) in enumerate(self.units):
            if u % nw != wid:
                continue
            pf = files.get(path) or files.setdefault(path, pq.ParquetFile(path))
            t = pf.read_row_group(rg, columns=["frame", "npz", "fan_png"], use_threads=False)
            for frame, npz, png in zip(t.column("frame").to_pylist(), t.column("npz").to_pylist(),
                                       t.column("fan_png").to_pylist()):
                yield decode_bytes(frame, npz, png)


class _ShardedArrays(_map_base()):
    """Map-style: global index -> (shard, row); files opened once per process, on first use."""

    def __init__(self, paths: list[Path], counts: list[int]):
        self.paths = [str(p) for p in paths]
        self.index = [(s, i) for s, c in enumerate(counts) for i in range(c)]
        self._pid, self._open = None, {}

    def __len__(self):
        return len(self.index)

    def _shard(self, s):
        if self._pid != os.getpid():
            self._pid, self._open = os.getpid(), {}
        if s not in self._open:
            self._open[s] = self.open(self.paths[s])
        return self._open[s]

    def close(self):
        for h in self._open.values():
            getattr(h, "close", lambda: None)()
        self._open = {}


class H5Frames(_ShardedArrays):
    def open(self, path):
        import h5py

        return h5py.File(path, "r")

    def __getitem__(self, j):
        s, i = self.index[j]
        h = self._shard(s)
        return int(h["frame"][i]), h["polar"][i], h["instance"][i], decode_png(h["fan_png"][i].tobytes())


class ZarrFrames(_ShardedArrays):
    def open(self, path):
        import zarr

        g = zarr.open_group(path, mode="r")
        return {"g": g, "frame": g["frame"][:], "polar": g["polar"], "instance": g["instance"],
                "fan_png": g["fan_png"], "fan_png_offsets": g["fan_png_offsets"][:]}

    def __getitem__(self, j):
        s, i = self.index[j]
        z = self._shard(s)
        o = z["fan_png_offsets"]
        return (int(z["frame"][i]), z["polar"][i], z["instance"][i],
                decode_png(z["fan_png"][int(o[i]):int(o[i + 1])].tobytes()))


READERS = {"webdataset_tar": wds_dataset, "parquet": ParquetFrames, "hdf5_gzip1": H5Frames,
           "hdf5_lzf": H5Frames, "zarr_v3": ZarrFrames}


def read_pass(make, workers: int, expected: list[int], ref: dict) -> dict:
    """One pass through a DataLoader: samples/s after the first batch and over the whole pass,
    each frame seen exactly once, frame 0 decoded to the dataset's own arrays."""
    from torch.utils.data import DataLoader

    ds = make()
    dl = DataLoader(ds, batch_size=BATCH, num_workers=workers, shuffle=False)
    seen, after, ok0 = [], 0, None
    t_start = time.perf_counter()
    t0 = None
    for b, (frame, polar, instance, fan) in enumerate(dl):
        ids = frame.tolist()
        seen.extend(ids)
        if 0 in ids:
            k = ids.index(0)
            p, i, f = polar[k].numpy(), instance[k].numpy(), fan[k].numpy()
            ok0 = bool(p.dtype == np.float32 and p.shape == ref["polar"].shape and np.array_equal(p, ref["polar"])
                       and np.array_equal(i, ref["instance"]) and f.dtype == np.uint8
                       and np.array_equal(f, ref["fan"]))
        if t0 is None:
            t0 = time.perf_counter()
        else:
            after += len(ids)
    t1 = time.perf_counter()
    if hasattr(ds, "close"):
        ds.close()
    return {"samples_per_s": after / (t1 - t0) if t1 > t0 and after else float("nan"),
            "whole_pass_samples_per_s": len(seen) / (t1 - t_start),
            "each_frame_once": sorted(seen) == sorted(expected) and len(seen) == len(set(seen)),
            "frame0_equal": ok0}


def hf_datasets_check(paths: list[Path], n: int) -> dict:
    try:
        import datasets
    except ImportError:
        return {"importable": False, "note": "the `datasets` package is not installed here: skipped"}
    try:
        d = datasets.load_dataset("parquet", data_files=[str(p) for p in paths], split="train")
        row = d[0]
        polar = np.load(io.BytesIO(row["npz"]))["polar"]
        return {"importable": True, "version": datasets.__version__, "reads": d.num_rows == n,
                "rows": d.num_rows, "columns": d.column_names, "polar_shape": list(polar.shape)}
    except Exception as exc:  # noqa: BLE001 - what it says is the result
        return {"importable": True, "reads": False, "error": f"{type(exc).__name__}: {exc}"}


# --------------------------------------------------------------------------- main


def machine_note() -> dict:
    import h5py
    import pyarrow
    import torch
    import webdataset
    import zarr
    import PIL

    return {"platform": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(),
            "cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "note": "shared, noisy cores (another job ran tests meanwhile): compare ratios within this run; "
                    "medians of the repeats; data read from the page cache (the files were just written)",
            "versions": {"numpy": np.__version__, "torch": torch.__version__, "pyarrow": pyarrow.__version__,
                         "h5py": h5py.__version__, "hdf5": h5py.version.hdf5_version, "zarr": zarr.__version__,
                         "webdataset": getattr(webdataset, "__version__", "?"), "pillow": PIL.__version__}}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", type=Path, default=None, help="an existing dataset folder (else one is generated)")
    p.add_argument("--frames", type=int, default=240)
    p.add_argument("--shard-frames", type=int, default=64)
    p.add_argument("--workers", default="0,2,4")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    worker_counts = [int(w) for w in args.workers.split(",")]
    warnings.filterwarnings("ignore", message="This DataLoader will create")  # 4 workers on 2 cores: on purpose
    tmp = Path(tempfile.mkdtemp(prefix="bench-shards-"))
    results: dict = {"machine": machine_note(), "shard_frames": args.shard_frames, "batch_size": BATCH,
                     "repeats": args.repeats, "workers": worker_counts}
    try:
        if args.dataset is None:
            from bench_dataset import scenario_doc
            from sonarsim.dataset import generate, load_scenario

            t = time.perf_counter()
            generate(load_scenario(scenario_doc(args.frames)), tmp / "dataset", workers=2, progress=False,
                     log=lambda m: None)
            results["generate_s"] = time.perf_counter() - t
            dataset = tmp / "dataset"
        else:
            dataset = args.dataset
        frames = source_frames(dataset)
        n = len(frames)
        results["frames"] = n
        results["source_folder_mb"] = sum(f["npz"].stat().st_size + f["png"].stat().st_size
                                          + len(f["json"]) + 1 for f in frames) / 1e6
        print(f"{n} frames from {dataset if args.dataset else 'a generated dataset'}, "
              f"{args.shard_frames} frames a shard, {results['source_folder_mb']:.1f} MB of NPZ+PNG+JSON")
        ref = {"polar": np.load(frames[0]["npz"])["polar"], "instance": np.load(frames[0]["npz"])["instance"],
               "fan": decode_png(frames[0]["png"].read_bytes())}
        assert frames[0]["frame"] == 0
        shards = shards_of(frames, args.shard_frames)
        counts = [len(s) for s in shards]
        cands: dict[str, dict] = {}
        packed: dict[str, list[Path]] = {}
        for name, pack in PACKERS.items():
            times, digests = [], []
            for r in range(args.repeats):
                out = tmp / "packed" / name / f"r{r}"
                out.mkdir(parents=True)
                t = time.perf_counter()
                paths = [pack(s, out / f"shard-{k:06d}") for k, s in enumerate(shards)]
                times.append(time.perf_counter() - t)
                digests.append(digest(paths, out))
                if r < args.repeats - 1:
                    shutil.rmtree(out)
            packed[name] = paths
            files = files_under(paths)
            cands[name] = {"pack_s": statistics.median(times), "pack_s_runs": times,
                           "mb_on_disk": sum(f.stat().st_size for f in files) / 1e6, "files": len(files),
                           "shards": len(paths), "byte_identical_repack": len(set(digests)) == 1}
            print(f"packed {name}: {cands[name]['pack_s']:.2f} s, {cands[name]['mb_on_disk']:.1f} MB, "
                  f"{len(files)} files", flush=True)
        expected = [f["frame"] for f in frames]
        runs: dict = {name: {w: [] for w in worker_counts} for name in PACKERS}
        for r in range(args.repeats):
            for w in worker_counts:
                for name in PACKERS:
                    res = read_pass(lambda: READERS[name](packed[name], counts), w, expected, ref)
                    runs[name][w].append(res)
            print(f"read repeat {r + 1}/{args.repeats} done", flush=True)
        for name, by_w in runs.items():
            c = cands[name]
            c["read"] = {}
            for w, rs in by_w.items():
                c["read"][f"workers_{w}"] = {
                    "samples_per_s": statistics.median(x["samples_per_s"] for x in rs),
                    "whole_pass_samples_per_s": statistics.median(x["whole_pass_samples_per_s"] for x in rs),
                    "samples_per_s_runs": [x["samples_per_s"] for x in rs],
                    "each_frame_once": all(x["each_frame_once"] for x in rs),
                    "frame0_equal": all(x["frame0_equal"] for x in rs)}
        results["candidates"] = cands
        results["hf_datasets_parquet"] = hf_datasets_check(packed["parquet"], n)
        best = max(worker_counts)
        base = cands["webdataset_tar"]["read"][f"workers_{best}"]["samples_per_s"]
        results[f"read_vs_webdataset_workers_{best}"] = {
            name: c["read"][f"workers_{best}"]["samples_per_s"] / base for name, c in cands.items()}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    head = f"{'candidate':<16}{'pack s':>8}{'MB':>8}{'files':>7}{'repack=':>8}" + "".join(
        f"{'w' + str(w) + ' smp/s':>11}" for w in worker_counts) + f"{'checks':>8}"
    print(head)
    for name, c in cands.items():
        ok = all(v["each_frame_once"] and v["frame0_equal"] for v in c["read"].values())
        print(f"{name:<16}{c['pack_s']:>8.2f}{c['mb_on_disk']:>8.1f}{c['files']:>7}"
              f"{'yes' if c['byte_identical_repack'] else 'no':>8}"
              + "".join(f"{c['read'][f'workers_{w}']['samples_per_s']:>11.1f}" for w in worker_counts)
              + f"{'ok' if ok else 'FAIL':>8}")
    print(f"read speed vs webdataset_tar at {best} workers: "
          + ", ".join(f"{k} {v:.2f}x" for k, v in results[f"read_vs_webdataset_workers_{best}"].items()))
    print(f"datasets.load_dataset('parquet'): {results['hf_datasets_parquet']}")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
