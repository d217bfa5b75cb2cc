"""The EMVA 1288 (Release 4.0, linear model) view of a fit: the standard's quantities, names,
symbols and units, each computed per posterior draw where it depends on the noise model, so
it carries a credible interval, with bayescap's own name beside it and a note where the two
definitions differ (docs/emva1288.md).

Besides the posterior numbers, every entry the standard computes from the measured rows
carries ``recipe``: the standard's own estimator on the CSV's rows (unweighted fits through
the origin up to 70 % of saturation, the variance maximum for saturation, the 5–95 % linearity
fit, spatial variances minus the averaged temporal variance), the numbers emva1288 would print
for the same table. Data-only quantities (the linearity error, the photons at saturation) have
no posterior: their ``median`` is the recipe's value and ``ci95`` is None.

The keys are emva1288's result names (``K``, ``QE``, ``sigma_d``, ``u_e_sat``, ...), so a
result compares key by key with emva1288's results JSON.
"""

from __future__ import annotations

import numpy as np

from bayescap.posterior.emva_limits import attach_limits
from bayescap.posterior.summary import json_safe

__all__ = ["emva1288_view", "emva1288_gain_draws", "EMVA_RELEASE"]

EMVA_RELEASE = "EMVA 1288 Release 4.0 (linear model)"

#: quantization noise of an ideal uniform quantizer, σ²_q (DN²)
S2Q = 1.0 / 12.0
#: the standard's floor of the dark temporal variance σ²_y.dark (DN²): below it quantization rules
S2_YDARK_FLOOR = 0.24
#: draws the model's variance peak is located on (a grid search per draw) and the standard's gain's line fitted on
N_PEAK_DRAWS = 4000


def _q(x):
    x = np.asarray(x, float).ravel()
    if not np.isfinite(x).any():
        return None, None
    lo, med, hi = np.quantile(x[np.isfinite(x)], [0.025, 0.5, 0.975])
    return float(med), [float(lo), float(hi)]


def _lsq_origin(x, y):
    """Unweighted least-squares slope of y = a·x (the standard's fits through the origin)."""
    return float(np.sum(x * y) / np.sum(x * x))


class _Sweep:
    """The standard's reading of the measured rows: the irradiation sweep (the pair rows of the most pixels:
    a spatial stack, or its crop, is left out), its saturation point (the row of largest temporal variance),
    the sensitivity rows (up to 70 % of the saturation signal), the linearity rows (5–95 %), the dark
    regression over exposure time, and the spatial row: of the rows of the most frames, the one nearest 50 %."""

    def __init__(self, data):
        d = data
        # a spatial stack (more than two frames) is not a sweep row, where pair rows exist beside it
        stack = np.asarray(d.n_frames, float) > 2 if d.n_frames is not None else np.zeros(d.n_levels, bool)
        sweep = (d.n_pixels == np.max(d.n_pixels)) & (~stack if np.any(~stack) else True)
        order = np.argsort(d.exposure_time_s[sweep], kind="stable")
        pick = lambda a: None if a is None else np.asarray(a, float)[sweep][order]
        self.data_rows = np.flatnonzero(sweep)[order]  # the CSV row index of each sweep row
        self.t = pick(d.exposure_time_s)
        self.mu_y = pick(d.mean_dn)
        self.mu_dark = pick(d.dark_mean_dn)
        self.s2_y = pick(d.temporal_var_dn2)
        self.s2_dark = pick(d.dark_temporal_var_dn2)
        self.mu_p = pick(d.photons_per_pixel)
        if self.mu_p is not None and not np.all(np.isfinite(self.mu_p)):
            self.mu_p = None
        self.signal = self.mu_y - self.mu_dark
        self.i_sat = int(np.argmax(self.s2_y))
        y_sat = self.signal[self.i_sat]
        self.sens = (np.arange(self.signal.size) <= self.i_sat) & (self.signal <= 0.7 * y_sat)
        self.lin = (self.signal >= 0.05 * y_sat) & (self.signal <= 0.95 * y_sat)
        # the variance turns over at the peak only if a brighter row exists (else no saturation)
        self.saturated = self.i_sat < self.signal.size - 1
        self.n_texp = int(np.unique(self.t).size)
        if self.n_texp > 2:
            # unweighted least-squares lines a·t + b
            self.dark_var_slope, self.s2_ydark0 = map(float, np.polyfit(self.t, self.s2_dark, 1))
            self.dark_mean_slope = float(np.polyfit(self.t, self.mu_dark, 1)[0])
        else:
            self.dark_var_slope = self.dark_mean_slope = None
            self.s2_ydark0 = float(self.s2_dark[0])
        # spatial-stack rows: the one nearest 50 % of saturation (the standard's PRNU point)
        sp = np.asarray(d.spatial_var_dn2, float) if d.spatial_var_dn2 is not None else None
        spd = np.asarray(d.dark_spatial_var_dn2, float) if d.dark_spatial_var_dn2 is not None else None
        L = np.asarray(d.n_frames, float) if d.n_frames is not None else None
        self.spatial = None
        if sp is not None and L is not None:
            ok = np.isfinite(sp) & np.isfinite(L) & (L > 1)
            if spd is not None:
                ok &= np.isfinite(spd)
            if ok.any():
                rows = np.flatnonzero(ok & (L == np.max(L[ok])))  # the largest stack: the standard's
                sig = d.mean_dn[rows] - d.dark_mean_dn[rows]
                r = rows[np.argmin(np.abs(sig - 0.5 * y_sat))]
                s2y = sp[r] - d.temporal_var_dn2[r] / L[r]
                s2yd = (spd[r] - d.dark_temporal_var_dn2[r] / L[r]) if spd is not None else np.nan
                self.spatial = {
                    "row": int(d.row_numbers[r]) if getattr(d, "row_numbers", None) is not None else int(r),
                    "n_pixels": int(d.n_pixels[r]),
                    "n_frames": int(L[r]),
                    "s2_y": float(s2y),
                    "s2_y_dark": float(s2yd),
                    "signal_dn": float(d.mean_dn[r] - d.dark_mean_dn[r]),
                }

    def recipe_gain(self):
        """K (DN/e⁻): Δσ²_y against Δμ_y through the origin over the sensitivity rows."""
        r = self.sens
        return _lsq_origin(self.signal[r], (self.s2_y - self.s2_dark)[r])

    def recipe_responsivity(self):
        """R (DN/photon): Δμ_y against μ_p through the origin over the sensitivity rows."""
        if self.mu_p is None:
            return None
        r = self.sens
        return _lsq_origin(self.mu_p[r], self.signal[r])

    def linearity(self):
        """The standard's linearity fit over the 5–95 % rows: the line a·μ_p + b minimising the
        relative deviations (weights 1/Δμ_y), and the deviations δ_y (%) of those rows."""
        if self.mu_p is None or self.lin.sum() < 3:
            return None
        X, Y = self.mu_p[self.lin], self.signal[self.lin]
        xy, xy2, x2y2 = np.sum(X / Y), np.sum(X / Y**2), np.sum((X / Y) ** 2)
        _y, _y2 = np.sum(1.0 / Y), np.sum(1.0 / Y**2)
        b = (xy * xy2 - x2y2 * _y) / (xy2**2 - x2y2 * _y2)
        a = (xy - b * xy2) / x2y2
        dev = 100.0 * (Y - (a * X + b)) / (a * X + b)
        return {"slope": float(a), "offset": float(b), "deviation_percent": dev, "mu_p": X}


def _model_gain(result, sw, idx):
    """K per draw (DN/e⁻) by the standard's definition applied to the fitted model: the unweighted
    slope through the origin of the model's Δσ²_y (temporal variance minus the dark row's, each as the
    model predicts it for that row, rounding and clip included) against Δμ_y over the sensitivity rows,
    for the draws ``idx``. The model takes a row's measured mean as its signal (without photon counts it
    predicts no other), so the line is the model's variance curve sampled where the standard samples
    the data. None without the sampler's chain or with a sensitivity row the model left out."""
    m, ch = result.model, getattr(result, "chains", None)
    if not m.data.has_dark_rows:  # a mean/variance table: the standard's Δσ²_y is undefined (no dark rows)
        return None
    rows = sw.data_rows[sw.sens]
    pos = np.searchsorted(m.rows, rows)
    if ch is None or rows.size == 0 or pos.max() >= m.rows.size or not np.array_equal(m.rows[pos], rows):
        return None
    th = ch.chain.reshape(-1, ch.chain.shape[-1])[idx]
    with np.errstate(all="ignore"):
        pred = m.predict(th)
    ds2 = pred["bright_var"][1][:, pos] - pred["dark_var"][1][:, rows]
    x = m.s_obs[pos]
    return np.sum(x * ds2, axis=1) / np.sum(x * x)


def emva1288_gain_draws(result, n_max=N_PEAK_DRAWS):
    """The conversion gain (e⁻/DN) as EMVA 1288 defines it, per draw: the inverse of the standard's
    straight line of Δσ²_y against Δμ_y through the fitted model over the standard's sensitivity rows
    (:func:`_model_gain`), on at most ``n_max`` draws of the walkers kept for the summaries. With a
    linear response it is ``conversion_gain_e_per_dn``; with ``response_nonlinearity`` it is the gain
    averaged over those rows (likewise with brighter-fatter), the number an EMVA 1288 datasheet prints.
    None without a chain."""
    kept = result._kept_mask() if hasattr(result, "_kept_mask") else None
    n = next(iter(result.draws.values())).size
    pool = np.arange(n) if kept is None else np.flatnonzero(kept)
    idx = pool if pool.size <= n_max else pool[np.linspace(0, pool.size - 1, n_max).round().astype(int)]
    K = _model_gain(result, _Sweep(result.model.data), idx)
    return None if K is None else 1.0 / K


def _model_variance_peak(result, sw, p, idx):
    """μe.sat per draw from the model: the latent (linear) signal, in e⁻, at which the model's
    temporal variance of the clipped output is largest: the standard's saturation point found on
    the fitted curve instead of among the measured rows. None without a clip term."""
    m = result.model
    if m.terms.clip == "none" or "clip_dn" not in p:
        return None
    k = p["conversion_gain_e_per_dn"][idx][:, None]
    c = np.broadcast_to(p["clip_dn"], p["conversion_gain_e_per_dn"].shape)[idx][:, None]
    tau = p["clip_spread_dn"][idx][:, None] if "clip_spread_dn" in p else np.zeros_like(k)
    t = float(sw.t[sw.i_sat])
    dm = float(sw.mu_dark[sw.i_sat])
    sub = {n: np.asarray(v)[idx] for n, v in p.items() if np.size(v) == p["conversion_gain_e_per_dn"].size}
    rd2 = np.asarray(m.dark_var_e2(sub, np.array([t])), float).reshape(-1, 1)
    if m.terms.clip == "well":
        dc = (sub["dark_current_e_per_s"][:, None] * t) if m.terms.dark_current else np.zeros_like(k)
        pre, post = dc / k**2, (rd2 - dc) / k**2 + S2Q
    else:
        pre, post = rd2 / k**2, None
    sp_c = np.sqrt(np.maximum(c - dm, 1.0) / k + pre + tau**2)
    h = np.linspace(-12.0, 3.0, 301)[None, :]
    mu = c + h * sp_c
    s = np.sqrt(np.maximum(mu - dm, 0.0) / k + pre)
    _, var, unclipped = m._clip_moments(mu, s, tau, c)
    var = var + (post if post is not None else unclipped * S2Q)
    j = np.argmax(var, axis=1)
    mu_pk = mu[np.arange(mu.shape[0]), j]
    return (mu_pk - dm) * k[:, 0]


def _entry(name, symbol, unit, draws=None, *, value=None, bayescap=None, recipe=None, note=None):
    med, ci = _q(draws) if draws is not None else (value, None)
    return {
        "name": name,
        "symbol": symbol,
        "unit": unit,
        "median": med,
        "ci95": ci,
        "recipe": recipe,
        "bayescap": bayescap,
        "note": note,
    }


def emva1288_view(result) -> dict:
    """The EMVA 1288 quantities of ``result`` (a :class:`~bayescap.posterior.FitResult`):
    ``{"standard", "quantities": {emva1288 key: {name, symbol, unit, median, ci95, recipe,
    bayescap, note}}, "saturation", "spatial_row", "notes"}``, JSON-able. ``median``/``ci95``
    are over the posterior draws (95 % equal-tailed); ``recipe`` is the standard's estimator on
    the measured rows (with the posterior median gain where it needs one)."""
    p = result.draws
    m = result.model
    sw = _Sweep(m.data)
    k = np.asarray(p["conversion_gain_e_per_dn"], float)  # e⁻/DN
    K = 1.0 / k  # DN/e⁻, the standard's system gain
    k_med = float(np.median(k))
    eta = np.asarray(p["quantum_efficiency"], float) if "quantum_efficiency" in p else None
    sigma_d_from = "read_noise_e" if m.terms.dark_current else "dark_noise_e"
    sigma_d = np.asarray(p[sigma_d_from], float)
    s2_ydark = np.maximum(sigma_d**2 * K**2 + S2Q, S2_YDARK_FLOOR)
    sigma_ydark = np.sqrt(s2_ydark)
    u_e_min = sigma_ydark / K + 0.5
    notes, q = [], {}
    K_rec = sw.recipe_gain()
    idx = result.thin_index(N_PEAK_DRAWS)
    K_std = _model_gain(result, sw, idx)
    bent = "response_nonlinearity" in p or "brighter_fatter_a00_per_e" in p
    if K_std is None:  # (no chain: the model's gain, the same thing for a linear response)
        K_std, how_k = K, "per posterior draw as 1 / conversion_gain_e_per_dn (no chain to evaluate the line on)"
    else:
        how_k = (
            f"the same line through the fitted model's variances at those rows' signals, per draw ({idx.size} draws)"
        )
    k_ss = _q(k)
    small = (
        "bayescap's conversion_gain_e_per_dn is the small-signal gain (the slope at zero signal) when "
        f"the response or the brighter-fatter term bends the model's PTC, as here: {k_ss[0]:.4g} [{k_ss[1][0]:.4g}, {k_ss[1][1]:.4g}] e-/DN, "
        "not this entry"
        if bent
        else "with a linear response the line's slope is 1 / conversion_gain_e_per_dn, bayescap's gain (exactly "
        "where the dark variances exceed 0.2 DN²; below, the exact rounding moments bend it slightly)"
    )
    q["K"] = _entry(
        "System gain",
        "K",
        "DN/e-",
        K_std,
        bayescap="not 1 / conversion_gain_e_per_dn (small-signal)" if bent else "1 / conversion_gain_e_per_dn",
        recipe=K_rec,
        note="the standard's K (DN per electron, the inverse of bayescap's e-/DN gain): the unweighted straight "
        "line of Δσ²_y against Δμ_y through the origin over the sensitivity rows (up to 70 % of saturation), an "
        f"average gain over those rows; here {how_k}; recipe: the line through the measured variances. {small}",
    )
    if bent:
        notes.append(
            "the response or the brighter-fatter term bends the model's PTC: K and 1/K are the standard's "
            "straight-line average over its "
            "rows; the quantities converted to electrons (η, σ_d, μe.sat, μe.min, DSNU1288, μ_I) use bayescap's "
            "small-signal gain conversion_gain_e_per_dn"
        )
    q["inverse_K"] = _entry(
        "Inverse system gain",
        "1/K",
        "e-/DN",
        1.0 / np.asarray(K_std, float),
        bayescap="not conversion_gain_e_per_dn (small-signal)" if bent else "conversion_gain_e_per_dn",
        recipe=1.0 / K_rec,
        note="1/K of the standard's straight-line average over its rows. " + small,
    )
    R_rec = sw.recipe_responsivity()
    if eta is not None:
        q["QE"] = _entry(
            "Quantum efficiency",
            "η",
            "%",
            100.0 * eta,
            bayescap="quantum_efficiency × 100",
            recipe=None if R_rec is None else 100.0 * R_rec / K_rec,
            note="electrons per photon at the CSV's photons_per_pixel (their wavelength); "
            "the standard's η = R/K from two fits up to 70 % of saturation, bayescap's from all rows' means jointly",
        )
        q["R"] = _entry(
            "Responsivity",
            "R",
            "DN/p",
            eta * K,
            bayescap="quantum_efficiency / conversion_gain_e_per_dn",
            recipe=R_rec,
            note="R = η·K: DN per photon",
        )
    else:
        notes.append("no photons_per_pixel column: η, R, μp.min, μp.sat and the linearity error need the irradiation")
    q["sigma_d"] = _entry(
        "Temporal dark noise",
        "σ_d",
        "e-",
        sigma_d,
        bayescap=sigma_d_from,
        recipe=float(np.sqrt(max(sw.s2_ydark0, S2_YDARK_FLOOR) - S2Q) / K_rec),
        note="dark temporal noise in electrons without quantization, at zero exposure time (the standard's "
        "intercept of σ²_y.dark over exposure time); with one exposure time it includes that time's dark current shot noise",
    )
    q["sigma_d_DN"] = _entry(
        "Temporal dark noise in DN",
        "σ_d·K",
        "DN",
        sigma_d * K,
        bayescap=f"{sigma_d_from} / conversion_gain_e_per_dn",
        recipe=float(np.sqrt(max(sw.s2_ydark0, S2_YDARK_FLOOR) - S2Q)),
        note="σ_d in DN, without quantization noise",
    )
    q["sigma_y_dark"] = _entry(
        "Temporal dark noise (output)",
        "σ_y.dark",
        "DN",
        sigma_ydark,
        bayescap=None,
        recipe=float(np.sqrt(max(sw.s2_ydark0, S2_YDARK_FLOOR))),
        note="sqrt(K²σ_d² + 1/12 DN²), floored at sqrt(0.24) DN as the standard does (quantization-limited)",
    )
    # saturation: the standard's point is the row of largest temporal variance
    if sw.saturated:
        if sw.mu_p is not None and eta is not None:
            u_p_sat = float(sw.mu_p[sw.i_sat])
            u_e_sat = eta * u_p_sat
            u_e_sat_rec = None if R_rec is None else R_rec / K_rec * u_p_sat
            how = (
                "μe.sat = η·μp.sat, μp.sat the photons of the row of largest temporal variance (the standard's recipe)"
            )
            q["u_p_sat"] = _entry(
                "Saturation irradiation",
                "μp.sat",
                "p",
                value=u_p_sat,
                recipe=u_p_sat,
                note="photons per pixel at the row of largest temporal variance: a measured value, no interval",
            )
        else:
            u_e_sat = k * float(sw.signal[sw.i_sat])
            u_e_sat_rec = float(sw.signal[sw.i_sat]) / K_rec
            how = "μe.sat = Δμ_y/K at the row of largest temporal variance (no photons_per_pixel for η·μp.sat)"
        q["u_e_sat"] = _entry(
            "Saturation capacity",
            "μe.sat",
            "e-",
            u_e_sat,
            bayescap="not full_well_e",
            recipe=u_e_sat_rec,
            note=how + ". bayescap's full_well_e is a different quantity: the charge at the clip (ADC maximum "
            "or well), where the mean stops rising; the variance peaks below it, as pixels start to clip",
        )
        peak = _model_variance_peak(result, sw, p, idx)
        if peak is not None:
            q["u_e_sat_model"] = _entry(
                "Saturation capacity at the model's variance peak",
                "μe.sat (model)",
                "e-",
                peak,
                bayescap="from clip_dn, clip_spread_dn and the noise model",
                note="the latent linear signal (e-) at the maximum of the fitted variance curve of the clipped output, "
                f"per draw ({idx.size} draws): the standard's saturation point on the model instead of among the rows",
            )
    else:
        u_e_sat = k * float(np.max(sw.signal))
        u_e_sat_rec = None
        notes.append(
            "the temporal variance never turns over: no row reaches saturation, so μe.sat, DR and SNR_max are "
            "lower bounds from the largest measured signal"
        )
        q["u_e_sat"] = _entry(
            "Saturation capacity (lower bound)",
            "μe.sat",
            "e-",
            u_e_sat,
            bayescap="not full_well_e",
            note="lower bound: the largest measured signal in electrons",
        )
    q["u_e_min"] = _entry(
        "Absolute sensitivity threshold (electrons)",
        "μe.min",
        "e-",
        u_e_min,
        recipe=float(np.sqrt(max(sw.s2_ydark0, S2_YDARK_FLOOR)) / K_rec + 0.5),
        note="μe.min = σ_y.dark/K + 1/2: the signal at SNR = 1, quantization included",
    )
    if eta is not None:
        u_p_min = u_e_min / eta
        q["u_p_min"] = _entry(
            "Absolute sensitivity threshold",
            "μp.min",
            "p",
            u_p_min,
            recipe=None
            if R_rec is None
            else float((np.sqrt(max(sw.s2_ydark0, S2_YDARK_FLOOR)) / K_rec + 0.5) * K_rec / R_rec),
            note="μp.min = μe.min/η (photons per pixel at SNR = 1)",
        )
        pitch = result.metadata.get("pixel_pitch_um")
        if pitch:
            area = float(pitch) ** 2
            q["u_p_min_area"] = _entry(
                "Absolute sensitivity threshold per area",
                "μp.min.area",
                "p/µm²",
                u_p_min / area,
                note=f"μp.min over the pixel area ({float(pitch):g} µm pitch squared)",
            )
    dr = u_e_sat / u_e_min
    dr_rec = None if u_e_sat_rec is None else u_e_sat_rec / q["u_e_min"]["recipe"]
    q["DR"] = _entry("Dynamic range", "DR", "", dr, recipe=dr_rec, note="DR = μp.sat/μp.min = μe.sat/μe.min")
    q["DR_dB"] = _entry(
        "Dynamic range in dB",
        "DR_dB",
        "dB",
        20.0 * np.log10(dr),
        bayescap="differs from derived.dynamic_range_db",
        recipe=None if dr_rec is None else 20.0 * np.log10(dr_rec),
        note="20 log10 DR. bayescap's dynamic_range_db divides the largest non-saturating signal by the dark "
        "noise (DSNU included, no +1/2) at the scene's exposure: a different ratio",
    )
    q["DR_bit"] = _entry(
        "Dynamic range in bits",
        "DR_bit",
        "bit",
        np.log2(dr),
        recipe=None if dr_rec is None else float(np.log2(dr_rec)),
        note="log2 DR",
    )
    snr = np.sqrt(u_e_sat)
    snr_rec = None if u_e_sat_rec is None else float(np.sqrt(u_e_sat_rec))
    q["SNR_max"] = _entry(
        "Maximum signal-to-noise ratio",
        "SNR_max",
        "",
        snr,
        recipe=snr_rec,
        note="SNR_max = sqrt(μe.sat): photon shot noise only",
    )
    q["SNR_max_dB"] = _entry(
        "Maximum SNR in dB",
        "SNR_max.dB",
        "dB",
        20.0 * np.log10(snr),
        bayescap="differs from derived.snr_max_db",
        recipe=None if snr_rec is None else 20.0 * np.log10(snr_rec),
        note="20 log10 SNR_max. bayescap's snr_max_db is the total SNR (PRNU, DSNU, dark noise included) at "
        "the largest non-saturating signal, the charge at the clip: a different point and a different noise",
    )
    q["SNR_max_bit"] = _entry(
        "Maximum SNR in bits",
        "SNR_max.bit",
        "bit",
        np.log2(snr),
        recipe=None if snr_rec is None else float(np.log2(snr_rec)),
        note="log2 SNR_max",
    )
    q["inverse_SNR_max"] = _entry(
        "Inverse maximum SNR",
        "1/SNR_max",
        "%",
        100.0 / snr,
        recipe=None if snr_rec is None else 100.0 / snr_rec,
        note="100/SNR_max",
    )
    lin = sw.linearity()
    if lin is not None:
        dev = lin["deviation_percent"]
        lo_, hi_ = float(dev.min()), float(dev.max())
        le_draws = getattr(result, "derived", {}).get("linearity_error_percent")
        lin_note = (
            f"the measured rows only (no interval): deviations from the standard's line a·μp + b over the {dev.size} "
            "rows between 5 % and 95 % of the saturation signal (relative deviations minimised); "
            + (
                "the fitted response's LE, with its interval, is the LE row"
                if le_draws is not None
                else "the fit has no response non-linearity term (the means are linear within their precision), so "
                "LE is the rows' value; what the rows scatter beyond their noise is mean_discrepancy"
            )
        )
        q["LE_min"] = _entry("Min linearity error", "LE_min", "%", value=lo_, recipe=lo_, note=lin_note)
        q["LE_max"] = _entry("Max linearity error", "LE_max", "%", value=hi_, recipe=hi_, note=lin_note)
        if le_draws is None:
            q["LE"] = _entry(
                "Linearity error",
                "LE",
                "%",
                value=0.5 * (hi_ - lo_),
                recipe=0.5 * (hi_ - lo_),
                note="LE = (max δ_y − min δ_y)/2 over the same rows, from the data (no interval)",
            )
        else:
            q["LE"] = _entry(
                "Linearity error",
                "LE",
                "%",
                np.asarray(le_draws, float),
                recipe=0.5 * (hi_ - lo_),
                bayescap="derived.linearity_error_percent",
                note="the fitted response's LE (the standard's line and δ over 5–95 % of the largest unclipped "
                "signal), with its interval; recipe: (max δ_y − min δ_y)/2 of the measured rows (LE_min, LE_max)",
            )
    sp = sw.spatial
    if "dsnu_e" in p:
        dsnu = np.asarray(p["dsnu_e"], float)
        rec_dn = None
        if sp is not None and np.isfinite(sp["s2_y_dark"]) and sp["s2_y_dark"] >= 0:
            rec_dn = float(np.sqrt(sp["s2_y_dark"]))
        dsnu_note = (
            "spatial standard deviation of the dark signal, temporal noise removed: the same definition. The "
            "standard subtracts σ²_y.stack.dark/L from the measured spatial variance (negative: undefined); bayescap "
            "models both parts (and rounding), so a pattern below the temporal noise is an upper limit, not a NaN"
        )
        if sp is not None and rec_dn is None:
            dsnu_note += f". Here the recipe's spatial variance is negative ({sp['s2_y_dark']:.4g} DN²)"
        q["DSNU1288"] = _entry(
            "DSNU",
            "DSNU1288",
            "e-",
            dsnu,
            bayescap="dsnu_e",
            recipe=None if rec_dn is None else rec_dn * k_med,
            note=dsnu_note,
        )
        q["DSNU1288_DN"] = _entry(
            "DSNU in DN",
            "DSNU1288.DN",
            "DN",
            dsnu * K,
            bayescap="dsnu_e / conversion_gain_e_per_dn",
            recipe=rec_dn,
            note="DSNU1288 in DN",
        )
    if "prnu_percent" in p:
        rec = None
        if sp is not None and np.isfinite(sp["s2_y"]):
            s2d = sp["s2_y_dark"] if np.isfinite(sp["s2_y_dark"]) else 0.0
            if sp["s2_y"] - s2d > 0:
                rec = float(100.0 * np.sqrt(sp["s2_y"] - s2d) / sp["signal_dn"])
        q["PRNU1288"] = _entry(
            "PRNU",
            "PRNU1288",
            "%",
            np.asarray(p["prnu_percent"], float),
            bayescap="prnu_percent",
            recipe=rec,
            note="spatial standard deviation of the photo-response over the mean signal, DSNU and temporal noise "
            "removed: the same definition. The standard takes it at 50 % of saturation; bayescap fits it to "
            "every spatial row. Both see only the pixels of the spatial stack (see spatial_row)",
        )
    if m.terms.dark_current and "dark_current_e_per_s" in p:
        q["u_I_var"] = _entry(
            "Dark current from variance",
            "μ_I.var",
            "e-/s",
            np.asarray(p["dark_current_e_per_s"], float),
            bayescap="dark_current_e_per_s",
            recipe=None if sw.dark_var_slope is None else sw.dark_var_slope / K_rec**2,
            note="dark temporal variance against exposure time, slope/K²: the same definition as bayescap's",
        )
    if sw.dark_mean_slope is not None:
        q["u_I_mean"] = _entry(
            "Dark current from mean",
            "μ_I.mean",
            "e-/s",
            sw.dark_mean_slope * k,
            recipe=sw.dark_mean_slope / K_rec,
            note="slope of the dark mean over exposure time (DN/s, from the data) divided by K per draw; bayescap fits "
            "it only where it agrees with the variances. Differs from μ_I.var where the camera corrects its offset",
        )
    view = json_safe(
        {
            "standard": EMVA_RELEASE,
            "sigma_d_from": sigma_d_from,
            "quantities": q,
            "saturation": {
                "row_index": sw.i_sat,
                "signal_dn": float(sw.signal[sw.i_sat]),
                "reached": bool(sw.saturated),
                "sensitivity_rows": int(sw.sens.sum()),
                "linearity_rows": int(sw.lin.sum()),
                "sweep_rows": int(sw.signal.size),
            },
            "spatial_row": sp,
            "notes": notes,
        }
    )  # limits in the fit JSON's form (bayescap.posterior.emva_limits)
    t_one = float(sw.t[0]) if sw.n_texp == 1 else None
    return attach_limits(view, result.to_dict()["parameters"], exposure_time_s=t_one)
