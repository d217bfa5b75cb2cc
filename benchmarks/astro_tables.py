"""Mean/variance-only photon-transfer tables (astronomy CCDs) from the frame simulator: K inside its
95 % interval, read noise within 10 % (issue 46, items 4 and 6).

    python benchmarks/run.py astro_tables            # writes benchmarks/results/astro_tables.md
    python benchmarks/astro_tables.py --n 10         # a small run (the file gives the command)

``--n`` amplifiers (default 60) are drawn by :func:`bayescap.validation.astro.draw_amplifier` (gain
0.6–1.8 e⁻/ADU, read noise 3–10 e⁻, brighter-fatter a₀₀ −(1–3)·10⁻⁶ per e⁻, wells 80 000–150 000 e⁻,
40–400 flat pairs), each simulated frame by frame (:mod:`bayescap.validation.framesim`, 32 × 32
pixels, bias removed by an overscan) and written as a CSV of only ``mean_dn,temporal_var_dn2``
(every other table also with ``n_pixels``; CONTRACT.md section 1b). Each is fitted with
``bayescap.fit`` at ``fast`` (seed 1; the preset a focal plane's batch runs, ``--quality standard``
for the MCMC) and scored with
:func:`bayescap.validation.astro.score_astro`. Targets: K's truth inside its 95 % interval in ≥ 92 %
of the tables; read noise within 10 %; no K more than 3 half-widths off.

A bayescap without mean/variance-only tables refuses them ("missing required column(s)"): the
benchmark then stops with that message, exit status 2, and writes nothing.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "astro_tables.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache" / "astro"


def tables(n, roi, seed=4646):
    """[(name, truth, seed, with_n_pixels)] for the run."""
    from dataclasses import replace

    from bayescap.validation.astro import draw_amplifier

    rng = np.random.default_rng(seed)
    return [(f"amp{i:03d}", replace(draw_amplifier(rng), roi_px=roi), seed * 1000 + i, i % 2 == 0) for i in range(n)]


def ensure_table(name, truth, seed, with_n):
    from bayescap.validation.astro import ensure_astro_csv

    return ensure_astro_csv(CACHE, name, truth, seed, n_pixels=with_n)


def check_supported(path, who="astro_tables"):
    """Stop with a clear message when this bayescap refuses mean/variance-only tables."""
    import bayescap
    from bayescap.exceptions import InputError
    from bayescap.validation.astro import refuses_mean_variance_tables

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bayescap.fit(str(path), seed=1, quality="fast")
    except InputError as e:
        msg = str(e).splitlines()[0]
        if refuses_mean_variance_tables(msg):
            print(
                f"{who}: this bayescap does not fit mean/variance-only tables (CONTRACT.md section 1b, "
                f"issue 46 item 4): it says {msg!r}. Nothing written.",
                file=sys.stderr,
            )
            raise SystemExit(2) from None
        raise


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=60, help="amplifier tables (default 60)")
    ap.add_argument("--roi", type=int, default=32, help="ROI side in pixels (default 32)")
    ap.add_argument("--quality", default="fast", choices=("fast", "standard", "accurate"))
    a = ap.parse_args(argv)
    from _machine import describe_machine, emit

    import bayescap
    from bayescap.validation.astro import score_astro

    todo = tables(a.n, a.roi)
    t0 = time.perf_counter()
    paths = [ensure_table(*x) for x in todo]
    gen_s = time.perf_counter() - t0
    check_supported(paths[0])
    recs = []
    for (name, truth, _seed, with_n), path in zip(todo, paths):
        t = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = bayescap.fit(str(path), seed=1, quality=a.quality).to_dict()
        wall = time.perf_counter() - t
        sc = score_astro(truth, d)
        sc.update(
            name=name,
            n_points=truth.n_points,
            a00=truth.a00_per_e,
            with_n=with_n,
            wall_s=wall,
            sampling_s=d["diagnostics"].get("wall_s"),
            converged=bool(d["diagnostics"].get("converged")),
            outliers=len(d.get("outliers", [])),
            terms=[x for x in d.get("model_terms", []) if x not in ("photon_shot", "read", "quantization")],
            k_ci=(d["parameters"].get("conversion_gain_e_per_dn") or {}).get("ci95"),
        )
        print(
            f"{name} g={truth.gain_e_per_adu:.3f} K={sc['k_median']} {sc['k_ci']} inside={sc['k_inside']} "
            f"read {sc['read_rel_err']:+.3f} ({sc['read_name']}) {wall:.1f}s",
            flush=True,
        )
        recs.append(sc)
    n = len(recs)

    def frac(xs):
        xs = list(xs)
        return f"{sum(xs)}/{len(xs)} ({100 * sum(xs) / len(xs):.0f} %)" if xs else "–"

    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        ).stdout.strip()
    except OSError:
        commit = "unknown"
    k_in = [r["k_inside"] for r in recs]
    rd10 = [abs(r["read_rel_err"]) < 0.10 for r in recs]
    tight = sum(r["k_miss_half_widths"] > 3 for r in recs)
    st = [r["sampling_s"] for r in recs if r["sampling_s"] is not None]
    L = [
        "# Astronomy tables: mean/variance-only photon-transfer curves",
        "",
        f"Command: `python benchmarks/astro_tables.py --n {a.n} --roi {a.roi} --quality {a.quality}` "
        f"(`python benchmarks/run.py astro_tables`), code at commit {commit}.  ",
        f"Machine: {describe_machine()}.  ",
        f"{n} amplifiers (`bayescap.validation.astro`: gain 0.6–1.8 e⁻/ADU, read noise 3–10 e⁻, a₀₀ −(1–3)·10⁻⁶/e⁻, "
        f"wells 80 000–150 000 e⁻, 40–400 flat pairs, {a.roi}×{a.roi} pixels, bias removed by an overscan), each a "
        "CSV of `mean_dn,temporal_var_dn2` (every other one with `n_pixels`), simulated frame by frame "
        f"({gen_s:.0f} s, cached), fitted at `{a.quality}`, seed 1.",
        "",
        "| check | result | target |",
        "|---|---|---|",
        f"| K's truth inside its 95 % interval | {frac(k_in)} | ≥ 92 % |",
        f"| … with `n_pixels` / without | {frac(r['k_inside'] for r in recs if r['with_n'])} / "
        f"{frac(r['k_inside'] for r in recs if not r['with_n'])} | |",
        f"| K more than 3 half-widths off | {tight} | 0 |",
        f"| read noise within 10 % | {frac(rd10)} | all |",
        f"| read noise's truth inside its 95 % interval | {frac(r['read_inside'] for r in recs)} | |",
        f"| median \\|read noise error\\| | {100 * np.nanmedian([abs(r['read_rel_err']) for r in recs]):.1f} % | |",
        f"| converged | {frac(r['converged'] for r in recs)} | all |",
        f"| tables with rows named outliers | {sum(r['outliers'] > 0 for r in recs)} | |",
        f"| `ptc_turnoff_dn` reported | {frac(r['ptc_turnoff_dn'] is not None for r in recs)} | all |",
        f"| sampling time median (max) | {np.median(st):.2f} s ({max(st):.2f} s) | |"
        if st
        else "| sampling time | – | |",
        "",
        "| table | points | n_pixels | gain truth | K median [95 %] | inside | read noise error | a₀₀ (/e⁻) | turnoff (DN) | outliers | s | terms |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in recs:
        ci = r["k_ci"] or [float("nan")] * 2
        turn = r["ptc_turnoff_dn"]
        L.append(
            f"| {r['name']} | {r['n_points']} | {'yes' if r['with_n'] else 'no'} | {r['k_truth']:.4f} | "
            f"{r['k_median']:.4f} [{ci[0]:.4f}, {ci[1]:.4f}] | {'yes' if r['k_inside'] else '**no**'} | "
            f"{100 * r['read_rel_err']:+.1f} % | {r['a00']:.2e} | {'–' if turn is None else f'{turn:.0f}'} | "
            f"{r['outliers']} | {r['sampling_s'] or float('nan'):.2f} | {', '.join(r['terms'])} |"
        )
    emit(L, OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
