"""Quantities the data determine only as limits are printed as limits in every output: the HTML
comparison report and the EMVA 1288 datasheet print ``< value (95 % upper limit)`` alone, never a
median with an interval (the Basler CCD's dark current and DSNU are upper limits in its fast fit with a
linear response; with the response non-linearity its data select, the dark current is measured)."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import bayescap
from bayescap.model import select_terms
from bayescap.posterior.emva import emva1288_view
from bayescap.report.datasheet import _fmt, datasheet_html, emva_limits
from bayescap.report.html import _quantity_row


@pytest.fixture(scope="module")
def basler_fast(basler_csv):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = bayescap.load(basler_csv)
        return bayescap.fit(
            data,
            seed=1,
            quality="fast",
            terms=select_terms(data, force={"nonlinearity": False, "brighter_fatter": False}),
        )


def _row(page, label):
    """The table row (``<tr>...</tr>``) of ``page`` whose text contains ``label``."""
    rows = [r for r in re.findall(r"<tr>.*?</tr>", page, flags=re.S) if label in r]
    assert len(rows) >= 1, label
    return rows[0]


def test_basler_fast_fit_has_upper_limits(basler_fast):
    p = basler_fast.to_dict()["parameters"]
    assert p["dark_current_e_per_s"]["limit"]["kind"] == "upper"
    assert p["dsnu_e"]["limit"]["kind"] == "upper"


def test_html_report_prints_limits_alone(basler_fast):
    """The rows of the HTML report's parameter and derived tables (its ``_quantity_row``, on the
    result's JSON as ``render_html`` calls it; the whole page takes ~15 s of figures)."""
    d = basler_fast.to_dict()
    lim = d["parameters"]["dark_current_e_per_s"]["limit"]
    row = "".join(_quantity_row("dark_current_e_per_s", d["parameters"]["dark_current_e_per_s"]))
    assert "&lt; " in row and "(95 % upper limit)" in row and f"{lim['value']:.4g}" in row, row
    assert "[" not in row, row  # no median [95 % interval]
    for group in ("parameters", "derived"):
        for k, v in d[group].items():
            cell = _quantity_row(k, v)[1]
            assert ("limit" in cell) == bool(v.get("limit")), (k, cell)
            assert ("[" in cell) == (not v.get("limit") and v.get("median") is not None), (k, cell)


def test_datasheet_prints_limits_alone(basler_fast):
    view = emva1288_view(basler_fast)
    params = basler_fast.to_dict()["parameters"]
    limits = emva_limits(view, params)
    # the quantities equal to a limited parameter carry its limit; those following it their own 97.5 % end
    assert limits["u_I_var"]["value"] == params["dark_current_e_per_s"]["limit"]["value"]
    assert limits["DSNU1288"]["value"] == params["dsnu_e"]["limit"]["value"]
    assert limits["DSNU1288_DN"] == {
        "kind": "upper",
        "value": view["quantities"]["DSNU1288_DN"]["ci95"][1],
        "level": 0.975,
        "because": "dsnu_e",
    }
    assert "K" not in limits and "QE" not in limits
    page = datasheet_html(basler_fast, view=view)
    row = _row(page, "Dark current from variance")
    assert "&lt; " in row and "(95 % upper limit)" in row and "e-/s" in row, row
    assert " – " not in row, row  # no interval beside it
    assert "(97.5 % upper limit)" in _row(page, "DSNU in DN")
    k = _row(page, "<td>K</td>")
    assert " – " in k and "limit" not in k


def test_datasheet_pdf_table_prints_limits_alone(basler_fast):
    """The PDF's table rows: the limit and its kind in place of a median and an interval."""
    from bayescap.report.datasheet_pdf import _rows

    view = emva1288_view(basler_fast)
    limits = emva_limits(view, basler_fast.to_dict()["parameters"])
    rows = {r[1]: r for r in _rows(view, limits)}
    lim = limits["u_I_var"]
    assert rows["μ_I.var"][3:5] == [f"< {_fmt(lim['value'])}", "(95 % upper limit)"]
    assert rows["DSNU1288.DN"][4] == "(97.5 % upper limit)"
    assert rows["K"][3] == _fmt(view["quantities"]["K"]["median"]) and " – " in rows["K"][4]


def _summary_with_draws(model, draws):
    """The parameter summaries of a result holding ``draws`` (no chains: every draw counts)."""
    from bayescap.posterior import FitResult

    r = FitResult(model=model, chains=None, metadata={}, scene=None, mtf=None, seed=0, quality="", draws=draws)
    return r.parameter_summary()


def test_read_noise_below_the_quantization_floor_is_limited_at_the_floor(tmp_path):
    """A tight read-noise posterior below 0.4 DN rests on the rounding model alone: its limit is
    at least the floor. Constructed like the zoo's i37_8bit_k100_dsnu (8-bit, K = 100 e-/DN, read
    5 e- = 0.05 DN), whose fit gave 4.78 [4.66, 4.88] e- and an upper limit of 4.86 e-."""
    from bayescap.model import PTCModel
    from bayescap.simulate import SensorTruth, simulate_ptc

    truth = SensorTruth(100.0, 5.0, 30000.0, dark_current_e_per_s=10.0, adc_bits=8, black_level_dn=4.0)
    simulate_ptc(truth, n_levels=12, seed=3, path=tmp_path / "s.csv")
    model = PTCModel(bayescap.load(tmp_path / "s.csv"))
    rng = np.random.default_rng(0)
    n = 4000
    draws = model.physical(np.repeat(np.atleast_2d(model.initial_guess()), n, axis=0))
    draws["conversion_gain_e_per_dn"] = rng.normal(100.0, 0.3, n)
    draws["read_noise_e"] = rng.normal(4.78, 0.06, n)
    s = _summary_with_draws(model, draws)["read_noise_e"]
    assert s["constrained"] is False and s["limit"]["kind"] == "upper"
    assert s["limit"]["value"] == s["upper_limit_95"] >= 0.4 * 100.0 * 0.999 > truth.read_noise_e
    assert s["ci95"][1] < truth.read_noise_e  # the posterior itself stays as it is, in ci95
