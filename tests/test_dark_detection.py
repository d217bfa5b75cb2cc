"""Issue 51: a dark current the data cannot see is printed as an upper limit, never as a detection.

The detection rule (:mod:`bayescap.posterior.dark_current`) is checked on draws with a known
likelihood, its two data witnesses on frame-simulated dark ramps (:mod:`bayescap.validation.framesim`,
independent of the model), and end to end on the issue's 8-bit sensor (K 100 e⁻/DN, read 5 e⁻, DSNU,
D·t ≤ 0.1 e⁻ against a read variance of 25 e⁻²), whose fit the old rule (2.5 % point above a fifth of
the median) printed as a detection on the seed used here."""

import warnings

import numpy as np

import bayescap
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
