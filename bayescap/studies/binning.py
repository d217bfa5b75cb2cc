"""Capacity of a 2 × 2 binned mode beside full resolution (the paper's closing remark, Section 4).

For a Table 1 pixel of pitch ``P`` in a fixed imaging area (the paper's 1/4-inch, ideal f/2.8
lens), Eq. 6 ``C = s·2^Δs·b'`` is computed three ways:

* ``full``: ``s = W·H/P²`` pixels, Δs of the pixel aperture × lens at pitch ``P``, TR of the pixel;
* ``charge`` and ``digital`` (``n × n`` binning): ``s/n²`` pixels, Δs of the binned aperture
  (:class:`bayescap.physics.binning.BinnedAperture`) × lens at pitch ``n·P``, TR of the binned
  pixel's noise (:func:`bayescap.physics.binning.binned_pixel`).

TR is Eq. 7 over the dynamic range on the 8-bit-equivalent scale (as in Fig. 4), at Δt = 100 ms,
25 °C, 10-bit ADC (K = FW/1024). Table 1 has no read noise or DSNU (the paper neglects them);
give them (``read_noise_e``, ``dsnu_e``) to see charge and digital binning differ. With Table 1
draws (:func:`bayescap.studies.sweep.sample_table1`) every quantity is an array over draws.
"""

from __future__ import annotations

import numpy as np

from bayescap.physics.binning import BINNING_MODES, BinnedAperture, binned_pixel
from bayescap.physics.capacity import information_capacity_bits, mtf_loss_bits, tonal_range, tonal_range_bits
from bayescap.physics.optics import DiffractionLens, MTFProduct, PixelAperture

__all__ = ["binning_capacity"]


def binning_capacity(
    pitch_um: float,
    *,
    full_well_e,
    prnu_frac,
    dark_current_e_per_s,
    read_noise_e=0.0,
    dsnu_e=0.0,
    area_mm: tuple[float, float] = (3.6, 2.7),
    f_number: float = 2.8,
    wavelength_nm: float = 555.0,
    exposure_time_s: float = 0.1,
    adc_bits: int = 10,
    n: int = 2,
) -> dict:
    """``{mode: {"pixels", "pitch_um", "delta_s_bits", "tr_bits", "capacity_bits"}}`` for the
    modes full, charge and digital; TR and capacity are arrays over the draws of the inputs."""
    fw = np.asarray(full_well_e, float)
    k = fw / 2.0**adc_bits
    s_full = area_mm[0] * area_mm[1] * 1e6 / pitch_um**2
    out = {}
    for mode in BINNING_MODES:
        nn = 1 if mode == "full" else n
        px = binned_pixel(
            mode,
            read_noise_e=read_noise_e,
            full_well_e=fw,
            conversion_gain_e_per_dn=k,
            dark_current_e_per_s=dark_current_e_per_s,
            exposure_time_s=exposure_time_s,
            dsnu_e=dsnu_e,
            prnu_frac=prnu_frac,
            n=n,
        )
        aperture = PixelAperture() if mode == "full" else BinnedAperture(n=n)
        lens = DiffractionLens(f_number=f_number, wavelength_nm=wavelength_nm, pixel_pitch_um=nn * pitch_um)
        ds = float(mtf_loss_bits(MTFProduct(components=(aperture, lens))).delta_s_bits)
        tr_b = tonal_range_bits(tonal_range(px.coeffs, px.s_max_e))
        pixels = s_full / nn**2
        out[mode] = {
            "pixels": pixels,
            "pitch_um": nn * pitch_um,
            "delta_s_bits": ds,
            "tr_bits": tr_b,
            "capacity_bits": information_capacity_bits(pixels, ds, bits_per_pixel=tr_b),
        }
    return out
