"""Numerical stability at the extremes (issue 7, item 5).

Simulated sensors spanning read noise 0.05–200 e⁻, conversion gain 0.01–1000 e⁻/DN, full well
10³–10⁶ e⁻, 8 to 16 bits, dark-dominated long exposures, a single exposure time, three levels,
noise below one DN everywhere, an MTF that reaches zero inside the band, and all rows saturated.
Every case must give finite, sensible numbers (loosely checked against the truth where the data
can inform them) or a clear error — never NaN, inf, a warning storm or a crash.

The Laplace–IS fast path runs without its MCMC fallback so that the file stays fast; where its
own check rejects the draws, the test checks that the result says so (``converged`` False, a
NOT CONVERGED note) and that the numbers are still finite and near the truth. Two cases also run
the short MCMC preset (``QUALITY_PRESETS["fast"]``, the fast path's fallback), marked slow.
"""

import warnings

import numpy as np
import pytest

import bayescap
from bayescap.api import fast_fit
from bayescap.exceptions import PTCInputError
from bayescap.inference.presets import QUALITY_PRESETS
from bayescap.physics.optics import DiffractionLens, MTFProduct, PixelAperture
from bayescap.report.text import format_text
from bayescap.simulate import SensorTruth, exposure_series, simulate_ptc

T = SensorTruth
SHAPE = (64, 64)  # 4096 pixels per frame: variance rel. sd 2 %, fast to simulate

#: id -> (truth, options)
CASES = {
    "read_noise_0.05e": (T(1.0, 0.05, 3000, adc_bits=12), {}),
    "read_noise_200e": (T(10.0, 200.0, 1e5, adc_bits=14), {}),
    "gain_0.01e_per_dn_16bit": (T(0.01, 0.5, 1000, adc_bits=16), {}),
    "gain_100e_per_dn_8bit": (T(100.0, 20.0, 2e4, adc_bits=8, black_level_dn=4), {}),
    "full_well_1e3": (T(0.2, 2.0, 1e3, adc_bits=12), {}),
    "full_well_1e6_16bit": (T(20.0, 10.0, 1e6, adc_bits=16), {}),
    "8bit": (T(20.0, 10.0, 4000, adc_bits=8, black_level_dn=4), {}),
    "16bit": (T(0.5, 3.0, 2e4, adc_bits=16), {}),
    "dark_dominated_long_exposures": (T(2.0, 5.0, 2e4, dark_current_e_per_s=5000.0, adc_bits=14), {"t_max": 1.0}),
    "single_exposure_time": (T(2.0, 5.0, 8000, adc_bits=12), {"single_t": 0.01}),
    "three_levels": (T(2.0, 5.0, 8000, adc_bits=12), {"n_levels": 3}),
    "noise_below_one_dn_everywhere": (T(1000.0, 5.0, 1e5, adc_bits=8, black_level_dn=4), {}),
}


def simulate(truth, opt, seed=1):
    ph, t = exposure_series(truth, opt.get("n_levels", 50), t_max_s=opt.get("t_max", 0.02))
    if "single_t" in opt:
        t = np.full_like(t, opt["single_t"])
    return simulate_ptc(truth, photons_per_pixel=ph, exposure_time_s=t, shape=SHAPE, seed=seed)


_cache = {}


def fitted(case):
    if case not in _cache:
        truth, opt = CASES[case]
        d = simulate(truth, opt)
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            r = fast_fit(d, seed=1, fallback=False)
        _cache[case] = (truth, d, r, w)
    return _cache[case]


def _all_finite(r):
    bad = [k for k, v in {**r.draws, **r.derived}.items() if not np.all(np.isfinite(v))]
    return bad


def _check_sensible(truth, r, *, tol_k_rejected=0.3):
    p = r.to_dict()["parameters"]
    k = p["conversion_gain_e_per_dn"]
    kt = truth.conversion_gain_e_per_dn
    if r.diag["converged"]:
        # the fast path's own check accepted: the truth inside its 95 % interval (1 % slack
        # for the simulator's rounding of the ADC level)
        assert 0.99 * k["ci95"][0] <= kt <= 1.01 * k["ci95"][1], (k, kt)
    else:
        assert r.notes[0].startswith("NOT CONVERGED")
        assert abs(k["median"] / kt - 1) < tol_k_rejected, (k, kt)
    rn = p["read_noise_e"]
    if rn["constrained"]:
        assert rn["ci95"][0] * 0.9 <= truth.read_noise_e <= rn["ci95"][1] * 1.1, (rn, truth.read_noise_e)
    fw = p["full_well_e"]
    if fw.get("median") is not None and r.diag["converged"]:
        assert 0.95 * fw["ci95"][0] <= truth.clip_charge_e <= 1.05 * fw["ci95"][1], (fw, truth.clip_charge_e)
    cap = r.to_dict()["derived"]["capacity_bits"]
    assert cap["median"] > 0 and np.isfinite(cap["ci95"]).all()


SLOWEST = {"read_noise_0.05e", "gain_100e_per_dn_8bit"}  # the fast fits over ~3 CPU-s

#: known failures of the sanity check, each with its diagnosis. Not strict: this one passes or
#: fails with the last digits of log p (below), so neither outcome says the defect is fixed.
KNOWN = {
    "noise_below_one_dn_everywhere": pytest.mark.xfail(
        strict=False,
        reason=(
            "K = 1000 e-/DN, 8 bits, read noise 0.005 DN: the fast path rejects itself (k̂ > 1), its optimum "
            "lies far below the highest point the MCMC reaches, and the standard MCMC does not converge "
            "either. Whether the rejected draws put K's median within the 30 % the check allows for a "
            "rejected result depends on the last digits of log p, so the check passes or fails by chance"
        ),
    )
}


#: cases whose fit (``fitted``'s cache) another test also asserts on: one xdist group each, so under
#: ``pytest -n 2`` both tests run on one worker and the case is fitted once
SHARED = {c: pytest.mark.xdist_group(f"test_extremes:{c}") for c in ("single_exposure_time",)}


def _case_param(c):
    # a known failure passes or fails by chance: its check is a benchmark (benchmarks/statistical_tests.py);
    # what holds regardless (finite, no warning storm, the report renders) the case's own test checks below
    marks = ([pytest.mark.slow] if c in SLOWEST else []) + ([KNOWN[c], pytest.mark.statistical] if c in KNOWN else [])
    return pytest.param(c, marks=marks + ([SHARED[c]] if c in SHARED else []))


@pytest.mark.parametrize("case", [_case_param(c) for c in CASES])
def test_extreme_case_finite_and_sensible(case):
    truth, d, r, w = fitted(case)
    assert _all_finite(r) == []
    # no warning storm: the fast path itself warns about nothing (a rejection is in the result)
    assert len(w) <= 2, [str(x.message)[:120] for x in w]
    _check_sensible(truth, r)
    # the report renders (capacity as a lower limit where the read noise is only an upper limit)
    txt = format_text(r)
    assert ("capacity C =" in txt) != ("capacity C >" in txt)


@SHARED["single_exposure_time"]
def test_single_exposure_time_reports_combined_dark_noise():
    truth, d, r, _ = fitted("single_exposure_time")
    p = r.to_dict()["parameters"]
    assert "dark_noise_e" in p and p["read_noise_e"]["constrained"] is False
    assert "dark_current" in r.model.terms.reasons


@pytest.mark.slow
def test_noise_below_one_dn_gives_upper_limit_not_detection():
    """Read noise of 0.005 DN is invisible (every dark pixel rounds to the black level): the result
    never claims a detection. The fast path rejects its own approximation here (K sits where the
    rounded variances stop growing), and rejected draws carry no calibrated upper limit: then it
    must say so first thing; only an accepted result's upper limit must cover the truth. The
    sensor of the case, on 12 exposure levels rather than 50: every level's noise is as far below
    1 DN, and the fast path's Newton search through the rounded moments costs 4 CPU-s rather than
    16 (the 50-level case is the statistical check above, a benchmark)."""
    truth, opt = CASES["noise_below_one_dn_everywhere"]
    d = simulate(truth, {**opt, "n_levels": 12})
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        r = fast_fit(d, seed=1, fallback=False)
    assert _all_finite(r) == []
    assert len(w) <= 2, [str(x.message)[:120] for x in w]
    txt = format_text(r)
    assert ("capacity C =" in txt) != ("capacity C >" in txt)
    rn = r.to_dict()["parameters"]["read_noise_e"]
    assert rn["constrained"] is False and "upper limit" in rn["note"]
    if r.diag["converged"]:
        assert rn["upper_limit_95"] >= truth.read_noise_e
    else:
        assert r.notes[0].startswith("NOT CONVERGED")


def test_mtf_zero_inside_the_band():
    truth, opt = CASES["single_exposure_time"]
    d = simulate(truth, {}, seed=3)
    lens = MTFProduct((PixelAperture(1.0), DiffractionLens(16.0, 555.0, 1.0)))  # cut-off 0.113 cy/px
    r = fast_fit(d, seed=1, mtf=lens, fallback=False)
    assert r.flags["mtf_band_cut"] and r.mtf_info["band_cut"]
    ds = r.derived["mtf_loss_bits"]
    assert np.all(np.isfinite(ds)) and np.all(ds < r.mtf_info["band_cut_bits"])
    with pytest.raises(ValueError, match="zero at every frequency"):
        fast_fit(d, seed=1, mtf=lambda f: np.zeros_like(np.asarray(f, float)), fallback=False)


def _all_saturated(truth):
    ph = np.linspace(2, 3, 10) * truth.clip_charge_e / truth.quantum_efficiency
    return simulate_ptc(truth, photons_per_pixel=ph, exposure_time_s=0.01, shape=(32, 32), seed=1)


# the ADC clips first: every row sits at the ADC maximum with no variance; or the well (8000 e-)
# clips before the ADC (8062 e-): the plateau keeps the read noise, means do not move
ALL_SATURATED = {"adc": T(1.0, 5.0, 1e5, adc_bits=12), "well": T(2.0, 5.0, 8000, adc_bits=12)}


@pytest.mark.parametrize("mechanism", list(ALL_SATURATED))
def test_all_rows_saturated_is_a_clear_input_error(mechanism, tmp_path, capsys):
    """Before: K came out 105x (ADC) or 3.7x (well) off with no input error. Now refused from
    the API (in-memory data and PTCModel), and by the CLI with exit status 2, one line, nothing written."""
    from bayescap.cli import main
    from bayescap.io.ptc_csv import write_ptc_csv
    from bayescap.model.ptc_model import PTCModel

    d = _all_saturated(ALL_SATURATED[mechanism])
    with pytest.raises(PTCInputError, match="every row is saturated") as e:
        fast_fit(d, seed=1, fallback=False)
    assert isinstance(e.value, ValueError) and e.value.column in ("mean_dn", "frac_saturated")
    with pytest.raises(PTCInputError, match="every row is saturated"):
        PTCModel(d)
    with pytest.raises(PTCInputError, match="every row is saturated"):
        bayescap.fit(d, seed=1, quality="standard")
    csv = tmp_path / "sat.csv"
    write_ptc_csv(d, csv)
    out = tmp_path / "out"
    with pytest.raises(PTCInputError, match="every row is saturated"):
        bayescap.load(csv)
    assert main(["fit", str(csv), "--quality", "fast", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "sat.csv" in err and "column" in err and "every row is saturated" in err
    assert not out.exists()


def test_one_unsaturated_row_is_not_refused():
    """The check is for *every* row: a series with rows below saturation is fitted as before."""
    truth = ALL_SATURATED["well"]
    ph = np.concatenate([[0.3, 0.6], np.linspace(2, 3, 8)]) * truth.clip_charge_e / truth.quantum_efficiency
    d = simulate_ptc(truth, photons_per_pixel=ph, exposure_time_s=0.01, shape=(32, 32), seed=1)
    from bayescap.model.ptc_model import PTCModel

    m = PTCModel(d)
    assert m.terms.clip != "none" and m.full_sat.sum() >= 1


@pytest.mark.slow
@pytest.mark.parametrize("case", ["three_levels", "gain_100e_per_dn_8bit"])
def test_mcmc_fast_preset_at_the_extremes(case):
    truth, opt = CASES[case]
    d = simulate(truth, opt)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        r = bayescap.fit(d, seed=1, quality=QUALITY_PRESETS["fast"])  # the MCMC preset itself
    assert _all_finite(r) == []
    assert len(w) <= 3, [str(x.message)[:120] for x in w]
    k = r.to_dict()["parameters"]["conversion_gain_e_per_dn"]
    assert abs(k["median"] / truth.conversion_gain_e_per_dn - 1) < 0.3
