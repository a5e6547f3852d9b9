"""examples/sonarsim_tour.ipynb runs from top to bottom (nbclient), so it never rots."""

from __future__ import annotations

from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[2] / "examples" / "sonarsim_tour.ipynb"


def test_the_tour_runs_and_shows_pictures():
    nbformat = pytest.importorskip("nbformat", reason="the test extra's nbformat is not installed")
    nbclient = pytest.importorskip("nbclient", reason="the test extra's nbclient is not installed")
    pytest.importorskip("ipykernel", reason="the test extra's ipykernel is not installed")

    nb = nbformat.read(NOTEBOOK, as_version=4)
    # Run where it lies (it reads oculus_floor.yaml and ../../shared/data from there); an error in
    # any cell raises CellExecutionError naming the cell.
    nbclient.NotebookClient(nb, timeout=120, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    pictures = [cell for cell in code if any("image/png" in out.get("data", {}) for out in cell.outputs)]
    # The demo's fan, the components, Fig. 9, the polar image, the multipath figure, the comparison
    # (and the recording when ../shared/data is there).
    assert len(pictures) >= 6, [cell.source[:40] for cell in code if cell not in pictures]
    text = "".join(out.get("text", "") for cell in code for out in cell.outputs)
    assert "SonarImage(aris3000-128" in text
    assert "OculusRecording(" in text or "../shared/data is absent" in text
    assert "L (" in text  # to_pil: an 8-bit grey image
    # Its duration (about a minute on a quiet machine) is the README's figure, not a test's: a
    # loaded machine takes longer with nothing wrong; the cells' timeout above guards a hang.
