"""The dark means' ramp: the dark current's second witness, in the likelihood when it agrees.

A dark current ``D`` raises the dark *variances* as ``D·t/K²`` and the dark *means* as ``D·t/K``.
EMVA 1288 measures it from the means' slope against the exposure time, and from the variances
when the camera clamps its black level (a clamp holds the means flat while the charge grows). The
means are the sharper witness by far: a dark mean over n pixels has an error √(var/2n), so with
10⁴ pixels a slope of a few hundredths of a DN per second is seen, where the variances need D·t
of several per cent of the read variance. Their risk is the black level itself: a clamp, a drift
with the sensor's temperature or a light leak moves them with no dark current at all.

So the means enter the likelihood (:func:`select_dark_mean`) only where both witnesses exist and
agree, before any fit:

1. the means follow a shift one for one: the pixels spread over at least
   :data:`MEAN_SPREAD_MIN_DN` about the DN grid (below, the rounded mean's response to a shift
   swings between ~0 and ~1 with its offset);
2. the dark variances alone see a ramp, :data:`VAR_RAMP_Z` standard errors above zero (their
   sampling errors times their line's Birge ratio, below): where they
   do not, the means would be the only witness, and a drifting black level could not be told from
   a dark current (the dark current stays the variances' limit);
3. the two slopes give the same ``D/K`` within :data:`AGREE_Z` standard errors, the variances'
   slope converted with a rough gain (the median of S/(V − V_dark), given
   :data:`K_REL_SD` relative uncertainty), each slope's error times its Birge ratio.

In the likelihood the dark means are ``b + (D/K)·t`` with the black level ``b`` profiled (their
weighted mean, less the slope times the weighted mean time; for a straight line with normal errors
the profile and the marginal over a flat prior on ``b`` give ``D/K`` the same likelihood). Each
row's error is its temporal one, √(var/2n), times the line's Birge ratio √(χ²/(n − 2)) when the
means scatter about their line more than that (a frame-to-frame offset noise, or a slow drift).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "MEAN_SPREAD_MIN_DN",
    "VAR_RAMP_Z",
    "AGREE_Z",
    "K_REL_SD",
    "DarkMeanLine",
    "weighted_slope",
    "mean_ramp",
    "dark_mean_line",
    "select_dark_mean",
]

#: the dark means witness a shift one for one where the pixels spread over at least this much (DN)
#: about the DN grid: the rounded mean's derivative is then 1 within 2·exp(−2π²s²) = 1.4 %
MEAN_SPREAD_MIN_DN = 0.5
#: the dark variances' own ramp must stand this many standard errors above zero for the means to enter
VAR_RAMP_Z = 3.0
#: the means' D/K and the variances' must agree within this many standard errors
AGREE_Z = 3.0
#: the relative uncertainty given to the rough gain that converts the variances' slope (DN²/s) to D/K
K_REL_SD = 0.10


def weighted_slope(t, y, sd):
    """Weighted least-squares line of ``y`` against ``t`` (row errors ``sd``): ``(slope, se, chi2,
    n)``, or None with fewer than three usable rows or one exposure time."""
    t, y, sd = (np.asarray(a, float) for a in (t, y, sd))
    ok = np.isfinite(t) & np.isfinite(y) & np.isfinite(sd) & (sd > 0)
    if ok.sum() < 3:
        return None
    t, y, w = t[ok], y[ok], 1.0 / sd[ok] ** 2
    tc = t - np.sum(w * t) / np.sum(w)
    stt = float(np.sum(w * tc * tc))
    if not stt > 0:
        return None
    slope = float(np.sum(w * tc * y) / stt)
    ybar = float(np.sum(w * y) / np.sum(w))
    chi2 = float(np.sum(w * (y - ybar - slope * tc) ** 2))
    return slope, float(1.0 / math.sqrt(stt)), chi2, int(ok.sum())


def _birge(fit) -> float:
    """√(χ²/(n − 2)) of a :func:`weighted_slope` line, at least 1: how much more the rows scatter about
    their line than their errors say."""
    return 1.0 if fit is None or fit[3] <= 2 else max(1.0, math.sqrt(fit[2] / (fit[3] - 2)))


def _means_follow_shifts(d) -> bool:
    vd = np.maximum(np.asarray(d.dark_temporal_var_dn2, float), 0.0)
    spread2 = float(np.median(vd))
    if d.dark_spatial_var_dn2 is not None:
        sp = np.asarray(d.dark_spatial_var_dn2, float)
        if np.any(np.isfinite(sp)):
            spread2 = max(spread2, float(np.nanmedian(sp)))
    return spread2 - 1.0 / 12.0 >= MEAN_SPREAD_MIN_DN**2  # Sheppard: the rounded values' variance less 1/12


def _mean_sd_dn(d) -> np.ndarray:
    """Each dark mean's temporal error (DN): a pair's mean over n pixels, √(var/2n)."""
    return np.sqrt(np.maximum(np.asarray(d.dark_temporal_var_dn2, float), 1e-6) / (2.0 * np.asarray(d.n_pixels, float)))


def mean_ramp(d):
    """The dark means' slope against the exposure time (DN/s, = D/K) and its standard error, or None
    with fewer than three rows or two exposure times, without dark pairs, or where the rounding bends
    the means (the pixels spread over less than :data:`MEAN_SPREAD_MIN_DN` about the DN grid, by
    temporal noise or by a fixed pattern)."""
    fit = _mean_line_fit(d)
    return None if fit is None else fit[:2]


def _mean_line_fit(d):
    """:func:`weighted_slope` of the dark means against the exposure time, or None where they are no
    witness (:func:`mean_ramp`)."""
    if not getattr(d, "has_dark_rows", True) or np.unique(np.asarray(d.exposure_time_s, float)).size < 2:
        return None
    if not _means_follow_shifts(d):
        return None
    return weighted_slope(d.exposure_time_s, d.dark_mean_dn, _mean_sd_dn(d))


@dataclass(frozen=True)
class DarkMeanLine:
    """The dark means' block of the likelihood: model ``mbar + (D/K)·tc`` with the black level
    profiled; ``sd`` each row's error (DN), Birge ratio included."""

    mbar: float  # the means' weighted mean (DN)
    tc: np.ndarray  # exposure time less the weighted mean time (s)
    sd: np.ndarray  # each row's error (DN)
    birge: float  # √(χ²/(n − 2)) of the means about their line, at least 1


def dark_mean_line(d) -> DarkMeanLine:
    """The block's constants for ``d`` (rows as in the table)."""
    t = np.asarray(d.exposure_time_s, float)
    m = np.asarray(d.dark_mean_dn, float)
    sd0 = _mean_sd_dn(d)
    birge = _birge(weighted_slope(t, m, sd0))
    sd = sd0 * birge
    w = 1.0 / sd**2
    tbar = float(np.sum(w * t) / np.sum(w))
    return DarkMeanLine(mbar=float(np.sum(w * m) / np.sum(w)), tc=t - tbar, sd=sd, birge=birge)


def _rough_gain(d):
    """The median of S/(V − V_dark) over rows with a clear shot noise, below the largest variance's
    signal (e⁻/DN), or None."""
    sig = np.asarray(d.mean_dn, float) - np.asarray(d.dark_mean_dn, float)
    v = np.asarray(d.temporal_var_dn2, float)
    shot = v - np.asarray(d.dark_temporal_var_dn2, float)
    if v.size == 0:
        return None
    peak = sig[int(np.argmax(v))]
    ok = (sig > 0) & (shot > 0.1 * v) & (sig <= 0.7 * peak) & (v >= 0.5)
    if d.frac_saturated is not None:
        ok &= ~(np.asarray(d.frac_saturated, float) > 0)
    if ok.sum() < 2:
        return None
    return float(np.median(sig[ok] / shot[ok]))


def select_dark_mean(d) -> tuple[bool, str | None]:
    """Whether the dark means enter the likelihood (the module docstring's three tests), and why:
    a sentence for the result when they enter or when the two witnesses disagree, None when the
    means cannot witness (rounding) or the variances see no ramp of their own."""
    mr = _mean_line_fit(d)
    if mr is None:
        return False, None
    t = np.asarray(d.exposure_time_s, float)
    vd = np.maximum(np.asarray(d.dark_temporal_var_dn2, float), 1e-6)
    nu = np.maximum(np.asarray(d.n_pixels, float) - 1.0, 1.0)
    vr = weighted_slope(t, vd, vd * np.sqrt(2.0 / nu))
    if vr is None or not vr[0] / (vr[1] * _birge(vr)) >= VAR_RAMP_Z:
        return False, None
    k = _rough_gain(d)
    if k is None:
        return False, None
    sv = vr[0] * k  # the variances' D/K (DN/s)
    se = math.hypot(vr[1] * _birge(vr) * k, K_REL_SD * sv, mr[1] * _birge(mr))
    z = (mr[0] - sv) / se
    if not abs(z) < AGREE_Z:
        return False, (
            f"the dark means rise by {mr[0]:.3g} DN/s, the dark variances' ramp says {sv:.3g} DN/s "
            f"({z:+.1f} standard errors): the black level moves with the exposure time (clamped, "
            "drifting, or light leaking in); the dark current is the variances' alone"
        )
    return True, (
        f"the dark means' ramp ({mr[0]:.3g} ± {mr[1] * _birge(mr):.2g} DN/s) agrees with the dark variances' "
        f"({sv:.3g} DN/s, {z:+.1f} standard errors): both witness the dark current, the black "
        "level profiled"
    )
