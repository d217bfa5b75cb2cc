"""Real sensors are not the textbook: a start inside the prior, plausibility warnings on the input
(units, photons, identical frames), limits printed as limits, stranded walkers left out of the
intervals, bounds that bind reported.

The test camera is an 8-bit sensor like the one that exposed these problems (K ≈ 49 e⁻/DN, dark
variance ≈ 0.1–0.25 DN², a visible dark-current ramp), simulated frame by frame, with its exposure
times written 1 000 times too short (µs written where ns were expected).
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
import pytest

import bayescap
from bayescap.cli import ingest as cli_ingest
from bayescap.inference.chains import ChainResult, stuck_walkers
from bayescap.inference.presets import QUALITY_PRESETS
from bayescap.io.plausibility import plausibility_warnings
from bayescap.io.ptc_csv import write_ptc_csv
from bayescap.model import PTCModel
from bayescap.posterior import FitResult
from bayescap.report.text import format_text
from bayescap.simulate import SensorTruth, exposure_series, simulate_ptc

TRUTH = SensorTruth(
    conversion_gain_e_per_dn=49.0,
    read_noise_e=16.0,
    full_well_e=11500.0,
    dark_current_e_per_s=10000.0,
    quantum_efficiency=0.5,
    adc_bits=8,
    black_level_dn=10.3,
)


def _camera(tmp_path, *, scale_t=1e-3, n_levels=16, name="cam.csv"):
    """The test camera (exposures 0–4 ms), its exposure times multiplied by ``scale_t``."""
    photons, t = exposure_series(TRUTH, n_levels, t_max_s=0.004)
    d = simulate_ptc(TRUTH, photons_per_pixel=photons, exposure_time_s=t, shape=(96, 96), seed=3)
    cols = {
        k: np.asarray(getattr(d, k), float)
        for k in (
            "exposure_time_s",
            "mean_dn",
            "temporal_var_dn2",
            "dark_mean_dn",
            "dark_temporal_var_dn2",
            "n_pixels",
            "photons_per_pixel",
            "frac_saturated",
        )
    }
    cols["exposure_time_s"] = cols["exposure_time_s"] * scale_t
    path = tmp_path / name
    write_ptc_csv(
        cols, path, metadata={"sensor": "8-bit test camera", "adc_bits": 8, "width_px": 2048, "height_px": 512}
    )
    return bayescap.load(path)


@pytest.fixture(scope="module")
def ns_camera(tmp_path_factory):
    return _camera(tmp_path_factory.mktemp("cam"))


@pytest.fixture(scope="module")
def ns_fit(ns_camera):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return bayescap.fit(ns_camera, seed=1, quality="fast")


def test_the_start_lies_inside_the_prior(ns_camera):
    """The dark ramp over µs-short exposures asks for ~10⁷ e⁻/s; the start must still lie inside
    the dark-current prior's 99.9 % range (half-normal, scale 10⁴ e⁻/s: ≤ 3.29 scales), and the
    data-driven guess it replaced is recorded."""
    m = PTCModel(ns_camera)
    x = m.initial_guess()
    scale = m.PRIOR["dark_current_scale_e_per_s"]
    assert np.exp(x[m.idx["log_dc"]]) <= 3.2906 * scale * (1 + 1e-9)
    assert np.isfinite(m.log_prob(x[None])[0])
    _, moved = m.initial_guess(projections=True)
    assert [p["parameter"] for p in moved] == ["dark_current_e_per_s"]
    assert moved[0]["guess"] > 1e6 and moved[0]["prior_scale_sd"] > 100


def test_the_clip_spread_scan_stays_inside_the_prior(ns_camera):
    """The start's clip spread is the best of a scan down to 10⁻³ DN; where the likelihood prefers
    the scan's bottom (as on a 100-level, 512×512 version of the test camera), the start is still
    within 3.29 sd of the log-normal prior's centre."""
    m = PTCModel(ns_camera)
    j = m.idx["log_tau"]
    m.log_prob = lambda th: -np.abs(np.atleast_2d(th)[:, j] - np.log(1e-3))  # the scan's bottom is best
    x = m.initial_guess()
    center = np.log(0.005 * (x[m.idx["clip_dn"]] - m.black_dn))
    assert abs(x[j] - center) <= 3.2906 * m.PRIOR["tau_log_sd"] + 1e-9


def test_unit_problem_is_named_and_the_fit_converges(ns_fit):
    d = ns_fit.to_dict()
    assert d["diagnostics"]["converged"]
    lo, hi = d["parameters"]["conversion_gain_e_per_dn"]["ci95"]
    assert lo < TRUTH.conversion_gain_e_per_dn < hi
    codes = {w["code"]: w for w in d["warnings"]}
    assert codes["exposure_time_unit"]["factor"] == 1e3
    assert d["diagnostics"]["start_outside_prior"][0]["parameter"] == "dark_current_e_per_s"
    txt = format_text(ns_fit)
    assert "exposure times look 1 000 times too short" in txt and "µs written where ns were expected" in txt
    assert "the data-driven start lay far in the prior's tail" in txt


def test_right_units_give_no_warning(tmp_path):
    assert plausibility_warnings(_camera(tmp_path, scale_t=1.0)) == []


def test_limits_are_printed_as_limits(ns_fit):
    """Dark current (posterior down to zero) and read noise (below 0.4 DN) are limits: the JSON keeps
    every key and adds ``limit``; the text prints the limit alone; DR, TR and capacity follow."""
    d = ns_fit.to_dict()
    for name in ("dark_current_e_per_s", "read_noise_e"):
        s = d["parameters"][name]
        assert {"median", "ci68", "ci95", "unit", "constrained"} <= set(s)
        assert s["constrained"] is False and s["limit"]["kind"] == "upper" and s["limit"]["level"] == 0.95
        assert s["limit"]["value"] >= np.quantile(ns_fit.draws[name], 0.9)
    assert d["derived"]["dynamic_range_db"]["limit"]["kind"] == "lower"
    txt = format_text(ns_fit)
    line = next(ln for ln in txt.splitlines() if ln.strip().startswith("dark_current_e_per_s"))
    assert "< " in line and "(95 % upper limit)" in line and "[" not in line, line
    assert "capacity C > " in txt


def test_one_exposure_time_gives_dark_current_as_a_limit(tmp_path):
    d = _camera(tmp_path, scale_t=1.0, n_levels=10)
    one_t = d.select(np.ones(d.n_levels, bool))
    t = np.full(one_t.n_levels, 0.002)
    cols = {k: np.asarray(getattr(one_t, k), float) for k in ("mean_dn", "temporal_var_dn2", "dark_mean_dn")}
    cols.update(exposure_time_s=t, dark_temporal_var_dn2=np.full(t.size, float(np.median(one_t.dark_temporal_var_dn2))))
    cols["n_pixels"] = np.asarray(one_t.n_pixels, float)
    write_ptc_csv(cols, tmp_path / "one_t.csv", metadata={"adc_bits": 8})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = bayescap.fit(bayescap.load(tmp_path / "one_t.csv"), seed=2, quality="fast", fallback=False)
    s = r.to_dict()["parameters"]["dark_current_e_per_s"]
    assert s["constrained"] is False and s["limit"]["kind"] == "upper"
    assert "dark_current_e_per_s" in format_text(r) and "(95 % upper limit)" in format_text(r)


def test_zero_variance_and_self_dark_are_warned(tmp_path):
    d = _camera(tmp_path, scale_t=1.0, n_levels=8)
    cols = {
        k: np.array(getattr(d, k), float)
        for k in ("exposure_time_s", "mean_dn", "temporal_var_dn2", "dark_mean_dn", "dark_temporal_var_dn2", "n_pixels")
    }
    cols["temporal_var_dn2"][2] = 0.0
    cols["dark_mean_dn"][4], cols["dark_temporal_var_dn2"][4] = cols["mean_dn"][4], cols["temporal_var_dn2"][4]
    write_ptc_csv(cols, tmp_path / "bad.csv", metadata={"adc_bits": 8})
    w = {x["code"]: x for x in plausibility_warnings(bayescap.load(tmp_path / "bad.csv"))}
    assert "identical" in w["zero_pair_variance"]["message"] and w["zero_pair_variance"]["rows"] == [3]
    assert w["dark_equals_bright"]["rows"] == [5]


@pytest.mark.parametrize("factor, word", [(100.0, "above 1"), (1e-5, "below 0.0001")])
def test_photons_inconsistent_with_the_signal(tmp_path, factor, word):
    d = _camera(tmp_path, scale_t=1.0, n_levels=8)
    cols = {
        k: np.array(getattr(d, k), float)
        for k in ("exposure_time_s", "mean_dn", "temporal_var_dn2", "dark_mean_dn", "dark_temporal_var_dn2", "n_pixels")
    }
    cols["photons_per_pixel"] = np.asarray(d.photons_per_pixel, float) / factor
    write_ptc_csv(cols, tmp_path / "ph.csv", metadata={"adc_bits": 8})
    w = {x["code"]: x for x in plausibility_warnings(bayescap.load(tmp_path / "ph.csv"))}
    assert word in w["photons_inconsistent"]["message"]
    assert w["photons_inconsistent"]["implied_quantum_efficiency"] == pytest.approx(0.5 * factor, rel=0.1)


def _frames_manifest(tmp_path, rows):
    rng = np.random.default_rng(0)
    for name in {r[0] for r in rows}:
        np.save(tmp_path / name, rng.poisson(100.0, size=(32, 32)).astype(np.uint16))
    lines = ["# adc_bits: 12", "file,kind,exposure_time_s"] + [",".join(r) for r in rows]
    (tmp_path / "manifest.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return tmp_path / "manifest.csv"


def _run_ingest(manifest, out):
    parser = cli_ingest.add_ingest_arguments(argparse.ArgumentParser(prog="bayescap ingest"))
    return cli_ingest.run_ingest(parser.parse_args([str(manifest), "-o", str(out), "--roi", "1.0"]))


@pytest.mark.parametrize(
    "rows, expected",
    [
        (
            [
                ("a.npy", "bright", "0.01"),
                ("a.npy", "bright", "0.01"),
                ("d0.npy", "dark", "0.01"),
                ("d1.npy", "dark", "0.01"),
            ],
            "the bright pair is a.npy twice",
        ),
        (
            [
                ("a.npy", "bright", "0.01"),
                ("b.npy", "bright", "0.01"),
                ("a.npy", "dark", "0.01"),
                ("b.npy", "dark", "0.01"),
            ],
            "listed both as a bright frame and as the dark",
        ),
    ],
)
def test_ingest_refuses_one_file_used_twice(tmp_path, capsys, rows, expected):
    out = tmp_path / "ptc.csv"
    assert _run_ingest(_frames_manifest(tmp_path, rows), out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err and "manifest.csv" in err, err
    assert not out.exists()


def test_ingest_refuses_identical_frames(tmp_path, capsys):
    rows = [
        ("a.npy", "bright", "0.01"),
        ("b.npy", "bright", "0.01"),
        ("d0.npy", "dark", "0.01"),
        ("d1.npy", "dark", "0.01"),
    ]
    manifest = _frames_manifest(tmp_path, rows)
    np.save(tmp_path / "b.npy", np.load(tmp_path / "a.npy"))  # the same exposure saved twice
    assert _run_ingest(manifest, tmp_path / "ptc.csv") == 2
    err = capsys.readouterr().err
    assert "a.npy and b.npy are identical" in err, err


def test_ingest_says_the_descriptor_unit(tmp_path, capsys):
    rng = np.random.default_rng(1)
    lines = ["v 3.0", "n 16 32 32"]
    for k, t_ns in enumerate((1e6, 2e6, 3e6)):
        for kind, photons in (("b", f" {1000.0 * (k + 1)}"), ("d", "")):
            lines.append(f"{kind} {t_ns}{photons}")
            for f in range(2):
                name = f"{kind}{k}_{f}.npy"
                mean = 100.0 + (300.0 * (k + 1) if kind == "b" else 0.0)
                np.save(tmp_path / name, rng.poisson(mean, size=(32, 32)).astype(np.uint16))
                lines.append(f"i {name}")
    (tmp_path / "d.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert _run_ingest(tmp_path / "d.txt", tmp_path / "ptc.csv") == 0
    err = capsys.readouterr().err
    assert "exposure times read in ns (the EMVA 1288 descriptor's unit" in err and "0.001–0.003 s" in err, err


def _synthetic_chains(model, x, *, stranded=None):
    """A ChainResult of 2 ensembles × 8 walkers × 60 steps from draws ``x`` (n ≥ 960, ndim), with
    walker 0 of ensemble 0 replaced by ``stranded`` (a point far below the mode) when given."""
    E, S, W = 2, 60, 8
    ch = np.array(x[: E * S * W].reshape(E, S, W, -1))
    if stranded is not None:
        ch[0, :, 0] = stranded + 1e-3 * np.arange(S)[:, None]
    lp = model.log_prob(ch.reshape(-1, ch.shape[-1])).reshape(E, S, W)
    return ChainResult(
        chain=ch,
        log_prob=lp,
        acceptance=np.full(E, 0.3),
        tau=np.ones(ch.shape[-1]),
        x_map=x[0],
        lp_map=float(lp.max()),
        settings=QUALITY_PRESETS["fast"],
        wall_s=0.0,
        n_rounds=1,
    )


def test_a_stranded_walker_never_sets_an_interval_end(ns_fit):
    m = ns_fit.model
    x = ns_fit.chains.chain.reshape(-1, m.ndim)
    bad = np.array(x[0])
    bad[m.idx["log_read"]] += 8.0  # read noise ~3 000 times the posterior's: thousands of nats down
    kw = dict(metadata=ns_fit.metadata, scene=ns_fit.scene, mtf=ns_fit.mtf, seed=1, quality="fast")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = FitResult.from_chains(m, _synthetic_chains(m, x, stranded=bad), **kw)
    d = r.to_dict()
    assert not d["diagnostics"]["converged"]  # a stranded walker fails the result
    assert d["parameters"]["read_noise_e"]["ci95"][1] < 2 * TRUTH.read_noise_e
    assert d["derived"]["dynamic_range_db"]["ci95"][0] > 40
    assert d["diagnostics"]["walkers_left_out"] == 1
    assert any("left out of every interval" in n for n in d["notes"])


def test_a_bound_that_binds_is_flagged(ns_fit):
    """The clip spread piled against its cap (a fraction of the clip level) is flagged with its
    consequence. The chains are a posterior that binds: the other parameters at their optimum with
    the clip spread held just under the cap, a small jitter around it, and the clip spread spread
    over the 0.3 (in log) below the cap, so no walker looks stranded."""
    from scipy.optimize import minimize

    m = ns_fit.model
    x = np.array(ns_fit.chains.chain.reshape(-1, m.ndim)[:960])
    j = m.idx["log_tau"]
    free = np.arange(m.ndim) != j

    def point(z, log_tau):
        v = np.array(x[0])
        v[free], v[j] = z, log_tau
        return v

    near_cap = float(np.log(m.tau_cap_dn(x[:1]))[0]) - 0.05
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        best = minimize(lambda z: -m.log_prob(point(z, near_cap)[None])[0], x[0][free], method="Powell")
    rng = np.random.default_rng(0)
    x[:] = point(best.x, near_cap)
    x[:, free] += (
        0.05 * ns_fit.chains.chain.reshape(-1, m.ndim)[:, free].std(0) * rng.standard_normal((960, free.sum()))
    )
    x[:, j] = np.log(m.tau_cap_dn(x)) - rng.uniform(1e-4, 0.3, 960)
    chains = _synthetic_chains(m, x)
    assert not any(stuck_walkers(chains.log_prob[e], m.ndim).any() for e in range(2))
    kw = dict(metadata=ns_fit.metadata, scene=ns_fit.scene, mtf=ns_fit.mtf, seed=1, quality="fast")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = FitResult.from_chains(m, chains, **kw)
    f = r.to_dict()["flags"]["bound_binding"]["clip_spread_dn"]
    assert f["side"] == "upper" and f"{100 * m.PRIOR['tau_max_frac']:g} % of the clip level" in f["bound"]
    assert "clip_spread_dn sits at its upper bound" in format_text(r)
    assert "bound_binding" not in ns_fit.flags


def test_repr_html_and_batch_table_print_limits_alone(ns_fit):
    from bayescap.cli.fit import _batch_table

    s = repr(ns_fit)
    assert "read_noise=< " in s and "(95 % upper limit)" in s and "capacity=> " in s, s
    h = ns_fit._repr_html_()
    assert "&lt; " in h and "95 % upper limit" in h
    row = _batch_table(["cam.csv"], [ns_fit]).splitlines()[-1]
    assert "(95 % lower limit)" in row.split("|")[-1], row


def test_a_measured_dark_current_near_the_prior_scale_stays_a_measurement(tmp_path):
    """The right units: the dark ramp (40 e⁻ over 4 ms) measures 10⁴ e⁻/s, the prior's scale. A
    posterior much narrower than the prior is a measurement wherever it sits in the prior."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = bayescap.fit(_camera(tmp_path, scale_t=1.0), seed=1, quality="fast")
    s = r.to_dict()["parameters"]["dark_current_e_per_s"]
    assert s["constrained"] is True and "limit" not in s
    assert s["ci95"][0] < TRUTH.dark_current_e_per_s < s["ci95"][1]
    assert r.to_dict()["warnings"] == []


def test_warnings_and_limits_survive_save_and_load(ns_fit, tmp_path):
    back = FitResult.load(ns_fit.save(tmp_path / "r.nc")).to_dict()
    d = ns_fit.to_dict()
    assert back["warnings"] == d["warnings"] != []
    assert back["parameters"]["dark_current_e_per_s"]["limit"] == d["parameters"]["dark_current_e_per_s"]["limit"]
    assert back["diagnostics"]["start_outside_prior"] == d["diagnostics"]["start_outside_prior"]
