"""Execute the notebooks (committed without outputs) with nbclient and check what they state.

The kernel is this interpreter (the ``python3_kernel`` fixture in conftest.py).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"

#: notebook -> (execution timeout per cell in s, fragments its printed output must contain)
EXPECTED = {
    "paper_reproduction.ipynb": (
        90,
        [
            # a few of the numbers the markdown states
            "photons per lux·s per µm² 4090.7",
            "lens limits at Nyquist below 2.68 µm",
            "Eq. 9 optimum 1.20",
        ],
    ),
    "manufacturer_comparison.ipynb": (
        150,
        [
            "compare: 5 sensors",
            "compare: 3 sensors",
            "P(C[M1_1.75um] > C[M2_1.75um])",
            'P(C[M1_1.75um] > C[M1_2.20um]) at 1/4"',
        ],
    ),
}


def test_every_notebook_is_checked():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_committed_without_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_executes(name, python3_kernel):
    timeout, fragments = EXPECTED[name]
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = nbclient.NotebookClient(
        nb, kernel_name=python3_kernel, timeout=timeout, resources={"metadata": {"path": str(NOTEBOOKS)}}
    )
    t0 = time.perf_counter()
    client.execute()
    print(f"{name} executed in {time.perf_counter() - t0:.1f} s")
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    for frag in fragments:
        assert frag in text, frag
