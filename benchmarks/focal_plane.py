"""A focal plane as one batch: 3 024 amplifier tables (189 CCDs × 16 amplifiers) through
``bayescap fit … --out DIR --dask 2`` and through the local pool (``--jobs 2``), ``--quality fast``
(issue 46, item 5).

    python benchmarks/run.py focal_plane                 # writes benchmarks/results/focal_plane.md
    python benchmarks/focal_plane.py --n-tables 64       # a small run (the file gives the command)
    python benchmarks/focal_plane.py --n-tables 192 --runs pool   # the local pool only (no comparison)

The tables come from :func:`bayescap.validation.astro.focal_plane` (gain 0.6–1.8 e⁻/ADU, read noise
3–10 e⁻, brighter-fatter a₀₀ −(1–3)·10⁻⁶ per e⁻, 40–400 flat pairs, 32 × 32 pixels per amplifier,
bias removed by an overscan), simulated frame by frame by :mod:`bayescap.validation.framesim` and
written as ``mean_dn,temporal_var_dn2,n_pixels`` CSVs (cached in ``benchmarks/.zoo_cache/focal_plane/``;
simulating all 3 024 takes 15–30 min on 2 cores, once). Both runs are the command line a user types,
timed from start to exit (the Dask run includes starting its 2-worker LocalCluster), seed 1, into
fresh temporary folders; then every ``result.json`` is compared between the two (wall times and the
``batch`` entry aside) and scored against the truths (:func:`bayescap.validation.astro.score_astro`).
Target: ≤ 5 min on 2 workers.

A bayescap without mean/variance-only tables refuses them: the benchmark then stops with that
message, exit status 2, and writes nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "focal_plane.md"
CACHE = ROOT / "benchmarks" / ".zoo_cache" / "focal_plane"


def _gen(item):
    from bayescap.validation.astro import ensure_astro_csv

    name, truth, seed = item
    return str(ensure_astro_csv(CACHE, name, truth, seed, n_pixels=True))


def _numbers(doc):
    doc = dict(doc)
    doc.pop("batch", None)
    doc["diagnostics"] = {k: v for k, v in doc.get("diagnostics", {}).items() if not k.endswith("wall_s")}
    return doc


def _load():
    try:
        return "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())
    except OSError:
        return "n/a"


def _verdict(wall, n, full=3024, target_s=300.0):
    """The target's verdict for a run of ``n`` tables: on the whole focal plane as measured; on fewer,
    at the run's own rate scaled to the whole (an extrapolation, said as one)."""
    if n >= full:
        return "met" if wall <= target_s else "**NOT met**"
    at = wall * full / n
    return f"{at:.0f} s at this rate (extrapolated): " + ("met" if at <= target_s else "**NOT met**")


def _children_cpu_s():
    """CPU seconds (user + system) of this process's finished children and their descendants."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cli(paths, out, extra, log):
    """Run ``bayescap fit`` on ``paths`` into ``out``: (wall seconds, CPU seconds of the command and
    the processes it started, exit status)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    cmd = [sys.executable, "-m", "bayescap", "fit", *map(str, paths)]
    cmd += ["--out", str(out), "--quality", "fast", "--seed", "1", "--no-progress", *extra]
    t, c = time.perf_counter(), _children_cpu_s()
    with open(log, "w") as fh:
        code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=fh, stderr=subprocess.STDOUT).returncode
    return time.perf_counter() - t, _children_cpu_s() - c, code


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--n-tables", type=int, default=3024, help="the first N amplifiers of the focal plane (default 3024)"
    )
    ap.add_argument("--workers", type=int, default=2, help="--dask and --jobs workers (default 2)")
    ap.add_argument("--gen-jobs", type=int, default=2, help="processes simulating the tables (default 2)")
    ap.add_argument("--keep", default=None, help="keep the two output folders under this folder")
    ap.add_argument(
        "--runs",
        default="dask,pool",
        help="which runs: dask, pool or both (default dask,pool; with one, no comparison between them)",
    )
    a = ap.parse_args(argv)
    runs = [r for r in ("dask", "pool") if r in a.runs.split(",")]
    if not runs:
        ap.error("--runs: dask, pool or dask,pool")
    from _machine import describe_machine, emit
    from astro_tables import check_supported

    from bayescap.validation.astro import focal_plane, score_astro

    amps = focal_plane()[: a.n_tables]
    truths = {name: truth for name, truth, _ in amps}
    check_supported(_gen(amps[0]), "focal_plane")
    t = time.perf_counter()
    with Pool(a.gen_jobs) as pool:
        paths = [Path(p) for p in pool.imap(_gen, amps, chunksize=8)]
    gen_s = time.perf_counter() - t
    n_rows = sum(t.n_points for _, t, _ in amps)
    tmp = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="focal_plane_"))
    tmp.mkdir(parents=True, exist_ok=True)
    load0 = _load()
    try:
        for sub in ("dask", "pool"):
            shutil.rmtree(tmp / sub, ignore_errors=True)
        flag = {"dask": "--dask", "pool": "--jobs"}
        timed = {sub: run_cli(paths, tmp / sub, [flag[sub], str(a.workers)], tmp / f"{sub}.log") for sub in runs}
        load1 = _load()
        recs, same, both = [], 0, 0
        missing = {sub: 0 for sub in runs}
        scored = runs[0]  # the run scored against the truths
        for p in paths:
            name = p.stem
            docs = {}
            for sub in runs:
                f = tmp / sub / name / "result.json"
                if f.exists():
                    docs[sub] = json.loads(f.read_text())
                else:
                    missing[sub] += 1
            if len(docs) == 2:
                both += 1
                same += _numbers(docs["dask"]) == _numbers(docs["pool"])
            if scored in docs:
                amp = name.rsplit("-", 1)[0]
                sc = score_astro(truths[amp], docs[scored])
                sc["name"] = amp
                sc["converged"] = bool(docs[scored].get("diagnostics", {}).get("converged"))
                sc["laplace_is"] = docs[scored].get("diagnostics", {}).get("method") == "laplace-is"
                recs.append(sc)
        tails = {sub: (tmp / f"{sub}.log").read_text().strip().splitlines()[-3:] for sub in runs}
    finally:
        if not a.keep:
            shutil.rmtree(tmp, ignore_errors=True)

    def frac(xs):
        xs = list(xs)
        return f"{sum(xs)}/{len(xs)} ({100 * sum(xs) / len(xs):.1f} %)" if xs else "–"

    n = len(amps)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    cmd = f"python benchmarks/focal_plane.py --n-tables {a.n_tables} --workers {a.workers}"
    if runs != ["dask", "pool"]:
        cmd += f" --runs {','.join(runs)}"
    label = {
        "dask": f"`--dask {a.workers}` (a new LocalCluster, its start-up included)",
        "pool": f"`--jobs {a.workers}` (the local process pool)",
    }
    rows = [
        f"| {label[sub]} | {t:.1f} | {n / t:.1f} | {cpu:.0f} | {cpu / n:.2f} | {code} | {n - missing[sub]}/{n} "
        f"| {_verdict(t, n)} |"
        for sub, (t, cpu, code) in timed.items()
    ]
    L = [
        "# A focal plane as one batch: amplifier PTC tables through `bayescap fit --dask` and the local pool",
        "",
        f"Command: `{cmd}` (`python benchmarks/run.py focal_plane`), code at commit {commit}.  ",
        f"Machine: {describe_machine()}.  ",
        f"Load average (1, 5, 15 min) before: {load0}; after: {load1} (a shared machine: other work inflates every time).",
        "",
        f"{n} amplifier tables ({n // 16} CCDs × 16 amplifiers; {n_rows} flat pairs in all; "
        "`bayescap.validation.astro.focal_plane`: gain 0.6–1.8 e⁻/ADU, read noise 3–10 e⁻, a₀₀ −(1–3)·10⁻⁶/e⁻, "
        "40–400 pairs, 32 × 32 pixels), CSVs of `mean_dn,temporal_var_dn2,n_pixels` simulated frame by frame "
        f"({gen_s:.0f} s here; cached). Both runs: `bayescap fit <{n} CSVs> --out DIR --quality fast --seed 1`, "
        "timed from start to exit.",
        "",
        "| run | wall (s) | tables/s | CPU (s) | CPU per table (s) | exit | result.json written | target: 3 024 tables ≤ 300 s |",
        "|---|---:|---:|---:|---:|---|---|---|",
        *rows,
        "",
        "CPU: user + system seconds of the command and every process it started (workers, Dask's "
        "scheduler and nannies), from `getrusage(RUSAGE_CHILDREN)`: less sensitive than the wall time to other "
        f"work on the machine. On {a.workers} cores the wall time cannot fall below CPU / {a.workers}.",
        "",
        (
            f"Same numbers: {same} of {both} amplifiers' `result.json` identical between the two runs (wall times "
            "and the `batch` entry aside)."
            if len(runs) == 2
            else f"Only the `{runs[0]}` run (`--runs {runs[0]}`): no comparison between the two."
        ),
        "",
        f"## Against the truths (the `{'--dask' if scored == 'dask' else '--jobs'}` run)",
        "",
        "| check | result |",
        "|---|---|",
        f"| K's truth inside its 95 % interval | {frac(r['k_inside'] for r in recs)} |",
        f"| K more than 3 half-widths off | {sum(r['k_miss_half_widths'] > 3 for r in recs)} |",
        f"| read noise within 10 % | {frac(abs(r['read_rel_err']) < 0.1 for r in recs)} |",
        f"| read noise's truth inside its 95 % interval | {frac(r['read_inside'] for r in recs)} |",
        f"| converged | {frac(r['converged'] for r in recs)} |",
        f"| fast path accepted (no MCMC fallback) | {frac(r['laplace_is'] for r in recs)} |",
        f"| `ptc_turnoff_dn` reported | {frac(r['ptc_turnoff_dn'] is not None for r in recs)} |",
        "",
        "## Per CCD (16 amplifiers each)",
        "",
        "| CCD | amplifiers | K inside 95 % | median \\|K − truth\\|/truth | read noise within 10 % | max \\|read noise error\\| |",
        "|---|---|---|---|---|---|",
    ]
    by_ccd = {}
    for r in recs:
        by_ccd.setdefault(r["name"].split("_")[0], []).append(r)
    for ccd, rs in sorted(by_ccd.items()):
        kerr = [abs(r["k_median"] / r["k_truth"] - 1) for r in rs if r["k_median"] is not None]
        L.append(
            f"| {ccd} | {len(rs)} | {sum(r['k_inside'] for r in rs)} | "
            f"{100 * np.median(kerr):.2f} % | {sum(abs(r['read_rel_err']) < 0.1 for r in rs)} | "
            f"{100 * np.nanmax([abs(r['read_rel_err']) for r in rs]):.1f} % |"
        )
    if any(code for _, _, code in timed.values()):
        L += ["", "Last lines of the runs' output:", ""]
        for sub, lines in tails.items():
            L += [f"- `{sub}`: " + " / ".join(x.strip() for x in lines)]
    emit(L, OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
