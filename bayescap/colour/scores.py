"""Camera scores users know (DxOMark's sensor scores), per draw, with printed definitions.

* Colour depth: CS at base gain (bits); and normalised to an 8-Mpixel print, ``CS + 3 · ½·log₂(N/8·10⁶)``
  (each of the three channels' noise shrinks by ``√(N/8·10⁶)`` when N pixels are printed at 8 Mpixel).
* Dynamic range (EV): ``log₂(clip / σ(0))`` per channel (raw signal above black over the dark noise),
  and print-normalised ``+ ½·log₂(N/8·10⁶)``.
* SNR at 18 % grey (dB): ``20·log₁₀(S/σ(S))`` at ``S = 0.18 · clip``.
* Low-light ISO: from a gain series (one fit per ISO), the ISO at which SNR 18 % falls to 30 dB,
  DR to 9 EV or CS to 18 bits, by linear interpolation in log₂ ISO between the two settings that
  bracket the threshold, per draw. Where the threshold is not crossed inside the series, the draw's
  value is a limit (above the highest ISO measured or below the lowest) and is reported as such.

Every function takes the noise model as in :mod:`bayescap.colour.sensitivity`: per channel
``σ²(S) = c0 + c1·S + c2·S²`` (DN²) at raw signal S (DN above black) and the clip (DN).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SCORE_DEFINITIONS",
    "LOW_LIGHT_THRESHOLDS",
    "PRINT_PIXELS",
    "colour_depth",
    "dynamic_range_ev",
    "snr_18_db",
    "low_light_iso",
    "var_coeffs_from_fit",
]

PRINT_PIXELS = 8e6
LOW_LIGHT_THRESHOLDS = {"snr_18_db": 30.0, "dynamic_range_ev": 9.0, "colour_depth_bits": 18.0}
SCORE_DEFINITIONS = {
    "colour_depth_bits": "colour sensitivity CS at base gain (bits)",
    "colour_depth_print_bits": "CS + 1.5·log2(N/8e6): CS at an 8-Mpixel print (½·log2(N/8e6) per channel)",
    "dynamic_range_ev": "log2(clip / σ(0)): raw clip over the dark noise, per channel (EV)",
    "dynamic_range_print_ev": "log2(clip / σ(0)) + ½·log2(N/8e6): at an 8-Mpixel print (EV)",
    "snr_18_db": "20·log10(S/σ(S)) at S = 18 % of the clip (dB)",
    "low_light_iso": "ISO at which SNR 18 % falls to 30 dB, DR to 9 EV or CS to 18 bits "
    "(linear in log2 ISO between the bracketing settings; a limit outside the series)",
}


def _coeffs(var_coeffs_dn2):
    v = np.asarray(var_coeffs_dn2, float)
    if v.shape[-1] != 3:
        raise ValueError(f"var_coeffs_dn2 must end in (c0, c1, c2), got shape {v.shape}")
    return v[..., 0], v[..., 1], v[..., 2]


def colour_depth(cs_bits, n_pixels) -> dict:
    """Colour depth draws: as measured and normalised to an 8-Mpixel print (bits)."""
    cs = np.asarray(cs_bits, float)
    shift = 1.5 * np.log2(float(n_pixels) / PRINT_PIXELS)
    return {"colour_depth_bits": cs, "colour_depth_print_bits": cs + shift}


def dynamic_range_ev(var_coeffs_dn2, clip_dn, n_pixels=None):
    """DR (EV) = log₂(clip/σ(0)), per draw and channel (shape of ``clip_dn``); with ``n_pixels``
    a pair (as measured, print-normalised)."""
    c0, _, _ = _coeffs(var_coeffs_dn2)
    dr = np.log2(np.asarray(clip_dn, float) / np.sqrt(c0))
    if n_pixels is None:
        return dr
    return dr, dr + 0.5 * np.log2(float(n_pixels) / PRINT_PIXELS)


def snr_18_db(var_coeffs_dn2, clip_dn, grey: float = 0.18):
    """SNR (dB) at ``grey`` × clip, per draw and channel."""
    c0, c1, c2 = _coeffs(var_coeffs_dn2)
    s = grey * np.asarray(clip_dn, float)
    return 20.0 * np.log10(s / np.sqrt(c0 + c1 * s + c2 * s * s))


def low_light_iso(iso, metric_draws, threshold: float) -> dict:
    """ISO at which a metric that falls with ISO reaches ``threshold``, per draw.

    ``iso``: (n_settings,) increasing; ``metric_draws``: (n_settings, n_draws) (draws at each
    setting paired by index: independent fits give independent draws). Returns ``draws`` (NaN where
    the draw is a limit), ``above`` (the metric is still above the threshold at the highest ISO:
    low-light ISO > max ISO), ``below`` (already below at the lowest: < min ISO), and a summary
    (median and 95 % interval of the draws that cross, and the fractions that are limits)."""
    iso = np.asarray(iso, float)
    m = np.asarray(metric_draws, float)
    if iso.ndim != 1 or iso.size < 2 or np.any(np.diff(iso) <= 0) or np.any(iso <= 0):
        raise ValueError("iso must hold at least two increasing positive settings")
    if m.ndim != 2 or m.shape[0] != iso.size:
        raise ValueError(f"metric_draws must have shape (n_settings, n_draws) = ({iso.size}, n), got {m.shape}")
    x = np.log2(iso)
    above = m[-1] > threshold
    below = m[0] <= threshold
    out = np.full(m.shape[1], np.nan)
    done = above | below
    for i in range(iso.size - 1):
        cross = ~done & (m[i] > threshold) & (m[i + 1] <= threshold)
        frac = (m[i, cross] - threshold) / (m[i, cross] - m[i + 1, cross])
        out[cross] = np.exp2(x[i] + frac * (x[i + 1] - x[i]))
        done |= cross
    # a non-monotone draw that re-crosses is taken at its first crossing; none left undecided
    ok = out[np.isfinite(out)]
    summary = {
        "threshold": threshold,
        "median": float(np.median(ok)) if ok.size else None,
        "interval_95": np.quantile(ok, [0.025, 0.975]).tolist() if ok.size else None,
        "frac_above_max_iso": float(np.mean(above)),
        "frac_below_min_iso": float(np.mean(below)),
        "iso_range": [float(iso[0]), float(iso[-1])],
    }
    if summary["frac_above_max_iso"] > 0.5:
        summary["limit"] = f"> ISO {iso[-1]:g} (the metric stays above {threshold:g} over the series)"
    elif summary["frac_below_min_iso"] > 0.5:
        summary["limit"] = f"< ISO {iso[0]:g} (the metric is below {threshold:g} at the lowest ISO)"
    return {"draws": out, "above": above, "below": below, "summary": summary}


def var_coeffs_from_fit(result, idx=None):
    """A monochrome fit's noise model in DN: ``(coeffs (n, 3), clip_dn (n,), clip_is_lower_bound)``.

    ``coeffs`` = (a/K², 1/K, c) from the fit's Eq. 1 coefficients (a includes dark noise, DSNU and
    the K²/12 rounding; c = PRNU²) at the fit's scene, ``clip_dn`` = the largest non-saturating
    signal / K. ``idx`` selects draws (e.g. ``result.thin_index(n)``)."""
    p = result.draws if idx is None else {k: np.asarray(v)[idx] for k, v in result.draws.items()}
    coeffs = result._noise_coefficients(p, result.scene.exposure_time_s)
    k = np.asarray(p["conversion_gain_e_per_dn"], float)
    s_max_e, lower = result.signal_max_e(p)
    a = np.broadcast_to(coeffs.a, k.shape) / k**2
    c = np.broadcast_to(coeffs.c, k.shape)
    return np.stack([a, np.broadcast_to(coeffs.b, k.shape) / k, c], axis=1), np.asarray(s_max_e) / k, bool(lower)
