"""The paper's integrals by adaptive quadrature, the reference for their closed forms:
:data:`TR_CASES`, :func:`tr_reference`, :func:`tr_simpson`, :func:`ds_reference`."""

from __future__ import annotations

import warnings

import numpy as np

# --------------------------------------------------------------------------- the paper's integrals by quadrature
#: (name, a e⁻², b, c, s1 e⁻, s2 e⁻, floor e⁻)
TR_CASES = [
    ("typical: σr 5 e⁻, PRNU 0.5 %, FW 10⁴ (no floor)", 25.0 + 1 / 12, 1.0, 0.005**2, 5.0, 1e4, 0.0),
    ("typical with the 8-bit floor (FW/256)", 25.0 + 1 / 12, 1.0, 0.005**2, 5.0, 1e4, 1e4 / 256),
    ("large PRNU 3 %, FW 10⁵", 100.0, 1.0, 0.03**2, 10.0, 1e5, 1e5 / 256),
    ("read noise 0.05 e⁻, from S = 0, no floor", 0.05**2, 1.0, 1e-6, 0.0, 1e3, 0.0),
    ("read noise 0.05 e⁻, from S = 0, floor", 0.05**2, 1.0, 1e-6, 0.0, 1e3, 1e3 / 256),
    ("read noise 200 e⁻, FW 10⁶ (floor)", 200.0**2, 1.0, 0.01**2, 200.0, 1e6, 1e6 / 256),
]


def tr_reference(a, b, c, s1, s2, floor):
    """∫ dS / max(σ(S), floor), σ² = a + bS + cS², from s1 to s2 by adaptive quadrature split at the
    floor crossing: (value, error estimate)."""
    from scipy import integrate

    f = lambda s: 1.0 / max(np.sqrt(a + b * s + c * s * s), floor)
    d = a - floor * floor
    pts = []
    if d < 0:
        s_star = (-2.0 * d) / (b + np.sqrt(b * b - 4 * c * d))
        if s1 < s_star < s2:
            pts = [s_star]
    edges = [s1] + pts + [s2]
    tot, err = 0.0, 0.0
    for lo, hi in zip(edges[:-1], edges[1:]):
        # substitute s = lo + u² near a 1/sqrt singularity at s = 0 (a → 0): smooth integrand
        g = lambda u, lo=lo: 2.0 * u * f(lo + u * u)
        v, e = integrate.quad(g, 0.0, np.sqrt(hi - lo), epsabs=0.0, epsrel=1e-13, limit=500)
        tot, err = tot + v, err + e
    return tot, err


def tr_simpson(a, b, c, s1, s2, floor, n, grid):
    """The same integral by Simpson's rule on ``n`` points, ``grid`` "log" or "linear"."""
    from scipy import integrate

    if grid == "log":
        lo = s1 if s1 > 0 else 1e-6 * s2  # a log grid cannot start at 0
        s = np.geomspace(lo, s2, n)
    else:
        s = np.linspace(s1, s2, n)
    y = 1.0 / np.maximum(np.sqrt(a + b * s + c * s * s), floor)
    return float(integrate.simpson(y, x=s))


def ds_reference(mtf):
    """The MTF loss Δs (bits) of ``mtf`` by adaptive quadrature (substituted at a cut-off inside the band)."""
    from scipy import integrate

    fn = 0.5
    cutoff = float(getattr(mtf, "cutoff_cy_per_px", np.inf))
    f_end = min(fn, cutoff)
    r = mtf.radial if hasattr(mtf, "radial") else mtf
    g = lambda f: f * np.log2(max(float(r(np.array([f]))[0]), 1e-300))
    if f_end < fn:
        # the integrand has a log singularity at the cut-off: f = f_end (1 − t²) makes it t·log t
        h = lambda t: 2.0 * f_end * t * g(f_end * (1.0 - t * t))
        with warnings.catch_warnings():  # quad reports roundoff near 1e-13: converged to that
            warnings.simplefilter("ignore", integrate.IntegrationWarning)
            v, _ = integrate.quad(h, 0.0, 1.0, epsabs=0.0, epsrel=1e-13, limit=500)
    else:
        v, _ = integrate.quad(g, 0.0, f_end, epsabs=0.0, epsrel=1e-13, limit=500)
    cut = 2.0 * np.log2(f_end / fn) if f_end < fn else 0.0
    return np.pi / fn**2 * v + cut
