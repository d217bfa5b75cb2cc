"""Small seeded simulation-based calibration (issue 6); the full run is ``benchmarks/sbc.py``.

The 30 seeded sensors of ``tests/test_coverage.py``: classic SBC, the truths drawn from the proper
prior ``benchmarks/sbc.py::SBC_PRIOR`` that every fit uses (``draw_sensor_prior``; variance and
mean discrepancies injected into the simulated data), fitted once per session with the
``standard`` sampler. The truth is ranked among L = 99 posterior draws thinned by the integrated
autocorrelation time (Talts et al. 2018), for every parameter and for capacity; with truths from
the fit's own prior the ranks are exactly uniform for a correct model and sampler.

Tolerance for the small sample: the ranks (0..99) go into 4 coarse bins of 25 ranks, and the
χ² statistic's null distribution is computed exactly for the actual number of sensors by
simulating Multinomial(n, ¼, ¼, ¼, ¼) counts (seeded, 200 000 draws) instead of trusting the
asymptotic χ²₃ with expected counts of 3–8. A calibrated posterior fails each quantity's test
with probability ≤ 1 %.
"""
from __future__ import annotations

import numpy as np
import pytest

from test_coverage import N_SENSORS, SEED, TRUTHS, _bench, fit_records

N_BINS = 4
ALPHA = 0.01
QUALITY = "standard"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="session")
def sbc_records(tmp_path_factory):
    # the same 30 seeded fits as tests/test_coverage.py (one cached set per session: the two
    # files check different statistics of one sample, and the slow part runs once)
    return fit_records(SEED, N_SENSORS, QUALITY, tmp_path_factory, TRUTHS)


def chi2_stat(counts):
    counts = np.asarray(counts, float)
    e = counts.sum(axis=-1, keepdims=True) / counts.shape[-1]
    return np.sum((counts - e) ** 2 / e, axis=-1)


def exact_p_value(counts, n_sim=200_000, seed=0):
    """P(χ² ≥ observed) under uniform ranks, from simulated multinomial counts of the same n."""
    n = int(np.sum(counts))
    k = len(counts)
    sim = np.random.default_rng(seed).multinomial(n, np.full(k, 1.0 / k), size=n_sim)
    return float(np.mean(chi2_stat(sim) >= chi2_stat(counts) - 1e-12))


def test_exact_p_value_matches_chi2_for_large_n():
    from scipy import stats
    counts = np.array([60, 45, 50, 45])
    assert exact_p_value(counts) == pytest.approx(stats.chi2.sf(chi2_stat(counts), 3), abs=0.01)


QUANTITIES = ["conversion_gain_e_per_dn", "read_noise_e", "dark_current_e_per_s", "full_well_e",
              "quantum_efficiency", "prnu_percent", "dsnu_e", "variance_discrepancy",
              "mean_discrepancy", "capacity_bits"]


@pytest.mark.parametrize("name", QUANTITIES)
def test_rank_uniformity(sbc_records, name):
    sbc = _bench()
    recs = [r for r in sbc_records if name in r["q"]]
    if len(recs) < 8:
        pytest.skip(f"{name}: only {len(recs)} sensors carry it")
    L = recs[0]["L"]
    ranks = np.array([r["q"][name]["rank"] for r in recs])
    counts, _, _ = sbc.chi2_uniform(ranks, L, N_BINS)
    p = exact_p_value(counts)
    u = np.mean([r["q"][name]["u"] for r in recs])
    assert p > ALPHA, (f"{name}: rank counts {counts.tolist()} over {len(recs)} sensors, exact χ² p = {p:.4f}; "
                       f"mean posterior CDF at truth {u:.3f} (> 0.5: fit below truth)")
