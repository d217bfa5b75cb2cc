"""Limits in the EMVA 1288 view (:func:`bayescap.posterior.emva.emva1288_view`): the quantities that
follow a bayescap parameter the data determine only as a limit carry that limit, in the same form
as the fit JSON's parameters (``"constrained": false``, ``"limit": {"kind", "value", "level"}``,
plus ``"limit_because"``), so the datasheet's HTML, PDF and ``--json`` print the same limits.

With one exposure time the view's σ_d is ``dark_noise_e``, read noise and dark-current shot noise
combined: a measurement (not a limit), whose split is given apart as what it is, two upper limits
(``view["dark_noise_split"]``).
"""

from __future__ import annotations

__all__ = ["FOLLOWS", "attach_limits", "quantity_limits"]

_DARK = ("read_noise_e", "dark_noise_e")

#: EMVA quantities that follow a bayescap parameter the data may determine only as a limit:
#: key -> (the parameters, +1 where the quantity grows with them, -1 where it falls). The
#: quantities equal to the parameter (σ_d, DSNU1288, PRNU1288, μ_I.var) print the parameter's own
#: limit; the others the matching end of their own 95 % interval (a 97.5 % one-sided limit)
FOLLOWS = {
    "sigma_d": (_DARK, 1),
    "sigma_d_DN": (_DARK, 1),
    "sigma_y_dark": (_DARK, 1),
    "u_e_min": (_DARK, 1),
    "u_p_min": (_DARK, 1),
    "u_p_min_area": (_DARK, 1),
    "DR": (_DARK, -1),
    "DR_dB": (_DARK, -1),
    "DR_bit": (_DARK, -1),
    "DSNU1288": (("dsnu_e",), 1),
    "DSNU1288_DN": (("dsnu_e",), 1),
    "PRNU1288": (("prnu_percent",), 1),
    "u_I_var": (("dark_current_e_per_s",), 1),
}


def quantity_limits(view, parameters) -> dict:
    """{EMVA key: {kind, value, level, because}} for the quantities of ``view`` that follow a
    parameter known only as an upper limit (``parameters``: the fit JSON's ``parameters``). The
    dark-noise quantities follow the one parameter the view's σ_d is (``view["sigma_d_from"]``):
    with one exposure time that is ``dark_noise_e``, measured, so they are no limits even though
    read noise alone is one."""
    q = view["quantities"]
    out = {}
    for key, (names, sign) in FOLLOWS.items():
        it = q.get(key)
        if it is None:
            continue
        if names == _DARK and view.get("sigma_d_from"):
            names = (view["sigma_d_from"],)
        causes = [n for n in names if (parameters.get(n) or {}).get("limit", {}).get("kind") == "upper"]
        if not causes:
            continue
        own = parameters[causes[0]]["limit"]
        if it.get("bayescap") == causes[0] and own.get("value") is not None:
            out[key] = {"kind": "upper", "value": own["value"], "level": own["level"], "because": causes[0]}
        elif it.get("ci95") is not None:
            lo, hi = it["ci95"]
            out[key] = {
                "kind": "upper" if sign > 0 else "lower",
                "value": hi if sign > 0 else lo,
                "level": 0.975,
                "because": ", ".join(causes),
            }
    return out


def _split(view, parameters, t_s) -> dict | None:
    """With σ_d = dark_noise_e (one exposure time): read noise and dark current as the fit JSON gives
    them (upper limits: each is the whole dark noise attributed to it)."""
    if view.get("sigma_d_from") != "dark_noise_e":
        return None
    out = {"exposure_time_s": t_s}
    for name in ("read_noise_e", "dark_current_e_per_s"):
        s = parameters.get(name) or {}
        lim = s.get("limit")
        if lim:
            out[name] = {"kind": lim["kind"], "value": lim["value"], "level": lim["level"], "unit": s.get("unit")}
    return out


def attach_limits(view, parameters, *, exposure_time_s=None) -> dict:
    """``view`` with each limited quantity's ``limit`` (:func:`quantity_limits`), in place; and with
    one exposure time the combined σ_d named as such and ``dark_noise_split``."""
    q = view["quantities"]
    for key, lim in quantity_limits(view, parameters).items():
        q[key]["constrained"] = False
        q[key]["limit"] = {"kind": lim["kind"], "value": lim["value"], "level": lim["level"]}
        q[key]["limit_because"] = lim["because"]
    split = _split(view, parameters, exposure_time_s)
    if split is not None:
        t = f" at t = {exposure_time_s:g} s" if exposure_time_s else ""
        sd = q["sigma_d"]
        sd["name"] = "Temporal dark noise (read noise and dark-current shot noise combined)"
        sd["note"] = (
            f"one exposure time{t}: the read noise and the dark current's shot noise sqrt(μ_I·t) cannot be "
            "told apart, so σ_d is their combination sqrt(σ_0² + μ_I·t), measured with its interval (not the "
            "standard's zero-time intercept). Each part alone is an upper limit (all of the dark noise "
            "attributed to it): see dark_noise_split"
        )
        view["dark_noise_split"] = split
    return view
