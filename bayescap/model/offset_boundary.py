"""The rounding moments of a population of pixels (:func:`~bayescap.model.pixel_quantization.\
_quantized_pixel_moments`) for small temporal noise (s ≤ 0.1 DN), by quadratures at the DN
boundaries, where the periodic grid needs up to 1 024 points an element.

With s ≪ 1 DN, a pixel at offset o has a rounded value that differs from round(o) only near a DN
boundary b (a half-integer): there it takes two values, the upper with probability p = Φ(u),
u = (o − b)/s, so its variance is v = pq and μ₄ + v² = pq(1 − 2pq) (q = 1 − p). Summed over the
boundaries these are v(o) and e(o) up to the products of two boundaries' tails, below
2Φ(−1/(2s)) ≈ 6e-7 of them for s ≤ :data:`_S_MAX`. Over o ~ N(δ, σ_o²) (the wrapped normal's
images are the boundaries' images), the normal of o times φ(u) is a normal in o:

    N(o; δ, σ_o²) φ(u) = s N(δ − b; 0, τ²) N(o; μ_b, σ_*²),   τ² = s² + σ_o²,
    μ_b − b = (δ − b) s²/τ²,   σ_* = s σ_o/τ,

so E_o[v] = Σ_b s N(δ − b; 0, τ²) E[R(u)] with R = pq/φ(u) = Φ(|u|)·Φ(−|u|)/φ(u) (an entire
function, ~1/|u| far out, evaluated by ``erfcx`` without underflow), u ~ N((δ − b)s/τ², σ_o²/τ²):
Gauss–Hermite nodes (:data:`_GH_FEW`, :data:`_GH_MANY`). V and E4 keep their relative precision however small they are
(the periodic grid's is absolute, ~1e-11 DN²).

H = var_o(m(o)) − σ_o², m(o) = E[round(o + sε)] = Σ_b Φ((o − b)/s) + const: each pair of terms'
covariance is a bivariate normal's, Φ₂(h_b, h_b'; ρ) − Φ(h_b)Φ(h_b') with h_b = (δ − b)/τ and
ρ = σ_o²/τ², and by Plackett's identity (∂Φ₂/∂ρ = φ₂, t = sin θ)

    var_o(m) = (1/2π) ∫₀^{arcsin ρ} Σ_{b,b'} exp(−(h_b − h_b')²/(2cos²θ) − h_b h_b'/(1 + sin θ)) dθ,

a smooth integrand (:data:`_GL_N` Gauss–Legendre nodes), over the boundaries with |h_b| ≤
:data:`_H_ACTIVE` (the others' T_b = Φ((o − b)/s) has variance ≤ Φ(−12): they change var_o(m) by
< 1e-16 DN²). Served for σ_o ≥ :data:`_SO_MIN`, where that is < 1e-7 of σ_o², H's scale. Fits of
8-bit sensors whose read noise is 0.05 DN spent nearly all their time in the periodic grid on these
elements (``benchmarks/subdn_speed.py``).
``tests/test_offset_boundary.py`` checks V, E4, H against the exact evaluation and an independent
quadrature.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfcx

__all__ = ["boundary_moments"]

#: Gauss–Hermite nodes of E[R(u)] (R entire, varying on the scale of 1; u's spread w = σ_o/τ ≤ 1):
#: :data:`_GH_FEW` where the mean u* is ≥ :data:`_FEW_RATIO` w from the boundary (R ~ 1/|u| is then
#: smooth on the nodes' scale), :data:`_GH_MANY` elsewhere. Measured against 64 nodes on 60 000 random
#: (δ, s, σ_o), s 1e-3-0.1, σ_o 1e-4-0.4 DN: relative errors of V ≤ 3.4e-8 and of E4 ≤ 6.1e-6
#: (14 nodes near a boundary: 2.2e-5, 20: 4.8e-7)
_GH_FEW, _GH_MANY = 8, 16
_FEW_RATIO = 6.0
_GH = {}
for _n in (_GH_FEW, _GH_MANY):
    _x, _w = np.polynomial.hermite_e.hermegauss(_n)
    _GH[_n] = (_x, _w / _w.sum())
#: a boundary whose factor N(δ − b; 0, τ²) is below e^{−46} ≈ 1e-20 of the largest one's is left out
#: (its E[R] is at most ~10³ times the largest one's: |u*| ≤ 1/s)
_LOG_NEGLIGIBLE = 46.0
#: served for s ≤ this (DN): two values per boundary, the neglected products of two tails below
#: 2Φ(−5) ≈ 6e-7 of v and e
_S_MAX = 0.1
#: ... and τ = √(s² + σ_o²) ≤ this (DN): the boundaries ±½ … ±9/2 hold every one with |h_b| ≤
#: :data:`_H_ACTIVE` (|δ − b| ≤ 4.8 DN) and with a factor N(δ − b; 0, τ²) within e^{−46} of the largest
_TAU_MAX = 0.4
_B = np.arange(-4.5, 5.0)
#: ... and σ_o ≥ this (DN)
_SO_MIN = 1e-4
#: boundaries with |h_b| = |δ − b|/τ ≤ this enter var_o(m)
_H_ACTIVE = 12.0
#: Gauss–Legendre nodes over θ of var_o(m): measured against 128 nodes on 40 000 random (δ, s, σ_o),
#: s 1e-3-0.1, σ_o 1e-4-0.4 DN, H's relative error ≤ 2.9e-7 (8 nodes: 1.5e-5, 16: 9e-9)
_GL_N = 12
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_GL_N)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W  # on [0, 1]
_PAIR_I, _PAIR_J = np.triu_indices(_B.size)
_SQRT_HALF_PI = np.sqrt(0.5 * np.pi)
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def boundary_moments(delta, s, so):
    """(served, V, E4, H) for 1-D ``delta`` (|δ| ≤ ½), ``s``, ``so`` (DN): ``served`` marks the
    elements this tier evaluates within its bound (module docstring); V, E4, H are NaN elsewhere."""
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    so = np.asarray(so, float)
    V = np.full(delta.shape, np.nan)
    E4 = np.full(delta.shape, np.nan)
    H = np.full(delta.shape, np.nan)
    with np.errstate(all="ignore"):
        tau2 = s * s + so * so
        served = (s > 0.0) & (s <= _S_MAX) & (so >= _SO_MIN) & (tau2 <= _TAU_MAX**2) & (np.abs(delta) <= 0.5)
    at = np.flatnonzero(served)
    if at.size:
        d = delta[at, None] - _B  # (n, boundaries)
        dd = d * d
        V[at], E4[at] = _boundary_v_e4(d, dd, s[at], so[at], tau2[at], np.square(0.5 - np.abs(delta[at])))
        H[at] = _var_of_means(d, dd, tau2[at], so[at]) - so[at] ** 2
    return served, V, E4, H


def _var_of_means(d, dd, tau2, so):
    """var_o(m(o)) of :func:`boundary_moments` by Plackett's identity (module docstring), for the
    offsets ``d`` = δ − b from the boundaries (n, nb) and their squares ``dd``."""
    out = np.zeros(d.shape[0])
    act = dd <= (_H_ACTIVE * _H_ACTIVE) * tau2[:, None]  # |h_b| ≤ 12
    rows = np.flatnonzero(act.any(-1))  # the others: no boundary within reach, var_o(m) = 0
    if rows.size == 0:
        return out
    act, tau2, so = act[rows], tau2[rows], so[rows]
    e, p = np.nonzero(act[:, _PAIR_I] & act[:, _PAIR_J])  # (element, pair), by element
    pi, pj = _PAIR_I[p], _PAIR_J[p]
    r = rows[e]
    inv_tau = 1.0 / np.sqrt(tau2)
    hi, hj = d[r, pi] * inv_tau[e], d[r, pj] * inv_tau[e]
    th1 = np.arcsin(so * so / tau2)
    th = th1[:, None] * _GL_X  # the nodes' θ, per element
    inv_c2 = 0.5 / np.square(np.cos(th))
    inv_1s = 1.0 / (1.0 + np.sin(th))
    dh = hi - hj
    f = np.exp(-(dh * dh)[:, None] * inv_c2[e] - (hi * hj)[:, None] * inv_1s[e])
    val = np.where(pi == pj, 1.0, 2.0) * th1[e] * (f * _GL_W).sum(-1) / (2.0 * np.pi)
    out[rows] = np.bincount(e, weights=val, minlength=rows.size)
    return out


def _boundary_v_e4(d, dd, s, so, tau2, dd_min):
    """V and E4 of :func:`boundary_moments` for the offsets ``d`` = δ − b from the boundaries (n, nb),
    their squares ``dd`` and the nearest one's ``dd_min``, summed over each element's boundaries
    in their order (each element's numbers are its own whatever the others).

    R = Φ(|u|)Φ(−|u|)/φ(u) = Φ(|u|)·M(|u|) with Mills' ratio M(a) = Φ(−a)/φ(a) = √(π/2) erfcx(a/√2),
    and Φ(−|u|) = M(|u|)φ(u): one ``erfcx`` and one exponential a node."""
    n = d.shape[0]
    # the boundaries whose factor N(δ − b; 0, τ²) is within e^{−46} of the nearest one's
    e, b = np.nonzero(dd <= (dd_min + 2.0 * _LOG_NEGLIGIBLE * tau2)[:, None])
    db = d[e, b]
    t2 = tau2[e]
    tau = np.sqrt(t2)
    ustar = db * (s[e] / t2)  # the mean of u about each boundary
    w = so[e] / tau  # its spread
    pref = (s[e] * _INV_SQRT_2PI / tau) * np.exp(-0.5 * db * db / t2)  # s N(δ − b; 0, τ²)
    few = np.abs(ustar) >= _FEW_RATIO * w
    V = np.zeros(n)
    E4 = np.zeros(n)
    for sel, n_nodes in ((few, _GH_FEW), (~few, _GH_MANY)):
        at = np.flatnonzero(sel)
        if at.size == 0:
            continue
        x, wt = _GH[n_nodes]
        a = np.abs(ustar[at, None] + w[at, None] * x)
        mills = _SQRT_HALF_PI * erfcx(a * np.sqrt(0.5))
        q = mills * (_INV_SQRT_2PI * np.exp(-0.5 * a * a))  # Φ(−|u|)
        Rw = ((1.0 - q) * mills) * wt
        rv = Rw.sum(-1)
        V += np.bincount(e[at], weights=pref[at] * rv, minlength=n)
        E4 += np.bincount(e[at], weights=pref[at] * (rv - 2.0 * (Rw * ((1.0 - q) * q)).sum(-1)), minlength=n)
    return V, E4
