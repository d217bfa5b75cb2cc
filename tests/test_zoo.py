"""The sensor zoo's fast subset and the frame simulator's own correctness.

The simulator (:mod:`bayescap.validation.framesim`) is checked against closed forms on large ROIs
(tolerances: 4 standard errors of the statistic); a handful of small zoo sensors from different
regimes are fitted with ``fast`` and scored (:func:`bayescap.validation.zoo.score`). Sensors on which
the current model is known to be wrong are strict xfails naming the defect, so the suite shows when
they are fixed. The full zoo is ``python benchmarks/run.py zoo``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.stats import norm, poisson

from bayescap.validation.framesim import (
    Acquisition,
    FrameSensor,
    clip_charge_e,
    expected_temporal_var_dn2,
    simulate_rows,
)
from bayescap.validation.zoo import ensure_csv, score, truths, zoo


def _one_row(sensor, photons, t=0.01, seed=1, n_frames=2, spatial=True):
    acq = Acquisition((t,), (photons,), (0,) if spatial else (), n_frames)
    return simulate_rows(sensor, acq, seed)[0]


# --------------------------------------------------------------------------- simulator
def test_temporal_variance_matches_the_closed_form():
    s = FrameSensor(
        k_e_per_dn=2.0,
        read_noise_e=3.0,
        full_well_e=1e6,
        quantum_efficiency=0.5,
        dark_current_e_per_s=100.0,
        prnu_frac=0.01,
        dsnu_e=2.0,
        adc_bits=16,
        black_level_dn=100.0,
        width_px=400,
        height_px=400,
    )
    n = 400 * 400
    for photons in (0.0, 400.0, 4000.0):
        r = _one_row(s, photons, spatial=False)
        expect = expected_temporal_var_dn2(s, photons, 0.01)
        se = expect * math.sqrt(2.0 / (n - 1))
        assert abs(r["temporal_var_dn2"] - expect) < 4 * se, (photons, r["temporal_var_dn2"], expect)
        # the mean: black level + (QE·μp + D·t)/K (PRNU averages out to p/sqrt(n))
        m_expect = 100.0 + (photons * 0.5 + 1.0) / 2.0
        # its sampling sd: temporal noise of the pair average, and the ROI's realised PRNU and DSNU means
        sd = math.sqrt(expect / (2 * n) + (0.01 * photons * 0.5 / 2.0) ** 2 / n + (2.0 / 2.0) ** 2 / n)
        assert abs(r["mean_dn"] - m_expect) < 4 * sd, (r["mean_dn"], m_expect, sd)


def test_truncating_adc_reads_half_a_dn_below_a_rounding_one():
    common = dict(
        k_e_per_dn=1.0, read_noise_e=3.0, full_well_e=1e6, adc_bits=12, black_level_dn=50.3, width_px=300, height_px=300
    )
    r_round = _one_row(FrameSensor(adc="round", **common), 1000.0, spatial=False)
    r_floor = _one_row(FrameSensor(adc="floor", **common), 1000.0, spatial=False)
    # same seed, same analog values: floor(x) − rint(x) ∈ {0, −1} with mean −0.5 for a noise ≫ 1 DN;
    # its sd over n pixels is 0.5/sqrt(n) per frame
    diff = r_floor["mean_dn"] - r_round["mean_dn"]
    assert abs(diff + 0.5) < 4 * 0.5 / math.sqrt(2 * 300 * 300)
    # the variance is the same (Sheppard's 1/12 in both)
    assert abs(r_floor["temporal_var_dn2"] / r_round["temporal_var_dn2"] - 1) < 4 * math.sqrt(2 / 90000)


def test_clipped_fraction_at_the_adc_maximum():
    s = FrameSensor(
        k_e_per_dn=4.0,
        read_noise_e=8.0,
        full_well_e=1e6,
        quantum_efficiency=1.0,
        adc_bits=10,
        black_level_dn=20.0,
        width_px=300,
        height_px=300,
    )
    # mean analog value about one sd above the rounding threshold of the maximum code (1022.5 DN)
    photons = 4030.0
    r = _one_row(s, photons, spatial=False)
    # exact: a pixel reads 1023 when 20 + (q + read)/4 >= 1022.5, q ~ Poisson(4030), read ~ N(0, 8²)
    q = np.arange(3500, 4600)
    p = float(np.sum(poisson.pmf(q, photons) * norm.sf((4010.0 - q) / 8.0)))
    n = 300 * 300
    assert abs(r["frac_saturated"] - p) < 4 * math.sqrt(p * (1 - p) / n)
    assert clip_charge_e(s) == ((1023 - 20.0) * 4.0, "adc")


@pytest.mark.parametrize("n_frames", [1, 2, 16])
def test_spatial_variance_of_a_frame_average(n_frames):
    s = FrameSensor(
        k_e_per_dn=1.0,
        read_noise_e=2.0,
        full_well_e=1e6,
        dsnu_e=3.0,
        adc_bits=16,
        black_level_dn=200.0,
        width_px=300,
        height_px=300,
    )
    r = _one_row(s, 0.0, n_frames=n_frames)
    expect = 9.0 + (4.0 + 1 / 12) / n_frames
    n = 300 * 300
    # the ROI's DSNU map is one draw: its sample variance scatters by 9·sqrt(2/n) around 9
    se = math.sqrt(2 / n) * math.hypot(9.0, expect)
    assert abs(r["dark_spatial_var_dn2"] - expect) < 4 * se
    assert r["n_frames"] == n_frames


def test_zoo_is_large_varied_and_deterministic(tmp_path):
    zs = zoo()
    assert len(zs) >= 60
    assert len({z.name for z in zs}) == len(zs)
    assert {z.sensor.adc_bits for z in zs} == {8, 10, 12, 14, 16}
    assert {z.sensor.adc for z in zs} == {"round", "floor"}
    assert {z.regime for z in zs} >= {"8-bit", "sub-DN", "photon-counting", "typical", "scientific"}
    ks = [z.sensor.k_e_per_dn for z in zs]
    assert min(ks) <= 0.06 and max(ks) >= 190
    z = next(z for z in zs if z.name == "acq_roi_32")
    a = ensure_csv(z, tmp_path / "a").read_text()
    b = ensure_csv(z, tmp_path / "b").read_text()
    assert a == b


# --------------------------------------------------------------------------- fits
def _fit_scores(name, tmp_path):
    import bayescap

    z = next(z for z in zoo() if z.name == name)
    path = ensure_csv(z, tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = bayescap.fit(str(path), seed=1, quality="fast").to_dict()
    return {p: r for p, r in score(truths(z), d).items() if r["status"] != "unscored"}


def _assert_right(sc):
    bad = {p: (r["verdict"], r["truth"]) for p, r in sc.items() if r["verdict"] not in ("ok", "absent")}
    assert not bad, bad


@pytest.mark.parametrize(
    "name",
    [
        "acq_roi_32",  # typical 10-bit, small ROI
        "i37_16bit_photon_counting",  # photon counting, K 0.25
        "b8_k40_read1",  # 8-bit, truncating ADC
        "sub_10bit_read0p3_dsnu1",  # sub-DN with a 16-frame spatial stack on every row
        "acq_unsaturated_16bit",  # full well not reached: a lower bound
        "acq_one_t_light_sweep",  # one exposure time: read noise and dark current as limits
    ],
)
def test_zoo_sensor_truth_inside(name, tmp_path):
    _assert_right(_fit_scores(name, tmp_path))


def test_zoo_sub_dn_dark_noise_is_a_limit(tmp_path):
    _assert_right(_fit_scores("i37_10bit_read0p1_one_t", tmp_path))


def test_zoo_single_frame_spatial_variance(tmp_path):
    _assert_right(_fit_scores("nf1_typical_12bit", tmp_path))


def test_truths_mark_what_the_data_cannot_identify():
    by = {z.name: truths(z) for z in zoo()}
    assert by["acq_unsaturated_16bit"]["full_well_e"][1] == "limit"
    assert by["acq_one_t_light_sweep"]["read_noise_e"][1] == "limit"
    assert by["acq_one_t_light_sweep"]["dark_noise_e"][1] == "identifiable"
    assert by["i37_8bit_floor_short_t"]["dark_current_e_per_s"][1] == "limit"
    assert by["acq_no_fpn"]["prnu_percent"][1] == "limit"
    assert by["acq_roi_1000"]["dsnu_e"][1] == "identifiable"
    assert np.isclose(by["acq_roi_1000"]["conversion_gain_e_per_dn"][0], 3.0)


def test_score_tells_a_detection_from_a_false_claim():
    """A truth the data are not expected to identify (status ``limit``) that one realisation
    detects, with a constrained 95 % interval holding it (draw33_14bit's dark current: 822 [174,
    1514] e-/s, truth 349, expected significance ~1 sd), is ``detected``; a constrained interval
    that excludes it (sub_12bit_read0p2_int's DSNU 0.33 [0.23, 0.45] e-, truth 0) is a false claim."""
    tr = {"dark_current_e_per_s": (349.4, "limit", ""), "dsnu_e": (0.0, "limit", "")}
    fit = {
        "parameters": {
            "dark_current_e_per_s": {"median": 822.0, "ci95": [173.9, 1513.5], "constrained": True},
            "dsnu_e": {"median": 0.33, "ci95": [0.23, 0.45], "constrained": True},
        }
    }
    sc = score(tr, fit)
    assert sc["dark_current_e_per_s"]["verdict"] == "detected"
    assert sc["dsnu_e"]["verdict"] == "claims-constrained"
