"""Reading scene and scenario documents (issue 21): alias bombs, recursive aliases, long
documents, huge integers, YAML 1.1's base-60 numbers, merge keys and byte-order marks."""

from __future__ import annotations

import time

import pytest

from sonarsim.config import document
from sonarsim.config.document import MAX_ALIASES, MAX_DOCUMENT_BYTES, MAX_DOCUMENT_NODES, read_document
from sonarsim.config.loader import load_scene
from sonarsim.errors import ConfigError, SonarsimError

SCENE = "sonar: {n_beams: 4, azimuth_fov_deg: 20, elevation_fov_deg: 10, range_min_m: 0.5, range_max_m: 5, " \
        "n_range_bins: 50}\n"


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_an_alias_bomb_is_refused_before_it_expands(tmp_path):
    # Nine levels of nine: 387 million values from a few hundred bytes.
    text = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 10))
    p = _write(tmp_path, "bomb.yaml", text)
    with pytest.raises(SonarsimError, match=r"bomb\.yaml: line \d+: the document expands to more than 500,000 values"):
        read_document(p)


def test_a_document_that_expands_just_within_the_limit_is_read(tmp_path):
    # 1 + 100 x (1 + 100 x 1) ... : a list of 49 aliases to a list of 10,000 scalars.
    p = _write(tmp_path, "ok.yaml", "a: &a [" + ", ".join(["1"] * 10_000) + "]\nb: [" + ", ".join(["*a"] * 40) + "]\n")
    doc = read_document(p)
    assert len(doc["b"]) == 40 and doc["b"][0] is doc["a"]  # shared, as PyYAML builds them


def test_a_recursive_alias_is_refused(tmp_path):
    for text in ("a: &a [1, *a]\n", "a: &a {b: *a}\n", "a: &a {b: [c, {d: *a}]}\n"):
        p = _write(tmp_path, "rec.yaml", text)
        with pytest.raises(SonarsimError, match="an anchor is used inside itself"):
            read_document(p)


SCENARIO = ("seed: 0\nscene:\n  " + SCENE + "trajectory: {generate: {kind: orbit, centre_m: [3, 0, 0.2], radius_m: 2.5, "
            "z_m: 1.0, frames: 4}}\n")


def test_a_recursive_alias_in_a_variation_is_refused_naming_the_file(tmp_path):
    from sonarsim.dataset.scenario import load_scenario

    p = _write(tmp_path, "scenario.yaml", SCENARIO + "variation:\n  sensor: &s {gain_db: {choice: [1, *s]}}\n")
    with pytest.raises(SonarsimError, match=r"scenario\.yaml: line \d+: an anchor is used inside itself"):
        load_scenario(p)


def test_a_choice_tree_built_from_aliases_is_refused_in_a_moment(tmp_path):
    # The audit's 747-byte scenario: a choice of choices, nine levels of eight (134 million
    # leaves), ran past 300 s with its memory growing.
    from sonarsim.dataset.scenario import load_scenario

    tree = "{choice: [&c0 {choice: [1, 2, 3, 4, 5, 6, 7, 8]}"
    for i in range(1, 9):
        tree += f", &c{i} {{choice: [" + ", ".join([f"*c{i - 1}"] * 8) + "]}"
    p = _write(tmp_path, "scenario.yaml", SCENARIO + "variation:\n  sensor:\n    gain_db: " + tree + "]}\n")
    assert p.stat().st_size < 1000
    t0 = time.monotonic()
    with pytest.raises(SonarsimError, match=r"scenario\.yaml: line \d+: the document expands to more than 500,000"):
        load_scenario(p)
    assert time.monotonic() - t0 < 30  # a hang guard (6 ms here; before: past 300 s)


def test_a_long_document_is_refused_while_it_is_read(tmp_path):
    n = MAX_DOCUMENT_NODES + 10
    p = _write(tmp_path, "long.yaml", "b: [" + ", ".join(["1"] * n) + "]\n")
    assert p.stat().st_size < MAX_DOCUMENT_BYTES
    with pytest.raises(SonarsimError, match=r"long\.yaml: the document holds more than 500,000 values"):
        read_document(p)


def test_the_largest_alias_document_is_refused_promptly(tmp_path):
    # The worst case of the size limit: a file of nothing but aliases, counted in the text before
    # libyaml composes them. A hang guard, not a benchmark.
    text = ("a: &a [1]\nb: [" + "*a, " * (MAX_DOCUMENT_BYTES // 4))[: MAX_DOCUMENT_BYTES - 2] + "]\n"
    p = _write(tmp_path, "aliases.yaml", text)
    t0 = time.monotonic()
    with pytest.raises(SonarsimError, match=r"aliases\.yaml: 1,048,\d+ aliases \(\*name\); a scene or scenario uses at "
                       r"most 100,000"):
        read_document(p)
    assert time.monotonic() - t0 < 30
    # Just within the count, the expansion decides (each alias here is a list of two values).
    p = _write(tmp_path, "many.yaml", "a: &a [1]\nb: [" + ", ".join(["*a"] * MAX_ALIASES) + "]\n")
    with pytest.raises(SonarsimError, match="expands to more than 500,000 values"):
        p.write_text("a: &a [1, 2, 3, 4, 5, 6]\nb: [" + ", ".join(["*a"] * MAX_ALIASES) + "]\n")
        read_document(p)
    p.write_text("a: &a [1]\nb: [" + ", ".join(["*a"] * MAX_ALIASES) + "]\n")
    assert len(read_document(p)["b"]) == MAX_ALIASES


def test_json_documents_are_bounded_too(tmp_path):
    p = _write(tmp_path, "long.json", "[" + ", ".join(["1"] * (MAX_DOCUMENT_NODES + 10)) + "]")
    with pytest.raises(SonarsimError, match=r"long\.json: the document holds more than 500,000 values"):
        read_document(p)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_an_integer_of_thousands_of_digits_is_refused_naming_the_file(tmp_path, suffix):
    # Python itself refuses to convert more than 4,300 digits (ValueError: a traceback before).
    text = '{"sonar": {"n_beams": ' + "9" * 5000 + "}}"
    p = _write(tmp_path, "big" + suffix, text)
    with pytest.raises(SonarsimError, match=r"big\.(yaml|json).*an integer of 5000 digits"):
        read_document(p)
    # Up to the limit, the number is read and the key that reads it refuses it.
    p = _write(tmp_path, "ok" + suffix, text.replace("9" * 5000, "9" * document.MAX_NUMBER_DIGITS))
    assert read_document(p)["sonar"]["n_beams"] == int("9" * document.MAX_NUMBER_DIGITS)


def test_base_60_numbers_are_strings_not_integers(tmp_path):
    # YAML 1.1 reads 1:30:00 as 5400; a user means no such thing.
    p = _write(tmp_path, "scene.yaml", SCENE.replace("n_beams: 4", "n_beams: 1:30:00"))
    assert read_document(p)["sonar"]["n_beams"] == "1:30:00"
    with pytest.raises(ConfigError, match=r"sonar\.n_beams: must be an integer, got '1:30:00'"):
        load_scene(p)
    # Ordinary numbers are unchanged.
    p = _write(tmp_path, "n.yaml", "a: [1, -2, +3, 0x1f, 0o17, 1_000, 1.5, -.5, 1e3, 1.0e+3, .inf, -.inf, 0b101]\n")
    assert read_document(p)["a"][:6] == [1, -2, 3, 31, "0o17", 1000]
    # Floats as YAML 1.2 and JSON write them (YAML 1.1 read 1e3 and -.5 as strings).
    assert read_document(p)["a"][6:] == [1.5, -0.5, 1000.0, 1000.0, float("inf"), float("-inf"), 5]


def test_merge_keys_are_honoured_and_may_be_overridden(tmp_path):
    # The anchor in a top-level x- key (dropped once read: every other key is checked).
    p = _write(tmp_path, "scene.yaml", "x-rock: &c {primitive: sphere, radius_m: 0.2, albedo: 0.5}\n" + SCENE +
               "objects:\n  - {<<: *c, name: a, pose: {position_m: [2, 0, 0]}}\n"
               "  - {<<: *c, name: b, albedo: 0.9, pose: {position_m: [3, 0, 0]}}\n")
    doc = read_document(p)
    assert "x-rock" not in doc
    assert doc["objects"][1] == {"primitive": "sphere", "radius_m": 0.2, "albedo": 0.9, "name": "b",
                                 "pose": {"position_m": [3, 0, 0]}}
    scene = load_scene(p)
    assert [o.backscatter.coefficient for o in scene.objects] == [0.5, 0.9]
    # Any other unknown top-level key is still refused.
    p = _write(tmp_path, "other.yaml", "rock: &c {primitive: sphere}\n" + SCENE)
    with pytest.raises(ConfigError, match="rock: unknown key"):
        load_scene(p)
    # A key given twice besides the merge is still refused.
    p = _write(tmp_path, "dup.yaml", "c: &c {x: 1}\nd: {<<: *c, y: 1, y: 2}\n")
    with pytest.raises(SonarsimError, match="the key 'y' is given twice"):
        read_document(p)


def test_a_byte_order_mark_is_not_part_of_the_document(tmp_path):
    p = tmp_path / "bom.yaml"
    p.write_bytes(b"\xef\xbb\xbf" + SCENE.encode())
    assert load_scene(p).sonar.n_beams == 4
    p = tmp_path / "bom.json"
    p.write_bytes(b"\xef\xbb\xbf" + b'{"a": 1}')
    assert read_document(p) == {"a": 1}
