"""How much a likelihood change moves log p: log_prob at 4 000 perturbed starts (sd 0.03 in every
coordinate, seed 0) on the Basler, the five benchmark and three bundled simulated CSVs and six
simulated Gpixel ROIs, saved to a file; a second run with ``--against`` compares.

    PYTHONPATH=/path/to/old/worktree python benchmarks/logprob_shift.py --save /tmp/old.npy
    python benchmarks/logprob_shift.py --against /tmp/old.npy
"""
import argparse
import glob
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def values():
    from bayescap.batch import gpixel_sensors
    from bayescap.model.ptc_model import PTCModel
    from bayescap.io.ptc_csv import read_ptc_csv

    paths = ([ROOT / "data" / "emva1288_basler_ccd12.csv"]
             + sorted(glob.glob(str(ROOT / "data" / "benchmark" / "*.csv")))
             + sorted(glob.glob(str(ROOT / "data" / "simulated" / "*.csv"))))
    datas = [read_ptc_csv(p) for p in paths] + gpixel_sensors(n_max=6)[0]
    out = []
    for d in datas:
        m = PTCModel(d)
        x0 = m.initial_guess()
        X = x0 + 3e-2 * np.random.default_rng(0).standard_normal((4000, m.ndim))
        out.append(m.log_prob(X))
    return np.concatenate(out)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--save", type=Path)
    ap.add_argument("--against", type=Path)
    a = ap.parse_args(argv)
    v = values()
    if a.save:
        np.save(a.save, v)
    if a.against:
        old = np.load(a.against)
        f = np.isfinite(old)
        d = np.abs(v[f] - old[f])
        print(f"{f.sum()} finite points (same support: {bool(np.array_equal(np.isfinite(v), f))}); "
              f"|Δ log p| median {np.median(d):.2e}, 99 % {np.quantile(d, 0.99):.2e}, max {d.max():.2e} nats")


if __name__ == "__main__":
    main()
