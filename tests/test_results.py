"""What a user touches of a fit result (issue 39): a result pickles (``fit_many(..., n_jobs=2)``),
its ``posterior.nc`` is an ArviZ InferenceData whose diagnostics agree with the report's, it saves
and loads, and its ``repr`` is short."""

import json
import pickle
import warnings

import numpy as np
import pytest

import bayescap
from bayescap.batch import fit_many

PHONE = "data/simulated/sim_phone_1p75um_10bit.csv"
BENCH = ["data/benchmark/M1_1.75um.csv", "data/benchmark/M2_2.80um.csv"]


@pytest.fixture(scope="module")
def fast_result():
    return bayescap.fit(PHONE, seed=1, quality="fast")


@pytest.fixture(scope="module")
def standard_result(phone_standard_fit):
    """``bayescap.fit`` of PHONE at seed 1, standard quality: the session's fit (tests/conftest.py),
    which tests/test_golden.py's fit_phone_standard also reads."""
    return phone_standard_fit


@pytest.mark.parametrize("which", ["fast_result", "standard_result"])
def test_a_result_pickles_and_comes_back_the_same(which, request):
    r = request.getfixturevalue(which)
    back = pickle.loads(pickle.dumps(r))
    assert back.to_dict() == r.to_dict()
    assert np.array_equal(back.chains.chain, r.chains.chain)


def test_fit_many_in_two_processes_returns_full_results():
    """The README's ``fit_many([...], n_jobs=2)``: results (not summaries) come back from the
    worker processes, each the sensor's own fit."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        two = fit_many(BENCH, seed=3, n_jobs=2)
        one = fit_many(BENCH, seed=3)
    for a, b in zip(two, one):
        assert isinstance(a, bayescap.FitResult)
        assert np.array_equal(a.chains.chain, b.chains.chain)
        assert a.to_dict()["derived"] == b.to_dict()["derived"]


def test_cli_fit_with_two_jobs(capsys):
    from bayescap.cli import main

    status = main(["fit", *BENCH, "--quality", "fast", "--jobs", "2", "--seed", "3", "--no-progress"])
    assert status in (0, None)
    out = capsys.readouterr().out
    assert all(p in out for p in BENCH)


def test_repr_is_short_and_names_the_key_numbers(fast_result, standard_result):
    for r in (fast_result, standard_result):
        s = repr(r)
        assert len(s) < 400 and "array" not in s
        cap = r.derived["capacity_bits"]
        assert s.startswith("FitResult(sensor=") and f"quality='{r.quality}'" in s and "converged=True" in s
        assert "K=" in s and "read_noise=" in s and f"{np.median(cap):.4g}" in s and "(95 %)" in s


def test_repr_html_is_a_table_of_medians_intervals_and_units(standard_result):
    h = standard_result._repr_html_()
    assert h.count("<tr>") == 1 + len(standard_result.parameter_summary()) + len(standard_result.derived)
    assert "<th>95 % interval</th>" in h and "<td>e-/DN</td>" in h and "capacity_bits" in h
    assert "R-hat max" in h


# ------------------------------------------------------------------------------ posterior.nc
@pytest.fixture(scope="module")
def written(standard_result, tmp_path_factory):
    """posterior.nc of the standard result as ``write_outputs`` writes it, read back."""
    import arviz as az

    from bayescap.report.text import to_inference_data

    p = tmp_path_factory.mktemp("nc") / "posterior.nc"
    to_inference_data(standard_result).to_netcdf(str(p), engine="h5netcdf")
    return az.from_netcdf(str(p)).load()


def test_posterior_nc_chains_are_ensembles_and_arviz_is_the_report(standard_result, written):
    """az.rhat and az.ess (bulk and tail) on the saved posterior.nc are the report's per-quantity
    R-hat and ESS, and their extremes its rhat_max and ess_min: one definition (the ensembles as
    chains, benchmarks/ess_check.py)."""
    import arviz as az

    E, S, W = standard_result.shape_esw
    assert written.posterior.sizes["chain"] == E and written.posterior.sizes["draw"] == S * W
    per = standard_result.diag["per_quantity"]
    unc, post = written.unconstrained_posterior, written.posterior
    rhat = {**az.rhat(unc).to_dict()["data_vars"], **az.rhat(post).to_dict()["data_vars"]}
    bulk = {**az.ess(unc).to_dict()["data_vars"], **az.ess(post).to_dict()["data_vars"]}
    tail = {
        **az.ess(unc, method="tail").to_dict()["data_vars"],
        **az.ess(post, method="tail").to_dict()["data_vars"],
    }
    for n, v in per.items():
        assert rhat[n]["data"] == pytest.approx(v["rhat"], abs=1e-9), n
        assert bulk[n]["data"] == pytest.approx(v["ess_bulk"], rel=1e-9), n
        assert tail[n]["data"] == pytest.approx(v["ess_tail"], rel=1e-9), n
    ess_min = min(min(bulk[n]["data"], tail[n]["data"]) for n in per)
    assert ess_min == pytest.approx(standard_result.diag["ess_min"], rel=1e-9)
    assert max(rhat[n]["data"] for n in per) == pytest.approx(standard_result.diag["rhat_max"], abs=1e-9)
    assert np.nanmax([float(az.rhat(written)[n]) for n in written.posterior.data_vars]) < 1.01


def test_posterior_nc_groups_units_attributes_and_loo(standard_result, written):
    import arviz as az

    from bayescap.posterior.inference_data import ALL_OBSERVATIONS

    for g in ("posterior", "log_likelihood", "posterior_predictive", "observed_data", "sample_stats", "constant_data"):
        assert g in written.groups(), g
    post = written.posterior
    constants = set(json.loads(written.attrs["constant_variables"]))
    assert set(standard_result.draws) | set(standard_result.derived) == set(post.data_vars) | constants
    assert constants <= set(written.constant_data.data_vars)
    assert post["conversion_gain_e_per_dn"].attrs["units"] == "e-/DN"
    assert post["capacity_bits"].attrs["units"] == "bits"
    assert written.attrs["quality"] == "standard" and written.attrs["seed"] == "1"
    assert written.attrs["bayescap_version"] == bayescap.__version__ and "units" in written.attrs
    blocks = set(written.observed_data.data_vars)
    assert (
        blocks
        == set(written.posterior_predictive.data_vars)
        == set(written.log_likelihood.data_vars) - {ALL_OBSERVATIONS}
    )
    n_obs = sum(written.observed_data[v].size for v in blocks)
    assert written.log_likelihood[ALL_OBSERVATIONS].sizes["observation"] == n_obs
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        lo = az.loo(written, var_name=ALL_OBSERVATIONS)
    assert np.isfinite(lo.elpd_loo) and lo.n_data_points == n_obs
    # the pointwise total is the blocks' log-likelihoods side by side
    ll = written.log_likelihood
    parts = sum(float(ll[v].sum()) for v in blocks)
    assert parts == pytest.approx(float(ll[ALL_OBSERVATIONS].sum()), rel=1e-12)
    # the replicated observations scatter around the observed ones, block by block
    for v in blocks:
        rep = written.posterior_predictive[v].median(("chain", "draw")).values
        obs = written.observed_data[v].values
        assert np.median(np.abs(rep / obs - 1)) < 0.1, v


def test_posterior_nc_one_variable_per_observation_kind_with_one_unit(written):
    """Each observed_data/posterior_predictive variable is one kind of observation in one unit
    (means in DN, variances in DN²), indexed by the CSV's file rows, so ``az.plot_ppc`` on one
    variable compares like with like."""
    from bayescap.posterior.inference_data import OBSERVATION_VARS

    units = {name: unit for name, unit, _ in OBSERVATION_VARS.values()}
    od, pp = written.observed_data, written.posterior_predictive
    assert {"signal_mean_dn", "temporal_var_dn2", "dark_temporal_var_dn2"} <= set(od.data_vars)
    for v in od.data_vars:
        assert od[v].attrs["units"] == pp[v].attrs["units"] == units[v]
        assert units[v] == ("DN" if v.endswith("_dn") else "DN²")
        assert od[v].dims == (f"{v}_row",) and pp[v].dims == ("chain", "draw", f"{v}_row")
        rows = od[v][f"{v}_row"].values
        assert len(set(rows)) == rows.size and rows.min() >= 1  # file rows, each once


def test_plot_ppc_per_observation_kind(written, tmp_path):
    """``az.plot_ppc(idata, var_names=[...])`` draws one panel per kind of observation."""
    import arviz as az
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(written.observed_data.data_vars)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        axes = az.plot_ppc(written, var_names=names, num_pp_samples=50, random_seed=1)
    titles = {ax.get_xlabel() or ax.get_title() for ax in np.ravel(axes)}
    assert all(any(n in t for t in titles) for n in names), titles
    plt.close("all")


def test_posterior_nc_constants_give_no_nan_rhat_and_units_are_uniform(standard_result, written):
    """A variable that is the same in every draw (this sensor has no clipped row: clip_dn; its
    MTF is fixed: mtf_loss_bits) is in constant_data, not in the posterior, so ``az.rhat`` and
    ``az.ess`` on the file give no NaN and no RuntimeWarning; every variable of every group has a
    ``units`` attribute, dimensionless ones all ``"dimensionless"``."""
    import arviz as az

    from bayescap.posterior.inference_data import DIMENSIONLESS

    assert np.ptp(standard_result.draws["clip_dn"]) == 0 and np.ptp(standard_result.derived["mtf_loss_bits"]) == 0
    assert {"clip_dn", "mtf_loss_bits"} <= set(json.loads(written.attrs["constant_variables"]))
    assert float(written.constant_data["clip_dn"]) == standard_result.draws["clip_dn"][0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        rhat = az.rhat(written)
        ess = az.ess(written)
    assert all(np.isfinite(float(rhat[v])) and np.isfinite(float(ess[v])) for v in rhat.data_vars)
    for g in written.groups():
        for v, da in written[g].data_vars.items():
            unit = da.attrs.get("units")
            assert unit not in (None, "", "1"), (g, v, unit)
    assert written.posterior["quantum_efficiency"].attrs["units"] == DIMENSIONLESS


def test_fast_path_posterior_nc_has_one_chain_and_says_so(fast_result):
    import arviz as az

    from bayescap.report.text import to_inference_data

    idata = to_inference_data(fast_result)
    assert idata.posterior.sizes["chain"] == 1 and idata.attrs["rhat_applicable"] == 0
    assert "R-hat does not apply" in idata.attrs["chains"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.isfinite(az.loo(idata, var_name="all_observations").elpd_loo)


# ------------------------------------------------------------------------------ save / load
@pytest.mark.parametrize("which", ["fast_result", "standard_result"])
def test_save_and_load_give_the_same_json_and_report(which, request, tmp_path):
    from bayescap.report.text import format_text

    r = request.getfixturevalue(which)
    p = r.save(tmp_path / "fit.nc")
    assert not [q for q in tmp_path.iterdir() if q.name.startswith(".")]  # written atomically
    back = bayescap.FitResult.load(p)
    assert back.to_dict() == r.to_dict()
    assert format_text(back) == format_text(r)
    assert np.array_equal(back.chains.chain, r.chains.chain)
    scene = bayescap.Scene(exposure_time_s=0.02)
    assert back.at_scene(scene).to_dict() == r.at_scene(scene).to_dict()
