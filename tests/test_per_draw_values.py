"""The fast path's top-up computes each draw's quantities once (``PerDrawValues``), which is exact
only for functions of each draw alone: checked here for the functions the fit hands it, and the
top-up's result checked bit for bit against computing everything every round."""

from dataclasses import replace

import numpy as np

import bayescap
from bayescap.api import _result_kw, mtf_from_metadata
from bayescap.inference import FastSettings, fast_posterior
from bayescap.inference.end_errors import PerDrawValues
from bayescap.model import PTCModel
from bayescap.physics.optics import TabulatedMTF
from bayescap.posterior import FitResult


class _Counted:
    """A per-draw function that counts the rows it is asked for."""

    per_draw = True

    def __init__(self):
        self.rows = 0

    def __call__(self, x):
        self.rows += x.shape[0]
        return {"s": x[:, 0] + x[:, 1] ** 2, "e": np.exp(0.3 * x[:, 2])}


def test_per_draw_values_computes_each_row_once_and_equals_the_direct_values():
    rng = np.random.default_rng(0)
    fn = _Counted()
    cache = PerDrawValues(fn)
    x = rng.normal(size=(50, 3))
    keep = rng.random(50) < 0.7
    got = cache.rows(x, keep)
    want = fn(x[keep])
    assert all(np.array_equal(got[k], want[k]) for k in want)
    assert list(got) == list(want)
    fn.rows = 0
    x2 = np.vstack([x, rng.normal(size=(30, 3))])  # the same draws followed by new ones
    keep2 = rng.random(80) < 0.7
    got = cache.rows(x2, keep2)
    want = _Counted()(x2[keep2])
    assert all(np.array_equal(got[k], want[k]) for k in want)
    # only the kept rows not computed before
    assert fn.rows == int(np.sum(keep2 & ~np.r_[keep, np.zeros(30, bool)]))
    # other draws (not a continuation): everything again
    fn.rows = 0
    x3 = x2.copy()
    x3[3, 0] += 1.0
    got = cache.rows(x3, keep2)
    assert fn.rows == int(keep2.sum())
    assert np.array_equal(got["s"], _Counted()(x3[keep2])["s"])


def test_per_draw_values_starts_again_when_the_names_change():
    calls = []

    def fn(x):
        calls.append(x.shape[0])
        return {"a": x[:, 0], **({"b": x[:, 1]} if len(calls) > 1 else {})}

    cache = PerDrawValues(fn)
    x = np.arange(20.0).reshape(10, 2)
    cache.rows(x[:6], np.ones(6, bool))
    got = cache.rows(x, np.ones(10, bool))  # the new rows bring a name: all of them again
    assert calls == [6, 4, 10]
    assert np.array_equal(got["a"], x[:, 0]) and np.array_equal(got["b"], x[:, 1])


def _basler_draws(n, seed=0):
    model = PTCModel.for_fit(bayescap.load("data/emva1288_basler_ccd12.csv"))
    x0 = np.asarray(model.initial_guess(), float)
    rng = np.random.default_rng(seed)
    x = x0 + 0.02 * rng.normal(size=(n, x0.size))
    j = model.idx["nl_1"]
    x[:, j : j + 4] = rng.normal(0.0, 0.5, (n, 4))  # a bent response: the linearity error varies
    return model, x


def test_derived_and_physical_values_of_a_draw_do_not_depend_on_the_others():
    """What PerDrawValues relies on: the result's derived quantities (the linearity error's per-draw
    response inverse included) and the physical parameters of some draws are those rows of the
    values of all of them, bit for bit, whatever the draws' positions and block boundaries."""
    model, x = _basler_draws(5000)
    mtf = mtf_from_metadata(model.data.metadata, [])
    fn = FitResult.derived_values_fn(model, **_result_kw(model.data, mtf=mtf, scene=None, seed=1))
    assert fn.per_draw
    full, phys = fn(x), model.physical(x)
    assert "linearity_error_percent" in full and np.ptp(full["linearity_error_percent"]) > 0
    rng = np.random.default_rng(1)
    for sub in (rng.permutation(5000)[:2100], np.arange(1999, 4400), rng.permutation(5000)):
        part, part_phys = fn(x[sub]), model.physical(x[sub])
        assert set(part) == set(full)
        for k in full:
            assert np.array_equal(part[k], full[k][sub]), k
        for k in phys:
            assert np.array_equal(part_phys[k], phys[k][sub]), k


def test_derived_values_with_mtf_draws_are_not_per_draw():
    """An MTF with its own draws is paired with the posterior's at random by position: no caching."""
    model, _ = _basler_draws(1)
    f = np.linspace(0.0, 0.6, 7)
    m = np.clip(1.0 - f, 0.1, 1.0)
    mtf = TabulatedMTF(f, m, samples=m[None, :] * np.array([[0.95], [1.0], [1.05]]).clip(0, 1))
    fn = FitResult.derived_values_fn(model, **_result_kw(model.data, mtf=mtf, scene=None, seed=1))
    assert not fn.per_draw


def test_top_up_with_per_draw_caching_gives_the_same_answer_bit_for_bit():
    """A gate out of reach of the default draws (several top-up rounds): the same draws, weights and
    interval-end errors whether the derived function is cached per draw or computed every round,
    and the cached one is asked for each draw at most once."""
    model, _ = _basler_draws(1)
    model = PTCModel(model.data, terms=replace(model.terms, nonlinearity=False, brighter_fatter=False))

    class Plain:
        rows = 0

        def __call__(self, x):
            type(self).rows += x.shape[0]
            return {"q": np.log(x[:, 0] ** 2 + 1.0) + x[:, 1]}

    class Cached(Plain):
        per_draw = True
        rows = 0

    s = FastSettings(end_mcse_max=0.02, end_confidence=None, max_proposals=14_000)
    ca, da = fast_posterior(model, seed=2, settings=s, derived_fn=Plain())
    cb, db = fast_posterior(model, seed=2, settings=s, derived_fn=Cached())
    assert da["n_topup"] > 0 and "q" in da["end_mcse"]
    assert np.array_equal(ca.chain, cb.chain)
    assert da["end_mcse"] == db["end_mcse"] and da["n_proposals"] == db["n_proposals"]
    assert np.array_equal(ca.extra["weighted_draws"]["w"], cb.extra["weighted_draws"]["w"])
    assert Cached.rows <= db["n_proposals"] * (1 + int(db["retried_with_restarts"])) < Plain.rows


def test_result_derives_each_distinct_draw_once_with_the_same_numbers():
    """A chain whose walkers repeat their draws (rejected moves): the physical parameters and
    derived quantities are computed on the distinct draws and given to the repeats, the same
    numbers bit for bit as computing every draw."""
    model, x = _basler_draws(300)
    rng = np.random.default_rng(2)
    chain = x[np.sort(rng.integers(0, 300, 4 * 50 * 8))].reshape(4, 50, 8, -1)  # ~75 % repeats
    mtf = mtf_from_metadata(model.data.metadata, [])
    kw = _result_kw(model.data, mtf=mtf, scene=None, seed=1)
    seen = []
    physical = model.physical
    model.physical = lambda th, **k: seen.append(len(th)) or physical(th, **k)
    once = FitResult._of_chain(model, chain, **kw)
    every = FitResult._of_chain(model, chain, repeats=False, **kw)
    n_distinct = len(np.unique(chain.reshape(-1, chain.shape[-1]), axis=0))
    assert seen == [n_distinct, chain[..., 0].size] and n_distinct < chain[..., 0].size / 2
    for d1, d2 in ((once.draws, every.draws), (once.derived, every.derived)):
        assert list(d1) == list(d2)
        for k in d2:
            assert np.array_equal(d1[k], d2[k]), k
    assert once.notes == every.notes and once.flags == every.flags


def test_from_chains_takes_over_the_checks_computation_on_the_same_chain(monkeypatch):
    """The MCMC's checks computed the final chain's derived quantities (chain_check_fns): the result
    takes them over instead of computing them again, with the same JSON; a chain that is not the
    last one checked (a copy) is computed afresh."""
    r = bayescap.fit("data/simulated/sim_phone_1p75um_10bit.csv", quality="fast", seed=1)
    kw = dict(metadata=r.metadata, scene=r.scene, mtf=r.mtf, seed=r.seed)
    check_derived, _ = FitResult.chain_check_fns(r.model, **kw)
    assert check_derived.result_of(r.chains.chain) is None
    check_derived(r.chains.chain)
    plain = FitResult.from_chains(r.model, r.chains, quality="fast", **kw).to_dict()
    calls = []
    real = FitResult._derive_draws
    monkeypatch.setattr(FitResult, "_derive_draws", lambda self, *a, **k: calls.append(1) or real(self, *a, **k))
    taken = FitResult.from_chains(r.model, r.chains, quality="fast", checked=check_derived, **kw)
    assert calls == [] and taken.to_dict() == plain
    copy = replace(r.chains, chain=r.chains.chain.copy())
    again = FitResult.from_chains(r.model, copy, quality="fast", checked=check_derived, **kw)
    assert calls == [1] and again.to_dict() == plain
    # the bounds check reads the summaries' physical draws: those of the kept chain, bit for bit
    th = again._kept(copy.chain.reshape(-1, copy.chain.shape[-1]))
    direct, kept = r.model.physical(th), again.summary_draws()
    assert list(direct) == list(kept) and all(np.array_equal(direct[k], kept[k]) for k in kept)
