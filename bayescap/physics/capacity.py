"""Tonal range, MTF loss and image information capacity (Tisse et al. 2008, Eq. 2, 6-9).

Everything here is vectorised over a leading axis of posterior draws: pass arrays of shape
``(n_draws,)`` and get arrays back; no Python loop runs over draws.

Conventions (also in the README, "How capacity is computed"):

* The noise model is Eq. 1, quadratic in the mean signal ``S`` (electrons):
  ``σ²(S) = a + b·S + c·S²`` (:class:`bayescap.physics.noise.NoiseCoefficients`).
* Tonal range, Eq. 7, is evaluated on an **8-bit-equivalent grey scale over the sensor's dynamic
  range**: the signal axis from 0 to ``S_max`` (the largest non-saturating signal, Eq. 2) is
  mapped linearly onto ``n_levels = 256`` grey levels, so one grey level is ``S_max/256``
  electrons, and the ``max(σ, 1)`` floor of Eq. 7 acts in those grey levels: in electrons the
  integrand is ``1/max(σ(S), S_max/256)``. The integral runs over the dynamic range, from
  ``S_min = σ(0)`` (the dark noise floor, Eq. 2's denominator) to ``S_max``. Hence
  ``TR ≤ 256`` and ``b' = log2 TR ≤ 8`` bits, as in the paper's Figs. 4 and 8.
* The integral of ``1/sqrt(a + bS + cS²)`` is evaluated in closed form (log/asinh), piecewise
  with the floor; it is exact to rounding (tested against quadrature).
* MTF loss, Eq. 9: ``Δs = π f_N⁻² ∫₀^{f_N} f log2 MTF(f) df`` with ``f`` in cycles per pixel
  and ``f_N = 0.5``. Where the MTF reaches zero inside the band (a lens cut-off ``f_c`` below
  Nyquist), the frequencies above ``f_c`` carry no image information at all: the band is cut,
  the integral runs over ``[0, f_c]`` and the lost band costs ``log2((f_c/f_N)²)`` bits, the
  fraction of the Nyquist disc that survives. The result stays finite, and the report says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bayescap.physics.noise import NoiseCoefficients

__all__ = [
    "integral_inv_sqrt_quadratic",
    "tonal_range",
    "mtf_loss_bits",
    "mtf_loss_bits_eq8",
    "information_capacity_bits",
    "effective_pixels",
    "tonal_range_bits",
    "MTFLoss",
    "NYQUIST_CY_PER_PX",
    "N_GREY_LEVELS",
]

NYQUIST_CY_PER_PX = 0.5
N_GREY_LEVELS = 256


def _antiderivative_diff(a, b, c, s1, s2):
    """∫_{s1}^{s2} dS / sqrt(a + bS + cS²), s2 ≥ s1 ≥ 0, a > 0, b ≥ 0, c ≥ 0 (stable form).

    For c > 0 the antiderivative is ln(2√c·√q + 2cS + b)/√c. The difference is written as
    log1p of a small ratio divided by √c, computed as y·log1p(z)/z with z = √c·y, so that
    c → 0 (negligible PRNU) loses no digits and tends to the c = 0 result 2(√q₂ − √q₁)/b.
    """
    a, b, c, s1, s2 = np.broadcast_arrays(*(np.asarray(x, float) for x in (a, b, c, s1, s2)))
    q1 = a + b * s1 + c * s1 * s1
    q2 = a + b * s2 + c * s2 * s2
    r1, r2 = np.sqrt(q1), np.sqrt(q2)
    ds = s2 - s1
    rc = np.sqrt(c)
    a1 = 2.0 * rc * r1 + 2.0 * c * s1 + b  # > 0
    # (A2 - A1)/√c without cancellation:
    y = (2.0 * ds * (b + c * (s1 + s2)) / (r1 + r2) + 2.0 * rc * ds) / a1
    z = rc * y
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(z > 1e-8, np.log1p(z) / np.where(z > 1e-8, z, 1.0), 1.0 - z / 2.0 + z * z / 3.0)
    return y * ratio


def integral_inv_sqrt_quadratic(a, b, c, s1, s2, floor=0.0):
    """∫_{s1}^{s2} dS / max(sqrt(a + bS + cS²), floor), vectorised, closed form.

    ``σ(S)`` is increasing for S ≥ 0, so the floor applies on ``[s1, S*]`` with σ(S*) = floor;
    that part contributes ``(S* − s1)/floor``. Returns 0 where s2 ≤ s1.
    """
    a, b, c, s1, s2, floor = np.broadcast_arrays(*(np.asarray(x, float) for x in (a, b, c, s1, s2, floor)))
    s2 = np.maximum(s2, s1)
    # S* solves c S² + b S + (a − floor²) = 0, the positive root (stable form)
    d = a - floor * floor
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = np.sqrt(np.maximum(b * b - 4.0 * c * d, 0.0))
        s_star = np.where(d >= 0, 0.0, (-2.0 * d) / (b + disc))
    s_star = np.clip(s_star, s1, s2)
    flat_part = np.where(floor > 0, (s_star - s1) / np.where(floor > 0, floor, 1.0), 0.0)
    return flat_part + _antiderivative_diff(a, b, c, s_star, s2)


def tonal_range(coeffs: NoiseCoefficients, s_max_e, *, n_levels: int = N_GREY_LEVELS, s_min_e=None):
    """Tonal range TR (Eq. 7) in distinguishable grey levels, 8-bit-equivalent scale.

    Parameters
    ----------
    coeffs : noise model σ²(S) = a + bS + cS² (e⁻²), arrays over draws.
    s_max_e : largest non-saturating signal (e⁻), the top of the dynamic range (Eq. 2).
    n_levels : grey levels spanning [0, s_max_e]; the max(σ, 1) floor acts in these units.
    s_min_e : bottom of the dynamic range (e⁻); default σ(0), the dark noise floor (Eq. 2).

    Returns TR (≤ n_levels); b' = log2(TR).
    """
    s_max_e = np.asarray(s_max_e, float)
    s_min = np.sqrt(coeffs.a) if s_min_e is None else np.asarray(s_min_e, float)
    grey_e = s_max_e / n_levels
    return integral_inv_sqrt_quadratic(coeffs.a, coeffs.b, coeffs.c, s_min, s_max_e, floor=grey_e)


@dataclass(frozen=True)
class MTFLoss:
    """Result of :func:`mtf_loss_bits`: Δs (bits, ≤ 0) and how the band was treated."""

    delta_s_bits: np.ndarray
    band_cut: bool
    f_end_cy_per_px: float
    band_cut_bits: float

    @property
    def has_draws(self) -> bool:
        """Whether Δs holds the MTF's own draws (a measured MTF with its uncertainty, from
        ``mtf_loss_bits(..., draws=True)``) rather than one value."""
        ds = np.asarray(self.delta_s_bits, float)
        return ds.ndim == 1 and ds.size > 1

    def to_dict(self):
        return {
            "band_cut": self.band_cut,
            "band_end_cy_per_px": self.f_end_cy_per_px,
            "band_cut_bits": self.band_cut_bits,
        }


@lru_cache(maxsize=32)
def _leggauss(n):
    """Gauss-Legendre nodes and weights on [-1, 1], cached (leggauss(256) costs ~25 ms)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def _gauss_legendre(n, lo, hi):
    x, w = _leggauss(n)
    return 0.5 * (hi - lo) * x + 0.5 * (hi + lo), 0.5 * (hi - lo) * w


def mtf_loss_bits(
    mtf, *, n_nodes: int = 256, f_nyquist_cy_per_px: float = NYQUIST_CY_PER_PX, draws: bool = False
) -> MTFLoss:
    """MTF loss Δs by Eq. 9 (bits, ≤ 0) for a radial MTF.

    ``mtf`` is an MTF component (``.radial(f)``, ``.cutoff_cy_per_px``) or a plain callable of
    frequency (cy/px). With ``draws=True`` and a component that carries draws, Δs is returned
    per draw. Gauss-Legendre quadrature on ``[0, f_end]`` (``f_end = min(f_N, cut-off)``);
    the integrand ``f log2 MTF`` is smooth except for a logarithmic end-point singularity at a
    lens cut-off, which the nodes never touch. A cut band adds ``log2((f_end/f_N)²)``.
    """
    cutoff = float(getattr(mtf, "cutoff_cy_per_px", np.inf))
    f_end = min(f_nyquist_cy_per_px, cutoff)
    band_cut = f_end < f_nyquist_cy_per_px
    if f_end <= 0:
        raise ValueError("the MTF is zero at every frequency: no image information passes")
    f, w = _gauss_legendre(n_nodes, 0.0, f_end)
    if draws and hasattr(mtf, "radial"):
        try:
            m = mtf.radial(f, draws=True)
        except TypeError:
            m = mtf.radial(f)
    else:
        m = mtf.radial(f) if hasattr(mtf, "radial") else mtf(f)
    m = np.asarray(m, float)
    tiny = np.finfo(float).tiny
    if np.any(m <= 0):
        # a zero inside the band that the component did not declare: cut the band there
        zero_idx = np.argmax(np.any(np.atleast_2d(m) <= 0, axis=0))
        f_zero = float(f[zero_idx])
        if zero_idx == 0:
            raise ValueError("the MTF is zero at every frequency: no image information passes")
        return mtf_loss_bits(_CutAt(mtf, f_zero), n_nodes=n_nodes, f_nyquist_cy_per_px=f_nyquist_cy_per_px, draws=draws)
    integral = np.sum(w * f * np.log2(np.maximum(m, tiny)), axis=-1)
    ds = np.pi / f_nyquist_cy_per_px**2 * integral
    cut_bits = 2.0 * np.log2(f_end / f_nyquist_cy_per_px) if band_cut else 0.0
    return MTFLoss(
        delta_s_bits=ds + cut_bits, band_cut=bool(band_cut), f_end_cy_per_px=float(f_end), band_cut_bits=float(cut_bits)
    )


class _CutAt:
    """Wraps an MTF whose first zero inside the band is at ``f_zero``."""

    def __init__(self, mtf, f_zero):
        self._mtf, self.cutoff_cy_per_px = mtf, f_zero

    def radial(self, f, draws=False):
        if hasattr(self._mtf, "radial"):
            try:
                return self._mtf.radial(f, draws=draws) if draws else self._mtf.radial(f)
            except TypeError:
                return self._mtf.radial(f)
        return self._mtf(f)


# --------------------------------------------------------------------------------------------
# Eq. 8: the 2-D MTF loss over the Nyquist rectangle (anisotropic MTFs)
# --------------------------------------------------------------------------------------------


def _quadrant_breaks(fn1, fn2, r_cut):
    """Angles in [0, π/2] where r_max(θ) = min(fn1/|cos θ|, fn2/|sin θ|, r_cut) has a kink."""
    br = {0.0, 0.5 * np.pi, float(np.arctan2(fn2, fn1))}
    if np.isfinite(r_cut):
        if r_cut > fn1:
            br.add(float(np.arccos(fn1 / r_cut)))
        if r_cut > fn2:
            br.add(float(np.arcsin(fn2 / r_cut)))
    return sorted(b for b in br if 0.0 <= b <= 0.5 * np.pi)


def _polar_nodes(fn1, fn2, r_cut, domain, n):
    """Gauss-Legendre nodes (fx, fy, weight) covering domain ∩ {r < r_cut} in polar coordinates.

    θ is split at every kink of the boundary so that each piece is smooth; the weights include
    the Jacobian r. Also returns the area of the region (∫ r_max²/2 dθ, same nodes).
    """
    q = _quadrant_breaks(fn1, fn2, r_cut if domain == "square" else np.inf)
    # all four quadrants, by reflection
    breaks = sorted(set(q) | {np.pi - b for b in q} | {np.pi + b for b in q} | {2 * np.pi - b for b in q})
    xs, ws = _leggauss(n)
    th_all, wth_all = [], []
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        if hi - lo < 1e-15:
            continue
        th_all.append(0.5 * (hi - lo) * xs + 0.5 * (hi + lo))
        wth_all.append(0.5 * (hi - lo) * ws)
    th = np.concatenate(th_all)
    wth = np.concatenate(wth_all)
    c, s = np.abs(np.cos(th)), np.abs(np.sin(th))
    if domain == "square":
        with np.errstate(divide="ignore"):
            rmax = np.minimum(
                np.where(c > 0, fn1 / np.where(c > 0, c, 1), np.inf),
                np.where(s > 0, fn2 / np.where(s > 0, s, 1), np.inf),
            )
    else:  # inscribed disc
        rmax = np.full_like(th, min(fn1, fn2))
    rmax = np.minimum(rmax, r_cut)
    u = 0.5 * (xs + 1.0)  # radial nodes on [0, 1]
    wu = 0.5 * ws
    r = rmax[:, None] * u[None, :]
    w = wth[:, None] * rmax[:, None] ** 2 * (u * wu)[None, :]  # r dr dθ
    area = float(np.sum(wth * rmax**2) / 2.0)
    return r * np.cos(th)[:, None], r * np.sin(th)[:, None], w, area


def mtf_loss_bits_eq8(mtf, *, n: int = 64, f_nyquist_cy_per_px=NYQUIST_CY_PER_PX, domain: str = "square") -> MTFLoss:
    """MTF loss Δs by Eq. 8 (bits, ≤ 0): the mean of ``log2 MTF²(f1, f2)`` over the Nyquist band.

    ``Δs = (4 f_N1 f_N2)⁻¹ ∬ log2 MTF²(f1, f2) df1 df2`` over ``[−f_N1, f_N1] × [−f_N2, f_N2]``,
    ``f`` in cy/px (the paper writes the angular frequency ``w``; the normalisation by
    ``4 f_N1 f_N2`` makes the mean over the band, which is unit-free). Uses ``mtf.mtf2d`` and so
    handles anisotropic components (:class:`~bayescap.physics.optics.LShapedAperture`).

    Parameters
    ----------
    mtf : an MTF component (``mtf2d``, ``cutoff_cy_per_px``) or a callable ``m(fx, fy)``.
    n : Gauss-Legendre nodes per angular piece and per radius (polar quadrature: the θ range is
        split at every kink of the band boundary, so each piece is smooth).
    f_nyquist_cy_per_px : ``f_N`` or ``(f_N1, f_N2)``.
    domain : ``"square"`` (Eq. 8) or ``"disc"``: the inscribed disc of radius ``f_N``, still
        normalised by the square. For an isotropic MTF the disc gives exactly Eq. 9
        (:func:`mtf_loss_bits`); a constant MTF ``m`` gives ``2 log2 m`` on the square and
        ``(π/2) log2 m`` on the disc.

    Where the MTF is zero inside the band. A zero *region* (beyond a lens cut-off ``f_c``, the
    smallest ``cutoff_cy_per_px`` of the components) carries no image information: as in
    :func:`mtf_loss_bits`, the band is cut to ``domain ∩ {|f| < f_c}``, the integral runs over
    what is left (still normalised by the square) and the cut costs ``log2(A_left/A_domain)``
    bits; ``MTFLoss.band_cut`` reports it and ``band_cut_bits`` gives that cost. On the square,
    the corners (``|f| > f_N``) are lost first, when ``f_c < √2 f_N``. Isolated zero *lines*
    (sinc zeros of a wide aperture) are integrable logarithmic singularities and leave Δs
    finite; a node that lands exactly on a zero is treated like an undeclared cut-off at that
    radius, as in :func:`mtf_loss_bits`.
    """
    if domain not in ("square", "disc"):
        raise ValueError(f"domain must be 'square' or 'disc', got {domain!r}")
    fn1, fn2 = (
        (float(f_nyquist_cy_per_px),) * 2
        if np.ndim(f_nyquist_cy_per_px) == 0
        else tuple(float(x) for x in f_nyquist_cy_per_px)
    )
    if not (fn1 > 0 and fn2 > 0):
        raise ValueError(f"Nyquist frequencies must be positive, got {f_nyquist_cy_per_px}")
    if domain == "disc" and fn1 != fn2:
        raise ValueError("domain='disc' needs f_N1 == f_N2 (a circular band)")
    fn2d = mtf.mtf2d if hasattr(mtf, "mtf2d") else mtf
    r_cut = float(getattr(mtf, "cutoff_cy_per_px", np.inf))
    if r_cut <= 0:
        raise ValueError("the MTF is zero at every frequency: no image information passes")
    full_area = 4.0 * fn1 * fn2 if domain == "square" else np.pi * fn1 * fn1
    for _ in range(8):  # undeclared zeros: shrink the cut radius and retry
        fx, fy, w, area = _polar_nodes(fn1, fn2, r_cut, domain, n)
        m = np.asarray(fn2d(fx, fy), float)
        bad = ~(m > 0)
        if not np.any(bad):
            break
        r_zero = float(np.min(np.hypot(fx, fy)[bad]))
        if r_zero <= 0:
            raise ValueError("the MTF is zero at zero frequency: no image information passes")
        r_cut = r_zero
    else:  # pragma: no cover - pathological input
        raise ValueError("could not isolate the zeros of the MTF inside the band")
    integral = float(np.sum(w * 2.0 * np.log2(m)))
    ds = integral / (4.0 * fn1 * fn2)
    band_cut = area < full_area * (1.0 - 1e-12)
    cut_bits = float(np.log2(area / full_area)) if band_cut else 0.0
    return MTFLoss(
        delta_s_bits=np.asarray(ds + cut_bits),
        band_cut=bool(band_cut),
        f_end_cy_per_px=float(r_cut),
        band_cut_bits=cut_bits,
    )


def tonal_range_bits(tonal_range_levels):
    """``b' = log2 TR`` (bits per pixel, Eq. 6/7), with TR floored at one grey level (b' ≥ 0)."""
    return np.log2(np.maximum(tonal_range_levels, 1.0))


def effective_pixels(n_pixels, delta_s_bits):
    """``s' = s · 2^Δs`` (Eq. 6): the pixel count ``s`` after the MTF loss ``Δs`` (bits)."""
    return np.asarray(n_pixels, float) * np.exp2(np.asarray(delta_s_bits, float))


def information_capacity_bits(n_pixels, delta_s_bits, tonal_range_levels=None, *, bits_per_pixel=None):
    """Eq. 6 with blur and noise: ``C = s' · b'`` with ``s' = s · 2^Δs`` effective pixels and
    ``b' = log2 TR`` bits per pixel (:func:`tonal_range_bits`), or ``b'`` given directly as
    ``bits_per_pixel``. Vectorised (arrays broadcast)."""
    if (tonal_range_levels is None) == (bits_per_pixel is None):
        raise TypeError("give exactly one of tonal_range_levels and bits_per_pixel")
    if bits_per_pixel is None:
        bits_per_pixel = tonal_range_bits(np.asarray(tonal_range_levels, float))
    return effective_pixels(n_pixels, delta_s_bits) * bits_per_pixel
