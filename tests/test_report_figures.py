"""The corner plot shows the physical parameters with readable labels and units, legibly, in a
small file."""

import pytest

from bayescap.report.plots import CORNER_LABELS, plot_corner

NUISANCE = ("clip_spread_dn", "variance_discrepancy", "mean_discrepancy", "clip_dn")


@pytest.fixture(scope="module")
def basler_result(basler_standard_fit):
    # what `bayescap fit data/emva1288_basler_ccd12.csv --seed 1 --out DIR` plots
    return basler_standard_fit


def test_corner_shows_the_physical_parameters_with_units(basler_result, tmp_path):
    r = basler_result
    path = tmp_path / "corner.png"
    fig = plot_corner(r, path)
    physical = [n for n in CORNER_LABELS if n in r.draws]
    assert len(physical) == 7  # K, read noise, dark current, full well, QE, PRNU, DSNU
    k = len(physical)
    assert len(fig.axes) == k * k
    bottom = fig.axes[(k - 1) * k :]
    xlabels = [ax.get_xlabel() for ax in bottom]
    assert xlabels == [CORNER_LABELS[n][0] for n in physical]
    assert xlabels[0] == "K (e⁻/DN)" and "dark current (e⁻/s)" in xlabels and "PRNU (%)" in xlabels
    text = " ".join(t.get_text() for ax in fig.axes for t in (ax.xaxis.label, ax.yaxis.label, ax.title))
    for n in NUISANCE + tuple(CORNER_LABELS):
        assert n not in text, n
    for ax in bottom:
        assert ax.xaxis.label.get_fontsize() >= 10
        assert min(t.get_fontsize() for t in ax.get_xticklabels()) >= 8
    # the figure is printed at its size: panels of about 1.5 inches, not shrunk from 2
    assert fig.get_size_inches()[0] <= 1.6 * k + 1
    size = path.stat().st_size
    assert size < 300_000, f"corner.png is {size / 1e3:.0f} kB"


def test_corner_keeps_other_formats(basler_result, tmp_path):
    path = tmp_path / "corner.pdf"
    plot_corner(basler_result, path, n_max=2000)
    assert path.read_bytes()[:4] == b"%PDF"


def _vertical_lines(ax):
    return sorted(float(ln.get_xdata()[0]) for ln in ax.lines if len(set(ln.get_xdata())) == 1)


def test_corner_draws_a_limit_as_a_limit(basler_result):
    """The Basler's DSNU is an upper limit in the report and the JSON: its histogram's title gives
    the limit alone and one line marks it; a detected quantity keeps its median and 95 % interval
    (three lines), the report's numbers."""
    r = basler_result
    summary = r.parameter_summary()
    assert summary["dsnu_e"]["limit"]["kind"] == "upper"
    fig = plot_corner(r, n_max=4000)
    physical = [n for n in CORNER_LABELS if n in r.draws]
    k = len(physical)
    diag = {n: fig.axes[i * k + i] for i, n in enumerate(physical)}
    dsnu = diag["dsnu_e"]
    assert dsnu.get_title().splitlines()[1].startswith("< ") and "95 % upper limit" in dsnu.get_title()
    assert _vertical_lines(dsnu) == pytest.approx([summary["dsnu_e"]["limit"]["value"]])
    k_ax = diag["conversion_gain_e_per_dn"]
    s = summary["conversion_gain_e_per_dn"]
    assert _vertical_lines(k_ax) == pytest.approx(sorted([s["ci95"][0], s["median"], s["ci95"][1]]))
    assert "[" in k_ax.get_title() and "limit" not in k_ax.get_title()
