"""bayescap.studies.gain_joint: the joint density of a gain series with shared coordinates tied.

The sampler's coverage against the simulated truth is checked by ``benchmarks/gain_joint.py``
(about a minute per series); here the density itself and the sampler's reporting."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bayescap.model.ptc_model import PTCModel
from bayescap.simulate import SensorTruth
from bayescap.studies import gain_joint as J
from bayescap.studies.gain_series import simulate_gain_series

TRUTH = SensorTruth(
    conversion_gain_e_per_dn=2.17,
    read_noise_e=5.56,
    full_well_e=8500.0,
    dark_current_e_per_s=0.44,
    quantum_efficiency=0.40,
    prnu_frac=0.015,
    dsnu_e=3.7,
    full_well_spread_frac=0.005,
    adc_bits=14,
    black_level_dn=64.0,
)
MD = {"pixel_pitch_um": 1.75, "adc_bits": 14, "black_level_dn": 64.0}


@pytest.fixture(scope="module")
def series():
    datas, truths = simulate_gain_series(
        TRUTH,
        [1, 2],
        read_noise_pre_e=3.4,
        read_noise_post_dn=2.0,
        seed=5,
        metadata=MD,
        n_levels=25,
        shape=(80, 80),
        spatial_frames=16,
        spatial_every=6,
    )
    return datas, truths


def test_joint_density_counts_the_shared_prior_once(series):
    """Moving a shared coordinate changes the joint log density by the change of each gain's log
    likelihood plus the change of the shared prior counted once."""
    datas, _ = series
    models = [PTCModel(d) for d in datas]
    jm = J.JointGainModel(models)
    assert jm.shared == list(J.SHARED_COORDS)
    th = [m.initial_guess() for m in models]
    x = jm.join(th, [th[0][models[0].idx[c]] for c in jm.shared])
    jm.ref_shared = x[: len(jm.shared)].copy()
    for m, g, t in zip(models, jm.split(x), th):  # split/join round trip (shared values from gain 1)
        for n in m.names:
            expect = th[0][models[0].idx[n]] if n in jm.shared else t[m.idx[n]]
            assert g[0, m.idx[n]] == expect
    j = jm.shared.index("log_prnu")
    x2 = x.copy()
    x2[j] += 0.05
    d_joint = jm.log_prob(x2)[0] - jm.log_prob(x)[0]
    a, b = jm.split(x), jm.split(x2)
    d_lik = sum(
        (m.log_prob(tb) - m.log_prior(tb)) - (m.log_prob(ta) - m.log_prior(ta)) for m, ta, tb in zip(models, a, b)
    )
    d_prior = models[0].log_prior(b[0]) - models[0].log_prior(a[0])
    assert d_joint == pytest.approx(float(d_lik[0] + d_prior[0]), rel=1e-9, abs=1e-9)


def test_importance_sampler_reports_its_check(series):
    datas, truths = series
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        j = J.fit_gain_series_jointly(datas, [1, 2], seed=0, sampler="is", n_draws=2000)
    assert j.sampler == "is" and j.converged == (j.khat < J.KHAT_MAX)
    assert bool(j.notes) == (not j.converged)
    d = j.to_dict()
    assert d["gains"][0]["analog_gain"] == 1.0 and set(d["shared"]) == {
        "quantum_efficiency",
        "prnu_percent",
        "dark_current_e_per_s",
        "dsnu_e",
    }
    # the shared QE is one set of draws, the same in every gain's physical draws
    np.testing.assert_array_equal(j.draws[0]["quantum_efficiency"], j.draws[1]["quantum_efficiency"])
    if j.converged:
        lo, hi = np.quantile(j.draws[0]["quantum_efficiency"], [0.0005, 0.9995])
        assert lo <= TRUTH.quantum_efficiency <= hi


def test_short_mcmc_is_reported_unconverged(series):
    """60 steps cannot give 50 kept steps per autocorrelation time: the result must say so."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        j = J.fit_gain_series_jointly(series[0], [1, 2], seed=0, sampler="mcmc", n_steps=60, n_draws=500)
    assert j.sampler == "mcmc" and j.mcmc["n_steps"] == 60
    assert not j.converged and any("did not converge" in n for n in j.notes)
    assert j.draws[0]["quantum_efficiency"].size == 40 * j.mcmc["n_walkers"]


def test_bad_sampler(series):
    with pytest.raises(ValueError, match="sampler"):
        J.fit_gain_series_jointly(series[0], [1, 2], sampler="nuts")
