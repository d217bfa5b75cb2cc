"""The response non-linearity term (bayescap.model.response): chosen when the means bend against
the photons, K unbiased on a compressive sensor, EMVA 1288's LE reported with an interval."""

import dataclasses

import numpy as np
import pytest

import bayescap
from bayescap.io.ptc_csv import PTCData
from bayescap.model import select_terms
from bayescap.model.response import response, response_inverse
from bayescap.physics.linearity import linearity_error_percent
from bayescap.simulate import SensorTruth, simulate_ptc

TRUTH = SensorTruth(10.0, 5.0, 30000, dark_current_e_per_s=5, adc_bits=12, response_nonlinearity=0.04)


def _rows(d, keep):
    kw = {}
    for f in (
        "exposure_time_s",
        "mean_dn",
        "temporal_var_dn2",
        "dark_mean_dn",
        "dark_temporal_var_dn2",
        "n_pixels",
        "photons_per_pixel",
        "frac_saturated",
        "row_numbers",
    ):
        v = getattr(d, f)
        kw[f] = None if v is None else np.asarray(v)[keep]
    return PTCData(**kw, metadata=d.metadata, source=d.source)


def test_response_inverse_and_le():
    x = np.linspace(0.0, 1000.0, 11)
    for a in (-0.2, -0.03, 0.0, 0.1):
        assert np.allclose(response_inverse(response(x, a, 1000.0), a, 1000.0), x, rtol=1e-12, atol=1e-9)
    # a linear response has LE 0; a quadratic one LE ∝ |a| (EMVA's line over 5–95 %)
    le = linearity_error_percent(lambda x: response(x, np.array([[0.0], [-0.02], [-0.04]]), 1.0), 1.0)
    assert le[0] < 1e-9 and le[2] == pytest.approx(2 * le[1], rel=0.02) and 0.2 < le[1] < 1.0


def test_linear_sensor_leaves_the_term_out():
    d = simulate_ptc(SensorTruth(10.0, 5.0, 30000, adc_bits=12), n_levels=20, shape=(48, 48), seed=5)
    t = select_terms(d)
    assert not t.nonlinearity and "linear" in t.reasons["response_nonlinearity"]


def test_compressive_sensor_brings_in_the_term_on_all_rows_and_below_70_percent():
    """The statistical check's input below: the 4 % compressive response is chosen from the means'
    bend against the photons on all rows and on the rows below 70 % of saturation."""
    d = simulate_ptc(TRUTH, n_levels=24, shape=(64, 64), seed=3)
    s = d.mean_dn - d.dark_mean_dn
    for keep in (np.ones(s.size, bool), s < 0.7 * s.max()):
        assert select_terms(_rows(d, keep)).nonlinearity


@pytest.mark.statistical  # two fits whose 95 % intervals must hold K; benchmarks/statistical_tests.py runs it
def test_compressive_sensor_k_unbiased_and_stable_to_rows():
    """A 4 % compressive response: K's truth (its small-signal gain) inside the 95 % interval on all
    rows and on the rows below 70 % of saturation, the two intervals overlapping, LE reported.
    (A linear model gives K ≈ 10.5 with an interval of ± 0.1 here.)"""
    d = simulate_ptc(TRUTH, n_levels=24, shape=(64, 64), seed=3)
    s = d.mean_dn - d.dark_mean_dn
    cis = []
    for keep in (np.ones(s.size, bool), s < 0.7 * s.max()):
        r = bayescap.fit(_rows(d, keep), quality="fast", seed=1)
        out = r.to_dict()
        assert r.model.terms.nonlinearity
        lo, hi = out["parameters"]["conversion_gain_e_per_dn"]["ci95"]
        assert lo < TRUTH.conversion_gain_e_per_dn < hi
        cis.append((lo, hi))
        a = out["parameters"]["response_nonlinearity"]
        assert a["ci95"][1] < 0  # compressive, detected
        assert out["derived"]["linearity_error_percent"]["ci95"][0] > 0.2
    assert cis[0][0] < cis[1][1] and cis[1][0] < cis[0][1]


# ---------------------------------------------------------------- without photon counts
# a 12-bit camera with a 4 % compressive response, measured as EMVA 1288 asks (many levels, a large
# ROI), its CSV without the photons_per_pixel column: only the PTC's bend tells the non-linearity
NO_PHOTONS = SensorTruth(10.0, 12.0, 30000, dark_current_e_per_s=5, adc_bits=12, response_nonlinearity=0.04)


def _without_photons(d, keep=None):
    d = dataclasses.replace(d, photons_per_pixel=None)
    return d if keep is None else d.select(keep)


def test_linear_sensor_without_photons_leaves_the_curvature_out():
    truth = dataclasses.replace(NO_PHOTONS, response_nonlinearity=0.0)
    d = _without_photons(simulate_ptc(truth, n_levels=30, shape=(200, 200), seed=3))
    t = select_terms(d)
    assert not t.nonlinearity and "PTC is straight" in t.reasons["response_nonlinearity"]


def test_compressive_sensor_without_photons_fits_the_ptc_curvature():
    """Without photons the bend of the temporal PTC selects the term; K's truth (the small-signal gain)
    inside the 95 % interval on all rows and on the rows below 70 % of saturation, the two intervals
    overlapping. (The linear model gives K ≈ 10.3–10.5 [± 0.1] on such data.)"""
    d = simulate_ptc(NO_PHOTONS, n_levels=30, shape=(200, 200), seed=3)
    s = d.mean_dn - d.dark_mean_dn
    cis = []
    for keep in (np.ones(s.size, bool), s < 0.7 * s.max()):
        dd = _without_photons(d, keep)
        t = select_terms(dd)
        assert t.nonlinearity and "PTC bends" in t.how["response_nonlinearity"]
        r = bayescap.fit(dd, terms=t, quality="fast", seed=1)
        out = r.to_dict()
        lo, hi = out["parameters"]["conversion_gain_e_per_dn"]["ci95"]
        assert lo < NO_PHOTONS.conversion_gain_e_per_dn < hi
        # the response's deviation at S_ref: compressive, its truth inside the (wide: the variances
        # alone shape the response) interval. Truth: S = x/(1 + b·x/x_top), b = c/(1 − c)
        b = NO_PHOTONS.response_nonlinearity / (1 - NO_PHOTONS.response_nonlinearity)
        x_top = dd.adc_max_dn - float(np.median(dd.dark_mean_dn))
        s_ref = r.model.response_ref_dn
        x_ref = s_ref / (1 - b * s_ref / x_top)
        dev = out["parameters"]["response_nonlinearity"]
        assert dev["median"] < 0 and dev["ci95"][0] < 1 / (1 + b * x_ref / x_top) - 1 < dev["ci95"][1]
        cis.append((lo, hi))
    assert cis[0][0] < cis[1][1] and cis[1][0] < cis[0][1]


def test_full_well_without_photons_spans_both_readings_of_the_bend():
    """Without photon counts the bend is the response's (bent means: the charge at the clip is K·x(c))
    or brighter-fatter's (straight means: K·(c − black)): half the draws take each reading, the same
    draw always the same one, and the note says so. With photons only the response's reading."""
    d = simulate_ptc(NO_PHOTONS, n_levels=30, shape=(200, 200), seed=3)
    r = bayescap.fit(_without_photons(d), quality="fast", seed=1)
    m = r.model
    assert m.response_share_unknown
    th = r.chains.chain.reshape(-1, m.ndim)[::7]
    p = m.physical(th)
    straight = (p["clip_dn"] - m.black_dn) * p["conversion_gain_e_per_dn"]
    bent = np.isclose(p["full_well_e"], straight, rtol=1e-12)
    assert 0.4 < bent.mean() < 0.6  # a fair coin per draw over ~1000 draws: ± 0.05 is 3 sd
    # a compressive response: more charge at the clip (most draws; the variances alone shape it loosely)
    assert np.mean(p["full_well_e"][~bent] > straight[~bent]) > 0.9
    # the same draw reads the same way in another chunk
    again = m.physical(th[1::2])["full_well_e"]
    assert np.array_equal(again, p["full_well_e"][1::2])
    note = r.to_dict()["parameters"]["full_well_e"]["note"]
    assert "brighter-fatter" in note and "both readings" in note
    with_photons = bayescap.fit(d, quality="fast", seed=1)
    assert not with_photons.model.response_share_unknown
    assert "both readings" not in (with_photons.to_dict()["parameters"]["full_well_e"].get("note") or "")


def test_the_richer_log_slope_only_for_a_knee():
    """response_degree_evidence on signals against photons with 3e-4 relative scatter: a soft knee
    in the top quarter needs the richer log-slope (F-test p < RICH_P_VALUE), a quadratic
    compression (exactly a low-degree curve) does not."""
    from bayescap.model.response import RICH_P_VALUE, response_degree_evidence

    rng = np.random.default_rng(3)
    u = np.linspace(0.02, 1.0, 40)
    knee = np.where(u <= 0.75, u, 0.75 + 0.2 * np.tanh((u - 0.75) / 0.2))
    for y, rich in ((knee, True), (u * (1.0 - 0.08 * u), False)):
        s = 3000.0 * y * (1.0 + 3e-4 * rng.standard_normal(u.size))
        p, n = response_degree_evidence(1e5 * u, s, s, np.ones(u.size, bool))
        assert n == u.size and (p < RICH_P_VALUE) == rich
