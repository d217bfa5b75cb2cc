"""The fast path's speed-for-accuracy knob: the number of importance draws.

    python benchmarks/fast_tradeoff.py [--n-sim 4] [--seeds 4] [--sizes 1500,3000,6000,12000] [--rounds 1,3]
                                       [--floor 0.1] [--gate none,0.02] [--tails 0,0.05] [--floor-pair 0,1] [--ref-cache DIR]
                                       [--adapt-nu none,10] [--inflation 1.2,1.0] [--topup global,targeted]
                                       [--set FIELD=VALUE ...] [--out FILE]

Issue 7 asks the fast path for both ≤ 50 ms per sensor and 95 % interval ends within 5 % of a long
reference run's (as a fraction of the reference's width). After the Newton start
(``fit.newton_map``) most of the fast path's time is its importance draws, whose number
(``FastSettings.n_proposals``) sets its Monte Carlo error: this script measures that trade. For the
bundled Basler CCD and the first ``--n-sim`` simulated sensors of ``speed_accuracy.sensor_set``
(the same references: ``bayescap.fit(quality="accurate")``, seed 1000 + i), and each number of
draws: the wall time of one ``fast_posterior`` attempt (best of 3, seed 1; a rejection's retry
doubles it) and, over ``--seeds`` seeds, the worst
interval-end error over every parameter and capacity (``speed_accuracy.errors_vs_ref``), k̂ and
whether the fast path's own check accepted; for each number of moment-matching rounds
(``FastSettings.adapt_rounds``, ``--rounds``) and share of clip-floor draws
(``FastSettings.clip_floor_fraction``, ``--floor``). Also the fast path's own predicted Monte Carlo
error of its interval ends (``diagnostics.interval_end_mcse_max``), and, with ``--gate``, the
acceptance gate on it (``FastSettings.end_mcse_max``: more draws until it is met, up to
``max_proposals``, else rejected; "none": report only, the default), and with ``--tails`` the share
of draws given to each long one-sided tail the fast path's probe finds (``FastSettings.tail_fraction``;
0: no probe, as before commit 89fd939) and with ``--floor-pair`` whether the clip floor and the
farthest-reaching tail also get draws together (``FastSettings.floor_pair``), and with ``--adapt-nu``
and ``--inflation`` the moment-matched rounds' t degrees of freedom (``FastSettings.adapt_nu``; none:
the Laplace t's ``nu``) and sd multiplier (``FastSettings.adapt_inflation``), and with ``--topup``
how a gate tops up (``FastSettings.topup``: "global", more moment-matched draws; "targeted", draws
aimed at the offending interval ends). ``--ref-cache DIR`` keeps each reference's quantiles in DIR
(computed on first use, by the same call; a reference takes 40–120 s here). Writes
benchmarks/results/fast_tradeoff.md (``--out``).
"""
from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "fast_tradeoff.md"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-sim", type=int, default=4)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--sizes", default="1500,3000,6000,12000")
    ap.add_argument("--rounds", default="1,3")
    ap.add_argument("--floor", default="0.1")
    ap.add_argument("--gate", default="none", help="end_mcse_max values, 'none' for no gate")
    ap.add_argument("--tails", default="0.05", help="FastSettings.tail_fraction values")
    ap.add_argument("--floor-pair", default="1", help="FastSettings.floor_pair values (0/1)")
    ap.add_argument("--adapt-nu", default="none", help="FastSettings.adapt_nu values, 'none' for nu")
    ap.add_argument("--inflation", default="1.2", help="FastSettings.adapt_inflation values")
    ap.add_argument("--topup", default="global", help="FastSettings.topup values (global, targeted)")
    ap.add_argument("--ref-cache", default=None, help="directory keeping the references' quantiles")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                    help="another FastSettings field for every run (int, float or 'none'), repeatable")
    ap.add_argument("--out", default=str(OUT))
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    import bayescap
    import speed_accuracy as sa
    from _machine import describe_machine
    from bayescap.inference.fast import FastSettings, fast_posterior
    from bayescap.api import fast_fit
    from bayescap.model.ptc_model import PTCModel

    gates = [None if g.strip().lower() == "none" else float(g) for g in a.gate.split(",")]
    nus = [None if v.strip().lower() == "none" else float(v) for v in a.adapt_nu.split(",")]
    sizes = [(int(n), int(r), float(f), g, float(tf), bool(int(fp)), an, float(inf), tu.strip())
             for tu in a.topup.split(",") for inf in a.inflation.split(",") for an in nus for fp in a.floor_pair.split(",")
             for tf in a.tails.split(",") for g in gates for f in a.floor.split(",") for r in a.rounds.split(",")
             for n in a.sizes.split(",")]
    from batch_accuracy import apply_sets

    base = apply_sets(FastSettings(), a.set)
    t_all = time.perf_counter()
    load0 = os.getloadavg()
    sensors = sa.sensor_set(a.n_sim)
    res = {k: [] for k in sizes}      # per (draws, rounds, floor): (sensor, wall, [(err, who, khat, accepted, mcse) per seed])
    for i, (name, d, _) in enumerate(sensors):
        print(f"[{i + 1}/{len(sensors)}] {name}: reference", flush=True)
        qref = _reference(d, i, name, a.ref_cache, bayescap, sa)
        m = PTCModel(d)
        for key in sizes:
            n, rounds, floor, gate, tails, pair, anu, infl, topup = key
            fs = replace(base, n_proposals=n, adapt_rounds=rounds, clip_floor_fraction=floor,
                         end_mcse_max=gate, tail_fraction=tails, floor_pair=pair, adapt_nu=anu,
                         adapt_inflation=infl, topup=topup)
            # one attempt (no retry with restarts after a rejection, which would double the time)
            wall = min(fast_posterior(m, seed=1, settings=replace(fs, retry_restarts=0))[1]["wall_s"]
                       for _ in range(3))
            runs = []
            for s in range(1, a.seeds + 1):
                fr = fast_fit(d, seed=s, settings=fs, fallback=False)
                e = sa.errors_vs_ref(sa.quantiles(fr), qref)
                x = fr.chains.extra
                runs.append((e[0], e[1], float(x["khat"]), bool(x["accepted"]),
                             float(fr.diag.get("interval_end_mcse_max", float("nan"))), int(x["n_proposals"]),
                             float(x["ess_is"])))
            res[key].append((name, wall, runs))
            errs = [r[0] for r in runs]
            print(f"   {_label(key)}: {wall * 1e3:6.1f} ms, "
                  f"worst end error {min(errs):.3f}–{max(errs):.3f} ({', '.join(sorted(set(r[1] for r in runs)))}), "
                  f"k̂ {min(r[2] for r in runs):.2f}–{max(r[2] for r in runs):.2f}, "
                  f"accepted {sum(r[3] for r in runs)}/{len(runs)}", flush=True)
    L = ["# Fast path: importance draws against speed and accuracy", "",
         f"Generated by `python benchmarks/fast_tradeoff.py --n-sim {a.n_sim} --seeds {a.seeds} --sizes {a.sizes} "
         f"--rounds {a.rounds} --floor {a.floor} --gate {a.gate} --tails {a.tails} --floor-pair {a.floor_pair}"
         f"{' --adapt-nu ' + a.adapt_nu if a.adapt_nu != 'none' else ''}"
         f"{' --inflation ' + a.inflation if a.inflation != '1.2' else ''}"
         f"{' --topup ' + a.topup if a.topup != 'global' else ''}"
         f"{' --ref-cache ' + a.ref_cache if a.ref_cache else ''}"
         f"{''.join(f' --set {kv}' for kv in a.set)}` on "
         f"{datetime.datetime.now().isoformat(timespec='minutes')} in {time.perf_counter() - t_all:.0f} s.",
         f"Machine: {describe_machine()}; load average before {load0[0]:.2f}, after {os.getloadavg()[0]:.2f}.", "",
         "Time: one attempt of `fast_posterior` (the Newton start, the importance draws, PSIS, resampling; "
         "without the retry with optimiser restarts that follows a rejection and doubles it), best of 3, seed 1. "
         "Error: the worst |Δ| of a 95 % interval end over every parameter and capacity, as a fraction of the "
         "reference's 95 % width (reference: `bayescap.fit(quality=\"accurate\")`, seed 1000 + i, whose own Monte "
         "Carlo error is ~0.005–0.008 of the width, `speed_accuracy.md`), median and max over the seeds; "
         "accepted: the fast path's own check (k̂ < 0.7, IS ESS ≥ 200, and with a gate every interval end's "
         "predicted Monte Carlo error ≤ the gate × width after topping up to at most 24 000 draws).", "",
         "| sensor | " + " | ".join(f"{_label(key)}: ms / error median (max) / k̂ median / accepted" for key in sizes) + " |",
         "|---|" + "---|" * len(sizes)]
    for j, (name, _, _) in enumerate(sensors):
        cells = []
        for key in sizes:
            _, wall, runs = res[key][j]
            errs = [r[0] for r in runs]
            cells.append(f"{wall * 1e3:.0f} / {np.median(errs):.3f} ({max(errs):.3f}) / {np.median([r[2] for r in runs]):.2f} / "
                         f"{sum(r[3] for r in runs)}/{len(runs)}")
        L.append(f"| {name} | " + " | ".join(cells) + " |")
    L += ["", "Over all sensors and seeds, runs the fast path's own check accepted:", "",
          "| draws | rounds | clip floor | gate | tails | floor pair | adapt ν | inflation | top-up | median time (ms) | accepted | "
          "draws used by accepted runs: median (max) | k̂: median (max) | IS ESS: median | worst end error: median | "
          "within 0.05 | own predicted end MC error (max over parameters): median |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for key in sizes:
        n, r, f, g, tf, fp, anu, infl, tu = key
        walls = [w for _, w, _ in res[key]]
        acc = [x for _, _, runs in res[key] for x in runs if x[3]]
        tot = sum(len(runs) for _, _, runs in res[key])
        e = [x[0] for x in acc]
        used = [x[5] for x in acc]
        kh = [x[2] for _, _, runs in res[key] for x in runs]
        ess = [x[6] for _, _, runs in res[key] for x in runs]
        L.append(f"| {n} | {r} | {f:g} | {g if g is not None else 'none'} | {tf:g} | {int(fp)} | "
                 f"{'ν' if anu is None else f'{anu:g}'} | {infl:g} | {tu} | {np.median(walls) * 1e3:.0f} | {len(acc)}/{tot} | "
                 f"{f'{np.median(used):.0f} ({max(used)})' if used else '–'} | {np.median(kh):.2f} ({max(kh):.2f}) | "
                 f"{np.median(ess):.0f} | "
                 f"{np.median(e) if e else float('nan'):.3f} | {sum(x <= 0.05 for x in e)}/{len(e)} | "
                 f"{np.nanmedian([x[4] for x in acc]) if acc else float('nan'):.3f} |")
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))


def _label(key):
    n, r, f, g, tf, fp, anu, infl, tu = key
    return (f"{n} draws, {r} round{'s' if r > 1 else ''}, floor {f:g}, gate {g if g is not None else 'none'}, "
            f"tails {tf:g}, floor pair {int(fp)}, adapt ν {'ν' if anu is None else f'{anu:g}'}, inflation {infl:g}, "
            f"top-up {tu}")


def _reference(d, i, name, cache, bayescap, sa):
    """The reference's quantiles (``speed_accuracy.quantiles`` of ``bayescap.fit(quality="accurate")``,
    seed 1000 + i), kept in ``cache`` (a directory) when given."""
    path = None
    if cache:
        slug = "".join(c if c.isascii() and c.isalnum() else "_" for c in name)[:40]
        path = Path(cache) / f"ref{i:02d}_{slug}.npz"
        if path.exists():
            with np.load(path) as z:
                return {k: z[k] for k in z.files}
    q = sa.quantiles(bayescap.fit(d, seed=1000 + i, quality="accurate"))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **q)
        os.replace(tmp, path)
    return q


if __name__ == "__main__":
    main()
