"""The fast path's mixture of proposals: adaptive moment-matching rounds and added components,
each draw weighted against the whole mixture (the balance heuristic), with every proposal's
density on every batch of draws computed once."""

from __future__ import annotations

import numpy as np

from bayescap.inference.importance import _moment_matched, _t_logpdf, psis_weights, student_t_draws


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
            hit = self._d[key] = (f, xb, f(xb))  # f and xb kept alive: their ids stay theirs
        return hit[2]

    def put(self, f, xb, values):
        self._d[(id(f), id(xb))] = (f, xb, values)

    def fill(self, fs, batches):
        """Every density of ``fs`` on every batch of ``batches``, each density evaluated once on the
        batches it has not seen, stacked (a top-up round of m new proposals over K old ones on B
        batches takes K + m calls instead of K·m + m·B)."""
        for f in fs:
            todo = [xb for xb in batches if (id(f), id(xb)) not in self._d]
            if not todo:
                continue
            vals = f(todo[0] if len(todo) == 1 else np.vstack(todo))
            at = 0
            for xb in todo:
                self.put(f, xb, vals[at : at + len(xb)])
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
    dens = [[cache.get(f, xb) for xb in xs] for f in pdfs]  # dens[k][b]: proposal k on batch b
    moments = []  # (location, scale) of each new t proposal

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
        for k, f in enumerate(pdfs):  # the earlier proposals on the new batch
            dens[k].append(cache.get(f, xr))
        t_new = _t_logpdf(mu, c, nu)
        cache.put(t_new, xr, lq_own)
        cache.fill([t_new], xs)
        dens.append([cache.get(t_new, xb) for xb in xs] + [lq_own])  # the new one on all
        pdfs.append(t_new)
        moments.append((mu, c))
        counts.append(n_r)
        xs.append(xr)
        lps.append(lpr)
    comps_out = [
        (pdfs[k], xs[k], lps[k], comps[k][3] if k < len(comps) else moments[k - len(comps)]) for k in range(len(xs))
    ]
    return np.vstack(xs), np.concatenate(lps), mix_logq(), comps_out


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
        out.append((f, xr, lpb[at[k] : at[k + 1]], (mu, c)))
    allx = xs + new_x
    allpdf = pdfs + new_pdf
    counts = counts + [len(xr) for xr in new_x]
    n_all = float(sum(counts))
    x = np.vstack(allx)
    for f, xr, lq in zip(new_pdf, new_x, new_lq):
        cache.put(f, xr, lq)
    cache.fill(allpdf, allx)
    terms = np.stack(
        [np.log(n / n_all) + np.concatenate([cache.get(f, xb) for xb in allx]) for f, n in zip(allpdf, counts)]
    )
    top = np.max(terms, axis=0)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(under="ignore", divide="ignore", invalid="ignore"):
        logq = top + np.log(np.sum(np.exp(terms - top), axis=0))
    return x, np.concatenate(lps + [lpb]), logq, out
