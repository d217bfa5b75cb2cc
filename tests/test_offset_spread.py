"""Rounding without spatial columns: the spread of the pixels' mean offsets (DSNU) about the DN
grid is a nuisance parameter, so rounding is averaged over it (pixel_offset_spread_dn)."""

import numpy as np
import pytest

import bayescap
from bayescap.model import select_terms
from bayescap.simulate import SensorTruth, simulate_ptc

# 8-bit, K = 100 e-/DN (read noise 0.05 DN), DSNU 0.3 DN spreading the offsets, no spatial columns
TRUTH = SensorTruth(100, 5.0, 30000, dark_current_e_per_s=10, adc_bits=8, black_level_dn=4, dsnu_e=30)


def test_dsnu_spread_offsets_keep_k_and_read_noise_honest():
    """With one offset assumed for every pixel the fit put K 4 % high with a tight interval and the
    read noise at 22 e- (truth 5)."""
    d = simulate_ptc(TRUTH, n_levels=16, shape=(64, 64), seed=23)
    r = bayescap.fit(d, quality="fast", seed=1)
    assert r.model.terms.offset_spread
    p = r.to_dict()["parameters"]
    lo, hi = p["conversion_gain_e_per_dn"]["ci95"]
    assert lo < TRUTH.conversion_gain_e_per_dn < hi
    assert p["read_noise_e"]["ci95"][0] < TRUTH.read_noise_e < 2 * p["read_noise_e"]["ci95"][1]
    lo, hi = p["pixel_offset_spread_dn"]["ci95"]
    assert lo < TRUTH.dsnu_e / TRUTH.conversion_gain_e_per_dn < hi


BOUNDARY = SensorTruth(12.0, 1.2, 9000, dark_current_e_per_s=5.0, adc_bits=10, black_level_dn=64.5, dsnu_e=6.0)


def test_offsets_across_the_rounding_boundary_bring_in_the_offset_spread():
    """The statistical check's input below (no spatial columns, read noise 0.1 DN, offsets spread
    across the rounding boundary): the offset spread enters the model."""
    d = simulate_ptc(BOUNDARY, n_levels=16, shape=(64, 64), seed=5)
    assert d.spatial_var_dn2 is None or not np.isfinite(d.spatial_var_dn2).any()
    assert select_terms(d).offset_spread


@pytest.mark.statistical  # a fit whose 95 % intervals must hold the truths; benchmarks/statistical_tests.py runs it
def test_offsets_spread_across_the_rounding_boundary():
    """10-bit, read noise 0.1 DN (1.2 e-, K 12 e-/DN), black level at the rounding boundary and a
    DSNU of 0.5 DN spreading the offsets across it, no spatial columns: the dark noise √(σ² + D·t)
    (1.20-1.24 e-) inside the read noise's interval. With one offset for all pixels the fit gave a
    variance discrepancy of 80 % and a read noise of 3.4 e- [1.27, 4.97]."""
    tr = BOUNDARY
    d = simulate_ptc(tr, n_levels=16, shape=(64, 64), seed=5)
    p = bayescap.fit(d, quality="fast", seed=1).to_dict()["parameters"]
    lo, hi = p["read_noise_e"]["ci95"]
    dark_noise_e = np.sqrt(tr.read_noise_e**2 + tr.dark_current_e_per_s * np.median(d.exposure_time_s))
    assert lo < dark_noise_e < hi, (lo, hi, dark_noise_e)
    assert hi < 1.3  # ... and measured, not an upper limit at several e-
    lo, hi = p["conversion_gain_e_per_dn"]["ci95"]
    assert lo < tr.conversion_gain_e_per_dn < hi
    assert p["variance_discrepancy"]["median"] < 0.05
