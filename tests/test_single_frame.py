"""n_frames = 1: the spatial variance of one frame of the pair, modelled given the pair's
temporal variance it shares its noise with (PTCModel._spatial_block)."""

import numpy as np
import pytest

import bayescap
from bayescap.model import PTCModel, select_terms
from bayescap.simulate import SensorTruth, simulate_ptc

TRUTH = SensorTruth(5.0, 5.0, 20000, adc_bits=12, prnu_frac=0.01, dsnu_e=10.0)


def _one_frame_table(tmp_path):
    return simulate_ptc(
        TRUTH, n_levels=16, shape=(64, 64), spatial_frames=1, spatial_every=2, seed=2, path=tmp_path / "one.csv"
    )


def test_single_frame_table_reads_as_one_frame_and_carries_prnu_and_dsnu(tmp_path):
    """The one-frame table (the statistical check's input) reads back with n_frames = 1 and its
    spatial columns bring the PRNU and DSNU terms into the model."""
    d = _one_frame_table(tmp_path)
    assert np.nanmax(d.n_frames) == 1
    t = select_terms(d)
    assert t.prnu and t.dsnu
    m = PTCModel(d, terms=t)
    assert {"log_prnu", "log_dsnu"} <= set(m.names)
    assert np.isfinite(m.log_prob(np.atleast_2d(m.initial_guess()))).all()


@pytest.mark.statistical  # a fit whose 95 % intervals must hold the truths; benchmarks/statistical_tests.py runs it
def test_single_frame_spatial_variance_recovers_prnu_and_dsnu(tmp_path):
    """A frame-level simulation whose spatial columns are one frame's spatial variance
    (n_frames = 1) is read and fitted; PRNU and DSNU truths lie inside their 95 % intervals."""
    d = _one_frame_table(tmp_path)
    assert np.nanmax(d.n_frames) == 1
    p = bayescap.fit(d, quality="fast", seed=1).to_dict()["parameters"]
    lo, hi = p["prnu_percent"]["ci95"]
    assert lo < 100 * TRUTH.prnu_frac < hi
    lo, hi = p["dsnu_e"]["ci95"]
    assert lo < TRUTH.dsnu_e < hi


def test_single_frame_conditional_moments():
    """Given the pair's variance s²_D, a one-frame spatial variance has mean P + T + (s²_D − T)/2
    and variance (1.5 T² + 4PT)/ν (Gaussian noise): checked against a direct simulation."""
    rng = np.random.default_rng(0)
    n, P, T, reps = 200, 2.0, 3.0, 10000
    pattern = rng.normal(0.0, np.sqrt(P), n)
    pattern = (pattern - pattern.mean()) / pattern.std(ddof=1) * np.sqrt(P)  # the realised P
    a = pattern + rng.normal(0.0, np.sqrt(T), (reps, n))
    b = pattern + rng.normal(0.0, np.sqrt(T), (reps, n))
    sa = a.var(axis=1, ddof=1)
    sd = ((a - b) / np.sqrt(2.0)).var(axis=1, ddof=1)
    nu = n - 1.0
    # linear regression of s²_A on s²_D: slope ½, residual variance (1.5 T² + 4PT)/ν (rel. se 1.4 %)
    slope = np.cov(sa, sd)[0, 1] / sd.var()
    resid = sa - (P + T + 0.5 * (sd - T))
    assert abs(slope - 0.5) < 0.05  # its standard error is 0.014
    assert abs(resid.mean()) < 4 * resid.std() / np.sqrt(reps)
    assert abs(resid.var() / ((1.5 * T * T + 4 * P * T) / nu) - 1) < 0.05
    # the model's block gives those moments
    obs, mean, shape, _ = PTCModel._spatial_block(
        np.array([1.0]), np.array([[P]]), np.array([[T]]), np.array([1.0]), np.array([T + 0.3]), np.array([nu]), 0.0
    )
    assert mean[0, 0] == P + T + 0.15
    assert np.isclose(mean[0, 0] ** 2 / shape[0, 0], (1.5 * T * T + 4 * P * T) / nu)
