"""Which ESS is right for bayescap's ensembles: walkers as chains, or the independent ensembles as chains?

    python benchmarks/ess_check.py [--seeds 24] [--presets standard,fast] [--quick]

The report's ESS could count each walker of each ensemble as a chain (``E·W`` chains of ``S``
steps) or each independent ensemble as one chain (``E`` chains of ``S·W`` draws, the layout of
``posterior.nc``, :func:`bayescap.inference.diagnostics.draw_order`): on a standard fit the
walker count is 35–40 % below the ensemble count. This script decides between them by measurement: for each sensor it
runs each MCMC preset's sampler (``standard``: 4 ensembles; ``fast``, the fast path's fallback: 2)
with a fixed budget (one round: its burn-in and first production round, no extension, so every
seed has the same length) with ``--seeds`` seeds, and
compares, per sampled parameter (the sampler's coordinates, on which the report's diagnostics
are computed),

- the spread across seeds of the posterior mean (the actual Monte Carlo error of the mean), with
- the Monte Carlo error each ESS predicts, ``posterior sd / √ESS`` (ArviZ's ``ess(method="mean")``
  and the reported bulk ESS), as a root mean square over the seeds;

and likewise the spread of the 5 % and 95 % quantiles with ArviZ's quantile MCSE under each
layout (the tail ESS). A ratio spread/predicted of 1 means the ESS is right; above 1, the ESS
overstates the information in the draws. With ``n`` seeds the spread itself is uncertain by a
factor in the χ² 95 % range printed with the table. Writes ``benchmarks/results/ess_check.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _machine import describe_machine, emit  # noqa: E402

OUT = ROOT / "benchmarks" / "results" / "ess_check.md"
SENSORS = ("data/emva1288_basler_ccd12.csv", "data/simulated/sim_industrial_3p45um_12bit.csv")


def layouts(x_esw):
    """The two (chains, draws) layouts of draws shaped (E, S, W): walkers as chains, ensembles as chains."""
    from bayescap.inference.diagnostics import draw_order

    E, S, W = x_esw.shape
    by_walker = np.transpose(x_esw, (0, 2, 1)).reshape(E * W, S)
    order, _, _ = draw_order(S, W)
    by_ensemble = x_esw.reshape(E, S * W)[:, order]
    return {"walker": by_walker, "ensemble": by_ensemble}


def one_fit(model, settings, seed):
    """Per parameter: mean, sd, 5 % and 95 % quantiles, and each layout's ESS (mean, bulk) and quantile MCSEs."""
    import arviz as az

    from bayescap.inference.mcmc import run_ensembles

    c = run_ensembles(model, settings=settings, seed=seed, n_jobs=1)
    out = []
    for j in range(c.chain.shape[-1]):
        x = c.chain[..., j]
        row = {
            "mean": float(x.mean()),
            "sd": float(x.std(ddof=1)),
            "q05": float(np.quantile(x, 0.05)),
            "q95": float(np.quantile(x, 0.95)),
            "steps": x.shape[1],
        }
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for name, a in layouts(x).items():
                row[f"ess_mean_{name}"] = float(az.ess(a, method="mean"))
                row[f"ess_bulk_{name}"] = float(az.ess(a, method="bulk"))
                row[f"ess_tail_{name}"] = float(az.ess(a, method="tail"))
                row[f"mcse_q05_{name}"] = float(az.mcse(a, method="quantile", prob=0.05))
                row[f"mcse_q95_{name}"] = float(az.mcse(a, method="quantile", prob=0.95))
        out.append(row)
    return out, c


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=24)
    ap.add_argument("--quick", action="store_true", help="8 seeds, the Basler sensor only (a development run)")
    ap.add_argument(
        "--presets", default="standard,fast", help="MCMC presets to check, comma-separated (default standard,fast)"
    )
    a = ap.parse_args(argv)
    from scipy.stats import chi2

    from bayescap.api import load
    from bayescap.inference.presets import QUALITY_PRESETS
    from bayescap.model import PTCModel, select_terms

    n_seeds = 8 if a.quick else a.seeds
    sensors = SENSORS[:1] if a.quick else SENSORS
    presets = [p for p in a.presets.split(",") if p]
    lo, hi = (np.sqrt(chi2.ppf(q, n_seeds - 1) / (n_seeds - 1)) for q in (0.025, 0.975))
    lines = [
        "# Which ESS: walkers as chains or ensembles as chains",
        "",
        "`python benchmarks/run.py ess_check`" + (" (--quick: 8 seeds, Basler only)" if a.quick else ""),
        "",
        f"Machine: {describe_machine()} (shared with other jobs: times are under load).",
        "",
        "Each MCMC preset's sampler with a fixed budget (its burn-in and first production round, no "
        f"extension), {n_seeds} seeds per sensor; the sampler's coordinates. *spread*: the sd across seeds of the posterior mean "
        "(or quantile); *pred*: the Monte Carlo error each ESS definition predicts (posterior sd/√ESS, "
        "or ArviZ's quantile MCSE), root mean square over the seeds; *ratio* = spread/pred, 1 when "
        f"the ESS is right. With {n_seeds} seeds a true ratio of 1 gives a measured ratio between "
        f"{lo:.2f} and {hi:.2f} (95 %, χ²).",
        "",
    ]
    summary = []
    for preset, path in [(p, s) for p in presets for s in sensors]:
        settings = replace(QUALITY_PRESETS[preset], max_rounds=1)
        data = load(ROOT / path)
        model = PTCModel(data, terms=select_terms(data))
        rows, walls = [], []
        for s in range(n_seeds):
            t = time.perf_counter()
            r, c = one_fit(model, settings, 1000 + s)
            walls.append(time.perf_counter() - t)
            rows.append(r)
            print(f"{preset} {path} seed {s}: {walls[-1]:.1f} s", file=sys.stderr, flush=True)
        E, S, W, D = c.chain.shape
        lines += [
            f"## `{preset}`: {path}",
            "",
            f"{E} ensembles × {W} walkers × {settings.n_burn} burn-in + {S} steps; {np.mean(walls):.1f} s a fit "
            "(one process, under load).",
            "",
            "| parameter | ESS walker (bulk / tail) | ESS ensemble (bulk / tail) | spread of mean | pred walker | ratio walker "
            "| pred ensemble | ratio ensemble | q05/q95 ratio walker | q05/q95 ratio ensemble |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        ratios = {"walker": [], "ensemble": [], "q_walker": [], "q_ensemble": []}
        for j, name in enumerate(model.names):
            col = lambda k, j=j, rows=rows: np.array([r[j][k] for r in rows])  # noqa: E731
            spread = col("mean").std(ddof=1)
            cells = [name]
            for lay in ("walker", "ensemble"):
                cells.append(f"{np.median(col(f'ess_bulk_{lay}')):.0f} / {np.median(col(f'ess_tail_{lay}')):.0f}")
            cells.append(f"{spread:.3g}")
            for lay in ("walker", "ensemble"):
                pred = np.sqrt(np.mean(col("sd") ** 2 / col(f"ess_mean_{lay}")))
                ratios[lay].append(spread / pred)
                cells += [f"{pred:.3g}", f"{spread / pred:.2f}"]
            for lay in ("walker", "ensemble"):
                rq = []
                for q in ("q05", "q95"):
                    pred = np.sqrt(np.mean(col(f"mcse_{q}_{lay}") ** 2))
                    rq.append(col(q).std(ddof=1) / pred)
                ratios[f"q_{lay}"] += rq
                cells.append(f"{rq[0]:.2f} / {rq[1]:.2f}")
            lines.append("| " + " | ".join(cells) + " |")
        gm = {k: float(np.exp(np.mean(np.log(v)))) for k, v in ratios.items()}
        lines += [
            "",
            f"Geometric mean ratio over the parameters: means {gm['walker']:.2f} (walker ESS), "
            f"{gm['ensemble']:.2f} (ensemble ESS); quantiles {gm['q_walker']:.2f} (walker), "
            f"{gm['q_ensemble']:.2f} (ensemble).",
            "",
        ]
        summary.append((preset, path, gm))
    lines += [
        "## Summary",
        "",
        "Geometric mean over the parameters of spread/predicted (1: the ESS is right).",
        "",
        "| preset | sensor | mean: walker | mean: ensemble | quantiles: walker | quantiles: ensemble |",
        "|---|---|---|---|---|---|",
    ]
    for preset, path, gm in summary:
        lines.append(
            f"| {preset} | {path} | {gm['walker']:.2f} | {gm['ensemble']:.2f} | {gm['q_walker']:.2f} "
            f"| {gm['q_ensemble']:.2f} |"
        )
    emit(lines, OUT)


if __name__ == "__main__":
    main()
