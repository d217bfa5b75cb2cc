"""The sensor's response and its non-linearity: the output signal S (DN above the dark level) as a
function of the linear signal x (DN, charge/K),

    S = g(x) = x · (1 + a · x / S_ref),

``a`` the fractional deviation from linearity at the reference signal ``S_ref`` (the largest
unclipped measured signal): a < 0 compressive, a > 0 expansive. Shot noise is Poisson in the
charge, so the output variance it causes is g'(x)²·x/K (delta method; g' = 1 + 2a·x/S_ref): the
response bends the photon-transfer curve as well as the mean. Read noise is added after the
conversion and is not bent.

:func:`response_evidence` measures, from the means against ``photons_per_pixel`` alone, whether
the data need the term (:func:`~bayescap.model.terms.select_terms`). Without photon counts,
:func:`variance_curvature_evidence` measures the bend of the temporal photon-transfer curve instead:
to first order in a the shot-noise variance is g'(x)²·x/K ≈ (S/K)·(1 + 3a·S/S_ref), so the PTC's
relative bend at S_ref is 3a. (A variance loss that leaves the means straight, the brighter-fatter
effect, bends it the same way: the variances alone cannot tell the two apart.)
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "NONLINEARITY_BOUNDS",
    "response",
    "response_inverse",
    "response_slope",
    "response_evidence",
    "variance_curvature_evidence",
]

#: hard bounds of ``a``: below −0.25 the response has a maximum inside the measured range (g' = 0
#: at x = S_ref/(−2a) < 2 S_ref) and is no longer invertible there; 0.5 is far beyond any sensor
#: (a 50 % excess of signal at the top)
NONLINEARITY_BOUNDS = (-0.24, 0.5)
#: the term is selected when the curvature of the means against the photons is at least this at the
#: top of the range (fraction) and at least :data:`EVIDENCE_SIGMA` standard errors from zero
EVIDENCE_MIN = 0.003
EVIDENCE_SIGMA = 4.0
#: without photons: the PTC's relative bend at the top (≈ 3a) must be at least this, and at least
#: :data:`VARIANCE_EVIDENCE_SIGMA` standard errors from zero. 2 rather than the means' 4: K and the
#: bend come from the same variances, and a bend left out biases K by about twice as many of K's
#: own standard errors as the bend has (benchmarks/ptc_curvature.py: a bend of ~4 sd, K 7 sd off),
#: while a bend wrongly let in (5 % of linear sensors) only widens K's interval
VARIANCE_EVIDENCE_MIN = 0.005
VARIANCE_EVIDENCE_SIGMA = 2.0


def response(x, a, s_ref):
    """g(x) = x (1 + a x / S_ref)."""
    return x * (1.0 + a * x / s_ref)


def response_slope(x, a, s_ref):
    """g'(x) = 1 + 2 a x / S_ref."""
    return 1.0 + 2.0 * a * x / s_ref


def response_inverse(s, a, s_ref):
    """x with g(x) = s, the root on the increasing branch: 2s / (1 + √(1 + 4as/S_ref)) (no
    cancellation as a → 0). Beyond the maximum of a compressive response (no root) the root of
    the maximum, x = S_ref/(−2a)."""
    disc = np.maximum(1.0 + 4.0 * a * s / s_ref, 0.0)
    return 2.0 * s / (1.0 + np.sqrt(disc))


def response_evidence(signal_dn, photons, weights_rows):
    """Curvature of the means against the photons: fit ``S = b₀ + b₁ μp + b₂ μp²`` (the offset as
    in EMVA 1288's linearity line; relative residuals) over the rows ``weights_rows`` (a boolean mask), and return
    ``(a, se)``: the fractional deviation b₂ μp,top / b₁ at the brightest of those rows and its
    standard error from the residual scatter. ``None`` with fewer than five rows."""
    r = np.asarray(weights_rows, bool) & np.isfinite(photons) & (signal_dn > 0) & (photons > 0)
    if r.sum() < 5:
        return None
    S, mp = signal_dn[r], photons[r]
    top = float(mp[np.argmax(S)])
    u = mp / top
    A = np.vstack([np.ones_like(u), u, u * u]).T / S[:, None]  # relative residuals: rows weighted by 1/S
    y = np.ones_like(S)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ coef
    dof = max(S.size - 3, 1)
    s2 = float(resid @ resid) / dof
    try:
        cov = s2 * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    _, b1, b2 = coef
    if not b1 > 0:
        return None
    a = b2 / b1
    # delta method for the ratio
    g = np.array([0.0, -b2 / b1**2, 1.0 / b1])
    se = float(np.sqrt(max(g @ cov @ g, 0.0)))
    return float(a), se


def variance_curvature_evidence(signal_dn, var_dn2, dark_var_dn2, n_pixels, rows):
    """Bend of the temporal PTC: fit the shot-noise variance ``V − V_dark = c₁ S + c₂ S²`` over the
    rows ``rows`` (a boolean mask), through zero (each row's dark variance carries its read noise,
    dark shot noise and rounding, as in the model), each row weighted by its sampling error (a pair
    variance over n pixels has relative sd √(2/(n−1)); the dark row's error adds), and return
    ``(bend, se)``: the relative bend c₂ S_top / c₁ at the brightest of those rows and its standard
    error. The error is scaled up by √(χ²/dof) when the rows scatter beyond their sampling error
    (never down). ``None`` with fewer than five rows or a non-increasing PTC."""
    S = np.asarray(signal_dn, float)
    V = np.asarray(var_dn2, float)
    Vd = np.asarray(dark_var_dn2, float)
    nu = np.maximum(np.asarray(n_pixels, float) - 1.0, 1.0)
    r = np.asarray(rows, bool) & np.isfinite(S) & np.isfinite(V) & np.isfinite(Vd) & (S > 0)
    if r.sum() < 5:
        return None
    S, y, nu = S[r], V[r] - Vd[r], nu[r]
    sd = np.sqrt(2.0 * (V[r] ** 2 + Vd[r] ** 2) / nu)
    u = S / float(S.max())
    A = np.vstack([u, u * u]).T / sd[:, None]
    b = y / sd
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    resid = b - A @ coef
    chi2_dof = float(resid @ resid) / max(S.size - 2, 1)
    try:
        cov = max(chi2_dof, 1.0) * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    c1, c2 = coef
    if not c1 > 0:
        return None
    g = np.array([-c2 / c1**2, 1.0 / c1])
    return float(c2 / c1), float(np.sqrt(max(g @ cov @ g, 0.0)))
