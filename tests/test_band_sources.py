"""bayescap.studies.band_sources: the posterior draws widened by named uncertainty sources."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from bayescap.studies import band_sources as B
from bayescap.studies.exposure import exposure_calibration, tonal_range_at_exposure

ROOT = Path(__file__).resolve().parents[1]


def test_table1_range_factors_span_the_printed_range():
    f = B.table1_range_factors(1.75, 20000, seed=0)  # Table 1: 8-9 ke-, mid 8.5 ke-; PRNU < 1.5 %
    assert f["full_well_e"].min() >= 8000 / 8500 and f["full_well_e"].max() <= 9000 / 8500
    assert f["full_well_e"].min() < 8000 / 8500 + 1e-3 and f["full_well_e"].max() > 9000 / 8500 - 1e-3
    assert 0 <= f["prnu_percent"].min() < 1e-3 and 1 - 1e-3 < f["prnu_percent"].max() <= 1
    # 2.80 µm: between the 2.20 (12-21 ke-) and 2.90 (19-25 ke-) rows, interpolated in pitch
    w = (2.8 - 2.2) / (2.9 - 2.2)
    lo, hi = 12000 + w * 7000, 21000 + w * 4000
    g = B.table1_range_factors(2.8, 20000, seed=1)["full_well_e"]
    assert g.min() >= lo / (0.5 * (lo + hi)) - 1e-12 and g.max() <= hi / (0.5 * (lo + hi)) + 1e-12


def test_unit_to_unit_factors_have_the_given_cv():
    n = 40000
    f = B.unit_to_unit_factors({"quantum_efficiency": 0.05, "read_noise_e": 0.2}, n, seed=2)
    for name, cv in (("quantum_efficiency", 0.05), ("read_noise_e", 0.2)):
        x = f[name]
        # standard errors: mean cv/sqrt(n); sd about cv/sqrt(2n)·(1 + small log-normal excess)
        assert abs(x.mean() - 1) < 4 * cv / np.sqrt(n)
        assert abs(x.std() - cv) < 6 * cv / np.sqrt(2 * n)
    with pytest.raises(ValueError, match="no unit-to-unit spread"):
        B.unit_to_unit_factors({"lens": 0.1}, 10)


@pytest.fixture(scope="module")
def fit():
    import bayescap

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = bayescap.fit(str(ROOT / "data/benchmark/M1_1.75um.csv"), seed=0, quality="fast")
    return r, exposure_calibration(r), r.thin_index(500)


def test_widened_with_unit_factors_is_the_posterior(fit):
    r, cal, idx = fit
    h = np.geomspace(0.01, 3, 6)
    tr0, _ = tonal_range_at_exposure(r, h, calibration=cal, idx=idx)
    w, c = B.widened(r, cal, {"full_well_e": np.ones(idx.size), "quantum_efficiency": np.ones(idx.size)}, idx)
    tr1, _ = tonal_range_at_exposure(w, h, calibration=c)
    np.testing.assert_allclose(tr1, tr0, rtol=1e-12)
    assert r.draws["full_well_e"].size > idx.size  # the original result is untouched


def test_table1_range_widens_tr_at_h0(fit):
    """The stand-in sits at PRNU = bound (the low-TR end of the range): drawing PRNU in [0, bound]
    and the full well over its range raises and widens TR where the sensor is at base gain, and the
    ADC caps the clip charge."""
    r, cal, idx = fit
    h = np.array([2.0])
    tr0, _ = tonal_range_at_exposure(r, h, calibration=cal, idx=idx)
    w, c = B.widened(r, cal, B.table1_range_factors(1.75, idx.size, seed=3), idx)
    tr1, _ = tonal_range_at_exposure(w, h, calibration=c)
    b0, b1 = np.log2(tr0[:, 0]), np.log2(tr1[:, 0])
    assert np.ptp(np.quantile(b1, [0.025, 0.975])) > 10 * np.ptp(np.quantile(b0, [0.025, 0.975]))
    assert np.median(b1) > np.median(b0)
    md = r.metadata
    top = (2 ** int(md["adc_bits"]) - 1 - float(md["black_level_dn"])) * w.draws["conversion_gain_e_per_dn"]
    assert np.all(w.draws["full_well_e"] <= top + 1e-9)
