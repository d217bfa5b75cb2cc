"""Why bayescap's conversion gain on the Basler reference set differs a little from emva1288's.

    python benchmarks/basler_vs_emva1288.py

emva1288 (1.0.2) fits the photon-transfer slope K_DN/e = Δσ²_y/Δμ_y by an *unweighted* least-squares
line through the origin over its own choice of rows (from the first step up to 70 % of the mean at
the variance peak, EMVA 1288 Release 3/4). bayescap weights every row by the sampling distribution of its variance (relative
error sqrt(2/ν + f²)), i.e. roughly by 1/σ², and uses every row including the roll-off. This script
recomputes the slope both ways on the same table, and the bayescap posterior, so the difference
can be attributed.
"""
import json
import warnings
from pathlib import Path

import numpy as np

import bayescap

warnings.simplefilter("ignore")
ROOT = Path(__file__).resolve().parents[1]


def main(seed=1):
    d = bayescap.load(ROOT / "data" / "emva1288_basler_ccd12.csv")
    full = d.n_pixels == d.n_pixels.max()  # the 50 full-frame rows
    mu = (d.mean_dn - d.dark_mean_dn)[full]
    dv = (d.temporal_var_dn2 - d.dark_temporal_var_dn2)[full]
    sat_mean = mu[np.argmax(d.temporal_var_dn2[full])]
    rows = mu <= 0.7 * sat_mean
    x, y = mu[rows], dv[rows]
    slope_unw = np.sum(x * y) / np.sum(x * x)                # through the origin, unweighted
    w = 1.0 / d.temporal_var_dn2[full][rows] ** 2            # 1/sd² weights: sd(var) ∝ var
    slope_w = np.sum(w * x * y) / np.sum(w * x * x)
    X = np.vstack([x, np.ones_like(x)]).T
    slope_off = np.linalg.lstsq(X, y, rcond=None)[0][0]      # unweighted with a free offset
    ref = json.loads((ROOT / "data" / "emva1288_refset001" / "reference_results_emva1288_v1.0.2.json").read_text())
    res = bayescap.fit(d, seed=seed)
    k = res.draws["conversion_gain_e_per_dn"]
    out = {
        "emva1288 1.0.2 (reported)": 1 / ref["K"]["value"],
        "unweighted LSQ through 0, rows <= 70 % of saturation (emva1288's recipe)": 1 / slope_unw,
        "unweighted LSQ with a free offset, same rows": 1 / slope_off,
        "1/sd^2-weighted LSQ through the origin, same rows": 1 / slope_w,
        "bayescap posterior median (all rows, Gamma likelihood)": float(np.median(k)),
        "bayescap 95 % interval": [float(x) for x in np.quantile(k, [0.025, 0.975])],
        "bayescap variance discrepancy f (median)": float(np.median(res.draws["variance_discrepancy"])),
        "rows used by the 70 % rule": int(rows.sum()),
    }
    for key, val in out.items():
        print(f"{key:<68} {val}")
    return out


if __name__ == "__main__":
    main()
