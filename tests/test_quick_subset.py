"""The quick subset (``pytest -m quick``): registered, its modules exist and span the layers."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from tests.conftest import QUICK_MODULES

ROOT = Path(__file__).resolve().parents[1]


def test_the_marker_is_registered_in_pyproject():
    if sys.version_info < (3, 11):
        tomllib = pytest.importorskip("tomli")
    else:
        import tomllib
    options = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert any(m.split(":")[0] == "quick" for m in options["markers"])


def test_the_subset_spans_every_layer_with_files_that_exist():
    assert all((ROOT / m).is_file() and m.startswith("tests/") and m.endswith(".py") for m in QUICK_MODULES)
    layers = {Path(m).parts[1] for m in QUICK_MODULES}
    assert {"core", "config", "scene", "trace", "paths", "reference", "renderer", "image", "sensor", "io",
            "analysis", "dataset"} <= layers


def test_this_module_is_marked_quick(request):
    assert request.node.get_closest_marker("quick") is not None
