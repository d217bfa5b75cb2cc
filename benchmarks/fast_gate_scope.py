"""What scoping the fast path's interval-end gate to the reported parameters would buy.

    python benchmarks/run.py fast_gate_scope    # writes benchmarks/results/fast_gate_scope.md
    python benchmarks/fast_gate_scope.py --only basler,pc_   # a subset, printed only

At ``quality="fast"`` the Laplace–IS path tops up its importance draws (6 000, at most 24 000) until
the predicted Monte Carlo error of every 95 % interval end (every physical parameter and the
derived quantities) is below a joint target (``FastSettings.end_mcse_max`` 0.035 of the width,
lowered by ``end_confidence`` over the number of ends). ``FastSettings.end_parameters`` restricts
the top-up and that gate to named physical parameters; the derived quantities are then checked by
the result (``bayescap.api.fit``: one above 0.035 sends the fit to the MCMC fallback) and the other
parameters are not checked at all. This measures, without changing the package, three variants on
the real Basler set, 13 linear-zoo sensors and 6 non-linear-zoo sensors (CSVs from
``benchmarks/.zoo_cache/``, simulated frame by frame when missing), each fitted with
``bayescap.fit(quality="fast", seed=1)`` in this one process:

* ``default``: ``FastSettings()`` (every physical parameter and the derived quantities gated);
* ``printed``: ``end_parameters`` = the parameters the text report prints in its parameter table
  (``bayescap.report.text.format_text``: every entry of ``parameters`` except the response's shape
  coefficients ``response_shape_*``; as intervals, or as limits where unconstrained), taken per
  sensor from the default fit's parameters;
* ``headline``: ``end_parameters`` = the eight EMVA 1288 parameters at the head of
  ``PARAMETER_ORDER`` (K, read noise, dark noise, dark current, full well, QE, PRNU, DSNU), leaving
  the nuisance terms (clip spread, discrepancies, response non-linearity, brighter-fatter, pixel
  offset spread) unjudged.

Per fit: CPU seconds (``time.process_time`` around ``bayescap.fit``, the least of 2 repeats; a first Basler fit takes the
imports out), importance draws (``n_proposals``, ``n_topup``), accepted or fell back to MCMC, the
worst interval-end error over the gated set and over every quantity the JSON reports
(``diagnostics.interval_end_mcse``) plus the ungated physical parameters (recomputed here with
``bayescap.inference.end_errors.interval_end_mcse`` on the weighted draws, counting the
resampling, as the fast path does), and the zoo's scorer (``bayescap.validation.zoo.score``) on the
truths (the Basler set has none: emva1288 reference values are not truths, so it is not scored).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "fast_gate_scope.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache"
BASLER = ROOT / "data" / "emva1288_basler_ccd12.csv"

#: a spread of the linear zoo's regimes (8-bit, sub-DN, photon-counting, typical, scientific; one
#: sensor whose fast path falls back to MCMC in benchmarks/results/zoo.md)
LINEAR = (
    "i37_8bit_k100_dsnu",
    "b8_k40_read1",
    "nf1_8bit",
    "b8_k20_half_black",
    "sub_10bit_read0p3_dsnu1",
    "sub_14bit_read0p4_floor",
    "i37_16bit_photon_counting",
    "pc_qcmos_k0p1",
    "pc_k0p05_16bit",
    "acq_roi_1000",
    "acq_well_clip_spread",
    "acq_unsaturated_16bit",
    "draw18_14bit",
)
#: one per non-linear shape but the soft knee (its fast fits are the zoo's slowest), cameras mixed
NONLINEAR = (
    "nl_quadratic_12bit_ph",
    "nl_cubic_16bit_ph",
    "nl_quartic_8bit_noph",
    "nl_s_shape_12bit_ph",
    "nl_two_slope_12bit_noph",
    "nl_brighter_fatter_12bit_ph",
)
VARIANTS = ("default", "printed", "headline")


def _settings(variant, printed):
    from bayescap.inference import FastSettings
    from bayescap.posterior.summary import PARAMETER_ORDER

    if variant == "default":
        return FastSettings()
    if variant == "printed":
        return FastSettings(end_parameters=tuple(printed))
    return FastSettings(end_parameters=tuple(PARAMETER_ORDER[:8]))


def _ungated_physical(res, have):
    """{physical parameter: interval-end error / width} for the parameters not in ``have``,
    recomputed on the fast path's weighted draws ({} after an MCMC fallback)."""
    from bayescap.inference.end_errors import _varies, interval_end_mcse

    wd = res.chains.extra.get("weighted_draws") if res.chains.extra else None
    if not wd or not hasattr(res.model, "physical"):
        return {}
    with np.errstate(all="ignore"):
        phys = res.model.physical(wd["x"])
    return {
        n: float(interval_end_mcse(v, wd["w"], n_resampled=wd["n_resampled"]))
        for n, v in phys.items()
        if n not in have and np.size(v) == len(wd["w"]) and _varies(v)
    }


def _worst(d):
    if not d:
        return (float("nan"), "")
    n = max(d, key=lambda k: d[k] if np.isfinite(d[k]) else np.inf)
    return (float(d[n]), n)


def fit_variant(path, variant, printed, truths, repeats=2):
    """One variant's fit of ``path``, repeated ``repeats`` times (the same seed: the same numbers,
    checked) and timed by the least CPU time of the repeats (the others' load adds, never removes)."""
    import json

    import bayescap
    from bayescap.validation.zoo import score

    fs = _settings(variant, printed)
    cpus, dumps = [], set()
    for _ in range(repeats):
        t0 = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = bayescap.fit(str(path), seed=1, quality="fast", fast_settings=fs)
        cpus.append(time.process_time() - t0)
        d = res.to_dict()
        dumps.add(json.dumps(d["parameters"], sort_keys=True, default=str))
    if len(dumps) != 1:
        raise RuntimeError(f"{path}: {variant}: the same seed gave different parameters")
    cpu = min(cpus)
    dg = d["diagnostics"]
    accepted = dg.get("fast_path_accepted", dg.get("method") == "laplace-is")
    rep = {k: float(v) for k, v in (dg.get("interval_end_mcse") or {}).items()}
    extra = _ungated_physical(res, rep) if accepted else {}
    gated_names = None if fs.end_parameters is None else set(fs.end_parameters)
    gated = {k: v for k, v in rep.items() if gated_names is None or k in gated_names}
    ungated = {**{k: v for k, v in rep.items() if k not in gated}, **extra}
    sc = score(truths, d) if truths else {}
    cov = [rec["verdict"] == "ok" for rec in sc.values() if rec["status"] == "identifiable"]
    return {
        "cpu_s": cpu,
        "params": [p for p in d["parameters"] if not p.startswith("response_shape_")],
        "accepted": bool(accepted),
        "converged": bool(dg.get("converged")),
        "reason": dg.get("fallback_reason", ""),
        "n_proposals": dg.get("n_proposals") if accepted else None,
        "n_topup": dg.get("n_topup", 0) if accepted else None,
        "worst_gated": _worst(gated),
        "worst_all": _worst({**rep, **extra}),
        "worst_ungated": _worst(ungated),
        "n_ungated_above_gate": sum(1 for v in ungated.values() if not v <= 0.035) if accepted else 0,
        "n_not_in_json": len(extra),
        "cov": (sum(cov), len(cov)),
        "ci": {p: d["parameters"][p].get("ci95") for p in d["parameters"] if not p.startswith("response_shape_")},
    }


def sensors(only):
    from bayescap.validation.zoo import ensure_csv, truths, zoo
    from bayescap.validation.zoo_nonlinear import ensure_csvs, nonlinear_zoo, scored_truths

    out = [("basler_ccd12 (real)", "real", BASLER, {})]
    lin = {z.name: z for z in zoo()}
    for n in LINEAR:
        z = lin[n]
        out.append((n, z.regime, ensure_csv(z, CACHE), truths(z)))
    nl = {z.name: z for z in nonlinear_zoo()}
    for n in NONLINEAR:
        z = nl[n]
        out.append((n, "non-linear", ensure_csvs(z, CACHE)[0], scored_truths(z)))
    return [s for s in out if only is None or any(o in s[0] for o in only)]


def _f(x, spec=".3f"):
    return "n/a" if x is None or x != x else format(x, spec)


def report(rows):
    from _machine import describe_machine

    L = [
        "# Scoping the fast path's interval-end gate: what it buys",
        "",
        "`python benchmarks/run.py fast_gate_scope` (this file; `--only TEXT` for a subset, printed only). "
        "The Laplace–IS fast path tops up its importance draws (6 000, at most 24 000) until the predicted Monte "
        "Carlo error of every 95 % interval end is below a joint target (`end_mcse_max` 0.035 of the width, "
        "lowered by `end_confidence` over the number of ends judged). `FastSettings.end_parameters` restricts the "
        "top-up and the gate to named physical parameters; the derived quantities are then checked by the result "
        "(`bayescap.api.fit`: one above 0.035 sends the fit to the MCMC fallback), the other parameters not at all. "
        f"{len(rows)} sensors (the real Basler set, linear-zoo and non-linear-zoo sensors from `benchmarks/.zoo_cache/`), "
        'each fitted with `bayescap.fit(quality="fast", seed=1)` per variant, in one process; the package is not changed.',
        "",
        "Variants:",
        "",
        "* `default`: `FastSettings()`: the top-up and the gate judge every physical parameter and the derived quantities.",
        "* `printed`: `FastSettings(end_parameters=…)` with the parameters the text report prints in its "
        "parameter table (every entry of `parameters` but `response_shape_*`), per sensor from its default fit; "
        "the derived quantities are checked afterwards by the result (above 0.035 of the width: MCMC fallback).",
        "* `headline`: `end_parameters` = the eight EMVA 1288 parameters (K, read noise, dark noise, dark current, "
        "full well, QE, PRNU, DSNU); clip spread, discrepancies, non-linearity etc. are not judged.",
        "",
        f"Machine: {describe_machine()}. CPU seconds: `time.process_time` around `bayescap.fit`, the least of "
        "2 repeats (same seed, identical parameters checked), one process, "
        "seed 1, the other sessions' load shares the 2 cores (CPU time is less sensitive to it than wall time).",
        "",
        "## Summary",
        "",
        "| variant | fits | median CPU s | total CPU s | median draws | fits at 24 000 draws | fast→MCMC | "
        "coverage (identifiable truths in 95 %) | worst end error, gated set (median / max) | worst end error, "
        "every quantity: the JSON's and the recomputed ungated parameters' (median / max) | largest ungated end error (quantity) | ungated ends > 0.035 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in VARIANTS:
        rs = [r[v] for r in rows if v in r]
        if not rs:
            continue
        cpu = [r["cpu_s"] for r in rs]
        draws = [r["n_proposals"] for r in rs if r["accepted"]]
        cov = np.sum([r["cov"] for r in rs], axis=0)
        wg = [r["worst_gated"][0] for r in rs if r["accepted"]]
        wa = [r["worst_all"][0] for r in rs if r["accepted"]]
        ung = [(r["worst_ungated"], row["name"]) for row in rows for r in [row.get(v)] if r and r["accepted"]]
        ung = [u for u in ung if u[0][0] == u[0][0]]
        big = max(ung, key=lambda u: u[0][0]) if ung else None
        L.append(
            f"| {v} | {len(rs)} | {np.median(cpu):.2f} | {np.sum(cpu):.1f} | "
            + (f"{np.median(draws):.0f}" if draws else "n/a")
            + f" | {sum(1 for x in draws if x >= 24000)} | {sum(not r['accepted'] for r in rs)} | "
            f"{cov[0]}/{cov[1]} ({100 * cov[0] / max(cov[1], 1):.0f} %) | "
            + (f"{np.median(wg):.3f} / {np.max(wg):.3f}" if wg else "n/a")
            + " | "
            + (f"{np.median(wa):.3f} / {np.max(wa):.3f}" if wa else "n/a")
            + " | "
            + (f"{big[0][0]:.3f} ({big[0][1]}, {big[1]})" if big else "none")
            + f" | {sum(r['n_ungated_above_gate'] for r in rs)} |"
        )
    L += [
        "",
        "Draws, end errors and the ungated column are over the fits the fast path accepted (after a "
        "fallback the MCMC's own end errors are reported, not the importance draws'). Coverage counts "
        "the zoo scorer's identifiable truths (`bayescap.validation.zoo.score`); the Basler set has no "
        "truths and is not scored. The ungated physical parameters' errors (in `headline`: clip spread, "
        "discrepancies, non-linearity, …; in `printed`: `response_shape_*`) are recomputed here from the weighted "
        "draws: the fit's JSON (`diagnostics.interval_end_mcse`) and its text carry only the gated parameters' and "
        "the derived quantities' errors, so the user sees none of them"
        f" ({sum(r[v]['n_not_in_json'] for r in rows for v in VARIANTS if v in r)} such parameter errors "
        "over these fits). A fallback's reason names what the fast path or the result's check rejected.",
        "",
        "## Per sensor",
        "",
        "| sensor | regime | variant | CPU s | draws (top-up) | fast path | worst gated end (quantity) | "
        "worst end, all (quantity) | worst ungated end (quantity) | truths in 95 % |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for v in VARIANTS:
            r = row.get(v)
            if r is None:
                continue
            fp = "accepted" if r["accepted"] else f"→MCMC ({r['reason'][:160]})"
            L.append(
                f"| {row['name']} | {row['regime']} | {v} | {r['cpu_s']:.2f} | "
                + (f"{r['n_proposals']} ({r['n_topup']})" if r["accepted"] else "–")
                + f" | {fp} | {_f(r['worst_gated'][0])} ({r['worst_gated'][1]}) | "
                f"{_f(r['worst_all'][0])} ({r['worst_all'][1]}) | "
                + (
                    f"{_f(r['worst_ungated'][0])} ({r['worst_ungated'][1]})"
                    if r["worst_ungated"][1] and r["accepted"]
                    else "–"
                )
                + " | "
                + (f"{r['cov'][0]}/{r['cov'][1]}" if r["cov"][1] else "–")
                + " |"
            )
    L += ["", "## Printed parameters per sensor (the `printed` variant's gate)", ""]
    for row in rows:
        if "default" in row:
            L.append(f"* {row['name']}: {', '.join(row['default']['params'])}")
    return L


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--only", default=None, help="sensors whose name contains this text (comma-separated); no results file"
    )
    a = ap.parse_args(argv)
    from _machine import emit

    import bayescap

    only = None if a.only is None else a.only.split(",")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bayescap.fit(str(BASLER), seed=1, quality="fast")  # imports and first-call costs out of the timings
    rows = []
    for name, regime, path, truths in sensors(only):
        row = {"name": name, "regime": regime}
        printed = None
        for v in VARIANTS:
            r = fit_variant(path, v, printed, truths)
            if v == "default":
                printed = r["params"]
            row[v] = r
            print(
                f"{name:30s} {v:9s} cpu {r['cpu_s']:6.2f}s draws {r['n_proposals']} acc {r['accepted']} "
                f"gated {_f(r['worst_gated'][0])} {r['worst_gated'][1]} all {_f(r['worst_all'][0])} "
                f"{r['worst_all'][1]} ungated {_f(r['worst_ungated'][0])} {r['worst_ungated'][1]} cov {r['cov']}",
                flush=True,
            )
        rows.append(row)
    emit(report(rows), None if a.only else OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
