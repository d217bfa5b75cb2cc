"""What is printed is what is known: the quantities the data do not determine become limits.

A parameter summary marked ``constrained: false`` keeps every key of the contract (``median``,
``ci68``, ``ci95``, ``unit``) and gains ``limit = {"kind": "upper" | "lower", "value", "level"}``;
the text report prints the limit alone (``< 629 (95 % upper limit)``), never a median with an
interval. Decided here:

* a scale parameter whose posterior reaches down to zero, or whose 95 % upper end is not far below
  its prior's (the data hardly moved it: :data:`PRIOR_DOMINATED_FRACTION`), is an upper limit;
* the summaries :meth:`FitResult.parameter_summary` already marks (read noise below 0.4 DN,
  one exposure time, no row at saturation) get their ``limit``;
* the derived quantities that depend on the dark noise (DR, TR, capacity) are lower limits when
  a dark-noise parameter is only an upper limit and matters at the scene.
"""

from __future__ import annotations

import numpy as np

__all__ = ["apply_parameter_limits", "apply_derived_limits", "LIMIT_LEVEL", "PRIOR_DOMINATED_FRACTION"]

#: the one-sided level of every limit
LIMIT_LEVEL = 0.95

#: a half-normal scale parameter whose posterior 97.5 % point is above this fraction of the prior's
#: is not constrained by the data (the prior's 97.5 % point is 2.24 scales)
PRIOR_DOMINATED_FRACTION = 0.3

#: the half-normal prior scale (``PTCModel.PRIOR`` key) of each scale parameter
_PRIOR_SCALES = {
    "read_noise_e": ("read_scale_e", 1.0),
    "dark_current_e_per_s": ("dark_current_scale_e_per_s", 1.0),
    "prnu_percent": ("prnu_scale", 100.0),
    "dsnu_e": ("dsnu_scale_e", 1.0),
}

#: the derived quantities that fall as the dark noise rises
_DARK_NOISE_DERIVED = ("dynamic_range_db", "tonal_range_bits", "capacity_bits", "capacity_bits_per_pixel")


def _limit(entry, kind, value, level=LIMIT_LEVEL):
    entry["constrained"] = False
    entry["limit"] = {"kind": kind, "value": None if value is None else float(value), "level": float(level)}


def apply_parameter_limits(result, out: dict) -> dict:
    """Add ``limit`` to the parameter summaries ``out`` (name -> summary) of ``result`` that the
    data do not determine, and mark prior-dominated scale parameters; returns ``out``."""
    m = result.model
    draws = result.summary_draws()
    for name, (key, factor) in _PRIOR_SCALES.items():
        s = out.get(name)
        if s is None or name not in draws or s.get("constrained", True) is not True:
            continue
        if name == "read_noise_e" and not m.terms.dark_current:
            continue
        bounds_key = {"read_noise_e": "read_log_bounds", "dark_current_e_per_s": "dark_current_log_bounds"}.get(name)
        bounds_key = bounds_key or {"prnu_percent": "prnu_log_bounds", "dsnu_e": "dsnu_log_bounds"}[name]
        if m.PRIOR.get(bounds_key) is not None:
            continue  # a log-uniform prior on bounds: no scale to compare with
        prior_975 = 2.2414 * factor * m.PRIOR[key]
        hi = float(np.quantile(draws[name], 0.975))
        if hi > PRIOR_DOMINATED_FRACTION * prior_975:
            s["constrained"] = False
            s["upper_limit_95"] = float(np.quantile(draws[name], LIMIT_LEVEL))
            s["note"] = (
                f"the data hardly constrain it: its 97.5 % point is {hi / prior_975:.0%} of the prior's "
                f"(half-normal, scale {factor * m.PRIOR[key]:g} {s.get('unit', '')}); the upper limit is the prior's"
            )
    for s in out.values():
        if s.get("constrained") is not False:
            continue
        if "upper_limit_95" in s:
            _limit(s, "upper", s["upper_limit_95"])
        elif "lower_bound" in s and not isinstance(s["lower_bound"], bool):
            _limit(s, "lower", s["lower_bound"], 0.975)
    return out


def _dark_noise_only_bounded(result, params: dict) -> list:
    """The dark-noise parameters that are upper limits and matter at the scene: read noise (or the
    combined dark noise), and a dark current whose 95 % upper value would add ≥ 10 % to the dark
    variance at the scene's exposure time."""
    p = result.summary_draws()
    out = []
    for name in ("read_noise_e", "dark_noise_e"):
        s = params.get(name)
        if s and s.get("limit") and name in p and (name == "dark_noise_e" or result.model.terms.dark_current):
            out.append(name)
    s = params.get("dark_current_e_per_s")
    if s and s.get("limit") and result.model.terms.dark_current and "read_noise_e" in p:
        sc = result.scene
        dc = s["limit"]["value"] * sc.exposure_time_s * sc.dark_current_factor
        if dc >= 0.1 * float(np.median(p["read_noise_e"])) ** 2:
            out.append("dark_current_e_per_s")
    return out


def apply_derived_limits(result, params: dict, out: dict) -> dict:
    """Mark the derived summaries ``out`` that follow a parameter known only as a limit: lower
    limits (the 5 % point) of DR, TR and capacity when the dark noise is only an upper limit at the
    scene, and of every flagged lower bound (no row at saturation); returns ``out``."""
    draws = result.summary_derived()
    causes = _dark_noise_only_bounded(result, params)
    for name, s in out.items():
        why = None
        if s.get("lower_bound") is True and name != "effective_pixels":  # s' = s·2^Δs: no full well in it
            why = "full_well_e"
        elif name in _DARK_NOISE_DERIVED and causes:
            why = ", ".join(causes)
        if why is None or name not in draws:
            continue
        s["limit"] = {
            "kind": "lower",
            "value": float(np.quantile(draws[name], 1.0 - LIMIT_LEVEL)),
            "level": LIMIT_LEVEL,
            "because": why,
        }
    return out
