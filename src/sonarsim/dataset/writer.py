"""``generate``: a scenario's frames written to a dataset folder, resumably.

A dataset folder ``DIR`` holds::

    DIR/dataset.json          the dataset's fingerprint and options (manifest module)
    DIR/manifest.jsonl        one line per frame: pose, seed, files, sizes, sha256 (manifest module)
    DIR/frames/000000.npz     per frame: polar, range_m, azimuth_deg and its labels (the total's
                              instance map, elevation maps, points, boxes); the component images
                              and per-component maps with labels="all", path-signature images
                              (and the components) with signatures=True
    DIR/frames/000000_polar.png, 000000_fan.png   with "png" in formats (far range at the top);
                              with ground truth and without "png", the one coco.json names
    DIR/coco.json             with ground truth: the objects' boxes in the frames' fan PNGs (or,
                              with coco="polar", polar PNGs; coco module)
    DIR/frames/000000_fan.txt, DIR/data.yaml, yolo-train.txt, yolo-val.txt   with "yolo" in
                              formats: YOLO labels beside the PNG coco.json names (yolo module)
    DIR/rosbag/               with rosbag="mcap" or "sqlite3": the ROS 2 bag (sonarsim.io.rosbag)
    DIR/sonarsim-run.json     the run's record (sonarsim.io.run_record)

Resuming. Started again on the same folder with the same scenario and options, ``generate``
keeps every frame whose manifest line verifies (the line's own checksum, the frame's spec, each
file's size and sha256, all read in full) and makes the others; a torn or damaged line, a
missing or changed file, is redone, never trusted. Frame files are written atomically
(temporary file and rename) before their manifest line, so a kill at any moment leaves complete
files or none. A folder made with another scenario or other options is refused before anything
is touched (its fingerprint, ``dataset.json``); asking for more frames of the same scenario
extends it. When all frames are done the manifest is rewritten in frame order, then
``coco.json`` and the bag are written from the finished frames (``rosbags`` cannot append, so a
resumed run writes the whole bag again). The NPZ files hold no timestamps (their zip entries
carry a fixed date), so the finished folder equals an uninterrupted run's bit for bit, whatever
the number of workers, except the run record. The bag too is the same, byte for byte: its
stamps start at a fixed time (``start_time``; by default
:data:`~sonarsim.io.rosbag.DEFAULT_START_TIME`) and follow the frames' times.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, SonarsimError, regular_file_bytes, shown
# One frame's options, files and bytes (the workers use them without importing this module);
# re-exported here, where they were defined before.
from .encoding import (  # noqa: F401
    _DYNAMIC_RANGE_DB,
    _STORED_ENTRIES,
    COCO_IMAGES,
    FORMATS,
    FRAMES_DIR,
    DatasetOptions,
    EncodedFrame,
    _annotations,
    _image_png,
    _png_bytes,
    _write_files,
    encode_frame,
    frame_files,
    npz_bytes,
)
from .frames import as_scenario, frame_memory_bytes, require_dataset_memory
from .manifest import (
    INFO_NAME,
    MANIFEST_NAME,
    Fingerprint,
    ManifestAppender,
    ManifestLines,
    frame_header,
    rewrite_manifest,
    scan_manifest,
    verify_record,
)
from .scenario import Scenario

__all__ = ["FORMATS", "DatasetOptions", "DatasetSummary", "EncodedFrame", "encode_frame", "frame_files",
           "generate", "npz_bytes"]

#: Name of the COCO file and of the bag folder inside a dataset folder.
COCO_NAME = "coco.json"
#: The YOLO files of a dataset folder with ``yolo`` in its formats (:mod:`sonarsim.dataset.yolo`).
YOLO_NAMES = ("data.yaml", "yolo-train.txt", "yolo-val.txt")
BAG_NAME = "rosbag"


@dataclass(frozen=True)
class DatasetSummary:
    """What :func:`generate` did.

    Attributes
    ----------
    out : Path
        The dataset folder.
    n_frames : int
        Frames in the dataset.
    rendered : int
        Frames made by this run.
    reused : int
        Frames of an earlier run that verified and were kept.
    seconds : float
        Wall time of this run.
    manifest : Path
    coco : Path or None
        ``coco.json`` (datasets with ground truth).
    rosbag : Path or None
        The bag folder.
    fingerprint : str
        The dataset's fingerprint (``dataset.json``).
    rosbag_start_ns : int or None
        The bag's first stamp, nanoseconds since 1970 (with a bag).
    shards : tuple of str
        The WebDataset shards' paths relative to ``out``, in order (with ``shards``).
    """

    out: Path
    n_frames: int
    rendered: int
    reused: int
    seconds: float
    manifest: Path
    coco: Path | None
    rosbag: Path | None
    fingerprint: str
    rosbag_start_ns: int | None = None
    shards: tuple[str, ...] = ()

    @property
    def frames_per_s(self) -> float:
        """Frames made by this run per second of wall time."""
        return self.rendered / self.seconds if self.seconds > 0 else 0.0


def _positive_int(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(key, f"must be a positive integer, got {shown(value)}")
    return int(value)


def _check_identity(info_path: Path, fingerprint: Fingerprint, n: int, out: Path) -> None:
    """Refuse a folder that holds another dataset (another scenario or other options)."""
    try:
        data = regular_file_bytes(info_path, "dataset description")
        if data is None:
            return
        doc = json.loads(data.decode("utf-8"))
    except (OSError, ValueError) as exc:
        raise SonarsimError(f"{info_path}: not a readable sonarsim dataset description ({exc}); this folder "
                            "holds something else: choose another --out or remove it") from None
    stored_n = doc.get("n_frames") if isinstance(doc, dict) else None
    stored = doc.get("fingerprint") if isinstance(doc, dict) else None
    if isinstance(stored_n, int) and stored == fingerprint.at(stored_n) and stored_n <= n:
        return  # the same dataset, or the same one asked for more frames
    what = "another dataset (made from another scenario or with other options"
    if isinstance(stored_n, int) and stored_n > n:
        what += f", or of {stored_n} frames where this run asks for {n}"
    raise SonarsimError(f"{out}: holds {what}: {INFO_NAME} differs); a dataset folder is resumed only with the "
                        "same scenario and options. Choose another --out, or remove it")


def _bag_frame(out: Path, record: Mapping[str, Any], stamp_ns: int) -> Any:
    """The bag frame of a finished frame, from its NPZ, stamped ``stamp_ns``."""
    from ..config.loader import parse_sonar_section
    from ..image.levels import default_fan_levels
    from ..image.result import SonarImage
    from ..io.output import read_npz
    from ..io.rosbag import frame_from_image

    arrays, config = read_npz(out / record["files"][0])
    sonar, pose = parse_sonar_section(config["sonar"], None)
    image = SonarImage(polar=arrays["polar"], range_m=arrays["range_m"], azimuth_deg=arrays["azimuth_deg"],
                       components={}, sonar=sonar, pose=pose, config=config)
    # 8-bit fan: what image viewers (rqt, Foxglove) show without a colour map; drawn as the
    # PNGs are (a device's counts, a render's dB).
    fan_u8 = default_fan_levels(image, dynamic_range_db=_DYNAMIC_RANGE_DB)
    points = {}
    if "points_world" in arrays and "points_object" in arrays:
        points = {"points_world": arrays["points_world"], "points_object": arrays["points_object"]}
    return frame_from_image(image, stamp_ns, fan=fan_u8, **points)


def _write_bag(out: Path, records: Iterable[Mapping[str, Any]], storage: str, stamps: Sequence[int],
               naming: tuple[Any, Any] | None = None) -> Path:
    """Write ``out/rosbag`` from the finished frames, in frame order, replacing an older bag.

    ``stamps``: each frame's stamp (:func:`~sonarsim.io.rosbag.frame_stamps` of the frames'
    times from the start time); ``naming``: its frame ids and topics
    (:func:`~sonarsim.io.rosbag.bag_naming`), default the defaults.
    """
    from ..io.output import temp_prefix
    from ..io.rosbag import BagWriter, remove_abandoned_bags

    remove_abandoned_bags(out)
    path = out / BAG_NAME
    if path.exists() or path.is_symlink():
        # Out of the final name first (one rename), then deleted: a kill meanwhile leaves a
        # hidden temporary folder that remove_abandoned_bags clears, never a half-deleted bag.
        old = Path(tempfile.mkdtemp(prefix=temp_prefix(BAG_NAME), suffix=".tmp", dir=out))
        os.rename(path, old / BAG_NAME) if path.is_dir() and not path.is_symlink() else os.unlink(path)
        shutil.rmtree(old, ignore_errors=True)
    frame_ids, topics = naming if naming is not None else (None, None)
    with BagWriter(path, storage=storage, frame_ids=frame_ids, topics=topics) as bag:
        for record, stamp in zip(records, stamps):
            bag.write_frame(_bag_frame(out, record, stamp))
    return path


def generate(
    scenario: Scenario | str | os.PathLike | Mapping,
    out: str | os.PathLike,
    frames: int | None = None,
    workers: int | None = None,
    formats: Iterable[str] = ("npz",),
    rosbag: str | None = None,
    labels: bool | str = "total",
    signatures: bool = False,
    coco: str = "fan",
    ghosts: bool = False,
    progress: bool = True,
    threads: int | None = None,
    batch_size: int | None = None,
    ray: str | None = None,
    command: Sequence[str] | None = None,
    log: Callable[[str], None] | None = None,
    on_frame: Callable[[int], None] | None = None,
    start_time: Any = None,
    frame_ids: Mapping[str, str] | None = None,
    topics: Mapping[str, str] | None = None,
    shards: int | None = None,
) -> DatasetSummary:
    """Render a scenario's frames into the dataset folder ``out`` (resumable; see the module docs).

    Parameters
    ----------
    scenario : Scenario, path or mapping
        A loaded scenario, or a scenario file or document (:func:`load_scenario`).
    out : path
        The dataset folder (created if missing).
    frames : int, optional
        Cap on the number of frames (``--frames N``); default all the scenario's.
    workers : int, optional
        Processes that render (1: this one), at most the cores and as many as the memory
        budget holds (:func:`~sonarsim.dataset.workers.cap_workers`; a cap is said in one line
        to ``log``); with ``ray``, Ray actors (default: the cluster's CPUs).
    formats : iterable of str
        :data:`FORMATS`: ``"npz"`` (always), ``"png"`` (polar and fan PNGs), ``"yolo"`` (YOLO
        labels and ``data.yaml``, :mod:`sonarsim.dataset.yolo`; needs ground truth).
    rosbag : {None, "mcap", "sqlite3"}
        Also write ``out/rosbag`` (needs the ``ros`` extra, :mod:`sonarsim.core.extras`): every frame's
        messages stamped ``start_time`` plus the frame's time after frame 0's.
    labels : bool or {"total", "all", "none"}
        What each frame's NPZ holds besides the device image (``polar``, ``range_m``,
        ``azimuth_deg``): the ground truth of issue 12's contract -- the total's instance map,
        the elevation maps, the points and the boxes (``"total"``, the default); also the
        component images and an instance map per component (``"all"``, ``True``); or nothing
        more (``"none"``, ``False``).
    signatures : bool
        Also store one image per path signature (:class:`DatasetOptions`).
    coco : {"fan", "polar"}
        With ground truth, the image of each frame that ``coco.json`` names and boxes:
        ``frames/NNNNNN_fan.png`` with the boxes in fan pixels (default), or
        ``frames/NNNNNN_polar.png`` with the boxes in polar pixels (a column per beam, the far
        range at the top). That PNG is written whether or not ``formats`` has ``"png"``. Boxes
        and masks are each object's direct echo (:mod:`sonarsim.dataset.coco`).
    ghosts : bool
        Also annotate each object's multipath ghosts in ``coco.json``, one annotation per path
        signature (categories ``<category>/<signature>``).
    progress : bool
        A progress bar on stderr (frames, rate, time left; needs ``tqdm``).
    threads : int, optional
        Ray-casting threads per worker; default the cores divided among the workers. The
        frames do not depend on it.
    batch_size : int, optional
        Frames per task sent to a worker.
    ray : str, optional
        Render on a Ray cluster instead of local processes: its address (``"auto"``,
        ``"ray://host:10001"``) or ``"local"`` (a new instance on this machine). Needs
        the ``ray`` extra (:mod:`sonarsim.core.extras`). The frames are the same as local ones.
    command : sequence of str, optional
        The command line, stored in the run record.
    log : callable, optional
        Receives one-line notes (default: ``sonarsim: ...`` on stderr).
    on_frame : callable, optional
        Called with each frame's index once its files and manifest line are written (in the
        order frames finish): progress for callers that show their own.
    start_time : str, float, int or datetime, optional
        The bag's first stamp (:func:`~sonarsim.io.rosbag.parse_start_time`: ISO 8601 or
        seconds since 1970); default the scenario's ``start_time``, else
        :data:`~sonarsim.io.rosbag.DEFAULT_START_TIME` (2000-01-01T00:00:00Z). It shapes the
        bag alone, not the frames or the fingerprint: the bag is written anew at the end of
        every run, so a run with another start time re-stamps it.
    shards : int, optional
        Also pack the frames into WebDataset tar shards of this many frames (``shards/``,
        ``shards.jsonl``; :mod:`sonarsim.dataset.shards`), each written when its last frame
        is done; not part of the fingerprint (another size rewrites the shards, not the frames).
    frame_ids, topics : mapping of str to str, optional
        The bag's frame names (``world``, ``sonar``, ``image``) and topics (``image``, ``fan``,
        ``pose``, ``tf``, ``points``), replacing the scenario's ``rosbag`` section name by name
        (:func:`~sonarsim.io.rosbag.bag_naming`); like ``start_time``, they shape the bag alone.

    Returns
    -------
    DatasetSummary

    Raises
    ------
    ConfigError
        Bad options (naming the key).
    SonarsimError
        An unwritable folder, a full disk (no half-written frame is left; run again to
        resume), a folder that holds another dataset, or ``rosbags`` missing for a bag.
        A bad ``start_time``, or one from which the last frame's stamp is past 2038-01-19
        (ROS 2 stamps hold int32 seconds), is a ``ConfigError`` naming ``start_time``.
    """
    from ..io.output import atomic_write, remove_abandoned_temp_files
    from ..io.run_record import OutputRun
    from .coco import scenario_categories, write_coco
    from .shards import SHARD_INDEX, ShardWriter, remove_shards
    from .workers import encoded_frames, encoded_frames_ray

    t_start = time.perf_counter()
    if workers is not None:
        workers = _positive_int(workers, "workers")
    if ray is not None:
        if not isinstance(ray, str) or not ray:
            raise ConfigError("ray", f"must be a cluster address, 'auto' or 'local', got {shown(ray)}")
        from .workers import _import_ray

        _import_ray()  # a missing extra fails now, not after the folder was prepared
    if threads is not None:
        threads = _positive_int(threads, "threads")
    if batch_size is not None:
        batch_size = _positive_int(batch_size, "batch_size")
    if shards is not None:
        from .shards import check_shard_frames

        shards = check_shard_frames(shards)
    options = DatasetOptions(labels=labels, formats=tuple(formats), rosbag=rosbag, signatures=signatures,
                             coco=coco, ghosts=ghosts)
    if options.rosbag is not None:
        from ..io.rosbag import _import_rosbags

        _import_rosbags()  # a missing extra fails now, not after hours of rendering
    scenario = as_scenario(scenario, frames)
    require_dataset_memory(scenario, options.labels)  # before the folder is touched
    n = scenario.n_frames
    width = max(6, len(str(n - 1)))
    out = Path(out)
    say = log or (lambda msg: print(f"sonarsim: {msg}", file=sys.stderr, flush=True))
    if workers is not None and workers > 1 and ray is None:
        # Local processes: no more than the cores run at once, nor than the budget holds
        # (a process per frame for --workers 1000 would pass any memory).
        from .workers import cap_workers

        workers, note = cap_workers(workers, frame_memory_bytes(scenario, options.labels))
        if note:
            say(note)

    stamps = None
    if options.rosbag is not None:
        # Before anything is rendered: a start time whose last frame a ROS 2 stamp cannot hold
        # fails now, not after hours of rendering.
        from ..io.rosbag import DEFAULT_START_NS, frame_stamps, parse_start_time

        if start_time is not None:
            start_ns, source = parse_start_time(start_time, "start_time"), None
        else:
            start_ns = scenario.start_time_ns if scenario.start_time_ns is not None else DEFAULT_START_NS
            source = scenario.source if scenario.start_time_ns is not None else None
        try:
            stamps = frame_stamps(start_ns, [scenario.trajectory.time_s(k) for k in range(n)], "start_time")
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.detail, source) from None
        from ..io.rosbag import bag_naming

        try:
            naming = bag_naming(scenario.rosbag, "rosbag", frame_ids=frame_ids, topics=topics)
        except ConfigError as exc:
            raise ConfigError(exc.key, exc.detail, scenario.source if scenario.rosbag else None) from None

    # Every frame's spec digest: the fingerprint, and what each manifest line must match.
    fingerprint = Fingerprint(options.document())
    # (and the header of its manifest line: what each line must match to be kept).
    expected = []
    classes: dict[str, None] = {}  # the class table of coco.json and the YOLO labels
    for spec in scenario.frame_specs():
        expected.append(frame_header(spec, frame_files(spec.index, width, options)))
        fingerprint.add(expected[-1]["spec_sha256"])
        classes.update(dict.fromkeys(scenario_categories([spec])))
    from ..io.codec import ENCODER

    options = replace(options, classes=tuple(classes), encoder=ENCODER)

    names = [INFO_NAME, MANIFEST_NAME] + ([COCO_NAME] if options.labels != "none" else [])
    names += list(YOLO_NAMES) if "yolo" in options.formats else []
    names += [SHARD_INDEX] if shards else []
    run = OutputRun.for_folder(out, names, command=command, log=say)
    _check_identity(out / INFO_NAME, fingerprint, n, out)
    with run:
        frames_dir = out / FRAMES_DIR
        try:
            frames_dir.mkdir(exist_ok=True)
        except OSError as exc:
            raise SonarsimError(f"{frames_dir}: cannot create: {exc.strerror or exc}") from None
        remove_abandoned_temp_files(frames_dir)
        info = {"sonarsim_dataset": 1, "fingerprint": fingerprint.value, "n_frames": n,
                "options": options.document(), "scenario": scenario.source, "description": scenario.description,
                "seed": scenario.seed}
        with atomic_write(out / INFO_NAME, "w", fsync=True) as handle:
            handle.write(json.dumps(info, indent=1, sort_keys=True) + "\n")

        # Trust nothing: each line is checked (seal, spec, every file read and hashed).
        # Records are not held: where each line lies is (ManifestLines), a few integers a frame
        # where records would take 60 kB each (6 GB for 100,000 frames).
        manifest_path = out / MANIFEST_NAME
        found = ManifestLines(manifest_path)
        for offset, length, record in scan_manifest(manifest_path):
            k = record.get("frame") if isinstance(record, dict) else None
            if isinstance(k, int) and not isinstance(k, bool) and 0 <= k < n and k not in found and verify_record(
                    record, out, expected[k]):
                found.at[k] = (offset, length)
        # Only verified lines stay (a torn or damaged line would confuse readers meanwhile).
        lines = rewrite_manifest(manifest_path, found, sorted(found.at))
        n_kept = len(lines)
        todo = [k for k in range(n) if k not in lines]
        if n_kept:
            say(f"{out}: {n_kept} of {n} frames verified and kept; making {len(todo)}")

        bar = _progress_bar(n, n_kept, progress)
        packer = ShardWriter(out, n, shards, lines) if shards else None
        try:
            with ManifestAppender(manifest_path) as manifest:
                if not todo:
                    produced = iter(())
                elif ray is not None:
                    produced = encoded_frames_ray(scenario, todo, options, width, ray, workers, threads, batch_size)
                else:
                    produced = encoded_frames(scenario, todo, options, width, workers or 1, threads, batch_size,
                                              out=out)
                for encoded in produced:
                    # Files first (here, or by the worker that made them, before it sent the
                    # record): a line always names complete files.
                    _write_files(out, encoded)
                    lines.at[encoded.index] = manifest.append(encoded.record)
                    if packer is not None:
                        packer.add(encoded.index)
                    bar.update(1)
                    if on_frame is not None:
                        on_frame(encoded.index)
        finally:
            bar.close()
        lines = rewrite_manifest(manifest_path, lines, range(n))  # in frame order
        if packer is not None:
            packer.lines_of = lines
        shard_names = tuple(packer.finish()) if packer is not None else ()
        if packer is None and remove_shards(out):
            say(f"{out}: removed the shards of an earlier run (this one was asked for none; --shards N makes them)")
        coco_path = None
        if options.labels != "none":
            # Streamed, a frame at a time (coco.json of 100,000 frames: half a GB).
            coco_path = out / COCO_NAME
            with atomic_write(coco_path, "w") as handle:
                write_coco(handle, lambda: lines.records(range(n)), image=options.coco, categories=options.classes)
        if "yolo" in options.formats:
            _write_yolo(out, n, width, options)
        bag_path = (_write_bag(out, lines.records(range(n)), options.rosbag, stamps, naming)
                    if options.rosbag else None)
    return DatasetSummary(out, n, len(todo), n_kept, time.perf_counter() - t_start, manifest_path,
                          coco_path, bag_path, fingerprint.value, stamps[0] if stamps else None, shard_names)


class _NoBar:
    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _write_yolo(out: Path, n: int, width: int, options: DatasetOptions) -> None:
    """``data.yaml`` and its image lists (the label files are the frames')."""
    from ..io.output import atomic_write
    from .yolo import data_yaml, image_lists

    train, val = image_lists([frame_files(k, width, options) for k in range(n)], options.coco)
    for name, text in zip(YOLO_NAMES, (data_yaml(options.classes), train, val)):
        with atomic_write(out / name, "w") as handle:
            handle.write(text)


def _progress_bar(total: int, done: int, enabled: bool) -> Any:
    """A tqdm bar on stderr (frames, rate, time left), or one that shows nothing."""
    if not enabled:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        return _NoBar()
    return tqdm(total=total, initial=done, unit="frame", file=sys.stderr, dynamic_ncols=True,
                desc="sonarsim dataset", smoothing=0.1)
