"""Time of one vectorised log-probability call (128 walkers at the model's start) for the bundled and
benchmark CSVs: the number to compare before and after a likelihood change, on the same machine
and load. Usage: ``python benchmarks/bench_logprob.py [--walkers 128] [--repeat 30]``."""
import argparse
import glob
import os
import time
from pathlib import Path

import numpy as np

from bayescap.model.ptc_model import PTCModel
from bayescap.io.ptc_csv import read_ptc_csv

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--walkers", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=30)
    a = ap.parse_args(argv)
    files = [ROOT / "data" / "emva1288_basler_ccd12.csv"] + sorted(map(Path, glob.glob(str(ROOT / "data" / "benchmark" / "*.csv"))))
    print(f"load average {os.getloadavg()[0]:.2f}; ms per log_prob call of {a.walkers} walkers (best of 3 × {a.repeat})")
    for f in files:
        m = PTCModel(read_ptc_csv(f))
        th = np.repeat(m.initial_guess()[None], a.walkers, 0)
        m.log_prob(th)
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            for _ in range(a.repeat):
                m.log_prob(th)
            best = min(best, (time.perf_counter() - t0) / a.repeat * 1e3)
        print(f"  {f.name:32s} {best:6.2f}")


if __name__ == "__main__":
    main()
