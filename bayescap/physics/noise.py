"""The sensor noise model, Eq. 1 of Tisse, Guichard & Cao (2008), in electrons.

The temporal and fixed-pattern noise of a pixel at mean signal ``S`` (e⁻) is quadratic in ``S``:

    σ²(S) = a + b·S + c·S²,  a = σ_read² + D·t + σ_DSNU² + K²/12,  b = 1,  c = PRNU²

(read noise, dark-current shot noise, DSNU and quantization; photon shot noise; PRNU as a
fraction). Everything is vectorised over a leading axis of posterior draws. The capacity
integrals (:mod:`bayescap.physics.capacity`), the photometry (:mod:`bayescap.physics.photometry`)
and the comparisons use this one definition; the likelihood (:mod:`bayescap.model`) takes its dark
part σ_read² + D·t from :func:`dark_variance_e2`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "NoiseCoefficients",
    "snr_db",
    "dynamic_range_db",
    "quantization_variance_e2",
    "dark_variance_e2",
    "variance_terms",
]


def quantization_variance_e2(conversion_gain_e_per_dn):
    """The quantization term of Eq. 1, ``K²/12`` (e⁻²) for a step of ``K`` e⁻/DN."""
    k = np.asarray(conversion_gain_e_per_dn, float)
    return k * k / 12.0


def dark_variance_e2(
    read_noise_e=None, dark_current_e_per_s=0.0, exposure_time_s=0.0, *, dark_current_factor=1.0, dark_noise_e=None
):
    """``σ_read² + f·D·t`` (e⁻²): read noise and dark-current shot noise, the dark current scaled by
    ``dark_current_factor`` ``f`` (a temperature away from the calibration's); ``dark_noise_e²`` when
    ``dark_noise_e`` is given (only their sum identifiable). Broadcasts over its arguments."""
    if dark_noise_e is not None:
        return np.asarray(dark_noise_e, float) ** 2
    return (
        np.asarray(read_noise_e, float) ** 2
        + dark_current_factor * np.asarray(dark_current_e_per_s, float) * exposure_time_s
    )


def variance_terms(
    signal_e,
    *,
    conversion_gain_e_per_dn,
    read_noise_e=None,
    dark_current_e_per_s=0.0,
    exposure_time_s=0.0,
    dark_current_factor=1.0,
    dark_noise_e=None,
    dsnu_e=None,
    prnu_frac=None,
) -> dict:
    """Each term of Eq. 1 at signal ``signal_e`` (e⁻), in e⁻², in the order of the sum:
    ``photon_shot``, then ``read`` and ``dark_current_shot`` (or ``read_plus_dark`` when
    ``dark_noise_e`` stands for their sum), ``dsnu`` and ``prnu`` when given, ``quantization``."""
    s = np.asarray(signal_e, float)
    terms = {"photon_shot": s}
    if dark_noise_e is None:
        terms["read"] = np.asarray(read_noise_e, float) ** 2
        terms["dark_current_shot"] = dark_current_factor * np.asarray(dark_current_e_per_s, float) * exposure_time_s
    else:
        terms["read_plus_dark"] = np.asarray(dark_noise_e, float) ** 2
    if dsnu_e is not None:
        terms["dsnu"] = np.asarray(dsnu_e, float) ** 2
    if prnu_frac is not None:
        terms["prnu"] = (np.asarray(prnu_frac, float) * s) ** 2
    terms["quantization"] = quantization_variance_e2(conversion_gain_e_per_dn)
    return terms


@dataclass(frozen=True)
class NoiseCoefficients:
    """σ²(S) = a + b·S + c·S² in e⁻², vectorised over draws."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray

    def with_quantization(self, old_step_e, new_step_e) -> "NoiseCoefficients":
        """The same noise with the quantization term of step ``old_step_e`` (e⁻/DN, the one in
        ``a``) replaced by that of ``new_step_e`` (e.g. the step at another analog gain); the steps
        broadcast against ``a``."""
        a = self.a - quantization_variance_e2(old_step_e) + quantization_variance_e2(new_step_e)
        return NoiseCoefficients(a=a, b=self.b, c=self.c)

    def variance(self, s_e):
        s_e = np.asarray(s_e, float)
        return self.a + self.b * s_e + self.c * s_e * s_e

    @classmethod
    def from_parameters(
        cls,
        *,
        read_noise_e,
        dark_current_e_per_s=0.0,
        exposure_time_s=0.0,
        dsnu_e=0.0,
        prnu_frac=0.0,
        conversion_gain_e_per_dn=0.0,
        dark_noise_e=None,
    ):
        """Eq. 1 terms. ``dark_noise_e``, if given, replaces ``read² + D·t`` (used when only
        their sum is identifiable)."""
        if dark_noise_e is None:
            rd2 = dark_variance_e2(read_noise_e, dark_current_e_per_s, exposure_time_s)
        else:
            rd2 = np.asarray(dark_noise_e, float) ** 2
        a = rd2 + np.asarray(dsnu_e, float) ** 2 + quantization_variance_e2(conversion_gain_e_per_dn)
        b = np.ones_like(a)
        c = np.asarray(prnu_frac, float) ** 2 * np.ones_like(a)
        return cls(a=np.asarray(a, float), b=b, c=c)


def snr_db(coeffs: NoiseCoefficients, s_e):
    """SNR of Eq. 1 in dB at signal ``s_e`` (e⁻): 10 log10(S²/σ²(S))."""
    s_e = np.asarray(s_e, float)
    return 10.0 * np.log10(s_e * s_e / coeffs.variance(s_e))


def dynamic_range_db(coeffs: NoiseCoefficients, s_max_e):
    """DR of Eq. 2: 20 log10(S_max / σ_dark) with σ_dark² = a (read, DC, DSNU, quantization)."""
    return 20.0 * np.log10(np.asarray(s_max_e, float) / np.sqrt(coeffs.a))
