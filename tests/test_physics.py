"""Physics of Tisse, Guichard & Cao (SPIE 2008): photometry, Table 1, SNR, MTF, Eq. 8/9, Fig. 4.

Tolerances: closed forms are compared at a few ulps times the number of terms (rtol 1e-12
unless a quadrature with a logarithmic singularity is involved, where the tolerance is set
from the measured convergence between n and 4n nodes); printed paper values at half a unit of
their last printed digit.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from scipy import integrate, optimize

from bayescap.cli import sweep as cli_sweep
from bayescap.physics import photometry
from bayescap.physics import table1 as paper
from bayescap.physics.capacity import mtf_loss_bits, mtf_loss_bits_eq8
from bayescap.physics.optics import (
    DiffractionLens,
    GaussianCrosstalk,
    LShapedAperture,
    MTFProduct,
    PixelAperture,
    TabulatedMTF,
    default_mtf,
    mtf50_cy_per_px,
)
from bayescap.studies import sweep

H_PLANCK, C_LIGHT = 6.62607015e-34, 299_792_458.0


# ---------------------------------------------------------------- photometry (Eq. 4, 5)


def test_photon_energy_and_paper_typo():
    e = photometry.photon_energy_j(555.0)
    assert e == pytest.approx(H_PLANCK * C_LIGHT / 555e-9, rel=1e-15)
    assert e == pytest.approx(3.579e-19, abs=0.0005e-19)
    # the paper prints 2.58e-19 J "for 555 nm": that is the photon energy at ~770 nm
    lam = H_PLANCK * C_LIGHT / photometry.PAPER_PHOTON_ENERGY_J * 1e9
    assert 765 < lam < 775


def test_photons_per_pixel_eq4():
    per = 1e-12 / (683.0 * H_PLANCK * C_LIGHT / 555e-9)  # photons per lux·s per µm²
    assert photometry.photons_per_pixel(1.0, 1.0) == pytest.approx(per, rel=1e-14)
    assert per == pytest.approx(4091, abs=0.5)
    # linear in H and alpha, quadratic in P
    got = photometry.photons_per_pixel(np.array([0.5, 2.0]), 2.0, fill_factor=0.5)
    np.testing.assert_allclose(got, per * np.array([0.5, 2.0]) * 0.5 * 4.0, rtol=1e-14)
    with pytest.raises(ValueError):
        photometry.photons_per_pixel(1.0, 1.0, fill_factor=0.0)


def test_exposure_eq5_fig2a_numbers():
    # Fig. 2(a): T = 0.85, m = -1e-3, f/2.8, dt = 100 ms (R = 1)
    g = 0.85 / (1 + 4 * (1 + 1e-3) ** 2 * 2.8**2)
    h = photometry.exposure_lux_s(np.array([10.0, 1e4]), exposure_time_s=0.1, f_number=2.8)
    np.testing.assert_allclose(h, g * np.array([10.0, 1e4]) * 0.1, rtol=1e-14)
    assert h[0] == pytest.approx(0.026216, rel=1e-4)
    # photons for the smallest pixel in the dimmest scene and the largest in the brightest
    n = photometry.photons_per_pixel(h, np.array([1.45, 5.2]))
    assert n[0] == pytest.approx(225.5, abs=0.1)
    assert n[1] == pytest.approx(2.9000e6, rel=1e-3)
    with pytest.raises(ValueError):
        photometry.exposure_lux_s(1.0, exposure_time_s=0.1, f_number=2.8, magnification=0.1)


# ---------------------------------------------------------------- Table 1


def test_table1_loader_values():
    rows = paper.load_table1()
    assert [r.pitch_um for r in rows] == [5.2, 3.2, 2.9, 2.2, 1.75, 1.45]
    assert [r.architecture for r in rows] == ["4T", "2.5T", "2.5T", "2.5T", "1.75T", "1.5T"]
    assert [r.sensitivity_e_per_lux_s for r in rows] == [57e3, 22e3, 16e3, 9.3e3, 5e3, 3e3]
    assert [(r.full_well_min_e, r.full_well_max_e) for r in rows] == [
        (28e3, 38e3),
        (22e3, 33e3),
        (19e3, 25e3),
        (12e3, 21e3),
        (8e3, 9e3),
        (4e3, 7e3),
    ]
    assert [r.dark_current_60c_e_per_s for r in rows] == [2000, 360, 300, 270, 25, 15]
    np.testing.assert_array_equal([r.dark_current_25c_e_per_s for r in rows][:4], [22, 12, 10, 9])
    assert np.isnan(rows[4].dark_current_25c_e_per_s) and np.isnan(rows[5].dark_current_25c_e_per_s)
    np.testing.assert_allclose([r.prnu_max_frac for r in rows], [0.0105] * 3 + [0.015, 0.015, 0.02])
    assert rows[5].sources["sensitivity"] == "model"  # the italic value
    assert rows[0].as_printed["dark_current_cells_as_printed"] == "250 – 22 * | 2000 *"


def test_table1_embedded_copy_matches_csv():
    assert paper.TABLE1_PATH.exists()
    assert paper.TABLE1_PATH.read_text(encoding="utf-8") == paper._EMBEDDED_CSV


def test_dark_current_reading_is_consistent_with_six_degree_law():
    """Our reading: 25 °C = the starred number after the dash; 60 °C = the next column.

    Over 35 °C the 6 °C law predicts a factor 2^(35/6) = 57; the Rhodes rows give 30-91,
    i.e. doubling every 5.4-7.1 °C. The other reading (the unstarred first number as the 25 °C
    value) gives 60/25 °C ratios of 1.25 and 0.83 for the Cohen rows: physically impossible.
    """
    rows = paper.load_table1()
    rhodes = [r for r in rows if np.isfinite(r.dark_current_25c_e_per_s)]
    doubling = [35.0 / np.log2(r.dark_current_60c_e_per_s / r.dark_current_25c_e_per_s) for r in rhodes]
    assert all(5.0 < d < 7.5 for d in doubling)
    other = [r.dark_current_60c_e_per_s / float(r.as_printed["dark_current_unassigned_as_printed"]) for r in rows]
    assert min(other) < 1.0


def test_dark_current_law():
    assert float(paper.dark_current_at(31.0, reference_e_per_s=10.0, reference_temperature_c=25.0)) == 20.0
    got = paper.dark_current_at(np.array([25.0, 60.0]), reference_e_per_s=1.0, reference_temperature_c=25.0)
    np.testing.assert_allclose(got, [1.0, 2 ** (35 / 6)], rtol=1e-14)
    r = paper.load_table1()[4]  # 1.75 µm: only 60 °C printed
    assert r.dark_current_e_per_s(25.0) == pytest.approx(25.0 / 2 ** (35 / 6), rel=1e-14)
    assert r.dark_current_e_per_s(60.0) == 25.0
    with pytest.raises(ValueError):
        paper.dark_current_at(30.0, reference_e_per_s=1.0, reference_temperature_c=25.0, doubling_c=0.0)


# ---------------------------------------------------------------- SNR (Eq. 1, Fig. 2b)


def _pixel(r):
    return dict(
        sensitivity_e_per_lux_s=r.sensitivity_e_per_lux_s,
        full_well_e=r.full_well_mid_e,
        dark_current_e_per_s=r.dark_current_e_per_s(25.0),
        prnu_frac=r.prnu_max_frac,
    )


def _shares(px, h):
    """Shares of σ² (shot, dark+quantization, PRNU) at exposure h."""
    s = px["sensitivity_e_per_lux_s"] * h
    a = px["dark_current_e_per_s"] * 0.1 + (px["full_well_e"] / 1024) ** 2 / 12
    p = (px["prnu_frac"] * s) ** 2
    tot = a + s + p
    return s / tot, a / tot, p / tot


def test_snr_ten_db_per_decade_in_shot_region():
    """Paper: 10 dB/decade from 1e-3 to 1e-1 lux·s. The local slope is 10 + 10(f_a − f_p)
    (f_a, f_p: dark+quantization and PRNU shares of σ²), so over a decade it must lie within
    10 ± 10·max(f_a + f_p). Measured (1e-2..1e-1): 8.7 (5.2 µm, PRNU) to 10.2 dB/decade;
    over 1e-3..1e-2 the 10-bit quantization (K = FW/1024) steepens it to 12-15 dB/decade."""
    for r in paper.load_table1():
        px = _pixel(r)
        slope = photometry.snr_slope_db_per_decade(1e-2, 1e-1, **px)
        h = np.logspace(-2, -1, 201)
        fs, fa, fp = _shares(px, h)
        bound = 10 * np.max(fa + fp)
        assert abs(slope - 10.0) <= bound + 1e-9, (r.pitch_um, slope, bound)
    # small pixels are shot-noise limited there: within 0.25 dB/decade of 10
    for r in paper.load_table1()[3:]:
        assert photometry.snr_slope_db_per_decade(1e-2, 1e-1, **_pixel(r)) == pytest.approx(10.0, abs=0.25)
    # pure shot noise: 10 dB/decade (a 40-bit ADC leaves K²/12 = 6.9e-8 e⁻², i.e. a share
    # below 7e-9 at S >= 10 e⁻ and a slope error below 1e-7 dB/decade)
    pure = dict(sensitivity_e_per_lux_s=1e4, full_well_e=1e9, dark_current_e_per_s=0.0, prnu_frac=0.0, adc_bits=40)
    assert photometry.snr_slope_db_per_decade(1e-3, 1e-1, **pure) == pytest.approx(10.0, abs=1e-7)


def test_snr_gap_smallest_vs_largest_pixel():
    """Paper: ≈ 10 dB. Pure shot noise gives 10·log10(57/3) = 12.79 dB; the large pixel's
    quantization and PRNU shares narrow it to 12.3 dB at 1e-2 lux·s and 11.2 dB at 1e-1."""
    rows = paper.load_table1()
    big, small = _pixel(rows[0]), _pixel(rows[-1])
    shot_gap = 10 * np.log10(57 / 3)
    for h in (1e-2, 1e-1):
        gap = float(photometry.snr_vs_exposure_db(h, **big) - photometry.snr_vs_exposure_db(h, **small))
        fs_big, fs_small = _shares(big, h)[0], _shares(small, h)[0]
        assert gap == pytest.approx(shot_gap + 10 * np.log10(fs_big / fs_small), abs=1e-9)
        assert 10.0 < gap < shot_gap
    assert shot_gap == pytest.approx(12.788, abs=5e-4)


def test_snr_flattens_where_prnu_dominates():
    for r in paper.load_table1():
        px = _pixel(r)
        h_top = 0.95 * px["full_well_e"] / px["sensitivity_e_per_lux_s"]
        fs, fa, fp = _shares(px, h_top)
        assert fp > fs  # PRNU dominates near saturation for every Table 1 pixel
        slope_top = photometry.snr_slope_db_per_decade(h_top / 2, h_top, **px)
        assert slope_top < 5.0
        ceiling = -20 * np.log10(px["prnu_frac"])
        snr_top = float(photometry.snr_vs_exposure_db(h_top, **px))
        assert ceiling - 10 * np.log10(1 + (fs + fa) / fp) == pytest.approx(snr_top, abs=1e-9)
        assert snr_top > ceiling - 3.1
        assert np.isnan(photometry.snr_vs_exposure_db(1.01 * h_top / 0.95, **px))


def test_mpe30_closed_form_matches_root():
    for r in paper.load_table1():
        px = _pixel(r)
        h = float(photometry.mpe30_lux_s(**px))
        root = optimize.brentq(lambda x: float(photometry.snr_vs_exposure_db(x, **px)) - 30.0, 1e-5, h * 1.5)
        assert h == pytest.approx(root, rel=1e-9)
    # unreachable 30 dB: PRNU above 1/sqrt(1000)
    assert np.isinf(
        photometry.mpe30_lux_s(sensitivity_e_per_lux_s=1e4, full_well_e=1e6, dark_current_e_per_s=0.0, prnu_frac=0.04)
    )


def test_farrell_tradeoff_monotone():
    rows = sweep.farrell_tradeoff()
    inv = [r["inv_mpe30_per_lux_s"] for r in rows]
    m50 = [r["mtf50_system_cy_per_mm"] for r in rows]
    # pitches decrease along the table: 1/MPE30 falls, MTF50 (cy/mm) rises
    assert np.all(np.diff(inv) < 0) and np.all(np.diff(m50) > 0)
    assert rows[0]["mtf50_detector_cy_per_px"] == pytest.approx(0.6034, abs=5e-5)


# ---------------------------------------------------------------- MTF components


def _l_mask_ft(ap, fx, fy, n=1600):
    """Brute-force midpoint-rule Fourier transform of the L-shaped mask (pixel units)."""
    x = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(x, x, indexing="ij")
    # rect 1: x in [-a, 0], y in [0, B-b]; rect 2: x in [0, A-a], y in [-b, B-b]
    m = ((X >= -ap.a) & (X < 0) & (Y >= 0) & (Y < ap.B - ap.b)) | (
        (X >= 0) & (X < ap.A - ap.a) & (Y >= -ap.b) & (Y < ap.B - ap.b)
    )
    ph = np.exp(-2j * np.pi * (fx * X[m] + fy * Y[m]))
    return abs(ph.sum()) / m.sum()


def test_l_shaped_aperture_eq3():
    ap = LShapedAperture()
    assert ap.fill_factor == pytest.approx(1 - 0.55 * 0.28)
    assert ap.mtf2d(0.0, 0.0) == pytest.approx(1.0, abs=1e-15)
    g = np.linspace(-0.5, 0.5, 41)
    FX, FY = np.meshgrid(g, g)
    m = ap.mtf2d(FX, FY)
    np.testing.assert_allclose(m, m[::-1, ::-1], atol=1e-14)  # symmetric about DC
    assert np.max(np.abs(m - m[:, ::-1])) > 0.1  # but not mirror-symmetric: anisotropic
    assert np.max(np.abs(m - m.T)) > 0.05  # nor isotropic
    # independent check against a brute-force transform of the mask (midpoint error ~1e-6)
    for fx, fy in [(0.3, 0.0), (0.0, 0.45), (0.25, -0.4), (-0.5, 0.5)]:
        assert ap.mtf2d(fx, fy) == pytest.approx(_l_mask_ft(ap, fx, fy), abs=2e-4)
    # no notch: the separable sinc of a full rectangle
    rect = LShapedAperture(A=0.8, B=0.9, a=0.3, b=0.0)
    np.testing.assert_allclose(rect.mtf2d(FX, FY), np.abs(np.sinc(0.8 * FX) * np.sinc(0.9 * FY)), atol=1e-14)
    with pytest.raises(ValueError):
        LShapedAperture(a=1.2)


def test_gaussian_crosstalk():
    s = 0.4
    g = GaussianCrosstalk(s)
    f = np.linspace(0, 1, 11)
    # Fourier transform of a unit-area Gaussian of sd s (numerically)
    ft = [
        integrate.quad(
            lambda x: np.exp(-x * x / (2 * s * s)) / np.sqrt(2 * np.pi) / s * np.cos(2 * np.pi * fi * x), -10, 10
        )[0]
        for fi in f
    ]
    np.testing.assert_allclose(g.radial(f), ft, atol=1e-10)
    an = GaussianCrosstalk(0.2, sigma_y_px=0.5)
    assert an.mtf2d(0.3, 0.0) > an.mtf2d(0.0, 0.3)


def test_fig3_diffraction_vs_detector():
    """Fig. 3: the lens MTF at the pixel's Nyquist frequency drops below the pixel's own
    (2/π = 0.637) below a pitch of 2.68 µm (f/2.8, 555 nm); the paper says 'smaller than 2.2 µm'."""
    pa = PixelAperture().radial(0.5)
    cross = optimize.brentq(lambda p: DiffractionLens(pixel_pitch_um=p).radial(0.5) - pa, 1.0, 5.0)
    assert cross == pytest.approx(2.684, abs=1e-3)
    assert DiffractionLens(pixel_pitch_um=1.45).radial(0.5) < pa


def test_mtf50():
    assert mtf50_cy_per_px(PixelAperture()) == pytest.approx(
        optimize.brentq(lambda f: np.sinc(f) - 0.5, 0.1, 0.9), abs=1e-10
    )
    assert np.isnan(mtf50_cy_per_px(lambda f: np.ones_like(f)))


# ---------------------------------------------------------------- Eq. 8 vs Eq. 9


class _Const:
    cutoff_cy_per_px = np.inf

    def __init__(self, m):
        self.m = m

    def radial(self, f):
        return np.full(np.shape(f), self.m)

    def mtf2d(self, fx, fy):
        return np.full(np.broadcast_shapes(np.shape(fx), np.shape(fy)), self.m)


@pytest.mark.parametrize("m", [0.3, 0.5, 0.9])
def test_constant_mtf_eq8_vs_eq9(m):
    assert float(mtf_loss_bits_eq8(_Const(m)).delta_s_bits) == pytest.approx(2 * np.log2(m), rel=1e-12)
    assert float(mtf_loss_bits(_Const(m)).delta_s_bits) == pytest.approx(np.pi / 2 * np.log2(m), rel=1e-12)
    assert float(mtf_loss_bits_eq8(_Const(m), domain="disc").delta_s_bits) == pytest.approx(
        np.pi / 2 * np.log2(m), rel=1e-12
    )


@pytest.mark.parametrize(
    "comp",
    [
        DiffractionLens(pixel_pitch_um=1.45, wavelength_nm=550),
        DiffractionLens(pixel_pitch_um=0.6, wavelength_nm=550),  # cut band
        GaussianCrosstalk(0.35),
    ],
)
def test_eq8_on_disc_equals_eq9_for_isotropic(comp):
    e8 = mtf_loss_bits_eq8(comp, domain="disc", n=256)
    e9 = mtf_loss_bits(comp, n_nodes=256)
    assert float(e8.delta_s_bits) == pytest.approx(float(e9.delta_s_bits), rel=1e-12, abs=1e-12)
    assert e8.band_cut == e9.band_cut
    assert e8.band_cut_bits == pytest.approx(e9.band_cut_bits, abs=1e-12)


def test_gaussian_closed_forms():
    s, fn = 0.4, 0.5
    g = GaussianCrosstalk(s)
    eq8 = -8 * np.pi**2 * s**2 * fn**2 / (3 * np.log(2))  # mean of log2 G² over the square
    eq9 = -(np.pi**3) * s**2 * fn**2 / (2 * np.log(2))
    assert float(mtf_loss_bits_eq8(g).delta_s_bits) == pytest.approx(eq8, rel=1e-12)
    assert float(mtf_loss_bits(g).delta_s_bits) == pytest.approx(eq9, rel=1e-12)


def test_eq8_adds_over_components():
    comps = (
        LShapedAperture(),
        GaussianCrosstalk(0.3, sigma_y_px=0.2),
        DiffractionLens(pixel_pitch_um=2.8, wavelength_nm=550),
    )
    total = float(mtf_loss_bits_eq8(MTFProduct(components=comps)).delta_s_bits)
    parts = [float(mtf_loss_bits_eq8(c).delta_s_bits) for c in comps]
    assert total == pytest.approx(sum(parts), rel=1e-12)


def test_pixel_aperture_independent_of_pitch():
    lens_only = lambda p: float(mtf_loss_bits(DiffractionLens(pixel_pitch_um=p)).delta_s_bits)
    for p in (1.2, 1.75, 3.2, 5.2):
        d = float(mtf_loss_bits(default_mtf(pixel_pitch_um=p)).delta_s_bits) - lens_only(p)
        assert d == pytest.approx(-0.49505, abs=5e-6)
    # Eq. 8: separable sinc -> 4 × mean of log2|sinc| on [0, 1/2]
    ref = 4 * integrate.quad(lambda f: np.log2(np.sinc(f)), 0, 0.5, epsabs=1e-14)[0] / 0.5
    assert float(mtf_loss_bits_eq8(PixelAperture()).delta_s_bits) == pytest.approx(ref, rel=1e-10)
    assert ref == pytest.approx(-0.8352, abs=5e-5)


@pytest.mark.parametrize("pitch, value", [(1.45, -1.877), (1.75, -1.572), (2.80, -1.105)])
def test_notes_cross_check_values(pitch, value):
    ds = float(mtf_loss_bits(default_mtf(pixel_pitch_um=pitch, wavelength_nm=550)).delta_s_bits)
    assert ds == pytest.approx(value, abs=5e-4)


def test_eq8_band_cut_where_lens_cuts_inside_square():
    fn = 0.5
    # 1.0 µm at 550 nm: f_c = 0.649 cy/px, between f_N and √2 f_N: only the corners are cut
    lens = DiffractionLens(pixel_pitch_um=1.0, wavelength_nm=550)
    fc = lens.cutoff_cy_per_px
    r = mtf_loss_bits_eq8(lens)
    area = np.pi * fc**2 - 4 * (fc**2 * np.arccos(fn / fc) - fn * np.sqrt(fc**2 - fn**2))
    assert r.band_cut and np.isfinite(r.delta_s_bits)
    assert r.band_cut_bits == pytest.approx(np.log2(area / (4 * fn * fn)), rel=1e-12)
    assert not mtf_loss_bits(lens).band_cut  # Eq. 9 never sees the corners
    # 0.6 µm: f_c < f_N: the square and the disc keep the same disc; only the cut cost differs
    small = DiffractionLens(pixel_pitch_um=0.6, wavelength_nm=550)
    sq, dc = mtf_loss_bits_eq8(small), mtf_loss_bits_eq8(small, domain="disc")
    assert float(sq.delta_s_bits - dc.delta_s_bits) == pytest.approx(np.log2(np.pi / 4), rel=1e-12)
    # convergence at the logarithmic end-point singularity: n=64 vs 256 within 1e-3 bit
    assert float(mtf_loss_bits_eq8(lens, n=64).delta_s_bits) == pytest.approx(
        float(mtf_loss_bits_eq8(lens, n=256).delta_s_bits), abs=1e-3
    )


def test_eq8_tabulated_zero_region_and_interior_zero_lines():
    f = np.linspace(0, 1, 101)
    tab = TabulatedMTF(f, np.clip(1 - f / 0.6, 0, None))
    r = mtf_loss_bits_eq8(tab)
    assert r.band_cut and r.f_end_cy_per_px == pytest.approx(0.6) and np.isfinite(r.delta_s_bits)
    # a wide aperture (3 px) has sinc zero lines inside the band: integrable, finite Δs
    w = 3.0
    fn2d = lambda x, y: np.abs(np.sinc(w * x) * np.sinc(w * y))
    exact = 4 * integrate.quad(lambda x: np.log2(abs(np.sinc(w * x))), 0, 0.5, points=[1 / 3], limit=200)[0] / 0.5
    e64 = float(mtf_loss_bits_eq8(fn2d, n=64).delta_s_bits)
    e256 = float(mtf_loss_bits_eq8(fn2d, n=256).delta_s_bits)
    assert abs(e256 - exact) < abs(e64 - exact) / 4 and abs(e64 - exact) < 0.02 * abs(exact)


# ---------------------------------------------------------------- Fig. 4 sweep


@pytest.fixture(scope="module")
def sweep_eq9():
    return sweep.pixel_size_sweep(n_draws=1000, seed=3)


def test_sweep_geometry_and_tr_trend(sweep_eq9):
    r = sweep_eq9
    k = int(np.argmin(np.abs(r.pitch_um - 1.75)))
    assert r.n_pixels[k] == pytest.approx(2048 * 1536, rel=0.01)  # the paper's 1/4-inch 1.75 µm sensors
    below = r.pitch_um < 1.45 - 1e-9
    slope = np.diff(r.tr_bits_draws[:, below], axis=1) / np.diff(r.pitch_um[below])
    np.testing.assert_allclose(slope, 0.35, rtol=1e-9)
    assert r.tr_bits_draws.shape == r.capacity_draws_bits.shape == (1000, r.pitch_um.size)


def test_sweep_optimum_eq9_not_the_papers(sweep_eq9):
    """Eq. 9 + the 0.35 bit/µm trend: optimum ≈ 1.21 µm, not 1.45 µm; effective pixels alone
    peak at 1.19 µm (NOTES: 'near 1.2 µm'); the TR fall moves it up by ~0.02 µm only."""
    o = sweep_eq9.optimal_pitch_summary()
    assert 1.19 < o["ci95_um"][0] <= o["median_um"] <= o["ci95_um"][1] < 1.23
    assert not (o["ci95_um"][0] <= 1.45 <= o["ci95_um"][1])
    assert sweep_eq9.effective_pixels_optimum_um == pytest.approx(1.19, abs=0.01)
    assert sweep_eq9.nominal_optimum_um > sweep_eq9.effective_pixels_optimum_um
    assert o["fraction_at_grid_edge"] == 0.0


def test_sweep_optimum_eq8_moves_up():
    r = sweep.pixel_size_sweep(np.round(np.arange(1.0, 2.4001, 0.02), 10), n_draws=400, seed=1, method="eq8")
    o = r.optimal_pitch_summary()
    assert 1.5 < o["median_um"] < 1.8
    assert r.effective_pixels_optimum_um == pytest.approx(1.55, abs=0.03)


def test_tr_difference_1p45_to_5p2(sweep_eq9):
    d = sweep_eq9.tr_difference_bits()
    assert d["nominal_bits"] == pytest.approx(0.787, abs=5e-4)  # over the dynamic range
    assert d["ci95_bits"][1] < 1.3  # the paper's 1.3 bit is not reached over the DR
    nom = sweep.nominal_table1()
    tb = np.log2(sweep.table1_tonal_range_levels(nom, exposure_lux_s=0.8587))[0]
    assert tb[0] - tb[-1] == pytest.approx(1.30, abs=5e-3)  # ... but at H ≈ 0.86 lux·s it is


def test_sweep_is_seeded(sweep_eq9):
    again = sweep.pixel_size_sweep(n_draws=1000, seed=3)
    np.testing.assert_array_equal(again.optimal_pitch_draws_um, sweep_eq9.optimal_pitch_draws_um)


def test_interpolate_tr_least_squares_trend():
    tp = np.array([1.45, 2.0, 3.0])
    tb = np.array([[6.0, 6.5, 7.0], [5.0, 5.0, 5.0]])
    out = sweep.interpolate_tr_bits(np.array([1.0, 1.45, 2.5]), tp, tb, trend_bits_per_um=None)
    x = tp - tp.mean()
    s0 = np.sum((tb[0] - tb[0].mean()) * x) / np.sum(x * x)
    np.testing.assert_allclose(out[0], [6.0 - 0.45 * s0, 6.0, 6.75])
    np.testing.assert_allclose(out[1], [5.0, 5.0, 5.0])
    with pytest.raises(ValueError):
        sweep.interpolate_tr_bits(np.array([6.0]), tp, tb)


def test_cli_json(capsys):
    parser = cli_sweep.add_sweep_arguments(argparse.ArgumentParser())
    args = parser.parse_args(
        ["pixel-size", "--format", "1/4in", "--f-number", "2.8", "--json", "--seed", "5", "--draws", "200"]
    )
    assert cli_sweep.run_sweep(args) == 0
    out = json.loads(capsys.readouterr().out)
    o = out["optimal_pitch"]
    assert o["ci95_um"][0] <= o["ci68_um"][0] <= o["median_um"] <= o["ci68_um"][1] <= o["ci95_um"][1]
    assert out["settings"]["imaging_area_mm"] == [3.6, 2.7]
    assert out["settings"]["draws"] == {
        "n": 200,
        "seed": 5,
        "full_well": "uniform within the Table 1 range",
        "prnu": "uniform in [0, bound]",
    }
    args = parser.parse_args(["pixel-size", "--draws", "50"])
    assert cli_sweep.run_sweep(args) == 0
    assert "optimal pitch: median" in capsys.readouterr().out
