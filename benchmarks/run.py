"""Run the maintained benchmarks; each writes one results file, ``benchmarks/results/<name>.md``.

    python benchmarks/run.py --list
    python benchmarks/run.py NAME [NAME ...] [--quick]
    python benchmarks/run.py --all [--quick]

Each benchmark runs as its own process (``python benchmarks/<name>.py``) from the repository root,
with the checkout first on ``PYTHONPATH`` so that it measures this tree's ``bayescap``. ``--quick``
passes ``--quick`` to the benchmarks that have a shorter development run (their results file says
so); the others run in full. Run one directly for its own options (``python benchmarks/NAME.py -h``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"

#: name -> (what it measures, rough run time on 2 cores, rough time with --quick or None)
BENCHMARKS = {
    "speed_accuracy": (
        "fast, standard and accurate presets on the Basler CCD and 10 simulated sensors: wall time, "
        "ESS/s, interval-end error against an accurate reference, coverage; naive emcee baselines",
        "20-40 min",
        "5-8 min",
    ),
    "batch_accuracy": (
        "the batch of simulated Gpixel ROIs: fit_many throughput on 1000 ROIs with and without the "
        "MCMC fallback, and the accepted fast-path intervals against pooled standard MCMC references",
        "10-20 min",
        "1-2 min",
    ),
    "batch_dask": (
        "1000 simulated Gpixel ROIs on a 2-worker Dask LocalCluster against the local process pool "
        "(in memory, and written as it runs): wall time, sensors/s, identical numbers",
        "5-10 min",
        None,
    ),
    "sbc": (
        "simulation-based calibration on 200 simulated sensors: rank uniformity and 50/68/95 % coverage "
        "per quantity (also writes sbc_ranks.png)",
        "5-10 min",
        "1 min",
    ),
    "integral_accuracy": (
        "tonal-range and MTF-loss integrals against quadrature; cost of propagating 10 000 draws",
        "10 s",
        None,
    ),
    "check_moves": (
        "emcee moves and the IndependenceMove on a known 6-D Gaussian and a banana/skewed/truncated target",
        "3-6 min",
        "1 min",
    ),
    "corrupt_inputs": (
        "the bundled CSVs corrupted ~300 ways through `bayescap fit --quality fast` (every variant fits "
        "or is refused in one line; degenerate tables refused), and faults while writing in subprocesses",
        "5-10 min",
        None,
    ),
    "response_shapes": (
        "a soft knee, an S-shaped 8-bit camera and a brighter-fatter CCD simulated frame by frame, with and "
        "without photon counts: coverage of K, dark noise, η, full well; K all rows vs below 70 %; outliers; time",
        "10-30 min",
        "5-15 min",
    ),
    "basler_vs_emva1288": (
        "the Basler conversion gain by emva1288's recipe, other least-squares fits and the bayescap posterior",
        "10 s",
        None,
    ),
    "ess_check": (
        "which ESS is right for the ensembles: the spread of posterior means and quantiles across 24 seeds "
        "against the Monte Carlo error predicted with walkers or ensembles as chains (Basler, one simulated)",
        "8-15 min",
        "1 min",
    ),
    "bench_logprob": ("cost of one vectorised PTCModel.log_prob call on the bundled and benchmark CSVs", "10 s", None),
    "fast_budget": (
        "where the fast path's time goes, as a fit runs it: log_prob calls and the derived quantities against the "
        "rest, per phase, on the speed_accuracy sensors",
        "1 min",
        None,
    ),
    "fast_gate_scope": (
        "the fast path's interval-end gate on every quantity against one scoped to the printed parameters or "
        "the eight EMVA 1288 ones (FastSettings.end_parameters): CPU time, draws, fallbacks, coverage, the "
        "largest ungated end error, on the Basler set and 19 zoo sensors",
        "3-6 min",
        None,
    ),
    "gain_joint": (
        "joint fit of simulated gain series (shared QE, PRNU, DSNU, dark current): sampler check, truth inside "
        "the joint intervals, width against separate fits; two series also by MCMC",
        "10-25 min",
        None,
    ),
    "colour_coverage": (
        "simulated Bayer cameras (frame by frame, from spectral sensitivities): per-channel K and QE and colour "
        "sensitivity against the truth (95 % coverage), from the separate channel fits and from the joint fit "
        "(fit_cfa, with its K check), CS interval widths with the CCM exact and uncertain",
        "5-25 min",
        "1-2 min",
    ),
    "quantization_regime": (
        "fit times (standard, fast) and log_prob cost of sensors with read noise below half a DN",
        "1-3 min",
        None,
    ),
    "ptc_curvature": (
        "the PTC's curvature without photon counts on simulated compressive and linear 12-bit cameras: term "
        "selected, K's coverage on all rows and below 70 % of saturation, the two intervals' agreement, "
        "against a linear response forced",
        "2-4 min",
        "1 min",
    ),
    "zoo_nonlinear": (
        "the non-linear zoo (42 frame-simulated sensors: quadratic, cubic, quartic, S-shaped, soft-knee, "
        "two-slope responses and brighter-fatter, with and without photon counts): coverage of K, noise, η, "
        "full well per shape, K from all rows against rows below 70 %, tight misses, outlier labels, times",
        "20-40 min",
        "8-15 min",
    ),
    "zoo_nonlinear_seeds": (
        "the non-linear zoo's 42 sensors on 5 independent simulation seeds at `fast` (all rows and rows below "
        "70 %): coverage per shape and per photons/no photons with Wilson intervals, K overlap, tight misses, "
        "the signed z of K ((mean - truth)/sd: bias and calibration)",
        "10-20 min",
        "6-12 min",
    ),
    "astro_tables": (
        "mean/variance-only PTC tables of 60 frame-simulated astronomy amplifiers (gain 0.6-1.8, 40-400 flat "
        "pairs, strong brighter-fatter): K inside its 95 % interval, read noise within 10 %; stops (exit 2, "
        "nothing written) on a bayescap without mean/variance tables",
        "15-30 min",
        None,
    ),
    "focal_plane": (
        "3024 amplifier tables (189 CCDs x 16) through `bayescap fit --out DIR --dask 2` and `--jobs 2`, fast: "
        "wall time (target 5 min), identical numbers, truths per CCD (--n-tables N for a small run; simulating "
        "the tables once takes 15-30 min)",
        "30-90 min",
        None,
    ),
    "focal_plane_cpu": (
        "where the CPU of a focal-plane amplifier's fast fit goes: 96 of the 3024 tables in one process (accepted "
        "vs MCMC fallback), the stages under cProfile (the clip rows' latent solver, log_prob, the draws, the "
        "fallback), and the command line with --jobs 2 (the batch's own cost per table)",
        "5-8 min",
        None,
    ),
    "process_stages": (
        "the whole process a user waits for (python -m bayescap fit CSV --json) on the bundled sensors at fast "
        "and standard, stage by stage (imports, read, model, sampler, result, write), bayescap --version, and a "
        "plain 2-parameter emcee script on the same CSV",
        "3-5 min",
        None,
    ),
    "statistical_tests": (
        "the suite's statistical checks the default pytest run leaves out (pytest -m statistical): coverage and "
        "SBC ranks on 30 prior-drawn sensors, the fast path's gain intervals on 48 small ROIs, MTF bootstrap coverage, "
        "the standard move mix on a skewed bounded target, emcee's DESnookerMove (a known defect), a slow burn-in "
        "transient discarded, truths inside single fits' intervals (compressive K, offsets across the rounding "
        "boundary, one-frame PRNU/DSNU, noise below 1 DN: a known failure by chance)",
        "3-5 min",
        None,
    ),
    "zoo": (
        "the sensor zoo (68 frame-simulated sensors nobody tuned to + the Basler set): truth in the 95 % "
        "interval per parameter and regime, standard and fast times, convergence, flags",
        "15-25 min",
        None,
    ),
    "colour_cfa_speed": (
        "one CFA camera's colour fit (four channels, K check, consensus, CS) against its monochrome fit: CPU "
        "time (target ≤ 3x; wall time and whole processes beside it), K check, true K in the joint interval, on cfasim cameras",
        "8-15 min",
        "1 min",
    ),
    "colour_warm_start": (
        "whether the CFA channels' fits would gain from starting their optimiser at the first channel's MAP: "
        "the MAP's share of a fast channel fit, Newton's calls from the own guess and from three warm starts",
        "1-2 min",
        None,
    ),
    "subdn_speed": (
        "fit times of two 8-bit sensors with read noise far below a DN (zoo draw20, draw25), fast and "
        "standard, and which tier of the rounding moments served how many elements",
        "2-3 min",
        None,
    ),
    "zoo_dark": (
        "the zoo's weak-dark-ramp family (24 frame-simulated sensors, D·t 1e-3 to 1 of the read variance, "
        "8-16 bit): the dark current held by its interval or printed limit, no detection the data cannot make",
        "6-12 min",
        None,
    ),
    "photon_counting": (
        "photon-counting sensors (K 0.1-0.5 e-/DN, 48 frame-simulated seeds): the conversion gain's 95 % "
        "coverage, bias and interval calibration",
        "10-20 min",
        None,
    ),
}


def results_file(name):
    return RESULTS / f"{name}.md"


def run(name, quick):
    cmd = [sys.executable, str(HERE / f"{name}.py")] + (["--quick"] if quick and BENCHMARKS[name][2] else [])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    out = results_file(name)
    before = out.stat().st_mtime_ns if out.exists() else None
    print(f"== {name}: {' '.join(['python', f'benchmarks/{name}.py'] + cmd[2:])}", flush=True)
    t = time.perf_counter()
    code = subprocess.run(cmd, cwd=ROOT, env=env).returncode
    wall = time.perf_counter() - t
    written = out.exists() and out.stat().st_mtime_ns != before
    rel = out.relative_to(ROOT)
    if written:
        print(f"== {name}: wrote {rel} in {wall:.0f} s" + (f" (exit code {code})" if code else ""), flush=True)
    else:
        print(f"== {name}: FAILED, exit code {code}, {rel} not written ({wall:.0f} s)", flush=True)
    return written, code


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", metavar="NAME", help="benchmarks to run (see --list)")
    ap.add_argument("--list", action="store_true", help="list the benchmarks, their results files and run times")
    ap.add_argument("--all", action="store_true", help="run every benchmark, in the order of --list")
    ap.add_argument("--quick", action="store_true", help="the shorter development run where a benchmark has one")
    a = ap.parse_args(argv)
    if a.list or not (a.names or a.all):
        for name, (what, full, quick) in BENCHMARKS.items():
            print(
                f"{name:20s} {full:>10s}"
                + (f" (--quick {quick})" if quick else "")
                + f"  -> {results_file(name).relative_to(ROOT)}\n{'':20s} {what}"
            )
        return 0
    unknown = [n for n in a.names if n not in BENCHMARKS]
    if unknown:
        ap.error(f"unknown benchmark(s) {', '.join(unknown)}; --list shows them")
    names = list(BENCHMARKS) if a.all else a.names
    outcome = {n: run(n, a.quick) for n in names}
    print("\nSummary:")
    for n, (written, code) in outcome.items():
        print(
            f"  {n:20s} "
            + (f"wrote {results_file(n).relative_to(ROOT)}" if written else "FAILED")
            + (f" (exit code {code})" if code else "")
        )
    return 0 if all(w and not c for w, c in outcome.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
