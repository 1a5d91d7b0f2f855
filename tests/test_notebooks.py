"""The notebooks are stored without outputs, execute top to bottom (nbclient), print the
paper's figures and draw figures."""

from __future__ import annotations

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"

EXPECTED = {
    "01_kinematics_and_calibration.ipynb": [
        "k = 0.224, delta_max = 8.00 deg, theta_max = 84.00 deg",  # the paper's Sec. V.A
        "delta at 60 deg = 5.71 deg",
        "PCC (best fit)",
        "(true 0.21)",
    ],
    "02_one_point_solver.ipynb": ["RANSAC", "efficiency"],
    "03_smoothing_vs_chain.ipynb": ["smoother  RMS per segment", "500-599"],
}


def test_every_notebook_is_listed() -> None:
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebooks_are_stored_without_outputs(name: str) -> None:
    """Outputs are what a run printed with the code of its day: stored, they go stale the next
    time the code changes. The notebooks are stored clean, and the test below runs them."""
    book = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [cell for cell in book.cells if cell.cell_type == "code"]
    assert code
    assert [cell.execution_count for cell in code if cell.outputs or cell.execution_count] == []


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_executes(name: str) -> None:
    book = nbformat.read(NOTEBOOKS / name, as_version=4)
    for cell in book.cells:  # run from scratch: stored outputs must not satisfy the checks
        if cell.cell_type == "code":
            cell.outputs = []
    client = nbclient.NotebookClient(book, timeout=180, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()  # raises CellExecutionError on any failing cell
    text, images = [], 0
    for cell in book.cells:
        for output in cell.get("outputs", []):
            assert output.output_type != "error"
            if output.output_type == "stream":
                text.append(output.text)
            elif "image/png" in output.get("data", {}):
                images += 1
    printed = "".join(text)
    for expected in EXPECTED[name]:
        assert expected in printed, expected
    assert images >= 1  # the figures are drawn, not just built
