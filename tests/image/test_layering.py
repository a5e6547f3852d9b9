"""Layers without circles (issue 23, item 5): the image types import nothing above them (plot,
io, renderer, analysis), not even inside a method, and the figures nothing of analysis; the
image types' pictures and files still work, through the hooks that the layers above register
(sonarsim.image.display)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sonarsim
from sonarsim.image import display

SRC = Path(sonarsim.__file__).resolve().parent
PNG = b"\x89PNG\r\n\x1a\n"


def imported_modules(path: Path) -> set[str]:
    """Every sonarsim module a file imports, at module level or inside a function (absolute names)."""
    package = "sonarsim." + ".".join(path.relative_to(SRC).with_suffix("").parts[:-1])
    package = package.rstrip(".")
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - (node.level - 1)])
                module = base + ("." + node.module if node.module else "")
            else:
                module = node.module or ""
            names.add(module)
            names.update(f"{module}.{a.name}" for a in node.names)  # ``from .. import plot``
    return {n for n in names if n == "sonarsim" or n.startswith("sonarsim.")}


def offending(folder: str, forbidden: tuple[str, ...]) -> dict[str, list[str]]:
    found = {}
    for path in sorted((SRC / folder).glob("*.py")):
        bad = sorted(m for m in imported_modules(path) if any(m == f or m.startswith(f + ".") for f in forbidden))
        if bad:
            found[path.name] = bad
    return found


def test_the_parser_sees_relative_and_lazy_imports():
    # The checker itself: a lazy relative import inside a method is found.
    assert "sonarsim.image.display" in imported_modules(SRC / "image" / "result.py")
    assert "sonarsim.io.output" in imported_modules(SRC / "plot" / "figures.py")
    assert "sonarsim.image.fan" in imported_modules(SRC / "plot" / "figures.py")  # inside a function


def test_the_image_types_import_nothing_above_them():
    assert offending("image", ("sonarsim.plot", "sonarsim.analysis", "sonarsim.renderer", "sonarsim.io")) == {}


def test_the_figures_import_nothing_of_analysis():
    assert offending("plot", ("sonarsim.analysis",)) == {}


def synthetic():
    from tests.plot.test_figures import point_target, synthetic

    return synthetic(point_target(), single=point_target())


def test_pictures_and_files_work_after_import_sonarsim(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    image = synthetic()
    assert image._repr_png_().startswith(PNG)
    image.save(tmp_path / "fan.png")
    assert (tmp_path / "fan.png").read_bytes().startswith(PNG)
    image.save(tmp_path / "polar.svg", kind="polar")
    assert (tmp_path / "polar.svg").read_bytes().startswith(b"<?xml")
    image.save_npz(tmp_path / "image.npz")
    with np.load(tmp_path / "image.npz") as z:
        np.testing.assert_array_equal(z["polar"], image.polar)
    fan = image.fan()
    assert fan._repr_png_().startswith(PNG)
    fan.save(tmp_path / "fan2.png")
    assert (tmp_path / "fan2.png").read_bytes().startswith(PNG)


def test_import_sonarsim_alone_installs_every_hook():
    # A fresh interpreter: nothing but ``import sonarsim``; light (neither NumPy nor matplotlib).
    code = ("import sys, sonarsim\n"
            "from sonarsim.image import display\n"
            "print(sorted(display.registered()) == sorted(display.HOOKS),"
            " 'numpy' in sys.modules, 'matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "False", "False"]


def test_a_missing_hook_says_which_module_provides_it(monkeypatch):
    image = synthetic()
    monkeypatch.setattr(display, "_registered", {})
    with pytest.raises(display.MissingHookError, match=r"SonarImage\._repr_png_ needs sonarsim\.plot\.notebook"):
        image._repr_png_()
    with pytest.raises(display.MissingHookError, match=r"SonarImage\.save_npz needs sonarsim\.io\.output"):
        image.save_npz("never.npz")
    with pytest.raises(display.MissingHookError, match=r"FanImage\.save needs sonarsim\.plot\.notebook"):
        image.fan().save("never.png")
    # The text repr needs no hook.
    assert repr(image).startswith("SonarImage(")


def test_register_refuses_an_unknown_hook():
    with pytest.raises(KeyError, match="no image hook 'paint'"):
        display.register("paint", print)
