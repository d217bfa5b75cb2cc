"""Convergence diagnostics of the ensembles: rank-normalised split R-hat, bulk and tail ESS
(Vehtari et al. 2021), integrated autocorrelation times and the Monte Carlo error of interval ends.
Every diagnostic counts each independent ensemble as one chain (:func:`by_ensemble`), as ArviZ does
on ``posterior.nc``."""

from __future__ import annotations

import functools
import warnings

import numpy as np
from scipy.special import ndtri


def _emcee_integrated_time(x, c=5):
    """emcee's ``autocorr.integrated_time(x, quiet=True, tol=0)`` for ``x`` (steps, walkers, params),
    with every walker's and parameter's FFT in one call instead of one Python call per walker and
    parameter (≈ 14 000 on a 4 × 300 × 96 × 12 chain, 0.6 s); equal to emcee's to rounding (tested)."""
    n_t = x.shape[0]
    n = 1
    while n < n_t:
        n <<= 1
    y = np.ascontiguousarray(np.transpose(x, (1, 2, 0)))  # (walkers, params, steps)
    f = np.fft.rfft(y - y.mean(axis=-1, keepdims=True), n=2 * n, axis=-1)
    acf = np.fft.irfft(f.real**2 + f.imag**2, n=2 * n, axis=-1)[..., :n_t]
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = acf / acf[..., :1]
    f_mean = acf.mean(axis=0).T  # (steps, params), walkers averaged
    taus = 2.0 * np.cumsum(f_mean, axis=0) - 1.0
    out = np.empty(x.shape[2])
    for d in range(x.shape[2]):
        m = np.arange(n_t) < c * taus[:, d]
        w = int(np.argmin(m)) if np.any(m) else n_t - 1
        out[d] = taus[w, d]
    return out


def integrated_time(chain):
    """Integrated autocorrelation time (steps) per parameter, emcee's estimator applied to each
    ensemble (walkers averaged, as emcee does) and the largest over ensembles kept."""
    taus = [_emcee_integrated_time(chain[e]) for e in range(chain.shape[0])]
    return np.max(np.array(taus), axis=0)


@functools.lru_cache(maxsize=2)
def draw_order(n_steps, n_walkers):
    """``(order, step, walker)``: the draws of one ensemble as one chain. Draw ``j`` of the chain is
    the ensemble's step-major draw ``order[j]`` (``step * n_walkers + walker``), from step
    ``step[j]`` of walker ``walker[j]``. The draws in the first half of the step-major order come
    first, then the middle draw of an odd count, then the second half, each walker by walker in
    step order. ArviZ's split of a chain into halves (``_split_chains``) is then a split *in time*
    (Vehtari et al. 2021): a drift shared by every ensemble (all start from one approximation) shows
    as a difference between the halves, and a slow burn-in transient of the clip spread cannot pass
    the check as a split of the walkers would let it. Within a half each walker's steps are
    consecutive, so the autocorrelation ESS sees each walker's own correlation in time. The layout
    of ``posterior.nc`` (:mod:`bayescap.posterior.inference_data`). The last two shapes' orders are
    cached (a round's check asks for the same one for every quantity); the arrays are read-only."""
    n = n_steps * n_walkers
    i = np.arange(n)
    half = n // 2
    part = np.where(i < half, 0, np.where(i >= n - half, 2, 1))
    s, w = np.divmod(i, n_walkers)
    order = np.lexsort((s, w, part))
    out = (order, s[order], w[order])
    for a in out:  # cached (every quantity of a chain asks for the same order): read-only
        a.setflags(write=False)
    return out


def by_ensemble(x_esw):
    """(E, S, W) -> (E, S*W): each independent ensemble as one chain, its draws in
    :func:`draw_order`. The chains of every diagnostic here (R-hat, bulk and tail ESS, the
    quantile MCSE): ``benchmarks/ess_check.py`` measured the spread of posterior means and
    quantiles across seeds against the Monte Carlo error each layout's ESS predicts: with the
    ensembles as chains the quantiles' agree and the means' spread is 6–12 % above the prediction;
    with each walker as a chain the ESS was 25–35 % too low."""
    x = np.asarray(x_esw)
    E, S, W = x.shape
    order, _, _ = draw_order(S, W)
    return np.ascontiguousarray(x.reshape(E, S * W)[:, order])


def diagnostics(x_esw, arviz_module=None):
    """Rank-normalised split R-hat and bulk/tail ESS (ArviZ's) of one quantity whose draws are
    shaped (n_ensembles, n_steps, n_walkers), the ensembles as chains (:func:`by_ensemble`): the
    numbers ``az.rhat`` and ``az.ess`` give on ``posterior.nc``."""
    import arviz as az

    x = np.asarray(x_esw, float)
    E, S, W = x.shape
    if not np.all(np.isfinite(x)):
        return {"rhat": float("nan"), "ess_bulk": 0.0, "ess_tail": 0.0}
    if np.ptp(x) == 0:
        return {"rhat": 1.0, "ess_bulk": float(E * S * W), "ess_tail": float(E * S * W)}
    ens = by_ensemble(x)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rhat = float(az.rhat(ens, method="rank"))
        ess_b = float(az.ess(ens, method="bulk"))
        ess_t = float(az.ess(ens, method="tail"))
    return {"rhat": rhat, "ess_bulk": ess_b, "ess_tail": ess_t}


def _sorted_ranks(srt):
    """Ranks (ties averaged) of the elements of the sorted array ``srt``, in its order."""
    obs = np.concatenate([[True], srt[1:] != srt[:-1]])
    dense = np.cumsum(obs)
    count = np.concatenate([np.nonzero(obs)[0], [obs.size]])
    return 0.5 * (count[dense] + count[dense - 1] + 1)


def _average_ranks(a, order=None):
    """Ranks of a 1-D array, ties averaged (scipy.stats.rankdata(method="average")); ``order``:
    an argsort of ``a`` if the caller has one."""
    order = np.argsort(a, kind="quicksort") if order is None else order
    r = np.empty(a.size)
    r[order] = _sorted_ranks(a[order])
    return r


def _blom(r):
    """ArviZ's rank normalisation of ranks ``r`` (Blom offsets, c = 3/8)."""
    return ndtri((r - 0.375) / (r.size + 0.25))


def _z_scale(a):
    """ArviZ's rank normalisation (Blom offsets, c = 3/8) over all elements of ``a``."""
    return _blom(_average_ranks(a.ravel())).reshape(a.shape)


def _split(a):
    """ArviZ's _split_chains for a 2-D (chains, draws) array."""
    half = a.shape[1] // 2
    return np.vstack([a[:, :half], a[:, -half:]])


def _rhat_kernel(a):
    """ArviZ 0.x ``_rhat`` (classic R-hat of a (chains, draws) array), without importing ArviZ."""
    n = a.shape[1]
    between = n * np.var(np.mean(a, axis=1), ddof=1)
    within = np.mean(np.var(a, axis=1, ddof=1))
    return float(np.sqrt((between / within + n - 1) / n))


def _ess_kernel(a):
    """ArviZ 0.x ``_ess`` (FFT autocovariance, Geyer's initial monotone sequence) of a
    (chains, draws) array, without importing ArviZ (whose import costs ~1 s)."""
    from scipy.fft import next_fast_len

    a = np.asarray(a, dtype=float)
    if np.max(a) - np.min(a) < np.finfo(float).resolution:
        return float(a.size)
    n_chain, n_draw = a.shape
    m = next_fast_len(2 * n_draw)
    chain_mean = a.mean(axis=1)
    c = a - chain_mean[:, None]
    f = np.fft.rfft(c, n=m, axis=1)
    # only the chains' mean autocovariance is used: the inverse transform is linear, so one of
    # the mean power spectrum serves (ArviZ inverts every chain's; equal to ~1e-15 relative)
    macov = np.fft.irfft(np.mean(f.real**2 + f.imag**2, axis=0), n=m)[:n_draw] / n_draw
    mean_var = macov[0] * n_draw / (n_draw - 1.0)
    var_plus = mean_var * (n_draw - 1.0) / n_draw
    if n_chain > 1:
        var_plus += np.var(chain_mean, ddof=1)
    rho = np.zeros(n_draw)
    rho_even = 1.0
    rho[0] = rho_even
    rho_odd = 1.0 - (mean_var - macov[1]) / var_plus
    rho[1] = rho_odd
    t = 1
    while t < (n_draw - 3) and (rho_even + rho_odd) > 0.0:
        rho_even = 1.0 - (mean_var - macov[t + 1]) / var_plus
        rho_odd = 1.0 - (mean_var - macov[t + 2]) / var_plus
        if (rho_even + rho_odd) >= 0:
            rho[t + 1] = rho_even
            rho[t + 2] = rho_odd
        t += 2
    max_t = t - 2
    if rho_even > 0:
        rho[max_t + 1] = rho_even
    t = 1
    while t <= max_t - 2:
        if (rho[t + 1] + rho[t + 2]) > (rho[t - 1] + rho[t]):
            rho[t + 1] = (rho[t - 1] + rho[t]) / 2.0
            rho[t + 2] = rho[t + 1]
        t += 2
    ess = n_chain * n_draw
    tau_hat = -1.0 + 2.0 * np.sum(rho[: max_t + 1]) + np.sum(rho[max_t + 1 : max_t + 2])
    tau_hat = max(tau_hat, 1 / np.log10(ess))
    return float(np.nan if np.isnan(rho).any() else ess / tau_hat)


def _type7_quantiles(srt, probs):
    """Quantiles of the sorted draws ``srt`` with ArviZ's arithmetic (``scipy.stats.mstats.mquantiles``,
    alphap = betap = 1: R's type 7, as ``np.quantile``, whose rounding differs): with many repeated
    draws a quantile a rounding below a repeated value leaves its copies out of the tail indicator,
    and the tail ESS moved 0.3 % from ArviZ's on a standard fit."""
    n = srt.size
    p = np.asarray(probs, float)
    aleph = n * p + (1.0 - p)
    k = np.floor(np.clip(aleph, 1, n - 1)).astype(int)
    gamma = np.clip(aleph - k, 0.0, 1.0)
    return (1.0 - gamma) * srt[k - 1] + gamma * srt[k]


def fast_diagnostics(x_esw):
    """The same numbers as :func:`diagnostics` (rank-normalised split R-hat, bulk and tail ESS, the
    ensembles as chains: ArviZ's algorithms, its ``_rhat``/``_ess`` kernels) with one rank sort
    shared by R-hat and bulk ESS instead of ArviZ's three, and one for the folded draws: 3× faster
    on a 4 × 200 × 72 chain. Falls back to :func:`diagnostics` when the shapes do not allow the
    sharing (an odd number of draws per ensemble) or for a single ensemble."""
    x = np.asarray(x_esw, float)
    E, S, W = x.shape
    if not np.all(np.isfinite(x)) or np.ptp(x) == 0 or (S * W) % 2 or S < 4 or E < 2:
        return diagnostics(x)
    _ess, _rhat = _ess_kernel, _rhat_kernel
    ens = by_ensemble(x)
    # the split halves hold every draw once (S·W even), so the ranks over all draws are ArviZ's over
    # the split chains; one sort serves the ranks, the median, the tail quantiles and the folded ranks
    flat = ens.ravel()
    order = np.argsort(flat, kind="quicksort")
    srt = flat[order]
    n = srt.size
    z = np.empty(n)
    z[order] = _blom(_sorted_ranks(srt))
    z = z.reshape(ens.shape)
    # the folded draws |x − median| in the sorted order fall then rise: a stable sort (timsort)
    # merges the two runs in linear time
    med = 0.5 * (srt[n // 2 - 1] + srt[n // 2]) if n % 2 == 0 else srt[n // 2]  # = np.median
    fold = np.abs(srt - med)
    o2 = np.argsort(fold, kind="stable")
    rf = np.empty(n)
    rf[o2] = _sorted_ranks(fold[o2])
    zf = np.empty(n)
    zf[order] = _blom(rf)
    zf = zf.reshape(ens.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rhat = float(max(_rhat(_split(z)), _rhat(_split(zf))))
        ess_b = float(_ess(_split(z)))
        ql, qh = _type7_quantiles(srt, (0.05, 0.95))
        ess_t = float(min(_ess(_split(ens <= ql)), _ess(_split(ens <= qh))))
    return {"rhat": rhat, "ess_bulk": ess_b, "ess_tail": ess_t}


#: the probabilities of the ±1 sd points of a standard normal, as ArviZ's quantile MCSE uses them
_ONE_SD_PROBS = (0.1586553, 0.8413447)


def quantile_mcse(x_esw, probs=(0.025, 0.975), quantiles=None):
    """Monte Carlo standard error of the quantiles ``probs`` of ensemble draws (E, S, W), in the
    draws' units: Vehtari et al. (2021, §4.3) as ArviZ 0.x's ``mcse(method="quantile")`` computes
    it, with the ensembles as chains (:func:`by_ensemble`, as the ESS of :func:`fast_diagnostics`).

    The ESS of the indicator 1{x ≤ q̂_p} over the split ensemble chains gives a Beta(ESS·p + 1,
    ESS·(1 − p) + 1) distribution for the probability below the estimate q̂_p; its ±1 sd points
    map to two order statistics of the draws, and the MCSE is half their distance.
    ``quantiles``: the draws' ``probs`` quantiles if the caller has them. Returns an array like
    ``probs`` (NaN where the draws are not all finite)."""
    from scipy.special import (
        betaincinv,  # scipy.stats.beta.ppf's kernel, without its overhead
    )

    x = np.asarray(x_esw, float)
    E, S, W = x.shape
    probs = np.atleast_1d(np.asarray(probs, float))
    if not np.all(np.isfinite(x)) or S < 4:
        return np.full(probs.shape, np.nan)
    ens = by_ensemble(x)
    flat = ens.ravel()
    n = flat.size
    qs = np.quantile(flat, probs) if quantiles is None else np.atleast_1d(quantiles)
    idx = []
    for p, q in zip(probs, qs):
        ess = _ess_kernel(_split(ens <= q))
        with np.errstate(invalid="ignore"):
            a = betaincinv(ess * p + 1.0, ess * (1.0 - p) + 1.0, np.array(_ONE_SD_PROBS)) * n - 1.0
        idx.append((int(np.floor(np.nanmax((a[0], 0)))), int(np.ceil(np.nanmin((a[1], n - 1))))))
    ks = sorted({k for pair in idx for k in pair})
    srt = np.partition(flat, ks)  # the order statistics needed, without a full sort
    return np.array([0.5 * (srt[i2] - srt[i1]) for i1, i2 in idx])


def interval_end_mcse_mcmc(x_esw):
    """Monte Carlo error of the 95 % interval's ends of ensemble draws (E, S, W), as a fraction of
    the interval's width: the larger of the two ends' :func:`quantile_mcse`. 0 for a constant
    quantity; NaN when the draws are not all finite. The MCMC counterpart of
    :func:`bayescap.inference.end_errors.interval_end_mcse` (importance draws)."""
    x = np.asarray(x_esw, float)
    if not np.all(np.isfinite(x)):
        return float("nan")
    probs = (0.025, 0.975)
    q = np.quantile(x, probs)
    if not q[1] > q[0]:
        return 0.0
    return float(np.max(quantile_mcse(x, probs, q)) / (q[1] - q[0]))


def worst_end(end):
    """The quantity of ``end`` ({name: interval-end error}) with the largest error; NaN (draws
    not all finite) counts as the worst."""
    return max(end, key=lambda k: end[k] if np.isfinite(end[k]) else np.inf)
