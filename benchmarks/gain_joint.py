"""Joint fit of simulated gain series against the truth and against separate per-gain fits.

    python benchmarks/gain_joint.py      # writes benchmarks/results/gain_joint.md

Pre-registered design: eight series of one simulated 1.75 µm sensor (the M2_1.75um stand-in's
truth: K = 2.1719 e⁻/DN at gain 1, QE 0.3991, PRNU 1.5 %, DSNU 3.7 e⁻, full well 8 500 e⁻) at
analog gains 1, 2, 4 with K ∝ 1/gain and read noise sqrt(3.4² + (2 DN · K)²) e⁻; four with a
12-bit ADC (it clips before the well above gain 1) and four with 14 bits, seeds 101-108; 25 levels,
80 × 80 pixels, 16-frame stacks every 6th level. Each is fitted jointly
(:func:`bayescap.studies.gain_joint.fit_gain_series_jointly`, ``sampler="auto"``, seed 0; series
101 and 105 also with ``sampler="mcmc"``, the fallback, 16000 steps) and
separately (:func:`bayescap.studies.gain_series.fit_gain_series`, quality fast). Reported: the
sampler used and its check, whether each truth is inside the joint 95 % interval (shared: QE, PRNU,
DSNU; per gain: K, read noise, clip charge), and the width of the shared parameters' joint
interval against the narrowest separate one. The dark current (0.44 e⁻/s over ≤ 20 ms exposures)
is not identified by these series and is left out of the coverage count.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "gain_joint.md"
SERIES = [(12, 101), (12, 102), (12, 103), (12, 104), (14, 105), (14, 106), (14, 107), (14, 108)]
#: series also fitted with sampler="mcmc" (the fallback when importance sampling fails its check)
MCMC_SERIES = {(12, 101), (14, 105)}
GAINS = [1.0, 2.0, 4.0]


def main() -> int:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import describe_machine, emit

    from bayescap.simulate import SensorTruth
    from bayescap.studies.gain_joint import fit_gain_series_jointly
    from bayescap.studies.gain_series import fit_gain_series, simulate_gain_series

    warnings.simplefilter("ignore")
    rows, inside, total = [], 0, 0
    t_all = time.perf_counter()
    jobs = [(b, s, "auto") for b, s in SERIES] + [(b, s, "mcmc") for b, s in SERIES if (b, s) in MCMC_SERIES]
    for bits, seed, how in jobs:
        truth = SensorTruth(
            conversion_gain_e_per_dn=2.1719,
            read_noise_e=5.56,
            full_well_e=8500.0,
            dark_current_e_per_s=0.438,
            quantum_efficiency=0.3991,
            prnu_frac=0.015,
            dsnu_e=3.7,
            full_well_spread_frac=0.005,
            adc_bits=bits,
            black_level_dn=64.0,
        )
        md = {"pixel_pitch_um": 1.75, "adc_bits": bits, "black_level_dn": 64.0}
        datas, truths = simulate_gain_series(
            truth,
            GAINS,
            read_noise_pre_e=3.4,
            read_noise_post_dn=2.0,
            seed=seed,
            metadata=md,
            n_levels=25,
            shape=(80, 80),
            spatial_frames=16,
            spatial_every=6,
        )
        t0 = time.perf_counter()
        j = fit_gain_series_jointly(datas, GAINS, seed=0, sampler=how)
        t_joint = time.perf_counter() - t0
        sep = fit_gain_series(datas, seed=0)
        checks = []
        shared_true = {
            "quantum_efficiency": truth.quantum_efficiency,
            "prnu_percent": 100 * truth.prnu_frac,
            "dsnu_e": truth.dsnu_e,
        }
        widths = []
        for k, v in shared_true.items():
            lo, hi = np.quantile(j.draws[0][k], [0.025, 0.975])
            checks.append(lo <= v <= hi)
            w_sep = min(np.subtract(*np.quantile(r.draws[k], [0.975, 0.025])) for r in sep.results)
            widths.append(f"{k} {(hi - lo) / w_sep:.2f}")
        for d, t in zip(j.draws, truths):
            for k, v in (
                ("conversion_gain_e_per_dn", t.conversion_gain_e_per_dn),
                ("read_noise_e", t.read_noise_e),
                ("full_well_e", t.clip_charge_e),
            ):
                lo, hi = np.quantile(d[k], [0.025, 0.975])
                checks.append(lo <= v <= hi)
        inside += sum(checks)
        total += len(checks)
        mc = j.mcmc
        rows.append(
            f"| {bits} | {seed} | {how} → {j.sampler} | {j.converged} | {j.khat:.2f} | "
            + (f"{mc['steps_per_tau']:.0f} | {mc['acceptance']:.2f} | " if mc else "– | – | ")
            + f"{sum(checks)}/{len(checks)} | {', '.join(widths)} | {t_joint:.0f} s |"
        )
        print(rows[-1], flush=True)
    text = (
        f"""# Joint fit of gain series (`python benchmarks/run.py gain_joint`)

{describe_machine()} (measured under load from other jobs); total {time.perf_counter() - t_all:.0f} s. Design: `benchmarks/gain_joint.py` docstring.

| ADC bits | seed | sampler asked → used | converged | Pareto k̂ (IS) | MCMC kept steps / τ | acceptance | truths inside 95 % | joint / narrowest separate 95 % width | joint fit time |
| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |
"""
        + "\n".join(rows)
        + f"""

Truths inside the joint 95 % intervals: {inside}/{total} (3 shared + 3 × 3 per-gain parameters per
series and sampler run; expected about 95 % if the intervals are calibrated; the checks within a
series are not independent). A joint / separate width near 1/√3 = 0.58 is what three gains of
similar precision should give.
"""
    )
    emit(text.splitlines(), OUT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
