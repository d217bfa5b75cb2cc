"""How long the MCMC's next round runs (:func:`bayescap.inference.mcmc.run_ensembles` extends the
ensembles in rounds until every check passes)."""

from __future__ import annotations

import numpy as np

CHASE_MAX_STEPS = 4000  # production steps beyond which a chase no longer grows the rounds by n/2


def _next_round_steps(n_done, settings, cache, chase=0):
    """Steps of the next round: ``extend_steps``, or with ``adaptive_extend`` enough to close the
    shortfall of the check that failed (ESS grows about linearly with the steps: n·(target/ESS − 1)
    + 10 %; a τ check: tau_factor·τ − n; an interval end's Monte Carlo error: n·((error/target)² −
    1) + 10 %), at most 3 n + extend_steps. From the second round in a row that the τ or the ESS
    check fails (``chase``), at least n/2 up to :data:`CHASE_MAX_STEPS`: a slowly mixing chain's τ
    estimate grows with the chain (its ESS stays put), and rounds sized to the last estimate chased
    it, 20 steps a round, until max_rounds. Not where τ is undefined (a walker that never moved) or
    R-hat fails: more steps do not cure a stuck walker or a chain in two places, and the rounds of a
    fit that cannot converge would grow without end. Even, so the shared-sort diagnostics apply.
    Deterministic: depends only on the chain."""
    base = settings.extend_steps or settings.n_steps
    if not settings.adaptive_extend or not cache or "_shortfall" not in cache:
        return base
    kind, *v = cache["_shortfall"]
    chasing = chase >= 2 and n_done < CHASE_MAX_STEPS and np.isfinite(v[0])
    if kind == "tau":
        need = v[0] if np.isfinite(v[0]) else base  # NaN: undefined τ, a walker yet to move
    elif kind == "mcse":  # the error falls as 1/√n
        target = settings.end_mcse_target if settings.end_mcse_target is not None else settings.end_mcse_goal
        need, chasing = 1.1 * n_done * ((v[0] / target) ** 2 - 1.0), False
    elif v[1] >= settings.rhat_target:  # R-hat failed: no ESS-based guess
        need, chasing = base, False
    else:
        need = 1.1 * n_done * (settings.ess_target / max(v[0], 1.0) - 1.0)
    if chasing:
        need = max(need, 0.5 * n_done)
    n = int(np.ceil(min(max(need, base), 3 * n_done + base)))
    return n + n % 2
