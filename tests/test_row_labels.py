"""Which down-weighted rows are called outliers: a corrupted row is; rows in the clip and
runs of neighbouring rows (a shape the model does not follow) are flagged for what they are."""

from types import SimpleNamespace

import numpy as np

import bayescap
from bayescap.posterior.checks import ChecksMixin


def _result(outlier_rows, frac_saturated=None, residual_z=None):
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    if frac_saturated is not None:
        d = d.select(np.ones(d.n_levels, bool))
        object.__setattr__(d, "frac_saturated", np.asarray(frac_saturated, float))
    r = SimpleNamespace(model=SimpleNamespace(data=d), notes=[], flags={})
    r.outliers = [{"row": int(x), "block": "bright_var", "probability": 0.9} for x in outlier_rows]
    r.NEAR_CLIP_FRACTION, r.RUN_LENGTH = ChecksMixin.NEAR_CLIP_FRACTION, ChecksMixin.RUN_LENGTH
    r.DEPART_Z, r.MOSTLY_CLIPPED = ChecksMixin.DEPART_Z, ChecksMixin.MOSTLY_CLIPPED
    ChecksMixin._separate_systematic_rows(r, residual_z)
    return r, d


def test_an_isolated_row_stays_an_outlier_and_a_run_becomes_structure():
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    order = [int(x) for x in np.asarray(d.row_numbers)[np.argsort(d.mean_dn - d.dark_mean_dn, kind="stable")]]
    run = order[20:24]  # four neighbours along the signal
    lone = order[5]
    r, _ = _result(run + [lone])
    assert [o["row"] for o in r.outliers] == [lone]
    assert sorted(r.flags["structured_residuals"]) == sorted(run)
    assert any("depart from the model together" in n for n in r.notes)
    # two neighbours are not yet a shape: both stay outliers
    r2, _ = _result(order[20:22])
    assert sorted(o["row"] for o in r2.outliers) == sorted(order[20:22]) and "structured_residuals" not in r2.flags


def test_rows_mostly_clipped_are_not_called_outliers():
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    fs = np.zeros(d.n_levels)
    top = int(np.argmax(d.mean_dn))
    fs[top] = 0.98
    label = int(np.asarray(d.row_numbers)[top])
    other = int(np.asarray(d.row_numbers)[0])
    r, _ = _result([label, other], frac_saturated=fs)
    assert r.flags["rows_in_the_clip_misfit"] == [label]
    assert [o["row"] for o in r.outliers] == [other]


def test_a_row_whose_neighbours_depart_with_it_is_structure():
    """One down-weighted row at a knee, its neighbours along the signal off the model in the same
    direction by more than DEPART_Z sd but not down-weighted: a shape, not an outlier. Neighbours
    within 1 sd, or departing the other way, leave it an outlier (a corrupted row)."""
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    order = [int(x) for x in np.asarray(d.row_numbers)[np.argsort(d.mean_dn - d.dark_mean_dn, kind="stable")]]
    row, below, above = order[30], order[29], order[31]
    base = {r: 0.3 for r in order}

    def labels(z_below, z_row, z_above):
        z = {**base, below: z_below, row: z_row, above: z_above}
        return _result([row], residual_z={"bright_var": z})[0]

    r = labels(-1.5, -6.3, -1.2)
    assert r.outliers == [] and r.flags["structured_residuals"] == [row]
    for zb, za in ((-0.5, -1.2), (+1.5, +1.2), (-1.5, +1.2)):
        r = labels(zb, -6.3, za)
        assert [o["row"] for o in r.outliers] == [row] and "structured_residuals" not in r.flags
    # the residuals of another block do not count
    z = {**base, below: -1.5, above: -1.2}
    r = _result([row], residual_z={"mean": z, "bright_var": {**base, row: -6.3}})[0]
    assert [o["row"] for o in r.outliers] == [row]


def test_a_half_clipped_row_is_in_the_clip_and_a_row_with_a_few_clipped_pixels_is_not():
    d = bayescap.load("data/simulated/sim_phone_1p75um_10bit.csv")
    order = np.argsort(d.mean_dn)
    half, few = int(order[-1]), int(order[-2])
    fs = np.zeros(d.n_levels)
    fs[half], fs[few] = 0.45, 0.05
    labels = np.asarray(d.row_numbers)
    r, _ = _result([int(labels[half]), int(labels[few])], frac_saturated=fs)
    assert r.flags["rows_in_the_clip_misfit"] == [int(labels[half])]
    assert [o["row"] for o in r.outliers] == [int(labels[few])]
    assert any("a tenth or more of their pixels clipped" in n for n in r.notes)
