"""Small seeded simulation-based calibration (issue 6); the full run is ``benchmarks/sbc.py``.

The 30 seeded sensors of ``tests/test_coverage.py``: classic SBC, the truths drawn from the proper
prior ``bayescap.validation.sbc.SBC_PRIOR`` that every fit uses (``draw_sensor_prior``; variance and
mean discrepancies injected into the simulated data), fitted once per session with the
``standard`` sampler. For every parameter and for capacity the statistic is the posterior CDF at
the truth, u = the fraction of all the fit's draws below it: with truths from the fit's own prior,
u is uniform on (0, 1) for a correct model and sampler (the probability integral transform, the
L → ∞ limit of the SBC rank among L draws, Talts et al. 2018).

Why u and not the rank among L = 99 thinned draws: the rank adds binomial noise to each sensor's u
(sd ≈ √(u(1 − u)/99), ~5 ranks), so the test's verdict would re-roll with any change of the
sampler at an unchanged posterior; on 200 sensors fitted with two samplers the mean of u and the
95 % coverage agree to the third digit while the rank p-values move by an order of magnitude both
ways. u's own Monte Carlo error (sd ≈ √(u(1 − u)/ESS) ≤ 0.016 at the standard preset's ESS ≥ 1 000)
moves a sensor to another bin only within ~0.016 of a bin edge. ``benchmarks/sbc.py`` keeps the
classic ranks on 200 sensors (with u's mean and tail fractions).

Tolerance for the small sample: u goes into 4 bins of width ¼, and the χ² statistic's null
distribution is computed exactly for the actual number of sensors by simulating
Multinomial(n, ¼, ¼, ¼, ¼) counts (seeded, 200 000 draws) instead of trusting the asymptotic χ²₃
with expected counts of 3–8. A calibrated posterior fails each quantity's test with probability
≤ 1 %.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_coverage import N_SENSORS, SEED, TRUTHS, fit_records

N_BINS = 4
ALPHA = 0.01
QUALITY = "standard"

pytestmark = [pytest.mark.slow, pytest.mark.statistical]


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


QUANTITIES = [
    "conversion_gain_e_per_dn",
    "read_noise_e",
    "dark_current_e_per_s",
    "full_well_e",
    "quantum_efficiency",
    "prnu_percent",
    "dsnu_e",
    "variance_discrepancy",
    "mean_discrepancy",
    "capacity_bits",
]


def cdf_bin_counts(u, n_bins=N_BINS):
    """Counts of posterior CDFs at the truth in ``n_bins`` equal bins of (0, 1) (u = 1 in the last)."""
    u = np.asarray(u, float)
    return np.bincount(np.minimum((u * n_bins).astype(int), n_bins - 1), minlength=n_bins)


def test_cdf_bin_counts():
    assert cdf_bin_counts([0.0, 0.24, 0.25, 0.5, 0.74, 0.99, 1.0]).tolist() == [2, 1, 2, 2]


@pytest.mark.parametrize("name", QUANTITIES)
def test_posterior_cdf_at_truth_uniform(sbc_records, name):
    recs = [r for r in sbc_records if name in r["q"]]
    if len(recs) < 8:
        pytest.skip(f"{name}: only {len(recs)} sensors carry it")
    u = np.array([r["q"][name]["u"] for r in recs])
    counts = cdf_bin_counts(u)
    p = exact_p_value(counts)
    assert p > ALPHA, (
        f"{name}: posterior CDF at the truth binned in quarters {counts.tolist()} over "
        f"{len(recs)} sensors, exact χ² p = {p:.4f}; mean {u.mean():.3f} (> 0.5: fit below truth)"
    )
