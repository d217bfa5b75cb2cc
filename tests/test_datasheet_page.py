"""The EMVA 1288 datasheet as a user reads it (issue 49): one K on the page (the plot's line is the
table's K, the small-signal gain named apart), defaults shown as defaults and an operating-point
block, a measured dark noise printed as a measurement with one exposure time (its split into read
noise and dark current as the limits they are), ``--json`` carrying every limit the page prints, and
linearity notes that agree with the fitted value."""

from __future__ import annotations

import json
import re
import warnings

import pytest

import bayescap
from bayescap.cli import main
from bayescap.posterior.emva import emva1288_view
from bayescap.report.datasheet import _fmt, datasheet_html, emva_limits, operating_point, ptc_figure


@pytest.fixture(scope="module")
def basler(basler_fast_fit):
    r = basler_fast_fit  # bayescap.fit of the Basler table, seed 1, fast: the session's (tests/conftest.py)
    return r, emva1288_view(r)


@pytest.fixture(scope="module")
def one_time(tmp_path_factory):
    """A frame-simulated sensor measured at one exposure time (0.1 s): read noise 4.5 e-, dark
    current 50 e-/s, so the dark noise is sqrt(4.5² + 5) = 5.02 e- (bayescap.validation.zoo)."""
    from bayescap.validation.zoo import ensure_csv, truths, zoo

    zs = next(z for z in zoo() if z.name == "acq_one_t_light_sweep")
    path = ensure_csv(zs, tmp_path_factory.mktemp("zoo"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = bayescap.fit(path, seed=1, quality="fast")
    return r, emva1288_view(r), truths(zs), path


def _legend(fig):
    return [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]


def test_ptc_plot_uses_the_tables_k_and_names_the_small_signal_gain_apart(basler):
    r, view = basler
    assert "response_nonlinearity" in r.draws  # the Basler's response bends: two gains differ
    k = view["quantities"]["K"]["median"]
    k0 = 1.0 / float(__import__("numpy").median(r.draws["conversion_gain_e_per_dn"]))
    labels = _legend(ptc_figure(r, view))
    main_line = next(t for t in labels if t.startswith("K = "))
    assert _fmt(k) in main_line and "EMVA 1288" in main_line
    small = next(t for t in labels if "small-signal" in t)
    assert _fmt(k0) in small and _fmt(k0) != _fmt(k)
    page = datasheet_html(r, view=view)
    assert f"<td class=n>{_fmt(k)}</td>" in page  # the table's K is the plot's


def test_defaults_are_marked_and_the_operating_point_is_given(basler):
    r, view = basler
    assert set(r.flags["metadata_defaults"]) == {"f_number", "wavelength_nm", "fill_factor"}
    op = dict(operating_point(r))
    assert op["wavelength"] == "not given (bayescap assumes 555 nm)"
    assert op["temperature"] == "not given" and op["gain"] == "not given"
    assert op["exposure time"].endswith("(51 times)")
    page = datasheet_html(r, view=view)
    assert "id=operating-point" in page
    for key in ("f_number", "wavelength_nm", "fill_factor"):
        row = re.search(rf"<tr><td>{key}</td><td>([^<]*)</td></tr>", page).group(1)
        assert row.endswith("(default, not from the CSV)"), row
    assert re.search(r"<tr><td>adc_bits</td><td>12</td></tr>", page)  # the CSV's own, unmarked


def test_one_exposure_time_prints_the_measured_dark_noise_as_a_measurement(one_time):
    r, view, truth, _ = one_time
    sd = view["quantities"]["sigma_d"]
    assert sd["bayescap"] == "dark_noise_e" and "limit" not in sd
    lo, hi = sd["ci95"]
    assert lo <= truth["dark_noise_e"][0] <= hi  # the combined dark noise, measured
    assert "combined" in sd["name"]
    split = view["dark_noise_split"]
    assert split["exposure_time_s"] == pytest.approx(0.1)
    assert split["read_noise_e"]["kind"] == "upper" and split["read_noise_e"]["value"] >= truth["read_noise_e"][0]
    assert split["dark_current_e_per_s"]["value"] >= truth["dark_current_e_per_s"][0]
    page = datasheet_html(r, view=view)
    row = next(x for x in re.findall(r"<tr>.*?</tr>", page, flags=re.S) if "<td>σ_d</td>" in x)
    assert "limit)" not in row and f"{_fmt(lo)} – {_fmt(hi)}" in row  # no "(95 % upper limit)"
    assert "read noise &lt; " in page and "dark current &lt; " in page


@pytest.mark.parametrize("which", ["basler", "one_time"])
def test_json_carries_every_limit_the_page_prints(which, request, tmp_path):
    r, view = request.getfixturevalue(which)[:2]
    page = datasheet_html(r, view=view)
    limits = emva_limits(view)
    assert limits  # the Basler's DSNU; the one-time sensor's DSNU
    for key, lim in limits.items():
        it = view["quantities"][key]
        assert it["limit"] == {k: lim[k] for k in ("kind", "value", "level")} and it["constrained"] is False
        sign = "&lt;" if lim["kind"] == "upper" else "&gt;"
        assert f"{sign} {_fmt(lim['value'])}" in page, key
    printed = re.findall(r"(&lt;|&gt;) ([-0-9.e+]+)[^<]*?limit\)", page)
    assert len(printed) == len(limits) + (2 if "dark_noise_split" in view else 0)


def test_datasheet_json_file_has_the_limits(one_time, tmp_path):
    _, view, _, path = one_time
    out = tmp_path / "sheet.json"
    assert main(["datasheet", str(path), "-o", str(tmp_path / "s.html"), "--json", str(out), "--seed", "1",
                 "--quality", "fast", "-q"]) == 0  # fmt: skip
    doc = json.loads(out.read_text())
    assert {k for k, v in doc["quantities"].items() if v.get("limit")} == set(emva_limits(view))
    assert "dark_noise_split" in doc


def test_linearity_notes_agree_with_the_fitted_value(basler):
    r, view = basler
    q = view["quantities"]
    assert q["LE"]["bayescap"] == "derived.linearity_error_percent" and q["LE"]["ci95"] is not None
    for key in ("LE_min", "LE_max"):
        note = q[key]["note"]
        assert "the fitted response's LE" in note and "instead" not in note, note
