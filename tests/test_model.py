"""The likelihood pieces and the data-driven term selection."""

import warnings

import numpy as np
import pytest
from scipy import stats

from bayescap.model import PTCModel, gamma_logpdf, select_terms
from bayescap.simulate import SensorTruth, simulate_ptc


@pytest.mark.parametrize("k", [0.7, 5.0, 50.0, 5e3, 5e6])
def test_gamma_logpdf_matches_scipy(k):
    sigma2 = 37.0
    v = sigma2 * np.array([0.5, 0.9, 1.0, 1.001, 1.3])
    ref = stats.gamma.logpdf(v, a=k, scale=sigma2 / k)
    np.testing.assert_allclose(gamma_logpdf(v, sigma2, k), ref, rtol=1e-9, atol=1e-7)


def test_gamma_logpdf_has_the_chi2_spread():
    # a pair variance over n pixels: relative sd sqrt(2/(n-1)) around the model value
    rng = np.random.default_rng(1)
    n, sigma2 = 1000, 12.0
    v = sigma2 * rng.chisquare(n - 1, 20000) / (n - 1)
    grid = np.linspace(v.min(), v.max(), 2001)
    pdf = np.exp(gamma_logpdf(grid, sigma2, (n - 1) / 2))
    mean = np.trapezoid(grid * pdf, grid)
    sd = np.sqrt(np.trapezoid((grid - mean) ** 2 * pdf, grid))
    assert mean == pytest.approx(sigma2, rel=1e-3)
    assert sd / sigma2 == pytest.approx(np.sqrt(2 / (n - 1)), rel=2e-3)


def test_clipped_moments_match_monte_carlo():
    rng = np.random.default_rng(2)
    mu, s, tau, c = 4000.0, 30.0, 20.0, 4095.0
    n_pix, n_frames = 4000, 400
    x = mu + tau * rng.standard_normal(n_pix)[:, None] + s * rng.standard_normal((n_pix, n_frames))
    y = np.minimum(x, c)
    mc_mean = y.mean()
    per_pixel_var = y.var(axis=1, ddof=1)  # temporal variance per pixel
    mc_var = per_pixel_var.mean()
    # standard errors: pixels are the independent units (their offsets are shared by all frames)
    se_mean = y.mean(axis=1).std(ddof=1) / np.sqrt(n_pix)
    se_var = per_pixel_var.std(ddof=1) / np.sqrt(n_pix)
    mean, var, unclipped = PTCModel._clip_moments(None, np.array(mu), np.array(s), np.array(tau), np.array(c))
    assert abs(mean - mc_mean) < 4 * se_mean
    assert abs(var - mc_var) < 4 * se_var
    assert unclipped == pytest.approx(np.mean(x < c), abs=0.01)


def _sim(**kw):
    truth = SensorTruth(
        conversion_gain_e_per_dn=2.0,
        read_noise_e=4.0,
        full_well_e=6000.0,
        dark_current_e_per_s=100.0,
        quantum_efficiency=0.6,
        adc_bits=12,
    )
    args = dict(seed=5, shape=(64, 64), n_levels=20)
    args.update(kw)
    return truth, simulate_ptc(truth, **args)


def test_terms_follow_the_data():
    truth, d = _sim()
    t = select_terms(d)
    assert t.dark_current and t.clip == "well" and t.quantum_efficiency and not t.prnu and not t.dsnu
    assert "prnu" in t.reasons and "dsnu" in t.reasons
    # one exposure time: only read² + D·t
    ph = np.linspace(100, 8000, 12)
    _, d1 = _sim(photons_per_pixel=ph, exposure_time_s=0.01)
    t1 = select_terms(d1)
    assert not t1.dark_current and "read² + D·t" in t1.reasons["dark_current"]
    assert "log_dark_noise" in PTCModel(d1).names and "log_dc" not in PTCModel(d1).names
    # never saturated: no clip term, full well a lower bound
    _, d2 = _sim(max_fraction=0.6)
    t2 = select_terms(d2)
    assert t2.clip == "none" and "lower bound" in t2.reasons["saturation"]
    # spatial stacks: PRNU and DSNU enter
    _, d3 = _sim(spatial_frames=8, spatial_every=5)
    t3 = select_terms(d3)
    assert t3.prnu and t3.dsnu


def test_adc_clip_detected():
    truth = SensorTruth(conversion_gain_e_per_dn=1.0, read_noise_e=3.0, full_well_e=20000.0, adc_bits=12)
    d = simulate_ptc(truth, seed=3, shape=(64, 64), n_levels=20)
    assert select_terms(d).clip == "adc"


def test_latent_signal_inverts_the_clipped_mean():
    truth, d = _sim()
    m = PTCModel(d)
    x = m.initial_guess()
    p = m.physical(x[None])
    k = p["conversion_gain_e_per_dn"]
    rows = m.clip_rows
    pre = np.zeros((1, rows.size)) + 1e-3
    mu, var, slope = m._latent_clip_rows(k, pre, p["clip_spread_dn"], p["clip_dn"], rows)
    s = np.sqrt(np.maximum(mu - m.dm[rows], 0) / k[:, None] + pre)
    mean, _ = m._clip_mean(
        mu, s, np.broadcast_to(p["clip_spread_dn"][:, None], mu.shape), np.broadcast_to(p["clip_dn"][:, None], mu.shape)
    )
    np.testing.assert_allclose(mean, m.m[rows][None, :], atol=1e-5 * s.max())
    assert np.all(mu >= m.m[rows] - 1e-9)


def test_latent_clip_solver_reaches_roots_deep_in_the_clip():
    """The latent clip means solve s' ψ((c − μ)/s') = c − measured mean (the shortfall below the
    clip) to its own precision, from rows far below the clip to rows whose measured mean lies 1e-12
    DN below it (root ~7 s' above the clip), for a small and a large conversion gain and well
    spread; rows at or above the clip (no root) stay finite. Before commit d00d849 plain Newton steps
    on the clipped mean stopped once it was within 1e-9 s of the measured one, which at a
    shortfall of 1e-8 DN put the root at h = −5.84 instead of −5.96."""
    import types

    from bayescap.model.clipping import _log_shortfall

    g = np.array([300, 30, 5, 1, 0.1, 1e-2, 1e-4, 1e-8, 1e-12, 0.0, -0.5])
    c0, dark = 1000.0, 10.0
    fake = types.SimpleNamespace(
        m=c0 - g,
        dm=np.full(g.size, dark),
        _clip_mean=PTCModel._clip_mean,
        _clip_moments=lambda mu, s, t, c: PTCModel._clip_moments(None, mu, s, t, c),
    )
    k, tau, c = np.array([0.5, 4.0, 50.0]), np.array([0.0, 3.0, 40.0]), np.full(3, c0)
    pre = np.full((3, g.size), 2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mu, var, slope = PTCModel._latent_clip_rows(fake, k, pre, tau, c, np.arange(g.size))
    assert np.all(np.isfinite(mu)) and np.all(np.isfinite(var)) and np.all(np.isfinite(slope))
    s = np.sqrt(np.maximum(mu - dark, 0) / k[:, None] + pre)
    sp = np.sqrt(s * s + tau[:, None] ** 2)
    short = sp * np.exp(_log_shortfall((c0 - mu) / sp))
    # the first row is unclipped: μ is its measured mean
    np.testing.assert_array_equal(mu[:, 0], c0 - g[0])
    np.testing.assert_allclose(short[:, 1:9], np.broadcast_to(c0 - fake.m[1:9], (3, 8)), rtol=1e-9)
    # the deeper the measured mean sits in the clip, the higher the latent mean
    assert np.all(np.diff(mu[:, :9], axis=1) > 0)
    assert np.all(mu[:, 9:] >= c0)


def test_clip_moments_closed_form_match_quadrature_at_large_well_spread():
    """Mean, within-pixel variance and unclipped fraction of clip(N(mu + τξ, s²), c) averaged over
    ξ: the closed forms of PTCModel._clip_mean/_clip_moments against an 8001-point sum over ξ
    (agreeing to 1e-9 s and 1e-9 s²) for τ/s from 0.01 to 100, mu from 6 s' below to 6 s' above
    the clip. The 9-node Gauss–Hermite sums they replaced were off by 1.3e-3 s (mean) and 5.3e-3 s²
    (variance) at τ = 2 s, 0.22 s and 0.12 s² at τ = 10 s."""
    from scipy.special import ndtr

    xi = np.linspace(-10, 10, 8001)
    w = np.exp(-0.5 * xi**2)
    w /= w.sum()
    for r in (0.01, 0.1, 1.0, 3.0, 10.0, 30.0, 100.0):
        s, tau, c = 1.0, r, 0.0
        mu = np.linspace(-6, 6, 241) * np.hypot(s, tau)
        x = mu[:, None] + tau * xi
        a = (c - x) / s
        Phi, phi = ndtr(a), np.exp(-0.5 * a * a) / np.sqrt(2 * np.pi)
        m1 = c - (c - x) * Phi - s * phi
        m2 = (x * x + s * s) * Phi - s * phi * (x + c) + c * c * (1.0 - Phi)
        ref = (m1 @ w, np.maximum(m2 - m1 * m1, 0.0) @ w, Phi @ w)
        full = [np.full_like(mu, v) for v in (s, tau, c)]
        mean, slope = PTCModel._clip_mean(mu, *full)
        got = PTCModel._clip_moments(None, mu, *full)
        np.testing.assert_allclose(mean, ref[0], rtol=0, atol=1e-9 * s)
        np.testing.assert_allclose(slope, ref[2], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-9 * s)
        np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-9 * s * s)
        np.testing.assert_allclose(got[2], ref[2], rtol=0, atol=1e-9)
        assert np.all(np.isfinite(got[1])) and np.all(got[1] >= 0)


def test_log_prob_vectorised_and_finite_at_start():
    _, d = _sim(spatial_frames=8, spatial_every=5)
    m = PTCModel(d)
    x = m.initial_guess()
    X = x + 1e-3 * np.random.default_rng(0).standard_normal((7, m.ndim))
    lp = m.log_prob(X)
    assert lp.shape == (7,) and np.all(np.isfinite(lp))
    np.testing.assert_allclose(lp[3], m.log_prob(X[3:4])[0], rtol=1e-12)
    # outside the prior support: -inf, no warning storm
    bad = x.copy()
    bad[m.idx["log_k"]] = 50.0
    assert m.log_prob(bad[None])[0] == -np.inf


def test_gamma_logpdf_mixed_shapes_match_scipy():
    """Shapes k ≤ 10 (lgamma) and > 10 (Stirling) in one array: each element as scipy's."""
    sigma2 = np.array([[3.0], [40.0]])
    k = np.array([0.7, 5.0, 10.0, 10.5, 3e3, 5e6])
    v = sigma2 * np.array([0.5, 0.9, 1.0, 1.001, 1.3, 0.999])
    ref = stats.gamma.logpdf(v, a=k, scale=sigma2 / k)
    np.testing.assert_allclose(gamma_logpdf(v, sigma2, k), ref, rtol=1e-9, atol=1e-7)


def test_robust_blocks_are_the_two_component_mixture():
    """The robust blocks' log-likelihood (computed with the shared log ratio and −log v added once)
    against the mixture written out with scipy: (1 − ε) Gamma(k, σ²/k) + ε LogNormal(log σ², 0.3) for
    the variances, (1 − ε) N(m, sd) + ε N(m, √(sd² + (0.3 m)²)) for the means; and the outlier
    probabilities ε·bad / mixture."""
    from bayescap.model.likelihood import OUTLIER_RATE as eps
    from bayescap.model.likelihood import OUTLIER_REL_SD as rs

    truth = SensorTruth(conversion_gain_e_per_dn=2.0, read_noise_e=5.0, full_well_e=8000.0, adc_bits=12)
    m = PTCModel(simulate_ptc(truth, seed=3, shape=(64, 64), n_levels=20))
    assert m.terms.robust
    rng = np.random.default_rng(5)
    obs = rng.uniform(1.0, 400.0, 30)
    model = obs[None, :] * np.exp(rng.normal(0.0, 0.6, (4, 30)))  # up to ~4 sd of the outlier law
    k = rng.uniform(0.8, 5e4, (4, 30))
    ll, prob = m._block_loglik("bright_var", obs, model, k, "gamma", with_outlier_prob=True)
    good = np.log1p(-eps) + stats.gamma.logpdf(obs, a=k, scale=model / k)
    bad = np.log(eps) + stats.lognorm.logpdf(obs, s=rs, scale=model)
    ref = np.logaddexp(good, bad)
    np.testing.assert_allclose(ll, ref, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(prob, np.exp(bad - ref), rtol=1e-9, atol=1e-15)
    sd = rng.uniform(0.1, 20.0, (4, 30))
    mu = obs[None, :] + rng.normal(0.0, 1.0, (4, 30)) * sd * rng.choice([1.0, 30.0], (4, 30))
    ll = m._block_loglik("mean", obs, mu, sd, "normal")
    ref = np.logaddexp(
        np.log1p(-eps) + stats.norm.logpdf(obs, mu, sd), np.log(eps) + stats.norm.logpdf(obs, mu, np.hypot(sd, rs * mu))
    )
    np.testing.assert_allclose(ll, ref, rtol=1e-12, atol=1e-9)


def test_logaddexp_matches_numpy():
    from bayescap.model.likelihood import _logaddexp

    rng = np.random.default_rng(4)
    a, b = rng.normal(0, 40, 10**5), rng.normal(0, 40, 10**5)
    a[:4], b[:4] = [-np.inf, -np.inf, 3.0, -800.0], [-np.inf, 2.0, -np.inf, -801.0]
    got, ref = _logaddexp(a, b), np.logaddexp(a, b)
    assert np.array_equal(np.isneginf(got), np.isneginf(ref)) and got[1] == 2.0 and got[2] == 3.0
    fin = np.isfinite(ref)
    scale = np.spacing(np.maximum(np.abs(ref[fin]), 1.0))
    assert np.max(np.abs(got[fin] - ref[fin]) / scale) <= 4


def test_clip_moments_far_below_the_clip_is_the_temporal_variance():
    """More than 8.5 s' below the clip the variance is s² (the bivariate part is skipped there);
    an array mixing both sides gives each element what it gives alone."""
    mu = np.array([-20.0, -9.0, -8.0, -3.0, 0.0, 2.0])
    s, tau, c = np.full(6, 0.8), np.full(6, 0.6), np.zeros(6)
    mean, var, slope = PTCModel._clip_moments(None, mu, s, tau, c)
    far = (c - mu) / np.hypot(s, tau) > 8.5
    assert far.sum() == 2 and np.all(var[far] == s[far] ** 2)
    for i in range(6):
        one = PTCModel._clip_moments(None, mu[i : i + 1], s[i : i + 1], tau[i : i + 1], c[i : i + 1])
        assert (one[0][0], one[1][0], one[2][0]) == (mean[i], var[i], slope[i])
    ref_mean, ref_slope = PTCModel._clip_mean(mu, s, tau, c)
    np.testing.assert_array_equal(mean, ref_mean)
    np.testing.assert_array_equal(slope, ref_slope)


def _split_case():
    _, d = _sim(spatial_frames=8, spatial_every=5)
    m = PTCModel(d)
    x = m.initial_guess()
    from bayescap.model.threads import SPLIT_MIN_ELEMENTS

    n = SPLIT_MIN_ELEMENTS // m._observations() + 101
    assert n >= 1000
    X = x + 0.01 * np.random.default_rng(3).standard_normal((n, m.ndim))
    return m, X


def test_large_log_prob_calls_split_into_halves_the_same_on_one_or_two_threads(monkeypatch):
    """A call of SPLIT_MIN_ELEMENTS draws × observations or more is two half calls (the second on
    a thread): the same numbers bit for bit whatever BAYESCAP_THREADS says, equal to the halves
    evaluated apart."""
    import bayescap.model.ptc_model as M
    import bayescap.model.threads as T

    m, X = _split_case()
    k = X.shape[0] // 2
    halves = np.concatenate([M._log_posterior(X[:k], lambda g: m), M._log_posterior(X[k:], lambda g: m)])
    out = {}
    for n in ("1", "2"):
        monkeypatch.setenv("BAYESCAP_THREADS", n)
        assert T.n_threads() == int(n)
        out[n] = m.log_prob(X)
    np.testing.assert_array_equal(out["1"], out["2"])
    np.testing.assert_array_equal(out["2"], halves)
    assert np.all(np.isfinite(out["2"]))


def test_split_log_prob_thread_keeps_the_callers_errstate(monkeypatch):
    """Draws whose prior overflows (log read noise 800) in the half evaluated on the worker thread:
    under the caller's np.errstate(all="ignore") no warning is raised there either (numpy's
    errstate is a context variable; the thread runs in a copy of the caller's context)."""
    m, X = _split_case()
    X = X.copy()
    X[-5:, m.idx["log_read"]] = 800.0
    monkeypatch.setenv("BAYESCAP_THREADS", "2")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with np.errstate(all="ignore"):
            lp = m.log_prob(X)
    assert np.all(lp[-5:] == -np.inf) and np.all(np.isfinite(lp[:-5]))


def _child_split(args):
    import bayescap.model.threads as T

    m, X = args
    return T.n_threads(), m.log_prob(X)


def test_pool_workers_use_one_thread_and_a_forked_child_rebuilds_the_pool(monkeypatch):
    """In a process started by multiprocessing (a pool worker) n_threads() is 1 unless
    BAYESCAP_THREADS says otherwise; a child forked after the parent made its thread pool builds
    its own (a pool inherited through fork has no thread: a submit to it would never run)."""
    import multiprocessing as mp

    m, X = _split_case()
    monkeypatch.delenv("BAYESCAP_THREADS", raising=False)
    ctx = mp.get_context("fork")
    with ctx.Pool(1) as pool:
        n, lp = pool.apply(_child_split, ((m, X),))
    assert n == 1
    monkeypatch.setenv("BAYESCAP_THREADS", "2")
    ref = m.log_prob(X)  # the parent's pool exists now
    with ctx.Pool(1) as pool:
        res = pool.apply_async(_child_split, ((m, X),))
        n2, lp2 = res.get(timeout=60)
    assert n2 == 2
    np.testing.assert_array_equal(lp, ref)
    np.testing.assert_array_equal(lp2, ref)


def test_two_pixel_rows_and_far_out_draws_evaluate_quietly(basler_csv):
    """Found by corrupting the Basler CSV: n_pixels = 2 (ν = 1, allowed by the contract)
    divided by zero in the DSNU's χ²_{ν−1} (now χ²₀ = 0), and a draw far out in log τ overflowed exp()
    in the prior with a RuntimeWarning on the command line (now −inf quietly, as the likelihood)."""
    import dataclasses

    from bayescap.io.ptc_csv import read_ptc_csv

    d = read_ptc_csv(basler_csv)
    two = dataclasses.replace(d, n_pixels=np.full_like(d.n_pixels, 2.0))
    m = PTCModel(two)
    assert m.nu_pattern == 1.0 and "z_roi_cross" in m.names
    x0 = m.initial_guess()
    assert np.isfinite(m.log_prob(x0[None])[0])
    m = PTCModel(d)
    far = np.repeat(m.initial_guess()[None], 2, axis=0)
    far[0, m.idx["log_tau"]] = 800.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lp = m.log_prob(far)
    assert lp[0] == -np.inf and np.isfinite(lp[1])
