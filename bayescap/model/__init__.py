"""The photon-transfer noise model (Tisse et al. 2008, Eq. 1, in DN) and its posterior density.

Modules, one idea each:

* :mod:`~bayescap.model.ptc_model`: :class:`PTCModel`, the posterior density of one data set;
  its method groups come from :mod:`~bayescap.model.parameters` (parameters, prior, start point),
  :mod:`~bayescap.model.prediction` (the predicted observation blocks),
  :mod:`~bayescap.model.clipping` (saturation) and :mod:`~bayescap.model.likelihood` (the blocks'
  densities, the robust outlier mixture);
* :mod:`~bayescap.model.quantization` (the rounded normal's moments, the rounded offset) and
  :mod:`~bayescap.model.pixel_quantization` (those moments averaged over spread pixel means, with
  the shipped uniform-offset table);
* :mod:`~bayescap.model.terms`: which terms the data can inform;
* :mod:`~bayescap.model.threads`: threads and processes a fit may use, the split of large calls;
* :mod:`~bayescap.model.stack`: :class:`PTCModelStack`, several models in one call.

Eq. 1 in electrons has its home in :mod:`bayescap.physics.noise`.
"""

from bayescap.model.likelihood import gamma_logpdf
from bayescap.model.parameters import PARAMETER_INFO
from bayescap.model.ptc_model import PTCModel
from bayescap.model.stack import PTCModelStack
from bayescap.model.terms import ModelTerms, rows_to_fit, saturation_flags, select_terms

__all__ = [
    "PARAMETER_INFO",
    "ModelTerms",
    "PTCModel",
    "PTCModelStack",
    "gamma_logpdf",
    "rows_to_fit",
    "saturation_flags",
    "select_terms",
]
