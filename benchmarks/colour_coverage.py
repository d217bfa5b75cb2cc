"""Colour sensitivity and per-channel QE of simulated Bayer cameras against their truth.

    python benchmarks/colour_coverage.py [--quick]   # writes benchmarks/results/colour_coverage.md

Pre-registered design: 128 cameras (seeds 0-127; ``--cameras N``; ``--quick``: 6; the first 32 were
the design before, kept as they were) from :mod:`bayescap.validation.cfasim`, frame by frame, with
K ~ U(1, 4) e⁻/DN, read noise ~ U(1.5, 6) e⁻, peak QE ~ U(0.35, 0.75), PRNU per channel
~ U(0.3, 1.5) %, a 12-bit ADC (black 64 DN), 14 log-spaced exposures from 0.3 % of the most
sensitive channel's clip to 115 % of the least sensitive one's, 160 × 160 mosaics (6400 pixels per
channel); sensitivities alternate between colour-science's Nikon 5100 and Sigma SDMerill, the
illuminant between D65 and A. 128 cameras: a 95 % coverage rate then has a binomial sd of 1.9 points
(32 cameras: 3.9), and each rate is given with its Clopper-Pearson 95 % interval.

Each of R, Gr, Gb, B is fitted separately (``bayescap.fit``, quality ``fast``, seed 0). The CCM is
the spectral one for the camera's sensitivities (ColorChecker N Ohta under the illuminant → linear
sRGB); CS (cube domain, 8-bit floor) per draw from the four channels' noise draws paired by index
(1000 draws). Checked: the truth inside the 95 % interval of K (per channel), QE (per channel) and
CS. The truth CS is the same function at the true coefficients, with the same CCM. Also reported:
the CS interval width, and CS with the CCM's bootstrap draws (the CCM taken as uncertain) and with
clipping after M (the output volume fixed), where the CCM's uncertainty enters.

The joint fit, what ``bayescap colour`` reports (``fit_cfa``, quality ``fast``, seed 0: its own
separate fits with the channels' child seeds, the K check, the consensus of the shared
coordinates), is checked on the same cameras: the truth inside the 95 % interval of the shared K,
the read noise, each channel's QE and PRNU and of CS (as above, on 1000 evenly thinned joint draws
at the truth's exposure time, CCM exact, clipped and not, evaluated as ``colour_summary`` does: exactly on
128 pilot draws and by the checked linear map of :mod:`bayescap.colour.cs_emulator` on all). The channels share one K here, so the K
check should pass on about 99 % of the cameras (its threshold p ≥ 0.01).

The truth is the population the camera is drawn from (its ``prnu_frac``, ``channel_qe``): what the
model's PRNU and QE estimate, the pixels' pattern being one sample of it (the model's ROI latents).
Why a CS interval misses is shown per miss: the truth's distance z from the median in units of the
median's distance to the interval's end on the truth's side (|z| > 1: outside), and what moves CS
from the posterior medians to the truth, per input (K, read noise, PRNU, clip), in half-widths of
the interval. A diagnostic, not a target: CS at the drawn pattern's own PRNU
(``truth["realized"]``), which the data pin more tightly than the population's.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "colour_coverage.md"
N_DRAWS = 1000


def _camera(seed):
    from bayescap.validation.cfasim import CFACamera

    rng = np.random.default_rng(10_000 + seed)
    return CFACamera(
        k_e_per_dn=float(rng.uniform(1.0, 4.0)),
        read_noise_e=float(rng.uniform(1.5, 6.0)),
        full_well_e=20_000.0,
        peak_qe=float(rng.uniform(0.35, 0.75)),
        prnu_frac=tuple(float(x) for x in rng.uniform(0.003, 0.015, 4)),
        sensitivities=("Nikon 5100 (NPL)", "Sigma SDMerill (NPL)")[seed % 2],
        illuminant=("D65", "A")[(seed // 2) % 2],
    )


def _inside(draws, truth):
    lo, hi = np.quantile(draws, [0.025, 0.975])
    return bool(lo <= truth <= hi), float(lo), float(hi)


def _z(x, lo, med, hi) -> float:
    """x's distance from the median in units of the median's distance to the interval's end on x's
    side: |z| > 1 exactly when x is outside [lo, hi]."""
    return float((x - med) / ((hi - med) if x >= med else (med - lo)))


def _rate(a: int, b: int) -> str:
    """a/b, the rate, its Clopper-Pearson 95 % interval and P(X ≤ a) for a true rate of 95 %."""
    from scipy import stats

    lo = stats.beta.ppf(0.025, a, b - a + 1) if a > 0 else 0.0
    hi = stats.beta.ppf(0.975, a + 1, b - a) if a < b else 1.0
    return f"{a}/{b} = {a / b:.1%} (95 % CI {lo:.1%}-{hi:.1%}; P(≤ {a} | 95 %) = {stats.binom.cdf(a, b, 0.95):.2f})"


def _drivers(cs_fn, v_med, clip_med, v_true, clip_true, half_width) -> str:
    """What moves CS from the posterior medians of its inputs to the truth, one input at a time,
    in half-widths of the CS interval: K (c1), read noise (c0), PRNU (c2) of every channel, clip."""
    base = cs_fn(v_med, clip_med)
    out = []
    for name, col in (("K", 1), ("read", 0), ("PRNU", 2)):
        v = v_med.copy()
        v[:, col] = v_true[:, col]
        out.append(f"{name} {(cs_fn(v, clip_med) - base) / half_width:+.2f}")
    out.append(f"clip {(cs_fn(v_med, clip_true) - base) / half_width:+.2f}")
    return ", ".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="6 cameras instead of 128")
    ap.add_argument("--cameras", type=int, default=128, help="cameras (seeds 0 to N-1; default 128)")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import describe_machine, emit

    import bayescap
    from bayescap.colour.ccm import ccm_from_spectral
    from bayescap.colour.cfa_fit import fit_cfa
    from bayescap.colour.cs_emulator import colour_sensitivity_emulated
    from bayescap.colour.scores import var_coeffs_from_fit
    from bayescap.colour.sensitivity import colour_sensitivity_bits
    from bayescap.io.ptc_csv import read_ptc_csv, write_ptc_csv
    from bayescap.validation.cfasim import CHANNELS, simulate_cfa_ptc

    seeds = range(6 if args.quick else args.cameras)
    t_all = time.perf_counter()
    rows, counts = [], {"K": [0, 0], "QE": [0, 0], "CS": [0, 0], "CS_clip": [0, 0]}
    joint = {
        "K": [0, 0],
        "read": [0, 0],
        "QE": [0, 0],
        "PRNU": [0, 0],
        "CS": [0, 0],
        "CS_clip": [0, 0],
        "CS at the drawn pattern's PRNU": [0, 0],
        "K check passed": [0, 0],
    }
    ranks, j_ranks, j_z, misses = [], [], [], []
    widths, widths_unc, widths_clip, t_cs = [], [], [], []
    emul, emul_used = [], []  # the joint CS's linear map: its leave-one-out residual / CS sd, whether used
    ccms = {}
    for seed in seeds:
        cam = _camera(seed)
        sim = simulate_cfa_ptc(seed, cam)
        truth = sim["truth"]
        coeffs, clips, qe_in, k_in, notes = [], [], [], [], []
        tables = {}
        with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for c in CHANNELS:
                path = Path(tmp) / f"{c}.csv"
                write_ptc_csv(sim[c]["rows"], path, metadata=sim[c]["metadata"])
                tables[c] = read_ptc_csv(path)
                r = bayescap.fit(path, seed=0, quality="fast")
                if not r.diag.get("converged"):
                    notes.append(f"{c} not converged")
                idx = r.thin_index(N_DRAWS)
                co, clip, lower = var_coeffs_from_fit(r, idx)
                if lower:
                    notes.append(f"{c} clip a lower bound")
                coeffs.append(co[:N_DRAWS])
                clips.append(clip[:N_DRAWS])
                qe_in.append(_inside(r.draws["quantum_efficiency"], truth["quantum_efficiency"][c])[0])
                k_in.append(_inside(r.draws["conversion_gain_e_per_dn"], truth["k_e_per_dn"])[0])
        n = min(len(x) for x in coeffs)
        v = np.stack([x[:n] for x in coeffs], axis=1)  # (n, 4, 3)
        clip = np.stack([x[:n] for x in clips], axis=1)
        key = (cam.sensitivities, cam.illuminant)
        if key not in ccms:
            ccms[key] = ccm_from_spectral(cam.sensitivities, illuminant=cam.illuminant, n_draws=N_DRAWS, seed=0)
        ccm = ccms[key]
        t0 = time.perf_counter()
        cs = colour_sensitivity_bits(v, clip, ccm.matrix, ccm.wb_gains)
        t_cs.append((time.perf_counter() - t0) / n * 1000)
        cs_true = float(
            colour_sensitivity_bits(truth["var_coeffs_dn2"], truth["clip_dn"][None], ccm.matrix, ccm.wb_gains)[0]
        )
        cs_ok, lo, hi = _inside(cs, cs_true)
        ranks.append(float(np.mean(cs < cs_true)))
        cs_clip_exact = colour_sensitivity_bits(v, clip, ccm.matrix, ccm.wb_gains, clip_output=True)
        cs_clip_true = colour_sensitivity_bits(
            truth["var_coeffs_dn2"], truth["clip_dn"][None], ccm.matrix, ccm.wb_gains, clip_output=True
        )[0]
        clip_ok = _inside(cs_clip_exact, cs_clip_true)[0]
        cs_unc = colour_sensitivity_bits(v, clip, ccm.as_draws(n), ccm.wb_gains)
        cs_clip = colour_sensitivity_bits(v, clip, ccm.as_draws(n), ccm.wb_gains, clip_output=True)
        widths.append(hi - lo)
        widths_unc.append(float(np.ptp(np.quantile(cs_unc, [0.025, 0.975]))))
        widths_clip.append(float(np.ptp(np.quantile(cs_clip, [0.025, 0.975]))))
        for name, oks in (("K", k_in), ("QE", qe_in), ("CS", [cs_ok]), ("CS_clip", [clip_ok])):
            counts[name][0] += sum(oks)
            counts[name][1] += len(oks)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            jf = fit_cfa(tables, seed=0, quality="fast")
        keep = np.linspace(0, jf.n_draws - 1, N_DRAWS).round().astype(int)
        t_exp = float(np.median(tables["Gr"].exposure_time_s))  # every row's, the truth's exposure time
        jv, jclip = jf.var_coeffs_dn2(t_exp)[keep], jf.clip_signal_dn()[keep]
        jd = jf.draws
        read_name = "read_noise_e" if "read_noise_e" in jd["R"] else "dark_noise_e"
        # as colour_summary evaluates it: the quadrature on 128 pilot draws and the checked linear map
        j_em = colour_sensitivity_emulated(jv, jclip, ccm.matrix, ccm.wb_gains)
        j_em_clip = colour_sensitivity_emulated(jv, jclip, ccm.matrix, ccm.wb_gains, clip_output=True)
        j_cs = j_em.bits
        for e in (j_em, j_em_clip):
            emul.append(e.choices["emulator"]["loo_resid_frac_of_sd"] if e.choices["emulator"] else None)
            emul_used.append(e.choices["evaluation"].startswith("the quadrature on 128"))
        real_v = truth["var_coeffs_dn2"].copy()
        real_v[:, 2] = np.array([truth["realized"]["prnu_frac"][c] for c in CHANNELS]) ** 2
        cs_true_real = float(colour_sensitivity_bits(real_v, truth["clip_dn"][None], ccm.matrix, ccm.wb_gains)[0])
        j_ok = {
            "K": [_inside(jd["R"]["conversion_gain_e_per_dn"], truth["k_e_per_dn"])[0]],
            "read": [_inside(jd["R"][read_name], truth["read_noise_e"])[0]],
            "QE": [_inside(jd[c]["quantum_efficiency"], truth["quantum_efficiency"][c])[0] for c in CHANNELS],
            "PRNU": [_inside(jd[c]["prnu_percent"] / 100.0, truth["prnu_frac"][c])[0] for c in CHANNELS],
            "CS": [_inside(j_cs, cs_true)[0]],
            "CS_clip": [_inside(j_em_clip.bits, cs_clip_true)[0]],
            "CS at the drawn pattern's PRNU": [_inside(j_cs, cs_true_real)[0]],
            "K check passed": [bool(jf.k_check["passed"])],
        }
        j_lo, j_med, j_hi = np.quantile(j_cs, [0.025, 0.5, 0.975])
        j_hw = (j_hi - j_lo) / 2
        j_z.append(_z(cs_true, j_lo, j_med, j_hi))
        j_ranks.append(float(np.mean(j_cs < cs_true)))
        if not j_ok["CS"][0]:

            def cs_one(vv, cl, m=ccm):
                return float(colour_sensitivity_bits(vv[None], cl[None], m.matrix, m.wb_gains)[0])

            misses.append(
                f"- camera {seed} ({cam.sensitivities.split()[0]} / {cam.illuminant}, K {cam.k_e_per_dn:.2f}, read "
                f"{cam.read_noise_e:.1f} e⁻): truth at z = {j_z[-1]:+.2f} (rank "
                f"{j_ranks[-1]:.3f}); from the medians to the truth: "
                + _drivers(
                    cs_one,
                    np.median(jv, axis=0),
                    np.median(jclip, axis=0),
                    truth["var_coeffs_dn2"],
                    truth["clip_dn"],
                    j_hw,
                )
                + f"; at the drawn pattern's PRNU z = {_z(cs_true_real, j_lo, j_med, j_hi):+.2f}"
            )
        for name, oks in j_ok.items():
            joint[name][0] += sum(oks)
            joint[name][1] += len(oks)
        if not jf.converged:
            notes.append("joint: a channel not converged")
        j_cell = (
            f"{'yes' if j_ok['K'][0] else 'NO'} / {'yes' if j_ok['read'][0] else 'NO'} / {sum(j_ok['QE'])}/4 / "
            f"{sum(j_ok['PRNU'])}/4 / {'yes' if j_ok['CS'][0] else 'NO'} ({j_z[-1]:+.2f}) / "
            f"{'yes' if j_ok['CS_clip'][0] else 'NO'} / p {jf.k_check['p_value']:.2f}"
        )
        rows.append(
            f"| {seed} | {cam.sensitivities.split()[0]} / {cam.illuminant} | {cam.k_e_per_dn:.2f} | {cam.read_noise_e:.1f} | "
            f"{sum(k_in)}/4 | {sum(qe_in)}/4 | {cs_true:.3f} | [{lo:.3f}, {hi:.3f}] | {'yes' if cs_ok else 'NO'} | "
            f"{widths_unc[-1]:.3f} | {np.median(cs_clip):.2f} ± {widths_clip[-1] / 2:.2f} | {j_cell} | "
            f"{'; '.join(notes) or '–'} |"
        )
        print(rows[-1], flush=True)
    cov = {k: _rate(a, b) for k, (a, b) in counts.items()}
    jcov = {k: _rate(a, b) for k, (a, b) in joint.items()}
    j_z_abs = np.abs(j_z)
    ccm_lines = [
        f"- {s} under {i}: noise gain {np.round(c.noise_gain(), 2).tolist()}, condition number {float(c.condition_number()):.2f}"
        for (s, i), c in ccms.items()
    ]
    text = (
        f"""# Colour sensitivity and per-channel QE against simulated Bayer cameras (`python benchmarks/run.py colour_coverage`)

{describe_machine()}; {"QUICK run (6 cameras)" if args.quick else f"full run, {len(seeds)} cameras"}; total {time.perf_counter() - t_all:.0f} s. Design: `benchmarks/colour_coverage.py` docstring. Channels fitted separately (`bayescap.fit`, fast), and jointly (`fit_cfa`, fast: what `bayescap colour` reports).

Truth inside the 95 % intervals (target ≥ 92 %), separate fits:

- K (each channel's own fit): {cov["K"]}
- QE per channel: {cov["QE"]}
- CS (cube, 8-bit floor, spectral CCM taken as exact): {cov["CS"]}
- CS clipped after M (CCM exact): {cov["CS_clip"]}

The joint fit (`fit_cfa`):

- K (shared): {jcov["K"]}
- read noise (shared): {jcov["read"]}
- QE per channel: {jcov["QE"]}
- PRNU per channel (not a target): {jcov["PRNU"]}
- CS (cube, 8-bit floor, CCM exact): {jcov["CS"]}
- CS clipped after M (CCM exact): {jcov["CS_clip"]}
- the K check passed (the channels share one K: about 99 % expected): {jcov["K check passed"]}
- diagnostic, CS at the drawn pattern's own PRNU instead of the population's: {jcov["CS at the drawn pattern's PRNU"]}

The truth's position among the CS draws (fraction of draws below it; uniform, mean 0.5 and
quartiles 0.25/0.5/0.75, if the intervals are calibrated): separate fits mean {np.mean(ranks):.2f},
quartiles {np.round(np.quantile(ranks, [0.25, 0.5, 0.75]), 2).tolist()}; joint fit mean {np.mean(j_ranks):.2f},
quartiles {np.round(np.quantile(j_ranks, [0.25, 0.5, 0.75]), 2).tolist()}. The joint CS truth's distance from
the median, z, in units of the median's distance to the interval's end on its side (|z| about
0.17, 0.34 and 1.0 at the 25th, 50th and 95th percentiles if Gaussian and calibrated; |z| > 1:
outside): quantiles 25/50/95 % of |z| {np.round(np.quantile(j_z_abs, [0.25, 0.5, 0.95]), 2).tolist()}; the misses
at most 1.1 out (within a few Monte Carlo errors of the interval's ends, ~0.05 of the half-width
with 1000 draws): {int(np.sum((j_z_abs > 1) & (j_z_abs <= 1.1)))} of {int(np.sum(j_z_abs > 1))}; the largest |z| {np.max(j_z_abs):.2f}.

Why the joint CS intervals that miss miss (the inputs' moves in half-widths of the interval; they do
not add exactly, CS being non-linear in them):

{chr(10).join(misses) or "- none"}

CS 95 % interval width: median {np.median(widths):.3f} bits (min {np.min(widths):.3f}); with the CCM's
bootstrap draws: median {np.median(widths_unc):.3f} bits (over the raw cube the CCM enters only through
the floor: its Jacobian cancels); with clipping after M (output volume fixed): median
{np.median(widths_clip):.3f} bits. CS costs {np.median(t_cs):.2f} s per 1000 draws (default n_grid, median over the cameras; machine shared).

The joint CS (raw cube and clipped), as `colour_summary` evaluates it (`bayescap.colour.cs_emulator`: the
quadrature on 128 pilot draws, a linear map of the draws' inputs on all when its leave-one-out residual
rms is ≤ 0.1 of CS's sd): the map used in {sum(emul_used)} of {len(emul_used)} evaluations (else the
quadrature on every draw); its leave-one-out residual / CS sd: median
{np.median([e for e in emul if e is not None]):.3f}, largest {max(e for e in emul if e is not None):.3f}.

Spectral CCMs (ColorChecker N Ohta → linear sRGB):
{chr(10).join(ccm_lines)}

| seed | sensitivities / illuminant | K e⁻/DN | read e⁻ | K inside | QE inside | CS truth (bits) | CS 95 % | inside | CS width, CCM uncertain | CS clipped after M (median ± half 95 %) | joint: K / read / QE / PRNU / CS (z) / CS clipped inside, K check p | notes |
| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |
"""
        + "\n".join(rows)
        + "\n"
    )
    emit(text.splitlines(), OUT)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
