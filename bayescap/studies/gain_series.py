"""One sensor at several analog gains (the paper's Figs. 5, 6 and 8(a)).

The paper plots SNR against exposure "for different analog gains (i.e. varying exposure times)"
and, in Fig. 8(a), TR at a common average exposure H₀ with one point per analog gain. Here each
gain is one photon-transfer CSV (the contract's ``# analog_gain:`` metadata says which); each is
fitted **separately** through the public API (:func:`bayescap.fit`), and the parameters that the
gain does not change are checked for consistency across gains:

* shared: quantum efficiency, PRNU, dark current (e⁻/s), and the full well in e⁻ *where the well
  clips before the ADC* (at a high gain the ADC clips first and the fitted clip charge is the ADC
  range times the conversion gain, not the well; those gains are left out of the full-well check);
* per gain: conversion gain (e⁻/DN, ∝ 1/gain), read noise in e⁻ (falls with gain when part of it
  is added after the amplifier), clip charge.

The joint fit, one posterior with the shared parameters tied, is
:func:`bayescap.studies.gain_joint.fit_gain_series_jointly`; the check below tests what it assumes. For a shared parameter with per-gain medians ``m_i`` and
posterior standard deviations ``s_i``, ``χ² = Σ (m_i − m̄)²/s_i²`` with the precision-weighted mean
``m̄`` has ``n − 1`` degrees of freedom if the gains agree; the p-value is reported and a parameter
is called consistent when p > 0.01.

Per gain, ``snr_db(h)`` gives SNR against H (lux·s, Figs. 5-6) and ``tr_points()`` the Fig. 8(a)
point: at gain ``g`` a camera that puts the scene's mean at mid-grey (18 % of the top) is used at
``H₀ = 0.18 · clip_e / sensitivity``, and TR there is that gain's own TR over its full range.
:func:`simulate_gain_series` makes a simulated series (tests, notebook).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from bayescap.exceptions import CompareInputError
from bayescap.posterior import summarize
from bayescap.studies.exposure import DEFAULT_MID_GREY, exposure_calibration, snr_at_exposure

__all__ = ["SHARED", "GainSeries", "fit_gain_series", "simulate_gain_series"]

#: parameters the analog gain does not change (full well: only where the well clips first)
SHARED = ("quantum_efficiency", "prnu_percent", "dark_current_e_per_s", "full_well_e")
_P_CONSISTENT = 0.01


@dataclass
class GainSeries:
    """Separate fits of one sensor at several analog gains, sorted by gain."""

    gains: list
    results: list
    adc_limited: list  # per gain: the ADC clips before the well
    consistency: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def snr_db(self, h_lux_s, n_draws: int = 1000) -> list:
        """Per gain, SNR (dB) draws against H: arrays ``(n_draws, n_h)``, NaN above the clip."""
        out = []
        for r in self.results:
            idx = r.thin_index(n_draws)
            out.append(snr_at_exposure(r, h_lux_s, calibration=exposure_calibration(r), idx=idx))
        return out

    def tr_points(self, mid_grey: float = DEFAULT_MID_GREY, n_draws: int = 1000) -> list[dict]:
        """Per gain: the average exposure H₀ (lux·s) at which the gain is used and TR there (bits),
        as draws and summaries (Fig. 8(a) points)."""
        pts = []
        for g, r in zip(self.gains, self.results):
            idx = r.thin_index(n_draws)
            cal = exposure_calibration(r)
            if cal is None:
                raise CompareInputError(f"gain {g}: no exposure calibration (photons_per_pixel or exposure_lux_s)")
            clip, _ = r.signal_max_e({k: v[idx] for k, v in r.draws.items()})
            h0 = mid_grey * clip / cal.sensitivity_e_per_lux_s[idx]
            tr = np.asarray(r.derived["tonal_range_bits"])[idx]
            pts.append(
                {
                    "analog_gain": g,
                    "h0_lux_s": summarize(h0, "lux·s"),
                    "tonal_range_bits": summarize(tr, "bits"),
                    "h0_draws": h0,
                    "tr_draws": tr,
                }
            )
        return pts

    def to_dict(self) -> dict:
        per_gain = []
        for g, r, adc in zip(self.gains, self.results, self.adc_limited):
            per_gain.append(
                {
                    "analog_gain": g,
                    "adc_clips_first": adc,
                    "converged": bool(r.diag.get("converged")),
                    **{k: summarize(r.draws[k], "") for k in ("conversion_gain_e_per_dn", "read_noise_e", *SHARED)},
                }
            )
        return {
            "fit": "separate per gain (no joint fit)",
            "gains": per_gain,
            "consistency": self.consistency,
            "notes": list(self.notes),
        }


def _consistency(name, values: list[np.ndarray], gains) -> dict:
    m = np.array([np.median(v) for v in values])
    s = np.array([np.std(v, ddof=1) for v in values])
    w = 1.0 / s**2
    mean = float(np.sum(w * m) / np.sum(w))
    chi2 = float(np.sum((m - mean) ** 2 * w))
    dof = len(values) - 1
    p = float(stats.chi2.sf(chi2, dof)) if dof > 0 else float("nan")
    return {
        "parameter": name,
        "gains": list(gains),
        "medians": m.tolist(),
        "sd": s.tolist(),
        "weighted_mean": mean,
        "chi2": chi2,
        "dof": dof,
        "p_value": p,
        "consistent": bool(dof > 0 and p > _P_CONSISTENT),
    }


def fit_gain_series(inputs, *, seed: int = 0, quality: str = "fast", gains=None) -> GainSeries:
    """Fit each CSV / PTCData of ``inputs`` separately and check the shared parameters.

    ``gains``: the analog gain of each input; default the ``analog_gain`` metadata of each file."""
    import bayescap

    datas = [bayescap.load(x) if isinstance(x, (str, bytes)) or hasattr(x, "__fspath__") else x for x in inputs]
    if gains is None:
        gains = []
        for d in datas:
            g = d.metadata.get("analog_gain")
            if g in (None, ""):
                raise CompareInputError(f"{d.source}: no '# analog_gain:' metadata; give gains=[...]")
            gains.append(float(g))
    if len(gains) != len(datas) or len(set(gains)) != len(gains):
        raise CompareInputError(f"need one distinct analog gain per input, got {gains}")
    order = np.argsort(gains)
    gains = [float(gains[i]) for i in order]
    datas = [datas[i] for i in order]
    results = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, d in enumerate(datas):
            results.append(bayescap.fit(d, seed=seed + i, quality=quality))
    adc = []
    for d, r in zip(datas, results):
        bits = d.metadata.get("adc_bits")
        top = None if bits in (None, "") else 2.0 ** int(bits) - 1
        adc.append(bool(top is not None and np.median(r.draws["clip_dn"]) >= top - 2.0))
    notes = []
    cons = {}
    for name in SHARED:
        keep = [i for i, r in enumerate(results) if name in r.draws and not (name == "full_well_e" and adc[i])]
        if len(keep) < 2:
            notes.append(f"{name}: fewer than two gains measure it; not checked")
            continue
        cons[name] = _consistency(name, [results[i].draws[name] for i in keep], [gains[i] for i in keep])
        if not cons[name]["consistent"]:
            notes.append(f"{name} differs between gains (chi2 p = {cons[name]['p_value']:.2g})")
    if any(adc):
        notes.append(
            "the ADC clips before the well at gain(s) "
            + ", ".join(f"{g:g}" for g, a in zip(gains, adc) if a)
            + ": the full well is not measured there"
        )
    return GainSeries(gains=gains, results=results, adc_limited=adc, consistency=cons, notes=notes)


def simulate_gain_series(truth, gains, *, read_noise_pre_e: float, read_noise_post_dn: float, seed: int = 0, **kw):
    """Simulated PTCData, one per analog gain: ``K_g = K_1/g`` and read noise
    ``sqrt(r_pre² + (σ_post·K_g)²)`` e⁻ (a pixel part before the amplifier and an ADC part after
    it); QE, PRNU, DSNU, dark current and full well as in ``truth`` (a
    :class:`bayescap.simulate.SensorTruth` at gain 1). ``kw`` goes to
    :func:`bayescap.simulate.simulate_ptc` (``metadata`` gets ``analog_gain``)."""
    from bayescap.simulate import simulate_ptc

    out, truths = [], []
    md = dict(kw.pop("metadata", {}) or {})
    for i, g in enumerate(gains):
        k = truth.conversion_gain_e_per_dn / g
        t = replace(
            truth,
            conversion_gain_e_per_dn=k,
            read_noise_e=float(np.hypot(read_noise_pre_e, read_noise_post_dn * k)),
        )
        truths.append(t)
        out.append(simulate_ptc(t, seed=seed + 1000 * i, metadata={**md, "analog_gain": float(g)}, **kw))
    return out, truths
