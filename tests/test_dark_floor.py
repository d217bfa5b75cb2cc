"""Dark rows the ADC's zero clips: the censoring shrinks the dark variances, so read noise and DSNU
measured on them are biased low. A frame-simulated sensor (bayescap.validation.framesim, which clips
at 0 DN like an ADC) with its black level one read-noise sd above zero: the fit flags the rows and
reports read noise and DSNU as lower limits that hold the truths, never as intervals that miss them."""

import warnings

import pytest

import bayescap
from bayescap.posterior.limits import clipped_variance_fraction
from bayescap.validation.zoo import _make, ensure_csv


def test_clipped_variance_fraction_matches_the_censored_normal():
    # Var(max(X, 0)) for X ~ N(m, 1): closed form, checked against values computed by Monte Carlo
    # with 4e6 draws (standard error ~7e-4)
    assert clipped_variance_fraction(2.0) == pytest.approx(0.9596, abs=3e-3)
    assert clipped_variance_fraction(2.5) == pytest.approx(0.9883, abs=3e-3)
    assert clipped_variance_fraction(8.0) == pytest.approx(1.0, abs=1e-12)


def test_floor_clipped_dark_rows_give_lower_limits(tmp_path):
    z = _make("floor_clip", 12, 2.0, 3.0, seed=77, black_dn=3.0, levels=8, roi=48, dsnu_dn=1.0, spatial="some")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = bayescap.fit(str(ensure_csv(z, tmp_path)), seed=1, quality="fast").to_dict()
    assert d["flags"].get("dark_floor_clipping")
    for name, truth in (("read_noise_e", z.sensor.read_noise_e), ("dsnu_e", z.sensor.dsnu_e)):
        p = d["parameters"][name]
        assert p["constrained"] is False and p["limit"]["kind"] == "lower", (name, p)
        assert p["limit"]["value"] < truth, (name, p["limit"], truth)
        assert "clips the darkest pixels" in p["note"]
    # K comes from the bright rows' shot noise: still a measurement
    assert d["parameters"]["conversion_gain_e_per_dn"]["constrained"] is True
