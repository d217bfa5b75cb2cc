"""Whether the data see a dark current: the data's own rule, not a fixed ratio.

A dark current ``D`` has two witnesses (EMVA 1288 reports both): the dark *variances* rise as
``D·t/K²`` (always in the likelihood) and the dark *means* as ``D·t/K`` above the black level
(very precise, but a black level that drifts or is clamped with time moves them too; in the
likelihood only where the two agree: :mod:`bayescap.model.dark_ramp`). The fit's
``dark_current_e_per_s`` is printed as a detection (a median with its 95 % interval) only when

1. **the posterior excludes zero**: the marginal likelihood of ``D`` (its posterior density divided by
   the prior's, estimated from the draws with a boundary-reflected kernel density) is at ``D = 0``
   below :data:`ZERO_LIKELIHOOD_RATIO` of its maximum, i.e. zero lies outside the 95 % likelihood
   interval (2·Δln L > 3.84; for a normal posterior: the median ≥ 1.96 sd above zero);
2. **the dark ramp stands out of its noise in a predictive check**: the weighted slope of the dark
   variances against the exposure time is at least :data:`RAMP_Z` standard errors above zero, each
   row's error the one the fitted model predicts for it (its Gamma shape, with the rounding's φ and
   the fitted discrepancy), i.e. ``D = 0`` would give so steep a ramp once in 700 sensors;
3. **the dark means do not contradict it**: where the means follow a shift one for one (the pixels
   spread over ≥ 0.5 DN about the DN grid: :func:`mean_ramp`), a dark current above the means' 97.5 % bound is not a detection
   (the means are flat where the variances rise: a clamped black level, or variances that rise for
   another reason). Means that rise faster than the variances allow (a drifting black level, a light
   leak) never make a detection: they are noted only.

Otherwise the dark current is an upper limit, the posterior's 95 % point, with a note saying which
test decided. :func:`dark_current_evidence` computes all three; :func:`dark_witness_notes` turns a
disagreement of the two witnesses into a flag and a note.
"""

from __future__ import annotations

import math

import numpy as np

from bayescap.model.dark_ramp import mean_ramp

__all__ = [
    "ZERO_LIKELIHOOD_RATIO",
    "RAMP_Z",
    "MEAN_Z",
    "zero_likelihood_ratio",
    "variance_ramp",
    "mean_ramp",
    "dark_current_evidence",
    "dark_witness_notes",
]

#: zero is outside the 95 % likelihood interval when the likelihood there is below this fraction of
#: its maximum: exp(−χ²₁(0.95)/2), 2·Δln L = 3.84
ZERO_LIKELIHOOD_RATIO = math.exp(-3.841458820694124 / 2.0)

#: the dark variances' ramp must be this many standard errors above zero (one-sided 0.13 %): at the
#: 95 % level (1.96) one invisible dark current in 40 would still be claimed, with an interval that
#: excludes its truth (issue 51's 8-bit sensor on one of its seeds: a 2.4 sd ramp)
RAMP_Z = 3.0

#: the dark means contradict the variances' dark current when their 97.5 % bound lies below its 95 %
#: interval (or their 2.5 % bound above it)
MEAN_Z = 1.959963984540054

#: draws the density is estimated from (evenly thinned; the bandwidth's sample size is capped at
#: this, as MCMC draws are autocorrelated)
_KDE_DRAWS = 4000


def zero_likelihood_ratio(x, prior_scale=None) -> float:
    """L(0) / max L of the marginal likelihood of a non-negative parameter from its posterior draws
    ``x``: the posterior density over the prior's (half-normal of ``prior_scale``; flat when None),
    estimated by a Gaussian kernel density reflected at 0 on a grid up to the draws' 99.5 % point.
    Near 1 when the posterior does not fall towards zero; near 0 when it excludes it."""
    x = np.asarray(x, float).ravel()
    x = x[np.isfinite(x)]
    if x.size < 10:
        return float("nan")
    x = np.maximum(x, 0.0)
    if x.size > _KDE_DRAWS:
        x = np.sort(x)[np.linspace(0, x.size - 1, _KDE_DRAWS).round().astype(int)]
    hi = float(np.quantile(x, 0.995))
    if not hi > 0:
        return 1.0  # every draw at zero
    sd = float(np.std(x))
    iqr = float(np.subtract(*np.quantile(x, [0.75, 0.25])))
    spread = min(sd, iqr / 1.349) if iqr > 0 else sd
    h = 0.9 * spread * x.size ** (-0.2)  # Silverman's rule
    h = max(h, 1e-3 * hi)
    w = np.ones_like(x)
    if prior_scale:
        w = np.exp(np.minimum(0.5 * (x / prior_scale) ** 2, 50.0))  # 1/prior, up to a constant
    # the reflected kernel sum on a grid from 0 to hi: the draws binned linearly onto a grid 8× finer
    # than the kernel's width (a relative error ~(spacing/h)²/12 < 1e-3), mirrored at 0, and
    # convolved with the sampled kernel by FFT: ~30× cheaper than the direct sum over 4 000 draws
    top = hi + 5.0 * h
    n = int(min(max(np.ceil(8.0 * top / h), 256), 1 << 16))
    dg = top / n
    keep = x <= top
    u = x[keep] / dg
    j = np.minimum(u.astype(np.intp), n - 1)
    frac = u - j
    c = np.bincount(j, w[keep] * (1.0 - frac), minlength=n + 1) + np.bincount(j + 1, w[keep] * frac, minlength=n + 1)
    c = c[: n + 1]
    mirrored = np.concatenate([c[:0:-1], [2.0 * c[0]], c[1:]])  # nodes −n..n (node 0 is its own mirror)
    m = int(min(np.ceil(5.0 * h / dg), n))
    kern = np.exp(-0.5 * (np.arange(-m, m + 1) * dg / h) ** 2)
    size = mirrored.size + kern.size - 1
    nfft = 1 << (size - 1).bit_length()
    full = np.fft.irfft(np.fft.rfft(mirrored, nfft) * np.fft.rfft(kern, nfft), nfft)[:size]
    f = np.maximum(full[m + n : m + n + int(np.floor(hi / dg)) + 1], 0.0)  # nodes 0..hi (FFT round-off below 0)
    peak = float(np.max(f))
    return float(f[0] / peak) if peak > 0 else float("nan")


def variance_ramp(model, theta):
    """How far the dark variances' rise with the exposure time stands out of their noise, as the model
    sees it (its rounding moments, read noise and DSNU included): ``(z, 1.0)`` with z = ±√Δχ², Δχ² the
    drop in the dark rows' χ² (each row's error the model's own, sd = model variance / √k at ``theta``)
    from the best model with D = 0, its read noise free to take up the mean D·t (profiled on a grid),
    to the model at ``theta``; the sign is that of the fitted rise. A raw slope of the variances
    against t would mistake the rounding's swing of a sub-DN dark variance for a ramp (or a fall).
    None with fewer than three rows, two exposure times or no dark-current coordinate."""
    idx = getattr(model, "idx", {})
    if np.unique(model.t).size < 2 or "log_dc" not in idx or "log_read" not in idx:
        return None
    th = np.asarray(theta, float).reshape(1, -1)
    read2 = math.exp(2.0 * th[0, idx["log_read"]])
    dt_max = math.exp(th[0, idx["log_dc"]]) * float(np.nanmax(model.t))
    grid = np.tile(th, (65, 1))  # D = 0; read² from the fitted read² to read² + D·t_max
    grid[:, idx["log_dc"]] = math.log(1e-12)
    grid[:, idx["log_read"]] = 0.5 * np.log(read2 + np.linspace(0.0, 1.0, 65) * dt_max)
    with np.errstate(all="ignore"):
        obs, pred, shape, _ = model.predict(th)["dark_var"]
        _, pred0, _, _ = model.predict(grid)["dark_var"]
    pred = np.asarray(pred, float)
    k = np.broadcast_to(np.asarray(shape, float), pred.shape)[0]
    obs = np.broadcast_to(np.asarray(obs, float), pred.shape)[0]
    pred, pred0 = pred[0], np.asarray(pred0, float)
    sd = pred / np.sqrt(k)
    ok = np.isfinite(obs) & np.isfinite(pred) & np.all(np.isfinite(pred0), axis=0) & (sd > 0)
    if ok.sum() < 3:
        return None
    chi2_0 = np.min(np.sum(((obs - pred0)[:, ok] / sd[ok]) ** 2, axis=1))
    d_chi2 = float(chi2_0 - np.sum(((obs - pred)[ok] / sd[ok]) ** 2))
    return (math.sqrt(d_chi2) if d_chi2 > 0 else -math.sqrt(-d_chi2), 1.0)


def dark_current_evidence(result) -> dict | None:
    """The three tests of the module docstring for ``result``'s dark current (None when the model
    has no dark-current term): ``{"zero_likelihood_ratio", "ramp_z", "mean_d_e_per_s",
    "mean_d_sd_e_per_s", "interval_e_per_s", "detected", "why"}``; the dark means' D is
    in e⁻/s (K at its posterior median). ``detected`` is None under a log-uniform prior on bounds
    (``dark_current_log_bounds``), which excludes zero by itself: the generic rule then decides."""
    m = result.model
    if not m.terms.dark_current:
        return None
    draws = result.summary_draws()
    x = np.asarray(draws["dark_current_e_per_s"], float)
    k = float(np.median(draws["conversion_gain_e_per_dn"]))
    bounds = m.PRIOR.get("dark_current_log_bounds")
    lr = float("nan") if bounds is not None else zero_likelihood_ratio(x, m.PRIOR["dark_current_scale_e_per_s"])
    theta = _median_theta(result)
    vr = variance_ramp(m, theta) if theta is not None else None
    ramp_z = float(vr[0] / vr[1]) if vr is not None and vr[1] > 0 else float("nan")
    mr = mean_ramp(m.data)
    lo, hi = (float(v) for v in np.quantile(x, [0.025, 0.975]))
    out = {
        "zero_likelihood_ratio": lr,
        "ramp_z": ramp_z,
        "mean_d_e_per_s": None if mr is None else mr[0] * k,
        "mean_d_sd_e_per_s": None if mr is None else mr[1] * k,
        "interval_e_per_s": [lo, hi],
    }
    if bounds is not None:
        # a log-uniform prior on [lo, hi] (a user's, or simulation-based calibration's) has declared
        # D ≥ lo > 0: whether D is distinguishable from zero is not a question it lets the data answer
        out["detected"] = None
        out["why"] = "a log-uniform prior on bounds: no zero to test"
        return out
    why = []
    if not (lr < ZERO_LIKELIHOOD_RATIO):
        why.append(
            f"the posterior does not exclude zero (the likelihood at D = 0 is {lr:.2f} of its maximum, "
            f"above {ZERO_LIKELIHOOD_RATIO:.3f})"
        )
    if not (ramp_z >= RAMP_Z):
        why.append(
            f"the dark variances rise with the exposure time by only {ramp_z:.2f} standard errors "
            f"(a detection needs {RAMP_Z:.2f})"
            if np.isfinite(ramp_z)
            else "the dark variances' ramp is not measured (fewer than three dark rows)"
        )
    if mr is not None and not why:
        bound = out["mean_d_e_per_s"] + MEAN_Z * out["mean_d_sd_e_per_s"]
        if bound < lo:
            why.append(
                f"the dark means stay flat: they rise by {out['mean_d_e_per_s']:.3g} ± "
                f"{out['mean_d_sd_e_per_s']:.2g} e-/s, below the variances' 95 % interval "
                f"[{lo:.3g}, {hi:.3g}] (a clamped black level, or variances that rise for another reason)"
            )
    out["detected"] = not why
    out["why"] = "; ".join(why)
    return out


def _median_theta(result):
    """The coordinate-wise median of the posterior draws in sampling coordinates (None without chains)."""
    c = getattr(result, "chains", None)
    if c is None or getattr(c, "chain", None) is None:
        return None
    ch = np.asarray(c.chain)
    return np.median(ch.reshape(-1, ch.shape[-1]), axis=0)


def dark_witness_notes(ev: dict) -> tuple[str | None, str | None]:
    """(flag, note) when the dark means and the dark variances disagree about the dark current
    (``ev`` of :func:`dark_current_evidence`), else (None, None): ``dark_mean_flat`` (the means stay
    below the variances' interval: a clamped black level?) or ``dark_mean_rises`` (the means rise
    above it: a drifting black level or a light leak?)."""
    if ev is None or ev.get("mean_d_e_per_s") is None:
        return None, None
    dm, sd = ev["mean_d_e_per_s"], ev["mean_d_sd_e_per_s"]
    lo, hi = ev["interval_e_per_s"]
    if dm + MEAN_Z * sd < lo and ev["ramp_z"] >= RAMP_Z and ev["zero_likelihood_ratio"] < ZERO_LIKELIHOOD_RATIO:
        return "dark_mean_flat", (
            f"the dark means rise by {dm:.3g} ± {sd:.2g} e-/s, below the dark variances' dark current "
            f"[{lo:.3g}, {hi:.3g}] e-/s: the two witnesses disagree (a black level clamped as the dark "
            "signal grows?); the dark current is printed as an upper limit"
        )
    if dm - MEAN_Z * sd > hi:
        return "dark_mean_rises", (
            f"the dark means rise by {dm:.3g} ± {sd:.2g} e-/s, above the dark variances' dark current "
            f"[{lo:.3g}, {hi:.3g}] e-/s: the black level drifts with the exposure time (or light leaks "
            "in); the dark current is taken from the variances"
        )
    return None, None
