"""The four CFA channels' separate fits as the draws the colour functions take.

When R, Gr, Gb and B are fitted separately (one :func:`bayescap.fit` per channel), their posteriors
are independent, so draws paired by index are draws of the joint posterior. This gathers, per draw,
the noise model in DN (:func:`bayescap.colour.scores.var_coeffs_from_fit`), the clip, each channel's
tonal range bits (Eq. 7, 8-bit floor) and MTF loss (Eq. 9), in the layout of
:func:`bayescap.colour.sensitivity.colour_sensitivity` and
:func:`bayescap.colour.capacity.colour_capacities`.
"""

from __future__ import annotations

import numpy as np

from bayescap.colour.scores import var_coeffs_from_fit

__all__ = ["CFA_CHANNELS", "channel_draws"]

CFA_CHANNELS = ("R", "Gr", "Gb", "B")


def channel_draws(results: dict, n_draws: int = 1000) -> dict:
    """``results``: {"R", "Gr", "Gb", "B"} → FitResult. Returns ``var_coeffs_dn2`` (n, 4, 3),
    ``clip_dn`` (n, 4), ``tonal_range_bits`` (n, 4), ``mtf_loss_bits`` (n, 4), ``notes`` (limits,
    unconverged fits) and ``n_draws`` (the smallest thinned count over the channels)."""
    missing = [c for c in CFA_CHANNELS if c not in results]
    if missing:
        raise ValueError(f"channel fits missing: {', '.join(missing)} (need R, Gr, Gb, B)")
    parts = {k: [] for k in ("var_coeffs_dn2", "clip_dn", "tonal_range_bits", "mtf_loss_bits")}
    notes = []
    for c in CFA_CHANNELS:
        r = results[c]
        idx = r.thin_index(n_draws)
        co, clip, lower = var_coeffs_from_fit(r, idx)
        if lower:
            notes.append(f"{c}: no row reaches the clip; the clip (and CS) is a lower bound")
        if not r.diag.get("converged"):
            notes.append(f"{c}: the fit did not converge")
        parts["var_coeffs_dn2"].append(co)
        parts["clip_dn"].append(clip)
        parts["tonal_range_bits"].append(np.asarray(r.derived["tonal_range_bits"])[idx])
        parts["mtf_loss_bits"].append(np.asarray(r.derived["mtf_loss_bits"])[idx])  # per draw, as tonal range
    n = min(len(x) for x in parts["clip_dn"])
    out = {k: np.stack([x[:n] for x in v], axis=1) for k, v in parts.items()}
    out["notes"] = notes
    out["n_draws"] = n
    return out
