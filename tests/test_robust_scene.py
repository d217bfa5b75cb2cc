"""Issue 6 behaviours: identifiability, unsaturated series, outlier rows, scenes."""

import numpy as np
import pytest

import bayescap
from bayescap.io.ptc_csv import write_ptc_csv
from bayescap.posterior import Scene
from bayescap.simulate import SensorTruth, simulate_ptc

TRUTH = SensorTruth(
    conversion_gain_e_per_dn=2.0,
    read_noise_e=4.0,
    full_well_e=9000.0,
    dark_current_e_per_s=30.0,
    quantum_efficiency=0.6,
)


def test_single_exposure_time_reports_only_the_combination():
    ph = np.linspace(50, 16000, 30)
    d = simulate_ptc(TRUTH, photons_per_pixel=ph, exposure_time_s=0.2, seed=4, shape=(80, 80))
    r = bayescap.fit(d, seed=1, quality="fast").to_dict()
    p = r["parameters"]
    truth_combined = np.sqrt(4.0**2 + 30.0 * 0.2)
    assert p["dark_noise_e"]["constrained"]
    assert p["dark_noise_e"]["ci95"][0] < truth_combined < p["dark_noise_e"]["ci95"][1]
    assert p["read_noise_e"]["constrained"] is False and "not separable" in p["read_noise_e"]["note"]
    assert p["dark_current_e_per_s"]["constrained"] is False
    assert "read_plus_dark_combined" in r["model_terms"] and "dark_current" in r["terms_left_out"]


def test_unsaturated_series_gives_a_lower_bound_for_full_well():
    d = simulate_ptc(TRUTH, seed=5, shape=(80, 80), max_fraction=0.6, n_levels=30)
    r = bayescap.fit(d, seed=1, quality="fast").to_dict()
    fw = r["parameters"]["full_well_e"]
    assert fw["constrained"] is False and fw["median"] is None
    assert 0.5 * TRUTH.clip_charge_e < fw["lower_bound"] < TRUTH.clip_charge_e
    assert r["flags"]["capacity_lower_bound"] and r["derived"]["capacity_bits"]["lower_bound"]
    assert "saturation" in r["terms_left_out"]


@pytest.fixture(scope="module")
def clean_and_corrupted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("corrupt")
    d = simulate_ptc(TRUTH, seed=7, path=tmp / "clean.csv", shape=(100, 100))
    cols = {
        c: np.array(getattr(d, c))
        for c in (
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
    # two bad rows: a lamp flicker (+40 %) and a dropped frame (-40 %) in the bright variance
    bad_idx = [10, 25]
    cols["temporal_var_dn2"][bad_idx] *= [1.4, 0.6]
    write_ptc_csv(cols, tmp / "bad.csv", metadata=d.metadata)
    bad_rows = sorted(int(d.row_numbers[i]) for i in bad_idx)
    return bayescap.fit(tmp / "clean.csv", seed=1), bayescap.fit(tmp / "bad.csv", seed=1), bad_rows


def test_corrupted_rows_named_and_gain_unchanged(clean_and_corrupted):
    clean, bad, bad_rows = clean_and_corrupted
    kc = clean.to_dict()["parameters"]["conversion_gain_e_per_dn"]
    kb = bad.to_dict()["parameters"]["conversion_gain_e_per_dn"]
    assert kc["ci95"][0] < kb["median"] < kc["ci95"][1]
    assert kb["ci95"][0] < TRUTH.conversion_gain_e_per_dn < kb["ci95"][1]
    named = sorted(o["row"] for o in bad.outliers if o["block"] == "bright_var")
    assert named == bad_rows
    assert not clean.outliers
    assert any("outlier rows" in n for n in bad.notes)


def test_scene_hotter_or_longer_means_more_dark_noise(clean_and_corrupted):
    res = clean_and_corrupted[0]
    base = res.at_scene(Scene(exposure_time_s=0.01, temperature_c=25.0, reference_temperature_c=25.0))
    longer = res.at_scene(Scene(exposure_time_s=1.0, temperature_c=25.0, reference_temperature_c=25.0))
    hotter = res.at_scene(Scene(exposure_time_s=1.0, temperature_c=55.0, reference_temperature_c=25.0))
    share = [r.noise_budget()["shares_percent"]["dark_current_shot"] for r in (base, longer, hotter)]
    assert share[0] < share[1] < share[2]
    # 30 °C hotter: dark current × 2^(30/6) = 32
    assert hotter.scene.dark_current_factor == pytest.approx(32.0)
    for name in ("tonal_range_bits", "dynamic_range_db", "capacity_bits"):
        med = [np.median(r.derived[name]) for r in (base, longer, hotter)]
        assert med[0] > med[1] > med[2], name


def test_cli_scene_requires_reference_temperature(tmp_path):
    import subprocess
    import sys

    p = tmp_path / "s.csv"
    simulate_ptc(TRUTH, seed=1, path=p, shape=(40, 40), n_levels=12)
    r = subprocess.run(
        [sys.executable, "-m", "bayescap.cli", "fit", str(p), "--scene", "temperature_c=40"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "temperature_c" in r.stderr and "Traceback" not in r.stderr


def test_model_selection_by_loo_keeps_the_mixture_for_corrupted_rows(tmp_path):
    """PSIS-LOO prefers the outlier mixture when two rows are corrupted and the plain χ²
    likelihood (the simplest variant) when the data are clean simulations."""
    from bayescap.studies.selection import select_model

    d = simulate_ptc(TRUTH, seed=7, shape=(100, 100))
    cols = {
        c: np.array(getattr(d, c))
        for c in (
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
    cols["temporal_var_dn2"][[10, 25]] *= [1.4, 0.6]
    write_ptc_csv(cols, tmp_path / "bad.csv", metadata=d.metadata)
    r_bad, s_bad = select_model(bayescap.load(tmp_path / "bad.csv"), seed=1, quality="fast")
    r_clean, s_clean = select_model(d, seed=1, quality="fast")
    assert s_bad["chosen"] == "discrepancy+outliers"
    assert s_bad["variants"]["gamma_only"]["n_khat_above_0.7"] > 0
    assert s_clean["chosen"] == "gamma_only"
    # every variant says whether its fit converged; a failed one is named in the result's notes
    for s in (s_bad, s_clean):
        assert all(isinstance(v["converged"], bool) for v in s["variants"].values())
        assert s["unconverged_variants"] == [n for n, v in s["variants"].items() if not v["converged"]]
    for r, s in ((r_bad, s_bad), (r_clean, s_clean)):
        named = [n for n in r.notes if n.startswith("model selection: the fit of")]
        assert bool(named) == bool(s["unconverged_variants"])
        assert all(f"'{v}'" in named[0] for v in s["unconverged_variants"])


def test_dark_pixels_clipped_at_zero_are_flagged():
    """A black level too low for the read noise and DSNU: the ADC's zero clips the darkest pixels
    (black 8 DN, dark pixel sd ≈ 5.4 DN: 7 % clipped), which shrinks the dark variances and biases
    read noise and DSNU low; the result names the rows. The same sensor at black 64 DN is not
    flagged."""
    from types import SimpleNamespace

    from bayescap.model.ptc_model import PTCModel
    from bayescap.posterior import FitResult
    from bayescap.simulate import SensorTruth, simulate_ptc

    for black, expect in ((8.0, True), (64.0, False)):
        tr = SensorTruth(
            conversion_gain_e_per_dn=2.0,
            read_noise_e=6.0,
            full_well_e=8000,
            dsnu_e=8.0,
            prnu_frac=0.005,
            adc_bits=12,
            black_level_dn=black,
        )
        d = simulate_ptc(tr, seed=2, n_levels=12, shape=(40, 40), spatial_frames=4, spatial_every=3)
        res = SimpleNamespace(model=PTCModel(d), flags={}, notes=[], DARK_FLOOR_SD=FitResult.DARK_FLOOR_SD)
        FitResult._check_dark_floor(res)
        assert ("dark_floor_clipping" in res.flags) is expect
        if expect:
            # the rows whose spatial column shows the DSNU (3 DN of read noise alone stays clear)
            spatial = [int(d.row_label(i)) for i in np.nonzero(np.isfinite(d.dark_spatial_var_dn2))[0]]
            assert res.flags["dark_floor_clipping"] == spatial
            assert "biased low" in res.notes[0] and "sd above 0 DN" in res.notes[0]


def test_scene_refuses_exposures_and_temperatures_out_of_range():
    """The checks live in Scene, so a Python caller gets them too (the command line turns the
    ValueError into its one-line error)."""
    import math

    for kw in (
        {"exposure_time_s": -1.0},
        {"exposure_time_s": math.nan},
        {"exposure_time_s": 1e308},
        {"exposure_time_s": 1.0, "temperature_c": -300.0, "reference_temperature_c": 25.0},
        {"exposure_time_s": 1.0, "temperature_c": 25.0, "reference_temperature_c": math.inf},
    ):
        with pytest.raises(ValueError, match="scene"):
            Scene(**kw)
    assert Scene(exposure_time_s=0.0).exposure_time_s == 0.0
