"""The boundary tier of the pixel-averaged rounding moments (bayescap.model.offset_boundary) against
the exact evaluation (pixel_quantization._quantized_pixel_moments(..., exact=True)) and against an
independent quadrature where the moments are too small for the exact grid's absolute precision."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import log_ndtr

import bayescap.model.offset_boundary as OB
import bayescap.model.pixel_quantization as PQ
from bayescap.model.offset_fourier import offset_fourier_moments
from bayescap.model.pixel_quantization import _quantized_pixel_moments

#: the bound of the served elements: relative to V, E4 and to H's scale, as for the Fourier tier
REL = 1e-4


def _regime_set(n, seed):
    """Random (δ, s, σ_o) over the small-s regime (s 1e-3-0.1 DN log-uniform, σ_o 1e-4-0.4 DN), half of
    them with δ near an integer DN (the dark rows of a sensor with an integer black level), plus the
    offsets and spreads that took the time in fits of 8-bit zoo sensors (draw20, draw25)."""
    rng = np.random.default_rng(seed)
    d = np.where(rng.uniform(size=n) < 0.5, rng.uniform(-0.5, 0.5, n), rng.normal(0.0, 0.02, n))
    s = np.exp(rng.uniform(np.log(1e-3), np.log(0.1), n))
    so = np.exp(rng.uniform(np.log(1e-4), np.log(0.4), n))
    e_d = np.array([0.0, 0.01, 0.3, -0.45, 0.5])
    e_s = np.array([0.005, 0.0125, 0.02, 0.045, 0.065, 0.1])
    e_so = np.array([1e-4, 0.003, 0.0038, 0.02, 0.037, 0.05, 0.11, 0.3])
    gd, gs, gso = (a.ravel() for a in np.meshgrid(e_d, e_s, e_so, indexing="ij"))
    return np.concatenate([d, gd]), np.concatenate([s, gs]), np.concatenate([so, gso])


def _grid_within_its_bound(s, so):
    """Where the exact grid's 1 024 points meet its own aliasing bound (pixel_quantization._QG_C):
    below, with s and σ_o both under ~0.005 DN, the reference itself is off."""
    a = 2.0 * np.pi**2 * so * so
    b = 0.5 * np.pi**2 * s * s
    return 1024**2 * a * b / (a + b) >= PQ._QG_C


def _h_scale(H, so):
    # H = var_o(pixel means) − σ_o² may cross zero: relative to the larger of |H| and σ_o² + H
    return np.maximum(np.abs(H), so * so + H)


def test_boundary_tier_within_its_bound_of_the_exact_moments():
    """On ~1 000 random (δ, s, σ_o) of the small-s regime where the exact grid meets its own bound:
    H within 1e-4 of the exact one relative to its scale (measured 2.9e-7 on 11 600 points), V and
    E4 where the exact ones are ≥ 1e-10 (the grid's absolute error is ~1e-13; below, the next test;
    measured 2.8e-7 and 6.1e-6: the neglected two-boundary products at s = 0.1 DN, the 16 nodes near a
    boundary)."""
    d, s, so = _regime_set(1200, 3)
    ok = _grid_within_its_bound(s, so)
    d, s, so = d[ok], s[ok], so[ok]
    V0, E40, H0 = _quantized_pixel_moments(d, s, so, exact=True)
    served, V, E4, H = OB.boundary_moments(d, s, so)
    assert served.sum() > 800 and np.all(served[np.hypot(s, so) <= OB._TAU_MAX])
    assert np.max(np.abs(H - H0)[served] / _h_scale(H0, so)[served]) <= REL
    for got, ref in ((V, V0), (E4, E40)):
        big = served & (ref >= 1e-10)
        assert big.sum() > 300
        assert np.max(np.abs(got - ref)[big] / ref[big]) <= REL


def _by_quadrature(d, s, so, e4=False):
    """V = E_o[pq] (or E4 = E_o[pq(1 − 2pq)]) summed over the boundaries, p = Φ(u), u = (o − b)/s, by
    adaptive quadrature of the logarithm of the integrand scaled by its value at the peak (no
    underflow however small V is)."""
    total = 0.0
    for b in OB._B:
        tau2 = s * s + so * so
        u0, w = (d - b) * s / tau2, so / np.sqrt(tau2)

        def lf(u, b=b):
            lpq = log_ndtr(u) + log_ndtr(-u)
            return (
                -0.5 * ((b + s * u - d) / so) ** 2
                + np.log(s / (so * np.sqrt(2 * np.pi)))
                + lpq
                + (np.log1p(-2 * np.exp(lpq)) if e4 else 0.0)
            )

        l0 = lf(u0)
        val, _ = quad(lambda u: np.exp(lf(u) - l0), u0 - 12 * w - 3, u0 + 12 * w + 3, epsabs=0, epsrel=1e-12, limit=200)
        total += np.exp(l0) * val
    return total


def test_boundary_tier_keeps_relative_precision_of_tiny_moments():
    """Far from every boundary V is far below the exact grid's absolute precision (1e-12 to 1e-300):
    the served V and E4 are within 1e-4 (measured 1.5e-13) of an adaptive quadrature of the same
    integrals in logarithms."""
    d = np.array([0.1, 0.0, 0.01, -0.2, 0.3, 0.0])
    s = np.array([0.0125, 0.065, 0.045, 0.02, 0.005, 0.06])
    so = np.array([0.0038, 0.037, 0.02, 0.05, 0.01, 0.03])
    served, V, E4, _ = OB.boundary_moments(d, s, so)
    assert np.all(served)
    ref = np.array([_by_quadrature(*x) for x in zip(d, s, so)])
    assert np.all(ref > 0) and ref.min() < 1e-100 and ref.max() < 1e-7
    np.testing.assert_allclose(V, ref, rtol=REL, atol=0)
    np.testing.assert_allclose(E4, [_by_quadrature(*x, e4=True) for x in zip(d, s, so)], rtol=REL, atol=0)


def test_boundary_tier_serves_the_slow_regime(monkeypatch):
    """The (δ, s, σ_o) that took minutes in fits of 8-bit sensors with 0.05 DN of read noise (offsets
    at an integer DN, s 5e-4-0.1 DN, σ_o 0.003-0.3 DN: the grid needed 64-1 024 points) never reach the
    periodic grid, and get the boundary tier's numbers (but for the few the Fourier tier serves)."""

    def no_grid(*args, **kwargs):
        raise AssertionError("the periodic grid was used in the boundary tier's regime")

    rng = np.random.default_rng(4)
    n = 400
    d = rng.normal(0.0, 0.01, n)
    s = np.exp(rng.uniform(np.log(5e-4), np.log(0.1), n))
    so = np.exp(rng.uniform(np.log(0.003), np.log(0.3), n))
    assert np.sum(so > 0.1) > 50 and np.sum(s < 0.005) > 50
    monkeypatch.setattr(PQ, "_grid_moments", no_grid)
    got = _quantized_pixel_moments(d, s, so)
    by_series = offset_fourier_moments(d, s, so)[0]  # the Fourier tier, tried first, takes a few
    served, *tier = OB.boundary_moments(d, s, so)
    assert np.all(served) and np.mean(by_series) < 0.2
    for a, b in zip(got, tier):
        np.testing.assert_array_equal(a[~by_series], b[~by_series])
    with pytest.raises(AssertionError, match="periodic grid"):  # the reference path still takes the grid
        _quantized_pixel_moments(d[:5], s[:5], so[:5], exact=True)


def test_boundary_tier_elementwise_and_nan_safe():
    """Each element's numbers are its own, bit for bit, in sub-arrays of any size; NaN, a spread below
    the tier's, s or τ above it are not served."""
    d, s, so = _regime_set(600, 9)
    full = OB.boundary_moments(d, s, so)
    assert full[0].sum() > 100
    rng = np.random.default_rng(1)
    for m in (1, 2, 7, 64, 129):
        idx = np.sort(rng.choice(d.size, m, replace=False))
        for a, b in zip(full, OB.boundary_moments(d[idx], s[idx], so[idx])):
            np.testing.assert_array_equal(a[idx], b)
    served, *_ = OB.boundary_moments(
        np.array([0.0, 0.0, 0.0, 0.0, 0.49, 0.49]),
        np.array([np.nan, 0.01, 0.01, 0.2, 0.01, 0.01]),
        np.array([0.01, np.nan, 5e-5, 0.01, 0.5, 0.01]),
    )
    np.testing.assert_array_equal(served, [False] * 5 + [True])
