"""The colour section of the HTML report and of the EMVA 1288 datasheet.

Both pages take the result of ``bayescap colour`` (its JSON: ``colour.json`` of ``--out``, or
``--json``'s output saved to a file), given with ``--colour FILE``: colour sensitivity, the scores
and the labelled colour capacities with 95 % intervals, the colour-correction matrix with its noise
gain and condition number, the white balance, the K check of the CFA channels with the per-channel
fits beside the joint one, the notes and the printed definitions.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

from bayescap.exceptions import InputError

__all__ = ["load_colour_result", "colour_section_html", "limit_text"]

_CHANNELS = ("R", "Gr", "Gb", "B")


def load_colour_result(path: os.PathLike | str) -> dict:
    """The JSON of ``bayescap colour``; :class:`InputError` (one line naming the file) otherwise."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise InputError(f"cannot read the colour result ({e.strerror or e})", path=path) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(
            f"not a JSON file ({e}); give the colour.json of 'bayescap colour --out DIR'", path=path
        ) from None
    colour = doc.get("colour") if isinstance(doc, dict) else None
    if not isinstance(colour, dict) or "cs_bits" not in colour or "cfa_fit" not in colour:
        raise InputError("no 'colour' block with cs_bits and cfa_fit: not the JSON of 'bayescap colour'", path=path)
    return doc


def limit_text(s, fmt="{:.4g}") -> str:
    """A summary without a median: its limit (``> x`` a lower bound, ``< x`` an upper limit), or "–"."""
    lim = s.get("limit") if isinstance(s, dict) else None
    if isinstance(lim, dict) and lim.get("value") is not None:
        sign, what = (">", "lower bound") if lim.get("kind") == "lower" else ("<", "upper limit")
        return f"{sign} {fmt.format(lim['value'])} ({what})"
    up = s.get("upper_limit_95") if isinstance(s, dict) else None
    return f"< {fmt.format(up)} (95 % upper limit)" if up is not None else "–"


def _e(x) -> str:
    return html.escape(str(x))


def _iv(s, fmt="{:.4g}") -> str:
    if not isinstance(s, dict) or s.get("median") is None or None in (s.get("ci95") or [None]):
        return _e(limit_text(s, fmt))
    lo, hi = s["ci95"]
    unit = s.get("unit", "")
    return _e(f"{fmt.format(s['median'])} [{fmt.format(lo)}, {fmt.format(hi)}] {unit}".rstrip())


def _rows(items) -> str:
    return "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in items)


def colour_section_html(doc: dict, *, heading: str = "Colour") -> str:
    """An HTML ``<section id="colour">`` of a ``bayescap colour`` result (module docstring)."""
    c = doc["colour"]
    f = c["cfa_fit"]
    rows = [
        ["colour sensitivity CS", _iv(c["cs_bits"])],
        ["CS without the floor, raw cube unclipped", _iv(c.get("cs_no_floor_bits"))],
    ]
    per_channel: dict = {}
    for k, v in c.get("scores", {}).items():
        base, _, ch = k.rpartition("_")
        if ch in _CHANNELS:
            per_channel.setdefault(base, {})[ch] = v
        elif k != "colour_depth_bits":
            rows.append([_e(k.replace("_", " ")), _iv(v)])
    for k, v in c.get("capacity", {}).items():
        rows.append([_e(f"colour capacity, {k.replace('_', ' ')}"), _iv(v, "{:.4g}")])
    parts = [f'<section id="colour"><h2>{_e(heading)}</h2>']
    parts.append(
        f"<p>{_e(doc.get('input', ''))}: medians and 95 % credible intervals over the posterior draws of the "
        f"four CFA channels ({_e(f['fit'])}; {'converged' if f.get('converged') else 'NOT CONVERGED'}).</p>"
    )
    parts.append("<table><tr><th>quantity</th><th>value</th></tr>" + _rows(rows) + "</table>")
    if per_channel:
        head = "<tr><th>per channel</th>" + "".join(f"<th>{ch}</th>" for ch in _CHANNELS) + "</tr>"
        body = [[_e(b.replace("_", " "))] + [_iv(v.get(ch)) for ch in _CHANNELS] for b, v in per_channel.items()]
        parts.append(f"<table>{head}{_rows(body)}</table>")
    ccm = c.get("ccm", {})
    if ccm:
        body = [
            [f"{v:.4f}" for v in row] + [f"{g:.3f}"] for row, g in zip(ccm.get("matrix", []), ccm.get("noise_gain", []))
        ]
        parts.append(
            f"<h3>Colour-correction matrix</h3><p>{_e(ccm.get('source', ''))}; uncertainty: "
            f"{_e(ccm.get('uncertainty', ''))}; condition number {ccm.get('condition_number', float('nan')):.3g}.</p>"
            "<table><tr><th colspan=3>M (white-balanced camera RGB → output)</th><th>noise gain √Σⱼ Mᵢⱼ²</th></tr>"
            + _rows(body)
            + "</table>"
        )
    wb = c.get("white_balance")
    if wb:
        parts.append(
            f"<p>White balance R, G, B: {_e(', '.join(f'{v:.4f}' for v in wb['gains']))} ({_e(wb['source'])}).</p>"
        )
    kc = f.get("k_check", {})
    if kc:
        verdict = "agree" if kc.get("passed") else "DISAGREE"
        parts.append(
            f"<h3>The CFA channels as one sensor</h3><p>K check: the channels' conversion gains {verdict} "
            f"(χ² {kc['chi2']:.2f}, {kc['dof']} dof, p = {kc['p_value']:.3g}; largest ratio {kc['max_ratio']:.4f}). "
            f"{_e(kc.get('definition', ''))}.</p>"
        )
    names = ("conversion_gain_e_per_dn", "read_noise_e", "full_well_e", "prnu_percent")
    head = "<tr><th>channel</th>" + "".join(f"<th>{_e(n)} separate</th><th>joint</th>" for n in names) + "</tr>"
    body = [
        [ch] + [x for n in names for x in (_iv(f["separate"][ch].get(n)), _iv(f["joint"][ch].get(n)))]
        for ch in f.get("channels", [])
    ]
    parts.append(f"<table>{head}{_rows(body)}</table>")
    notes = list(f.get("notes", [])) + list(c.get("notes", []))
    if notes:
        parts.append("<ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>")
    ch = c.get("choices", {})
    defs = [("CS", ch.get("definition", "")), ("domain", ch.get("domain", "")), ("floor", ch.get("floor", ""))]
    if ch.get("clipping"):
        defs.append(("clipping", ch["clipping"]))
    defs += list(c.get("definitions", {}).items())
    parts.append("<dl class=small>" + "".join(f"<dt>{_e(k)}</dt><dd>{_e(v)}</dd>" for k, v in defs) + "</dl>")
    parts.append("</section>")
    return "\n".join(parts)
