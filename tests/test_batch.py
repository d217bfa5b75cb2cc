"""The batch path vectorised across sensors (issue 7, item 5): PTCModelStack and Lockstep.

The claim under test is exact: a stacked evaluation returns each sensor's own ``log_prob`` bit
for bit, so a batch gives every sensor the result of its own ``bayescap.fit``."""

import warnings

import numpy as np
import pytest

import bayescap
from bayescap.batch import fit_many, gpixel_sensors
from bayescap.inference.lockstep import Lockstep, stack_groups
from bayescap.model import PTCModel, PTCModelStack
from bayescap.simulate import SensorTruth, simulate_ptc


def _stackable_sets():
    """Groups of models that stack: simulated Gpixel ROIs (clip rows, QE), and sensor designs
    with spatial columns (PRNU, DSNU and their latents) at several seeds, 8-bit (ADC clip), and
    12-bit with a dark current both the dark variances and the dark means see (the dark means'
    block)."""
    datas, _ = gpixel_sensors(n_max=24, seed=2)
    sets = [[PTCModel(d) for d in datas]]
    for t in (
        SensorTruth(
            conversion_gain_e_per_dn=2.0, read_noise_e=3.0, full_well_e=8000, prnu_frac=0.01, dsnu_e=2.0, adc_bits=12
        ),
        SensorTruth(
            conversion_gain_e_per_dn=20.0, read_noise_e=1.0, full_well_e=1e5, prnu_frac=0.01, dsnu_e=0.5, adc_bits=8
        ),
        SensorTruth(
            conversion_gain_e_per_dn=1.0,
            read_noise_e=3.0,
            full_well_e=8000,
            dark_current_e_per_s=3000,
            prnu_frac=0.01,
            dsnu_e=2.0,
            adc_bits=12,
        ),
    ):
        sets.append(
            [
                PTCModel(simulate_ptc(t, n_levels=20, shape=(32, 32), seed=s, spatial_frames=4, spatial_every=2))
                for s in range(6)
            ]
        )
    return sets


def _points(m, n, rng):
    x = m.initial_guess() + 0.01 * rng.standard_normal((n, m.ndim))
    x[0, 0] = 50.0  # outside the prior: −inf, filtered before the likelihood
    return x


def test_stacked_log_prob_equals_each_models_own_bit_for_bit():
    rng = np.random.default_rng(3)
    n_groups = 0
    sets = _stackable_sets()
    for ms in sets:
        for ix in (ix for g in stack_groups(ms) for ix in g):
            if len(ix) < 2:
                continue
            n_groups += 1
            group = [ms[i] for i in ix]
            stack = PTCModelStack(group)
            ths = [_points(m, int(rng.integers(8, 40)), rng) for m in group]
            sensor = np.repeat(np.arange(len(group)), [len(t) for t in ths])
            lp = stack.log_prob(np.vstack(ths), sensor)
            solo = np.concatenate([m.log_prob(t) for m, t in zip(group, ths)])
            assert np.array_equal(lp, solo)  # −inf included
            starts = np.r_[0, np.cumsum([len(t) for t in ths])[:-1]]
            assert np.all(np.isneginf(lp[starts]))
            # the comparison covers the likelihood: every sensor has draws inside the support
            assert all(np.isfinite(part).any() for part in np.split(lp, starts[1:]))
    assert n_groups >= 4
    assert any(m.terms.dark_mean for ms in sets for m in ms)  # the dark means' block is covered


def test_a_model_stacked_with_itself_equals_its_own_calls_bit_for_bit():
    """PTCModelStack([m, m, m]) (the MCMC ensembles in lockstep) uses m's own data for every draw
    instead of gathering copies; each request's log p is still m.log_prob of that request alone,
    bit for bit, with requests of different spreads in one call (the rows near the clip are
    chosen per request: the second request's gains are spread far wider)."""
    # the first two of _stackable_sets()'s Gpixel ROIs, without simulating the other sets
    rois = gpixel_sensors(n_max=24, seed=2)[0][:2]
    models = [PTCModel(bayescap.load("data/emva1288_basler_ccd12.csv"))] + [PTCModel(d) for d in rois]
    for i, m in enumerate(models):
        # a generator per model: its points do not depend on the other models' dimensions
        rng = np.random.default_rng(11 + i)
        stack = PTCModelStack([m] * 3)
        assert stack._same
        x0 = m.initial_guess()
        ths = [_points(m, 30, rng), x0 + 0.2 * rng.standard_normal((17, m.ndim)), _points(m, 5, rng)]
        ths[1][:, m.idx["log_k"]] += rng.normal(0.0, 0.5, 17)  # gains far apart: clip rows differ
        sensor = np.repeat(np.arange(3), [len(t) for t in ths])
        lp = stack.log_prob(np.vstack(ths), sensor)
        solo = np.concatenate([m.log_prob(t) for t in ths])
        assert np.array_equal(lp, solo)
        assert all(np.isfinite(part).sum() >= 2 for part in np.split(lp, np.cumsum([len(t) for t in ths])[:-1]))


def test_stack_refuses_models_of_different_structure():
    a = PTCModel(bayescap.load("data/emva1288_basler_ccd12.csv"))
    b = PTCModel(gpixel_sensors(n_max=1, seed=0)[0][0])
    assert PTCModelStack.signature(a) != PTCModelStack.signature(b)
    with pytest.raises(ValueError, match="does not stack"):
        PTCModelStack([a, b])


class _Toy:
    """A stand-in stack: log p = −|x|²/2 per model, with a counter of calls; a point with x₀ = 99
    raises (a model that fails on its input)."""

    def __init__(self, n):
        self.models = [self] * n
        self.calls = 0

    def log_prob(self, theta, sensor=None):
        self.calls += 1
        th = np.atleast_2d(theta)
        if np.any(th[:, 0] == 99):
            raise FloatingPointError("bad point")
        return -0.5 * np.sum(th**2, axis=1)


def test_lockstep_returns_each_fit_its_values_and_isolates_a_failure():
    toy = _Toy(5)
    ls = Lockstep(toy, solo_points=10**9)

    def fit(k):
        def fn(log_prob):
            if k == 3:
                raise RuntimeError("sensor 3 failed")
            return [float(log_prob(np.full((1, 2), k + j))[0]) for j in range(k + 1)]

        return fn

    before = list(warnings.filters)
    out = ls.run([fit(k) for k in range(5)], concurrency=2)
    assert warnings.filters == before  # the caller's filters are restored
    assert isinstance(out[3], RuntimeError)
    for k in (0, 1, 2, 4):
        assert out[k] == [-((k + j) ** 2) for j in range(k + 1)]
    # 2 at a time, each request waits for the other running fit: fewer calls than requests
    assert ls.n_requests == sum(k + 1 for k in (0, 1, 2, 4))
    assert toy.calls == ls.n_calls < ls.n_requests


def test_lockstep_a_failing_request_fails_only_its_fit():
    ls = Lockstep(_Toy(3), solo_points=10**9)
    fns = [lambda lp, x=x: float(lp(np.array([[x, 0.0]]))[0]) for x in (1.0, 99.0, 2.0)]
    out = ls.run(fns)
    assert out[0] == -0.5 and out[2] == -2.0
    assert isinstance(out[1], FloatingPointError)


@pytest.mark.slow
def test_fit_many_gives_each_sensor_its_own_fit():
    """The batch's draws are those of bayescap.fit with the sensor's seed, whatever stack_size
    (and n_jobs: the stacks are shared out among processes)."""
    datas, _ = gpixel_sensors(n_max=6, seed=5)
    seeds = [int(c.generate_state(1)[0]) for c in np.random.SeedSequence(9).spawn(len(datas))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rejected sensors warn NOT CONVERGED
        batch = fit_many(datas, seed=9, fallback=False)
        one_by_one = fit_many(datas, seed=9, fallback=False, stack_size=1)
        two_procs = fit_many(datas, seed=9, fallback=False, n_jobs=2, summary_only=True)
        for d, s, r, r1, r2 in zip(datas, seeds, batch, one_by_one, two_procs):
            own = bayescap.fit(d, seed=s, quality="fast", fallback=False)
            assert np.array_equal(r.chains.chain, own.chains.chain)
            assert np.array_equal(r1.chains.chain, own.chains.chain)
            assert r2["conversion_gain_e_per_dn"] == tuple(
                float(v) for v in np.quantile(own.draws["conversion_gain_e_per_dn"], [0.025, 0.5, 0.975])
            )
            assert r.diag["khat"] == own.diag["khat"]
    groups = [len(ix) for g in stack_groups([PTCModel(d) for d in datas]) for ix in g]
    assert sorted(r.chains.extra["stacked"]["sensors"] for r in batch) == sorted(n for n in groups for _ in range(n))
    assert max(groups) >= 2  # some sensors were evaluated stacked


@pytest.mark.slow
def test_fit_many_fallbacks_shared_out_across_processes_are_each_sensors_own():
    """With n_jobs > 1 the MCMC fallbacks run after every process's fast paths, shared out evenly:
    each is still bayescap.fit's own fallback for that sensor and seed (here every fast path is
    rejected: k̂ must be below −1; two sensors, one fallback per process)."""
    from bayescap.inference import FastSettings

    datas, _ = gpixel_sensors(n_max=2, seed=5)
    seeds = [int(c.generate_state(1)[0]) for c in np.random.SeedSequence(9).spawn(len(datas))]
    fs = FastSettings(khat_max=-1.0, retry_restarts=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit_many(datas, seed=9, n_jobs=2, summary_only=True, settings=fs)
        for d, s, r in zip(datas, seeds, res):
            own = bayescap.fit(d, seed=s, quality="fast", fast_settings=fs)
            assert own.diag["method"] == "emcee" and r["method"] == "emcee" and not r["accepted"]
            assert r["conversion_gain_e_per_dn"] == tuple(
                float(v) for v in np.quantile(own.draws["conversion_gain_e_per_dn"], [0.025, 0.5, 0.975])
            )
            assert r["converged"] == own.diag["converged"]


@pytest.mark.slow
def test_fit_many_mcmc_preset_reports_a_bad_sensor_instead_of_stopping():
    """quality="standard" fits one sensor at a time (MCMC); a refused input is reported in its
    place, as with the fast preset."""
    res = fit_many(
        ["data/simulated/sim_phone_1p75um_10bit.csv", "no_such_file.csv"], quality="standard", seed=1, summary_only=True
    )
    assert res[0]["converged"] and "file not found" in res[1]["error"]


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"n_jobs": 0}, "n_jobs must be a whole number >= 1, got 0"),
        ({"n_jobs": 1.5}, "n_jobs must be a whole number >= 1"),
        ({"stack_size": 0}, "stack_size must be"),
        ({"seed": -1}, "seed must be a whole number >= 0"),
        ({"seed": None}, "seed must be a whole number >= 0"),
        ({"settings": "fast"}, "settings must be a FastSettings"),
    ],
)
def test_fit_many_refuses_bad_arguments_with_an_input_error(kw, match):
    """fit_many(n_jobs=0) and the like are refused up front, as bayescap.fit's arguments are,
    instead of a foreign error from the process pool or numpy (or silence)."""
    from bayescap.exceptions import InputError

    args = {"seed": 1, **kw}
    with pytest.raises(InputError, match=match):
        fit_many(["data/emva1288_basler_ccd12.csv"], **args)
