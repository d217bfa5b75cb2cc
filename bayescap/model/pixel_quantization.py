"""Rounding of a population of pixels whose means are spread (fixed patterns, the well spread):
the temporal variance of the rounded values averaged over the pixels, its sampling factor, and
the spatial variance that rounding adds to the pixel means (:func:`_quantized_pixel_moments`),
integrated over the wrapped normal of the offsets on a midpoint grid, by Gauss–Hermite nodes, or
from a shipped table when the offsets are uniform.

The table ``_uniform_offset_table.npz`` sits next to this module (:data:`UNIFORM_TABLE_FILE`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bayescap.model.offset_boundary import boundary_moments
from bayescap.model.offset_fourier import offset_fourier_moments
from bayescap.model.quantization import (
    _QG_GRIDS,
    _QG_SIZES,
    _gaussian_harmonics,
    _harmonics,
    _rounded_normal_moments,
    _rows_matmul,
    _small_unique,
)

__all__ = ["UNIFORM_TABLE_FILE", "write_uniform_offset_table"]

_GH_X, _GH_W = np.polynomial.hermite_e.hermegauss(9)
_GH_W = _GH_W / _GH_W.sum()

#: midpoint grids over a pixel mean's offset within one DN (:func:`_quantized_pixel_moments`).
#: The M-point rule's error is the aliasing of the product of the wrapped normal (harmonics
#: e^{−2π²k²σ_o²}) and the moments (harmonics down to ~e^{−π²n²s²/2}, the 4th moment's products):
#: at most ~e^{−c}, c = M²·ab/(a + b), a = 2π²σ_o², b = π²s²/2. Each element takes the smallest M
#: of :data:`_QG_SIZES` (:mod:`~bayescap.model.quantization`) with c ≥ :data:`_QG_C` (measured against 256 points: max error 6e-12 at
#: c ≥ 23 over s 0.02-0.75 DN, σ_o 1/32-0.7 DN), 1 024 where none does (s below ~0.005 DN). A fixed
#: M = 32 errs by up to 1.8e-3 DN² where s and σ_o are both below ~0.05 DN, and is 2-4× more points
#: than needed where they are not.
_QG_M = 32  # below σ_o = 1/_QG_M (and σ_o < s/4): Gauss–Hermite nodes instead of a grid
#: the Gauss–Hermite nodes need the integrands smooth on the scale of σ_o: σ_o < s/4 (error ≤ 1.5e-13
#: against a 4 096-point quadrature over s 0.005-0.75 DN; with σ_o between s/2 and 2s they are
#: off by up to 1e-3 DN², 4 % of V), else the grid
_GH_SO_OVER_S = 0.25
_QG_C = 25.0
_QG_X = _QG_GRIDS[_QG_M]
_QG_J = np.arange(-6, 6)  # DN boundaries j + ½ of the Stein term
#: :func:`_wrapped_normal_grid`: below this σ_o (DN) the images j = −1, 0, 1 (the next ones are
#: ≥ 1 DN away: e^{−½(1/0.1)²} ≈ 2e-22 of the peak); from it up the Fourier series to
#: :data:`_WN_K` harmonics (the next one's factor e^{−2π²·15²·0.1²} ≈ 9e-20)
_WN_FOURIER_SO = 0.1
_WN_K = 14
_WN_CS = {
    M: np.concatenate(
        [
            np.cos(2.0 * np.pi * np.arange(1, _WN_K + 1)[:, None] * x),
            np.sin(2.0 * np.pi * np.arange(1, _WN_K + 1)[:, None] * x),
        ]
    )  # (2K, M)
    for M, x in _QG_GRIDS.items()
}


def _grid_size(s, so):
    """Points of the offset grid for each element (:data:`_QG_SIZES`, :data:`_QG_C`)."""
    a = 2.0 * np.pi**2 * so * so
    b = 0.5 * np.pi**2 * s * s
    with np.errstate(all="ignore"):
        c1 = a * b / (a + b)  # c for M = 1
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
    in one matrix product: no exponential per grid point (a sum of twelve images at every grid
    point, 384 exponentials an element, takes half of a ``log_prob`` call of a sensor with a
    spatial stack whose read noise is below 0.5 DN). Both forms agree with the sum of ±40 images to 1e-15
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
        S, C = _harmonics(delta[four], _WN_K)  # (K, n)
        q = 2.0 * _gaussian_harmonics(so[four], _WN_K)  # (K, n)
        A = np.concatenate([(q * C).T, (q * S).T], axis=1)  # (n, 2K)
        w[four] = 1.0 + _rows_matmul(A, _WN_CS[M])
    return w / w.sum(-1, keepdims=True)


def _quantized_pixel_moments(delta, s, so, exact=False):
    """Rounding of pixels whose means are spread: offsets o ~ N(δ, σ_o²) (δ relative to an integer
    DN, σ_o = ``so``), each pixel's values round(o + s·ε), ε ~ N(0, 1) drawn anew every frame.

    Returns ``(V, E4, H)`` (1-D, like ``delta``):

    * V  = E_o[var(round(o + sε) | o)], the temporal variance averaged over the pixels;
    * E4 = E_o[μ₄ + var²] of the same, for the sampling variance of a pair estimate;
    * H  = var_o(E[round(o + sε) | o]) − σ_o², the spatial variance that rounding adds to the
      pixel means (up to 1/12 DN² for s → 0: a pattern whose pixels sit still is quantized too).

    Where its error bound holds (relative 1e-4 of V, E4 and H; :mod:`~bayescap.model.offset_fourier`)
    and ``exact`` is false, a Fourier series in δ whose coefficients are tabulated in s (3-8× faster
    than the grid); else for s ≤ 0.1 DN, σ_o from 1e-4 DN and s² + σ_o² ≤ 0.16 DN², quadratures at
    the DN boundaries (relative 1e-5 of V, E4 and H; :mod:`~bayescap.model.offset_boundary`; the
    grid needs up to 1 024 points there). Elsewhere, or with ``exact``, the offsets' distribution modulo 1 DN is the
    wrapped normal, integrated on a periodic midpoint
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
    wide = so > 0.7
    # the Fourier series in δ with coefficients tabulated in s (:mod:`~bayescap.model.offset_fourier`)
    # where its error bound holds; the exact evaluations below for the others
    series = np.zeros(delta.shape, bool)
    cand = np.flatnonzero(~(point | wide)) if not exact else np.empty(0, np.intp)
    if cand.size:
        got, vs, e4s, hs = offset_fourier_moments(delta[cand], s[cand], so[cand])
        at = cand[got]
        series[at] = True
        V[at], E4[at], H[at] = vs[got], e4s[got], hs[got]
    # small s: quadratures at the DN boundaries (:mod:`~bayescap.model.offset_boundary`) where
    # they hold
    cand = np.flatnonzero(~(point | wide | series)) if not exact else np.empty(0, np.intp)
    if cand.size:
        got, vb, e4b, hb = boundary_moments(delta[cand], s[cand], so[cand])
        at = cand[got]
        series[at] = True
        V[at], E4[at], H[at] = vb[got], e4b[got], hb[got]
    narrow = ~point & ~series & (so < 1.0 / _QG_M) & (so < _GH_SO_OVER_S * s)
    grid = ~(point | narrow | wide | series)
    if np.any(point):  # no pattern: the pixels share one offset
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
    if np.any(wide):  # offsets uniform modulo 1 DN: functions of s alone (tabulated)
        V[wide], E4[wide], H[wide] = _uniform_offset_moments(s[wide])
    if np.any(grid):
        gi = np.flatnonzero(grid)
        sizes = _grid_size(s[gi], so[gi])
        for M in _small_unique(sizes):
            at_M = gi[sizes == M]
            step = max(1, _QG_CHUNK_POINTS // int(M))
            for i0 in range(0, at_M.size, step):
                _grid_moments(delta, s, so, at_M[i0 : i0 + step], int(M), V, E4, H)
    return V, E4, H


#: :func:`_quantized_pixel_moments` works on the grid's (elements, M) arrays in chunks of at most this
#: many points (1 MB a float array): a fast path's 6 000 draws × 13 spatial-stack rows × 16 points
#: had ~10 MB arrays, and the same work in chunks took 76 instead of 111-114 ms (the largest
#: call of benchmarks/quantization_regime.py); each element's numbers are its
#: own either way
_QG_CHUNK_POINTS = 131072


def _grid_moments(delta, s, so, at, M, V, E4, H):
    """The grid branch of :func:`_quantized_pixel_moments` for the elements ``at`` (grid size ``M``),
    written into ``V``, ``E4``, ``H``."""
    dl, sg, sog = delta[at], s[at], so[at]
    x = _QG_GRIDS[M]
    # the moments at the grid's offsets (the grid's harmonics computed once, not per element)
    m, v, m4 = _rounded_normal_moments(x, sg[:, None], J=5)
    h = m - x  # rounding bias of a pixel's mean
    w = _wrapped_normal_grid(dl, sog, M)  # wrapped normal on the grid
    V[at] = (w * v).sum(-1)
    E4[at] = (w * (m4 + v * v)).sum(-1)
    eh = (w * h).sum(-1)
    var_h = np.maximum((w * h * h).sum(-1) - eh * eh, 0.0)
    # Stein: cov(o, h(o)) = σ_o² E[h'(o)], E[h'] = Σ_b N(b; δ, τ²) − 1 (τ² = s² + σ_o²)
    tau = np.sqrt(sg * sg + sog * sog)
    zz = (_QG_J + 0.5 - dl[:, None]) / tau[:, None]
    dens = np.exp(-0.5 * zz * zz).sum(-1) / (tau * np.sqrt(2.0 * np.pi))
    dens = np.where(tau > 1.0, 1.0, dens)  # |Σ − 1| < 3e-9 beyond
    H[at] = var_h + 2.0 * sog * sog * (dens - 1.0)


_UNIFORM_TABLE = {}

#: :func:`_uniform_offset_moments`'s table as shipped (built by :func:`_build_uniform_offset_table`;
#: rebuild it with
#: ``python -c "from bayescap.model.pixel_quantization import write_uniform_offset_table as w; w()"``
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
    a = np.minimum(0.5, 12.0 * sg)[:, None]  # beyond ±12 s from the boundary v = 0
    x = 0.5 + a * u  # offsets about the boundary at ½ DN
    x = x - np.round(x)
    _, v, m4 = _rounded_normal_moments(x, sg[:, None], J=5)
    w = a * wu  # ∫ over one period of length 1
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
