"""What a user touches of a fit result (issue 39): a result pickles (``fit_many(..., n_jobs=2)``),
its ``posterior.nc`` is an ArviZ InferenceData whose diagnostics agree with the report's, it saves
and loads, and its ``repr`` is short."""

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
def standard_result():
    return bayescap.fit(PHONE, seed=1, quality="standard", n_jobs=1)


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
