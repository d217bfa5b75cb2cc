"""Simulation-based calibration (Talts et al. 2018): :data:`SBC_PRIOR`, the proper prior the truths
are drawn from and every fit uses; :func:`draw_sensor_prior` and :func:`simulate_prior_sensor`, a
sensor and its data set; :func:`run_one`, simulate, fit and rank one sensor."""

from __future__ import annotations

import math
import time
import warnings

import numpy as np


# --------------------------------------------------------------------------- SBC: truths
def _logu(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


#: the proper, realistic prior of the classic SBC (truths ``"prior"``): the truths are drawn
#: from it (``draw_sensor_prior``) and every fit uses exactly it (``bayescap.fit(prior=...)``).
#: Natural-unit bounds of log-uniform priors; QE uniform; f and g log-normal as in production but
#: with log-sd 1 (a 95 % range of 0.14–7 % for f instead of 0.05–19 %).
SBC_PRIOR = dict(
    log_k_bounds=(math.log(0.5), math.log(8.0)),
    read_log_bounds=(1.0, 20.0),
    dark_current_log_bounds=(1.0, 200.0),
    qe_bounds=(0.3, 0.8),
    prnu_log_bounds=(0.003, 0.02),
    dsnu_log_bounds=(1.0, 20.0),
    f_center=0.01,
    f_log_sd=1.0,
    g_center=0.005,
    g_log_sd=1.0,
)


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
    and DSNU) above 0 DN, and the ADC bits that give the drawn range. The DSNU counts: with a
    black level set by the read noise alone, sensors with read noise and DSNU in the outer 2.5 %
    had 2–4 % of their dark pixels clipped at 0 DN (the fit flags such data: ``dark_floor_clipping``)."""
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
    truth = SensorTruth(
        conversion_gain_e_per_dn=K,
        read_noise_e=rn,
        full_well_e=fw,
        dark_current_e_per_s=dc,
        quantum_efficiency=qe,
        prnu_frac=prnu,
        dsnu_e=dsnu,
        full_well_spread_frac=spread,
        adc_bits=bits,
        black_level_dn=black,
    )
    sim = dict(
        n_levels=n_levels, shape=(100, 100), spatial_frames=8 if spatial else 0, spatial_every=5 if spatial else 0
    )
    return truth, sim, {"variance_discrepancy": f, "mean_discrepancy": g}


def simulate_prior_sensor(truth, sim, extra, sim_seed):
    """The classic SBC's data set of a sensor drawn by :func:`draw_sensor_prior`: simulated with
    ``sim_seed``, the discrepancies ``extra`` injected with the stream ``sim_seed + 7``
    (:func:`run_one`)."""
    from bayescap.simulate import simulate_ptc

    data = simulate_ptc(truth, seed=sim_seed, **sim)
    return inject_discrepancies(
        data, extra["variance_discrepancy"], extra["mean_discrepancy"], np.random.default_rng(sim_seed + 7)
    )


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

    kw = dict(
        temporal_var_dn2=scale(data.temporal_var_dn2),
        dark_temporal_var_dn2=scale(data.dark_temporal_var_dn2),
        spatial_var_dn2=scale(data.spatial_var_dn2),
        dark_spatial_var_dn2=scale(data.dark_spatial_var_dn2),
    )
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
    truth = SensorTruth(
        conversion_gain_e_per_dn=K,
        read_noise_e=rn,
        full_well_e=fw,
        dark_current_e_per_s=dc,
        quantum_efficiency=qe,
        prnu_frac=prnu,
        dsnu_e=dsnu,
        full_well_spread_frac=spread,
        adc_bits=bits,
        black_level_dn=black,
    )
    sim = dict(n_levels=50, shape=(100, 100), spatial_frames=8 if spatial else 0, spatial_every=5 if spatial else 0)
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
    from bayescap.physics import capacity as cap

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
        tau = (
            np.nanmax(np.where(np.isfinite(result.chains.tau), result.chains.tau, np.nan))
            if np.any(np.isfinite(result.chains.tau))
            else S / 10.0
        )  # cautious: 10 spaced steps
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


#: sampler settings of :func:`run_one`'s ``quality="sbc"``: the standard preset's chain
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

    ``args = (i, truth_seed, sim_seed, fit_seed, quality, L[, truths[, n_levels[, spatial_fraction]]])``
    (seeds from :func:`sensor_seeds`; ``quality`` a preset name or ``"sbc"`` for :data:`SBC_SETTINGS`); ``truths`` is
    ``"realistic"`` (default: :func:`draw_sensor`, production priors) or ``"prior"`` (classic SBC:
    :func:`draw_sensor_prior`, discrepancies injected, fitted with ``SBC_PRIOR``)."""
    i, truth_ss, sim_seed, fit_seed, quality, L = args[:6]
    truths = args[6] if len(args) > 6 else "realistic"
    n_levels = args[7] if len(args) > 7 else SBC_LEVELS
    spatial_fraction = args[8] if len(args) > 8 else 0.4
    from bayescap.api import fit
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
                res = fit(data, seed=fit_seed + 7919 * attempt, quality=_settings(quality), n_jobs=1, prior=prior)
                break
            except Exception as exc:  # noqa: BLE001
                errors.append(f"{type(exc).__name__}: {exc}")
        else:
            return {
                "i": i,
                "truths": truths,
                "truth": truth.to_dict(),
                "injected": extra,
                "failed": errors,
                "wall_s": time.perf_counter() - t0,
            }
    wall = time.perf_counter() - t0
    tv = truth_values(truth, res)
    if truths == "prior":
        tv["variance_discrepancy"] = extra["variance_discrepancy"]
        if "mean_discrepancy" in res.draws:
            tv["mean_discrepancy"] = extra["mean_discrepancy"]
    summ = res.parameter_summary()
    idx = thinned_index(res, L, np.random.default_rng(fit_seed + 1))
    rec = {
        "i": i,
        "truths": truths,
        "truth": truth.to_dict(),
        "injected": extra,
        "sim": {k: (list(v) if isinstance(v, tuple) else v) for k, v in sim.items()},
        "clip": res.model.terms.clip,
        "adc_clips_first": truth.adc_clips_first,
        "converged": bool(res.diag["converged"]),
        "failed_checks": res.diag["failed_checks"],
        "n_rounds": res.diag["n_rounds"],
        "tau_max": float(res.diag["tau_max_steps"]),
        "wall_s": wall,
        "L": int(idx.size),
        "fit_errors": errors,
        "q": {},
    }
    rrng = np.random.default_rng(fit_seed + 2)
    for name, t in tv.items():
        x = res.derived[name] if name in res.derived else res.draws[name]
        qs = np.quantile(x, [0.025, 0.16, 0.25, 0.5, 0.75, 0.84, 0.975])
        rec["q"][name] = {
            "truth": float(t),
            "rank": rank_of(t, x[idx], rrng),
            "u": float(np.mean(x < t)),  # posterior CDF at the truth, all draws
            "median": float(qs[3]),
            "in50": bool(qs[2] <= t <= qs[4]),
            "in68": bool(qs[1] <= t <= qs[5]),
            "in95": bool(qs[0] <= t <= qs[6]),
            "rel_sd": float(np.std(x) / abs(qs[3])) if qs[3] else float("nan"),
            "constrained": bool(summ.get(name, {}).get("constrained", True)),
        }
    return rec
