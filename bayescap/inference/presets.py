"""The inference settings in one registry: the MCMC sampler's (:class:`SamplerSettings`), the fast
path's (:class:`FastSettings`) and the quality presets (fast, standard, accurate)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SamplerSettings:
    """Knobs of the sampler (docs/performance.md, "Presets and knobs")."""

    n_ensembles: int = 4
    walkers_per_dim: int = 8
    min_walkers: int = 48
    n_burn: int = 50
    # burn-in steps when the walkers start from accepted Laplace–IS draws (importance_start), which
    # already spread like the posterior (None: n_burn, as from the Laplace ball)
    n_burn_is_start: int | None = None
    n_steps: int = 200  # production steps of the first round
    extend_steps: int | None = 100  # steps of each further round (None: n_steps)
    max_rounds: int = 8  # extend until converged, at most this many rounds
    rhat_target: float = 1.01
    ess_target: float = 1000.0  # bulk and tail, every parameter and capacity
    tau_factor: float = 10.0  # production length ≥ tau_factor × integrated autocorrelation time
    max_draws: int = 8000  # posterior draws kept for propagation
    de_fraction: float = 0.8  # DEMove share of the non-independence moves, the rest StretchMove
    independence_fraction: float = 0.0  # share of IndependenceMove steps (t proposal at the Laplace start)
    independence_nu: float = 6.0  # its Student-t degrees of freedom
    independence_scale: float = 1.0  # its sd multiplier on the Laplace covariance
    map_restarts: int = 2  # extra optimiser starts in find_map (the Laplace start)
    adaptive_extend: bool = False  # size each further round from the ESS / τ shortfall (≥ extend_steps)
    importance_start: bool = True  # with the IndependenceMove: start from Laplace–IS draws when accepted
    start_proposals: int = 6000  # importance draws of that start (FastSettings.n_proposals)
    # largest Monte Carlo error of a reported 95 % interval end, as a fraction of its width
    # (interval_end_mcse_mcmc; None: computed and reported, not checked)
    end_mcse_target: float | None = None
    # without end_mcse_target: extend (rounds sized from the 1/√n law, up to max_rounds) while an
    # interval end's Monte Carlo error is above this fraction of its width. A goal, not a check: a
    # fit still above it at max_rounds is flagged (imprecise_interval_ends), not failed (None: no goal)
    end_mcse_goal: float | None = None


@dataclass(frozen=True)
class FastSettings:
    """Knobs of the Laplace–IS fast path (:mod:`bayescap.inference.fast`; ``docs/performance.md``)."""

    nu: float = 4.0  # Student-t degrees of freedom of the proposals
    n_proposals: int = 6000  # importance draws before any top-up (1 + adapt_rounds vectorised log_prob calls)
    adapt_fraction: float = 2 / 3  # share drawn from the moment-matched proposals
    adapt_inflation: float = 1.2  # sd multiplier on the weighted covariance of the draws so far
    refine_iter: int = 6  # BFGS route only (laplace_start(optimizer="bfgs")): whitened Hessian re-evaluations
    polish: bool = True  # BFGS route only: whitened gradient ascent after find_map (polish_map)
    n_draws: int = 4000  # equally weighted draws returned after resampling
    khat_max: float = 0.7  # accept when Pareto k̂ < khat_max ...
    min_ess_is: float = 200.0  # ... and the importance-sampling ESS ≥ this
    n_restarts: int = 0  # extra optimiser starts in find_map
    retry_restarts: int = 2  # on rejection, retry once with this many restarts
    scale: float = 1.0  # proposal scale factor on the Laplace covariance (sd multiplier)
    polish_both: bool = False  # clip coordinates: optimise in the model's coordinates first (the retry does)
    adapt_rounds: int = 3  # moment-matching rounds sharing the adapt_fraction draws
    clip_floor_fraction: float = 0.1  # clip coordinates: share of the first draws from _clip_floor_proposal
    end_mcse_max: float | None = (
        0.035  # accept only when every interval end's predicted Monte Carlo error ≤ this × width (None: report only)
    )
    max_proposals: int = 24000  # draws in all, topping up towards end_mcse_max (n_proposals: no top-up)
    tail_fraction: float = (
        0.05  # share of the draws from each long one-sided tail the probe finds (_tail_probe; 0: no probe)
    )
    tail_max_fraction: float = 0.2  # at most this share for all tail (and pair) components together
    floor_pair: bool = (
        True  # with the clip floor and a tail: tail_fraction more draws from both at once (_pair_proposal)
    )
    adapt_nu: float | None = None  # degrees of freedom of the moment-matched rounds' t (None: nu)
    topup: str = "targeted"  # end_mcse_max's top-up: "targeted" (_end_components) or "global" (moment-matched t)
    topup_components: int = 8  # targeted top-up: at most this many interval ends aimed at per round
    topup_draws: int | None = (
        None  # targeted top-up: draws per round at least (a quarter of those so far if more; None: n_proposals/4)
    )
    wide_fraction: float = (
        0.1  # share of the draws from a defensive t at the MAP, wide_scale × the Laplace sd (0: none)
    )
    wide_scale: float = 3.0
    end_tolerance: float = 0.05  # with end_confidence: the error (× width) every interval end should stay within ...
    end_confidence: float | None = (
        0.9  # ... with at least this predicted probability, all ends at once (None: per end only)
    )
    # the physical parameters whose interval ends the top-up and the gate judge (None: every physical
    # parameter and the derived quantities of fast_posterior's derived_fn); a caller that reports only
    # some parameters (the colour fit's channels, bayescap.colour.cfa_fit) names them, and then the
    # derived quantities' errors are left to the result's own check (FitResult), the others' unjudged
    end_parameters: tuple | None = None


QUALITY_PRESETS = {
    # fast: the Laplace–IS fast path's fallback (bayescap.fit(quality="fast") runs this MCMC preset where
    # the importance draws fail their check). The standard preset's sampler (IS start, IndependenceMove
    # 70 %, rounds sized from the shortfall) with 2 ensembles and ESS ≥ 200: ~1.8× faster than
    # DE/stretch from a Laplace ball at the same interval-end errors against the `accurate` references
    "fast": SamplerSettings(
        n_ensembles=2,
        walkers_per_dim=10,
        n_burn=80,
        n_steps=60,
        extend_steps=20,
        max_rounds=8,
        ess_target=200,
        tau_factor=10,
        max_draws=4000,
        independence_fraction=0.7,
        independence_nu=4.0,
        independence_scale=1.3,
        adaptive_extend=True,
        map_restarts=0,
    ),
    # standard: the targets (R-hat < 1.01, ESS >= 1000 for every parameter and capacity).
    # 70 % of the steps are IndependenceMove proposals (t, ν 4, sd × 1.3) fitted to the burn-in (share
    # cut where they are rarely accepted), the rest DE 0.8 + stretch 0.2; walkers start from Laplace–IS
    # draws. τ 4–7 steps instead of 16–22. 5 walkers per parameter but at least 80, 80 steps: the τ
    # check (80 ≥ 10 τ) and not the ESS binds, and 10·D walkers gave ESS 1 900–4 300 where 1 000 is
    # asked (ESS is the ensembles' draws over ~2–3 τ, whatever the walker count). Not fewer than 80:
    # with 48–64 walkers the zoo's 8-parameter draw00_8bit mixed with τ 37–61 steps and did not
    # converge in 16 rounds, with 80 τ 7.6 in one round; rounds after the first are sized from the
    # ESS/τ shortfall. Burn-in 40 steps
    # after an accepted Laplace–IS start (the walkers are then already spread like the posterior; the
    # burn-in refits the IndependenceMove's t twice and moves stranded walkers), 80 from the Laplace
    # ball; a drift the short burn-in leaves shows in the time-split R-hat, and its steps are then
    # discarded (run_ensembles). One optimiser start (polish_map reaches the 2-restart MAP on 13 sensors).
    "standard": SamplerSettings(
        walkers_per_dim=5,
        min_walkers=80,
        n_burn=80,
        n_burn_is_start=40,
        n_steps=80,
        extend_steps=20,
        # 20 rounds (was 16): the zoo's draw11_10bit (a slow log K, τ 17-39 steps) has a drift cut
        # near round 15 with 80 or 120 walkers alike, and converges in the round after it (17 with 80)
        max_rounds=20,
        independence_fraction=0.7,
        independence_nu=4.0,
        independence_scale=1.3,
        adaptive_extend=True,
        map_restarts=0,
        # the flag's threshold (bayescap.posterior.IMPRECISE_END_MCSE): the few fits whose chain
        # passes R-hat/ESS/τ with an end's error above it (a slow clip level or outlier weight;
        # ~1 in 25 zoo sensors) run on until it is below, instead of being flagged
        end_mcse_goal=0.1,
    ),
    # accurate: every reported interval end's Monte Carlo error ≤ 1 % of its width too (issue 7). Up to 20
    # rounds of 800 steps: with a clip spread τ ≈ 120 steps the 50 τ length check can pass with the clip
    # spread's ends at 1.1 %, and 12 rounds (9 600 steps) can leave 1.18 % (1/√n asks for ~13 400).
    # Rounds run only while a check fails
    "accurate": SamplerSettings(
        n_ensembles=8,
        n_burn=400,
        n_steps=800,
        extend_steps=None,
        max_rounds=20,
        rhat_target=1.005,
        ess_target=2000,
        tau_factor=50,
        max_draws=20000,
        end_mcse_target=0.01,
    ),
}
