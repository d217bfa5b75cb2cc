"""Execute notebooks/paper_reproduction.ipynb (committed without outputs) with nbclient.

The kernel is this interpreter (``sys.executable``): a kernelspec pointing at it is written to a
temporary JUPYTER_PATH, so the test works in a fresh venv where only ``pip install -e .[test]``
ran and the venv is not activated (the stock ``python3`` kernelspec runs whatever ``python`` is
on PATH).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOK = Path(__file__).resolve().parent.parent / "notebooks" / "paper_reproduction.ipynb"
KERNEL = "bayescap-test-python"


@pytest.fixture
def kernel_name(tmp_path, monkeypatch):
    spec_dir = tmp_path / "kernels" / KERNEL
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "bayescap test kernel", "language": "python"}))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    return KERNEL


def test_notebook_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
def test_notebook_executes(kernel_name):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, kernel_name=kernel_name, timeout=90,
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    # a few of the numbers the markdown states
    assert "photons per lux·s per µm² 4090.7" in text
    assert "lens limits at Nyquist below 2.68 µm" in text
    assert "Eq. 9 optimum 1.20" in text
