"""Where the fast path's time goes: log_prob calls, points evaluated and wall time of
``fast.fast_posterior`` on the bundled Basler CCD and 8 simulated Gpixel GSPRINT4521 ROIs.

    python benchmarks/fast_path_evaluations.py [--set gpixel|speed_accuracy] [--out FILE]

Uses only ``PTCModel.log_prob`` and ``fast_posterior``, so the same script measures an older commit
(``git worktree add --detach /tmp/old <commit>; PYTHONPATH=/tmp/old python benchmarks/...``).
Prints a Markdown table: per sensor the wall time (best of 2), log_prob calls, points, the largest
batch sizes by points, k̂ and whether the retry ran."""
import argparse
import collections
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None)
    ap.add_argument("--set", choices=("gpixel", "speed_accuracy"), default="gpixel",
                    help="the Basler and 8 Gpixel ROIs, or speed_accuracy.sensor_set(10) (the README's 11)")
    a = ap.parse_args(argv)
    import bayescap
    from _machine import describe_machine, emit
    from bayescap.inference import fast
    from bayescap.batch import gpixel_sensors
    from bayescap.model.ptc_model import PTCModel
    from bayescap.io.ptc_csv import read_ptc_csv

    if a.set == "speed_accuracy":
        from speed_accuracy import sensor_set
        datas = [(name, d) for name, d, _ in sensor_set(10)]
    else:
        datas = [("Basler CCD (real)", read_ptc_csv(ROOT / "data" / "emva1288_basler_ccd12.csv"))]
        datas += [(f"Gpixel ROI sim {i} (seed 0)", d) for i, d in enumerate(gpixel_sensors(n_max=8, seed=0)[0])]
    hist = collections.Counter()
    orig = PTCModel.log_prob

    def counted(self, X):
        X = np.atleast_2d(X)
        hist[len(X)] += 1
        return orig(self, X)

    load = os.getloadavg()
    rows, total = [], 0.0
    for name, d in datas:
        m = PTCModel(d)
        walls = []
        for _ in range(2):
            hist.clear()
            PTCModel.log_prob = counted
            t = time.perf_counter()
            _, dg = fast.fast_posterior(m, seed=1)
            walls.append(time.perf_counter() - t)
            PTCModel.log_prob = orig
        w = min(walls)
        total += w
        top = sorted(hist.items(), key=lambda kv: -kv[0] * kv[1])[:3]
        rows.append(f"| {name} | {w:.3f} | {sum(hist.values())} | {sum(k * v for k, v in hist.items())} | "
                    + ", ".join(f"{v}×{k}" for k, v in top)
                    + f" | {dg['khat']:.2f} {'✓' if dg['accepted'] else '✗'} | {dg.get('retried_with_restarts')} |")
    L = [f"bayescap {getattr(bayescap, '__version__', '?')} from {Path(bayescap.__file__).parent}; "
         f"{describe_machine()}; load before {load[0]:.2f}, after {os.getloadavg()[0]:.2f}.", "",
         "| sensor | wall s (best of 2) | log_prob calls | points | largest batches (calls×points) | k̂ | retried |",
         "|---|---|---|---|---|---|---|", *rows, f"| **all** | **{total:.2f}** | | | | | |"]
    emit(L, a.out)


if __name__ == "__main__":
    main()
