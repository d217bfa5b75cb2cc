"""Fast path: Laplace approximation + Pareto-smoothed importance sampling (Laplace–IS).

1. **Mode and curvature.** :func:`bayescap.inference.optimize.laplace_start` runs Newton's method
   on whitened finite-difference Hessians from the initial guess and the extra starts of the
   multi-start, and returns the MAP with a Laplace covariance consistent to ±25 %. Models with a
   free clip level or a QE are handled in :class:`bayescap.inference.coordinates.SamplerCoordinates`
   (``log(clip_dn − lower bound)``, ``log(qe)``: the photon counts tie QE to K along a ridge that
   is straight in logs); the draws come back in the model's coordinates.
2. **Proposals.** A multivariate Student-t ``t_ν(x_MAP, Σ)`` (a third of ``n_proposals``) and
   defensive components (:mod:`bayescap.inference.proposals`): a t ``wide_scale`` × wider, the clip
   floor (the clip uniform down to its lower bound), and a uniform-reach component for each long
   one-sided tail that :func:`_tail_probe` finds on rays from the MAP (a dark current, clip spread
   or DSNU the data cannot tell from zero). The rest come from ``adapt_rounds`` moment-matching
   rounds, each a t at the weighted moments of all draws so far (:mod:`bayescap.inference.mixture`).
3. **Weights.** ``log p(x) − log q_mix(x)`` over all draws, against the mixture of all proposals
   (the balance heuristic), smoothed by PSIS (Vehtari, Simpson, Gelman, Yao & Gabry 2024, JMLR
   25(72); :func:`bayescap.inference.importance.psis_weights`), which also gives k̂.
   **In stages** (off by default: ``fast_stages.FIRST_STAGE_FRACTION`` 1). With a fraction below 1,
   when the top-up (4.) may add draws and the model has physical parameters to judge, only that
   share of ``n_proposals`` is drawn first, with the same shares and rounds, and topped up as the
   whole set would be; where those draws, or the top-up's, fail the proposal's check (k̂, IS ESS),
   the attempt starts again with all ``n_proposals``, exactly as without stages (same seed, same
   draws; ``n_first_stage`` and ``first_stage_grown`` in the diagnostics). A third cut the
   focal-plane amplifiers' draws by ~60 % but narrowed the zoo's intervals by 1.8 % on average (the
   fewer draws see less of the tails), so it is not used.
4. **Top-up.** Each 95 % interval end's predicted Monte Carlo error is computed for every physical
   parameter and derived quantity (:mod:`bayescap.inference.end_errors`). While the worst is above
   the target, more draws are added, up to ``max_proposals``: by default t components aimed at the
   offending ends (the importance density of a quantile has half its mass beyond it); with
   ``FastSettings.end_parameters`` only the named parameters' ends. The target
   is ``end_mcse_max`` of the width, lowered so that *every* end is within ``end_tolerance`` with
   predicted probability ``end_confidence`` (Π erf(tol/(s_i√2)) over the ends' errors s_i).
5. **Resampling.** Systematic resampling to ``n_draws`` equally weighted draws (as many as there
   are weighted draws after a top-up, unless the caller set ``n_draws``), shuffled.

**Its own diagnostic.** The draws are accepted when k̂ < ``khat_max`` (0.7, the PSIS paper's
threshold for a few thousand draws; below 2 155 draws its 1 − 1/log₁₀ n, which is lower), the importance-sampling ESS ``1/Σw²`` ≥ ``min_ess_is`` (200)
and the interval-end target is met. Otherwise they must not be used: ``diag["accepted"]`` is False
with the reason, and ``bayescap.fit(quality="fast")`` falls back to MCMC. A rejection by k̂ or the
ESS is retried once with ``retry_restarts`` optimiser starts, optimising in the model's
coordinates first (``polish_both``); one by the interval-end target alone is not. When the restarts
end at the first attempt's MAP and covariance (within 0.02 posterior sd and 0.05 of the whitened
covariance), the importance sampling is not repeated: the same proposals and seed give the same
draws and verdict (``diag["retry_skipped"]`` says so).

The draws come back as a :class:`bayescap.inference.chains.ChainResult` with ``chain`` shaped
``(1, n_draws, 1, ndim)`` (one "ensemble", one "walker") and ``extra = {"method": "laplace-is",
"khat": ..., "ess_is": ..., "end_mcse": ..., ...}``, and the weighted draws behind the resampled
ones in ``extra["weighted_draws"]`` (from which :class:`bayescap.posterior.FitResult` computes the
derived quantities' interval-end errors). R-hat and MCMC ESS do not apply to resampled independent
draws; the result reports k̂ and the IS ESS instead.
"""

from __future__ import annotations

import time
from dataclasses import asdict, replace

import numpy as np

from bayescap._blas import one_blas_thread
from bayescap.inference.chains import ChainResult
from bayescap.inference.coordinates import SamplerCoordinates, _sampler_coordinates
from bayescap.inference.curvature import laplace_covariance, refine_covariance
from bayescap.inference.end_errors import (
    _END_PROBS,
    PerDrawValues,
    _all_ends,
    _end_table,
    _end_values,
    _joint_target,
    _physical_fn,
    _weighted_kept,
    _within_logprob,
    _worst_end_mcse,
)
from bayescap.inference.fast_stages import (
    _SAME_COV,
    _SAME_SD,
    _first_stage,
    _initial_mixture,
    _khat_limit,
    _passes,
    _resample,
    _same_start,
    _sorted_end_errors,
)
from bayescap.inference.importance import (
    psis_weights,
)
from bayescap.inference.mixture import _adaptive_rounds, _add_components
from bayescap.inference.optimize import find_map, laplace_start
from bayescap.inference.presets import QUALITY_PRESETS, FastSettings
from bayescap.inference.proposals import (
    _end_components,
    _tail_entry,
)
from bayescap.model.ptc_model import PTCModel

__all__ = ["fast_posterior", "METHOD"]

METHOD = "laplace-is"


def _start_in_coordinates(model, wrapped, settings):
    """The MAP, its log p and the Laplace covariance in the sampler coordinates ``wrapped``: Newton
    from every start mapped into them (:func:`laplace_start`'s ``coords``), and the seconds taken."""
    t0 = time.perf_counter()
    z0, lp0, cz, _ = laplace_start(
        model,
        n_restarts=settings.n_restarts,
        refine_iter=settings.refine_iter,
        polish=settings.polish,
        coords=wrapped,
        polish_both=settings.polish_both,
    )
    return z0, lp0, cz, time.perf_counter() - t0


def _fast_in_coordinates(model, wrapped, seed, n_draws, settings, derived_fn, start=None):
    """:func:`_fast_once` in the sampler coordinates ``wrapped``: from :func:`_start_in_coordinates`
    (``start``: its result, computed here when None), the importance draws there, and the result
    mapped back to the model's coordinates (draws, their log p without the Jacobian, the MAP)."""
    z0, _, cz, t_start = _start_in_coordinates(model, wrapped, settings) if start is None else start
    d_fn = None if derived_fn is None else _InCoordinates(derived_fn, wrapped)
    chains, diag = _fast_once(wrapped, seed, n_draws, settings, z0, cz, d_fn)
    diag["wall_map_s"] += t_start
    diag["wall_s"] += t_start
    chains.wall_s += t_start
    D = wrapped.ndim
    z = chains.chain.reshape(-1, D)
    chains.chain = wrapped.to_x(z).reshape(chains.chain.shape)
    chains.log_prob = chains.log_prob - wrapped.log_jacobian(z).reshape(chains.log_prob.shape)
    chains.x_map = wrapped.to_x(chains.x_map)
    chains.lp_map = float(model.log_prob(chains.x_map[None])[0])
    wd = chains.extra.get("weighted_draws")
    if wd is not None:
        wd["x"] = wrapped.to_x(wd["x"])
    chains.extra["coordinates"] = diag["coordinates"] = wrapped.describe()
    return chains, diag


class _InCoordinates:
    """``fn`` (draws in the model's coordinates -> {name: values}) of draws in ``coords``; of each
    draw alone (``per_draw``) when ``fn`` is: the map between the coordinates is row by row."""

    def __init__(self, fn, coords):
        self.fn, self.coords = fn, coords
        self.per_draw = bool(getattr(fn, "per_draw", False))

    def __call__(self, z):
        return self.fn(self.coords.to_x(z))


def _physical_per_draw(model) -> bool:
    """Whether the physical parameters of ``model``'s draws (:func:`_physical_fn`) are each a
    function of its draw alone: a :class:`PTCModel`'s, in its coordinates or the sampler's."""
    inner = model.model if isinstance(model, SamplerCoordinates) else model
    return isinstance(inner, PTCModel)


def _mode_and_covariance(model, settings, x_map, cov, t0):
    """The MAP, log p there and the Laplace covariance (computed where not given), and the time the
    MAP was done (with Newton, the covariance comes out of the same iterations)."""
    if x_map is None and cov is None:
        x_map, lp_map, cov, t_map = laplace_start(
            model, n_restarts=settings.n_restarts, refine_iter=settings.refine_iter, polish=settings.polish
        )
        return x_map, lp_map, cov, t_map + t0
    if x_map is None:
        x_map, lp_map = find_map(model, n_restarts=settings.n_restarts)
    else:
        x_map = np.asarray(x_map, float)
        lp_map = float(model.log_prob(x_map[None])[0])
    t_map = time.perf_counter()
    if cov is None:
        cov = laplace_covariance(model, x_map)
        cov = refine_covariance(model, x_map, cov, max_iter=settings.refine_iter)
    return x_map, lp_map, cov, t_map


def _top_up(model, settings, rng, derived_fn, x, logp, logq, comps, cache, n_draws, default_n):
    """PSIS weights of the draws and, where an interval end's predicted Monte Carlo error is above
    the target, more draws until it is not (at most ``max_proposals`` in all). Returns (draws, log p,
    weights, k̂, IS ESS, {name: worst end's error}, {name: ends' errors}, the worst, the target,
    the draws to resample, the draws added, the mixture's components, the resampling's order: None or
    (a parameter's name, its values on the kept draws))."""
    w, khat, ess = psis_weights(logp - logq)
    khat, ess = float(khat), float(ess)
    gate, tol, conf = settings.end_mcse_max, settings.end_tolerance, settings.end_confidence
    n_topup, n_out, partial = 0, n_draws, False
    # each round looks at the quantities of every draw that counts, the earlier rounds' draws
    # included: each draw's are computed once (the linearity error's per-draw response inverse was
    # ~40 % of a Basler fast fit), where the functions are of each draw alone
    phys = _physical_fn(model)
    gated = None if settings.end_parameters is None else set(settings.end_parameters)
    if gated is not None:
        derived_fn = None  # (FastSettings.end_parameters: the derived quantities are the result's to check)
    if phys is not None and _physical_per_draw(model):
        phys = PerDrawValues(phys)
    if derived_fn is not None and getattr(derived_fn, "per_draw", False):
        derived_fn = PerDrawValues(derived_fn)

    # the physical parameters (their errors are this path's; a derived quantity's FitResult computes
    # again, for randomly ordered resampling): one of them may be the resampling's order
    params = set(_end_values(model, x, w, None, names=gated, phys=phys)[2]) if phys is not None else set()
    key = None  # the parameter the draws are resampled in the order of (_sorted_end_errors)

    def table(vals_, wk_, mcse_=None, ends_=None):
        """:func:`_end_table` of ``vals_`` (given: only the resampling order's entry), the
        resampling-order parameter's by :func:`_sorted_end_errors`."""
        if mcse_ is None:
            mcse_, ends_ = _end_table(vals_, wk_, n_out)
        if key in vals_:
            errs = _sorted_end_errors(vals_[key], wk_, n_out)
            ends_[key] = [float("nan")] * len(_END_PROBS) if errs is None else errs
            mcse_[key] = float("nan") if errs is None else max(errs)
        return mcse_, ends_

    def full_table():
        """Every quantity's interval-end errors on the current draws: (kept draws, weights, values,
        {name: worst end}, {name: ends}, the worst, the per-end target). The parameter whose ends are
        worst for randomly ordered resampling becomes the resampling's order (``key``)."""
        nonlocal key
        xk_, wk_, vals_ = _end_values(model, x, w, derived_fn, names=gated, phys=phys)
        key = None
        mcse_, ends_ = table(vals_, wk_)
        # (only with a gate on the ends: without one, as for the MCMC's start, the order is not needed)
        cand = [n for n in mcse_ if gate is not None and n in params and np.isfinite(mcse_[n])]
        if cand:
            key = max(cand, key=lambda n: mcse_[n])
            mcse_, ends_ = table(vals_, wk_, mcse_, ends_)
        worst_, target_ = _worst_end_mcse(mcse_), _joint_target(_all_ends(ends_), tol, conf, gate)
        return xk_, wk_, vals_, mcse_, ends_, worst_, target_

    xk, wk, vals, mcse, ends, worst, target = full_table()
    # more draws until every interval end's predicted Monte Carlo error is below the target (its
    # variance falls as 1/N; the target: end_mcse_max, lower where many ends near it would leave the
    # worst of them outside end_tolerance, _joint_target), at most max_proposals in all; not when
    # k̂ already rejects the proposal (more of the same draws would not help)
    while (
        target is not None
        and comps is not None
        and worst > target
        and khat < _khat_limit(settings, x.shape[0])
        and x.shape[0] < settings.max_proposals
    ):
        want = x.shape[0] * (1.1 * (worst / target) ** 2 - 1.0)
        n_more = int(min(max(want, settings.n_proposals / 3), settings.max_proposals - x.shape[0]))
        aimed = []
        if settings.topup == "targeted":
            # draws aimed at the offending ends (their error falls faster than 1/√N there)
            # rounds of topup_draws while few are missing, growing with the draws so far (at most
            # 7 rounds from the default 6 000 to max_proposals) where many are
            base = settings.n_proposals / 4 if settings.topup_draws is None else settings.topup_draws
            n_more = int(min(max(base, x.shape[0] / 4), settings.max_proposals - x.shape[0]))
            aimed = _end_components(
                xk, wk, vals, mcse, target, n_out, settings.adapt_inflation, settings.topup_components, ends
            )
        if aimed and n_more >= len(aimed):
            each = [n_more // len(aimed) + (1 if i < n_more % len(aimed) else 0) for i in range(len(aimed))]
            x, logp, logq, comps = _add_components(
                model, settings, rng, comps, [(mu, c, n) for (mu, c), n in zip(aimed, each)], cache
            )
        else:
            x, logp, logq, comps = _adaptive_rounds(model, replace(settings, adapt_rounds=1), rng, comps, n_more, cache)
        n_topup += n_more
        w, khat, ess = psis_weights(logp - logq)
        khat, ess = float(khat), float(ess)
        # more draws are resampled after a top-up (n_draws unless the caller set it), as many as
        # there are weighted draws, so that the resampling does not undo the gain
        n_out = n_draws if not default_n else int(max(n_draws, x.shape[0]))
        # between rounds only the quantities near or above the target are looked at again (sorting
        # every quantity each round is a sizeable share of a gated fit); once they are below it,
        # all of them (and the target again), and the rounds go on if one is above
        watch = None if settings.topup != "targeted" else {n for n, e in mcse.items() if not e <= 0.8 * target}
        if watch is None:
            xk, wk, vals, mcse, ends, worst, target = full_table()
            continue
        xk, wk, vals = _end_values(model, x, w, derived_fn, names=watch, phys=phys)
        part, part_ends = table(vals, wk)
        partial = not _worst_end_mcse(part) <= target
        if not partial:
            xk, wk, vals, mcse, ends, worst, target = full_table()
            continue
        mcse = {**{n: e for n, e in mcse.items() if n not in watch}, **part}
        ends = {**{n: e for n, e in ends.items() if n not in watch}, **part_ends}
        worst = _worst_end_mcse(mcse)
        target = _joint_target(_all_ends(ends), tol, conf, gate)
        if not worst > target:
            # the watched quantities meet the new target, judged with the others' errors of an
            # earlier round (other weights, fewer draws resampled): all of them again before the
            # rounds stop, so that a table the stale errors pass and the fresh ones fail is not
            # rejected with draws to spare
            xk, wk, vals, mcse, ends, worst, target = full_table()
            partial = False
    if (n_topup and partial) or (key is not None and key not in vals):
        # the rounds stopped above the target: every quantity's error, as reported
        xk, wk, vals, mcse, ends, worst, target = full_table()
    order = None if key is None else (key, np.asarray(vals[key], float))
    return x, logp, w, khat, ess, mcse, ends, worst, target, n_out, n_topup, comps, order


def _fast_once(model, seed, n_draws, settings, x_map, cov, derived_fn=None):
    """One attempt of the fast path (:func:`fast_posterior`); ``n_draws`` None: ``settings.n_draws``,
    more after a top-up."""
    wrapped = _sampler_coordinates(model) if x_map is None and cov is None else None
    if wrapped is not None:
        return _fast_in_coordinates(model, wrapped, seed, n_draws, settings, derived_fn)
    t0 = time.perf_counter()
    default_n = n_draws is None
    n_draws = int(settings.n_draws if default_n else n_draws)
    x_map, lp_map, cov, t_map = _mode_and_covariance(model, settings, x_map, cov, t0)
    t_lap = time.perf_counter()
    n_first = _first_stage(settings) if _physical_fn(model) is not None else settings.n_proposals
    staged = n_first < settings.n_proposals
    if staged:
        # the first stage: its draws are judged (k̂, IS ESS) and topped up as the whole set would be
        first = replace(settings, n_proposals=n_first)
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        x, logp, logq, comps, cache, tails, pairs, n_each = _initial_mixture(model, first, rng, x_map, lp_map, cov)
        ok = comps is not None and _passes(settings, *psis_weights(logp - logq)[1:], x.shape[0])
        if ok:
            x, logp, w, khat, ess, mcse, ends, worst, target, n_out, n_topup, _, order = _top_up(
                model, first, rng, derived_fn, x, logp, logq, comps, cache, n_draws, default_n
            )
            ok = _passes(settings, khat, ess, x.shape[0])
        staged = ok
    if not staged:
        # all n_proposals at once (the stage's draws, or the top-up's, failed the proposal's check:
        # then from the start again, as without stages: the same seed, the same draws)
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        x, logp, logq, comps, cache, tails, pairs, n_each = _initial_mixture(model, settings, rng, x_map, lp_map, cov)
        x, logp, w, khat, ess, mcse, ends, worst, target, n_out, n_topup, _, order = _top_up(
            model, settings, rng, derived_fn, x, logp, logq, comps, cache, n_draws, default_n
        )
    gate, tol, conf = settings.end_mcse_max, settings.end_tolerance, settings.end_confidence
    p_within = float(np.exp(_within_logprob(_all_ends(ends), tol)))
    n_draws = n_out
    n_outside = int(np.sum(~np.isfinite(logp)))
    t_is = time.perf_counter()
    idx = _resample(w, n_draws, rng, None if order is None else order[1])
    draws = x[idx]
    lp = logp[idx]
    reasons = []
    khat_limit = _khat_limit(settings, x.shape[0])
    if not khat < khat_limit:
        reasons.append(f"Pareto k̂ {khat:.2f} ≥ {khat_limit:.3g}")
    if not ess >= settings.min_ess_is:
        reasons.append(f"importance-sampling ESS {ess:.0f} < {settings.min_ess_is:g}")
    if not np.isfinite(lp_map):
        reasons.append("no finite MAP")
    # a proposal that passes but whose draws are too few for the interval ends: not a failed
    # optimiser, so fast_posterior does not retry it with restarts
    mcse_only = not reasons
    if target is not None and not worst <= target:
        if not np.isfinite(worst):
            reasons.append("interval-end Monte Carlo error undefined: a parameter's draws are not all finite")
        elif not worst <= gate:
            reasons.append(
                f"interval-end Monte Carlo error {worst:.3f} of the width > {gate:g} after {x.shape[0]} draws"
            )
        else:
            reasons.append(
                f"predicted probability that every interval end is within {tol:g} of the width "
                f"{p_within:.2f} < {conf:g} (worst end {worst:.3f}) after {x.shape[0]} draws"
            )
    wall = time.perf_counter() - t0
    diag = {
        "method": METHOD,
        "accepted": not reasons,
        "reason": "; ".join(reasons),
        "khat": khat,
        "ess_is": ess,
        "n_proposals": int(x.shape[0]),
        "n_topup": int(n_topup),
        # the first stage's draws (0: none), and whether the proposal's check on them asked for
        # all n_proposals from the start (the stage's draws then add to the cost, not to the draws)
        "n_first_stage": int(n_first if n_first < settings.n_proposals else 0),
        "first_stage_grown": bool(n_first < settings.n_proposals and not staged),
        "end_mcse_max": gate,
        "end_tolerance": tol,
        "end_confidence": conf,
        "end_within_probability": p_within,
        "rejected_for_mcse_only": bool(reasons) and mcse_only,
        "n_draws": n_draws,
        "n_outside_support": n_outside,
        "khat_max": khat_limit,
        "min_ess_is": settings.min_ess_is,
        "nu": settings.nu,
        "wall_s": wall,
        "wall_map_s": t_map - t0,  # with Newton (the default) the covariance too
        "wall_laplace_s": t_lap - t_map,
        "wall_is_s": t_is - t_lap,
        "end_mcse": mcse,
        # the long one-sided tails the probe found, each given tail_fraction of the draws
        "tails": [_tail_entry(model, t, n_each) for t in tails]
        + [_tail_entry(model, t, n_each, " with the clip floor") for t in pairs],
        "settings": asdict(settings),
    }
    D = x_map.size
    chains = ChainResult(
        chain=draws.reshape(1, n_draws, 1, D),
        log_prob=lp.reshape(1, n_draws, 1),
        acceptance=np.array([1.0]),  # no Markov chain: every resampled draw is kept
        tau=np.ones(D),  # independent draws: τ = 1 step
        x_map=x_map,
        lp_map=float(lp_map),
        settings=QUALITY_PRESETS["fast"],
        wall_s=wall,
        n_rounds=0,
        extra={
            k: diag[k]
            for k in (
                "method",
                "khat",
                "ess_is",
                "n_proposals",
                "n_topup",
                "n_first_stage",
                "first_stage_grown",
                "accepted",
                "reason",
                "khat_max",
                "min_ess_is",
                "nu",
                "end_mcse",
                "end_mcse_max",
                "end_tolerance",
                "end_confidence",
                "end_within_probability",
                "tails",
                "settings",
            )
        },
    )
    # the weighted draws behind the resampled ones (those of non-negligible weight, as _end_mcse
    # keeps them): FitResult computes the interval ends' Monte Carlo error of the derived
    # quantities (capacity, TR, ...) from them, which need the scene and MTF this path has not got
    xk, wk = _weighted_kept(x, w)
    chains.extra["weighted_draws"] = {"x": xk, "w": wk, "n_resampled": n_draws}
    return chains, diag


def _attempt_start(model, settings):
    """Where an attempt of the fast path starts: (sampler coordinates or None, MAP, log p there,
    Laplace covariance, both in those coordinates, seconds taken)."""
    wrapped = _sampler_coordinates(model)
    if wrapped is not None:
        z0, lp0, cz, t = _start_in_coordinates(model, wrapped, settings)
        return wrapped, z0, lp0, cz, t
    t0 = time.perf_counter()
    x0, lp0, c0, _ = laplace_start(
        model, n_restarts=settings.n_restarts, refine_iter=settings.refine_iter, polish=settings.polish
    )
    return None, x0, lp0, c0, time.perf_counter() - t0


def _attempt(model, seed, n_draws, settings, x_map, cov, derived_fn, start):
    """One attempt (:func:`_fast_once`) from ``start`` (:func:`_attempt_start`; None: from the
    given ``x_map`` and ``cov``)."""
    if start is None:
        return _fast_once(model, seed, n_draws, settings, x_map, cov, derived_fn)
    wrapped, x0, lp0, c0, t = start
    if wrapped is not None:
        return _fast_in_coordinates(model, wrapped, seed, n_draws, settings, derived_fn, start=(x0, lp0, c0, t))
    chains, diag = _fast_once(model, seed, n_draws, settings, x0, c0, derived_fn)
    diag["wall_map_s"] += t
    diag["wall_s"] += t
    chains.wall_s += t
    return chains, diag


@one_blas_thread
def fast_posterior(
    model,
    *,
    seed,
    n_draws: int | None = None,
    settings: FastSettings = FastSettings(),
    x_map=None,
    cov=None,
    derived_fn=None,
):
    """Laplace–IS posterior draws for ``model`` (module docstring).

    Parameters
    ----------
    model : the posterior (:class:`bayescap.model.PTCModel` or anything with ``log_prob``,
        ``ndim``, ``initial_guess``).
    seed : seeds the proposal and the resampling (same seed, same draws).
    n_draws : equally weighted draws returned (default ``settings.n_draws``).
    settings : :class:`FastSettings`.
    x_map, cov : a MAP and covariance already computed (used as given: no retry with restarts);
        computed here when not given.
    derived_fn : ``x (n, ndim) -> {name: values (n,)}``, quantities computed from the parameters
        (capacity, TR, ...; :meth:`bayescap.posterior.FitResult.derived_values_fn`): their interval
        ends' Monte Carlo error joins the parameters' in ``end_mcse``, so that the top-up towards
        ``settings.end_mcse_max`` covers them too (without it, a derived quantity above the gate is
        found only by the result's own check, and ``bayescap.fit`` falls back to MCMC).

    Returns
    -------
    (ChainResult, dict) : the draws as a ChainResult of shape ``(1, n_draws, 1, ndim)`` and the
    diagnostics ``{"accepted", "khat", "ess_is", "n_proposals", "khat_max", "min_ess_is",
    "reason", "wall_s", ...}``. ``accepted`` is False when the caller must fall back to MCMC.
    """
    given = x_map is not None or cov is not None
    start = None if given else _attempt_start(model, settings)
    chains, diag = _attempt(model, seed, n_draws, settings, x_map, cov, derived_fn, start)
    diag["retried_with_restarts"] = False
    if (
        not diag["accepted"]
        and not diag["rejected_for_mcse_only"]
        and not given
        and settings.retry_restarts > settings.n_restarts
    ):
        # a single optimiser start can stop at the initial guess (measured on small-frame
        # sensors): retry with restarts before declaring failure
        retry = replace(settings, n_restarts=settings.retry_restarts, polish_both=True)
        start2 = _attempt_start(model, retry)
        first = {k: diag[k] for k in ("khat", "ess_is", "reason")}
        if _same_start(start, start2):
            # the restarts end where the first attempt started: the same proposals, the same seed,
            # so the same draws and the same verdict; the importance sampling is not repeated
            wall = diag["wall_s"] + start2[4]
            diag["retry_skipped"] = (
                f"the {settings.retry_restarts} restarts found the first attempt's MAP and covariance again "
                f"(within {_SAME_SD:g} posterior sd and {_SAME_COV:g} of the covariance): "
                "the same proposals would give the same verdict"
            )
            chains.extra["retry_skipped"] = diag["retry_skipped"]
        else:
            c2, d2 = _attempt(model, seed, n_draws, retry, None, None, derived_fn, start2)
            wall = d2["wall_s"] + diag["wall_s"]
            if d2["accepted"] or d2["khat"] < diag["khat"]:  # keep the better of the two attempts
                chains, diag = c2, d2
        diag["wall_s"] = chains.wall_s = wall
        diag["retried_with_restarts"] = True
        diag["first_attempt"] = first
    chains.extra["retried_with_restarts"] = diag["retried_with_restarts"]
    wd = chains.extra.get("weighted_draws")
    if derived_fn is not None and wd is not None and settings.end_parameters is None:
        # the function whose quantities' interval-end errors are in end_mcse (with its inputs, for
        # FitResult to reuse them: FitResult._derived_end_mcse_importance)
        wd["derived_fn"] = derived_fn
    return chains, diag
