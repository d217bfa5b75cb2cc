"""bayescap.studies.fig4_bands: Fig. 4 with every uncertain input drawn; the optimum reflects the
inputs, not the grid."""

from __future__ import annotations

import numpy as np
import pytest

from bayescap.studies import fig4_bands as F
from bayescap.studies import sweep


def test_optimum_does_not_depend_on_the_grid():
    """C(P) is smooth (PCHIP b', spline Δs), so a parabola through the grid maximum finds the same
    optimum on a 0.005 and a 0.0125 µm grid: to well under a thousandth of a µm, draw by draw."""
    fine = F.capacity_bands(n_draws=300, seed=3)
    coarse = F.capacity_bands(np.round(np.arange(1.0, 3.0 + 1e-9, 0.0125), 10), n_draws=300, seed=3)
    assert np.max(np.abs(fine.optimal_pitch_draws_um - coarse.optimal_pitch_draws_um)) < 5e-4


def test_eq8_optimum_does_not_stick_to_a_table_pitch():
    """With b' linear between Table 1 pitches the Eq. 8 optimum cannot pass the kink at 1.75 µm
    (its distribution ends there); with PCHIP the density falls off smoothly before it."""
    b = F.capacity_bands(
        np.round(np.arange(1.3, 2.0 + 1e-9, 0.005), 10), sources=("table1",), n_draws=400, seed=0, method="eq8"
    )
    o = b.optimal_pitch_draws_um
    assert np.mean(np.abs(o - 1.75) < 0.01) < 0.01  # no pile-up at the knot
    assert 1.5 < np.median(o) < 1.75


def test_each_source_widens_the_eq9_optimum():
    """Only the Table 1 ranges: the optimum (in the extrapolated region below 1.45 µm) barely moves.
    Drawing the TR slope or the wavelength widens it: these are the inputs the optimum depends on."""
    w = {}
    for src in (("table1",), ("table1", "tr_slope"), ("table1", "wavelength"), F.SOURCES):
        lo, hi = F.capacity_bands(n_draws=400, seed=1, sources=src).optimum_summary()["ci95_um"]
        w[src] = hi - lo
    assert w[("table1",)] < 0.01
    assert w[("table1", "tr_slope")] > 5 * w[("table1",)]
    assert w[("table1", "wavelength")] > 5 * w[("table1",)]


def test_paper_recipe_is_recovered_without_extra_sources():
    """Without drawn slope and wavelength, Δs at 555 nm equals the sweep's Δs to the spline's
    accuracy, and b' at a Table 1 pitch is that pitch's own TR."""
    b = F.capacity_bands(n_draws=50, seed=0, sources=("table1",))
    p = np.array([1.75, 2.2, 2.9])
    ds, _ = sweep.delta_s_vs_pitch(p)
    k = [int(np.argmin(abs(b.pitch_um - x))) for x in p]
    np.testing.assert_allclose(b.delta_s_draws[0, k], ds, atol=1e-6)
    # PCHIP passes through b' at the Table 1 pitches, draw by draw
    t = list(b.table_pitch_um).index(2.2)
    np.testing.assert_allclose(b.tr_bits_draws[:, k[1]], b.table_tr_bits_draws[:, t], rtol=1e-12)


def test_bad_source():
    with pytest.raises(ValueError, match="unknown uncertainty sources"):
        F.capacity_bands(sources=("lens",))


def test_cli_sweep_bands(capsys):
    """``bayescap sweep pixel-size --bands ...`` adds the optimum with the drawn inputs; a bad
    source is refused with status 2 and one line."""
    import json

    from bayescap.cli.sweep import main

    assert main(["pixel-size", "--draws", "200", "--bands", "table1,wavelength", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    b = d["optimal_pitch_bands"]
    assert b["sources"] == ["table1", "wavelength"] and b["n_draws"] == 200
    direct = F.capacity_bands(
        np.round(np.arange(1.0, 5.2 + 1e-9, 0.005), 10), sources=("table1", "wavelength"), n_draws=200, seed=0
    ).optimum_summary()
    assert b["ci95_um"] == direct["ci95_um"]
    assert main(["pixel-size", "--bands", "table1,lens"]) == 2
    err = capsys.readouterr().err
    assert "--bands" in err and err.strip().count("\n") == 0
