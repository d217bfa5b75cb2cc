"""The BFGS stall rule of ``fit._bfgs`` (``BFGS_STALL_EVALS``, ``BFGS_STALL_NATS``) replayed on full
BFGS runs: for 29 sensors (20 simulated Gpixel ROIs seed 0, the Basler, the five benchmark and three
bundled simulated CSVs) × 2 starts (``find_map`` from the initial guess, ``find_map_scaled`` from the
first extra start), record every objective value of an unstopped run, then for each window N and
tolerance report the evaluations the rule would have spent and how far its best value is from the
full run's.

    python benchmarks/bfgs_stall.py
"""
import glob
import importlib
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def traces():
    from scipy import optimize

    from bayescap.batch import gpixel_sensors
    from bayescap.model.ptc_model import PTCModel
    from bayescap.io.ptc_csv import read_ptc_csv

    fm = importlib.import_module("bayescap.fit")
    fm.BFGS_STALL_EVALS = 10**9          # full runs
    paths = ([ROOT / "data" / "emva1288_basler_ccd12.csv"]
             + sorted(glob.glob(str(ROOT / "data" / "benchmark" / "*.csv")))
             + sorted(glob.glob(str(ROOT / "data" / "simulated" / "*.csv"))))
    datas = gpixel_sensors(n_max=20, seed=0)[0] + [read_ptc_csv(p) for p in paths]
    orig = optimize.minimize
    out = []
    for d in datas:
        m = PTCModel(d)
        for which in ("find_map", "scaled"):
            tr = []

            def recording(fun, x0, **kw):
                def f2(x):
                    v = fun(x)
                    tr.append(v[0])
                    return v
                return orig(f2, x0, **kw)

            fm.optimize.minimize = recording
            try:
                if which == "find_map":
                    fm.find_map(m, n_restarts=0)
                else:
                    fm.find_map_scaled(m, fm._map_starts(m)[0])
            finally:
                fm.optimize.minimize = orig
            out.append(np.array(tr))
    return out


def replay(t, n, tol):
    best, since = np.inf, 0
    for i, v in enumerate(t):
        if v < best - tol:
            best, since = v, 0
        else:
            best, since = min(best, v), since + 1
            if since >= n:
                return i + 1
    return len(t)


def main():
    tr = traces()
    print(f"{len(tr)} BFGS runs, {sum(map(len, tr))} evaluations unstopped\n")
    print("| window N | tolerance (nats) | evaluations | max loss vs full run (nats) | runs losing > 0.01 |")
    print("|---|---|---|---|---|")
    for n in (5, 10, 13, 14, 15, 20, 25):
        for tol in (1e-3,):
            stops = [replay(t, n, tol) for t in tr]
            gaps = np.array([np.min(t[:s]) - np.min(t) for t, s in zip(tr, stops)])
            print(f"| {n} | {tol:g} | {sum(stops)} | {gaps.max():.4f} | {(gaps > 0.01).sum()} |")


if __name__ == "__main__":
    sys.exit(main())
