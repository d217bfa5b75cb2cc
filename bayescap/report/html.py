"""One self-contained HTML page comparing sensors (Tisse et al. 2008, Section 4, Figs. 5-8).

    bayescap report A.csv B.csv ... -o report.html [--area 1/4in] [--h0 0.4]

Across sensors: capacity with 95 % intervals at full resolution and at the fixed area
(Fig. 8(b)), TR against the average exposure H₀ with credible bands (Fig. 8(a)), SNR against
exposure (Figs. 5-6) and the matrix of pairwise probabilities. Per sensor: the photon-transfer
curve with its posterior predictive band and residuals, the SNR curve, the corner plot, the
parameter and derived tables and the sampler diagnostics. Images are PNGs embedded as base64:
no external assets. The file is written atomically.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from bayescap.io.ptc_csv import atomic_write_text
from bayescap.physics.noise import snr_db
from bayescap.report.colour_section import colour_section_html
from bayescap.report.compare_plots import (
    _N_CURVE_DRAWS,
    H0_GRID_LUX_S,
    _band,
    plot_capacity,
    plot_probability_matrix,
    plot_snr_exposure,
    plot_tr_h0,
)
from bayescap.report.plots import plain_text, plot_corner, plot_ptc, png_bytes
from bayescap.report.text import format_or_na
from bayescap.studies.compare import Comparison
from bayescap.studies.exposure import _coefficients, snr_at_exposure

__all__ = [
    "render_html",
    "write_report",
    "plot_capacity",
    "plot_tr_h0",
    "plot_snr_exposure",
    "plot_probability_matrix",
    "plot_snr_sensor",
    "H0_GRID_LUX_S",
    "SECTION_IDS",
]


#: the cross-sensor sections every report has (per-sensor sections are ``sensor-<i>``)
SECTION_IDS = ("summary", "capacity", "tonal-range", "snr", "probabilities", "conventions")


#: resolution of the embedded figures, and of the corner plots (shown at most 1000 px wide)
_DPI = 90
_CORNER_DPI = 90
_CORNER_DRAWS = 8000

#: what the tables call the fit's and the comparison's quantities: (name, scale, unit shown);
#: the contract's identifier stays in the cell's tooltip
QUANTITY_NAMES = {
    "conversion_gain_e_per_dn": ("conversion gain K", 1.0, "e⁻/DN"),
    "read_noise_e": ("read noise", 1.0, "e⁻"),
    "dark_noise_e": ("dark noise (read and dark-current shot noise)", 1.0, "e⁻"),
    "dark_current_e_per_s": ("dark current", 1.0, "e⁻/s"),
    "full_well_e": ("full well (clip level)", 1.0, "e⁻"),
    "quantum_efficiency": ("quantum efficiency", 1.0, ""),
    "prnu_percent": ("PRNU", 1.0, "%"),
    "dsnu_e": ("DSNU", 1.0, "e⁻"),
    "clip_spread_dn": ("spread of the pixels about the clip", 1.0, "DN"),
    "variance_discrepancy": ("variance discrepancy f (systematics)", 1.0, ""),
    "mean_discrepancy": ("mean discrepancy g (non-linearity)", 1.0, ""),
    "snr_max_db": ("maximum SNR (Eq. 1)", 1.0, "dB"),
    "dynamic_range_db": ("dynamic range (Eq. 2)", 1.0, "dB"),
    "tonal_range_bits": ("tonal range b′ (Eq. 7)", 1.0, "bit"),
    "mtf_loss_bits": ("MTF loss Δs (Eq. 9)", 1.0, "bit"),
    "effective_pixels": ("effective pixels s′", 1e6, "Mpixel"),
    "capacity_bits": ("information capacity C (Eq. 6)", 1e6, "Mbit"),
    "tonal_range_bits_h0": ("tonal range b′ at H₀", 1.0, "bit"),
    "s_max_h0_e": ("top of the signal range at H₀", 1.0, "e⁻"),
    "analog_gain_h0": ("analog gain at H₀", 1.0, "×"),
    "capacity_full_bits": ("capacity C at full resolution, TR at H₀", 1e6, "Mbit"),
    "capacity_area_bits": ("capacity C at the fixed area, TR at H₀", 1e6, "Mbit"),
}

#: what the conventions table calls its rows
CONVENTION_NAMES = {
    "area": "fixed imaging area",
    "area_tolerance": "tolerance of the area",
    "h0_lux_s": "average exposure H₀ (lux·s)",
    "mid_grey_fraction": "mean scene, fraction of the signal range",
    "h0_convention": "placement at H₀",
    "seed": "seed",
    "quality": "quality preset",
    "n_draws_per_sensor": "posterior draws per sensor",
    "probability": "probability of superiority",
    "practical_difference": "practical difference δ (fraction of capacity)",
    "practical_probability": "practical-difference probability",
    "intervals": "intervals",
}

_UNITS = {"e-": "e⁻", "e-/DN": "e⁻/DN", "e-/s": "e⁻/s", "bits": "bit"}


def _quiet(fn, *args, **kwargs):
    """Run a plotting function with corner.py's contour warnings (root logger) silenced."""
    import logging

    root = logging.getLogger()
    level = root.level
    root.setLevel(logging.ERROR)
    try:
        return fn(*args, **kwargs)
    finally:
        root.setLevel(level)


def _png(fig, dpi=_DPI) -> str:
    """The figure as a base64 PNG (256-colour palette, see :func:`~bayescap.report.plots.png_bytes`)."""
    return base64.b64encode(png_bytes(fig, dpi)).decode("ascii")


def plot_snr_sensor(s):
    """One sensor's SNR curve with its 95 % band: against exposure when calibrated, else against
    the signal in electrons."""
    fig = Figure(figsize=(6, 3.4))
    ax = fig.subplots()
    r = s.result
    idx = r.thin_index(_N_CURVE_DRAWS)
    if s.calibration is not None:
        _band(
            ax,
            H0_GRID_LUX_S,
            snr_at_exposure(r, H0_GRID_LUX_S, calibration=s.calibration, idx=idx),
            "C0",
            "posterior median",
        )
        ax.set_xlabel("photometric exposure H (lux·s)")
    else:
        p = {k: v[idx] for k, v in r.draws.items()}
        clip, _ = r.signal_max_e(p)
        sig = np.geomspace(1.0, float(np.max(clip)), 80)
        co = _coefficients(r, p)
        snr = np.where(sig[None, :] <= clip[:, None], snr_db(co, sig[None, :]), np.nan)
        _band(ax, sig, snr, "C0", "posterior median")
        ax.set_xlabel("signal (e⁻)  [no exposure calibration]")
    ax.set_xscale("log")
    ax.set_ylabel("SNR (dB)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(plain_text(f"SNR (Eq. 1), 95 % band: {s.name}"), fontsize=10)
    fig.tight_layout()
    return fig


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:0 auto;max-width:1200px;
padding:1em 2em;color:#222;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em} h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:1.6em}
h3{margin-top:1.2em}
table{border-collapse:collapse;font-size:.85em;margin:.5em 0} th,td{border:1px solid #ccc;padding:3px 7px;
text-align:right} th{background:#f3f3f3} td.l,th.l{text-align:left}
img{max-width:100%;height:auto;display:block;margin:.4em 0;border:1px solid #eee}
.sim{background:#fff4d6;border:1px solid #e0b84c;padding:.5em .8em;margin:.5em 0}
.warn{color:#a30000} .small{font-size:.85em;color:#555} nav a{margin-right:1em}
img.corner{max-width:1000px}
.grid{display:grid;grid-template-columns:1fr 1fr;gap:1em} code{background:#f5f5f5;padding:0 3px}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _f(x, fmt="{:.4g}"):
    if x is None:
        return "—"
    if isinstance(x, (int, float)) and 1e4 <= abs(x) < 1e9 and fmt == "{:.4g}":
        return f"{x:,.0f}".replace(",", "\u202f")  # 15 020, not 1.502e+04
    if isinstance(x, (int, float)) and abs(x) >= 1e5:
        return f"{x:.4g}"
    return fmt.format(x)


def _limit_text(lim, scale=1.0, fmt="{:.4g}") -> str:
    """``&lt; 629 (95 % upper limit)``: a quantity the data do not determine, as its limit alone."""
    value = "—" if lim.get("value") is None else _f(lim["value"] / scale, fmt)
    because = f", follows {_e(lim['because'])}" if lim.get("because") else ""
    sign = "&lt;" if lim["kind"] == "upper" else "&gt;"
    return f"{sign} {value} <span class=small>({100 * lim['level']:g} % {_e(lim['kind'])} limit{because})</span>"


def _iv(s, scale=1.0, fmt="{:.4g}"):
    """Median [95 %] of a summary; its limit alone when it carries one (``limit``)."""
    if s and s.get("limit"):
        return _limit_text(s["limit"], scale, fmt)
    if not s or s.get("median") is None:
        return "—"
    lo, hi = s["ci95"]
    return (
        f"{_f(s['median'] / scale, fmt)} <span class=small>[{_f(lo / scale, fmt)}, "
        f"{_f(hi / scale, fmt) if hi is not None else '—'}]</span>"
    )


def _img(b64, alt, cls="") -> str:
    return (
        f'<figure><img{" class=" + cls if cls else ""} alt="{_e(alt)}" src="data:image/png;base64,{b64}"><figcaption class=small>{_e(alt)}'
        f"</figcaption></figure>"
    )


def _name(key) -> str:
    return QUANTITY_NAMES[key][0] if key in QUANTITY_NAMES else key.replace("_", " ")


def _quantity_row(key, s, label_suffix="") -> list[str]:
    """A table row: readable name (identifier in the tooltip), median [95 %], unit."""
    name, scale, unit = QUANTITY_NAMES.get(key, (key.replace("_", " "), 1.0, None))
    if unit is None:
        unit = _UNITS.get(s.get("unit", ""), s.get("unit", ""))
    return [f'<span title="{_e(key)}">{_e(name + label_suffix)}</span>', _iv(s, scale), _e(unit)]


def _table(header, rows, left=1) -> str:
    h = "".join(f"<th{' class=l' if i < left else ''}>{_e(c)}</th>" for i, c in enumerate(header))
    body = "".join(
        "<tr>" + "".join(f"<td{' class=l' if i < left else ''}>{c}</td>" for i, c in enumerate(r)) + "</tr>"
        for r in rows
    )
    return f"<table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>"


def _is_simulated(s) -> bool:
    md = s.result.metadata
    txt = " ".join(str(md.get(k, "")) for k in ("simulated", "sensor", "note", "manufacturer")).lower()
    return bool(md.get("simulated")) or "simulated" in txt


def _convention(key, v) -> str:
    if key == "area" and isinstance(v, dict) and {"name", "width_mm", "height_mm"} <= set(v):
        return f"{v['name']}: {v['width_mm']:g} × {v['height_mm']:g} mm" + (
            f" (diagonal {v['diagonal_mm']:g} mm)" if v.get("diagonal_mm") else ""
        )
    if v is None:
        return "none"
    if isinstance(v, dict):
        return ", ".join(f"{a}: {b}" for a, b in v.items())
    return str(v)


def render_html(cmp: Comparison, *, title: str = "bayescap sensor comparison", colour: dict | None = None) -> str:
    """The report page as a string (figures rendered now, embedded as base64 PNG)."""
    d = cmp.to_dict()
    c = d["conventions"]
    area = c["area"]
    an = area["name"] if area else "area"
    parts = [
        f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{_e(title)}</title>"
        f"<style>{_CSS}</style></head><body>",
        f"<h1>{_e(title)}</h1>",
        f"<p class=small>bayescap {_e(d['bayescap_version'])} · seed {_e(c['seed'])} · quality "
        f"{_e(c['quality'])} · medians with 95 % equal-tailed credible intervals</p>",
    ]
    sims = [s.name for s in cmp.sensors if _is_simulated(s)]
    if sims:
        parts.append(
            f"<div class=sim><b>Simulated data.</b> These inputs are simulations or PTCs built from "
            f"datasheet values, not measurements: {_e(', '.join(sims))}.</div>"
        )
    nav = " ".join(f'<a href="#{i}">{i.replace("-", " ")}</a>' for i in SECTION_IDS)
    nav += " " + " ".join(f'<a href="#sensor-{i}">{_e(s.name)}</a>' for i, s in enumerate(cmp.sensors))
    parts.append(f"<nav>{nav}</nav>")

    # summary table
    rows = []
    for s in d["sensors"]:
        a = s.get("area")
        rows.append(
            [
                _e(s["name"]) + (" <span class=warn>(not converged)</span>" if not s["converged"] else ""),
                _f(s["pixel_pitch_um"]),
                f"{s['pixels_full'] / 1e6:.3f} M" if s.get("pixels_full") else "—",
                (f"{a['width_px']}×{a['height_px']}" + (" (smaller)" if a["smaller_than_area"] else "")) if a else "—",
                _iv(s.get("exposure_calibration", {}) and s["exposure_calibration"]["sensitivity_e_per_lux_s"]),
                _iv(s.get("tonal_range_bits_h0"), fmt="{:.3f}"),
                _iv(s.get("capacity_full_bits"), 1e6),
                _iv(s.get("capacity_area_bits"), 1e6),
                "TR at H0" if s["capacity_basis"] == "tr_at_h0" else "TR full range",
            ]
        )
    parts.append(
        '<section id="summary"><h2>Summary</h2>'
        + _table(
            [
                "sensor",
                "pitch (µm)",
                "pixels",
                f"pixels @{an}",
                "sensitivity (e⁻/lux·s)",
                f"TR(H0={c['h0_lux_s']:g}) bits",
                "C full (Mbit)",
                f"C @{an} (Mbit)",
                "capacity basis",
            ],
            rows,
        )
        + "</section>"
    )

    parts.append(
        '<section id="capacity"><h2>Information capacity (Fig. 8(b))</h2>'
        + _img(_png(plot_capacity(cmp)), "capacity at full resolution and at the fixed area, 95 % intervals")
        + "</section>"
    )
    parts.append(
        '<section id="tonal-range"><h2>Tonal range against average exposure H0 (Fig. 8(a))</h2>'
        + _img(_png(plot_tr_h0(cmp)), "TR against H0 with 95 % credible bands")
        + "</section>"
    )
    parts.append(
        '<section id="snr"><h2>SNR against exposure (Figs. 5-6)</h2>'
        + _img(_png(plot_snr_exposure(cmp)), "SNR against photometric exposure with 95 % bands")
        + "</section>"
    )

    # pairwise
    delta = cmp.conventions.get("practical_difference", 0.01)
    dp = f"{100 * delta:g} %"
    prow = []
    for p in d["pairs"]:
        row = [_e(f"{p['a']} vs {p['b']}")]
        for q in ("full", "area"):
            row += [
                _iv(p[f"ratio_{q}"], fmt="{:.4f}"),
                _f(p[f"p_a_greater_{q}"], "{:.3f}"),
                _f(p.get(f"p_a_practically_greater_{q}"), "{:.3f}"),
                _f(p.get(f"p_b_practically_greater_{q}"), "{:.3f}"),
            ]
        row.append("TR at H0" if p["basis"] == "tr_at_h0" else "TR full range")
        prow.append(row)
    psec = [
        '<section id="probabilities"><h2>Pairwise probabilities</h2>',
        "<p>The capacity ratio C_A/C_B with its 95 % interval; P(A captures more information than B) "
        "from the independent posteriors (all pairs of draws); and what matters in practice: "
        f"P(C_A &gt; (1+δ)·C_B), the probability that A is larger by more than the practical difference "
        f"δ = {_e(dp)} (<code>--practical-difference</code>), and the same for B. A probability P(A&gt;B) "
        "near 1 with both practical probabilities near 0 means: A is larger, by less than δ. The "
        "matrices are coloured by the practical probability.</p>",
    ]
    if len(cmp.sensors) > 1:
        psec.append(
            "<div class=grid>"
            + _img(_png(plot_probability_matrix(cmp, "full")), f"P(C_row > (1+δ)·C_column), δ = {dp}, full resolution")
        )
        if area:
            psec.append(
                _img(_png(plot_probability_matrix(cmp, "area")), f"P(C_row > (1+δ)·C_column), δ = {dp}, at {an}")
            )
        psec.append("</div>")
        psec.append(
            _table(
                [
                    "pair",
                    "C_A/C_B full",
                    "P(A>B) full",
                    f"P(A>B+{dp}) full",
                    f"P(B>A+{dp}) full",
                    f"C_A/C_B @{an}",
                    f"P(A>B) @{an}",
                    f"P(A>B+{dp}) @{an}",
                    f"P(B>A+{dp}) @{an}",
                    "basis",
                ],
                prow,
            )
        )
    else:
        psec.append("<p>Only one sensor: no pairs.</p>")
    parts.append("".join(psec) + "</section>")

    # per sensor
    for i, (s, sd) in enumerate(zip(cmp.sensors, d["sensors"])):
        r = s.result
        rd = r.to_dict()
        sec = [
            f'<section id="sensor-{i}"><h2>{_e(s.name)}</h2>',
            f"<p class=small>{_e(sd['sensor'])} · input <code>{_e(sd['input'])}</code> · fit seed {sd['seed']}</p>",
        ]
        if _is_simulated(s):
            sec.append("<div class=sim>Simulated (or built from datasheet values): not a measurement.</div>")
        own = sd.get("notes", [])
        fit_notes = [n for n in rd.get("notes", []) if not (n.startswith("NOT CONVERGED") and not sd["converged"])]
        for n in own + fit_notes:
            sec.append(f"<p class=warn>! {_e(n)}</p>")
        prm = [
            _quantity_row(k, v) + ["yes" if v.get("constrained", True) else "no"] for k, v in rd["parameters"].items()
        ]
        der = [_quantity_row(k, v) for k, v in rd["derived"].items()]
        for k in ("tonal_range_bits_h0", "s_max_h0_e", "analog_gain_h0", "capacity_full_bits", "capacity_area_bits"):
            if sd.get(k):
                der.append(_quantity_row(k, sd[k], f" ({an})" if k == "capacity_area_bits" else ""))
        dg = rd["diagnostics"]
        num = lambda key, spec, dg=dg: format_or_na(dg.get(key), spec)

        diag = [
            ["converged", "yes" if dg["converged"] else "<span class=warn>no</span>"],
            (
                ["Pareto k̂ (target)", f"{num('khat', '.2f')} (&lt; {dg['khat_max']:g})"]
                if dg.get("method") == "laplace-is"
                else ["R-hat max (target)", f"{num('rhat_max', '.4f')} (&lt; {dg['rhat_target']})"]
            ),
            ["ESS min (target)", f"{num('ess_min', '.0f')} (≥ {dg['ess_target']:.0f})"],
            [
                "sampler",
                _e(
                    f"Laplace–IS, IS ESS {num('ess_is', '.0f')} of {dg['n_proposals']} proposals, "
                    f"{dg['n_draws']} resampled draws, {dg['wall_s']:.1f} s, quality {dg['quality']}"
                    if dg.get("method") == "laplace-is"
                    else f"{dg['n_ensembles']} ensembles × {dg['n_walkers']} walkers × {dg['n_steps']} steps, "
                    f"{dg['n_rounds']} round(s), {dg['wall_s']:.1f} s, quality {dg['quality']}"
                ),
            ],
            ["model terms", _e(", ".join(t.replace("_", " ") for t in rd["model_terms"]))],
            [
                "MTF",
                _e(
                    ", ".join(
                        cc.get("name", "").replace("_", " ")
                        for cc in rd.get("mtf", {}).get("model", {}).get("components", [])
                    )
                ),
            ],
        ]
        if dg.get("interval_end_mcse_max") is not None:
            tgt = dg.get("interval_end_mcse_target")
            diag.append(
                [
                    "Monte Carlo error of the 95 % interval ends, of the width (target)",
                    _e(
                        f"{num('interval_end_mcse_max', '.3f')}"
                        + (f" ({_name(dg['interval_end_mcse_worst'])})" if dg.get("interval_end_mcse_worst") else "")
                        + (f" (≤ {tgt:g})" if tgt is not None else " (reported, not a check)")
                    ),
                ]
            )
        if dg.get("failed_checks"):
            diag.append(["failed checks", _e("; ".join(dg["failed_checks"]))])
        sec.append(
            "<div class=grid><div><h3>Parameters</h3>"
            + _table(["parameter", "median [95 %]", "unit", "constrained"], prm)
            + "</div><div><h3>Derived</h3>"
            + _table(["quantity", "median [95 %]", "unit"], der)
            + "<h3>Diagnostics</h3>"
            + _table(["check", "value"], diag, left=2)
            + "</div></div>"
        )
        sec.append(
            "<div class=grid>"
            + _img(_png(plot_ptc(r)), f"{s.name}: photon-transfer curve, posterior predictive 95 % band and residuals")
            + _img(_png(plot_snr_sensor(s)), f"{s.name}: SNR with 95 % band")
            + "</div>"
        )
        sec.append(
            _img(
                _png(_quiet(plot_corner, r, n_max=_CORNER_DRAWS), dpi=_CORNER_DPI),
                f"{s.name}: corner plot of the physical parameters",
                "corner",
            )
        )
        parts.append("".join(sec) + "</section>")

    conv = [
        [f'<span title="{_e(k)}">{_e(CONVENTION_NAMES.get(k, k.replace("_", " ")))}</span>', _e(_convention(k, v))]
        for k, v in c.items()
    ]
    parts.append(
        '<section id="conventions"><h2>Conventions</h2>'
        + _table(["convention", "value"], conv, left=2)
        + "<p class=small>See docs/compare.md: optical formats, H0 placement at mid-grey, exposure "
        "calibration, the probability of superiority.</p></section>"
    )
    parts.append(colour_section_html(colour) if colour is not None else "")  # bayescap colour's result
    parts.append("</body></html>\n")
    return "\n".join(parts)


def write_report(cmp: Comparison, path, *, title: str = "bayescap sensor comparison", **kw) -> Path:
    """Render and write the page atomically (temp file in the same folder, then rename)."""
    path = Path(path)
    atomic_write_text(path, render_html(cmp, title=title, **kw))
    return path
