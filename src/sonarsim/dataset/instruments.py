"""Datasets of every instrument of a scene (side-scan, scanning, single-beam, multibeam, FLS):
each instrument's films cut into chunks of pings, with their ground truth, a picture for people,
a manifest, and optionally one ROS 2 bag of them all.

:func:`write_instrument_dataset` writes into ``out``::

    NAME/000000.npz         chunk 0 of instrument NAME: pings [0, chunk) of its film
    NAME/000000.png         the chunk as people look at it (dB, 8-bit)
    NAME/000000_labels.png  side-scan only: the labels as grey levels (below)
    manifest.jsonl          one sealed line per chunk, sorted by instrument then chunk
    coco.json               side-scan: the objects' boxes and masks on the chunks' PNGs
    dataset.json            what made it: scene digest, seed, pings, chunk, instruments
    rosbag/                 optional (``rosbag="mcap"``): every chunk's pings, in time order

Per chunk, the NPZ holds the film's arrays (``config`` says which film):

* side-scan (:class:`~sonarsim.image.films.Waterfall`): ``samples`` ``(n, 2, n_samples)``
  float32, ``slant_range_m``, ``geometry/<field>``, and its labels ``labels/instance`` (int32,
  the id of ``config["ids"]`` bringing the most energy to each sample, -1 none),
  ``labels/shadow`` (bool: the floor hidden behind an object) and ``labels/boxes`` (int32
  ``(n_ids, 2, 4)``: per id and side ``[ping_min, sample_min, ping_max, sample_max]`` in the
  chunk's own pings, -1 where the id dominates none); the PNG is the waterfall (port far to
  near, starboard near to far, the chunk's first ping at the top), the labels PNG laid out
  alike: 0 nothing, 64 shadow, 128 a plane (the floor), ``255 - 12 (id mod 8)`` an object;
* scanning (:class:`~sonarsim.instruments.scanning.ScanImage`): ``samples`` ``(n_samples,
  n_steps)``, ``angle_deg``, ``range_m``, ``geometry/<field>``; PNG one row per step;
* single-beam (:class:`~sonarsim.image.films.Envelope`): ``samples`` ``(n, n_samples)``,
  ``range_m``, ``bottom_range_m``, ``geometry/<field>``; PNG one row per ping;
* multibeam (:class:`~sonarsim.image.films.Soundings`): ``angle_deg``, ``two_way_time_s``,
  ``intensity``, ``range_m`` ``(n, n_beams)``, ``water_column``, ``points_m`` (the truth) when
  the film has them; PNG the intensity, one row per ping;
* FLS: one NPZ per ping (``chunk`` is 1 for it), :func:`sonarsim.dataset.frames.frame_arrays`
  of the frame (the polar image, its instance map, points, boxes), PNG the polar image.

Manifest lines: ``instrument``, ``type``, ``chunk``, ``first_ping``, ``n_pings``, ``time_s``
(first and last ping), ``seed``, ``files``, their ``bytes`` and ``sha256``, for a side-scan
``image_shape`` (the PNG's ``[height, width]``) and ``boxes`` (per object and side it dominates:
``{"id", "name", "side", "box", "display", "segmentation", "area"}``, :func:`_boxes`), and ``check``
(:func:`~sonarsim.dataset.manifest.seal_record`).

Resuming: ``dataset.json`` is written first; each chunk's files are written (atomically) before
its manifest line is appended; a run in a folder of the same dataset keeps every chunk whose
line verifies (sealed, this chunk's header, every file's size and sha256) and makes the others
(a killed run's, a damaged or missing file's); the manifest is rewritten in order at the end, so
a resumed dataset is byte-identical to an uninterrupted one. A folder of another dataset is
refused.

Seeding: ping ``k`` of an instrument draws from ``(seed, k)`` whoever renders it (the chunk
is rendered with ``render_pings(first_ping=a)``; a side-scan's side ``s`` from ``(seed, 2k +
s)``), and the vehicle's poses and times are computed once for the whole run, so the files are
the same bytes whatever the number of workers, the order chunks finish in, and (per ping) the
chunk size.
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, shown

__all__ = ["InstrumentDatasetSummary", "chunk_arrays", "has_instruments", "sidescan_coco", "write_instrument_dataset",
           "write_scenario_instruments"]

_DYNAMIC_RANGE_DB = 60.0
_SHADOW_GREY = 64
_PLANE_GREY = 128


@dataclass(frozen=True)
class InstrumentDatasetSummary:
    """What :func:`write_instrument_dataset` wrote.

    Attributes
    ----------
    out : pathlib.Path
    records : tuple of dict
        The manifest's lines, in order.
    pings : dict of str to int
        Pings per instrument.
    bag : pathlib.Path or None
    rendered, kept : int
        Chunks made by this run, and kept from an earlier one (their files verified).
    """

    out: Path
    records: tuple
    pings: dict
    bag: Path | None = None
    rendered: int = 0
    kept: int = 0


def _scene_of(scene: Any, seed: int | None):
    """``(Scene, seed)``: the scene (a path, a document, a Scene) with ``render.seed = seed``."""
    from ..config.loader import load_scene

    s = load_scene(scene)
    if seed is None:
        return s, int(s.render.seed)
    from .scenario import MAX_SEED

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) <= MAX_SEED:
        raise ConfigError("seed", f"must be an integer in [0, 2**128), got {shown(seed)}")
    return dataclasses.replace(s, render=dataclasses.replace(s.render, seed=int(seed))), int(seed)


def _per_instrument(value: Any, names: list[str], key: str, default: Any = None) -> dict:
    if isinstance(value, Mapping):
        unknown = [k for k in value if k not in names]
        if unknown:
            raise ConfigError(f"{key}.{unknown[0]}", f"no such instrument; the scene has: {', '.join(names)}")
        return {n: value.get(n, default) for n in names}
    return {n: value if value is not None else default for n in names}


def _positive(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(key, f"must be a positive integer, got {shown(value)}")
    return int(value)


def _png(image: np.ndarray) -> bytes:
    from ..image.levels import to_uint8
    from .encoding import _png_bytes

    finite = np.nan_to_num(np.asarray(image, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return _png_bytes(to_uint8(finite, "db", 0.0, _DYNAMIC_RANGE_DB))


def chunk_arrays(film: Any, kind: str) -> tuple[dict, dict]:
    """A chunk's film as NPZ arrays and a JSON-able config (see the module's notes)."""
    geo = {f"geometry/{k}": v for k, v in film.geometry.as_dict().items()} if hasattr(film, "geometry") else {}
    if kind == "sidescan":
        return film.arrays(), film.config()
    if kind == "scanning":
        return ({"samples": film.samples, "angle_deg": film.angle_deg, "range_m": film.range_m, **geo},
                {"film": "scan", "range_min_m": film.range_min_m, "range_max_m": film.range_max_m,
                 "step_deg": film.step_deg, "source": film.source, "unit": film.unit_name})
    if kind == "singlebeam":
        return ({"samples": film.samples, "range_m": film.range_m, "bottom_range_m": film.bottom_range_m, **geo},
                {"film": "envelope", "range_min_m": film.range_min_m, "range_max_m": film.range_max_m,
                 "source": film.source, "unit": film.unit_name})
    if kind == "multibeam":
        arrays = {"angle_deg": film.angle_deg, "two_way_time_s": film.two_way_time_s, "intensity": film.intensity,
                  "range_m": film.range_m, **geo}
        if film.water_column is not None:
            arrays["water_column"] = film.water_column
        if film.points_m is not None:
            arrays["points_m"] = film.points_m
        return arrays, {"film": "soundings", "source": film.source, "unit": film.unit_name}
    raise ConfigError("instrument.type", f"no dataset layout for a {kind} film")


def _pictures(film: Any, kind: str, n_objects: int = 0) -> dict[str, bytes]:
    """The chunk's PNGs, by suffix."""
    from .encoding import _png_bytes

    if kind == "sidescan":
        out = {".png": _png(film.display())}
        if film.labels is not None:
            inst = film.display(film.labels["instance"])
            shadow = film.display(film.labels["shadow"])
            # Objects bright (255, 243, ... for ids 0, 1, ..., repeating after 8), planes mid grey,
            # shadow dark: what people look for stands out from the floor it lies on.
            obj = inst < n_objects
            grey = np.where(inst < 0, np.where(shadow, _SHADOW_GREY, 0),
                            np.where(obj, 255 - 12 * np.mod(inst, 8), _PLANE_GREY))
            out["_labels.png"] = _png_bytes(grey.astype(np.uint8))
        return out
    if kind == "scanning":
        return {".png": _png(film.samples.T)}
    if kind == "singlebeam":
        return {".png": _png(film.samples)}
    return {".png": _png(film.intensity)}


def _boxes(film: Any, n_objects: int) -> list[dict]:
    """Per object (not the planes) and side it dominates: its box in the chunk's samples
    (``box``: ``[ping_min, sample_min, ping_max, sample_max]``) and in the chunk's PNG
    (``display``: ``[row_min, col_min, row_max, col_max]``, port mirrored left of nadir), its
    pixels there as COCO's uncompressed RLE (``segmentation``) and their count (``area``)."""
    from .coco import rle

    if film.labels is None:
        return []
    boxes = film.labels["boxes"]
    n = film.n_samples
    disp = film.display(film.labels["instance"])
    out = []
    for i in range(min(n_objects, boxes.shape[0])):
        for side, side_name in enumerate(("port", "starboard")):
            p0, s0, p1, s1 = (int(v) for v in boxes[i, side])
            if p0 < 0:
                continue
            display = [p0, n - 1 - s1, p1, n - 1 - s0] if side == 0 else [p0, n + s0, p1, n + s1]
            half = np.full_like(disp, -1)
            cols = slice(0, n) if side == 0 else slice(n, 2 * n)
            half[:, cols] = disp[:, cols]
            segmentation, area = rle(half, i, display)
            out.append({"id": i, "name": film.ids[i], "side": side_name, "box": [p0, s0, p1, s1],
                        "display": display, "segmentation": segmentation, "area": area})
    return out


def sidescan_coco(records: list[dict]) -> dict:
    """The COCO document of a dataset's side-scan chunks: one image per chunk (its PNG, ``id``
    its place among them), one annotation per object and side (``bbox`` ``[x, y, w, h]`` in the
    PNG's pixels, x the column, y the ping; ``segmentation``, ``area``), one category per object
    kind (:func:`~sonarsim.dataset.coco.category_of`). The labels are the total's: the object
    bringing the most energy to a sample, multipath included."""
    from .coco import category_of

    images, annotations, categories = [], [], {}
    for r in records:
        if r.get("type") != "sidescan":
            continue
        k = len(images)
        height, width = r["image_shape"]
        images.append({"id": k, "file_name": r["files"][1], "height": height, "width": width,
                       "instrument": r["instrument"], "chunk": r["chunk"], "first_ping": r["first_ping"],
                       "time_s": r["time_s"]})
        for b in r.get("boxes", []):
            cid = categories.setdefault(category_of(b["name"]), len(categories) + 1)
            r0, c0, r1, c1 = b["display"]
            annotations.append({"id": len(annotations) + 1, "image_id": k, "category_id": cid,
                                "bbox": [c0, r0, c1 - c0 + 1, r1 - r0 + 1], "area": b["area"],
                                "segmentation": b["segmentation"], "iscrowd": 0, "object": b["name"],
                                "side": b["side"]})
    return {"info": {"description": "sonarsim: objects in side-scan waterfall chunks (the total's labels)",
                     "version": "1"},
            "images": images, "annotations": annotations,
            "categories": [{"id": cid, "name": name, "supercategory": "object"} for name, cid in categories.items()]}


# One chunk (in this process or a worker) --------------------------------------------------

_WORKER: dict[str, Any] = {}


def _simulator(scene: Any, backend: str | None):
    from ..renderer.simulator import Simulator

    key = id(scene)
    if _WORKER.get("key") != key:
        if _WORKER.get("sim") is not None:
            _WORKER["sim"].close()
        _WORKER["sim"] = Simulator(scene, backend=backend) if backend else Simulator(scene)
        _WORKER["key"] = key
    return _WORKER["sim"]


def _render_chunk(scene: Any, backend: str | None, name: str, kind: str, a: int, poses: list, times: np.ndarray,
                  chunk_index: int) -> tuple[dict[str, bytes], dict]:
    """Render pings ``[a, a + len(poses))`` of ``name`` and encode them: ``(files, record)``."""
    from ..instruments import render_pings
    from .encoding import _image_png, npz_bytes
    from .frames import frame_arrays

    sim = _simulator(scene, backend)
    stem = f"{name}/{chunk_index:06d}"
    labels = kind in ("sidescan", "fls")
    film = render_pings(sim, name, poses=poses, times_s=times, first_ping=a,
                        labels="total" if kind == "fls" else labels)
    files: dict[str, bytes] = {}
    record: dict[str, Any] = {"instrument": name, "type": kind, "chunk": chunk_index, "first_ping": a,
                              "n_pings": len(poses), "time_s": [float(times[0]), float(times[-1])]}
    if kind == "fls":
        image = film[0]
        files[f"{stem}.npz"] = npz_bytes(frame_arrays(image, components=False), {"film": "polar", **_jsonable(
            image.config)})
        files[f"{stem}.png"] = _image_png(image, "polar")
    else:
        arrays, config = chunk_arrays(film, kind)
        files[f"{stem}.npz"] = npz_bytes(arrays, config)
        for suffix, data in _pictures(film, kind, len(sim.scene.objects)).items():
            files[f"{stem}{suffix}"] = data
        if kind == "sidescan":
            record["boxes"] = _boxes(film, len(sim.scene.objects))
            record["image_shape"] = [film.n_pings, 2 * film.n_samples]
    return files, record


def _jsonable(config: Any) -> dict:
    try:
        return json.loads(json.dumps(config, default=str)) if isinstance(config, Mapping) else {}
    except (TypeError, ValueError):
        return {}


def _init_worker(scene: Any, backend: str | None) -> None:
    _WORKER["scene"] = scene
    _WORKER["backend"] = backend


def _worker_task(args: tuple) -> tuple[dict[str, bytes], dict]:
    return _render_chunk(_WORKER["scene"], _WORKER["backend"], *args)


# The dataset ------------------------------------------------------------------------------


def write_instrument_dataset(
    scene: Any,
    out: str | os.PathLike,
    n_pings: int | Mapping[str, int] | None = None,
    chunk: int | Mapping[str, int] = 64,
    seed: int | None = None,
    *,
    instruments: list[str] | None = None,
    trajectory: Any = None,
    workers: int = 1,
    rosbag: str | None = None,
    start_ns: int | None = None,
    backend: str | None = None,
) -> InstrumentDatasetSummary:
    """Render every instrument of ``scene`` (or ``instruments``) into a dataset folder.

    Parameters
    ----------
    scene : str, os.PathLike, mapping or Scene
        A scene file, document or :class:`~sonarsim.Scene` with ``instruments``.
    out : str or os.PathLike
        The dataset folder (created; a folder of the same dataset is resumed, one of another
        refused).
    n_pings : int or mapping of str to int, optional
        Pings per instrument (one number for all, or per name). Default: with a
        ``trajectory``, its span at each instrument's ping period; otherwise required.
    chunk : int or mapping of str to int
        Pings per file: a side-scan's waterfall chunk, a scanning sonar's steps, single-beam or
        multibeam pings. An FLS always writes one ping per file.
    seed : int, optional
        The renderer's seed (``render.seed``); default the scene's. Ping ``k`` draws from
        ``(seed, k)``.
    instruments : list of str, optional
        Which instruments (default all).
    trajectory : sonarsim.dataset.trajectory.Trajectory, optional
        The VEHICLE's timestamped poses (each ping interpolated at its time); default the
        scene's vehicle pose (running ahead at ``vehicle.speed_m_s``).
    workers : int
        Processes rendering chunks (1: this process). The files do not depend on it.
    rosbag : {"mcap", "sqlite3"}, optional
        Also write ``out/rosbag`` (:func:`sonarsim.io.rosbag_instruments.write_instrument_bag`).
    start_ns : int, optional
        The bag's stamp of the earliest ping (default 2000-01-01T00:00:00Z).
    backend : str, optional
        The ray caster (``Simulator(backend=...)``).

    Returns
    -------
    InstrumentDatasetSummary

    Raises
    ------
    ConfigError
        An unknown instrument, a count or chunk that is not a positive integer, no ``n_pings``
        without a trajectory, ``rosbag`` not a storage.
    """
    from ..config.instruments import FlsSpec
    from ..core.memory import require
    from ..instruments import vehicle_poses
    from ..io.output import atomic_write
    from .manifest import ManifestAppender, read_manifest, seal_record, verify_record, write_manifest

    sc, seed = _scene_of(scene, seed)
    specs = sc.instruments or (FlsSpec(name="sonar", sonar=sc.sonar),)
    names = [s.name for s in specs]
    chosen = names if instruments is None else list(instruments)
    for n in chosen:
        if n not in names:
            raise ConfigError("instruments", f"no instrument {shown(n)} in the scene; it has: {', '.join(names)}")
    spec_of = {s.name: s for s in specs}
    counts = _per_instrument(n_pings, chosen, "n_pings")
    chunks = _per_instrument(chunk, chosen, "chunk", 64)
    workers = _positive(workers, "workers")
    if rosbag is not None and rosbag not in ("mcap", "sqlite3"):
        raise ConfigError("rosbag", f"must be mcap or sqlite3, got {shown(rosbag)}")
    sim_like = type("_SceneOnly", (), {"scene": sc})()
    plan: list[tuple] = []  # (name, kind, a, poses, times, chunk index)
    all_poses: dict[str, list] = {}
    all_times: dict[str, np.ndarray] = {}
    for name in chosen:
        spec = spec_of[name]
        if counts[name] is None and trajectory is None:
            raise ConfigError(f"n_pings.{name}", "give the number of pings (there is no trajectory to span)")
        n = None if counts[name] is None else _positive(counts[name], f"n_pings.{name}")
        size = 1 if spec.type_name == "fls" else _positive(chunks[name], f"chunk.{name}")
        poses, times = vehicle_poses(sim_like, spec, n, trajectory)
        require(len(poses) * 200, f"the poses of {len(poses)} pings of {name}", "n_pings")
        all_poses[name], all_times[name] = poses, times
        for c, a in enumerate(range(0, len(poses), size)):
            plan.append((name, spec.type_name, a, poses[a:a + size], times[a:a + size], c))

    out = Path(out)
    info = {"scene_sha256": hashlib.sha256(json.dumps(sc.to_dict(), sort_keys=True, default=str).encode()).hexdigest(),
            "seed": seed, "instruments": {n: {"type": spec_of[n].type_name, "pings": len(all_poses[n]),
                                              "chunk": 1 if spec_of[n].type_name == "fls" else chunks[n]}
                                          for n in chosen},
            "trajectory": None if trajectory is None else _trajectory_digest(trajectory)}
    _check_folder(out, info)
    out.mkdir(parents=True, exist_ok=True)
    for name in chosen:
        (out / name).mkdir(exist_ok=True)
    # The identity first: a run killed later leaves a folder that only this dataset resumes.
    with atomic_write(out / "dataset.json", "w", fsync=True) as fh:
        fh.write(json.dumps(info, indent=2, sort_keys=True) + "\n")

    def header(t: tuple) -> dict:
        """What a chunk's manifest line must say before its checksums (to verify a kept one)."""
        name, kind, a, poses, times, c = t
        return {"instrument": name, "type": kind, "chunk": c, "first_ping": a, "n_pings": len(poses),
                "time_s": [float(times[0]), float(times[-1])], "seed": seed, "files": _chunk_files(name, kind, c)}

    def write_files(files: dict[str, bytes], record: dict) -> dict:
        for rel, data in files.items():
            with atomic_write(out / rel) as fh:
                fh.write(data)
        record = {**record, "seed": seed, "files": list(files),
                  "bytes": {rel: len(data) for rel, data in files.items()},
                  "sha256": {rel: hashlib.sha256(data).hexdigest() for rel, data in files.items()}}
        return seal_record(record)

    # Resume: the chunks whose manifest lines verify (sealed, this chunk's, files intact) are kept.
    manifest = out / "manifest.jsonl"
    tasks = [tuple(t) for t in plan]
    wanted = {(t[0], t[5]): header(t) for t in tasks}
    records: dict[tuple[str, int], dict] = {}
    for r in read_manifest(manifest):
        key = (r.get("instrument"), r.get("chunk")) if isinstance(r, dict) else None
        if key in wanted and key not in records and verify_record(r, out, wanted[key]):
            records[key] = r
    kept = len(records)
    write_manifest(manifest, [records[k] for k in sorted(records, key=lambda k: (chosen.index(k[0]), k[1]))])
    tasks = [t for t in tasks if (t[0], t[5]) not in records]
    with ManifestAppender(manifest) as appender:
        def commit(key: tuple, files: dict[str, bytes], record: dict) -> None:
            records[key] = write_files(files, record)
            appender.append(records[key])  # after its files: a line always names finished files

        if workers == 1 or len(tasks) <= 1:
            for t in tasks:
                commit((t[0], t[5]), *_render_chunk(sc, backend, *t))
        else:
            from .workers import worker_context

            try:
                with cf.ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=worker_context(),
                                            initializer=_init_worker, initargs=(sc, backend)) as pool:
                    futures = {pool.submit(_worker_task, t): (t[0], t[5]) for t in tasks}
                    for fut in cf.as_completed(futures):
                        commit(futures[fut], *fut.result())
            except cf.process.BrokenProcessPool:
                from ..errors import SonarsimError

                raise SonarsimError("a worker process died (killed, or out of memory: try fewer workers; from "
                                    "Python, call with workers > 1 from a script file under `if __name__ == "
                                    "'__main__':`, which worker processes import); the chunks written so far are "
                                    "kept: run again to resume") from None
    if _WORKER.get("sim") is not None and workers == 1:
        _WORKER["sim"].close()
        _WORKER.clear()

    # In instrument then chunk order: the same file whatever the workers and the resumes.
    ordered = [records[k] for k in sorted(records, key=lambda k: (chosen.index(k[0]), k[1]))]
    write_manifest(manifest, ordered)
    if any(r["type"] == "sidescan" for r in ordered):
        with atomic_write(out / "coco.json", "w") as fh:
            json.dump(sidescan_coco(ordered), fh, sort_keys=True, separators=(",", ":"))

    bag = None
    if rosbag is not None:
        bag = _write_bag(out, sc, chosen, spec_of, ordered, all_poses, all_times, rosbag, start_ns)
    return InstrumentDatasetSummary(out, tuple(ordered), {n: len(all_poses[n]) for n in chosen}, bag,
                                    rendered=len(ordered) - kept, kept=kept)


def _chunk_files(name: str, kind: str, c: int) -> list[str]:
    """A chunk's files, in manifest order."""
    stem = f"{name}/{c:06d}"
    return [f"{stem}.npz", f"{stem}.png"] + ([f"{stem}_labels.png"] if kind == "sidescan" else [])


def _trajectory_digest(trajectory: Any) -> str:
    h = hashlib.sha256()
    for name in ("times_s", "positions_m", "quats_xyzw"):
        h.update(np.ascontiguousarray(getattr(trajectory, name), np.float64).tobytes())
    return h.hexdigest()


def _check_folder(out: Path, info: dict) -> None:
    """Refuse a folder that holds another dataset (its ``dataset.json`` says another scene,
    seed, trajectory, instruments, pings or chunks: an FLS dataset's too); the same one is
    rewritten, to the same bytes."""
    path = out / "dataset.json"
    if not path.is_file():
        return
    try:
        old = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        old = None
    if old != json.loads(json.dumps(info)):
        raise ConfigError("out", f"{out} holds another dataset (its dataset.json differs: another scene, seed, "
                          "trajectory, pings or chunk); choose another folder or remove it")


def has_instruments(scene_doc: Any) -> bool:
    """Whether a scene document's instruments include a type other than the FLS (those datasets
    are written by :func:`write_scenario_instruments`; an FLS alone by ``generate``)."""
    if not isinstance(scene_doc, Mapping):
        return False
    items = scene_doc.get("instruments")
    sonar = scene_doc.get("sonar")
    types = [i.get("type", "fls") for i in items if isinstance(i, Mapping)] if isinstance(items, list) else []
    if isinstance(sonar, Mapping):
        types.append(sonar.get("type", "fls"))
    return any(t != "fls" for t in types)


def write_scenario_instruments(scenario: Any, out: str | os.PathLike, *, chunk: int | Mapping[str, int] = 64,
                               workers: int | None = None, rosbag: str | None = None, start_ns: int | None = None,
                               backend: str | None = None) -> InstrumentDatasetSummary:
    """A scenario whose scene has instruments, as :func:`write_instrument_dataset` writes it.

    The scenario's trajectory is the VEHICLE's; every instrument pings at its own period over
    the trajectory's span (its first ``max_frames`` poses when capped: ``--frames N``). Its
    ``seed`` is the renderer's; its ``start_time`` the bag's first stamp.

    Raises
    ------
    ConfigError
        ``variation`` (a new scene per frame: an instrument's film is one scene's) or a random
        trajectory (poses without a track).
    """
    from ..config.loader import scene_from_dict
    from .trajectory import Trajectory

    if scenario.variation.objects or scenario.variation.ground or scenario.variation.planes \
            or scenario.variation.sensor:
        raise ConfigError("variation", "a scene with instruments is rendered as one scene along the trajectory "
                          "(a film of pings); a variation per frame is not supported for it")
    traj = scenario.trajectory
    if not isinstance(traj, Trajectory):
        raise ConfigError("trajectory", "a scene with instruments needs a track (a file, an orbit or a lawnmower): "
                          "random poses make no film of pings")
    if scenario.max_frames is not None and scenario.max_frames < traj.n_frames:
        k = scenario.max_frames
        traj = Trajectory(traj.times_s[:k], traj.positions_m[:k], traj.quats_xyzw[:k],
                          None if traj.rpy_deg is None else traj.rpy_deg[:k])
    scene = scene_from_dict(scenario.scene, base_dir=scenario.base_dir, source=scenario.source)
    return write_instrument_dataset(scene, out, None, chunk, scenario.seed, trajectory=traj, workers=workers or 1,
                                    rosbag=rosbag, start_ns=start_ns if start_ns is not None else
                                    scenario.start_time_ns, backend=backend)


def _write_bag(out: Path, sc: Any, chosen: list[str], spec_of: dict, records: list[dict], poses: dict, times: dict,
               storage: str, start_ns: int | None) -> Path:
    """The bag of every chunk, read back from the NPZ files just written."""
    import shutil

    from ..io import rosbag as rb
    from ..io.output import read_npz
    from ..io.rosbag_instruments import write_instrument_bag

    films: dict[str, Any] = {}
    for name in chosen:
        kind = spec_of[name].type_name
        if kind == "fls":
            continue  # the FLS's own bag: sonarsim dataset (its frames are polar images)
        parts = [read_npz(out / r["files"][0]) for r in records if r["instrument"] == name]
        films[name] = _film_from_npz(kind, parts)
    path = out / "rosbag"
    if path.exists():
        shutil.rmtree(path)
    if not films:
        return None
    return write_instrument_bag(path, films, sc, poses={n: poses[n] for n in films},
                                start_ns=rb.DEFAULT_START_NS if start_ns is None else start_ns, storage=storage)


def _film_from_npz(kind: str, parts: list[tuple[dict, dict]]) -> Any:
    """The whole film of an instrument from its chunks' NPZ (arrays, config)."""
    from ..image.films import GEOMETRY_FIELDS, Envelope, PingGeometry, Soundings, Waterfall
    from ..instruments.scanning import ScanImage

    geometry = PingGeometry.concatenate([PingGeometry(**{k: a[f"geometry/{k}"] for k in GEOMETRY_FIELDS})
                                         for a, _ in parts])
    cat = lambda key, axis=0: np.concatenate([a[key] for a, _ in parts], axis=axis)  # noqa: E731
    a0, c0 = parts[0]
    unit = str(c0.get("unit", "counts"))  # (chunks written before films said their unit: the device's)
    if kind == "sidescan":
        return Waterfall(cat("samples"), c0["range_min_m"], c0["range_max_m"], geometry, unit_name=unit)
    if kind == "scanning":
        return ScanImage(cat("samples", 1), cat("angle_deg"), c0["range_min_m"], c0["range_max_m"], geometry,
                         c0["step_deg"], unit_name=unit)
    if kind == "singlebeam":
        return Envelope(cat("samples"), c0["range_min_m"], c0["range_max_m"], cat("bottom_range_m"), geometry,
                        unit_name=unit)
    return Soundings(cat("angle_deg"), cat("two_way_time_s"), cat("intensity"), geometry,
                     cat("water_column") if "water_column" in a0 else None,
                     cat("points_m") if "points_m" in a0 else None, unit_name=unit)
