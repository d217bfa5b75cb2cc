"""Simulation-based calibration of bayescap's posterior (issue 6).

Method (Talts, Betancourt, Simpson, Vehtari & Gelman 2018, "Validating Bayesian inference
algorithms with simulation-based calibration", arXiv:1804.06788): draw a true sensor, simulate
frame-level photon-transfer data from it with :func:`bayescap.simulate.simulate_ptc`, fit with
:func:`bayescap.fit`, and rank the truth among ``L`` posterior draws thinned by the integrated
autocorrelation time. If the posterior is calibrated the ranks are uniform on ``0..L``.

**Classic SBC (``--truths prior``, the default).** Classic SBC needs truths drawn from the prior
the fit uses. The production prior (``PTCModel.PRIOR``) is deliberately wide (log K uniform on
1e-4..1e4 e⁻/DN, read noise of scale 1000 e⁻, ...): most of its draws are not sensors. So the SBC
uses a proper, realistic prior ``SBC_PRIOR`` for every model parameter, draws the truths from it
(:func:`draw_sensor_prior`) and fits with exactly it (``bayescap.fit(prior=SBC_PRIOR)``). The
simulator has no systematics, so the variance and mean discrepancies f and g are drawn from their
priors and injected into the simulated data as the likelihood describes them
(:func:`inject_discrepancies`). What is *not* from the fit's prior, because it is not a model
parameter: the full well and ADC range (the clip level's prior is uniform between data-derived
bounds), black level, and the per-pixel well spread (drawn from the clip-spread prior expressed
as a fraction of the full well); those parts are likelihood-dominated. ``docs/calibration.md``
lists the details.

**Realistic-range variant (``--truths realistic``).** Truths from :func:`draw_sensor`, fitted with
the production priors: uniform ranks then hold only where the likelihood dominates the prior.

The coverage of the equal-tailed 50/68/95 % intervals (from all kept draws, as a user sees them)
is reported with the ranks.

Capacity truth: ``C`` computed from the true parameters exactly as :meth:`FitResult._derive`
computes it from each draw, with the fit's own scene (exposure time) and MTF, and with the noise
terms the fit includes (a PRNU/DSNU the fit cannot see is not in its capacity estimand).

    python benchmarks/sbc.py --n 200 --seed 1 --quality standard --jobs 1 --truths prior --levels 50

writes ``benchmarks/results/sbc.md`` and ``benchmarks/results/sbc_ranks.png`` (and the raw
per-sensor records as JSON lines to ``--raw``, default in the system temp directory).
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one thread per worker process: the pool supplies parallelism

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"

#: ranked quantities: fit name -> truth name (see ``truth_values``)
PARAMS = ["conversion_gain_e_per_dn", "read_noise_e", "dark_current_e_per_s", "full_well_e",
          "quantum_efficiency", "prnu_percent", "dsnu_e", "variance_discrepancy",
          "mean_discrepancy", "capacity_bits"]
LEVELS = (0.50, 0.68, 0.95)


# --------------------------------------------------------------------------- truths
def _logu(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


#: the proper, realistic prior of the classic SBC (``--truths prior``): the truths are drawn
#: from it (``draw_sensor_prior``) and every fit uses exactly it (``bayescap.fit(prior=...)``).
#: Natural-unit bounds of log-uniform priors; QE uniform; f and g log-normal as in production but
#: with log-sd 1 (a 95 % range of 0.14–7 % for f instead of 0.05–19 %).
SBC_PRIOR = dict(log_k_bounds=(math.log(0.5), math.log(8.0)), read_log_bounds=(1.0, 20.0),
                 dark_current_log_bounds=(1.0, 200.0), qe_bounds=(0.3, 0.8),
                 prnu_log_bounds=(0.003, 0.02), dsnu_log_bounds=(1.0, 20.0),
                 f_center=0.01, f_log_sd=1.0, g_center=0.005, g_log_sd=1.0)
#: exposure levels per simulated sensor in the classic SBC (cost: see the report)
SBC_LEVELS = 50


def _draw_core(rng):
    """The draws both truth generators share, in this order (the random stream depends on it):
    K log-U(0.5, 8) e⁻/DN, read noise log-U(1, 20) e⁻, full well log-U(3 000, 60 000) e⁻, dark
    current log-U(1, 200) e⁻/s, QE U(0.3, 0.8), ADC range / full well log-U(0.4, 2.5). Black level
    64·2^j DN, the smallest at least 6 read-noise sd above 0 DN: a real camera's offset keeps the
    dark noise off the ADC's zero (64 DN fixed clipped 3 % of the dark pixels of a K = 0.56, 19 e⁻
    sensor, an artefact the model rightly does not describe); ADC bits from the range, 10–16.
    The last value, the drawn ADC range / full well, lets :func:`_black_and_bits` raise the black
    level for a DSNU drawn later."""
    K = _logu(rng, 0.5, 8.0)
    rn = _logu(rng, 1.0, 20.0)
    fw = _logu(rng, 3000.0, 60000.0)
    dc = _logu(rng, 1.0, 200.0)
    qe = float(rng.uniform(0.3, 0.8))
    ratio = _logu(rng, 0.4, 2.5)
    black, bits = _black_and_bits(K, rn, fw, ratio)
    return K, rn, fw, dc, qe, black, bits, ratio


def _black_and_bits(K, rn, fw, ratio, dsnu=0.0):
    """Black level 64·2^j DN, the smallest at least 6 sd of the dark pixel distribution (read noise
    and DSNU) above 0 DN, and the ADC bits that give the drawn range. Without DSNU this is the
    rule of the runs before 2026-11-23; with it, the all-spatial SBC (seed 2) had two sensors
    (68, 174) whose dark pixels clipped at 0 DN for 2–4 % (black 64 DN at 1.7–2.1 sd): both had
    read noise and DSNU in the outer 2.5 % (the fit now flags such data: ``dark_floor_clipping``)."""
    black = 64.0
    while black < 6.0 * math.hypot(rn, dsnu) / K:
        black *= 2.0
    bits = int(np.clip(round(math.log2(ratio * fw / K + black + 1.0)), 10, 16))
    return black, bits


def draw_sensor_prior(rng, n_levels=SBC_LEVELS, spatial_fraction=0.4):
    """One sensor drawn from ``SBC_PRIOR`` (classic SBC), its simulation settings and the
    discrepancies to inject.

    Parameters the model has, drawn from exactly the prior the fit uses: K log-U(0.5, 8) e⁻/DN,
    read noise log-U(1, 20) e⁻, dark current log-U(1, 200) e⁻/s, QE U(0.3, 0.8), PRNU
    log-U(0.3 %, 2 %) and DSNU log-U(1, 20) e⁻ (sensors with a spatial stack, probability 0.4),
    variance discrepancy f and mean discrepancy g log-normal(log 1 %, 1) and log-normal(log 0.5 %, 1).
    Not a model parameter, so not from its prior: the full well log-U(3 000, 60 000) e⁻ and the ADC
    (as in :func:`draw_sensor`; the clip level's prior is uniform between data-derived bounds much
    wider than its likelihood), and the per-pixel well spread, drawn from the model's clip-spread
    prior expressed as a fraction of the full well (log-normal(log 0.5 %, 1.5), truncated at the
    model's 2 % cap). Sensors without a spatial stack get, with probability 0.5, a PRNU
    U(0.2 %, 1 %) that the model does not see (it only shapes the ADC roll-off, absorbed by τ).
    """
    from bayescap.simulate import SensorTruth

    K, rn, fw, dc, qe, black, bits, ratio = _draw_core(rng)
    while True:  # truncated log-normal (rejection)
        spread = float(np.exp(rng.normal(math.log(0.005), 1.5)))
        if spread < 0.02:
            break
    spatial = bool(rng.uniform() < spatial_fraction)
    if spatial:
        prnu = _logu(rng, 0.003, 0.02)
        dsnu = _logu(rng, 1.0, 20.0)
        black, bits = _black_and_bits(K, rn, fw, ratio, dsnu)
    else:
        prnu = float(rng.uniform(0.002, 0.01)) if rng.uniform() < 0.5 else 0.0
        dsnu = 0.0
    f = float(np.exp(rng.normal(math.log(SBC_PRIOR["f_center"]), SBC_PRIOR["f_log_sd"])))
    g = float(np.exp(rng.normal(math.log(SBC_PRIOR["g_center"]), SBC_PRIOR["g_log_sd"])))
    truth = SensorTruth(conversion_gain_e_per_dn=K, read_noise_e=rn, full_well_e=fw,
                        dark_current_e_per_s=dc, quantum_efficiency=qe, prnu_frac=prnu, dsnu_e=dsnu,
                        full_well_spread_frac=spread, adc_bits=bits, black_level_dn=black)
    sim = dict(n_levels=n_levels, shape=(100, 100), spatial_frames=8 if spatial else 0,
               spatial_every=5 if spatial else 0)
    return truth, sim, {"variance_discrepancy": f, "mean_discrepancy": g}


def simulate_prior_sensor(truth, sim, extra, sim_seed):
    """The classic SBC's data set of a sensor drawn by :func:`draw_sensor_prior`: simulated with
    ``sim_seed``, the discrepancies ``extra`` injected with the stream ``sim_seed + 7``
    (:func:`run_one`; ``benchmarks/clip_coordinates_mcmc.py`` rebuilds the SBC's data sets with it)."""
    from bayescap.simulate import simulate_ptc

    data = simulate_ptc(truth, seed=sim_seed, **sim)
    return inject_discrepancies(data, extra["variance_discrepancy"], extra["mean_discrepancy"],
                                np.random.default_rng(sim_seed + 7))


def inject_discrepancies(data, f, g, rng):
    """The model's discrepancy terms applied to simulated data, as the likelihood describes them.

    Every measured variance (temporal, dark, spatial, plateau) is multiplied by an independent
    Gamma(1/f², f²) factor (mean 1, relative variance f²: the sampling scatter's 2/ν becomes
    2/ν + f² + 2f²/ν); the photon count of every row is divided by (1 + g·ε), ε ~ N(0, 1), so that
    the measured signal is QE·μp/K·(1 + g·ε) in terms of the reported μp — the mean block's
    N(s_model, g·s_model)."""
    import dataclasses

    def scale(a):
        if a is None:
            return None
        a = np.asarray(a, float)
        return a * rng.gamma(1.0 / f**2, f**2, size=a.shape)

    kw = dict(temporal_var_dn2=scale(data.temporal_var_dn2),
              dark_temporal_var_dn2=scale(data.dark_temporal_var_dn2),
              spatial_var_dn2=scale(data.spatial_var_dn2),
              dark_spatial_var_dn2=scale(data.dark_spatial_var_dn2))
    if data.photons_per_pixel is not None:
        eps = rng.standard_normal(data.photons_per_pixel.shape)
        kw["photons_per_pixel"] = np.asarray(data.photons_per_pixel, float) / np.maximum(1.0 + g * eps, 0.05)
    return dataclasses.replace(data, **{k: v for k, v in kw.items() if v is not None or getattr(data, k) is None})


def draw_sensor(rng):
    """One realistic sensor and its simulation settings (the "realistic range").

    K log-uniform 0.5–8 e⁻/DN; read noise log-uniform 1–20 e⁻; full well log-uniform
    3 000–60 000 e⁻; dark current log-uniform 1–200 e⁻/s; QE uniform 0.3–0.8; black level
    64·2^j DN ≥ 6 read-noise sd; ADC bits chosen
    so that the ADC range (2^bits − 1 − black)·K over the full well is log-uniform in 0.4–2.5
    (rounded to whole bits, 10–16): sometimes the ADC clips first, sometimes the well;
    per-pixel well spread uniform 0–3 %. With probability 0.4 a spatial stack (8 frames at every
    5th level) and PRNU uniform 0.3–2 %, DSNU log-uniform 1–20 e⁻; otherwise no stack and, with
    probability 0.5, a PRNU uniform 0.2–1 % that only shapes the saturation roll-off (DSNU 0).
    50 levels, 100×100-pixel ROI, the simulator's default sweep (to 115 % of the clip charge,
    exposure times up to 20 ms).
    """
    from bayescap.simulate import SensorTruth

    K, rn, fw, dc, qe, black, bits, ratio = _draw_core(rng)
    spread = float(rng.uniform(0.0, 0.03))
    spatial = bool(rng.uniform() < 0.4)
    if spatial:
        prnu = float(rng.uniform(0.003, 0.02))
        dsnu = _logu(rng, 1.0, 20.0)
        black, bits = _black_and_bits(K, rn, fw, ratio, dsnu)
    else:
        prnu = float(rng.uniform(0.002, 0.01)) if rng.uniform() < 0.5 else 0.0
        dsnu = 0.0
    truth = SensorTruth(conversion_gain_e_per_dn=K, read_noise_e=rn, full_well_e=fw,
                        dark_current_e_per_s=dc, quantum_efficiency=qe, prnu_frac=prnu, dsnu_e=dsnu,
                        full_well_spread_frac=spread, adc_bits=bits, black_level_dn=black)
    sim = dict(n_levels=50, shape=(100, 100), spatial_frames=8 if spatial else 0,
               spatial_every=5 if spatial else 0)
    return truth, sim


def sensor_seeds(seed, n):
    """Independent (truth, simulation, fit) seeds for sensors 0..n−1 (SeedSequence spawning)."""
    out = []
    for child in np.random.SeedSequence(seed).spawn(n):
        a, b, c = child.spawn(3)
        out.append((a, int(b.generate_state(1)[0]), int(c.generate_state(1)[0])))
    return out


# --------------------------------------------------------------------------- truth values
def truth_values(truth, result):
    """True value of every ranked quantity the fit reports (same names as ``result.draws``)."""
    import bayescap.physics.capacity as cap

    m = result.model
    p = {"conversion_gain_e_per_dn": truth.conversion_gain_e_per_dn}
    if m.terms.dark_current:
        p["read_noise_e"] = truth.read_noise_e
        p["dark_current_e_per_s"] = truth.dark_current_e_per_s
    else:  # one exposure time: only sqrt(read² + D·t) is in the model
        t1 = float(np.unique(m.t[m.t > 0])[0]) if np.any(m.t > 0) else 0.0
        p["dark_noise_e"] = math.sqrt(truth.read_noise_e**2 + truth.dark_current_e_per_s * t1)
    if "full_well_e" in result.draws:
        p["full_well_e"] = truth.clip_charge_e
    if "quantum_efficiency" in result.draws:
        p["quantum_efficiency"] = truth.quantum_efficiency
    if "prnu_percent" in result.draws:
        p["prnu_percent"] = 100.0 * truth.prnu_frac
    if "dsnu_e" in result.draws:
        p["dsnu_e"] = truth.dsnu_e
    # capacity exactly as FitResult._derive, for one "draw" holding the truth
    pa = {k: np.atleast_1d(np.asarray(v, float)) for k, v in p.items()}
    coeffs = result._noise_coefficients(pa, result.scene.exposure_time_s)
    s_max, _ = result.signal_max_e(pa)
    bprime = np.log2(np.maximum(cap.tonal_range(coeffs, s_max), 1.0))
    ds = float(np.mean(result.derived["mtf_loss_bits"]))  # the fit's own Δs (constant per draw)
    w, h = result.metadata.get("width_px"), result.metadata.get("height_px")
    if w and h:
        p["capacity_bits"] = float(float(w) * float(h) * np.exp2(ds) * bprime[0])
    else:
        p["capacity_bits_per_pixel"] = float(np.exp2(ds) * bprime[0])
    return p


# --------------------------------------------------------------------------- ranks
def thinned_index(result, L, rng):
    """Flat indices of ``L`` draws spaced by the largest integrated autocorrelation time.

    Draws are taken at steps ``s0, s0+Δ, …`` (Δ = ceil(τ_max)) of every ensemble, from walkers
    picked at random without replacement over (ensemble, step, walker)."""
    E, S, W = result.shape_esw
    tau = float(result.diag["tau_max_steps"])
    if not math.isfinite(tau):  # emcee's estimate failed (seen once at standard quality): be
        tau = np.nanmax(np.where(np.isfinite(result.chains.tau), result.chains.tau, np.nan)) \
            if np.any(np.isfinite(result.chains.tau)) else S / 10.0  # cautious: 10 spaced steps
    step = max(1, int(math.ceil(tau)))
    s0 = int(rng.integers(0, step))
    steps = np.arange(s0, S, step)
    pool = np.array([(e, s, w) for e in range(E) for s in steps for w in range(W)])
    pick = pool[rng.choice(len(pool), size=min(L, len(pool)), replace=False)]
    return pick[:, 0] * S * W + pick[:, 1] * W + pick[:, 2]


def rank_of(truth, draws, rng):
    """Number of draws below the truth, ties broken at random (Talts et al. 2018)."""
    draws = np.asarray(draws, float)
    below = int(np.sum(draws < truth))
    ties = int(np.sum(draws == truth))
    return below + (int(rng.integers(0, ties + 1)) if ties else 0)


#: sampler settings of the classic SBC run (``--quality sbc``): the standard preset's chain
#: lengths with 2 instead of 4 ensembles and at most 2 rounds (cost; ranks use draws thinned by
#: the autocorrelation time, and the convergence flag is recorded per sensor)
SBC_SETTINGS = dict(n_ensembles=2, n_burn=100, n_steps=200, max_rounds=2, ess_target=200.0)


def _settings(quality):
    if quality == "sbc":
        from bayescap.inference.presets import SamplerSettings
        return SamplerSettings(**SBC_SETTINGS)
    return quality


def run_one(args):
    """Simulate, fit and rank one sensor; returns a JSON-able record.

    ``args = (i, truth_seed, sim_seed, fit_seed, quality, L[, truths[, n_levels]])``; ``truths`` is
    ``"realistic"`` (default: :func:`draw_sensor`, production priors) or ``"prior"`` (classic SBC:
    :func:`draw_sensor_prior`, discrepancies injected, fitted with ``SBC_PRIOR``)."""
    i, truth_ss, sim_seed, fit_seed, quality, L = args[:6]
    truths = args[6] if len(args) > 6 else "realistic"
    n_levels = args[7] if len(args) > 7 else SBC_LEVELS
    spatial_fraction = args[8] if len(args) > 8 else 0.4
    import bayescap
    from bayescap.simulate import simulate_ptc

    rng = np.random.default_rng(truth_ss)
    prior, extra = None, {}
    if truths == "prior":
        truth, sim, extra = draw_sensor_prior(rng, n_levels, spatial_fraction)
        prior = SBC_PRIOR
    else:
        truth, sim = draw_sensor(rng)
    t0 = time.perf_counter()
    if truths == "prior":
        data = simulate_prior_sensor(truth, sim, extra, sim_seed)
    else:
        data = simulate_ptc(truth, seed=sim_seed, **sim)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # one process per fit: the sensors are the parallel units (forked pool workers are
        # daemonic and may not fork the ensembles again; the numbers do not depend on n_jobs)
        errors = []
        for attempt in range(3):
            # a fit that raises (e.g. emcee refusing linearly dependent walkers after the burn-in
            # reset moved most of them onto one walker's path) is retried with another seed; the
            # errors are recorded and counted in the report, and a sensor is never dropped silently
            try:
                res = bayescap.fit(data, seed=fit_seed + 7919 * attempt, quality=_settings(quality),
                                   n_jobs=1, prior=prior)
                break
            except Exception as exc:  # noqa: BLE001
                errors.append(f"{type(exc).__name__}: {exc}")
        else:
            return {"i": i, "truths": truths, "truth": truth.to_dict(), "injected": extra,
                    "failed": errors, "wall_s": time.perf_counter() - t0}
    wall = time.perf_counter() - t0
    tv = truth_values(truth, res)
    if truths == "prior":
        tv["variance_discrepancy"] = extra["variance_discrepancy"]
        if "mean_discrepancy" in res.draws:
            tv["mean_discrepancy"] = extra["mean_discrepancy"]
    summ = res.parameter_summary()
    idx = thinned_index(res, L, np.random.default_rng(fit_seed + 1))
    rec = {"i": i, "truths": truths, "truth": truth.to_dict(), "injected": extra, "sim": {k: (list(v) if isinstance(v, tuple) else v) for k, v in sim.items()},
           "clip": res.model.terms.clip, "adc_clips_first": truth.adc_clips_first,
           "converged": bool(res.diag["converged"]), "failed_checks": res.diag["failed_checks"],
           "n_rounds": res.diag["n_rounds"], "tau_max": float(res.diag["tau_max_steps"]), "wall_s": wall,
           "L": int(idx.size), "fit_errors": errors, "q": {}}
    rrng = np.random.default_rng(fit_seed + 2)
    for name, t in tv.items():
        x = res.derived[name] if name in res.derived else res.draws[name]
        qs = np.quantile(x, [0.025, 0.16, 0.25, 0.5, 0.75, 0.84, 0.975])
        rec["q"][name] = {
            "truth": float(t),
            "rank": rank_of(t, x[idx], rrng),
            "u": float(np.mean(x < t)),            # posterior CDF at the truth, all draws
            "median": float(qs[3]),
            "in50": bool(qs[2] <= t <= qs[4]), "in68": bool(qs[1] <= t <= qs[5]),
            "in95": bool(qs[0] <= t <= qs[6]),
            "rel_sd": float(np.std(x) / abs(qs[3])) if qs[3] else float("nan"),
            "constrained": bool(summ.get(name, {}).get("constrained", True)),
        }
    return rec


# --------------------------------------------------------------------------- statistics
def chi2_uniform(ranks, L, n_bins):
    """χ² test of uniformity of ranks on 0..L in ``n_bins`` equal bins ((L+1) % n_bins == 0)."""
    ranks = np.asarray(ranks, int)
    if (L + 1) % n_bins:
        raise ValueError("L + 1 must be a multiple of the number of bins")
    counts = np.bincount(ranks // ((L + 1) // n_bins), minlength=n_bins)
    exp = ranks.size / n_bins
    chi2 = float(np.sum((counts - exp) ** 2 / exp))
    return counts, chi2, float(stats.chi2.sf(chi2, n_bins - 1))


def binom_band(n, p, alpha=0.01):
    """Central acceptance band [lo, hi] of a Binomial(n, p) count, each tail ≤ alpha/2."""
    lo = int(stats.binom.ppf(alpha / 2, n, p))
    hi = int(stats.binom.isf(alpha / 2, n, p))
    return lo, hi


def summarise(records, n_bins=10, subset=None):
    """Per quantity: n, rank χ² p-value, bin counts, coverage per level, mean u (bias sign)."""
    out = {}
    for name in PARAMS:
        rs = [r for r in records if name in r["q"] and (subset is None or subset(r, name))]
        if not rs:
            continue
        L = rs[0]["L"]
        ranks = [r["q"][name]["rank"] for r in rs if r["L"] == L]
        counts, chi2, p = chi2_uniform(ranks, L, n_bins) if len(ranks) >= n_bins else (None, float("nan"), float("nan"))
        cov = {lv: int(sum(r["q"][name][f"in{int(round(100 * lv))}"] for r in rs)) for lv in LEVELS}
        u = np.array([r["q"][name]["u"] for r in rs])
        out[name] = {"n": len(rs), "counts": None if counts is None else counts.tolist(), "chi2": chi2, "p": p,
                     "cov": cov, "u_mean": float(u.mean()), "frac_u_lt_025": float(np.mean(u < 0.025)),
                     "frac_u_gt_975": float(np.mean(u > 0.975))}
    return out


# --------------------------------------------------------------------------- report
def _plot(summary, path, L, n_bins, title="bayescap SBC"):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in PARAMS if n in summary and summary[n]["counts"] is not None]
    if not names:
        return
    cols = 4
    rows = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        s = summary[name]
        c = np.array(s["counts"])
        n = s["n"]
        ax.bar(np.arange(n_bins), c, width=0.9, color="C0")
        lo, hi = binom_band(n, 1.0 / n_bins, alpha=0.01)
        ax.axhspan(lo, hi, color="0.85", zorder=0)
        ax.axhline(n / n_bins, color="k", lw=0.8)
        ax.set_title(f"{name}\nn={n}, χ² p={s['p']:.3g}", fontsize=9)
        ax.set_xticks([0, n_bins - 1])
        ax.set_xticklabels(["0", str(L)])
        ax.set_xlabel("rank of truth (binned)", fontsize=8)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(f"{title}; grey: 99 % band per bin for uniform ranks", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt_cov(k, n):
    return f"{k}/{n} = {100 * k / n:.1f} %" if n else "–"


REALISTIC_TEXT = (
    "**Truths are not drawn from the model's prior** (`--truths realistic`). They come from the realistic range of "
    "`draw_sensor`: K log-U(0.5, 8) e⁻/DN, read noise log-U(1, 20) e⁻, full well "
    "log-U(3 000, 60 000) e⁻, dark current log-U(1, 200) e⁻/s, QE U(0.3, 0.8), black level 64·2^j DN ≥ 6 read-noise sd, ADC bits so that "
    "ADC range / full well is log-U(0.4, 2.5), well spread U(0, 3 %), 40 % with spatial stacks "
    "(PRNU U(0.3, 2 %), DSNU log-U(1, 20) e⁻); 50 levels, 100×100 px, fitted with the production "
    "priors. Uniform ranks are expected only where the likelihood dominates the prior.")
CLASSIC_TEXT = (
    "**Classic SBC** (`--truths prior`, Talts et al. 2018): every model parameter is drawn from "
    "`SBC_PRIOR` and every fit uses exactly that prior (`bayescap.fit(prior=SBC_PRIOR)`): K "
    "log-U(0.5, 8) e⁻/DN, read noise log-U(1, 20) e⁻, dark current log-U(1, 200) e⁻/s, QE "
    "U(0.3, 0.8), PRNU log-U(0.3 %, 2 %) and DSNU log-U(1, 20) e⁻ ({spatial_pct:g} % of sensors, with an "
    "8-frame spatial stack at every 5th level), variance discrepancy f ~ logN(log 1 %, 1) and mean "
    "discrepancy g ~ logN(log 0.5 %, 1), **injected into the simulated data** as the likelihood "
    "describes them (`inject_discrepancies`). Not model parameters, hence not from the model's prior: "
    "full well log-U(3 000, 60 000) e⁻ and the ADC range (the clip level's prior is uniform between "
    "data-derived bounds far wider than its likelihood), and the per-pixel well spread (from the "
    "clip-spread prior as a fraction of the full well). {levels} levels, 100×100 px; black level and ADC "
    "bits depend on the drawn sensor as in `draw_sensor`.")


def _read_dn(rec):
    t = rec["truth"]
    return t["read_noise_e"] / t["conversion_gain_e_per_dn"]


def write_report(records, summary, path_md, *, cmd, wall_s, args, n_bins, strata):
    L = records[0]["L"]
    n = len(records)
    lines = [
        "# Simulation-based calibration" + (" (classic: truths from the fit's prior)" if records[0].get("truths") == "prior" else " (realistic-range truths)"),
        "",
        f"Command: `{cmd}`  ",
        f"Machine: {platform.node()} — {platform.platform()}, Python {platform.python_version()}, "
        f"{os.cpu_count()} CPUs (shared), {args.jobs} worker processes  ",
        f"Date: {time.strftime('%Y-%m-%d %H:%M %Z')}; "
        + (f"wall time {wall_s / 60:.1f} min" if wall_s is not None else "report rebuilt from the raw records")
        + f" for {n} sensors (simulation + fit per sensor: median "
        f"{np.median([r['wall_s'] for r in records]):.1f} s, max {max(r['wall_s'] for r in records):.1f} s, "
        f"total {sum(r['wall_s'] for r in records) / 60:.0f} process-min on a machine shared with other jobs)  ",
        f"Quality preset: `{args.quality}`" + (f" (SamplerSettings({', '.join(f'{k}={v}' for k, v in SBC_SETTINGS.items())}), the rest as `standard`)" if args.quality == "sbc" else "") + f"; rank among L = {L} draws thinned by the integrated "
        f"autocorrelation time; {n_bins} rank bins.",
        "",
        (CLASSIC_TEXT.format(levels=records[0]["sim"]["n_levels"],
                             spatial_pct=100.0 * getattr(args, "spatial_fraction", 0.4))
         if records[0].get("truths") == "prior"
         else REALISTIC_TEXT),
        "",
        f"ADC clips first: {sum(r['adc_clips_first'] for r in records)}/{n}; fitted clip mechanism: "
        + ", ".join(f"{c} {sum(r['clip'] == c for r in records)}" for c in sorted({r['clip'] for r in records}))
        + f"; converged (standard targets): {sum(r['converged'] for r in records)}/{n}.",
        "",
        "## Rank uniformity and coverage (all sensors)",
        "",
        "| quantity | n | χ² p (rank uniformity) | 50 % | 68 % | 95 % | mean posterior CDF at truth | truth < 2.5 % / > 97.5 % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary.items():
        c = s["cov"]
        lines.append(f"| {name} | {s['n']} | {s['p']:.3g} | {_fmt_cov(c[0.5], s['n'])} | "
                     f"{_fmt_cov(c[0.68], s['n'])} | {_fmt_cov(c[0.95], s['n'])} | {s['u_mean']:.3f} | "
                     f"{100 * s['frac_u_lt_025']:.1f} % / {100 * s['frac_u_gt_975']:.1f} % |")
    lo95, hi95 = binom_band(n, 0.95, alpha=0.01)
    lines += ["",
              f"For n = {n}, a calibrated 95 % interval covers between {lo95} and {hi95} truths "
              "(central 99 % binomial band); targets: χ² p > 0.01 and 95 % coverage in 92–98 %. "
              "Mean posterior CDF at the truth: 0.5 if unbiased; > 0.5 means the posterior sits "
              "*below* the truth (the fit underestimates), < 0.5 above it.",
              "",
              f"χ² p-values are asymptotic: with fewer than {5 * n_bins} sensors (expected count < 5 "
              "per bin, e.g. PRNU/DSNU, carried only by the sensors with spatial stacks) they are "
              "approximate. Diagnoses and proposed fixes: `docs/calibration.md`.",
              "",
              "Bin counts (rank bins from low to high):",
              "", "```"]
    for name, s in summary.items():
        lines.append(f"{name:28s} {s['counts']}")
    lines += ["```", ""]
    for title, sub in strata.items():
        lines += [f"## {title}", "",
                  "| quantity | n | χ² p | 50 % | 68 % | 95 % | mean CDF at truth |", "|---|---|---|---|---|---|---|"]
        for name, s in sub.items():
            c = s["cov"]
            lines.append(f"| {name} | {s['n']} | {s['p']:.3g} | {_fmt_cov(c[0.5], s['n'])} | "
                         f"{_fmt_cov(c[0.68], s['n'])} | {_fmt_cov(c[0.95], s['n'])} | {s['u_mean']:.3f} |")
        lines.append("")
    lines += ["![rank histograms](sbc_ranks.png)", ""]
    Path(path_md).write_text("\n".join(lines))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=200, help="number of simulated sensors")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quality", default="standard",
                    help='a preset name, or "sbc" for SBC_SETTINGS (2 ensembles, at most 2 rounds)')
    ap.add_argument("--truths", choices=("prior", "realistic"), default="prior",
                    help="prior: classic SBC (truths from SBC_PRIOR, fitted with it, f and g injected); "
                         "realistic: draw_sensor's range fitted with the production priors")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (each fit is independent)")
    ap.add_argument("--levels", type=int, default=SBC_LEVELS, help="exposure levels per sensor (--truths prior)")
    ap.add_argument("--spatial-fraction", type=float, default=0.4,
                    help="share of sensors with a spatial stack (PRNU, DSNU) (--truths prior); 1 ranks PRNU "
                         "and DSNU on every sensor")
    ap.add_argument("--L", type=int, default=99, help="thinned posterior draws per sensor (L+1 ranks)")
    ap.add_argument("--bins", type=int, default=10)
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--raw", type=Path, default=Path(tempfile.gettempdir()) / "bayescap_sbc_raw.jsonl",
                    help="per-sensor records, one JSON object per line (written as they finish)")
    ap.add_argument("--from-raw", type=Path, default=None,
                    help="only rebuild the report from raw records of an earlier (possibly partial) run")
    ap.add_argument("--cmd", default=None, help="with --from-raw: the command that made the records")
    args = ap.parse_args(argv)
    cmd = "python benchmarks/sbc.py " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.mkdir(parents=True, exist_ok=True)
    if args.from_raw is not None:
        records = [json.loads(line) for line in open(args.from_raw) if line.strip()]
        records.sort(key=lambda r: r["i"])
        # a partial run: keep the complete prefix 0..m-1 only (the sensors still running when it
        # stopped are the slow ones; dropping just them would bias the set towards easy sensors)
        done = {r["i"] for r in records}
        m = next(i for i in range(len(done) + 1) if i not in done)
        records = [r for r in records if r["i"] < m]
        note = "" if m == args.n else f" (partial: the first {m} of {args.n} sensors)"
        report(records, args=args, cmd=(args.cmd or cmd) + note, wall_s=None)
        return
    tasks = [(i, a, b, c, args.quality, args.L, args.truths, args.levels, args.spatial_fraction)
             for i, (a, b, c) in enumerate(sensor_seeds(args.seed, args.n))]
    t0 = time.perf_counter()
    records = []
    with open(args.raw, "w") as fh:
        if args.jobs > 1:
            import multiprocessing as mp
            with mp.get_context("fork").Pool(args.jobs, maxtasksperchild=20) as pool:
                for rec in pool.imap_unordered(run_one, tasks):
                    records.append(rec)
                    fh.write(json.dumps(rec) + "\n")
                    fh.flush()
                    print(f"[{len(records)}/{args.n}] sensor {rec['i']} clip={rec.get('clip')} "
                          f"{rec['wall_s']:.1f}s conv={rec.get('converged')} errors={rec.get('fit_errors') or rec.get('failed')}",
                          flush=True)
        else:
            for t in tasks:
                rec = run_one(t)
                records.append(rec)
                fh.write(json.dumps(rec) + "\n")
                fh.flush()
                print(f"[{len(records)}/{args.n}] sensor {rec['i']} {rec['wall_s']:.1f}s "
                      f"conv={rec.get('converged')} errors={rec.get('fit_errors') or rec.get('failed')}", flush=True)
    wall = time.perf_counter() - t0
    records.sort(key=lambda r: r["i"])
    report(records, args=args, cmd=cmd, wall_s=wall)


def report(records, *, args, cmd, wall_s):
    n_bins = args.bins
    failed = [r for r in records if "failed" in r]
    retried = [r for r in records if r.get("fit_errors")]
    records = [r for r in records if "failed" not in r]
    if failed or retried:
        cmd = cmd + (f"; {len(retried)} fits retried with another seed after an error, "
                     f"{len(failed)} sensors failed 3 attempts and are not ranked: "
                     + ", ".join(str(r["i"]) for r in failed) if failed else
                     f"; {len(retried)} fits retried with another seed after an error (errors in the raw records)")
    summary = summarise(records, n_bins)
    strata = {
        "Stratified: ADC clips first": summarise(records, n_bins, lambda r, n: r["adc_clips_first"]),
        "Stratified: full well clips first": summarise(records, n_bins, lambda r, n: not r["adc_clips_first"]),
        "Stratified: converged fits only": summarise(records, n_bins, lambda r, n: r["converged"]),
        "Stratified: read noise below 0.5 DN (σ_read/K; quantization regime)": summarise(
            records, n_bins, lambda r, n: _read_dn(r) < 0.5),
        "Stratified: read noise at least 0.5 DN": summarise(records, n_bins, lambda r, n: _read_dn(r) >= 0.5),
        "Stratified: the fit reports the quantity constrained": summarise(
            records, n_bins, lambda r, n: r["q"][n]["constrained"]),
        "Stratified: the fit reports the quantity unconstrained (upper limit)": summarise(
            records, n_bins, lambda r, n: not r["q"][n]["constrained"]),
    }
    out = Path(args.out)
    classic = records[0].get("truths") == "prior"
    _plot(summary, out / "sbc_ranks.png", records[0]["L"], n_bins,
          title="bayescap SBC (classic: truths from the fit's prior)" if classic else "bayescap SBC (realistic-range truths)")
    write_report(records, summary, out / "sbc.md", cmd=cmd, wall_s=wall_s, args=args, n_bins=n_bins, strata=strata)
    for name, s in summary.items():
        print(f"{name:28s} n={s['n']:4d} p={s['p']:.3g} cov50={s['cov'][0.5]} cov68={s['cov'][0.68]} "
              f"cov95={s['cov'][0.95]} u_mean={s['u_mean']:.3f}")
    return summary


if __name__ == "__main__":
    main()
