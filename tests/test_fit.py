"""Whole fits: the real EMVA 1288 reference set, reproducibility, the CLI outputs."""

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import python_stdout, standard_recipe_gain

import bayescap
from bayescap.inference import chains as inf_chains
from bayescap.inference import coordinates as inf_coordinates
from bayescap.inference import curvature as inf_curvature
from bayescap.inference import diagnostics as inf_diagnostics
from bayescap.inference import mcmc as inf_mcmc
from bayescap.inference import moves as inf_moves
from bayescap.inference import newton as inf_newton
from bayescap.inference import optimize as inf_optimize
from bayescap.inference import presets as inf_presets
from bayescap.inference import starts as inf_starts
from bayescap.model import select_terms
from bayescap.report.text import format_text

EMVA_K_E_PER_DN = 3.571  # emva1288 1.0.2 on the full set: 1/K = 1/0.2801
EMVA_READ_NOISE_E = 10.92  # sigma_d = sigma_y.dark / K


@pytest.fixture(scope="module")
def basler_fit(basler_standard_fit):
    # the standard fit of the real reference set (seed 1), shared with other test files (conftest)
    return basler_standard_fit


def test_basler_matches_emva1288(basler_fit):
    d = basler_fit.to_dict()
    p = d["parameters"]
    k = p["conversion_gain_e_per_dn"]["median"]
    rn = p["read_noise_e"]["median"]
    # the set's response is compressive (about -2 % at the top, the response term is selected): K
    # is the small-signal gain; the standard's K is the slope of Δσ² against Δμ through the origin
    # over the rows up to 70 % of saturation, which averages the compression. The same recipe applied
    # to the model's variances at the posterior median gives emva1288's K.
    m = basler_fit.model
    assert m.terms.nonlinearity
    k_std = standard_recipe_gain(basler_fit)
    assert abs(k_std / EMVA_K_E_PER_DN - 1) < 0.01
    assert abs(k / EMVA_K_E_PER_DN - 1) < 0.05
    assert abs(rn / EMVA_READ_NOISE_E - 1) < 0.05
    assert d["diagnostics"]["converged"]
    # η likewise: the standard's responsivity (model means against photons through the origin, same
    # rows) times its K
    x = basler_fit.chains.chain
    pred = m.predict(np.median(x.reshape(-1, x.shape[-1]), axis=0)[None])
    rows = m.s_obs <= 0.7 * m.s_obs[np.argmax(m.v)]
    mu_p, s_model = m.mu_p[rows], pred["mean"][1][0][rows]
    eta_std = np.sum(mu_p * s_model) / np.sum(mu_p**2) * k_std
    assert eta_std == pytest.approx(0.4525, rel=0.02)
    assert p["quantum_efficiency"]["median"] == pytest.approx(0.4525, rel=0.05)
    # the clip is the ADC's: reported as such, and full well is the charge at the clip, the response
    # undone: the clip's signal (20 DN above S_ref) over 1 + the response's deviation at S_ref
    assert p["full_well_e"]["clip_source"] == "adc"
    dev = p["response_nonlinearity"]["median"]
    assert p["full_well_e"]["median"] == pytest.approx((4095 - 14.72) * k / (1 + dev), rel=3e-3)
    # a 14 ms dark series barely detects dark current (D·t ≈ 1 e⁻ against σ_d² ≈ 120 e⁻²): a wide
    # interval, or an upper limit, holding emva1288's value from the same variances (70 e⁻/s)
    dc = p["dark_current_e_per_s"]
    assert dc["ci95"][0] < 70.0 < dc["ci95"][1] and dc["ci95"][1] > 3 * dc["ci95"][0]
    cap = d["derived"]["capacity_bits"]
    assert cap["ci95"][0] < cap["median"] < cap["ci95"][1]
    assert d["model_terms"][:2] == ["photon_shot", "read"]


def test_contract_json_shape(basler_fit):
    d = json.loads(json.dumps(basler_fit.to_dict()))
    for key in ("bayescap_version", "input", "sensor", "parameters", "derived", "model_terms", "diagnostics"):
        assert key in d
    for name, s in d["parameters"].items():
        assert {"median", "ci68", "ci95", "unit", "constrained"} <= set(s), name
        if s["median"] is not None:
            assert s["ci95"][0] <= s["ci68"][0] <= s["median"] <= s["ci68"][1] <= s["ci95"][1], name
    for name in (
        "tonal_range_bits",
        "dynamic_range_db",
        "snr_max_db",
        "mtf_loss_bits",
        "effective_pixels",
        "capacity_bits",
    ):
        assert {"median", "ci68", "ci95", "unit"} <= set(d["derived"][name]), name
    dg = d["diagnostics"]
    assert {"method", "converged", "rhat_max", "ess_min"} <= set(dg)
    assert dg["rhat_max"] < 1.01 and dg["ess_min"] >= 400


def test_text_report_says_what_it_did(basler_fit):
    txt = format_text(basler_fit)
    assert "converged" in txt and "capacity C =" in txt and "95 % interval" in txt
    assert "upper limit" in txt  # dark current
    assert "pixel_pitch_um unknown" in txt  # the lens term left out, and why


def test_same_seed_same_numbers(tmp_path):
    truth = bayescap.simulate.SensorTruth(conversion_gain_e_per_dn=1.5, read_noise_e=2.0, full_well_e=5000.0)
    data = bayescap.simulate.simulate_ptc(truth, seed=1, shape=(50, 50), n_levels=25)
    a = bayescap.fit(data, seed=5, quality="fast").to_dict()
    b = bayescap.fit(data, seed=5, quality="fast").to_dict()
    for d in (a, b):
        d["diagnostics"].pop("wall_s")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    c = bayescap.fit(data, seed=6, quality="fast").to_dict()
    assert (
        c["parameters"]["conversion_gain_e_per_dn"]["median"] != a["parameters"]["conversion_gain_e_per_dn"]["median"]
    )


@pytest.mark.slow
def test_cli_json_and_out_dir(tmp_path, capsys):
    """``bayescap fit CSV --json --out DIR``, run in this process (main(argv) is the console script's
    entry point; tests/test_cli_commands.py and tests/test_faults.py run ``--out`` in fresh processes)."""
    from bayescap.cli import main

    csv = tmp_path / "s.csv"
    truth = bayescap.simulate.SensorTruth(
        conversion_gain_e_per_dn=2.0, read_noise_e=3.0, full_well_e=8000.0, prnu_frac=0.01, dsnu_e=1.0
    )
    bayescap.simulate.simulate_ptc(
        truth,
        seed=2,
        shape=(50, 50),
        n_levels=25,
        spatial_frames=8,
        spatial_every=6,
        path=csv,
        metadata={"pixel_pitch_um": 2.2},
    )
    before = csv.read_bytes()
    out = tmp_path / "out"
    code = main(["fit", str(csv), "--json", "--seed", "3", "--quality", "fast", "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    d = json.loads(cap.out)
    assert d["input"] == str(csv)
    assert d["parameters"]["prnu_percent"]["constrained"]
    assert d["sensor"]["pixel_pitch_um"] == 2.2
    assert {p.name for p in out.iterdir()} == {"result.json", "report.txt", "posterior.nc", "ptc.png", "corner.png"}
    assert json.loads((out / "result.json").read_text())["parameters"] == d["parameters"]
    import arviz as az

    idata = az.from_netcdf(out / "posterior.nc")
    assert "conversion_gain_e_per_dn" in idata.posterior and "capacity_bits" in idata.posterior
    assert csv.read_bytes() == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temp files left


# ------------------------------------------------------------------------------ stranded walkers
def test_stuck_walker_rule_on_exact_gaussian_draws():
    """For exact draws of a D-dim Gaussian, lp_max − lp = χ²_D/2; the rule flags a walker only when
    its *best* over the steps stays ½·χ²_D(1 − 1e-6) + 5 nats below: with 200 walkers × 20 steps of
    independent draws the chance of any false flag is far below 1e-6. A walker planted 100 nats down
    is flagged, and only it."""
    from bayescap.inference.chains import stuck_threshold, stuck_walkers

    rng = np.random.default_rng(3)
    for D in (3, 10, 14):
        lp = -0.5 * rng.chisquare(D, size=(20, 200))
        assert not stuck_walkers(lp, D).any()
        lp[:, 17] -= 100.0
        flagged = stuck_walkers(lp, D)
        assert flagged[17] and flagged.sum() == 1
    assert 25 < stuck_threshold(10) < 35


def test_stranded_walker_is_reported_not_averaged_in(basler_fit):
    """A walker whose production log-probability sits far below the mode makes the fit NOT CONVERGED,
    with the failing check named (its draws are not posterior draws)."""
    import dataclasses
    import warnings

    from bayescap.posterior import FitResult

    c = basler_fit.chains
    lp = np.array(c.log_prob, copy=True)
    lp[1, :, 5] -= 500.0
    bad = dataclasses.replace(c, log_prob=lp)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = FitResult.from_chains(
            basler_fit.model,
            bad,
            metadata=basler_fit.metadata,
            scene=basler_fit.scene,
            mtf=basler_fit.mtf,
            seed=basler_fit.seed,
            quality="standard",
        )
    assert not r.diag["converged"] and r.diag["walkers_stuck"] == 1
    assert any("stuck" in f for f in r.diag["failed_checks"])
    assert basler_fit.diag["walkers_stuck"] == 0
    # the note says what to rerun with: the next preset up, and for `accurate` (the longest preset)
    # a longer run
    assert r.notes[0].startswith("NOT CONVERGED") and r.notes[0].endswith("rerun with --quality accurate")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ra = FitResult.from_chains(
            basler_fit.model,
            bad,
            metadata=basler_fit.metadata,
            scene=basler_fit.scene,
            mtf=basler_fit.mtf,
            seed=basler_fit.seed,
            quality="accurate",
        )
    assert not ra.diag["converged"] and "--quality accurate" not in ra.notes[0]
    assert "max_rounds=" in ra.notes[0]


@pytest.mark.slow
def test_walkers_stranded_in_burn_in_are_moved():
    """Simulated M1 1.75 µm (data/benchmark). Started from the raw Laplace covariance, 32 of 160
    walkers of the short MCMC stayed at mean-discrepancy 0.1–0.4, 140–265 nats below the mode, and
    alone put QE's 95 % lower bound at 0.341 (main mode 0.398–0.402, truth 0.3991). Here 12 of 80
    walkers are planted there (g = 0.3, QE = 0.33): burn-in must move every one, and production
    must have none stranded and a QE interval inside the main mode, holding the truth."""

    import numpy as np

    from bayescap.model.ptc_model import PTCModel

    data = bayescap.load(Path(__file__).resolve().parents[1] / "data" / "benchmark" / "M1_1.75um.csv")
    model = PTCModel(data)
    x_map, _, cov, _ = inf_optimize.laplace_start(model)
    rng = np.random.default_rng(7)
    p0 = inf_mcmc._initial_ball(model, x_map, cov, 80, rng)
    bad = p0[:12].copy()
    bad[:, model.idx["log_g"]] = np.log(0.3)
    bad[:, model.idx["qe"]] = 0.33
    p0[:12] = bad
    lp_bad = model.log_prob(bad)
    assert np.all(np.isfinite(lp_bad)) and np.all(lp_bad < model.log_prob(x_map[None])[0] - 100)
    from dataclasses import replace

    # the reset itself, with DE/stretch moves only (the standard preset's IndependenceMove proposals
    # usually pull such walkers back before the check, so it would not be exercised)
    for settings, must_reset in (
        (replace(inf_presets.QUALITY_PRESETS["standard"], independence_fraction=0.0), True),
        (inf_presets.QUALITY_PRESETS["standard"], False),
    ):
        rstate = np.random.RandomState(11).get_state()
        inf_mcmc._WORKER_MODEL = model
        try:
            # 100 burn-in steps (the reset happens there) and 200 production steps: 16 000 draws, plenty
            # for 95 % bounds that must fall inside 0.39-0.41 around a main mode of 0.398-0.402
            _, chain, lp, *_, n_reset, _ = inf_mcmc._run_segment(
                (0, p0.copy(), None, rstate, 100, 200, settings, (x_map, cov))
            )
        finally:
            inf_mcmc._WORKER_MODEL = None
        if must_reset:
            assert n_reset >= 12
        assert not inf_chains.stuck_walkers(lp, model.ndim).any()
        qe = chain[..., model.idx["qe"]].ravel()
        lo, hi = np.quantile(qe, [0.025, 0.975])
        assert 0.39 < lo < 0.3991 < hi < 0.41


def test_rhat_halves_are_split_in_time():
    """R-hat's split halves are the first and second half of the steps (Vehtari et al. 2021), so a
    drift that every ensemble shares (all start from one approximation) fails the check; the same
    draws without the drift pass. (Split into halves of the walkers instead, the drifted chain
    would pass with R-hat 1.000.)"""
    from bayescap.inference.diagnostics import diagnostics, fast_diagnostics

    rng = np.random.default_rng(5)
    E, S, W = 4, 200, 32
    x = rng.standard_normal((E, S, W))
    drifted = x + np.where(np.arange(S) < S // 2, 0.5, 0.0)[None, :, None]  # half an sd, first half only
    # with ~E*S*W/2 independent draws per half, a 0.5 sd shift gives R-hat ≈ 1 + 0.5²/8 ≈ 1.03
    for a in (fast_diagnostics(drifted), diagnostics(drifted)):
        assert a["rhat"] > 1.02
    for a in (fast_diagnostics(x), diagnostics(x)):
        assert a["rhat"] < 1.005


def _sim00():
    """The first simulated sensor of benchmarks/speed_accuracy.py's ``sensor_set`` (sim00, the same
    draws from seed 2024): 10 bits, K 0.64 e-/DN, well clip 301 e-, 50 levels."""
    from bayescap.simulate import SensorTruth, simulate_ptc

    seed = 2024
    rng = np.random.default_rng(seed)
    bits = int(rng.choice([10, 12, 12, 14]))
    k = float(np.exp(rng.uniform(np.log(0.3), np.log(10.0))))
    fw = float(np.exp(rng.uniform(np.log(0.3), np.log(1.5))) * (2**bits - 1 - 64) * k)
    truth = SensorTruth(
        conversion_gain_e_per_dn=k,
        read_noise_e=float(np.exp(rng.uniform(np.log(1), np.log(30)))),
        full_well_e=fw,
        dark_current_e_per_s=float(rng.choice([0.0, 30.0, 300.0])),
        quantum_efficiency=float(rng.uniform(0.3, 0.8)),
        prnu_frac=0.005,
        full_well_spread_frac=0.005,
        adc_bits=bits,
    )
    assert truth.adc_bits == 10 and abs(truth.conversion_gain_e_per_dn - 0.64) < 0.01
    return simulate_ptc(truth, n_levels=50, seed=seed)


def test_laplace_start_finds_the_higher_optimum():
    """On sim00 the initial guess puts the clip spread τ on its prior cap (a wall), and the optimiser
    from it stops there, > 90 nats below the mode the MCMC samples (its 4 x 100 x 64 draws reach
    log p = -408.48); so does the start with a ten times larger variance discrepancy. The extra start
    with log τ - 2 (starts.MAP_START_LOG_TAU_SHIFT) reaches the mode. Checked in log(clip - lower bound)
    coordinates, where mcmc_start and the fast path optimise a free clip level."""

    from bayescap.model.ptc_model import PTCModel

    # the wall case: the clip spread's cap at 2 % of the clip (the default cap, 10 %, leaves the mode
    # reachable from the first start, checked at the end)
    # (the response held linear: the case is the clip spread's wall, and its log p levels are those of
    # this model; the means' small bend on sim00 selects the response term otherwise)
    d = _sim00()
    lin = select_terms(d, force={"nonlinearity": False})
    m = PTCModel(d, terms=lin, prior={"tau_max_frac": 0.02})
    c = inf_coordinates._sampler_coordinates(m)

    def lp_x(z):
        return float(m.log_prob(c.to_x(z)[None])[0])

    z_one, _, _, _ = inf_optimize.laplace_start(m, n_restarts=0, multi_start=False, coords=c)
    z, lp, cov, _ = inf_optimize.laplace_start(m, n_restarts=0, coords=c)
    assert lp_x(z_one) < -500
    assert lp_x(z) > -408.48
    assert np.all(np.isfinite(cov)) and np.all(np.linalg.eigvalsh(cov) > 0)
    # the optimiser itself reaches the mode from the τ start (not a later step by chance)
    starts = inf_starts._map_starts(m)
    assert len(starts) == 2
    (end,), _ = inf_newton.newton_map(c, [c.start_from_x(starts[-1])])
    assert lp_x(end.x) > -408.48
    m = PTCModel(d, terms=lin)
    c = inf_coordinates._sampler_coordinates(m)
    z_one, _, _, _ = inf_optimize.laplace_start(m, n_restarts=0, multi_start=False, coords=c)
    assert float(m.log_prob(c.to_x(z_one)[None])[0]) > -408.48
    # the BFGS route (kept for comparison) agrees
    z_b, _, _, _ = inf_optimize.laplace_start(m, n_restarts=0, coords=c, optimizer="bfgs")
    assert abs(lp_x(z_b) - lp_x(z)) < 0.01


class _Gaussians:
    """log of a mixture of two well separated Gaussians N(m_k, C_k) (weights w_k), or of one."""

    def __init__(self, means, covs, weights):
        self.means, self.covs, self.w, self.ndim = means, covs, weights, means[0].size

    def log_prob(self, x):
        x = np.atleast_2d(x)
        out = []
        for m, C, w in zip(self.means, self.covs, self.w):
            d = x - m
            out.append(
                np.log(w)
                - 0.5 * np.einsum("ij,jk,ik->i", d, np.linalg.inv(C), d)
                - 0.5 * np.linalg.slogdet(2 * np.pi * C)[1]
            )
        return np.logaddexp.reduce(np.array(out), axis=0)


def test_newton_map_finds_a_gaussian_mode_and_its_covariance():
    """A correlated 6-d Gaussian with sds 0.01-0.5 (condition number ~2500), started 3-8 sd away
    from two points: the mode to 1e-4 sd and the covariance to 1e-6 (the stencil is exact for a
    quadratic), the lower start dropped as the same mode, a non-finite start skipped."""
    rng = np.random.default_rng(3)
    n = 6
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    C = (Q * np.geomspace(0.01, 0.5, n) ** 2) @ Q.T
    m = rng.normal(0, 2, n)
    g = _Gaussians([m], [C], [1.0])
    L = np.linalg.cholesky(C)

    class WithWall(_Gaussians):
        def log_prob(self, x):
            x = np.atleast_2d(x)
            return np.where(x[:, 0] > 1e3, -np.inf, super().log_prob(x))

    g = WithWall([m], [C], [1.0])
    starts = [m + L @ rng.normal(0, 3, n), m + L @ rng.normal(0, 5, n), np.full(n, 2e3)]
    ends, n_calls = inf_newton.newton_map(g, starts)
    assert len(ends) == 2  # the start beyond the wall is not an optimum
    best = max(ends, key=lambda o: o.lp)
    assert best.converged and best.reason == "converged"
    # The point returned is where the last whitened stencil was taken. On a quadratic the step from
    # a whitened stencil is exact to rounding, but the first step comes from the raw stencil
    # (relative steps 1e-4: Hessian rounding ~1e-7 relative, times the condition number), and when
    # it lands within the gain tolerance no further step is taken: 3.5e-6 sd from the mode on one
    # machine, < 1e-6 on another (the BLAS kernel differs). 1e-4 sd: 30x the rounding seen, and
    # far inside the 0.045 sd that the gain tolerance alone allows (predicted gain < 1e-3 nats).
    np.testing.assert_allclose(np.linalg.solve(L, best.x - m), 0.0, atol=1e-4)
    np.testing.assert_allclose(best.cov, C, rtol=1e-6, atol=1e-12)
    other = min(ends, key=lambda o: o.lp)
    assert other.reason in ("reached the mode of a higher start", "converged")
    assert n_calls < 30
    with pytest.raises(RuntimeError, match="no finite starting point"):
        inf_newton.newton_map(g, [np.full(n, 2e3)])


def test_newton_map_keeps_each_start_on_its_own_mode():
    """Two Gaussians 40 sd apart (weights 0.3 and 0.7): one start near each ends on its own mode,
    with log p and covariance of that component (the other's mass is e^-800 there)."""
    n = 3
    C1, C2 = np.diag([0.04, 0.09, 0.01]), np.diag([0.01, 0.25, 0.04])
    m1, m2 = np.zeros(n), np.array([8.0, 0.0, 0.0])
    g = _Gaussians([m1, m2], [C1, C2], [0.3, 0.7])
    ends, _ = inf_newton.newton_map(g, [m1 + 0.3, m2 - 0.3])
    for o, m, C, w in zip(ends, (m1, m2), (C1, C2), (0.3, 0.7)):
        assert o.converged
        np.testing.assert_allclose(o.x, m, atol=1e-6)
        np.testing.assert_allclose(o.cov, C, rtol=1e-6, atol=1e-12)
        assert abs(o.lp - (np.log(w) - 0.5 * np.linalg.slogdet(2 * np.pi * C)[1])) < 1e-9


def test_newton_map_next_to_a_wall_retries_the_stencil_at_smaller_steps():
    """A Gaussian whose support ends 0.1 sd beyond the mode in x₀: the Hessian stencil at the
    whitened step h crosses the wall, the retry evaluates it at h/10 and h/100 together (one call of
    2 stencils), and the mode and covariance come out as without the wall (the stencil is exact for
    a quadratic)."""
    n = 3
    C, m = np.diag([0.04, 0.09, 0.01]), np.zeros(n)
    sizes = []

    class Wall(_Gaussians):
        def log_prob(self, x):
            x = np.atleast_2d(x)
            sizes.append(x.shape[0])
            return np.where(x[:, 0] > 0.1 * 0.2, -np.inf, super().log_prob(x))

    ends, n_calls = inf_newton.newton_map(Wall([m], [C], [1.0]), [m + np.array([-0.3, 0.4, 0.1])])
    (o,) = ends
    assert o.converged
    np.testing.assert_allclose(o.x, m, atol=1e-6)
    np.testing.assert_allclose(o.cov, C, rtol=1e-6, atol=1e-12)
    stencil = n * n + n + 1
    assert 2 * stencil in sizes  # the retry: both smaller steps in one call
    assert n_calls == len(sizes)


@pytest.mark.slow
@pytest.mark.statistical  # a standard fit of 12 rounds; benchmarks/statistical_tests.py runs it
def test_slow_burn_in_transient_is_discarded_not_reported(monkeypatch):
    """The walkers of sim00 started from the optimum 136 nats below the mode (the Laplace start
    before its extra optimiser start, restored here) relax over 300-400 steps, longer than the
    standard burn-in; the clip spread τ is the slowest. The standard preset used to say "converged"
    with τ's median at 2.3-2.7 DN; the accurate reference (seed 7, 8 ensembles, 400 burn-in steps)
    has median 1.655 DN and sd(log τ) 1.10. Now the time-split R-hat sees the drift and the first
    half of the production becomes burn-in. Tolerance: 4 sd of the Monte Carlo error of a median of
    log τ at ESS ≥ 1000 (this run) and ≥ 2000 (the reference): 4 · 1.2533 · 1.10 ·
    sqrt(1/1000 + 1/2000) = 0.21."""
    # the BFGS route from the initial guess alone: its optimum 136 nats below the mode (Newton from
    # there stays on τ's cap, 160 nats below, with the raw covariance: a start the extra starts exist for)
    monkeypatch.setattr(inf_optimize, "LAPLACE_OPTIMIZER", "bfgs")
    monkeypatch.setattr(inf_optimize, "_map_starts", lambda model: [])
    monkeypatch.setattr(inf_optimize, "find_map_scaled", lambda *a, **k: pytest.fail("no extra start expected"))
    # (the wall case: the clip spread capped at 2 % of the clip, where the initial guess's τ sits)
    d = _sim00()  # (the response held linear, as in test_laplace_start_finds_the_higher_optimum)
    r = bayescap.fit(
        d,
        seed=1,
        quality="standard",
        prior={"tau_max_frac": 0.02},
        terms=select_terms(d, force={"nonlinearity": False}),
    )
    dg = r.diag
    assert dg["converged"]
    assert dg["burn_in_extended_steps"] > 0
    # the check stops at the first quantity that fails (in parameter order), which names the event
    assert dg["drift_events"] and all(e["rhat"] >= 1.01 for e in dg["drift_events"])
    assert any(n.startswith("burn-in extended by") for n in r.notes)
    med = np.median(r.draws["clip_spread_dn"])
    assert abs(np.log(med / 1.655)) < 0.21


def test_a_drift_moves_the_first_half_of_the_production_to_burn_in(basler_fit, monkeypatch):
    """The drift rule's bookkeeping, on short rounds: when the convergence check fails on R-hat (split
    in time, so a drift every ensemble shares) the first half of the production so far becomes burn-in,
    the checks run on what follows (the next round at least as long as the cut), and the event is
    recorded and reported. The convergence check is
    scripted here (R-hat 1.05 of log_k after round 1, then passed); the rule on a real slow transient
    is test_slow_burn_in_transient_is_discarded_not_reported (a statistical check)."""
    from dataclasses import replace
    from warnings import catch_warnings, simplefilter

    from bayescap.posterior import FitResult

    model = basler_fit.model
    seen = []

    def check(chain, settings, cache, *rest):
        seen.append(chain.shape[1])
        if len(seen) == 1:
            cache["_shortfall"] = ("ess", 50.0, 1.05, model.idx["log_k"])  # (kind, ESS, R-hat, quantity)
            return False
        return True

    monkeypatch.setattr(inf_mcmc, "_default_converged", check)
    settings = replace(
        inf_presets.QUALITY_PRESETS["fast"], n_burn=10, n_steps=60, extend_steps=20, adaptive_extend=False
    )
    c = inf_mcmc.run_ensembles(model, settings=settings, seed=3, n_jobs=1)
    # round 2 checks the 30 steps left after the 30 moved to burn-in, plus as many new ones as were
    # moved (more than extend_steps = 20), so the checked chain does not shrink
    assert seen == [60, 60]
    assert c.chain.shape[1] == c.log_prob.shape[1] == 60 and c.n_rounds == 2
    assert c.extra["burn_in_extended"] == 30
    assert c.extra["drift"] == [{"round": 1, "quantity": "log_k", "rhat": 1.05, "steps_discarded": 30}]
    with catch_warnings():
        simplefilter("ignore")
        r = FitResult.from_chains(
            model, c, metadata=basler_fit.metadata, scene=basler_fit.scene, mtf=basler_fit.mtf, seed=3, quality="fast"
        )
    assert r.diag["burn_in_extended_steps"] == 30 and r.diag["drift_events"] == c.extra["drift"]
    assert any(n.startswith("burn-in extended by 30 steps") for n in r.notes), r.notes


class _Quadratic:
    """log p = −½ (x − m)ᵀ A (x − m) + c·(x₀ − m₀)⁴ (no Hessian contribution at m)."""

    def __init__(self, A, m, c=0.0):
        self.A, self.m, self.c, self.ndim = A, m, c, m.size

    def log_prob(self, x):
        d = np.atleast_2d(x) - self.m
        return -0.5 * np.einsum("ij,jk,ik->i", d, self.A, d) + self.c * d[:, 0] ** 4


def test_laplace_covariance_is_exact_for_a_quadratic_and_second_order_otherwise():
    rng = np.random.default_rng(5)
    n = 7
    B = rng.standard_normal((n, n))
    A = B @ B.T + n * np.eye(n)  # eigenvalues ≥ n > 1: below laplace_covariance's sd cap
    m = rng.normal(0, 3, n)
    cov = inf_curvature.laplace_covariance(_Quadratic(A, m), m, h=1e-2)
    np.testing.assert_allclose(cov, np.linalg.inv(A), rtol=1e-6, atol=1e-9)
    # with a quartic term the error is O(h²): the second difference of c·d⁴ is 12 c d² + 2 c h²
    x = m + 0.3
    exact = np.linalg.inv(A - np.diag([12 * 2.0 * 0.3**2] + [0] * (n - 1)))
    errs = [
        np.max(np.abs(inf_curvature.laplace_covariance(_Quadratic(A, m, c=2.0), x, h=hh) - exact))
        for hh in (3e-2, 3e-3)
    ]
    assert 50 < errs[0] / errs[1] < 200  # 100× for a 10× smaller step
    e0 = 3e-2 * max(1.0, abs(x[0]))  # the step along x₀
    predicted = np.linalg.inv(A - np.diag([12 * 2.0 * 0.3**2 + 2 * 2.0 * e0**2] + [0] * (n - 1)))
    np.testing.assert_allclose(
        inf_curvature.laplace_covariance(_Quadratic(A, m, c=2.0), x, h=3e-2), predicted, rtol=1e-6, atol=1e-9
    )


@pytest.mark.slow
def test_ensembles_in_lockstep_give_the_chains_of_one_after_the_other():
    """_run_segments runs the ensembles of one process in lockstep (one stacked log_prob call for
    their walkers); the chains, log p, final states and proposals are those of _run_segment run
    for each ensemble in turn, bit for bit."""

    from bayescap.model.ptc_model import PTCModel

    model = PTCModel(bayescap.load(Path(__file__).resolve().parents[1] / "data" / "emva1288_basler_ccd12.csv"))
    x_map, _, cov, _ = inf_optimize.laplace_start(model, n_restarts=0)
    settings = inf_presets.QUALITY_PRESETS["standard"]
    tasks = []
    for i in range(3):
        p0 = inf_mcmc._initial_ball(model, x_map, cov, 8 * model.ndim, np.random.default_rng(i))
        rstate = np.random.RandomState(20 + i).get_state()
        tasks.append((i, p0, None, rstate, 20, 30 + 10 * i, settings, (x_map, cov)))
    inf_mcmc._WORKER_MODEL = model
    try:
        together = inf_mcmc._run_segments(tasks)
        alone = [inf_mcmc._run_segment(t) for t in tasks]
    finally:
        inf_mcmc._WORKER_MODEL = None
    for a, b in zip(together, alone):
        assert a[0] == b[0]
        for u, v in zip(a[1:6], b[1:6]):
            if isinstance(u, tuple):  # the RandomState state
                assert all(np.array_equal(p, q) for p, q in zip(u, v))
            else:
                assert np.array_equal(u, v)
        assert np.array_equal(a[6], b[6]) and a[7] == b[7]
        assert all(np.array_equal(p, q) for p, q in zip(a[8], b[8]))


def test_ensembles_in_a_fork_pool_give_the_chains_of_lockstep(monkeypatch):
    """run_ensembles with n_jobs=2 (the default on two cores: a fork pool, one process an ensemble)
    gives the chains, log p and rounds of n_jobs=1 (the ensembles in lockstep in this process), bit
    for bit. Short rounds that never converge (3 of them), so the pool also runs the extensions."""
    from dataclasses import replace

    from bayescap.model.ptc_model import PTCModel

    model = PTCModel(bayescap.load(Path(__file__).resolve().parents[1] / "data" / "emva1288_basler_ccd12.csv"))
    settings = replace(
        inf_presets.QUALITY_PRESETS["fast"], ess_target=1e12, max_rounds=3, n_burn=10, n_steps=12, extend_steps=6
    )
    made, workers = [], inf_mcmc._Workers

    def counted(n):
        made.append(n)
        return workers(n)

    monkeypatch.setattr(inf_mcmc, "_Workers", counted)
    pool, lockstep = (inf_mcmc.run_ensembles(model, settings=settings, seed=3, n_jobs=n) for n in (2, 1))
    assert made == [2]  # the first run forked its pool of 2 processes, the second none
    assert pool.n_rounds == lockstep.n_rounds == 3
    assert np.array_equal(pool.chain, lockstep.chain) and np.array_equal(pool.log_prob, lockstep.log_prob)
    assert np.array_equal(pool.acceptance, lockstep.acceptance)


@pytest.mark.parametrize("shift", [0.0, 0.5])
def test_convergence_check_in_the_pool_decides_as_one_after_the_other(shift):
    """_default_converged with the ensembles' pool (every quantity diagnosed in the workers) gives
    the answer and the cache of the serial check (stop at the first failure)."""
    rng = np.random.default_rng(9)
    E, S, W, D = 4, 400, 24, 5
    chain = rng.standard_normal((E, S, W, D))
    chain[:, : S // 2, :, 2] += shift  # a drift in parameter 2: R-hat fails there
    settings = inf_presets.QUALITY_PRESETS["standard"]

    def derived(ch):
        return {"sum": ch.sum(axis=-1)}

    serial, pooled = {}, {}
    a = inf_mcmc._default_converged(chain, settings, serial, derived)
    pool = inf_mcmc._Workers(2)
    try:
        b = inf_mcmc._default_converged(chain, settings, pooled, derived, pool)
    finally:
        pool.close()
    assert a == b == (shift == 0.0)
    assert serial.keys() == pooled.keys()
    for k in serial:  # diagnostics dicts, and the τ of every parameter ("_tau", an array)
        assert np.array_equal(serial[k], pooled[k]) if isinstance(serial[k], np.ndarray) else serial[k] == pooled[k], k


def _ar1_walkers(rng, E, S, W, phi):
    """(E, S, W) draws of independent AR(1) walkers with unit marginal variance."""
    e = rng.standard_normal((E, S, W)) * np.sqrt(1.0 - phi * phi)
    x = np.empty_like(e)
    x[:, 0] = rng.standard_normal((E, W))
    for t in range(1, S):
        x[:, t] = phi * x[:, t - 1] + e[:, t]
    return x


def test_quantile_mcse_is_arviz_quantile_mcse_with_ensembles_as_chains():
    """diagnostics.quantile_mcse (the MCMC interval ends' Monte Carlo error) is ArviZ 0.x's
    mcse(method="quantile") on the ensembles-as-chains layout of the ESS (posterior.nc's), to rounding."""

    import arviz as az

    x = np.exp(0.5 * _ar1_walkers(np.random.default_rng(3), 4, 200, 48, 0.8))  # skewed
    ens = inf_diagnostics.by_ensemble(x)
    ours = inf_diagnostics.quantile_mcse(x, [0.025, 0.975])
    theirs = [float(az.mcse(ens, method="quantile", prob=p)) for p in (0.025, 0.975)]
    assert ours == pytest.approx(theirs, rel=1e-12)
    lo, hi = np.quantile(x, [0.025, 0.975])
    assert inf_diagnostics.interval_end_mcse_mcmc(x) == pytest.approx(max(theirs) / (hi - lo), rel=1e-12)
    assert inf_diagnostics.interval_end_mcse_mcmc(np.ones((2, 10, 4))) == 0.0
    bad = x.copy()
    bad[0, 0, 0] = np.nan
    assert np.isnan(inf_diagnostics.interval_end_mcse_mcmc(bad))


def test_quantile_mcse_matches_the_spread_over_replications():
    """The predicted Monte Carlo sd of the 2.5 % and 97.5 % quantiles of autocorrelated walkers
    (AR(1), φ = 0.7: τ ≈ 5.7 steps; 2 ensembles × 16 walkers × 200 steps) is the sd of those
    quantiles over 300 replications within 15 %: the sd of an sd estimated from 300 replications
    is 4.1 %, and the root mean square of the predictions is far more precise (measured ratios
    0.97–1.05 over three seeds while writing this test)."""
    rng = np.random.default_rng(11)
    ends, pred = [], []
    for _ in range(300):
        x = _ar1_walkers(rng, 2, 200, 16, 0.7)
        ends.append(np.quantile(x, [0.025, 0.975]))
        pred.append(inf_diagnostics.quantile_mcse(x))
    observed = np.std(np.array(ends), axis=0, ddof=1)
    predicted = np.sqrt(np.mean(np.array(pred) ** 2, axis=0))
    assert observed == pytest.approx(predicted, rel=0.15)


def test_a_walker_that_never_moved_fails_the_length_check_and_extends_the_run():
    """A walker stuck at one point for the whole production (the IndependenceMove allows it where
    its proposal undervalues the posterior) makes the autocorrelation time undefined (NaN). That
    fails _default_converged, which asks for a round of extend_steps, instead of passing there and
    failing only in FitResult's check (a run stopped NOT CONVERGED unextended)."""
    import dataclasses

    rng = np.random.default_rng(5)
    chain = np.stack([_ar1_walkers(rng, 4, 100, 24, 0.3) for _ in range(3)], axis=-1)
    settings = dataclasses.replace(inf_presets.QUALITY_PRESETS["standard"], adaptive_extend=True)
    cache = {}
    assert inf_mcmc._default_converged(chain, settings, cache)
    chain[2, :, 7, :] = chain[2, 0, 7, :]  # walker 7 of ensemble 2 never moves
    assert not np.all(np.isfinite(inf_diagnostics.integrated_time(chain)))
    cache = {}
    assert not inf_mcmc._default_converged(chain, settings, cache)
    assert cache["_shortfall"][0] == "tau" and np.isnan(cache["_shortfall"][1])
    assert inf_mcmc._next_round_steps(100, settings, cache) == settings.extend_steps


def test_rounds_that_chase_the_same_check_grow_by_half_the_chain():
    """A slowly mixing chain's τ estimate grows with the chain and its ESS stays put, so rounds
    sized to the last shortfall add extend_steps at a time until max_rounds (the non-linear zoo's
    soft knee without photon counts: 20 rounds, 540 steps, 10 τ = 556, not converged). From the
    second round in a row that the τ or the ESS check fails, a round adds at least half the chain;
    the first such round and the interval-end sizing are as before."""
    settings = inf_presets.QUALITY_PRESETS["standard"]
    assert settings.adaptive_extend and settings.extend_steps == 20
    tau = {"_shortfall": ("tau", 3.0)}
    ess = {"_shortfall": ("ess", 960.0, 1.001, 0)}
    mcse = {"_shortfall": ("mcse", 0.12, "x")}
    for cache in (tau, ess):
        assert inf_mcmc._next_round_steps(300, settings, cache, 1) == settings.extend_steps
        assert inf_mcmc._next_round_steps(300, settings, cache, 2) == 150
    # a large ESS shortfall keeps its own (larger) size
    assert inf_mcmc._next_round_steps(300, settings, {"_shortfall": ("ess", 500.0, 1.001, 0)}, 2) == 330
    n = int(np.ceil(1.1 * 300 * ((0.12 / settings.end_mcse_goal) ** 2 - 1.0)))
    assert inf_mcmc._next_round_steps(300, settings, mcse, 5) == n + n % 2
    # not where more steps cure nothing (a walker that never moved: τ undefined; R-hat failing), and
    # not beyond CHASE_MAX_STEPS: the zoo's b8_k200_dsnu50dn, whose stuck walkers never converge,
    # would otherwise grow by half its chain for 20 rounds
    stuck = {"_shortfall": ("tau", float("nan"))}
    split = {"_shortfall": ("ess", 40.0, 1.3, 0)}
    for cache in (stuck, split):
        assert inf_mcmc._next_round_steps(300, settings, cache, 5) == settings.extend_steps
    from bayescap.inference.rounds import CHASE_MAX_STEPS

    assert inf_mcmc._next_round_steps(CHASE_MAX_STEPS, settings, tau, 5) == settings.extend_steps


def test_end_mcse_target_extends_the_run_until_the_ends_are_accurate():
    """With SamplerSettings.end_mcse_target, _default_converged fails a chain whose R-hat and ESS
    pass while an interval end's Monte Carlo error exceeds the target, names the quantity, and sizes
    the next round from the 1/√n law; the error of every reported quantity lands in the cache
    either way, and the pool shares the work out without changing it."""
    import dataclasses

    rng = np.random.default_rng(5)
    chain = np.stack([_ar1_walkers(rng, 4, 400, 24, 0.3) for _ in range(3)], axis=-1)
    reported = lambda ch: {"a": ch[..., 0], "b": np.exp(ch[..., 1]), "c": ch[..., 2]}
    base = dataclasses.replace(inf_presets.QUALITY_PRESETS["standard"], adaptive_extend=True)
    cache = {}
    assert inf_mcmc._default_converged(chain, base, cache, reported_fn=reported)
    end = cache["end_mcse"]
    assert set(end) == {"a", "b", "c"} and all(0 < v < 0.05 for v in end.values())
    worst = max(end, key=end.get)
    strict = dataclasses.replace(base, end_mcse_target=end[worst] / 1.5)
    cache = {}
    assert not inf_mcmc._default_converged(chain, strict, cache, reported_fn=reported)
    assert cache["_shortfall"] == ("mcse", end[worst], worst)
    # the error falls as 1/√n: a target 1.5× below the error needs 2.25× the steps, 1.25× more (+10 %)
    n_next = inf_mcmc._next_round_steps(400, strict, cache)
    assert n_next % 2 == 0 and abs(n_next - 1.1 * 400 * 1.25) <= 2
    loose = dataclasses.replace(base, end_mcse_target=1.01 * end[worst])
    assert inf_mcmc._default_converged(chain, loose, {}, reported_fn=reported)
    pool = inf_mcmc._Workers(2)
    try:
        pooled = {}
        assert not inf_mcmc._default_converged(chain, strict, pooled, pool=pool, reported_fn=reported)
    finally:
        pool.close()
    assert pooled["end_mcse"] == cache["end_mcse"]


def test_mcmc_result_reports_its_interval_ends_monte_carlo_error(basler_fit):
    """A standard fit gives the Monte Carlo error of the 95 % interval ends of every parameter and
    derived quantity that varies (JSON diagnostics and the text report), computed on the final
    chain; the standard preset reports it without a target, the accurate one checks ≤ 1 %."""
    dg = basler_fit.to_dict()["diagnostics"]
    end = dg["interval_end_mcse"]
    varying = [n for n, v in list(basler_fit.draws.items()) + list(basler_fit.derived.items()) if np.ptp(v) > 0]
    assert set(end) == set(varying) and "capacity_bits" in end and "clip_dn" not in end  # the ADC's: fixed
    assert dg["interval_end_mcse_max"] == max(end.values()) == end[dg["interval_end_mcse_worst"]]
    assert dg["interval_end_mcse_target"] is None
    # the same numbers as computing them afresh from the result's draws
    E, S, W = basler_fit.shape_esw
    k = dg["interval_end_mcse_worst"]
    x = (basler_fit.draws.get(k) if k in basler_fit.draws else basler_fit.derived[k]).reshape(E, S, W)
    assert inf_diagnostics.interval_end_mcse_mcmc(x) == pytest.approx(end[k], rel=1e-12)
    # ESS ≥ 1 000 puts a Gaussian's 2.5 % point within ~0.68/√ESS ≈ 2 % of the width
    assert 0.002 < dg["interval_end_mcse_max"] < 0.05
    txt = format_text(basler_fit)
    assert f"Monte Carlo error of the 95 % interval ends: up to {dg['interval_end_mcse_max']:.3f}" in txt
    assert inf_presets.QUALITY_PRESETS["accurate"].end_mcse_target == 0.01
    assert "IndependenceMove" in dg["method_description"]
    # at another scene the derived quantities move, and their errors are recomputed; the parameters' stay
    from bayescap.posterior import Scene

    other = basler_fit.at_scene(Scene(exposure_time_s=0.5))
    end2 = other.diag["interval_end_mcse"]
    assert set(end2) == set(end)
    for n in basler_fit.draws:
        if n in end:
            assert end2[n] == end[n]
    cap = other.derived["capacity_bits"].reshape(E, S, W)
    assert end2["capacity_bits"] == inf_diagnostics.interval_end_mcse_mcmc(cap) != end["capacity_bits"]
    assert other.diag["interval_end_mcse_max"] == max(end2.values())
    # with a target the new scene's errors miss, the result at that scene says NOT CONVERGED
    import copy

    strict = copy.copy(basler_fit)
    strict.diag = dict(basler_fit.diag, interval_end_mcse_target=1e-6)
    at = strict.at_scene(Scene(exposure_time_s=0.5))
    assert not at.diag["converged"] and at.notes[0].startswith("NOT CONVERGED")
    assert [f for f in at.diag["failed_checks"] if f.startswith("Monte Carlo error of a 95 % interval end")]
    assert basler_fit.diag["converged"] and not basler_fit.diag["failed_checks"]  # the original untouched


def test_imprecise_interval_ends_are_flagged_where_no_check_bounds_them(basler_fit):
    """An MCMC result without an end_mcse_target flags (and notes) the quantities whose interval
    ends' Monte Carlo error is above IMPRECISE_END_MCSE of the width: none on the standard Basler fit
    (worst ~0.02); with one parameter's error raised above it, that one, in the JSON flags, the notes
    and the text report, and still at another scene (a parameter's error does not move with it); a
    target (accurate's check) takes over from the flag. (A real case: a simulated ROI whose clip level
    sits on a shelf.)"""
    import copy

    from bayescap.posterior import IMPRECISE_END_MCSE, Scene

    assert "imprecise_interval_ends" not in basler_fit.flags
    assert not [n for n in basler_fit.notes if n.startswith("imprecise interval ends")]
    assert basler_fit.diag["interval_end_mcse_max"] < IMPRECISE_END_MCSE
    r = copy.copy(basler_fit)
    r.diag, r.flags, r.notes = dict(basler_fit.diag), dict(basler_fit.flags), list(basler_fit.notes)
    r.diag["interval_end_mcse"] = dict(basler_fit.diag["interval_end_mcse"], read_noise_e=0.31)
    r._flag_imprecise_ends()
    assert r.flags["imprecise_interval_ends"] == {"read_noise_e": 0.31}
    note = [n for n in r.notes if n.startswith("imprecise interval ends")]
    assert len(note) == 1 and "read_noise_e" in note[0] and "0.31" in note[0]
    assert note[0] in format_text(r) and r.to_dict()["flags"]["imprecise_interval_ends"] == {"read_noise_e": 0.31}
    r._flag_imprecise_ends()  # idempotent: one note
    assert len([n for n in r.notes if n.startswith("imprecise interval ends")]) == 1
    other = r.at_scene(Scene(exposure_time_s=0.5))
    assert other.flags["imprecise_interval_ends"] == {"read_noise_e": 0.31}
    assert len([n for n in other.notes if n.startswith("imprecise interval ends")]) == 1
    r.diag["interval_end_mcse_target"] = 0.01
    r._flag_imprecise_ends()
    assert "imprecise_interval_ends" not in r.flags
    assert not [n for n in r.notes if n.startswith("imprecise interval ends")]
    assert "imprecise_interval_ends" not in basler_fit.flags  # the original untouched


def test_sampler_subclass_gives_emcee_chains_across_rounds():
    """moves._Sampler (log-probabilities taken as an array, the generator's state copied once per
    run_mcmc) gives the chain of emcee's own EnsembleSampler bit for bit, also when a run is
    continued by a new sampler from the returned state (as run_ensembles' rounds and burn-in halves
    do), and returns the same random state; NaN log-probabilities are refused as emcee does."""

    import emcee

    cov = np.array([[1.0, 0.5, 0.0], [0.5, 2.0, 0.3], [0.0, 0.3, 0.5]])
    prec = np.linalg.inv(cov)

    def log_prob(x):
        return -0.5 * np.einsum("ij,jk,ik->i", x, prec, x)

    def run(cls):
        rng = np.random.default_rng(3)
        p0 = rng.standard_normal((16, 3))
        rstate = np.random.RandomState(11).get_state()
        chains = []
        state = emcee.State(p0, random_state=rstate)
        for _ in range(3):  # three rounds, each a new sampler
            moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.StretchMove(), 0.2)]
            s = cls(16, 3, log_prob, vectorize=True, moves=moves)
            state = s.run_mcmc(state, 25, progress=False)
            chains.append(s.get_chain())
        return np.concatenate(chains), state

    a, sa_ = run(emcee.EnsembleSampler)
    b, sb = run(inf_moves._Sampler)
    assert np.array_equal(a, b)
    assert all(np.array_equal(np.asarray(u), np.asarray(v)) for u, v in zip(sa_.random_state, sb.random_state))
    s = inf_moves._Sampler(16, 3, lambda x: np.full(x.shape[0], np.nan), vectorize=True)
    with pytest.raises(ValueError, match="NaN"):
        s.run_mcmc(np.random.default_rng(0).standard_normal((16, 3)), 2, progress=False)


def test_pooled_round_check_derives_only_after_the_parameters_pass():
    """_default_converged with the ensembles' pool diagnoses the parameters first and asks for the
    derived draws only when they pass (a failing round does not compute them, as without a pool);
    the answer and the cache of a passing chain are those of the check without a pool."""
    from dataclasses import replace

    class InProcessPool:  # the pool's interface, run here
        n_processes = 2

        def map(self, fn, items):
            return [fn(x) for x in items]

    chain = np.random.default_rng(4).standard_normal((4, 40, 16, 3))
    calls = []

    def derived_fn(ch):
        calls.append(1)
        return {"sum": ch.sum(axis=-1)}

    base = replace(inf_presets.QUALITY_PRESETS["standard"], tau_factor=0.0, end_mcse_goal=None)
    for target, passes in ((1.0, True), (1e9, False)):
        settings = replace(base, ess_target=target)
        calls.clear()
        pooled, alone = {}, {}
        got = inf_mcmc._default_converged(chain, settings, pooled, derived_fn, InProcessPool())
        assert got is passes and len(calls) == int(passes)
        assert inf_mcmc._default_converged(chain, settings, alone, derived_fn, None) is passes
        if passes:
            assert pooled.keys() == alone.keys() and "sum" in pooled
            assert all(pooled[k] == alone[k] for k in pooled if k != "_tau")


def test_round_checks_compute_the_derived_draws_once_per_chain(monkeypatch, basler_fit):
    """``FitResult.chain_check_fns``: the convergence check and the interval-end check of a round
    are given the same chain; its derived quantities (capacity, TR, ...) are computed once for both,
    and again for a new chain. The values are those of a fresh computation."""
    from bayescap.posterior import FitResult

    r = basler_fit
    kw = dict(metadata=r.metadata, scene=r.scene, mtf=r.mtf, seed=r.seed)
    calls = []
    orig = FitResult._of_chain.__func__
    monkeypatch.setattr(FitResult, "_of_chain", classmethod(lambda cls, *a, **k: calls.append(1) or orig(cls, *a, **k)))
    derived_fn, reported_fn = FitResult.chain_check_fns(r.model, **kw)
    chain = r.chains.chain[:, -20:]
    d, rep = derived_fn(chain), reported_fn(chain)
    assert len(calls) == 1
    assert set(d) <= set(rep) and "capacity_bits" in d
    fresh = orig(FitResult, r.model, chain, **kw)
    np.testing.assert_array_equal(rep["capacity_bits"].ravel(), fresh.derived["capacity_bits"])
    np.testing.assert_array_equal(d["tonal_range_bits"].ravel(), fresh.derived["tonal_range_bits"])
    derived_fn(chain[:, -10:])
    assert len(calls) == 2  # a new chain: computed again


def test_emcee_imported_without_scipy_stats():
    """The MCMC imports emcee without scipy.stats (inference.moves._import_emcee; emcee's KDE move is
    its only user: ~1 s of a 2-core machine's process start), and emcee stays whole: its KDEMove,
    whose scipy.stats import then happens on first use, samples, and scipy.stats imports normally."""

    code = (
        "import sys, numpy as np\n"
        "import bayescap.inference.moves\n"
        "print('scipy.stats' in sys.modules)\n"
        "import emcee\n"
        "s = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * np.sum(x**2), moves=emcee.moves.KDEMove())\n"
        "s.run_mcmc(np.random.default_rng(0).standard_normal((8, 2)), 20, progress=False)\n"
        "print(s.acceptance_fraction.mean() > 0, 'scipy.stats' in sys.modules)\n"
        "import scipy.stats\n"
        "print(scipy.stats.norm.cdf(0.0))\n"
    )
    stdout = python_stdout(code)
    assert stdout.split() == ["False", "True", "True", "0.5"]


def test_burn_in_after_an_importance_start(basler_fit):
    """Walkers started from accepted Laplace–IS draws run ``n_burn_is_start`` burn-in steps, from the
    Laplace ball ``n_burn``; the chain and the result's diagnostics record the burn-in run."""
    from dataclasses import replace

    base = replace(
        inf_presets.QUALITY_PRESETS["standard"], n_burn=12, n_burn_is_start=4, n_steps=6, max_rounds=1, ess_target=1e12
    )
    model = basler_fit.model
    c_is = inf_mcmc.run_ensembles(model, settings=base, seed=3, n_jobs=1)
    c_ball = inf_mcmc.run_ensembles(model, settings=replace(base, importance_start=False), seed=3, n_jobs=1)
    assert c_is.extra["importance_start"] and c_is.extra["n_burn"] == 4
    assert not c_ball.extra["importance_start"] and c_ball.extra["n_burn"] == 12
    assert c_is.chain.shape[1] == c_ball.chain.shape[1] == 6
    assert c_is.chain.shape[2] == max(base.min_walkers, base.walkers_per_dim * model.ndim)


@pytest.mark.parametrize(
    "end, goal, passes", [(0.2, 0.1, False), (0.05, 0.1, True), (float("nan"), 0.1, True), (0.2, None, True)]
)
def test_interval_end_goal_extends_the_run(monkeypatch, end, goal, passes):
    """``end_mcse_goal`` (standard: 0.1, the imprecise-ends flag's threshold): a chain that passes
    R-hat, ESS and τ with an interval end's Monte Carlo error above the goal is run on, the next
    round sized from the 1/√n law; an undefined error (draws not all finite) or no goal passes."""
    from dataclasses import replace

    rng = np.random.default_rng(9)
    chain = rng.standard_normal((4, 200, 24, 2))
    settings = replace(inf_presets.QUALITY_PRESETS["standard"], ess_target=100.0, end_mcse_goal=goal)
    monkeypatch.setattr(inf_mcmc, "_end_mcse_all", lambda quantities, pool=None: {"a": 0.01, "q": end})
    cache = {}
    ok = inf_mcmc._default_converged(chain, settings, cache, reported_fn=lambda c: {"a": c[..., 0], "q": c[..., 1]})
    assert ok is passes
    if not passes:
        assert cache["_shortfall"] == ("mcse", end, "q")
        # (0.2 / 0.1)² − 1 = 3 times the 200 steps, +10 %, capped at 3 n + extend_steps
        assert inf_mcmc._next_round_steps(200, settings, cache) == min(int(np.ceil(1.1 * 200 * 3)), 3 * 200 + 20)
