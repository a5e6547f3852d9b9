"""The README and the documentation keep up with the code.

The README's first part (up to "What the demo writes") is run as a newcomer would: its shell
commands after the install, its Python block, in a scratch folder. Its links and the files it
names resolve, its test command is CI's, every sub-command is in its command list and in the
command-line page, and every key an object of a scene file takes is described on the scene-file
page."""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sonarsim.cli.main import build_parser
from sonarsim.config.loader import OBJECT_KEYS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: The README's first part ends where this section begins: what comes before it is run.
FIRST_PART_END = "## What the demo writes"


def readme() -> str:
    return README.read_text(encoding="utf-8")


def first_part() -> str:
    text = readme()
    assert FIRST_PART_END in text, f"README.md has no '{FIRST_PART_END}' section"
    return text.split(FIRST_PART_END, 1)[0]


def section(text: str, heading: str) -> str:
    """The ``## heading`` section of a Markdown text, up to the next heading of the same level."""
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, flags=re.M | re.S)
    assert match, f"no '## {heading}' section"
    return match.group(1)


def blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.M | re.S)


def subcommands() -> list[str]:
    parser = build_parser()
    (action,) = [a for a in parser._actions if a.dest == "command"]  # the sub-parsers' action
    return sorted(action.choices)


# ------------------------------------------------------------------------------ shape


def test_the_readme_is_a_page_to_start_from():
    text = readme()
    assert len(text.splitlines()) <= 320, "README.md has grown past about 300 lines: move detail into docs/"
    for heading in ("Requirements", "Two commands", "A first scene in five minutes", "Conventions",
                    "Where to go next"):
        assert re.search(rf"^## {re.escape(heading)}$", text, flags=re.M), f"README.md lacks '## {heading}'"
    assert "python -m pytest -m quick" in text  # the quick subset, beside the full suite's duration
    assert re.search(r"about \d+ minutes on 2 cores", text)


def test_the_readme_test_command_is_what_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = 'pip install -e ".[test,ray,viewer,diff]" && python -m pytest -q'
    assert command in first_part()
    assert re.search(r"^pip install -q -e \"\.\[test,ray,viewer,diff\]\" && python -m pytest -q$", ci, flags=re.M)


def test_every_extra_the_readme_and_ci_install_exists():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    extras = set(tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
                 ["optional-dependencies"])
    named = set()
    for text in (readme(), (ROOT / ".ci" / "run").read_text(encoding="utf-8")):
        for group in re.findall(r'\.\[([a-z,]+)\]', text):
            named |= set(group.split(","))
    assert named and named <= extras, f"extras named but not in pyproject.toml: {sorted(named - extras)}"
    assert "docs" in named


def test_the_readme_links_and_the_files_it_names_exist():
    text = readme()
    headings = {re.sub(r"[^\w\- ]", "", h).strip().lower().replace(" ", "-")
                for h in re.findall(r"^#+ (.+)$", text, flags=re.M)}
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    assert len(links) > 10
    for link in links:
        if link.startswith(("http://", "https://")):
            continue
        path, _, anchor = link.partition("#")
        if not path:
            assert anchor in headings, f"README.md links to #{anchor}, which is no heading of it"
            continue
        assert (ROOT / path).exists(), f"README.md links to {path}, which does not exist"
    # Every example and page it names as code, too (`examples/...`, `docs/...`).
    for name in re.findall(r"`((?:examples|docs|benchmarks)/[\w./-]+)`", text):
        assert (ROOT / name).exists(), f"README.md names {name}, which does not exist"


def test_the_docs_pages_the_readme_names_are_in_the_site():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    for page in set(re.findall(r"\]\(docs/([\w-]+\.md)\)", readme())):
        assert re.search(rf":\s*{re.escape(page)}\s*$", nav, flags=re.M), f"docs/{page} is not in mkdocs.yml's nav"


# ------------------------------------------------------------------------------ the first part runs


def scratch_copy(tmp_path: Path) -> Path:
    """A folder holding the repository's examples, as the README's commands expect them."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples", ignore=shutil.ignore_patterns("*.ipynb"))
    return tmp_path


def sonarsim_commands() -> list[str]:
    """The README first part's shell commands, from ``sonarsim`` on (the venv and install
    steps before it are CI's own)."""
    commands = []
    for block in blocks(first_part(), "bash"):
        for line in block.splitlines():
            for step in (s.strip() for s in line.split("&&")):
                if step.startswith("sonarsim "):
                    commands.append(step)
    return commands


def test_the_first_part_has_commands_to_run():
    commands = sonarsim_commands()
    assert any(c.startswith("sonarsim demo ") for c in commands)
    assert any(c.startswith("sonarsim render examples/") for c in commands)


@pytest.mark.parametrize("command", sonarsim_commands())
def test_every_command_of_the_readme_first_part_runs(tmp_path, command):
    cwd = scratch_copy(tmp_path)
    args = shlex.split(command)
    done = subprocess.run([sys.executable, "-m", "sonarsim", *args[1:]], cwd=cwd, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    out = cwd / args[args.index("--out") + 1]
    assert (out / "fan_figure.png").stat().st_size > 10_000  # a picture a person can open
    assert '"status": "complete"' in (out / "sonarsim-run.json").read_text(encoding="utf-8")


def test_the_readme_figures_the_demo_names_are_written(tmp_path):
    # The first command promises these files to open.
    promised = re.findall(r"`sonarsim-demo/(\w+\.png)`", first_part())
    promised += re.findall(r"`(\w+_figure\.png)`", section(first_part(), "Two commands"))
    assert "fan_figure.png" in promised
    from sonarsim.cli.demo import DEMO_FIGURES

    assert {p.removesuffix(".png") for p in promised} <= set(DEMO_FIGURES)


def test_the_python_block_of_the_readme_first_part_runs(tmp_path):
    (code,) = blocks(first_part(), "python")
    cwd = scratch_copy(tmp_path)
    done = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    written = sorted(p.name for p in cwd.glob("first_z*.png"))
    assert written == ["first_z0.8.png", "first_z1.2.png", "first_z1.6.png"]


def test_the_first_scene_in_the_readme_is_the_example_file():
    # The YAML shown is the example's (comments and layout aside): what it says is what runs.
    import yaml

    from sonarsim.config.loader import load_scene

    (shown,) = blocks(first_part(), "yaml")
    example = ROOT / "examples" / "first_scene.yaml"
    assert yaml.safe_load(shown) == yaml.safe_load(example.read_text(encoding="utf-8"))
    scene = load_scene(example)
    assert scene.sonar_pose.rpy_deg[1] == pytest.approx(25.0)  # the pitch the README explains


# ------------------------------------------------------------------------------ reference pages


def test_the_parser_has_the_commands_we_expect():
    # Guards the tests below against a parser it cannot read (an empty list passes anything).
    assert {"render", "demo", "dataset", "compare", "fit", "calibrate"} <= set(subcommands())


def listed_commands(text: str) -> set[str]:
    block = re.search(r"```text\n(.*?)```", text, flags=re.S)
    assert block, "no ```text block of commands"
    return {m.group(1) for m in re.finditer(r"^sonarsim ([a-z-]+)\b", block.group(1), flags=re.M)}


@pytest.mark.parametrize("command", subcommands())
def test_every_subcommand_is_in_the_readme_command_list(command):
    listed = listed_commands(section(readme(), "Command line"))
    assert command in listed, f"`sonarsim {command}` is missing from README.md's command list"


@pytest.mark.parametrize("command", subcommands())
def test_every_subcommand_is_in_the_command_line_page(command):
    listed = listed_commands((DOCS / "cli.md").read_text(encoding="utf-8"))
    assert command in listed, f"`sonarsim {command}` is missing from docs/cli.md's command list"


@pytest.mark.parametrize("key", OBJECT_KEYS)
def test_every_object_key_is_in_the_scene_file_page(key):
    text = (DOCS / "scene-files.md").read_text(encoding="utf-8")
    # As a key in the example YAML (`key:`), in its comments (`sphere (radius_m)`), or named in
    # the prose (`key`); a bare word would not do: "scale" and "name" are also plain English.
    assert re.search(rf"(?<![\w.]){re.escape(key)}(?=[:),])|`{re.escape(key)}`", text), (
        f"the object key {key!r} is not described in docs/scene-files.md")
