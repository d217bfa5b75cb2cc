"""The whole process a user waits for, stage by stage (issue 50).

    python benchmarks/run.py process_stages        # writes benchmarks/results/process_stages.md
    python benchmarks/process_stages.py --repeat 1 # one run of each, printed and written

For the bundled sensors (the real Basler CCD and the simulated ones in ``data/simulated/``), at
``fast`` and ``standard``, three measurements, each in fresh Python processes (the median of
``--repeat`` runs):

* **whole process**: ``python -m bayescap fit CSV --quality Q --json --seed 1`` from start to exit, as a
  user types it (stdout to /dev/null), with the stages' seed, so that both run the same fit (a drawn
  seed would mix accepted and rejected fast paths from run to run);
* **stages**: the same work in one process, timed stage by stage with ``time.perf_counter``: imports
  (``bayescap`` and ``bayescap.api``, with the scipy it loads; emcee is imported by the fit when it
  samples by MCMC (without scipy.stats, see ``bayescap.inference.moves``), so its import falls in the fit),
  reading the CSV, building the model (term selection and the rows a fit sees), the fit itself split
  into the sampler's own wall time (start, optimisation, sampling: ``diagnostics.wall_s``) and the
  rest of ``bayescap.fit`` (checks, derived quantities' draws), the result's dictionary
  (``to_dict``: summaries, intervals, limits, notes) and writing the JSON;
* **a plain 2-parameter emcee script** on the same CSV (``benchmarks/_plain_emcee.py``: log K and
  log read noise, Gaussian variances, StretchMove, 32 walkers × 2 500 steps, one walker per call: how
  a new user would write it), from start to exit: the yardstick issue 50 asks the whole process to beat.

Before measuring, ``python -m compileall`` writes bayescap's bytecode cache (``__pycache__``), as
``pip install`` does: otherwise, where ``PYTHONDONTWRITEBYTECODE`` is set (as in this project's
sandbox), every process compiles bayescap's ~80 modules from source again. What that costs is
measured too: the imports of a copy of the package without a cache, with
``PYTHONDONTWRITEBYTECODE=1`` (the imports of an uncompiled checkout), alternating with those of the
compiled one.

Also ``bayescap --version`` (start to exit). Every whole-process time is given as wall time and as CPU
time (user + sys of the process and of the pool workers it forks, from ``getrusage``): on a shared
machine the CPU time is the fairer comparison. Targets (issue 50, quiet 2-core machine): ``--version``
≤ 0.3 s; the Basler ``fit --json`` ≤ 2 s, the phone sensor's ≤ 2 s; faster than the plain script.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
OUT = ROOT / "benchmarks" / "results" / "process_stages.md"

SENSORS = {
    "basler_ccd12 (real)": "data/emva1288_basler_ccd12.csv",
    "phone 1.75 µm 10-bit": "data/simulated/sim_phone_1p75um_10bit.csv",
    "industrial 3.45 µm 12-bit": "data/simulated/sim_industrial_3p45um_12bit.csv",
    "scientific 6.5 µm 16-bit": "data/simulated/sim_scientific_6p5um_16bit_unsaturated.csv",
    "S-shaped 8-bit": "data/simulated/sim_s_shape_8bit.csv",
}

STAGES_DRIVER = r"""
import json, resource, sys, time
def cpu():  # user + sys of this process and of its reaped children (the fit's pool workers)
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime
t0, c0 = time.perf_counter(), cpu()
import bayescap
import bayescap.api
t1, c1 = time.perf_counter(), cpu()
from bayescap.model import PTCModel
path, quality, out = sys.argv[1], sys.argv[2], sys.argv[3]
data = bayescap.load(path)
t2 = time.perf_counter()
model = PTCModel.for_fit(data)
t3 = time.perf_counter()
result = bayescap.fit(model, quality=quality, seed=1)
t4, c4 = time.perf_counter(), cpu()
doc = result.to_dict()
t5 = time.perf_counter()
from bayescap.io.atomic import atomic_write_text
atomic_write_text(out, json.dumps(doc, default=float))
t6, c6 = time.perf_counter(), cpu()
d = result.diag
ws = None
if d.get("method") == "emcee":  # log-p evaluations of the sampling: every walker once a step
    ws = int(d["n_ensembles"] * d["n_walkers"] * (d["n_burn"] + d["n_steps"] + d.get("burn_in_extended_steps", 0)))
print(json.dumps({"import": t1 - t0, "read": t2 - t1, "model": t3 - t2, "fit": t4 - t3,
                  "sampler": float(d.get("wall_s", float("nan"))), "result": t5 - t4,
                  "write": t6 - t5, "method": d.get("method"), "cpu_import": c1 - c0, "cpu_fit": c4 - c1,
                  "cpu_total": c6 - c0, "walker_steps": ws, "ess_min": d.get("ess_min"),
                  "converged": d.get("converged")}))
"""


IMPORTS = "import bayescap\nimport bayescap.api\n"


def _env(root=ROOT, **extra):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.setdefault("OMP_NUM_THREADS", "1")
    env.update(extra)
    return env


def _compile():
    """bayescap's bytecode cache, written as ``pip install`` writes it (read even where
    ``PYTHONDONTWRITEBYTECODE`` forbids writing it)."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "bayescap")], check=True)


def _imports(n, tmp):
    """{"cached": (median wall, median CPU), "uncached": (...)} of ``import bayescap, bayescap.api``
    in ``n`` fresh processes each, the two alternating (a shared machine's load drifts): with this
    checkout's bytecode cache, and from a copy of the package without one, with
    ``PYTHONDONTWRITEBYTECODE=1`` (each process compiles the package again)."""
    root = Path(tmp) / "uncompiled"
    shutil.copytree(ROOT / "bayescap", root / "bayescap", ignore=shutil.ignore_patterns("__pycache__"))
    # (run from the package's parent: ``python -c`` puts the working directory first on the path)
    envs = {"cached": (_env(), ROOT), "uncached": (_env(root, PYTHONDONTWRITEBYTECODE="1"), root)}
    runs = {k: ([], []) for k in envs}
    for i in range(n):
        for k in envs if i % 2 == 0 else reversed(list(envs)):
            w, c = _wall([sys.executable, "-c", IMPORTS], 1, env=envs[k][0], cwd=envs[k][1])
            runs[k][0].append(w)
            runs[k][1].append(c)
    return {k: (statistics.median(w), statistics.median(c)) for k, (w, c) in runs.items()}


def _children_cpu():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _wall(cmd, repeat, env=None, cwd=ROOT):
    """(median wall time, median CPU time) in seconds of ``repeat`` runs of ``cmd`` (a list), each a
    fresh process; the CPU time is user + sys of the process and of the workers it forks."""
    times, cpus = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), _children_cpu()
        subprocess.run(
            cmd, cwd=cwd, env=env or _env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True
        )
        times.append(time.perf_counter() - t)
        cpus.append(_children_cpu() - c)
    return statistics.median(times), statistics.median(cpus)


def _stages(path, quality, repeat, tmp):
    runs = []
    for _ in range(repeat):
        out = subprocess.run(
            [sys.executable, "-c", STAGES_DRIVER, path, quality, str(Path(tmp) / "r.json")],
            cwd=ROOT,
            env=_env(),
            capture_output=True,
            text=True,
            check=True,
        )
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    keys = ("import", "read", "model", "fit", "sampler", "result", "write", "cpu_import", "cpu_fit", "cpu_total")
    med = {k: statistics.median(r[k] for r in runs) for k in keys}
    for k in ("method", "walker_steps", "ess_min", "converged"):  # the same in every run (seed 1)
        med[k] = runs[0][k]
    return med


def run(repeat):
    rows = []
    _compile()
    with tempfile.TemporaryDirectory() as tmp:
        plain = ROOT / "benchmarks" / "_plain_emcee.py"
        version = _wall([sys.executable, "-m", "bayescap", "--version"], max(repeat, 3))
        imports = _imports(max(3 * repeat, 9), tmp)
        for name, csv in SENSORS.items():
            plain_s, plain_cpu = _wall([sys.executable, str(plain), csv], repeat)
            for q in ("fast", "standard"):
                whole, whole_cpu = _wall(
                    [sys.executable, "-m", "bayescap", "fit", csv, "--quality", q, "--json", "--seed", "1"], repeat
                )
                st = _stages(csv, q, repeat, tmp)
                rows.append(
                    {
                        "name": name,
                        "quality": q,
                        "whole": whole,
                        "whole_cpu": whole_cpu,
                        "plain": plain_s,
                        "plain_cpu": plain_cpu,
                        **st,
                    }
                )
                print(json.dumps(rows[-1]), flush=True)
    return version, imports, rows


def report(version, imports, rows, repeat):
    from _machine import describe_machine, emit

    try:
        load = "{:.1f}, {:.1f}, {:.1f}".format(*os.getloadavg())
    except OSError:
        load = "unknown"
    basler = next(r for r in rows if r["name"].startswith("basler") and r["quality"] == "standard")
    phone = next(r for r in rows if r["name"].startswith("phone") and r["quality"] == "standard")
    faster = sum(r["whole"] < r["plain"] for r in rows if r["quality"] == "standard")
    faster_cpu = sum(r["whole_cpu"] < r["plain_cpu"] for r in rows if r["quality"] == "standard")
    n_std = sum(r["quality"] == "standard" for r in rows)
    ver_wall, ver_cpu = version
    L = [
        "# The whole process, stage by stage",
        "",
        f"`python benchmarks/run.py process_stages` (`python benchmarks/process_stages.py --repeat {repeat}`); "
        f"each number the median of {repeat} fresh processes. Machine: {describe_machine()}; load average "
        f"at the end {load} (above ~1 the machine was shared: the wall times are pessimistic, and the CPU "
        "times, user + sys of the process and the workers it forks, are the fairer comparison).",
        "",
        "## Targets (issue 50, quiet 2-core machine)",
        "",
        f"* `bayescap --version`: **{ver_wall:.2f} s** wall, {ver_cpu:.2f} s CPU (target ≤ 0.3 s)",
        f"* the Basler `fit --json` (`standard`, the default): **{basler['whole']:.2f} s** wall, "
        f"{basler['whole_cpu']:.2f} s CPU (target ≤ 2 s)",
        f"* the simulated 1.75 µm phone sensor (bundled; not the issue's held-out 47-row one), `fit --json`: **{phone['whole']:.2f} s** wall, "
        f"{phone['whole_cpu']:.2f} s CPU (target ≤ 2 s)",
        f"* the plain 2-parameter emcee script on the same CSV: Basler {basler['plain']:.2f} s wall, "
        f"{basler['plain_cpu']:.2f} s CPU; `standard` faster than it on {faster} of {n_std} sensors by wall time, "
        f"{faster_cpu} of {n_std} by CPU time",
        "",
        "## Imports and the bytecode cache",
        "",
        "Every process below reads bayescap's bytecode cache, compiled first (`python -m compileall`, as "
        "`pip install` does). Without it, where `PYTHONDONTWRITEBYTECODE` is set (as in this project's "
        "sandbox), every process compiles the package again:",
        "",
        f"Medians of {max(3 * repeat, 9)} processes each, the two kinds alternating:",
        "",
        f"* `import bayescap, bayescap.api` with the cache: {imports['cached'][0]:.2f} s wall, "
        f"{imports['cached'][1]:.2f} s CPU",
        f"* the same from a copy without a cache, `PYTHONDONTWRITEBYTECODE=1`: {imports['uncached'][0]:.2f} s wall, "
        f"{imports['uncached'][1]:.2f} s CPU",
        "",
        "## Per sensor",
        "",
        "Stages from one process (wall seconds): imports (bayescap and bayescap.api, with their scipy), reading "
        "the CSV, building the model (terms and rows), the fit (of which the sampler: start, optimisation, "
        "sampling; the fit imports emcee when it samples by MCMC), the result's dictionary (summaries, limits, "
        "notes) and writing the JSON. 'whole' is `python -m bayescap fit CSV --quality Q --json --seed 1` (the "
        "stages' seed) from start to exit, wall and CPU; 'fit CPU' the fit's user + sys (its pool workers included); 'walker-steps' the "
        "log-p evaluations of the MCMC's burn-in and production (ensembles × walkers × steps; the start's "
        "optimiser and importance draws not counted); 'plain' the plain emcee script, wall and CPU.",
        "",
        "| sensor | preset | method | whole | whole CPU | imports | read | model | fit | fit CPU | of which sampler "
        "| result | write | walker-steps | ESS min | plain emcee | plain CPU |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ws = "–" if r["walker_steps"] is None else f"{r['walker_steps']:,}".replace(",", " ")
        ess = "–" if r["ess_min"] is None else f"{r['ess_min']:.0f}"
        L.append(
            f"| {r['name']} | {r['quality']} | {r['method']} | {r['whole']:.2f} | {r['whole_cpu']:.2f} | "
            f"{r['import']:.2f} | {r['read']:.3f} | {r['model']:.3f} | {r['fit']:.2f} | {r['cpu_fit']:.2f} | "
            f"{r['sampler']:.2f} | {r['result']:.2f} | {r['write']:.3f} | {ws} | {ess} | {r['plain']:.2f} | "
            f"{r['plain_cpu']:.2f} |"
        )
    return emit(L, OUT)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes per measurement (median; default 3)")
    a = ap.parse_args(argv)
    version, imports, rows = run(a.repeat)
    report(version, imports, rows, a.repeat)


if __name__ == "__main__":
    main()
