"""The posterior of a fit: :class:`FitResult` (draws, derived quantities, diagnostics, the fit
JSON), the :class:`Scene` it is evaluated at, and the summaries of draws."""

from bayescap.posterior.diagnose import IMPRECISE_END_MCSE
from bayescap.posterior.result import FitResult
from bayescap.posterior.scene import Scene
from bayescap.posterior.summary import DERIVED_INFO, rerun_advice, summarize

__all__ = ["FitResult", "Scene", "summarize", "DERIVED_INFO", "rerun_advice", "IMPRECISE_END_MCSE"]
