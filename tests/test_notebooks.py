"""Every notebook runs top to bottom on a fresh kernel; committed notebooks carry no outputs."""

import nbformat
import pytest
from conftest import ROOT
from nbclient import NotebookClient

NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
#: Per-cell limit [s]: the longest cell (the short work-precision sweep) takes a few seconds.
CELL_TIMEOUT = 300


def test_the_three_notebooks_exist():
    names = [p.name for p in NOTEBOOKS]
    assert names == [
        "01_planar_3r.ipynb",
        "02_industrial_arm_estop.ipynb",
        "03_speed_vs_accuracy.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_committed_notebook_is_stripped(path):
    nb = nbformat.read(path, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, cell.source[:60]


@pytest.mark.parametrize(
    "path",
    # the first in the default run; the two longer ones (~15-20 s each) in the slow run
    [p if i == 0 else pytest.param(p, marks=pytest.mark.slow) for i, p in enumerate(NOTEBOOKS)],
    ids=[p.stem for p in NOTEBOOKS],
)
def test_notebook_runs_without_error(path):
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(
        nb,
        timeout=CELL_TIMEOUT,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    client.execute()  # raises CellExecutionError with the cell and traceback on any error
    images = [
        output
        for cell in nb.cells
        if cell.cell_type == "code"
        for output in cell.outputs
        if "image/png" in output.get("data", {})
    ]
    assert len(images) >= 2, "the notebook's figures were not displayed"
