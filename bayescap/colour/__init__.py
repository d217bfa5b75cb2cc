"""Colour: colour sensitivity, colour-correction matrices, colour capacities and camera scores.

The paper's future work ("evaluating colour sensitivity instead of tonal range"): the four CFA
channels' noise posteriors → colour sensitivity (DxOMark's definition) with intervals.
Submodules: :mod:`~bayescap.colour.sensitivity` (CS), :mod:`~bayescap.colour.ccm` (matrices and
their noise cost), :mod:`~bayescap.colour.capacity` (colour capacities),
:mod:`~bayescap.colour.scores` (colour depth, dynamic range, low-light ISO).
"""

from bayescap.colour.sensitivity import ColourSensitivity, colour_sensitivity, colour_sensitivity_bits

__all__ = ["ColourSensitivity", "colour_sensitivity", "colour_sensitivity_bits"]
