"""The fast path's first stage, its resampling in a parameter's order and the retry it skips when
the restarts find the same start (bayescap.inference.fast, issue 50)."""

from dataclasses import replace

import numpy as np
from test_fast import GaussianModel

import bayescap.inference.fast_stages as stages
from bayescap.inference import FastSettings, fast_posterior
from bayescap.inference.end_errors import _end_errors


class NamedGaussian(GaussianModel):
    """N(mu, cov) with the coordinates as named physical parameters (the fast path judges their
    interval ends)."""

    def physical(self, th):
        th = np.atleast_2d(th)
        return {f"p{i}": th[:, i] for i in range(self.ndim)}


class HeavyTails(NamedGaussian):
    """Independent coordinates of density ∝ (1 + x²)^−0.6 (tails heavier than a Cauchy's, no t with
    ν = 4 and its defensive components cover them: k̂ rejects every attempt), and one mode that every
    optimiser start finds."""

    def __init__(self):
        super().__init__(np.zeros(3), np.eye(3))

    def log_prob(self, th):
        return -0.6 * np.sum(np.log1p(np.atleast_2d(th) ** 2), axis=1)


def _gaussian():
    return NamedGaussian([1.0, -2.0, 0.5], [[1.0, 0.6, 0.0], [0.6, 2.0, -0.3], [0.0, -0.3, 0.5]])


def test_first_stage_is_a_third_and_its_ends_hold(monkeypatch):
    """With the stage set to a third (off by default) and the default interval-end target, the first
    stage draws 2 000 of the 6 000; on a Gaussian it passes the proposal's check, so the draws in all are the stage's plus the top-up's,
    fewer than n_proposals alone before; and every returned interval end is within 0.05 of the width
    (end_tolerance) of the exact one, seeds 1-3. Without a target, or without a top-up to grow into,
    there is no stage (all n_proposals at once), nor by default."""
    _, dg = fast_posterior(_gaussian(), seed=1, settings=FastSettings(retry_restarts=0))
    assert dg["n_first_stage"] == 0 and dg["n_proposals"] >= 6000
    monkeypatch.setattr(stages, "FIRST_STAGE_FRACTION", 1 / 3)
    model = _gaussian()
    s = FastSettings(retry_restarts=0)
    sd = np.sqrt(np.diag(model.cov))
    for seed in (1, 2, 3):
        ch, dg = fast_posterior(model, seed=seed, settings=s)
        assert dg["accepted"], dg["reason"]
        assert dg["n_first_stage"] == 2000 and not dg["first_stage_grown"]
        assert dg["n_proposals"] == 2000 + dg["n_topup"] < s.n_proposals
        x = ch.chain.reshape(-1, 3)
        for j in range(3):
            width = 2 * 1.959964 * sd[j]
            lo, hi = np.quantile(x[:, j], [0.025, 0.975])
            assert abs(lo - (model.mu[j] - 1.959964 * sd[j])) < 0.05 * width, (seed, j)
            assert abs(hi - (model.mu[j] + 1.959964 * sd[j])) < 0.05 * width, (seed, j)
    for other in (replace(s, end_mcse_max=None), replace(s, max_proposals=s.n_proposals)):
        _, dg = fast_posterior(model, seed=1, settings=other)
        assert dg["n_first_stage"] == 0 and dg["n_proposals"] == s.n_proposals


def test_a_failed_stage_starts_again_as_without_stages(monkeypatch):
    """Where the first stage fails the proposal's check (heavy tails: k̂ ≥ 0.7), the attempt draws
    all n_proposals from the start with the same seed: the same draws and verdict as with the stage
    switched off."""
    monkeypatch.setattr(stages, "FIRST_STAGE_FRACTION", 1 / 3)
    model = HeavyTails()
    s = FastSettings(retry_restarts=0)
    ch, dg = fast_posterior(model, seed=4, settings=s)
    assert not dg["accepted"] and dg["first_stage_grown"] and dg["n_first_stage"] == 2000
    monkeypatch.setattr(stages, "FIRST_STAGE_FRACTION", 1.0)
    ch2, dg2 = fast_posterior(model, seed=4, settings=s)
    assert dg2["n_first_stage"] == 0
    np.testing.assert_array_equal(ch.chain, ch2.chain)
    assert dg["khat"] == dg2["khat"] and dg["reason"] == dg2["reason"]


def test_khat_limit_follows_the_sample_size_below_2155_draws():
    """The PSIS paper's threshold min(0.7, 1 − 1/log₁₀ S): 0.7 from 2 155 draws on, lower below."""
    s = FastSettings()
    assert stages._khat_limit(s, 6000) == 0.7 and stages._khat_limit(s, 2200) == 0.7
    assert abs(stages._khat_limit(s, 1000) - 2 / 3) < 1e-12
    assert stages._khat_limit(s, 2000) < 0.7


def test_resampling_in_a_parameters_order_keeps_its_counts_to_one_draw():
    """Resampled in the order of a quantity's values, the share of the n draws at or below each of
    its values is its weighted share to within 1/n (random order: off by ~√(p(1 − p)/n)); and the
    predicted end errors then differ from the random order's only by the resampling's term: equal
    to the weighted draws' own (n → ∞) up to (1/n)² in the variance."""
    rng = np.random.default_rng(11)
    x = rng.standard_normal(5000)
    w = np.exp(-0.5 * (x - 0.3) ** 2 / 0.8 + 0.5 * x * x)
    w /= w.sum()
    n = 4000
    idx = stages._resample(w, n, np.random.default_rng(2), x)
    o = np.argsort(x)
    F = np.cumsum(w[o])
    v = x[o]
    got = np.searchsorted(np.sort(x[idx]), v, side="right") / n
    assert np.max(np.abs(got - F)) <= 1.0 / n + 1e-12
    rand = stages._resample(w, n, np.random.default_rng(2))
    got_r = np.searchsorted(np.sort(x[rand]), v, side="right") / n
    assert np.max(np.abs(got_r - F)) > 5.0 / n
    e_sorted = stages._sorted_end_errors(x, w, 10**9)
    np.testing.assert_allclose(e_sorted, _end_errors(x, w), rtol=1e-6)
    assert all(a < b for a, b in zip(stages._sorted_end_errors(x, w, n), _end_errors(x, w, n_resampled=n)))


def test_retry_is_skipped_when_the_restarts_find_the_same_start(monkeypatch):
    """Rejected by k̂ (heavy tails), the retry with restarts ends at the first attempt's MAP and
    covariance: the importance draws are not repeated (the draws and verdict are the first attempt's,
    with the reason in the diagnostics); forced to repeat them, the verdict is the same."""
    model = HeavyTails()
    ch, dg = fast_posterior(model, seed=2)
    assert not dg["accepted"] and dg["retried_with_restarts"]
    assert "same proposals" in dg["retry_skipped"] and ch.extra["retry_skipped"] == dg["retry_skipped"]
    assert dg["first_attempt"]["khat"] == dg["khat"]
    monkeypatch.setattr(stages, "_SAME_SD", -1.0)
    _, d2 = fast_posterior(model, seed=2)
    assert d2["retried_with_restarts"] and "retry_skipped" not in d2 and not d2["accepted"]
