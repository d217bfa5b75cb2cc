"""The monotone response (a Bernstein log-slope) and the brighter-fatter term
(bayescap.model.response), checked on frames simulated here pixel by pixel: Poisson charge, a
response written as a small local function (not the model's), Gaussian read noise, rounding and
clipping. Shapes: a soft knee (slope 1 → 0.6 past 60 % of the well), an S shape (expansive low,
compressive high) on an 8-bit camera, and a brighter-fatter CCD (a₀₀ = −2e-6 per e⁻, means linear)."""

import dataclasses

import numpy as np
import pytest

import bayescap
from bayescap.io.ptc_csv import PTCData
from bayescap.model import PTCModel, select_terms
from bayescap.model.response import (
    bf_factor,
    deviation_at_ref,
    linearise,
    linearity_error_shape,
    response_forward,
)


# ---------------------------------------------------------------- a frame simulator of its own
def _frames(k, read_e, eta, well_e, bits, photons, resp=None, a00=0.0, black=64.0, shape=(96, 96), seed=0):
    """Rows of a photon-transfer table from frame pairs (a bright and a dark pair per row)."""
    rng = np.random.default_rng(seed)
    adc_max = 2**bits - 1

    def frame(mu_p):
        q = rng.poisson(mu_p * eta, size=shape).astype(float)
        if a00:
            # brighter-fatter: charge flows to the four neighbours in proportion to the collected
            # charge (means kept; the variance falls by a factor ≈ 1 + a₀₀μ)
            lap = np.roll(q, 1, 0) + np.roll(q, -1, 0) + np.roll(q, 1, 1) + np.roll(q, -1, 1) - 4 * q
            q = q - a00 / 8.0 * q.mean() * lap
        q = np.minimum(q, well_e)
        if resp is not None:
            q = resp(q)
        x = np.rint(black + (q + read_e * rng.standard_normal(shape)) / k)
        return np.clip(x, 0, adc_max)

    def pair(mu_p):
        a, b = frame(mu_p), frame(mu_p)
        d = a - b
        return (a.mean() + b.mean()) / 2, (np.mean(d * d) - (a.mean() - b.mean()) ** 2) / 2, np.mean(a >= adc_max)

    rows = np.array([pair(mu) + pair(0.0)[:2] for mu in photons])
    n = len(photons)
    return PTCData(
        exposure_time_s=np.full(n, 0.01),
        mean_dn=rows[:, 0],
        temporal_var_dn2=rows[:, 1],
        dark_mean_dn=rows[:, 3],
        dark_temporal_var_dn2=rows[:, 4],
        n_pixels=np.full(n, shape[0] * shape[1]),
        photons_per_pixel=np.asarray(photons, float),
        frac_saturated=rows[:, 2],
        metadata={"adc_bits": bits},
        source="frames",
    )


WELL_A = 45000.0


def _soft_knee(q, q0=0.6 * WELL_A, w=0.15 * WELL_A, drop=0.4):
    """Slope exactly 1 at 0, falling smoothly to 1 − drop past q0."""
    s0 = 1.0 / (1.0 + np.exp(q0 / w))
    return q - drop * w * (np.logaddexp(0.0, (q - q0) / w) - np.logaddexp(0.0, -q0 / w) - s0 * q / w)


def _case_knee(seed=1, shape=(128, 128)):
    """A 12-bit camera (K 10 e⁻/DN, η 0.5, dark noise 30 e⁻) with a soft knee; the well clips."""
    return _frames(10.0, 30.0, 0.5, WELL_A, 12, np.geomspace(200, 110000, 40), resp=_soft_knee, shape=shape, seed=seed)


def _case_s_shape(seed=2):
    """An 8-bit CMOS-like camera (K 50 e⁻/DN, η 0.6, read 15 e⁻): output u + u²/2 − u³/2 of the
    well fraction u (slope 1 at 0, 1.2 at u = 1/3, 0.5 at the top)."""
    Q = 12000.0

    def resp(q):
        u = np.minimum(q, Q) / Q
        return Q * (u + 0.5 * u**2 - 0.5 * u**3)

    return _frames(50.0, 15.0, 0.6, Q, 8, np.geomspace(60, 26000, 40), resp=resp, black=10.0, seed=seed)


def _case_bf(seed=3):
    """A 16-bit CCD (K 1.5 e⁻/ADU, read 5 e⁻) with brighter-fatter a₀₀ = −2e-6 per e⁻ and a linear
    response."""
    return _frames(1.5, 5.0, 0.8, 150000.0, 16, np.geomspace(200, 200000, 30), a00=-2e-6, black=1000.0, seed=seed)


# ---------------------------------------------------------------- the response function
def test_log_slope_response_is_monotone_with_unit_slope_at_zero():
    rng = np.random.default_rng(0)
    theta = np.vstack([np.zeros(4), rng.normal(0.0, 1.0, (20, 4))])
    s = np.linspace(0.0, 1500.0, 61)[None, :]
    x, slope = linearise(s, theta, 1000.0)
    assert np.all(x[:, 0] == 0.0) and np.allclose(slope[:, 0], 1.0)
    assert np.all(np.diff(x, axis=1) > 0) and np.all(slope > 0)
    assert np.allclose(x[0], s[0])  # θ = 0: linear
    # h' is the derivative of h (the quadrature against a finite difference)
    x2, _ = linearise(s + 1e-3, theta, 1000.0)
    assert np.allclose((x2 - x) / 1e-3, slope, rtol=1e-5, atol=1e-6)
    # the forward response inverts it
    assert np.allclose(response_forward(x, theta, 1000.0), s, atol=1e-6)
    # linear: no deviation, no linearity error
    assert deviation_at_ref(theta[:1], 1000.0)[0] == 0.0
    assert linearity_error_shape(theta[:1], 1000.0)[0] < 1e-9


def test_spline_log_slope_is_local_and_integrates_exactly():
    """The rich log-slope (a quadratic B-spline on SPLINE_INTERVALS intervals, RICH_BASIS values):
    L(0) = 0, the table's h and h' against adaptive quadrature of exp(L) and a finite difference,
    the forward response inverts it (h within 1e-6: the means with photons are precise to ~1e-4);
    and a change of the last value bends L only in the top
    interval (the low rows, which pin K, keep L = 0); the knots crowd towards the clip (the last
    interval 1/n² wide) and lie on the h table's nodes."""
    from scipy.integrate import quad

    from bayescap.model.response import N_TABLE, RICH_BASIS, log_slope
    from bayescap.model.response_spline import SPLINE_INTERVALS, knots

    rng = np.random.default_rng(1)
    theta = np.cumsum(rng.normal(0.0, 0.05, (6, RICH_BASIS)), axis=1)  # steps at the prior's scale
    s = np.linspace(0.0, 1200.0, 49)[None, :]
    x, slope = linearise(s, theta, 1000.0)
    assert np.all(log_slope(np.zeros((1, 1)), theta) == 0.0)
    for i in (0, 3):
        for v in (0.13, 0.5, 0.97):
            ref = (
                1000.0
                * quad(lambda u: float(np.exp(log_slope(np.array([[u]]), theta[i : i + 1])[0, 0])), 0, v, limit=200)[0]
            )
            assert linearise(np.array([[1000.0 * v]]), theta[i : i + 1], 1000.0)[0][0, 0] == pytest.approx(
                ref, rel=1e-6
            )
    x2, _ = linearise(s + 1e-3, theta, 1000.0)
    assert np.allclose((x2 - x) / 1e-3, slope, rtol=1e-5, atol=1e-6)
    assert np.allclose(response_forward(x, theta, 1000.0), s, atol=1e-6)
    # per_point (Gauss–Legendre for the polynomial) gives the table's numbers for the spline
    xp, sp = linearise(s, theta, 1000.0, per_point=True)
    assert np.array_equal(xp, x) and np.array_equal(sp, slope)
    step = np.zeros((1, RICH_BASIS))
    step[0, -1] = -0.5
    u = np.linspace(0.0, 1.0, 201)[None, :]
    L = log_slope(u, step)[0]
    t = knots()
    assert t[0] == 0.0 and t[-1] == 1.0 and np.all(np.diff(t) > 0) and np.all(np.diff(t, 2) < 0)
    assert 1.0 - t[-2] == pytest.approx(1.0 / SPLINE_INTERVALS**2)
    assert np.allclose(t * N_TABLE, np.round(t * N_TABLE), atol=1e-9)  # knots on the table's nodes
    assert np.all(L[u[0] <= t[-2]] == 0.0) and np.all(L[u[0] > t[-2]] < 0.0) and L[-1] == pytest.approx(-0.5)


def test_two_slope_ptc_gets_the_spline_without_photons():
    """Without photons a two-slope ADC's temporal PTC steps down at the kink (the variance falls by
    the slope ratio squared): the degree-4 and degree-8 polynomials both miss it, so their F-test
    says little, but the degree-4 proxy's χ² against the variances' sampling errors calls for the
    spline; a quadratic compression's PTC (smooth) keeps degree 4 under the same noise."""
    from bayescap.model.response import N_BASIS, RICH_P_VALUE, response_degree_evidence

    rng = np.random.default_rng(5)
    S = np.linspace(1500.0, 60000.0, 30)
    n_pix = 1e4
    kink = 42000.0
    x_two = np.where(S <= kink, S, kink + (S - kink) / 0.7)
    slope_two = np.where(S <= kink, 1.0, 0.7)
    x_quad = 2 * S / (1 + np.sqrt(1 - 4 * 0.1 * S / 66000.0))  # S = x(1 − 0.1 x/66000)
    slope_quad = 1.0 - 2 * 0.1 * x_quad / 66000.0
    for x, g, rich in ((x_two, slope_two, True), (x_quad, slope_quad, False)):
        v = g * g * x / 1.5 + 2.0
        sd = v * np.sqrt(2.0 / (n_pix - 1.0))
        vm = v + sd * rng.standard_normal(S.size)
        p_f, _ = response_degree_evidence(S, vm, sd, np.ones(S.size, bool))
        p, n = response_degree_evidence(S, vm, sd, np.ones(S.size, bool), sd_known=True)
        assert n == S.size and (p < RICH_P_VALUE) == rich
        if rich:
            assert p_f > RICH_P_VALUE  # the F-test alone would keep degree N_BASIS
    assert N_BASIS == 4


def test_rich_shape_is_the_spline_with_and_without_photons(tmp_path):
    """The non-linear zoo's 16-bit two-slope camera (frames simulated, seed of the zoo): without
    photon counts the degree test (its χ² leg) picks the spline, with them the F-test on the means
    does; the quadratic camera without photons keeps degree 4. A saved result records the spline's
    knots, and a file whose knots differ is refused."""
    from bayescap.model.response import N_BASIS, RICH_BASIS
    from bayescap.model.response_spline import SPLINE_INTERVALS, knots
    from bayescap.posterior.storage import _check_response_knots, _response_knots
    from bayescap.validation.zoo_nonlinear import ensure_csvs, nonlinear_zoo

    want = {
        "nl_two_slope_16bit_noph": RICH_BASIS,
        "nl_two_slope_16bit_ph": RICH_BASIS,
        "nl_quadratic_16bit_noph": N_BASIS,
    }
    for z in nonlinear_zoo():
        if z.name in want:
            terms = select_terms(bayescap.load(str(ensure_csvs(z, tmp_path)[0])))
            assert terms.nonlinearity and terms.response_degree == want[z.name], z.name
            # a saved result carries the spline's knots; a file with other knots, or none recorded,
            # is refused on loading (its coefficients on other knots are another shape)
            saved = _response_knots(terms)
            assert saved == (knots().tolist() if want[z.name] == RICH_BASIS else None), z.name
            _check_response_knots("fit.nc", terms, {"response_spline_knots": saved})
            if saved is not None:
                for other in ({}, {"response_spline_knots": np.linspace(0.0, 1.0, SPLINE_INTERVALS + 1).tolist()}):
                    with pytest.raises(ValueError, match="knots are"):
                        _check_response_knots("fit.nc", terms, other)


def test_bf_factor_is_astier_eq16():
    """(exp(2a₀₀μ) − 1)/(2a₀₀) = μ · expm1(z)/z with z = 2a₀₀μ."""
    a00, mu = -2e-6, np.array([1.0, 1e4, 1e5])
    z = 2 * a00 * mu
    assert np.allclose(mu * bf_factor(z), np.expm1(2 * a00 * mu) / (2 * a00), rtol=1e-12)
    assert bf_factor(np.array([0.0]))[0] == 1.0


# ---------------------------------------------------------------- which term the data choose
def test_s_shape_selects_the_response():
    t = select_terms(_case_s_shape())
    assert t.nonlinearity and "means bend" in t.how["response_nonlinearity"]


def test_brighter_fatter_with_photons_is_told_apart():
    """Straight means and bent variances: brighter-fatter, not a response."""
    t = select_terms(_case_bf())
    assert t.brighter_fatter and not t.nonlinearity
    assert "linear in the photons" in t.reasons["response_nonlinearity"]


def test_brighter_fatter_without_photons_cannot_be_told_apart():
    d = dataclasses.replace(_case_bf(), photons_per_pixel=None)
    t = select_terms(d)
    assert t.nonlinearity and not t.brighter_fatter
    assert "cannot be told apart" in t.reasons["brighter_fatter"]


def test_brighter_fatter_without_photons_holds_its_truths():
    """docs/real_sensors.md's claim: without photon counts the response term stands in for
    brighter-fatter; K and the dark noise hold their truths, and the full well's interval, spanning
    the bent and the straight reading, holds the true charge at the clip ((ADC max − black)·K: the
    means are straight)."""
    d = dataclasses.replace(_case_bf(), photons_per_pixel=None)
    p = bayescap.fit(d, quality="fast", seed=1).to_dict()["parameters"]
    truths = {"conversion_gain_e_per_dn": 1.5, "dark_noise_e": 5.0, "full_well_e": (2**16 - 1 - 1000.0) * 1.5}
    for name, truth in truths.items():
        lo, hi = p[name]["ci95"]
        assert lo < truth < hi, (name, p[name]["ci95"], truth)
    assert "both readings" in p["full_well_e"]["note"]


def test_brighter_fatter_variance_matches_the_frames():
    """The model's variance with the fitted-in a₀₀ bends as the frames do: at the simulated a₀₀ the
    predicted bright variances match the measured ones within their sampling error (K, read noise,
    QE at their truth)."""
    d = _case_bf()
    m = PTCModel(d)
    th = m.initial_guess()
    th[m.idx["log_k"]] = np.log(1.5)
    th[m.idx["log_dark_noise"]] = np.log(5.0)
    th[m.idx["bf"]] = -2e-6 * 1.5 * m.response_ref_dn
    pred = m.predict(th[None])["bright_var"][1][0]
    ok = (d.mean_dn[m.rows] - d.dark_mean_dn[m.rows]) < 0.95 * m.response_ref_dn
    rel = (m.v - pred)[ok] / pred[ok]
    se = np.sqrt(2.0 / m.nu[ok])
    # the simulator's first-order loss against Eq. 16: < 1.5 % at the top (a₀₀μ ≈ −0.2)
    assert np.all(np.abs(rel) < 5 * se + 0.015)
    th[m.idx["bf"]] = 0.0
    lin = m.predict(th[None])["bright_var"][1][0]
    top = np.argmax(np.where(ok, m.s_obs, -np.inf))
    assert (m.v[top] - lin[top]) / lin[top] < -0.1  # without the term: 10 % off at the top


# ---------------------------------------------------------------- fits
@pytest.mark.parametrize("case", ["knee"])
def test_shapes_cover_the_truth_without_outlier_labels(case):
    """K, the dark noise, η (and the full well for the knee) inside their 95 % intervals, and no row of
    the bent range called an outlier: the flexible response takes up the structured residuals (the
    quadratic response named 18 of 50 rows outliers on a knee, and K missed by 5 % on an S shape).
    The S shape's fit (the fast path falls back to MCMC there: minutes on this machine) is in
    ``benchmarks/response_shapes.py``."""
    if case == "knee":
        d, truth = _case_knee(), {"conversion_gain_e_per_dn": 10.0, "dark_noise_e": 30.0, "quantum_efficiency": 0.5}
        truth["full_well_e"] = WELL_A
    else:
        d, truth = _case_s_shape(), {"conversion_gain_e_per_dn": 50.0, "dark_noise_e": 15.0, "quantum_efficiency": 0.6}
    r = bayescap.fit(d, quality="fast", seed=1)
    out = r.to_dict()
    assert out["response_model"]["response"] == "monotone_log_slope"
    for name, v in truth.items():
        lo, hi = out["parameters"][name]["ci95"]
        assert lo < v < hi, (name, lo, v, hi)
    # no row of the bent, unclipped range is an outlier (rows at the clip, where the response and
    # the clip's roll-off meet, may still be: 2 of 50 on a 400²-pixel knee)
    s = d.mean_dn - d.dark_mean_dn
    below = {d.row_label(i) for i in range(s.size) if s[i] < 0.9 * r.model.response_ref_dn}
    assert not [o for o in out["outliers"] if o["row"] in below], out["outliers"]


def test_corrupted_row_is_still_named_on_a_bent_sensor():
    """A row whose photon count is reported 8 % high is named an outlier (the response's smoothness
    cannot follow one row)."""
    d = _case_knee()
    i = 20
    ph = np.array(d.photons_per_pixel)
    ph[i] *= 1.08
    d = dataclasses.replace(d, photons_per_pixel=ph)
    out = bayescap.fit(d, quality="fast", seed=1).to_dict()
    named = [o.get("row") for o in out["outliers"]]
    assert d.row_label(i) in named, out["outliers"]
