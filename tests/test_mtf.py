"""Tests for bayescap.measure (ISO 12233:2023 slanted-edge SFR with bootstrap uncertainty).

Real data: Peter D. Burns' sfrmat3 example edges with SFRs computed by his ISO 12233:2023
reference code sfrmat5 (tests/data/slanted_edge/README.md).  Synthetic data: edges rendered
by :func:`bayescap.measure.synthetic.synthetic_edge` with a known analytic MTF.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from bayescap.exceptions import MTFInputError, MTFWarning
from bayescap.measure import SFRResult, measure_sfr, read_mtf_table, synthetic_edge, synthetic_edge_mtf, write_mtf_table

tifffile = pytest.importorskip("tifffile")

DATA = Path(__file__).parent / "data" / "slanted_edge"
REF = DATA / "reference_sfr_sfrmat5"
NYQUIST_CY_PER_PX = 0.5


def _quiet_measure(*args, **kwargs) -> SFRResult:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MTFWarning)
        return measure_sfr(*args, **kwargs)


def _rms_to_nyquist(freq, a, b) -> float:
    m = freq <= NYQUIST_CY_PER_PX + 1e-12
    return float(np.sqrt(np.mean((np.asarray(a)[m] - np.asarray(b)[m]) ** 2)))


def _true_mtf50(sigma_px, fill_factor, angle_deg) -> float:
    f = np.linspace(0.0, 1.0, 200_001)
    m = synthetic_edge_mtf(f, sigma_px=sigma_px, fill_factor=fill_factor, angle_deg=angle_deg)
    k = int(np.argmax(m < 0.5))
    return float(f[k - 1] + (m[k - 1] - 0.5) / (m[k - 1] - m[k]) * (f[k] - f[k - 1]))


# Local stand-in for Eq. 9 of Tisse, Guichard & Cao (2008):
#   Delta s = pi f_N^-2 int_0^{f_N} f log2 MTF(f) df,  f_N = 0.5 cy/px.
# (bayescap.physics.capacity.mtf_loss_bits is the package's version.)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)
_GL_F = 0.5 * NYQUIST_CY_PER_PX * (_GL_X + 1.0)
_GL_WF = 0.5 * NYQUIST_CY_PER_PX * _GL_W


def _mtf_loss_bits(mtf_at_gl: np.ndarray) -> np.ndarray:
    """Eq. 9 from MTF values at the Gauss-Legendre nodes ``_GL_F`` (last axis)."""
    return np.pi / NYQUIST_CY_PER_PX**2 * np.sum(_GL_WF * _GL_F * np.log2(mtf_at_gl), axis=-1)


# ---------------------------------------------------------------------------------------
# Real edges vs the sfrmat5 reference
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def v_mono():
    return tifffile.imread(DATA / "sfrmat3_v_edge_mono.tif")


@pytest.mark.parametrize("npol, ref_sfr50", [(1, 0.1980), (5, 0.1956)])
def test_v_edge_mono_matches_sfrmat5(v_mono, npol, ref_sfr50):
    ref = read_mtf_table(REF / f"sfr_sfrmat3_v_edge_mono_npol{npol}.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error", MTFWarning)  # a clean capture: no warning expected
        r = measure_sfr(v_mono, npol=npol, n_boot=50)
    assert r.orientation == "vertical" and r.channel == "mono" and r.warnings == []
    np.testing.assert_allclose(r.freq_cy_per_px, ref.freq_cy_per_px, atol=1e-6)
    rms = _rms_to_nyquist(r.freq_cy_per_px, r.mtf, ref.mtf)
    assert rms < 0.02  # acceptance criterion of the issue
    assert rms < 1e-4  # regression guard: the implementation reproduces sfrmat5 exactly
    assert abs(r.mtf50_cy_per_px / ref_sfr50 - 1) < 0.02
    assert abs(r.mtf50_cy_per_px - ref.mtf50_cy_per_px) < 1e-5
    assert r.edge_angle_deg == pytest.approx(5.39, abs=0.005)
    assert round(100 * r.sampling_efficiency) == 66
    lo, hi = r.mtf50_ci()
    assert lo < r.mtf50_cy_per_px < hi and hi - lo < 0.05 * r.mtf50_cy_per_px


@pytest.mark.parametrize("npol", [1, 5])
def test_v_edge_rgb_matches_sfrmat5_per_channel(npol):
    img = tifffile.imread(DATA / "sfrmat3_v_edge.tif")
    ref = read_mtf_table(REF / f"sfr_sfrmat3_v_edge_npol{npol}.csv")
    r = _quiet_measure(img, npol=npol, n_boot=20)
    assert r.channel == "lum" and ref.channel == "Lum"
    for ours, theirs in [("R", "R"), ("G", "G"), ("B", "B"), ("lum", "Lum")]:
        rms = _rms_to_nyquist(r.freq_cy_per_px, r.mtf_by_channel[ours], ref.mtf_by_channel[theirs])
        assert rms < 1e-4, (ours, rms)
        ref50 = ref.mtf50_by_channel_cy_per_px[theirs]
        assert abs(r.mtf50_by_channel_cy_per_px[ours] / ref50 - 1) < 0.02
    np.testing.assert_array_equal(r.mtf, r.mtf_by_channel["lum"])
    g = _quiet_measure(img, npol=npol, n_boot=5, channel="G")
    assert g.channel == "G"
    np.testing.assert_array_equal(g.mtf, r.mtf_by_channel["G"])


def test_h_edge_detected_horizontal_and_consistent_with_v_edge(v_mono):
    h = _quiet_measure(tifffile.imread(DATA / "sfrmat3_h_edge_mono.tif"), n_boot=200)
    v = _quiet_measure(v_mono, n_boot=200)
    assert h.orientation == "horizontal"
    assert h.edge_angle_deg == pytest.approx(90 + 5.39, abs=0.1)  # sfrmat convention
    assert 0.1 < h.mtf50_cy_per_px < 0.35
    # same camera: the two MTF50 agree within their combined bootstrap uncertainty
    sd = math.hypot(np.std(h.mtf50_samples), np.std(v.mtf50_samples))
    assert abs(h.mtf50_cy_per_px - v.mtf50_cy_per_px) < 1.96 * sd


# ---------------------------------------------------------------------------------------
# Synthetic edges with known MTF
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "sigma_px, fill_factor, angle_deg, shape",
    [
        (0.5, 1.0, 5.0, (200, 100)),
        (0.8, 1.0, -4.0, (200, 100)),
        (0.6, 0.7, 85.0, (100, 200)),
        (0.4, 1.0, 7.0, (150, 80)),
    ],
)
def test_synthetic_mtf50_within_2_percent(sigma_px, fill_factor, angle_deg, shape):
    img = synthetic_edge(shape, angle_deg, sigma_px=sigma_px, fill_factor=fill_factor, noise_sd=0.002, seed=1)
    r = _quiet_measure(img, n_boot=0)
    tilt = angle_deg if abs(angle_deg) < 45 else angle_deg - 90
    assert r.edge_angle_deg == pytest.approx(angle_deg, abs=0.05)
    truth = _true_mtf50(sigma_px, fill_factor, tilt)
    assert abs(r.mtf50_cy_per_px / truth - 1) < 0.02
    rc = _quiet_measure(img, n_boot=0, correct_bin_width=True)
    assert abs(rc.mtf50_cy_per_px / truth - 1) < 0.02


def test_iso_bias_is_the_bin_width_response():
    """Noise-free: ISO result = truth x sinc(f cos(t)/4); the corrected option = truth."""
    ang, sig = 5.0, 0.45
    img = synthetic_edge((240, 100), ang, sigma_px=sig)
    r = _quiet_measure(img, n_boot=0)
    f = r.freq_cy_per_px
    truth = synthetic_edge_mtf(f, sigma_px=sig, angle_deg=ang)
    m = f <= NYQUIST_CY_PER_PX
    binned = truth * np.sinc(f * math.cos(math.radians(ang)) / 4)
    assert np.max(np.abs(r.mtf - binned)[m]) < 3e-3
    assert np.max(np.abs(r.mtf - truth)[m]) > 5e-3  # the ISO bias is real and visible
    rc = _quiet_measure(img, n_boot=0, correct_bin_width=True)
    assert np.max(np.abs(rc.mtf - truth)[m]) < 3e-3


@pytest.mark.slow
@pytest.mark.statistical
def test_bootstrap_interval_coverage_on_synthetic_edges():
    """95 % intervals of MTF50 and of the Eq. 9 MTF loss cover the truth at the nominal rate.

    Pre-registered design (not tuned on these seeds): 40 edges of 200 x 100 px, angle
    U(3, 8) deg, Gaussian sigma U(0.4, 0.7) px, fill factor 1, step 0.6 with white noise
    0.01 (SNR 60), npol = 5, 200 replicates, bin-width correction on (the ISO bin-width
    bias is deterministic and is tested separately above).  The number of covering
    intervals X ~ Binomial(40, 0.95) if the intervals are calibrated: we reject if X falls
    below the 0.5 % quantile.  Too *wide* intervals cannot be detected that way (P(X = 40)
    = 13 %), so we also check sum(z^2) of the standardised errors against the 0.5-99.5 %
    range of chi^2(40).
    """
    n_edges = 40
    rng = np.random.default_rng(2024)
    angles = rng.uniform(3.0, 8.0, n_edges)
    sigmas = rng.uniform(0.4, 0.7, n_edges)
    cover50 = cover_ds = 0
    z50, zds = [], []
    for i in range(n_edges):
        img = synthetic_edge(
            (200, 100), angles[i], sigma_px=sigmas[i], contrast=0.6, mean_level=0.5, noise_sd=0.01, seed=i
        )
        r = _quiet_measure(img, npol=5, n_boot=200, seed=i, correct_bin_width=True)
        t50 = _true_mtf50(sigmas[i], 1.0, angles[i])
        lo, hi = r.mtf50_ci(0.95)
        cover50 += lo <= t50 <= hi
        z50.append((r.mtf50_cy_per_px - t50) / np.std(r.mtf50_samples))
        tds = _mtf_loss_bits(synthetic_edge_mtf(_GL_F, sigma_px=sigmas[i], angle_deg=angles[i]))
        ds_samples = _mtf_loss_bits(r.mtf_samples_at(_GL_F))
        dlo, dhi = np.percentile(ds_samples, [2.5, 97.5])
        cover_ds += dlo <= tds <= dhi
        zds.append((_mtf_loss_bits(r.mtf_at(_GL_F)) - tds) / np.std(ds_samples))
    k_min = stats.binom.ppf(0.005, n_edges, 0.95)
    chi_lo, chi_hi = stats.chi2.ppf([0.005, 0.995], n_edges)
    print(
        f"coverage MTF50 {cover50}/{n_edges}, MTF loss {cover_ds}/{n_edges} (k_min {k_min:.0f});"
        f" sum z^2 MTF50 {np.sum(np.square(z50)):.1f}, loss {np.sum(np.square(zds)):.1f} "
        f"(chi2 range {chi_lo:.1f}-{chi_hi:.1f})"
    )
    assert cover50 >= k_min
    assert cover_ds >= k_min
    assert chi_lo < np.sum(np.square(z50)) < chi_hi
    assert chi_lo < np.sum(np.square(zds)) < chi_hi


def test_bootstrap_is_seeded_and_shaped(v_mono):
    a = _quiet_measure(v_mono, n_boot=30, seed=7)
    b = _quiet_measure(v_mono, n_boot=30, seed=7)
    assert a.mtf_samples.shape == (30, a.freq_cy_per_px.size)
    assert a.mtf50_samples.shape == (30,)
    np.testing.assert_array_equal(a.mtf_samples, b.mtf_samples)
    assert np.all(np.isfinite(a.mtf_samples))
    lo, hi = a.mtf_ci()
    assert np.all(lo <= hi)
    none = _quiet_measure(v_mono, n_boot=0)
    assert none.mtf_samples.shape == (0, none.freq_cy_per_px.size)
    assert all(math.isnan(x) for x in none.mtf50_ci())


# ---------------------------------------------------------------------------------------
# Result object, tables
# ---------------------------------------------------------------------------------------
def test_result_interface(v_mono, tmp_path):
    r = _quiet_measure(v_mono, n_boot=20)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.mtf50_cy_per_px = 1.0  # type: ignore[misc]
    f = r.freq_cy_per_px
    assert r.mtf_at(f[3]) == pytest.approx(r.mtf[3])
    assert r.mtf_at(5.0) == pytest.approx(r.mtf[-1])  # clamped, not 0
    assert r.mtf_samples_at([0.1, 0.2]).shape == (20, 2)
    d = r.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["mtf50_cy_per_px"] == pytest.approx(r.mtf50_cy_per_px)
    out = tmp_path / "mtf.csv"
    write_mtf_table(r, out)
    assert out.read_text().splitlines()[0] == "freq_cy_per_px,mtf,mtf_ci95_low,mtf_ci95_high"
    back = read_mtf_table(out)
    np.testing.assert_allclose(back.mtf, r.mtf, atol=1e-6)
    assert back.mtf50_cy_per_px == pytest.approx(r.mtf50_cy_per_px, abs=1e-5)


def test_roi_equals_crop(v_mono):
    padded = np.pad(v_mono, ((7, 3), (20, 11)), mode="edge")
    r1 = _quiet_measure(v_mono, n_boot=0)
    r2 = _quiet_measure(padded, roi=(20, 7, 20 + v_mono.shape[1], 7 + v_mono.shape[0]), n_boot=0)
    np.testing.assert_allclose(r1.mtf, r2.mtf, atol=1e-12)
    assert r2.roi == (20, 7, 145, 307)


def test_read_mtf_table_formats(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("# comment\nfreq_cy_per_px,mtf\n0,1\n0.25,0.6\n0.5,0.2\n")
    t = read_mtf_table(p)
    assert t.channel == "mtf" and t.mtf_samples.shape == (0, 3)
    assert t.mtf50_cy_per_px == pytest.approx(0.25 + 0.25 * 0.1 / 0.4)
    assert t.mtf_at(0.75) == pytest.approx(0.2)


@pytest.mark.parametrize(
    "text, match",
    [
        ("freq,mtf\n0,1\n0.5,0.3\n", r"row 1, column 1"),
        ("freq_cy_per_px,contrast\n0,1\n0.5,0.3\n", r"row 1, column 2: unexpected column"),
        ("freq_cy_per_px,mtf\n0,1\n0.25,abc\n0.5,0.3\n", r"row 3, column 2 \('mtf'\)"),
        ("freq_cy_per_px,mtf\n0,1\n0.25,nan\n0.5,0.3\n", r"row 3, column 2"),
        ("freq_cy_per_px,mtf\n0,1\n0.5,0.3\n0.4,0.2\n", r"row 4, column 1.*increasing"),
        ("freq_cy_per_px,mtf\n0,1\n0.5\n", r"row 3: 1 columns"),
        # not normalised (an MTF of 5 would give Δs = +2.9 bits and a capacity 11x the
        # pixel count's; 1e308 overflowed): refused
        ("freq_cy_per_px,mtf\n0,5\n0.5,3\n", r"row 2, column 2.*at 0 cy/px is 5, not 1"),
        ("freq_cy_per_px,mtf\n0.1,0.9\n0.2,50\n0.5,0.3\n", r"row 3, column 2.*above 10"),
        ("", r"empty"),
    ],
)
def test_read_mtf_table_bad_input(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(MTFInputError, match=match) as exc:
        read_mtf_table(p)
    assert "bad.csv" in str(exc.value)


def test_read_mtf_table_missing_file(tmp_path):
    with pytest.raises(MTFInputError, match="nope.csv"):
        read_mtf_table(tmp_path / "nope.csv")


# ---------------------------------------------------------------------------------------
# Corrupt images and warnings
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "image, match",
    [
        (np.full((100, 60), 0.4), "constant"),
        (0.5 + 0.01 * np.random.default_rng(0).standard_normal((100, 60)), "no edge"),
        (np.linspace(0, 1, 60)[None, :], "too small"),
        (np.zeros((100, 60, 4)), "shape"),
    ],
    ids=["constant", "noise-only", "one-row", "rgba"],
)
def test_corrupt_images(image, match):
    with pytest.raises(MTFInputError, match=match):
        measure_sfr(image, n_boot=0)


def test_nan_pixels_rejected_with_location():
    img = synthetic_edge((100, 60), 5.0)
    img[12, 34] = np.nan
    with pytest.raises(MTFInputError, match="row 12, column 34"):
        measure_sfr(img, n_boot=0)


def test_bad_arguments():
    img = synthetic_edge((100, 60), 5.0)
    for kw in ({"npol": 7}, {"window": "kaiser"}, {"roi": (0, 0, 500, 10)}, {"channel": "G"}):
        with pytest.raises(MTFInputError):
            measure_sfr(img, n_boot=0, **kw)
    with pytest.raises(MTFInputError, match="phase cycle|aligned"):
        measure_sfr(synthetic_edge((100, 60), 0.0, noise_sd=0.0), n_boot=0)


def test_edge_not_crossing_roi_rejected():
    img = synthetic_edge((100, 60), 5.0, center=(2.0, 50.0))
    with pytest.raises(MTFInputError):
        measure_sfr(img, n_boot=0)


def test_warnings_clipping_contrast_angle_bins():
    # clipping: 8-bit edge saturating the bright side
    img = np.clip(synthetic_edge((150, 80), 5.0, contrast=0.8, mean_level=170), 0, 255)
    with pytest.warns(MTFWarning, match="clipping"):
        r = measure_sfr(np.round(img).astype(np.uint8), n_boot=0)
    assert any("clipping" in w for w in r.warnings)
    # low contrast (< 20 %)
    with pytest.warns(MTFWarning, match="contrast"):
        measure_sfr(synthetic_edge((150, 80), 5.0, contrast=0.1, noise_sd=0.001), n_boot=0)
    # slant outside 2-10 deg and too few phase cycles for the bootstrap
    with pytest.warns(MTFWarning) as rec:
        measure_sfr(synthetic_edge((150, 80), 1.5, noise_sd=0.001), n_boot=10)
    msgs = [str(w.message) for w in rec]
    assert any("slant 1.50 deg" in m for m in msgs)
    assert any("phase cycles" in m for m in msgs)
    # 26.57 deg (slope 1/2): only two sub-pixel phases -> half of the 4x bins stay empty
    with pytest.warns(MTFWarning) as rec:
        r = measure_sfr(synthetic_edge((150, 150), math.degrees(math.atan(0.5)), noise_sd=0.001), n_boot=0)
    assert any("empty projection bin" in str(w.message) for w in rec)
    assert any("empty projection bin" in w for w in r.warnings)


def test_broken_image_is_one_line_of_error(tmp_path):
    """Pillow warns ("Corrupt EXIF data") before it fails on a broken TIFF; the warning's two lines
    must not come out above bayescap's error: only the one line naming the file."""
    import subprocess
    import sys

    p = tmp_path / "broken.tif"
    p.write_bytes(b"II*\x00garbage")
    r = subprocess.run([sys.executable, "-m", "bayescap.cli", "mtf", str(p)], capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bayescap: error:") and "broken.tif" in lines[0], r.stderr
