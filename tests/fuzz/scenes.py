"""Seeded fuzzing of scene files (issue 11 item 6): mutators and the check every case must pass.

A case is one mutation of a seed scene (the example scene files, and variants of them that
switch on the sensor, the render settings and a plane so that every section is exercised), at
one of two levels:

* ``doc``: the parsed document is mutated (keys deleted, copied, renamed, given the wrong
  case, values swapped for other types, extreme numbers, empty or huge containers, deep nesting)
  and handed to :func:`sonarsim.config.loader.scene_from_dict`;
* ``text``: the YAML or JSON text is mutated (byte flips, truncation, insertions, duplicated
  lines, tabs, broken indentation, bytes that are not UTF-8), written to a file and read with
  :func:`sonarsim.load_scene`.

:func:`check_case` runs one case and says what happened: the loader refused it with the
documented error (a :class:`~sonarsim.errors.SonarsimError` whose one-line message names the
key or the file), or accepted a scene whose values are plausible (finite, in the documented
ranges, its images within the memory budget); optionally a small render of an accepted scene
must give a finite image of the configured shape or a :class:`~sonarsim.errors.ConfigError`.
Anything else (another exception, a case that runs past its time limit, a traced allocation
beyond the budget) is a failure, described in :attr:`Outcome.failure`.

Used by ``tests/fuzz/test_scenes_fuzz.py`` (a few thousand cases) and
``benchmarks/fuzz_scenes.py`` (100,000).
"""

from __future__ import annotations

import copy
import json
import math
import signal
import time
import tracemalloc
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"

#: The budget cases run under: small, so that a size check that is missing shows up as a
#: traced allocation beyond it rather than as a machine that swaps.
FUZZ_BUDGET_BYTES = 64 * 2**20

#: A case that runs longer than this (seconds) counts as a hang. Loading takes milliseconds (a
#: document of 7,000 objects about a second, traced); on a machine loaded ten times over the
#: same load took past 5 s, so the guard is a hang's, not a speed test's.
LOAD_TIME_LIMIT_S = 30.0
RENDER_TIME_LIMIT_S = 30.0

#: A frame's images, rays and speckle fields are checked together against the budget
#: (``Simulator.require_frame_memory``), so a case's traced peak stays within the budget. What
#: this catches is an allocation no check sized (a beam table of n_beams 10**9 took 8 GB).
PEAK_BUDGETS = 1

#: Messages longer than this are not a one-line message a person reads.
MAX_MESSAGE_CHARS = 2000


# Seeds -------------------------------------------------------------------------------------

def seed_documents() -> list[tuple[str, dict]]:
    """The documents mutations start from: ``(name, document)``.

    The example scene files as they are, and variants of them that add a sensor section, the
    render settings, a plane and a sonar given by its numbers rather than a preset, so that the
    mutations reach every section the loader parses.
    """
    seeds = []
    for path in sorted(EXAMPLES.glob("*.yaml")):
        with open(path, encoding="utf-8") as f:
            seeds.append((path.name, yaml.safe_load(f)))
    base = dict(seeds[0][1]) if seeds else {"sonar": {"preset": "aris3000-128"}}
    oculus = next((d for n, d in seeds if "oculus" in n), base)
    with_sensor = copy.deepcopy(oculus)
    with_sensor["sensor"] = {
        "preset": "oculus-m1200d-hf", "gain_db": 10.0,
        "noise": {"level_db": 80.0}, "output": {"compression": "log", "floor_db": 60.0, "ceiling_db": 150.0},
        "pulse": {"kind": "chirp", "length_us": 50.0, "bandwidth_khz": 100.0, "window": "taylor", "sidelobe_db": 30.0},
        "absorption": {"model": "constant", "db_per_m": 0.5},
    }
    seeds.append(("oculus_floor+sensor", with_sensor))
    numeric = copy.deepcopy(base)
    numeric["sonar"] = {
        "n_beams": 48, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
        "range_max_m": 6.0, "range_resolution_m": 0.02, "beam_width_deg": 0.6, "frequency_khz": 1200.0,
        "pose": {"position_m": [0.0, 0.0, 1.0], "quat_xyzw": [0.0, 0.17, 0.0, 0.98]},
    }
    numeric["render"] = {
        "elevation_samples": 16, "azimuth_samples": 2, "tvg": True, "max_order": 3, "bounces": [1, 2],
        "method": "fast", "beam_pattern": "gaussian", "range_splat": True, "double_beam": "split",
        "double_line_of_sight": False, "speckle": True, "seed": 7, "threads": 1,
    }
    numeric["planes"] = list(numeric.get("planes", [])) + [
        {"name": "surface", "point_m": [0.0, 0.0, 3.0], "normal": [0.0, 0.0, -1.0], "albedo": 0.0, "specular": 0.9},
    ]
    numeric["objects"] = list(numeric.get("objects", [])) + [
        {"name": "ball", "primitive": "sphere", "radius_m": 0.2, "scale": [1.0, 1.0, 2.0],
         "pose": {"position_m": [2.5, 0.0, 0.5]}, "material": {"law": "lambertian", "albedo": 0.5}},
    ]
    seeds.append(("materials+numeric", numeric))
    table = copy.deepcopy(oculus)
    table["sonar"] = {"preset": "oculus-m1200d-hf", "beam_angles_deg": [10.0, 5.0, 0.0, -5.0, -10.0], "n_beams": 5,
                      "n_range_bins": 200, "pose": oculus["sonar"].get("pose", {})}
    seeds.append(("oculus_floor+beam_table", table))
    return seeds


# Document mutations --------------------------------------------------------------------------

EXTREME_NUMBERS = (0, -1, 1, 0.0, -0.0, 1e300, -1e300, float("nan"), float("inf"), float("-inf"), 1e-300,
                   -1e-300, 5e-324, 2**63, -2**63, 2**64 + 1, 10**30, 10**400, 2**31 - 1, 179.999, 180, 90, 1e6,
                   1e6 + 1, 0.5, 2, 3, 9, 10, 1e9)
KNOWN_KEYS = (
    "sonar", "render", "ground", "planes", "objects", "sensor", "preset", "n_beams", "azimuth_fov_deg",
    "beam_angles_deg", "beam_angles_file", "beam_width_deg", "elevation_fov_deg", "range_min_m", "range_max_m",
    "n_range_bins", "range_resolution_m", "frequency_khz", "pose", "position_m", "rpy_deg", "quat_xyzw",
    "elevation_samples", "azimuth_samples", "tvg", "max_order", "bounces", "method", "beam_pattern", "range_splat",
    "double_beam", "double_line_of_sight", "speckle", "seed", "threads", "height_m", "albedo", "specular",
    "material", "name", "point_m", "normal", "primitive", "size_m", "radius_m", "mesh", "scale", "law", "mu",
    "mu_db", "specular_strength", "roughness", "texture", "noise", "output", "pulse", "absorption", "bang",
    "elevation_pattern", "azimuth_pattern", "table", "width_deg", "window", "span_deg", "leakage_beams",
    "source_level_db", "gain_db", "sound_speed_m_s", "model", "level_db", "dtype", "gamma",
)
WORDS = ("auto", "box", "sphere", "cylinder", "fast", "paper", "split", "lambert", "rough", "aris3000-128",
         "oculus-m1200d-hf", "gaussian", "uniform", "table", "taylor", "log", "uint8", "float32", "chirp", "k",
         "world", "ground", "O", "objects", "x", "../../../../etc/passwd", "/dev/zero", "examples", ".", "",
         "~", "null", "é", "\u202e", "a\nb", "\x00", "NaN", ".inf")


def _random_value(rng: np.random.Generator, depth: int = 0) -> Any:
    """A value of a random type: numbers (often extreme), strings, lists, maps, None, bools."""
    kind = rng.integers(12) if depth < 3 else rng.integers(7)
    if kind <= 2:
        return EXTREME_NUMBERS[rng.integers(len(EXTREME_NUMBERS))]
    if kind == 3:
        return float(rng.normal() * 10.0 ** int(rng.integers(-3, 4)))
    if kind == 4:
        return WORDS[rng.integers(len(WORDS))]
    if kind == 5:
        return [None, True, False][rng.integers(3)]
    if kind == 6:
        return int(rng.integers(-5, 300))
    if kind == 7:
        return "x" * int(10.0 ** int(rng.integers(2, 6)))  # very long strings
    if kind == 8:
        return [] if rng.random() < 0.3 else [_random_value(rng, depth + 1) for _ in range(rng.integers(1, 5))]
    if kind == 9:
        return {} if rng.random() < 0.3 else {KNOWN_KEYS[rng.integers(len(KNOWN_KEYS))]: _random_value(rng, depth + 1)}
    if kind == 10:
        return _nested(rng)
    return [float(v) for v in rng.normal(size=rng.integers(0, 5)) * 10.0 ** int(rng.integers(-2, 4))]


def _nested(rng: np.random.Generator) -> Any:
    """A list or map nested tens to thousands deep."""
    # Python's repr and deepcopy recurse: deepcopy (three frames a level) fails in the test itself beyond about 300.
    depth = int(10 ** rng.uniform(1, 2.5))
    value: Any = 1.0
    for i in range(depth):
        value = [value] if i % 2 or rng.random() < 0.5 else {"a": value}
    return value


def _nodes(doc: Any, path: tuple = ()) -> Iterator[tuple[tuple, Any]]:
    """Every (path, node) of a document down to depth 8, the root included (path ``()``)."""
    yield path, doc
    if len(path) >= 8:  # not into what a mutation nested deeply
        return
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _nodes(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _nodes(v, path + (i,))


def _parent(doc: Any, path: tuple) -> Any:
    for p in path[:-1]:
        doc = doc[p]
    return doc


def _mutate_once(doc: Any, rng: np.random.Generator) -> tuple[Any, str]:
    """One mutation of ``doc`` (in place where it can be); returns the new root and what was done."""
    nodes = list(_nodes(doc))
    path, node = nodes[rng.integers(len(nodes))]
    op = int(rng.integers(10))
    if not path:  # the root itself
        if op == 0:
            return _random_value(rng), "root replaced"
        if isinstance(doc, dict):
            doc[KNOWN_KEYS[rng.integers(len(KNOWN_KEYS))]] = _random_value(rng)
        return doc, "root key added"
    parent, last = _parent(doc, path), path[-1]
    where = "/".join(map(str, path))
    if op == 0:  # delete
        del parent[last]
        return doc, f"deleted {where}"
    if op in (1, 2):  # another type, or an extreme number
        parent[last] = EXTREME_NUMBERS[rng.integers(len(EXTREME_NUMBERS))] if op == 1 else _random_value(rng)
        return doc, f"replaced {where}"
    if op == 3 and isinstance(node, (int, float)) and not isinstance(node, bool):  # scale a number
        parent[last] = node * float(10.0 ** int(rng.integers(-6, 7))) * (-1 if rng.random() < 0.2 else 1)
        return doc, f"scaled {where}"
    if op == 4:  # empty container or string
        parent[last] = [[], {}, "", None][rng.integers(4)]
        return doc, f"emptied {where}"
    if isinstance(parent, dict):
        if op == 5:  # the key in another case
            new = str(last).upper() if rng.random() < 0.5 else str(last).capitalize()
            parent[new] = parent.pop(last)
            return doc, f"recased {where}"
        if op == 6:  # an unknown or misplaced key
            key = KNOWN_KEYS[rng.integers(len(KNOWN_KEYS))] if rng.random() < 0.7 else f"{last}_typo"
            parent[key] = copy.deepcopy(node) if rng.random() < 0.5 else _random_value(rng)
            return doc, f"added {where}/../{key}"
        if op == 7:  # a key copied to a sibling's place (one quantity given twice)
            keys = list(parent)
            other = keys[rng.integers(len(keys))]
            parent[other] = copy.deepcopy(node)
            return doc, f"copied {where} to {other}"
        if op == 8 and not isinstance(last, str):
            return doc, "kept"
    if isinstance(parent, list):
        if op in (5, 6):
            parent.insert(int(rng.integers(len(parent) + 1)), copy.deepcopy(node))
            return doc, f"duplicated {where}"
        if op == 7:
            parent.reverse()
            return doc, f"reversed {where[:where.rfind('/')]}"
    if op == 8:
        parent[last] = _nested(rng)
        return doc, f"nested {where}"
    if isinstance(node, list) and node:
        # Long lists of numbers are cheap to refuse; thousands of objects are slow to parse
        # (about 0.2 ms each) and prove nothing more than hundreds.
        most = 2000 if all(not isinstance(v, (dict, list)) for v in node) else 100
        parent[last] = node * int(rng.integers(2, most))
        return doc, f"repeated {where}"
    parent[last] = _random_value(rng)
    return doc, f"replaced {where}"


def _perturb(doc: Any, rng: np.random.Generator) -> tuple[Any, str]:
    """A gentle mutation: one number of ``doc`` moved by up to a factor of two, or a boolean
    flipped (most such scenes are still valid: they exercise the accepted side)."""
    leaves = [(p, v) for p, v in _nodes(doc) if p and isinstance(v, (int, float))]
    if not leaves:
        return doc, "kept"
    path, v = leaves[rng.integers(len(leaves))]
    parent = _parent(doc, path)
    if isinstance(v, bool):
        parent[path[-1]] = not v
    elif isinstance(v, int):
        parent[path[-1]] = max(0, v + int(rng.integers(-3, 4)) * max(1, abs(v) // 4))
    else:
        parent[path[-1]] = float(v * rng.uniform(0.5, 2.0) + rng.normal() * 0.1)
    return doc, f"perturbed {'/'.join(map(str, path))}"


def mutate_document(doc: Any, rng: np.random.Generator) -> tuple[Any, list[str]]:
    """A copy of ``doc`` with one to four random mutations; returns it and what was done.

    A third of the mutations are gentle (:func:`_perturb`), the rest hostile.
    """
    out = copy.deepcopy(doc)
    done = []
    for _ in range(min(4, int(rng.geometric(0.5)))):
        out, what = _perturb(out, rng) if rng.random() < 1 / 3 else _mutate_once(out, rng)
        done.append(what)
    return out, done


# Text mutations ------------------------------------------------------------------------------

def mutate_text(data: bytes, rng: np.random.Generator) -> tuple[bytes, list[str]]:
    """``data`` with one to four byte-level mutations; returns it and what was done."""
    b = bytearray(data)
    done = []
    for _ in range(int(rng.integers(1, 5))):
        op = int(rng.integers(9))
        at = int(rng.integers(len(b) + 1))
        if op == 0 and b:  # flip bits
            i = min(at, len(b) - 1)
            b[i] ^= 1 << int(rng.integers(8))
            done.append(f"flipped byte {i}")
        elif op == 1:  # truncate
            del b[at:]
            done.append(f"truncated at {at}")
        elif op == 2:  # insert random bytes: any (often not UTF-8), or printable ASCII
            n = int(rng.integers(1, 8))
            b[at:at] = rng.bytes(n) if rng.random() < 0.3 else bytes(rng.integers(32, 127, n).astype(np.uint8))
            done.append(f"inserted bytes at {at}")
        elif op == 3:  # insert YAML/JSON syntax
            tok = [b":", b"-", b"[", b"]", b"{", b"}", b",", b"&a", b"*a", b"!!python/object:os.system", b"<<: *a",
                   b"? ", b"|", b">", b"'", b'"', b"#", b"%YAML 1.1\n", b"---\n", b"...\n", b"\\u0000",
                   b"!!binary", b"1e999", b".nan", b"0x7fffffffffffffffff", b"~"][rng.integers(26)]
            b[at:at] = tok
            done.append(f"inserted {tok!r} at {at}")
        elif op == 4:  # duplicate a line
            lines = bytes(b).splitlines(keepends=True)
            if lines:
                i = int(rng.integers(len(lines)))
                lines.insert(i, lines[i])
                b = bytearray(b"".join(lines))
                done.append(f"duplicated line {i + 1}")
        elif op == 5:  # tabs or broken indentation
            lines = bytes(b).splitlines(keepends=True)
            if lines:
                i = int(rng.integers(len(lines)))
                lines[i] = [b"\t", b"  ", b" ", b""][rng.integers(4)] + lines[i].lstrip(b" ")
                b = bytearray(b"".join(lines))
                done.append(f"reindented line {i + 1}")
        elif op == 6:  # non-UTF-8 bytes
            b[at:at] = [b"\xff", b"\xc3", b"\xe9", b"\xed\xa0\x80", b"\xef\xbb\xbf", b"\x00"][rng.integers(6)]
            done.append(f"non-UTF-8 at {at}")
        elif op == 7:  # a digit run made huge or a number made extreme
            b[at:at] = [b"9" * 400, b"1e308", b"-1e-320", b"inf", b"nan", b"00000000001"][rng.integers(6)]
            done.append(f"number at {at}")
        else:  # delete a span
            del b[at:at + int(rng.integers(1, 40))]
            done.append(f"deleted from {at}")
    return bytes(b), done


# Cases ---------------------------------------------------------------------------------------

@dataclass
class Case:
    """One fuzz case: a mutated document (``doc``) or a mutated file's bytes (``data``)."""

    index: int
    seed_name: str
    level: str  # "doc" or "text"
    mutations: list[str]
    doc: Any = None
    data: bytes | None = None
    suffix: str = ".yaml"
    render: bool = False
    # Files the case's document refers to (``files`` level): name -> (kind, content), written
    # into the case's own folder before it is loaded (see :func:`write_referenced`).
    files: dict[str, tuple[str, bytes]] | None = None

    def describe(self) -> str:
        return f"case {self.index} ({self.level} of {self.seed_name}: {'; '.join(self.mutations)})"


def generate_cases(n: int, seed: int, render_every: int = 0) -> Iterator[Case]:
    """``n`` cases from one seed: two thirds document mutations, one third text mutations.

    ``render_every``: every that many cases (0: none) also renders the scene if it loads.
    """
    seeds = seed_documents()
    texts = []
    for name, doc in seeds:
        # Both the files as written (comments and flow style) and dumps of the variants.
        path = EXAMPLES / name
        texts.append((name, path.read_bytes() if path.is_file() else yaml.safe_dump(doc).encode(), ".yaml"))
        texts.append((name + ".json", json.dumps(doc, indent=1).encode(), ".json"))
    rng = np.random.default_rng(seed)
    for i in range(n):
        render = bool(render_every) and i % render_every == 0
        if rng.random() < HOSTILE_SHARE:
            yield hostile_case(i, rng, texts, render)
            continue
        if rng.random() < 2 / 3:
            name, doc = seeds[rng.integers(len(seeds))]
            mutated, done = mutate_document(doc, rng)
            yield Case(i, name, "doc", done, doc=mutated, render=render)
        else:
            name, data, suffix = texts[rng.integers(len(texts))]
            mutated, done = mutate_text(data, rng)
            yield Case(i, name, "text", done, data=mutated, suffix=suffix, render=render)


# Hostile cases (issue 21) --------------------------------------------------------------------
#
# What the mutations above rarely reach: scenes of thousands of objects, YAML aliases that
# expand (bombs, recursion, merges, long runs) and files the scene refers to that are pipes,
# devices, folders, symbolic-link loops, empty or missing (meshes, their material libraries and
# texture images, beam tables, pattern tables).

#: The share of cases that are hostile (a third each of objects, aliases, files).
HOSTILE_SHARE = 0.06
#: What a referenced file can be (``ok``: the intended content).
FILE_KINDS = ("ok", "ok", "ok", "fifo", "dir", "missing", "loop", "device", "empty", "garbage")
_SMALL_SONAR = {"preset": "aris3000-128", "n_range_bins": 128, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}}


def _png_bytes() -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray((np.arange(64, dtype=np.uint8).reshape(8, 8) * 4)).save(buf, format="PNG")
    return buf.getvalue()


def _many_objects(rng: np.random.Generator) -> tuple[dict, list[str]]:
    # Up to 10,000: a scene of 20,000 loads in about 2 s on a quiet machine, past the 5 s limit
    # on a loaded one (and tracing allocations triples it).
    n = int(10 ** rng.uniform(2, 4))
    kinds = [{"primitive": "sphere", "radius_m": 0.01}, {"primitive": "box", "size_m": [0.05, 0.05, 0.05]},
             {"primitive": "cylinder", "radius_m": 0.02, "height_m": 0.1}, {"primitive": "sphere", "radius_m": 0.3}]
    xyz = np.column_stack([rng.uniform(1, 4.5, n), rng.uniform(-1, 1, n), rng.uniform(0.02, 0.5, n)])
    objects = []
    for k in range(n):
        obj = dict(kinds[rng.integers(len(kinds))] if k % 50 == 0 else kinds[0])
        obj.update(name=f"o{k}", pose={"position_m": [float(v) for v in xyz[k]]})
        objects.append(obj)
    if rng.random() < 0.1:  # one name given twice, far down the list
        objects[-1]["name"] = objects[int(rng.integers(n))]["name"]
    return {"sonar": dict(_SMALL_SONAR), "ground": {}, "objects": objects}, [f"{n} objects"]


def _alias_text(base: bytes, rng: np.random.Generator) -> tuple[bytes, list[str]]:
    op = int(rng.integers(5))
    if op == 0:  # a bomb: levels of aliases, each repeating the previous
        levels, width = int(rng.integers(2, 12)), int(rng.integers(2, 12))
        text = "b0: &b0 [x" + ", x" * (width - 1) + "]\n" + "".join(
            f"b{i}: &b{i} [" + ", ".join([f"*b{i - 1}"] * width) + "]\n" for i in range(1, levels))
        return base + b"\n" + text.encode(), [f"alias bomb {width}^{levels}"]
    if op == 1:  # an anchor used inside itself
        return base + b"\nloop: &loop {a: [1, *loop]}\n", ["recursive alias"]
    if op == 2:  # a long run of aliases to one anchor
        n = int(10 ** rng.uniform(2, 6))
        return base + b"\nrun: [&r 1" + b", *r" * n + b"]\n", [f"{n} aliases"]
    if op == 3:  # merge keys into the sonar section (valid YAML; the keys are then checked)
        return (b"defaults: &d {range_max_m: 4.0, n_range_bins: 64}\n" + base.replace(b"sonar:\n", b"sonar:\n  <<: *d\n", 1),
                ["merge key"])
    # an alias of the objects list in the planes, or of the sonar as an object
    return base.replace(b"objects:", b"objects: &objs", 1) + b"\nplanes: *objs\n", ["objects aliased as planes"]


def _referenced_files(rng: np.random.Generator) -> tuple[dict, dict, list[str]]:
    kinds = {name: FILE_KINDS[rng.integers(len(FILE_KINDS))] if rng.random() < 0.5 else "ok"
             for name in ("m.obj", "m.mtl", "t.png", "beams.csv", "pattern.csv")}
    contents = {
        "m.obj": b"mtllib m.mtl\nusemtl a\nv 2 -0.5 0.1\nv 2 0.5 0.1\nv 2 0 0.9\nvt 0 0\nvt 1 0\nvt 0.5 1\n"
                 b"f 1/1 2/2 3/3\n",
        "m.mtl": b"newmtl a\nKd 1 1 1\nmap_Kd t.png\n",
        "t.png": _png_bytes(),
        "beams.csv": b"angle_deg\n" + b"".join(f"{a:.2f}\n".encode() for a in np.linspace(14, -14, 32)),
        "pattern.csv": b"angle_deg,gain_db\n-30,-40\n-10,-6\n0,0\n10,-6\n30,-40\n",
    }
    files = {name: (kind, contents[name] if kind != "garbage" else rng.bytes(200)) for name, kind in kinds.items()}
    sonar = dict(_SMALL_SONAR)
    if rng.random() < 0.5:
        sonar["beam_angles_file"] = "beams.csv"
    doc: dict = {"sonar": sonar, "ground": {},
                 "objects": [{"name": "m", "mesh": "m.obj", "material": {"texture": bool(rng.random() < 0.6)}}]}
    if rng.random() < 0.4:
        doc["sensor"] = {"preset": "oculus-m1200d-hf", "azimuth_pattern": {"shape": "table", "table": "pattern.csv"}}
    what = [f"{name} {kind}" for name, kind in kinds.items() if kind != "ok"] or ["every file ok"]
    return doc, files, what


def hostile_case(index: int, rng: np.random.Generator, texts: list, render: bool) -> Case:
    """One hostile case: many objects, aliases, or referenced files (see above)."""
    kind = int(rng.integers(3))
    if kind == 0:
        doc, done = _many_objects(rng)
        return Case(index, "many objects", "doc", done, doc=doc, render=render)
    if kind == 1:
        name, data, suffix = texts[rng.integers(len(texts))]
        if suffix == ".json":
            name, data, suffix = texts[0]
        mutated, done = _alias_text(data, rng)
        return Case(index, name, "text", done, data=mutated, suffix=".yaml", render=render)
    doc, files, done = _referenced_files(rng)
    return Case(index, "referenced files", "files", done, doc=doc, files=files, render=render)


def write_referenced(folder: Path, files: dict[str, tuple[str, bytes]]) -> None:
    """Make each referenced file in ``folder`` as its kind says (``missing``: not at all)."""
    import os

    folder.mkdir(parents=True, exist_ok=True)
    for name, (kind, content) in files.items():
        path = folder / name
        if kind in ("ok", "garbage"):
            path.write_bytes(content)
        elif kind == "empty":
            path.write_bytes(b"")
        elif kind == "fifo":
            os.mkfifo(path)
        elif kind == "dir":
            path.mkdir()
        elif kind == "loop":
            os.symlink(name, path)  # a link to itself
        elif kind == "device":
            os.symlink("/dev/zero", path)


# The check -----------------------------------------------------------------------------------

@dataclass
class Outcome:
    """What a case came to: ``accepted``, ``refused`` (with ``error_key``) or ``failure``."""

    case: Case
    accepted: bool = False
    rendered: bool = False
    # The ConfigError's key (indices dropped: ``objects[].name``), ``render:KEY`` for a refusal
    # at render time, or the kind of a refusal that names no key (``file: invalid YAML``).
    error_key: str | None = None
    failure: str | None = None
    seconds: float = 0.0
    peak_bytes: int = 0


class CaseTimeout(Exception):
    """Raised in the case by the alarm: it ran past its time limit."""


@contextmanager
def time_limit(seconds: float):
    """Interrupt the block with :class:`CaseTimeout` after ``seconds`` (main thread, Unix)."""
    def on_alarm(signum, frame):
        raise CaseTimeout(f"ran past {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def check_error(exc: BaseException, case: Case, path: Path | None) -> str | None:
    """Why the refusal ``exc`` of ``case`` breaks the promise (None: it keeps it).

    The promise: a :class:`SonarsimError`, its message one line, not empty, of readable
    length, naming the file (a file's case) or the key (a ConfigError of a document).
    """
    from sonarsim.errors import ConfigError, SonarsimError

    if not isinstance(exc, SonarsimError):
        return f"{type(exc).__name__} instead of a SonarsimError: {str(exc)[:300]}"
    msg = str(exc)
    if not msg.strip():
        return "empty message"
    if "\n" in msg or "\r" in msg:
        return f"message of {len(msg.splitlines())} lines: {msg[:300]!r}"
    if len(msg) > MAX_MESSAGE_CHARS:
        return f"message of {len(msg)} characters: {msg[:200]!r}..."
    if path is not None and str(path) not in msg:
        return f"message does not name the file: {msg[:300]!r}"
    if path is None and isinstance(exc, ConfigError) and not exc.key and not msg.startswith("must be a mapping"):
        return f"ConfigError naming no key: {msg[:300]!r}"
    return None


def check_scene(scene, budget: int) -> str | None:
    """Why an accepted scene is implausible (None: it is plausible).

    Every number finite and in its documented range, the poses rigid transforms within the
    scene's extent, the images of one frame within ``budget`` (the ray fan is checked when
    rendering: a sample of the accepted scenes is rendered).
    """
    from sonarsim.config.scene import MAX_COORDINATE_M, MAX_LENGTH_M, MAX_ORDER_LIMIT
    from sonarsim.config.sonar import IMAGES_PER_FRAME
    from sonarsim.core.rays import auto_elevation_samples

    s = scene.sonar
    a = np.asarray(s.beam_angles_deg)
    problems = []
    if not (a.size >= 1 and np.all(np.isfinite(a)) and np.all(np.abs(s.beam_edges_deg) < 90)):
        problems.append(f"beam angles {a[:5]}")
    if a.size > 1 and not np.all(np.diff(a) < 0):
        problems.append("beam angles not descending")
    if not 0 < s.elevation_fov_deg < 180:
        problems.append(f"elevation_fov_deg {s.elevation_fov_deg}")
    if not (math.isfinite(s.range_max_m) and 0 <= s.range_min_m < s.range_max_m):
        problems.append(f"range window {s.range_min_m}..{s.range_max_m}")
    if not (isinstance(s.n_range_bins, int) and s.n_range_bins >= 1):
        problems.append(f"n_range_bins {s.n_range_bins!r}")
    if not (math.isfinite(s.range_resolution_m) and s.range_resolution_m > 0):
        problems.append(f"range resolution {s.range_resolution_m}")
    if s.n_range_bins * a.size * 4 * IMAGES_PER_FRAME > budget:
        problems.append(f"images of {s.n_range_bins} x {a.size} beyond the budget")
    for name, pose in [("sonar", scene.sonar_pose)] + [(o.name, o.pose) for o in scene.objects]:
        m = pose.matrix()
        r = m[:3, :3]
        if not (np.all(np.isfinite(m)) and np.allclose(r @ r.T, np.eye(3), atol=1e-6)
                and np.all(np.abs(m[:3, 3]) <= MAX_COORDINATE_M)):
            problems.append(f"pose of {name} not a rigid transform within the scene")
    for o in scene.objects:
        dims = [v for v in (o.radius_m, o.height_m) if v is not None] + list(o.size_m or ())
        dims += list(np.atleast_1d(o.scale))
        if not all(math.isfinite(v) and 0 < v <= MAX_LENGTH_M for v in dims):
            problems.append(f"object {o.name} dimensions {dims}")
    for p in scene.reflecting_planes:
        if not (np.all(np.isfinite(p.point_m)) and abs(np.linalg.norm(p.normal) - 1) < 1e-9):
            problems.append(f"plane {p.name}")
        if not (0 <= p.specular <= 1 and 0 <= p.backscatter.coefficient <= 1):
            problems.append(f"plane {p.name} albedo/specular")
    for o in scene.objects:
        if not (0 <= o.backscatter.coefficient <= 1):
            problems.append(f"object {o.name} albedo {o.backscatter.coefficient}")
    r = scene.render
    if not 1 <= r.max_order <= MAX_ORDER_LIMIT or not r.bounces:
        problems.append(f"max_order {r.max_order} bounces {r.bounces}")
    n_el = auto_elevation_samples(s) if r.elevation_samples == "auto" else int(r.elevation_samples)
    if n_el < 1 or r.azimuth_samples < 1:
        problems.append(f"samples {n_el} x {r.azimuth_samples}")
    return "; ".join(problems) or None


def _render_check(scene, budget: int) -> tuple[bool, str | None, str | None]:
    """Render ``scene`` once, noise-free: (rendered, refusal key, failure)."""
    from sonarsim import Simulator
    from sonarsim.errors import ConfigError

    try:
        with Simulator(scene) as sim:
            img = sim.render(speckle=False, keep_rays=False)
    except ConfigError as exc:
        return False, f"render:{exc.key}", check_error(exc, Case(-1, "", "doc", []), None)
    polar = np.asarray(img.polar)
    shape = (scene.sonar.n_range_bins, scene.sonar.n_beams)
    if polar.shape != shape:
        return True, None, f"rendered shape {polar.shape}, configured {shape}"
    if not np.all(np.isfinite(polar)):
        return True, None, f"rendered image has {int(np.sum(~np.isfinite(polar)))} non-finite pixels"
    if np.any(polar < 0):
        return True, None, f"rendered image has negative intensities (min {polar.min()})"
    return True, None, None


def check_case(case: Case, workdir: Path, budget: int = FUZZ_BUDGET_BYTES, trace_memory: bool = True) -> Outcome:
    """Run one case under ``budget`` and a time limit; the outcome says whether it kept the promise.

    Parameters
    ----------
    case : Case
    workdir : Path
        Folder the text cases are written to (and removed from); the document cases resolve
        relative paths against the examples' folder.
    budget : int
        The memory budget (bytes) the loader and renderer check sizes against; with
        ``trace_memory`` the traced peak of the case must stay within :data:`PEAK_BUDGETS` of it.
    trace_memory : bool
        Trace Python and NumPy allocations (slower) and fail a case whose peak exceeds that.
    """
    from sonarsim.core.memory import set_memory_budget

    import shutil

    out = Outcome(case)
    path = None
    folder = None
    if case.level == "text":
        path = workdir / f"case{case.index}{case.suffix}"
        path.write_bytes(case.data)
    elif case.files is not None:
        folder = workdir / f"case{case.index}"
        write_referenced(folder, case.files)
    set_memory_budget(budget)
    if trace_memory:
        tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            _load_and_render(case, path, budget, out, folder)
    finally:
        out.seconds = time.perf_counter() - t0
        if trace_memory:
            out.peak_bytes = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        set_memory_budget(None)
        if path is not None:
            path.unlink(missing_ok=True)
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
    # An overflow or an invalid value on the way is how silent nonsense starts (a quaternion of
    # 1e300 once became the identity): NumPy's RuntimeWarnings fail the case. UserWarnings
    # (objects that cannot echo) are the library talking to the user.
    numeric = [w for w in seen if issubclass(w.category, RuntimeWarning)]
    if out.failure is None and numeric:
        w = numeric[0]
        out.failure = f"{w.category.__name__} at {Path(w.filename).name}:{w.lineno}: {w.message}"
    if out.failure is None and out.peak_bytes > PEAK_BUDGETS * budget:
        out.failure = (f"traced allocations peaked at {out.peak_bytes / 2**20:.1f} MiB, beyond {PEAK_BUDGETS} x the "
                       f"{budget / 2**20:.0f} MiB budget")
    return out


def _load_and_render(case: Case, path: Path | None, budget: int, out: Outcome, folder: Path | None = None) -> None:
    """Load the case (from ``path``, or its document), check what comes back, render if asked;
    records the outcome in ``out``."""
    from sonarsim.config.loader import load_scene, scene_from_dict

    scene = None
    try:
        with time_limit(LOAD_TIME_LIMIT_S):
            scene = load_scene(path) if path is not None else scene_from_dict(case.doc, base_dir=folder or EXAMPLES)
    except CaseTimeout as exc:
        out.failure = f"load {exc}"
    except Exception as exc:  # noqa: BLE001 - classifying every exception is the point
        out.failure = check_error(exc, case, path)
        key = getattr(exc, "key", None)
        out.error_key = _generic_key(key) if key else _kind_of_file_error(exc, path)
    if scene is None:
        return
    out.accepted = True
    try:
        out.failure = check_scene(scene, budget)
    except Exception as exc:  # noqa: BLE001 - a scene whose own properties fail
        out.failure = f"accepted scene fails on use: {type(exc).__name__}: {str(exc)[:300]}"
    if out.failure is not None or not case.render:
        return
    try:
        with time_limit(RENDER_TIME_LIMIT_S):
            out.rendered, key, out.failure = _render_check(scene, budget)
        if key:
            out.error_key = _generic_key(key)
    except CaseTimeout as exc:
        out.failure = f"render {exc}"
    except Exception as exc:  # noqa: BLE001
        out.failure = f"render: {type(exc).__name__}: {str(exc)[:300]}"


def _kind_of_file_error(exc: BaseException, path: Path | None) -> str:
    """``file: invalid YAML``, ``file: not UTF-8 text``, ...: a refusal naming no key, counted by kind."""
    import re

    msg = str(exc)
    if path is not None and msg.startswith(f"{path}: "):
        msg = msg[len(str(path)) + 2:]
    msg = re.sub(r"'[^']*'|(?<![\w-])\d+(?![\w-])", "_", msg)
    kind = re.split(r" at |:|\(|;", msg, maxsplit=1)[0].strip()
    return f"{'file' if path is not None else 'document'}: {kind}"


def _generic_key(key: str) -> str:
    """``objects[3].pose.rpy_deg[1]`` -> ``objects[].pose.rpy_deg[]``: keys counted together."""
    import re

    return re.sub(r"\[\d+\]", "[]", key)


@dataclass
class Summary:
    """Counts over many outcomes."""

    cases: int = 0
    accepted: int = 0
    rendered: int = 0
    refused: dict[str, int] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)
    slowest_s: float = 0.0
    slowest_case: str = ""
    peak_bytes: int = 0

    def add(self, out: Outcome) -> None:
        self.cases += 1
        self.accepted += out.accepted
        self.rendered += out.rendered
        if out.error_key:
            self.refused[out.error_key] = self.refused.get(out.error_key, 0) + 1
        if out.failure:
            self.failures.append(f"{out.case.describe()}: {out.failure}")
        if out.seconds > self.slowest_s:
            self.slowest_s, self.slowest_case = out.seconds, out.case.describe()
        self.peak_bytes = max(self.peak_bytes, out.peak_bytes)
