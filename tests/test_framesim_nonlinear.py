"""The frame simulator's response shapes and brighter-fatter, the non-linear zoo's definitions and
the astronomy tables: checked against closed forms written here, not against the model.

Statistical tolerances are 4 standard errors of the statistic (the pair-difference variance of N
pixels has a relative standard error sqrt(2/N)); where a first-order formula is compared, the
allowance also holds the known size of its next order.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from bayescap.validation.astro import AmpTruth, astronomy_table, draw_amplifier, focal_plane, write_astro_csv
from bayescap.validation.framesim import Acquisition, FrameSensor, clip_charge_e, simulate_rows
from bayescap.validation.responses import SHAPES, Response, bf_expected_var_e2, collect_brighter_fatter
from bayescap.validation.zoo_nonlinear import FAMILY, ensure_csvs, has_photons, nonlinear_zoo, scored_truths

ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- independence
@pytest.mark.parametrize("module", ["framesim", "responses", "astro", "zoo_nonlinear", "zoo"])
def test_simulator_modules_do_not_import_the_model(module):
    tree = ast.parse((ROOT / "bayescap" / "validation" / f"{module}.py").read_text())
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            names.append(("." * node.level) + (node.module or ""))
        elif isinstance(node, ast.Import):
            names += [a.name for a in node.names]
    bad = [
        n for n in names if n.startswith(("bayescap.model", "bayescap.simulate", "bayescap.api", "bayescap.inference"))
    ]
    bad += [n for n in names if n == "bayescap" or n.startswith("..")]
    assert not bad, f"{module} imports {bad}"


# --------------------------------------------------------------------------- response shapes
STRONG = {"quadratic": 0.1, "cubic": 0.12, "quartic": 0.07, "s_shape": 0.06, "soft_knee": 0.15, "two_slope": 0.3}


@pytest.mark.parametrize("kind", SHAPES)
def test_shapes_are_increasing_with_unit_slope_at_zero(kind):
    r = Response(kind, STRONG[kind], 1000.0, knee=0.75, x_max=1.45)
    x = np.linspace(0.0, 1.45, 20001)
    f = r.f(x)
    assert f[0] == 0.0
    assert np.all(np.diff(f) > 0)
    h = 1e-6
    assert float(r.f(h)) / h == pytest.approx(1.0, abs=1e-5)  # K stays the small-signal gain
    # slope_x is the derivative of f (central differences, away from the two-slope kink)
    xs = np.array([0.1, 0.5, 0.9, 1.2])
    num = (r.f(xs + 1e-6) - r.f(xs - 1e-6)) / 2e-6
    assert np.allclose(r.slope_x(xs), num, rtol=1e-5, atol=1e-7)
    # the inverse on electrons
    for q in (10.0, 500.0, 1000.0, 1400.0):
        assert r.inverse(float(r.apply(q))) == pytest.approx(q, rel=1e-9)
    if kind != "s_shape":
        assert np.all(f[1:] <= x[1:] + 1e-15)  # compressive everywhere
    else:
        assert float(r.f(0.3)) > 0.3  # expansive at low signal
        assert float(r.f(1.0)) < 1.0 and float(r.slope_x(1.0)) < 1.0  # compressive at the top


def test_s_shape_slope_rises_then_falls():
    r = Response("s_shape", 0.05, 1.0)
    assert float(r.slope_x(2 / 9)) == pytest.approx(1 + 4 * 0.05 / 9)
    assert float(r.slope_x(1.0)) == pytest.approx(1 - 5 * 0.05)


def test_a_response_that_turns_over_is_refused():
    with pytest.raises(ValueError, match="not increasing"):
        Response("quartic", 0.2, 1.0, x_max=1.45)
    with pytest.raises(ValueError, match="kind"):
        Response("sigmoid", 0.1, 1.0)


def test_response_bends_the_simulated_means():
    """Mean DN of a flat through a cubic response: black + f(μ)/K (+ Jensen's f''·μ/2, tiny)."""
    k, ref = 2.0, 50_000.0
    resp = Response("cubic", 0.12, ref)
    s = FrameSensor(
        k,
        3.0,
        1e6,
        quantum_efficiency=1.0,
        adc_bits=16,
        black_level_dn=100.0,
        response=resp,
        width_px=200,
        height_px=200,
    )
    rows = simulate_rows(s, Acquisition((0.01, 0.01), (10_000.0, 40_000.0)), seed=3)
    for r, mu in zip(rows, (10_000.0, 40_000.0)):
        expect = 100.0 + float(resp.apply(mu)) / k
        slope = float(resp.slope_x(mu / ref))
        sd = math.sqrt((slope**2 * mu + 3.0**2) / k**2 / (2 * 200 * 200))
        jensen = abs(-6 * 0.12 * mu / ref**2) * mu / 2 / k  # |f''(μ)|·Var(q)/2 in DN
        assert abs(r["mean_dn"] - expect) < 4 * sd + jensen, (r["mean_dn"], expect)
        assert abs(r["mean_dn"] - (100.0 + mu / k)) > 20 * sd  # the bend is there
        # the shot-noise variance is bent by the slope squared (delta method)
        var = slope**2 * mu / k**2 + (3.0 / k) ** 2 + 1 / 12
        assert abs(r["temporal_var_dn2"] - var) < 4 * var * math.sqrt(2 / (200 * 200)), (r["temporal_var_dn2"], var)


def test_clip_charge_goes_through_the_response():
    resp = Response("two_slope", 0.3, 10_000.0, knee=0.6)
    s = FrameSensor(2.0, 3.0, 1e6, adc_bits=12, black_level_dn=100.0, response=resp)
    q, by = clip_charge_e(s)
    assert by == "adc"
    assert float(resp.apply(q)) / 2.0 + 100.0 == pytest.approx(4095.0, rel=1e-12)
    assert q > (4095 - 100) * 2.0  # a compressive response clips at more charge


# --------------------------------------------------------------------------- brighter-fatter
def _lattice_c00(mu, a00, n):
    """The exact flat-field variance of the continuous-time process on an n×n periodic lattice
    (a₀₁ = −a₀₀/4): dC/dμ = AC + CA + I, so C = (e^{2Aμ} − I)/(2A); A is diagonal in Fourier space."""
    k = 2 * np.pi * np.arange(n) / n
    a = a00 - 0.5 * a00 * (np.cos(k)[:, None] + np.cos(k)[None, :])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(np.abs(a) > 1e-300, np.expm1(2 * a * mu) / (2 * np.where(a == 0, 1, a)), mu)
    return float(c.mean())


@pytest.mark.parametrize("mu", [20_000.0, 80_000.0])
def test_brighter_fatter_variance_deficit_follows_astier(mu):
    a00, n = -2.5e-6, 256
    q = collect_brighter_fatter(np.random.default_rng(int(mu)), np.full((2, n, n), mu), a00)
    d = q[0] - q[1]
    var = (float(np.mean(d * d)) - float(d.mean()) ** 2) / 2
    se = var * math.sqrt(2.0 / (n * n))
    # the mean is kept (the area a full pixel loses its neighbours gain)
    assert abs(float(q.mean()) - mu) < 4 * math.sqrt(mu / (2 * n * n))
    # Astier 2019 Eq. 16 to first order: C00 = μ + a00·μ²; its next order is (2/3)(a00² + 4a01²)μ³
    second = (2 / 3) * (a00**2 + 4 * (a00 / 4) ** 2) * mu**3
    assert abs(var - (mu + a00 * mu**2)) < 4 * se + second
    assert mu - var > 4 * se  # the deficit is measured, not noise (expected: 9.5 se at 20 000 e⁻)
    # and the whole curve: the exact solution of the simulated process (16 slices: O(1/16) at 2nd order)
    assert abs(var - _lattice_c00(mu, a00, n)) < 4 * se + second / 16
    # Eq. 16 itself (a00 only) is within the neighbours' second-order term
    assert abs(var - float(bf_expected_var_e2(mu, a00))) < 4 * se + (2 / 3) * 4 * (a00 / 4) ** 2 * mu**3


def test_brighter_fatter_in_dn_through_the_frame_chain():
    """simulate_rows with a00 < 0: C00 in DN = (e^{2a00μg} − 1)/(2a00g²) + n00/g² to first order."""
    g, read, a00, mu_e = 2.0, 5.0, -2e-6, 60_000.0
    s = FrameSensor(
        g,
        read,
        1e6,
        quantum_efficiency=1.0,
        adc_bits=18,
        black_level_dn=500.0,
        width_px=200,
        height_px=200,
        bf_a00_per_e=a00,
    )
    r = simulate_rows(s, Acquisition((0.01,), (mu_e,)), seed=11)[0]
    mu_dn = r["mean_dn"] - r["dark_mean_dn"]
    assert mu_dn == pytest.approx(mu_e / g, rel=1e-3)
    astier = math.expm1(2 * a00 * mu_dn * g) / (2 * a00 * g**2) + (read**2) / g**2 + 1 / 12
    se = astier * math.sqrt(2 / (200 * 200))
    second = (2 / 3) * 4 * (a00 / 4) ** 2 * mu_e**3 / g**2
    assert abs(r["temporal_var_dn2"] - astier) < 4 * se + second
    assert (mu_dn / g + read**2 / g**2) - r["temporal_var_dn2"] > 10 * se


def test_brighter_fatter_refuses_a_positive_a00():
    with pytest.raises(ValueError):
        collect_brighter_fatter(np.random.default_rng(0), np.ones((4, 4)), 1e-6)


# --------------------------------------------------------------------------- the non-linear zoo
def test_nonlinear_zoo_covers_the_family():
    zs = nonlinear_zoo()
    assert len(zs) >= 40
    assert len({z.name for z in zs}) == len(zs)
    for shape in FAMILY:
        sub = [z for z in zs if z.tags[0] == shape]
        assert {has_photons(z) for z in sub} == {True, False}
        assert len({z.tags[2] for z in sub}) >= 3
    bf = [z for z in zs if z.tags[0] == "brighter_fatter"]
    assert all(-3e-6 <= z.sensor.bf_a00_per_e <= -1e-6 for z in bf)
    for z in zs:
        t = scored_truths(z)
        assert ("quantum_efficiency" in t) == has_photons(z)
        assert t["conversion_gain_e_per_dn"][0] == z.sensor.k_e_per_dn
        if z.sensor.response is not None:  # the full-well truth is the charge at which the ADC clips
            y = float(z.sensor.response.apply(t["full_well_e"][0]))
            assert y / z.sensor.k_e_per_dn + z.sensor.black_level_dn == pytest.approx(z.sensor.adc_max_dn, rel=1e-9)


def test_nonlinear_zoo_csvs(tmp_path):
    z = next(z for z in nonlinear_zoo() if z.name == "nl_quadratic_16bit_noph")
    p_all, p_low = ensure_csvs(z, tmp_path)
    head = [ln for ln in p_all.read_text().splitlines() if not ln.startswith("#")]
    assert "photons_per_pixel" not in head[0].split(",")
    n_all = len(head) - 1
    low = [ln for ln in p_low.read_text().splitlines() if not ln.startswith("#")][1:]
    assert 0 < len(low) < n_all
    cols = head[0].split(",")
    sig = [
        float(r.split(",")[cols.index("mean_dn")]) - float(r.split(",")[cols.index("dark_mean_dn")]) for r in head[1:]
    ]
    assert len(low) == sum(s < 0.7 * max(sig) for s in sig)
    z2 = next(z for z in nonlinear_zoo() if z.name == "nl_quadratic_16bit_ph")
    text = ensure_csvs(z2, tmp_path)[0].read_text().splitlines()
    assert "photons_per_pixel" in next(ln for ln in text if not ln.startswith("#")).split(",")


# --------------------------------------------------------------------------- astronomy tables
def test_astronomy_table_rows_and_bias_removal(tmp_path):
    t = AmpTruth(1.3, 6.0, -2e-6, 100_000.0, 60, bias_adu=2345.6, roi_px=64)
    rows = astronomy_table(t, seed=5)
    assert set(rows[0]) == {"mean_dn", "temporal_var_dn2", "n_pixels"}
    m = np.array([r["mean_dn"] for r in rows])
    v = np.array([r["temporal_var_dn2"] for r in rows])
    n = 64 * 64
    e = t.charges_e()
    # bias removed: the lowest means are the charge over the gain (overscan of 512 pixels per frame)
    # sd: temporal noise of the pair average, the two overscan means (512 pixels), the realised PRNU
    sd = np.sqrt(v[:5] / (2 * n) + (6.0 / 1.3) ** 2 / 512 / 2 + (0.005 * e[:5] / 1.3) ** 2 / n)
    assert np.all(np.abs(m[:5] - e[:5] / 1.3) < 4 * sd)
    # low signal: shot noise + read noise (brighter-fatter negligible there)
    expect = e[:10] / 1.3**2 + (6.0 / 1.3) ** 2 + 1 / 12
    assert np.all(np.abs(v[:10] - expect) < 4 * expect * math.sqrt(2 / n))
    # high, unsaturated signal: the brighter-fatter deficit (a00·μ: 12–16 % at 60 000–80 000 e⁻)
    hi = (e > 60_000) & (e < 80_000)
    assert hi.sum() >= 1
    lin = e[hi] / 1.3**2 + (6.0 / 1.3) ** 2
    assert np.all(v[hi] < lin * (1 - 4 * math.sqrt(2 / n)))
    # the PTC turns over before the last row (rows past the well)
    assert int(np.argmax(v)) < len(v) - 3
    p = tmp_path / "amp.csv"
    write_astro_csv(p, rows, {"sensor": "amp"})
    lines = p.read_text().splitlines()
    assert lines[0] == "# sensor: amp" and lines[1] == "mean_dn,temporal_var_dn2,n_pixels"
    assert len(lines) == 2 + 60
    rows2 = astronomy_table(t, seed=5, n_pixels=False)
    assert [(r["mean_dn"], r["temporal_var_dn2"]) for r in rows2] == list(zip(m, v))  # the seed fixes the numbers
    write_astro_csv(p, rows2)
    assert p.read_text().splitlines()[0] == "mean_dn,temporal_var_dn2"


def test_focal_plane_draws():
    fp = focal_plane()
    assert len(fp) == 3024 and len({n for n, _, _ in fp}) == 3024 and len({s for _, _, s in fp}) == 3024
    g = np.array([t.gain_e_per_adu for _, t, _ in fp])
    pts = np.array([t.n_points for _, t, _ in fp])
    a00 = np.array([t.a00_per_e for _, t, _ in fp])
    assert g.min() >= 0.6 and g.max() <= 1.8
    assert pts.min() >= 40 and pts.max() <= 400
    assert np.all((a00 <= -1e-6) & (a00 >= -3e-6))
    weak = draw_amplifier(np.random.default_rng(0), strong_bf=False)
    assert -1e-6 <= weak.a00_per_e <= -2e-7


def test_score_astro_reads_the_fit_json():
    from bayescap.validation.astro import refuses_mean_variance_tables, score_astro

    t = AmpTruth(1.2, 6.0, -2e-6, 100_000.0, 50)
    res = {
        "parameters": {
            "conversion_gain_e_per_dn": {"median": 1.21, "ci95": [1.19, 1.23]},
            "dark_noise_e": {"median": 6.3, "ci95": [5.9, 6.7]},
        },
        "derived": {"ptc_turnoff_dn": {"median": 80_000.0}},
    }
    sc = score_astro(t, res)
    assert sc["k_inside"] and sc["k_miss_half_widths"] == 0.0
    assert sc["read_name"] == "dark_noise_e" and sc["read_rel_err"] == pytest.approx(0.05)
    assert sc["read_inside"] and sc["ptc_turnoff_dn"] == 80_000.0
    res["parameters"]["conversion_gain_e_per_dn"] = {"median": 1.28, "ci95": [1.26, 1.30]}
    sc = score_astro(t, res)
    assert not sc["k_inside"] and sc["k_miss_half_widths"] == pytest.approx(3.0)
    msg = "f.csv, row header, column 'exposure_time_s': missing required column(s): exposure_time_s, dark_mean_dn"
    assert refuses_mean_variance_tables(msg)
    assert not refuses_mean_variance_tables("f.csv, row 3, column 'mean_dn': not a number")
