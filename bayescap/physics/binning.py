"""n × n pixel binning: the noise, tonal range and MTF of a binned pixel (the paper's closing remark).

Tisse et al. (2008) close Section 4: "halving pixel size and combining photodiode charges or
digital values from four adjacent pixels, i.e. 2 × 2 pixel binning, will not allow an increase of
image information capacity". This module gives the binned pixel's Eq. 1 noise model, full well
and MTF, so that its capacity can be set beside the full-resolution one.

Derivation. A native pixel at mean signal ``S`` (e⁻) has the Eq. 1 variance

    σ²(S) = r² + D·t + σ_DSNU² + K²/12 + S + p²·S²

(read noise ``r``, dark current ``D`` over ``t``, DSNU, quantization with step ``K`` e⁻/DN, shot
noise, PRNU fraction ``p``). Under uniform light each of the ``N = n²`` sub-pixels gets ``S``;
the binned signal is ``S_b = N·S``. Sub-pixels are independent (no crosstalk), so the variances
of what is summed add:

* shot noise: ``N·S = S_b`` (the binned pixel is shot-noise limited like a pixel of N times the area);
* dark-current shot noise ``N·D·t`` and DSNU ``N·σ_DSNU²`` (both originate in the photodiodes);
* PRNU: ``Σ(1 + g_i)·S`` has variance ``N·p²·S² = (p²/N)·S_b²``: the relative PRNU falls by ``√N``;
* **charge binning** (the charges are summed on the shared floating diffusion, then read once):
  one read noise ``r²`` and one quantization ``K_b²/12``;
* **digital binning** (each sub-pixel read and digitised, the N values added): N read noises
  ``N·r²`` (for 2 × 2: the read noise doubles, ``√4·r``) and N quantizations ``N·K²/12``.

Full well: each sub-pixel clips at ``FW``, so digital binning clips at ``N·FW``. Charge binning
clips at ``N·FW`` only if the floating diffusion and the ADC range hold the sum; by default we
assume they do, with the ADC step scaled to keep the output range (``K_b = N·K``), and both can
be given (``binned_full_well_e``, ``binned_conversion_gain_e_per_dn``).

MTF of the binned pixel (``f`` in cycles per *binned* pixel, one axis): the sub-pixel aperture of
width ``√ff`` sub-pixels, ``sinc(√ff·f/n)``, times the sum of ``n`` sub-pixels ``1/n`` binned pixel
apart, ``|sin(π f)/(n·sin(π f/n))|``. For fill factor 1 the product is ``sinc(f)``: a binned
pixel is exactly a square pixel of ``n`` times the pitch (:class:`BinnedAperture`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescap.physics.noise import NoiseCoefficients
from bayescap.physics.optics import MTFComponent

__all__ = ["BINNING_MODES", "BinnedPixel", "binned_pixel", "BinnedAperture"]

BINNING_MODES = ("full", "charge", "digital")


@dataclass(frozen=True)
class BinnedPixel:
    """Noise model (e⁻², of the binned signal), top of the range (e⁻) and sub-pixels per binned pixel."""

    coeffs: NoiseCoefficients
    s_max_e: np.ndarray
    n_sub: int
    mode: str


def binned_pixel(
    mode: str,
    *,
    read_noise_e,
    full_well_e,
    conversion_gain_e_per_dn,
    dark_current_e_per_s=0.0,
    exposure_time_s=0.0,
    dsnu_e=0.0,
    prnu_frac=0.0,
    n: int = 2,
    binned_full_well_e=None,
    binned_conversion_gain_e_per_dn=None,
) -> BinnedPixel:
    """The Eq. 1 noise of a native pixel (``mode="full"``) or of an ``n × n`` binned pixel
    (``"charge"`` or ``"digital"``), vectorised over draws (see the module docstring)."""
    if mode not in BINNING_MODES:
        raise ValueError(f"mode must be one of {BINNING_MODES}, got {mode!r}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    f = lambda x: np.asarray(x, float)  # noqa: E731
    r2, dt, dsnu2, p2 = (
        f(read_noise_e) ** 2,
        f(dark_current_e_per_s) * exposure_time_s,
        f(dsnu_e) ** 2,
        f(prnu_frac) ** 2,
    )
    k, fw = f(conversion_gain_e_per_dn), f(full_well_e)
    big_n = 1 if mode == "full" else n * n
    if mode == "charge":
        kb = big_n * k if binned_conversion_gain_e_per_dn is None else f(binned_conversion_gain_e_per_dn)
        read_q = r2 + kb * kb / 12.0
    else:
        read_q = big_n * (r2 + k * k / 12.0)
    a = read_q + big_n * (dt + dsnu2)
    s_max = big_n * fw if (mode != "charge" or binned_full_well_e is None) else f(binned_full_well_e)
    coeffs = NoiseCoefficients(a=np.asarray(a, float), b=np.ones_like(a, dtype=float), c=p2 / big_n * np.ones_like(a))
    return BinnedPixel(coeffs=coeffs, s_max_e=np.asarray(s_max, float), n_sub=big_n, mode=mode)


@dataclass(frozen=True)
class BinnedAperture(MTFComponent):
    """Aperture MTF of an ``n × n`` binned pixel, frequencies in cycles per binned pixel."""

    n: int = 2
    fill_factor: float = 1.0
    name: str = "binned_aperture"

    def __post_init__(self):
        if self.n < 1 or not (0.0 < self.fill_factor <= 1.0):
            raise ValueError(f"need n >= 1 and 0 < fill_factor <= 1, got {self.n}, {self.fill_factor}")

    def _axis(self, f):
        f = np.asarray(f, float)
        sub = np.sinc(np.sqrt(self.fill_factor) * f / self.n)
        with np.errstate(divide="ignore", invalid="ignore"):
            den = self.n * np.sin(np.pi * f / self.n)
            comb = np.where(np.abs(den) > 1e-12, np.sin(np.pi * f) / np.where(np.abs(den) > 1e-12, den, 1.0), 1.0)
        return np.abs(sub * comb)

    def radial(self, f_cy_per_px):
        return self._axis(f_cy_per_px)

    def mtf2d(self, fx_cy_per_px, fy_cy_per_px):
        return self._axis(fx_cy_per_px) * self._axis(fy_cy_per_px)

    def describe(self):
        return {"name": self.name, "n": self.n, "fill_factor": self.fill_factor}
