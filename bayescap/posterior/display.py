"""Short displays of a fit result: the one-line ``repr`` and the notebook's HTML table (parameter,
median, 95 % interval, unit), instead of the arrays a dataclass ``repr`` would print."""

from __future__ import annotations

import html

import numpy as np

from bayescap.posterior.summary import DERIVED_ORDER, PARAMETER_ORDER

__all__ = ["short_repr", "html_table"]


def _g(x, digits=4):
    return "—" if x is None else f"{x:.{digits}g}"


def _median_ci(x):
    lo, med, hi = np.quantile(np.asarray(x, float), [0.025, 0.5, 0.975])
    return f"{_g(med)} [{_g(lo)}, {_g(hi)}]"


def _limit_text(s) -> str:
    """``< 629 (95 % upper limit)`` for a summary that carries a limit."""
    lim = s["limit"]
    return f"{'<' if lim['kind'] == 'upper' else '>'} {_g(lim['value'])} ({100 * lim['level']:g} % {lim['kind']} limit)"


def _name(result):
    """The sensor's name (metadata), else the input file's."""
    md = result.metadata or {}
    return md.get("sensor") or getattr(getattr(result.model, "data", None), "source", "")


def short_repr(result) -> str:
    """``FitResult(sensor, quality, converged, K, read noise, capacity [95 % interval])``."""
    parts = [f"sensor={_name(result)!r}", f"quality={result.quality!r}"]
    if "converged" in result.diag:
        parts.append(f"converged={bool(result.diag['converged'])}")
    if not result.draws:
        return "FitResult(" + ", ".join(parts) + ", no draws)"
    ps = result.parameter_summary()
    ds = result.derived_summary(ps)
    p = result.summary_draws()  # stranded walkers left out

    def value(s, x):
        return _limit_text(s) if s.get("limit") else _median_ci(x)

    parts.append(f"K={_median_ci(p['conversion_gain_e_per_dn'])} e-/DN")
    rn = "read_noise_e" if "read_noise_e" in p else "dark_noise_e" if "dark_noise_e" in p else None
    if rn:
        key = rn if rn in ps else "read_noise_e"  # (without dark pairs the intercept is reported as read noise)
        parts.append(f"{key.removesuffix('_e')}={value(ps[key], p[rn])} e-")
    for cap, unit in (("capacity_bits", "bits"), ("capacity_bits_per_pixel", "bits/pixel")):
        if cap in ds:
            parts.append(f"capacity={value(ds[cap], result.summary_derived()[cap])} {unit} (95 %)")
            break
    return "FitResult(" + ", ".join(parts) + ")"


def html_table(result) -> str:
    """An HTML table of the physical parameters and derived quantities: median, 95 % interval, unit."""
    ps = result.parameter_summary()
    d = {"parameters": ps, "derived": result.derived_summary(ps)}
    dg = result.diag
    conv = {True: "converged", False: "NOT CONVERGED"}.get(dg.get("converged"), "")
    head = html.escape(f"{_name(result)}: quality {result.quality}" + (f", {conv}" if conv else ""))
    if dg.get("method") == "laplace-is":
        sampler = f"Laplace–IS, Pareto k̂ {_g(dg.get('khat'), 3)}, {dg.get('n_draws')} draws"
    elif dg:
        sampler = (
            f"emcee, R-hat max {_g(dg.get('rhat_max'), 5)}, ESS min {_g(dg.get('ess_min'), 4)}; "
            f"{dg.get('n_ensembles')} ensembles × {dg.get('n_walkers')} walkers × {dg.get('n_steps')} steps"
        )
    else:
        sampler = ""
    rows = []
    for block, order in (("parameters", PARAMETER_ORDER), ("derived", DERIVED_ORDER)):
        s = d[block]
        for n in order + [k for k in s if k not in order]:
            if n not in s:
                continue
            v = s[n]
            if v.get("limit"):
                rows.append(
                    f"<tr><td>{html.escape(n)}</td><td>—</td><td>{html.escape(_limit_text(v))}</td>"
                    f"<td>{html.escape(v.get('unit', ''))}</td></tr>"
                )
                continue
            lo, hi = v["ci95"]
            tag = ""
            if v.get("constrained") is False:
                tag = " (upper limit)" if "upper_limit_95" in v else " (lower bound)" if "lower_bound" in v else ""
            elif v.get("lower_bound") is True:
                tag = " (lower bound)"
            rows.append(
                f"<tr><td>{html.escape(n)}</td><td>{_g(v['median'])}</td>"
                f"<td>[{_g(lo)}, {_g(hi)}]{tag}</td><td>{html.escape(v.get('unit', ''))}</td></tr>"
            )
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in result.notes)
    return (
        f"<div><p><b>{head}</b><br>{html.escape(sampler)}</p>"
        "<table><thead><tr><th>quantity</th><th>median</th><th>95 % interval</th><th>unit</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>" + (f"<ul>{notes}</ul>" if notes else "") + "</div>"
    )
