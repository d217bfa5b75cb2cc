"""CCMs, their noise cost, colour capacities and camera scores (bayescap.colour)."""

import numpy as np
import pytest

from bayescap.colour.capacity import colour_capacities
from bayescap.colour.ccm import ccm_from_matrix, ccm_from_spectral, condition_number, noise_gain
from bayescap.colour.scores import colour_depth, dynamic_range_ev, low_light_iso, snr_18_db
from bayescap.colour.sensitivity import colour_sensitivity_bits
from bayescap.colour.spectral import reflectance_domain


def test_noise_gain_and_condition_number_closed_forms():
    m = np.array([[2.0, -1.0, 0.0], [0.0, 1.0, 0.0], [0.0, -3.0, 4.0]])
    np.testing.assert_allclose(noise_gain(m), [np.sqrt(5.0), 1.0, 5.0], rtol=1e-15)
    s = np.linalg.svd(m, compute_uv=False)
    assert condition_number(m) == pytest.approx(s[0] / s[-1], rel=1e-12)
    assert condition_number(np.eye(3)) == pytest.approx(1.0)
    # vectorised over draws
    assert noise_gain(np.stack([m, np.eye(3)])).shape == (2, 3)


@pytest.mark.parametrize(
    "m, msg",
    [
        (np.ones((3, 3)), "singular"),
        ([[1, 0, 0], [0, np.inf, 0], [0, 0, 1]], "non-finite"),
        (np.eye(2), "3×3"),
        ([["a", 0, 0], [0, 1, 0], [0, 0, 1]], "3×3 numbers"),
        (-np.eye(3), "non-positive"),
    ],
)
def test_user_matrix_refused(m, msg):
    with pytest.raises(ValueError, match=msg):
        ccm_from_matrix(m, source="my.json")


def test_user_matrix_draws_are_a_stated_uncertainty():
    m = np.array([[1.6, -0.4, -0.2], [-0.2, 1.5, -0.3], [0.0, -0.5, 1.5]])
    c = ccm_from_matrix(m, rel_sd=0.03, n_draws=500, seed=1)
    assert c.draws.shape == (500, 3, 3)
    nz = m != 0  # a zero element stays zero under a relative spread
    rel = c.draws[:, nz] / m[nz] - 1
    np.testing.assert_array_equal(c.draws[:, ~nz], 0.0)
    assert np.std(rel) == pytest.approx(0.03, rel=0.1)  # 4000 values: SE of the sd ≈ 1.1 %
    assert "0.03" in c.uncertainty
    again = ccm_from_matrix(m, rel_sd=0.03, n_draws=500, seed=1)
    np.testing.assert_array_equal(c.draws, again.draws)
    assert ccm_from_matrix(m).draws is None


@pytest.fixture(scope="module")
def nikon():
    return ccm_from_spectral("Nikon 5100 (NPL)", n_draws=40, seed=0)


def test_spectral_ccm_is_white_preserving_and_reproduces_the_chart(nikon):
    import colour

    np.testing.assert_allclose(nikon.matrix.sum(axis=1), 1.0, rtol=1e-12)
    assert nikon.wb_gains[1] == 1.0 and np.all(nikon.wb_gains > 0)
    # the fitted matrix beats the identity on the chart it was fitted to
    from colour.characterisation import training_data_sds_to_RGB

    sens = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(sens.shape)
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    msds = colour.colorimetry.sds_and_msds_to_msds([sd.copy().align(sens.shape) for sd in sds.values()])
    rgb, rgb_w = training_data_sds_to_RGB(msds, sens, ill)
    white = (ill.values @ sens.values) * rgb_w
    np.testing.assert_allclose(white, white[1], rtol=1e-9)  # white balanced
    rgb = rgb / white[1]
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(sens.shape)
    xyz = colour.msds_to_XYZ(msds, cmfs, ill, method="Integration", shape=sens.shape) / 100
    target = colour.XYZ_to_RGB(
        xyz,
        "sRGB",
        illuminant=colour.XYZ_to_xy(colour.sd_to_XYZ(ill, cmfs, method="Integration") / 100),
        chromatic_adaptation_transform="Bradford",
    )
    err_m = np.sqrt(np.mean((rgb @ nikon.matrix.T - target) ** 2))
    err_i = np.sqrt(np.mean((rgb - target) ** 2))
    assert err_m < 0.3 * err_i
    assert nikon.draws.shape == (40, 3, 3) and np.all(np.std(nikon.draws, axis=0) > 0)


def test_overlapping_sensitivities_cost_more_noise(nikon):
    """The Sigma (Foveon-like, strongly overlapping) sensitivities need a far noisier matrix."""
    sigma = ccm_from_spectral("Sigma SDMerill (NPL)")
    assert np.all(sigma.noise_gain() > nikon.noise_gain())
    assert sigma.condition_number() > 3 * nikon.condition_number()
    d = sigma.to_dict()
    assert d["source"].startswith("spectral: Sigma") and len(d["noise_gain"]) == 3


def test_reflectance_domain_spans_less_than_the_cube(nikon):
    resp = reflectance_domain("Nikon 5100 (NPL)")
    assert resp.shape == (24, 3) and np.all(resp >= 0)
    v = np.array([[[2.3, 0.5, 6e-5], [2.3, 0.5, 4e-5], [2.3, 0.5, 4e-5], [2.3, 0.5, 1e-4]]])
    clip = np.full((1, 4), 4031.0)
    cube = colour_sensitivity_bits(v, clip, nikon.matrix, nikon.wb_gains)
    chart = colour_sensitivity_bits(v, clip, nikon.matrix, nikon.wb_gains, domain=resp)
    assert chart[0] < cube[0] - 1.0


def test_colour_capacities_by_definition():
    cs = np.array([20.0, 22.0])
    b = np.array([[7.0, 7.5, 7.5, 7.0], [6.0, 6.5, 6.5, 6.0]])
    caps = colour_capacities(cs, 4e6, b, delta_s_channel_bits=-1.0, delta_s_lum_bits=-0.5)
    np.testing.assert_allclose(caps["superpixel"]["bits"], cs * 1e6)
    np.testing.assert_allclose(caps["per_channel"]["bits"], b.sum(axis=1) * 1e6 * 0.5)
    np.testing.assert_allclose(caps["cs_luminance_mtf"]["bits"], cs * 4e6 * 2**-0.5)
    assert all("definition" in v for v in caps.values())


def test_scores_closed_forms():
    v = np.array([[4.0, 0.5, 1e-4]])
    clip = np.array([4000.0])
    assert dynamic_range_ev(v, clip)[0] == pytest.approx(np.log2(2000.0))
    dr, dr_print = dynamic_range_ev(v, clip, n_pixels=32e6)
    assert dr_print[0] - dr[0] == pytest.approx(1.0)
    s = 720.0
    assert snr_18_db(v, clip)[0] == pytest.approx(20 * np.log10(s / np.sqrt(4 + 0.5 * s + 1e-4 * s * s)))
    cd = colour_depth(np.array([22.0]), 32e6)
    assert cd["colour_depth_print_bits"][0] == pytest.approx(22.0 + 1.5 * 2.0)


def test_low_light_iso_interpolates_in_log_iso_and_reports_limits():
    iso = np.array([100.0, 200.0, 400.0, 800.0])
    # draw 0 crosses 30 halfway between 200 and 400; draw 1 never falls to 30; draw 2 starts below
    m = np.array([[40.0, 45.0, 20.0], [34.0, 44.0, 19.0], [26.0, 43.0, 18.0], [20.0, 42.0, 17.0]])
    r = low_light_iso(iso, m, 30.0)
    assert r["draws"][0] == pytest.approx(200.0 * 2**0.5)
    assert np.isnan(r["draws"][1]) and r["above"][1]
    assert np.isnan(r["draws"][2]) and r["below"][2]
    assert r["summary"]["frac_above_max_iso"] == pytest.approx(1 / 3)
    r2 = low_light_iso(iso, m[:, [1, 1]], 30.0)
    assert r2["summary"]["limit"].startswith("> ISO 800")
    with pytest.raises(ValueError, match="increasing"):
        low_light_iso(iso[::-1], m, 30.0)


def test_low_light_iso_from_a_simulated_gain_series():
    """Three gains of one simulated sensor: SNR at 18 % grey and DR fall with gain; the ISO where
    they cross their thresholds lies between the settings whose medians bracket them."""
    from bayescap.colour.scores import gain_series_scores
    from bayescap.simulate import SensorTruth
    from bayescap.studies.gain_series import fit_gain_series, simulate_gain_series

    truth = SensorTruth(conversion_gain_e_per_dn=4.0, read_noise_e=3.0, full_well_e=12000.0, prnu_frac=0.01)
    md = {"pixel_pitch_um": 2.0, "adc_bits": 12, "black_level_dn": 64.0}
    datas, _ = simulate_gain_series(
        truth,
        [1.0, 4.0, 16.0],
        read_noise_pre_e=2.5,
        read_noise_post_dn=1.5,
        seed=3,
        metadata=md,
        n_levels=14,
        shape=(60, 60),
        spatial_frames=4,
        spatial_every=4,
    )
    series = fit_gain_series(datas, seed=0)
    out = gain_series_scores(series, n_draws=400)
    assert out["iso"] == [100.0, 400.0, 1600.0] and "assumed" in out["iso_note"]
    for name in ("snr_18_db", "dynamic_range_ev"):
        med = out[name]["per_setting_median"]
        assert med[0] > med[1] > med[2]
        if out[name]["median"] is not None:
            th = out[name]["threshold"]
            i = next(k for k in range(2) if med[k] > th >= med[k + 1])
            assert out["iso"][i] <= out[name]["median"] <= out["iso"][i + 1]
        else:
            assert "limit" in out[name]


def test_reflectance_domain_is_the_spectral_integral_balanced_by_the_white_balance():
    """Raw response = Σ_λ R(λ) E(λ) S_c(λ) on the sensitivities' grid, each channel scaled so that
    a perfect white gives raw ∝ 1/wb (the white balance's definition)."""
    import colour

    sens = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    shape = sens.shape
    wl = np.asarray(shape.wavelengths)
    white = colour.SpectralDistribution(dict(zip(wl, np.ones(wl.size))), name="white")
    ramp = colour.SpectralDistribution(dict(zip(wl, np.linspace(0.1, 0.9, wl.size))), name="ramp")
    wb = np.array([2.1, 1.0, 1.4])
    resp = reflectance_domain(sens, {"white": white, "ramp": ramp}, "A", wb_gains=wb)
    e = np.asarray(colour.SDS_ILLUMINANTS["A"].copy().align(shape).values)
    s = np.asarray(sens.values)
    raw = np.stack([e @ s, (np.linspace(0.1, 0.9, wl.size) * e) @ s]) * ((1 / wb) / (e @ s))
    np.testing.assert_allclose(resp, raw / raw.max(), rtol=1e-12)
    np.testing.assert_allclose(resp[0] / resp[0, 1], 1 / wb, rtol=1e-12)


def test_sensitivities_from_a_csv_and_refusals(tmp_path):
    from bayescap.colour.spectral import load_sensitivities

    p = tmp_path / "sens.csv"
    p.write_text(
        "wavelength_nm,R,G,B\n"
        + "".join(f"{w},{0.1 + (w > 580)},{0.5},{0.1 + (w < 490)}\n" for w in range(400, 701, 10))
    )
    sens = load_sensitivities(p)
    assert sens.shape.start == 400 and sens.shape.end == 700 and np.asarray(sens.values).shape == (31, 3)
    resp = reflectance_domain(p)
    assert resp.shape == (24, 3) and resp.max() == 1.0
    bad = tmp_path / "bad.csv"
    bad.write_text("wavelength_nm,R,G,B\n400,1,1,1\n410,1,x,1\n")
    with pytest.raises(ValueError, match="bad.csv: row 3"):
        load_sensitivities(bad)
    with pytest.raises(ValueError, match="not a file and not one of"):
        load_sensitivities("Canon 5D")
    with pytest.raises(ValueError, match="unknown illuminant 'D66'"):
        reflectance_domain("Nikon 5100 (NPL)", illuminant="D66")
