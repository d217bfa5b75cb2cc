"""The fast path's stages and checks (:mod:`bayescap.inference.fast`): the first draws (the Laplace
t, the defensive components and the adaptive rounds), the first stage's size, the proposal's own
check (k̂ with the PSIS paper's sample-size threshold, the IS ESS), resampling in a parameter's
order with its interval ends' predicted error, and the test of whether a retry starts where the
first attempt did."""

from __future__ import annotations

import numpy as np

from bayescap.inference.coordinates import SamplerCoordinates
from bayescap.inference.curvature import _proposal_cov
from bayescap.inference.end_errors import _END_PROBS, _kept, _weighted_cdf
from bayescap.inference.importance import _systematic_resample, _t_logpdf, student_t_draws, student_t_logpdf
from bayescap.inference.mixture import _adaptive_rounds, _DensityCache
from bayescap.inference.proposals import (
    _clip_floor_proposal,
    _floor_top,
    _pair_proposal,
    _tail_probe,
    _tail_proposal,
)

__all__ = ["FIRST_STAGE_FRACTION", "FIRST_STAGE_MIN"]


#: the first stage's share of ``n_proposals`` (:func:`_first_stage`; 1: no stage, the default), and its
#: least number of draws. A stage of a third (or a half) cut the draws of the focal-plane amplifiers
#: from 6 000–9 400 to 2 500–3 900 (CPU per table 0.63 → 0.49 s), but made the 95 % intervals of
#: 24 zoo fits 1.8 % (1.9 %) narrower on average than all 6 000 draws at once (218 intervals, standard
#: error 0.2 %; both ends moved inwards by ~0.9 % of the width: the fewer draws see less of the tails,
#: which the interval-end errors predicted from the weights do not show), against 0.1 % ± 0.06 % for
#: the same code without the stage. Off until a stage is found that keeps the tails.
FIRST_STAGE_FRACTION, FIRST_STAGE_MIN = 1.0, 1000


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


#: the retry's start is the first attempt's when its MAP is within this many posterior sds
#: (Mahalanobis, the first covariance) and its whitened covariance within this of the identity
_SAME_SD, _SAME_COV = 0.02, 0.05


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
    cdf = _weighted_cdf(values, w)
    if cdf is None:
        return None
    v, ws, F, _, width = cdf
    ws = ws / np.sum(ws)
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
