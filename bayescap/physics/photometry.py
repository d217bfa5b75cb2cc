"""Photon budget (Eq. 4, 5), SNR versus exposure (Eq. 1, Fig. 2b) and Farrell's MPE30.

Tisse, Guichard & Cao (SPIE 2008), Section 2.3.

* Eq. 4: mean photons per pixel ``η = H / (K_m · E_photon) · α · P²`` with ``H`` the photometric
  exposure (lux·s = lm·s/m²), ``K_m = 683 lm/W`` and ``E_photon = h·c/λ`` at 555 nm.
  The paper prints ``E_photon ≈ 2.58·10⁻¹⁹ J`` for 555 nm; ``h·c/555 nm = 3.579·10⁻¹⁹ J``
  (2.58·10⁻¹⁹ J is the energy at 770 nm), so the printed value is a typo and the default here
  is ``h·c/λ``; pass ``photon_energy_j=PAPER_PHOTON_ENERGY_J`` to use the printed number
  (it gives 1.387× more photons).
* Eq. 5 (after Cartrysse et al.): ``H = T_lens / (1 + 4(1 − m)²(f/#)²) · R · E_scene · Δt``.
* Eq. 1 with Table 1 parameters: signal ``S = sensitivity · H`` electrons; photon shot noise,
  dark-current shot noise ``D·Δt``, PRNU ``K_PRNU·S`` and quantization ``K²/12`` with
  ``K = full well / 2ⁿ``; read noise and DSNU neglected as in the paper. Above the full well
  the pixel saturates: SNR is NaN there.
"""

from __future__ import annotations

import numpy as np

from bayescap.physics.noise import NoiseCoefficients, snr_db

__all__ = [
    "K_M_LM_PER_W",
    "PLANCK_J_S",
    "SPEED_OF_LIGHT_M_S",
    "PAPER_PHOTON_ENERGY_J",
    "photon_energy_j",
    "photons_per_lux_s_um2",
    "photons_per_pixel",
    "exposure_lux_s",
    "pixel_noise_coefficients",
    "signal_e",
    "snr_vs_exposure_db",
    "snr_slope_db_per_decade",
    "mpe30_lux_s",
]

K_M_LM_PER_W = 683.0
PLANCK_J_S = 6.62607015e-34
SPEED_OF_LIGHT_M_S = 299_792_458.0
#: the value printed in the paper for 555 nm (a typo for 3.58e-19 J; see module docstring)
PAPER_PHOTON_ENERGY_J = 2.58e-19


def photon_energy_j(wavelength_nm=555.0):
    """Photon energy ``h·c/λ`` in joules (λ in nm). 555 nm → 3.579·10⁻¹⁹ J."""
    return _photon_energy(wavelength_nm)


def _photon_energy(wavelength_nm):
    lam = np.asarray(wavelength_nm, float)
    if np.any(~(lam > 0)):
        raise ValueError(f"wavelength_nm must be positive, got {wavelength_nm}")
    return PLANCK_J_S * SPEED_OF_LIGHT_M_S / (lam * 1e-9)


def photons_per_lux_s_um2(*, wavelength_nm=555.0, k_m_lm_per_w=K_M_LM_PER_W, photon_energy_j=None):
    """Photons per lux·s per µm² of pixel area (Eq. 4 with α = 1, P = 1 µm): 4091 at 555 nm."""
    e = _photon_energy(wavelength_nm) if photon_energy_j is None else np.asarray(photon_energy_j, float)
    return 1e-12 / (k_m_lm_per_w * e)


def photons_per_pixel(
    h_lux_s, pitch_um, *, fill_factor=1.0, wavelength_nm=555.0, k_m_lm_per_w=K_M_LM_PER_W, photon_energy_j=None
):
    """Eq. 4: mean number of photons incident on one pixel.

    Parameters
    ----------
    h_lux_s : photometric exposure H (lux·s); broadcasts against ``pitch_um``.
    pitch_um : pixel pitch P (µm); the pixel area is P².
    fill_factor : α in (0, 1].
    photon_energy_j : override ``h·c/λ`` (e.g. :data:`PAPER_PHOTON_ENERGY_J`).

    >>> round(float(photons_per_pixel(1.0, 1.0)))
    4091
    """
    ff = np.asarray(fill_factor, float)
    if np.any((ff <= 0) | (ff > 1)):
        raise ValueError(f"fill_factor must be in (0, 1], got {fill_factor}")
    p = np.asarray(pitch_um, float)
    if np.any(~(p > 0)):
        raise ValueError(f"pitch_um must be positive, got {pitch_um}")
    per_um2 = photons_per_lux_s_um2(
        wavelength_nm=wavelength_nm, k_m_lm_per_w=k_m_lm_per_w, photon_energy_j=photon_energy_j
    )
    return np.asarray(h_lux_s, float) * per_um2 * ff * p * p


def exposure_lux_s(scene_lux, *, exposure_time_s, f_number, magnification=-1e-3, transmittance=0.85, reflectance=1.0):
    """Eq. 5: photometric exposure H (lux·s) at the sensor for a Lambertian scene.

    ``H = T_lens / (1 + 4 (1 − m)² N²) · R · E_scene · Δt`` with magnification ``m < 0``.
    The defaults are those of Fig. 2(a) (T = 0.85, m = −10⁻³); the paper does not state R for
    Fig. 2(a): R = 1 (a white Lambertian scene) is the default here.
    """
    if not (0 < transmittance <= 1) or not (0 < reflectance <= 1):
        raise ValueError("transmittance and reflectance must be in (0, 1]")
    if magnification >= 0:
        raise ValueError(f"magnification m must be negative (inverted real image), got {magnification}")
    if not (f_number > 0 and exposure_time_s >= 0):
        raise ValueError("f_number must be positive and exposure_time_s non-negative")
    g = transmittance / (1.0 + 4.0 * (1.0 - magnification) ** 2 * f_number**2)
    return g * reflectance * np.asarray(scene_lux, float) * exposure_time_s


def pixel_noise_coefficients(
    *, full_well_e, dark_current_e_per_s, prnu_frac, exposure_time_s=0.1, adc_bits=10, read_noise_e=0.0, dsnu_e=0.0
) -> NoiseCoefficients:
    """Eq. 1 noise model of a Table 1 pixel: σ² = D·Δt + K²/12 + S + (K_PRNU·S)², K = FW/2ⁿ.

    Vectorised over draws (arrays broadcast). Read noise and DSNU default to 0 (the paper's
    Fig. 2(b) assumption).
    """
    k = np.asarray(full_well_e, float) / 2.0**adc_bits
    return NoiseCoefficients.from_parameters(
        read_noise_e=read_noise_e,
        dark_current_e_per_s=dark_current_e_per_s,
        exposure_time_s=exposure_time_s,
        dsnu_e=dsnu_e,
        prnu_frac=prnu_frac,
        conversion_gain_e_per_dn=k,
    )


def signal_e(h_lux_s, sensitivity_e_per_lux_s):
    """Mean photo-signal S = sensitivity · H (electrons)."""
    return np.asarray(sensitivity_e_per_lux_s, float) * np.asarray(h_lux_s, float)


def snr_vs_exposure_db(
    h_lux_s, *, sensitivity_e_per_lux_s, full_well_e, dark_current_e_per_s, prnu_frac, exposure_time_s=0.1, adc_bits=10
):
    """SNR (dB, Eq. 1) against photometric exposure H (lux·s); NaN where S > full well.

    The dark-current charge ``D·Δt`` is not added to the signal (it is subtracted as black
    level); only its shot noise enters σ².
    """
    coeffs = pixel_noise_coefficients(
        full_well_e=full_well_e,
        dark_current_e_per_s=dark_current_e_per_s,
        prnu_frac=prnu_frac,
        exposure_time_s=exposure_time_s,
        adc_bits=adc_bits,
    )
    s = signal_e(h_lux_s, sensitivity_e_per_lux_s)
    with np.errstate(divide="ignore"):
        out = snr_db(coeffs, s)
    return np.where(s <= np.asarray(full_well_e, float), out, np.nan)


def snr_slope_db_per_decade(h_lo_lux_s, h_hi_lux_s, **pixel):
    """Mean slope of the SNR curve (dB per decade of H) between two exposures."""
    s_lo, s_hi = snr_vs_exposure_db(np.array([h_lo_lux_s, h_hi_lux_s]), **pixel)
    return (s_hi - s_lo) / np.log10(h_hi_lux_s / h_lo_lux_s)


def mpe30_lux_s(
    *,
    sensitivity_e_per_lux_s,
    full_well_e,
    dark_current_e_per_s,
    prnu_frac,
    exposure_time_s=0.1,
    adc_bits=10,
    snr_threshold_db=30.0,
):
    """Farrell's MPE30: the smallest exposure H (lux·s) with SNR(H) ≥ 30 dB (Section 2.3).

    Closed form: with ρ = 10^(SNR/10), S² = ρ(a + S + cS²) gives
    ``S = [ρ + sqrt(ρ² + 4(1 − ρc)ρa)] / (2(1 − ρc))``. Returns ``inf`` where 30 dB is never
    reached (PRNU ≥ 1/√ρ = 3.16 %, or the needed signal exceeds the full well).
    Vectorised over draws.
    """
    coeffs = pixel_noise_coefficients(
        full_well_e=full_well_e,
        dark_current_e_per_s=dark_current_e_per_s,
        prnu_frac=prnu_frac,
        exposure_time_s=exposure_time_s,
        adc_bits=adc_bits,
    )
    rho = 10.0 ** (snr_threshold_db / 10.0)
    a, b, c = np.broadcast_arrays(coeffs.a, coeffs.b, coeffs.c)
    den = 1.0 - rho * c
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (rho * b + np.sqrt((rho * b) ** 2 + 4.0 * den * rho * a)) / (2.0 * den)
        h = s / np.asarray(sensitivity_e_per_lux_s, float)
    ok = (den > 0) & (s <= np.asarray(full_well_e, float))
    return np.where(ok, h, np.inf)
