"""The exposure-time unit check from the table as a whole (issue 49): an 8-bit camera whose µs
exposure times were written where ns were expected, whose dark variance rises only 3.6 standard
errors over the (wrong) times and whose dark mean falls with exposure (the camera corrects its
offset), gets the ``exposure_time_unit`` warning; the same table with the right times does not.

The table is simulated frame by frame (bayescap.simulate: 96×96 pixels, 16 levels up to 4 ms); the
camera's offset correction is applied to the simulated means afterwards (the dark signal's mean
taken off, overshooting by 0.03 DN at the longest time)."""

from __future__ import annotations

import numpy as np
import pytest

import bayescap
from bayescap.io import plausibility as P
from bayescap.io.ptc_csv import write_ptc_csv
from bayescap.simulate import SensorTruth, exposure_series, simulate_ptc

TRUTH = SensorTruth(
    conversion_gain_e_per_dn=49.0,
    read_noise_e=16.0,
    full_well_e=11500.0,
    dark_current_e_per_s=300.0,
    quantum_efficiency=0.5,
    adc_bits=8,
    black_level_dn=10.3,
)
COLUMNS = (
    "exposure_time_s",
    "mean_dn",
    "temporal_var_dn2",
    "dark_mean_dn",
    "dark_temporal_var_dn2",
    "n_pixels",
    "photons_per_pixel",
    "frac_saturated",
)


def _camera(tmp_path, scale_t):
    photons, t = exposure_series(TRUTH, 16, t_max_s=0.004)
    d = simulate_ptc(TRUTH, photons_per_pixel=photons, exposure_time_s=t, shape=(96, 96), seed=3)
    cols = {k: np.asarray(getattr(d, k), float) for k in COLUMNS}
    tt = cols["exposure_time_s"]
    corr = TRUTH.dark_current_e_per_s * tt / TRUTH.conversion_gain_e_per_dn + 0.03 * tt / tt.max()
    cols["dark_mean_dn"] = cols["dark_mean_dn"] - corr
    cols["mean_dn"] = np.where(cols["frac_saturated"] < 1, cols["mean_dn"] - corr, cols["mean_dn"])
    cols["exposure_time_s"] = tt * scale_t
    path = tmp_path / f"cam_{scale_t:g}.csv"
    write_ptc_csv(cols, path, metadata={"sensor": "8-bit camera", "adc_bits": 8})
    return bayescap.load(path)


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    folder = tmp_path_factory.mktemp("unit")
    return _camera(folder, 1e-3), _camera(folder, 1.0)


def test_the_case_is_the_real_one(tables):
    """A weak dark-variance ramp (below the single-ramp check's 5 standard errors) and a falling
    dark mean: the single-ramp check says nothing."""
    wrong, _ = tables
    t = np.asarray(wrong.exposure_time_s)
    _, z = P._ramp(t, np.asarray(wrong.dark_temporal_var_dn2))
    slope_mean, _ = P._ramp(t, np.asarray(wrong.dark_mean_dn))
    assert 3.0 < z < P.RAMP_MIN_SIGNIFICANCE and slope_mean < 0
    assert P._dark_ramp_warning(wrong, P._gain_e_per_dn(wrong)) is None


def test_table_as_a_whole_names_the_unit(tables):
    wrong, right = tables
    w = {x["code"]: x for x in P.plausibility_warnings(wrong)}
    assert "exposure_time_unit" in w
    assert w["exposure_time_unit"]["factor"] == 1e3
    assert "µs written where ns were expected" in w["exposure_time_unit"]["message"]
    assert "exposure_time_unit" not in {x["code"] for x in P.plausibility_warnings(right)}


def test_bundled_tables_give_no_unit_warning():
    """No false alarm on the bundled sensors (the real Basler set, the Gpixel-based, the simulated
    and the benchmark stand-ins)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "data"
    paths = sorted(p for p in root.rglob("*.csv") if "sensor_specs" not in p.parts)
    checked = 0
    for p in paths:
        try:
            d = bayescap.load(p)
        except Exception:  # not a photon-transfer table (frame lists, MTF tables)
            continue
        checked += 1
        assert "exposure_time_unit" not in {x["code"] for x in P.plausibility_warnings(d)}, p
    assert checked >= 10
