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

__all__ = ["NoiseCoefficients", "dark_variance_e2", "dynamic_range_db", "snr_db"]


def dark_variance_e2(read_noise_e=None, dark_current_e_per_s=0.0, exposure_time_s=0.0, *, dark_noise_e=None):
    """σ_read² + D·t (e⁻²), the temporal dark part of Eq. 1's ``a``; ``dark_noise_e²`` when
    ``dark_noise_e`` is given (only the sum identifiable). Broadcasts over its arguments."""
    if dark_noise_e is not None:
        return np.asarray(dark_noise_e, float) ** 2
    return np.asarray(read_noise_e, float) ** 2 + np.asarray(dark_current_e_per_s, float) * exposure_time_s


@dataclass(frozen=True)
class NoiseCoefficients:
    """σ²(S) = a + b·S + c·S² in e⁻², vectorised over draws."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray

    def variance(self, s_e):
        s_e = np.asarray(s_e, float)
        return self.a + self.b * s_e + self.c * s_e * s_e

    @classmethod
    def from_parameters(cls, *, read_noise_e, dark_current_e_per_s=0.0, exposure_time_s=0.0,
                        dsnu_e=0.0, prnu_frac=0.0, conversion_gain_e_per_dn=0.0,
                        dark_noise_e=None):
        """Eq. 1 terms. ``dark_noise_e``, if given, replaces ``read² + D·t`` (used when only
        their sum is identifiable)."""
        k = np.asarray(conversion_gain_e_per_dn, float)
        rd2 = dark_variance_e2(read_noise_e, dark_current_e_per_s, exposure_time_s, dark_noise_e=dark_noise_e)
        a = rd2 + np.asarray(dsnu_e, float) ** 2 + k * k / 12.0
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
