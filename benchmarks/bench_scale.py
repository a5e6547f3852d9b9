"""Datasets at scale (issue 41 item 4): time, disk and memory of runs of two sizes, extrapolated to 100,000 frames.

Each size runs ``generate`` in a fresh process on the demo tank's orbit (``bench_dataset``'s
scenario: ARIS 3000 preset, 128 beams x 1288 bins, all bounces, the default labels), with the
formats a detector's training set takes (NPZ, the fan PNG and ``coco.json``, YOLO labels,
WebDataset shards of 256 frames), then runs it again on the finished folder (every frame
verified, read in full, and kept: what a resume after a kill costs before it renders). Per size
it records the wall time of both runs, the folder's bytes (per frame and in the files written
once: ``coco.json``, the manifest, the shards), and the peak resident memory of the parent
and of the largest worker (``getrusage``).

The extrapolation is linear in the frame count for what grows with it -- render time, bytes,
the parent's memory (it holds every manifest record: the two sizes give the slope) -- and
says so; the workers' memory does not grow with the count.

Usage::

    python benchmarks/bench_scale.py [--sizes 500 1500] [--workers 2] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

_RUN = """
import json, os, resource, sys, threading, time
sys.path.insert(0, {bench!r})
peak = {{}}
def _watch():  # the workers' peak resident memory (VmHWM), polled: they are not our children
    me = os.getpid()
    while True:
        parent, hwm = {{}}, {{}}
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                with open(f"/proc/{{pid}}/status") as f:
                    fields = dict(line.split(":", 1) for line in f.read().splitlines() if ":" in line)
                parent[int(pid)] = int(fields["PPid"])
                if "VmHWM" in fields:
                    hwm[int(pid)] = int(fields["VmHWM"].split()[0]) / 1024
            except (OSError, KeyError, ValueError):
                continue
        for pid, mb in hwm.items():
            up, seen = parent.get(pid), 0
            while up not in (None, 0, 1, me) and seen < 50:
                up, seen = parent.get(up), seen + 1
            if up == me:
                peak[pid] = max(peak.get(pid, 0.0), mb)
        time.sleep(0.5)
threading.Thread(target=_watch, daemon=True).start()
from bench_dataset import scenario_doc
from sonarsim.dataset import generate, load_scenario
scenario = load_scenario(scenario_doc({n}))
t0 = time.perf_counter()
summary = generate(scenario, {out!r}, workers={workers}, formats=("npz", "yolo"), shards=256, progress=False,
                   log=lambda m: None)
t1 = time.perf_counter()
again = generate(scenario, {out!r}, workers={workers}, formats=("npz", "yolo"), shards=256, progress=False,
                 log=lambda m: None)
t2 = time.perf_counter()
assert again.rendered == 0 and again.reused == {n}
print(json.dumps({{"make_s": t1 - t0, "verify_s": t2 - t1,
                  "parent_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "worker_peak_mb": max(peak.values(), default=0.0)}}))
"""


def _bytes(folder: Path) -> dict[str, int]:
    sizes = {"frames": 0, "shards": 0, "other": 0}
    for path in folder.rglob("*"):
        if path.is_file():
            part = path.relative_to(folder).parts[0]
            sizes[part if part in sizes else "other"] += path.stat().st_size
    for name in ("coco.json", "manifest.jsonl"):
        sizes[name] = (folder / name).stat().st_size
    return sizes


def measure(n: int, workers: int) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix="bench-scale-"))
    try:
        out = tmp / "ds"
        code = _RUN.format(bench=str(Path(__file__).parent), n=n, out=str(out), workers=workers)
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        row = json.loads(proc.stdout.strip().splitlines()[-1])
        row.update(frames=n, bytes=_bytes(out))
        return row
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def parent_rate(n: int = 200) -> float:
    """Frames/s that ``generate``'s parent process can take in when it writes what workers
    send (Ray's actors send the bytes: its nodes need not share a disk): a frame's files
    written atomically, its manifest line, and its WebDataset shard packed, replayed from a
    finished folder's bytes. The ceiling of a Ray cluster of any size on one parent."""
    import time

    sys.path.insert(0, str(Path(__file__).parent))
    from bench_dataset import scenario_doc

    from sonarsim.dataset import generate, load_scenario
    from sonarsim.dataset.encoding import EncodedFrame, _write_files
    from sonarsim.dataset.manifest import ManifestAppender, ManifestLines
    from sonarsim.dataset.shards import ShardWriter

    tmp = Path(tempfile.mkdtemp(prefix="bench-parent-"))
    try:
        src = tmp / "src"
        generate(load_scenario(scenario_doc(n)), src, workers=2, formats=("npz", "yolo"), progress=False,
                 log=lambda m: None)
        records = [json.loads(t) for t in (src / "manifest.jsonl").read_text().splitlines()]
        frames = [EncodedFrame(r["frame"], tuple((f, (src / f).read_bytes()) for f in r["files"]),
                               {k: v for k, v in r.items() if k != "check"}) for r in records]
        out = tmp / "out"
        (out / "frames").mkdir(parents=True)
        lines = ManifestLines(out / "manifest.jsonl")
        packer = ShardWriter(out, n, 64, lines)
        t0 = time.perf_counter()
        with ManifestAppender(out / "manifest.jsonl") as manifest:
            for encoded in frames:
                _write_files(out, encoded)
                lines.at[encoded.index] = manifest.append(encoded.record)
                packer.add(encoded.index)
        return n / (time.perf_counter() - t0)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def extrapolate(a: dict, b: dict, target: int) -> dict:
    """Linear in the frame count, from the two sizes' difference (fixed costs cancel)."""
    dn = b["frames"] - a["frames"]

    def line(key_a: float, key_b: float) -> float:
        slope = (key_b - key_a) / dn
        return key_b + slope * (target - b["frames"])

    total_a, total_b = sum(a["bytes"][k] for k in ("frames", "shards", "other")), sum(
        b["bytes"][k] for k in ("frames", "shards", "other"))
    return {
        "frames": target,
        "make_hours": line(a["make_s"], b["make_s"]) / 3600,
        "verify_before_resume_minutes": line(a["verify_s"], b["verify_s"]) / 60,
        "disk_gb": line(total_a, total_b) / 1e9,
        "disk_gb_without_shards": line(total_a - a["bytes"]["shards"], total_b - b["bytes"]["shards"]) / 1e9,
        "coco_json_mb": line(a["bytes"]["coco.json"], b["bytes"]["coco.json"]) / 1e6,
        "manifest_mb": line(a["bytes"]["manifest.jsonl"], b["bytes"]["manifest.jsonl"]) / 1e6,
        "parent_peak_mb": line(a["parent_peak_mb"], b["parent_peak_mb"]),
        "parent_mb_per_1000_frames": 1000 * (b["parent_peak_mb"] - a["parent_peak_mb"]) / dn,
        "worker_peak_mb": max(a["worker_peak_mb"], b["worker_peak_mb"]),
        "frames_per_s": dn / (b["make_s"] - a["make_s"]),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", type=int, nargs=2, default=(500, 1500))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--target", type=int, default=100_000)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    rows = [measure(n, args.workers) for n in args.sizes]
    for row in rows:
        print(json.dumps(row))
    result = {"runs": rows, "extrapolated": extrapolate(rows[0], rows[1], args.target), "workers": args.workers,
              "parent_intake_frames_per_s": parent_rate()}
    print(f"parent_intake_frames_per_s: {result['parent_intake_frames_per_s']:.1f}")
    for key, value in result["extrapolated"].items():
        print(f"{key}: {value:.3f}" if isinstance(value, float) else f"{key}: {value}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
