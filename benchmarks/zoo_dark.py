"""The zoo's weak-dark-ramp family (issue 51): is a dark current the data cannot see printed as a limit?

    python benchmarks/run.py zoo_dark                 # writes benchmarks/results/zoo_dark.md
    python benchmarks/zoo_dark.py --only 8bit         # a subset (names containing the text), printed only

The sensors of :func:`bayescap.validation.zoo_dark.dark_family` (D·t_max from 10⁻³ to 1 of the read
variance, 8-16 bit, with and without DSNU, some with n_frames = 1) are simulated frame by frame by
:mod:`bayescap.validation.framesim` (CSVs cached in ``benchmarks/.zoo_cache/``) and fitted with
``bayescap.fit`` at ``standard`` quality (seed 1), one fit at a time. Each fit's dark current is scored
by :func:`~bayescap.validation.zoo_dark.score_dark`: it holds the truth when the truth is inside its 95 %
interval or below its printed upper limit; a detection where D·t_max < 1 % of the read variance is a
false detection. The other parameters are scored by the main zoo's
:func:`~bayescap.validation.zoo.score`. Targets (issue 51): the truth held in ≥ 95 % of the sensors,
no false detection.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "zoo_dark.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache"

from zoo import SHORT, cell, fit_one, flags_of  # noqa: E402  (the main zoo's fit and cells)


def run(only=None, quality="standard"):
    from bayescap.validation.zoo import ensure_csv, score, truths
    from bayescap.validation.zoo_dark import dark_family, score_dark

    rows = []
    sensors = [z for z in dark_family() if not only or only in z.name]
    fit_one(ensure_csv(sensors[0], CACHE), "fast")  # imports and first-call costs out of the timings
    for zs in sensors:
        path = ensure_csv(zs, CACHE)
        d = fit_one(path, quality)
        row = {"name": zs.name, "regime": zs.regime, "tags": list(zs.tags), "notes": zs.notes, "flags": flags_of(d)}
        row["wall_s"] = d.get("wall_s")
        if "parameters" in d:
            row["dark"] = score_dark(zs, d)
            row["score"] = score(truths(zs), d)
            p = d["parameters"].get("dark_current_e_per_s") or {}
            row["detection"] = p.get("detection")
            row["dark_note"] = p.get("note")
            row["converged"] = d["diagnostics"].get("converged")
        rows.append(row)
        print(json.dumps({k: row.get(k) for k in ("name", "dark", "flags")}, default=float), flush=True)
    return rows


def _fmt(x, digits=3):
    return "—" if x is None else f"{x:.{digits}g}"


def report(rows, quality):
    from _machine import describe_machine

    from bayescap.posterior.dark_current import RAMP_Z, ZERO_LIKELIHOOD_RATIO
    from bayescap.validation.zoo_dark import INVISIBLE_RATIO

    fitted = [r for r in rows if "dark" in r]
    held = sum(r["dark"]["holds"] for r in fitted)
    false = [r for r in fitted if r["dark"]["false_detection"]]
    invisible = [r for r in fitted if r["dark"]["ratio"] < INVISIBLE_RATIO]
    det = [r for r in fitted if r["dark"]["reported"] == "detection"]
    L = [
        "# The zoo's weak-dark-ramp family (issue 51)",
        "",
        f"`python benchmarks/run.py zoo_dark` — {len(rows)} sensors of "
        "`bayescap.validation.zoo_dark.dark_family`, simulated frame by frame by `bayescap.validation.framesim`, "
        f"fitted at `{quality}` quality (seed 1). Machine: {describe_machine()}.",
        "",
        "## Summary (targets: truth held ≥ 95 %, no detection where D·t_max < 1 % of the read variance)",
        "",
        f"* dark current held (inside the 95 % interval, or below the printed upper limit): "
        f"**{held}/{len(fitted)}** ({100 * held / max(len(fitted), 1):.0f} %)",
        f"* detections claimed where D·t_max < {100 * INVISIBLE_RATIO:g} % of the read variance: "
        f"**{len(false)}** of {len(invisible)} such sensors",
        f"* detections in all: {len(det)} (each holds the truth: "
        f"{sum(r['dark']['holds'] for r in det)}/{len(det)}); limits: {len(fitted) - len(det)}",
        f"* fits that failed: {len(rows) - len(fitted)}; not converged: "
        f"{sum(1 for r in fitted if not r.get('converged'))}",
        "",
        "## Per sensor",
        "",
        "Columns: D·t_max / σ_read²; the dark current's truth and what the fit prints (a limit `< x`, or "
        "median [95 %]); the detection tests (likelihood at D = 0 over its maximum, a detection needs "
        f"< {ZERO_LIKELIHOOD_RATIO:.3f}; the dark variances' ramp in standard errors, needs ≥ {RAMP_Z:g}; the dark "
        "means' own D ± sd, e⁻/s, — where the rounding bends them); the "
        "verdict; the main zoo's cells for K, read noise and DSNU (`ok`, `L` limit holding the truth, …).",
        "",
        "| sensor | tags | D·t/σ² | D truth | printed | L(0)/L̂ | ramp z | means' D | verdict | K | read | DSNU | s | flags |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        if "dark" not in r:
            L.append(f"| {r['name']} | | | | | | | | failed | | | | | {r['flags']} |")
            continue
        dk, det_ = r["dark"], r.get("detection") or {}
        if dk["reported"] == "limit":
            printed = f"< {_fmt(dk['value'])}"
        elif dk["reported"] == "detection":
            printed = f"{_fmt(dk['median'])} [{_fmt(dk['interval'][0])}, {_fmt(dk['interval'][1])}]"
        else:
            printed = "—"
        mw = det_.get("mean_ramp_e_per_s")
        means = "—" if mw is None else f"{mw:.3g} ± {det_.get('mean_ramp_sd_e_per_s'):.2g}"
        v = dk["verdict"]
        sc = r.get("score", {})
        L.append(
            f"| {r['name']} | {', '.join(t for t in r['tags'] if t != 'weak-dark') or '-'} | {dk['ratio']:.2g} | "
            f"{dk['truth']:.3g} | {printed} | {_fmt(det_.get('zero_likelihood_ratio'), 2)} | "
            f"{_fmt(det_.get('ramp_z'), 2)} | {means} | {v if v == 'ok' else '**' + v + '**'} | "
            f"{cell(sc.get('conversion_gain_e_per_dn'))} | {cell(sc.get('read_noise_e'))} | {cell(sc.get('dsnu_e'))} | "
            f"{_fmt(r.get('wall_s'), 2)} | {r['flags']} |"
        )
    L += ["", "Sensor notes: " + "; ".join(f"{r['name']}: {r['notes']}" for r in rows) + "."]
    L += [
        "",
        "Cells of the other parameters as in `zoo.md` (" + ", ".join(f"{v} = {k}" for k, v in SHORT.items()) + ").",
    ]
    return L


def main(argv=None):
    from _machine import emit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="fit only the sensors whose name contains this text (printed only)")
    ap.add_argument("--quality", default="standard")
    a = ap.parse_args(argv)
    rows = run(a.only, a.quality)
    emit(report(rows, a.quality), None if a.only or a.quality != "standard" else OUT)


if __name__ == "__main__":
    main()
