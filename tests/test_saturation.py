"""Saturation roll-off: the clip spread's cap and the bounds the model reports."""

import numpy as np

import bayescap
from bayescap.model import PTCModel
from bayescap.simulate import SensorTruth, simulate_ptc


def test_wide_roll_off_is_fitted_not_capped():
    """Full wells spread by 5 % (τ = 150 DN, 5 % of the clip): the spread's truth inside its
    95 % interval (a cap at 2 % of the clip held it at 45 [3, 61] DN)."""
    tr = SensorTruth(2.0, 3.0, 6000, adc_bits=12, full_well_spread_frac=0.05)
    d = simulate_ptc(tr, n_levels=30, shape=(64, 64), seed=7, max_fraction=1.3)
    p = bayescap.fit(d, quality="fast", seed=1).to_dict()["parameters"]
    lo, hi = p["clip_spread_dn"]["ci95"]
    assert lo < tr.full_well_spread_frac * tr.full_well_e / tr.conversion_gain_e_per_dn < hi
    lo, hi = p["full_well_e"]["ci95"]
    assert lo < tr.full_well_e < hi


def test_parameter_bounds_and_a_binding_clip_spread():
    """The model lists its walls; draws pressed against the clip spread's cap are named."""
    d = simulate_ptc(SensorTruth(10.0, 5.0, 30000, adc_bits=12), n_levels=20, shape=(32, 32), seed=4)
    m = PTCModel(d)
    b = m.parameter_bounds()
    assert b["clip_spread_dn"]["relative_to"] == "clip_dn" and b["clip_spread_dn"]["upper"] == m.PRIOR["tau_max_frac"]
    p = m.physical(np.repeat(m.initial_guess()[None, :], 100, axis=0))
    assert "clip_spread_dn" not in m.binding_bounds(p)
    p["clip_spread_dn"] = 0.999 * m.PRIOR["tau_max_frac"] * np.asarray(p.get("clip_dn", m.adc), float) * np.ones(100)
    hit = m.binding_bounds(p)["clip_spread_dn"]
    assert hit["side"] == "upper" and hit["fraction_near"] == 1.0


def test_the_measured_saturated_fraction_bounds_the_clip_spread():
    """With an ADC clip and ``frac_saturated``, the 'saturated' block penalises a clip spread that
    would put pixels at the ADC maximum in rows that have none (a spread standing in for a knee),
    and costs little at the spread the data support. The bundled phone sensor's start point:
    τ ≈ 10 DN, then 5 % and 9 % of the ADC maximum."""
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    m = PTCModel.for_fit(d)
    assert m.terms.clip == "adc" and m.sat_rows.size
    x = m.initial_guess()

    def saturated_loglik(tau_dn):
        y = x.copy()
        y[m.idx["log_tau"]] = np.log(tau_dn)
        return float(m.loglik_terms(y[None])["saturated"].sum())

    fitted, wide, wider = (saturated_loglik(t) for t in (np.exp(x[m.idx["log_tau"]]), 0.05 * m.adc, 0.09 * m.adc))
    assert fitted > -10 and wide < fitted - 50 and wider < wide
    # the block's rows are the data's file rows, and a model without the column has no such block
    assert set(m.observation_rows("saturated")) <= set(np.asarray(d.row_numbers).tolist())
    d2 = d.select(np.ones(d.n_levels, bool))
    object.__setattr__(d2, "frac_saturated", None)
    assert "saturated" not in PTCModel.for_fit(d2).loglik_terms(x[None])


def test_rows_below_the_first_saturated_pixel_are_response_evidence_when_the_adc_clips_first():
    """A row with every pixel at the ADC maximum: the wells hold more than the ADC reads, so the
    rows above 90 % of the peak variance's signal without a saturated pixel are unclipped evidence
    (a soft knee there is the response's). Without ``frac_saturated`` the 90 % rule keeps them out
    (a well that clips first would bend the means there too)."""
    from bayescap.model.terms import _unclipped_rows, saturation_flags

    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    full, _ = saturation_flags(d)
    sig = d.mean_dn - d.dark_mean_dn
    top = sig > 0.9 * sig[np.argmax(np.where(full, -np.inf, d.temporal_var_dn2))]
    ok = _unclipped_rows(d, full)
    assert np.any(ok & top) and not np.any(ok & (d.frac_saturated > 0))
    d2 = d.select(np.ones(d.n_levels, bool))
    object.__setattr__(d2, "frac_saturated", None)
    assert not np.any(_unclipped_rows(d2, full) & top)
