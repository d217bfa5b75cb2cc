"""A fitted sensor at a photometric exposure H (lux·s): the photon calibration from its rows with
photon counts, and the tonal range and SNR of Eq. 1 at H, per posterior draw (Fig. 8a)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bayescap.exceptions import CompareInputError
from bayescap.physics.capacity import tonal_range
from bayescap.physics.noise import NoiseCoefficients, snr_db
from bayescap.physics.photometry import photons_per_lux_s_um2
from bayescap.posterior import FitResult, summarize
from bayescap.studies.compare_defaults import DEFAULT_MID_GREY


@dataclass(frozen=True)
class ExposureCalibration:
    """Sensitivity in e⁻ per lux·s, per posterior draw (aligned with ``FitResult.draws``)."""

    sensitivity_e_per_lux_s: np.ndarray
    source: str

    def to_dict(self):
        return {"source": self.source, "sensitivity_e_per_lux_s": summarize(self.sensitivity_e_per_lux_s, "e-/(lux·s)")}


def _linear_rows(d, model):
    """Rows usable for a slope: not clipped, below 80 % of the signal at the variance peak."""
    ok = ~np.asarray(model.full_sat, bool)
    if d.frac_saturated is not None:
        ok &= np.asarray(d.frac_saturated) <= 0
    v = np.where(ok, d.temporal_var_dn2, -np.inf)
    s_peak = float(d.signal_dn[int(np.argmax(v))])
    return ok & (d.signal_dn <= 0.8 * s_peak) & (d.signal_dn > 0)


def exposure_calibration(result: FitResult) -> ExposureCalibration | None:
    """The sensitivity (e⁻/lux·s) per draw, or None when the file has no exposure calibration
    (see the module docstring for the order of the sources)."""
    d = result.model.data
    p = result.draws
    n = next(iter(p.values())).size
    if d.exposure_lux_s is not None:
        rows = _linear_rows(d, result.model) & (np.asarray(d.exposure_lux_s) > 0)
        if np.count_nonzero(rows) >= 2:
            h = np.asarray(d.exposure_lux_s)[rows]
            s = np.asarray(d.signal_dn)[rows]
            slope_dn = float(np.sum(h * s) / np.sum(h * h))  # least squares through the origin
            return ExposureCalibration(
                p["conversion_gain_e_per_dn"] * slope_dn,
                f"exposure_lux_s column ({np.count_nonzero(rows)} linear rows) x conversion gain",
            )
    md = result.metadata
    if md.get("sensitivity_e_per_lux_s") not in (None, ""):
        try:
            s = float(md["sensitivity_e_per_lux_s"])
        except (TypeError, ValueError):
            raise CompareInputError(
                f"{d.source}: metadata sensitivity_e_per_lux_s must be a number, got {md['sensitivity_e_per_lux_s']!r}"
            ) from None
        if not (s > 0 and math.isfinite(s)):
            raise CompareInputError(f"{d.source}: metadata sensitivity_e_per_lux_s must be positive, got {s}")
        return ExposureCalibration(np.full(n, s), "sensitivity_e_per_lux_s metadata (fixed value)")
    pitch = md.get("pixel_pitch_um")
    if "quantum_efficiency" in p and pitch:
        per_px = float(photons_per_lux_s_um2(wavelength_nm=555.0)) * float(pitch) ** 2
        return ExposureCalibration(
            p["quantum_efficiency"] * per_px,
            f"photons_per_pixel column: QE x {per_px:.0f} photons/(lux·s) per "
            f"{float(pitch):g} µm pixel (Eq. 4, 555 nm)",
        )
    return None


def _coefficients(result: FitResult, p) -> NoiseCoefficients:
    """Eq. 1's coefficients of the draws ``p`` ({name: (n,)}) at the result's scene, as columns
    (n, 1) that broadcast against a row of signals or exposures."""
    col = {k: np.asarray(v, float)[:, None] for k, v in p.items()}
    return result._noise_coefficients(col, result.scene.exposure_time_s)


def tonal_range_at_exposure(
    result: FitResult,
    h0_lux_s,
    *,
    calibration: ExposureCalibration | None = None,
    mid_grey: float = DEFAULT_MID_GREY,
    idx=None,
):
    """TR (grey levels, 8-bit-equivalent scale) at average exposures ``h0_lux_s``, per draw.

    Returns ``(tr, s_max_e)``, each of shape ``(n_draws, n_h0)`` (``n_h0`` = 1 for a scalar).
    ``S_max = min(clip, sensitivity·H₀/mid_grey)``; TR is Eq. 7 over ``[σ(0), S_max]`` with the
    quantization term ``K²/12`` of the fit scaled by the analog gain ``g = clip/S_max``.
    ``idx`` selects draws (e.g. ``result.thin_index(n)``). Vectorised: no loop over draws.
    """
    if not (0 < mid_grey <= 1):
        raise CompareInputError(f"mid-grey fraction must be in (0, 1], got {mid_grey}")
    cal = calibration if calibration is not None else exposure_calibration(result)
    if cal is None:
        raise CompareInputError(
            f"{result.model.data.source}: no exposure calibration (exposure_lux_s "
            "column, photons_per_pixel with pixel_pitch_um, or sensitivity_e_per_lux_s)"
        )
    sel = slice(None) if idx is None else idx
    p = {k: v[sel] for k, v in result.draws.items()}
    sens = np.asarray(cal.sensitivity_e_per_lux_s)[sel][:, None]
    h = np.atleast_1d(np.asarray(h0_lux_s, float))[None, :]
    if np.any(~(h > 0)):
        raise CompareInputError(f"H0 must be positive (lux·s), got {h0_lux_s}")
    clip, _ = result.signal_max_e(p)
    clip = np.asarray(clip, float)[:, None]
    with np.errstate(over="ignore"):  # an H0 of 1e308 lux·s: every pixel at the clip, as meant
        s_max = np.minimum(clip, sens * h / mid_grey)
    k = np.asarray(p["conversion_gain_e_per_dn"], float)[:, None]
    gain = clip / s_max
    tr = tonal_range(_coefficients(result, p).with_quantization(k, k / gain), s_max)
    return np.asarray(tr, float), s_max


def snr_at_exposure(result: FitResult, h_lux_s, *, calibration: ExposureCalibration | None = None, idx=None):
    """SNR (dB, Eq. 1) against photometric exposure H (lux·s), per draw: ``(n_draws, n_h)``;
    NaN where the signal passes the clip (Figs. 5-6)."""
    cal = calibration if calibration is not None else exposure_calibration(result)
    if cal is None:
        raise CompareInputError(f"{result.model.data.source}: no exposure calibration")
    sel = slice(None) if idx is None else idx
    p = {k: v[sel] for k, v in result.draws.items()}
    s = np.asarray(cal.sensitivity_e_per_lux_s)[sel][:, None] * np.atleast_1d(np.asarray(h_lux_s, float))[None, :]
    coeffs = _coefficients(result, p)
    clip, _ = result.signal_max_e(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = snr_db(coeffs, s)
    return np.where(s <= np.asarray(clip)[:, None], out, np.nan)
