"""The numerical steps 2-10 of the ISO 12233 e-SFR, with the conventions of sfrmat5.

Per-row edge location and polynomial edge fit (steps 2-4), projection of the pixels into
supersampled bins along the fitted edge (step 6), and ESF -> LSF -> windowed DFT ->
derivative correction (steps 7-10). :func:`bayescap.measure.sfr.measure_sfr` runs them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bayescap.exceptions import MTFInputError


# --------------------------------------------------------------------------------------
# Small numerical helpers (sfrmat conventions)
# --------------------------------------------------------------------------------------
def _mround(x: Any) -> Any:
    """MATLAB ``round`` (half away from zero); numpy rounds half to even."""
    x = np.asarray(x, dtype=float)
    r = np.sign(x) * np.floor(np.abs(x) + 0.5)
    return r if r.ndim else float(r)


def _tukey_symmetric(k: np.ndarray, n: np.ndarray, alpha: float) -> np.ndarray:
    """Value at 0-based index ``k`` of the symmetric ``n``-point Tukey window."""
    n = np.asarray(n, dtype=float)
    m = (n - 1) / 2
    kk = np.minimum(k, n - 1 - k)
    with np.errstate(divide="ignore", invalid="ignore"):
        taper = 0.5 * (1 + np.cos(np.pi * (kk / (alpha * m) - 1)))
    w = np.where(kk <= alpha * m, taper, 1.0)
    return np.where(n <= 1, 1.0, w)


def _tukey_window(n: int, mid: Any, alpha: float = 1.0) -> np.ndarray:
    """Asymmetric Tukey window of length ``n`` centred at 1-based ``mid`` (sfrmat ``tukey2``).

    Vectorised over ``mid``: returns shape ``mid.shape + (n,)``.
    """
    mid = np.asarray(mid, dtype=float)[..., None]
    if n < 3:
        return np.ones(mid.shape[:-1] + (n,))
    n2 = _mround(2 * np.maximum(mid, n - mid))
    j = np.arange(n)
    k = np.where(mid >= n / 2, j, n2 - n + j)
    return _tukey_symmetric(k, n2, alpha)


def _hamming_window(n: int, mid: Any) -> np.ndarray:
    """Asymmetric Hamming window centred at 1-based ``mid`` (sfrmat ``ahamming``)."""
    mid = np.asarray(mid, dtype=float)[..., None] + 0.5
    wid = np.maximum(mid - 1, n - mid)
    i = np.arange(1, n + 1)
    return 0.54 + 0.46 * np.cos(np.pi * (i - mid) / wid)


def _row_window(n: int, mid: Any, window: str) -> np.ndarray:
    """Window used for the per-row edge location (ISO step 3/4)."""
    if window == "hamming":
        return _hamming_window(n, mid)
    # sfrmat5: "This step makes the edge finding more stable"
    return 0.95 * _tukey_window(n, mid, 1.0) + 0.05


def _fir2fix(n: int) -> np.ndarray:
    """Correction for the response of the 3-tap central difference (sfrmat ``fir2fix``).

    ``x/sin(x)`` with ``x = pi*i/(n+1)`` for the 1-based index ``i >= 2``, capped at 10.
    """
    corr = np.ones(n)
    i = np.arange(2, n + 1)
    x = np.pi * i / (n + 1)
    with np.errstate(divide="ignore"):
        corr[1:] = np.minimum(np.abs(x / np.sin(x)), 10.0)
    return corr


class _EdgeFit:
    """Polynomial x = P(y) fitted to per-row edge locations (sfrmat ``findedge2``).

    Fitted in a scaled variable for conditioning (as sfrmat does with ``polyfit``'s mu).
    """

    def __init__(self, y: np.ndarray, x: np.ndarray, npol: int) -> None:
        self.poly = np.polynomial.Polynomial.fit(y, x, npol)
        self.slope0 = float(self.poly.deriv()(0.0))  # dx/dy at y = 0 (fitme(end-1))

    def __call__(self, y: np.ndarray) -> np.ndarray:
        return self.poly(y)


# --------------------------------------------------------------------------------------
# ISO 12233 steps
# --------------------------------------------------------------------------------------
def _row_derivative(a: np.ndarray, sign: float) -> np.ndarray:
    """ISO step 2: derivative along rows with FIR [0.5, -0.5] (sfrmat ``deriv1``).

    MATLAB ``conv(row, [0.5 -0.5], 'same')`` gives ``0.5*(a[i+1]-a[i])`` at ``i``; the
    first and last samples are replaced by their neighbours.
    """
    c = np.empty_like(a)
    c[:, :-1] = sign * 0.5 * (a[:, 1:] - a[:, :-1])
    c[:, 0] = c[:, 1]
    c[:, -1] = c[:, -2]
    return c


def _centroids_1based(c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """ISO step 3: centroid of each row of ``c*w`` in 1-based index units, minus 0.5."""
    cw = c * w
    idx = np.arange(1, c.shape[1] + 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (cw @ idx) / cw.sum(axis=1) - 0.5


def _edge_locations(a: np.ndarray, sign: float, npol: int, window: str) -> tuple[np.ndarray, _EdgeFit]:
    """ISO steps 2-4 for one record: per-row locations and the refitted polynomial."""
    nlin, npix = a.shape
    c = _row_derivative(a, sign)
    y = np.arange(nlin, dtype=float)
    loc = _centroids_1based(c, _row_window(npix, (npix + 1) / 2, window)[None, :])
    if not np.all(np.isfinite(loc)):
        raise MTFInputError("edge location failed: derivative sums to zero in some rows (no edge?)")
    fit = _EdgeFit(y, loc, npol)
    loc = _centroids_1based(c, _row_window(npix, fit(y), window))
    if not np.all(np.isfinite(loc)):
        raise MTFInputError("edge location failed after re-windowing (no edge?)")
    return loc, _EdgeFit(y, loc, npol)


def _project(
    a: np.ndarray,
    x_edge: np.ndarray,
    ref: _EdgeFit,
    nbin: int,
    nlin: int,
) -> tuple[np.ndarray, int]:
    """ISO step 6: project pixels along the edge into 1/nbin-pixel bins (sfrmat ``project2``).

    ``a`` are the rows (any subset, possibly repeated) and ``x_edge`` the fitted edge
    position in each of them; ``nlin`` is the number of rows of the analysed array.  The
    bin origin is set by the full-data fit ``ref`` (``x - (x_edge - ref(0))`` with the bin
    offset from ``ref``'s slope at row 0, as sfrmat), so that bootstrap replicates, whose
    own polynomial may be extrapolated wildly at rows they do not contain, share the bin
    grid of the main analysis.  Returns the supersampled ESF (length ``npix*nbin``) and
    the number of empty bins that were filled.
    """
    npix = a.shape[1]
    nn = npix * nbin
    offset = int(_mround(-nbin * (nlin - 1) * ref.slope0))
    dl = abs(offset)
    offset = min(offset, 0)
    bwidth = nn + dl + 150
    p2 = x_edge - ref(np.zeros(1))[0]
    x = np.arange(npix, dtype=float)
    ling = np.ceil((x[None, :] - p2[:, None]) * nbin).astype(np.int64) - offset  # 0-based
    ling = np.clip(ling, 0, bwidth - 1).ravel()
    counts = np.bincount(ling, minlength=bwidth).astype(float)
    sums = np.bincount(ling, weights=a.ravel(), minlength=bwidth)
    start = int(_mround(0.5 * dl))
    n_empty = 0
    for i in range(start, start + nn):  # sequential neighbour fill, as sfrmat
        if counts[i] == 0:
            n_empty += 1
            if i == 0:
                counts[i], sums[i] = counts[i + 1], sums[i + 1]
            elif i == start + nn - 1:
                counts[i], sums[i] = counts[i - 1], sums[i - 1]
            else:
                counts[i] = (counts[i - 1] + counts[i + 1]) / 2
                sums[i] = (sums[i - 1] + sums[i + 1]) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        esf = sums[start : start + nn] / counts[start : start + nn]
    bad = ~np.isfinite(esf)
    if bad.any() and not bad.all():
        # Still empty after the sfrmat fill (only possible at the ends of the range, e.g.
        # for a bootstrap replicate lacking the first rows): nearest populated value.
        good = np.flatnonzero(~bad)
        pos = np.clip(np.searchsorted(good, np.flatnonzero(bad)), 0, good.size - 1)
        esf[bad] = esf[good[pos]]
    return esf, n_empty


def _esf_to_mtf(esf: np.ndarray, sign: float, window: str) -> np.ndarray:
    """ISO steps 7-10 for a stack of ESFs (shape (..., nn)); returns (..., nn//2+1).

    7. LSF by the central difference [0.5, 0, -0.5], ends replaced by neighbours; shifted so
       that its maximum (mean index of ties) sits at ``round((nn+1)/2)`` (zero fill).
    8. Tukey (alpha=1) or Hamming window centred at nn/2.
    9. |DFT| normalised by its zero-frequency value.
    10. Multiplied by the capped central-difference correction :func:`_fir2fix`.
    """
    esf = np.atleast_2d(esf)
    nb, nn = esf.shape
    c = np.empty_like(esf)
    c[:, 1:-1] = sign * 0.5 * (esf[:, 2:] - esf[:, :-2])
    c[:, 0] = c[:, 1]
    c[:, -1] = c[:, -2]
    idx = np.arange(1, nn + 1)
    ismax = c == c.max(axis=1, keepdims=True)
    mm = (ismax * idx).sum(axis=1) / ismax.sum(axis=1)
    shift = _mround(mm - _mround((nn + 1) / 2)).astype(np.int64)
    src = np.arange(nn)[None, :] + shift[:, None]
    valid = (src >= 0) & (src < nn)
    c = np.where(valid, np.take_along_axis(c, np.clip(src, 0, nn - 1), axis=1), 0.0)
    if window == "hamming":
        win = _hamming_window(nn, nn / 2)
    else:
        win = _tukey_window(nn, nn / 2, 1.0)
    spec = np.abs(np.fft.rfft(c * win, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        mtf = spec / spec[:, :1]
    return mtf * _fir2fix(mtf.shape[1])[None, :]
