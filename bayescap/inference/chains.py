"""The sampler's raw output and the stuck-walker test shared by the MCMC, the fast path and the result."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayescap.inference.presets import SamplerSettings


@dataclass
class ChainResult:
    """Raw output of the ensembles: chain (n_ensembles, n_steps, n_walkers, ndim)."""

    chain: np.ndarray
    log_prob: np.ndarray
    acceptance: np.ndarray  # per ensemble, mean acceptance fraction
    tau: np.ndarray  # integrated autocorrelation time per parameter (steps)
    x_map: np.ndarray
    lp_map: float
    settings: SamplerSettings
    wall_s: float
    n_rounds: int
    extra: dict = field(default_factory=dict)


def stuck_threshold(ndim: int) -> float:
    """Log-probability drop below the best walker beyond which a walker is not sampling the posterior.

    Near the mode ``lp_max − lp`` of a posterior draw is about ``χ²_D/2``; a walker whose best
    log-probability over a stretch of steps stays below ``lp_max − (½·χ²_D(1 − 10⁻⁶) + 5)`` is lost
    in a region the posterior does not visit (probability < 10⁻⁶ per walker for a Gaussian
    posterior; the 5 nats allow for heavier tails). 29 nats for D = 10."""
    from scipy.special import chdtri  # the χ² quantile from its upper tail, without scipy.stats

    return 0.5 * float(chdtri(ndim, 1e-6)) + 5.0


def stuck_walkers(log_prob, ndim: int) -> np.ndarray:
    """Walkers (columns of ``log_prob``, shaped (steps, walkers)) whose best log-probability stays
    more than :func:`stuck_threshold` below the best of all."""
    lp = np.where(np.isfinite(log_prob), log_prob, -np.inf)
    best = np.max(lp, axis=0)
    return best < np.max(best) - stuck_threshold(ndim)
