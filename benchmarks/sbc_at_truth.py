"""The model at the truth: for SBC sensors, the likelihood's blocks evaluated at the true parameters,
with the ROI pattern latents set to the simulator's own realised maps (reconstructed from the seed).

A block whose per-sensor mean z-score (√n · mean of (obs/model − 1)·√shape) is not ~N(0, 1) over
sensors is a mismatch between model and simulator, before any sampling. The realised DSNU map's
sample variance is also checked against DSNU²·χ²_ν/ν. Usage (seconds, no fits):

    python benchmarks/sbc_at_truth.py --seed 3 --first 0 --last 40 --spatial-fraction 1
    python benchmarks/sbc_at_truth.py --seed 3 --sensor 68 --spatial-fraction 1   # one sensor, per block
    python benchmarks/sbc_at_truth.py --seed 2 --sensor 58 --repeat 300   # + Monte Carlo of its dark ROI

Not ranked: clip rows (the model's clip spread τ has no single true value in the simulator).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sbc  # noqa: E402

from bayescap.model.ptc_model import PTCModel  # noqa: E402
from bayescap.simulate import _FixedPattern, _frames, simulate_ptc  # noqa: E402


def _wh_inverse(q, n):
    """z with Wilson–Hilferty χ²_n/n(z) = q (the inverse of model._chi2_over_nu)."""
    a = 2.0 / (9.0 * n)
    return (q ** (1.0 / 3.0) - 1.0 + a) / np.sqrt(a)


def at_truth(seed, i, spatial_fraction):
    ts, ss, _ = sbc.sensor_seeds(seed, max(i + 1, 200))[i]
    truth, sim, _ = sbc.draw_sensor_prior(np.random.default_rng(ts), sbc.SBC_LEVELS, spatial_fraction)
    data = simulate_ptc(truth, seed=ss, **sim)   # no discrepancies injected: the model's core
    m = PTCModel(data, prior=sbc.SBC_PRIOR)
    th = m.initial_guess()
    K = truth.conversion_gain_e_per_dn
    for n, v in {"log_k": K, "log_read": truth.read_noise_e, "log_dc": truth.dark_current_e_per_s,
                 "log_dsnu": truth.dsnu_e, "log_prnu": truth.prnu_frac, "log_f": 1e-6}.items():
        if n in m.idx:
            th[m.idx[n]] = np.log(v)
    if "qe" in m.idx:
        th[m.idx["qe"]] = truth.quantum_efficiency
    realised = None
    if m.pattern_latents:
        fp = _FixedPattern(truth, tuple(sim["shape"]), np.random.default_rng(ss))  # same stream
        nu = m.nu_pattern
        b = fp.dsnu.var(ddof=1)
        realised = b / truth.dsnu_e**2 - 1.0
        if "z_roi_prnu" in m.idx:
            # Bartlett's latents of the realised maps (model._pattern_moments inverted): var_s(p) = a
            # gives z₁, cov_s(p, d) = c gives z₃ = c·√ν/(DSNU·√a), var_s(d) = b then gives z₂ (until
            # 2026-11-24 z₃ was 0: the maps' cross-covariance left out)
            pm = (fp.prnu - 1.0).ravel()
            a = pm.var(ddof=1)
            c = float(np.cov(pm, fp.dsnu.ravel(), ddof=1)[0, 1])
            z3 = c * np.sqrt(nu) / (truth.dsnu_e * np.sqrt(a))
            th[m.idx["z_roi_prnu"]] = _wh_inverse(a / truth.prnu_frac**2, nu)
            th[m.idx["z_roi_cross"]] = z3
            th[m.idx["z_roi_dsnu"]] = _wh_inverse((b * nu / truth.dsnu_e**2 - z3 * z3) / (nu - 1), nu - 1)
        else:
            th[m.idx["z_roi_dsnu"]] = _wh_inverse(b / truth.dsnu_e**2, nu)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pr = m.predict(th[None])
    out = {}
    for blk in ("dark_var", "dark_spatial_var", "bright_var", "spatial_var"):
        if blk not in pr:
            continue
        obs, mod, shape, _ = pr[blk]
        z = (obs / mod[0] - 1.0) * np.sqrt(shape[0])
        if blk == "bright_var":
            z = z[np.setdiff1d(np.arange(z.size), m.clip_rows)]
        if z.size:
            out[blk] = (float(z.mean() * np.sqrt(z.size)), int(z.size), float(np.mean(obs / mod[0] - 1.0)))
    return truth, out, realised


def dark_roi_monte_carlo(seed, i, spatial_fraction, repeats, t_s=0.01):
    """Mean spatial variance of 8-frame dark averages over ``repeats`` fresh temporal noises on the
    sensor's fixed ROI maps, relative to the model's P + T at the truth: (mean − 1, its standard
    error, one row's relative sd). Tests the dark spatial rows' expectation, free of the one noise
    draw the data happened to get."""
    ts, ss, _ = sbc.sensor_seeds(seed, max(i + 1, 200))[i]
    truth, sim, _ = sbc.draw_sensor_prior(np.random.default_rng(ts), sbc.SBC_LEVELS, spatial_fraction)
    shape = tuple(sim["shape"])
    fp = _FixedPattern(truth, shape, np.random.default_rng(ss))
    K = truth.conversion_gain_e_per_dn
    P = fp.dsnu.var(ddof=1) / K**2
    T = ((truth.read_noise_e**2 + truth.dark_current_e_per_s * t_s) / K**2 + 1.0 / 12.0) / 8.0
    rng = np.random.default_rng(5)
    v = np.array([_frames(truth, fp, 0.0, t_s, 8, shape, rng).mean(0).var(ddof=1) for _ in range(repeats)])
    return v.mean() / (P + T) - 1.0, v.std() / np.sqrt(repeats) / (P + T), v.std() / (P + T)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--last", type=int, default=40)
    ap.add_argument("--sensor", type=int, default=None)
    ap.add_argument("--spatial-fraction", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=0, help="with --sensor: Monte Carlo repeats of its dark ROI")
    a = ap.parse_args(argv)
    ids = [a.sensor] if a.sensor is not None else range(a.first, a.last)
    agg, dev = {}, []
    for i in ids:
        truth, out, realised = at_truth(a.seed, i, a.spatial_fraction)
        s = truth.read_noise_e / truth.conversion_gain_e_per_dn
        regime = "read < 0.5 DN" if s < 0.5 else "read >= 0.5 DN"
        if realised is not None:
            dev.append(realised)
        if a.sensor is not None:
            print(truth)
            for blk, (zs, n, rel) in out.items():
                print(f"{blk:18s} n={n:3d} √n·mean z {zs:+.2f} (N(0,1) if the model holds)  mean rel. residual {100 * rel:+.3f} %")
        for blk, (zs, n, _) in out.items():
            agg.setdefault((blk, regime), []).append((zs, i))
    if a.sensor is not None and a.repeat:
        d, se, row = dark_roi_monte_carlo(a.seed, a.sensor, a.spatial_fraction, a.repeat)
        print(f"dark ROI, {a.repeat} Monte Carlo repeats (t = 10 ms): mean/(P + T) − 1 = {100 * d:+.2f} ± "
              f"{100 * se:.2f} % (one row's sd {100 * row:.2f} %)")
    if a.sensor is None:
        for (blk, regime), v in sorted(agg.items()):
            z = np.array([x[0] for x in v])
            worst = sorted(v, key=lambda x: -abs(x[0]))[:3]
            print(f"{blk:18s} {regime:15s} sensors {z.size:3d}: mean {z.mean():+.2f} sd {z.std():.2f} "
                  f"(N(0,1) expected); worst " + ", ".join(f"{i}: {zz:+.1f}" for zz, i in worst))
        if dev:
            dev = np.array(dev)
            print(f"realised DSNU map variance / DSNU² − 1 over {dev.size} sensors: mean {100 * dev.mean():+.2f} %, "
                  f"sd {100 * dev.std():.2f} % (χ²_ν/ν: sd {100 * np.sqrt(2 / 9999):.2f} % for 100×100 px)")


if __name__ == "__main__":
    main()
