"""Execute the notebooks (committed without outputs) with nbclient and check what they state and
that every figure they draw is shown.

The kernel is this interpreter (the ``python3_kernel`` fixture in conftest.py). A figure counts as
shown when the cell's outputs carry it as ``image/png`` (a ``display_data`` or ``execute_result``),
which is what Jupyter draws; a notebook that selects the Agg backend, or leaves a pyplot-free
``Figure`` undisplayed, shows no image.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"

#: notebook -> (execution timeout per cell in s, fragments its printed output must contain,
#: number of figures it shows)
EXPECTED = {
    "colour_depth.ipynb": (
        120,
        [
            "noise gain R, G, B",
            "K check passed",
            "colour depth (CS clipped after M, as bayescap colour prints)",
            "at an 8-Mpixel print",
            "raw cube, unclipped",
            "superpixel",
            "cs_luminance_mtf",
        ],
        # CCM noise gains, CS intervals (clipped after M as bayescap colour prints, and the raw cube
        # unclipped), capacities by definition
        3,
    ),
    "paper_reproduction.ipynb": (
        90,
        [
            # a few of the numbers the markdown states
            "photons per lux·s per µm² 4090.7",
            "lens limits at Nyquist below 2.68 µm",
            "Eq. 9 optimum 1.2",
            "shared parameters across gains",
            "measured detector MTF at",
            "verdicts:",
        ],
        # Figs. 1(c), 2(a), 2(b), 3, the MPE30/MTF50 trade-off, Fig. 4, Figs. 5-6, Fig. 7, Fig. 8(a-b), binning
        10,
    ),
    "manufacturer_comparison.ipynb": (
        150,
        [
            "compare: 5 sensors",
            "compare: 3 sensors",
            "P(C[M1_1.75um] > C[M2_1.75um])",
            'P(C[M1_1.75um] > C[M1_2.20um]) at 1/4"',
            "x Table 1 ranges",
        ],
        # Fig. 8(a) TR(H0), the same with the Table 1 ranges, Fig. 8(b) capacity, Figs. 5-6 SNR(H),
        # the probability matrix
        5,
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


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_leaves_the_backend_to_jupyter(name):
    """``matplotlib.use("Agg")`` (or any backend choice) in a notebook hides its figures in Jupyter."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    src = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    assert "matplotlib.use(" not in src and "MPLBACKEND" not in src


def image_outputs(nb) -> list[bytes]:
    """The PNG images an executed notebook shows, in order."""
    import base64

    return [
        base64.b64decode(o["data"]["image/png"])
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.outputs
        if o.output_type in ("display_data", "execute_result") and "image/png" in o.get("data", {})
    ]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_executes(name, python3_kernel):
    timeout, fragments, n_figures = EXPECTED[name]
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
    images = image_outputs(nb)
    assert len(images) == n_figures, f"{name} shows {len(images)} figures, expected {n_figures}"
    for png in images:
        assert png.startswith(b"\x89PNG") and len(png) > 5000
