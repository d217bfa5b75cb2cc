"""Frequentist coverage of the 95 % intervals on simulated sensors with known truth (issue 2).

30 sensors are drawn from the proper prior of the classic SBC (``bayescap.validation.sbc.SBC_PRIOR``,
``draw_sensor_prior``: K log-uniform 0.5–8 e⁻/DN, read noise log-uniform 1–20 e⁻, dark current
log-uniform 1–200 e⁻/s, QE uniform 0.3–0.8, 40 % with PRNU/DSNU and spatial stacks, variance and
mean discrepancies f, g injected; full well log-uniform 3 000–60 000 e⁻ with ADC bits chosen so
that sometimes the ADC and sometimes the well clips first; 50 levels, 100×100-pixel ROI),
simulated frame by frame, and fitted with the default (``standard``) sampler and exactly that
prior. For every ranked quantity the number of 95 % intervals that contain the truth must be
consistent with Binomial(n, 0.95), counting only the sensors where the fit reports the quantity
as constrained. With truths from the fit's prior, Bayesian intervals have exactly their nominal
coverage on average over the prior, so this is a test of the model and the sampler, not of luck.

Tolerance: a two-sided binomial acceptance band with at most α/2 = 0.5 % in each tail, so a
calibrated posterior fails each test with probability ≤ 1 %. With n ≈ 30 the upper tail is empty
(P(all covered) ≈ 21 %): the test detects intervals that are too narrow or biased, not too wide
(the rank test of ``tests/test_sbc_small.py`` sees both).

The fits run once per session (several processes when possible) and are cached on disk under
pytest's base temp directory with a file lock, so with pytest-xdist the workers share them
instead of each refitting (the pattern of the pytest-xdist docs for once-only session fixtures). Set ``BAYESCAP_FIT_CACHE`` to a directory to
keep them across sessions (only while the code and seeds are unchanged).
"""

from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from bayescap.validation.sbc import run_one, sensor_seeds

SEED = 20240602
N_SENSORS = 30
ALPHA = 0.01
QUALITY = "standard"
COVERAGE_PARAMS = [
    "conversion_gain_e_per_dn",
    "read_noise_e",
    "full_well_e",
    "quantum_efficiency",
    "dark_current_e_per_s",
    "prnu_percent",
    "dsnu_e",
    "capacity_bits",
]
TRUTHS = "prior"  # classic SBC truths (bayescap.validation.sbc.run_one, as benchmarks/sbc.py --truths prior)
N_LEVELS = 50

pytestmark = [pytest.mark.slow, pytest.mark.statistical]


def fit_records(seed, n, quality, tmp_path_factory, tag):
    """Simulate and fit ``n`` sensors once per session (shared across xdist workers)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    if os.environ.get("BAYESCAP_FIT_CACHE"):  # reuse fits across sessions (same seeds, same code)
        base = Path(os.environ["BAYESCAP_FIT_CACHE"])
        base.mkdir(parents=True, exist_ok=True)
    cache = base / f"{tag}_{seed}_{n}_{quality}.json"
    with open(str(cache) + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if cache.exists():
            return json.loads(cache.read_text())
        tasks = [(i, a, b, c, quality, 99, TRUTHS, N_LEVELS) for i, (a, b, c) in enumerate(sensor_seeds(seed, n))]
        jobs = min(2, os.cpu_count() or 1)
        if jobs > 1:
            import multiprocessing as mp

            with mp.get_context("fork").Pool(jobs) as pool:
                recs = list(pool.imap(run_one, tasks))
        else:
            recs = [run_one(t) for t in tasks]
        failed = [r["i"] for r in recs if "failed" in r]
        assert not failed, f"fits that raised three times: {failed}"
        cache.write_text(json.dumps(recs))
        return recs


@pytest.fixture(scope="session")
def coverage_records(tmp_path_factory):
    return fit_records(SEED, N_SENSORS, QUALITY, tmp_path_factory, TRUTHS)


def acceptance_band(n, p=0.95, alpha=ALPHA):
    """[lo, hi] such that P(Binomial(n, p) < lo) ≤ α/2 and P(Binomial(n, p) > hi) ≤ α/2."""
    return int(stats.binom.ppf(alpha / 2, n, p)), int(stats.binom.isf(alpha / 2, n, p))


def _coverage(records, name):
    used = [r for r in records if name in r["q"] and r["q"][name]["constrained"]]
    k = sum(r["q"][name]["in95"] for r in used)
    u = np.array([r["q"][name]["u"] for r in used])
    misses = [(r["i"], round(r["q"][name]["u"], 4), r["clip"]) for r in used if not r["q"][name]["in95"]]
    return k, len(used), u, misses


def test_band_is_what_the_docstring_says():
    for n in (24, 30, 90):
        lo, hi = acceptance_band(n)
        assert stats.binom.cdf(lo - 1, n, 0.95) <= ALPHA / 2 < stats.binom.cdf(lo, n, 0.95)
        assert stats.binom.sf(hi, n, 0.95) <= ALPHA / 2


def test_sensors_span_both_clip_mechanisms(coverage_records):
    assert len(coverage_records) == N_SENSORS >= 24
    adc_first = sum(r["adc_clips_first"] for r in coverage_records)
    assert 0 < adc_first < N_SENSORS
    assert any(r["sim"]["spatial_frames"] for r in coverage_records)


@pytest.mark.parametrize("name", COVERAGE_PARAMS)
def test_95_interval_coverage(coverage_records, name):
    """Coverage of the 95 % interval of one parameter, among the sensors where the fit reports
    it constrained; false-alarm probability ≤ 1 % for a calibrated posterior."""
    k, n, u, misses = _coverage(coverage_records, name)
    # PRNU/DSNU exist only on the sensors with a spatial stack (6 of the 30 with this seed): with
    # n = 6 the band accepts ≥ 4 covered, so it still fails the old ~65 % coverage with
    # probability 0.35 and a 50 % coverage with probability 0.66; the 200-sensor benchmark
    # (benchmarks/results/sbc.md) is the real check for them
    assert n >= (5 if name in ("prnu_percent", "dsnu_e") else 20), f"only {n} sensors report {name} constrained"
    lo, hi = acceptance_band(n)
    assert lo <= k <= hi, (
        f"{name}: {k}/{n} 95 % intervals contain the truth (accept {lo}..{hi}); "
        f"misses (sensor, posterior CDF at truth, clip): {misses}"
    )


POOLED = ["conversion_gain_e_per_dn", "read_noise_e", "full_well_e"]


def test_95_interval_coverage_pooled(coverage_records):
    """K, read noise and full well together. The indicators of one sensor are positively correlated
    (exactly equal for K and full well when the ADC clips: full well = (ADC − black)·K), so the
    pooled count is not Binomial(3n). The test treats each sensor as one trial carrying the mean
    of its indicators and uses the Binomial(n_sensors, 0.95) band: exact under perfect
    correlation, conservative under less; false-alarm probability ≤ 1 %."""
    per_sensor = []
    for r in coverage_records:
        ind = [r["q"][p]["in95"] for p in POOLED if p in r["q"] and r["q"][p]["constrained"]]
        if ind:
            per_sensor.append(np.mean(ind))
    n = len(per_sensor)
    lo, hi = acceptance_band(n)
    cov = float(np.sum(per_sensor))
    detail = {p: _coverage(coverage_records, p)[:2] for p in POOLED}
    assert lo <= cov <= hi, f"pooled coverage {cov:.2f}/{n} sensor-equivalents (accept {lo}..{hi}); {detail}"


def test_read_noise_below_the_quantization_floor(coverage_records):
    """Sensors whose true read noise is below 0.4 DN (σ_read/K; the regime where rounding at a
    fixed dark offset gives far less than σ² + 1/12 and the old model put every draw below the
    truth): their 95 % intervals must contain the truth as often as Binomial(n, 0.95) allows
    (two-sided band, false-alarm probability ≤ 1 %), and so must the 95 % upper limits
    (one-sided)."""
    used = [r for r in coverage_records if r["truth"]["read_noise_e"] / r["truth"]["conversion_gain_e_per_dn"] < 0.4]
    assert len(used) >= 3, f"only {len(used)} sensors below 0.4 DN of read noise in this sample"
    k = sum(r["q"]["read_noise_e"]["in95"] for r in used)
    lo, hi = acceptance_band(len(used))
    u = [round(r["q"]["read_noise_e"]["u"], 4) for r in used]
    assert lo <= k <= hi, f"{k}/{len(used)} 95 % intervals hold the truth (accept {lo}..{hi}); CDF at truth {u}"
    ok = sum(r["q"]["read_noise_e"]["u"] <= 0.95 for r in used)
    assert ok >= int(stats.binom.ppf(ALPHA, len(used), 0.95)), f"upper limit above truth in {ok}/{len(used)}; {u}"
