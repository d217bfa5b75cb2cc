"""2 × 2 binning (bayescap.physics.binning, bayescap.studies.binning): closed-form cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayescap.physics.binning import BinnedAperture, binned_pixel
from bayescap.physics.capacity import mtf_loss_bits, tonal_range
from bayescap.physics.noise import snr_db
from bayescap.physics.optics import DiffractionLens, MTFProduct, PixelAperture
from bayescap.studies.binning import binning_capacity

PIX = dict(read_noise_e=5.0, full_well_e=4000.0, conversion_gain_e_per_dn=4.0, dark_current_e_per_s=20.0)
PIX.update(exposure_time_s=0.1, dsnu_e=3.0, prnu_frac=0.02)


def test_noise_terms_by_mode():
    """σ² = a + S + c S² with, for N = 4 sub-pixels: charge a = r² + N(Dt + DSNU²) + (N K)²/12,
    digital a = N(r² + Dt + DSNU² + K²/12); both c = p²/N and S_max = N·FW."""
    r2, dt, d2, k, p = 25.0, 2.0, 9.0, 4.0, 0.02
    full = binned_pixel("full", **PIX)
    charge = binned_pixel("charge", **PIX)
    digital = binned_pixel("digital", **PIX)
    assert float(full.coeffs.a) == pytest.approx(r2 + dt + d2 + k * k / 12)
    assert float(charge.coeffs.a) == pytest.approx(r2 + 4 * (dt + d2) + (4 * k) ** 2 / 12)
    assert float(digital.coeffs.a) == pytest.approx(4 * (r2 + dt + d2 + k * k / 12))
    for b in (charge, digital):
        assert float(b.coeffs.c) == pytest.approx(p * p / 4) and float(b.s_max_e) == 16000.0
    # digital binning doubles the read noise (√4 r): its read-noise share of a is 4 r² = (2 r)²
    only_read = dict(PIX, dark_current_e_per_s=0.0, dsnu_e=0.0, conversion_gain_e_per_dn=0.0)
    assert math.sqrt(float(binned_pixel("digital", **only_read).coeffs.a)) == pytest.approx(2 * 5.0)
    assert math.sqrt(float(binned_pixel("charge", **only_read).coeffs.a)) == pytest.approx(5.0)
    # SNR of the binned signal S_b = 4 S, shot noise only: 10 log10(4 S) = SNR(S) + 6.02 dB
    shot = dict(only_read, read_noise_e=0.0, prnu_frac=0.0)
    s = 1000.0
    gain_db = float(
        snr_db(binned_pixel("charge", **shot).coeffs, 4 * s) - snr_db(binned_pixel("full", **shot).coeffs, s)
    )
    assert gain_db == pytest.approx(10 * math.log10(4))


def test_binning_one_by_one_is_full_resolution():
    a, b = binned_pixel("full", **PIX), binned_pixel("charge", n=1, **PIX)
    assert (float(a.coeffs.a), float(a.coeffs.c), float(a.s_max_e)) == (
        float(b.coeffs.a),
        float(b.coeffs.c),
        float(b.s_max_e),
    )


def test_binned_aperture_is_a_pixel_of_twice_the_pitch():
    """Fill factor 1: sinc(f/2)·cos(π f/2) = sinc(f), the aperture of a pixel n times larger."""
    f = np.linspace(0, 1.5, 301)
    np.testing.assert_allclose(BinnedAperture(n=2).radial(f), PixelAperture().radial(f), atol=1e-12)
    np.testing.assert_allclose(BinnedAperture(n=3).radial(f), PixelAperture().radial(f), atol=1e-12)
    # fill factor 0.5: the gaps between sub-pixels keep more high frequencies than a full 2P box
    assert BinnedAperture(n=2, fill_factor=0.5).radial(0.5) > PixelAperture().radial(0.5)
    fx, fy = np.meshgrid(f[:50], f[:50])
    np.testing.assert_allclose(BinnedAperture(n=2).mtf2d(fx, fy), PixelAperture().mtf2d(fx, fy), atol=1e-12)


def test_ideal_charge_binning_equals_a_native_pixel_of_twice_the_pitch():
    """No read noise, dark current, DSNU, quantization: a charge-binned pixel of pitch P is a native
    pixel of pitch 2P with four times the full well and half the PRNU, so the capacities in a fixed
    area are equal; digital binning too (nothing is read twice)."""
    p, fw, prnu = 1.45, 5500.0, 0.02
    kw = dict(dark_current_e_per_s=0.0, read_noise_e=0.0, dsnu_e=0.0, adc_bits=40)
    binned = binning_capacity(p, full_well_e=fw, prnu_frac=prnu, **kw)
    native = binning_capacity(2 * p, full_well_e=4 * fw, prnu_frac=prnu / 2, **kw)["full"]
    for mode in ("charge", "digital"):
        assert binned[mode]["pixels"] == pytest.approx(native["pixels"])
        assert binned[mode]["delta_s_bits"] == pytest.approx(native["delta_s_bits"], abs=1e-12)
        assert float(binned[mode]["capacity_bits"]) == pytest.approx(float(native["capacity_bits"]), rel=1e-9)
    ds_lens = mtf_loss_bits(MTFProduct(components=(PixelAperture(), DiffractionLens(pixel_pitch_um=2 * p))))
    assert binned["charge"]["delta_s_bits"] == pytest.approx(float(ds_lens.delta_s_bits))


def test_read_noise_makes_charge_binning_win_and_draws_broadcast():
    """With read noise, charge binning (read once) has the higher TR; vectorised over draws."""
    fw = np.array([4000.0, 5500.0, 7000.0])
    r = binning_capacity(1.45, full_well_e=fw, prnu_frac=0.02, dark_current_e_per_s=0.26, read_noise_e=5.56)
    assert r["charge"]["tr_bits"].shape == (3,)
    assert np.all(r["charge"]["tr_bits"] > r["digital"]["tr_bits"])
    assert np.all(r["charge"]["capacity_bits"] > r["digital"]["capacity_bits"])
    # same TR integral as a hand-built noise model
    a = 5.56**2 + 4 * 0.026 + (4 * fw / 1024) ** 2 / 12
    from bayescap.physics.noise import NoiseCoefficients

    hand = tonal_range(NoiseCoefficients(a=a, b=np.ones(3), c=np.full(3, 0.02**2 / 4)), 4 * fw)
    np.testing.assert_allclose(r["charge"]["tr_bits"], np.log2(hand), rtol=1e-12)


def test_bad_mode():
    with pytest.raises(ValueError, match="mode"):
        binned_pixel("analog", **PIX)
