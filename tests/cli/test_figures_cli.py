"""Every command writes its annotated figures beside its exact-pixel PNGs, registers them in its
run record, writes SVG/PDF when asked, and none with --no-figures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

import sonarsim
from sonarsim.cli import main as cli
from sonarsim.io.run_record import RECORD_NAME, read_record

from tests.cli.test_cli import TINY_SCENE

PNG = b"\x89PNG\r\n\x1a\n"


def run_main(capsys, *args) -> tuple[int, str]:
    code = cli.main([str(a) for a in args])
    return code, capsys.readouterr().err


@pytest.fixture()
def tiny_scene(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY_SCENE))
    return path


def recorded(folder: Path) -> list[str]:
    doc = read_record(folder / RECORD_NAME)
    assert doc["status"] == "complete"
    return sorted(e["name"] for e in doc["files"])


def test_render_writes_and_registers_its_figures_and_leaves_the_pngs_as_they_were(capsys, tmp_path, tiny_scene):
    with_figures, without = tmp_path / "a", tmp_path / "b"
    code, err = run_main(capsys, "render", tiny_scene, "--out", with_figures)
    assert code == 0, err
    names = ["fan.png", "fan_figure.png", "polar.png", "polar_figure.png", "render.npz"]
    assert sorted(os.listdir(with_figures)) == sorted([*names, RECORD_NAME])
    assert recorded(with_figures) == names
    assert (with_figures / "fan_figure.png").read_bytes().startswith(PNG)
    assert f"wrote {with_figures / 'fan_figure.png'}" in err
    code, err = run_main(capsys, "render", tiny_scene, "--out", without, "--no-figures")
    assert code == 0, err
    assert recorded(without) == ["fan.png", "polar.png", "render.npz"]
    assert "figure" not in " ".join(os.listdir(without))
    for name in ("fan.png", "polar.png"):  # the exact-pixel images do not depend on the figures
        assert (with_figures / name).read_bytes() == (without / name).read_bytes()


def test_svg_and_pdf_on_request_and_stale_figures_removed(capsys, tmp_path, tiny_scene):
    out = tmp_path / "out"
    code, err = run_main(capsys, "render", tiny_scene, "--out", out, "--figure-format", "svg,pdf", "--colormap", "grey")
    assert code == 0, err
    figures = sorted(n for n in os.listdir(out) if "_figure" in n)
    assert figures == ["fan_figure.pdf", "fan_figure.svg", "polar_figure.pdf", "polar_figure.svg"]
    assert (out / "fan_figure.svg").read_bytes().startswith(b"<?xml")
    assert (out / "polar_figure.pdf").read_bytes().startswith(b"%PDF")
    assert set(figures) <= set(recorded(out))
    # The same folder with PNG figures: the SVG and PDF of the earlier run are stale.
    code, err = run_main(capsys, "render", tiny_scene, "--out", out)
    assert code == 0, err
    assert sorted(n for n in os.listdir(out) if "_figure" in n) == ["fan_figure.png", "polar_figure.png"]


def test_a_bad_figure_format_is_refused_on_one_line(capsys, tmp_path, tiny_scene):
    with pytest.raises(SystemExit) as exc:
        cli.main(["render", str(tiny_scene), "--out", str(tmp_path / "o"), "--figure-format", "png,tiff"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--figure-format must be a comma-separated list of png, svg, pdf" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_show_writes_figures_in_the_devices_counts(capsys, tmp_path, shared_data):
    out = tmp_path / "out"
    recording = shared_data / "real" / "oculus" / "three_pings_8bit.raw"
    code, err = run_main(capsys, "show", recording, "--out", out, "--frame", "2")
    assert code == 0, err
    assert recorded(out) == ["fan.png", "fan_figure.png", "polar.png", "polar_figure.png"]
    code, err = run_main(capsys, "show", recording, "--out", out, "--no-figures")
    assert code == 0, err
    assert sorted(os.listdir(out)) == ["fan.png", "polar.png", RECORD_NAME]


def test_compare_writes_a_figure_only_with_out(capsys, tmp_path, tiny_scene, monkeypatch):
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    sonarsim.render(sonarsim.load_scene(tiny_scene)).save_npz(a)
    doc = yaml.safe_load(tiny_scene.read_text())
    doc["sonar"]["pose"]["position_m"][2] += 0.1
    sonarsim.render(doc).save_npz(b)
    monkeypatch.chdir(tmp_path)
    before = sorted(os.listdir(tmp_path))
    code, err = run_main(capsys, "compare", a, b)
    assert code == 0, err
    assert sorted(os.listdir(tmp_path)) == before  # prints its table, writes nothing
    out = tmp_path / "cmp"
    code, err = run_main(capsys, "compare", a, b, "--out", out, "--figure-format", "png,svg")
    assert code == 0, err
    assert recorded(out) == ["compare_figure.png", "compare_figure.svg"]
    # Matplotlib draws text as glyphs, each text's string in a comment beside them: the panels' titles.
    svg = (out / "compare_figure.svg").read_text()
    assert "A: a.npz" in svg and "B: b.npz" in svg


def test_colormap_takes_matplotlibs_spelling_of_grey(capsys, tmp_path):
    from sonarsim.cli.main import build_parser

    for spelling in ("gray", "Grey", "GRAY"):
        args = build_parser().parse_args(["render", "s.yaml", "--out", str(tmp_path), "--colormap", spelling])
        assert args.colormap == "grey"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["render", "s.yaml", "--out", str(tmp_path), "--colormap", "jet"])
    assert "invalid choice: 'jet'" in capsys.readouterr().err
