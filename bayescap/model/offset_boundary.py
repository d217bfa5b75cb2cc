"""The rounding moments of a population of pixels (:func:`~bayescap.model.pixel_quantization.\
_quantized_pixel_moments`) for small temporal noise, by Gauss–Hermite quadrature at each DN
boundary: the tier for pixels whose means sit far from every boundary.

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

H = var_o(m(o)) − σ_o², m(o) = E[round(o + sε)]: with m(o) = Σ_b ±T_b(o), T_b = Φ(−(|b| −
sign(b)·o)/s) ∈ [0, 1] and E[T_b] = Φ(−|b − δ|/τ), var_o(m) ≤ E[m²] ≤ B = (Σ_b √E[T_b])².
An element is served only where that is negligible: B/2 ≤ :data:`_H_REL`·(σ_o² − B), H = −σ_o² +
B/2 (all pixels round to the same value but for tails; relative error ≤ 1e-5 of |H|). Those
are the elements that made the periodic grid slow: measured in fits of 8-bit sensors whose read
noise is 0.05 DN (``benchmarks/subdn_speed.py``), 87-99.9 % of the grid's work.
``tests/test_offset_boundary.py`` checks V, E4, H against the exact evaluation and an independent
quadrature.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erfcx, ndtr

__all__ = ["boundary_moments"]

#: Gauss–Hermite nodes of E[R(u)] (R entire, varying on the scale of 1; u's spread w = σ_o/τ ≤ 1):
#: :data:`_GH_FEW` where the mean u* is ≥ :data:`_FEW_RATIO` w from the boundary (R ~ 1/|u| is then
#: smooth on the nodes' scale), :data:`_GH_MANY` elsewhere. Measured against 64 nodes on 40 000 random
#: (δ, s, σ_o), s 1e-3-0.1, σ_o 1e-4-0.2 DN: relative errors of V and E4 ≤ 2.3e-7 (8 nodes, |u*| ≥ 6w)
#: and ≤ 4.8e-7 (20 nodes, any u*); 12 and 16 nodes reach 9e-5 and 6e-6 near the boundary
_GH_FEW, _GH_MANY = 8, 20
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
#: ... and τ = √(s² + σ_o²) ≤ this (DN): the boundaries ±½, ±3/2, ±5/2 (the next ones, ≥ 3 DN from
#: δ, have E[T_b] < Φ(−15) and terms below e^{−100} of the nearest one's)
_TAU_MAX = 0.2
_B = np.array([-2.5, -1.5, -0.5, 0.5, 1.5, 2.5])
#: served where H's bound B/2 is below this fraction of σ_o² − B
_H_REL = 1e-5
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
        tau = np.sqrt(tau2)
        d = delta[:, None] - _B  # (n, boundaries)
        B = np.square(np.sqrt(ndtr(-np.abs(d) / tau[:, None])).sum(-1))
        so2 = so * so
        served = (
            (s > 0.0)
            & (s <= _S_MAX)
            & (so > 0.0)
            & (tau <= _TAU_MAX)
            & (np.abs(delta) <= 0.5)
            & (0.5 * B <= _H_REL * (so2 - B))
        )
    at = np.flatnonzero(served)
    if at.size:
        V[at], E4[at] = _boundary_v_e4(d[at], s[at], so[at], tau2[at])
        H[at] = 0.5 * B[at] - so2[at]
    return served, V, E4, H


def _boundary_v_e4(d, s, so, tau2):
    """V and E4 of :func:`boundary_moments` for offsets ``d`` = δ − b from the boundaries (n, nb).

    R = Φ(|u|)Φ(−|u|)/φ(u) = Φ(|u|)·M(|u|) with Mills' ratio M(a) = Φ(−a)/φ(a) = √(π/2) erfcx(a/√2),
    and pq = Φ(|u|)·M(|u|)φ(u): one ``erfcx`` and one exponential a node."""
    tau = np.sqrt(tau2)
    ustar = d * (s / tau2)[:, None]  # the mean of u about each boundary
    w = np.broadcast_to((so / tau)[:, None], d.shape)  # its spread
    lp = -0.5 * d * d / tau2[:, None]
    keep = lp >= lp.max(-1, keepdims=True) - _LOG_NEGLIGIBLE
    few = keep & (np.abs(ustar) >= _FEW_RATIO * w)
    rv = np.zeros(d.shape)
    re = np.zeros(d.shape)
    for mask, n_nodes in ((few, _GH_FEW), (keep & ~few, _GH_MANY)):
        at = np.nonzero(mask)
        if at[0].size == 0:
            continue
        x, wt = _GH[n_nodes]
        a = np.abs(ustar[at][:, None] + w[at][:, None] * x)
        mills = _SQRT_HALF_PI * erfcx(a * np.sqrt(0.5))
        q = mills * (_INV_SQRT_2PI * np.exp(-0.5 * a * a))  # Φ(−|u|)
        R = (1.0 - q) * mills
        rv[at] = (R * wt).sum(-1)
        re[at] = (R * (1.0 - 2.0 * (1.0 - q) * q) * wt).sum(-1)
    pref = (s * _INV_SQRT_2PI / tau)[:, None] * np.exp(lp)  # s N(δ − b; 0, τ²)
    return (pref * rv).sum(-1), (pref * re).sum(-1)
