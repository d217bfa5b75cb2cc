"""The colour page of the PDF datasheet: the same content as the HTML datasheet's colour section
(:mod:`bayescap.report.colour_section`), from the JSON of ``bayescap colour``, on one A4 landscape
page drawn on a :class:`matplotlib.figure.Figure` (no pyplot).

Colour sensitivity, the scores and the labelled capacities with medians and 95 % intervals (a limit
alone where the draws give only a limit), the per-channel scores, the colour-correction matrix with
its noise gain and condition number, the white balance, the K check with the separate and joint
channel fits, the choices (domain, floor, clipping), the notes and the printed definitions.
"""

from __future__ import annotations

import textwrap

from bayescap.report.colour_section import limit_text
from bayescap.report.pdf_table import grid_table

__all__ = ["colour_page", "colour_rows"]

_CHANNELS = ("R", "Gr", "Gb", "B")


def _value(s, fmt="{:.4g}") -> tuple[str, str]:
    """(median, '95 % interval') as text; a limit alone where there is no interval."""
    if not isinstance(s, dict) or s.get("median") is None or None in (s.get("ci95") or [None]):
        return limit_text(s, fmt), ""
    lo, hi = s["ci95"]
    unit = s.get("unit", "")
    return f"{fmt.format(s['median'])} {unit}".rstrip(), f"{fmt.format(lo)} – {fmt.format(hi)}"


def colour_rows(c: dict) -> list[list[str]]:
    """The table of the colour page: [quantity, median, 95 % interval] rows of a ``colour`` block."""
    rows = [["colour sensitivity CS", *_value(c["cs_bits"])]]
    if c.get("cs_no_floor_bits"):
        rows.append(["CS without the floor, raw cube unclipped", *_value(c["cs_no_floor_bits"])])
    per_channel: list = []
    for k, v in c.get("scores", {}).items():
        base, _, ch = k.rpartition("_")
        if ch in _CHANNELS:
            per_channel.append([f"{base.replace('_', ' ')} ({ch})", *_value(v)])
        elif k != "colour_depth_bits":
            rows.append([k.replace("_", " "), *_value(v)])
    for k, v in c.get("capacity", {}).items():
        rows.append([f"colour capacity, {k.replace('_', ' ')}", *_value(v)])
    return rows + per_channel


def colour_page(doc: dict, *, name: str, page_in=(11.69, 8.27)):
    """The colour page of a ``bayescap colour`` result ``doc`` (its JSON) as a Figure."""
    from matplotlib.figure import Figure

    c = doc["colour"]
    f = c["cfa_fit"]
    fig = Figure(figsize=page_in)
    fig.text(0.03, 0.965, f"{name}: colour (beyond EMVA 1288)", fontsize=14, weight="bold", va="top", parse_math=False)
    ok = bool(f.get("converged"))
    sub = (
        f"bayescap colour of {doc.get('input', '')}; medians and 95 % credible intervals over the posterior draws "
        f"of the four CFA channels ({f.get('fit', '')}; {'converged' if ok else 'NOT CONVERGED'})"
    )
    fig.text(0.03, 0.935, textwrap.fill(sub, 200), fontsize=7.5, va="top", color="0.3" if ok else "#b00000",
             parse_math=False)  # fmt: skip
    grid_table(fig.add_axes((0.03, 0.35, 0.47, 0.55)), colour_rows(c), ["Quantity", "Median", "95 % interval"],
           [0.5, 0.25, 0.25])  # fmt: skip
    right = []
    ccm = c.get("ccm") or {}
    if ccm:
        rows = [
            [f"{v:.4f}" for v in row] + [f"{g:.3f}"] for row, g in zip(ccm.get("matrix", []), ccm.get("noise_gain", []))
        ]
        head = ["M: R", "G", "B", "noise gain √Σⱼ Mᵢⱼ²"]  # white-balanced raw R, G, B → output row
        grid_table(fig.add_axes((0.53, 0.78, 0.44, 0.12)), rows, head, [0.2, 0.2, 0.2, 0.4])
        right.append(
            f"CCM: {ccm.get('source', '')}; uncertainty: {ccm.get('uncertainty', '')}; "
            f"condition number {ccm.get('condition_number', float('nan')):.3g}."
        )
    wb = c.get("white_balance")
    if wb:
        right.append(f"White balance R, G, B: {', '.join(f'{v:.4f}' for v in wb['gains'])} ({wb['source']}).")
    kc = f.get("k_check") or {}
    if kc:
        verdict = "agree" if kc.get("passed") else "DISAGREE"
        right.append(
            f"K check: the channels' conversion gains {verdict} (chi2 {kc['chi2']:.2f}, {kc['dof']} dof, "
            f"p = {kc['p_value']:.3g}; largest ratio {kc['max_ratio']:.4f})."
        )
    fig.text(0.53, 0.76, "\n".join(textwrap.fill(t, 105) for t in right), fontsize=6.5, va="top", parse_math=False)
    names = (("conversion_gain_e_per_dn", "K (e-/DN)"), ("read_noise_e", "read (e-)"), ("prnu_percent", "PRNU (%)"))
    rows = []
    for ch in f.get("channels", []):
        row = [ch]
        for n, _ in names:
            for part in ("separate", "joint"):
                med, iv = _value(f.get(part, {}).get(ch, {}).get(n), "{:.3g}")
                row.append(f"{med.split(' ')[0]} [{iv}]" if iv else med)
        rows.append(row)
    head = ["ch"] + [f"{lab} {p}" for _, lab in names for p in ("sep.", "joint")]
    grid_table(fig.add_axes((0.53, 0.35, 0.44, 0.28)), rows, head, [0.06] + [0.94 / 6] * 6, fontsize=5.5)
    ch = c.get("choices", {})
    lines = [f"CS: {ch.get('definition', '')}", f"domain: {ch.get('domain', '')}", f"floor: {ch.get('floor', '')}"]
    if ch.get("clipping"):
        lines.append(f"clipping: {ch['clipping']}")
    lines += [f"{k}: {v}" for k, v in c.get("definitions", {}).items()]
    lines += [f"note: {n}" for n in list(f.get("notes", [])) + list(c.get("notes", []))]
    body = "\n".join(textwrap.fill(t, 250, subsequent_indent="    ") for t in lines)
    fig.text(0.03, 0.33, body, fontsize=5.5, va="top", color="0.15", parse_math=False)
    return fig
