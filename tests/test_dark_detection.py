"""Issue 51: a dark current the data cannot see is printed as an upper limit, never as a detection.

The detection rule (:mod:`bayescap.posterior.dark_current`) is checked on draws with a known
likelihood, its two data witnesses on frame-simulated dark ramps (:mod:`bayescap.validation.framesim`,
independent of the model), and end to end on the issue's 8-bit sensor (K 100 e⁻/DN, read 5 e⁻, DSNU,
D·t ≤ 0.1 e⁻ against a read variance of 25 e⁻²), whose fit the old rule (2.5 % point above a fifth of
the median) printed as a detection on the seed used here."""

import dataclasses
import warnings

import numpy as np

import bayescap
from bayescap.model import PTCModel
from bayescap.model.dark_ramp import dark_mean_line, select_dark_mean
from bayescap.model.terms import select_terms
from bayescap.posterior.dark_current import (
    RAMP_Z,
    ZERO_LIKELIHOOD_RATIO,
    mean_ramp,
    zero_likelihood_ratio,
)
from bayescap.validation.framesim import simulate_rows, write_csv
from bayescap.validation.zoo import _make, ensure_csv
from bayescap.validation.zoo_dark import score_dark


def _normal_draws(mu, sd=1.0, n=4000, seed=0):
    x = np.random.default_rng(seed).normal(mu, sd, 4 * n)
    return x[x > 0][:n]


def test_zero_likelihood_ratio_of_known_posteriors():
    # flat on [0, 1]: the likelihood at 0 is its maximum (the kernel estimate's noise at 4000 draws
    # and ~0.06 bandwidth is ~10 %)
    flat = np.random.default_rng(1).uniform(0, 1, 4000)
    assert zero_likelihood_ratio(flat) > 0.7
    # normal 1 sd above zero: L(0)/L̂ = exp(-1/2) = 0.61, far above the threshold
    assert zero_likelihood_ratio(_normal_draws(1.0)) > 2 * ZERO_LIKELIHOOD_RATIO
    # 4 sd: exp(-8) = 3e-4 (the boundary kernel's upward bias is ~2·f'(0)·h/√(2π), a factor ~1.5)
    assert zero_likelihood_ratio(_normal_draws(4.0)) < ZERO_LIKELIHOOD_RATIO / 10


def test_zero_likelihood_ratio_divides_out_the_prior():
    # a half-normal prior of scale 1 times a likelihood N(2, 1): the posterior is N(1, 1/2) on x > 0,
    # whose density at 0 is exp(-1) = 0.37 of its peak, the likelihood's exp(-2) = 0.135 (the boundary
    # kernel's upward bias, 2·f'(0)·h/(f(0)·√(2π)) with h ≈ 0.1, is ~16 %)
    post = _normal_draws(1.0, np.sqrt(0.5), seed=3)
    assert zero_likelihood_ratio(post) > 0.3
    assert 0.08 < zero_likelihood_ratio(post, prior_scale=1.0) < 0.25


def _load(zs, tmp_path):
    path = tmp_path / "s.csv"
    write_csv(path, simulate_rows(zs.sensor, zs.acq, zs.seed), zs.metadata())
    return bayescap.load(str(path))


def test_dark_means_witness_the_dark_current(tmp_path):
    # 12-bit, K 2 e-/DN, read 4 e-, D 2000 e-/s up to 20 ms: the dark means rise by D·t/K = 20 DN,
    # each row's mean over 2·48² pixel values known to √(4 DN²/4608) = 0.03 DN
    zs = _make("ramp", 12, 2.0, 2.0, seed=5, dark=2000.0, t_max=0.02, levels=12, roi=48, spatial="none")
    d_dn, sd_dn = mean_ramp(_load(zs, tmp_path))
    assert abs(d_dn * 2.0 - 2000.0) < 3.5 * sd_dn * 2.0


def test_dark_means_witness_stands_down_below_the_rounding(tmp_path):
    # 8-bit, K 100, read 0.3 DN, no DSNU: the rounded means follow a shift by a gain that swings with
    # where they fall within a DN (0.44-1.14 on the zoo_dark family's such sensors): no witness
    zs = _make("still", 8, 100.0, 0.3, seed=6, dark=10.0, t_max=0.01, levels=12, roi=32, spatial="none")
    assert mean_ramp(_load(zs, tmp_path)) is None


def _fit(zs, tmp_path_factory):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = ensure_csv(zs, tmp_path_factory.mktemp(zs.name))
        return bayescap.fit(str(path), seed=1, quality="fast").to_dict()


def test_invisible_dark_current_is_an_upper_limit_holding_the_truth(tmp_path_factory):
    """Issue 51's truncating 8-bit sensor (K 100 e-/DN, read 5 e-, DSNU 30 e-, D 10 e-/s up to 10 ms)
    on the seed whose dark variances happen to rise by 2.4 sd: the old rule printed 193 [59, 339] e-/s,
    a detection excluding the truth."""
    zs = _make("i51_8bit_floor", 8, 100, 0.05, seed=3, dsnu_dn=0.3, dark=10, t_max=0.01, levels=40, adc="floor")
    d = _fit(zs, tmp_path_factory)
    p = d["parameters"]["dark_current_e_per_s"]
    assert p["constrained"] is False and p["limit"]["kind"] == "upper", p
    assert p["limit"]["value"] >= zs.sensor.dark_current_e_per_s
    assert "not a detection" in p["note"]
    assert p["detection"]["ramp_z"] < RAMP_Z
    assert score_dark(zs, d)["verdict"] == "ok"


def test_one_frame_spatial_dark_ramp_holds_the_truth(tmp_path_factory):
    """Issue 51's 12-bit sensor with a one-frame spatial variance (n_frames = 1), read 4 e-, D 20 e-/s
    up to 20 ms (D·t ≤ 0.4 e-), on a seed whose posterior sits low (median ~11 e-/s): printed as an
    upper limit above the truth, not as an interval below it."""
    zs = _make("i51_12bit_nf1", 12, 2.0, 2.0, seed=20, dark=20, t_max=0.02, n_frames=1, spatial="all")
    d = _fit(zs, tmp_path_factory)
    rec = score_dark(zs, d)
    assert rec["verdict"] == "ok", rec
    p = d["parameters"]["dark_current_e_per_s"]
    # the dark means see this dark current (D·t/K = 0.2 DN against a 0.014 DN error per row)
    assert abs(p["detection"]["mean_ramp_e_per_s"] - 20.0) < 3.5 * p["detection"]["mean_ramp_sd_e_per_s"]


def _ramp_sensor():
    # 12-bit, K 1 e-/DN, read 3 e-, D 600 e-/s up to 10 ms: D·t_max = 6 e- against 9 e-² of read
    # variance; the dark variances see it (~6 DN² over 9), the dark means far better (6 DN, each row
    # known to √(9/(2·48²)) = 0.04 DN)
    return _make("both_witnesses", 12, 1.0, 3.0, seed=11, dark=600.0, t_max=0.01, levels=16, roi=48, spatial="none")


def test_dark_means_enter_the_likelihood_where_both_witnesses_agree(tmp_path):
    zs = _ramp_sensor()
    path = tmp_path / "s.csv"
    write_csv(path, simulate_rows(zs.sensor, zs.acq, zs.seed), zs.metadata())
    data = bayescap.load(str(path))
    use, why = select_dark_mean(data)
    assert use, why
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        both = bayescap.fit(str(path), seed=1, quality="fast")
        alone = bayescap.fit(
            PTCModel(data, terms=dataclasses.replace(select_terms(data), dark_mean=False)), seed=1, quality="fast"
        )
    assert both.model.terms.dark_mean and not alone.model.terms.dark_mean
    d_both = both.summary_draws()["dark_current_e_per_s"]
    d_alone = alone.summary_draws()["dark_current_e_per_s"]
    lo, hi = np.quantile(d_both, [0.025, 0.975])
    assert lo < 600.0 < hi
    # the means' slope is known to ~1 %, the variances' to ~10 %: the joint D/K is the means' (its
    # spread the slope's standard error times the line's Birge ratio), D's spread adds K's
    assert np.std(d_both) < 0.3 * np.std(d_alone)
    ratio = d_both / both.summary_draws()["conversion_gain_e_per_dn"]
    line = dark_mean_line(data)
    se = mean_ramp(data)[1] * line.birge
    # a product of two normal witnesses: the variances' pull the means' slope by their precision share
    alone_ratio = d_alone / alone.summary_draws()["conversion_gain_e_per_dn"]
    w = se**2 / (se**2 + np.var(alone_ratio))
    expected = mean_ramp(data)[0] + w * (np.median(alone_ratio) - mean_ramp(data)[0])
    assert abs(np.median(ratio) - expected) < 0.15 * se  # the draws' own error is ~0.05 se
    assert abs(np.std(ratio) / se - 1.0) < 0.1


def _with_dark_means(data, means):
    return dataclasses.replace(data, dark_mean_dn=np.asarray(means, float))


def test_a_clamped_or_drifting_black_level_keeps_the_means_out(tmp_path):
    zs = _ramp_sensor()
    path = tmp_path / "s.csv"
    write_csv(path, simulate_rows(zs.sensor, zs.acq, zs.seed), zs.metadata())
    data = bayescap.load(str(path))
    t = data.exposure_time_s
    noise = data.dark_mean_dn - np.polyval(np.polyfit(t, data.dark_mean_dn, 1), t)
    # clamped: the means stay at the black level while the variances rise
    use, why = select_dark_mean(_with_dark_means(data, data.dark_mean_dn[0] + noise))
    assert not use and "clamped" in why
    # drifting: the means rise three times faster than the charge does
    slope = mean_ramp(data)[0]
    use, why = select_dark_mean(_with_dark_means(data, data.dark_mean_dn + 2.0 * slope * t))
    assert not use and "drifting" in why
    terms = select_terms(_with_dark_means(data, data.dark_mean_dn[0] + noise))
    assert not terms.dark_mean and "clamped" in terms.reasons["dark_mean"]


def test_dark_means_stay_out_without_the_variances_witness(tmp_path):
    # the dark current of test_invisible_dark_current_is_an_upper_limit_holding_the_truth's kind, seen
    # by the means only: a drifting black level could not be told from it
    zs = _make("means_only", 12, 2.0, 2.0, seed=20, dark=20, t_max=0.02, n_frames=1, spatial="all")
    data = _load(zs, tmp_path)
    assert mean_ramp(data) is not None
    assert select_dark_mean(data) == (False, None)
