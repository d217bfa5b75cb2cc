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
   **In stages.** When the top-up (4.) may add draws and the model has physical parameters to
   judge, only ``FIRST_STAGE_FRACTION`` (a third) of ``n_proposals`` is drawn first, with the same
   shares and rounds, and topped up as the whole set would be. Where those draws, or the top-up's,
   fail the proposal's check (k̂, IS ESS), the attempt starts again with all ``n_proposals``, exactly
   as without stages (same seed, same draws: the stage's draws are lost, ``n_first_stage`` and
   ``first_stage_grown`` in the diagnostics); the stage alone is not trusted with a rejection or
   with more rounds (more moment-matched rounds on a proposal that misses a tail lower k̂ without
   reaching the tail: measured on a one-sided tail without the tail components). On the focal-plane
   amplifiers 2 500–3 900 draws in all instead of 6 000–9 400, at the same targets.
4. **Top-up.** Each 95 % interval end's predicted Monte Carlo error is computed for every physical
   parameter and derived quantity (:mod:`bayescap.inference.end_errors`). While the worst is above
   the target, more draws are added, up to ``max_proposals``: by default t components aimed at the
   offending ends (the importance density of a quantile has half its mass beyond it). The target
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
from bayescap.inference.curvature import _proposal_cov, laplace_covariance, refine_covariance
from bayescap.inference.end_errors import (
    _END_PROBS,
    PerDrawValues,
    _all_ends,
    _end_table,
    _end_values,
    _joint_target,
    _kept,
    _physical_fn,
    _weighted_kept,
    _within_logprob,
    _worst_end_mcse,
)
from bayescap.inference.importance import (
    _systematic_resample,
    _t_logpdf,
    psis_weights,
    student_t_draws,
    student_t_logpdf,
)
from bayescap.inference.mixture import _adaptive_rounds, _add_components, _DensityCache
from bayescap.inference.optimize import find_map, laplace_start
from bayescap.inference.presets import QUALITY_PRESETS, FastSettings
from bayescap.inference.proposals import (
    _clip_floor_proposal,
    _end_components,
    _floor_top,
    _pair_proposal,
    _tail_entry,
    _tail_probe,
    _tail_proposal,
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


def _initial_mixture(model, settings, rng, x_map, lp_map, cov):
    """The first ``n_proposals`` draws: the Laplace t, the defensive components (wide t, clip floor,
    long tails and a tail paired with the floor) and the adaptive rounds. Returns (draws, log p,
    log q of the mixture, its components or None, the density cache, the tails, the pairs, the
    draws of each tail or pair component)."""
    nu = settings.nu
    n2 = int(round(settings.adapt_fraction * settings.n_proposals))
    n1 = settings.n_proposals - n2
    c1 = _proposal_cov(cov, settings.scale)
    # adapt_fraction 1 leaves nothing to adapt from: then every draw comes from the Laplace t
    floor = (
        isinstance(model, SamplerCoordinates)
        and model.j is not None
        and settings.clip_floor_fraction > 0
        and n1 > 0
        and n2 > 0
    )
    n_floor = int(round(settings.clip_floor_fraction * settings.n_proposals)) if floor else 0
    # defensive components: the clip floor, and each long one-sided tail the probe finds
    extra = []  # [(logpdf, draws)]
    tails, pairs, n_each = [], [], 0
    if n1 > 0 and n2 > 0 and settings.tail_fraction > 0:
        skip = {(model.j, -1.0)} if floor else set()  # the clip floor covers that one
        tails = _tail_probe(model, x_map, lp_map, c1, skip)
        # the clip floor meets the farthest-reaching other tail (a sharp clip edge lets the clip
        # level sit anywhere down to its bound while the clip spread is in its lower tail)
        others = [t for t in tails if n_floor and t[0] != model.j]
        pairs = [max(others, key=lambda t: t[3])] if others and settings.floor_pair else []
        n_comp = max(len(tails) + len(pairs), 1)
        n_each = min(
            int(round(settings.tail_fraction * settings.n_proposals)),
            int(settings.tail_max_fraction * settings.n_proposals) // n_comp,
            (n2 // 2) // n_comp,
        )
        if n_each <= 0:
            tails, pairs = [], []
        n2 -= n_each * (len(tails) + len(pairs))  # the same number of draws in all
    # a defensive t, wide_scale × wider than the Laplace t (Hesterberg 1995): it bounds the weights
    # where the posterior reaches further than the Laplace and the moment-matched rounds, whose
    # weighted moments cannot see draws they never made (on small ROIs the heaviest weights can sit
    # 2–3 Laplace sds out, where only a much larger sample finds them)
    n_wide = min(int(round(settings.wide_fraction * settings.n_proposals)), n2 // 2) if n1 > 0 and n2 > 0 else 0
    n2 -= n_wide  # (at most half of what the rounds have left)
    x1, _ = student_t_draws(x_map, c1, nu, (n1 - n_floor) if n1 > 0 else n2, rng)
    if n_wide:
        c_w = c1 * float(settings.wide_scale) ** 2
        extra.append((_t_logpdf(x_map, c_w, nu), student_t_draws(x_map, c_w, nu, n_wide, rng)[0]))
    if n_floor:
        draw_f, pdf_f = _clip_floor_proposal(model, x_map, c1, nu)
        extra.append((pdf_f, draw_f(n_floor, rng)[0]))
    for j, _, v, reach in tails:
        draw_t, pdf_t = _tail_proposal(x_map, c1, nu, j, v, reach)
        extra.append((pdf_t, draw_t(n_each, rng)[0]))
    for j, side, _, reach in pairs:
        draw_p, pdf_p = _pair_proposal(x_map, c1, nu, (j, side, reach), (model.j, _floor_top(x_map, c1, model.j)))
        extra.append((pdf_p, draw_p(n_each, rng)[0]))
    n_t = x1.shape[0]
    x1 = np.vstack([x1] + [xe for _, xe in extra])  # one log_prob call for all
    with np.errstate(all="ignore"):
        lp1 = model.log_prob(x1)
    cache = _DensityCache()
    if n1 > 0 and n2 > 0:
        comps = [(_t_logpdf(x_map, c1, nu), x1[:n_t], lp1[:n_t], (x_map, c1))]
        at = n_t
        for pdf_e, xe in extra:
            comps.append((pdf_e, x1[at : at + len(xe)], lp1[at : at + len(xe)], None))
            at += len(xe)
        x, logp, logq, comps = _adaptive_rounds(model, settings, rng, comps, n2, cache)
    else:
        x, logp, logq, comps = x1, lp1, student_t_logpdf(x1, x_map, c1, nu), None
    return x, logp, logq, comps, cache, tails, pairs, n_each


def _resample(w, n, rng, values=None):
    """Indices of ``n`` equally weighted draws from weights ``w`` (systematic resampling), shuffled.
    ``values``: a quantity's values on the kept draws (:func:`_kept`): the kept draws are then
    resampled in its order, so that the count of resampled draws at or below each of its values is
    n times their weight to within one draw (:func:`_sorted_end_errors`)."""
    if values is None:
        idx = _systematic_resample(w, n, rng)
    else:
        kept = np.flatnonzero(_kept(w))
        o = np.argsort(values, kind="stable")
        wo = w[kept][o]
        idx = kept[o][_systematic_resample(wo / np.sum(wo), n, rng)]
    return idx[rng.permutation(n)]


def _sorted_end_errors(values, w, n_resampled):
    """:func:`bayescap.inference.end_errors._end_errors` of a quantity whose draws are resampled in the
    order of its own values (systematic resampling): the count of the ``n_resampled`` draws below
    an end is then n·F̂ to within one draw (not the random count whose variance ~p(1 − p)/n
    :func:`_end_errors` adds), so the resampling adds at most (1/n)² to the variance of F̂ (taken
    whole). Where a long tail lies beyond an end the random count's error dominates: on focal-plane
    amplifiers the clip level's upper end stayed at 0.03–0.06 of the width through 4 000–21 000
    draws for it alone. None when the values are not all finite."""
    v = np.asarray(values, float)
    if not np.all(np.isfinite(v)):
        return None
    o = np.argsort(v)
    v, ws = v[o], w[o]
    F = np.cumsum(ws)
    F /= F[-1]
    ws = ws / np.sum(ws)
    width = np.interp(0.975, F, v) - np.interp(0.025, F, v)
    if not width > 0:
        return [0.0 for _ in _END_PROBS]
    c2 = np.cumsum(ws * ws)
    out = []
    for p in _END_PROBS:
        q = np.interp(p, F, v)
        k = int(np.searchsorted(v, q, side="right")) - 1
        below = c2[k] if k >= 0 else 0.0
        var = (1.0 - p) ** 2 * below + p * p * (c2[-1] - below) + (1.0 / float(n_resampled)) ** 2
        se = float(np.sqrt(max(var, 0.0)))
        out.append(float(0.5 * (np.interp(min(p + se, 1.0), F, v) - np.interp(max(p - se, 0.0), F, v)) / width))
    return out


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
    if phys is not None and _physical_per_draw(model):
        phys = PerDrawValues(phys)
    if derived_fn is not None and getattr(derived_fn, "per_draw", False):
        derived_fn = PerDrawValues(derived_fn)

    # the physical parameters (their errors are this path's; a derived quantity's FitResult computes
    # again, for randomly ordered resampling): one of them may be the resampling's order
    params = set(_end_values(model, x, w, None, phys=phys)[2]) if phys is not None else set()
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
        xk_, wk_, vals_ = _end_values(model, x, w, derived_fn, phys=phys)
        key = None
        mcse_, ends_ = table(vals_, wk_)
        cand = [n for n in mcse_ if n in params and np.isfinite(mcse_[n])]
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


#: the first stage's share of ``n_proposals`` (:func:`_first_stage`), and its least number of draws
FIRST_STAGE_FRACTION, FIRST_STAGE_MIN = 1 / 3, 1000


def _first_stage(settings):
    """The draws of the first stage: ``FIRST_STAGE_FRACTION`` of ``n_proposals`` (at least
    ``FIRST_STAGE_MIN``) when the top-up may add draws towards an interval-end target (the stage's
    draws then grow only where that target or the proposal's check asks for more); else all
    ``n_proposals`` at once (and so too for a model without physical parameters, whose draws no
    interval end judges: :func:`_fast_once`)."""
    n = int(settings.n_proposals)
    if settings.end_mcse_max is None or settings.max_proposals <= n:
        return n
    return min(n, max(int(FIRST_STAGE_MIN), int(round(FIRST_STAGE_FRACTION * n))))


def _passes(settings, khat, ess, n):
    """The proposal's own check on ``n`` draws: k̂ below :func:`_khat_limit` and the IS ESS at least
    ``min_ess_is``."""
    return bool(khat < _khat_limit(settings, n) and ess >= settings.min_ess_is)


def _khat_limit(settings, n):
    """The largest k̂ accepted for ``n`` draws: ``khat_max``, and at most the PSIS paper's
    sample-size threshold 1 − 1/log₁₀ n (Vehtari et al. 2024, §3.2.1: below it, k̂ < 0.7 is not
    enough for n < 2 155 draws)."""
    return min(float(settings.khat_max), 1.0 - 1.0 / np.log10(max(n, 11)))


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


#: the retry's start is the first attempt's when its MAP is within this many posterior sds
#: (Mahalanobis, the first covariance) and its whitened covariance within this of the identity
_SAME_SD, _SAME_COV = 0.02, 0.05


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


def _same_start(a, b):
    """Whether two :func:`_attempt_start` results are one start (module constants ``_SAME_SD``,
    ``_SAME_COV``): the same coordinates, MAP and covariance to well within the Monte Carlo noise."""
    if a is None or b is None or (a[0] is None) != (b[0] is None):
        return False
    x1, c1, x2, c2 = a[1], a[3], b[1], b[3]
    if not (np.all(np.isfinite(x1)) and np.all(np.isfinite(x2)) and np.isfinite(a[2]) and np.isfinite(b[2])):
        return False
    try:
        L = np.linalg.cholesky(c1)
    except np.linalg.LinAlgError:
        return False
    d = np.linalg.solve(L, x2 - x1)
    W = np.linalg.solve(L, np.linalg.solve(L, c2).T)  # L⁻¹ C₂ L⁻ᵀ
    if not np.all(np.isfinite(W)):
        return False
    return bool(np.sqrt(d @ d) <= _SAME_SD and np.max(np.abs(W - np.eye(W.shape[0]))) <= _SAME_COV)


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
    if derived_fn is not None and wd is not None:
        # the function whose quantities' interval-end errors are in end_mcse (with its inputs, for
        # FitResult to reuse them: FitResult._derived_end_mcse_importance)
        wd["derived_fn"] = derived_fn
    return chains, diag
