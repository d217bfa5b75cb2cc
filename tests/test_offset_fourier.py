"""The tabulated Fourier series of the pixel-averaged rounding moments (bayescap.model.offset_fourier)
against the exact evaluation (pixel_quantization._quantized_pixel_moments(..., exact=True))."""

from __future__ import annotations

import numpy as np

import bayescap.model.offset_fourier as F
from bayescap.model.offset_boundary import boundary_moments
from bayescap.model.pixel_quantization import _quantized_pixel_moments

#: the bound the series is served under: relative to V, E4 and to H's scale (the module docstring)
REL = 1e-4


def _rel_errors(got, ref, so):
    (V, E4, H), (V0, E40, H0) = got, ref
    with np.errstate(divide="ignore", invalid="ignore"):  # V0 = 0 where s → 0 (never served)
        return _rel(V, E4, H, V0, E40, H0, so)


def _rel(V, E4, H, V0, E40, H0, so):
    # H = var_o(pixel means) − σ_o² may cross zero: its error relative to the larger of |H| and the
    # spatial variance of the pixel means it enters, σ_o² + H
    return (
        np.abs(V - V0) / V0,
        np.abs(E4 - E40) / E40,
        np.abs(H - H0) / np.maximum(np.abs(H0), so * so + H0),
    )


def _domain_set(n, seed):
    """Random (δ, s, σ_o) over the domain the model calls the moments on (s² < 0.2 or s² + σ_o² < ½
    DN², prediction._quantized_var), log-uniform in s from 1e-4 DN and σ_o from 1e-5 DN, plus the
    edges: δ at 0 and ±½, s and σ_o at the table's ends and just outside, σ_o near the uniform cut
    at 0.7 DN."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(-0.5, 0.5, n)
    s = np.exp(rng.uniform(np.log(1e-4), np.log(0.75), n))
    so = np.exp(rng.uniform(np.log(1e-5), np.log(0.7), n))
    e_d = np.array([-0.5, -0.25, 0.0, 0.1, 0.49, 0.5])
    e_s = np.array([1e-3, F._S0 * 0.999, F._S0, F._S0 * 1.001, 0.02, 0.1, 0.3, 0.447, 0.6, 0.7])
    e_so = np.array([0.0, 1e-6, F._SO_MIN * 0.999, F._SO_MIN, 0.01, 0.05, 0.2, 0.5, 0.69, 0.7])
    gd, gs, gso = (a.ravel() for a in np.meshgrid(e_d, e_s, e_so, indexing="ij"))
    d, s, so = np.concatenate([d, gd]), np.concatenate([s, gs]), np.concatenate([so, gso])
    keep = (s * s < 0.2) | (s * s + so * so < 0.5)
    return d[keep], s[keep], so[keep]


def test_series_within_its_bound_of_the_exact_moments():
    """On ~6 000 random (δ, s, σ_o) and the 600 edge points: where the series serves an element,
    V, E4 and H are within 1e-4 (relative) of the exact evaluation (measured: < 4e-6 on 200 000
    points); where it does not, the boundary tier's or the exact ones, bit for bit; and it serves the
    bulk of where sensors sit (s from 0.1 to 0.7 DN, σ_o from 0.02 to 0.7 DN, V ≥ 1e-3)."""
    d, s, so = _domain_set(6000, 11)
    ref = _quantized_pixel_moments(d, s, so, exact=True)
    got = _quantized_pixel_moments(d, s, so)
    served, *series = F.offset_fourier_moments(d, s, so)
    assert served.sum() > 1000
    for a, b in zip(got, series):  # what the model gets is the series where served
        np.testing.assert_array_equal(a[served], b[served])
    for name, r in zip(("V", "E4", "H"), _rel_errors(got, ref, so)):
        assert np.max(r[served]) <= REL, name
    # elsewhere the boundary tier's numbers where it serves (tests/test_offset_boundary.py), the exact ones
    # bit for bit where it does not
    by_boundary, *boundary = boundary_moments(d, s, so)
    for a, b, c in zip(got, ref, boundary):
        np.testing.assert_array_equal(a[~served & by_boundary], c[~served & by_boundary])
        np.testing.assert_array_equal(a[~served & ~by_boundary], b[~served & ~by_boundary])
    assert np.sum(~served & ~by_boundary) > 500
    bulk = (s >= 0.1) & (so >= 0.02) & (ref[0] >= 1e-3)
    assert bulk.sum() > 300 and np.all(served[bulk])
    # the edges: s below the table and σ_o below its minimum are never served
    assert not np.any(served[(s < F._S0) | (so < F._SO_MIN)])


def test_series_elementwise_and_nan_safe():
    """Each element's numbers are its own, bit for bit, in sub-arrays of any size (a stacked
    evaluation, PTCModelStack, relies on it); NaN inputs are not served."""
    rng = np.random.default_rng(5)
    n = 2000
    d = rng.uniform(-0.5, 0.5, n)
    s = rng.uniform(0.01, 0.7, n)
    so = rng.uniform(0.005, 0.7, n)
    full = F.offset_fourier_moments(d, s, so)
    for m in (1, 2, 7, 64, 129):
        idx = np.sort(rng.choice(n, m, replace=False))
        for a, b in zip(full, F.offset_fourier_moments(d[idx], s[idx], so[idx])):
            np.testing.assert_array_equal(a[idx], b)
    served, *_ = F.offset_fourier_moments(np.array([0.1, 0.1]), np.array([np.nan, 0.3]), np.array([0.1, np.nan]))
    assert not np.any(served)


def test_shipped_offset_fourier_table_is_a_fresh_build(monkeypatch, tmp_path):
    """The shipped table is what _build_offset_fourier_table computes now; a missing file is rebuilt."""
    fresh = F._build_offset_fourier_table()
    with np.load(F.OFFSET_FOURIER_TABLE_FILE) as z:
        np.testing.assert_array_equal(z["s"], fresh["s"])
        np.testing.assert_allclose(z["coef"], fresh["coef"], rtol=0, atol=1e-15)
    assert F.OFFSET_FOURIER_TABLE_FILE.stat().st_size < 2_000_000
    out = tmp_path / "t.npz"
    F.write_offset_fourier_table(out)
    monkeypatch.setattr(F, "OFFSET_FOURIER_TABLE_FILE", tmp_path / "missing.npz")
    np.testing.assert_array_equal(F._load_table()["coef"], fresh["coef"])
    monkeypatch.setattr(F, "OFFSET_FOURIER_TABLE_FILE", out)
    np.testing.assert_array_equal(F._load_table()["coef"], fresh["coef"])


def test_elements_far_from_a_boundary_are_skipped_only_where_they_would_not_be_served():
    """The pre-screen (offset more than 4.6 τ from a DN boundary) leaves out only elements whose
    exact V is below the series' threshold: on random points near and beyond the cut, every
    skipped element has V < 1e-5 / 2 (the bound 2Φ(−z)(1 + 2 %) < 5e-6)."""
    rng = np.random.default_rng(8)
    n = 3000
    s = rng.uniform(F._S0, 0.3, n)
    so = rng.uniform(F._SO_MIN, 0.3, n) * rng.choice([0.02, 1.0], n)
    so = np.maximum(so, F._SO_MIN)
    tau = np.sqrt(s * s + so * so)
    z = rng.uniform(3.5, 6.0, n)
    d = np.clip(0.5 - z * tau, -0.5, 0.5) * rng.choice([-1.0, 1.0], n)
    skipped = (0.5 - np.abs(d)) > F._Z_SKIP * tau
    assert skipped.sum() > 200
    V = _quantized_pixel_moments(d[skipped], s[skipped], so[skipped], exact=True)[0]
    assert np.max(V) < 0.5 * F._V_MIN
    assert not np.any(F.offset_fourier_moments(d, s, so)[0][skipped])
