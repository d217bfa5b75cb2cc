"""Fit times of sensors whose read noise is below half a DN (the quantization regime).

    python benchmarks/quantization_regime.py      # writes benchmarks/results/quantization_regime.md

The likelihood's exact rounding terms (``bayescap.model.prediction``, ``_quantized_var``: the rounded normal's
offset, moments and, with a spatial stack, the pixel-mean offsets' wrapped normal on a grid) make
these sensors' ``log_prob`` calls several times the cost of the others'. The sensors are the
truths of the slowest ``standard`` fits of two 200-sensor SBC runs (``benchmarks/sbc.py``, seed 3
with ``--spatial-fraction 1``: #143, #196, #68, #107; seed 1: #183, #99, #35; 35-104 s there against
~1.8 s for the median sensor), simulated here with one fixed seed each (50 levels, 100 × 100 pixels, 8-frame stacks at every 5th
level where the SBC had them; no injected discrepancies), plus a 10 e⁻/DN sensor with 1 e⁻ of
read noise. For each: the time of one ``log_prob`` call of 40 draws near the start (half an
ensemble, the size of emcee's calls in ``standard``), and the wall time of ``bayescap.fit`` with
``quality="standard"`` and ``"fast"`` (seed 1, the machine's default workers; imports excluded by a
first fit of the Basler CSV).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "quantization_regime.md"

#: (label, SensorTruth keywords, spatial stack?) — the SBC's truths, rounded to 4 digits
SENSORS = [
    (
        "sbc-s143",
        dict(
            conversion_gain_e_per_dn=6.3283,
            read_noise_e=1.426,
            full_well_e=12905.68,
            dark_current_e_per_s=2.5509,
            quantum_efficiency=0.4236,
            prnu_frac=0.005,
            dsnu_e=2.0677,
            full_well_spread_frac=0.0167,
            adc_bits=12,
        ),
        True,
    ),
    (
        "sbc-s196",
        dict(
            conversion_gain_e_per_dn=5.5592,
            read_noise_e=1.1155,
            full_well_e=6905.64,
            dark_current_e_per_s=52.1111,
            quantum_efficiency=0.5887,
            prnu_frac=0.0071,
            dsnu_e=1.0472,
            full_well_spread_frac=0.0022,
            adc_bits=11,
        ),
        True,
    ),
    (
        "sbc-s68",
        dict(
            conversion_gain_e_per_dn=4.6508,
            read_noise_e=1.0464,
            full_well_e=13638.71,
            dark_current_e_per_s=82.6377,
            quantum_efficiency=0.4682,
            prnu_frac=0.0052,
            dsnu_e=1.1698,
            full_well_spread_frac=0.0002,
            adc_bits=12,
        ),
        True,
    ),
    (
        "sbc-s107",
        dict(
            conversion_gain_e_per_dn=6.4724,
            read_noise_e=2.819,
            full_well_e=20212.99,
            dark_current_e_per_s=190.1152,
            quantum_efficiency=0.4826,
            prnu_frac=0.0069,
            dsnu_e=2.6976,
            full_well_spread_frac=0.0054,
            adc_bits=13,
        ),
        True,
    ),
    (
        "sbc-183",
        dict(
            conversion_gain_e_per_dn=7.2747,
            read_noise_e=2.3983,
            full_well_e=44373.29,
            dark_current_e_per_s=24.7456,
            quantum_efficiency=0.6642,
            prnu_frac=0.0058,
            dsnu_e=1.0567,
            full_well_spread_frac=0.0029,
            adc_bits=12,
        ),
        True,
    ),
    (
        "sbc-99",
        dict(
            conversion_gain_e_per_dn=6.4084,
            read_noise_e=1.5002,
            full_well_e=34850.94,
            dark_current_e_per_s=6.1928,
            quantum_efficiency=0.5066,
            prnu_frac=0.0036,
            dsnu_e=0.0,
            full_well_spread_frac=0.0022,
            adc_bits=13,
        ),
        False,
    ),
    (
        "sbc-35",
        dict(
            conversion_gain_e_per_dn=3.8232,
            read_noise_e=1.0917,
            full_well_e=3853.15,
            dark_current_e_per_s=3.849,
            quantum_efficiency=0.3965,
            prnu_frac=0.0,
            dsnu_e=0.0,
            full_well_spread_frac=0.0118,
            adc_bits=10,
        ),
        False,
    ),
    (
        "k10-rn1",
        dict(
            conversion_gain_e_per_dn=10.0,
            read_noise_e=1.0,
            full_well_e=20000.0,
            dark_current_e_per_s=5.0,
            prnu_frac=0.005,
            dsnu_e=1.0,
            adc_bits=12,
        ),
        False,
    ),
]


def _time_call(m, n=40, repeat=10):
    rng = np.random.default_rng(0)
    th = m.initial_guess()[None] + 0.01 * rng.standard_normal((n, m.ndim))
    m.log_prob(th)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(repeat):
            m.log_prob(th)
        best = min(best, (time.perf_counter() - t0) / repeat)
    return best * 1e3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.parse_args(argv)
    warnings.simplefilter("ignore")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _machine import describe_machine, emit

    import bayescap
    from bayescap.model.ptc_model import PTCModel
    from bayescap.simulate import SensorTruth, simulate_ptc

    bayescap.fit(bayescap.load(str(ROOT / "data" / "emva1288_basler_ccd12.csv")), seed=1)  # imports, pools
    lines = [
        "# Quantization-regime fit times",
        "",
        f"Generated by `python benchmarks/quantization_regime.py` (module docstring: sensors and method); "
        f"machine: {describe_machine()}; load average before the run {os.getloadavg()[0]:.2f}.",
        "",
        "| sensor | read noise (DN) | spatial stack | log_prob, 40 draws (ms) | standard (s) | rounds | "
        "converged | fast (s) | fast accepted |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for i, (label, kw, spatial) in enumerate(SENSORS):
        truth = SensorTruth(**kw)
        data = simulate_ptc(truth, seed=1000 + i, spatial_frames=8 if spatial else 0, spatial_every=5 if spatial else 0)
        ms = _time_call(PTCModel(data))
        t0 = time.perf_counter()
        r = bayescap.fit(data, seed=1, quality="standard")
        t_std = time.perf_counter() - t0
        t0 = time.perf_counter()
        f = bayescap.fit(data, seed=1, quality="fast")
        t_fast = time.perf_counter() - t0
        row = (
            f"| {label} | {truth.read_noise_e / truth.conversion_gain_e_per_dn:.3f} | {'yes' if spatial else 'no'} | "
            f"{ms:.2f} | {t_std:.2f} | {r.diag.get('n_rounds')} | {r.diag.get('converged')} | {t_fast:.2f} | "
            f"{f.diag.get('method') == 'laplace-is'} |"
        )
        print(row, flush=True)
        lines.append(row)
    lines += ["", "`fast accepted` False: the fast path rejected itself and the MCMC fallback ran (its time included)."]
    emit(lines, OUT)


if __name__ == "__main__":
    main()
