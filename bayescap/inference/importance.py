"""Importance-sampling building blocks: multivariate Student-t draws and log densities, Pareto-
smoothed importance weights (PSIS, with k̂ and the importance-sampling ESS), systematic
resampling and moment matching of weighted draws."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.special import gammaln

from bayescap.inference.curvature import _proposal_cov

__all__ = ["student_t_draws", "student_t_logpdf", "psis_weights"]


def student_t_draws(mean, cov, nu, n, rng):
    """``n`` draws of a multivariate Student-t ``t_ν(mean, cov)`` and their log densities.

    ``x = mean + L z / sqrt(u)``, ``z ~ N(0, I)``, ``u ~ χ²_ν/ν``; the Mahalanobis distance is
    ``|z|²/u``, so no triangular solve is needed. Returns (x (n, d), log q (n,)).
    """
    mean = np.asarray(mean, float)
    d = mean.size
    L = np.linalg.cholesky(cov)
    z = rng.standard_normal((n, d))
    u = rng.chisquare(nu, size=n) / nu
    x = mean + (z @ L.T) / np.sqrt(u)[:, None]
    maha = np.einsum("ij,ij->i", z, z) / u
    logdet = 2.0 * np.sum(np.log(np.diag(L)))
    logq = (
        gammaln(0.5 * (nu + d))
        - gammaln(0.5 * nu)
        - 0.5 * d * np.log(nu * np.pi)
        - 0.5 * logdet
        - 0.5 * (nu + d) * np.log1p(maha / nu)
    )
    return x, logq


def student_t_logpdf(x, mean, cov, nu):
    """log density of ``t_ν(mean, cov)`` at rows of ``x`` (n, d)."""
    return _t_logpdf(mean, cov, nu)(x)


def _t_logpdf(mean, cov, nu):
    """``x -> log t_ν(x; mean, cov)`` for rows of ``x``, with the Cholesky factor's inverse and the
    normalising constant computed once: the fast path evaluates each proposal on every batch of draws
    (a matrix product per call instead of a Cholesky factorisation and a solve)."""
    mean = np.asarray(mean, float)
    d = mean.size
    L = np.linalg.cholesky(cov)
    Linv_t = np.linalg.inv(L).T
    const = gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * np.log(nu * np.pi) - np.sum(np.log(np.diag(L)))

    def logpdf(x):
        z = (np.atleast_2d(x) - mean) @ Linv_t
        maha = np.einsum("ij,ij->i", z, z)
        return const - 0.5 * (nu + d) * np.log1p(maha / nu)

    return logpdf


def _gpdfit(x):
    """Generalized Pareto fit of the sorted tail ``x`` (Zhang & Stephens 2009 with the weak
    prior on k of Vehtari et al.): ArviZ 0.x's ``_gpdfit``. Returns (k, sigma)."""
    prior_bs, prior_k = 3, 10
    n = len(x)
    m_est = 30 + int(n**0.5)
    b = 1 - np.sqrt(m_est / (np.arange(1, m_est + 1, dtype=float) - 0.5))
    b /= prior_bs * x[int(n / 4 + 0.5) - 1]
    b += 1 / x[-1]
    k = np.log1p(-b[:, None] * x).mean(axis=1)
    len_scale = n * (np.log(-(b / k)) - k - 1)
    w = 1 / np.exp(len_scale - len_scale[:, None]).sum(axis=1)
    real = w >= 10 * np.finfo(float).eps
    if not np.all(real):
        w, b = w[real], b[real]
    w /= w.sum()
    b_post = np.sum(b * w)
    k_post = np.log1p(-b_post * x).mean()
    sigma = -k_post / b_post
    k_post = (n * k_post + prior_k * 0.5) / (n + prior_k)
    return k_post, sigma


def _gpinv(probs, kappa, sigma):
    """Inverse generalized Pareto CDF for probs strictly inside (0, 1) (ArviZ 0.x's ``_gpinv``)."""
    if sigma <= 0:
        return np.full_like(probs, np.nan)
    if np.abs(kappa) < np.finfo(float).eps:
        return sigma * -np.log1p(-probs)
    return sigma * np.expm1(-kappa * np.log1p(-probs)) / kappa


def _psislw(lw):
    """Pareto-smoothed log weights (normalised) and k̂ of one 1-D vector: ArviZ 0.x's ``psislw``
    (reff 1), re-implemented so that the fast path does not import ArviZ (~1 s per process)."""
    x = np.array(lw, dtype=float)
    n = x.size
    cutoff_ind = -int(np.ceil(min(n / 5.0, 3 * n**0.5))) - 1
    x -= np.max(x)
    order = np.argsort(x)
    xcutoff = max(x[order[cutoff_ind]], np.log(np.finfo(float).tiny))
    expxcutoff = np.exp(xcutoff)
    (tail,) = np.where(x > xcutoff)
    x_tail = x[tail]
    k = np.inf
    if len(x_tail) > 4:
        si = np.argsort(x_tail)
        x_tail = np.exp(x_tail) - expxcutoff
        k, sigma = _gpdfit(x_tail[si])
        if np.isfinite(k):
            sti = np.arange(0.5, len(x_tail)) / len(x_tail)
            x[tail[si]] = np.log(_gpinv(sti, k, sigma) + expxcutoff)
            x[x > 0] = 0
    top = np.max(x)
    x -= top + np.log(np.sum(np.exp(x - top)))
    return x, k


def psis_weights(log_w):
    """Pareto-smoothed normalised weights, k̂ and the IS effective sample size.

    ``log_w`` (..., n): raw log importance weights; −inf (outside the prior support) allowed.
    Returns (w (..., n) summing to 1, k̂ (...), ESS (...)). The same numbers as
    :func:`arviz.psislw` (tested), without importing ArviZ.
    """
    lw = np.asarray(log_w, float)
    finite = np.isfinite(lw)
    top = np.max(np.where(finite, lw, -np.inf), axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    # zero weight stays (numerically) zero after normalisation; psislw wants finite input
    lw = np.where(finite, lw - top, -800.0)
    flat = lw.reshape(-1, lw.shape[-1])
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        out = [_psislw(row) for row in flat]
    lws = np.stack([o[0] for o in out]).reshape(lw.shape)
    khat = np.array([o[1] for o in out]).reshape(lw.shape[:-1])
    w = np.exp(lws - np.max(lws, axis=-1, keepdims=True))
    w = w / np.sum(w, axis=-1, keepdims=True)
    ess = 1.0 / np.sum(w * w, axis=-1)
    return w, np.asarray(khat, float), ess


def _systematic_resample(w, n, rng):
    """Indices of ``n`` equally weighted draws from weights ``w`` (systematic resampling)."""
    c = np.cumsum(w)
    c[-1] = 1.0
    pos = (rng.random() + np.arange(n)) / n
    return np.searchsorted(c, pos, side="left")


def _moment_matched(x, w, fallback, inflation):
    """Student-t location and scale at the weighted mean and covariance of ``x`` (``fallback`` when
    they are not usable)."""
    m = w @ x
    c_w = np.cov(x.T, aweights=w)
    if np.all(np.isfinite(m)) and np.all(np.isfinite(c_w)) and np.linalg.matrix_rank(c_w) == x.shape[1]:
        return m, _proposal_cov(c_w, inflation)
    return fallback
