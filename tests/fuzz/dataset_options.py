"""Seeded fuzzing of ``sonarsim dataset`` (issue 37): command lines, scenario files and dataset
folders, generators and the check every case must pass.

A case is one command line over one scenario file in a folder of its own. The scenario is one
of four small ones (random views, an orbit, a recorded track read from a CSV file beside a
scene file, a lawnmower survey; 12 beams, 48 range bins, a few frames) with 0 to 3 of its
:data:`SCENARIO_ASPECTS` made hostile: seeds, unknown keys, start times, bag names, trajectory
numbers and files (missing, empty, a folder, a pipe, garbage, NaN rows, times running
backwards), variation distributions, the scene, huge frame counts and the file's text itself.
The command line has 0 to 3 of :data:`CLI_ASPECTS` made hostile: ``--workers``, ``--frames``,
``--seed``, ``--start-time``, ``--frame-ids``, ``--topics``, the choices, ``--max-memory``,
the output folder (a file, another dataset, a folder with a user's file, a half-written dataset
to resume, a run interrupted by Ctrl-C after some frames), an unknown option or a required one
left out. The other options are drawn from the valid ones (``--png``, ``--labels``, ``--coco``,
``--coco-ghosts``, ``--signatures``, ``--rosbag``, ...).

:func:`check_case` runs the command in this process (:func:`sonarsim.cli.main.main`) and says
whether it kept the promise:

* exit 0 with a complete, consistent dataset folder: ``dataset.json`` and one sealed manifest
  line per frame, in order, each naming files whose size and SHA-256 are the line's (hashed
  here), NPZs with a finite image of the shape of their axes, ``coco.json`` naming existing
  images, the PNGs and the bag when asked for (with the topics asked for), the run record
  "complete", nothing in the folder the manifest does not name, the summary line on stderr;
* or exit 2 (bad input) or 3 (an outcome that means nothing) with exactly one ``error:`` line
  on stderr that names an option, a scenario key or a file, and nothing half-written: no
  temporary file left, no folder created for a refusal of the input, the files of a folder that
  was there before (another dataset, a user's file) untouched;
* never a traceback, another status, a case past its time limit, a traced allocation beyond
  the memory budget it ran under.

A resumed case (a half-written folder, an interrupted run) must end in the same bytes as an
uninterrupted run of the same command in a fresh folder (issue 37 item 3): every file's SHA-256
but the run record's. With ``repeat=True`` every accepted case is also run again in a fresh
folder, in one process where it used several, and compared the same way.

Used by ``tests/fuzz/test_dataset_fuzz.py`` (a quick seeded subset) and
``benchmarks/fuzz_dataset.py`` (the long run).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import io
import json
import os
import re
import shutil
import stat
import time
import tracemalloc
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import yaml

from tests.fuzz.scenes import CaseTimeout, time_limit

#: The memory budget a case runs under when it gives none: small, so that a size nobody checked
#: shows up as a traced allocation beyond it. (A worker process is counted at 160 MiB, so this
#: budget holds one: cases that start processes give ``--max-memory 1G``.)
FUZZ_BUDGET = "256M"
FUZZ_BUDGET_BYTES = 256 * 2**20
#: Seconds a case may take: a few frames of 12 x 48 render in well under a second here; starting
#: worker processes takes several seconds on a loaded machine, and a resumed case runs three times.
CASE_TIME_LIMIT_S = 90.0
MAX_MESSAGE_CHARS = 2000
#: What a case may trace beyond its budget: the run record, the manifest's text and the scenario's
#: parse, a fixed cost whatever the sizes (a dataset of 3 frames traced 1.1 MiB under
#: ``--max-memory 1M``); the sizes a user sets are what the budget governs.
FIXED_BYTES = 2 * 2**20

SONAR = {"n_beams": 12, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
         "range_max_m": 4.0, "n_range_bins": 48, "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}}
SCENE = {
    "sonar": SONAR,
    "render": {"elevation_samples": 6, "bounces": [1, 2]},
    "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
    "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.3],
                 "pose": {"position_m": [2.5, 0.0, 0.15]}, "albedo": 0.8}],
}
VARIATION = {
    "objects": [{"name": "rock", "count": {"randint": [0, 2]},
                 "pool": [{"primitive": "sphere", "radius_m": {"uniform": [0.05, 0.15]}},
                          {"primitive": "box", "size_m": [0.2, 0.2, 0.1]}],
                 "weights": [2, 1],
                 "pose": {"position_m": [{"uniform": [1.5, 3.5]}, {"uniform": [-0.8, 0.8]}, 0.1]},
                 "albedo": {"uniform": [0.3, 0.9]}}],
    "ground": {"albedo": {"uniform": [0.3, 0.6]}},
}
TRACK_CSV = ("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0.0,0.0,0.0,1.0,0.0,20.0,0.0\n1.0,0.3,0.0,1.0,0.5,20.0,2.0\n"
             "2.0,0.6,0.05,1.0,1.0,21.0,4.0\n")


def base_scenarios() -> dict[str, dict]:
    """The scenarios cases start from, by name (documents; ``track`` reads ``track.csv`` and
    ``scene.yaml`` from the scenario's folder)."""
    random_views = {
        "description": "random views of a block", "seed": 11, "scene": copy.deepcopy(SCENE),
        "trajectory": {"generate": {"kind": "random", "frames": 4, "bounds_m": [[-1.0, -1.0, 0.8], [0.0, 1.0, 1.2]],
                                    "look_at_bounds_m": [[2.3, -0.2, 0.0], [2.7, 0.2, 0.3]],
                                    "jitter_deg": [2.0, 4.0]}},
        "variation": copy.deepcopy(VARIATION),
    }
    orbit = {
        "seed": 3, "scene": copy.deepcopy(SCENE),
        "trajectory": {"rate_hz": 2.0, "generate": {"kind": "orbit", "centre_m": [2.5, 0.0, 0.15], "radius_m": 2.0,
                                                    "z_m": 1.0, "frames": 3, "sweep_deg": 40.0}},
        "variation": {"ground": {"albedo": {"uniform": [0.35, 0.65]}}},
    }
    with_sensor = copy.deepcopy(SCENE)
    with_sensor["sensor"] = {"gain_db": 0.0, "noise": {"level_db": 40.0}}
    track = {
        "seed": 5, "scene": "scene.yaml", "trajectory": {"file": "track.csv", "rate_hz": 1.0},
        "start_time": "2024-05-01T12:00:00Z",
        "rosbag": {"frame_ids": {"world": "map"}, "topics": {"image": "/oculus/image"}},
    }
    lawnmower = {
        "seed": 2024, "scene": with_sensor,
        "trajectory": {"rate_hz": 1.0, "generate": {"kind": "lawnmower", "area_m": [[0.0, -0.5], [1.0, 0.5]],
                                                    "spacing_m": 1.0, "z_m": 1.0, "speed_m_s": 1.0,
                                                    "pitch_deg": 20.0}},
        "variation": {"sensor": {"gain_db": {"normal": [0.0, 1.0], "min": -3, "max": 3}}},
    }
    return {"random": random_views, "orbit": orbit, "track": track, "lawnmower": lawnmower}


# Hostile values ------------------------------------------------------------------------------

NUMBERS = (0, -1, 1, 0.0, -0.0, 0.5, 2, 1e300, -1e300, float("nan"), float("inf"), float("-inf"), 1e-300, 5e-324,
           2**63, 10**30, 10**400, "x", "", None, True, [], {}, [1, 2], "1e3")
SEEDS = (-1, 2**128, 2**128 - 1, 2**200, 1.5, "7", float("nan"), True, None, [], 0, 10**400)
START_TIMES = ("now", 0, -1, -1e20, 1e20, "2038-01-19T03:14:07Z", "2038-01-19T03:14:08Z", "1969-12-31T23:59:59Z",
               "2024-13-01", "2024-02-30T00:00:00Z", float("nan"), float("inf"), True, [], "x" * 200, "1714564800",
               1714564800, 1714564800.5, "2024-05-01T12:00:00+25:00", "")
ROS_NAMES = ("", " ", "a b", "/", "//x", "1abc", "~x", "x/", "é", "a\nb", "x" * 300, "/sonar/image", "map", 3, None,
             [], "sonar", "world", "/tf", "/oculus/fan")
BAG_KEYS = ("world", "sonar", "image", "fan", "pose", "tf", "points", "camera", "Image")
UNKNOWN_KEYS = ("sede", "Seed", "frames", "trajectory_", "topics", "variations", "start-time", "x", "", "rosbag ")
#: A key made unknown where it stands (a typo), by where.
UNKNOWN_PLACES = ((), ("trajectory",), ("trajectory", "generate"), ("variation",), ("rosbag",),
                  ("rosbag", "topics"), ("variation", "objects", 0))
TRAJECTORY_FILES = ("missing", "empty", "folder", "pipe", "garbage", "not utf-8", "header only", "nan row",
                    "backwards", "far away", "wrong header", "huge angle", "tum zero quaternion", "one pose", "ok")
FRAME_COUNTS = (10**6, 10**9, 10**30, 2**63, 10**400)


def _pick(rng: np.random.Generator, values: tuple) -> Any:
    return copy.deepcopy(values[int(rng.integers(len(values)))])


def _trajectory_file(kind: str, rng: np.random.Generator) -> tuple[str, bytes | None]:
    """(file name, content) of a trajectory file of ``kind`` (None: made by :func:`_make_special`)."""
    header = "t,x,y,z,roll_deg,pitch_deg,yaw_deg\n"
    rows = {
        "empty": "", "header only": header, "nan row": header + "0,0,0,1,0,20,0\n1,nan,0,1,0,20,0\n",
        "backwards": header + "1,0,0,1,0,20,0\n0,0.1,0,1,0,20,0\n", "far away": header + "0,1e300,0,1,0,20,0\n",
        "wrong header": "t,x,y,z\n0,0,0,1\n", "huge angle": header + "0,0,0,1,0,1e9,0\n",
        "one pose": header + "0,0,0,1,0,20,0\n", "ok": TRACK_CSV,
    }
    if kind == "tum zero quaternion":
        return "track.tum", b"0 0 0 1 0 0 0 0\n1 0.1 0 1 0 0 0 1\n"
    if kind == "garbage":
        return "track.csv", rng.bytes(int(rng.integers(1, 400)))
    if kind == "not utf-8":
        return "track.csv", (header + "0,0,0,1,0,20,0\n").encode() + b"\xff\xfe\x00,1\n"
    if kind in rows:
        return "track.csv", rows[kind].encode()
    return "track.csv", None  # missing, folder, pipe


def _set(doc: dict, path: tuple, value: Any) -> None:
    for p in path[:-1]:
        doc = doc[p]
    doc[path[-1]] = value


def _numeric_paths(node: Any, path: tuple = ()) -> Iterator[tuple]:
    """Paths of every number (and every list of numbers) under ``node``."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numeric_paths(v, path + (k,))
    elif isinstance(node, list):
        if node and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in node):
            yield path
        for i, v in enumerate(node):
            yield from _numeric_paths(v, path + (i,))
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path


#: What a case may make hostile in the scenario file; the rest of it is valid.
SCENARIO_ASPECTS = ("seed", "unknown key", "start_time", "rosbag", "trajectory number", "trajectory file",
                    "variation", "scene", "frame count", "description", "text")


def _hostile_scenario(doc: dict, aspect: str, rng: np.random.Generator, files: dict) -> str:
    """Make ``aspect`` of the scenario ``doc`` hostile (in place; referenced files into
    ``files``); returns what was done."""
    if aspect == "seed":
        doc["seed"] = _pick(rng, SEEDS)
        return f"seed {doc['seed']!r}"[:80]
    if aspect == "unknown key":
        place = UNKNOWN_PLACES[int(rng.integers(len(UNKNOWN_PLACES)))]
        node: Any = doc
        for p in place:
            if isinstance(node, dict) and p not in node:
                node[p] = {}
            if isinstance(node, list) and not (isinstance(p, int) and p < len(node)):
                break
            node = node[p]
        if not isinstance(node, dict) or (place and place[0] == "variation" and "generate" in place):
            node = doc
            place = ()
        key = _pick(rng, UNKNOWN_KEYS)
        node[key] = _pick(rng, NUMBERS)
        return f"unknown key {'.'.join(map(str, place + (key,)))!r}"
    if aspect == "start_time":
        doc["start_time"] = _pick(rng, START_TIMES)
        return f"start_time {doc['start_time']!r}"[:80]
    if aspect == "rosbag":
        choice = int(rng.integers(5))
        if choice == 0:
            doc["rosbag"] = _pick(rng, NUMBERS)
        elif choice == 1:
            doc["rosbag"] = {_pick(rng, ("frame_ids", "topics", "frameids", "qos")): _pick(rng, ROS_NAMES)}
        else:
            part = "frame_ids" if choice == 2 else "topics"
            doc["rosbag"] = {part: {_pick(rng, BAG_KEYS): _pick(rng, ROS_NAMES) for _ in range(int(rng.integers(1, 4)))}}
        return f"rosbag {doc['rosbag']!r}"[:120]
    if aspect == "trajectory number":
        paths = list(_numeric_paths(doc["trajectory"]))
        path = ("trajectory",) + paths[int(rng.integers(len(paths)))] if paths else ("trajectory", "rate_hz")
        value = _pick(rng, NUMBERS)
        _set(doc, path, value)
        return f"{'.'.join(map(str, path))} = {value!r}"[:100]
    if aspect == "trajectory file":
        kind = _pick(rng, TRAJECTORY_FILES)
        name, content = _trajectory_file(kind, rng)
        files[name] = (kind, content)
        doc["trajectory"] = {"file": name, **({"rate_hz": 1.0} if rng.random() < 0.5 else {})}
        if name.endswith(".tum"):
            doc["trajectory"]["format"] = "tum"
        return f"trajectory file {kind}"
    if aspect == "variation":
        variation = doc.setdefault("variation", {}) if isinstance(doc.get("variation"), dict) else {}
        doc["variation"] = variation
        choice = int(rng.integers(8))
        if choice == 0:
            value = _pick(rng, ({"randint": [0, 10**6]}, {"randint": [5, 1]}, {"randint": [-3, 2]}, {"randint": [0, 1e300]},
                                {"choice": []}, {"uniform": [0, 2]}, 10**9, -1, {"randint": [0, 10**30]}))
            group = copy.deepcopy(VARIATION["objects"][0])
            group["count"] = value
            variation["objects"] = [group]
            return f"variation count {value!r}"
        if choice == 1:
            value = _pick(rng, ({"uniform": [float("nan"), 1]}, {"uniform": [1, 0]}, {"normal": [0, -1]},
                                {"normal": [0, float("inf")]}, {"uniform": [2, 5]}, {"choice": [0.5, 7]},
                                {"choice": [0.5], "weights": [-1]}, {"choice": [0.2, 0.4], "weights": [0, 0]},
                                {"gauss": [0, 1]}, {"uniform": [0, 1], "normal": [0, 1]}, {"uniform": "x"}))
            variation["ground"] = {"albedo": value}
            return f"variation ground albedo {value!r}"
        if choice == 2:
            group = copy.deepcopy(VARIATION["objects"][0])
            group["pool"] = _pick(rng, ([], [{}], [{"primitive": "torus"}], [{"mesh": "missing.obj"}], "sphere",
                                        [{"primitive": "sphere", "radius_m": {"uniform": [1e300, 1e301]}}],
                                        [{"primitive": "sphere", "radius_m": -1}]))
            variation["objects"] = [group]
            return f"variation pool {group['pool']!r}"[:100]
        if choice == 3:
            variation["planes"] = {_pick(rng, ("surface", "nope", "")): {"specular": {"uniform": [0.1, 0.9]}}}
            return "variation of a plane the scene does not have"
        if choice == 4:
            variation["sensor"] = {_pick(rng, ("gain_db", "noise", "bogus")): _pick(rng, NUMBERS)}
            return f"variation sensor {variation['sensor']!r}"[:100]
        if choice == 5:
            group = copy.deepcopy(VARIATION["objects"][0])
            group["weights"] = _pick(rng, ([1], [-1, 2], [0, 0], [float("nan"), 1], [1, 2, 3], "x"))
            variation["objects"] = [group]
            return f"variation weights {group['weights']!r}"
        if choice == 6:
            group = copy.deepcopy(VARIATION["objects"][0])
            group["pose"] = {"position_m": [{"uniform": [1e7, 1e8]}, 0, 0.1]} if rng.random() < 0.5 else {
                "rpy_deg": [{"uniform": [0, float("inf")]}, 0, 0]}
            variation["objects"] = [group]
            return f"variation pose {group['pose']!r}"[:100]
        doc["variation"] = _pick(rng, NUMBERS)
        return f"variation {doc['variation']!r}"[:80]
    if aspect == "scene":
        choice = int(rng.integers(6))
        if choice == 0:
            doc["scene"] = _pick(rng, ("missing.yaml", "", 7, None, [], "track.csv", "/dev/null"))
            return f"scene {doc['scene']!r}"
        scene = doc["scene"] if isinstance(doc["scene"], dict) else copy.deepcopy(SCENE)
        doc["scene"] = scene
        key, value = _pick(rng, (("n_range_bins", 10**7), ("n_beams", 10**5), ("range_max_m", 1e300),
                                 ("n_range_bins", 0), ("range_resolution_m", 1e-9), ("elevation_fov_deg", 0)))
        if choice == 1:
            scene["render"] = {**scene.get("render", {}), "elevation_samples": _pick(rng, (10**6, 0, -1, 10**30))}
            return f"scene.render.elevation_samples {scene['render']['elevation_samples']!r}"
        if choice == 2:
            scene["objects"] = [{"name": "o", "primitive": "sphere", "radius_m": 0.1}] * int(rng.integers(2, 4))
            return "scene objects of one name"
        scene["sonar"] = {**scene["sonar"], key: value}
        return f"scene.sonar.{key} {value!r}"
    if aspect == "frame count":
        n = _pick(rng, FRAME_COUNTS)
        doc["trajectory"] = {"generate": {"kind": _pick(rng, ("random", "orbit")), "frames": n}}
        base = base_scenarios()
        gen = doc["trajectory"]["generate"]
        if gen["kind"] == "random":
            gen.update({k: v for k, v in base["random"]["trajectory"]["generate"].items() if k not in ("kind", "frames")})
        else:
            gen.update({k: v for k, v in base["orbit"]["trajectory"]["generate"].items() if k not in ("kind", "frames")})
        return f"trajectory of {n} {gen['kind']} frames"
    if aspect == "description":
        doc["description"] = _pick(rng, ("x" * 100_000, 7, [], None, "a\nb", "\x00", {"a": 1}))
        return f"description {str(doc['description'])[:30]!r}"
    raise AssertionError(aspect)


def _scenario_text(doc: dict, rng: np.random.Generator, hostile_text: bool) -> tuple[bytes, str, str | None]:
    """The scenario file's bytes, its suffix, and what was done to the text (``None``: nothing)."""
    as_json = rng.random() < 0.25
    try:
        text = (json.dumps(doc) if as_json else yaml.safe_dump(doc, sort_keys=False)).encode()
    except (TypeError, ValueError, OverflowError):  # (a value YAML/JSON cannot write: written by repr)
        text, as_json = repr(doc).encode(), False
    suffix = ".json" if as_json else ".yaml"
    if not hostile_text:
        return text, suffix, None
    op = int(rng.integers(6))
    if op == 0:
        return text[: int(rng.integers(len(text)))], suffix, "text cut"
    if op == 1:
        return b"\xff\xfe" + text, suffix, "bytes that are not UTF-8"
    if op == 2:
        return b"", suffix, "empty file"
    if op == 3:
        return text + b"\nseed: 12\n", ".yaml", "seed given twice"
    if op == 4:
        return b"- a list\n- of things\n", ".yaml", "a list, not a mapping"
    return b"{\"seed\": 1,", ".json", "JSON cut"


# Command lines -------------------------------------------------------------------------------

WORKERS = ("0", "-1", "abc", "1.5", "", "nan", "1e3", "1000", "99999999999999999999999", "2", "1", "0x2", " 2")
FRAMES = ("0", "-3", "abc", "", "1e3", "1" + "0" * 30, "1", "2", "3", "100000", "2.0", "-0")
CLI_SEEDS = ("-1", "abc", str(2**128), str(2**128 - 1), str(2**200), "0", "7", "1e3", "", "0x10")
CLI_START_TIMES = ("now", "0", "-1", "-1e20", "1e20", "2038-01-19T03:14:00Z", "2024-05-01T12:00:00Z", "1714564800",
                   "nan", "inf", "", "2024-02-30", "1e9", "2024-05-01T14:00:00+02:00", "-1714564800")
NAMES = ("world=map", "world=map,sonar=sonar_link", "world=", "=x", "world=a,world=b", "camera=x", "sonar=a b",
         "image=sonar", "world", ",", "world=map,,sonar=s", "world=/map", "sonar=1x")
TOPIC_NAMES = ("image=/oculus/image", "image=/a b", "fan=/sonar/image", "image=/x,fan=/x", "tf=tf", "points=",
               "camera=/c", "image=~/x", "pose=/p,tf=/t,points=/q,fan=/f,image=/i", "image=//x", "fan")
MEMORY = ("1M", "8M", "16M", "0", "-1", "x", "1e400", "32M", "64M")
OUT_STATES = ("file", "other dataset", "user file", "half-written", "interrupted", "complete", "missing parent",
              "fifo manifest", "garbage dataset.json")
#: Resumed folders most often: what a kill, a full disk or a user leave behind.
OUT_STATE_WEIGHTS = (0.05, 0.08, 0.06, 0.35, 0.25, 0.08, 0.04, 0.04, 0.05)
#: How a half-written folder was damaged before the case resumes it.
DAMAGE = ("frame deleted", "frame cut", "frame byte flipped", "torn last line", "garbage line", "manifest deleted",
          "abandoned temp file", "run record says running", "dataset.json deleted", "frame replaced by a folder",
          "coco.json deleted", "stray file in frames")

#: What a case may make hostile on the command line; the rest of it is valid.
CLI_ASPECTS = ("workers", "frames", "seed", "start-time", "frame-ids", "topics", "choices", "max-memory", "out",
               "unknown option", "left out")


@dataclass
class Case:
    """One command line (``argv``, without the program's name) over a scenario of seed ``index``.

    ``argv`` holds ``SCENARIO`` and ``OUT`` where the case's scenario file and output folder go;
    ``scenario`` is the file's bytes (``suffix``: its extension) and ``files`` what it refers
    to (name -> (kind, bytes or None)); ``out_state`` what the output folder holds before the
    case (:data:`OUT_STATES`, ``damage`` for a half-written one).
    """

    index: int
    base: str
    argv: list[str]
    scenario: bytes
    suffix: str
    files: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    out_state: str | None = None
    damage: str | None = None
    interrupt_after: int = 1

    def describe(self) -> str:
        state = f", out: {self.out_state}" + (f" ({self.damage})" if self.damage else "") if self.out_state else ""
        return f"case {self.index} ({self.base}: {'; '.join(self.notes) or 'valid'}{state}): sonarsim {' '.join(self.argv)}"


def _option(rng: np.random.Generator, name: str, value: str) -> list[str]:
    # Both forms a user types; the separate token also when the value begins with a minus.
    return [f"{name}={value}"] if rng.random() < 0.3 else [name, value]


def generate_cases(n: int, seed: int, processes: bool = True) -> Iterator[Case]:
    """``n`` cases from ``seed`` (the same cases for the same seed): a valid scenario and command
    line with 0 to 3 aspects made hostile in all.

    Parameters
    ----------
    processes : bool
        Whether cases may start worker processes (``--workers 2`` or more under a budget that
        holds them; several seconds each). Without, ``--workers`` is still fuzzed but every
        valid value runs in this process (the budget holds one worker).
    """
    rng = np.random.default_rng(seed)
    bases = base_scenarios()
    names = list(bases)
    for index in range(n):
        base = names[int(rng.integers(len(names)))]
        doc = copy.deepcopy(bases[base])
        files: dict = {}
        if base == "track":
            files["track.csv"] = ("ok", TRACK_CSV.encode())
            files["scene.yaml"] = ("ok", yaml.safe_dump(SCENE).encode())
        # A third of the cases are about the output folder (resumed, interrupted, another
        # dataset's, a file ...), with at most one other hostile part; the rest mix 0 to 3.
        folder_case = rng.random() < 1 / 3
        m = int(rng.choice([0, 0, 0, 1] if folder_case else [0, 0, 1, 1, 1, 2, 2, 3]))
        others = tuple(a for a in SCENARIO_ASPECTS + CLI_ASPECTS if a != "out")
        aspects = list(rng.choice(others, m, replace=False)) if m else []
        if folder_case:
            aspects.append("out")
        notes: list[str] = []
        for aspect in aspects:
            if aspect in SCENARIO_ASPECTS and aspect != "text":
                notes.append(_hostile_scenario(doc, str(aspect), rng, files))
        text, suffix, what = _scenario_text(doc, rng, "text" in aspects)
        if what:
            notes.append(what)
        hostile = {str(a) for a in aspects if a in CLI_ASPECTS}
        budget = FUZZ_BUDGET
        options: dict[str, str | None] = {"--out": "OUT"}
        frames = "3" if rng.random() < 0.8 or "frame count" in aspects else None
        if "frames" in hostile:
            frames = _pick(rng, FRAMES)
            notes.append(f"--frames {frames!r}")
        if frames is not None:
            options["--frames"] = frames
        rosbag = rng.random() < 0.25
        if "workers" in hostile:
            options["--workers"] = _pick(rng, WORKERS)
            notes.append(f"--workers {options['--workers']!r}")
            if processes and rng.random() < 0.6:
                budget = "1G"  # holds 2 workers of 160 MiB and their frames: processes start
        elif processes and rng.random() < 0.05:
            options["--workers"] = "2"
            budget = "1G"
        elif rng.random() < 0.2:
            options["--workers"] = "1"
        if "seed" in hostile:
            options["--seed"] = _pick(rng, CLI_SEEDS)
            notes.append(f"--seed {options['--seed']!r}")
        elif rng.random() < 0.15:
            options["--seed"] = str(int(rng.integers(0, 2**31)))
        if "start-time" in hostile:
            options["--start-time"] = _pick(rng, CLI_START_TIMES)
            rosbag = rosbag or rng.random() < 0.8
            notes.append(f"--start-time {options['--start-time']!r}")
        elif rosbag and rng.random() < 0.3:
            options["--start-time"] = "2024-05-01T12:00:00Z"
        for option, values in (("--frame-ids", NAMES), ("--topics", TOPIC_NAMES)):
            if option[2:] in hostile:
                options[option] = _pick(rng, values)
                rosbag = rosbag or rng.random() < 0.8
                notes.append(f"{option} {options[option]!r}")
            elif rosbag and rng.random() < 0.2:
                options[option] = values[0]
        if rosbag:
            options["--rosbag"] = _pick(rng, ("mcap", "sqlite3"))
        labels = _pick(rng, ("total", "total", "all", "none"))
        if labels != "total" or rng.random() < 0.2:
            options["--labels"] = labels
        if rng.random() < 0.2:
            options["--coco"] = _pick(rng, ("fan", "polar"))
        flags = [f for f, p in (("--png", 0.2), ("--coco-ghosts", 0.15), ("--signatures", 0.1)) if rng.random() < p]
        if "choices" in hostile:
            option = _pick(rng, ("--labels", "--coco", "--rosbag", "--ray"))
            options[option] = _pick(rng, ("", "bogus", "ALL", "mcap,sqlite3", "fan ")) if option != "--ray" else ""
            notes.append(f"{option} {options[option]!r}")
        if "max-memory" in hostile:
            budget = _pick(rng, MEMORY)
            notes.append(f"--max-memory {budget}")
        out_state = damage = None
        if "out" in hostile:
            out_state = str(rng.choice(OUT_STATES, p=OUT_STATE_WEIGHTS))
            if out_state == "half-written":
                damage = _pick(rng, DAMAGE)
            notes.append("out")
        interrupt_after = int(rng.integers(0, 3))
        if "left out" in hostile:
            left = _pick(rng, ("SCENARIO", "--out"))
            if left == "--out":
                del options["--out"]
            notes.append(f"{left} left out")
        args = ["dataset"] + (["SCENARIO"] if "SCENARIO left out" not in notes else [])
        for name in rng.permutation(list(options)):
            args += _option(rng, str(name), str(options[name]))
        args += flags + ["--no-progress"]
        if "unknown option" in hostile:
            unknown = _pick(rng, ("--nope", "-x", "--frame", "--worker", "--out-dir", "--rosbags"))
            args += [unknown, _pick(rng, ("-1", "1", "mcap"))]
            notes.append(f"unknown {unknown}")
        argv = _option(rng, "--max-memory", budget) + args
        yield Case(index, base, argv, text, suffix, files, notes, out_state, damage, interrupt_after)


# Files of a case -----------------------------------------------------------------------------

def _make_special(path: Path, kind: str) -> None:
    if kind == "folder":
        path.mkdir()
    elif kind == "pipe":
        os.mkfifo(path)


def _resolve(argv: list[str], scenario: Path, out: Path) -> list[str]:
    resolved = []
    for a in argv:
        name, eq, value = a.partition("=")
        target = value if eq else a
        target = {"SCENARIO": str(scenario), "OUT": str(out)}.get(target, target)
        resolved.append(f"{name}={target}" if eq else target)
    return resolved


def _tree(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (relative name -> SHA-256; a folder or special file: its kind)."""
    out: dict[str, str] = {}
    if not folder.is_dir():
        return out
    for root, dirs, names in os.walk(folder):
        for name in dirs + names:
            p = Path(root) / name
            rel = str(p.relative_to(folder))
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode):
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = "folder"
            else:
                out[rel] = "special"
    return out


def _temporary_files(folder: Path) -> list[str]:
    """What :func:`~sonarsim.io.output.atomic_write` and the bag writer leave when they fail."""
    from sonarsim.io.output import TEMP_MARK

    return sorted(name for name in _tree(folder) if TEMP_MARK in Path(name).name or name.endswith(".tmp"))


def _run_main(argv: list[str]) -> tuple[int | None, str, str | None]:
    """``main(argv)`` in this process: (status, stderr, what escaped)."""
    from sonarsim.cli.main import main

    stderr, stdout = io.StringIO(), io.StringIO()
    status = escaped = None
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            status = main(argv)
        except SystemExit as exc:  # argparse's refusals
            status = exc.code if isinstance(exc.code, int) else 2
        except CaseTimeout:
            raise
        except BaseException as exc:  # noqa: BLE001 - what the promise forbids: a traceback
            escaped = f"{type(exc).__name__} escaped: {str(exc)[:300]}"
    return status, stderr.getvalue(), escaped


@contextlib.contextmanager
def _interrupting(after: int) -> Iterator[None]:
    """Ctrl-C (a KeyboardInterrupt) once ``after`` frames' files are written, as a user who
    stops a run does."""
    from sonarsim.dataset import writer

    real = writer._write_files
    count = [0]

    def write_files(out, encoded):
        if count[0] >= after:
            raise KeyboardInterrupt
        count[0] += 1
        return real(out, encoded)

    writer._write_files = write_files
    try:
        yield
    finally:
        writer._write_files = real


def _damage(out: Path, damage: str, rng: np.random.Generator) -> None:
    """Damage a finished dataset folder as a kill, a disk or a user might."""
    frames = sorted((out / "frames").glob("*.npz"))
    manifest = out / "manifest.jsonl"
    victim = frames[int(rng.integers(len(frames)))] if frames else None
    if damage == "frame deleted" and victim:
        victim.unlink()
    elif damage == "frame cut" and victim:
        data = victim.read_bytes()
        victim.write_bytes(data[: len(data) // 2])
    elif damage == "frame byte flipped" and victim:
        data = bytearray(victim.read_bytes())
        data[int(rng.integers(len(data)))] ^= 0x20
        victim.write_bytes(bytes(data))
    elif damage == "torn last line":
        data = manifest.read_bytes()
        manifest.write_bytes(data[: len(data) - int(rng.integers(2, 40))])
    elif damage == "garbage line":
        with open(manifest, "ab") as f:
            f.write(b'{"frame": 0, "files": ["../../etc/passwd"]}\n\xff garbage\n')
    elif damage == "manifest deleted":
        manifest.unlink()
    elif damage == "abandoned temp file":
        from sonarsim.io.output import temp_prefix

        # A PID that no process has here (above the kernel's largest).
        name = temp_prefix("000000.npz").replace(f"-{os.getpid()}-", "-4194399-") + "abcd1234.tmp"
        (out / "frames" / name).write_bytes(b"half a frame")
    elif damage == "run record says running":
        record = json.loads((out / "sonarsim-run.json").read_text())
        record.update(status="running", pid=4194399)
        (out / "sonarsim-run.json").write_text(json.dumps(record))
    elif damage == "dataset.json deleted":
        (out / "dataset.json").unlink()
    elif damage == "frame replaced by a folder" and victim:
        victim.unlink()
        victim.mkdir()
    elif damage == "coco.json deleted":
        (out / "coco.json").unlink(missing_ok=True)
    elif damage == "stray file in frames":
        (out / "frames" / "notes.txt").write_text("mine")


# The check -----------------------------------------------------------------------------------

@dataclass
class Outcome:
    """What a case came to: ``status`` 0 (a dataset), 2 or 3 (refused, naming ``error_key``), or
    a ``failure`` (why it broke the promise)."""

    case: Case
    status: int | None = None
    error_key: str | None = None
    message: str | None = None
    failure: str | None = None
    frames: int = 0
    compared: bool = False
    processes: bool = False
    seconds: float = 0.0
    peak_bytes: int = 0


def _budget_of(argv: list[str]) -> int:
    """The memory budget a case runs under (bytes; the fuzz's when it gives none that parses)."""
    from sonarsim.core.memory import parse_size

    for i, a in enumerate(argv):
        text = a.split("=", 1)[1] if a.startswith("--max-memory=") else argv[i + 1] if a == "--max-memory" else None
        if text is not None:
            try:
                return parse_size(text)
            except ValueError:
                return FUZZ_BUDGET_BYTES
    return FUZZ_BUDGET_BYTES


def check_case(case: Case, workdir: Path, trace_memory: bool = True, repeat: bool = False,
               processes: bool = True) -> Outcome:
    """Run ``case`` in this process in a folder of its own under ``workdir`` (removed after);
    returns what it came to (see the module's promise).

    Parameters
    ----------
    trace_memory : bool
        Trace allocations (about twice slower) and fail a case whose peak exceeds its budget.
    repeat : bool
        Also run every accepted case again in a fresh folder (in this process) and compare
        every file's SHA-256; resumed cases are always compared so.
    processes : bool
        ``False``: this machine counts as one core (no worker process starts whatever
        ``--workers`` says): the quick subset's speed.
    """
    from sonarsim.dataset import workers

    folder = workdir / f"case{case.index}"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(case.index)
    outcome = Outcome(case)
    saved_cores = workers.available_cores
    if not processes:
        workers.available_cores = lambda: 1
    t0 = time.perf_counter()
    try:
        with time_limit(CASE_TIME_LIMIT_S):
            _check(case, folder, outcome, rng, trace_memory, repeat, processes)
    except CaseTimeout as exc:
        outcome.failure = f"the case {exc}"
    finally:
        outcome.seconds = time.perf_counter() - t0
        workers.available_cores = saved_cores
        shutil.rmtree(folder, ignore_errors=True)
        if folder.exists():  # a pipe or a folder without permissions
            os.system(f"rm -rf {str(folder)!r}")
    return outcome


def _prepare(case: Case, folder: Path, scenario: Path, out: Path, rng: np.random.Generator) -> str | None:
    """Make what the case's output folder holds before it runs; returns a failure, or None."""
    from sonarsim.cli.main import main

    state = case.out_state
    if state is None:
        return None
    if state == "file":
        out.write_text("not a folder")
    elif state == "missing parent":
        pass  # OUT is under a folder that does not exist: _out_path
    elif state == "user file":
        out.mkdir()
        (out / "notes.txt").write_text("a user's notes")
    elif state == "fifo manifest":
        out.mkdir()
        os.mkfifo(out / "manifest.jsonl")
    elif state == "garbage dataset.json":
        out.mkdir()
        (out / "dataset.json").write_bytes(b"\x00\xffnot json")
    elif state == "other dataset":
        other = folder / "other.yaml"
        doc = base_scenarios()["orbit"]
        other.write_text(yaml.safe_dump(doc))
        with contextlib.redirect_stderr(io.StringIO()):
            if main(["dataset", str(other), "--out", str(out), "--frames", "2", "--no-progress"]) != 0:
                return "could not make the other dataset"
    elif state in ("half-written", "complete", "interrupted"):
        return "run"  # made from the case's own command (see _check)
    return None


def _out_path(case: Case, folder: Path) -> Path:
    return folder / "no" / "such" / "out" if case.out_state == "missing parent" else folder / "out"


def _check(case: Case, folder: Path, outcome: Outcome, rng: np.random.Generator, trace: bool, repeat: bool,
           processes: bool) -> None:
    scenario = folder / f"scenario{case.suffix}"
    scenario.write_bytes(case.scenario)
    for name, (kind, content) in case.files.items():
        if content is not None:
            (folder / name).write_bytes(content)
        else:
            _make_special(folder / name, kind)
    out = _out_path(case, folder)
    argv = _resolve(case.argv, scenario, out)
    budget = _budget_of(argv)
    workers = _value_of(argv, "--workers")
    outcome.processes = (processes and budget >= 2**30 and workers is not None and workers.strip().isdigit()
                         and int(workers) >= 2)
    prepared = _prepare(case, folder, scenario, out, rng)
    resumed = False
    if prepared == "run":
        # The case's own command first: finished, finished and damaged, or stopped by Ctrl-C.
        if case.out_state == "interrupted":
            with _interrupting(case.interrupt_after):
                status, err, escaped = _run_main(argv)
            if escaped:
                outcome.failure = f"interrupted run: {escaped}"
                return
            if status == 0:
                pass  # fewer frames than the interrupt waited for: it finished
            elif status == 130:
                if len([l for l in err.splitlines() if l.strip()]) != 1 or "interrupted by Ctrl-C" not in err:
                    outcome.failure = f"interrupted run: not one line saying so: {err.strip()[:300]!r}"
                    return
                left = _temporary_files(out)
                if left:
                    outcome.failure = f"interrupted run left temporary files: {left[:3]}"
                    return
            else:
                return _judge_refusal(outcome, status, err, escaped, out, {}, False, budget, trace, folder)
        else:
            status, err, escaped = _run_main(argv)
            if status != 0 or escaped:
                # The command itself is refused: judged as the case (the folder never existed).
                return _judge_refusal(outcome, status, err, escaped, out, {}, False, budget, trace, folder)
            if case.out_state == "half-written":
                _damage(out, case.damage or "", rng)
        resumed = True
    elif prepared is not None:
        outcome.failure = prepared
        return
    before = _tree(out)
    existed = out.exists() or out.is_symlink()
    if trace:
        tracemalloc.start()
    try:
        status, err, escaped = _run_main(argv)
    finally:
        if trace:
            outcome.peak_bytes = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    outcome.status = status
    if escaped:
        outcome.failure = escaped
        return
    if status != 0:
        return _judge_refusal(outcome, status, err, escaped, out, before, existed, budget, trace, folder)
    outcome.failure = _judge_dataset(outcome, argv, err, out, budget, trace)
    if outcome.failure is None and case.out_state == "user file" and _tree(out).get("notes.txt") != before["notes.txt"]:
        outcome.failure = "the user's file beside the dataset was changed"
    if outcome.failure is None and (resumed or repeat or outcome.processes):
        outcome.failure = _compare_fresh(argv, out, folder)
        outcome.compared = True


def _message_key(line: str, folder: Path) -> str | None:
    """What an error line names: an option, ``FILE: KEY`` of a scenario key, or a file."""
    message = line.split("error:", 1)[1].strip()
    option = re.search(r"(?<![\w-])(--[a-z][a-z-]*)", message)
    where = str(folder) + "/"
    if message.startswith(where) or f" {where}" in message or f"'{where}" in message:
        rest = message[message.index(where) + len(where):]
        name = re.split(r"[:\s']", rest, maxsplit=1)[0]
        if option and message.index(option.group(1)) < message.index(where):
            return option.group(1)
        generic = re.sub(r"^(scenario)\.(yaml|json)$", r"\1", name)
        generic = re.sub(r"^out/.*", "out/...", re.sub(r"^no/such/out.*", "out", generic))
        after = rest[len(name):]
        key = re.match(r":\s*([A-Za-z_][\w.\[\]-]*):", after)
        if key and generic == "scenario":
            return "scenario: " + re.sub(r"\[\d+\]", "[]", key.group(1))
        return f"file: {generic}"
    if option:
        return option.group(1)
    if "required" in message or "unrecognized" in message or "arguments" in message:
        return "argparse: " + " ".join(message.split()[:3])
    return None


def _judge_refusal(outcome: Outcome, status: int | None, err: str, escaped: str | None, out: Path,
                   before: dict, existed: bool, budget: int, traced: bool, folder: Path) -> None:
    outcome.status = status
    if escaped:
        outcome.failure = escaped
        return
    if status not in (2, 3):
        outcome.failure = f"exit status {status!r}: {err.strip()[-300:]!r}"
        return
    if "Traceback" in err:
        outcome.failure = "a traceback on stderr"
        return
    if traced and outcome.peak_bytes > budget + FIXED_BYTES:
        outcome.failure = f"refused after tracing {outcome.peak_bytes / 2**20:.1f} MiB, beyond the budget"
        return
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if "error:" in line]
    if len(errors) != 1:
        outcome.failure = f"{len(errors)} error lines: {err.strip()[:300]!r}"
        return
    # Besides the error: argparse's usage, and sonarsim's notes (a --workers cap, frames kept).
    usage = False
    for line in lines:
        if line.startswith("usage:"):
            usage = True
        elif line in errors or line.startswith("sonarsim: ") or (usage and line.startswith(" ")):
            continue
        else:
            outcome.failure = f"a stray line on stderr: {line[:200]!r}"
            return
    line = errors[0]
    outcome.message = line
    if len(line) > MAX_MESSAGE_CHARS:
        outcome.failure = f"a message of {len(line)} characters"
        return
    key = _message_key(line, folder)
    if key is None:
        outcome.failure = f"a refusal naming no option, key or file: {line[:300]!r}"
        return
    outcome.error_key = f"{status}: {key}" if status == 3 else key
    left = _temporary_files(out)
    if left:
        outcome.failure = f"refused, and left temporary files: {left[:3]}"
        return
    after = _tree(out)
    if not existed and after:
        # A refusal of the input comes before the folder is made (a run that failed midway
        # keeps its verified frames, but none of these cases fails midway).
        outcome.failure = f"refused, yet made {out.name} ({len(after)} entries: {sorted(after)[:4]})"
        return
    changed = [name for name, digest in before.items() if after.get(name) != digest
               and name not in ("sonarsim-run.json", "manifest.jsonl")]
    if changed:
        outcome.failure = f"refused, and changed what the folder held: {changed[:4]}"


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _judge_dataset(outcome: Outcome, argv: list[str], err: str, out: Path, budget: int, traced: bool) -> str | None:
    """Why the folder of an accepted case is not a complete, consistent dataset (None: it is)."""
    if "Traceback" in err or "error:" in err:
        return f"exit 0 with an error or a traceback on stderr: {err.strip()[:300]!r}"
    if traced and outcome.peak_bytes > budget + FIXED_BYTES:
        return f"traced {outcome.peak_bytes / 2**20:.1f} MiB, beyond the {budget / 2**20:.0f} MiB budget"
    left = _temporary_files(out)
    if left:
        return f"temporary files left: {left[:3]}"
    try:
        info = json.loads((out / "dataset.json").read_text())
        lines = (out / "manifest.jsonl").read_text().splitlines()
        records = [json.loads(line) for line in lines]
    except (OSError, ValueError) as exc:
        return f"dataset.json or the manifest unreadable: {exc}"
    n = info.get("n_frames")
    outcome.frames = n if isinstance(n, int) else 0
    if not isinstance(n, int) or n < 1 or len(records) != n or [r.get("frame") for r in records] != list(range(n)):
        return f"{len(records)} manifest lines for n_frames {n!r}, or out of order"
    summary = re.search(r": (\d+) frames \((\d+) made, (\d+) kept\)", err)
    if not summary or int(summary.group(1)) != n or int(summary.group(2)) + int(summary.group(3)) != n:
        return f"no summary line for {n} frames: {err.strip()[-300:]!r}"
    asked = _value_of(argv, "--frames")
    if asked is not None and n > int(asked):
        return f"{n} frames for --frames {asked}"
    named = {"dataset.json", "manifest.jsonl", "sonarsim-run.json", "frames"}
    for r in records:
        body = {k: v for k, v in r.items() if k != "check"}
        if hashlib.sha256(_canonical(body).encode()).hexdigest() != r.get("check"):
            return f"frame {r['frame']}'s manifest line fails its seal"
        for name in r.get("files", []):
            path = out / name
            named.add(name)
            try:
                data = path.read_bytes()
            except OSError as exc:
                return f"frame {r['frame']}: {name} unreadable: {exc}"
            if len(data) != r["bytes"].get(name) or hashlib.sha256(data).hexdigest() != r["sha256"].get(name):
                return f"frame {r['frame']}: {name}'s size or SHA-256 is not its manifest line's"
        npz = [name for name in r.get("files", []) if name.endswith(".npz")]
        if len(npz) != 1:
            return f"frame {r['frame']} names {len(npz)} NPZ files"
        with np.load(out / npz[0], allow_pickle=False) as d:
            polar, rng_m, az = d["polar"], d["range_m"], d["azimuth_deg"]
            if polar.shape != (rng_m.size, az.size) or not np.all(np.isfinite(polar)) or np.any(polar < 0):
                return f"frame {r['frame']}: an image of shape {polar.shape} for {rng_m.size} x {az.size}, or not finite"
        if "--png" in argv and not {f"frames/{r['frame']:06d}_polar.png", f"frames/{r['frame']:06d}_fan.png"} <= set(
                r["files"]):
            return f"frame {r['frame']}: --png without its PNGs"
    labels = _value_of(argv, "--labels") or "total"
    if labels != "none":
        named.add("coco.json")
        try:
            coco = json.loads((out / "coco.json").read_text())
        except (OSError, ValueError) as exc:
            return f"coco.json unreadable: {exc}"
        if len(coco.get("images", [])) != n or any(not (out / i["file_name"]).is_file() for i in coco["images"]):
            return "coco.json's images are not the frames' files"
        ids = {i["id"] for i in coco["images"]}
        if any(a.get("image_id") not in ids for a in coco.get("annotations", [])):
            return "a COCO annotation of an image that is not there"
    if _value_of(argv, "--rosbag"):
        named |= {"rosbag"}
        try:
            meta = yaml.safe_load((out / "rosbag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        except (OSError, KeyError, TypeError, yaml.YAMLError) as exc:
            return f"the bag's metadata unreadable: {exc}"
        topics = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
        asked_topics = _value_of(argv, "--topics")
        for item in (asked_topics.split(",") if asked_topics else []):
            name, _, topic = item.partition("=")
            if topic.strip() not in topics and not (name.strip() == "points" and labels == "none"):
                return f"--topics {asked_topics}: {item} not in the bag's topics {sorted(topics)}"
        if meta.get("message_count", 0) < n:
            return f"a bag of {meta.get('message_count')} messages for {n} frames"
    record = json.loads((out / "sonarsim-run.json").read_text())
    if record.get("status") != "complete":
        return f"the run record says {record.get('status')!r}"
    # A user's file beside the dataset or among its frames is theirs: kept (and checked untouched).
    stray = [name for name in _tree(out) if name.split("/")[0] not in ("rosbag",) and name not in named
             and Path(name).name != "notes.txt"]
    if stray:
        return f"files the manifest does not name: {stray[:4]}"
    return None


def _value_of(argv: list[str], option: str) -> str | None:
    for i, a in enumerate(argv):
        if a.startswith(option + "="):
            return a.split("=", 1)[1]
        if a == option and i + 1 < len(argv):
            return argv[i + 1]
    return None


def _compare_fresh(argv: list[str], out: Path, folder: Path) -> str | None:
    """Run the same command in a fresh folder, in one process, and compare every file (issue 37
    item 3: the same bytes whatever the workers and however often the run was resumed)."""
    fresh = folder / "fresh"
    again = [a.replace(str(out), str(fresh)) for a in argv]
    # One process: the worker count changes how fast, never what.
    cleaned = []
    skip = False
    for a in again:
        if skip:
            skip = False
            continue
        if a == "--workers":
            skip = True
            continue
        if not a.startswith("--workers="):
            cleaned.append(a)
    status, err, escaped = _run_main(cleaned)
    if status != 0 or escaped:
        return f"the same command in a fresh folder: exit {status}, {escaped or err.strip()[-200:]!r}"
    a, b = _tree(out), _tree(fresh)
    for tree in (a, b):  # the run record, and a user's file the damaged folder held
        for name in [n for n in tree if n == "sonarsim-run.json" or Path(n).name == "notes.txt"]:
            del tree[name]
    if a != b:
        differ = sorted(name for name in set(a) | set(b) if a.get(name) != b.get(name))
        return f"not the bytes of an uninterrupted run in one process: {differ[:5]}"
    shutil.rmtree(fresh, ignore_errors=True)
    return None


@dataclass
class Summary:
    """Counts over many outcomes."""

    cases: int = 0
    written: int = 0
    frames: int = 0
    compared: int = 0
    processes: int = 0
    by_status: dict[int, int] = field(default_factory=dict)
    by_base: dict[str, int] = field(default_factory=dict)
    by_out_state: dict[str, int] = field(default_factory=dict)
    refused: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    slowest_s: float = 0.0
    slowest_case: str = ""
    peak_bytes: int = 0

    def add(self, out: Outcome) -> None:
        self.cases += 1
        self.written += out.status == 0 and out.failure is None
        self.frames += out.frames if out.failure is None else 0
        self.compared += out.compared and out.failure is None
        self.processes += out.processes and out.status == 0
        self.by_base[out.case.base] = self.by_base.get(out.case.base, 0) + 1
        state = (out.case.out_state or "new") + (f" ({out.case.damage})" if out.case.damage else "")
        self.by_out_state[state] = self.by_out_state.get(state, 0) + 1
        if out.status is not None:
            self.by_status[out.status] = self.by_status.get(out.status, 0) + 1
        if out.error_key:
            self.refused[out.error_key] = self.refused.get(out.error_key, 0) + 1
        if out.failure:
            self.failures.append(f"{out.case.describe()}: {out.failure}")
        if out.seconds > self.slowest_s:
            self.slowest_s, self.slowest_case = out.seconds, out.case.describe()
        self.peak_bytes = max(self.peak_bytes, out.peak_bytes)
