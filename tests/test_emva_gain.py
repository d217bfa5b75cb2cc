"""The EMVA view's system gain K is the standard's definition applied to the fitted model: the
unweighted straight line of Δσ²_y against Δμ_y through the origin over the standard's sensitivity
rows. With the response term (the Basler set) that is an average gain, not bayescap's small-signal
conversion gain; with a linear response the two are the same number."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import bayescap
from bayescap.posterior.emva import N_PEAK_DRAWS, _model_gain, _Sweep, emva1288_view

LINEAR_CSV = Path(__file__).resolve().parents[1] / "data" / "simulated" / "sim_industrial_3p45um_12bit.csv"
EMVA1288_INVERSE_K = 3.5706  # emva1288 1.0.2 on the bundled Basler table: 1/K in e-/DN


def _fast_fit(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bayescap.fit(path, seed=1, quality="fast")


def _recipe_inverse_k_se(sw):
    """Standard error (e-/DN) of the recipe's 1/K: the unweighted slope through the origin has
    se² = s²/Σx², s² the rows' residual scatter about the line (here far above their sampling error,
    so the scatter, not the pixel count, sets it)."""
    x = sw.signal[sw.sens]
    y = (sw.s2_y - sw.s2_dark)[sw.sens]
    K = np.sum(x * y) / np.sum(x * x)
    s2 = np.sum((y - K * x) ** 2) / (x.size - 1)
    return float(np.sqrt(s2 / np.sum(x * x)) / K**2)


def test_basler_gain_is_the_standards_average_not_the_small_signal_gain(basler_fast_fit):
    r = basler_fast_fit  # the Basler table's fast fit at seed 1 (_fast_fit's call): the session's, tests/conftest.py
    assert r.model.terms.nonlinearity  # the set's compressive response (a ≈ −0.02) is selected
    view = emva1288_view(r)
    q = view["quantities"]
    inv = q["inverse_K"]
    assert inv["recipe"] == pytest.approx(EMVA1288_INVERSE_K, rel=1e-4)
    lo, hi = inv["ci95"]
    assert q["K"]["median"] * inv["median"] == pytest.approx(1.0, rel=1e-3)
    # the recipe's value is an estimate with its own error: 1.96 of its standard errors either side
    tol = 1.96 * _recipe_inverse_k_se(_Sweep(r.model.data))
    assert lo - tol <= EMVA1288_INVERSE_K <= hi + tol, (lo, hi, tol)
    # the small-signal gain lies below the average gain's interval (the response compresses)
    k_lo, k_hi = np.quantile(r.draws["conversion_gain_e_per_dn"], [0.025, 0.975])
    assert k_hi < lo
    assert inv["bayescap"].startswith("not ") and "small-signal" in inv["note"]
    assert any("small-signal gain" in n for n in view["notes"])  # what the electron quantities use
    # the fit's own result carries the same gain beside K, so a user sees both without the datasheet
    der = r.to_dict()["derived"]["emva1288_gain_e_per_dn"]
    assert der["median"] == pytest.approx(inv["median"], rel=2e-3)
    assert der["ci95"][0] > k_hi


def test_linear_sensor_gain_is_the_conversion_gain():
    """A linear simulated sensor (the response term not selected): per draw the model's line over
    the standard's rows has slope 1/conversion_gain to rounding error (dark variances above the
    0.2 DN² below which the exact rounding moments would bend the line)."""
    r = _fast_fit(LINEAR_CSV)
    assert not r.model.terms.nonlinearity
    idx = r.thin_index(N_PEAK_DRAWS)
    K = _model_gain(r, _Sweep(r.model.data), idx)
    k = r.draws["conversion_gain_e_per_dn"][idx]
    assert np.allclose(K * k, 1.0, rtol=0, atol=1e-12)
    inv = emva1288_view(r)["quantities"]["inverse_K"]
    assert inv["bayescap"] == "conversion_gain_e_per_dn"
    assert inv["median"] == pytest.approx(np.median(k), rel=1e-12)
    assert "emva1288_gain_e_per_dn" not in r.to_dict()["derived"]  # the same number as K: not repeated
