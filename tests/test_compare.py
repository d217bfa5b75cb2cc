"""bayescap compare / report: area arithmetic, TR at H0, pairwise probabilities, CLI (HTML: test_html_browser.py).

The benchmark files are simulated (data/benchmark/README.md); fits use quality="fast" except
where a test is about accuracy.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bayescap.cli import compare as cli_compare
from bayescap.studies import area, exposure
from bayescap.studies import compare as C

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "data" / "benchmark"
M1 = BENCH / "M1_1.75um.csv"
M2 = BENCH / "M2_2.80um.csv"


# ------------------------------------------------------------------------------ area
def test_optical_format_table_and_parsing():
    a = area.parse_area("1/4in")
    assert (a.width_mm, a.height_mm) == (3.6, 2.7) and math.isclose(a.diagonal_mm, 4.5)
    assert area.parse_area('1/3.2"').width_mm == 4.54 and area.parse_area("1/3").height_mm == 3.6
    b = area.parse_area("5x4mm")
    assert (b.width_mm, b.height_mm) == (5.0, 4.0)
    assert area.parse_area("none") is None
    with pytest.raises(C.CompareInputError):
        area.parse_area("1/9.9in")


def test_area_crop_arithmetic():
    q = area.parse_area("1/4in")
    # 2.20 µm, 2056 x 1544 (Table 2): floor(3600/2.2) = 1636, floor(2700/2.2) = 1227
    c = area.area_crop(2056, 1544, 2.2, q)
    assert (c.width_px, c.height_px, c.pixels, c.cropped, c.smaller_than_area) == (1636, 1227, 1636 * 1227, True, False)
    # 2.80 µm, 1600 x 1200: floor(3600/2.8) = 1285, floor(2700/2.8) = 964
    c = area.area_crop(1600, 1200, 2.8, q)
    assert (c.width_px, c.height_px) == (1285, 964)
    # 1.75 µm, 2048 x 1536 is 3.584 x 2.688 mm: fills 1/4" within the 2 % tolerance, not cropped
    c = area.area_crop(2048, 1536, 1.75, q)
    assert (c.width_px, c.height_px, c.cropped, c.smaller_than_area) == (2048, 1536, False, False)
    assert math.isclose(c.covered_fraction, 3.584 * 2.688 / (3.6 * 2.7))
    # a VGA 3 µm sensor (1.92 x 1.44 mm) is smaller than 1/4": keeps its size, flagged
    c = area.area_crop(640, 480, 3.0, q)
    assert (c.width_px, c.height_px, c.cropped, c.smaller_than_area) == (640, 480, False, True)
    # portrait sensors get a portrait area
    c = area.area_crop(1544, 2056, 2.2, q)
    assert (c.width_px, c.height_px) == (1227, 1636)


# ------------------------------------------------------------------------------ probabilities
def test_prob_greater_exact_cases():
    x = np.random.default_rng(1).normal(size=3000)
    assert C.prob_greater(x, x) == 0.5  # ties count one half
    assert C.prob_greater(x + 100, x) == 1.0 and C.prob_greater(x, x + 100) == 0.0
    # N(δ,1) vs N(0,1): P = Φ(δ/√2); sd of the estimate ≈ sqrt(P(1-P)·(1/n+1/m)·(2/3)) < 0.008
    y = np.random.default_rng(2).normal(size=3000)
    d = 0.5
    p = C.prob_greater(x + d, y)
    expect = 0.5 * (1 + math.erf(d / 2))
    assert abs(p - expect) < 4 * 0.008


# ------------------------------------------------------------------------------ fits (shared)
@pytest.fixture(scope="module")
def cmp12():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return C.compare([str(M1), str(M2)], quality="fast", seed=0)


def test_exposure_calibration_recovers_simulated_sensitivity(cmp12):
    for s in cmp12.sensors:
        truth = float(s.result.metadata["sensitivity_truth_e_per_lux_s"])
        sens = s.calibration.sensitivity_e_per_lux_s
        assert "exposure_lux_s" in s.calibration.source
        lo, hi = np.quantile(sens, [0.0005, 0.9995])
        assert lo < truth < hi, (s.name, lo, truth, hi)


def test_tr_at_h0_limits_and_vectorisation(cmp12):
    s = cmp12.sensors[0]
    r = s.result
    idx = r.thin_index(500)
    h = np.geomspace(1e-3, 100, 40)
    tr, smax = exposure.tonal_range_at_exposure(r, h, calibration=s.calibration, idx=idx)
    assert tr.shape == smax.shape == (idx.size, h.size)
    b = np.log2(np.maximum(tr, 1.0))
    assert np.all(np.diff(b, axis=1) >= -1e-9)  # TR never falls as H0 rises
    # at a bright H0 the sensor is at base gain: TR over the full range, the fit's own number
    np.testing.assert_allclose(b[:, -1], r.derived["tonal_range_bits"][idx], rtol=1e-10)
    # below the knee S_max = sensitivity·H0/0.18
    sens = s.calibration.sensitivity_e_per_lux_s[idx]
    np.testing.assert_allclose(smax[:, 0], sens * 1e-3 / 0.18)
    snr = exposure.snr_at_exposure(r, h, calibration=s.calibration, idx=idx)
    assert snr.shape == (idx.size, h.size) and np.all(np.isnan(snr[:, -1]))  # 100 lux·s clips


def test_clearly_better_sensor_and_ratio(cmp12):
    """At 1/4" the 1.75 µm sensor keeps 2048 × 1536 pixels against the 2.80 µm sensor's 1285 × 964:
    the posterior is sure of the ordering there. Δs and b' do not depend on the crop, so the area
    capacity is the full-resolution one times the kept fraction of pixels, draw by draw."""
    d = cmp12.to_dict()
    (pair,) = d["pairs"]
    assert (pair["a"], pair["b"]) == ("M1_1.75um", "M2_2.80um")
    assert pair["p_a_greater_area"] > 0.99
    a, b = d["sensors"]
    for s, sd in zip(cmp12.sensors, (a, b)):
        kept = sd["area"]["pixels"] / sd["pixels_full"]
        np.testing.assert_allclose(s.draws["capacity_area_bits"], s.draws["capacity_full_bits"] * kept, rtol=1e-12)
    # same pixel count at 1/4" (not cropped): the area capacity is the full one
    assert a["area"]["pixels"] == a["pixels_full"] == 2048 * 1536
    assert b["area"]["pixels"] == 1285 * 964


def test_fit_and_compare_use_the_same_mtf(cmp12):
    """``bayescap fit`` and ``compare`` build the MTF from the same metadata, crosstalk included.

    A Gaussian kernel exp(−2π²σ²f²) multiplies the MTF, so Eq. 9 adds its closed form
    Δs_G = π f_N⁻² ∫₀^{f_N} f·log2(exp(−2π²σ²f²)) df = −π³σ²f_N²/(2 ln 2) to the aperture × lens Δs
    (no band cut at 1.75 µm, f/2.8)."""
    from bayescap.api import load, mtf_from_metadata
    from bayescap.physics.capacity import mtf_loss_bits

    md = load(M1).metadata
    assert "crosstalk_sigma_px" not in md  # the stand-ins carry no crosstalk (none is published)
    sigma = 0.3
    with_xt = float(mtf_loss_bits(mtf_from_metadata({**md, "crosstalk_sigma_px": sigma})).delta_s_bits)
    without = float(mtf_loss_bits(mtf_from_metadata(md)).delta_s_bits)
    assert with_xt - without == pytest.approx(-(math.pi**3) * sigma**2 * 0.25 / (2 * math.log(2)), rel=1e-9)
    # the compare result carries exactly the Δs of its metadata (same function)
    dsm = cmp12.sensors[0].result.derived["mtf_loss_bits"]
    assert np.allclose(dsm, without, rtol=1e-12)


def test_sensor_against_itself_is_even(cmp12):
    """The same file fitted with two seeds: independent posteriors of one quantity, P ≈ 0.5.

    The two posterior medians differ by Monte-Carlo error only; with ESS ≥ n_eff per fit,
    P = Φ(δ/√2) with δ ~ N(0, 2/n_eff) (in posterior sd): sd(P) ≈ 0.282·sqrt(2/n_eff)."""
    import warnings

    import bayescap

    r1 = cmp12.sensors[0].result
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r2 = bayescap.fit(str(M1), seed=12345, quality="fast")
    same = C.compare_results([r1, r1], names=["a", "b"])
    assert same.pairs[0]["p_a_greater_area"] == 0.5
    two = C.compare_results([r1, r2], names=["seed_a", "seed_b"])
    n_eff = min(r1.diag["ess_min"], r2.diag["ess_min"])
    tol = 4 * 0.282 * math.sqrt(2 / n_eff)
    assert abs(two.pairs[0]["p_a_greater_area"] - 0.5) < tol
    assert abs(two.pairs[0]["ratio_area"]["median"] - 1) < 0.01


# ------------------------------------------------------------------------------ CLI
def _parser(fn):
    p = argparse.ArgumentParser()
    fn(p)
    return p


@pytest.mark.slow
def test_cli_benchmark_runtime_and_json_equals_text(tmp_path):
    files = sorted(str(p) for p in BENCH.glob("*.csv"))
    assert len(files) == 5
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "compare", *files, "--json", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    print(f"bayescap compare data/benchmark/*.csv: wall {wall:.1f} s, CPU {cpu:.1f} s")
    assert proc.returncode == 0, proc.stderr
    # the machine is shared: the budget is on CPU time, one core's minute
    assert cpu < 60, f"compare took {cpu:.1f} s of CPU ({wall:.1f} s wall)"
    d = json.loads(proc.stdout)
    assert d == json.loads((tmp_path / "compare.json").read_text())
    text = (tmp_path / "compare.txt").read_text()
    assert text == C.format_compare_text(d)
    assert len(d["pairs"]) == 10
    # every printed number is the JSON's: capacity medians (Mbit, 4 digits), P (3 decimals)
    for s in d["sensors"]:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(s["name"] + " "))
        assert f"{s['capacity_area_bits']['median'] / 1e6:.4g} [" in line
        assert f"{s['tonal_range_bits_h0']['median']:.3f} [" in line
    # each pair's line, once for full resolution and once at the area: the ratio with its interval,
    # P(A>B), P(A>B+δ), P(B>A+δ), P(within δ)
    for p in d["pairs"]:
        lines = [ln for ln in text.splitlines() if f"{p['a']} vs {p['b']}" in ln]
        assert len(lines) == 2
        for line, q in zip(lines, ("full", "area")):
            nums = re.findall(r"\d+\.\d+", line.split(f"{p['a']} vs {p['b']}", 1)[1])
            want = [f"{p[f'ratio_{q}']['median']:.4f}", *(f"{x:.4f}" for x in p[f"ratio_{q}"]["ci95"])]
            want += [
                f"{p[k + '_' + q]:.3f}"
                for k in ("p_a_greater", "p_a_practically_greater", "p_b_practically_greater", "p_equivalent")
            ]
            assert nums == want, (line, want)


@pytest.mark.parametrize(
    "argv, what",
    [
        (["missing.csv"], "missing.csv"),
        ([str(M1), "--area", "1/9in"], "--area"),
        ([str(M1), "--h0", "-1"], "--h0"),
        ([str(M1), "--mid-grey", "1.5"], "--mid-grey"),
    ],
)
def test_bad_input_exits_2_with_one_line(argv, what, capsys):
    args = _parser(cli_compare.add_compare_arguments).parse_args(argv)
    assert cli_compare.run_compare(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and what in err


def test_bad_csv_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    lines = M1.read_text().splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.startswith("exposure_time_s"))
    cells = lines[i + 2].split(",")
    cells[2] = "-5"  # negative temporal variance
    lines[i + 2] = ",".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    args = _parser(cli_compare.add_compare_arguments).parse_args([str(M1), str(bad), "--out", str(tmp_path / "o")])
    assert cli_compare.run_compare(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.csv" in err and "temporal_var_dn2" in err
    assert not (tmp_path / "o").exists()  # nothing written on refusal


# ------------------------------------------------------------------------------ HTML
# the HTML report's structure (sections, inline PNGs, self-contained, atomic write) is checked on
# the two-sensor report of tests/test_html_browser.py, which this module's fits would repeat
