"""Eq. 2, 7, 9 against closed forms and independent quadrature."""

import numpy as np
import pytest
from scipy import integrate

from bayescap.physics.capacity import integral_inv_sqrt_quadratic, mtf_loss_bits, tonal_range
from bayescap.physics.noise import NoiseCoefficients, dynamic_range_db, snr_db
from bayescap.physics.optics import DiffractionLens, MTFProduct, PixelAperture, TabulatedMTF, default_mtf


def _quad(a, b, c, s1, s2, floor=0.0):
    f = lambda s: 1.0 / max(np.sqrt(a + b * s + c * s * s), floor)
    pts = []
    if floor > 0:
        disc = b * b - 4 * c * (a - floor**2)
        if a < floor**2:
            pts = [(-2 * (a - floor**2)) / (b + np.sqrt(disc))]
    return integrate.quad(f, s1, s2, points=[p for p in pts if s1 < p < s2] or None, limit=500, epsabs=0, epsrel=1e-12)[
        0
    ]


@pytest.mark.parametrize(
    "a,b,c,s1,s2,floor",
    [
        (100.0, 1.0, 1e-4, 10.0, 1e4, 0.0),  # read + shot + PRNU
        (100.0, 1.0, 0.0, 10.0, 1e4, 0.0),  # no PRNU (c = 0 branch)
        (100.0, 1.0, 1e-14, 10.0, 1e4, 0.0),  # negligible PRNU: no cancellation
        (100.0, 1.0, 1e-4, 10.0, 1e4, 40.0),  # with the max(σ, 1) floor
        (4e4, 1.0, 0.01, 200.0, 1e5, 1000.0),  # floor below σ everywhere
        (1e-6, 1.0, 0.0, 0.0, 100.0, 0.5),  # tiny read noise, integral from 0
        (2.5e-3, 1.0, 2.5e-5, 0.05, 1e6, 3906.25),  # read noise 0.05 e-, huge well, 8-bit floor
    ],
)
def test_tonal_integral_matches_quadrature(a, b, c, s1, s2, floor):
    got = integral_inv_sqrt_quadratic(a, b, c, s1, s2, floor)
    ref = _quad(a, b, c, s1, s2, floor)
    assert got == pytest.approx(ref, rel=1e-9)


def test_pure_shot_noise_closed_form():
    # σ² = S: TR = 2(√S_max − √S_min) in noise units (no floor)
    s_min, s_max = 25.0, 1e4
    got = integral_inv_sqrt_quadratic(0.0, 1.0, 0.0, s_min, s_max)
    assert got == pytest.approx(2 * (np.sqrt(s_max) - np.sqrt(s_min)), rel=1e-14)


def test_tonal_range_eight_bit_scale_and_vectorised():
    # noise far below one grey level everywhere: TR = 256 (1 - S_min/S_max) exactly
    co = NoiseCoefficients(a=np.array([1e-6]), b=np.array([1e-6]), c=np.array([0.0]))
    s_max = np.array([1e5])
    tr = tonal_range(co, s_max)
    assert tr[0] == pytest.approx(256 * (1 - 1e-3 / 1e5), rel=1e-12)
    # vectorised over draws, finite at extremes
    n = 1000
    rng = np.random.default_rng(0)
    co = NoiseCoefficients.from_parameters(
        read_noise_e=rng.uniform(0.05, 200, n),
        prnu_frac=rng.uniform(0, 0.02, n),
        conversion_gain_e_per_dn=rng.uniform(0.01, 100, n),
    )
    s_max = rng.uniform(1e3, 1e6, n)
    tr = tonal_range(co, s_max)
    assert tr.shape == (n,) and np.all(np.isfinite(tr)) and np.all((tr > 0) & (tr <= 256))


def test_snr_and_dr_definitions():
    co = NoiseCoefficients.from_parameters(
        read_noise_e=10.0,
        dark_current_e_per_s=100.0,
        exposure_time_s=0.01,
        conversion_gain_e_per_dn=2.0,
        prnu_frac=0.01,
        dsnu_e=1.0,
    )
    a = 100 + 1 + 1 + 4 / 12
    assert co.a == pytest.approx(a)
    assert dynamic_range_db(co, 1e4) == pytest.approx(20 * np.log10(1e4 / np.sqrt(a)))
    assert snr_db(co, 1e4) == pytest.approx(10 * np.log10(1e8 / (a + 1e4 + 1e-4 * 1e8)))


def test_constant_mtf_eq9():
    for m in (0.9, 0.5, 0.1):
        ds = mtf_loss_bits(lambda f, m=m: np.full_like(f, m)).delta_s_bits
        assert ds == pytest.approx(np.pi / 2 * np.log2(m), rel=1e-12)


def test_gaussian_mtf_eq9_closed_form():
    # MTF = exp(-2π²σ²f²): ∫0^fN f log2 MTF df = -2π²σ² fN⁴/(4 ln 2)
    sig = 0.4
    ds = mtf_loss_bits(lambda f: np.exp(-2 * np.pi**2 * sig**2 * f**2)).delta_s_bits
    fN = 0.5
    assert ds == pytest.approx(np.pi / fN**2 * (-2 * np.pi**2 * sig**2 * fN**4 / (4 * np.log(2))), rel=1e-12)


@pytest.mark.parametrize("pitch,expected", [(1.45, -1.877), (1.75, -1.572), (2.80, -1.105)])
def test_pixel_plus_diffraction_reference_values(pitch, expected):
    # independent calculation in NOTES (λ = 550 nm, f/2.8, fill factor 1)
    ds = mtf_loss_bits(default_mtf(pixel_pitch_um=pitch, wavelength_nm=550.0)).delta_s_bits
    assert ds == pytest.approx(expected, abs=1.5e-3)


def test_pixel_aperture_alone_independent_of_pitch_and_additive():
    ap = mtf_loss_bits(PixelAperture()).delta_s_bits
    assert ap == pytest.approx(-0.495, abs=1e-3)
    lens = DiffractionLens(f_number=2.8, wavelength_nm=550.0, pixel_pitch_um=2.2)
    both = mtf_loss_bits(MTFProduct(components=(PixelAperture(), lens))).delta_s_bits
    assert both == pytest.approx(ap + mtf_loss_bits(lens).delta_s_bits, rel=1e-12)


def test_band_cut_below_nyquist_is_finite_and_reported():
    # f/8 with 1.4 µm pixels: diffraction cut-off 0.32 cy/px < 0.5
    res = mtf_loss_bits(default_mtf(pixel_pitch_um=1.4, f_number=8.0))
    assert res.band_cut and res.f_end_cy_per_px == pytest.approx(1.4e-3 / (555e-6 * 8.0))
    assert (
        np.isfinite(res.delta_s_bits) and res.delta_s_bits < mtf_loss_bits(default_mtf(pixel_pitch_um=1.4)).delta_s_bits
    )
    assert res.band_cut_bits == pytest.approx(2 * np.log2(res.f_end_cy_per_px / 0.5))
    # the lost band dominates smoothly: no jump as the cut-off crosses Nyquist
    just_in = mtf_loss_bits(DiffractionLens(f_number=2.8, wavelength_nm=555, pixel_pitch_um=0.5 * 555e-3 * 2.8 * 0.999))
    just_out = mtf_loss_bits(
        DiffractionLens(f_number=2.8, wavelength_nm=555, pixel_pitch_um=0.5 * 555e-3 * 2.8 * 1.001)
    )
    assert just_in.band_cut and not just_out.band_cut
    assert abs(just_in.delta_s_bits - just_out.delta_s_bits) < 0.05


def test_measured_mtf_with_draws():
    f = np.linspace(0, 0.5, 51)
    base = np.exp(-2 * np.pi**2 * 0.3**2 * f**2)
    draws = base[None, :] ** np.linspace(0.9, 1.1, 5)[:, None]
    comp = TabulatedMTF(freq_cy_per_px=f, mtf=base, samples=draws)
    ds = mtf_loss_bits(comp, draws=True).delta_s_bits
    assert ds.shape == (5,) and np.all(np.diff(ds) < 0)
