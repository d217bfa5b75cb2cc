"""Densities of the observations: the gamma density of a sample variance, the normal density of a
mean, the robust outlier mixture around both, and :class:`_LikelihoodMixin`, the
:class:`~bayescap.model.PTCModel` methods that turn its predictions into log-likelihood blocks.

A temporal variance from a frame pair over ``n`` pixels follows a scaled χ² with ``ν = n − 1``
degrees of freedom around the model variance: Gamma(ν/2, 2σ²/ν) (:func:`gamma_logpdf`). Rows of
the blocks in :data:`ROBUST_BLOCKS` may be bad measurements: a broad component of prior weight
:data:`OUTLIER_RATE` (Hogg, Bovy & Lang 2010) takes them.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln, log_ndtr, ndtri

__all__ = ["BOUND_BLOCKS", "OUTLIER_RATE", "OUTLIER_REL_SD", "ROBUST_BLOCKS", "gamma_logpdf"]

_LOG_2PI = np.log(2.0 * np.pi)
#: prior probability that a row is a bad measurement, and the relative scatter of bad rows
OUTLIER_RATE = 0.02
OUTLIER_REL_SD = 0.3
ROBUST_BLOCKS = ("bright_var", "dark_var", "mean")
#: blocks that bound the model rather than give the observations a density (kind "upper_probit"):
#: in the posterior, but not among the pointwise terms PSIS-LOO and the posterior predictive read
#: (a bound that holds contributes exactly 0 in every draw, which leaves LOO's Pareto fit undefined)
BOUND_BLOCKS = ("saturated",)
# log of OUTLIER_RATE × the log-normal's normalisation, less log v (added to both components)
_BAD_GAMMA_CONST = float(np.log(OUTLIER_RATE) - np.log(OUTLIER_REL_SD) - 0.5 * np.log(2.0 * np.pi))


def gamma_logpdf(v, sigma2, k):
    """log Gamma(v; shape k, scale σ²/k) (mean σ²), stable for huge k.

    Written as ``k(log r − r + 1) + [k log k − k − lgamma(k)] − log v`` with ``r = v/σ²``;
    ``log r − r + 1 = log1p(d) − d`` with ``d = r − 1``; the bracket uses Stirling's series for
    k > 10 (no cancellation between two 10⁶-sized numbers).
    """
    g, _ = _gamma_logpdf_and_log_ratio(v, sigma2, k)
    return g - np.log(v)


def _gamma_logpdf_and_log_ratio(v, sigma2, k):
    """:func:`gamma_logpdf` + log v, and log(v/σ²): the robust blocks reuse the log ratio for
    their outlier component (one logarithm per element fewer)."""
    r = v / sigma2
    d = r - 1.0
    lr = np.log1p(d)
    core = lr - d
    kk = np.asarray(k, float)
    with np.errstate(divide="ignore"):
        inv = 1.0 / kk
        stirling = 0.5 * np.log(kk) - 0.5 * _LOG_2PI - inv * (1.0 / 12.0 - inv * inv * (1.0 / 360.0))
    small = ~(kk > 10.0)
    if small.any():  # rare (ν = n_pixels − 1 is large): lgamma only where Stirling is not used
        shape = np.broadcast_shapes(stirling.shape, core.shape)
        stirling = np.array(np.broadcast_to(stirling, shape))  # a writable copy
        small = np.broadcast_to(small, shape)
        ks = np.broadcast_to(kk, shape)[small]
        with np.errstate(divide="ignore", invalid="ignore"):
            stirling[small] = ks * np.log(ks) - ks - gammaln(ks)
    return kk * core + stirling, lr


def _norm_logpdf(x, mu, sd):
    z = (x - mu) / sd
    return -0.5 * z * z - np.log(sd) - 0.5 * _LOG_2PI


def _logaddexp(a, b):
    """``np.logaddexp(a, b)`` from numpy's vectorised exp and log: 3× faster on large arrays
    (numpy's logaddexp calls the scalar libm functions element by element); equal to it within
    1 ulp of max(|result|, 1) on 10⁶ random pairs (``tests/test_model.py`` allows 4), −inf where
    both are −inf."""
    m = np.maximum(a, b)
    with np.errstate(invalid="ignore"):
        # log(1 + e) for e = exp(−|a − b|) in (0, 1]: absolute error ≤ 1.2e-16, i.e. within an ulp
        # of max(|result|, 1), and cheaper than log1p there (7 against 11 ns an
        # element); |a − b| capped at 50 (e ≥ 2e-22, which rounds away against 1)
        # so that exp never takes its slow underflow path (25 against 9 ns)
        out = m + np.log(1.0 + np.exp(-np.minimum(np.abs(a - b), 50.0)))
    return np.where(m == -np.inf, m, out)


class _LikelihoodMixin:
    """The likelihood blocks of :class:`~bayescap.model.PTCModel`: each block of
    :meth:`predict` (:class:`~bayescap.model.prediction._PredictionMixin`) scored by its density,
    robust blocks with the outlier mixture, and the blocks' observations labelled by file row."""

    def _block_loglik(self, name, obs, model, spread, kind, with_outlier_prob=False):
        obs = obs if np.ndim(obs) == 2 else obs[None, :]
        if kind == "upper_probit":
            # an upper bound: the model's fraction above the measured one by the probit tolerance
            good = log_ndtr((ndtri(obs) - ndtri(np.clip(model, 0.0, 1.0 - 1e-12))) / spread)
            return (good, None) if with_outlier_prob else good
        robust = self.terms.robust and name in ROBUST_BLOCKS
        if not robust:
            good = gamma_logpdf(obs, model, spread) if kind == "gamma" else _norm_logpdf(obs, model, spread)
            return (good, None) if with_outlier_prob else good
        # a broad outlier component (Hogg, Bovy & Lang 2010): a row is a bad measurement with
        # prior probability OUTLIER_RATE, then scattered by OUTLIER_REL_SD around the model.
        # Both components of a gamma block carry the same −log v (added once at the end), and the
        # outlier's log-normal needs log(v/model), which the gamma density has already computed.
        if kind == "gamma":
            good, lr = _gamma_logpdf_and_log_ratio(obs, model, spread)
            bad = (-0.5 / OUTLIER_REL_SD**2) * lr * lr + _BAD_GAMMA_CONST
            shift = -np.log(obs)
        else:
            good = _norm_logpdf(obs, model, spread)
            # hypot's overflow guard is not needed for DN-sized numbers; sqrt is ~4× cheaper
            bad = _norm_logpdf(obs, model, np.sqrt(spread * spread + (OUTLIER_REL_SD * model) ** 2))
            bad = bad + np.log(OUTLIER_RATE)
            shift = 0.0
        a = np.log1p(-OUTLIER_RATE) + good
        ll = _logaddexp(a, bad)
        if with_outlier_prob:
            return ll + shift, np.exp(bad - ll)
        return ll + shift

    def loglik_terms(self, th):
        """Pointwise log-likelihood blocks (each (n_draws, n_obs))."""
        return {name: self._block_loglik(name, *blk) for name, blk in self.predict(th).items()}

    #: the CSV column each likelihood block's observations come from
    BLOCK_COLUMNS = {
        "dark_var": "dark_temporal_var_dn2",
        "bright_var": "temporal_var_dn2",
        "mean": "mean_dn",
        "clip_mean": "mean_dn",
        "plateau_var": "temporal_var_dn2",
        "spatial_var": "spatial_var_dn2",
        "dark_spatial_var": "dark_spatial_var_dn2",
        "dark_mean": "dark_mean_dn",
        "saturated": "frac_saturated",
    }

    def nonfinite_observations(self, x):
        """The observations whose log-likelihood is not finite at the point ``x`` (ndim,): a list of
        ``(block, file row, CSV column, observed value, model value)``, in block and row order. Used
        to name the offending rows when no optimiser start has a finite posterior."""
        th = np.atleast_2d(np.asarray(x, float))[:1]
        out = []
        with np.errstate(all="ignore"):
            for name, blk in self.predict(th).items():
                rows = self.observation_rows(name)
                ll = np.broadcast_to(self._block_loglik(name, *blk), (1, rows.size))[0]
                obs = np.broadcast_to(blk[0], (1, rows.size))[0]
                mod = np.broadcast_to(blk[1], (1, rows.size))[0]
                for j in np.nonzero(~np.isfinite(ll))[0]:
                    out.append((name, int(rows[j]), self.BLOCK_COLUMNS.get(name, name), float(obs[j]), float(mod[j])))
        return out

    def pointwise_loglik(self, th):
        """Log-likelihood of every observation for draws ``th``: (n_draws, n_obs), and the
        matching labels ``[(block, row), ...]`` (for PSIS-LOO; the bounds of :data:`BOUND_BLOCKS`
        left out)."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            terms = self.loglik_terms(th)
        labels, cols = [], []
        for name, ll in terms.items():
            if name in BOUND_BLOCKS:
                continue
            rows = self.observation_rows(name)
            ll = np.broadcast_to(ll, (th.shape[0], rows.size))
            cols.append(ll)
            labels += [(name, int(r)) for r in rows]
        return np.concatenate(cols, axis=1), labels

    def outlier_probabilities(self, th, pred=None) -> dict:
        """Posterior probability that each observation is an outlier, per block: {block: (rows,
        probabilities)} averaged over the draws ``th`` (``pred``: ``self.predict(th)`` if the
        caller has it already)."""
        out = {}
        if not self.terms.robust:
            return out
        n = np.atleast_2d(th).shape[0]
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for name, blk in (self.predict(th) if pred is None else pred).items():
                if name not in ROBUST_BLOCKS:
                    continue
                out[name] = (self.observation_rows(name), self._mean_outlier_prob(name, blk, n))
        return out

    #: draws × observations per chunk of :meth:`_mean_outlier_prob`
    OUTLIER_CHUNK_ELEMENTS = 1 << 20

    def _mean_outlier_prob(self, name, blk, n):
        """``nanmean`` over the ``n`` draws of a block's outlier probabilities, computed in chunks of
        draws (the density's temporaries are (draws, observations) arrays) and summed draw by draw
        in order: the same numbers as ``np.nanmean(prob, axis=0)`` of the whole, bit for bit (its
        sum over the first axis of a C-ordered array also adds row after row)."""
        cols = max(int(np.shape(blk[1])[-1]), 1)
        per = max(1, self.OUTLIER_CHUNK_ELEMENTS // cols)
        tot = cnt = None
        for lo in range(0, n, per):
            part = tuple(x[lo : lo + per] if np.ndim(x) == 2 and np.shape(x)[0] == n and n > 1 else x for x in blk[:3])
            _, prob = self._block_loglik(name, *part, blk[3], with_outlier_prob=True)
            prob = np.atleast_2d(prob)
            if tot is None:
                tot, cnt = np.zeros(prob.shape[1]), np.zeros(prob.shape[1], np.intp)
            for row in prob:
                bad = np.isnan(row)
                tot += np.where(bad, 0.0, row)
                cnt += ~bad
        return tot / cnt

    def observation_rows(self, block):
        """Data-row labels (1-based file rows) of the observations of a block."""
        d = self.data
        ok = np.nonzero(~self.full_sat)[0]
        idx = {
            "dark_var": np.arange(d.n_levels),
            "bright_var": ok,
            "mean": ok,
            "clip_mean": np.nonzero(self.full_sat)[0],
            "plateau_var": np.nonzero(self.full_sat)[0],
            "spatial_var": ok[self.sp_rows],
            "dark_spatial_var": self.spd_rows,
            "dark_mean": np.arange(d.n_levels),
            "saturated": ok[getattr(self, "sat_rows", np.zeros(0, int))],
        }[block]
        return np.array([d.row_label(i) for i in idx], int)

    def log_likelihood(self, th):
        terms = self.loglik_terms(th)
        return sum(v.sum(axis=1) for v in terms.values())
