"""examples/differentiable.ipynb runs from top to bottom on the CPU (issue 24 item 7)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "differentiable.ipynb"


def test_the_differentiable_notebook_runs_and_shows_its_figures():
    pytest.importorskip("jax")
    nbformat = pytest.importorskip("nbformat", reason="the test extra's nbformat is not installed")
    nbclient = pytest.importorskip("nbclient", reason="the test extra's nbclient is not installed")
    pytest.importorskip("ipykernel", reason="the test extra's ipykernel is not installed")

    nb = nbformat.read(NOTEBOOK, as_version=4)
    t0 = time.perf_counter()
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    elapsed = time.perf_counter() - t0
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    pictures = [cell for cell in code if any("image/png" in out.get("data", {}) for out in cell.outputs)]
    text = "".join(out.get("text", "") for cell in code for out in cell.outputs)
    assert len(pictures) >= 2 + ("held-out PSNR" in text), [cell.source[:40] for cell in code if cell not in pictures]
    assert "refined" in text and "RMS height error over the seen vertices" in text
    assert "held-out PSNR" in text or "../shared/data is absent" in text
    print(f"the notebook took {elapsed:.1f} s")
