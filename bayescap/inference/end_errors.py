"""Interval-end Monte Carlo errors of weighted draws: each 95 % interval end's predicted error as a
fraction of the width (with the resampling's share), the table over every quantity that varies,
and the joint check that every end is within a tolerance with a given probability."""

from __future__ import annotations

import numpy as np
from scipy.special import erfc

__all__ = ["interval_end_mcse"]


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
    For equal weights that is p(1 − p)(1/n − 1/N), sampling n of N without replacement; unequal
    weights add to it (at n = N it is not 0). Returns the largest over ``probs``, divided by
    Q(0.975) − Q(0.025) (0 when the width is 0; NaN when the values are not all finite, as
    :func:`bayescap.inference.diagnostics.interval_end_mcse_mcmc`)."""
    errs = _end_errors(values, w, probs, n_resampled)
    return float("nan") if errs is None else max(errs, default=0.0)


def _weighted_cdf(values, w):
    """The values sorted, their weights in that order, the normalised cumulative weight F, the
    weights' total and the 95 % width Q(0.975) − Q(0.025) (Q interpolated in F); None when the
    values are not all finite."""
    v = np.asarray(values, float)
    if not np.all(np.isfinite(v)):
        return None
    o = np.argsort(v)
    v, ws = v[o], w[o]
    F = np.cumsum(ws)
    F_tot = F[-1]
    F /= F_tot
    return v, ws, F, F_tot, np.interp(0.975, F, v) - np.interp(0.025, F, v)


def _end_errors(values, w, probs=(0.025, 0.975), n_resampled=None):
    """Per end of ``probs``: :func:`interval_end_mcse`'s error as a fraction of the width (a list;
    None when the values are not all finite, zeros when the width is 0)."""
    cdf = _weighted_cdf(values, w)
    if cdf is None:
        return None
    v, ws, F, F_tot, width = cdf
    Q = lambda p: np.interp(p, F, v)
    if not width > 0:
        return [0.0 for _ in probs]
    # Σ w_i² (1{v_i ≤ q} − p)² from the cumulative sum of w² up to q (one pass for both ends)
    c2 = np.cumsum(ws * ws)
    if n_resampled:
        # systematic resampling gives draw i floor(n w_i) copies and one more with probability
        # frac(n w_i); the count below q varies as a sum of those Bernoullis given the total n
        fr = n_resampled * (ws / F_tot)
        fr -= np.floor(fr)  # frac(n w_i): np.mod is ~5x slower here
        bern = np.cumsum(fr * (1.0 - fr))
    out = []
    for p in probs:
        q = Q(p)
        k = int(np.searchsorted(v, q, side="right")) - 1  # the last draw at or below q
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
    keep = _kept(w)
    return x[keep], w[keep]


def _kept(w):
    """:func:`_weighted_kept`'s mask."""
    return w > 1e-12 * np.max(w)


class PerDrawValues:
    """``fn`` (draws (n, ndim) -> {name: values (n,)}) on rows of a growing array of draws, each row
    computed once: the fast path's top-up adds draws round by round and looks at the quantities of
    every draw of non-negligible weight each time. Only for a function of each draw alone (no grid
    or normalisation shared by the draws, no pairing by position), whose values on some rows are
    those rows of its values on all of them. :meth:`rows` starts again when the draws are not
    those of the last call followed by new ones, or a call returns other names."""

    def __init__(self, fn):
        self.fn = fn
        self._x = None  # the draws of the last call
        self._vals = None  # {name: values on every row of _x, NaN where not computed}
        self._done = np.zeros(0, bool)

    def rows(self, x, keep):
        """{name: values} of ``fn`` on ``x[keep]`` (``keep`` a boolean mask of x's rows)."""
        n, m = x.shape[0], 0 if self._x is None else self._x.shape[0]
        if m and not (x is self._x or (n >= m and np.array_equal(x[:m], self._x))):
            self._vals, self._done, m = None, np.zeros(0, bool), 0
        if n > m:
            self._done = np.concatenate([self._done, np.zeros(n - m, bool)])
            if self._vals is not None:
                self._vals = {k: np.concatenate([v, np.full(n - m, np.nan)]) for k, v in self._vals.items()}
        self._x = x
        idx = np.flatnonzero(keep)
        need = idx[~self._done[idx]]
        if need.size:
            new = {k: v for k, v in self.fn(x[need]).items() if np.size(v) == need.size}
            if self._vals is not None and list(new) != list(self._vals):
                self._vals, self._done = None, np.zeros(n, bool)
                return self.rows(x, keep)  # (once: with nothing computed, every kept row is new)
            if self._vals is None:
                self._vals = {k: np.full(n, np.nan) for k in new}
            for k, v in new.items():
                self._vals[k][need] = v
            self._done[need] = True
        return {k: v[idx] for k, v in (self._vals or {}).items()}


def _on_kept(fn, x, keep, xk):
    """``fn`` of the kept draws ``xk = x[keep]`` (through its cache for a :class:`PerDrawValues`)."""
    return fn.rows(x, keep) if isinstance(fn, PerDrawValues) else fn(xk)


def _end_mcse(model, x, w, n_resampled=None, derived_fn=None):
    """{name: interval-end Monte Carlo error / width} of every physical parameter that varies, for
    weighted draws (and ``n_resampled`` draws resampled from them: :func:`interval_end_mcse`); NaN
    for a parameter whose draws are not all finite (reported as the worst, :func:`_worst_end_mcse`).
    With ``derived_fn`` (draws in ``model``'s coordinates -> {name: values}), the quantities it
    returns too (capacity, TR, ...: what :class:`bayescap.posterior.FitResult` computes from the same
    weighted draws afterwards)."""
    xk, wk, vals = _end_values(model, x, w, derived_fn)
    return {n: interval_end_mcse(v, wk, n_resampled=n_resampled) for n, v in vals.items()}


def _end_values(model, x, w, derived_fn=None, names=None, phys=None):
    """(kept draws, their weights, {name: values on them}) of the quantities :func:`_end_mcse`
    looks at (those that vary); ``names``: only those (the derived quantities computed only when
    one of them is among them). ``phys``: the physical parameters' function of the draws when the
    caller has it (default :func:`_physical_fn` of ``model``); it and ``derived_fn`` may be
    :class:`PerDrawValues`, which compute each draw once over the calls."""
    phys = _physical_fn(model) if phys is None else phys
    if phys is None:
        return x[:0], w[:0], {}
    keep = _kept(w)
    xk, wk = x[keep], w[keep]
    with np.errstate(all="ignore"):
        p = _on_kept(phys, x, keep, xk)
        if derived_fn is not None and (names is None or any(n not in p for n in names)):
            d = _on_kept(derived_fn, x, keep, xk)
            p = {**p, **{n: v for n, v in d.items() if np.size(v) == xk.shape[0]}}
    return xk, wk, {n: v for n, v in p.items() if (names is None or n in names) and _varies(v)}


_END_PROBS = (0.025, 0.975)


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
    width for tol 0.05, conf 0.9); twenty at once need tol/2.8 each (0.018), where a per-end gate
    of 0.035 leaves the worst of ~20 ends ~0.07 off. ``cap`` when ``confidence`` is None or it
    holds there."""
    if confidence is None or cap is None:
        return cap
    s = np.asarray(errs, float)
    s = s[np.isfinite(s)]
    level = float(np.log(confidence))
    if _within_logprob(np.minimum(s, cap), tol) >= level:
        return float(cap)
    lo, hi = 0.0, float(cap)
    for _ in range(40):  # the probability falls as g grows: bisection to ~1e-12 of cap
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
