"""Rounding to integer DN: the mean, variance and 4th moment of a rounded normal
round(N(δ, s²)) (:func:`_rounded_normal_moments`: Fourier series, or direct sums for tiny s),
and the offset δ whose rounded normal has a measured mean (:func:`_rounded_offset`).

The averages of these moments over a population of pixels whose means are spread are in
:mod:`bayescap.model.pixel_quantization`.
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr, ndtri

#: midpoint grids over a pixel mean's offset within one DN, by size (the sizes and their use are
#: :mod:`bayescap.model.pixel_quantization`'s); :func:`_rounded_normal_moments_fourier` caches the
#: harmonics of each grid it is given
_QG_SIZES = (8, 16, 32, 64, 128, 256, 512, 1024)
_QG_GRIDS = {M: (np.arange(M) + 0.5) / M - 0.5 for M in _QG_SIZES}
_QG_HARMONICS = {}  # (M, K) -> (sin, cos) of 2πk·x on grid M, k = 1..K (_rounded_normal_moments_fourier)


#: from this s (DN) up, :func:`_rounded_normal_moments` uses the Fourier series of
#: :func:`_rounded_normal_moments_fourier` (harmonics 1-4; the 5th is e^{−50π²s²} < 1e-19), as
#: :func:`_rounded_offset` does from :data:`_RO_FOURIER_S`
_RN_FOURIER_S = 0.3
#: below it, more harmonics: K from s ≥ 1.5/(K + 1) (the first one left out, ω = 2π(K + 1), has
#: (ωs)² e^{−(ωs)²/2} < 1e-17 relative to s⁴, as the 5th at s = 0.3); below the last, the sums
_RN_FOURIER_K = ((0.3, 4), (1.5 / 9, 8), (1.5 / 17, 16), (1.5 / 33, 32))


def _small_unique(a):
    """``np.unique`` of an array of small non-negative integers (harmonic counts, grid sizes), by
    ``np.bincount``: ~10× faster on the 2 000-80 000 elements of a ``log_prob`` call (np.unique's
    hashing was 1.5-2 % of a sub-half-DN sensor's fit)."""
    return np.flatnonzero(np.bincount(np.asarray(a).ravel()))


def _rn_harmonics(s):
    """Harmonics the Fourier series of :func:`_rounded_normal_moments` needs at ``s`` (0: the direct
    sums), elementwise (NaN: 0)."""
    k = np.zeros(np.shape(s), dtype=np.intp)
    for s_min, K in reversed(_RN_FOURIER_K):
        k[s >= s_min] = K
    return k


def _rounded_normal_moments(delta, s, J=6):
    """Mean, variance and central 4th moment of round(N(δ, s²)) (δ relative to an integer DN).

    Where s ≥ 1.5/33 ≈ 0.045 DN: the Fourier series of :func:`_rounded_normal_moments_fourier`,
    with 4 harmonics from s = 0.3 DN, 8, 16 or 32 below (:data:`_RN_FOURIER_K`); below 0.045 DN,
    direct sums over the integers j = −J..J with J at most 2 (the DN boundaries beyond ±3/2 are ≥ 11 s
    away for |δ| ≤ 1; ``J`` matters only for :func:`_rounded_normal_moments_sums` called directly).
    With the sums, these moments and the offset solver took most of a fast fit of a 12-bit sensor
    whose dark noise is half a DN (sim05 of ``benchmarks/speed_accuracy.py``); the sums on the
    32-point offset grid of :func:`_quantized_pixel_moments` (320 normal CDFs an element) take most
    of a ``log_prob`` call of a sensor with a spatial stack and 0.2 DN of read noise, hence the
    series from 0.045 DN.
    ``delta`` and ``s`` broadcast; an ``s`` that is constant along trailing axes may be given with
    length-1 axes there (a 1-D ``delta`` with ``s`` of shape (n, 1): the grid's harmonics are
    computed once). Each element's numbers depend on its own δ and s only.
    """
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    if np.all(s >= _RN_FOURIER_S):  # the common case (NaN: not), without the split
        return _rounded_normal_moments_fourier(delta, s, 4)
    kk = _rn_harmonics(s)
    ks = _small_unique(kk)

    def one(d, sv, K):
        # below 0.045 DN the DN boundaries beyond ±3/2 are ≥ 11 s away for |δ| ≤ 1: J = 2 suffices
        return _rounded_normal_moments_fourier(d, sv, K) if K else _rounded_normal_moments_sums(d, sv, min(J, 2))

    if ks.size == 1:
        return one(delta, s, int(ks[0]))
    shape = np.broadcast_shapes(delta.shape, s.shape)
    out = [np.empty(shape) for _ in range(3)]
    if delta.ndim == 1 and s.shape == (shape[0], 1):
        # a grid of offsets sharing one s per row (_quantized_pixel_moments): split by rows
        for K in ks:
            rows = kk[:, 0] == K
            for o, v in zip(out, one(delta, s[rows], int(K))):
                o[rows] = v
        return tuple(out)
    d = np.broadcast_to(delta, shape)
    sb = np.broadcast_to(s, shape)
    kb = np.broadcast_to(kk, shape)
    for K in ks:
        sel = kb == K
        for o, v in zip(out, one(d[sel], sb[sel], int(K))):
            o[sel] = v
    return tuple(out)


def _harmonics(delta, K):
    """sin(2πkδ) and cos(2πkδ), k = 1..K, for a 1-D ``delta``, as (K, n) arrays: one sin and one
    cos, then the angle-addition recurrence (sin/cos cost ~11 ns an element here, a multiply ~1 ns)."""
    th = (2.0 * np.pi) * delta
    S = np.empty((K,) + th.shape)
    C = np.empty((K,) + th.shape)
    s1, c1 = np.sin(th, out=S[0]), np.cos(th, out=C[0])
    for k in range(1, K):
        np.add(S[k - 1] * c1, C[k - 1] * s1, out=S[k])
        np.subtract(C[k - 1] * c1, S[k - 1] * s1, out=C[k])
    return S, C


def _gaussian_harmonics(s, K):
    """e^{−2π²k²s²}, k = 1..K, for a 1-D ``s``, as a (K, n) array: one exponential, then
    multiplications (e^{(k+1)²} = e^{k²} · e^{2k+1})."""
    e = np.exp(-2.0 * np.pi**2 * s * s)
    out = np.empty((K,) + e.shape)
    out[0] = e
    e2 = e * e
    step = e
    for k in range(1, K):
        step = step * e2  # e^{2k+1}
        np.multiply(out[k - 1], step, out=out[k])
    return out


# ω = 2πk and the Fourier coefficients of the sawtooth's powers wⁿ (w(y) = y on [−½, ½), period
# 1): n odd i(−1)^k αₙ, n even (−1)^k γₙ; the columns of the matrices below are the sums over k that
# _rounded_normal_moments_fourier needs (each term times q_k = 2(−1)^k e^{−ω²s²/2})
def _rn_matrices(K):
    w = 2.0 * np.pi * np.arange(1.0, K + 1.0)
    sin = np.stack(
        [
            1.0 / w,  # α₁
            0.25 / w - 6.0 / w**3,  # α₃
            2.0 / w,  # ω γ₂
            w,
        ],
        axis=1,
    )  # ω² α₁
    cos = np.stack(
        [
            np.ones(K),  # ω α₁
            2.0 / w**2,  # γ₂
            1.0 / w**2 - 24.0 / w**4,  # γ₄
            0.25 - 6.0 / w**2,  # ω α₃
            w**2,
        ],
        axis=1,
    )  # ω³ α₁
    sign = 2.0 * np.where(np.arange(1, K + 1) % 2 == 1, -1.0, 1.0)  # 2 (−1)^k
    return sin, cos, sign


_RN_MATRICES = {K: _rn_matrices(K) for _, K in _RN_FOURIER_K}


#: rows per block of :func:`_rows_matmul` (a multiple of BLAS's register tiles)
_GRID_BLOCK = 128


def _rows_matmul(left, right):
    """``left @ right`` for ``left`` (rows, K) and ``right`` (K, M), as products of blocks of
    :data:`_GRID_BLOCK` rows (the last one padded with zeros).

    The blocks make every product the same shape whatever the number of rows: OpenBLAS takes
    other kernels for small products, whose sums differ in the last bit (measured: a row computed
    alone or among 7 differed from the same row among 500), and a row's numbers must not depend
    on the other rows of the call (:class:`PTCModelStack`, ``tests/test_calibration_terms.py``)."""
    n, K = left.shape
    nb = -(-n // _GRID_BLOCK)
    pad = np.zeros((nb * _GRID_BLOCK, K))
    pad[:n] = left
    return (pad.reshape(nb, _GRID_BLOCK, K) @ right).reshape(nb * _GRID_BLOCK, -1)[:n]


def _rounded_normal_moments_fourier(delta, s, K=4):
    """:func:`_rounded_normal_moments` by Fourier series to ``K`` harmonics (4 for s ≥ 0.3 DN;
    :data:`_RN_FOURIER_K` for smaller s).

    With X = δ + Y, Y ~ N(0, s²), the rounding error is e = round(X) − X = −w(X), w the sawtooth,
    and round(X) − E[round X] = Y + e − ē. Its moments need E[Yᵐ eⁿ] (m ≤ 3, n ≤ 4), which follow
    from the Fourier coefficients of wⁿ and E[Yᵐ e^{iωY}] = (−i d/dω)ᵐ e^{−ω²s²/2} (ω = 2πk: the
    factor e^{−2π²k²s²} of each harmonic). Equal to the sums over the integers to 1e-14 (mean,
    variance) and 1e-12 (4th moment, a sum of O(1) terms) (``tests/test_calibration_terms.py``)."""
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    shape = np.broadcast_shapes(delta.shape, s.shape)
    # harmonics of δ and of s each on their own (flat) elements, then broadcast: a grid of offsets
    # sharing one s per row (_quantized_pixel_moments) computes each exponential once
    rn_sin, rn_cos, rn_sign = _RN_MATRICES[K] if K in _RN_MATRICES else _rn_matrices(K)
    if delta is _QG_GRIDS.get(delta.size):  # an offset grid's harmonics: computed once
        if (delta.size, K) not in _QG_HARMONICS:
            _QG_HARMONICS[delta.size, K] = _harmonics(delta, K)
        S, C = _QG_HARMONICS[delta.size, K]
    else:
        S, C = _harmonics(delta.reshape(-1), K)
    pad_d = (1,) * (len(shape) - delta.ndim)  # leading axes of the broadcast shape
    S, C = S.reshape((K,) + pad_d + delta.shape), C.reshape((K,) + pad_d + delta.shape)
    q = (rn_sign[:, None] * _gaussian_harmonics(s.reshape(-1), K)).reshape(
        (K,) + (1,) * (len(shape) - s.ndim) + s.shape
    )
    v2 = s * s
    v4 = v2 * v2
    # Expanding E[Yᵐeⁿ] (E[e] = A₁, E[e²] = 1/12 + B₂, E[e³] = A₃, E[e⁴] = 1/80 + B₄, E[Ye] = v₂B₀,
    # E[Ye²] = −v₂A₂, E[Ye³] = v₂B₃, E[Y²e] = v₂A₁ − v₄A₄, E[Y²e²] = v₂/12 + v₂B₂ − 2v₄B₀,
    # E[Y³e] = 3v₄B₀ − v₆B₅; A, B the sine and cosine sums of the columns of _rn_matrices) and
    # collecting terms (the v₄B₀ ones cancel):
    #   m  = δ + A₁,   v = v₂ + 1/12 + V_c − A₁²,
    #   m₄ = 3v₄ + v₂/2 + 1/80 + L_c + A₁·P_s + A₁²(½ − 6v₂ + Q_c − 3A₁²),
    # with the sums V_c = 2v₂B₀ + B₂, L_c = B₄ + 4v₂B₃ + 6v₂B₂ − 4v₆B₅, P_s = 12v₄A₄ + 12v₂A₂ − 4A₃
    # and Q_c = 12v₂B₀ + 6B₂ formed from combined coefficients: 5 sums instead of 9, ~11 array
    # passes instead of ~35 (the same numbers as term by term, to rounding)
    a1, a3, g2, w2a1 = rn_sin.T  # α₁, α₃, ωγ₂, ω²α₁
    b0, b2, b4, b3, b5 = rn_cos.T  # ωα₁, γ₂, γ₄, ωα₃, ω³α₁
    if delta.ndim == 1 and s.shape == (shape[0], 1):
        # a grid of offsets sharing one s per row: Σ_k coef[row, c, k] q[k, row] S[k, x] as one
        # product of (rows·columns, K) by the grid's (K, M), without (K, rows, M) temporaries
        r2, r4 = v2[:, 0, None], v4[:, 0, None]  # (rows, 1)
        qr = q.reshape(K, -1).T  # (rows, K)
        ls = np.stack([np.broadcast_to(a1 * qr, qr.shape), (12.0 * r4 * w2a1 + 12.0 * r2 * g2 - 4.0 * a3) * qr], axis=1)
        lc = np.stack(
            [
                (2.0 * r2 * b0 + b2) * qr,
                (b4 + 4.0 * r2 * b3 + 6.0 * r2 * b2 - 4.0 * r4 * r2 * b5) * qr,
                (12.0 * r2 * b0 + 6.0 * b2) * qr,
            ],
            axis=1,
        )
        n = qr.shape[0]
        A1, P_s = _rows_matmul(ls.reshape(2 * n, K), S.reshape(K, -1)).reshape(n, 2, -1).transpose(1, 0, 2)
        V_c, L_c, Q_c = _rows_matmul(lc.reshape(3 * n, K), C.reshape(K, -1)).reshape(n, 3, -1).transpose(1, 0, 2)
    else:
        QS = np.broadcast_to(q * S, (K,) + shape).reshape(K, -1)
        QC = np.broadcast_to(q * C, (K,) + shape).reshape(K, -1)
        if K == 4:
            # (4, 4) by (4, N) directly: a row's sums do not depend on N here (tested
            # with sub-arrays of every size), and the blocked product costs ~5 % of a call on sim05
            A1, A3, A2, A4 = (rn_sin.T @ QS).reshape((4,) + shape)
            B0, B2, B4, B3, B5 = (rn_cos.T @ QC).reshape((5,) + shape)
        else:
            A1, A3, A2, A4 = _rows_matmul(QS.T, rn_sin).T.reshape((4,) + shape)
            B0, B2, B4, B3, B5 = _rows_matmul(QC.T, rn_cos).T.reshape((5,) + shape)
        V_c = 2.0 * v2 * B0 + B2
        L_c = B4 + 4.0 * v2 * B3 + 6.0 * v2 * B2 - 4.0 * v4 * v2 * B5
        P_s = 12.0 * v4 * A4 + 12.0 * v2 * A2 - 4.0 * A3
        Q_c = 12.0 * v2 * B0 + 6.0 * B2
    a1s = A1 * A1
    m = delta + A1
    v = (v2 + 1.0 / 12.0) + V_c - a1s
    m4 = (3.0 * v4 + 0.5 * v2 + 1.0 / 80.0) + L_c + A1 * P_s + a1s * ((0.5 - 6.0 * v2) + Q_c - 3.0 * a1s)
    return tuple(np.broadcast_to(r, shape) for r in (m, v, m4))


def _rounded_normal_moments_sums(delta, s, J=6):
    """:func:`_rounded_normal_moments` by direct sums over the integers j = −J..J."""
    j = np.arange(-J, J + 1, dtype=float)
    b = j[:-1] + 0.5  # boundaries between j and j+1
    cdf = ndtr((b - delta[..., None]) / s[..., None])
    p = np.diff(
        np.concatenate([np.zeros(cdf.shape[:-1] + (1,)), cdf, np.ones(cdf.shape[:-1] + (1,))], axis=-1), axis=-1
    )
    m = p @ j
    c = j - m[..., None]
    c2 = c * c
    v = np.sum(p * c2, axis=-1)
    m4 = np.sum(p * c2 * c2, axis=-1)
    return m, v, m4


#: ``_rounded_offset``: from this s_tot up, the rounded mean's Fourier series (4 harmonics: the 5th is
#: e^{−50π²s²} < 1e-19) replaces the sums over DN boundaries; above the second, the mean is δ itself
#: to double precision (its first harmonic e^{−2π²s²}/π < 2e-15)
_RO_FOURIER_S = 0.3
_RO_IDENTITY_S = 1.3


def _rounded_offset(frac_obs, s_tot, n_iter=12):
    """The offset δ ∈ [−½, ½] whose rounded normal N(δ, s_tot²) has mean ``frac_obs`` (the
    measured mean's distance from the nearest integer DN). E[round] is increasing in δ and
    maps [−½, ½] onto itself. Each element stops once its mean matches to 1e-9 DN, so its value
    does not depend on the other elements of the array (a stacked evaluation,
    :class:`PTCModelStack`, gives each sensor its own numbers bit for bit).

    By s_tot: above :data:`_RO_IDENTITY_S` (1.3 DN) δ is ``frac_obs``; from :data:`_RO_FOURIER_S`
    (0.3 DN) Newton on the Fourier series E[round X] = δ − Σ_k (−1)^{k+1} e^{−2π²k²s²} sin(2πkδ)/(πk),
    whose slope is at least 0.66 there (3-4 steps); below, safeguarded Newton on the sums over the DN
    boundaries (:func:`_rounded_offset_boundaries`). The boundary sums alone cost half of a fast fit
    of a 12-bit sensor whose read noise is half a DN (sim05 of ``benchmarks/speed_accuracy.py``)."""
    shape = np.broadcast(frac_obs, s_tot).shape
    fo = np.clip(np.broadcast_to(frac_obs, shape).astype(float), -0.5, 0.5).reshape(-1)
    s = np.broadcast_to(s_tot, shape).astype(float).reshape(-1)
    d = fo.copy()  # s_tot > 1.3 DN: the identity
    four = (s >= _RO_FOURIER_S) & (s <= _RO_IDENTITY_S)
    low = ~(s >= _RO_FOURIER_S)  # (and NaN, as before)
    if np.any(four):
        d[four] = _rounded_offset_fourier(fo[four], s[four], n_iter)
    if np.any(low):
        # s < 0.3 DN: boundaries ½, 3/2, 5/2 (the next one's terms are below Φ(−10) ≈ 8e-24)
        d[low] = _rounded_offset_boundaries(fo[low], s[low], n_iter, n_boundaries=3)
    return d.reshape(shape)


def _rounded_offset_fourier(fo, s, n_iter):
    """:func:`_rounded_offset` for 0.3 ≤ s ≤ 1.3 DN (1-D inputs): Newton on the Fourier series
    (the harmonics of each iterate by :func:`_harmonics`: one sin and one cos)."""
    k = np.arange(1.0, 5.0)[:, None]
    qk = np.array([1.0, -1.0, 1.0, -1.0])[:, None] * _gaussian_harmonics(s, 4)  # (−1)^{k+1} e^{−2π²k²s²}
    a = qk / (np.pi * k)
    b = 2.0 * qk
    d = fo.copy()
    for _ in range(n_iter):
        S, C = _harmonics(d, 4)
        gap = d - np.sum(a * S, axis=0) - fo
        done = np.abs(gap) < 1e-9
        if np.all(done):
            break
        slope = 1.0 - np.sum(b * C, axis=0)
        d = np.where(done, d, np.clip(d - gap / slope, -0.5, 0.5))
    return d


def _rounded_offset_boundaries(frac_obs, s_tot, n_iter=12, n_boundaries=6):
    """:func:`_rounded_offset` by safeguarded Newton on E[round X] = Σ_{b>0} [Φ((δ−b)/s) −
    Φ((−b−δ)/s)] over the DN boundaries b = ½ … ``n_boundaries`` − ½ (bisection when a step leaves
    the bracket); with 6, exact to 1e-12 for s ≤ 0.75 DN. :func:`_rounded_offset` uses it for
    s < 0.3 DN with 3 (½, 3/2, 5/2: the terms of 7/2 are below Φ(−3/0.3) ≈ 8e-24 there), half the
    evaluations of 6.

    Newton starts from the inverse of the nearest boundary's term alone, δ₀ = sign(f)·max(½ +
    s·Φ⁻¹(|f|), 0): every element then meets the 1e-9 DN tolerance within 3 steps (40 000 random
    offsets and s from 0.01 to 0.3 DN; ``tests/test_calibration_terms.py``). Started from δ₀ = f,
    small offsets need up to 22 steps (the mean is exponentially flat near 0 at small s), more
    than the 12 allowed, and the solver takes 70 % of a ``log_prob`` call of a sensor whose read
    noise is 0.1 DN."""
    bs = [k + 0.5 for k in range(n_boundaries)]  # positive boundaries; E[round X] is odd in δ
    shape = np.broadcast(frac_obs, s_tot).shape
    fo_all = np.broadcast_to(frac_obs, shape).astype(float).reshape(-1)
    s_all = np.broadcast_to(s_tot, shape).astype(float).reshape(-1)
    f = np.clip(fo_all, -0.5, 0.5)
    with np.errstate(all="ignore"):
        d_all = np.copysign(np.clip(0.5 + s_all * ndtri(np.maximum(np.abs(f), 1e-300)), 0.0, 0.5), f)
    # Newton on the elements not yet converged only (each element's steps are its own, so the
    # result is the same as iterating all of them until the last one converges: 2.4 passes' worth
    # instead of 4 on a sensor with 0.14 DN of read noise). One boundary at a time on 1-D arrays,
    # summed in the order np.sum takes over an (n, boundaries) array (the same bits, 30 % less
    # time: that sum over a short last axis and the (n, 3) temporaries are half its cost)
    idx = None
    d, fo, s = d_all, fo_all, s_all
    lo = np.full(d.size, -0.5)
    hi = -lo
    # A start of ±0 (|f| ≤ Φ(−½/s): nearly every element of a sensor whose read noise is 0.2-0.3 DN)
    # has E[round X] = 0 exactly (ndtr(zp) − ndtr(zm) of equal arguments), so its first pass needs the
    # slope's exponentials only: the same bits without the first of its (usually three) passes' ndtr calls
    zero = d == 0.0
    skip = None if not np.any(zero) else zero
    for _ in range(n_iter):
        m = dm = None
        for b in bs:
            zp = (d - b) / s
            zm = (-b - d) / s
            if skip is None:
                t = ndtr(zp) - ndtr(zm)
            else:
                t = np.zeros(d.size)
                if not np.all(skip):
                    live = ~skip
                    t[live] = ndtr(zp[live]) - ndtr(zm[live])
            e = np.exp(-0.5 * zp * zp) + np.exp(-0.5 * zm * zm)
            if m is None:
                m, dm = t, e
            else:
                m += t
                dm += e
        dm *= 0.3989422804014327 / s
        gap = m - fo
        done = np.abs(gap) < 1e-9
        if np.all(done):
            break
        lo = np.where(gap < 0, d, lo)
        hi = np.where(gap >= 0, d, hi)
        nd = d - gap / np.maximum(dm, 1e-300)
        d = np.where(done, d, np.where((nd > lo) & (nd < hi), nd, 0.5 * (lo + hi)))
        keep = ~done
        if idx is None:  # first pass: every element
            d_all = d.copy()
            idx = np.flatnonzero(keep)
        else:
            d_all[idx] = d
            idx = idx[keep]
        d, fo, s, lo, hi = d[keep], fo[keep], s[keep], lo[keep], hi[keep]
        skip = None
    return d_all.reshape(shape)
