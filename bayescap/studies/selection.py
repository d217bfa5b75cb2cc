"""Choosing between nested models by PSIS-LOO (Vehtari, Gelman & Gabry 2017) through ArviZ.

Terms the data cannot inform are left out before any fit (:func:`bayescap.model.select_terms`).
Where two nested models are both identifiable, the choice is made from the posterior: each
variant is fitted, the pointwise log-likelihood of every observation (every variance and mean
row) is evaluated on thinned posterior draws, and PSIS-LOO's expected log predictive density
(elpd) is compared. **Criterion**: the variant with the highest elpd wins, unless a simpler
variant is close to it, in which case the simpler one is kept. "Close" means a difference below
4 (small by the reading of Sivula, Magnusson & Vehtari 2022), or below two standard errors of the
paired difference *provided* the simpler variant has no observation with Pareto k̂ > 0.7: when a
few rows dominate the difference (outliers), the standard error is itself unreliable and the
rows the simpler model cannot predict are exactly the evidence against it. k̂ > 0.7 counts are
reported for every variant.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from bayescap.model import select_terms

__all__ = ["loo", "select_model", "VARIANTS"]

#: nested variants: name -> (changes to the data-driven terms, number of extra terms vs the simplest)
VARIANTS = {
    "gamma_only": (dict(robust=False, discrepancy=False), 0),
    "discrepancy": (dict(robust=False, discrepancy=True), 1),
    "discrepancy+outliers": (dict(robust=True, discrepancy=True), 2),
}


def _idata(ll):
    import arviz as az

    return az.from_dict(log_likelihood={"obs": ll[None, :, :]}, posterior={"_": np.zeros((1, ll.shape[0]))})


def loo(result, n_draws: int = 2000) -> dict:
    """PSIS-LOO of a FitResult: elpd, its standard error, p_loo and the Pareto k̂ counts."""
    import arviz as az

    m = result.model
    D = result.chains.chain.shape[-1]
    th = result.chains.chain.reshape(-1, D)[result.thin_index(n_draws)]
    ll, labels = m.pointwise_loglik(th)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = az.loo(_idata(ll), pointwise=True)
    k = np.asarray(r.pareto_k)
    bad = [f"{labels[i][0]} row {labels[i][1]}" for i in np.nonzero(k > 0.7)[0]]
    return {
        "elpd_loo": float(r.elpd_loo),
        "se": float(r.se),
        "p_loo": float(r.p_loo),
        "n_obs": int(ll.shape[1]),
        "khat_max": float(np.max(k)),
        "n_khat_above_0.7": len(bad),
        "khat_above_0.7": bad,
        "_ll": ll,
    }


def select_model(data, *, seed=None, quality="standard", variants=None, progress=False, **fit_kwargs):
    """Fit the nested variants, compare them by PSIS-LOO and return (chosen FitResult, table).

    The table lists, per variant, elpd_loo, its se, the difference to the best and the se of
    that difference (paired over observations), p_loo, k̂ counts, and which was chosen and why.
    ``fit_kwargs`` (scene, mtf) are passed to :func:`bayescap.fit`.
    """
    from bayescap.api import fit

    base = select_terms(data)
    names = list(variants or VARIANTS)
    results, table = {}, {}
    for name in names:
        change, _ = VARIANTS[name]
        terms = replace(base, **change)
        res = fit(data, seed=seed, quality=quality, terms=terms, progress=progress, **fit_kwargs)
        lo = loo(res)
        # an unconverged variant's elpd is uncertain too: say so with its numbers
        lo["converged"] = bool(res.diag.get("converged", False))
        lo["method"] = res.diag.get("method", "mcmc")
        results[name] = res
        table[name] = lo
    best = max(names, key=lambda n: table[n]["elpd_loo"])
    # paired differences over the same observations
    for n in names:
        d = table[best]["_ll"], table[n]["_ll"]
        if d[0].shape[1] == d[1].shape[1]:
            pw_best = _pointwise_elpd(d[0])
            pw_n = _pointwise_elpd(d[1])
            diff = pw_best - pw_n
            table[n]["elpd_diff"] = float(diff.sum())
            table[n]["se_diff"] = float(np.sqrt(diff.size * diff.var()))
        else:
            table[n]["elpd_diff"] = float(table[best]["elpd_loo"] - table[n]["elpd_loo"])
            table[n]["se_diff"] = float("nan")
    chosen, why = best, "highest elpd_loo"
    for n in sorted(names, key=lambda n: VARIANTS[n][1]):
        if VARIANTS[n][1] >= VARIANTS[best][1]:
            continue
        dd, se = table[n]["elpd_diff"], table[n]["se_diff"]
        if dd < 4 or (dd < 2 * se and table[n]["n_khat_above_0.7"] == 0):
            chosen = n
            why = f"simpler than '{best}' and close to it (Δelpd {dd:.1f} ± {se:.1f})"
            break
    for n in names:
        table[n].pop("_ll")
    summary = {
        "criterion": "PSIS-LOO elpd; a simpler variant is kept when Δelpd < 4, or Δelpd < 2 se "
        "and it has no observation with Pareto k̂ > 0.7",
        "chosen": chosen,
        "why": why,
        "variants": table,
    }
    res = results[chosen]
    res.model_selection = summary
    res.notes.append(
        f"model selection by PSIS-LOO: '{chosen}' ({why}); "
        + ", ".join(f"{n}: elpd {table[n]['elpd_loo']:.1f}" for n in names)
    )
    unconverged = [n for n in names if not table[n]["converged"]]
    summary["unconverged_variants"] = unconverged
    if unconverged:
        res.notes.append(
            "model selection: the fit of "
            + ", ".join(f"'{n}'" for n in unconverged)
            + " did not converge (its R-hat/ESS or fast-path check failed), so its elpd is "
            "uncertain; rerun with --quality accurate to confirm the choice"
        )
    return res, summary


def _pointwise_elpd(ll):
    """PSIS-LOO pointwise elpd for a (n_draws, n_obs) log-likelihood matrix."""
    import arviz as az

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = az.loo(_idata(ll), pointwise=True)
    return np.asarray(r.loo_i)
