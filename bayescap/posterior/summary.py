"""Summaries of posterior draws (median, 68 % and 95 % intervals), the derived quantities'
units and meaning, JSON cleaning, and what to rerun an unconverged fit with."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DERIVED_INFO", "PARAMETER_ORDER", "DERIVED_ORDER", "summarize", "rerun_advice", "json_safe"]

DERIVED_INFO = {
    "tonal_range_bits": ("bits", "b' = log2 TR (Eq. 7), 8-bit-equivalent grey scale"),
    "dynamic_range_db": ("dB", "DR (Eq. 2)"),
    "snr_max_db": ("dB", "SNR at the largest non-saturating signal (Eq. 1)"),
    "mtf_loss_bits": ("bits", "Δs (Eq. 9)"),
    "effective_pixels": ("pixels", "s' = s·2^Δs"),
    "capacity_bits": ("bits", "C = s'·b' (Eq. 6)"),
    "linearity_error_percent": ("%", "EMVA 1288 linearity error LE of the fitted response (5–95 % of saturation)"),
    "emva1288_gain_e_per_dn": (
        "e-/DN",
        "EMVA 1288's gain: its straight line through the fitted PTC up to 70 % of saturation",
    ),
}

#: the order the reports list the physical parameters and derived quantities in
PARAMETER_ORDER = [
    "conversion_gain_e_per_dn",
    "read_noise_e",
    "dark_noise_e",
    "dark_current_e_per_s",
    "full_well_e",
    "quantum_efficiency",
    "prnu_percent",
    "dsnu_e",
    "clip_spread_dn",
    "variance_discrepancy",
    "mean_discrepancy",
    "response_nonlinearity",
    "brighter_fatter_a00_per_e",
    "pixel_offset_spread_dn",
]
DERIVED_ORDER = [
    "snr_max_db",
    "dynamic_range_db",
    "tonal_range_bits",
    "mtf_loss_bits",
    "effective_pixels",
    "capacity_bits",
    "capacity_bits_per_pixel",
    "linearity_error_percent",
    "emva1288_gain_e_per_dn",
]


def _q(x, qs):
    return [float(v) for v in np.quantile(x, qs)]


def summarize(x, unit="", constrained=True, **extra):
    """Median, 68 % and 95 % equal-tailed intervals of a 1-D array of draws."""
    x = np.asarray(x, float).ravel()
    q = _q(x, [0.025, 0.16, 0.5, 0.84, 0.975])
    out = {"median": q[2], "ci68": [q[1], q[3]], "ci95": [q[0], q[4]], "unit": unit, "constrained": bool(constrained)}
    out.update(extra)
    return out


def _json_float(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def rerun_advice(quality) -> str:
    """What to rerun an unconverged MCMC fit of preset ``quality`` with (a preset name, or anything
    else for custom settings): the next preset up; for ``accurate`` (already the longest preset) a
    longer run, which the command line has no flag for."""
    return {"fast": "--quality standard or accurate", "standard": "--quality accurate"}.get(
        quality,
        "a longer run (from Python: bayescap.fit(..., quality=replace(QUALITY_PRESETS['accurate'], "
        "max_rounds=40)), with dataclasses.replace and bayescap.inference.QUALITY_PRESETS)",
    )


def json_safe(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _json_float(obj)
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    return obj
