"""Simulation-based calibration of bayescap's posterior (issue 6).

Method (Talts, Betancourt, Simpson, Vehtari & Gelman 2018, "Validating Bayesian inference
algorithms with simulation-based calibration", arXiv:1804.06788): draw a true sensor, simulate
frame-level photon-transfer data from it with :func:`bayescap.simulate.simulate_ptc`, fit with
:func:`bayescap.fit`, and rank the truth among ``L`` posterior draws thinned by the integrated
autocorrelation time. If the posterior is calibrated the ranks are uniform on ``0..L``.

**Classic SBC (``--truths prior``, the default).** Classic SBC needs truths drawn from the prior
the fit uses. The production prior (``PTCModel.PRIOR``) is deliberately wide (log K uniform on
1e-4..1e4 e⁻/DN, read noise of scale 1000 e⁻, ...): most of its draws are not sensors. So the SBC
uses a proper, realistic prior ``bayescap.validation.sbc.SBC_PRIOR`` for every model parameter, draws
the truths from it (``validation.sbc.draw_sensor_prior``) and fits with exactly it
(``bayescap.fit(prior=SBC_PRIOR)``). The
simulator has no systematics, so the variance and mean discrepancies f and g are drawn from their
priors and injected into the simulated data as the likelihood describes them
(``validation.sbc.inject_discrepancies``). What is *not* from the fit's prior, because it is not a model
parameter: the full well and ADC range (the clip level's prior is uniform between data-derived
bounds), black level, and the per-pixel well spread (drawn from the clip-spread prior expressed
as a fraction of the full well); those parts are likelihood-dominated. ``docs/calibration.md``
lists the details.

**Realistic-range variant (``--truths realistic``).** Truths from ``validation.sbc.draw_sensor``, fitted with
the production priors: uniform ranks then hold only where the likelihood dominates the prior.

The coverage of the equal-tailed 50/68/95 % intervals (from all kept draws, as a user sees them)
is reported with the ranks.

Capacity truth: ``C`` computed from the true parameters exactly as :meth:`FitResult._derive`
computes it from each draw, with the fit's own scene (exposure time) and MTF, and with the noise
terms the fit includes (a PRNU/DSNU the fit cannot see is not in its capacity estimand).

    python benchmarks/sbc.py --n 200 --seed 1 --quality standard --jobs 1 --truths prior --levels 50

The simulate-fit-rank loop of one sensor is ``bayescap.validation.sbc.run_one`` (the test suite runs it on
30 sensors: tests/test_coverage.py, tests/test_sbc_small.py). Writes ``benchmarks/results/sbc.md``
and the rank histograms beside it, ``benchmarks/results/sbc_ranks.png`` (and the raw per-sensor
records as JSON lines to ``--raw``, default in the system temp directory; ``--from-raw`` rebuilds
the report from them).
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one thread per worker process: the pool supplies parallelism

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

#: ranked quantities (names of ``FitResult.draws`` / ``derived``; truths: ``validation.sbc.truth_values``)
PARAMS = [
    "conversion_gain_e_per_dn",
    "read_noise_e",
    "dark_current_e_per_s",
    "full_well_e",
    "quantum_efficiency",
    "prnu_percent",
    "dsnu_e",
    "variance_discrepancy",
    "mean_discrepancy",
    "capacity_bits",
]
LEVELS = (0.50, 0.68, 0.95)


from _machine import describe_machine  # noqa: E402

from bayescap.validation.sbc import SBC_LEVELS, SBC_SETTINGS, run_one, sensor_seeds  # noqa: E402


# --------------------------------------------------------------------------- statistics
def chi2_uniform(ranks, L, n_bins):
    """χ² test of uniformity of ranks on 0..L in ``n_bins`` equal bins ((L+1) % n_bins == 0)."""
    ranks = np.asarray(ranks, int)
    if (L + 1) % n_bins:
        raise ValueError("L + 1 must be a multiple of the number of bins")
    counts = np.bincount(ranks // ((L + 1) // n_bins), minlength=n_bins)
    exp = ranks.size / n_bins
    chi2 = float(np.sum((counts - exp) ** 2 / exp))
    return counts, chi2, float(stats.chi2.sf(chi2, n_bins - 1))


def binom_band(n, p, alpha=0.01):
    """Central acceptance band [lo, hi] of a Binomial(n, p) count, each tail ≤ alpha/2."""
    lo = int(stats.binom.ppf(alpha / 2, n, p))
    hi = int(stats.binom.isf(alpha / 2, n, p))
    return lo, hi


def summarise(records, n_bins=10, subset=None):
    """Per quantity: n, rank χ² p-value, bin counts, coverage per level, mean u (bias sign)."""
    out = {}
    for name in PARAMS:
        rs = [r for r in records if name in r["q"] and (subset is None or subset(r, name))]
        if not rs:
            continue
        L = rs[0]["L"]
        ranks = [r["q"][name]["rank"] for r in rs if r["L"] == L]
        counts, chi2, p = chi2_uniform(ranks, L, n_bins) if len(ranks) >= n_bins else (None, float("nan"), float("nan"))
        cov = {lv: int(sum(r["q"][name][f"in{int(round(100 * lv))}"] for r in rs)) for lv in LEVELS}
        u = np.array([r["q"][name]["u"] for r in rs])
        out[name] = {
            "n": len(rs),
            "counts": None if counts is None else counts.tolist(),
            "chi2": chi2,
            "p": p,
            "cov": cov,
            "u_mean": float(u.mean()),
            "frac_u_lt_025": float(np.mean(u < 0.025)),
            "frac_u_gt_975": float(np.mean(u > 0.975)),
        }
    return out


# --------------------------------------------------------------------------- report
def _plot(summary, path, L, n_bins, title="bayescap SBC"):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in PARAMS if n in summary and summary[n]["counts"] is not None]
    if not names:
        return
    cols = 4
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        s = summary[name]
        c = np.array(s["counts"])
        n = s["n"]
        ax.bar(np.arange(n_bins), c, width=0.9, color="C0")
        lo, hi = binom_band(n, 1.0 / n_bins, alpha=0.01)
        ax.axhspan(lo, hi, color="0.85", zorder=0)
        ax.axhline(n / n_bins, color="k", lw=0.8)
        ax.set_title(f"{name}\nn={n}, χ² p={s['p']:.3g}", fontsize=9)
        ax.set_xticks([0, n_bins - 1])
        ax.set_xticklabels(["0", str(L)])
        ax.set_xlabel("rank of truth (binned)", fontsize=8)
    for ax in axes.ravel()[len(names) :]:
        ax.axis("off")
    fig.suptitle(f"{title}; grey: 99 % band per bin for uniform ranks", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt_cov(k, n):
    return f"{k}/{n} = {100 * k / n:.1f} %" if n else "–"


REALISTIC_TEXT = (
    "**Truths are not drawn from the model's prior** (`--truths realistic`). They come from the realistic range of "
    "`draw_sensor`: K log-U(0.5, 8) e⁻/DN, read noise log-U(1, 20) e⁻, full well "
    "log-U(3 000, 60 000) e⁻, dark current log-U(1, 200) e⁻/s, QE U(0.3, 0.8), black level 64·2^j DN ≥ 6 read-noise sd, ADC bits so that "
    "ADC range / full well is log-U(0.4, 2.5), well spread U(0, 3 %), 40 % with spatial stacks "
    "(PRNU U(0.3, 2 %), DSNU log-U(1, 20) e⁻); 50 levels, 100×100 px, fitted with the production "
    "priors. Uniform ranks are expected only where the likelihood dominates the prior."
)
CLASSIC_TEXT = (
    "**Classic SBC** (`--truths prior`, Talts et al. 2018): every model parameter is drawn from "
    "`SBC_PRIOR` and every fit uses exactly that prior (`bayescap.fit(prior=SBC_PRIOR)`): K "
    "log-U(0.5, 8) e⁻/DN, read noise log-U(1, 20) e⁻, dark current log-U(1, 200) e⁻/s, QE "
    "U(0.3, 0.8), PRNU log-U(0.3 %, 2 %) and DSNU log-U(1, 20) e⁻ ({spatial_pct:g} % of sensors, with an "
    "8-frame spatial stack at every 5th level), variance discrepancy f ~ logN(log 1 %, 1) and mean "
    "discrepancy g ~ logN(log 0.5 %, 1), **injected into the simulated data** as the likelihood "
    "describes them (`inject_discrepancies`). Not model parameters, hence not from the model's prior: "
    "full well log-U(3 000, 60 000) e⁻ and the ADC range (the clip level's prior is uniform between "
    "data-derived bounds far wider than its likelihood), and the per-pixel well spread (from the "
    "clip-spread prior as a fraction of the full well). {levels} levels, 100×100 px; black level and ADC "
    "bits depend on the drawn sensor as in `draw_sensor`."
)


def _read_dn(rec):
    t = rec["truth"]
    return t["read_noise_e"] / t["conversion_gain_e_per_dn"]


def write_report(records, summary, path_md, *, cmd, wall_s, args, n_bins, strata):
    L = records[0]["L"]
    n = len(records)
    lines = [
        "# Simulation-based calibration"
        + (
            " (classic: truths from the fit's prior)"
            if records[0].get("truths") == "prior"
            else " (realistic-range truths)"
        ),
        "",
        f"Command: `{cmd}`  ",
        f"Machine: {describe_machine()}; {args.jobs} worker processes  ",
        (f"Wall time {wall_s / 60:.1f} min" if wall_s is not None else "report rebuilt from the raw records")
        + f" for {n} sensors (simulation + fit per sensor: median "
        f"{np.median([r['wall_s'] for r in records]):.1f} s, max {max(r['wall_s'] for r in records):.1f} s, "
        f"total {sum(r['wall_s'] for r in records) / 60:.0f} process-min on a machine shared with other jobs)  ",
        f"Quality preset: `{args.quality}`"
        + (
            f" (SamplerSettings({', '.join(f'{k}={v}' for k, v in SBC_SETTINGS.items())}), the rest as `standard`)"
            if args.quality == "sbc"
            else ""
        )
        + f"; rank among L = {L} draws thinned by the integrated "
        f"autocorrelation time; {n_bins} rank bins.",
        "",
        (
            CLASSIC_TEXT.format(
                levels=records[0]["sim"]["n_levels"], spatial_pct=100.0 * getattr(args, "spatial_fraction", 0.4)
            )
            if records[0].get("truths") == "prior"
            else REALISTIC_TEXT
        ),
        "",
        f"ADC clips first: {sum(r['adc_clips_first'] for r in records)}/{n}; fitted clip mechanism: "
        + ", ".join(f"{c} {sum(r['clip'] == c for r in records)}" for c in sorted({r["clip"] for r in records}))
        + f"; converged (standard targets): {sum(r['converged'] for r in records)}/{n}.",
        "",
        "## Rank uniformity and coverage (all sensors)",
        "",
        "| quantity | n | χ² p (rank uniformity) | 50 % | 68 % | 95 % | mean posterior CDF at truth | truth < 2.5 % / > 97.5 % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary.items():
        c = s["cov"]
        lines.append(
            f"| {name} | {s['n']} | {s['p']:.3g} | {_fmt_cov(c[0.5], s['n'])} | "
            f"{_fmt_cov(c[0.68], s['n'])} | {_fmt_cov(c[0.95], s['n'])} | {s['u_mean']:.3f} | "
            f"{100 * s['frac_u_lt_025']:.1f} % / {100 * s['frac_u_gt_975']:.1f} % |"
        )
    lo95, hi95 = binom_band(n, 0.95, alpha=0.01)
    lines += [
        "",
        f"For n = {n}, a calibrated 95 % interval covers between {lo95} and {hi95} truths "
        "(central 99 % binomial band); targets: χ² p > 0.01 and 95 % coverage in 92–98 %. "
        "Mean posterior CDF at the truth: 0.5 if unbiased; > 0.5 means the posterior sits "
        "*below* the truth (the fit underestimates), < 0.5 above it.",
        "",
        f"χ² p-values are asymptotic: with fewer than {5 * n_bins} sensors (expected count < 5 "
        "per bin, e.g. PRNU/DSNU, carried only by the sensors with spatial stacks) they are "
        "approximate. Diagnoses and proposed fixes: `docs/calibration.md`.",
        "",
        "Bin counts (rank bins from low to high):",
        "",
        "```",
    ]
    for name, s in summary.items():
        lines.append(f"{name:28s} {s['counts']}")
    lines += ["```", ""]
    for title, sub in strata.items():
        lines += [
            f"## {title}",
            "",
            "| quantity | n | χ² p | 50 % | 68 % | 95 % | mean CDF at truth |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, s in sub.items():
            c = s["cov"]
            lines.append(
                f"| {name} | {s['n']} | {s['p']:.3g} | {_fmt_cov(c[0.5], s['n'])} | "
                f"{_fmt_cov(c[0.68], s['n'])} | {_fmt_cov(c[0.95], s['n'])} | {s['u_mean']:.3f} |"
            )
        lines.append("")
    lines += ["![rank histograms](sbc_ranks.png)", ""]
    Path(path_md).write_text("\n".join(lines))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=200, help="number of simulated sensors")
    ap.add_argument("--quick", action="store_true", help="20 sensors instead of --n")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--quality", default="standard", help='a preset name, or "sbc" for SBC_SETTINGS (2 ensembles, at most 2 rounds)'
    )
    ap.add_argument(
        "--truths",
        choices=("prior", "realistic"),
        default="prior",
        help="prior: classic SBC (truths from SBC_PRIOR, fitted with it, f and g injected); "
        "realistic: draw_sensor's range fitted with the production priors",
    )
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (each fit is independent)")
    ap.add_argument("--levels", type=int, default=SBC_LEVELS, help="exposure levels per sensor (--truths prior)")
    ap.add_argument(
        "--spatial-fraction",
        type=float,
        default=0.4,
        help="share of sensors with a spatial stack (PRNU, DSNU) (--truths prior); 1 ranks PRNU "
        "and DSNU on every sensor",
    )
    ap.add_argument("--L", type=int, default=99, help="thinned posterior draws per sensor (L+1 ranks)")
    ap.add_argument("--bins", type=int, default=10)
    ap.add_argument(
        "--raw",
        type=Path,
        default=Path(tempfile.gettempdir()) / "bayescap_sbc_raw.jsonl",
        help="per-sensor records, one JSON object per line (written as they finish)",
    )
    ap.add_argument(
        "--from-raw",
        type=Path,
        default=None,
        help="only rebuild the report from raw records of an earlier (possibly partial) run",
    )
    ap.add_argument("--cmd", default=None, help="with --from-raw: the command that made the records")
    args = ap.parse_args(argv)
    if args.quick:
        args.n = 20
    cmd = "python benchmarks/sbc.py " + " ".join(argv if argv is not None else sys.argv[1:])
    RESULTS.mkdir(parents=True, exist_ok=True)
    if args.from_raw is not None:
        records = [json.loads(line) for line in open(args.from_raw) if line.strip()]
        records.sort(key=lambda r: r["i"])
        # a partial run: keep the complete prefix 0..m-1 only (the sensors still running when it
        # stopped are the slow ones; dropping just them would bias the set towards easy sensors)
        done = {r["i"] for r in records}
        m = next(i for i in range(len(done) + 1) if i not in done)
        records = [r for r in records if r["i"] < m]
        note = "" if m == args.n else f" (partial: the first {m} of {args.n} sensors)"
        report(records, args=args, cmd=(args.cmd or cmd) + note, wall_s=None)
        return
    tasks = [
        (i, a, b, c, args.quality, args.L, args.truths, args.levels, args.spatial_fraction)
        for i, (a, b, c) in enumerate(sensor_seeds(args.seed, args.n))
    ]
    t0 = time.perf_counter()
    records = []
    with open(args.raw, "w") as fh:
        if args.jobs > 1:
            import multiprocessing as mp

            with mp.get_context("fork").Pool(args.jobs, maxtasksperchild=20) as pool:
                for rec in pool.imap_unordered(run_one, tasks):
                    records.append(rec)
                    fh.write(json.dumps(rec) + "\n")
                    fh.flush()
                    print(
                        f"[{len(records)}/{args.n}] sensor {rec['i']} clip={rec.get('clip')} "
                        f"{rec['wall_s']:.1f}s conv={rec.get('converged')} errors={rec.get('fit_errors') or rec.get('failed')}",
                        flush=True,
                    )
        else:
            for t in tasks:
                rec = run_one(t)
                records.append(rec)
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                print(
                    f"[{len(records)}/{args.n}] sensor {rec['i']} {rec['wall_s']:.1f}s "
                    f"conv={rec.get('converged')} errors={rec.get('fit_errors') or rec.get('failed')}",
                    flush=True,
                )
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: r["i"])
    report(records, args=args, cmd=cmd, wall_s=wall)


def report(records, *, args, cmd, wall_s):
    n_bins = args.bins
    failed = [r for r in records if "failed" in r]
    retried = [r for r in records if r.get("fit_errors")]
    records = [r for r in records if "failed" not in r]
    if failed or retried:
        cmd = cmd + (
            f"; {len(retried)} fits retried with another seed after an error, "
            f"{len(failed)} sensors failed 3 attempts and are not ranked: " + ", ".join(str(r["i"]) for r in failed)
            if failed
            else f"; {len(retried)} fits retried with another seed after an error (errors in the raw records)"
        )
    summary = summarise(records, n_bins)
    strata = {
        "Stratified: ADC clips first": summarise(records, n_bins, lambda r, n: r["adc_clips_first"]),
        "Stratified: full well clips first": summarise(records, n_bins, lambda r, n: not r["adc_clips_first"]),
        "Stratified: converged fits only": summarise(records, n_bins, lambda r, n: r["converged"]),
        "Stratified: read noise below 0.5 DN (σ_read/K; quantization regime)": summarise(
            records, n_bins, lambda r, n: _read_dn(r) < 0.5
        ),
        "Stratified: read noise at least 0.5 DN": summarise(records, n_bins, lambda r, n: _read_dn(r) >= 0.5),
        "Stratified: the fit reports the quantity constrained": summarise(
            records, n_bins, lambda r, n: r["q"][n]["constrained"]
        ),
        "Stratified: the fit reports the quantity unconstrained (upper limit)": summarise(
            records, n_bins, lambda r, n: not r["q"][n]["constrained"]
        ),
    }
    out = RESULTS
    classic = records[0].get("truths") == "prior"
    _plot(
        summary,
        out / "sbc_ranks.png",
        records[0]["L"],
        n_bins,
        title="bayescap SBC (classic: truths from the fit's prior)"
        if classic
        else "bayescap SBC (realistic-range truths)",
    )
    write_report(records, summary, out / "sbc.md", cmd=cmd, wall_s=wall_s, args=args, n_bins=n_bins, strata=strata)
    for name, s in summary.items():
        print(
            f"{name:28s} n={s['n']:4d} p={s['p']:.3g} cov50={s['cov'][0.5]} cov68={s['cov'][0.68]} "
            f"cov95={s['cov'][0.95]} u_mean={s['u_mean']:.3f}"
        )
    return summary


if __name__ == "__main__":
    main()
