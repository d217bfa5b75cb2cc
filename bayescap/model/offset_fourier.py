"""The rounding moments of a population of pixels (:func:`~bayescap.model.pixel_quantization.\
_quantized_pixel_moments`) as Fourier series in the offset δ, with coefficients tabulated in s.

A pixel whose mean sits at offset x (DN, modulo 1) and whose temporal noise is s has the rounded
moments v(x), e(x) = μ₄(x) + v(x)² and the rounding bias h(x) = E[round(x + sε)] − x, periodic in x
with period 1 DN (v, e, h² even, h odd). Averaged over offsets o ~ N(δ, σ_o²) (the wrapped normal
modulo 1 DN, whose k-th Fourier coefficient is e^{−2π²k²σ_o²} e^{−2πikδ}), each is a convolution:

    E_o[f(o)] = c₀(s) + Σ_{k≥1} c_k(s) e^{−2π²k²σ_o²} cos 2πkδ        (f = v, e, h²)
    E_o[h(o)] = Σ_{k≥1} (−1)^k e^{−2π²k²(s² + σ_o²)} sin(2πkδ)/(πk)   (closed form)

The coefficients c_k(s) (k ≤ 32) are tabulated on 1 424 equally spaced s from 0.005 to 0.72 DN
(:func:`_build_offset_fourier_table`, shipped as :data:`OFFSET_FOURIER_TABLE_FILE`, 1.1 MB) and
interpolated by cubics through four nodes. An element takes 8, 16 or 32 harmonics, the fewest
with K²(π²s²/2 + 2π²σ_o²) ≥ 30 (the neglected terms are below e^{−30} of the coefficients: e's
harmonics decay as e^{−π²k²s²/2}, the slowest of the three). The absolute error, from the
interpolation in s, is below 1e-9 DN² (measured against the exact evaluation on 200 000 random
(δ, s, σ_o)); :func:`offset_fourier_moments` returns an element only where that is a relative
error ≤ 1e-4: V and E4 ≥ :data:`_V_MIN` and σ_o ≥ :data:`_SO_MIN` (smaller spreads make H a
difference of nearly equal numbers); measured there: ≤ 2.2e-6 of V, E4 and H (150 000 random points,
27 000 of them served). The others stay with the exact evaluation.
``tests/test_offset_fourier.py`` bounds the relative errors of V, E4 and H by 1e-4 on a dense random
set over the served domain and its edges.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bayescap.model.quantization import _gaussian_harmonics, _harmonics, _rounded_normal_moments

__all__ = ["OFFSET_FOURIER_TABLE_FILE", "offset_fourier_moments", "write_offset_fourier_table"]

#: the table's s nodes (DN) and harmonics
_S0, _S1, _NS = 0.005, 0.72, 1424
_KMAX = 32
_K_TIERS = (8, 16, 32)
#: an element is served by the series when K²(π²s²/2 + 2π²σ_o²) ≥ this for K ≤ 32
_B_MIN = 30.0
#: served only where σ_o ≥ this (DN) ...
_SO_MIN = 0.005
#: ... and the computed V and E4 are ≥ this (DN², DN⁴): the absolute error < 1e-9 is then < 1e-4 relative
_V_MIN = 1e-5
#: elements whose offset is more than this many τ = √(s² + σ_o²) from the nearest DN boundary are not
#: evaluated: V ≤ E[round(X)²], X ~ N(δ, τ²), ≤ 2Φ(−z)(1 + 2 %) < 5e-6 < :data:`_V_MIN` for
#: z = (½ − |δ|)/τ > 4.6 (τ ≤ 1 DN), so the series would not serve them (a sensor whose dark
#: pixels sit 0.1 DN from an integer with 0.1 DN of noise spent 40 % more on its moments)
_Z_SKIP = 4.6
#: elements per chunk of the evaluation at 32 harmonics (temporaries of a few MB)
_CHUNK = 4096

#: :func:`_build_offset_fourier_table` as shipped; rebuild with
#: ``python -c "from bayescap.model.offset_fourier import write_offset_fourier_table as w; w()"``
#: after changing that function (a build takes ~0.5 s; ``tests/test_offset_fourier.py`` checks the
#: file against a fresh build)
OFFSET_FOURIER_TABLE_FILE = Path(__file__).with_name("_offset_fourier_table.npz")


def _build_offset_fourier_table():
    """Cosine coefficients c_k(s), k = 0..32, of v, μ₄ + v² and h² over one period of the offset
    at the s nodes: the exact moments (:func:`~bayescap.model.quantization._rounded_normal_moments`)
    at N equally spaced offsets, N a power of 2 with (N − 32)·s ≥ 2.6 (the aliased harmonics are
    below e^{−π²·2.6²/2} ≈ 3e-15), and their discrete Fourier transform."""
    sg = np.linspace(_S0, _S1, _NS)
    coef = np.empty((_NS, 3, _KMAX + 1))
    sizes = np.maximum(128, 2 ** np.ceil(np.log2(_KMAX + 2.6 / sg + 1.0))).astype(int)
    for N in np.unique(sizes):
        at = np.flatnonzero(sizes == N)
        x = np.arange(N) / N
        x = x - np.round(x)  # offsets in [−½, ½)
        m, v, m4 = _rounded_normal_moments(x, sg[at, None], J=5)
        h = m - x
        F = np.fft.rfft(np.stack([v, m4 + v * v, h * h], axis=1), axis=-1).real[..., : _KMAX + 1] / N
        F[..., 1:] *= 2.0
        coef[at] = F
    return {"s": sg, "coef": coef}


def write_offset_fourier_table(path=None):
    """Write :func:`_build_offset_fourier_table` to ``path`` (default :data:`OFFSET_FOURIER_TABLE_FILE`)."""
    path = Path(path) if path is not None else OFFSET_FOURIER_TABLE_FILE
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **_build_offset_fourier_table())
    os.replace(tmp, path)


_TABLES = {}


def _load_table():
    """The shipped table, or a fresh build when the file is missing or not the expected shape."""
    try:
        with np.load(OFFSET_FOURIER_TABLE_FILE) as z:
            table = {k: np.array(z[k], float) for k in ("s", "coef")}
        if table["s"].shape != (_NS,) or table["coef"].shape != (_NS, 3, _KMAX + 1):
            return _build_offset_fourier_table()
        if not np.all(np.isfinite(table["coef"])):
            return _build_offset_fourier_table()
        return table
    except (OSError, KeyError, ValueError):
        return _build_offset_fourier_table()


def _stencils(K):
    """For each stencil start i, the Newton forward differences of the nodes i..i+3 (the cubic
    through them is D₀ + t(D₁ + (t−1)(D₂ + (t−2)D₃)), t = (s − s_i)/Δs), harmonics 0..K, as
    (NS − 3, 4, 3(K + 1)) (one contiguous row per stencil); cached."""
    if K not in _TABLES:
        if "coef" not in _TABLES:
            _TABLES["coef"] = _load_table()["coef"]
        y = _TABLES["coef"][:, :, : K + 1].reshape(_NS, -1)
        d1 = np.diff(y, axis=0)
        d2 = np.diff(d1, axis=0)
        d3 = np.diff(d2, axis=0)
        n = _NS - 3
        _TABLES[K] = np.ascontiguousarray(np.stack([y[:n], d1[:n], d2[:n] / 2.0, d3[:n] / 6.0], axis=1))
    return _TABLES[K]


_DS = (_S1 - _S0) / (_NS - 1)


def _series_tier(delta, s, so, K):
    """(V, E4, H) by the series to ``K`` harmonics (1-D inputs inside the table's s range)."""
    n = delta.size
    D = _stencils(K)
    u = (s - _S0) / _DS
    i = np.clip(np.floor(u).astype(np.intp) - 1, 0, _NS - 4)
    t = (u - i)[:, None]
    S, Cs = _harmonics(delta, K)  # (K, n)
    U = np.empty((n, K + 1, 1))
    U[:, 0, 0] = 1.0
    U[:, 1:, 0] = (_gaussian_harmonics(so, K) * Cs).T
    # each stencil node's series first ((n, 12, K+1) by (n, K+1, 1)), then the cubic in s of the sums
    G = np.matmul(D[i].reshape(n, 12, K + 1), U).reshape(n, 4, 3)
    F = G[:, 0] + t * (G[:, 1] + (t - 1.0) * (G[:, 2] + (t - 2.0) * G[:, 3]))  # (n, 3): V, E4, E[h²]
    # E[h] and the Stein term Σ_b N(b; δ, τ²) − 1 = 2 Σ_k (−1)^k e^{−2π²k²τ²} cos 2πkδ (b = j + ½),
    # both with q_k = 2(−1)^k e^{−2π²k²τ²}, τ² = s² + σ_o²
    k = np.arange(1, K + 1)
    q = (2.0 * np.where(k % 2 == 1, -1.0, 1.0))[:, None] * _gaussian_harmonics(np.sqrt(s * s + so * so), K)
    qs, qc = (q / (2.0 * np.pi * k[:, None])) * S, q * Cs
    # summed row by row (np.sum over axis 0 of a (K, 1) array sums pairwise, in another order than
    # for many columns: an element's numbers must not depend on the other elements of the call)
    eh, dens_m1 = qs[0].copy(), qc[0].copy()
    for j in range(1, K):
        eh += qs[j]
        dens_m1 += qc[j]
    H = np.maximum(F[:, 2] - eh * eh, 0.0) + 2.0 * so * so * dens_m1
    return F[:, 0], F[:, 1], H


def _tier(s, so):
    """Harmonics each element needs (8, 16 or 32; 0 where 32 are not enough or s, σ_o are outside
    the served range, NaN included)."""
    b = np.pi**2 * (0.5 * s * s + 2.0 * so * so)
    out = np.zeros(s.shape, dtype=np.intp)
    inside = (s >= _S0) & (s <= _S1 - 2.0 * _DS) & (so >= _SO_MIN)
    for K in reversed(_K_TIERS):
        out[inside & (K * K * b >= _B_MIN)] = K
    return out


def offset_fourier_moments(delta, s, so):
    """(served, V, E4, H) for 1-D ``delta``, ``s``, ``so`` (DN): ``served`` marks the elements the
    series evaluates within its error bound (module docstring); V, E4, H are set there only."""
    delta = np.asarray(delta, float)
    s = np.asarray(s, float)
    so = np.asarray(so, float)
    V = np.full(delta.shape, np.nan)
    E4 = np.full(delta.shape, np.nan)
    H = np.full(delta.shape, np.nan)
    tiers = _tier(s, so)
    with np.errstate(invalid="ignore"):
        tiers[(0.5 - np.abs(delta)) > _Z_SKIP * np.sqrt(s * s + so * so)] = 0
    for K in _K_TIERS:
        at_K = np.flatnonzero(tiers == K)
        step = _CHUNK * (_KMAX // K)
        for i0 in range(0, at_K.size, step):
            at = at_K[i0 : i0 + step]
            V[at], E4[at], H[at] = _series_tier(delta[at], s[at], so[at], K)
    served = (V >= _V_MIN) & (E4 >= _V_MIN)
    return served, V, E4, H
