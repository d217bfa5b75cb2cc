"""Detector MTF = system MTF / lens MTF (bayescap.measure.detector, ``bayescap mtf --lens-mtf``).

A synthetic slanted edge is blurred by a known lens (Gaussian PSF, σ_L) and a known detector
(square pixel aperture × Gaussian crosstalk, σ_D): its system MTF is the product of the two. The
lens MTF is given as a table in lp/mm; the detector MTF must come back."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from bayescap.exceptions import MTFInputError
from bayescap.measure import measure_sfr, synthetic_edge, synthetic_edge_mtf
from bayescap.measure.detector import detector_mtf, detector_table_text, read_lens_mtf_table

ROOT = Path(__file__).resolve().parents[1]
PITCH_UM, HEIGHT_PX = 1.75, 1536
SIGMA_LENS, SIGMA_DET, ANGLE = 0.4, 0.3, 5.0


def _lens_table(path: Path) -> Path:
    """Gaussian lens MTF exp(-2π²σ_L²f²), σ_L in pixels, tabulated in lp/mm up to 1 cy/px."""
    f_cy_px = np.linspace(0, 1.0, 81)
    f_lp_mm = f_cy_px / (PITCH_UM / 1000)
    m = np.exp(-2 * math.pi**2 * SIGMA_LENS**2 * f_cy_px**2)
    path.write_text("# Gaussian lens, sigma 0.4 px at 1.75 um\nfrequency_lp_per_mm,mtf\n")
    with path.open("a") as fh:
        for a, b in zip(f_lp_mm, m):
            fh.write(f"{a:.10g},{b:.10g}\n")
    return path


def _edge(noise_sd, seed=0):
    sigma = math.hypot(SIGMA_LENS, SIGMA_DET)  # Gaussians convolve: variances add
    return synthetic_edge((240, 100), ANGLE, sigma_px=sigma, noise_sd=noise_sd, seed=seed)


def _measure(img, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return measure_sfr(img, correct_bin_width=True, **kw)


def test_known_lens_and_detector_recovered_noise_free(tmp_path):
    lens = read_lens_mtf_table(_lens_table(tmp_path / "lens.csv"))
    assert lens.unit == "lp/mm"
    r = _measure(_edge(0.0), n_boot=0)
    d = detector_mtf(r, lens, pixel_pitch_um=PITCH_UM, height_px=HEIGHT_PX)
    f = d.freq_cy_per_px
    truth = synthetic_edge_mtf(f, sigma_px=SIGMA_DET, angle_deg=ANGLE)  # aperture × crosstalk
    band = f <= 0.5
    assert np.all(d.valid[band])
    # the measured system MTF is within 3e-3 of the truth (test_mtf); the lens divides the error by
    # its MTF, ≥ exp(-2π²·0.16·0.25) = 0.45 below Nyquist
    tol = 3e-3 / math.exp(-2 * math.pi**2 * SIGMA_LENS**2 * 0.25)
    assert np.max(np.abs(d.mtf - truth)[band]) < tol
    # and it is not the system MTF: the lens's share is large at Nyquist
    assert np.max(np.abs(r.mtf - truth)[band]) > 0.1
    # units: lp/mm = cy/px / pitch(mm); cycles per image height = cy/px × height
    np.testing.assert_allclose(d.freq_lp_per_mm, f / 0.00175)
    np.testing.assert_allclose(d.freq_cy_per_image_height, f * HEIGHT_PX)
    i = int(np.argmin(abs(f - 0.5)))
    assert d.freq_cy_per_image_height[i] == pytest.approx(HEIGHT_PX / 2, rel=0.02)


def test_detector_interval_covers_truth_with_noise(tmp_path):
    lens = read_lens_mtf_table(_lens_table(tmp_path / "lens.csv"))
    r = _measure(_edge(0.01, seed=3), n_boot=200, seed=3)
    d = detector_mtf(r, lens, pixel_pitch_um=PITCH_UM)
    for f0 in (0.125, 0.25, 0.375):
        i = int(np.argmin(abs(d.freq_cy_per_px - f0)))
        t = synthetic_edge_mtf(d.freq_cy_per_px[i], sigma_px=SIGMA_DET, angle_deg=ANGLE)
        assert d.ci95[0][i] <= t <= d.ci95[1][i], (f0, d.ci95[0][i], t, d.ci95[1][i])
        # the interval is the system interval scaled by 1/lens: wider than the system's own
        assert d.ci95[1][i] - d.ci95[0][i] > np.subtract(*np.quantile(r.mtf_samples[:, i], [0.975, 0.025]))
    text = detector_table_text(d)
    assert text.splitlines()[0].startswith("freq_cy_per_px,freq_lp_per_mm,freq_cy_per_image_height,detector_mtf")


def test_lens_below_threshold_is_not_divided(tmp_path):
    """Where the lens MTF is below min_lens_mtf (or outside its table) the quotient is not reported."""
    p = tmp_path / "lens.csv"
    p.write_text("frequency_cy_per_px,mtf\n0,1\n0.3,0.5\n0.4,0.01\n")
    lens = read_lens_mtf_table(p)
    r = _measure(_edge(0.0), n_boot=0)
    d = detector_mtf(r, lens)
    f = d.freq_cy_per_px
    assert np.all(d.valid[f <= 0.3]) and not np.any(d.valid[f > 0.4])
    assert any("below 0.05" in n for n in d.notes)
    assert d.to_dict()["detector_mtf"][-1] is None


@pytest.mark.parametrize(
    "text, match",
    [
        ("freq,mtf\n0,1\n", "line 1: expected a header"),
        ("frequency_lp_per_mm,mtf\n0,1\n10,abc\n", "line 3, column mtf"),
        ("frequency_lp_per_mm,mtf\n0,1\n-5,0.9\n", "line 3, column frequency_lp_per_mm"),
        ("frequency_lp_per_mm,mtf\n0,1\n0,0.9\n", "strictly increasing"),
        ("frequency_lp_per_mm,mtf\n0,100\n10,90\n", "fraction"),
    ],
)
def test_bad_lens_table(tmp_path, text, match):
    p = tmp_path / "lens.csv"
    p.write_text(text)
    with pytest.raises(MTFInputError, match=match):
        read_lens_mtf_table(p)


def test_cli_lens_mtf(tmp_path):
    img = tmp_path / "edge.npy"
    np.save(img, _edge(0.005, seed=1))
    lens = _lens_table(tmp_path / "lens.csv")
    run = [sys.executable, "-m", "bayescap", "mtf", str(img), "--n-boot", "50", "--correct-bin-width"]
    out = subprocess.run(
        [
            *run,
            "--lens-mtf",
            str(lens),
            "--pixel-pitch-um",
            "1.75",
            "--height-px",
            "1536",
            "--out",
            str(tmp_path / "d.csv"),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    assert "detector MTF = system MTF / lens MTF" in out.stdout and "lp/mm" in out.stdout
    assert "cy/image height" in out.stdout
    assert (tmp_path / "d.csv").read_text().startswith("freq_cy_per_px,freq_lp_per_mm")
    # lp/mm table without a pitch: one line, status 2
    bad = subprocess.run([*run, "--lens-mtf", str(lens)], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "--pixel-pitch-um" in bad.stderr and "Traceback" not in bad.stderr
    assert bad.stderr.strip().count("\n") == 0
