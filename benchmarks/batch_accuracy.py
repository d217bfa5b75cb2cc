"""The batch of simulated Gpixel ROIs: its throughput, and whether its accepted fast-path intervals
are right (the fast path against MCMC references).

    python benchmarks/batch_accuracy.py [--batch 1000] [--n 300] [--topped-up 30] [--plain 30] [--rejected 10]
                                        [--refs 4] [--first M] [--ref-cache DIR] [--set FIELD=VALUE ...]
    python benchmarks/batch_accuracy.py --quick

Writes ``benchmarks/results/batch_accuracy.md``.

**Throughput.** ``bayescap.batch.fit_many`` (fast preset, 2 processes, 64 sensors in lockstep) on the
first ``--batch`` ROIs of ``bayescap.batch.gpixel_sensors(seed=1)`` (32 × 32 pixels, 30 levels), with
the MCMC fallback where the fast path rejects (as ``fit_many`` runs by default) and without it:
wall time, accepted ROIs, the true K inside the 95 % interval. ``--batch 0`` skips it.

**Accuracy.** Issue 7 wants the fast preset's 95 % interval ends within 5 % of a reference run's
(relative to the width) whenever its own check accepts; ``speed_accuracy.py`` checks that on 51-row
CSVs, this on the batch's small ROIs, whose clip levels are long-tailed. Of the first ``--n`` ROIs,
with the seeds ``fit_many(seed=1)`` gives them, it takes up to ``--topped-up`` ROIs the fast path
accepted after topping up, up to ``--plain`` accepted without, and up to ``--rejected`` it rejected
(their intervals are not reported as results; measured to show what the rejection saves), and
compares every parameter's and capacity's 95 % interval ends with the pooled draws of ``--refs``
independent ``standard`` MCMC runs (each end's Monte Carlo error ~0.025 of the width alone, ~half
that pooled over 4). References that did not converge are counted apart.

With ``--first M`` it takes every one of the first M ROIs instead, whatever the fast path did (an
unbiased sample of the accepted ones, for comparing settings on the same ROIs), and with
``--ref-cache DIR`` keeps each ROI's pooled reference ends there (a JSON file per ROI and
reference count), so that other settings are measured against the same references. Over ~20 ends
a reference's own error adds to the worst one: 4 pooled runs (~0.0125 of the width an end) put
~0.03 into it alone, 16 (~0.006) ~0.015. ``--set`` changes a field of the fast path's
``FastSettings`` in both parts (e.g. ``--set end_confidence=0.99``, ``--set end_tolerance=0.1``).
``--quick``: 20 ROIs' throughput and 8 of the first 40 against 2 references each, 1–2 minutes.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "batch_accuracy.md"


def reference_ends(refs, names):
    """{name: (lo, hi, own end error / width pooled)} of the pooled draws of ``refs`` (FitResults):
    the 95 % ends and each run's ``interval_end_mcse`` averaged, / √refs; and how many converged."""
    out = {}
    for n in names:
        xs = [r.draws.get(n, r.derived.get(n)) for r in refs]
        if any(x is None for x in xs):
            continue
        x = np.concatenate([np.ravel(v) for v in xs])
        lo, hi = np.quantile(x, [0.025, 0.975])
        err = np.mean([float((r.diag.get("interval_end_mcse") or {}).get(n, np.nan)) for r in refs]) / np.sqrt(
            len(refs)
        )
        out[n] = (float(lo), float(hi), float(err))
    return out, sum(bool(r.diag["converged"]) for r in refs)


def worst_end(fast, ref, names, fast_mcse):
    """Worst |Δ end| / reference width over ``names`` (fast: the batch summary; ref: reference_ends),
    and per quantity the ratio of its worse end's |Δ| to the Monte Carlo error both sides predict
    (the fast path's ``fast_mcse[name]``, the references' pooled own error: about 1 in the median and
    ≤ 2 on ~95 % when the predictions are right)."""
    worst, wn, ratios = 0.0, "", []
    for n in names:
        if n not in ref:
            continue
        lo, hi, ref_err = ref[n]
        if not hi - lo > 0:
            continue
        e = max(abs(fast[n][0] - lo), abs(fast[n][2] - hi)) / (hi - lo)
        if e > worst:
            worst, wn = e, n
        pred = float(np.hypot(fast_mcse.get(n, np.nan), ref_err))
        if np.isfinite(pred) and pred > 0:
            ratios.append(e / pred)
    return worst, wn, ratios


def apply_sets(fs, sets):
    """``fs`` (FastSettings) with each "FIELD=VALUE" of ``sets``: 'none' for None, else the
    field's default's type (a bool from 0/1/true/false; a float where the default is None)."""
    from dataclasses import fields, replace

    defaults = {f.name: f.default for f in fields(fs)}
    for kv in sets:
        k, v = kv.split("=", 1)
        if k not in defaults:
            raise SystemExit(f"--set {kv}: FastSettings has no field {k!r}")
        d = defaults[k]
        if v.lower() == "none":
            val = None
        elif isinstance(d, bool):
            val = v.lower() in ("1", "true", "yes")
        elif isinstance(d, (int, float, str)):
            val = type(d)(v)
        else:
            val = float(v)
        fs = replace(fs, **{k: val})
    return fs


def batch_throughput(n, *, seed, n_jobs, stack_size=64, fallback=False, sets=()):
    """``sets``: "FIELD=VALUE" changes to the batch's FastSettings (``apply_sets``)."""
    from bayescap.batch import fit_many, gpixel_sensors
    from bayescap.exceptions import ConvergenceWarning
    from bayescap.inference.fast import FastSettings

    fs = apply_sets(FastSettings(), sets)

    t = time.perf_counter()
    datas, truths = gpixel_sensors(n_max=n, seed=seed)
    t_sim = time.perf_counter() - t
    t = time.perf_counter()
    with warnings.catch_warnings():
        # without the fallback every rejected sensor warns NOT CONVERGED: they are counted below
        warnings.simplefilter("ignore", ConvergenceWarning)
        res = fit_many(
            datas, seed=seed, n_jobs=n_jobs, fallback=fallback, summary_only=True, stack_size=stack_size, settings=fs
        )
    t_fit = time.perf_counter() - t
    acc = sum(r["accepted"] for r in res)
    conv = sum(r["converged"] for r in res)  # with the fallback: the result returned
    # (q2.5, q50, q97.5): the 95 % interval is [0] .. [2]
    kin = sum(
        r["conversion_gain_e_per_dn"][0] <= tr.conversion_gain_e_per_dn <= r["conversion_gain_e_per_dn"][2]
        for r, tr in zip(res, truths)
        if r["accepted"]
    )
    # why the rejected ones were: k̂/ESS, or the interval-end checks at the draw cap, or the
    # interval-end checks with draws to spare
    why = {
        "k̂ or IS ESS": 0,
        "interval ends, at the draw cap": 0,
        "other (below the cap, or a derived quantity's check)": 0,
    }
    for r in res:
        if r.get("accepted") or "error" in r:
            continue
        reason = r.get("reason", "")
        if "Pareto" in reason or "importance-sampling ESS" in reason:
            why["k̂ or IS ESS"] += 1
        elif f"after {fs.max_proposals} draws" in reason:
            why["interval ends, at the draw cap"] += 1
        else:
            why["other (below the cap, or a derived quantity's check)"] += 1
    # results flagged with imprecise interval ends (an MCMC fallback whose ends' Monte Carlo error is above
    # posterior.IMPRECISE_END_MCSE of the width), and the true K inside the fallbacks' intervals
    imprecise = sum(bool(r.get("imprecise_interval_ends")) for r in res)
    fb_kin = sum(
        r["conversion_gain_e_per_dn"][0] <= tr.conversion_gain_e_per_dn <= r["conversion_gain_e_per_dn"][2]
        for r, tr in zip(res, truths)
        if not r["accepted"] and "error" not in r and r.get("method") == "emcee"
    )
    return dict(
        n=len(datas),
        t_sim=t_sim,
        t_fit=t_fit,
        accepted=acc,
        k_inside=kin,
        n_jobs=n_jobs,
        stack_size=stack_size,
        fallback=fallback,
        converged=conv,
        sets=list(sets),
        rejected_why=why,
        imprecise=imprecise,
        fallback_k_inside=fb_kin,
    )


def batch_lines(batch):
    L = []
    if batch:
        L.append(
            "## Batch throughput "
            + ("with" if batch.get("fallback") else "without")
            + " the MCMC fallback (`bayescap.batch.fit_many`, fast preset"
            + (f"; FastSettings {', '.join(batch['sets'])}" if batch.get("sets") else "")
            + ")"
        )
        L.append("")
        L.append(
            f"{batch['n']} simulated Gpixel GSPRINT4521 ROIs×gains (data/gpixel_gsprint4521; 32×32-pixel "
            f"frames, 30 levels): simulation {batch['t_sim']:.0f} s; fit {batch['t_fit']:.0f} s with "
            f"n_jobs={batch['n_jobs']}, stack_size={batch.get('stack_size', 1)} "
            f"= {batch['t_fit'] / batch['n'] * 1e3:.0f} ms/sensor; fast path "
            f"accepted on {batch['accepted']}/{batch['n']}; true K inside the 95 % interval on "
            f"{batch['k_inside']}/{batch['accepted']} accepted "
            + (
                f"(the others ran the MCMC fallback, its time included; converged in the end: "
                f"{batch['converged']}/{batch['n']})."
                if batch.get("fallback")
                else "(no MCMC fallback in this measurement)."
            )
        )
        if batch.get("rejected_why"):
            L.append("")
            L.append(
                "Rejected by the fast path's check: "
                + ", ".join(f"{k} {v}" for k, v in batch["rejected_why"].items())
                + "."
            )
        if batch.get("fallback"):
            n_fb = batch["n"] - batch["accepted"]
            L.append("")
            L.append(
                f"MCMC fallbacks: true K inside the 95 % interval on {batch.get('fallback_k_inside', '?')}/{n_fb}; "
                f"results flagged `imprecise_interval_ends` (an interval end's Monte Carlo error above 0.1 of "
                f"the width): {batch.get('imprecise', '?')}/{batch['n']}."
            )
        L.append("")
    return L


_WORKER = {}


def _reference_job(args):
    """One ROI's references: (i, reference_ends, converged count)."""
    i, n_max, n_refs = args
    warnings.simplefilter("ignore")
    import bayescap
    from bayescap.batch import gpixel_sensors

    if _WORKER.get("n_max") != n_max:  # the ROIs' data, once
        _WORKER.update(n_max=n_max, datas=gpixel_sensors(n_max=n_max, seed=1)[0])
    datas = _WORKER["datas"]
    refs = [bayescap.fit(datas[i], seed=1000 + 10 * i + k, quality="standard") for k in range(n_refs)]
    names = set(refs[0].draws) | {"capacity_bits", "capacity_bits_per_pixel"}
    ref, n_conv = reference_ends(refs, sorted(names))
    return i, ref, n_conv


def references(idx, n_max, n_refs, cache_dir=None):
    """{i: (reference_ends, converged count)} for the ROIs ``idx`` (each MCMC run's ensembles in a
    process per core; cached in ``cache_dir`` by ROI, reference count and ``n_max``, which fixes the
    ROI's data)."""
    import json

    out, todo = {}, []
    for i in idx:
        f = None if cache_dir is None else Path(cache_dir) / f"roi{i}_n{n_max}_refs{n_refs}.json"
        if f is not None and f.exists():
            d = json.loads(f.read_text())
            out[i] = ({k: tuple(v) for k, v in d["ref"].items()}, d["n_conv"])
        else:
            todo.append(i)
    for i in todo:
        _, ref, n_conv = _reference_job((i, n_max, n_refs))
        out[i] = (ref, n_conv)
        if cache_dir is not None:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            f = Path(cache_dir) / f"roi{i}_n{n_max}_refs{n_refs}.json"
            tmp = f.with_suffix(".tmp")
            tmp.write_text(json.dumps({"ref": ref, "n_conv": n_conv}))
            os.replace(tmp, f)
        print(f"reference ROI {i}: {n_conv}/{n_refs} converged", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--quick", action="store_true", help="--batch 20 --n 40 --topped-up 3 --plain 3 --rejected 2 --refs 2"
    )
    ap.add_argument("--batch", type=int, default=None, help="ROIs in the throughput run (default 1000; 0 skips it)")
    ap.add_argument("--n", type=int, default=None, help="ROIs the accuracy part picks from (default 300)")
    ap.add_argument("--topped-up", type=int, default=None, help="default 30")
    ap.add_argument("--plain", type=int, default=None, help="default 30")
    ap.add_argument("--rejected", type=int, default=None, help="default 10")
    ap.add_argument("--refs", type=int, default=None, help="standard runs pooled per reference (default 4)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="a FastSettings field (int, float or 'none'), repeatable",
    )
    ap.add_argument(
        "--first",
        type=int,
        default=None,
        help="every one of the first FIRST ROIs instead of --topped-up/--plain/--rejected",
    )
    ap.add_argument("--ref-cache", default=None, help="directory keeping the references' pooled ends")
    a = ap.parse_args(argv)
    quick = dict(batch=20, n=40, topped_up=3, plain=3, rejected=2, refs=2)
    full = dict(batch=1000, n=300, topped_up=30, plain=30, rejected=10, refs=4)
    for k, v in (quick if a.quick else full).items():
        if getattr(a, k) is None:
            setattr(a, k, v)
    warnings.simplefilter("ignore")
    from _machine import describe_machine, emit

    import bayescap  # noqa: F401
    from bayescap.batch import _summary, fit_many, gpixel_sensors
    from bayescap.inference.fast import FastSettings

    fs = apply_sets(FastSettings(), a.set)
    t_all = time.perf_counter()
    load_before = os.getloadavg()
    batch = (
        [batch_throughput(a.batch, seed=1, n_jobs=2, stack_size=64, fallback=fb, sets=a.set) for fb in (True, False)]
        if a.batch
        else []
    )
    datas, truths = gpixel_sensors(n_max=a.n, seed=1)
    t = time.perf_counter()
    # FitResults, for their diagnostics: in this process (fit_many's workers cannot send a FitResult
    # back, its derived-quantity function does not pickle); the seeds and results do not depend on n_jobs
    full = fit_many(datas, seed=1, n_jobs=1, fallback=False, settings=fs)
    t_fast = time.perf_counter() - t
    picks = {"topped up": [], "plain": [], "rejected": []}
    for i, r in enumerate(full):
        acc = bool(r.diag.get("fast_path_accepted", r.diag.get("converged")))
        kind = "rejected" if not acc else ("topped up" if r.chains.extra.get("n_topup") else "plain")
        cap = {"topped up": a.topped_up, "plain": a.plain, "rejected": a.rejected}[kind]
        if (i < a.first) if a.first is not None else len(picks[kind]) < cap:
            picks[kind].append(i)
    chosen = sorted(i for v in picks.values() for i in v)
    n_cached = (
        sum((Path(a.ref_cache) / f"roi{i}_n{a.n}_refs{a.refs}.json").exists() for i in chosen) if a.ref_cache else 0
    )
    ref_all = references(chosen, a.n, a.refs, a.ref_cache)
    picks_all = [bool(r.diag.get("fast_path_accepted", r.diag.get("converged"))) for r in full]
    rows, summary, signed = [], {}, {}
    for kind, idx in picks.items():
        errs, bad_ref, ratios = [], 0, []
        for i in idx:
            fast = _summary(full[i])
            names = [k for k, v in fast.items() if isinstance(v, tuple)]
            ref, n_conv = ref_all[i]
            e, wn, rat = worst_end(fast, ref, names, full[i].diag.get("interval_end_mcse") or {})
            if kind != "rejected" and n_conv == a.refs:
                for n in names:
                    if n in ref and ref[n][1] > ref[n][0]:
                        w_ref = ref[n][1] - ref[n][0]
                        signed.setdefault(n, []).append(
                            ((fast[n][0] - ref[n][0]) / w_ref, (fast[n][2] - ref[n][1]) / w_ref)
                        )
            pred = full[i].diag.get("interval_end_mcse_max", float("nan"))
            draws = int(full[i].chains.extra["n_proposals"])
            khat = float(full[i].chains.extra["khat"])
            rows.append(
                f"| {i} | {kind} | {draws} | {khat:.2f} | {pred:.3f} | {e:.3f} | {wn} | "
                f"{np.median(rat):.2f} / {max(rat):.2f} | {n_conv}/{a.refs} |"
            )
            print(rows[-1], flush=True)
            if n_conv == a.refs:
                errs.append(e)
                ratios += rat
            else:
                bad_ref += 1
        summary[kind] = (len(idx), errs, bad_ref, ratios)
    how = (
        f"--first {a.first}"
        if a.first is not None
        else f"--topped-up {a.topped_up} --plain {a.plain} --rejected {a.rejected}"
    )
    L = [
        "# The batch of simulated Gpixel ROIs: throughput and accuracy",
        "",
        f"Generated by `python benchmarks/batch_accuracy.py --batch {a.batch} --n {a.n} {how} --refs {a.refs}"
        f"{''.join(f' --set {kv}' for kv in a.set)}` in {time.perf_counter() - t_all:.0f} s"
        + (
            f" (with `--ref-cache`: {n_cached} of the {len(ref_all)} ROIs' references from earlier runs)"
            if a.ref_cache
            else ""
        )
        + ".",
        f"Machine: {describe_machine()}. Load average before {', '.join(f'{x:.2f}' for x in load_before)}, "
        f"after {', '.join(f'{x:.2f}' for x in os.getloadavg())}.",
        "",
    ]
    for b in batch:
        L += batch_lines(b)
    L += [
        "## The fast path's intervals against MCMC references",
        "",
        f"ROIs of `gpixel_sensors(n_max={a.n}, seed=1)` with `fit_many(seed=1)`'s seeds (fast settings: gate "
        f"{fs.end_mcse_max}, joint confidence {fs.end_confidence} within {fs.end_tolerance:g}, {fs.topup} top-up, "
        f"{fs.n_proposals} draws first, at most {fs.max_proposals}; the {a.n} fast paths "
        f"{t_fast:.1f} s in one process, {sum(picks_all)} accepted); reference: the pooled draws of "
        f"{a.refs} `standard` MCMC runs with other seeds. Error: the worst |Δ end| over every parameter and "
        "capacity as a fraction of the reference's 95 % width. A rejected ROI's intervals are not a result "
        "(production runs the MCMC fallback); they are measured here to show what the rejection catches.",
        "",
        "Ratio: per quantity, its worse end's |Δ| over the error both sides predict (the fast path's "
        "`interval_end_mcse`, the references' own / √refs, in quadrature); right predictions give ~0.7–1.05 in "
        "the median and ≤ 2 on 91–95 % (speed_accuracy.md's summary).",
        "",
        # with another end_tolerance (--set end_tolerance=...), also the count within it
        "| kind | ROIs | references all converged | worst end within 0.05 | "
        + ("" if fs.end_tolerance == 0.05 else f"worst end within {fs.end_tolerance:g} | ")
        + "worst end error: median / max | ratio: median, ≤ 2 |",
        "|---|---|---|---|---|---|" + ("" if fs.end_tolerance == 0.05 else "---|"),
    ]
    for kind, (n, errs, bad, rat) in summary.items():
        if errs:
            L.append(
                f"| {kind} | {n} | {n - bad} | {sum(e <= 0.05 for e in errs)}/{len(errs)} | "
                + ("" if fs.end_tolerance == 0.05 else f"{sum(e <= fs.end_tolerance for e in errs)}/{len(errs)} | ")
                + f"{np.median(errs):.3f} / {max(errs):.3f} | {np.median(rat):.2f}, "
                f"{100 * np.mean(np.asarray(rat) <= 2):.0f} % of {len(rat)} |"
            )
        else:
            L.append(f"| {kind} | {n} | {n - bad} | – | " + ("" if fs.end_tolerance == 0.05 else "– | ") + "– | – |")
    # the signed errors, accepted ROIs: the worst-end counts above mix Monte Carlo scatter, which
    # the fast path predicts, with a systematic shift, which it cannot see from its own draws
    L += [
        "",
        "Signed error of each end (fast − reference, / reference width) over the accepted ROIs with "
        "converged references: mean ± its standard error, and sd. A positive lower and a negative upper "
        "mean: intervals narrower than the reference's.",
        "",
        "| quantity | ROIs | lower end: mean ± se, sd | upper end: mean ± se, sd |",
        "|---|---|---|---|",
    ]
    for n in sorted(signed):
        v = np.asarray(signed[n])
        se = v.std(axis=0, ddof=1) / np.sqrt(len(v)) if len(v) > 1 else np.full(2, np.nan)
        L.append(
            f"| {n} | {len(v)} | "
            + " | ".join(
                f"{v[:, j].mean():+.4f} ± {se[j]:.4f}, {v[:, j].std(ddof=1) if len(v) > 1 else np.nan:.4f}"
                for j in (0, 1)
            )
            + " |"
        )
    L += [
        "",
        "| ROI | kind | draws | k̂ | predicted worst end error | observed worst end error | quantity | "
        "ratio: median / max | references converged |",
        "|---|---|---|---|---|---|---|---|---|",
    ] + rows
    emit(L, OUT)


if __name__ == "__main__":
    main()
