"""Fast path: Laplace approximation + Pareto-smoothed importance sampling (Laplace–IS).

Steps (all vectorised; 1 + ``adapt_rounds`` ``log_prob`` calls for the importance draws):

1. MAP and Laplace covariance by :func:`bayescap.fit.laplace_start`: Newton's method
   (:func:`bayescap.fit.newton_map`) on finite-difference Hessians taken in whitened coordinates
   (the raw Hessian is distorted by the ~1e11 condition number and ``log_prob`` jitter), from the
   initial guess and the extra starts of :func:`bayescap.fit._map_starts`, all in one ``log_prob``
   call per iteration; the covariance is the whitened Hessian's at the optimum, consistent to
   ±25 %. If the draws are rejected (below), the whole path is retried once with
   ``retry_restarts`` more starts (before 2026-11-23 late day: BFGS, then
   :func:`refine_covariance` and :func:`polish_map`, still available as
   ``laplace_start(optimizer="bfgs")``);
2. ``n_proposals/3`` draws from a multivariate Student-t ``t_ν(x_MAP, Σ)``; their PSIS weights
   give a weighted mean and covariance, and the other ``2/3`` are drawn from a t at those
   moments, in ``FastSettings.adapt_rounds`` rounds (3; one before 2026-11-23 late day), each at
   the moments of all draws so far (adaptive importance sampling);
3. importance weights ``log p(x) − log q_mix(x)`` over all draws (the mixture of the
   proposals, the balance heuristic), smoothed by PSIS (Vehtari, Simpson, Gelman, Yao & Gabry
   2024, JMLR 25(72)) with the algorithm of :func:`arviz.psislw` (re-implemented in
   :func:`psis_weights`, so that the fast path does not import ArviZ), which also returns k̂;
4. systematic resampling to ``n_draws`` equally weighted draws, shuffled.

Before step 2, :func:`_tail_probe` evaluates the posterior on rays from the MAP (one ``log_prob``
call) and finds the long one-sided tails the t does not reach (a dark current, clip spread or DSNU
the data cannot tell from zero); each gets ``tail_fraction`` (5 %) of the draws from
:func:`_tail_proposal`, taken from the adaptive rounds' share, part of the mixture of step 3.

Newton and steps 2-4 run in :class:`bayescap.fit.SamplerCoordinates`: the clip as
``log(clip_dn − lower bound)`` where the model has a free clip level (``clip_dn`` between
data-derived bounds), the QE as ``log(qe)`` where it has one (since 2026-11-25: the photon counts tie
QE to K along a thin ridge that is straight in logs and curved in QE, whose ends the straight t
proposals missed, narrowing the gain-linked intervals by ~1 % of the width a side on small ROIs);
the draws come back in the model's coordinates. There ``clip_floor_fraction`` (10 %) of the first draws come
from a defensive proposal with the clip uniform down to its lower bound
(:func:`_clip_floor_proposal`), part of the mixture of step 3. The retry after a rejection runs
Newton in the model's coordinates first and then in those (``FastSettings.polish_both``).

**Its own diagnostic.** k̂ below ``khat_max`` (0.7, the PSIS paper's threshold for a few
thousand draws, ``min(1 − 1/log10 S, 0.7)``) and an importance-sampling ESS ``1/Σw²`` of at
least ``min_ess_is`` (200). When either fails the draws must not be used: the caller falls back
to MCMC (:func:`bayescap.fit` with ``quality="fast"`` does so, with a note). ``benchmarks/speed_accuracy.py`` measures
the interval errors against long MCMC runs as a function of k̂. The diagnostics also carry each
physical parameter's predicted Monte Carlo error of its 95 % interval ends
(:func:`interval_end_mcse`, ``end_mcse``, counting the resampling to ``n_draws``), which the report
prints (:class:`bayescap.posterior.FitResult` adds the derived quantities', capacity and TR among
them, from the weighted draws the path leaves in ``extra["weighted_draws"]``): at the default 6 000 draws its median for the worst parameter was 0.028 of the width before
the resampling term (``fast_tradeoff.md``, 11 sensors) and 0.033 with it (``fast_tradeoff_gate.md``,
3 sensors), so the worst of ~20 interval ends is often more than 0.05 off by Monte Carlo
error alone. ``FastSettings.end_mcse_max`` (0.035 of the width by default since 2026-11-24
afternoon; None: report only, as before) makes it a check: above the target the path draws more,
up to ``max_proposals`` (then resampling as many draws as there are weighted ones, unless the caller
set ``n_draws``), and rejects the run (without the optimiser retry) when the target stays out of
reach. The top-up (``FastSettings.topup``) aims its draws at the offending ends by default
(:func:`_end_components`: a t at the weighted moments of the draws beyond each end, where the
importance density of a quantile has half its mass), which on 200 small Gpixel ROIs accepts 196
where more moment-matched draws (``"global"``) accepted 168, at 0.7× their time
(``benchmarks/results/batch_gate.md``). Where k̂ is 0.5–0.7 the error falls more slowly than 1/√N
(the weights' variance is infinite): ``fast_tradeoff.py --gate --topup`` measures it.

**All ends at once** (since 2026-11-24 evening). A gate on each end does not bound the worst of
them: with ~20 ends near 0.035, the worst is ~2.2 predicted errors out, ~0.07 of the width, and on
the first 60 simulated Gpixel ROIs only 35 of 58 accepted had every end within 0.05 of 16 pooled
MCMC runs' (``benchmarks/results/batch_accuracy_first60_per_end.md``). ``FastSettings.end_confidence``
(0.9) and ``end_tolerance`` (0.05) ask instead that the predicted probability that *every* end is
within the tolerance, Π erf(tol/(s_i√2)) over the ends' predicted errors s_i, be at least the
confidence: the top-up aims at the per-end error that gives it (:func:`_joint_target`; one end may
keep tol/1.64, twenty need tol/2.8) and the path rejects when ``max_proposals`` cannot reach it.
The probability is reported (``end_within_probability``). There 49 of 56 accepted ROIs had every end
within 0.05 (``batch_accuracy_first60.md``), at ~1.4× the fast paths' time. The rest were misses the
prediction does not see: draws that carry large weights turn up only in a bigger sample (on ROI 8
k̂ is 0.14 at 9 375 draws and 0.56–0.68 at 60 000; docs/performance.md, "2026-11-24, 20:10–").
Against those, ``wide_fraction`` (10 %) of the draws come from a defensive t at the MAP with
``wide_scale`` (3) × the Laplace sd, part of the mixture: on the first 120 ROIs every end within
0.05 on 105 of 114 accepted, against 93 of 113 without it.

The draws come back as a :class:`bayescap.fit.ChainResult` with ``chain`` shaped
``(1, n_draws, 1, ndim)`` (one "ensemble", one "walker") and
``extra = {"method": "laplace-is", "khat": ..., "ess_is": ..., ...}``. R-hat and MCMC ESS do
not apply to resampled independent draws; :meth:`bayescap.posterior.FitResult._diagnose`
reports k̂ and the IS ESS for such chains instead. ``bayescap.fit(quality="fast")`` runs this
path and falls back to MCMC when it is rejected.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy.special import erfc, gammaln

from bayescap._blas import one_blas_thread
from bayescap.inference.chains import ChainResult
from bayescap.inference.coordinates import (
    SamplerCoordinates,
    _sampler_coordinates,
)
from bayescap.inference.optimize import (
    _proposal_cov,
    find_map,
    laplace_covariance,
    laplace_start,
    refine_covariance,
)
from bayescap.inference.presets import QUALITY_PRESETS

__all__ = ["FastSettings", "fast_posterior", "student_t_draws", "student_t_logpdf", "psis_weights", "interval_end_mcse",
           "METHOD"]

METHOD = "laplace-is"


@dataclass(frozen=True)
class FastSettings:
    """Knobs of the Laplace–IS fast path (see ``docs/performance.md``)."""

    nu: float = 4.0               # Student-t degrees of freedom of the proposals (6 before 2026-11-23)
    n_proposals: int = 6000       # importance draws in all (1 + adapt_rounds vectorised log_prob calls; 3000 before)
    adapt_fraction: float = 2 / 3  # share drawn from the moment-matched second proposal
    adapt_inflation: float = 1.2  # sd multiplier on the weighted covariance of the draws so far
    refine_iter: int = 6          # BFGS route only (laplace_start(optimizer="bfgs")): whitened Hessian re-evaluations
    polish: bool = True           # BFGS route only: whitened gradient ascent after find_map (polish_map)
    n_draws: int = 4000           # equally weighted draws returned after resampling
    khat_max: float = 0.7         # accept when Pareto k̂ < khat_max ...
    min_ess_is: float = 200.0     # ... and the importance-sampling ESS ≥ this
    n_restarts: int = 0           # extra optimiser starts in find_map
    retry_restarts: int = 2       # on rejection, retry once with this many restarts
    scale: float = 1.0            # proposal scale factor on the Laplace covariance (sd multiplier)
    polish_both: bool = False     # clip coordinates: optimise in the model's coordinates first (the retry does)
    adapt_rounds: int = 3         # moment-matching rounds sharing the adapt_fraction draws (1 before 2026-11-23 late day)
    clip_floor_fraction: float = 0.1  # clip coordinates: share of the first draws from _clip_floor_proposal (0 before 2026-11-23 afternoon)
    end_mcse_max: float | None = 0.035  # accept only when every interval end's predicted Monte Carlo error ≤ this × width (None: report only, the default before 2026-11-24 afternoon)
    max_proposals: int = 24000    # draws in all, topping up towards end_mcse_max (n_proposals: no top-up)
    tail_fraction: float = 0.05   # share of the draws from each long one-sided tail the probe finds (_tail_probe; 0: no probe)
    tail_max_fraction: float = 0.2  # at most this share for all tail (and pair) components together
    floor_pair: bool = True       # with the clip floor and a tail: tail_fraction more draws from both at once (_pair_proposal)
    adapt_nu: float | None = None  # degrees of freedom of the moment-matched rounds' t (None: nu)
    topup: str = "targeted"       # end_mcse_max's top-up: "targeted" (_end_components) or "global" (moment-matched t, before 2026-11-24 afternoon)
    topup_components: int = 8     # targeted top-up: at most this many interval ends aimed at per round (4 before 2026-11-24 evening)
    topup_draws: int | None = None  # targeted top-up: draws per round at least (a quarter of those so far if more; None: n_proposals/4)
    wide_fraction: float = 0.1    # share of the draws from a defensive t at the MAP, wide_scale × the Laplace sd (0: none, before 2026-11-24 evening)
    wide_scale: float = 3.0
    end_tolerance: float = 0.05   # with end_confidence: the error (× width) every interval end should stay within ...
    end_confidence: float | None = 0.9  # ... with at least this predicted probability, all ends at once (None: per end only, before 2026-11-24 evening)


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
    logq = (gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * np.log(nu * np.pi)
            - 0.5 * logdet - 0.5 * (nu + d) * np.log1p(maha / nu))
    return x, logq


def student_t_logpdf(x, mean, cov, nu):
    """log density of ``t_ν(mean, cov)`` at rows of ``x`` (n, d)."""
    return _t_logpdf(mean, cov, nu)(x)


def _t_logpdf(mean, cov, nu):
    """``x -> log t_ν(x; mean, cov)`` for rows of ``x``, with the Cholesky factor's inverse and the
    normalising constant computed once: the fast path evaluates each proposal on every batch of draws
    (a matrix product per call instead of a Cholesky factorisation and a solve: ~8 % of a Basler
    fast fit before)."""
    mean = np.asarray(mean, float)
    d = mean.size
    L = np.linalg.cholesky(cov)
    Linv_t = np.linalg.inv(L).T
    const = (gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * np.log(nu * np.pi)
             - np.sum(np.log(np.diag(L))))

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


def _floor_top(x_map, c1, j):
    """log of the clip floor's reach above the lower bound: the MAP plus 3 Laplace sds in z."""
    return float(x_map[j] + 3.0 * np.sqrt(c1[j, j]))


def _clip_floor_proposal(model, x_map, c1, nu):
    """Defensive proposal for the clip level near its lower bound, in :class:`SamplerCoordinates`.

    Where the clip's posterior density stays up down to its data-derived lower bound ``lo`` (the
    well clips just above the last unclipped row), ``z = log(clip − lo)`` has a long exponential
    left tail that a t around the mode does not reach: on a simulated 10-bit sensor the MCMC put
    2.5 % of the mass below z = −3.85 where 48 000 t draws put 0.1 % below −3.22
    (``benchmarks/clip_floor_tail.py``), and the clip spread's lower interval end came out ~0.2 of
    the width too high with k̂ 0.4–0.5 (k̂ cannot see a region no draw visits). This component draws ``clip − lo`` uniform on (0, e^{z_MAP + 3 sd})
    and the other coordinates from the Laplace t's marginal (Hesterberg 1995, defensive importance
    sampling). Returns (draw(n, rng) -> (z, log q), logpdf(z))."""
    D = x_map.size
    j = model.j
    oth = np.array([i for i in range(D) if i != j], int)
    m_o, c_o = x_map[oth], c1[np.ix_(oth, oth)]
    log_a = _floor_top(x_map, c1, j)

    def draw(n, rng):
        xo, lqo = student_t_draws(m_o, c_o, nu, n, rng)
        z = np.empty((n, D))
        z[:, oth] = xo
        z[:, j] = log_a + np.log1p(-rng.random(n))      # log of a uniform on (0, 1]
        return z, lqo + (z[:, j] - log_a)

    t_o = _t_logpdf(m_o, c_o, nu)

    def logpdf(z):
        z = np.atleast_2d(z)
        out = t_o(z[:, oth]) + (z[:, j] - log_a)
        return np.where(z[:, j] <= log_a, out, -np.inf)

    return draw, logpdf


#: where :func:`_tail_probe` looks, in Laplace sds from the MAP, and how far a tail must reach
_TAIL_GRID = np.array([3.0, 4.5, 6.0, 8.0, 11.0, 16.0, 24.0, 36.0])
_TAIL_DROP = 10.0      # a tail reaches as far as log p stays within this of the MAP's (nats)
_TAIL_MIN_REACH = 6.0  # a Gaussian reaches 4.47 sd: beyond 6, the Laplace t under-covers the tail


def _tail_probe(model, x_map, lp_map, cov, skip=()):
    """Long one-sided tails of the posterior that the Laplace t does not reach.

    For every coordinate j and side, log p on two rays from the MAP, at the multiples
    :data:`_TAIL_GRID` of the Laplace sd of x_j: along the axis (the others at the MAP) and along
    the Laplace conditional line (the others at their Laplace conditional mean,
    ``x_MAP + s·Σ[:, j]/√Σ_jj``). A Gaussian posterior drops by s²/2 on the line, so stays within
    :data:`_TAIL_DROP` (10 nats) of the MAP out to 4.5 sd. A scale parameter the data bound on one
    side only (a dark current, a clip spread or a discrepancy that may be zero) has a posterior
    that follows its prior far out on the other side: on the bundled Basler, log p is within
    10 nats of the MAP out to 16 sd below the MAP in log(clip spread) and log(DSNU), where the
    importance proposals put almost no draw (``docs/performance.md``, "Long one-sided tails,
    probed"). One ``log_prob`` call (4·D·8 points; the axis ray is left out where it is the line).
    Returns ``[(j, side, direction (D,), reach in sds), ...]`` for the rays that stay within 10 nats
    beyond :data:`_TAIL_MIN_REACH` sds (the better of the two rays of a side), ``skip`` a set of
    (j, side) to leave out."""
    D = x_map.size
    sd = np.sqrt(np.diag(cov))
    G = _TAIL_GRID
    rays = []
    for j in range(D):
        line = cov[:, j] / sd[j]                     # one Laplace sd of x_j, the others conditional
        axis = np.zeros(D)
        axis[j] = sd[j]
        dirs = [line] if np.array_equal(line, axis) else [line, axis]
        for side in (-1.0, 1.0):
            if (j, side) not in skip:
                rays += [(j, side, side * v) for v in dirs]
    if not rays:
        return []
    pts = x_map + (G[None, :, None] * np.array([r[2] for r in rays])[:, None, :]).reshape(-1, D)
    with np.errstate(all="ignore"):
        drop = (model.log_prob(pts) - lp_map).reshape(len(rays), G.size)
    drop = np.where(np.isfinite(drop), drop, -np.inf)
    best = {}
    for (j, side, v), dr in zip(rays, drop):
        above = dr >= -_TAIL_DROP
        # the reach: the last grid point within the drop, before the first one beyond it
        n_in = int(np.argmin(above)) if not above.all() else G.size
        if n_in == 0:
            continue
        reach = G[n_in - 1]
        if n_in < G.size and np.isfinite(dr[n_in]):   # linear interpolation to the crossing
            a, b = dr[n_in - 1], dr[n_in]
            reach += (G[n_in] - G[n_in - 1]) * (a + _TAIL_DROP) / (a - b)
        if reach > _TAIL_MIN_REACH and reach > best.get((j, side), (0.0, None))[0]:
            best[(j, side)] = (reach, v)
    return [(j, side, v, reach) for (j, side), (reach, v) in sorted(best.items())]


def _coord_name(model, j):
    names = getattr(model, "names", None)
    n = names[j] if names is not None and j < len(names) else f"x{j}"
    if isinstance(model, SamplerCoordinates):
        n = {model.j: "log(clip_dn - lower bound)", model.q: "log(qe)"}.get(j, n)
    return n


def _tail_entry(model, tail, n_draws, suffix=""):
    """A tail of :func:`_tail_probe` (or a pair with the clip floor) as the diagnostics list it."""
    j, side, _, reach = tail
    return {"parameter": _coord_name(model, j) + suffix, "side": "lower" if side < 0 else "upper",
            "reach_sd": round(float(reach), 2), "n_draws": int(n_draws)}


def _tail_proposal(x_map, c1, nu, j, direction, reach):
    """Defensive proposal for one long one-sided tail found by :func:`_tail_probe`: the distance s
    (in Laplace sds of x_j) uniform on (0, 1.25·reach) along ``direction`` from the MAP, and the
    other coordinates a Laplace t about that ray: the conditional covariance of the Laplace t given
    x_j when the ray is the conditional line, its marginal when the ray is the axis (the others held
    at the MAP). :func:`_clip_floor_proposal` is the same idea for the clip level. Returns
    (draw(n, rng) -> (x, log q), logpdf(x))."""
    D = x_map.size
    oth = np.array([i for i in range(D) if i != j], int)
    sd_j = float(np.sqrt(c1[j, j]))
    step = np.asarray(direction, float) / direction[j]        # per unit of x_j − x_MAP,j
    side = float(np.sign(direction[j]))
    top = 1.25 * reach * sd_j                                   # the range of |x_j − x_MAP,j|
    c_o = c1[np.ix_(oth, oth)]
    if np.count_nonzero(step[oth]):                             # the conditional line
        c_o = c_o - np.outer(c1[oth, j], c1[j, oth]) / c1[j, j]
    c_o = _proposal_cov(c_o, 1.0)
    zero = np.zeros(oth.size)

    def draw(n, rng):
        d = side * top * rng.random(n)
        eo, lqo = student_t_draws(zero, c_o, nu, n, rng)
        x = x_map + d[:, None] * step
        x[:, oth] += eo
        return x, lqo - np.log(top)

    t_o = _t_logpdf(zero, c_o, nu)

    def logpdf(x):
        x = np.atleast_2d(x)
        d = x[:, j] - x_map[j]
        r = x[:, oth] - (x_map[oth] + d[:, None] * step[oth])
        out = t_o(r) - np.log(top)
        return np.where((side * d >= 0) & (side * d <= top), out, -np.inf)

    return draw, logpdf


def _pair_proposal(x_map, c1, nu, axis, floor):
    """Defensive proposal for a long tail meeting the clip floor: coordinate ``axis = (j, side,
    reach)`` uniform on its side out to 1.25 reach Laplace sds, the clip (``floor = (k, log_a)``) as
    in :func:`_clip_floor_proposal`, the other coordinates from the Laplace t's marginal.

    On the simulated sim09 of ``speed_accuracy.sensor_set`` (10-bit, 878 e⁻ well) the MCMC
    reference's draws in the clip spread's lower tail have the clip level spread down towards its
    bound: a corner that neither the floor (the clip spread near its mode) nor the clip spread's own
    tail proposal (the clip near its mode) reaches, and the clip spread's lower interval end came
    out 0.04–0.11 of the width too high with k̂ ≈ 0 (docs/performance.md, "Long one-sided tails,
    probed"). Returns (draw(n, rng) -> (x, log q), logpdf(x))."""
    D = x_map.size
    j, side, reach = int(axis[0]), float(axis[1]), float(axis[2])
    k, log_a = floor
    top = 1.25 * reach * np.sqrt(c1[j, j])
    oth = np.array([i for i in range(D) if i not in (j, k)], int)
    m_o, c_o = x_map[oth], c1[np.ix_(oth, oth)]

    def draw(n, rng):
        x = np.empty((n, D))
        xo, lq = student_t_draws(m_o, c_o, nu, n, rng)
        x[:, oth] = xo
        x[:, j] = x_map[j] + side * top * rng.random(n)
        x[:, k] = log_a + np.log1p(-rng.random(n))
        return x, lq - np.log(top) + (x[:, k] - log_a)

    t_o = _t_logpdf(m_o, c_o, nu)

    def logpdf(x):
        x = np.atleast_2d(x)
        d = side * (x[:, j] - x_map[j])
        out = t_o(x[:, oth]) - np.log(top) + (x[:, k] - log_a)
        return np.where((d >= 0) & (d <= top) & (x[:, k] <= log_a), out, -np.inf)

    return draw, logpdf


class _DensityCache:
    """Each proposal's log density on each batch of draws, computed once over the calls of
    :func:`_adaptive_rounds` and :func:`_add_components` in one fast-path attempt (the top-up adds
    proposals and batches; without the cache every call re-evaluated them all on all draws)."""

    def __init__(self):
        self._d = {}

    def get(self, f, xb):
        key = (id(f), id(xb))
        hit = self._d.get(key)
        if hit is None:
            hit = self._d[key] = (f, xb, f(xb))     # f and xb kept alive: their ids stay theirs
        return hit[2]

    def put(self, f, xb, values):
        self._d[(id(f), id(xb))] = (f, xb, values)

    def fill(self, fs, batches):
        """Every density of ``fs`` on every batch of ``batches``, each density evaluated once on the
        batches it has not seen, stacked (a top-up round of m new proposals over K old ones on B
        batches made K·m + m·B calls; this makes K + m: 3 % off 64 small ROIs' fast paths run one at
        a time, docs/performance.md, "2026-11-24, 22:15–")."""
        for f in fs:
            todo = [xb for xb in batches if (id(f), id(xb)) not in self._d]
            if not todo:
                continue
            vals = f(todo[0] if len(todo) == 1 else np.vstack(todo))
            at = 0
            for xb in todo:
                self.put(f, xb, vals[at:at + len(xb)])
                at += len(xb)


def _adaptive_rounds(model, settings, rng, comps, n2, cache=None):
    """``settings.adapt_rounds`` moment-matching rounds sharing ``n2`` draws: every round's t sits at
    the PSIS-weighted moments of all draws so far, weighted against the mixture of the proposals so
    far (the balance heuristic). ``comps``: the first proposals, ``[(logpdf, draws, log p, t
    location and scale or None), ...]``, the Laplace t first (one batch of draws each: a list
    returned by an earlier call continues it). Each proposal's density on each batch of draws is
    computed once (``cache``: a :class:`_DensityCache` kept over calls). Returns (draws, log p, log q of
    the final mixture, the components in the format of ``comps``)."""
    cache = _DensityCache() if cache is None else cache
    nu = settings.nu if settings.adapt_nu is None else float(settings.adapt_nu)
    R = max(1, int(settings.adapt_rounds))
    sizes = [n2 // R + (1 if r < n2 % R else 0) for r in range(R)]
    pdfs = [c[0] for c in comps]
    counts = [len(c[1]) for c in comps]
    xs, lps = [c[1] for c in comps], [c[2] for c in comps]
    cache.fill(pdfs, xs)
    dens = [[cache.get(f, xb) for xb in xs] for f in pdfs]      # dens[k][b]: proposal k on batch b
    moments = []                                     # (location, scale) of each new t proposal

    def mix_logq():
        # log Σ_k (n_k/N) q_k(x), one log-sum-exp over the stacked components (numpy's pairwise
        # logaddexp calls the scalar libm functions: 1.5 % of a Basler fast fit)
        n_all = float(sum(counts))
        terms = np.stack([np.log(n / n_all) + np.concatenate(dens[k]) for k, n in enumerate(counts)])
        top = np.max(terms, axis=0)
        top = np.where(np.isfinite(top), top, 0.0)
        with np.errstate(under="ignore", divide="ignore", invalid="ignore"):
            return top + np.log(np.sum(np.exp(terms - top), axis=0))

    for n_r in sizes:
        x = np.vstack(xs)
        w, _, ess_r = psis_weights(np.concatenate(lps) - mix_logq())
        mu, c = moments[-1] if moments else comps[0][3]
        if ess_r >= 5:
            mu, c = _moment_matched(x, w, (mu, c), settings.adapt_inflation)
        xr, lq_own = student_t_draws(mu, c, nu, n_r, rng)
        with np.errstate(all="ignore"):
            lpr = model.log_prob(xr)
        for k, f in enumerate(pdfs):                 # the earlier proposals on the new batch
            dens[k].append(cache.get(f, xr))
        t_new = _t_logpdf(mu, c, nu)
        cache.put(t_new, xr, lq_own)
        cache.fill([t_new], xs)
        dens.append([cache.get(t_new, xb) for xb in xs] + [lq_own])   # the new one on all
        pdfs.append(t_new)
        moments.append((mu, c))
        counts.append(n_r)
        xs.append(xr)
        lps.append(lpr)
    comps_out = [(pdfs[k], xs[k], lps[k], comps[k][3] if k < len(comps) else moments[k - len(comps)])
                 for k in range(len(xs))]
    return np.vstack(xs), np.concatenate(lps), mix_logq(), comps_out


def _physical_fn(model):
    """``x (n, ndim) -> {name: values}`` for the model behind ``model`` (None if it has none)."""
    if hasattr(model, "physical"):
        return model.physical
    inner = getattr(model, "model", None)
    if inner is not None and hasattr(inner, "physical") and hasattr(model, "to_x"):
        return lambda x: inner.physical(model.to_x(x))
    return None


def interval_end_mcse(values, w, probs=(0.025, 0.975), n_resampled=None):
    """Monte Carlo error of weighted quantiles, as a fraction of the 95 % interval's width.

    For self-normalised importance weights ``w`` the estimate F̂(q) = Σ w_i 1{v_i ≤ q} has variance
    ≈ Σ w_i² (1{v_i ≤ q} − p)² (the delta method; Owen 2013, "Monte Carlo theory, methods and
    examples", §9.2); its standard error ``se`` in probability maps to the quantile as
    (Q(p + se) − Q(p − se))/2, with Q the weighted quantile function. With ``n_resampled``, the
    quantile is read off that many draws resampled from the N weighted ones, which adds the variance
    of the resampled count below the end: systematic resampling gives draw i ⌊n w_i⌋ copies and one
    more with probability f_i = frac(n w_i), so that count varies as a sum of Bernoullis given
    their total, S_A·S_B/(S_A + S_B)/n² with S = Σ f_i(1 − f_i) below (A) and above (B) the end.
    For equal weights that is p(1 − p)(1/n − 1/N), sampling n of N without replacement (the term
    used before 2026-11-24 afternoon, which left out that unequal weights add to it: at n = N it
    said 0). Returns the
    largest over ``probs``, divided by Q(0.975) − Q(0.025) (0 when the width is 0; NaN when the
    values are not all finite, as :func:`bayescap.fit.interval_end_mcse_mcmc`)."""
    errs = _end_errors(values, w, probs, n_resampled)
    return float("nan") if errs is None else max(errs, default=0.0)


def _end_errors(values, w, probs=(0.025, 0.975), n_resampled=None):
    """Per end of ``probs``: :func:`interval_end_mcse`'s error as a fraction of the width (a list;
    None when the values are not all finite, zeros when the width is 0)."""
    v = np.asarray(values, float)
    if not np.all(np.isfinite(v)):
        return None
    o = np.argsort(v)
    v, ws = v[o], w[o]
    F = np.cumsum(ws)
    F_tot = F[-1]
    F /= F_tot
    Q = lambda p: np.interp(p, F, v)      # noqa: E731
    width = Q(0.975) - Q(0.025)
    if not width > 0:
        return [0.0 for _ in probs]
    # Σ w_i² (1{v_i ≤ q} − p)² from the cumulative sum of w² up to q (one pass for both ends)
    c2 = np.cumsum(ws * ws)
    if n_resampled:
        # systematic resampling gives draw i floor(n w_i) copies and one more with probability
        # frac(n w_i); the count below q varies as a sum of those Bernoullis given the total n
        fr = n_resampled * (ws / F_tot)
        fr -= np.floor(fr)                  # frac(n w_i): np.mod is ~5x slower here
        bern = np.cumsum(fr * (1.0 - fr))
    out = []
    for p in probs:
        q = Q(p)
        k = int(np.searchsorted(v, q, side="right")) - 1      # the last draw at or below q
        below = c2[k] if k >= 0 else 0.0
        var = (1.0 - p) ** 2 * below + p * p * (c2[-1] - below)
        if n_resampled and bern[-1] > 0:
            s_a = bern[k] if k >= 0 else 0.0
            var += s_a * (bern[-1] - s_a) / bern[-1] / float(n_resampled) ** 2
        se = float(np.sqrt(max(var, 0.0)))
        out.append(float(0.5 * (Q(min(p + se, 1.0)) - Q(max(p - se, 0.0))) / width))
    return out


def _weighted_kept(x, w):
    """The weighted draws that count (weight above 1e-12 of the largest), and their weights."""
    keep = w > 1e-12 * np.max(w)
    return x[keep], w[keep]


def _end_mcse(model, x, w, n_resampled=None, derived_fn=None):
    """{name: interval-end Monte Carlo error / width} of every physical parameter that varies, for
    weighted draws (and ``n_resampled`` draws resampled from them: :func:`interval_end_mcse`); NaN
    for a parameter whose draws are not all finite (reported as the worst, :func:`_worst_end_mcse`).
    With ``derived_fn`` (draws in ``model``'s coordinates -> {name: values}), the quantities it
    returns too (capacity, TR, ...: what :class:`bayescap.posterior.FitResult` computes from the same
    weighted draws afterwards)."""
    xk, wk, vals = _end_values(model, x, w, derived_fn)
    return {n: interval_end_mcse(v, wk, n_resampled=n_resampled) for n, v in vals.items()}


def _end_values(model, x, w, derived_fn=None, names=None):
    """(kept draws, their weights, {name: values on them}) of the quantities :func:`_end_mcse`
    looks at (those that vary); ``names``: only those (the derived quantities computed only when
    one of them is among them)."""
    phys = _physical_fn(model)
    if phys is None:
        return x[:0], w[:0], {}
    xk, wk = _weighted_kept(x, w)
    with np.errstate(all="ignore"):
        p = phys(xk)
        if derived_fn is not None and (names is None or any(n not in p for n in names)):
            p = {**p, **{n: v for n, v in derived_fn(xk).items() if np.size(v) == xk.shape[0]}}
    return xk, wk, {n: v for n, v in p.items() if (names is None or n in names) and _varies(v)}


_END_PROBS = (0.025, 0.975)


def _end_components(xk, wk, vals, mcse, target, n_resampled, inflation, max_components, ends=None):
    """Proposals aimed at the interval ends whose predicted Monte Carlo error is above ``target``
    (the targeted top-up of :class:`FastSettings`, ``topup="targeted"``).

    The importance density that estimates P(v ≤ q) best is ∝ p(x)·|1{v ≤ q} − P| (Owen 2013,
    §9.2): half of it lies beyond the end. A moment-matched t over the whole posterior puts only
    ~2.5 % of its draws there, so topping up with it cuts an end's error as 1/√N; this puts a t at
    the weighted moments of the draws beyond the quantile at twice the end's tail probability (so
    that the end itself is inside), for the worst ends first, at most ``max_components`` of them,
    one per region (an end whose region shares half its weight with a chosen one is left to that
    one: capacity's lower end and TR's are often the same draws). Regions with an importance ESS
    below D + 2 get none. ``mcse``: {name: worst end's error} of ``vals`` (:func:`interval_end_mcse`),
    to look at those above ``target`` only; ``ends``: {name: [error of each end]} of the same draws
    (:func:`_end_table`), computed here when not given. Returns [(location, scale), ...] (worst end
    first)."""
    D = xk.shape[1]
    cands = []
    for name, v in vals.items():
        if not mcse.get(name, 0.0) > target:
            continue
        errs = _end_errors(v, wk, _END_PROBS, n_resampled) if ends is None else ends[name]
        if errs is None or not np.all(np.isfinite(errs)):
            continue
        cands += [(e, name, p) for e, p in zip(errs, _END_PROBS) if e > target]
    cands.sort(key=lambda c: -c[0])
    out, masks = [], []
    for _, name, p in cands:
        v = np.asarray(vals[name], float)
        o = np.argsort(v)
        F = np.cumsum(wk[o])
        F /= F[-1]
        if p < 0.5:
            mask = v <= np.interp(2.0 * p, F, v[o])
        else:
            mask = v >= np.interp(1.0 - 2.0 * (1.0 - p), F, v[o])
        wm = wk[mask]
        tot = wm.sum()
        if not tot > 0 or any(np.sum(wk[mask & m]) >= 0.5 * tot for m in masks):
            continue
        wm = wm / tot
        if 1.0 / np.sum(wm * wm) < D + 2:
            continue
        mc = _moment_matched(xk[mask], wm, None, inflation)
        if mc is None:
            continue
        out.append(mc)
        masks.append(mask)
        if len(out) >= max_components:
            break
    return out


def _add_components(model, settings, rng, comps, new, cache=None):
    """Draw from each new proposal ``new = [(location, scale, n), ...]`` (t, ``adapt_nu`` or ``nu``
    degrees of freedom) in one ``log_prob`` call and join them to the mixture ``comps`` (the format
    of :func:`_adaptive_rounds`; ``cache`` its density cache). Returns what :func:`_adaptive_rounds`
    returns."""
    cache = _DensityCache() if cache is None else cache
    nu = settings.nu if settings.adapt_nu is None else float(settings.adapt_nu)
    pdfs = [c[0] for c in comps]
    counts = [len(c[1]) for c in comps]
    xs, lps = [c[1] for c in comps], [c[2] for c in comps]
    new_x, new_lq, new_pdf = [], [], []
    for mu, c, n in new:
        xr, lq = student_t_draws(mu, c, nu, int(n), rng)
        new_x.append(xr)
        new_lq.append(lq)
        new_pdf.append(_t_logpdf(mu, c, nu))
    xb = np.vstack(new_x)
    with np.errstate(all="ignore"):
        lpb = model.log_prob(xb)
    at = np.cumsum([0] + [len(xr) for xr in new_x])
    out = list(comps)
    for k, (xr, (mu, c, _), f) in enumerate(zip(new_x, new, new_pdf)):
        out.append((f, xr, lpb[at[k]:at[k + 1]], (mu, c)))
    allx = xs + new_x
    allpdf = pdfs + new_pdf
    counts = counts + [len(xr) for xr in new_x]
    n_all = float(sum(counts))
    x = np.vstack(allx)
    for f, xr, lq in zip(new_pdf, new_x, new_lq):
        cache.put(f, xr, lq)
    cache.fill(allpdf, allx)
    terms = np.stack([np.log(n / n_all) + np.concatenate([cache.get(f, xb) for xb in allx])
                      for f, n in zip(allpdf, counts)])
    top = np.max(terms, axis=0)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(under="ignore", divide="ignore", invalid="ignore"):
        logq = top + np.log(np.sum(np.exp(terms - top), axis=0))
    return x, np.concatenate(lps + [lpb]), logq, out


def _varies(v):
    """Whether draws ``v`` are not all one value (non-finite draws count as varying: their error is
    NaN, not left out)."""
    v = np.asarray(v, float)
    return bool(v.size) and (not np.all(np.isfinite(v)) or np.ptp(v) > 0)


def _within_logprob(errs, tol):
    """log P(every |error| ≤ ``tol``) for independent normal errors of sd ``errs`` (the interval
    ends' predicted Monte Carlo errors, as fractions of the width): Σ log(1 − erfc(tol/(s√2)));
    −inf when an error is not finite."""
    s = np.asarray(errs, float)
    if not np.all(np.isfinite(s)):
        return float("-inf")
    s = s[s > 0]
    with np.errstate(divide="ignore"):
        return float(np.sum(np.log1p(-erfc(tol / (s * np.sqrt(2.0))))))


def _joint_target(errs, tol, confidence, cap):
    """The per-end error the top-up aims at: the largest g ≤ ``cap`` such that, with every end
    above g brought down to g, all of ``errs`` are within ``tol`` with probability ≥ ``confidence``
    (:func:`_within_logprob`). One end at the gate may keep an error of tol/1.64 (0.030 of the
    width for tol 0.05, conf 0.9); twenty at once need tol/2.8 each (0.018): the benchmark asks
    for the worst of ~20 ends within 5 %, which a per-end gate of 0.035 leaves ~0.07 on small ROIs
    (benchmarks/results/batch_accuracy*.md). ``cap`` when ``confidence`` is None or it holds there."""
    if confidence is None or cap is None:
        return cap
    s = np.asarray(errs, float)
    s = s[np.isfinite(s)]
    level = float(np.log(confidence))
    if _within_logprob(np.minimum(s, cap), tol) >= level:
        return float(cap)
    lo, hi = 0.0, float(cap)
    for _ in range(40):             # the probability falls as g grows: bisection to ~1e-12 of cap
        g = 0.5 * (lo + hi)
        lo, hi = (g, hi) if _within_logprob(np.minimum(s, g), tol) >= level else (lo, g)
    return lo


def _end_table(vals, wk, n_resampled):
    """({name: worst end's error}, {name: [error of each end]}) of ``vals`` on weights ``wk``
    (:func:`_end_errors`; NaN where a quantity's draws are not all finite)."""
    mcse, ends = {}, {}
    for n, v in vals.items():
        errs = _end_errors(v, wk, _END_PROBS, n_resampled)
        ends[n] = [float("nan")] * len(_END_PROBS) if errs is None else errs
        mcse[n] = float("nan") if errs is None else max(errs, default=0.0)
    return mcse, ends


def _all_ends(ends):
    return [e for v in ends.values() for e in v]


def _worst_end_mcse(mcse):
    """The largest of ``mcse``'s values; NaN (draws not all finite) is the largest, 0 for none."""
    vals = list(mcse.values())
    if any(not np.isfinite(v) for v in vals):
        return float("nan")
    return max(vals, default=0.0)


def _fast_once(model, seed, n_draws, settings, x_map, cov, derived_fn=None):
    """One attempt of the fast path (:func:`fast_posterior`); ``n_draws`` None: ``settings.n_draws``,
    more after a top-up."""
    wrapped = _sampler_coordinates(model) if x_map is None and cov is None else None
    if wrapped is not None:
        # Newton from every start mapped into z (laplace_start's ``coords``). (BFGS run in z alone
        # had stopped 6 nats below the mode on a simulated ROI, so the BFGS route optimised in x and
        # refined in z; Newton in z reaches the same optimum or a higher one on the 29 sensors of
        # benchmarks/local_optima.py, docs/performance.md, "Newton's method".)
        t0 = time.perf_counter()
        z0, _, cz, _ = laplace_start(model, n_restarts=settings.n_restarts, refine_iter=settings.refine_iter,
                                     polish=settings.polish, coords=wrapped, polish_both=settings.polish_both)
        t_start = time.perf_counter() - t0
        d_fn = None if derived_fn is None else (lambda z: derived_fn(wrapped.to_x(z)))
        chains, diag = _fast_once(wrapped, seed, n_draws, settings, z0, cz, d_fn)
        diag["wall_map_s"] += t_start
        diag["wall_s"] += t_start
        chains.wall_s += t_start
        # back to the model's coordinates: draws, their log p without the Jacobian, the MAP
        D = wrapped.ndim
        z = chains.chain.reshape(-1, D)
        chains.chain = wrapped.to_x(z).reshape(chains.chain.shape)
        chains.log_prob = chains.log_prob - wrapped.log_jacobian(z).reshape(chains.log_prob.shape)
        chains.x_map = wrapped.to_x(chains.x_map)
        chains.lp_map = float(model.log_prob(chains.x_map[None])[0])
        wd = chains.extra.get("weighted_draws")
        if wd is not None:
            wd["x"] = wrapped.to_x(wd["x"])
        chains.extra["coordinates"] = diag["coordinates"] = wrapped.describe()
        return chains, diag
    t0 = time.perf_counter()
    default_n = n_draws is None
    n_draws = int(settings.n_draws if default_n else n_draws)
    if x_map is None and cov is None:
        x_map, lp_map, cov, t_map = laplace_start(model, n_restarts=settings.n_restarts,
                                                  refine_iter=settings.refine_iter, polish=settings.polish)
        t_map += t0
    else:
        if x_map is None:
            x_map, lp_map = find_map(model, n_restarts=settings.n_restarts)
        else:
            x_map = np.asarray(x_map, float)
            lp_map = float(model.log_prob(x_map[None])[0])
        t_map = time.perf_counter()
        if cov is None:
            cov = laplace_covariance(model, x_map)
            cov = refine_covariance(model, x_map, cov, max_iter=settings.refine_iter)
    t_lap = time.perf_counter()
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    nu = settings.nu
    n2 = int(round(settings.adapt_fraction * settings.n_proposals))
    n1 = settings.n_proposals - n2
    c1 = _proposal_cov(cov, settings.scale)
    # adapt_fraction 1 leaves nothing to adapt from: then every draw comes from the Laplace t
    floor = (isinstance(model, SamplerCoordinates) and model.j is not None
             and settings.clip_floor_fraction > 0 and n1 > 0 and n2 > 0)
    n_floor = int(round(settings.clip_floor_fraction * settings.n_proposals)) if floor else 0
    # defensive components: the clip floor, and each long one-sided tail the probe finds
    extra = []                                          # [(logpdf, draws)]
    tails, pairs = [], []
    if n1 > 0 and n2 > 0 and settings.tail_fraction > 0:
        skip = {(model.j, -1.0)} if floor else set()    # the clip floor covers that one
        tails = _tail_probe(model, x_map, lp_map, c1, skip)
        # the clip floor meets the farthest-reaching other tail (on sim09 the clip spread's lower
        # one: a sharp clip edge lets the clip level sit anywhere down to its bound)
        others = [t for t in tails if n_floor and t[0] != model.j]
        pairs = [max(others, key=lambda t: t[3])] if others and settings.floor_pair else []
        n_comp = max(len(tails) + len(pairs), 1)
        n_each = min(int(round(settings.tail_fraction * settings.n_proposals)),
                     int(settings.tail_max_fraction * settings.n_proposals) // n_comp, (n2 // 2) // n_comp)
        if n_each <= 0:
            tails, pairs = [], []
        n2 -= n_each * (len(tails) + len(pairs))        # the same number of draws in all
    # a defensive t, wide_scale × wider than the Laplace t (Hesterberg 1995): it bounds the weights
    # where the posterior reaches further than the Laplace and the moment-matched rounds, whose
    # weighted moments cannot see draws they never made (on small Gpixel ROIs the heaviest weights
    # sat 2–3 Laplace sds out, found only with 60 000 draws; docs/performance.md, "2026-11-24, 20:10–")
    n_wide = min(int(round(settings.wide_fraction * settings.n_proposals)), n2 // 2) if n1 > 0 and n2 > 0 else 0
    n2 -= n_wide                                        # (at most half of what the rounds have left)
    x1, _ = student_t_draws(x_map, c1, nu, (n1 - n_floor) if n1 > 0 else n2, rng)
    if n_wide:
        c_w = c1 * float(settings.wide_scale) ** 2
        extra.append((_t_logpdf(x_map, c_w, nu), student_t_draws(x_map, c_w, nu, n_wide, rng)[0]))
    if n_floor:
        draw_f, pdf_f = _clip_floor_proposal(model, x_map, c1, nu)
        extra.append((pdf_f, draw_f(n_floor, rng)[0]))
    for j, _, v, reach in tails:
        draw_t, pdf_t = _tail_proposal(x_map, c1, nu, j, v, reach)
        extra.append((pdf_t, draw_t(n_each, rng)[0]))
    for j, side, _, reach in pairs:
        draw_p, pdf_p = _pair_proposal(x_map, c1, nu, (j, side, reach), (model.j, _floor_top(x_map, c1, model.j)))
        extra.append((pdf_p, draw_p(n_each, rng)[0]))
    n_t = x1.shape[0]
    x1 = np.vstack([x1] + [xe for _, xe in extra])    # one log_prob call for all
    with np.errstate(all="ignore"):
        lp1 = model.log_prob(x1)
    cache = _DensityCache()
    if n1 > 0 and n2 > 0:
        comps = [(_t_logpdf(x_map, c1, nu), x1[:n_t], lp1[:n_t], (x_map, c1))]
        at = n_t
        for pdf_e, xe in extra:
            comps.append((pdf_e, x1[at:at + len(xe)], lp1[at:at + len(xe)], None))
            at += len(xe)
        x, logp, logq, comps = _adaptive_rounds(model, settings, rng, comps, n2, cache)
    else:
        x, logp, logq, comps = x1, lp1, student_t_logpdf(x1, x_map, c1, nu), None
    w, khat, ess = psis_weights(logp - logq)
    khat, ess = float(khat), float(ess)
    gate, tol, conf = settings.end_mcse_max, settings.end_tolerance, settings.end_confidence
    n_topup, n_out, partial = 0, n_draws, False

    def full_table():
        """Every quantity's interval-end errors on the current draws: (kept draws, weights, values,
        {name: worst end}, {name: ends}, the worst, the per-end target)."""
        xk_, wk_, vals_ = _end_values(model, x, w, derived_fn)
        mcse_, ends_ = _end_table(vals_, wk_, n_out)
        return xk_, wk_, vals_, mcse_, ends_, _worst_end_mcse(mcse_), _joint_target(_all_ends(ends_), tol, conf, gate)

    xk, wk, vals, mcse, ends, worst, target = full_table()
    # top up: more draws until every interval end's predicted Monte Carlo error is below the target
    # (its variance falls as 1/N; the target: end_mcse_max, lower where many ends near it would
    # leave the worst of them outside end_tolerance, _joint_target), at most max_proposals in all;
    # not when k̂ already rejects the proposal (more of the same draws would not help)
    while (target is not None and comps is not None and worst > target and khat < settings.khat_max
           and x.shape[0] < settings.max_proposals):
        want = x.shape[0] * (1.1 * (worst / target) ** 2 - 1.0)
        n_more = int(min(max(want, settings.n_proposals / 3), settings.max_proposals - x.shape[0]))
        aimed = []
        if settings.topup == "targeted":
            # draws aimed at the offending ends (their error falls faster than 1/√N there)
            # rounds of topup_draws while few are missing, growing with the draws so far (at most
            # 7 rounds from the default 6 000 to max_proposals) where many are
            base = settings.n_proposals / 4 if settings.topup_draws is None else settings.topup_draws
            n_more = int(min(max(base, x.shape[0] / 4), settings.max_proposals - x.shape[0]))
            aimed = _end_components(xk, wk, vals, mcse, target, n_out, settings.adapt_inflation,
                                    settings.topup_components, ends)
        if aimed and n_more >= len(aimed):
            each = [n_more // len(aimed) + (1 if i < n_more % len(aimed) else 0) for i in range(len(aimed))]
            x, logp, logq, comps = _add_components(model, settings, rng, comps,
                                                   [(mu, c, n) for (mu, c), n in zip(aimed, each)], cache)
        else:
            x, logp, logq, comps = _adaptive_rounds(model, replace(settings, adapt_rounds=1), rng, comps, n_more,
                                                    cache)
        n_topup += n_more
        w, khat, ess = psis_weights(logp - logq)
        khat, ess = float(khat), float(ess)
        # more draws are resampled after a top-up (n_draws unless the caller set it), so that
        # the resampling does not undo the gain: as many as there are weighted draws (twice the
        # IS ESS before 2026-11-24 afternoon, when interval_end_mcse's resampling term left out
        # what unequal weights add: with it, 2·ESS draws undid much of the gain)
        n_out = n_draws if not default_n else int(max(n_draws, x.shape[0]))
        # between rounds only the quantities near or above the target are looked at again (the
        # sorting of every quantity each round was ~12 % of a gated batch fit); once they are
        # below it, all of them (and the target again), and the rounds go on if one is above
        watch = None if settings.topup != "targeted" else {
            n for n, e in mcse.items() if not e <= 0.8 * target}
        if watch is None:
            xk, wk, vals, mcse, ends, worst, target = full_table()
            continue
        xk, wk, vals = _end_values(model, x, w, derived_fn, names=watch)
        part, part_ends = _end_table(vals, wk, n_out)
        partial = not _worst_end_mcse(part) <= target
        if not partial:
            xk, wk, vals, mcse, ends, worst, target = full_table()
            continue
        mcse = {**{n: e for n, e in mcse.items() if n not in watch}, **part}
        ends = {**{n: e for n, e in ends.items() if n not in watch}, **part_ends}
        worst = _worst_end_mcse(mcse)
        target = _joint_target(_all_ends(ends), tol, conf, gate)
        if not worst > target:
            # the watched quantities meet the new target, judged with the others' errors of an
            # earlier round (other weights, fewer draws resampled): all of them again before the
            # rounds stop. Without this, a table that the stale errors passed and the fresh ones
            # failed was rejected below with draws to spare (15 of the 1 000 batch ROIs at
            # 7 500–14 647 of 24 000 draws; docs/performance.md, "2026-11-24, 22:15–")
            xk, wk, vals, mcse, ends, worst, target = full_table()
            partial = False
    if n_topup and partial:     # the rounds stopped above the target: every quantity's error, as reported
        xk, wk, vals, mcse, ends, worst, target = full_table()
    p_within = float(np.exp(_within_logprob(_all_ends(ends), tol)))
    n_draws = n_out
    n_outside = int(np.sum(~np.isfinite(logp)))
    t_is = time.perf_counter()
    idx = _systematic_resample(w, n_draws, rng)
    idx = idx[rng.permutation(n_draws)]
    draws = x[idx]
    lp = logp[idx]
    reasons = []
    if not khat < settings.khat_max:
        reasons.append(f"Pareto k̂ {khat:.2f} ≥ {settings.khat_max:g}")
    if not ess >= settings.min_ess_is:
        reasons.append(f"importance-sampling ESS {ess:.0f} < {settings.min_ess_is:g}")
    if not np.isfinite(lp_map):
        reasons.append("no finite MAP")
    # a proposal that passes but whose draws are too few for the interval ends: not a failed
    # optimiser, so fast_posterior does not retry it with restarts
    mcse_only = not reasons
    if target is not None and not worst <= target:
        if not np.isfinite(worst):
            reasons.append("interval-end Monte Carlo error undefined: a parameter's draws are not all finite")
        elif not worst <= gate:
            reasons.append(f"interval-end Monte Carlo error {worst:.3f} of the width > {gate:g} "
                           f"after {x.shape[0]} draws")
        else:
            reasons.append(f"predicted probability that every interval end is within {tol:g} of the width "
                           f"{p_within:.2f} < {conf:g} (worst end {worst:.3f}) after {x.shape[0]} draws")
    wall = time.perf_counter() - t0
    diag = {
        "method": METHOD,
        "accepted": not reasons,
        "reason": "; ".join(reasons),
        "khat": khat,
        "ess_is": ess,
        "n_proposals": int(x.shape[0]),
        "n_topup": int(n_topup),
        "end_mcse_max": gate,
        "end_tolerance": tol,
        "end_confidence": conf,
        "end_within_probability": p_within,
        "rejected_for_mcse_only": bool(reasons) and mcse_only,
        "n_draws": n_draws,
        "n_outside_support": n_outside,
        "khat_max": settings.khat_max,
        "min_ess_is": settings.min_ess_is,
        "nu": settings.nu,
        "wall_s": wall,
        "wall_map_s": t_map - t0,          # with Newton (the default) the covariance too
        "wall_laplace_s": t_lap - t_map,
        "wall_is_s": t_is - t_lap,
        "end_mcse": mcse,
        # the long one-sided tails the probe found, each given tail_fraction of the draws
        "tails": [_tail_entry(model, t, n_each) for t in tails]
                 + [_tail_entry(model, t, n_each, " with the clip floor") for t in pairs],
        "settings": asdict(settings),
    }
    D = x_map.size
    chains = ChainResult(
        chain=draws.reshape(1, n_draws, 1, D),
        log_prob=lp.reshape(1, n_draws, 1),
        acceptance=np.array([1.0]),       # no Markov chain: every resampled draw is kept
        tau=np.ones(D),                   # independent draws: τ = 1 step
        x_map=x_map, lp_map=float(lp_map),
        settings=QUALITY_PRESETS["fast"],
        wall_s=wall, n_rounds=0,
        extra={k: diag[k] for k in ("method", "khat", "ess_is", "n_proposals", "n_topup", "accepted", "reason",
                                    "khat_max", "min_ess_is", "nu", "end_mcse", "end_mcse_max", "end_tolerance",
                                    "end_confidence", "end_within_probability", "tails", "settings")},
    )
    # the weighted draws behind the resampled ones (those of non-negligible weight, as _end_mcse
    # keeps them): FitResult computes the interval ends' Monte Carlo error of the derived
    # quantities (capacity, TR, ...) from them, which need the scene and MTF this path has not got
    xk, wk = _weighted_kept(x, w)
    chains.extra["weighted_draws"] = {"x": xk, "w": wk, "n_resampled": n_draws}
    return chains, diag


@one_blas_thread
def fast_posterior(model, *, seed, n_draws: int | None = None,
                   settings: FastSettings = FastSettings(), x_map=None, cov=None, derived_fn=None):
    """Laplace–IS posterior draws for ``model`` (module docstring).

    Parameters
    ----------
    model : the posterior (:class:`bayescap.model.PTCModel` or anything with ``log_prob``,
        ``ndim``, ``initial_guess``).
    seed : seeds the proposal and the resampling (same seed, same draws).
    n_draws : equally weighted draws returned (default ``settings.n_draws``).
    settings : :class:`FastSettings`.
    x_map, cov : a MAP and covariance already computed (used as given: no retry with restarts);
        computed here when not given.
    derived_fn : ``x (n, ndim) -> {name: values (n,)}``, quantities computed from the parameters
        (capacity, TR, ...; :meth:`bayescap.posterior.FitResult.derived_values_fn`): their interval
        ends' Monte Carlo error joins the parameters' in ``end_mcse``, so that the top-up towards
        ``settings.end_mcse_max`` covers them too (without it, a derived quantity above the gate is
        found only by the result's own check, and ``bayescap.fit`` falls back to MCMC).

    Returns
    -------
    (ChainResult, dict) : the draws as a ChainResult of shape ``(1, n_draws, 1, ndim)`` and the
    diagnostics ``{"accepted", "khat", "ess_is", "n_proposals", "khat_max", "min_ess_is",
    "reason", "wall_s", ...}``. ``accepted`` is False when the caller must fall back to MCMC.
    """
    chains, diag = _fast_once(model, seed, n_draws, settings, x_map, cov, derived_fn)
    diag["retried_with_restarts"] = False
    if (not diag["accepted"] and not diag["rejected_for_mcse_only"] and x_map is None
            and settings.retry_restarts > settings.n_restarts):
        # a single optimiser start can stop at the initial guess (measured on small-frame
        # sensors): retry with restarts before declaring failure
        retry = replace(settings, n_restarts=settings.retry_restarts, polish_both=True)
        c2, d2 = _fast_once(model, seed, n_draws, retry, None, None, derived_fn)
        first = {k: diag[k] for k in ("khat", "ess_is", "reason")}
        wall = d2["wall_s"] + diag["wall_s"]
        if d2["accepted"] or d2["khat"] < diag["khat"]:   # keep the better of the two attempts
            chains, diag = c2, d2
        diag["wall_s"] = chains.wall_s = wall
        diag["retried_with_restarts"] = True
        diag["first_attempt"] = first
    chains.extra["retried_with_restarts"] = diag["retried_with_restarts"]
    wd = chains.extra.get("weighted_draws")
    if derived_fn is not None and wd is not None:
        # the function whose quantities' interval-end errors are in end_mcse (with its inputs, for
        # FitResult to reuse them: FitResult._derived_end_mcse_importance)
        wd["derived_fn"] = derived_fn
    return chains, diag
