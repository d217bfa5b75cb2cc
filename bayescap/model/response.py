"""The sensor's response and its non-linearity, and the brighter-fatter loss of variance.

**Response.** The output signal S (DN above the dark level) is a monotone smooth function of the
linear signal x = charge/K (DN). The model writes its inverse, the *linearisation* x = h(S), as

    h(S) = S_ref ∫₀^{S/S_ref} exp(L(u)) du,   L(u) = Σ_{k=1..m} θ_k B_{k,m}(u),

with B_{k,m} the Bernstein polynomials of degree m (:data:`N_BASIS`) on [0, 1] without B_{0,m}, or
(:data:`RICH_BASIS` coefficients, when the data show a knee or a kink) the quadratic B-splines on
:data:`SPLINE_INTERVALS` intervals (knots crowding towards the clip) without the first (either way L(0) = 0: h'(0) = 1, and
K stays the small-signal gain), ``S_ref`` the largest unclipped
measured signal. h' = exp(L) > 0, so the response is monotone whatever the coefficients; beyond
S_ref the slope is held at its value there (the clip level lies a little above). The integral
is a fixed Gauss–Legendre quadrature, vectorised over draws and rows. All θ = 0 is the linear
response; a quadratic, cubic or quartic compression, an S shape (expansive low, compressive
high) and a soft knee are all smooth log-slopes of low degree. The prior (docs/model.md) shrinks
θ towards 0.

Writing the inverse keeps the model free of root finding where it matters: a row's measured mean
S gives its linear signal x = h(S) and the slope g'(x) = 1/h'(S) directly. Shot noise is Poisson
in the charge, so the output variance it causes is g'(x)²·x/K = h(S)/(h'(S)²·K) (delta method).
The means against the photons need g(x) = h⁻¹(x): :func:`response_forward` (Newton from the
measured mean, two steps, or from x for a grid).

**Brighter-fatter.** Charge already collected repels further charge into the neighbours: the
pixel's variance grows less than its mean (Astier et al. 2019, PASP 131, Eq. 16; LSST cp_pipe's
"EXPAPPROXIMATION"): C₀₀ = (exp(2a₀₀μ) − 1)/(2a₀₀) e⁻² at a mean charge μ (e⁻), a₀₀ < 0 per
electron. The model samples the dimensionless ``b = a₀₀·K·S_ref`` (the bend at the top) and
multiplies the shot variance by expm1(z)/z, z = 2b·x/S_ref. It leaves the means straight: only
the means against photon counts tell it apart from a response that bends both.

:func:`response_evidence` measures from the means against ``photons_per_pixel`` whether the data
need the response (:func:`~bayescap.model.terms.select_terms`); :func:`variance_curvature_evidence`
measures the bend of the temporal photon-transfer curve (to first order the shot-noise variance
is (S/K)(1 + 3a·S/S_ref) for a quadratic response of deviation a, and (S/K)(1 + b·S/S_ref) for
brighter-fatter: the variances alone cannot tell the two apart).

:func:`response` / :func:`response_inverse` are the one-parameter quadratic S = x(1 + a·x/S_ref)
(kept for callers that describe a response by its deviation a at S_ref).
"""

from __future__ import annotations

import numpy as np

from bayescap.model.response_spline import RICH_BASIS, h_table_spline, is_spline, spline_basis

__all__ = [
    "N_BASIS",
    "RICH_BASIS",
    "PROXY_DEGREE",
    "SHAPE_BOUND",
    "BF_BOUND",
    "log_slope",
    "linearise",
    "response_forward",
    "deviation_at_ref",
    "linearity_error_shape",
    "shape_draws",
    "bf_factor",
    "shape_start",
    "response_shape_evidence",
    "response_degree_evidence",
    "response",
    "response_inverse",
    "response_evidence",
    "variance_curvature_evidence",
]

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
#: with photons, the brighter-fatter term enters on a variance loss (a bend below zero) at least this
#: many standard errors deep: K is pinned by the means as well, so a false term costs K's accuracy
#: (a 2.4-sd upward bend on a linear zoo sensor moved K 1.3 % off with the term in)
BF_EVIDENCE_SIGMA = 3.0


#: degree of the Bernstein basis of the log-slope (coefficients θ₁..θ_m)
N_BASIS = 4
#: the degree of the richer polynomial :func:`response_degree_evidence` tests the degree-4 shape against
PROXY_DEGREE = 8
#: ... chosen on an F-test of the two degrees' smooth fits at this p-value (strong evidence: a richer
#: shape costs K's precision without photon counts, and sampling time)
RICH_P_VALUE = 1e-3
#: a wall on every |θ_k| (far beyond the prior's bulk: a slope ratio e^±8)
SHAPE_BOUND = 8.0
#: a wall on |b| = |a₀₀·K·S_ref| (the brighter-fatter bend at the top): e^{2b} spans 0.02–50
BF_BOUND = 2.0
#: intervals of the per-draw table of h(S) = ∫₀^S exp(L): the integral on each interval by the
#: end-corrected trapezoid (exact to h⁵·f⁗), between nodes the cubic Hermite interpolant of h and
#: h' = exp(L) (error ~h⁴·f‴/384: relative 1e-9 at |θ| ~ 1, the prior's scale; at |θ| ~ 3 about 3e-5,
#: no worse than 12-node Gauss–Legendre per point, which costs ~7× more on 60 rows)
N_TABLE = 128
#: Gauss–Legendre nodes of ∫₀^v exp(L) per point, for one point per draw (a table costs N_TABLE
#: evaluations per draw): relative error < 1e-9 with 12 nodes at |θ| ~ 1
_GL_T, _GL_W = np.polynomial.legendre.leggauss(12)
_GL_T = 0.5 * (_GL_T + 1.0)
_GL_W = 0.5 * _GL_W


def _bernstein_to_power(m):
    """The matrix T (m, m) with c = θ T: the power-basis coefficients c_j of u^j (j = 1..m) of
    Σ_k θ_k B_{k,m}(u) (k = 1..m). B_{k,m}(u) = C(m,k) Σ_{j≥k} C(m−k, j−k) (−1)^{j−k} u^j."""
    from math import comb

    T = np.zeros((m, m))
    for k in range(1, m + 1):
        for j in range(k, m + 1):
            T[k - 1, j - 1] = comb(m, k) * comb(m - k, j - k) * (-1) ** (j - k)
    return T


_POWER = {N_BASIS: _bernstein_to_power(N_BASIS)}


def log_slope(u, theta):
    """L(u) = Σ_k θ_k B_k(u) (k = 1..m), u clipped to [0, 1]: the Bernstein polynomials B_{k,m}, or
    for m = :data:`RICH_BASIS` the quadratic B-splines. ``theta`` (n, m); ``u`` with a leading axis
    of n draws (or 1), any trailing axes: returns u's broadcast shape. (Horner's scheme in the
    power basis.)"""
    theta = np.atleast_2d(np.asarray(theta, float))
    m = theta.shape[1]
    if is_spline(m):
        u = np.asarray(u, float)
        B = spline_basis(u)  # u.shape + (m,)
        th = theta.reshape((theta.shape[0],) + (1,) * (u.ndim - 1) + (m,)) if u.ndim else theta[0]
        return np.sum(B * th, axis=-1)
    c = _power_coefficients(theta)  # (n, m): coefficients of u, u², ..., u^m
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    extra = (1,) * (u.ndim - 1)
    L = c[:, m - 1].reshape((-1,) + extra) * u
    for j in range(m - 2, -1, -1):
        L += c[:, j].reshape((-1,) + extra)
        L *= u
    return L


def _power_coefficients(theta):
    """c (n, m): L(u) = Σ_j c_j u^j (j = 1..m) for the Bernstein coefficients ``theta`` (n, m)."""
    m = theta.shape[1]
    T = _POWER.get(m)
    if T is None:
        T = _POWER.setdefault(m, _bernstein_to_power(m))
    return theta @ T


def _h_table(theta, n_table=N_TABLE):
    """Per draw, on u = 0, 1/K, ..., 1 (K = ``n_table``): h(u) = ∫₀^u exp(L), and exp(L)/K and
    (exp(L))'/K, the Hermite data in units of one interval. Each (n, K + 1)."""
    if is_spline(theta.shape[1]):
        return h_table_spline(theta, n_table)
    c = _power_coefficients(theta)
    n, m = c.shape
    g = _TABLE_NODES.get(n_table)
    if g is None:  # (the nodes of each table size, once)
        g = np.linspace(0.0, 1.0, n_table + 1)
        g.setflags(write=False)
        g = _TABLE_NODES.setdefault(n_table, g)
    h = 1.0 / n_table
    H, f, fp = np.empty((n, n_table + 1)), np.empty((n, n_table + 1)), np.empty((n, n_table + 1))
    H[:, 0] = 0.0
    seg, tmp = np.empty((min(n, _H_BLOCK), n_table)), np.empty((min(n, _H_BLOCK), n_table))
    # in blocks of draws that stay in cache, in place (3× faster on 6 000 draws than whole-array
    # temporaries); the same operations in the same order as written out whole, bit for bit
    for a in range(0, n, _H_BLOCK):
        b = min(a + _H_BLOCK, n)
        cb, L, dL, s, t = c[a:b], f[a:b], fp[a:b], seg[: b - a], tmp[: b - a]
        # Horner's scheme, element by element (a BLAS product's rounding would depend on how many
        # draws come together, and a stacked fit must give each sensor its own numbers bit for bit)
        np.multiply(cb[:, m - 1 : m], g, out=L)  # L = Σ cᵢ u^(i+1)
        dL[...] = m * cb[:, m - 1 : m]  # L' = Σ (i+1) cᵢ u^i
        for i in range(m - 2, -1, -1):
            L += cb[:, i : i + 1]
            L *= g
            dL *= g
            dL += (i + 1) * cb[:, i : i + 1]
        np.exp(L, out=L)  # f = exp(L)
        dL *= L  # f' = f·L'
        np.add(L[:, :-1], L[:, 1:], out=s)  # the end-corrected trapezoid on each interval
        s *= 0.5 * h
        np.subtract(dL[:, :-1], dL[:, 1:], out=t)
        t *= h * h / 12.0
        s += t
        np.cumsum(s, axis=1, out=H[a:b, 1:])
        L *= h
        dL *= h
    return H, f, fp


#: draws per block of :func:`_h_table`
_H_BLOCK = 256
#: :func:`_h_table`'s nodes u = 0, 1/K, ..., 1 by table size K
_TABLE_NODES = {}


def _linearise_points(v, theta, s_ref):
    """:func:`linearise` point by point (Gauss–Legendre), for draws with few points."""
    vc = np.clip(v, 0.0, 1.0)
    integral = vc * np.sum(np.exp(log_slope(vc[..., None] * _GL_T, theta)) * _GL_W, axis=-1)
    slope = np.exp(log_slope(vc, theta))
    top = np.exp(log_slope(np.ones((1,) * np.ndim(v)), theta))
    x = s_ref * (integral + np.maximum(v - 1.0, 0.0) * top + np.minimum(v, 0.0))
    return x, np.where(v < 0.0, 1.0, slope)


def linearise(s, theta, s_ref, per_point=False, table=None):
    """The linear signal x = h(S) (DN) and the slope h'(S) for measured signals ``s`` (DN; leading
    axis of draws or 1) and shape coefficients ``theta`` (n, m): below 0 the slope is 1, above
    S_ref it stays at its value there. (Cubic Hermite interpolation of h and of exp(L) in a per-draw
    table of :data:`N_TABLE` intervals: errors far below the means' and variances' precision;
    ``per_point=True`` integrates at each point instead, cheaper for one or two points per draw.
    The choice is the caller's, never the array's size: a stacked fit must give each sensor its
    own numbers bit for bit. ``table``: :func:`_h_table` of ``theta`` when the caller has it.)"""
    s = np.asarray(s, float)
    v = s / s_ref
    theta = np.atleast_2d(np.asarray(theta, float))
    n = theta.shape[0]
    shape = np.broadcast_shapes(v.shape, (n,) + (1,) * (v.ndim - 1)) if v.ndim else (n,)
    if per_point and not is_spline(theta.shape[1]):  # (Gauss–Legendre is not exact across a spline's knots)
        return _linearise_points(v, theta, s_ref)
    H, fh, fph = _h_table(theta) if table is None else table
    k = H.shape[1] - 1
    vb = np.broadcast_to(v, shape)
    j, a, a1, b0, b1 = _hermite_weights(vb.reshape(shape[0], -1), k)
    if n > 1:
        j += (np.arange(n) * (k + 1))[:, None]
    H, fh, fph = H.ravel(), fh.ravel(), fph.ravel()
    j1 = j + 1
    f0, f1 = fh[j], fh[j1]  # (each gathered once)
    integral = a1 * H[j] - a * H[j1] + b0 * f0 + b1 * f1
    slope = (a1 * f0 - a * f1) * k + b0 * fph[j] + b1 * fph[j1]
    integral, slope = integral.reshape(shape), slope.reshape(shape)
    top = (fh[(np.arange(n) + 1) * (k + 1) - 1] * k).reshape((n,) + (1,) * (len(shape) - 1))
    x = s_ref * (integral + np.maximum(vb - 1.0, 0.0) * top + np.minimum(vb, 0.0))
    slope = np.where(vb < 0.0, 1.0, slope)
    return x, slope


def _hermite_weights(v, k):
    """The interval ``j`` of the table of ``k`` intervals each of ``v`` (S/S_ref) falls in, and the
    cubic Hermite basis at its position t within it: (j, a, 1 + a, b0, b1) with h00 = 1 + a,
    h01 = −a, h10 = b0 = t³ − 2t² + t, h11 = b1 = t³ − t² (:func:`linearise`)."""
    t = np.clip(v, 0.0, 1.0) * k
    j = np.minimum(t.astype(np.intp), k - 1)
    t -= j
    t2 = t * t
    t3 = t2 * t
    a = 2.0 * t3 - 3.0 * t2
    b0, b1 = t3 - 2.0 * t2 + t, t3 - t2
    return j, a, 1.0 + a, b0, b1


def linearise_weights(s, s_ref, n_table=N_TABLE):
    """What :func:`linearise` computes from the signals alone, for signals ``s`` (DN, 1-D) that are
    the same for every draw (a model's measured signals): pass it as ``weights`` to
    :func:`linearise_at`."""
    v = np.asarray(s, float) / s_ref
    j, a, a1, b0, b1 = _hermite_weights(v, n_table)
    return dict(
        j=j, j1=j + 1, a=a, a1=a1, b0=b0, b1=b1, over=np.maximum(v - 1.0, 0.0), under=np.minimum(v, 0.0), neg=v < 0.0
    )


def linearise_at(weights, table, s_ref):
    """:func:`linearise` of the signals of :func:`linearise_weights` for every draw of ``table``
    (:func:`_h_table`): (n, rows) each, the same numbers bit for bit (the same operations on the
    same values; the weights are not recomputed for every draw and every call)."""
    H, fh, fph = table
    k = H.shape[1] - 1
    w = weights
    j, j1, a, a1, b0, b1 = w["j"], w["j1"], w["a"], w["a1"], w["b0"], w["b1"]
    f0, f1 = fh.take(j, axis=1), fh.take(j1, axis=1)
    integral = a1 * H.take(j, axis=1) - a * H.take(j1, axis=1) + b0 * f0 + b1 * f1
    slope = (a1 * f0 - a * f1) * k + b0 * fph.take(j, axis=1) + b1 * fph.take(j1, axis=1)
    top = fh[:, k : k + 1] * k
    x = s_ref * (integral + w["over"] * top + w["under"])
    if w["neg"].any():
        slope = np.where(w["neg"], 1.0, slope)
    return x, slope


def response_forward(x, theta, s_ref, s0=None, steps=None):
    """S = g(x) = h⁻¹(x) (DN) by Newton's method from ``s0`` (default x; ``steps`` default 2 from
    a given s0, 30 from x). h is increasing with a bounded positive slope: each step lands on the
    tangent's root, clamped to stay within a factor of the previous iterate."""
    x = np.asarray(x, float)
    s = np.array(x if s0 is None else s0, float)
    n = (30 if s0 is None else 2) if steps is None else steps
    for _ in range(n):
        h, dh = linearise(s, theta, s_ref)
        step = (h - x) / dh
        if s0 is None:  # from afar: at most half the way to zero or twice the iterate per step
            lim = 0.5 * np.abs(s) + 1e-9 * s_ref
            step = np.clip(step, -lim, lim)
        s = s - step
    return s


def deviation_at_ref(theta, s_ref):
    """The response's fractional deviation from linearity at S_ref, per draw: S_ref/h(S_ref) − 1
    (the quadratic's ``a``; negative compressive)."""
    theta = np.atleast_2d(np.asarray(theta, float))
    x, _ = linearise(np.full((theta.shape[0], 1), s_ref), theta, s_ref, per_point=True)
    return s_ref / x[:, 0] - 1.0


def linearity_error_shape(theta, s_ref):
    """EMVA 1288's LE (%) of the fitted response per draw
    (:func:`~bayescap.physics.linearity.linearity_error_percent`) over 5–95 % of the linear signal
    at S_ref, h(S_ref), the response g = h⁻¹ by Newton's method on the standard's grid."""
    from bayescap.physics.linearity import linearity_error_percent

    theta = np.atleast_2d(np.asarray(theta, float))
    out = []
    for i in range(0, theta.shape[0], 2048):  # in blocks that stay in cache (2× faster on 20 000 draws)
        th = theta[i : i + 2048]
        x_sat, _ = linearise(np.full((th.shape[0], 1), s_ref), th, s_ref, per_point=True)
        out.append(linearity_error_percent(lambda x, th=th: _forward_table(x, th, s_ref), x_sat[:, 0], n_points=32))
    return np.concatenate(out) if out else np.zeros(0)


def _forward_table(x, theta, s_ref):
    """g(x) = h⁻¹(x) for x (n, k) in [0, h(S_ref)] per draw, from the same Hermite table as
    :func:`linearise`: the interval by one sorted search over all draws (each draw's table offset by
    twice its index after scaling to [0, 1]), then Newton's method on the interval's cubic."""
    theta = np.atleast_2d(np.asarray(theta, float))
    n = theta.shape[0]
    H, fh, _ = _h_table(theta)
    k = H.shape[1] - 1
    top = H[:, -1:]
    off = 2.0 * np.arange(n)[:, None]
    y = np.clip(np.asarray(x, float) / s_ref, 0.0, top)
    table = (H / top + off).ravel()
    j = np.searchsorted(table, (y / top + off).ravel(), side="right").reshape(y.shape) - 1
    j = np.clip(j - (np.arange(n) * (k + 1))[:, None], 0, k - 1) + (np.arange(n) * (k + 1))[:, None]
    H, fh = H.ravel(), fh.ravel()
    H0, H1, f0, f1 = H[j], H[j + 1], fh[j], fh[j + 1]
    t = np.clip((y - H0) / np.where(H1 > H0, H1 - H0, 1.0), 0.0, 1.0)
    for _ in range(4):
        t2 = t * t
        t3 = t2 * t
        a = 2.0 * t3 - 3.0 * t2
        val = (1.0 + a) * H0 - a * H1 + (t3 - 2.0 * t2 + t) * f0 + (t3 - t2) * f1
        der = (6.0 * t2 - 6.0 * t) * (H0 - H1) + (3.0 * t2 - 4.0 * t + 1.0) * f0 + (3.0 * t2 - 2.0 * t) * f1
        t = np.clip(t - (val - y) / np.maximum(der, 1e-300), 0.0, 1.0)
    return s_ref * ((j % (k + 1)) + t) / k


def shape_draws(p):
    """θ (n, m) from the physical draws ``p`` (``response_shape_1`` ...), None without them."""
    if "response_shape_1" not in p:
        return None
    m = sum(1 for k in p if k.startswith("response_shape_"))
    return np.column_stack([np.asarray(p[f"response_shape_{k}"], float) for k in range(1, m + 1)])


def bf_factor(z):
    """expm1(z)/z, the brighter-fatter factor of the shot variance (1 at z = 0)."""
    z = np.asarray(z, float)
    small = np.abs(z) < 1e-6
    if not small.any():  # (the usual case: the same numbers without the two selections)
        return np.expm1(z) / z
    zs = np.where(small, 1.0, z)
    return np.where(small, 1.0 + 0.5 * z, np.expm1(zs) / zs)


def shape_start(signal_dn, photons, rows, s_ref, m=N_BASIS):
    """Start values of θ and the responsivity c = QE/K (DN per photon, small signal) from the
    means against the photons: log(Δμp/ΔS) between neighbouring rows is log(1/c) + L(u) at their
    mid-signal, a linear least-squares problem. None with fewer than m + 3 rows."""
    r = np.asarray(rows, bool) & np.isfinite(photons) & (signal_dn > 0) & (photons > 0)
    if r.sum() < m + 3:
        return None
    S, mp = signal_dn[r], photons[r]
    o = np.argsort(S)
    S, mp = S[o], mp[o]
    dS, dp = np.diff(S), np.diff(mp)
    ok = (dS > 0) & (dp > 0)
    if ok.sum() < m + 2:
        return None
    um = 0.5 * (S[1:] + S[:-1])[ok] / s_ref
    y = np.log(dp[ok] / dS[ok])
    B = log_slope(um[None, :, None], np.eye(m))  # (m, rows, 1) basis values
    A = np.column_stack([np.ones(um.size)] + [B[k, :, 0] for k in range(m)])
    w = np.sqrt(dS[ok] / dS[ok].max())  # wider steps: less relative noise
    coef, *_ = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)
    theta = np.clip(coef[1:], -0.5 * SHAPE_BOUND, 0.5 * SHAPE_BOUND)
    return theta, float(np.exp(-coef[0]))


def response_shape_evidence(signal_dn, photons, rows):
    """Any smooth bend of the means against the photons: a cubic ``S = b₀ + b₁u + b₂u² + b₃u³``
    (u = μp/μp,top; relative residuals as in EMVA 1288's linearity fit) against the straight line,
    over the rows ``rows``. Returns ``(dev, chi2)``: the largest fractional deviation of the cubic
    from its own straight part over the rows' range, |b₂u + b₃u²|/b₁, and the Wald χ² (2 degrees of
    freedom) of (b₂, b₃) from the residual scatter. None with fewer than six rows."""
    r = np.asarray(rows, bool) & np.isfinite(photons) & (signal_dn > 0) & (photons > 0)
    if r.sum() < 6:
        return None
    S, mp = signal_dn[r], photons[r]
    u = mp / float(mp.max())
    A = np.vstack([np.ones_like(u), u, u * u, u**3]).T / S[:, None]
    try:
        coef, *_ = np.linalg.lstsq(A, np.ones_like(S), rcond=None)
    except np.linalg.LinAlgError:
        return None
    resid = 1.0 - A @ coef
    s2 = float(resid @ resid) / max(S.size - 4, 1)
    try:
        cov = s2 * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    b = coef[2:]
    if not coef[1] > 0:
        return None
    try:
        chi2 = float(b @ np.linalg.solve(cov[2:, 2:], b))
    except np.linalg.LinAlgError:
        return None
    ug = np.linspace(u.min(), 1.0, 64)
    dev = float(np.max(np.abs(b[0] * ug + b[1] * ug * ug)) / coef[1])
    return dev, chi2


def response_degree_evidence(u, y, sd, rows, lo=N_BASIS, hi=PROXY_DEGREE, sd_known=False):
    """Whether a shape needs the richer (spline) log-slope: smooth fits of ``y`` against ``u`` (a
    Chebyshev series of degree ``lo + 1`` and ``hi + 1``, the polynomial a log-slope of degree m
    bends a curve into to first order) over the rows ``rows``, each weighted by ``1/sd``, compared
    by the F-test of the nested fits. With photon counts ``u`` are the photons and ``y`` the signals
    (``sd`` the signals: relative residuals, as in EMVA 1288's linearity fit); without them ``u`` the
    signals and ``y`` the shot variances (``sd`` their sampling errors). With ``sd_known`` (the
    variances' sampling errors are errors, not only weights) the p-value is the smaller of the
    F-test's and the χ² test of the degree-``lo + 1`` fit's own residuals: a step in the PTC's slope
    (a two-slope ADC) leaves both polynomials far off, so the F-test between them says little, while
    the low one's χ² per degree of freedom is tens (a smooth shape's about 1). Returns ``(p_value,
    n_rows)``, None with too few rows for the richer fit to leave four degrees of freedom."""
    from scipy.special import chdtrc, fdtrc

    u, y, sd = (np.asarray(a, float) for a in (u, y, sd))
    r = np.asarray(rows, bool) & np.isfinite(u) & np.isfinite(y) & np.isfinite(sd) & (sd > 0)
    n, p_lo, p_hi = int(r.sum()), lo + 2, hi + 2
    if n < p_hi + 4:
        return None
    x = 2.0 * (u[r] - u[r].min()) / max(float(np.ptp(u[r])), 1e-300) - 1.0
    V = np.polynomial.chebyshev.chebvander(x, hi + 1) / sd[r][:, None]
    b = y[r] / sd[r]
    rss = []
    for p in (p_lo, p_hi):
        coef, *_ = np.linalg.lstsq(V[:, :p], b, rcond=None)
        res = b - V[:, :p] @ coef
        rss.append(float(res @ res))
    if not rss[1] > 0:
        return (0.0 if rss[0] > 0 else 1.0), n
    F = ((rss[0] - rss[1]) / (p_hi - p_lo)) / (rss[1] / (n - p_hi))
    p = float(fdtrc(p_hi - p_lo, n - p_hi, max(F, 0.0)))
    if sd_known:
        p = min(p, float(chdtrc(n - p_lo, rss[0])))
    return p, n


def response(x, a, s_ref):
    """g(x) = x (1 + a x / S_ref)."""
    return x * (1.0 + a * x / s_ref)


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
    keep = sd > 0  # (rows of zero variance, bright and dark: noise far below a DN, no weight to give)
    if keep.sum() < 5:
        return None
    S, y, sd = S[keep], y[keep], sd[keep]
    u = S / float(S.max())
    A = np.vstack([u, u * u]).T / sd[:, None]
    b = y / sd
    try:
        coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    except np.linalg.LinAlgError:
        return None
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
