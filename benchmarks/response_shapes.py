"""Response shapes and brighter-fatter on frame-level simulations: coverage of K, the dark noise, η
and the full well, the agreement of K from all rows with K from the rows below 70 % of the largest
signal, the rows called outliers, the response/brighter-fatter reading and the wall time, with and
without photon counts.

    python benchmarks/response_shapes.py [--quick] [--quality standard]

The sensors are simulated frame by frame by the small simulator of ``tests/test_response_shapes.py``
(Poisson charge, a local response function, Gaussian read noise, rounding, clipping; not the model's
simulator): a 12-bit camera with a soft knee (K 10 e⁻/DN, η 0.5, dark noise 30 e⁻, 400² pixels), an
8-bit S-shaped camera (K 50, η 0.6, read 15 e⁻) and a brighter-fatter CCD (K 1.5 e⁻/ADU, read 5 e⁻,
a₀₀ = −2e-6 per e⁻, linear response). One seed each (``--seeds N`` for more). Writes
``benchmarks/results/response_shapes.md``.
"""

import argparse
import dataclasses
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _machine import describe_machine, emit

import bayescap

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_response_shapes import WELL_A, _case_bf, _case_knee, _case_s_shape  # noqa: E402

warnings.simplefilter("ignore")
OUT = ROOT / "benchmarks" / "results" / "response_shapes.md"

CASES = {
    "knee (12-bit)": (
        lambda seed: _case_knee(seed, shape=(400, 400)),
        {"conversion_gain_e_per_dn": 10.0, "dark_noise_e": 30.0, "quantum_efficiency": 0.5, "full_well_e": WELL_A},
    ),
    "S shape (8-bit)": (
        _case_s_shape,
        {"conversion_gain_e_per_dn": 50.0, "dark_noise_e": 15.0, "quantum_efficiency": 0.6, "full_well_e": 12000.0},
    ),
    "brighter-fatter CCD": (
        _case_bf,
        {"conversion_gain_e_per_dn": 1.5, "dark_noise_e": 5.0, "quantum_efficiency": 0.8},
    ),
}
SHORT = {"conversion_gain_e_per_dn": "K", "dark_noise_e": "σ_d", "quantum_efficiency": "η", "full_well_e": "FW"}


def _fit(d, quality, truth):
    t0 = time.perf_counter()
    r = bayescap.fit(d, quality=quality, seed=1)
    wall = time.perf_counter() - t0
    out = r.to_dict()
    P = out["parameters"]
    cells = {}
    for name, v in truth.items():
        e = P.get(name)
        if e is None or e.get("median") is None:
            cells[name] = ("limit", None)
            continue
        lo, hi = e["ci95"]
        cells[name] = (f"{e['median']:.4g} [{lo:.4g}, {hi:.4g}]", bool(lo <= v <= hi))
    return {
        "cells": cells,
        "k_ci": P["conversion_gain_e_per_dn"]["ci95"],
        "outliers": len(out["outliers"]),
        "reading": out["response_model"]["reading"],
        "converged": bool(out["diagnostics"].get("converged", True)),
        "wall": wall,
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="with photon counts only")
    ap.add_argument("--quality", default="standard")
    ap.add_argument("--seeds", type=int, default=1)
    a = ap.parse_args()
    L = [
        "# Response shapes and brighter-fatter (frame-level simulations)",
        "",
        f"`python benchmarks/response_shapes.py --quality {a.quality}"
        + (" --quick" if a.quick else "")
        + (f" --seeds {a.seeds}" if a.seeds != 1 else "")
        + "`. Machine: "
        + describe_machine()
        + ".",
        "",
        "Per sensor: the 95 % intervals (✓ truth inside, ✗ outside) from all rows; whether K from all rows and",
        "K from the rows below 70 % of the largest signal overlap; rows called outliers (all rows / below 70 %);",
        "the reading of `response_model`; wall time of each fit (seconds).",
        "",
        "| sensor | photons | seed | K | σ_d | η | FW | K all ∩ K<70 % | outliers | converged | wall s | reading |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    walls = []
    for name, (make, truth) in CASES.items():
        for photons in (True,) if a.quick else (True, False):
            for seed in range(1, a.seeds + 1):
                d = make(seed)
                tr = dict(truth)
                if not photons:
                    d = dataclasses.replace(d, photons_per_pixel=None)
                    tr.pop("quantum_efficiency")
                s = d.mean_dn - d.dark_mean_dn
                full = _fit(d, a.quality, tr)
                low = _fit(
                    d.select(s < 0.7 * s.max()), a.quality, {"conversion_gain_e_per_dn": tr["conversion_gain_e_per_dn"]}
                )
                (k1, k2), (l1, l2) = full["k_ci"], low["k_ci"]
                walls += [full["wall"], low["wall"]]
                col = []
                for q in ("conversion_gain_e_per_dn", "dark_noise_e", "quantum_efficiency", "full_well_e"):
                    c = full["cells"].get(q)
                    col.append("–" if c is None else (c[0] if c[1] is None else f"{c[0]} {'✓' if c[1] else '✗'}"))
                L.append(
                    f"| {name} | {'yes' if photons else 'no'} | {seed} | "
                    + " | ".join(col)
                    + f" | {'yes' if (k1 <= l2 and l1 <= k2) else 'NO'} | {full['outliers']} / {low['outliers']} | "
                    f"{'yes' if full['converged'] and low['converged'] else 'NO'} | {full['wall']:.1f} / {low['wall']:.1f} | "
                    f"{full['reading']} |"
                )
    L += ["", f"Median wall time per fit: {np.median(walls):.1f} s over {len(walls)} fits."]
    emit(L, OUT)


if __name__ == "__main__":
    main()
