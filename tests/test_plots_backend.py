"""Plotting leaves matplotlib's global state alone: no backend switch (which would turn a
notebook's display off) and no change to rcParams."""

from pathlib import Path

import matplotlib
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def svg_backend():
    before = matplotlib.get_backend()
    matplotlib.use("svg")
    try:
        yield
    finally:
        matplotlib.use(before)


def test_plots_keep_the_backend_and_rcparams(svg_backend, tmp_path):
    import bayescap
    from bayescap.report.plots import plot_corner, plot_ptc

    # a small bundled sensor whose fast fit takes its fast path (0.7 s; the Basler set's, 2 s)
    result = bayescap.fit(ROOT / "data/benchmark/M1_1.75um.csv", quality="fast", seed=1)
    rc = dict(matplotlib.rcParams)
    assert matplotlib.get_backend() == "svg"
    fig = plot_ptc(result, tmp_path / "ptc.png")
    assert matplotlib.get_backend() == "svg"
    assert fig.axes and (tmp_path / "ptc.png").stat().st_size > 0
    fig = plot_corner(result, tmp_path / "corner.png", n_max=500)
    assert matplotlib.get_backend() == "svg"
    assert fig.axes and (tmp_path / "corner.png").stat().st_size > 0
    assert dict(matplotlib.rcParams) == rc


def test_report_figures_keep_the_backend(svg_backend):
    from bayescap.report.html import _png, plot_capacity, plot_snr_sensor, plot_tr_h0
    from bayescap.studies.compare import compare

    cmp = compare(
        [ROOT / "data/benchmark/M1_1.75um.csv", ROOT / "data/benchmark/M2_1.75um.csv"],
        seed=1,
        quality="fast",
        n_draws=500,
    )
    rc = dict(matplotlib.rcParams)
    for fig in (plot_capacity(cmp), plot_tr_h0(cmp), plot_snr_sensor(cmp.sensors[0])):
        assert _png(fig)
        assert matplotlib.get_backend() == "svg"
    assert dict(matplotlib.rcParams) == rc
