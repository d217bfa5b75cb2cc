"""Where the CPU of a focal-plane amplifier's ``fast`` fit goes: a fixed subset of the focal plane's
tables (every 31st of the 3 024, the same cached CSVs as ``benchmarks/focal_plane.py``), fitted

1. in this process, one table after another (``bayescap.fit(csv, quality="fast", seed=1)``, one thread,
   one process: ``BAYESCAP_THREADS=1 BAYESCAP_JOBS=1``), its CPU per table split into the tables the
   fast path accepted and those it sent to the MCMC fallback;
2. the same under ``cProfile``: the share of the CPU in each stage (the profiler's own cost inflates
   the small calls, so the shares are approximate; the absolute CPU comes from 1.);
3. through the command line a user types, ``bayescap fit <CSVs> --out DIR --quality fast --seed 1
   --jobs 2``: the CPU of the command and its two workers per table, against 1. (the batch's own cost:
   three processes' start and imports, loading the tables, the result files and summary table, and
   two workers sharing the machine's caches).

    python benchmarks/focal_plane_cpu.py                 # writes benchmarks/results/focal_plane_cpu.md
    python benchmarks/focal_plane_cpu.py --n-tables 24   # a smaller subset (the file gives the command)

The focal-plane target (issue 46: 3 024 tables in ≤ 300 s on 2 workers) needs ≤ ~0.19 CPU-s per table,
the batch's cost included. On a shared machine every CPU time is inflated by the other work (the load
average is in the file); compare numbers of one run.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("BAYESCAP_THREADS", "1")
os.environ.setdefault("BAYESCAP_JOBS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "focal_plane_cpu.md"

#: the stages reported: (label, file suffix, function name); cumulative CPU of the outermost call
STAGES = [
    ("whole fit (`bayescap.fit`)", "bayescap/api.py", "fit"),
    ("fast path (`fast_posterior`, all attempts)", "inference/fast.py", "fast_posterior"),
    ("↳ MAP and Laplace covariance (Newton)", "inference/optimize.py", "laplace_start"),
    (
        "↳ first 6 000 draws (Laplace t, defensive components, adaptive rounds)",
        "inference/fast_stages.py",
        "_initial_mixture",
    ),
    ("↳ top-up towards the interval-end gate", "inference/fast.py", "_top_up"),
    ("MCMC fallback (`run_ensembles`)", "inference/mcmc.py", "run_ensembles"),
    ("result (`FitResult.from_chains`: derived quantities, row checks)", "posterior/result.py", "from_chains"),
    ("`PTCModel.log_prob` (every caller)", "model/ptc_model.py", "_log_posterior"),
    ("↳ predictions (`predict`)", "model/prediction.py", "predict"),
    ("↳↳ clip rows' latent solver (`_latent_clip_rows`)", "model/clipping.py", "_latent_clip_rows"),
    ("↳↳↳ its moments at the latent mean (`_clip_var_slope`)", "model/clipping.py", "_clip_var_slope"),
]


def _load():
    try:
        return "{:.1f} {:.1f} {:.1f}".format(*os.getloadavg())
    except OSError:
        return "n/a"


def _self_cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _fit_all(paths):
    """Each table's fit in this process: [(CPU s, accepted by the fast path)]."""
    import bayescap

    out = []
    for p in paths:
        c = _self_cpu()
        r = bayescap.fit(str(p), quality="fast", seed=1)
        out.append((_self_cpu() - c, r.diag.get("method") == "laplace-is"))
    return out


def _cumulative(stats, suffix, name):
    """Cumulative seconds of the function ``name`` in a file ending with ``suffix`` (0 if not called)."""
    total = 0.0
    for (fname, _, fn), (_, _, _, ct, _) in stats.stats.items():
        if fn == name and fname.replace(os.sep, "/").endswith(suffix):
            total += ct
    return total


def _cli(paths, jobs, tmp):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.pop("BAYESCAP_THREADS", None)  # (as a user runs it: the batch's workers use one thread each)
    env.pop("BAYESCAP_JOBS", None)
    out = Path(tmp) / f"jobs{jobs}"
    cmd = [sys.executable, "-m", "bayescap", "fit", *map(str, paths), "--out", str(out)]
    cmd += ["--quality", "fast", "--seed", "1", "--no-progress", "--jobs", str(jobs)]
    t, c = time.perf_counter(), _children_cpu()
    code = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    return time.perf_counter() - t, _children_cpu() - c, code


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-tables", type=int, default=96, help="tables in the subset (default 96)")
    ap.add_argument("--step", type=int, default=31, help="every STEP-th amplifier of the focal plane (default 31)")
    a = ap.parse_args(argv)
    from _machine import describe_machine, emit
    from focal_plane import _gen

    from bayescap.validation.astro import focal_plane

    amps = focal_plane()[:: a.step][: a.n_tables]
    paths = [Path(_gen(amp)) for amp in amps]
    n = len(paths)
    load0 = _load()
    _fit_all(paths[:1])  # imports and first-call tables out of the way
    plain = _fit_all(paths)
    prof = cProfile.Profile()
    prof.enable()
    _fit_all(paths)
    prof.disable()
    stats = pstats.Stats(prof)
    tmp = tempfile.mkdtemp(prefix="focal_plane_cpu_")
    try:
        cli = {jobs: _cli(paths, jobs, tmp) for jobs in (2,)}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    load1 = _load()

    cpu = [c for c, _ in plain]
    acc = [c for c, ok in plain if ok]
    rej = [c for c, ok in plain if not ok]
    per = sum(cpu) / n
    whole = _cumulative(stats, "bayescap/api.py", "fit")
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    cmd = f"python benchmarks/focal_plane_cpu.py --n-tables {a.n_tables} --step {a.step}"
    L = [
        "# Where the CPU of a focal-plane amplifier's `fast` fit goes",
        "",
        f"Command: `{cmd}` (`python benchmarks/run.py focal_plane_cpu`), code at commit {commit}.  ",
        f"Machine: {describe_machine()}.  ",
        f"Load average (1, 5, 15 min) before: {load0}; after: {load1} (a shared machine: other work inflates every CPU time).",
        "",
        f"{n} amplifier tables of `bayescap.validation.astro.focal_plane` (1 in {a.step} of the 3 024; "
        f"{sum(t.n_points for _, t, _ in amps)} flat pairs in all), the cached CSVs of `benchmarks/focal_plane.py`. "
        "Target (issue 46): 3 024 tables in ≤ 300 s on 2 workers, i.e. ≤ ~0.19 CPU-s per table, the batch's cost included.",
        "",
        "## CPU per table",
        "",
        "| how | tables | CPU per table (s) |",
        "|---|---:|---:|",
        f"| in this process, one thread (`bayescap.fit`, imports excluded) | {n} | {per:.3f} |",
        f"| … accepted by the fast path | {len(acc)} | {sum(acc) / max(len(acc), 1):.3f} |",
        f"| … sent to the MCMC fallback | {len(rej)} | {sum(rej) / max(len(rej), 1):.3f} |",
        f"| … the fallbacks' share of the whole | | {100 * sum(rej) / max(sum(cpu), 1e-12):.0f} % |",
    ]
    for jobs, (wall, c, code) in cli.items():
        L.append(
            f"| `bayescap fit <{n} CSVs> --out DIR --quality fast --seed 1 --jobs {jobs}` (the command and its "
            f"workers, start-up included; wall {wall:.0f} s, exit {code}) | {n} | {c / n:.3f} |"
        )
    L += [
        "",
        "## Stages (under cProfile, share of the whole fit)",
        "",
        "| stage | CPU per table (s, profiled) | share |",
        "|---|---:|---:|",
    ]
    for label, suffix, name in STAGES:
        t = _cumulative(stats, suffix, name)
        L.append(f"| {label} | {t / n:.3f} | {100 * t / max(whole, 1e-12):.0f} % |")
    L += [
        "",
        "Rows marked ↳ are parts of the row above them. `log_prob` is called by the MAP, the draws, the top-up "
        "and the MCMC fallback alike.",
    ]
    emit(L, OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
