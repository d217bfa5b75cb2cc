"""The sensor zoo: truth-in-95 % per parameter, fit times and flags on sensors nobody tuned to.

    python benchmarks/run.py zoo            # writes benchmarks/results/zoo.md
    python benchmarks/zoo.py --only i37     # a subset (names containing the text), printed only

Every sensor of :func:`bayescap.validation.zoo.zoo` is simulated frame by frame by
:mod:`bayescap.validation.framesim` (independent of the likelihood; CSVs cached in
``benchmarks/.zoo_cache/``, gitignored, keyed by a hash of the definition), then fitted with
``bayescap.fit`` at ``standard`` and at ``fast`` quality (seed 1, the default workers), one fit at a
time in this process, each fit timed alone (``time.perf_counter`` around ``bayescap.fit``; CSV
reading included, imports excluded by a first fit). The fit's JSON (``to_dict()``) is scored
against the truths with :func:`bayescap.validation.zoo.score`. The real Basler set is fitted too
and compared with emva1288's reference values (a reference, not a truth: not counted in coverage).

Cells: ``ok`` truth inside the 95 % interval, ``miss``, ``MISS>3w`` a miss by more than three
interval widths (a defect), ``L`` a non-identifiable truth reported as a limit (``constrained:
false``) that holds it, ``L+`` such a truth detected (a constrained interval that holds it), ``L!`` a
non-identifiable truth reported as constrained with an interval that excludes it, ``L✗`` a limit that
excludes the truth, ``(…)`` an unscored truth (between identifiable and not), ``–`` no such
parameter in the fit.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
import traceback
import warnings
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "zoo.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache"
BASLER = ROOT / "data" / "emva1288_basler_ccd12.csv"
BASLER_REF = ROOT / "data" / "emva1288_refset001" / "reference_results_emva1288_v1.0.2.json"

SHORT = {
    "conversion_gain_e_per_dn": "K",
    "read_noise_e": "read",
    "dark_noise_e": "dark noise",
    "dark_current_e_per_s": "D",
    "full_well_e": "FW",
    "quantum_efficiency": "QE",
    "prnu_percent": "PRNU",
    "dsnu_e": "DSNU",
}
NOTES = {}
CELL = {
    "ok": "ok",
    "miss": "miss",
    "MISS>3w": "**MISS>3w**",
    "claims-constrained": "**L!**",
    "limit-wrong": "**L✗**",
    "detected": "L+",
    "limited": "L≥",
}


def cell(rec):
    if rec is None:
        return ""
    v = rec["verdict"]
    if v == "absent":
        return "–"
    if rec["status"] == "limit":
        return "L" if v == "ok" else CELL[v]
    c = CELL.get(v, v)
    return f"({c})" if rec["status"] == "unscored" else c


def fit_one(path, quality):
    import bayescap
    from bayescap.exceptions import InputError

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = bayescap.fit(str(path), seed=1, quality=quality)
        d = res.to_dict()
    except InputError as e:
        return {"refused": str(e).splitlines()[0][:160], "wall_s": time.perf_counter() - t0}
    except Exception as e:  # a crash is a defect to list, not a reason to stop the zoo
        return {
            "error": f"{type(e).__name__}: {e}"[:200],
            "trace": traceback.format_exc()[-800:],
            "wall_s": time.perf_counter() - t0,
        }
    d["wall_s"] = time.perf_counter() - t0
    return d


def flags_of(d):
    if "refused" in d:
        msg = d["refused"]
        return "refused: " + (msg.split(".csv, ", 1)[1] if ".csv, " in msg else msg)
    if "error" in d:
        return "ERROR " + d["error"]
    diag = d.get("diagnostics", {})
    out = []
    if not diag.get("converged", False):
        out.append("NOT CONVERGED (" + ",".join(map(str, diag.get("failed_checks") or [])) + ")")
    if diag.get("fast_path_accepted") is False:
        out.append("fast→MCMC")
    for k, v in (d.get("flags") or {}).items():
        if k not in ("metadata_defaults",) and v:
            out.append(k)
    return "; ".join(out)


def summarize(rows, key):
    """Coverage per parameter and regime over identifiable truths; limit handling counts."""
    cov = defaultdict(lambda: [0, 0])  # (regime|"all", param) -> [inside, n]
    lim = defaultdict(lambda: [0, 0])
    for r in rows:
        sc = r.get(key)
        if sc is None:
            continue
        for p, rec in sc.items():
            if rec["verdict"] == "absent":
                continue
            for reg in (r["regime"], "all"):
                if rec["status"] == "identifiable" and rec["verdict"] == "limited":
                    c = lim[(reg, "identifiable reported as a lower limit")]
                    c[0] += 1
                    c[1] += 1
                elif rec["status"] == "identifiable":
                    c = cov[(reg, p)]
                    c[0] += rec["verdict"] == "ok"
                    c[1] += 1
                elif rec["status"] == "limit":
                    c = lim[(reg, p)]
                    c[0] += rec["verdict"] in ("ok", "detected")
                    c[1] += 1
    return cov, lim


def times(rows, key):
    t = [r[key]["wall_s"] for r in rows if key in r and "parameters" in r[key]]
    return (float(np.median(t)), float(np.max(t)), len(t)) if t else (float("nan"), float("nan"), 0)


def basler_row():
    ref = {k: v["value"] for k, v in json.loads(BASLER_REF.read_text()).items()}
    truth = {
        "conversion_gain_e_per_dn": 1 / ref["K"],
        "quantum_efficiency": ref["QE"] / 100,
        "prnu_percent": ref["PRNU1288"],
    }
    return truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--only",
        default=None,
        help="fit only sensors whose name contains this text (or one of several, comma-separated); no results file",
    )
    ap.add_argument("--no-fast", action="store_true")
    ap.add_argument("--jsonl", default=str(CACHE / "last_run.jsonl"), help="every fit's scores and flags")
    ap.add_argument(
        "--from-log",
        default=None,
        help="write the results file from a run's --jsonl log (a partial run lists its sensors only)",
    )
    ap.add_argument("--note", default="", help="a sentence for the results file's header (how this run was made)")
    a = ap.parse_args(argv)
    if a.from_log:
        recs = [json.loads(line) for line in open(a.from_log)]
        bas = next((r for r in recs if r["name"].startswith("basler")), None)
        rows = [r for r in recs if r is not bas]
        lines = report(
            rows,
            bas or {"name": "basler_ccd12 (real)", "regime": "real (reference)", "tags": ()},
            float("nan"),
            [r.get("load", float("nan")) for r in rows],
            a,
        )
        emit_lines(lines, OUT)
        return 0

    from _machine import emit

    import bayescap
    from bayescap.validation.zoo import PARAMETERS, ensure_csv, score, truths, zoo

    only = None if a.only is None else a.only.split(",")
    sensors = [z for z in zoo() if only is None or any(o in z.name for o in only)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bayescap.fit(str(BASLER), seed=1, quality="fast")  # imports and first-call costs out of the timings
    t_gen = time.perf_counter()
    paths = {z.name: ensure_csv(z, CACHE) for z in sensors}
    t_gen = time.perf_counter() - t_gen
    rows = []
    Path(a.jsonl).parent.mkdir(parents=True, exist_ok=True)
    load = []
    with open(a.jsonl, "w") as log:
        for z in sensors:
            tr = truths(z)
            row = {"name": z.name, "regime": z.regime, "tags": z.tags, "notes": z.notes, "load": _loadavg()}
            for q in ("standard",) + (() if a.no_fast else ("fast",)):
                load.append(_loadavg())
                d = fit_one(paths[z.name], q)
                row[q] = {"wall_s": d["wall_s"], "flags": flags_of(d)}
                if "parameters" in d:
                    row[q]["parameters"] = True
                    row[q]["converged"] = bool(d["diagnostics"].get("converged"))
                    row[f"score_{q}"] = score(tr, d)
                    row[f"fit_{q}"] = {p: d["parameters"].get(p) for p in PARAMETERS}
            print(
                f"{z.name:28s} {z.regime:15s} std {row['standard']['wall_s']:6.2f}s "
                + (f"fast {row['fast']['wall_s']:5.2f}s " if "fast" in row else "")
                + " ".join(f"{SHORT[p]}={cell(r)}" for p, r in row.get("score_standard", {}).items())
                + f" {row['standard']['flags']}",
                flush=True,
            )
            log.write(json.dumps(row, default=float) + "\n")
            rows.append(row)
        # the real Basler set against emva1288's reference values
        bas = {"name": "basler_ccd12 (real)", "regime": "real (reference)", "tags": (), "notes": ""}
        ref = basler_row()
        for q in ("standard",) + (() if a.no_fast else ("fast",)):
            d = fit_one(BASLER, q)
            bas[q] = {
                "wall_s": d["wall_s"],
                "flags": flags_of(d),
                "parameters": "parameters" in d,
                "converged": bool(d.get("diagnostics", {}).get("converged")),
            }
            if "parameters" in d:
                emva_k = d.get("derived", {}).get("emva1288_gain_e_per_dn")
                if emva_k is not None:
                    # with the response term K is the small-signal gain; emva1288's is its straight line
                    d = {**d, "parameters": {**d["parameters"], "conversion_gain_e_per_dn": emva_k}}
                bas[f"score_{q}"] = score({p: (v, "reference", "emva1288 1.0.2") for p, v in ref.items()}, d)
        log.write(json.dumps(bas, default=float) + "\n")
    lines = report(rows, bas, t_gen, load, a)
    emit(lines, None if a.only else OUT)
    return 0


def _load_text(load):
    load = [x for x in load if x == x]
    if not load:
        return "**Under load**: other sessions shared the 2 cores, so the times are upper bounds of an idle machine's. "
    return (
        f"**Under load**: other sessions shared the 2 cores (1-min load average {min(load):.1f}–{max(load):.1f} "
        "when the fits started), so the times are upper bounds of an idle machine's. "
    )


def _gen_text(t_gen):
    return f"Simulating the CSVs took {t_gen:.0f} s (cached afterwards)." if t_gen == t_gen else ""


def emit_lines(lines, out):
    from _machine import emit

    emit(lines, out)


def _loadavg():
    try:
        return float(open("/proc/loadavg").read().split()[0])
    except OSError:
        return float("nan")


def report(rows, bas, t_gen, load, a):
    from _machine import describe_machine

    from bayescap.validation.zoo import PARAMETERS, zoo

    NOTES.update({z.name: z.notes for z in zoo()})
    L = [
        "# Sensor zoo: truth in the 95 % interval, times, flags",
        "",
        "`python benchmarks/run.py zoo` (this file; `python benchmarks/zoo.py --only TEXT` for a subset). "
        f"{len(rows)} simulated sensors (`bayescap.validation.zoo`, frames from `bayescap.validation.framesim`, "
        "which shares no code with the likelihood) and the real Basler set. Seed 1, each fit alone and timed "
        "(CSV reading included, imports not). Machine: "
        + describe_machine()
        + ". "
        + _load_text(load)
        + _gen_text(t_gen),
        "",
        *([a.note, ""] if getattr(a, "note", "") else []),
        "Cells (standard fit): `ok` truth inside the 95 % interval; `miss`; **MISS>3w** a miss by more than "
        "three interval widths (a defect); `L` a truth the data cannot identify, reported as a limit "
        "(`constrained: false`) that holds it; `L+` such a truth detected in this realisation (a constrained 95 % "
        "interval that holds it); `L≥` an identifiable truth the fit reports only as a lower limit that holds it "
        "(its data flagged as biased: dark rows clipped at 0 DN; counted apart from the coverage); **L!** such a truth reported as constrained with an interval that excludes it; "
        "**L✗** a limit that "
        "excludes the truth; `(…)` a truth between identifiable and not (shown, not counted); `–` no such "
        "parameter in the fit; empty: not applicable (no spatial columns, one exposure time). "
        "Which truths count as identifiable: `bayescap.validation.zoo.truths`. The Basler row sets bayescap "
        "against emva1288's reference values (`miss (Nw)`: N interval widths apart; not counted): its K is "
        "`emva1288_gain_e_per_dn`, the standard's straight line through the fitted PTC, since the set's "
        "non-linearity makes bayescap's K the small-signal gain; QE and PRNU keep bayescap's definitions "
        "(QE over the small-signal gain, PRNU as the population value), which differ from the standard's.",
        "",
        "| sensor | regime | tags | "
        + " | ".join(SHORT[p] for p in PARAMETERS)
        + " | standard s | fast s | converged std/fast | flags (standard; fast) |",
        "|" + " --- |" * (len(PARAMETERS) + 7),
    ]
    for r in rows + [bas]:
        sc = r.get("score_standard", {})
        std, fast = r.get("standard", {}), r.get("fast", {})
        conv = "/".join(
            ("yes" if x.get("converged") else "**no**") if x.get("parameters") else "—" for x in (std, fast) if x
        )
        fl = "; ".join(x for x in (std.get("flags", ""), fast.get("flags", "") and "fast: " + fast["flags"]) if x)
        fl = _short(fl)
        cells = []
        for p in PARAMETERS:
            rec = sc.get(p)
            if rec is not None and rec["status"] == "reference":
                cells.append("ok" if rec.get("inside") else f"miss ({rec['miss_widths']:.1f}w)")
            else:
                cells.append(cell(rec))
        L.append(
            f"| {r['name']} | {r['regime']} | {', '.join(r['tags'])} | "
            + " | ".join(cells)
            + f" | {std.get('wall_s', float('nan')):.2f} | {fast.get('wall_s', float('nan')):.2f} | {conv} | {fl} |"
        )
    L += ["", "## Coverage of the identifiable truths (95 % intervals; target 92–98 %)", ""]
    for key, label in (("score_standard", "standard"), ("score_fast", "fast")):
        cov, lim = summarize(rows, key)
        if not cov:
            continue
        regimes = sorted({reg for reg, _ in cov if reg != "all"}) + ["all"]
        L += [f"**{label}** — inside / identifiable truths (%)", ""]
        L.append("| parameter | " + " | ".join(regimes) + " |")
        L.append("|" + " --- |" * (len(regimes) + 1))
        for p in PARAMETERS + ("all",):
            cells = []
            for reg in regimes:
                if p == "all":
                    i = sum(v[0] for (rg, _), v in cov.items() if rg == reg)
                    n = sum(v[1] for (rg, _), v in cov.items() if rg == reg)
                else:
                    i, n = cov.get((reg, p), (0, 0))
                cells.append(f"{i}/{n} ({100 * i / n:.0f} %)" if n else "")
            L.append(f"| {SHORT.get(p, p)} | " + " | ".join(cells) + " |")
        # how far each regime's coverage is from 95 %, in binomial standard deviations of its count
        zs = []
        for reg in regimes:
            i = sum(v[0] for (rg, _), v in cov.items() if rg == reg)
            n = sum(v[1] for (rg, _), v in cov.items() if rg == reg)
            zs.append(f"{(i / n - 0.95) / np.sqrt(0.95 * 0.05 / n):+.1f}" if n else "")
        L.append("| all: (coverage − 95 %) / binomial sd | " + " | ".join(zs) + " |")
        li = sum(v[0] for (rg, _), v in lim.items() if rg == "all")
        ln = sum(v[1] for (rg, _), v in lim.items() if rg == "all")
        L += ["", f"Non-identifiable truths reported as limits that hold them ({label}): {li}/{ln}.", ""]
    L += ["## Times (target: standard median ≤ 1 s, max ≤ 3 s; fast median ≤ 0.1 s, max ≤ 0.5 s)", ""]
    L += ["| preset | regime | median s | max s | fits |", "| --- | --- | --- | --- | --- |"]
    for q in ("standard", "fast"):
        for reg in sorted({r["regime"] for r in rows}) + ["all"]:
            sub = [r for r in rows if reg == "all" or r["regime"] == reg]
            med, mx, n = times(sub, q)
            if n:
                L.append(f"| {q} | {reg} | {med:.2f} | {mx:.2f} | {n} |")
    for q in ("standard", "fast"):
        fitted = [r for r in rows if r.get(q, {}).get("parameters")]
        refused = [r["name"] for r in rows if "refused" in r.get(q, {}).get("flags", "")]
        crashed = [r["name"] for r in rows if r.get(q, {}).get("flags", "").startswith("ERROR")]
        nc = [r["name"] for r in fitted if not r[q].get("converged")]
        L.append(
            f"\n{q}: {len(fitted)} fitted, {len(nc)} not converged ({', '.join(nc) or 'none'}), "
            f"{len(refused)} refused ({', '.join(refused) or 'none'}), {len(crashed)} crashed ({', '.join(crashed) or 'none'})."
        )
    L += ["", "## Defects found (the work list)", ""]
    for r in rows:
        items = []
        for q in ("standard", "fast"):
            x = r.get(q)
            if not x:
                continue
            if not x.get("parameters"):
                items.append(f"{q}: {x['flags']}")
                continue
            if not x.get("converged"):
                items.append(f"{q}: {x['flags']}")
            for p, rec in r.get(f"score_{q}", {}).items():
                if rec["verdict"] in ("MISS>3w", "claims-constrained", "limit-wrong") and rec["status"] != "unscored":
                    f = r.get(f"fit_{q}", {}).get(p) or {}
                    items.append(
                        f"{q}: {SHORT[p]} {rec['verdict']} (truth {rec['truth']:.4g}, fit {_fmt_fit(f)}; {rec['why']})"
                    )
        if items:
            note = f" [{NOTES[r['name']]}]" if NOTES.get(r["name"]) else ""
            L.append(
                f"* **{r['name']}** ({r['regime']}; {', '.join(r['tags']) or '-'}){note}: " + _short("; ".join(items))
            )
    return L


def _short(text):
    """Flags without the cache path of the CSV a refusal names."""
    return re.sub(r"\S+\.csv, ", "", text)


def _fmt_fit(f):
    if not f:
        return "—"
    if f.get("median") is None:
        return f"lower bound {f.get('lower_bound'):.4g}"
    lo, hi = f["ci95"]
    s = f"{f['median']:.4g} [{lo:.4g}, {hi:.4g}]"
    return s + (" unconstrained" if f.get("constrained") is False else "")


if __name__ == "__main__":
    sys.exit(main())
