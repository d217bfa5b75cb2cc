"""Time a default (standard-quality) fit of a 50-level photon-transfer CSV.

    python benchmarks/bench_fit.py [--repeats 3]

Reports the wall time of ``bayescap.fit`` (Python start-up and imports excluded, measured
separately), split into its phases, for the bundled real Basler set (51 rows) and a simulated
50-level sensor, with 1 and 2 worker processes. Writes benchmarks/results/bench_fit.md.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _machine import describe_machine

ROOT = Path(__file__).resolve().parents[1]


def _machine():
    import datetime

    return (f"{describe_machine()}; load average before the run {os.getloadavg()[0]:.2f}; "
            f"{datetime.datetime.now().isoformat(timespec='minutes')}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "bench_fit.md"))
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "import time; t=time.perf_counter(); import bayescap, arviz; "
                        "print(time.perf_counter()-t)"], capture_output=True, text=True, check=True)
    import_s = float(r.stdout.strip())
    import bayescap
    from bayescap.inference.coordinates import mcmc_start
    from bayescap.model.ptc_model import PTCModel

    files = {"Basler CCD (real, 51 rows)": ROOT / "data" / "emva1288_basler_ccd12.csv",
             "simulated 1.75 um (50 rows)": ROOT / "data" / "simulated" / "sim_phone_1p75um_10bit.csv"}
    rows = []
    for label, path in files.items():
        data = bayescap.load(path)
        m = PTCModel(data)
        t = time.perf_counter()
        x = mcmc_start(m)[0]       # the fit's start: MAP and Laplace covariance
        t_map = time.perf_counter() - t
        X = np.tile(x, (36, 1)) + 1e-4 * np.random.default_rng(0).standard_normal((36, m.ndim))
        t = time.perf_counter()
        for _ in range(200):
            m.log_prob(X)
        t_lp = (time.perf_counter() - t) / 200
        for jobs in (1, 2):
            walls, sampl = [], []
            for rep in range(args.repeats):
                t = time.perf_counter()
                res = bayescap.fit(data, seed=rep, n_jobs=jobs)
                walls.append(time.perf_counter() - t)
                sampl.append(res.chains.wall_s)
            dg = res.diag
            rows.append((label, jobs, np.median(walls), np.median(sampl), t_map, 1e3 * t_lp, dg["converged"],
                         dg["rhat_max"], dg["ess_min"], dg["n_ensembles"], dg["n_walkers"], dg["n_steps"]))
            print(rows[-1], flush=True)
    lines = ["# Default fit timing (`python benchmarks/bench_fit.py`)", "", f"Machine: {_machine()}.", "",
             f"Python start-up + `import bayescap, arviz`: {import_s:.2f} s (not included below).", "",
             "| data | processes | fit wall (s, median of %d) | of which MAP + sampling (s) | MAP + Laplace (s) | "
             "log-prob, 36 walkers (ms) | converged | R-hat max | ESS min | ensembles × walkers × steps |" % args.repeats,
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r[0]} | {r[1]} | {r[2]:.2f} | {r[3]:.2f} | {r[4]:.2f} | {r[5]:.2f} | {r[6]} | {r[7]:.4f} | "
                     f"{r[8]:.0f} | {r[9]} × {r[10]} × {r[11]} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
