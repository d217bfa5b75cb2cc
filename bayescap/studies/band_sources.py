"""What a band carries: a fitted sensor's posterior draws widened by other named sources.

A fit's posterior draws carry the **measurement** uncertainty only: with a long photon-transfer
series it is a fraction of a percent, and the Fig. 8(a) bands are too narrow to see. Two other
sources can be multiplied into the draws, each named in the result:

* ``table1_range_factors``: for a Table 2 stand-in simulated at Table 1's point values (full well
  at mid-range, PRNU at its bound: ``data/benchmark/README.md``), the range Table 1 prints for the
  pitch, i.e. what the paper's sensor could have been: full well uniform in [min, max] (as a
  factor on the mid-range value), PRNU uniform in [0, bound] (a factor on the bound). Between
  Table 1 pitches the range is interpolated linearly, as the stand-in's values are;
* ``unit_to_unit_factors``: a log-normal spread per parameter with the coefficients of variation
  you give (none is published for these sensors, so there is no default).

:func:`widened` returns a shallow copy of the result whose ``draws`` (thinned by ``idx``) are
multiplied by the factors, and the exposure calibration with the QE factor applied, for
:func:`bayescap.studies.exposure.tonal_range_at_exposure` and
:func:`~bayescap.studies.exposure.snr_at_exposure`. The clip charge is capped at the ADC range
(``(2^bits − 1 − black) · K``) when the metadata give the bit depth.
"""

from __future__ import annotations

import copy

import numpy as np

from bayescap.physics.table1 import load_table1
from bayescap.studies.exposure import ExposureCalibration

__all__ = ["table1_range_factors", "unit_to_unit_factors", "widened"]

#: result draw name -> what the factor multiplies
FACTOR_NAMES = ("full_well_e", "prnu_percent", "quantum_efficiency", "read_noise_e", "dark_current_e_per_s")


def table1_range_factors(pitch_um: float, n: int, *, seed=0) -> dict:
    """Factors on a stand-in's full well (mid-range) and PRNU (bound) spanning Table 1's ranges."""
    rows = sorted(load_table1(), key=lambda r: r.pitch_um)
    p = [r.pitch_um for r in rows]
    lo = float(np.interp(pitch_um, p, [r.full_well_min_e for r in rows]))
    hi = float(np.interp(pitch_um, p, [r.full_well_max_e for r in rows]))
    rng = np.random.default_rng(seed)
    u = rng.random((2, n))
    mid = 0.5 * (lo + hi)
    return {"full_well_e": (lo + (hi - lo) * u[0]) / mid, "prnu_percent": u[1]}


def unit_to_unit_factors(cv: dict, n: int, *, seed=0) -> dict:
    """Log-normal factors of mean 1 with coefficient of variation ``cv[name]`` per parameter."""
    unknown = set(cv) - set(FACTOR_NAMES)
    if unknown:
        raise ValueError(f"no unit-to-unit spread for {sorted(unknown)}; choose from {FACTOR_NAMES}")
    rng = np.random.default_rng(seed)
    out = {}
    for name, c in cv.items():
        s2 = np.log1p(float(c) ** 2)
        out[name] = np.exp(rng.normal(-0.5 * s2, np.sqrt(s2), n))
    return out


def widened(result, calibration: ExposureCalibration | None, factors: dict, idx):
    """``(result copy, calibration)`` with the draws at ``idx`` multiplied by ``factors`` (arrays of
    ``len(idx)``; several factor dicts can be merged by multiplying them beforehand)."""
    idx = np.asarray(idx)
    draws = {k: np.asarray(v)[idx].copy() for k, v in result.draws.items()}
    for name, f in factors.items():
        if name not in FACTOR_NAMES:
            raise ValueError(f"unknown factor {name!r}; choose from {FACTOR_NAMES}")
        if name in draws:
            draws[name] = draws[name] * np.asarray(f, float)
    md = result.metadata
    if "full_well_e" in draws and md.get("adc_bits") not in (None, ""):
        top = (2.0 ** int(md["adc_bits"]) - 1 - float(md.get("black_level_dn") or 0.0)) * draws[
            "conversion_gain_e_per_dn"
        ]
        draws["full_well_e"] = np.minimum(draws["full_well_e"], top)
    out = copy.copy(result)
    out.draws = draws
    cal = None
    if calibration is not None:
        sens = np.asarray(calibration.sensitivity_e_per_lux_s)[idx] * np.asarray(factors.get("quantum_efficiency", 1.0))
        cal = ExposureCalibration(sens, calibration.source + " (widened: " + ", ".join(sorted(factors)) + ")")
    return out, cal
