"""The non-linear zoo: coverage, all rows against the rows below 70 %, tight misses, outlier labels
and times on sensors whose response is not the model's (issue 46, item 6).

    python benchmarks/run.py zoo_nonlinear          # writes benchmarks/results/zoo_nonlinear.md
    python benchmarks/zoo_nonlinear.py --quick      # the 12-bit cameras (brighter-fatter: 12 and 14-bit), 16 sensors
    python benchmarks/zoo_nonlinear.py --only s_shape,knee   # names containing a text, printed only

The 42 sensors of :func:`bayescap.validation.zoo_nonlinear.nonlinear_zoo` (seven shapes × three
cameras × with and without ``photons_per_pixel``) are simulated frame by frame by
:mod:`bayescap.validation.framesim` (independent of the likelihood; CSVs cached in
``benchmarks/.zoo_cache/nonlinear/``). Each is fitted, seed 1, one fit at a time and timed:
``standard`` on every row, ``fast`` on every row, and ``standard`` on the rows whose signal is below
70 % of the largest (EMVA 1288's range). Scored with :func:`bayescap.validation.zoo.score` on the
issue's parameters (K, read noise or dark noise, η with photon counts, full well; all rows):

* coverage: truth inside the 95 % interval, per shape (target ≥ 92 %);
* overlap: K's 95 % intervals from all rows and from the rows below 70 % overlap (target ≥ 95 %);
* tight miss: the truth more than 3 half-widths outside an interval (target: none);
* outlier labels: rows the fit names outliers (every sensor here is smooth: target none);
* sampling time: the fit's ``diagnostics.wall_s`` (target: ``standard`` median ≤ 2 s).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import traceback
import warnings
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "zoo_nonlinear.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache" / "nonlinear"
BASLER = ROOT / "data" / "emva1288_basler_ccd12.csv"
SHORT = {
    "conversion_gain_e_per_dn": "K",
    "read_noise_e": "read",
    "dark_noise_e": "dark noise",
    "quantum_efficiency": "η",
    "full_well_e": "FW",
}
QUICK_CAMERAS = ("12bit", "14bit")


def _loadavg():
    try:
        return float(open("/proc/loadavg").read().split()[0])
    except OSError:
        return float("nan")


def fit_one(path, quality, n_jobs=None):
    """One fit's contract dict, its time, and ``draw_moments``: the posterior mean and sd of each
    scored parameter's draws (for the signed z-score (mean − truth)/sd)."""
    import bayescap
    from bayescap.exceptions import InputError

    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = bayescap.fit(str(path), seed=1, quality=quality, n_jobs=n_jobs)
            d = res.to_dict()
            draws = res.summary_draws()
            d["draw_moments"] = {p: [float(np.mean(draws[p])), float(np.std(draws[p]))] for p in SHORT if p in draws}
    except InputError as e:
        return {"refused": str(e).splitlines()[0][:200], "wall_s": time.perf_counter() - t0}
    except Exception as e:  # a crash is a finding to list, not a reason to stop the zoo
        return {
            "error": f"{type(e).__name__}: {e}"[:200],
            "trace": traceback.format_exc()[-600:],
            "wall_s": time.perf_counter() - t0,
        }
    d["wall_s"] = time.perf_counter() - t0
    return d


def summary_of(d, truths):
    """What the report needs from one fit."""
    from bayescap.validation.zoo import score

    if "parameters" not in d:
        return {"failed": d.get("refused") or d.get("error"), "wall_s": d["wall_s"]}
    diag = d.get("diagnostics", {})
    sc = score(truths, d)
    for rec in sc.values():  # distance in half-widths (the tight-miss unit)
        mw = rec.get("miss_widths")
        rec["miss_half_widths"] = 2 * mw if mw is not None and mw == mw else None
    k = d["parameters"].get("conversion_gain_e_per_dn", {})
    pars = {
        p: {x: d["parameters"][p].get(x) for x in ("median", "ci95", "constrained")}
        for p in SHORT
        if p in d["parameters"]
    }
    return {
        "params": pars,
        "wall_s": d["wall_s"],
        "sampling_s": diag.get("wall_s"),
        "converged": bool(diag.get("converged")),
        "k": [k.get("median"), *(k.get("ci95") or [None, None])],
        "score": sc,
        "outliers": [o["row"] for o in d.get("outliers", [])],
        "terms": d.get("model_terms", []),
        "flags": sorted(k for k, v in (d.get("flags") or {}).items() if v and k != "metadata_defaults"),
        "moments": d.get("draw_moments", {}),
    }


def run_sensor(z, paths, no_fast):
    from bayescap.validation.zoo_nonlinear import has_photons, output_clip_e, scored_truths, shape_of

    tr = scored_truths(z)
    row = {
        "name": z.name,
        "shape": shape_of(z),
        "camera": z.tags[2],
        "photons": has_photons(z),
        "notes": z.notes,
        "truths": {p: v[:2] for p, v in tr.items()},
        "output_clip_e": output_clip_e(z),
        "commit": _commit(),
        "load": _loadavg(),
    }
    p_all, p_low = paths
    row["standard"] = summary_of(fit_one(p_all, "standard"), tr)
    if not no_fast:
        row["fast"] = summary_of(fit_one(p_all, "fast"), tr)
    row["low70"] = summary_of(fit_one(p_low, "standard"), {"conversion_gain_e_per_dn": tr["conversion_gain_e_per_dn"]})
    return row


def overlap(row):
    a, b = row["standard"].get("k"), row["low70"].get("k")
    if not a or not b or None in a or None in b:
        return None
    return bool(a[1] <= b[2] and b[1] <= a[2])


def _pct(i, n):
    return f"{i}/{n} ({100 * i / n:.0f} %)" if n else "–"


def _verdict_cell(rec):
    if rec is None:
        return ""
    v = rec["verdict"]
    if v == "ok":
        return "ok"
    if v == "absent":
        return "–"
    if rec["status"] != "identifiable":
        return f"({v})"
    h = rec.get("miss_half_widths")
    if h is None:
        return v
    return f"**miss {h:.1f}h**" if h > 3 else f"miss {h:.1f}h"


def _fw_cell(r):
    """The full-well verdict, and whether the interval holds the output-referred clip instead."""
    rec = r["standard"].get("score", {}).get("full_well_e")
    c = _verdict_cell(rec)
    fw = r["standard"].get("params", {}).get("full_well_e")
    if rec and rec["verdict"] != "ok" and fw and fw.get("ci95") and None not in fw["ci95"]:
        lo, hi = fw["ci95"]
        if lo <= r["output_clip_e"] <= hi:
            c += " (holds (max−black)·K)"
    return c


def shape_stats(rows, key="standard"):
    """Per shape (and 'all'): inside/n per parameter, tight misses, overlaps, outlier labels, times."""
    st = defaultdict(lambda: defaultdict(lambda: [0, 0]))
    extra = defaultdict(lambda: {"tight": 0, "ov": [0, 0], "outl": [0, 0], "t": [], "tf": [], "failed": 0})
    for r in rows:
        for g in (r["shape"], "all"):
            e = extra[g]
            fit = r.get(key, {})
            if "score" not in fit:
                e["failed"] += 1
                continue
            for p, rec in fit["score"].items():
                if rec["status"] != "identifiable" or rec["verdict"] == "absent":
                    continue
                c = st[g]["noise" if p in ("read_noise_e", "dark_noise_e") else p]
                c[0] += rec["verdict"] == "ok"
                c[1] += 1
                h = rec.get("miss_half_widths")
                e["tight"] += int(rec["verdict"] != "ok" and h is not None and h > 3)
            ov = overlap(r)
            if ov is not None:
                e["ov"][0] += ov
                e["ov"][1] += 1
            e["outl"][0] += bool(fit["outliers"])
            e["outl"][1] += 1
            if fit.get("sampling_s") is not None:
                e["t"].append(fit["sampling_s"])
            f = r.get("fast", {})
            if f.get("sampling_s") is not None:
                e["tf"].append(f["sampling_s"])
    return st, extra


def _commit():
    try:
        return subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def report(rows, note, gen_s):
    from _machine import describe_machine

    from bayescap.validation.zoo_nonlinear import FAMILY

    commit = next((r["commit"] for r in rows if r.get("commit")), None) or _commit()
    load = [r["load"] for r in rows if r.get("load") == r.get("load")]
    L = [
        "# Non-linear zoo: response shapes and brighter-fatter",
        "",
        "`python benchmarks/run.py zoo_nonlinear` (this file; `python benchmarks/zoo_nonlinear.py --quick` for the "
        f"12-bit cameras, brighter-fatter also 14-bit). {len(rows)} simulated sensors "
        "(`bayescap.validation.zoo_nonlinear`: frames from `bayescap.validation.framesim`, which shares no code "
        "with the likelihood), code at commit {commit}. Seed 1, each fit alone; times are the fit's own "
        "sampling time (`diagnostics.wall_s`). Machine: ".replace("{commit}", commit)
        + describe_machine()
        + (
            f". **Under load**: other sessions shared the 2 cores (1-min load average {min(load):.1f}–{max(load):.1f} "
            "when the fits started), so the times are upper bounds of an idle machine's."
            if load
            else "."
        )
        + (f" Simulating the CSVs took {gen_s:.0f} s (cached afterwards)." if gen_s == gen_s else ""),
        "",
        *([note, ""] if note else []),
        "Scored (all rows, `standard`): K, read noise (dark noise with one exposure time), η (only with photon "
        "counts) and full well, truth inside the 95 % interval; truths in the fit's conventions "
        "(`bayescap.validation.zoo_nonlinear`: K the small-signal gain, full well the charge at which the mean "
        "pixel's output clips, CONTRACT.md's definition; through a compressive response that is more charge than "
        "(ADC max − black)·K, the output-referred clip the model reports as `full_well_e` on main: a full-well "
        "miss whose interval holds that instead is marked `(holds (max−black)·K)`, a convention rather than a "
        "wrong measurement, still counted as a miss). *K overlap*: K's 95 % intervals from all rows and from the rows whose signal is "
        "below 70 % of the largest overlap. *Tight miss*: a truth more than 3 half-widths outside its interval. "
        "*Outlier labels*: sensors with at least one row named an outlier (all these sensors are smooth).",
        "",
        "## Per shape (targets: checks ≥ 92 %, K overlap ≥ 95 %, no tight miss, no outlier label, "
        "`standard` median ≤ 2 s)",
        "",
        "| shape | K | read/dark noise | η | full well | all checks | K overlap | tight misses | sensors with outlier labels | standard s median (max) | fast s median |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    st, extra = shape_stats(rows)
    for g in [s for s in FAMILY if s in extra] + ["all"]:
        c = st[g]
        tot = [sum(v[0] for v in c.values()), sum(v[1] for v in c.values())]
        e = extra[g]
        t = e["t"]
        L.append(
            f"| {g} | {_pct(*c['conversion_gain_e_per_dn'])} | {_pct(*c['noise'])} | {_pct(*c['quantum_efficiency'])} "
            f"| {_pct(*c['full_well_e'])} | **{_pct(*tot)}** | {_pct(*e['ov'])} | {e['tight']} | {_pct(*e['outl'])} "
            + (f"| {np.median(t):.2f} ({max(t):.2f}) " if t else "| – ")
            + (f"| {np.median(e['tf']):.2f} |" if e["tf"] else "| – |")
            + (f" ({e['failed']} fits failed)" if e["failed"] else "")
        )
    # photons against no photons
    L += ["", "## With and without photon counts (all shapes; `standard`)", ""]
    L.append("| photon counts | sensors | all checks | K | K overlap | tight misses | sensors with outlier labels |")
    L.append("|---|---|---|---|---|---|---|")
    for ph in (True, False):
        sub = [r for r in rows if r["photons"] == ph]
        if not sub:
            continue
        s2, e2 = shape_stats(sub)
        c = s2["all"]
        tot = [sum(v[0] for v in c.values()), sum(v[1] for v in c.values())]
        e = e2["all"]
        L.append(
            f"| {'yes' if ph else 'no'} | {len(sub)} | {_pct(*tot)} | {_pct(*c['conversion_gain_e_per_dn'])} | "
            f"{_pct(*e['ov'])} | {e['tight']} | {_pct(*e['outl'])} |"
        )
    if any("fast" in r for r in rows):
        s3, e3 = shape_stats(rows, "fast")
        c = s3["all"]
        tot = [sum(v[0] for v in c.values()), sum(v[1] for v in c.values())]
        L += ["", f"`fast` on all rows: {_pct(*tot)} of the checks hold the truth, {e3['all']['tight']} tight misses."]
    L += [
        "",
        "## Per sensor",
        "",
        "Verdicts (`standard`, all rows): `ok`, `miss N.Nh` (N half-widths out; **bold** beyond 3), `–` no such "
        "parameter. K intervals are 95 %.",
        "",
        "| sensor | shape, strength | K all rows | K rows < 70 % | overlap | K | noise | η | FW | fast: K noise η FW | outlier rows | std s | fast s | terms / flags |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        s, lo, f = r["standard"], r["low70"], r.get("fast", {})
        sc = s.get("score", {})

        def kcell(x):
            k = x.get("k")
            if not k or None in k:
                return "failed: " + str(x.get("failed", ""))[:80]
            return f"{k[0]:.4g} [{k[1]:.4g}, {k[2]:.4g}]"

        noise = (
            sc.get("read_noise_e")
            if sc.get("read_noise_e", {}).get("status") == "identifiable"
            else sc.get("dark_noise_e")
        )
        fsc = f.get("score", {})
        fnoise = (
            fsc.get("read_noise_e")
            if fsc.get("read_noise_e", {}).get("status") == "identifiable"
            else fsc.get("dark_noise_e")
        )
        fast_cells = (
            " ".join(
                _verdict_cell(x) or "·"
                for x in (
                    fsc.get("conversion_gain_e_per_dn"),
                    fnoise,
                    fsc.get("quantum_efficiency"),
                    fsc.get("full_well_e"),
                )
            )
            if fsc
            else "–"
        )
        extra_terms = [
            t for t in s.get("terms", []) if t in ("response_nonlinearity", "variance_discrepancy", "brighter_fatter")
        ]
        flags = ", ".join(extra_terms + s.get("flags", []) + ([] if s.get("converged", True) else ["NOT CONVERGED"]))
        ov = overlap(r)
        L.append(
            f"| {r['name']} | {r['notes'].split(', ')[0]}, {r['notes'].split(', ')[1]} | {kcell(s)} | {kcell(lo)} | "
            f"{'yes' if ov else ('**no**' if ov is False else '–')} | "
            f"{_verdict_cell(sc.get('conversion_gain_e_per_dn'))} | {_verdict_cell(noise)} | "
            f"{_verdict_cell(sc.get('quantum_efficiency'))} | {_fw_cell(r)} | {fast_cells} | "
            f"{len(s.get('outliers', []))} | {s.get('sampling_s') or float('nan'):.2f} | "
            f"{f.get('sampling_s') or float('nan'):.2f} | {flags} |"
        )
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--only", default=None, help="sensors whose name contains one of these comma-separated texts; printed only"
    )
    ap.add_argument(
        "--quick", action="store_true", help="the 12-bit cameras (brighter-fatter: 12 and 14-bit), 16 sensors"
    )
    ap.add_argument("--no-fast", action="store_true", help="skip the fast fits")
    ap.add_argument("--jsonl", default=str(CACHE / "last_run.jsonl"), help="every sensor's record, as it runs")
    ap.add_argument("--from-log", default=None, help="write the results file from a run's --jsonl log")
    ap.add_argument("--note", default="", help="a sentence for the results file's header (how this run was made)")
    a = ap.parse_args(argv)
    from _machine import emit

    if a.from_log:
        rows = [json.loads(line) for line in open(a.from_log)]
        emit(report(rows, a.note, float("nan")), OUT)
        return 0

    import bayescap
    from bayescap.validation.zoo_nonlinear import ensure_csvs, nonlinear_zoo

    only = None if a.only is None else a.only.split(",")
    sensors = [
        z
        for z in nonlinear_zoo()
        if (only is None or any(o in z.name for o in only)) and (not a.quick or z.tags[2] in QUICK_CAMERAS)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bayescap.fit(str(BASLER), seed=1, quality="fast")  # imports and first-call costs out of the timings
    t = time.perf_counter()
    paths = {z.name: ensure_csvs(z, CACHE) for z in sensors}
    gen_s = time.perf_counter() - t
    Path(a.jsonl).parent.mkdir(parents=True, exist_ok=True)
    rows = []
    with open(a.jsonl, "w") as log:
        for z in sensors:
            r = run_sensor(z, paths[z.name], a.no_fast)
            s = r["standard"]
            print(
                f"{z.name:34s} K {s.get('k')} low70 {r['low70'].get('k')} overlap {overlap(r)} "
                + " ".join(f"{SHORT[p]}={_verdict_cell(v)}" for p, v in s.get("score", {}).items())
                + f" outliers {len(s.get('outliers', []))} std {s.get('sampling_s') or float('nan'):.2f}s",
                flush=True,
            )
            log.write(json.dumps(r, default=float) + "\n")
            log.flush()
            rows.append(r)
    note = a.note + (" A --quick run (one camera per shape)." if a.quick else "")
    emit(report(rows, note.strip(), gen_s), None if a.only else OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
