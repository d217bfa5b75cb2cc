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


def emva_limits(view, parameters=None) -> dict:
    """{EMVA key: {kind, value, level, because}}: the limits the view carries
    (:mod:`bayescap.posterior.emva_limits`, the same in ``--json``); the datasheet prints these as
    limits alone, as the text report does. ``parameters`` is not needed (kept for callers)."""
    return {
        k: {**it["limit"], "because": it.get("limit_because", "")}
        for k, it in view["quantities"].items()
        if it.get("limit")
    }


#: metadata an operating point is made of: (key, label, unit)
OPERATING_POINT = (
    ("analog_gain", "gain", ""),
    ("black_level_dn", "offset (black level)", "DN"),
    ("wavelength_nm", "wavelength", "nm"),
    ("temperature_c", "temperature", "°C"),
)


def operating_point(result) -> list[tuple[str, str]]:
    """(label, value) of the measurement's operating point: exposure time(s) from the rows, gain,
    offset, wavelength and temperature from the metadata, ``not given`` where the CSV says nothing
    (a default bayescap assumed, e.g. 555 nm, is named as such, not as the sensor's)."""
    d, md = result.model.data, result.metadata
    defaults = set((result.flags or {}).get("metadata_defaults") or [])
    t = np.unique(np.asarray(d.exposure_time_s, float))
    exp = f"{_fmt(t[0])} s (one exposure time)" if t.size == 1 else f"{_fmt(t[0])} – {_fmt(t[-1])} s ({t.size} times)"
    out = [("exposure time", exp)]
    for key, label, unit in OPERATING_POINT:
        v = md.get(key)
        if v is None:
            out.append((label, "not given"))
        elif key in defaults:
            out.append((label, f"not given (bayescap assumes {v:g} {unit})".replace(" )", ")")))
        else:
            out.append((label, f"{v:g} {unit}".strip() if isinstance(v, (int, float)) else str(v)))
    return out


def _meta_rows(result) -> list[tuple[str, str]]:
    """The metadata table: the sensor's keys, each default marked as one."""
    defaults = set((result.flags or {}).get("metadata_defaults") or [])
    return [
        (str(k), f"{v} (default, not from the CSV)" if k in defaults else str(v))
        for k, v in result.metadata.items()
        if v is not None
    ]


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
    sweep rows, the sensitivity rows (≤ 70 % of saturation) apart, with the line of slope K (the
    view's, the table's: EMVA 1288's straight line, median and 95 % band), with a non-linear
    response also the small-signal gain's line (named apart), and the saturation point. ``ax``: draw into it (its figure is
    returned) instead of a figure of its own."""
    from matplotlib.figure import Figure

    view = emva1288_view(result) if view is None else view
    sw = _Sweep(result.model.data)
    x, y = sw.signal, sw.s2_y - sw.s2_dark
    kq = view["quantities"]["K"]  # the table's K: EMVA 1288's straight line, with its interval
    own = ax is None  # a figure of its own, or an axes of the caller's (the PDF page)
    if own:
        ax = Figure(figsize=(4.6, 3.3), dpi=90).add_subplot(1, 1, 1)
    fig = ax.figure
    ax.plot(x[~sw.sens], y[~sw.sens], "o", ms=3, mfc="none", color="0.45", label="rows")
    ax.plot(x[sw.sens], y[sw.sens], "o", ms=3, color="C0", label="fit range of the standard (≤ 70 %)")
    xs = np.linspace(0.0, float(np.max(x)), 50)
    med, (lo, hi) = kq["median"], kq["ci95"]
    ax.fill_between(xs, lo * xs, hi * xs, color="C1", alpha=0.3, lw=0)
    ax.plot(xs, med * xs, "-", color="C1", lw=1, label=f"K = {_fmt(med)} DN/e⁻ (EMVA 1288 line, as in the table)")
    if "response_nonlinearity" in result.draws:  # the small-signal gain, named apart
        k0 = 1.0 / float(np.median(result.draws["conversion_gain_e_per_dn"]))
        ax.plot(xs, k0 * xs, ":", color="C2", lw=1, label=f"small-signal K₀ = {_fmt(k0)} DN/e⁻ (slope at zero)")
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
    limits = emva_limits(view) if limits is None else limits
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


#: on screen the notes are a column of the table; printed (A4 landscape, one page) they are left out
#: (the PDF has none either) and everything is set smaller
_CSS = """
body{font-family:Helvetica,Arial,sans-serif;font-size:11px;margin:14px;max-width:1100px}
h1{font-size:16px;margin:0 0 2px 0} h2{font-size:11px;margin:6px 0 1px 0} .sub{color:#555;margin-bottom:6px}
table{border-collapse:collapse} td,th{border-bottom:1px solid #ddd;padding:2px 5px;vertical-align:top}
th{background:#eee;text-align:left} td.n{text-align:right;white-space:nowrap;font-variant-numeric:tabular-nums}
td.note{color:#555;font-size:9px;max-width:300px} .grid{display:flex;gap:10px;align-items:flex-start}
.meta td{border:none;padding:0 6px 0 0} .bad{color:#b00;font-weight:bold} img{max-width:100%}
@page{size:A4 landscape;margin:7mm}
@media print{body{margin:0;font-size:8.5px;max-width:none} h1{font-size:13px} h2{font-size:9px;margin:3px 0 0 0}
 .note{display:none} td,th{padding:0 3px} img{width:340px} ul{margin:2px 0;padding-left:12px}
 .meta td{padding:0 4px 0 0} .sub{margin-bottom:2px} .grid>div:first-child{flex:0 0 64%} #emva-table{width:100%}}
"""


def datasheet_html(result, *, view=None, title=None, colour=None) -> str:
    """The one-page datasheet of ``result`` as a self-contained HTML string."""
    view = emva1288_view(result) if view is None else view
    q = view["quantities"]
    meta = dict(result.metadata)
    name = title or meta.get("sensor") or Path(str(result.model.data.source)).stem
    e = html.escape
    limits = emva_limits(view)
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
        "<th>95 % interval</th><th>Standard's recipe</th><th>bayescap</th><th class=note>Note</th></tr>"
        + "".join(rows)
        + "</table>"
    )
    long = ("note", "source")  # long texts: on screen, not in print
    meta_rows = "".join(
        f"<tr{' class=note' if k in long else ''}><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in _meta_rows(result)
    )
    op_rows = "".join(f"<tr><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in operating_point(result))
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
    split = view.get("dark_noise_split")
    if split:
        parts = [
            f"{label} {_limit_text(split[n], split[n].get('unit') or '')}"
            for n, label in (("read_noise_e", "read noise"), ("dark_current_e_per_s", "dark current"))
            if n in split
        ]
        facts.append(
            "one exposure time: σ_d is read noise and dark-current shot noise combined (measured); "
            + ("the split: " + "; ".join(parts) + " (each the whole dark noise attributed to it)" if parts else "")
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
        f"<h2>Operating point</h2><table class=meta id=operating-point>{op_rows}</table>"
        f"<h2>Sensor</h2><table class=meta id=metadata>{meta_rows}</table>"
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
