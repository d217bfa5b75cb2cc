"""emcee moves checked on targets whose answer is known: a correlated 6-D Gaussian
(:func:`target_cov`, :func:`run_move`) and a banana, a skewed and a truncated coordinate against
exact draws (:func:`check_banana`)."""

from __future__ import annotations

import numpy as np

# --------------------------------------------------------------------------- emcee moves on known targets
NDIM = 6


def target_cov(seed=7):
    """A fixed correlated covariance: random rotation of a spectrum, then scaled sds 0.01–10."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((NDIM, NDIM))
    Q, _ = np.linalg.qr(A)
    corr = Q @ np.diag(np.geomspace(0.05, 3.0, NDIM)) @ Q.T
    d = np.sqrt(np.diag(corr))
    corr = corr / np.outer(d, d)
    sd = np.geomspace(0.01, 10.0, NDIM)
    return corr * np.outer(sd, sd)


def moves_registry():
    import emcee

    return {
        "StretchMove": [(emcee.moves.StretchMove(), 1.0)],
        "DEMove": [(emcee.moves.DEMove(), 1.0)],
        "DE 0.8 + Stretch 0.2 (fit.py)": [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)],
        "DESnookerMove": [(emcee.moves.DESnookerMove(), 1.0)],
        "DE 0.8 + Snooker 0.2": [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)],
    }


def independence_moves(mean, cov, fraction=0.5, *, nu=6.0, scale=1.0):
    """bayescap's IndependenceMove (t proposal at ``mean``, ``cov``) mixed with DE 0.8 + stretch 0.2."""
    import emcee

    from bayescap.inference.moves import IndependenceMove

    rest = 1.0 - fraction
    return [
        (IndependenceMove(mean, cov, nu=nu, scale=scale), fraction),
        (emcee.moves.DEMove(), 0.8 * rest),
        (emcee.moves.StretchMove(), 0.2 * rest),
    ]


def independence_registry(cov):
    """Independence-move mixtures on the Gaussian target: with the exact covariance as proposal,
    and with a deliberately poor one (mean shifted by 1 sd along every axis, sds × 0.6: the
    proposal misses the tails, the case where an independence sampler can stick)."""
    sd = np.sqrt(np.diag(cov))
    return {
        "Indep 0.5 (exact Σ) + DE/stretch": independence_moves(np.zeros(NDIM), cov, 0.5),
        "Indep 0.5 (shifted, 0.6 sd) + DE/stretch": independence_moves(sd, 0.36 * cov, 0.5),
        "Indep 1.0 (exact Σ)": independence_moves(np.zeros(NDIM), cov, 1.0),
        "Indep 0.7 ν4 ×1.3 (shifted, 0.6 sd) + DE/stretch (standard)": independence_moves(
            sd, 0.36 * cov, 0.7, nu=4.0, scale=1.3
        ),
    }


def run_move(moves, cov, *, seed, n_walkers=32, n_burn=1000, n_steps=6000, thin=1, log_prob=None, p0=None):
    """Sample N(0, cov) (or ``log_prob``, started from ``p0``) with ``moves``; returns
    (draws (n, ndim), acceptance, τ max)."""
    import emcee

    prec = np.linalg.inv(cov)
    rng = np.random.default_rng(seed)

    if log_prob is None:

        def log_prob(x):
            return -0.5 * np.einsum("ij,jk,ik->i", x, prec, x)

    L = np.linalg.cholesky(cov)
    if p0 is None:
        p0 = rng.standard_normal((n_walkers, NDIM)) @ L.T  # start from the target: no burn-in bias
    s = emcee.EnsembleSampler(n_walkers, p0.shape[1], log_prob, vectorize=True, moves=moves)
    s.random_state = np.random.RandomState(seed).get_state()
    st = s.run_mcmc(p0, n_burn, progress=False)
    s.reset()
    s.run_mcmc(st, n_steps, progress=False)
    chain = s.get_chain(thin=thin)
    tau = float(np.max(emcee.autocorr.integrated_time(chain, quiet=True, tol=0)))
    return chain.reshape(-1, p0.shape[1]), float(s.acceptance_fraction.mean()), tau


# ---------------------------------------------------------------- a non-Gaussian target
BANANA_B, BANANA_S1, TRUNC_LO = 0.5, 1.5, -0.5


def banana_draws(n, rng):
    """Exact draws of the 4-D test target: a banana (y1 ~ N(0, s1²), x2 = y2 + b(y1² − s1²),
    y2 ~ N(0, 1)), a skewed log-normal coordinate x3 = log of a Gamma(2) (left-skewed) and a
    standard normal truncated at x4 > −0.5 (a bound next to the mode, like a clip level or an
    upper limit at zero)."""
    from scipy.stats import truncnorm

    y1 = BANANA_S1 * rng.standard_normal(n)
    x2 = rng.standard_normal(n) + BANANA_B * (y1**2 - BANANA_S1**2)
    x3 = np.log(rng.gamma(2.0, size=n))
    x4 = truncnorm.rvs(TRUNC_LO, np.inf, size=n, random_state=rng)
    return np.column_stack([y1, x2, x3, x4])


def banana_log_prob(x):
    x = np.atleast_2d(x)
    y1, x2, x3, x4 = x.T
    y2 = x2 - BANANA_B * (y1**2 - BANANA_S1**2)
    lp = -0.5 * (y1 / BANANA_S1) ** 2 - 0.5 * y2**2 + (2.0 * x3 - np.exp(x3)) - 0.5 * x4**2
    return np.where(x4 > TRUNC_LO, lp, -np.inf)


class _Target:
    """Shim so that bayescap.inference.optimize.laplace_start can find the mode and Laplace covariance."""

    ndim = 4

    def log_prob(self, x):
        return banana_log_prob(x)

    def initial_guess(self):
        return np.array([0.1, 0.0, 0.5, 0.2])


def check_banana(moves_fn, *, seeds, n_steps, n_walkers=32, probs=(0.025, 0.16, 0.5, 0.84, 0.975)):
    """Run ``moves_fn(x_map, cov)`` on the banana target from the Laplace start (as bayescap's
    sampler does) and compare mean, sd and quantiles with 400 000 exact draws. Returns the largest
    |error| / (Monte Carlo standard error across seeds, floored by the exact draws' own error)
    and the raw errors."""
    from bayescap.inference.mcmc import _initial_ball
    from bayescap.inference.optimize import laplace_start

    tgt = _Target()
    x_map, _, cov, _ = laplace_start(tgt)
    exact = banana_draws(400_000, np.random.default_rng(123))
    stats_exact = np.vstack([exact.mean(0), exact.std(0), np.quantile(exact, probs, axis=0)])
    got, accs, taus = [], [], []
    for sd_ in seeds:
        p0 = _initial_ball(tgt, x_map, cov, n_walkers, np.random.default_rng(sd_))
        x, a, tau = run_move(
            moves_fn(x_map, cov), cov, seed=sd_, n_steps=n_steps, log_prob=banana_log_prob, p0=p0, n_walkers=n_walkers
        )
        got.append(np.vstack([x.mean(0), x.std(0), np.quantile(x, probs, axis=0)]))
        accs.append(a)
        taus.append(tau)
    got = np.array(got)  # (seeds, 2 + len(probs), 4)
    err = got.mean(0) - stats_exact
    se = got.std(0, ddof=1) / np.sqrt(len(seeds))
    z = np.abs(err) / se
    return {
        "z_max": float(z.max()),
        "err": err,
        "se": se,
        "acceptance": float(np.mean(accs)),
        "tau": float(np.mean(taus)),
        "x_map": x_map,
    }
