"""Plausibility checks of a photon-transfer table: values every reader accepts one by one, which
together say that a unit or a file is wrong.

* ``exposure_time_unit``: the dark signal grows with the exposure time at a rate that implies an
  absurd dark current (above :data:`MAX_DARK_CURRENT_E_PER_S`): the exposure times are too short by
  a factor of 10³ (µs written where ns were expected, as in an EMVA 1288 descriptor written in µs)
  or more.
  When no ramp is that significant, the table as a whole is asked (:func:`table_unit_warning`):
  the dark variance's implied dark current at the *lower* end of its 97.7 % one-sided bound
  against :data:`MAX_DARK_CURRENT_E_PER_S`, and the photons per second the photon counts and the
  times imply against :data:`MAX_PHOTON_FLUX_PER_PIXEL_S` (a weaker hint that decides only
  together with a positive dark ramp).
* ``photons_inconsistent``: the photon counts and the signal imply a quantum efficiency above 1 or
  below :data:`MIN_QE`.
* ``zero_pair_variance``: a pair variance of exactly 0 below the clip level: the two frames of the
  pair are identical (one file used twice).
* ``dark_equals_bright``: a row whose bright and dark statistics are identical (a frame used as
  its own dark).

Each warning names the rows and the likely cause; nothing here refuses a table (a refusal is for
data that cannot be right: :func:`bayescap.io.ingest.ingest` refuses a pair made of one file).
The conversion gain these checks use is the EMVA 1288 estimate (the photon-transfer slope up to
70 % of the largest signal), good enough to tell a factor of 1 000.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "plausibility_warnings",
    "table_unit_warning",
    "MAX_DARK_CURRENT_E_PER_S",
    "MAX_PHOTON_FLUX_PER_PIXEL_S",
    "MIN_QE",
]

#: a dark current above this (e⁻/s per pixel) is not a sensor at room temperature: the hottest
#: uncooled CMOS sensors reach 10³–10⁴ e⁻/s
MAX_DARK_CURRENT_E_PER_S = 1e5

#: photons per pixel per second above this are not a photon-transfer set-up (a 10 000 e⁻ well
#: filled in a microsecond); a tenth of it is a bright laboratory source at the edge of plausible
MAX_PHOTON_FLUX_PER_PIXEL_S = 1e10

#: the one-sided bound (in standard errors) the dark ramp's lower end is taken at
RAMP_LOWER_BOUND_SE = 2.0

#: a quantum efficiency below this is a unit problem, not a sensor
MIN_QE = 1e-4

#: the ratio slope / standard error of the dark ramp above which the ramp counts as seen
RAMP_MIN_SIGNIFICANCE = 5.0

#: what a factor of 10³, 10⁶, 10⁹ too short usually is
_UNIT_HINTS = {
    1e3: "µs written where ns were expected (an EMVA 1288 descriptor gives ns), or ms where µs were",
    1e6: "ms written where ns were expected, or s where µs were",
    1e9: "s written where ns were expected",
}


_FACTOR_TEXT = {1e3: "1 000", 1e6: "10⁶", 1e9: "10⁹"}


def _rows(data, idx) -> str:
    labels = [str(data.row_label(int(i))) for i in idx]
    return ", ".join(labels[:8]) + (" …" if len(labels) > 8 else "")


def _gain_e_per_dn(data):
    """EMVA 1288's K (as e⁻/DN): slope of the dark-subtracted variance against the signal through
    the origin, over the rows below 70 % of the largest signal; None when not positive."""
    s = np.asarray(data.mean_dn, float) - np.asarray(data.dark_mean_dn, float)
    v = np.asarray(data.temporal_var_dn2, float) - np.asarray(data.dark_temporal_var_dn2, float)
    ok = np.isfinite(s) & np.isfinite(v) & (s > 0) & (s <= 0.7 * np.nanmax(s))
    if data.adc_max_dn is not None:
        ok &= np.asarray(data.mean_dn, float) < 0.9 * data.adc_max_dn
    if ok.sum() < 2:
        return None
    slope = float(np.sum(s[ok] * v[ok]) / np.sum(s[ok] ** 2))
    return 1.0 / slope if slope > 0 and np.isfinite(slope) else None


def _ramp(t, y):
    """Least-squares slope of y against t and its significance (slope / standard error)."""
    a, b = np.polyfit(t, y, 1)
    r = y - (a * t + b)
    n = t.size
    se = np.sqrt(np.sum(r * r) / max(n - 2, 1) / max(np.sum((t - t.mean()) ** 2), 1e-300))
    return float(a), (float(abs(a) / se) if se > 0 else np.inf)


def _dark_ramp_warning(data, k_e):
    t = np.asarray(data.exposure_time_s, float)
    if np.unique(t).size < 3 or k_e is None:
        return None
    rates = []
    dm = np.asarray(data.dark_mean_dn, float)
    a, z = _ramp(t, dm)
    if a > 0 and z > RAMP_MIN_SIGNIFICANCE:
        rates.append(("dark mean", a * k_e, a * np.ptp(t)))
    vd = np.asarray(data.dark_temporal_var_dn2, float)
    a, z = _ramp(t, vd)
    if a > 0 and z > RAMP_MIN_SIGNIFICANCE:
        rates.append(("dark variance", a * k_e * k_e, None))
    if not rates:
        return None
    what, rate, rise_dn = max(rates, key=lambda r: r[1])
    if not rate > MAX_DARK_CURRENT_E_PER_S:
        return None
    factor = next((f for f in (1e3, 1e6, 1e9) if rate / f <= MAX_DARK_CURRENT_E_PER_S), 1e9)
    rise = f" (the dark mean rises {rise_dn:.3g} DN)" if rise_dn is not None else ""
    return {
        "code": "exposure_time_unit",
        "factor": factor,
        "implied_dark_current_e_per_s": rate,
        "message": (
            f"exposure times look {_FACTOR_TEXT[factor]} times too short: the {what} grows over "
            f"{t.min():.3g}–{t.max():.3g} s{rise} at a rate that means a dark current of {rate:.3g} e-/s "
            f"(with K ≈ {k_e:.3g} e-/DN), above any sensor's {MAX_DARK_CURRENT_E_PER_S:.0e} e-/s; likely "
            f"{_UNIT_HINTS[factor]}. exposure_time_s is in seconds"
        ),
    }


def _photon_warning(data, k_e):
    mu_p = data.photons_per_pixel
    if mu_p is None or k_e is None:
        return None
    mu_p = np.asarray(mu_p, float)
    s = np.asarray(data.mean_dn, float) - np.asarray(data.dark_mean_dn, float)
    ok = np.isfinite(mu_p) & (mu_p > 0) & (s > 0) & (s <= 0.7 * np.nanmax(s))
    if ok.sum() < 2:
        return None
    qe = float(np.sum(mu_p[ok] * s[ok]) / np.sum(mu_p[ok] ** 2)) * k_e
    if MIN_QE <= qe <= 1.0 + 0.1:  # the recipe's K is good to a few %
        return None
    side = (
        "above 1: photons_per_pixel is too small (photons per µm² rather than per pixel? an irradiance "
        "without the exposure time?)"
        if qe > 1
        else f"below {MIN_QE:g}: photons_per_pixel is too large (a unit or a factor of the pixel area?)"
    )
    return {
        "code": "photons_inconsistent",
        "implied_quantum_efficiency": qe,
        "message": f"the photon counts and the signal imply a quantum efficiency of {qe:.3g} (with K ≈ "
        f"{k_e:.3g} e-/DN), {side}",
    }


def _photon_flux(data):
    """Photons per pixel per second of the rows below 70 % of the largest signal: the median of
    photons_per_pixel / exposure_time_s, or None without photon counts."""
    if data.photons_per_pixel is None:
        return None
    mu_p, t = np.asarray(data.photons_per_pixel, float), np.asarray(data.exposure_time_s, float)
    s = np.asarray(data.mean_dn, float) - np.asarray(data.dark_mean_dn, float)
    ok = np.isfinite(mu_p) & (mu_p > 0) & (t > 0) & (s > 0) & (s <= 0.7 * np.nanmax(s))
    return float(np.median(mu_p[ok] / t[ok])) if ok.any() else None


def table_unit_warning(data, k_e=None):
    """``exposure_time_unit`` from the table as a whole, where no single ramp is significant enough
    for :func:`_dark_ramp_warning` (an 8-bit camera's dark variance rises 3–4 standard errors over
    the times, its dark mean falls as the camera corrects its offset):

    * the dark variance's ramp, at the lower end of its one-sided bound (slope − 2 standard errors),
      still implies a dark current above :data:`MAX_DARK_CURRENT_E_PER_S`: even the least the data
      allow is no sensor's;
    * or the ramp is positive by 2 standard errors, its central rate above that maximum, and the
      photon counts over the times give more than a tenth of
      :data:`MAX_PHOTON_FLUX_PER_PIXEL_S` photons per pixel per second: two independent signs;
    * or the photons per second alone exceed :data:`MAX_PHOTON_FLUX_PER_PIXEL_S`.

    None when the table says nothing against its times."""
    k_e = _gain_e_per_dn(data) if k_e is None else k_e
    t = np.asarray(data.exposure_time_s, float)
    flux = _photon_flux(data)
    why, rate = [], None
    if np.unique(t).size >= 3 and k_e is not None:
        vd = np.asarray(data.dark_temporal_var_dn2, float)
        a, z = _ramp(t, vd)
        if a > 0 and np.isfinite(z) and z > 0:
            rate = a * k_e * k_e
            low = rate * (1.0 - RAMP_LOWER_BOUND_SE / z)
            if low > MAX_DARK_CURRENT_E_PER_S:
                why.append(
                    f"the dark variance grows over {t.min():.3g}–{t.max():.3g} s at {z:.1f} standard errors, so the "
                    f"dark current is at least {low:.3g} e-/s (central {rate:.3g} e-/s, K ≈ {k_e:.3g} e-/DN), above "
                    f"any sensor's {MAX_DARK_CURRENT_E_PER_S:.0e} e-/s"
                )
            elif (
                z >= RAMP_LOWER_BOUND_SE
                and rate > MAX_DARK_CURRENT_E_PER_S
                and flux
                and flux > 0.1 * MAX_PHOTON_FLUX_PER_PIXEL_S
            ):
                why.append(
                    f"the dark variance's ramp ({z:.1f} standard errors) means a dark current of {rate:.3g} e-/s and "
                    f"the photon counts {flux:.3g} photons per pixel per second: both far above what sensors and "
                    "light sources give"
                )
    if not why and flux and flux > MAX_PHOTON_FLUX_PER_PIXEL_S:
        why.append(
            f"the photon counts over the exposure times are {flux:.3g} photons per pixel per second, above "
            f"{MAX_PHOTON_FLUX_PER_PIXEL_S:.0e} (a 10 000 e- well filled in a microsecond)"
        )
    if not why:
        return None
    return {
        "code": "exposure_time_unit",
        "factor": 1e3,
        "implied_dark_current_e_per_s": rate,
        "photons_per_pixel_per_s": flux,
        "message": "exposure times look 1 000 times too short: " + "; ".join(why) + f"; likely {_UNIT_HINTS[1e3]}. "
        "exposure_time_s is in seconds",
    }


def plausibility_warnings(data) -> list[dict]:
    """The plausibility warnings of a :class:`~bayescap.io.ptc_csv.PTCData`: a list of dicts with
    ``code``, ``message`` (the rows and the likely cause) and the numbers behind them."""
    out = []
    m = np.asarray(data.mean_dn, float)
    v = np.asarray(data.temporal_var_dn2, float)
    dm = np.asarray(data.dark_mean_dn, float)
    vd = np.asarray(data.dark_temporal_var_dn2, float)
    below_clip = np.ones(m.size, bool)
    if data.adc_max_dn is not None:
        below_clip &= m < data.adc_max_dn - 0.5
    if data.frac_saturated is not None:
        below_clip &= np.asarray(data.frac_saturated, float) < 1.0
    same = np.flatnonzero((m == dm) & (v == vd))
    if same.size:
        out.append(
            {
                "code": "dark_equals_bright",
                "rows": [int(data.row_label(int(i))) for i in same],
                "message": f"row(s) {_rows(data, same)}: the bright and dark statistics are identical: "
                "the same frames were used as the bright pair and as its dark",
            }
        )
    zero = np.flatnonzero((v == 0) & below_clip)
    zero_d = np.flatnonzero(vd == 0)
    for idx, which in ((zero, "bright"), (zero_d, "dark")):
        idx = np.setdiff1d(idx, same)
        if idx.size:
            out.append(
                {
                    "code": "zero_pair_variance",
                    "rows": [int(data.row_label(int(i))) for i in idx],
                    "message": f"row(s) {_rows(data, idx)}: the {which} pair variance is exactly 0"
                    + (" below the clip level" if which == "bright" else "")
                    + ": the two frames of the pair are identical (one file used twice?)",
                }
            )
    k_e = _gain_e_per_dn(data)
    for w in (_dark_ramp_warning(data, k_e) or table_unit_warning(data, k_e), _photon_warning(data, k_e)):
        if w is not None:
            out.append(w)
    return out
