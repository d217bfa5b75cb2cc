"""The CFA frame simulator (bayescap.validation.cfasim) against its own stated truth."""

import numpy as np
import pytest

from bayescap.validation.cfasim import (
    CHANNELS,
    CFAAcquisition,
    CFACamera,
    channel_qe,
    reflectance_responses,
    simulate_cfa_pairs,
    simulate_cfa_ptc,
    split_planes,
)


@pytest.fixture(scope="module")
def sim():
    return simulate_cfa_ptc(3)


def test_planes_are_the_rggb_quads():
    m = np.arange(16).reshape(4, 4)
    p = split_planes(m)
    assert p["R"].tolist() == [[0, 2], [8, 10]]
    assert p["Gr"].tolist() == [[1, 3], [9, 11]]
    assert p["Gb"].tolist() == [[4, 6], [12, 14]]
    assert p["B"].tolist() == [[5, 7], [13, 15]]


def test_same_seed_same_rows(sim):
    again = simulate_cfa_ptc(3)
    for c in CHANNELS:
        np.testing.assert_array_equal(sim[c]["rows"]["temporal_var_dn2"], again[c]["rows"]["temporal_var_dn2"])


def test_channels_see_their_own_qe(sim):
    """Mean signal per photon × K is each channel's QE (to the shot-noise error of the mean)."""
    t = sim["truth"]
    k = t["k_e_per_dn"]
    for c in CHANNELS:
        r = sim[c]["rows"]
        ok = r["frac_saturated"] == 0
        s_dn = (r["mean_dn"] - r["dark_mean_dn"])[ok]
        mu = r["photons_per_pixel"][ok]
        qe = t["quantum_efficiency"][c]
        # per row: the mean of n pixels (two frames) carries shot + PRNU + read noise
        n = r["n_pixels"][ok]
        var_e = mu * qe + (t["prnu_frac"][c] * mu * qe) ** 2 + t["read_noise_e"] ** 2
        se = np.sqrt(var_e / n) / (mu * qe)
        z = (s_dn * k / mu - qe) / qe / np.maximum(se, 1e-12)
        assert np.all(np.abs(z) < 5), (c, z)


def test_temporal_variance_is_shot_plus_read(sim):
    """Pair-difference variance = S/K + read²/K² + 1/12 (DN²); its relative error is √(2/n)."""
    t = sim["truth"]
    for j, c in enumerate(CHANNELS):
        r = sim[c]["rows"]
        ok = (r["frac_saturated"] == 0) & (r["mean_dn"] < 0.9 * (2**12 - 1))
        s = (r["mean_dn"] - r["dark_mean_dn"])[ok]
        c0, c1, _ = t["var_coeffs_dn2"][j]
        expect = c0 + c1 * s
        rel = r["temporal_var_dn2"][ok] / expect - 1.0
        assert np.all(np.abs(rel) < 5 * np.sqrt(2.0 / r["n_pixels"][ok])), (c, rel)


def test_gb_qe_ratio_and_pairs_are_mosaics():
    cam = CFACamera(gb_qe_ratio=0.97, width_px=8, height_px=6)
    qe = channel_qe(cam)
    assert qe["Gb"] == pytest.approx(0.97 * qe["Gr"], rel=1e-12)
    pairs = simulate_cfa_pairs(cam, CFAAcquisition(photons_per_pixel=(100.0,)), seed=0)
    assert pairs[0]["flat"][0].shape == (6, 8) and pairs[0]["flat"][0].dtype == np.uint16


def test_white_patch_response_is_the_flat_qe():
    cam = CFACamera()
    resp, names = reflectance_responses(cam)
    assert len(names) == 24 and resp.shape == (24, 3)
    qe = channel_qe(cam)
    # every patch reflects less than a perfect white in every channel
    assert np.all(resp < np.array([qe["R"], qe["Gr"], qe["B"]]))


def test_odd_mosaic_refused():
    with pytest.raises(ValueError, match="even"):
        CFACamera(width_px=7)


def test_realized_pattern_is_the_drawn_one(sim):
    """The realised PRNU is the simulated planes' own: the flats' spatial variance at the brightest
    unclipped row is (PRNU·S)² + the pair average's temporal variance τ = (S/K + read²/K² + 1/12)/2,
    to its sampling error given the pattern (the temporal part's: sd √((4·(PRNU·S)²·τ + 2τ²)/n));
    and it differs from the population's by the pattern's sampling (relative sd 1/√(2n))."""
    t = sim["truth"]
    real = t["realized"]
    for j, c in enumerate(CHANNELS):
        r = sim[c]["rows"]
        i = np.flatnonzero((r["frac_saturated"] == 0) & (r["mean_dn"] < 0.8 * (2**12 - 1)))[-1]
        s = r["mean_dn"][i] - r["dark_mean_dn"][i]
        c0, c1, _ = t["var_coeffs_dn2"][j]
        temporal = (c0 + c1 * s) / 2.0
        p_real = real["prnu_frac"][c]
        pattern = (p_real * s) ** 2
        n = r["n_pixels"][i]
        sd = np.sqrt((4 * pattern * temporal + 2 * temporal**2) / n)
        assert abs(r["spatial_var_dn2"][i] - pattern - temporal) < 5 * sd, c
        rel = p_real / t["prnu_frac"][c] - 1.0
        assert abs(rel) < 5 / np.sqrt(2.0 * n), c
        assert real["quantum_efficiency"][c] == pytest.approx(
            t["quantum_efficiency"][c], rel=5 * t["prnu_frac"][c] / np.sqrt(n)
        )
