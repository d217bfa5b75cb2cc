"""Does sampling the clip level as z = log(clip_dn − lower bound) help the MCMC where it does not converge?

    python benchmarks/clip_coordinates_mcmc.py --sensors 29,33,87,191,193,131,4 [--out F]

Rebuilds sensors of the all-spatial SBC (seed 3, ``benchmarks/sbc.py --spatial-fraction 1``; data sets,
injected discrepancies and SBC prior as there) and runs the `standard` ensembles
(:func:`bayescap.fit.run_ensembles`, parameters-only convergence check) twice with the same seed:
on the model (the clip level sampled as ``clip_dn``, as bayescap does) and on
:class:`bayescap.fit.LogClipCoordinates` (the coordinates its fast path and MCMC start already use),
mapped back. Prints per sensor and run: converged, rounds, production steps, walkers reset in
burn-in, wall time and the 95 % intervals of log K, clip_dn, log τ and log f. Sensors without a free
clip level are skipped. An experiment for docs/performance.md ("2026-11-24, 11:25–"), not a preset.
"""
import argparse
import os
import sys
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sensors", default="29,33,87,191,193,131,4")
    ap.add_argument("--out", default=None)
    ap.add_argument("--modes", default="clip_dn,log(clip − lo)", help="comma-separated: clip_dn, log(clip − lo)")
    ap.add_argument("--no-reset", action="store_true",
                    help="switch off the stuck-walker reset in burn-in (fit._reset_stuck_walkers), for this run only")
    a = ap.parse_args(argv)
    import importlib

    import sbc
    from _machine import describe_machine, emit

    from bayescap.model.ptc_model import PTCModel
    F = importlib.import_module("bayescap.fit")
    warnings.simplefilter("ignore")
    if a.no_reset:
        F._reset_stuck_walkers = lambda sampler, state, ndim: (state, 0)   # inherited by the forked workers
    seeds = sbc.sensor_seeds(3, 200)
    lines = [f"# The MCMC with the clip level in log coordinates ({describe_machine()})", "",
             f"`python benchmarks/clip_coordinates_mcmc.py --sensors {a.sensors}`"
             + (f" --modes '{a.modes}'" if a.modes != "clip_dn,log(clip − lo)" else "")
             + (" --no-reset (the stuck-walker reset switched off)" if a.no_reset else ""), "",
             "| sensor | coordinates | converged | rounds | steps | walker resets in burn-in (2 checks × 4 ensembles × W walkers) | wall (s) | log K 95 % | clip_dn 95 % | log τ 95 % | log f 95 % |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for i in map(int, a.sensors.split(",")):
        ts, ss, fs = seeds[i]
        truth, sim, extra = sbc.draw_sensor_prior(np.random.default_rng(ts), sbc.SBC_LEVELS, 1.0)
        data = sbc.simulate_prior_sensor(truth, sim, extra, ss)
        m = PTCModel(data, prior=sbc.SBC_PRIOR)
        if not F.LogClipCoordinates.applies(m):
            print(f"sensor {i}: no free clip level, skipped", flush=True)
            continue
        for mode in a.modes.split(","):
            t0 = time.perf_counter()
            if mode == "clip_dn":
                ch = F.run_ensembles(m, settings=F.QUALITY_PRESETS["standard"], seed=fs, n_jobs=2)
                chain = ch.chain
            else:
                cz = F.LogClipCoordinates(m)
                ch = F.run_ensembles(cz, settings=F.QUALITY_PRESETS["standard"], seed=fs, n_jobs=2)
                chain = cz.to_x(ch.chain)
            wall = time.perf_counter() - t0
            flat = chain.reshape(-1, chain.shape[-1])
            iv = {n: np.quantile(flat[:, m.names.index(n)], [0.025, 0.975]) for n in ("log_k", "clip_dn", "log_tau", "log_f")}
            row = (f"| {i} | {mode} | {ch.extra.get('param_diagnostics') is not None} | {ch.n_rounds} | {chain.shape[1]} | "
                   f"{sum(ch.extra['walkers_reset'])} (W = {chain.shape[2]}) | {wall:.1f} | "
                   + " | ".join(f"[{v[0]:.4f}, {v[1]:.4f}]" for v in iv.values()) + " |")
            print(row, flush=True)
            lines.append(row)
    emit(lines, a.out)


if __name__ == "__main__":
    main()
