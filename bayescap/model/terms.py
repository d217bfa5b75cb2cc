"""Which terms enter the fit: the data decide (:func:`select_terms`), and every left-out term
is recorded with its reason (:class:`ModelTerms`). :func:`saturation_flags` finds the fully
clipped rows and whether saturation is reached.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bayescap.exceptions import PTCInputError
from bayescap.io.ptc_csv import PTCData, check_table
from bayescap.model.dark_ramp import select_dark_mean
from bayescap.model.prediction import _QUANT_EXACT_S2
from bayescap.model.response import (
    BF_EVIDENCE_SIGMA,
    EVIDENCE_MIN,
    EVIDENCE_SIGMA,
    N_BASIS,
    RICH_BASIS,
    RICH_P_VALUE,
    VARIANCE_EVIDENCE_MIN,
    VARIANCE_EVIDENCE_SIGMA,
    response_degree_evidence,
    response_evidence,
    response_shape_evidence,
    variance_curvature_evidence,
)
from bayescap.model.response_spline import SPLINE_INTERVALS

__all__ = ["ModelTerms", "rows_at_a_skewed_clip", "rows_to_fit", "saturation_flags", "select_terms"]


@dataclass(frozen=True)
class ModelTerms:
    """Which terms the data can inform, and why the others are left out."""

    dark_current: bool
    clip: str  # "none" | "adc" (fixed at the ADC maximum) | "adc_sampled" | "well"
    clip_spread: bool
    quantum_efficiency: bool
    prnu: bool
    dsnu: bool
    robust: bool = True
    discrepancy: bool = True
    nonlinearity: bool = False
    response_degree: int = N_BASIS  # degree of the response's log-slope (bayescap.model.response)
    offset_spread: bool = False
    brighter_fatter: bool = False
    dark_mean: bool = False
    reasons: dict = field(default_factory=dict)  # term -> why it is left out
    how: dict = field(default_factory=dict)  # term -> how an included term enters (caveats)

    def names(self) -> list[str]:
        out = ["photon_shot", "read"]
        out.append("dark_current_shot" if self.dark_current else "read_plus_dark_combined")
        if self.dark_mean:
            out.append("dark_mean_ramp")
        out.append("quantization")
        if self.prnu:
            out.append("prnu")
        if self.dsnu:
            out.append("dsnu")
        if self.clip != "none":
            out.append("saturation")
        if self.discrepancy:
            out.append("variance_discrepancy")
        if self.robust:
            out.append("outlier_mixture")
        if self.quantum_efficiency:
            out += ["quantum_efficiency", "mean_discrepancy"]
        if self.nonlinearity:
            out.append("response_nonlinearity")
        if self.brighter_fatter:
            out.append("brighter_fatter")
        if self.offset_spread:
            out.append("pixel_offset_spread")
        return out


def saturation_flags(d: PTCData):
    """Rows fully clipped (plateau at the top of the series) and whether saturation is reached.

    A row is fully clipped when ``frac_saturated`` ≥ 0.999, or when its mean sits at the top of
    the series and its temporal variance has collapsed below a tenth of the peak variance (a
    well that clips before the read-out keeps only read noise there)."""
    check_table(d)  # repeated rows, every row (mostly) saturated: input errors, not fits (in-memory data too)
    v, m = d.temporal_var_dn2, d.mean_dn
    vmax = float(v.max())
    top = m >= m.max() - max(1.0, 1e-4 * m.max())
    full = top & (v < 0.1 * vmax)
    if np.any(full):
        # only rows at the plateau's own variance level (not partly clipped rows beside it)
        # (within 10 % of the plateau minimum: a row whose variance is higher still has unclipped
        # pixels — classified as fully clipped it was modelled with the read noise alone, 15–40
        # standard errors off on simulated well-clipped sensors, and inflated f; the clip-row
        # model describes it)
        v_pl = float(np.min(v[full]))
        full = full & (v <= 1.1 * v_pl + 0.01)
    partial = np.zeros_like(full)
    if d.frac_saturated is not None:
        fs = d.frac_saturated
        # within 2 DN of the ADC maximum with some but not all pixels there: partly clipped by the
        # ADC, not a well's plateau, however low its variance (an 8-bit sensor at K 0.5: K 7 % low)
        adc_part = (fs > 0) & (fs < 0.999) & (m >= d.adc_max_dn - 2.0) if d.adc_max_dn is not None else False
        full = (full & ~adc_part) | (fs >= 0.999)
        partial = (fs > 0) & ~full
    if np.all(full):
        raise PTCInputError(
            "every row is saturated (at the plateau's mean and variance): no row lies on "
            "the photon-transfer curve; add exposures below saturation",
            path=d.source,
            column="mean_dn",
        )
    i_peak = int(np.argmax(np.where(full, -np.inf, v)))
    above = (~full) & (np.arange(v.size) > i_peak)
    turnover = bool(np.any(above & (v < 0.8 * v[i_peak])))
    adc = d.adc_max_dn
    near_adc = False
    if adc is not None:
        nf = ~full
        if np.any(nf):
            near_adc = bool(np.any(m[nf] + 4.0 * np.sqrt(v[nf]) >= adc))
    reached = bool(np.any(full) or np.any(partial) or turnover or near_adc)
    return full, reached


#: an ADC clip below this many electrons: the charge's Poisson skewness there (1/√N) exceeds 0.05
SKEWED_CLIP_E = 400.0


def rows_at_a_skewed_clip(d: PTCData):
    """``(mask, clip_e)`` of the rows to leave out of a fit because they are partly clipped by the
    ADC at a clip of few electrons, or None.

    The model takes each pixel's charge near the clip as normal; at a clip of N electrons its
    Poisson skewness is 1/√N, and below :data:`SKEWED_CLIP_E` the clipped pixels' tail differs from
    the normal's enough to pull K by about a percent through the partly clipped rows, with an
    interval of a fraction of that (an 8-bit camera at K 0.5 e⁻/DN, clip ~95 e⁻: K 1.3 % high,
    ±0.7 %). The rows without clipped pixels hold the truth, and with a clip at the ADC's maximum
    the full well stays known ((max − black)·K). The clip's charge comes from a rough gain, the
    median of S/(V − V_dark) over the unclipped rows whose variance is above the rounding's floor.
    Needs ``frac_saturated``; leaves at least five rows."""
    fs = d.frac_saturated
    if fs is None or not d.has_dark_rows or d.adc_max_dn is None:
        return None
    partial = (fs > 1e-3) & (fs < 0.999)
    if not partial.any() or np.sum(~partial) < 5:
        return None
    full, reached = saturation_flags(d)
    if _clip_mechanism(d, full, reached)[0] != "adc":
        return None
    sig = d.mean_dn - d.dark_mean_dn
    shot = d.temporal_var_dn2 - d.dark_temporal_var_dn2
    ok = (fs <= 1e-3) & ~full & (d.temporal_var_dn2 >= _QUANT_EXACT_S2) & (sig > 0) & (shot > 0)
    if ok.sum() < 3:
        return None
    k = float(np.median(sig[ok] / shot[ok]))
    clip_e = (d.adc_max_dn - float(np.median(d.dark_mean_dn))) * k
    if not clip_e < SKEWED_CLIP_E:
        return None
    return partial, clip_e


def rows_to_fit(d: PTCData) -> tuple[PTCData, str | None]:
    """The data a fit should see, and a note when rows were left out: the rows partly clipped at a
    skewed ADC clip (:func:`rows_at_a_skewed_clip`)."""
    found = rows_at_a_skewed_clip(d)
    if found is None:
        return d, None
    mask, clip_e = found
    rows = d.row_numbers if d.row_numbers is not None else np.arange(1, d.n_levels + 1)
    left = ", ".join(str(int(r)) for r in np.asarray(rows)[mask])
    return d.select(~mask), (
        f"rows {left} left out: partly clipped by the ADC at about {clip_e:.0f} e⁻, where the charge's Poisson "
        f"skewness (1/√N = {1 / np.sqrt(clip_e):.2f}) makes the model's normal tail of the clipped pixels "
        "approximate enough to pull K by about a percent; the rows without clipped pixels and the clip at the "
        "ADC's maximum give the full well"
    )


def _clip_mechanism(d: PTCData, full, reached):
    """How the output clips: at the ADC maximum (everything clipped, plateau variance ≈ 0), or
    at the full well before the read-out (plateau keeps the read noise)."""
    adc = d.adc_max_dn
    if not reached:
        return "none", None
    if np.any(full):
        plateau_m = d.mean_dn[full]
        plateau_v = d.temporal_var_dn2[full]
        if adc is not None and np.all(plateau_m >= adc - 0.5):
            return "adc", (
                f"the fully clipped rows sit at the ADC maximum {adc:g} DN: the clip level "
                "is the ADC's, and the photodiode's own well may be deeper"
            )
        dark_v = _dark_variance_dn2(d)
        if np.median(plateau_v) >= 0.3 * dark_v:
            return "well", (
                "the plateau keeps the read noise: the full well clips before the read-out; "
                "its variance also informs the read noise"
            )
        return "adc_sampled", "the plateau has no noise left: an ADC-like clip at a fitted level"
    if adc is not None:
        nf = ~full
        if np.any(d.mean_dn[nf] + 4.0 * np.sqrt(d.temporal_var_dn2[nf]) >= adc):
            return "adc", f"the top rows approach the ADC maximum {adc:g} DN"
        return "well", "the variance turns over below the ADC maximum: the full well clips first"
    return "adc_sampled", "the variance turns over: a clip at a fitted level"


def select_terms(d: PTCData, *, force: dict | None = None) -> ModelTerms:
    """Decide from the data which terms enter the fit (module docstring), with reasons."""
    reasons, how = {}, {}
    t = d.exposure_time_s
    t_pos = t[t > 0]
    with np.errstate(over="ignore"):  # a subnormal exposure time: the ratio is inf, still ≥ 1.5
        multi_t = t_pos.size >= 2 and (t_pos.max() / t_pos.min() >= 1.5)
    if not multi_t:
        n_t = np.unique(t_pos).size
        reasons["dark_current"] = (
            "all rows share one exposure time" if n_t < 2 else f"the {n_t} exposure times span less than 1.5×"
        ) + ": only read² + D·t is identifiable (reported as dark_noise_e)"
    full, reached = saturation_flags(d)
    clip, why = _clip_mechanism(d, full, reached)
    if clip == "none":
        reasons["saturation"] = (
            "no row approaches saturation: the full well is reported as a lower bound (the largest measured signal)"
        )
    else:
        how["saturation"] = why
    # partially clipped rows need the spread of pixel means about the clip
    clip_spread = clip != "none"
    qe = d.photons_per_pixel is not None
    if not qe:
        reasons["quantum_efficiency"] = "no photons_per_pixel column"
    prnu = d.spatial_var_dn2 is not None and np.any(np.isfinite(d.spatial_var_dn2))
    dsnu = (d.dark_spatial_var_dn2 is not None and np.any(np.isfinite(d.dark_spatial_var_dn2))) or prnu
    if not prnu:
        reasons["prnu"] = "no spatial_var_dn2 column: pair differences cancel fixed-pattern noise"
    if not dsnu:
        reasons["dsnu"] = "no dark_spatial_var_dn2 column: pair differences cancel fixed-pattern noise"
    nonlin, bfat = _select_nonlinearity(d, full, reasons, how)
    degree = _response_degree(d, full, how) if nonlin else N_BASIS
    offsets = _select_offset_spread(d, dsnu, full, reasons, how)
    terms = dict(
        dark_current=multi_t,
        clip=clip,
        clip_spread=clip_spread,
        quantum_efficiency=qe,
        prnu=prnu,
        dsnu=dsnu,
        nonlinearity=nonlin,
        response_degree=degree,
        brighter_fatter=bfat,
        offset_spread=offsets,
    )
    if multi_t and d.has_dark_rows:
        dark_mean, why = select_dark_mean(d)
        if why:
            (how if dark_mean else reasons)["dark_mean"] = why
        terms["dark_mean"] = dark_mean
    if not d.has_dark_rows:
        terms.update(_mean_variance_terms(d, reasons, how))
    if force:
        terms.update(force)
    return ModelTerms(**terms, reasons=reasons, how=how)


# ---------------------------------------------------------------- mean/variance tables (no dark rows)


def _mean_variance_terms(d: PTCData, reasons, how) -> dict:
    """The terms of a mean/variance table (no dark pairs; :mod:`bayescap.io.ptc_csv`): the read noise
    is the photon-transfer curve's intercept, and what only dark pairs, exposure times or spatial
    columns inform is left out, each with its reason. Without ``n_pixels`` the variances' scatter is
    the fitted discrepancy alone (the variance discrepancy term is always in)."""
    reasons.pop("dark_current", None)
    reasons["dark_current"] = (
        "a mean/variance table (no dark pairs): dark current is not measured; the read noise is the "
        "photon-transfer curve's intercept, which also holds any dark-current shot noise of the flats"
    )
    for term in ("prnu", "dsnu"):
        reasons[term] = (
            "a mean/variance table: pair differences cancel fixed-pattern noise, and without dark pairs "
            "the spatial variances cannot be split into PRNU and DSNU"
        )
    how["read_noise"] = (
        "no dark pairs: the read noise is the intercept of the photon-transfer curve, "
        "variance = read²/K² + 1/12 + S/K at S → 0 (the means taken with the bias removed, "
        f"offset {float(d.dark_mean_dn[0]):g} DN)"
    )
    if not d.n_pixels_known:
        how["variance_discrepancy"] = (
            "no n_pixels column: the variances' sampling error is not known, so their whole scatter is "
            "the fitted fractional discrepancy f (no Gamma sampling term)"
        )
    return dict(dark_current=False, prnu=False, dsnu=False, discrepancy=True)


def _dark_variance_dn2(d: PTCData) -> float:
    """The dark (read-noise) variance (DN²): the median dark pair's, or, without dark pairs, the
    photon-transfer curve's intercept from a straight line through the lower half of the
    unclipped rows (at least the rounding's 1/12 DN²)."""
    if d.has_dark_rows:
        return float(np.median(d.dark_temporal_var_dn2))
    return float(np.median(intercept_variance_dn2(d)))


def intercept_variance_dn2(d: PTCData) -> np.ndarray:
    """Per row, the PTC's intercept (DN²) for a table without dark pairs (:func:`_dark_variance_dn2`):
    a least-squares line of the variance against the signal over the rows up to half the signal of
    the largest variance; a start point and a scale, never data of the likelihood."""
    s, v = d.signal_dn, d.temporal_var_dn2
    i_peak = int(np.argmax(v))
    rows = (s <= 0.5 * s[i_peak]) & (s >= 0)
    if rows.sum() < 3:
        rows = np.argsort(s)[: max(2, min(5, s.size))]
    x, y = s[rows], v[rows]
    if np.ptp(x) > 0:
        c = np.polyfit(x, y, 1)[1]
    else:
        c = float(np.min(y))
    return np.full(s.size, max(float(c), 1.0 / 12.0))


def _mean_variance_curvature_evidence(sig, var, n_pixels, rows):
    """The PTC's bend without dark pairs (the counterpart of
    :func:`~bayescap.model.response.variance_curvature_evidence`): fit ``V = c₀ + c₁ S + c₂ S²``
    over ``rows`` with relative weights (a pair variance's sampling error is proportional to it) and
    return ``(bend, se)``, the relative bend c₂ S_top / c₁ of the shot-noise part and its standard
    error. The error comes from the residual scatter (never below the sampling error when
    ``n_pixels`` is known). ``None`` with fewer than six rows or a non-increasing PTC."""
    S, V = np.asarray(sig, float), np.asarray(var, float)
    r = np.asarray(rows, bool) & np.isfinite(S) & np.isfinite(V) & (S > 0) & (V > 0)
    if r.sum() < 6:
        return None
    S, V, nu = S[r], V[r], np.asarray(n_pixels, float)[r] - 1.0
    u = S / float(S.max())
    sd = V * (np.sqrt(2.0 / nu) if np.all(np.isfinite(nu)) else 1.0)
    A = np.vstack([np.ones_like(u), u, u * u]).T / sd[:, None]
    b = V / sd
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    resid = b - A @ coef
    chi2_dof = float(resid @ resid) / max(S.size - 3, 1)
    scale = max(chi2_dof, 1.0) if np.all(np.isfinite(nu)) else chi2_dof
    try:
        cov = scale * np.linalg.inv(A.T @ A)
    except np.linalg.LinAlgError:
        return None
    _, c1, c2 = coef
    if not c1 > 0:
        return None
    g = np.array([0.0, -c2 / c1**2, 1.0 / c1])
    return float(c2 / c1), float(np.sqrt(max(g @ cov @ g, 0.0)))


def _unclipped_rows(d: PTCData, full):
    """Rows whose pixels are all below the clip: not fully clipped, no saturated pixel, more than
    4 temporal sd below the ADC maximum, and below 90 % of the signal of the largest temporal
    variance (a well that clips before the ADC bends the means there without a saturated value).
    The last rule is dropped when a row has (nearly) all its pixels at the ADC maximum
    (``frac_saturated`` ≥ 0.999): every well then holds more than the ADC reads, and a bend below
    the first saturated pixel is the response's (a soft knee), not a well's clip."""
    ok = ~full
    sig = d.mean_dn - d.dark_mean_dn
    fs = d.frac_saturated
    adc_first = fs is not None and d.adc_max_dn is not None and bool(np.any(full & (fs >= 0.999)))
    if np.any(ok) and not adc_first:
        i_peak = np.flatnonzero(ok)[int(np.argmax(d.temporal_var_dn2[ok]))]
        ok &= sig <= 0.9 * sig[i_peak]
    if d.frac_saturated is not None:
        ok &= ~(d.frac_saturated > 0)
    if d.adc_max_dn is not None:
        ok &= d.mean_dn + 4.0 * np.sqrt(np.maximum(d.temporal_var_dn2, 0.0)) < d.adc_max_dn
    return ok


def _select_nonlinearity(d: PTCData, full, reasons, how) -> tuple[bool, bool]:
    """Whether the response term and the brighter-fatter term enter (:mod:`bayescap.model.response`),
    each chosen by its own evidence over the unclipped rows from 5 % of the largest signal up.

    With photon counts: the response when the means bend against the photons (a quadratic
    curvature of at least ``EVIDENCE_MIN`` at the top, ``EVIDENCE_SIGMA`` standard errors from zero,
    or a cubic's bend of that size with a Wald χ² of at least ``EVIDENCE_SIGMA²``: S shapes have
    little quadratic part); brighter-fatter when the temporal PTC bends
    (:func:`_ptc_bends`): given the means, a response accounts for its share of the bend and the
    a₀₀ term for the rest. Without photon counts only the PTC's bend is measured, and the response
    term (flexible enough for either reading) fits it: the two cannot be told apart."""
    sig = d.mean_dn - d.dark_mean_dn
    ok = _unclipped_rows(d, full)
    if not np.any(ok):
        reasons["response_nonlinearity"] = "no unclipped row to measure the response on"
        reasons["brighter_fatter"] = "no unclipped row to measure the photon-transfer curve's bend on"
        return False, False
    rows = ok & (sig >= 0.05 * sig[ok].max())
    if d.photons_per_pixel is None and not d.has_dark_rows:
        return False, _mean_variance_bend(d, sig, rows, reasons, how)
    if d.photons_per_pixel is None:
        reasons["brighter_fatter"] = (
            "no photons_per_pixel column: a brighter-fatter variance loss and a response non-linearity bend the "
            "photon-transfer curve alike and cannot be told apart; the response term describes either"
        )
        return _select_ptc_curvature(d, sig, rows, reasons, how), False
    photons = np.asarray(d.photons_per_pixel, float)
    ev = response_evidence(sig, photons, rows)
    if ev is None:
        reasons["response_nonlinearity"] = "fewer than five unclipped rows with photons: the response is not measured"
        reasons["brighter_fatter"] = "fewer than five unclipped rows: the photon-transfer curve's bend is not measured"
        return False, False
    a, se = ev
    quad = abs(a) >= EVIDENCE_MIN and abs(a) >= EVIDENCE_SIGMA * se
    shape = response_shape_evidence(sig, photons, rows)
    cubic = shape is not None and shape[0] >= EVIDENCE_MIN and shape[1] >= EVIDENCE_SIGMA**2
    bf, bf_text = _brighter_fatter_evidence(d, sig, rows, a, se)
    if bf:
        how["brighter_fatter"] = (
            bf_text + ": a brighter-fatter term (the shot variance (exp(2·a00·μ) − 1)/(2·a00), Astier et al. 2019) "
            "enters the variances only; the means against the photons decide how much of the bend is the response's"
        )
    else:
        reasons["brighter_fatter"] = bf_text
    if quad or cubic:
        dev = a if quad else shape[0]
        how["response_nonlinearity"] = (
            f"the means bend against the photons: {100 * dev:+.2g} % at the top of the unclipped rows "
            f"(± {100 * se:.2g} %); a monotone response (log-slope in a Bernstein basis, shrunk towards "
            "linear) enters the means and the variances"
        )
        return True, bf
    reasons["response_nonlinearity"] = (
        f"the means are linear in the photons within the data's precision: {100 * a:+.2g} ± {100 * se:.2g} % "
        "at the top of the unclipped rows"
    )
    return False, bf


def _mean_variance_bend(d: PTCData, sig, rows, reasons, how) -> bool:
    """A mean/variance table (astronomers' flat pairs, no dark pairs, no photon counts): the PTC's bend
    is always fitted, by the brighter-fatter term (Astier et al. 2019's a₀₀ model, LSST cp_pipe's
    EXPAPPROXIMATION; one parameter). CCD flats show brighter-fatter, and a bend as small as such a
    table's sampling error allows moves a straight line's K by several of its standard errors (about
    three quarters of the bend at the top); fitted, K's interval carries it. A response non-linearity
    bends the PTC alike and cannot be told apart without photon counts: the response term stays out."""
    ev = _ptc_bends(d, sig, rows)
    measured = (
        "" if ev is None else f" (it bends {100 * ev[0]:+.2g} ± {100 * ev[1]:.2g} % at the top of the unclipped rows)"
    )
    how["brighter_fatter"] = (
        "a mean/variance table: the photon-transfer curve's bend is always fitted by the brighter-fatter term "
        "(Astier et al. 2019's a00 model, as LSST cp_pipe fits flat pairs)" + measured + ": a bend within the "
        "table's sampling error would move a straight line's K by several of its standard errors, so K's "
        "interval carries it"
    )
    reasons["response_nonlinearity"] = (
        "a mean/variance table (no photon counts): a response non-linearity and a brighter-fatter loss bend the "
        "photon-transfer curve alike and cannot be told apart; the brighter-fatter term describes the bend"
    )
    return True


def _brighter_fatter_evidence(d: PTCData, sig, rows, a, se_a) -> tuple[bool, str]:
    """Whether the temporal PTC loses more variance than the response of the means explains.

    A response ``S ∝ x(1 + a·x/x_top)`` (the means' quadratic curvature ``a`` against the photons,
    :func:`~bayescap.model.response.response_evidence`) bends the PTC by about ``3a`` at the top
    (the local gain squared over the compressed signal); brighter-fatter is what is left. It only
    lowers the variance (charge pushes later charge to the neighbours: a₀₀ < 0 in Astier's
    convention), so the term enters on a residual loss of at least ``VARIANCE_EVIDENCE_MIN`` and
    ``BF_EVIDENCE_SIGMA`` standard errors deep. Returns ``(enters, sentence)``."""
    bend = _ptc_bends(d, sig, rows)
    if bend is None:
        return False, "fewer than five unclipped rows: the photon-transfer curve's bend is not measured"
    rest = bend[0] - 3.0 * a
    se = float(np.hypot(bend[1], 3.0 * se_a))
    said = (
        f"the temporal PTC bends {100 * bend[0]:+.2g} % (± {100 * bend[1]:.2g} %) at the top of the unclipped rows, "
        f"the response of the means {100 * 3 * a:+.2g} % of it: {100 * rest:+.2g} ± {100 * se:.2g} % left"
    )
    if rest < 0 and -rest >= VARIANCE_EVIDENCE_MIN and -rest >= BF_EVIDENCE_SIGMA * se:
        return True, said
    if rest > 0:
        return False, said + " (brighter-fatter can only lower the variance)"
    return False, said + f" (within {BF_EVIDENCE_SIGMA:g} standard errors of none)"


def _ptc_bends(d: PTCData, sig, rows):
    """``(bend, se, significant)`` of the temporal PTC over ``rows``
    (:func:`~bayescap.model.response.variance_curvature_evidence`), significant when the bend is at
    least ``VARIANCE_EVIDENCE_MIN`` and ``VARIANCE_EVIDENCE_SIGMA`` standard errors from zero; None
    with too few rows."""
    # rounding: below ½ DN² a pair variance is not σ² + 1/12 and bends with the signal on a linear
    # sensor (an 8-bit camera at K 130 e⁻/DN "bent" −26 %); only rows above it measure the bend, and
    # with a dark variance below it the intercept is fitted instead of subtracted
    rows = rows & (d.temporal_var_dn2 >= _QUANT_EXACT_S2)
    if d.has_dark_rows and np.median(d.dark_temporal_var_dn2) >= _QUANT_EXACT_S2:
        ev = variance_curvature_evidence(sig, d.temporal_var_dn2, d.dark_temporal_var_dn2, d.n_pixels, rows)
    else:  # a mean/variance table, or dark rows below the rounding's floor: the intercept is fitted with the bend
        ev = _mean_variance_curvature_evidence(sig, d.temporal_var_dn2, d.n_pixels, rows)
    if ev is None:
        return None
    bend, se = ev
    return bend, se, bool(abs(bend) >= VARIANCE_EVIDENCE_MIN and abs(bend) >= VARIANCE_EVIDENCE_SIGMA * se)


def _select_ptc_curvature(d: PTCData, sig, rows, reasons, how) -> bool:
    """Without photons: the response term enters when the temporal PTC (variance less the dark
    variance, against the signal) bends by at least ``VARIANCE_EVIDENCE_MIN`` at the top of the
    rows, ``VARIANCE_EVIDENCE_SIGMA`` standard errors (its sampling error) from zero. The variances fix the
    bend and the small-signal gain; whether the response or the variance bends (a
    brighter-fatter-like loss) needs the means against the photons."""
    ev = _ptc_bends(d, sig, rows)
    if ev is None:
        reasons["response_nonlinearity"] = (
            "no photons_per_pixel column and fewer than five unclipped rows: the PTC's curvature is not measured"
        )
        return False
    bend, se, significant = ev
    if significant:
        how["response_nonlinearity"] = (
            f"no photons_per_pixel column, and the temporal PTC bends {100 * bend:+.2g} % (± {100 * se:.2g} %) "
            "at the top of the unclipped rows: fitted as a monotone response (log-slope in a Bernstein basis), "
            "from the variances alone. K is the small-signal gain either way (its interval is wider: only the low "
            "rows pin it), but a variance loss that leaves the means straight (brighter-fatter) bends the PTC "
            "alike: the response's shape and the linearity error assume the response reading; photon counts "
            "would tell the two apart"
        )
        return True
    reasons["response_nonlinearity"] = (
        f"no photons_per_pixel column, and the temporal PTC is straight within its sampling error: "
        f"{100 * bend:+.2g} ± {100 * se:.2g} % at the top of the unclipped rows"
    )
    return False


def _response_degree(d: PTCData, full, how) -> int:
    """The response's log-slope, as its number of coefficients: richer when a degree-4 shape leaves
    structure (:func:`~bayescap.model.response.response_degree_evidence` at :data:`RICH_P_VALUE`,
    over the rows the response is selected on; with photon counts an F-test on the means against
    the photons, without them on the temporal PTC, or the degree-4 proxy's χ²), else
    :data:`N_BASIS`. The richer shape is the local spline (:data:`RICH_BASIS` values, its knots
    crowding towards the clip), so a knee or a kink does not pull the low rows that pin K, and a
    soft knee's steep log-slope just below the clip is followed (a degree-8 polynomial does not
    follow it there, docs/real_sensors.md)."""
    sig = d.mean_dn - d.dark_mean_dn
    ok = _unclipped_rows(d, full)
    if not np.any(ok):
        return N_BASIS
    rows = ok & (sig >= 0.05 * sig[ok].max())
    if d.photons_per_pixel is not None:
        ev = response_degree_evidence(np.asarray(d.photons_per_pixel, float), sig, np.abs(sig), rows)
        what = "the means against the photons"
    else:
        V, Vd = d.temporal_var_dn2, d.dark_temporal_var_dn2
        sd = np.sqrt(2.0 * (V**2 + Vd**2) / np.maximum(d.n_pixels - 1.0, 1.0))
        ev = response_degree_evidence(sig, V - Vd, sd, rows & (V >= _QUANT_EXACT_S2), sd_known=True)
        what = "the temporal photon-transfer curve"
    if ev is None or not ev[0] < RICH_P_VALUE:
        return N_BASIS
    photons = d.photons_per_pixel is not None
    how["response_nonlinearity"] = how.get("response_nonlinearity", "") + (
        f"; {what} has a shape a degree-{N_BASIS} log-slope does not follow (a knee or a kink: "
        f"{'F-test' if photons else 'F-test or χ²'} p = {ev[0]:.1g} over {ev[1]} rows), so the log-slope is "
        f"a quadratic spline on {SPLINE_INTERVALS} intervals (local: it bends only near a knee or kink)"
    )
    return RICH_BASIS


def _select_offset_spread(d: PTCData, dsnu: bool, full, reasons, how) -> bool:
    """Without spatial columns (no DSNU term) the spread of the pixels' mean offsets about the
    integer DN grid is unknown; rounding depends on it where the temporal noise is below the
    quantization floor (variance < 0.6 DN²): there it is a nuisance parameter."""
    if dsnu:
        return False
    low = np.concatenate([d.dark_temporal_var_dn2, d.temporal_var_dn2[~full]])
    if np.any(low < 0.6):
        how["pixel_offset_spread"] = (
            "rows below the quantization floor and no spatial column: the spread of the pixels' mean "
            "offsets (DSNU) about the DN grid is fitted, so rounding is averaged over it"
        )
        return True
    return False
