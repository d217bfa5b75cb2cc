"""Practical differences in comparisons (issue 49): the ratio beside P(C_A > C_B), and the
probability that one capacity exceeds the other by more than δ, which the matrix is coloured by."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bayescap.studies import compare as C


def _sensor(name, draws):
    return SimpleNamespace(name=name, basis="full_range", draws={"capacity_full_bits": draws})


def _cmp(draws, delta=0.01):
    sensors = [_sensor(f"s{i}", d) for i, d in enumerate(draws)]
    rng = np.random.default_rng(0)
    pairs = [
        C._pair(i, j, sensors[i], sensors[j], rng, delta)
        for i in range(len(sensors))
        for j in range(i + 1, len(sensors))
    ]
    return C.Comparison(sensors=sensors, pairs=pairs, conventions={"area": None, "practical_difference": delta})


def test_a_tiny_sure_difference_is_not_a_practical_one():
    """The issue's case: ratio 1.0019 [1.0003, 1.0034] gives P(C_A > C_B) ≈ 0.99, but with δ = 1 %
    neither sensor is practically larger and they are practically equivalent."""
    rng = np.random.default_rng(1)
    b = 1.6e6 * (1 + 0.0006 * rng.standard_normal(4000))
    a = 1.0019 * 1.6e6 * (1 + 0.0006 * rng.standard_normal(4000))
    pr = _cmp([a, b]).pairs[0]
    assert pr["p_a_greater_full"] > 0.98
    assert pr["ratio_full"]["median"] == pytest.approx(1.0019, abs=3e-4)
    assert pr["p_a_practically_greater_full"] < 1e-6 and pr["p_b_practically_greater_full"] < 1e-6
    assert pr["p_equivalent_full"] > 0.999


def test_practical_probability_is_exact_over_all_pairs():
    x, y = np.array([1.0, 1.5, 2.0]), np.array([1.0, 1.2])
    # X > 1.1·Y: 1.5 > 1.1, 1.32; 2.0 > both; 1.0 > none -> 4 of 6
    assert C.prob_practically_greater(x, y, 0.1) == pytest.approx(4 / 6)
    assert C.prob_practically_greater(x, y, 0.0) == C.prob_greater(x, y)


def test_matrix_is_coloured_by_the_practical_probability():
    from bayescap.report.compare_plots import plot_probability_matrix

    rng = np.random.default_rng(2)
    base = 1e6 * (1 + 0.001 * rng.standard_normal(3000))
    cmp = _cmp([1.002 * base[rng.permutation(3000)], base, 1.2 * base[rng.permutation(3000)]], delta=0.01)
    fig = plot_probability_matrix(cmp, "full")
    shown = fig.axes[0].images[0].get_array()
    practical = cmp.practical_matrix("full")
    np.testing.assert_allclose(np.ma.filled(shown, np.nan), practical)
    assert cmp.probability_matrix("full")[0, 1] > 0.9 and practical[0, 1] < 0.01  # sure, but not practical
    assert practical[2, 0] > 0.99 and practical[0, 2] < 0.01
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert any("×1.002" in t for t in texts)  # the ratio beside the probability
    assert "δ = 1 %" in fig.axes[0].get_title()


def test_coinciding_curves_differ_in_line_style_and_marker():
    from matplotlib.figure import Figure

    from bayescap.report.compare_plots import _band

    ax = Figure().subplots()
    x = np.geomspace(1e-3, 10, 61)
    d = np.tile(np.log(x), (50, 1))
    for k in range(5):
        _band(ax, x, d, f"C{k}", f"s{k}", k=k)
    styles = {(str(ln.get_linestyle()), ln.get_marker()) for ln in ax.lines}
    assert len(styles) == 5


def test_cli_prints_the_practical_difference(capsys):
    from bayescap.cli import main

    bench = Path(__file__).resolve().parents[1] / "data" / "benchmark"
    argv = ["compare", str(bench / "M1_1.75um.csv"), str(bench / "M2_1.75um.csv"), "--no-progress"]
    assert main([*argv, "--practical-difference", "0.05", "--area", "none"]) == 0
    out = capsys.readouterr().out
    assert "δ = 5%" in out and "P(A>B+5%)" in out and "C_A/C_B" in out
    assert main([*argv, "--rope", "1.5"]) == 2
    assert "--practical-difference" in capsys.readouterr().err
