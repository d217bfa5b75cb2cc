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
