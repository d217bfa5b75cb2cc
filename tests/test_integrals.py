"""Integral accuracy (issue 7, item 4): TR closed form vs quadrature, Δs Gauss–Legendre vs
closed forms, and the cost of propagating 10 000 draws."""

import time

import numpy as np
import pytest

from bayescap.physics.capacity import integral_inv_sqrt_quadratic, mtf_loss_bits, tonal_range
from bayescap.physics.noise import NoiseCoefficients
from bayescap.physics.optics import DiffractionLens, GaussianCrosstalk
from bayescap.validation.integrals import TR_CASES, ds_reference, tr_reference, tr_simpson


@pytest.mark.parametrize("case", TR_CASES, ids=[c[0] for c in TR_CASES])
def test_tr_closed_form_matches_adaptive_quadrature(case):
    name, a, b, c, s1, s2, fl = case
    ref, err = tr_reference(a, b, c, s1, s2, fl)
    cf = float(integral_inv_sqrt_quadratic(a, b, c, s1, s2, floor=fl))
    assert err < 1e-12 * ref
    assert abs(cf / ref - 1) < 1e-12


def test_simpson_log_grid_beats_linear_on_a_typical_sensor():
    name, a, b, c, s1, s2, fl = TR_CASES[0]
    ref, _ = tr_reference(a, b, c, s1, s2, fl)
    e_log = abs(tr_simpson(a, b, c, s1, s2, fl, 1000, "log") / ref - 1)
    e_lin = abs(tr_simpson(a, b, c, s1, s2, fl, 1000, "linear") / ref - 1)
    assert e_log < 1e-8 < 1e-7 < e_lin


def test_delta_s_closed_forms():
    # constant MTF m: Δs = (π/2) log2 m (Eq. 9); Gaussian exp(−2π²σ²f²): −π³σ²f_N²/(2 ln 2)
    for n in (8, 64, 256):
        v = float(mtf_loss_bits(lambda f: np.full_like(np.asarray(f, float), 0.3), n_nodes=n).delta_s_bits)
        assert v == pytest.approx(0.5 * np.pi * np.log2(0.3), abs=1e-13)
        s = 0.7
        v = float(mtf_loss_bits(GaussianCrosstalk(sigma_px=s), n_nodes=n).delta_s_bits)
        assert v == pytest.approx(-(np.pi**3) * s * s * 0.25 / (2 * np.log(2)), abs=1e-12)


def test_delta_s_with_band_cut_converges_slowly():
    """A lens cut-off inside the band: log singularity at the cut-off, error ~ 1/n²."""
    lens = DiffractionLens(8.0, 555.0, 1.4)
    ref = ds_reference(lens)
    e = {n: abs(float(mtf_loss_bits(lens, n_nodes=n).delta_s_bits) - ref) for n in (64, 256)}
    assert e[256] < 1e-4  # the default n = 256: good to 1e-4 bits
    assert 8 < e[64] / e[256] < 32  # algebraic (≈ 16 = 4²), not geometric, convergence


def test_propagating_10k_draws_is_fast():
    rng = np.random.default_rng(0)
    n = 10_000
    coeffs = NoiseCoefficients.from_parameters(
        read_noise_e=rng.uniform(2, 10, n), dsnu_e=1.0, prnu_frac=0.005, conversion_gain_e_per_dn=rng.uniform(1, 3, n)
    )
    smax = rng.uniform(8e3, 1.2e4, n)
    tonal_range(coeffs, smax)
    t = time.perf_counter()
    for _ in range(5):
        tr = tonal_range(coeffs, smax)
    assert (time.perf_counter() - t) / 5 < 0.05  # generous: measured ≈ 0.5 ms here
    assert np.all(np.isfinite(tr)) and np.all(tr <= 256)
