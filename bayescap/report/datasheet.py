"""A one-page EMVA 1288 datasheet of a fit: the standard's quantities with their 95 % credible
intervals and the standard's recipe beside them (:func:`bayescap.posterior.emva.emva1288_view`),
the photon-transfer curve and the SNR curve as embedded PNGs, the sensor's metadata and the
fit's convergence line, in one self-contained HTML file (docs/emva1288.md).

The figures are :class:`matplotlib.figure.Figure` objects drawn without pyplot and without
touching matplotlib's backend.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from bayescap._version import __version__
from bayescap.io.atomic import atomic_write_text
from bayescap.posterior.emva import S2Q, _Sweep, emva1288_view
from bayescap.report.colour_section import colour_section_html

__all__ = ["datasheet_html", "write_datasheet", "ptc_figure", "snr_figure", "emva_limits"]

#: the rows of the table, in the order a datasheet lists them
TABLE_ORDER = (
    "QE",
    "R",
    "K",
    "inverse_K",
    "sigma_d",
    "sigma_y_dark",
    "u_p_min",
    "u_p_min_area",
    "u_e_min",
    "u_p_sat",
    "u_e_sat",
    "u_e_sat_model",
    "SNR_max",
    "SNR_max_dB",
    "SNR_max_bit",
    "inverse_SNR_max",
    "DR",
    "DR_dB",
    "DR_bit",
    "LE_min",
    "LE_max",
    "LE",
    "u_I_mean",
    "u_I_var",
    "DSNU1288",
    "DSNU1288_DN",
    "PRNU1288",
)
N_CURVE_DRAWS = 400

#: EMVA quantities that follow a bayescap parameter the data may determine only as a limit:
#: key -> (the parameters, +1 where the quantity grows with them, -1 where it falls). The
#: quantities equal to the parameter (σ_d, DSNU1288, PRNU1288, μ_I.var) print the parameter's own
#: limit; the others the matching end of their own 95 % interval (a 97.5 % one-sided limit)
_FOLLOWS = {
    "sigma_d": (("read_noise_e", "dark_noise_e"), 1),
    "sigma_d_DN": (("read_noise_e", "dark_noise_e"), 1),
    "sigma_y_dark": (("read_noise_e", "dark_noise_e"), 1),
    "u_e_min": (("read_noise_e", "dark_noise_e"), 1),
    "u_p_min": (("read_noise_e", "dark_noise_e"), 1),
    "u_p_min_area": (("read_noise_e", "dark_noise_e"), 1),
    "DR": (("read_noise_e", "dark_noise_e"), -1),
    "DR_dB": (("read_noise_e", "dark_noise_e"), -1),
    "DR_bit": (("read_noise_e", "dark_noise_e"), -1),
    "DSNU1288": (("dsnu_e",), 1),
    "DSNU1288_DN": (("dsnu_e",), 1),
    "PRNU1288": (("prnu_percent",), 1),
    "u_I_var": (("dark_current_e_per_s",), 1),
}


def emva_limits(view, parameters) -> dict:
    """{EMVA key: {kind, value, level, because}} for the quantities of ``view`` that follow a
    parameter known only as an upper limit (``parameters``: ``result.to_dict()["parameters"]``,
    whose limits :mod:`bayescap.posterior.limits` sets). The datasheet prints these as limits
    alone, as the text report does."""
    q = view["quantities"]
    out = {}
    for key, (names, sign) in _FOLLOWS.items():
        it = q.get(key)
        if it is None:
            continue
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


def _limit_text(lim, unit) -> str:
    """``< 136.7 e-/s (95 % upper limit)``."""
    sign = "<" if lim["kind"] == "upper" else ">"
    return f"{sign} {_fmt(lim['value'])}{' ' + unit if unit else ''} ({100 * lim['level']:g} % {lim['kind']} limit)"


def _fmt(x):
    if x is None:
        return "–"
    x = float(x)
    if not math.isfinite(x):
        return "–"
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 1e5 or a < 1e-3:
        return f"{x:.3e}"
    digits = max(0, 3 - int(math.floor(math.log10(a))))
    return f"{x:.{min(digits, 4)}f}"


def _png(fig) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def ptc_figure(result, view=None, ax=None):
    """The standard's photon-transfer plot: σ²_y − σ²_y.dark against μ_y − μ_y.dark (DN) for the
    sweep rows, the sensitivity rows (≤ 70 % of saturation) apart, with the line of slope K
    (posterior median, 95 % band) and the saturation point. ``ax``: draw into it (its figure is
    returned) instead of a figure of its own."""
    from matplotlib.figure import Figure

    view = emva1288_view(result) if view is None else view
    sw = _Sweep(result.model.data)
    x, y = sw.signal, sw.s2_y - sw.s2_dark
    K = 1.0 / np.asarray(result.draws["conversion_gain_e_per_dn"], float)
    own = ax is None  # a figure of its own, or an axes of the caller's (the PDF page)
    if own:
        ax = Figure(figsize=(4.6, 3.3), dpi=90).add_subplot(1, 1, 1)
    fig = ax.figure
    ax.plot(x[~sw.sens], y[~sw.sens], "o", ms=3, mfc="none", color="0.45", label="rows")
    ax.plot(x[sw.sens], y[sw.sens], "o", ms=3, color="C0", label="fit range of the standard (≤ 70 %)")
    xs = np.linspace(0.0, float(np.max(x)), 50)
    lo, med, hi = np.quantile(K, [0.025, 0.5, 0.975])
    ax.fill_between(xs, lo * xs, hi * xs, color="C1", alpha=0.3, lw=0)
    ax.plot(xs, med * xs, "-", color="C1", lw=1, label=f"K = {med:.4g} DN/e⁻ (posterior)")
    if sw.saturated:
        ax.axvline(x[sw.i_sat], color="C3", lw=0.8, ls="--", label="saturation (variance maximum)")
    ax.set_xlabel("μ_y − μ_y.dark (DN)")
    ax.set_ylabel("σ²_y − σ²_y.dark (DN²)")
    ax.set_title("Photon transfer", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    if own:
        fig.tight_layout()
    return fig


def snr_figure(result, view=None, limits=None, ax=None):
    """The standard's SNR plot: measured SNR = (μ_y − μ_y.dark)/σ_y of the sweep rows against the
    photons per pixel (electrons without photons_per_pixel), the linear model's temporal SNR
    η μ_p / sqrt(σ_d² + σ_q²/K² + η μ_p) (posterior median, 95 % band), the ideal sqrt(μ_p), and
    μp.min and μp.sat (at their limit where they are one). ``ax`` as for :func:`ptc_figure`."""
    from matplotlib.figure import Figure

    view = emva1288_view(result) if view is None else view
    q = view["quantities"]
    sw = _Sweep(result.model.data)
    p = result.draws
    idx = result.thin_index(N_CURVE_DRAWS)
    k = np.asarray(p["conversion_gain_e_per_dn"], float)[idx][:, None]
    sig_d = np.asarray(p["read_noise_e"] if result.model.terms.dark_current else p["dark_noise_e"], float)[idx][:, None]
    photons = sw.mu_p is not None and "quantum_efficiency" in p
    eta = np.asarray(p["quantum_efficiency"], float)[idx][:, None] if photons else np.ones_like(k)
    xdata = sw.mu_p if photons else sw.signal * float(np.median(k))
    snr_data = sw.signal / np.sqrt(np.maximum(sw.s2_y, 1e-12))
    good = (xdata > 0) & (sw.s2_y > 0)
    if sw.saturated:  # beyond the variance maximum the clipped rows' SNR means nothing
        good &= np.arange(xdata.size) <= sw.i_sat
    top = float(np.max(xdata[good])) * 1.3
    bottom = max(0.5, float(np.min(xdata[good])) / 10.0)
    xs = np.geomspace(bottom, top, 120)[None, :]
    snr = eta * xs / np.sqrt(sig_d**2 + S2Q * k**2 + eta * xs)
    lo, med, hi = np.quantile(snr, [0.025, 0.5, 0.975], axis=0)
    own = ax is None  # a figure of its own, or an axes of the caller's (the PDF page)
    if own:
        ax = Figure(figsize=(4.6, 3.3), dpi=90).add_subplot(1, 1, 1)
    fig = ax.figure
    ax.fill_between(xs[0], lo, hi, color="C1", alpha=0.3, lw=0)
    ax.plot(xs[0], med, "-", color="C1", lw=1, label="linear model (posterior)")
    ax.plot(xs[0], np.sqrt(np.median(eta) * xs[0]), ":", color="0.3", lw=1, label="ideal sqrt(η μ_p)")
    ax.plot(xdata[good], snr_data[good], "o", ms=3, color="C0", label="rows")
    limits = emva_limits(view, result.to_dict()["parameters"]) if limits is None else limits
    for key, label, style in (("u_p_min", "μp.min", "-."), ("u_p_sat", "μp.sat", "--")):
        lim = limits.get(key)
        if photons and lim and lim.get("value"):  # a limit is drawn as its limit, never as a median
            sign = "<" if lim["kind"] == "upper" else ">"
            ax.axvline(lim["value"], color="C3", lw=0.8, ls=style, label=f"{label} {sign} this ({lim['kind']} limit)")
        elif photons and q.get(key, {}).get("median"):
            ax.axvline(q[key]["median"], color="C3", lw=0.8, ls=style, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("irradiation μ_p (photons/pixel)" if photons else "signal μ_e (e⁻)")
    ax.set_ylabel("SNR")
    ax.set_title("Signal-to-noise ratio", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3, which="both")
    if own:
        fig.tight_layout()
    return fig


def _convergence_line(result) -> str:
    d = result.diag or {}
    parts = [f"method {d.get('method', '?')}", f"quality {result.quality}", f"seed {result.seed}"]
    if d.get("rhat_max") is not None:
        parts.append(f"R̂ max {float(d['rhat_max']):.3f}")
    if d.get("ess_min") is not None:
        parts.append(f"ESS min {float(d['ess_min']):.0f}")
    ok = d.get("converged")
    head = "converged" if ok else "NOT CONVERGED"
    failed = d.get("failed_checks") or []
    tail = f" (failed: {'; '.join(map(str, failed))})" if failed and not ok else ""
    return f"{head}: " + ", ".join(parts) + tail


_CSS = """
body{font-family:Helvetica,Arial,sans-serif;font-size:11px;margin:14px;max-width:1000px}
h1{font-size:16px;margin:0 0 2px 0} .sub{color:#555;margin-bottom:8px}
table{border-collapse:collapse} td,th{border-bottom:1px solid #ddd;padding:2px 5px;vertical-align:top}
th{background:#eee;text-align:left} td.n{text-align:right;white-space:nowrap;font-variant-numeric:tabular-nums}
td.note{color:#555;font-size:9px;max-width:300px} .grid{display:flex;gap:10px;align-items:flex-start}
.meta td{border:none;padding:0 6px 0 0} .bad{color:#b00;font-weight:bold} img{max-width:100%}
@media print{body{margin:0} @page{size:A4 landscape;margin:8mm}}
"""


def datasheet_html(result, *, view=None, title=None, colour=None) -> str:
    """The one-page datasheet of ``result`` as a self-contained HTML string."""
    view = emva1288_view(result) if view is None else view
    q = view["quantities"]
    meta = dict(result.metadata)
    name = title or meta.get("sensor") or Path(str(result.model.data.source)).stem
    e = html.escape
    limits = emva_limits(view, result.to_dict()["parameters"])
    rows = []
    for key in TABLE_ORDER:
        if key not in q:
            continue
        it = q[key]
        ci = it["ci95"]
        if key in limits:  # the limit alone, in the median and interval columns together
            lim = limits[key]
            value = f"<td class=n colspan=2>{e(_limit_text(lim, it['unit'] or ''))}</td>"
            note = f"data determine it only as a limit (follows {lim['because']}). {it['note'] or ''}"
        else:
            ci_s = "–" if ci is None else f"{_fmt(ci[0])} – {_fmt(ci[1])}"
            value = f"<td class=n>{_fmt(it['median'])}</td><td class=n>{ci_s}</td>"
            note = it["note"] or ""
        rows.append(
            "<tr>"
            f"<td>{e(it['name'])}</td><td>{e(it['symbol'])}</td><td>{e(it['unit'] or '')}</td>"
            f"{value}<td class=n>{_fmt(it['recipe'])}</td>"
            f"<td>{e(it['bayescap'] or '')}</td><td class=note>{e(note)}</td>"
            "</tr>"
        )
    table = (
        "<table id=emva-table><tr><th>Quantity</th><th>Symbol</th><th>Unit</th><th>Median</th>"
        "<th>95 % interval</th><th>Standard's recipe</th><th>bayescap</th><th>Note</th></tr>"
        + "".join(rows)
        + "</table>"
    )
    meta_rows = "".join(f"<tr><td>{e(str(k))}</td><td>{e(str(v))}</td></tr>" for k, v in meta.items() if v is not None)
    sat = view["saturation"]
    spatial = view.get("spatial_row")
    facts = [
        f"{sat['sweep_rows']} sweep rows; saturation (variance maximum) at row index {sat['row_index']} "
        f"({sat['signal_dn']:.1f} DN above dark); {sat['sensitivity_rows']} rows ≤ 70 % for K, η and R; "
        f"{sat['linearity_rows']} rows in 5–95 % for LE",
    ]
    if spatial:
        facts.append(
            f"spatial stack: row {spatial['row']}, {spatial['n_pixels']} pixels × {spatial['n_frames']} frames "
            "(DSNU1288 and PRNU1288 describe these pixels only)"
        )
    facts += list(view.get("notes", []))
    conv = _convergence_line(result)
    conv_cls = "" if (result.diag or {}).get("converged") else " class=bad"
    ptc = _png(ptc_figure(result, view))
    snr = _png(snr_figure(result, view, limits))
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>{e(str(name))}: EMVA 1288 datasheet</title><style>{_CSS}</style></head><body>"
        f"<h1>{e(str(name))}</h1>"
        f"<div class=sub>{e(view['standard'])} view of a bayescap {e(__version__)} fit of "
        f"{e(str(result.model.data.source))}; medians and 95 % credible intervals over the posterior draws</div>"
        f"<div{conv_cls}>Fit: {e(conv)}</div>"
        "<div class=grid><div>"
        f"{table}"
        "</div><div>"
        f"<img alt='photon transfer curve' src='data:image/png;base64,{ptc}'>"
        f"<img alt='SNR curve' src='data:image/png;base64,{snr}'>"
        f"<table class=meta>{meta_rows}</table>"
        "</div></div>"
        "<ul>"
        + "".join(f"<li>{e(f)}</li>" for f in facts)
        + "</ul>"
        + (colour_section_html(colour, heading="Colour (beyond EMVA 1288)") if colour else "")
        + "</body></html>"
    )


def write_datasheet(result, path, *, title=None) -> Path:
    """Write :func:`datasheet_html` of ``result`` to ``path`` (atomically); returns the path."""
    path = Path(path)
    atomic_write_text(path, datasheet_html(result, title=title))
    return path
