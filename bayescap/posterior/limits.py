"""What is printed is what is known: the quantities the data do not determine become limits.

A parameter summary marked ``constrained: false`` keeps every key of the contract (``median``,
``ci68``, ``ci95``, ``unit``) and gains ``limit = {"kind": "upper" | "lower", "value", "level"}``;
the text report prints the limit alone (``< 629 (95 % upper limit)``), never a median with an
interval. Decided here:

* a scale parameter whose posterior reaches down to zero, or whose 95 % interval is nearly as wide
  as its prior's (the data hardly narrowed it: :data:`PRIOR_DOMINATED_FRACTION`), is an upper limit;
* the dark current is a detection only when the data's own tests pass
  (:mod:`bayescap.posterior.dark_current`: the posterior excludes zero at 95 %, the dark variances'
  ramp is significant in a predictive check, and the dark means do not contradict it); otherwise
  it is an upper limit, with the test that decided in its note;
* the summaries :meth:`FitResult.parameter_summary` already marks (read noise below 0.4 DN,
  one exposure time, no row at saturation) get their ``limit``;
* read noise, dark noise and DSNU measured on dark rows the ADC's zero clips (flagged
  ``dark_floor_clipping``) are lower limits where the censoring's bias exceeds their precision;
* a derived quantity that depends on a parameter known only as an upper limit (DR on the read
  noise; TR and capacity where the dark noise is above one grey level) is a lower limit: it
  follows when moving that parameter to a tenth of its value moves the quantity's median by more
  than :data:`FOLLOW_FRACTION` of its 95 % width.
"""

from __future__ import annotations

import numpy as np

from bayescap.physics.capacity import mtf_loss_bits

__all__ = [
    "apply_parameter_limits",
    "apply_derived_limits",
    "LIMIT_LEVEL",
    "PRIOR_DOMINATED_FRACTION",
    "FOLLOW_FRACTION",
]

#: the one-sided level of every limit
LIMIT_LEVEL = 0.95

#: a half-normal scale parameter whose posterior 95 % interval is wider than this fraction of the
#: prior's (0.03–2.24 scales) is not constrained by the data
PRIOR_DOMINATED_FRACTION = 0.5

#: a derived quantity follows a parameter known only as an upper limit when the parameter at a
#: tenth of its value moves the quantity's median by more than this fraction of its 95 % width
FOLLOW_FRACTION = 0.5

#: draws the dependence of the derived quantities is checked on
_FOLLOW_DRAWS = 2000

#: each scale parameter's half-normal prior: its scale's ``PTCModel.PRIOR`` key, the factor from
#: the prior's unit to the reported one, and the key of the log-uniform bounds that replace it
_PRIOR_SCALES = {
    "read_noise_e": ("read_scale_e", 1.0, "read_log_bounds"),
    "dark_current_e_per_s": ("dark_current_scale_e_per_s", 1.0, "dark_current_log_bounds"),
    "prnu_percent": ("prnu_scale", 100.0, "prnu_log_bounds"),
    "dsnu_e": ("dsnu_scale_e", 1.0, "dsnu_log_bounds"),
}


def _limit(entry, kind, value, level=LIMIT_LEVEL):
    entry["constrained"] = False
    entry["limit"] = {"kind": kind, "value": None if value is None else float(value), "level": float(level)}


def clipped_variance_fraction(margin_sd):
    """Var(max(X, 0)) / Var(X) for X normal with its mean ``margin_sd`` sd above 0: how much the ADC's
    zero shrinks a dark variance when it clips the low tail (0.989 at 2.5 sd, 0.960 at 2, 0.553 at 0.5)."""
    from scipy.special import ndtr  # the normal cdf, without importing scipy.stats

    m = float(margin_sd)
    p, q = float(ndtr(m)), float(np.exp(-0.5 * m * m) / np.sqrt(2.0 * np.pi))
    mean = m * p + q  # E[max(X, 0)]
    second = (m * m + 1.0) * p + m * q  # E[max(X, 0)²]
    return max(second - mean * mean, 0.0)


def _floor_clipped_limits(result, out, draws):
    """Read noise, dark noise and DSNU measured on dark rows the ADC's zero clips are biased low by
    the censoring (:meth:`ChecksMixin._check_dark_floor`): where that bias exceeds 5 % or half of the
    parameter's 95 % half-width, the parameter is a lower limit (its 2.5 % point), never an interval."""
    margin = getattr(result, "dark_floor_margin_sd", None)
    if not result.flags.get("dark_floor_clipping") or margin is None:
        return
    shrink = 1.0 - np.sqrt(clipped_variance_fraction(margin))  # fractional bias of a noise sd
    for name in _FLOOR_BIASED:
        s = out.get(name)
        if s is None or name not in draws:
            continue
        lo, med, hi = np.quantile(draws[name], [0.025, 0.5, 0.975])
        if shrink <= 0.05 and shrink * med <= 0.25 * (hi - lo):
            continue  # a bias under 5 % and small against the interval: the interval stands
        s.pop("upper_limit_95", None)
        s.pop("limit", None)
        s["constrained"] = False
        s["lower_bound"] = float(lo)
        s["note"] = (
            f"the ADC's zero clips the darkest pixels (dark mean {margin:.1f} sd above 0 DN): the dark "
            f"variances it is measured on shrink by ~{1 - clipped_variance_fraction(margin):.0%}, so it is "
            "a lower limit only (raise the black level, as EMVA 1288 requires)"
        )


def _dark_current_limit(result, out, draws):
    """Decide the dark current's detection by :func:`~bayescap.posterior.dark_current.dark_current_evidence`
    (in place of the generic rule of :meth:`FitResult.parameter_summary`, both ways)."""
    from bayescap.posterior.dark_current import dark_current_evidence

    s = out.get("dark_current_e_per_s")
    if s is None or "dark_current_e_per_s" not in draws or not result.model.terms.dark_current:
        return
    ev = getattr(result, "_dark_evidence", None)
    if ev is None:
        ev = dark_current_evidence(result)
        result._dark_evidence = ev
    if ev is None:
        return
    s["detection"] = {
        "zero_likelihood_ratio": ev["zero_likelihood_ratio"],
        "ramp_z": ev["ramp_z"],
        "mean_ramp_e_per_s": ev["mean_d_e_per_s"],
        "mean_ramp_sd_e_per_s": ev["mean_d_sd_e_per_s"],
    }
    if ev["detected"] is None:
        return  # a log-uniform prior on bounds: the generic rule of parameter_summary stands
    if ev["detected"]:
        s["constrained"] = True
        s.pop("upper_limit_95", None)
        s.pop("note", None)
        return
    s["constrained"] = False
    s["upper_limit_95"] = float(np.quantile(draws["dark_current_e_per_s"], LIMIT_LEVEL))
    s["note"] = "an upper limit, not a detection: " + ev["why"]
    if ev["mean_d_e_per_s"] is not None:
        s["note"] += (
            f"; the dark means rise by {ev['mean_d_e_per_s']:.3g} ± {ev['mean_d_sd_e_per_s']:.2g} e-/s "
            "(EMVA 1288's dark current from the means; a black level that drifts with the exposure time moves "
            "them too)"
        )


#: the parameters measured on the dark rows' spread, biased low when the ADC's zero clips it
_FLOOR_BIASED = ("read_noise_e", "dark_noise_e", "dsnu_e")


def apply_parameter_limits(result, out: dict) -> dict:
    """Add ``limit`` to the parameter summaries ``out`` (name -> summary) of ``result`` that the
    data do not determine, and mark prior-dominated scale parameters; returns ``out``."""
    m = result.model
    draws = result.summary_draws()
    _floor_clipped_limits(result, out, draws)
    _dark_current_limit(result, out, draws)
    for name, (key, factor, bounds_key) in _PRIOR_SCALES.items():
        s = out.get(name)
        if s is None or name not in draws or s.get("constrained", True) is not True:
            continue  # absent, or already a limit (with one exposure time, read noise is)
        if m.PRIOR.get(bounds_key) is not None:
            continue  # a log-uniform prior on bounds: no scale to compare with
        prior_width = (2.2414 - 0.03134) * factor * m.PRIOR[key]  # the half-normal's 2.5–97.5 % points
        lo, hi = np.quantile(draws[name], [0.025, 0.975])
        if hi - lo > PRIOR_DOMINATED_FRACTION * prior_width:
            s["constrained"] = False
            s["upper_limit_95"] = float(np.quantile(draws[name], LIMIT_LEVEL))
            s["note"] = (
                f"the data hardly constrain it: its 95 % interval is {(hi - lo) / prior_width:.0%} as wide as "
                f"the prior's (half-normal, scale {factor * m.PRIOR[key]:g} {s.get('unit', '')})"
            )
    for s in out.values():
        if s.get("constrained") is not False:
            continue
        if "upper_limit_95" in s:
            _limit(s, "upper", s["upper_limit_95"])
        elif "lower_bound" in s and not isinstance(s["lower_bound"], bool):
            _limit(s, "lower", s["lower_bound"], 0.975)
    return out


#: the parameters whose upper limit the derived quantities can follow
_UPPER_LIMITED = ("read_noise_e", "dark_noise_e", "dark_current_e_per_s", "dsnu_e")


def _followers(result, params: dict, names) -> dict:
    """{derived quantity: the parameters known only as upper limits that it depends on}: a quantity
    depends on a parameter when that parameter at a tenth of its value (each draw) moves the
    quantity's median by more than :data:`FOLLOW_FRACTION` of its 95 % width."""
    causes = [n for n in _UPPER_LIMITED if (params.get(n) or {}).get("limit", {}).get("kind") == "upper"]
    if not causes:
        return {}
    p = result.summary_draws()
    n = next(iter(p.values())).size
    take = np.linspace(0, n - 1, min(n, _FOLLOW_DRAWS)).round().astype(int)
    p = {k: np.asarray(v)[take] for k, v in p.items()}
    if not mtf_loss_bits(result.mtf, draws=True).has_draws:  # (each draw's own: the result's)
        base = {k: np.asarray(v, float)[take] for k, v in result.summary_derived().items() if np.size(v) == n}
    else:
        base = _derived_of(result, p)
    out = {}
    for c in causes:
        # (without dark pairs the intercept's dark_noise_e draws are reported as read_noise_e)
        src = "dark_noise_e" if c == "read_noise_e" and c not in p and "dark_noise_e" in p else c
        if src not in p:
            continue
        # the linearity error is a function of the response shape draws alone (DerivedMixin._linearity_error):
        # no noise parameter moves it, so it is not computed again here (and follows none)
        moved = _derived_of(result, {**p, src: 0.1 * p[src]}, linearity=False)
        for name in names:
            if name not in base or name not in moved:
                continue
            lo, med, hi = np.quantile(base[name], [0.025, 0.5, 0.975])
            shift = abs(float(np.median(moved[name])) - float(med))
            if shift > FOLLOW_FRACTION * max(float(hi - lo), 1e-12 * abs(float(med))):
                out.setdefault(name, []).append(c)
    return out


def _derived_of(result, p: dict, linearity: bool = True) -> dict:
    """The derived quantities of the physical draws ``p`` at ``result``'s scene, MTF and metadata
    (without the linearity error when not ``linearity``)."""
    tmp = type(result)(
        model=result.model,
        chains=None,
        metadata=result.metadata,
        scene=result.scene,
        mtf=result.mtf,
        seed=result.seed,
        quality="",
        draws=p,
    )
    with np.errstate(all="ignore"):
        tmp._derive(linearity=linearity)
    return {k: np.asarray(v, float) for k, v in tmp.derived.items() if np.size(v) == next(iter(p.values())).size}


def apply_derived_limits(result, params: dict, out: dict) -> dict:
    """Mark the derived summaries ``out`` that follow a parameter known only as a limit: lower
    limits (the 5 % point) of the quantities that depend on a parameter known only as an upper
    limit (:func:`_followers`), and of every flagged lower bound (no row at saturation); returns
    ``out``."""
    draws = result.summary_derived()
    follows = _followers(result, params, [n for n in out if n not in ("mtf_loss_bits", "effective_pixels")])
    for name, s in out.items():
        why = None
        if s.get("lower_bound") is True and name != "effective_pixels":  # s' = s·2^Δs: no full well in it
            why = "full_well_e"
        elif name in follows:
            why = ", ".join(follows[name])
        if why is None or name not in draws:
            continue
        s["limit"] = {
            "kind": "lower",
            "value": float(np.quantile(draws[name], 1.0 - LIMIT_LEVEL)),
            "level": LIMIT_LEVEL,
            "because": why,
        }
    return out
