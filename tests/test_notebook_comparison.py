"""Execute notebooks/manufacturer_comparison.ipynb (committed without outputs) with nbclient.

The kernel is this interpreter (the ``python3_kernel`` fixture in conftest.py).
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOK = Path(__file__).resolve().parent.parent / "notebooks" / "manufacturer_comparison.ipynb"


def test_notebook_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
def test_notebook_executes(python3_kernel):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, kernel_name=python3_kernel, timeout=150,
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    t0 = time.perf_counter()
    client.execute()
    print(f"manufacturer_comparison.ipynb executed in {time.perf_counter() - t0:.1f} s")
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "compare: 5 sensors" in text and "compare: 3 sensors" in text
    assert "P(C[M1_1.75um] > C[M2_1.75um])" in text
    assert "P(C[M1_1.75um] > C[M1_2.20um]) at 1/4\"" in text
