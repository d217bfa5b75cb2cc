"""What the fit says about the sensor's response and the brighter-fatter effect
(``response_model`` in the result's JSON and one line of its text): which term the data chose,
and whether the two could be told apart (docs/real_sensors.md)."""

from __future__ import annotations

import numpy as np

__all__ = ["response_model_summary"]


def _ci(x):
    lo, med, hi = np.quantile(np.asarray(x, float), [0.025, 0.5, 0.975])
    return float(med), float(lo), float(hi)


def response_model_summary(result) -> dict:
    """``{"response", "brighter_fatter", "told_apart", "reading", ...}``: ``response`` is
    ``"linear"`` or ``"monotone_log_slope"`` (the Bernstein log-slope of
    :mod:`bayescap.model.response`, with ``n_basis`` and ``reference_signal_dn``);
    ``brighter_fatter`` whether the a₀₀ term is in the model, with ``brighter_fatter_detected``
    (its 95 % interval excludes 0); ``told_apart`` whether the means against photon counts could
    tell a response non-linearity from a variance-only loss; ``reading`` the sentence the text
    prints."""
    m = result.model
    tm = m.terms
    p = result.draws
    photons = m.data.photons_per_pixel is not None
    bent = bool(getattr(tm, "nonlinearity", False))
    bf = bool(getattr(tm, "brighter_fatter", False))
    out = {
        "response": "monotone_log_slope" if bent else "linear",
        "brighter_fatter": bf,
        "told_apart": photons,
    }
    if bent or bf:
        out["reference_signal_dn"] = float(m.response_ref_dn)
    if bent:
        out["n_basis"] = m.n_basis
    detected = None
    if bf and "brighter_fatter_a00_per_e" in p:
        med, lo, hi = _ci(p["brighter_fatter_a00_per_e"])
        detected = bool(lo > 0 or hi < 0)
        out["brighter_fatter_detected"] = detected
    if not photons and bent:
        reading = (
            "the photon-transfer curve bends; without photon counts a response non-linearity and a "
            "brighter-fatter variance loss cannot be told apart: fitted as a response (K, the small-signal "
            "gain, is valid either way, with a wider interval; the full well and the linearity error assume the "
            "response reading, and on a brighter-fatter sensor overstate the charge at the clip); add "
            "photons_per_pixel to tell them apart"
        )
    elif bent and detected:
        reading = (
            f"the means bend against the photons (response non-linearity, deviation at S_ref "
            f"{100 * _ci(p['response_nonlinearity'])[0]:+.2g} %) and the variances bend further: brighter-fatter "
            f"a00 = {_ci(p['brighter_fatter_a00_per_e'])[0]:.3g} per e-"
        )
    elif bent:
        reading = (
            f"response non-linearity: the means bend against the photons (deviation at S_ref "
            f"{100 * _ci(p['response_nonlinearity'])[0]:+.2g} %)"
            + ("; no brighter-fatter beyond it (a00 consistent with 0)" if bf else "")
        )
    elif bf and detected:
        reading = (
            f"brighter-fatter: the means are straight against the photons, the variances bend "
            f"(a00 = {_ci(p['brighter_fatter_a00_per_e'])[0]:.3g} per e-)"
        )
    elif bf:
        reading = "linear: the means are straight against the photons and a00 is consistent with 0"
    elif photons:
        reading = "linear: the means are straight against the photons and the photon-transfer curve does not bend"
    else:
        reading = (
            "linear: the photon-transfer curve does not bend (without photon counts the means' linearity is "
            "not measured)"
        )
    out["reading"] = reading
    return out
