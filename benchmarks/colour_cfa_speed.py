"""One CFA sensor's full colour fit against its monochrome fit: CPU time (target: ≤ 3×).

Each simulated camera (``bayescap.validation.cfasim``: a frame-level RGGB simulator from
colour-science's spectral sensitivities, written independently of the model) gives four channel
tables. Timed, per camera and preset, after one warm-up fit:

* monochrome: ``bayescap.fit`` of the Gr table (one channel, as ``bayescap fit`` runs it: the MCMC
  presets' ensembles in one process per core, the fast path in this process);
* colour: ``fit_cfa`` of the four tables with its default process count (the separate fits one
  after the other in this process, a channel's MCMC ensembles in lockstep; the K check, the
  consensus) plus
  ``colour_summary`` (CS per draw with the CCM's stated uncertainty, on one thread: the quadrature on
  128 pilot draws and the checked linear map on all, whose leave-one-out residual over CS's sd is
  recorded with the Monte Carlo error of CS's interval ends; scores and capacities): what
  ``bayescap colour`` computes after reading the tables;
* the same colour run with ``n_jobs=2`` (the same numbers, checked): a worker process fits half the
  channels;
* with the fast preset (``bayescap colour``'s default), the whole processes too: ``bayescap colour``
  of the four CSVs (``--json``) against ``bayescap fit`` of the Gr CSV (``--quality fast --json``),
  imports, reading and output included.

CPU time is the target's measure (this process and its ended workers, ``getrusage``; for the whole
processes, the ended child's): the machine is shared, and wall times there say more about the other
jobs than about the code (a colour fit that spreads its fits over the cores gains less where other
jobs hold them). Wall times and the load average are recorded beside it. The pooled colour run's
*critical path* in CPU seconds (the longer of this process's and its worker's channel fits, then CS
etc., of the ``n_jobs=2`` run) estimates its wall time on otherwise idle cores, against the
monochrome fast fit's CPU time (one process).

Each timing is the fastest of ``--repeats`` runs (default 3; at ``fast``, whose fits take a fraction
of a second, ``--repeats-fast``, default 7; the runs in turn, per camera and preset), the ratios
with the median of the runs listed too: a burst of other jobs during one run slows its CPU time as
well (shared caches and cores), and would otherwise decide its row.

Also recorded: whether the K check passed and whether the true K lies in the joint 95 % interval.

    python benchmarks/colour_cfa_speed.py [--quick] [--seeds N] [--repeats N] [--repeats-fast N]

Writes ``benchmarks/results/colour_cfa_speed.md``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _machine import describe_machine, emit  # noqa: E402

import bayescap  # noqa: E402
from bayescap.colour.ccm import ccm_from_matrix  # noqa: E402
from bayescap.colour.cfa_fit import colour_summary, fit_cfa  # noqa: E402
from bayescap.io.ptc_csv import read_ptc_csv, write_ptc_csv  # noqa: E402
from bayescap.validation.cfasim import CHANNELS, simulate_cfa_ptc  # noqa: E402

#: a white-preserving camera -> sRGB matrix of ordinary noise cost (Nikon D850's, from its DNG)
CCM = [[1.4009, -0.3130, -0.0879], [-0.1249, 1.4125, -0.2876], [0.0080, -0.4077, 1.3997]]
#: the colour run's other process count, against its default (one)
OTHER_JOBS = {"fast": 2, "standard": 2}


def tables(seed: int, tmp: Path) -> tuple[dict, dict]:
    sim = simulate_cfa_ptc(seed)
    out = {}
    for c in CHANNELS:
        path = tmp / f"s{seed}_{c}.csv"
        write_ptc_csv(sim[c]["rows"], path, metadata=sim[c]["metadata"])
        out[c] = read_ptc_csv(path)
    return out, sim["truth"]


def cpu_s() -> float:
    """CPU time of this process and of its children that have ended (the fits' worker processes)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def children_cpu_s() -> float:
    """CPU time of this process's children that have ended."""
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return b.ru_utime + b.ru_stime


def reap_workers() -> None:
    """Wait for this process's worker processes to end (so that their CPU time is counted)."""
    import multiprocessing as mp

    for p in mp.active_children():
        p.join()


def cli_cpu_s(args) -> float:
    """CPU seconds of one ``python -m bayescap ARGS`` process (and its workers), which must succeed."""
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(HERE.parent), env.get("PYTHONPATH")) if p)
    c0 = children_cpu_s()
    out = subprocess.run([sys.executable, "-m", "bayescap", *args], env=env, capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"bayescap {' '.join(args)} failed: {out.stderr[-500:]}")
    return children_cpu_s() - c0


def whole_processes(tmp: Path, seed: int) -> tuple[float, float]:
    """CPU seconds of ``bayescap fit`` of the Gr CSV (fast) and of ``bayescap colour`` of the four CSVs
    (fast, its default; the CCM, white balance and CCM uncertainty of :func:`colour_run`)."""
    csv = {c: str(tmp / f"s{seed}_{c}.csv") for c in CHANNELS}
    mono = cli_cpu_s(["fit", csv["Gr"], "--quality", "fast", "--seed", str(seed), "--json"])
    ccm = ",".join(f"{v:g}" for row in CCM for v in row)
    colour = cli_cpu_s(
        ["colour", *(csv[c] for c in CHANNELS), "--ccm", ccm, "--wb", "2.2,1,1.25", "--ccm-rel-sd", "0.02"]
        + ["--quality", "fast", "--seed", str(seed), "--json"]
    )
    return mono, colour


def colour_run(tb, seed, quality, times=None, n_jobs=None):
    t0, c0 = time.perf_counter(), time.process_time()
    f = fit_cfa(tb, seed=seed, quality=quality, n_jobs=n_jobs)
    t1, c1 = time.perf_counter(), time.process_time()
    ccm = ccm_from_matrix(CCM, source="D850 DNG", rel_sd=0.02, n_draws=f.n_draws, seed=seed)
    t = float(np.median(tb["Gr"].exposure_time_s))
    md = tb["Gr"].metadata
    s = colour_summary(
        f, ccm, [2.2, 1.0, 1.25], exposure_time_s=t, n_pixels_sensor=md["width_px"] * md["height_px"] * 4, metadata=md
    )
    if times is not None:
        times["fits"], times["summary"] = t1 - t0, time.perf_counter() - t1
        # CPU seconds of this process alone: its share of the channel fits, then CS etc.
        times["fits_cpu_self"], times["summary_cpu"] = c1 - c0, time.process_time() - c1
    return f, s


def measure(tb, seed, q, tmp=None) -> dict:
    """One run of each: the monochrome fit, the colour run and the colour run with the other process count (wall
    and CPU seconds), checking that the colour numbers do not depend on the process count; with
    ``tmp`` (the CSVs' folder) the whole processes too."""
    out = {}
    t0, c0 = time.perf_counter(), cpu_s()
    bayescap.fit(tb["Gr"], seed=seed, quality=q)
    out["mono"] = time.perf_counter() - t0
    reap_workers()
    out["monocpu"] = cpu_s() - c0
    t0, c0, k0 = time.perf_counter(), cpu_s(), children_cpu_s()
    parts: dict = {}
    f, s = colour_run(tb, seed, q, parts)
    out["colour"] = time.perf_counter() - t0
    reap_workers()  # (fit_cfa does not wait for its workers to exit: their CPU counts once ended)
    out["colourcpu"] = cpu_s() - c0
    crit = {"default": max(parts["fits_cpu_self"], children_cpu_s() - k0) + parts["summary_cpu"]}
    out["summarycpu"] = parts["summary_cpu"]
    t0, c0, k0 = time.perf_counter(), cpu_s(), children_cpu_s()
    parts1: dict = {}
    f1, _ = colour_run(tb, seed, q, parts1, n_jobs=OTHER_JOBS[q])  # the same numbers, checked below
    out["colour1"] = time.perf_counter() - t0
    reap_workers()
    out["colour1cpu"] = cpu_s() - c0
    crit["other"] = max(parts1["fits_cpu_self"], children_cpu_s() - k0) + parts1["summary_cpu"]
    # the pooled run's critical path in CPU seconds, what its wall time would be on otherwise idle
    # cores: the longer of this process's channel fits and its worker's, then CS etc. (one process)
    out["colourcrit"] = crit["other" if OTHER_JOBS[q] > 1 else "default"]
    if tmp is not None:
        out["climono"], out["clicolour"] = whole_processes(tmp, seed)
    assert np.array_equal(f1.draws["R"]["conversion_gain_e_per_dn"], f.draws["R"]["conversion_gain_e_per_dn"])
    out["_fits"], out["_summary"], out["_fit"], out["_summary_dict"] = parts["fits"], parts["summary"], f, s
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 cameras, the fast preset only")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument(
        "--repeats", type=int, default=3, help="runs of each timing per camera and preset; the table gives the fastest"
    )
    ap.add_argument("--repeats-fast", type=int, default=7, help="--repeats at the fast preset")
    args = ap.parse_args(argv)
    n = args.seeds or (2 if args.quick else 5)
    presets = ("fast",) if args.quick else ("fast", "standard")
    reps = {"fast": args.repeats_fast, "standard": args.repeats}
    rows = []
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        warm, _ = tables(999, tmp)
        bayescap.fit(warm["Gr"], seed=0, quality="fast")
        colour_run(warm, 0, "fast")
        for seed in range(n):
            tb, truth = tables(seed, tmp)
            row = {"seed": seed}
            for q in presets:
                runs = [measure(tb, seed, q, tmp if q == "fast" else None) for _ in range(reps[q])]
                for key in runs[0]:
                    if key.startswith("_"):
                        continue
                    row[f"{key}_{q}"] = min(r[key] for r in runs)
                    row[f"{key}_med_{q}"] = float(np.median([r[key] for r in runs]))
                best = min(runs, key=lambda r: r["colour"])  # the split of the fastest colour run
                row[f"fits_{q}"], row[f"summary_{q}"] = best["_fits"], best["_summary"]
                f, s = runs[0]["_fit"], runs[0]["_summary_dict"]
                k = f.to_dict()["shared"]["conversion_gain_e_per_dn"]["ci95"]
                row[f"ok_{q}"] = (f.k_check["passed"], bool(k[0] <= truth["k_e_per_dn"] <= k[1]), f.converged)
                row[f"cs_{q}"] = s["cs_bits"]["median"]
                emu = s["choices"].get("emulator")
                row[f"csmap_{q}"] = emu["loo_resid_frac_of_sd"] if emu else None
                row[f"csmc_{q}"] = s["choices"]["cs_interval_end_mc_error_frac_of_width"]
            rows.append(row)
            print({k: v for k, v in row.items() if "_med_" not in k}, flush=True)
    lines = [
        "# One CFA sensor's colour fit against its monochrome fit",
        "",
        f"`python benchmarks/colour_cfa_speed.py{' --quick' if args.quick else ''}"
        f"{f' --seeds {args.seeds}' if args.seeds else ''}{f' --repeats {args.repeats}' if args.repeats != 3 else ''}"
        f"{f' --repeats-fast {args.repeats_fast}' if args.repeats_fast != 7 else ''}`; "
        f"{describe_machine()}",
        "",
        "Cameras: `bayescap.validation.cfasim.simulate_cfa_ptc(seed)` (Nikon 5100 sensitivities under D65, "
        "K 2 e-/DN, read 3 e-, well 12 000 e-, 80x80 px per channel, 14 levels). Monochrome: `bayescap.fit` of "
        "the Gr table. Colour: `fit_cfa` of the four tables with its default process count (four separate fits "
        "one after the other in this process, at `fast` each gated on the parameters the colour result reports, "
        "at `standard` each channel's ensembles in lockstep; the K check, the consensus) + "
        "`colour_summary` (CS on 1000 joint draws with a CCM of 2 % stated "
        "element uncertainty, clipped after the CCM as by default, on one thread: the quadrature on 128 pilot "
        "draws and, where its leave-one-out check admits it, a linear map of the draws' inputs on all, "
        "`bayescap.colour.cs_emulator`; scores, capacities). Times "
        f"after one warm-up fit; each the fastest of {reps['fast']} runs at `fast`, {args.repeats} at `standard` "
        "(monochrome, colour and colour with the "
        "other process count in turn; the ratios with the median of the runs are listed below the table). CPU time, the "
        "target's measure: this process and its ended workers (the monochrome MCMC's ensemble processes, the "
        "colour fit's channel processes); 'CS etc.': this process's CPU seconds in `colour_summary`. Critical "
        "path: of the `n_jobs=2` colour run, the longer of this process's and its worker's CPU seconds in the "
        "channel fits, plus CS etc.: its wall time on otherwise idle cores. 'Other process count': the same "
        "colour run (the same numbers, checked) with `n_jobs=2` (a worker process fits half the channels; every "
        "colour run runs a channel's MCMC ensembles in lockstep in its process, the monochrome fit in one forked "
        "process per core). "
        "Wall times beside them, not the measure: the machine is shared.",
        "",
        f"Load average (1 min) at the start {load0[0]:.2f}, at the end {os.getloadavg()[0]:.2f} on "
        f"{os.cpu_count()} cores.",
        "",
        "| seed | preset | CPU mono (s) | CPU colour (s) | CPU ratio | CS etc. CPU (s) | other process count "
        "CPU (s) | its ratio | critical path (CPU s) | its ratio | wall mono (s) | wall colour (s) | wall ratio "
        "| wall other process count (s) | K check | true K in joint 95 % | converged | CS (bits) | CS map's "
        "leave-one-out residual / CS sd | CS 95 % ends' MC error / width |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        for q in presets:
            kc, kin, conv = r[f"ok_{q}"]
            m = r[f"monocpu_{q}"]
            lines.append(
                f"| {r['seed']} | {q} | {m:.2f} | {r[f'colourcpu_{q}']:.2f} | {r[f'colourcpu_{q}'] / m:.2f} | "
                f"{r[f'summarycpu_{q}']:.2f} | {r[f'colour1cpu_{q}']:.2f} | {r[f'colour1cpu_{q}'] / m:.2f} | "
                f"{r[f'colourcrit_{q}']:.2f} | {r[f'colourcrit_{q}'] / m:.2f} | {r[f'mono_{q}']:.2f} | "
                f"{r[f'colour_{q}']:.2f} | {r[f'colour_{q}'] / r[f'mono_{q}']:.2f} | {r[f'colour1_{q}']:.2f} | "
                f"{'pass' if kc else 'FAIL'} | {'yes' if kin else 'no'} | {conv} | {r[f'cs_{q}']:.3f} | "
                + (f"{r[f'csmap_{q}']:.3f}" if r[f"csmap_{q}"] is not None else "not used")
                + f" | {r[f'csmc_{q}']:.3f} |"
            )
    lines += [
        "",
        "Whole processes (fast preset, `bayescap colour`'s default; CPU seconds of the ended child, the "
        f"fastest of {reps['fast']}): `bayescap colour` of the four CSVs against `bayescap fit` of the Gr CSV, "
        "imports, reading and output included.",
        "",
        "| seed | bayescap fit --quality fast (CPU s) | bayescap colour (CPU s) | ratio |",
        "|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['seed']} | {r['climono_fast']:.2f} | {r['clicolour_fast']:.2f} | "
            f"{r['clicolour_fast'] / r['climono_fast']:.2f} |"
        )
    lines.append("")

    def total(num, den):
        return sum(r[num] for r in rows) / sum(r[den] for r in rows)

    def verdict(num, den, label, target=True, note=""):
        rr = [r[num] / r[den] for r in rows]
        tot = total(num, den)
        judged = f": {'meets' if max(tot, np.median(rr)) <= 3.0 else 'MISSES'} the 3x target" if target else ""
        lines.append(
            f"- {label}: median {np.median(rr):.2f}x (range {min(rr):.2f}-{max(rr):.2f}x), total "
            f"{tot:.2f}x{judged}{note}."
        )

    for q in presets:
        verdict(f"colourcpu_{q}", f"monocpu_{q}", f"CPU time, colour ({q}) / monochrome ({q})")
    for q in presets:
        verdict(
            f"colour1cpu_{q}",
            f"monocpu_{q}",
            f"CPU time, colour with n_jobs={OTHER_JOBS[q]} ({q}) / monochrome ({q})",
            target=False,
        )
    if "standard" in presets:
        verdict(
            "colourcpu_fast",
            "monocpu_standard",
            "CPU time, colour (fast) / monochrome (standard, bayescap fit's default)",
        )
    verdict("clicolour_fast", "climono_fast", "whole processes' CPU time, bayescap colour / bayescap fit (fast)")
    verdict(
        "colourcrit_fast",
        "monocpu_fast",
        "critical path in CPU seconds, colour (fast, n_jobs=2) / monochrome (fast, one process)",
        note=f" on {os.cpu_count()} otherwise idle cores (an estimate of the wall time there: the longer of the "
        "two processes' channel fits, then CS etc.; the fork and the results' transfer are in it)",
    )
    if min(reps.values()) > 1:
        for q in presets:
            rr = [r[f"colourcpu_med_{q}"] / r[f"monocpu_med_{q}"] for r in rows]
            lines.append(
                f"- with the median of the {reps[q]} runs instead of the fastest, CPU time, colour ({q}) / "
                f"monochrome ({q}): median {np.median(rr):.2f}x (range {min(rr):.2f}-{max(rr):.2f}x)."
            )
    for q in presets:
        verdict(
            f"colour_{q}",
            f"mono_{q}",
            f"wall time, colour ({q}) / monochrome ({q})",
            target=False,
            note=" (not the measure: the load average above)",
        )
    lines.append("")
    emit(lines, HERE / "results" / "colour_cfa_speed.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
