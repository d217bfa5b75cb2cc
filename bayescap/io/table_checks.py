"""Checks of a photon-transfer table beyond its single values (called by
:func:`bayescap.io.ptc_csv.read_ptc_csv`): records the csv module cannot read, a metadata key given
twice, rows repeated, a lit mean far below its dark mean, a table with no row mostly unclipped.
Each refuses in one line naming the file
(and row or column)."""

from __future__ import annotations

import csv
import math

import numpy as np

from bayescap.exceptions import PTCInputError

__all__ = [
    "check_lit_not_below_dark",
    "check_repeated_rows",
    "check_some_row_mostly_unclipped",
    "DARKER_THAN_DARK_SIGMA",
    "MOSTLY_SATURATED",
]


def _check_repeated_key(seen: dict, key: str, value: str, lineno: int, path) -> None:
    """A metadata key given twice with different values is refused, naming both lines (which one
    holds is not for the reader to guess); the same value twice is harmless."""
    if key in seen and seen[key][1] != value:
        first, v0 = seen[key]
        raise PTCInputError(
            f"metadata '{key}' is given twice: '{_short(v0)}' on line {first} and '{_short(value)}' on line "
            f"{lineno}; keep one",
            path=path,
            row=f"metadata line {lineno}",
        )
    seen.setdefault(key, (lineno, value))


def _short(text: str, n: int = 40) -> str:
    return text if len(text) <= n else text[:n] + "…"


def _records(reader, path):
    """The CSV reader's records; a record the csv module cannot read (a field over its size limit,
    a NUL byte) is an input error naming its line."""
    while True:
        try:
            rec = next(reader)
        except StopIteration:
            return
        except csv.Error as e:
            raise PTCInputError(
                f"cannot read the table ({e}) near line {reader.line_num} of the table", path=path
            ) from None
        yield rec


def check_repeated_rows(cols: dict, rownums, path) -> None:
    """Refuse a table in which a data row repeats another exactly (every column): a copy-paste
    error, or rows that are not independent measurements. Taken as independent, such rows shrink
    every interval (a table repeated 10 times gives intervals ~3x narrower) around the same
    values, so the fit would report a precision the data do not have."""
    from collections import Counter

    keys = [tuple("nan" if math.isnan(x) else float(x) for x in rec) for rec in zip(*cols.values())]
    counts = Counter(keys)
    first = {}
    for k, key in enumerate(keys):
        if key in first:
            raise PTCInputError(
                f"row {rownums[k]} repeats row {rownums[first[key]]} exactly (every column; {counts[key]} copies): "
                "a copy-paste error, or rows that are not independent measurements; remove the repeats "
                "(repeated rows would narrow every interval as if they were new data)",
                path=path,
                row=rownums[k],
            )
        first[key] = k


#: a lit row whose mean sits more than this many pixel noise σ below its dark mean is refused
DARKER_THAN_DARK_SIGMA = 3.0


def check_lit_not_below_dark(d, path=None) -> None:
    """Refuse a row whose lit mean lies more than :data:`DARKER_THAN_DARK_SIGMA` pixel noise σ below
    its dark mean, σ² = ``temporal_var_dn2`` + ``dark_temporal_var_dn2`` + 1/12 DN² (quantisation).

    Light adds charge: a flat frame's mean can fall below its dark frame's by the means' own scatter
    (σ/√n_pixels, a small fraction of σ) or a black-level drift of a DN or so, never by several times
    the noise of a single pixel. Such a row is a wrong value (a zero written for a missing mean, a
    dark row from another set), and fitting it costs minutes of a sampler that cannot converge
    (the outlier term cannot place a row 60 σ below the curve in a mixture that
    converges). Every real and simulated table shipped or benchmarked here stays above −0.01 σ."""
    s = np.asarray(d.mean_dn, float) - np.asarray(d.dark_mean_dn, float)
    var = np.maximum(np.asarray(d.temporal_var_dn2, float), 0.0) + np.maximum(
        np.asarray(d.dark_temporal_var_dn2, float), 0.0
    )
    sigma = np.sqrt(var + 1.0 / 12.0)
    bad = np.nonzero(s < -DARKER_THAN_DARK_SIGMA * sigma)[0]
    if not bad.size:
        return
    i = int(bad[0])
    row = int(d.row_numbers[i]) if d.row_numbers is not None else i + 1
    raise PTCInputError(
        f"the lit mean {float(d.mean_dn[i]):g} DN is {-float(s[i]):.4g} DN below the row's dark mean "
        f"{float(d.dark_mean_dn[i]):g} DN ({-float(s[i] / sigma[i]):.1f} times a pixel's noise σ "
        f"{float(sigma[i]):.3g} DN): light cannot darken a frame; check the value (a 0 for a missing "
        "mean?) and that the dark row belongs to this exposure",
        path=path or d.source,
        row=row,
        column="mean_dn",
    )


#: a row with more of its pixels clipped than this is "mostly saturated"
MOSTLY_SATURATED = 0.5


def check_some_row_mostly_unclipped(d, path=None) -> None:
    """Refuse a table whose every row has more than half its pixels clipped (``frac_saturated`` >
    :data:`MOSTLY_SATURATED`). Such a table has no row on the photon-transfer curve: the gain,
    the well and the quantum efficiency would rest on the clipped tails of the pixel distribution
    alone, and the fit gives a tight, wrong answer (a simulated 10-bit sensor of K 4.0 e⁻/DN: K
    3.73 [3.61, 3.86], converged). Without a ``frac_saturated`` column this is not checked (the
    fully clipped case is, :func:`check_not_all_saturated`)."""
    fs = d.frac_saturated
    if fs is None or d.n_levels < 2 or not np.all(fs > MOSTLY_SATURATED):
        return
    raise PTCInputError(
        f"every row is mostly saturated (frac_saturated {float(np.min(fs)):.2f} to {float(np.max(fs)):.2f}, "
        f"above {MOSTLY_SATURATED:g} on all {d.n_levels} rows): no row lies on the photon-transfer curve, "
        "so gain, full well and quantum efficiency cannot be measured honestly; add exposures below saturation",
        path=path or d.source,
        column="frac_saturated",
    )


def check_not_all_saturated(d, path=None):
    """Refuse a series in which every row is saturated (no row on the photon-transfer curve).

    Two signatures: (1) every row clipped at the ADC (``frac_saturated`` ≥ 0.999, or the bright
    mean within 0.5 DN of the ADC maximum); (2) a plateau: the bright means do not move (spread
    within 6 standard errors of a row mean plus 0.5 DN) although the exposure
    (``photons_per_pixel``, else ``exposure_lux_s``, else ``exposure_time_s``) changes by ≥ 20 %
    — a well that clips before the read-out. Nothing can be fitted from such data (the gain
    comes out 4–100× wrong), so it is an input error. Called by :func:`read_ptc_csv` and by
    :func:`bayescap.model.saturation_flags` (so a PTCModel built from in-memory data is checked too).
    """
    path = d.source if path is None else path
    n = d.n_levels
    if n < 2:
        return
    adc = d.adc_max_dn
    fs = d.frac_saturated
    at_adc = adc is not None and bool(np.all(d.mean_dn >= adc - 0.5))
    if at_adc or (fs is not None and np.all(fs >= 0.999)):
        why = f"bright means at the ADC maximum {adc:g} DN" if at_adc else "frac_saturated ≥ 0.999 on every row"
        raise PTCInputError(
            f"every row is saturated ({why}): no row lies on the photon-transfer curve, so "
            "gain and noise cannot be measured; add exposures below saturation",
            path=path,
            column="mean_dn" if at_adc else "frac_saturated",
        )
    for col in ("photons_per_pixel", "exposure_lux_s", "exposure_time_s"):
        x = getattr(d, col)
        if x is not None and np.all(np.isfinite(x)) and np.min(x) > 0:
            break
    else:
        return
    if np.max(x) < 1.2 * np.min(x):
        return
    se = np.sqrt(np.maximum(d.temporal_var_dn2, 0.0) / d.n_pixels)
    if np.ptp(d.mean_dn) <= 6.0 * float(np.max(se)) + 0.5 and np.median(d.signal_dn) > 0:
        raise PTCInputError(
            f"every row is saturated: the bright means stay at {np.median(d.mean_dn):.1f} DN "
            f"(spread {np.ptp(d.mean_dn):.2f} DN) while {col} changes "
            f"{np.max(x) / np.min(x):.2f}×: no row lies on the photon-transfer curve, so gain "
            "and noise cannot be measured; add exposures below saturation",
            path=path,
            column="mean_dn",
        )
