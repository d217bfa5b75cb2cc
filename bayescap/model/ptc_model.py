"""The photon-transfer noise model (Tisse et al. 2008, Eq. 1) and its posterior density.

Everything is in electrons with the conversion gain ``K`` (e⁻/DN). For a bright row at mean
signal ``S`` (DN above the dark level) and exposure time ``t`` the temporal variance of the
pixel values is, before clipping,

    σ²_y(S) = S/K + (σ_read² + D·t)/K² + 1/12          [DN²]

(photon shot noise, dark-current shot noise, read noise, quantization), and for the dark row
``σ²_dark = (σ_read² + D·t)/K² + 1/12``. Pair differences cancel fixed-pattern noise, so DSNU and
PRNU enter only through the spatial columns: ``spatial_var = (PRNU·S)² + DSNU²/K² + σ²_y/L``.

**Saturation.** Pixel values clip at a level ``c`` (DN): the ADC maximum or the full well,
whichever comes first. Across the ROI, pixels approach the clip at different light levels
(PRNU, per-pixel well depth), described by a spread ``τ`` (DN) of the pixel means. The mean and
temporal variance of a clipped Gaussian, averaged over that spread (closed forms, ``_clip_moments``),
give the smooth roll-off of the measured variance; the latent (unclipped) signal of each row
near the clip is found by inverting the clipped-mean relation with a monotone Newton iteration.
Fully clipped rows (variance ≈ 0) locate the clip level only: they enter through their mean.
With no row near saturation no clip term is fitted and the full well is reported as a lower
bound.

**Likelihood.** A temporal variance from a frame pair over ``n`` pixels follows a scaled χ²
with ``ν = n − 1`` degrees of freedom around the *model* variance: Gamma(ν/2, 2σ²/ν). Real
data carry systematics (illumination drift, non-linearity) far above the 0.4 % statistical
error of a 10⁵-pixel variance; a fitted fractional discrepancy ``f`` widens the distribution
to an effective ``ν_eff`` with ``2/ν_eff = 2/ν + f²`` (same mean, relative variance
``2/ν + f²``), so the intervals stay honest. ``f`` is reported: a large value says the model
or the data are inadequate. With ``photons_per_pixel`` the means are fitted jointly:
``S = QE·μ_p/K`` with a fractional mean discrepancy ``g`` (non-linearity).

**Terms enter only when the data can inform them** (:func:`select_terms`); the reasons for
every left-out term are recorded.
"""
from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.special import erfcx, gammaln, ndtr, ndtri, owens_t

from bayescap.io.ptc_csv import PTCData, check_not_all_saturated
from bayescap.exceptions import PTCInputError

__all__ = ["PTCModel", "PTCModelStack", "ModelTerms", "select_terms", "saturation_flags", "gamma_logpdf", "PARAMETER_INFO"]

_LOG_2PI = np.log(2.0 * np.pi)
#: prior probability that a row is a bad measurement, and the relative scatter of bad rows
OUTLIER_RATE = 0.02
OUTLIER_REL_SD = 0.3
ROBUST_BLOCKS = ("bright_var", "dark_var", "mean")
# log of OUTLIER_RATE × the log-normal's normalisation, less log v (added to both components)
_BAD_GAMMA_CONST = float(np.log(OUTLIER_RATE) - np.log(OUTLIER_REL_SD) - 0.5 * np.log(2.0 * np.pi))
_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(9)
_GH_W = _GH_W / _GH_W.sum()

# physical parameter -> (unit, description)
PARAMETER_INFO = {
    "conversion_gain_e_per_dn": ("e-/DN", "conversion gain K"),
    "read_noise_e": ("e-", "temporal read noise"),
    "dark_current_e_per_s": ("e-/s", "dark current (from the dark-noise growth with time)"),
    "dark_noise_e": ("e-", "read noise and dark-current shot noise combined at the single exposure time"),
    "full_well_e": ("e-", "charge at which the pixel output clips"),
    "quantum_efficiency": ("", "quantum efficiency"),
    "prnu_percent": ("%", "photo-response non-uniformity"),
    "dsnu_e": ("e-", "dark-signal non-uniformity"),
    "clip_spread_dn": ("DN", "spread of the pixel means about the clip level"),
    "variance_discrepancy": ("", "fractional discrepancy of the variances (systematics)"),
    "mean_discrepancy": ("", "fractional discrepancy of the means (non-linearity)"),
}


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
    if np.any(small):    # rare (ν = n_pixels − 1 is large): lgamma only where Stirling is not used
        shape = np.broadcast_shapes(stirling.shape, core.shape)
        stirling = np.array(np.broadcast_to(stirling, shape))      # a writable copy
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
        # of max(|result|, 1), and cheaper than log1p there (7 against 11 ns an element,
        # benchmarks/ufunc_costs.py); |a − b| capped at 50 (e ≥ 2e-22, which rounds away against 1)
        # so that exp never takes its slow underflow path (25 against 9 ns)
        out = m + np.log(1.0 + np.exp(-np.minimum(np.abs(a - b), 50.0)))
    return np.where(m == -np.inf, m, out)


def _halfnormal_log_prior(u, scale):
    """log density of u = log x when x ~ HalfNormal(scale) (Jacobian included)."""
    x = np.exp(u)
    return u - 0.5 * (x / scale) ** 2


def _scale_log_prior(u, scale, log_bounds=None):
    """log prior of u = log x: half-normal of ``scale`` in x, or, with ``log_bounds = (lo, hi)``
    (natural values), log-uniform on [lo, hi] (uniform in u, normalised)."""
    if log_bounds is None:
        return _halfnormal_log_prior(u, scale)
    a, b = np.log(log_bounds[0]), np.log(log_bounds[1])
    return np.where((u >= a) & (u <= b), -np.log(b - a), -np.inf)


def _chi2_over_nu(z, nu):
    """χ²_ν/ν as a function of a standard normal z (Wilson–Hilferty; relative error of the
    quantiles < 1e-4 for ν ≥ 10, far below the ~√(2/ν) spread it describes)."""
    a = 2.0 / (9.0 * nu)
    return np.maximum(1.0 - a + z * np.sqrt(a), 1e-3) ** 3


def _log_shortfall(h):
    """log ψ(h), ψ(h) = h Φ(h) + φ(h): the clipped normal's shortfall below the clip in units of its
    sd, E[(c − X)⁺]/s' for X ~ N(c − h s', s'²). Written as ψ(h) = e^{−h²/2} (φ(0) + ½ h
    erfcx(−h/√2)), the form :meth:`PTCModel._latent_clip_rows` evaluates inline: its logarithm
    stays finite where ψ itself underflows (h < −38), and the bracket's cancellation for h < 0
    costs a relative error of only ~h²·1e-16 (1e-13 at h = −37); ψ = h to double precision above
    h = 30, where erfcx would overflow."""
    h = np.asarray(h, float)
    hc = np.minimum(h, 30.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = -0.5 * hc * hc + np.log(0.3989422804014327 + 0.5 * hc * erfcx(-0.7071067811865476 * hc))
    return np.where(h > 30.0, np.log(np.maximum(h, 30.0)), out)


# ψ⁻¹ tabulated on a uniform grid of log ψ from −60 (h ≈ −10.8) to 2.5 (h ≈ 12), for the first
# guess of the latent clip solver: an index computed, not searched (np.interp on a table uniform in
# h cost 80 µs for 700 elements); outside the grid the guess is the end's h, and Newton goes on
_PSI_L0, _PSI_DL = -60.0, 0.01


def _psi_inverse_table():
    h = np.linspace(-11.0, 12.5, 200001)
    L = _log_shortfall(h)
    grid = _PSI_L0 + _PSI_DL * np.arange(int(round((2.5 - _PSI_L0) / _PSI_DL)) + 1)
    return np.interp(grid, L, h)


_PSI_INV = _psi_inverse_table()


def _psi_inverse_guess(L):
    """h with log ψ(h) ≈ L by linear interpolation in :data:`_PSI_INV` (clamped to its range; NaN
    gives its upper end)."""
    t = np.fmax(np.fmin((L - _PSI_L0) / _PSI_DL, _PSI_INV.size - 1.000001), 0.0)   # fmin: NaN → top
    i = t.astype(np.intp)
    lo = _PSI_INV[i]
    return lo + (t - i) * (_PSI_INV[i + 1] - lo)


#: below this s² + σ_o² (DN²) the rounded-normal moments replace Sheppard's σ² + 1/12
_QUANT_EXACT_S2 = 0.5


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
    whose dark noise is half a DN (sim05 of ``benchmarks/speed_accuracy.py``; docs/performance.md,
    "2026-11-23, 19:40–22:40"); the sums on the 32-point offset grid of
    :func:`_quantized_pixel_moments` (320 normal CDFs an element) took most of a ``log_prob`` call
    of a sensor with a spatial stack and 0.2 DN of read noise until the series replaced them from
    0.045 DN (2026-11-24, "11:25–" in docs/performance.md).
    ``delta`` and ``s`` broadcast; an ``s`` that is constant along trailing axes may be given with
    length-1 axes there (a 1-D ``delta`` with ``s`` of shape (n, 1): the grid's harmonics are
    computed once). Each element's numbers depend on its own δ and s only.
    """
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    if np.all(s >= _RN_FOURIER_S):                      # the common case (NaN: not), without the split
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
        step = step * e2                       # e^{2k+1}
        np.multiply(out[k - 1], step, out=out[k])
    return out


# ω = 2πk and the Fourier coefficients of the sawtooth's powers wⁿ (w(y) = y on [−½, ½), period
# 1): n odd i(−1)^k αₙ, n even (−1)^k γₙ; the columns of the matrices below are the sums over k that
# _rounded_normal_moments_fourier needs (each term times q_k = 2(−1)^k e^{−ω²s²/2})
def _rn_matrices(K):
    w = 2.0 * np.pi * np.arange(1.0, K + 1.0)
    sin = np.stack([1.0 / w,                                   # α₁
                    0.25 / w - 6.0 / w**3,                     # α₃
                    2.0 / w,                                   # ω γ₂
                    w], axis=1)                                # ω² α₁
    cos = np.stack([np.ones(K),                                # ω α₁
                    2.0 / w**2,                                # γ₂
                    1.0 / w**2 - 24.0 / w**4,                  # γ₄
                    0.25 - 6.0 / w**2,                         # ω α₃
                    w**2], axis=1)                             # ω³ α₁
    sign = 2.0 * np.where(np.arange(1, K + 1) % 2 == 1, -1.0, 1.0)   # 2 (−1)^k
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
    if delta is _QG_GRIDS.get(delta.size):              # an offset grid's harmonics: computed once
        if (delta.size, K) not in _QG_HARMONICS:
            _QG_HARMONICS[delta.size, K] = _harmonics(delta, K)
        S, C = _QG_HARMONICS[delta.size, K]
    else:
        S, C = _harmonics(delta.reshape(-1), K)
    pad_d = (1,) * (len(shape) - delta.ndim)            # leading axes of the broadcast shape
    S, C = S.reshape((K,) + pad_d + delta.shape), C.reshape((K,) + pad_d + delta.shape)
    q = (rn_sign[:, None] * _gaussian_harmonics(s.reshape(-1), K)).reshape((K,) + (1,) * (len(shape) - s.ndim) + s.shape)
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
    # passes instead of ~35 (the same numbers to rounding; until 2026-11-24 term by term)
    a1, a3, g2, w2a1 = rn_sin.T                         # α₁, α₃, ωγ₂, ω²α₁
    b0, b2, b4, b3, b5 = rn_cos.T                       # ωα₁, γ₂, γ₄, ωα₃, ω³α₁
    if delta.ndim == 1 and s.shape == (shape[0], 1):
        # a grid of offsets sharing one s per row: Σ_k coef[row, c, k] q[k, row] S[k, x] as one
        # product of (rows·columns, K) by the grid's (K, M), without (K, rows, M) temporaries
        r2, r4 = v2[:, 0, None], v4[:, 0, None]         # (rows, 1)
        qr = q.reshape(K, -1).T                         # (rows, K)
        ls = np.stack([np.broadcast_to(a1 * qr, qr.shape),
                       (12.0 * r4 * w2a1 + 12.0 * r2 * g2 - 4.0 * a3) * qr], axis=1)
        lc = np.stack([(2.0 * r2 * b0 + b2) * qr,
                       (b4 + 4.0 * r2 * b3 + 6.0 * r2 * b2 - 4.0 * r4 * r2 * b5) * qr,
                       (12.0 * r2 * b0 + 6.0 * b2) * qr], axis=1)
        n = qr.shape[0]
        A1, P_s = _rows_matmul(ls.reshape(2 * n, K), S.reshape(K, -1)).reshape(n, 2, -1).transpose(1, 0, 2)
        V_c, L_c, Q_c = _rows_matmul(lc.reshape(3 * n, K), C.reshape(K, -1)).reshape(n, 3, -1).transpose(1, 0, 2)
    else:
        QS = np.broadcast_to(q * S, (K,) + shape).reshape(K, -1)
        QC = np.broadcast_to(q * C, (K,) + shape).reshape(K, -1)
        if K == 4:
            # (4, 4) by (4, N) as before 2026-11-24: a row's sums do not depend on N here (tested
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
    b = (j[:-1] + 0.5)  # boundaries between j and j+1
    cdf = ndtr((b - delta[..., None]) / s[..., None])
    p = np.diff(np.concatenate([np.zeros(cdf.shape[:-1] + (1,)), cdf, np.ones(cdf.shape[:-1] + (1,))], axis=-1), axis=-1)
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
    d = fo.copy()                                    # s_tot > 1.3 DN: the identity
    four = (s >= _RO_FOURIER_S) & (s <= _RO_IDENTITY_S)
    low = ~(s >= _RO_FOURIER_S)                      # (and NaN, as before)
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
    qk = np.array([1.0, -1.0, 1.0, -1.0])[:, None] * _gaussian_harmonics(s, 4)   # (−1)^{k+1} e^{−2π²k²s²}
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
    offsets and s from 0.01 to 0.3 DN; ``tests/test_calibration_terms.py``). Started from δ₀ = f, as
    before 2026-11-24, small offsets needed up to 22 steps (the mean is exponentially flat near 0 at
    small s), more than the 12 allowed, and the solver took 70 % of a ``log_prob`` call of a sensor
    whose read noise is 0.1 DN (docs/performance.md, "2026-11-24, 11:25–")."""
    bs = [k + 0.5 for k in range(n_boundaries)]     # positive boundaries; E[round X] is odd in δ
    shape = np.broadcast(frac_obs, s_tot).shape
    fo_all = np.broadcast_to(frac_obs, shape).astype(float).reshape(-1)
    s_all = np.broadcast_to(s_tot, shape).astype(float).reshape(-1)
    f = np.clip(fo_all, -0.5, 0.5)
    with np.errstate(all="ignore"):
        d_all = np.copysign(np.clip(0.5 + s_all * ndtri(np.maximum(np.abs(f), 1e-300)), 0.0, 0.5), f)
    # Newton on the elements not yet converged only (each element's steps are its own, so the
    # result is the same as iterating all of them until the last one converges: 2.4 passes' worth
    # instead of 4 on a sensor with 0.14 DN of read noise). One boundary at a time on 1-D arrays,
    # summed in the order np.sum took over an (n, boundaries) array until 2026-11-25 (the same bits,
    # 30 % less time: that sum over a short last axis and the (n, 3) temporaries were half the cost)
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
        if idx is None:                              # first pass: every element
            d_all = d.copy()
            idx = np.flatnonzero(keep)
        else:
            d_all[idx] = d
            idx = idx[keep]
        d, fo, s, lo, hi = d[keep], fo[keep], s[keep], lo[keep], hi[keep]
        skip = None
    return d_all.reshape(shape)


#: Sheppard's s² + 1/12 is the variance of rounded values over *all* offsets; a pixel's temporal
#: variance about its own mean is smaller by Q(s) = Σₖ e^{−4π²k²s²}/(2π²k²) (the rounding bias of
#: its mean, h below, averaged): Q < 2e-5 DN² (relative < 1e-4) only for s² ≥ 0.2 DN²
_QUANT_TEMPORAL_S2 = 0.2
#: midpoint grids over a pixel mean's offset within one DN (:func:`_quantized_pixel_moments`).
#: The M-point rule's error is the aliasing of the product of the wrapped normal (harmonics
#: e^{−2π²k²σ_o²}) and the moments (harmonics down to ~e^{−π²n²s²/2}, the 4th moment's products):
#: at most ~e^{−c}, c = M²·ab/(a + b), a = 2π²σ_o², b = π²s²/2. Each element takes the smallest M
#: of :data:`_QG_SIZES` with c ≥ :data:`_QG_C` (measured against 256 points: max error 6e-12 at
#: c ≥ 23 over s 0.02-0.75 DN, σ_o 1/32-0.7 DN), 1 024 where none does (s below ~0.005 DN). Until
#: 2026-11-24 every element took M = 32, whose error reached 1.8e-3 DN² where s and σ_o are both
#: below ~0.05 DN and which was 2-4× more points than needed where they are not.
_QG_M = 32                # below σ_o = 1/_QG_M (and σ_o < s/4): Gauss–Hermite nodes instead of a grid
#: the Gauss–Hermite nodes need the integrands smooth on the scale of σ_o: σ_o < s/4 (error ≤ 1.5e-13
#: against a 4 096-point quadrature over s 0.005-0.75 DN; with σ_o between s/2 and 2s they had been
#: off by up to 1e-3 DN², 4 % of V, measured 2026-11-24), else the grid
_GH_SO_OVER_S = 0.25
_QG_SIZES = (8, 16, 32, 64, 128, 256, 512, 1024)
_QG_C = 25.0
_QG_GRIDS = {M: (np.arange(M) + 0.5) / M - 0.5 for M in _QG_SIZES}
_QG_X = _QG_GRIDS[_QG_M]
_QG_HARMONICS = {}        # (M, K) -> (sin, cos) of 2πk·x on grid M, k = 1..K (_rounded_normal_moments_fourier)
_QG_J = np.arange(-6, 6)  # DN boundaries j + ½ of the Stein term (the wrapped normal's images until 2026-11-24)
#: :func:`_wrapped_normal_grid`: below this σ_o (DN) the images j = −1, 0, 1 (the next ones are
#: ≥ 1 DN away: e^{−½(1/0.1)²} ≈ 2e-22 of the peak); from it up the Fourier series to
#: :data:`_WN_K` harmonics (the next one's factor e^{−2π²·15²·0.1²} ≈ 9e-20)
_WN_FOURIER_SO = 0.1
_WN_K = 14
_WN_CS = {M: np.concatenate([np.cos(2.0 * np.pi * np.arange(1, _WN_K + 1)[:, None] * x),
                             np.sin(2.0 * np.pi * np.arange(1, _WN_K + 1)[:, None] * x)])   # (2K, M)
          for M, x in _QG_GRIDS.items()}


def _grid_size(s, so):
    """Points of the offset grid for each element (:data:`_QG_SIZES`, :data:`_QG_C`)."""
    a = 2.0 * np.pi**2 * so * so
    b = 0.5 * np.pi**2 * s * s
    with np.errstate(all="ignore"):
        c1 = a * b / (a + b)                     # c for M = 1
    # NaN (a draw whose variance is not finite: its moments are NaN whatever the grid): the smallest
    M = np.where(np.isnan(c1), _QG_SIZES[0], _QG_SIZES[-1]).astype(np.intp)
    for size in reversed(_QG_SIZES[:-1]):
        M[c1 * size * size >= _QG_C] = size
    return M


def _wrapped_normal_grid(delta, so, M=_QG_M):
    """Weights (n, M) of the M-point midpoint grid (:data:`_QG_GRIDS`) under the wrapped normal
    N(δ, σ_o²) modulo 1 DN (1-D ``delta`` and ``so``, 0 < σ_o ≤ 0.7), normalised to sum 1.

    Below :data:`_WN_FOURIER_SO` (0.1 DN) the density's three nearest images; from it, its Fourier
    series 1 + 2 Σ_k e^{−2π²k²σ_o²} cos 2πk(x − δ), k ≤ :data:`_WN_K`, whose cosines are the grid's
    (constants) combined with δ's harmonics (:func:`_harmonics`: one sin and one cos per element)
    in one matrix product: no exponential per grid point. Until 2026-11-24 the sum of twelve
    images at every grid point (384 exponentials an element) took half of a ``log_prob`` call of a
    sensor with a spatial stack whose read noise is below 0.5 DN (docs/performance.md,
    "2026-11-24, 11:25–"). Both forms agree with the sum of ±40 images to 1e-15
    (``tests/test_calibration_terms.py``)."""
    delta = np.asarray(delta, float)
    so = np.asarray(so, float)
    x = _QG_GRIDS[M]
    w = np.empty(delta.shape + (M,))
    four = so >= _WN_FOURIER_SO
    if np.any(~four):
        d = (x[:, None] - delta[~four, None, None] + np.arange(-1.0, 2.0)) / so[~four, None, None]
        w[~four] = np.exp(-0.5 * d * d).sum(-1)
    if np.any(four):
        S, C = _harmonics(delta[four], _WN_K)                           # (K, n)
        q = 2.0 * _gaussian_harmonics(so[four], _WN_K)                   # (K, n)
        A = np.concatenate([(q * C).T, (q * S).T], axis=1)              # (n, 2K)
        w[four] = 1.0 + _rows_matmul(A, _WN_CS[M])
    return w / w.sum(-1, keepdims=True)


def _quantized_pixel_moments(delta, s, so):
    """Rounding of pixels whose means are spread: offsets o ~ N(δ, σ_o²) (δ relative to an integer
    DN, σ_o = ``so``), each pixel's values round(o + s·ε), ε ~ N(0, 1) drawn anew every frame.

    Returns ``(V, E4, H)`` (1-D, like ``delta``):

    * V  = E_o[var(round(o + sε) | o)], the temporal variance averaged over the pixels;
    * E4 = E_o[μ₄ + var²] of the same, for the sampling variance of a pair estimate;
    * H  = var_o(E[round(o + sε) | o]) − σ_o², the spatial variance that rounding adds to the
      pixel means (up to 1/12 DN² for s → 0: a pattern whose pixels sit still is quantized too).

    The offsets' distribution modulo 1 DN is the wrapped normal, integrated on a periodic midpoint
    grid of 8-1 024 points chosen per element from s and σ_o (:func:`_grid_size`; uniform for
    σ_o > 0.7 DN, where its harmonics are < e^{−2π²·0.49} ≈ 6e-5, and then tabulated in s); for
    σ_o < 1/32 and σ_o < s/4, Gauss–Hermite nodes about δ; for σ_o = 0, the point δ.
    cov(o, h(o)) comes from Stein's lemma in closed form:
    σ_o²·(Σ_b N(b; δ, s² + σ_o²) − 1), b the half-integer DN boundaries."""
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    so = np.asarray(so, float)
    V = np.empty_like(delta)
    E4 = np.empty_like(delta)
    H = np.empty_like(delta)
    point = so < 1e-6
    narrow = ~point & (so < 1.0 / _QG_M) & (so < _GH_SO_OVER_S * s)
    wide = so > 0.7
    grid = ~(point | narrow | wide)
    if np.any(point):   # no pattern: the pixels share one offset
        _, vp, m4p = _rounded_normal_moments(delta[point], s[point], J=5)
        V[point], E4[point], H[point] = vp, m4p + vp * vp, 0.0
    if np.any(narrow):
        # a spread narrower than the grid: Gauss–Hermite nodes about δ (the integrands are smooth
        # on the scale of s; the nodes stay within ±1 DN, so no wrapping is needed)
        xg = delta[narrow, None] + so[narrow, None] * _GH_X
        mg, vg, m4g = _rounded_normal_moments(xg, s[narrow, None], J=5)
        V[narrow] = (vg * _GH_W).sum(-1)
        E4[narrow] = ((m4g + vg * vg) * _GH_W).sum(-1)
        em = (mg * _GH_W).sum(-1)
        H[narrow] = (mg * mg * _GH_W).sum(-1) - em * em - so[narrow] ** 2
    if np.any(wide):    # offsets uniform modulo 1 DN: functions of s alone (tabulated)
        V[wide], E4[wide], H[wide] = _uniform_offset_moments(s[wide])
    if np.any(grid):
        gi = np.flatnonzero(grid)
        sizes = _grid_size(s[gi], so[gi])
        for M in _small_unique(sizes):
            at_M = gi[sizes == M]
            step = max(1, _QG_CHUNK_POINTS // int(M))
            for i0 in range(0, at_M.size, step):
                _grid_moments(delta, s, so, at_M[i0:i0 + step], int(M), V, E4, H)
    return V, E4, H


#: :func:`_quantized_pixel_moments` works on the grid's (elements, M) arrays in chunks of at most this
#: many points (1 MB a float array): a fast path's 6 000 draws × 13 spatial-stack rows × 16 points
#: had ~10 MB arrays, and the same work in chunks took 76 instead of 111-114 ms (the largest recorded
#: call of sbc-s68 of benchmarks/quantization_regime.py, 2026-11-25); each element's numbers are its
#: own either way
_QG_CHUNK_POINTS = 131072


def _grid_moments(delta, s, so, at, M, V, E4, H):
    """The grid branch of :func:`_quantized_pixel_moments` for the elements ``at`` (grid size ``M``),
    written into ``V``, ``E4``, ``H``."""
    dl, sg, sog = delta[at], s[at], so[at]
    x = _QG_GRIDS[M]
    # the moments at the grid's offsets (the grid's harmonics computed once, not per element)
    m, v, m4 = _rounded_normal_moments(x, sg[:, None], J=5)
    h = m - x                                   # rounding bias of a pixel's mean
    w = _wrapped_normal_grid(dl, sog, M)        # wrapped normal on the grid
    V[at] = (w * v).sum(-1)
    E4[at] = (w * (m4 + v * v)).sum(-1)
    eh = (w * h).sum(-1)
    var_h = np.maximum((w * h * h).sum(-1) - eh * eh, 0.0)
    # Stein: cov(o, h(o)) = σ_o² E[h'(o)], E[h'] = Σ_b N(b; δ, τ²) − 1 (τ² = s² + σ_o²)
    tau = np.sqrt(sg * sg + sog * sog)
    zz = (_QG_J + 0.5 - dl[:, None]) / tau[:, None]
    dens = np.exp(-0.5 * zz * zz).sum(-1) / (tau * np.sqrt(2.0 * np.pi))
    dens = np.where(tau > 1.0, 1.0, dens)       # |Σ − 1| < 3e-9 beyond
    H[at] = var_h + 2.0 * sog * sog * (dens - 1.0)


_UNIFORM_TABLE = {}

#: :func:`_uniform_offset_moments`'s table as shipped (built by :func:`_build_uniform_offset_table`;
#: rebuild it with ``python -c "from bayescap.model import write_uniform_offset_table as w; w()"``
#: after changing that function). Building it costs ~0.18 s, paid by the first fit in a process
#: that needs it: a fast fit of sim05 of ``benchmarks/speed_accuracy.py`` took 411 ms in a new
#: process against 216 ms after. Loading it costs ~1 ms; ``tests/test_calibration_terms.py``
#: checks the file against a fresh build.
UNIFORM_TABLE_FILE = Path(__file__).with_name("_uniform_offset_table.npz")


def _build_uniform_offset_table():
    """:func:`_uniform_offset_moments`'s table: 1 024 log-spaced s from 10⁻³ to 0.75 DN and, for
    each, the logarithms of V and E4 as integrals over one period of the offset, centred on a DN
    boundary, where the integrands live (256-point Gauss–Legendre over ±min(½, 12 s) DN)."""
    ls = np.linspace(np.log(1e-3), np.log(0.75), 1024)
    sg = np.exp(ls)
    u, wu = np.polynomial.legendre.leggauss(256)
    a = np.minimum(0.5, 12.0 * sg)[:, None]          # beyond ±12 s from the boundary v = 0
    x = 0.5 + a * u                                   # offsets about the boundary at ½ DN
    x = x - np.round(x)
    _, v, m4 = _rounded_normal_moments(x, sg[:, None], J=5)
    w = a * wu                                        # ∫ over one period of length 1
    return {"ls": ls, "lv": np.log((w * v).sum(-1)), "le4": np.log((w * (m4 + v * v)).sum(-1))}


def write_uniform_offset_table(path=None):
    """Write :func:`_build_uniform_offset_table` to ``path`` (default :data:`UNIFORM_TABLE_FILE`)."""
    path = Path(path) if path is not None else UNIFORM_TABLE_FILE
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **_build_uniform_offset_table())
    os.replace(tmp, path)


def _uniform_offset_table():
    """The shipped table (:data:`UNIFORM_TABLE_FILE`), or a fresh build when the file is missing or
    not the expected shape; cached for the process."""
    if not _UNIFORM_TABLE:
        table = None
        try:
            with np.load(UNIFORM_TABLE_FILE) as z:
                table = {k: np.array(z[k], float) for k in ("ls", "lv", "le4")}
            if any(v.shape != (1024,) or not np.all(np.isfinite(v)) for v in table.values()):
                table = None
        except (OSError, KeyError, ValueError):
            table = None
        _UNIFORM_TABLE.update(table if table is not None else _build_uniform_offset_table())
    return _UNIFORM_TABLE


def _uniform_offset_moments(s):
    """(V, E4, H) of :func:`_quantized_pixel_moments` for offsets uniform modulo 1 DN (σ_o > 0.7):
    functions of s alone, tabulated once (:func:`_build_uniform_offset_table`, shipped as
    :data:`UNIFORM_TABLE_FILE`: 1 024 points, log-spaced s from 10⁻³ to 0.75 DN; linear
    interpolation in log s, relative error < 2e-5) — H = s² + 1/12 − V (Sheppard's total variance,
    split into the temporal part and the means')."""
    t = _uniform_offset_table()
    ls = np.log(np.clip(s, 1e-3, 0.75))
    V = np.exp(np.interp(ls, t["ls"], t["lv"]))
    E4 = np.exp(np.interp(ls, t["ls"], t["le4"]))
    return V, E4, s * s + 1.0 / 12.0 - V


@dataclass(frozen=True)
class ModelTerms:
    """Which terms the data can inform, and why the others are left out."""

    dark_current: bool
    clip: str  # "none" | "adc" (fixed at the ADC maximum) | "adc_sampled" | "well"
    clip_spread: bool
    quantum_efficiency: bool
    prnu: bool
    dsnu: bool
    robust: bool = True
    discrepancy: bool = True
    reasons: dict = field(default_factory=dict)  # term -> why it is left out
    how: dict = field(default_factory=dict)      # term -> how an included term enters (caveats)

    def names(self) -> list[str]:
        out = ["photon_shot", "read"]
        out.append("dark_current_shot" if self.dark_current else "read_plus_dark_combined")
        out.append("quantization")
        if self.prnu:
            out.append("prnu")
        if self.dsnu:
            out.append("dsnu")
        if self.clip != "none":
            out.append("saturation")
        if self.discrepancy:
            out.append("variance_discrepancy")
        if self.robust:
            out.append("outlier_mixture")
        if self.quantum_efficiency:
            out += ["quantum_efficiency", "mean_discrepancy"]
        return out


def saturation_flags(d: PTCData):
    """Rows fully clipped (plateau at the top of the series) and whether saturation is reached.

    A row is fully clipped when ``frac_saturated`` ≥ 0.999, or when its mean sits at the top of
    the series and its temporal variance has collapsed below a tenth of the peak variance (a
    well that clips before the read-out keeps only read noise there)."""
    check_not_all_saturated(d)   # every row on the plateau: an input error, not a fit
    v, m = d.temporal_var_dn2, d.mean_dn
    vmax = float(v.max())
    top = m >= m.max() - max(1.0, 1e-4 * m.max())
    full = top & (v < 0.1 * vmax)
    if np.any(full):
        # only rows at the plateau's own variance level (not partly clipped rows beside it)
        # (within 10 % of the plateau minimum: a row whose variance is higher still has unclipped
        # pixels — classified as fully clipped it was modelled with the read noise alone, 15–40
        # standard errors off on simulated well-clipped sensors, and inflated f; the clip-row
        # model describes it)
        v_pl = float(np.min(v[full]))
        full = full & (v <= 1.1 * v_pl + 0.01)
    partial = np.zeros_like(full)
    if d.frac_saturated is not None:
        full = full | (d.frac_saturated >= 0.999)
        partial = (d.frac_saturated > 0) & ~full
    if np.all(full):
        raise PTCInputError("every row is saturated (at the plateau's mean and variance): no row lies on "
                            "the photon-transfer curve; add exposures below saturation",
                            path=d.source, column="mean_dn")
    i_peak = int(np.argmax(np.where(full, -np.inf, v)))
    above = (~full) & (np.arange(v.size) > i_peak)
    turnover = bool(np.any(above & (v < 0.8 * v[i_peak])))
    adc = d.adc_max_dn
    near_adc = False
    if adc is not None:
        nf = ~full
        if np.any(nf):
            near_adc = bool(np.any(m[nf] + 4.0 * np.sqrt(v[nf]) >= adc))
    reached = bool(np.any(full) or np.any(partial) or turnover or near_adc)
    return full, reached


def _clip_mechanism(d: PTCData, full, reached):
    """How the output clips: at the ADC maximum (everything clipped, plateau variance ≈ 0), or
    at the full well before the read-out (plateau keeps the read noise)."""
    adc = d.adc_max_dn
    if not reached:
        return "none", None
    if np.any(full):
        plateau_m = d.mean_dn[full]
        plateau_v = d.temporal_var_dn2[full]
        if adc is not None and np.all(plateau_m >= adc - 0.5):
            return "adc", (f"the fully clipped rows sit at the ADC maximum {adc:g} DN: the clip level "
                           "is the ADC's, and the photodiode's own well may be deeper")
        dark_v = float(np.median(d.dark_temporal_var_dn2))
        if np.median(plateau_v) >= 0.3 * dark_v:
            return "well", ("the plateau keeps the read noise: the full well clips before the read-out; "
                            "its variance also informs the read noise")
        return "adc_sampled", "the plateau has no noise left: an ADC-like clip at a fitted level"
    if adc is not None:
        nf = ~full
        if np.any(d.mean_dn[nf] + 4.0 * np.sqrt(d.temporal_var_dn2[nf]) >= adc):
            return "adc", f"the top rows approach the ADC maximum {adc:g} DN"
        return "well", "the variance turns over below the ADC maximum: the full well clips first"
    return "adc_sampled", "the variance turns over: a clip at a fitted level"


def select_terms(d: PTCData, *, force: dict | None = None) -> ModelTerms:
    """Decide from the data which terms enter the fit (module docstring), with reasons."""
    reasons, how = {}, {}
    t = d.exposure_time_s
    t_pos = t[t > 0]
    with np.errstate(over="ignore"):     # a subnormal exposure time: the ratio is inf, still ≥ 1.5
        multi_t = t_pos.size >= 2 and (t_pos.max() / t_pos.min() >= 1.5)
    if not multi_t:
        reasons["dark_current"] = ("all rows share one exposure time: only read² + D·t is "
                                   "identifiable (reported as dark_noise_e)")
    full, reached = saturation_flags(d)
    clip, why = _clip_mechanism(d, full, reached)
    if clip == "none":
        reasons["saturation"] = ("no row approaches saturation: the full well is reported as a "
                                 "lower bound (the largest measured signal)")
    else:
        how["saturation"] = why
    # partially clipped rows need the spread of pixel means about the clip
    clip_spread = clip != "none"
    qe = d.photons_per_pixel is not None
    if not qe:
        reasons["quantum_efficiency"] = "no photons_per_pixel column"
    prnu = d.spatial_var_dn2 is not None and np.any(np.isfinite(d.spatial_var_dn2))
    dsnu = (d.dark_spatial_var_dn2 is not None and np.any(np.isfinite(d.dark_spatial_var_dn2))) or prnu
    if not prnu:
        reasons["prnu"] = "no spatial_var_dn2 column: pair differences cancel fixed-pattern noise"
    if not dsnu:
        reasons["dsnu"] = "no dark_spatial_var_dn2 column: pair differences cancel fixed-pattern noise"
    terms = dict(dark_current=multi_t, clip=clip, clip_spread=clip_spread, quantum_efficiency=qe,
                 prnu=prnu, dsnu=dsnu)
    if force:
        terms.update(force)
    return ModelTerms(**terms, reasons=reasons, how=how)


class PTCModel:
    """Posterior density of the noise-model parameters for one PTCData.

    Sampling coordinates are unconstrained (logs of scales) with the Jacobians in the priors;
    :meth:`log_prob` takes an array ``(n_walkers, n_dim)`` and returns ``(n_walkers,)``.
    :meth:`physical` maps draws to named physical parameters.
    """

    #: prior scales (see README, "Priors"). The ``*_log_bounds`` / ``qe_bounds`` entries are
    #: ``None`` in production (half-normal scale priors, QE uniform on (0, 1]); a pair
    #: ``(lo, hi)`` of *natural* values replaces the half-normal by a log-uniform prior on
    #: [lo, hi] (QE: uniform on [lo, hi]). Override per model with ``PTCModel(data, prior={...})``
    #: or ``bayescap.fit(..., prior={...})``; ``benchmarks/sbc.py`` does so to fit with exactly
    #: the prior it draws its true sensors from (classic SBC).
    PRIOR = dict(log_k_bounds=(np.log(1e-4), np.log(1e4)), read_scale_e=1000.0,
                 dark_current_scale_e_per_s=1e4, prnu_scale=0.05, dsnu_scale_e=100.0,
                 f_center=0.01, f_log_sd=1.5, g_center=0.005, g_log_sd=1.5,
                 tau_log_sd=1.5, tau_max_frac=0.02,
                 read_log_bounds=None, dark_current_log_bounds=None, prnu_log_bounds=None,
                 dsnu_log_bounds=None, qe_bounds=None)

    def __init__(self, data: PTCData, terms: ModelTerms | None = None, prior: dict | None = None):
        self.data = data
        self.terms = terms or select_terms(data)
        # results computed once per model (initial_guess, the observation count), shared by its
        # shallow copies (bayescap.batch._with_log_prob; a PTCModelStack view gets its own)
        self._memo = {}
        if prior:
            unknown = set(prior) - set(PTCModel.PRIOR)
            if unknown:
                raise ValueError(f"unknown prior keys {sorted(unknown)}; known: {sorted(PTCModel.PRIOR)}")
            self.PRIOR = {**PTCModel.PRIOR, **prior}  # instance attribute: the class default stays
        d, tm = data, self.terms
        self.full_sat, self.saturation_reached = saturation_flags(d)
        ok = ~self.full_sat
        self.rows = np.nonzero(ok)[0]
        self.t = d.exposure_time_s
        self.adc = d.adc_max_dn
        self.black_dn = float(d.dark_mean_dn[np.argmin(d.exposure_time_s)])
        names = ["log_k"]
        names.append("log_read" if tm.dark_current else "log_dark_noise")
        if tm.dark_current:
            names.append("log_dc")
        m_ok = d.mean_dn[ok]
        v_ok = d.temporal_var_dn2[ok]
        self.max_mean_ok = float(m_ok.max())
        if tm.clip in ("adc_sampled", "well"):
            names.append("clip_dn")
            lo = self.max_mean_ok + 1e-6 * max(1.0, self.max_mean_ok)
            if np.any(self.full_sat):
                hi = float(d.mean_dn[self.full_sat].max()) + 10.0 * np.sqrt(max(v_ok.max(), 1.0))
            else:
                hi = self.adc if self.adc is not None else 2.0 * self.max_mean_ok
                hi = max(hi, lo * 1.05)
            if self.adc is not None:
                hi = min(hi, self.adc + 0.5)
            self.clip_bounds = (lo, max(hi, lo + 1e-3))
        elif tm.clip == "adc":
            self.clip_bounds = (self.adc, self.adc)
        else:
            self.clip_bounds = None
        if tm.clip_spread:
            names.append("log_tau")
        if tm.quantum_efficiency:
            names += ["qe", "log_g"]
        if tm.prnu:
            names.append("log_prnu")
        if tm.dsnu:
            names.append("log_dsnu")
        # the ROI's realised fixed patterns (see _pattern_moments): standard-normal latents
        self.pattern_latents = []
        if tm.dsnu:
            self.pattern_latents.append("z_roi_dsnu")
        if tm.prnu:
            self.pattern_latents += ["z_roi_prnu", "z_roi_cross"]
        names += self.pattern_latents
        if tm.discrepancy:
            names.append("log_f")
        self.names = names
        self.ndim = len(names)
        self.idx = {n: i for i, n in enumerate(names)}
        # data arrays (non-fully-clipped rows)
        self.m = d.mean_dn[ok]
        self.v = np.maximum(d.temporal_var_dn2[ok], 1e-6)
        self.vd = np.maximum(d.dark_temporal_var_dn2, 1e-6)
        self.dm = d.dark_mean_dn[ok]
        self.tt = self.t[ok]
        self.nu = d.n_pixels[ok] - 1.0
        self.nu_d = d.n_pixels - 1.0
        self.s_obs = self.m - self.dm
        # rows near enough to a possible clip level to need the clipped-moment model
        if self.clip_bounds is not None:
            tau_max = self.PRIOR["tau_max_frac"] * self.clip_bounds[1]
            reach = self.m + 8.0 * np.sqrt(self.v + tau_max**2)
            self.clip_rows = np.nonzero(reach >= self.clip_bounds[0])[0]
        else:
            self.clip_rows = np.zeros(0, int)
        self.lin_rows = np.setdiff1d(np.arange(self.m.size), self.clip_rows)
        if tm.quantum_efficiency:
            self.mu_p = d.photons_per_pixel[ok]
        # fully clipped rows: their mean locates a sampled clip level
        self.full_means = d.mean_dn[self.full_sat]
        self.full_v = d.temporal_var_dn2[self.full_sat]
        self.full_nu = d.n_pixels[self.full_sat] - 1.0
        self.t_full = self.t[self.full_sat]
        self.vd_ok = self.vd[~self.full_sat]
        self.full_sd = np.sqrt(d.temporal_var_dn2[self.full_sat] / d.n_pixels[self.full_sat]
                               + (1e-4 * np.maximum(self.full_means, 1.0)) ** 2 + 0.01**2)
        # spatial rows
        self.sp_rows = np.zeros(0, int)
        self.spd_rows = np.zeros(0, int)
        if tm.prnu and d.spatial_var_dn2 is not None:
            sp = d.spatial_var_dn2[ok]
            self.sp_rows = np.setdiff1d(np.nonzero(np.isfinite(sp))[0], self.clip_rows)
            self.sp = sp
        if tm.dsnu and d.dark_spatial_var_dn2 is not None:
            self.spd_rows = np.nonzero(np.isfinite(d.dark_spatial_var_dn2))[0]
            self.spd = d.dark_spatial_var_dn2
        nfr = d.n_frames if d.n_frames is not None else np.full(d.n_levels, 2.0)
        nfr = np.where(np.isfinite(nfr), nfr, 2.0)
        self.L_ok = nfr[ok]
        self.L_all = nfr
        # degrees of freedom of the ROI's pattern sample variance (one ROI for every spatial row)
        sp_any = np.zeros(d.n_levels, bool)
        for col in (d.spatial_var_dn2, d.dark_spatial_var_dn2):
            if col is not None:
                sp_any |= np.isfinite(col)
        self.nu_pattern = float(np.median(d.n_pixels[sp_any]) - 1.0) if np.any(sp_any) else float(np.median(d.n_pixels) - 1.0)
        # fractional offsets of the measured means from the nearest integer DN (quantization)
        self.dark_frac_dn = d.dark_mean_dn - np.round(d.dark_mean_dn)
        self.bright_frac_dn = self.m - np.round(self.m)
        self.full_frac_dn = self.full_means - np.round(self.full_means)

    # ------------------------------------------------------------------ parameters
    def physical(self, theta) -> dict:
        """Named physical parameters for draws ``theta`` (n, ndim)."""
        th = np.atleast_2d(theta)
        g = lambda n: th[:, self.idx[n]]  # noqa: E731
        k = np.exp(g("log_k"))
        out = {"conversion_gain_e_per_dn": k}
        if self.terms.dark_current:
            out["read_noise_e"] = np.exp(g("log_read"))
            out["dark_current_e_per_s"] = np.exp(g("log_dc"))
        else:
            out["dark_noise_e"] = np.exp(g("log_dark_noise"))
        if self.terms.clip in ("adc_sampled", "well"):
            c = g("clip_dn")
        elif self.terms.clip == "adc":
            c = np.full(th.shape[0], self.adc)
        else:
            c = None
        if c is not None:
            out["clip_dn"] = c
            out["full_well_e"] = (c - self.black_dn) * k
        if self.terms.clip_spread:
            out["clip_spread_dn"] = np.exp(g("log_tau"))
        if self.terms.quantum_efficiency:
            out["quantum_efficiency"] = g("qe")
            out["mean_discrepancy"] = np.exp(g("log_g"))
        if self.terms.prnu:
            out["prnu_percent"] = 100.0 * np.exp(g("log_prnu"))
        if self.terms.dsnu:
            out["dsnu_e"] = np.exp(g("log_dsnu"))
        out["variance_discrepancy"] = np.exp(g("log_f")) if self.terms.discrepancy else np.zeros(th.shape[0])
        return out

    def dark_var_e2(self, p, t):
        """σ_read² + D·t (e⁻²) for each draw at exposure times t: shape (n_draws, n_t)."""
        t = np.atleast_1d(np.asarray(t, float))
        if self.terms.dark_current:
            return p["read_noise_e"][:, None] ** 2 + p["dark_current_e_per_s"][:, None] * t
        return np.broadcast_to(p["dark_noise_e"][:, None] ** 2, (p["dark_noise_e"].size, t.shape[-1]))

    # ------------------------------------------------------------------ prior
    def _clip_reference_dn(self, th):
        """The clip level the clip spread's prior refers to, per draw: the sampled ``clip_dn``, or
        the ADC maximum when the ADC clips at a known level."""
        if "clip_dn" in self.idx:
            return th[:, self.idx["clip_dn"]]
        return np.full(th.shape[0], self.adc, dtype=float)

    def tau_cap_dn(self, th):
        """Upper bound of the clip spread τ (DN) in the prior, per draw: ``tau_max_frac`` of
        :meth:`_clip_reference_dn` (a wall: log prior −∞ beyond it)."""
        return self.PRIOR["tau_max_frac"] * self._clip_reference_dn(np.atleast_2d(th))

    #: request ids of the draws in a call (a PTCModelStack's view sets them): reductions over
    #: "the draws of this call" are then per request, so a sensor's numbers do not depend on which
    #: other sensors share the call
    _request_ids = None
    _request_segments = None

    def _request_reduce(self, ufunc, a):
        """``ufunc.reduce`` of ``a`` (n,) over the draws of one request: a scalar for a single
        model; per draw (n,) for a stacked view."""
        if self._request_ids is None:
            return ufunc.reduce(a)
        if self._request_segments is None:     # the requests' starts and sizes, once per view
            ids = self._request_ids
            starts = np.flatnonzero(np.concatenate(([True], ids[1:] != ids[:-1])))
            self._request_segments = (starts, np.diff(np.append(starts, ids.size)))
        starts, sizes = self._request_segments
        return np.repeat(ufunc.reduceat(a, starts), sizes)

    @staticmethod
    def _per_draw(x):
        """A per-sensor number as a column for (n_draws, rows) arithmetic: scalars unchanged,
        per-draw arrays (n,) of a stacked view as (n, 1)."""
        return x if np.ndim(x) == 0 else np.asarray(x)[:, None]

    def log_prior(self, th):
        P = self.PRIOR
        g = lambda n: th[:, self.idx[n]]  # noqa: E731
        lk = g("log_k")
        lp = np.where((lk > P["log_k_bounds"][0]) & (lk < P["log_k_bounds"][1]), 0.0, -np.inf)
        if self.terms.dark_current:
            lp = lp + _scale_log_prior(g("log_read"), P["read_scale_e"], P["read_log_bounds"])
            lp = lp + _scale_log_prior(g("log_dc"), P["dark_current_scale_e_per_s"], P["dark_current_log_bounds"])
        else:
            lp = lp + _halfnormal_log_prior(g("log_dark_noise"), P["read_scale_e"])
        if self.terms.clip in ("adc_sampled", "well"):
            c = g("clip_dn")
            lo, hi = self.clip_bounds
            lp = lp + np.where((c > lo) & (c < hi), -np.log(hi - lo), -np.inf)
        if self.terms.clip_spread:
            cref = self._clip_reference_dn(th)
            lt = g("log_tau")
            center = np.log(0.005 * np.maximum(cref - self.black_dn, 1.0))
            lp = lp + _norm_logpdf(lt, center, P["tau_log_sd"])
            lp = lp + np.where(np.exp(lt) < self.tau_cap_dn(th), 0.0, -np.inf)
        if self.terms.quantum_efficiency:
            qe = g("qe")
            qlo, qhi = P["qe_bounds"] if P["qe_bounds"] is not None else (0.0, 1.0)
            lp = lp + np.where((qe > qlo) & (qe <= qhi), 0.0, -np.inf)
            lp = lp + _norm_logpdf(g("log_g"), np.log(P["g_center"]), P["g_log_sd"])
        if self.terms.prnu:
            lp = lp + _scale_log_prior(g("log_prnu"), P["prnu_scale"], P["prnu_log_bounds"])
        if self.terms.dsnu:
            lp = lp + _scale_log_prior(g("log_dsnu"), P["dsnu_scale_e"], P["dsnu_log_bounds"])
        for n in self.pattern_latents:
            lp = lp - 0.5 * g(n) ** 2  # standard normal (constant dropped)
        if self.terms.discrepancy:
            lp = lp + _norm_logpdf(g("log_f"), np.log(P["f_center"]), P["f_log_sd"])
        return lp

    # ------------------------------------------------------------------ fixed patterns
    def _pattern_moments(self, th, p):
        """Sample (co)variances of the ROI's *realised* fixed patterns, for draws ``th``.

        The PRNU map p_i (fraction) and the DSNU map d_i (e⁻) are one realisation, shared by
        every spatial row. Over n pixels (ν = n − 1) their sample covariance matrix is
        Wishart(ν, diag(PRNU², DSNU²))/ν; by Bartlett's decomposition with standard-normal
        latents z₁ (``z_roi_prnu``), z₂ (``z_roi_dsnu``), z₃ (``z_roi_cross``):

            var_s(p)   = PRNU² · χ²_ν/ν (z₁)
            var_s(d)   = DSNU² · [(ν−1)·χ²_{ν−1}/(ν−1) (z₂) + z₃²]/ν
            cov_s(p,d) = PRNU·DSNU · √(χ²_ν/ν (z₁)) · z₃/√ν

        Returns (var_s(p), var_s(d) [e⁻²], cov_s(p, d) [e⁻]), each (n_draws, 1)."""
        nu = self.nu_pattern
        n = th.shape[0]
        zero = np.zeros((n, 1))
        a = b = c = zero
        if self.terms.dsnu:
            dsnu2 = (p["dsnu_e"] ** 2)[:, None]
            z2 = th[:, self.idx["z_roi_dsnu"]][:, None]
            if self.terms.prnu:
                prnu = (p["prnu_percent"] / 100.0)[:, None]
                z1 = th[:, self.idx["z_roi_prnu"]][:, None]
                z3 = th[:, self.idx["z_roi_cross"]][:, None]
                q1 = _chi2_over_nu(z1, nu)
                a = prnu**2 * q1
                # (χ²₀ = 0: with two pixels, ν = 1, the DSNU's sample variance is z₃² alone; ν is an
                # array of one per sensor in a PTCModelStack)
                rest = np.where(nu > 1.0, (nu - 1.0) * _chi2_over_nu(z2, np.maximum(nu - 1.0, 1.0)), 0.0)
                b = dsnu2 * (rest + z3 * z3) / nu
                c = prnu * np.sqrt(dsnu2) * np.sqrt(q1) * z3 / np.sqrt(nu)
            else:
                b = dsnu2 * _chi2_over_nu(z2, nu)
        return a, b, c

    def _quantized_var(self, s2, frac, spread2):
        """Quantization of the temporal variance, and of the fixed pattern, for every draw and row.

        ``s2`` (n_draws, rows): temporal variance before rounding (DN²); ``frac`` (rows,): the
        measured mean's offset from the nearest integer DN; ``spread2`` (n_draws, 1 or rows):
        variance σ_o² of the per-pixel mean offsets (fixed patterns, well spread).

        Returns ``(var, phi, excess)``: the pixel-averaged temporal variance of the rounded values,
        the factor φ of its sampling variance (relative variance of a pair estimate over n pixels
        = φ/ν; 2 for a normal), and the excess of the per-pixel means' spatial variance over σ_o²
        that rounding adds (what a spatial variance of frame averages sees besides σ_o²).
        Sheppard's s² + 1/12, φ = 2 and no excess where s² ≥ 0.2 DN² and s² + σ_o² ≥ ½ DN²
        (relative errors < 3e-4, below the ≥ 0.4 % sampling error of a variance over ≤ 10⁵
        pixels); elsewhere the exact moments of :func:`_quantized_pixel_moments`."""
        var = s2 + 1.0 / 12.0
        phi = np.full_like(var, 2.0)
        excess = np.zeros_like(var)
        sp2 = np.maximum(np.broadcast_to(spread2, s2.shape), 0.0)
        need = (s2 < _QUANT_TEMPORAL_S2) | (s2 + sp2 < _QUANT_EXACT_S2)
        if not np.any(need):
            return var, phi, excess
        s = np.sqrt(np.maximum(s2[need], 1e-8))
        so = np.sqrt(sp2[need])
        fr = np.broadcast_to(frac, s2.shape)[need]
        delta = _rounded_offset(fr, np.sqrt(s * s + so * so))
        V, E4, H = _quantized_pixel_moments(delta, s, so)
        # the measured variances are floored at 1e-6 DN² (a sample with no differing pixel): so is
        # the model, which otherwise penalises a ratio 1e-6/1e-12 for identical "zero" data
        V = np.maximum(V, 1e-6)
        var[need] = V
        phi[need] = E4 / (2.0 * V * V)
        excess[need] = H
        return var, phi, excess

    # ------------------------------------------------------------------ likelihood
    def _clip_moments(self, mu, s, tau, c):
        """Mean, within-pixel variance and unclipped fraction of clip(N(mu + τξ, s²), c), averaged
        over the well spread ξ ~ N(0, 1), all in closed form. Shapes broadcast.

        The mean and the unclipped fraction (= dmean/dmu) are :meth:`_clip_mean`'s. The variance
        within a pixel (its temporal noise, clipped), averaged over pixels, is
        E_ξ[E_ε m²] − E_ξ[(E_ε m)²]; the first term is a clipped second moment of N(mu, s'²),
        s'² = s² + τ², and the second the clipped product moment of two readings of one pixel, a
        bivariate normal with correlation ρ = τ²/s'². With h = (c − mu)/s' and
        k = √((1 − ρ)/(1 + ρ)):

            var = s'² [(h² + 1) Φ(h) + h φ(h) − (h² + ρ) Φ₂(h, h; ρ) − 2 h φ(h) Φ(h k)
                       − √(1 − ρ²)/(2π) exp(−h²/(1 + ρ))],   Φ₂(h, h; ρ) = Φ(h) − 2 T(h, k)

        (T: Owen's T function). The 9-node Gauss–Hermite sum over ξ used before was off by
        5.3e-3 s² at τ = 2 s and 0.12 s² at τ = 10 s; this agrees with an 8 001-point sum to
        1e-10 s² for τ/s up to 100 (``tests/test_model.py``) and costs a third. Returns (mean,
        var, unclipped fraction)."""
        mu, s, tau, c = np.broadcast_arrays(mu, s, tau, c)
        s2 = s * s
        sp2 = np.maximum(s2 + tau * tau, 1e-300)
        sp = np.sqrt(sp2)
        d = c - mu
        h = d / sp
        Ph = ndtr(h)
        ph = np.exp(-0.5 * h * h) * 0.3989422804014327
        mean = c - d * Ph - sp * ph          # _clip_mean's, from the same h
        # more than 8.5 s' below the clip nothing is clipped to double precision: the temporal
        # variance itself (the difference below loses digits as h² grows). The bivariate part
        # (Owen's T, ~85 ns an element) is evaluated only where it is kept.
        var = np.array(s2, dtype=float)      # a copy, also for 0-d input
        w = ~(h > 8.5)
        if w.any():
            hw, phw, Phw, rho = h[w], ph[w], Ph[w], tau[w] * tau[w] / sp2[w]
            k = np.sqrt((1.0 - rho) / (1.0 + rho))
            P2 = Phw - 2.0 * owens_t(hw, k)
            M = ((hw * hw + rho) * P2 + 2.0 * hw * phw * ndtr(hw * k)
                 + np.sqrt(1.0 - rho * rho) * 0.15915494309189535 * np.exp(-hw * hw / (1.0 + rho)))
            var[w] = np.maximum(sp2[w] * ((hw * hw + 1.0) * Phw + hw * phw - M), 0.0)
        return mean, var, Ph

    def predict(self, th):
        """Model predictions per observation block, for draws ``th`` (n, ndim).

        Returns ``{block: (observed, model, spread, kind)}``: for ``kind == "gamma"`` the
        spread is the shape ``k`` (the observed value ~ Gamma(k, model/k)); for
        ``"normal"`` it is the standard deviation. Blocks: ``dark_var`` (every row),
        ``bright_var`` and ``mean`` (rows not fully clipped), ``clip_mean`` (fully clipped rows,
        sampled clip), ``spatial_var``/``dark_spatial_var`` (rows with spatial columns)."""
        p = self.physical(th)
        k = p["conversion_gain_e_per_dn"]
        K = k[:, None]
        if self.terms.discrepancy:
            f2 = np.exp(2.0 * th[:, self.idx["log_f"]])[:, None]
        else:
            f2 = np.zeros((th.shape[0], 1))
        rd2_ok = self.dark_var_e2(p, self.tt)  # (n, rows)
        rd2_all = self.dark_var_e2(p, self.t)
        out = {}
        pa, pb, pc = self._pattern_moments(th, p)  # realised ROI patterns (zeros without the terms)
        # dark temporal variances (all rows); rounding at the measured offset below 1 DN
        vdm, phi_d, hd = self._quantized_var(rd2_all / (K * K), self.dark_frac_dn, pb / (K * K))
        out["dark_var"] = (self.vd, vdm, 1.0 / (phi_d / self.nu_d + f2), "gamma")
        # bright temporal variances, unclipped rows: S from the measured mean
        S = np.broadcast_to(self.s_obs, rd2_ok.shape).copy()
        vm, phi_b, hb = self._quantized_var(S / K + rd2_ok / (K * K), self.bright_frac_dn,
                                        pa * S * S + pb / (K * K) + 2.0 * pc * S / K)
        slope = np.ones_like(vm)
        if self.clip_rows.size:
            c = p["clip_dn"]
            tau = p["clip_spread_dn"]
            # rows more than 8.5 sd of N(mean, s² + τ²) below the clip for every draw are unclipped
            # to double precision (_clip_mean): keep only the others. (The rule of the 9-node
            # quadrature, 8.5 s + 4.52 τ, let rows with τ ≫ s in at h ≈ 4.5: a clipped fraction 3e-6)
            # (bounds over each sensor's draws: over all draws here, per request in a PTCModelStack)
            k_min, c_min, tau_max = (self._per_draw(self._request_reduce(f, a)) for f, a in
                                     ((np.minimum, k), (np.minimum, c), (np.maximum, tau)))
            cr = self.clip_rows
            s_est = np.sqrt(self.v[..., cr] + self.s_obs[..., cr] / k_min)
            alpha_min = (c_min - self.m[..., cr]) / np.sqrt(s_est**2 + tau_max**2)
            need = alpha_min < 8.5
            needed = need if need.ndim == 1 else need.any(axis=0)
            rows = cr[needed]
        if self.clip_rows.size and rows.size:
            # stacked sensors: a row one sensor needs is computed for all, kept where needed
            keep = None if need.ndim == 1 else need[:, needed]
            keep = None if keep is None or keep.all() else keep
            put = (lambda new, old: new) if keep is None else (lambda new, old: np.where(keep, new, old))
            if self.terms.clip == "well":
                # the well clips the collected charge; read noise and quantization come after
                dc_e2 = (p["dark_current_e_per_s"][:, None] * self.tt[..., rows]
                         if self.terms.dark_current else np.zeros((k.size, rows.size)))
                pre = dc_e2 / (K * K)
                post = (rd2_ok[:, rows] - dc_e2) / (K * K) + 1.0 / 12.0
                mu, var_c, sl = self._latent_clip_rows(k, pre, tau, c, rows)
                vm[:, rows] = put(var_c + post, vm[:, rows])
            else:
                # the ADC clips everything; quantization survives only for the unclipped pixels
                mu, var_c, sl = self._latent_clip_rows(k, rd2_ok[:, rows] / (K * K), tau, c, rows)
                vm[:, rows] = put(var_c + sl / 12.0, vm[:, rows])
            S[:, rows] = put(mu - self.dm[..., rows], S[:, rows])
            slope[:, rows] = put(sl, slope[:, rows])
        out["bright_var"] = (self.v, np.maximum(vm, 1e-12), 1.0 / (phi_b / self.nu + f2), "gamma")
        self._last_latent_signal_dn = S
        if self.terms.quantum_efficiency:
            qe = p["quantum_efficiency"][:, None]
            g2 = p["mean_discrepancy"][:, None] ** 2
            s_model = qe * self.mu_p / K
            m_err2 = (self.v + self.vd_ok) / (self.nu + 1.0)
            sd = np.sqrt(g2 * s_model**2 + m_err2 / np.maximum(slope, 1e-6) ** 2)
            out["mean"] = (S, s_model, sd, "normal")
        if self.terms.clip == "well" and self.full_means.size:
            # plateau rows: charge at the (spread) well; read noise and quantization remain
            post_full = self.dark_var_e2(p, self.t_full)
            if self.terms.dark_current:
                post_full = post_full - p["dark_current_e_per_s"][:, None] * self.t_full
            tau_full = np.broadcast_to(p["clip_spread_dn"][:, None], post_full.shape)
            # rounding of the plateau values: exact below the quantization floor (offsets spread by
            # the well spread τ), Sheppard above
            vfull, phi_pl, _ = self._quantized_var(post_full / (K * K), self.full_frac_dn, tau_full**2)
            cmean = np.broadcast_to(p["clip_dn"][:, None], vfull.shape)
            if self.adc is not None:
                # the ADC clips the plateau's read noise too (wells just below the ADC maximum):
                # moments of clip(N(c + τξ, σ²_post), ADC) over the well spread ξ
                cm, cv, unclipped = self._clip_moments(
                    np.array(cmean), np.sqrt(post_full) / K, tau_full,
                    np.broadcast_to(self._per_draw(self.adc), vfull.shape).astype(float))
                # only where the ADC clips a measurable part (keeps the exact rounding otherwise)
                clipped = unclipped < 1.0 - 1e-9
                vfull = np.where(clipped, cv + unclipped / 12.0, vfull)
                cmean = cm
            out["plateau_var"] = (np.maximum(self.full_v, 1e-6), np.maximum(vfull, 1e-6),
                                  1.0 / (phi_pl / self.full_nu + f2), "gamma")
        else:
            cmean = None
        if self.terms.clip in ("adc_sampled", "well") and self.full_means.size:
            if cmean is None:
                cmean = np.broadcast_to(p["clip_dn"][:, None], (k.size, self.full_means.size))
            out["clip_mean"] = (self.full_means, cmean, np.atleast_2d(self.full_sd), "normal")
        # spatial variances of L-frame averages: the ROI's realised pattern P (the same in every
        # row, see _pattern_moments) plus the averaged temporal noise T. Given the pattern, only
        # T's sample variance and its sample covariance with the pattern scatter:
        # var = (2T² + 4PT)/ν (+ f² relative)
        if self.sp_rows.size:
            r = self.sp_rows
            Sr = S[:, r]
            # realised pattern, plus what rounding adds to it below the quantization floor
            P = pa * Sr * Sr + pb / (K * K) + 2.0 * pc * Sr / K + hb[:, r]
            T = vm[:, r] / self.L_ok[..., r]
            out["spatial_var"] = (self.sp[..., r], np.maximum(P + T, 1e-12),
                                  self._pattern_shape(P, T, self.nu[..., r], f2), "gamma")
        if self.spd_rows.size:
            r = self.spd_rows
            P = pb / (K * K) + hd[:, r]
            T = vdm[:, r] / self.L_all[..., r]
            out["dark_spatial_var"] = (np.maximum(self.spd[..., r], 1e-9), np.maximum(P + T, 1e-12),
                                       self._pattern_shape(P, T, self.nu_d[..., r], f2), "gamma")
        return out

    @staticmethod
    def _pattern_shape(P, T, nu, f2):
        """Gamma shape of a spatial variance given the realised pattern P and temporal part T."""
        P = np.maximum(P, 0.0)
        rel = (2.0 * T * T + 4.0 * P * T) / (nu * (P + T) ** 2)
        return 1.0 / (rel + f2)

    def _block_loglik(self, name, obs, model, spread, kind, with_outlier_prob=False):
        obs = obs if np.ndim(obs) == 2 else obs[None, :]
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
    BLOCK_COLUMNS = {"dark_var": "dark_temporal_var_dn2", "bright_var": "temporal_var_dn2", "mean": "mean_dn",
                     "clip_mean": "mean_dn", "plateau_var": "temporal_var_dn2", "spatial_var": "spatial_var_dn2",
                     "dark_spatial_var": "dark_spatial_var_dn2"}

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
        matching labels ``[(block, row), ...]`` (for PSIS-LOO)."""
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            terms = self.loglik_terms(th)
        labels, cols = [], []
        for name, ll in terms.items():
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
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for name, blk in (self.predict(th) if pred is None else pred).items():
                if name not in ROBUST_BLOCKS:
                    continue
                _, prob = self._block_loglik(name, *blk, with_outlier_prob=True)
                out[name] = (self.observation_rows(name), np.nanmean(prob, axis=0))
        return out

    def observation_rows(self, block):
        """Data-row labels (1-based file rows) of the observations of a block."""
        d = self.data
        ok = np.nonzero(~self.full_sat)[0]
        idx = {"dark_var": np.arange(d.n_levels), "bright_var": ok, "mean": ok,
               "clip_mean": np.nonzero(self.full_sat)[0], "plateau_var": np.nonzero(self.full_sat)[0],
               "spatial_var": ok[self.sp_rows],
               "dark_spatial_var": self.spd_rows}[block]
        return np.array([d.row_label(i) for i in idx], int)

    @staticmethod
    def _clip_mean(mu, s, tau, c):
        """Mean of clip(N(mu + τξ, s²), c) averaged over ξ ~ N(0, 1), and its derivative in mu.

        Closed form: mu + τξ + sε is N(mu, s² + τ²), and min(a, c − τξ) = min(a + τξ, c) − τξ, so
        the average is the clipped mean of N(mu, s² + τ²) and the derivative its unclipped
        fraction Φ((c − mu)/√(s² + τ²)). The 9-node Gauss–Hermite sum used before was off by
        1.3e-3 s at τ = 2 s and 0.22 s at τ = 10 s (a large well spread, a huge full well; docs/
        performance.md), and cost nine normal CDFs per element."""
        sp = np.sqrt(s * s + tau * tau)
        d = c - mu
        alpha = d / sp
        Phi = ndtr(alpha)
        phi = np.exp(-0.5 * alpha * alpha) * 0.3989422804014327
        return c - d * Phi - sp * phi, Phi

    def _latent_clip_rows(self, k, pre_var_dn2, tau, c, rows):
        """Latent unclipped row means (DN) of the clip rows: solve E[clip(μ)] = measured mean.

        The clipped quantity has variance ``(μ − dark)/K + pre_var_dn2`` (shot noise plus what
        is added before the clip). Written as its shortfall below the clip, the equation is
        ``s' ψ((c − μ)/s') = c − measured mean`` (s'² that variance plus τ², ψ of
        :func:`_log_shortfall`), and its logarithm is concave and decreasing in μ: a Newton step on
        it overshoots the root at most once, from below, and then converges from above (plain
        Newton steps on the clipped mean, used before commit d00d849, approach from below but
        crawl where the root lies deep in the clip: 12 passes on the simulated 1.75 µm sensor,
        now 4).
        The first guess inverts ψ from a table at the variance of the measured mean; steps that
        leave the bracket of the points seen so far bisect it. Returns (μ, variance of the clipped
        values, unclipped fraction = dE/dμ)."""
        m_obs = self.m[..., rows]
        dm = self.dm[..., rows]
        K = k[:, None]
        shape = pre_var_dn2.shape
        cc = np.broadcast_to(c[:, None], shape)
        tt_ = np.broadcast_to(tau[:, None], shape)
        mu = np.broadcast_to(m_obs, shape).copy()
        mu_f = mu.reshape(-1)          # a view: updates land in mu
        # the fixed inputs of each element, one row each, so that dropping the converged elements
        # is one fancy-indexing call instead of six
        P = np.empty((6,) + shape)
        for i, a in enumerate((m_obs, dm, K, pre_var_dn2, tt_, cc)):
            P[i] = a
        P = P.reshape(6, -1)
        idx = np.arange(mu_f.size)
        mu_a = mu_f.copy()
        # first pass, on every element: the clipped mean at the measured mean
        mo_a, dm_a, k_a, pre_a, tau_a, c_a = P
        s = np.sqrt(np.maximum(mu_a - dm_a, 0.0) / k_a + pre_a)
        mean, _ = self._clip_mean(mu_a, s, tau_a, c_a)
        # elements already within 1e-9 of the noise of it (the unclipped rows) stay there
        todo = ~(mo_a - mean < 1e-9 * s)
        if todo.any():
            idx, mu_a, P, s = idx[todo], mu_a[todo], P[:, todo], s[todo]
            mo_a, dm_a, k_a, pre_a, tau_a, c_a = P
            g_obs = c_a - mo_a           # the measured shortfall (≤ 0: no root, μ → ∞)
            pos = g_obs > 0
            with np.errstate(divide="ignore", invalid="ignore"):
                # first guess: ψ inverted at the variance of the measured mean, never below it
                sp = np.sqrt(s * s + tau_a * tau_a)
                guess = c_a - sp * _psi_inverse_guess(np.log(g_obs / sp))
            mu_a = np.where(pos & (guess > mu_a), guess, mu_a)
            lo, hi = mo_a.copy(), np.full(mu_a.size, np.inf)   # the clipped mean is below / above
            with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
                for _ in range(30):
                    mo_a, dm_a, k_a, pre_a, tau_a, c_a = P
                    g_obs = c_a - mo_a
                    s = np.sqrt(np.maximum(mu_a - dm_a, 0.0) / k_a + pre_a)
                    sp = np.sqrt(s * s + tau_a * tau_a)
                    h = np.minimum((c_a - mu_a) / sp, 30.0)
                    # Φ(h) = ½ erfcx(−h/√2) e^{−h²/2} and ψ(h) = e^{−h²/2} (φ(0) + ½ h erfcx(−h/√2)):
                    # one erfcx gives both, without cancellation for h < 0 (:func:`_log_shortfall`)
                    e2 = np.exp(-0.5 * h * h)
                    X = erfcx(-0.7071067811865476 * h)
                    B = 0.3989422804014327 + 0.5 * h * X
                    short = sp * e2 * B
                    gap = short - g_obs          # = measured mean − clipped mean
                    # converged within 1e-9 of the noise and 1e-6 of the shortfall itself (a row
                    # deep in the clip has a shortfall far below the noise; the step taken after
                    # convergence squares that relative error)
                    done = np.abs(gap) < np.where(pos, np.minimum(1e-9 * s, 1e-6 * g_obs), 1e-9 * s)
                    below = gap > 0
                    lo = np.where(below, np.maximum(lo, mu_a), lo)
                    hi = np.where(below, hi, np.minimum(hi, mu_a))
                    # d(clipped mean)/dμ, with the growth of the shot noise with μ
                    slope = np.maximum(e2 * (0.5 * X - 0.3989422804014327 * (mu_a > dm_a) * 0.5 / (k_a * sp)),
                                       1e-300)
                    step_lin = np.minimum(np.maximum(gap / slope, 0.0), 50.0 * (s + tau_a))
                    step_log = (np.log(B) - 0.5 * h * h + np.log(sp / g_obs)) * short / slope
                    new = mu_a + np.where(pos, step_log, step_lin)
                    # a step from within the tolerance is taken too (it lands on the root to
                    # rounding, so the result does not depend on the pass at which an element
                    # converged); one leaving the bracket bisects it, or without an upper end takes
                    # the plain Newton step (which never passes the root)
                    out = ~((new > lo) & (new < hi)) & pos & ~done
                    new = np.where(out, np.where(hi < np.inf, 0.5 * (lo + hi), mu_a + step_lin), new)
                    mu_a = np.where(np.isfinite(new), new, mu_a)
                    mu_f[idx] = mu_a
                    if done.all():
                        break
                    if done.any():   # drop the converged elements
                        keep = ~done
                        idx, mu_a, P, lo, hi, pos = idx[keep], mu_a[keep], P[:, keep], lo[keep], hi[keep], pos[keep]
        s = np.sqrt(np.maximum(mu - dm, 0.0) / K + pre_var_dn2)
        mean, var, slope = self._clip_moments(mu, s, tt_, cc)
        return mu, var, slope

    def log_likelihood(self, th):
        terms = self.loglik_terms(th)
        return sum(v.sum(axis=1) for v in terms.values())

    def log_prob(self, theta):
        """log prior + log likelihood of draws ``theta`` (n, ndim) or one draw (ndim,): (n,).
        Calls of :data:`SPLIT_MIN_ELEMENTS` (draws × observations) or more are evaluated in two
        halves, on two threads where :func:`n_threads` allows (:func:`_split_rows`)."""
        th = np.atleast_2d(np.asarray(theta, float))
        if th.shape[0] >= 1000 and th.shape[0] * self._observations() >= SPLIT_MIN_ELEMENTS:
            return _split_rows(lambda part: _log_posterior(part, lambda good: self), th)
        return _log_posterior(th, lambda good: self)

    def _observations(self) -> int:
        """Observations per draw (the likelihood blocks' columns), counted once from one draw."""
        def count():
            with np.errstate(all="ignore"):
                pred = self.predict(np.atleast_2d(self.initial_guess()))
            return int(sum(np.shape(v[1])[-1] for v in pred.values()))
        return self._memoized("observations", count)

    def _memoized(self, key, compute):
        """``compute()``, once per model (:attr:`_memo`, shared by its shallow copies)."""
        memo = self.__dict__.setdefault("_memo", {})      # (a model unpickled from before _memo)
        if key not in memo:
            memo[key] = compute()
        return memo[key]

    # ------------------------------------------------------------------ start point
    def initial_guess(self) -> np.ndarray:
        """A deterministic starting point from EMVA-1288-style linear fits (no randomness).

        Computed once per model (a copy returned each time): it costs ~1.3 ms with its scan of the
        clip spread, and a fast fit asks for it three times (the Newton start, the sampler
        coordinates, the observation count)."""
        return self._memoized("initial_guess", self._initial_guess).copy()

    def _initial_guess(self) -> np.ndarray:
        tm = self.terms
        s, v = self.s_obs, self.v
        vd_ok = self.vd[~self.full_sat]
        lin = s <= 0.7 * s.max()
        if lin.sum() < 2:
            lin = np.ones_like(s, bool)
        y = v[lin] - vd_ok[lin]
        x = s[lin]
        slope = np.sum(x * y) / max(np.sum(x * x), 1e-300)
        if len(x) >= 3:
            A = np.vstack([x, np.ones_like(x)]).T
            slope = np.linalg.lstsq(A, y, rcond=None)[0][0]
        slope = slope if np.isfinite(slope) and slope > 0 else 1.0
        k0 = float(np.clip(1.0 / slope, 2e-3, 5e2))
        vd0 = float(np.median(self.vd))
        sig0_e2 = max((vd0 - 1.0 / 12.0) * k0 * k0, (0.05 * k0) ** 2)
        if vd0 < 1.0 / 12.0 + 0.25:
            # near or below the quantization floor: invert the exact rounded-normal variance at the
            # median dark row's measured offset (Sheppard's σ² + 1/12 would put σ near 0, where the
            # likelihood is flat and a local optimiser strays)
            i = int(np.argsort(self.vd)[self.vd.size // 2])
            s_grid = np.geomspace(0.03, 1.0, 200)
            frac = np.full(s_grid.size, self.dark_frac_dn[i])
            _, vg, _ = _rounded_normal_moments(_rounded_offset(frac, s_grid), s_grid)
            s0 = float(s_grid[np.argmin(np.abs(vg - vd0))])
            sig0_e2 = max((s0 * k0) ** 2, (0.05 * k0) ** 2)
        th = {"log_k": np.log(k0)}
        if tm.dark_current:
            t = self.t
            if np.ptp(t) > 0:
                b = np.polyfit(t, self.vd, 1)[0] * k0 * k0
            else:
                b = 0.0
            tmax = max(t.max(), 1e-9)
            dc0 = b if b > 0 else 0.05 * sig0_e2 / tmax
            dc0 = min(dc0, 0.5 * sig0_e2 / tmax) if b <= 0 else dc0
            r2 = max(sig0_e2 - dc0 * np.median(t), 0.25 * sig0_e2)
            th["log_read"] = 0.5 * np.log(r2)
            th["log_dc"] = np.log(max(dc0, 1e-6))
        else:
            th["log_dark_noise"] = 0.5 * np.log(sig0_e2)
        if tm.clip in ("adc_sampled", "well"):
            lo, hi = self.clip_bounds
            if self.full_means.size:
                th["clip_dn"] = float(np.clip(self.full_means.mean(), lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo)))
            else:
                th["clip_dn"] = lo + 0.02 * (hi - lo)
        if tm.clip_spread:
            cref = th.get("clip_dn", self.adc if self.adc is not None else self.max_mean_ok)
            th["log_tau"] = np.log(max(0.005 * (cref - self.black_dn), 0.5))
        if tm.quantum_efficiency:
            x = self.mu_p[lin]
            r = np.sum(x * s[lin]) / max(np.sum(x * x), 1e-300)
            th["qe"] = float(np.clip(r * k0, 0.01, 0.99))
            th["log_g"] = np.log(0.005)
        if tm.prnu or tm.dsnu:
            dsnu_dn2 = 1e-4
            if self.spd_rows.size:
                r = self.spd_rows
                dsnu_dn2 = max(np.median(self.spd[r] - self.vd[r] / self.L_all[r]), 1e-4)
            if tm.dsnu:
                th["log_dsnu"] = 0.5 * np.log(dsnu_dn2 * k0 * k0)
            if tm.prnu:
                pr2 = 1e-6
                if self.sp_rows.size:
                    r = self.sp_rows
                    est = (self.sp[r] - v[r] / self.L_ok[r] - dsnu_dn2) / np.maximum(s[r], 1e-9) ** 2
                    pr2 = max(np.median(est), 1e-8)
                th["log_prnu"] = 0.5 * np.log(pr2)
        for n in self.pattern_latents:
            th[n] = 0.0
        if tm.discrepancy:
            th["log_f"] = np.log(0.01)
        # keep the start inside an overridden (bounded) prior
        P = self.PRIOR
        for name, key in (("log_read", "read_log_bounds"), ("log_dc", "dark_current_log_bounds"),
                          ("log_prnu", "prnu_log_bounds"), ("log_dsnu", "dsnu_log_bounds")):
            if name in th and P[key] is not None:
                a, b = np.log(P[key][0]), np.log(P[key][1])
                th[name] = float(np.clip(th[name], a + 1e-3 * (b - a), b - 1e-3 * (b - a)))
        lk0, lk1 = P["log_k_bounds"]
        th["log_k"] = float(np.clip(th["log_k"], lk0 + 1e-3 * (lk1 - lk0), lk1 - 1e-3 * (lk1 - lk0)))
        if "qe" in th and P["qe_bounds"] is not None:
            q0, q1 = P["qe_bounds"]
            th["qe"] = float(np.clip(th["qe"], q0 + 1e-3 * (q1 - q0), q1 - 1e-3 * (q1 - q0)))
        x = np.array([th[n] for n in self.names], float)
        if tm.clip_spread:
            # the clip spread: a deterministic scan of log_prob over τ from 10⁻³ DN to the prior's cap.
            # Below the quantization floor the plateau variance depends on τ only for τ ≲ 0.7 DN
            # (exact rounding), flat above (Sheppard): a start in the flat part leaves the
            # optimiser there, thousands of nats below the mode
            cref = th.get("clip_dn", self.adc if self.adc is not None else self.max_mean_ok)
            hi = np.log(0.999 * self.PRIOR["tau_max_frac"] * cref)
            grid = np.linspace(np.log(1e-3), hi, 16) if hi > np.log(1e-3) else np.array([th["log_tau"]])
            cand = np.repeat(x[None, :], grid.size + 1, axis=0)
            cand[1:, self.idx["log_tau"]] = grid
            lp = self.log_prob(cand)
            if np.any(np.isfinite(lp)):
                x = cand[int(np.nanargmax(np.where(np.isfinite(lp), lp, -np.inf)))]
        return x


#: a :meth:`PTCModel.log_prob` call of this many draws × observations or more (and ≥ 1 000 draws)
#: is evaluated in two halves, one of them on a second thread (numpy's ufuncs release the GIL).
#: Measured on this project's 2-core VM, a call alone: Basler CCD (133 observations a draw) 4 000
#: draws 29.0 → 18.2 ms, 2 000 15.7 → 12.5, 1 500 12.2 → 9.5, 933 7.4 → 7.1, 500 4.4 → 5.7; a
#: simulated Gpixel ROI (90) 2 000 draws 7.2 → 8.3 ms, slower: the hand-over costs ~1 ms
#: (benchmarks/results/ab_trees_b9fb93f.md). Inside a fast fit the Basler's calls gained nothing
#: until OpenBLAS's spinning worker was held off (bayescap/_blas.py); since, two halves on two threads
#: against one: 1 000 draws 0.85, 2 000 0.73, 4 000 0.64 (docs/performance.md, "OpenBLAS threads").
SPLIT_MIN_ELEMENTS = 200_000

_SPLIT_POOL = {}


def _env_count(name):
    """The environment variable ``name`` as a count ≥ 1, or None when unset or not an integer."""
    env = os.environ.get(name)
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    return None


def _allowed(env_name, default_fn) -> int:
    """How many processes or threads a fit may use: the environment variable ``env_name`` if set;
    else 1 in a process started by :mod:`multiprocessing` (a pool worker, e.g. one of
    ``bayescap.batch.fit_many``'s: its siblings have the other cores); else ``default_fn()``."""
    env = _env_count(env_name)
    if env is not None:
        return env
    import multiprocessing as mp

    if mp.parent_process() is not None:
        return 1
    return default_fn()


def n_threads() -> int:
    """Threads a large ``log_prob`` call may use (:func:`_allowed`, ``BAYESCAP_THREADS``): 2 where this
    process may run on two cores or more."""
    def two_if_two_cores():
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:        # not on Linux
            cores = os.cpu_count() or 1
        return 2 if cores >= 2 else 1
    return _allowed("BAYESCAP_THREADS", two_if_two_cores)


def _split_rows(fn, th):
    """``fn(th)`` for row-wise ``fn``, as ``fn`` of the first and of the second half of the rows,
    concatenated: the second half on a worker thread when :func:`n_threads` > 1, else after the
    first. The halves are the same whatever the thread count (and the number of cores), so the
    numbers are too. (A call's rows are not quite independent: :meth:`PTCModel.predict` skips clip
    rows that no draw of the call needs, which changes a value in its last bits; so a split call can
    differ from an unsplit one there, never from another split one.)"""
    k = th.shape[0] // 2
    if n_threads() < 2:
        return np.concatenate([fn(th[:k]), fn(th[k:])])
    import contextvars
    from concurrent.futures import ThreadPoolExecutor

    pid = os.getpid()
    pool = _SPLIT_POOL.get(pid)
    if pool is None:          # one per process: a pool inherited through fork has no thread
        _SPLIT_POOL.clear()
        pool = _SPLIT_POOL[pid] = ThreadPoolExecutor(1, thread_name_prefix="bayescap-log-prob")
    # the worker runs in a copy of this context: numpy's errstate (a context variable) goes with it
    fut = pool.submit(contextvars.copy_context().run, fn, th[k:])
    try:
        first = fn(th[:k])
    finally:
        second = fut.result()
    return np.concatenate([first, second])


def _log_posterior(theta, model_for):
    """log prior + log likelihood of draws ``theta`` (n, ndim): the likelihood only where the prior
    is finite. ``model_for(good)`` gives the model to evaluate the draws ``good`` (a boolean mask;
    None: all draws) with: the model itself, or a :class:`PTCModelStack` view of those draws."""
    th = np.atleast_2d(np.asarray(theta, float))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # far-out draws (a walker at log τ = 800) overflow exp() in the prior: −inf, as meant
        lp = model_for(None).log_prior(th)
    good = np.isfinite(lp)
    out = np.full(th.shape[0], -np.inf)
    if np.any(good):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            ll = model_for(good).log_likelihood(th[good])
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        out[good] = lp[good] + ll
    return out


class PTCModelStack:
    """Several :class:`PTCModel` of one structure evaluated in one ``log_prob`` call (issue 7:
    a batch vectorised across sensors, :func:`bayescap.batch.fit_many`).

    A ``log_prob`` call on a few points costs ~0.6 ms, almost all of it per-call overhead (the
    fast path makes ~200 such calls per sensor); stacking sensors pays it once per call. Sensors
    stack when :meth:`signature` agrees: the same parameters, terms and prior, and the same rows
    in every block (clip rows, spatial rows, fully clipped rows), so every array of the model has
    the same shape. The per-row data become (n_draws, rows) arrays gathered by each draw's sensor
    and the per-sensor numbers (black level, ADC maximum, clip-level bounds) per-draw arrays;
    :class:`PTCModel`'s own methods then run unchanged on that view.

    A sensor's numbers do not depend on the other sensors in the call: every operation is
    elementwise over (draw, row) except the choice of rows near the clip, which is taken over
    each request's draws (``request``), as a single model takes it over its call's draws.
    ``tests/test_batch.py`` checks that a stacked call equals each model's own ``log_prob``
    bit for bit.
    """

    #: per-row data arrays (stacked along a new first axis)
    ROW_ARRAYS = ("m", "v", "vd", "dm", "tt", "t", "nu", "nu_d", "s_obs", "mu_p", "full_means", "full_v",
                  "full_nu", "full_sd", "sp", "spd", "L_ok", "L_all", "dark_frac_dn", "bright_frac_dn",
                  "full_frac_dn", "t_full", "vd_ok")

    def __init__(self, models):
        self.models = list(models)
        if not self.models:
            raise ValueError("PTCModelStack needs at least one model")
        sig = self.signature(self.models[0])
        for i, m in enumerate(self.models[1:], 1):
            if self.signature(m) != sig:
                raise ValueError(f"model {i} does not stack with model 0: different parameters, terms, "
                                 "prior or block rows (group models by PTCModelStack.signature)")
        m0 = self.models[0]
        self.ndim, self.names = m0.ndim, m0.names
        # one model stacked with itself (the ensembles of an MCMC preset in lockstep,
        # fit._run_segments): its own data serve every draw, nothing to gather
        self._same = all(m is m0 for m in self.models)
        self._rows = {} if self._same else {a: np.stack([getattr(m, a) for m in self.models])
                                            for a in self.ROW_ARRAYS if hasattr(m0, a)}
        self._black = np.array([m.black_dn for m in self.models], float)
        self._adc = None if m0.adc is None else np.array([m.adc for m in self.models], float)
        self._nu_pattern = np.array([m.nu_pattern for m in self.models], float)
        self._clip_bounds = (None if m0.clip_bounds is None else
                             tuple(np.array([m.clip_bounds[j] for m in self.models], float) for j in (0, 1)))

    @staticmethod
    def signature(model: PTCModel):
        """What must agree for models to stack (a hashable tuple)."""
        tm = model.terms
        terms = (tm.dark_current, tm.clip, tm.clip_spread, tm.quantum_efficiency, tm.prnu, tm.dsnu,
                 tm.robust, tm.discrepancy)
        shapes = tuple((a, np.shape(getattr(model, a))) for a in PTCModelStack.ROW_ARRAYS if hasattr(model, a))
        rows = tuple(tuple(np.asarray(getattr(model, a)).tolist()) for a in ("clip_rows", "lin_rows", "sp_rows", "spd_rows"))
        prior = tuple(sorted((k, repr(v)) for k, v in model.PRIOR.items()))
        return (tuple(model.names), terms, shapes, rows, int(np.sum(model.full_sat)), model.adc is None,
                model.clip_bounds is None, prior)

    def view(self, sensor, request=None) -> PTCModel:
        """A PTCModel whose data are those of ``sensor[i]`` for draw ``i`` (``request``: the id of
        the request each draw belongs to, for the per-request reductions)."""
        sensor = np.asarray(sensor, int)
        v = copy.copy(self.models[0])
        v._memo = {}            # model 0's initial guess is not this view's
        if self._same:
            # the model's own (rows,) arrays broadcast over the draws as in a single model's call;
            # only the choice of rows near the clip is per request. (With gathered (draws, rows)
            # copies a lockstep call of 2 × 48 draws took 6-7 % longer: benchmarks/ab_trees.py)
            v._request_ids = np.asarray(sensor if request is None else request)
            v._request_segments = None
            return v
        v.__class__ = _StackView
        v._stack_rows, v._stack_sensor, v._gathered = self._rows, sensor, {}
        v.black_dn = self._black[sensor]
        v.adc = None if self._adc is None else self._adc[sensor]
        v.nu_pattern = self._nu_pattern[sensor][:, None]
        v.clip_bounds = None if self._clip_bounds is None else tuple(b[sensor] for b in self._clip_bounds)
        v._request_ids = np.asarray(sensor if request is None else request)
        v._request_segments = None
        return v

    def log_prob(self, theta, sensor, request=None):
        """``PTCModel.log_prob`` of draw ``theta[i]`` under model ``sensor[i]``: (n,).

        Draws of one request must be contiguous (the clip-row choice is per request)."""
        sensor = np.asarray(sensor, int)
        request = sensor if request is None else np.asarray(request)
        return _log_posterior(theta, lambda good: self.view(sensor if good is None else sensor[good],
                                                            request if good is None else request[good]))


class _GatheredRows:
    """A per-row data array of a :class:`PTCModelStack` view, gathered by draw on first use (a
    log-prior evaluation, or a model that does not use the array, never pays for it)."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        got = obj._gathered
        if self.name not in got:
            got[self.name] = obj._stack_rows[self.name][obj._stack_sensor]
        return got[self.name]

    def __set__(self, obj, value):
        obj._gathered[self.name] = value


class _StackView(PTCModel):
    """A :class:`PTCModel` evaluated on stacked data (made by :meth:`PTCModelStack.view` only)."""


for _a in PTCModelStack.ROW_ARRAYS:
    _d = _GatheredRows()
    _d.__set_name__(_StackView, _a)
    setattr(_StackView, _a, _d)
del _a, _d
