"""Posterior inference: the Laplace–IS fast path (:mod:`~bayescap.inference.fast`), emcee ensembles
(:mod:`~bayescap.inference.mcmc`), their settings and presets, and their diagnostics.

emcee is imported only when MCMC runs: :class:`IndependenceMove` (an emcee move) loads on first
access, so that a fast fit never imports emcee or scipy.stats."""

from __future__ import annotations

from bayescap.inference import diagnostics
from bayescap.inference.chains import ChainResult
from bayescap.inference.coordinates import SamplerCoordinates
from bayescap.inference.fast import fast_posterior
from bayescap.inference.mcmc import run_ensembles
from bayescap.inference.optimize import laplace_start
from bayescap.inference.presets import QUALITY_PRESETS, FastSettings, SamplerSettings

__all__ = [
    "SamplerSettings",
    "FastSettings",
    "QUALITY_PRESETS",
    "run_ensembles",
    "fast_posterior",
    "ChainResult",
    "diagnostics",
    "laplace_start",
    "SamplerCoordinates",
    "IndependenceMove",
]


def __getattr__(name):
    if name == "IndependenceMove":
        from bayescap.inference.moves import IndependenceMove

        return IndependenceMove
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
