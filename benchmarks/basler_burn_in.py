"""Standard preset on the bundled Basler CCD with a given burn-in and first-round length: wall time,
steps, drift events (time-split R-hat) and the dark current's 2.5/50/97.5 % points per seed.

    python benchmarks/basler_burn_in.py 100 100     # the standard preset's own lengths
    python benchmarks/basler_burn_in.py 40 60       # a shorter burn-in

The dark current of this 14 ms series is an upper limit whose lower tail fills slowly; the
accurate reference puts its 2.5 % point at 5.7 e-/s (docs/performance.md)."""
import dataclasses
import importlib
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import bayescap

F = importlib.import_module("bayescap.fit")
CSV = Path(__file__).resolve().parents[1] / "data" / "emva1288_basler_ccd12.csv"


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    nb, ns = int(argv[0]), int(argv[1])
    seeds = [int(s) for s in argv[2:]] or [1, 2, 3, 4]
    q = dataclasses.replace(F.QUALITY_PRESETS["standard"], n_burn=nb, n_steps=ns)
    warnings.simplefilter("ignore")
    for seed in seeds:
        t = time.perf_counter()
        r = bayescap.fit(str(CSV), seed=seed, quality=q)
        dg = r.diag
        dc = np.quantile(r.draws["dark_current_e_per_s"], [0.025, 0.5, 0.975])
        print(f"seed {seed}: {time.perf_counter() - t:.2f} s, converged {dg['converged']}, {dg['n_steps']} steps "
              f"in {dg['n_rounds']} rounds, discarded {dg['burn_in_extended_steps']} "
              f"{[(e['quantity'], round(e['rhat'], 3)) for e in dg['drift_events']]}, R-hat max {dg['rhat_max']:.4f}, "
              f"ESS min {dg['ess_min']:.0f}, dark current {np.round(dc, 2)} e-/s")


if __name__ == "__main__":
    main()
