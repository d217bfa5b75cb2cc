"""Do the CFA channels agree on what their read-out chain shares? A χ² of the channels' values
about their precision-weighted mean, and the K check built on it (:func:`bayescap.colour.cfa_fit.fit_cfa`:
digital per-channel scaling in the RAW, crosstalk or a wrong black level make the conversion gains
disagree)."""

from __future__ import annotations

import numpy as np
from scipy.special import chdtrc

__all__ = ["K_CHECK_P_MIN", "chi2_check", "k_check"]

#: the K check (and each shared parameter's consistency check) fails below this p-value
K_CHECK_P_MIN = 0.01


def chi2_check(mu, sd) -> tuple[float, int, float]:
    """χ² of values ``mu`` (sd ``sd``) about their precision-weighted mean: (χ², dof, p)."""
    sd = np.maximum(sd, 1e-12)
    w = 1.0 / sd**2
    mean = float(np.sum(w * mu) / np.sum(w))
    chi2 = float(np.sum(((mu - mean) / sd) ** 2))
    dof = len(mu) - 1
    # chdtrc: the χ² survival function (scipy.stats.chi2.sf's own), without importing scipy.stats
    # (~0.7 CPU s at the colour command's start, more than a fast channel fit)
    return chi2, dof, float(chdtrc(dof, chi2)) if dof > 0 else 1.0


def k_check(separate: dict, channels) -> dict:
    """The K check (:mod:`bayescap.colour.cfa_fit`'s docstring) from the separate fits' draws
    ``separate[channel][parameter]``."""
    lk = [np.log(separate[c]["conversion_gain_e_per_dn"]) for c in channels]
    chi2, dof, p = chi2_check(np.array([np.median(v) for v in lk]), np.array([np.std(v, ddof=1) for v in lk]))
    k = np.exp([np.median(v) for v in lk])
    return {
        "definition": "chi-square of the channels' log K (separate fits) about their precision-weighted mean, "
        f"{dof} degrees of freedom; passes when p >= {K_CHECK_P_MIN:g}",
        "k_e_per_dn": {c: float(v) for c, v in zip(channels, k)},
        "chi2": chi2,
        "dof": dof,
        "p_value": p,
        "max_ratio": float(k.max() / k.min()),
        "passed": bool(p >= K_CHECK_P_MIN),
    }
