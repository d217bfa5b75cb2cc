"""CS over many posterior draws: the quadrature on a pilot subset, a checked linear map for the rest.

Over a posterior, CS is a smooth function of a draw's inputs (the R, G, B noise coefficients, the
clip levels, the CCM and white-balance elements), and the posterior is narrow: across the draws CS
is linear in those inputs to within the quadrature's own per-draw error (the simulated cameras of
``benchmarks/colour_cfa_speed.py``: a least-squares fit on 128 of 1000 draws predicts the other 872
with a residual sd of 7·10⁻⁴ bits, the 40-node rule's scatter about a 128-node one, against CS's
posterior sd of 0.026 bits). So :func:`colour_sensitivity_emulated` evaluates CS exactly
(:func:`~bayescap.colour.sensitivity.colour_sensitivity`) on ``n_pilot`` evenly spaced draws, fits
CS on the pilots' inputs by least squares, and gives every draw the fitted value.

The check, every call: the pilots' leave-one-out residuals (exact for least squares: the residual
over ``1 − h_ii``, ``h`` the hat matrix's diagonal) estimate the map's error on a draw it was not fitted
on. The map is used only when their root mean square is at most ``max_resid_frac`` (default 0.1) of
the pilots' CS sd (or below 10⁻⁶ bits), so that it adds at most 1 % to the variance of the draws'
CS; otherwise, and wherever the map cannot be fitted (fewer than twice as many pilots as inputs, a
non-finite CS), every draw is evaluated exactly. What was done, with the residual, is stated in the
result's ``choices``.
"""

from __future__ import annotations

import numpy as np

from bayescap.colour.sensitivity import ColourSensitivity, checked_inputs, colour_sensitivity

__all__ = ["colour_sensitivity_emulated", "EMULATOR_PILOTS", "EMULATOR_MAX_RESID_FRAC"]

#: draws evaluated exactly (at least twice the map's ~25 inputs, for its leave-one-out check)
EMULATOR_PILOTS = 128
#: the largest leave-one-out residual rms, as a fraction of the pilots' CS sd, at which the map is used
EMULATOR_MAX_RESID_FRAC = 0.1


def _inputs(var_coeffs_dn2, clip_dn, ccm, wb_gains) -> np.ndarray:
    """Per draw what CS depends on (n, 24): log c0, √c1, √c2 of R, G, B, log of their clips, the CCM's
    and the white balance's elements; every draw checked as the quadrature checks its inputs."""
    rgb, clip3, ccm_d, wb_d = checked_inputs(var_coeffs_dn2, clip_dn, ccm, wb_gains)
    n = rgb.shape[0]
    return np.column_stack(
        [np.log(rgb[..., 0]), np.sqrt(rgb[..., 1]), np.sqrt(rgb[..., 2]), np.log(clip3), ccm_d.reshape(n, 9), wb_d]
    )


def _linear_fit(x_pilot, y, x_all):
    """Least squares of ``y`` on ``[1, x]`` (standardised columns; constant ones dropped; the SVD's
    rank): (the fitted values at ``x_all``, the leave-one-out residuals, the rank)."""
    mu = x_pilot.mean(axis=0)
    sd = x_pilot.std(axis=0)
    keep = sd > 1e-12 * np.maximum(np.abs(mu), 1.0)
    scale = np.where(keep, sd, 1.0)[keep]
    z = np.column_stack([np.ones(len(y)), (x_pilot[:, keep] - mu[keep]) / scale])
    u, s, vt = np.linalg.svd(z, full_matrices=False)
    r = int(np.sum(s > s[0] * 1e-10))
    u, s, vt = u[:, :r], s[:r], vt[:r]
    beta = vt.T @ ((u.T @ y) / s)
    h = np.sum(u * u, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        loo = (y - z @ beta) / (1.0 - h)
    z_all = np.column_stack([np.ones(len(x_all)), (x_all[:, keep] - mu[keep]) / scale])
    return z_all @ beta, loo, r


def colour_sensitivity_emulated(
    var_coeffs_dn2,
    clip_dn,
    ccm,
    wb_gains,
    *,
    n_pilot: int = EMULATOR_PILOTS,
    max_resid_frac: float = EMULATOR_MAX_RESID_FRAC,
    **kw,
) -> ColourSensitivity:
    """CS per draw as :func:`~bayescap.colour.sensitivity.colour_sensitivity` (same arguments; ``kw``
    its keywords), computed exactly on ``n_pilot`` of the draws and by a checked linear map of the
    draws' inputs on every draw (module docstring). ``choices["evaluation"]`` says which was used,
    ``choices["emulator"]`` the map's check (pilots, inputs, leave-one-out residual rms in bits and
    as a fraction of CS's sd)."""
    x = _inputs(var_coeffs_dn2, clip_dn, ccm, wb_gains)
    n = x.shape[0]

    def exact(reason):
        cs = colour_sensitivity(var_coeffs_dn2, clip_dn, ccm, wb_gains, **kw)
        cs.choices["evaluation"] = f"the quadrature on every draw ({reason})"
        cs.choices["emulator"] = None
        return cs

    if n < 2 * n_pilot:
        return exact(f"{n} draws: no fewer with the linear map's {n_pilot} pilots")
    pick = np.linspace(0, n - 1, n_pilot).round().astype(int)

    def sub(a, shape):
        a = np.asarray(a, float)
        return a[pick] if a.ndim == len(shape) + 1 else a

    v = np.asarray(var_coeffs_dn2, float)
    clip = np.asarray(clip_dn, float)
    pilot = colour_sensitivity(
        v[pick], clip[pick] if clip.ndim >= 1 else clip, sub(ccm, (3, 3)), sub(wb_gains, (3,)), **kw
    )
    y = pilot.bits
    if not np.all(np.isfinite(y)):
        return exact("a pilot draw's CS is not finite")
    if 2 * (x.shape[1] + 1) > n_pilot:
        return exact(f"{n_pilot} pilots for {x.shape[1]} inputs")
    fitted, loo, rank = _linear_fit(x[pick], y, x)
    rms = float(np.sqrt(np.mean(loo**2))) if np.all(np.isfinite(loo)) else float("inf")
    sd = float(np.std(y, ddof=1))
    frac = rms / sd if sd > 0 else (0.0 if rms == 0 else float("inf"))
    check = {  # (None where not finite: the JSON carries it)
        "pilots": int(n_pilot),
        "inputs": int(rank - 1),
        "loo_resid_rms_bits": rms if np.isfinite(rms) else None,
        "pilot_cs_sd_bits": sd,
        "loo_resid_frac_of_sd": frac if np.isfinite(frac) else None,
        "max_resid_frac": float(max_resid_frac),
    }
    if not (rms <= max_resid_frac * sd or rms <= 1e-6):
        cs = exact(
            f"the linear map's leave-one-out residual rms {rms:.2g} bits is {frac:.2g} of CS's sd over "
            f"{n_pilot} pilots, above {max_resid_frac:g}"
        )
        cs.choices["emulator"] = check
        return cs
    choices = dict(pilot.choices)
    choices["evaluation"] = (
        f"the quadrature on {n_pilot} evenly spaced pilot draws, every draw's CS from a least-squares linear map "
        f"of its inputs (log c0, √c1, √c2 and log clip of R, G, B; CCM and white-balance elements) fitted on them: "
        f"leave-one-out residual rms {rms:.2g} bits, {frac:.2g} of CS's sd (used at ≤ {max_resid_frac:g})"
    )
    choices["emulator"] = check
    return ColourSensitivity(bits=fitted, choices=choices)
