"""Posterior sampling of the noise model: MAP start, several independent emcee ensembles,
rank-normalised R-hat and bulk/tail ESS from ArviZ.

Why several ensembles: the walkers of one affine-invariant ensemble are not independent chains,
so R-hat across them means little. We run ``n_ensembles`` independently seeded ensembles,
each started from its own draw around the optimum, and compute R-hat and ESS with one chain per
ensemble (Vehtari et al. 2021; :func:`bayescap.inference.diagnostics.by_ensemble`, the layout
of ``posterior.nc``: ``benchmarks/ess_check.py`` measured that this ESS predicts the spread of
posterior quantiles across seeds, and that of the means to 6–12 %, where one chain per walker
understated the ESS by 25–35 %). The diagnostics are checked
on every parameter and on the capacity (see :mod:`bayescap.posterior`).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import time

import numpy as np

from bayescap._blas import one_blas_thread
from bayescap._progress import bar
from bayescap.inference.chains import ChainResult, stuck_walkers
from bayescap.inference.coordinates import mcmc_start
from bayescap.inference.curvature import _proposal_cov
from bayescap.inference.diagnostics import (
    fast_diagnostics,
    integrated_time,
    interval_end_mcse_mcmc,
    worst_end,
)
from bayescap.inference.presets import FastSettings, SamplerSettings
from bayescap.inference.rounds import _next_round_steps
from bayescap.model import PTCModel
from bayescap.model.threads import _allowed

__all__ = ["run_ensembles"]


def _moves(settings: SamplerSettings, x_map=None, cov=None, fraction=None):
    import emcee

    from bayescap.inference.moves import IndependenceMove

    de = settings.de_fraction
    ind = (settings.independence_fraction if fraction is None else fraction) if x_map is not None else 0.0
    out = []
    if ind > 0:
        out.append((IndependenceMove(x_map, cov, nu=settings.independence_nu, scale=settings.independence_scale), ind))
    rest = 1.0 - ind
    if rest <= 0:
        return out
    if de >= 1:
        out.append((emcee.moves.DEMove(), rest))
    else:
        out += [(emcee.moves.DEMove(), rest * de), (emcee.moves.StretchMove(), rest * (1.0 - de))]
    return out


def _importance_start(model, x_map, cov, seed, coords=None, n_proposals=6000):
    """Distinct approximate posterior draws to start the walkers from, and their mean and
    covariance for the IndependenceMove's first proposal: the fast path's Laplace–IS
    (:func:`bayescap.inference.fast.fast_posterior` at this MAP and covariance, default :class:`FastSettings`:
    6 000 importance draws in two ``log_prob`` calls) resampled. Closer to the posterior than the
    Laplace ball where the posterior is skewed; it does not remove the slow filling of the Basler dark
    current's lower tail, which is why the standard burn-in is not cut below 80
    steps (of 10·D walkers).
    The draws reach the long one-sided tails the fast path's probe finds (fewer extra rounds), but
    not the clip floor's pair with a tail (``floor_pair=False``): walkers started in that corner
    need more steps (docs/performance.md, "The fast preset", for the tail probe).
    With ``coords`` (:class:`SamplerCoordinates`), ``x_map`` and ``cov`` are in those
    coordinates and the draws come back in the model's. None when the IS check rejects the draws
    (then: the Laplace ball)."""
    from bayescap.inference.fast import fast_posterior

    target = model if coords is None else coords
    # no gate on the interval ends' Monte Carlo error (the fast preset's default has one): these
    # draws only start the walkers, and a top-up or a rejection would change them
    chains, diag = fast_posterior(
        target,
        seed=seed,
        x_map=x_map,
        cov=cov,
        settings=FastSettings(n_draws=4000, floor_pair=False, n_proposals=n_proposals, end_mcse_max=None),
    )
    if not diag["accepted"]:
        return None
    x = chains.chain.reshape(-1, model.ndim)
    if coords is not None:
        x = coords.to_x(x)
    draws = np.unique(x, axis=0)
    if draws.shape[0] < 4 * model.ndim:
        return None
    return draws, x.mean(axis=0), np.cov(x.T)


def _initial_ball(model, x_map, cov, n_walkers, rng):
    """Walkers drawn from the Laplace approximation, kept inside the prior support."""
    L = np.linalg.cholesky(cov + 1e-12 * np.eye(cov.shape[0]))
    out = np.empty((n_walkers, x_map.size))
    filled = 0
    for _ in range(50):
        z = x_map + rng.standard_normal((n_walkers, x_map.size)) @ L.T
        ok = np.isfinite(model.log_prob(z))
        take = min(ok.sum(), n_walkers - filled)
        out[filled : filled + take] = z[ok][:take]
        filled += take
        if filled == n_walkers:
            return out
        L = 0.5 * L
    raise RuntimeError("could not place walkers inside the prior support around the optimum")


_WORKER_MODEL = None  # the model, inherited by forked workers (copy-on-write)


def _sampler(model, nw, settings, proposal):
    from bayescap.inference.moves import _Sampler

    return _Sampler(nw, model.ndim, model.log_prob, vectorize=True, moves=_moves(settings, *proposal))


#: IndependenceMove acceptance at or above which it keeps its full share of the steps
INDEPENDENCE_ACCEPT_REF = 0.25


def _adapted_proposal(sampler, ndim, proposal, settings):
    """The IndependenceMove's proposal for what follows a burn-in stretch: (mean, covariance of the
    stretch's draws (walkers not stranded), share of the steps). The share is
    ``independence_fraction · min(1, a / INDEPENDENCE_ACCEPT_REF)`` with ``a`` the move's acceptance in
    the stretch, so that where the t fits the posterior badly (a ridge, several modes: acceptance
    ≈ 0) the DE/stretch moves get the steps back. The previous mean and covariance are kept when
    the new ones are not usable."""
    from bayescap.inference.moves import IndependenceMove

    mean, cov = proposal[0], proposal[1]
    frac = proposal[2] if len(proposal) > 2 else settings.independence_fraction
    mv = [m for m in sampler._moves if isinstance(m, IndependenceMove)]
    if mv and mv[0].n_proposed:
        a = mv[0].n_accepted / mv[0].n_proposed
        frac = settings.independence_fraction * min(1.0, a / INDEPENDENCE_ACCEPT_REF)
    chain, lp = sampler.get_chain(), sampler.get_log_prob()
    keep = ~stuck_walkers(lp, ndim)
    x = chain[:, keep].reshape(-1, ndim)
    if x.shape[0] >= 4 * ndim:
        mu, c = x.mean(axis=0), np.cov(x.T)
        if np.all(np.isfinite(mu)) and np.all(np.isfinite(c)):
            try:
                np.linalg.cholesky(_proposal_cov(c, 1.0))
                mean, cov = mu, c
            except np.linalg.LinAlgError:
                pass
    return mean, cov, frac


def _run_segments(tasks):
    """:func:`_run_segment` for several ensembles in this process, in lockstep: each ensemble runs
    in a greenlet (:class:`bayescap.inference.lockstep.Lockstep`), and their ``log_prob`` requests (half an
    ensemble's walkers each, for the DE/stretch moves) are evaluated in one
    :class:`~bayescap.model.PTCModelStack` call of the model with itself. A call on a few walkers
    costs mostly per-call overhead (~0.6 ms), so two ensembles in one call cost little more than one.
    The stack returns the model's own ``log_prob`` bit for bit (per request), so the chains are
    the same as one ensemble after the other."""
    from bayescap.inference.lockstep import Lockstep, _with_log_prob
    from bayescap.model import PTCModelStack

    model = _WORKER_MODEL
    if len(tasks) < 2 or type(model) is not PTCModel:
        return [_run_segment(t) for t in tasks]
    ls = Lockstep(PTCModelStack([model] * len(tasks)))
    fns = [(lambda lp, t=t: _run_segment(t, _with_log_prob(model, lp))) for t in tasks]
    out = ls.run(fns, ignore_warnings=False)
    for r in out:
        if isinstance(r, BaseException):
            raise r
    return out


def _run_segment(task, model=None):
    """Run one ensemble for (optional burn-in +) ``n_steps`` from a given state.

    Self-contained so it can run in a forked worker; the ensemble's random stream travels in
    the state, so results do not depend on which process runs which ensemble.

    With ``settings.independence_fraction > 0`` the IndependenceMove proposes from a t at
    ``task[7]`` = (mean, cov[, share]) (the Laplace start); after each half of the burn-in the t is
    refitted to that half's draws and its share of the steps to its acceptance there
    (:func:`_adapted_proposal`; burn-in only: in production the moves are fixed, so production is a
    valid Markov chain), and the final proposal is returned for the next round."""
    import emcee

    idx, coords, log_prob, rstate, n_burn, n_steps, settings = task[:7]
    proposal = task[7] if len(task) > 7 else (None, None)
    model = _WORKER_MODEL if model is None else model
    nw = coords.shape[0]
    adapt = settings.independence_fraction > 0 and proposal[0] is not None
    s = _sampler(model, nw, settings, proposal)
    state = emcee.State(coords, log_prob=log_prob, random_state=rstate)
    n_reset = 0
    if n_burn:
        # two halves, each ending with the stranded-walker check: walkers moved at the middle get
        # half a burn-in to settle, and stragglers are caught at the end
        for steps in (n_burn // 2, n_burn - n_burn // 2):
            if steps:
                state = s.run_mcmc(state, steps, progress=False, skip_initial_state_check=True)
                if adapt:
                    proposal = _adapted_proposal(s, model.ndim, proposal, settings)
                state, n = _reset_stuck_walkers(s, state, model.ndim)
                n_reset += n
                s = _sampler(model, nw, settings, proposal) if adapt else s
                s.reset()
    # emcee's initial-state check (centred, column-scaled condition number <= 1e8) rejects a posterior
    # whose parameters are nearly collinear (gain x clip level pins the full well: condition ~1e11),
    # which the walkers, drawn from a full-rank Laplace covariance, rightly reproduce
    state = s.run_mcmc(state, n_steps, progress=False, skip_initial_state_check=True)
    accepted = s.acceptance_fraction * n_steps
    return (
        idx,
        s.get_chain(),
        s.get_log_prob(),
        state.coords,
        state.log_prob,
        state.random_state,
        accepted,
        n_reset,
        proposal,
    )


def _reset_stuck_walkers(sampler, state, ndim):
    """After burn-in, move walkers stuck far below the mode onto positions that the other walkers
    visited in the second half of burn-in.

    Affine-invariant ensembles can strand a few walkers in a region of negligible posterior mass
    (measured: 13 of 160 walkers 140–265 nats below the mode on a simulated 1.75 µm sensor, which
    alone set the quantum efficiency's lower 95 % bound); the stretch and DE moves, built from
    differences between walkers, rarely bring them back. Done during burn-in only, so the
    production chain stays a valid Markov chain; the ensemble's own random stream picks the
    positions, so the result stays reproducible."""
    import emcee

    lp_b = sampler.get_log_prob()
    half = lp_b.shape[0] // 2
    stuck = stuck_walkers(lp_b[half:], ndim)
    if not np.any(stuck):
        return state, 0
    good = np.nonzero(~stuck)[0]
    chain_b = sampler.get_chain()[half:]
    rs = np.random.RandomState()
    rs.set_state(state.random_state)
    n = int(stuck.sum())
    ti = rs.randint(0, chain_b.shape[0], size=n)
    wi = good[rs.randint(0, good.size, size=n)]
    coords = np.array(state.coords, copy=True)
    lp = np.array(state.log_prob, copy=True)
    coords[stuck] = chain_b[ti, wi]
    lp[stuck] = lp_b[half:][ti, wi]
    return emcee.State(coords, log_prob=lp, random_state=rs.get_state()), n


def _default_jobs(n_ensembles):
    """Processes for the ensembles (:func:`bayescap.model.threads._allowed`, ``BAYESCAP_JOBS``): one per
    core, at most one per ensemble; 1 in a multiprocessing worker, where the ensembles run in lockstep (a
    pool of its own per batch worker's MCMC fallback would oversubscribe the cores and fork per
    fallback)."""
    return _allowed("BAYESCAP_JOBS", lambda: max(1, min(n_ensembles, os.cpu_count() or 1)))


class _Workers:
    """A fork pool and its number of processes (``multiprocessing.Pool`` keeps that private)."""

    def __init__(self, n_processes: int):
        self.n_processes = int(n_processes)
        self._pool = mp.get_context("fork").Pool(self.n_processes)

    def imap_unordered(self, fn, items):
        return self._pool.imap_unordered(fn, items)

    def map(self, fn, items):
        return self._pool.map(fn, items)

    def close(self):
        self._pool.terminate()
        self._pool.join()


def _pool(n_jobs, n_tasks):
    """A fork pool (:class:`_Workers`) kept for every round of one fit (None: run in this process)."""
    if n_jobs > 1 and n_tasks > 1 and "fork" in mp.get_all_start_methods():
        return _Workers(min(n_jobs, n_tasks))
    return None


def _map_segments(tasks, pool, pbar=None):
    """Results of every task, in task order. The tasks are shared out among the pool's processes
    (or this one), and each share runs in lockstep (:func:`_run_segments`)."""
    n_proc = 1 if pool is None else max(1, min(pool.n_processes, len(tasks)))
    shares = [tasks[w::n_proc] for w in range(n_proc)]
    out = []
    runs = pool.imap_unordered(_run_segments, shares) if pool is not None else map(_run_segments, shares)
    for part in runs:
        out.extend(part)
        if pbar is not None:
            done = {r[0] for r in part}
            pbar.update(sum(t[4] + t[5] for t in tasks if t[0] in done))
    return sorted(out, key=lambda r: r[0])


@one_blas_thread
def run_ensembles(
    model: PTCModel,
    *,
    settings: SamplerSettings = SamplerSettings(),
    seed=None,
    progress: bool = False,
    converged_fn=None,
    n_jobs: int | None = None,
    derived_fn=None,
    reported_fn=None,
) -> ChainResult:
    """Run ``settings.n_ensembles`` independently seeded emcee ensembles.

    Each ensemble: walkers drawn from the Laplace approximation at the MAP, a burn-in, then
    production rounds (``n_steps``, then ``extend_steps`` each); after each round the ensembles are checked together by
    ``converged_fn(chain)`` (default: R-hat/ESS of the parameters and of the quantities
    ``derived_fn(chain)`` returns, e.g. capacity; and length ≥ tau_factor·τ; then, with
    ``reported_fn(chain)`` (every quantity the result gives an interval for), the Monte Carlo
    error of the 95 % interval ends against ``settings.end_mcse_target``, or its goal
    ``settings.end_mcse_goal``)
    and extended while it fails, up to ``max_rounds``. The ensembles run in ``n_jobs`` forked
    processes (default: one per core, at most one per ensemble; ``BAYESCAP_JOBS`` overrides);
    the numbers do not depend on ``n_jobs``.
    """
    global _WORKER_MODEL
    # emcee, imported here and not with the package: before the workers are forked, so that they
    # inherit it instead of each importing it again (~0.75 s), and before the fit's clock starts
    import bayescap.inference.moves  # noqa: F401

    t0 = time.perf_counter()
    with bar(progress, total=1, desc="start: optimiser", unit="step") as start_bar:
        x_map, lp_map, cov, coords, z_map, cov_z = mcmc_start(model, n_restarts=settings.map_restarts)
        start_bar.update(1)
    ss = np.random.SeedSequence(seed)
    children = ss.spawn(settings.n_ensembles)
    nw = max(settings.min_walkers, settings.walkers_per_dim * model.ndim)
    nw += nw % 2
    n_jobs = _default_jobs(settings.n_ensembles) if n_jobs is None else max(1, int(n_jobs))
    is_start = None
    proposal = (x_map, cov)
    if settings.independence_fraction > 0 and settings.importance_start:
        is_seed = int(ss.spawn(1)[0].generate_state(1)[0])
        n_is = settings.start_proposals
        is_start = (
            _importance_start(model, x_map, cov, is_seed, n_proposals=n_is)
            if coords is None
            else _importance_start(model, z_map, cov_z, is_seed, coords=coords, n_proposals=n_is)
        )
        if is_start is not None and is_start[0].shape[0] < nw:
            is_start = None  # too few distinct draws to start every walker at its own: the Laplace ball
        if is_start is not None:
            proposal = (is_start[1], is_start[2])
    n_burn = settings.n_burn
    if is_start is not None and settings.n_burn_is_start is not None:
        n_burn = settings.n_burn_is_start
    # one bar a round, each with its own fixed total (ensembles × steps), so none ever goes back
    pbar = bar(
        progress,
        total=settings.n_ensembles * (n_burn + settings.n_steps),
        desc="sampling, round 1",
        unit="step",
    )
    tasks = []
    for i, child in enumerate(children):
        rng = np.random.default_rng(child)
        if is_start is not None:
            draws = is_start[0]
            p0 = draws[rng.choice(draws.shape[0], size=nw, replace=False)]
        else:
            p0 = _initial_ball(model, x_map, cov, nw, rng)
        rstate = np.random.RandomState(child.generate_state(1)[0]).get_state()
        tasks.append((i, p0, None, rstate, n_burn, settings.n_steps, settings, proposal))
    _WORKER_MODEL = model
    pool = _pool(n_jobs, len(tasks))  # forked after _WORKER_MODEL is set: the workers inherit it
    try:
        chunks = [[] for _ in children]
        lps = [[] for _ in children]
        accepted = np.zeros(len(children))
        walkers_reset = np.zeros(len(children), int)
        n_prod = 0
        rounds = 0
        discard = 0  # production steps moved to the burn-in after a drift (below)
        drift = []
        chase = ("", 0)  # the check that failed the last rounds, and in how many in a row (_next_round_steps)
        while True:
            rounds += 1
            results = _map_segments(tasks, pool, pbar)
            n_prod += tasks[0][5]
            tasks = []
            for idx, ch, lp, coords, lpf, rstate, acc, n_reset, prop in results:
                walkers_reset[idx] += n_reset
                chunks[idx].append(ch)
                lps[idx].append(lp)
                accepted[idx] += acc.mean()
                tasks.append((idx, coords, lpf, rstate, 0, 0, settings, prop))
            chain = np.stack([np.concatenate(c, axis=0) for c in chunks])[:, discard:]  # (E, S, W, D)
            cache = {}
            ok = (
                converged_fn(chain, settings)
                if converged_fn is not None
                else _default_converged(chain, settings, cache, derived_fn, pool, reported_fn)
            )
            if ok or rounds >= settings.max_rounds:
                break
            n_done = chain.shape[1]
            sf = cache.get("_shortfall")
            if sf is not None and sf[0] == "ess" and not sf[2] < settings.rhat_target and chain.shape[1] >= 40:
                # R-hat failed. Its halves are split in time (diagnostics.draw_order), so this is most
                # often a drift that every ensemble shares: a burn-in transient slower than n_burn
                # (a clip spread τ can relax over 300-400 steps). The first half of the
                # production so far becomes burn-in; the checks then run on what follows.
                cut = (chain.shape[1] // 2) & ~1
                discard += cut
                names = getattr(model, "names", None)
                q = names[sf[3]] if names is not None and isinstance(sf[3], (int, np.integer)) else str(sf[3])
                drift.append({"round": rounds, "quantity": q, "rhat": float(sf[2]), "steps_discarded": cut})
                n_done -= cut
                cache = {}
            kind = (cache.get("_shortfall") or ("",))[0]
            chase = (kind, chase[1] + 1 if kind == chase[0] else 1)
            n_next = _next_round_steps(n_done, settings, cache, chase[1] if kind in ("tau", "ess") else 0)
            if drift and drift[-1]["round"] == rounds:
                # at least the steps just discarded: the chain checked next is no shorter than this
                # one (with extend_steps alone, repeated cuts on a slow sensor, τ 20-30 steps,
                # kept it at a few τ until max_rounds)
                n_next = max(n_next, drift[-1]["steps_discarded"] + (drift[-1]["steps_discarded"] % 2))
            tasks = [t[:5] + (n_next,) + t[6:] for t in tasks]
            pbar.close()
            pbar = bar(progress, total=settings.n_ensembles * n_next, desc=f"sampling, round {rounds + 1}", unit="step")
    finally:
        _WORKER_MODEL = None
        if pool is not None:
            pool.close()
        pbar.close()
    lp = np.stack([np.concatenate(c, axis=0) for c in lps])[:, discard:]
    acc = accepted / n_prod
    end_mcse = cache.pop("end_mcse", None)  # of the final chain: the last check's
    tau = cache.pop("_tau", None)  # the same: ~13 ms for a standard fit's chain
    if tau is None:
        tau = integrated_time(chain)
    return ChainResult(
        chain=chain,
        log_prob=lp,
        acceptance=acc,
        tau=tau,
        x_map=x_map,
        lp_map=lp_map,
        settings=settings,
        wall_s=time.perf_counter() - t0,
        n_rounds=rounds,
        extra={
            "n_jobs": n_jobs,
            "n_burn": int(n_burn),  # burn-in steps run (n_burn_is_start after an accepted IS start)
            "importance_start": is_start is not None,
            "walkers_reset": [int(v) for v in walkers_reset],
            # production steps discarded as burn-in after a time-split R-hat failure
            "burn_in_extended": int(discard),
            "drift": drift,
            # diagnostics of the final chain's parameters, when all were computed
            "param_diagnostics": cache if ok and converged_fn is None else None,
            # {quantity: Monte Carlo error of its 95 % interval ends / width}
            "end_mcse": end_mcse,
        },
    )


def _end_mcse_share(xs):
    """:func:`interval_end_mcse_mcmc` of each (E, S, W) array of ``xs`` (a pool worker's share)."""
    return [interval_end_mcse_mcmc(x) for x in xs]


def _diagnostics_share(xs):
    """:func:`fast_diagnostics` of each (E, S, W) array of ``xs`` (a pool worker's share)."""
    return [fast_diagnostics(x) for x in xs]


def _default_converged(chain, settings, cache=None, derived_fn=None, pool=None, reported_fn=None):
    """R-hat/ESS of every parameter (then of the derived quantities ``derived_fn(chain)``
    returns, ``{name: (E, S, W) draws}``) and length ≥ tau_factor·τ; the first failure, in that
    order, decides. ``cache`` (a dict) receives the diagnostics up to it (keys: parameter index,
    derived name), so that :class:`bayescap.posterior.FitResult` need not recompute them for the
    final chain. When those pass and ``reported_fn`` is given: the Monte Carlo error of the 95 %
    interval ends of every quantity ``reported_fn(chain)`` returns (:func:`interval_end_mcse_mcmc`,
    in ``cache["end_mcse"]``), checked against ``settings.end_mcse_target`` when it is set, else
    against the goal ``settings.end_mcse_goal`` (its failure extends the run; it is no check of the
    result: :class:`~bayescap.posterior.FitResult` flags the ends instead).

    Without ``pool`` the quantities are checked one after the other, stopping at the first
    failure. With the ensembles' ``pool`` (idle between rounds) every parameter is diagnosed, shared
    out among its processes (the rank sorts cost ~2 ms per quantity and were 20 % of a standard fit
    on the Basler CSV), then, when they all pass, every derived quantity. The answer is the same
    either way, and so is the cache of a chain that passes."""
    E, S, W, D = chain.shape
    tau = integrated_time(chain)
    if cache is not None:
        cache["_tau"] = tau
        # an undefined τ (NaN: a walker that has not moved in the whole production, which the
        # IndependenceMove allows at a point its proposal undervalues) fails too, and asks for a
        # round of extend_steps (rather than passing here and failing in FitResult's check)
        need = settings.tau_factor * tau - S
        cache["_shortfall"] = ("tau", float(np.max(need)) if np.all(np.isfinite(need)) else float("nan"))
    if not np.all(S >= settings.tau_factor * tau):
        return False

    def ok(key, d):
        if cache is not None:
            cache[key] = d
            cache["_shortfall"] = ("ess", min(d["ess_bulk"], d["ess_tail"]), d["rhat"], key)
        return d["rhat"] < settings.rhat_target and min(d["ess_bulk"], d["ess_tail"]) >= settings.ess_target

    if pool is not None:
        # the parameters first, then (when they pass) the derived quantities: a round whose
        # parameters fail does not compute the derived draws (~0.1 s on 26 000 draws, growing with
        # the chain), as without a pool
        for items in ([(j, chain[..., j]) for j in range(D)], derived_fn):
            if callable(items):
                items = list(items(chain).items())
            if not items:
                continue
            diags = _shared_out(pool, _diagnostics_share, [x for _, x in items])
            for (key, _), d in zip(items, diags):
                if not ok(key, d):
                    return False
    else:
        for j in range(D):
            if not ok(j, fast_diagnostics(chain[..., j])):
                return False
        if derived_fn is not None:
            for name, x in derived_fn(chain).items():
                if not ok(name, fast_diagnostics(x)):
                    return False
    if cache is not None:
        cache.pop("_shortfall", None)
    if reported_fn is not None:
        end = _end_mcse_all(reported_fn(chain), pool)
        if cache is not None:
            cache["end_mcse"] = end
        target = settings.end_mcse_target
        if target is not None and end:
            worst = worst_end(end)
            if not end[worst] <= target:
                if cache is not None:
                    cache["_shortfall"] = ("mcse", end[worst], worst)
                return False
        goal = settings.end_mcse_goal
        if target is None and goal is not None and end:
            # a goal (a flag at the end, not a failed check); an undefined error (draws not all
            # finite) is not one more steps can fix
            worst = max(end, key=lambda k: end[k] if np.isfinite(end[k]) else -np.inf)
            if np.isfinite(end[worst]) and end[worst] > goal:
                if cache is not None:
                    cache["_shortfall"] = ("mcse", end[worst], worst)
                return False
    return True


def _end_mcse_all(quantities, pool=None):
    """{name: :func:`interval_end_mcse_mcmc`} of ``quantities`` ({name: (E, S, W) draws}), shared
    out among the ``pool``'s processes when there is one."""
    names = list(quantities)
    if pool is None or len(names) < 2:
        vals = [interval_end_mcse_mcmc(quantities[k]) for k in names]
    else:
        vals = _shared_out(pool, _end_mcse_share, [quantities[k] for k in names])
    return {k: float(v) for k, v in zip(names, vals)}


def _shared_out(pool, share_fn, xs):
    """``share_fn`` (a list -> a list of results) over ``xs`` shared out round-robin among the
    pool's processes; the results in the order of ``xs``."""
    n = max(1, min(pool.n_processes, len(xs)))
    out = [None] * len(xs)
    for w, part in enumerate(pool.map(share_fn, [xs[w::n] for w in range(n)])):
        out[w::n] = part
    return out
