"""The README keeps up with the code: every sub-command is in its command list, and every key an
object of a scene file takes is described in its scene-file section."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from sonarsim.cli.main import build_parser
from sonarsim.config.loader import OBJECT_KEYS

README = Path(__file__).resolve().parents[1] / "README.md"


def section(text: str, heading: str) -> str:
    """The README's ``## heading`` section, up to the next heading of the same level."""
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, flags=re.M | re.S)
    assert match, f"README.md has no '## {heading}' section"
    return match.group(1)


def subcommands() -> list[str]:
    parser = build_parser()
    (action,) = [a for a in parser._actions if a.dest == "command"]  # the sub-parsers' action
    return sorted(action.choices)


def test_the_parser_has_the_commands_we_expect():
    # Guards the test below against a parser it cannot read (an empty list passes anything).
    assert {"render", "demo", "dataset", "compare", "fit", "calibrate"} <= set(subcommands())


@pytest.mark.parametrize("command", subcommands())
def test_every_subcommand_is_in_the_readme_command_list(command):
    text = section(README.read_text(encoding="utf-8"), "Command line")
    block = re.search(r"```text\n(.*?)```", text, flags=re.S)
    assert block, "the Command line section has no ```text block of commands"
    listed = {m.group(1) for m in re.finditer(r"^sonarsim ([a-z-]+)\b", block.group(1), flags=re.M)}
    assert command in listed, f"`sonarsim {command}` is missing from README.md's command list"


@pytest.mark.parametrize("key", OBJECT_KEYS)
def test_every_object_key_is_in_the_readme_scene_section(key):
    text = section(README.read_text(encoding="utf-8"), "Scene files")
    # As a key in the example YAML (`key:`), in its comments (`sphere (radius_m)`), or named in
    # the prose (`key`); a bare word would not do: "scale" and "name" are also plain English.
    assert re.search(rf"(?<![\w.]){re.escape(key)}(?=[:),])|`{re.escape(key)}`", text), (
        f"the object key {key!r} is not described in README.md's 'Scene files' section")
